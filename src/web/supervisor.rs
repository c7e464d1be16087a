//! The daemon's page as a process of its own: nothing a request does can end the capturing
//! process (docs/architecture.md, "The operator page's process").
//!
//! The daemon binds the page's address itself (so a taken port is its error, said once, and the
//! address stays the same across restarts: clients wait in the socket's backlog meanwhile) and
//! starts `layerwise serve` on that socket, handed down as descriptor [`LISTEN_FD`]. The child
//! bounds its own address space (`web.memory_mb`), makes itself the kernel's first choice when
//! memory runs out (`oom_score_adj`), and dies with the thread that started it
//! (`PR_SET_PDEATHSIG`), in a process group of its own (a terminal's Ctrl-C goes to the
//! daemon, which stops it). When it ends for any reason but our stop (an abort on a failed
//! allocation, a crash, a kill), this thread logs how and starts it again after a back-off
//! (1 s, doubling to 30 s, back to 1 s once it ran a minute). The daemon's stop sends SIGTERM,
//! then SIGKILL after [`STOP_GRACE`]. Every wait is on the daemon's clock, beside its shutdown.

use super::WebError;
use crate::clock::{Backoff, SharedClock};
use crate::shutdown::Shutdown;
use std::ffi::OsString;
use std::net::{SocketAddr, TcpListener};
use std::os::fd::AsRawFd;
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tracing::{info, warn};

/// The descriptor the page process finds its listening socket at.
pub const LISTEN_FD: i32 = 3;
/// How long a stopped page process has to end before it is killed.
pub const STOP_GRACE: Duration = Duration::from_secs(2);
/// The first wait before a restart; it doubles up to [`RESTART_MAX`].
const RESTART_FIRST: Duration = Duration::from_secs(1);
const RESTART_MAX: Duration = Duration::from_secs(30);
/// A page process that ran this long restarts after [`RESTART_FIRST`] again.
const STABLE: Duration = Duration::from_secs(60);

/// The program and arguments that serve the page on [`LISTEN_FD`] (the binary knows its own
/// command line).
#[derive(Clone, Debug)]
pub struct PageCommand {
    pub program: PathBuf,
    /// `argv[0]` as `ps` shows it.
    pub name: String,
    pub args: Vec<OsString>,
}

