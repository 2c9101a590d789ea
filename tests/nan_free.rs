//! Issue 11, row 9: no NaN ever leaves the daemon. CRC-valid DF17 frames with random ME
//! fields (absurd velocities, altitudes, NUC/NACp, CPR values) from a few aircraft go through
//! the daemon's own per-aircraft code, for every tracker it can run, and every number it
//! would publish (state, covariances, predictions) must be finite.

use adsb_tracker::config::{Config, ALGORITHMS};
use adsb_tracker::daemon::aircraft::{Aircraft, AircraftConfig};
use adsb_tracker::daemon::registry::TrackState;
use adsb_tracker::daemon::stats::{Counts, Stats};
use adsb_tracker::decode::cpr::CprConfig;
use adsb_tracker::decode::{Decoder, DecoderConfig, Icao};
use adsb_tracker::feed::RawFrame;
use adsb_tracker::sim::encode::df17;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::collections::HashMap;

/// Random DF17 frames of `aircraft` addresses, at `rate_hz` frames per second of feed time:
/// the type code is drawn so that every kind of message comes (positions, velocities,
/// identification, status), every other ME bit at random.
fn random_frames(n: usize, aircraft: u32, rate_hz: f64, seed: u64) -> Vec<RawFrame> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|i| {
            let icao = Icao(0x40_0000 + rng.gen_range(0..aircraft));
            let tc: u64 = rng.gen_range(0..32);
            let me = (tc << 51) | (rng.gen::<u64>() & ((1 << 51) - 1));
            RawFrame::new(i as f64 / rate_hz, &df17(icao, me), None).unwrap()
        })
        .collect()
}

/// Every number of a published state that must be finite.
fn numbers(s: &TrackState) -> Vec<(&'static str, f64)> {
    let mut v = vec![
        ("t", s.t),
        ("lat", s.lat),
        ("lon", s.lon),
        ("alt_m", s.alt_m),
        ("ve", s.ve),
        ("vn", s.vn),
        ("vu", s.vu),
        ("pos_sigma_m", s.pos_sigma_m),
        ("vel_sigma_mps", s.vel_sigma_mps),
        ("ground_speed_mps", s.ground_speed_mps),
        ("track_deg", s.track_deg),
        ("vertical_rate_mps", s.vertical_rate_mps),
        ("last_seen", s.last_seen),
        ("p_cv", s.mode_probabilities.cv),
        ("p_ca", s.mode_probabilities.ca),
        ("p_ct", s.mode_probabilities.ct),
        ("p_ch", s.mode_probabilities.ch),
        ("p_chca", s.mode_probabilities.chca),
    ];
    for row in s.pos_cov_enu_m2.iter().chain(&s.vel_cov_enu_m2ps2) {
        v.extend(row.iter().map(|&x| ("cov", x)));
    }
    for p in &s.predictions {
        v.extend([
            ("prediction.t", p.t),
            ("prediction.lat", p.lat),
            ("prediction.lon", p.lon),
            ("prediction.alt_m", p.alt_m),
            ("prediction.pos_sigma_m", p.pos_sigma_m),
        ]);
    }
    v
}

/// What one tracker made of the frames.
#[derive(Debug, Default)]
struct Outcome {
    published: u64,
    updates: u64,
    non_finite: u64,
    resets: u64,
    jumps: u64,
    first_bad: Option<String>,
}

/// The daemon's path for each frame: decode, the aircraft's `handle`, then what a task would
/// publish after it (with predictions, as the API serves it).
fn run(frames: &[RawFrame], algorithm: &str) -> Outcome {
    let config = Config::default_config().unwrap();
    let mut tracker_config = config.tracker.clone();
    tracker_config.algorithm = algorithm.to_string();
    let cfg = AircraftConfig {
        cpr: CprConfig {
            receiver: Some((49.0, 2.5)),
            ..CprConfig::default()
        },
        tracker: adsb_tracker::daemon::build_tracker,
        tracker_config,
        duplicate_window_s: config.decode.duplicate_window_s,
    };
    let horizons = config.tracker.prediction_horizons_s.clone();
    let mut decoder = Decoder::new(DecoderConfig {
        fix_single_bit: false,
        recent_address_s: 60.0,
    });
    let stats = Stats::new();
    let mut counts = Counts::default();
    let mut aircraft: HashMap<Icao, Aircraft> = HashMap::new();
    let mut out = Outcome::default();
    for f in frames {
        let Ok(d) = decoder.decode(f) else { continue };
        let ac = aircraft
            .entry(d.icao)
            .or_insert_with(|| Aircraft::new(d.icao, &cfg));
        if !ac.handle(&d, &mut counts) {
            continue;
        }
        let Some(p) = ac.published(&horizons, &mut counts) else {
            continue;
        };
        out.published += 1;
        let s = p.track_state();
        let bad: Vec<_> = numbers(&s)
            .into_iter()
            .filter(|(_, x)| !x.is_finite())
            .collect();
        if !bad.is_empty() {
            out.non_finite += 1;
            out.first_bad
                .get_or_insert_with(|| format!("{d:?}: {bad:?}"));
        }
    }
    counts.flush(&stats);
    let snap = stats.snapshot();
    out.updates = snap.track_updates;
    out.resets = snap.track_resets_nonfinite;
    out.jumps = snap.track_resets_jump;
    out
}

#[test]
fn random_df17_never_publishes_a_non_finite_number() {
    // The 200,000 frames (about 4 s for all trackers in a release build).
    let n = 200_000;
    let frames = random_frames(n, 40, 200.0, 9);
    let mut resets = 0;
    for name in ALGORITHMS {
        let o = run(&frames, name);
        eprintln!("{name}: {o:?}");
        assert_eq!(
            o.non_finite,
            0,
            "{name}: {}",
            o.first_bad.unwrap_or_default()
        );
        // The frames do reach the trackers: absurd but decodable positions and velocities,
        // published nearly every time.
        assert!(o.updates > n as u64 / 20, "{name}: {} updates", o.updates);
        assert!(o.published + o.resets >= o.updates, "{name}: {o:?}");
        // Random positions jump across the globe: each jump the position decoder lets
        // through restarts the track rather than stretching it over continents.
        assert!(o.jumps > o.updates / 2, "{name}: {o:?}");
        resets += o.resets;
    }
    // Absurd velocity reports give some filters absurd accelerations, whose predictions run
    // thousands of kilometres off: those tracks were reset, not published.
    assert!(resets > 0);
}
