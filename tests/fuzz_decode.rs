//! Property tests: the decoder, the CPR decoder and the tracker take arbitrary input without
//! panicking, and what they accept is well-formed.

use adsb_tracker::decode::cpr::{CprConfig, CprDecoder, PositionFix};
use adsb_tracker::decode::{Cpr, Decoder, DecoderConfig, Message};
use adsb_tracker::feed::RawFrame;
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]

    #[test]
    fn decoder_never_panics(bytes in prop::collection::vec(any::<u8>(), 14), long in any::<bool>(), t in 0.0f64..1e6) {
        let mut d = Decoder::new(DecoderConfig::default());
        let n = if long { 14 } else { 7 };
        let frame = RawFrame::new(t, &bytes[..n], None).unwrap();
        if let Ok(dec) = d.decode(&frame) {
            prop_assert!(dec.icao.0 <= 0xFF_FFFF);
            if let Message::AirbornePosition { cpr, .. } = dec.msg {
                prop_assert!(cpr.lat < 1 << 17 && cpr.lon < 1 << 17);
            }
        }
        prop_assert_eq!(d.stats().frames, 1);
    }

    #[test]
    fn cpr_positions_are_on_the_globe(reports in prop::collection::vec((any::<u32>(), any::<u32>(), any::<bool>(), 0.0f64..5.0, any::<bool>()), 1..40)) {
        let mut c = CprDecoder::new(CprConfig { receiver: Some((43.6, 1.4)), ..CprConfig::default() });
        let mut t = 0.0;
        for (lat, lon, odd, dt, surface) in reports {
            t += dt;
            let cpr = Cpr { lat, lon, odd };
            let fix = if surface { c.surface(t, cpr) } else { c.airborne(t, cpr) };
            if let PositionFix::Accepted { lat_deg, lon_deg, .. } = fix {
                prop_assert!((-90.0..=90.0).contains(&lat_deg), "{}", lat_deg);
                prop_assert!((-180.0..=180.0).contains(&lon_deg), "{}", lon_deg);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Every tracker the daemon can run takes erratic reports (jumps, odd gaps, one-sided
    /// reports, huge and tiny variances) without a panic, a NaN or a non-positive variance.
    #[test]
    fn every_tracker_survives_erratic_reports(
        reports in prop::collection::vec(
            (0.0f64..30.0, -5e4f64..5e4, -5e4f64..5e4, 0.0f64..12e3, -300.0f64..300.0, -300.0f64..300.0, 0u8..3, 0.5f64..1e4),
            1..60)
    ) {
        use adsb_tracker::track::{Measurement, Observed};
        use nalgebra::{Matrix3, Vector3};
        let mut cfg = adsb_tracker::config::Config::default_config().unwrap().tracker;
        for name in adsb_tracker::config::ALGORITHMS {
            cfg.algorithm = name.to_string();
            let mut tr = adsb_tracker::daemon::build_tracker(&cfg);
            let mut t = 0.0;
            for &(dt, e, n, u, ve, vn, kind, var) in &reports {
                t += dt;
                let obs = |v: Vector3<f64>| Observed { value: v, cov: Matrix3::identity() * var, grid: None };
                let m = Measurement {
                    t_s: t,
                    position: (kind != 1).then(|| obs(Vector3::new(e, n, u))),
                    velocity: (kind != 0).then(|| obs(Vector3::new(ve, vn, 0.0))),
                };
                let _ = tr.update(&m);
                if let Some(est) = tr.estimate() {
                    prop_assert!(est.pos_m.iter().chain(est.vel_mps.iter()).all(|x| x.is_finite()), "{name}");
                    prop_assert!(est.pos_cov_m2.diagonal().iter().all(|v| v.is_finite() && *v > 0.0), "{name}");
                    let p = est.mode_probabilities.iter().sum::<f64>();
                    prop_assert!((p - 1.0).abs() < 1e-6, "{name}: probabilities sum to {p}");
                }
            }
        }
    }
}
