//! Configuration: `config/default.toml` documents every key; a file given with `--config`
//! overrides any subset of it. A bad value is refused at start with the key's name.

use crate::feed::Format;
use serde::Deserialize;
use std::path::{Path, PathBuf};

mod tracker;
pub use tracker::{DivergenceConfig, GateConfig, HybridConfig, ImmConfig, PerMode, TrackerConfig};

/// The defaults, embedded so the binary runs anywhere without the repository.
pub const DEFAULT_TOML: &str = include_str!("../../config/default.toml");

/// Why a configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// TOML syntax or a value of the wrong type; the message names the key.
    #[error("{0}")]
    Parse(String),
    /// A value of the right type outside its allowed range.
    #[error("config key `{key}`: {problem}")]
    Invalid { key: String, problem: String },
}

/// Largest `tracker.channel_capacity`, batches: a per-aircraft queue longer than this only
/// hides a pipeline that cannot keep up (and tokio refuses absurd capacities by panicking).
const MAX_CHANNEL_CAPACITY: usize = 65_536;

/// A value of the right type refused, naming its key.
fn bad(key: &str, problem: impl Into<String>) -> ConfigError {
    ConfigError::Invalid {
        key: key.to_string(),
        problem: problem.into(),
    }
}

/// The whole configuration.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub server: ServerConfig,
    /// Receiver location: the reference for surface CPR decoding before a track has one.
    #[serde(default)]
    pub receiver: Option<ReceiverConfig>,
    /// Live TCP feeds. Empty: the daemon replays [`ReplayConfig`] instead.
    #[serde(default)]
    pub feeds: Vec<FeedConfig>,
    pub replay: ReplayConfig,
    pub decode: DecodeConfig,
    pub cpr: CprConfigToml,
    pub tracker: TrackerConfig,
    pub pipeline: PipelineConfig,
}

