//! Linear Kalman steps over nalgebra fixed-size matrices (const generics, no allocation).
//!
//! After adskalman: motion models are a trait giving F(dt) and Q(dt) ([`MotionModel`]); the
//! innovation covariance is factored by Cholesky and a failure is a typed error in every
//! build; the covariance update is Joseph's form. dt is always an argument: ADS-B reports
//! arrive at irregular times.

use super::TrackError;
use nalgebra::{Cholesky, SMatrix, SVector};

/// ln(2π), for the Gaussian log-likelihood.
const LN_2PI: f64 = 1.837_877_066_409_345_3;

/// A motion model: the state transition F(dt) and the process noise Q(dt) it accumulates.
///
/// Object-safe, so an IMM can hold `&dyn MotionModel<N>` / `Box<dyn MotionModel<N>>` for its
/// list of models.
pub trait MotionModel<const N: usize> {
    /// State transition over `dt_s` seconds.
    fn f(&self, dt_s: f64) -> SMatrix<f64, N, N>;
    /// Process noise covariance accumulated over `dt_s` seconds.
    fn q(&self, dt_s: f64) -> SMatrix<f64, N, N>;

    /// F(dt) and Q(dt) together: one evaluation of what they share (the CT model's
    /// trigonometric coefficients, the per-axis powers of dt). Must equal `(f(dt), q(dt))`.
    fn fq(&self, dt_s: f64) -> (SMatrix<f64, N, N>, SMatrix<f64, N, N>) {
        (self.f(dt_s), self.q(dt_s))
    }

    /// One prediction step with this model (see [`predict`]).
    fn predict(&self, x: &mut SVector<f64, N>, p: &mut SMatrix<f64, N, N>, dt_s: f64) {
        let (f, q) = self.fq(dt_s);
        predict(x, p, &f, &q);
    }

    /// [`MotionModel::predict`]'s state and the east and north variances of its P (entries
    /// (0, 0) and (1, 1)) from `(x, p)`, the same bits, without the rest of P: what a
    /// published prediction reads (a position and its horizontal σ, three horizons a
    /// snapshot). A model that overrides `predict` overrides this with the same sums.
    fn predict_horizontal(
        &self,
        x: &SVector<f64, N>,
        p: &SMatrix<f64, N, N>,
        dt_s: f64,
    ) -> (SVector<f64, N>, f64, f64) {
        let (f, q) = self.fq(dt_s);
        predicted_horizontal(&f, &q, x, p)
    }
}

/// What an update learnt about a measurement: the quantities gating, divergence detection
/// (paper 000) and IMM mode probabilities (paper 002) are computed from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Innovation<const M: usize> {
    /// ε = z − H x̂(k|k−1).
    pub residual: SVector<f64, M>,
    /// S = H P(k|k−1) Hᵀ + R.
    pub s: SMatrix<f64, M, M>,
    /// Normalised innovation squared εᵀ S⁻¹ ε: χ²(M) for a consistent filter.
    pub nis: f64,
    /// The diagonal of S's Cholesky factor L, for [`Innovation::log_likelihood`].
    l_diag: SVector<f64, M>,
    /// [`Innovation::nis_leading2`], taken from the whitened innovation the NIS is computed
    /// from.
    nis_leading2: f64,
}

impl<const M: usize> Innovation<M> {
    /// ln N(ε; 0, S) = −(NIS + M ln 2π + ln det S)/2, with ln det S = 2 ln Πᵢ Lᵢᵢ from the
    /// Cholesky factor, never from det S itself.
    ///
    /// The product of the M ≤ 6 diagonal entries (standard deviations, metres or m/s) is
    /// far inside f64's range for any covariance a track holds, and one logarithm of it
    /// costs a third of the three that Σ ln Lᵢᵢ took (those were 3 % of the default
    /// tracker's instructions on the fleet: an IMM asks for six likelihoods a report). Only
    /// when the product leaves f64's normal range (about 1e±308: six standard deviations
    /// all below 1e-51, say) is the sum of the logarithms taken instead, so the result
    /// never under- or overflows.
    ///
    /// Computed when asked: a single filter (the CV filter, `kalman-cv`) never reads it.
    pub fn log_likelihood(&self) -> f64 {
        let det_l: f64 = self.l_diag.iter().product();
        let ln_det_l = if det_l.is_normal() && det_l > 0.0 {
            det_l.ln()
        } else {
            self.l_diag.iter().map(|d| d.ln()).sum::<f64>()
        };
        -0.5 * (self.nis + M as f64 * LN_2PI + 2.0 * ln_det_l)
    }

    /// The NIS of the first two components alone, ε₀₁ᵀ S₀₁⁻¹ ε₀₁ with S₀₁ their 2x2 block:
    /// east and north of a position or a velocity report, what the track's windowed NIS
    /// sums ([`super::nis::horizontal`]). S's Cholesky factor L is lower triangular, so its
    /// leading 2x2 block factors S₀₁, and the first two entries of the whitened innovation
    /// w = L⁻¹ ε, which the NIS |w|² is computed from, are that block's: the result is
    /// w₀² + w₁², kept when the NIS is computed. NaN for M < 2.
    ///
    /// It was worked out here from ε, S₀₁ and L's diagonal, with two divisions in a chain,
    /// on loads of the struct the update had just written: 3.9 % of a `kalman-cv` fleet
    /// replay's cycles for 2 % of its instructions (`perf annotate`).
    pub fn nis_leading2(&self) -> f64 {
        self.nis_leading2
    }
}

/// (A + Aᵀ)/2: removes the asymmetry rounding leaves in a covariance.
///
/// Entry by entry, the same sums as `(a + a.transpose()) * 0.5`, without its two temporary
/// matrices (0.25 % of the default tracker's fleet replay instructions).
pub fn symmetrise<const N: usize>(a: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    SMatrix::from_fn(|i, j| (a[(i, j)] + a[(j, i)]) * 0.5)
}

/// The `R`×`C` block of `m` at (`row`, `col`), copied by a loop. A fixed view's
/// `into_owned` goes through an iterator that nalgebra does not inline (its
/// `allocate_from_iterator`: 2.8 % of a `kalman-cv` fleet replay went there); `from_fn` and
/// `copy_from` do not.
#[inline(always)]
pub fn block<const R: usize, const C: usize, const N: usize, const M: usize>(
    m: &SMatrix<f64, N, M>,
    row: usize,
    col: usize,
) -> SMatrix<f64, R, C> {
    let mut out = SMatrix::<f64, R, C>::zeros();
    out.copy_from(&m.fixed_view::<R, C>(row, col));
    out
}

/// The `R` entries of `v` from `row` (see [`block`]).
#[inline(always)]
pub fn rows<const R: usize, const N: usize>(v: &SVector<f64, N>, row: usize) -> SVector<f64, R> {
    block::<R, 1, N, 1>(v, row, 0)
}

/// Prediction: x ← F x, P ← F P Fᵀ + Q (symmetrised).
pub fn predict<const N: usize>(
    x: &mut SVector<f64, N>,
    p: &mut SMatrix<f64, N, N>,
    f: &SMatrix<f64, N, N>,
    q: &SMatrix<f64, N, N>,
) {
    *x = f * *x;
    *p = symmetrise(&(sparse_fpf(f, p) + q));
}

/// [`predict`]'s state and the east and north variances of its P (entries (0, 0) and
/// (1, 1)), without the other entries ([`MotionModel::predict_horizontal`]; the whole
/// prediction was 1 % of the default tracker's fleet replay). The same bits as [`predict`]:
/// for a 6x6 F on the models' support ([`fpf_support6`]) each entry is that function's sums
/// for it written out, then the symmetrisation's ½ (m + m); any other F, or size, takes
/// [`predict`] itself.
pub fn predicted_horizontal<const N: usize>(
    f: &SMatrix<f64, N, N>,
    q: &SMatrix<f64, N, N>,
    x: &SVector<f64, N>,
    p: &SMatrix<f64, N, N>,
) -> (SVector<f64, N>, f64, f64) {
    if let (Ok(f6), Ok(q6), Ok(p6)) = (
        <&[f64; 36]>::try_from(f.as_slice()),
        <&[f64; 36]>::try_from(q.as_slice()),
        <&[f64; 36]>::try_from(p.as_slice()),
    ) {
        if !OFF_SUPPORT6.iter().any(|&i| f6[i] != 0.0) {
            // Column-major: entry (r, c) at 6c + r. Row i of F has its support at columns
            // i, 3, 4 (i = 0, 1). G = F P on that row, then (G Fᵀ)ᵢᵢ, each summed from zero
            // in fpf_support6's order; then + Q and ½ (m + m).
            let (fe, pe) = (
                |r: usize, c: usize| f6[6 * c + r],
                |r: usize, c: usize| p6[6 * c + r],
            );
            let var = |i: usize, q_ii: f64| {
                let g = |k: usize| {
                    0.0 + fe(i, i) * pe(i, k) + fe(i, 3) * pe(3, k) + fe(i, 4) * pe(4, k)
                };
                let fpf = 0.0 + g(i) * fe(i, i) + g(3) * fe(i, 3) + g(4) * fe(i, 4);
                let m = fpf + q_ii;
                (m + m) * 0.5
            };
            // Q(0, 0) and Q(1, 1) at 0 and 7.
            return (f * x, var(0, q6[0]), var(1, q6[7]));
        }
    }
    let (mut x, mut p) = (*x, *p);
    predict(&mut x, &mut p, f, q);
    let entry = |i: usize| p.get((i, i)).copied().unwrap_or(f64::NAN);
    (x, entry(0), entry(1))
}

