//! `evaluate --recording` (issue 10): consistency without truth on real recordings, per
//! tracker and declared NACp.
//!
//! - `diverging` is paper 000's criterion confirmed on four reports in a row, the point where
//!   the suppressor acts: on every recording and every declared NACp it is on for under 1 %
//!   of the steady updates with `hybrid` and `imm`. The plain `kalman-cv`, which takes the
//!   declared NACp literally and learns nothing, is flagged on 3 % of the LAX NACp 10
//!   updates: on the clock LAX's aircraft show (`feed::pace`), NACp 10 is about their noise,
//!   NACp 8 and 9 far above it (it was 45 % on the nominal 270 frames/s, which was the
//!   clock's error, not the declaration's).
//! - The hybrid and the IMM learn each aircraft's noise (`track::noise`): on AFR34ZG
//!   (declares nothing, so R starts from NUCp's 38 m per axis) the hybrid's position sigma
//!   moves from 7 m to about 1.1 m, its windowed NIS per degree of freedom to about 0.9
//!   (the IMM's 0.56; the plain Kalman filter's 0.03). The NIS is over the horizontal
//!   components (`track::nis`): at cruise the velocity reports hold still between 1-kt
//!   steps, so half of what it sums stays near zero. Before the learner winsorised its
//!   samples (`NoiseParams::outlier_ratio`), a few outlying reports held the hybrid's
//!   learned noise up.
//! - The windowed NIS is inside its band on 82 % of the hybrid's steady updates on AFR34ZG
//!   (83 % before a position could be set aside in a turn, 80 % before up to four
//!   positions in a row could be set aside, `track::outlier`;
//!   81 % before λ's standard error was the samples' own scatter, `track::noise`;
//!   83 % before a contradicted NACv stopped holding its velocity noise up, `track::noise`)
//!   since a position's term is read under the aircraft's learned tail index
//!   (`track::tails`; 78 % read as Gaussian), 78 % since its CV filter's q_h is scaled per aircraft by what its velocity reports show
//!   (`track::process_noise`: 48 % with the configured q_h, its velocity claim twice the
//!   error) and a velocity report's term is its bin's randomised quantile residual
//!   (`track::quantised`; 26 % with the Gaussian NIS of the rounded value, 17 % before the
//!   steady-flight process noise), 60 % for the IMM (43 % read as Gaussian; 54 % before the standard error), 61 % for the hybrid's LAX
//!   NACp 10 aircraft on their own clock (25 % on the nominal clock, 52 % before the
//!   prior-data conflict rule), where the same statistic is inside it on 93-94 % of the updates on
//!   the simulator's white noise (`tests/tracker_bench.rs`): the statistic is calibrated,
//!   these innovations are not Gaussian white noise. What is left on AFR34ZG is mostly
//!   positions off in time along the track; on LAX the windows below the band (32 % of
//!   NACp 10's, 51 % of NACp 9's): the learned noise stays above the aircraft's own, held up
//!   by the declaration (docs/evaluation.md). The Gaussian statistic's limit on rounded velocities:
//!   `afr34zg_velocity_reports_repeat_and_bound_the_nis`.
//!
//! A change that moves these figures must update them here and in docs/evaluation.md.

use adsb_tracker::config::Config;
use adsb_tracker::eval::consistency::{self, Group};
use std::collections::BTreeMap;
use std::path::Path;

fn groups(file: &str, rate_hz: f64, tracker: &str) -> BTreeMap<String, Group> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(file);
    let cfg = Config::default_config().unwrap();
    // As `evaluate` reads it: an untimed recording on the clock its aircraft show.
    let (frames, _) =
        consistency::read_recording(&path, None, rate_hz, cfg.decode.fit_untimed_clock).unwrap();
    consistency::measure(&frames, &cfg, tracker)
}

fn within(what: &str, x: Option<f64>, lo: f64, hi: f64) {
    let x = x.unwrap_or_else(|| panic!("{what}: no value"));
    assert!((lo..=hi).contains(&x), "{what}: {x} not in [{lo}, {hi}]");
}

