//! A live Beast feed faster than the pipeline: with the default policy every message reaches
//! its aircraft (backpressure through TCP flow control); with `pipeline.overload = "drop"`
//! what is shed is counted, exactly. Loopback only, bounded in size and time.

mod common;

use adsb_tracker::config::{Config, FeedConfig};
use adsb_tracker::daemon::router::Overload;
use adsb_tracker::daemon::Source;
use adsb_tracker::feed::Format;
use adsb_tracker::sim::scenario::Reference;
use adsb_tracker::sim::{fleet, simulate, FleetSpec};
use common::{get_json, TestDaemon};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;
use tokio::io::AsyncWriteExt;

/// A simulated fleet as a Beast file: 200 aircraft for 45 s (about 37,000 frames, 0.9 MB).
fn fleet_file(test: &str) -> PathBuf {
    // One directory per test: the tests of this file run in parallel in one process.
    let dir = std::env::temp_dir().join(format!("adsb-{test}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let spec = FleetSpec {
        reference: Reference {
            lat_deg: 51.47,
            lon_deg: -0.46,
        },
        aircraft: 200,
        radius_km: 250.0,
        duration_s: 45.0,
        seed: 7,
        mode_weights: Default::default(),
    };
    let prefix = dir.join("fleet");
    simulate(&fleet(&spec).unwrap(), 7, &prefix).unwrap();
    dir.join("fleet.beast")
}

/// Frames per ICAO address in a clean Beast file of DF17 frames, counted from the bytes
/// (escape-aware walk, independent of the crate's parser).
fn frames_per_icao(data: &[u8]) -> BTreeMap<String, u64> {
    let mut out = BTreeMap::new();
    let mut i = 0;
    while i + 1 < data.len() {
        assert_eq!(data[i], 0x1a);
        let n = match data[i + 1] {
            b'2' => 7,
            b'3' => 14,
            t => panic!("type {t}"),
        };
        let mut payload = Vec::new();
        let mut j = i + 2;
        while payload.len() < 7 + n {
            payload.push(data[j]);
            j += if data[j] == 0x1a { 2 } else { 1 };
        }
        let msg = &payload[7..];
        let icao = format!("{:02x}{:02x}{:02x}", msg[1], msg[2], msg[3]);
        *out.entry(icao).or_default() += 1;
        i = j;
    }
    out
}

/// A pipeline slower than the feed: the IMM on every report (the costliest default tracker)
/// and one batch of room per aircraft.
fn slow_config() -> Config {
    let mut c = Config::default_config().unwrap();
    c.tracker.algorithm = "imm".into();
    c.tracker.channel_capacity = 1;
    c
}

/// Serves `data` to the first client as fast as the socket takes it, then stays connected
/// (a live feed gone quiet) until aborted.
async fn serve_once(data: Vec<u8>) -> (std::net::SocketAddr, tokio::task::JoinHandle<()>) {
    let server = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = server.local_addr().unwrap();
    let task = tokio::spawn(async move {
        let (mut s, _) = server.accept().await.unwrap();
        s.write_all(&data).await.unwrap();
        tokio::time::sleep(Duration::from_secs(60)).await;
    });
    (addr, task)
}

/// Waits until `frames` frames were routed and every queue is empty. Returns the stats and
/// the largest ingest lag `/healthz` reported as `degraded` on the way (0 if never).
async fn wait_drained(d: &TestDaemon, frames: u64) -> (serde_json::Value, f64) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(120);
    let mut degraded_lag_s: f64 = 0.0;
    loop {
        let (code, h) = get_json(d.addr, "/healthz").await;
        if code == 503 {
            assert_eq!(h["status"], "degraded", "{h}");
            degraded_lag_s = degraded_lag_s.max(h["ingest_lag_s"].as_f64().unwrap());
        }
        let (_, s) = get_json(d.addr, "/api/v1/stats").await;
        if s["frames"] == frames && s["queued_frames"] == 0 && s["queued_batches"] == 0 {
            // One more look: the last batches may still be in a task's hands.
            tokio::time::sleep(Duration::from_millis(200)).await;
            let (_, s2) = get_json(d.addr, "/api/v1/stats").await;
            if s2["track_updates"] == s["track_updates"] {
                return (s2, degraded_lag_s);
            }
        }
        assert!(tokio::time::Instant::now() < deadline, "stuck: {s}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

fn live(config: &mut Config, addr: std::net::SocketAddr) -> Source {
    config.feeds = vec![FeedConfig {
        name: "fast".into(),
        addr: addr.to_string(),
        format: Format::Beast,
        silence_timeout_s: adsb_tracker::config::DEFAULT_SILENCE_TIMEOUT_S,
    }];
    Source::Feeds(config.feeds.clone())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_feed_faster_than_the_pipeline_loses_nothing() {
    let path = fleet_file("lossless");
    let data = std::fs::read(&path).unwrap();
    let expected = frames_per_icao(&data);
    let total: u64 = expected.values().sum();
    assert_eq!(expected.len(), 200);
    assert!(total > 30_000, "{total}");

    // The reference: the same file replayed (a replay always waits).
    let reference = {
        let d = TestDaemon::replay_file(path.clone(), slow_config()).await;
        let s = d.wait_replay().await;
        d.stop().await;
        s
    };

    let (addr, sender) = serve_once(data).await;
    let mut config = slow_config();
    assert_eq!(config.pipeline.overload, Overload::Backpressure);
    // Degraded as soon as the backlog is 20 ms old.
    config.pipeline.max_lag_s = 0.02;
    let source = live(&mut config, addr);
    let d = TestDaemon::start(config, source, None).await;
    let (s, degraded_lag_s) = wait_drained(&d, total).await;
    assert!(degraded_lag_s > 0.02, "never degraded: {s}");
    // Caught up: healthy again, no lag.
    let (code, h) = get_json(d.addr, "/healthz").await;
    assert_eq!((code, h["ingest_lag_s"].as_f64()), (200, Some(0.0)), "{h}");
    assert_eq!(s["channel_drops"], 0, "{s}");
    assert_eq!(s["channel_dropped_messages"], 0, "{s}");
    assert_eq!(s["feeds"][0]["frames"], total, "{s}");
    assert_eq!(s["aircraft_messages"], total, "{s}");
    for key in ["positions_accepted", "track_updates", "tracks_created"] {
        assert_eq!(s[key], reference[key], "{key}: live {s} replay {reference}");
    }
    // Every aircraft got every one of its messages.
    let (_, tracks) = get_json(d.addr, "/api/v1/tracks").await;
    let got: BTreeMap<String, u64> = tracks["tracks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            (
                t["icao"].as_str().unwrap().to_string(),
                t["messages"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(got, expected);
    // The stream was faster than the pipeline: frames waited in the queues (the latency
    // histogram saw waits of tens of milliseconds) and nothing was lost.
    assert!(s["latency"]["p99_s"].as_f64().unwrap() >= 0.01, "{s}");
    sender.abort();
    d.stop().await;
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_drop_policy_counts_exactly_what_it_sheds() {
    let path = fleet_file("drop");
    let data = std::fs::read(&path).unwrap();
    let total: u64 = frames_per_icao(&data).values().sum();
    let (addr, sender) = serve_once(data).await;
    let mut config = slow_config();
    config.pipeline.overload = Overload::Drop;
    // The smallest budget: a burst of the whole file cannot all be queued.
    config.pipeline.max_queued_frames = 1024;
    let source = live(&mut config, addr);
    let d = TestDaemon::start(config, source, None).await;
    let (s, _) = wait_drained(&d, total).await;
    let dropped = s["channel_dropped_messages"].as_u64().unwrap();
    assert!(dropped > 0, "the stream should outrun the IMM: {s}");
    assert!(s["channel_drops"].as_u64().unwrap() > 0);
    let (_, tracks) = get_json(d.addr, "/api/v1/tracks").await;
    let delivered: u64 = tracks["tracks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["messages"].as_u64().unwrap())
        .sum();
    // What reached the aircraft plus what was dropped is every frame: the aircraft's count
    // (every one, whether or not it has a track to list) against the router's.
    assert_eq!(
        s["aircraft_messages"].as_u64().unwrap() + dropped,
        total,
        "{s}"
    );
    // The listed tracks are some of those aircraft: an aircraft that got only a few
    // messages may have no position yet, or its track ended (its last snapshot still
    // counting). With nearly every batch dropped, a share of them are in that state.
    assert!(delivered <= total - dropped, "{s}");
    assert!(delivered > 0, "{s}");
    sender.abort();
    d.stop().await;
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
}
