//! The shape of a report's innovation, learned per aircraft (issue 10): a position's, and a
//! rounded velocity's.
//!
//! The windowed NIS ([`super::nis`]) reads each report's term as χ²(2) when the filter is
//! consistent, which is true for Gaussian innovations. A real aircraft's positions are not
//! Gaussian about their prediction: AFR34ZG's, at cruise, are positions valid at a time a
//! few tens of ms off their timestamp, with a tail to half a second, so their horizontal NIS
//! has a median of 0.83 where χ²(2)'s is 1.39, and a 99th percentile of 41 where χ²(2)'s is
//! 9.2. A window of 20 terms that holds one such report is out of its band, whatever the
//! filter's covariance; a covariance large enough to cover the tail puts the rest below it.
//!
//! The Kalman gain is the best linear one for any noise of a given covariance, so the
//! estimate needs no change (a Student-t update, which weighs each report by its own
//! innovation, was tried on AFR34ZG and followed the positions less: the median
//! fix-to-track 8.2 → 8.8-9.3 m). What changes is the claim about the next report: its
//! horizontal innovation is read as a bivariate Student-t whose **covariance is the filter's
//! S** and whose tail index ν is the aircraft's (scale (ν − 2)/ν S; Roth, Özkan & Gustafsson
//! 2013, "A Student's t filter for heavy tailed process and measurement noise", ICASSP), and
//! the report's term is its quantile residual under that claim (Dunn & Smyth 1996, as
//! [`super::quantised`] does for a rounded velocity's bin): with d² = εᵀS⁻¹ε, the
//! t's survival function is (1 + d²/(ν − 2))^(−ν/2), and the χ²(2) quantile of the same
//! probability is ν ln(1 + d²/(ν − 2)) ([`t_nis`]), d² itself as ν → ∞.
//!
//! ν is learned from a statistic that does not see the covariance's size, on the report's
//! innovation along the track standardised by its own predicted variance, z = aᵀε/√(aᵀSa)
//! (a the horizontal direction of the predicted velocity): for the t every projection is a
//! univariate t of the same ν, and the ratio of the 90th to the 50th percentile of z² is
//! (t_ν(0.95)/t_ν(0.75))² at any scale, 5.95 for the Gaussian ([`tail_index`]). So a filter
//! too sure or too cautious by a factor still shows as a NIS off its band (module test
//! `a_scale_error_still_shows`), and so does one whose error along the track is larger than
//! it claims there and not across it (`an_error_along_the_track_alone_still_shows`): its d²
//! is a mixture of two Gaussian widths, which the same ratio taken on d² read as a tail (the
//! simulator's `airliner-timing`, too sure along the track, went from 54 to 69 % of its
//! windows in band that way; from 54 to 57 % this way), while its z is a Gaussian. Only the shape is the
//! aircraft's. The percentiles are stochastic-approximation estimates (Robbins & Monro
//! 1951) of ln z², with a gain that falls as 1/n to a floor, from the Gaussian's as a prior:
//! Gaussian innovations keep a ν of ten or more (∞ on 95 % of paper002's reports), which
//! leaves their terms within a few % of d².
//!
//! The hybrid's CV filter learns and uses it on its position reports, and the plain `imm`
//! where CV is its published mode (learning from its CV model's innovation while CV holds
//! 0.9, as it learns the noise): a manoeuvre's innovations are model error, which should
//! read as what it is.
//!
//! **Velocity reports.** A velocity report on a narrow claim (its spread under two 1-kt
//! bins, [`super::quantised`]) has for its term the sum of its two quantile residuals
//! squared, χ²(2) when the claim is right. Real ones have a tail too: on the LAX recording,
//! the hybrid's CV-filter velocity terms had a median of 0.69 where χ²(2)'s is 1.39 and a
//! mean of 1.5 (a probe of every update, not kept), the shape of a t of ν ≈ 4 with about
//! the claimed variance. So each aircraft has a second index of the same kind, learned from
//! those residuals (each a univariate N(0, 1) under the claim, so the same percentile ratio
//! reads its ν at any scale), and a narrow report's term is read under it with
//! [`t_nis`]: the residuals stand in for the standardised innovation, which is what they
//! are without rounding. Through the bins the tail is read only in part: a claim half a
//! bin wide hides most of it (module test
//! `velocity_reports_learn_the_tail_of_their_quantile_residuals`). A wide claim (the simulator's NACv 2) keeps its Gaussian term, and
//! the q_h learner ([`super::process_noise`]) keeps reading the Gaussian quantile NIS, so no
//! estimate moves.

