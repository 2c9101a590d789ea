//! A TCP client for one live feed (Beast on readsb port 30005, AVR on port 30002).
//!
//! It connects, hands on one [`FrameBatch`] per socket read, and when the connection drops
//! it counts the partial frame, waits (capped exponential backoff, reset after a connection
//! that delivered frames) and connects again, forever, until shutdown. Every wait selects on
//! the shutdown token. The parser (and so its clock) lives across reconnects, so feed time
//! keeps running forward even when the receiver's counter restarted in between.

use super::{parser_for, Format, FrameParser, ParseStats, RawFrame};
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tokio::io::AsyncReadExt;
use tokio::net::TcpStream;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// Bytes asked of the socket per read (a parser leaves at most one line unconsumed, which
/// [`MAX_LINE_BYTES`](super::text::MAX_LINE_BYTES) keeps well below this). A read returns
/// what the socket holds, so a slow feed still gets small batches at once; a fast one is
/// read in large batches, fewer wake-ups per frame downstream (as the replay's chunks).
const READ_BYTES: usize = 256 * 1024;

/// Nominal frame rate for untimed AVR when the config gives none: a busy receiver's order of
/// magnitude. It only spaces `*hex;` frames in feed time; timed formats ignore it.
pub const DEFAULT_NOMINAL_RATE_HZ: f64 = 1000.0;

fn default_nominal_rate_hz() -> f64 {
    DEFAULT_NOMINAL_RATE_HZ
}

/// One configured TCP feed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TcpFeed {
    /// Name in logs, stats and [`FrameBatch::feed`].
    pub name: String,
    /// `host:port` to connect to.
    pub addr: String,
    /// What the server sends: `beast` or `avr` (any [`Format`] is parsed).
    pub format: Format,
    /// Pacing of untimed AVR frames (see [`parser_for`]).
    #[serde(default = "default_nominal_rate_hz")]
    pub nominal_rate_hz: f64,
    /// [`ClientTiming::idle_timeout`] of this feed, s (`feeds[].silence_timeout_s`).
    #[serde(default = "crate::config::default_silence_timeout_s")]
    pub silence_timeout_s: f64,
}

/// The frames of one socket read: one channel message per read, not per frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameBatch {
    /// The feed's [`TcpFeed::name`].
    pub feed: Arc<str>,
    pub frames: Vec<RawFrame>,
    /// When the frames were read (a paced replay: when they were due). The ingest lag and
    /// the arrival-to-publication latency are measured from here.
    pub arrived: Instant,
    /// Signalled once every aircraft has processed its messages of this batch (held by the
    /// batch and by each aircraft's share of it): how a cluster track node acknowledges a
    /// bus message only after its aircraft processed it. `None` for feeds and replays.
    pub done: Option<Arc<Completion>>,
}

/// Fires once when the last holder lets go: the router hands a clone to every aircraft that
/// gets messages of the batch, so the drop of the last clone means all of them processed
/// theirs (or were retired, or shutdown came).
#[derive(Debug)]
pub struct Completion(Option<tokio::sync::oneshot::Sender<()>>);

impl Completion {
    /// A completion and the receiver that resolves when its last clone is dropped.
    pub fn new() -> (Arc<Self>, tokio::sync::oneshot::Receiver<()>) {
        let (tx, rx) = tokio::sync::oneshot::channel();
        (Arc::new(Self(Some(tx))), rx)
    }
}

impl Drop for Completion {
    fn drop(&mut self) {
        if let Some(tx) = self.0.take() {
            // The receiver gone (the node stopping) is no one's concern.
            let _ = tx.send(());
        }
    }
}

/// Two batches are equal whatever their completion token (one is never compared).
impl PartialEq for Completion {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// Reconnection and timeout policy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClientTiming {
    /// First wait after a failed or dropped connection; doubles per failure.
    pub backoff_initial: Duration,
    /// Longest wait.
    pub backoff_max: Duration,
    /// Give up a connection attempt after this long (an unreachable host otherwise hangs
    /// for the kernel's SYN retries, minutes).
    pub connect_timeout: Duration,
    /// Drop a connection that delivers no frame for this long (`feeds[].silence_timeout_s`)
    /// and connect again: a peer that vanished without closing never ends a read, and a
    /// receiver that only sends heartbeats (readsb does on idle outputs) or garbage hears
    /// nothing. While a connected feed is silent past half of this, it is reported `silent`
    /// (and `/healthz` degraded).
    pub idle_timeout: Duration,
}

