//! `GET /api/v1/stream`: server-sent events.
//!
//! - `track`: one Track JSON object (an element of `/api/v1/tracks`' `tracks`, predictions
//!   included), when the aircraft changed.
//! - `retire`: `{"icao", "t", "reason"}`: the aircraft is gone (`reason` `"retired"`), or no
//!   longer passes the client's filters (`"filtered"`); `t` is the feed time, s.
//! - `stats`: the `/api/v1/stats` JSON, every `server.stream.stats_period_s`.
//!
//! Query filters: `bbox=minLon,minLat,maxLon,maxLat` (degrees; `minLon > maxLon` crosses the
//! antimeridian), `icao=hex[,hex...]`, `mode=CV[,CT...]`; a bad value is a 400 `{"error"}`.
//!
//! A new client first gets a `track` event per current track, then the changes. Each client
//! has a task of its own on the server's runtime. The aircraft tasks tell it which aircraft
//! changed through the daemon's broadcast ([`crate::output::UpdateFeed`], never waited for);
//! it keeps a set of aircraft due an event, and when an aircraft's turn comes (at most
//! `server.stream.max_updates_per_s` a second each) it sends the aircraft's snapshot as the
//! registry has it then: updates in between are coalesced, the latest wins, and what a
//! client has waiting is one flag per aircraft, whatever the update rate.
//!
//! A slow or stalled client never slows the pipeline and holds bounded memory: its events
//! wait in a queue of at most `server.stream.client_buffer_bytes` (plus one chunk being
//! filled); while that is full no event is made, the aircraft that change meanwhile are
//! only marked, and they are sent from the current state once the client reads again. A
//! client that falls so far behind that the broadcast overtakes it is brought up to date the
//! same way: every aircraft marked. Both count in `stream.lagged`. A client whose socket
//! takes nothing for `server.write_timeout_s` is cut by the server. Comment lines keep an
//! idle connection alive every `server.stream.keepalive_s`.

use super::params::{self, LonLatBox};
use super::{ApiError, ApiState};
use crate::daemon::registry::TrackState;
use crate::daemon::Shared;
use crate::decode::Icao;
use crate::output::{Listener, OutputEvent};
use axum::body::{Body, Bytes};
use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use std::collections::{HashMap, VecDeque};
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::sync::{broadcast, mpsc};
use tokio::time::Instant;

/// Bytes of events gathered before they are handed to the connection as one chunk.
const CHUNK_BYTES: usize = 16 * 1024;

/// How often aircraft held back by the rate limit are looked at again. Their turn comes
/// at most this late.
const RECHECK: Duration = Duration::from_millis(50);

/// Longest an aircraft waits for the registry to show the update it was told of (the task
/// broadcasts an update a few microseconds before it swaps the batch's snapshot in); past
/// it the registry's snapshot is sent as it is.
const CATCH_UP: Duration = Duration::from_secs(1);

/// Reconnection delay the client is asked to use, ms (the SSE `retry:` field).
const RETRY_MS: u32 = 2000;

/// `GET /api/v1/stream` query.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct StreamQuery {
    /// `minLon,minLat,maxLon,maxLat` in degrees.
    bbox: Option<String>,
    /// Comma-separated ICAO addresses (6 hex digits each).
    icao: Option<String>,
    /// Comma-separated flight-mode labels.
    mode: Option<String>,
}

/// What a client asked to see.
#[derive(Clone, Debug, Default)]
pub struct Filter {
    pub bbox: Option<LonLatBox>,
    /// Sorted.
    pub icaos: Option<Vec<Icao>>,
    pub modes: Option<Vec<&'static str>>,
}

impl Filter {
    fn parse(q: &StreamQuery) -> Result<Self, ApiError> {
        Ok(Self {
            bbox: params::stream_bbox(q.bbox.as_deref().unwrap_or(""))?,
            icaos: params::icaos(q.icao.as_deref().unwrap_or(""))?,
            modes: params::modes(q.mode.as_deref().unwrap_or(""))?,
        })
    }

    /// Could events of this aircraft pass? (Checked before anything else is read.)
    fn wants(&self, icao: Icao) -> bool {
        self.icaos
            .as_ref()
            .is_none_or(|v| v.binary_search(&icao).is_ok())
    }

    fn matches(&self, t: &TrackState) -> bool {
        self.wants(t.icao)
            && self.bbox.is_none_or(|b| b.contains(t.lat, t.lon))
            && self.modes.as_ref().is_none_or(|m| m.contains(&t.mode))
    }
}

