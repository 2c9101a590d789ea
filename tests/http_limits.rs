//! The HTTP server against hostile clients (issue 11, rows 1, 2, 3 and 7), and feed
//! liveness (row 5): each a bounded loopback test with small limits.

mod common;

use adsb_tracker::config::{Config, FeedConfig};
use adsb_tracker::daemon::Source;
use adsb_tracker::feed::Format;
use common::{get, get_json, TestDaemon};
use std::net::SocketAddr;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

fn config(server: &str) -> Config {
    Config::from_toml_str(&format!("[server]\n{server}\n")).unwrap()
}

/// Sends `request` raw and reads until the server closes (or `within` passes).
async fn raw(addr: SocketAddr, request: &[u8], within: Duration) -> (String, Duration) {
    let start = Instant::now();
    let mut s = TcpStream::connect(addr).await.unwrap();
    // A server may answer and close before it has read everything: ignore a reset here.
    let _ = s.write_all(request).await;
    let mut out = Vec::new();
    let _ = tokio::time::timeout(within, s.read_to_end(&mut out)).await;
    (String::from_utf8_lossy(&out).into_owned(), start.elapsed())
}

/// The status, one header's value and the JSON body of a raw response.
fn parse(response: &str, header: &str) -> (u16, Option<String>, serde_json::Value) {
    let (head, body) = response.split_once("\r\n\r\n").unwrap_or((response, ""));
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    let value = head.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        k.eq_ignore_ascii_case(header).then(|| v.trim().to_string())
    });
    let json = serde_json::from_str(body).unwrap_or(serde_json::Value::Null);
    (status, value, json)
}

/// Row 7: every error is the API's JSON, the framework's and hyper's own included.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_error_body_is_json() {
    let d = TestDaemon::replay(
        "toulouse-sample.beast",
        config("max_requests_per_connection = 3"),
    )
    .await;
    d.wait_replay().await;
    let w = Duration::from_secs(5);
    for method in ["POST", "PUT", "DELETE", "OPTIONS", "PATCH"] {
        for path in ["/api/v1/tracks", "/healthz", "/api/v1/stats"] {
            let req = format!("{method} {path} HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\nConnection: close\r\n\r\n");
            let (r, _) = raw(d.addr, req.as_bytes(), w).await;
            let (status, allow, json) = parse(&r, "allow");
            assert_eq!(status, 405, "{method} {path}: {r}");
            assert_eq!(allow.as_deref(), Some("GET,HEAD"), "{method} {path}");
            assert_eq!(json["error"], "method not allowed", "{method} {path}: {r}");
        }
    }
    let cases: Vec<(Vec<u8>, u16, &str)> = vec![
        (
            b"GET /api/v1/tracks/%FF%FE HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".to_vec(),
            400,
            "UTF-8",
        ),
        (
            b"GET /api/v1/tracks/zz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".to_vec(),
            400,
            "zz",
        ),
        (
            b"GET /nowhere HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".to_vec(),
            404,
            "no such endpoint",
        ),
        (b"GARBAGE\r\n\r\n".to_vec(), 400, "malformed HTTP request"),
        (
            [
                b"GET /".as_slice(),
                &[b'a'; 100_000],
                b" HTTP/1.1\r\nHost: x\r\n\r\n",
            ]
            .concat(),
            414,
            "URI too long",
        ),
        (
            [
                b"GET / HTTP/1.1\r\nHost: x\r\nX-Big: ".as_slice(),
                &[b'a'; 1 << 20],
                b"\r\n\r\n",
            ]
            .concat(),
            431,
            "request header fields too large",
        ),
    ];
    for (req, want, text) in cases {
        let (r, _) = raw(d.addr, &req, w).await;
        let (status, ctype, json) = parse(&r, "content-type");
        assert_eq!(status, want, "{r}");
        assert_eq!(ctype.as_deref(), Some("application/json"), "{r}");
        let error = json["error"]
            .as_str()
            .unwrap_or_else(|| panic!("no error in {r}"));
        assert!(error.contains(text), "{error:?} should mention {text:?}");
    }
    // max_requests_per_connection = 3: three pipelined answers, the third closing; the
    // fourth request is never answered.
    let req = b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n".repeat(4);
    let (r, _) = raw(d.addr, &req, w).await;
    assert_eq!(r.matches("HTTP/1.1 200 OK").count(), 3, "{r}");
    assert_eq!(r.matches("connection: close").count(), 1, "{r}");
    d.stop().await;
}