/// The non-zero entries of each row of `f`, column indices ascending.
///
/// Motion-model transitions are sparse (per-axis 2x2 or 3x3 blocks, the CT model's 2x2
/// rotation coupling the horizontal velocities, zero rows for reset accelerations): a 9x9 F
/// has 9 to 21 non-zeros of 81.
struct RowSupport<const N: usize> {
    col: [[usize; N]; N],
    len: [usize; N],
}

impl<const N: usize> RowSupport<N> {
    fn of(f: &SMatrix<f64, N, N>) -> Self {
        let mut s = Self {
            col: [[0; N]; N],
            len: [0; N],
        };
        for (i, (cols, len)) in s.col.iter_mut().zip(s.len.iter_mut()).enumerate() {
            for k in 0..N {
                if f[(i, k)] != 0.0 {
                    cols[*len] = k;
                    *len += 1;
                }
            }
        }
        s
    }

    fn row(&self, i: usize) -> &[usize] {
        &self.col[i][..self.len[i]]
    }
}

/// By row, a superset of the columns where the F of every motion model of
/// [`super::models`] (9-state) can be non-zero, ascending: per axis position ← position,
/// velocity (both horizontal velocities for the CT model) and acceleration; velocity ←
/// velocity (both horizontal for CT) and acceleration; acceleration ← itself (or nothing
/// when reset). 22 entries of 81.
const SUPPORT9: [&[usize]; 9] = [
    &[0, 3, 4, 6],
    &[1, 3, 4, 7],
    &[2, 5, 8],
    &[3, 4, 6],
    &[3, 4, 7],
    &[5, 8],
    &[6],
    &[7],
    &[8],
];

/// [`SUPPORT9`] without the vertical acceleration (state 8): the leading 8 states of the
/// models with horizontal acceleration ([`super::models::ResetTail`]). 19 entries of 64,
/// written out in [`fpf_support8`]; what is off it is [`OFF_SUPPORT8`] (tested against
/// this list).
#[cfg(test)]
const SUPPORT8: [&[usize]; 8] = [
    &[0, 3, 4, 6],
    &[1, 3, 4, 7],
    &[2, 5],
    &[3, 4, 6],
    &[3, 4, 7],
    &[5],
    &[6],
    &[7],
];

/// [`SUPPORT9`]'s leading 6 states, the support of the models that keep position and
/// velocity alone (CV, CT, CH, [`super::models::ResetTail`]) and of the CV filter, by row:
/// {0, 3, 4}, {1, 3, 4}, {2, 5}, {3, 4}, {3, 4}, {5}. 13 entries of 36, written out in
/// [`fpf_support6`]; what is off it is [`OFF_SUPPORT6`] (tested against this list).
#[cfg(test)]
const SUPPORT6: [&[usize]; 6] = [&[0, 3, 4], &[1, 3, 4], &[2, 5], &[3, 4], &[3, 4], &[5]];

/// The column-major indices (6c + r) of the 23 entries of a 6x6 F off the 6-state
/// support of the motion models (the leading block of [`SUPPORT9`]).
const OFF_SUPPORT6: [usize; 23] = [
    1, 2, 3, 4, 5, // column 0: rows 1-5
    6, 8, 9, 10, 11, // column 1: rows 0, 2-5
    12, 13, 15, 16, 17, // column 2: rows 0, 1, 3-5
    20, 23, // column 3: rows 2, 5
    26, 29, // column 4: rows 2, 5
    30, 31, 33, 34, // column 5: rows 0, 1, 3, 4
];

/// The column-major indices (8c + r) of the 45 entries of an 8x8 F off the 8-state support
/// of the models with horizontal acceleration (the leading block of [`SUPPORT9`]).
const OFF_SUPPORT8: [usize; 45] = [
    1, 2, 3, 4, 5, 6, 7, // column 0: rows 1-7
    8, 10, 11, 12, 13, 14, 15, // column 1: rows 0, 2-7
    16, 17, 19, 20, 21, 22, 23, // column 2: rows 0, 1, 3-7
    26, 29, 30, 31, // column 3: rows 2, 5-7
    34, 37, 38, 39, // column 4: rows 2, 5-7
    40, 41, 43, 44, 46, 47, // column 5: rows 0, 1, 3, 4, 6, 7
    49, 50, 52, 53, 55, // column 6: rows 1, 2, 4, 5, 7
    56, 58, 59, 61, 62, // column 7: rows 0, 2, 3, 5, 6
];

/// [`fpf_support6`] for the 8-state blocks (F zero at [`OFF_SUPPORT8`]): 19 non-zeros, 304
/// products where the dense one takes 1024, the same bits (tested). Written out per size
/// rather than sharing the G Fᵀ half with [`fpf_support6`]: passed as a list of per-row
/// terms, that half was not unrolled (2.5 % more instructions on the fleet, 49 ns against
/// 42 ns for 6 states).
fn fpf_support8(f: &[f64; 64], p: &[f64; 64], out: &mut [f64; 64]) -> bool {
    // Column-major: F[r, c] is f[8c + r].
    if OFF_SUPPORT8.iter().any(|&i| f[i] != 0.0) {
        return false;
    }
    let fe = |r: usize, c: usize| f[8 * c + r];
    let mut g = [[0.0; 8]; 8];
    for (gc, pc) in g.iter_mut().zip(p.chunks_exact(8)) {
        let Ok(pc) = <&[f64; 8]>::try_from(pc) else {
            return false;
        };
        *gc = [
            0.0 + fe(0, 0) * pc[0] + fe(0, 3) * pc[3] + fe(0, 4) * pc[4] + fe(0, 6) * pc[6],
            0.0 + fe(1, 1) * pc[1] + fe(1, 3) * pc[3] + fe(1, 4) * pc[4] + fe(1, 7) * pc[7],
            0.0 + fe(2, 2) * pc[2] + fe(2, 5) * pc[5],
            0.0 + fe(3, 3) * pc[3] + fe(3, 4) * pc[4] + fe(3, 6) * pc[6],
            0.0 + fe(4, 3) * pc[3] + fe(4, 4) * pc[4] + fe(4, 7) * pc[7],
            0.0 + fe(5, 5) * pc[5],
            0.0 + fe(6, 6) * pc[6],
            0.0 + fe(7, 7) * pc[7],
        ];
    }
    let column = |terms: &[(usize, f64)]| {
        let mut o = [0.0; 8];
        for &(k, w) in terms {
            for (ov, gv) in o.iter_mut().zip(&g[k]) {
                *ov += gv * w;
            }
        }
        o
    };
    let cols = [
        column(&[(0, fe(0, 0)), (3, fe(0, 3)), (4, fe(0, 4)), (6, fe(0, 6))]),
        column(&[(1, fe(1, 1)), (3, fe(1, 3)), (4, fe(1, 4)), (7, fe(1, 7))]),
        column(&[(2, fe(2, 2)), (5, fe(2, 5))]),
        column(&[(3, fe(3, 3)), (4, fe(3, 4)), (6, fe(3, 6))]),
        column(&[(3, fe(4, 3)), (4, fe(4, 4)), (7, fe(4, 7))]),
        column(&[(5, fe(5, 5))]),
        column(&[(6, fe(6, 6))]),
        column(&[(7, fe(7, 7))]),
    ];
    for (o, c) in out.chunks_exact_mut(8).zip(&cols) {
        o.copy_from_slice(c);
    }
    true
}

