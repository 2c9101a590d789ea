//! The manoeuvre gate of paper 002 (§1.2, Fig. 1; ALGORITHMS.md §002) that chooses between
//! the cheap CV Kalman filter and the IMM, and labels the manoeuvre.
//!
//! Paper 002 compares, over the last N reports (N = 5), the changes of ground speed Δv,
//! ground (along-track) acceleration Δa, heading Δφ and pitch Δβ with thresholds
//! λv = 10 m/s, λa = 5 m/s², λφ = 1°, λβ = 5°: all below → CV. That is
//! [`GateParams::paper002`].
//!
//! Measured on a prototype, those thresholds never fire on what airliners fly every day:
//! 1–1.5 m/s² along track changes the speed by 3 m/s over five half-second reports (λv is
//! 10 m/s), and a steady climb or descent, even at 3.4°, has no pitch CHANGE at all. So the
//! DEFAULT gate ([`GateParams::default`]) tests rates instead, each estimated by least
//! squares over a window of velocity reports and required to be both above its threshold
//! and significant (k σ of its own estimation noise):
//! - turn rate: slope of the heading over the last 5 reports, > 0.5°/s (paper 002's
//!   λφ = 1° over five reports half a second apart);
//! - along-track acceleration: slope of the ground speed over the last 12 reports (~6 s),
//!   > 0.3 m/s²;
//! - vertical speed: mean vertical rate over the last 6 reports, > 1.5 m/s (300 ft/min).
//!
//! The turn-rate test alone is slow at a turn's ONSET: its window still holds the straight
//! reports before the turn, which dilute the slope. So a second test looks for the onset
//! itself, as a change-point (hinge) fit: for m = 1..=3, the newest m reports are taken as
//! the first of a turn and the reports before them (up to 8) as the straight reference; the
//! heading is fitted as a + b·max(0, t − t_ref) (t_ref the last reference report) by least
//! squares, and the turn is on when the rate since the onset b exceeds λ = 0.5°/s and 4σ of
//! its own estimate for some m. The reference must not itself be turning (its own slope
//! under λ), or the end of a turn would read as the onset of another; once on, the
//! turn-rate test holds the turn at its release thresholds. Only measured velocities feed
//! it (a filter's velocity is correlated from report to report, which its σ ignores).
//! Measured on paper 002's scenario (70.7 m/s, 3°/s, NACv 2: 1° of heading noise per
//! report, one report a second), 100 runs: mean delay from the onset to the CT label
//! 2.23 s → 1.80 s, false switches unchanged (0.26 per 100 straight updates); at k = 3.5σ
//! 1.63 s but ten times as many false turn labels.
//!
//! A third, the first-report test ([`GateParams::first_report_turn_sigmas`], 2.9σ), takes
//! the split m = 1 alone: at one report a second, the first report after paper 002's onset
//! is 2.9σ off the straight line, so a test of that report alone labels about half the
//! onsets there, for about 0.37 % of straight reports labelled a turn (where the three
//! splits at 3σ gave about 1 %). It labels the turn and is no manoeuvre
//! ([`GateFlags::any`] leaves it out): the tracker opens its IMM on the tests that need more
//! than one report, so no estimate changes, and the next report confirms the label or it
//! goes. Its reference must not drift (its own slope within [`FIRST_REPORT_MAX_DRIFT_Z`]
//! σ): a heading that wanders under the turn threshold puts the newest report far from the
//! reference's mean, which would read as an onset (measured on a real airliner's cruise:
//! 2.5 % of it labelled turning without the guard, as without the test with it). 100 runs
//! of paper 002: onset 1.72 → 1.45 s, false switches 0.07 → 0.38 per 100 straight updates.
//!
//! A turn's END waits too: the turn-rate test holds the turn until its five-report slope
//! falls under its release thresholds, which the reports after the end only bring about as
//! the window slides past it (3.4 s at paper 002's 3°/s and one report a second). So while a
//! turn is held, an end test ([`GateParams::turn_end_sigmas`], 3.5σ) fits the reports since
//! the turn began as the turn's line with a hinge, a + b·t + c·max(0, t − t_ref), for the
//! newest m = 2..=8 reports after t_ref ([`hinge_end`]): the turn ends when its rate b is a
//! turn, the change c is against it and significant (k σ), and the rate since, b + c, is
//! consistent with one under λ. The line is known from every report since the turn began,
//! so two reports past the end tell it. Like the first-report test it only labels (the turn
//! tests still hold, and the tracker's IMM with them, until they release: no estimate
//! moves). 100 runs of paper 002: turn ends labelled after 1.87 s instead of 3.43 s, labels
//! right 98.4 → 98.7 %, 0.3 reports a run inside the turns labelled straight too early.
//! (The same test on the ground speed, to end an acceleration's label, gained nothing: at
//! NACv 2 a 0.4 m/s² acceleration's end takes as long to tell from noise as its onset, and
//! its false ends cost what its early ends gained; docs/evaluation.md.)
//!
//! The along-track test waits the same way, and longer: over 24 reports the straight
//! ones dilute a 0.4 m/s² acceleration's slope for most of the window. So the same hinge
//! fit runs on the ground speed ([`GateParams::accel_onset_reports`]: m = 1..=12 newest
//! reports against up to 12 steady ones before), at the same k (4σ). Measured at NACv 2
//! and 2 Hz (100 runs of a 0.4 m/s² onset): seen after 7.1 s instead of 7.9 s, where a
//! test knowing the onset time and the rate would need about 6.1 s (module tests). With the
//! learned vertical noise below, the approach scenario's labels went from 93.7 % to 95.5 %
//! right, the departure's from 92.0 % to 93.2 % (100 runs; docs/evaluation.md).
//!
//! An acceleration is then **held by its own line** ([`GateParams::accel_hold_sigmas`],
//! 3σ): the trend window's slope (24 reports, σ about 0.07 m/s² at NACv 2) scatters about
//! a gentle acceleration's rate, and the approach's 0.3 m/s² deceleration, at λ itself,
//! fell under the release (0.6 λ, 0.6·4σ) on about one report in twenty, each time
//! dropping its label for seconds. While an acceleration is held, every measured report
//! since it fired is summed into one line; once it has 12 reports, that line holds the
//! acceleration past the trend test's release while its own slope passes the release and
//! the trend's slope is not k combined σ under it. At the acceleration's end the trend's
//! slope falls away from the line and releases it: for the departure's 0.4-0.5 m/s² about
//! when the trend test alone would, for a 0.3 m/s² deceleration later (module test, 100
//! runs: its label dropped on 1.6 % of its reports instead of 10.7 %, and steady for good
//! 7.2 s after its end instead of 3.8 s). 40 runs: approach labels 95.1 → 96.0 % right,
//! the departure's 93.0 % unchanged (k = 2.4 gave 95.7 %, 4 and 5 cost the departure's
//! ends 0.3 and 0.8 points; docs/evaluation.md).
//!
//! The vertical test's σ is learned per aircraft from successive vertical rates
//! ([`DiffNoise`]): NACv's vertical bound is far looser than a barometric rate, and the
//! capped bound was either too sure (the simulator's NACv 2 noise, σ 2.3 m/s: false climb
//! labels on 2.5 % of level reports) or too cautious (a quiet baro rate).
//!
//! A **climb or descent's onset** ([`GateParams::vertical_onset_sigmas`], 4.5σ): the
//! six-report mean of a step from level to 7 m/s, at the simulator's NACv 2 vertical noise
//! (σ 2.33 m/s, σ of the mean 0.95 m/s), passes 4σ only on the fourth report of the
//! descent, since the level reports before it still average in. Level flight's rate is
//! known, zero, so no reference is needed: the newest m = 2..5 reports' mean is tested
//! against it, each at its own σ (a step of 7 m/s passes 4.5σ on its second or third
//! report), and every one of the m must be on the mean's side of level (a gust beside a
//! level report is not a climb). It costs chance climbs: level reports at σ 2.33 m/s are
//! labelled vertical on 0.17 % of reports instead of 0.09 % (module test). 40 runs: the
//! approach's descent onsets labelled in 1.75 s instead of 2.23 s, the airliner's in
//! 0.98 s instead of 1.62 s (docs/evaluation.md).
//!
//! A climb changes the height; chance rates do not. So the same newest-m means are taken
//! at a lower k ([`GateParams::vertical_onset_altitude_sigmas`], 3σ) when the barometric
//! altitude, which the tracker notes from each position report ([`Gate::altitude`]), has
//! left the range of the altitudes noted with the six reports before the m by at least a
//! 25-ft step in the mean's direction. The range, not one altitude, so that an altitude
//! flickering between two steps in level flight (held at a step's edge) is no climb until
//! it reaches a third. 100 runs of the approach: its descents labelled in 1.38 s instead
//! of 1.75 s, false switches unchanged; module test (200 runs of a 7 m/s step, σ 2.33 m/s,
//! from a level at every phase of its step): first labelled on report 1.59 instead of
//! 1.89, level reports labelled vertical the same, and with an altitude that flickers on
//! half its reports 0.21 % instead of 0.18 %.
//!
//! ADS-B gives the velocity directly (airborne velocity message, DO-260B §2.2.3.2.6), so
//! heading and speed changes are MEASURED, not differentiated positions; the gate feeds on
//! those reports. Their 1-kt (0.514 m/s) and 64-ft/min (0.325 m/s) resolution adds a uniform
//! quantisation error of variance q²/12 to each component, which the significance test
//! includes; least squares over several reports averages it down (a heading at 70 m/s is
//! quantised to 0.4°, far above a 0.5°/s rate over one half-second report).
//!
//! When the track only receives positions, the tracker feeds the gate with its own filtered
//! velocity (a derived sample: no quantisation, the covariance it is given as is). Derived
//! samples serve the turn and the paper's tests only: positions with ADS-B's ~10 m noise
//! cannot resolve 0.3 m/s² or 1.5 m/s within these windows (measured on paper 002's scenario
//! fed positions only: the along-track test on a CV filter's velocity fired on 1.4 % of
//! straight-leg reports), so the along-track and vertical tests use measured velocities only
//! (a big speed or height change still shows as divergence to the tracker).
//!
//! Hysteresis: a fired gate stays fired while its statistic exceeds `release_ratio` times its
//! threshold (and significance), so a manoeuvre at the threshold does not flicker.
//! Fixed-capacity ring buffer: no allocation.

use std::sync::Arc;

use super::{
    FlightMode, Lateral, Observed, SpeedTrend, TurnDirection, VerticalTrend, UNMEASURED_VARIANCE,
};

/// k of the first-report turn test by default ([`GateParams::first_report_turn_sigmas`]):
/// 2.9σ, the level at which paper 002's 3°/s turn at 70.7 m/s (a first report 2.9σ of its
/// heading noise off the straight line) is labelled on that report about half the time,
/// for about 0.37 % of straight reports labelled a turn for one report (two-sided
/// Gaussian tail). Measured, 100 runs (docs/evaluation.md): paper002's mean onset delay
/// 1.72 → 1.45 s, false switches 0.07 → 0.38 per 100 straight updates; k = 3.0 gave
/// 1.49 s, 2.8 gave 1.41 s and 0.47.
pub const FIRST_REPORT_TURN_SIGMAS: f64 = 2.9;

/// k of the turn's end test by default ([`GateParams::turn_end_sigmas`]): 3.5σ. Measured,
/// 100 runs (docs/evaluation.md): paper 002's turn ends labelled after 1.87 s instead of
/// 3.43 s, with 0.3 reports a run inside its turns labelled straight too early; 3.0σ gave
/// 1.67 s and three times as many (0.9 a run), 4.0σ 2.07 s.
pub const TURN_END_SIGMAS: f64 = 3.5;

/// Most reports a window may span.
pub const GATE_CAPACITY: usize = 32;

/// Room past the longest window in the gate's sliding buffer: one report more than this goes
/// between two slides. 3 makes the default buffer 27 samples of 56 bytes, 1,512 bytes: under
/// jemalloc's 1,536-byte size class, where 8 took the 2,048-byte class (per aircraft: memory
/// at fleet scale), for a 1.3 KB copy every fourth report instead of every ninth.
const GATE_SLACK: usize = 3;

/// 1 knot in m/s: the resolution of ADS-B velocity components (DO-260B §2.2.3.2.6.1.7/.8,
/// subsonic).
pub const KNOT_MPS: f64 = 0.514_444;
/// 64 ft/min in m/s: the resolution of the ADS-B vertical rate (DO-260B §2.2.3.2.6.1.14).
pub const VRATE_LSB_MPS: f64 = 64.0 * 0.3048 / 60.0;

/// Thresholds and windows of the gate. A threshold of `None` disables its test.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GateParams {
    /// N: reports over which the paper's changes Δv, Δa, Δφ, Δβ are taken (paper: 5).
    pub window_reports: usize,
    /// λv: |Δ ground speed| over the window, m/s (paper: 10).
    pub speed_change_mps: Option<f64>,
    /// λa: |Δ along-track acceleration| over the window, m/s² (paper: 5). The accelerations
    /// are differences of consecutive ground speeds.
    pub accel_change_mps2: Option<f64>,
    /// λφ: |Δ heading| over the window, degrees (paper: 1).
    pub heading_change_deg: Option<f64>,
    /// λβ: |Δ pitch| (flight-path angle) over the window, degrees (paper: 5).
    pub pitch_change_deg: Option<f64>,
    /// |Turn rate| threshold, °/s (least-squares slope of the heading).
    pub turn_rate_deg_s: Option<f64>,
    /// Reports in the turn-rate window.
    pub turn_window_reports: usize,
    /// Turn onset test (module doc): at most this many newest reports are tried as the
    /// first reports of a turn (0 disables the test).
    pub onset_reports: usize,
    /// Reports before a candidate onset that give the straight reference heading.
    pub onset_reference_reports: usize,
    /// k of the onset test: the rate since the onset must exceed k times its own σ.
    pub onset_sigmas: f64,
    /// k of the first-report turn test (module doc), `None` to disable it: the newest report
    /// alone against the straight reference labels a turn when its rate exceeds λ and k σ,
    /// without opening the IMM; the next report confirms it (the onset or turn-rate test
    /// fires) or the label goes.
    pub first_report_turn_sigmas: Option<f64>,
    /// k of the turn's end test (module doc), `None` to disable it: while a turn is held,
    /// the newest reports leaving the turn's own line (its rate changed by more than k σ,
    /// to a rate under the threshold) end its label, without closing the IMM.
    pub turn_end_sigmas: Option<f64>,
    /// |Along-track acceleration| threshold, m/s² (least-squares slope of the ground speed).
    pub along_track_accel_mps2: Option<f64>,
    /// k of the acceleration's hold (module doc), `None` to disable it: while an
    /// acceleration is held, the line through every measured report since it fired holds
    /// it past the trend window's release, until the trend's slope falls k combined σ
    /// under that line's.
    pub accel_hold_sigmas: Option<f64>,
    /// Acceleration onset test (module doc): at most this many newest reports are tried as
    /// the first of an acceleration (0 disables the test). Its k is `onset_sigmas`.
    pub accel_onset_reports: usize,
    /// Reports before a candidate acceleration onset that give the steady reference speed.
    pub accel_onset_reference_reports: usize,
    /// |Vertical rate| threshold, m/s (mean over the vertical window).
    pub vertical_rate_mps: Option<f64>,
    /// Reports in the vertical-rate window.
    pub vertical_window_reports: usize,
    /// k of the climb or descent onset test (module doc), `None` to disable it: the mean
    /// of the newest m = 2..n−1 of the window's reports against level flight, each m at
    /// k σ of its own mean.
    pub vertical_onset_sigmas: Option<f64>,
    /// k of the altitude-confirmed climb or descent onset (module doc), `None` to disable
    /// it: the same newest m reports' mean at this lower k, when the barometric altitude has
    /// left the level it held before them by a step in the same direction.
    pub vertical_onset_altitude_sigmas: Option<f64>,
    /// Reports in the along-track acceleration window (and the most a turn's rate is fitted
    /// over, [`Gate::turn_rate_since_start_rad_s`]).
    pub trend_window_reports: usize,
    /// Reports older than this before the newest leave every window, s.
    pub max_window_s: f64,
    /// k: a rate must also exceed k times the σ of its own estimate (0 disables).
    pub significance_sigmas: f64,
    /// A fired test stays fired while its statistic exceeds this fraction of its threshold
    /// (1 = no hysteresis).
    pub release_ratio: f64,
    /// Below this ground speed the heading is meaningless and the turn tests are skipped,
    /// m/s.
    pub min_speed_mps: f64,
    /// Ceiling on the σ of a measured velocity component, m/s (see [`GateParams::default`]).
    pub max_velocity_sigma_mps: f64,
    /// Resolution of a measured horizontal velocity component, m/s (1 kt).
    pub speed_quantum_mps: f64,
    /// Resolution of a measured vertical rate, m/s (64 ft/min).
    pub vrate_quantum_mps: f64,
    /// Reports over which the vertical rate's noise is learned from successive reports
    /// ([`DiffNoise`]); 0 keeps the stated σ (capped at `max_velocity_sigma_mps`).
    pub vrate_noise_window_reports: f64,
}

impl GateParams {
    /// The most reports a test reads (the largest of the windows, the onset test's
    /// reference and its newest reports together), within 2..=[`GATE_CAPACITY`]: what the
    /// gate's buffer holds.
    pub fn longest_window(&self) -> usize {
        [
            self.window_reports,
            self.turn_window_reports,
            self.vertical_window_reports,
            self.trend_window_reports,
            self.onset_reference_reports
                .saturating_add(self.onset_reports),
            self.accel_onset_reference_reports
                .saturating_add(self.accel_onset_reports),
        ]
        .into_iter()
        .max()
        .unwrap_or(GATE_CAPACITY)
        .clamp(2, GATE_CAPACITY)
    }

