//! The project's default tracker: paper 002's threshold-gated CV Kalman filter / IMM
//! (ALGORITHMS.md §002), every Kalman step guarded by paper 000's divergence suppressor.
//!
//! - Below every gate threshold ([`super::gate`]) the cheap 6-state CV Kalman filter runs
//!   (filter "kalman-cv"; paper 002 §1.2 case 1, eq. 6–10). When a gate fires, or when the CV
//!   filter keeps diverging (paper 000's criterion on `divergence_trigger` consecutive
//!   reports: how a track fed only positions notices a manoeuvre), the IMM over the models of
//!   [`super::models`] takes over (filter "imm"; §1.2 case 2).
//! - The switch carries the state over exactly: CV → IMM starts every IMM model at
//!   [x̂, 0] with P = diag(P, σ_a² I) (the acceleration unknown), so the combined estimate is
//!   the CV estimate; IMM → CV keeps the position/velocity part of the combined estimate
//!   and its covariance block (the marginal). No jump.
//! - The IMM runs over CV and the modes the gate named ([`gate_modes`]; every mode when it
//!   opens blind or by divergence alone): a turn needs no climb models, and the measured
//!   velocities already say which manoeuvre it is (`variable_structure`).
//! - No chatter: the gate has hysteresis, and the IMM stays on for at least
//!   `min_manoeuvre_dwell_s` after the gate last fired.
//! - Blind: the gate needs measured velocities. On a track fed positions only (no velocity
//!   report for `velocity_stale_s`) it could only read the filter's own velocity, which lags
//!   a turn and scatters inside one, so the IMM runs and labels by its own mode
//!   probabilities (`imm_without_velocity`, default on: the hybrid is then the IMM). With
//!   it off, the gate decides on that velocity, the IMM stays on while its most probable
//!   mode is a manoeuvre and its CT models keep the configured rate.
//! - Labels: while a gate test holds, the label and the I062/200 movement axes are the
//!   gate's (turn → CT with its direction; vertical and speed → CHCA; vertical → CH; speed
//!   → CA). While the IMM runs with no gate test holding, the IMM's most probable mode when
//!   the gate has no measured velocity to read (a track fed positions only) or the IMM was
//!   opened by divergence alone, else CV. On the CV filter, CV. The gate reads velocities
//!   measured by ADS-B, so it labels with almost no delay and without the IMM's glitches
//!   (paper 002 Fig. 8).
//! - [`Tracker::predict`] extrapolates by the model of the current label (paper 002 §1.3):
//!   CV, CA, CH, CHCA, or CT at the rate of the current turn as the gate measures it
//!   ([`Gate::turn_rate_since_start_rad_s`]).

use super::divergence::{guarded_update, let_prediction, DivergenceParams, Observation};
use super::gate::{Gate, GateFlags, GateParams, GateReading};
use super::imm::{
    estimate_of, labels_of_mode, AxisThresholds, EstimateInfo, HeldModeFit, Imm, ImmMode,
    ImmParams, InitParams, Initiator, Labels, Start, IMM_NAME, N_MODES,
};
use super::kalman::{self, MotionModel};
use super::lag::VelocityLag;
use super::models::{Cv, Matrix6, Matrix9, Model, State6, State9, ACC};
use super::nis::NisWindow;
use super::noise::{height_m, local_up, NoiseLearner, NoiseParams};
use super::outlier::{OutlierGate, OutlierParams};
use super::process_noise::{Narrow, SteadyQ, SteadyQParams};
use super::tails::{TailIndex, TailParams};
use super::{
    Estimate, FlightMode, Lateral, Measurement, Observed, PositionPrediction, TrackError, Tracker,
    TurnDirection,
};
use nalgebra::{Matrix3, Vector3};

/// CA's IMM probability under which a confirmed turn (its direction known, no speed test
/// holding) runs without it: [`HybridTracker::running_set`]. A mode at 0.1 % adds 0.1 % of
/// its estimate to the mixture; CA comes back when a turn onset, a heading change or a
/// speed test names it again.
const CA_PRUNE_PROBABILITY: f64 = 0.001;

/// Name of the hybrid tracker.
pub const NAME: &str = "hybrid";

/// [`Estimate::filter`] while the CV Kalman filter runs.
pub const CV_FILTER: &str = "kalman-cv";

/// The IMM modes the gate's tests name ([`HybridParams::variable_structure`]): CV always
/// (every manoeuvre ends in it); for a turn CA, whose free horizontal acceleration follows a
/// turn flown at another rate than the CT models' (without it, paper 000's 4 g reversal:
/// turn velocity RMSE 11.8 m/s against 10.8, 100 runs; kept for a confirmed turn too, where
/// leaving it out cost paper 003's turns 5 % of their velocity RMSE), and the CT mode of the
/// turn's `direction`, or both CT modes when none is given (the caller gives it only while
/// the turn-rate test holds without an onset test: at an onset the direction may be
/// misread); CA for a speed change; CH for a climb or descent; CHCA for a horizontal
/// acceleration (speed or turn) with a vertical one (a turn begun while levelling off:
/// without it, the departure's turn altitude RMSE 5.4 m against 4.3). `None` when no test
/// holds.
pub fn gate_modes(flags: &GateFlags, direction: Option<TurnDirection>) -> Option<[bool; N_MODES]> {
    let turn = flags.turning();
    let left = turn && direction != Some(TurnDirection::Right);
    let right = turn && direction != Some(TurnDirection::Left);
    let speed = flags.speed_changing();
    let vertical = flags.vertical || flags.pitch_change;
    if !(turn || speed || vertical) {
        return None;
    }
    let mut modes = [false; N_MODES];
    for (on, mode) in [
        (true, ImmMode::Cv),
        (speed || turn, ImmMode::Ca),
        (left, ImmMode::CtLeft),
        (right, ImmMode::CtRight),
        (vertical, ImmMode::Ch),
        ((speed || turn) && vertical, ImmMode::Chca),
    ] {
        if let Some(m) = modes.get_mut(mode.index()) {
            *m = on;
        }
    }
    Some(modes)
}

/// q_h of the hybrid's CV filter by default, m²/s³: it runs in steady flight only, the gate
/// handing every manoeuvre to the IMM (whose CV mode keeps [`Cv::default`]'s 0.25).
/// What a real airliner's velocity shows over the next seconds: on AFR34ZG at cruise the
/// mean squared change of the velocity reports per axis grows by 0.06 (m/s)² a second over
/// lags of 0.5-2.6 s (the slope, free of the 1-kt steps' flicker; docs/evaluation.md,
/// "Velocity reports that repeat"). `kalman-cv`, whose one model rides through every
/// manoeuvre, keeps (0.5 m/s²)²·s = 0.25 (`track::cv::CvParams`), and so does the IMM's CV
/// mode: with less, the plain `imm` took AFR34ZG's gentle wander for turns (CT on 210
/// updates instead of 100, their NIS/dof 5.6 instead of 1.9). At 0.25 here, where the
/// reports are GNSS-grade, the velocity covariance was 15 times the error (velocity ANEES
/// 0.13 on `airliner-gnss-velocity`); the position's claim stays honest at the lower value
/// because its correlated share is learned from successive reports (`track::noise`).
pub const STEADY_Q_H_M2PS3: f64 = 0.06;

/// Tuning of [`HybridTracker`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HybridParams {
    /// The CV filter's model (6-state). Default [`Cv::default`] with q_h
    /// [`STEADY_Q_H_M2PS3`].
    pub cv: Cv,
    /// The IMM.
    pub imm: ImmParams,
    /// The gate. Default [`GateParams::default`]; paper 002's is [`GateParams::paper002`].
    pub gate: GateParams,
    /// Paper 000 on the CV filter's steps.
    pub divergence: DivergenceParams,
    /// Initiation.
    pub init: InitParams,
    /// Movement-axis thresholds when the IMM labels (opened by divergence alone).
    pub axes: AxisThresholds,
    /// The IMM stays on at least this long after the gate last fired, s. Default 4 s: eight
    /// ADS-B velocity reports, longer than the gate's turn window (2 s), so a gate
    /// flickering at a threshold does not flip the filter back and forth.
    pub min_manoeuvre_dwell_s: f64,
    /// Consecutive divergence events of the CV filter that open the IMM without the gate.
    /// Default 3: a consistent CV filter meets paper 000's criterion (r = 3) on ~3-6 % of
    /// reports, so three in a row by chance happen about once in 10⁴ reports.
    pub divergence_trigger: u32,
    /// Without a velocity report for this long, the gate is fed the filter's own velocity
    /// after each position update, s. Default 3 s (six missed ADS-B velocity reports).
    pub velocity_stale_s: f64,
    /// Run the IMM whenever velocity reports are stale (`velocity_stale_s`), gate or not.
    /// Default true: from positions alone the gate sees a turn late, through the CV filter's
    /// lagging velocity, and hands the IMM a diverged state. Measured on paper 002 fed
    /// positions only (100 runs): turns 30.8 m with the gate deciding against the IMM's
    /// 23.2 m, straight legs 20.3 m against 22.0 m, over the whole flight 23.9 m against
    /// 22.4 m; on paper 000's 4 g reversal fed positions only, turns 51 m against 24 m.
    pub imm_without_velocity: bool,
    /// Set the CT models' turn rate to the one the gate measures while a turn holds (within
    /// `turn_rate_limits_deg_s`), instead of the fixed standard rate. Default true: airliners
    /// turn at 1-3 °/s depending on speed and bank.
    pub adapt_turn_rate: bool,
    /// Clamp of the adapted turn rate, °/s. Default 0.5 to 6.
    pub turn_rate_limits_deg_s: (f64, f64),
    /// The measurement noise learned per aircraft ([`super::noise`]): the CV filter, the
    /// IMM and the gate all see the declared covariance scaled by what the CV filter's
    /// innovations taught. Learned only while the CV filter runs.
    pub noise: NoiseParams,
    /// IMM probability given to the gate's label when the IMM opens; CV gets half the rest
    /// and the other modes share the remainder. Default 0.5.
    pub entry_probability: f64,
    /// The IMM runs over CV and the modes the gate named within `min_manoeuvre_dwell_s`
    /// ([`gate_modes`]), not all six: a variable-structure IMM whose model set the measured
    /// velocities choose (paper 002 §1.2: "which thresholds fire chooses" among the
    /// manoeuvre models; paper 003's VSIMM). Default true. A level turn runs CV, CA and the
    /// CT mode of its direction (both CT modes at its onset) instead of all six, a speed
    /// change CV and CA, and
    /// the mixing sums over as many fewer pairs. A mode stays in the set for the dwell after
    /// the gate last named it, as the IMM itself does after the gate's last test. Opened by
    /// divergence alone, or blind (no measured velocity), the IMM keeps every mode: nothing
    /// then says which manoeuvre it is.
    pub variable_structure: bool,
    /// Learn how much older the aircraft's velocity reports are than its positions
    /// ([`super::lag::VelocityLag`]) and let the IMM's CT modes allow for it
    /// ([`ImmParams::velocity_lag_s`], which applies until then). Default true: a lag is used
    /// once the turns and speed changes seen put it above 0.1 s by three standard errors.
    pub learn_velocity_lag: bool,
    /// Position reports out of their time set aside ([`super::outlier`]): while velocity
    /// reports show a straight flight, a position whose horizontal NIS in the CV filter
    /// is one a consistent filter shows once in 10⁶ reports, at most four in a row and
    /// while such reports are rare; in the IMM branch, the same against the held mode
    /// while the velocity reports fit it. Default on ([`OutlierParams::default`]).
    pub outliers: OutlierParams,
    /// The CV filter's q_h scaled per aircraft by what its velocity reports show
    /// ([`super::process_noise`]), at most the configured [`HybridParams::cv`]'s. Default on.
    pub steady_q: SteadyQParams,
    /// A position report's term of the windowed NIS read under a Student-t claim of the
    /// aircraft's own tail index ([`super::tails`]); the estimate is unchanged. Default on.
    pub tails: TailParams,
    /// The same for a velocity report on a narrow claim, its two quantile residuals read
    /// under the tail index of the aircraft's velocity reports (module doc of
    /// [`super::tails`], "Velocity reports"). Default on.
    pub velocity_tails: TailParams,
}

