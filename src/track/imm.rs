//! The interacting multiple model (IMM) estimator of Blom & Bar-Shalom (IEEE TAC 33(8), 1988;
//! Bar-Shalom, Li, Kirubarajan 2001, §11.6.6), which paper 002 calls RMIMM (residual-based
//! IMM, ALGORITHMS.md §002), over the models of [`super::models`] in their common 9-state.
//!
//! One cycle, for a report at dt after the last one:
//! 1. Mixing: c̄ⱼ = Σᵢ πᵢⱼ μᵢ, μᵢ|ⱼ = πᵢⱼ μᵢ / c̄ⱼ, x̂⁰ⱼ = Σᵢ μᵢ|ⱼ x̂ᵢ,
//!    P⁰ⱼ = Σᵢ μᵢ|ⱼ [Pᵢ + (x̂ᵢ − x̂⁰ⱼ)(x̂ᵢ − x̂⁰ⱼ)ᵀ].
//! 2. Mode-matched filtering: each model predicts from (x̂⁰ⱼ, P⁰ⱼ) and updates with the
//!    report, the step guarded by paper 000's divergence suppressor ([`super::divergence`]).
//!    Each mode does this on the states its model keeps, the reset accelerations being
//!    restored as the 9-state step leaves them ([`ResetTail`]: 6 states for CV, CT and CH, 8
//!    for CA and CHCA): the same numbers for half the work or less.
//! 3. Mode probabilities: μⱼ ∝ c̄ⱼ Λⱼ with Λⱼ the likelihood of the nominal residual,
//!    computed in LOG space: ln μⱼ = ln c̄ⱼ + ln Λⱼ − logsumexp (a residual of a few hundred
//!    σ gives ln Λ ≈ −10⁵, whose exponential underflows f64 to 0 in every mode at once).
//! 4. Combination: x̂ = Σ μⱼ x̂ⱼ, P = Σ μⱼ [Pⱼ + (x̂ⱼ − x̂)(x̂ⱼ − x̂)ᵀ] (the spread of means).
//!
//! The Markov transition matrix depends on dt (reports are irregular): a mode i is left
//! within dt with probability 1 − exp(−dt/τᵢ) (τᵢ its mean sojourn time) and a switch goes
//! to mode j with the configured relative weight wᵢⱼ, so πᵢᵢ = exp(−dt/τᵢ) and
//! πᵢⱼ = (1 − exp(−dt/τᵢ)) wᵢⱼ / Σₖ wᵢₖ (at most one switch per interval).
//!
//! Works with position-only, velocity-only and joint reports: the likelihood is that of
//! whatever the report measured. Everything is in fixed-size arrays: no allocation.

use super::divergence::{
    guarded_update, let_prediction, DivergenceParams, Observation, Prediction,
};
use super::kalman::{self, MotionModel};
use super::models::{
    Ca, Ch, Chca, Ct, Cv, Matrix6, Matrix9, Model, ResetTail, State6, State9, ACC, POS, VEL,
};
use super::noise::{local_up, BlockStat, NoiseLearner, NoiseParams};
use super::outlier::{OutlierGate, OutlierParams};
use super::quantised::OnGrid;
use super::tails::{TailIndex, TailParams};
use super::{
    Estimate, FlightMode, Lateral, Measurement, Observed, SpeedTrend, TrackError, Tracker,
    TurnDirection, VerticalTrend,
};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// Number of IMM modes ([`ImmMode::ALL`]).
pub const N_MODES: usize = 6;

/// The IMM's modes: paper 002's five flight modes, CT split by direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ImmMode {
    /// Constant velocity.
    Cv,
    /// Constant acceleration, level.
    Ca,
    /// Coordinated turn to the left.
    CtLeft,
    /// Coordinated turn to the right.
    CtRight,
    /// Climb or descent at constant ground velocity.
    Ch,
    /// Climb or descent with horizontal acceleration.
    Chca,
}

impl ImmMode {
    /// All modes, in the order of every per-mode array of this module.
    pub const ALL: [ImmMode; N_MODES] = [
        Self::Cv,
        Self::Ca,
        Self::CtLeft,
        Self::CtRight,
        Self::Ch,
        Self::Chca,
    ];

    /// Position in [`ImmMode::ALL`].
    pub fn index(self) -> usize {
        match self {
            Self::Cv => 0,
            Self::Ca => 1,
            Self::CtLeft => 2,
            Self::CtRight => 3,
            Self::Ch => 4,
            Self::Chca => 5,
        }
    }

    /// The flight-mode label of this mode.
    pub fn flight_mode(self) -> FlightMode {
        match self {
            Self::Cv => FlightMode::Cv,
            Self::Ca => FlightMode::Ca,
            Self::CtLeft | Self::CtRight => FlightMode::Ct,
            Self::Ch => FlightMode::Ch,
            Self::Chca => FlightMode::Chca,
        }
    }

    /// The turn direction of a CT mode.
    pub fn turn(self) -> Option<TurnDirection> {
        match self {
            Self::CtLeft => Some(TurnDirection::Left),
            Self::CtRight => Some(TurnDirection::Right),
            _ => None,
        }
    }
}

/// The models' parameters; CT right is CT left mirrored (ω → −ω).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ModelSet {
    /// Constant velocity.
    pub cv: Cv,
    /// Constant acceleration.
    pub ca: Ca,
    /// Coordinated turn; `omega_rad_s` is the magnitude used by both directions.
    pub ct: Ct,
    /// Climb/descent.
    pub ch: Ch,
    /// Climb/descent with horizontal acceleration.
    pub chca: Chca,
}

impl ModelSet {
    /// The models in [`ImmMode::ALL`] order.
    pub fn models(&self) -> [Model; N_MODES] {
        let rate = self.ct.omega_rad_s.abs();
        [
            Model::Cv(self.cv),
            Model::Ca(self.ca),
            Model::Ct(Ct {
                omega_rad_s: rate,
                ..self.ct
            }),
            Model::Ct(Ct {
                omega_rad_s: -rate,
                ..self.ct
            }),
            Model::Ch(self.ch),
            Model::Chca(self.chca),
        ]
    }
}

/// Tuning of the IMM.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImmParams {
    /// The models.
    pub models: ModelSet,
    /// Which modes take part (a disabled mode has probability 0 and costs nothing).
    pub enabled: [bool; N_MODES],
    /// Mean sojourn time τ of each mode, s: the mode is kept over dt with probability
    /// exp(−dt/τ). Default 30 s for CV (≈ 0.983 per 0.5 s report: airliners fly straight for
    /// minutes), 20 s for the manoeuvres (a standard-rate 60° turn lasts 20 s; speed and
    /// vertical changes last tens of seconds).
    pub mean_sojourn_s: [f64; N_MODES],
    /// Relative weights of the mode a switch goes to: row i, column j (the diagonal is
    /// ignored). Default: from CV to each manoeuvre alike; from a manoeuvre back to CV 4
    /// times as likely as to another manoeuvre, and a turn reverses direction rarely (1/4).
    pub switch_weights: [[f64; N_MODES]; N_MODES],
    /// Mode probabilities of a new track. Default CV 0.6, the others 0.08.
    pub initial_probabilities: [f64; N_MODES],
    /// Paper 000's criterion and suppressor on each model's step.
    pub divergence: DivergenceParams,
    /// How much older a velocity report is than the frame that carries it, s: the CT modes
    /// take it as their velocity that long ago ([`aged_for_turn`]). 0 (the default): every
    /// report is current, as the simulator's are unless told otherwise. Real transponders'
    /// can be about a second old (`afr34zg-cdg-tls.jsonl`: 1.07 s, `eval::latency`).
    pub velocity_lag_s: f64,
}

impl Default for ImmParams {
    fn default() -> Self {
        let mut w = [[1.0; N_MODES]; N_MODES];
        for (i, row) in w.iter_mut().enumerate() {
            row[i] = 0.0;
            if i != 0 {
                row[0] = 4.0;
            }
        }
        w[2][3] = 0.25;
        w[3][2] = 0.25;
        Self {
            models: ModelSet::default(),
            enabled: [true; N_MODES],
            mean_sojourn_s: [30.0, 20.0, 20.0, 20.0, 20.0, 20.0],
            switch_weights: w,
            initial_probabilities: [0.6, 0.08, 0.08, 0.08, 0.08, 0.08],
            divergence: DivergenceParams::default(),
            velocity_lag_s: 0.0,
        }
    }
}

/// Weights proportional to exp(aᵢ) for log-weights aᵢ, scaled so that the largest is 1:
/// exp(aᵢ − max a), which neither overflows nor underflows where it matters (the largest
/// weight is exactly 1, so their sum is at least 1 and normalising by it is safe; a weight
/// that underflows to 0 is below 1e-308 of the largest). `None` when no aᵢ is finite.
///
/// The posterior mode probabilities are these weights normalised. (They were
/// exp(aᵢ − ln Σ exp aⱼ), which computed every exponential twice and a logarithm: 1 % of
/// the default tracker's fleet replay instructions, for the same numbers to rounding.)
fn relative_weights<const N: usize>(log_weights: &[f64; N]) -> Option<[f64; N]> {
    let max = log_weights
        .iter()
        .cloned()
        .fold(f64::NEG_INFINITY, f64::max);
    if !max.is_finite() {
        return None;
    }
    Some(log_weights.map(|a| (a - max).exp()))
}

/// Entries of a 9x9 symmetric matrix's upper triangle.
const PACKED9: usize = 45;

/// A symmetric 9x9 matrix by its upper triangle, column by column (rows 0..=c of column c):
/// 360 bytes instead of 648.
type Packed9 = [f64; PACKED9];

/// Column `c`'s part of a [`Packed9`]: rows 0..=c, from offset c(c+1)/2.
fn packed_col(c: usize) -> std::ops::Range<usize> {
    let start = c * (c + 1) / 2;
    start..start + c + 1
}

/// The upper triangle of `p`, column by column.
fn pack(p: &Matrix9) -> Packed9 {
    let mut out = [0.0; PACKED9];
    for (c, col) in p.data.0.iter().enumerate() {
        if let (Some(o), Some(v)) = (out.get_mut(packed_col(c)), col.get(..=c)) {
            o.copy_from_slice(v);
        }
    }
    out
}

/// The symmetric matrix whose upper triangle `packed` holds, or its leading K×K block
/// (K ≤ 9: the first K(K+1)/2 entries).
fn unpack<const K: usize>(packed: &Packed9) -> SMatrix<f64, K, K> {
    let mut m = SMatrix::<f64, K, K>::zeros();
    for c in 0..K {
        if let Some(col) = packed.get(packed_col(c)) {
            for (r, v) in col.iter().enumerate() {
                m[(r, c)] = *v;
                m[(c, r)] = *v;
            }
        }
    }
    m
}

/// Σᵢ wᵢ [Pᵢ + (x̂ᵢ − x̂)(x̂ᵢ − x̂)ᵀ] over the terms with wᵢ > 0: the mixed covariance
/// P⁰ⱼ (Bar-Shalom et al. 2001, eq. 11.6.6-11) and the combined one (eq. 11.6.6-20).
///
/// In place over fixed-size arrays (no temporary 9x9 matrices for the outer product and
/// the scaled sum): entry by entry the same operations as `out += (Pᵢ + d dᵀ) wᵢ`. Every Pᵢ
/// the estimator holds is exactly symmetric (each comes out of a symmetrisation:
/// [`kalman::symmetrise`], a Kalman update, [`Prediction::covariance`]), which is why it is
/// stored as its upper triangle ([`Packed9`]), and so is d dᵀ (dᵣ d꜀ = d꜀ dᵣ in floating
/// point): the sum is accumulated over the upper triangle alone and mirrored, the same
/// result with 45 entries instead of 81.
///
/// Over the leading K states alone (K ≤ 9; their block of the packed Pᵢ is its first
/// K(K+1)/2 entries): what a mode whose model resets the rest needs ([`ResetTail`]).
fn spread_sum<const K: usize>(
    x: &[State9; N_MODES],
    p: &[Packed9; N_MODES],
    w: &[f64; N_MODES],
    mean: &SVector<f64, K>,
) -> SMatrix<f64, K, K> {
    let mut out = [0.0f64; PACKED9];
    for ((xi, pi), &wi) in x.iter().zip(p).zip(w) {
        if wi > 0.0 {
            let mut d = [0.0f64; K];
            for ((dk, xk), mk) in d.iter_mut().zip(xi.iter()).zip(mean.iter()) {
                *dk = xk - mk;
            }
            for (c, dc) in d.iter().enumerate() {
                let (Some(oc), Some(pc)) = (out.get_mut(packed_col(c)), pi.get(packed_col(c)))
                else {
                    continue;
                };
                for ((o, pv), dr) in oc.iter_mut().zip(pc).zip(&d) {
                    *o += (pv + dr * dc) * wi;
                }
            }
        }
    }
    unpack::<K>(&out)
}

