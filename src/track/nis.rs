//! The windowed normalised innovation squared (NIS) a track publishes: its own running
//! consistency check (Bar-Shalom, Li, Kirubarajan 2001, §5.4.2, the "time-average NIS").
//!
//! Each update's NIS εᵀS⁻¹ε is χ²(m) for a consistent filter, m the number of measured
//! components; over a window of updates the sum is χ²(Σm) when the innovations are white
//! (which a consistent filter's are). So the published pair (sum, Σm) is judged against the
//! χ²(Σm) quantiles: a sum far above its band says the filter is too sure of itself (or the
//! aircraft manoeuvres), far below too cautious. Fixed capacity: no allocation.
//!
//! **Over the horizontal components only** ([`horizontal`]): east and north of the position
//! and of the velocity, the components `pos_cov_enu_m2` and `vel_cov_enu_m2ps2` make their
//! claims about. The vertical ones are barometric altitude and rate, reported in 25 ft and
//! 64 ft/min steps: in level flight each report repeats the last, its innovation is zero,
//! and a χ² over it counts degrees of freedom that carry nothing. Over all six components
//! the statistic sat at 0.7-0.8 per degree of freedom for a filter given exactly the noise
//! the simulator draws, inside its 95 % band on only 67-82 % of the updates
//! (`docs/evaluation.md`): it read a consistent filter as a cautious one.

use super::kalman::Innovation;
use super::{Observed, UNMEASURED_VARIANCE};
use nalgebra::{Matrix4, SMatrix, SVector, Vector4};

/// Updates in the window. Default 20: ten seconds of ADS-B at 2 Hz, about 90 degrees of
/// freedom with positions and velocities, where the 95 % band of the sum is ±30 % of its
/// mean: narrow enough to tell a filter off by a factor of 2 in variance.
pub const NIS_WINDOW: usize = 20;

/// A published windowed NIS: the sum over the window and its degrees of freedom.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NisStat {
    /// Σ NIS over the window.
    pub nis: f64,
    /// Σ m over the window (measured components).
    pub dof: u32,
}

/// The last [`NIS_WINDOW`] updates' NIS and dof.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NisWindow {
    nis: [f64; NIS_WINDOW],
    dof: [u8; NIS_WINDOW],
    next: usize,
    len: usize,
}

impl Default for NisWindow {
    fn default() -> Self {
        Self {
            nis: [0.0; NIS_WINDOW],
            dof: [0; NIS_WINDOW],
            next: 0,
            len: 0,
        }
    }
}

impl NisWindow {
    /// Adds one update's NIS over `dof` measured components (a non-finite NIS is skipped).
    pub fn push(&mut self, nis: f64, dof: u8) {
        if !nis.is_finite() || dof == 0 {
            return;
        }
        if let (Some(n), Some(d)) = (self.nis.get_mut(self.next), self.dof.get_mut(self.next)) {
            *n = nis;
            *d = dof;
        }
        self.next = (self.next + 1) % NIS_WINDOW;
        self.len = (self.len + 1).min(NIS_WINDOW);
    }

    /// Forgets everything (a new track).
    pub fn clear(&mut self) {
        *self = Self::default();
    }

    /// The sum and its dof; `None` while empty.
    pub fn stat(&self) -> Option<NisStat> {
        if self.len == 0 {
            return None;
        }
        // Unfilled slots hold zeros: summing the whole arrays is the window's sum.
        Some(NisStat {
            nis: self.nis.iter().sum(),
            dof: self.dof.iter().map(|&d| u32::from(d)).sum(),
        })
    }
}

/// Whether a component with this measurement variance is measured (one with
/// [`UNMEASURED_VARIANCE`] is not).
fn is_measured(variance: f64) -> bool {
    variance < 0.5 * UNMEASURED_VARIANCE
}

/// Measured horizontal components (east, north) of an observation.
pub fn horizontal_components(o: &Observed) -> u8 {
    (0..2).map(|i| u8::from(is_measured(o.cov[(i, i)]))).sum()
}

/// Measured horizontal components of a report's position and velocity: the degrees of
/// freedom of its [`horizontal`] NIS.
pub fn horizontal_dof(position: Option<&Observed>, velocity: Option<&Observed>) -> u8 {
    position.map_or(0, horizontal_components) + velocity.map_or(0, horizontal_components)
}

/// The NIS of an innovation (residual ε, covariance S; R the measurement's covariance) over
/// its measured horizontal components: ε_hᵀ S_hh⁻¹ ε_h, with S_hh the block of S over them.
/// That is the NIS of the horizontal measurement alone (the marginal of a Gaussian is the
/// block of its covariance), χ²([`horizontal_dof`]) for a consistent filter.
///
/// The innovation is laid out in 3-blocks, a position's and a velocity's (east, north, up;
/// M = 3 or 6); a component is measured when its variance in R is below half of
/// [`UNMEASURED_VARIANCE`]. NaN when none is measured or S_hh is not positive definite (the
/// window then skips the update).
#[inline]
pub fn horizontal<const M: usize>(inn: &Innovation<M>, r: &SMatrix<f64, M, M>) -> f64 {
    // The common case, one report's position or velocity with east and north measured: the
    // NIS of the leading two components, which the update computed for nothing (every
    // report pays for this statistic).
    let measured = |k: usize| r.get((k, k)).is_some_and(|&v| is_measured(v));
    if M == 3 && measured(0) && measured(1) {
        return inn.nis_leading2();
    }
    horizontal_general(&inn.residual, &inn.s, r)
}

