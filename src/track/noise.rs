//! Measurement noise learned per aircraft from its own innovations (issue 10).
//!
//! ADS-B declares its accuracy (NACp, NACv; NUCp on older transponders) as a 95 % bound,
//! not as a noise level, and many aircraft declare nothing: a filter that takes the bound
//! literally is far too sure of itself on one aircraft and far too cautious on the next
//! (on the LAX recording the aircraft declaring NACp 10 show a median NIS per degree of
//! freedom of 2-5; the AFR34ZG flight, declaring nothing, 0.05). So each aircraft scales
//! the declared covariance R₀ of each measured block (position, velocity) by a factor λ
//! it learns:
//!
//! - **Method**: covariance matching on the innovations (Mehra 1972, "Approaches to
//!   adaptive filtering", IEEE TAC 17(5), §III-B; in navigation "innovation-based adaptive
//!   estimation", Mohamed & Schwarz 1999, J. Geodesy 73, eq. 22): for a filter at its
//!   optimum E[ε εᵀ] = H P⁻ Hᵀ + R, so R̂ = Ĉ_ε − H P⁻ Hᵀ over a window. Only the scale
//!   is learned, from traces over the horizontal components of the block:
//!   λ̂ = (εᵀε − Tr(H P⁻ Hᵀ)) / Tr(R₀), one sample per report, averaged.
//! - **Horizontal only**: NACp and NACv describe the GNSS solution's horizontal accuracy,
//!   and that is what is learned and scaled. The vertical is another sensor whose noise is
//!   known: barometric altitude in 25 ft steps, vertical rate in 64 ft/min steps, constant in
//!   level flight (their innovations there are zero, and would teach a zero noise).
//! - **Prior and bound**: the declared R₀ is the prior, worth [`NoiseParams::prior_weight`]
//!   samples of λ = 1, and λ is kept in [`NoiseParams::min_scale`, `NoiseParams::max_scale`]:
//!   the declaration bounds what is learned (σ between a twentieth and four times what it
//!   implies, by default). The factor applied, λ', is λ shrunk towards 1 by twice its
//!   standard error ([`NoiseScale::effective`]): a declaration the data do not contradict is
//!   used as it is.
//! - **Outliers**: a plain mean of squares belongs to its largest terms. Real feeds have
//!   a few reports from another error process (a position from a bad CPR pair, a GNSS
//!   glitch, a late frame), and one of them, even clamped at `max_scale`, outweighs a
//!   hundred ordinary ones when the true λ is small. So εᵀε is first winsorised at
//!   [`NoiseParams::outlier_ratio`] times its predicted size Tr(S), a Huber-type robust
//!   scale (Huber 1981, *Robust Statistics*, §5.6): an outlier then counts as an unlucky
//!   draw of the noise being learned. A persistent rise of the noise still raises λ, by up
//!   to (ratio − 1)/(window + prior weight) of itself a report, 3.6 % at the defaults.
//!   Measured on AFR34ZG (nothing declared, the NUCp fall-back σ₀ about 40 m per axis):
//!   most position samples were about 0.02, and λ sat at 0.1-0.35, held up by the few at
//!   the clamp. With the cap, the hybrid's CV filter's horizontal position NIS per degree
//!   of freedom (a probe: εᵀε / (Tr S / 2)) went from a median of 0.29 to 0.72, and its
//!   windows of 10 position reports inside their 95 % band from 31 % to 49 %.
//! - **Window**: an exponentially weighted mean over about [`NoiseParams::window`] reports
//!   (50 s of ADS-B at 2 Hz): slow against a manoeuvre's onset, fast against a flight.
//! - **Correlated error** (a consider covariance, after Schmidt 1966 and Bierman 1977
//!   §VII.2): a GNSS position error wanders over tens of seconds, and a filter that averages
//!   2 Hz reports as independent shrinks its covariance far below it; the innovations do not
//!   show such an error either, since the track follows it. A declared NACp bounds the
//!   *total* error, so the part of the declared variance that is not white noise,
//!   σ₀²·max(0, 1 − λ_w') per horizontal axis, is taken as slowly correlated and added to the
//!   published position covariance ([`NoiseLearner::position_bias_var`]). The white share
//!   λ_w is learned from the steps between successive position reports
//!   ([`NoiseLearner::learn_position_step`]), not from the innovations: a filter whose
//!   memory outgrows the error's time constant (a small process noise) shows the error's
//!   drift in its innovations, which covariance matching would take for white noise, and
//!   the correlated share would vanish just when the filter averages most (measured:
//!   `docs/evaluation.md`, "Velocity reports that repeat"). For
//!   an error whose time constant exceeds the filter's memory (seconds) the filter passes it
//!   through whole, so this is its error covariance; a loose declaration makes it cautious.
//!   With nothing declared (the NUCp fall-back is a containment bound of the type code, not
//!   of this aircraft) nothing is added.
//! - **When**: the owner decides. The hybrid tracker learns only while its CV filter runs
//!   (level or steady flight): in a manoeuvre the innovations measure the model's error,
//!   not the receiver's, and would teach the filter to ignore the next manoeuvre.

#[cfg(test)]
use super::UNMEASURED_VARIANCE;
use super::{Estimate, Measurement, Observed};
use nalgebra::{Matrix3, Vector3};

/// Mean Earth radius, m (IUGG R1), for [`local_up`].
pub(crate) const EARTH_RADIUS_M: f64 = 6_371_008.8;

/// The local vertical of a spherical Earth at `pos_m` (a position in a track's tangent
/// frame), a unit vector in the frame; the frame's own up where that is not finite. The
/// sphere's normal differs from the ellipsoid's by a fraction of a percent of the tilt.
pub fn local_up(pos_m: &Vector3<f64>) -> Vector3<f64> {
    let up = (pos_m + Vector3::z() * EARTH_RADIUS_M).normalize();
    if up.iter().all(|c| c.is_finite()) {
        up
    } else {
        Vector3::z()
    }
}

/// The height above the spherical Earth of [`local_up`] of `pos_m` (a position in a
/// track's tangent frame), m: the altitude the frame's up coordinate falls below as the
/// aircraft moves from the frame's origin (125 m at 40 km), for tests of the altitude's
/// change. The sphere's height differs from the ellipsoid's by a constant over a track's
/// few seconds.
pub fn height_m(pos_m: &Vector3<f64>) -> f64 {
    (pos_m + Vector3::z() * EARTH_RADIUS_M).norm() - EARTH_RADIUS_M
}

