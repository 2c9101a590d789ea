//! The daemon on a live TCP Beast feed that drops in the middle of a frame and comes back.

mod common;

use adsb_tracker::config::{Config, FeedConfig};
use adsb_tracker::daemon::Source;
use adsb_tracker::feed::Format;
use common::{fixture, get_json, TestDaemon};
use std::time::Duration;
use tokio::io::AsyncWriteExt;

/// Byte offsets where each Beast frame of `data` starts, found by walking the escapes
/// (independent of the crate's parser): `0x1a`, a type byte, then 6 + 1 + n payload bytes in
/// which a literal 0x1a is doubled.
fn frame_starts(data: &[u8]) -> Vec<usize> {
    let mut starts = Vec::new();
    let mut i = 0;
    while i + 1 < data.len() {
        assert_eq!(data[i], 0x1a, "recording is clean Beast");
        let n = match data[i + 1] {
            b'1' => 2,
            b'2' => 7,
            b'3' => 14,
            t => panic!("type {t}"),
        };
        starts.push(i);
        let mut j = i + 2;
        let mut left = 6 + 1 + n;
        while left > 0 {
            j += if data[j] == 0x1a { 2 } else { 1 };
            left -= 1;
        }
        i = j;
    }
    starts
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn beast_feed_reconnects_after_a_cut_mid_frame() {
    let data = std::fs::read(fixture("toulouse-sample.beast")).unwrap();
    let starts = frame_starts(&data);
    assert_eq!(starts.len(), 239);
    // Cut 5 bytes into frame 120; the second connection starts at frame 121.
    let cut = starts[120] + 5;
    let resume = starts[121];

    let server = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let feed_addr = server.local_addr().unwrap();
    let first = data[..cut].to_vec();
    let second = data[resume..].to_vec();
    let server_task = tokio::spawn(async move {
        let (mut s, _) = server.accept().await.unwrap();
        s.write_all(&first).await.unwrap();
        s.shutdown().await.unwrap();
        drop(s);
        let (mut s, _) = server.accept().await.unwrap();
        s.write_all(&second).await.unwrap();
        // Keep the connection open: a live feed that is simply quiet now.
        tokio::time::sleep(Duration::from_secs(30)).await;
    });

    let mut config = Config::default_config().unwrap();
    config.feeds = vec![FeedConfig {
        name: "test-beast".into(),
        addr: feed_addr.to_string(),
        format: Format::Beast,
        silence_timeout_s: adsb_tracker::config::DEFAULT_SILENCE_TIMEOUT_S,
    }];
    let source = Source::Feeds(config.feeds.clone());
    let d = TestDaemon::start(config, source, None).await;

    // 239 frames in the file, one cut in half: 238 arrive.
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    let stats = loop {
        let (_, s) = get_json(d.addr, "/api/v1/stats").await;
        if s["frames"] == 238 {
            break s;
        }
        assert!(tokio::time::Instant::now() < deadline, "stuck: {s}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let feed = &stats["feeds"][0];
    assert_eq!(feed["connects"], 2, "{feed}");
    assert_eq!(feed["disconnects"], 1, "{feed}");
    assert_eq!(feed["connected"], true, "{feed}");
    // The 5 bytes of the cut frame are counted as a truncated tail, nothing else is lost.
    assert_eq!(feed["parse"]["truncated_tail_bytes"], 5, "{feed}");
    assert_eq!(feed["parse"]["garbage_bytes"], 0, "{feed}");

    let (code, health) = get_json(d.addr, "/healthz").await;
    assert_eq!(code, 200, "{health}");
    assert_eq!(health["status"], "ok");

    let summary = d.stop().await;
    assert_eq!(summary.stats.frames, 238);
    server_task.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_is_degraded_while_the_only_feed_is_down() {
    // A port with nobody listening: bind, note the address, close.
    let addr = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap()
    };
    let mut config = Config::default_config().unwrap();
    config.feeds = vec![FeedConfig {
        name: "down".into(),
        addr: addr.to_string(),
        format: Format::Avr,
        silence_timeout_s: adsb_tracker::config::DEFAULT_SILENCE_TIMEOUT_S,
    }];
    let source = Source::Feeds(config.feeds.clone());
    let d = TestDaemon::start(config, source, None).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (code, health) = get_json(d.addr, "/healthz").await;
    assert_eq!(code, 503, "{health}");
    assert_eq!(health["status"], "degraded");
    assert_eq!(health["feeds"][0]["connected"], false);
    // The API keeps serving meanwhile.
    let (code, tracks) = get_json(d.addr, "/api/v1/tracks").await;
    assert_eq!(code, 200);
    assert_eq!(tracks["tracks"].as_array().unwrap().len(), 0);
    d.stop().await;
}
