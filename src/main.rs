//! The `layerwise` command: parses the arguments, runs the command, exits once.

mod cli;

use clap::Parser;

/// The last large block freed serves the next allocation of its size (`layerwise::alloc`).
#[global_allocator]
static ALLOCATOR: layerwise::alloc::LargeBlockCache = layerwise::alloc::LargeBlockCache::new();

fn main() {
    // Like other command-line tools: `layerwise dicom info DIR | head` ends quietly.
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let args = cli::Cli::parse();
    layerwise::logging::init(args.verbose);
    let code = match args.command.run() {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("error: {}", cli::report(&e));
            1
        }
    };
    std::process::exit(code);
}