#[test]
fn afr34zg_is_rarely_flagged() {
    for (tracker, nis_dof, sigma_m, in_band_pct) in [
        ("hybrid", (0.75, 1.1), (0.9, 1.6), (79.0, 87.0)),
        ("kalman-cv", (0.01, 0.08), (6.0, 9.0), (0.0, 15.0)),
        ("imm", (0.45, 0.85), (1.0, 3.0), (55.0, 72.0)),
    ] {
        let g = groups("afr34zg-cdg-tls.jsonl", 1000.0, tracker);
        let all = &g["all"];
        assert_eq!(all.airborne, 12_109, "{tracker}");
        within(
            &format!("{tracker} steady diverging %"),
            all.steady_diverging_pct(),
            0.0,
            1.0,
        );
        within(
            &format!("{tracker} airborne diverging %"),
            all.airborne_diverging_pct(),
            0.0,
            1.0,
        );
        within(
            &format!("{tracker} NIS/dof"),
            all.median_nis_per_dof(),
            nis_dof.0,
            nis_dof.1,
        );
        // The track is right: 6-9 m from each frame's own decode.
        within(
            &format!("{tracker} scatter"),
            all.median_scatter_m(),
            5.0,
            10.0,
        );
        within(
            &format!("{tracker} sigma"),
            all.median_pos_sigma_m(),
            sigma_m.0,
            sigma_m.1,
        );
        within(
            &format!("{tracker} NIS in band %"),
            all.nis_in_band_pct(),
            in_band_pct.0,
            in_band_pct.1,
        );
    }
}

/// The papers' trackers take the declaration literally, and their windowed NIS says so: on
/// AFR34ZG, whose NUCp fall-back (38 m per axis) is far wider than its noise, below its band
/// on 92-98 % of the steady updates, a twentieth of the hybrid's NIS per degree of freedom
/// (docs/evaluation.md, "Every tracker's windowed NIS").
#[test]
fn afr34zg_the_papers_trackers_report_their_caution() {
    for (tracker, below_pct) in [
        ("singer", (96.0, 99.5)),
        ("singer-nosupp", (90.0, 95.0)),
        ("cs-jerk", (90.0, 95.0)),
        ("imm-ckf", (92.0, 97.0)),
    ] {
        let g = groups("afr34zg-cdg-tls.jsonl", 1000.0, tracker);
        let all = &g["all"];
        assert!(all.steady_nis > 10_000, "{tracker}: {}", all.steady_nis);
        within(
            &format!("{tracker} below band %"),
            all.nis_below_band_pct(),
            below_pct.0,
            below_pct.1,
        );
        within(
            &format!("{tracker} NIS/dof"),
            all.median_nis_per_dof(),
            0.01,
            0.05,
        );
    }
}

#[test]
fn lax_every_nacp_is_rarely_flagged() {
    for tracker in ["hybrid", "imm"] {
        let g = groups("lax-messages.avr.txt", 270.0, tracker);
        assert_eq!(g["10"].airborne, 32_407);
        for (nacp, group) in &g {
            if group.steady < 30 {
                continue;
            }
            within(
                &format!("{tracker} NACp {nacp} steady diverging %"),
                group.steady_diverging_pct(),
                0.0,
                1.0,
            );
        }
        within(
            &format!("{tracker} NACp 10 airborne diverging %"),
            g["10"].airborne_diverging_pct(),
            0.0,
            2.5,
        );
    }
    // The hybrid's NACp 10 aircraft: horizontal NIS per degree of freedom 0.85 on the
    // clock the aircraft show (1.8 on the nominal 270 frames/s, whose rate errors of ±30 %
    // made positions and velocities disagree by metres per second; 0.78 with the velocity
    // reports' terms read as Gaussian, `track::tails`).
    let g = groups("lax-messages.avr.txt", 270.0, "hybrid");
    within(
        "hybrid NACp 10 NIS/dof",
        g["10"].median_nis_per_dof(),
        0.6,
        0.95,
    );
}

