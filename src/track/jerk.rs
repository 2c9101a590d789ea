//! Jerk-model trackers of paper 001 (ALGORITHMS.md §001, Dai, Fang, Dai, Zou, Wang 2016):
//! the plain Jerk model (zero-mean Markov jerk, Mehrotra & Mahapatra 1997), the "current
//! statistical" CS-Jerk model (non-zero-mean jerk, fixed α) and the paper's improved CS-Jerk
//! (activation factor f_k adapting α and σ_j).
//!
//! Per horizontal axis the state is [p, v, a, j]; the jerk obeys
//! j̇ = −α (j − j̄) + w, w white with density 2ασ_j². Its exact discretisation is the order-4
//! [`singer::chain`]: F(T) is §001's matrix with p1, q1, r1, s1, G(T) eq. 15's input vector
//! of j̄, and Q = 2ασ_j² \[q_ij\] with q_ij = ∫₀ᵀ g_i g_j ds (the paper only cites Qiao et al.
//! 2002; derived in [`singer`]'s module doc, series below αT = 1, tested against quadrature
//! of exp(Aτ) b bᵀ exp(Aτ)ᵀ). The vertical axis is a plain CV.
//!
//! Adaptation (improved CS-Jerk), after each update with a position:
//! - statistic: the normalised innovation squared d = εᵀ S⁻¹ ε of the horizontal position
//!   (2-D). The paper writes the test on tr[S(k)] but builds f_k from d; d is the statistic
//!   that is χ²(2) under "no manoeuvre", so the test here is d > ε = 9.21 (χ²(2) at 1 %),
//!   a named choice ([`JerkParams::activation_threshold`]).
//! - f_k = 1/d when d > ε, else 1 (eq. 9); α = f_k α₀ (eq. 13) for the next prediction.
//! - j̄ = mean of the last l jerk estimates (eq. 10), per axis.
//! - σ_j² = (4 − π)/π (f_k j_max − |j̄|)² (eq. 12). The paper prints the j̄ < 0 branch as
//!   (f_k j_−max + j̄)²; with j_−max read as the magnitude of the negative bound (the
//!   current-statistical convention of Zhou & Kumar, σ² = (4 − π)/π (a_max − |ā|)²) both
//!   branches are this one expression for symmetric bounds.
//!
//! Plain CS-Jerk: j̄ = ĵ(k|k), α = α₀, σ_j² = (4 − π)/π (j_max − |j̄|)².
//! Plain Jerk: j̄ = 0, α = α₀, σ_j² = (4 − π)/π j_max² (the CS variance at zero mean, so the
//! three differ only by the mean and the adaptation).

use super::alt::{self, scatter, Lifecycle, Step};
use super::kalman::{self, Innovation};
use super::nis::{self, NisWindow};
use super::singer;
use super::{Estimate, FlightMode, Measurement, Observed, TrackError, Tracker};
use nalgebra::{Cholesky, Matrix2, SMatrix, SVector, Vector2};

/// Name of the improved CS-Jerk tracker.
pub const NAME_CS_JERK: &str = "cs-jerk";
/// Name of the plain CS-Jerk tracker.
pub const NAME_CS_JERK_PLAIN: &str = "cs-jerk-plain";
/// Name of the plain Jerk tracker.
pub const NAME_JERK: &str = "jerk";

/// Longest jerk history for j̄ (the paper's l ranges over 3–10).
const MAX_HISTORY: usize = 10;

/// Which of paper 001's three models.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JerkVariant {
    /// Zero-mean Markov jerk, fixed α and σ_j.
    Jerk,
    /// Current-statistical jerk: mean ĵ(k|k), fixed α.
    CsJerkPlain,
    /// Paper 001's improved CS-Jerk: activation factor, windowed mean.
    CsJerkImproved,
}

