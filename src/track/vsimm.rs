//! Variable-structure IMM with square-root cubature Kalman filters (paper 003, ALGORITHMS.md
//! §003, Du & Zhang 2020), and its fixed-structure baselines IMM-CKF and IMM-SRCKF.
//!
//! Horizontal state [x, vx, ax, y, vy, ay] (common to every model, so mixing is exact); the
//! vertical axis is a separate plain CV Kalman filter (no mode in it).
//!
//! Model set M (seven filters for paper 003's five model kinds):
//! - CV: acceleration states forced to 0 (with a small noise so the factor stays full rank);
//! - CA: Wiener-process acceleration (white jerk);
//! - CS: "current statistical" (Zhou & Kumar): Singer chain with the mean acceleration ā taken
//!   from the model's mixed estimate, σ² = (4 − π)/π (a_max − |ā|)² ([`super::singer::chain`]);
//! - slow turn left/right and fast turn left/right: coordinated turns at fixed rates ±0.45°/s
//!   and ±1.8°/s (paper 003's scenario: a 90° turn in 200 s and one in 50 s), acceleration
//!   states = the centripetal ω × v. The rates are fixed (documented choice): a turn-rate state
//!   would need the nonlinear CT; the cubature rule is exact for these linear models.
//!
//! Variable structure (the rule, applied at each report from the previous step's result):
//! the active set M'_k is the union of
//! 1. every model whose probability is at least [`VsimmParams::keep_probability`];
//! 2. the most probable model and its neighbours in the digraph
//!    CV–{CA, slow L, slow R}, CA–{CV, CS}, CS–{CV, CA}, slow L–{CV, fast L},
//!    slow R–{CV, fast R}, fast L–{slow L, CV}, fast R–{slow R, CV};
//! 3. all models when a manoeuvre shows: the most probable model's NIS at the last update
//!    exceeded [`VsimmParams::manoeuvre_nis`] (χ²(2) at 1 %).
//!
//! Transition probabilities P_rs[M'_{k−1}, M'_k] (eq. 4): row r gives 0.95 to s = r and
//! shares 0.05 equally over the other active models, then is renormalised over M'_k (a row
//! whose model was dropped is thus uniform). A model entering the set gets its initial state
//! from the mixing step (eq. 6–8) like any other. Likelihoods are combined in log space.
//!
//! In the square-root variants the mixed and fused covariances are formed as factors too:
//! Σ μ_r (S_r S_rᵀ + d_r d_rᵀ) = Tria([√μ_r S_r, √μ_r d_r]_r); P is formed only for the
//! published estimate. The IMM-CKF baseline forms P everywhere and re-factors it.
//!
//! Label: the most probable model maps to CV → CV, CA and CS → CA, turns → CT; the
//! probabilities in [`Estimate::mode_probabilities`] are summed the same way.

use super::alt::{Lifecycle, Step};
use super::cubature::{self, Fit, Matrix6, Vector6};
use super::kalman;
use super::nis::{self, NisWindow};
use super::singer;
use super::{Estimate, FlightMode, Measurement, Observed, TrackError, Tracker};
use nalgebra::{Cholesky, Matrix2, SMatrix, SVector, Vector2};

/// Name of the VSIMM-SRCKF tracker.
pub const NAME_VSIMM: &str = "vsimm-srckf";
/// Name of the fixed-structure IMM with plain CKFs.
pub const NAME_IMM_CKF: &str = "imm-ckf";
/// Name of the fixed-structure IMM with SRCKFs.
pub const NAME_IMM_SRCKF: &str = "imm-srckf";

/// Number of models.
pub const MODELS: usize = 7;

/// The models, in the order of [`Vsimm::model_probabilities`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Model {
    /// Constant velocity.
    Cv,
    /// Constant acceleration (Wiener acceleration).
    Ca,
    /// Current statistical.
    Cs,
    /// Slow left turn (counter-clockwise seen from above).
    SlowLeft,
    /// Slow right turn.
    SlowRight,
    /// Fast left turn.
    FastLeft,
    /// Fast right turn.
    FastRight,
}

impl Model {
    /// All models.
    pub const ALL: [Model; MODELS] = [
        Self::Cv,
        Self::Ca,
        Self::Cs,
        Self::SlowLeft,
        Self::SlowRight,
        Self::FastLeft,
        Self::FastRight,
    ];

    fn neighbours(self) -> &'static [Model] {
        match self {
            Self::Cv => &[Self::Ca, Self::SlowLeft, Self::SlowRight],
            Self::Ca => &[Self::Cv, Self::Cs],
            Self::Cs => &[Self::Cv, Self::Ca],
            Self::SlowLeft => &[Self::Cv, Self::FastLeft],
            Self::SlowRight => &[Self::Cv, Self::FastRight],
            Self::FastLeft => &[Self::SlowLeft, Self::Cv],
            Self::FastRight => &[Self::SlowRight, Self::Cv],
        }
    }

    fn label(self) -> FlightMode {
        match self {
            Self::Cv => FlightMode::Cv,
            Self::Ca | Self::Cs => FlightMode::Ca,
            _ => FlightMode::Ct,
        }
    }
}

