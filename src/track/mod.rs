//! Tracking math: pure, synchronous, no tokio, no I/O, no JSON.
//!
//! Shape (after Stone Soup and adskalman): motion models give F(dt) and Q(dt) over nalgebra
//! fixed-size matrices ([`kalman`]); a [`Tracker`] owns its initiation, prediction and update
//! for one aircraft and is what the daemon drives. Everything is in metres and seconds in a
//! local east-north-up plane ([`geo`]); dt is always an argument (ADS-B reports are irregular).

pub(crate) mod alt;
pub mod cubature;
pub mod cv;
pub mod divergence;
pub mod gate;
pub mod geo;
pub mod hybrid;
pub mod imm;
pub mod jerk;
pub mod kalman;
pub mod lag;
pub mod models;
pub mod nis;
pub mod noise;
pub mod outlier;
pub mod process_noise;
pub mod quantised;
pub mod shared;
pub mod singer;
pub mod tails;
pub mod vsimm;

use nalgebra::{Matrix3, Vector3};

/// The five flight modes of paper 002 (ALGORITHMS.md §002).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FlightMode {
    /// Straight, constant velocity.
    Cv,
    /// Constant along-track acceleration.
    Ca,
    /// Coordinated turn.
    Ct,
    /// Climb or descent at constant ground velocity.
    Ch,
    /// Climb or descent with horizontal acceleration.
    Chca,
}

impl FlightMode {
    /// All modes, in the order of [`Estimate::mode_probabilities`].
    pub const ALL: [FlightMode; 5] = [Self::Cv, Self::Ca, Self::Ct, Self::Ch, Self::Chca];

    /// The label used in JSON and the truth CSV.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Cv => "CV",
            Self::Ca => "CA",
            Self::Ct => "CT",
            Self::Ch => "CH",
            Self::Chca => "CHCA",
        }
    }
}

impl std::str::FromStr for FlightMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|m| m.as_str().eq_ignore_ascii_case(s))
            .ok_or_else(|| format!("unknown flight mode {s:?} (expected CV, CA, CT, CH or CHCA)"))
    }
}

/// Direction of a coordinated turn (paper 002's CT mode has a left and a right variant).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TurnDirection {
    /// Counter-clockwise seen from above (heading decreasing).
    Left,
    /// Clockwise seen from above (heading increasing).
    Right,
}

/// Transversal movement, after ASTERIX CAT062 I062/200 "Mode of Movement" (TRANS).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Lateral {
    /// Constant course.
    #[default]
    Straight,
    /// Turning left.
    Left,
    /// Turning right.
    Right,
}

/// Longitudinal movement, after I062/200 (LONG): the trend of the ground speed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum SpeedTrend {
    /// Constant ground speed.
    #[default]
    Constant,
    /// Accelerating along track.
    Increasing,
    /// Decelerating along track.
    Decreasing,
}

/// Vertical movement, after I062/200 (VERT).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum VerticalTrend {
    /// Level flight.
    #[default]
    Level,
    /// Climbing.
    Climb,
    /// Descending.
    Descent,
}

/// A measured vector in the local ENU plane with its covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observed {
    /// Value: position in metres or velocity in m/s, east-north-up.
    pub value: Vector3<f64>,
    /// Its covariance (m^2 or m^2/s^2). A component that was not measured carries a huge
    /// variance ([`UNMEASURED_VARIANCE`]) rather than a NaN.
    pub cov: Matrix3<f64>,
    /// The grid the horizontal components were rounded to before they were sent (a ground
    /// velocity's 1-kt steps along the aircraft's local east and north), or `None` when the
    /// value is not on a grid that matters. `cov` counts the rounding as noise of variance
    /// step²/12 as well; the filters that read the grid update on the bin itself and the
    /// windowed NIS takes the bin's probability ([`quantised`]), since a rounded value that
    /// repeats is no Gaussian draw.
    pub grid: Option<quantised::Grid>,
}

/// Variance given to a component a report did not carry (e.g. vertical rate missing):
/// (1 km)^2 or (1 km/s)^2, so the gain on it is negligible without special-casing H.
pub const UNMEASURED_VARIANCE: f64 = 1.0e6;

/// What one ADS-B report tells the tracker, already in the local ENU plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measurement {
    /// Feed time of the report, seconds.
    pub t_s: f64,
    /// Position (from an airborne position message after CPR decoding).
    pub position: Option<Observed>,
    /// Velocity (from a velocity message: ground velocity and vertical rate).
    pub velocity: Option<Observed>,
}

/// A predicted position and its horizontal uncertainty: what a published prediction carries
/// ([`Tracker::predict_positions`]), in the track's plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionPrediction {
    /// Seconds ahead of the estimate.
    pub dt_s: f64,
    /// Feed time of the prediction, s.
    pub t_s: f64,
    /// Position, m, in the track's plane.
    pub pos_m: Vector3<f64>,
    /// 1-sigma horizontal position uncertainty, m ([`Estimate::pos_sigma_m`]).
    pub pos_sigma_m: f64,
}

