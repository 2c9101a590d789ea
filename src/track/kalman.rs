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

    /// One prediction step with this model (see [`predict`]).
    fn predict(&self, x: &mut SVector<f64, N>, p: &mut SMatrix<f64, N, N>, dt_s: f64) {
        predict(x, p, &self.f(dt_s), &self.q(dt_s));
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
    /// ln N(ε; 0, S) = −(NIS + M ln 2π + ln det S)/2, with ln det S = 2 Σ ln Lᵢᵢ from the
    /// Cholesky factor, so it never under- or overflows the way det S itself would.
    pub log_likelihood: f64,
}

/// (A + Aᵀ)/2: removes the asymmetry rounding leaves in a covariance.
pub fn symmetrise<const N: usize>(a: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    (a + a.transpose()) * 0.5
}

/// Prediction: x ← F x, P ← F P Fᵀ + Q (symmetrised).
pub fn predict<const N: usize>(
    x: &mut SVector<f64, N>,
    p: &mut SMatrix<f64, N, N>,
    f: &SMatrix<f64, N, N>,
    q: &SMatrix<f64, N, N>,
) {
    *x = f * *x;
    *p = symmetrise(&(f * *p * f.transpose() + q));
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
pub fn update<const N: usize, const M: usize>(
    x: &mut SVector<f64, N>,
    p: &mut SMatrix<f64, N, N>,
    z: &SVector<f64, M>,
    h: &SMatrix<f64, M, N>,
    r: &SMatrix<f64, M, M>,
) -> Result<Innovation<M>, TrackError> {
    if !z.iter().all(|v| v.is_finite()) {
        return Err(TrackError::NonFinite("measurement"));
    }
    if !r.iter().all(|v| v.is_finite()) {
        return Err(TrackError::NonFinite("measurement covariance"));
    }
    if !x.iter().chain(p.iter()).all(|v| v.is_finite()) {
        return Err(TrackError::NonFinite("state"));
    }
    let residual = z - h * *x;
    let hp = h * *p;
    let s = symmetrise(&(hp * h.transpose() + r));
    let chol = Cholesky::new(s).ok_or(TrackError::NotPositiveDefinite)?;
    // S Kᵀ = H P  =>  Kᵀ = S⁻¹ H P (S and P symmetric).
    let k = chol.solve(&hp).transpose();
    let x_new = *x + k * residual;
    let i_kh = SMatrix::<f64, N, N>::identity() - k * h;
    let p_new = symmetrise(&(i_kh * *p * i_kh.transpose() + k * r * k.transpose()));
    if !x_new.iter().all(|v| v.is_finite()) || Cholesky::new(p_new).is_none() {
        return Err(TrackError::NotPositiveDefinite);
    }
    // NIS = εᵀ S⁻¹ ε = |L⁻¹ ε|².
    let l = chol.l();
    let w = l
        .solve_lower_triangular(&residual)
        .ok_or(TrackError::NotPositiveDefinite)?;
    let nis = w.norm_squared();
    let ln_det_s = 2.0 * l.diagonal().iter().map(|d| d.ln()).sum::<f64>();
    let log_likelihood = -0.5 * (nis + M as f64 * LN_2PI + ln_det_s);
    *x = x_new;
    *p = p_new;
    Ok(Innovation {
        residual,
        s,
        nis,
        log_likelihood,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
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
        assert!((inn.log_likelihood - expected_ll).abs() < 1e-12);
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

    #[test]
    fn log_likelihood_in_log_space_survives_tiny_and_huge_covariances() {
        // det S = 1e-400 underflows f64 (and 1e400 overflows); the log form does not:
        // two components of variance 1e-200 each -> ln det S = 2 ln(1e-200).
        for var in [1e-200, 1e200] {
            let mut x = Vector2::zeros();
            let mut p = Matrix2::identity() * var * 0.5;
            let r = Matrix2::identity() * var * 0.5;
            let inn = update(&mut x, &mut p, &Vector2::zeros(), &Matrix2::identity(), &r).unwrap();
            let expected = -0.5 * (2.0 * LN_2PI + 2.0 * var.ln());
            assert!(
                (inn.log_likelihood - expected).abs() < 1e-9 * expected.abs(),
                "{var}"
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
