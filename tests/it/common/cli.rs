//! The `layerwise` binary run as a child process: starting it, stopping it, checking how it
//! ended, with failure messages that show what it said.

use std::path::Path;

pub fn layerwise() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_layerwise"))
}

/// What a finished command said, for failure messages: its exit code, stdout and stderr.
pub fn report(out: &std::process::Output) -> String {
    format!(
        "exit {:?}\n--- stdout\n{}\n--- stderr\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Checks that a command exited 0, showing its output if not.
pub fn assert_success(out: &std::process::Output) {
    assert!(out.status.success(), "{}", report(out));
}

/// Checks that a command exited 1 (a refusal, not a crash or a success) and returns its stderr.
pub fn assert_exit_1(out: &std::process::Output) -> String {
    assert_eq!(out.status.code(), Some(1), "{}", report(out));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Running a command to its end and checking how it ended; failures name the command line.
pub trait Run {
    /// Runs to the end, checks it exited 0 and returns the output.
    fn succeeds(&mut self) -> std::process::Output;
    /// Runs to the end, checks it exited 0 and returns its stdout as text.
    fn stdout_ok(&mut self) -> String {
        String::from_utf8_lossy(&self.succeeds().stdout).into_owned()
    }
    /// Runs to the end, checks it exited 0 and returns its stdout parsed as JSON.
    fn json_ok(&mut self) -> serde_json::Value {
        let out = self.succeeds();
        serde_json::from_slice(&out.stdout)
            .unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {}", report(&out)))
    }
    /// Runs to the end, checks it exited 1 and returns its stderr.
    fn fails(&mut self) -> String;
}

fn output_of(command: &mut std::process::Command) -> std::process::Output {
    command
        .output()
        .unwrap_or_else(|e| panic!("{command:?} did not start: {e}"))
}

impl Run for std::process::Command {
    fn succeeds(&mut self) -> std::process::Output {
        let out = output_of(self);
        assert!(out.status.success(), "{self:?}: {}", report(&out));
        out
    }

    fn fails(&mut self) -> String {
        let out = output_of(self);
        assert_eq!(out.status.code(), Some(1), "{self:?}: {}", report(&out));
        String::from_utf8_lossy(&out.stderr).into_owned()
    }
}

/// `layerwise run --config FILE`, not started.
pub fn run_command(config_path: &Path) -> std::process::Command {
    let mut command = layerwise();
    command.arg("run").arg("--config").arg(config_path);
    command
}

/// Runs `layerwise run --config FILE` to its end and checks it succeeded.
pub fn run_build(config_path: &Path) -> std::process::Output {
    run_command(config_path).succeeds()
}

/// Starts `layerwise run --config FILE` in the background, its stderr going to `stderr`.
pub fn spawn_build(config_path: &Path, stderr: std::process::Stdio) -> std::process::Child {
    run_command(config_path)
        .stderr(stderr)
        .spawn()
        .expect("layerwise run starts")
}

/// Sends SIGTERM to a running `layerwise` and waits for it to end.
pub fn terminate(child: std::process::Child) -> std::process::Output {
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    child.wait_with_output().unwrap()
}

/// `status --json` of a build, polled until `ready` accepts it.
pub fn status_until(
    build: &std::path::Path,
    what: &str,
    ready: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    loop {
        let out = layerwise()
            .args(["status", "--json", "--build"])
            .arg(build)
            .output()
            .unwrap();
        if out.status.success() {
            let status: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            if ready(&status) {
                return status;
            }
        }
        assert!(
            std::time::Instant::now() < deadline,
            "status never showed {what}"
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
}