#[test]
fn lax_declared_accuracy_is_a_bound() {
    // The plain Kalman filter learns nothing and takes NACp literally. On the clock the
    // aircraft show, NACp 10's 4 m per axis is about their noise (NIS/dof 0.84; it was 15
    // on the nominal clock, flagged on 45 % of the steady updates, which was the clock's
    // doing), while NACp 9 and 8, bounds of 30 m and 93 m, are three to twenty times the
    // noise in σ: the filter is far too cautious there.
    let g = groups("lax-messages.avr.txt", 270.0, "kalman-cv");
    let dof = |k: &str| g[k].median_nis_per_dof().unwrap();
    within("NACp 10 NIS/dof", Some(dof("10")), 0.7, 1.0);
    within("NACp 9 NIS/dof", Some(dof("9")), 0.1, 0.25);
    within("NACp 8 NIS/dof", Some(dof("8")), 0.02, 0.08);
    within(
        "NACp 10 steady diverging %",
        g["10"].steady_diverging_pct(),
        1.0,
        6.0,
    );
}

/// AFR34ZG's positions have a heavier tail about their prediction than a Gaussian
/// (`track::tails`): read under a Student-t of the aircraft's own tail index, with the
/// filter's covariance, the IMM's windowed NIS is in band on 60 % of its steady updates
/// where the Gaussian reading gives 43 %. The hybrid's gained 3 points (84 % where the
/// Gaussian reading gave 81 %) until its noise windows were cut from 100 reports to 30
/// (`track::noise::NoiseParams::window`); since then it reads 83 % either way: the shorter
/// memory follows the noise the tail was standing in for (on LAX the position tails still
/// take the hybrid's steady windows in band from 67.8 to 71.2 %). (82/77 before
/// the velocity innovation was centred on its running mean, `track::noise::InnovationMean`;
/// 83/78 before a position could be set aside in a turn, `track::outlier`; 80/75 and
/// 59/42 before up to four positions in a row could be set aside, `track::outlier`; 81/78
/// and 54/39 before λ's standard error was the samples' own scatter, `track::noise`); the track
/// and its covariance are the same, update for update. The velocity reports' terms are read
/// as Gaussian in both runs (the next test reads them under their own tail).
#[test]
fn afr34zg_position_tails_change_the_claim_not_the_track() {
    let frames = afr34zg_frames();
    let run = |tracker: &str, tails: bool| {
        let mut config = Config::default_config().unwrap();
        config.tracker.hybrid.learn_position_tails = tails;
        config.tracker.hybrid.learn_velocity_tails = false;
        let mut p = adsb_tracker::eval::bench::sync_pipeline(&config, tracker);
        let states: Vec<_> = frames
            .iter()
            .filter_map(|f| p.push(f)?.state)
            .map(|s| {
                (
                    s.t,
                    s.lat,
                    s.lon,
                    s.alt_m,
                    s.pos_sigma_m,
                    s.mode,
                    s.diverging,
                )
            })
            .collect();
        let g = consistency::measure(&frames, &config, tracker);
        (states, g["all"].nis_in_band_pct().unwrap_or(f64::NAN))
    };
    // (tracker, band read as Gaussian, band read as t, the least gain of the t reading.)
    for (tracker, gaussian_band, t_band, gain) in [
        ("hybrid", 78.0..=87.0, 78.0..=87.0, -1.0),
        ("imm", 34.0..=45.0, 50.0..=63.0, 3.0),
    ] {
        let (gaussian, gaussian_in_band) = run(tracker, false);
        let (t, t_in_band) = run(tracker, true);
        assert_eq!(gaussian.len(), t.len(), "{tracker}");
        assert!(gaussian == t, "{tracker}: an estimate moved");
        eprintln!(
            "{tracker} NIS in band: Gaussian {gaussian_in_band:.1} %, Student-t {t_in_band:.1} %"
        );
        assert!(gaussian_band.contains(&gaussian_in_band), "{tracker}");
        assert!(t_band.contains(&t_in_band), "{tracker}");
        assert!(t_in_band > gaussian_in_band + gain, "{tracker}");
    }
}

