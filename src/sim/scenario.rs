//! Scenario files: what the aircraft do and how a receiver hears them (TOML, `serde`).
//!
//! A scenario names a reference point, global settings (duration, default seed, NACp, NACv,
//! reception probability, emission jitter, optional corruption and junk rates, report periods)
//! and one or more aircraft. Each aircraft starts somewhere (lat/lon/alt or east/north/up from
//! the reference), with an initial velocity, and flies a list of segments of the five flight
//! modes of paper 002 (ALGORITHMS.md §002), plus a per-axis jerk segment for paper 001.
//!
//! Every table refuses unknown keys, and [`Scenario::validate`] names the offending key in its
//! error, e.g. `aircraft[1].segments[2].turn_rate_dps: must be > 0`.

use super::truth::Trajectory;
use super::SimError;
use crate::decode::{Callsign, Icao};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::Deserialize;
use std::collections::HashSet;

/// Position and velocity reports per second of a DO-260B transponder: one every 0.5 s on
/// average (DO-260B §2.2.3.3.1.1: airborne position and velocity every 0.4-0.6 s).
pub const DEFAULT_REPORT_PERIOD_S: f64 = 0.5;
/// Truth sampling period when the scenario does not give one.
pub const DEFAULT_TRUTH_PERIOD_S: f64 = 0.5;
/// Latitudes beyond this are refused: the local-level integration of `truth` divides by
/// cos(lat), and CPR zones shrink to one near the poles. Nothing the papers need is there.
pub const MAX_ABS_LAT_DEG: f64 = 85.0;
/// Longest scenario: a week (Beast counters are 48 bits of 12 MHz, about 271 days).
pub const MAX_DURATION_S: f64 = 7.0 * 86_400.0;

/// A whole scenario file.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// The receiver's position and the origin of every `east_m`/`north_m` start.
    pub reference: Reference,
    pub settings: Settings,
    pub aircraft: Vec<AircraftSpec>,
}

/// A point on the WGS-84 ellipsoid (height 0): the receiver and the ENU origin.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Reference {
    pub lat_deg: f64,
    pub lon_deg: f64,
}

/// Global settings: timing, accuracy categories and the receiver's imperfections.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    /// Simulated time span, seconds (t runs from 0 to this).
    pub duration_s: f64,
    /// Seed used when the caller gives none (same seed, byte-identical outputs).
    #[serde(default)]
    pub seed: u64,
    /// Navigation accuracy category for position, 1..=11 (DO-260B §2.2.3.2.7.2.11,
    /// Table 2-71): sets the horizontal position noise and is sent in TC 31.
    pub nac_p: u8,
    /// Navigation accuracy category for velocity, 1..=4 (DO-260B §2.2.3.2.6.1.5,
    /// Table 2-22): sets the velocity noise and is sent in TC 19.
    pub nac_v: u8,
    /// Probability that the receiver hears a frame, in [0, 1].
    pub reception_probability: f64,
    /// Half-width of the uniform jitter added to every emission interval, seconds; 0.1 with
    /// a 0.5 s period gives DO-260B's 0.4-0.6 s. Must be less than half of every period.
    pub jitter_s: f64,
    /// Period of position and of velocity reports, seconds (papers 001 and 003 use 1 s and
    /// 2 s).
    #[serde(default = "default_report_period_s")]
    pub report_period_s: f64,
    /// Period of the regular truth samples, seconds (truth rows are also written at each
    /// received position or velocity report).
    #[serde(default = "default_truth_period_s")]
    pub truth_period_s: f64,
    /// Whether airborne velocity messages are sent at all (paper 001 measures positions only).
    #[serde(default = "default_true")]
    pub velocity_reports: bool,
    /// Probability that a received frame has 1 to 3 bits flipped (its CRC is not fixed).
    #[serde(default)]
    pub corrupt_frame_rate: f64,
    /// Probability that a run of 1 to 16 junk bytes precedes a frame in the Beast output
    /// (and a junk text line in the AVR output).
    #[serde(default)]
    pub junk_rate: f64,
    /// Whether the aircraft declares its accuracy: `false` sends no operational status
    /// (so no NACp reaches the receiver, which falls back on the position type code's NUCp)
    /// and NACv 0 in its velocity messages, as older transponders do. `nac_p`/`nac_v` then
    /// still set the noise. Default true.
    #[serde(default = "default_true")]
    pub declare_accuracy: bool,
    /// White horizontal position noise per axis, m, instead of the NACp's σ (EPU/2.4477):
    /// declared accuracy is a 95 % bound, real noise is often well inside it. 0..=10,000.
    #[serde(default)]
    pub position_noise_sigma_m: Option<f64>,
    /// White horizontal velocity noise per axis, m/s, instead of the NACv's σ. 0..=100.
    #[serde(default)]
    pub velocity_noise_sigma_mps: Option<f64>,
    /// Correlated GNSS position error: the stationary σ per horizontal axis of a
    /// first-order Gauss–Markov process, m (0 = none, the default). 0..=10,000.
    #[serde(default)]
    pub gnss_bias_sigma_m: f64,
    /// Its time constant τ, s: b(t + Δ) = e^(−Δ/τ) b(t) + σ √(1 − e^(−2Δ/τ)) w. Default 60 s
    /// (GNSS errors wander over tens of seconds to minutes). 0.1..=100,000.
    #[serde(default = "default_gnss_bias_tau_s")]
    pub gnss_bias_tau_s: f64,
    /// Barometric altitude error: the stationary σ of a first-order Gauss–Markov process
    /// added to the reported altitude before its 25-ft rounding, m (0 = none, the default:
    /// the altitude is the truth, rounded). An autopilot holds its altitude to a few feet,
    /// and one held at a step's edge makes the report flicker between two steps. 0..=1,000.
    #[serde(default)]
    pub baro_alt_error_sigma_m: f64,
    /// Its time constant τ, s. Default 10 s. 0.1..=100,000.
    #[serde(default = "default_baro_alt_error_tau_s")]
    pub baro_alt_error_tau_s: f64,
    /// Position/velocity validity offset, s: the position a frame carries is the truth this
    /// long before the frame is sent (a transponder's position latency; velocity reports
    /// are current). Default 0. -2..=2.
    #[serde(default)]
    pub position_validity_offset_s: f64,
    /// The same for velocities: the velocity a frame carries is the truth this long before
    /// the frame is sent. Real transponders send velocities about a second older than their
    /// positions (`afr34zg-cdg-tls.jsonl`: 1.07 s, `eval::latency`). Default 0. -2..=2.
    #[serde(default)]
    pub velocity_validity_offset_s: f64,
    /// Random position validity, s: each position a frame carries is the truth at a time
    /// τ ~ N(0, σ²) away from its validity time (after `position_validity_offset_s`), τ
    /// drawn per report: timing noise, which moves a report by −v τ along the track.
    /// Default 0. 0..=1.
    #[serde(default)]
    pub position_validity_jitter_s: f64,
    /// Bursts of stale positions: the mean interval between them, s (exponentially
    /// distributed; 0 = none, the default). In each burst `stale_position_reports` position
    /// reports in a row carry the position of `stale_position_age_s` earlier: what the real
    /// AFR34ZG recording shows about every 48 s (one to four positions 0.5-0.8 s behind
    /// the flight, innovations of NIS 200-600 where 2 is usual; `docs/evaluation.md`).
    /// 0 or 1..=100,000.
    #[serde(default)]
    pub stale_position_interval_s: f64,
    /// Position reports per burst. Default 2. 1..=20.
    #[serde(default = "default_stale_position_reports")]
    pub stale_position_reports: u32,
    /// How old a burst's positions are, s. Default 0.6. 0..=5.
    #[serde(default = "default_stale_position_age_s")]
    pub stale_position_age_s: f64,
}

