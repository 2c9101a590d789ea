//! Paper 000 (Shu, You, Wang, Fei 2005; ALGORITHMS.md §000): the divergence criterion and
//! its suppressor, guarding every Kalman step of the hybrid tracker (its CV filter and each
//! model of its IMM).
//!
//! - Criterion (eq. 24): εᵀε > r·Tr(S), ε = z − H x̂(k+1|k), S = H P(k+1|k) Hᵀ + R, with the
//!   storage factor r ∈ [1, 5] (the paper uses 3).
//! - Suppressor (eq. 25–29): when the criterion holds, the prediction covariance is
//!   re-made as P(k+1|k) = Adapt·Φ P(k|k) Φᵀ + Q with Adapt solved from Tr(εεᵀ) = Tr(S):
//!   Adapt = (εᵀε − Tr(H Q Hᵀ) − Tr(R)) / Tr(H Φ P Φᵀ Hᵀ), kept only when > 1 (§4: "Adapt
//!   must exceed 1, a negative numerator is discarded"); the gain is then recomputed and the
//!   update redone with the inflated P. So a prediction ([`Prediction`]) keeps Φ P Φᵀ and Q
//!   apart until the update.
//!
//! Choices the paper leaves open (it measures 2-D radar positions only):
//! - A report may carry a position, a velocity or both. Metres and m/s are not summed: the
//!   criterion and Adapt are evaluated per measured 3-vector block (position, velocity), and
//!   the filter diverges when any block does; Adapt is the largest of the firing blocks' (the
//!   paper's practical rule §5.1 step 4 likewise takes the max over its x and y axes).
//! - A component carrying [`UNMEASURED_VARIANCE`] (e.g. no vertical rate) is left out of
//!   εᵀε and of every trace: its 10⁶ variance would otherwise mask any divergence.
//! - The innovation returned is the NOMINAL one (un-inflated S): its NIS and log-likelihood
//!   are what the model itself predicted, which is what IMM mode probabilities must weigh; a
//!   suppressed model is rescued in state, not in credibility.
//! - Adapt is capped ([`DivergenceParams::max_adapt`]) so a wild outlier cannot blow P up
//!   by an unbounded factor.
//! - Confirmation ([`DivergenceParams::confirm`]): every step is tested and every event
//!   counted, but the suppressor acts from the `confirm`-th consecutive event on (paper 000
//!   §3 points to a sliding window, chosen by Neyman–Pearson, to detect a manoeuvre rather
//!   than a single large residual). Measured on paper 002's scenario with ADS-B-like reports
//!   (2 Hz position σ 10 m and velocity σ 0.5 m/s): a consistent filter meets the r = 3
//!   criterion on ~3 % of the 3-D blocks by chance, and since P ≪ R there, each such false
//!   alarm makes Adapt ≈ 2 Tr(R)/Tr(HΦPΦᵀHᵀ) (tens) and pulls the estimate most of the way
//!   to that noisy report: suppressing on every single event raised the CV filter's
//!   position RMSE from 2.2 m to 5.7 m on straight legs. A run of events by chance is rare
//!   while a real divergence holds on every report. Straight-leg RMSE of the CV filter on
//!   that scenario by `confirm`: 1 → 5.67 m, 2 → 2.61 m, 3 → 2.37 m, never suppressing →
//!   2.23 m; of the IMM: 5.62, 2.57, 2.22, 2.22 m. The default is 4: on the evaluation
//!   bench's paper 002 scenario (NACp 8, NACv 2, 100 runs of 1000 s) runs of three chance
//!   events still happened, each throwing a converged filter back to a report ~40 m off,
//!   while no run of four did: straight-leg RMSE of the hybrid 10.353 m at 3, 10.322 m at 4
//!   and 5 (the IMM: 10.339, 10.322, 10.322 m). At ~4 % of reports meeting r = 3 by chance,
//!   a run of four is ~40 times rarer than one of three: for a feeder with 200 aircraft at
//!   2 reports/s, a chance suppression every ~15 minutes instead of every ~20 s of the whole
//!   sky. The price is one report of delay on a real divergence: the position-only 2 g turn
//!   of the tests peaks at 129 m instead of 35 m (1100 m unsuppressed).
//! - Measured too: with velocity in every report, a CV filter that lags in a turn diverges
//!   in its VELOCITY block, and the paper's single Adapt then inflates the position block as
//!   well, so the position follows the noisy position reports (turn RMSE 9.8 m against
//!   2.5 m unsuppressed). In the hybrid tracker the IMM takes over within ~1 s of a turn's
//!   onset, so this costs nothing there; a stand-alone CV filter fed velocities is better
//!   off with `suppress: false`.

