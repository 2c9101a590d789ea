//! The built-in scenarios fly what their papers (and their own comments) say: states at key
//! times against values worked out by hand from the descriptions in ALGORITHMS.md.

use adsb_tracker::sim::load_scenario;
use adsb_tracker::sim::truth::{Flight, TruthState};

/// The single aircraft of a built-in scenario, ready to fly.
fn flight(name: &str) -> Flight {
    let s = load_scenario(name).unwrap();
    let mut plans = s.plan().unwrap();
    assert_eq!(plans.len(), 1);
    Flight::new(plans.remove(0).trajectory)
}

fn speed_track(s: &TruthState) -> (f64, f64) {
    (
        s.ve_mps.hypot(s.vn_mps),
        s.ve_mps.atan2(s.vn_mps).to_degrees().rem_euclid(360.0),
    )
}

#[test]
fn paper001_jerk_profile() {
    // x velocity at the phase boundaries, from the paper's profile read with a 15 m/s^3 jerk
    // over 60-80 s (see the scenario's comment): v = v0 + a0 T + j T^2 / 2 per phase.
    //   60: -300; 80: -300 + 15*400/2 = 2700 (a = 300); 90: 2700 + 300*10 - 60*100/2 = 2700
    //   (a = -300); 110: 2700 - 300*20 = -3300; 120: -3300 - 300*10 + 10*100/2 = -5800
    //   (a = -200); 140: -5800 - 200*20 = -9800; 150: -9800 - 200*10 + 60*100/2 = -8800
    //   (a = 400); 160: -8800 + 400*10 = -4800; then constant to 200 s.
    let mut f = flight("paper001");
    let want = [
        (0.0, -300.0, "CV"),
        (60.0, -300.0, "CA"),
        (70.0, -300.0 + 15.0 * 100.0 / 2.0, "CA"),
        (80.0, 2700.0, "CA"),
        (90.0, 2700.0, "CA"),
        (110.0, -3300.0, "CA"),
        (120.0, -5800.0, "CA"),
        (140.0, -9800.0, "CA"),
        (150.0, -8800.0, "CA"),
        (159.999, -4800.0 - 400.0 * 0.001, "CA"),
        (160.0, -4800.0, "CV"),
        (200.0, -4800.0, "CV"),
    ];
    for (t, ve, mode) in want {
        let s = f.state_at(t);
        assert!((s.ve_mps - ve).abs() < 1e-6, "t {t}: {} vs {ve}", s.ve_mps);
        assert!((s.vn_mps - 200.0).abs() < 1e-9);
        assert_eq!(
            (s.mode.as_str(), s.alt_m, s.vu_mps),
            (mode, 10_000.0, 0.0),
            "t {t}"
        );
    }
    // x(200) = 10 000 - 18 000 + 14 000 + 32 000 - 6 000 - 46 333.3 - 156 000 - 98 000
    //          - 68 000 - 192 000 = -528 333.3 m along the equator-ish track (y reaches
    //          40 km: 0.36 deg of latitude, where the east scale differs by 2e-5).
    let s = f.state_at(200.0);
    let x_arc = s.lon_deg.to_radians() * (6_378_137.0 + 10_000.0);
    assert!((x_arc + 528_333.3).abs() < 0.0001 * 528_333.3, "{x_arc}");
}

#[test]
fn paper003_turns_to_y_and_back_to_x() {
    let mut f = flight("paper003");
    for (t, track, mode) in [
        (0.0, 90.0, "CV"),
        (399.0, 90.0, "CV"),
        (500.0, 45.0, "CT"),
        (600.0, 0.0, "CV"),
        (609.0, 0.0, "CV"),
        (635.0, 45.0, "CT"),
        (660.0, 90.0, "CV"),
        (900.0, 90.0, "CV"),
    ] {
        let s = f.state_at(t);
        let (v, trk) = speed_track(&s);
        let d = (trk - track + 180.0).rem_euclid(360.0) - 180.0;
        assert!(
            (v - 150.0).abs() < 1e-9 && d.abs() < 1e-9,
            "t {t}: {v} {trk}"
        );
        assert_eq!((s.mode.as_str(), s.alt_m), (mode, 9000.0), "t {t}");
    }
}

#[test]
fn paper000_reverses_and_decelerates() {
    let mut f = flight("paper000");
    let (v, trk) = speed_track(&f.state_at(130.0));
    assert!((v - 250.0).abs() < 1e-9 && (trk - 180.0).abs() < 1e-9); // half way round, right
    assert_eq!(f.state_at(130.0).mode.as_str(), "CT");
    let (v, trk) = speed_track(&f.state_at(210.0));
    assert!((v - 200.0).abs() < 1e-9 && (trk - 270.0).abs() < 1e-9);
    let (v, trk) = speed_track(&f.state_at(300.0));
    assert!((v - 150.0).abs() < 1e-9 && (trk - 270.0).abs() < 1e-9);
}

#[test]
fn departure_and_approach_end_where_their_comments_say() {
    let mut f = flight("departure");
    let s = f.state_at(60.0);
    assert!((s.alt_m - 904.4).abs() < 1e-9 && (speed_track(&s).0 - 110.0).abs() < 1e-9);
    assert_eq!(f.state_at(30.0).mode.as_str(), "CHCA");
    let s = f.state_at(180.0);
    assert!((s.alt_m - 2344.4).abs() < 1e-9);
    let s = f.state_at(480.0);
    let (v, trk) = speed_track(&s);
    assert!(
        (s.alt_m - 2344.4).abs() < 1e-9 && (v - 150.0).abs() < 1e-9 && (trk - 53.0).abs() < 1e-9
    );
    assert_eq!(s.mode.as_str(), "CV");

    let mut f = flight("approach");
    let s = f.state_at(180.0);
    assert!((s.alt_m - 2160.0).abs() < 1e-9);
    let s = f.state_at(440.0);
    // 3-degree slope: vertical rate / ground speed = tan 3 deg (to the 4 decimals given).
    let (v, trk) = speed_track(&s);
    assert!(((-s.vu_mps / v).atan().to_degrees() - 3.0).abs() < 1e-3);
    assert!((trk - 143.0).abs() < 1e-9 && s.mode.as_str() == "CH");
    let s = f.state_at(640.0);
    let (v, trk) = speed_track(&s);
    assert!(
        (s.alt_m - (3000.0 - 840.0 - 200.0 * 5.7649 - 540.0)).abs() < 1e-9,
        "{}",
        s.alt_m
    );
    assert!((v - 74.0).abs() < 1e-9 && (trk - 143.0).abs() < 1e-9 && s.mode.as_str() == "CHCA");
}