/// Σᵢ wᵢ x̂ᵢ over the leading K states, the terms with wᵢ > 0.
fn weighted_mean<const K: usize>(x: &[State9; N_MODES], w: &[f64; N_MODES]) -> SVector<f64, K> {
    let mut mean = SVector::<f64, K>::zeros();
    for (xi, &wi) in x.iter().zip(w) {
        if wi > 0.0 {
            for (m, xk) in mean.iter_mut().zip(xi.iter()) {
                *m += xk * wi;
            }
        }
    }
    mean
}

/// Writes a K-state (x, P) as the 9-state one of a [`ResetTail`] model: the reset states
/// at zero with variance `reset_var`, uncorrelated.
fn embed<const K: usize>(
    x: &SVector<f64, K>,
    p: &SMatrix<f64, K, K>,
    reset_var: f64,
    x_out: &mut State9,
    p_out: &mut Packed9,
) {
    x_out.fill(0.0);
    for (o, v) in x_out.iter_mut().zip(x.iter()) {
        *o = *v;
    }
    // Column c of the packed triangle is rows 0..=c: the kept block's column for c < K,
    // else zeros with the reset variance on the diagonal. Whole columns are copied (one
    // bounds check each, not one per entry).
    p_out.fill(0.0);
    for c in 0..9 {
        let Some(col) = p_out.get_mut(packed_col(c)) else {
            continue;
        };
        match p.data.0.get(c) {
            Some(kept) => {
                for (o, v) in col.iter_mut().zip(kept) {
                    *o = *v;
                }
            }
            None => {
                if let Some(diagonal) = col.last_mut() {
                    *diagonal = reset_var;
                }
            }
        }
    }
}

/// What one mode's filter reports of a step besides its new state.
struct ModeOutcome {
    /// Consecutive divergence events (paper 000) up to this step.
    run: u32,
    /// NIS over the measured horizontal components, and the log-likelihood, of the nominal
    /// innovation.
    nis: f64,
    log_likelihood: f64,
    /// A velocity report on a grid with this mode's claim about it ([`Guarded::on_grid`]).
    on_grid: Option<OnGrid>,
    /// The nominal innovation blocks, for [`super::noise`].
    blocks: [BlockStat; 2],
    /// Pⱼ(k|k−1) − Pⱼ(k|k) over the velocity block.
    correction: Matrix3<f64>,
    /// The position report's along-track z when [`ModeInput::along`], else NaN.
    along_z: f64,
}

/// [`mode_step`] with the state count of `model`'s kept states.
fn mode_step_of(
    model: &Model,
    input: &ModeInput,
    x_out: &mut State9,
    p_out: &mut Packed9,
) -> Result<ModeOutcome, TrackError> {
    match model {
        Model::Cv(m) => mode_step::<6>(m, input, x_out, p_out),
        Model::Ct(m) => match aged_for_turn(input.obs, m.omega_rad_s, input.velocity_lag_s) {
            Some(obs) => mode_step::<6>(
                m,
                &ModeInput {
                    obs: &obs,
                    ..*input
                },
                x_out,
                p_out,
            ),
            None => mode_step::<6>(m, input, x_out, p_out),
        },
        Model::Ch(m) => mode_step::<6>(m, input, x_out, p_out),
        Model::Ca(m) => mode_step::<8>(m, input, x_out, p_out),
        Model::Chca(m) => mode_step::<8>(m, input, x_out, p_out),
    }
}

/// A report's velocity as a CT model at `omega_rad_s` sees it when the report is `lag_s`
/// old: under the model the velocity turns at ω, so the report's v(t − lag) is
/// R(−ω·lag) v(t), and the report rotated by ω·lag (its covariance with it) measures v(t).
/// Exact for the model's deterministic motion; the process noise of those `lag_s` is not
/// added. `None` when nothing turns: no lag, no rate, or no velocity in the report (CV and
/// CH keep their velocity, so a lag changes nothing there; CA and CHCA would take
/// v − a·lag, not modelled: a speed change of 0.5 m/s² moves the velocity 0.5 m/s in a
/// second, where a 3°/s turn at 140 m/s turns it 7 m/s).
fn aged_for_turn(obs: &Observation, omega_rad_s: f64, lag_s: f64) -> Option<Observation> {
    let angle = omega_rad_s * lag_s;
    if angle == 0.0 || !angle.is_finite() {
        return None;
    }
    let (sin, cos) = angle.sin_cos();
    let r = Matrix3::new(cos, -sin, 0.0, sin, cos, 0.0, 0.0, 0.0, 1.0);
    let turned = |o: &Observed| Observed {
        value: r * o.value,
        cov: r * o.cov * r.transpose(),
        grid: o.grid.map(|g| g.turned_about_z(angle)),
    };
    match obs {
        Observation::Position(_) => None,
        Observation::Velocity(v) => Some(Observation::Velocity(turned(v))),
        Observation::Both(p, v) => Some(Observation::Both(*p, turned(v))),
    }
}

/// What one mode's filter reads in an IMM step.
#[derive(Clone, Copy)]
struct ModeInput<'a> {
    /// Every mode's state after the last step.
    states: &'a ModeStates,
    /// This mode's mixing weights μᵢ|ⱼ.
    w: &'a [f64; N_MODES],
    dt_s: f64,
    obs: &'a Observation,
    divergence: &'a DivergenceParams,
    /// This mode's consecutive divergence events before the step.
    previous_run: u32,
    /// [`ImmParams::velocity_lag_s`].
    velocity_lag_s: f64,
    /// Form the report's along-track z ([`super::tails::along_track_z`]) if it is a position
    /// report: the CV mode's.
    along: bool,
}

/// One mode's mixing, prediction and guarded update on the leading K states of its
/// [`ResetTail`] model, written to `x_out`, `p_out` as 9-state: the same numbers as
/// [`mode_step_full`] (tested) with the work of a K-state filter. On an update error the
/// prediction is written and the error returned. A model whose reset variance is not
/// positive (no 9-state covariance would then be positive definite) takes the 9-state path,
/// which is what fails there.
fn mode_step<const K: usize>(
    model: &impl ResetTail<K>,
    input: &ModeInput,
    x_out: &mut State9,
    p_out: &mut Packed9,
) -> Result<ModeOutcome, TrackError> {
    let reset_var = model.reset_variance();
    if !(reset_var > 0.0 && reset_var.is_finite()) {
        return mode_step_full(model, input, x_out, p_out);
    }
    let x0 = weighted_mean::<K>(&input.states.x, input.w);
    let p0 = spread_sum::<K>(&input.states.x, &input.states.p, input.w, &x0);
    let (f, q) = model.leading_fq(input.dt_s);
    let_prediction!(pred = f, q; x0, &p0);
    guarded_mode(&pred, input, |x, p| embed(x, p, reset_var, x_out, p_out))
}

/// [`mode_step`] in the full 9 states, for any model: the reference the reduced step is
/// tested against.
fn mode_step_full(
    model: &dyn MotionModel<9>,
    input: &ModeInput,
    x_out: &mut State9,
    p_out: &mut Packed9,
) -> Result<ModeOutcome, TrackError> {
    let x0 = weighted_mean::<9>(&input.states.x, input.w);
    let p0 = spread_sum::<9>(&input.states.x, &input.states.p, input.w, &x0);
    let pred = Prediction::<9>::new(model, &x0, &p0, input.dt_s);
    guarded_mode(&pred, input, |x, p| {
        *x_out = *x;
        *p_out = pack(p);
    })
}

/// The guarded update of a mode's prediction: `write` gets the updated state (or, when the
/// update fails, the prediction, and the error is returned).
fn guarded_mode<const K: usize>(
    pred: &Prediction<K>,
    input: &ModeInput,
    write: impl FnOnce(&SVector<f64, K>, &SMatrix<f64, K, K>),
) -> Result<ModeOutcome, TrackError> {
    let (mut x, mut p) = (SVector::<f64, K>::zeros(), SMatrix::<f64, K, K>::zeros());
    let guarded = guarded_update(
        pred,
        input.obs,
        input.divergence,
        input.previous_run,
        &mut x,
        &mut p,
    );
    match guarded {
        Ok(g) => {
            write(&x, &p);
            Ok(ModeOutcome {
                run: g.run,
                nis: g.nis_horizontal,
                log_likelihood: g.log_likelihood,
                on_grid: g.on_grid,
                blocks: g.blocks,
                correction: pred.covariance_block3(g.adapt, VEL)
                    - kalman::block::<3, 3, K, K>(&p, VEL, VEL),
                along_z: match input.obs {
                    Observation::Position(o) if input.along => {
                        super::tails::along_track_z(pred, &o.cov, &o.value)
                    }
                    _ => f64::NAN,
                },
            })
        }
        Err(e) => {
            write(&pred.x, &pred.covariance(1.0));
            Err(e)
        }
    }
}

/// Every mode's state and covariance (the covariances packed): 2.6 KB, the bulk of an
/// IMM.
#[derive(Clone, Debug, PartialEq)]
struct ModeStates {
    x: [State9; N_MODES],
    p: [Packed9; N_MODES],
}

impl ModeStates {
    /// Before any reset: zero states, identity covariances.
    fn initial() -> Self {
        Self {
            x: [State9::zeros(); N_MODES],
            p: [pack(&Matrix9::identity()); N_MODES],
        }
    }
}

/// What [`Imm::states`] reads while no states are held.
static INITIAL_STATES: std::sync::LazyLock<ModeStates> =
    std::sync::LazyLock::new(ModeStates::initial);

/// The IMM estimator: one state and covariance per mode and the mode probabilities.
///
/// The per-mode states are held on the heap only from the first [`Imm::reset`] or
/// [`Imm::step`] until [`Imm::release`]: the hybrid tracker releases them while its CV
/// filter runs (two thirds of a fleet's aircraft at any time), where they are never read
/// (it enters the IMM again through `reset`, which overwrites them all). 2.6 KB less per
/// such aircraft; while none are held every reader sees the initial states, as before.
#[derive(Clone, Debug, PartialEq)]
pub struct Imm {
    /// Shared by every estimator built with the same tuning ([`super::shared`]).
    params: std::sync::Arc<ImmParams>,
    models: [Model; N_MODES],
    states: Option<Box<ModeStates>>,
    mu: [f64; N_MODES],
    /// Consecutive divergence events of each mode's filter (paper 000 confirmation).
    divergence_runs: [u32; N_MODES],
    /// Σⱼ μⱼ (Pⱼ(k|k−1) − Pⱼ(k|k)) over the velocity block at the last step.
    velocity_correction_cov: Matrix3<f64>,
    divergence_events: [u64; N_MODES],
    /// Each mode's NIS at the last step (nominal innovation; NaN when its update failed).
    nis: [f64; N_MODES],
    /// The most probable mode's term of the windowed NIS at the last step
    /// ([`Imm::published_nis`]).
    published_nis: f64,
    /// The quantile residuals [`Imm::published_nis`] came from when it is a velocity
    /// report's on a narrow claim ([`Imm::published_residuals`]); NaN otherwise.
    published_residuals: [f64; 2],
    /// The CV model's innovation blocks at the last step, for [`super::noise`].
    cv_blocks: [BlockStat; 2],
    /// The CV model's along-track z of a position report at the last step, for
    /// [`super::tails`] (NaN for any other report, or when not [`Imm::form_along_z`]).
    cv_along_z: f64,
    /// Form [`Imm::cv_along_z`] at all ([`Imm::form_along_z`]): the plain `imm`'s tail
    /// learner reads it, the hybrid's IMM branch does not.
    along_wanted: bool,
    /// The modes of the current model set ([`Imm::set_active`]): the enabled ones unless a
    /// caller narrows them.
    active: [bool; N_MODES],
    /// The velocity reports' age the CT modes allow for, s ([`ImmParams::velocity_lag_s`],
    /// or what the aircraft's reports taught: [`Imm::set_velocity_lag`]).
    velocity_lag_s: f64,
}

