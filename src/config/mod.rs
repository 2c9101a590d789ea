//! Configuration: `config/default.toml` documents every key; a file given with `--config`
//! overrides any subset of it. A bad value is refused at start with the key's name.

use crate::feed::Format;
use serde::Deserialize;
use std::path::{Path, PathBuf};

mod cluster;
pub use cluster::{ClusterConfig, Role, MAX_PARTITIONS};
mod map;
pub use map::MapConfig;
mod output;
pub use output::{AsterixConfig, BBox, JsonlConfig, OutputConfig, SbsConfig, SystemRef};
mod tracker;
mod web;
pub use tracker::{DivergenceConfig, GateConfig, HybridConfig, ImmConfig, PerMode, TrackerConfig};
pub use web::{HistoryConfig, ReadsbConfig, StreamConfig, MAX_HISTORY_POINTS};

/// The defaults, embedded so the binary runs anywhere without the repository.
pub const DEFAULT_TOML: &str = include_str!("../../config/default.toml");

/// Why a configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// (The I/O error is part of the message, not a separate cause: said once.)
    #[error("cannot read {path}: {error}")]
    Read {
        path: PathBuf,
        error: std::io::Error,
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

/// Slowest replay speed, feed seconds per wall second: a day of feed time in ~3 years.
/// Anything slower is a typo, and its waits overflow timers.
pub const MIN_SPEED: f64 = 1e-3;
/// Fastest replay speed other than 0 (as fast as possible).
pub const MAX_SPEED: f64 = 1e6;

/// A finite number within `lo..=hi` (the range named in the refusal).
/// The longest `decode.duplicate_window_s`, s: a transponder sends each extended squitter
/// type at intervals of 0.4 s or more (position and velocity every 0.4-0.6 s, DO-260B), so
/// a wider window could take a real repeat of an unchanged report for a copy.
pub const MAX_DUPLICATE_WINDOW_S: f64 = 0.35;

fn seconds_within(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), ConfigError> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(bad(
            key,
            format!("must be within {lo}..={hi}, got {}", Short(v)),
        ))
    }
}

/// A number for a message: plain when short, in scientific notation when plain would be
/// long (f64::MAX is 309 digits plain).
pub struct Short(pub f64);

impl std::fmt::Display for Short {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = self.0.abs();
        if self.0.is_finite() && a != 0.0 && !(1e-4..1e9).contains(&a) {
            write!(f, "{:e}", self.0)
        } else {
            write!(f, "{}", self.0)
        }
    }
}

/// An integer within `lo..=hi`.
fn int_within<T: PartialOrd + std::fmt::Display>(
    key: &str,
    v: T,
    lo: T,
    hi: T,
) -> Result<(), ConfigError> {
    if v >= lo && v <= hi {
        Ok(())
    } else {
        Err(bad(key, format!("must be within {lo}..={hi}, got {v}")))
    }
}