use super::divergence::Prediction;
use super::noise::local_up;
use nalgebra::{Matrix3, Vector3};

/// Tuning of [`TailIndex`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TailParams {
    /// Learn and use ν; `false` reads every position term as Gaussian (ν = ∞). Default true.
    pub enabled: bool,
    /// Lowest ν. Default 3: the covariance exists above 2.
    pub min_nu: f64,
    /// Floor of the percentile estimates' gain, in ln z² per report. Default 0.005: a
    /// memory of a few hundred reports; the log-ratio is then good to about 0.07.
    pub min_gain: f64,
}

impl Default for TailParams {
    fn default() -> Self {
        Self {
            enabled: true,
            min_nu: 3.0,
            min_gain: 0.005,
        }
    }
}

/// The percentiles of z² that set ν.
const P_LOW: f64 = 0.5;
const P_HIGH: f64 = 0.9;

/// The gain is `GAIN / (n + PRIOR_REPORTS)`, down to the floor: about one over the density
/// of ln z² at its median for χ²(1) (0.21), the efficient gain for a quantile.
const GAIN: f64 = 5.0;

/// The Gaussian percentiles count as this many reports.
const PRIOR_REPORTS: f64 = 30.0;

/// ν is solved again after this many reports (a bisection of [`BISECTIONS`] steps on a
/// table; between two solves ν moves by far less than its own uncertainty, some 10 %).
const SOLVE_EVERY: u16 = 32;

/// Steps of the bisection on κ = 2/ν: κ to 3·10⁻⁷, ν to 10⁻⁴ of itself up to ν = 100.
const BISECTIONS: u32 = 20;

/// An aircraft's learned tail index of one kind of its innovations: its positions' along
/// the track, or its velocity reports' quantile residuals (module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TailIndex {
    /// ln of the 50th and 90th percentiles of z².
    ln_low: f64,
    ln_high: f64,
    /// Reports learned from (the gain's 1/n), saturating.
    n: f64,
    /// ν in force (∞ for the Gaussian).
    nu: f64,
    /// Reports since ν was solved.
    since_solve: u16,
}

impl Default for TailIndex {
    fn default() -> Self {
        Self {
            // χ²(1)'s: the squares of the normal's (1 + p)/2 quantiles.
            ln_low: 2.0 * NORMAL_Q75.ln(),
            ln_high: 2.0 * NORMAL_Q95.ln(),
            n: 0.0,
            nu: f64::INFINITY,
            since_solve: 0,
        }
    }
}

impl TailIndex {
    /// ν in force (∞ before the data says otherwise, or when not enabled).
    pub fn nu(&self) -> f64 {
        self.nu
    }

    /// The term of the windowed NIS of a position report whose horizontal Gaussian NIS is
    /// `d2` (2 degrees of freedom), under the learned ν ([`t_nis`]): `d2` itself while ν is
    /// ∞, which it stays when learning is not enabled.
    pub fn nis(&self, d2: f64) -> f64 {
        t_nis(d2, self.nu)
    }

    /// Learns from one standardised innovation `z` (ignored unless finite and non-zero): a
    /// position report's along the track over its predicted standard deviation there, or
    /// one quantile residual of a velocity report.
    pub fn learn(&mut self, z: f64, params: &TailParams) {
        let y = (z * z).ln();
        if !(params.enabled && y.is_finite()) {
            return;
        }
        self.n = (self.n + 1.0).min(1.0e9);
        let gain = (GAIN / (self.n + PRIOR_REPORTS)).max(params.min_gain);
        let step = |q: &mut f64, p: f64| *q += gain * (p - f64::from(u8::from(y <= *q)));
        step(&mut self.ln_low, P_LOW);
        step(&mut self.ln_high, P_HIGH);
        self.since_solve += 1;
        if self.since_solve >= SOLVE_EVERY {
            self.since_solve = 0;
            self.nu = tail_index((self.ln_high - self.ln_low).exp(), params.min_nu);
        }
    }
}