/// The stream's settings, from `[server.stream]` (validated at load).
#[derive(Clone, Copy, Debug)]
struct Settings {
    /// Shortest time between two `track` events of one aircraft.
    period: Duration,
    stats_period: Duration,
    keepalive: Duration,
    max_clients: usize,
    /// Chunks a client may have waiting.
    queue_chunks: usize,
}

impl Settings {
    fn from_config(c: &crate::config::StreamConfig) -> Self {
        let secs = |s: f64, fallback: f64| {
            Duration::try_from_secs_f64(s).unwrap_or(Duration::from_secs_f64(fallback))
        };
        Self {
            period: secs(1.0 / c.max_updates_per_s, 0.5),
            stats_period: secs(c.stats_period_s, 1.0),
            keepalive: secs(c.keepalive_s, 15.0),
            max_clients: c.max_clients,
            queue_chunks: (c.client_buffer_bytes / CHUNK_BYTES).max(1),
        }
    }
}

/// The handler: checks the filters and the client cap, starts the client's task and answers
/// with its events.
#[utoipa::path(get, path = "/api/v1/stream", tag = "stream",
    params(
        ("bbox" = Option<String>, Query, description = "minLon,minLat,maxLon,maxLat in degrees (minLon > maxLon crosses the antimeridian; minLat must not exceed maxLat); empty is no filter"),
        ("icao" = Option<String>, Query, description = "comma-separated ICAO addresses, 6 hex digits each, at most 10000; empty is no filter"),
        ("mode" = Option<String>, Query, description = "comma-separated flight-mode labels: CV, CA, CT, CH, CHCA (any case); empty is no filter"),
    ),
    responses(
        (status = 200, description = "Server-sent events: `track` (data: a Track), `retire` (data: a Retire), `stats` (data: the Stats)", body = String, content_type = "text/event-stream"),
        (status = 400, description = "A malformed or unknown parameter, a box whose latitudes are out of order, or too many addresses", body = super::ErrorBody),
        (status = 503, description = "Over server.stream.max_clients", body = super::ErrorBody),
    ))]
pub(super) async fn stream(
    State(api): State<ApiState>,
    query: Result<Query<StreamQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(q) = query.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let filter = Filter::parse(&q)?;
    let shared = api.shared;
    let settings = Settings::from_config(&shared.config.server.stream);
    let stats = shared.stats.stream.clone();
    // `inc` returns the count before: over the cap, undo and refuse.
    if usize::try_from(stats.clients.inc()).unwrap_or(0) >= settings.max_clients {
        stats.clients.dec();
        stats.clients_refused.inc();
        return Err(ApiError::Unavailable(format!(
            "too many stream clients (server.stream.max_clients = {})",
            settings.max_clients
        )));
    }
    stats.clients_accepted.inc();
    let (tx, rx) = mpsc::channel(settings.queue_chunks);
    // Listening starts before the first state is read: nothing falls between the two.
    let listener = shared.feed.listen();
    let client = Client::new(shared, filter, settings, listener, tx);
    tokio::spawn(client.run());
    Ok((
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static("text/event-stream"),
            ),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
            // Proxies (nginx) would otherwise hold the events back.
            (
                header::HeaderName::from_static("x-accel-buffering"),
                HeaderValue::from_static("no"),
            ),
        ],
        Body::new(Events { rx }),
    )
        .into_response())
}

/// The response body: the chunks the client's task makes, as they come.
struct Events {
    rx: mpsc::Receiver<Bytes>,
}

impl http_body::Body for Events {
    type Data = Bytes;
    type Error = std::convert::Infallible;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Bytes>, Self::Error>>> {
        self.rx
            .poll_recv(cx)
            .map(|chunk| chunk.map(|c| Ok(http_body::Frame::data(c))))
    }
}

/// What the client knows of one aircraft, and whether it is due an event.
#[derive(Clone, Copy, Debug)]
struct Seen {
    /// The client was sent a `track` of it and no `retire` since.
    shown: bool,
    /// Not before this may its next `track` go.
    next_at: Option<Instant>,
    /// Queued in `ready` or `waiting`.
    dirty: bool,
    /// Feed time of the newest update it was told of, s: the registry is awaited until its
    /// snapshot is at least this recent (or [`CATCH_UP`] passed since `dirty_since`).
    want_t_s: f64,
    dirty_since: Instant,
}

/// One client's task: its filters, what it was sent, and its queue.
struct Client {
    shared: Shared,
    filter: Filter,
    settings: Settings,
    listener: Listener,
    tx: mpsc::Sender<Bytes>,
    seen: HashMap<Icao, Seen>,
    /// Aircraft due an event now, in the order they became due.
    ready: VecDeque<Icao>,
    /// Aircraft held back by the rate limit or awaiting the registry.
    waiting: Vec<Icao>,
    /// Events gathered for the next chunk.
    out: Vec<u8>,
    /// The client's queue was found full and nothing was handed over since.
    blocked: bool,
    last_write: Instant,
}