/// LAX's velocity reports have a heavier tail about their claim than a Gaussian
/// (`track::tails`, "Velocity reports"): most of its NACp 9 and 10 aircraft report to the
/// knot on a claim narrower than two knots, and their quantile residuals' median sits near
/// half of χ²(2)'s with a tail above it. Read under a Student-t of the aircraft's own
/// velocity tail index, the hybrid's windowed NIS is in band on 72 % of NACp 10's steady
/// updates (68.5 % read as Gaussian) and on 69 % of NACp 9's (60.5 %); the plain IMM's on
/// 61 % (49 %) and 42 % (32 %). (With the hybrid's noise windows at 100 reports rather than
/// 30, `track::noise::NoiseParams::window`: 69/64 % and 64/52 %. Before the velocity
/// innovation was centred on its running mean, `track::noise::InnovationMean`: the
/// hybrid's 65/61 % and 51/44 %.) The tracks and their
/// covariance are the same, update for update.
#[test]
fn lax_velocity_tails_change_the_claim_not_the_track() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join("lax-messages.avr.txt");
    let base = Config::default_config().unwrap();
    let (frames, _) =
        consistency::read_recording(&path, None, 270.0, base.decode.fit_untimed_clock).unwrap();
    let run = |tracker: &str, tails: bool| {
        let mut config = base.clone();
        config.tracker.hybrid.learn_velocity_tails = tails;
        let mut p = adsb_tracker::eval::bench::sync_pipeline(&config, tracker);
        let states: Vec<_> = frames
            .iter()
            .filter_map(|f| p.push(f)?.state)
            .map(|s| (s.t, s.lat, s.lon, s.pos_sigma_m, s.mode, s.diverging))
            .collect();
        let g = consistency::measure(&frames, &config, tracker);
        let pct = |k: &str| g[k].nis_in_band_pct().unwrap_or(f64::NAN);
        (states, pct("10"), pct("9"))
    };
    // (tracker, NACp 10's band read as Gaussian and as t, NACp 9's the same.)
    for (tracker, g10, t10, g9, t9) in [
        ("hybrid", 64.0..=73.0, 67.0..=77.0, 55.0..=65.0, 64.0..=74.0),
        ("imm", 44.0..=53.0, 55.0..=64.0, 28.0..=37.0, 37.0..=47.0),
    ] {
        let (gaussian, gaussian10, gaussian9) = run(tracker, false);
        let (t, tail10, tail9) = run(tracker, true);
        assert_eq!(gaussian.len(), t.len(), "{tracker}");
        assert!(gaussian == t, "{tracker}: an estimate moved");
        eprintln!(
            "{tracker} NIS in band, NACp 10: {gaussian10:.1} -> {tail10:.1} %, \
             NACp 9: {gaussian9:.1} -> {tail9:.1} %"
        );
        assert!(g10.contains(&gaussian10), "{tracker} {gaussian10}");
        assert!(t10.contains(&tail10), "{tracker} {tail10}");
        assert!(g9.contains(&gaussian9), "{tracker} {gaussian9}");
        assert!(t9.contains(&tail9), "{tracker} {tail9}");
        assert!(tail10 > gaussian10 + 3.0, "{tracker}");
        assert!(tail9 > gaussian9 + 5.0, "{tracker}");
    }
}

/// AFR34ZG's velocity reports are about a second older than its positions
/// (`eval::latency`, no tracker involved): in its departure and arrival turns, the position
/// reports less the integral of the velocity reports follow v(t)·1.07 s. The same method
/// finds the simulator's known offsets within 0.1 s (its module test).
#[test]
fn afr34zg_velocities_lag_its_positions_by_about_a_second() {
    use adsb_tracker::eval::latency;
    let frames = afr34zg_frames();
    let all = latency::reports(&frames);
    let o = all
        .values()
        .next()
        .and_then(latency::estimate)
        .unwrap_or_else(|| panic!("no estimate"));
    assert_eq!(all.len(), 1);
    assert!(o.windows >= 10, "{o:?}");
    assert!((0.95..=1.2).contains(&o.velocity_lag_s), "{o:?}");
    assert!(o.sigma_s < 0.05, "{o:?}");
}