/// The χ²(2) quantile of the survival probability of a bivariate Student-t innovation of
/// tail index `nu` and covariance S at squared Mahalanobis distance `d2` = εᵀS⁻¹ε (module
/// doc): ν ln(1 + d²/(ν − 2)), with ln_1p for the small d²/ν of a large ν; `d2` for ν = ∞.
pub fn t_nis(d2: f64, nu: f64) -> f64 {
    if nu.is_finite() && nu > 2.0 {
        nu * (d2 / (nu - 2.0)).ln_1p()
    } else {
        d2
    }
}

/// A position report's innovation along the predicted track, over its predicted standard
/// deviation there: z = aᵀε / √(aᵀ S a), with a the horizontal direction of the predicted
/// velocity, S = P⁻ + R over the position, `r` the report's covariance and `z_m` its value
/// (the state's position and velocity are its leading six). NaN when the aircraft barely
/// moves (no track direction) or S is not positive there.
pub fn along_track_z<const K: usize>(
    pred: &Prediction<K>,
    r: &Matrix3<f64>,
    z_m: &Vector3<f64>,
) -> f64 {
    if K < 6 {
        return f64::NAN;
    }
    let pos: Vector3<f64> = pred.x.fixed_rows::<3>(0).into_owned();
    let vel: Vector3<f64> = pred.x.fixed_rows::<3>(3).into_owned();
    let up = local_up(&pos);
    let v_h = vel - up * vel.dot(&up);
    let speed = v_h.norm();
    if speed.is_nan() || speed <= 1.0 {
        return f64::NAN;
    }
    let a = v_h / speed;
    let s = pred.fpf.fixed_view::<3, 3>(0, 0) + pred.q.fixed_view::<3, 3>(0, 0) + r;
    let var = a.dot(&(s * a));
    if var.is_nan() || var <= 0.0 {
        return f64::NAN;
    }
    a.dot(&(z_m - pos)) / var.sqrt()
}

/// The standard normal's 75th and 95th percentiles.
const NORMAL_Q75: f64 = 0.674_489_750_196_081_7;
const NORMAL_Q95: f64 = 1.644_853_626_951_472_7;

/// Points of the table of [`percentile_ratio`], evenly in κ = 2/ν over `(0, 2/3]`.
const TABLE_POINTS: usize = 64;

/// The largest κ of the table (ν = 3).
const KAPPA_TABLE_MAX: f64 = 2.0 / 3.0;

/// The ratio of the 90th to the 50th percentile of z² for a univariate t of tail index
/// ν = 2/κ at any scale, (t_ν(0.95)/t_ν(0.75))²; κ = 0 is the Gaussian's, 5.95. Tabulated
/// once (Student's t quantiles are iterative) and interpolated linearly in κ: the
/// ratio is smooth in κ, the table good to 10⁻³ of it.
fn percentile_ratio(kappa: f64) -> f64 {
    use statrs::distribution::{ContinuousCDF, StudentsT};
    use std::sync::OnceLock;
    static TABLE: OnceLock<[f64; TABLE_POINTS + 1]> = OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let mut t = [(NORMAL_Q95 / NORMAL_Q75).powi(2); TABLE_POINTS + 1];
        for (i, r) in t.iter_mut().enumerate().skip(1) {
            let nu = 2.0 / (KAPPA_TABLE_MAX * i as f64 / TABLE_POINTS as f64);
            if let Ok(d) = StudentsT::new(0.0, 1.0, nu) {
                *r = (d.inverse_cdf(0.95) / d.inverse_cdf(0.75)).powi(2);
            }
        }
        t
    });
    let at = (kappa.max(0.0) / KAPPA_TABLE_MAX * TABLE_POINTS as f64).min(TABLE_POINTS as f64);
    let i = (at.floor() as usize).min(TABLE_POINTS - 1);
    let frac = at - i as f64;
    match (table.get(i), table.get(i + 1)) {
        (Some(a), Some(b)) => a + frac * (b - a),
        _ => f64::NAN,
    }
}

