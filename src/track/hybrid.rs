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
//! - No chatter: the gate has hysteresis, and the IMM stays on for at least
//!   `min_manoeuvre_dwell_s` after the gate last fired.
//! - Labels: while a gate test holds, the label and the I062/200 movement axes are the
//!   gate's (turn → CT with its direction; vertical and speed → CHCA; vertical → CH; speed
//!   → CA); when the IMM was opened by divergence alone, the IMM's most probable mode; else
//!   CV. The gate reads velocities measured by ADS-B, so it labels with almost no delay
//!   where the IMM's probabilities need seconds to move (paper 002 Fig. 8).
//! - [`Tracker::predict`] extrapolates by the model of the current label (paper 002 §1.3):
//!   CV, CA, CH, CHCA, or CT at the turn rate the gate measures.

use super::divergence::{guarded_update, DivergenceParams, Observation, Prediction};
use super::gate::{Gate, GateParams, GateReading};
use super::imm::{
    estimate_of, labels_of_mode, AxisThresholds, EstimateInfo, Imm, ImmMode, ImmParams, InitParams,
    Initiator, Labels, Start, IMM_NAME, N_MODES,
};
use super::kalman::MotionModel;
use super::models::{Cv, Matrix6, Matrix9, Model, State6, State9, ACC};
use super::{
    Estimate, FlightMode, Lateral, Measurement, Observed, TrackError, Tracker, TurnDirection,
};
use nalgebra::Vector3;

/// Name of the hybrid tracker.
pub const NAME: &str = "hybrid";
/// [`Estimate::filter`] while the CV Kalman filter runs.
pub const CV_FILTER: &str = "kalman-cv";

/// Tuning of [`HybridTracker`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HybridParams {
    /// The CV filter's model (6-state). Default [`Cv::default`].
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
    /// Set the CT models' turn rate to the one the gate measures while a turn holds (within
    /// `turn_rate_limits_deg_s`), instead of the fixed standard rate. Default true: airliners
    /// turn at 1-3 °/s depending on speed and bank.
    pub adapt_turn_rate: bool,
    /// Clamp of the adapted turn rate, °/s. Default 0.5 to 6.
    pub turn_rate_limits_deg_s: (f64, f64),
    /// IMM probability given to the gate's label when the IMM opens; CV gets half the rest
    /// and the other modes share the remainder. Default 0.5.
    pub entry_probability: f64,
}

impl Default for HybridParams {
    fn default() -> Self {
        Self {
            cv: Cv::default(),
            imm: ImmParams::default(),
            gate: GateParams::default(),
            divergence: DivergenceParams::default(),
            init: InitParams::default(),
            axes: AxisThresholds::default(),
            min_manoeuvre_dwell_s: 4.0,
            divergence_trigger: 3,
            velocity_stale_s: 3.0,
            adapt_turn_rate: true,
            turn_rate_limits_deg_s: (0.5, 6.0),
            entry_probability: 0.5,
        }
    }
}

impl HybridParams {
    /// Paper 002's tracker as printed: its gate thresholds ([`GateParams::paper002`]).
    pub fn paper002() -> Self {
        Self {
            gate: GateParams::paper002(),
            ..Self::default()
        }
    }
}