/// In AFR34ZG's turns the velocity reports point where the aircraft was heading a second
/// before, and its hybrid's windowed NIS there says so: median 2.85 per degree of freedom
/// over its 563 updates labelled CT when every report is taken as current. Learning the lag
/// from the flight's own turns (`track::lag`, on by default; 1.08 s, learnt after the
/// departure's turns) brings it to 1.51; the lag given for the whole flight
/// (`tracker.imm.velocity_lag_s = 1.07`, this file's figure above) to 1.06. The plain
/// `imm`, whose most probable mode is CT on 111 updates, learns it the same way: 4.09
/// taken as current, 1.27 learnt, 1.25 given.
///
/// Since positions out of their time are set aside (`track::outlier`), the figures are
/// hybrid 3.29, 1.65, 1.17 and imm 4.80, 1.87, 1.77. The flight's bursts of stale
/// positions (two or three every 16-48 s) had each counted in the learned noise as an
/// unlucky draw, at five times its predicted size: what the tracks learn now is the noise
/// of the reports they use, smaller, and the turns' own model error shows against it.
/// The `imm` has 100 CT updates instead of 111: in a replay 16 of its old CT labels sat on
/// the cruise's bursts, the IMM explaining a stale position as a turn (NIS/dof 18 there).
///
/// Since the hybrid's CV filter takes the steady-flight process noise
/// (`tracker.steady_q_horizontal` = 0.06 instead of 0.25), the hybrid's figures are 3.35,
/// 2.34, 1.75 (590 CT updates): a window of 20 updates at a turn's labelled updates still holds the CV
/// filter's innovations from the turn's onset, larger against its smaller q (a turn is a
/// surprise to a straight-flight model, and should read as one). The learned lag still
/// brings the turns most of the way to the lag given. Since that q_h is scaled per aircraft
/// by what its velocity reports show (`track::process_noise`: AFR34ZG's about a third), the
/// same holds more so: 3.98, 2.82, 1.85 (592 CT updates). Since the `imm` reads a position's
/// term under the aircraft's tail index where CV is its published mode (`track::tails`), its
/// figures are 3.84, 1.76, 1.68: the windows at its CT labels still hold a few steady-flight
/// terms from before the turn's onset, read so (the hybrid's 3.99, 2.82, 1.85). Since a
/// declared accuracy the innovations contradict stops holding the learned noise up
/// (`track::noise::PRIOR_CONFLICT_SCALE`: AFR34ZG's velocities declare NACv), the
/// hybrid's are 3.33, 2.59, 1.77 (618 CT updates): its velocity noise, learned smaller
/// sooner, makes the turns' model error show less in the windows at their labels.
///
/// Since λ's standard error is the samples' own scatter (`track::noise`, Welford), the
/// velocity noise of both trackers learns down to its floor and stays there: the hybrid's
/// figures are 3.46, 2.72, 1.76 (620 CT updates), and over lags given from 1.04 to 1.11 s
/// 1.66-1.93. The `imm`'s are 3.77 taken as current (135 CT updates) and 8.34 learnt,
/// and over the lags given (sorted) 2.14, 2.29, 2.35, 2.59, 3.14, 4.38, 6.21, 9.47: not a
/// function of the lag but of one position in the arrival's first turn, at
/// 1720252441.03 (NUCp 6), half a second old, 57 m behind the track. Out of steady flight
/// no velocity report vouches for a straight line, so it is not set aside
/// (`track::outlier`); where the IMM's CT holds about 100 % at that instant it takes the
/// position as one term of about 100 per degree of freedom, and the 20 windows after it
/// read 8-17 through the rest of the turn (the arrival's CT labels, 80 of them, then all
/// sit in those windows); where the mixture is split, the position widens the covariance
/// instead (sigma 18 m) and the windows stay near 2.5. The learnt run's history (lag 0
/// until the departure's turns taught 1.07) landed it in the first case. Since up to four
/// positions in a row may be set aside in steady flight (`track::outlier`), the figures are
/// hybrid 3.46, 2.77, 1.78 and `imm` 3.99, 3.33 learnt, and over the lags given (sorted)
/// 2.18, 2.22, 2.24, 2.41, 2.73, 4.85, 4.89, 7.22: the learnt run in the second case. Since
/// a position may be set aside in a turn where the velocity reports fit the held mode
/// (`track::outlier`), the hybrid's are 3.36, 2.72, 1.82 and the `imm`'s 4.31 taken as
/// current (137 CT updates), 3.33 learnt, the lags given the same. So the `imm`'s
/// figure is read over the lags given: at least half of them under the one taken as
/// current, the best under 2.6, the learnt one inside their span.
///
/// Since the hybrid's noise windows are 30 reports rather than 100
/// (`track::noise::NoiseParams::window`), its figures are 3.44, 3.01, 2.06 (623 CT
/// updates): the noise learned over the short steady legs between the turns is smaller
/// when a turn begins, and the learnt lag, still taught by the departure's turns, takes the
/// turns' windows less far down than the lag given for the whole flight.
#[test]
fn afr34zg_turns_are_consistent_with_the_velocity_lag() {
    let frames = afr34zg_frames();
    let median_ct_nis = |tracker: &str, learn: bool, lag_s: f64| {
        let mut config = Config::default_config().unwrap();
        config.tracker.hybrid.learn_velocity_lag = learn;
        config.tracker.imm.velocity_lag_s = lag_s;
        let mut p = adsb_tracker::eval::bench::sync_pipeline(&config, tracker);
        let mut nis: Vec<f64> = frames
            .iter()
            .filter_map(|f| p.push(f)?.state)
            .filter(|s| !s.on_ground && s.mode == "CT")
            .filter_map(|s| Some(s.nis? / f64::from(s.nis_dof.filter(|&d| d > 0)?)))
            .collect();
        nis.sort_by(f64::total_cmp);
        (nis.len(), nis[nis.len() / 2])
    };
    // The hybrid: (fewest CT updates, NIS/dof above which taken as current, under which
    // learnt, and the band given.)
    let (n, current) = median_ct_nis("hybrid", false, 0.0);
    let (_, learnt) = median_ct_nis("hybrid", true, 0.0);
    let (_, given) = median_ct_nis("hybrid", false, 1.07);
    let report = format!(
        "hybrid: {n} CT updates: NIS/dof {current:.2}, learnt {learnt:.2}, given {given:.2}"
    );
    eprintln!("{report}");
    assert!(n > 500, "{report}");
    assert!(current > 3.1, "{report}");
    assert!(learnt < 3.2 && learnt < current - 0.3, "{report}");
    assert!((1.4..2.4).contains(&given), "{report}");
    // The IMM: its figure swings with the lag given (module doc above), so it is read over
    // lags given from 1.04 to 1.11 s.
    let (n, current) = median_ct_nis("imm", false, 0.0);
    let (_, learnt) = median_ct_nis("imm", true, 0.0);
    let mut given: Vec<f64> = (104..=111)
        .map(|centi_s| median_ct_nis("imm", false, f64::from(centi_s) / 100.0).1)
        .collect();
    given.sort_by(f64::total_cmp);
    let report =
        format!("imm: {n} CT updates: NIS/dof {current:.2}, learnt {learnt:.2}, given {given:.2?}");
    eprintln!("{report}");
    let helped = given.iter().filter(|&&g| g < current).count();
    assert!(n > 90, "{report}");
    assert!(current > 3.0, "{report}");
    assert!(helped >= given.len() / 2, "{report}");
    assert!(given[0] < 2.6, "{report}");
    assert!(
        (given[0]..=given[given.len() - 1]).contains(&learnt),
        "{report}"
    );
}

