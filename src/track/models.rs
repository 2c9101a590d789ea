//! The motion models of paper 002 (ALGORITHMS.md §002, eq. 1–5) over one common 3-D state, so
//! that the IMM ([`super::imm`]) can mix them.
//!
//! State x = [e, n, u, ve, vn, vu, ae, an, au] (m, m/s, m/s², east-north-up), indices
//! [`POS`], [`VEL`], [`ACC`]. Paper 002 writes every model in its own state (2-D for CT, 2- or
//! 3-state per axis for the others, eq. 1–5) and stacks them in the 9-state γ of eq. (6); we
//! use that γ, so a model without acceleration "maps it to zero": its F sends the
//! acceleration to 0 and its Q gives it a small variance σ_r² (`acc_reset_sigma_mps2`), the
//! usual way of mixing models of unequal dimension in an IMM (the combined acceleration is
//! then the probability-weighted acceleration of the models that have one).
//!
//! The paper gives discrete-time models with a fixed sampling period T and a noise gain
//! matrix (T_CV, T_CA, ...). ADS-B reports are irregular (0.01 s to tens of seconds apart), so
//! each model here is the exact discretisation over the actual dt of a continuous-time model
//! ẋ = A x + G w, w white with spectral density Qc: F(dt) = exp(A dt) and
//! Q(dt) = ∫₀^dt exp(Aτ) G Qc Gᵀ exp(Aτ)ᵀ dτ (Bar-Shalom, Li, Kirubarajan, *Estimation with
//! Applications to Tracking and Navigation*, 2001, §6.2: "continuous white noise
//! acceleration" (CWNA, §6.2.2) for the constant-velocity channels, "continuous Wiener process
//! acceleration" (§6.2.3) for the constant-acceleration ones). The tests check every F against
//! the matrix exponential and every Q against numerical quadrature of that integral.

use super::kalman::MotionModel;
use nalgebra::{SMatrix, SVector};

/// The common IMM state [e, n, u, ve, vn, vu, ae, an, au].
pub type State9 = SVector<f64, 9>;
/// 9x9 matrix over [`State9`].
pub type Matrix9 = SMatrix<f64, 9, 9>;
/// The constant-velocity state [e, n, u, ve, vn, vu] (the first six entries of [`State9`]).
pub type State6 = SVector<f64, 6>;
/// 6x6 matrix over [`State6`].
pub type Matrix6 = SMatrix<f64, 6, 6>;

/// Index of the east position in the state; north and up follow.
pub const POS: usize = 0;
/// Index of the east velocity; north and up follow.
pub const VEL: usize = 3;
/// Index of the east acceleration; north and up follow.
pub const ACC: usize = 6;

/// Default σ_r of the acceleration a model without acceleration resets to zero, m/s².
/// Small (0.05 m/s²) so that such a model asserts "no acceleration", yet non-zero so that
/// its P stays positive definite.
pub const ACC_RESET_SIGMA_MPS2: f64 = 0.05;

/// F and Q of one constant-velocity axis (CWNA, Bar-Shalom et al. §6.2.2; paper 002 eq. 1):
/// F = [[1, T], [0, 1]], Q = qc [[T³/3, T²/2], [T²/2, T]]. `f` must be the identity on entry.
fn cv_axis<const N: usize>(
    f: &mut SMatrix<f64, N, N>,
    q: &mut SMatrix<f64, N, N>,
    axis: usize,
    dt_s: f64,
    qc: f64,
) {
    let (p, v) = (POS + axis, VEL + axis);
    let (t1, t2, t3) = (dt_s, dt_s * dt_s, dt_s * dt_s * dt_s);
    f[(p, v)] = t1;
    q[(p, p)] = qc * t3 / 3.0;
    q[(p, v)] = qc * t2 / 2.0;
    q[(v, p)] = qc * t2 / 2.0;
    q[(v, v)] = qc * t1;
}

/// F and Q of one constant-acceleration axis, Wiener-process acceleration (white jerk of
/// density qj; Bar-Shalom et al. §6.2.3; paper 002 eq. 2 for F):
/// F = [[1, T, T²/2], [0, 1, T], [0, 0, 1]],
/// Q = qj [[T⁵/20, T⁴/8, T³/6], [T⁴/8, T³/3, T²/2], [T³/6, T²/2, T]].
fn ca_axis<const N: usize>(
    f: &mut SMatrix<f64, N, N>,
    q: &mut SMatrix<f64, N, N>,
    axis: usize,
    dt_s: f64,
    qj: f64,
) {
    let (p, v, a) = (POS + axis, VEL + axis, ACC + axis);
    let t = dt_s;
    let (t2, t3) = (t * t, t * t * t);
    let (t4, t5) = (t3 * t, t3 * t2);
    f[(p, v)] = t;
    f[(p, a)] = t2 / 2.0;
    f[(v, a)] = t;
    let entries = [
        (p, p, t5 / 20.0),
        (p, v, t4 / 8.0),
        (p, a, t3 / 6.0),
        (v, v, t3 / 3.0),
        (v, a, t2 / 2.0),
        (a, a, t),
    ];
    for (i, j, value) in entries {
        q[(i, j)] = qj * value;
        q[(j, i)] = qj * value;
    }
}

/// The acceleration of `axis` is not part of the model: F sends it to zero, Q gives it σ_r².
fn reset_acc_axis(f: &mut Matrix9, q: &mut Matrix9, axis: usize, sigma_mps2: f64) {
    let a = ACC + axis;
    f[(a, a)] = 0.0;
    q[(a, a)] = sigma_mps2 * sigma_mps2;
}

