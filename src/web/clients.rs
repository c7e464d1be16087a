//! Who holds the page's connections, and who gives way when they run out: the table of open
//! connections (one [`Client`] each, shared with its requests as an extension) and what each is
//! doing, set by the middleware here.
//!
//! A connection is accepted at once. At `web.max_connections` open, or
//! `web.max_connections_per_client` from one address, the new connection closes one that is
//! waiting for a request (or still sending a request's body): first one that never had a
//! request answered (with a token: never showed it), among those first one that never sent a
//! byte, then one of the address holding the most, the one waiting longest. So a client that
//! sends its request with its connection is not closed by the idle connections opened after
//! it, however fast they come. Connections being answered (a picture being made, a download, an
//! open page's event stream) are never closed to make room; only when every connection is being
//! answered is the newcomer refused (503). So idle or stalled clients, however many, and
//! clients that connect before they authenticate cannot keep the operator out: nginx's
//! `limit_conn` and timeouts, with the reserve going to whoever makes requests.

use axum::body::{Body, Bytes};
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::collections::{BTreeMap, HashMap};
use std::net::IpAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};
use tokio::sync::Notify;

/// Request bodies the page accepts (the calibration page's points, an acknowledgement).
pub const MAX_BODY_BYTES: usize = 64 * 1024;

/// The limits of the page's connections (from `[web]`).
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    pub max_connections: usize,
    pub per_client: usize,
    /// From a connection's start, or its previous answer's end, to a request's last header.
    pub header_timeout: Duration,
    /// From a request's headers to its body's last byte.
    pub body_timeout: Duration,
    /// Nothing read or written while no request is being answered.
    pub idle_timeout: Duration,
}

impl Limits {
    pub fn of(config: &crate::config::WebConfig) -> Limits {
        Limits {
            max_connections: config.max_connections,
            per_client: config.max_connections_per_client,
            header_timeout: Duration::from_secs(config.header_timeout_s),
            body_timeout: Duration::from_secs(config.body_timeout_s),
            idle_timeout: Duration::from_secs(config.idle_timeout_s),
        }
    }
}

/// What a connection is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Phase {
    /// Waiting for a request, or reading its headers.
    Waiting = 0,
    /// Reading a request's body.
    Receiving = 1,
    /// A request being answered: its response is being made.
    Answering = 2,
    /// A response's body being sent (a download, an event stream).
    Sending = 3,
}

impl Phase {
    fn of(v: u8) -> Phase {
        match v {
            1 => Phase::Receiving,
            2 => Phase::Answering,
            3 => Phase::Sending,
            _ => Phase::Waiting,
        }
    }

    /// Whether a connection doing this may be closed to make room.
    fn gives_way(self) -> bool {
        matches!(self, Phase::Waiting | Phase::Receiving)
    }
}

/// One open connection.
pub struct Client {
    pub addr: IpAddr,
    id: u64,
    phase: AtomicU8,
    /// A request of it was answered (not refused for want of the token).
    proven: AtomicBool,
    /// It serves an event stream.
    stream: AtomicBool,
    /// It sent a byte.
    heard: AtomicBool,
    /// Its socket, to look for bytes it sent that were not read yet (-1: none).
    fd: AtomicI32,
    /// When its phase last changed, in ms from the table's start.
    since_ms: AtomicU64,
    epoch: Instant,
    closed: AtomicBool,
    close: Notify,
}

impl Client {
    pub fn phase(&self) -> Phase {
        Phase::of(self.phase.load(Ordering::SeqCst))
    }

    fn set(&self, phase: Phase) {
        self.phase.store(phase as u8, Ordering::SeqCst);
        let ms = self.epoch.elapsed().as_millis() as u64;
        self.since_ms.store(ms, Ordering::SeqCst);
    }

    /// Marks the connection as one that sent something.
    pub fn heard(&self) {
        self.heard.store(true, Ordering::Relaxed);
    }

    /// Its socket `fd`, open while the connection is in the table.
    pub fn watch(&self, fd: std::os::fd::RawFd) {
        self.fd.store(fd, Ordering::Relaxed);
    }

    /// Whether it sent something: read already, or waiting in its socket (a request sent with
    /// the connection that its task has not read yet).
    fn spoke(&self) -> bool {
        if self.heard.load(Ordering::Relaxed) {
            return true;
        }
        let fd = self.fd.load(Ordering::Relaxed);
        if fd < 0 {
            return false;
        }
        let mut byte = 0u8;
        // SAFETY: a one-byte peek into a local on the connection's socket, open while it is in
        // the table (its task removes it before closing it); it never blocks.
        let n = unsafe {
            libc::recv(
                fd,
                (&mut byte as *mut u8).cast(),
                1,
                libc::MSG_PEEK | libc::MSG_DONTWAIT,
            )
        };
        if n > 0 {
            self.heard();
        }
        n > 0
    }