/// Tuning of [`JerkTracker`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JerkParams {
    /// The model. Default: the improved CS-Jerk.
    pub variant: JerkVariant,
    /// α₀, 1/s. Default 1/20 (the paper's value).
    pub alpha0: f64,
    /// Maximum jerk per horizontal axis (east, north), m/s³. Default 2 m/s³: an airliner
    /// rolls into a 25–30° bank (≈ 5 m/s² lateral) over 3–5 s, about 1–2 m/s³. (The paper's
    /// missile-like scenario uses 70 m/s³.)
    pub j_max_mps3: [f64; 2],
    /// l, the jerk estimates averaged for j̄ (eq. 10), 1..=10. Default 5 (the paper: 3–10).
    pub history_len: usize,
    /// Activation threshold on d = εᵀS⁻¹ε. Default 9.21 (χ²(2) at 1 %, the paper's value).
    pub activation_threshold: f64,
    /// Vertical acceleration spectral density (CV vertically), m²/s³. Default 0.09.
    pub q_v_m2ps3: f64,
    /// A report this long after the track restarts it, s. Default 60 s.
    pub max_gap_s: f64,
    /// A velocity report at most this old initialises a new track's velocity, s. Default 5 s.
    pub init_velocity_max_age_s: f64,
    /// 1-σ horizontal speed of a track started without velocity, m/s. Default 300 m/s.
    pub init_speed_sigma_mps: f64,
    /// 1-σ vertical rate of a track started without velocity, m/s. Default 30 m/s.
    pub init_vrate_sigma_mps: f64,
    /// 1-σ of the initial horizontal acceleration, m/s². Default 5 m/s² (a 27° bank).
    pub init_accel_sigma_mps2: f64,
}

impl Default for JerkParams {
    fn default() -> Self {
        Self {
            variant: JerkVariant::CsJerkImproved,
            alpha0: 1.0 / 20.0,
            j_max_mps3: [2.0, 2.0],
            history_len: 5,
            activation_threshold: 9.21,
            q_v_m2ps3: 0.09,
            max_gap_s: 60.0,
            init_velocity_max_age_s: 5.0,
            init_speed_sigma_mps: 300.0,
            init_vrate_sigma_mps: 30.0,
            init_accel_sigma_mps2: 5.0,
        }
    }
}

/// State [e, ve, ae, je, n, vn, an, jn, u, vu].
pub type State10 = SVector<f64, 10>;
/// 10x10 matrix over [`State10`].
pub type Matrix10 = SMatrix<f64, 10, 10>;
const POS: [usize; 3] = [0, 4, 8];
const VEL: [usize; 3] = [1, 5, 9];
const JERK: [usize; 2] = [3, 7];
/// (4 − π)/π, the current-statistical variance factor.
const CS_FACTOR: f64 = (4.0 - std::f64::consts::PI) / std::f64::consts::PI;

#[derive(Clone, Copy, Debug, PartialEq)]
struct Track {
    t_s: f64,
    x: State10,
    p: Matrix10,
}

/// One of paper 001's jerk trackers.
#[derive(Clone, Debug, PartialEq)]
pub struct JerkTracker {
    params: JerkParams,
    life: Lifecycle,
    track: Option<Track>,
    /// Activation factor from the last position update (eq. 9).
    f_k: f64,
    /// Ring of the last jerk estimates per axis, and how many are filled.
    history: [[f64; MAX_HISTORY]; 2],
    history_next: usize,
    history_filled: usize,
    activations: u64,
    /// The windowed NIS of the track's reports ([`super::nis`]).
    nis: NisWindow,
}

impl Default for JerkTracker {
    fn default() -> Self {
        Self::new(JerkParams::default())
    }
}

impl JerkTracker {
    /// A tracker with no track yet.
    pub fn new(params: JerkParams) -> Self {
        Self {
            params,
            life: Lifecycle::new(params.max_gap_s, params.init_velocity_max_age_s),
            track: None,
            f_k: 1.0,
            history: [[0.0; MAX_HISTORY]; 2],
            history_next: 0,
            history_filled: 0,
            activations: 0,
            nis: NisWindow::default(),
        }
    }

    /// The tuning in use.
    pub fn params(&self) -> &JerkParams {
        &self.params
    }

    /// Updates where the activation test fired (f_k < 1).
    pub fn activations(&self) -> u64 {
        self.activations
    }

    /// Times a long gap restarted the track.
    pub fn reinitialisations(&self) -> u64 {
        self.life.reinitialisations
    }

    #[cfg(test)]
    fn covariance(&self) -> Option<Matrix10> {
        self.track.map(|t| t.p)
    }