    /// Paper 002's gate as printed (§2): N = 5, λv = 10 m/s, λa = 5 m/s², λφ = 1°, λβ = 5°,
    /// changes between the first and the last report of the window, no significance test,
    /// no hysteresis.
    pub fn paper002() -> Self {
        Self {
            window_reports: 5,
            speed_change_mps: Some(10.0),
            accel_change_mps2: Some(5.0),
            heading_change_deg: Some(1.0),
            pitch_change_deg: Some(5.0),
            turn_rate_deg_s: None,
            turn_window_reports: 5,
            onset_reports: 0,
            onset_reference_reports: 8,
            onset_sigmas: 4.0,
            first_report_turn_sigmas: None,
            turn_end_sigmas: None,
            along_track_accel_mps2: None,
            accel_hold_sigmas: None,
            accel_onset_reports: 0,
            accel_onset_reference_reports: 12,
            vertical_rate_mps: None,
            vertical_window_reports: 6,
            vertical_onset_sigmas: None,
            vertical_onset_altitude_sigmas: None,
            trend_window_reports: 12,
            max_window_s: 30.0,
            significance_sigmas: 0.0,
            release_ratio: 1.0,
            min_speed_mps: 10.0,
            max_velocity_sigma_mps: f64::INFINITY,
            speed_quantum_mps: KNOT_MPS,
            vrate_quantum_mps: VRATE_LSB_MPS,
            vrate_noise_window_reports: 0.0,
        }
    }
}

impl Default for GateParams {
    /// The rate gates of the module doc: turn rate > 0.5°/s over 5 reports (and the onset
    /// test over the newest 1-3 against 8 before), along-track acceleration > 0.3 m/s² over
    /// 24 (12 s at ADS-B's 2 Hz: with NACv 2 velocity noise, σ ≈ 1.2 m/s, a 0.4-1 m/s²
    /// take-off acceleration is 4σ-significant over 24 reports but not over 12; measured on
    /// the departure scenario: labels right 91 % vs 68 %), vertical rate > 1.5 m/s over 6,
    /// each significant at k = 4σ; released at 0.6 of the threshold; windows cut at 15 s.
    /// The measured
    /// velocity σ is capped at 1.5 m/s for the significance test: the NACv category bounds
    /// a 95 % error (NACv 1: < 10 m/s) while GNSS ground velocity is good to a few tenths of
    /// a m/s, the 1-kt resolution dominating, and a conservative NACv must not blind the gate.
    fn default() -> Self {
        Self {
            window_reports: 5,
            speed_change_mps: None,
            accel_change_mps2: None,
            heading_change_deg: None,
            pitch_change_deg: None,
            turn_rate_deg_s: Some(0.5),
            turn_window_reports: 5,
            onset_reports: 3,
            onset_reference_reports: 8,
            onset_sigmas: 4.0,
            first_report_turn_sigmas: Some(FIRST_REPORT_TURN_SIGMAS),
            turn_end_sigmas: Some(TURN_END_SIGMAS),
            along_track_accel_mps2: Some(0.3),
            accel_hold_sigmas: Some(ACCEL_HOLD_SIGMAS),
            accel_onset_reports: 12,
            accel_onset_reference_reports: 12,
            vertical_rate_mps: Some(1.5),
            vertical_window_reports: 6,
            vertical_onset_sigmas: Some(VERTICAL_ONSET_SIGMAS),
            vertical_onset_altitude_sigmas: Some(VERTICAL_ONSET_ALTITUDE_SIGMAS),
            trend_window_reports: 24,
            max_window_s: 15.0,
            significance_sigmas: 4.0,
            release_ratio: 0.6,
            min_speed_mps: 10.0,
            max_velocity_sigma_mps: 1.5,
            speed_quantum_mps: KNOT_MPS,
            vrate_quantum_mps: VRATE_LSB_MPS,
            vrate_noise_window_reports: 50.0,
        }
    }
}

/// One velocity in the window, with what the tests need precomputed (56 bytes: the gate is
/// per aircraft, and memory at fleet scale is per aircraft; the wrapped heading is kept for
/// the newest sample alone, [`Gate::newest_angle_rad`], and the heading's variance is
/// computed where it is read, [`Sample::heading_var`]).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
struct Sample {
    t_s: f64,
    /// Ground speed, m/s.
    speed_mps: f64,
    /// Heading as a math angle atan2(vn, ve) (counter-clockwise from east), unwrapped from
    /// the previous sample's (continuous through ±π), rad.
    heading_rad: f64,
    /// Vertical rate, m/s (NaN-free; meaningful only when `var_u` is finite).
    vu_mps: f64,
    /// Variance of one horizontal component, (m/s)².
    var_h: f64,
    /// Variance of the vertical rate, (m/s)²; infinite when not measured.
    var_u: f64,
    /// The newest barometric altitude when this sample came ([`Gate::altitude`]), m; −∞
    /// before any (not NaN: a gate must compare equal to its copy). An f32 (a millimetre
    /// at 12 km) in the padding beside `measured`: the sample stays 56 bytes.
    alt_m: f32,
    /// From a velocity report (not derived from a filter).
    measured: bool,
}

impl Sample {
    /// Variance of the heading, rad²: the horizontal component variance over speed².
    /// Computed when read: kept in the sample, it took 8 of its 64 bytes to save one
    /// division per read, and only the turn tests read it.
    fn heading_var(&self) -> f64 {
        self.var_h / (self.speed_mps * self.speed_mps)
    }
}

/// Which tests hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct GateFlags {
    /// Turn rate.
    pub turn: bool,
    /// Turn onset: the newest reports leave a straight reference at a rate.
    pub turn_onset: bool,
    /// The newest report alone leaves a straight reference at a rate
    /// ([`GateParams::first_report_turn_sigmas`]): a turn label, not a manoeuvre (not in
    /// [`GateFlags::any`]).
    pub turn_first_report: bool,
    /// The held turn has ended: the newest reports leave its line for a rate under the
    /// threshold ([`GateParams::turn_end_sigmas`]). A label, not a manoeuvre's end: the turn
    /// tests still hold (and keep the IMM) until they release.
    pub turn_end: bool,
    /// Along-track acceleration.
    pub along_track: bool,
    /// Acceleration onset: the newest reports leave a steady reference speed at a rate.
    pub accel_onset: bool,
    /// Vertical rate.
    pub vertical: bool,
    /// Paper's Δv.
    pub speed_change: bool,
    /// Paper's Δa.
    pub accel_change: bool,
    /// Paper's Δφ.
    pub heading_change: bool,
    /// Paper's Δβ.
    pub pitch_change: bool,
}

impl GateFlags {
    /// Any test holds: a manoeuvre.
    pub fn any(&self) -> bool {
        self.turning() || self.speed_changing() || self.vertical || self.pitch_change
    }

    /// A turn test holds: the turn rate, its onset or the paper's Δφ.
    pub fn turning(&self) -> bool {
        self.turn || self.turn_onset || self.heading_change
    }

    /// A speed test holds: the along-track acceleration, its onset, the paper's Δv or Δa.
    pub fn speed_changing(&self) -> bool {
        self.along_track || self.accel_onset || self.speed_change || self.accel_change
    }
}

/// The statistics of the last evaluation and the tests that hold.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct GateReading {
    /// Turn rate, rad/s, positive = left (counter-clockwise).
    pub turn_rate_rad_s: Option<f64>,
    /// Rate of the turn since its onset, rad/s, positive = left: set when the onset test
    /// holds.
    pub onset_turn_rate_rad_s: Option<f64>,
    /// Along-track acceleration, m/s².
    pub along_track_accel_mps2: Option<f64>,
    /// Acceleration since its onset, m/s²: set when the acceleration onset test was
    /// evaluated (the along-track test not holding).
    pub onset_accel_mps2: Option<f64>,
    /// Mean vertical rate, m/s.
    pub vertical_rate_mps: Option<f64>,
    /// Paper's Δv (last − first), m/s. This and the next four are computed only when one
    /// of the paper's tests is configured.
    pub speed_change_mps: Option<f64>,
    /// Paper's Δa (last − first), m/s².
    pub accel_change_mps2: Option<f64>,
    /// Paper's Δφ (last − first, counter-clockwise positive), rad.
    pub heading_change_rad: Option<f64>,
    /// Paper's Δβ (last − first), rad.
    pub pitch_change_rad: Option<f64>,
    /// Flight-path angle of the newest report, rad.
    pub pitch_rad: Option<f64>,
    /// The tests that hold.
    pub flags: GateFlags,
}

impl GateReading {
    /// A manoeuvre: some test holds.
    pub fn manoeuvre(&self) -> bool {
        self.flags.any()
    }

    /// Transversal movement: a turn test holds, in the direction of the turn.
    pub fn lateral(&self) -> Lateral {
        self.lateral_with(true)
    }

    /// [`GateReading::lateral`] of the tests alone, without the label-only flags
    /// ([`GateFlags::turn_first_report`], [`GateFlags::turn_end`]): what the tracker's
    /// filters act on (the turn rate its CT models take), so that those labels move no
    /// estimate.
    pub fn tested_lateral(&self) -> Lateral {
        self.lateral_with(false)
    }

    /// Transversal movement, with or without the label-only flags.
    fn lateral_with(&self, label_only: bool) -> Lateral {
        let f = &self.flags;
        let sign = if label_only && f.turn_end {
            None
        } else if f.turn {
            self.turn_rate_rad_s
        } else if f.turn_onset || (label_only && f.turn_first_report) {
            self.onset_turn_rate_rad_s
        } else if f.heading_change {
            self.heading_change_rad
        } else {
            None
        };
        match sign {
            Some(s) if s > 0.0 => Lateral::Left,
            Some(s) if s < 0.0 => Lateral::Right,
            _ => Lateral::Straight,
        }
    }

    /// The along-track acceleration of the rate test that holds (the trend test's, else the
    /// onset test's), m/s²; `None` when neither holds.
    pub fn along_track_rate_mps2(&self) -> Option<f64> {
        if self.flags.along_track {
            self.along_track_accel_mps2
        } else if self.flags.accel_onset {
            self.onset_accel_mps2
        } else {
            None
        }
    }

    /// Longitudinal movement.
    pub fn speed(&self) -> SpeedTrend {
        let sign = if self.flags.along_track || self.flags.accel_onset {
            self.along_track_rate_mps2()
        } else if self.flags.speed_change {
            self.speed_change_mps
        } else if self.flags.accel_change {
            self.accel_change_mps2
        } else {
            None
        };
        match sign {
            Some(s) if s > 0.0 => SpeedTrend::Increasing,
            Some(s) if s < 0.0 => SpeedTrend::Decreasing,
            _ => SpeedTrend::Constant,
        }
    }

    /// Vertical movement (for the paper's pitch test, the sign of the newest pitch).
    pub fn vertical(&self) -> VerticalTrend {
        let sign = if self.flags.vertical {
            self.vertical_rate_mps
        } else if self.flags.pitch_change {
            self.pitch_rad
        } else {
            None
        };
        match sign {
            Some(s) if s > 0.0 => VerticalTrend::Climb,
            Some(s) if s < 0.0 => VerticalTrend::Descent,
            _ => VerticalTrend::Level,
        }
    }

    /// The label the tests point at: a turn → CT (with its direction); else a vertical and
    /// a speed change → CHCA; vertical alone → CH; speed alone → CA. `None` when no test
    /// holds.
    pub fn label(&self) -> Option<(FlightMode, Option<TurnDirection>)> {
        self.label_with(self.lateral())
    }

    /// [`GateReading::label`] of the tests alone (as [`GateReading::tested_lateral`]): the
    /// mode the tracker's IMM enters with.
    pub fn tested_label(&self) -> Option<(FlightMode, Option<TurnDirection>)> {
        self.label_with(self.tested_lateral())
    }

    /// The label for a transversal movement `lateral`.
    fn label_with(&self, lateral: Lateral) -> Option<(FlightMode, Option<TurnDirection>)> {
        match lateral {
            Lateral::Left => return Some((FlightMode::Ct, Some(TurnDirection::Left))),
            Lateral::Right => return Some((FlightMode::Ct, Some(TurnDirection::Right))),
            Lateral::Straight => {}
        }
        let vertical = self.vertical() != VerticalTrend::Level;
        let speed = self.speed() != SpeedTrend::Constant;
        match (vertical, speed) {
            (true, true) => Some((FlightMode::Chca, None)),
            (true, false) => Some((FlightMode::Ch, None)),
            (false, true) => Some((FlightMode::Ca, None)),
            (false, false) => None,
        }
    }
}

/// Wraps the difference of two angles in (−π, π] (so the difference is in (−2π, 2π))
/// back into (−π, π].
fn wrap_pi(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    if a > PI {
        a - TAU
    } else if a <= -PI {
        a + TAU
    } else {
        a
    }
}

/// The sums a least-squares line through points (t, y) with per-point variances v needs,
/// gathered in one pass: n, Σt, Σt², Σy, Σty, Σv. The gate takes t and y from the newest
/// report (t − t_newest, y − y_newest), so that n Σty − Σt Σy works on numbers of a few
/// seconds and units and does not cancel; every window the gate reads is then a run of
/// these sums over its newest reports, which one pass over the buffer gives all together
/// ([`Gate::evaluate`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct LineSums {
    n: f64,
    st: f64,
    stt: f64,
    sy: f64,
    sty: f64,
    sv: f64,
}

impl LineSums {
    #[inline(always)]
    fn add(&mut self, t: f64, y: f64, v: f64) {
        self.n += 1.0;
        self.st += t;
        self.stt += t * t;
        self.sy += y;
        self.sty += t * y;
        self.sv += v;
    }

    /// Least-squares slope of y(t) and its σ for the per-point variance Σv/n:
    /// slope = Σ(t − t̄)(y − ȳ) / Σ(t − t̄)², σ² = (Σv/n) / Σ(t − t̄)², from the sums as
    /// (n Σty − Σt Σy) / (n Σt² − (Σt)²) and Σv / (n Σt² − (Σt)²). `None` with fewer than 3
    /// points, no spread in t, or a non-finite result.
    fn slope(&self) -> Option<(f64, f64)> {
        if self.n < 3.0 {
            return None;
        }
        let sxx = self.n * self.stt - self.st * self.st;
        if sxx <= 0.0 {
            return None;
        }
        let slope = (self.n * self.sty - self.st * self.sy) / sxx;
        let sigma = (self.sv / sxx).sqrt();
        (slope.is_finite() && sigma.is_finite()).then_some((slope, sigma))
    }
}

/// A window's [`LineSums`], with how many of its samples were too slow for a heading and
/// how many were derived (not measured): the tests that cannot use such samples skip the
/// window.
#[derive(Clone, Copy, Debug, Default)]
struct Run {
    sums: LineSums,
    slow: usize,
    derived: usize,
}

impl Run {
    /// The runs of the newest `a` and of the newest `b` samples of `held` (both at most its
    /// length), each sample added by `add`, newest first, in one pass over the longer.
    #[inline(always)]
    fn two(held: &[Sample], a: usize, b: usize, add: impl Fn(&mut Run, &Sample)) -> (Run, Run) {
        let (short, long) = (a.min(b), a.max(b));
        let mut run = Run::default();
        let mut newest_first = held.iter().rev();
        for s in newest_first.by_ref().take(short) {
            add(&mut run, s);
        }
        let at_short = run;
        for s in newest_first.take(long - short) {
            add(&mut run, s);
        }
        if a <= b {
            (at_short, run)
        } else {
            (run, at_short)
        }
    }
}

/// The sums over the newest m reports of a split (Σt, Σt², Σy, Σty, in the shifted
/// coordinates of [`LineSums`]), added one report per m, and what a hinge
/// h = max(0, t − t_ref) at the last report before them makes of them: h is zero before
/// t_ref, so only these reports add to Σh, Σh², Σhy and Σth. Shared by the onset and the
/// end tests ([`hinge_onset`], [`hinge_end`]).
#[derive(Clone, Copy, Debug, Default)]
struct NewestSums {
    st: f64,
    stt: f64,
    sy: f64,
    sty: f64,
}

/// [`NewestSums`]' hinge sums at one t_ref: (Σh, Σh², Σhy, Σth).
struct HingeSums {
    sh: f64,
    shh: f64,
    shy: f64,
    sth: f64,
}

impl NewestSums {
    #[inline(always)]
    fn add(&mut self, t: f64, y: f64) {
        self.st += t;
        self.stt += t * t;
        self.sy += y;
        self.sty += t * y;
    }

    /// The hinge's sums for the `m` reports added, the hinge at `t_ref`:
    /// Σh = Σt − m t_ref, Σh² = Σt² − 2 t_ref Σt + m t_ref², Σhy = Σty − t_ref Σy,
    /// Σth = Σt² − t_ref Σt.
    #[inline(always)]
    fn hinge(&self, m: usize, t_ref: f64) -> HingeSums {
        let mf = m as f64;
        HingeSums {
            sh: self.st - mf * t_ref,
            shh: self.stt - 2.0 * t_ref * self.st + mf * t_ref * t_ref,
            shy: self.sty - t_ref * self.sy,
            sth: self.stt - t_ref * self.st,
        }
    }
}

/// A hinge fit found by [`hinge_onset`]: (rate since the onset, its σ, t_ref).
type HingeFit = (f64, f64, f64);

/// The split m = 1 of [`hinge_onset`]: what the first-report test reads
/// ([`first_report_fires`]), gathered by the onset test's own pass.
#[derive(Clone, Copy, Debug, PartialEq)]
struct FirstSplit {
    /// n·Σ(h − h̄)(y − ȳ) and n·Σ(h − h̄)² of the hinge at the newest report.
    n_hy: f64,
    n_hxx: f64,
    /// The reference's (every report but the newest) k·Σ(t − t̄)(y − ȳ) and k·Σ(t − t̄)²,
    /// k its count: its own slope is the first over the second.
    k_ref_ty: f64,
    k_ref_tt: f64,
    k_ref: f64,
}

