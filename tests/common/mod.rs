//! Helpers shared by the integration tests: a minimal HTTP/1.1 client (so the tests talk to
//! the daemon over a real socket, as a user would) and a daemon started on port 0.
#![allow(dead_code)]

use adsb_tracker::app::{run, RunOptions};
use adsb_tracker::config::Config;
use adsb_tracker::daemon::source::{Replay, ReplayData};
use adsb_tracker::daemon::{RunSummary, Source};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

/// Path of a fixture file.
pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// GET `path`; returns the status code and the body.
pub async fn get(addr: SocketAddr, path: &str) -> (u16, String) {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    let req = format!("GET {path} HTTP/1.1\r\nHost: test\r\nConnection: close\r\n\r\n");
    s.write_all(req.as_bytes()).await.unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).await.unwrap();
    let text = String::from_utf8(buf).unwrap();
    let (head, body) = text.split_once("\r\n\r\n").unwrap();
    let status: u16 = head.split(' ').nth(1).unwrap().parse().unwrap();
    (status, body.to_string())
}

/// GET and parse JSON.
pub async fn get_json(addr: SocketAddr, path: &str) -> (u16, serde_json::Value) {
    let (code, body) = get(addr, path).await;
    let v = serde_json::from_str(&body).unwrap_or_else(|e| panic!("{path}: {e}: {body}"));
    (code, v)
}

/// A daemon running in the background of a test.
pub struct TestDaemon {
    pub addr: SocketAddr,
    pub shutdown: CancellationToken,
    pub handle: JoinHandle<RunSummary>,
}

impl TestDaemon {
    /// Starts the daemon on `source`, serving on 127.0.0.1:0.
    pub async fn start(config: Config, source: Source, tracks_out: Option<PathBuf>) -> Self {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let shutdown = CancellationToken::new();
        let opts = RunOptions {
            source,
            listener: Some(listener),
            tracks_out,
            exit_at_end: false,
        };
        let token = shutdown.clone();
        let handle = tokio::spawn(async move { run(config, opts, token).await.unwrap() });
        Self {
            addr,
            shutdown,
            handle,
        }
    }

    /// Replays a fixture as fast as possible, once.
    pub async fn replay(name: &str, config: Config) -> Self {
        Self::replay_file(fixture(name), config).await
    }

    /// Replays a file as fast as possible, once.
    pub async fn replay_file(path: PathBuf, config: Config) -> Self {
        let source = Source::Replay(Replay {
            data: ReplayData::File(path),
            format: None,
            speed: 0.0,
            loop_: false,
            nominal_rate_hz: config.decode.nominal_rate_hz,
            fit_untimed_clock: config.decode.fit_untimed_clock,
            loop_gap_s: 0.0,
            progress: false,
        });
        Self::start(config, source, None).await
    }

