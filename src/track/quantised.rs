//! Reports rounded to a grid, and their term of the windowed NIS (issue 10).
//!
//! ADS-B sends a ground velocity's east and north components rounded to 1 kt (0.51 m/s;
//! 4 kt when supersonic). An airliner's GNSS velocity is far finer than that (a few cm/s),
//! so in steady flight the value sits in one bin for seconds: 79 % of AFR34ZG's airborne
//! velocity reports repeat the last one exactly (`docs/evaluation.md`, "Velocity reports
//! that repeat"). Its innovation against any smooth prediction is then the rounding error of
//! a value that barely moves: near zero for a while, then a whole step. The filter counts
//! the rounding as noise of variance Δ²/12 in R (Sheppard's correction, right on average),
//! but a Gaussian NIS of such innovations is not χ²: on AFR34ZG the velocity reports' median
//! NIS per degree of freedom was 0.002 where χ²(2)'s is 0.69, and no constant Gaussian
//! claim put more than 56 % of ten-report windows inside their band.
//!
//! What the filter claims about a report is a distribution of the value *before* rounding,
//! N(ẑ, Σ) with Σ = H P⁻ Hᵀ + R_w (R_w the report's own noise, R less the rounding's
//! share). That gives each bin [z − Δ/2, z + Δ/2] its probability, and the report a
//! **randomised quantile residual** (Dunn & Smyth 1996, "Randomized quantile residuals",
//! J. Comput. Graph. Stat. 5(3):236-244): with F the claimed distribution function and U
//! uniform on (0, 1), u = F(a) + U (F(b) − F(a)) is uniform on (0, 1), and r = Φ⁻¹(u)
//! exactly N(0, 1), when the claim is right, whatever the bin's width. For the two
//! components the chain rule of Rosenblatt (1952, "Remarks on a multivariate
//! transformation", Ann. Math. Stat. 23(3):470-472) gives the second's residual from its
//! distribution given the first's bin (here the Gaussian with the first's truncated
//! moments, the posterior the filter itself would form). And when every claim is a
//! one-step-ahead prediction given the reports before, the residuals are independent from
//! report to report (the probability integral transform of a sequence of correct
//! predictive distributions, Diebold, Gunther & Tay 1998, Int. Econ. Rev. 39(4):863-883).
//! So r_e² + r_n² is χ²(2) per report and the window's sum keeps its χ² band, where the
//! Gaussian NIS of a value that repeats does not.
//!
//! For a wide claim (Σ ≫ Δ²) the residual is the Gaussian one of the innovation to within
//! the rounding, so on noisy reports nothing changes (the simulator's NACv 2 noise, σ
//! 1.2 m/s). U comes from a hash of the report and the claim: the same inputs give the same
//! statistic, run after run.
//!
//! The grid is the aircraft's local east and north ([`Grid::axes`]), which the track's plane
//! is turned from by its tilt and the meridians' convergence (up to 9° at
//! `MAX_TRACK_RADIUS_M`): everything here is taken in those axes, where the report's
//! covariance is diagonal (horizontal, horizontal, vertical) and the bins are squares.
//!
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use statrs::function::erf::{erfc, erfc_inv};

/// The least noise a report on a grid is claimed to have before its rounding, (m/s)² per
/// axis: a GNSS receiver's velocity noise, 0.05 m/s. The report's R less the rounding's
/// Δ²/12 can fall below it (a learned scale that saw mostly repeats); the residual then uses
/// this. It matters little: on AFR34ZG's cruise the residuals' window was inside its band
/// 85.2, 85.6 and 85.6 % of the time with 0.02, 0.05 and 0.1 m/s (a prototype of the
/// hybrid's CV filter).
pub const MIN_WHITE_VAR_M2PS2: f64 = 0.05 * 0.05;

/// A report's own noise before rounding, per horizontal axis: the mean of its two horizontal
/// variances `r_a`, `r_b` less the rounding's Δ²/12 (which every report on a grid counts),
/// at least [`MIN_WHITE_VAR_M2PS2`].
fn white_var(r_a: f64, r_b: f64, step: f64) -> f64 {
    (0.5 * (r_a + r_b) - step * step / 12.0).max(MIN_WHITE_VAR_M2PS2)
}

