//! `GET /api/v1/tracks/{icao}/history` (issue 12): the bounded trail of AFR34ZG's whole
//! flight, replayed.

mod common;

use adsb_tracker::config::Config;
use common::{get_json, TestDaemon};

/// The trail's points as (t, lat, lon, alt_m), checked for shape.
fn points(v: &serde_json::Value) -> Vec<(f64, f64, f64, f64)> {
    v["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let keys: Vec<&str> = p.as_object().unwrap().keys().map(|k| k.as_str()).collect();
            assert_eq!(keys, ["alt_m", "lat", "lon", "t"]); // (serde_json sorts keys)
            (
                p["t"].as_f64().unwrap(),
                p["lat"].as_f64().unwrap(),
                p["lon"].as_f64().unwrap(),
                p["alt_m"].as_f64().unwrap(),
            )
        })
        .collect()
}

async fn trail(config: Config) -> (Vec<(f64, f64, f64, f64)>, serde_json::Value) {
    let d = TestDaemon::replay("afr34zg-cdg-tls.jsonl", config).await;
    d.wait_replay().await;
    let (code, h) = get_json(d.addr, "/api/v1/tracks/393322/history").await;
    assert_eq!(code, 200, "{h}");
    assert_eq!(h["icao"], "393322");
    let (_, track) = get_json(d.addr, "/api/v1/tracks/393322").await;
    for (path, want) in [
        ("/api/v1/tracks/abcdef/history", 404),
        ("/api/v1/tracks/zzz/history", 400),
        ("/api/v1/tracks/3933221/history", 400),
    ] {
        let (code, v) = get_json(d.addr, path).await;
        assert_eq!(code, want, "{path}: {v}");
        assert!(v["error"].is_string(), "{path}: {v}");
    }
    d.stop().await;
    (points(&h), track)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_default_trail_is_the_last_ten_minutes_at_one_point_a_second() {
    let (p, track) = trail(Config::default_config().unwrap()).await;
    // The flight ends with a long taxi at Toulouse, mostly heard every second: points at
    // least 1 s apart over the last 10 minutes (456 of them: the receiver missed some
    // seconds), oldest first.
    assert!((450..=600).contains(&p.len()), "{}", p.len());
    for w in p.windows(2) {
        assert!(w[1].0 - w[0].0 >= 1.0 - 1e-3, "{:?}", w);
    }
    let (first, last) = (p[0], p[p.len() - 1]);
    assert!(last.0 - first.0 <= 600.0, "{} s", last.0 - first.0);
    assert!(last.0 - first.0 >= 590.0, "{} s", last.0 - first.0);
    // The newest point is the track's estimate, or one at most a second before it.
    let t = track["t"].as_f64().unwrap();
    assert!(t - last.0 >= -1e-3 && t - last.0 < 1.0, "{t} {last:?}");
    assert!(
        (track["lat"].as_f64().unwrap() - last.1).abs() < 1e-3,
        "{track} {last:?}"
    );
    assert!(
        (track["lon"].as_f64().unwrap() - last.2).abs() < 1e-3,
        "{track} {last:?}"
    );
    // The last ten minutes are the approach into Toulouse-Blagnac (43.63 N, 1.37 E) and the
    // taxi: within 50 km of it, from over 1,000 m down to the ground.
    for (t, lat, lon, _) in &p {
        assert!(
            (lat - 43.63).abs() < 0.5 && (lon - 1.37).abs() < 0.5,
            "{t}: {lat},{lon}"
        );
    }
    assert!(first.3 > 1000.0, "{first:?}");
    assert!(last.3 < 300.0, "{last:?}");
    assert!(
        (last.1 - 43.63).abs() < 0.05 && (last.2 - 1.37).abs() < 0.05,
        "{last:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_smaller_trail_keeps_its_bounds() {
    let config =
        Config::from_toml_str("[history]\nwindow_minutes = 1.0\nmax_points = 30\n").unwrap();
    let (p, _) = trail(config).await;
    assert!((25..=30).contains(&p.len()), "{}", p.len());
    for w in p.windows(2) {
        assert!(w[1].0 - w[0].0 >= 2.0 - 1e-3, "{:?}", w);
    }
    assert!(p[p.len() - 1].0 - p[0].0 <= 60.0);
    let config = Config::from_toml_str("[history]\nmax_points = 0\n").unwrap();
    let (p, _) = trail(config).await;
    assert!(p.is_empty());
}