    /// Marks the connection as serving an event stream until the guard is dropped.
    pub fn streaming(self: &Arc<Self>) -> StreamMark {
        self.stream.store(true, Ordering::SeqCst);
        StreamMark(self.clone())
    }

    /// Closes the connection (its task drops it).
    pub fn close(&self) {
        self.closed.store(true, Ordering::SeqCst);
        self.close.notify_one();
    }

    /// Resolves once [`Client::close`] was called.
    pub async fn closed(&self) {
        if !self.closed.load(Ordering::SeqCst) {
            self.close.notified().await;
        }
    }
}

/// See [`Client::streaming`].
pub struct StreamMark(Arc<Client>);

impl Drop for StreamMark {
    fn drop(&mut self) {
        self.0.stream.store(false, Ordering::SeqCst);
    }
}

/// Sets a phase for as long as it lives, then the one it was made with.
struct PhaseGuard {
    client: Arc<Client>,
    after: Phase,
}

impl PhaseGuard {
    /// Now `now`, and `after` once dropped.
    fn switch(&mut self, now: Phase, after: Phase) {
        self.client.set(now);
        self.after = after;
    }
}

impl Drop for PhaseGuard {
    fn drop(&mut self) {
        self.client.set(self.after);
    }
}

fn phase(client: &Arc<Client>, now: Phase, after: Phase) -> PhaseGuard {
    client.set(now);
    PhaseGuard {
        client: client.clone(),
        after,
    }
}

/// The open connections.
pub struct Clients {
    limits: Limits,
    epoch: Instant,
    table: Mutex<Table>,
}

#[derive(Default)]
struct Table {
    next: u64,
    open: BTreeMap<u64, Arc<Client>>,
    per_address: HashMap<IpAddr, usize>,
}

impl Table {
    fn remove(&mut self, id: u64) {
        if let Some(client) = self.open.remove(&id) {
            if let Some(n) = self.per_address.get_mut(&client.addr) {
                *n -= 1;
                if *n == 0 {
                    self.per_address.remove(&client.addr);
                }
            }
        }
    }

    /// The connection to close for room (see the module doc), among those `pick` accepts. One
    /// that seems silent is looked at first: if it sent something, the next is chosen.
    fn victim(&self, pick: impl Fn(&Client) -> bool) -> Option<Arc<Client>> {
        loop {
            let victim = self
                .open
                .values()
                .filter(|c| pick(c) && !c.closed.load(Ordering::SeqCst))
                .min_by_key(|c| {
                    (
                        c.proven.load(Ordering::SeqCst),
                        c.heard.load(Ordering::Relaxed),
                        usize::MAX - self.per_address.get(&c.addr).copied().unwrap_or(0),
                        c.since_ms.load(Ordering::SeqCst),
                    )
                })
                .cloned()?;
            // Each turn marks one more connection heard: at most as many turns as are open.
            if victim.heard.load(Ordering::Relaxed) || !victim.spoke() {
                return Some(victim);
            }
        }
    }

    fn evict(&mut self, victim: &Client) {
        victim.close();
        self.remove(victim.id);
    }
}

impl Clients {
    pub fn new(limits: Limits) -> Clients {
        Clients {
            limits,
            epoch: Instant::now(),
            table: Mutex::new(Table::default()),
        }
    }

