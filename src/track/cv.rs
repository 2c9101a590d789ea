//! Constant-velocity Kalman tracker in the local ENU plane: the "CV" branch of paper 002's
//! threshold-gated tracker (ALGORITHMS.md §002), with paper 000's divergence criterion
//! computed on every position update (flag and count only; the suppressor is separate).
//!
//! State x = [e, n, u, ve, vn, vu] (m, m/s). Motion model: continuous white-noise
//! acceleration per axis (Bar-Shalom, Li, Kirubarajan, *Estimation with Applications to
//! Tracking and Navigation*, 2001, §6.2.2): ẋ = A x + G w, A = [[0, I], [0, 0]], G = [0; I],
//! w white with spectral density diag(q_h, q_h, q_v). Then, for each axis,
//! F(T) = [[1, T], [0, 1]] and Q(T) = q [[T³/3, T²/2], [T²/2, T]] exactly (eq. 6.2.2-12),
//! for any T: ADS-B reports are irregular, so T is always the actual time between reports.

use super::kalman::{self, Innovation, MotionModel};
use super::quantised::OnGrid;
use super::{Estimate, FlightMode, Measurement, Observed, PositionPrediction, TrackError, Tracker};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// 6-state vector [e, n, u, ve, vn, vu].
pub type State6 = SVector<f64, 6>;
/// 6x6 matrix over [`State6`].
pub type Matrix6 = SMatrix<f64, 6, 6>;

/// Name reported in [`Estimate::filter`].
pub const NAME: &str = "kalman-cv";

/// Tuning of [`CvKalman`]. The defaults are for airliners reported by ADS-B.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CvParams {
    /// Horizontal acceleration spectral density q_h, m²/s³ (per axis). The velocity then
    /// random-walks with variance q_h·T. Default (0.5 m/s²)²·s = 0.25: an airliner in
    /// "straight" flight changes speed by at most ~0.5 m/s² (thrust changes, gusts, gentle
    /// heading corrections), so over one ADS-B interval (0.5 s) the velocity may wander
    /// by σ ≈ 0.35 m/s and over 10 s by 1.6 m/s. Real turns (standard rate at 230 m/s is
    /// 12 m/s² lateral) are the manoeuvre models' business, not this filter's.
    pub q_h_m2ps3: f64,
    /// Vertical acceleration spectral density q_v, m²/s³. Default (0.3 m/s²)²·s = 0.09:
    /// airline operations keep vertical load-factor changes within about ±0.05 g
    /// (0.5 m/s²) for comfort, for a few seconds at a time (level-offs, pitch changes).
    pub q_v_m2ps3: f64,
    /// A report this long after the last one starts a new track, s. Default 60 s: after a
    /// minute without data a CV prediction of an airliner is off by kilometres if it turned,
    /// and a fresh start converges faster than a wrong state recovers.
    pub max_gap_s: f64,
    /// A velocity report at most this old initialises the velocity of a new track, s.
    /// Default 5 s: ten ADS-B velocity intervals, over which q_h·T adds only 1.1 m/s of σ.
    pub init_velocity_max_age_s: f64,
    /// 1-σ of the horizontal velocity of a track started without a velocity report, m/s
    /// (mean zero). Default 300 m/s: covers any subsonic aircraft.
    pub init_speed_sigma_mps: f64,
    /// 1-σ of the vertical rate of a track started without a velocity report, m/s.
    /// Default 30 m/s (6000 ft/min).
    pub init_vrate_sigma_mps: f64,
    /// Paper 000's storage factor r in εᵀε > r·Tr(S) (r ∈ [1, 5]; the paper uses 3).
    pub divergence_r: f64,
    /// Consecutive events before [`Estimate::diverging`] is set. Default 4, as the
    /// suppressor's confirmation in the other trackers (`divergence` module doc): a
    /// consistent filter meets the criterion on a few % of reports by chance, four in a row
    /// almost never, while a real divergence holds on every report.
    pub divergence_confirm: u32,
}

impl Default for CvParams {
    fn default() -> Self {
        Self {
            q_h_m2ps3: 0.25,
            q_v_m2ps3: 0.09,
            max_gap_s: 60.0,
            init_velocity_max_age_s: 5.0,
            init_speed_sigma_mps: 300.0,
            init_vrate_sigma_mps: 30.0,
            divergence_r: 3.0,
            divergence_confirm: 4,
        }
    }
}

/// The 3-D constant-velocity model (continuous white-noise acceleration).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CvModel {
    /// Horizontal acceleration spectral density, m²/s³.
    pub q_h_m2ps3: f64,
    /// Vertical acceleration spectral density, m²/s³.
    pub q_v_m2ps3: f64,
}

impl CvModel {
    fn axis_q(&self, axis: usize) -> f64 {
        if axis < 2 {
            self.q_h_m2ps3
        } else {
            self.q_v_m2ps3
        }
    }