    /// Polls the stats until the replay is finished and every aircraft task has drained.
    pub async fn wait_replay(&self) -> serde_json::Value {
        let deadline = tokio::time::Instant::now() + Duration::from_secs(120);
        loop {
            let (_, s) = get_json(self.addr, "/api/v1/stats").await;
            if s["replay_finished"].as_bool() == Some(true) {
                return s;
            }
            assert!(
                tokio::time::Instant::now() < deadline,
                "timed out waiting for the replay to finish: {s}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// Shuts down and waits for the daemon to finish.
    pub async fn stop(self) -> RunSummary {
        self.shutdown.cancel();
        tokio::time::timeout(Duration::from_secs(10), self.handle)
            .await
            .expect("daemon did not shut down within 10 s")
            .unwrap()
    }
}

/// One server-sent event: its name and its data (one line of JSON here).
#[derive(Clone, Debug)]
pub struct SseEvent {
    pub name: String,
    pub data: String,
    /// When it was read.
    pub at: tokio::time::Instant,
}

impl SseEvent {
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_str(&self.data).unwrap_or_else(|e| panic!("{e}: {}", self.data))
    }
}

/// A server-sent-events client over a raw socket: the response head, then the chunked body
/// decoded and cut into events as a browser's EventSource does.
pub struct SseClient {
    stream: tokio::net::TcpStream,
    /// Bytes read and not yet decoded from the chunked encoding.
    raw: Vec<u8>,
    /// Decoded body not yet cut into events.
    body: Vec<u8>,
    /// The response head.
    pub head: String,
    pub status: u16,
    ended: bool,
}

impl SseClient {
    /// Sends the request and reads the response head.
    pub async fn connect(addr: SocketAddr, path: &str) -> Self {
        let mut stream = tokio::net::TcpStream::connect(addr).await.unwrap();
        let req = format!("GET {path} HTTP/1.1\r\nHost: test\r\nAccept: text/event-stream\r\n\r\n");
        stream.write_all(req.as_bytes()).await.unwrap();
        let mut raw = Vec::new();
        let head_end = loop {
            if let Some(i) = raw.windows(4).position(|w| w == b"\r\n\r\n") {
                break i;
            }
            let mut buf = [0u8; 4096];
            let n = tokio::time::timeout(Duration::from_secs(10), stream.read(&mut buf))
                .await
                .expect("no response head within 10 s")
                .unwrap();
            assert!(n > 0, "connection closed before the head");
            raw.extend_from_slice(&buf[..n]);
        };
        let head = String::from_utf8_lossy(&raw[..head_end]).to_string();
        let status = head.split(' ').nth(1).unwrap().parse().unwrap();
        raw.drain(..head_end + 4);
        Self {
            stream,
            raw,
            body: Vec::new(),
            head,
            status,
            ended: false,
        }
    }

    /// The body of a response that is not a stream (an error, with a content-length).
    pub async fn read_to_end(mut self) -> String {
        let length = self.head.lines().find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.eq_ignore_ascii_case("content-length")
                .then(|| v.trim().parse::<usize>().ok())?
        });
        if let Some(n) = length {
            while self.raw.len() < n {
                let mut buf = [0u8; 4096];
                let got = tokio::time::timeout(Duration::from_secs(5), self.stream.read(&mut buf))
                    .await
                    .expect("body within 5 s")
                    .unwrap();
                assert!(got > 0, "closed before the body's end");
                self.raw.extend_from_slice(&buf[..got]);
            }
            return String::from_utf8_lossy(&self.raw[..n]).to_string();
        }
        let _ = tokio::time::timeout(Duration::from_secs(5), async {
            while !self.ended {
                self.read_more().await;
            }
        })
        .await;
        String::from_utf8_lossy(&self.body).to_string()
    }

    /// Decodes what the chunked encoding holds so far into `body`.
    fn decode(&mut self) {
        loop {
            let Some(eol) = self.raw.windows(2).position(|w| w == b"\r\n") else {
                return;
            };
            let size_text = String::from_utf8_lossy(&self.raw[..eol]).to_string();
            let size = usize::from_str_radix(size_text.trim(), 16)
                .unwrap_or_else(|e| panic!("bad chunk size {size_text:?}: {e}"));
            if self.raw.len() < eol + 2 + size + 2 {
                return;
            }
            if size == 0 {
                self.ended = true;
                self.raw.clear();
                return;
            }
            self.body
                .extend_from_slice(&self.raw[eol + 2..eol + 2 + size]);
            self.raw.drain(..eol + 2 + size + 2);
        }
    }

    async fn read_more(&mut self) {
        let mut buf = [0u8; 65536];
        let n = self.stream.read(&mut buf).await.unwrap_or(0);
        if n == 0 {
            self.ended = true;
        }
        self.raw.extend_from_slice(&buf[..n]);
        self.decode();
    }

    /// The next event (comments and `retry:` lines skipped), or None when the stream ends or
    /// nothing comes within `within`.
    pub async fn next_event(&mut self, within: Duration) -> Option<SseEvent> {
        let deadline = tokio::time::Instant::now() + within;
        loop {
            while let Some(end) = self.body.windows(2).position(|w| w == b"\n\n") {
                let block = String::from_utf8(self.body[..end].to_vec()).unwrap();
                self.body.drain(..end + 2);
                let mut name = None;
                let mut data = None;
                for line in block.lines() {
                    if let Some(v) = line.strip_prefix("event: ") {
                        name = Some(v.to_string());
                    } else if let Some(v) = line.strip_prefix("data: ") {
                        data = Some(v.to_string());
                    }
                }
                if let Some(data) = data {
                    return Some(SseEvent {
                        name: name.unwrap_or_else(|| "message".into()),
                        data,
                        at: tokio::time::Instant::now(),
                    });
                }
            }
            if self.ended {
                return None;
            }
            if tokio::time::timeout_at(deadline, self.read_more())
                .await
                .is_err()
            {
                return None;
            }
        }
    }