impl Default for HybridParams {
    fn default() -> Self {
        Self {
            cv: Cv {
                q_h_m2ps3: STEADY_Q_H_M2PS3,
                ..Cv::default()
            },
            imm: ImmParams::default(),
            gate: GateParams::default(),
            divergence: DivergenceParams::default(),
            init: InitParams::default(),
            axes: AxisThresholds::default(),
            min_manoeuvre_dwell_s: 4.0,
            divergence_trigger: 3,
            velocity_stale_s: 3.0,
            imm_without_velocity: true,
            adapt_turn_rate: true,
            turn_rate_limits_deg_s: (0.5, 6.0),
            entry_probability: 0.5,
            variable_structure: true,
            noise: NoiseParams::default(),
            learn_velocity_lag: true,
            outliers: OutlierParams::default(),
            steady_q: SteadyQParams::default(),
            tails: TailParams::default(),
            velocity_tails: TailParams::default(),
        }
    }
}

impl HybridParams {
    /// Paper 002's tracker as printed: its gate thresholds ([`GateParams::paper002`]) and
    /// its RMIMM over every mode (its gate's changes name a manoeuvre's onset, not the modes
    /// that follow it; with the model set following them, the departure's turn altitude RMSE
    /// was 4.3 m against 3.2).
    pub fn paper002() -> Self {
        Self {
            gate: GateParams::paper002(),
            variable_structure: false,
            ..Self::default()
        }
    }
}

/// A velocity given in the track frame's axes, turned into the east-north-up axes at `pos_m`
/// (a position in that frame), for the gate's tests.
///
/// The filter works in one fixed tangent plane per track, which is exact Cartesian geometry;
/// but there a level aircraft d metres from the origin has a "vertical" velocity of about
/// −v·d/R (10 m/s at 300 km), and the gate's climb test would fire on every cruise. The
/// labels are about the aircraft's own vertical, so the gate reads the velocity rotated by
/// the minimal rotation taking the frame's up to the local up of a spherical Earth,
/// normalize(p + R·ẑ). The sphere's normal differs from the ellipsoid's by under 1 % of the
/// tilt (0.2 m/s at 600 km and 230 m/s); the meridian convergence the minimal rotation leaves
/// in the heading is constant over the gate's window, whose tests read changes.
fn to_local_axes(pos_m: &Vector3<f64>, v: &Observed) -> Observed {
    let z = Vector3::z();
    let up = local_up(pos_m);
    let axis = z.cross(&up);
    let sin = axis.norm();
    if sin.is_nan() || sin <= 1e-12 || !up.iter().all(|c| c.is_finite()) {
        return *v;
    }
    let cos = z.dot(&up);
    let k = axis / sin;
    // Rodrigues: R = I cosθ + sinθ [k]x + (1 − cosθ) k kᵀ takes ẑ to `up`; the local axes are
    // R's columns, so local components are Rᵀ v.
    let kx = Matrix3::new(0.0, -k.z, k.y, k.z, 0.0, -k.x, -k.y, k.x, 0.0);
    let r = Matrix3::identity() * cos + kx * sin + k * k.transpose() * (1.0 - cos);
    let rt = r.transpose();
    Observed {
        value: rt * v.value,
        cov: rt * v.cov * r,
        // The gate reads values and covariances, not bins.
        grid: None,
    }
}

/// Which filter runs.
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(
    clippy::large_enum_variant,
    reason = "one per tracker, held in place; boxing the CV state would allocate"
)]
enum Branch {
    /// The CV Kalman filter with its state.
    Cv { x: State6, p: Matrix6 },
    /// The IMM (its state lives in [`HybridTracker::imm`]); `by_divergence`: opened by the
    /// divergence trigger with no gate test holding (and none since).
    Imm { by_divergence: bool },
}

/// Counters of the tracker's life.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct HybridStats {
    /// Switches CV → IMM.
    pub to_imm: u64,
    /// Switches IMM → CV.
    pub to_cv: u64,
    /// Updates run by the CV filter.
    pub cv_updates: u64,
    /// Updates run by the IMM.
    pub imm_updates: u64,
    /// Times a long gap restarted the track.
    pub reinitialisations: u64,
}

/// Paper 002's hybrid tracker for one aircraft ([`Tracker`] "hybrid"); module doc.
#[derive(Clone, Debug, PartialEq)]
pub struct HybridTracker {
    /// Shared by every tracker built with the same tuning ([`super::shared`]).
    params: std::sync::Arc<HybridParams>,
    gate: Gate,
    imm: Imm,
    init: Initiator,
    branch: Branch,
    labels: Labels,
    /// Feed time of the last report with a velocity.
    last_velocity_t_s: Option<f64>,
    /// In the IMM branch, what the velocity reports vouch for: the manoeuvre the held mode
    /// predicts, as the gate's flags do for the CV filter's straight line.
    imm_fit: HeldModeFit,
    /// Feed time the gate (or the divergence trigger) last held.
    last_fire_t_s: f64,
    /// When the gate last named each IMM mode ([`gate_modes`]), s.
    named_t_s: [f64; N_MODES],
    /// Consecutive divergence events of the CV filter.
    cv_divergence_run: u32,
    /// Position reports set aside ([`super::outlier`]). Kept over a restart, like the
    /// noise: what it learns is the feed's.
    outliers: OutlierGate,
    /// Covariance of the last correction of the velocity estimate, K S Kᵀ (velocity block).
    velocity_correction_cov: Matrix3<f64>,
    diverging: bool,
    divergence_events: u64,
    stats: HybridStats,
    /// The windowed NIS of the running filter's nominal innovations.
    nis: NisWindow,
    /// The aircraft's learned measurement noise. Kept when a gap restarts the track: it
    /// is the transponder's and the receiver's, not the track's.
    noise: NoiseLearner,
    /// The age of its velocity reports, learned (`learn_velocity_lag`); boxed, made at the
    /// first report: under 400 bytes (`tests/memory_budget.rs`) that a tracker built without
    /// it does not hold. Kept over a restart like the noise.
    lag: Option<Box<VelocityLag>>,
    /// Its CV filter's learned factor on q_h ([`super::process_noise`]). Kept over a
    /// restart like the noise: how steadily it flies is the aircraft's.
    steady_q: SteadyQ,
    /// The tail index of its CV filter's position innovations ([`super::tails`]). Kept over
    /// a restart like the noise.
    tails: TailIndex,
    /// The tail index of its CV filter's velocity reports' quantile residuals. Kept the same
    /// way.
    velocity_tails: TailIndex,
}

impl Default for HybridTracker {
    fn default() -> Self {
        Self::new(HybridParams::default())
    }
}

impl HybridTracker {
    /// A tracker with no track yet.
    pub fn new(params: HybridParams) -> Self {
        Self {
            params: super::shared::shared(params),
            gate: Gate::new(params.gate),
            imm: Imm::new(params.imm),
            init: Initiator::new(params.init, &params.cv),
            branch: Branch::Cv {
                x: State6::zeros(),
                p: Matrix6::identity(),
            },
            labels: Labels::CV,
            last_velocity_t_s: None,
            imm_fit: HeldModeFit::default(),
            last_fire_t_s: f64::NEG_INFINITY,
            named_t_s: [f64::NEG_INFINITY; N_MODES],
            cv_divergence_run: 0,
            outliers: OutlierGate::default(),
            velocity_correction_cov: Matrix3::zeros(),
            diverging: false,
            divergence_events: 0,
            stats: HybridStats::default(),
            nis: NisWindow::default(),
            noise: NoiseLearner::default(),
            lag: None,
            steady_q: SteadyQ::default(),
            tails: TailIndex::default(),
            velocity_tails: TailIndex::default(),
        }
    }

    /// The tuning in use.
    pub fn params(&self) -> &HybridParams {
        &self.params
    }

    /// Gives `m` to the velocity-lag learner, and the IMM the lag to use
    /// ([`super::lag::learn`]).
    fn learn_lag(&mut self, m: &Measurement) {
        let track_t_s = self.init.track_t_s();
        let configured_s = self.params.imm.velocity_lag_s;
        if let Some(lag_s) = super::lag::learn(&mut self.lag, m, track_t_s, configured_s) {
            self.imm.set_velocity_lag(lag_s);
        }
    }

    /// Whether the IMM runs.
    pub fn in_imm(&self) -> bool {
        matches!(self.branch, Branch::Imm { .. })
    }

    /// The gate.
    pub fn gate(&self) -> &Gate {
        &self.gate
    }

    /// The IMM (meaningful while [`HybridTracker::in_imm`]).
    pub fn imm(&self) -> &Imm {
        &self.imm
    }

    /// Life counters.
    pub fn stats(&self) -> HybridStats {
        HybridStats {
            reinitialisations: self.init.reinitialisations(),
            ..self.stats
        }
    }

    /// The CV filter's model: the configured one with q_h scaled by what the aircraft's
    /// velocity reports showed ([`super::process_noise`]).
    fn steady_cv(&self) -> Cv {
        Cv {
            q_h_m2ps3: self.params.cv.q_h_m2ps3 * self.steady_q.scale(),
            ..self.params.cv
        }
    }

    /// Starts a track from the initiator's 9-state.
    fn start(&mut self, t_s: f64, x: &State9, p: &Matrix9, velocity: Option<&Observed>) {
        self.branch = Branch::Cv {
            x: kalman::rows::<6, _>(x, 0),
            p: kalman::block::<6, 6, _, _>(p, 0, 0),
        };
        self.gate.clear();
        self.labels = Labels::CV;
        self.last_fire_t_s = f64::NEG_INFINITY;
        self.named_t_s = [f64::NEG_INFINITY; N_MODES];
        self.cv_divergence_run = 0;
        self.diverging = false;
        self.last_velocity_t_s = None;
        self.imm_fit = HeldModeFit::default();
        self.steady_q.restart();
        self.nis.clear();
        if let Some(v) = velocity {
            let local = to_local_axes(&kalman::rows::<3, _>(x, 0), v);
            self.gate.push(t_s, &local, true);
            self.last_velocity_t_s = Some(t_s);
        }
    }