/// Tuning of the learner.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseParams {
    /// Learn at all; `false` keeps λ = 1 (the declared R). Default true.
    pub enabled: bool,
    /// Weight of the declared R₀ (λ = 1) in the mean, in reports. Default 10: five seconds
    /// of reports before the data outweigh the declaration.
    pub prior_weight: f64,
    /// The same for velocity reports that declare no accuracy (NACv or NUCr 0), whose R₀ is
    /// then NACv 1's bound (10 m/s), not this aircraft's noise. Default 1.
    ///
    /// The mean is linear in λ, so a prior of λ = 1 worth 10 reports still weighs 10/110
    /// once the window is full: a velocity whose noise is a fiftieth of the fall-back
    /// (λ = 0.02: 0.6 m/s under NACv 1's σ of 4 m/s) is held at λ ≈ 0.09 + 0.91·0.02 ≈
    /// 0.11, five times its variance, and the prior fades by e⁻¹ only every 110 reports
    /// after that. Measured on `turns-undeclared` (100 runs, hybrid; docs/evaluation.md):
    /// velocity ANEES 0.96 → 1.33, position 1.67 → 1.92, windowed NIS in band 68 → 81 %,
    /// turn onset 1.19 → 1.03 s; the scenarios that declare NACv, unchanged.
    ///
    /// Positions keep [`NoiseParams::prior_weight`]: whether an aircraft declares NACp is
    /// known only from its operational status message, seconds after its first position,
    /// and a weak prior over those first reports moved the declared scenarios (departure
    /// position ANEES 1.63 → 1.53 over 100 runs, out of its band). Where the accuracy is
    /// declared the stronger prior is needed: with a prior of 1 for every block, paper 002's
    /// early λ scatters and its false switches rise from 0.09 to 0.63 per 100 straight
    /// updates.
    pub undeclared_prior_weight: f64,
    /// Reports in covariance matching's exponential window for λ of the position reports.
    /// Default 30 (15 s at 2 Hz; `tracker.hybrid.noise_window_reports`). The velocity
    /// reports' λ has its own, [`NoiseParams::velocity_window`].
    ///
    /// A real aircraft's noise is not one constant, and a short memory follows it: near an
    /// airport its steady legs last tens of seconds between manoeuvres (the filter learns
    /// only on them), and on LAX, with 100, an aircraft's velocity λ was still falling from
    /// the declared bound well into a leg, its windows of the NIS below their band (a
    /// probe, docs/evaluation.md "A shorter memory": λ 0.6 → 0.49 over 15 s at −0.7 % a
    /// report, the data saying 0.05). Measured (hybrid, steady windowed NIS in band, the
    /// position window then the velocity's): LAX 67.0 % at 100/100, 68.8 at 100/30, 69.6 at
    /// 50/30, 71.2 at 30/30, 70.7 at 20/30, 71.6 at 10/30, 70.9 at 30/20; AFR34ZG 84.3, 84.7,
    /// 81.9, 82.8, 80.6, 82.1, 80.8 (one flight's 1,249 steady updates: it scatters by ±2
    /// points from one setting to the next, LAX's 13,375 much less). Below 30 LAX gains
    /// nothing more and each λ scatters more. On the simulator (40 runs) the straight-leg
    /// RMSE and labels are the same at 30/30, the windowed NIS in band up by up to 8 points.
    pub window: f64,
    /// The same window for λ of the velocity reports. Default 30
    /// (`tracker.hybrid.velocity_noise_window_reports`): on LAX 10, 20, 30, 50 and 100
    /// (positions at 100) gave 67.1, 68.2, 68.8, 67.5, 67.0 % in band.
    pub velocity_window: f64,
    /// Reports in the window of the white position noise learned from successive positions
    /// ([`NoiseLearner::learn_position_step`]), which the consider term reads. Default 100:
    /// at 30 the consider term scatters with it and the airliner's position ANEES rose
    /// 4.13 → 4.30 (40 runs; docs/evaluation.md, "A shorter memory").
    pub white_window: f64,
    /// Lower bound on λ. Default 1/400 (σ a twentieth of the declared: a NACv 1 bound of
    /// 10 m/s is a σ of 4 m/s, and real reports scatter by a few tenths).
    pub min_scale: f64,
    /// Upper bound on λ. Default 16 (σ four times the declared).
    pub max_scale: f64,
    /// εᵀε is winsorised at this many times Tr(S) before it becomes a sample (module doc,
    /// "Outliers"). Default 5: a 2-component Gaussian innovation exceeds it with probability
    /// e⁻⁵ = 0.7 %, and the winsorised mean is low by that much, which λ's own scatter
    /// (the shrinkage of [`NoiseScale::effective`]) covers.
    pub outlier_ratio: f64,
    /// Let the data overrule a declaration they contradict ([`PRIOR_CONFLICT_SCALE`]).
    /// Default true.
    pub prior_conflict: bool,
    /// Weight α per report of the running mean of the velocity innovation that covariance
    /// matching centres on ([`InnovationMean`]); 0 reads εᵀε as it is. Default 0.2, a mean
    /// over about nine reports (4-5 s at 2 Hz): shorter than the gentle speed changes it
    /// is for, longer than the scatter of one report. Measured on LAX (`evaluate
    /// --recording`, hybrid, steady windows in band; docs/evaluation.md): 61.9 % at 0,
    /// 63.1 at 0.05, 65.7 at 0.1, 67.0 at 0.2, 66.8 at 0.3; AFR34ZG 83.6, 84.4, 82.5, 84.3,
    /// 80.5. Positions are not centred: their mean is the timing runs and the GNSS wander
    /// the consider term is for (tried: docs/evaluation.md).
    pub velocity_centre_weight: f64,
}

impl Default for NoiseParams {
    fn default() -> Self {
        Self {
            enabled: true,
            prior_weight: 10.0,
            undeclared_prior_weight: 1.0,
            window: 30.0,
            velocity_window: 30.0,
            white_window: 100.0,
            min_scale: 1.0 / 400.0,
            max_scale: 16.0,
            outlier_ratio: 5.0,
            prior_conflict: true,
            velocity_centre_weight: 0.2,
        }
    }
}

/// One block's share of an update, over its measured horizontal components: what
/// covariance matching reads.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BlockStat {
    /// εᵀε of the nominal innovation, m² or m²/s².
    pub e2: f64,
    /// Tr(S) of the nominal innovation covariance.
    pub tr_s: f64,
    /// Tr(R) as used in the update (λ R₀).
    pub tr_r: f64,
    /// The innovation's first two components (east and north of the track's frame), zero
    /// where not measured: what [`InnovationMean`] centres εᵀε on.
    pub e_h: [f64; 2],
}

impl BlockStat {
    /// Whether the block was measured at all.
    pub fn measured(&self) -> bool {
        self.tr_r > 0.0
    }

    /// Whether the innovation says something about R: the state is no less certain than
    /// the report. While it is less certain (a young track, a long gap), the innovation
    /// mostly measures the state's error: εᵀε − Tr(H P⁻ Hᵀ) is then a small difference of
    /// large numbers, often far below zero, and says little about R.
    fn informative(&self) -> bool {
        self.measured() && self.tr_s - self.tr_r <= self.tr_r
    }
}

