//! The HTTP server: hyper's HTTP/1 connections around the API's router, bounded in every
//! dimension a client controls, on a runtime of its own.
//!
//! - **Its own threads, in two lanes.** The server runs on threads apart from the
//!   pipeline's, so however many clients it serves, the aircraft tasks never wait behind a
//!   response: ingest keeps its pace. One thread (the request lane, at
//!   `server.request_nice`) accepts connections, reads requests and answers them; the
//!   sending of large bodies and the building of the track list happen on the bulk lane
//!   (`server.threads` threads at `server.nice`, lowest priority by default), so they yield
//!   the CPU to ingest, and a small request never queues behind them (see [`super::fair`]).
//! - **Time.** A request head must arrive within `server.header_read_timeout_s` (hyper's
//!   timer, which also runs while a kept-alive connection waits for its next request: the
//!   idle timeout); a handler must answer within `server.request_timeout_s` (tower-http); a
//!   response write that makes no progress for `server.write_timeout_s` cuts the connection
//!   (tokio-io-timeout), so a client that never reads holds nothing for long.
//! - **Memory.** Request heads are capped at `server.max_header_bytes`; hyper answers
//!   pipelined requests one at a time, each after the previous response is buffered, so a
//!   non-reading client holds at most one response, and the big one (`/api/v1/tracks`) is a
//!   body shared by every reader. `server.max_requests_per_connection` closes a connection
//!   after that many requests.
//! - **Count.** At most `server.max_connections` connections are served; one more gets a
//!   503 `{"error"}` and is closed. Accept errors (out of file descriptors) are counted,
//!   logged at most every 10 s, and retried after a pause, never in a busy loop.
//! - **Shutdown.** On shutdown the listener closes, open connections finish the request in
//!   hand (idle ones close at once), and after `server.shutdown_grace_s` the rest are cut.
//! - **Errors.** hyper's own answers to unparsable requests (400, 414, 431) have no body;
//!   [`ErrorBodies`] gives them the API's `{"error"}` JSON like every other error.

use super::app;
use crate::config::ServerConfig;
use crate::daemon::Shared;
use axum::http::{header, HeaderValue, Request};
use hyper::body::Incoming;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::server::graceful::GracefulShutdown;
use hyper_util::service::TowerToHyperService;
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::{Duration, Instant};
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tokio_io_timeout::TimeoutStream;
use tokio_util::sync::CancellationToken;
use tower::ServiceExt;

/// Pause after a failed `accept` (typically EMFILE: out of file descriptors) before the
/// next: the condition lasts until connections close, and retrying at once would spin.
const ACCEPT_ERROR_PAUSE: Duration = Duration::from_millis(100);

/// At most one accept-error log line per this long.
const ACCEPT_ERROR_LOG_EVERY: Duration = Duration::from_secs(10);

/// Time to write the 503 refusal to a connection over the cap before it is dropped.
const REFUSAL_WRITE_TIMEOUT: Duration = Duration::from_secs(1);

/// Refusals being written at once; past this, connections over the cap are closed without
/// an answer (a flood must not turn the refusals themselves into a resource).
const MAX_REFUSALS_IN_FLIGHT: usize = 64;

/// The server's limits, from `[server]` (validated at load).
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    pub max_connections: usize,
    pub header_read_timeout: Duration,
    pub write_timeout: Duration,
    pub max_requests_per_connection: u64,
    pub max_header_bytes: usize,
    pub shutdown_grace: Duration,
    pub threads: usize,
    pub nice: i32,
    pub request_nice: i32,
}

impl Limits {
    /// The limits of a `[server]` section (a value a duration cannot hold, which validation
    /// refuses, falls back to a bound rather than panicking).
    pub fn from_config(c: &ServerConfig) -> Self {
        let secs = |s: f64, fallback: u64| {
            Duration::try_from_secs_f64(s).unwrap_or(Duration::from_secs(fallback))
        };
        Self {
            max_connections: c.max_connections.clamp(1, Semaphore::MAX_PERMITS),
            header_read_timeout: secs(c.header_read_timeout_s, 10),
            write_timeout: secs(c.write_timeout_s, 20),
            max_requests_per_connection: c.max_requests_per_connection.max(1),
            max_header_bytes: c.max_header_bytes.max(MIN_HEAD_BYTES),
            shutdown_grace: secs(c.shutdown_grace_s, 5),
            threads: c.threads.clamp(1, 64),
            nice: c.nice.clamp(0, 19),
            request_nice: c.request_nice.clamp(0, 19),
        }
    }
}

