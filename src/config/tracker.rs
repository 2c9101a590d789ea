//! The `[tracker]` section: which tracker runs and the tuning of the default one (paper
//! 002's gate, the IMM's transition matrix, paper 000's divergence criterion), turned into
//! the parameter structs of [`crate::track`]. The track module knows nothing of TOML: the
//! daemon builds its trackers from what this module gives.

use super::{bad, ConfigError};
use crate::track::cv::CvParams;
use crate::track::divergence::DivergenceParams;
use crate::track::gate::{GateParams, GATE_CAPACITY};
use crate::track::hybrid::HybridParams;
use crate::track::imm::{ImmParams, ImmTrackerParams, N_MODES};
use crate::track::noise::NoiseParams;
use crate::track::outlier::OutlierParams;
use crate::track::process_noise::SteadyQParams;
use crate::track::tails::TailParams;
use serde::Deserialize;

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TrackerConfig {
    /// Which tracker each aircraft runs.
    pub algorithm: String,
    /// An aircraft silent this long (feed time) is retired, s.
    pub retire_after_s: f64,
    /// Capacity of each aircraft task's channel (batches); a full channel drops and counts.
    pub channel_capacity: usize,
    /// White-noise acceleration spectral density of the CV model of `kalman-cv` and of the
    /// IMMs' CV mode, horizontal, m^2/s^3.
    pub cv_q_horizontal: f64,
    /// The same for the hybrid's Kalman filter, which runs in steady flight only (its gate
    /// hands every manoeuvre to the IMM), m^2/s^3.
    pub steady_q_horizontal: f64,
    /// Same, vertical, m^2/s^3.
    pub cv_q_vertical: f64,
    /// A gap longer than this re-initialises a track, s.
    pub max_gap_s: f64,
    /// Horizons of the predicted positions served by `/api/v1/tracks/{icao}/prediction`, s.
    pub prediction_horizons_s: Vec<f64>,
    /// Paper 002's manoeuvre gate.
    pub gate: GateConfig,
    /// The IMM (in the hybrid's manoeuvres, and alone as `imm`).
    pub imm: ImmConfig,
    /// Paper 000's divergence criterion and suppressor.
    pub divergence: DivergenceConfig,
    /// The hybrid's switching.
    pub hybrid: HybridConfig,
}

/// `[tracker.gate]`: a preset and any of its values overridden (`None`: the preset's). A
/// threshold of 0 disables its test.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GateConfig {
    /// `airliner` ([`GateParams::default`]) or `paper002` ([`GateParams::paper002`]).
    pub preset: String,
    pub window_reports: Option<usize>,
    pub speed_change_mps: Option<f64>,
    pub accel_change_mps2: Option<f64>,
    pub heading_change_deg: Option<f64>,
    pub pitch_change_deg: Option<f64>,
    pub turn_rate_deg_s: Option<f64>,
    pub turn_window_reports: Option<usize>,
    pub onset_reports: Option<usize>,
    pub onset_reference_reports: Option<usize>,
    pub onset_sigmas: Option<f64>,
    /// 0 disables the first-report turn test.
    pub first_report_turn_sigmas: Option<f64>,
    /// 0 disables the turn's end test.
    pub turn_end_sigmas: Option<f64>,
    pub along_track_accel_mps2: Option<f64>,
    /// 0 disables the acceleration's hold by its own line.
    pub accel_hold_sigmas: Option<f64>,
    pub accel_onset_reports: Option<usize>,
    pub accel_onset_reference_reports: Option<usize>,
    pub trend_window_reports: Option<usize>,
    pub vertical_rate_mps: Option<f64>,
    /// 0 disables the climb or descent onset test.
    pub vertical_onset_sigmas: Option<f64>,
    /// 0 disables the altitude-confirmed climb or descent onset.
    pub vertical_onset_altitude_sigmas: Option<f64>,
    pub vertical_window_reports: Option<usize>,
    pub max_window_s: Option<f64>,
    pub significance_sigmas: Option<f64>,
    pub release_ratio: Option<f64>,
    pub min_speed_mps: Option<f64>,
    pub max_velocity_sigma_mps: Option<f64>,
    pub vrate_noise_window_reports: Option<f64>,
}

/// One value per IMM mode, by name.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PerMode {
    pub cv: f64,
    pub ca: f64,
    pub ct_left: f64,
    pub ct_right: f64,
    pub ch: f64,
    pub chca: f64,
}

impl PerMode {
    /// In [`crate::track::imm::ImmMode::ALL`] order, each checked by [`check`] under
    /// `key.<mode>`.
    fn checked(
        &self,
        key: &str,
        lo: f64,
        lo_open: bool,
        hi: f64,
    ) -> Result<[f64; N_MODES], ConfigError> {
        let values = self.array();
        for (v, name) in values.iter().zip(MODE_KEYS) {
            check(&format!("{key}.{name}"), *v, lo, lo_open, hi)?;
        }
        Ok(values)
    }