/// The grid a report's horizontal components were rounded to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// The step Δ, in the value's unit (m/s for a ground velocity).
    pub step: f64,
    /// The axes the value was rounded along: the rotation from the aircraft's local east,
    /// north and up to the track's frame (the one that took the report into the frame). A
    /// quaternion, not its matrix: every velocity report carries one, and 32 bytes are a
    /// report's copies' cost where 72 were (`tests/memory_budget.rs`).
    pub axes: UnitQuaternion<f64>,
    /// A turn about the track frame's vertical applied after `axes`, rad: an IMM's turn
    /// models take a velocity report turned by their rate times its age
    /// ([`Grid::turned_about_z`]), and the grid turns with it, kept as an angle until the
    /// axes are needed (for a narrow claim only).
    pub turn_rad: f64,
}

impl Grid {
    /// A grid of step `step` along the columns of `rotation` (a rotation matrix: the local
    /// axes in the track's frame).
    pub fn new(step: f64, rotation: &Matrix3<f64>) -> Self {
        Self {
            step,
            axes: UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
                *rotation,
            )),
            turn_rad: 0.0,
        }
    }

    /// The grid of a report turned by `angle_rad` about the track frame's vertical, with it.
    pub fn turned_about_z(&self, angle_rad: f64) -> Self {
        Self {
            turn_rad: self.turn_rad + angle_rad,
            ..*self
        }
    }

    /// The axes as a matrix (columns: local east, north, up in the track's frame).
    pub fn matrix(&self) -> Matrix3<f64> {
        let axes = self.axes.to_rotation_matrix().into_inner();
        if self.turn_rad == 0.0 {
            return axes;
        }
        let (sin, cos) = self.turn_rad.sin_cos();
        Matrix3::new(cos, -sin, 0.0, sin, cos, 0.0, 0.0, 0.0, 1.0) * axes
    }
}

/// √2.
const SQRT_2: f64 = std::f64::consts::SQRT_2;
/// 1 / √(2π), the standard normal density's constant.
const FRAC_1_SQRT_2PI: f64 = 0.398_942_280_401_432_7;

/// A report on a grid with the filter's narrow claim about its two horizontal components
/// before rounding, in the grid's axes: what its term of the windowed NIS is computed from
/// ([`OnGrid::nis`]). Formed where the update has the innovation (a turn into the grid's
/// axes, about 70 multiplications); the quantiles are taken only when asked, since an IMM
/// forms one per mode and publishes one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OnGrid {
    /// The bins' centres (the reported values).
    reported: [f64; 2],
    /// The claimed mean before rounding, ẑ = z − ε.
    mean: [f64; 2],
    /// The claimed covariance before rounding: east-east, east-north, north-north.
    cov: [f64; 3],
    /// The grid's step Δ.
    step: f64,
}

impl OnGrid {
    /// From an update's innovation (residual ε = z − ẑ and covariance S over a report's
    /// three components, in the track's frame) of a report `reported` made with covariance
    /// `r`, on `grid`. `r` counts the rounding as Δ²/12 per horizontal axis (as every report
    /// on a grid does, `Observed::grid`), which comes off S: the claim is about the value
    /// before rounding, whose own noise is at least [`MIN_WHITE_VAR_M2PS2`].
    ///
    /// `None` when the claim is wide ([`WIDE_CLAIM_STEPS`]: its quantile NIS is then the
    /// Gaussian NIS the update computed, which is the report's term), when the step is not a
    /// positive number, or when a value is not finite.
    pub fn of(
        residual: &Vector3<f64>,
        s: &Matrix3<f64>,
        r: &Matrix3<f64>,
        reported: &Vector3<f64>,
        grid: &Grid,
    ) -> Option<Self> {
        let step = grid.step;
        if !(step > 0.0 && step.is_finite()) {
            return None;
        }
        // Wide: the claim's spread before rounding at least WIDE_CLAIM_STEPS steps on either
        // horizontal axis, taken on the track frame's axes (a threshold, not a bin: the
        // grid's axes are turned from them by a few degrees). A NaN is not wide, and is
        // refused below.
        let white_frame = white_var(r[(0, 0)], r[(1, 1)], step);
        let narrowest = (s[(0, 0)] - r[(0, 0)]).min(s[(1, 1)] - r[(1, 1)]) + white_frame;
        if narrowest >= (WIDE_CLAIM_STEPS * step).powi(2) {
            return None;
        }
        Self::in_grid_axes(residual, s, r, reported, grid)
    }