/// How the pipeline behaves under load (`[pipeline]`).
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PipelineConfig {
    /// `backpressure` (default: a feed faster than the pipeline is slowed, nothing is lost)
    /// or `drop` (a full aircraft channel drops that aircraft's messages of the batch,
    /// counted and logged).
    pub overload: crate::daemon::router::Overload,
    /// `/healthz` answers 503 `degraded` while the ingest lag is above this, s; a warning
    /// is logged once per such episode.
    pub max_lag_s: f64,
    /// Frames decoded and queued for aircraft tasks, all aircraft together: the bound on the
    /// pipeline's queued memory (about 100 bytes a frame) whatever the fleet's size.
    pub max_queued_frames: usize,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ServerConfig {
    /// Address the HTTP API listens on.
    pub listen: String,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ReceiverConfig {
    pub lat_deg: f64,
    pub lon_deg: f64,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FeedConfig {
    /// A name for stats and logs.
    pub name: String,
    /// `host:port` of a readsb/dump1090 output (30005 Beast, 30002 AVR).
    pub addr: String,
    /// `beast` or `avr`.
    pub format: Format,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ReplayConfig {
    /// Recording to replay when no feed is configured; empty = the embedded recording.
    pub file: String,
    /// `auto` or one of the formats.
    pub format: String,
    /// Feed seconds per wall second; 0 = as fast as possible.
    pub speed: f64,
    /// Start again at the end (time keeps increasing across loops).
    #[serde(rename = "loop")]
    pub loop_: bool,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DecodeConfig {
    /// Repair single-bit errors in DF17/18 (counted apart from clean frames).
    pub fix_single_bit: bool,
    /// DF4/5/20/21 are accepted only from addresses seen in DF11/17/18 this recently, s.
    pub recent_address_s: f64,
    /// Feed time given to text frames without a timestamp: frames per second of feed time.
    pub nominal_rate_hz: f64,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CprConfigToml {
    /// Longest time between the even and odd frames of a global decode, s.
    pub pair_window_s: f64,
    /// Fastest plausible airborne ground speed, m/s.
    pub max_speed_mps: f64,
    /// Fastest plausible surface speed, m/s.
    pub max_surface_speed_mps: f64,
}

/// The tracker algorithms the daemon can run: `hybrid` (paper 002's threshold-gated CV
/// Kalman / IMM with paper 000's divergence suppression, gate tuned for airliners; the
/// default), `hybrid-paper002` (the same with the paper's printed gate thresholds),
/// `kalman-cv` (CV Kalman filter alone) and `imm` (the IMM alone); then the other papers':
/// `singer` (paper 000, with its divergence suppressor) and `singer-nosupp`, `cs-jerk`
/// (paper 001's improved CS-Jerk), `cs-jerk-plain` and `jerk`, `vsimm-srckf` (paper 003),
/// `imm-ckf` and `imm-srckf`.
pub const ALGORITHMS: &[&str] = &[
    "hybrid",
    "hybrid-paper002",
    "kalman-cv",
    "imm",
    "singer",
    "singer-nosupp",
    "cs-jerk",
    "cs-jerk-plain",
    "jerk",
    "vsimm-srckf",
    "imm-ckf",
    "imm-srckf",
];

impl Config {
    /// The embedded defaults.
    pub fn default_config() -> Result<Self, ConfigError> {
        Self::from_toml_str(DEFAULT_TOML)
    }

    /// Defaults overridden by `text` (any subset of keys), then validated.
    pub fn from_toml_str(text: &str) -> Result<Self, ConfigError> {
        let mut base: toml::Table = DEFAULT_TOML
            .parse()
            .map_err(|e: toml::de::Error| ConfigError::Parse(format!("embedded defaults: {e}")))?;
        let over: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| ConfigError::Parse(e.to_string()))?;
        merge(&mut base, over);
        let cfg: Config = toml::Value::Table(base)
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Parse(e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads and validates a file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml_str(&text)
    }

    /// Range checks that types cannot express.
    pub fn validate(&self) -> Result<(), ConfigError> {
        fn positive(key: &str, v: f64) -> Result<(), ConfigError> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(bad(key, format!("must be a finite number > 0, got {v}")))
            }
        }
        if self.server.listen.parse::<std::net::SocketAddr>().is_err() {
            return Err(bad(
                "server.listen",
                format!(
                    "{:?} is not an address like 127.0.0.1:8080",
                    self.server.listen
                ),
            ));
        }
        if let Some(r) = self.receiver {
            if !(-90.0..=90.0).contains(&r.lat_deg) {
                return Err(bad("receiver.lat_deg", "must be within -90..90"));
            }
            if !(-180.0..=180.0).contains(&r.lon_deg) {
                return Err(bad("receiver.lon_deg", "must be within -180..180"));
            }
        }
        for (i, f) in self.feeds.iter().enumerate() {
            if !matches!(f.format, Format::Beast | Format::Avr) {
                return Err(bad(
                    &format!("feeds[{i}].format"),
                    "a TCP feed is `beast` or `avr`",
                ));
            }
            if f.addr.is_empty() || !f.addr.contains(':') {
                return Err(bad(&format!("feeds[{i}].addr"), "expected host:port"));
            }
        }
        if self.replay.format != "auto" && self.replay.format.parse::<Format>().is_err() {
            return Err(bad(
                "replay.format",
                "expected auto, beast, avr, csv, iso or jsonl",
            ));
        }
        if !(self.replay.speed.is_finite() && self.replay.speed >= 0.0) {
            return Err(bad(
                "replay.speed",
                "must be >= 0 (0 = as fast as possible)",
            ));
        }
        positive("decode.recent_address_s", self.decode.recent_address_s)?;
        positive("decode.nominal_rate_hz", self.decode.nominal_rate_hz)?;
        positive("cpr.pair_window_s", self.cpr.pair_window_s)?;
        positive("cpr.max_speed_mps", self.cpr.max_speed_mps)?;
        positive("cpr.max_surface_speed_mps", self.cpr.max_surface_speed_mps)?;
        if !ALGORITHMS.contains(&self.tracker.algorithm.as_str()) {
            return Err(bad(
                "tracker.algorithm",
                format!(
                    "unknown {:?}; expected one of {}",
                    self.tracker.algorithm,
                    ALGORITHMS.join(", ")
                ),
            ));
        }
        positive("tracker.retire_after_s", self.tracker.retire_after_s)?;
        positive("tracker.cv_q_horizontal", self.tracker.cv_q_horizontal)?;
        positive("tracker.cv_q_vertical", self.tracker.cv_q_vertical)?;
        positive("tracker.max_gap_s", self.tracker.max_gap_s)?;
        for (i, h) in self.tracker.prediction_horizons_s.iter().enumerate() {
            if !(h.is_finite() && *h > 0.0 && *h <= 3600.0) {
                return Err(bad(
                    &format!("tracker.prediction_horizons_s[{i}]"),
                    format!("must be within (0, 3600] s, got {h}"),
                ));
            }
        }
        if self.tracker.channel_capacity == 0
            || self.tracker.channel_capacity > MAX_CHANNEL_CAPACITY
        {
            return Err(bad(
                "tracker.channel_capacity",
                format!("must be within 1..={MAX_CHANNEL_CAPACITY}"),
            ));
        }
        if !(self.pipeline.max_lag_s.is_finite()
            && self.pipeline.max_lag_s > 0.0
            && self.pipeline.max_lag_s <= 86_400.0)
        {
            return Err(bad(
                "pipeline.max_lag_s",
                format!(
                    "must be within (0, 86400] s, got {}",
                    self.pipeline.max_lag_s
                ),
            ));
        }

        self.tracker.validate_tuning()
    }
}

/// Deep merge of TOML tables: keys of `over` replace those of `base`; tables merge.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// Each config text is refused with a message naming its key (tests of this module and of
/// [`tracker`]).
#[cfg(test)]
fn assert_refused_naming(cases: &[(&str, &str)]) {
    for (text, key) in cases {
        let err = Config::from_toml_str(text).unwrap_err().to_string();
        assert!(
            err.contains(key),
            "{text:?} gave {err:?}, expected it to name {key}"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_parse_and_validate() {
        let c = Config::default_config().unwrap();
        assert_eq!(c.server.listen, "127.0.0.1:8080");
        assert!(c.feeds.is_empty());
        assert_eq!(c.tracker.algorithm, "hybrid");
        assert_eq!(c.decode.recent_address_s, 60.0);
    }

    #[test]
    fn override_is_partial() {
        let c = Config::from_toml_str("[tracker]\nretire_after_s = 42.5\n").unwrap();
        assert_eq!(c.tracker.retire_after_s, 42.5);
        assert_eq!(
            c.tracker.channel_capacity,
            Config::default_config().unwrap().tracker.channel_capacity
        );
    }

    #[test]
    fn bad_values_name_their_key() {
        let cases = [
            (
                "[tracker]\nretire_after_s = -1.0\n",
                "tracker.retire_after_s",
            ),
            ("[tracker]\nalgorithm = \"magic\"\n", "tracker.algorithm"),
            ("[server]\nlisten = \"nowhere\"\n", "server.listen"),
            (
                "[decode]\nrecent_address_s = \"soon\"\n",
                "recent_address_s",
            ),
            ("[decode]\nbogus_key = 1\n", "bogus_key"),
            (
                "[[feeds]]\nname = \"a\"\naddr = \"127.0.0.1:30005\"\nformat = \"csv\"\n",
                "feeds[0].format",
            ),
            (
                "[receiver]\nlat_deg = 91.0\nlon_deg = 0.0\n",
                "receiver.lat_deg",
            ),
            ("[pipeline]\noverload = \"panic\"\n", "overload"),
            ("[pipeline]\nmax_lag_s = 0.0\n", "pipeline.max_lag_s"),
            (
                "[tracker]\nchannel_capacity = 2305843009213693952\n",
                "tracker.channel_capacity",
            ),
        ];
        assert_refused_naming(&cases);
    }

    #[test]
    fn feeds_parse() {
        let c = Config::from_toml_str(
            "[[feeds]]\nname = \"readsb\"\naddr = \"127.0.0.1:30005\"\nformat = \"beast\"\n\
             [[feeds]]\nname = \"avr\"\naddr = \"127.0.0.1:30002\"\nformat = \"avr\"\n",
        )
        .unwrap();
        assert_eq!(c.feeds.len(), 2);
        assert_eq!(c.feeds[1].format, Format::Avr);
    }
}