    /// In [`crate::track::imm::ImmMode::ALL`] order.
    fn array(&self) -> [f64; N_MODES] {
        [
            self.cv,
            self.ca,
            self.ct_left,
            self.ct_right,
            self.ch,
            self.chca,
        ]
    }
}

/// The mode names of [`PerMode`], in the same order: for messages.
/// The longest `tracker.imm.velocity_lag_s`, s: the simulator's offsets go to 2 s.
const MAX_VELOCITY_LAG_S: f64 = 5.0;

const MODE_KEYS: [&str; N_MODES] = ["cv", "ca", "ct_left", "ct_right", "ch", "chca"];

/// `[tracker.imm]`: the Markov chain of the modes and the CT models' rate.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ImmConfig {
    /// Mean sojourn time τ of each mode, s: kept over dt with probability exp(−dt/τ).
    pub mean_sojourn_s: PerMode,
    /// Where a switch goes: row = from, column = to, modes in [`PerMode`] order; the
    /// diagonal is ignored.
    pub switch_weights: Vec<Vec<f64>>,
    /// Mode probabilities of a new track.
    pub initial_probabilities: PerMode,
    /// Turn rate of the CT models when it is not adapted, deg/s.
    pub ct_turn_rate_deg_s: f64,
    /// How much older a velocity report is than its frame, s ([`ImmParams::velocity_lag_s`]).
    pub velocity_lag_s: f64,
}

/// `[tracker.divergence]`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DivergenceConfig {
    /// Storage factor r of εᵀε > r·Tr(S).
    pub r: f64,
    /// Whether the suppressor acts (else only detect and count).
    pub suppress: bool,
    /// Consecutive events before the suppressor acts.
    pub confirm: u32,
    /// Upper bound of the inflation factor Adapt.
    pub max_adapt: f64,
}

/// `[tracker.hybrid]`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HybridConfig {
    /// The IMM stays on at least this long after the gate last fired, s.
    pub min_manoeuvre_dwell_s: f64,
    /// Consecutive divergence events of the CV filter that open the IMM (0: never).
    pub divergence_trigger: u32,
    /// Without a velocity report this long, the gate reads the filter's velocity, s.
    pub velocity_stale_s: f64,
    /// Run the IMM whenever velocity reports are stale.
    pub imm_without_velocity: bool,
    /// Run the CT models at the turn rate the gate measures.
    pub adapt_turn_rate: bool,
    /// Clamp of the adapted turn rate, deg/s.
    pub turn_rate_limits_deg_s: [f64; 2],
    /// IMM probability of the gate's label when the IMM opens.
    pub entry_probability: f64,
    /// While a gate test holds, run the IMM over CV and the modes it names.
    pub variable_structure: bool,
    /// Learn each aircraft's measurement noise from its innovations (`track::noise`).
    pub learn_noise: bool,
    /// Learn how much older each aircraft's velocity reports are than its positions
    /// (`track::lag`), for the IMM's CT modes: the hybrid's and the plain `imm`'s.
    pub learn_velocity_lag: bool,
    /// Scale the hybrid's steady-flight q_h per aircraft by what its velocity reports show
    /// (`track::process_noise`), down to `steady_q_min_scale` times `steady_q_horizontal`.
    pub learn_steady_q: bool,
    pub steady_q_min_scale: f64,
    /// Read a position report's term of the windowed NIS of `hybrid` and `imm` under a
    /// Student-t claim whose covariance is the filter's and whose tail index is learned per
    /// aircraft (`track::tails`); false: the Gaussian NIS. The estimate is the same either
    /// way.
    pub learn_position_tails: bool,
    /// The same for a velocity report on a narrow claim (its two quantile residuals), under
    /// a tail index learned from them (`track::tails`, "Velocity reports"); false: the
    /// Gaussian quantile NIS.
    pub learn_velocity_tails: bool,
    /// Bounds of the learned factor on the declared covariance.
    pub noise_scale_limits: [f64; 2],
    /// An innovation's εᵀε is winsorised at this many times Tr(S) before the learner
    /// averages it (`NoiseParams::outlier_ratio`).
    pub noise_outlier_ratio: f64,
    /// Let an aircraft's innovations overrule a declared accuracy they contradict
    /// (`NoiseParams::prior_conflict`).
    pub noise_prior_conflict: bool,
    /// Weight per report of the running mean of the velocity innovation that the learner
    /// centres on (`NoiseParams::velocity_centre_weight`), in [0, 1]; 0: not centred.
    pub noise_velocity_centre_weight: f64,
    /// Reports in covariance matching's exponential window for the position reports
    /// (`NoiseParams::window`), at least 1.
    pub noise_window_reports: f64,
    /// The same for the velocity reports (`NoiseParams::velocity_window`), at least 1.
    pub velocity_noise_window_reports: f64,
    /// Position reports out of their time set aside (`track::outlier`): the horizontal NIS
    /// above which (0: never), how many in a row at most, and below which share of recent
    /// position reports above it.
    pub outlier_nis: f64,
    pub outlier_max_in_a_row: u32,
    pub outlier_max_share: f64,
}