impl PositionPrediction {
    /// The prediction `dt_s` ahead, at `t_s`, of a predicted state whose leading three
    /// entries are the position, with its east and north variances.
    pub fn of_state<const N: usize>(
        dt_s: f64,
        t_s: f64,
        x: &nalgebra::SVector<f64, N>,
        var_e: f64,
        var_n: f64,
    ) -> Self {
        Self {
            dt_s,
            t_s,
            pos_m: kalman::rows::<3, N>(x, 0),
            pos_sigma_m: horizontal_sigma(var_e, var_n),
        }
    }

    /// The prediction `dt_s` ahead that the estimate `e` is.
    pub fn of(dt_s: f64, e: &Estimate) -> Self {
        Self {
            dt_s,
            t_s: e.t_s,
            pos_m: e.pos_m,
            pos_sigma_m: e.pos_sigma_m(),
        }
    }
}

/// Seconds from a track's time `track_t_s` to `t_s` when `t_s` is at or after it (a finite,
/// non-negative step): the trackers predict forward only, and refuse other times.
pub fn time_ahead_s(track_t_s: f64, t_s: f64) -> Option<f64> {
    let dt_s = t_s - track_t_s;
    (dt_s.is_finite() && dt_s >= 0.0).then_some(dt_s)
}

/// The published predictions of a single filter holding (`x`, `p`) at `track_t_s` under
/// `model`: at each of `horizons_s` ahead of `base_t_s` (those before the track skipped), the
/// position and the east and north variances alone ([`MotionModel::predict_horizontal`],
/// the same bits as a whole prediction), the variances passed through `variances` (the
/// hybrid adds the correlated error it does not filter).
#[allow(clippy::too_many_arguments)]
pub fn predict_horizontal_positions<const N: usize>(
    model: &impl kalman::MotionModel<N>,
    track_t_s: f64,
    x: &nalgebra::SVector<f64, N>,
    p: &nalgebra::SMatrix<f64, N, N>,
    base_t_s: f64,
    horizons_s: &[f64],
    variances: impl Fn(f64, f64) -> (f64, f64),
    out: &mut Vec<PositionPrediction>,
) {
    for &ahead_s in horizons_s {
        let t_s = base_t_s + ahead_s;
        let Some(dt_s) = time_ahead_s(track_t_s, t_s) else {
            continue;
        };
        let (x, var_e, var_n) = model.predict_horizontal(x, p, dt_s);
        let (var_e, var_n) = variances(var_e, var_n);
        out.push(PositionPrediction::of_state(ahead_s, t_s, &x, var_e, var_n));
    }
}

/// sqrt(σₑ² + σₙ²): the 1-sigma horizontal uncertainty of east and north variances (a
/// negative sum, which rounding could leave, reads as 0).
pub fn horizontal_sigma(var_e: f64, var_n: f64) -> f64 {
    (var_e + var_n).max(0.0).sqrt()
}

/// [`Tracker::predict_positions`] through [`Tracker::predict`], a whole estimate per horizon:
/// the default, and the reference the trackers' own forms are tested against.
pub fn predict_positions_by_estimate<T: Tracker + ?Sized>(
    tracker: &T,
    base_t_s: f64,
    horizons_s: &[f64],
    out: &mut Vec<PositionPrediction>,
) {
    for &dt_s in horizons_s {
        if let Some(e) = tracker.predict(base_t_s + dt_s) {
            out.push(PositionPrediction::of(dt_s, &e));
        }
    }
}

/// Test support: the tracker's own [`Tracker::predict_positions`] and
/// [`Tracker::estimated_position`] give, bit for bit, what its whole estimates give
/// ([`predict_positions_by_estimate`], [`Tracker::estimate`]). Returns the number of
/// predictions compared; nothing to compare (no track) is 0.
#[cfg(test)]
pub(crate) fn assert_reads_match_the_estimate<T: Tracker + ?Sized>(
    tracker: &T,
    horizons_s: &[f64],
) -> usize {
    let Some(e) = tracker.estimate() else {
        return 0;
    };
    let (mut own, mut by_estimate) = (Vec::new(), Vec::new());
    tracker.predict_positions(e.t_s, horizons_s, &mut own);
    predict_positions_by_estimate(tracker, e.t_s, horizons_s, &mut by_estimate);
    let bits = |v: &[PositionPrediction]| {
        v.iter()
            .flat_map(|p| {
                [
                    p.dt_s,
                    p.t_s,
                    p.pos_m.x,
                    p.pos_m.y,
                    p.pos_m.z,
                    p.pos_sigma_m,
                ]
            })
            .map(f64::to_bits)
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&own), bits(&by_estimate), "t {}", e.t_s);
    let (t_s, pos_m) = tracker
        .estimated_position()
        .unwrap_or((f64::NAN, Vector3::zeros()));
    assert_eq!(t_s.to_bits(), e.t_s.to_bits());
    assert!(
        pos_m
            .iter()
            .zip(e.pos_m.iter())
            .all(|(a, b)| a.to_bits() == b.to_bits()),
        "{pos_m} against {}",
        e.pos_m
    );
    own.len()
}

