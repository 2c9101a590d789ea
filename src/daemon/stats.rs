//! The daemon's counters: one set of Prometheus metrics that `/metrics` encodes and
//! `/api/v1/stats` reads, so the two can never disagree.
//!
//! Hot paths never touch these per frame: the router flushes its local decode counters once
//! per batch, aircraft tasks once per processed batch.

use crate::decode::DecodeStats;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

type Labels = Vec<(&'static str, String)>;

/// Every counter of the daemon.
pub struct Stats {
    registry: Registry,
    /// Frames handed on by the feeds.
    pub frames_in: Counter,
    /// Frames by downlink format (all frames the decoder saw).
    pub frames_by_df: Family<Labels, Counter>,
    /// DF17/18 frames by type code.
    pub frames_by_tc: Family<Labels, Counter>,
    /// Frames the decoder rejected, by reason.
    pub frames_skipped: Family<Labels, Counter>,
    /// DF17/18 frames whose single-bit error the CRC repaired.
    pub crc_fixed: Counter,
    /// Positions decoded and handed to the tracker.
    pub positions_accepted: Counter,
    /// Positions refused (implausible jump, NL mismatch, ...), by reason.
    pub positions_rejected: Family<Labels, Counter>,
    /// Tracker updates done and refused.
    pub track_updates: Counter,
    pub track_errors: Family<Labels, Counter>,
    /// Aircraft tasks alive now, spawned, retired.
    pub tracks_active: Gauge,
    pub tracks_created: Counter,
    pub tracks_retired: Counter,
    /// Batches not delivered because an aircraft task's channel was full.
    pub channel_drops: Counter,
    /// Messages lost with those batches.
    pub channel_dropped_messages: Counter,
    /// Set once a replay has been read to its end and every aircraft task has drained.
    pub replay_finished: std::sync::atomic::AtomicBool,
    /// Highest feed time seen, s (f64 bits).
    feed_time_bits: AtomicU64,
    /// Feed status snapshots, by feed name (set by the daemon at start).
    feeds: Mutex<Vec<std::sync::Arc<crate::feed::tcp::FeedStatus>>>,
}

impl Default for Stats {
    fn default() -> Self {
        Self::new()
    }
}

impl Stats {
    /// All metrics, registered under the `adsb_` prefix.
    pub fn new() -> Self {
        let mut registry = Registry::with_prefix("adsb");
        let s = Self {
            frames_in: Counter::default(),
            frames_by_df: Family::default(),
            frames_by_tc: Family::default(),
            frames_skipped: Family::default(),
            crc_fixed: Counter::default(),
            positions_accepted: Counter::default(),
            positions_rejected: Family::default(),
            track_updates: Counter::default(),
            track_errors: Family::default(),
            tracks_active: Gauge::default(),
            tracks_created: Counter::default(),
            tracks_retired: Counter::default(),
            channel_drops: Counter::default(),
            channel_dropped_messages: Counter::default(),
            replay_finished: std::sync::atomic::AtomicBool::new(false),
            feed_time_bits: AtomicU64::new(0f64.to_bits()),
            feeds: Mutex::new(Vec::new()),
            registry: Registry::default(),
        };
        registry.register(
            "frames",
            "Frames received from the feeds",
            s.frames_in.clone(),
        );
        registry.register(
            "frames_by_df",
            "Frames by downlink format",
            s.frames_by_df.clone(),
        );
        registry.register(
            "frames_by_type_code",
            "DF17/18 frames by type code",
            s.frames_by_tc.clone(),
        );
        registry.register(
            "frames_skipped",
            "Frames the decoder refused, by reason",
            s.frames_skipped.clone(),
        );
        registry.register(
            "crc_fixed",
            "DF17/18 frames repaired by single-bit correction",
            s.crc_fixed.clone(),
        );
        registry.register(
            "positions_accepted",
            "CPR positions handed to the tracker",
            s.positions_accepted.clone(),
        );
        registry.register(
            "positions_rejected",
            "CPR positions refused, by reason",
            s.positions_rejected.clone(),
        );
        registry.register("track_updates", "Tracker updates", s.track_updates.clone());
        registry.register(
            "track_errors",
            "Tracker steps refused, by reason",
            s.track_errors.clone(),
        );
        registry.register(
            "tracks_active",
            "Aircraft tracked now",
            s.tracks_active.clone(),
        );
        registry.register(
            "tracks_created",
            "Aircraft tasks spawned",
            s.tracks_created.clone(),
        );
        registry.register(
            "tracks_retired",
            "Aircraft tasks retired after silence",
            s.tracks_retired.clone(),
        );
        registry.register(
            "channel_drops",
            "Batches dropped because an aircraft channel was full",
            s.channel_drops.clone(),
        );
        registry.register(
            "channel_dropped_messages",
            "Messages lost in dropped batches",
            s.channel_dropped_messages.clone(),
        );
        Self { registry, ..s }
    }

    /// Adds a decoder's counters accumulated since the last flush (`delta` = now - before).
    pub fn add_decode(&self, now: &DecodeStats, before: &DecodeStats) {
        add_deltas(&self.frames_by_df, "df", &now.by_df, &before.by_df);
        add_deltas(&self.frames_by_tc, "tc", &now.by_tc, &before.by_tc);
        for ((reason, a), (_, b)) in skip_counts(now).into_iter().zip(skip_counts(before)) {
            if a > b {
                self.frames_skipped
                    .get_or_create(&vec![("reason", reason.to_string())])
                    .inc_by(a - b);
            }
        }
        if now.crc_fixed > before.crc_fixed {
            self.crc_fixed.inc_by(now.crc_fixed - before.crc_fixed);
        }
    }

    /// Records the feed time reached (monotonic max).
    pub fn observe_feed_time(&self, t_s: f64) {
        let mut cur = self.feed_time_bits.load(Ordering::Relaxed);
        while f64::from_bits(cur) < t_s {
            match self.feed_time_bits.compare_exchange_weak(
                cur,
                t_s.to_bits(),
                Ordering::Relaxed,
                Ordering::Relaxed,
            ) {
                Ok(_) => break,
                Err(actual) => cur = actual,
            }
        }
    }

    /// Highest feed time seen, s.
    pub fn feed_time_s(&self) -> f64 {
        f64::from_bits(self.feed_time_bits.load(Ordering::Relaxed))
    }

    /// Registers a feed's status for /healthz and the stats.
    pub fn add_feed(&self, status: std::sync::Arc<crate::feed::tcp::FeedStatus>) {
        if let Ok(mut f) = self.feeds.lock() {
            f.push(status);
        }
    }

    /// Status of every registered feed.
    pub fn feeds(&self) -> Vec<crate::feed::tcp::FeedStatusSnapshot> {
        self.feeds
            .lock()
            .map(|f| f.iter().map(|s| s.snapshot()).collect())
            .unwrap_or_default()
    }

    /// Prometheus text exposition of every metric.
    pub fn encode_prometheus(&self) -> String {
        let mut out = String::new();
        // Encoding into a String cannot fail (fmt::Write for String is infallible).
        let _ = prometheus_client::encoding::text::encode(&mut out, &self.registry);
        out
    }

    /// The JSON view of `/api/v1/stats`.
    pub fn snapshot(&self) -> StatsSnapshot {
        let numbers = || (0..32).map(|n: u32| n.to_string());
        let by_df = read_family(&self.frames_by_df, "df", numbers());
        let by_tc = read_family(&self.frames_by_tc, "tc", numbers());
        let read = |f: &Family<Labels, Counter>, key: &'static str, names: &[&str]| {
            read_family(f, key, names.iter().map(|n| n.to_string()))
        };
        StatsSnapshot {
            feed_time: self.feed_time_s(),
            replay_finished: self.replay_finished.load(Ordering::Acquire),
            frames: self.frames_in.get(),
            frames_by_df: by_df,
            frames_by_type_code: by_tc,
            frames_skipped: read(&self.frames_skipped, "reason", SKIP_REASONS),
            crc_fixed: self.crc_fixed.get(),
            positions_accepted: self.positions_accepted.get(),
            positions_rejected: read(&self.positions_rejected, "reason", POSITION_REJECT_REASONS),
            track_updates: self.track_updates.get(),
            track_errors: read(&self.track_errors, "reason", TRACK_ERROR_REASONS),
            tracks_active: self.tracks_active.get(),
            tracks_created: self.tracks_created.get(),
            tracks_retired: self.tracks_retired.get(),
            channel_drops: self.channel_drops.get(),
            channel_dropped_messages: self.channel_dropped_messages.get(),
            feeds: self.feeds(),
        }
    }
}