pub use crate::track::imm::IMM_NOISE_WINDOW_REPORTS;

/// `v` finite and within `lo..=hi` (`lo_open`: `lo` itself excluded).
fn check(key: &str, v: f64, lo: f64, lo_open: bool, hi: f64) -> Result<f64, ConfigError> {
    let above = if lo_open { v > lo } else { v >= lo };
    if v.is_finite() && above && v <= hi {
        Ok(v)
    } else {
        let open = if lo_open { "(" } else { "[" };
        Err(bad(
            key,
            format!("must be within {open}{lo}, {hi}], got {v}"),
        ))
    }
}

fn count(key: &str, v: usize, lo: usize, hi: usize) -> Result<usize, ConfigError> {
    if (lo..=hi).contains(&v) {
        Ok(v)
    } else {
        Err(bad(key, format!("must be within {lo}..={hi}, got {v}")))
    }
}

/// An onset test's `{prefix}_reports` (0..=capacity − 3) and `{prefix}_reference_reports`
/// (3..=capacity), each overriding the preset's (`preset`) when given, and together within
/// the gate's capacity.
fn onset_counts(
    prefix: &str,
    reports: Option<usize>,
    reference: Option<usize>,
    preset: (usize, usize),
) -> Result<(usize, usize), ConfigError> {
    let cap = GATE_CAPACITY;
    let (key_n, key_ref) = (
        format!("tracker.gate.{prefix}_reports"),
        format!("tracker.gate.{prefix}_reference_reports"),
    );
    let n = reports.map_or(Ok(preset.0), |v| count(&key_n, v, 0, cap - 3))?;
    let r = reference.map_or(Ok(preset.1), |v| count(&key_ref, v, 3, cap))?;
    if n + r > cap {
        return Err(bad(
            &key_ref,
            format!("{prefix}_reports + {prefix}_reference_reports must be at most {cap}"),
        ));
    }
    Ok((n, r))
}

/// A threshold: ≥ 0, 0 disabling the test.
fn threshold(key: &str, v: f64) -> Result<Option<f64>, ConfigError> {
    let v = check(key, v, 0.0, false, f64::MAX)?;
    Ok((v > 0.0).then_some(v))
}

impl GateConfig {
    /// The preset with the overrides applied, checked.
    pub fn params(&self) -> Result<GateParams, ConfigError> {
        let mut p = match self.preset.as_str() {
            "airliner" => GateParams::default(),
            "paper002" => GateParams::paper002(),
            other => {
                return Err(bad(
                    "tracker.gate.preset",
                    format!("unknown {other:?}; expected airliner or paper002"),
                ))
            }
        };
        let k = |name: &str| format!("tracker.gate.{name}");
        let cap = GATE_CAPACITY;
        if let Some(v) = self.window_reports {
            p.window_reports = count(&k("window_reports"), v, 2, cap)?;
        }
        let thresholds = [
            (
                &self.speed_change_mps,
                "speed_change_mps",
                &mut p.speed_change_mps,
            ),
            (
                &self.accel_change_mps2,
                "accel_change_mps2",
                &mut p.accel_change_mps2,
            ),
            (
                &self.heading_change_deg,
                "heading_change_deg",
                &mut p.heading_change_deg,
            ),
            (
                &self.pitch_change_deg,
                "pitch_change_deg",
                &mut p.pitch_change_deg,
            ),
            (
                &self.turn_rate_deg_s,
                "turn_rate_deg_s",
                &mut p.turn_rate_deg_s,
            ),
            (
                &self.along_track_accel_mps2,
                "along_track_accel_mps2",
                &mut p.along_track_accel_mps2,
            ),
            (
                &self.vertical_rate_mps,
                "vertical_rate_mps",
                &mut p.vertical_rate_mps,
            ),
        ];
        for (value, name, slot) in thresholds {
            if let Some(v) = *value {
                *slot = threshold(&k(name), v)?;
            }
        }
        if let Some(v) = self.turn_window_reports {
            p.turn_window_reports = count(&k("turn_window_reports"), v, 3, cap)?;
        }
        (p.onset_reports, p.onset_reference_reports) = onset_counts(
            "onset",
            self.onset_reports,
            self.onset_reference_reports,
            (p.onset_reports, p.onset_reference_reports),
        )?;
        (p.accel_onset_reports, p.accel_onset_reference_reports) = onset_counts(
            "accel_onset",
            self.accel_onset_reports,
            self.accel_onset_reference_reports,
            (p.accel_onset_reports, p.accel_onset_reference_reports),
        )?;
        if let Some(v) = self.onset_sigmas {
            p.onset_sigmas = check(&k("onset_sigmas"), v, 0.0, false, 100.0)?;
        }
        if let Some(v) = self.first_report_turn_sigmas {
            let v = check(&k("first_report_turn_sigmas"), v, 0.0, false, 100.0)?;
            p.first_report_turn_sigmas = (v > 0.0).then_some(v);
        }
        if let Some(v) = self.turn_end_sigmas {
            let v = check(&k("turn_end_sigmas"), v, 0.0, false, 100.0)?;
            p.turn_end_sigmas = (v > 0.0).then_some(v);
        }
        if let Some(v) = self.accel_hold_sigmas {
            let v = check(&k("accel_hold_sigmas"), v, 0.0, false, 100.0)?;
            p.accel_hold_sigmas = (v > 0.0).then_some(v);
        }
        if let Some(v) = self.vertical_onset_sigmas {
            let v = check(&k("vertical_onset_sigmas"), v, 0.0, false, 100.0)?;
            p.vertical_onset_sigmas = (v > 0.0).then_some(v);
        }
        if let Some(v) = self.vertical_onset_altitude_sigmas {
            let v = check(&k("vertical_onset_altitude_sigmas"), v, 0.0, false, 100.0)?;
            p.vertical_onset_altitude_sigmas = (v > 0.0).then_some(v);
        }
        if let Some(v) = self.trend_window_reports {
            p.trend_window_reports = count(&k("trend_window_reports"), v, 3, cap)?;
        }
        if let Some(v) = self.vertical_window_reports {
            p.vertical_window_reports = count(&k("vertical_window_reports"), v, 1, cap)?;
        }
        if let Some(v) = self.max_window_s {
            p.max_window_s = check(&k("max_window_s"), v, 0.0, true, 3600.0)?;
        }
        if let Some(v) = self.significance_sigmas {
            p.significance_sigmas = check(&k("significance_sigmas"), v, 0.0, false, 100.0)?;
        }
        if let Some(v) = self.release_ratio {
            p.release_ratio = check(&k("release_ratio"), v, 0.0, true, 1.0)?;
        }
        if let Some(v) = self.min_speed_mps {
            p.min_speed_mps = check(&k("min_speed_mps"), v, 0.0, false, 1000.0)?;
        }
        if let Some(v) = self.max_velocity_sigma_mps {
            p.max_velocity_sigma_mps =
                check(&k("max_velocity_sigma_mps"), v, 0.0, true, f64::INFINITY)?;
        }
        if let Some(v) = self.vrate_noise_window_reports {
            p.vrate_noise_window_reports =
                check(&k("vrate_noise_window_reports"), v, 0.0, false, 1.0e6)?;
        }
        Ok(p)
    }
}

