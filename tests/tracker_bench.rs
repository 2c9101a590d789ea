//! The default tracker (paper 002's hybrid with paper 000's suppressor) on the evaluation
//! bench and on a real flight, against the bounds its issue sets. Monte Carlo runs are fewer
//! than the 100 of docs/evaluation.md to keep the suite short; the bounds hold with margin.

use adsb_tracker::config::Config;
use adsb_tracker::eval::bench::{monte_carlo, read_frames, track_frames};
use adsb_tracker::eval::score::{chi2_band_95, offset_m, Scores};
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

fn run(scenario: &str, trackers: &[&str], runs: u64) -> Vec<Scores> {
    run_with(scenario, trackers, runs, &Config::default_config().unwrap())
}

fn run_with(scenario: &str, trackers: &[&str], runs: u64, config: &Config) -> Vec<Scores> {
    let sc = adsb_tracker::sim::load_scenario(scenario).unwrap();
    let names: Vec<String> = trackers.iter().map(|s| s.to_string()).collect();
    let dir = std::env::temp_dir().join(format!("adsb-tb-{scenario}-{}", std::process::id()));
    let exp = monte_carlo(&sc, &names, runs, 1, config, &dir).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    exp.results.into_iter().map(|r| r.scores).collect()
}

fn rmse(s: &Scores, group: &str) -> f64 {
    s.estimates[group].pos_rmse().unwrap()
}

#[test]
fn paper002_hybrid_against_kalman_and_imm() {
    let runs = 20;
    let r = run("paper002", &["hybrid", "kalman-cv", "imm"], runs);
    let (hy, kf, imm) = (&r[0], &r[1], &r[2]);
    let report = format!(
        "straight: hybrid {:.2} kf {:.2} imm {:.2}; turns: hybrid {:.2} kf {:.2} imm {:.2}",
        rmse(hy, "CV"),
        rmse(kf, "CV"),
        rmse(imm, "CV"),
        rmse(hy, "CT"),
        rmse(kf, "CT"),
        rmse(imm, "CT")
    );
    // Straight legs: at most the CV Kalman filter's error, and the IMM's: with a velocity
    // measured every second both sit on the same floor (10.322 m each over 100 runs; the
    // Kalman filter's 10.595 m is its lag after the turns). The hybrid learns each
    // aircraft's measurement noise (`track::noise`); here the reports declare exactly the
    // noise they carry, so learning can only scatter about it: 0.7 % on these 20 runs
    // (10.26 m against 10.19 m), the price of what it gains where declarations are wrong.
    assert!(rmse(hy, "CV") <= rmse(kf, "CV"), "{report}");
    assert!(rmse(hy, "CV") <= 1.01 * rmse(imm, "CV"), "{report}");
    // Turns: within 5 % of the IMM and clearly below the Kalman filter.
    assert!(rmse(hy, "CT") <= 1.05 * rmse(imm, "CT"), "{report}");
    assert!(rmse(hy, "CT") < 0.8 * rmse(kf, "CT"), "{report}");
    // Labels: every turn onset found, within 2 s on average (1.80 s measured over 100 runs
    // with NACv 2 velocity noise at 70 m/s; the paper's RMIMM needed about 12 s), almost no
    // false switch.
    assert_eq!(hy.missed_onsets, 0);
    let delay = hy.mean_detection_delay_s().unwrap();
    eprintln!("{report}; mean detection delay {delay:.2} s");
    assert!(delay <= 2.0, "mean detection delay {delay} s");
    let fs = hy.false_switches_per_100().unwrap();
    // 0.38 over 100 runs: the first-report turn test (`GateParams::first_report_turn_sigmas`)
    // labels a straight report a turn about 0.37 % of the time, for one report, which is
    // what labelling half of the onsets on their first report costs (0.07 before it; 0.28
    // before the gate learned the vertical rate's noise). The bound is 1.
    assert!(fs <= 0.7, "{fs} false switches per 100 straight updates");
    // Turns alone (every onset here is a turn): 1.45 s over 100 runs with the first-report
    // test, 1.72 s without.
    let (turn, _, _) = hy.mean_delay_to_s("CT");
    assert!(turn.unwrap() <= 1.6, "turn onset {turn:?} s");
    // And their ends, back to CV: 1.87 s over 100 runs with the turn's end test
    // (`GateParams::turn_end_sigmas`), 3.43 s without.
    let (end, ends, missed) = hy.mean_delay_to_s("CV");
    assert_eq!((ends, missed), (2 * runs as usize, 0));
    assert!(end.unwrap() <= 2.3, "turn end {end:?} s");
    assert!(hy.label_accuracy().unwrap() > 0.95);
    // Consistency: the average position NEES inside the 95 % band of 2 dof over all samples
    // of one run at a time (a wide band: samples within a run are correlated).
    let anees = hy.estimates["all"].anees_pos().unwrap();
    let (lo, hi) = chi2_band_95(2.0, runs as f64);
    assert!(
        anees > lo && anees < hi,
        "ANEES {anees} outside [{lo}, {hi}]"
    );
    // The track's own claim, checked where the noise is the one it assumes: the published
    // windowed NIS (horizontal components, `track::nis`) inside its 95 % band on about
    // 93 % of the updates (92.8 % over 100 runs; 82 % when the quantised vertical was
    // counted), and `diverging` never on (0 of 200 k updates over 100 runs).
    let nis = hy.nis_in_band_pct().unwrap();
    assert!((88.0..=98.0).contains(&nis), "NIS in band {nis} %");
    assert_eq!(hy.diverging_updates, 0);
}