/// The non-zero counters of `family` among the label values `names` of `key`.
fn read_family(
    family: &Family<Labels, Counter>,
    key: &'static str,
    names: impl Iterator<Item = String>,
) -> BTreeMap<String, u64> {
    names
        .filter_map(|n| {
            let v = family.get_or_create(&vec![(key, n.clone())]).get();
            (v > 0).then_some((n, v))
        })
        .collect()
}

/// Adds `now - before`, element by element, to the counters of `family` labelled `key` = index.
fn add_deltas(family: &Family<Labels, Counter>, key: &'static str, now: &[u64], before: &[u64]) {
    for (i, (a, b)) in now.iter().zip(before).enumerate() {
        if a > b {
            family
                .get_or_create(&vec![(key, i.to_string())])
                .inc_by(a - b);
        }
    }
}

/// Reasons under which the decoder's skips are counted (see [`crate::decode::Skip`]).
pub const SKIP_REASONS: &[&str] = &[
    "mode_ac",
    "wrong_length",
    "bad_crc",
    "unknown_address",
    "unsupported_df",
    "unsupported_cf",
];

/// The decoder's skip counters, labelled as [`SKIP_REASONS`].
fn skip_counts(s: &DecodeStats) -> [(&'static str, u64); 6] {
    [
        ("mode_ac", s.mode_ac),
        ("wrong_length", s.wrong_length),
        ("bad_crc", s.crc_rejected),
        ("unknown_address", s.unknown_address),
        ("unsupported_df", s.unsupported_df),
        ("unsupported_cf", s.unsupported_cf),
    ]
}

/// Reasons under which the aircraft tasks count refused positions.
pub const POSITION_REJECT_REASONS: &[&str] = &[
    "invalid_cpr",
    "bad_time",
    "zone_mismatch",
    "latitude_out_of_range",
    "impossible_speed",
];
/// Reasons under which tracker errors are counted.
pub const TRACK_ERROR_REASONS: &[&str] = &["not_positive_definite", "out_of_order", "non_finite"];

/// `GET /api/v1/stats`.
#[derive(Clone, Debug, Serialize)]
pub struct StatsSnapshot {
    pub feed_time: f64,
    /// True once a replay was read to its end and fully processed.
    pub replay_finished: bool,
    pub frames: u64,
    pub frames_by_df: BTreeMap<String, u64>,
    pub frames_by_type_code: BTreeMap<String, u64>,
    pub frames_skipped: BTreeMap<String, u64>,
    pub crc_fixed: u64,
    pub positions_accepted: u64,
    pub positions_rejected: BTreeMap<String, u64>,
    pub track_updates: u64,
    pub track_errors: BTreeMap<String, u64>,
    pub tracks_active: i64,
    pub tracks_created: u64,
    pub tracks_retired: u64,
    pub channel_drops: u64,
    pub channel_dropped_messages: u64,
    pub feeds: Vec<crate::feed::tcp::FeedStatusSnapshot>,
}