/// Row 1: idle connections are closed after the header-read timeout, and connections over
/// the cap get a JSON 503 instead of exhausting the process's descriptors.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_connections_are_capped_and_closed() {
    let d = TestDaemon::replay(
        "toulouse-sample.beast",
        config("max_connections = 8\nheader_read_timeout_s = 0.5"),
    )
    .await;
    d.wait_replay().await;
    let mut idle = Vec::new();
    for _ in 0..8 {
        idle.push(TcpStream::connect(d.addr).await.unwrap());
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    // One more: refused at once with a JSON 503.
    let (r, took) = raw(d.addr, b"", Duration::from_secs(5)).await;
    let (status, _, json) = parse(&r, "retry-after");
    assert_eq!(status, 503, "{r}");
    assert!(json["error"]
        .as_str()
        .unwrap()
        .contains("server.max_connections = 8"));
    assert!(took < Duration::from_secs(2), "refusal took {took:?}");
    // The idle ones are closed by the server within the timeout (plus scheduling slack).
    let start = Instant::now();
    for mut s in idle {
        let mut buf = [0u8; 64];
        let n = tokio::time::timeout(Duration::from_secs(5), s.read(&mut buf))
            .await
            .expect("an idle connection was never closed")
            .unwrap_or(0);
        assert_eq!(n, 0, "an idle connection got data");
    }
    assert!(
        start.elapsed() < Duration::from_secs(3),
        "{:?}",
        start.elapsed()
    );
    // Room again: served.
    let (code, stats) = get_json(d.addr, "/api/v1/stats").await;
    assert_eq!(code, 200);
    assert!(
        stats["http"]["connections_refused"].as_u64().unwrap() >= 1,
        "{stats}"
    );
    assert!(
        stats["http"]["connections_timed_out"].as_u64().unwrap() >= 8,
        "{stats}"
    );
    assert_eq!(
        stats["http"]["connections_open"].as_i64(),
        Some(1),
        "{stats}"
    );
    d.stop().await;
}

/// Row 2: shutdown while a client has sent half a request head ends within the grace
/// period, not when the client leaves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_is_bounded_by_the_grace_period() {
    let d = TestDaemon::replay(
        "toulouse-sample.beast",
        config("shutdown_grace_s = 0.5\nheader_read_timeout_s = 60"),
    )
    .await;
    d.wait_replay().await;
    let mut half = TcpStream::connect(d.addr).await.unwrap();
    half.write_all(b"GET /api/v1/tra").await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let start = Instant::now();
    d.shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(5), d.handle)
        .await
        .expect("shutdown waited for the half-sent request")
        .unwrap();
    assert!(
        start.elapsed() < Duration::from_secs(3),
        "{:?}",
        start.elapsed()
    );
    drop(half);
}

/// Row 3: a client that pipelines requests and never reads is cut after the write timeout;
/// nothing it asked for is held after.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_never_reads_is_cut() {
    let d = TestDaemon::replay(
        "lax-messages.avr.txt",
        config("write_timeout_s = 0.5\ntracks_cache_ms = 0"),
    )
    .await;
    d.wait_replay().await;
    let (_, tracks) = get(d.addr, "/api/v1/tracks").await;
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let mut s = socket.connect(d.addr).await.unwrap();
    // Enough responses to fill both socket buffers many times over.
    let req = b"GET /api/v1/tracks HTTP/1.1\r\nHost: x\r\n\r\n";
    let n = (64 << 20) / tracks.len().max(1) + 1;
    let mut sent = 0;
    for _ in 0..n.min(2000) {
        match tokio::time::timeout(Duration::from_millis(200), s.write_all(req)).await {
            Ok(Ok(())) => sent += 1,
            _ => break,
        }
    }
    assert!(sent > 0);
    // The server gives up on us.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let (_, stats) = get_json(d.addr, "/api/v1/stats").await;
        if stats["http"]["connections_timed_out"].as_u64() >= Some(1)
            && stats["http"]["connections_open"].as_i64() == Some(1)
        {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the non-reading client was never cut: {stats}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // What we get when we finally read ends early: the connection was closed.
    let mut got = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut got)).await;
    assert!(
        got.len() < sent * tracks.len(),
        "every response was delivered"
    );
    d.stop().await;
}

/// Row 5: a feed that connects and then sends nothing is reported silent (`/healthz`
/// degraded) and reconnected after its silence timeout.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_feed_is_noticed_and_reconnected() {
    let server = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let feed_addr = server.local_addr().unwrap();
    // Accepts every connection and keeps it open, sending nothing.
    let silent = tokio::spawn(async move {
        let mut held = Vec::new();
        while let Ok((s, _)) = server.accept().await {
            held.push(s);
        }
    });
    let mut config = Config::default_config().unwrap();
    config.feeds = vec![FeedConfig {
        name: "mute".into(),
        addr: feed_addr.to_string(),
        format: Format::Beast,
        silence_timeout_s: 1.0,
    }];
    let d = TestDaemon::start(config.clone(), Source::Feeds(config.feeds.clone()), None).await;
    tokio::time::sleep(Duration::from_millis(200)).await;
    let (code, h) = get_json(d.addr, "/healthz").await;
    assert_eq!(code, 200, "{h}");
    assert_eq!(h["feeds"][0]["connected"], true);
    // Past half the timeout: silent, degraded.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let (code, h) = get_json(d.addr, "/healthz").await;
    assert_eq!(code, 503, "{h}");
    assert_eq!(h["status"], "degraded");
    assert_eq!(h["feeds"][0]["silent"], true, "{h}");
    // Past the timeout: dropped and connected again.
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let (_, h) = get_json(d.addr, "/healthz").await;
        if h["feeds"][0]["connects"].as_u64() >= Some(2) {
            let err = h["feeds"][0]["last_error"].as_str().unwrap_or_default();
            assert!(err.contains("silence_timeout_s"), "{h}");
            break;
        }
        assert!(Instant::now() < deadline, "never reconnected: {h}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    d.stop().await;
    silent.abort();
}
