//! Cubature Kalman filter steps (Arasaratnam & Haykin, "Cubature Kalman Filters", IEEE TAC
//! 2009), in the square-root form paper 003 uses (ALGORITHMS.md §003) and the plain form of
//! its IMM-CKF baseline, for a 6-state and an M-dimensional linear measurement.
//!
//! Cubature rule (paper 003 eq. 3): 2n points ξ_i = √n·[±e_i], weights 1/(2n); a Gaussian
//! N(x, S Sᵀ) is represented by X_i = x + S ξ_i.
//!
//! Square-root form: the lower-triangular factor S (P = S Sᵀ) is propagated with
//! triangularisations S = Tria(A) (A Aᵀ = S Sᵀ): the time update is
//! S⁻ = Tria([X*_c, S_Q]) with X*_c the centred, 1/√(2n)-weighted propagated points, the
//! measurement update S_zz = Tria([Z_c, S_R]), K = (X_c Z_cᵀ) S_zz⁻ᵀ S_zz⁻¹,
//! S⁺ = Tria([X_c − K Z_c, K S_R]). P is never formed or re-factored.
//!
//! Tria is a QR decomposition of Aᵀ computed with Givens rotations applied to A's columns
//! (an orthogonal transformation from the right, A Θ = [S 0]), then each column's sign is
//! chosen so that diag S > 0. Givens rather than nalgebra's Householder QR because the
//! widths vary (18, 14, 16, 49 columns) and nalgebra's static QR needs a typenum bound per
//! width in generic code; the rotations work on any `SMatrix<f64, 6, C>` in place, without
//! allocation.

use super::TrackError;
use nalgebra::{Cholesky, SMatrix, SVector};

/// State dimension of the cubature filters here.
pub const N: usize = 6;
/// 6-state.
pub type Vector6 = SVector<f64, N>;
/// 6x6.
pub type Matrix6 = SMatrix<f64, N, N>;
/// Number of cubature points, 2n.
pub const POINTS: usize = 2 * N;

/// S with A Aᵀ = S Sᵀ, S lower triangular with a non-negative diagonal, for A of R rows
/// (R ≤ C): Givens rotations zero row i right of the diagonal, row by row.
pub fn tria<const R: usize, const C: usize>(a: &SMatrix<f64, R, C>) -> SMatrix<f64, R, R> {
    let mut w = *a;
    for i in 0..R.min(C) {
        for j in (i + 1)..C {
            let (p, q) = (w[(i, i)], w[(i, j)]);
            if q == 0.0 {
                continue;
            }
            let r = p.hypot(q);
            let (c, s) = (p / r, q / r);
            for k in i..R {
                let (u, v) = (w[(k, i)], w[(k, j)]);
                w[(k, i)] = c * u + s * v;
                w[(k, j)] = -s * u + c * v;
            }
        }
        if w[(i, i)] < 0.0 {
            for k in i..R {
                w[(k, i)] = -w[(k, i)];
            }
        }
    }
    SMatrix::<f64, R, R>::from_fn(|r, c| if c <= r && c < C { w[(r, c)] } else { 0.0 })
}

/// The 2n cubature points of N(x, S Sᵀ), as columns.
pub fn points(x: &Vector6, s: &Matrix6) -> SMatrix<f64, N, POINTS> {
    let scale = (N as f64).sqrt();
    let mut pts = SMatrix::<f64, N, POINTS>::zeros();
    for i in 0..N {
        let col = s.column(i) * scale;
        pts.set_column(i, &(x + col));
        pts.set_column(i + N, &(x - col));
    }
    pts
}

/// Mean of the columns and the centred columns scaled by 1/√(2n).
fn centred<const R: usize>(
    pts: &SMatrix<f64, R, POINTS>,
) -> (SVector<f64, R>, SMatrix<f64, R, POINTS>) {
    let mean = pts.column_mean();
    let w = 1.0 / (POINTS as f64).sqrt();
    let mut c = *pts;
    for j in 0..POINTS {
        let col = (pts.column(j) - mean) * w;
        c.set_column(j, &col);
    }
    (mean, c)
}

/// Square-root time update through x ↦ F x + u with process noise factor `s_q`.
pub fn sr_predict(x: &mut Vector6, s: &mut Matrix6, f: &Matrix6, u: &Vector6, s_q: &Matrix6) {
    let prop = f * points(x, s);
    let mut moved = prop;
    for j in 0..POINTS {
        let col = prop.column(j) + u;
        moved.set_column(j, &col);
    }
    let (mean, xc) = centred(&moved);
    let mut a = SMatrix::<f64, N, { POINTS + N }>::zeros();
    a.fixed_columns_mut::<POINTS>(0).copy_from(&xc);
    a.fixed_columns_mut::<N>(POINTS).copy_from(s_q);
    *x = mean;
    *s = tria(&a);
}