    /// [`OnGrid::of`] for any claim, wide or not.
    fn in_grid_axes(
        residual: &Vector3<f64>,
        s: &Matrix3<f64>,
        r: &Matrix3<f64>,
        reported: &Vector3<f64>,
        grid: &Grid,
    ) -> Option<Self> {
        let step = grid.step;
        // Into the grid's own axes: only its east and north rows (a'ᵢ S aⱼ).
        let m = grid.matrix();
        let (a0, a1) = (m.column(0).into_owned(), m.column(1).into_owned());
        let quad = |x: &Matrix3<f64>, u: &Vector3<f64>, v: &Vector3<f64>| u.dot(&(x * v));
        let (ree, ren, rnn) = (quad(r, &a0, &a0), quad(r, &a0, &a1), quad(r, &a1, &a1));
        let white = white_var(ree, rnn, step);
        let (ze, zn) = (a0.dot(reported), a1.dot(reported));
        let (ee, en) = (a0.dot(residual), a1.dot(residual));
        let g = Self {
            reported: [ze, zn],
            mean: [ze - ee, zn - en],
            cov: [
                quad(s, &a0, &a0) - ree + white,
                quad(s, &a0, &a1) - ren,
                quad(s, &a1, &a1) - rnn + white,
            ],
            step,
        };
        let finite = g
            .reported
            .iter()
            .chain(&g.mean)
            .chain(&g.cov)
            .all(|v| v.is_finite());
        finite.then_some(g)
    }

    /// The report's randomised quantile residuals, east then north given east (module doc):
    /// each N(0, 1) when the claim is right. NaN when the claim is not a covariance.
    pub fn residuals(&self) -> [f64; 2] {
        let [u_e, u_n] = uniforms(self.hash());
        let [ce, cen, cn] = self.cov;
        let half = 0.5 * self.step;
        let [ze, zn] = self.reported;
        let [me, mn] = self.mean;
        if !(ce > 0.0 && cn > 0.0) {
            return [f64::NAN; 2];
        }
        let east = Bin::of(me, ce, ze - half, ze + half);
        // North given east's bin: the Gaussian the first component's truncated moments
        // leave (the update a filter would make with that bin).
        let (t_mean, t_var) = east.truncated_moments();
        let k = cen / ce;
        let mean_n = mn + k * (t_mean - me);
        let var_n = (cn - k * cen + k * k * t_var).max(f64::MIN_POSITIVE);
        let north = Bin::of(mean_n, var_n, zn - half, zn + half);
        [east.quantile_residual(u_e), north.quantile_residual(u_n)]
    }

    /// The claim's variance before rounding, mean of its two axes.
    pub fn claim_var(&self) -> f64 {
        0.5 * (self.cov[0] + self.cov[2])
    }

    /// The report's term of the windowed NIS: the sum of its squared quantile residuals,
    /// χ²(2) when the claim is right.
    pub fn nis(&self) -> f64 {
        let [e, n] = self.residuals();
        e * e + n * n
    }
}

/// A claim whose spread before rounding is at least this many grid steps on each horizontal
/// axis is wide ([`OnGrid::of`]): the bin spans at most half its σ, and the quantile NIS
/// averages what the Gaussian one does within 5 % (module test
/// `a_wide_claim_reads_as_the_gaussian_nis`, at 2.4 steps). The quantiles cost about 200 ns
/// (four error functions, two inverses); a wide claim pays nothing for them: the
/// simulator's NACv 2 velocities, and a filter that takes NACv literally.
pub const WIDE_CLAIM_STEPS: f64 = 2.0;