impl Default for ClientTiming {
    fn default() -> Self {
        Self {
            backoff_initial: Duration::from_millis(500),
            backoff_max: Duration::from_secs(30),
            connect_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs_f64(crate::config::DEFAULT_SILENCE_TIMEOUT_S),
        }
    }
}

/// Live counters of one feed, shared with the API (`/healthz`, stats).
#[derive(Debug)]
pub struct FeedStatus {
    name: Arc<str>,
    connected: AtomicBool,
    /// When the feed last delivered a frame, or connected: silence is measured from it.
    last_frame: Mutex<Instant>,
    /// How long a connected feed may be silent before it is reconnected.
    silence_timeout: Duration,
    connects: AtomicU64,
    disconnects: AtomicU64,
    bytes: AtomicU64,
    frames: AtomicU64,
    /// Never held across an `.await`.
    last_error: Mutex<Option<String>>,
    /// The parser's counters, copied after every read. Never held across an `.await`.
    parse: Mutex<ParseStats>,
}

/// A point-in-time copy of [`FeedStatus`].
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct FeedStatusSnapshot {
    pub name: String,
    pub connected: bool,
    /// Seconds since the feed last delivered a frame (or connected, or started trying).
    pub silent_s: f64,
    /// True while the feed is down, or connected but silent past half its
    /// `silence_timeout_s` (at the whole of it, it is reconnected).
    pub silent: bool,
    /// Successful connections so far.
    pub connects: u64,
    /// Connections that ended (closed by the peer, failed, idle, or shut down).
    pub disconnects: u64,
    /// Bytes received.
    pub bytes: u64,
    /// Frames handed on to the channel.
    pub frames: u64,
    pub last_error: Option<String>,
    pub parse: ParseStats,
}

