//! The daemon's counters: one set of Prometheus metrics that `/metrics` encodes and
//! `/api/v1/stats` reads, so the two can never disagree.
//!
//! Hot paths never touch these per frame: the router flushes its local decode counters once
//! per batch, aircraft tasks once per processed batch.

use crate::decode::cpr::RejectReason;
use crate::decode::DecodeStats;
use crate::track::TrackError;
use prometheus_client::encoding::{EncodeMetric, MetricEncoder, NoLabelSet};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::{MetricType, TypedMetric};
use prometheus_client::registry::Registry;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::Semaphore;

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
    /// Messages that reached their aircraft (routed, not dropped): with
    /// `channel_dropped_messages`, every message the router gave an aircraft (DF17/18, and
    /// the Mode S replies whose address it knows). Counted by the aircraft, so the sum
    /// checks the router's own count.
    pub aircraft_messages: Counter,
    /// Position and velocity reports that repeated the aircraft's last one of their kind
    /// within `decode.duplicate_window_s` (one transmission heard twice), not given to the
    /// tracker again. Counted in `aircraft_messages` too.
    pub duplicate_reports: Counter,
    /// Position reports the trackers set aside as out of their time (`track::outlier`):
    /// counted in `positions_accepted` and `track_updates` too.
    pub outlier_positions: Counter,
    /// Tracker updates done and refused.
    pub track_updates: Counter,
    pub track_errors: Family<Labels, Counter>,
    /// Tracks reset because their estimate (or a prediction) was non-finite or ran away off
    /// the globe: never published (the daemon's last line of defence).
    pub track_resets_nonfinite: Counter,
    /// Tracks restarted at a position that cannot continue them: too far from the track's
    /// plane (`aircraft::MAX_TRACK_RADIUS_M`), or the first after the position decoder gave
    /// up its reference.
    pub track_resets_jump: Counter,
    /// Aircraft the registry lists now (what `/healthz` counts and `/api/v1/tracks` serves
    /// when they have an estimate): counted by the router, which alone registers and retires
    /// them. After a replay's end their tasks are gone but their last tracks are still
    /// served, and still counted. Then aircraft spawned and retired so far.
    pub tracks_active: Gauge,
    pub tracks_created: Counter,
    pub tracks_retired: Counter,
    /// Batches not delivered because an aircraft task's channel was full.
    pub channel_drops: Counter,
    /// Messages lost with those batches.
    pub channel_dropped_messages: Counter,
    /// Batches not delivered because an aircraft task's channel was full, under
    /// `pipeline.overload = "drop"` only (the default waits).
    /// Set once a replay has been read to its end and every aircraft task has drained.
    pub replay_finished: std::sync::atomic::AtomicBool,
    /// Set when a task the pipeline needs died: `/healthz` answers 503 until the daemon,
    /// which stops on it, has exited.
    pub pipeline_failed: std::sync::atomic::AtomicBool,
    /// Time from a feed batch's arrival to its aircraft's published snapshot.
    pub latency: LatencyHistogram,
    /// Queues and the router's progress: the ingest lag.
    routing: Arc<RoutingState>,
    /// `pipeline.max_lag_s`: past it the daemon is lagging (`/healthz` degraded).
    max_lag_s: f64,
    /// Highest feed time seen, s (f64 bits).
    feed_time_bits: AtomicU64,
    /// Feed status snapshots, by feed name (set by the daemon at start).
    feeds: Mutex<Vec<std::sync::Arc<crate::feed::tcp::FeedStatus>>>,
    /// The HTTP server's connection counters.
    pub http: Arc<HttpStats>,
    /// The outputs' counters (`[output.*]`).
    pub outputs: Arc<crate::output::OutputStats>,
    /// The event stream's counters (`GET /api/v1/stream`).
    pub stream: Arc<StreamStats>,
    /// A cluster node's counters (`[cluster]`), absent in one process.
    pub cluster: Option<Arc<crate::cluster::ClusterStats>>,
}