fn afr34zg_frames() -> Vec<adsb_tracker::feed::RawFrame> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join("afr34zg-cdg-tls.jsonl");
    consistency::read_frames_at(&path, None, 1000.0).unwrap()
}

/// What the windowed NIS can show where velocity reports repeat (`docs/evaluation.md`,
/// "Velocity reports that repeat"). In 1-kt steps the velocity of an airliner in steady
/// flight repeats the last report: on AFR34ZG 79 % of the airborne velocity reports do
/// (`evaluate --recording`'s "velocity reports held" column), where the simulator's NACv 2
/// noise repeats on under 2 %. A held report's innovation is near zero whatever a filter
/// claims. So even the best one-step predictor there is (the last report itself, its
/// innovation the step to the next) with the best constant variance a filter could claim
/// puts barely half of the windows of ten velocity reports inside their 95 % χ² band, where
/// a white Gaussian innovation would put 95 %: the limit of a Gaussian statistic on the
/// issue's 90 %, not a filter's. The best variance is the 1-kt step's quantisation variance,
/// Δ²/12. So the track's windowed NIS takes a velocity report's bin instead, the randomised
/// quantile residual of the filter's claim (`track::quantised`), whose windows are inside
/// their band 95 % of the time on held values when the claim is right (its module test).
#[test]
fn afr34zg_velocity_reports_repeat_and_bound_the_nis() {
    let frames = afr34zg_frames();
    let g = consistency::measure(&frames, &Config::default_config().unwrap(), "kalman-cv");
    within(
        "AFR34ZG velocity reports held %",
        g["all"].velocity_held_pct(),
        77.0,
        82.0,
    );
    // The steps between successive reports at most a second apart, both over 100 m/s:
    // squared, per axis, m²/s².
    const KT_MPS: f64 = 1852.0 / 3600.0;
    let mut reports = consistency::VelocityReports::new(&Config::default_config().unwrap());
    let mut steps: Vec<f64> = Vec::new();
    for f in &frames {
        let Some(r) = reports.push(f) else { continue };
        let Some((tp, (pe, pn))) = r.previous else {
            continue;
        };
        let (e, n) = r.en_kt;
        let fast = |e: f64, n: f64| e.hypot(n) * KT_MPS > 100.0;
        if r.t_s - tp <= 1.0 && fast(e, n) && fast(pe, pn) {
            steps.push(((e - pe).powi(2) + (n - pn).powi(2)) * KT_MPS * KT_MPS / 2.0);
        }
    }
    assert!(steps.len() > 4000, "{} steps", steps.len());
    let held = steps.iter().filter(|&&s| s == 0.0).count() as f64 / steps.len() as f64;
    const WINDOW: usize = 10;
    let (lo, hi) = consistency::chi2_band(2.0 * WINDOW as f64);
    let in_band = |var: f64| {
        let windows: Vec<f64> = steps
            .windows(WINDOW)
            .map(|w| 2.0 * w.iter().sum::<f64>() / var)
            .collect();
        windows.iter().filter(|&&s| (lo..=hi).contains(&s)).count() as f64 / windows.len() as f64
    };
    // The claimed per-axis variance swept over four decades, 5 % apart.
    let (best_share, best_var) = (0..190)
        .map(|k| 1e-4 * 1.05_f64.powi(k))
        .map(|var| (in_band(var), var))
        .fold((0.0, 0.0), |a, b| if b.0 > a.0 { b } else { a });
    let quantisation_var = (1852.0_f64 / 3600.0).powi(2) / 12.0;
    eprintln!(
        "{} steps, {:.1} % held; best constant variance {best_var:.4} (m/s)² \
         (Δ²/12 = {quantisation_var:.4}): {:.1} % of {WINDOW}-report windows in band",
        steps.len(),
        100.0 * held,
        100.0 * best_share
    );
    assert!((0.75..0.88).contains(&held), "held {held}");
    assert!(best_share < 0.65, "best share {best_share}");
    assert!(
        (0.5 * quantisation_var..2.0 * quantisation_var).contains(&best_var),
        "best variance {best_var}"
    );
}