/// hyper's smallest read buffer; a request head limit below it is raised to it.
const MIN_HEAD_BYTES: usize = 8192;

/// A running server: its thread and the result it ends with.
pub struct ServerHandle {
    done: tokio::sync::oneshot::Receiver<io::Result<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ServerHandle {
    /// Waits until the server has stopped (after `shutdown` and its grace period).
    pub async fn stopped(mut self) -> io::Result<()> {
        let result = (&mut self.done)
            .await
            .unwrap_or_else(|_| Err(io::Error::other("the HTTP server thread panicked")));
        if let Some(t) = self.thread.take() {
            // The runtime has returned: the thread is ending.
            let _ = tokio::task::spawn_blocking(move || t.join()).await;
        }
        result
    }
}

/// Starts the API on `listener`, on runtimes of its own (the request lane's one thread and
/// the bulk lane's `server.threads`), until `shutdown` is cancelled.
pub fn spawn(
    listener: TcpListener,
    shared: Shared,
    shutdown: CancellationToken,
) -> io::Result<ServerHandle> {
    let limits = Limits::from_config(&shared.config.server);
    // The listener moves to the server's runtime (its registration belongs to the caller's).
    let listener = listener.into_std()?;
    let bulk = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(limits.threads)
        .thread_name("adsb-http-bulk")
        .on_thread_start(move || lower_priority(limits.nice))
        .enable_all()
        .build()?;
    let bulk_lane = bulk.handle().clone();
    let requests = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("adsb-http")
        .on_thread_start(move || {
            lower_priority(limits.request_nice);
            super::fair::set_bulk_lane(bulk_lane.clone());
        })
        .enable_all()
        .build()?;
    let (tx, done) = tokio::sync::oneshot::channel();
    let thread = std::thread::Builder::new()
        .name("adsb-http-main".into())
        .spawn(move || {
            lower_priority(limits.request_nice);
            let bulk_lane = bulk.handle().clone();
            let result = requests.block_on(async move {
                let listener = TcpListener::from_std(listener)?;
                serve(listener, shared, limits, shutdown, bulk_lane).await;
                Ok(())
            });
            // Connections cut at the deadline may leave tasks behind: don't wait for them.
            requests.shutdown_background();
            bulk.shutdown_background();
            let _ = tx.send(result);
        })?;
    Ok(ServerHandle {
        done,
        thread: Some(thread),
    })
}

/// Adds `nice` to the calling thread's niceness (Linux: setpriority on a thread id affects
/// that thread only). A failure (a container that forbids it) is logged and harmless.
fn lower_priority(nice: i32) {
    if nice == 0 {
        return;
    }
    #[cfg(target_os = "linux")]
    {
        // SAFETY: gettid has no preconditions; getpriority/setpriority read and set the
        // scheduling priority of the thread `tid` (ours) and touch no memory of ours.
        let ok = unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            let current = libc::getpriority(libc::PRIO_PROCESS, tid);
            libc::setpriority(libc::PRIO_PROCESS, tid, (current + nice).min(19)) == 0
        };
        if !ok {
            tracing::debug!(
                error = %io::Error::last_os_error(),
                "could not lower the HTTP threads' priority (server.nice, server.request_nice)"
            );
        }
    }
}