use super::kalman::{self, Innovation, MotionModel};
use super::noise::BlockStat;
use super::quantised::{Grid, OnGrid};
use super::{Observed, TrackError, UNMEASURED_VARIANCE};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// Tuning of the criterion and the suppressor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DivergenceParams {
    /// Storage factor r of eq. 24 (the paper: r ∈ [1, 5], 3 from its simulations). Smaller:
    /// earlier detection, more false alarms. Default 3.
    pub r: f64,
    /// Whether the suppressor (eq. 25–29) acts; `false` only detects and counts. Default true.
    pub suppress: bool,
    /// Upper bound on Adapt. Default 10⁴: enough to hand a converged filter (position σ of a
    /// few metres) back to a measurement kilometres away, finite for any outlier.
    pub max_adapt: f64,
    /// Consecutive events (this step included) before the suppressor acts; 1 = the paper's
    /// every-event rule. Default 4 (module doc).
    pub confirm: u32,
}

impl Default for DivergenceParams {
    fn default() -> Self {
        Self {
            r: 3.0,
            suppress: true,
            max_adapt: 1.0e4,
            confirm: 4,
        }
    }
}

/// A prediction x̂(k+1|k) with Φ P(k|k) Φᵀ and Q kept apart (the suppressor rescales the
/// first alone).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prediction<const N: usize> {
    /// x̂(k+1|k) = Φ x̂(k|k).
    pub x: SVector<f64, N>,
    /// Φ P(k|k) Φᵀ.
    pub fpf: SMatrix<f64, N, N>,
    /// Q(k).
    pub q: SMatrix<f64, N, N>,
}

/// `let_prediction!(pred = f, q; x, p)` binds `pred` to the [`Prediction`] of `(x, p)` with
/// the transition `f` and the process noise `q` of one step, formed in the caller's frame.
///
/// A macro, not a function: a function returning the prediction had it copied into its
/// caller's frame (Φ P Φᵀ is written through a reference, which keeps the compiler from
/// building the value where it is returned), a `memcpy` of 624 or 1,088 bytes a mode a
/// report on the per-report paths (the IMM's modes, the hybrid's CV filter): 1.5 % of the
/// default tracker's fleet instructions.
macro_rules! let_prediction {
    ($pred:ident = $f:expr, $q:expr; $x:expr, $p:expr) => {
        let f = &$f;
        let mut $pred = $crate::track::divergence::Prediction {
            x: f * $x,
            fpf: nalgebra::SMatrix::zeros(),
            q: $q,
        };
        $crate::track::kalman::sparse_fpf_into(f, $p, &mut $pred.fpf);
    };
}
pub(crate) use let_prediction;

impl<const N: usize> Prediction<N> {
    /// Predicts `(x, p)` over `dt_s` with `model` ([`let_prediction`], returned).
    pub fn new(
        model: &dyn MotionModel<N>,
        x: &SVector<f64, N>,
        p: &SMatrix<f64, N, N>,
        dt_s: f64,
    ) -> Self {
        let (f, q) = model.fq(dt_s);
        let_prediction!(pred = f, q; x, p);
        pred
    }

    /// The block of rows and columns `offset..offset + 3` of [`Prediction::covariance`]
    /// (`adapt`), without forming the rest: entry by entry the same arithmetic.
    pub fn covariance_block3(&self, adapt: f64, offset: usize) -> nalgebra::Matrix3<f64> {
        nalgebra::Matrix3::from_fn(|i, j| self.covariance_entry(adapt, offset + i, offset + j))
    }