/// `host:port` with a port in 1..=65535 and a non-empty host (a name, an IPv4 address or a
/// bracketed IPv6 one); resolved only when the feed connects.
fn check_host_port(addr: &str) -> Result<(), String> {
    let (host, port) = addr
        .rsplit_once(':')
        .ok_or_else(|| format!("{addr:?}: expected host:port"))?;
    let host = host.trim_start_matches('[').trim_end_matches(']');
    if host.is_empty() || host.chars().any(char::is_whitespace) {
        return Err(format!("{addr:?}: expected host:port"));
    }
    match port.parse::<u16>() {
        Ok(p) if p > 0 => Ok(()),
        _ => Err(format!("{addr:?}: the port must be within 1..=65535")),
    }
}

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
    /// `[output.*]`: ASTERIX CAT062, SBS and JSON-lines outputs, each off when absent.
    #[serde(default)]
    pub output: OutputConfig,
    /// `[map]`: the live map page at `/`.
    pub map: MapConfig,
    /// `[history]`: the per-aircraft trails.
    pub history: HistoryConfig,
    /// `[cluster]`: this process's part in a cluster over NATS JetStream; absent, the
    /// daemon is one process with no bus.
    #[serde(default)]
    pub cluster: Option<ClusterConfig>,
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
    /// Connections open at once; one more is refused with 503.
    pub max_connections: usize,
    /// Time to send a request head (and the keep-alive idle limit), s.
    pub header_read_timeout_s: f64,
    /// Longest a response write may make no progress, s.
    pub write_timeout_s: f64,
    /// Longest a handler may take, s.
    pub request_timeout_s: f64,
    /// Requests served on one connection before it is closed.
    pub max_requests_per_connection: u64,
    /// Largest request head, bytes.
    pub max_header_bytes: usize,
    /// Time open connections get to finish at shutdown, s.
    pub shutdown_grace_s: f64,
    /// Longest a cached `/api/v1/tracks` body is served, ms (0: never cached).
    pub tracks_cache_ms: u64,
    /// gzip level of the cached `/api/v1/tracks` body for clients that accept gzip (0: none).
    pub tracks_gzip_level: u32,
    /// Worker threads of the server's runtime.
    pub threads: usize,
    /// Niceness added to the server's bulk lane (sending large bodies, building them).
    pub nice: i32,
    /// Niceness added to the server's request lane (accepting, reading requests, small
    /// answers).
    pub request_nice: i32,
    /// `[server.stream]`: the server-sent event stream.
    pub stream: StreamConfig,
    /// `[server.readsb]`: readsb's JSON and the tar1090 page.
    pub readsb: ReadsbConfig,
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
    /// A connected feed that sends nothing for this long is reported down and reconnected,
    /// s. A Beast or AVR feed of a working receiver is never silent for seconds.
    #[serde(default = "default_silence_timeout_s")]
    pub silence_timeout_s: f64,
}

/// `feeds[].silence_timeout_s` when not given, s: a receiver that hears nothing for 30 s
/// is broken, or its antenna is.
pub const DEFAULT_SILENCE_TIMEOUT_S: f64 = 30.0;