fn default_stale_position_reports() -> u32 {
    2
}

fn default_stale_position_age_s() -> f64 {
    0.6
}

fn default_gnss_bias_tau_s() -> f64 {
    60.0
}

fn default_baro_alt_error_tau_s() -> f64 {
    10.0
}

fn default_report_period_s() -> f64 {
    DEFAULT_REPORT_PERIOD_S
}

fn default_truth_period_s() -> f64 {
    DEFAULT_TRUTH_PERIOD_S
}

fn default_true() -> bool {
    true
}

/// One simulated aircraft.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AircraftSpec {
    /// ICAO 24-bit address, six hex digits.
    pub icao: String,
    /// Up to 8 characters of A-Z, 0-9 and space (the 6-bit charset of DO-260B §2.2.3.2.5.2).
    pub callsign: String,
    pub start: Start,
    pub velocity: InitialVelocity,
    pub segments: Vec<Segment>,
}

/// Where an aircraft is at t = 0: either `lat_deg`/`lon_deg`/`alt_m`, or
/// `east_m`/`north_m`/`up_m` in the reference's tangent plane (`up_m` is the altitude).
#[derive(Clone, Copy, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Start {
    pub lat_deg: Option<f64>,
    pub lon_deg: Option<f64>,
    pub alt_m: Option<f64>,
    pub east_m: Option<f64>,
    pub north_m: Option<f64>,
    pub up_m: Option<f64>,
}

/// Velocity at t = 0: either `ground_speed_mps` + `track_deg` (true, clockwise from north),
/// or `ve_mps` + `vn_mps`; plus the vertical rate (`vertical_rate_mps` or `vu_mps`, default 0),
/// which must equal the first segment's (0 for the level modes CV, CA, CT and JERK).
#[derive(Clone, Copy, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InitialVelocity {
    pub ground_speed_mps: Option<f64>,
    pub track_deg: Option<f64>,
    pub vertical_rate_mps: Option<f64>,
    pub ve_mps: Option<f64>,
    pub vn_mps: Option<f64>,
    pub vu_mps: Option<f64>,
}

/// Turn direction of a coordinated turn, seen from above.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TurnDirection {
    /// Counter-clockwise: the track angle decreases.
    Left,
    /// Clockwise: the track angle increases.
    Right,
}

