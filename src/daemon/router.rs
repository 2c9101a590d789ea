//! The router: checks frame batches and hands each aircraft its messages.
//!
//! One router task owns the decoder (CRC, recent-address filter) and the map from ICAO
//! address to aircraft channel, so routing takes no lock. It passes on what the decoder
//! accepted as a [`Heard`] (the frame's payload, 24 bytes); each aircraft's task reads the
//! message itself (the type's doc says why). Messages of one batch are gathered per aircraft
//! and sent as one channel message each: a channel hop and a task wake-up per frame would
//! cost more than the decoding.
//!
//! Nothing is dropped by default ([`Overload::Backpressure`]): when an aircraft's channel is
//! full the router waits for room, its own input channel fills, the feed stops reading its
//! socket and TCP flow control slows the sender (a replay simply waits). Shedding load is a
//! policy the user must choose ([`Overload::Drop`]): counted, and logged once per episode.

use super::aircraft::{run_task, Aircraft, AircraftBatch, AircraftConfig, TaskContext};
use super::stats::Stats;
use crate::decode::{DecodeStats, Decoder, DecoderConfig, Heard, Icao};
use crate::feed::tcp::FrameBatch;
use rustc_hash::FxHashMap;
use serde::Deserialize;
use std::collections::hash_map::Entry;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio::task::JoinSet;

/// How often (feed seconds) the router looks for aircraft to retire.
const SWEEP_PERIOD_S: f64 = 1.0;
/// How often (wall clock) the router looks for aircraft silent in wall time (a dead feed
/// whose clock stopped).
const WALL_SWEEP_PERIOD: Duration = Duration::from_secs(1);
/// While dropping, at most one warning per this long.
const DROP_LOG_PERIOD: Duration = Duration::from_secs(10);

/// What the router does when an aircraft task's channel is full (`pipeline.overload`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Overload {
    /// Wait for room: the feed is slowed, nothing is lost (the default).
    #[default]
    Backpressure,
    /// Drop that aircraft's messages of the batch, count them (`channel_drops`,
    /// `channel_dropped_messages`) and warn once per episode.
    Drop,
}

struct Handle {
    /// Boxed batches: a tokio channel allocates its slots 32 at a time, and 32 pointers
    /// take 256 bytes where 32 batches took 1.8 KB, per aircraft.
    tx: mpsc::Sender<Box<AircraftBatch>>,
    last_seen_s: f64,
    /// Wall-clock arrival of its last batch.
    last_arrival: Instant,
    /// Messages of the batch being routed (no allocation between batches).
    pending: Vec<Heard>,
    /// Messages it had in the last batch: the room reserved for the next one.
    last_batch_len: usize,
}

impl Handle {
    /// Feed time it was last heard: its newest pending message's, else its last delivered
    /// batch's.
    fn heard_s(&self) -> f64 {
        self.pending.last().map_or(self.last_seen_s, |p| p.time_s)
    }
}

/// Router settings.
pub struct RouterConfig {
    pub decoder: DecoderConfig,
    pub aircraft: AircraftConfig,
    /// Feed seconds of silence after which an aircraft is retired.
    pub retire_after_s: f64,
    /// Wall-clock silence after which an aircraft is retired even if the feed's clock
    /// stopped (a dead feed).
    pub idle: Duration,
    /// Capacity of each aircraft channel, in batches.
    pub channel_capacity: usize,
    pub overload: Overload,
}

/// Counts and logs drops under [`Overload::Drop`]: one warning when an episode starts, then
/// at most one per [`DROP_LOG_PERIOD`] with the count since.
#[derive(Default)]
struct DropLog {
    since_log: u64,
    last_log: Option<Instant>,
}

impl DropLog {
    fn dropped(&mut self, n: u64, stats: &Stats) {
        stats.channel_drops.inc();
        stats.channel_dropped_messages.inc_by(n);
        self.since_log += n;
        let due = self.last_log.is_none_or(|t| t.elapsed() >= DROP_LOG_PERIOD);
        if due {
            tracing::warn!(
                dropped = self.since_log,
                total = stats.channel_dropped_messages.get(),
                "pipeline overloaded: dropping messages (pipeline.overload = \"drop\")"
            );
            self.since_log = 0;
            self.last_log = Some(Instant::now());
        }
    }
}