/// A tracker's estimate at a time.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// Time of the estimate, seconds of feed time.
    pub t_s: f64,
    /// Position, metres ENU.
    pub pos_m: Vector3<f64>,
    /// Velocity, m/s ENU.
    pub vel_mps: Vector3<f64>,
    /// Position covariance, m^2.
    pub pos_cov_m2: Matrix3<f64>,
    /// Velocity covariance, (m/s)^2.
    pub vel_cov_m2ps2: Matrix3<f64>,
    /// Current flight-mode label.
    pub mode: FlightMode,
    /// Probability of each mode, in the order of [`FlightMode::ALL`].
    pub mode_probabilities: [f64; 5],
    /// Which filter produced this estimate (e.g. "kalman-cv").
    pub filter: &'static str,
    /// True while paper 000's criterion has held on the last `confirm` reports in a row
    /// (the suppressor acts): a divergence, not a chance event.
    pub diverging: bool,
    /// Divergence events counted over the track's life.
    pub divergence_events: u64,
    /// Position reports set aside as out of their time ([`outlier`]) over the aircraft's
    /// life; 0 for a tracker without the test.
    pub outlier_positions: u64,
    /// Direction of the turn when `mode` is [`FlightMode::Ct`], else `None`.
    pub turn: Option<TurnDirection>,
    /// Transversal movement (I062/200 TRANS).
    pub lateral: Lateral,
    /// Longitudinal movement (I062/200 LONG).
    pub speed: SpeedTrend,
    /// Vertical movement (I062/200 VERT).
    pub vertical: VerticalTrend,
    /// The windowed normalised innovation squared ([`nis`]); `None` before the first
    /// update (every tracker keeps one).
    pub nis: Option<nis::NisStat>,
}

impl Estimate {
    /// 1-sigma horizontal position uncertainty: sqrt of the trace of the EN block, metres.
    pub fn pos_sigma_m(&self) -> f64 {
        horizontal_sigma(self.pos_cov_m2[(0, 0)], self.pos_cov_m2[(1, 1)])
    }

    /// 1-sigma horizontal velocity uncertainty, m/s.
    pub fn vel_sigma_mps(&self) -> f64 {
        (self.vel_cov_m2ps2[(0, 0)] + self.vel_cov_m2ps2[(1, 1)])
            .max(0.0)
            .sqrt()
    }
}

/// Why a tracker step failed. The tracker stays usable: the daemon counts the error and
/// (for `NotPositiveDefinite`) re-initialises from the next position.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TrackError {
    /// The innovation covariance S could not be Cholesky-factored.
    #[error("innovation covariance is not positive definite")]
    NotPositiveDefinite,
    /// A measurement older than the track (out of order): ignored.
    #[error("measurement at {t_s} s is older than the track at {track_t_s} s")]
    OutOfOrder { t_s: f64, track_t_s: f64 },
    /// A non-finite number reached the filter.
    #[error("non-finite value in {0}")]
    NonFinite(&'static str),
}

/// One aircraft's tracker: initiation, prediction and update over irregular reports.
///
/// Object-safe so the daemon can hold `Box<dyn Tracker>` chosen by `tracker.algorithm`.
pub trait Tracker: Send {
    /// Short name of the algorithm (the `filter` field when it has one filter).
    fn name(&self) -> &'static str;

    /// Takes one report. The first report with a position initiates the track; reports before
    /// it are ignored (Ok). A report older than the track is refused with `OutOfOrder`.
    fn update(&mut self, m: &Measurement) -> Result<(), TrackError>;

    /// The current (filtered) estimate, `None` before initiation.
    fn estimate(&self) -> Option<Estimate>;

    /// The current estimate's time and position alone ([`Tracker::estimate`]'s `t_s` and
    /// `pos_m`, the same numbers): what the daemon's trail records after every batch of
    /// reports, where a whole estimate (covariances, labels, NIS) was formed for two fields.
    fn estimated_position(&self) -> Option<(f64, Vector3<f64>)> {
        self.estimate().map(|e| (e.t_s, e.pos_m))
    }