/// Which of the three filters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Variant {
    /// Paper 003's VSIMM with SRCKFs.
    VsimmSrckf,
    /// Fixed structure (all models), plain CKF.
    ImmCkf,
    /// Fixed structure (all models), SRCKF.
    ImmSrckf,
}

/// Tuning of [`Vsimm`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VsimmParams {
    /// Which filter. Default VSIMM-SRCKF.
    pub variant: Variant,
    /// Diagonal of the transition matrix. Default 0.95 (paper 003 eq. 12).
    pub p_stay: f64,
    /// Slow-turn rate, deg/s. Default 0.45 (paper 003: 90° in 200 s).
    pub slow_turn_dps: f64,
    /// Fast-turn rate, deg/s. Default 1.8 (paper 003: 90° in 50 s).
    pub fast_turn_dps: f64,
    /// CV and turn models' white-acceleration density, m²/s³. Default 0.25 (as the CV
    /// tracker: ±0.5 m/s² of unmodelled acceleration).
    pub q_cv_m2ps3: f64,
    /// CA model's white-jerk density, m²/s⁵. Default 0.1 (≈ 0.3 m/s³ over a second).
    pub q_ca_m2ps5: f64,
    /// CS model's manoeuvre frequency α, 1/s. Default 1/20 (as paper 001's α₀).
    pub cs_alpha: f64,
    /// CS model's maximum acceleration, m/s². Default 6 m/s² (a 30° bank).
    pub cs_a_max_mps2: f64,
    /// Noise on acceleration states the model fixes (CV: 0, turns: ω × v), m/s² (1σ per
    /// step). Default 0.05: keeps the factor full rank, negligible otherwise.
    pub fixed_accel_sigma_mps2: f64,
    /// A model at or above this probability stays active. Default 1e-3.
    pub keep_probability: f64,
    /// NIS of the most probable model above which all models are activated. Default 9.21.
    pub manoeuvre_nis: f64,
    /// Vertical acceleration spectral density, m²/s³. Default 0.09.
    pub q_v_m2ps3: f64,
    /// A report this long after the track restarts it, s. Default 60 s.
    pub max_gap_s: f64,
    /// A velocity report at most this old initialises a new track's velocity, s. Default 5 s.
    pub init_velocity_max_age_s: f64,
    /// 1-σ horizontal speed of a track started without velocity, m/s. Default 300 m/s.
    pub init_speed_sigma_mps: f64,
    /// 1-σ vertical rate of a track started without velocity, m/s. Default 30 m/s.
    pub init_vrate_sigma_mps: f64,
    /// 1-σ initial horizontal acceleration, m/s². Default 3 m/s².
    pub init_accel_sigma_mps2: f64,
}

impl Default for VsimmParams {
    fn default() -> Self {
        Self {
            variant: Variant::VsimmSrckf,
            p_stay: 0.95,
            slow_turn_dps: 0.45,
            fast_turn_dps: 1.8,
            q_cv_m2ps3: 0.25,
            q_ca_m2ps5: 0.1,
            cs_alpha: 1.0 / 20.0,
            cs_a_max_mps2: 6.0,
            fixed_accel_sigma_mps2: 0.05,
            keep_probability: 1e-3,
            manoeuvre_nis: 9.21,
            q_v_m2ps3: 0.09,
            max_gap_s: 60.0,
            init_velocity_max_age_s: 5.0,
            init_speed_sigma_mps: 300.0,
            init_vrate_sigma_mps: 30.0,
            init_accel_sigma_mps2: 3.0,
        }
    }
}

const X: usize = 0;
const VX: usize = 1;
const AX: usize = 2;
const Y: usize = 3;
const VY: usize = 4;
const AY: usize = 5;
/// Jitter added to Q before its Cholesky factor, m² (dt = 0 gives Q = 0).
const Q_JITTER: f64 = 1e-9;