/// The tail index ν whose percentile ratio ([`percentile_ratio`]) is `ratio`, at least
/// `min_nu` (and at least 3, the table's end); ∞ for a ratio at or below the Gaussian's. The
/// ratio rises with κ = 2/ν, so a bisection on κ.
pub fn tail_index(ratio: f64, min_nu: f64) -> f64 {
    let kappa_max = (2.0 / min_nu.max(2.0 + 1e-6)).min(KAPPA_TABLE_MAX);
    if ratio.is_nan() || ratio <= percentile_ratio(0.0) {
        return f64::INFINITY;
    }
    if ratio >= percentile_ratio(kappa_max) {
        return 2.0 / kappa_max;
    }
    let (mut lo, mut hi) = (0.0, kappa_max);
    for _ in 0..BISECTIONS {
        let mid = 0.5 * (lo + hi);
        if percentile_ratio(mid) < ratio {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let kappa = 0.5 * (lo + hi);
    if kappa > 0.0 {
        2.0 / kappa
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::SeedableRng;
    use rand_distr::{ChiSquared, Distribution, StandardNormal};

    /// χ²(2)'s 99.9th percentile, −2 ln 0.001.
    const CHI2_999: f64 = 13.815_510_557_964_274;

    /// One report's (d², z) for a bivariate t innovation of tail index `nu` (∞: Gaussian)
    /// whose true covariance is diag(`along`², `across`²) against a claimed S = I: a normal
    /// pair over the t's shared mixing variable.
    fn draw(rng: &mut StdRng, nu: f64, along: f64, across: f64) -> (f64, f64) {
        let (g1, g2): (f64, f64) = (StandardNormal.sample(rng), StandardNormal.sample(rng));
        let mix = if nu.is_finite() {
            let w: f64 = ChiSquared::new(nu).map_or(nu, |c| c.sample(rng));
            ((nu - 2.0) / w).sqrt()
        } else {
            1.0
        };
        let (a, c) = (mix * along * g1, mix * across * g2);
        (a * a + c * c, a)
    }

    /// What a learner makes of `n` reports ([`draw`]): its ν, and the mean and the share
    /// above χ²(2)'s 99.9th percentile of its terms over the second half.
    fn learn(nu: f64, along: f64, across: f64, n: usize, seed: u64) -> (f64, f64, f64) {
        let mut rng = StdRng::seed_from_u64(seed);
        let params = TailParams::default();
        let mut tails = TailIndex::default();
        let (mut sum, mut above, mut count) = (0.0, 0usize, 0usize);
        for k in 0..n {
            let (d2, z) = draw(&mut rng, nu, along, across);
            let term = tails.nis(d2);
            tails.learn(z, &params);
            if k >= n / 2 {
                sum += term;
                above += usize::from(term > CHI2_999);
                count += 1;
            }
        }
        (tails.nu(), sum / count as f64, above as f64 / count as f64)
    }

    #[test]
    fn the_term_is_the_chi_square_quantile_of_the_t_probability() {
        use statrs::distribution::{ContinuousCDF, FisherSnedecor};
        for nu in [3.0, 4.5, 10.0, 80.0] {
            // d²/(2 c) ~ F(2, ν) with the scale c = (ν − 2)/ν.
            let f = FisherSnedecor::new(2.0, nu).unwrap();
            for d2 in [0.01, 0.5, 1.386, 5.99, 30.0, 400.0] {
                let survival = f.sf(d2 * nu / (2.0 * (nu - 2.0)));
                let want = -2.0 * survival.ln();
                let got = t_nis(d2, nu);
                assert!(
                    (got - want).abs() <= 1e-9 * want.max(1.0),
                    "{nu} {d2}: {got} {want}"
                );
            }
        }
        assert_eq!(t_nis(3.7, f64::INFINITY), 3.7);
        // A large ν is the Gaussian to within d⁴/(2ν).
        assert!((t_nis(2.0, 1.0e6) - 2.0).abs() < 1e-5);
    }

    #[test]
    fn the_tail_index_inverts_the_percentile_ratio() {
        use statrs::distribution::{ContinuousCDF, StudentsT};
        // The table against Student's t between its points, and its Gaussian end.
        for nu in [3.1, 3.7, 5.3, 9.0, 27.0, 300.0] {
            let d = StudentsT::new(0.0, 1.0, nu).unwrap();
            let want = (d.inverse_cdf(0.95) / d.inverse_cdf(0.75)).powi(2);
            let got = percentile_ratio(2.0 / nu);
            assert!((got / want - 1.0).abs() < 1e-3, "{nu}: {got} {want}");
            let back = tail_index(want, 3.0);
            assert!((back / nu - 1.0).abs() < 0.02, "{nu}: {back}");
        }
        assert!((percentile_ratio(0.0) - 5.9468).abs() < 1e-3);
        assert_eq!(tail_index(5.0, 3.0), f64::INFINITY);
        assert_eq!(tail_index(f64::NAN, 3.0), f64::INFINITY);
        // A heavier tail than ν = 3 allows is held there.
        assert_eq!(tail_index(500.0, 3.0), 3.0);
    }

    #[test]
    fn gaussian_innovations_stay_gaussian() {
        for seed in 0..4 {
            let (nu, mean, above) = learn(f64::INFINITY, 1.0, 1.0, 4000, seed);
            assert!(nu > 8.0, "seed {seed}: ν {nu}");
            assert!((mean - 2.0).abs() < 0.15, "seed {seed}: mean {mean}");
            assert!(above < 0.003, "seed {seed}: above {above}");
        }
    }

    #[test]
    fn learns_a_heavy_tail_and_reads_it_as_chi_square() {
        for seed in 0..4 {
            let (nu, mean, above) = learn(4.0, 1.0, 1.0, 4000, seed);
            assert!((3.0..=6.0).contains(&nu), "seed {seed}: ν {nu}");
            assert!((mean - 2.0).abs() < 0.25, "seed {seed}: mean {mean}");
            assert!(above < 0.005, "seed {seed}: above {above}");
            // Read as Gaussian, the same draws are beyond χ²(2)'s 99.9th percentile 16 times
            // as often: (1 + 13.8/2)⁻² = 1.6 %.
            let mut rng = StdRng::seed_from_u64(seed);
            let n = 4000;
            let gaussian_above = (0..n)
                .filter(|_| draw(&mut rng, 4.0, 1.0, 1.0).0 > CHI2_999)
                .count() as f64
                / n as f64;
            assert!(gaussian_above > 0.01, "seed {seed}: {gaussian_above}");
        }
    }

    #[test]
    fn a_scale_error_still_shows() {
        // A filter three times too sure (every d² three times its claim) or three times too
        // cautious: ν stays the Gaussian's, and the terms' mean is 6 or 2/3.
        let root3 = 3f64.sqrt();
        for (sd, want) in [(root3, 6.0), (1.0 / root3, 2.0 / 3.0)] {
            let (nu, mean, _) = learn(f64::INFINITY, sd, sd, 4000, 7);
            assert!(nu > 8.0, "sd {sd}: ν {nu}");
            assert!((mean / want - 1.0).abs() < 0.1, "sd {sd}: mean {mean}");
        }
        // A heavy tail too sure by 3: the shape is learned, the size still shows.
        let (nu, mean, _) = learn(4.0, root3, root3, 4000, 7);
        assert!((3.0..=6.0).contains(&nu), "ν {nu}");
        assert!(mean > 3.0, "mean {mean}");
    }

    #[test]
    fn an_error_along_the_track_alone_still_shows() {
        // Three times the claimed deviation along the track, as claimed across it: d² is a
        // mixture of two Gaussian widths (mean 10), z a Gaussian of the wrong size.
        for seed in 0..4 {
            let (nu, mean, above) = learn(f64::INFINITY, 3.0, 1.0, 4000, seed);
            assert!(nu > 8.0, "seed {seed}: ν {nu}");
            assert!(mean > 7.0, "seed {seed}: ν {nu} mean {mean}");
            assert!(above > 0.1, "seed {seed}: above {above}");
        }
    }

    /// What a velocity learner makes of `n` reports on a 1-kt grid whose value before
    /// rounding is the claim's mean plus an error of tail index `nu` and exactly the claimed
    /// covariance (a narrow claim: σ 0.55 m/s of noise, 0.32 m/s of the filter's own, 1.2
    /// bins in all): its ν, the mean of its terms over the second half, and how often those
    /// terms, and the same reports read as Gaussian, are beyond χ²(2)'s 99.9th percentile.
    /// A claim half a bin wide hides most of a tail in its bins: at σ 0.24 m/s the same
    /// ν = 4 is learned as 17, and 0.6 % of the terms stay beyond (0.85 % read as Gaussian).
    fn learn_velocity(nu: f64, n: usize, seed: u64) -> (f64, f64, f64, f64) {
        use crate::track::gate::KNOT_MPS;
        use crate::track::quantised::{Grid, OnGrid};
        use nalgebra::{Matrix3, Vector3};
        use rand::Rng;
        let mut rng = StdRng::seed_from_u64(seed);
        let params = TailParams::default();
        let mut tails = TailIndex::default();
        let grid = Grid::new(KNOT_MPS, &Matrix3::identity());
        let (white, own) = (0.3, 0.1);
        let r = Matrix3::from_diagonal(&Vector3::new(
            white + KNOT_MPS * KNOT_MPS / 12.0,
            white + KNOT_MPS * KNOT_MPS / 12.0,
            1.0,
        ));
        let s = r + Matrix3::from_diagonal(&Vector3::new(own, own, 0.0));
        let sd = (white + own).sqrt();
        let (mut sum, mut above, mut gaussian_above, mut count) = (0.0, 0, 0, 0);
        for k in 0..n {
            let mean = Vector3::new(
                200.0 + rng.gen::<f64>() * KNOT_MPS,
                -30.0 + rng.gen::<f64>() * KNOT_MPS,
                0.0,
            );
            let mix = if nu.is_finite() {
                let w: f64 = ChiSquared::new(nu).map_or(nu, |c| c.sample(&mut rng));
                ((nu - 2.0) / w).sqrt()
            } else {
                1.0
            };
            let (g1, g2): (f64, f64) = (
                StandardNormal.sample(&mut rng),
                StandardNormal.sample(&mut rng),
            );
            let value = mean + Vector3::new(g1, g2, 0.0) * (mix * sd);
            let z = value.map(|v| (v / KNOT_MPS).round() * KNOT_MPS);
            let g = OnGrid::of(&(z - mean), &s, &r, &z, &grid).expect("a narrow claim");
            let residuals = g.residuals();
            let gaussian: f64 = residuals.iter().map(|v| v * v).sum();
            let term = tails.nis(gaussian);
            for v in residuals {
                tails.learn(v, &params);
            }
            if k >= n / 2 {
                sum += term;
                above += usize::from(term > CHI2_999);
                gaussian_above += usize::from(gaussian > CHI2_999);
                count += 1;
            }
        }
        let c = count as f64;
        (
            tails.nu(),
            sum / c,
            above as f64 / c,
            gaussian_above as f64 / c,
        )
    }

    #[test]
    fn velocity_reports_learn_the_tail_of_their_quantile_residuals() {
        for seed in 0..3 {
            // Gaussian: ν stays large, the terms χ²(2).
            let (nu, mean, above, _) = learn_velocity(f64::INFINITY, 4000, seed);
            assert!(nu > 8.0, "seed {seed}: ν {nu}");
            assert!((mean - 2.0).abs() < 0.15, "seed {seed}: mean {mean}");
            assert!(above < 0.003, "seed {seed}: above {above}");
            // A tail of ν = 4 through the 1-kt bins: learned, and read as χ²(2), where the
            // Gaussian reading puts more than ten times χ²(2)'s share beyond its 99.9th
            // percentile.
            let (nu, mean, above, gaussian_above) = learn_velocity(4.0, 4000, seed);
            assert!((3.0..=6.5).contains(&nu), "seed {seed}: ν {nu}");
            assert!((mean - 2.0).abs() < 0.3, "seed {seed}: mean {mean}");
            assert!(above < 0.005, "seed {seed}: above {above}");
            assert!(gaussian_above > 0.01, "seed {seed}: {gaussian_above}");
        }
    }

    #[test]
    fn only_a_finite_non_zero_innovation_teaches() {
        let params = TailParams::default();
        let mut tails = TailIndex::default();
        for z in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0] {
            for _ in 0..100 {
                tails.learn(z, &params);
            }
        }
        assert_eq!(tails, TailIndex::default());
        let off = TailParams {
            enabled: false,
            ..params
        };
        let mut rng = StdRng::seed_from_u64(3);
        for _ in 0..1000 {
            tails.learn(draw(&mut rng, 3.0, 1.0, 1.0).1, &off);
        }
        assert_eq!(tails, TailIndex::default());
        assert_eq!(tails.nis(9.0), 9.0);
    }
}