/// One piece of flight, selected by its `mode` key.
///
/// The level modes (CV, CA, CT, JERK) fly at constant altitude; CH and CHCA climb or descend
/// at `vertical_rate_mps`. Along-track modes keep the track angle (CV, CA, CH, CHCA) or turn it
/// at a constant rate at constant speed (CT).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(tag = "mode", deny_unknown_fields)]
pub enum Segment {
    /// Straight and level at constant velocity.
    #[serde(rename = "CV")]
    Cv { duration_s: f64 },
    /// Straight and level with constant along-track acceleration (speed must stay >= 0).
    #[serde(rename = "CA")]
    Ca { duration_s: f64, accel_mps2: f64 },
    /// Level coordinated turn at constant speed and constant turn rate (> 0).
    #[serde(rename = "CT")]
    Ct {
        duration_s: f64,
        turn_rate_dps: f64,
        direction: TurnDirection,
    },
    /// Climb (> 0) or descent (< 0) at constant ground velocity.
    #[serde(rename = "CH")]
    Ch {
        duration_s: f64,
        vertical_rate_mps: f64,
    },
    /// Climb or descent with constant along-track acceleration (take-off, landing).
    #[serde(rename = "CHCA")]
    Chca {
        duration_s: f64,
        vertical_rate_mps: f64,
        accel_mps2: f64,
    },
    /// Level flight with constant jerk on each horizontal axis (paper 001's profile); the
    /// acceleration carries over between consecutive JERK segments (a JERK with zero jerks
    /// holds the acceleration) and starts from zero after any other segment. Labelled CA,
    /// the closest of the five modes.
    #[serde(rename = "JERK")]
    Jerk {
        duration_s: f64,
        jerk_east_mps3: f64,
        jerk_north_mps3: f64,
    },
}

impl Segment {
    /// The segment's duration, seconds.
    pub fn duration_s(&self) -> f64 {
        match *self {
            Self::Cv { duration_s }
            | Self::Ca { duration_s, .. }
            | Self::Ct { duration_s, .. }
            | Self::Ch { duration_s, .. }
            | Self::Chca { duration_s, .. }
            | Self::Jerk { duration_s, .. } => duration_s,
        }
    }

    /// Vertical rate flown during the segment, m/s (0 for the level modes).
    pub fn vertical_rate_mps(&self) -> f64 {
        match *self {
            Self::Ch {
                vertical_rate_mps, ..
            }
            | Self::Chca {
                vertical_rate_mps, ..
            } => vertical_rate_mps,
            _ => 0.0,
        }
    }
}

/// An aircraft after validation: parsed identity and its trajectory.
#[derive(Clone, Debug)]
pub struct AircraftPlan {
    pub icao: Icao,
    pub callsign: Callsign,
    pub trajectory: Trajectory,
}

fn invalid(key: impl Into<String>, reason: impl Into<String>) -> SimError {
    SimError::Invalid {
        key: key.into(),
        reason: reason.into(),
    }
}

/// `value` must be finite and within `range` (inclusive), or an error naming `key`.
fn check_range(key: &str, value: f64, lo: f64, hi: f64) -> Result<(), SimError> {
    if !value.is_finite() || value < lo || value > hi {
        return Err(invalid(
            key,
            format!("must be within [{lo}, {hi}], got {value}"),
        ));
    }
    Ok(())
}

/// `value` must be finite and > 0, or an error naming `key`.
pub(crate) fn check_positive(key: &str, value: f64) -> Result<(), SimError> {
    if !value.is_finite() || value <= 0.0 {
        return Err(invalid(key, format!("must be > 0, got {value}")));
    }
    Ok(())
}

/// `value` must be finite, or an error naming `key`.
pub(crate) fn check_finite(key: &str, value: f64) -> Result<(), SimError> {
    if !value.is_finite() {
        return Err(invalid(
            key,
            format!("must be a finite number, got {value}"),
        ));
    }
    Ok(())
}

/// A callsign as sent in TC 1-4: 1 to 8 characters of A-Z, 0-9 and space, padded with spaces.
pub fn parse_callsign(s: &str) -> Option<Callsign> {
    if s.is_empty() || s.len() > 8 {
        return None;
    }
    let mut out = [b' '; 8];
    for (slot, b) in out.iter_mut().zip(s.bytes()) {
        if !(b.is_ascii_uppercase() || b.is_ascii_digit() || b == b' ') {
            return None;
        }
        *slot = b;
    }
    Some(Callsign(out))
}

impl Scenario {
    /// Parses and validates a scenario from TOML text.
    ///
    /// A file whose only table is `[fleet]` ([`FleetFile`]) is a generated fleet: the
    /// generator and its seed stand in the file, not a thousand aircraft.
    pub fn from_toml_str(text: &str) -> Result<Self, SimError> {
        let parse_error = |e: toml::de::Error| SimError::Parse {
            message: e.to_string(),
        };
        let table: toml::Table = toml::from_str(text).map_err(parse_error)?;
        if table.contains_key("fleet") {
            let file: FleetFile = toml::from_str(text).map_err(parse_error)?;
            let scenario = fleet(&file.fleet)?;
            scenario.validate()?;
            return Ok(scenario);
        }
        let scenario: Scenario = toml::from_str(text).map_err(parse_error)?;
        scenario.validate()?;
        Ok(scenario)
    }

    /// Checks every value and builds every trajectory once; the first problem found is
    /// returned with the key that holds it.
    pub fn validate(&self) -> Result<(), SimError> {
        self.plan().map(|_| ())
    }