/// The running mean of a block's innovation, which covariance matching centres on
/// ([`NoiseParams::velocity_centre_weight`]).
///
/// Covariance matching (module doc) reads εᵀε as the innovation's *covariance*, which holds
/// only for a zero-mean innovation. A model error that persists is a mean: an airliner in
/// "steady" flight changes its speed by a few hundredths of a m/s² for tens of seconds, under
/// every acceleration test, and the CV filter follows it a fraction of a second late, so
/// its velocity innovations sit off zero along the track for as long (on
/// `lax-messages.avr.txt` +0.27 m/s while the speed grows at 0.05-0.2 m/s², −0.21 m/s while
/// it falls: docs/evaluation.md, "Gentle speed changes"). Read as noise, that mean raises
/// λ, a larger R makes the filter lag more, and the lag raises λ again; the claim ends up
/// wide where the speed is steady. Myers & Tapley (1976, "Adaptive sequential estimation
/// with unknown noise statistics", IEEE Trans. Autom. Control 21(4):520-523) estimate R from
/// the residuals' sample covariance about their sample mean for that reason: a bias is not
/// noise.
///
/// The mean is exponential, of weight α per sample (at least 1/n over the first n), and
/// excludes the sample it centres, so for a zero-mean innovation E|ε − m|² = E|ε|² (1 + v)
/// with v the mean's variance in units of one sample's, v' = (1 − α)² v + α²; dividing by
/// 1 + v makes the centred square unbiased (α/(2 − α) once the weight has settled).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct InnovationMean {
    mean: [f64; 2],
    /// The mean's variance over one sample's (v above).
    var: f64,
    /// Samples seen, up to 1/α.
    n: f64,
}

impl InnovationMean {
    /// `stat` with εᵀε centred on the mean of the samples before it (unbiased, type doc),
    /// then `stat`'s innovation taken into the mean at weight `alpha`. `stat` unchanged when
    /// `alpha` is not in (0, 1] or the block says nothing about R
    /// ([`BlockStat::informative`]), and on the first sample (no mean yet).
    pub fn centre(&mut self, stat: &BlockStat, alpha: f64) -> BlockStat {
        if !(alpha > 0.0 && alpha <= 1.0 && stat.informative()) {
            return *stat;
        }
        let [m_e, m_n] = self.mean;
        let [e, n] = stat.e_h;
        let centred = BlockStat {
            e2: ((e - m_e).powi(2) + (n - m_n).powi(2)) / (1.0 + self.var),
            ..*stat
        };
        let first = self.n < 1.0;
        self.n = (self.n + 1.0).min(1.0 / alpha);
        let w = alpha.max(1.0 / self.n);
        self.mean = [m_e + w * (e - m_e), m_n + w * (n - m_n)];
        self.var = (1.0 - w).powi(2) * self.var + w * w;
        if first || !centred.e2.is_finite() {
            *stat
        } else {
            centred
        }
    }
}

/// One block's learned scale λ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseScale {
    lambda: f64,
    /// Samples seen (capped at the window).
    n: f64,
    /// The samples' variance about their own mean (`data_mean`), over the same window: for
    /// λ's standard error. About their mean, not about λ: λ lags the data by the prior's
    /// weight, and (sample − λ)² counted that lag as scatter (after a fall from 1 to 0.04
    /// the factor applied was 4 λ for a hundred reports and more; docs/evaluation.md, "λ's
    /// standard error").
    scatter: f64,
    /// The weight of the last sample in λ (1 / (n + prior)).
    weight: f64,
    /// The mean of the samples alone (no prior), over the same window.
    data_mean: f64,
    /// The data have contradicted the declaration ([`PRIOR_CONFLICT_SCALE`]): the prior
    /// weighs [`CONFLICT_PRIOR_WEIGHT`] from then on.
    conflict: bool,
}

impl Default for NoiseScale {
    fn default() -> Self {
        Self {
            lambda: 1.0,
            n: 0.0,
            scatter: 0.0,
            weight: 1.0,
            data_mean: 0.0,
            conflict: false,
        }
    }
}

/// Reports before the data may overrule the declaration ([`PRIOR_CONFLICT_SCALE`]).
pub const PRIOR_CONFLICT_REPORTS: f64 = 20.0;

/// A prior-data conflict (Evans & Moshonov 2006, "Checking for prior-data conflict",
/// Bayesian Analysis 1(4)): once [`PRIOR_CONFLICT_REPORTS`] samples average below this
/// scale, the declaration is not this aircraft's noise but a loose bound on it (NACp 8's
/// 93 m on an aircraft whose positions scatter by 4 m, as on LAX), and holding λ near
/// prior/(prior + n) of it for a hundred reports only makes the filter too cautious.
/// From then on the prior weighs [`CONFLICT_PRIOR_WEIGHT`] and λ is the data's mean with
/// that. For a declaration that is right (λ = 1) the mean of 20 samples of a 2-component
/// innovation (χ²₂/2: standard deviation 1) is below 0.2 with probability under 10⁻⁶.
pub const PRIOR_CONFLICT_SCALE: f64 = 0.2;

/// The declared R's weight, in reports, once the data conflict with it.
pub const CONFLICT_PRIOR_WEIGHT: f64 = 1.0;

impl NoiseScale {
    /// λ: the factor on the declared covariance.
    pub fn lambda(&self) -> f64 {
        self.lambda
    }

    /// The factor applied: λ shrunk towards 1 by twice its standard error (a soft
    /// threshold), so that a declaration the data do not contradict is used as declared.
    /// Learning a noise that is exactly as declared would otherwise only add λ's scatter
    /// (0.4 % of straight-leg RMSE on paper 002, where every report declares its true
    /// noise).
    pub fn effective(&self) -> f64 {
        let margin = 2.0 * self.lambda_std_err();
        let d = self.lambda - 1.0;
        1.0 + d.signum() * (d.abs() - margin).max(0.0)
    }

    /// λ's standard error: the samples' variance through the exponential window, whose
    /// estimate has the variance of a mean of 2/w − 1 samples (w the newest sample's weight).
    pub fn lambda_std_err(&self) -> f64 {
        (self.scatter * self.weight / (2.0 - self.weight).max(1.0)).sqrt()
    }

    /// Learns from one update of the block, made with R = λ R₀ (`stat.tr_r`), its accuracy
    /// declared ([`NoiseParams::prior_weight`]).
    pub fn learn(&mut self, stat: &BlockStat, params: &NoiseParams) {
        self.learn_with_prior(
            stat,
            params,
            params.prior_weight,
            params.prior_conflict,
            params.window,
        );
    }