    /// Runs the current filter on the report at `t_s`. `vouched`: current velocity reports
    /// show no horizontal manoeuvre, so a position far off the CV filter's line may be set
    /// aside ([`super::outlier`]); then `Ok(false)`, and the track is as it was. In the IMM
    /// branch a position may be set aside where the held mode's prediction is vouched for
    /// ([`HeldModeFit`]), as in the plain `imm`.
    fn filter_step(
        &mut self,
        t_s: f64,
        dt_s: f64,
        obs: &Observation,
        vouched: bool,
    ) -> Result<bool, TrackError> {
        let cv = self.steady_cv();
        let nis = match &mut self.branch {
            Branch::Cv { x, p } => {
                let (f, q) = MotionModel::<6>::fq(&cv, dt_s);
                let_prediction!(pred = f, q; *x, p);
                let (mut x_new, mut p_new) = (State6::zeros(), Matrix6::zeros());
                let g = guarded_update(
                    &pred,
                    obs,
                    &self.params.divergence,
                    self.cv_divergence_run,
                    &mut x_new,
                    &mut p_new,
                )?;
                // Paper 000's run counts the report either way: a run of reports far off
                // the line is a divergence, whether or not they were used.
                self.cv_divergence_run = g.run;
                if matches!(obs, Observation::Position(_))
                    && self
                        .outliers
                        .set_aside(g.nis_horizontal, vouched, &self.params.outliers)
                {
                    return Ok(false);
                }
                *x = x_new;
                *p = p_new;
                // The report's term of the windowed NIS, its quantiles taken once; a
                // position's, and a velocity's on a narrow claim, read under the aircraft's
                // tail index of its kind before it learns from it. The q_h learner reads the
                // Gaussian quantile NIS: the shape is a claim, the track stays as it is.
                let mut narrow = None;
                let published = match (obs, g.on_grid) {
                    (Observation::Position(o), _) => {
                        let term = self.tails.nis(g.nis_horizontal);
                        if self.params.tails.enabled {
                            self.tails.learn(
                                super::tails::along_track_z(&pred, &o.cov, &o.value),
                                &self.params.tails,
                            );
                        }
                        term
                    }
                    (_, Some(og)) => {
                        let residuals = og.residuals();
                        let d2 = residuals.iter().map(|r| r * r).sum::<f64>();
                        narrow = Some(Narrow {
                            nis: d2,
                            claim_var: og.claim_var(),
                        });
                        let term = self.velocity_tails.nis(d2);
                        if self.params.velocity_tails.enabled {
                            for r in residuals {
                                self.velocity_tails.learn(r, &self.params.velocity_tails);
                            }
                        }
                        term
                    }
                    _ => g.published_nis(),
                };
                self.steady_q.learn(
                    dt_s,
                    matches!(obs, Observation::Velocity(_) | Observation::Both(..)),
                    narrow,
                    self.params.cv.q_h_m2ps3,
                    &self.params.steady_q,
                );
                // Published: a divergence the suppressor acts on (paper 000's criterion on
                // `confirm` consecutive reports), not each chance event; a consistent
                // filter meets the criterion on a few % of reports, four in a row almost
                // never (module doc of `divergence`).
                self.diverging = g.run >= self.params.divergence.confirm;
                let [pos, vel] = g.blocks;
                self.noise.learn(&pos, &vel, &self.params.noise);
                if matches!(obs, Observation::Position(_)) {
                    // Only a report without a velocity may feed the gate a derived one.
                    // Only the velocity block of Adapt·Φ P Φᵀ + Q − P(k|k) is needed.
                    self.velocity_correction_cov = pred.fpf.fixed_view::<3, 3>(3, 3) * g.adapt
                        + pred.q.fixed_view::<3, 3>(3, 3)
                        - p.fixed_view::<3, 3>(3, 3);
                }
                self.stats.cv_updates += 1;
                published
            }
            Branch::Imm { .. } => {
                if !self.imm_fit.step(
                    &mut self.imm,
                    &mut self.outliers,
                    &self.params.outliers,
                    t_s,
                    dt_s,
                    obs,
                )? {
                    return Ok(false);
                }
                let best = self.imm.most_probable();
                self.diverging = self.imm.divergence_run(best) >= self.params.divergence.confirm;
                self.velocity_correction_cov = *self.imm.velocity_correction_cov();
                self.cv_divergence_run = 0;
                self.stats.imm_updates += 1;
                // Where CV is the published mode, its term is a steady report's like the CV
                // filter's and is read under the same two tail indices (which only the CV
                // filter teaches); a manoeuvre's model error reads as what it is.
                let nis = self.imm.published_nis();
                if best != ImmMode::Cv {
                    nis
                } else if matches!(obs, Observation::Position(_)) {
                    self.tails.nis(nis)
                } else if self.imm.published_residuals().is_some() {
                    self.velocity_tails.nis(nis)
                } else {
                    nis
                }
            }
        };
        self.nis.push(nis, obs.horizontal_dof());
        if self.diverging {
            self.divergence_events = self.divergence_events.saturating_add(1);
        }
        Ok(true)
    }

    /// No velocity report for `velocity_stale_s`: the gate reads the filter's velocity.
    fn velocity_stale(&self, t_s: f64) -> bool {
        self.last_velocity_t_s
            .is_none_or(|tv| t_s - tv > self.params.velocity_stale_s)
    }

    /// Feeds the gate: the report's velocity, or the filter's when velocity reports stopped.
    ///
    /// A filtered velocity's error is strongly correlated from one report to the next: what
    /// scatters from report to report is only its correction K ε, of covariance
    /// K S Kᵀ = P(k|k−1) − P(k|k). That, not P(k|k), is the per-sample variance the gate's
    /// least-squares significance test assumes, so it is what a derived sample carries.
    fn feed_gate(&mut self, m: &Measurement) {
        let x = match &self.branch {
            Branch::Cv { x, .. } => *x,
            Branch::Imm { .. } => kalman::rows::<6, _>(&self.imm.combined_state(), 0),
        };
        let pos = kalman::rows::<3, _>(&x, 0);
        if let Some(p) = m
            .position
            .as_ref()
            .filter(|p| p.cov[(2, 2)] < 0.5 * super::UNMEASURED_VARIANCE)
        {
            self.gate.altitude(height_m(&p.value));
        }
        if let Some(v) = &m.velocity {
            self.gate.push(m.t_s, &to_local_axes(&pos, v), true);
            self.last_velocity_t_s = Some(m.t_s);
        } else if self.velocity_stale(m.t_s) {
            let derived = Observed {
                value: kalman::rows::<3, _>(&x, 3),
                cov: self.velocity_correction_cov,
                grid: None,
            };
            self.gate.push(m.t_s, &to_local_axes(&pos, &derived), false);
        }
    }

    /// The IMM's model set at `t_s`: the modes the gate named within the dwell (CV among
    /// them: [`gate_modes`] always names it), when it reads measured velocities; every mode
    /// when the IMM runs blind, on divergence alone (nothing named), or with
    /// `variable_structure` off.
    fn model_set(&self, t_s: f64, blind: bool) -> [bool; N_MODES] {
        let dwell = self.params.min_manoeuvre_dwell_s;
        let mut set = [false; N_MODES];
        for (on, t) in set.iter_mut().zip(self.named_t_s) {
            *on = t_s - t <= dwell;
        }
        if !self.params.variable_structure || blind || !set.contains(&true) {
            [true; N_MODES]
        } else {
            set
        }
    }

    /// The model set of an IMM that is running: [`HybridTracker::model_set`], without CA
    /// in a `confirmed_turn` (the caller's turn direction) where no speed test holds and CA's
    /// probability has fallen under [`CA_PRUNE_PROBABILITY`]. CA follows a turn flown at
    /// another rate than the CT models' (kept in the set for that, [`gate_modes`]); once the
    /// turn's own CT mode holds it, CA filtered for nothing: 4.6 % of a fleet replay's
    /// instructions (`docs/speed.md`).
    fn running_set(
        &self,
        t_s: f64,
        blind: bool,
        confirmed_turn: bool,
        f: &GateFlags,
    ) -> [bool; N_MODES] {
        let mut set = self.model_set(t_s, blind);
        let ca = ImmMode::Ca.index();
        if self.params.variable_structure
            && !blind
            && confirmed_turn
            && !f.speed_changing()
            && self
                .imm
                .probabilities()
                .get(ca)
                .is_some_and(|&mu| mu < CA_PRUNE_PROBABILITY)
        {
            if let Some(on) = set.get_mut(ca) {
                *on = false;
            }
        }
        set
    }

    /// The IMM mode of the gate's label.
    fn entry_mode(&self, reading: &GateReading) -> Option<ImmMode> {
        // The tests' label: the label-only tests only label.
        let (mode, turn) = reading.tested_label()?;
        Some(match (mode, turn) {
            (FlightMode::Ct, Some(TurnDirection::Left)) => ImmMode::CtLeft,
            (FlightMode::Ct, _) => ImmMode::CtRight,
            (FlightMode::Ca, _) => ImmMode::Ca,
            (FlightMode::Ch, _) => ImmMode::Ch,
            (FlightMode::Chca, _) => ImmMode::Chca,
            (FlightMode::Cv, _) => ImmMode::Cv,
        })
    }

    /// IMM mode probabilities for an IMM opened on the gate's `label`.
    fn entry_probabilities(&self, reading: &GateReading) -> Option<[f64; N_MODES]> {
        let target = self.entry_mode(reading)?;
        let e = self.params.entry_probability.clamp(0.0, 1.0);
        let rest = (1.0 - e) / 2.0;
        let mut mu = [rest / (N_MODES - 2) as f64; N_MODES];
        mu[ImmMode::Cv.index()] = rest;
        mu[target.index()] = e;
        Some(mu)
    }

    /// The filter's current position in the track's frame, m.
    fn position_m(&self) -> Vector3<f64> {
        match &self.branch {
            Branch::Cv { x, .. } => kalman::rows::<3, _>(x, 0),
            Branch::Imm { .. } => kalman::rows::<3, _>(&self.imm.combined_state(), 0),
        }
    }

    /// The track predicted to each `(tag, t_s)` of `steps` by the current label's model
    /// ([`Tracker::predict`]): `each(tag, t_s, x, P)`, position and velocity, for the times
    /// at or after the track's (the others are skipped); the IMM's combined estimate is
    /// formed once for all of them. What a whole estimate and, while the IMM runs, a
    /// published prediction share (the CV filter's published predictions compute only the
    /// entries they read, the same bits: [`Tracker::predict_positions`]).
    fn predicted<T>(
        &self,
        steps: impl Iterator<Item = (T, f64)>,
        mut each: impl FnMut(T, f64, &State6, &Matrix6),
    ) {
        let Some(track_t_s) = self.init.track_t_s() else {
            return;
        };
        // (tag and time, dt from the track) for the times that can be predicted.
        let steps =
            steps.filter_map(|(tag, t_s)| Some(((tag, t_s), super::time_ahead_s(track_t_s, t_s)?)));
        match &self.branch {
            Branch::Cv { x, p } => {
                let cv = self.steady_cv();
                for ((tag, t_s), dt_s) in steps {
                    let (mut x, mut p) = (*x, *p);
                    MotionModel::<6>::predict(&cv, &mut x, &mut p, dt_s);
                    each(tag, t_s, &x, &p);
                }
            }
            Branch::Imm { .. } => {
                self.imm.predicted_positions_velocities(
                    &self.label_model(),
                    steps,
                    |(tag, t_s), x, p| each(tag, t_s, x, p),
                );
            }
        }
    }

    /// The turn rate for the CT models: the rate of the current turn since it began, as the
    /// gate measures it, while a turn holds; the configured rate otherwise.
    /// `stale`: no measured velocity ([`HybridTracker::velocity_stale`]), so no rate
    /// worth adapting to.
    fn turn_rate(&self, stale: bool, reading: &GateReading) -> f64 {
        let (lo, hi) = self.params.turn_rate_limits_deg_s;
        let default = self.params.imm.models.ct.omega_rad_s.abs();
        if !self.params.adapt_turn_rate || reading.tested_lateral() == Lateral::Straight || stale {
            return default;
        }
        self.gate
            .turn_rate_since_start_rad_s()
            .or(reading.turn_rate_rad_s)
            .map_or(default, |w| {
                w.abs()
                    .clamp(lo.to_radians(), hi.to_radians().max(lo.to_radians()))
            })
    }

