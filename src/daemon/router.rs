//! The router: decodes frame batches and hands each aircraft its messages.
//!
//! One router task owns the decoder (CRC, recent-address filter) and the map from ICAO
//! address to aircraft channel, so routing takes no lock. Messages of one batch are grouped
//! per aircraft and sent as one channel message each: a channel hop per frame would cost more
//! than the decoding. A full aircraft channel drops that batch and counts it.

use super::aircraft::{run_task, Aircraft, AircraftConfig, TaskContext};
use super::stats::Stats;
use crate::decode::{DecodeStats, Decoded, Decoder, DecoderConfig, Icao};
use crate::feed::tcp::FrameBatch;
use std::collections::HashMap;
use std::sync::Arc;
use tokio::sync::mpsc;
use tokio::task::JoinSet;

/// How often (feed seconds) the router looks for aircraft to retire.
const SWEEP_PERIOD_S: f64 = 1.0;

struct Handle {
    tx: mpsc::Sender<Vec<Decoded>>,
    last_seen_s: f64,
}

/// Router settings.
pub struct RouterConfig {
    pub decoder: DecoderConfig,
    pub aircraft: AircraftConfig,
    /// Feed seconds of silence after which an aircraft is retired.
    pub retire_after_s: f64,
    /// Capacity of each aircraft channel, in batches.
    pub channel_capacity: usize,
    /// Wait for room in a full aircraft channel instead of dropping (replays: waiting only
    /// slows the replay, and an evaluation must see every frame). Live feeds drop and count.
    pub lossless: bool,
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
    let mut aircraft: HashMap<Icao, Handle> = HashMap::new();
    let mut pending: HashMap<Icao, Vec<Decoded>> = HashMap::new();
    let mut tasks = JoinSet::new();
    let mut next_sweep_s = f64::NEG_INFINITY;
    let mut now_s = f64::NEG_INFINITY;

    loop {
        let batch = tokio::select! {
            biased;
            _ = ctx.shutdown.cancelled() => break,
            b = rx.recv() => match b {
                Some(b) => b,
                None => break,
            },
        };
        stats.frames_in.inc_by(batch.frames.len() as u64);
        for frame in &batch.frames {
            now_s = now_s.max(frame.time_s);
            if let Ok(d) = decoder.decode(frame) {
                pending.entry(d.icao).or_default().push(d);
            }
        }
        stats.observe_feed_time(now_s);
        stats.add_decode(decoder.stats(), &flushed);
        flushed = decoder.stats().clone();

        // Retire before routing, so a replay loop that jumps ahead in time starts afresh.
        if now_s >= next_sweep_s {
            let cutoff = now_s - cfg.retire_after_s;
            aircraft.retain(|icao, h| {
                let keep = h.last_seen_s >= cutoff || pending.contains_key(icao);
                if !keep {
                    tracing::debug!(%icao, "retired after silence");
                    ctx.registry.remove(*icao);
                    stats.tracks_retired.inc();
                }
                keep
            });
            next_sweep_s = now_s + SWEEP_PERIOD_S;
        }

        for (icao, msgs) in pending.drain() {
            let last = msgs.last().map_or(now_s, |d| d.time_s);
            let handle = aircraft.entry(icao).or_insert_with(|| {
                let (tx, rx) = mpsc::channel(cfg.channel_capacity);
                let slot = ctx.registry.register(icao);
                stats.tracks_created.inc();
                stats.tracks_active.inc();
                tasks.spawn(run_task(
                    Aircraft::new(icao, &cfg.aircraft),
                    rx,
                    slot,
                    ctx.clone(),
                ));
                Handle {
                    tx,
                    last_seen_s: last,
                }
            });
            handle.last_seen_s = handle.last_seen_s.max(last);
            let n = msgs.len() as u64;
            let sent = if cfg.lossless {
                handle
                    .tx
                    .send(msgs)
                    .await
                    .map_err(|e| mpsc::error::TrySendError::Closed(e.0))
            } else {
                handle.tx.try_send(msgs)
            };
            match sent {
                Ok(()) => {}
                Err(mpsc::error::TrySendError::Full(_)) => {
                    stats.channel_drops.inc();
                    stats.channel_dropped_messages.inc_by(n);
                }
                Err(mpsc::error::TrySendError::Closed(_)) => {
                    // The task retired on its own (wall-clock idle): forget it; the next
                    // message spawns a fresh one.
                    aircraft.remove(&icao);
                    stats.channel_drops.inc();
                    stats.channel_dropped_messages.inc_by(n);
                }
            }
        }
        // Reap finished tasks without waiting.
        while tasks.try_join_next().is_some() {}
    }
    drop(aircraft);
    while tasks.join_next().await.is_some() {}
}