impl Imm {
    /// An estimator with zero states; call [`Imm::reset`] before the first step.
    pub fn new(params: ImmParams) -> Self {
        let mut imm = Self {
            params: super::shared::shared(params),
            models: params.models.models(),
            states: None,
            mu: [0.0; N_MODES],
            divergence_runs: [0; N_MODES],
            velocity_correction_cov: Matrix3::zeros(),
            divergence_events: [0; N_MODES],
            nis: [f64::NAN; N_MODES],
            published_nis: f64::NAN,
            published_residuals: [f64::NAN; 2],
            cv_blocks: [BlockStat::default(); 2],
            cv_along_z: f64::NAN,
            along_wanted: false,
            active: params.enabled,
            velocity_lag_s: params.velocity_lag_s,
        };
        imm.mu = imm.normalised(&params.initial_probabilities);
        imm
    }

    /// The tuning in use.
    pub fn params(&self) -> &ImmParams {
        &self.params
    }

    /// Form the CV model's along-track z of each position report ([`Imm::cv_along_z`]).
    pub fn form_along_z(&mut self, wanted: bool) {
        self.along_wanted = wanted;
    }

    /// The age of this aircraft's velocity reports, s, learned from them
    /// ([`super::lag::VelocityLag`]): it replaces [`ImmParams::velocity_lag_s`].
    pub fn set_velocity_lag(&mut self, lag_s: f64) {
        if lag_s.is_finite() && lag_s >= 0.0 {
            self.velocity_lag_s = lag_s;
        }
    }

    /// `probabilities` restricted to the active modes and normalised (uniform over the
    /// active modes when they sum to nothing).
    fn normalised(&self, probabilities: &[f64; N_MODES]) -> [f64; N_MODES] {
        let mut mu = [0.0; N_MODES];
        for (i, m) in mu.iter_mut().enumerate() {
            if self.active[i] && probabilities[i].is_finite() {
                *m = probabilities[i].max(0.0);
            }
        }
        let sum: f64 = mu.iter().sum();
        if sum > 0.0 {
            mu.iter_mut().for_each(|m| *m /= sum);
        } else {
            let n = self.active.iter().filter(|e| **e).count().max(1) as f64;
            for (i, m) in mu.iter_mut().enumerate() {
                *m = if self.active[i] { 1.0 / n } else { 0.0 };
            }
        }
        mu
    }

    /// Narrows the model set to `modes` (within the enabled ones; all of them when that
    /// leaves none): a variable-structure IMM (Li & Bar-Shalom 1996, "Multiple-model
    /// estimation with variable structure", IEEE TAC 41(4); paper 003's VSIMM), whose
    /// caller knows which modes the data can be in. Takes effect at the next step:
    /// - the transition matrix is re-normalised over the active modes ([`Imm::transition`]);
    /// - a mode that leaves the set passes its whole probability on, by its switch weights,
    ///   to the modes that stay: the mixing folds its estimate into theirs, so the combined
    ///   estimate does not jump;
    /// - a mode that enters has probability 0 before the step, so it starts from the mixture
    ///   of the others (its own old state gets weight 0);
    /// - an inactive mode is not filtered and costs nothing.
    pub fn set_active(&mut self, modes: [bool; N_MODES]) {
        let mut active = [false; N_MODES];
        for ((a, m), e) in active.iter_mut().zip(modes).zip(self.params.enabled) {
            *a = m && e;
        }
        self.active = if active.contains(&true) {
            active
        } else {
            self.params.enabled
        };
    }

    /// Gives `mode` (an active one) probability `share` (0..=1) at the combined estimate:
    /// its state becomes the combined (x̂, P) and μ ← (1 − share) μ + share·e_mode. A
    /// component placed at the mixture's own mean with the mixture's covariance leaves the
    /// combined estimate exactly where it was, so this moves no estimate; it is how a
    /// manoeuvre the gate names enters an IMM that already runs, as [`Imm::reset`] with the
    /// gate's entry probabilities is how the IMM opens.
    pub fn enter(&mut self, mode: ImmMode, share: f64) {
        let i = mode.index();
        if !self.active.get(i).copied().unwrap_or(false) || !(0.0..=1.0).contains(&share) {
            return;
        }
        // Symmetric by construction ([`Imm::combined`]), and packing reads one triangle.
        let (x, p) = self.combined();
        let p = pack(&p);
        let states = self.states_mut();
        if let (Some(xs), Some(ps)) = (states.x.get_mut(i), states.p.get_mut(i)) {
            *xs = x;
            *ps = p;
        }
        let mut mu = self.mu;
        for m in mu.iter_mut() {
            *m *= 1.0 - share;
        }
        if let Some(m) = mu.get_mut(i) {
            *m += share;
        }
        self.mu = self.normalised(&mu);
    }

    /// The modes of the current model set ([`Imm::set_active`]).
    pub fn active(&self) -> &[bool; N_MODES] {
        &self.active
    }

    /// Restarts every mode from the same (x, P) with mode probabilities `mu` (normalised;
    /// the configured initial ones when `None`). The combined estimate is then exactly
    /// (x, P): a switch into the IMM does not move the estimate.
    pub fn reset(&mut self, x: &State9, p: &Matrix9, mu: Option<&[f64; N_MODES]>) {
        let states = self.states_mut();
        states.x = [*x; N_MODES];
        states.p = [pack(&kalman::symmetrise(p)); N_MODES];
        let initial = self.params.initial_probabilities;
        self.mu = self.normalised(mu.unwrap_or(&initial));
        self.divergence_runs = [0; N_MODES];
    }

    /// Drops the per-mode states until the next [`Imm::reset`] or [`Imm::step`] (struct
    /// doc): for a caller that will not read them before a reset.
    pub fn release(&mut self) {
        self.states = None;
    }

    /// The per-mode states (the initial ones while none are held).
    fn states(&self) -> &ModeStates {
        self.states.as_deref().unwrap_or(&INITIAL_STATES)
    }

    /// The per-mode states, allocated (initial) if none are held.
    fn states_mut(&mut self) -> &mut ModeStates {
        self.states
            .get_or_insert_with(|| Box::new(ModeStates::initial()))
    }

    /// Sets the turn rate magnitude of both CT models, rad/s.
    pub fn set_turn_rate(&mut self, rate_rad_s: f64) {
        if !rate_rad_s.is_finite() {
            return;
        }
        let rate = rate_rad_s.abs();
        for (mode, model) in ImmMode::ALL.iter().zip(self.models.iter_mut()) {
            if let Model::Ct(ct) = model {
                ct.omega_rad_s = if *mode == ImmMode::CtRight {
                    -rate
                } else {
                    rate
                };
            }
        }
    }

    /// The model of `mode`.
    pub fn model(&self, mode: ImmMode) -> &Model {
        &self.models[mode.index()]
    }

    /// Mode probabilities in [`ImmMode::ALL`] order.
    pub fn probabilities(&self) -> &[f64; N_MODES] {
        &self.mu
    }

    /// Probabilities in [`FlightMode::ALL`] order (CT = left + right).
    pub fn flight_mode_probabilities(&self) -> [f64; 5] {
        let m = &self.mu;
        [m[0], m[1], m[2] + m[3], m[4], m[5]]
    }

    /// The most probable mode.
    pub fn most_probable(&self) -> ImmMode {
        let mut best = ImmMode::Cv;
        for mode in ImmMode::ALL {
            if self.mu[mode.index()] > self.mu[best.index()] {
                best = mode;
            }
        }
        best
    }

    /// The CV model's nominal innovation blocks (position, velocity) at the last step;
    /// zeros when it was not updated.
    pub fn cv_blocks(&self) -> &[BlockStat; 2] {
        &self.cv_blocks
    }

    /// The CV model's along-track z of the last step's position report
    /// ([`super::tails::along_track_z`]); NaN for any other report.
    pub fn cv_along_z(&self) -> f64 {
        self.cv_along_z
    }

    /// Consecutive divergence events of `mode`'s filter up to the last step.
    pub fn divergence_run(&self, mode: ImmMode) -> u32 {
        self.divergence_runs.get(mode.index()).copied().unwrap_or(0)
    }

    /// The NIS of `mode`'s filter at the last step over the report's measured horizontal
    /// components ([`super::nis::horizontal`]; NaN before one, or when it failed).
    pub fn nis(&self, mode: ImmMode) -> f64 {
        self.nis.get(mode.index()).copied().unwrap_or(f64::NAN)
    }

    /// The most probable mode's term of the track's windowed NIS at the last step: its
    /// horizontal NIS ([`Imm::nis`]), or for a velocity report on a grid its quantile NIS
    /// ([`super::quantised`]). NaN before a step.
    pub fn published_nis(&self) -> f64 {
        self.published_nis
    }

    /// The two quantile residuals of [`Imm::published_nis`] (east, then north given east,
    /// in the grid's axes; [`super::quantised::OnGrid::residuals`]) when the last step's
    /// term was a velocity report's on a narrow claim: what a tail index of the velocity
    /// reports reads ([`super::tails`]). `None` for any other term.
    pub fn published_residuals(&self) -> Option<[f64; 2]> {
        self.published_residuals
            .iter()
            .all(|r| r.is_finite())
            .then_some(self.published_residuals)
    }

    /// Divergence events per mode over the estimator's life.
    pub fn divergence_events(&self) -> &[u64; N_MODES] {
        &self.divergence_events
    }

    /// Covariance of the last step's correction of the velocity, Σⱼ μⱼ Kⱼ Sⱼ Kⱼᵀ =
    /// Σⱼ μⱼ (Pⱼ(k|k−1) − Pⱼ(k|k)) over the velocity block: the report-to-report scatter of
    /// the estimated velocity (its error itself is strongly correlated from report to
    /// report).
    pub fn velocity_correction_cov(&self) -> &Matrix3<f64> {
        &self.velocity_correction_cov
    }

    /// The state and covariance of one mode's filter.
    pub fn mode_state(&self, mode: ImmMode) -> (State9, Matrix9) {
        let states = self.states();
        let i = mode.index();
        (states.x[i], unpack(&states.p[i]))
    }

    /// The Markov transition matrix over `dt_s` (module doc), from every enabled mode to
    /// the active ones ([`Imm::set_active`]): an active mode stays with probability
    /// exp(−dt/τ) and leaves by its switch weights over the other active modes; an inactive
    /// one leaves with certainty. With every enabled mode active (the default) it is the
    /// plain IMM's.
    pub fn transition(&self, dt_s: f64) -> [[f64; N_MODES]; N_MODES] {
        let mut pi = [[0.0; N_MODES]; N_MODES];
        let params = &*self.params;
        let active = &self.active;
        // The active modes, ascending: each row's sums and writes run over these alone
        // (the hybrid's IMM runs on a subset; filtering all six columns per row cost about
        // 120 more instructions a step).
        let mut set = [0_usize; N_MODES];
        let mut n_set = 0;
        for (j, _) in active.iter().enumerate().filter(|(_, a)| **a) {
            if let Some(slot) = set.get_mut(n_set) {
                *slot = j;
                n_set += 1;
            }
        }
        let set = set.get(..n_set).unwrap_or(&[]);
        // exp(−dt/τ) once per distinct τ (the defaults have two: CV's and the manoeuvres').
        let mut stays: [(f64, f64); N_MODES] = [(f64::NAN, 0.0); N_MODES];
        let mut n_stays = 0;
        for (i, row) in pi.iter_mut().enumerate() {
            if !params.enabled[i] {
                continue;
            }
            let tau = params.mean_sojourn_s[i];
            let known = stays
                .get(..n_stays)
                .and_then(|s| s.iter().find(|(t, _)| *t == tau));
            let stay = match known {
                _ if !active[i] => 0.0,
                Some(&(_, stay)) => stay,
                None => {
                    let stay = if tau > 0.0 {
                        (-dt_s.max(0.0) / tau).exp()
                    } else {
                        0.0
                    };
                    if let Some(slot) = stays.get_mut(n_stays) {
                        *slot = (tau, stay);
                        n_stays += 1;
                    }
                    stay
                }
            };
            let weights = &params.switch_weights[i];
            // Summed in ascending j, as before.
            let mut total = 0.0;
            for &j in set {
                if j != i {
                    total += weights[j].max(0.0);
                }
            }
            if total > 0.0 && stay.is_finite() {
                row[i] = stay;
                for &j in set {
                    if j != i {
                        row[j] = (1.0 - stay) * weights[j].max(0.0) / total;
                    }
                }
            } else if active[i] {
                row[i] = 1.0;
            } else {
                // No weight towards the set: leave for each active mode alike.
                let n = n_set.max(1) as f64;
                for &j in set {
                    row[j] = 1.0 / n;
                }
            }
        }
        pi
    }