    /// The jerk mean j̄ per axis for the next prediction.
    fn jerk_mean(&self, x: &State10) -> [f64; 2] {
        match self.params.variant {
            JerkVariant::Jerk => [0.0, 0.0],
            JerkVariant::CsJerkPlain => JERK.map(|i| x[i]),
            JerkVariant::CsJerkImproved => {
                let l = self.params.history_len.clamp(1, MAX_HISTORY);
                let n = self.history_filled.min(l);
                if n == 0 {
                    return [0.0, 0.0];
                }
                let mut mean = [0.0; 2];
                for (axis, m) in mean.iter_mut().enumerate() {
                    let ring = self.history.get(axis).copied().unwrap_or_default();
                    let sum: f64 = (1..=n)
                        .map(|back| {
                            let idx = (self.history_next + MAX_HISTORY - back) % MAX_HISTORY;
                            ring.get(idx).copied().unwrap_or(0.0)
                        })
                        .sum();
                    *m = sum / n as f64;
                }
                mean
            }
        }
    }

    /// (F, G·j̄, Q) of the whole state over `dt_s` with the current adaptation.
    fn matrices(&self, x: &State10, dt_s: f64) -> (Matrix10, State10, Matrix10) {
        let f_k = match self.params.variant {
            JerkVariant::CsJerkImproved => self.f_k,
            _ => 1.0,
        };
        let alpha = f_k * self.params.alpha0;
        let c = singer::chain::<4>(alpha, dt_s);
        let j_bar = self.jerk_mean(x);
        let mut f = Matrix10::zeros();
        let mut u = State10::zeros();
        let mut q = Matrix10::zeros();
        for (axis, base) in [0usize, 4].into_iter().enumerate() {
            let j_max = self.params.j_max_mps3.get(axis).copied().unwrap_or(0.0);
            let mean = j_bar.get(axis).copied().unwrap_or(0.0);
            let sigma2 = match self.params.variant {
                JerkVariant::Jerk => CS_FACTOR * j_max * j_max,
                _ => CS_FACTOR * (f_k * j_max - mean.abs()).powi(2),
            };
            f.fixed_view_mut::<4, 4>(base, base).copy_from(&c.f);
            u.fixed_rows_mut::<4>(base).copy_from(&(c.g * mean));
            q.fixed_view_mut::<4, 4>(base, base)
                .copy_from(&(c.q_unit * (2.0 * alpha * sigma2)));
        }
        f[(8, 8)] = 1.0;
        f[(8, 9)] = dt_s;
        f[(9, 9)] = 1.0;
        let qv = self.params.q_v_m2ps3;
        q[(8, 8)] = qv * dt_s.powi(3) / 3.0;
        q[(8, 9)] = qv * dt_s.powi(2) / 2.0;
        q[(9, 8)] = q[(8, 9)];
        q[(9, 9)] = qv * dt_s;
        (f, u, q)
    }

    fn initiate(&mut self, t_s: f64, position: &Observed, velocity: Option<(f64, Observed)>) {
        let mut x = State10::zeros();
        let mut p = Matrix10::zeros();
        scatter(&mut x, &mut p, POS, position);
        let a2 = self.params.init_accel_sigma_mps2.powi(2);
        match velocity {
            Some((age_s, v)) => {
                scatter(&mut x, &mut p, VEL, &v);
                p[(1, 1)] += a2 * age_s * age_s;
                p[(5, 5)] += a2 * age_s * age_s;
                p[(9, 9)] += self.params.q_v_m2ps3 * age_s;
            }
            None => {
                let h = self.params.init_speed_sigma_mps.powi(2);
                p[(1, 1)] = h;
                p[(5, 5)] = h;
                p[(9, 9)] = self.params.init_vrate_sigma_mps.powi(2);
            }
        }
        p[(2, 2)] = a2;
        p[(6, 6)] = a2;
        for (axis, &i) in JERK.iter().enumerate() {
            let j_max = self.params.j_max_mps3.get(axis).copied().unwrap_or(0.0);
            p[(i, i)] = (CS_FACTOR * j_max * j_max).max(1e-6);
        }
        self.track = Some(Track { t_s, x, p });
        self.f_k = 1.0;
        self.history_filled = 0;
        self.history_next = 0;
    }