/// A lock whose data stays valid even if a holder panicked (plain counters and a string).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl FeedStatus {
    /// A feed's status, with the default silence timeout.
    pub fn new(name: impl Into<Arc<str>>) -> Self {
        Self::with_silence_timeout(name, ClientTiming::default().idle_timeout)
    }

    /// A feed's status; `silence_timeout` as in [`ClientTiming::idle_timeout`].
    pub fn with_silence_timeout(name: impl Into<Arc<str>>, silence_timeout: Duration) -> Self {
        Self {
            name: name.into(),
            connected: AtomicBool::new(false),
            last_frame: Mutex::new(Instant::now()),
            silence_timeout,
            connects: AtomicU64::new(0),
            disconnects: AtomicU64::new(0),
            bytes: AtomicU64::new(0),
            frames: AtomicU64::new(0),
            last_error: Mutex::new(None),
            parse: Mutex::new(ParseStats::default()),
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn is_connected(&self) -> bool {
        self.connected.load(Ordering::Relaxed)
    }

    /// Time since the last frame (or connection).
    pub fn silent_for(&self) -> Duration {
        lock(&self.last_frame).elapsed()
    }

    /// Down, or connected and silent past half the silence timeout: not delivering what
    /// a working receiver delivers.
    pub fn is_silent(&self) -> bool {
        !self.is_connected() || self.silent_for() > self.silence_timeout / 2
    }

    fn heard(&self) {
        *lock(&self.last_frame) = Instant::now();
    }

    pub fn snapshot(&self) -> FeedStatusSnapshot {
        FeedStatusSnapshot {
            name: self.name.to_string(),
            connected: self.connected.load(Ordering::Relaxed),
            silent_s: self.silent_for().as_secs_f64(),
            silent: self.is_silent(),
            connects: self.connects.load(Ordering::Relaxed),
            disconnects: self.disconnects.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
            frames: self.frames.load(Ordering::Relaxed),
            last_error: lock(&self.last_error).clone(),
            parse: lock(&self.parse).clone(),
        }
    }

    fn set_error(&self, text: String) {
        *lock(&self.last_error) = Some(text);
    }

    fn set_parse(&self, stats: &ParseStats) {
        lock(&self.parse).clone_from(stats);
    }
}

/// Runs the client for `cfg` with the default [`ClientTiming`] but its own silence
/// timeout, until `shutdown` is cancelled or the receiving end of `tx` is dropped.
pub async fn run_client(
    cfg: TcpFeed,
    tx: mpsc::Sender<FrameBatch>,
    status: Arc<FeedStatus>,
    shutdown: CancellationToken,
) {
    let timing = ClientTiming {
        idle_timeout: cfg.silence_timeout(),
        ..ClientTiming::default()
    };
    run_client_with(cfg, timing, tx, status, shutdown).await;
}

impl TcpFeed {
    /// `silence_timeout_s` as a duration (the default for a value a duration cannot hold;
    /// the config refuses those at load).
    pub fn silence_timeout(&self) -> Duration {
        Duration::try_from_secs_f64(self.silence_timeout_s)
            .unwrap_or(ClientTiming::default().idle_timeout)
    }
}

/// How a connection ended.
enum End {
    /// Closed by the peer, failed or idle: reconnect.
    Dropped,
    /// Shutdown, or nobody listens to `tx` any more: stop.
    Stop,
}

/// [`run_client`] with an explicit reconnection policy.
pub async fn run_client_with(
    cfg: TcpFeed,
    timing: ClientTiming,
    tx: mpsc::Sender<FrameBatch>,
    status: Arc<FeedStatus>,
    shutdown: CancellationToken,
) {
    let feed: Arc<str> = Arc::from(cfg.name.as_str());
    let mut parser = parser_for(cfg.format, cfg.nominal_rate_hz);
    let mut backoff = timing.backoff_initial;
    // Connection attempts failed in a row.
    let mut failures: u64 = 0;
    while !tx.is_closed() {
        let attempt = tokio::time::timeout(timing.connect_timeout, TcpStream::connect(&cfg.addr));
        let connected = tokio::select! {
            _ = shutdown.cancelled() => return,
            r = attempt => r,
        };
        match connected {
            Ok(Ok(stream)) => {
                status.connects.fetch_add(1, Ordering::Relaxed);
                status.heard();
                status.connected.store(true, Ordering::Relaxed);
                failures = 0;
                tracing::info!(feed = %feed, addr = %cfg.addr, "feed connected");
                let mut conn = Connection {
                    stream,
                    parser: parser.as_mut(),
                    feed: &feed,
                    tx: &tx,
                    status: &status,
                    timing: &timing,
                    delivered: false,
                    last_frame: Instant::now(),
                };
                let end = conn.run(&shutdown).await;
                let delivered = conn.delivered;
                status.connected.store(false, Ordering::Relaxed);
                status.disconnects.fetch_add(1, Ordering::Relaxed);
                if matches!(end, End::Stop) {
                    return;
                }
                if delivered {
                    backoff = timing.backoff_initial;
                }
            }
            Ok(Err(e)) => {
                failures += 1;
                let why = format!("connect to {}: {e}", cfg.addr);
                log_failure(&feed, &why, failures, backoff);
                status.set_error(why);
            }
            Err(_) => {
                failures += 1;
                let why = format!(
                    "connect to {}: no answer within {:?}",
                    cfg.addr, timing.connect_timeout
                );
                log_failure(&feed, &why, failures, backoff);
                status.set_error(why);
            }
        }
        tokio::select! {
            _ = shutdown.cancelled() => return,
            _ = tokio::time::sleep(backoff) => {}
        }
        backoff = backoff.saturating_mul(2).min(timing.backoff_max);
    }
}

/// A failed connection attempt, at warn (a feed that never connects is the first thing an
/// operator must see), as often as the attempts themselves: the capped exponential backoff
/// spaces them (at most one every `backoff_max`, 30 s, once it has grown).
fn log_failure(feed: &str, why: &str, failures: u64, retry_in: Duration) {
    tracing::warn!(
        feed = %feed,
        failures,
        retry_in_s = retry_in.as_secs_f64(),
        "feed connection failed: {why}"
    );
}

/// One connection's read loop.
struct Connection<'a> {
    stream: TcpStream,
    parser: &'a mut dyn FrameParser,
    feed: &'a Arc<str>,
    tx: &'a mpsc::Sender<FrameBatch>,
    status: &'a FeedStatus,
    timing: &'a ClientTiming,
    /// Some frames reached the channel on this connection.
    delivered: bool,
    /// When this connection last delivered a frame (or opened).
    last_frame: Instant,
}

