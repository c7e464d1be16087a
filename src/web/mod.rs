//! The operator page: the newest layer of every view with its vectors, the build's timeline and
//! health, served over HTTP from what is on disk in a build directory (journal, status.json,
//! originals, calibration). It only reads the build, except the calibration page, which saves
//! points files and calibrations into it when `web.calibration_page` allows. The daemon starts it
//! beside the capture path and `layerwise serve --build DIR` serves any build, finished or being
//! written by another process.
//!
//! The server runs on its own thread with its own small runtime, so no request, slow client or
//! picture being encoded can take time from the capture path. It watches the journal, the
//! inspection and alarm logs and status.json (woken by the system's change notification, and a
//! stat every 250 ms besides; then only the appended bytes) and pushes updates to open pages as
//! server-sent events. Only layer numbers and view names from a request reach the file system.

mod alarm;
pub mod bed;
pub mod calibration;
pub mod clients;
pub mod files;
pub mod harness;
mod host;
pub mod listener;
pub mod preview;
mod priority;
pub mod process;
mod routes;
mod state;
pub mod supervisor;
pub mod timeline;
pub mod trends;
mod verdicts;
mod wake;

use crate::config::WebConfig;
use crate::shutdown::Shutdown;
use clients::{Clients, Limits};
use preview::Pictures;
use priority::lower_priority;
pub(crate) use state::PageState;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicUsize;
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, Instant, SystemTime};
use timeline::{Tails, Timeline};
use tokio::sync::{watch, Semaphore};
use tracing::warn;

/// How often the journal and status.json are looked at.
pub const WATCH_PERIOD: Duration = Duration::from_millis(250);
/// The status report (it sums the sizes of the series) is made at most this often.
const STATUS_PERIOD: Duration = Duration::from_secs(1);
/// The status report is made again at least this often when nothing changed, so the ages it
/// shows count on and a daemon that died is shown stopped.
const STATUS_STALE: Duration = Duration::from_secs(5);

/// How long after a status report the next one waits unless it is urgent: [`STATUS_PERIOD`], or
/// ten times what the last one took (it replays the journal: 0.3-0.5 s at 12 000 layers), so
/// that remaking it takes at most a tenth of a core on a long build; never more than
/// [`STATUS_STALE`].
fn status_gap(took: Duration) -> Duration {
    (took * 10).clamp(STATUS_PERIOD, STATUS_STALE)
}