/// The onset test (module doc) on a series y(t) with per-report variance: for m =
/// 1..=`max_newest`, the newest m of `all` are taken as the first of a change and the reports
/// before them (at least 3) as the steady reference; y is fitted as a + b·max(0, t − t_ref)
/// (t_ref the last reference report) by least squares. Returns the strongest fit in σ, as
/// (b, its σ, t_ref), over the splits whose reference is steady (its own slope under
/// `lambda`: the end of a change must not read as the onset of another).
///
/// Also returns the split m = 1 alone, when its reference is steady ([`FirstSplit`]).
///
/// `ty` gives a report's (t, y) in the shifted coordinates of [`LineSums`], and `totals`
/// are the sums over every report of `all` in them; t_ref is returned in them too. Each
/// split's reference is the totals less the newest m, and the newest m's own sums, added one
/// report per m, give the hinge's ([`NewestSums`]): O(m) for every split together (the test
/// runs on every report of every aircraft).
fn hinge_onset(
    all: &[Sample],
    totals: &LineSums,
    max_newest: usize,
    lambda: f64,
    ty: impl Fn(&Sample) -> (f64, f64),
) -> (Option<HingeFit>, Option<FirstSplit>) {
    let LineSums {
        mut st,
        mut stt,
        mut sy,
        mut sty,
        sv: sum_var,
        ..
    } = *totals;
    let n = all.len();
    let (nf, sum_y) = (n as f64, sy);
    let mut newest = NewestSums::default();
    // The strongest split so far as (n·Σ(h − h̄)(y − ȳ), n·Σ(h − h̄)², t_ref): its slope is
    // the first over the second, and its significance² the first² / (second · Σvar), so
    // splits compare by cross-multiplication, with no division in the loop (divisions
    // were most of the test's cost).
    let mut best: Option<(f64, f64, f64)> = None;
    let mut first = None;
    for m in 1..=max_newest {
        let Some(split) = n.checked_sub(m).filter(|&s| s >= 3) else {
            break;
        };
        // The newest m leave the reference: its own slope, k Σ(t − t̄)(y − ȳ) over
        // k Σ(t − t̄)², must be under λ.
        let Some((t, y)) = all.get(split).map(&ty) else {
            break;
        };
        st -= t;
        stt -= t * t;
        sy -= y;
        sty -= t * y;
        newest.add(t, y);
        let k = split as f64;
        let k_sxx = k * stt - st * st;
        if k_sxx <= 0.0 || (k * sty - st * sy).abs() >= lambda * k_sxx {
            continue;
        }
        // The hinge h = max(0, t − t_ref): zero on the reference, so only the newest m
        // reports add to Σh, Σh², Σhy.
        let Some(t_ref) = all.get(split - 1).map(|s| ty(s).0) else {
            break;
        };
        let HingeSums { sh, shh, shy, .. } = newest.hinge(m, t_ref);
        let n_hxx = nf * shh - sh * sh;
        if n_hxx <= 0.0 {
            continue;
        }
        let n_hy = nf * shy - sh * sum_y;
        if m == 1 {
            first = Some(FirstSplit {
                n_hy,
                n_hxx,
                k_ref_ty: k * sty - st * sy,
                k_ref_tt: k_sxx,
                k_ref: k,
            });
        }
        if best.is_none_or(|(hy0, hxx0, _)| n_hy * n_hy * hxx0 > hy0 * hy0 * n_hxx) {
            best = Some((n_hy, n_hxx, t_ref));
        }
    }
    // b = Σ(h − h̄)(y − ȳ) / Σ(h − h̄)², σ² = (Σvar / n) / Σ(h − h̄)².
    let best = best.and_then(|(n_hy, n_hxx, t_ref)| {
        let (b, sigma) = (n_hy / n_hxx, (sum_var / n_hxx).sqrt());
        (b.is_finite() && sigma.is_finite()).then_some((b, sigma, t_ref))
    });
    (best, first)
}

/// The first-report test on [`hinge_onset`]'s m = 1 split, over `n` reports with variances
/// summing to `sum_var`: its rate b = n_hy / n_hxx above λ and k σ (σ² = Σvar / n_hxx), and
/// its reference not drifting (its own slope within [`FIRST_REPORT_MAX_DRIFT_Z`] of its σ,
/// at the mean variance: σ² = (Σvar / n)·k_ref / k_ref_tt). Compared squared, without a
/// division or a root (every denominator is positive). Returns the rate when it fires.
fn first_report_fires(
    split: &FirstSplit,
    n: f64,
    sum_var: f64,
    lambda: f64,
    k: f64,
) -> Option<f64> {
    let FirstSplit {
        n_hy,
        n_hxx,
        k_ref_ty,
        k_ref_tt,
        k_ref,
    } = *split;
    let fires = n_hy.abs() > lambda * n_hxx && n_hy * n_hy > k * k * sum_var * n_hxx;
    // The drift is checked last: few reports get that far.
    let z2 = FIRST_REPORT_MAX_DRIFT_Z * FIRST_REPORT_MAX_DRIFT_Z;
    (fires && k_ref_ty * k_ref_ty < z2 * k_ref_tt * (sum_var / n) * k_ref).then(|| n_hy / n_hxx)
}

/// The end test (module doc) on a series y(t) (per-report variance) that holds a
/// manoeuvre: for m = [`END_MIN_NEWEST`]..=`max_newest`, the newest m of `points` are
/// taken as the first after its end and the reports before them (at least
/// [`END_MIN_REFERENCE`]) as the manoeuvre; y is fitted as a + b·t + c·max(0, t − t_ref)
/// (t_ref the last reference report) by least squares, b the manoeuvre's rate and b + c
/// the rate since. The end
/// fires for a split whose reference is a manoeuvre (|b| > λ), whose change is against it
/// and significant (c·b < 0, |c| > k σ_c), and whose rate since is consistent with one
/// under the threshold (|b + c| < λ + 2 σ of b + c). Returns the rate since of the most
/// significant such split.
///
/// Why a line for the reference: at a turn's end the turn-rate test's five-report slope
/// falls off only as the window slides past the end (3.4 s at paper 002's 3°/s and one
/// report a second), where the turn's own line, known from the reports since it began,
/// tells the newest reports off it after two reports. Every sum is in the shifted
/// coordinates of [`LineSums`]; with n·S the centred sums times n, the 2×2 system of
/// (b, c) has determinant D = n·Stt n·Shh − (n·Sth)², c = (n·Stt n·Shy − n·Sth n·Sty) / D
/// and var c = Σvar · n·Stt / D (Σvar/n the per-report variance), var(b + c) =
/// Σvar · (n·Stt + n·Shh − 2 n·Sth) / D.
fn hinge_end(
    points: impl DoubleEndedIterator<Item = (f64, f64, f64)> + Clone,
    max_newest: usize,
    lambda: f64,
    k: f64,
) -> Option<f64> {
    let mut totals = LineSums::default();
    for (t, y, v) in points.clone() {
        totals.add(t, y, v);
    }
    let LineSums {
        n,
        st,
        stt,
        sy,
        sty,
        sv,
    } = totals;
    let n_tt = n * stt - st * st;
    let n_ty = n * sty - st * sy;
    // The newest m's sums, newest first; the hinge is at the report before them.
    let mut newest = NewestSums::default();
    let mut newest_first = points.rev();
    // The strongest split so far as (c·D, D · Σvar · n·Stt, b + c).
    let mut best: Option<(f64, f64, f64)> = None;
    for m in 1..=max_newest {
        if n < (m + END_MIN_REFERENCE) as f64 {
            break;
        }
        let (t, y, _) = newest_first.next()?;
        newest.add(t, y);
        if m < END_MIN_NEWEST {
            continue;
        }
        // The peek is the last reference report: t_ref.
        let (t_ref, _, _) = newest_first.clone().next()?;
        let HingeSums { sh, shh, shy, sth } = newest.hinge(m, t_ref);
        let n_hh = n * shh - sh * sh;
        let n_th = n * sth - st * sh;
        let n_hy = n * shy - sh * sy;
        let d = n_tt * n_hh - n_th * n_th;
        if d.is_nan() || d <= 0.0 {
            continue;
        }
        // c·D and b·D: the tests compare them against D's multiples, with no division
        // (as in `hinge_onset`).
        let nc = n_tt * n_hy - n_th * n_ty;
        let nb = n_hh * n_ty - n_th * n_hy;
        // The reference is a manoeuvre (|b| > λ) and the change is against it (c·b < 0).
        if nb.abs() <= lambda * d || nc * nb >= 0.0 {
            continue;
        }
        // Significant: c² / var c = (c·D)² / (D · Σvar · n·Stt) > k².
        let z_den = d * sv * n_tt;
        if nc * nc <= k * k * z_den {
            continue;
        }
        // The rate since is consistent with one under λ: |b + c| < λ + 2 σ(b + c).
        let since_d = nb + nc;
        let var_since_d2 = sv * (n_tt + n_hh - 2.0 * n_th) * d;
        if since_d.abs() >= lambda * d + 2.0 * var_since_d2.max(0.0).sqrt() {
            continue;
        }
        // The strongest split: z² compared by cross-multiplication.
        if best.is_none_or(|(nc0, den0, _)| nc * nc * den0 > nc0 * nc0 * z_den) {
            best = Some((nc, z_den, since_d / d));
        }
    }
    best.map(|(_, _, since)| since).filter(|s| s.is_finite())
}

/// Fewest reports the end test ([`hinge_end`]) takes as the manoeuvre's line.
const END_MIN_REFERENCE: usize = 4;

/// Fewest reports after the end the end test takes: one report never ends a turn. Real
/// velocity reports have outliers a split of one would read as an end (AFR34ZG's
/// mid-turn heading jumps of 1.3° against a 2°/s turn at 124 m/s: with single-report ends
/// allowed, 42 turn labels ended on that flight where 28 did without the test, 31 of them
/// back to a turn within 10 s; with two, 35 and 24), and where a turn's end is two reports
/// old the two-report split tells it anyway (paper 002: ends labelled after 1.87 s instead
/// of 1.77 s, 100 runs).
const END_MIN_NEWEST: usize = 2;

/// Most reports the turn's end test tries as the first after the end: the turn-rate test
/// (five reports) releases within about as many after a turn's end, and the end label must
/// cover the reports until it does.
const END_TURN_REPORTS: usize = 8;

/// The largest |slope / σ| of the first-report test's reference: a reference that drifts
/// (a gentle turn under λ, a heading wandering with the wind) makes the newest report's
/// offset from the reference's mean grow with the reference's length, which the test
/// would read as an onset.
const FIRST_REPORT_MAX_DRIFT_Z: f64 = 2.0;

/// The noise variance of a measured series, learned from the differences of successive
/// reports (von Neumann et al. 1941, "Distribution of the ratio of the mean square successive
/// difference to the variance", Ann. Math. Stat. 12(4)): for reports yₖ = xₖ + vₖ of a
/// slowly varying x with white noise of variance σ², E[(yₖ − yₖ₋₁)²] = 2σ² + (xₖ − xₖ₋₁)²,
/// so half the mean squared difference estimates σ², biased up by the trend's own step (a
/// 1 m/s² vertical acceleration adds 0.125 (m/s)² at 2 Hz). It needs no model and no
/// filter, and a steady climb teaches the same noise as level flight.
///
/// Why the gate learns the vertical rate's noise: NACv's vertical bound (NACv 2: 15 ft/s,
/// σ 2.3 m/s) is far above what barometric rates scatter (64 ft/min steps, constant in
/// level flight), so the gate capped the stated σ at `max_velocity_sigma_mps` (1.5 m/s);
/// where the rate really is that noisy, the capped σ made the vertical test fire on level
/// flight (the departure scenario, NACv 2 simulated at its bound: 4.7 s of false climb
/// labels in a run). Learned, each aircraft's test uses its own scatter.
///
/// The declared (capped) variance is the prior, worth [`DIFF_NOISE_PRIOR`] reports; the
/// mean is exponential over the window; a difference is winsorised at
/// [`DIFF_NOISE_WINSOR`] times the current σ² so that the step of a climb's onset moves it
/// by a bounded amount.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct DiffNoise {
    /// σ² learned, (m/s)²; 0 before the first report (after it, never 0: the prior is at
    /// least the quantisation's variance and each step keeps a share of it), which keeps
    /// the gate within its 256 bytes.
    var: f64,
    /// Differences averaged so far (capped at the window).
    n: f64,
}

/// Weight of the declared variance in [`DiffNoise`], in reports.
const DIFF_NOISE_PRIOR: f64 = 10.0;
/// A squared difference counts at most this many times the current σ² (4σ).
const DIFF_NOISE_WINSOR: f64 = 16.0;
/// Reports further apart than this are not differenced (the trend's step would dominate), s.
const DIFF_NOISE_MAX_GAP_S: f64 = 2.0;

impl DiffNoise {
    /// Starts from the declared variance `prior` if nothing is learned yet.
    fn prime(&mut self, prior: f64) {
        if self.var == 0.0 {
            self.var = prior;
        }
    }

    /// σ², once a report was seen.
    fn var(&self) -> Option<f64> {
        (self.var > 0.0).then_some(self.var)
    }

    /// Learns from the difference `d` of two successive reports.
    fn learn(&mut self, d: f64, window: f64) {
        if self.var().is_none() || !d.is_finite() {
            return;
        }
        let sample = (0.5 * d * d).min(DIFF_NOISE_WINSOR * self.var);
        self.n = (self.n + 1.0).min(window);
        let w = 1.0 / (self.n + DIFF_NOISE_PRIOR).min(window);
        self.var += w * (sample - self.var);
    }
}

/// The gate: a window of the last velocities and the state of its hysteresis.
///
/// The samples live in a sliding buffer of the longest window the tests read
/// ([`GateParams::longest_window`]) plus [`GATE_SLACK`]: written in order, and when the end
/// is reached the newest capacity − 1 slide back to the front (one 1.3 KB copy every fourth
/// report with the default windows). The newest n are always one contiguous slice, so
/// every test is a plain loop over a slice with no modulo; and the buffer is 1.5 KB with
/// the default windows (the gate is per aircraft: memory at fleet scale).
#[derive(Clone, Debug, PartialEq)]
pub struct Gate {
    params: Arc<GateParams>,
    samples: Box<[Sample]>,
    /// One past the newest sample.
    end: usize,
    /// Samples held (at most the longest window), the newest `len` before `end`.
    len: usize,
    /// The newest sample's heading wrapped to (−π, π], rad: what the next one unwraps
    /// from.
    newest_angle_rad: f64,
    reading: GateReading,
    /// Feed time the current turn began (the last straight report before it), while a turn
    /// test holds.
    turn_start_s: Option<f64>,
    /// The measured vertical rate's noise, learned ([`DiffNoise`]).
    vrate_noise: DiffNoise,
    /// While an acceleration is held: the line sums of every measured report since it
    /// fired, t and y from the first of them (its time, s, and ground speed, m/s).
    accel_since: Option<(f64, f64, LineSums)>,
    /// The newest barometric altitude ([`Gate::altitude`]), m; −∞ before any.
    alt_m: f64,
}

impl Gate {
    /// An empty gate.
    pub fn new(params: GateParams) -> Self {
        Self {
            samples: vec![Sample::default(); params.longest_window() + GATE_SLACK]
                .into_boxed_slice(),
            params: super::shared::shared(params),
            end: 0,
            len: 0,
            newest_angle_rad: 0.0,
            reading: GateReading::default(),
            turn_start_s: None,
            vrate_noise: DiffNoise::default(),
            accel_since: None,
            alt_m: f64::NEG_INFINITY,
        }
    }

    /// The tuning in use.
    pub fn params(&self) -> &GateParams {
        &self.params
    }

    /// Forgets every sample (a new track).
    pub fn clear(&mut self) {
        self.len = 0;
        self.end = 0;
        self.reading = GateReading::default();
        self.turn_start_s = None;
        self.accel_since = None;
        self.vrate_noise = DiffNoise::default();
        self.alt_m = f64::NEG_INFINITY;
    }

    /// Notes a measured barometric altitude, m (height above the sphere, from a position
    /// report): what the altitude-confirmed climb onset reads
    /// ([`GateParams::vertical_onset_altitude_sigmas`]). Evaluates nothing: the next
    /// velocity does.
    pub fn altitude(&mut self, alt_m: f64) {
        if alt_m.is_finite() {
            self.alt_m = alt_m;
        }
    }

    /// The rate of the current turn, rad/s (+ = left): the least-squares slope of the
    /// heading over the reports since the turn began (at most the trend window's), the rate
    /// the CT models and the prediction should use. Over a fixed long window the straight
    /// reports before the turn would dilute it for as long as the window (24 reports: 12 s
    /// at 2 Hz, i.e. most of a 90° turn at 3°/s); over the short one it is noisy. `None`
    /// while no turn test holds. Computed on demand.
    pub fn turn_rate_since_start_rad_s(&self) -> Option<f64> {
        let start = self.turn_start_s?;
        let window = self.recent(self.params.trend_window_reports);
        let first = window.partition_point(|s| s.t_s < start);
        if let Some(since) = window.get(first..).filter(|w| w.len() >= 3) {
            if let Some((slope, _)) = self.heading_slope_of(since) {
                return Some(slope);
            }
        }
        let r = &self.reading;
        if r.flags.turn {
            r.turn_rate_rad_s
        } else {
            r.onset_turn_rate_rad_s
        }
    }

    /// The last evaluation.
    pub fn reading(&self) -> &GateReading {
        &self.reading
    }

    /// Samples held at most: the longest window.
    fn capacity(&self) -> usize {
        self.samples.len().saturating_sub(GATE_SLACK).max(1)
    }

    /// Number of samples held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// No samples held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The newest sample.
    fn newest(&self) -> Option<&Sample> {
        self.recent(1).last()
    }