    /// One IMM cycle for a report `dt_s` after the last one.
    ///
    /// A model whose update fails keeps its prediction and gets likelihood 0; if every
    /// model fails, the first error is returned and the estimator is left unchanged.
    pub fn step(&mut self, dt_s: f64, obs: &Observation) -> Result<(), TrackError> {
        if !dt_s.is_finite() || dt_s < 0.0 {
            return Err(TrackError::NonFinite("dt"));
        }
        let pi = self.transition(dt_s);
        let mut c_bar = [0.0; N_MODES];
        for (j, c) in c_bar.iter_mut().enumerate() {
            *c = (0..N_MODES).map(|i| pi[i][j] * self.mu[i]).sum();
        }
        let states = self.states();
        let mut x_new = states.x;
        let mut p_new = states.p;
        let mut log_post = [f64::NEG_INFINITY; N_MODES];
        let mut runs = [0; N_MODES];
        let mut corrections = [Matrix3::zeros(); N_MODES];
        let mut nis = [f64::NAN; N_MODES];
        // The report on a grid of the mode with the largest posterior weight so far: the one
        // published (kept as the loop goes, not one per mode).
        let mut best_grid: Option<(usize, f64, OnGrid)> = None;
        let mut cv_blocks = [BlockStat::default(); 2];
        let mut cv_along_z = f64::NAN;
        let mut first_error = None;
        let mut any_ok = false;
        let divergence = &self.params.divergence;
        for (j, (x_out, p_out)) in x_new.iter_mut().zip(p_new.iter_mut()).enumerate() {
            if !self.active[j] || c_bar[j] <= 0.0 {
                continue;
            }
            // Mixing: μᵢ|ⱼ = πᵢⱼ μᵢ / c̄ⱼ.
            let mut w = [0.0; N_MODES];
            for ((wi, row), mu) in w.iter_mut().zip(&pi).zip(self.mu) {
                *wi = row[j] * mu / c_bar[j];
            }
            // Mode-matched, divergence-guarded filtering, on the states the model keeps.
            let input = ModeInput {
                states,
                w: &w,
                dt_s,
                obs,
                divergence,
                previous_run: self.divergence_runs[j],
                velocity_lag_s: self.velocity_lag_s,
                along: self.along_wanted && j == ImmMode::Cv.index(),
            };
            let outcome = mode_step_of(&self.models[j], &input, x_out, p_out);
            match outcome {
                Ok(o) => {
                    any_ok = true;
                    runs[j] = o.run;
                    nis[j] = o.nis;
                    if j == ImmMode::Cv.index() {
                        cv_blocks = o.blocks;
                        cv_along_z = o.along_z;
                    }
                    corrections[j] = o.correction;
                    if o.log_likelihood.is_finite() {
                        log_post[j] = c_bar[j].ln() + o.log_likelihood;
                        if let Some(g) = o.on_grid {
                            if best_grid.is_none_or(|(_, lp, _)| log_post[j] > lp) {
                                best_grid = Some((j, log_post[j], g));
                            }
                        }
                    }
                }
                Err(e) => {
                    if first_error.is_none() {
                        first_error = Some(e);
                    }
                }
            }
        }
        if !any_ok {
            return Err(first_error.unwrap_or(TrackError::NotPositiveDefinite));
        }
        // Normalised below; no finite likelihood keeps the predicted probabilities.
        let mu = relative_weights(&log_post).unwrap_or(c_bar);
        self.cv_blocks = cv_blocks;
        self.cv_along_z = cv_along_z;
        let states = self.states_mut();
        states.x = x_new;
        states.p = p_new;
        self.mu = self.normalised(&mu);
        self.divergence_runs = runs;
        self.nis = nis;
        // Only the published mode's quantiles are taken (two inverse error functions).
        // The most probable mode is the one of the largest posterior weight (normalising keeps
        // the order), unless no likelihood was finite.
        let best = self.most_probable().index();
        let gaussian = nis.get(best).copied().unwrap_or(f64::NAN);
        (self.published_nis, self.published_residuals) = match best_grid {
            Some((j, _, g)) if j == best => {
                let r = g.residuals();
                (r.iter().map(|v| v * v).sum(), r)
            }
            _ => (gaussian, [f64::NAN; 2]),
        };
        self.velocity_correction_cov = corrections
            .iter()
            .zip(self.mu)
            .fold(Matrix3::zeros(), |acc, (c, mu)| acc + c * mu);
        // A step that met the criterion is the one whose run is not 0.
        for (events, run) in self.divergence_events.iter_mut().zip(runs) {
            *events = events.saturating_add(u64::from(run > 0));
        }
        Ok(())
    }

    /// The combined estimate x̂ = Σ μⱼ x̂ⱼ and P = Σ μⱼ [Pⱼ + (x̂ⱼ − x̂)(x̂ⱼ − x̂)ᵀ], symmetric by
    /// construction (each Pⱼ is): symmetrising it would change nothing.
    pub fn combined(&self) -> (State9, Matrix9) {
        self.combined_leading::<9>()
    }

    /// [`Imm::combined`] over the leading K states (K ≤ 9): the same entries, the rest not
    /// computed. An estimate reads position and velocity alone (K = 6: 21 covariance entries
    /// of 45).
    pub fn combined_leading<const K: usize>(&self) -> (SVector<f64, K>, SMatrix<f64, K, K>) {
        let states = self.states();
        let x = weighted_mean::<K>(&states.x, &self.mu);
        (x, spread_sum::<K>(&states.x, &states.p, &self.mu, &x))
    }

    /// The combined estimate x̂ = Σ μⱼ x̂ⱼ alone (no covariance: a tenth of the work).
    pub fn combined_state(&self) -> State9 {
        weighted_mean::<9>(&self.states().x, &self.mu)
    }

    /// The combined estimate predicted `dt_s` ahead by `model`, position and velocity (the
    /// leading 6 states and their covariance): what a published prediction reads. Computed
    /// on the states the model keeps ([`ResetTail`]: 6, or 8 with a horizontal
    /// acceleration), whose F is bordered by zeros in the 9-state one, so the numbers are
    /// those of predicting [`Imm::combined`] in 9 states (tested) for a fraction of the work.
    pub fn predicted_position_velocity(&self, model: &Model, dt_s: f64) -> (State6, Matrix6) {
        let mut out = (State6::zeros(), Matrix6::zeros());
        self.predicted_positions_velocities(model, std::iter::once(((), dt_s)), |(), x, p| {
            out = (*x, *p);
        });
        out
    }

    /// [`Imm::predicted_position_velocity`] for each `(tag, dt_s)` of `steps`, the combined
    /// estimate formed once for all of them: `each(tag, x, P)` in order.
    pub fn predicted_positions_velocities<T>(
        &self,
        model: &Model,
        steps: impl Iterator<Item = (T, f64)>,
        mut each: impl FnMut(T, &State6, &Matrix6),
    ) {
        match model {
            Model::Cv(m) => self.predicted_leading::<6, T>(m, steps, &mut each),
            Model::Ct(m) => self.predicted_leading::<6, T>(m, steps, &mut each),
            Model::Ch(m) => self.predicted_leading::<6, T>(m, steps, &mut each),
            Model::Ca(m) => self.predicted_leading::<8, T>(m, steps, &mut each),
            Model::Chca(m) => self.predicted_leading::<8, T>(m, steps, &mut each),
        }
    }

    fn predicted_leading<const K: usize, T>(
        &self,
        model: &impl ResetTail<K>,
        steps: impl Iterator<Item = (T, f64)>,
        each: &mut impl FnMut(T, &State6, &Matrix6),
    ) {
        let (x0, p0) = self.combined_leading::<K>();
        for (tag, dt_s) in steps {
            let (mut x, mut p) = (x0, p0);
            let (f, q) = model.leading_fq(dt_s);
            kalman::predict(&mut x, &mut p, &f, &q);
            each(
                tag,
                &kalman::rows::<6, _>(&x, 0),
                &kalman::block::<6, 6, _, _>(&p, 0, 0),
            );
        }
    }
}

/// Track initiation and re-initiation, shared by [`ImmTracker`] and the hybrid tracker.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InitParams {
    /// A report this long after the last one starts a new track, s. Default 60 s: after a
    /// minute without data a prediction of an airliner is off by kilometres if it turned,
    /// and a fresh start converges faster than a wrong state recovers.
    pub max_gap_s: f64,
    /// A velocity report at most this old initialises the velocity of a new track, s.
    /// Default 5 s.
    pub init_velocity_max_age_s: f64,
    /// 1-σ of the horizontal velocity of a track started without a velocity, m/s. Default
    /// 300 m/s: any subsonic aircraft.
    pub init_speed_sigma_mps: f64,
    /// 1-σ of the vertical rate of a track started without a velocity, m/s. Default 30 m/s.
    pub init_vrate_sigma_mps: f64,
    /// 1-σ of the acceleration of a new 9-state (mean zero), m/s². Default 2 m/s²: take-off
    /// acceleration and a standard-rate turn at 130 kt are both within 1σ.
    pub init_accel_sigma_mps2: f64,
}

impl Default for InitParams {
    fn default() -> Self {
        Self {
            max_gap_s: 60.0,
            init_velocity_max_age_s: 5.0,
            init_speed_sigma_mps: 300.0,
            init_vrate_sigma_mps: 30.0,
            init_accel_sigma_mps2: 2.0,
        }
    }
}

/// What [`Initiator::offer`] decided for a report.
#[derive(Clone, Debug, PartialEq)]
pub enum Start {
    /// The track runs: filter this report.
    Running,
    /// A new track starts at this report's time with this 9-state (acceleration zero).
    /// Boxed: every report's answer is moved out of a `Result`, and 720 bytes inline made
    /// each a memcpy (0.6 % of the default tracker's fleet replay instructions) for a state
    /// that comes once a track.
    New(Box<(State9, Matrix9)>),
    /// No track yet (report without a position): nothing to do.
    Waiting,
}

/// The initiation rules of the project's trackers (those of `track::cv` too): the first
/// report with a position starts the track, its velocity from the same report, or from a
/// velocity report at most `init_velocity_max_age_s` older (its variance grown by the CV
/// density times the age), or zero with a wide σ; a report more than `max_gap_s` after the
/// track starts a new one; a report older than the track is refused.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Initiator {
    params: InitParams,
    /// Horizontal and vertical CV densities used to age a pending velocity, m²/s³.
    age_q_m2ps3: [f64; 2],
    /// Time of the track, `None` before initiation.
    track_t_s: Option<f64>,
    pending_velocity: Option<(f64, Observed)>,
    reinitialisations: u64,
}

fn observed_is_finite(o: &Observed) -> bool {
    o.value.iter().chain(o.cov.iter()).all(|v| v.is_finite())
}

impl Initiator {
    /// No track yet; `cv` ages pending velocities.
    pub fn new(params: InitParams, cv: &Cv) -> Self {
        Self {
            params,
            age_q_m2ps3: [cv.q_h_m2ps3, cv.q_v_m2ps3],
            track_t_s: None,
            pending_velocity: None,
            reinitialisations: 0,
        }
    }

    /// Time of the track.
    pub fn track_t_s(&self) -> Option<f64> {
        self.track_t_s
    }

    /// Times a long gap restarted the track.
    pub fn reinitialisations(&self) -> u64 {
        self.reinitialisations
    }

    /// Records that the track now stands at `t_s`.
    pub fn advance(&mut self, t_s: f64) {
        self.track_t_s = Some(t_s);
    }