/// Constant velocity in 3-D (paper 002 eq. 1, CWNA): straight flight. Horizontal and
/// vertical acceleration densities differ; the acceleration state is reset to zero.
///
/// Implements `MotionModel<6>` as well (the same model over [`State6`]): the hybrid tracker
/// runs this cheap 6-state filter on straight legs and the 9-state one inside the IMM.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cv {
    /// Horizontal acceleration spectral density q_h, m²/s³ (per axis).
    pub q_h_m2ps3: f64,
    /// Vertical acceleration spectral density q_v, m²/s³.
    pub q_v_m2ps3: f64,
    /// σ_r of the reset acceleration, m/s².
    pub acc_reset_sigma_mps2: f64,
}

impl Default for Cv {
    /// q_h = (0.5 m/s²)²·s = 0.25: an airliner in "straight" flight changes speed by at most
    /// ~0.5 m/s² (thrust changes, gusts, gentle heading corrections); q_v = (0.3 m/s²)²·s =
    /// 0.09: airline operations keep vertical load-factor changes within about ±0.05 g. The
    /// same tuning as the project's 6-state CV filter (`track::cv`). The hybrid's own CV
    /// filter, for steady flight only, takes less (`hybrid::STEADY_Q_H_M2PS3`).
    fn default() -> Self {
        Self {
            q_h_m2ps3: 0.25,
            q_v_m2ps3: 0.09,
            acc_reset_sigma_mps2: ACC_RESET_SIGMA_MPS2,
        }
    }
}

impl Cv {
    fn densities(&self) -> [f64; 3] {
        [self.q_h_m2ps3, self.q_h_m2ps3, self.q_v_m2ps3]
    }
}

fn cv3d<const N: usize>(
    dt_s: f64,
    densities: [f64; 3],
) -> (SMatrix<f64, N, N>, SMatrix<f64, N, N>) {
    let mut f = SMatrix::<f64, N, N>::identity();
    let mut q = SMatrix::<f64, N, N>::zeros();
    for (axis, qc) in densities.into_iter().enumerate() {
        cv_axis(&mut f, &mut q, axis, dt_s, qc);
    }
    (f, q)
}

fn cv3d_reset(dt_s: f64, densities: [f64; 3], sigma_r: f64) -> (Matrix9, Matrix9) {
    let (mut f, mut q) = cv3d::<9>(dt_s, densities);
    for axis in 0..3 {
        reset_acc_axis(&mut f, &mut q, axis, sigma_r);
    }
    (f, q)
}

impl MotionModel<6> for Cv {
    fn f(&self, dt_s: f64) -> Matrix6 {
        cv3d::<6>(dt_s, self.densities()).0
    }
    fn q(&self, dt_s: f64) -> Matrix6 {
        cv3d::<6>(dt_s, self.densities()).1
    }
    fn fq(&self, dt_s: f64) -> (Matrix6, Matrix6) {
        cv3d::<6>(dt_s, self.densities())
    }
}

impl MotionModel<9> for Cv {
    fn f(&self, dt_s: f64) -> Matrix9 {
        cv3d_reset(dt_s, self.densities(), self.acc_reset_sigma_mps2).0
    }
    fn q(&self, dt_s: f64) -> Matrix9 {
        cv3d_reset(dt_s, self.densities(), self.acc_reset_sigma_mps2).1
    }
    fn fq(&self, dt_s: f64) -> (Matrix9, Matrix9) {
        cv3d_reset(dt_s, self.densities(), self.acc_reset_sigma_mps2)
    }
}

/// Constant along-track acceleration at constant altitude (paper 002 eq. 2, "CA: constant
/// acceleration or deceleration, heading unchanged, level"): horizontal Wiener-process
/// acceleration, vertical CWNA with the small level-flight density; the vertical
/// acceleration is reset to zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ca {
    /// Horizontal jerk spectral density q_j, m²/s⁵ (per axis).
    pub jerk_q_h_m2ps5: f64,
    /// Vertical acceleration spectral density, m²/s³.
    pub q_v_m2ps3: f64,
    /// σ_r of the reset vertical acceleration, m/s².
    pub acc_reset_sigma_mps2: f64,
}

impl Default for Ca {
    /// q_j = 0.5 m²/s⁵: the acceleration random-walks by 0.7 m/s² per √s, so the model
    /// reaches an airliner's 1–2 m/s² along-track acceleration (take-off, speed changes on
    /// ATC request) within 2–4 s of its onset; vertical as [`Cv`].
    fn default() -> Self {
        Self {
            jerk_q_h_m2ps5: 0.5,
            q_v_m2ps3: 0.09,
            acc_reset_sigma_mps2: ACC_RESET_SIGMA_MPS2,
        }
    }
}

/// Horizontal CA and vertical CWNA over the leading N ≥ 8 states (the vertical acceleration,
/// state 8, not included when N = 8).
fn ca_level<const N: usize>(
    dt_s: f64,
    qj: f64,
    q_v: f64,
) -> (SMatrix<f64, N, N>, SMatrix<f64, N, N>) {
    let mut f = SMatrix::<f64, N, N>::identity();
    let mut q = SMatrix::<f64, N, N>::zeros();
    ca_axis(&mut f, &mut q, 0, dt_s, qj);
    ca_axis(&mut f, &mut q, 1, dt_s, qj);
    cv_axis(&mut f, &mut q, 2, dt_s, q_v);
    (f, q)
}