    /// Entry (i, j) of [`Prediction::covariance`] (`adapt`), 0 outside the matrix: the sums
    /// of `symmetrise(fpf * adapt + q)`, ((Adapt·ΦPΦᵀ + Q)ᵢⱼ + (Adapt·ΦPΦᵀ + Q)ⱼᵢ)/2, and so
    /// also entry (j, i) (a sum is the same in either order). A nominal step (Adapt = 1)
    /// skips the products by 1 (x·1 = x exactly).
    #[inline(always)]
    fn covariance_entry(&self, adapt: f64, i: usize, j: usize) -> f64 {
        let term = |r: usize, c: usize| {
            let f = self.fpf.get((r, c)).copied().unwrap_or(0.0);
            let q = self.q.get((r, c)).copied().unwrap_or(0.0);
            if adapt == 1.0 {
                f + q
            } else {
                f * adapt + q
            }
        };
        (term(i, j) + term(j, i)) * 0.5
    }

    /// P(k+1|k) = Adapt·Φ P Φᵀ + Q (eq. 25; Adapt = 1 is the ordinary eq. 6), symmetrised:
    /// formed over its lower triangle and mirrored ([`Prediction::covariance_entry`]),
    /// without the scaled sum as a temporary (0.6 % of `hybrid`'s fleet instructions).
    pub fn covariance(&self, adapt: f64) -> SMatrix<f64, N, N> {
        let mut p = SMatrix::<f64, N, N>::zeros();
        for j in 0..N {
            for i in j..N {
                let v = self.covariance_entry(adapt, i, j);
                p[(i, j)] = v;
                p[(j, i)] = v;
            }
        }
        p
    }
}

/// What a report measured, in the layout of [`super::models`]: position at state index 0,
/// velocity at index 3 (the same for the 6- and the 9-state filters).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Observation {
    /// Position only (H = [I 0 ...]).
    Position(Observed),
    /// Velocity only (H = [0 I ...]).
    Velocity(Observed),
    /// Both, one joint 6-D update.
    Both(Observed, Observed),
}

impl Observation {
    /// Measured horizontal components: the degrees of freedom of the windowed NIS
    /// ([`super::nis::horizontal`]).
    pub fn horizontal_dof(&self) -> u8 {
        match self {
            Self::Position(o) | Self::Velocity(o) => super::nis::horizontal_components(o),
            Self::Both(p, v) => super::nis::horizontal_dof(Some(p), Some(v)),
        }
    }

    /// The observation in a report, `None` when it carries neither.
    pub fn of(position: Option<&Observed>, velocity: Option<&Observed>) -> Option<Self> {
        match (position, velocity) {
            (Some(p), Some(v)) => Some(Self::Both(*p, *v)),
            (Some(p), None) => Some(Self::Position(*p)),
            (None, Some(v)) => Some(Self::Velocity(*v)),
            (None, None) => None,
        }
    }
}

/// What one guarded update found, besides the posterior it wrote ([`guarded_update`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Guarded {
    /// NIS of the nominal innovation.
    pub nis: f64,
    /// NIS of the nominal innovation over its measured horizontal components
    /// ([`super::nis::horizontal`]): what the gate-like tests of the trackers read (the
    /// outlier test, the IMM's "velocity fits CV").
    pub nis_horizontal: f64,
    /// A velocity report on a grid ([`Observed::grid`](super::Observed)) with the
    /// nominal claim about it, whose quantile NIS ([`OnGrid::nis`]) is the report's term of
    /// the track's windowed NIS; `None` for any other report.
    pub on_grid: Option<OnGrid>,
    /// ln N(ε; 0, S) of the nominal innovation.
    pub log_likelihood: f64,
    /// The criterion held (a divergence event).
    pub diverged: bool,
    /// Consecutive events up to this step (0 when it did not diverge).
    pub run: u32,
    /// The Adapt applied (1 when none).
    pub adapt: f64,
    /// The nominal innovation over the measured components of the position block (`[0]`)
    /// and of the velocity block (`[1]`); zeros for a block not in the report. What
    /// [`super::noise`] learns the measurement noise from.
    pub blocks: [BlockStat; 2],
}

