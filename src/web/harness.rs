//! The page's request path without a socket: bytes in as a client sends them on one connection,
//! the bytes the page answers out, through the same connection handling (hyper's parser, the
//! deadlines and limits, the middleware) and routes a client's connection goes through. The
//! coverage-guided fuzz target `web_request` (fuzz/) and tests/it/fuzz_smoke.rs drive it.

use super::{listener, page_state, routes, PageState, WebError};
use crate::config::WebConfig;
use crate::shutdown::{Shutdown, StopReason};
use std::path::Path;
use std::sync::Arc;

/// A page of a build directory answering byte streams.
pub struct Harness {
    runtime: tokio::runtime::Runtime,
    shared: Arc<PageState>,
    app: axum::Router,
}

impl Harness {
    /// The page of the build `dir` with `config`'s limits and token. Its event streams send
    /// their first update and end (the page is stopping), so every answer ends.
    pub fn new(dir: &Path, config: &WebConfig) -> Result<Harness, WebError> {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .max_blocking_threads(2)
            .build()
            .map_err(WebError::Runtime)?;
        let stop = Shutdown::new();
        stop.request(StopReason::TriggerEnded);
        let shared = page_state(dir, config, stop)?;
        let app = runtime.block_on(async { routes::router(shared.clone()) });
        Ok(Harness {
            runtime,
            shared,
            app,
        })
    }

    /// What the page answers `input`, sent on one connection (a socket pair) that the client
    /// then closes for writing (the page answers what it read and closes).
    pub fn answer(&self, input: &[u8]) -> Vec<u8> {
        let Ok((near, far)) = std::os::unix::net::UnixStream::pair() else {
            return Vec::new();
        };
        let input = input.to_vec();
        let client = std::thread::spawn(move || {
            use std::io::{Read, Write};
            let mut near = near;
            let _ = near.write_all(&input);
            let _ = near.shutdown(std::net::Shutdown::Write);
            let mut out = Vec::new();
            let _ = near.read_to_end(&mut out);
            out
        });
        self.runtime.block_on(async {
            let admitted = self.shared.clients.admit([127, 0, 0, 1].into());
            let far = far
                .set_nonblocking(true)
                .and_then(|()| tokio::net::UnixStream::from_std(far));
            if let (Some(admitted), Ok(far)) = (admitted, far) {
                let served = tokio::spawn(listener::connection(
                    far,
                    admitted,
                    self.app.clone(),
                    self.shared.clients.clone(),
                    Shutdown::new(),
                ));
                // A panic while answering is the caller's (the fuzzer's) to see.
                if let Err(e) = served.await {
                    if e.is_panic() {
                        std::panic::resume_unwind(e.into_panic());
                    }
                }
            }
        });
        client.join().unwrap_or_default()
    }
}