/// The data of a `retire` event.
#[derive(Serialize, utoipa::ToSchema)]
pub(super) struct Retire {
    #[schema(value_type = String, pattern = "^[0-9a-f]{6}$")]
    icao: Icao,
    /// Feed time, s.
    t: f64,
    /// `retired` (the daemon dropped the aircraft) or `filtered` (it left the filters).
    reason: &'static str,
}

impl Client {
    fn new(
        shared: Shared,
        filter: Filter,
        settings: Settings,
        listener: Listener,
        tx: mpsc::Sender<Bytes>,
    ) -> Self {
        Self {
            shared,
            filter,
            settings,
            listener,
            tx,
            seen: HashMap::new(),
            ready: VecDeque::new(),
            waiting: Vec::new(),
            out: Vec::with_capacity(CHUNK_BYTES + 4096),
            blocked: false,
            last_write: Instant::now(),
        }
    }

    async fn run(mut self) {
        let stats = self.shared.stats.stream.clone();
        let shutdown = self.shared.shutdown.clone();
        // The waits below borrow this clone, not `self`, which their branches change.
        let tx = self.tx.clone();
        self.out
            .extend_from_slice(format!("retry: {RETRY_MS}\n\n").as_bytes());
        self.resync();
        let mut recheck = tokio::time::interval(RECHECK);
        recheck.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut stats_tick = tokio::time::interval(self.settings.stats_period);
        stats_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            self.fill();
            // Hand a chunk over when one is full, or when nothing more is ready to join it.
            if !self.out.is_empty() && (self.out.len() >= CHUNK_BYTES || self.ready.is_empty()) {
                match self.tx.try_reserve() {
                    Ok(permit) => {
                        permit.send(Bytes::from(std::mem::take(&mut self.out)));
                        self.out.reserve(CHUNK_BYTES + 4096);
                        self.blocked = false;
                        self.last_write = Instant::now();
                        continue;
                    }
                    Err(mpsc::error::TrySendError::Closed(())) => break,
                    Err(mpsc::error::TrySendError::Full(())) => {
                        if !self.blocked {
                            self.blocked = true;
                            stats.lagged.inc();
                        }
                    }
                }
            }
            let keepalive_at = self.last_write + self.settings.keepalive;
            let has_out = !self.out.is_empty();
            tokio::select! {
                biased;
                _ = shutdown.cancelled() => break,
                // Room again in the client's queue: the loop hands the chunk over.
                r = tx.reserve(), if has_out => match r {
                    Ok(permit) => drop(permit),
                    Err(_) => break,
                },
                _ = tx.closed(), if !has_out => break,
                e = self.listener.rx.recv() => match e {
                    Ok(OutputEvent::Update(p)) => self.mark(p.icao, p.estimate.t_s),
                    Ok(OutputEvent::Retired(icao)) => self.mark(icao, f64::NEG_INFINITY),
                    Err(broadcast::error::RecvError::Lagged(n)) => {
                        stats.lagged.inc();
                        stats.lagged_updates.inc_by(n);
                        self.resync();
                    }
                    Err(broadcast::error::RecvError::Closed) => break,
                },
                _ = recheck.tick() => self.recheck(),
                _ = stats_tick.tick() => self.write_stats(),
                _ = tokio::time::sleep_until(keepalive_at) => {
                    if self.out.is_empty() {
                        self.out.extend_from_slice(b": keep-alive\n\n");
                    }
                    // Counted as written: the next comment comes a period later.
                    self.last_write = Instant::now();
                }
            }
        }
        stats.clients.dec();
    }

    /// Marks an aircraft due an event (a `track` or a `retire`, decided when it is sent).
    fn mark(&mut self, icao: Icao, t_s: f64) {
        if !self.filter.wants(icao) {
            return;
        }
        let now = Instant::now();
        let e = self.seen.entry(icao).or_insert(Seen {
            shown: false,
            next_at: None,
            dirty: false,
            want_t_s: f64::NEG_INFINITY,
            dirty_since: now,
        });
        e.want_t_s = e.want_t_s.max(t_s);
        if e.dirty {
            if self.blocked {
                self.shared.stats.stream.lagged_updates.inc();
            }
            return;
        }
        e.dirty = true;
        e.dirty_since = now;
        if e.next_at.is_none_or(|at| at <= now) {
            self.ready.push_back(icao);
        } else {
            self.waiting.push(icao);
        }
    }

    /// Every aircraft, and every one the client was shown, marked: the client's view is made
    /// current from the registry (the first state, and after falling behind).
    fn resync(&mut self) {
        let shown: Vec<Icao> = self
            .seen
            .iter()
            .filter(|(_, s)| s.shown)
            .map(|(i, _)| *i)
            .collect();
        for icao in self.shared.registry.addresses().into_iter().chain(shown) {
            self.mark(icao, f64::NEG_INFINITY);
        }
    }

    /// Aircraft whose turn has come move from `waiting` to `ready`.
    fn recheck(&mut self) {
        let now = Instant::now();
        let seen = &self.seen;
        let ready = &mut self.ready;
        self.waiting.retain(|icao| {
            let due = seen
                .get(icao)
                .is_none_or(|s| s.next_at.is_none_or(|at| at <= now));
            if due {
                ready.push_back(*icao);
            }
            !due
        });
    }

    /// Makes events of ready aircraft until the chunk is full.
    fn fill(&mut self) {
        let now = Instant::now();
        while self.out.len() < CHUNK_BYTES {
            let Some(icao) = self.ready.pop_front() else {
                return;
            };
            self.emit(icao, now);
        }
    }

    /// The event due for one aircraft, from the registry's snapshot now.
    fn emit(&mut self, icao: Icao, now: Instant) {
        let Some(seen) = self.seen.get_mut(&icao) else {
            return;
        };
        let snapshot = self.shared.registry.get_published(icao);
        if let Some(p) = &snapshot {
            if p.estimate.t_s < seen.want_t_s && now.duration_since(seen.dirty_since) < CATCH_UP {
                // The registry has not caught up with the update yet: look again shortly.
                self.waiting.push(icao);
                return;
            }
        }
        seen.dirty = false;
        seen.want_t_s = f64::NEG_INFINITY;
        let state = snapshot.map(|p| p.track_state());
        match state {
            Some(s) if self.filter.matches(&s) => {
                seen.shown = true;
                seen.next_at = Some(now + self.settings.period);
                write_event(&mut self.out, "track", &s);
            }
            other => {
                let was_shown = seen.shown;
                let gone = other.is_none();
                if gone || !was_shown {
                    // Nothing left to remember of it.
                    self.seen.remove(&icao);
                } else {
                    seen.shown = false;
                }
                if was_shown {
                    let retire = Retire {
                        icao,
                        t: self.shared.stats.feed_time_s(),
                        reason: if gone { "retired" } else { "filtered" },
                    };
                    write_event(&mut self.out, "retire", &retire);
                }
            }
        }
        self.count_event();
    }

    fn write_stats(&mut self) {
        if self.out.len() < CHUNK_BYTES {
            write_event(&mut self.out, "stats", &self.shared.stats.snapshot());
            self.count_event();
        }
    }

    fn count_event(&self) {
        self.shared.stats.stream.events.inc();
    }
}