    /// Validates and returns the aircraft ready to fly.
    pub fn plan(&self) -> Result<Vec<AircraftPlan>, SimError> {
        self.validate_globals()?;
        let mut seen: Vec<(u32, usize)> = Vec::with_capacity(self.aircraft.len());
        let mut plans = Vec::with_capacity(self.aircraft.len());
        for (i, ac) in self.aircraft.iter().enumerate() {
            let icao: Icao = ac
                .icao
                .parse()
                .map_err(|e: String| invalid(format!("aircraft[{i}].icao"), e))?;
            if icao.0 == 0 {
                return Err(invalid(
                    format!("aircraft[{i}].icao"),
                    "000000 is not an address",
                ));
            }
            if let Some((_, j)) = seen.iter().find(|(a, _)| *a == icao.0) {
                return Err(invalid(
                    format!("aircraft[{i}].icao"),
                    format!("{icao} is already used by aircraft[{j}]"),
                ));
            }
            seen.push((icao.0, i));
            let callsign = parse_callsign(&ac.callsign).ok_or_else(|| {
                invalid(
                    format!("aircraft[{i}].callsign"),
                    format!(
                        "{:?}: must be 1 to 8 characters of A-Z, 0-9 and space",
                        ac.callsign
                    ),
                )
            })?;
            let trajectory = Trajectory::build(ac, i, &self.reference, self.settings.duration_s)?;
            plans.push(AircraftPlan {
                icao,
                callsign,
                trajectory,
            });
        }
        Ok(plans)
    }

    fn validate_globals(&self) -> Result<(), SimError> {
        let r = &self.reference;
        check_range(
            "reference.lat_deg",
            r.lat_deg,
            -MAX_ABS_LAT_DEG,
            MAX_ABS_LAT_DEG,
        )?;
        check_range("reference.lon_deg", r.lon_deg, -180.0, 180.0)?;
        let s = &self.settings;
        check_positive("settings.duration_s", s.duration_s)?;
        check_range("settings.duration_s", s.duration_s, 0.0, MAX_DURATION_S)?;
        if !(1..=11).contains(&s.nac_p) {
            return Err(invalid(
                "settings.nac_p",
                format!(
                    "must be 1..=11, got {} (0 means unknown accuracy: no noise to simulate)",
                    s.nac_p
                ),
            ));
        }
        if !(1..=4).contains(&s.nac_v) {
            return Err(invalid(
                "settings.nac_v",
                format!(
                    "must be 1..=4, got {} (0 means unknown accuracy: no noise to simulate)",
                    s.nac_v
                ),
            ));
        }
        check_range(
            "settings.reception_probability",
            s.reception_probability,
            0.0,
            1.0,
        )?;
        check_range(
            "settings.corrupt_frame_rate",
            s.corrupt_frame_rate,
            0.0,
            1.0,
        )?;
        check_range("settings.junk_rate", s.junk_rate, 0.0, 1.0)?;
        if let Some(v) = s.position_noise_sigma_m {
            check_range("settings.position_noise_sigma_m", v, 0.0, 10_000.0)?;
        }
        if let Some(v) = s.velocity_noise_sigma_mps {
            check_range("settings.velocity_noise_sigma_mps", v, 0.0, 100.0)?;
        }
        check_range(
            "settings.gnss_bias_sigma_m",
            s.gnss_bias_sigma_m,
            0.0,
            10_000.0,
        )?;
        check_range(
            "settings.gnss_bias_tau_s",
            s.gnss_bias_tau_s,
            0.1,
            100_000.0,
        )?;
        check_range(
            "settings.baro_alt_error_sigma_m",
            s.baro_alt_error_sigma_m,
            0.0,
            1_000.0,
        )?;
        check_range(
            "settings.baro_alt_error_tau_s",
            s.baro_alt_error_tau_s,
            0.1,
            100_000.0,
        )?;
        check_range(
            "settings.position_validity_offset_s",
            s.position_validity_offset_s,
            -2.0,
            2.0,
        )?;
        check_range(
            "settings.velocity_validity_offset_s",
            s.velocity_validity_offset_s,
            -2.0,
            2.0,
        )?;
        check_range(
            "settings.position_validity_jitter_s",
            s.position_validity_jitter_s,
            0.0,
            1.0,
        )?;
        if s.stale_position_interval_s != 0.0 {
            check_range(
                "settings.stale_position_interval_s",
                s.stale_position_interval_s,
                1.0,
                100_000.0,
            )?;
        }
        check_range(
            "settings.stale_position_reports",
            f64::from(s.stale_position_reports),
            1.0,
            20.0,
        )?;
        check_range(
            "settings.stale_position_age_s",
            s.stale_position_age_s,
            0.0,
            5.0,
        )?;
        check_positive("settings.report_period_s", s.report_period_s)?;
        check_positive("settings.truth_period_s", s.truth_period_s)?;
        check_range("settings.truth_period_s", s.truth_period_s, 1e-3, f64::MAX)?;
        check_range(
            "settings.report_period_s",
            s.report_period_s,
            1e-3,
            f64::MAX,
        )?;
        check_finite("settings.jitter_s", s.jitter_s)?;
        let shortest = s.report_period_s.min(super::receiver::STATUS_PERIOD_S);
        if s.jitter_s < 0.0 || s.jitter_s >= shortest / 2.0 {
            return Err(invalid(
                "settings.jitter_s",
                format!(
                    "must be >= 0 and < {} (half the shortest emission period), got {}",
                    shortest / 2.0,
                    s.jitter_s
                ),
            ));
        }
        if self.aircraft.is_empty() {
            return Err(invalid("aircraft", "at least one aircraft is needed"));
        }
        Ok(())
    }
}

/// A scenario file that names a generated fleet: `[fleet]` with the keys of [`FleetSpec`]
/// (`reference = { lat_deg, lon_deg }`, `aircraft`, `radius_km`, `duration_s`, `seed`).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FleetFile {
    pub fleet: FleetSpec,
}