    /// The newest `n` samples within `max_window_s` of the newest, oldest first.
    fn recent(&self, n: usize) -> &[Sample] {
        let k = n.min(self.len);
        let held = self
            .samples
            .get(self.end.saturating_sub(k)..self.end)
            .unwrap_or(&[]);
        let Some(newest) = held.last() else {
            return held;
        };
        let oldest_t = newest.t_s - self.params.max_window_s;
        // Samples are in time order: the window starts after the newest one older than the
        // cut. Scanned from the newest, which touches only samples the caller reads next; a
        // binary search probed the middle of the buffer, which at fleet scale is out of cache
        // (`Gate::push` went from 11.3 to 8.4 % of a 1000-aircraft replay's profile). (Finding
        // the cut once per push instead of per window saved nothing measurable and took 8
        // bytes the gate's memory budget does not have, `tests/memory_budget.rs`.)
        let first = held
            .iter()
            .rposition(|s| s.t_s < oldest_t)
            .map_or(0, |i| i + 1);
        held.get(first..).unwrap_or(&[])
    }

    /// Adds a velocity at `t_s` and re-evaluates every test. `measured`: the velocity comes
    /// from a report (quantised, σ capped), not from a filter. A sample older than the
    /// newest is ignored.
    pub fn push(&mut self, t_s: f64, v: &Observed, measured: bool) -> &GateReading {
        if !t_s.is_finite()
            || !v.value.iter().chain(v.cov.iter()).all(|x| x.is_finite())
            || self.newest().is_some_and(|s| t_s < s.t_s)
        {
            return &self.reading;
        }
        let p = &self.params;
        let (ve, vn, vu) = (v.value.x, v.value.y, v.value.z);
        let (quantum_h, quantum_u, cap) = if measured {
            (
                p.speed_quantum_mps.powi(2) / 12.0,
                p.vrate_quantum_mps.powi(2) / 12.0,
                p.max_velocity_sigma_mps.powi(2),
            )
        } else {
            (0.0, 0.0, f64::INFINITY)
        };
        let var_h = (0.5 * (v.cov[(0, 0)] + v.cov[(1, 1)])).min(cap).max(0.0) + quantum_h;
        let var_u = if v.cov[(2, 2)] < 0.5 * UNMEASURED_VARIANCE {
            v.cov[(2, 2)].min(cap).max(0.0) + quantum_u
        } else {
            f64::INFINITY
        };
        let speed_mps = ve.hypot(vn);
        let angle_rad = vn.atan2(ve);
        // The heading unwrapped from the previous sample's: slopes and fits read differences,
        // which a common offset leaves alone.
        let heading_rad = self.newest().map_or(angle_rad, |prev| {
            prev.heading_rad + wrap_pi(angle_rad - self.newest_angle_rad)
        });
        let sample = Sample {
            t_s,
            speed_mps,
            heading_rad,
            vu_mps: vu,
            var_h,
            var_u,
            alt_m: self.alt_m as f32,
            measured,
        };
        if measured && var_u.is_finite() && p.vrate_noise_window_reports > 0.0 {
            // The previous report of a vertical rate, if it is the newest sample and close.
            let previous = self
                .newest()
                .filter(|s| {
                    s.measured && s.var_u.is_finite() && t_s - s.t_s <= DIFF_NOISE_MAX_GAP_S
                })
                .map(|s| s.vu_mps);
            let window = p.vrate_noise_window_reports;
            self.vrate_noise.prime(var_u);
            if let Some(prev_vu) = previous {
                self.vrate_noise.learn(vu - prev_vu, window);
            }
        }
        if self.end >= self.samples.len() {
            // Slide: the newest capacity − 1 to the front; the oldest held one drops.
            let keep = self.len.min(self.capacity() - 1);
            let from = self.end - keep;
            self.samples.copy_within(from..self.end, 0);
            self.end = keep;
        }
        if let Some(s) = self.samples.get_mut(self.end) {
            *s = sample;
        }
        self.end += 1;
        self.len = (self.len + 1).min(self.capacity());
        self.newest_angle_rad = angle_rad;
        self.evaluate();
        &self.reading
    }

    /// Least-squares slope of the unwrapped heading over `window` and its σ; `None` when
    /// fewer than 3 samples or when any is slower than `min_speed_mps` (its heading is then
    /// noise).
    fn heading_slope_of(&self, window: &[Sample]) -> Option<(f64, f64)> {
        let newest = window.last()?;
        let mut sums = LineSums::default();
        for s in window {
            if s.speed_mps < self.params.min_speed_mps {
                return None;
            }
            sums.add(
                s.t_s - newest.t_s,
                s.heading_rad - newest.heading_rad,
                s.heading_var(),
            );
        }
        sums.slope()
    }

    /// Every test on the newest samples (module doc) into `self.reading`.
    ///
    /// The windows are all runs of the newest reports within `max_window_s`, so one pass
    /// from the newest back gathers every window's sums ([`LineSums`]) at once, with counts
    /// of the slow and of the derived samples each has seen:
    /// - the turn-rate test (the heading over `turn_window_reports`, no slow sample),
    /// - the turn onset test (over its reference and newest reports: no slow or derived
    ///   sample),
    /// - the along-track test (the ground speed of the measured samples over
    ///   `trend_window_reports`),
    /// - the acceleration onset test (over its reference and newest reports: no derived
    ///   sample).
    ///
    /// With a pass per test and a window found per test, the gate took 4,140 instructions a
    /// report (15 % of a `hybrid` fleet replay's); with the two passes, 3,460.
    fn evaluate(&mut self) {
        let p = *self.params;
        let old = self.reading.flags;
        let mut r = GateReading::default();
        let held = self.recent(self.capacity());
        let len = held.len();
        let Some(&newest) = held.last() else {
            self.reading = r;
            return;
        };
        let (t0, speed0, heading0) = (newest.t_s, newest.speed_mps, newest.heading_rad);
        let turn_n = p.turn_window_reports.min(len);
        let turn_onset_n = p
            .onset_reference_reports
            .saturating_add(p.onset_reports)
            .min(len);
        let trend_n = p.trend_window_reports.min(len);
        let accel_onset_n = p
            .accel_onset_reference_reports
            .saturating_add(p.accel_onset_reports)
            .min(len);
        let (turn, turn_onset) = Run::two(held, turn_n, turn_onset_n, |run, s| {
            run.slow += usize::from(s.speed_mps < p.min_speed_mps);
            run.derived += usize::from(!s.measured);
            run.sums
                .add(s.t_s - t0, s.heading_rad - heading0, s.heading_var());
        });
        let (trend, accel_onset) = Run::two(held, trend_n, accel_onset_n, |run, s| {
            if s.measured {
                run.sums.add(s.t_s - t0, s.speed_mps - speed0, s.var_h);
            } else {
                run.derived += 1;
            }
        });
        // (t, y) of a sample in the coordinates of the sums.
        let heading_ty = |s: &Sample| (s.t_s - t0, s.heading_rad - heading0);
        let speed_ty = |s: &Sample| (s.t_s - t0, s.speed_mps - speed0);
        let newest_of = |n: usize| held.get(len.saturating_sub(n)..).unwrap_or(&[]);

        // Turn rate: slope of the unwrapped heading (a turn that began with the onset test
        // is held by this one at its release thresholds).
        let lambda_turn = p.turn_rate_deg_s.map(f64::to_radians);
        if let Some((slope, sigma)) = (turn.slow == 0).then(|| turn.sums.slope()).flatten() {
            r.turn_rate_rad_s = Some(slope);
            r.flags.turn = fires(slope, sigma, lambda_turn, old.turn || old.turn_onset, &p);
        }
        // The turn onset test: the strongest (in σ) of the hinge fits of the heading over
        // the newest m = 1..=`onset_reports` reports, as (rate since the onset, its σ, the
        // time of the last straight report). Only measured velocities, and only a
        // reference that is not itself turning (its own slope under λ): the end of a turn
        // must not read as the onset of another.
        let mut onset_s = None;
        if let (false, Some(lambda), true) = (r.flags.turn, lambda_turn, p.onset_reports > 0) {
            if turn_onset.slow == 0 && turn_onset.derived == 0 {
                let all = newest_of(turn_onset_n);
                let (best, first) =
                    hinge_onset(all, &turn_onset.sums, p.onset_reports, lambda, heading_ty);
                if let Some((rate, sigma, t_ref)) = best {
                    r.flags.turn_onset = onset_fires(rate, sigma, lambda, false, &p);
                    r.onset_turn_rate_rad_s = Some(rate);
                    onset_s = Some(t_ref + t0);
                }
                // The first-report test: the newest report's hinge alone, labelled only when
                // its reference does not drift.
                if let (false, Some(k), Some(split)) =
                    (r.flags.turn_onset, p.first_report_turn_sigmas, first)
                {
                    let sums = &turn_onset.sums;
                    if let Some(rate) = first_report_fires(&split, sums.n, sums.sv, lambda, k) {
                        r.flags.turn_first_report = true;
                        r.onset_turn_rate_rad_s = Some(rate);
                    }
                }
            }
        }
        // The turn's end (a label): the reports since the turn began (at most the trend
        // window's, every one measured and fast enough) against the turn's own line.
        if let (true, Some(start), Some(k), Some(lambda)) = (
            r.flags.turn,
            self.turn_start_s,
            p.turn_end_sigmas,
            lambda_turn,
        ) {
            let since = newest_of(trend_n);
            let since = since
                .get(since.partition_point(|s| s.t_s <= start)..)
                .unwrap_or(&[]);
            if since
                .iter()
                .all(|s| s.measured && s.speed_mps >= p.min_speed_mps)
            {
                let points = since.iter().map(|s| {
                    let (t, y) = heading_ty(s);
                    (t, y, s.heading_var())
                });
                r.flags.turn_end = hinge_end(points, END_TURN_REPORTS, lambda, k).is_some();
            }
        }
        // When the current turn began: the onset's reference report, or for a turn the
        // turn-rate test found first, the oldest report of its window.
        let turn_start_s = if !(r.flags.turn || r.flags.turn_onset) {
            None
        } else if let Some(t0) = self.turn_start_s {
            Some(t0)
        } else if r.flags.turn_onset {
            onset_s
        } else {
            newest_of(turn_n).first().map(|s| s.t_s)
        };

        // Along-track acceleration over the trend window (its measured reports).
        if let Some((slope, sigma)) = trend.sums.slope() {
            r.along_track_accel_mps2 = Some(slope);
            // An acceleration that began with the onset test is held by this one at its
            // release thresholds.
            let was = old.along_track || old.accel_onset;
            r.flags.along_track = fires(slope, sigma, p.along_track_accel_mps2, was, &p);
        }
        // The along-track acceleration onset test: the hinge fit on the ground speed over
        // the newest m = 1..=`accel_onset_reports` measured reports against the
        // `accel_onset_reference_reports` before them (derived velocities are too smooth
        // and too correlated for it, as for the trend test).
        if let (false, Some(lambda), true, 0) = (
            r.flags.along_track,
            p.along_track_accel_mps2,
            p.accel_onset_reports > 0,
            accel_onset.derived,
        ) {
            let all = newest_of(accel_onset_n);
            if let (Some((rate, sigma, _)), _) = hinge_onset(
                all,
                &accel_onset.sums,
                p.accel_onset_reports,
                lambda,
                speed_ty,
            ) {
                // With hysteresis, like every rate test: the trend test's slope is still
                // diluted when the onset test finds a gentle acceleration, and would let it
                // flicker.
                let held = old.accel_onset || old.along_track;
                r.flags.accel_onset = onset_fires(rate, sigma, lambda, held, &p);
                r.onset_accel_mps2 = Some(rate);
            }
        }
        // The acceleration's hold: the line since it fired holds it past the trend window's
        // release while the trend's slope is not significantly under that line's.
        let accel_held = old.along_track || old.accel_onset;
        if let (true, false, Some(k), Some((_, _, since))) = (
            accel_held,
            r.flags.along_track || r.flags.accel_onset,
            p.accel_hold_sigmas,
            self.accel_since.as_ref(),
        ) {
            if let (Some((ls, lsig)), Some((ts, tsig))) = (
                (since.n >= ACCEL_HOLD_MIN_REPORTS)
                    .then(|| since.slope())
                    .flatten(),
                trend.sums.slope(),
            ) {
                let below = (ts - ls) * ls.signum();
                if fires(ls, lsig, p.along_track_accel_mps2, true, &p)
                    && below > -k * tsig.hypot(lsig)
                {
                    r.flags.along_track = true;
                    r.along_track_accel_mps2 = Some(ls);
                }
            }
        }
        let accel_since = if r.flags.along_track || r.flags.accel_onset {
            let mut since = self.accel_since;
            if newest.measured {
                let (t_first, y_first, sums) =
                    since.get_or_insert((newest.t_s, newest.speed_mps, LineSums::default()));
                sums.add(
                    newest.t_s - *t_first,
                    newest.speed_mps - *y_first,
                    newest.var_h,
                );
            }
            since
        } else {
            None
        };
        // Each report's variance: the learned one when learning (at least the quantisation's;
        // nothing is learned with `vrate_noise_window_reports` 0), else the stated one.
        let learned_var_u = self
            .vrate_noise
            .var()
            .map(|v| v.max(p.vrate_quantum_mps.powi(2) / 12.0));
        let (mut n, mut sum, mut var) = (0.0, 0.0, 0.0);
        for s in newest_of(p.vertical_window_reports.min(len))
            .iter()
            .filter(|s| s.measured && s.var_u.is_finite())
        {
            n += 1.0;
            sum += s.vu_mps;
            var += learned_var_u.unwrap_or(s.var_u);
        }
        if n > 0.0 {
            let mean = sum / n;
            let sigma = (var / n / n).sqrt();
            r.vertical_rate_mps = Some(mean);
            // Held at the threshold alone: with NACv 2's σ (2.3 m/s) the six-report mean of
            // a 4.5 m/s descent falls under ρ·kσ once in a hundred reports.
            let sigma = if old.vertical { 0.0 } else { sigma };
            r.flags.vertical = fires(mean, sigma, p.vertical_rate_mps, old.vertical, &p);
            // A climb or descent's onset (module doc): the newest m reports' mean against
            // level flight, whose rate is known (0), where the window's mean still
            // averages in the level reports before it.
            if let (false, Some(k)) = (r.flags.vertical, p.vertical_onset_sigmas) {
                // Each report with its index in `held` (in time order), where the
                // altitude-confirmed test finds the altitudes noted with the
                // [`ALTITUDE_REFERENCE_REPORTS`] before it: the level an onset there left.
                // Read only when a mean passes k' σ: most reports never need it.
                let level_before = |i: usize| {
                    let from = i.saturating_sub(ALTITUDE_REFERENCE_REPORTS);
                    altitude_range(held.get(from..i).unwrap_or(&[]))
                };
                let confirm = p
                    .vertical_onset_altitude_sigmas
                    .filter(|_| self.alt_m.is_finite())
                    .map(|k_alt| (k_alt, self.alt_m, level_before));
                let window_n = p.vertical_window_reports.min(len);
                let newest_first = (len - window_n..len)
                    .rev()
                    .filter_map(|i| Some((held.get(i)?, i)))
                    .filter(|(s, _)| s.measured && s.var_u.is_finite())
                    .map(|(s, i)| (s.vu_mps, learned_var_u.unwrap_or(s.var_u), i));
                // `n` measured reports in the window, counted above.
                let threshold = p.vertical_rate_mps;
                if let Some(m) = vertical_onset(newest_first, n as usize, threshold, k, confirm) {
                    r.flags.vertical = true;
                    if m.signum() != mean.signum() {
                        r.vertical_rate_mps = Some(m);
                    }
                }
            }
        }

        // Paper 002: changes between the first and the last of the last N reports (only
        // when one of its tests is configured).
        let paper = [
            p.speed_change_mps,
            p.accel_change_mps2,
            p.heading_change_deg,
            p.pitch_change_deg,
        ];
        if paper.iter().any(Option::is_some) {
            self.paper_changes(&mut r, old);
        }
        self.turn_start_s = turn_start_s;
        self.accel_since = accel_since;
        self.reading = r;
    }

    /// The paper's Δv, Δa, Δφ, Δβ over the last N reports into `r`.
    fn paper_changes(&self, r: &mut GateReading, old: GateFlags) {
        let p = &self.params;
        let window = self.recent(p.window_reports);
        let (Some(f), Some(l)) = (window.first(), window.last()) else {
            return;
        };
        r.pitch_rad = l.var_u.is_finite().then(|| l.vu_mps.atan2(l.speed_mps));
        if window.len() < 2 {
            return;
        }
        let dv = l.speed_mps - f.speed_mps;
        r.speed_change_mps = Some(dv);
        r.flags.speed_change = fires(dv, 0.0, p.speed_change_mps, old.speed_change, p);
        if f.speed_mps >= p.min_speed_mps && l.speed_mps >= p.min_speed_mps {
            let heading_change = l.heading_rad - f.heading_rad;
            r.heading_change_rad = Some(heading_change);
            r.flags.heading_change = fires(
                heading_change,
                0.0,
                p.heading_change_deg.map(f64::to_radians),
                old.heading_change,
                p,
            );
        }
        if f.var_u.is_finite() && l.var_u.is_finite() {
            let db = l.vu_mps.atan2(l.speed_mps) - f.vu_mps.atan2(f.speed_mps);
            r.pitch_change_rad = Some(db);
            r.flags.pitch_change = fires(
                db,
                0.0,
                p.pitch_change_deg.map(f64::to_radians),
                old.pitch_change,
                p,
            );
        }
        // Along-track accelerations: differences of consecutive ground speeds.
        let accel = |w: &[Sample]| match w {
            [a, b] if b.t_s > a.t_s => Some((b.speed_mps - a.speed_mps) / (b.t_s - a.t_s)),
            _ => None,
        };
        let first_accel = window.windows(2).find_map(accel);
        let last_accel = window.windows(2).rev().find_map(accel);
        if let (Some(a0), Some(a1)) = (first_accel, last_accel) {
            let da = a1 - a0;
            r.accel_change_mps2 = Some(da);
            r.flags.accel_change = fires(da, 0.0, p.accel_change_mps2, old.accel_change, p);
        }
    }
}