/// `event: NAME`, `data: JSON`, blank line. (serde_json writes no newline.)
fn write_event<T: Serialize>(out: &mut Vec<u8>, name: &str, data: &T) {
    let start = out.len();
    out.extend_from_slice(b"event: ");
    out.extend_from_slice(name.as_bytes());
    out.extend_from_slice(b"\ndata: ");
    if serde_json::to_writer(&mut *out, data).is_err() {
        // Plain numbers and strings cannot fail to serialise; an event half written would
        // be worse than none.
        out.truncate(start);
        return;
    }
    out.extend_from_slice(b"\n\n");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filters_parse_and_refuse() {
        let q = StreamQuery {
            bbox: None,
            icao: Some("A0B1C2,393322,a0b1c2".into()),
            mode: Some("CT,CV".into()),
        };
        let f = Filter::parse(&q).unwrap();
        assert_eq!(f.icaos, Some(vec![Icao(0x393322), Icao(0xa0b1c2)]));
        assert!(f.wants(Icao(0xa0b1c2)) && !f.wants(Icao(0xa0b1c3)));
        assert_eq!(f.modes, Some(vec!["CT", "CV"]));
        for (icao, mode) in [("zzzzzz", "CV"), ("393322", "XX"), ("3933", "CV")] {
            let q = StreamQuery {
                bbox: None,
                icao: Some(icao.into()),
                mode: Some(mode.into()),
            };
            assert!(Filter::parse(&q).is_err(), "{icao} {mode}");
        }
    }

    #[test]
    fn events_are_framed() {
        let mut out = Vec::new();
        write_event(
            &mut out,
            "retire",
            &Retire {
                icao: Icao(0x393322),
                t: 12.5,
                reason: "retired",
            },
        );
        assert_eq!(
            String::from_utf8(out).unwrap(),
            "event: retire\ndata: {\"icao\":\"393322\",\"t\":12.5,\"reason\":\"retired\"}\n\n"
        );
    }
}