    /// After an update: f_k from the horizontal position innovation (eq. 9), jerk history.
    fn adapt(&mut self, x: &State10, position_innovation: Option<(Vector2<f64>, Matrix2<f64>)>) {
        if self.params.variant != JerkVariant::CsJerkImproved {
            return;
        }
        if let Some((eps, s)) = position_innovation {
            let d = Cholesky::new(s).map(|c| eps.dot(&c.solve(&eps)));
            self.f_k = match d {
                Some(d) if d.is_finite() && d > self.params.activation_threshold => {
                    self.activations = self.activations.saturating_add(1);
                    1.0 / d
                }
                _ => 1.0,
            };
        }
        for (axis, &i) in JERK.iter().enumerate() {
            if let Some(slot) = self
                .history
                .get_mut(axis)
                .and_then(|ring| ring.get_mut(self.history_next))
            {
                *slot = x[i];
            }
        }
        self.history_next = (self.history_next + 1) % MAX_HISTORY;
        self.history_filled = (self.history_filled + 1).min(MAX_HISTORY);
    }

    fn estimate_of(&self, t_s: f64, x: &State10, p: &Matrix10) -> Estimate {
        Estimate {
            t_s,
            pos_m: alt::gather(x, POS),
            vel_mps: alt::gather(x, VEL),
            pos_cov_m2: alt::gather_cov(p, POS),
            vel_cov_m2ps2: alt::gather_cov(p, VEL),
            mode: FlightMode::Cv,
            mode_probabilities: [1.0, 0.0, 0.0, 0.0, 0.0],
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
}

fn horizontal<const M: usize>(inn: &Innovation<M>) -> (Vector2<f64>, Matrix2<f64>) {
    (
        inn.residual.fixed_rows::<2>(0).into_owned(),
        inn.s.fixed_view::<2, 2>(0, 0).into_owned(),
    )
}

impl Tracker for JerkTracker {
    fn reset(&mut self) {
        *self = Self::new(self.params);
    }

    fn name(&self) -> &'static str {
        match self.params.variant {
            JerkVariant::Jerk => NAME_JERK,
            JerkVariant::CsJerkPlain => NAME_CS_JERK_PLAIN,
            JerkVariant::CsJerkImproved => NAME_CS_JERK,
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
        let (f, u, q) = self.matrices(&track.x, dt_s);
        let (mut x, mut p) = (track.x, track.p);
        kalman::predict(&mut x, &mut p, &f, &q);
        x += u;
        let dof = nis::horizontal_dof(m.position.as_ref(), m.velocity.as_ref());
        let position_innovation = match (&m.position, &m.velocity) {
            (Some(pos), Some(vel)) => {
                let mut z = SVector::<f64, 6>::zeros();
                z.fixed_rows_mut::<3>(0).copy_from(&pos.value);
                z.fixed_rows_mut::<3>(3).copy_from(&vel.value);
                let mut h = SMatrix::<f64, 6, 10>::zeros();
                h.fixed_rows_mut::<3>(0).copy_from(&alt::pick::<10>(POS));
                h.fixed_rows_mut::<3>(3).copy_from(&alt::pick::<10>(VEL));
                let mut r = SMatrix::<f64, 6, 6>::zeros();
                r.fixed_view_mut::<3, 3>(0, 0).copy_from(&pos.cov);
                r.fixed_view_mut::<3, 3>(3, 3).copy_from(&vel.cov);
                let inn = kalman::update(&mut x, &mut p, &z, &h, &r)?;
                self.nis.push(nis::horizontal(&inn, &r), dof);
                Some(horizontal(&inn))
            }
            (Some(pos), None) => {
                let inn =
                    kalman::update(&mut x, &mut p, &pos.value, &alt::pick::<10>(POS), &pos.cov)?;
                self.nis.push(nis::horizontal(&inn, &pos.cov), dof);
                Some(horizontal(&inn))
            }
            (None, Some(vel)) => {
                let inn =
                    kalman::update(&mut x, &mut p, &vel.value, &alt::pick::<10>(VEL), &vel.cov)?;
                self.nis.push(nis::horizontal(&inn, &vel.cov), dof);
                None
            }
            (None, None) => None,
        };
        self.adapt(&x, position_innovation);
        self.track = Some(Track { t_s: m.t_s, x, p });
        Ok(())
    }

    fn estimate(&self) -> Option<Estimate> {
        self.track.map(|t| self.estimate_of(t.t_s, &t.x, &t.p))
    }

    fn predict(&self, t_s: f64) -> Option<Estimate> {
        let track = self.track?;
        let dt_s = t_s - track.t_s;
        if !dt_s.is_finite() || dt_s < 0.0 {
            return None;
        }
        let (f, u, q) = self.matrices(&track.x, dt_s);
        let (mut x, mut p) = (track.x, track.p);
        kalman::predict(&mut x, &mut p, &f, &q);
        x += u;
        Some(self.estimate_of(t_s, &x, &p))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::singer::tests::straight_leg;
    use crate::track::singer::tests::{gaussian3, observed, quadrature, random_dt_stress};
    use nalgebra::Vector3;
    use rand::rngs::StdRng;
    use rand::SeedableRng;

    fn rel_close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * a.abs().max(b.abs()).max(1e-300)
    }

    #[test]
    fn f_and_g_match_the_printed_forms_and_q_matches_quadrature() {
        for x in [1e-6, 1e-3, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0] {
            let t = 4.0;
            let a = x / t;
            let c = singer::chain::<4>(a, t);
            let e = (-a * t).exp();
            if x >= 0.5 {
                // §001's printed p1, q1, r1, s1 and eq. 15 (accurate where they do not cancel).
                let p1 = (2.0 - 2.0 * a * t + a * a * t * t - 2.0 * e) / (2.0 * a.powi(3));
                let q1 = (e - 1.0 + a * t) / (a * a);
                let r1 = (1.0 - e) / a;
                for (i, v) in [p1, q1, r1, e].into_iter().enumerate() {
                    assert!(rel_close(c.f[(i, 3)], v, 1e-10), "F[{i}][3] x={x}");
                }
                let g = [
                    (2.0 * t - a * t * t + a * a * t.powi(3) / 3.0 - (2.0 - 2.0 * e) / a)
                        / (2.0 * a * a),
                    (-t + a * t * t / 2.0 + (1.0 - e) / a) / a,
                    t - (1.0 - e) / a,
                    1.0 - e,
                ];
                for (i, v) in g.into_iter().enumerate() {
                    assert!(rel_close(c.g[i], v, 1e-9), "G[{i}] x={x}");
                }
            }
            let (q, g) = quadrature::<4>(a, t);
            for i in 0..4 {
                assert!(rel_close(c.g[i], g[i], 1e-9), "G[{i}] x={x}");
                for j in 0..4 {
                    assert!(rel_close(c.q_unit[(i, j)], q[(i, j)], 1e-9), "q x={x}");
                }
            }
        }
        // Limits: q11 → T⁷/252 as α → 0 (integrated white jerk).
        let c = singer::chain::<4>(1e-9, 2.0);
        assert!(rel_close(c.q_unit[(0, 0)], 128.0 / 252.0, 1e-6));
    }

    fn all_variants() -> [JerkVariant; 3] {
        [
            JerkVariant::Jerk,
            JerkVariant::CsJerkPlain,
            JerkVariant::CsJerkImproved,
        ]
    }

    #[test]
    fn covariance_stays_symmetric_positive_definite() {
        for variant in all_variants() {
            let mut kf = JerkTracker::new(JerkParams {
                variant,
                ..JerkParams::default()
            });
            random_dt_stress(&mut kf, |kf, step| {
                let p = kf.covariance().unwrap();
                assert_eq!(p, p.transpose(), "{variant:?} step {step}");
                assert!(Cholesky::new(p).is_some(), "{variant:?} step {step}");
            });
            assert_eq!(kf.reinitialisations(), 0);
        }
    }

    #[test]
    fn the_windowed_nis_is_published_and_follows_the_claim() {
        for variant in [
            JerkVariant::Jerk,
            JerkVariant::CsJerkPlain,
            JerkVariant::CsJerkImproved,
        ] {
            let per_dof = crate::track::singer::tests::windowed_nis_by_claim(|| {
                Box::new(JerkTracker::new(JerkParams {
                    variant,
                    ..JerkParams::default()
                }))
            });
            crate::track::singer::tests::assert_the_claim_shows(&format!("{variant:?}"), per_dof);
        }
    }

    #[test]
    fn beats_raw_measurements_on_a_straight_leg() {
        for variant in all_variants() {
            let mut kf = JerkTracker::new(JerkParams {
                variant,
                ..JerkParams::default()
            });
            let (filt, raw) = straight_leg(&mut kf);
            println!(
                "{}: straight leg RMSE {filt:.1} m (raw {raw:.1} m)",
                kf.name()
            );
            assert!(
                filt < 0.8 * raw,
                "{variant:?}: filter {filt} m vs raw {raw} m"
            );
        }
    }

    /// Paper 001's x profile (ALGORITHMS.md §001): (jerk m/s³, acceleration reset) per second.
    fn paper_001_truth() -> Vec<[f64; 4]> {
        // State [x, v, a, j] sampled each second, integrated exactly for piecewise jerk.
        let mut s = [10_000.0, -300.0, 0.0, 0.0];
        let mut out = vec![s];
        for k in 0..200 {
            let t = k as f64;
            let j = match t {
                t if (60.0..80.0).contains(&t) => 15.0,
                t if (80.0..90.0).contains(&t) => -60.0,
                t if (110.0..120.0).contains(&t) => 10.0,
                t if (140.0..150.0).contains(&t) => 60.0,
                _ => 0.0,
            };
            if (t - 160.0).abs() < 1e-9 {
                // "then constant velocity": the acceleration ends at 160 s.
                s[2] = 0.0;
            }
            let [x, v, a, _] = s;
            s = [x + v + a / 2.0 + j / 6.0, v + a + j / 2.0, a + j, j];
            out.push(s);
        }
        out
    }

    #[test]
    fn paper_001_profile_mean_errors() {
        let truth = paper_001_truth();
        // Checks of the profile itself: a = 300 m/s² at 80 s, −300 at 90 s, −200 at 120 s,
        // 400 at 150 s.
        for (k, a) in [(80, 300.0), (90, -300.0), (120, -200.0), (150, 400.0)] {
            assert!((truth[k][2] - a).abs() < 1e-9, "a({k})");
        }
        let sigma = Vector3::new(100.0, 100.0, 10.0);
        let runs = 100;
        let mut table = Vec::new();
        for variant in all_variants() {
            let params = JerkParams {
                variant,
                j_max_mps3: [70.0, 0.01],
                ..JerkParams::default()
            };
            let (mut mean_abs_x, mut mean_abs_v, mut rmse_x) = (0.0, 0.0, 0.0);
            let mut sq_per_step = vec![0.0; truth.len()];
            let mut rng = StdRng::seed_from_u64(1);
            for _ in 0..runs {
                let mut kf = JerkTracker::new(params);
                for (k, s) in truth.iter().enumerate() {
                    let t = k as f64;
                    let pos = Vector3::new(s[0], 200.0 * t, 0.0);
                    let m = Measurement {
                        t_s: t,
                        position: Some(observed(pos + gaussian3(&mut rng, &sigma), &sigma)),
                        velocity: (k == 0).then(|| {
                            let vs = Vector3::new(20.0, 20.0, 1.0);
                            observed(
                                Vector3::new(s[1], 200.0, 0.0) + gaussian3(&mut rng, &vs),
                                &vs,
                            )
                        }),
                    };
                    kf.update(&m).unwrap();
                    let est = kf.estimate().unwrap();
                    let ex = est.pos_m.x - s[0];
                    mean_abs_x += ex.abs();
                    mean_abs_v += (est.vel_mps.x - s[1]).abs();
                    if let Some(acc) = sq_per_step.get_mut(k) {
                        *acc += ex * ex;
                    }
                }
            }
            let n = (runs * truth.len()) as f64;
            mean_abs_x /= n;
            mean_abs_v /= n;
            for sq in &sq_per_step {
                rmse_x += (sq / runs as f64).sqrt();
            }
            rmse_x /= truth.len() as f64;
            println!(
                "paper 001 profile, {:>13}: mean |x error| {mean_abs_x:7.2} m, mean RMSE_x \
                 {rmse_x:7.2} m, mean |vx error| {mean_abs_v:7.2} m/s",
                JerkTracker::new(params).name()
            );
            table.push((mean_abs_x, mean_abs_v));
            assert!(mean_abs_x.is_finite() && mean_abs_x < 1000.0);
        }
    }
}