/// The HTTP server's connection counters (`/api/v1/stats` `http`, `/metrics` `adsb_http_*`).
#[derive(Debug, Default)]
pub struct HttpStats {
    /// Connections open now.
    pub connections_open: Gauge,
    /// Connections refused with 503 at `server.max_connections`.
    pub connections_refused: Counter,
    /// Connections closed by a timeout (request head not sent in time, or a response
    /// write stalled past `server.write_timeout_s`).
    pub connections_timed_out: Counter,
    /// `accept` failures (out of file descriptors, ...).
    pub accept_errors: Counter,
}

/// The event stream's counters (`/api/v1/stats` `stream`, `/metrics` `adsb_stream_*`).
#[derive(Debug, Default)]
pub struct StreamStats {
    /// Clients connected now.
    pub clients: Gauge,
    /// Clients accepted since start.
    pub clients_accepted: Counter,
    /// Clients refused at `server.stream.max_clients`.
    pub clients_refused: Counter,
    /// Events sent (`track`, `retire`, `stats`).
    pub events: Counter,
    /// Times a client fell behind (the broadcast overtook it, or its buffer was full) and
    /// was brought up to date from the current state instead of the updates it missed.
    pub lagged: Counter,
    /// Updates those clients missed.
    pub lagged_updates: Counter,
}

/// A copy of [`StreamStats`].
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct StreamStatsSnapshot {
    pub clients: i64,
    pub clients_accepted: u64,
    pub clients_refused: u64,
    pub events: u64,
    pub lagged: u64,
    pub lagged_updates: u64,
}

impl StreamStats {
    pub fn snapshot(&self) -> StreamStatsSnapshot {
        StreamStatsSnapshot {
            clients: self.clients.get(),
            clients_accepted: self.clients_accepted.get(),
            clients_refused: self.clients_refused.get(),
            events: self.events.get(),
            lagged: self.lagged.get(),
            lagged_updates: self.lagged_updates.get(),
        }
    }

    fn register(&self, registry: &mut Registry) {
        registry.register(
            "stream_clients",
            "Event-stream clients connected",
            self.clients.clone(),
        );
        registry.register(
            "stream_clients_accepted",
            "Event-stream clients accepted",
            self.clients_accepted.clone(),
        );
        registry.register(
            "stream_clients_refused",
            "Event-stream clients refused at server.stream.max_clients",
            self.clients_refused.clone(),
        );
        registry.register(
            "stream_events",
            "Server-sent events sent (track, retire, stats)",
            self.events.clone(),
        );
        registry.register(
            "stream_lagged",
            "Times an event-stream client fell behind and was resynchronised from the current state",
            self.lagged.clone(),
        );
        registry.register(
            "stream_lagged_updates",
            "Track updates event-stream clients missed by falling behind",
            self.lagged_updates.clone(),
        );
    }
}

/// A copy of [`HttpStats`].
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct HttpStatsSnapshot {
    pub connections_open: i64,
    pub connections_refused: u64,
    pub connections_timed_out: u64,
    pub accept_errors: u64,
}

impl HttpStats {
    pub fn snapshot(&self) -> HttpStatsSnapshot {
        HttpStatsSnapshot {
            connections_open: self.connections_open.get(),
            connections_refused: self.connections_refused.get(),
            connections_timed_out: self.connections_timed_out.get(),
            accept_errors: self.accept_errors.get(),
        }
    }
}

impl Default for Stats {
    fn default() -> Self {
        Self::new()
    }
}

/// Frame budget of [`Stats::new`] (`pipeline.max_queued_frames`' default).
pub const DEFAULT_MAX_QUEUED_FRAMES: usize = 32_768;
/// Lag limit of [`Stats::new`] (`pipeline.max_lag_s`' default), s.
pub const DEFAULT_MAX_LAG_S: f64 = 5.0;

impl Stats {
    /// All metrics, registered under the `adsb_` prefix, with the default frame budget.
    pub fn new() -> Self {
        Self::for_pipeline(DEFAULT_MAX_QUEUED_FRAMES, DEFAULT_MAX_LAG_S)
    }