impl Connection<'_> {
    async fn run(&mut self, shutdown: &CancellationToken) -> End {
        let mut buf = vec![0u8; READ_BYTES];
        let mut filled = 0;
        loop {
            if filled == buf.len() {
                // Cannot happen with our parsers (they leave at most one frame or line), but
                // a full buffer must never stall the loop: count it and start over.
                self.parser.finish(&buf);
                filled = 0;
            }
            // Silence is counted from the last frame, not the last byte: heartbeats and
            // garbage do not keep a feed alive.
            let deadline = self
                .last_frame
                .checked_add(self.timing.idle_timeout)
                .unwrap_or_else(|| Instant::now() + Duration::from_secs(86_400));
            let read = tokio::select! {
                _ = shutdown.cancelled() => None,
                r = tokio::time::timeout_at(
                    deadline.into(),
                    self.stream.read(buf.get_mut(filled..).unwrap_or(&mut [])),
                ) => Some(r),
            };
            let tail = buf.get(..filled).unwrap_or(&[]);
            let why = match read {
                None => {
                    // Stopping: the partial frame is counted, not parsed.
                    self.parser.finish(tail);
                    self.status.set_parse(self.parser.stats());
                    return End::Stop;
                }
                Some(Ok(Ok(0))) => "closed by peer".to_string(),
                Some(Ok(Err(e))) => format!("read: {e}"),
                Some(Err(_)) => format!(
                    "no frame for {:?} (feeds[].silence_timeout_s)",
                    self.timing.idle_timeout
                ),
                Some(Ok(Ok(n))) => {
                    self.status.bytes.fetch_add(n as u64, Ordering::Relaxed);
                    filled += n;
                    let mut frames = Vec::new();
                    let data = buf.get(..filled).unwrap_or(&[]);
                    let used = self.parser.parse(data, &mut frames).min(filled);
                    buf.copy_within(used..filled, 0);
                    filled -= used;
                    self.status.set_parse(self.parser.stats());
                    if !self.send(frames, shutdown).await {
                        return End::Stop;
                    }
                    continue;
                }
            };
            tracing::warn!(feed = %self.feed, reason = %why, "feed disconnected");
            self.status.set_error(why);
            // The tail is counted as a truncated frame (or, for a complete final text line
            // without newline, parsed and sent).
            let mut frames = Vec::new();
            self.parser.finish_into(tail, &mut frames);
            self.status.set_parse(self.parser.stats());
            return if self.send(frames, shutdown).await {
                End::Dropped
            } else {
                End::Stop
            };
        }
    }

    fn batch(&self, frames: Vec<RawFrame>) -> FrameBatch {
        FrameBatch {
            feed: Arc::clone(self.feed),
            frames,
            arrived: Instant::now(),
            done: None,
        }
    }

    /// Queues one read's frames. Waiting here is the feed's backpressure: while the channel
    /// is full this connection is not read, the kernel buffers, and TCP flow control slows
    /// the sender, which is lossless up to the sender's own buffer. Returns false when the
    /// channel is closed or shutdown came first.
    async fn send(&mut self, frames: Vec<RawFrame>, shutdown: &CancellationToken) -> bool {
        if frames.is_empty() {
            return true;
        }
        let n = frames.len() as u64;
        // Heard now, whatever the wait for room below (backpressure is not silence).
        self.status.heard();
        self.last_frame = Instant::now();
        let batch = self.batch(frames);
        let sent = tokio::select! {
            _ = shutdown.cancelled() => return false,
            r = self.tx.send(batch) => r.is_ok(),
        };
        if sent {
            self.status.frames.fetch_add(n, Ordering::Relaxed);
            self.delivered = true;
        }
        sent
    }
}