impl ImmConfig {
    /// The IMM's parameters (models from `base`, whose CV noise the caller set), checked.
    fn params(
        &self,
        base: ImmParams,
        divergence: DivergenceParams,
    ) -> Result<ImmParams, ConfigError> {
        let mut p = ImmParams { divergence, ..base };
        p.mean_sojourn_s =
            self.mean_sojourn_s
                .checked("tracker.imm.mean_sojourn_s", 0.0, true, 1.0e6)?;
        let key = "tracker.imm.switch_weights";
        if self.switch_weights.len() != N_MODES {
            return Err(bad(
                key,
                format!("expected {N_MODES} rows (from cv, ca, ct_left, ct_right, ch, chca)"),
            ));
        }
        for (i, (row, from)) in self.switch_weights.iter().zip(MODE_KEYS).enumerate() {
            let row_key = format!("{key}[{i}]");
            if row.len() != N_MODES {
                return Err(bad(&row_key, format!("expected {N_MODES} weights")));
            }
            let mut off_diagonal = 0.0;
            for (j, (w, slot)) in row.iter().zip(p.switch_weights[i].iter_mut()).enumerate() {
                *slot = check(&format!("{row_key}[{j}]"), *w, 0.0, false, 1.0e6)?;
                if i != j {
                    off_diagonal += *w;
                }
            }
            if off_diagonal <= 0.0 {
                return Err(bad(
                    &row_key,
                    format!(
                        "a switch from {from} must go somewhere: some weight off the diagonal > 0"
                    ),
                ));
            }
        }
        let initial = self.initial_probabilities.checked(
            "tracker.imm.initial_probabilities",
            0.0,
            false,
            1.0,
        )?;
        if initial.iter().sum::<f64>() <= 0.0 {
            return Err(bad(
                "tracker.imm.initial_probabilities",
                "must not all be 0",
            ));
        }
        p.initial_probabilities = initial;
        let rate = check(
            "tracker.imm.ct_turn_rate_deg_s",
            self.ct_turn_rate_deg_s,
            0.0,
            true,
            30.0,
        )?;
        // As models::STANDARD_RATE_RAD_S is written (to_radians() differs in the last bit).
        p.models.ct.omega_rad_s = rate * std::f64::consts::PI / 180.0;
        p.velocity_lag_s = check(
            "tracker.imm.velocity_lag_s",
            self.velocity_lag_s,
            0.0,
            false,
            MAX_VELOCITY_LAG_S,
        )?;
        Ok(p)
    }
}