fn ca_with_vertical_cv(dt_s: f64, qj: f64, q_v: f64, sigma_r: f64) -> (Matrix9, Matrix9) {
    let (mut f, mut q) = ca_level::<9>(dt_s, qj, q_v);
    reset_acc_axis(&mut f, &mut q, 2, sigma_r);
    (f, q)
}

impl MotionModel<9> for Ca {
    fn f(&self, dt_s: f64) -> Matrix9 {
        ca_with_vertical_cv(dt_s, self.jerk_q_h_m2ps5, self.q_v_m2ps3, 0.0).0
    }
    fn q(&self, dt_s: f64) -> Matrix9 {
        ca_with_vertical_cv(
            dt_s,
            self.jerk_q_h_m2ps5,
            self.q_v_m2ps3,
            self.acc_reset_sigma_mps2,
        )
        .1
    }
    /// F does not depend on the densities: one evaluation gives both.
    fn fq(&self, dt_s: f64) -> (Matrix9, Matrix9) {
        ca_with_vertical_cv(
            dt_s,
            self.jerk_q_h_m2ps5,
            self.q_v_m2ps3,
            self.acc_reset_sigma_mps2,
        )
    }
}

/// Coordinated turn in the horizontal plane at a FIXED turn rate ω (paper 002 eq. 3), the
/// vertical channel CWNA, the acceleration reset to zero.
///
/// Choice (ALGORITHMS.md leaves it open): fixed rates, one model per direction (ω > 0 is
/// counter-clockwise seen from above, i.e. a LEFT turn; the IMM holds a +ω and a −ω model),
/// which keeps the model linear so the IMM stays a bank of plain Kalman filters. The rate is
/// a field, so the hybrid tracker may set it from the turn rate its gate measures in the
/// velocity reports ([`super::hybrid::HybridParams::adapt_turn_rate`]).
///
/// Continuous model, horizontal: ṗ = v, v̇ = ω J v + w, J = [[0, −1], [1, 0]], w white with
/// density q_h I. With c = cos ωT, s = sin ωT:
/// F_pv = [[s/ω, −(1 − c)/ω], [(1 − c)/ω, s/ω]], F_vv = [[c, −s], [s, c]] (paper eq. 3);
/// Q_pp = q_h·2(T − s/ω)/ω² I, Q_pv = q_h[(1 − c)/ω² I − (T − s/ω)/ω J], Q_vv = q_h T I
/// (the isotropic noise commutes with the rotation, which makes these closed forms short).
/// For |ωT| < 0.1 the coefficients come from their Taylor series (the closed forms cancel
/// catastrophically as ω → 0); at ω = 0 the model is exactly [`Cv`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ct {
    /// Turn rate ω, rad/s; positive = left (counter-clockwise).
    pub omega_rad_s: f64,
    /// Horizontal acceleration density around the turn, m²/s³.
    pub q_h_m2ps3: f64,
    /// Vertical acceleration density, m²/s³.
    pub q_v_m2ps3: f64,
    /// σ_r of the reset acceleration, m/s².
    pub acc_reset_sigma_mps2: f64,
}

/// The standard-rate turn, 3°/s (ICAO Doc 8168; the rate of paper 002's scenario), rad/s.
pub const STANDARD_RATE_RAD_S: f64 = 3.0 * std::f64::consts::PI / 180.0;

impl Ct {
    /// A left (+) or right (−) turn at `rate_rad_s` (magnitude) with the default noise.
    pub fn turning(left: bool, rate_rad_s: f64) -> Self {
        let omega = rate_rad_s.abs();
        Self {
            omega_rad_s: if left { omega } else { -omega },
            ..Self::default()
        }
    }
}

impl Default for Ct {
    /// A left standard-rate turn; q_h = 0.5 m²/s³ covers the mismatch between the fixed rate
    /// and the rate actually flown (and roll-in/roll-out), q_v as [`Cv`].
    fn default() -> Self {
        Self {
            omega_rad_s: STANDARD_RATE_RAD_S,
            q_h_m2ps3: 0.5,
            q_v_m2ps3: 0.09,
            acc_reset_sigma_mps2: ACC_RESET_SIGMA_MPS2,
        }
    }
}

/// The trigonometric coefficients of the CT model over one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CtCoefficients {
    /// cos ωT.
    pub cos: f64,
    /// sin ωT.
    pub sin: f64,
    /// sin(ωT)/ω.
    pub sin_over_w: f64,
    /// (1 − cos ωT)/ω.
    pub one_minus_cos_over_w: f64,
    /// (1 − cos ωT)/ω².
    pub one_minus_cos_over_w2: f64,
    /// (T − sin(ωT)/ω)/ω.
    pub t_minus_sin_over_w2: f64,
    /// 2(T − sin(ωT)/ω)/ω².
    pub two_t_minus_sin_over_w3: f64,
}

/// Below this |ωT| the CT coefficients come from their Taylor series. At 0.1 the next
/// neglected term (x¹⁰/11!) is below 1e-17 relative, while the closed forms would already
/// lose ~1e-12 to cancellation.
pub const CT_SERIES_BELOW: f64 = 0.1;

/// Evaluates Σ cₖ y^k by Horner's rule.
fn horner(y: f64, coefficients: &[f64]) -> f64 {
    coefficients.iter().rev().fold(0.0, |acc, c| acc * y + c)
}

