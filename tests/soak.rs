//! Churn soak (issue 11): waves of aircraft appear on a live Beast feed over loopback, fly,
//! fall silent and are retired, wave after wave. Memory stays flat and no per-aircraft
//! table grows: the router's map (`tracks_active`), the registry (`/healthz` `tracks`) and
//! the aircraft tasks all return to the size of the live fleet.
//!
//! The short form runs in `cargo test` (`SOAK_WAVES` waves, 40 by default: 10,000 aircraft); the long form is
//! `scripts/soak.sh`, which runs this test with more waves and prints the RSS of every wave.

mod common;

use adsb_tracker::config::Config;
use adsb_tracker::decode::Icao;
use adsb_tracker::decode::VerticalRateSource;
use adsb_tracker::sim::encode::{airborne_position, airborne_velocity, VelocityReport};
use common::{beast, get_json, with_beast_feed};
use std::time::{Duration, Instant};
use tokio::io::AsyncWriteExt;

/// Aircraft per wave.
const WAVE_AIRCRAFT: u32 = 250;
/// Feed time a wave flies, s.
const WAVE_S: f64 = 20.0;
/// `tracker.retire_after_s` of the test: silent this long, an aircraft is retired.
const RETIRE_S: f64 = 5.0;

/// Wave `w`: `WAVE_AIRCRAFT` new addresses, each flying east from its own spot for
/// `WAVE_S` s of feed time starting at `w * WAVE_S`, a position every 0.5 s (even and odd
/// alternating) and a velocity every second.
fn wave(w: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let t0 = f64::from(w) * WAVE_S + 1.0;
    let steps = (WAVE_S / 0.5) as u32;
    for k in 0..steps {
        let t = t0 + f64::from(k) * 0.5;
        for a in 0..WAVE_AIRCRAFT {
            let icao = Icao(0x100000 + w * WAVE_AIRCRAFT + a);
            let lat = 40.0 + f64::from(a % 50) * 0.1;
            let lon = -5.0 + f64::from(a / 50) * 0.5 + (t - t0) * 230.0 / 85_000.0;
            let t = t + f64::from(a) * 1e-4;
            beast(
                t,
                &airborne_position(icao, 35_000.0, lat, lon, k % 2 == 1),
                &mut out,
            );
            if k % 2 == 0 {
                let v = VelocityReport {
                    ve_kt: 447.0,
                    vn_kt: 0.0,
                    vrate_fpm: 0.0,
                    vrate_source: VerticalRateSource::Baro,
                    nac_v: 2,
                };
                beast(t + 0.01, &airborne_velocity(icao, &v), &mut out);
            }
        }
    }
    out
}

/// Resident set size of this process, KiB.
fn rss_kib() -> u64 {
    common::rss_bytes() / 1024
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn churn_keeps_memory_and_tables_flat() {
    let waves: u32 = std::env::var("SOAK_WAVES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(40);
    let config = Config::from_toml_str(&format!(
        "[tracker]\nretire_after_s = {RETIRE_S}\nalgorithm = \"hybrid\"\n"
    ))
    .unwrap();
    let (d, mut sock) = with_beast_feed(config, "waves", 60.0).await;

    let mut frames_sent = 0u64;
    let mut rss_after = Vec::new();
    let start = Instant::now();
    for w in 0..waves {
        let data = wave(w);
        frames_sent += u64::from(WAVE_AIRCRAFT) * (WAVE_S / 0.5) as u64 * 3 / 2;
        sock.write_all(&data).await.unwrap();
        // Wait until this wave is processed.
        let deadline = Instant::now() + Duration::from_secs(60);
        let stats = loop {
            let (_, s) = get_json(d.addr, "/api/v1/stats").await;
            if s["frames"].as_u64() == Some(frames_sent) && s["queued_frames"] == 0 {
                break s;
            }
            assert!(Instant::now() < deadline, "wave {w} not processed: {s}");
            tokio::time::sleep(Duration::from_millis(20)).await;
        };
        let (_, health) = get_json(d.addr, "/healthz").await;
        let active = stats["tracks_active"].as_i64().unwrap();
        let listed = health["tracks"].as_u64().unwrap();
        // The previous waves are retired by feed time (the current wave started 20 s
        // after the last one ended, past retire_after_s): only this wave is alive.
        assert!(
            active <= i64::from(WAVE_AIRCRAFT) && listed <= u64::from(WAVE_AIRCRAFT),
            "wave {w}: {active} tasks, {listed} listed"
        );
        assert_eq!(
            stats["tracks_created"].as_u64(),
            Some(u64::from((w + 1) * WAVE_AIRCRAFT)),
            "{stats}"
        );
        let retired = stats["tracks_retired"].as_u64().unwrap();
        assert!(
            retired >= u64::from(w * WAVE_AIRCRAFT),
            "wave {w}: {retired} retired"
        );
        assert_eq!(stats["track_errors"], serde_json::json!({}), "{stats}");
        rss_after.push(rss_kib());
        if std::env::var("SOAK_VERBOSE").is_ok() {
            println!(
                "wave {w}: {:.1} s, RSS {} KiB, {active} tasks, {listed} listed, {retired} retired",
                start.elapsed().as_secs_f64(),
                rss_kib()
            );
        }
    }
    // Flat: after the first quarter (allocator and caches warm), RSS grows by less than
    // one wave's worth of aircraft at a generous 64 KiB each.
    let warm = rss_after[rss_after.len() / 4];
    let last = *rss_after.last().unwrap();
    let max = *rss_after.iter().max().unwrap();
    let bound = u64::from(WAVE_AIRCRAFT) * 64;
    assert!(
        last <= warm + bound,
        "RSS grew from {warm} KiB to {last} KiB over the waves: {rss_after:?}"
    );
    println!(
        "soak: {waves} waves of {WAVE_AIRCRAFT} aircraft, {} created; RSS warm {warm} KiB, \
         last {last} KiB, max {max} KiB",
        waves * WAVE_AIRCRAFT
    );
    d.stop().await;
}