/// Result of a measurement update: log-likelihood of the innovation and its NIS.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fit {
    /// ln N(ν; 0, S_zz).
    pub log_likelihood: f64,
    /// νᵀ S_zz⁻¹ ν.
    pub nis: f64,
}

fn fit_from_factor<const M: usize>(
    nu: &SVector<f64, M>,
    l: &SMatrix<f64, M, M>,
) -> Result<Fit, TrackError> {
    let w = l
        .solve_lower_triangular(nu)
        .ok_or(TrackError::NotPositiveDefinite)?;
    let nis = w.norm_squared();
    let ln_det: f64 = 2.0 * l.diagonal().iter().map(|d| d.ln()).sum::<f64>();
    let ll = -0.5 * (nis + M as f64 * (2.0 * std::f64::consts::PI).ln() + ln_det);
    if ll.is_finite() {
        Ok(Fit {
            log_likelihood: ll,
            nis,
        })
    } else {
        Err(TrackError::NotPositiveDefinite)
    }
}

/// Square-root measurement update with z = H x + v, v ~ N(0, S_R S_Rᵀ). On error the state
/// is unchanged.
pub fn sr_update<const M: usize>(
    x: &mut Vector6,
    s: &mut Matrix6,
    z: &SVector<f64, M>,
    h: &SMatrix<f64, M, N>,
    s_r: &SMatrix<f64, M, M>,
) -> Result<Fit, TrackError> {
    let pts = points(x, s);
    let (xm, xc) = centred(&pts);
    let zpts = h * pts;
    let (zm, zc) = centred(&zpts);
    let mut a = SMatrix::<f64, M, { POINTS + 6 }>::zeros();
    a.fixed_columns_mut::<POINTS>(0).copy_from(&zc);
    for c in 0..M.min(6) {
        a.set_column(POINTS + c, &s_r.column(c));
    }
    let s_zz = tria(&a);
    if s_zz.diagonal().iter().any(|d| !(d.is_finite() && *d > 0.0)) {
        return Err(TrackError::NotPositiveDefinite);
    }
    let p_xz = xc * zc.transpose();
    // K S_zz S_zzᵀ = P_xz: solve S_zz Y = P_xzᵀ, then S_zzᵀ Kᵀ = Y.
    let y = s_zz
        .solve_lower_triangular(&p_xz.transpose())
        .ok_or(TrackError::NotPositiveDefinite)?;
    let k = s_zz
        .transpose()
        .solve_upper_triangular(&y)
        .ok_or(TrackError::NotPositiveDefinite)?
        .transpose();
    let nu = z - zm;
    let fit = fit_from_factor(&nu, &s_zz)?;
    let mut b = SMatrix::<f64, N, { POINTS + 6 }>::zeros();
    b.fixed_columns_mut::<POINTS>(0).copy_from(&(xc - k * zc));
    let ksr = k * s_r;
    for c in 0..M.min(6) {
        b.set_column(POINTS + c, &ksr.column(c));
    }
    let x_new = xm + k * nu;
    let s_new = tria(&b);
    if !x_new.iter().chain(s_new.iter()).all(|v| v.is_finite()) {
        return Err(TrackError::NotPositiveDefinite);
    }
    *x = x_new;
    *s = s_new;
    Ok(fit)
}

/// Plain CKF time update: factors P for the points, then forms P⁻ = Σ w X*X*ᵀ − x x ᵀ + Q.
pub fn ckf_predict(
    x: &mut Vector6,
    p: &mut Matrix6,
    f: &Matrix6,
    u: &Vector6,
    q: &Matrix6,
) -> Result<(), TrackError> {
    let s = Cholesky::new(*p)
        .ok_or(TrackError::NotPositiveDefinite)?
        .l();
    let mut pts = f * points(x, &s);
    for j in 0..POINTS {
        let col = pts.column(j) + u;
        pts.set_column(j, &col);
    }
    let (mean, xc) = centred(&pts);
    *x = mean;
    let pp = xc * xc.transpose() + q;
    *p = (pp + pp.transpose()) * 0.5;
    Ok(())
}