    /// Switches filter when the gate says so, and sets the labels.
    fn decide(&mut self, t_s: f64) {
        let reading = *self.gate.reading();
        let trigger = matches!(self.branch, Branch::Cv { .. })
            && self.params.divergence_trigger > 0
            && self.cv_divergence_run >= self.params.divergence_trigger;
        // A steady climb or descent at constant ground velocity (CH) is constant velocity in
        // three dimensions: the CV Kalman filter models it exactly, so only a horizontal
        // manoeuvre (or a diverging CV filter) pays for the IMM. Terminal-area traffic climbs
        // and descends most of the time: on the LAX recording this keeps most updates cheap.
        let f = reading.flags;
        let horizontal = f.turning() || f.speed_changing();
        let stale = self.velocity_stale(t_s);
        let blind = self.params.imm_without_velocity && stale;
        let needs_imm = (reading.manoeuvre() && horizontal) || trigger || blind;
        // Without measured velocities the gate reads the filter's own velocity, whose
        // report-to-report scatter in a manoeuvre is large: it releases mid-turn. There the
        // IMM's residual-based mode probabilities are the better witness, so a manoeuvre the
        // IMM still believes in keeps it on (measured on paper 002 fed positions only: the
        // hybrid left the IMM a dozen times per turn, turn RMSE 49 m against the IMM's 23 m).
        let imm_manoeuvre = matches!(self.branch, Branch::Imm { .. })
            && stale
            && self.imm.most_probable() != ImmMode::Cv;
        if needs_imm || imm_manoeuvre {
            self.last_fire_t_s = t_s;
        }
        // The direction of a confirmed turn (the rate test holds on measured velocities, no
        // onset test does): the sign of its rate is then significant ([`Lateral`] of the
        // tests), and the opposite CT mode leaves the IMM's set once the dwell since it was
        // last named runs out. In a turn that CT mode's likelihood is negligible: paper
        // 002's turn RMSE moves by under a millimetre, paper 000's 4 g reversal improves
        // (its old side no longer mixes in), and a fleet replay runs 5 % fewer instructions
        // (`docs/speed.md`).
        let confirmed = f.turn && !f.turn_onset && !f.heading_change && !stale;
        let direction = match reading.tested_lateral() {
            Lateral::Left if confirmed => Some(TurnDirection::Left),
            Lateral::Right if confirmed => Some(TurnDirection::Right),
            _ => None,
        };
        if let Some(named) = gate_modes(&f, direction) {
            for (t, on) in self.named_t_s.iter_mut().zip(named) {
                if on {
                    *t = t_s;
                }
            }
        }
        match self.branch {
            Branch::Cv { x, p } if needs_imm => {
                let mut x9 = State9::zeros();
                x9.fixed_rows_mut::<6>(0).copy_from(&x);
                if let Some(a) = reading.along_track_rate_mps2() {
                    // Start the acceleration at the gate's along-track estimate.
                    let v = Vector3::new(x[3], x[4], 0.0);
                    if v.norm() > 1.0 {
                        x9.fixed_rows_mut::<3>(ACC).copy_from(&(v.normalize() * a));
                    }
                }
                let mut p9 = Matrix9::zeros();
                p9.fixed_view_mut::<6, 6>(0, 0).copy_from(&p);
                let a2 = self.params.init.init_accel_sigma_mps2.powi(2);
                for i in ACC..ACC + 3 {
                    p9[(i, i)] = a2;
                }
                let mu = self.entry_probabilities(&reading);
                self.imm.set_active(self.model_set(t_s, blind));
                self.imm.reset(&x9, &p9, mu.as_ref());
                self.branch = Branch::Imm {
                    by_divergence: !reading.manoeuvre(),
                };
                self.stats.to_imm += 1;
            }
            Branch::Imm { .. } if t_s - self.last_fire_t_s >= self.params.min_manoeuvre_dwell_s => {
                let (x, p) = self.imm.combined_leading::<6>();
                self.branch = Branch::Cv { x, p };
                self.steady_q.restart();
                // Not read again before the next switch's reset: 2.6 KB less per aircraft.
                self.imm.release();
                self.stats.to_cv += 1;
            }
            _ => {}
        }
        if let Branch::Imm { by_divergence } = self.branch {
            let before = *self.imm.active();
            self.imm
                .set_active(self.running_set(t_s, blind, direction.is_some(), &f));
            // The gate's label enters a running IMM as it opens one: at the combined
            // estimate, with the entry probability (otherwise it starts at probability 0 and
            // needs reports to overtake the manoeuvre in course: the approach's turn begun
            // as its deceleration ends, velocity RMSE 1.32 against 1.29 m/s).
            if let Some(target) = self.entry_mode(&reading) {
                let i = target.index();
                if !before[i] && self.imm.active()[i] {
                    self.imm.enter(target, self.params.entry_probability);
                }
            }
            let rate = self.turn_rate(stale, &reading);
            self.imm.set_turn_rate(rate);
            if reading.manoeuvre() {
                self.branch = Branch::Imm {
                    by_divergence: false,
                };
            }
            // Blind (no measured velocity), the IMM's own mode probabilities label: the gate
            // then reads the filter's velocity, which the IMM itself made.
            self.labels = match reading.label() {
                Some((mode, turn)) if !blind => Labels {
                    mode,
                    turn,
                    lateral: reading.lateral(),
                    speed: reading.speed(),
                    vertical: reading.vertical(),
                },
                _ if stale || by_divergence => {
                    let x = self.imm.combined_state();
                    labels_of_mode(self.imm.most_probable(), &x, &self.params.axes)
                }
                _ => Labels::CV,
            };
        } else {
            // In the CV filter: level and straight, or a steady climb/descent the gate saw.
            self.labels = match reading.label() {
                Some((mode, turn)) => Labels {
                    mode,
                    turn,
                    lateral: reading.lateral(),
                    speed: reading.speed(),
                    vertical: reading.vertical(),
                },
                None => Labels::CV,
            };
        }
    }

    fn info(&self) -> EstimateInfo {
        let (filter, mode_probabilities) = match self.branch {
            Branch::Cv { .. } => (CV_FILTER, [1.0, 0.0, 0.0, 0.0, 0.0]),
            Branch::Imm { .. } => (IMM_NAME, self.imm.flight_mode_probabilities()),
        };
        EstimateInfo {
            labels: self.labels,
            mode_probabilities,
            filter,
            diverging: self.diverging,
            divergence_events: self.divergence_events,
            outlier_positions: self.outliers.count(),
            nis: self.nis.stat(),
        }
    }

    /// The model of the current label, for prediction (paper 002 §1.3).
    fn label_model(&self) -> Model {
        let mode = match (self.labels.mode, self.labels.turn) {
            (FlightMode::Cv, _) => ImmMode::Cv,
            (FlightMode::Ca, _) => ImmMode::Ca,
            (FlightMode::Ct, Some(TurnDirection::Right)) => ImmMode::CtRight,
            (FlightMode::Ct, _) => ImmMode::CtLeft,
            (FlightMode::Ch, _) => ImmMode::Ch,
            (FlightMode::Chca, _) => ImmMode::Chca,
        };
        *self.imm.model(mode)
    }
}

impl Tracker for HybridTracker {
    /// A new track; the learned measurement noise is kept (it is the aircraft's).
    fn reset(&mut self) {
        let noise = self.noise;
        let outliers = self.outliers;
        let (tails, velocity_tails) = (self.tails, self.velocity_tails);
        let lag = super::lag::kept_over_restart(self.lag.take());
        *self = Self::new(*self.params);
        self.noise = noise;
        self.noise.forget_position();
        self.outliers = outliers;
        self.tails = tails;
        self.velocity_tails = velocity_tails;
        self.lag = lag;
    }

    fn outlier_positions(&self) -> u64 {
        self.outliers.count()
    }

    fn set_accuracy_declared(&mut self, position: bool, velocity: bool) {
        self.noise.accuracy_declared = position;
        self.noise.velocity_declared = velocity;
    }