/// The accept loop, then the graceful shutdown with its deadline. Connections are served on
/// the current runtime (the request lane) and send their large bodies on `bulk`.
pub async fn serve(
    listener: TcpListener,
    shared: Shared,
    limits: Limits,
    stop: CancellationToken,
    bulk: tokio::runtime::Handle,
) {
    let router = app(shared.clone());
    let stats = shared.stats.http.clone();
    let permits = Arc::new(Semaphore::new(limits.max_connections));
    let refusals = Arc::new(Semaphore::new(MAX_REFUSALS_IN_FLIGHT));
    let graceful = GracefulShutdown::new();
    let mut connections = tokio::task::JoinSet::new();
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout)
        .max_buf_size(limits.max_header_bytes.max(MIN_HEAD_BYTES))
        .max_header_size(limits.max_header_bytes);
    let mut last_accept_log: Option<Instant> = None;
    loop {
        let accepted = tokio::select! {
            _ = stop.cancelled() => break,
            // Reap finished connection tasks as they end (the set never grows past the cap).
            Some(_) = connections.join_next(), if !connections.is_empty() => continue,
            a = listener.accept() => a,
        };
        let (stream, _peer) = match accepted {
            Ok(a) => a,
            Err(e) => {
                stats.accept_errors.inc();
                if last_accept_log.is_none_or(|t| t.elapsed() >= ACCEPT_ERROR_LOG_EVERY) {
                    last_accept_log = Some(Instant::now());
                    tracing::warn!(
                        error = %e,
                        open = stats.connections_open.get(),
                        "HTTP accept failed; pausing accepts (server.max_connections = {})",
                        limits.max_connections
                    );
                }
                tokio::select! {
                    _ = stop.cancelled() => break,
                    _ = tokio::time::sleep(ACCEPT_ERROR_PAUSE) => {}
                }
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        let Ok(permit) = permits.clone().try_acquire_owned() else {
            stats.connections_refused.inc();
            if let Ok(slot) = refusals.clone().try_acquire_owned() {
                tokio::spawn(async move {
                    refuse(stream, limits.max_connections).await;
                    drop(slot);
                });
            }
            continue;
        };
        stats.connections_open.inc();
        let io = guarded(stream, &limits);
        let service = per_connection(router.clone(), limits.max_requests_per_connection);
        let conn = builder.serve_connection(io, TowerToHyperService::new(service));
        let conn: super::fair::Connection<_> = Box::pin(graceful.watch(conn));
        let stats = stats.clone();
        let bulk = bulk.clone();
        connections.spawn(async move {
            // Large bodies go out on the bulk lane, a bounded share per poll: see `fair`.
            if let Some(Err(e)) = super::fair::serve_connection(conn, &bulk).await {
                if is_timeout(&e) {
                    stats.connections_timed_out.inc();
                }
                tracing::debug!(error = %e, "HTTP connection ended with an error");
            }
            stats.connections_open.dec();
            drop(permit);
        });
    }
    drop(listener);
    // Idle connections close at once; those with a request in hand get the grace period.
    tokio::select! {
        _ = graceful.shutdown() => {}
        _ = tokio::time::sleep(limits.shutdown_grace) => {
            tracing::info!(
                open = connections.len(),
                "HTTP connections still open after server.shutdown_grace_s: cut"
            );
        }
    }
    connections.abort_all();
    while connections.join_next().await.is_some() {}
}

/// A hyper error that is a timeout: the header read timer, or the socket's write timeout.
fn is_timeout(e: &hyper::Error) -> bool {
    if e.is_timeout() {
        return true;
    }
    let mut source = std::error::Error::source(e);
    while let Some(s) = source {
        if let Some(io) = s.downcast_ref::<io::Error>() {
            return io.kind() == io::ErrorKind::TimedOut;
        }
        source = s.source();
    }
    false
}

/// The 503 answer to a connection over `server.max_connections`, then close.
async fn refuse(mut stream: TcpStream, max_connections: usize) {
    let body = format!(
        "{{\"error\":\"too many connections (server.max_connections = {max_connections})\"}}"
    );
    let response = format!(
        "HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n\
         content-length: {}\r\nretry-after: 1\r\nconnection: close\r\n\r\n{body}",
        body.len()
    );
    let _ = tokio::time::timeout(REFUSAL_WRITE_TIMEOUT, async {
        stream.write_all(response.as_bytes()).await?;
        stream.shutdown().await
    })
    .await;
}

/// The router for one connection: after `max_requests` requests, the response says
/// `connection: close` and hyper closes the connection once it is written.
fn per_connection(
    router: axum::Router,
    max_requests: u64,
) -> impl tower::Service<
    Request<Incoming>,
    Response = axum::response::Response,
    Error = std::convert::Infallible,
    Future = impl Send,
> + Clone {
    let served = Arc::new(AtomicU64::new(0));
    tower::service_fn(move |req: Request<Incoming>| {
        let n = served.fetch_add(1, Ordering::Relaxed) + 1;
        let router = router.clone();
        async move {
            let mut response = router.oneshot(req.map(axum::body::Body::new)).await?;
            if n >= max_requests {
                response
                    .headers_mut()
                    .insert(header::CONNECTION, HeaderValue::from_static("close"));
            }
            Ok(response)
        }
    })
}

/// A connection's socket with its write timeout and [`ErrorBodies`].
fn guarded(stream: TcpStream, limits: &Limits) -> TokioIo<ErrorBodies> {
    let mut timed = TimeoutStream::new(stream);
    timed.set_write_timeout(Some(limits.write_timeout));
    TokioIo::new(ErrorBodies::new(Box::pin(timed), limits.max_header_bytes))
}

/// The socket seen by hyper: passes everything through, except hyper's own bodiless error
/// responses (400, 414, 431 for requests it cannot parse), which it rewrites into the API's
/// `{"error"}` JSON.
///
/// hyper writes such a response as one head with `content-length: 0` and then closes; the
/// API's own error responses always have a JSON body, so a bodiless 400/414/431 can only be
/// hyper's. The replacement is written in full before anything else (it is small); hyper is
/// told its own bytes were written.
///
/// It also watches the request bytes to tell a long request line (414) from long headers
/// (431): hyper reports both as a too-large head once the head limit is reached.
pub struct ErrorBodies {
    inner: Pin<Box<TimeoutStream<TcpStream>>>,
    /// A rewritten response not yet fully written.
    pending: Vec<u8>,
    /// Bytes of it already written.
    pending_at: usize,
    /// Scanner state of the request bytes.
    scan: HeadScan,
    /// `server.max_header_bytes`.
    head_limit: usize,
}

/// Where the request bytes are: inside a request line (and how long it is so far), or in
/// the headers; the last four bytes find the CR LF CR LF that ends a head.
#[derive(Clone, Copy, Debug, Default)]
struct HeadScan {
    in_headers: bool,
    request_line_bytes: usize,
    last4: u32,
}

impl HeadScan {
    const END_OF_HEAD: u32 = u32::from_be_bytes(*b"\r\n\r\n");

    fn feed(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.last4 = (self.last4 << 8) | u32::from(b);
            if self.last4 == Self::END_OF_HEAD {
                // The next byte starts a request line.
                *self = Self::default();
            } else if !self.in_headers {
                if b == b'\n' {
                    self.in_headers = true;
                } else {
                    self.request_line_bytes += 1;
                }
            }
        }
    }

    /// For a head hyper found too large (over `limit` bytes): is it the request line that
    /// is too long (unterminated, or over half the limit) rather than the headers?
    fn uri_too_long(&self, limit: usize) -> bool {
        !self.in_headers || self.request_line_bytes > limit / 2
    }
}