/// Runs until the batch channel closes (end of replay) or shutdown; then closes every
/// aircraft channel and waits for the tasks to drain and finish.
pub async fn run_router(
    mut rx: mpsc::Receiver<FrameBatch>,
    cfg: RouterConfig,
    ctx: Arc<TaskContext>,
) {
    let stats: Arc<Stats> = ctx.stats.clone();
    let mut decoder = Decoder::new(cfg.decoder);
    let mut flushed = DecodeStats::default();
    let mut aircraft: FxHashMap<Icao, Handle> = FxHashMap::default();
    let mut touched: Vec<Icao> = Vec::new();
    // Aircraft retired in this batch that still have messages of it to receive.
    let mut retiring: Vec<Handle> = Vec::new();
    let mut tasks = JoinSet::new();
    let mut next_sweep_s = f64::NEG_INFINITY;
    let mut now_s = f64::NEG_INFINITY;
    let mut drops = DropLog::default();
    let mut wall_sweep = tokio::time::interval(WALL_SWEEP_PERIOD);
    wall_sweep.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);

    loop {
        let batch = tokio::select! {
            biased;
            _ = ctx.shutdown.cancelled() => break,
            b = rx.recv() => match b {
                Some(b) => b,
                None => break,
            },
            _ = wall_sweep.tick() => {
                retire_wall_idle(&mut aircraft, cfg.idle, &ctx);
                continue;
            }
        };
        stats.routing(batch.arrived, rx.len());
        stats.frames_in.inc_by(batch.frames.len() as u64);
        for frame in &batch.frames {
            now_s = now_s.max(frame.time_s);
            let Ok(d) = decoder.accept(frame) else {
                continue;
            };
            let handle = match aircraft.entry(d.icao) {
                Entry::Vacant(e) => e.insert(spawn_aircraft(
                    d.icao,
                    d.time_s,
                    batch.arrived,
                    &cfg,
                    &ctx,
                    &mut tasks,
                )),
                Entry::Occupied(mut e) => {
                    // Silent past the retirement delay before this message (a replay that
                    // looped, a gap in the feed): the old track is retired and this message
                    // starts a new one, even though the sweep would keep an aircraft heard
                    // in this batch. Its messages of the batch before the gap still go to
                    // the old task.
                    let h = e.get();
                    if d.time_s - h.heard_s() > cfg.retire_after_s {
                        tracing::debug!(icao = %d.icao, "retired after silence (seen again)");
                        stats.tracks_retired.inc();
                        stats.tracks_active.dec();
                        let old = e.insert(spawn_aircraft(
                            d.icao,
                            d.time_s,
                            batch.arrived,
                            &cfg,
                            &ctx,
                            &mut tasks,
                        ));
                        if !old.pending.is_empty() {
                            retiring.push(old);
                        }
                    }
                    e.into_mut()
                }
            };
            if handle.pending.is_empty() {
                touched.push(d.icao);
                // What the last batch took. A Vec that outgrows it is reallocated and copied
                // (about 3 % of a `kalman-cv` fleet replay's time); reserving half as much
                // again saved two thirds of that but held 1.1 MiB more anonymous memory at
                // 1000 aircraft (RssAnon 19.7-19.9 against 18.5-18.7 MiB, tracking at 20x
                // real time), and the memory per aircraft is the tighter budget.
                handle.pending.reserve(handle.last_batch_len);
            }
            handle.pending.push(d);
        }
        stats.observe_feed_time(now_s);
        stats.add_decode(decoder.stats(), &flushed);
        flushed = decoder.stats().clone();

        // Retire before sending, so a replay loop that jumps ahead in time starts afresh.
        // Silence is measured from an aircraft's last message, in this batch or before: an
        // aircraft whose messages of this batch all came before the cutoff is retired after
        // it gets them, as it would have been had the feed come in smaller batches.
        if now_s >= next_sweep_s {
            let cutoff = now_s - cfg.retire_after_s;
            aircraft.retain(|icao, h| {
                let keep = h.heard_s().max(h.last_seen_s) >= cutoff;
                if !keep {
                    tracing::debug!(%icao, "retired after silence");
                    ctx.registry.remove(*icao);
                    stats.tracks_retired.inc();
                    stats.tracks_active.dec();
                    if !h.pending.is_empty() {
                        retiring.push(Handle {
                            tx: h.tx.clone(),
                            pending: std::mem::take(&mut h.pending),
                            ..*h
                        });
                    }
                }
                keep
            });
            next_sweep_s = now_s + SWEEP_PERIOD_S;
        }

        // Retired aircraft get their last messages (then their tasks drain and end), and
        // every aircraft heard in this batch its messages.
        let mut stopping = false;
        for mut old in retiring.drain(..) {
            let sent = deliver(&mut old, &batch, cfg.overload, &ctx, &mut drops).await;
            if sent == Delivery::Shutdown {
                stopping = true;
                break;
            }
        }
        for icao in touched.drain(..) {
            if stopping {
                break;
            }
            let Some(handle) = aircraft.get_mut(&icao) else {
                continue;
            };
            match deliver(handle, &batch, cfg.overload, &ctx, &mut drops).await {
                Delivery::Sent => {}
                Delivery::Shutdown => stopping = true,
                Delivery::Gone => {
                    // The task ended (it panicked: tasks otherwise end only when the router
                    // drops them). Forget it; its next message spawns a fresh one.
                    tracing::error!(%icao, "aircraft task gone; its messages of this batch are lost");
                    ctx.registry.remove(icao);
                    stats.tracks_active.dec();
                    aircraft.remove(&icao);
                }
            }
        }
        if rx.is_empty() {
            stats.router_idle();
        }
        // Reap finished tasks without waiting.
        while tasks.try_join_next().is_some() {}
    }
    stats.router_idle();
    drop(aircraft);
    while tasks.join_next().await.is_some() {}
}