pub fn default_silence_timeout_s() -> f64 {
    DEFAULT_SILENCE_TIMEOUT_S
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ReplayConfig {
    /// Recording to replay when no feed is configured; empty = the embedded recording.
    pub file: String,
    /// Which embedded recording (`lax`, `afr34zg`) when `file` is empty.
    pub embedded: String,
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
    /// Learn the real clock of a recording whose frames carry no time from its aircraft
    /// (`feed::pace`) before replaying it.
    pub fit_untimed_clock: bool,
    /// A position or velocity report equal to the aircraft's last one of its kind within
    /// this many seconds of feed time is one transmission heard twice (two receivers merged
    /// into one feed), not given to the tracker again; 0 keeps every copy. Below 0.4 s, the
    /// shortest interval at which a transponder repeats an extended squitter.
    pub duplicate_window_s: f64,
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
        let text = std::fs::read_to_string(path).map_err(|error| ConfigError::Read {
            path: path.to_path_buf(),
            error,
        })?;
        Self::from_toml_str(&text)
    }

    /// Range checks that types cannot express: every number has a range, and a value
    /// outside it is refused naming its key, so no arithmetic on a configured value can
    /// overflow, panic or wait forever.
    pub fn validate(&self) -> Result<(), ConfigError> {
        fn positive(key: &str, v: f64) -> Result<(), ConfigError> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(bad(
                    key,
                    format!("must be a finite number > 0, got {}", Short(v)),
                ))
            }
        }
        let s = &self.server;
        if s.listen.parse::<std::net::SocketAddr>().is_err() {
            return Err(bad(
                "server.listen",
                format!("{:?} is not an address like 127.0.0.1:8080", s.listen),
            ));
        }
        int_within("server.max_connections", s.max_connections, 1, 65_536)?;
        seconds_within(
            "server.header_read_timeout_s",
            s.header_read_timeout_s,
            0.1,
            3600.0,
        )?;
        seconds_within("server.write_timeout_s", s.write_timeout_s, 0.1, 3600.0)?;
        seconds_within("server.request_timeout_s", s.request_timeout_s, 0.1, 3600.0)?;
        int_within(
            "server.max_requests_per_connection",
            s.max_requests_per_connection,
            1,
            1_000_000,
        )?;
        int_within("server.max_header_bytes", s.max_header_bytes, 8192, 1 << 20)?;
        seconds_within("server.shutdown_grace_s", s.shutdown_grace_s, 0.0, 600.0)?;
        int_within("server.tracks_cache_ms", s.tracks_cache_ms, 0, 10_000)?;
        int_within("server.tracks_gzip_level", s.tracks_gzip_level, 0, 9)?;
        int_within("server.threads", s.threads, 1, 64)?;
        int_within("server.nice", s.nice, 0, 19)?;
        int_within("server.request_nice", s.request_nice, 0, 19)?;
        s.stream.validate()?;
        s.readsb.validate()?;
        self.history.validate()?;
        if let Some(r) = self.receiver {
            if !(-90.0..=90.0).contains(&r.lat_deg) {
                return Err(bad("receiver.lat_deg", "must be within -90..90"));
            }
            if !(-180.0..=180.0).contains(&r.lon_deg) {
                return Err(bad("receiver.lon_deg", "must be within -180..180"));
            }
        }
        let mut names = std::collections::HashSet::new();
        for (i, f) in self.feeds.iter().enumerate() {
            if f.name.trim().is_empty() {
                return Err(bad(&format!("feeds[{i}].name"), "must not be empty"));
            }
            if !names.insert(f.name.as_str()) {
                return Err(bad(
                    &format!("feeds[{i}].name"),
                    format!("{:?} names two feeds; each needs its own name", f.name),
                ));
            }
            if !matches!(f.format, Format::Beast | Format::Avr) {
                return Err(bad(
                    &format!("feeds[{i}].format"),
                    "a TCP feed is `beast` or `avr`",
                ));
            }
            check_host_port(&f.addr).map_err(|p| bad(&format!("feeds[{i}].addr"), p))?;
            seconds_within(
                &format!("feeds[{i}].silence_timeout_s"),
                f.silence_timeout_s,
                0.5,
                86_400.0,
            )?;
        }
        if crate::daemon::source::embedded(&self.replay.embedded).is_none() {
            let names: Vec<&str> = crate::daemon::source::EMBEDDED
                .iter()
                .map(|e| e.name)
                .collect();
            return Err(bad(
                "replay.embedded",
                format!(
                    "no embedded recording {:?}; expected one of {}",
                    self.replay.embedded,
                    names.join(", ")
                ),
            ));
        }
        if self.replay.format != "auto" && self.replay.format.parse::<Format>().is_err() {
            return Err(bad(
                "replay.format",
                "expected auto, beast, avr, csv, iso or jsonl",
            ));
        }
        if self.replay.speed != 0.0 {
            seconds_within("replay.speed", self.replay.speed, MIN_SPEED, MAX_SPEED).map_err(
                |_| {
                    bad(
                        "replay.speed",
                        format!(
                            "must be 0 (as fast as possible) or within {MIN_SPEED}..={MAX_SPEED}, got {}",
                            Short(self.replay.speed)
                        ),
                    )
                },
            )?;
        }
        seconds_within(
            "decode.recent_address_s",
            self.decode.recent_address_s,
            1e-3,
            86_400.0,
        )?;
        if self.decode.duplicate_window_s != 0.0 {
            seconds_within(
                "decode.duplicate_window_s",
                self.decode.duplicate_window_s,
                1e-6,
                MAX_DUPLICATE_WINDOW_S,
            )?;
        }
        seconds_within(
            "decode.nominal_rate_hz",
            self.decode.nominal_rate_hz,
            1e-3,
            1e7,
        )?;
        seconds_within("cpr.pair_window_s", self.cpr.pair_window_s, 1e-3, 3600.0)?;
        seconds_within("cpr.max_speed_mps", self.cpr.max_speed_mps, 1.0, 100_000.0)?;
        seconds_within(
            "cpr.max_surface_speed_mps",
            self.cpr.max_surface_speed_mps,
            1.0,
            1000.0,
        )?;
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
        seconds_within(
            "tracker.retire_after_s",
            self.tracker.retire_after_s,
            1e-3,
            86_400.0,
        )?;
        positive("tracker.cv_q_horizontal", self.tracker.cv_q_horizontal)?;
        positive(
            "tracker.steady_q_horizontal",
            self.tracker.steady_q_horizontal,
        )?;
        positive("tracker.cv_q_vertical", self.tracker.cv_q_vertical)?;
        seconds_within("tracker.max_gap_s", self.tracker.max_gap_s, 1e-3, 86_400.0)?;
        for (i, h) in self.tracker.prediction_horizons_s.iter().enumerate() {
            if !(h.is_finite() && *h > 0.0 && *h <= 3600.0) {
                return Err(bad(
                    &format!("tracker.prediction_horizons_s[{i}]"),
                    format!("must be within (0, 3600] s, got {}", Short(*h)),
                ));
            }
        }
        int_within(
            "tracker.channel_capacity",
            self.tracker.channel_capacity,
            1,
            MAX_CHANNEL_CAPACITY,
        )?;
        if !(self.pipeline.max_lag_s.is_finite()
            && self.pipeline.max_lag_s > 0.0
            && self.pipeline.max_lag_s <= 86_400.0)
        {
            return Err(bad(
                "pipeline.max_lag_s",
                format!(
                    "must be within (0, 86400] s, got {}",
                    Short(self.pipeline.max_lag_s)
                ),
            ));
        }
        int_within(
            "pipeline.max_queued_frames",
            self.pipeline.max_queued_frames,
            1024,
            1 << 24,
        )?;

        self.output.validate()?;
        self.map.validate()?;
        if let Some(c) = &self.cluster {
            c.validate()?;
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
        assert_eq!(c.decode.duplicate_window_s, 0.2);
        // 0 keeps every copy.
        let off = Config::from_toml_str("[decode]\nduplicate_window_s = 0.0\n").unwrap();
        assert_eq!(off.decode.duplicate_window_s, 0.0);
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
                "[decode]\nduplicate_window_s = 0.5\n",
                "decode.duplicate_window_s",
            ),
            (
                "[tracker.imm]\nvelocity_lag_s = -0.5\n",
                "tracker.imm.velocity_lag_s",
            ),
            (
                "[decode]\nduplicate_window_s = -0.1\n",
                "decode.duplicate_window_s",
            ),
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
            // Issue 11, row 6: values that panicked, overflowed or waited forever.
            ("[replay]\nspeed = 1e-300\n", "replay.speed"),
            ("[replay]\nspeed = 1e300\n", "replay.speed"),
            ("[tracker]\nretire_after_s = 2e19\n", "tracker.retire_after_s"),
            ("[tracker]\nmax_gap_s = 1e308\n", "tracker.max_gap_s"),
            ("[pipeline]\nmax_queued_frames = 0\n", "pipeline.max_queued_frames"),
            (
                "[pipeline]\nmax_queued_frames = 9223372036854775807\n",
                "pipeline.max_queued_frames",
            ),
            ("[decode]\nnominal_rate_hz = 1e-300\n", "decode.nominal_rate_hz"),
            ("[cpr]\npair_window_s = inf\n", "cpr.pair_window_s"),
            ("[server]\nmax_connections = 0\n", "server.max_connections"),
            ("[server]\nheader_read_timeout_s = 1e30\n", "server.header_read_timeout_s"),
            ("[server]\nwrite_timeout_s = nan\n", "server.write_timeout_s"),
            ("[server]\nmax_header_bytes = 100\n", "server.max_header_bytes"),
            ("[server]\nshutdown_grace_s = -1.0\n", "server.shutdown_grace_s"),
            ("[server]\nthreads = 0\n", "server.threads"),
            ("[server]\nnice = 20\n", "server.nice"),
            ("[server]\nrequest_nice = -1\n", "server.request_nice"),
            ("[server]\ntracks_cache_ms = 99999999\n", "server.tracks_cache_ms"),
            ("[server]\ntracks_gzip_level = 10\n", "server.tracks_gzip_level"),
            // Issue 12: the stream, the trails, readsb's view.
            ("[server.stream]\nmax_updates_per_s = 0.0\n", "server.stream.max_updates_per_s"),
            ("[server.stream]\nmax_updates_per_s = nan\n", "server.stream.max_updates_per_s"),
            ("[server.stream]\nstats_period_s = 0.01\n", "server.stream.stats_period_s"),
            ("[server.stream]\nkeepalive_s = 1e9\n", "server.stream.keepalive_s"),
            ("[server.stream]\nmax_clients = 0\n", "server.stream.max_clients"),
            ("[server.stream]\nclient_buffer_bytes = 10\n", "server.stream.client_buffer_bytes"),
            ("[server.stream]\nbogus = 1\n", "bogus"),
            ("[replay]\nembedded = \"cdg\"\n", "replay.embedded"),
            ("[history]\nwindow_minutes = 0.0\n", "history.window_minutes"),
            ("[history]\nwindow_minutes = inf\n", "history.window_minutes"),
            ("[history]\nmax_points = 100000000\n", "history.max_points"),
            ("[server.readsb]\nrefresh_ms = 5\n", "server.readsb.refresh_ms"),
            (
                "[server.readsb]\ntar1090_dir = \"/nonexistent/tar1090\"\n",
                "server.readsb.tar1090_dir",
            ),
            // Row 12: feeds refused at start, not failing forever after.
            (
                "[[feeds]]\nname = \"a\"\naddr = \"127.0.0.1:99999\"\nformat = \"beast\"\n",
                "feeds[0].addr",
            ),
            (
                "[[feeds]]\nname = \"a\"\naddr = \":30005\"\nformat = \"beast\"\n",
                "feeds[0].addr",
            ),
            (
                "[[feeds]]\nname = \"\"\naddr = \"127.0.0.1:30005\"\nformat = \"beast\"\n",
                "feeds[0].name",
            ),
            (
                "[[feeds]]\nname = \"a\"\naddr = \"h:1\"\nformat = \"beast\"\n\
                 [[feeds]]\nname = \"a\"\naddr = \"h:2\"\nformat = \"avr\"\n",
                "feeds[1].name",
            ),
            (
                "[[feeds]]\nname = \"a\"\naddr = \"h:1\"\nformat = \"beast\"\nsilence_timeout_s = 0.0\n",
                "feeds[0].silence_timeout_s",
            ),
        ];
        assert_refused_naming(&cases);
    }

    #[test]
    fn huge_numbers_are_printed_short() {
        let err = Config::from_toml_str("[tracker]\nretire_after_s = 1.7976931348623157e308\n")
            .unwrap_err()
            .to_string();
        assert!(err.ends_with("got 1.7976931348623157e308"), "{err}");
        assert_eq!(Short(2.5).to_string(), "2.5");
        assert_eq!(Short(1e-300).to_string(), "1e-300");
        assert_eq!(Short(f64::INFINITY).to_string(), "inf");
    }

    #[test]
    fn feed_addresses_of_every_kind_are_accepted() {
        for addr in [
            "127.0.0.1:30005",
            "localhost:30005",
            "[::1]:30005",
            "feeder.example:1",
        ] {
            let text = format!("[[feeds]]\nname = \"a\"\naddr = \"{addr}\"\nformat = \"beast\"\n");
            let c = Config::from_toml_str(&text).unwrap_or_else(|e| panic!("{addr}: {e}"));
            assert_eq!(c.feeds[0].silence_timeout_s, DEFAULT_SILENCE_TIMEOUT_S);
        }
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