#[test]
fn departure_and_approach_labels() {
    for scenario in ["departure", "approach"] {
        let r = run(scenario, &["hybrid"], 10);
        let s = &r[0];
        let acc = s.label_accuracy().unwrap();
        let fs = s.false_switches_per_100().unwrap();
        eprintln!("{scenario}: labels right {acc:.4}, false switches {fs:.2} per 100");
        // 100 runs: departure 93.2 %, approach 95.5 % (92.0 % and 93.7 % before the gate's
        // acceleration onset test and learned vertical noise).
        let floor = if scenario == "departure" { 0.92 } else { 0.94 };
        assert!(acc >= floor, "{scenario}: label accuracy {acc}");
        // 100 runs: 0.27 and 0.32 (the first-report turn test's one-report labels; 0.05
        // and 0.07 without it).
        assert!(fs <= 0.6, "{scenario}: {fs} false switches per 100");
        // The windowed NIS in its band: 94.4 % and 93.7 % over 100 runs.
        let nis = s.nis_in_band_pct().unwrap();
        assert!(
            (90.0..=98.0).contains(&nis),
            "{scenario}: NIS in band {nis} %"
        );
        // Turns are labelled within 1.5 s on average (100 runs: departure 1.24 s at 2 deg/s,
        // approach 0.92 s at 3 deg/s; 1.46 and 1.10 s without the first-report test); the accelerations'
        // onsets and ends take 5-8 s, at the data's limit (docs/evaluation.md).
        let (turn, _, missed) = s.mean_delay_to_s("CT");
        assert_eq!(missed, 0, "{scenario}");
        assert!(turn.unwrap() <= 1.6, "{scenario}: turn onset {turn:?} s");
        // Every mode the scenario flies is labelled correctly somewhere.
        for (truth, row) in &s.confusion {
            assert!(
                row.get(truth).copied().unwrap_or(0) > 0,
                "{scenario}: {truth} never labelled: {row:?}"
            );
        }
        assert!(
            s.confusion.len() >= 4,
            "{scenario}: {:?}",
            s.confusion.keys()
        );
    }
}