    /// [`NoiseScale::learn`] with the declared R₀ worth `prior_weight` reports, the data
    /// allowed to overrule it (`may_conflict`, [`PRIOR_CONFLICT_SCALE`]) or not, over an
    /// exponential window of `window` reports.
    pub fn learn_with_prior(
        &mut self,
        stat: &BlockStat,
        params: &NoiseParams,
        prior_weight: f64,
        may_conflict: bool,
        window: f64,
    ) {
        if !params.enabled || !stat.measured() || self.lambda <= 0.0 {
            return;
        }
        let tr_r0 = stat.tr_r / self.lambda;
        let tr_hph = (stat.tr_s - stat.tr_r).max(0.0);
        if !stat.informative() {
            return;
        }
        let lo = params.min_scale.min(params.max_scale);
        // Winsorised at `outlier_ratio` times its own predicted size (module doc): one
        // report from a different error process (a CPR jump, a GNSS glitch) counts as an
        // unlucky draw of the learned one, not as 16 draws.
        let e2 = stat.e2.min(params.outlier_ratio * stat.tr_s);
        let sample = ((e2 - tr_hph) / tr_r0).clamp(lo, params.max_scale);
        if !sample.is_finite() || tr_r0 <= 0.0 {
            return;
        }
        let prior_weight = if self.conflict {
            prior_weight.min(CONFLICT_PRIOR_WEIGHT)
        } else {
            prior_weight
        };
        self.push(sample, params, prior_weight, window);
        if !self.conflict
            && may_conflict
            && prior_weight > CONFLICT_PRIOR_WEIGHT
            && self.n >= PRIOR_CONFLICT_REPORTS
            && self.data_mean < PRIOR_CONFLICT_SCALE
        {
            self.conflict = true;
            let p = CONFLICT_PRIOR_WEIGHT;
            self.lambda =
                ((p + self.n * self.data_mean) / (p + self.n)).clamp(lo, params.max_scale);
            self.weight = 1.0 / (self.n + p);
        }
    }

    /// Learns from one sample of λ itself (an estimate of the noise's variance over the
    /// declared), winsorised at `outlier_ratio` times the current λ: what
    /// [`NoiseLearner::learn_position_step`] feeds, over [`NoiseParams::white_window`].
    fn learn_ratio(&mut self, sample: f64, params: &NoiseParams, prior_weight: f64) {
        if !params.enabled || !sample.is_finite() || self.lambda <= 0.0 {
            return;
        }
        let lo = params.min_scale.min(params.max_scale);
        let sample = sample
            .min(params.outlier_ratio * self.lambda)
            .clamp(lo, params.max_scale);
        self.push(sample, params, prior_weight, params.white_window);
    }

    /// Adds a sample (already winsorised and bounded) to the mean of (`prior_weight` × 1,
    /// samples...), forgetting beyond `window` reports.
    fn push(&mut self, sample: f64, params: &NoiseParams, prior_weight: f64, window: f64) {
        let lo = params.min_scale.min(params.max_scale);
        self.n = (self.n + 1.0).min(window);
        let weight = 1.0 / (self.n + prior_weight.max(0.0));
        // Welford's update of a mean and variance, with the window's weight 1/n (West 1979,
        // "Updating mean and variance estimates", CACM 22(9)).
        let before = sample - self.data_mean;
        self.data_mean += before / self.n;
        self.scatter += (before * (sample - self.data_mean) - self.scatter) / self.n;
        let d = sample - self.lambda;
        self.weight = weight;
        self.lambda = (self.lambda + weight * d).clamp(lo, params.max_scale);
    }

    /// `o` with its horizontal covariance scaled by λ, horizontal meaning perpendicular to
    /// `up` (the local vertical at the aircraft, a unit vector in the track's frame):
    /// D R D with D = I + (√λ − 1)(I − u uᵀ), a congruence, so the result is a covariance
    /// whatever R is. For a report made as R = h (I − u uᵀ) + v u uᵀ it gives exactly
    /// λ h (I − u uᵀ) + v u uᵀ: the vertical variance, and an unmeasured vertical's
    /// [`UNMEASURED_VARIANCE`], untouched. (Scaling the frame's own x and y instead is wrong
    /// far from the frame's origin: there the huge variance of an unmeasured altitude,
    /// tilted, lies partly along them, and the known horizontal would leak into it.)
    pub fn apply(&self, o: &Observed, up: &Vector3<f64>) -> Observed {
        let lambda = self.effective();
        if lambda == 1.0 {
            return *o;
        }
        let horizontal = Matrix3::identity() - up * up.transpose();
        let d = Matrix3::identity() + horizontal * (lambda.sqrt() - 1.0);
        Observed {
            value: o.value,
            cov: d * o.cov * d,
            grid: o.grid,
        }
    }
}

/// The learned scales of an aircraft's position and velocity reports.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NoiseLearner {
    /// Position reports.
    pub position: NoiseScale,
    /// Velocity reports.
    pub velocity: NoiseScale,
    /// The last position report's declared horizontal variance per axis, m² (0 before one).
    declared_pos_var_m2: f64,
    /// The aircraft declares its position accuracy (NACp): only then is the declared
    /// variance a bound on the total error ([`NoiseLearner::position_bias_var`]).
    pub accuracy_declared: bool,
    /// The aircraft declares its velocity accuracy (NACv or NUCr above 0).
    pub velocity_declared: bool,
    /// The white part of the position noise over the declared, from successive position
    /// reports ([`NoiseLearner::learn_position_step`]): what the consider term reads.
    pub white_position: NoiseScale,
    /// The last position report used for it: (time s, value m).
    last_position: Option<(f64, Vector3<f64>)>,
    /// The running mean of the velocity innovation ([`NoiseParams::velocity_centre_weight`]).
    velocity_mean: InnovationMean,
}

/// Position reports further apart than this are not differenced, s.
const POSITION_STEP_MAX_S: f64 = 2.0;

impl NoiseLearner {
    /// Learns from one update's position and velocity blocks, the velocity's declared R₀ a
    /// weaker prior when it declares nothing ([`NoiseParams::undeclared_prior_weight`]).
    ///
    /// Only a declared accuracy can conflict with the data ([`PRIOR_CONFLICT_SCALE`]): the
    /// fall-back of an aircraft that declares no position accuracy is a guess, not a claim,
    /// and there a faster fall measured worse (AFR34ZG, NUCp's 38 m: the hybrid's windowed
    /// NIS in band 82.8 → 78.9 %, the IMM's 56.4 → 48.6 %).
    pub fn learn(&mut self, position: &BlockStat, velocity: &BlockStat, params: &NoiseParams) {
        self.position.learn_with_prior(
            position,
            params,
            params.prior_weight,
            params.prior_conflict && self.accuracy_declared,
            params.window,
        );
        let velocity_prior = if self.velocity_declared {
            params.prior_weight
        } else {
            params.undeclared_prior_weight
        };
        let velocity = &self
            .velocity_mean
            .centre(velocity, params.velocity_centre_weight);
        self.velocity.learn_with_prior(
            velocity,
            params,
            velocity_prior,
            params.prior_conflict && self.velocity_declared,
            params.velocity_window,
        );
    }