    /// Whether there is a track: [`Tracker::estimate`] would be `Some`. The daemon asks after
    /// every report without a position (did a long gap end the track?), and forming a whole
    /// estimate to answer cost 1-2 % of the fleet replay's instructions; the trackers with a
    /// cheaper answer give it.
    fn has_track(&self) -> bool {
        self.estimate().is_some()
    }

    /// The estimate extrapolated by the current model to `t_s` (>= the track's time), with the
    /// process noise added to its covariance; `None` before initiation.
    fn predict(&self, t_s: f64) -> Option<Estimate>;

    /// [`Tracker::predict`] at `base_t_s + dt_s` for each `dt_s` of `horizons_s`, reduced to
    /// the position and its horizontal σ and appended to `out` (a horizon the tracker cannot
    /// predict is left out). The daemon asks for these with every snapshot it publishes;
    /// forming a whole estimate per horizon (labels, velocity, NIS) to read three numbers
    /// was 1.4 % of a `kalman-cv` fleet replay's instructions, and the hybrid's IMM formed
    /// its combined estimate once per horizon, so the trackers with a cheaper way give it,
    /// with the same numbers (tested against [`predict_positions_by_estimate`], the
    /// default).
    fn predict_positions(
        &self,
        base_t_s: f64,
        horizons_s: &[f64],
        out: &mut Vec<PositionPrediction>,
    ) {
        predict_positions_by_estimate(self, base_t_s, horizons_s, out);
    }

    /// Drops the track: the tracker is as new, with the same parameters, and the next report
    /// with a position initiates a new track. The daemon's last line of defence, for an
    /// estimate that went non-finite or left the globe, and for an aircraft that reappears
    /// too far from where its track's plane was laid.
    fn reset(&mut self);

    /// Whether the aircraft declares its position accuracy (NACp), so that the position
    /// covariance it reports is that declaration rather than a fall-back on the type code's
    /// NUCp, and its velocity accuracy (NACv or NUCr above 0, rather than NACv 1's bound
    /// taken for 0). The daemon says so before each report. Ignored by default; the hybrid
    /// tracker and the IMM bound the total error they publish by a declaration and learn
    /// an undeclared block's noise with a weaker prior ([`noise`]).
    fn set_accuracy_declared(&mut self, _position: bool, _velocity: bool) {}

    /// Position reports set aside as out of their time over the aircraft's life
    /// ([`outlier`]; [`Estimate::outlier_positions`] without forming an estimate): the
    /// daemon counts them after each update. 0 for a tracker without the test.
    fn outlier_positions(&self) -> u64 {
        0
    }
}

/// The alternative trackers of papers 000, 001 and 003 by name, with default parameters:
/// "singer", "singer-nosupp" ([`singer`]), "cs-jerk", "cs-jerk-plain", "jerk" ([`jerk`]),
/// "vsimm-srckf", "imm-ckf", "imm-srckf" ([`vsimm`]). `None` for any other name.
pub fn build_alternative(name: &str) -> Option<Box<dyn Tracker>> {
    use jerk::{JerkParams, JerkTracker, JerkVariant};
    use singer::{SingerParams, SingerTracker};
    use vsimm::{Variant, Vsimm, VsimmParams};
    let jerk = |variant| -> Box<dyn Tracker> {
        Box::new(JerkTracker::new(JerkParams {
            variant,
            ..JerkParams::default()
        }))
    };
    let imm = |variant| -> Box<dyn Tracker> {
        Box::new(Vsimm::new(VsimmParams {
            variant,
            ..VsimmParams::default()
        }))
    };
    Some(match name {
        singer::NAME => Box::new(SingerTracker::default()),
        singer::NAME_NO_SUPPRESSION => Box::new(SingerTracker::new(SingerParams {
            suppression: false,
            ..SingerParams::default()
        })),
        jerk::NAME_CS_JERK => jerk(JerkVariant::CsJerkImproved),
        jerk::NAME_CS_JERK_PLAIN => jerk(JerkVariant::CsJerkPlain),
        jerk::NAME_JERK => jerk(JerkVariant::Jerk),
        vsimm::NAME_VSIMM => imm(Variant::VsimmSrckf),
        vsimm::NAME_IMM_CKF => imm(Variant::ImmCkf),
        vsimm::NAME_IMM_SRCKF => imm(Variant::ImmSrckf),
        _ => return None,
    })
}

#[cfg(test)]
mod alternative_tests {
    #[test]
    fn every_alternative_builds_under_its_own_name() {
        let names = [
            "singer",
            "singer-nosupp",
            "cs-jerk",
            "cs-jerk-plain",
            "jerk",
            "vsimm-srckf",
            "imm-ckf",
            "imm-srckf",
        ];
        for name in names {
            let t = super::build_alternative(name).unwrap();
            assert_eq!(t.name(), name);
            assert!(t.estimate().is_none());
        }
        assert!(super::build_alternative("kalman-cv").is_none());
    }
}