/// A supervised page process. It stops when the shutdown it was started with is requested.
pub struct PageProcess {
    pub addr: SocketAddr,
    pid: Arc<AtomicU32>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl PageProcess {
    /// Binds `addr` and keeps a page process serving on it (see the module doc) from a thread
    /// of its own until `shutdown` is requested. The token file is checked here, once.
    pub fn start(
        config: &crate::config::WebConfig,
        addr: SocketAddr,
        command: PageCommand,
        clock: SharedClock,
        shutdown: &Shutdown,
    ) -> Result<PageProcess, WebError> {
        if let Some(path) = &config.token_file {
            super::read_token(path)?;
        }
        let listen_error = |source| WebError::Listen { addr, source };
        let listener = super::listener::bind(addr).map_err(listen_error)?;
        let addr = listener.local_addr().map_err(listen_error)?;
        let stop = shutdown.clone();
        let pid = Arc::new(AtomicU32::new(0));
        let current = pid.clone();
        let thread = std::thread::Builder::new()
            .name("layerwise-page".into())
            .spawn(move || supervise(&listener, &command, &clock, &stop, &current))
            .map_err(WebError::Runtime)?;
        Ok(PageProcess {
            addr,
            pid,
            thread: Some(thread),
        })
    }

    /// The page process's id while one runs.
    pub fn pid(&self) -> Option<u32> {
        Some(self.pid.load(Ordering::SeqCst)).filter(|&p| p != 0)
    }

    /// Waits until the page process was stopped (once the shutdown is requested).
    pub fn join(mut self) {
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Starts the page process, and again each time it ends, until `stop`.
fn supervise(
    listener: &TcpListener,
    command: &PageCommand,
    clock: &SharedClock,
    stop: &Shutdown,
    current: &AtomicU32,
) {
    let mut backoff = Backoff::new(RESTART_FIRST, RESTART_MAX);
    while !stop.is_requested() {
        let started = clock.elapsed();
        match spawn(listener, command) {
            Ok(child) => {
                current.store(child.id(), Ordering::SeqCst);
                info!(pid = child.id(), "operator page process started");
                let ended = run_until_stop(child, clock, stop);
                current.store(0, Ordering::SeqCst);
                let Some(status) = ended else { return };
                if clock.elapsed().saturating_sub(started) >= STABLE {
                    backoff.reset();
                }
                warn!(
                    status = %status,
                    restart_in_s = backoff.current().as_secs_f64(),
                    "the operator page process ended; capture goes on, the page restarts"
                );
            }
            Err(e) => warn!(
                error = %e,
                restart_in_s = backoff.current().as_secs_f64(),
                "cannot start the operator page process; capture goes on"
            ),
        }
        if stop.wait(&clock.after(backoff.advance())).is_some() {
            return;
        }
    }
}

/// `layerwise serve` on the listening socket (see the module doc).
fn spawn(listener: &TcpListener, command: &PageCommand) -> std::io::Result<Child> {
    let fd = listener.as_raw_fd();
    // SAFETY: getpid has no preconditions.
    let parent = unsafe { libc::getpid() };
    let mut cmd = Command::new(&command.program);
    cmd.arg0(&command.name)
        .args(&command.args)
        .stdin(std::process::Stdio::null())
        // glibc's malloc reserves 64 MiB of address space per thread arena: two keep the
        // address-space bound about memory in use.
        .env("MALLOC_ARENA_MAX", "2");
    // SAFETY: only async-signal-safe system calls between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            if fd == LISTEN_FD {
                if libc::fcntl(fd, libc::F_SETFD, 0) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            } else if libc::dup2(fd, LISTEN_FD) < 0 {
                return Err(std::io::Error::last_os_error());
            }
            libc::setpgid(0, 0);
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 || libc::getppid() != parent
            {
                return Err(std::io::Error::other("the daemon ended"));
            }
            Ok(())
        });
    }
    cmd.spawn()
}

/// Waits for the child to end (its status) or for `stop` (then stops it: None).
fn run_until_stop(mut child: Child, clock: &SharedClock, stop: &Shutdown) -> Option<ExitStatus> {
    let Ok(ended) = exit_watch(child.id()) else {
        // No thread to watch it with: stopped, and started again after the back-off.
        signal(&child, libc::SIGKILL);
        return child.wait().ok();
    };
    crossbeam_channel::select! {
        recv(ended) -> _ => return child.wait().ok(),
        recv(stop.receiver()) -> _ => {}
    }
    signal(&child, libc::SIGTERM);
    crossbeam_channel::select! {
        recv(ended) -> _ => {}
        recv(clock.after(STOP_GRACE)) -> _ => {
            warn!(pid = child.id(), "the operator page process did not stop: killed");
            signal(&child, libc::SIGKILL);
        }
    }
    let _ = child.wait();
    None
}

/// A channel that hangs up once process `pid` ended, still unreaped (`WNOWAIT`): until our
/// `wait`, its id cannot be another process's, so signalling it stays safe.
fn exit_watch(pid: u32) -> std::io::Result<crossbeam_channel::Receiver<()>> {
    let (tx, rx) = crossbeam_channel::bounded::<()>(0);
    std::thread::Builder::new()
        .name("layerwise-page-wait".into())
        .spawn(move || {
            loop {
                // SAFETY: a zeroed siginfo_t for waitid to fill.
                let mut info: libc::siginfo_t = unsafe { std::mem::zeroed() };
                // SAFETY: waiting for our own child, without reaping it.
                let r = unsafe {
                    libc::waitid(libc::P_PID, pid, &mut info, libc::WEXITED | libc::WNOWAIT)
                };
                if r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::EINTR) {
                    break;
                }
            }
            drop(tx);
        })?;
    Ok(rx)
}

fn signal(child: &Child, signal: libc::c_int) {
    // SAFETY: kill on our unreaped child (see exit_watch).
    unsafe {
        libc::kill(child.id() as libc::pid_t, signal);
    }
}