/// What became of an aircraft's messages of a batch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Delivery {
    /// Sent, or dropped and counted under [`Overload::Drop`].
    Sent,
    /// The task is gone (its messages dropped and counted).
    Gone,
    /// Shutdown came while waiting for room.
    Shutdown,
}

/// Sends `handle`'s pending messages to its task: waiting for room in the frame budget
/// ([`Stats::reserve_frames`]) and in the aircraft's channel, or, under the drop policy,
/// dropping them (counted) when there is none.
async fn deliver(
    handle: &mut Handle,
    batch: &FrameBatch,
    overload: Overload,
    ctx: &TaskContext,
    drops: &mut DropLog,
) -> Delivery {
    // An aircraft replaced in this batch (silent past the retirement delay, then heard
    // again) is listed twice among those touched: the second time it has nothing pending.
    // Nothing is sent then, and it is not "seen" at the batch's newest time: that made its
    // next silence look shorter by up to a batch's span of feed time, so how often a track
    // was retired depended on how the file was read (LAX: 247 tracks with 256 KiB chunks,
    // 244 with 1 MiB ones).
    let Some(last) = handle.pending.last().map(|d| d.time_s) else {
        return Delivery::Sent;
    };
    let stats = &ctx.stats;
    let arrived = batch.arrived;
    let done = batch.done.clone();
    let msgs = std::mem::take(&mut handle.pending);
    handle.last_batch_len = msgs.len();
    handle.last_seen_s = handle.last_seen_s.max(last);
    handle.last_arrival = arrived;
    let n = msgs.len();
    // Under backpressure, room in the frame budget and in the channel now (as nearly always)
    // sends the batch without building the futures of the waiting path (a cancellation
    // future registered and removed under the token's lock on every batch: 0.5 % of a
    // `kalman-cv` fleet replay's instructions); shutdown is still seen first.
    if overload == Overload::Backpressure && ctx.shutdown.is_cancelled() {
        return Delivery::Shutdown;
    }
    let permits = match (stats.try_reserve_frames(n), overload) {
        (Some(permits), _) => permits,
        // No room in the budget: wait for it, or for shutdown.
        (None, Overload::Backpressure) => tokio::select! {
            biased;
            _ = ctx.shutdown.cancelled() => return Delivery::Shutdown,
            permits = stats.reserve_frames(n) => permits,
        },
        // Shed without building the batch.
        (None, Overload::Drop) => {
            drops.dropped(n as u64, stats);
            return Delivery::Sent;
        }
    };
    let batch = Box::new(AircraftBatch {
        msgs,
        arrived,
        permits,
        done,
    });
    let sent = match (handle.tx.try_send(batch), overload) {
        // The channel is full: wait for room, or for shutdown (the batch's frames given
        // back to the budget). The drop policy sheds it below.
        (Err(mpsc::error::TrySendError::Full(batch)), Overload::Backpressure) => {
            tokio::select! {
                biased;
                _ = ctx.shutdown.cancelled() => {
                    stats.release_frames(permits);
                    return Delivery::Shutdown;
                }
                r = handle.tx.send(batch) => {
                    r.map_err(|e| mpsc::error::TrySendError::Closed(e.0))
                }
            }
        }
        (other, _) => other,
    };
    match sent {
        Ok(()) => Delivery::Sent,
        Err(mpsc::error::TrySendError::Full(m)) => {
            stats.release_frames(m.permits);
            drops.dropped(n as u64, stats);
            Delivery::Sent
        }
        Err(mpsc::error::TrySendError::Closed(m)) => {
            stats.release_frames(m.permits);
            drops.dropped(n as u64, stats);
            Delivery::Gone
        }
    }
}