impl DivergenceConfig {
    fn params(&self) -> Result<DivergenceParams, ConfigError> {
        Ok(DivergenceParams {
            r: check("tracker.divergence.r", self.r, 0.0, true, 100.0)?,
            suppress: self.suppress,
            confirm: count("tracker.divergence.confirm", self.confirm as usize, 1, 1000)? as u32,
            max_adapt: check(
                "tracker.divergence.max_adapt",
                self.max_adapt,
                1.0,
                false,
                f64::MAX,
            )?,
        })
    }
}

impl TrackerConfig {
    /// The CV model noise and paper 000's r of the `kalman-cv` tracker.
    pub fn cv_params(&self) -> Result<CvParams, ConfigError> {
        Ok(CvParams {
            q_h_m2ps3: self.cv_q_horizontal,
            q_v_m2ps3: self.cv_q_vertical,
            max_gap_s: self.max_gap_s,
            divergence_r: self.divergence.params()?.r,
            divergence_confirm: self.divergence.params()?.confirm,
            ..CvParams::default()
        })
    }

    /// The IMM's parameters: `[tracker.imm]`, `[tracker.divergence]` and the CV noise.
    fn imm_base(&self) -> Result<ImmParams, ConfigError> {
        let mut base = ImmParams::default();
        base.models.cv.q_h_m2ps3 = self.cv_q_horizontal;
        base.models.cv.q_v_m2ps3 = self.cv_q_vertical;
        self.imm.params(base, self.divergence.params()?)
    }

    /// The `imm` tracker.
    pub fn imm_tracker_params(&self) -> Result<ImmTrackerParams, ConfigError> {
        let mut p = ImmTrackerParams {
            imm: self.imm_base()?,
            ..ImmTrackerParams::default()
        };
        p.init.max_gap_s = self.max_gap_s;
        // The plain IMM keeps its own window (`noise_window_reports` and
        // `velocity_noise_window_reports` are the hybrid's; IMM_NOISE_WINDOW_REPORTS says why).
        p.noise = NoiseParams {
            window: IMM_NOISE_WINDOW_REPORTS,
            velocity_window: IMM_NOISE_WINDOW_REPORTS,
            ..self.noise_params()?
        };
        p.learn_velocity_lag = self.hybrid.learn_velocity_lag;
        p.outliers = self.outlier_params()?;
        p.tails = self.tail_params();
        p.velocity_tails = self.velocity_tail_params();
        Ok(p)
    }

    /// The `hybrid` tracker; with `paper002_gate`, paper 002's printed gate thresholds
    /// whatever `[tracker.gate]` says, and the IMM over every mode (the `hybrid-paper002`
    /// tracker).
    pub fn hybrid_params(&self, paper002_gate: bool) -> Result<HybridParams, ConfigError> {
        let mut p = HybridParams::default();
        p.cv.q_h_m2ps3 = self.steady_q_horizontal;
        p.cv.q_v_m2ps3 = self.cv_q_vertical;
        p.imm = self.imm_base()?;
        p.divergence = self.divergence.params()?;
        p.init.max_gap_s = self.max_gap_s;
        p.gate = if paper002_gate {
            GateParams::paper002()
        } else {
            self.gate.params()?
        };
        let h = &self.hybrid;
        p.min_manoeuvre_dwell_s = check(
            "tracker.hybrid.min_manoeuvre_dwell_s",
            h.min_manoeuvre_dwell_s,
            0.0,
            false,
            3600.0,
        )?;
        p.divergence_trigger = h.divergence_trigger;
        p.velocity_stale_s = check(
            "tracker.hybrid.velocity_stale_s",
            h.velocity_stale_s,
            0.0,
            true,
            3600.0,
        )?;
        p.imm_without_velocity = h.imm_without_velocity;
        p.adapt_turn_rate = h.adapt_turn_rate;
        let [lo, hi] = h.turn_rate_limits_deg_s;
        let key = "tracker.hybrid.turn_rate_limits_deg_s";
        check(key, lo, 0.0, true, 30.0)?;
        check(key, hi, lo, false, 30.0)?;
        p.turn_rate_limits_deg_s = (lo, hi);
        p.entry_probability = check(
            "tracker.hybrid.entry_probability",
            h.entry_probability,
            0.0,
            false,
            1.0,
        )?;
        // Paper 002's preset runs its RMIMM over every mode ([`HybridParams::paper002`]).
        p.variable_structure = h.variable_structure && !paper002_gate;
        p.noise = self.noise_params()?;
        p.learn_velocity_lag = h.learn_velocity_lag;
        p.outliers = self.outlier_params()?;
        p.steady_q = SteadyQParams {
            enabled: h.learn_steady_q,
            min_scale: check(
                "tracker.hybrid.steady_q_min_scale",
                h.steady_q_min_scale,
                0.0,
                true,
                1.0,
            )?,
            ..SteadyQParams::default()
        };
        p.tails = self.tail_params();
        p.velocity_tails = self.velocity_tail_params();
        Ok(p)
    }