impl Guarded {
    /// The report's term of the track's windowed NIS: the quantile NIS of a report on a
    /// grid ([`super::quantised`]), else the horizontal NIS.
    pub fn published_nis(&self) -> f64 {
        self.on_grid.map_or(self.nis_horizontal, |g| g.nis())
    }
}

/// Components whose variance is below half of [`UNMEASURED_VARIANCE`] count as measured.
fn measured(r_ii: f64) -> bool {
    r_ii < 0.5 * UNMEASURED_VARIANCE
}

/// Paper 000's criterion (eq. 24) and Adapt (eq. 29) for one 3-vector block starting at
/// `start` of an M-vector innovation; `state_offset` is the state index of the block. In the
/// same pass, εᵀε, Tr(S) and Tr(R) over the block's measured horizontal components (its
/// first two), which [`super::noise`] learns from. The criterion's part is `None` when the
/// block does not diverge, else `Some(adapt)` (possibly ≤ 1, which means "no inflation").
fn block_check<const N: usize, const M: usize>(
    inn: &Innovation<M>,
    r: &SMatrix<f64, M, M>,
    pred: &Prediction<N>,
    start: usize,
    state_offset: usize,
    r_factor: f64,
) -> (BlockStat, Option<f64>) {
    let (mut e2, mut tr_s, mut tr_r, mut tr_hqh, mut tr_hfpfh) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let mut horizontal = BlockStat::default();
    let mut e_h = [0.0; 2];
    let mut any = false;
    for i in 0..3 {
        if i == 2 {
            horizontal = BlockStat {
                e2,
                tr_s,
                tr_r,
                e_h,
            };
        }
        let (m, s) = (start + i, state_offset + i);
        let (Some(&e), Some(&s_mm), Some(&r_mm)) =
            (inn.residual.get(m), inn.s.get((m, m)), r.get((m, m)))
        else {
            continue;
        };
        if !measured(r_mm) {
            continue;
        }
        any = true;
        if let Some(c) = e_h.get_mut(i) {
            *c = e;
        }
        e2 += e * e;
        tr_s += s_mm;
        tr_r += r_mm;
        // H selects state components, so H Q Hᵀ and H Φ P Φᵀ Hᵀ are diagonal picks.
        tr_hqh += pred.q.get((s, s)).copied().unwrap_or(0.0);
        tr_hfpfh += pred.fpf.get((s, s)).copied().unwrap_or(0.0);
    }
    if !any || e2 <= r_factor * tr_s {
        return (horizontal, None);
    }
    let numerator = e2 - tr_hqh - tr_r;
    let adapt = if tr_hfpfh > 0.0 {
        numerator / tr_hfpfh
    } else {
        1.0
    };
    (horizontal, Some(adapt))
}

/// One Kalman update from `pred` guarded by paper 000's criterion and suppressor.
///
/// The nominal update runs first (P = Φ P Φᵀ + Q); if the criterion holds on a measured
/// block, this is the `previous_run + 1`-th consecutive event, and when that reaches
/// `confirm` with suppression on, Adapt > 1 is solved (eq. 29), capped, and the update is
/// redone from the same prediction with P = Adapt·Φ P Φᵀ + Q. The caller keeps the run
/// ([`Guarded::run`]) for its next step. Errors are those of [`kalman::update`].
///
/// The posterior x̂(k+1|k+1), P(k+1|k+1) is written to `x_out`, `p_out` (unspecified on
/// error): where the caller keeps it, not returned by value and copied again (a 6x6 or
/// 8x8 covariance a mode per report).
pub fn guarded_update<const N: usize>(
    pred: &Prediction<N>,
    obs: &Observation,
    params: &DivergenceParams,
    previous_run: u32,
    x_out: &mut SVector<f64, N>,
    p_out: &mut SMatrix<f64, N, N>,
) -> Result<Guarded, TrackError> {
    match obs {
        Observation::Position(o) => guarded_update_m::<N, 3>(
            pred,
            &o.value,
            &kalman::block3(0),
            &o.cov,
            &[0],
            None,
            params,
            previous_run,
            x_out,
            p_out,
        ),
        Observation::Velocity(o) => guarded_update_m::<N, 3>(
            pred,
            &o.value,
            &kalman::block3(3),
            &o.cov,
            &[3],
            o.grid.as_ref(),
            params,
            previous_run,
            x_out,
            p_out,
        ),
        Observation::Both(p, v) => {
            let mut z = SVector::<f64, 6>::zeros();
            z.fixed_rows_mut::<3>(0).copy_from(&p.value);
            z.fixed_rows_mut::<3>(3).copy_from(&v.value);
            let mut r = SMatrix::<f64, 6, 6>::zeros();
            r.fixed_view_mut::<3, 3>(0, 0).copy_from(&p.cov);
            r.fixed_view_mut::<3, 3>(3, 3).copy_from(&v.cov);
            guarded_update_m::<N, 6>(
                pred,
                &z,
                &kalman::blocks6(0, 3),
                &r,
                &[0, 3],
                None,
                params,
                previous_run,
                x_out,
                p_out,
            )
        }
    }
}