/// Which filter runs.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Branch {
    /// The CV Kalman filter with its state.
    Cv { x: State6, p: Matrix6 },
    /// The IMM (its state lives in [`HybridTracker::imm`]); `by_divergence`: opened by the
    /// divergence trigger with no gate test holding.
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
    params: HybridParams,
    gate: Gate,
    imm: Imm,
    init: Initiator,
    branch: Branch,
    labels: Labels,
    /// Feed time of the last report with a velocity.
    last_velocity_t_s: Option<f64>,
    /// Feed time the gate (or the divergence trigger) last held.
    last_fire_t_s: f64,
    /// Consecutive divergence events of the CV filter.
    cv_divergence_run: u32,
    diverging: bool,
    divergence_events: u64,
    stats: HybridStats,
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
            params,
            gate: Gate::new(params.gate),
            imm: Imm::new(params.imm),
            init: Initiator::new(params.init, &params.cv),
            branch: Branch::Cv {
                x: State6::zeros(),
                p: Matrix6::identity(),
            },
            labels: Labels::CV,
            last_velocity_t_s: None,
            last_fire_t_s: f64::NEG_INFINITY,
            cv_divergence_run: 0,
            diverging: false,
            divergence_events: 0,
            stats: HybridStats::default(),
        }
    }

    /// The tuning in use.
    pub fn params(&self) -> &HybridParams {
        &self.params
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

    /// Starts a track from the initiator's 9-state.
    fn start(&mut self, t_s: f64, x: &State9, p: &Matrix9, velocity: Option<&Observed>) {
        self.branch = Branch::Cv {
            x: x.fixed_rows::<6>(0).into_owned(),
            p: p.fixed_view::<6, 6>(0, 0).into_owned(),
        };
        self.gate.clear();
        self.labels = Labels::CV;
        self.last_fire_t_s = f64::NEG_INFINITY;
        self.cv_divergence_run = 0;
        self.diverging = false;
        self.last_velocity_t_s = None;
        if let Some(v) = velocity {
            self.gate.push(t_s, v, true);
            self.last_velocity_t_s = Some(t_s);
        }
    }

    /// The current filter's position/velocity estimate and its covariance (6-state).
    fn state6(&self) -> (State6, Matrix6) {
        match &self.branch {
            Branch::Cv { x, p } => (*x, *p),
            Branch::Imm { .. } => {
                let (x, p) = self.imm.combined();
                (
                    x.fixed_rows::<6>(0).into_owned(),
                    p.fixed_view::<6, 6>(0, 0).into_owned(),
                )
            }
        }
    }

    /// Runs the current filter on the report.
    fn filter_step(&mut self, dt_s: f64, obs: &Observation) -> Result<(), TrackError> {
        match &mut self.branch {
            Branch::Cv { x, p } => {
                let pred = Prediction::<6>::new(&self.params.cv, x, p, dt_s);
                let g = guarded_update(&pred, obs, &self.params.divergence)?;
                *x = g.x;
                *p = g.p;
                self.diverging = g.diverged;
                self.cv_divergence_run = if g.diverged {
                    self.cv_divergence_run.saturating_add(1)
                } else {
                    0
                };
                self.stats.cv_updates += 1;
            }
            Branch::Imm { .. } => {
                self.imm.step(dt_s, obs)?;
                self.diverging = self.imm.diverged(self.imm.most_probable());
                self.cv_divergence_run = 0;
                self.stats.imm_updates += 1;
            }
        }
        if self.diverging {
            self.divergence_events = self.divergence_events.saturating_add(1);
        }
        Ok(())
    }

    /// Feeds the gate: the report's velocity, or the filter's when velocity reports stopped.
    fn feed_gate(&mut self, m: &Measurement) {
        if let Some(v) = &m.velocity {
            self.gate.push(m.t_s, v, true);
            self.last_velocity_t_s = Some(m.t_s);
        } else if self
            .last_velocity_t_s
            .is_none_or(|tv| m.t_s - tv > self.params.velocity_stale_s)
        {
            let (x, p) = self.state6();
            let derived = Observed {
                value: x.fixed_rows::<3>(3).into_owned(),
                cov: p.fixed_view::<3, 3>(3, 3).into_owned(),
            };
            self.gate.push(m.t_s, &derived, false);
        }
    }

    /// IMM mode probabilities for an IMM opened on the gate's `label`.
    fn entry_probabilities(&self, reading: &GateReading) -> Option<[f64; N_MODES]> {
        let (mode, turn) = reading.label()?;
        let target = match (mode, turn) {
            (FlightMode::Ct, Some(TurnDirection::Left)) => ImmMode::CtLeft,
            (FlightMode::Ct, _) => ImmMode::CtRight,
            (FlightMode::Ca, _) => ImmMode::Ca,
            (FlightMode::Ch, _) => ImmMode::Ch,
            (FlightMode::Chca, _) => ImmMode::Chca,
            (FlightMode::Cv, _) => ImmMode::Cv,
        };
        let e = self.params.entry_probability.clamp(0.0, 1.0);
        let rest = (1.0 - e) / 2.0;
        let mut mu = [rest / (N_MODES - 2) as f64; N_MODES];
        mu[ImmMode::Cv.index()] = rest;
        mu[target.index()] = e;
        Some(mu)
    }

    /// The turn rate for the CT models: the gate's smoothed rate while a turn holds.
    fn turn_rate(&self, reading: &GateReading) -> f64 {
        let (lo, hi) = self.params.turn_rate_limits_deg_s;
        let default = self.params.imm.models.ct.omega_rad_s.abs();
        if !self.params.adapt_turn_rate || reading.lateral() == Lateral::Straight {
            return default;
        }
        reading
            .smoothed_turn_rate_rad_s
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
        if reading.manoeuvre() || trigger {
            self.last_fire_t_s = t_s;
        }
        match self.branch {
            Branch::Cv { x, p } if reading.manoeuvre() || trigger => {
                let mut x9 = State9::zeros();
                x9.fixed_rows_mut::<6>(0).copy_from(&x);
                if reading.flags.along_track {
                    // Start the acceleration at the gate's along-track estimate.
                    let v = Vector3::new(x[3], x[4], 0.0);
                    let a = reading.along_track_accel_mps2.unwrap_or(0.0);
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
                self.imm.reset(&x9, &p9, mu.as_ref());
                self.branch = Branch::Imm {
                    by_divergence: !reading.manoeuvre(),
                };
                self.stats.to_imm += 1;
            }
            Branch::Imm { .. } if t_s - self.last_fire_t_s >= self.params.min_manoeuvre_dwell_s => {
                let (x, p) = self.imm.combined();
                self.branch = Branch::Cv {
                    x: x.fixed_rows::<6>(0).into_owned(),
                    p: p.fixed_view::<6, 6>(0, 0).into_owned(),
                };
                self.stats.to_cv += 1;
            }
            _ => {}
        }
        if let Branch::Imm { by_divergence } = self.branch {
            let rate = self.turn_rate(&reading);
            self.imm.set_turn_rate(rate);
            if reading.manoeuvre() {
                self.branch = Branch::Imm {
                    by_divergence: false,
                };
            }
            self.labels = match reading.label() {
                Some((mode, turn)) => Labels {
                    mode,
                    turn,
                    lateral: reading.lateral(),
                    speed: reading.speed(),
                    vertical: reading.vertical(),
                },
                None if by_divergence => {
                    let (x, _) = self.imm.combined();
                    labels_of_mode(self.imm.most_probable(), &x, &self.params.axes)
                }
                None => Labels::CV,
            };
        } else {
            self.labels = Labels::CV;
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
    fn name(&self) -> &'static str {
        NAME
    }

    fn update(&mut self, m: &Measurement) -> Result<(), TrackError> {
        let track_t_s = self.init.track_t_s();
        match self.init.offer(m)? {
            Start::Waiting => Ok(()),
            Start::New(x, p) => {
                self.start(m.t_s, &x, &p, m.velocity.as_ref());
                Ok(())
            }
            Start::Running => {
                let Some(obs) = Observation::of(m.position.as_ref(), m.velocity.as_ref()) else {
                    return Ok(());
                };
                let dt_s = m.t_s - track_t_s.unwrap_or(m.t_s);
                self.filter_step(dt_s, &obs)?;
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
        Some(match &self.branch {
            Branch::Cv { x, p } => estimate_of(t_s, x, p, &info),
            Branch::Imm { .. } => {
                let (x, p) = self.imm.combined();
                estimate_of(t_s, &x, &p, &info)
            }
        })
    }

    /// Extrapolates by the current label's model (paper 002 §1.3), its Q added; CT at the
    /// turn rate in use (the gate's when `adapt_turn_rate`).
    fn predict(&self, t_s: f64) -> Option<Estimate> {
        let track_t_s = self.init.track_t_s()?;
        let dt_s = t_s - track_t_s;
        if !dt_s.is_finite() || dt_s < 0.0 {
            return None;
        }
        let info = self.info();
        Some(match &self.branch {
            Branch::Cv { x, p } => {
                let (mut x, mut p) = (*x, *p);
                MotionModel::<6>::predict(&self.params.cv, &mut x, &mut p, dt_s);
                estimate_of(t_s, &x, &p, &info)
            }
            Branch::Imm { .. } => {
                let (mut x, mut p) = self.imm.combined();
                self.label_model().predict(&mut x, &mut p, dt_s);
                estimate_of(t_s, &x, &p, &info)
            }
        })
    }
}
