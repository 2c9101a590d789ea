//! Issue 11, rows 10 and 11: the daemon's views agree (`tracks_active` is what the registry
//! lists, during a replay and after its end), and a replay looped by `serve` retires every
//! aircraft across the loop gap, so each pass starts clean.

mod common;

use adsb_tracker::config::Config;
use adsb_tracker::daemon::aircraft::{AircraftConfig, TaskContext};
use adsb_tracker::daemon::registry::Registry;
use adsb_tracker::daemon::router::{run_router, Overload, RouterConfig};
use adsb_tracker::daemon::source::{run_replay, Replay, ReplayData, ReplayProgress};
use adsb_tracker::daemon::stats::{Stats, StatsSnapshot};
use adsb_tracker::decode::cpr::CprConfig;
use adsb_tracker::decode::DecoderConfig;
use adsb_tracker::feed::tcp::FrameBatch;
use common::{fixture, get_json, TestDaemon};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// Row 10: after a replay's end its tracks are still served (`replay --serve`), so they are
/// still counted: `tracks_active` in the stats and `/metrics` is what `/healthz` counts (the
/// aircraft the registry holds), and `/api/v1/tracks` lists those of them that have an
/// estimate.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_a_replay_the_stats_count_the_tracks_still_served() {
    let d = TestDaemon::replay("us-short-flights.csv", Config::default_config().unwrap()).await;
    let stats = d.wait_replay().await;
    // The nine aircraft of the recording, none retired (its 61 s hold no silence that long).
    assert_eq!(stats["tracks_created"], 9);
    assert_eq!(stats["tracks_retired"], 0);
    assert_eq!(stats["tracks_active"], 9, "{stats}");
    let (code, health) = get_json(d.addr, "/healthz").await;
    assert_eq!(code, 200, "{health}");
    assert_eq!(health["tracks"], 9);
    // Two of the nine sent no position (identification and altitude only): no estimate, so
    // nothing to list; the seven others are listed.
    let (_, tracks) = get_json(d.addr, "/api/v1/tracks").await;
    let listed = tracks["tracks"].as_array().unwrap();
    assert_eq!(listed.len(), 7, "{tracks}");
    assert!(listed
        .iter()
        .all(|t| t["positions_accepted"].as_u64().unwrap() > 0));
    let (_, metrics) = common::get(d.addr, "/metrics").await;
    assert!(metrics.contains("\nadsb_tracks_active 9\n"), "{metrics}");
    d.stop().await;
}

/// The router fed by the daemon's own looping replay source, stopped after exactly
/// `passes` passes of `name`: what the stats say then.
async fn looped(name: &str, passes: u64) -> StatsSnapshot {
    let config = Config::default_config().unwrap();
    let stats = Arc::new(Stats::new());
    let shutdown = CancellationToken::new();
    let ctx = Arc::new(TaskContext {
        registry: Arc::new(Registry::default()),
        stats: stats.clone(),
        updates: None,
        feed: Arc::new(adsb_tracker::output::UpdateFeed::default()),
        shutdown: CancellationToken::new(),
        prediction_horizons_s: Vec::new(),
    });
    let router_cfg = RouterConfig {
        decoder: DecoderConfig {
            fix_single_bit: true,
            recent_address_s: config.decode.recent_address_s,
        },
        aircraft: AircraftConfig {
            cpr: CprConfig {
                receiver: Some((49.0097, 2.5479)),
                ..CprConfig::default()
            },
            tracker: adsb_tracker::daemon::build_tracker,
            tracker_config: config.tracker.clone(),
            duplicate_window_s: config.decode.duplicate_window_s,
        },
        retire_after_s: config.tracker.retire_after_s,
        idle: Duration::from_secs(3600),
        channel_capacity: config.tracker.channel_capacity,
        overload: Overload::Backpressure,
    };
    let (router_tx, router_rx) = mpsc::channel::<FrameBatch>(8);
    let router = tokio::spawn(run_router(router_rx, router_cfg, ctx));
    // As `serve` loops a recording: each pass `retire_after_s + 1` after the last.
    let replay = Replay {
        data: ReplayData::File(fixture(name)),
        format: None,
        speed: 0.0,
        loop_: true,
        nominal_rate_hz: config.decode.nominal_rate_hz,
        fit_untimed_clock: config.decode.fit_untimed_clock,
        loop_gap_s: config.tracker.retire_after_s + 1.0,
        progress: false,
    };
    let (tx, mut rx) = mpsc::channel::<FrameBatch>(1);
    let progress = Arc::new(ReplayProgress::default());
    let source = {
        let (progress, shutdown) = (progress.clone(), shutdown.clone());
        tokio::task::spawn_blocking(move || run_replay(&replay, &tx, &progress, &shutdown))
    };
    // The frames of one pass, counted by a reader of its own.
    let mut reader =
        adsb_tracker::feed::replay::FileReader::open(fixture(name), None, 1000.0).expect("fixture");
    let mut per_pass = 0u64;
    let mut batch = Vec::new();
    while reader.next_batch(&mut batch).unwrap() {
        per_pass += batch.len() as u64;
    }
    // Forward exactly `passes` passes, then stop the source.
    let mut left = per_pass * passes;
    while left > 0 {
        let mut b = rx.recv().await.expect("the replay loops forever");
        b.frames.truncate(left.min(b.frames.len() as u64) as usize);
        left -= b.frames.len() as u64;
        router_tx.send(b).await.unwrap();
    }
    shutdown.cancel();
    drop(rx);
    source.await.unwrap().unwrap();
    // The router drains every aircraft, then ends.
    drop(router_tx);
    router.await.unwrap();
    let s = stats.snapshot();
    assert_eq!(s.frames, per_pass * passes);
    s
}

fn impossible_speed(s: &StatsSnapshot) -> u64 {
    s.positions_rejected
        .get("impossible_speed")
        .copied()
        .unwrap_or(0)
}

/// Row 11: looped twice, a recording gives twice what one pass gives, and no rejection the
/// single pass does not have; every aircraft of the first pass is retired across the gap.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_looped_replay_starts_each_pass_clean() {
    for name in ["afr34zg-cdg-tls.jsonl", "us-short-flights.csv"] {
        let once = looped(name, 1).await;
        let twice = looped(name, 2).await;
        assert_eq!(
            impossible_speed(&twice),
            2 * impossible_speed(&once),
            "{name}"
        );
        assert_eq!(
            twice.positions_accepted,
            2 * once.positions_accepted,
            "{name}"
        );
        assert_eq!(twice.track_updates, 2 * once.track_updates, "{name}");
        assert_eq!(twice.tracks_created, 2 * once.tracks_created, "{name}");
        // Every aircraft of the first pass retired when it reappeared after the gap.
        assert_eq!(twice.tracks_retired, once.tracks_created, "{name}");
        assert_eq!(twice.tracks_active as u64, once.tracks_created, "{name}");
        eprintln!(
            "{name}: one pass {} updates, {} impossible_speed; two passes {} updates, {} impossible_speed",
            once.track_updates,
            impossible_speed(&once),
            twice.track_updates,
            impossible_speed(&twice)
        );
    }
}