/// The CT coefficients for turn rate `omega_rad_s` over `dt_s`.
pub fn ct_coefficients(omega_rad_s: f64, dt_s: f64) -> CtCoefficients {
    let t = dt_s;
    let x = omega_rad_s * t;
    let (sin, cos) = x.sin_cos();
    if x.abs() < CT_SERIES_BELOW {
        let y = x * x;
        // sin x / x, (1 − cos x)/x², (x − sin x)/x³ as series in y = x².
        let sinc = horner(
            y,
            &[1.0, -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362_880.0],
        );
        let cosc2 = horner(
            y,
            &[
                0.5,
                -1.0 / 24.0,
                1.0 / 720.0,
                -1.0 / 40_320.0,
                1.0 / 3_628_800.0,
            ],
        );
        let sinc3 = horner(
            y,
            &[
                1.0 / 6.0,
                -1.0 / 120.0,
                1.0 / 5040.0,
                -1.0 / 362_880.0,
                1.0 / 39_916_800.0,
            ],
        );
        CtCoefficients {
            cos,
            sin,
            sin_over_w: t * sinc,
            one_minus_cos_over_w: t * x * cosc2,
            one_minus_cos_over_w2: t * t * cosc2,
            t_minus_sin_over_w2: t * t * x * sinc3,
            two_t_minus_sin_over_w3: 2.0 * t * t * t * sinc3,
        }
    } else {
        let w = omega_rad_s;
        let t_minus = t - sin / w;
        CtCoefficients {
            cos,
            sin,
            sin_over_w: sin / w,
            one_minus_cos_over_w: (1.0 - cos) / w,
            one_minus_cos_over_w2: (1.0 - cos) / (w * w),
            t_minus_sin_over_w2: t_minus / w,
            two_t_minus_sin_over_w3: 2.0 * t_minus / (w * w),
        }
    }
}

fn ct_fq(m: &Ct, dt_s: f64) -> (Matrix9, Matrix9) {
    let (mut f, mut q) = ct_pos_vel::<9>(m, dt_s);
    for axis in 0..3 {
        reset_acc_axis(&mut f, &mut q, axis, m.acc_reset_sigma_mps2);
    }
    (f, q)
}

/// The CT model's F and Q over the leading N ≥ 6 states (position and velocity; the
/// acceleration states, when N = 9, left at the identity and zero).
fn ct_pos_vel<const N: usize>(m: &Ct, dt_s: f64) -> (SMatrix<f64, N, N>, SMatrix<f64, N, N>) {
    let (mut f, mut q) = cv3d::<N>(dt_s, [m.q_h_m2ps3, m.q_h_m2ps3, m.q_v_m2ps3]);
    let k = ct_coefficients(m.omega_rad_s, dt_s);
    let (e, n, ve, vn) = (POS, POS + 1, VEL, VEL + 1);
    f[(e, ve)] = k.sin_over_w;
    f[(e, vn)] = -k.one_minus_cos_over_w;
    f[(n, ve)] = k.one_minus_cos_over_w;
    f[(n, vn)] = k.sin_over_w;
    f[(ve, ve)] = k.cos;
    f[(ve, vn)] = -k.sin;
    f[(vn, ve)] = k.sin;
    f[(vn, vn)] = k.cos;
    let qh = m.q_h_m2ps3;
    let pp = qh * k.two_t_minus_sin_over_w3;
    let pv_i = qh * k.one_minus_cos_over_w2;
    let pv_j = qh * k.t_minus_sin_over_w2;
    let entries = [
        (e, e, pp),
        (n, n, pp),
        (e, n, 0.0),
        (e, ve, pv_i),
        (e, vn, pv_j),
        (n, ve, -pv_j),
        (n, vn, pv_i),
        (ve, ve, qh * dt_s),
        (vn, vn, qh * dt_s),
        (ve, vn, 0.0),
    ];
    for (i, j, value) in entries {
        q[(i, j)] = value;
        q[(j, i)] = value;
    }
    (f, q)
}

impl MotionModel<9> for Ct {
    fn f(&self, dt_s: f64) -> Matrix9 {
        ct_fq(self, dt_s).0
    }
    fn q(&self, dt_s: f64) -> Matrix9 {
        ct_fq(self, dt_s).1
    }
    fn fq(&self, dt_s: f64) -> (Matrix9, Matrix9) {
        ct_fq(self, dt_s)
    }
}

/// Climb or descent at constant ground velocity (paper 002 eq. 4, "CH: constant climb or
/// descent rate at constant ground speed"): 3-D CWNA with the horizontal density of [`Cv`]
/// and a larger vertical one; the acceleration is reset to zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ch {
    /// Horizontal acceleration density, m²/s³.
    pub q_h_m2ps3: f64,
    /// Vertical acceleration density, m²/s³.
    pub q_v_m2ps3: f64,
    /// σ_r of the reset acceleration, m/s².
    pub acc_reset_sigma_mps2: f64,
}

impl Default for Ch {
    /// q_v = (1 m/s²)²·s: the vertical rate changes by 5–15 m/s within 5–15 s at a climb
    /// onset or a level-off; horizontal as [`Cv`].
    fn default() -> Self {
        Self {
            q_h_m2ps3: 0.25,
            q_v_m2ps3: 1.0,
            acc_reset_sigma_mps2: ACC_RESET_SIGMA_MPS2,
        }
    }
}