    /// Learns the white part of the position noise from the step between successive
    /// position reports less the motion the track's velocity `vel_mps` gives, over the
    /// horizontal (`up` the local vertical): per axis E(d²) = 2σ_w² plus what a slowly
    /// correlated error moves in the step (for a 60 s time constant, 1/60 of its variance
    /// over half a second). So unlike covariance matching, whose innovations carry whatever
    /// correlated error the filter does not follow, it sees the white noise alone, however
    /// long the filter's memory. A report without a position teaches nothing.
    pub fn learn_position_step(
        &mut self,
        m: &Measurement,
        vel_mps: &Vector3<f64>,
        up: &Vector3<f64>,
        params: &NoiseParams,
    ) {
        let Some(position) = &m.position else {
            return;
        };
        let (t_s, pos_m) = (m.t_s, &position.value);
        if let Some((t0, p0)) = self.last_position {
            let dt = t_s - t0;
            if dt > 0.0 && dt <= POSITION_STEP_MAX_S && self.declared_pos_var_m2 > 0.0 {
                let d = pos_m - p0 - vel_mps * dt;
                let d_h2 = d.norm_squared() - d.dot(up).powi(2);
                let sample = d_h2 / (4.0 * self.declared_pos_var_m2);
                self.white_position
                    .learn_ratio(sample, params, params.prior_weight);
            }
        }
        self.last_position = Some((t_s, *pos_m));
    }

    /// Forgets the last position (a new track: its frame may have moved).
    pub fn forget_position(&mut self) {
        self.last_position = None;
    }

    /// Notes the declared (unscaled) covariance of a position report.
    pub fn note_position(&mut self, declared: &Observed) {
        let v = 0.5 * (declared.cov[(0, 0)] + declared.cov[(1, 1)]);
        if v.is_finite() && v > 0.0 {
            self.declared_pos_var_m2 = v;
        }
    }

    /// The report a filter uses: `m` with each block's horizontal covariance scaled by what
    /// was learned ([`NoiseScale::apply`]; `up` the local vertical at the track), its declared
    /// position covariance noted first for [`NoiseLearner::position_bias_var`].
    pub fn prepare(&mut self, m: &Measurement, up: &Vector3<f64>) -> Measurement {
        if let Some(o) = &m.position {
            self.note_position(o);
        }
        Measurement {
            t_s: m.t_s,
            position: m.position.as_ref().map(|o| self.position.apply(o, up)),
            velocity: m.velocity.as_ref().map(|o| self.velocity.apply(o, up)),
        }
    }

    /// `est` with the correlated position error the filter does not carry
    /// ([`NoiseLearner::position_bias_var`]) added to its horizontal position covariance.
    pub fn with_position_bias(&self, mut est: Estimate) -> Estimate {
        let (var_e, var_n) =
            self.with_position_bias_var(est.pos_cov_m2[(0, 0)], est.pos_cov_m2[(1, 1)]);
        est.pos_cov_m2[(0, 0)] = var_e;
        est.pos_cov_m2[(1, 1)] = var_n;
        est
    }

    /// The east and north position variances `var_e`, `var_n` with that error added (what
    /// [`NoiseLearner::with_position_bias`] does to an estimate, for a prediction that
    /// carries only its horizontal σ).
    pub fn with_position_bias_var(&self, var_e: f64, var_n: f64) -> (f64, f64) {
        let b = self.position_bias_var();
        if b > 0.0 {
            (var_e + b, var_n + b)
        } else {
            (var_e, var_n)
        }
    }