/// What the fleet generator needs: how many aircraft, where, for how long.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FleetSpec {
    pub reference: Reference,
    /// Number of aircraft.
    pub aircraft: usize,
    /// Starts are uniform over a disc of this radius around the reference, km.
    pub radius_km: f64,
    pub duration_s: f64,
    /// Seed of the generator (and the default seed of the scenario it makes).
    pub seed: u64,
    /// Relative frequency of each flight mode among the segments; default: one fifth each.
    #[serde(default)]
    pub mode_weights: ModeWeights,
}

/// Relative weights of the five modes in a generated fleet's segments (`[fleet]
/// mode_weights = { cv = .., ca = .., ct = .., ch = .., chca = .. }`), any non-negative
/// numbers with a positive sum; a missing mode weighs 1.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModeWeights {
    #[serde(default = "one")]
    pub cv: f64,
    #[serde(default = "one")]
    pub ca: f64,
    #[serde(default = "one")]
    pub ct: f64,
    #[serde(default = "one")]
    pub ch: f64,
    #[serde(default = "one")]
    pub chca: f64,
}

fn one() -> f64 {
    1.0
}

impl Default for ModeWeights {
    fn default() -> Self {
        Self {
            cv: 1.0,
            ca: 1.0,
            ct: 1.0,
            ch: 1.0,
            chca: 1.0,
        }
    }
}

impl ModeWeights {
    fn as_array(&self) -> [f64; 5] {
        [self.cv, self.ca, self.ct, self.ch, self.chca]
    }

    /// Index 0..5 (CV, CA, CT, CH, CHCA) drawn with these weights. Equal weights draw
    /// exactly as the generator always did (`gen_range(0..5)`), so existing fleets keep their
    /// bytes.
    fn draw(&self, rng: &mut StdRng) -> usize {
        let w = self.as_array();
        if w.iter().all(|&x| x == w[0]) {
            // i32, as the generator always drew it (a usize draw takes other random bits).
            return rng.gen_range(0i32..5).unsigned_abs() as usize;
        }
        let total: f64 = w.iter().sum();
        let mut u = rng.gen::<f64>() * total;
        for (i, x) in w.iter().enumerate() {
            if u < *x {
                return i;
            }
            u -= x;
        }
        4
    }
}

/// Bounds the fleet generator keeps its aircraft within (an airliner's envelope).
const FLEET_SPEED_MPS: (f64, f64) = (90.0, 260.0);
const FLEET_ALT_M: (f64, f64) = (1_500.0, 12_500.0);
const FLEET_MAX_ACCEL_MPS2: f64 = 1.5;
const FLEET_MAX_VRATE_MPS: f64 = 15.0;
const FLEET_TURN_RATE_DPS: (f64, f64) = (0.5, 3.0);
const FLEET_SEGMENT_S: (f64, f64) = (20.0, 120.0);
/// Largest fleet: 100,000 aircraft (addresses are drawn among 16.7 M, callsigns number
/// SIM00000-SIM99999).
pub const MAX_FLEET: usize = 100_000;