/// F P Fᵀ for a 6x6 F zero at [`OFF_SUPPORT6`], both matrices column-major (entry (r, c) at
/// 6c + r): [`fpf_on_support`] on that support written out, so no support list is walked at
/// run time. The same terms in the same order, so the same bits as the dense product
/// (tested); 156 products where the dense one takes 432. Written to `out`; false (and
/// nothing written) when F has a non-zero off the support.
fn fpf_support6(f: &[f64; 36], p: &[f64; 36], out: &mut [f64; 36]) -> bool {
    // Column-major: F[r, c] is f[6c + r].
    if OFF_SUPPORT6.iter().any(|&i| f[i] != 0.0) {
        return false;
    }
    let fe = |r: usize, c: usize| f[6 * c + r];
    // G = F P, column j: G[i, j] = Σₖ F[i, k] P[k, j] over row i's support, k ascending,
    // from zero as the dense product sums.
    let mut g = [[0.0; 6]; 6];
    for (gc, pc) in g.iter_mut().zip(p.chunks_exact(6)) {
        let Ok(pc) = <&[f64; 6]>::try_from(pc) else {
            return false;
        };
        *gc = [
            0.0 + fe(0, 0) * pc[0] + fe(0, 3) * pc[3] + fe(0, 4) * pc[4],
            0.0 + fe(1, 1) * pc[1] + fe(1, 3) * pc[3] + fe(1, 4) * pc[4],
            0.0 + fe(2, 2) * pc[2] + fe(2, 5) * pc[5],
            0.0 + fe(3, 3) * pc[3] + fe(3, 4) * pc[4],
            0.0 + fe(4, 3) * pc[3] + fe(4, 4) * pc[4],
            0.0 + fe(5, 5) * pc[5],
        ];
    }
    // G Fᵀ, column j: Σₖ G[:, k] F[j, k] over row j's support, k ascending (axpy form).
    let column = |terms: &[(usize, f64)]| {
        let mut o = [0.0; 6];
        for &(k, w) in terms {
            for (ov, gv) in o.iter_mut().zip(&g[k]) {
                *ov += gv * w;
            }
        }
        o
    };
    let cols = [
        column(&[(0, fe(0, 0)), (3, fe(0, 3)), (4, fe(0, 4))]),
        column(&[(1, fe(1, 1)), (3, fe(1, 3)), (4, fe(1, 4))]),
        column(&[(2, fe(2, 2)), (5, fe(2, 5))]),
        column(&[(3, fe(3, 3)), (4, fe(3, 4))]),
        column(&[(3, fe(4, 3)), (4, fe(4, 4))]),
        column(&[(5, fe(5, 5))]),
    ];
    for (o, c) in out.chunks_exact_mut(6).zip(&cols) {
        o.copy_from_slice(c);
    }
    true
}

/// Whether every non-zero of `f` lies in `support` (one row slice per row).
fn within_support<const N: usize>(f: &SMatrix<f64, N, N>, support: &[&[usize]]) -> bool {
    support.len() == N
        && support.iter().enumerate().all(|(i, cols)| {
            (0..N).fold(true, |ok, k| ok & (f[(i, k)] == 0.0 || cols.contains(&k)))
        })
}

/// F P Fᵀ summing, for each entry, the terms of the columns in `support` (ascending).
#[inline(always)]
fn fpf_on_support<const N: usize>(
    f: &SMatrix<f64, N, N>,
    p: &SMatrix<f64, N, N>,
    support: &[&[usize]],
) -> SMatrix<f64, N, N> {
    // G = F P, column by column: G[i, j] = Σₖ F[i, k] P[k, j].
    let mut g = SMatrix::<f64, N, N>::zeros();
    for j in 0..N {
        for (i, cols) in support.iter().enumerate() {
            let mut acc = 0.0;
            for &k in cols.iter() {
                acc += f[(i, k)] * p[(k, j)];
            }
            g[(i, j)] = acc;
        }
    }
    // G Fᵀ: entry (i, j) = Σₖ G[i, k] F[j, k] over row j of F.
    let mut out = SMatrix::<f64, N, N>::zeros();
    for (j, cols) in support.iter().enumerate() {
        let mut col = [0.0; N];
        for &k in cols.iter() {
            let fjk = f[(j, k)];
            for (i, c) in col.iter_mut().enumerate() {
                *c += g[(i, k)] * fjk;
            }
        }
        out.column_mut(j).copy_from_slice(&col);
    }
    out
}

/// F P Fᵀ for a sparse F, bit for bit what the dense product `f * p * f.transpose()` gives.
///
/// nalgebra evaluates each entry of a small fixed-size product as Σₖ aᵢₖ bₖⱼ accumulated with
/// k ascending; a term with a zero factor adds an exact zero (P is finite here). Summing only
/// the terms of a superset of F's non-zeros, k still ascending, therefore gives the same
/// floating-point result with nnz·N instead of N³ multiplications per product (tested
/// bit-equal): the motion models' fixed pattern ([`SUPPORT9`]) when F fits it, else the
/// non-zeros found in F. The 6- and 8-state blocks of the models are written out on their
/// support ([`fpf_support6`], [`fpf_support8`]); any other F below 9x9 takes the dense
/// product (same result).
pub fn sparse_fpf<const N: usize>(
    f: &SMatrix<f64, N, N>,
    p: &SMatrix<f64, N, N>,
) -> SMatrix<f64, N, N> {
    let mut out = SMatrix::<f64, N, N>::zeros();
    sparse_fpf_into(f, p, &mut out);
    out
}

/// [`sparse_fpf`] written into `out` (every entry), for a caller that keeps the product in a
/// struct: returned by value from a function with several returns, the 6x6 or 8x8 product
/// was copied once more on its way out (a `memcpy` call per prediction, 0.9 % of a fleet
/// replay's instructions).
pub fn sparse_fpf_into<const N: usize>(
    f: &SMatrix<f64, N, N>,
    p: &SMatrix<f64, N, N>,
    out: &mut SMatrix<f64, N, N>,
) {
    // The 6- and 8-state blocks write straight into the result (the slices convert exactly
    // when N is 6 or 8).
    if N == 6 || N == 8 {
        if let (Ok(f8), Ok(p8), Ok(o8)) = (
            <&[f64; 64]>::try_from(f.as_slice()),
            <&[f64; 64]>::try_from(p.as_slice()),
            <&mut [f64; 64]>::try_from(out.as_mut_slice()),
        ) {
            if fpf_support8(f8, p8, o8) {
                return;
            }
        }
        if let (Ok(f6), Ok(p6), Ok(o6)) = (
            <&[f64; 36]>::try_from(f.as_slice()),
            <&[f64; 36]>::try_from(p.as_slice()),
            <&mut [f64; 36]>::try_from(out.as_mut_slice()),
        ) {
            if fpf_support6(f6, p6, o6) {
                return;
            }
        }
    }
    if N < 9 {
        // Other sizes below 9, and a 6x6 or 8x8 F off the models' pattern: the dense
        // product, fully unrolled and vectorised.
        *out = f * p * f.transpose();
    } else if N == 9 && within_support(f, &SUPPORT9) {
        *out = fpf_on_support(f, p, &SUPPORT9);
    } else {
        let support = RowSupport::of(f);
        let rows: [&[usize]; N] = std::array::from_fn(|i| support.row(i));
        *out = fpf_on_support(f, p, &rows);
    }
}

/// Whether the symmetric `a` is positive definite, by an LDLᵀ factorisation (no square
/// roots, fixed size, no allocation).
///
/// A symmetric matrix is positive definite if and only if every pivot dⱼ of its LDLᵀ
/// factorisation is positive (Golub & Van Loan, *Matrix Computations*, 4th ed., §4.2), and
/// dⱼ = ℓⱼⱼ² where ℓ is the Cholesky factor: this is the same test as a Cholesky
/// factorisation (it fails on the same matrices up to rounding), without its N square
/// roots. A NaN pivot fails too.
///
/// Always inlined: every update checks its posterior once, N known there (as a call it
/// cost 1.5 % more of `kalman-cv`'s fleet instructions and 0.8 % more of `hybrid`'s).
#[inline(always)]
pub fn is_positive_definite<const N: usize>(a: &SMatrix<f64, N, N>) -> bool {
    // l[(j, k)] for k < j holds Lⱼₖ; inv_d the pivots' reciprocals (one division per pivot,
    // not one per entry); w the unscaled entries Lⱼₘ dₘ of the row being factored, so each
    // term of the inner sum is one product.
    let mut l = SMatrix::<f64, N, N>::zeros();
    let mut inv_d = [0.0; N];
    // Row j writes w[k] before it reads it (m < k), so one buffer serves every row.
    let mut w = [0.0; N];
    for j in 0..N {
        let mut djj = a[(j, j)];
        for k in 0..j {
            let mut v = a[(j, k)];
            for m in 0..k {
                v -= w[m] * l[(k, m)];
            }
            w[k] = v;
            let ljk = v * inv_d[k];
            l[(j, k)] = ljk;
            djj -= ljk * v;
        }
        // One test for all three failures: a NaN pivot compares false, as do 0, negatives and
        // +∞. Written `d ≤ MAX`, not `d < ∞`: the same pivots pass, but the compiler turned
        // the latter into sixteen integer instructions of classification a pivot, where this
        // is two comparisons (1.4 % of a `kalman-cv` fleet replay's instructions).
        if !(djj > 0.0 && djj <= f64::MAX) {
            return false;
        }
        inv_d[j] = 1.0 / djj;
    }
    true
}

