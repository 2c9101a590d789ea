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