    /// The correlated position error's variance per horizontal axis, m² (module doc): the
    /// declared variance the white noise leaves unexplained; 0 when nothing is declared.
    pub fn position_bias_var(&self) -> f64 {
        if !self.accuracy_declared {
            return 0.0;
        }
        // Only what λ misses by more than twice its standard error: a white noise as
        // declared gives λ scattering about 1, and that scatter is not a bias.
        self.declared_pos_var_m2 * (1.0 - self.white_position.effective()).max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic standard normal samples from `seed` (Box-Muller on a xorshift).
    fn normals(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        move || {
            let (u1, u2) = (uniform().max(1e-300), uniform());
            (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
        }
    }

    /// A scalar random walk of position measured with noise σ_true while the filter is told
    /// σ₀: the learned λ must approach (σ_true/σ₀)², within the bounds.
    fn learned_lambda(sigma_true: f64, sigma0: f64, steps: usize) -> f64 {
        learned_lambda_with_outliers(sigma_true, sigma0, steps, 0, &NoiseParams::default())
    }

    /// [`learned_lambda`] where every `outlier_every`-th report (0: none) is off by
    /// 30 σ_true on each axis: another error process, as a CPR decode off by a zone.
    fn learned_lambda_with_outliers(
        sigma_true: f64,
        sigma0: f64,
        steps: usize,
        outlier_every: usize,
        params: &NoiseParams,
    ) -> f64 {
        learned_scale(sigma_true, sigma0, steps, outlier_every, params).lambda()
    }

    /// The learner of [`learned_lambda_with_outliers`] itself.
    fn learned_scale(
        sigma_true: f64,
        sigma0: f64,
        steps: usize,
        outlier_every: usize,
        params: &NoiseParams,
    ) -> NoiseScale {
        let mut normal = normals(0x9E37_79B9_7F4A_7C15_u64);
        let mut scale = NoiseScale::default();
        // A 1-D Kalman filter on a constant, three identical axes.
        let (mut x, mut p) = (0.0_f64, 1.0e6_f64);
        let q = 0.01;
        for step in 1..=steps {
            p += q;
            let outlier = if outlier_every > 0 && step % outlier_every == 0 {
                30.0 * sigma_true
            } else {
                0.0
            };
            let r = sigma0 * sigma0 * scale.lambda();
            let mut e2 = 0.0;
            let z = [
                sigma_true * normal() + outlier,
                sigma_true * normal() + outlier,
                sigma_true * normal() + outlier,
            ];
            let s = p + r;
            for zi in z {
                e2 += (zi - x) * (zi - x);
            }
            let stat = BlockStat {
                e2,
                tr_s: 3.0 * s,
                tr_r: 3.0 * r,
                e_h: [0.0; 2],
            };
            // The update (three independent looks at one scalar, for brevity).
            let mean_z = (z[0] + z[1] + z[2]) / 3.0;
            let k = p / (p + r / 3.0);
            x += k * (mean_z - x);
            p *= 1.0 - k;
            scale.learn(&stat, params);
        }
        scale
    }

    /// λ's standard error is the samples' own. A noise a fifth of the declared σ (λ =
    /// 0.04, as LAX's NACv-declaring airliners) is learned after a fall from the prior's 1;
    /// the factor applied stays within 25 % of λ. While the standard error was taken about
    /// the lagging λ, the fall itself counted as scatter for a hundred reports and more,
    /// and the factor applied sat at about 4 λ (LAX: λ 0.036, applied 0.142).
    #[test]
    fn the_applied_factor_follows_a_learned_fall() {
        // At the default window (100) and at 30 (docs/evaluation.md, "A shorter memory"):
        // the shorter window's standard error is √(100/30) times larger, and so is the
        // shrinkage.
        for (window, within) in [(30.0, 1.5), (100.0, 1.25)] {
            applied_factor_follows_a_learned_fall(window, within);
        }
    }

    fn applied_factor_follows_a_learned_fall(window: f64, within: f64) {
        let params = NoiseParams {
            window,
            ..NoiseParams::default()
        };
        for steps in [200, 400, 2000] {
            let s = learned_scale(0.2, 1.0, steps, 0, &params);
            // Below 0.04 by what the helper's filter overstates its own variance (its q on
            // a constant).
            assert!(
                s.lambda() > 0.02 && s.lambda() < 0.045,
                "{steps}: {}",
                s.lambda()
            );
            assert!(
                s.effective() < within * s.lambda(),
                "{steps}: λ {} applied {}",
                s.lambda(),
                s.effective()
            );
            // Samples of a 3-component innovation: λ (1 + P/R) χ²₃/3, standard deviation
            // about λ √(2/3); through the window, λ's standard error a fifth to a tenth of λ.
            let want = s.lambda() * (2.0_f64 / 3.0).sqrt() / (2.0 / s.weight - 1.0).sqrt();
            let got = s.lambda_std_err();
            assert!(
                got > 0.5 * want && got < 2.0 * want,
                "{steps}: {got} vs {want}"
            );
        }
    }

    /// A velocity that declares nothing is weighed against NACv 1's bound (σ₀ 4 m/s); one
    /// that reports to 0.6 m/s has λ = 0.0225. With the declared prior's weight the bound
    /// still holds λ at 2.4 times that after 100 s of reports; as the weak prior it is for,
    /// it is learned (within 10 %).
    #[test]
    fn a_fall_back_bound_is_a_weak_prior() {
        let truth = 0.6_f64.powi(2) / 4.0_f64.powi(2);
        let declared = NoiseParams::default();
        let weak = NoiseParams {
            prior_weight: declared.undeclared_prior_weight,
            ..declared
        };
        // 100 s of 2 Hz reports (the declared prior as it was before the data could
        // overrule it: an undeclared velocity never can).
        let strong = learned_lambda_with_outliers(
            0.6,
            4.0,
            200,
            0,
            // The window of 100 this was measured with, whatever the default: at 30 the
            // prior fades within 40 reports whatever its weight.
            &NoiseParams {
                prior_conflict: false,
                window: 100.0,
                ..declared
            },
        );
        let learned = learned_lambda_with_outliers(0.6, 4.0, 200, 0, &weak);
        eprintln!("λ {strong} with the declared prior, {learned} with the weak one, truth {truth}");
        assert!(strong > 2.0 * truth, "{strong}");
        assert!((learned / truth - 1.0).abs() < 0.35, "{learned}");
        // And through the learner: the velocity block takes the prior its declaration gives.
        // The same innovation every time (its mean would centre it away: not centred).
        let stat = BlockStat {
            e2: 0.02,
            tr_s: 0.03,
            tr_r: 0.02,
            e_h: [0.1, 0.1],
        };
        let uncentred = NoiseParams {
            velocity_centre_weight: 0.0,
            ..declared
        };
        let (mut on, mut off) = (NoiseLearner::default(), NoiseLearner::default());
        on.velocity_declared = true;
        for _ in 0..20 {
            on.learn(&BlockStat::default(), &stat, &uncentred);
            off.learn(&BlockStat::default(), &stat, &uncentred);
        }
        assert!(off.velocity.lambda() < 0.5 * on.velocity.lambda());
        assert_eq!(
            on.position,
            NoiseScale::default(),
            "an unmeasured block learns nothing"
        );
    }

    #[test]
    fn one_report_in_fifty_from_another_process_does_not_set_the_noise() {
        // True λ = (2/5)² = 0.16; 2 % of the reports are 30 σ off. Each outlier also
        // pulls the filter's state, which the next reports' innovations show: λ ends
        // 1.8 times the truth here, against 4 times without the winsorising.
        let robust = learned_lambda_with_outliers(2.0, 5.0, 2000, 50, &NoiseParams::default());
        assert!((0.14..0.35).contains(&robust), "λ {robust}, want 0.16-0.3");
        // The plain mean of squares (no winsorising but the clamp at max_scale): each
        // outlier adds about 16/110, so λ ends four times too large.
        let plain = NoiseParams {
            outlier_ratio: f64::INFINITY,
            ..NoiseParams::default()
        };
        let naive = learned_lambda_with_outliers(2.0, 5.0, 2000, 50, &plain);
        assert!(
            naive > 2.0 * robust,
            "plain λ {naive} against robust {robust}"
        );
        // A noise that really is four times the declared variance is still learned.
        let up = learned_lambda_with_outliers(10.0, 5.0, 2000, 50, &NoiseParams::default());
        assert!((3.0..7.0).contains(&up), "λ {up}, want about 4-6");
    }

    #[test]
    fn learns_a_noise_larger_and_smaller_than_declared() {
        let up = learned_lambda(10.0, 5.0, 2000);
        assert!((3.0..5.0).contains(&up), "λ {up}, want about 4");
        let down = learned_lambda(2.0, 5.0, 2000);
        assert!((0.10..0.25).contains(&down), "λ {down}, want about 0.16");
        let same = learned_lambda(5.0, 5.0, 2000);
        assert!((0.75..1.3).contains(&same), "λ {same}, want about 1");
    }

    #[test]
    fn bounded_by_the_declaration() {
        // Every sample is winsorised at the bound, so λ ends just inside it.
        let p = NoiseParams::default();
        let far = learned_lambda(100.0, 5.0, 2000);
        assert!((0.95 * p.max_scale..=p.max_scale).contains(&far), "{far}");
        let tiny = learned_lambda(0.01, 5.0, 2000);
        assert!((p.min_scale..=1.05 * p.min_scale).contains(&tiny), "{tiny}");
    }

    #[test]
    fn the_prior_holds_until_data_outweigh_it() {
        let params = NoiseParams::default();
        let mut scale = NoiseScale::default();
        // One report with a huge innovation counts as εᵀε = ratio·Tr(S): a sample of
        // (ratio·2 − 1) / 1 = 9 here, whose weight is 1 / (1 + prior).
        let huge = BlockStat {
            e2: 1.0e9,
            tr_s: 2.0,
            tr_r: 1.0,
            e_h: [0.0; 2],
        };
        scale.learn(&huge, &params);
        let sample = params.outlier_ratio * 2.0 - 1.0;
        let most = 1.0 + (sample - 1.0) / (1.0 + params.prior_weight);
        assert!((scale.lambda() - most).abs() < 1e-12, "{}", scale.lambda());
        // Without the winsorising, the clamp at max_scale is the limit.
        let mut plain_scale = NoiseScale::default();
        let plain = NoiseParams {
            outlier_ratio: f64::INFINITY,
            ..params
        };
        plain_scale.learn(&huge, &plain);
        let most = 1.0 + (params.max_scale - 1.0) / (1.0 + params.prior_weight);
        assert!(
            (plain_scale.lambda() - most).abs() < 1e-12,
            "{}",
            plain_scale.lambda()
        );
        // An unmeasured block teaches nothing.
        let before = scale;
        scale.learn(&BlockStat::default(), &params);
        assert_eq!(scale, before);
    }

    #[test]
    fn the_unexplained_declared_variance_is_the_bias() {
        let mut learner = NoiseLearner::default();
        let declared = Observed {
            value: Vector3::zeros(),
            cov: Matrix3::from_diagonal(&Vector3::new(16.0, 16.0, 9.0)),
            grid: None,
        };
        learner.note_position(&declared);
        learner.accuracy_declared = true;
        assert_eq!(learner.position_bias_var(), 0.0, "λ = 1: all white");
        learner.white_position.lambda = 0.25;
        assert_eq!(learner.position_bias_var(), 12.0);
        learner.accuracy_declared = false;
        assert_eq!(learner.position_bias_var(), 0.0, "nothing declared");
        learner.accuracy_declared = true;
        learner.white_position.lambda = 4.0;
        assert_eq!(learner.position_bias_var(), 0.0, "noisier than declared");
        // The innovations' λ is not what the consider term reads.
        learner.white_position.lambda = 1.0;
        learner.position.lambda = 0.25;
        assert_eq!(learner.position_bias_var(), 0.0);
    }

    /// Successive position reports at 2 Hz, white noise σ_w = 2 m per axis on a Gauss-Markov
    /// bias of 4 m with a 60 s time constant (the `airliner-nacp10` receiver), declared
    /// σ₀ = 5 m: the steps learn the white variance, 4 m², within 15 %, and the consider
    /// term is the declared variance less it (not less the bias, which a long filter memory
    /// would have shown its innovations as white noise).
    #[test]
    fn position_steps_learn_the_white_noise_under_a_wandering_bias() {
        use rand::rngs::StdRng;
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = StdRng::seed_from_u64(5);
        let white = Normal::new(0.0, 2.0).unwrap();
        let unit = Normal::new(0.0, 1.0).unwrap();
        let params = NoiseParams::default();
        let mut learner = NoiseLearner {
            accuracy_declared: true,
            ..NoiseLearner::default()
        };
        let declared = Observed {
            value: Vector3::zeros(),
            cov: Matrix3::from_diagonal(&Vector3::new(25.0, 25.0, 100.0)),
            grid: None,
        };
        let vel = Vector3::new(230.0, 0.0, 0.0);
        let at = |t_s: f64, value: Vector3<f64>| Measurement {
            t_s,
            position: Some(Observed {
                value,
                cov: declared.cov,
                grid: None,
            }),
            velocity: None,
        };
        let (dt, tau, sigma_b): (f64, f64, f64) = (0.5, 60.0, 4.0);
        let phi: f64 = (-dt / tau).exp();
        let mut bias = Vector3::new(
            sigma_b * unit.sample(&mut rng),
            sigma_b * unit.sample(&mut rng),
            0.0,
        );
        let mut learned = Vec::new();
        for k in 0..4000 {
            let t = k as f64 * dt;
            for axis in 0..2 {
                bias[axis] =
                    phi * bias[axis] + sigma_b * (1.0 - phi * phi).sqrt() * unit.sample(&mut rng);
            }
            let noise = Vector3::new(white.sample(&mut rng), white.sample(&mut rng), 0.0);
            let z = vel * t + bias + noise;
            learner.note_position(&declared);
            learner.learn_position_step(&at(t, z), &vel, &Vector3::z(), &params);
            if k > 400 {
                learned.push(learner.white_position.lambda() * 25.0);
            }
        }
        let mean = learned.iter().sum::<f64>() / learned.len() as f64;
        assert!(
            (mean - 4.0).abs() < 0.6,
            "white variance learned {mean} m², truth 4"
        );
        let bias_var = learner.position_bias_var();
        assert!(
            (17.0..23.0).contains(&bias_var),
            "consider {bias_var} m², want 25 − 4"
        );
        // A gap longer than POSITION_STEP_MAX_S is not differenced; a new track forgets.
        let before = learner.white_position;
        let z = Vector3::zeros();
        learner.learn_position_step(&at(1e6, z), &vel, &Vector3::z(), &params);
        assert_eq!(learner.white_position, before);
        learner.forget_position();
        learner.learn_position_step(&at(1e6 + 0.5, z), &vel, &Vector3::z(), &params);
        assert_eq!(learner.white_position, before);
        // Nor does a report without a position.
        let velocity_only = Measurement {
            position: None,
            ..at(1e6 + 1.0, z)
        };
        learner.learn_position_step(&velocity_only, &vel, &Vector3::z(), &params);
        assert_eq!(learner.white_position, before);
    }

    /// A declaration twenty times the noise in σ (NACp 8's bound on a few metres): with the
    /// prior-data conflict rule λ falls near the data within 50 reports; without it, the
    /// declaration worth 10 reports holds it at a tenth. A declaration that is right never
    /// trips the rule.
    #[test]
    fn a_contradicted_declaration_stops_holding_lambda_up() {
        let on = NoiseParams::default();
        let off = NoiseParams {
            prior_conflict: false,
            ..on
        };
        let fast = learned_lambda_with_outliers(1.0, 20.0, 50, 0, &on);
        let slow = learned_lambda_with_outliers(1.0, 20.0, 50, 0, &off);
        // The truth is 1/400; with the prior worth one report λ ≈ (1 + 50/400)/51.
        assert!(fast < 0.03, "{fast}");
        assert!(slow > 0.1, "{slow}");
        let later = learned_lambda_with_outliers(1.0, 20.0, 400, 0, &on);
        assert!(later < 0.006, "{later}");
        for steps in [25, 100, 2000] {
            let right = learned_lambda_with_outliers(10.0, 10.0, steps, 0, &on);
            let right_off = learned_lambda_with_outliers(10.0, 10.0, steps, 0, &off);
            assert_eq!(right, right_off, "{steps}");
        }
    }

    /// A two-axis velocity filter (a random walk of density `q` per report, per axis) on
    /// reports of noise σ 0.1 m/s declared as σ₀ 1 m/s (λ = 0.01), while the true velocity
    /// swings by ±`swing_mps` over 240 reports (two minutes at 2 Hz: at most 0.08 m/s² for
    /// a swing of 1.5 m/s), the learner's velocity block fed as the hybrid feeds it.
    /// Returns (the λ learned, the mean centred square over the mean raw one).
    fn learned_under_a_swing(swing_mps: f64, centre: f64) -> (f64, f64) {
        let params = NoiseParams {
            velocity_centre_weight: centre,
            ..NoiseParams::default()
        };
        let mut normal = normals(0x2545_F491_4F6C_DD1D_u64);
        let (sigma, sigma0, q) = (0.1, 1.0, 1.0e-4);
        let mut learner = NoiseLearner {
            velocity_declared: true,
            ..NoiseLearner::default()
        };
        let (mut x, mut p) = ([0.0_f64; 2], 1.0_f64);
        let (mut raw, mut centred) = (0.0, 0.0);
        for k in 0..4000 {
            let phase = 2.0 * std::f64::consts::PI * k as f64 / 240.0;
            let truth = [swing_mps * phase.sin(), swing_mps * phase.cos()];
            p += q;
            let r = sigma0 * sigma0 * learner.velocity.lambda();
            let e = [
                truth[0] + sigma * normal() - x[0],
                truth[1] + sigma * normal() - x[1],
            ];
            let stat = BlockStat {
                e2: e[0] * e[0] + e[1] * e[1],
                tr_s: 2.0 * (p + r),
                tr_r: 2.0 * r,
                e_h: e,
            };
            if k >= 1000 {
                raw += stat.e2;
                let mut probe = learner.velocity_mean;
                centred += probe.centre(&stat, centre).e2;
            }
            learner.learn(&BlockStat::default(), &stat, &params);
            let gain = p / (p + r);
            for (xi, ei) in x.iter_mut().zip(e) {
                *xi += gain * ei;
            }
            p *= 1.0 - gain;
        }
        (learner.velocity.lambda(), centred / raw)
    }

    /// Covariance matching reads a lag as noise; centred on its running mean it does not.
    /// Steady (no swing), centring changes nothing: its square is unbiased, and λ is
    /// learned within 25 % of the truth either way. Under a gentle swing (1.5 m/s over two
    /// minutes, 0.08 m/s² at most, under any acceleration test) the filter lags it, and the
    /// raw squares teach a λ several times the truth; the centred ones stay near it.
    #[test]
    fn a_lagged_speed_change_is_not_learned_as_noise() {
        let truth = 0.01;
        let (steady_raw, _) = learned_under_a_swing(0.0, 0.0);
        let (steady_centred, ratio) = learned_under_a_swing(0.0, 0.2);
        let (swing_raw, _) = learned_under_a_swing(1.5, 0.0);
        let (swing_centred, _) = learned_under_a_swing(1.5, 0.2);
        eprintln!(
            "λ steady {steady_raw:.4} / {steady_centred:.4} (centred square over raw {ratio:.3}), \
             swinging {swing_raw:.4} / {swing_centred:.4}, truth {truth}"
        );
        for l in [steady_raw, steady_centred, swing_centred] {
            assert!((l / truth - 1.0).abs() < 0.25, "λ {l}");
        }
        assert!(swing_raw > 3.0 * truth, "λ {swing_raw}");
        assert!((ratio - 1.0).abs() < 0.05, "centred over raw {ratio}");
    }

    /// The centred square is unbiased on white innovations (the mean's own variance taken
    /// off, type doc of [`InnovationMean`]), for any weight; a constant innovation is all
    /// mean, and centred away.
    #[test]
    fn the_centred_square_is_unbiased() {
        let mut normal = normals(0x9E37_79B9_7F4A_7C15_u64);
        for alpha in [0.05, 0.2, 0.5, 1.0] {
            let mut mean = InnovationMean::default();
            let (mut sum, n) = (0.0, 40_000);
            for _ in 0..n {
                let e = [normal(), normal()];
                let stat = BlockStat {
                    e2: e[0] * e[0] + e[1] * e[1],
                    tr_s: 2.0,
                    tr_r: 1.5,
                    e_h: e,
                };
                sum += mean.centre(&stat, alpha).e2;
            }
            let m = sum / n as f64 / 2.0;
            assert!((m - 1.0).abs() < 0.02, "α {alpha}: E|ε − m|² / 2 = {m}");
        }
        let mut mean = InnovationMean::default();
        let constant = BlockStat {
            e2: 0.5,
            tr_s: 2.0,
            tr_r: 1.5,
            e_h: [0.5, 0.5],
        };
        assert_eq!(
            mean.centre(&constant, 0.2).e2,
            0.5,
            "the first sample has no mean"
        );
        for _ in 0..3 {
            assert_eq!(mean.centre(&constant, 0.2).e2, 0.0);
        }
        // Not informative (the state less certain than the report): left as it is.
        let young = BlockStat {
            tr_s: 4.0,
            ..constant
        };
        assert_eq!(mean.centre(&young, 0.2), young);
        assert_eq!(mean.centre(&constant, 0.0), constant, "α 0: not centred");
    }

    #[test]
    fn apply_scales_the_local_horizontal_only() {
        let scale = NoiseScale {
            lambda: 4.0,
            ..NoiseScale::default()
        };
        let o = Observed {
            value: Vector3::new(1.0, 2.0, 3.0),
            cov: Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 3.0)),
            grid: None,
        };
        let want = Matrix3::from_diagonal(&Vector3::new(4.0, 4.0, 3.0));
        assert!((scale.apply(&o, &Vector3::z()).cov - want).norm() < 1e-12);
        // Far from the frame's origin the local vertical is tilted (6 degrees here) and an
        // unmeasured altitude's variance lies partly along the frame's x: the scaled report
        // is the one made in the local axes with λ h, exactly.
        let tilt = nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), 6f64.to_radians());
        let up = tilt * Vector3::z();
        let local = |h: f64| {
            tilt.matrix()
                * Matrix3::from_diagonal(&Vector3::new(h, h, UNMEASURED_VARIANCE))
                * tilt.matrix().transpose()
        };
        let unmeasured = Observed {
            value: o.value,
            cov: local(1444.0),
            grid: None,
        };
        let scaled = scale.apply(&unmeasured, &up).cov;
        let exact = local(4.0 * 1444.0);
        assert!(
            (scaled - exact).norm() < 1e-6 * exact.norm(),
            "{scaled} {exact}"
        );
        assert!((scaled - scaled.transpose()).norm() < 1e-9);
        assert!(scaled.cholesky().is_some());
    }
}