/// (F, u, Q) of a model over `dt_s`; `a_bar` is the CS model's mean acceleration (x, y).
fn model_matrices(
    params: &VsimmParams,
    model: Model,
    dt_s: f64,
    a_bar: Vector2<f64>,
) -> (Matrix6, Vector6, Matrix6) {
    let t = dt_s;
    let mut f = Matrix6::zeros();
    let mut u = Vector6::zeros();
    let mut q = Matrix6::zeros();
    let white_acc = |q: &mut Matrix6, density: f64| {
        for (p, v) in [(X, VX), (Y, VY)] {
            q[(p, p)] += density * t.powi(3) / 3.0;
            q[(p, v)] += density * t.powi(2) / 2.0;
            q[(v, p)] += density * t.powi(2) / 2.0;
            q[(v, v)] += density * t;
        }
    };
    let fixed_acc = params.fixed_accel_sigma_mps2.powi(2);
    match model {
        Model::Cv => {
            for (p, v) in [(X, VX), (Y, VY)] {
                f[(p, p)] = 1.0;
                f[(p, v)] = t;
                f[(v, v)] = 1.0;
            }
            white_acc(&mut q, params.q_cv_m2ps3);
            q[(AX, AX)] = fixed_acc;
            q[(AY, AY)] = fixed_acc;
        }
        Model::Ca => {
            let c = singer::chain::<3>(0.0, t);
            for base in [X, Y] {
                f.fixed_view_mut::<3, 3>(base, base).copy_from(&c.f);
                q.fixed_view_mut::<3, 3>(base, base)
                    .copy_from(&(c.q_unit * params.q_ca_m2ps5));
            }
        }
        Model::Cs => {
            let c = singer::chain::<3>(params.cs_alpha, t);
            let factor = (4.0 - std::f64::consts::PI) / std::f64::consts::PI;
            for (axis, base) in [X, Y].into_iter().enumerate() {
                let mean = a_bar[axis];
                let sigma2 = (factor * (params.cs_a_max_mps2 - mean.abs()).powi(2)).max(1e-4);
                f.fixed_view_mut::<3, 3>(base, base).copy_from(&c.f);
                u.fixed_rows_mut::<3>(base).copy_from(&(c.g * mean));
                q.fixed_view_mut::<3, 3>(base, base)
                    .copy_from(&(c.q_unit * (2.0 * params.cs_alpha * sigma2)));
            }
        }
        Model::SlowLeft | Model::SlowRight | Model::FastLeft | Model::FastRight => {
            let rate_dps = match model {
                Model::SlowLeft => params.slow_turn_dps,
                Model::SlowRight => -params.slow_turn_dps,
                Model::FastLeft => params.fast_turn_dps,
                _ => -params.fast_turn_dps,
            };
            let w = rate_dps.to_radians();
            let (s, c) = (w * t).sin_cos();
            // sin(ωT)/ω and (1 − cos ωT)/ω, finite as ω → 0.
            let (sw, cw) = if w.abs() * t < 1e-6 {
                (t, w * t * t / 2.0)
            } else {
                (s / w, (1.0 - c) / w)
            };
            f[(X, X)] = 1.0;
            f[(X, VX)] = sw;
            f[(X, VY)] = -cw;
            f[(VX, VX)] = c;
            f[(VX, VY)] = -s;
            f[(Y, Y)] = 1.0;
            f[(Y, VX)] = cw;
            f[(Y, VY)] = sw;
            f[(VY, VX)] = s;
            f[(VY, VY)] = c;
            // Centripetal acceleration after the step: a = ω × v.
            for col in 0..6 {
                f[(AX, col)] = -w * f[(VY, col)];
                f[(AY, col)] = w * f[(VX, col)];
            }
            white_acc(&mut q, params.q_cv_m2ps3);
            q[(AX, AX)] += fixed_acc;
            q[(AY, AY)] += fixed_acc;
        }
    }
    for i in 0..6 {
        q[(i, i)] += Q_JITTER;
    }
    (f, u, q)
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Track {
    t_s: f64,
    /// Per-model state and lower-triangular factor (P = S Sᵀ).
    x: [Vector6; MODELS],
    s: [Matrix6; MODELS],
    mu: [f64; MODELS],
    active: [bool; MODELS],
    /// NIS of each model at the last position update.
    nis: [f64; MODELS],
    /// Fused horizontal state and factor.
    fused_x: Vector6,
    fused_s: Matrix6,
    /// Vertical CV [u, vu].
    xv: Vector2<f64>,
    pv: Matrix2<f64>,
}

/// The VSIMM-SRCKF tracker and its two fixed-structure baselines.
#[derive(Clone, Debug, PartialEq)]
pub struct Vsimm {
    params: VsimmParams,
    life: Lifecycle,
    track: Option<Track>,
    /// Sum over updates of the number of active models (VSIMM cost measure).
    model_steps: u64,
    /// The windowed NIS of the track's reports ([`super::nis`]).
    nis: NisWindow,
}

impl Default for Vsimm {
    fn default() -> Self {
        Self::new(VsimmParams::default())
    }
}

/// Tria of the mixture Σ w_r (S_r S_rᵀ + d_r d_rᵀ) over the given members.
fn mixture_factor(members: &[(f64, Vector6, Matrix6)], mean: &Vector6) -> Matrix6 {
    let mut a = SMatrix::<f64, 6, { MODELS * 7 }>::zeros();
    for (k, (w, x, s)) in members.iter().enumerate().take(MODELS) {
        let sw = w.max(0.0).sqrt();
        a.fixed_columns_mut::<6>(k * 7).copy_from(&(s * sw));
        a.set_column(k * 7 + 6, &((x - mean) * sw));
    }
    cubature::tria(&a)
}

/// Σ w_r (P_r + d_r d_rᵀ) in covariance form (IMM-CKF).
fn mixture_cov(members: &[(f64, Vector6, Matrix6)], mean: &Vector6) -> Matrix6 {
    let mut p = Matrix6::zeros();
    for (w, x, s) in members {
        let d = x - mean;
        p += (s * s.transpose() + d * d.transpose()) * *w;
    }
    (p + p.transpose()) * 0.5
}

fn log_sum_exp(values: &[f64]) -> f64 {
    let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !max.is_finite() {
        return max;
    }
    max + values.iter().map(|v| (v - max).exp()).sum::<f64>().ln()
}

impl Vsimm {
    /// A tracker with no track yet.
    pub fn new(params: VsimmParams) -> Self {
        Self {
            params,
            life: Lifecycle::new(params.max_gap_s, params.init_velocity_max_age_s),
            track: None,
            model_steps: 0,
            nis: NisWindow::default(),
        }
    }

    /// The tuning in use.
    pub fn params(&self) -> &VsimmParams {
        &self.params
    }

    /// Model probabilities in the order of [`Model::ALL`] (zero when inactive).
    pub fn model_probabilities(&self) -> Option<[f64; MODELS]> {
        self.track.map(|t| t.mu)
    }

    /// Sum over updates of the number of models filtered.
    pub fn model_steps(&self) -> u64 {
        self.model_steps
    }

    /// The fused horizontal factor (tests: it must stay triangular with a positive diagonal).
    #[cfg(test)]
    fn fused_factor(&self) -> Option<Matrix6> {
        self.track.map(|t| t.fused_s)
    }

    fn square_root(&self) -> bool {
        self.params.variant != Variant::ImmCkf
    }

    fn initiate(&mut self, t_s: f64, position: &Observed, velocity: Option<(f64, Observed)>) {
        let mut x = Vector6::zeros();
        let mut p = Matrix6::zeros();
        x[X] = position.value.x;
        x[Y] = position.value.y;
        p[(X, X)] = position.cov[(0, 0)];
        p[(X, Y)] = position.cov[(0, 1)];
        p[(Y, X)] = position.cov[(1, 0)];
        p[(Y, Y)] = position.cov[(1, 1)];
        let a2 = self.params.init_accel_sigma_mps2.powi(2);
        let mut xv = Vector2::new(position.value.z, 0.0);
        let mut pv = Matrix2::new(position.cov[(2, 2)], 0.0, 0.0, 0.0);
        match velocity {
            Some((age_s, v)) => {
                x[VX] = v.value.x;
                x[VY] = v.value.y;
                p[(VX, VX)] = v.cov[(0, 0)] + a2 * age_s * age_s;
                p[(VX, VY)] = v.cov[(0, 1)];
                p[(VY, VX)] = v.cov[(1, 0)];
                p[(VY, VY)] = v.cov[(1, 1)] + a2 * age_s * age_s;
                xv[1] = v.value.z;
                pv[(1, 1)] = v.cov[(2, 2)] + self.params.q_v_m2ps3 * age_s;
            }
            None => {
                let h = self.params.init_speed_sigma_mps.powi(2);
                p[(VX, VX)] = h;
                p[(VY, VY)] = h;
                pv[(1, 1)] = self.params.init_vrate_sigma_mps.powi(2);
            }
        }
        p[(AX, AX)] = a2;
        p[(AY, AY)] = a2;
        let Some(chol) = Cholesky::new(kalman::symmetrise(&p)) else {
            return;
        };
        let s = chol.l();
        let mut mu = [0.0; MODELS];
        let mut active = [false; MODELS];
        let all = self.params.variant != Variant::VsimmSrckf;
        for (i, m) in Model::ALL.iter().enumerate() {
            let on = all || *m == Model::Cv || Model::Cv.neighbours().contains(m);
            active[i] = on;
        }
        let n_on = active.iter().filter(|a| **a).count().max(1) as f64;
        for (i, on) in active.iter().enumerate() {
            mu[i] = if *on { 1.0 / n_on } else { 0.0 };
        }
        self.track = Some(Track {
            t_s,
            x: [x; MODELS],
            s: [s; MODELS],
            mu,
            active,
            nis: [0.0; MODELS],
            fused_x: x,
            fused_s: s,
            xv,
            pv,
        });
    }

    /// The active set for the next step (module doc).
    fn next_active(&self, tr: &Track) -> [bool; MODELS] {
        if self.params.variant != Variant::VsimmSrckf {
            return [true; MODELS];
        }
        let best = most_probable(&tr.mu);
        if tr.nis[best] > self.params.manoeuvre_nis {
            return [true; MODELS];
        }
        let mut on: [bool; MODELS] = std::array::from_fn(|i| {
            tr.active.get(i).copied().unwrap_or(false)
                && tr.mu.get(i).copied().unwrap_or(0.0) >= self.params.keep_probability
        });
        if let Some(b) = on.get_mut(best) {
            *b = true;
        }
        if let Some(model) = Model::ALL.get(best) {
            for n in model.neighbours() {
                if let Some(i) = Model::ALL.iter().position(|m| m == n) {
                    on[i] = true;
                }
            }
        }
        on
    }

    fn estimate_of(
        &self,
        t_s: f64,
        x: &Vector6,
        p: &Matrix6,
        xv: &Vector2<f64>,
        pv: &Matrix2<f64>,
        mu: &[f64; MODELS],
    ) -> Estimate {
        let mut pos_cov = nalgebra::Matrix3::zeros();
        let mut vel_cov = nalgebra::Matrix3::zeros();
        for (r, i) in [X, Y].into_iter().enumerate() {
            for (c, j) in [X, Y].into_iter().enumerate() {
                pos_cov[(r, c)] = p[(i, j)];
            }
        }
        for (r, i) in [VX, VY].into_iter().enumerate() {
            for (c, j) in [VX, VY].into_iter().enumerate() {
                vel_cov[(r, c)] = p[(i, j)];
            }
        }
        pos_cov[(2, 2)] = pv[(0, 0)];
        vel_cov[(2, 2)] = pv[(1, 1)];
        let best = most_probable(mu);
        let mut probs = [0.0; 5];
        for (m, w) in Model::ALL.iter().zip(mu.iter()) {
            let idx = FlightMode::ALL
                .iter()
                .position(|f| *f == m.label())
                .unwrap_or(0);
            if let Some(slot) = probs.get_mut(idx) {
                *slot += w;
            }
        }
        Estimate {
            t_s,
            pos_m: nalgebra::Vector3::new(x[X], x[Y], xv[0]),
            vel_mps: nalgebra::Vector3::new(x[VX], x[VY], xv[1]),
            pos_cov_m2: pos_cov,
            vel_cov_m2ps2: vel_cov,
            mode: Model::ALL.get(best).map_or(FlightMode::Cv, |m| m.label()),
            mode_probabilities: probs,
            filter: self.name(),
            diverging: false,
            divergence_events: 0,
            outlier_positions: 0,
            // This tracker does not label movement axes.
            turn: None,
            lateral: super::Lateral::Straight,
            speed: super::SpeedTrend::Constant,
            vertical: super::VerticalTrend::Level,
            nis: self.nis.stat(),
        }
    }

    /// One IMM cycle over the horizontal state; returns the new track and the most probable
    /// model's NIS of the report over its horizontal components (the track's term of its
    /// windowed NIS).
    fn cycle(
        &mut self,
        tr: &Track,
        dt_s: f64,
        m: &Measurement,
    ) -> Result<(Track, f64), TrackError> {
        let sr = self.square_root();
        let active = self.next_active(tr);
        let n_on = active.iter().filter(|a| **a).count();
        let off = if n_on > 1 {
            (1.0 - self.params.p_stay) / (n_on - 1) as f64
        } else {
            0.0
        };
        // Transition rows over the new active set, renormalised.
        let mut trans = [[0.0; MODELS]; MODELS];
        for (r, row) in trans.iter_mut().enumerate() {
            if !tr.active[r] {
                continue;
            }
            let mut sum = 0.0;
            for s in 0..MODELS {
                if active[s] {
                    row[s] = if r == s { self.params.p_stay } else { off };
                    sum += row[s];
                }
            }
            if sum > 0.0 {
                for v in row.iter_mut() {
                    *v /= sum;
                }
            }
        }
        let mut c = [0.0; MODELS];
        for s in 0..MODELS {
            c[s] = (0..MODELS).map(|r| trans[r][s] * tr.mu[r]).sum();
        }
        let mut next = *tr;
        next.t_s = m.t_s;
        next.active = active;
        let mut log_post = [f64::NEG_INFINITY; MODELS];
        let mut fit_nis = [f64::NAN; MODELS];
        let h_pos = {
            let mut h = SMatrix::<f64, 2, 6>::zeros();
            h[(0, X)] = 1.0;
            h[(1, Y)] = 1.0;
            h
        };
        let h_vel = {
            let mut h = SMatrix::<f64, 2, 6>::zeros();
            h[(0, VX)] = 1.0;
            h[(1, VY)] = 1.0;
            h
        };
        for s in 0..MODELS {
            if !active[s] || c[s] <= 0.0 {
                next.mu[s] = 0.0;
                continue;
            }
            // Mixing (eq. 6–8).
            let mut members = [(0.0, Vector6::zeros(), Matrix6::zeros()); MODELS];
            let mut x0 = Vector6::zeros();
            for r in 0..MODELS {
                let w = trans[r][s] * tr.mu[r] / c[s];
                members[r] = (w, tr.x[r], tr.s[r]);
                x0 += tr.x[r] * w;
            }
            let model = Model::ALL.get(s).copied().unwrap_or(Model::Cv);
            let (f, u, q) = model_matrices(&self.params, model, dt_s, Vector2::new(x0[AX], x0[AY]));
            let mut x = x0;
            let fit: Option<Fit>;
            let mut nis_pos = 0.0;
            if sr {
                let mut sfac = mixture_factor(&members, &x0);
                let s_q = Cholesky::new(q).ok_or(TrackError::NotPositiveDefinite)?.l();
                cubature::sr_predict(&mut x, &mut sfac, &f, &u, &s_q);
                fit = match (&m.position, &m.velocity) {
                    (Some(pos), Some(vel)) => {
                        let (z, h, r) = joint(pos, vel, &h_pos, &h_vel);
                        let s_r = Cholesky::new(r).ok_or(TrackError::NotPositiveDefinite)?.l();
                        let fit = cubature::sr_update(&mut x, &mut sfac, &z, &h, &s_r)?;
                        nis_pos = fit.nis;
                        Some(fit)
                    }
                    (Some(pos), None) => {
                        let r = pos.cov.fixed_view::<2, 2>(0, 0).into_owned();
                        let s_r = Cholesky::new(r).ok_or(TrackError::NotPositiveDefinite)?.l();
                        let fit =
                            cubature::sr_update(&mut x, &mut sfac, &pos.value.xy(), &h_pos, &s_r)?;
                        nis_pos = fit.nis;
                        Some(fit)
                    }
                    (None, Some(vel)) => {
                        let r = vel.cov.fixed_view::<2, 2>(0, 0).into_owned();
                        let s_r = Cholesky::new(r).ok_or(TrackError::NotPositiveDefinite)?.l();
                        Some(cubature::sr_update(
                            &mut x,
                            &mut sfac,
                            &vel.value.xy(),
                            &h_vel,
                            &s_r,
                        )?)
                    }
                    (None, None) => None,
                };
                next.s[s] = sfac;
            } else {
                let mut p = mixture_cov(&members, &x0);
                cubature::ckf_predict(&mut x, &mut p, &f, &u, &q)?;
                fit = match (&m.position, &m.velocity) {
                    (Some(pos), Some(vel)) => {
                        let (z, h, r) = joint(pos, vel, &h_pos, &h_vel);
                        let fit = cubature::ckf_update(&mut x, &mut p, &z, &h, &r)?;
                        nis_pos = fit.nis;
                        Some(fit)
                    }
                    (Some(pos), None) => {
                        let r = pos.cov.fixed_view::<2, 2>(0, 0).into_owned();
                        let fit =
                            cubature::ckf_update(&mut x, &mut p, &pos.value.xy(), &h_pos, &r)?;
                        nis_pos = fit.nis;
                        Some(fit)
                    }
                    (None, Some(vel)) => {
                        let r = vel.cov.fixed_view::<2, 2>(0, 0).into_owned();
                        Some(cubature::ckf_update(
                            &mut x,
                            &mut p,
                            &vel.value.xy(),
                            &h_vel,
                            &r,
                        )?)
                    }
                    (None, None) => None,
                };
                next.s[s] = Cholesky::new(p).ok_or(TrackError::NotPositiveDefinite)?.l();
            }
            next.x[s] = x;
            next.nis[s] = nis_pos;
            fit_nis[s] = fit.map_or(f64::NAN, |f| f.nis);
            log_post[s] = c[s].ln() + fit.map_or(0.0, |f| f.log_likelihood);
        }
        self.model_steps = self.model_steps.saturating_add(n_on as u64);
        // Mode probabilities (eq. 9) in log space.
        let norm = log_sum_exp(&log_post);
        if !norm.is_finite() {
            return Err(TrackError::NonFinite("mode probabilities"));
        }
        for s in 0..MODELS {
            next.mu[s] = if active[s] {
                (log_post[s] - norm).exp()
            } else {
                0.0
            };
        }
        let term = fit_nis
            .get(most_probable(&next.mu))
            .copied()
            .unwrap_or(f64::NAN);
        // Fusion (eq. 10–11).
        let mut fused = Vector6::zeros();
        for s in 0..MODELS {
            fused += next.x[s] * next.mu[s];
        }
        let members: [(f64, Vector6, Matrix6); MODELS] =
            std::array::from_fn(|s| (next.mu[s], next.x[s], next.s[s]));
        next.fused_x = fused;
        next.fused_s = if sr {
            mixture_factor(&members, &fused)
        } else {
            Cholesky::new(mixture_cov(&members, &fused))
                .ok_or(TrackError::NotPositiveDefinite)?
                .l()
        };
        Ok((next, term))
    }
}

/// The index of the largest of the model probabilities `mu` (the last of equals).
fn most_probable(mu: &[f64; MODELS]) -> usize {
    (0..MODELS)
        .max_by(|&a, &b| mu[a].total_cmp(&mu[b]))
        .unwrap_or(0)
}

/// Horizontal position and velocity as one 4-D measurement.
fn joint(
    pos: &Observed,
    vel: &Observed,
    h_pos: &SMatrix<f64, 2, 6>,
    h_vel: &SMatrix<f64, 2, 6>,
) -> (SVector<f64, 4>, SMatrix<f64, 4, 6>, SMatrix<f64, 4, 4>) {
    let z = SVector::<f64, 4>::new(pos.value.x, pos.value.y, vel.value.x, vel.value.y);
    let mut h = SMatrix::<f64, 4, 6>::zeros();
    h.fixed_rows_mut::<2>(0).copy_from(h_pos);
    h.fixed_rows_mut::<2>(2).copy_from(h_vel);
    let mut r = SMatrix::<f64, 4, 4>::zeros();
    r.fixed_view_mut::<2, 2>(0, 0)
        .copy_from(&pos.cov.fixed_view::<2, 2>(0, 0));
    r.fixed_view_mut::<2, 2>(2, 2)
        .copy_from(&vel.cov.fixed_view::<2, 2>(0, 0));
    (z, h, r)
}

fn vertical_predict(x: &mut Vector2<f64>, p: &mut Matrix2<f64>, q_v: f64, dt_s: f64) {
    let f = Matrix2::new(1.0, dt_s, 0.0, 1.0);
    let q = Matrix2::new(
        q_v * dt_s.powi(3) / 3.0,
        q_v * dt_s.powi(2) / 2.0,
        q_v * dt_s.powi(2) / 2.0,
        q_v * dt_s,
    );
    kalman::predict(x, p, &f, &q);
}

impl Tracker for Vsimm {
    fn reset(&mut self) {
        *self = Self::new(self.params);
    }

    fn name(&self) -> &'static str {
        match self.params.variant {
            Variant::VsimmSrckf => NAME_VSIMM,
            Variant::ImmCkf => NAME_IMM_CKF,
            Variant::ImmSrckf => NAME_IMM_SRCKF,
        }
    }

    fn update(&mut self, m: &Measurement) -> Result<(), TrackError> {
        let step = self.life.step(m, self.track.map(|t| t.t_s))?;
        let (track, dt_s) = match step {
            Step::NoTrack => {
                self.track = None;
                return Ok(());
            }
            Step::Initiate { position, velocity } => {
                self.initiate(m.t_s, &position, velocity);
                self.nis.clear();
                return Ok(());
            }
            Step::Update { dt_s } => match self.track {
                Some(t) => (t, dt_s),
                None => return Ok(()),
            },
        };
        let (mut next, term) = self.cycle(&track, dt_s, m)?;
        self.nis.push(
            term,
            nis::horizontal_dof(m.position.as_ref(), m.velocity.as_ref()),
        );
        vertical_predict(&mut next.xv, &mut next.pv, self.params.q_v_m2ps3, dt_s);
        let mut h1 = SMatrix::<f64, 1, 2>::zeros();
        h1[(0, 0)] = 1.0;
        if let Some(pos) = &m.position {
            kalman::update(
                &mut next.xv,
                &mut next.pv,
                &SVector::<f64, 1>::new(pos.value.z),
                &h1,
                &SMatrix::<f64, 1, 1>::new(pos.cov[(2, 2)]),
            )?;
        }
        if let Some(vel) = &m.velocity {
            let mut hv = SMatrix::<f64, 1, 2>::zeros();
            hv[(0, 1)] = 1.0;
            kalman::update(
                &mut next.xv,
                &mut next.pv,
                &SVector::<f64, 1>::new(vel.value.z),
                &hv,
                &SMatrix::<f64, 1, 1>::new(vel.cov[(2, 2)]),
            )?;
        }
        self.track = Some(next);
        Ok(())
    }

    fn estimate(&self) -> Option<Estimate> {
        self.track.map(|t| {
            self.estimate_of(
                t.t_s,
                &t.fused_x,
                &(t.fused_s * t.fused_s.transpose()),
                &t.xv,
                &t.pv,
                &t.mu,
            )
        })
    }

    /// Each model predicted by its own matrices, then fused (no mixing: the mode does not
    /// switch over the horizon in expectation beyond the probabilities held).
    fn predict(&self, t_s: f64) -> Option<Estimate> {
        let tr = self.track?;
        let dt_s = t_s - tr.t_s;
        if !dt_s.is_finite() || dt_s < 0.0 {
            return None;
        }
        let mut members = [(0.0, Vector6::zeros(), Matrix6::zeros()); MODELS];
        let mut fused = Vector6::zeros();
        for (s, model) in Model::ALL.iter().enumerate() {
            if !tr.active[s] {
                continue;
            }
            let (f, u, q) = model_matrices(
                &self.params,
                *model,
                dt_s,
                Vector2::new(tr.x[s][AX], tr.x[s][AY]),
            );
            let (mut x, mut p) = (tr.x[s], tr.s[s] * tr.s[s].transpose());
            kalman::predict(&mut x, &mut p, &f, &q);
            x += u;
            let sf = Cholesky::new(p).map(|c| c.l())?;
            members[s] = (tr.mu[s], x, sf);
            fused += x * tr.mu[s];
        }
        let p = mixture_cov(&members, &fused);
        let (mut xv, mut pv) = (tr.xv, tr.pv);
        vertical_predict(&mut xv, &mut pv, self.params.q_v_m2ps3, dt_s);
        Some(self.estimate_of(t_s, &fused, &p, &xv, &pv, &tr.mu))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::singer::tests::{gaussian3, observed, random_dt_stress, straight_leg};
    use nalgebra::Vector3;
    use rand::rngs::StdRng;
    use rand::SeedableRng;

    fn variants() -> [Variant; 3] {
        [Variant::VsimmSrckf, Variant::ImmCkf, Variant::ImmSrckf]
    }

    fn tracker(variant: Variant) -> Vsimm {
        Vsimm::new(VsimmParams {
            variant,
            ..VsimmParams::default()
        })
    }

    #[test]
    fn turn_model_matches_the_exact_circle() {
        // A left fast turn for 50 s at 150 m/s heading north turns 90° to the west and
        // moves by the radius R = v/ω both ways (closed-form circle).
        let p = VsimmParams::default();
        let (f, _, _) = model_matrices(&p, Model::FastLeft, 50.0, Vector2::zeros());
        let x = f * Vector6::new(0.0, 0.0, 0.0, 0.0, 150.0, 0.0);
        let r = 150.0 / 1.8f64.to_radians();
        assert!((x[X] + r).abs() < 1e-6 && (x[Y] - r).abs() < 1e-6, "{x}");
        assert!((x[VX] + 150.0).abs() < 1e-9 && x[VY].abs() < 1e-9);
        // Centripetal acceleration v²/R towards the centre (−R, 0): south.
        assert!(x[AX].abs() < 1e-9 && (x[AY] + 150.0 * 150.0 / r).abs() < 1e-9);
    }

    #[test]
    fn factor_stays_triangular_with_positive_diagonal() {
        for variant in variants() {
            let mut kf = tracker(variant);
            random_dt_stress(&mut kf, |kf, step| {
                let tr = kf.track.unwrap();
                for s in std::iter::once(tr.fused_s).chain(tr.s.iter().copied()) {
                    for i in 0..6 {
                        assert!(s[(i, i)] > 0.0, "{variant:?} step {step}: {s}");
                        for j in i + 1..6 {
                            assert_eq!(s[(i, j)], 0.0, "{variant:?} step {step}");
                        }
                    }
                }
                let mu_sum: f64 = tr.mu.iter().sum();
                assert!((mu_sum - 1.0).abs() < 1e-9);
                let p = kf.fused_factor().unwrap();
                assert!(p.iter().all(|v| v.is_finite()));
            });
        }
    }

    #[test]
    fn the_windowed_nis_is_published_and_follows_the_claim() {
        for variant in [Variant::VsimmSrckf, Variant::ImmCkf, Variant::ImmSrckf] {
            let per_dof = crate::track::singer::tests::windowed_nis_by_claim(|| {
                Box::new(Vsimm::new(VsimmParams {
                    variant,
                    ..VsimmParams::default()
                }))
            });
            crate::track::singer::tests::assert_the_claim_shows(&format!("{variant:?}"), per_dof);
        }
    }

    #[test]
    fn beats_raw_measurements_on_a_straight_leg() {
        for variant in variants() {
            let mut kf = tracker(variant);
            let (filt, raw) = straight_leg(&mut kf);
            println!(
                "{}: straight leg RMSE {filt:.1} m (raw {raw:.1} m)",
                kf.name()
            );
            assert!(filt < 0.8 * raw, "{variant:?}: {filt} vs {raw}");
            assert_eq!(kf.estimate().unwrap().mode, FlightMode::Cv);
        }
    }

    /// Paper 003's scenario: x0 = (0, 2000) m, 150 m/s along x; slow left turn 400–600 s
    /// (0.45°/s, to +y), CV 600–610 s, fast right turn 610–660 s (−1.8°/s, back to +x), CV
    /// to 900 s; reports every 2 s with σ = 50 m horizontally (our choice: ADS-B NACp 8).
    fn paper_003_truth() -> Vec<(f64, Vector2<f64>)> {
        let dt = 0.01;
        let (mut pos, mut heading) = (Vector2::new(0.0, 2000.0), 0.0f64);
        let mut out = Vec::new();
        for k in 0..=90_000 {
            let t = k as f64 * dt;
            if k % 200 == 0 {
                out.push((t, pos));
            }
            let rate = if (400.0..600.0).contains(&t) {
                0.45f64.to_radians()
            } else if (610.0..660.0).contains(&t) {
                -1.8f64.to_radians()
            } else {
                0.0
            };
            let h_mid = heading + rate * dt / 2.0;
            pos += Vector2::new(h_mid.cos(), h_mid.sin()) * 150.0 * dt;
            heading += rate * dt;
        }
        out
    }

    #[test]
    fn paper_003_scenario_rmse_and_cpu_time() {
        let truth = paper_003_truth();
        assert!(
            (truth.last().unwrap().1.y
                - (2000.0 + 150.0 / 0.45f64.to_radians() + 150.0 / 1.8f64.to_radians() + 1500.0))
                .abs()
                < 5.0
        );
        let sigma = Vector3::new(50.0, 50.0, 10.0);
        let runs = 20;
        let mut rows = Vec::new();
        for variant in variants() {
            let mut rng = StdRng::seed_from_u64(3);
            let (mut se_x, mut se_y, mut n) = (0.0, 0.0, 0usize);
            let mut cpu = std::time::Duration::ZERO;
            let mut model_steps = 0;
            for _ in 0..runs {
                let mut kf = tracker(variant);
                for (k, (t, p)) in truth.iter().enumerate() {
                    let z = Vector3::new(p.x, p.y, 0.0) + gaussian3(&mut rng, &sigma);
                    let m = Measurement {
                        t_s: *t,
                        position: Some(observed(z, &sigma)),
                        velocity: (k == 0).then(|| {
                            observed(Vector3::new(150.0, 0.0, 0.0), &Vector3::repeat(5.0))
                        }),
                    };
                    let start = std::time::Instant::now();
                    kf.update(&m).unwrap();
                    cpu += start.elapsed();
                    let est = kf.estimate().unwrap();
                    se_x += (est.pos_m.x - p.x).powi(2);
                    se_y += (est.pos_m.y - p.y).powi(2);
                    n += 1;
                }
                model_steps += kf.model_steps();
            }
            let (rx, ry) = ((se_x / n as f64).sqrt(), (se_y / n as f64).sqrt());
            println!(
                "paper 003 scenario, {:>11}: RMSE x {rx:6.2} m, y {ry:6.2} m; CPU {:.1} µs per \
                 update (debug build); {:.2} models per update",
                tracker(variant).name(),
                cpu.as_secs_f64() * 1e6 / n as f64,
                model_steps as f64 / n as f64
            );
            rows.push((rx, ry, model_steps));
            assert!(rx < 50.0 && ry < 50.0, "{variant:?}: {rx} {ry}");
        }
        // VSIMM runs fewer models than the fixed structures (counted, not timed: timings are
        // for the benchmarks, this machine's load makes them flaky in a test).
        assert!(
            rows[0].2 < rows[2].2,
            "VSIMM ran no fewer model steps than IMM-SRCKF"
        );
    }
}