    /// The prediction of (`x`, `p`) over `dt_s`, returned: what
    /// [`MotionModel::predict`] does in place, for a caller whose prior must stay as it is
    /// (the filter's update keeps its track until the posterior is accepted) without
    /// copying it first.
    ///
    /// The same step as the generic `x ← F x, P ← F P Fᵀ + Q`, in closed form: with
    /// P = [[A, B], [Bᵀ, C]] (position, cross, velocity blocks) and F = [[I, T I], [0, I]],
    /// F P Fᵀ = [[A + T(B + Bᵀ) + T² C, B + T C], [Bᵀ + T C, C]]. A third of the flops of two
    /// 6x6 products; tested equal to the generic form.
    ///
    /// With A and C symmetric (every P the CV filter holds is: its start is symmetrised,
    /// its update writes each entry and its mirror from one sum), the result is symmetric
    /// to the bit, entry (i, j) and (j, i) being the same sums in the same order; so no
    /// symmetrisation follows (½ (P + Pᵀ) of a symmetric P is P), and Q is added on its 12
    /// non-zero entries alone. The full Q and the symmetrisation were 4 % of a `kalman-cv`
    /// fleet replay's instructions; the result is the same bits (`fleet-same-tracks.sh`).
    pub fn predicted(&self, x: &State6, p: &Matrix6, dt_s: f64) -> (State6, Matrix6) {
        let v = kalman::rows::<3, _>(x, 3);
        let mut x_new = *x;
        let mut pos = x_new.fixed_rows_mut::<3>(0);
        pos += v * dt_s;
        let a = kalman::block::<3, 3, _, _>(p, 0, 0);
        let b = kalman::block::<3, 3, _, _>(p, 0, 3);
        let c = kalman::block::<3, 3, _, _>(p, 3, 3);
        let b_new = b + c * dt_s;
        let a_new = a + (b + b.transpose()) * dt_s + c * (dt_s * dt_s);
        let mut p_new = Matrix6::zeros();
        p_new.fixed_view_mut::<3, 3>(0, 0).copy_from(&a_new);
        p_new.fixed_view_mut::<3, 3>(0, 3).copy_from(&b_new);
        p_new
            .fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&b_new.transpose());
        p_new.fixed_view_mut::<3, 3>(3, 3).copy_from(&c);
        let (t1, t2, t3) = (dt_s, dt_s * dt_s, dt_s * dt_s * dt_s);
        for axis in 0..3 {
            let qa = self.axis_q(axis);
            p_new[(axis, axis)] += qa * t3 / 3.0;
            p_new[(axis, axis + 3)] += qa * t2 / 2.0;
            p_new[(axis + 3, axis)] += qa * t2 / 2.0;
            p_new[(axis + 3, axis + 3)] += qa * t1;
        }
        (x_new, p_new)
    }
}

impl MotionModel<6> for CvModel {
    /// F(T) = [[I, T·I], [0, I]].
    fn f(&self, dt_s: f64) -> Matrix6 {
        let mut f = Matrix6::identity();
        for axis in 0..3 {
            f[(axis, axis + 3)] = dt_s;
        }
        f
    }

    /// Q(T) per axis = q [[T³/3, T²/2], [T²/2, T]] (Bar-Shalom et al. eq. 6.2.2-12).
    fn q(&self, dt_s: f64) -> Matrix6 {
        let (t1, t2, t3) = (dt_s, dt_s * dt_s, dt_s * dt_s * dt_s);
        let mut q = Matrix6::zeros();
        for axis in 0..3 {
            let qa = self.axis_q(axis);
            q[(axis, axis)] = qa * t3 / 3.0;
            q[(axis, axis + 3)] = qa * t2 / 2.0;
            q[(axis + 3, axis)] = qa * t2 / 2.0;
            q[(axis + 3, axis + 3)] = qa * t1;
        }
        q
    }

    /// [`CvModel::predicted`] in place.
    fn predict(&self, x: &mut State6, p: &mut Matrix6, dt_s: f64) {
        (*x, *p) = self.predicted(x, p, dt_s);
    }