impl MotionModel<9> for Ch {
    fn f(&self, dt_s: f64) -> Matrix9 {
        cv3d_reset(dt_s, [0.0; 3], 0.0).0
    }
    fn q(&self, dt_s: f64) -> Matrix9 {
        cv3d_reset(
            dt_s,
            [self.q_h_m2ps3, self.q_h_m2ps3, self.q_v_m2ps3],
            self.acc_reset_sigma_mps2,
        )
        .1
    }
    /// F does not depend on the densities: one evaluation gives both.
    fn fq(&self, dt_s: f64) -> (Matrix9, Matrix9) {
        cv3d_reset(
            dt_s,
            [self.q_h_m2ps3, self.q_h_m2ps3, self.q_v_m2ps3],
            self.acc_reset_sigma_mps2,
        )
    }
}

/// Climb or descent with horizontal acceleration (paper 002 eq. 5, "CHCA: take-off and
/// landing"): horizontal Wiener-process acceleration as [`Ca`], vertical CWNA with the
/// larger density of [`Ch`]; the vertical acceleration is reset to zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chca {
    /// Horizontal jerk density, m²/s⁵.
    pub jerk_q_h_m2ps5: f64,
    /// Vertical acceleration density, m²/s³.
    pub q_v_m2ps3: f64,
    /// σ_r of the reset vertical acceleration, m/s².
    pub acc_reset_sigma_mps2: f64,
}

impl Default for Chca {
    /// Horizontal as [`Ca`], vertical as [`Ch`].
    fn default() -> Self {
        Self {
            jerk_q_h_m2ps5: 0.5,
            q_v_m2ps3: 1.0,
            acc_reset_sigma_mps2: ACC_RESET_SIGMA_MPS2,
        }
    }
}

impl MotionModel<9> for Chca {
    fn f(&self, dt_s: f64) -> Matrix9 {
        ca_with_vertical_cv(dt_s, 0.0, 0.0, 0.0).0
    }
    fn q(&self, dt_s: f64) -> Matrix9 {
        ca_with_vertical_cv(
            dt_s,
            self.jerk_q_h_m2ps5,
            self.q_v_m2ps3,
            self.acc_reset_sigma_mps2,
        )
        .1
    }
    /// F does not depend on the densities: one evaluation gives both.
    fn fq(&self, dt_s: f64) -> (Matrix9, Matrix9) {
        ca_with_vertical_cv(
            dt_s,
            self.jerk_q_h_m2ps5,
            self.q_v_m2ps3,
            self.acc_reset_sigma_mps2,
        )
    }
}

/// Any of the five models: the IMM's model list without boxing (static dispatch, no
/// allocation), still usable as `&dyn MotionModel<9>`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Model {
    /// Constant velocity.
    Cv(Cv),
    /// Constant acceleration, level.
    Ca(Ca),
    /// Coordinated turn.
    Ct(Ct),
    /// Climb/descent at constant ground velocity.
    Ch(Ch),
    /// Climb/descent with horizontal acceleration.
    Chca(Chca),
}

impl Model {
    /// The model as a trait object.
    pub fn as_dyn(&self) -> &dyn MotionModel<9> {
        match self {
            Model::Cv(m) => m,
            Model::Ca(m) => m,
            Model::Ct(m) => m,
            Model::Ch(m) => m,
            Model::Chca(m) => m,
        }
    }
}

/// A 9-state model that resets its states from `K` on at every step: F's rows and columns
/// there are zero and Q gives each of them σ_r² and nothing else.
///
/// Such a state leaves every prediction as (0, σ_r²) whatever it held, uncorrelated with the
/// rest, and a position or velocity report does not see it, so the update leaves it there.
/// The leading K states can therefore be predicted and updated alone: the same numbers as
/// the 9-state step, a fraction of the work. The IMM's CV, CT and CH models are 6-state
/// filters in disguise, its CA and CHCA models 8-state ones.
pub trait ResetTail<const K: usize>: MotionModel<9> {
    /// The leading K×K blocks of F(dt) and Q(dt) (tested against `fq`).
    fn leading_fq(&self, dt_s: f64) -> (SMatrix<f64, K, K>, SMatrix<f64, K, K>);
    /// σ_r², the variance each reset state is given, (m/s²)².
    fn reset_variance(&self) -> f64;
}

impl ResetTail<6> for Cv {
    /// The 6-state CV filter's F and Q.
    fn leading_fq(&self, dt_s: f64) -> (Matrix6, Matrix6) {
        MotionModel::<6>::fq(self, dt_s)
    }
    fn reset_variance(&self) -> f64 {
        self.acc_reset_sigma_mps2 * self.acc_reset_sigma_mps2
    }
}

impl ResetTail<6> for Ct {
    fn leading_fq(&self, dt_s: f64) -> (Matrix6, Matrix6) {
        ct_pos_vel::<6>(self, dt_s)
    }
    fn reset_variance(&self) -> f64 {
        self.acc_reset_sigma_mps2 * self.acc_reset_sigma_mps2
    }
}

impl ResetTail<6> for Ch {
    fn leading_fq(&self, dt_s: f64) -> (Matrix6, Matrix6) {
        cv3d::<6>(dt_s, [self.q_h_m2ps3, self.q_h_m2ps3, self.q_v_m2ps3])
    }
    fn reset_variance(&self) -> f64 {
        self.acc_reset_sigma_mps2 * self.acc_reset_sigma_mps2
    }
}