/// The real AFR34ZG flight (CDG -> TLS): labels against the vertical rate decoded
/// independently by rs1090 in the fixture.
#[test]
fn real_flight_labels_follow_the_vertical_profile() {
    let path = fixture("afr34zg-cdg-tls.jsonl");
    let mut reference: Vec<(f64, f64)> = Vec::new();
    for line in std::fs::read_to_string(&path).unwrap().lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        if let (Some(t), Some(vr)) = (v["timestamp"].as_f64(), v["vertical_rate"].as_f64()) {
            reference.push((t, vr));
        }
    }
    reference.sort_by(|a, b| a.0.total_cmp(&b.0));
    let frames = read_frames(&path, None).unwrap();
    let mut config = Config::default_config().unwrap();
    config.receiver = None;
    let trace = track_frames(&frames, &config, "hybrid");
    let est = trace.estimates.values().next().unwrap();
    let (mut climb, mut climb_ch, mut level, mut level_cv) = (0, 0, 0, 0);
    for e in est {
        let i = reference.partition_point(|r| r.0 <= e.t);
        let Some(&(tr, vr_fpm)) = i.checked_sub(1).and_then(|i| reference.get(i)) else {
            continue;
        };
        if e.t - tr > 5.0 {
            continue;
        }
        use adsb_tracker::track::FlightMode::*;
        if vr_fpm.abs() > 1000.0 {
            climb += 1;
            climb_ch += usize::from(matches!(e.mode, Ch | Chca));
        } else if vr_fpm.abs() < 100.0 && e.alt_m > 9000.0 {
            level += 1;
            level_cv += usize::from(e.mode == Cv);
        }
    }
    let climb_frac = climb_ch as f64 / climb as f64;
    let level_frac = level_cv as f64 / level as f64;
    eprintln!(
        "AFR34ZG: CH/CHCA on {climb_ch} of {climb} estimates in climbs and descents > 1000 \
         ft/min, CV on {level_cv} of {level} in level cruise above 9000 m"
    );
    assert!(
        climb > 1000 && level > 500,
        "{climb} climbing, {level} cruising estimates"
    );
    assert!(
        climb_frac >= 0.80,
        "CH/CHCA in climbs and descents: {climb_frac}"
    );
    assert!(level_frac >= 0.95, "CV in level cruise: {level_frac}");
}

/// Horizontal error of each estimate against the truth at its time, as (time since the
/// first truth sample, error m).
fn errors_over_time(
    truth: &adsb_tracker::eval::score::TruthTrack,
    estimates: &[adsb_tracker::eval::score::EstimateSample],
) -> Vec<(f64, f64)> {
    let t0 = truth.samples().first().map_or(0.0, |s| s.t);
    estimates
        .iter()
        .filter_map(|e| {
            let (d, _) = offset_m(&truth.at(e.t)?, e.lat, e.lon, e.alt_m);
            Some((e.t - t0, d.norm()))
        })
        .collect()
}