impl ErrorBodies {
    fn new(inner: Pin<Box<TimeoutStream<TcpStream>>>, head_limit: usize) -> Self {
        Self {
            inner,
            pending: Vec::new(),
            pending_at: 0,
            scan: HeadScan::default(),
            head_limit,
        }
    }

    /// Writes what is left of a rewritten response; Ready(Ok) once it is all out.
    fn poll_pending(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        while self.pending_at < self.pending.len() {
            let rest = self.pending.get(self.pending_at..).unwrap_or(&[]);
            match self.inner.as_mut().poll_write(cx, rest) {
                Poll::Ready(Ok(0)) => return Poll::Ready(Err(io::ErrorKind::WriteZero.into())),
                Poll::Ready(Ok(n)) => self.pending_at += n,
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Pending => return Poll::Pending,
            }
        }
        self.pending.clear();
        self.pending_at = 0;
        Poll::Ready(Ok(()))
    }

    /// The JSON response replacing hyper's bodiless `head`, if it is one.
    fn rewrite(&self, head: &[u8]) -> Option<Vec<u8>> {
        let status = hyper_error_status(head)?;
        let (status, reason, error) = match status {
            431 | 414 if self.scan.uri_too_long(self.head_limit) => {
                (414, "URI Too Long", "URI too long".to_string())
            }
            431 => (
                431,
                "Request Header Fields Too Large",
                "request header fields too large".to_string(),
            ),
            414 => (414, "URI Too Long", "URI too long".to_string()),
            _ => (400, "Bad Request", "malformed HTTP request".to_string()),
        };
        let body = serde_json::to_vec(&super::ErrorBody { error }).ok()?;
        let mut out = format!(
            "HTTP/1.1 {status} {reason}\r\ncontent-type: application/json\r\n\
             content-length: {}\r\nconnection: close\r\n\r\n",
            body.len()
        )
        .into_bytes();
        out.extend_from_slice(&body);
        Some(out)
    }
}