/// N aircraft on random routes for load tests: random starts within the radius, random
/// speeds, tracks and altitudes, and random sequences of the five modes that stay within an
/// airliner's envelope (90-260 m/s, 1.5-12.5 km, |a| <= 1.5 m/s^2, |vz| <= 15 m/s, turns of
/// 0.5-3 deg/s). Distinct ICAO addresses, callsigns `SIM00000`... Receiver settings: NACp 9,
/// NACv 2, 90 % reception, DO-260B's 0.4-0.6 s intervals.
///
/// The spec is checked first (errors name `fleet.aircraft`, `fleet.radius_km`, ...): at most
/// [`MAX_FLEET`] aircraft, so that distinct addresses always exist.
pub fn fleet(spec: &FleetSpec) -> Result<Scenario, SimError> {
    if spec.aircraft == 0 || spec.aircraft > MAX_FLEET {
        return Err(invalid(
            "fleet.aircraft",
            format!("must be 1..={MAX_FLEET}, got {}", spec.aircraft),
        ));
    }
    check_range("fleet.radius_km", spec.radius_km, 0.0, 2_000.0)?;
    check_positive("fleet.duration_s", spec.duration_s)?;
    check_range("fleet.duration_s", spec.duration_s, 0.0, MAX_DURATION_S)?;
    check_range(
        "fleet.reference.lat_deg",
        spec.reference.lat_deg,
        -MAX_ABS_LAT_DEG,
        MAX_ABS_LAT_DEG,
    )?;
    check_range(
        "fleet.reference.lon_deg",
        spec.reference.lon_deg,
        -180.0,
        180.0,
    )?;
    let w = spec.mode_weights.as_array();
    if w.iter().any(|x| !(x.is_finite() && *x >= 0.0)) || w.iter().sum::<f64>() <= 0.0 {
        return Err(invalid(
            "fleet.mode_weights",
            format!("must be finite, >= 0, with a positive sum, got {w:?}"),
        ));
    }
    let mut rng = StdRng::seed_from_u64(spec.seed);
    let mut used = HashSet::with_capacity(spec.aircraft);
    let mut aircraft = Vec::with_capacity(spec.aircraft);
    for i in 0..spec.aircraft {
        let icao = loop {
            let a: u32 = rng.gen_range(1..0xFF_FFFF);
            if used.insert(a) {
                break a;
            }
        };
        let r_m = spec.radius_km * 1000.0 * rng.gen::<f64>().sqrt();
        let bearing = rng.gen_range(0.0..std::f64::consts::TAU);
        let mut speed = rng.gen_range(120.0..250.0);
        let mut alt = rng.gen_range(3_000.0..12_000.0);
        let track_deg = rng.gen_range(0.0..360.0);
        let alt0 = alt;
        let mut segments = Vec::new();
        let mut total_s = 0.0;
        while total_s < spec.duration_s {
            let d = rng.gen_range(FLEET_SEGMENT_S.0..FLEET_SEGMENT_S.1);
            total_s += d;
            let accel = |rng: &mut StdRng, speed: &mut f64| {
                let target = rng.gen_range(FLEET_SPEED_MPS.0..FLEET_SPEED_MPS.1);
                let a = ((target - *speed) / d).clamp(-FLEET_MAX_ACCEL_MPS2, FLEET_MAX_ACCEL_MPS2);
                *speed += a * d;
                a
            };
            let climb = |rng: &mut StdRng, alt: &mut f64| {
                let target = rng.gen_range(FLEET_ALT_M.0..FLEET_ALT_M.1);
                let vz = ((target - *alt) / d).clamp(-FLEET_MAX_VRATE_MPS, FLEET_MAX_VRATE_MPS);
                *alt += vz * d;
                vz
            };
            let seg = match spec.mode_weights.draw(&mut rng) {
                0 => Segment::Cv { duration_s: d },
                1 => Segment::Ca {
                    duration_s: d,
                    accel_mps2: accel(&mut rng, &mut speed),
                },
                2 => Segment::Ct {
                    duration_s: d,
                    turn_rate_dps: rng.gen_range(FLEET_TURN_RATE_DPS.0..FLEET_TURN_RATE_DPS.1),
                    direction: if rng.gen::<bool>() {
                        TurnDirection::Left
                    } else {
                        TurnDirection::Right
                    },
                },
                3 => Segment::Ch {
                    duration_s: d,
                    vertical_rate_mps: climb(&mut rng, &mut alt),
                },
                _ => Segment::Chca {
                    duration_s: d,
                    vertical_rate_mps: climb(&mut rng, &mut alt),
                    accel_mps2: accel(&mut rng, &mut speed),
                },
            };
            segments.push(seg);
        }
        let first_vz = segments.first().map_or(0.0, Segment::vertical_rate_mps);
        aircraft.push(AircraftSpec {
            icao: format!("{icao:06x}"),
            callsign: format!("SIM{i:05}"),
            start: Start {
                east_m: Some(r_m * bearing.sin()),
                north_m: Some(r_m * bearing.cos()),
                up_m: Some(alt0),
                ..Start::default()
            },
            velocity: InitialVelocity {
                ground_speed_mps: Some(speed_at_start(&segments, speed)),
                track_deg: Some(track_deg),
                vertical_rate_mps: Some(first_vz),
                ..InitialVelocity::default()
            },
            segments,
        });
    }
    Ok(Scenario {
        reference: spec.reference,
        settings: Settings {
            duration_s: spec.duration_s,
            seed: spec.seed,
            nac_p: 9,
            nac_v: 2,
            reception_probability: 0.9,
            jitter_s: 0.1,
            report_period_s: DEFAULT_REPORT_PERIOD_S,
            truth_period_s: DEFAULT_TRUTH_PERIOD_S,
            velocity_reports: true,
            corrupt_frame_rate: 0.0,
            junk_rate: 0.0,
            declare_accuracy: true,
            position_noise_sigma_m: None,
            velocity_noise_sigma_mps: None,
            gnss_bias_sigma_m: 0.0,
            gnss_bias_tau_s: default_gnss_bias_tau_s(),
            baro_alt_error_sigma_m: 0.0,
            baro_alt_error_tau_s: default_baro_alt_error_tau_s(),
            position_validity_offset_s: 0.0,
            velocity_validity_offset_s: 0.0,
            position_validity_jitter_s: 0.0,
            stale_position_interval_s: 0.0,
            stale_position_reports: default_stale_position_reports(),
            stale_position_age_s: default_stale_position_age_s(),
        },
        aircraft,
    })
}