/// A new aircraft: its registry slot, its task, and the router's handle on it. Counted in
/// `tracks_created` and `tracks_active`, which thus always equals what the registry lists:
/// the router alone registers and removes aircraft, and counts both.
fn spawn_aircraft(
    icao: Icao,
    time_s: f64,
    arrived: Instant,
    cfg: &RouterConfig,
    ctx: &Arc<TaskContext>,
    tasks: &mut JoinSet<()>,
) -> Handle {
    let (tx, rx) = mpsc::channel(cfg.channel_capacity);
    let slot = ctx.registry.register(icao);
    ctx.stats.tracks_created.inc();
    ctx.stats.tracks_active.inc();
    tasks.spawn(run_task(
        Box::new(Aircraft::new(icao, &cfg.aircraft)),
        rx,
        slot,
        ctx.clone(),
    ));
    Handle {
        tx,
        last_seen_s: time_s,
        last_arrival: arrived,
        pending: Vec::new(),
        last_batch_len: 4,
    }
}

/// Retires aircraft that received nothing for `idle` of wall-clock time: the feed-time sweep
/// cannot see them when the feed's clock stopped with the feed.
fn retire_wall_idle(aircraft: &mut FxHashMap<Icao, Handle>, idle: Duration, ctx: &TaskContext) {
    aircraft.retain(|icao, h| {
        let keep = h.last_arrival.elapsed() < idle;
        if !keep {
            tracing::debug!(%icao, "idle, retiring");
            ctx.registry.remove(*icao);
            ctx.stats.tracks_retired.inc();
            ctx.stats.tracks_active.dec();
        }
        keep
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::registry::Registry;
    use crate::output::UpdateFeed;
    use tokio_util::sync::CancellationToken;

    fn context() -> TaskContext {
        TaskContext {
            registry: Arc::new(Registry::default()),
            stats: Arc::new(Stats::new()),
            updates: None,
            feed: Arc::new(UpdateFeed::default()),
            shutdown: CancellationToken::new(),
            prediction_horizons_s: Vec::new(),
        }
    }

    /// A handle on a channel of one batch, with `n` messages pending.
    fn handle(n: usize) -> (Handle, mpsc::Receiver<Box<AircraftBatch>>) {
        let (tx, rx) = mpsc::channel(1);
        let mut h = Handle {
            tx,
            last_seen_s: 0.0,
            last_arrival: Instant::now(),
            pending: Vec::new(),
            last_batch_len: 0,
        };
        fill(&mut h, n);
        (h, rx)
    }

    fn fill(h: &mut Handle, n: usize) {
        h.pending = (0..n)
            .map(|k| Heard {
                time_s: k as f64,
                payload: 5,
                icao: Icao(0x4840d6),
                df: 11,
                signal: None,
                corrected_bits: 0,
            })
            .collect();
    }

    fn batch() -> FrameBatch {
        FrameBatch {
            feed: Arc::from("test"),
            frames: Vec::new(),
            arrived: Instant::now(),
            done: None,
        }
    }

    /// Under backpressure a batch goes at once while there is room, waits while the
    /// aircraft's channel is full (nothing dropped), and on shutdown gives up its place in
    /// the frame budget.
    #[tokio::test]
    async fn a_full_channel_is_waited_for_and_shutdown_ends_the_wait() {
        let ctx = context();
        let mut drops = DropLog::default();
        let (mut h, mut rx) = handle(3);
        let b = batch();
        let sent = deliver(&mut h, &b, Overload::Backpressure, &ctx, &mut drops).await;
        assert_eq!(sent, Delivery::Sent);
        assert_eq!(ctx.stats.aircraft_queued(), 3);

        // The channel (one batch) is full: the next one waits until the task takes one.
        fill(&mut h, 2);
        let mut waiting = Box::pin(deliver(
            &mut h,
            &b,
            Overload::Backpressure,
            &ctx,
            &mut drops,
        ));
        assert!(
            tokio::time::timeout(Duration::from_millis(50), &mut waiting)
                .await
                .is_err(),
            "sent into a full channel"
        );
        let first = rx.recv().await.expect("the first batch");
        assert_eq!((first.msgs.len(), first.permits), (3, 3));
        assert_eq!(waiting.await, Delivery::Sent);
        assert_eq!(ctx.stats.aircraft_queued(), 5);

        // Full again (the second batch is not taken): shutdown ends the wait, and the
        // waiting batch's frames leave the budget.
        ctx.stats.release_frames(first.permits);
        fill(&mut h, 4);
        let waiting = deliver(&mut h, &b, Overload::Backpressure, &ctx, &mut drops);
        let stop = async {
            tokio::time::sleep(Duration::from_millis(20)).await;
            ctx.shutdown.cancel();
        };
        let (delivered, ()) = tokio::join!(waiting, stop);
        assert_eq!(delivered, Delivery::Shutdown);
        assert_eq!(ctx.stats.aircraft_queued(), 2);
        let second = rx.try_recv().expect("the second batch");
        assert_eq!((second.msgs.len(), second.permits), (2, 2));
        // Once shut down, nothing more is sent, room or not.
        fill(&mut h, 1);
        let late = deliver(&mut h, &b, Overload::Backpressure, &ctx, &mut drops).await;
        assert_eq!(late, Delivery::Shutdown);
        assert!(rx.try_recv().is_err());
    }

    /// An aircraft with nothing pending (listed twice among those touched, when it was
    /// replaced in the batch) is sent nothing and is not marked as heard at the batch's
    /// time: its next silence is measured from its last message.
    #[tokio::test]
    async fn nothing_pending_sends_nothing_and_is_not_heard() {
        let ctx = context();
        let mut drops = DropLog::default();
        let (mut h, mut rx) = handle(1);
        h.last_seen_s = 12.5;
        h.pending.clear();
        let sent = deliver(&mut h, &batch(), Overload::Backpressure, &ctx, &mut drops).await;
        assert_eq!(sent, Delivery::Sent);
        assert!(rx.try_recv().is_err());
        assert_eq!(h.last_seen_s, 12.5);
        assert_eq!(ctx.stats.aircraft_queued(), 0);
    }

    /// A batch for a task that is gone is counted as dropped, its frames given back.
    #[tokio::test]
    async fn a_gone_task_is_reported_and_its_frames_released() {
        let ctx = context();
        let mut drops = DropLog::default();
        let (mut h, rx) = handle(3);
        drop(rx);
        let sent = deliver(&mut h, &batch(), Overload::Backpressure, &ctx, &mut drops).await;
        assert_eq!(sent, Delivery::Gone);
        assert_eq!(ctx.stats.aircraft_queued(), 0);
        assert_eq!(ctx.stats.channel_dropped_messages.get(), 3);
    }
}