    /// Validates a report and decides whether it starts, continues or waits for a track.
    pub fn offer(&mut self, m: &Measurement) -> Result<Start, TrackError> {
        if !m.t_s.is_finite()
            || !m
                .position
                .iter()
                .chain(m.velocity.iter())
                .all(observed_is_finite)
        {
            return Err(TrackError::NonFinite("measurement"));
        }
        if let Some(track_t_s) = self.track_t_s {
            if m.t_s < track_t_s {
                return Err(TrackError::OutOfOrder {
                    t_s: m.t_s,
                    track_t_s,
                });
            }
            if m.t_s - track_t_s <= self.params.max_gap_s {
                return Ok(Start::Running);
            }
            self.track_t_s = None;
            self.reinitialisations = self.reinitialisations.saturating_add(1);
        }
        match (&m.position, &m.velocity) {
            (Some(pos), vel) => {
                let (x, p) = self.initial_state(m.t_s, pos, vel.as_ref());
                self.track_t_s = Some(m.t_s);
                self.pending_velocity = None;
                Ok(Start::New(Box::new((x, p))))
            }
            (None, Some(vel)) => {
                if self.pending_velocity.is_none_or(|(tv, _)| m.t_s >= tv) {
                    self.pending_velocity = Some((m.t_s, *vel));
                }
                Ok(Start::Waiting)
            }
            (None, None) => Ok(Start::Waiting),
        }
    }

    fn initial_state(
        &self,
        t_s: f64,
        position: &Observed,
        velocity: Option<&Observed>,
    ) -> (State9, Matrix9) {
        let mut x = State9::zeros();
        let mut p = Matrix9::zeros();
        x.fixed_rows_mut::<3>(POS).copy_from(&position.value);
        p.fixed_view_mut::<3, 3>(POS, POS).copy_from(&position.cov);
        let recent = self
            .pending_velocity
            .filter(|(tv, _)| (0.0..=self.params.init_velocity_max_age_s).contains(&(t_s - tv)));
        let (v, v_cov) = match (velocity, recent) {
            (Some(v), _) => (v.value, v.cov),
            (None, Some((tv, v))) => {
                let age_s = t_s - tv;
                let mut cov = v.cov;
                for axis in 0..3 {
                    cov[(axis, axis)] += self.age_q_m2ps3[usize::from(axis == 2)] * age_s;
                }
                (v.value, cov)
            }
            (None, None) => {
                let (h, u) = (
                    self.params.init_speed_sigma_mps.powi(2),
                    self.params.init_vrate_sigma_mps.powi(2),
                );
                (
                    Vector3::zeros(),
                    Matrix3::from_diagonal(&Vector3::new(h, h, u)),
                )
            }
        };
        x.fixed_rows_mut::<3>(VEL).copy_from(&v);
        p.fixed_view_mut::<3, 3>(VEL, VEL).copy_from(&v_cov);
        let a2 = self.params.init_accel_sigma_mps2.powi(2);
        p.fixed_view_mut::<3, 3>(ACC, ACC)
            .copy_from(&(Matrix3::identity() * a2));
        (x, kalman::symmetrise(&p))
    }
}

/// The labels of an estimate: flight mode, turn direction and the I062/200 movement axes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Labels {
    /// Flight mode.
    pub mode: FlightMode,
    /// Turn direction when the mode is CT.
    pub turn: Option<TurnDirection>,
    /// Transversal movement.
    pub lateral: Lateral,
    /// Longitudinal movement.
    pub speed: SpeedTrend,
    /// Vertical movement.
    pub vertical: VerticalTrend,
}

impl Labels {
    /// Straight and level at constant speed.
    pub const CV: Labels = Labels {
        mode: FlightMode::Cv,
        turn: None,
        lateral: Lateral::Straight,
        speed: SpeedTrend::Constant,
        vertical: VerticalTrend::Level,
    };
}

/// Filter-level facts of an estimate besides the state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct EstimateInfo {
    pub labels: Labels,
    pub mode_probabilities: [f64; 5],
    pub filter: &'static str,
    pub diverging: bool,
    pub divergence_events: u64,
    pub outlier_positions: u64,
    pub nis: Option<super::nis::NisStat>,
}

/// An [`Estimate`] from the position/velocity part of a state and covariance (6 or 9 states).
pub(crate) fn estimate_of<const N: usize>(
    t_s: f64,
    x: &nalgebra::SVector<f64, N>,
    p: &nalgebra::SMatrix<f64, N, N>,
    info: &EstimateInfo,
) -> Estimate {
    Estimate {
        t_s,
        pos_m: kalman::rows::<3, _>(x, POS),
        vel_mps: kalman::rows::<3, _>(x, VEL),
        pos_cov_m2: kalman::block::<3, 3, _, _>(p, POS, POS),
        vel_cov_m2ps2: kalman::block::<3, 3, _, _>(p, VEL, VEL),
        mode: info.labels.mode,
        mode_probabilities: info.mode_probabilities,
        filter: info.filter,
        diverging: info.diverging,
        divergence_events: info.divergence_events,
        outlier_positions: info.outlier_positions,
        turn: info.labels.turn,
        lateral: info.labels.lateral,
        speed: info.labels.speed,
        vertical: info.labels.vertical,
        nis: info.nis,
    }
}

/// Name of the plain IMM tracker.
pub const IMM_NAME: &str = "imm";

/// Tuning of [`ImmTracker`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImmTrackerParams {
    /// The IMM.
    pub imm: ImmParams,
    /// Initiation.
    pub init: InitParams,
    /// Movement-axis thresholds read from the combined state.
    pub axes: AxisThresholds,
    /// The measurement noise learned per aircraft ([`super::noise`]), from the CV model's
    /// innovations while CV holds at least [`LEARN_CV_PROBABILITY`].
    pub noise: NoiseParams,
    /// Learn how much older the aircraft's velocity reports are than its positions
    /// ([`super::lag::VelocityLag`]) and let the CT modes allow for it, as the hybrid does
    /// (`HybridParams::learn_velocity_lag`); until a lag is learnt,
    /// [`ImmParams::velocity_lag_s`]. Default true.
    pub learn_velocity_lag: bool,
    /// Position reports out of their time set aside ([`super::outlier`]), judged by the
    /// held mode's innovation while that mode holds at least [`LEARN_CV_PROBABILITY`] and
    /// the last velocity report, within 3 s, fitted it: the velocity reports vouch for the
    /// flight the mode predicts (a straight line under CV, the turn under CT), as the
    /// hybrid's gate does for its CV filter. Default on.
    pub outliers: OutlierParams,
    /// A position report's term of the windowed NIS read under a Student-t claim of the
    /// aircraft's tail index ([`super::tails`]), learned from the CV model's along-track
    /// innovation while CV holds at least [`LEARN_CV_PROBABILITY`]. Default on.
    pub tails: TailParams,
    /// The same for a velocity report on a narrow claim, its quantile residuals read under
    /// the tail index of the aircraft's velocity reports, learned from them while CV holds
    /// at least [`LEARN_CV_PROBABILITY`] and is the published mode. Default on.
    pub velocity_tails: TailParams,
}

/// The plain IMM's covariance-matching window, reports, for positions and velocities alike
/// ([`NoiseParams::window`]; the hybrid's default is shorter). It learns only while its CV
/// mode holds [`LEARN_CV_PROBABILITY`], and at 30 AFR34ZG's steady windows of its NIS fell
/// from 65.6 to 52.0 % in band (docs/evaluation.md, "A shorter memory").
pub const IMM_NOISE_WINDOW_REPORTS: f64 = 100.0;

impl Default for ImmTrackerParams {
    fn default() -> Self {
        Self {
            imm: ImmParams::default(),
            init: InitParams::default(),
            axes: AxisThresholds::default(),
            noise: NoiseParams {
                window: IMM_NOISE_WINDOW_REPORTS,
                velocity_window: IMM_NOISE_WINDOW_REPORTS,
                ..NoiseParams::default()
            },
            learn_velocity_lag: true,
            outliers: OutlierParams::default(),
            tails: TailParams::default(),
            velocity_tails: TailParams::default(),
        }
    }
}

/// Velocity reports older than this no longer vouch for the held mode's flight (the
/// outlier test's condition, [`HeldModeFit`]), s: the hybrid's `velocity_stale_s`
/// default, six missed reports.
const VELOCITY_CURRENT_S: f64 = 3.0;

/// A velocity report vouches for the flight the held mode predicts (a straight line under
/// CV, the turn under CT) when that mode's horizontal NIS on it is under this: χ²(2)'s 99 %
/// point, −2 ln 0.01. A turn's or a speed change's first reports exceed it under CV before
/// CV's probability falls, and a roll-out's under CT.
const VELOCITY_FITS_MODE_NIS: f64 = 9.21;

/// The plain IMM learns the measurement noise only while its CV mode is this probable: the
/// other models' innovations, and CV's in a manoeuvre, carry model error.
pub const LEARN_CV_PROBABILITY: f64 = 0.9;

/// What an IMM's velocity reports vouch for ([`super::outlier`]): the last one's feed time,
/// the mode held before it, and whether that mode's horizontal innovation on it was within
/// χ²(2)'s 99 % point (`VELOCITY_FITS_MODE_NIS`). A position far off the held mode's
/// prediction may be set aside while that mode holds at least [`LEARN_CV_PROBABILITY`] and
/// the last velocity report, within 3 s (`VELOCITY_CURRENT_S`), fitted it: a straight line
/// under CV, the turn under CT. What the plain `imm` and the hybrid's IMM branch share.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HeldModeFit {
    last_velocity: Option<(f64, ImmMode, bool)>,
}

impl HeldModeFit {
    /// Steps `imm` on `obs` at `t_s`, or sets the report aside (`Ok(false)`, `imm` as it
    /// was) when it is a position the velocity reports vouch against and `gate` sets aside.
    pub fn step(
        &mut self,
        imm: &mut Imm,
        gate: &mut OutlierGate,
        params: &OutlierParams,
        t_s: f64,
        dt_s: f64,
        obs: &Observation,
    ) -> Result<bool, TrackError> {
        let held = imm.most_probable();
        let position_only = matches!(obs, Observation::Position(_));
        let vouched = imm.probabilities()[held.index()] >= LEARN_CV_PROBABILITY
            && self.last_velocity.is_some_and(|(t, mode, fits)| {
                fits && mode == held && t_s - t <= VELOCITY_CURRENT_S
            });
        // The step runs in place; a report that may be set aside is stepped from a copy
        // kept to go back to (about 2.6 KB, only then).
        let before = (position_only && gate.may_set_aside(vouched, params)).then(|| imm.clone());
        imm.step(dt_s, obs)?;
        if !position_only {
            let fits = imm.nis(held) < VELOCITY_FITS_MODE_NIS;
            self.last_velocity = Some((t_s, held, fits));
        }
        if position_only && gate.set_aside(imm.nis(held), vouched, params) {
            if let Some(before) = before {
                *imm = before;
                return Ok(false);
            }
        }
        Ok(true)
    }
}

/// Thresholds turning a state into the I062/200 movement axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisThresholds {
    /// |along-track acceleration| above which the speed is Increasing/Decreasing, m/s².
    /// Default 0.3 m/s²: above the ~0.1 m/s² of speed-hold wander, below the 0.5–2 m/s² of
    /// deliberate speed changes.
    pub along_track_accel_mps2: f64,
    /// |vertical rate| above which the aircraft Climbs/Descends, m/s. Default 1.5 m/s
    /// (≈ 300 ft/min): five times the 64 ft/min resolution of the ADS-B vertical rate, and
    /// the rate below which ATC considers an aircraft level-ish.
    pub vertical_rate_mps: f64,
}

impl Default for AxisThresholds {
    fn default() -> Self {
        Self {
            along_track_accel_mps2: 0.3,
            vertical_rate_mps: 1.5,
        }
    }
}

/// The plain IMM as a tracker ("imm"): always on, the label is the most probable mode, the
/// movement axes come from that mode (turn) and from the combined state (along-track
/// acceleration, vertical rate). For comparison with the hybrid tracker, like paper 002's
/// RMIMM.
#[derive(Clone, Debug, PartialEq)]
pub struct ImmTracker {
    params: ImmTrackerParams,
    imm: Imm,
    init: Initiator,
    nis: super::nis::NisWindow,
    /// The aircraft's learned measurement noise, kept across restarts.
    noise: NoiseLearner,
    /// The age of its velocity reports, learned (`learn_velocity_lag`); boxed, made at the
    /// first report, kept across restarts.
    lag: Option<Box<super::lag::VelocityLag>>,
    /// Position reports set aside ([`super::outlier`]), kept across restarts.
    outliers: OutlierGate,
    /// The tail index of its position innovations ([`super::tails`]), kept across restarts.
    tails: TailIndex,
    /// The tail index of its velocity reports' quantile residuals, kept the same way.
    velocity_tails: TailIndex,
    /// What its velocity reports vouch for: the IMM's word for "the velocity reports show
    /// the flight the held mode predicts", which the hybrid's CV filter takes from its gate.
    held_fit: HeldModeFit,
}