/// The "velocity reports held" column tells the two kinds of velocity apart: the
/// simulator's NACv 2 noise (σ 1.2 m/s, paper002) repeats the last report on under 2 % of
/// the reports, a GNSS-grade 0.05 m/s (`airliner-gnss-velocity`) on about 80 %, as
/// AFR34ZG's real reports do (previous test); `airliner-nacp10`'s 0.3 m/s on about 18 %.
#[test]
fn held_velocity_reports_on_the_simulator() {
    let dir = std::env::temp_dir().join(format!("adsb-held-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = Config::default_config().unwrap();
    for (scenario, lo, hi) in [
        ("paper002", 0.0, 2.0),
        ("airliner-nacp10", 12.0, 25.0),
        ("airliner-gnss-velocity", 75.0, 88.0),
    ] {
        let sc = adsb_tracker::sim::load_scenario(scenario).unwrap();
        let prefix = dir.join(scenario);
        let summary = adsb_tracker::sim::simulate(&sc, sc.settings.seed, &prefix).unwrap();
        let frames = consistency::read_frames_at(&summary.beast_path, None, 1000.0).unwrap();
        let g = consistency::measure(&frames, &config, "kalman-cv");
        eprintln!(
            "{scenario}: {:?} % of {} velocity reports held",
            g["all"].velocity_held_pct(),
            g["all"].velocity_reports
        );
        within(
            &format!("{scenario} velocity reports held %"),
            g["all"].velocity_held_pct(),
            lo,
            hi,
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}