/// The generator tracks the speed forward from the start; recover the start speed by
/// undoing the along-track accelerations (exact: speed changes only in CA and CHCA).
fn speed_at_start(segments: &[Segment], final_speed: f64) -> f64 {
    segments.iter().fold(final_speed, |v, s| match *s {
        Segment::Ca {
            duration_s,
            accel_mps2,
        }
        | Segment::Chca {
            duration_s,
            accel_mps2,
            ..
        } => v - accel_mps2 * duration_s,
        _ => v,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
[reference]
lat_deg = 43.6
lon_deg = 1.37

[settings]
duration_s = 100.0
nac_p = 9
nac_v = 2
reception_probability = 1.0
jitter_s = 0.1

[[aircraft]]
icao = "abc123"
callsign = "TEST1"
start = { east_m = 0.0, north_m = 0.0, up_m = 3000.0 }
velocity = { ground_speed_mps = 100.0, track_deg = 90.0 }
segments = [
  { mode = "CV", duration_s = 50.0 },
  { mode = "CT", duration_s = 50.0, turn_rate_dps = 3.0, direction = "left" },
]
"#;

    fn err_of(text: &str) -> String {
        match Scenario::from_toml_str(text) {
            Ok(_) => String::from("<accepted>"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn minimal_scenario_parses_with_defaults() {
        let s = Scenario::from_toml_str(MINIMAL).unwrap();
        assert_eq!(s.settings.seed, 0);
        assert_eq!(s.settings.report_period_s, 0.5);
        assert_eq!(s.settings.truth_period_s, 0.5);
        assert!(s.settings.velocity_reports);
        assert_eq!(s.settings.corrupt_frame_rate, 0.0);
        assert_eq!(s.aircraft.len(), 1);
        assert_eq!(
            s.aircraft[0].segments[1],
            Segment::Ct {
                duration_s: 50.0,
                turn_rate_dps: 3.0,
                direction: TurnDirection::Left
            }
        );
        let plans = s.plan().unwrap();
        assert_eq!(plans[0].icao, Icao(0xabc123));
        assert_eq!(plans[0].callsign.0, *b"TEST1   ");
    }

    #[test]
    fn errors_name_the_offending_key() {
        let cases = [
            (
                MINIMAL.replace("turn_rate_dps = 3.0", "turn_rate_dps = 0.0"),
                "aircraft[0].segments[1].turn_rate_dps: must be > 0, got 0",
            ),
            (
                MINIMAL.replace("turn_rate_dps = 3.0", "turn_rate_dps = -2.0"),
                "aircraft[0].segments[1].turn_rate_dps: must be > 0, got -2",
            ),
            (
                MINIMAL.replace("\"abc123\"", "\"abc12\""),
                "aircraft[0].icao: \"abc12\" is not an ICAO address (6 hex digits)",
            ),
            (
                MINIMAL.replace("\"TEST1\"", "\"test1\""),
                "aircraft[0].callsign: \"test1\": must be 1 to 8 characters of A-Z, 0-9 and space",
            ),
            (
                MINIMAL.replace("nac_p = 9", "nac_p = 12"),
                "settings.nac_p: must be 1..=11, got 12 (0 means unknown accuracy: no noise to simulate)",
            ),
            (
                MINIMAL.replace("reception_probability = 1.0", "reception_probability = 1.5"),
                "settings.reception_probability: must be within [0, 1], got 1.5",
            ),
            (
                MINIMAL.replace("jitter_s = 0.1", "jitter_s = 0.1\ngnss_bias_sigma_m = -1.0"),
                "settings.gnss_bias_sigma_m: must be within [0, 10000], got -1",
            ),
            (
                MINIMAL.replace("jitter_s = 0.1", "jitter_s = 0.1\ngnss_bias_tau_s = 0.0"),
                "settings.gnss_bias_tau_s: must be within [0.1, 100000], got 0",
            ),
            (
                MINIMAL.replace(
                    "jitter_s = 0.1",
                    "jitter_s = 0.1\nposition_validity_offset_s = 2.5",
                ),
                "settings.position_validity_offset_s: must be within [-2, 2], got 2.5",
            ),
            (
                MINIMAL.replace("jitter_s = 0.1", "jitter_s = 0.1\nposition_noise_sigma_m = nan"),
                "settings.position_noise_sigma_m: must be within [0, 10000], got NaN",
            ),
            (
                MINIMAL.replace(
                    "jitter_s = 0.1",
                    "jitter_s = 0.1\nvelocity_noise_sigma_mps = 101.0",
                ),
                "settings.velocity_noise_sigma_mps: must be within [0, 100], got 101",
            ),
            (
                MINIMAL.replace("jitter_s = 0.1", "jitter_s = 0.25"),
                "settings.jitter_s: must be >= 0 and < 0.25 (half the shortest emission period), got 0.25",
            ),
            (
                MINIMAL.replace("duration_s = 100.0", "duration_s = 101.0"),
                "aircraft[0].segments: durations sum to 100 s, less than settings.duration_s = 101 s",
            ),
            (
                MINIMAL.replace("{ mode = \"CV\", duration_s = 50.0 }", "{ mode = \"CA\", duration_s = 50.0, accel_mps2 = -3.0 }"),
                "aircraft[0].segments[0].accel_mps2: ground speed would fall to -50 m/s by the end of the segment (it must stay >= 0)",
            ),
            (
                MINIMAL.replace("track_deg = 90.0 }", "track_deg = 90.0, vertical_rate_mps = 5.0 }"),
                "aircraft[0].velocity.vertical_rate_mps: 5 m/s differs from the first segment's vertical rate (0 m/s; CV, CA, CT and JERK are level)",
            ),
            (
                MINIMAL.replace("up_m = 3000.0 }", "up_m = 3000.0, lat_deg = 1.0 }"),
                "aircraft[0].start: give either lat_deg, lon_deg and alt_m, or east_m, north_m and up_m",
            ),
            (
                MINIMAL.replace("track_deg = 90.0 }", "track_deg = 90.0, ve_mps = 3.0 }"),
                "aircraft[0].velocity: give either ground_speed_mps and track_deg, or ve_mps and vn_mps",
            ),
        ];
        for (text, want) in cases {
            assert_eq!(err_of(&text), want);
        }
    }

    #[test]
    fn duplicate_addresses_are_refused() {
        let two = format!(
            "{MINIMAL}{}",
            &MINIMAL[MINIMAL.find("[[aircraft]]").unwrap()..]
        );
        assert_eq!(
            err_of(&two),
            "aircraft[1].icao: abc123 is already used by aircraft[0]"
        );
    }

    #[test]
    fn unknown_keys_are_refused_everywhere() {
        for (from, to) in [
            ("jitter_s = 0.1", "jitter_s = 0.1\nnacp = 3"),
            ("lon_deg = 1.37", "lon_deg = 1.37\nalt_m = 3.0"),
            (
                "direction = \"left\"",
                "direction = \"left\", accel_mps2 = 1.0",
            ),
            (
                "callsign = \"TEST1\"",
                "callsign = \"TEST1\"\nsquawk = 1200",
            ),
        ] {
            let e = err_of(&MINIMAL.replace(from, to));
            assert!(e.contains("unknown field"), "{from}: {e}");
        }
        let e = err_of(&MINIMAL.replace("direction = \"left\"", "direction = \"up\""));
        assert!(e.contains("unknown variant `up`"), "{e}");
        let e = err_of(&MINIMAL.replace("mode = \"CV\"", "mode = \"CX\""));
        assert!(e.contains("unknown variant `CX`"), "{e}");
    }

    #[test]
    fn callsign_charset() {
        assert_eq!(parse_callsign("KLM1023").unwrap().0, *b"KLM1023 ");
        assert_eq!(parse_callsign("A B").unwrap().0, *b"A B     ");
        assert!(parse_callsign("").is_none());
        assert!(parse_callsign("ABCDEFGHI").is_none());
        assert!(parse_callsign("AB-1").is_none());
        assert!(parse_callsign("ÄB").is_none());
    }

    #[test]
    fn fleet_is_valid_distinct_and_within_envelope() {
        let spec = FleetSpec {
            reference: Reference {
                lat_deg: 50.0,
                lon_deg: 8.0,
            },
            aircraft: 200,
            radius_km: 150.0,
            duration_s: 1800.0,
            seed: 7,
            mode_weights: ModeWeights::default(),
        };
        let s = fleet(&spec).unwrap();
        let plans = s.plan().unwrap();
        assert_eq!(plans.len(), 200);
        let addrs: HashSet<u32> = plans.iter().map(|p| p.icao.0).collect();
        assert_eq!(addrs.len(), 200);
        for ac in &s.aircraft {
            let e = ac.start.east_m.unwrap();
            let n = ac.start.north_m.unwrap();
            assert!(e.hypot(n) <= 150_000.0);
            let sum: f64 = ac.segments.iter().map(Segment::duration_s).sum();
            assert!(sum >= 1800.0);
            // Walk the speed and altitude: they must stay in the stated envelope.
            let mut v = ac.velocity.ground_speed_mps.unwrap();
            let mut h = ac.start.up_m.unwrap();
            assert!((120.0..250.0).contains(&v), "{v}");
            for seg in &ac.segments {
                if let Segment::Ca { accel_mps2, .. } | Segment::Chca { accel_mps2, .. } = *seg {
                    assert!(accel_mps2.abs() <= 1.5);
                    v += accel_mps2 * seg.duration_s();
                }
                if let Segment::Ct { turn_rate_dps, .. } = *seg {
                    assert!((0.5..3.0).contains(&turn_rate_dps));
                }
                assert!(seg.vertical_rate_mps().abs() <= 15.0);
                h += seg.vertical_rate_mps() * seg.duration_s();
                assert!((89.999..=260.001).contains(&v), "{v}");
                assert!((1_499.999..=12_500.001).contains(&h), "{h}");
            }
        }
        // Same seed, same fleet.
        assert_eq!(fleet(&spec).unwrap(), s);
        let bad = |f: FleetSpec| fleet(&f).unwrap_err().to_string();
        assert_eq!(
            bad(FleetSpec {
                aircraft: 0,
                ..spec
            }),
            "fleet.aircraft: must be 1..=100000, got 0"
        );
        assert_eq!(
            bad(FleetSpec {
                radius_km: f64::NAN,
                ..spec
            }),
            "fleet.radius_km: must be within [0, 2000], got NaN"
        );
        assert_eq!(
            bad(FleetSpec {
                duration_s: -1.0,
                ..spec
            }),
            "fleet.duration_s: must be > 0, got -1"
        );
        assert!(bad(FleetSpec {
            mode_weights: ModeWeights {
                cv: -1.0,
                ..ModeWeights::default()
            },
            ..spec
        })
        .starts_with("fleet.mode_weights: "));
    }

    #[test]
    fn fleet_mode_weights_shape_the_segments() {
        let spec = FleetSpec {
            reference: Reference {
                lat_deg: 50.0,
                lon_deg: 8.0,
            },
            aircraft: 300,
            radius_km: 150.0,
            duration_s: 3600.0,
            seed: 3,
            mode_weights: ModeWeights {
                cv: 6.0,
                ca: 1.0,
                ct: 2.0,
                ch: 1.0,
                chca: 0.0,
            },
        };
        let s = fleet(&spec).unwrap();
        let mut time = [0.0; 5];
        for seg in s.aircraft.iter().flat_map(|a| &a.segments) {
            let i = match seg {
                Segment::Cv { .. } => 0,
                Segment::Ca { .. } => 1,
                Segment::Ct { .. } => 2,
                Segment::Ch { .. } => 3,
                Segment::Chca { .. } => 4,
                _ => unreachable!("the generator makes the five modes only"),
            };
            time[i] += seg.duration_s();
        }
        let total: f64 = time.iter().sum();
        // Segment lengths do not depend on the mode: time shares follow the weights.
        for (share, want) in time
            .iter()
            .map(|t| t / total)
            .zip([0.6, 0.1, 0.2, 0.1, 0.0])
        {
            assert!((share - want).abs() < 0.02, "{time:?}");
        }
    }
}