impl Default for ImmTracker {
    fn default() -> Self {
        Self::new(ImmTrackerParams::default())
    }
}

impl ImmTracker {
    /// A tracker with no track yet.
    pub fn new(params: ImmTrackerParams) -> Self {
        let mut imm = Imm::new(params.imm);
        imm.form_along_z(params.tails.enabled);
        Self {
            params,
            imm,
            init: Initiator::new(params.init, &params.imm.models.cv),
            nis: super::nis::NisWindow::default(),
            noise: NoiseLearner::default(),
            lag: None,
            outliers: OutlierGate::default(),
            tails: TailIndex::default(),
            velocity_tails: TailIndex::default(),
            held_fit: HeldModeFit::default(),
        }
    }

    /// The estimator.
    pub fn imm(&self) -> &Imm {
        &self.imm
    }

    /// Gives `m` to the velocity-lag learner, and the IMM the lag to use
    /// ([`super::lag::learn`], as the hybrid does).
    fn learn_lag(&mut self, m: &Measurement) {
        let track_t_s = self.init.track_t_s();
        let configured_s = self.params.imm.velocity_lag_s;
        if let Some(lag_s) = super::lag::learn(&mut self.lag, m, track_t_s, configured_s) {
            self.imm.set_velocity_lag(lag_s);
        }
    }

    fn info(&self) -> EstimateInfo {
        let best = self.imm.most_probable();
        let x = self.imm.combined_state();
        let labels = labels_of_mode(best, &x, &self.params.axes);
        EstimateInfo {
            labels,
            mode_probabilities: self.imm.flight_mode_probabilities(),
            filter: IMM_NAME,
            // A divergence the suppressor acts on (`confirm` events in a row), not each
            // chance event: as the hybrid publishes it.
            diverging: self.imm.divergence_run(best) >= self.params.imm.divergence.confirm,
            divergence_events: self.imm.divergence_events()[best.index()],
            outlier_positions: self.outliers.count(),
            nis: self.nis.stat(),
        }
    }
}

/// Labels for `mode`, the speed and vertical axes read from the state `x`.
pub(crate) fn labels_of_mode(mode: ImmMode, x: &State9, axes: &AxisThresholds) -> Labels {
    let (ve, vn, vu) = (x[VEL], x[VEL + 1], x[VEL + 2]);
    let speed_h = ve.hypot(vn);
    let along = if speed_h > 1.0 {
        (x[ACC] * ve + x[ACC + 1] * vn) / speed_h
    } else {
        0.0
    };
    let speed = if along > axes.along_track_accel_mps2 {
        SpeedTrend::Increasing
    } else if along < -axes.along_track_accel_mps2 {
        SpeedTrend::Decreasing
    } else {
        SpeedTrend::Constant
    };
    let vertical = if vu > axes.vertical_rate_mps {
        VerticalTrend::Climb
    } else if vu < -axes.vertical_rate_mps {
        VerticalTrend::Descent
    } else {
        VerticalTrend::Level
    };
    let lateral = match mode.turn() {
        Some(TurnDirection::Left) => Lateral::Left,
        Some(TurnDirection::Right) => Lateral::Right,
        None => Lateral::Straight,
    };
    Labels {
        mode: mode.flight_mode(),
        turn: mode.turn(),
        lateral,
        speed,
        vertical,
    }
}