    /// [`MotionModel::predict`]'s state and east and north variances alone: the closed
    /// form's sums for those entries (the same bits, tested through
    /// `published_predictions_are_the_estimates_predictions`), without predicting the other
    /// 34 entries of P (three horizons a snapshot: 1.3 % of a `kalman-cv` fleet replay's
    /// instructions).
    fn predict_horizontal(&self, x: &State6, p: &Matrix6, dt_s: f64) -> (State6, f64, f64) {
        let (t2, t3) = (dt_s * dt_s, dt_s * dt_s * dt_s);
        let x_new = State6::from_fn(|i, _| if i < 3 { x[i] + x[i + 3] * dt_s } else { x[i] });
        // A + T (B + Bᵀ) + T² C + Q on the diagonal, for the two horizontal axes.
        let var = |a: usize| {
            p[(a, a)]
                + (p[(a, a + 3)] + p[(a, a + 3)]) * dt_s
                + p[(a + 3, a + 3)] * t2
                + self.axis_q(a) * t3 / 3.0
        };
        (x_new, var(0), var(1))
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Track {
    t_s: f64,
    x: State6,
    p: Matrix6,
}

/// Constant-velocity Kalman tracker for one aircraft ([`Tracker`] "kalman-cv").
///
/// - Initiation on the first report with a position; the velocity comes from the same report,
///   or from a velocity report at most `init_velocity_max_age_s` older, or is zero with
///   variance `init_*_sigma`².
/// - A report carrying position and velocity is one joint 6-D update (H = I); position or
///   velocity alone a 3-D one. All fixed-size: no allocation.
/// - A report older than the track is refused (`OutOfOrder`) and changes nothing; a report
///   more than `max_gap_s` after the track re-initialises it. A report whose update is
///   refused (`NotPositiveDefinite`) counts as missed: the track moves to its prediction at
///   the report's time.
/// - On each position update, paper 000's criterion εᵀε > r·Tr(S) over the position part of
///   the innovation is one divergence event; [`Estimate::diverging`] is set while the last
///   `divergence_confirm` position updates were all events.
#[derive(Clone, Debug, PartialEq)]
pub struct CvKalman {
    params: CvParams,
    model: CvModel,
    track: Option<Track>,
    /// Latest velocity report seen while there was no track: (time, velocity).
    pending_velocity: Option<(f64, Observed)>,
    diverging: bool,
    /// Consecutive divergence events.
    divergence_run: u32,
    divergence_events: u64,
    reinitialisations: u64,
    nis: super::nis::NisWindow,
}

impl Default for CvKalman {
    fn default() -> Self {
        Self::new(CvParams::default())
    }
}

impl CvKalman {
    /// A tracker with no track yet.
    pub fn new(params: CvParams) -> Self {
        Self {
            params,
            model: CvModel {
                q_h_m2ps3: params.q_h_m2ps3,
                q_v_m2ps3: params.q_v_m2ps3,
            },
            track: None,
            pending_velocity: None,
            diverging: false,
            divergence_run: 0,
            divergence_events: 0,
            reinitialisations: 0,
            nis: super::nis::NisWindow::default(),
        }
    }

    /// The tuning in use.
    pub fn params(&self) -> &CvParams {
        &self.params
    }

    /// The motion model in use.
    pub fn model(&self) -> &CvModel {
        &self.model
    }

    /// Times a long gap restarted the track.
    pub fn reinitialisations(&self) -> u64 {
        self.reinitialisations
    }

    /// Starts a track from a report with a position.
    fn initiate(&mut self, t_s: f64, position: &Observed, velocity: Option<&Observed>) {
        let mut x = State6::zeros();
        let mut p = Matrix6::zeros();
        x.fixed_rows_mut::<3>(0).copy_from(&position.value);
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(&position.cov);
        let recent = self
            .pending_velocity
            .filter(|(tv, _)| (0.0..=self.params.init_velocity_max_age_s).contains(&(t_s - tv)));
        match (velocity, recent) {
            (Some(v), _) => {
                x.fixed_rows_mut::<3>(3).copy_from(&v.value);
                p.fixed_view_mut::<3, 3>(3, 3).copy_from(&v.cov);
            }
            (None, Some((tv, v))) => {
                // The velocity random-walks by q·T per axis since it was reported.
                let age_s = t_s - tv;
                x.fixed_rows_mut::<3>(3).copy_from(&v.value);
                let mut cov = v.cov;
                for axis in 0..3 {
                    cov[(axis, axis)] += self.model.axis_q(axis) * age_s;
                }
                p.fixed_view_mut::<3, 3>(3, 3).copy_from(&cov);
            }
            (None, None) => {
                let (h, v) = (
                    self.params.init_speed_sigma_mps.powi(2),
                    self.params.init_vrate_sigma_mps.powi(2),
                );
                p.fixed_view_mut::<3, 3>(3, 3)
                    .copy_from(&Matrix3::from_diagonal(&Vector3::new(h, h, v)));
            }
        }
        self.track = Some(Track {
            t_s,
            x,
            p: kalman::symmetrise(&p),
        });
        self.pending_velocity = None;
        self.diverging = false;
        self.divergence_run = 0;
        self.nis.clear();
    }

    /// Paper 000's criterion over the position part of an innovation: εᵀε > r·Tr(S).
    fn position_diverges(&self, residual: &Vector3<f64>, s_pos: &Matrix3<f64>) -> bool {
        residual.norm_squared() > self.params.divergence_r * s_pos.trace()
    }

    /// The track's state and covariance predicted to `t_s` (at or after the track's time),
    /// what [`Tracker::predict`] reads.
    fn predicted(&self, t_s: f64) -> Option<(State6, Matrix6)> {
        let track = self.track.as_ref()?;
        let dt_s = super::time_ahead_s(track.t_s, t_s)?;
        Some(self.model.predicted(&track.x, &track.p, dt_s))
    }

    fn estimate_of(&self, t_s: f64, x: &State6, p: &Matrix6) -> Estimate {
        Estimate {
            t_s,
            pos_m: kalman::rows::<3, _>(x, 0),
            vel_mps: kalman::rows::<3, _>(x, 3),
            pos_cov_m2: kalman::block::<3, 3, _, _>(p, 0, 0),
            vel_cov_m2ps2: kalman::block::<3, 3, _, _>(p, 3, 3),
            mode: FlightMode::Cv,
            mode_probabilities: [1.0, 0.0, 0.0, 0.0, 0.0],
            filter: NAME,
            diverging: self.diverging,
            divergence_events: self.divergence_events,
            outlier_positions: 0,
            // The CV filter does not label manoeuvres: it always says straight, constant, level.
            turn: None,
            lateral: super::Lateral::Straight,
            speed: super::SpeedTrend::Constant,
            vertical: super::VerticalTrend::Level,
            nis: self.nis.stat(),
        }
    }
}

/// Updates `track` to the report's time `t_s` from its prediction `prior` there, with
/// z = x[sel] + v, v ~ N(0, r): the posterior is written straight into the track. A refused
/// update may have written part of a posterior, so the track is then set to the prediction:
/// the refused report counts as missed.
///
/// The prediction is passed whole and read in place (taking the returned pair apart,
/// `let (x, p) = ...`, moved P once more).
#[inline(always)]
fn update_track<const M: usize>(
    track: &mut Track,
    t_s: f64,
    prior: &(State6, Matrix6),
    z: &SVector<f64, M>,
    sel: &[usize; M],
    r: &SMatrix<f64, M, M>,
) -> Result<Innovation<M>, TrackError> {
    let (x, p) = prior;
    let inn = kalman::update_selected_to_outlined(x, p, z, sel, r, &mut track.x, &mut track.p);
    if inn.is_err() {
        track.x = *x;
        track.p = *p;
    }
    track.t_s = t_s;
    inn
}

fn observed_is_finite(o: &Observed) -> bool {
    o.value.iter().chain(o.cov.iter()).all(|v| v.is_finite())
}

impl Tracker for CvKalman {
    fn reset(&mut self) {
        *self = Self::new(self.params);
    }

    fn name(&self) -> &'static str {
        NAME
    }

    fn update(&mut self, m: &Measurement) -> Result<(), TrackError> {
        if !m.t_s.is_finite()
            || !m
                .position
                .iter()
                .chain(m.velocity.iter())
                .all(observed_is_finite)
        {
            return Err(TrackError::NonFinite("measurement"));
        }
        if let Some(track) = &self.track {
            if m.t_s < track.t_s {
                return Err(TrackError::OutOfOrder {
                    t_s: m.t_s,
                    track_t_s: track.t_s,
                });
            }
            if m.t_s - track.t_s > self.params.max_gap_s {
                self.track = None;
                self.reinitialisations = self.reinitialisations.saturating_add(1);
            }
        }
        // The prior is predicted out of the track, and [`update_track`] writes the posterior
        // straight into it: copying the state into a working copy and back, three copies of
        // P an update, was 3 % of a `kalman-cv` fleet replay's instructions. (A refused
        // report counts as missed: predicting on from its time is the same model step as
        // predicting from the track's older time.)
        let Some(track) = self.track.as_mut() else {
            match (&m.position, &m.velocity) {
                (Some(pos), vel) => self.initiate(m.t_s, pos, vel.as_ref()),
                (None, Some(vel)) => {
                    if self.pending_velocity.is_none_or(|(tv, _)| m.t_s >= tv) {
                        self.pending_velocity = Some((m.t_s, *vel));
                    }
                }
                (None, None) => {}
            }
            return Ok(());
        };
        let prior = self.model.predicted(&track.x, &track.p, m.t_s - track.t_s);
        // `Some((ε_pos, S_pos))` when the report had a position, for the divergence test.
        let position_innovation = match (&m.position, &m.velocity) {
            (Some(pos), Some(vel)) => {
                let mut z = State6::zeros();
                z.fixed_rows_mut::<3>(0).copy_from(&pos.value);
                z.fixed_rows_mut::<3>(3).copy_from(&vel.value);
                let mut r = Matrix6::zeros();
                r.fixed_view_mut::<3, 3>(0, 0).copy_from(&pos.cov);
                r.fixed_view_mut::<3, 3>(3, 3).copy_from(&vel.cov);
                let inn = update_track(track, m.t_s, &prior, &z, &kalman::blocks6(0, 3), &r)?;
                self.nis.push(
                    super::nis::horizontal(&inn, &r),
                    super::nis::horizontal_dof(Some(pos), Some(vel)),
                );
                Some((
                    kalman::rows::<3, _>(&inn.residual, 0),
                    kalman::block::<3, 3, _, _>(&inn.s, 0, 0),
                ))
            }
            (Some(pos), None) => {
                let inn = update_track(
                    track,
                    m.t_s,
                    &prior,
                    &pos.value,
                    &kalman::block3(0),
                    &pos.cov,
                )?;
                self.nis.push(
                    super::nis::horizontal(&inn, &pos.cov),
                    super::nis::horizontal_dof(Some(pos), None),
                );
                Some((inn.residual, inn.s))
            }
            (None, Some(vel)) => {
                let inn = update_track(
                    track,
                    m.t_s,
                    &prior,
                    &vel.value,
                    &kalman::block3(3),
                    &vel.cov,
                )?;
                let on_grid = vel
                    .grid
                    .and_then(|g| OnGrid::of(&inn.residual, &inn.s, &vel.cov, &vel.value, &g));
                self.nis.push(
                    on_grid.map_or_else(|| super::nis::horizontal(&inn, &vel.cov), |g| g.nis()),
                    super::nis::horizontal_dof(None, Some(vel)),
                );
                None
            }
            (None, None) => return Ok(()),
        };
        if let Some((residual, s_pos)) = position_innovation {
            if self.position_diverges(&residual, &s_pos) {
                self.divergence_events = self.divergence_events.saturating_add(1);
                self.divergence_run = self.divergence_run.saturating_add(1);
            } else {
                self.divergence_run = 0;
            }
            self.diverging = self.divergence_run >= self.params.divergence_confirm.max(1);
        }
        Ok(())
    }

    fn estimate(&self) -> Option<Estimate> {
        self.track
            .as_ref()
            .map(|t| self.estimate_of(t.t_s, &t.x, &t.p))
    }

    fn estimated_position(&self) -> Option<(f64, Vector3<f64>)> {
        self.track
            .as_ref()
            .map(|t| (t.t_s, kalman::rows::<3, _>(&t.x, 0)))
    }

    fn has_track(&self) -> bool {
        self.track.is_some()
    }

    fn predict(&self, t_s: f64) -> Option<Estimate> {
        let (x, p) = self.predicted(t_s)?;
        Some(self.estimate_of(t_s, &x, &p))
    }

    /// [`Tracker::predict`]'s prediction, position and σ alone (no estimate formed).
    fn predict_positions(
        &self,
        base_t_s: f64,
        horizons_s: &[f64],
        out: &mut Vec<PositionPrediction>,
    ) {
        let Some(track) = self.track.as_ref() else {
            return;
        };
        super::predict_horizontal_positions(
            &self.model,
            track.t_s,
            &track.x,
            &track.p,
            base_t_s,
            horizons_s,
            |var_e, var_n| (var_e, var_n),
            out,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::UNMEASURED_VARIANCE;
    use nalgebra::{Cholesky, SymmetricEigen};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, StandardNormal};

    fn gaussian3(rng: &mut StdRng, sigma: &Vector3<f64>) -> Vector3<f64> {
        Vector3::from_fn(|i, _| {
            let z: f64 = StandardNormal.sample(rng);
            z * sigma[i]
        })
    }

    fn observed(value: Vector3<f64>, sigma: &Vector3<f64>) -> Observed {
        Observed {
            value,
            cov: Matrix3::from_diagonal(&sigma.component_mul(sigma)),
            grid: None,
        }
    }

    /// A = [[0, I], [0, 0]] and G Qc Gᵀ = diag(0, 0, 0, q_h, q_h, q_v) of the continuous model.
    fn continuous(model: &CvModel) -> (Matrix6, Matrix6) {
        let mut a = Matrix6::zeros();
        let mut gqg = Matrix6::zeros();
        for axis in 0..3 {
            a[(axis, axis + 3)] = 1.0;
            gqg[(axis + 3, axis + 3)] = model.axis_q(axis);
        }
        (a, gqg)
    }

    #[test]
    fn f_and_q_match_the_matrix_exponential_and_numerical_integration() {
        let model = CvModel {
            q_h_m2ps3: 0.25,
            q_v_m2ps3: 0.09,
        };
        let (a, gqg) = continuous(&model);
        for dt in [0.05, 0.5, 1.0, 3.7, 12.5, 30.0] {
            // F = exp(A T), by nalgebra's Padé matrix exponential.
            let f_exp = (a * dt).exp();
            assert!((model.f(dt) - f_exp).norm() < 1e-12, "F at {dt}");
            // Q = ∫₀ᵀ exp(Aτ) G Qc Gᵀ exp(Aτ)ᵀ dτ by composite Simpson over 200 intervals.
            let n = 200;
            let h = dt / n as f64;
            let mut integral = Matrix6::zeros();
            for k in 0..=n {
                let tau = h * k as f64;
                let w = if k == 0 || k == n {
                    1.0
                } else if k % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                let e = (a * tau).exp();
                integral += e * gqg * e.transpose() * w;
            }
            integral *= h / 3.0;
            let q = model.q(dt);
            let rel = (q - integral).norm() / q.norm();
            assert!(rel < 1e-10, "Q at {dt}: relative error {rel}");
        }
    }

    #[test]
    fn closed_form_prediction_equals_the_generic_step() {
        let model = CvModel {
            q_h_m2ps3: 0.25,
            q_v_m2ps3: 0.09,
        };
        let mut rng = StdRng::seed_from_u64(3);
        for dt in [0.0, 0.05, 1.0, 17.0] {
            // A random symmetric positive definite P = L Lᵀ + I and a random state.
            let l = Matrix6::from_fn(|_, _| rng.gen_range(-10.0..10.0));
            let p0 = l * l.transpose() + Matrix6::identity();
            let x0 = State6::from_fn(|_, _| rng.gen_range(-1e4..1e4));
            let (mut x1, mut p1) = (x0, p0);
            model.predict(&mut x1, &mut p1, dt);
            let (mut x2, mut p2) = (x0, p0);
            kalman::predict(&mut x2, &mut p2, &model.f(dt), &model.q(dt));
            assert!((x1 - x2).norm() <= 1e-12 * x2.norm(), "x at {dt}");
            assert!((p1 - p2).norm() <= 1e-12 * p2.norm(), "P at {dt}");
            // Symmetric to the bit without a symmetrisation (its doc).
            assert_eq!(p1, p1.transpose(), "P at {dt} is not exactly symmetric");
        }
    }

    /// What the closed-form prediction relies on: the filter's P is symmetric to the bit
    /// after every step (start, prediction, each kind of update), so the prediction needs no
    /// symmetrisation.
    #[test]
    fn the_covariance_stays_exactly_symmetric() {
        let mut rng = StdRng::seed_from_u64(41);
        let mut kf = CvKalman::default();
        let (mut t_s, mut pos, vel) = (
            0.0,
            Vector3::new(1e4, -3e3, 9e3),
            Vector3::new(180.0, -60.0, 4.0),
        );
        for k in 0..600 {
            t_s += rng.gen_range(0.05..1.5);
            pos += vel * 0.5;
            let noisy = |v: Vector3<f64>, s: f64, rng: &mut StdRng| {
                v + Vector3::from_fn(|_, _| rng.gen_range(-s..s))
            };
            let position = Observed {
                value: noisy(pos, 20.0, &mut rng),
                // A full covariance (a report's is rotated into the track's frame).
                cov: {
                    let l = Matrix3::from_fn(|_, _| rng.gen_range(-20.0..20.0));
                    l * l.transpose() + Matrix3::identity()
                },
                grid: None,
            };
            let velocity = Observed {
                value: noisy(vel, 1.0, &mut rng),
                cov: Matrix3::from_diagonal(&Vector3::new(0.3, 0.4, 2.0)),
                grid: None,
            };
            let m = Measurement {
                t_s,
                position: (k % 3 != 1).then_some(position),
                velocity: (k % 3 != 0).then_some(velocity),
            };
            if let Some((_, predicted)) = kf.predicted(t_s) {
                assert_eq!(
                    predicted,
                    predicted.transpose(),
                    "P predicted to update {k} is not exactly symmetric"
                );
            }
            kf.update(&m).expect("a finite report in time order");
            let p = kf.track.as_ref().expect("a track").p;
            assert_eq!(
                p,
                p.transpose(),
                "P after update {k} is not exactly symmetric"
            );
        }
    }

    /// Straight-line truth with ADS-B-like noise, position and velocity reports alternating
    /// at irregular 0.4-0.6 s intervals (as airborne position and velocity messages do).
    #[test]
    fn filtered_position_beats_raw_measurements() {
        let mut rng = StdRng::seed_from_u64(2024);
        let pos_sigma = Vector3::new(30.0, 30.0, 10.0);
        let vel_sigma = Vector3::new(1.5, 1.5, 1.0);
        let p0 = Vector3::new(-20_000.0, 5_000.0, 10_000.0);
        let v = Vector3::new(200.0, 150.0, 5.0);
        let mut kf = CvKalman::default();
        let (mut sq_filter, mut sq_raw, mut n) = (0.0, 0.0, 0usize);
        let mut t = 0.0;
        let mut k = 0usize;
        while t < 600.0 {
            let truth = p0 + v * t;
            let m = if k % 2 == 0 {
                let z = truth + gaussian3(&mut rng, &pos_sigma);
                if t > 60.0 {
                    sq_raw += (z - truth).norm_squared();
                }
                Measurement {
                    t_s: t,
                    position: Some(observed(z, &pos_sigma)),
                    velocity: None,
                }
            } else {
                Measurement {
                    t_s: t,
                    position: None,
                    velocity: Some(observed(v + gaussian3(&mut rng, &vel_sigma), &vel_sigma)),
                }
            };
            kf.update(&m).unwrap();
            if t > 60.0 && k % 2 == 0 {
                let est = kf.estimate().unwrap();
                sq_filter += (est.pos_m - truth).norm_squared();
                n += 1;
            }
            t += rng.gen_range(0.4..0.6);
            k += 1;
        }
        let rmse_filter = (sq_filter / n as f64).sqrt();
        let rmse_raw = (sq_raw / n as f64).sqrt();
        let ratio = rmse_filter / rmse_raw;
        eprintln!("CV RMSE: filter {rmse_filter:.2} m, raw {rmse_raw:.2} m, ratio {ratio:.3}");
        // Raw 3-D RMSE is sqrt(30² + 30² + 10²) = 43.6 m in expectation.
        assert!((rmse_raw - 43.6).abs() < 3.0, "{rmse_raw}");
        assert!(ratio < 0.35, "ratio {ratio}");
    }

    /// Wilson–Hilferty: the p-quantile of χ²(k) ≈ k (1 − 2/(9k) + z_p √(2/(9k)))³.
    fn chi2_quantile(k: f64, z_p: f64) -> f64 {
        let c = 2.0 / (9.0 * k);
        k * (1.0 - c + z_p * c.sqrt()).powi(3)
    }

    /// NEES over 200 Monte Carlo runs of a truth drawn from the filter's own model: the
    /// run-averaged NEES at each step is χ²(6·200)/200 for a consistent filter.
    #[test]
    fn nees_is_inside_its_chi_square_band() {
        const RUNS: usize = 200;
        const STEPS: usize = 100;
        let params = CvParams::default();
        let model = CvModel {
            q_h_m2ps3: params.q_h_m2ps3,
            q_v_m2ps3: params.q_v_m2ps3,
        };
        let pos_sigma = Vector3::new(30.0, 30.0, 10.0);
        let vel_sigma = Vector3::new(1.5, 1.5, 1.0);
        let mut rng = StdRng::seed_from_u64(99);
        let mut nees_sum = [0.0; STEPS];
        for _ in 0..RUNS {
            let mut kf = CvKalman::new(params);
            let mut truth = State6::from_column_slice(&[0.0, 0.0, 9_000.0, 220.0, -80.0, 3.0]);
            let mut t = 0.0;
            for (step, sum) in nees_sum.iter_mut().enumerate() {
                if step > 0 {
                    let dt = rng.gen_range(0.2..3.0);
                    t += dt;
                    let l = Cholesky::new(model.q(dt)).unwrap().l();
                    let w = l * State6::from_fn(|_, _| StandardNormal.sample(&mut rng));
                    truth = model.f(dt) * truth + w;
                }
                let pos = truth.fixed_rows::<3>(0).into_owned();
                let vel = truth.fixed_rows::<3>(3).into_owned();
                let m = Measurement {
                    t_s: t,
                    position: Some(observed(pos + gaussian3(&mut rng, &pos_sigma), &pos_sigma)),
                    velocity: Some(observed(vel + gaussian3(&mut rng, &vel_sigma), &vel_sigma)),
                };
                kf.update(&m).unwrap();
                let track = kf.track.unwrap();
                let err = track.x - truth;
                let nees = err.dot(&Cholesky::new(track.p).unwrap().solve(&err));
                *sum += nees;
            }
        }
        let dof = 6.0 * RUNS as f64;
        let lo = chi2_quantile(dof, -1.959_964) / RUNS as f64;
        let hi = chi2_quantile(dof, 1.959_964) / RUNS as f64;
        let avg: Vec<f64> = nees_sum.iter().map(|s| s / RUNS as f64).collect();
        let inside = avg.iter().filter(|a| (lo..=hi).contains(*a)).count();
        let grand = avg.iter().sum::<f64>() / STEPS as f64;
        eprintln!("NEES: band [{lo:.3}, {hi:.3}], {inside}/{STEPS} steps inside, mean {grand:.3}");
        // 95 % band: expect ~95 of 100 steps inside; 88 is > 3 binomial σ below that.
        assert!(inside >= 88, "{inside} steps inside");
        assert!((grand - 6.0).abs() < 0.3, "mean NEES {grand}");
    }

    #[test]
    fn covariance_stays_symmetric_positive_definite() {
        let mut rng = StdRng::seed_from_u64(5);
        let mut kf = CvKalman::default();
        let pos_sigma = Vector3::new(50.0, 50.0, 15.0);
        let vel_sigma = Vector3::new(2.0, 2.0, 1.0);
        let mut t = 0.0;
        let mut min_eig = f64::INFINITY;
        for step in 0..10_000 {
            // Log-uniform dt in 0.01..20 s.
            t += 10f64.powf(rng.gen_range(-2.0..20f64.log10()));
            let truth = Vector3::new(150.0 * t, -40.0 * t, 8000.0 + 2.0 * t);
            let vel = Vector3::new(150.0, -40.0, 2.0);
            let kind = step % 4;
            let mut vel_obs = observed(vel + gaussian3(&mut rng, &vel_sigma), &vel_sigma);
            if kind == 3 {
                // No vertical rate in this report.
                vel_obs.value.z = 0.0;
                vel_obs.cov[(2, 2)] = UNMEASURED_VARIANCE;
            }
            let m = Measurement {
                t_s: t,
                position: (kind != 1)
                    .then(|| observed(truth + gaussian3(&mut rng, &pos_sigma), &pos_sigma)),
                velocity: (kind != 0).then_some(vel_obs),
            };
            kf.update(&m).unwrap();
            let p = kf.track.unwrap().p;
            assert_eq!(p, p.transpose(), "asymmetric at step {step}");
            assert!(
                Cholesky::new(p).is_some(),
                "not positive definite at step {step}"
            );
            if step % 50 == 0 {
                min_eig = min_eig.min(SymmetricEigen::new(p).eigenvalues.min());
            }
        }
        assert_eq!(kf.reinitialisations(), 0);
        assert!(min_eig > 0.0);
    }

    #[test]
    fn missing_vertical_rate_does_not_pull_the_climb_to_zero() {
        // Truth climbs at 10 m/s; velocity reports carry vu = 0 with UNMEASURED_VARIANCE.
        // The climb must still be estimated from the altitudes.
        let mut rng = StdRng::seed_from_u64(11);
        let pos_sigma = Vector3::new(30.0, 30.0, 7.5);
        let vel_sigma = Vector3::new(1.0, 1.0, 1.0);
        let mut kf = CvKalman::default();
        let mut t = 0.0;
        for k in 0..480 {
            let truth = Vector3::new(230.0 * t, 0.0, 1000.0 + 10.0 * t);
            let m = if k % 2 == 0 {
                Measurement {
                    t_s: t,
                    position: Some(observed(
                        truth + gaussian3(&mut rng, &pos_sigma),
                        &pos_sigma,
                    )),
                    velocity: None,
                }
            } else {
                let mut v = observed(
                    Vector3::new(230.0, 0.0, 10.0) + gaussian3(&mut rng, &vel_sigma),
                    &vel_sigma,
                );
                v.value.z = 0.0;
                v.cov[(2, 2)] = UNMEASURED_VARIANCE;
                Measurement {
                    t_s: t,
                    position: None,
                    velocity: Some(v),
                }
            };
            kf.update(&m).unwrap();
            t += 0.5;
        }
        let est = kf.estimate().unwrap();
        assert!((est.vel_mps.z - 10.0).abs() < 1.0, "vu {}", est.vel_mps.z);
        assert!((est.vel_mps.x - 230.0).abs() < 1.0, "ve {}", est.vel_mps.x);
    }

    fn pos_report(t_s: f64, value: Vector3<f64>, sigma_m: f64) -> Measurement {
        Measurement {
            t_s,
            position: Some(observed(value, &Vector3::repeat(sigma_m))),
            velocity: None,
        }
    }

    #[test]
    fn initiation_out_of_order_gap_and_identity() {
        let mut kf = CvKalman::default();
        assert_eq!(kf.name(), "kalman-cv");
        assert!(kf.estimate().is_none());
        // A velocity report before any position is remembered for initiation.
        let vel = observed(Vector3::new(100.0, 0.0, -5.0), &Vector3::new(1.0, 1.0, 1.0));
        kf.update(&Measurement {
            t_s: 0.0,
            position: None,
            velocity: Some(vel),
        })
        .unwrap();
        assert!(kf.estimate().is_none());
        kf.update(&pos_report(2.0, Vector3::new(1.0, 2.0, 3.0), 10.0))
            .unwrap();
        let est = kf.estimate().unwrap();
        assert_eq!(est.pos_m, Vector3::new(1.0, 2.0, 3.0));
        assert_eq!(est.vel_mps, Vector3::new(100.0, 0.0, -5.0));
        // Velocity variance grew by q·T over the 2 s: 1 + 0.25·2 horizontally, 1 + 0.09·2 up.
        assert!((est.vel_cov_m2ps2[(0, 0)] - 1.5).abs() < 1e-12);
        assert!((est.vel_cov_m2ps2[(2, 2)] - 1.18).abs() < 1e-12);
        assert_eq!(est.mode, FlightMode::Cv);
        assert_eq!(est.mode_probabilities, [1.0, 0.0, 0.0, 0.0, 0.0]);
        assert_eq!(est.filter, "kalman-cv");

        // Out of order: refused, nothing changes.
        let before = kf.clone();
        let err = kf.update(&pos_report(1.0, Vector3::zeros(), 10.0));
        assert_eq!(
            err,
            Err(TrackError::OutOfOrder {
                t_s: 1.0,
                track_t_s: 2.0
            })
        );
        assert_eq!(kf, before);
        // Non-finite: refused, nothing changes.
        let err = kf.update(&pos_report(3.0, Vector3::new(f64::NAN, 0.0, 0.0), 10.0));
        assert_eq!(err, Err(TrackError::NonFinite("measurement")));
        assert_eq!(kf, before);

        // A gap over 60 s restarts from the new position alone, velocity unknown.
        kf.update(&pos_report(70.0, Vector3::new(5e4, 0.0, 0.0), 10.0))
            .unwrap();
        let est = kf.estimate().unwrap();
        assert_eq!(kf.reinitialisations(), 1);
        assert_eq!(est.pos_m, Vector3::new(5e4, 0.0, 0.0));
        assert_eq!(est.vel_mps, Vector3::zeros());
        assert!((est.vel_cov_m2ps2[(0, 0)] - 300f64.powi(2)).abs() < 1e-9);
        assert!((est.vel_cov_m2ps2[(2, 2)] - 30f64.powi(2)).abs() < 1e-9);
    }

    /// The update writes its posterior into the track: a refused one must leave the track at
    /// its prediction to the report's time (not a partly written posterior), the refused
    /// report counted as missed, and every form of report (position, velocity, both) must.
    #[test]
    fn a_refused_update_leaves_the_track_predicted() {
        let start = |kf: &mut CvKalman| {
            kf.update(&pos_report(0.0, Vector3::new(0.0, 0.0, 1000.0), 10.0))
                .unwrap();
            kf.update(&Measurement {
                t_s: 1.0,
                position: None,
                velocity: Some(observed(
                    Vector3::new(80.0, 5.0, 0.0),
                    &Vector3::repeat(1.0),
                )),
            })
            .unwrap();
        };
        // A covariance of −0.9 times the prior's leaves S = 0.1 P positive definite, and
        // makes the posterior P − P S⁻¹ P = −9 P, which the check refuses.
        let refused = |kf: &CvKalman, t_s: f64, pos: bool, vel: bool| {
            let (x, p) = kf.predicted(t_s).unwrap();
            let negative = |offset: usize| Observed {
                value: kalman::rows::<3, _>(&x, offset) + Vector3::repeat(3.0),
                cov: kalman::block::<3, 3, _, _>(&p, offset, offset) * -0.9,
                grid: None,
            };
            Measurement {
                t_s,
                position: pos.then(|| negative(0)),
                velocity: vel.then(|| negative(3)),
            }
        };
        for (pos, vel) in [(true, false), (false, true), (true, true)] {
            let mut kf = CvKalman::default();
            start(&mut kf);
            let mut missed = kf.clone();
            let (x, p) = kf.predicted(2.5).unwrap();
            let err = kf.update(&refused(&kf, 2.5, pos, vel));
            assert_eq!(err, Err(TrackError::NotPositiveDefinite), "{pos} {vel}");
            let est = kf.estimate().unwrap();
            assert_eq!(est.t_s, 2.5);
            assert_eq!(est.pos_m, kalman::rows::<3, _>(&x, 0));
            assert_eq!(est.vel_mps, kalman::rows::<3, _>(&x, 3));
            assert_eq!(est.pos_cov_m2, kalman::block::<3, 3, _, _>(&p, 0, 0));
            assert_eq!(est.vel_cov_m2ps2, kalman::block::<3, 3, _, _>(&p, 3, 3));
            assert!(kalman::is_positive_definite(&p));
            // The next report updates as if the refused one had never come: the same model
            // step, split at the refused report's time (equal to rounding).
            let next = pos_report(3.0, Vector3::new(240.0, 20.0, 1001.0), 10.0);
            kf.update(&next).unwrap();
            missed.update(&next).unwrap();
            let (a, b) = (kf.estimate().unwrap(), missed.estimate().unwrap());
            assert!((a.pos_m - b.pos_m).norm() < 1e-9, "{pos} {vel}");
            assert!((a.vel_mps - b.vel_mps).norm() < 1e-9);
            assert!((a.pos_cov_m2 - b.pos_cov_m2).norm() < 1e-9 * b.pos_cov_m2.norm());
        }
    }

    #[test]
    fn prediction_follows_the_closed_form() {
        let mut kf = CvKalman::default();
        let sigma = Vector3::new(10.0, 20.0, 5.0);
        let vel_sigma = Vector3::new(1.0, 2.0, 0.5);
        kf.update(&Measurement {
            t_s: 100.0,
            position: Some(observed(Vector3::new(0.0, 0.0, 1000.0), &sigma)),
            velocity: Some(observed(Vector3::new(200.0, -100.0, 4.0), &vel_sigma)),
        })
        .unwrap();
        assert!(kf.predict(99.0).is_none());
        let dt: f64 = 7.0;
        let pred = kf.predict(100.0 + dt).unwrap();
        assert_eq!(pred.t_s, 107.0);
        assert!((pred.pos_m - Vector3::new(1400.0, -700.0, 1028.0)).norm() < 1e-9);
        // No cross-covariance at initiation: P_pos(T) = σp² + T² σv² + q T³/3 per axis,
        // P_vel(T) = σv² + q T.
        for (axis, q) in [(0, 0.25), (1, 0.25), (2, 0.09)] {
            let pp = sigma[axis].powi(2) + dt * dt * vel_sigma[axis].powi(2) + q * dt.powi(3) / 3.0;
            let pv = vel_sigma[axis].powi(2) + q * dt;
            assert!(
                (pred.pos_cov_m2[(axis, axis)] - pp).abs() < 1e-9,
                "axis {axis}"
            );
            assert!(
                (pred.vel_cov_m2ps2[(axis, axis)] - pv).abs() < 1e-9,
                "axis {axis}"
            );
        }
        // Predicting does not move the track.
        assert_eq!(kf.estimate().unwrap().t_s, 100.0);
    }

    #[test]
    fn divergence_criterion_flags_a_jump() {
        let mut kf = CvKalman::default();
        let sigma_m = 30.0;
        for k in 0..20 {
            let t = k as f64;
            kf.update(&pos_report(t, Vector3::new(100.0 * t, 0.0, 0.0), sigma_m))
                .unwrap();
        }
        let quiet = kf.estimate().unwrap();
        // A 2 km jump: εᵀε ≈ 4e6 m² against 3·Tr(S) of a few 1e4 m².
        kf.update(&pos_report(
            20.0,
            Vector3::new(2000.0 + 2000.0, 0.0, 0.0),
            sigma_m,
        ))
        .unwrap();
        let est = kf.estimate().unwrap();
        // One event, not yet a divergence: the flag waits for `divergence_confirm` in a row.
        assert!(!est.diverging);
        assert_eq!(est.divergence_events, quiet.divergence_events + 1);
        // Noise-free reports on the line never trip it; the jump trips it exactly once.
        assert!(!quiet.diverging);
        assert_eq!(quiet.divergence_events, 0);
        assert_eq!(est.divergence_events, 1);
        // The aircraft really is elsewhere: reports 2 km off, each an event, the fourth sets
        // the flag.
        let mut off = kf.clone();
        for k in 21..24 {
            let t = k as f64;
            off.update(&pos_report(
                t,
                Vector3::new(100.0 * t + 2000.0, 0.0, 0.0),
                sigma_m,
            ))
            .unwrap();
            let e = off.estimate().unwrap();
            assert_eq!(e.divergence_events, (k - 19) as u64, "at {t} s");
            assert_eq!(e.diverging, k == 23, "at {t} s");
        }
        // Back on the line the filter, pulled off by the jump (its velocity too), needs some
        // reports to settle (without paper 000's suppressor, which is not applied here):
        // by 40 s later the flag has cleared.
        for k in 21..60 {
            let t = k as f64;
            kf.update(&pos_report(t, Vector3::new(100.0 * t, 0.0, 0.0), sigma_m))
                .unwrap();
        }
        let est = kf.estimate().unwrap();
        assert!(!est.diverging);
        assert!(est.divergence_events > 1);
    }

    /// The published predictions ([`Tracker::predict_positions`]) are those of a whole
    /// estimate per horizon, and the trail's position ([`Tracker::estimated_position`]) the
    /// estimate's, bit for bit.
    #[test]
    fn published_predictions_are_the_estimates_predictions() {
        let mut rng = StdRng::seed_from_u64(5);
        let mut tracker = CvKalman::new(CvParams::default());
        let horizons_s = [0.0, 5.0, 10.0, 30.0, -3.0, f64::NAN];
        let sigma = Vector3::new(10.0, 10.0, 15.0);
        for k in 0..200 {
            let t_s = 0.5 * f64::from(k);
            let truth = Vector3::new(200.0 * t_s, 30.0 * t_s, 3000.0);
            let m = Measurement {
                t_s,
                position: Some(observed(truth + gaussian3(&mut rng, &sigma), &sigma)),
                velocity: (k % 2 == 1)
                    .then(|| observed(Vector3::new(200.0, 30.0, 0.0), &Vector3::repeat(0.5))),
            };
            tracker.update(&m).unwrap();
            assert_eq!(
                crate::track::assert_reads_match_the_estimate(&tracker, &horizons_s),
                4
            );
        }
    }
}