    /// The position terms' tail index of `hybrid` and `imm`
    /// (`tracker.hybrid.learn_position_tails`).
    fn tail_params(&self) -> TailParams {
        TailParams {
            enabled: self.hybrid.learn_position_tails,
            ..TailParams::default()
        }
    }

    /// The velocity terms' tail index of `hybrid` and `imm`
    /// (`tracker.hybrid.learn_velocity_tails`).
    fn velocity_tail_params(&self) -> TailParams {
        TailParams {
            enabled: self.hybrid.learn_velocity_tails,
            ..TailParams::default()
        }
    }

    /// The outlier test of `hybrid` and `imm` (`[tracker.hybrid] outlier_*` keys).
    fn outlier_params(&self) -> Result<OutlierParams, ConfigError> {
        let h = &self.hybrid;
        Ok(OutlierParams {
            nis: check(
                "tracker.hybrid.outlier_nis",
                h.outlier_nis,
                0.0,
                false,
                1.0e6,
            )?,
            max_in_a_row: count(
                "tracker.hybrid.outlier_max_in_a_row",
                h.outlier_max_in_a_row as usize,
                0,
                100,
            )? as u32,
            max_share: check(
                "tracker.hybrid.outlier_max_share",
                h.outlier_max_share,
                0.0,
                false,
                1.0,
            )?,
            ..OutlierParams::default()
        })
    }

    /// The learned measurement noise of `hybrid` and `imm` (`[tracker.hybrid]` keys).
    fn noise_params(&self) -> Result<NoiseParams, ConfigError> {
        let h = &self.hybrid;
        let [lo, hi] = h.noise_scale_limits;
        let key = "tracker.hybrid.noise_scale_limits";
        Ok(NoiseParams {
            enabled: h.learn_noise,
            min_scale: check(key, lo, 0.0, true, 1.0)?,
            max_scale: check(key, hi, 1.0, false, 1.0e4)?,
            outlier_ratio: check(
                "tracker.hybrid.noise_outlier_ratio",
                h.noise_outlier_ratio,
                1.0,
                false,
                1.0e6,
            )?,
            prior_conflict: h.noise_prior_conflict,
            window: check(
                "tracker.hybrid.noise_window_reports",
                h.noise_window_reports,
                1.0,
                false,
                1.0e6,
            )?,
            velocity_window: check(
                "tracker.hybrid.velocity_noise_window_reports",
                h.velocity_noise_window_reports,
                1.0,
                false,
                1.0e6,
            )?,
            velocity_centre_weight: check(
                "tracker.hybrid.noise_velocity_centre_weight",
                h.noise_velocity_centre_weight,
                0.0,
                false,
                1.0,
            )?,
            ..NoiseParams::default()
        })
    }