impl Tracker for ImmTracker {
    /// A new track; the learned measurement noise and velocity lag are kept (they are the
    /// aircraft's).
    fn reset(&mut self) {
        let noise = self.noise;
        let outliers = self.outliers;
        let lag = super::lag::kept_over_restart(self.lag.take());
        let (tails, velocity_tails) = (self.tails, self.velocity_tails);
        *self = Self::new(self.params);
        self.noise = noise;
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
        IMM_NAME
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
                self.imm.reset(x, p, None);
                self.nis.clear();
                self.noise.forget_position();
                Ok(())
            }
            Start::Running => {
                let up = local_up(&kalman::rows::<3, _>(&self.imm.combined_state(), POS));
                let m = &self.noise.prepare(m, &up);
                let Some(obs) = Observation::of(m.position.as_ref(), m.velocity.as_ref()) else {
                    return Ok(());
                };
                let dt_s = m.t_s - track_t_s.unwrap_or(m.t_s);
                // CV's probability before this report: a manoeuvre that starts here shows
                // first as CV's innovation, and is learned from once at most.
                let steady = self.imm.probabilities()[ImmMode::Cv.index()] >= LEARN_CV_PROBABILITY;
                let position_only = matches!(obs, Observation::Position(_));
                if !self.held_fit.step(
                    &mut self.imm,
                    &mut self.outliers,
                    &self.params.outliers,
                    m.t_s,
                    dt_s,
                    &obs,
                )? {
                    return Ok(());
                }
                if steady {
                    let [pos, vel] = *self.imm.cv_blocks();
                    self.noise.learn(&pos, &vel, &self.params.noise);
                    if m.position.is_some() {
                        let vel = kalman::rows::<3, _>(&self.imm.combined_state(), VEL);
                        self.noise
                            .learn_position_step(m, &vel, &up, &self.params.noise);
                    }
                }
                self.init.advance(m.t_s);
                // A position's term, and a velocity's on a narrow claim, under the
                // aircraft's tail index of its kind, read before it learns, where CV is the
                // published mode (as the hybrid's CV filter: a manoeuvre's model error reads
                // as what it is).
                let cv_published = self.imm.most_probable() == ImmMode::Cv;
                let residuals = self.imm.published_residuals().filter(|_| cv_published);
                let published = if position_only && cv_published {
                    self.tails.nis(self.imm.published_nis())
                } else if residuals.is_some() {
                    self.velocity_tails.nis(self.imm.published_nis())
                } else {
                    self.imm.published_nis()
                };
                if steady && position_only {
                    self.tails.learn(self.imm.cv_along_z(), &self.params.tails);
                }
                if let (true, true, Some(rs)) =
                    (steady, self.params.velocity_tails.enabled, residuals)
                {
                    for r in rs {
                        self.velocity_tails.learn(r, &self.params.velocity_tails);
                    }
                }
                self.nis.push(
                    published,
                    super::nis::horizontal_dof(m.position.as_ref(), m.velocity.as_ref()),
                );
                Ok(())
            }
        }
    }

    fn estimate(&self) -> Option<Estimate> {
        let t_s = self.init.track_t_s()?;
        let (x, p) = self.imm.combined_leading::<6>();
        Some(
            self.noise
                .with_position_bias(estimate_of(t_s, &x, &p, &self.info())),
        )
    }

    fn has_track(&self) -> bool {
        self.init.track_t_s().is_some()
    }

    /// Extrapolates the combined estimate by the most probable mode's model (paper 002
    /// §1.3), its process noise added.
    fn predict(&self, t_s: f64) -> Option<Estimate> {
        let track_t_s = self.init.track_t_s()?;
        let dt_s = t_s - track_t_s;
        if !dt_s.is_finite() || dt_s < 0.0 {
            return None;
        }
        let (x, p) = self
            .imm
            .predicted_position_velocity(self.imm.model(self.imm.most_probable()), dt_s);
        Some(
            self.noise
                .with_position_bias(estimate_of(t_s, &x, &p, &self.info())),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::UNMEASURED_VARIANCE;

    /// A velocity report `lag` seconds old, turned by [`aged_for_turn`], is the CT model's
    /// velocity now: the model's own F carries the report's velocity over the lag to the
    /// same vector (to rounding), its covariance turned with it. Nothing turns without a
    /// lag, a rate, or a velocity.
    #[test]
    fn a_late_velocity_is_turned_on_by_the_turn() {
        use crate::track::models::{Ct, ResetTail};
        for (left, rate_dps, lag_s) in [(true, 3.0, 1.0), (false, 2.0, 1.07), (true, 0.5, 0.3)] {
            let ct = Ct::turning(left, rate_dps * std::f64::consts::PI / 180.0);
            // The state a lag ago: heading north-east at 140 m/s, climbing 2 m/s.
            let then = State6::from([0.0, 0.0, 3000.0, 99.0, 99.0, 2.0]);
            let (f, _) = ResetTail::<6>::leading_fq(&ct, lag_s);
            let now = f * then;
            let cov = Matrix3::new(4.0, 1.0, 0.5, 1.0, 2.0, 0.25, 0.5, 0.25, 9.0);
            let report = Observed {
                value: then.fixed_rows::<3>(3).into_owned(),
                cov,
                grid: None,
            };
            let Some(Observation::Velocity(turned)) =
                aged_for_turn(&Observation::Velocity(report), ct.omega_rad_s, lag_s)
            else {
                panic!("a turned velocity");
            };
            let want = now.fixed_rows::<3>(3).into_owned();
            assert!((turned.value - want).norm() < 1e-9, "{turned:?} {want}");
            // The horizontal variance is turned (its trace kept), the vertical untouched.
            assert!((turned.cov.trace() - cov.trace()).abs() < 1e-12);
            assert_eq!(turned.cov[(2, 2)], cov[(2, 2)]);
            assert!((turned.cov - turned.cov.transpose()).norm() < 1e-12);
            // Both: the position stays as it was.
            let position = Observed {
                value: Vector3::new(1.0, 2.0, 3.0),
                cov: Matrix3::identity(),
                grid: None,
            };
            let both = aged_for_turn(&Observation::Both(position, report), ct.omega_rad_s, lag_s);
            assert_eq!(both, Some(Observation::Both(position, turned)));
            assert_eq!(
                aged_for_turn(&Observation::Position(position), ct.omega_rad_s, lag_s),
                None
            );
            assert_eq!(
                aged_for_turn(&Observation::Velocity(report), ct.omega_rad_s, 0.0),
                None
            );
            assert_eq!(
                aged_for_turn(&Observation::Velocity(report), 0.0, lag_s),
                None
            );
        }
    }

    /// Each mode's step on its model's leading states ([`mode_step`]) is bit for bit the
    /// 9-state one ([`mode_step_full`]): state, covariance, NIS, likelihood, divergence run
    /// and velocity correction, on random mixtures, steps and reports, including reports far
    /// enough off to diverge and be suppressed, and velocity reports without a vertical rate.
    #[test]
    fn the_reduced_mode_step_is_the_9_state_step() {
        use rand::rngs::StdRng;
        use rand::{Rng, SeedableRng};
        let mut rng = StdRng::seed_from_u64(23);
        let mut suppressed = 0;
        let mut along = 0u32;
        let mut errors = 0;
        for case in 0..3000 {
            // Mode states as an IMM holds them: the reset tails at (0, σ_r²) for some modes,
            // anything for others, each covariance symmetric positive definite.
            let states = ModeStates {
                x: std::array::from_fn(|i| {
                    State9::from_fn(|k, _| {
                        let scale = [3e4, 3e4, 3e3, 250.0, 250.0, 20.0, 2.0, 2.0, 1.0][k];
                        if i % 2 == 0 && k >= ACC {
                            0.0
                        } else {
                            rng.gen_range(-scale..scale)
                        }
                    })
                }),
                p: std::array::from_fn(|_| {
                    let l = Matrix9::from_fn(|i, j| {
                        if i >= j {
                            rng.gen_range(-3.0..3.0)
                        } else {
                            0.0
                        }
                    });
                    pack(&kalman::symmetrise(
                        &(l * l.transpose() + Matrix9::identity()),
                    ))
                }),
            };
            let mut w: [f64; N_MODES] = std::array::from_fn(|_| rng.gen_range(0.0..1.0));
            w[rng.gen_range(0..N_MODES)] = 0.0;
            let total: f64 = w.iter().sum();
            w.iter_mut().for_each(|v| *v /= total);
            let dt_s = [0.0, 0.1, 0.5, 1.0, 2.7, 12.0][case % 6];
            let off = if case % 5 == 0 { 400.0 } else { 20.0 };
            let position = Observed {
                value: Vector3::from_fn(|_, _| rng.gen_range(-3e4..3e4)),
                cov: Matrix3::from_diagonal(&Vector3::new(25.0, 25.0, 100.0)),
                grid: None,
            };
            let mut velocity = Observed {
                value: Vector3::from_fn(|_, _| rng.gen_range(-off..off)),
                cov: Matrix3::from_diagonal(&Vector3::new(0.3, 0.3, 1.0)),
                grid: None,
            };
            if case % 3 == 0 {
                velocity.cov[(2, 2)] = UNMEASURED_VARIANCE;
            }
            let obs = match case % 4 {
                0 => Observation::Position(position),
                1 => Observation::Velocity(velocity),
                _ => Observation::Both(position, velocity),
            };
            let run = [0, 3, 4][case % 3];
            let mut models = ModelSet::default().models();
            let omega = rng.gen_range(-0.2..0.2);
            for m in models.iter_mut() {
                if let Model::Ct(ct) = m {
                    ct.omega_rad_s = omega;
                }
            }
            let divergence = DivergenceParams::default();
            for model in &models {
                let (mut x_r, mut p_r) = (State9::zeros(), [0.0; PACKED9]);
                let (mut x_f, mut p_f) = (State9::zeros(), [0.0; PACKED9]);
                let input = ModeInput {
                    states: &states,
                    w: &w,
                    dt_s,
                    obs: &obs,
                    divergence: &divergence,
                    previous_run: run,
                    velocity_lag_s: 0.0,
                    along: true,
                };
                let reduced = mode_step_of(model, &input, &mut x_r, &mut p_r);
                let full = mode_step_full(model.as_dyn(), &input, &mut x_f, &mut p_f);
                // -0.0 and 0.0 are one value to every later operation.
                assert!(x_r == x_f, "case {case} {model:?}: {x_r} vs {x_f}");
                assert!(p_r == p_f, "case {case} {model:?}: covariance");
                match (reduced, full) {
                    (Ok(r), Ok(f)) => {
                        assert_eq!(
                            (r.run, r.blocks, r.correction),
                            (f.run, f.blocks, f.correction),
                            "case {case}"
                        );
                        assert!(r.nis == f.nis || (r.nis.is_nan() && f.nis.is_nan()));
                        assert_eq!(r.log_likelihood, f.log_likelihood);
                        // The along-track z of a position report, on the same prediction.
                        let is_position = matches!(obs, Observation::Position(_));
                        assert_eq!(r.along_z.is_nan(), f.along_z.is_nan() || !is_position);
                        assert!(
                            !is_position
                                || f.along_z.is_nan()
                                || (r.along_z - f.along_z).abs() <= 1e-9 * f.along_z.abs().max(1.0),
                            "case {case}: {} vs {}",
                            r.along_z,
                            f.along_z
                        );
                        along += u32::from(r.along_z.is_finite());
                        suppressed += u32::from(r.run >= divergence.confirm);
                    }
                    (Err(r), Err(f)) => {
                        assert_eq!(r, f);
                        errors += 1;
                    }
                    (r, f) => panic!("case {case}: {:?} vs {:?}", r.is_ok(), f.is_ok()),
                }
            }
        }
        // The suppressed path was exercised, and the along-track z formed.
        assert!(suppressed > 100, "{suppressed} suppressed, {errors} errors");
        assert!(along > 100, "{along} along-track z");
    }

    /// The triangular in-place spread sum is bit for bit the full matrix sum it replaced
    /// (for the exactly symmetric covariances the estimator holds).
    #[test]
    fn spread_sum_is_the_full_sum() {
        use rand::rngs::StdRng;
        use rand::{Rng, SeedableRng};
        let mut rng = StdRng::seed_from_u64(17);
        for _ in 0..200 {
            let x: [State9; N_MODES] =
                std::array::from_fn(|_| State9::from_fn(|_, _| rng.gen_range(-1e4..1e4)));
            let p: [Matrix9; N_MODES] = std::array::from_fn(|_| {
                let l = Matrix9::from_fn(|_, _| rng.gen_range(-10.0..10.0));
                kalman::symmetrise(&(l * l.transpose()))
            });
            let mut w: [f64; N_MODES] = std::array::from_fn(|_| rng.gen_range(0.0..1.0));
            w[rng.gen_range(0..N_MODES)] = 0.0;
            let mean = State9::from_fn(|_, _| rng.gen_range(-1e4..1e4));
            let mut full = Matrix9::zeros();
            for ((xi, pi), wi) in x.iter().zip(&p).zip(w) {
                if wi > 0.0 {
                    let d = xi - mean;
                    full += (pi + d * d.transpose()) * wi;
                }
            }
            assert_eq!(spread_sum(&x, &p.map(|pi| pack(&pi)), &w, &mean), full);
            // Packing is lossless for a symmetric matrix.
            assert!(p.iter().all(|pi| unpack::<9>(&pack(pi)) == *pi));
        }
    }

    fn observed(value: Vector3<f64>, sigma: f64) -> Observed {
        Observed {
            value,
            cov: Matrix3::identity() * sigma * sigma,
            grid: None,
        }
    }

    #[test]
    fn relative_weights_survive_what_linear_space_does_not() {
        // e^-1e5 underflows to 0 in f64; the shifted weights keep the ratio.
        let v = [-1.0e5, -1.0e5 - 2f64.ln(), f64::NEG_INFINITY];
        let w = relative_weights(&v).unwrap_or_default();
        assert_eq!(w[0], 1.0);
        assert!((w[1] - 0.5).abs() < 1e-9); // -1e5 - ln 2 is rounded to 1e5's ulp
        assert_eq!(w[2], 0.0);
        assert!((-1.0e5f64).exp() == 0.0);
        assert_eq!(relative_weights(&[f64::NEG_INFINITY; 3]), None);
        // A NaN log-weight stays NaN (the normalisation then gives its mode nothing) and
        // does not become the shift.
        let w = relative_weights(&[f64::NAN, 1.0]).unwrap_or_default();
        assert!(w[0].is_nan() && w[1] == 1.0);
    }

    #[test]
    fn transition_matrix_is_stochastic_and_follows_dt() {
        let imm = Imm::new(ImmParams::default());
        for dt in [0.0, 0.01, 0.5, 10.0, 1e6] {
            let pi = imm.transition(dt);
            for row in pi {
                assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                assert!(row.iter().all(|p| *p >= 0.0));
            }
        }
        // CV stays with exp(-0.5/30) over half a second; a turn with exp(-0.5/20).
        let pi = imm.transition(0.5);
        assert!((pi[0][0] - (-0.5f64 / 30.0).exp()).abs() < 1e-15);
        assert!((pi[2][2] - (-0.5f64 / 20.0).exp()).abs() < 1e-15);
        // From CT left: back to CV 4/(4 + 1 + 0.25 + 1 + 1) of the switches.
        let leave = 1.0 - (-0.5f64 / 20.0).exp();
        assert!((pi[2][0] - leave * 4.0 / 7.25).abs() < 1e-15);
        assert!((pi[2][3] - leave * 0.25 / 7.25).abs() < 1e-15);
        // dt = 0: the identity.
        let pi = imm.transition(0.0);
        assert!((0..N_MODES).all(|i| pi[i][i] == 1.0));
    }

    /// A narrowed model set (a variable-structure IMM): every row still sums to 1, only the
    /// active modes are reached, an inactive mode leaves with certainty by its switch
    /// weights over the active ones, and widening the set again gives the plain matrix.
    #[test]
    fn a_narrowed_set_transitions_only_into_its_modes() {
        let mut imm = Imm::new(ImmParams::default());
        let plain = imm.transition(0.5);
        // CV, CA and both turns (what the hybrid runs in a level turn).
        imm.set_active([true, true, true, true, false, false]);
        let pi = imm.transition(0.5);
        for (i, row) in pi.iter().enumerate() {
            assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12, "row {i}");
            assert!(
                row[4] == 0.0 && row[5] == 0.0,
                "row {i} reaches an inactive mode"
            );
        }
        // CT left stays as before; it leaves over CV, CA and CT right by 4 : 1 : 0.25.
        let leave = 1.0 - (-0.5f64 / 20.0).exp();
        assert_eq!(pi[2][2], plain[2][2]);
        assert!((pi[2][0] - leave * 4.0 / 5.25).abs() < 1e-15);
        assert!((pi[2][1] - leave * 1.0 / 5.25).abs() < 1e-15);
        // CH, inactive, leaves with certainty: to CV 4/6, to CA and each turn 1/6.
        assert_eq!(pi[4][4], 0.0);
        assert!((pi[4][0] - 4.0 / 7.0).abs() < 1e-15);
        assert!((pi[4][1] - 1.0 / 7.0).abs() < 1e-15);
        // An empty set, or one of disabled modes only, is every enabled mode.
        imm.set_active([false; N_MODES]);
        assert_eq!(imm.active(), &[true; N_MODES]);
        assert_eq!(imm.transition(0.5), plain);
    }

    /// An IMM reset at the origin, flying east at 100 m/s, every mode at σ 5 m.
    fn level_at_100_mps() -> Imm {
        let mut imm = Imm::new(ImmParams::default());
        let mut x = State9::zeros();
        x[3] = 100.0;
        imm.reset(&x, &(Matrix9::identity() * 25.0), None);
        imm
    }

    /// A mode that leaves the set hands its probability on and is no longer filtered; the
    /// combined estimate moves only by what the report teaches (no jump from dropping a
    /// mode's estimate); a mode that enters starts at probability 0 and gains from the next
    /// reports.
    #[test]
    fn modes_leave_and_enter_the_set_without_a_jump() {
        let mut imm = level_at_100_mps();
        let report =
            |t: f64| Observation::Position(observed(Vector3::new(100.0 * t, 0.0, 0.0), 10.0));
        let mut t = 0.0;
        for _ in 0..20 {
            t += 0.5;
            imm.step(0.5, &report(t)).unwrap();
        }
        let before = imm.probabilities()[ImmMode::Ch.index()];
        assert!(before > 0.0);
        // CH, CHCA and CA leave.
        imm.set_active([true, false, true, true, false, false]);
        let (x0, _) = imm.combined();
        t += 0.5;
        imm.step(0.5, &report(t)).unwrap();
        let mu = imm.probabilities();
        assert_eq!((mu[1], mu[4], mu[5]), (0.0, 0.0, 0.0));
        assert!((mu.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let (x1, p1) = imm.combined();
        assert!(
            (x1[0] - (x0[0] + 50.0)).abs() < 1.0,
            "{} -> {}",
            x0[0],
            x1[0]
        );
        assert!(kalman::is_positive_definite(&p1));
        // CH enters again at 0, and a climb's onset makes a climbing mode the likeliest.
        imm.set_active([true; N_MODES]);
        let mut climbing = 0.0f64;
        for k in 0..12 {
            t += 0.5;
            let climb = if k > 4 {
                10.0 * (k - 4) as f64 * 0.5
            } else {
                0.0
            };
            let obs = Observation::Both(
                observed(Vector3::new(100.0 * t, 0.0, climb), 10.0),
                observed(
                    Vector3::new(100.0, 0.0, if k > 4 { 10.0 } else { 0.0 }),
                    0.5,
                ),
            );
            imm.step(0.5, &obs).unwrap();
            let mu = imm.probabilities();
            if k == 0 {
                assert!(mu[4] > 0.0);
            }
            climbing = climbing.max(mu[4] + mu[5]);
        }
        assert!(climbing > 0.5, "{climbing}");
    }

    /// A mode entering at the combined estimate moves no estimate, and holds its share.
    #[test]
    fn entering_at_the_combined_estimate_moves_nothing() {
        let mut imm = level_at_100_mps();
        imm.set_active([true, true, false, false, false, false]);
        for k in 1..=20 {
            let t = 0.5 * k as f64;
            let obs = Observation::Position(observed(
                Vector3::new(100.0 * t + 0.2 * t * t, 3.0 * (k % 3) as f64, 0.0),
                10.0,
            ));
            imm.step(0.5, &obs).unwrap();
        }
        let (x0, p0) = imm.combined();
        imm.set_active([true, true, true, true, false, false]);
        imm.enter(ImmMode::CtLeft, 0.5);
        let (x1, p1) = imm.combined();
        assert!(
            (x1 - x0).norm() <= 1e-12 * x0.norm(),
            "{}",
            (x1 - x0).norm()
        );
        assert!(
            (p1 - p0).norm() <= 1e-12 * p0.norm(),
            "{}",
            (p1 - p0).norm()
        );
        let mu = imm.probabilities();
        assert!(mu[ImmMode::CtLeft.index()] >= 0.5);
        assert!((mu.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // An inactive mode, or a share outside 0..=1, changes nothing.
        let held = imm.clone();
        imm.enter(ImmMode::Ch, 0.5);
        imm.enter(ImmMode::Ca, 1.5);
        assert_eq!(imm.probabilities(), held.probabilities());
        for mode in ImmMode::ALL {
            assert_eq!(imm.mode_state(mode), held.mode_state(mode));
        }
    }

    /// Two enabled modes, hand-computed mixing, mode probability and combination.
    #[test]
    fn two_mode_cycle_matches_a_hand_computation() {
        let params = ImmParams {
            enabled: [true, false, false, false, true, false],
            ..ImmParams::default()
        };
        let mut imm = Imm::new(params);
        let x = State9::zeros();
        let p = Matrix9::identity() * 100.0;
        imm.reset(&x, &p, Some(&[0.5, 0.0, 0.0, 0.0, 0.5, 0.0]));
        // dt = 0: no motion, Q = 0 except the acceleration reset; mixing of equal states
        // leaves each at (0, 100 I). Position report (10, 0, 0), R = 100 I:
        // both models: K = 1/2 on position, x_e = 5, P_ee = 50; identical likelihoods.
        let obs = Observation::Position(observed(Vector3::new(10.0, 0.0, 0.0), 10.0));
        imm.step(0.0, &obs).unwrap();
        let mu = imm.probabilities();
        assert!((mu[0] - 0.5).abs() < 1e-12 && (mu[4] - 0.5).abs() < 1e-12);
        let (xc, pc) = imm.combined();
        assert!((xc[0] - 5.0).abs() < 1e-12);
        assert!((pc[(0, 0)] - 50.0).abs() < 1e-9);
        // Now give the two modes different states by hand and check the spread term:
        // x_cv,e = 0, x_ch,e = 10, μ = (0.25, 0.75): x̂ = 7.5, P_ee = 50 + 0.25·56.25 + 0.75·6.25.
        imm.states_mut().x[0][0] = 0.0;
        imm.states_mut().x[4][0] = 10.0;
        imm.mu = [0.25, 0.0, 0.0, 0.0, 0.75, 0.0];
        let (xc, pc) = imm.combined();
        assert!((xc[0] - 7.5).abs() < 1e-12);
        assert!((pc[(0, 0)] - (50.0 + 0.25 * 56.25 + 0.75 * 6.25)).abs() < 1e-9);
        // Mode probabilities from likelihoods: a vertical velocity report of 5 m/s with
        // σ = 1: under CV (vertical P from reset: P_uu,vel = 100) vs CH alike at dt = 0, so
        // compare instead with a dt where their Q differ: both see the same residual, and
        // μ_j ∝ c̄_j N(ε; 0, S_j) by hand.
        imm.reset(&x, &p, Some(&[0.5, 0.0, 0.0, 0.0, 0.5, 0.0]));
        let dt = 2.0;
        let v_obs = Observed {
            value: Vector3::new(0.0, 0.0, 5.0),
            cov: Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 1.0)),
            grid: None,
        };
        imm.step(dt, &Observation::Velocity(v_obs)).unwrap();
        let pi = imm.transition(dt);
        let c_cv = pi[0][0] * 0.5 + pi[4][0] * 0.5;
        let c_ch = pi[0][4] * 0.5 + pi[4][4] * 0.5;
        // Velocity variance after predict: 100 + q·dt per axis; S = that + 1.
        let s = |qh: f64, qv: f64| {
            [
                100.0 + qh * dt + 1.0,
                100.0 + qh * dt + 1.0,
                100.0 + qv * dt + 1.0,
            ]
        };
        let ll = |s: [f64; 3]| {
            -0.5 * (25.0 / s[2]
                + s.iter().map(|v| v.ln()).sum::<f64>()
                + 3.0 * (2.0 * std::f64::consts::PI).ln())
        };
        let cv = params.models.cv;
        let ch = params.models.ch;
        let l_cv = ll(s(cv.q_h_m2ps3, cv.q_v_m2ps3));
        let l_ch = ll(s(ch.q_h_m2ps3, ch.q_v_m2ps3));
        let expected_cv = 1.0 / (1.0 + (c_ch / c_cv) * (l_ch - l_cv).exp());
        assert!(
            (imm.probabilities()[0] - expected_cv).abs() < 1e-12,
            "{} vs {expected_cv}",
            imm.probabilities()[0]
        );
    }

    #[test]
    fn probabilities_survive_a_residual_of_thousands_of_sigma() {
        let mut imm = Imm::new(ImmParams::default());
        let mut p = Matrix9::identity();
        p[(0, 0)] = 1.0;
        imm.reset(&State9::zeros(), &p, None);
        // 10 km off with σ = 1 m: ln Λ ≈ −5e7 in every mode, exp() underflows to 0.
        let obs = Observation::Position(observed(Vector3::new(1.0e4, 0.0, 0.0), 1.0));
        imm.step(1.0, &obs).unwrap();
        let mu = imm.probabilities();
        assert!(mu.iter().all(|m| m.is_finite()));
        assert!((mu.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let (x, p) = imm.combined();
        assert!(x.iter().all(|v| v.is_finite()) && p.cholesky().is_some());
    }

    #[test]
    fn works_with_position_only_velocity_only_and_joint_reports() {
        let mut imm = Imm::new(ImmParams::default());
        let mut x = State9::zeros();
        x[VEL] = 100.0;
        imm.reset(&x, &(Matrix9::identity() * 25.0), None);
        let mut unmeasured_vrate = observed(Vector3::new(100.0, 0.0, 0.0), 0.5);
        unmeasured_vrate.cov[(2, 2)] = UNMEASURED_VARIANCE;
        let reports = [
            Observation::Position(observed(Vector3::new(50.0, 0.0, 0.0), 10.0)),
            Observation::Velocity(unmeasured_vrate),
            Observation::Both(
                observed(Vector3::new(150.0, 0.0, 0.0), 10.0),
                observed(Vector3::new(100.0, 0.0, 0.0), 0.5),
            ),
        ];
        for (k, obs) in reports.iter().enumerate() {
            imm.step(0.5, obs).unwrap();
            let (xc, pc) = imm.combined();
            assert!(
                (xc[0] - 50.0 * (k + 1) as f64).abs() < 10.0,
                "{k}: {}",
                xc[0]
            );
            assert!(pc.cholesky().is_some());
            assert!((imm.probabilities().iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn reset_puts_the_combined_estimate_exactly_at_the_given_state() {
        let mut imm = Imm::new(ImmParams::default());
        let x = State9::from_fn(|i, _| i as f64 * 3.5 - 7.0);
        let mut p = Matrix9::identity() * 4.0;
        p[(0, 3)] = 1.0;
        p[(3, 0)] = 1.0;
        imm.reset(&x, &p, Some(&[0.1, 0.2, 0.3, 0.1, 0.2, 0.1]));
        let (xc, pc) = imm.combined();
        assert!((xc - x).norm() < 1e-12);
        assert!((pc - p).norm() < 1e-12);
    }

    /// The leading block of the combined estimate is computed alone with the same bits.
    #[test]
    fn the_combined_leading_block_is_the_combined_estimates() {
        let mut imm = Imm::new(ImmParams::default());
        let mut x = State9::zeros();
        x[2] = 9000.0;
        x[3] = 120.0;
        imm.reset(&x, &(Matrix9::identity() * 25.0), None);
        let (pos, vel) = (
            Vector3::new(50.0, 20.0, 9010.0),
            Vector3::new(118.0, 9.0, 1.5),
        );
        for k in 0..12 {
            let obs = if k % 2 == 0 {
                Observation::Position(Observed {
                    value: pos + Vector3::new(60.0 * k as f64, 8.0 * (k as f64).sin(), 0.0),
                    cov: Matrix3::identity() * 100.0,
                    grid: None,
                })
            } else {
                Observation::Velocity(Observed {
                    value: vel + Vector3::new(0.4 * (k as f64).cos(), 0.5, 0.0),
                    cov: Matrix3::identity() * 0.3,
                    grid: None,
                })
            };
            imm.step(0.5, &obs).unwrap();
        }
        let (x9, p9) = imm.combined();
        // Several modes weigh in, so the spread of means is part of the sum.
        assert!(imm.probabilities().iter().filter(|&&m| m > 1e-3).count() >= 3);
        let (x6, p6) = imm.combined_leading::<6>();
        assert_eq!(x6, kalman::rows::<6, 9>(&x9, 0));
        assert_eq!(p6, kalman::block::<6, 6, 9, 9>(&p9, 0, 0));
        assert_eq!(imm.combined_leading::<9>(), (x9, p9));
        // A prediction on the states each model keeps is the 9-state one's position and
        // velocity, bit for bit, for every model (a CT at an adapted rate too) and horizon.
        let mut models: Vec<Model> = ImmMode::ALL.iter().map(|&m| *imm.model(m)).collect();
        models.push(Model::Ct(Ct::turning(true, 0.07)));
        for model in models {
            for dt_s in [0.0, 0.4, 1.0, 5.0, 30.0] {
                let (mut x, mut p) = (x9, p9);
                model.predict(&mut x, &mut p, dt_s);
                let (xl, pl) = imm.predicted_position_velocity(&model, dt_s);
                assert_eq!(xl, kalman::rows::<6, 9>(&x, 0), "{model:?} {dt_s}");
                assert_eq!(
                    pl,
                    kalman::block::<6, 6, 9, 9>(&p, 0, 0),
                    "{model:?} {dt_s}"
                );
            }
        }
    }

    /// [`HeldModeFit`]: a position far off the held mode's prediction is set aside (the IMM
    /// as it was) while the velocity reports fit that mode, in straight flight under CV and
    /// in a turn under CT; once a velocity report does not fit, the next position is used.
    #[test]
    fn the_held_mode_vouches_for_its_own_flight() {
        let params = OutlierParams::default();
        // (turn rate °/s, the mode that holds.)
        for (rate_dps, mode) in [(0.0, ImmMode::Cv), (3.0, ImmMode::CtLeft)] {
            let omega = f64::to_radians(rate_dps);
            let (v_mps, r_m) = (100.0, 100.0 / omega.max(1e-12));
            // A level flight from the origin heading east, turning left at `omega`.
            let truth = |t: f64| {
                let (s, c) = (omega * t).sin_cos();
                if omega == 0.0 {
                    (
                        Vector3::new(v_mps * t, 0.0, 0.0),
                        Vector3::new(v_mps, 0.0, 0.0),
                    )
                } else {
                    (
                        Vector3::new(r_m * s, r_m * (1.0 - c), 0.0),
                        Vector3::new(v_mps * c, v_mps * s, 0.0),
                    )
                }
            };
            let mut imm = level_at_100_mps();
            let (mut fit, mut gate) = (HeldModeFit::default(), OutlierGate::default());
            let mut t = 0.0;
            for k in 0..120 {
                t += 0.5;
                let (pos, vel) = truth(t);
                let obs = if k % 2 == 0 {
                    Observation::Position(observed(pos, 3.0))
                } else {
                    Observation::Velocity(observed(vel, 0.5))
                };
                assert!(fit
                    .step(&mut imm, &mut gate, &params, t, 0.5, &obs)
                    .unwrap());
            }
            assert_eq!(imm.most_probable(), mode, "{rate_dps}");
            assert!(imm.probabilities()[mode.index()] >= LEARN_CV_PROBABILITY);
            // A position 0.6 s stale (60 m behind along the flight): set aside, nothing moved.
            let kept = imm.combined_state();
            t += 0.5;
            let stale = Observation::Position(observed(truth(t - 0.6).0, 3.0));
            assert!(!fit
                .step(&mut imm, &mut gate, &params, t, 0.5, &stale)
                .unwrap());
            assert_eq!(imm.combined_state(), kept, "{rate_dps}");
            assert_eq!(gate.count(), 1);
            // A velocity report 20 m/s off the mode: it vouches for nothing, and the next
            // stale position is used.
            t += 0.5;
            let (_, vel) = truth(t);
            let off = Observation::Velocity(observed(vel + Vector3::new(0.0, 20.0, 0.0), 0.5));
            assert!(fit
                .step(&mut imm, &mut gate, &params, t, 0.5, &off)
                .unwrap());
            t += 0.5;
            let stale = Observation::Position(observed(truth(t - 0.6).0, 3.0));
            assert!(fit
                .step(&mut imm, &mut gate, &params, t, 0.5, &stale)
                .unwrap());
            assert_eq!(gate.count(), 1, "{rate_dps}");
        }
    }
}