/// [`guarded_update`] for an M-vector z = x[sel] + v whose 3-blocks sit at the state offsets
/// `blocks`; both Kalman updates are the specialised [`kalman::update_selected_to`], from the
/// prediction's covariance into the caller's `x_out`, `p_out`. `grid`: z is one
/// report on a grid of that step ([`Guarded::on_grid`]; a 3-vector only, else ignored).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn guarded_update_m<const N: usize, const M: usize>(
    pred: &Prediction<N>,
    z: &SVector<f64, M>,
    sel: &[usize; M],
    r: &SMatrix<f64, M, M>,
    blocks: &[usize],
    grid: Option<&Grid>,
    params: &DivergenceParams,
    previous_run: u32,
    x_out: &mut SVector<f64, N>,
    p_out: &mut SMatrix<f64, N, N>,
) -> Result<Guarded, TrackError> {
    let inn = kalman::update_selected_to(&pred.x, &pred.covariance(1.0), z, sel, r, x_out, p_out)?;
    let on_grid = match grid {
        Some(g) if M == 3 => {
            let three =
                |v: &SVector<f64, M>| Vector3::from_fn(|i, _| v.get(i).copied().unwrap_or(0.0));
            let three3 = |m: &SMatrix<f64, M, M>| {
                Matrix3::from_fn(|i, j| m.get((i, j)).copied().unwrap_or(0.0))
            };
            OnGrid::of(
                &three(&inn.residual),
                &three3(&inn.s),
                &three3(r),
                &three(z),
                g,
            )
        }
        _ => None,
    };
    let mut diverged = false;
    let mut adapt = 1.0_f64;
    let mut stats = [BlockStat::default(); 2];
    for (b, &state_offset) in blocks.iter().enumerate() {
        let (stat, criterion) = block_check(&inn, r, pred, 3 * b, state_offset, params.r);
        if let Some(slot) = stats.get_mut(state_offset / 3) {
            *slot = stat;
        }
        if let Some(a) = criterion {
            diverged = true;
            if a.is_finite() {
                adapt = adapt.max(a);
            }
        }
    }
    adapt = adapt.min(params.max_adapt);
    let run = if diverged {
        previous_run.saturating_add(1)
    } else {
        0
    };
    if diverged && params.suppress && run >= params.confirm && adapt > 1.0 {
        kalman::update_selected_to(&pred.x, &pred.covariance(adapt), z, sel, r, x_out, p_out)?;
    } else {
        adapt = 1.0;
    }
    Ok(Guarded {
        nis: inn.nis,
        nis_horizontal: super::nis::horizontal(&inn, r),
        on_grid,
        log_likelihood: inn.log_likelihood(),
        diverged,
        run,
        adapt,
        blocks: stats,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::models::{Cv, Matrix6, State6};
    use nalgebra::{Matrix3, Vector3};
    use rand::rngs::StdRng;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// The predicted covariance is `symmetrise(Adapt·Φ P Φᵀ + Q)` to the bit, for the
    /// nominal Adapt = 1 and for a suppressor's Adapt > 1, with Φ P Φᵀ not symmetric to the
    /// bit (as the sparse product leaves it) and with non-finite entries.
    #[test]
    fn predicted_covariance_is_the_symmetrised_sum_to_the_bit() {
        let mut rng = StdRng::seed_from_u64(9);
        let n = Normal::new(0.0, 50.0).unwrap();
        for k in 0..200 {
            let mut fpf = SMatrix::<f64, 8, 8>::from_fn(|_, _| n.sample(&mut rng));
            let q = {
                let a = SMatrix::<f64, 8, 8>::from_fn(|_, _| n.sample(&mut rng));
                a * a.transpose()
            };
            if k % 50 == 7 {
                fpf[(3, 1)] = f64::NAN;
                fpf[(2, 6)] = f64::INFINITY;
            }
            let pred = Prediction {
                x: SVector::zeros(),
                fpf,
                q,
            };
            for adapt in [1.0, 1.0 + n.sample(&mut rng).abs()] {
                let want = kalman::symmetrise(&(fpf * adapt + q));
                let got = pred.covariance(adapt);
                assert!(
                    got.iter()
                        .zip(want.iter())
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "case {k}, adapt {adapt}"
                );
            }
        }
    }

    /// [`guarded_update`] with its posterior beside what it found.
    struct Updated<const N: usize> {
        x: SVector<f64, N>,
        p: SMatrix<f64, N, N>,
        guarded: Guarded,
    }

    impl<const N: usize> std::ops::Deref for Updated<N> {
        type Target = Guarded;
        fn deref(&self) -> &Guarded {
            &self.guarded
        }
    }

    fn updated<const N: usize>(
        pred: &Prediction<N>,
        obs: &Observation,
        params: &DivergenceParams,
        previous_run: u32,
    ) -> Result<Updated<N>, TrackError> {
        let (mut x, mut p) = (SVector::zeros(), SMatrix::zeros());
        let guarded = guarded_update(pred, obs, params, previous_run, &mut x, &mut p)?;
        Ok(Updated { x, p, guarded })
    }

    /// The paper's rule: suppress on every event.
    fn every_event() -> DivergenceParams {
        DivergenceParams {
            confirm: 1,
            ..DivergenceParams::default()
        }
    }

    #[test]
    fn suppression_waits_for_the_confirming_event() {
        let cv = Cv::default();
        let pred = Prediction::<6>::new(&cv, &State6::zeros(), &Matrix6::identity(), 1.0);
        let obs = position(Vector3::new(100.0, 0.0, 0.0), 1.0);
        let params = DivergenceParams::default();
        assert_eq!(params.confirm, 4);
        let mut run = 0;
        for k in 1..=3 {
            let g = updated(&pred, &obs, &params, run).unwrap();
            assert!(g.diverged && g.run == k && g.adapt == 1.0, "event {k}");
            run = g.run;
        }
        let fourth = updated(&pred, &obs, &params, run).unwrap();
        assert!(fourth.diverged && fourth.run == 4 && fourth.adapt > 1.0);
        let first = updated(&pred, &obs, &params, 0).unwrap();
        // Its state is the one the paper's every-event rule gives at once.
        let paper = updated(&pred, &obs, &every_event(), 0).unwrap();
        assert_eq!(fourth.x, paper.x);
        assert_eq!(
            first.x,
            updated(
                &pred,
                &obs,
                &DivergenceParams {
                    suppress: false,
                    ..params
                },
                0
            )
            .unwrap()
            .x
        );
        // A quiet step ends the run.
        let quiet = updated(&pred, &position(Vector3::zeros(), 1.0), &params, 5).unwrap();
        assert_eq!(quiet.run, 0);
    }

    fn position(value: Vector3<f64>, sigma_m: f64) -> Observation {
        Observation::Position(Observed {
            value,
            cov: Matrix3::identity() * sigma_m * sigma_m,
            grid: None,
        })
    }

    #[test]
    fn adapt_solves_eq_29_and_restores_tr_s_equal_to_the_residual() {
        // 6-state CV at rest, P = I, dt = 1, q tiny; a position residual of 100 m on east.
        let cv = Cv {
            q_h_m2ps3: 1e-6,
            q_v_m2ps3: 1e-6,
            ..Cv::default()
        };
        let p = Matrix6::identity();
        let pred = Prediction::<6>::new(&cv, &State6::zeros(), &p, 1.0);
        // Φ P Φᵀ position diagonal: 1 + T² = 2 per axis; Tr(HΦPΦᵀHᵀ) = 6; Tr(HQHᵀ) = 3e-6/3.
        let obs = position(Vector3::new(100.0, 0.0, 0.0), 1.0);
        let g = updated(&pred, &obs, &every_event(), 0).unwrap();
        assert!(g.diverged);
        let expected = (100.0f64.powi(2) - 3.0 * 1e-6 / 3.0 - 3.0) / 6.0;
        assert!(
            (g.adapt - expected).abs() < 1e-9,
            "{} vs {expected}",
            g.adapt
        );
        // With the inflated P, Tr(S) = Tr(ε εᵀ) = 10⁴ (eq. 26).
        let p_inflated = pred.covariance(g.adapt);
        let tr_s = (0..3).map(|i| p_inflated[(i, i)] + 1.0).sum::<f64>();
        assert!((tr_s - 1.0e4).abs() < 1e-6, "{tr_s}");
        // The nominal NIS is reported: ε²/S_ee = 10⁴/(2 + 1e-6/3 + 1).
        assert!((g.nis - 1.0e4 / (3.0 + 1e-6 / 3.0)).abs() < 1e-6);
        // A small residual: no event, no inflation, the ordinary Kalman update.
        let g = updated(
            &pred,
            &position(Vector3::new(1.0, 0.0, 0.0), 1.0),
            &every_event(),
            0,
        )
        .unwrap();
        assert!(!g.diverged);
        assert_eq!(g.adapt, 1.0);
        // K = 2/3 on east: x_e = 2/3.
        assert!((g.x[0] - 2.0 / 3.0).abs() < 1e-6);
    }

    #[test]
    fn criterion_threshold_is_r_times_the_trace() {
        let cv = Cv {
            q_h_m2ps3: 0.0,
            q_v_m2ps3: 0.0,
            ..Cv::default()
        };
        let tiny = Matrix6::identity() * 1e-12;
        let pred = Prediction::<6>::new(&cv, &State6::zeros(), &tiny, 1.0);
        // P ≈ 0: S ≈ R = I, Tr(S) ≈ 3. εᵀε = 9 - δ: no; 9 + δ: yes (r = 3).
        for (e2, fires) in [(8.99_f64, false), (9.01, true)] {
            let obs = position(Vector3::new(e2.sqrt(), 0.0, 0.0), 1.0);
            let g = updated(&pred, &obs, &every_event(), 0).unwrap();
            assert_eq!(g.diverged, fires, "{e2}");
            // Adapt = (εᵀε − 3)/(3·2e-12) is huge: capped at max_adapt.
            assert_eq!(g.adapt, if fires { 1.0e4 } else { 1.0 });
        }
        // r = 1 fires at εᵀε > 3.
        let params = DivergenceParams {
            r: 1.0,
            ..DivergenceParams::default()
        };
        let obs = position(Vector3::new(2.0, 0.0, 0.0), 1.0);
        assert!(updated(&pred, &obs, &params, 0).unwrap().diverged);
    }

    #[test]
    fn unmeasured_components_do_not_mask_divergence() {
        let cv = Cv::default();
        let pred = Prediction::<6>::new(&cv, &State6::zeros(), &Matrix6::identity(), 1.0);
        // Altitude unmeasured: its 1e6 variance would make r·Tr(S) ≥ 3e6.
        let mut cov = Matrix3::identity() * 100.0;
        cov[(2, 2)] = UNMEASURED_VARIANCE;
        let obs = Observation::Position(Observed {
            value: Vector3::new(200.0, 0.0, 0.0),
            cov,
            grid: None,
        });
        let g = updated(&pred, &obs, &every_event(), 0).unwrap();
        assert!(g.diverged && g.adapt > 1.0);
    }

    /// Straight east at 200 m/s, then a 90° turn at 6°/s (a 2 g manoeuvre at this speed:
    /// 21 m/s²) for 15 s, then straight north. Position-only reports each second, σ = 10 m.
    fn truth(t: f64) -> Vector3<f64> {
        let (v, w) = (200.0, 6f64.to_radians());
        let (t0, t1) = (60.0, 75.0);
        if t <= t0 {
            Vector3::new(v * t, 0.0, 3000.0)
        } else if t <= t1 {
            let a = w * (t - t0);
            Vector3::new(v * t0 + v * a.sin() / w, v * (1.0 - a.cos()) / w, 3000.0)
        } else {
            let r = v / w;
            Vector3::new(v * t0 + r, r + v * (t - t1), 3000.0)
        }
    }

    /// Runs a 6-state CV filter with small process noise over the manoeuvre; returns the
    /// position error (horizontal) at each second.
    fn run(params: &DivergenceParams, seed: u64) -> (Vec<f64>, u64) {
        let sigma = 10.0;
        let cv = Cv {
            q_h_m2ps3: 0.01,
            q_v_m2ps3: 0.01,
            ..Cv::default()
        };
        let mut rng = StdRng::seed_from_u64(seed);
        let noise = Normal::new(0.0, sigma).unwrap();
        let mut x = State6::zeros();
        x.fixed_rows_mut::<3>(0).copy_from(&truth(0.0));
        x[3] = 200.0;
        let mut p =
            Matrix6::from_diagonal(&nalgebra::Vector6::new(100.0, 100.0, 100.0, 4.0, 4.0, 4.0));
        let mut errors = Vec::new();
        let mut events = 0;
        let mut run_length = 0;
        for k in 1..=150 {
            let t = k as f64;
            let z = truth(t) + Vector3::from_fn(|_, _| noise.sample(&mut rng));
            let pred = Prediction::<6>::new(&cv, &x, &p, 1.0);
            let g = updated(&pred, &position(z, sigma), params, run_length).unwrap();
            run_length = g.run;
            x = g.x;
            p = g.p;
            events += u64::from(g.diverged);
            errors.push((x.fixed_rows::<2>(0) - truth(t).fixed_rows::<2>(0)).norm());
        }
        (errors, events)
    }

    #[test]
    fn suppression_halves_the_peak_error_of_a_sharp_manoeuvre_and_recovers() {
        let off = DivergenceParams {
            suppress: false,
            ..DivergenceParams::default()
        };
        for (seed, on) in (0..6).zip(
            [DivergenceParams::default(), every_event()]
                .into_iter()
                .cycle(),
        ) {
            let (e_on, n_on) = run(&on, seed);
            let (e_off, n_off) = run(&off, seed);
            let peak_on = e_on.iter().cloned().fold(0.0, f64::max);
            let peak_off = e_off.iter().cloned().fold(0.0, f64::max);
            assert!(
                peak_on <= 0.5 * peak_off,
                "seed {seed}: peak {peak_on} vs {peak_off}"
            );
            // Events are counted by both (detection does not depend on suppression).
            assert!(n_on > 0 && n_off > 0);
            // Recovery: within 3σ = 30 m from 20 s after the manoeuvre's end (t = 95 s) on,
            // and the unsuppressed one has not recovered by then.
            let tail_on = e_on[94..].iter().cloned().fold(0.0, f64::max);
            assert!(
                tail_on < 30.0,
                "seed {seed}: suppressed error {tail_on} after recovery"
            );
            assert!(e_off[94] > 30.0, "seed {seed}: unsuppressed {}", e_off[94]);
            if seed < 2 {
                eprintln!(
                    "divergence (confirm {}): peak {peak_on:.1} m suppressed vs {peak_off:.1} m, events {n_on}/{n_off}, e(95s) {:.1} vs {:.1}",
                    on.confirm, e_on[94], e_off[94]
                );
            }
        }
    }
}