/// An onset test's decision on its fitted rate: |rate| > λ and |rate| > kσ (k =
/// `onset_sigmas`), both scaled by `release_ratio` while the change it starts is `held`.
fn onset_fires(rate: f64, sigma: f64, lambda: f64, held: bool, p: &GateParams) -> bool {
    let scale = if held { p.release_ratio } else { 1.0 };
    let a = rate.abs();
    a > scale * lambda && a > scale * p.onset_sigmas * sigma
}

/// k of the acceleration's hold by default ([`GateParams::accel_hold_sigmas`]).
pub const ACCEL_HOLD_SIGMAS: f64 = 3.0;

/// k of the climb or descent onset test by default ([`GateParams::vertical_onset_sigmas`]).
/// It looks at up to four means (m = 2..5 of the six-report window) where the window test
/// looks at one, so each look is held to more than the window's 4σ: Šidák's correction of
/// a two-sided 4σ test (6.3·10⁻⁵) for four looks asks 4.4σ; 4.5 is the value measured
/// (40 runs of the approach: 4σ labelled its descents' onsets in 1.48 s but doubled the
/// false climbs, 5σ in 1.99 s; docs/evaluation.md).
pub const VERTICAL_ONSET_SIGMAS: f64 = 4.5;

/// The fewest newest reports the climb or descent onset test averages: one report of a
/// barometric rate is too easily a gust, or a rate the transponder rounded up.
const VERTICAL_ONSET_MIN_REPORTS: usize = 2;

/// k of the altitude-confirmed climb or descent onset by default
/// ([`GateParams::vertical_onset_altitude_sigmas`]): two kinds of evidence must agree, the
/// rates' mean and the altitude's step, so each is held to less than the 4.5σ of the rates
/// alone. Measured (40 runs of the approach, its descents' onsets): 3.5σ 1.50 s, 3σ 1.44 s,
/// 2.5σ 1.38 s; on LAX (`--nominal-rate 270`) 21, 46 and 55 updates changed from level to
/// vertical, most of them gentle climbs at the threshold (docs/evaluation.md).
pub const VERTICAL_ONSET_ALTITUDE_SIGMAS: f64 = 3.0;

/// Reports before a climb or descent onset whose altitudes give the level it left
/// ([`GateParams::vertical_onset_altitude_sigmas`]): 3 s at 2 Hz. The onset must leave
/// their whole range, so an altitude that flickers between two steps in level flight (an
/// autopilot holding it at a step's edge) is not a climb until it reaches a third.
const ALTITUDE_REFERENCE_REPORTS: usize = 6;

/// The (lowest, highest) altitude noted with `samples`, m; `None` when there are none or
/// one came before any altitude (the level is then unknown).
fn altitude_range(samples: &[Sample]) -> Option<(f64, f64)> {
    let mut range: Option<(f64, f64)> = None;
    for s in samples {
        let a = f64::from(s.alt_m);
        if !a.is_finite() {
            return None;
        }
        let (lo, hi) = range.get_or_insert((a, a));
        *lo = lo.min(a);
        *hi = hi.max(a);
    }
    range
}

/// The altitude step that confirms a climb or descent onset, m: one 25-ft step of a Q-bit
/// altitude (DO-260B §2.2.3.2.3.4.3, 7.62 m) less a metre for the height's conversion
/// from the track's plane. A Gillham altitude's 100-ft step passes it too.
const ALTITUDE_STEP_M: f64 = 25.0 * 0.3048 - 1.0;

/// The climb or descent onset test ([`GateParams::vertical_onset_sigmas`]) over the
/// window's `n` measured (rate m/s, variance (m/s)²) pairs, newest first: the mean of the
/// newest m, for the smallest m in 2..n−1 (the whole window is the window test's own)
/// whose |mean| is above `threshold` and above k σ of itself and whose every rate is on
/// the mean's side of level. That last condition is what a single gust or rounded-up
/// report cannot meet with a level one beside it; a climb's reports all can.
///
/// With `confirm` = (k', newest altitude m, the range of the altitudes noted before a
/// report, by the report's third item, [`altitude_range`]), a mean that passes only k' σ
/// (k' < k) is taken as well when the newest altitude has left, in the mean's direction
/// and by at least one altitude step ([`ALTITUDE_STEP_M`]), the range noted before the
/// oldest of the m: a climb changes the height, chance rates do not.
fn vertical_onset<L: Fn(usize) -> Option<(f64, f64)>>(
    newest_first: impl Iterator<Item = (f64, f64, usize)>,
    n: usize,
    threshold: Option<f64>,
    k: f64,
    confirm: Option<(f64, f64, L)>,
) -> Option<f64> {
    let lambda = threshold?;
    let (mut m, mut sum, mut var) = (0usize, 0.0, 0.0);
    let (mut lowest, mut highest) = (f64::INFINITY, f64::NEG_INFINITY);
    for (rate, v, index) in newest_first.take(n.saturating_sub(1)) {
        m += 1;
        sum += rate;
        var += v;
        lowest = lowest.min(rate);
        highest = highest.max(rate);
        if lowest <= 0.0 && highest >= 0.0 {
            // A rate at or across level: no longer m on one side.
            return None;
        }
        if m < VERTICAL_ONSET_MIN_REPORTS {
            continue;
        }
        let mean = sum / m as f64;
        let sigma = var.sqrt() / m as f64;
        if mean.abs() > lambda && mean.abs() > k * sigma {
            return Some(mean);
        }
        if let Some((k_alt, alt_m, level_before)) = &confirm {
            if mean.abs() > lambda && mean.abs() > k_alt * sigma {
                if let Some((lo, hi)) = level_before(index) {
                    let moved = if mean > 0.0 { alt_m - hi } else { lo - alt_m };
                    if moved >= ALTITUDE_STEP_M {
                        return Some(mean);
                    }
                }
            }
        }
    }
    None
}

/// Reports since an acceleration fired before its line may hold it.
const ACCEL_HOLD_MIN_REPORTS: f64 = 12.0;