/// The status of a bodiless 400/414/431 response head (what hyper answers to a request it
/// cannot parse), or None for anything else.
fn hyper_error_status(buf: &[u8]) -> Option<u16> {
    const MAX_HEAD: usize = 512;
    if buf.len() > MAX_HEAD || !buf.ends_with(b"\r\n\r\n") {
        return None;
    }
    let status = match buf.get(..13)? {
        b"HTTP/1.1 400 " => 400,
        b"HTTP/1.1 414 " => 414,
        b"HTTP/1.1 431 " => 431,
        _ => return None,
    };
    let bodiless = buf
        .windows(b"content-length: 0\r\n".len())
        .any(|w| w.eq_ignore_ascii_case(b"content-length: 0\r\n"));
    bodiless.then_some(status)
}

impl AsyncRead for ErrorBodies {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let r = this.inner.as_mut().poll_read(cx, buf);
        if let Poll::Ready(Ok(())) = r {
            this.scan.feed(buf.filled().get(before..).unwrap_or(&[]));
        }
        r
    }
}

impl AsyncWrite for ErrorBodies {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        match this.poll_pending(cx) {
            Poll::Ready(Ok(())) => {}
            Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
            Poll::Pending => return Poll::Pending,
        }
        if let Some(replacement) = this.rewrite(buf) {
            this.pending = replacement;
            // hyper's bytes are accounted for; ours go out now or on the next poll.
            if let Poll::Ready(Err(e)) = this.poll_pending(cx) {
                return Poll::Ready(Err(e));
            }
            return Poll::Ready(Ok(buf.len()));
        }
        this.inner.as_mut().poll_write(cx, buf)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        // A head on its own (hyper's error responses are one) goes through the check above.
        if let Some(first) = bufs.iter().find(|b| !b.is_empty()) {
            if hyper_error_status(first).is_some() {
                return Pin::new(this).poll_write(cx, first);
            }
        }
        match this.poll_pending(cx) {
            Poll::Ready(Ok(())) => this.inner.as_mut().poll_write_vectored(cx, bufs),
            Poll::Ready(Err(e)) => Poll::Ready(Err(e)),
            Poll::Pending => Poll::Pending,
        }
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        match this.poll_pending(cx) {
            Poll::Ready(Ok(())) => this.inner.as_mut().poll_flush(cx),
            other => other,
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        match this.poll_pending(cx) {
            Poll::Ready(Ok(())) => this.inner.as_mut().poll_shutdown(cx),
            other => other,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hyper_error_heads_are_recognised_and_nothing_else() {
        let h =
            b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-length: 0\r\ndate: x\r\n\r\n";
        assert_eq!(hyper_error_status(h), Some(431));
        let h = b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n";
        assert_eq!(hyper_error_status(h), Some(400));
        // The API's own 400s carry a body.
        let h = b"HTTP/1.1 400 Bad Request\r\ncontent-type: application/json\r\ncontent-length: 31\r\n\r\n";
        assert_eq!(hyper_error_status(h), None);
        let h = b"HTTP/1.1 200 OK\r\ncontent-length: 0\r\n\r\n";
        assert_eq!(hyper_error_status(h), None);
        // Not a whole head.
        assert_eq!(hyper_error_status(b"HTTP/1.1 431 Request"), None);
    }

    #[test]
    fn head_scan_tells_a_long_request_line_from_long_headers() {
        let mut s = HeadScan::default();
        s.feed(b"GET /");
        s.feed(&[b'a'; 9000]);
        assert!(s.uri_too_long(16384));
        let mut s = HeadScan::default();
        s.feed(b"GET / HTTP/1.1\r\nHost: x\r\nX-Big: ");
        s.feed(&[b'a'; 9000]);
        assert!(!s.uri_too_long(16384));
        // A whole request resets the scan; the next one starts in its request line.
        let mut s = HeadScan::default();
        s.feed(b"GET / HTTP/1.1\r\nHost: x\r\n\r\nGET /");
        assert!(!s.in_headers);
        assert_eq!(s.request_line_bytes, 5);
    }
}
