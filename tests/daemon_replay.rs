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
        assert_eq!(t["mode"], "CV");
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

    // Filters: a box around the whole US keeps all, one over Europe none; mode=CV keeps all.
    let (_, all) = get_json(d.addr, "/api/v1/tracks?bbox=24,-125,50,-66&mode=CV").await;
    assert_eq!(all["tracks"].as_array().unwrap().len(), 7);
    let (_, none) = get_json(d.addr, "/api/v1/tracks?bbox=40,-5,55,10").await;
    assert_eq!(none["tracks"].as_array().unwrap().len(), 0);
    let (_, none) = get_json(d.addr, "/api/v1/tracks?mode=CT").await;
    assert_eq!(none["tracks"].as_array().unwrap().len(), 0);

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
    let (code, t) = get_json(d.addr, "/api/v1/tracks/393322").await;
    assert_eq!(code, 200, "{t}");
    assert_eq!(t["callsign"], "AFR34ZG");
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