/// Paper 000 as the paper has it, positions only (radar plots): the 4 g reversal at 120 s
/// makes a filter lose the aircraft; the suppressor keeps the peak error to at most half of
/// what it is without, and the track recovers. Through the daemon's own pipeline, the
/// default tracker with and without `[tracker.divergence] suppress`.
#[test]
fn paper000_positions_suppressor_halves_the_peak_and_recovers() {
    use adsb_tracker::eval::io::{parse_truth, read};
    let sc = adsb_tracker::sim::load_scenario("paper000-positions").unwrap();
    let dir = std::env::temp_dir().join(format!("adsb-tb-p000-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let with = Config::default_config().unwrap();
    let without = Config::from_toml_str("[tracker.divergence]\nsuppress = false\n").unwrap();
    let runs = 10;
    let (mut peak_on, mut peak_off) = (0.0, 0.0);
    let (mut after_on, mut after_off, mut tail_on) = (0.0, 0.0, 0.0);
    for seed in 1..=runs {
        let sum = adsb_tracker::sim::simulate(&sc, seed, &dir.join(format!("r{seed}"))).unwrap();
        let frames = read_frames(&sum.beast_path, None).unwrap();
        let truth = parse_truth(&read(&sum.truth_path).unwrap(), "truth").unwrap();
        let truth = truth.values().next().unwrap();
        let run = |config: &Config| {
            let trace = track_frames(&frames, config, "hybrid");
            errors_over_time(truth, trace.estimates.values().next().unwrap())
        };
        // From the manoeuvre on (the start is initiation); the straight minute after the
        // reversal; the last minute, 20 s after the deceleration ended.
        let peak = |e: &[(f64, f64)]| {
            e.iter()
                .filter(|p| p.0 >= 120.0)
                .map(|p| p.1)
                .fold(0.0, f64::max)
        };
        let mean_over = |e: &[(f64, f64)], from: f64, to: f64| {
            let v: Vec<f64> = e
                .iter()
                .filter(|p| p.0 >= from && p.0 < to)
                .map(|p| p.1)
                .collect();
            v.iter().sum::<f64>() / v.len().max(1) as f64
        };
        let (on, off) = (run(&with), run(&without));
        peak_on += peak(&on) / runs as f64;
        peak_off += peak(&off) / runs as f64;
        after_on += mean_over(&on, 140.0, 200.0) / runs as f64;
        after_off += mean_over(&off, 140.0, 200.0) / runs as f64;
        tail_on += mean_over(&on, 240.0, 300.0) / runs as f64;
    }
    std::fs::remove_dir_all(&dir).ok();
    eprintln!(
        "paper000-positions ({runs} runs): mean peak error from the manoeuvre on {peak_on:.1} m \
         with the suppressor, {peak_off:.1} m without; mean error over the minute after the \
         reversal {after_on:.1} m vs {after_off:.1} m; over the last minute {tail_on:.1} m"
    );
    assert!(peak_on <= 0.5 * peak_off, "{peak_on} vs {peak_off}");
    // Recovered: sooner than without, and back at the filtered-position floor at the end
    // (raw reports: sigma 12.3 m per axis).
    assert!(after_on < after_off, "{after_on} vs {after_off}");
    assert!(tail_on < 15.0, "{tail_on}");
}

/// Issue 10 on the simulator: noise the declarations do not describe. The hybrid learns each
/// aircraft's noise (`track::noise`); with `learn_noise = false` it takes the declarations
/// literally, which is the "before" of docs/evaluation.md (100 runs there).
#[test]
fn learned_noise_on_undeclared_and_correlated_errors() {
    let runs = 20;
    let literal = Config::from_toml_str("[tracker.hybrid]\nlearn_noise = false\n").unwrap();
    let learned = Config::default_config().unwrap();
    let (lo, hi) = chi2_band_95(2.0, runs as f64);
    let anees = |s: &Scores| s.estimates["all"].anees_pos().unwrap();
    let delay = |s: &Scores| s.mean_detection_delay_s().unwrap();
    // The scenario taken literally and learned, and a line saying both.
    let both = |scenario: &str| {
        let before = run_with(scenario, &["hybrid"], runs, &literal).remove(0);
        let after = run_with(scenario, &["hybrid"], runs, &learned).remove(0);
        let report = format!(
            "{scenario}: ANEES {:.2} -> {:.2} [{lo:.2}, {hi:.2}], onset {:.2} -> {:.2} s, \
             RMSE {:.2} -> {:.2} m",
            anees(&before),
            anees(&after),
            delay(&before),
            delay(&after),
            rmse(&before, "all"),
            rmse(&after, "all")
        );
        (before, after, report)
    };

    // No accuracy declared: R from NUCp's 38 m against a 15 m truth, NACv 1's bound against
    // 0.6 m/s. Taken literally the covariance is ~7x too large and the turn is seen late.
    let (before, after, report) = both("turns-undeclared");
    let (before, after) = (&before, &after);
    eprintln!("{report}");
    assert!(anees(before) < 0.4, "{report}");
    assert!(anees(after) > lo && anees(after) < hi, "{report}");
    assert!(delay(after) <= 1.5, "{report}");
    assert!(rmse(after, "all") < rmse(before, "all"), "{report}");
    assert_eq!(after.missed_onsets, 0);
    assert!(after.false_switches_per_100().unwrap() <= 1.0, "{report}");
    // An undeclared block's fall-back R is a weak prior (`NoiseParams::undeclared_prior_weight`):
    // the velocity's noise, a fiftieth of NACv 1's bound, is learned, not held at 5x by the
    // prior (velocity ANEES 1.33, windowed NIS in band 81 % over 100 runs; 0.96 and 68 %
    // with the declared prior's weight).
    let vel = after.estimates["all"].anees_vel().unwrap();
    assert!(vel > 1.1, "velocity ANEES {vel}");
    let nis = after.nis_in_band_pct().unwrap();
    assert!(nis >= 75.0, "windowed NIS in band {nis} %");

    // NACp 9 declared, white 5 m plus a Gauss-Markov bias of 8 m / 60 s: taken literally the
    // filter averages the bias away in its covariance (ANEES ~20); the declared variance the
    // white noise leaves unexplained, published as correlated error, brings it near 2.
    let (before, after, report) = both("turns-correlated");
    let (before, after) = (&before, &after);
    eprintln!("{report}");
    assert!(anees(before) > 10.0, "{report}");
    assert!((1.0..3.0).contains(&anees(after)), "{report}");
    assert!(delay(after) <= 1.5, "{report}");
    assert!(rmse(after, "all") <= 1.02 * rmse(before, "all"), "{report}");
    assert!(after.false_switches_per_100().unwrap() <= 1.0, "{report}");
}

/// Issue 10's stand-in for a real high-rate airliner (NACp 10 declared, correlated GNSS
/// error, every frame heard): its turns are labelled within a second, its descents within
/// two, and what takes longer is told apart by kind (`Scores::mean_delay_to_s`).
#[test]
fn airliner_turns_are_labelled_within_a_second() {
    let r = run("airliner-nacp10", &["hybrid"], 10);
    let s = &r[0];
    let by = |mode: &str| s.mean_delay_to_s(mode);
    let report = format!(
        "turn {:?}, descent {:?}, decelerating descent {:?}, ends {:?}",
        by("CT"),
        by("CH"),
        by("CHCA"),
        by("CV")
    );
    eprintln!("airliner-nacp10: {report}");
    // 100 runs: turns 0.51 s (200 onsets; 0.61 s without the first-report turn test),
    // descents 1.58 s, the deceleration within the descent 4.98 s (0.3 m/s² against NACv 2's
    // ground speed: the data's own limit, docs/evaluation.md), the turns' ends 0.83 s (1.76 s
    // without the turn's end test).
    let (turn, turns, missed) = by("CT");
    assert_eq!((turns, missed), (20, 0), "{report}");
    assert!(turn.unwrap() <= 1.0, "{report}");
    let (descent, _, missed) = by("CH");
    assert_eq!(missed, 0, "{report}");
    assert!(descent.unwrap() <= 2.5, "{report}");
    let (decel, _, missed) = by("CHCA");
    assert_eq!(missed, 0, "{report}");
    assert!(decel.unwrap() <= 8.0, "{report}");
    let (end, ends, missed) = by("CV");
    assert_eq!((ends, missed), (20, 0), "{report}");
    assert!(end.unwrap() <= 1.3, "{report}");
    // The headline mean is over every onset, the slow deceleration included.
    let all = s.mean_detection_delay_s().unwrap();
    assert!(all > turn.unwrap(), "{report}; all onsets {all}");
    assert!(s.false_switches_per_100().unwrap() <= 1.0, "{report}");
}

/// Velocity reports a second older than their frames, as AFR34ZG's are (`eval::latency`):
/// in paper 002's turns (3°/s at 70 m/s) each points 3° behind, 3.7 m/s off, and the
/// hybrid's turn error grows sixfold (100 runs: 9.7 → 60.6 m, ANEES 1.78 → 24.7). With
/// `tracker.imm.velocity_lag_s` set to the lag, its CT modes turn each report on by the turn
/// over the lag (`imm::aged_for_turn`): 13.0 m, ANEES 2.06. The labels wait for the late
/// velocities either way (turn onset 2.5 s).
#[test]
fn velocity_reports_a_second_late_are_turned_on() {
    let mut sc = adsb_tracker::sim::load_scenario("paper002").unwrap();
    sc.settings.velocity_validity_offset_s = 1.0;
    let runs = 10;
    let mut scores = Vec::new();
    for lag_s in [0.0, 1.0] {
        let mut config = Config::default_config().unwrap();
        config.tracker.imm.velocity_lag_s = lag_s;
        let dir = std::env::temp_dir().join(format!("adsb-tb-lag{lag_s}-{}", std::process::id()));
        let exp = monte_carlo(&sc, &["hybrid".to_string()], runs, 1, &config, &dir).unwrap();
        std::fs::remove_dir_all(&dir).ok();
        scores.extend(exp.results.into_iter().map(|r| r.scores));
    }
    let (late, turned) = (&scores[0], &scores[1]);
    let report = format!(
        "turn RMSE {:.1} -> {:.1} m, straight {:.2} -> {:.2} m, ANEES {:.2} -> {:.2}",
        rmse(late, "CT"),
        rmse(turned, "CT"),
        rmse(late, "CV"),
        rmse(turned, "CV"),
        late.estimates["all"].anees_pos().unwrap(),
        turned.estimates["all"].anees_pos().unwrap(),
    );
    eprintln!("{report}");
    assert!(rmse(late, "CT") > 40.0, "{report}");
    assert!(rmse(turned, "CT") < 16.0, "{report}");
    assert!(rmse(turned, "CV") <= rmse(late, "CV"), "{report}");
    let anees = turned.estimates["all"].anees_pos().unwrap();
    assert!((1.5..=3.0).contains(&anees), "{report}");
}

/// Position reports out of their time (`track::outlier`): the airliner of `airliner-nacp10`
/// with AFR34ZG's bursts of stale positions (two reports 0.6 s behind the flight, about every
/// 48 s: `airliner-stale`). Used, each burst pulls the track 140 m back and its covariance
/// claims nothing of it (100 runs: hybrid position RMSE 10.2 m, ANEES 9.5; imm 10.1 m,
/// ANEES 8.5); set aside while the velocity reports vouch for a straight flight, the tracks
/// are back near the burst-free scenario's (7.7 m, ANEES 5.0; 7.8 m, 5.1; airliner-nacp10
/// 7.1 m, 4.3 and 7.2 m, 4.4), and the windowed NIS is in its band 82 % and 58 % of the
/// time (airliner-nacp10: 86 % and 62 %). Before the consider term's white share was
/// learned from successive positions (`track::noise`) and the hybrid's CV filter took the
/// steady-flight process noise, the bursts used gave ANEES 70.9 and 26.6.
#[test]
fn stale_position_bursts_are_set_aside() {
    let runs = 10;
    let mut off = Config::default_config().unwrap();
    off.tracker.hybrid.outlier_nis = 0.0;
    let used = run_with("airliner-stale", &["hybrid", "imm"], runs, &off);
    let aside = run("airliner-stale", &["hybrid", "imm"], runs);
    for ((u, a), name) in used.iter().zip(&aside).zip(["hybrid", "imm"]) {
        let anees = |s: &Scores| s.estimates["all"].anees_pos().unwrap();
        let report = format!(
            "{}: RMSE {:.1} -> {:.1} m (straight {:.1} -> {:.1}), ANEES {:.1} -> {:.1}, NIS in band {:.1} -> {:.1} %",
            name,
            rmse(u, "all"),
            rmse(a, "all"),
            rmse(u, "CV"),
            rmse(a, "CV"),
            anees(u),
            anees(a),
            u.nis_in_band_pct().unwrap(),
            a.nis_in_band_pct().unwrap(),
        );
        eprintln!("{report}");
        assert!(anees(u) > 6.0 && anees(u) > 1.5 * anees(a), "{report}");
        assert!(anees(a) < 7.0, "{report}");
        assert!(rmse(a, "all") < 0.85 * rmse(u, "all"), "{report}");
        assert!(rmse(a, "CV") < 0.8 * rmse(u, "CV"), "{report}");
        assert!(
            a.nis_in_band_pct().unwrap() > u.nis_in_band_pct().unwrap() + 15.0,
            "{report}"
        );
    }
}

/// Velocity reports that repeat (`airliner-gnss-velocity`: `airliner-nacp10` with a GNSS
/// receiver's 0.05 m/s of velocity noise instead of 0.3 m/s, so that, in 1-kt steps, 82 % of
/// the velocity reports repeat the last one, as AFR34ZG's 79 % do). The velocity is five
/// times more accurate than `airliner-nacp10`'s, but with the hybrid's CV filter at the
/// process noise of `kalman-cv` (q_h = 0.25 m²/s³, `tracker.steady_q_horizontal` before it
/// existed) what the track claimed for it hardly moved: its velocity ANEES was 0.13 (the
/// claim 15 times the error) and the windowed NIS, which sees held reports' near-zero
/// innovations against that claim, in its band 28 % of the time instead of 61 %.
///
/// (Both without the learned factor on q_h, `learned_steady_q_makes_the_velocity_claim_honest`.)
/// With the steady-flight q_h = 0.05 the velocity claim follows the reports more (100 runs:
/// velocity ANEES 0.13 → 0.44; `airliner-nacp10` 0.66 → 1.32, its NIS in band 60.9 → 85.7 %)
/// while the position's claim stays honest: its correlated share is now learned from
/// successive position reports, which a long filter memory does not fool (with covariance
/// matching's λ, q_h = 0.01 had let the position ANEES reach 31).
///
/// Since λ's standard error is the samples' own scatter (`track::noise`), the learned
/// velocity noise falls further at either q_h, the GNSS velocity's claim most at the
/// larger one (10 runs: `airliner-gnss-velocity` velocity ANEES 0.21 → 0.37, NIS in band
/// 39.1 → 52.5 %; `airliner-nacp10` 1.52 → 1.39, 83.9 → 88.7 %): the steady q_h still moves
/// the claim towards its error, by less than twice where it was three times.
#[test]
fn repeating_velocity_reports_show_the_velocity_caution() {
    let runs = 10;
    let mut before = Config::default_config().unwrap();
    before.tracker.steady_q_horizontal = 0.25;
    before.tracker.hybrid.learn_steady_q = false;
    let mut after = Config::default_config().unwrap();
    after.tracker.hybrid.learn_steady_q = false;
    let q_before = |sc: &str| run_with(sc, &["hybrid"], runs, &before).remove(0);
    let q_after = |sc: &str| run_with(sc, &["hybrid"], runs, &after).remove(0);
    let (white_before, white) = (q_before("airliner-nacp10"), q_after("airliner-nacp10"));
    let (gnss_before, gnss) = (
        q_before("airliner-gnss-velocity"),
        q_after("airliner-gnss-velocity"),
    );
    let vel = |s: &Scores| s.estimates["CH"].vel_rmse().unwrap();
    let vel_anees = |s: &Scores| s.estimates["all"].anees_vel().unwrap();
    let pos_anees = |s: &Scores| s.estimates["all"].anees_pos().unwrap();
    let nis = |s: &Scores| s.nis_in_band_pct().unwrap();
    let line = |name: &str, b: &Scores, a: &Scores| {
        format!(
            "{name}: descent velocity RMSE {:.3} -> {:.3} m/s, velocity ANEES {:.2} -> {:.2}, \
             position ANEES {:.2} -> {:.2}, NIS in band {:.1} -> {:.1} %",
            vel(b),
            vel(a),
            vel_anees(b),
            vel_anees(a),
            pos_anees(b),
            pos_anees(a),
            nis(b),
            nis(a)
        )
    };
    let report = format!(
        "{}\n{}",
        line("airliner-nacp10", &white_before, &white),
        line("airliner-gnss-velocity", &gnss_before, &gnss)
    );
    eprintln!("{report}");
    // The GNSS velocity is far more accurate; at q_h = 0.25 its claim did not follow.
    assert!(vel(&gnss_before) < 0.4 * vel(&white_before), "{report}");
    assert!(vel_anees(&gnss_before) < 0.3, "{report}");
    assert!(nis(&gnss_before) < nis(&white_before) - 20.0, "{report}");
    // At the steady q_h the velocity claims move towards their errors, the windowed NIS
    // into its band, and the position claims stay where they were or nearer 2.
    assert!(vel_anees(&gnss) > 1.5 * vel_anees(&gnss_before), "{report}");
    assert!((1.0..2.4).contains(&vel_anees(&white)), "{report}");
    assert!(
        nis(&white) > 80.0 && nis(&gnss) > nis(&gnss_before) + 5.0,
        "{report}"
    );
    for (b, a) in [(&white_before, &white), (&gnss_before, &gnss)] {
        assert!(pos_anees(a) < pos_anees(b) + 0.2, "{report}");
        assert!(rmse(a, "all") < rmse(b, "all") + 0.1, "{report}");
    }
}

/// The steady-flight q_h scaled per aircraft by its velocity reports' quantile residuals
/// (`track::process_noise`, `tracker.hybrid.learn_steady_q`). On `airliner-gnss-velocity`
/// (GNSS-grade velocity in 1-kt steps, as AFR34ZG's) the configured q_h left the velocity
/// claim five times the error (ANEES 0.37, 100 runs); learned, it comes to 2.03 (20 runs),
/// the windowed NIS in band from 49 to 69 % of the time, turn onsets 1.57 -> 1.34 s; the
/// position's ANEES 4.30 -> 4.47 and RMSE 7.1 -> 7.2 m, a little worse.
/// With the 30-report covariance-matching windows (the default since 2026-12-06; 100 before)
/// the trade is a little steeper, 10 runs: position ANEES 3.81 -> 4.14 (3.84 -> 4.06 at 100),
/// RMSE 6.66 -> 6.90 m (6.7 -> 6.8), for a velocity ANEES 0.37 -> 1.93 (-> 1.80) and a
/// windowed NIS in band 55 -> 77 % (53 -> 74): the learned q_h follows a shorter memory of
/// the velocity residuals, and the position follows the velocity's integral more.
/// On `airliner-nacp10` (0.3 m/s of velocity noise) it moves nothing that matters.
#[test]
fn learned_steady_q_makes_the_velocity_claim_honest() {
    let runs = 10;
    let mut fixed = Config::default_config().unwrap();
    fixed.tracker.hybrid.learn_steady_q = false;
    let off = |sc: &str| run_with(sc, &["hybrid"], runs, &fixed).remove(0);
    let on = |sc: &str| run(sc, &["hybrid"], runs).remove(0);
    let (gnss_off, gnss_on) = (off("airliner-gnss-velocity"), on("airliner-gnss-velocity"));
    let (white_off, white_on) = (off("airliner-nacp10"), on("airliner-nacp10"));
    let vel_anees = |s: &Scores| s.estimates["all"].anees_vel().unwrap();
    let pos_anees = |s: &Scores| s.estimates["all"].anees_pos().unwrap();
    let nis = |s: &Scores| s.nis_in_band_pct().unwrap();
    let report = format!(
        "airliner-gnss-velocity: velocity ANEES {:.2} -> {:.2}, position ANEES {:.2} -> {:.2}, \
         NIS in band {:.1} -> {:.1} %, RMSE {:.2} -> {:.2} m; airliner-nacp10: velocity \
         ANEES {:.2} -> {:.2}, NIS in band {:.1} -> {:.1} %",
        vel_anees(&gnss_off),
        vel_anees(&gnss_on),
        pos_anees(&gnss_off),
        pos_anees(&gnss_on),
        nis(&gnss_off),
        nis(&gnss_on),
        rmse(&gnss_off, "all"),
        rmse(&gnss_on, "all"),
        vel_anees(&white_off),
        vel_anees(&white_on),
        nis(&white_off),
        nis(&white_on),
    );
    eprintln!("{report}");
    assert!(vel_anees(&gnss_off) < 0.6, "{report}");
    assert!((1.5..2.6).contains(&vel_anees(&gnss_on)), "{report}");
    assert!(nis(&gnss_on) > nis(&gnss_off) + 10.0, "{report}");
    assert!(
        pos_anees(&gnss_on) < pos_anees(&gnss_off) + 0.45,
        "{report}"
    );
    // The position follows the velocity's integral more, whose held rounding error is the
    // airliner's (docs/evaluation.md: 7.1 -> 7.2 m over 100 runs; 6.66 -> 6.90 m here at the
    // 30-report windows, 6.69 -> 6.82 m at 100).
    for (a, b) in [(&gnss_on, &gnss_off), (&white_on, &white_off)] {
        assert!(rmse(a, "all") < rmse(b, "all") + 0.35, "{report}");
        assert!(rmse(a, "CT") < rmse(b, "CT") + 0.1, "{report}");
    }
    assert!(
        (vel_anees(&white_on) - vel_anees(&white_off)).abs() < 0.1
            && (nis(&white_on) - nis(&white_off)).abs() < 2.0,
        "{report}"
    );
}