/// The typed errors of a non-finite input, in the order every update checks them.
fn check_finite<const N: usize, const M: usize>(
    x: &SVector<f64, N>,
    p: &SMatrix<f64, N, N>,
    z: &SVector<f64, M>,
    r: &SMatrix<f64, M, M>,
) -> Result<(), TrackError> {
    check_measurement_finite(z, r)?;
    if !state_finite(x, p) {
        return Err(TrackError::NonFinite("state"));
    }
    Ok(())
}

/// The measurement half of [`check_finite`].
#[inline(always)]
fn check_measurement_finite<const M: usize>(
    z: &SVector<f64, M>,
    r: &SMatrix<f64, M, M>,
) -> Result<(), TrackError> {
    if !all_finite(z.as_slice()) {
        return Err(TrackError::NonFinite("measurement"));
    }
    if !all_finite(r.as_slice()) {
        return Err(TrackError::NonFinite("measurement covariance"));
    }
    Ok(())
}

/// Every entry of the prior finite.
fn state_finite<const N: usize>(x: &SVector<f64, N>, p: &SMatrix<f64, N, N>) -> bool {
    all_finite(x.as_slice()) && all_finite(p.as_slice())
}

/// The error [`check_finite`] would have returned first for a prior that is not finite,
/// else `e`: what a selected update that failed reports ([`update_selected`]'s doc).
#[cold]
fn prior_error<const N: usize>(
    x: &SVector<f64, N>,
    p: &SMatrix<f64, N, N>,
    e: TrackError,
) -> TrackError {
    if state_finite(x, p) {
        e
    } else {
        TrackError::NonFinite("state")
    }
}

/// Every value finite, without a branch per value (the check runs on every update).
///
/// v·0 is ±0 for a finite v and NaN for ±∞ or NaN, and a sum of zeros is zero, so the sum of
/// the v·0 is zero exactly when every v is finite. Four independent sums let the products
/// and additions run in vector lanes (a single running sum would be a chain of dependent
/// additions, and `is_finite` per value did not vectorise: 135 instructions for the 54
/// values of a CV update, now about 110).
fn all_finite(values: &[f64]) -> bool {
    let mut lanes = [0.0_f64; 4];
    let chunks = values.chunks_exact(4);
    let mut tail = 0.0;
    for v in chunks.remainder() {
        tail += v * 0.0;
    }
    for chunk in chunks {
        for (lane, v) in lanes.iter_mut().zip(chunk) {
            *lane += v * 0.0;
        }
    }
    (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]) + tail == 0.0
}

/// Solves L Lᵀ X = B in place for the Cholesky factor `l` (lower triangle read): forward
/// substitution by column updates, back substitution by dot products summed in ascending
/// order, as nalgebra's `Cholesky::solve` does it, without its generic views. Each division
/// by Lᵢᵢ is a product with its reciprocal, computed once: M divisions where the
/// substitutions took 2 M C (36 for a 3-vector report on a 6-state filter, a quarter of the
/// update's time). A product with a rounded reciprocal differs from the quotient by at most
/// an ulp, so X is nalgebra's to rounding (tested through [`update_selected`]).
///
/// Always inlined (one call per update, M and C known there): left to the compiler's
/// heuristics, the fleet replay ran 1.3 % more of `hybrid`'s instructions and 2.5 % more
/// of `kalman-cv`'s, for the same bits.
#[inline(always)]
fn cholesky_solve_mut<const M: usize, const C: usize>(
    l: &SMatrix<f64, M, M>,
    b: &mut SMatrix<f64, M, C>,
) {
    let inv_diag: [f64; M] = std::array::from_fn(|i| 1.0 / l[(i, i)]);
    for c in 0..C {
        let mut y = [0.0; M];
        for (i, yi) in y.iter_mut().enumerate() {
            *yi = b[(i, c)];
        }
        // L y = b.
        for i in 0..M {
            let coeff = y[i] * inv_diag[i];
            y[i] = coeff;
            for k in i + 1..M {
                y[k] += -coeff * l[(k, i)];
            }
        }
        // Lᵀ x = y.
        for i in (0..M).rev() {
            let mut dot = 0.0;
            for k in i + 1..M {
                dot += l[(k, i)] * y[k];
            }
            y[i] = (y[i] - dot) * inv_diag[i];
        }
        for (i, yi) in y.iter().enumerate() {
            b[(i, c)] = *yi;
        }
    }
}

/// `Some(sel)` when H selects state components: row m is the unit row e_{sel[m]}ᵀ, with
/// sel strictly ascending (what [`update_selected`] takes).
pub fn selection<const N: usize, const M: usize>(h: &SMatrix<f64, M, N>) -> Option<[usize; M]> {
    let mut sel = [0; M];
    for (m, s) in sel.iter_mut().enumerate() {
        let mut found = None;
        for k in 0..N {
            let v = h[(m, k)];
            if v == 1.0 && found.is_none() {
                found = Some(k);
            } else if v != 0.0 {
                return None;
            }
        }
        *s = found?;
    }
    sel.windows(2).all(|w| w[0] < w[1]).then_some(sel)
}

/// `[offset, offset + 1, offset + 2]`: a 3-vector block of the state.
pub const fn block3(offset: usize) -> [usize; 3] {
    [offset, offset + 1, offset + 2]
}

/// `[a, a + 1, a + 2, b, b + 1, b + 2]`: two 3-vector blocks of the state (a < b − 2).
pub const fn blocks6(a: usize, b: usize) -> [usize; 6] {
    [a, a + 1, a + 2, b, b + 1, b + 2]
}

/// [`update`] for an H that selects the state components `sel` (z = x[sel] + v: a position
/// block, a velocity block, or both), with a fraction of the work. `sel` must be strictly
/// ascending and inside the state, else the step is refused with `NotPositiveDefinite`
/// (nothing reachable by input builds such a `sel`).
///
/// With H selecting, H x = x[sel], B = P Hᵀ = P[:, sel] and S = P[sel, sel] + R are copies,
/// not products (Bar-Shalom et al. 2001, eq. 5.2.3-9 to -11). S is Cholesky-factored
/// (S = L Lᵀ) and K = B S⁻¹ solves S Kᵀ = Bᵀ (never inverting S, and dividing by L's
/// diagonal once: [`cholesky_solve_mut`]); the residual, S, the NIS and the likelihood are
/// the dense update's bit for bit, K and x to rounding.
///
/// The covariance is Joseph's form (Bar-Shalom et al. 2001, eq. 5.2.3-18),
/// P ← (I − KH) P (I − KH)ᵀ + K R Kᵀ, which stays symmetric positive semi-definite for any
/// gain, evaluated as the equal P − ½ (K Wᵀ + W Kᵀ) with W = 2B − K S. Expanding Joseph's
/// form gives P − K Bᵀ − B Kᵀ + K S Kᵀ for every K; ½ (K Wᵀ + W Kᵀ) is K Bᵀ + B Kᵀ − K S Kᵀ
/// (S symmetric), so nothing is dropped: W − B = B − K S is the gain's rounding error, which
/// Joseph's form carries and the short form P − K Bᵀ drops. It costs N M² + N² M
/// multiplications (162 for a 6-state filter and a 3-vector report) where the product form
/// on the selection took 2 (M + 1) N² + N M² + N² M (450), and the result is symmetric by
/// construction. It differs from [`update_dense`]'s products only by rounding (tested within
/// 1e-12 of the covariance's scale), then is checked positive definite
/// ([`is_positive_definite`]). NIS = |L⁻¹ ε|² and ln det S = 2 ln Πᵢ Lᵢᵢ
/// ([`Innovation::log_likelihood`]) come from the same factor.
#[inline(always)]
pub fn update_selected<const N: usize, const M: usize>(
    x: &mut SVector<f64, N>,
    p: &mut SMatrix<f64, N, N>,
    z: &SVector<f64, M>,
    sel: &[usize; M],
    r: &SMatrix<f64, M, M>,
) -> Result<Innovation<M>, TrackError> {
    let mut p_new = SMatrix::<f64, N, N>::zeros();
    let post = selected_posterior(x, p, z, sel, r, &mut p_new).map_err(|e| prior_error(x, p, e))?;
    accept(x, p, post.x, p_new, &post.chol, post.residual, post.s).map_err(|e| prior_error(x, p, e))
}

