//! `[server.stream]`, `[server.readsb]` and `[history]`: the event stream, the readsb/tar1090
//! view and the per-aircraft trails (issue 12). `config/default.toml` documents every key.

use super::{bad, int_within, seconds_within, ConfigError};
use serde::Deserialize;

/// `GET /api/v1/stream`, the server-sent event stream.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StreamConfig {
    /// `track` events a client gets per aircraft per second at most; updates in between are
    /// coalesced (the latest is sent when the aircraft's turn comes).
    pub max_updates_per_s: f64,
    /// A `stats` event (the `/api/v1/stats` JSON) every this many seconds.
    pub stats_period_s: f64,
    /// A comment line after this many seconds without an event, so proxies and clients see
    /// the connection alive, s.
    pub keepalive_s: f64,
    /// Stream clients at once; one more is answered 503 `{"error"}`.
    pub max_clients: usize,
    /// Bytes of events a client may have waiting in the server for its socket; past it the
    /// client's events stop being made, and it catches up from the current state (`lagged`).
    pub client_buffer_bytes: usize,
}

/// `/data/aircraft.json`, `/data/receiver.json` and the tar1090 page.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ReadsbConfig {
    /// A copy of tar1090's `html/` directory, served at `/tar1090/` (with `/tar1090/data/`
    /// answered by the daemon); empty: not served.
    pub tar1090_dir: String,
    /// `refresh` of `receiver.json`: how often tar1090 fetches `aircraft.json`, ms.
    pub refresh_ms: u64,
}

/// `[history]`: the per-aircraft trail of `GET /api/v1/tracks/{icao}/history`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HistoryConfig {
    /// Minutes of feed time a trail covers (older points are dropped).
    pub window_minutes: f64,
    /// Points a trail holds at most (0: no trails). Points are at least
    /// `window_minutes * 60 / max_points` seconds apart.
    pub max_points: usize,
}

impl Default for HistoryConfig {
    /// `config/default.toml`'s values: 10 minutes, 600 points.
    fn default() -> Self {
        Self {
            window_minutes: 10.0,
            max_points: 600,
        }
    }
}

impl HistoryConfig {
    /// The trail's span, s.
    pub fn window_s(&self) -> f64 {
        self.window_minutes * 60.0
    }

    /// Shortest feed time between two points of a trail, s.
    pub fn min_interval_s(&self) -> f64 {
        if self.max_points == 0 {
            f64::INFINITY
        } else {
            self.window_s() / self.max_points as f64
        }
    }
}

/// Most points a trail may be configured to hold: 36,000 points of about 5 bytes are
/// 180 KB per aircraft (more for a trail of jumps across the globe), already far past what
/// a map draws.
pub const MAX_HISTORY_POINTS: usize = 36_000;

impl StreamConfig {
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
        seconds_within(
            "server.stream.max_updates_per_s",
            self.max_updates_per_s,
            0.01,
            100.0,
        )?;
        seconds_within(
            "server.stream.stats_period_s",
            self.stats_period_s,
            0.1,
            3600.0,
        )?;
        seconds_within("server.stream.keepalive_s", self.keepalive_s, 1.0, 3600.0)?;
        int_within("server.stream.max_clients", self.max_clients, 1, 65_536)?;
        int_within(
            "server.stream.client_buffer_bytes",
            self.client_buffer_bytes,
            16_384,
            64 << 20,
        )
    }
}

impl ReadsbConfig {
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
        int_within("server.readsb.refresh_ms", self.refresh_ms, 100, 60_000)?;
        if !self.tar1090_dir.is_empty() && !std::path::Path::new(&self.tar1090_dir).is_dir() {
            return Err(bad(
                "server.readsb.tar1090_dir",
                format!(
                    "{:?} is not a directory (a copy of tar1090's html/)",
                    self.tar1090_dir
                ),
            ));
        }
        Ok(())
    }
}

impl HistoryConfig {
    pub(super) fn validate(&self) -> Result<(), ConfigError> {
        seconds_within("history.window_minutes", self.window_minutes, 0.1, 1440.0)?;
        int_within("history.max_points", self.max_points, 0, MAX_HISTORY_POINTS)
    }
}