    /// Checks every tuning value (the daemon then builds trackers without failing).
    pub fn validate_tuning(&self) -> Result<(), ConfigError> {
        self.cv_params()?;
        self.imm_tracker_params()?;
        self.hybrid_params(false)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::config::Config;
    use crate::track::cv::CvParams;
    use crate::track::hybrid::HybridParams;
    use crate::track::imm::ImmTrackerParams;

    #[test]
    fn default_toml_is_the_code_defaults() {
        // config/default.toml documents the defaults: it must say what the code does.
        let c = Config::default_config().unwrap().tracker;
        assert_eq!(c.hybrid_params(false).unwrap(), HybridParams::default());
        assert_eq!(c.hybrid_params(true).unwrap(), HybridParams::paper002());
        assert_eq!(c.imm_tracker_params().unwrap(), ImmTrackerParams::default());
        assert_eq!(c.cv_params().unwrap(), CvParams::default());
    }

    #[test]
    fn overrides_reach_the_tracker() {
        let c = Config::from_toml_str(
            "[tracker.gate]\npreset = \"paper002\"\nheading_change_deg = 2.5\npitch_change_deg = 0\n\
             [tracker.imm]\nmean_sojourn_s = { cv = 60.0 }\nct_turn_rate_deg_s = 1.5\n\
             [tracker.divergence]\nr = 2.0\nconfirm = 1\n\
             [tracker.hybrid]\nmin_manoeuvre_dwell_s = 8.0\n",
        )
        .unwrap()
        .tracker;
        let p = c.hybrid_params(false).unwrap();
        assert_eq!(p.gate.heading_change_deg, Some(2.5));
        assert_eq!(p.gate.pitch_change_deg, None);
        assert_eq!(p.gate.speed_change_mps, Some(10.0));
        assert_eq!(p.gate.turn_rate_deg_s, None);
        assert_eq!(p.imm.mean_sojourn_s[0], 60.0);
        assert_eq!(p.imm.mean_sojourn_s[1], 20.0);
        assert!((p.imm.models.ct.omega_rad_s - 1.5f64.to_radians()).abs() < 1e-15);
        assert_eq!((p.divergence.r, p.divergence.confirm), (2.0, 1));
        assert_eq!(p.imm.divergence, p.divergence);
        assert_eq!(p.min_manoeuvre_dwell_s, 8.0);
        let robust = |toml: &str| {
            Config::from_toml_str(toml)
                .unwrap()
                .tracker
                .hybrid_params(false)
                .unwrap()
                .noise
                .outlier_ratio
        };
        assert_eq!(robust(""), 5.0);
        assert_eq!(robust("[tracker.hybrid]\nnoise_outlier_ratio = 8.0\n"), 8.0);
        // The velocity innovation's running mean, for hybrid and imm alike.
        let centre = |toml: &str| {
            let t = Config::from_toml_str(toml).unwrap().tracker;
            let h = t.hybrid_params(false).unwrap().noise.velocity_centre_weight;
            assert_eq!(
                h,
                t.imm_tracker_params().unwrap().noise.velocity_centre_weight
            );
            h
        };
        assert_eq!(centre(""), 0.2);
        let window = |toml: &str| {
            let t = Config::from_toml_str(toml).unwrap().tracker;
            let h = t.hybrid_params(false).unwrap().noise;
            let imm = t.imm_tracker_params().unwrap().noise;
            assert_eq!(imm.window, super::IMM_NOISE_WINDOW_REPORTS);
            assert_eq!(imm.velocity_window, super::IMM_NOISE_WINDOW_REPORTS);
            (h.window, h.velocity_window, h.white_window)
        };
        assert_eq!(window(""), (30.0, 30.0, 100.0));
        assert_eq!(
            window("[tracker.hybrid]\nnoise_window_reports = 100\n"),
            (100.0, 30.0, 100.0)
        );
        assert_eq!(
            window("[tracker.hybrid]\nvelocity_noise_window_reports = 50\n"),
            (30.0, 50.0, 100.0)
        );
        assert_eq!(
            centre("[tracker.hybrid]\nnoise_velocity_centre_weight = 0\n"),
            0.0
        );
        assert_eq!(c.cv_params().unwrap().divergence_r, 2.0);
        // The transition matrix built from them: CV kept over 1 s with exp(-1/60).
        let imm = crate::track::imm::Imm::new(p.imm);
        assert!((imm.transition(1.0)[0][0] - (-1.0f64 / 60.0).exp()).abs() < 1e-15);
        // The gate's acceleration onset test and learned vertical noise (airliner preset).
        let g = Config::from_toml_str(
            "[tracker.gate]\npreset = \"airliner\"\naccel_onset_reports = 6\n\
             accel_onset_reference_reports = 20\nvrate_noise_window_reports = 0\n",
        )
        .unwrap()
        .tracker
        .hybrid_params(false)
        .unwrap()
        .gate;
        assert_eq!(
            (g.accel_onset_reports, g.accel_onset_reference_reports),
            (6, 20)
        );
        assert_eq!(g.vrate_noise_window_reports, 0.0);
        assert_eq!(g.longest_window(), 26);
        let gate_of = |toml: &str| {
            Config::from_toml_str(toml)
                .unwrap()
                .tracker
                .hybrid_params(false)
                .unwrap()
                .gate
        };
        // The first-report turn test: on by default at 2.9σ, another k, or 0 for off.
        let first = |toml: &str| gate_of(toml).first_report_turn_sigmas;
        assert_eq!(first(""), Some(2.9));
        assert_eq!(
            first("[tracker.gate]\nfirst_report_turn_sigmas = 3.5\n"),
            Some(3.5)
        );
        assert_eq!(
            first("[tracker.gate]\nfirst_report_turn_sigmas = 0\n"),
            None
        );
        assert_eq!(first("[tracker.gate]\npreset = \"paper002\"\n"), None);
        // The turn's end test: on by default at 3.5σ, another k, or 0 for off.
        let end = |toml: &str| gate_of(toml).turn_end_sigmas;
        assert_eq!(end(""), Some(3.5));
        assert_eq!(end("[tracker.gate]\nturn_end_sigmas = 3\n"), Some(3.0));
        assert_eq!(end("[tracker.gate]\nturn_end_sigmas = 0\n"), None);
        assert_eq!(end("[tracker.gate]\npreset = \"paper002\"\n"), None);
        // The acceleration's hold by its own line: on by default at 3σ, or 0 for off.
        let hold = |toml: &str| gate_of(toml).accel_hold_sigmas;
        assert_eq!(hold(""), Some(3.0));
        assert_eq!(hold("[tracker.gate]\naccel_hold_sigmas = 2.4\n"), Some(2.4));
        assert_eq!(hold("[tracker.gate]\naccel_hold_sigmas = 0\n"), None);
        assert_eq!(hold("[tracker.gate]\npreset = \"paper002\"\n"), None);
        // The climb or descent onset test: on by default at 4.5σ, or 0 for off.
        let onset = |toml: &str| gate_of(toml).vertical_onset_sigmas;
        assert_eq!(onset(""), Some(4.5));
        assert_eq!(
            onset("[tracker.gate]\nvertical_onset_sigmas = 4\n"),
            Some(4.0)
        );
        assert_eq!(onset("[tracker.gate]\nvertical_onset_sigmas = 0\n"), None);
        assert_eq!(onset("[tracker.gate]\npreset = \"paper002\"\n"), None);
        // Its altitude-confirmed form: on by default at 3σ, or 0 for off.
        let confirmed = |toml: &str| gate_of(toml).vertical_onset_altitude_sigmas;
        assert_eq!(confirmed(""), Some(3.0));
        assert_eq!(
            confirmed("[tracker.gate]\nvertical_onset_altitude_sigmas = 3.5\n"),
            Some(3.5)
        );
        assert_eq!(
            confirmed("[tracker.gate]\nvertical_onset_altitude_sigmas = 0\n"),
            None
        );
        assert_eq!(confirmed("[tracker.gate]\npreset = \"paper002\"\n"), None);
    }

    #[test]
    fn bad_tuning_names_its_key() {
        let cases = [
            ("[tracker.gate]\npreset = \"fast\"\n", "tracker.gate.preset"),
            ("[tracker.gate]\nturn_rate_deg_s = -1.0\n", "tracker.gate.turn_rate_deg_s"),
            ("[tracker.gate]\nturn_window_reports = 99\n", "tracker.gate.turn_window_reports"),
            ("[tracker.gate]\nrelease_ratio = 0.0\n", "tracker.gate.release_ratio"),
            (
                "[tracker.gate]\nfirst_report_turn_sigmas = -2.0\n",
                "tracker.gate.first_report_turn_sigmas",
            ),
            (
                "[tracker.gate]\nturn_end_sigmas = -1.0\n",
                "tracker.gate.turn_end_sigmas",
            ),
            (
                "[tracker.gate]\naccel_hold_sigmas = -1.0\n",
                "tracker.gate.accel_hold_sigmas",
            ),
            (
                "[tracker.gate]\nvertical_onset_altitude_sigmas = -1.0\n",
                "tracker.gate.vertical_onset_altitude_sigmas",
            ),
            (
                "[tracker.gate]\nvertical_onset_sigmas = -1.0\n",
                "tracker.gate.vertical_onset_sigmas",
            ),
            ("[tracker.gate]\nbogus = 1.0\n", "bogus"),
            (
                "[tracker.gate]\naccel_onset_reports = 20\naccel_onset_reference_reports = 20\n",
                "tracker.gate.accel_onset_reference_reports",
            ),
            (
                "[tracker.gate]\naccel_onset_reference_reports = 2\n",
                "tracker.gate.accel_onset_reference_reports",
            ),
            (
                "[tracker.gate]\nvrate_noise_window_reports = -1.0\n",
                "tracker.gate.vrate_noise_window_reports",
            ),
            (
                "[tracker.imm]\nmean_sojourn_s = { ch = 0.0 }\n",
                "tracker.imm.mean_sojourn_s.ch",
            ),
            (
                "[tracker.imm]\nswitch_weights = [[0.0, 1.0]]\n",
                "tracker.imm.switch_weights",
            ),
            (
                "[tracker.imm]\nswitch_weights = [[1,0,0,0,0,0],[4,0,1,1,1,1],[4,1,0,1,1,1],[4,1,1,0,1,1],[4,1,1,1,0,1],[4,1,1,1,1,0]]\n",
                "tracker.imm.switch_weights[0]",
            ),
            (
                "[tracker.imm]\nswitch_weights = [[0,1,1,1,1,1],[4,0,1,1,1,1],[4,1,0,-1,1,1],[4,1,1,0,1,1],[4,1,1,1,0,1],[4,1,1,1,1,0]]\n",
                "tracker.imm.switch_weights[2][3]",
            ),
            ("[tracker.divergence]\nconfirm = 0\n", "tracker.divergence.confirm"),
            ("[tracker.divergence]\nr = nan\n", "tracker.divergence.r"),
            (
                "[tracker.hybrid]\nturn_rate_limits_deg_s = [3.0, 1.0]\n",
                "tracker.hybrid.turn_rate_limits_deg_s",
            ),
            (
                "[tracker.hybrid]\nnoise_outlier_ratio = 0.5\n",
                "tracker.hybrid.noise_outlier_ratio",
            ),
            (
                "[tracker.hybrid]\nentry_probability = 1.5\n",
                "tracker.hybrid.entry_probability",
            ),
            (
                "[tracker.hybrid]\nnoise_velocity_centre_weight = 1.5\n",
                "tracker.hybrid.noise_velocity_centre_weight",
            ),
            (
                "[tracker.hybrid]\nnoise_window_reports = 0.5\n",
                "tracker.hybrid.noise_window_reports",
            ),
            (
                "[tracker.hybrid]\nvelocity_noise_window_reports = 0\n",
                "tracker.hybrid.velocity_noise_window_reports",
            ),
        ];
        crate::config::assert_refused_naming(&cases);
    }
}