    fn name(&self) -> &'static str {
        NAME
    }

    fn update(&mut self, m: &Measurement) -> Result<(), TrackError> {
        let track_t_s = self.init.track_t_s();
        if self.params.learn_velocity_lag {
            self.learn_lag(m);
        }
        match self.init.offer(m)? {
            Start::Waiting => Ok(()),
            Start::New(start) => {
                let (x, p) = &*start;
                self.start(m.t_s, x, p, m.velocity.as_ref());
                Ok(())
            }
            Start::Running => {
                // The report with the learned noise: the filter and the gate weigh it so.
                let up = local_up(&self.position_m());
                let m = &self.noise.prepare(m, &up);
                let Some(obs) = Observation::of(m.position.as_ref(), m.velocity.as_ref()) else {
                    return Ok(());
                };
                let dt_s = m.t_s - track_t_s.unwrap_or(m.t_s);
                // Current velocity reports in which the gate sees no horizontal manoeuvre
                // vouch for a straight flight: a position far off it may be set aside (a
                // report with a velocity never is).
                let vouched = matches!(obs, Observation::Position(_)) && {
                    let f = self.gate.reading().flags;
                    !(f.turning() || f.speed_changing() || self.velocity_stale(m.t_s))
                };
                if !self.filter_step(m.t_s, dt_s, &obs, vouched)? {
                    return Ok(());
                }
                if let Branch::Cv { x, .. } = &self.branch {
                    let vel = kalman::rows::<3, _>(x, 3);
                    self.noise
                        .learn_position_step(m, &vel, &up, &self.params.noise);
                }
                self.init.advance(m.t_s);
                self.feed_gate(m);
                self.decide(m.t_s);
                Ok(())
            }
        }
    }

    fn estimate(&self) -> Option<Estimate> {
        let t_s = self.init.track_t_s()?;
        let info = self.info();
        let est = match &self.branch {
            Branch::Cv { x, p } => estimate_of(t_s, x, p, &info),
            Branch::Imm { .. } => {
                let (x, p) = self.imm.combined_leading::<6>();
                estimate_of(t_s, &x, &p, &info)
            }
        };
        Some(self.noise.with_position_bias(est))
    }

    fn estimated_position(&self) -> Option<(f64, Vector3<f64>)> {
        let t_s = self.init.track_t_s()?;
        Some((t_s, self.position_m()))
    }

    fn has_track(&self) -> bool {
        self.init.track_t_s().is_some()
    }

    /// Extrapolates by the current label's model (paper 002 §1.3), its Q added; CT at the
    /// turn rate in use (the gate's when `adapt_turn_rate`).
    fn predict(&self, t_s: f64) -> Option<Estimate> {
        let info = self.info();
        let mut est = None;
        self.predicted(std::iter::once(((), t_s)), |(), t_s, x, p| {
            est = Some(self.noise.with_position_bias(estimate_of(t_s, x, p, &info)));
        });
        est
    }

    /// [`Tracker::predict`]'s predictions, position and σ alone: no estimate formed, and
    /// while the IMM runs its combined estimate formed once for every horizon.
    fn predict_positions(
        &self,
        base_t_s: f64,
        horizons_s: &[f64],
        out: &mut Vec<PositionPrediction>,
    ) {
        // The CV filter's predictions: only the entries read
        // (`MotionModel::predict_horizontal`, the same bits as `predicted`'s).
        if let (Branch::Cv { x, p }, Some(track_t_s)) = (&self.branch, self.init.track_t_s()) {
            let bias = |var_e, var_n| self.noise.with_position_bias_var(var_e, var_n);
            super::predict_horizontal_positions(
                &self.steady_cv(),
                track_t_s,
                x,
                p,
                base_t_s,
                horizons_s,
                bias,
                out,
            );
            return;
        }
        let steps = horizons_s
            .iter()
            .map(|&ahead_s| (ahead_s, base_t_s + ahead_s));
        self.predicted(steps, |ahead_s, t_s, x, p| {
            let (var_e, var_n) = self.noise.with_position_bias_var(p[(0, 0)], p[(1, 1)]);
            out.push(PositionPrediction::of_state(ahead_s, t_s, x, var_e, var_n));
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::noise::EARTH_RADIUS_M;

    #[test]
    fn local_axes_take_out_the_tilt_of_a_distant_level_flight() {
        // On the sphere, 300 km east of the origin (angle θ = d/R), level flight due east at
        // 230 m/s has frame components v(cosθ, 0, −sinθ): locally it is (230, 0, 0).
        let theta = 300_000.0 / EARTH_RADIUS_M;
        let pos = Vector3::new(
            EARTH_RADIUS_M * theta.sin(),
            0.0,
            EARTH_RADIUS_M * theta.cos() - EARTH_RADIUS_M,
        );
        let v = Observed {
            value: 230.0 * Vector3::new(theta.cos(), 0.0, -theta.sin()),
            cov: Matrix3::identity(),
            grid: None,
        };
        let local = to_local_axes(&pos, &v);
        assert!(
            (local.value - Vector3::new(230.0, 0.0, 0.0)).norm() < 1e-9,
            "{}",
            local.value
        );
        // Rotation keeps the covariance's trace.
        assert!((local.cov.trace() - 3.0).abs() < 1e-12);
        // At the origin nothing changes.
        let same = to_local_axes(&Vector3::zeros(), &v);
        assert_eq!(same.value, v.value);
    }
    use crate::track::gate::{KNOT_MPS, VRATE_LSB_MPS};
    use crate::track::imm::{ImmTracker, ImmTrackerParams};
    use crate::track::{SpeedTrend, VerticalTrend, UNMEASURED_VARIANCE};
    use nalgebra::{Matrix3, Vector3};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// One leg of a synthetic flight: constant turn rate (rad/s, + = left), along-track
    /// acceleration (m/s²) and vertical rate (m/s) until `until_s`.
    #[derive(Clone, Copy, Debug)]
    struct Leg {
        until_s: f64,
        turn_rad_s: f64,
        accel_mps2: f64,
        vrate_mps: f64,
    }

    fn leg(until_s: f64, turn_deg_s: f64, accel_mps2: f64, vrate_mps: f64) -> Leg {
        Leg {
            until_s,
            turn_rad_s: turn_deg_s.to_radians(),
            accel_mps2,
            vrate_mps,
        }
    }

    impl Leg {
        /// The truth label of this leg.
        fn labels(&self) -> (FlightMode, Option<TurnDirection>) {
            if self.turn_rad_s > 0.0 {
                (FlightMode::Ct, Some(TurnDirection::Left))
            } else if self.turn_rad_s < 0.0 {
                (FlightMode::Ct, Some(TurnDirection::Right))
            } else {
                match (self.vrate_mps != 0.0, self.accel_mps2 != 0.0) {
                    (true, true) => (FlightMode::Chca, None),
                    (true, false) => (FlightMode::Ch, None),
                    (false, true) => (FlightMode::Ca, None),
                    (false, false) => (FlightMode::Cv, None),
                }
            }
        }
    }

    #[derive(Clone, Copy, Debug)]
    struct Truth {
        t_s: f64,
        pos: Vector3<f64>,
        vel: Vector3<f64>,
        leg: Leg,
    }

    /// Flies the legs from `pos` at `speed` along the math angle `angle_rad`, integrating
    /// with 5 ms midpoint steps, and samples the truth at `times`.
    fn fly(
        pos: Vector3<f64>,
        angle_rad: f64,
        speed: f64,
        legs: &[Leg],
        times: &[f64],
    ) -> Vec<Truth> {
        let (mut p, mut a, mut s, mut t) = (pos, angle_rad, speed, 0.0);
        let leg_at = |t: f64| {
            *legs
                .iter()
                .find(|l| t < l.until_s)
                .unwrap_or(legs.last().unwrap())
        };
        let vel = |a: f64, s: f64, vu: f64| Vector3::new(s * a.cos(), s * a.sin(), vu);
        let mut out = Vec::with_capacity(times.len());
        for &target in times {
            while t < target {
                let l = leg_at(t);
                let h = (target - t).min(0.005).min((l.until_s - t).max(1e-9));
                let (am, sm) = (a + 0.5 * h * l.turn_rad_s, s + 0.5 * h * l.accel_mps2);
                p += vel(am, sm, l.vrate_mps) * h;
                a += h * l.turn_rad_s;
                s += h * l.accel_mps2;
                t += h;
            }
            let l = leg_at(t);
            // Flown over a sphere, as the gate reads it (`noise::local_up`): the leg's
            // level is level to the local vertical, which tilts by d/R from the frame's
            // (at 40 km, 200 m/s along the tangent plane is a 1.3 m/s climb).
            let r = EARTH_RADIUS_M;
            let v = vel(a, s, l.vrate_mps);
            out.push(Truth {
                t_s: target,
                pos: Vector3::new(p.x, p.y, p.z - (p.x * p.x + p.y * p.y) / (2.0 * r)),
                vel: Vector3::new(v.x, v.y, v.z - (p.x * v.x + p.y * v.y) / r),
                leg: l,
            });
        }
        out
    }

    /// Report times: every 0.5 s with ±0.15 s uniform jitter.
    fn report_times(rng: &mut StdRng, end_s: f64) -> Vec<f64> {
        let mut t = 0.0;
        let mut out = Vec::new();
        while t <= end_s {
            out.push(t);
            t += 0.5 + rng.gen_range(-0.15..0.15);
        }
        out
    }

    const POS_SIGMA: [f64; 3] = [10.0, 10.0, 15.0];
    const VEL_SIGMA_MPS: f64 = 0.5;

    /// How the reports carry the data.
    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Feed {
        /// Position and velocity in every report.
        Joint,
        /// Alternately a position and a velocity report (as ADS-B sends them).
        Alternating,
        /// Positions only.
        PositionOnly,
    }

    /// ADS-B-like reports of the truth: position with σ = (10, 10, 15) m; velocity with
    /// σ = 0.5 m/s per component, quantised to 1 kt and 64 ft/min; the covariances carry
    /// the noise plus the quantisation variance.
    fn reports(truth: &[Truth], feed: Feed, rng: &mut StdRng) -> Vec<Measurement> {
        let n = Normal::new(0.0, 1.0).unwrap();
        let q = |x: f64, lsb: f64| (x / lsb).round() * lsb;
        let pos_cov = Matrix3::from_diagonal(&Vector3::from(POS_SIGMA.map(|s| s * s)));
        let vh = VEL_SIGMA_MPS.powi(2) + KNOT_MPS.powi(2) / 12.0;
        let vv = VEL_SIGMA_MPS.powi(2) + VRATE_LSB_MPS.powi(2) / 12.0;
        let vel_cov = Matrix3::from_diagonal(&Vector3::new(vh, vh, vv));
        truth
            .iter()
            .enumerate()
            .map(|(k, tr)| {
                let mut noise = || n.sample(rng);
                let position = Observed {
                    value: tr.pos + Vector3::from_fn(|i, _| POS_SIGMA[i] * noise()),
                    cov: pos_cov,
                    grid: None,
                };
                let mut noise = || n.sample(rng) * VEL_SIGMA_MPS;
                let velocity = Observed {
                    value: Vector3::new(
                        q(tr.vel.x + noise(), KNOT_MPS),
                        q(tr.vel.y + noise(), KNOT_MPS),
                        q(tr.vel.z + noise(), VRATE_LSB_MPS),
                    ),
                    cov: vel_cov,
                    grid: None,
                };
                let (position, velocity) = match feed {
                    Feed::Joint => (Some(position), Some(velocity)),
                    Feed::Alternating if k % 2 == 0 => (Some(position), None),
                    Feed::Alternating => (None, Some(velocity)),
                    Feed::PositionOnly => (Some(position), None),
                };
                Measurement {
                    t_s: tr.t_s,
                    position,
                    velocity,
                }
            })
            .collect()
    }

    /// Paper 002 §2: 1000 s, x0 = [1000 m, 50 m/s, 1000 m, 50 m/s], 3°/s, left turn
    /// 200–400 s, right turn 600–700 s; level at 3000 m.
    fn paper_legs() -> Vec<Leg> {
        vec![
            leg(200.0, 0.0, 0.0, 0.0),
            leg(400.0, 3.0, 0.0, 0.0),
            leg(600.0, 0.0, 0.0, 0.0),
            leg(700.0, -3.0, 0.0, 0.0),
            leg(1000.0 + 1.0, 0.0, 0.0, 0.0),
        ]
    }

    fn paper_truth(rng: &mut StdRng) -> Vec<Truth> {
        let times = report_times(rng, 1000.0);
        fly(
            Vector3::new(1000.0, 1000.0, 3000.0),
            std::f64::consts::FRAC_PI_4,
            50.0 * 2f64.sqrt(),
            &paper_legs(),
            &times,
        )
    }

    /// A gate that never fires: the hybrid is then the CV Kalman filter alone (with or
    /// without paper 000's suppressor).
    fn cv_only(suppress: bool) -> HybridParams {
        let gate = GateParams {
            speed_change_mps: None,
            accel_change_mps2: None,
            heading_change_deg: None,
            pitch_change_deg: None,
            turn_rate_deg_s: None,
            along_track_accel_mps2: None,
            vertical_rate_mps: None,
            ..GateParams::default()
        };
        HybridParams {
            gate,
            divergence_trigger: 0,
            imm_without_velocity: false,
            divergence: DivergenceParams {
                suppress,
                ..DivergenceParams::default()
            },
            ..HybridParams::default()
        }
    }

    /// One tracker's run: the estimate after each report, and the hybrid's switch times.
    struct Run {
        estimates: Vec<Estimate>,
        /// Report indices at which the hybrid switched CV → IMM.
        to_imm: Vec<usize>,
    }

    fn run_hybrid(params: HybridParams, reports: &[Measurement]) -> Run {
        let mut tracker = HybridTracker::new(params);
        let mut estimates = Vec::with_capacity(reports.len());
        let mut to_imm = Vec::new();
        for (k, m) in reports.iter().enumerate() {
            let before = tracker.stats().to_imm;
            tracker.update(m).unwrap();
            if tracker.stats().to_imm > before {
                to_imm.push(k);
            }
            estimates.push(tracker.estimate().unwrap());
        }
        Run { estimates, to_imm }
    }

    /// The label-only tests (the first-report turn test, the turn's end test) label and
    /// nothing else: with each and without it the hybrid's every estimate is the same to the
    /// bit (the IMM opens, enters, takes its turn rate and closes on the other tests alone),
    /// and only labels differ, on some reports.
    #[test]
    fn the_label_only_tests_move_no_estimate() {
        let switches: [fn(&mut GateParams); 2] = [
            |g| g.first_report_turn_sigmas = None,
            |g| g.turn_end_sigmas = None,
        ];
        for (test, switch_off) in switches.iter().enumerate() {
            let mut relabelled = 0;
            for seed in 0..4 {
                let mut rng = StdRng::seed_from_u64(300 + seed);
                let truth = paper_truth(&mut rng);
                let feed = reports(&truth, Feed::Joint, &mut rng);
                let with = run_hybrid(HybridParams::default(), &feed);
                let mut off = HybridParams::default();
                switch_off(&mut off.gate);
                let without = run_hybrid(off, &feed);
                assert_eq!(with.to_imm, without.to_imm, "test {test}, seed {seed}");
                for (a, b) in with.estimates.iter().zip(&without.estimates) {
                    assert_eq!(
                        (a.pos_m, a.vel_mps, a.pos_cov_m2, a.vel_cov_m2ps2),
                        (b.pos_m, b.vel_mps, b.pos_cov_m2, b.vel_cov_m2ps2),
                        "test {test}, seed {seed}, t {}",
                        a.t_s
                    );
                    assert_eq!(a.mode_probabilities, b.mode_probabilities);
                    relabelled += usize::from(a.mode != b.mode);
                }
            }
            // Their labels come a report or more early at turn onsets and ends, and now
            // and then on a straight report.
            assert!(relabelled > 0, "test {test}");
        }
    }

    fn run_imm(reports: &[Measurement]) -> Run {
        let mut tracker = ImmTracker::new(ImmTrackerParams::default());
        let estimates = reports
            .iter()
            .map(|m| {
                tracker.update(m).unwrap();
                tracker.estimate().unwrap()
            })
            .collect();
        Run {
            estimates,
            to_imm: Vec::new(),
        }
    }

    /// Squared horizontal errors by segment class: [straight, turn] × (sum, count).
    #[derive(Default, Clone, Copy, Debug)]
    struct Errors {
        pos: [(f64, usize); 2],
        vel: [(f64, usize); 2],
    }

    const STRAIGHT: usize = 0;
    const TURN: usize = 1;

    impl Errors {
        /// Adds a run, skipping the first `warmup_s` of convergence.
        fn add(&mut self, truth: &[Truth], run: &Run, warmup_s: f64) {
            for (tr, e) in truth.iter().zip(&run.estimates) {
                if tr.t_s < warmup_s {
                    continue;
                }
                let class = usize::from(tr.leg.turn_rad_s != 0.0);
                let dp = (e.pos_m - tr.pos).fixed_rows::<2>(0).norm_squared();
                let dv = (e.vel_mps - tr.vel).fixed_rows::<2>(0).norm_squared();
                self.pos[class].0 += dp;
                self.pos[class].1 += 1;
                self.vel[class].0 += dv;
                self.vel[class].1 += 1;
            }
        }
        fn pos(&self, class: usize) -> f64 {
            (self.pos[class].0 / self.pos[class].1 as f64).sqrt()
        }
        fn vel(&self, class: usize) -> f64 {
            (self.vel[class].0 / self.vel[class].1 as f64).sqrt()
        }
        fn line(&self) -> String {
            format!(
                "{:.3} / {:.3} m, {:.3} / {:.3} m/s",
                self.pos(STRAIGHT),
                self.pos(TURN),
                self.vel(STRAIGHT),
                self.vel(TURN)
            )
        }
    }

    /// The χ²(k) quantile at the standard-normal quantile z, by Wilson–Hilferty:
    /// k (1 − 2/(9k) + z √(2/(9k)))³ (within 0.1 % of the exact value for k ≥ 9).
    fn chi2_quantile(k: f64, z: f64) -> f64 {
        let c = 2.0 / (9.0 * k);
        k * (1.0 - c + z * c.sqrt()).powi(3)
    }

    #[test]
    fn chi2_quantiles_match_the_tables() {
        // Tabulated: χ²(24) 2.5 % = 12.401, 97.5 % = 39.364; χ²(60) 97.5 % = 83.298.
        assert!((chi2_quantile(24.0, -1.959_964) - 12.401).abs() < 0.02);
        assert!((chi2_quantile(24.0, 1.959_964) - 39.364).abs() < 0.02);
        assert!((chi2_quantile(60.0, 1.959_964) - 83.298).abs() < 0.05);
    }

    /// Position NEES e' P⁻¹ e (3 dof).
    fn nees(e: &Estimate, truth: &Truth) -> f64 {
        let d = e.pos_m - truth.pos;
        e.pos_cov_m2
            .cholesky()
            .map_or(f64::INFINITY, |c| d.dot(&c.solve(&d)))
    }

    /// Delay from `onset_s` to the first estimate labelled CT in `direction`.
    fn detection_delay(truth: &[Truth], run: &Run, onset_s: f64, direction: TurnDirection) -> f64 {
        truth
            .iter()
            .zip(&run.estimates)
            .find(|(tr, e)| {
                tr.t_s >= onset_s && e.mode == FlightMode::Ct && e.turn == Some(direction)
            })
            .map_or(f64::INFINITY, |(tr, _)| tr.t_s - onset_s)
    }

    /// Everything measured on paper 002's scenario over Monte Carlo runs.
    #[derive(Default)]
    struct PaperResult {
        hybrid: Errors,
        imm: Errors,
        cv: Errors,
        cv_plain: Errors,
        delays: Vec<f64>,
        imm_delays: Vec<f64>,
        false_switches: usize,
        straight_updates: usize,
        nees_sum: f64,
        nees_n: usize,
        nees_by_time: Vec<f64>,
        hybrid_label_errors_in_turns: usize,
        imm_label_errors_in_turns: usize,
        reports_in_turns: usize,
    }

    impl PaperResult {
        fn mean_delay(&self) -> f64 {
            self.delays.iter().sum::<f64>() / self.delays.len() as f64
        }
        fn false_per_100(&self) -> f64 {
            100.0 * self.false_switches as f64 / self.straight_updates as f64
        }
        fn report(&self, name: &str, runs: u64) {
            let imm_delay = self.imm_delays.iter().sum::<f64>() / self.imm_delays.len() as f64;
            eprintln!(
                "paper 002 [{name}, {runs} runs] RMSE straight / turn: hybrid {}; IMM {}; \
                 CV+suppressor {}; CV plain {}",
                self.hybrid.line(),
                self.imm.line(),
                self.cv.line(),
                self.cv_plain.line()
            );
            eprintln!(
                "paper 002 [{name}] turn detection delay hybrid mean {:.2} s (max {:.2}), \
                 IMM mean {imm_delay:.2} s; false switches {} in {} straight updates \
                 ({:.3}/100); wrong labels inside turns (after 2 s) hybrid {} IMM {} of {}",
                self.mean_delay(),
                self.delays.iter().cloned().fold(0.0, f64::max),
                self.false_switches,
                self.straight_updates,
                self.false_per_100(),
                self.hybrid_label_errors_in_turns,
                self.imm_label_errors_in_turns,
                self.reports_in_turns
            );
        }
    }

    fn paper_monte_carlo(feed: Feed, runs: u64, params: HybridParams) -> PaperResult {
        let mut r = PaperResult::default();
        for seed in 0..runs {
            let mut rng = StdRng::seed_from_u64(100 + seed);
            let truth = paper_truth(&mut rng);
            let reps = reports(&truth, feed, &mut rng);
            let h = run_hybrid(params, &reps);
            let i = run_imm(&reps);
            r.hybrid.add(&truth, &h, 10.0);
            r.imm.add(&truth, &i, 10.0);
            r.cv.add(&truth, &run_hybrid(cv_only(true), &reps), 10.0);
            r.cv_plain
                .add(&truth, &run_hybrid(cv_only(false), &reps), 10.0);
            for (onset, dir) in [(200.0, TurnDirection::Left), (600.0, TurnDirection::Right)] {
                r.delays.push(detection_delay(&truth, &h, onset, dir));
                r.imm_delays.push(detection_delay(&truth, &i, onset, dir));
            }
            r.false_switches += h
                .to_imm
                .iter()
                .filter(|&&k| truth[k].leg.turn_rad_s == 0.0)
                .count();
            r.straight_updates += truth.iter().filter(|t| t.leg.turn_rad_s == 0.0).count();
            r.nees_by_time
                .resize(truth.len().max(r.nees_by_time.len()), 0.0);
            for (k, (tr, e)) in truth.iter().zip(&h.estimates).enumerate() {
                if tr.t_s >= 10.0 {
                    let v = nees(e, tr);
                    r.nees_sum += v;
                    r.nees_n += 1;
                    r.nees_by_time[k] += v / runs as f64;
                }
            }
            // Paper 002 Fig. 8's "glitches": reports well inside a turn (from 2 s after its
            // onset) labelled other than that turn.
            for ((tr, he), ie) in truth.iter().zip(&h.estimates).zip(&i.estimates) {
                if (tr.t_s > 202.0 && tr.t_s < 400.0) || (tr.t_s > 602.0 && tr.t_s < 700.0) {
                    let want = tr.leg.labels();
                    r.reports_in_turns += 1;
                    r.hybrid_label_errors_in_turns += usize::from((he.mode, he.turn) != want);
                    r.imm_label_errors_in_turns += usize::from((ie.mode, ie.turn) != want);
                }
            }
        }
        r
    }

    /// Monte Carlo runs: few in debug builds (the IMM is ~50x slower unoptimised), more
    /// with `cargo test --release`.
    fn runs(debug: u64, release: u64) -> u64 {
        if cfg!(debug_assertions) {
            debug
        } else {
            release
        }
    }

    #[test]
    fn paper_002_scenario() {
        let runs = runs(3, 20);
        let r = paper_monte_carlo(Feed::Joint, runs, HybridParams::default());
        r.report("joint reports", runs);
        // NEES: at each time the run-average of a consistent filter's position NEES is
        // χ²(3·runs)/runs; its two-sided 95 % band.
        let k = 3.0 * runs as f64;
        let (lo, hi) = (
            chi2_quantile(k, -1.959_964) / runs as f64,
            chi2_quantile(k, 1.959_964) / runs as f64,
        );
        let times = &r.nees_by_time[20..];
        let inside = times.iter().filter(|v| (lo..=hi).contains(*v)).count() as f64;
        let frac_inside = inside / times.len() as f64;
        let mean_nees = r.nees_sum / r.nees_n as f64;
        eprintln!(
            "paper 002 [joint] hybrid position NEES: mean {mean_nees:.3} (3 expected); the \
             run-average lies in its 95 % band [{lo:.2}, {hi:.2}] at {:.1} % of the times",
            100.0 * frac_inside
        );
        let (h, i) = (&r.hybrid, &r.imm);
        // Straight legs: no worse than the CV filter (with or without paper 000), and as
        // good as the IMM: with ADS-B velocity in every report all three sit at the same
        // measurement-limited floor (measured: equal to 0.1 %), so "<" is asserted within
        // that floor. The hybrid learns the measurement noise (`noise`); here the noise is
        // exactly what the reports declare, so learning can only scatter about it: 0.3 %
        // (2.223 m against the IMM's 2.216 m on 20 runs), the price of the gains on
        // undeclared and correlated noise (docs/evaluation.md).
        assert!(h.pos(STRAIGHT) <= r.cv.pos(STRAIGHT));
        assert!(h.pos(STRAIGHT) <= r.cv_plain.pos(STRAIGHT));
        assert!(h.pos(STRAIGHT) <= 1.006 * i.pos(STRAIGHT));
        // Turns: within 5 % of the IMM, better than the CV filter.
        assert!(h.pos(TURN) <= 1.05 * i.pos(TURN));
        assert!(h.pos(TURN) < r.cv.pos(TURN) && h.pos(TURN) < r.cv_plain.pos(TURN));
        assert!(h.vel(TURN) < r.cv_plain.vel(TURN));
        assert!(r.mean_delay() <= 2.0, "detection delay {}", r.mean_delay());
        assert!(r.false_per_100() <= 1.0);
        assert!((lo..=hi).contains(&mean_nees), "mean NEES {mean_nees}");
        assert!(frac_inside >= 0.85, "{frac_inside}");
        // No glitches: the hybrid keeps the turn label inside the turns.
        assert!(r.hybrid_label_errors_in_turns <= r.reports_in_turns / 100);
    }

    #[test]
    fn paper_002_scenario_as_adsb_sends_it_and_with_positions_only() {
        // Alternate position and velocity reports (ADS-B's separate messages).
        let runs = runs(2, 10);
        let r = paper_monte_carlo(Feed::Alternating, runs, HybridParams::default());
        r.report("alternating position / velocity reports", runs);
        // Straight legs: the same measurement-limited floor as the CV filter and the IMM,
        // within the scatter of the learned noise about the declared one (as in the joint
        // feed above): 0.2 % with the hybrid's window of 30 reports against the IMM's 100
        // (3.181 vs 3.174 m on 10 runs; under 0.2 % when both were 100).
        assert!(r.hybrid.pos(STRAIGHT) <= 1.004 * r.cv_plain.pos(STRAIGHT));
        assert!(r.hybrid.pos(STRAIGHT) <= 1.004 * r.imm.pos(STRAIGHT));
        assert!(r.hybrid.pos(TURN) <= 1.05 * r.imm.pos(TURN));
        assert!(r.hybrid.pos(TURN) < r.cv_plain.pos(TURN));
        assert!(r.mean_delay() <= 2.0 && r.false_per_100() <= 1.0);
        // Positions only: the hybrid runs the IMM (`imm_without_velocity`), so it is the IMM.
        let r = paper_monte_carlo(Feed::PositionOnly, runs, HybridParams::default());
        r.report("positions only", runs);
        for class in [STRAIGHT, TURN] {
            assert!((r.hybrid.pos(class) - r.imm.pos(class)).abs() <= 0.005 * r.imm.pos(class));
        }
        assert!(r.hybrid.pos(TURN) < 0.5 * r.cv_plain.pos(TURN));
        // Were the gate to decide on the filter's own velocity (the IMM kept on while its
        // mode probabilities say manoeuvre, its CT models at the configured rate): better
        // than the IMM on straight legs (no IMM jitter: 5.35 vs 5.49 m), but behind it in
        // turns (7.0 vs 6.0 m: the turn is seen late, the IMM handed a lagging state). The
        // IMM is the better whole (and on the bench: 22.4 vs 23.9 m over the flight).
        let gated = HybridParams {
            imm_without_velocity: false,
            ..HybridParams::default()
        };
        let r = paper_monte_carlo(Feed::PositionOnly, runs, gated);
        r.report("positions only, gate deciding", runs);
        assert!(r.hybrid.pos(STRAIGHT) < r.imm.pos(STRAIGHT));
        assert!(r.hybrid.pos(STRAIGHT) < r.cv_plain.pos(STRAIGHT));
        assert!(r.hybrid.pos(TURN) < 0.5 * r.cv_plain.pos(TURN));
        assert!(r.hybrid.pos(TURN) < 1.3 * r.imm.pos(TURN));
        assert!(r.hybrid_label_errors_in_turns <= r.reports_in_turns / 20);
        assert!(r.mean_delay() <= 8.0 && r.false_per_100() <= 1.0);
    }

    #[test]
    fn switches_carry_state_and_covariance_without_a_jump() {
        let mut rng = StdRng::seed_from_u64(7);
        let truth = paper_truth(&mut rng);
        let reps = reports(&truth, Feed::Joint, &mut rng);
        let mut tracker = HybridTracker::default();
        let (mut into_imm, mut out_of_imm) = (0, 0);
        for m in &reps {
            let before = tracker.clone();
            tracker.update(m).unwrap();
            if tracker.in_imm() == before.in_imm() || before.estimate().is_none() {
                continue;
            }
            // The same report through the same tracker with the switch disabled.
            let mut held = before.clone();
            if before.in_imm() {
                std::sync::Arc::make_mut(&mut held.params).min_manoeuvre_dwell_s = f64::INFINITY;
                out_of_imm += 1;
            } else {
                held.gate = Gate::new(cv_only(true).gate);
                std::sync::Arc::make_mut(&mut held.params).divergence_trigger = 0;
                into_imm += 1;
            }
            held.update(m).unwrap();
            assert_eq!(held.in_imm(), before.in_imm());
            let (a, b) = (tracker.estimate().unwrap(), held.estimate().unwrap());
            assert!(
                (a.pos_m - b.pos_m).norm() < 1e-9,
                "{} vs {}",
                a.pos_m,
                b.pos_m
            );
            assert!((a.vel_mps - b.vel_mps).norm() < 1e-9);
            assert!((a.pos_cov_m2 - b.pos_cov_m2).norm() < 1e-9 * b.pos_cov_m2.norm());
            assert!((a.vel_cov_m2ps2 - b.vel_cov_m2ps2).norm() < 1e-9 * b.vel_cov_m2ps2.norm());
            assert_ne!(a.filter, b.filter);
        }
        // Both turns were entered and left.
        assert!(into_imm >= 2 && out_of_imm >= 2, "{into_imm} {out_of_imm}");
    }

    /// In paper 002's level turns the IMM runs CV, CA and the CT mode of the turn's
    /// direction (both CT modes until the onset tests have been quiet for the dwell: the
    /// direction may be misread at an onset; CA until its probability falls under
    /// [`CA_PRUNE_PROBABILITY`]), and every mode with `variable_structure` off; the
    /// estimates differ only by what the dropped modes would have mixed in.
    #[test]
    fn a_turn_runs_the_turn_modes_alone() {
        let mut rng = StdRng::seed_from_u64(7);
        let truth = paper_truth(&mut rng);
        let reps = reports(&truth, Feed::Joint, &mut rng);
        let dwell_s = HybridParams::default().min_manoeuvre_dwell_s;
        let mut narrowed = HybridTracker::default();
        let mut full = HybridTracker::new(HybridParams {
            variable_structure: false,
            ..HybridParams::default()
        });
        let (mut both, mut one_side, mut ca_pruned, mut worst_m) = (0, [0; 2], 0, 0.0f64);
        let mut onset_t_s = f64::NEG_INFINITY;
        for m in &reps {
            narrowed.update(m).unwrap();
            full.update(m).unwrap();
            if full.in_imm() {
                assert_eq!(full.imm().active(), &[true; N_MODES]);
            }
            let reading = *narrowed.gate.reading();
            let f = reading.flags;
            if f.turn_onset || f.heading_change {
                onset_t_s = m.t_s;
            }
            if narrowed.in_imm() && (f.turn || f.turn_onset) && !f.vertical {
                let active = *narrowed.imm().active();
                let expected = if m.t_s - onset_t_s <= dwell_s {
                    both += 1;
                    // CA may already be pruned by its probability where the turn is
                    // confirmed on this report (`running_set`), dwell or not.
                    let ca = active[ImmMode::Ca.index()];
                    [true, ca, true, true, false, false]
                } else {
                    let left = reading.turn_rate_rad_s.unwrap() > 0.0;
                    one_side[usize::from(left)] += 1;
                    // CA too, until its probability falls under the pruning threshold.
                    let ca = active[ImmMode::Ca.index()];
                    ca_pruned += usize::from(!ca);
                    [true, ca, left, !left, false, false]
                };
                assert_eq!(active, expected, "t {}", m.t_s);
                let (a, b) = (narrowed.estimate().unwrap(), full.estimate().unwrap());
                worst_m = worst_m.max((a.pos_m - b.pos_m).norm());
            }
        }
        // Most of each turn runs one CT mode, turns both ways, and most of that without CA.
        assert!(
            both >= 5 && one_side.iter().all(|&n| n > 100),
            "{both} {one_side:?}"
        );
        assert!(
            2 * ca_pruned > one_side[0] + one_side[1],
            "{ca_pruned} {one_side:?}"
        );
        // The turn modes dominate either way: a few cm apart at most on this run.
        assert!(worst_m < 0.5, "{worst_m} m");
    }

    /// The gate's modes: CV always; a turn names CA and the CT of its direction, or both CT
    /// modes when the direction is not given; CHCA only with a horizontal and a vertical test.
    #[test]
    fn gate_modes_name_the_turn_direction() {
        let turn = GateFlags {
            turn: true,
            ..GateFlags::default()
        };
        assert_eq!(gate_modes(&GateFlags::default(), None), None);
        assert_eq!(
            gate_modes(&turn, None),
            Some([true, true, true, true, false, false])
        );
        assert_eq!(
            gate_modes(&turn, Some(TurnDirection::Left)),
            Some([true, true, true, false, false, false])
        );
        assert_eq!(
            gate_modes(&turn, Some(TurnDirection::Right)),
            Some([true, true, false, true, false, false])
        );
        let climbing_turn = GateFlags {
            vertical: true,
            ..turn
        };
        assert_eq!(
            gate_modes(&climbing_turn, Some(TurnDirection::Right)),
            Some([true, true, false, true, true, true])
        );
        let climb = GateFlags {
            vertical: true,
            ..GateFlags::default()
        };
        assert_eq!(
            gate_modes(&climb, Some(TurnDirection::Left)),
            Some([true, false, false, false, true, false])
        );
    }

    /// Horizons the daemon publishes, one in the past (refused) and one non-finite.
    const HORIZONS_S: [f64; 6] = [0.0, 5.0, 10.0, 30.0, -3.0, f64::NAN];

    /// The published predictions ([`Tracker::predict_positions`]) are those of a whole
    /// estimate per horizon, and the trail's position ([`Tracker::estimated_position`])
    /// the estimate's, bit for bit, in both branches, with and without the declared
    /// position bias, on a departure (accelerations, a climb, a turn) fed as ADS-B sends it.
    #[test]
    fn published_predictions_are_the_estimates_predictions() {
        let mut rng = StdRng::seed_from_u64(11);
        let truth = departure_truth(&mut rng);
        let reps = reports(&truth, Feed::Alternating, &mut rng);
        for declared in [false, true] {
            let mut tracker = HybridTracker::default();
            tracker.set_accuracy_declared(declared, true);
            let (mut in_imm, mut in_cv, mut biased) = (0, 0, 0);
            for m in &reps {
                tracker.update(m).unwrap();
                match crate::track::assert_reads_match_the_estimate(&tracker, &HORIZONS_S) {
                    0 => continue,
                    n => assert_eq!(n, 4, "t {}", m.t_s),
                }
                if tracker.in_imm() {
                    in_imm += 1;
                } else {
                    in_cv += 1;
                }
                if tracker.noise.position_bias_var() > 0.0 {
                    biased += 1;
                }
            }
            assert!(
                in_imm > 100 && in_cv > 100,
                "{in_imm} in the IMM, {in_cv} in CV"
            );
            assert_eq!(
                biased > 0,
                declared,
                "{biased} predictions with a position bias"
            );
        }
    }

    #[test]
    fn no_chatter_on_noisy_straight_flight() {
        let mut rng = StdRng::seed_from_u64(11);
        let (mut switches, mut label_changes, mut updates) = (0, 0, 0);
        for (speed, feed) in [
            (70.0, Feed::Joint),
            (130.0, Feed::Alternating),
            (230.0, Feed::Joint),
            (230.0, Feed::Alternating),
            (100.0, Feed::PositionOnly),
        ] {
            let times = report_times(&mut rng, 600.0);
            let angle = rng.gen_range(0.0..std::f64::consts::TAU);
            let legs = [leg(601.0, 0.0, 0.0, 0.0)];
            let truth = fly(Vector3::new(0.0, 0.0, 9000.0), angle, speed, &legs, &times);
            let reps = reports(&truth, feed, &mut rng);
            let run = run_hybrid(HybridParams::default(), &reps);
            // Count from 10 s on (initiation).
            let first = truth.iter().position(|t| t.t_s >= 10.0).unwrap_or(0);
            switches += run.to_imm.iter().filter(|&&k| k >= first).count();
            label_changes += run.estimates[first..]
                .windows(2)
                .filter(|w| w[0].mode != w[1].mode)
                .count();
            updates += reps.len() - first;
        }
        eprintln!(
            "straight flight: {switches} switches to the IMM and {label_changes} label changes \
             in {updates} updates"
        );
        assert!(100 * switches <= updates, "{switches} in {updates}");
        assert!(100 * label_changes <= 2 * updates);
    }

    /// A departure: level acceleration, climb, climbing acceleration, a right turn at 2°/s
    /// (not the CT models' 3°/s).
    fn departure_legs() -> Vec<Leg> {
        vec![
            leg(60.0, 0.0, 0.0, 0.0),
            leg(120.0, 0.0, 1.2, 0.0),
            leg(210.0, 0.0, 0.0, 8.0),
            leg(270.0, 0.0, 0.8, 8.0),
            leg(300.0, 0.0, 0.0, 0.0),
            leg(360.0, -2.0, 0.0, 0.0),
            leg(421.0, 0.0, 0.0, 0.0),
        ]
    }

    /// The departure flown from 500 m at 80 m/s over 420 s of ADS-B report times.
    fn departure_truth(rng: &mut StdRng) -> Vec<Truth> {
        let times = report_times(rng, 420.0);
        fly(
            Vector3::new(0.0, 0.0, 500.0),
            0.3,
            80.0,
            &departure_legs(),
            &times,
        )
    }

    /// Fractions of reports (from 10 s on) with the right label and the right movement axes.
    fn departure_accuracy(params: HybridParams, runs: u64) -> (f64, f64) {
        let (mut labels_ok, mut axes_ok, mut n) = (0, 0, 0);
        for seed in 0..runs {
            let mut rng = StdRng::seed_from_u64(300 + seed);
            let truth = departure_truth(&mut rng);
            let reps = reports(&truth, Feed::Joint, &mut rng);
            let run = run_hybrid(params, &reps);
            for (tr, e) in truth.iter().zip(&run.estimates) {
                if tr.t_s < 10.0 {
                    continue;
                }
                n += 1;
                labels_ok += usize::from(tr.leg.labels() == (e.mode, e.turn));
                let lateral = match tr.leg.labels().1 {
                    Some(TurnDirection::Left) => Lateral::Left,
                    Some(TurnDirection::Right) => Lateral::Right,
                    None => Lateral::Straight,
                };
                let speed = match tr.leg.accel_mps2 {
                    a if a > 0.0 => SpeedTrend::Increasing,
                    a if a < 0.0 => SpeedTrend::Decreasing,
                    _ => SpeedTrend::Constant,
                };
                let vertical = match tr.leg.vrate_mps {
                    v if v > 0.0 => VerticalTrend::Climb,
                    v if v < 0.0 => VerticalTrend::Descent,
                    _ => VerticalTrend::Level,
                };
                axes_ok +=
                    usize::from((e.lateral, e.speed, e.vertical) == (lateral, speed, vertical));
            }
        }
        (labels_ok as f64 / n as f64, axes_ok as f64 / n as f64)
    }

    #[test]
    fn departure_profile_is_labelled() {
        let runs = runs(2, 10);
        let (labels, axes) = departure_accuracy(HybridParams::default(), runs);
        let (paper_labels, paper_axes) = departure_accuracy(HybridParams::paper002(), runs);
        eprintln!(
            "departure ({runs} runs): labels right {:.1} %, movement axes right {:.1} %; \
             with paper 002's gate thresholds {:.1} % and {:.1} %",
            100.0 * labels,
            100.0 * axes,
            100.0 * paper_labels,
            100.0 * paper_axes
        );
        // 94.5 % and 94.5 % measured (10 runs). Before the truth flew over a sphere (`fly`)
        // the axes were right 86.6 %: along the frame's tangent plane, 40 km out at 200 m/s,
        // level flight is a 1.3 m/s climb to the local vertical the gate reads, and the
        // climb onset test's newest reports saw it (labels 90.6 %, axes 84.9 %).
        assert!(labels >= 0.93 && axes >= 0.93, "{labels} {axes}");
    }

    #[test]
    fn covariances_stay_positive_definite_over_random_steps() {
        let mut rng = StdRng::seed_from_u64(5);
        let n01 = Normal::new(0.0, 1.0).unwrap();
        let mut hybrid = HybridTracker::default();
        let mut imm = ImmTracker::default();
        let imm_steps = runs(2_000, 10_000);
        let (mut pos, mut vel) = (
            Vector3::new(0.0, 0.0, 3000.0),
            Vector3::new(120.0, 0.0, 0.0),
        );
        let mut t = 0.0;
        let mut checked = 0;
        for step in 0..10_000 {
            // dt log-uniform from 0.01 s to 40 s, and now and then a gap beyond max_gap_s.
            let dt = if rng.gen_bool(0.002) {
                90.0
            } else {
                10f64.powf(rng.gen_range(-2.0..1.6))
            };
            // The truth manoeuvres at random: up to ±3 m/s² per axis.
            let acc = Vector3::from_fn(|_, _| 3.0 * n01.sample(&mut rng)).cap_magnitude(6.0);
            pos += vel * dt + acc * (0.5 * dt * dt.min(5.0));
            vel = (vel + acc * dt.min(5.0)).cap_magnitude(300.0);
            t += dt;
            let mut pos_cov = Matrix3::from_diagonal(&Vector3::new(100.0, 100.0, 225.0));
            let mut vel_cov = Matrix3::identity() * 0.3;
            if rng.gen_bool(0.1) {
                pos_cov[(2, 2)] = UNMEASURED_VARIANCE;
                vel_cov[(2, 2)] = UNMEASURED_VARIANCE;
            }
            let position = Observed {
                value: pos
                    + Vector3::from_fn(|i, _| {
                        pos_cov[(i, i)].min(225.0).sqrt() * n01.sample(&mut rng)
                    }),
                cov: pos_cov,
                grid: None,
            };
            let velocity = Observed {
                value: vel + Vector3::from_fn(|_, _| 0.5 * n01.sample(&mut rng)),
                cov: vel_cov,
                grid: None,
            };
            let m = match rng.gen_range(0..3) {
                0 => Measurement {
                    t_s: t,
                    position: Some(position),
                    velocity: None,
                },
                1 => Measurement {
                    t_s: t,
                    position: None,
                    velocity: Some(velocity),
                },
                _ => Measurement {
                    t_s: t,
                    position: Some(position),
                    velocity: Some(velocity),
                },
            };
            let mut trackers: Vec<&mut dyn Tracker> = vec![&mut hybrid];
            if step < imm_steps {
                trackers.push(&mut imm);
            }
            for tracker in trackers {
                tracker.update(&m).unwrap();
                let Some(e) = tracker.estimate() else {
                    continue;
                };
                for p in [tracker.predict(t + 60.0).unwrap(), e] {
                    for c in [p.pos_cov_m2, p.vel_cov_m2ps2] {
                        assert!(c.iter().all(|v| v.is_finite()), "step {step}");
                        assert_eq!(c, c.transpose(), "step {step}");
                        assert!(c.cholesky().is_some(), "step {step}: {c}");
                    }
                    assert!(p
                        .pos_m
                        .iter()
                        .chain(p.vel_mps.iter())
                        .all(|v| v.is_finite()));
                    assert!((p.mode_probabilities.iter().sum::<f64>() - 1.0).abs() < 1e-9);
                }
                checked += 1;
            }
            // The full internal covariances too.
            match &hybrid.branch {
                Branch::Cv { p, .. } => assert!(p.cholesky().is_some()),
                Branch::Imm { .. } => {
                    for mode in ImmMode::ALL {
                        assert!(
                            hybrid.imm.mode_state(mode).1.cholesky().is_some(),
                            "{mode:?}"
                        );
                    }
                }
            }
        }
        eprintln!(
            "random steps: {checked} estimates checked; hybrid {:?}",
            hybrid.stats()
        );
        assert!(hybrid.stats().to_imm > 0 && hybrid.stats().reinitialisations > 0);
    }

    #[test]
    fn prediction_extrapolates_by_the_current_mode() {
        let mut rng = StdRng::seed_from_u64(21);
        let times = report_times(&mut rng, 1000.0);
        let mut truth_times = times.clone();
        let reps_truth = fly(
            Vector3::new(1000.0, 1000.0, 3000.0),
            std::f64::consts::FRAC_PI_4,
            50.0 * 2f64.sqrt(),
            &paper_legs(),
            &times,
        );
        let reps = reports(&reps_truth, Feed::Joint, &mut rng);
        // Predict from inside the left turn (250 s) and from a straight leg (450 s).
        for (from_s, mode) in [(250.0, FlightMode::Ct), (450.0, FlightMode::Cv)] {
            let mut tracker = HybridTracker::default();
            for m in reps.iter().filter(|m| m.t_s <= from_s) {
                tracker.update(m).unwrap();
            }
            let now = tracker.estimate().unwrap();
            assert_eq!(now.mode, mode);
            let horizons = [30.0, 60.0, 120.0];
            truth_times.clear();
            truth_times.extend(horizons.iter().map(|h| now.t_s + h));
            let future = fly(
                Vector3::new(1000.0, 1000.0, 3000.0),
                std::f64::consts::FRAC_PI_4,
                50.0 * 2f64.sqrt(),
                &paper_legs(),
                &truth_times,
            );
            let mut last_sigma = 0.0;
            for (h, tr) in horizons.iter().zip(&future) {
                let p = tracker.predict(now.t_s + h).unwrap();
                let d = (p.pos_m - tr.pos).fixed_rows::<2>(0).into_owned();
                let cov = p.pos_cov_m2.fixed_view::<2, 2>(0, 0).into_owned();
                let m2 = d.dot(&cov.cholesky().unwrap().solve(&d));
                // A straight-line extrapolation of the current velocity, for comparison.
                let straight = (now.pos_m + now.vel_mps * *h - tr.pos)
                    .fixed_rows::<2>(0)
                    .norm();
                eprintln!(
                    "predict from {from_s} s ({mode:?}) +{h} s: error {:.1} m, σ {:.1} m, \
                     Mahalanobis² {m2:.2}; straight-line error {straight:.1} m",
                    d.norm(),
                    p.pos_sigma_m()
                );
                // Within the 99.9 % ellipse (χ²(2) = 13.8), uncertainty growing.
                assert!(m2 < 13.8);
                assert!(p.pos_sigma_m() > last_sigma);
                last_sigma = p.pos_sigma_m();
                if mode == FlightMode::Ct {
                    assert!(d.norm() < 0.2 * straight);
                }
            }
        }
    }

    #[test]
    fn tracker_basics() {
        let mut t = HybridTracker::default();
        assert_eq!(t.name(), "hybrid");
        assert!(t.estimate().is_none() && t.predict(10.0).is_none());
        let v = Observed {
            value: Vector3::new(100.0, 0.0, 0.0),
            cov: Matrix3::identity() * 0.25,
            grid: None,
        };
        let p = Observed {
            value: Vector3::new(0.0, 0.0, 1000.0),
            cov: Matrix3::identity() * 100.0,
            grid: None,
        };
        // A velocity alone waits; the position then starts the track with that velocity.
        t.update(&Measurement {
            t_s: 0.0,
            position: None,
            velocity: Some(v),
        })
        .unwrap();
        assert!(t.estimate().is_none());
        t.update(&Measurement {
            t_s: 1.0,
            position: Some(p),
            velocity: None,
        })
        .unwrap();
        let e = t.estimate().unwrap();
        assert_eq!(
            (e.filter, e.mode, e.lateral),
            (CV_FILTER, FlightMode::Cv, Lateral::Straight)
        );
        assert_eq!(e.vel_mps, v.value);
        // Out of order is refused and changes nothing; non-finite input too.
        let old = Measurement {
            t_s: 0.5,
            position: Some(p),
            velocity: None,
        };
        assert_eq!(
            t.update(&old),
            Err(TrackError::OutOfOrder {
                t_s: 0.5,
                track_t_s: 1.0
            })
        );
        let mut bad = p;
        bad.value.x = f64::NAN;
        let bad = Measurement {
            t_s: 2.0,
            position: Some(bad),
            velocity: None,
        };
        assert_eq!(t.update(&bad), Err(TrackError::NonFinite("measurement")));
        assert_eq!(t.estimate().unwrap(), e);
        // predict() refuses the past.
        assert!(t.predict(0.0).is_none());
        assert_eq!(ImmTracker::default().name(), "imm");
    }
}
