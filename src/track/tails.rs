//! The shape of a position report's innovation, learned per aircraft (issue 10).
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
//! fix-to-track 8.2 → 9.1-9.3 m). What changes is the claim about the next report: its
//! horizontal innovation is read as a bivariate Student-t whose **covariance is the filter's
//! S** and whose tail index ν is the aircraft's (scale (ν − 2)/ν S; Roth, Özkan & Gustafsson
//! 2013, "A Student's t filter for heavy tailed process and measurement noise", ICASSP), and
//! the report's term is its randomised quantile residual under that claim (Dunn & Smyth
//! 1996, as [`super::quantised`] does for a rounded velocity): with d² = εᵀS⁻¹ε, the
//! t's survival function is (1 + d²/(ν − 2))^(−ν/2), and the χ²(2) quantile of the same
//! probability is ν ln(1 + d²/(ν − 2)) ([`t_nis`]), d² itself as ν → ∞.
//!
//! ν is learned from a statistic that does not see the covariance's size: the ratio of the
//! 90th to the 50th percentile of the aircraft's d², (10^(2/ν) − 1)/(2^(2/ν) − 1) for the
//! t at any scale, ln 10 / ln 2 = 3.32 for the Gaussian ([`tail_index`]). So a filter too
//! sure or too cautious by a factor still shows as a NIS off its band (module test
//! `a_scale_error_still_shows`); only the shape is the aircraft's. The percentiles are
//! stochastic-approximation estimates (Robbins & Monro 1951) of ln d², with a gain that
//! falls as 1/n to a floor, from the Gaussian's as a prior: Gaussian innovations keep a ν
//! of tens or more, which leaves their terms within a few % of d².
//!
//! Only the hybrid's CV filter learns and uses it, on its position reports: a manoeuvre's
//! innovations are model error, and the velocity reports' terms are their bins' quantile
//! residuals already.

/// Tuning of [`PositionTails`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TailParams {
    /// Learn and use ν; `false` reads every position term as Gaussian (ν = ∞). Default true.
    pub enabled: bool,
    /// Lowest ν. Default 3: the covariance exists above 2, and AFR34ZG's d² give about 3.2.
    pub min_nu: f64,
    /// Floor of the percentile estimates' gain, in ln d² per report. Default 0.005: a
    /// memory of a few hundred reports; the log-ratio is then good to about 0.05, a ν of
    /// 30 or more on Gaussian innovations.
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

/// The percentiles of d² that set ν.
const P_LOW: f64 = 0.5;
const P_HIGH: f64 = 0.9;

/// The gain is `GAIN / (n + PRIOR_REPORTS)`, down to the floor: about one over the density
/// of ln d² at its median for χ²(2) (0.35), the efficient gain for a quantile.
const GAIN: f64 = 3.0;

/// The Gaussian percentiles count as this many reports.
const PRIOR_REPORTS: f64 = 30.0;

/// ν is solved again after this many reports (a bisection of 40 steps; between two, ν
/// moves by far less than its own uncertainty).
const SOLVE_EVERY: u16 = 16;

/// An aircraft's learned tail index of its position innovations (module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionTails {
    /// ln of the 50th and 90th percentiles of d².
    ln_low: f64,
    ln_high: f64,
    /// Reports learned from (the gain's 1/n), saturating.
    n: f64,
    /// ν in force (∞ for the Gaussian).
    nu: f64,
    /// Reports since ν was solved.
    since_solve: u16,
}

impl Default for PositionTails {
    fn default() -> Self {
        Self {
            // χ²(2)'s: −2 ln(1 − p).
            ln_low: (-2.0 * (1.0 - P_LOW).ln()).ln(),
            ln_high: (-2.0 * (1.0 - P_HIGH).ln()).ln(),
            n: 0.0,
            nu: f64::INFINITY,
            since_solve: 0,
        }
    }
}

impl PositionTails {
    /// ν in force (∞ before the data says otherwise, or when not enabled).
    pub fn nu(&self) -> f64 {
        self.nu
    }