/// Plain CKF measurement update: P_zz, P_xz from the points, K = P_xz P_zz⁻¹,
/// P ← P − K P_zz Kᵀ. On error the state is unchanged.
pub fn ckf_update<const M: usize>(
    x: &mut Vector6,
    p: &mut Matrix6,
    z: &SVector<f64, M>,
    h: &SMatrix<f64, M, N>,
    r: &SMatrix<f64, M, M>,
) -> Result<Fit, TrackError> {
    let s = Cholesky::new(*p)
        .ok_or(TrackError::NotPositiveDefinite)?
        .l();
    let pts = points(x, &s);
    let (xm, xc) = centred(&pts);
    let zpts = h * pts;
    let (zm, zc) = centred(&zpts);
    let p_zz = zc * zc.transpose() + r;
    let chol =
        Cholesky::new((p_zz + p_zz.transpose()) * 0.5).ok_or(TrackError::NotPositiveDefinite)?;
    let p_xz = xc * zc.transpose();
    let k = chol.solve(&p_xz.transpose()).transpose();
    let nu = z - zm;
    let fit = fit_from_factor(&nu, &chol.l())?;
    let x_new = xm + k * nu;
    let p_new = *p - k * p_zz * k.transpose();
    let p_new = (p_new + p_new.transpose()) * 0.5;
    if !x_new.iter().all(|v| v.is_finite()) || Cholesky::new(p_new).is_none() {
        return Err(TrackError::NotPositiveDefinite);
    }
    *x = x_new;
    *p = p_new;
    Ok(fit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::kalman;
    use nalgebra::{Matrix2, Vector2};

    fn sample_factor() -> Matrix6 {
        let a = Matrix6::from_fn(|i, j| {
            ((i * 7 + j * 3) % 5) as f64 - 1.5 + if i == j { 4.0 } else { 0.0 }
        });
        Cholesky::new(a * a.transpose()).unwrap().l()
    }

    #[test]
    fn tria_is_a_triangular_square_root() {
        let a = SMatrix::<f64, 6, 18>::from_fn(|i, j| ((i * 5 + j * 11) % 7) as f64 - 3.0);
        let s = tria(&a);
        let target = a * a.transpose();
        assert!((s * s.transpose() - target).norm() < 1e-12 * target.norm());
        for i in 0..6 {
            assert!(s[(i, i)] > 0.0);
            for j in i + 1..6 {
                assert_eq!(s[(i, j)], 0.0);
            }
        }
        // The same factor as Cholesky (unique with a positive diagonal).
        let l = Cholesky::new(target).unwrap().l();
        assert!((s - l).norm() < 1e-10 * l.norm());
    }

    #[test]
    fn linear_srckf_and_ckf_equal_the_kalman_filter() {
        // For linear F and H the cubature rule is exact: both forms must reproduce
        // kalman::predict / kalman::update.
        let s0 = sample_factor();
        let p0 = s0 * s0.transpose();
        let x0 = Vector6::new(1.0, 2.0, -1.0, 4.0, 0.5, 0.1);
        let mut f = Matrix6::identity();
        f[(0, 1)] = 2.0;
        f[(1, 2)] = 2.0;
        f[(3, 4)] = 2.0;
        f[(0, 2)] = 2.0;
        let q = Matrix6::from_diagonal(&Vector6::new(1.0, 0.5, 0.1, 1.0, 0.5, 0.1));
        let s_q = Cholesky::new(q).unwrap().l();
        let mut h = SMatrix::<f64, 2, 6>::zeros();
        h[(0, 0)] = 1.0;
        h[(1, 3)] = 1.0;
        let r = Matrix2::new(4.0, 1.0, 1.0, 9.0);
        let z = Vector2::new(7.0, 3.0);

        let (mut xk, mut pk) = (x0, p0);
        kalman::predict(&mut xk, &mut pk, &f, &q);
        let inn = kalman::update(&mut xk, &mut pk, &z, &h, &r).unwrap();

        let (mut xs, mut ss) = (x0, s0);
        sr_predict(&mut xs, &mut ss, &f, &Vector6::zeros(), &s_q);
        let fit = sr_update(&mut xs, &mut ss, &z, &h, &Cholesky::new(r).unwrap().l()).unwrap();
        assert!((xs - xk).norm() < 1e-10, "{xs} {xk}");
        assert!((ss * ss.transpose() - pk).norm() < 1e-10 * pk.norm());
        assert!((fit.log_likelihood - inn.log_likelihood()).abs() < 1e-10);
        assert!((fit.nis - inn.nis).abs() < 1e-10);

        let (mut xc, mut pc) = (x0, p0);
        ckf_predict(&mut xc, &mut pc, &f, &Vector6::zeros(), &q).unwrap();
        let fit = ckf_update(&mut xc, &mut pc, &z, &h, &r).unwrap();
        assert!((xc - xk).norm() < 1e-10);
        assert!((pc - pk).norm() < 1e-10 * pk.norm());
        assert!((fit.log_likelihood - inn.log_likelihood()).abs() < 1e-10);
    }
}
