//! Every tracker the daemon can run, on every real recording, whole file: no NaN, covariances
//! that stay symmetric positive definite, and no track lost to a failed filter step.

use adsb_tracker::config::{Config, ALGORITHMS};
use adsb_tracker::daemon::aircraft::AircraftConfig;
use adsb_tracker::daemon::pipeline::SyncPipeline;
use adsb_tracker::decode::cpr::CprConfig;
use adsb_tracker::decode::DecoderConfig;
use adsb_tracker::eval::bench::read_frames;
use nalgebra::Matrix3;
use std::path::PathBuf;

const RECORDINGS: &[&str] = &[
    "toulouse-sample.beast",
    "us-short-flights.csv",
    "pymodes-2015-03-03.txt",
    "afr34zg-cdg-tls.jsonl",
    "lax-messages.avr.txt",
];

fn check(algorithm: &str, recording: &str) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(recording);
    let frames = read_frames(&path, None).unwrap();
    let mut config = Config::default_config().unwrap();
    config.tracker.algorithm = algorithm.to_string();
    // lax has no timestamps; its real rate is about 270 frames/s.
    let rate = if recording.starts_with("lax") {
        270.0
    } else {
        1000.0
    };
    let frames: Vec<_> = if recording.starts_with("lax") {
        frames
            .iter()
            .enumerate()
            .map(|(i, f)| {
                adsb_tracker::feed::RawFrame::new(i as f64 / rate, f.bytes(), None).unwrap()
            })
            .collect()
    } else {
        frames
    };
    let mut p = SyncPipeline::new(
        DecoderConfig::default(),
        AircraftConfig {
            cpr: CprConfig {
                receiver: None,
                ..CprConfig::default()
            },
            tracker: adsb_tracker::daemon::build_tracker,
            tracker_config: config.tracker.clone(),
            duplicate_window_s: config.decode.duplicate_window_s,
        },
    );
    let mut updates = 0u64;
    for f in &frames {
        let Some(u) = p.push(f) else { continue };
        let Some(s) = u.state else { continue };
        updates += 1;
        let finite = [
            s.lat,
            s.lon,
            s.alt_m,
            s.ve,
            s.vn,
            s.vu,
            s.pos_sigma_m,
            s.vel_sigma_mps,
        ]
        .iter()
        .all(|v| v.is_finite());
        assert!(finite, "{algorithm} on {recording}: non-finite state {s:?}");
        for (name, c) in [
            ("position", s.pos_cov_enu_m2),
            ("velocity", s.vel_cov_enu_m2ps2),
        ] {
            let m = Matrix3::from_fn(|i, j| c[i][j]);
            let asym = (m - m.transpose()).abs().max();
            assert!(
                asym <= 1e-6 * m.abs().max().max(1.0),
                "{algorithm} on {recording}: {name} covariance not symmetric"
            );
            assert!(
                m.cholesky().is_some(),
                "{algorithm} on {recording}: {name} covariance not positive definite: {m}"
            );
        }
    }
    let snap = p.stats().snapshot();
    assert!(updates > 0, "{algorithm} on {recording}: no update");
    assert!(
        !snap.track_errors.contains_key("not_positive_definite")
            && !snap.track_errors.contains_key("non_finite"),
        "{algorithm} on {recording}: {:?}",
        snap.track_errors
    );
}

#[test]
fn every_tracker_on_every_recording() {
    for algorithm in ALGORITHMS {
        for recording in RECORDINGS {
            check(algorithm, recording);
        }
    }
}