    /// Every event within `within`.
    pub async fn events_for(&mut self, within: Duration) -> Vec<SseEvent> {
        let deadline = tokio::time::Instant::now() + within;
        let mut v = Vec::new();
        loop {
            let left = deadline.saturating_duration_since(tokio::time::Instant::now());
            if left.is_zero() {
                return v;
            }
            match self.next_event(left).await {
                Some(e) => v.push(e),
                None => return v,
            }
        }
    }
}

/// A replay of `name` paced at `speed` (feed seconds per wall second), once.
pub fn paced(name: &str, config: &Config, speed: f64) -> Source {
    Source::Replay(Replay {
        data: ReplayData::File(fixture(name)),
        format: None,
        speed,
        loop_: false,
        nominal_rate_hz: config.decode.nominal_rate_hz,
        fit_untimed_clock: config.decode.fit_untimed_clock,
        loop_gap_s: 0.0,
        progress: false,
    })
}

/// A response read off the wire: status, headers (lower-case names), body.
pub struct Reply {
    pub status: u16,
    pub headers: std::collections::BTreeMap<String, String>,
    pub body: Vec<u8>,
}

impl Reply {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.get(name).map(String::as_str)
    }
}

/// GET `path` with extra header lines, on a connection of its own, the response as bytes.
pub async fn get_with(addr: SocketAddr, path: &str, headers: &[(&str, &str)]) -> Reply {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    let mut req = format!("GET {path} HTTP/1.1\r\nHost: test\r\nConnection: close\r\n");
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    req.push_str("\r\n");
    s.write_all(req.as_bytes()).await.unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).await.unwrap();
    let end = buf
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a response head");
    let head = String::from_utf8_lossy(&buf[..end]).into_owned();
    let mut lines = head.lines();
    let status = lines
        .next()
        .and_then(|l| l.split(' ').nth(1))
        .and_then(|s| s.parse().ok())
        .expect("a status line");
    let headers = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    Reply {
        status,
        headers,
        body: buf[end + 4..].to_vec(),
    }
}

/// Resident set size of this process, bytes (Linux).
pub fn rss_bytes() -> u64 {
    let statm = std::fs::read_to_string("/proc/self/statm").unwrap_or_default();
    let pages: u64 = statm
        .split_whitespace()
        .nth(1)
        .and_then(|p| p.parse().ok())
        .unwrap_or(0);
    pages * 4096
}

/// One Beast long frame at feed time `t_s` (12 MHz counter), 0x1a escaped.
pub fn beast(t_s: f64, frame: &[u8; 14], out: &mut Vec<u8>) {
    beast_at_ticks((t_s * 12e6) as u64, frame, out);
}

/// One Beast frame (type '2' for 7 bytes, '3' for 14) at counter `ticks` (12 MHz), signal
/// 0x80, 0x1a escaped.
pub fn beast_at_ticks(ticks: u64, data: &[u8], out: &mut Vec<u8>) {
    out.push(0x1a);
    out.push(if data.len() == 7 { b'2' } else { b'3' });
    let mut body = ticks.to_be_bytes()[2..].to_vec();
    body.push(0x80);
    body.extend_from_slice(data);
    for b in body {
        out.push(b);
        if b == 0x1a {
            out.push(0x1a);
        }
    }
}

/// The daemon reading a Beast feed (`[[feeds]]` named `name`) from a listener of the
/// test's, and the test's end of that connection.
pub async fn with_beast_feed(
    mut config: Config,
    name: &str,
    silence_timeout_s: f64,
) -> (TestDaemon, tokio::net::TcpStream) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    config.feeds = vec![adsb_tracker::config::FeedConfig {
        name: name.into(),
        addr: listener.local_addr().unwrap().to_string(),
        format: adsb_tracker::feed::Format::Beast,
        silence_timeout_s,
    }];
    let d = TestDaemon::start(config.clone(), Source::Feeds(config.feeds), None).await;
    let (sock, _) = listener.accept().await.unwrap();
    (d, sock)
}
