//! The daemon end to end on real recordings: replay, then query the HTTP API over a socket.
//!
//! Expected counts come from an independent decode of the same files with pyModeS 2.x (see
//! each assertion's comment), never from this crate's own output.

mod common;

use adsb_tracker::config::Config;
use common::{get, get_json, TestDaemon};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn us_short_flights_end_to_end() {
    let d = TestDaemon::replay("us-short-flights.csv", Config::default_config().unwrap()).await;
    let stats = d.wait_replay().await;
    // pyModeS: 486 frames, all DF17 with a clean CRC, 9 addresses.
    assert_eq!(stats["frames"], 486);
    assert_eq!(stats["frames_by_df"]["17"], 486);
    assert_eq!(stats["crc_fixed"], 0);
    assert_eq!(stats["tracks_created"], 9);
    assert_eq!(stats["channel_drops"], 0);

    let (code, tracks) = get_json(d.addr, "/api/v1/tracks").await;
    assert_eq!(code, 200);
    let tracks = tracks["tracks"].as_array().unwrap();
    // pyModeS: 7 of the 9 aircraft send an even and an odd airborne position within 10 s.
    assert_eq!(tracks.len(), 7, "{tracks:?}");
    for t in tracks {
        for key in [
            "t",
            "icao",
            "lat",
            "lon",
            "alt_m",
            "ve",
            "vn",
            "vu",
            "mode",
            "filter",
            "pos_sigma_m",
            "diverging",
            "callsign",
            "ground_speed_mps",
            "track_deg",
            "vertical_rate_mps",
            "mode_probabilities",
            "messages",
            "last_seen",
        ] {
            assert!(t.get(key).is_some(), "track lacks {key}: {t}");
        }
        assert!(
            ["CV", "CA", "CT", "CH", "CHCA"].contains(&t["mode"].as_str().unwrap()),
            "{t}"
        );
        let sigma = t["pos_sigma_m"].as_f64().unwrap();
        assert!(sigma > 0.0 && sigma < 200.0, "pos_sigma_m {sigma}");
        // The recording is over the United States.
        let (lat, lon) = (t["lat"].as_f64().unwrap(), t["lon"].as_f64().unwrap());
        assert!(
            (24.0..50.0).contains(&lat) && (-125.0..-66.0).contains(&lon),
            "{lat},{lon}"
        );
    }

    // One aircraft by address, and the error cases.
    let icao = tracks[0]["icao"].as_str().unwrap().to_string();
    let (code, one) = get_json(d.addr, &format!("/api/v1/tracks/{icao}")).await;
    assert_eq!(code, 200);
    assert_eq!(one["icao"], icao.as_str());
    let (code, one_upper) =
        get_json(d.addr, &format!("/api/v1/tracks/{}", icao.to_uppercase())).await;
    assert_eq!(code, 200);
    assert_eq!(one_upper["icao"], icao.as_str());
    for (path, want) in [
        ("/api/v1/tracks/000001", 404),
        ("/api/v1/tracks/zzzzzz", 400),
        ("/api/v1/tracks/12345", 400),
        ("/api/v1/tracks/1234567", 400),
        ("/api/v1/tracks?bbox=1,2,3", 400),
        ("/api/v1/tracks?bbox=a,b,c,d", 400),
        ("/api/v1/tracks?mode=XX", 400),
        ("/api/v1/tracks?colour=red", 400),
        ("/api/v1/nothing", 404),
    ] {
        let (code, body) = get_json(d.addr, path).await;
        assert_eq!(code, want, "{path}: {body}");
        assert!(
            body["error"].as_str().is_some_and(|e| !e.is_empty()),
            "{path}: {body}"
        );
    }

    // Predictions at +30/60/120 s: a CV track moves ground_speed * dt along its track, and
    // its uncertainty grows with the horizon.
    let (code, p) = get_json(d.addr, &format!("/api/v1/tracks/{icao}/prediction")).await;
    assert_eq!(code, 200, "{p}");
    let preds = p["predictions"].as_array().unwrap();
    assert_eq!(preds.len(), 3);
    let (lat0, lon0) = (one["lat"].as_f64().unwrap(), one["lon"].as_f64().unwrap());
    let speed = one["ground_speed_mps"].as_f64().unwrap();
    let mut last_sigma = one["pos_sigma_m"].as_f64().unwrap();
    for (pr, dt) in preds.iter().zip([30.0, 60.0, 120.0]) {
        assert_eq!(pr["dt_s"].as_f64().unwrap(), dt);
        let (lat, lon) = (pr["lat"].as_f64().unwrap(), pr["lon"].as_f64().unwrap());
        // Equirectangular distance is exact enough over a few km.
        let dn = (lat - lat0).to_radians() * 6_371_000.0;
        let de = (lon - lon0).to_radians() * 6_371_000.0 * lat0.to_radians().cos();
        let moved = dn.hypot(de);
        // Straight-line modes move speed * dt; a turn moves along a chord, an acceleration
        // more or less: only bound those.
        if ["CV", "CH"].contains(&one["mode"].as_str().unwrap()) {
            assert!(
                (moved - speed * dt).abs() < 0.01 * speed * dt + 5.0,
                "dt {dt}: {moved} m vs {}",
                speed * dt
            );
        } else {
            assert!(
                moved > 0.3 * speed * dt && moved < 1.6 * speed * dt,
                "dt {dt}: {moved} m"
            );
        }
        let sigma = pr["pos_sigma_m"].as_f64().unwrap();
        assert!(
            sigma > last_sigma,
            "sigma must grow: {sigma} after {last_sigma}"
        );
        last_sigma = sigma;
    }
    let (code, _) = get_json(d.addr, "/api/v1/tracks/000001/prediction").await;
    assert_eq!(code, 404);
    let (code, _) = get_json(d.addr, "/api/v1/tracks/xyz/prediction").await;
    assert_eq!(code, 400);

    // Filters: a box around the whole US keeps all, one over Europe none; each mode keeps
    // exactly the tracks with that label.
    let (_, all) = get_json(
        d.addr,
        "/api/v1/tracks?bbox=24,-125,50,-66&mode=CV,CA,CT,CH,CHCA",
    )
    .await;
    assert_eq!(all["tracks"].as_array().unwrap().len(), 7);
    let (_, none) = get_json(d.addr, "/api/v1/tracks?bbox=40,-5,55,10").await;
    assert_eq!(none["tracks"].as_array().unwrap().len(), 0);
    for mode in ["CV", "CA", "CT", "CH", "CHCA"] {
        let want = tracks.iter().filter(|t| t["mode"] == mode).count();
        let (_, got) = get_json(d.addr, &format!("/api/v1/tracks?mode={mode}")).await;
        let got = got["tracks"].as_array().unwrap();
        assert_eq!(got.len(), want, "mode={mode}");
        assert!(got.iter().all(|t| t["mode"] == mode));
    }

    // Health and metrics.
    let (code, health) = get_json(d.addr, "/healthz").await;
    assert_eq!(code, 200);
    assert_eq!(health["status"], "ok");
    let (code, metrics) = get(d.addr, "/metrics").await;
    assert_eq!(code, 200);
    assert!(metrics.contains("adsb_frames_total 486"), "{metrics}");
    assert!(metrics.contains("adsb_tracks_created_total 9"), "{metrics}");

    let summary = d.stop().await;
    assert_eq!(summary.stats.frames, 486);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn afr34zg_whole_flight() {
    let d = TestDaemon::replay("afr34zg-cdg-tls.jsonl", Config::default_config().unwrap()).await;
    let stats = d.wait_replay().await;
    // pyModeS: 57,793 frames: DF0 15,691, DF4 4,296, DF5 1,031, DF16 810, DF17 15,573,
    // DF20 7,770, DF21 12,622; one aircraft, 393322.
    assert_eq!(stats["frames"], 57_793);
    for (df, n) in [
        ("0", 15_691),
        ("4", 4_296),
        ("5", 1_031),
        ("16", 810),
        ("17", 15_573),
        ("20", 7_770),
        ("21", 12_622),
    ] {
        assert_eq!(stats["frames_by_df"][df], n, "DF{df}");
    }
    assert_eq!(stats["tracks_created"], 1);
    // The recording merges receivers: 388 airborne positions, 119 surface positions and
    // 334 velocity reports arrive twice, the copies microseconds apart (the same DF17 bytes
    // within 50 ms, counted from the file with a script). Each is used once.
    assert_eq!(stats["duplicate_reports"], 388 + 119 + 334);
    let (code, t) = get_json(d.addr, "/api/v1/tracks/393322").await;
    assert_eq!(code, 200, "{t}");
    assert_eq!(t["callsign"], "AFR34ZG");
    // Its bursts of stale positions (one to four 0.5-0.8 s behind the flight, every 16-48 s:
    // `track::outlier`): the hybrid sets aside about 150 positions, counted on the
    // track and over the daemon alike, and each is still an accepted position.
    let outliers = t["outlier_positions"].as_u64().unwrap();
    assert_eq!(stats["outlier_positions"].as_u64(), Some(outliers));
    assert!((120..=200).contains(&outliers), "{outliers}");
    assert!(outliers * 20 < t["positions_accepted"].as_u64().unwrap());
    // Every frame of the file is this aircraft's, and none comes from an unknown address
    // (the DF0/4/5/16/20/21 replies are admitted because DF17 was heard first).
    assert_eq!(
        t["messages"].as_u64().unwrap(),
        57_793
            - stats["frames_skipped"]
                .as_object()
                .map_or(0, |m| m.values().map(|v| v.as_u64().unwrap()).sum())
    );
    // The flight ends at Toulouse-Blagnac (43.629 N, 1.364 E), on the ground.
    let (lat, lon) = (t["lat"].as_f64().unwrap(), t["lon"].as_f64().unwrap());
    assert!(
        (lat - 43.629).abs() < 0.03 && (lon - 1.364).abs() < 0.04,
        "{lat},{lon}"
    );
    d.stop().await;
}

/// Runs a replay of `path` to its end without HTTP and returns the final stats.
async fn replay_to_end(path: &std::path::Path) -> adsb_tracker::daemon::RunSummary {
    use adsb_tracker::app::{run, RunOptions};
    use adsb_tracker::daemon::source::{Replay, ReplayData};
    use adsb_tracker::daemon::Source;
    let config = Config::default_config().unwrap();
    let opts = RunOptions {
        source: Source::Replay(Replay {
            data: ReplayData::File(path.to_path_buf()),
            format: Some(adsb_tracker::feed::Format::Beast),
            speed: 0.0,
            loop_: false,
            nominal_rate_hz: 1000.0,
            fit_untimed_clock: true,
            loop_gap_s: 0.0,
            progress: false,
        }),
        listener: None,
        tracks_out: None,
        exit_at_end: true,
    };
    run(config, opts, tokio_util::sync::CancellationToken::new())
        .await
        .unwrap()
}

/// Byte ranges of each Beast frame (walking the 0x1a escapes, independently of the parser).
fn beast_frames(data: &[u8]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut i = 0;
    while i + 1 < data.len() {
        let n = match data[i + 1] {
            b'1' => 2,
            b'2' => 7,
            _ => 14,
        };
        let mut j = i + 2;
        for _ in 0..(7 + n) {
            j += if data[j] == 0x1a { 2 } else { 1 };
        }
        out.push(i..j);
        i = j;
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_corruption_and_a_truncated_tail_lose_no_good_frame() {
    use rand::{Rng, SeedableRng};
    let clean = std::fs::read(common::fixture("toulouse-sample.beast")).unwrap();
    let dir = std::env::temp_dir().join(format!("adsb-garbage-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let clean_path = dir.join("clean.beast");
    std::fs::write(&clean_path, &clean).unwrap();
    let reference = replay_to_end(&clean_path).await.stats;
    assert_eq!(reference.frames, 239);

    // Junk (never 0x1a) between frames, one bit flipped in the data of every 3rd long
    // frame whose payload has no 0x1a near the flip, and the last frame cut in half.
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let frames = beast_frames(&clean);
    let mut dirty = Vec::new();
    let mut junk = 0u64;
    let mut flipped = 0u64;
    let mut long = 0u64;
    for (k, r) in frames.iter().enumerate() {
        let mut f = clean[r.clone()].to_vec();
        let last = k + 1 == frames.len();
        // Flip a bit of the ME field (byte 12 of the frame, after type, counter and signal),
        // only in frames without escapes, so the framing stays the same.
        let is_long = f[1] == b'3';
        long += u64::from(is_long);
        if is_long && long % 3 == 0 && f.len() == 2 + 6 + 1 + 14 && f[2 + 7 + 8] != 0x1a {
            f[2 + 7 + 8] ^= 0x04;
            if f[2 + 7 + 8] != 0x1a {
                flipped += 1;
            } else {
                f[2 + 7 + 8] ^= 0x04;
            }
        }
        if last {
            f.truncate(f.len() / 2);
        }
        dirty.extend_from_slice(&f);
        if !last {
            let n = rng.gen_range(0..20);
            for _ in 0..n {
                let b: u8 = rng.gen();
                dirty.push(if b == 0x1a { 0x1b } else { b });
            }
            junk += n;
        }
    }
    let dirty_path = dir.join("dirty.beast");
    std::fs::write(&dirty_path, &dirty).unwrap();
    let got = replay_to_end(&dirty_path).await;
    let parse = got.replay.unwrap();
    assert_eq!(parse.frames, 238, "every complete frame parsed");
    assert_eq!(parse.garbage_bytes, junk, "garbage counted exactly");
    assert!(parse.truncated_tail_bytes > 0);
    let s = got.stats;
    assert_eq!(s.frames, 238);
    // Each flipped DF17 frame was repaired by the single-bit correction (on by default).
    assert!(flipped >= 5, "test flips too few frames: {flipped}");
    let df17_flipped = s.crc_fixed;
    assert!(
        df17_flipped > 0 && df17_flipped <= flipped,
        "{df17_flipped} of {flipped}"
    );
    // Every good frame was used: the aircraft and the decoded DF counts are those of the clean
    // run, minus what the cut frame carried.
    assert_eq!(s.tracks_created, reference.tracks_created);
    let total = |m: &std::collections::BTreeMap<String, u64>| m.values().sum::<u64>();
    assert_eq!(total(&s.frames_by_df), total(&reference.frames_by_df) - 1);
    assert!(s.positions_accepted + 1 >= reference.positions_accepted);
    std::fs::remove_dir_all(&dir).ok();
}