/// [`horizontal`] for any layout (both blocks of a joint report, or a block with a
/// component unmeasured; off the hot path): the measured horizontal components picked, and
/// their block of S solved, in a 4x4 padded with the identity and a zero residual, which add
/// nothing.
fn horizontal_general<const M: usize>(
    residual: &SVector<f64, M>,
    s: &SMatrix<f64, M, M>,
    r: &SMatrix<f64, M, M>,
) -> f64 {
    let mut picked = [0_usize; 4];
    let mut n = 0;
    for k in (0..M).filter(|k| k % 3 < 2) {
        if r.get((k, k)).is_some_and(|&v| is_measured(v)) {
            if let Some(slot) = picked.get_mut(n) {
                *slot = k;
                n += 1;
            }
        }
    }
    if n == 0 {
        return f64::NAN;
    }
    let mut sh = Matrix4::<f64>::identity();
    let mut eh = Vector4::<f64>::zeros();
    for (a, &ka) in picked.iter().take(n).enumerate() {
        eh[a] = residual.get(ka).copied().unwrap_or(f64::NAN);
        for (b, &kb) in picked.iter().take(n).enumerate() {
            sh[(a, b)] = s.get((ka, kb)).copied().unwrap_or(f64::NAN);
        }
    }
    sh.cholesky()
        .and_then(|chol| chol.l_dirty().solve_lower_triangular(&eh))
        .map_or(f64::NAN, |w| w.norm_squared())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    #[test]
    fn window_sums_the_last_updates() {
        let mut w = NisWindow::default();
        assert_eq!(w.stat(), None);
        w.push(2.0, 3);
        w.push(f64::NAN, 3);
        assert_eq!(w.stat(), Some(NisStat { nis: 2.0, dof: 3 }));
        for _ in 0..NIS_WINDOW {
            w.push(1.0, 2);
        }
        // The first push left the window.
        assert_eq!(
            w.stat(),
            Some(NisStat {
                nis: NIS_WINDOW as f64,
                dof: 2 * NIS_WINDOW as u32
            })
        );
        let mut o = Observed {
            value: Vector3::zeros(),
            cov: Matrix3::identity(),
            grid: None,
        };
        assert_eq!(horizontal_dof(Some(&o), None), 2);
        assert_eq!(horizontal_dof(Some(&o), Some(&o)), 4);
        o.cov[(1, 1)] = UNMEASURED_VARIANCE;
        assert_eq!(horizontal_dof(Some(&o), Some(&o)), 2);
        assert_eq!(horizontal_dof(None, None), 0);
    }

    /// A random symmetric positive definite M x M matrix (L Lᵀ plus a ridge).
    fn spd<const M: usize>(rng: &mut impl rand::Rng) -> SMatrix<f64, M, M> {
        let l = SMatrix::<f64, M, M>::from_fn(|_, _| rng.gen_range(-3.0..3.0));
        let a = l * l.transpose() + SMatrix::<f64, M, M>::identity() * 0.5;
        (a + a.transpose()) * 0.5
    }

    /// The horizontal NIS is the NIS of the horizontal block, whatever the vertical does:
    /// against a direct solve on random innovations (position, velocity, both, with a
    /// component unmeasured), and the vertical's share is exactly what separates it from the
    /// full NIS when S has no horizontal-vertical correlation.
    #[test]
    fn horizontal_nis_is_the_horizontal_blocks_nis() {
        use rand::{rngs::StdRng, Rng, SeedableRng};
        let mut rng = StdRng::seed_from_u64(5);
        for case in 0..500 {
            // Both blocks (M = 6): horizontal indices 0, 1, 3, 4.
            let s6 = spd::<6>(&mut rng);
            let mut r6 = SMatrix::<f64, 6, 6>::identity();
            let e6 = SVector::<f64, 6>::from_fn(|_, _| rng.gen_range(-5.0..5.0));
            let idx: Vec<usize> = if case % 3 == 0 {
                r6[(4, 4)] = UNMEASURED_VARIANCE;
                vec![0, 1, 3]
            } else {
                vec![0, 1, 3, 4]
            };
            let sub = nalgebra::DMatrix::from_fn(idx.len(), idx.len(), |a, b| s6[(idx[a], idx[b])]);
            let eh = nalgebra::DVector::from_fn(idx.len(), |a, _| e6[idx[a]]);
            let want = eh.dot(&sub.clone().cholesky().unwrap().solve(&eh));
            let got = horizontal_general(&e6, &s6, &r6);
            assert!(
                (got - want).abs() <= 1e-9 * want.max(1.0),
                "case {case}: {got} vs {want}"
            );

            // One block (M = 3): the 2x2 written out.
            let s3 = spd::<3>(&mut rng);
            let e3 = SVector::<f64, 3>::from_fn(|_, _| rng.gen_range(-5.0..5.0));
            let sub = s3.fixed_view::<2, 2>(0, 0).into_owned();
            let eh = e3.fixed_rows::<2>(0).into_owned();
            let want = eh.dot(&sub.cholesky().unwrap().solve(&eh));
            let got = horizontal_general(&e3, &s3, &Matrix3::identity());
            assert!(
                (got - want).abs() <= 1e-9 * want.max(1.0),
                "case {case}: {got} vs {want}"
            );

            // No correlation with the vertical: full NIS = horizontal + ε_u² / S_uu.
            let mut sb = s3;
            sb[(0, 2)] = 0.0;
            sb[(1, 2)] = 0.0;
            sb[(2, 0)] = 0.0;
            sb[(2, 1)] = 0.0;
            let full = e3.dot(&sb.cholesky().unwrap().solve(&e3));
            let split =
                horizontal_general(&e3, &sb, &Matrix3::identity()) + e3[2] * e3[2] / sb[(2, 2)];
            assert!((full - split).abs() <= 1e-9 * full.max(1.0), "case {case}");
        }
        // One measured component; none; a singular block.
        let s = Matrix3::identity() * 4.0;
        let mut r = Matrix3::identity() * UNMEASURED_VARIANCE;
        r[(1, 1)] = 1.0;
        assert_eq!(
            horizontal_general(&Vector3::new(9.0, 2.0, 7.0), &s, &r),
            1.0
        );
        r[(1, 1)] = UNMEASURED_VARIANCE;
        assert!(horizontal_general(&Vector3::new(9.0, 2.0, 7.0), &s, &r).is_nan());
        let singular = Matrix3::zeros();
        assert!(horizontal_general(
            &Vector3::new(1.0, 1.0, 0.0),
            &singular,
            &Matrix3::identity()
        )
        .is_nan());
    }

    /// The update's free leading-two NIS (a position or velocity report with east and north
    /// measured) is the horizontal block's NIS, and the other layouts go the general way:
    /// random priors and reports through the Kalman update the trackers use.
    #[test]
    fn the_updates_leading_nis_is_the_horizontal_nis() {
        use crate::track::kalman;
        use rand::{rngs::StdRng, Rng, SeedableRng};
        let mut rng = StdRng::seed_from_u64(9);
        for case in 0..500 {
            let p = spd::<6>(&mut rng) * 10.0;
            let x = SVector::<f64, 6>::from_fn(|_, _| rng.gen_range(-100.0..100.0));
            let z = Vector3::from_fn(|_, _| rng.gen_range(-100.0..100.0));
            let mut r = spd::<3>(&mut rng);
            if case % 4 == 0 {
                r[(2, 2)] = UNMEASURED_VARIANCE; // no vertical: still the fast path
            }
            if case % 4 == 1 {
                r[(0, 0)] = UNMEASURED_VARIANCE; // east unmeasured: the general path
            }
            let (mut xu, mut pu) = (x, p);
            let Ok(inn) = kalman::update_selected(&mut xu, &mut pu, &z, &kalman::block3(3), &r)
            else {
                continue;
            };
            let want = horizontal_general(&inn.residual, &inn.s, &r);
            let got = horizontal(&inn, &r);
            assert!(
                (got - want).abs() <= 1e-9 * want.max(1.0),
                "case {case}: {got} vs {want}"
            );
        }
    }

    /// For a consistent filter (ε drawn from N(0, S)) the horizontal NIS averages its dof,
    /// 2 for one block and 4 for both, however strongly the components are correlated.
    #[test]
    fn horizontal_nis_of_consistent_innovations_averages_its_dof() {
        use rand::{rngs::StdRng, SeedableRng};
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = StdRng::seed_from_u64(11);
        let s6 = spd::<6>(&mut rng);
        let l = s6.cholesky().unwrap().l();
        let n = 20_000;
        let (mut sum6, mut sum3) = (0.0, 0.0);
        let s3 = s6.fixed_view::<3, 3>(0, 0).into_owned();
        for _ in 0..n {
            let z = SVector::<f64, 6>::from_fn(|_, _| StandardNormal.sample(&mut rng));
            let e = l * z;
            sum6 += horizontal_general(&e, &s6, &SMatrix::<f64, 6, 6>::identity());
            sum3 += horizontal_general(
                &e.fixed_rows::<3>(0).into_owned(),
                &s3,
                &Matrix3::identity(),
            );
        }
        // Standard error of the mean of χ²(k): sqrt(2k / n) ≈ 0.02 for k = 4.
        assert!(
            (sum6 / f64::from(n) - 4.0).abs() < 0.1,
            "{}",
            sum6 / f64::from(n)
        );
        assert!(
            (sum3 / f64::from(n) - 2.0).abs() < 0.07,
            "{}",
            sum3 / f64::from(n)
        );
    }
}