#[derive(Debug, thiserror::Error)]
pub enum WebError {
    #[error("cannot listen on {addr} (set web.listen to a free address, or \"\" for no page)")]
    Listen {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error("web.token_file {} (write the token, one line, into it)", path.display())]
    TokenRead {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("web.token_file {}: must hold one token of at least 16 characters without spaces (e.g. from `openssl rand -hex 32`)", path.display())]
    TokenInvalid { path: PathBuf },
    #[error("cannot start the page server")]
    Runtime(#[source] std::io::Error),
}

/// A running page server. It stops when the shutdown it was started with is requested, or when
/// [`WebServer::stop`] is called (or it is dropped).
pub struct WebServer {
    pub addr: SocketAddr,
    /// A child of the shutdown it was started with.
    stop: Shutdown,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl WebServer {
    /// Listens on `addr` (port 0: any free port, see [`WebServer::addr`]) and serves the build
    /// directory `dir` from a thread of its own until `shutdown` is requested.
    pub fn start(
        dir: &Path,
        config: &WebConfig,
        addr: SocketAddr,
        shutdown: &Shutdown,
    ) -> Result<WebServer, WebError> {
        let std_listener =
            listener::bind(addr).map_err(|source| WebError::Listen { addr, source })?;
        WebServer::start_listening(dir, config, std_listener, shutdown)
    }

    /// Serves `dir` on a listening socket already bound (the daemon's, handed to its page
    /// process), until `shutdown` is requested.
    pub fn start_listening(
        dir: &Path,
        config: &WebConfig,
        std_listener: std::net::TcpListener,
        shutdown: &Shutdown,
    ) -> Result<WebServer, WebError> {
        let listen_error = |source| WebError::Listen {
            addr: std_listener
                .local_addr()
                .unwrap_or_else(|_| SocketAddr::from(([0, 0, 0, 0], 0))),
            source,
        };
        std_listener.set_nonblocking(true).map_err(listen_error)?;
        let addr = std_listener.local_addr().map_err(listen_error)?;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .max_blocking_threads(4)
            .thread_name("layerwise-web")
            .on_thread_start(lower_priority)
            .build()
            .map_err(WebError::Runtime)?;
        let stop = shutdown.child();
        let shared = page_state(dir, config, stop.clone())?;
        let server_stop = stop.clone();
        let thread = std::thread::Builder::new()
            .name("layerwise-web".into())
            .spawn(move || {
                lower_priority();
                runtime.block_on(async move {
                    let listener = match tokio::net::TcpListener::from_std(std_listener) {
                        Ok(l) => l,
                        Err(e) => return warn!(error = %e, "page server: cannot listen"),
                    };
                    tokio::spawn(watch_build(shared.clone(), WATCH_PERIOD));
                    let app = routes::router(shared.clone());
                    listener::serve(listener, app, shared.clients.clone(), server_stop).await;
                });
                // Pictures being encoded are not waited for.
                runtime.shutdown_timeout(Duration::from_millis(100));
            })
            .map_err(WebError::Runtime)?;
        Ok(WebServer {
            addr,
            stop,
            thread: Some(thread),
        })
    }

    /// Stops the server (open event streams end, requests being answered finish) and waits for
    /// its thread.
    pub fn stop(mut self, reason: crate::shutdown::StopReason) {
        self.stop.request(reason);
        self.wait();
    }

    /// Waits for the server to stop (once the shutdown it was started with is requested).
    pub fn join(mut self) {
        self.wait();
    }

    fn wait(&mut self) {
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for WebServer {
    /// A server dropped without [`WebServer::stop`] stops too (its own shutdown, a child of the
    /// one it was started with, is requested).
    fn drop(&mut self) {
        if !self.stop.is_requested() {
            self.stop.request(crate::shutdown::StopReason::Terminated(
                crate::shutdown::TermSignal::Term,
            ));
        }
        self.wait();
    }
}

/// What the handlers of a page of `dir` share, the timeline read (see [`PageState`]).
fn page_state(dir: &Path, config: &WebConfig, stop: Shutdown) -> Result<Arc<PageState>, WebError> {
    let token = match &config.token_file {
        Some(path) => Some(read_token(path)?),
        None => None,
    };
    let mut limits = Limits::of(config);
    limits.max_connections = process::connection_room(limits.max_connections);
    limits.per_client = limits.per_client.min(limits.max_connections);
    // What is on disk already is read before the first request is answered.
    let (mut timeline, mut tails) = (Timeline::default(), Tails::new(dir));
    if let Err(e) = timeline.refresh(&mut tails) {
        warn!(dir = %dir.display(), error = %crate::logging::Chain(&e), "page server: cannot read the build's logs yet");
    }
    Ok(Arc::new(PageState {
        dir: dir.to_path_buf(),
        config: config.clone(),
        token,
        timeline: RwLock::new(timeline),
        tails: Mutex::new(tails),
        status: RwLock::new(None),
        info: Mutex::new(None),
        pictures: Pictures::new(config.preview_px, config.cache_mb as usize * 1_000_000),
        encode: Semaphore::new(1),
        clients: Arc::new(Clients::new(limits)),
        updates: watch::channel(0).0,
        streams: AtomicUsize::new(0),
        stop,
    }))
}

/// The bearer token of `web.token_file`, checked.
pub fn read_token(path: &Path) -> Result<String, WebError> {
    let text =
        crate::fsutil::read_text_bounded(path, 4096).map_err(|source| WebError::TokenRead {
            path: path.to_path_buf(),
            source,
        })?;
    let token = text.trim().to_string();
    if token.len() < 16 || token.chars().any(|c| c.is_whitespace() || c.is_control()) {
        return Err(WebError::TokenInvalid {
            path: path.to_path_buf(),
        });
    }
    Ok(token)
}

/// Looks at the journal, the inspection and alarm logs and status.json when they change (as the
/// system tells: [`wake`]) and every `period` ([`WATCH_PERIOD`]) besides; when they changed, reads
/// what is new, remakes the status (at most every [`STATUS_PERIOD`] or [`status_gap`],
/// at least every [`STATUS_STALE`]; at once when the inspection or alarm log grew: a layer's
/// flags or an alarm wait for no period), tells the open pages, and makes the newest layer's
/// previews ahead of their request.
async fn watch_build(shared: Arc<PageState>, period: Duration) {
    let wake = wake::BuildWake::new(&shared.dir)
        .map_err(|e| {
            tracing::info!(
                dir = %shared.dir.display(),
                error = %e,
                "page server: no change notification for the build directory; it is looked at every {} ms instead",
                period.as_millis()
            )
        })
        .ok();
    // Without notifications, only the look period wakes the watch.
    let changed = || async {
        match &wake {
            Some(w) => w.changed().await,
            None => std::future::pending().await,
        }
    };
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let stop = shared.stop.clone();
    // The journal's length, the inspection and alarm logs' lengths, status.json's time.
    let mut seen: Option<(u64, u64, Option<SystemTime>)> = None;
    let mut status_at: Option<Instant> = None;
    let mut gap = STATUS_PERIOD;
    let mut pending = true;
    let mut warned = false;
    let preparing = Arc::new(std::sync::atomic::AtomicBool::new(false));
    // A log longer than one read is read on at once.
    let mut again = false;
    loop {
        if !std::mem::take(&mut again) {
            tokio::select! {
                _ = tick.tick() => {}
                _ = changed() => {}
                _ = stop.requested() => return,
            }
        } else if stop.is_requested() {
            return;
        }
        let s = shared.clone();
        let looked = tokio::task::spawn_blocking(move || {
            let stamp = |name: &str| std::fs::metadata(s.dir.join(name)).ok();
            // The alarm's history too: an acknowledgement (on any page, or `alarm ack`) clears
            // the banner of every open page.
            let logs = stamp(crate::build_dir::INSPECTION).map_or(0, |m| m.len())
                + stamp(crate::build_dir::ALARM).map_or(0, |m| m.len());
            let journal = stamp(crate::build_dir::JOURNAL).map_or(0, |m| m.len());
            let status = stamp(crate::build_dir::STATUS).and_then(|m| m.modified().ok());
            // Read and parsed before the timeline is locked: the page's requests wait only
            // for what was read to be taken in.
            let (appended, error) = s.tails.lock().unwrap_or_else(|e| e.into_inner()).read();
            let more = appended.more;
            let applied = s
                .timeline
                .write()
                .unwrap_or_else(|e| e.into_inner())
                .apply(appended);
            (journal, logs, status, applied, error.map_or(Ok(more), Err))
        })
        .await;
        let Ok((journal, logs, status_time, applied, read)) = looked else {
            continue;
        };
        match read {
            Err(e) if !warned => {
                warn!(dir = %shared.dir.display(), error = %crate::logging::Chain(&e), "page server: cannot read the build's logs");
                warned = true;
            }
            Ok(more) => again = more,
            Err(_) => {}
        }
        let looks = (journal, logs, status_time);
        // A grown inspection or alarm log is what the operator must see without delay.
        let urgent = seen.is_some_and(|(_, before, _)| before != logs);
        // What was read changed the timeline (the rest of a log read in steps, too): the pages
        // are told, even when the files looked the same as at the last look.
        if seen != Some(looks) || applied || status_at.is_some_and(|t| t.elapsed() >= STATUS_STALE)
        {
            seen = Some(looks);
            pending = true;
        }
        if !pending || (!urgent && status_at.is_some_and(|t| t.elapsed() < gap)) {
            continue;
        }
        pending = false;
        let started = Instant::now();
        status_at = Some(started);
        let s = shared.clone();
        let _ = tokio::task::spawn_blocking(move || s.refresh_status()).await;
        gap = status_gap(started.elapsed());
        shared.updates.send_modify(|v| *v += 1);
        // The newest previews are made beside the watch, one batch at a time.
        if !preparing.swap(true, std::sync::atomic::Ordering::SeqCst) {
            let (s, flag) = (shared.clone(), preparing.clone());
            tokio::spawn(async move {
                routes::prepare_newest(&s).await;
                flag.store(false, std::sync::atomic::Ordering::SeqCst);
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    #[test]
    fn a_slow_status_report_is_remade_less_often_but_never_staler_than_its_bound() {
        let ms = Duration::from_millis;
        assert_eq!(status_gap(ms(20)), STATUS_PERIOD, "a short build");
        assert_eq!(status_gap(ms(350)), ms(3500), "a tenth of a core");
        assert_eq!(status_gap(ms(2000)), STATUS_STALE);
    }

    #[test]
    fn a_layers_flags_reach_the_pages_without_waiting_for_the_look_period() {
        let dir = tempfile::tempdir().unwrap();
        let inspection = dir.path().join(crate::build_dir::INSPECTION);
        std::fs::write(&inspection, "").unwrap();
        let stop = Shutdown::new();
        let shared = page_state(dir.path(), &WebConfig::default(), stop.clone()).unwrap();
        let mut updates = shared.updates.subscribe();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            // A look period far longer than the test: only the change notification can tell.
            let watch = tokio::spawn(watch_build(shared.clone(), Duration::from_secs(3600)));
            let wait = Duration::from_secs(20);
            // The first look (at once) tells the pages what is there.
            tokio::time::timeout(wait, updates.changed())
                .await
                .expect("the first look")
                .unwrap();
            let first = *updates.borrow_and_update();
            let mut log = std::fs::OpenOptions::new()
                .append(true)
                .open(&inspection)
                .unwrap();
            log.write_all(b"{\"layer\":1,\"flags\":[]}\n").unwrap();
            tokio::time::timeout(wait, updates.changed())
                .await
                .expect("the pages told of the new record before the next look")
                .unwrap();
            assert!(*updates.borrow() > first);
            stop.request(crate::shutdown::StopReason::Terminated(
                crate::shutdown::TermSignal::Term,
            ));
            watch.await.unwrap();
        });
    }
}