    /// All metrics, with a budget of `max_queued_frames` frames queued for aircraft tasks
    /// ([`Stats::reserve_frames`]) and `max_lag_s` as the lag past which ingest is lagging
    /// (`[pipeline]`).
    pub fn for_pipeline(max_queued_frames: usize, max_lag_s: f64) -> Self {
        let budget_frames = max_queued_frames.clamp(1, Semaphore::MAX_PERMITS);
        let mut registry = Registry::with_prefix("adsb");
        let s = Self {
            frames_in: Counter::default(),
            frames_by_df: Family::default(),
            frames_by_tc: Family::default(),
            frames_skipped: Family::default(),
            crc_fixed: Counter::default(),
            positions_accepted: Counter::default(),
            positions_rejected: Family::default(),
            aircraft_messages: Counter::default(),
            duplicate_reports: Counter::default(),
            outlier_positions: Counter::default(),
            track_updates: Counter::default(),
            track_errors: Family::default(),
            track_resets_nonfinite: Counter::default(),
            track_resets_jump: Counter::default(),
            tracks_active: Gauge::default(),
            tracks_created: Counter::default(),
            tracks_retired: Counter::default(),
            channel_drops: Counter::default(),
            channel_dropped_messages: Counter::default(),
            replay_finished: std::sync::atomic::AtomicBool::new(false),
            pipeline_failed: std::sync::atomic::AtomicBool::new(false),
            latency: LatencyHistogram::default(),
            routing: Arc::new(RoutingState {
                budget: Semaphore::new(budget_frames),
                budget_frames,
                router_queued: AtomicI64::new(0),
                routing_arrival_ns: AtomicU64::new(0),
                epoch: Instant::now(),
            }),
            max_lag_s,
            feed_time_bits: AtomicU64::new(0f64.to_bits()),
            feeds: Mutex::new(Vec::new()),
            http: Arc::new(HttpStats::default()),
            outputs: Arc::new(crate::output::OutputStats::default()),
            stream: Arc::new(StreamStats::default()),
            cluster: None,
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
        registry.register(
            "aircraft_messages",
            "Messages that reached their aircraft (routed, not dropped)",
            s.aircraft_messages.clone(),
        );
        registry.register(
            "duplicate_reports",
            "Position and velocity reports heard twice (one transmission from two receivers), used once",
            s.duplicate_reports.clone(),
        );
        registry.register(
            "outlier_positions",
            "Position reports set aside as out of their time (a stale fix, another receiver's clock)",
            s.outlier_positions.clone(),
        );
        registry.register("track_updates", "Tracker updates", s.track_updates.clone());
        registry.register(
            "track_errors",
            "Tracker steps refused, by reason",
            s.track_errors.clone(),
        );
        registry.register(
            "track_resets_nonfinite",
            "Tracks reset because their estimate was non-finite or ran away (never published)",
            s.track_resets_nonfinite.clone(),
        );
        registry.register(
            "track_resets_jump",
            "Tracks restarted at a position that cannot continue them",
            s.track_resets_jump.clone(),
        );
        registry.register(
            "tracks_active",
            "Aircraft tracked now (after a replay's end: its last tracks, still served)",
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
        registry.register(
            "ingest_latency_seconds",
            "Time from a frame's arrival to its aircraft's published snapshot",
            s.latency.clone(),
        );
        registry.register(
            "ingest_lag_seconds",
            "Age of the frames the router is working on (0 when it has nothing queued)",
            LagGauge(GaugeFn::Lag, s.routing.clone()),
        );
        registry.register(
            "queued_frames",
            "Frames queued for aircraft tasks",
            LagGauge(GaugeFn::AircraftQueued, s.routing.clone()),
        );
        registry.register(
            "queued_batches",
            "Feed batches queued for the router",
            LagGauge(GaugeFn::RouterQueued, s.routing.clone()),
        );
        registry.register(
            "http_connections_open",
            "HTTP connections open",
            s.http.connections_open.clone(),
        );
        registry.register(
            "http_connections_refused",
            "HTTP connections refused at server.max_connections",
            s.http.connections_refused.clone(),
        );
        registry.register(
            "http_connections_timed_out",
            "HTTP connections closed by a header-read or write timeout",
            s.http.connections_timed_out.clone(),
        );
        registry.register(
            "http_accept_errors",
            "HTTP accept failures",
            s.http.accept_errors.clone(),
        );
        s.outputs.register(&mut registry);
        s.stream.register(&mut registry);
        Self { registry, ..s }
    }

    /// [`Stats::for_pipeline`] of a cluster node, with its cluster counters.
    pub fn for_cluster(
        max_queued_frames: usize,
        max_lag_s: f64,
        cluster: Arc<crate::cluster::ClusterStats>,
    ) -> Self {
        let mut s = Self::for_pipeline(max_queued_frames, max_lag_s);
        cluster.register(&mut s.registry);
        s.cluster = Some(cluster);
        s
    }

    /// The permits a batch of `n` frames takes: `n`, at most the whole budget (so one huge
    /// batch can always go).
    fn permits_for(&self, n: usize) -> u32 {
        n.min(self.routing.budget_frames).min(u32::MAX as usize) as u32
    }

    /// Waits for room for a batch of `n` frames in the budget of frames queued for aircraft
    /// tasks; returns the permits taken, to give back with [`Stats::release_frames`] once the
    /// batch is processed. The budget bounds the queued memory whatever the fleet's size.
    pub async fn reserve_frames(&self, n: usize) -> u32 {
        let permits = self.permits_for(n);
        // The semaphore is never closed, so acquiring only waits.
        if let Ok(p) = self.routing.budget.acquire_many(permits).await {
            p.forget();
        }
        permits
    }

    /// [`Stats::reserve_frames`] without waiting: `None` when there is no room.
    pub fn try_reserve_frames(&self, n: usize) -> Option<u32> {
        let permits = self.permits_for(n);
        let p = self.routing.budget.try_acquire_many(permits).ok()?;
        p.forget();
        Some(permits)
    }

    /// Gives back the permits of a processed (or dropped) batch.
    pub fn release_frames(&self, permits: u32) {
        self.routing.budget.add_permits(permits as usize);
    }

    /// Frames queued for aircraft tasks now: the budget in use.
    pub fn aircraft_queued(&self) -> i64 {
        self.routing.queued_frames()
    }

    /// The router starts a batch that arrived at `arrived`, with `waiting` more batches
    /// behind it.
    pub fn routing(&self, arrived: Instant, waiting: usize) {
        let r = &self.routing;
        let ns = arrived.saturating_duration_since(r.epoch).as_nanos() as u64;
        r.routing_arrival_ns.store(ns.max(1), Ordering::Relaxed);
        r.router_queued.store(waiting as i64, Ordering::Relaxed);
    }

    /// The router has nothing left to do.
    pub fn router_idle(&self) {
        self.routing.routing_arrival_ns.store(0, Ordering::Relaxed);
        self.routing.router_queued.store(0, Ordering::Relaxed);
    }

    /// Feed batches queued for the router.
    pub fn router_queued(&self) -> i64 {
        self.routing.router_queued.load(Ordering::Relaxed)
    }

    /// Ingest lag, s: how long ago the frames the router is working on arrived; 0 when it
    /// is idle. A pipeline that keeps up shows the time one batch takes; one that falls
    /// behind shows its backlog growing.
    pub fn ingest_lag_s(&self) -> f64 {
        self.routing.lag_s()
    }

    /// The lag past which ingest is lagging (`/healthz` degraded), s.
    pub fn max_lag_s(&self) -> f64 {
        self.max_lag_s
    }

    /// Records the time from a batch's arrival to its publication.
    pub fn observe_latency(&self, d: Duration) {
        self.latency.observe(d);
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
        let lag_s = self.ingest_lag_s();
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
            aircraft_messages: self.aircraft_messages.get(),
            duplicate_reports: self.duplicate_reports.get(),
            outlier_positions: self.outlier_positions.get(),
            track_updates: self.track_updates.get(),
            track_errors: read(&self.track_errors, "reason", TRACK_ERROR_REASONS),
            track_resets_nonfinite: self.track_resets_nonfinite.get(),
            track_resets_jump: self.track_resets_jump.get(),
            tracks_active: self.tracks_active.get(),
            tracks_created: self.tracks_created.get(),
            tracks_retired: self.tracks_retired.get(),
            channel_drops: self.channel_drops.get(),
            channel_dropped_messages: self.channel_dropped_messages.get(),
            ingest_lag_s: lag_s,
            lagging: lag_s > self.max_lag_s,
            queued_frames: self.aircraft_queued(),
            queued_batches: self.router_queued(),
            latency: self.latency.summary(),
            feeds: self.feeds(),
            http: self.http.snapshot(),
            outputs: self.outputs.snapshot(),
            stream: self.stream.snapshot(),
            cluster: self.cluster.as_ref().map(|c| c.snapshot()),
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
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
#[schema(as = Stats)]
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
    /// Messages that reached their aircraft (routed, not dropped).
    pub aircraft_messages: u64,
    /// Of them, position and velocity reports heard twice within
    /// `decode.duplicate_window_s` (one transmission from two receivers), used once.
    pub duplicate_reports: u64,
    /// Position reports the trackers set aside as out of their time (`track::outlier`).
    pub outlier_positions: u64,
    pub track_updates: u64,
    pub track_errors: BTreeMap<String, u64>,
    /// Tracks reset instead of publishing a non-finite or runaway estimate.
    pub track_resets_nonfinite: u64,
    /// Tracks restarted at a position that cannot continue them.
    pub track_resets_jump: u64,
    pub tracks_active: i64,
    pub tracks_created: u64,
    pub tracks_retired: u64,
    pub channel_drops: u64,
    pub channel_dropped_messages: u64,
    /// Age of the frames the router is working on, s (0 when idle).
    pub ingest_lag_s: f64,
    /// True while `ingest_lag_s` is past `pipeline.max_lag_s`.
    pub lagging: bool,
    /// Frames queued for aircraft tasks.
    pub queued_frames: i64,
    /// Feed batches queued for the router.
    pub queued_batches: i64,
    /// Arrival-to-publication latency.
    pub latency: LatencySummary,
    pub feeds: Vec<crate::feed::tcp::FeedStatusSnapshot>,
    /// The HTTP server's connections.
    pub http: HttpStatsSnapshot,
    /// The outputs' counters.
    pub outputs: crate::output::OutputStatsSnapshot,
    /// The event stream's clients.
    pub stream: StreamStatsSnapshot,
    /// A cluster node's counters (absent in one process).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(required = false)]
    pub cluster: Option<crate::cluster::ClusterSnapshot>,
}

/// Counters an aircraft (or the synchronous pipeline) keeps locally and flushes into the
/// shared [`Stats`] once per batch: a shared atomic per frame costs more than the frame's
/// work once two cores contend for its cache line.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Counts {
    /// See [`Stats::aircraft_messages`].
    pub messages: u64,
    /// See [`Stats::duplicate_reports`].
    pub duplicate_reports: u64,
    /// See [`Stats::outlier_positions`].
    pub outlier_positions: u64,
    pub positions_accepted: u64,
    pub track_updates: u64,
    /// By [`POSITION_REJECT_REASONS`] index.
    pub positions_rejected: [u64; 5],
    /// By [`TRACK_ERROR_REASONS`] index.
    pub track_errors: [u64; 3],
    /// See [`Stats::track_resets_nonfinite`].
    pub track_resets_nonfinite: u64,
    /// See [`Stats::track_resets_jump`].
    pub track_resets_jump: u64,
}

impl Counts {
    /// Counts a refused position.
    pub fn position_rejected(&mut self, r: RejectReason) {
        let i = match r {
            RejectReason::InvalidCpr => 0,
            RejectReason::BadTime => 1,
            RejectReason::ZoneMismatch => 2,
            RejectReason::LatitudeOutOfRange => 3,
            RejectReason::ImpossibleSpeed => 4,
        };
        if let Some(c) = self.positions_rejected.get_mut(i) {
            *c += 1;
        }
    }

    /// Counts a refused tracker step.
    pub fn track_error(&mut self, e: &TrackError) {
        let i = match e {
            TrackError::NotPositiveDefinite => 0,
            TrackError::OutOfOrder { .. } => 1,
            TrackError::NonFinite(_) => 2,
        };
        if let Some(c) = self.track_errors.get_mut(i) {
            *c += 1;
        }
    }

    /// Adds everything to `stats` and starts again from zero.
    pub fn flush(&mut self, stats: &Stats) {
        if self.messages > 0 {
            stats.aircraft_messages.inc_by(self.messages);
        }
        if self.duplicate_reports > 0 {
            stats.duplicate_reports.inc_by(self.duplicate_reports);
        }
        if self.outlier_positions > 0 {
            stats.outlier_positions.inc_by(self.outlier_positions);
        }
        if self.positions_accepted > 0 {
            stats.positions_accepted.inc_by(self.positions_accepted);
        }
        if self.track_updates > 0 {
            stats.track_updates.inc_by(self.track_updates);
        }
        if self.track_resets_nonfinite > 0 {
            stats
                .track_resets_nonfinite
                .inc_by(self.track_resets_nonfinite);
        }
        if self.track_resets_jump > 0 {
            stats.track_resets_jump.inc_by(self.track_resets_jump);
        }
        let labelled = |family: &Family<Labels, Counter>, names: &[&str], counts: &[u64]| {
            for (name, &n) in names.iter().zip(counts) {
                if n > 0 {
                    family
                        .get_or_create(&vec![("reason", name.to_string())])
                        .inc_by(n);
                }
            }
        };
        labelled(
            &stats.positions_rejected,
            POSITION_REJECT_REASONS,
            &self.positions_rejected,
        );
        labelled(&stats.track_errors, TRACK_ERROR_REASONS, &self.track_errors);
        *self = Self::default();
    }
}

/// Upper bounds of the latency buckets, s: 10 µs doubling to about 42 s (23 buckets, then
/// +Inf), fine enough to read a p99 within a factor of 2 from 10 µs to tens of seconds.
fn latency_bounds_s() -> impl Iterator<Item = f64> {
    (0..LATENCY_BUCKETS - 1).map(|i| 1e-5 * f64::from(1u32 << i))
}
const LATENCY_BUCKETS: usize = 24;

/// A lock-free latency histogram (atomic buckets): observed once per aircraft batch from
/// every worker thread, where prometheus-client's histogram takes a write lock.
#[derive(Clone, Debug, Default)]
pub struct LatencyHistogram {
    inner: Arc<LatencyInner>,
}

#[derive(Debug, Default)]
struct LatencyInner {
    buckets: [AtomicU64; LATENCY_BUCKETS],
    sum_ns: AtomicU64,
}

/// Quantiles read from the histogram's buckets (each the upper bound of the bucket that
/// holds it, so within a factor of 2 above the true value).
#[derive(Clone, Debug, Default, PartialEq, Serialize, utoipa::ToSchema)]
pub struct LatencySummary {
    pub count: u64,
    pub mean_s: f64,
    pub p50_s: f64,
    pub p99_s: f64,
    pub max_bucket_s: f64,
}

impl LatencyHistogram {
    /// Records one duration.
    pub fn observe(&self, d: Duration) {
        let s = d.as_secs_f64();
        let i = latency_bounds_s()
            .position(|b| s <= b)
            .unwrap_or(LATENCY_BUCKETS - 1);
        if let Some(b) = self.inner.buckets.get(i) {
            b.fetch_add(1, Ordering::Relaxed);
        }
        self.inner.sum_ns.fetch_add(
            d.as_nanos().min(u128::from(u64::MAX)) as u64,
            Ordering::Relaxed,
        );
    }

    /// Per-bucket counts with their upper bounds (the last is +Inf, as f64::MAX).
    fn buckets(&self) -> Vec<(f64, u64)> {
        latency_bounds_s()
            .chain(std::iter::once(f64::MAX))
            .zip(&self.inner.buckets)
            .map(|(b, c)| (b, c.load(Ordering::Relaxed)))
            .collect()
    }

    /// Count, mean and bucket quantiles.
    pub fn summary(&self) -> LatencySummary {
        let buckets = self.buckets();
        let count: u64 = buckets.iter().map(|(_, c)| c).sum();
        let quantile = |q: f64| {
            let rank = (q * count as f64).ceil().max(1.0) as u64;
            let mut seen = 0;
            for (bound, c) in &buckets {
                seen += c;
                if seen >= rank {
                    return if *bound == f64::MAX {
                        f64::INFINITY
                    } else {
                        *bound
                    };
                }
            }
            0.0
        };
        let max_bucket_s = buckets
            .iter()
            .rev()
            .find(|(_, c)| *c > 0)
            .map_or(
                0.0,
                |(b, _)| if *b == f64::MAX { f64::INFINITY } else { *b },
            );
        LatencySummary {
            count,
            mean_s: if count > 0 {
                self.inner.sum_ns.load(Ordering::Relaxed) as f64 * 1e-9 / count as f64
            } else {
                0.0
            },
            p50_s: if count > 0 { quantile(0.5) } else { 0.0 },
            p99_s: if count > 0 { quantile(0.99) } else { 0.0 },
            max_bucket_s,
        }
    }
}

impl TypedMetric for LatencyHistogram {
    const TYPE: MetricType = MetricType::Histogram;
}

impl EncodeMetric for LatencyHistogram {
    fn encode(&self, mut encoder: MetricEncoder) -> Result<(), std::fmt::Error> {
        let buckets = self.buckets();
        let count = buckets.iter().map(|(_, c)| c).sum();
        let sum_s = self.inner.sum_ns.load(Ordering::Relaxed) as f64 * 1e-9;
        encoder.encode_histogram::<NoLabelSet>(sum_s, count, &buckets, None)
    }

    fn metric_type(&self) -> MetricType {
        MetricType::Histogram
    }
}

/// The queues and the router's progress, shared with the gauges of `/metrics`.
#[derive(Debug)]
struct RoutingState {
    /// Frames handed to aircraft tasks and not yet processed, all aircraft together: one
    /// permit a frame (`pipeline.max_queued_frames`).
    budget: Semaphore,
    budget_frames: usize,
    /// Feed batches waiting for the router (set by the router after each receive).
    router_queued: AtomicI64,
    /// Arrival of the batch the router is working on, ns after `epoch`; 0 when idle.
    routing_arrival_ns: AtomicU64,
    /// Origin of `routing_arrival_ns`.
    epoch: Instant,
}

impl RoutingState {
    /// Permits in use.
    fn queued_frames(&self) -> i64 {
        self.budget_frames
            .saturating_sub(self.budget.available_permits()) as i64
    }

    fn lag_s(&self) -> f64 {
        let ns = self.routing_arrival_ns.load(Ordering::Relaxed);
        if ns == 0 {
            return 0.0;
        }
        let arrived = self.epoch + Duration::from_nanos(ns);
        Instant::now()
            .saturating_duration_since(arrived)
            .as_secs_f64()
    }
}

#[derive(Clone, Copy, Debug)]
enum GaugeFn {
    Lag,
    AircraftQueued,
    RouterQueued,
}

/// A gauge computed when `/metrics` is read.
#[derive(Clone, Debug)]
struct LagGauge(GaugeFn, Arc<RoutingState>);

impl TypedMetric for LagGauge {
    const TYPE: MetricType = MetricType::Gauge;
}

impl EncodeMetric for LagGauge {
    fn encode(&self, mut encoder: MetricEncoder) -> Result<(), std::fmt::Error> {
        match self.0 {
            GaugeFn::Lag => encoder.encode_gauge(&self.1.lag_s()),
            GaugeFn::AircraftQueued => encoder.encode_gauge(&self.1.queued_frames()),
            GaugeFn::RouterQueued => {
                encoder.encode_gauge(&self.1.router_queued.load(Ordering::Relaxed))
            }
        }
    }

    fn metric_type(&self) -> MetricType {
        MetricType::Gauge
    }
}