    /// The term of the windowed NIS of a position report whose horizontal Gaussian NIS is
    /// `d2` (2 degrees of freedom), under the learned ν ([`t_nis`]).
    pub fn nis(&self, d2: f64, params: &TailParams) -> f64 {
        if params.enabled {
            t_nis(d2, self.nu)
        } else {
            d2
        }
    }

    /// Learns from one position report's horizontal Gaussian NIS `d2` (ignored unless
    /// finite and positive).
    pub fn learn(&mut self, d2: f64, params: &TailParams) {
        if !(params.enabled && d2.is_finite() && d2 > 0.0) {
            return;
        }
        let y = d2.ln();
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

/// The ratio of the 90th to the 50th percentile of d² for a bivariate t of tail index
/// 2/κ at any scale: (10^κ − 1)/(2^κ − 1), with expm1 (its κ → 0 limit, the Gaussian's, is
/// ln 10 / ln 2).
fn percentile_ratio(kappa: f64) -> f64 {
    let (ln_high, ln_low) = (-(1.0 - P_HIGH).ln(), -(1.0 - P_LOW).ln());
    if kappa <= 0.0 {
        ln_high / ln_low
    } else {
        (kappa * ln_high).exp_m1() / (kappa * ln_low).exp_m1()
    }
}

/// The tail index ν whose percentile ratio ([`percentile_ratio`]) is `ratio`, at least
/// `min_nu`; ∞ for a ratio at or below the Gaussian's. The ratio rises with κ = 2/ν, so a
/// bisection on κ.
pub fn tail_index(ratio: f64, min_nu: f64) -> f64 {
    let kappa_max = 2.0 / min_nu.max(2.0 + 1e-6);
    if !(ratio > percentile_ratio(0.0)) {
        return f64::INFINITY;
    }
    if ratio >= percentile_ratio(kappa_max) {
        return 2.0 / kappa_max;
    }
    let (mut lo, mut hi) = (0.0, kappa_max);
    for _ in 0..40 {
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
    use rand::{Rng, SeedableRng};

    /// A draw of d² for a bivariate t of tail index `nu` and covariance I (ν = ∞: χ²(2)),
    /// by inverting its survival function (module doc).
    fn draw_d2(rng: &mut StdRng, nu: f64) -> f64 {
        let u: f64 = rng.gen_range(f64::EPSILON..1.0);
        if nu.is_finite() {
            (nu - 2.0) * (u.powf(-2.0 / nu) - 1.0)
        } else {
            -2.0 * u.ln()
        }
    }

    /// What a learner makes of `n` draws of tail index `nu` scaled by `scale` (a filter
    /// whose S is `1/scale` of the truth): its ν, and the mean and the share above χ²(2)'s
    /// 99.9th percentile (13.8) of its terms over the second half.
    fn learn(nu: f64, scale: f64, n: usize, seed: u64) -> (f64, f64, f64) {
        let mut rng = StdRng::seed_from_u64(seed);
        let params = TailParams::default();
        let mut tails = PositionTails::default();
        let (mut sum, mut above, mut count) = (0.0, 0usize, 0usize);
        for k in 0..n {
            let d2 = scale * draw_d2(&mut rng, nu);
            let term = tails.nis(d2, &params);
            tails.learn(d2, &params);
            if k >= n / 2 {
                sum += term;
                above += usize::from(term > CHI2_999);
                count += 1;
            }
        }
        (tails.nu(), sum / count as f64, above as f64 / count as f64)
    }

    /// χ²(2)'s 99.9th percentile, −2 ln 0.001.
    const CHI2_999: f64 = 13.815_510_557_964_274;

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
                assert!((got - want).abs() <= 1e-9 * want.max(1.0), "{nu} {d2}: {got} {want}");
            }
        }
        assert_eq!(t_nis(3.7, f64::INFINITY), 3.7);
        // A large ν is the Gaussian to within d⁴/(2ν).
        assert!((t_nis(2.0, 1.0e6) - 2.0).abs() < 1e-5);
    }