/// [`update_selected`] from the prior (`x`, `p`) into `x_out`, `p_out`, which hold the
/// posterior on success and are unspecified on error (the prior is never touched). For a
/// caller whose prior is a temporary: the posterior goes where it is kept, where
/// [`update_selected`] on a copy of the prior, its result then moved out, copied the
/// covariance twice more (paper 000's guard, every mode of the IMM: 1.1 % of a fleet
/// replay's instructions).
#[inline(always)]
pub fn update_selected_to<const N: usize, const M: usize>(
    x: &SVector<f64, N>,
    p: &SMatrix<f64, N, N>,
    z: &SVector<f64, M>,
    sel: &[usize; M],
    r: &SMatrix<f64, M, M>,
    x_out: &mut SVector<f64, N>,
    p_out: &mut SMatrix<f64, N, N>,
) -> Result<Innovation<M>, TrackError> {
    let post = selected_posterior(x, p, z, sel, r, p_out).map_err(|e| prior_error(x, p, e))?;
    if !acceptable(&post.x, p_out) {
        return Err(prior_error(x, p, TrackError::NotPositiveDefinite));
    }
    *x_out = post.x;
    innovation(&post.chol, post.residual, post.s).map_err(|e| prior_error(x, p, e))
}

/// The posterior state of [`update_selected`] and what its innovation is made of, not yet
/// checked.
struct Posterior<const N: usize, const M: usize> {
    x: SVector<f64, N>,
    chol: Cholesky<f64, nalgebra::Const<M>>,
    residual: SVector<f64, M>,
    s: SMatrix<f64, M, M>,
}

/// The arithmetic of [`update_selected`] (its doc), shared by both forms; the posterior
/// covariance is written to `p_new` (every entry), not yet checked.
#[inline(always)]
fn selected_posterior<const N: usize, const M: usize>(
    x: &SVector<f64, N>,
    p: &SMatrix<f64, N, N>,
    z: &SVector<f64, M>,
    sel: &[usize; M],
    r: &SMatrix<f64, M, M>,
    p_new: &mut SMatrix<f64, N, N>,
) -> Result<Posterior<N, M>, TrackError> {
    // The prior's finiteness is not checked here: a non-finite entry of x or P reaches the
    // posterior (its state, or its covariance's lower triangle, which the LDLᵀ check reads
    // in full), so the update fails, and the caller then names the prior as the cause
    // ([`prior_error`]). That check cost 3 % of a `kalman-cv` fleet replay's instructions,
    // on updates whose every prior is a checked posterior, predicted.
    check_measurement_finite(z, r)?;
    if sel.iter().any(|&k| k >= N) || sel.windows(2).any(|w| w[0] >= w[1]) {
        return Err(TrackError::NotPositiveDefinite);
    }
    let mut residual = SVector::<f64, M>::zeros();
    let mut hp = SMatrix::<f64, M, N>::zeros();
    for (m, &k) in sel.iter().enumerate() {
        residual[m] = z[m] - x[k];
        hp.row_mut(m).copy_from(&p.row(k));
    }
    let mut s = *r;
    for (a, &ka) in sel.iter().enumerate() {
        for (b, &kb) in sel.iter().enumerate() {
            s[(a, b)] = p[(ka, kb)] + r[(a, b)];
        }
    }
    let s = symmetrise(&s);
    let chol = Cholesky::new(s).ok_or(TrackError::NotPositiveDefinite)?;
    // S Kᵀ = H P  =>  Kᵀ = S⁻¹ H P (S and P symmetric).
    let mut kt = hp;
    cholesky_solve_mut(chol.l_dirty(), &mut kt);
    let k = kt.transpose();
    let x_new = x + k * residual;

    // W = 2B − K S (B = P Hᵀ = (H P)ᵀ), then A = K Wᵀ and P − ½ (A + Aᵀ), every entry
    // and its mirror from the same two sums: symmetric exactly.
    let ks = columns_times::<N, M, M>(&k, |l, m| s[(l, m)]);
    let w = SMatrix::<f64, N, M>::from_fn(|i, m| 2.0 * hp[(m, i)] - ks[(i, m)]);
    let a = columns_times::<N, M, N>(&k, |m, j| w[(j, m)]);
    // The lower triangle, each entry written to its mirror too: what `from_fn` over every
    // entry gave (a sum of two values is the same in either order), for half the sums.
    for j in 0..N {
        for i in j..N {
            let v = 0.5 * ((p[(i, j)] + p[(j, i)]) - (a[(i, j)] + a[(j, i)]));
            p_new[(i, j)] = v;
            p_new[(j, i)] = v;
        }
    }
    Ok(Posterior {
        x: x_new,
        chol,
        residual,
        s,
    })
}

/// [`update_selected_to`] out of line, one copy per (N, M), for a caller with several update
/// sites, and without [`update`]'s search for the selection in H (120 instructions a call).
/// The CV filter (`kalman-cv`) updates with a position, a velocity or both: with
/// the update inlined at its three sites the fleet replay ran 2 % fewer instructions
/// but took 6 % more CPU on one core (2.20 against 2.07 s, five runs each).
#[inline(never)]
pub fn update_selected_to_outlined<const N: usize, const M: usize>(
    x: &SVector<f64, N>,
    p: &SMatrix<f64, N, N>,
    z: &SVector<f64, M>,
    sel: &[usize; M],
    r: &SMatrix<f64, M, M>,
    x_out: &mut SVector<f64, N>,
    p_out: &mut SMatrix<f64, N, N>,
) -> Result<Innovation<M>, TrackError> {
    update_selected_to(x, p, z, sel, r, x_out, p_out)
}

/// The N×C product whose column c is Σₜ a[:, t]·coef(t, c): a times the T×C matrix `coef`,
/// in axpy form down the columns (which vectorises), each entry summed over t ascending from
/// zero as nalgebra's dense product sums it.
#[inline(always)]
fn columns_times<const N: usize, const T: usize, const C: usize>(
    a: &SMatrix<f64, N, T>,
    coef: impl Fn(usize, usize) -> f64,
) -> SMatrix<f64, N, C> {
    // Columns as arrays: the inner loop has a constant length and no bounds checks.
    let mut out = [[0.0; N]; C];
    for (c, out_col) in out.iter_mut().enumerate() {
        for (t, a_col) in a.data.0.iter().enumerate() {
            let w = coef(t, c);
            for i in 0..N {
                out_col[i] += a_col[i] * w;
            }
        }
    }
    SMatrix::from_data(nalgebra::ArrayStorage(out))
}

/// NIS = εᵀ S⁻¹ ε = |L⁻¹ ε|² from S's Cholesky factor L, and the same of the first two
/// components alone ([`Innovation::nis_leading2`]).
fn nis_of<const M: usize>(
    chol: &Cholesky<f64, nalgebra::Const<M>>,
    residual: &SVector<f64, M>,
) -> Result<(f64, f64), TrackError> {
    // The triangular solve reads L's lower triangle only, so the factor as stored (its upper
    // triangle not zeroed) serves without `Cholesky::l`'s copy.
    let w = chol
        .l_dirty()
        .solve_lower_triangular(residual)
        .ok_or(TrackError::NotPositiveDefinite)?;
    let leading2 = match (w.get(0), w.get(1)) {
        (Some(w0), Some(w1)) => w0 * w0 + w1 * w1,
        _ => f64::NAN,
    };
    Ok((w.norm_squared(), leading2))
}

/// Measurement update with z = H x + v, v ~ N(0, R).
///
/// S = H P Hᵀ + R is Cholesky-factored (S = L Lᵀ); the gain K = P Hᵀ S⁻¹ is obtained by
/// solving S Kᵀ = H P, never by inverting S. The covariance uses Joseph's form
/// P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ, which stays symmetric positive semi-definite even
/// with a sub-optimal gain, then is symmetrised and checked positive definite by Cholesky.
///
/// On error `x` and `p` are left unchanged: `NonFinite` for a non-finite input,
/// `NotPositiveDefinite` when S or the updated P cannot be factored.
///
/// An H that selects state components (every row a unit row, columns ascending: position
/// and velocity reports) goes to [`update_selected`], which gives the same result with a
/// fraction of the work; any other H to [`update_dense`].
pub fn update<const N: usize, const M: usize>(
    x: &mut SVector<f64, N>,
    p: &mut SMatrix<f64, N, N>,
    z: &SVector<f64, M>,
    h: &SMatrix<f64, M, N>,
    r: &SMatrix<f64, M, M>,
) -> Result<Innovation<M>, TrackError> {
    match selection(h) {
        Some(sel) => update_selected(x, p, z, &sel, r),
        None => update_dense(x, p, z, h, r),
    }
}