impl OnGrid {
    /// Bits of every input, mixed: the seed of the report's uniforms (a multiply-rotate
    /// fold, then one SplitMix64 finish, which spreads any input bit over the whole word).
    fn hash(&self) -> u64 {
        let h = self
            .reported
            .iter()
            .chain(&self.mean)
            .chain(&self.cov)
            .fold(0x9e37_79b9_7f4a_7c15_u64, |h, v| {
                (h ^ v.to_bits())
                    .wrapping_mul(0xff51_afd7_ed55_8ccd)
                    .rotate_left(29)
            });
        splitmix64(h)
    }
}

/// SplitMix64's finaliser (Steele, Lea & Flood 2014): a 64-bit mix whose outputs pass
/// BigCrush, for turning the inputs' bits into uniforms.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Two uniforms in (0, 1) from a seed: 53 bits each, at the centres of their cells (never 0
/// or 1).
fn uniforms(seed: u64) -> [f64; 2] {
    let unit = |x: u64| ((x >> 11) as f64 + 0.5) / (1_u64 << 53) as f64;
    let a = splitmix64(seed);
    [unit(a), unit(splitmix64(a))]
}

/// Φ(x), the standard normal distribution function, accurate in the lower tail.
fn phi_lower(x: f64) -> f64 {
    0.5 * erfc(-x / SQRT_2)
}

/// 1 − Φ(x), accurate in the upper tail.
fn phi_upper(x: f64) -> f64 {
    0.5 * erfc(x / SQRT_2)
}

/// The standard normal density.
fn density(x: f64) -> f64 {
    FRAC_1_SQRT_2PI * (-0.5 * x * x).exp()
}

/// One component's claim N(`mean`, `var`) against its bin [a, b], standardised:
/// α = (a − mean)/σ, β = (b − mean)/σ, and the bin's probability z, each probability taken in
/// the tail the bin lies in (1 − Φ above the mean, Φ below it), where it keeps its digits: a
/// bin 10σ out has a probability of 10⁻²³, which Φ(β) − Φ(α) near 1 would lose entirely.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Bin {
    mean: f64,
    var: f64,
    a: f64,
    b: f64,
    alpha: f64,
    beta: f64,
    /// The distribution function at α and β, in the bin's tail: (1 − Φ(α), 1 − Φ(β)) when
    /// α ≥ 0, else (Φ(α), Φ(β)).
    p_alpha: f64,
    p_beta: f64,
}

impl Bin {
    fn of(mean: f64, var: f64, a: f64, b: f64) -> Self {
        let sd = var.sqrt();
        let (alpha, beta) = ((a - mean) / sd, (b - mean) / sd);
        let (p_alpha, p_beta) = if alpha >= 0.0 {
            (phi_upper(alpha), phi_upper(beta))
        } else {
            (phi_lower(alpha), phi_lower(beta))
        };
        Self {
            mean,
            var,
            a,
            b,
            alpha,
            beta,
            p_alpha,
            p_beta,
        }
    }

    /// The bin's probability under the claim.
    fn probability(&self) -> f64 {
        if self.alpha >= 0.0 {
            self.p_alpha - self.p_beta
        } else {
            self.p_beta - self.p_alpha
        }
    }

    /// The randomised quantile residual with the uniform `u`: Φ⁻¹ of a point drawn
    /// uniformly between the distribution function at the bin's edges. A bin beyond f64's
    /// reach (about 38σ) gives the standardised distance to its nearer edge, which is what
    /// the residual tends to there.
    fn quantile_residual(&self, u: f64) -> f64 {
        if self.alpha >= 0.0 {
            // Upper tail: 1 − u = Q(α) − U (Q(α) − Q(β)).
            let q = self.p_alpha - u * (self.p_alpha - self.p_beta);
            if q > 0.0 {
                SQRT_2 * erfc_inv(2.0 * q)
            } else {
                self.alpha
            }
        } else {
            // Lower tail (or a bin that holds the mean, whose probabilities are far from 0
            // and 1): u = Φ(α) + U (Φ(β) − Φ(α)).
            let p = self.p_alpha + u * (self.p_beta - self.p_alpha);
            if p > 0.0 {
                -SQRT_2 * erfc_inv(2.0 * p)
            } else {
                self.beta
            }
        }
    }