    #[test]
    fn the_tail_index_inverts_the_percentile_ratio() {
        for nu in [3.0, 3.2, 4.0, 6.0, 20.0, 100.0] {
            let got = tail_index(percentile_ratio(2.0 / nu), 3.0);
            assert!((got - nu).abs() < 1e-6 * nu, "{nu}: {got}");
        }
        assert_eq!(tail_index(3.0, 3.0), f64::INFINITY);
        assert_eq!(tail_index(f64::NAN, 3.0), f64::INFINITY);
        // The Gaussian's ratio is ln 10 / ln 2; a heavier one than ν = 3 allows is held there.
        assert!((percentile_ratio(0.0) - 10f64.ln() / 2f64.ln()).abs() < 1e-12);
        assert!((percentile_ratio(1e-9) - percentile_ratio(0.0)).abs() < 1e-6);
        assert_eq!(tail_index(50.0, 3.0), 3.0);
    }

    #[test]
    fn gaussian_innovations_stay_gaussian() {
        for seed in 0..4 {
            let (nu, mean, above) = learn(f64::INFINITY, 1.0, 4000, seed);
            assert!(nu > 12.0, "seed {seed}: ν {nu}");
            assert!((mean - 2.0).abs() < 0.12, "seed {seed}: mean {mean}");
            assert!(above < 0.003, "seed {seed}: above {above}");
        }
    }

    #[test]
    fn learns_a_heavy_tail_and_reads_it_as_chi_square() {
        for seed in 0..4 {
            let (nu, mean, above) = learn(4.0, 1.0, 4000, seed);
            assert!((3.0..=5.5).contains(&nu), "seed {seed}: ν {nu}");
            assert!((mean - 2.0).abs() < 0.2, "seed {seed}: mean {mean}");
            assert!(above < 0.004, "seed {seed}: above {above}");
            // Read as Gaussian, the same draws are beyond χ²(2)'s 99.9th percentile 16 times
            // as often: (1 + 13.8/2)⁻² = 1.6 %.
            let mut rng = StdRng::seed_from_u64(seed);
            let n = 4000;
            let gaussian_above =
                (0..n).filter(|_| draw_d2(&mut rng, 4.0) > CHI2_999).count() as f64 / n as f64;
            assert!(gaussian_above > 0.01, "seed {seed}: {gaussian_above}");
        }
    }

    #[test]
    fn a_scale_error_still_shows() {
        // A filter three times too sure (every d² three times its claim) or three times too
        // cautious: ν stays the Gaussian's, and the terms' mean is 6 or 2/3.
        for (scale, want) in [(3.0, 6.0), (1.0 / 3.0, 2.0 / 3.0)] {
            let (nu, mean, _) = learn(f64::INFINITY, scale, 4000, 7);
            assert!(nu > 25.0, "scale {scale}: ν {nu}");
            assert!((mean / want - 1.0).abs() < 0.08, "scale {scale}: mean {mean}");
        }
        // A heavy tail too sure by 3: the shape is learned, the size still shows.
        let (nu, mean, _) = learn(4.0, 3.0, 4000, 7);
        assert!((3.0..=5.5).contains(&nu), "ν {nu}");
        assert!(mean > 3.0, "mean {mean}");
    }

    #[test]
    fn only_a_finite_positive_nis_teaches() {
        let params = TailParams::default();
        let mut tails = PositionTails::default();
        for d2 in [f64::NAN, f64::INFINITY, -1.0, 0.0] {
            for _ in 0..100 {
                tails.learn(d2, &params);
            }
        }
        assert_eq!(tails, PositionTails::default());
        let off = TailParams {
            enabled: false,
            ..params
        };
        let mut rng = StdRng::seed_from_u64(3);
        for _ in 0..1000 {
            tails.learn(draw_d2(&mut rng, 3.0), &off);
        }
        assert_eq!(tails, PositionTails::default());
        assert_eq!(tails.nis(9.0, &off), 9.0);
    }
}