/// [`update`] with dense products for any H: the reference the specialised
/// [`update_selected`] is tested against, and the path of an H that does not select.
pub fn update_dense<const N: usize, const M: usize>(
    x: &mut SVector<f64, N>,
    p: &mut SMatrix<f64, N, N>,
    z: &SVector<f64, M>,
    h: &SMatrix<f64, M, N>,
    r: &SMatrix<f64, M, M>,
) -> Result<Innovation<M>, TrackError> {
    check_finite(x, p, z, r)?;
    let residual = z - h * *x;
    let hp = h * *p;
    let s = symmetrise(&(hp * h.transpose() + r));
    let chol = Cholesky::new(s).ok_or(TrackError::NotPositiveDefinite)?;
    // S Kᵀ = H P  =>  Kᵀ = S⁻¹ H P (S and P symmetric).
    let k = chol.solve(&hp).transpose();
    let x_new = *x + k * residual;
    let i_kh = SMatrix::<f64, N, N>::identity() - k * h;
    let p_new = symmetrise(&(i_kh * *p * i_kh.transpose() + k * r * k.transpose()));
    accept(x, p, x_new, p_new, &chol, residual, s)
}

/// The common end of both updates: the new state is taken only if it is finite and its
/// covariance positive definite; then the NIS from S's Cholesky factor.
fn accept<const N: usize, const M: usize>(
    x: &mut SVector<f64, N>,
    p: &mut SMatrix<f64, N, N>,
    x_new: SVector<f64, N>,
    p_new: SMatrix<f64, N, N>,
    chol: &Cholesky<f64, nalgebra::Const<M>>,
    residual: SVector<f64, M>,
    s: SMatrix<f64, M, M>,
) -> Result<Innovation<M>, TrackError> {
    if !acceptable(&x_new, &p_new) {
        return Err(TrackError::NotPositiveDefinite);
    }
    let inn = innovation(chol, residual, s)?;
    *x = x_new;
    *p = p_new;
    Ok(inn)
}

/// Whether an update's posterior may be taken: a finite state and a positive definite
/// covariance.
#[inline(always)]
fn acceptable<const N: usize>(x: &SVector<f64, N>, p: &SMatrix<f64, N, N>) -> bool {
    x.iter().all(|v| v.is_finite()) && is_positive_definite(p)
}

