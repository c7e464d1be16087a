//! The page's listener: accepts every connection at once (who gives way when they run out is
//! [`super::clients`]'s business), serves each with HTTP/1.1 under deadlines, and stops with the
//! server.
//!
//! - A request's headers must arrive within `web.header_timeout_s` of the connection's start or
//!   of the previous answer's end (nginx's `client_header_timeout`), in at most
//!   [`MAX_HEAD_BYTES`] (431 beyond); its body within `web.body_timeout_s`
//!   ([`super::clients::receive`]).
//! - Nothing read or written for `web.idle_timeout_s` while no request is being answered closes
//!   the connection: an idle keep-alive, a client that reads nothing of its answer (nginx's
//!   `send_timeout`). A response being made (a slow picture) is waited for.
//! - Each connection accepted reads what it was sent before the next is accepted, so a client
//!   that sends its request with its connection is answered however many connect around it.

use super::clients::{Client, Clients, Phase};
use axum::body::Body;
use axum::Router;
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpListener;
use tokio::time::{Instant, Sleep};

/// The most bytes of a request's line and headers.
pub const MAX_HEAD_BYTES: usize = 16 * 1024;
/// Headers of one request at most.
const MAX_HEADERS: usize = 64;
/// How long connections may take to finish when the server stops.
const STOP_GRACE: Duration = Duration::from_secs(1);

/// Connections the kernel completes for the page before it accepts them (nginx: 511; std's
/// bind gives 128, which a burst of connections fills while the page accepts).
const BACKLOG: i32 = 1024;

/// A socket listening on `addr` with a backlog of [`BACKLOG`].
pub fn bind(addr: std::net::SocketAddr) -> std::io::Result<std::net::TcpListener> {
    use std::os::fd::AsRawFd;
    let listener = std::net::TcpListener::bind(addr)?;
    // SAFETY: listen again on a socket this function owns: Linux takes the new backlog.
    if unsafe { libc::listen(listener.as_raw_fd(), BACKLOG) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(listener)
}

/// What a newcomer is told when every connection is being answered.
const BUSY: &[u8] = b"HTTP/1.1 503 Service Unavailable\r\nRetry-After: 1\r\n\
Content-Type: application/json\r\nContent-Length: 70\r\nConnection: close\r\n\r\n\
{\"error\":\"every connection of the page is being answered: retry soon\"}";

/// Serves `app` on `listener` until `stop` is requested.
pub(crate) async fn serve(
    listener: TcpListener,
    app: Router,
    clients: Arc<Clients>,
    stop: crate::shutdown::Shutdown,
) {
    let mut connections = tokio::task::JoinSet::new();
    loop {
        let accepted = tokio::select! {
            accepted = listener.accept() => accepted,
            _ = stop.requested() => break,
        };
        match accepted {
            Ok((stream, peer)) => match clients.admit(peer.ip()) {
                Some(client) => {
                    let _ = stream.set_nodelay(true);
                    client.watch(std::os::fd::AsRawFd::as_raw_fd(&stream));
                    let (app, clients, stop) = (app.clone(), clients.clone(), stop.clone());
                    connections.spawn(connection(stream, client, app, clients, stop));
                }
                None => {
                    let _ = stream.try_write(BUSY);
                }
            },
            // Out of file descriptors: an idle connection makes room, else wait a little.
            Err(e) if matches!(e.raw_os_error(), Some(libc::EMFILE | libc::ENFILE)) => {
                if !clients.make_room() {
                    tokio::time::sleep(Duration::from_millis(50)).await;
                }
            }
            Err(_) => {}
        }
        while connections.try_join_next().is_some() {}
        // The connection just accepted reads its request before the next one is accepted.
        tokio::task::yield_now().await;
    }
    let _ = tokio::time::timeout(STOP_GRACE, async {
        while connections.join_next().await.is_some() {}
    })
    .await;
}

/// One connection, until it ends, is closed to make room, or the server stops.
pub(crate) async fn connection<S>(
    stream: S,
    client: Arc<Client>,
    app: Router,
    clients: Arc<Clients>,
    stop: crate::shutdown::Shutdown,
) where
    S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let limits = clients.limits();
    let io = hyper_util::rt::TokioIo::new(Connection {
        stream,
        client: client.clone(),
        idle: limits.idle_timeout,
        deadline: Box::pin(tokio::time::sleep(limits.idle_timeout)),
    });
    let for_requests = client.clone();
    let service = hyper::service::service_fn(move |mut request: hyper::Request<_>| {
        request.extensions_mut().insert(for_requests.clone());
        tower::ServiceExt::oneshot(app.clone(), request.map(Body::new))
    });
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(limits.header_timeout)
        .max_buf_size(MAX_HEAD_BYTES)
        .max_headers(MAX_HEADERS)
        .writev(false)
        // A client that closes its side after its request still gets the answer.
        .half_close(true)
        .keep_alive(true);
    let served = http.serve_connection(io, service);
    tokio::pin!(served);
    tokio::select! {
        _ = served.as_mut() => {}
        _ = client.closed() => {}
        _ = stop.requested() => {
            served.as_mut().graceful_shutdown();
            let _ = served.as_mut().await;
        }
    }
    clients.remove(&client);
}

/// A connection's stream with the idle timer (see the module doc).
struct Connection<S> {
    stream: S,
    client: Arc<Client>,
    idle: Duration,
    deadline: Pin<Box<Sleep>>,
}

impl<S> Connection<S> {
    fn touch(&mut self) {
        let at = Instant::now() + self.idle;
        self.deadline.as_mut().reset(at);
    }

    /// When the stream has nothing: an error once the connection has been idle too long with no
    /// response being made (the server then closes it), else wait (woken at the deadline).
    fn idle_check(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        if self.client.phase() == Phase::Answering {
            self.touch();
            return Poll::Pending;
        }
        match self.deadline.as_mut().poll(cx) {
            Poll::Ready(()) => Poll::Ready(Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "idle connection closed (web.idle_timeout_s)",
            ))),
            Poll::Pending => Poll::Pending,
        }
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Connection<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        match Pin::new(&mut self.stream).poll_read(cx, buf) {
            Poll::Ready(Ok(())) => {
                if buf.filled().len() > before {
                    self.client.heard();
                    self.touch();
                }
                Poll::Ready(Ok(()))
            }
            Poll::Pending => self.idle_check(cx),
            other => other,
        }
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Connection<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        match Pin::new(&mut self.stream).poll_write(cx, buf) {
            Poll::Ready(Ok(n)) => {
                if n > 0 {
                    self.touch();
                }
                Poll::Ready(Ok(n))
            }
            // A client that reads nothing of its answer is idle too.
            Poll::Pending => self.idle_check(cx).map_ok(|()| 0),
            other => other,
        }
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }
}