/// The 8-state leading block of a model with horizontal acceleration.
pub type Matrix8 = SMatrix<f64, 8, 8>;

impl ResetTail<8> for Ca {
    fn leading_fq(&self, dt_s: f64) -> (Matrix8, Matrix8) {
        ca_level::<8>(dt_s, self.jerk_q_h_m2ps5, self.q_v_m2ps3)
    }
    fn reset_variance(&self) -> f64 {
        self.acc_reset_sigma_mps2 * self.acc_reset_sigma_mps2
    }
}

impl ResetTail<8> for Chca {
    fn leading_fq(&self, dt_s: f64) -> (Matrix8, Matrix8) {
        ca_level::<8>(dt_s, self.jerk_q_h_m2ps5, self.q_v_m2ps3)
    }
    fn reset_variance(&self) -> f64 {
        self.acc_reset_sigma_mps2 * self.acc_reset_sigma_mps2
    }
}

impl MotionModel<9> for Model {
    fn f(&self, dt_s: f64) -> Matrix9 {
        self.as_dyn().f(dt_s)
    }
    fn q(&self, dt_s: f64) -> Matrix9 {
        self.as_dyn().q(dt_s)
    }
    fn fq(&self, dt_s: f64) -> (Matrix9, Matrix9) {
        self.as_dyn().fq(dt_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DTS: [f64; 6] = [0.05, 0.5, 1.0, 4.2, 12.5, 30.0];

    /// The continuous model behind a discrete one: A, G Qc Gᵀ, and which acceleration
    /// components are reset (not part of the continuous dynamics).
    struct Continuous {
        a: Matrix9,
        gqg: Matrix9,
        reset: [bool; 9],
        reset_var: f64,
    }

    fn continuous(model: &Model) -> Continuous {
        let mut a = Matrix9::zeros();
        let mut gqg = Matrix9::zeros();
        let mut reset = [false; 9];
        for axis in 0..3 {
            a[(POS + axis, VEL + axis)] = 1.0;
        }
        let (q_acc, q_jerk, accel_axes, sigma_r): ([f64; 3], f64, usize, f64) = match model {
            Model::Cv(m) => (
                [m.q_h_m2ps3, m.q_h_m2ps3, m.q_v_m2ps3],
                0.0,
                0,
                m.acc_reset_sigma_mps2,
            ),
            Model::Ch(m) => (
                [m.q_h_m2ps3, m.q_h_m2ps3, m.q_v_m2ps3],
                0.0,
                0,
                m.acc_reset_sigma_mps2,
            ),
            Model::Ct(m) => {
                a[(VEL, VEL + 1)] = -m.omega_rad_s;
                a[(VEL + 1, VEL)] = m.omega_rad_s;
                (
                    [m.q_h_m2ps3, m.q_h_m2ps3, m.q_v_m2ps3],
                    0.0,
                    0,
                    m.acc_reset_sigma_mps2,
                )
            }
            Model::Ca(m) => (
                [0.0, 0.0, m.q_v_m2ps3],
                m.jerk_q_h_m2ps5,
                2,
                m.acc_reset_sigma_mps2,
            ),
            Model::Chca(m) => (
                [0.0, 0.0, m.q_v_m2ps3],
                m.jerk_q_h_m2ps5,
                2,
                m.acc_reset_sigma_mps2,
            ),
        };
        for axis in 0..3 {
            if axis < accel_axes {
                a[(VEL + axis, ACC + axis)] = 1.0;
                gqg[(ACC + axis, ACC + axis)] = q_jerk;
            } else {
                gqg[(VEL + axis, VEL + axis)] = q_acc[axis];
                reset[ACC + axis] = true;
            }
        }
        Continuous {
            a,
            gqg,
            reset,
            reset_var: sigma_r * sigma_r,
        }
    }

    fn all_models() -> Vec<(&'static str, Model)> {
        vec![
            ("CV", Model::Cv(Cv::default())),
            ("CA", Model::Ca(Ca::default())),
            ("CT left", Model::Ct(Ct::turning(true, STANDARD_RATE_RAD_S))),
            (
                "CT right 6 deg/s",
                Model::Ct(Ct::turning(false, 2.0 * STANDARD_RATE_RAD_S)),
            ),
            ("CH", Model::Ch(Ch::default())),
            ("CHCA", Model::Chca(Chca::default())),
        ]
    }

    /// Relative difference of two matrices, by the largest entry of the reference.
    fn rel(a: &Matrix9, b: &Matrix9) -> f64 {
        (a - b).abs().max() / b.abs().max().max(1e-300)
    }

    /// Q by composite Simpson over 600 intervals of exp(Aτ) G Qc Gᵀ exp(Aτ)ᵀ, with exp(Aτ)
    /// advanced by multiplying with exp(A h) (nalgebra's Padé exponential).
    fn q_by_quadrature(c: &Continuous, dt: f64) -> Matrix9 {
        let n = 600;
        let h = dt / n as f64;
        let step = (c.a * h).exp();
        let mut e = Matrix9::identity();
        let mut sum = Matrix9::zeros();
        for i in 0..=n {
            let w = if i == 0 || i == n {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            sum += w * e * c.gqg * e.transpose();
            e *= step;
        }
        sum * h / 3.0
    }

    #[test]
    fn every_f_matches_the_matrix_exponential_of_its_continuous_model() {
        for (name, model) in all_models() {
            let c = continuous(&model);
            for dt in DTS {
                let f = model.f(dt);
                let mut expected = (c.a * dt).exp();
                for (i, &is_reset) in c.reset.iter().enumerate() {
                    if is_reset {
                        // A reset component: its row and column of F are zero.
                        expected.row_mut(i).fill(0.0);
                        expected.column_mut(i).fill(0.0);
                    }
                }
                assert!(
                    rel(&f, &expected) < 1e-12,
                    "{name} F at dt {dt}: {f} vs {expected}"
                );
            }
        }
    }

    #[test]
    fn every_q_matches_numerical_integration_of_the_continuous_noise() {
        for (name, model) in all_models() {
            let c = continuous(&model);
            for dt in DTS {
                let q = model.q(dt);
                let mut expected = q_by_quadrature(&c, dt);
                for (i, &is_reset) in c.reset.iter().enumerate() {
                    if is_reset {
                        expected[(i, i)] = c.reset_var;
                    }
                }
                assert!(
                    rel(&q, &expected) < 1e-9,
                    "{name} Q at dt {dt}: {q} vs {expected}"
                );
                // Entry by entry too: the small entries must not hide behind the largest.
                for i in 0..9 {
                    for j in 0..9 {
                        let scale = (expected[(i, i)] * expected[(j, j)]).sqrt();
                        assert!(
                            (q[(i, j)] - expected[(i, j)]).abs() <= 1e-9 * scale + 1e-300,
                            "{name} Q[{i},{j}] at dt {dt}"
                        );
                    }
                }
                assert_eq!(q, q.transpose(), "{name} Q symmetric");
                assert!(q.cholesky().is_some(), "{name} Q positive definite at {dt}");
            }
        }
    }

    #[test]
    fn closed_forms_of_paper_002() {
        let t = 2.0;
        // CA (eq. 2): [[1, T, T²/2], [0, 1, T], [0, 0, 1]] per horizontal axis.
        let f = Ca::default().f(t);
        assert_eq!(f[(POS, VEL)], 2.0);
        assert_eq!(f[(POS, ACC)], 2.0);
        assert_eq!(f[(VEL + 1, ACC + 1)], 2.0);
        assert_eq!(f[(ACC + 1, ACC + 1)], 1.0);
        assert_eq!(f[(ACC + 2, ACC + 2)], 0.0);
        // Wiener-acceleration Q: qj T⁵/20 = 0.5·32/20 = 0.8; qj T³/6 = 0.5·8/6.
        let q = Ca::default().q(t);
        assert!((q[(POS, POS)] - 0.8).abs() < 1e-15);
        assert!((q[(POS, ACC)] - 2.0 / 3.0).abs() < 1e-15);
        // CT (eq. 3) at ω = 3°/s, T = 10 s: ωT = π/6.
        let ct = Ct::turning(true, STANDARD_RATE_RAD_S);
        let w = STANDARD_RATE_RAD_S;
        let f = ct.f(10.0);
        let (s, c) = (0.5, 3f64.sqrt() / 2.0);
        assert!((f[(POS, VEL)] - s / w).abs() < 1e-12);
        assert!((f[(POS, VEL + 1)] + (1.0 - c) / w).abs() < 1e-12);
        assert!((f[(POS + 1, VEL)] - (1.0 - c) / w).abs() < 1e-12);
        assert!((f[(VEL, VEL)] - c).abs() < 1e-15 && (f[(VEL + 1, VEL)] - s).abs() < 1e-15);
        // A left turn from east heads north-east: v = (100, 0) becomes (100c, 100s).
        let mut x = State9::zeros();
        x[VEL] = 100.0;
        let x1 = f * x;
        assert!((x1[VEL] - 100.0 * c).abs() < 1e-12 && (x1[VEL + 1] - 50.0).abs() < 1e-12);
        // CV and CH share F; CA and CHCA share F.
        assert_eq!(MotionModel::<9>::f(&Cv::default(), t), Ch::default().f(t));
        assert_eq!(Ca::default().f(t), Chca::default().f(t));
        // The 6-state CV is the 9-state one without the acceleration.
        let cv = Cv::default();
        let (f6, q6): (Matrix6, Matrix6) = (cv.f(t), cv.q(t));
        let (f9, q9): (Matrix9, Matrix9) = (cv.f(t), cv.q(t));
        assert_eq!(f6, f9.fixed_view::<6, 6>(0, 0).into_owned());
        assert_eq!(q6, q9.fixed_view::<6, 6>(0, 0).into_owned());
    }

    #[test]
    fn ct_tends_to_cv_as_the_turn_rate_vanishes() {
        let cv = Cv {
            q_h_m2ps3: 0.5,
            ..Cv::default()
        };
        for dt in DTS {
            for w in [0.0, 1e-300, 1e-12, -1e-9] {
                let ct = Ct {
                    omega_rad_s: w,
                    ..Ct::default()
                };
                // The true F differs from CV's by sin ωT ≈ ωT in the velocity rotation.
                let tol = 1e-14 + 2.0 * (w * dt).abs();
                let f_cv = MotionModel::<9>::f(&cv, dt);
                let q_cv = MotionModel::<9>::q(&cv, dt);
                assert!(rel(&ct.f(dt), &f_cv) <= tol, "F {w} {dt}");
                assert!(rel(&ct.q(dt), &q_cv) <= tol, "Q {w} {dt}");
            }
        }
    }

    #[test]
    fn ct_series_and_closed_forms_agree_at_the_switch_and_match_the_exponential() {
        // Just either side of |ωT| = 0.1 the two branches must agree to rounding.
        let dt = 1.0;
        let below = ct_coefficients(0.1 * (1.0 - 1e-12), dt);
        let above = ct_coefficients(0.1 * (1.0 + 1e-12), dt);
        let pairs = [
            (below.sin_over_w, above.sin_over_w),
            (below.one_minus_cos_over_w, above.one_minus_cos_over_w),
            (below.one_minus_cos_over_w2, above.one_minus_cos_over_w2),
            (below.t_minus_sin_over_w2, above.t_minus_sin_over_w2),
            (below.two_t_minus_sin_over_w3, above.two_t_minus_sin_over_w3),
        ];
        for (i, (b, a)) in pairs.iter().enumerate() {
            assert!(((b - a) / a).abs() < 1e-10, "coefficient {i}: {b} vs {a}");
        }
        // Small but non-zero ω inside the series range: F against exp(A T) and Q against
        // quadrature (catastrophic cancellation in the closed forms would show here).
        for w in [1e-7, 1e-4, 0.01] {
            let model = Model::Ct(Ct {
                omega_rad_s: w,
                ..Ct::default()
            });
            let c = continuous(&model);
            for dt in [0.05, 2.0, 9.0] {
                let mut expected = (c.a * dt).exp();
                for i in ACC..ACC + 3 {
                    expected.row_mut(i).fill(0.0);
                    expected.column_mut(i).fill(0.0);
                }
                assert!(rel(&model.f(dt), &expected) < 1e-13, "F {w} {dt}");
                // (T − sin ωT/ω)/ω ≈ ωT³/6 is the coefficient the closed form would lose.
                let k = ct_coefficients(w, dt);
                let x = w * dt;
                // Reference: Σₖ (−1)ᵏ x^(2k+1)/(2k+3)! summed term by term to 12 terms.
                let mut reference = 0.0;
                let mut term = x / 6.0;
                for k in 0..12 {
                    reference += term;
                    let n = (2 * k + 4) as f64;
                    term *= -x * x / (n * (n + 1.0));
                }
                reference *= dt * dt;
                assert!(((k.t_minus_sin_over_w2 - reference) / reference).abs() < 1e-12);
                let mut q_ref = q_by_quadrature(&c, dt);
                for i in ACC..ACC + 3 {
                    q_ref[(i, i)] = c.reset_var;
                }
                assert!(rel(&model.q(dt), &q_ref) < 1e-9, "Q {w} {dt}");
            }
        }
    }

    #[test]
    fn models_are_object_safe_and_dispatch() {
        let models: Vec<Box<dyn MotionModel<9>>> =
            vec![Box::new(Cv::default()), Box::new(Model::Ct(Ct::default()))];
        let by_enum = Model::Ct(Ct::default());
        assert_eq!(models[1].f(3.0), by_enum.as_dyn().f(3.0));
        assert_eq!(models[0].q(3.0), MotionModel::<9>::q(&Cv::default(), 3.0));
    }

    /// `fq` is `(f, q)` for every model (it shares their work, nothing else).
    #[test]
    fn fq_is_f_and_q() {
        let models = [
            Model::Cv(Cv::default()),
            Model::Ca(Ca::default()),
            Model::Ct(Ct::default()),
            Model::Ct(Ct::turning(false, 0.01)),
            Model::Ch(Ch::default()),
            Model::Chca(Chca::default()),
        ];
        for dt in [0.0, 0.3, 1.0, 17.0] {
            for m in &models {
                assert_eq!(m.fq(dt), (m.f(dt), m.q(dt)), "{m:?} at {dt}");
            }
            let cv = Cv::default();
            assert_eq!(
                MotionModel::<6>::fq(&cv, dt),
                (MotionModel::<6>::f(&cv, dt), MotionModel::<6>::q(&cv, dt))
            );
        }
    }

    /// What [`ResetTail`] claims of a model, checked on its 9-state F and Q: they are the
    /// K-state ones bordered by zeros, with σ_r² on Q's diagonal from K on.
    fn assert_reset_tail<const K: usize>(model: &impl ResetTail<K>) {
        let var = model.reset_variance();
        assert!(var > 0.0);
        for dt in [0.0, 0.05, 0.5, 1.0, 4.2, 30.0] {
            let (f9, q9) = MotionModel::<9>::fq(model, dt);
            let (fk, qk) = model.leading_fq(dt);
            for i in 0..9 {
                for j in 0..9 {
                    let (f, q) = if i < K && j < K {
                        (fk[(i, j)], qk[(i, j)])
                    } else if i == j {
                        (0.0, var)
                    } else {
                        (0.0, 0.0)
                    };
                    assert_eq!((f9[(i, j)], q9[(i, j)]), (f, q), "({i}, {j}) at dt {dt}");
                }
            }
        }
    }

    #[test]
    fn the_imm_models_are_their_leading_blocks_and_a_reset_tail() {
        assert_reset_tail::<6>(&Cv::default());
        assert_reset_tail::<6>(&Ct::default());
        assert_reset_tail::<6>(&Ct::turning(false, 0.01));
        assert_reset_tail::<6>(&Ct::turning(true, 1e-9));
        assert_reset_tail::<6>(&Ch::default());
        assert_reset_tail::<8>(&Ca::default());
        assert_reset_tail::<8>(&Chca::default());
    }
}