    pub fn limits(&self) -> Limits {
        self.limits
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Table> {
        self.table.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A place for a new connection from `addr`, made by closing another if needed; None when
    /// every connection that would have to give way is being answered.
    pub fn admit(&self, addr: IpAddr) -> Option<Arc<Client>> {
        let mut table = self.lock();
        let from_addr = table.per_address.get(&addr).copied().unwrap_or(0);
        if from_addr >= self.limits.per_client {
            let victim = table.victim(|c| c.addr == addr && c.phase().gives_way())?;
            table.evict(&victim);
        } else if table.open.len() >= self.limits.max_connections {
            let victim = table.victim(|c| c.phase().gives_way())?;
            table.evict(&victim);
        }
        table.next += 1;
        let client = Arc::new(Client {
            addr,
            id: table.next,
            phase: AtomicU8::new(Phase::Waiting as u8),
            proven: AtomicBool::new(false),
            stream: AtomicBool::new(false),
            heard: AtomicBool::new(false),
            fd: AtomicI32::new(-1),
            since_ms: AtomicU64::new(self.epoch.elapsed().as_millis() as u64),
            epoch: self.epoch,
            closed: AtomicBool::new(false),
            close: Notify::new(),
        });
        table.open.insert(client.id, client.clone());
        *table.per_address.entry(addr).or_default() += 1;
        Some(client)
    }

    /// Closes one connection that gives way (out of file descriptors: one for the next).
    pub fn make_room(&self) -> bool {
        let mut table = self.lock();
        match table.victim(|c| c.phase().gives_way()) {
            Some(victim) => {
                table.evict(&victim);
                true
            }
            None => false,
        }
    }

    /// Closes the event stream of the address holding the most, the oldest (at
    /// `web.max_event_streams`: a page's browser opens it again by itself).
    pub fn close_a_stream(&self) -> bool {
        let table = self.lock();
        let streams = |addr: &IpAddr| {
            table
                .open
                .values()
                .filter(|c| c.addr == *addr && c.stream.load(Ordering::SeqCst))
                .count()
        };
        let victim = table
            .open
            .values()
            .filter(|c| c.stream.load(Ordering::SeqCst) && !c.closed.load(Ordering::SeqCst))
            .max_by_key(|c| (streams(&c.addr), u64::MAX - c.id))
            .cloned();
        drop(table);
        victim.map(|v| v.close()).is_some()
    }

    /// Forgets a connection that ended.
    pub fn remove(&self, client: &Client) {
        self.lock().remove(client.id);
    }

    /// Connections open.
    pub fn open(&self) -> usize {
        self.lock().open.len()
    }
}

/// The middleware that tells a connection's [`Client`] what its request does: answering until
/// the response is made, then sending until its body is sent; a request answered otherwise
/// than 401 proves the connection.
pub(crate) async fn track(request: Request, next: Next) -> Response {
    let Some(client) = request.extensions().get::<Arc<Client>>().cloned() else {
        return next.run(request).await;
    };
    let mut sending = phase(&client, Phase::Answering, Phase::Waiting);
    let response = next.run(request).await;
    if response.status() != StatusCode::UNAUTHORIZED {
        client.proven.store(true, Ordering::SeqCst);
    }
    sending.switch(Phase::Sending, Phase::Waiting);
    response.map(|body| {
        Body::new(Tracked {
            inner: body,
            _sending: sending,
        })
    })
}

/// A response body that keeps its connection [`Phase::Sending`] until it is sent or dropped.
struct Tracked {
    inner: Body,
    _sending: PhaseGuard,
}

impl http_body::Body for Tracked {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Bytes>, axum::Error>>> {
        Pin::new(&mut self.get_mut().inner).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

/// The middleware that receives a request's body before anything answers it: refused at once
/// (413) when its Content-Length is over [`MAX_BODY_BYTES`], read to its end within
/// `web.body_timeout_s` (else 408) and at most that many bytes; the connection is closed after
/// a refusal, so an unread body never holds it.
pub(crate) async fn receive(
    State(limits): State<Limits>,
    request: Request,
    next: Next,
) -> Response {
    let headers = request.headers();
    let length = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    let has_body = length.is_some_and(|n| n > 0) || headers.contains_key(header::TRANSFER_ENCODING);
    if !has_body {
        return next.run(request).await;
    }
    if length.is_some_and(|n| n > MAX_BODY_BYTES as u64) {
        return refuse(StatusCode::PAYLOAD_TOO_LARGE, too_large());
    }
    let receiving = request
        .extensions()
        .get::<Arc<Client>>()
        .map(|c| phase(c, Phase::Receiving, Phase::Answering));
    let (parts, body) = request.into_parts();
    let read = tokio::time::timeout(limits.body_timeout, read_body(body)).await;
    drop(receiving);
    match read {
        Err(_) => refuse(
            StatusCode::REQUEST_TIMEOUT,
            format!(
                "the request's body did not arrive within {} s (web.body_timeout_s)",
                limits.body_timeout.as_secs()
            ),
        ),
        Ok(Err(status)) if status == StatusCode::PAYLOAD_TOO_LARGE => refuse(status, too_large()),
        Ok(Err(status)) => refuse(status, "the request's body could not be read".into()),
        Ok(Ok(bytes)) => {
            next.run(Request::from_parts(parts, Body::from(bytes)))
                .await
        }
    }
}

fn too_large() -> String {
    format!("a request's body may have at most {MAX_BODY_BYTES} bytes")
}

/// A body read to its end, at most [`MAX_BODY_BYTES`].
async fn read_body(body: Body) -> Result<Bytes, StatusCode> {
    use futures_util::StreamExt;
    let mut stream = body.into_data_stream();
    let mut bytes = Vec::new();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|_| StatusCode::BAD_REQUEST)?;
        if bytes.len() + chunk.len() > MAX_BODY_BYTES {
            return Err(StatusCode::PAYLOAD_TOO_LARGE);
        }
        bytes.extend_from_slice(&chunk);
    }
    Ok(Bytes::from(bytes))
}

/// An error answer (as the routes give them) after which the connection is closed.
fn refuse(status: StatusCode, message: String) -> Response {
    let mut response =
        (status, axum::Json(serde_json::json!({ "error": message }))).into_response();
    response
        .headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits(max: usize, per_client: usize) -> Limits {
        Limits {
            max_connections: max,
            per_client,
            header_timeout: Duration::from_secs(10),
            body_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(30),
        }
    }

    #[test]
    fn a_newcomer_closes_an_idle_connection_never_one_being_answered() {
        let clients = Clients::new(limits(3, 3));
        let a: IpAddr = "10.0.0.1".parse().unwrap();
        let first = clients.admit(a).unwrap();
        let second = clients.admit(a).unwrap();
        let third = clients.admit(a).unwrap();
        // The second was answered once (proven), the third is being answered.
        second.proven.store(true, Ordering::SeqCst);
        let _third = phase(&third, Phase::Answering, Phase::Waiting);
        let fourth = clients.admit(a).unwrap();
        assert!(
            first.closed.load(Ordering::SeqCst),
            "the unproven idle one gave way"
        );
        assert_eq!(clients.open(), 3);
        let _fourth = phase(&fourth, Phase::Sending, Phase::Waiting);
        let fifth = clients.admit(a).unwrap();
        assert!(
            second.closed.load(Ordering::SeqCst),
            "then the proven idle one"
        );
        assert!(!third.closed.load(Ordering::SeqCst) && !fourth.closed.load(Ordering::SeqCst));
        // Everything being answered: a newcomer is refused.
        let _fifth = phase(&fifth, Phase::Answering, Phase::Waiting);
        assert!(clients.admit(a).is_none());
        assert_eq!(clients.open(), 3);
        // A body being received gives way.
        drop(_fifth);
        let _receiving = phase(&fifth, Phase::Receiving, Phase::Answering);
        assert!(clients.admit(a).is_some());
        assert!(fifth.closed.load(Ordering::SeqCst));
    }

    #[test]
    fn a_connection_that_sent_its_request_outlasts_silent_ones_opened_after_it() {
        let clients = Clients::new(limits(3, 3));
        let a: IpAddr = "10.0.0.1".parse().unwrap();
        // Its request waits in its socket, not read yet.
        let (mut near, far) = std::os::unix::net::UnixStream::pair().unwrap();
        std::io::Write::write_all(&mut near, b"GET / HTTP/1.1\r\n\r\n").unwrap();
        let operator = clients.admit(a).unwrap();
        operator.watch(std::os::fd::AsRawFd::as_raw_fd(&far));
        let silent: Vec<_> = (0..20).map(|_| clients.admit(a).unwrap()).collect();
        assert!(!operator.closed.load(Ordering::SeqCst));
        let closed = silent.iter().filter(|c| c.closed.load(Ordering::SeqCst));
        assert_eq!(closed.count(), 18);
    }

    #[test]
    fn the_address_holding_the_most_gives_way_first_and_each_address_has_its_share() {
        let (many, one): (IpAddr, IpAddr) =
            ("10.0.0.1".parse().unwrap(), "10.0.0.2".parse().unwrap());
        let closed =
            |c: &[Arc<Client>]| c.iter().filter(|c| c.closed.load(Ordering::SeqCst)).count();
        // Full: the operator's second connection closes one of the flood's, not its own.
        let clients = Clients::new(limits(4, 4));
        let operator = clients.admit(one).unwrap();
        let flood: Vec<_> = (0..3).map(|_| clients.admit(many).unwrap()).collect();
        clients.admit(one).unwrap();
        assert!(!operator.closed.load(Ordering::SeqCst));
        assert_eq!(closed(&flood), 1);
        // At its share, an address makes room among its own, though there is room for others.
        let clients = Clients::new(limits(8, 3));
        let operator = clients.admit(one).unwrap();
        let flood: Vec<_> = (0..3).map(|_| clients.admit(many).unwrap()).collect();
        clients.admit(many).unwrap();
        assert!(!operator.closed.load(Ordering::SeqCst));
        assert_eq!(closed(&flood), 1);
        assert_eq!(clients.open(), 4);
    }

    #[test]
    fn the_stream_of_the_address_holding_the_most_streams_is_closed_first() {
        let clients = Clients::new(limits(8, 8));
        let (many, one): (IpAddr, IpAddr) =
            ("10.0.0.1".parse().unwrap(), "10.0.0.2".parse().unwrap());
        let page = clients.admit(one).unwrap();
        let _page_stream = page.streaming();
        let flood: Vec<_> = (0..2).map(|_| clients.admit(many).unwrap()).collect();
        let _marks: Vec<_> = flood.iter().map(|c| c.streaming()).collect();
        assert!(clients.close_a_stream());
        assert!(!page.closed.load(Ordering::SeqCst));
        assert!(flood[0].closed.load(Ordering::SeqCst));
    }
}