/// One test with significance and hysteresis: |stat| > λ and |stat| > kσ to fire; once
/// fired, |stat| > ρλ and |stat| > ρkσ to stay (ρ = `release_ratio`).
fn fires(stat: f64, sigma: f64, threshold: Option<f64>, was: bool, p: &GateParams) -> bool {
    let Some(lambda) = threshold else {
        return false;
    };
    let scale = if was { p.release_ratio } else { 1.0 };
    let a = stat.abs();
    a > scale * lambda && a > scale * p.significance_sigmas * sigma
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// A velocity report as ADS-B would send it: each component with Gaussian noise σ, then
    /// quantised to 1 kt (horizontal) and 64 ft/min (vertical).
    fn report(v: Vector3<f64>, sigma: f64, rng: &mut StdRng) -> Observed {
        let n = Normal::new(0.0, sigma).unwrap();
        let q = |x: f64, lsb: f64| (x / lsb).round() * lsb;
        Observed {
            value: Vector3::new(
                q(v.x + n.sample(rng), KNOT_MPS),
                q(v.y + n.sample(rng), KNOT_MPS),
                q(v.z + n.sample(rng) * 0.5, VRATE_LSB_MPS),
            ),
            cov: Matrix3::from_diagonal(&Vector3::new(sigma * sigma, sigma * sigma, 0.0625)),
            grid: None,
        }
    }

    /// Fraction of reports (after the first 12) at which the gate reports a manoeuvre, for
    /// a velocity profile v(t) reported every 0.5 s.
    fn fire_rate(
        params: GateParams,
        v: impl Fn(f64) -> Vector3<f64>,
        seed: u64,
    ) -> (f64, GateReading) {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut gate = Gate::new(params);
        let (mut fired, mut total) = (0, 0);
        let mut last = GateReading::default();
        for k in 0..400 {
            let t = 0.5 * k as f64;
            let r = *gate.push(t, &report(v(t), 0.5, &mut rng), true);
            if k >= 12 {
                total += 1;
                fired += usize::from(r.manoeuvre());
                last = r;
            }
        }
        (fired as f64 / total as f64, last)
    }

    #[test]
    fn the_default_buffer_fits_a_1536_byte_allocation() {
        // jemalloc's size classes between 1 and 2 KiB are 1,280, 1,536, 1,792 and 2,048
        // bytes: a buffer of 1,537 would take 2,048 per aircraft.
        assert_eq!(std::mem::size_of::<Sample>(), 56);
        let gate = Gate::new(GateParams::default());
        let bytes = std::mem::size_of_val(&*gate.samples);
        assert!(bytes <= 1536, "{bytes}");
        assert_eq!(gate.capacity(), GateParams::default().longest_window());
    }

    #[test]
    fn every_window_is_the_newest_samples_within_the_time_cut() {
        // Gaps from 0.1 s to beyond `max_window_s` (30 s), through many slides of the
        // buffer: each window is the newest n held samples no older than the newest less
        // max_window_s, as a plain filter over everything pushed finds them.
        let mut rng = StdRng::seed_from_u64(17);
        let gap = rand_distr::Uniform::new(0.1, 12.0);
        let mut gate = Gate::new(GateParams::default());
        let mut times = Vec::new();
        let mut t = 0.0;
        for k in 0..2000 {
            t += if k % 97 == 0 {
                45.0
            } else {
                gap.sample(&mut rng)
            };
            gate.push(
                t,
                &report(Vector3::new(100.0, 50.0, 0.0), 0.5, &mut rng),
                true,
            );
            times.push(t);
            let cut = t - gate.params.max_window_s;
            for n in [1, 5, 6, 11, 12, 24, GATE_CAPACITY] {
                let held = &times[times.len().saturating_sub(n.min(gate.len))..];
                let want: Vec<f64> = held.iter().copied().filter(|&s| s >= cut).collect();
                let got: Vec<f64> = gate.recent(n).iter().map(|s| s.t_s).collect();
                assert_eq!(got, want, "push {k}, n {n}");
            }
        }
    }

    /// 95 % radius of a circular 2-D Gaussian per σ (DO-260B's NACv bounds are 95 %).
    const R95_2D: f64 = 2.447_746_830_680_816;

    fn heading_speed(heading_deg: f64, speed: f64, vu: f64) -> Vector3<f64> {
        // Heading clockwise from north.
        let h = heading_deg.to_radians();
        Vector3::new(speed * h.sin(), speed * h.cos(), vu)
    }

    /// Reports every `period_s` with noise `sigma` (m/s per axis): the first `delay` after
    /// `onset_s` at which the gate's lateral axis is `want`, for a turn of `rate_deg_s`
    /// (+ = right) from `onset_s` to `end_s`, and the reports after `end_s` still not
    /// straight.
    fn turn_timing(
        params: GateParams,
        rate_deg_s: f64,
        (onset_s, end_s): (f64, f64),
        (period_s, sigma): (f64, f64),
        seed: u64,
    ) -> (Option<f64>, usize, usize) {
        let mut rng = StdRng::seed_from_u64(seed);
        let phase = rand::Rng::gen_range(&mut rng, 0.0..period_s);
        let want = if rate_deg_s > 0.0 {
            Lateral::Right
        } else {
            Lateral::Left
        };
        let heading = |t: f64| 30.0 + rate_deg_s * (t.clamp(onset_s, end_s) - onset_s);
        let mut gate = Gate::new(params);
        let (mut delay, mut lingering, mut opposite) = (None, 0, 0);
        let mut t = phase;
        while t < end_s + 60.0 {
            let r = *gate.push(
                t,
                &report(heading_speed(heading(t), 70.7, 0.0), sigma, &mut rng),
                true,
            );
            if t >= onset_s && t < end_s && delay.is_none() && r.lateral() == want {
                delay = Some(t - onset_s);
            }
            if t >= end_s {
                lingering += usize::from(r.lateral() != Lateral::Straight);
            }
            opposite += usize::from(r.lateral() != want && r.lateral() != Lateral::Straight);
            t += period_s;
        }
        (delay, lingering, opposite)
    }

    #[test]
    fn turn_onset_test_shortens_the_wait_without_false_turns() {
        // Paper 002's scenario as ADS-B reports it: 70.7 m/s, a 3°/s turn, one velocity a
        // second with NACv 2 noise (σ = 1.23 m/s per axis, i.e. 1° of heading), the turn
        // starting at a random phase of the reports.
        let sigma = 3.0 / R95_2D;
        // The onset test alone (the first-report test has its own tests below).
        let with = GateParams {
            first_report_turn_sigmas: None,
            ..GateParams::default()
        };
        let without = GateParams {
            onset_reports: 0,
            ..GateParams::default()
        };
        let (mut with_sum, mut without_sum, mut n) = (0.0, 0.0, 0.0);
        let (mut lingering_with, mut lingering_without) = (0, 0);
        let mut opposite = 0;
        for seed in 0..200 {
            let rate = if seed % 2 == 0 { 3.0 } else { -3.0 };
            let timing = |p| turn_timing(p, rate, (100.0, 140.0), (1.0, sigma), seed);
            let (Some(a), l_a, opp_a) = timing(with) else {
                panic!("seed {seed}: turn missed with the onset test");
            };
            let (Some(b), l_b, opp_b) = timing(without) else {
                panic!("seed {seed}: turn missed without the onset test");
            };
            assert!(
                a <= b,
                "seed {seed}: {a} s with the onset test, {b} s without"
            );
            // The end of a turn is not the onset of another one: the onset test labels no
            // report as turning the other way (the turn-rate test alone does, rarely, on
            // noise).
            assert!(opp_a <= opp_b, "seed {seed}: {opp_a} vs {opp_b}");
            opposite += opp_b;
            with_sum += a;
            without_sum += b;
            lingering_with += l_a;
            lingering_without += l_b;
            n += 1.0;
        }
        let (with, without) = (with_sum / n, without_sum / n);
        eprintln!(
            "turn onset at NACv 2, 1 Hz: seen after {with:.2} s with the onset test, \
             {without:.2} s with the turn-rate test alone; reports still turning after the \
             turn's end {lingering_with} vs {lingering_without}; reports turning the other \
             way {opposite}"
        );
        assert!(with < 1.95 && without - with > 0.3, "{with} vs {without}");
        // The release at the turn's end is the turn-rate test's, unchanged.
        assert!(lingering_with <= lingering_without + 10);
    }

    /// Paper 002's reports exactly: one a second, a 3°/s turn starting on a report at
    /// 70.7 m/s, NACv 2 (1° of heading per report). The first report after the onset is
    /// 2.9σ off the straight line: the first-report test labels it about half the time,
    /// the onset test's 4σ about an eighth.
    #[test]
    fn first_report_test_labels_half_of_the_onsets_on_their_first_report() {
        let sigma = 3.0 / R95_2D;
        let first_report_share = |params: GateParams| {
            let mut first = 0;
            for seed in 0..400_u64 {
                let mut rng = StdRng::seed_from_u64(1000 + seed);
                let rate = if seed % 2 == 0 { 3.0 } else { -3.0 };
                let mut gate = Gate::new(params);
                for k in 0..=30 {
                    let t = f64::from(k);
                    let heading = 30.0 + rate * (t - 29.0).max(0.0);
                    let r = *gate.push(
                        t,
                        &report(heading_speed(heading, 70.7, 0.0), sigma, &mut rng),
                        true,
                    );
                    if k == 30 && r.lateral() != Lateral::Straight {
                        first += 1;
                    }
                }
            }
            f64::from(first) / 400.0
        };
        let with = first_report_share(GateParams::default());
        let without = first_report_share(GateParams {
            first_report_turn_sigmas: None,
            ..GateParams::default()
        });
        eprintln!("onsets labelled on their first report: {with:.3} with the first-report test, {without:.3} without");
        assert!((0.38..=0.62).contains(&with), "{with}");
        assert!(without < 0.3 && with - without > 0.2, "{with} vs {without}");
    }

    /// The end of a paper 002 turn (70.7 m/s, 3°/s, one report a second, 1° of heading noise,
    /// at a random phase): (delay from the end to the first report labelled straight, whether
    /// the turn test still held there, reports inside the steady turn labelled straight,
    /// reports inside it).
    fn turn_end_timing(params: GateParams, seed: u64) -> (Option<f64>, bool, usize, usize) {
        let (onset_s, end_s, sigma): (f64, f64, f64) = (30.0, 90.0, 3.0 / R95_2D);
        let mut rng = StdRng::seed_from_u64(seed);
        let rate = if seed % 2 == 0 { 3.0 } else { -3.0 };
        let phase = rand::Rng::gen_range(&mut rng, 0.0..1.0);
        let mut gate = Gate::new(params);
        let (mut delay, mut held, mut early, mut inside) = (None, false, 0, 0);
        let mut t: f64 = phase;
        while t < end_s + 15.0 {
            let heading = 30.0 + rate * (t.clamp(onset_s, end_s) - onset_s);
            let r = *gate.push(
                t,
                &report(heading_speed(heading, 70.7, 0.0), sigma, &mut rng),
                true,
            );
            if t >= onset_s + 10.0 && t < end_s {
                inside += 1;
                early += usize::from(r.lateral() == Lateral::Straight);
            }
            if t >= end_s && delay.is_none() && r.lateral() == Lateral::Straight {
                delay = Some(t - end_s);
                held = r.flags.turn;
            }
            t += 1.0;
        }
        (delay, held, early, inside)
    }

    #[test]
    fn turn_end_test_labels_the_end_sooner_without_ending_steady_turns() {
        let timing = |params: GateParams| {
            let (mut sum, mut n, mut held, mut early, mut inside) = (0.0, 0, 0, 0, 0);
            for seed in 0..400_u64 {
                let (delay, was_held, e, i) = turn_end_timing(params, 5000 + seed);
                if let Some(d) = delay {
                    sum += d;
                    n += 1;
                    held += usize::from(was_held);
                }
                early += e;
                inside += i;
            }
            assert_eq!(n, 400, "every end is labelled");
            (sum / 400.0, held, early as f64 / inside as f64)
        };
        let (with, held, early_with) = timing(GateParams::default());
        let (without, _, early_without) = timing(GateParams {
            turn_end_sigmas: None,
            ..GateParams::default()
        });
        eprintln!(
            "turn end labelled after {with:.2} s with the end test ({held} of 400 while the \
             turn test still held; {:.3} % of steady-turn reports straight), {without:.2} s \
             without ({:.3} %)",
            100.0 * early_with,
            100.0 * early_without
        );
        // Measured: 1.89 s with, 3.35 s without.
        assert!(with <= 2.2 && without >= 3.0, "{with} vs {without}");
        // It labels: the turn test (and the tracker's IMM) still holds where it ends most
        // turns.
        assert!(held >= 200, "{held}");
        assert!(early_with <= 0.005, "{early_with}");
    }

    /// [`hinge_end`]'s rate since the end is the plain least-squares fit of
    /// a + b·t + c·max(0, t − t_ref) (its b + c), for the split it picks.
    #[test]
    fn hinge_end_reads_the_plain_three_parameter_fit() {
        let mut rng = StdRng::seed_from_u64(17);
        let noise = Normal::new(0.0, 0.3).unwrap();
        let mut checked = 0;
        for case in 0..300 {
            let n = rng.gen_range(6..=20_usize);
            let m_true = rng.gen_range(1..=4_usize).min(n - 4);
            let rate = rng.gen_range(0.5..3.0) * if case % 2 == 0 { 1.0 } else { -1.0 };
            let mut t: f64 = -rng.gen_range(0.0..1.0);
            let mut pts = Vec::new();
            for _ in 0..n {
                pts.push(t);
                t -= rng.gen_range(0.4..1.2);
            }
            pts.reverse();
            let t_end = pts[n - 1 - m_true];
            let points: Vec<(f64, f64, f64)> = pts
                .iter()
                .map(|&t| (t, rate * t.min(t_end) + noise.sample(&mut rng), 0.09))
                .collect();
            let Some(since) = hinge_end(points.iter().copied(), 8, 0.3, 3.5) else {
                continue;
            };
            // Every split's plain fit; the returned rate is one of them.
            let fits: Vec<f64> = (END_MIN_NEWEST..=8_usize)
                .filter(|&m| n >= m + END_MIN_REFERENCE)
                .map(|m| {
                    let t_ref = points[n - 1 - m].0;
                    let a = nalgebra::DMatrix::from_fn(n, 3, |i, j| match j {
                        0 => 1.0,
                        1 => points[i].0,
                        _ => (points[i].0 - t_ref).max(0.0),
                    });
                    let y = nalgebra::DVector::from_fn(n, |i, _| points[i].1);
                    let ata = a.transpose() * &a;
                    let x = ata.cholesky().unwrap().solve(&(a.transpose() * y));
                    x[1] + x[2]
                })
                .collect();
            assert!(
                fits.iter().any(|f| (f - since).abs() < 1e-9),
                "case {case}: {since} not in {fits:?}"
            );
            checked += 1;
        }
        assert!(checked > 100, "{checked}");
    }

    /// The first-report test labels; it is no manoeuvre for the tracker (which opens its
    /// IMM on the tests that need more than one report).
    #[test]
    fn a_first_report_turn_is_a_label_not_a_manoeuvre() {
        let mut gate = Gate::new(GateParams::default());
        let cov = Matrix3::identity() * (1.0 / R95_2D).powi(2);
        let mut seen = None;
        for k in 0..=12 {
            // Straight and exact, then a 0.9° step at 100 m/s: 3.4σ of the gate's heading
            // noise for these reports (0.26° with the 1-kt quantisation), so the first-report
            // test fires and the onset test's 4σ does not; the turn-rate test's slope over
            // five reports, 0.18°/s, is under its 0.5°/s.
            let heading = if k < 12 { 10.0 } else { 10.9 };
            let r = *gate.push(
                f64::from(k),
                &Observed {
                    value: heading_speed(heading, 100.0, 0.0),
                    cov,
                    grid: None,
                },
                true,
            );
            if k == 12 {
                seen = Some(r);
            }
        }
        let r = seen.unwrap();
        assert!(r.flags.turn_first_report, "{r:?}");
        assert!(!r.flags.turn && !r.flags.turn_onset, "{r:?}");
        assert!(!r.manoeuvre());
        assert_eq!(r.lateral(), Lateral::Right);
        assert_eq!(
            r.label(),
            Some((FlightMode::Ct, Some(TurnDirection::Right)))
        );
    }

    /// A heading that wanders at 0.3°/s (under the turn threshold) with little noise: the
    /// newest report sits far from the mean of the ten before it, which is drift, not an
    /// onset. The test needs its reference straight and stays silent.
    #[test]
    fn a_drifting_reference_does_not_read_as_a_first_report_turn() {
        let mut rng = StdRng::seed_from_u64(7);
        let mut gate = Gate::new(GateParams::default());
        let mut unguarded = 0;
        for k in 0..400 {
            let t = 0.5 * f64::from(k);
            let r = *gate.push(
                t,
                &report(heading_speed(90.0 + 0.3 * t, 230.0, 0.0), 0.1, &mut rng),
                true,
            );
            assert!(!r.flags.turn_first_report, "report {k}: {r:?}");
            // What the newest report alone says against the reference's mean.
            let all = gate.recent(11);
            if all.len() == 11 {
                let (t0, h0) = (all[10].t_s, all[10].heading_rad);
                let mut sums = LineSums::default();
                for s in all {
                    sums.add(s.t_s - t0, s.heading_rad - h0, s.heading_var());
                }
                let ty = |s: &Sample| (s.t_s - t0, s.heading_rad - h0);
                if let (Some((rate, sigma, _)), _) =
                    hinge_onset(all, &sums, 1, 0.5_f64.to_radians(), ty)
                {
                    unguarded += usize::from(
                        rate.abs() > 0.5_f64.to_radians()
                            && rate.abs() > FIRST_REPORT_TURN_SIGMAS * sigma,
                    );
                }
            }
        }
        // Without the guard the drift would have read as an onset on most reports.
        assert!(unguarded > 200, "{unguarded}");
    }

    #[test]
    fn onset_test_holds_its_false_alarm_rate_at_nacv_2() {
        // Straight flight at the noise of the scenario above, at 1 and 2 reports a second.
        let sigma = 3.0 / R95_2D;
        for (period, seed) in [(1.0, 21), (0.5, 22)] {
            let mut rng = StdRng::seed_from_u64(seed);
            let mut gate = Gate::new(GateParams::default());
            let (mut fired, mut onsets, mut total, mut first) = (0, 0, 0, 0);
            for k in 0..4000 {
                let r = *gate.push(
                    period * k as f64,
                    &report(heading_speed(250.0, 70.7, 0.0), sigma, &mut rng),
                    true,
                );
                if k >= 12 {
                    total += 1;
                    fired += usize::from(r.flags.turn || r.flags.turn_onset);
                    onsets += usize::from(r.flags.turn_onset);
                    first += usize::from(r.flags.turn_first_report);
                }
            }
            let rate = fired as f64 / total as f64;
            let first_rate = first as f64 / total as f64;
            eprintln!("straight at NACv 2, {period} s: turn tests fire on {rate:.4} ({onsets} by the onset test); the first-report label on {first_rate:.4}");
            assert!(rate < 0.005, "{period} s: {rate}");
            // Two-sided 2.9σ: 0.37 % of reports (fewer with the drift guard, more with the
            // 1-kt quantisation's tails).
            assert!(
                (0.001..0.008).contains(&first_rate),
                "{period} s: {first_rate}"
            );
        }
    }

    #[test]
    fn derived_velocities_never_feed_the_onset_test() {
        // A filter's own velocity, turning sharply: only the turn-rate test may see it.
        let mut gate = Gate::new(GateParams::default());
        let cov = Matrix3::identity() * 1e-4;
        for k in 0..20 {
            let h = if k < 12 { 0.0 } else { 5.0 * (k - 11) as f64 };
            let r = *gate.push(
                k as f64,
                &Observed {
                    value: heading_speed(h, 100.0, 0.0),
                    cov,
                    grid: None,
                },
                false,
            );
            assert!(!r.flags.turn_onset && r.onset_turn_rate_rad_s.is_none());
        }
        assert!(gate.reading().flags.turn);
    }

    /// Reports every 0.5 s (random phase) at NACv 2 noise, 110 m/s level, accelerating at
    /// `accel` from 100 s to 140 s: the first delay after the onset at which the gate's
    /// speed axis shows it, and the reports in the first 100 s with any speed axis.
    fn accel_timing(params: GateParams, accel: f64, seed: u64) -> (Option<f64>, usize) {
        let mut rng = StdRng::seed_from_u64(seed);
        let sigma = 3.0 / R95_2D;
        let want = if accel > 0.0 {
            SpeedTrend::Increasing
        } else {
            SpeedTrend::Decreasing
        };
        let speed = |t: f64| 110.0 + accel * (t.clamp(100.0, 140.0) - 100.0);
        let mut gate = Gate::new(params);
        let (mut delay, mut false_speed) = (None, 0);
        let mut t = rand::Rng::gen_range(&mut rng, 0.0..0.5);
        while t < 140.0 {
            let r = *gate.push(
                t,
                &report(heading_speed(53.0, speed(t), 0.0), sigma, &mut rng),
                true,
            );
            if t < 100.0 {
                false_speed += usize::from(r.speed() != SpeedTrend::Constant);
            } else if delay.is_none() && r.speed() == want {
                delay = Some(t - 100.0);
            }
            t += 0.5;
        }
        (delay, false_speed)
    }

    /// A 120 s deceleration at `accel` after 100 s of steady flight, then 60 s steady, at
    /// NACv 2 and 2 Hz: (reports inside it after its first label that were not labelled
    /// decelerating, reports inside it, seconds after its end until the label is steady for
    /// good).
    fn accel_hold_timing(params: GateParams, accel: f64, seed: u64) -> (usize, usize, f64) {
        let mut rng = StdRng::seed_from_u64(seed);
        let sigma = 3.0 / R95_2D;
        let speed = |t: f64| 180.0 + accel * (t.clamp(100.0, 220.0) - 100.0);
        let mut gate = Gate::new(params);
        let (mut dropped, mut inside, mut labelled, mut last_held) = (0, 0, false, 220.0);
        let mut t = rand::Rng::gen_range(&mut rng, 0.0..0.5);
        while t < 280.0 {
            let r = *gate.push(
                t,
                &report(heading_speed(53.0, speed(t), 0.0), sigma, &mut rng),
                true,
            );
            let decelerating = r.speed() == SpeedTrend::Decreasing;
            if (100.0..220.0).contains(&t) {
                labelled |= decelerating;
                if labelled {
                    inside += 1;
                    dropped += usize::from(!decelerating);
                }
            } else if t >= 220.0 && r.speed() != SpeedTrend::Constant {
                last_held = t;
            }
            t += 0.5;
        }
        (dropped, inside, last_held - 220.0)
    }

    #[test]
    fn a_gentle_deceleration_is_held_by_its_own_line() {
        // The approach scenario's 0.3 m/s² deceleration, at the trend test's λ: its 24-report
        // slope (σ about 0.07 m/s²) fell under the release on about one report in twenty.
        let without = GateParams {
            accel_hold_sigmas: None,
            ..GateParams::default()
        };
        let mut sums = [[0.0; 3]; 2];
        for seed in 0..100 {
            for (sum, params) in sums.iter_mut().zip([GateParams::default(), without]) {
                let (dropped, inside, end_s) = accel_hold_timing(params, -0.3, seed);
                sum[0] += dropped as f64;
                sum[1] += inside as f64;
                sum[2] += end_s / 100.0;
            }
        }
        let [with, without] = sums;
        let share = |s: [f64; 3]| s[0] / s[1];
        eprintln!(
            "-0.3 m/s² for 120 s: labels dropped inside it {:.2} % with the hold, {:.2} % \
             without; labelled steady for good {:.2} s and {:.2} s after its end",
            100.0 * share(with),
            100.0 * share(without),
            with[2],
            without[2]
        );
        assert!(
            share(with) < share(without) / 3.0,
            "{with:?} vs {without:?}"
        );
        // The price: its end, where the trend's slope must now fall 3σ under the line
        // (about 0.09 m/s²) where the release let go at 0.18, about 3.4 s later.
        assert!(with[2] < without[2] + 4.0, "{with:?} vs {without:?}");
    }

    #[test]
    fn accel_onset_test_shortens_the_wait_without_false_accelerations() {
        // The departure scenario's 0.4 m/s² level acceleration at NACv 2 (σ 1.23 m/s per
        // axis), two reports a second. The fastest any test can be: with the onset time and
        // the rate known, the log-likelihood ratio after t s is a² t³ r / (6σ²) at r reports
        // a second, and 4σ (a ratio of 8) takes about 6.1 s.
        let without = GateParams {
            accel_onset_reports: 0,
            ..GateParams::default()
        };
        let (mut with_sum, mut without_sum, mut n) = (0.0, 0.0, 0.0);
        let (mut false_with, mut false_without) = (0, 0);
        for seed in 0..100 {
            let accel = if seed % 2 == 0 { 0.4 } else { -0.4 };
            let (Some(a), f_a) = accel_timing(GateParams::default(), accel, seed) else {
                panic!("seed {seed}: acceleration missed with the onset test");
            };
            let (Some(b), f_b) = accel_timing(without, accel, seed) else {
                panic!("seed {seed}: acceleration missed without the onset test");
            };
            with_sum += a;
            without_sum += b;
            false_with += f_a;
            false_without += f_b;
            n += 1.0;
        }
        let (with, without) = (with_sum / n, without_sum / n);
        eprintln!(
            "0.4 m/s² at NACv 2, 2 Hz: seen after {with:.2} s with the onset test, \
             {without:.2} s with the trend test alone; reports labelled accelerating in 100 s \
             of steady flight: {false_with} vs {false_without} (of {})",
            100 * 200
        );
        assert!(with < 7.5 && without - with > 0.5, "{with} vs {without}");
        // Steady flight: at most one report in a thousand labelled as a speed change.
        assert!(false_with <= 20, "{false_with}");
    }

    /// Level flight at 110 m/s with vertical rates of noise `sigma_u` declared at
    /// `declared_sigma_u`, then a climb at `climb_mps` from 100 s: the share of the level
    /// reports (after 10 s) labelled vertical, the report count from the climb's onset to
    /// its label, and the gate's learned σ.
    fn vertical_timing(
        params: GateParams,
        noise_sigmas: (f64, f64),
        climb_mps: f64,
        seed: u64,
    ) -> (f64, Option<usize>, Option<f64>) {
        vertical_run(params, noise_sigmas, climb_mps, None, seed)
    }

    /// `vertical_timing`, and with `altitude` = (edge, σ) a barometric altitude before each
    /// velocity report, as position reports interleave with velocities (a quarter of a
    /// second before each): the truth's height (level, `edge` = 0 at the middle of a 25-ft
    /// step and 0.5 at its edge, then the climb from t = 100 s) plus white error of σ, in
    /// 25-ft steps. Level at an edge with white error is the worst case for the altitude's
    /// confirmation: the altitude flickers between two steps on about half the reports,
    /// which real level flight does far less often.
    fn vertical_run(
        params: GateParams,
        (sigma_u, declared_sigma_u): (f64, f64),
        climb_mps: f64,
        altitude: Option<(f64, f64)>,
        seed: u64,
    ) -> (f64, Option<usize>, Option<f64>) {
        let mut rng = StdRng::seed_from_u64(seed);
        let noise = Normal::new(0.0, sigma_u).unwrap();
        let step_m = 25.0 * 0.3048;
        let mut gate = Gate::new(params);
        let cov = Matrix3::from_diagonal(&Vector3::new(1.5, 1.5, declared_sigma_u.powi(2)));
        let direction = if climb_mps > 0.0 {
            VerticalTrend::Climb
        } else {
            VerticalTrend::Descent
        };
        let (mut fired, mut level, mut onset) = (0, 0, None);
        for k in 0..300 {
            let t = 0.5 * k as f64;
            if let Some((edge, baro_sigma_m)) = altitude {
                let t_alt = t - 0.25;
                let h = (3000.0 + edge) * step_m + climb_mps * (t_alt - 100.0).max(0.0);
                let error_m = Normal::new(0.0, baro_sigma_m.max(1e-9))
                    .unwrap()
                    .sample(&mut rng);
                gate.altitude(((h + error_m) / step_m).round() * step_m);
            }
            let vu = if t >= 100.0 { climb_mps } else { 0.0 };
            let vu = ((vu + noise.sample(&mut rng)) / VRATE_LSB_MPS).round() * VRATE_LSB_MPS;
            let value = Vector3::new(88.0, 66.0, vu);
            let r = *gate.push(
                t,
                &Observed {
                    value,
                    cov,
                    grid: None,
                },
                true,
            );
            if (10.0..100.0).contains(&t) {
                level += 1;
                fired += usize::from(r.flags.vertical);
            } else if t >= 100.0 && onset.is_none() && r.vertical() == direction {
                onset = Some(k - 200);
            }
        }
        let sigma = gate.vrate_noise.var().map(f64::sqrt);
        (fired as f64 / level as f64, onset, sigma)
    }

    #[test]
    fn vertical_noise_is_learned_from_successive_reports() {
        let stated = GateParams {
            vrate_noise_window_reports: 0.0,
            ..GateParams::default()
        };
        // NACv 2's vertical bound taken at its word (σ 2.33 m/s, what the simulator draws):
        // the stated σ, capped at 1.5 m/s, fires on level flight; the learned one does not.
        let (mut fired_learned, mut fired_stated) = (0.0, 0.0);
        for seed in 0..20 {
            let (f, _, sigma) = vertical_timing(GateParams::default(), (2.33, 2.33), 10.0, seed);
            let sigma = sigma.unwrap();
            assert!(
                (sigma / 2.33 - 1.0).abs() < 0.3,
                "seed {seed}: learned σ {sigma}"
            );
            fired_learned += f / 20.0;
            fired_stated += vertical_timing(stated, (2.33, 2.33), 10.0, seed).0 / 20.0;
        }
        eprintln!(
            "level flight, vertical σ 2.33 m/s: labelled vertical on {fired_learned:.4} of \
             the reports with the learned σ, {fired_stated:.4} with the stated one capped"
        );
        assert!(fired_learned < 0.001, "{fired_learned}");
        assert!(fired_stated > 0.003, "{fired_stated}");
        // A quiet barometric rate (σ 0.2 m/s, its 64 ft/min steps) under the same loose
        // declaration: learned small, a 4 m/s climb is seen on its third report by the
        // window alone (the six-report mean passes 1.5 m/s), where the capped stated σ
        // waits at least for the fourth (4σ of the mean: 2.45 m/s); with the onset test,
        // on its second (the mean of the newest two, both climbing).
        let window_only = GateParams {
            vertical_onset_sigmas: None,
            ..GateParams::default()
        };
        let stated = GateParams {
            vertical_onset_sigmas: None,
            ..stated
        };
        for seed in 0..20 {
            let (f, onset, sigma) = vertical_timing(window_only, (0.2, 2.33), 4.0, seed);
            assert!(sigma.unwrap() < 0.4, "seed {seed}: {sigma:?}");
            assert_eq!(f, 0.0, "seed {seed}");
            assert_eq!(onset, Some(2), "seed {seed}");
            let (_, onset, _) = vertical_timing(stated, (0.2, 2.33), 4.0, seed);
            assert!(onset.is_some_and(|k| k >= 3), "seed {seed}: {onset:?}");
            // (On its first where noise put the level report before it above level too.)
            let (f, onset, _) = vertical_timing(GateParams::default(), (0.2, 2.33), 4.0, seed);
            assert_eq!(f, 0.0, "seed {seed}");
            assert!(onset.is_some_and(|k| k <= 1), "seed {seed}: {onset:?}");
        }
    }

    /// A climb's onset at the simulator's NACv 2 vertical noise (σ 2.33 m/s, learned), a
    /// step from level to 7 m/s (the approach's first descent) at 2 Hz, 200 runs: the
    /// six-report mean passes 4σ of itself (3.8 m/s) on the fourth report of the climb
    /// (index 3); the newest reports' mean against level flight sees it on the third (index
    /// 2). The price: level reports labelled vertical 0.17 % of the time instead of 0.09 %
    /// (each chance climb is held while the six-report mean stays above 0.9 m/s).
    #[test]
    fn a_climb_is_seen_by_its_newest_reports_against_level_flight() {
        let window_only = GateParams {
            vertical_onset_sigmas: None,
            ..GateParams::default()
        };
        let (mut with, mut without, mut false_with, mut false_without) = (0.0, 0.0, 0.0, 0.0);
        let runs = 200;
        for seed in 0..runs {
            let (f, onset, _) = vertical_timing(GateParams::default(), (2.33, 2.33), 7.0, seed);
            with += onset.unwrap() as f64 / runs as f64;
            false_with += f / runs as f64;
            let (f, onset, _) = vertical_timing(window_only, (2.33, 2.33), 7.0, seed);
            without += onset.unwrap() as f64 / runs as f64;
            false_without += f / runs as f64;
        }
        eprintln!(
            "7 m/s climb at σ 2.33 m/s: first labelled on report index {with:.2} with the \
             onset test, {without:.2} without; level reports labelled vertical \
             {false_with:.5} and {false_without:.5}"
        );
        assert!(without > 2.8, "{without}");
        assert!(with < without - 0.7, "{with} against {without}");
        assert!(false_with < 0.0025, "{false_with}");
    }

    /// A climb changes the height; chance rates do not. The newest reports' mean at 3σ,
    /// taken when the altitude has left its level by a step, labels a 7 m/s climb or
    /// descent at the simulator's NACv 2 noise (σ 2.33 m/s) sooner than the 4.5σ test
    /// alone (from a level at every phase of its 25-ft step), never labels a quiet level
    /// vertical, and with an altitude that flickers between two steps on half its reports
    /// labels level flight vertical hardly more often.
    #[test]
    fn a_climb_is_confirmed_by_its_altitude() {
        let without = GateParams {
            vertical_onset_altitude_sigmas: None,
            ..GateParams::default()
        };
        let runs = 200;
        let mean_onset = |params: GateParams, climb: f64, baro: (f64, f64)| {
            let (mut onset, mut false_rate) = (0.0, 0.0);
            for seed in 0..runs {
                // A quiet level at every phase of its step: the climb reaches the next
                // step after 0.4-7.2 m (not at its very edge, where σ 0 would flicker).
                let (edge, sigma) = baro;
                let edge = if edge.is_nan() {
                    0.9 * ((seed as f64 * 0.618_034).fract() - 0.5)
                } else {
                    edge
                };
                let (f, o, _) =
                    vertical_run(params, (2.33, 2.33), climb, Some((edge, sigma)), seed);
                onset += o.unwrap() as f64 / runs as f64;
                false_rate += f / runs as f64;
            }
            (onset, false_rate)
        };
        let quiet = (f64::NAN, 0.0);
        let flicker = (0.5, 2.0);
        let (with_climb, quiet_false) = mean_onset(GateParams::default(), 7.0, quiet);
        let (with_descent, _) = mean_onset(GateParams::default(), -7.0, quiet);
        let (without_climb, without_false) = mean_onset(without, 7.0, quiet);
        let (flicker_climb, flicker_false) = mean_onset(GateParams::default(), 7.0, flicker);
        let (_, flicker_without) = mean_onset(without, 7.0, flicker);
        eprintln!(
            "7 m/s at σ 2.33 m/s: first labelled on report index {with_climb:.2} (climb), \
             {with_descent:.2} (descent) with the altitude, {without_climb:.2} without, \
             {flicker_climb:.2} from a flickering altitude; level reports labelled vertical \
             {quiet_false:.5} / {without_false:.5} (quiet altitude), {flicker_false:.5} / \
             {flicker_without:.5} (flickering)"
        );
        assert!(
            with_climb < without_climb - 0.25,
            "{with_climb} against {without_climb}"
        );
        assert!(with_descent < without_climb - 0.15, "{with_descent}");
        assert!(flicker_climb <= without_climb, "{flicker_climb}");
        // A quiet altitude never confirms a chance rate.
        assert_eq!(quiet_false, without_false);
        assert!(flicker_false < 1.5 * flicker_without, "{flicker_false}");
    }

    #[test]
    fn paper_preset_has_the_printed_thresholds() {
        let p = GateParams::paper002();
        assert_eq!(p.window_reports, 5);
        assert_eq!(p.speed_change_mps, Some(10.0));
        assert_eq!(p.accel_change_mps2, Some(5.0));
        assert_eq!(p.heading_change_deg, Some(1.0));
        assert_eq!(p.pitch_change_deg, Some(5.0));
    }

    #[test]
    fn straight_level_flight_with_quantised_noisy_reports_does_not_fire() {
        for (speed, seed) in [(70.0, 1), (120.0, 2), (230.0, 3)] {
            let (rate, _) = fire_rate(
                GateParams::default(),
                |_| heading_speed(37.0, speed, 0.0),
                seed,
            );
            assert!(rate < 0.005, "{speed} m/s: fired on {rate}");
        }
    }

    #[test]
    fn default_gate_catches_what_airliners_fly_and_the_paper_preset_does_not() {
        // 1.2 m/s² along track from 120 m/s; a 3° climb at 120 m/s (6.3 m/s); a 1.2°/s turn
        // at 230 m/s (25° bank); each flown steadily for the whole run.
        let accel = |t: f64| heading_speed(80.0, 120.0 + 1.0 * t, 0.0);
        let climb = |_t: f64| heading_speed(80.0, 120.0, 120.0 * 3f64.to_radians().tan());
        let turn = |t: f64| heading_speed(80.0 + 1.2 * t, 230.0, 0.0);
        type Profile<'a> = &'a dyn Fn(f64) -> Vector3<f64>;
        let cases: [(&str, Profile, FlightMode); 3] = [
            ("acceleration 1 m/s²", &accel, FlightMode::Ca),
            ("climb 3°", &climb, FlightMode::Ch),
            ("turn 1.2°/s", &turn, FlightMode::Ct),
        ];
        for (name, v, mode) in cases {
            let (rate, last) = fire_rate(GateParams::default(), v, 7);
            assert!(rate > 0.95, "{name}: default gate fired on {rate}");
            assert_eq!(last.label().map(|l| l.0), Some(mode), "{name}");
            let (paper_rate, _) = fire_rate(GateParams::paper002(), v, 7);
            eprintln!("gate {name}: default fires {rate:.3}, paper002 {paper_rate:.3}");
        }
        // The paper's thresholds miss the climb and the acceleration: they fire no more
        // often than on noise alone (Δa of differentiated speeds has σ ≈ 2 m/s² here).
        let straight = |_t: f64| heading_speed(80.0, 120.0, 0.0);
        let (noise, _) = fire_rate(GateParams::paper002(), straight, 7);
        let (r, _) = fire_rate(GateParams::paper002(), climb, 7);
        assert!(r < 0.05 && r <= noise + 0.02, "{r} vs {noise}");
        let accel_1_2 = |t: f64| heading_speed(80.0, 120.0 + 1.2 * t, 0.0);
        let (r, _) = fire_rate(GateParams::paper002(), accel_1_2, 7);
        assert!(r < 0.05 && r <= noise + 0.02, "{r} vs {noise}");
        eprintln!("gate paper002 on straight level flight: fires {noise:.3}");
        let (r, last) = fire_rate(GateParams::default(), accel_1_2, 7);
        assert!(r > 0.99 && last.speed() == SpeedTrend::Increasing);
    }

    #[test]
    fn directions_and_labels() {
        let (_, left) = fire_rate(
            GateParams::default(),
            |t| heading_speed(10.0 - 3.0 * t, 70.0, 0.0),
            3,
        );
        assert_eq!(left.lateral(), Lateral::Left);
        assert_eq!(
            left.label(),
            Some((FlightMode::Ct, Some(TurnDirection::Left)))
        );
        assert!((left.turn_rate_rad_s.unwrap().to_degrees() - 3.0).abs() < 0.5);
        let (_, right) = fire_rate(
            GateParams::default(),
            |t| heading_speed(10.0 + 3.0 * t, 70.0, 0.0),
            3,
        );
        assert_eq!(right.lateral(), Lateral::Right);
        let (_, chca) = fire_rate(
            GateParams::default(),
            |t| heading_speed(10.0, 70.0 + t, -5.0),
            3,
        );
        assert_eq!(chca.label(), Some((FlightMode::Chca, None)));
        assert_eq!(chca.vertical(), VerticalTrend::Descent);
        // The paper preset's heading test sees a 3°/s turn (3° over 4 half-second gaps... 6°).
        let (_, paper) = fire_rate(
            GateParams::paper002(),
            |t| heading_speed(10.0 + 3.0 * t, 70.0, 0.0),
            3,
        );
        assert_eq!(
            paper.label(),
            Some((FlightMode::Ct, Some(TurnDirection::Right)))
        );
        assert!((paper.heading_change_rad.unwrap().to_degrees() + 6.0).abs() < 1.5);
    }

    #[test]
    fn heading_wraps_through_north_and_slow_aircraft_skip_turn_tests() {
        let mut gate = Gate::new(GateParams::default());
        let cov = Matrix3::identity() * 0.01;
        // Headings 358°, 359°, 0°, 1°, 2° at 1 s: 1°/s clockwise (right), no 360° jump.
        for (k, h) in [358.0, 359.0, 0.0, 1.0, 2.0].into_iter().enumerate() {
            gate.push(
                k as f64,
                &Observed {
                    value: heading_speed(h, 100.0, 0.0),
                    cov,
                    grid: None,
                },
                false,
            );
        }
        let r = gate.reading();
        assert!((r.turn_rate_rad_s.unwrap().to_degrees() + 1.0).abs() < 1e-9);
        assert_eq!(r.lateral(), Lateral::Right);
        // On the ground at 3 m/s the heading is noise: no turn test.
        let mut gate = Gate::new(GateParams::default());
        for k in 0..10 {
            gate.push(
                k as f64,
                &Observed {
                    value: heading_speed(40.0 * k as f64, 3.0, 0.0),
                    cov,
                    grid: None,
                },
                false,
            );
        }
        assert_eq!(gate.reading().turn_rate_rad_s, None);
        assert!(!gate.reading().flags.turn);
    }

    #[test]
    fn hysteresis_keeps_a_turn_at_the_threshold_from_flickering() {
        let params = GateParams::default();
        let cov = Matrix3::identity() * 1e-6;
        // A turn rate alternating 0.45 and 0.55 °/s (around λ = 0.5): once fired, it holds.
        let mut gate = Gate::new(params);
        let mut heading = 0.0;
        let mut fired_once = false;
        let mut dropped_after = false;
        for k in 0..60 {
            heading += if (k / 5) % 2 == 0 { 0.55 } else { 0.45 } * 0.5;
            let r = *gate.push(
                0.5 * k as f64,
                &Observed {
                    value: heading_speed(heading, 100.0, 0.0),
                    cov,
                    grid: None,
                },
                false,
            );
            if r.flags.turn {
                fired_once = true;
            } else if fired_once {
                dropped_after = true;
            }
        }
        assert!(fired_once && !dropped_after);
        // Without hysteresis it flickers.
        let mut gate = Gate::new(GateParams {
            release_ratio: 1.0,
            ..params
        });
        let mut heading = 0.0;
        let mut toggles = 0;
        let mut was = false;
        for k in 0..60 {
            heading += if (k / 5) % 2 == 0 { 0.55 } else { 0.45 } * 0.5;
            let r = *gate.push(
                0.5 * k as f64,
                &Observed {
                    value: heading_speed(heading, 100.0, 0.0),
                    cov,
                    grid: None,
                },
                false,
            );
            toggles += usize::from(r.flags.turn != was);
            was = r.flags.turn;
        }
        assert!(toggles > 4, "{toggles}");
    }

    #[test]
    fn unmeasured_vertical_rate_and_old_samples_are_ignored() {
        let mut gate = Gate::new(GateParams::default());
        let mut cov = Matrix3::identity() * 0.25;
        cov[(2, 2)] = UNMEASURED_VARIANCE;
        for k in 0..12 {
            gate.push(
                k as f64 * 0.5,
                &Observed {
                    value: Vector3::new(100.0, 0.0, 50.0),
                    cov,
                    grid: None,
                },
                true,
            );
        }
        assert_eq!(gate.reading().vertical_rate_mps, None);
        assert!(!gate.reading().manoeuvre());
        // Out-of-order and non-finite samples change nothing.
        let before = gate.clone();
        gate.push(
            1.0,
            &Observed {
                value: Vector3::new(0.0, 100.0, 0.0),
                cov,
                grid: None,
            },
            true,
        );
        gate.push(
            f64::NAN,
            &Observed {
                value: Vector3::new(0.0, 100.0, 0.0),
                cov,
                grid: None,
            },
            true,
        );
        assert_eq!(gate, before);
        // After a 20 s gap the old samples leave the window (15 s).
        gate.push(
            25.5,
            &Observed {
                value: Vector3::new(0.0, 100.0, 0.0),
                cov,
                grid: None,
            },
            true,
        );
        assert_eq!(gate.reading().turn_rate_rad_s, None);
    }

    /// Any f64 a decoder could hand over, the awkward ones often.
    fn any_value() -> impl proptest::strategy::Strategy<Value = f64> {
        use proptest::prelude::*;
        prop_oneof![
            4 => -400.0..400.0f64,
            1 => Just(0.0),
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => Just(-1e300),
            1 => Just(1e300),
            1 => Just(f64::MIN_POSITIVE),
        ]
    }

    /// [`hinge_onset`] written plainly: for each split, the reference's slope by two-pass
    /// least squares, then the hinge fit by its centred sums; the strongest split in σ.
    fn hinge_reference(
        all: &[(f64, f64, f64)],
        max_newest: usize,
        lambda: f64,
    ) -> Option<(f64, f64, f64)> {
        let n = all.len();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let sum_var: f64 = all.iter().map(|p| p.2).sum();
        let mut best: Option<(f64, f64, f64)> = None;
        for m in 1..=max_newest {
            let Some(split) = n.checked_sub(m).filter(|&s| s >= 3) else {
                break;
            };
            let (rt, ry): (Vec<f64>, Vec<f64>) = all[..split].iter().map(|p| (p.0, p.1)).unzip();
            let (tb, yb) = (mean(&rt), mean(&ry));
            let sxx: f64 = rt.iter().map(|t| (t - tb) * (t - tb)).sum();
            let sxy: f64 = rt.iter().zip(&ry).map(|(t, y)| (t - tb) * (y - yb)).sum();
            if sxx <= 0.0 || (sxy / sxx).abs() >= lambda {
                continue;
            }
            let t_ref = all[split - 1].0;
            let h: Vec<f64> = all.iter().map(|p| (p.0 - t_ref).max(0.0)).collect();
            let y: Vec<f64> = all.iter().map(|p| p.1).collect();
            let (hb, yb) = (mean(&h), mean(&y));
            let hxx: f64 = h.iter().map(|v| (v - hb) * (v - hb)).sum();
            let hxy: f64 = h.iter().zip(&y).map(|(a, b)| (a - hb) * (b - yb)).sum();
            if hxx <= 0.0 {
                continue;
            }
            let (b, sigma) = (hxy / hxx, (sum_var / n as f64 / hxx).sqrt());
            if best.is_none_or(|(b0, s0, _)| b.abs() / sigma > b0.abs() / s0) {
                best = Some((b, sigma, t_ref));
            }
        }
        best
    }

    /// Two-pass least squares of (t, y, var) points: the slope and its σ for the mean
    /// variance.
    fn ls_reference(points: &[(f64, f64, f64)]) -> Option<(f64, f64)> {
        let n = points.len() as f64;
        if n < 3.0 {
            return None;
        }
        let tb = points.iter().map(|p| p.0).sum::<f64>() / n;
        let yb = points.iter().map(|p| p.1).sum::<f64>() / n;
        let vb = points.iter().map(|p| p.2).sum::<f64>() / n;
        let sxx: f64 = points.iter().map(|p| (p.0 - tb) * (p.0 - tb)).sum();
        let sxy: f64 = points.iter().map(|p| (p.0 - tb) * (p.1 - yb)).sum();
        (sxx > 0.0).then(|| (sxy / sxx, (vb / sxx).sqrt()))
    }

    /// The gate's rate tests written plainly, a window and a fit per test as
    /// [`Gate::evaluate`] did before it gathered every window in one pass: the reading that
    /// follows `old` on the gate's current samples (the paper's tests aside: they read
    /// first and last samples only, and are not part of the pass).
    /// [`hinge_end`] by a plain least-squares solve per split (Cholesky of AᵀA), in
    /// coordinates centred on the newest report.
    fn hinge_end_reference(pts: &[(f64, f64, f64)], lambda: f64, k: f64) -> Option<f64> {
        let n = pts.len();
        let &(t0, y0, _) = pts.last()?;
        let mean_var = pts.iter().map(|q| q.2).sum::<f64>() / n as f64;
        let mut best: Option<(f64, f64)> = None;
        for m in (END_MIN_NEWEST..=END_TURN_REPORTS).filter(|&m| n >= m + END_MIN_REFERENCE) {
            let t_ref = pts[n - 1 - m].0 - t0;
            let a = nalgebra::DMatrix::from_fn(n, 3, |i, j| match j {
                0 => 1.0,
                1 => pts[i].0 - t0,
                _ => (pts[i].0 - t0 - t_ref).max(0.0),
            });
            let y = nalgebra::DVector::from_fn(n, |i, _| pts[i].1 - y0);
            let Some(chol) = (a.transpose() * &a).cholesky() else {
                continue;
            };
            let x = chol.solve(&(a.transpose() * y));
            let cov = chol.inverse() * mean_var;
            let (b, c) = (x[1], x[2]);
            let var_since = cov[(1, 1)] + cov[(2, 2)] + 2.0 * cov[(1, 2)];
            let z2 = c * c / cov[(2, 2)];
            let ends = b.abs() > lambda
                && c * b < 0.0
                && z2 > k * k
                && (b + c).abs() < lambda + 2.0 * var_since.max(0.0).sqrt();
            if ends && best.is_none_or(|(z0, _)| z2 > z0) {
                best = Some((z2, b + c));
            }
        }
        best.map(|(_, since)| since)
    }

    fn reading_reference(
        gate: &Gate,
        old: GateFlags,
        start: Option<f64>,
        since: Option<(f64, f64, LineSums)>,
    ) -> GateReading {
        let p = *gate.params;
        let mut r = GateReading::default();
        let heading = |w: &[Sample]| -> Option<(f64, f64)> {
            if w.iter().any(|s| s.speed_mps < p.min_speed_mps) {
                return None;
            }
            let pts: Vec<_> = w
                .iter()
                .map(|s| (s.t_s, s.heading_rad, s.heading_var()))
                .collect();
            ls_reference(&pts)
        };
        // The (t, heading, variance) of a window whose every sample is measured and fast
        // enough: what the onset and end tests read.
        let headings = |w: &[Sample]| -> Option<Vec<(f64, f64, f64)>> {
            w.iter()
                .all(|s| s.measured && s.speed_mps >= p.min_speed_mps)
                .then(|| {
                    w.iter()
                        .map(|s| (s.t_s, s.heading_rad, s.heading_var()))
                        .collect()
                })
        };
        let lambda_turn = p.turn_rate_deg_s.map(f64::to_radians);
        if let Some((slope, sigma)) = heading(gate.recent(p.turn_window_reports)) {
            r.turn_rate_rad_s = Some(slope);
            r.flags.turn = fires(slope, sigma, lambda_turn, old.turn || old.turn_onset, &p);
        }
        if let (true, Some(start), Some(k), Some(lambda)) =
            (r.flags.turn, start, p.turn_end_sigmas, lambda_turn)
        {
            let since: Vec<_> = gate
                .recent(p.trend_window_reports)
                .iter()
                .filter(|s| s.t_s > start)
                .copied()
                .collect();
            if let Some(pts) = headings(&since) {
                r.flags.turn_end = hinge_end_reference(&pts, lambda, k).is_some();
            }
        }
        if let (false, Some(lambda)) = (r.flags.turn, lambda_turn) {
            let all = gate.recent(p.onset_reference_reports + p.onset_reports);
            if let (true, Some(pts)) = (p.onset_reports > 0, headings(all)) {
                if let Some((rate, sigma, _)) = hinge_reference(&pts, p.onset_reports, lambda) {
                    r.flags.turn_onset = onset_fires(rate, sigma, lambda, false, &p);
                    r.onset_turn_rate_rad_s = Some(rate);
                }
                // The first-report test: the newest report's hinge alone, its reference (every
                // report before it, at the mean variance of all) not drifting.
                if let (false, Some(k)) = (r.flags.turn_onset, p.first_report_turn_sigmas) {
                    let mean_var = pts.iter().map(|q| q.2).sum::<f64>() / pts.len() as f64;
                    let reference: Vec<_> = pts[..pts.len() - 1]
                        .iter()
                        .map(|&(t, y, _)| (t, y, mean_var))
                        .collect();
                    let steady = ls_reference(&reference)
                        .is_some_and(|(b, s)| (b / s).abs() < FIRST_REPORT_MAX_DRIFT_Z);
                    if let (true, Some((rate, sigma, _))) =
                        (steady, hinge_reference(&pts, 1, lambda))
                    {
                        if rate.abs() > lambda && rate.abs() > k * sigma {
                            r.flags.turn_first_report = true;
                            r.onset_turn_rate_rad_s = Some(rate);
                        }
                    }
                }
            }
        }
        let trend: Vec<_> = gate
            .recent(p.trend_window_reports)
            .iter()
            .filter(|s| s.measured)
            .map(|s| (s.t_s, s.speed_mps, s.var_h))
            .collect();
        if let Some((slope, sigma)) = ls_reference(&trend) {
            r.along_track_accel_mps2 = Some(slope);
            let was = old.along_track || old.accel_onset;
            r.flags.along_track = fires(slope, sigma, p.along_track_accel_mps2, was, &p);
        }
        if let (false, Some(lambda)) = (r.flags.along_track, p.along_track_accel_mps2) {
            let all = gate.recent(p.accel_onset_reference_reports + p.accel_onset_reports);
            if p.accel_onset_reports > 0 && all.iter().all(|s| s.measured) {
                let pts: Vec<_> = all.iter().map(|s| (s.t_s, s.speed_mps, s.var_h)).collect();
                if let Some((rate, sigma, _)) = hinge_reference(&pts, p.accel_onset_reports, lambda)
                {
                    let held = old.accel_onset || old.along_track;
                    r.flags.accel_onset = onset_fires(rate, sigma, lambda, held, &p);
                    r.onset_accel_mps2 = Some(rate);
                }
            }
        }
        // The hold: the line since the acceleration fired (its sums as the gate kept them
        // before this report) against this window's trend.
        if let (true, false, Some(k), Some((_, _, since))) = (
            old.along_track || old.accel_onset,
            r.flags.along_track || r.flags.accel_onset,
            p.accel_hold_sigmas,
            since,
        ) {
            let line = (since.n >= ACCEL_HOLD_MIN_REPORTS).then(|| since.slope());
            if let (Some(Some((ls, lsig))), Some((ts, tsig))) = (line, ls_reference(&trend)) {
                if fires(ls, lsig, p.along_track_accel_mps2, true, &p)
                    && (ts - ls) * ls.signum() > -k * tsig.hypot(lsig)
                {
                    r.flags.along_track = true;
                    r.along_track_accel_mps2 = Some(ls);
                }
            }
        }
        let learned = gate
            .vrate_noise
            .var()
            .map(|v| v.max(p.vrate_quantum_mps.powi(2) / 12.0));
        let vertical: Vec<_> = gate
            .recent(p.vertical_window_reports)
            .iter()
            .filter(|s| s.measured && s.var_u.is_finite())
            .map(|s| (s.vu_mps, learned.unwrap_or(s.var_u)))
            .collect();
        if !vertical.is_empty() {
            let n = vertical.len() as f64;
            let mean = vertical.iter().map(|v| v.0).sum::<f64>() / n;
            let sigma = (vertical.iter().map(|v| v.1).sum::<f64>() / n / n).sqrt();
            r.vertical_rate_mps = Some(mean);
            let sigma = if old.vertical { 0.0 } else { sigma };
            r.flags.vertical = fires(mean, sigma, p.vertical_rate_mps, old.vertical, &p);
            if let (false, Some(k), Some(lambda)) = (
                r.flags.vertical,
                p.vertical_onset_sigmas,
                p.vertical_rate_mps,
            ) {
                // Every m = 2..n−1 newest, brute force.
                for m in VERTICAL_ONSET_MIN_REPORTS..vertical.len() {
                    let newest = &vertical[vertical.len() - m..];
                    let mean_m = newest.iter().map(|v| v.0).sum::<f64>() / m as f64;
                    let sigma_m = newest.iter().map(|v| v.1).sum::<f64>().sqrt() / m as f64;
                    let one_side =
                        newest.iter().all(|v| v.0 > 0.0) || newest.iter().all(|v| v.0 < 0.0);
                    if one_side && mean_m.abs() > lambda && mean_m.abs() > k * sigma_m {
                        r.flags.vertical = true;
                        if mean_m.signum() != mean.signum() {
                            r.vertical_rate_mps = Some(mean_m);
                        }
                        break;
                    }
                }
            }
        }
        r
    }

    /// The one-pass [`Gate::evaluate`] reads what a window and a fit per test read
    /// ([`reading_reference`]): the same tests hold and every statistic agrees to 1e-9
    /// (relative), on random flights of straight legs, turns, accelerations, climbs and
    /// slow taxiing, reported 0.2-3 s apart with gaps past the windows' time cut, a share
    /// of them derived, through many slides of the buffer; with the default windows and
    /// with every window of a different length.
    #[test]
    fn one_pass_evaluation_reads_what_a_fit_per_window_reads() {
        let odd = GateParams {
            turn_window_reports: 7,
            onset_reports: 4,
            onset_reference_reports: 5,
            trend_window_reports: 17,
            accel_onset_reports: 6,
            accel_onset_reference_reports: 9,
            vertical_window_reports: 3,
            ..GateParams::default()
        };
        let mut fired = [0usize; 6];
        for (case, params) in [GateParams::default(), odd].into_iter().enumerate() {
            for seed in 0..40u64 {
                let mut rng = StdRng::seed_from_u64(1000 * case as u64 + seed);
                let mut gate = Gate::new(params);
                let (mut t, mut heading_deg, mut speed, mut vu) = (0.0, 0.0, 120.0f64, 0.0);
                let (mut turn_deg_s, mut accel, mut leg_end) = (0.0, 0.0, 0.0);
                for k in 0..600 {
                    let dt = if k % 151 == 150 {
                        20.0
                    } else {
                        rng.gen_range(0.2..3.0)
                    };
                    t += dt;
                    if t > leg_end {
                        leg_end = t + rng.gen_range(5.0..40.0);
                        turn_deg_s = [0.0, 0.0, 3.0, -1.5, 0.7][rng.gen_range(0..5)];
                        accel = [0.0, 0.0, 0.4, -0.8][rng.gen_range(0..4)];
                        vu = [0.0, 0.0, 6.0, -4.0][rng.gen_range(0..4)];
                        if rng.gen_range(0..10) == 0 {
                            speed = 6.0;
                        }
                    }
                    heading_deg += turn_deg_s * dt;
                    speed = (speed + accel * dt).clamp(3.0, 260.0);
                    let measured = rng.gen_range(0..8) != 0;
                    let v = report(heading_speed(heading_deg, speed, vu), 0.8, &mut rng);
                    let (old, start, since) =
                        (gate.reading().flags, gate.turn_start_s, gate.accel_since);
                    let got = *gate.push(t, &v, measured);
                    let want = reading_reference(&gate, old, start, since);
                    let close = |a: Option<f64>, b: Option<f64>| match (a, b) {
                        (None, None) => true,
                        (Some(a), Some(b)) => {
                            (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1e-3)
                        }
                        _ => false,
                    };
                    let ctx = format!("case {case}, seed {seed}, report {k}: {got:?} vs {want:?}");
                    assert_eq!(got.flags, want.flags, "{ctx}");
                    assert!(close(got.turn_rate_rad_s, want.turn_rate_rad_s), "{ctx}");
                    assert!(
                        close(got.onset_turn_rate_rad_s, want.onset_turn_rate_rad_s),
                        "{ctx}"
                    );
                    assert!(
                        close(got.along_track_accel_mps2, want.along_track_accel_mps2),
                        "{ctx}"
                    );
                    assert!(close(got.onset_accel_mps2, want.onset_accel_mps2), "{ctx}");
                    assert!(
                        close(got.vertical_rate_mps, want.vertical_rate_mps),
                        "{ctx}"
                    );
                    for (n, f) in fired.iter_mut().zip([
                        got.flags.turn,
                        got.flags.turn_onset,
                        got.flags.along_track,
                        got.flags.accel_onset,
                        got.flags.vertical,
                        got.flags.turn_end,
                    ]) {
                        *n += usize::from(f);
                    }
                }
            }
        }
        // Every test fired (the onset and end tests on fewer reports: they hold only until
        // the turn or trend test takes over, or releases), so the comparison covered both
        // sides of each.
        assert!(fired.iter().all(|&n| n > 50), "{fired:?}");
    }

    proptest::proptest! {
        /// The division-free [`hinge_onset`] finds the split the plain fit finds,
        /// with the same rate, σ and onset time (to 1e-9, relative).
        #[test]
        fn hinge_onset_is_the_plain_least_squares_fit(
            gaps in proptest::collection::vec(0.3..1.2f64, 4..32),
            values in proptest::collection::vec(-3.0..3.0f64, 32),
            ramp in -2.0..2.0f64,
            start in 0usize..30,
            t0 in 0.0..1e5f64,
        ) {
            let mut t = t0;
            let mut points = Vec::new();
            for (k, (gap, v)) in gaps.iter().zip(&values).enumerate() {
                t += gap;
                let y = 100.0 + v + ramp * (k.saturating_sub(start) as f64);
                points.push((t, y, 0.5 + v.abs()));
            }
            let samples: Vec<Sample> = points
                .iter()
                .map(|&(t_s, speed_mps, var_h)| Sample { t_s, speed_mps, var_h, measured: true, ..Sample::default() })
                .collect();
            let newest = samples[samples.len() - 1];
            let ty = |s: &Sample| (s.t_s - newest.t_s, s.speed_mps - newest.speed_mps);
            let mut totals = LineSums::default();
            for s in &samples {
                let (t, y) = ty(s);
                totals.add(t, y, s.var_h);
            }
            let (fast, first) = hinge_onset(&samples, &totals, 12, 0.3, ty);
            let fast = fast.map(|(b, sigma, t_ref)| (b, sigma, t_ref + newest.t_s));
            // The m = 1 split's sums give its own fit (the first-report test's).
            let plain_first = hinge_reference(&points, 1, 0.3);
            match (first, plain_first) {
                (Some(FirstSplit { n_hy, n_hxx, .. }), Some((b, sigma, _))) => {
                    let sum_var: f64 = points.iter().map(|q| q.2).sum();
                    let (fb, fs) = (n_hy / n_hxx, (sum_var / n_hxx).sqrt());
                    assert!((fb - b).abs() <= 1e-9 * fb.abs().max(b.abs()).max(1.0), "{fb} vs {b}");
                    assert!((fs - sigma).abs() <= 1e-9 * fs.max(sigma).max(1.0), "{fs} vs {sigma}");
                }
                (None, None) => {}
                other => panic!("m = 1 {other:?}"),
            }
            let plain = hinge_reference(&points, 12, 0.3);
            let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0);
            match (fast, plain) {
                (None, None) => {}
                (Some(f), Some(p)) => {
                    proptest::prop_assert!(close(f.0, p.0) && close(f.1, p.1) && close(f.2, p.2), "{f:?} vs {p:?}");
                }
                (f, p) => proptest::prop_assert!(false, "{f:?} vs {p:?}"),
            }
        }

        /// Whatever reports arrive (non-finite values, zero or huge covariances, repeated or
        /// jumping times, measured or derived), the gate never panics and what it reads is
        /// finite or absent, and a test that holds has its statistic.
        #[test]
        fn any_report_sequence_gives_a_finite_reading(
            reports in proptest::collection::vec(
                (0.0..3.0f64, any_value(), any_value(), any_value(), any_value(), any_value(),
                 proptest::bool::ANY, any_value()),
                1..80,
            )
        ) {
            let mut gate = Gate::new(GateParams::default());
            let mut t = 0.0;
            for (dt, ve, vn, vu, var_h, var_u, measured, alt_m) in reports {
                t += dt;
                gate.altitude(alt_m);
                let cov = Matrix3::from_diagonal(&Vector3::new(var_h.abs(), var_h.abs(), var_u.abs()));
                let r = *gate.push(t, &Observed { value: Vector3::new(ve, vn, vu), cov, grid: None }, measured);
                for v in [
                    r.turn_rate_rad_s,
                    r.onset_turn_rate_rad_s,
                    r.along_track_accel_mps2,
                    r.onset_accel_mps2,
                    r.vertical_rate_mps,
                ]
                .into_iter()
                .flatten()
                {
                    proptest::prop_assert!(v.is_finite(), "{r:?}");
                }
                proptest::prop_assert!(!r.flags.accel_onset || r.onset_accel_mps2.is_some());
                proptest::prop_assert!(!r.flags.vertical || r.vertical_rate_mps.is_some());
                proptest::prop_assert!(gate.vrate_noise.var().is_none_or(f64::is_finite));
            }
        }
    }
}