    /// The mean and variance of the claim truncated to the bin (Johnson, Kotz &
    /// Balakrishnan 1994, §10.1). Where the bin's probability has lost its digits (a bin
    /// more than about 7σ out) the nearer edge with the bin's own spread, Δ²/12; the mean
    /// always inside the bin, the variance positive and at most the claim's.
    fn truncated_moments(&self) -> (f64, f64) {
        let (mean, var, a, b) = (self.mean, self.var, self.a, self.b);
        let z = self.probability();
        let bin_var = (b - a) * (b - a) / 12.0;
        let (t_mean, t_var) = if z > 1e-12 {
            let (da, db) = (density(self.alpha), density(self.beta));
            let ratio = (da - db) / z;
            (
                mean + var.sqrt() * ratio,
                var * (1.0 + (self.alpha * da - self.beta * db) / z - ratio * ratio),
            )
        } else {
            (mean.clamp(a, b), bin_var)
        };
        let m = if t_mean.is_finite() {
            t_mean.clamp(a, b)
        } else {
            mean.clamp(a, b)
        };
        let v = if t_var.is_finite() && t_var > 0.0 {
            t_var.min(var).min(3.0 * bin_var)
        } else {
            bin_var.min(var)
        };
        (m, v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    const KT: f64 = 1852.0 / 3600.0;

    fn round_to(x: f64, step: f64) -> f64 {
        (x / step).round() * step
    }

    /// A report on the grid with its claim, the innovation laid out as an update gives it.
    fn on_grid(truth: [f64; 2], claim: [f64; 2], cov: [f64; 3], white: f64, step: f64) -> OnGrid {
        let z = Vector3::new(round_to(truth[0], step), round_to(truth[1], step), 0.0);
        let rounding = step * step / 12.0;
        let r = Matrix3::from_diagonal(&Vector3::new(white + rounding, white + rounding, 1.0));
        let s = Matrix3::new(
            cov[0] + r[(0, 0)],
            cov[1],
            0.0,
            cov[1],
            cov[2] + r[(1, 1)],
            0.0,
            0.0,
            0.0,
            2.0,
        );
        let residual = z - Vector3::new(claim[0], claim[1], 0.0);
        OnGrid::in_grid_axes(&residual, &s, &r, &z, &grid(step)).unwrap()
    }

    /// A grid along the track frame's own axes.
    fn grid(step: f64) -> Grid {
        Grid::new(step, &Matrix3::identity())
    }

    /// The residuals are taken in the grid's axes: a report and its claim turned into a
    /// frame tilted and turned from them (as far from the track's origin) give the same
    /// residuals as in the grid's own frame, to rounding.
    #[test]
    fn the_residuals_are_taken_in_the_grids_axes() {
        let mut rng = StdRng::seed_from_u64(12);
        let std = Normal::new(0.0, 1.0).unwrap();
        let turn = nalgebra::Rotation3::from_euler_angles(0.09, -0.05, 0.6).into_inner();
        for _ in 0..200 {
            let truth = [
                230.0 + 0.1 * std.sample(&mut rng),
                -3.0 + 0.1 * std.sample(&mut rng),
            ];
            let g = on_grid(truth, [230.0, -3.0], [0.01, 0.002, 0.012], 0.0025, KT);
            // The same report in the turned frame: value, claim and covariances rotated.
            let z = Vector3::new(g.reported[0], g.reported[1], -1.0);
            let mean = Vector3::new(g.mean[0], g.mean[1], -1.0);
            let rounding = KT * KT / 12.0;
            let r =
                Matrix3::from_diagonal(&Vector3::new(0.0025 + rounding, 0.0025 + rounding, 0.5));
            let claim = Matrix3::new(0.01, 0.002, 0.0, 0.002, 0.012, 0.0, 0.0, 0.0, 0.3);
            let s = claim + r;
            let turned = OnGrid::in_grid_axes(
                &(turn * (z - mean)),
                &(turn * s * turn.transpose()),
                &(turn * r * turn.transpose()),
                &(turn * z),
                &Grid::new(KT, &turn),
            )
            .unwrap();
            let (a, b) = (g.residuals(), turned.residuals());
            // The hash seeds differ (other bits), so compare through the bins' quantiles:
            // both residuals of each report lie in the same bin's image.
            for k in 0..2 {
                assert!((turned.reported[k] - g.reported[k]).abs() < 1e-9);
                assert!((turned.mean[k] - g.mean[k]).abs() < 1e-9);
                assert!(a[k].is_finite() && b[k].is_finite());
            }
            assert!((turned.cov[0] - g.cov[0]).abs() < 1e-12);
            assert!((turned.cov[1] - g.cov[1]).abs() < 1e-12);
            assert!((turned.cov[2] - g.cov[2]).abs() < 1e-12);
        }
    }

    /// The quantile residual against the closed form: with a bin far wider than nothing
    /// and a claim at its centre, u's image under Φ⁻¹; a bin far in either tail stays
    /// finite and on its side; the truncated moments match a numerical integration.
    #[test]
    fn one_component_against_closed_forms() {
        // A bin (−∞-like, +∞-like) is the whole line: r = Φ⁻¹(u).
        for (u, want) in [
            (0.5, 0.0),
            (0.975, 1.959_963_984_540_054),
            (0.025, -1.959_963_984_540_054),
        ] {
            let r = Bin::of(0.0, 1.0, -40.0, 40.0).quantile_residual(u);
            assert!((r - want).abs() < 1e-12, "{u}: {r}");
        }
        // Far tails keep digits: a bin at 10-11 σ gives a residual between 10 and 11.
        for u in [1e-9, 0.3, 0.999] {
            let up = Bin::of(0.0, 1.0, 10.0, 11.0).quantile_residual(u);
            assert!((10.0..=11.0).contains(&up), "{up}");
            let down = Bin::of(0.0, 1.0, -11.0, -10.0).quantile_residual(u);
            assert!((-11.0..=-10.0).contains(&down), "{down}");
        }
        // Beyond f64's reach: the nearer edge.
        assert_eq!(Bin::of(0.0, 1.0, 50.0, 51.0).quantile_residual(0.5), 50.0);
        assert_eq!(
            Bin::of(0.0, 1.0, -51.0, -50.0).quantile_residual(0.5),
            -50.0
        );
        // Truncated moments against a midpoint-rule integral.
        for (mean, var, a, b) in [
            (0.0, 1.0, -0.3, 0.5),
            (1.0, 0.04, 0.8, 1.4),
            (0.0, 2.0, 1.0, 3.0),
        ] {
            let n = 200_000;
            let (mut w, mut m1, mut m2) = (0.0, 0.0, 0.0);
            for i in 0..n {
                let x = a + (b - a) * (i as f64 + 0.5) / n as f64;
                let d = (-(x - mean) * (x - mean) / (2.0 * var)).exp();
                w += d;
                m1 += d * x;
                m2 += d * x * x;
            }
            let (m, v) = (m1 / w, m2 / w - (m1 / w) * (m1 / w));
            let (tm, tv) = Bin::of(mean, var, a, b).truncated_moments();
            assert!((tm - m).abs() < 1e-6, "{tm} vs {m}");
            assert!((tv - v).abs() < 1e-6, "{tv} vs {v}");
        }
    }

    /// A right claim gives N(0, 1) residuals, uncorrelated between the components, a
    /// χ²(2) NIS per report, and windows of 20 reports inside their χ²(40) band 95 % of the
    /// time (95.4 %), where the Gaussian NIS of the same rounded values is inside it 74 %:
    /// the value wanders slowly through 1-kt bins, the claim is its mean with the claimed
    /// spread (σ 0.1-0.14 m/s, correlated between east and north) and the report's own
    /// noise (0.06 m/s), so the rounding error of successive reports is correlated, as a
    /// real airliner's is.
    #[test]
    fn a_right_claim_gives_standard_residuals_where_the_gaussian_nis_fails() {
        let mut rng = StdRng::seed_from_u64(3);
        let white: f64 = 0.06 * 0.06;
        let n = 40_000;
        let (mut s1, mut s2, mut s3, mut cross, mut se2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut counts = [0_u32; 10];
        let mut held = 0;
        let mut last = [f64::NAN; 2];
        let cov = [0.01, 0.004, 0.02];
        let chol = Matrix3::new(cov[0], cov[1], 0.0, cov[1], cov[2], 0.0, 0.0, 0.0, 1.0)
            .cholesky()
            .unwrap()
            .l();
        let std = Normal::new(0.0, 1.0).unwrap();
        let mut base = [230.0, -40.0];
        let (mut window_q, mut window_g) = (Vec::new(), Vec::new());
        let (mut in_band_q, mut in_band_g, mut windows) = (0, 0, 0);
        // χ²(40)'s 2.5 % and 97.5 % points.
        let band = 24.433..=59.342;
        for k in 0..n {
            base[0] += 0.01 * std.sample(&mut rng);
            base[1] += 0.01 * std.sample(&mut rng);
            // The value before rounding is the claim's mean plus an error drawn from the
            // claim, plus the report's own noise.
            let e = chol * Vector3::new(std.sample(&mut rng), std.sample(&mut rng), 0.0);
            let w = white.sqrt();
            let truth = [
                base[0] + e.x + w * std.sample(&mut rng),
                base[1] + e.y + w * std.sample(&mut rng),
            ];
            let g = on_grid(truth, base, cov, white, KT);
            if g.reported == last {
                held += 1;
            }
            last = g.reported;
            let [re, rn] = g.residuals();
            s1 += re;
            s2 += re * re + rn * rn;
            se2 += re * re;
            s3 += rn;
            cross += re * rn;
            let nis = g.nis();
            let bucket = (chi2_2_cdf(nis) * 10.0) as usize;
            counts[bucket.min(9)] += 1;
            // The Gaussian NIS of the same report with R = white + Δ²/12.
            let rq = white + KT * KT / 12.0;
            let (se, sen, sn) = (cov[0] + rq, cov[1], cov[2] + rq);
            let (de, dn) = (g.reported[0] - base[0], g.reported[1] - base[1]);
            let det = se * sn - sen * sen;
            let gauss = (sn * de * de - 2.0 * sen * de * dn + se * dn * dn) / det;
            window_q.push(nis);
            window_g.push(gauss);
            if window_q.len() == 20 {
                windows += 1;
                in_band_q += usize::from(band.contains(&window_q.iter().sum::<f64>()));
                in_band_g += usize::from(band.contains(&window_g.iter().sum::<f64>()));
                window_q.clear();
                window_g.clear();
            }
            let _ = k;
        }
        let nf = f64::from(n);
        assert!(
            (s1 / nf).abs() < 0.02 && (s3 / nf).abs() < 0.02,
            "{s1} {s3}"
        );
        assert!(
            (s2 / nf - 2.0).abs() < 0.04,
            "mean NIS {} (east {} north {})",
            s2 / nf,
            se2 / nf,
            (s2 - se2) / nf
        );
        assert!((cross / nf).abs() < 0.02, "cross {}", cross / nf);
        // Deciles of χ²(2): each 10 % within 1 point.
        for c in counts {
            assert!((f64::from(c) / nf - 0.1).abs() < 0.01, "{counts:?}");
        }
        let (q, g) = (
            in_band_q as f64 / windows as f64,
            in_band_g as f64 / windows as f64,
        );
        assert!((0.93..=0.97).contains(&q), "quantile windows in band {q}");
        assert!(g < 0.8, "gaussian windows in band {g}");
        assert!(held > n / 4, "held {held}");
    }

    /// χ²(2)'s distribution function.
    fn chi2_2_cdf(x: f64) -> f64 {
        1.0 - (-0.5 * x).exp()
    }

    /// A claim too sure of itself (its spread a third of the error's) or too cautious
    /// (three times) shows: the mean NIS far above or below 2.
    #[test]
    fn a_wrong_claim_shows() {
        let mut rng = StdRng::seed_from_u64(8);
        let std = Normal::new(0.0, 1.0).unwrap();
        for (claimed_sd, true_sd, above) in [(0.1, 0.3, true), (0.9, 0.3, false)] {
            let mut sum = 0.0;
            for _ in 0..5000 {
                let base = [rng.gen_range(100.0..200.0), rng.gen_range(-50.0..50.0)];
                let truth = [
                    base[0] + true_sd * std.sample(&mut rng),
                    base[1] + true_sd * std.sample(&mut rng),
                ];
                let v = claimed_sd * claimed_sd;
                sum += on_grid(truth, base, [v, 0.0, v], MIN_WHITE_VAR_M2PS2, KT).nis();
            }
            let mean = sum / 5000.0;
            if above {
                assert!(mean > 4.0, "{mean}");
            } else {
                assert!(mean < 1.0, "{mean}");
            }
        }
    }

    /// On a claim far wider than the grid, the quantile NIS is the Gaussian NIS of the
    /// innovation to within the rounding: a wide claim (σ 1.2 m/s, NACv 2's) moves by a few
    /// percent on average, and the same inputs give the same number.
    #[test]
    fn a_wide_claim_reads_as_the_gaussian_nis() {
        let mut rng = StdRng::seed_from_u64(4);
        let std = Normal::new(0.0, 1.0).unwrap();
        let (mut q, mut g) = (0.0, 0.0);
        for _ in 0..20_000 {
            let base = [rng.gen_range(100.0..200.0), rng.gen_range(-50.0..50.0)];
            let sd = 1.5_f64.sqrt();
            let truth = [
                base[0] + sd * std.sample(&mut rng),
                base[1] + sd * std.sample(&mut rng),
            ];
            let o = on_grid(truth, base, [0.1, 0.0, 0.1], 1.4, KT);
            q += o.nis();
            assert_eq!(o.nis().to_bits(), o.nis().to_bits());
            // Such a claim is wide: the update's Gaussian NIS stands for it.
            let rq = 1.4 + KT * KT / 12.0;
            let r = Matrix3::from_diagonal(&Vector3::new(rq, rq, 1.0));
            let s = r + Matrix3::from_diagonal(&Vector3::new(0.1, 0.1, 1.0));
            let z = Vector3::new(o.reported[0], o.reported[1], 0.0);
            assert!(OnGrid::of(&Vector3::zeros(), &s, &r, &z, &grid(KT)).is_none());
            let s = 0.1 + 1.4 + KT * KT / 12.0;
            let (de, dn) = (o.reported[0] - base[0], o.reported[1] - base[1]);
            g += (de * de + dn * dn) / s;
        }
        assert!((q / 20_000.0 - 2.0).abs() < 0.06, "{}", q / 20_000.0);
        assert!((q / g - 1.0).abs() < 0.05, "{q} vs {g}");
    }

    /// Bad inputs give `None` or NaN, never a panic: a step of 0 or NaN, a NaN value, a
    /// claim that is not a covariance.
    #[test]
    fn bad_inputs_are_refused() {
        let z = Vector3::new(100.0, 0.0, 0.0);
        let m = Matrix3::identity();
        assert!(OnGrid::of(&z, &m, &m, &z, &grid(0.0)).is_none());
        assert!(OnGrid::of(&z, &m, &m, &z, &grid(f64::NAN)).is_none());
        assert!(OnGrid::of(&Vector3::new(f64::NAN, 0.0, 0.0), &m, &m, &z, &grid(KT)).is_none());
        let negative = Matrix3::identity() * -5.0;
        let g = OnGrid::of(&z, &negative, &m, &z, &grid(KT)).unwrap();
        assert!(g.nis().is_nan());
    }
}