/// The innovation of an accepted update: the NIS from S's Cholesky factor.
fn innovation<const M: usize>(
    chol: &Cholesky<f64, nalgebra::Const<M>>,
    residual: SVector<f64, M>,
    s: SMatrix<f64, M, M>,
) -> Result<Innovation<M>, TrackError> {
    let (nis, nis_leading2) = nis_of(chol, &residual)?;
    Ok(Innovation {
        residual,
        s,
        nis,
        l_diag: chol.l_dirty().diagonal(),
        nis_leading2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    /// A random symmetric positive definite matrix with entries spread over `scale` decades.
    fn random_spd<const N: usize>(rng: &mut StdRng, scale: f64) -> SMatrix<f64, N, N> {
        let d = SVector::<f64, N>::from_fn(|_, _| 10f64.powf(rng.gen_range(-scale..scale)));
        let l = SMatrix::<f64, N, N>::from_fn(|i, j| {
            if i >= j {
                rng.gen_range(-1.0..1.0)
            } else {
                0.0
            }
        });
        let a = SMatrix::<f64, N, N>::from_diagonal(&d)
            * (l * l.transpose())
            * SMatrix::<f64, N, N>::from_diagonal(&d)
            + SMatrix::<f64, N, N>::from_diagonal(&d.component_mul(&d)) * 1e-3;
        symmetrise(&a)
    }

    fn pick_h<const N: usize, const M: usize>(sel: &[usize; M]) -> SMatrix<f64, M, N> {
        let mut h = SMatrix::<f64, M, N>::zeros();
        for (m, &k) in sel.iter().enumerate() {
            h[(m, k)] = 1.0;
        }
        h
    }

    /// The specialised update against the dense one: the same innovation, NIS and
    /// likelihood bit for bit, the same errors, the state within 1e-9 of its step (the gain
    /// is computed with reciprocals of L's diagonal) and the covariance within 1e-12 of its
    /// scale (the largest entry of P before and after): the two evaluate Joseph's form in a
    /// different order.
    fn assert_selected_equals_dense<const N: usize, const M: usize>(seed: u64, sel: [usize; M]) {
        let mut rng = StdRng::seed_from_u64(seed);
        let p0 = random_spd::<N>(&mut rng, 3.0);
        let mut r = random_spd::<M>(&mut rng, 2.0);
        if rng.gen_bool(0.3) {
            // A diagonal R with an unmeasured component, as velocity reports without a
            // vertical rate carry.
            r = SMatrix::<f64, M, M>::from_diagonal(&r.diagonal());
            r[(M - 1, M - 1)] = crate::track::UNMEASURED_VARIANCE;
        }
        let x0 = SVector::<f64, N>::from_fn(|_, _| rng.gen_range(-1e4..1e4));
        let z = SVector::<f64, M>::from_fn(|m, _| x0[sel[m]] + rng.gen_range(-100.0..100.0));
        let h = pick_h::<N, M>(&sel);
        assert_eq!(selection(&h), Some(sel));
        let (mut x1, mut p1) = (x0, p0);
        let (mut x2, mut p2) = (x0, p0);
        let a = update_selected(&mut x1, &mut p1, &z, &sel, &r);
        let b = update_dense(&mut x2, &mut p2, &z, &h, &r);
        assert_eq!(a, b, "innovation, seed {seed}");
        // The form that writes elsewhere: the same bits, and its prior untouched.
        let (mut x3, mut p3) = (SVector::zeros(), SMatrix::zeros());
        let c = update_selected_to(&x0, &p0, &z, &sel, &r, &mut x3, &mut p3);
        assert_eq!(a, c, "innovation of the _to form, seed {seed}");
        if a.is_ok() {
            assert_eq!((x1, p1), (x3, p3), "posterior of the _to form, seed {seed}");
        }
        // The gain is nalgebra's to rounding (reciprocals for quotients), which S's
        // condition (up to 1e12 here) amplifies: 3e-12 of the step K ε seen, bound 1e-9.
        let moved = (x2 - x0).amax().max(f64::MIN_POSITIVE);
        let err_x = (x1 - x2).amax() / moved;
        assert!(
            err_x <= 1e-9,
            "x differs by {err_x:e} of its step, seed {seed}"
        );
        let scale = p0.amax().max(p2.amax());
        let err = (p1 - p2).amax() / scale;
        assert!(
            err <= 1e-12,
            "P differs by {err:e} of its scale, seed {seed}"
        );
        assert_eq!(p1, p1.transpose(), "P symmetric, seed {seed}");
        if let (Ok(a), Ok(b)) = (a, b) {
            assert_eq!(a.nis.to_bits(), b.nis.to_bits());
            assert_eq!(a.log_likelihood().to_bits(), b.log_likelihood().to_bits());
        }
    }

    /// A prior with one non-finite entry (`which` indexes x's N entries, then P's N² in
    /// column-major order; P's mirror entry stays finite) is refused by both forms of the
    /// selected update as `NonFinite("state")`, the prior untouched: the update no longer
    /// checks the prior first, so this is what shows that a non-finite entry anywhere still
    /// fails the posterior's check and is named as the cause.
    fn assert_poisoned_prior_is_refused<const N: usize, const M: usize>(
        seed: u64,
        sel: [usize; M],
        which: usize,
        bad: f64,
    ) {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut x = SVector::<f64, N>::from_fn(|_, _| rng.gen_range(-1e4..1e4));
        let mut p = random_spd::<N>(&mut rng, 2.0);
        let which = which % (N + N * N);
        match x.as_mut_slice().get_mut(which) {
            Some(v) => *v = bad,
            None => {
                if let Some(v) = p.as_mut_slice().get_mut(which - N) {
                    *v = bad;
                }
            }
        }
        let z = SVector::<f64, M>::from_fn(|_, _| rng.gen_range(-1e4..1e4));
        let r = random_spd::<M>(&mut rng, 1.0);
        let (x0, p0) = (x, p);
        let err = update_selected(&mut x, &mut p, &z, &sel, &r);
        assert_eq!(
            err,
            Err(TrackError::NonFinite("state")),
            "entry {which} = {bad}"
        );
        // Bit for bit: a NaN entry is not equal to itself.
        assert!(x
            .iter()
            .zip(x0.iter())
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        assert!(p
            .iter()
            .zip(p0.iter())
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        let (mut x_out, mut p_out) = (SVector::<f64, N>::zeros(), SMatrix::<f64, N, N>::zeros());
        let err = update_selected_to(&x, &p, &z, &sel, &r, &mut x_out, &mut p_out);
        assert_eq!(
            err,
            Err(TrackError::NonFinite("state")),
            "entry {which} = {bad}"
        );
    }

    proptest! {
        #[test]
        fn a_non_finite_prior_entry_anywhere_is_refused_as_the_state(
            seed in any::<u64>(),
            which in 0..200usize,
            bad in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), Just(f64::NEG_INFINITY)],
        ) {
            assert_poisoned_prior_is_refused::<6, 3>(seed, block3(0), which, bad);
            assert_poisoned_prior_is_refused::<6, 3>(seed, block3(3), which, bad);
            assert_poisoned_prior_is_refused::<6, 6>(seed, blocks6(0, 3), which, bad);
            assert_poisoned_prior_is_refused::<8, 3>(seed, block3(0), which, bad);
            assert_poisoned_prior_is_refused::<9, 6>(seed, blocks6(0, 3), which, bad);
        }

        #[test]
        fn selected_update_is_the_dense_update(seed in any::<u64>()) {
            assert_selected_equals_dense::<6, 3>(seed, block3(0));
            assert_selected_equals_dense::<6, 3>(seed, block3(3));
            assert_selected_equals_dense::<6, 6>(seed, blocks6(0, 3));
            assert_selected_equals_dense::<9, 3>(seed, block3(0));
            assert_selected_equals_dense::<9, 3>(seed, block3(3));
            assert_selected_equals_dense::<9, 6>(seed, blocks6(0, 3));
            assert_selected_equals_dense::<10, 3>(seed, [0, 1, 4]);
        }

        #[test]
        fn sparse_prediction_is_the_dense_product(seed in any::<u64>(), dt in 0.0..30.0f64) {
            use crate::track::models::{Ca, Ch, Chca, Ct, Cv, ResetTail};
            let mut rng = StdRng::seed_from_u64(seed);
            let p = random_spd::<9>(&mut rng, 3.0);
            let models: [&dyn MotionModel<9>; 6] = [
                &Cv::default(),
                &Ca::default(),
                &Ct::default(),
                &Ct::turning(false, 0.3),
                &Ch::default(),
                &Chca::default(),
            ];
            for m in models {
                let f = m.f(dt);
                prop_assert_eq!(sparse_fpf(&f, &p), f * p * f.transpose());
            }
            // Any other sparsity (found at run time), and an F outside the models' pattern.
            let mut f5 = SMatrix::<f64, 10, 10>::from_fn(|_, _| rng.gen_range(-2.0..2.0));
            f5[(1, 3)] = 0.0;
            f5[(4, 0)] = 0.0;
            let p5 = random_spd::<10>(&mut rng, 2.0);
            prop_assert_eq!(sparse_fpf(&f5, &p5), f5 * p5 * f5.transpose());
            let mut f9 = models[2].f(dt);
            f9[(8, 0)] = 0.5;
            prop_assert_eq!(sparse_fpf(&f9, &p), f9 * p * f9.transpose());
            let p6 = random_spd::<6>(&mut rng, 3.0);
            let f6 = MotionModel::<6>::f(&Cv::default(), dt);
            prop_assert_eq!(sparse_fpf(&f6, &p6), f6 * p6 * f6.transpose());
            // The 6-state leading blocks of the models that keep position and velocity
            // alone (`SUPPORT6`), and a 6x6 F off that pattern (the dense path).
            let leading6 = [
                ResetTail::<6>::leading_fq(&Cv::default(), dt).0,
                ResetTail::<6>::leading_fq(&Ct::turning(true, 0.05), dt).0,
                ResetTail::<6>::leading_fq(&Ct::turning(false, 0.3), dt).0,
                ResetTail::<6>::leading_fq(&Ch::default(), dt).0,
            ];
            for f6 in leading6 {
                prop_assert_eq!(sparse_fpf(&f6, &p6), f6 * p6 * f6.transpose());
            }
            let mut off = leading6[1];
            off[(5, 0)] = 0.25;
            prop_assert_eq!(sparse_fpf(&off, &p6), off * p6 * off.transpose());
            // A published prediction's entries alone: `predict`'s, bit for bit, on the
            // pattern and off it.
            let q6 = random_spd::<6>(&mut rng, 1.0);
            let x6 = SVector::<f64, 6>::from_fn(|_, _| rng.gen_range(-1e5..1e5));
            for f6 in leading6.iter().chain([&off]) {
                let (mut x, mut p) = (x6, p6);
                predict(&mut x, &mut p, f6, &q6);
                let (hx, var_e, var_n) = predicted_horizontal(f6, &q6, &x6, &p6);
                prop_assert_eq!(hx, x);
                prop_assert_eq!(var_e.to_bits(), p[(0, 0)].to_bits());
                prop_assert_eq!(var_n.to_bits(), p[(1, 1)].to_bits());
            }
            // The 8-state leading blocks of the models with horizontal acceleration.
            let p8 = random_spd::<8>(&mut rng, 3.0);
            for f8 in [Ca::default().leading_fq(dt).0, Chca::default().leading_fq(dt).0] {
                prop_assert_eq!(sparse_fpf(&f8, &p8), f8 * p8 * f8.transpose());
            }
            let mut off8 = Ca::default().leading_fq(dt).0;
            off8[(7, 0)] = 0.5;
            prop_assert_eq!(sparse_fpf(&off8, &p8), off8 * p8 * off8.transpose());
        }

        #[test]
        fn ldlt_check_agrees_with_cholesky(seed in any::<u64>(), shift in -2.0..0.5f64) {
            let mut rng = StdRng::seed_from_u64(seed);
            // Shifting the spectrum down makes about half of these indefinite.
            let a = random_spd::<9>(&mut rng, 0.5);
            let min = nalgebra::SymmetricEigen::new(a).eigenvalues.min();
            let b = a - SMatrix::<f64, 9, 9>::identity() * (min * (1.0 - shift));
            prop_assert_eq!(is_positive_definite(&b), Cholesky::new(b).is_some());
        }
    }

    #[test]
    fn all_finite_finds_a_non_finite_value_wherever_it_sits() {
        // Lengths around the four lanes and the tail; finite values as large as f64 allows
        // (their products with zero must not overflow) and both signed zeros.
        for len in 0..14 {
            let finite: Vec<f64> = (0..len)
                .map(|i| match i % 4 {
                    0 => -0.0,
                    1 => f64::MAX,
                    2 => -f64::MAX,
                    _ => f64::MIN_POSITIVE / 4.0,
                })
                .collect();
            assert!(all_finite(&finite), "{finite:?}");
            for i in 0..len {
                for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                    let mut v = finite.clone();
                    v[i] = bad;
                    assert!(!all_finite(&v), "{bad} at {i} of {len}");
                }
            }
        }
    }

    #[test]
    fn the_off_support_lists_are_the_complements_of_the_supports() {
        // Column-major indices n·c + r of the entries (r, c) outside `support`.
        fn off(support: &[&[usize]]) -> Vec<usize> {
            let n = support.len();
            (0..n * n)
                .filter(|i| !support[i % n].contains(&(i / n)))
                .collect()
        }
        assert_eq!(off(&SUPPORT6), OFF_SUPPORT6);
        assert_eq!(off(&SUPPORT8), OFF_SUPPORT8);
    }

    #[test]
    fn selection_recognises_only_ascending_unit_rows() {
        assert_eq!(selection(&pick_h::<9, 3>(&block3(3))), Some([3, 4, 5]));
        let mut h = pick_h::<9, 3>(&block3(0));
        h[(1, 5)] = 0.5;
        assert_eq!(selection(&h), None);
        let h = pick_h::<9, 2>(&[4, 1]);
        assert_eq!(selection(&h), None);
        let mut h = pick_h::<9, 2>(&[1, 4]);
        h[(0, 1)] = 2.0;
        assert_eq!(selection(&h), None);
        assert!(!is_positive_definite(&Matrix2::new(1.0, 2.0, 2.0, 1.0)));
        assert!(!is_positive_definite(&Matrix2::new(
            f64::NAN,
            0.0,
            0.0,
            1.0
        )));
        assert!(is_positive_definite(&Matrix2::new(2.0, 1.0, 1.0, 2.0)));
        // Every pivot must be finite and positive: +∞, ±0 and NaN fail, the largest finite
        // value and the smallest normal one pass (the one test per pivot, `0 < d ≤ MAX`).
        let diag = |a: f64, b: f64| is_positive_definite(&Matrix2::new(a, 0.0, 0.0, b));
        for bad in [
            f64::INFINITY,
            f64::NEG_INFINITY,
            0.0,
            -0.0,
            f64::NAN,
            -1e-300,
        ] {
            assert!(!diag(bad, 1.0) && !diag(1.0, bad), "{bad}");
        }
        for good in [f64::MAX, f64::MIN_POSITIVE] {
            assert!(diag(good, 1.0) && diag(1.0, good), "{good}");
        }
        // A pivot that overflows in the elimination: 1 − 1e300·1e300 = −∞.
        assert!(!is_positive_definite(&Matrix2::new(1.0, 1e300, 1e300, 1.0)));
        // A malformed selection is refused, not a panic.
        let (mut x, mut p) = (SVector::<f64, 3>::zeros(), SMatrix::<f64, 3, 3>::identity());
        let err = update_selected(&mut x, &mut p, &Vector1::new(0.0), &[7], &Matrix1::new(1.0));
        assert_eq!(err, Err(TrackError::NotPositiveDefinite));
    }
    use nalgebra::{Matrix1, Matrix1x2, Matrix2, Vector1, Vector2};

    /// 1-D constant velocity, for the trait tests.
    struct Cv1 {
        q: f64,
    }

    impl MotionModel<2> for Cv1 {
        fn f(&self, dt_s: f64) -> Matrix2<f64> {
            Matrix2::new(1.0, dt_s, 0.0, 1.0)
        }
        fn q(&self, dt_s: f64) -> Matrix2<f64> {
            self.q
                * Matrix2::new(
                    dt_s.powi(3) / 3.0,
                    dt_s.powi(2) / 2.0,
                    dt_s.powi(2) / 2.0,
                    dt_s,
                )
        }
    }

    #[test]
    fn scalar_update_matches_the_closed_form() {
        // Scalar: prior N(10, 4), measurement 13 with variance 1.
        // K = 4/5, x = 10 + 0.8·3 = 12.4, P = 4·1/5 = 0.8, NIS = 9/5,
        // ln L = −(9/5 + ln 2π + ln 5)/2.
        let mut x = Vector1::new(10.0);
        let mut p = Matrix1::new(4.0);
        let inn = update(
            &mut x,
            &mut p,
            &Vector1::new(13.0),
            &Matrix1::new(1.0),
            &Matrix1::new(1.0),
        )
        .unwrap();
        assert!((x[0] - 12.4).abs() < 1e-12);
        assert!((p[(0, 0)] - 0.8).abs() < 1e-12);
        assert!((inn.nis - 1.8).abs() < 1e-12);
        assert!((inn.s[(0, 0)] - 5.0).abs() < 1e-12);
        let expected_ll = -0.5 * (1.8 + (2.0 * std::f64::consts::PI).ln() + 5f64.ln());
        assert!((inn.log_likelihood() - expected_ll).abs() < 1e-12);
    }

    #[test]
    fn position_update_of_a_cv_state() {
        // Prior x = [0, 10], P = diag(100, 25); measure position 5 with R = 100:
        // S = 200, K = [0.5, 0], x = [2.5, 10], P = diag(50, 25) (no cross-covariance, so
        // the velocity learns nothing). NIS = 25/200.
        let mut x = Vector2::new(0.0, 10.0);
        let mut p = Matrix2::new(100.0, 0.0, 0.0, 25.0);
        let h = Matrix1x2::new(1.0, 0.0);
        let inn = update(&mut x, &mut p, &Vector1::new(5.0), &h, &Matrix1::new(100.0)).unwrap();
        assert!((x - Vector2::new(2.5, 10.0)).norm() < 1e-12);
        assert!((p - Matrix2::new(50.0, 0.0, 0.0, 25.0)).norm() < 1e-12);
        assert!((inn.nis - 0.125).abs() < 1e-12);
    }

    /// The log-likelihood of a zero innovation with S = var·I (M components), against
    /// −(M ln 2π + M ln var)/2.
    fn assert_isotropic_log_likelihood<const M: usize>(var: f64) {
        let mut x = SVector::<f64, M>::zeros();
        let mut p = SMatrix::<f64, M, M>::identity() * var * 0.5;
        let r = SMatrix::<f64, M, M>::identity() * var * 0.5;
        let h = SMatrix::<f64, M, M>::identity();
        let inn = update(&mut x, &mut p, &SVector::zeros(), &h, &r).unwrap();
        let expected = -0.5 * M as f64 * (LN_2PI + var.ln());
        assert!(
            (inn.log_likelihood() - expected).abs() < 1e-9 * expected.abs(),
            "{M} components of variance {var}"
        );
    }

    #[test]
    fn log_likelihood_in_log_space_survives_tiny_and_huge_covariances() {
        // det S = 1e-400 underflows f64 (and 1e400 overflows); the log form does not:
        // two components of variance 1e-200 each -> ln det S = 2 ln(1e-200).
        for var in [1e-200, 1e200] {
            assert_isotropic_log_likelihood::<2>(var);
        }
        // Three components whose factor's diagonal multiplies out of f64's normal range
        // (1e-375, 1e375): the sum of logarithms takes over.
        for var in [1e-250, 1e250] {
            assert_isotropic_log_likelihood::<3>(var);
        }
    }

    /// One logarithm of the factor's diagonal product is the sum of their logarithms, to
    /// rounding, over the covariances a track meets (standard deviations 1e-3 to 1e6).
    #[test]
    fn log_of_the_product_is_the_sum_of_logs() {
        let mut rng = StdRng::seed_from_u64(5);
        for _ in 0..2000 {
            let l_diag = SVector::<f64, 6>::from_fn(|_, _| 10f64.powf(rng.gen_range(-3.0..6.0)));
            let inn = Innovation {
                residual: SVector::<f64, 6>::zeros(),
                s: SMatrix::<f64, 6, 6>::identity(),
                nis: rng.gen_range(0.0..20.0),
                l_diag,
                nis_leading2: f64::NAN,
            };
            let sum: f64 = l_diag.iter().map(|d| d.ln()).sum();
            let expected = -0.5 * (inn.nis + 6.0 * LN_2PI + 2.0 * sum);
            let got = inn.log_likelihood();
            assert!(
                (got - expected).abs() <= 1e-13 * expected.abs().max(1.0),
                "{l_diag}"
            );
        }
    }

    #[test]
    fn errors_are_typed_and_leave_the_state_alone() {
        let mut x = Vector2::new(1.0, 2.0);
        let mut p = Matrix2::identity();
        let h = Matrix2::identity();
        // Indefinite S: R = −3 I makes S = −2 I.
        let err = update(
            &mut x,
            &mut p,
            &Vector2::zeros(),
            &h,
            &(Matrix2::identity() * -3.0),
        );
        assert_eq!(err, Err(TrackError::NotPositiveDefinite));
        let err = update(
            &mut x,
            &mut p,
            &Vector2::new(f64::NAN, 0.0),
            &h,
            &Matrix2::identity(),
        );
        assert_eq!(err, Err(TrackError::NonFinite("measurement")));
        assert_eq!(x, Vector2::new(1.0, 2.0));
        assert_eq!(p, Matrix2::identity());
    }

    #[test]
    fn motion_models_are_object_safe_and_predict() {
        let models: [&dyn MotionModel<2>; 2] = [&Cv1 { q: 0.0 }, &Cv1 { q: 3.0 }];
        for (i, m) in models.iter().enumerate() {
            let mut x = Vector2::new(1.0, 2.0);
            let mut p = Matrix2::identity();
            m.predict(&mut x, &mut p, 2.0);
            // x = [1 + 2·2, 2]; P = F Fᵀ + q[[8/3, 2], [2, 2]] with F Fᵀ = [[5, 2], [2, 1]].
            assert_eq!(x, Vector2::new(5.0, 2.0));
            let q = 3.0 * i as f64;
            let expected = Matrix2::new(
                5.0 + q * 8.0 / 3.0,
                2.0 + q * 2.0,
                2.0 + q * 2.0,
                1.0 + q * 2.0,
            );
            assert!((p - expected).norm() < 1e-12, "{p}");
        }
    }
}
