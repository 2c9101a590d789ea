//! The ingest role: frames from the feeds (or the replay), CRC-checked and addressed by the
//! same decoder as the single process, published in packs to their partition's subject.
//!
//! Lossless by backpressure: at most `cluster.max_inflight` packs await the stream's
//! acknowledgement; past that the role waits, stops reading its channel, the feeds stop
//! reading their sockets and TCP slows the senders (a replay simply waits). A pack whose
//! publication failed is published again under the same message id, which JetStream's
//! duplicate window stores once.

use super::bus::{Bus, PendingAck};
use super::stats::ClusterStats;
use super::wire::{partition_of, PackWriter};
use crate::config::ClusterConfig;
use crate::daemon::stats::Stats;
use crate::decode::{DecodeStats, Decoder, DecoderConfig};
use crate::feed::tcp::FrameBatch;
use bytes::Bytes;
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// A pack is sent once it holds this much, even mid-batch (NATS refuses messages over its
/// `max_payload`, 1 MiB by default).
const MAX_PACK_BYTES: usize = 256 * 1024;
/// Wait between attempts to publish while the bus refuses.
const RETRY_WAIT: Duration = Duration::from_millis(500);

struct InFlight {
    partition: u32,
    id: String,
    payload: Bytes,
    frames: u64,
    /// `None`: its acknowledgement failed; it is to be published again.
    ack: Option<PendingAck>,
}

/// Publishes with its message ids and bounded in-flight acknowledgements.
struct Publisher<B: Bus> {
    bus: B,
    run_id: String,
    seq: u64,
    inflight: VecDeque<InFlight>,
    max_inflight: usize,
    cstats: Arc<ClusterStats>,
}

impl<B: Bus> Publisher<B> {
    /// Publishes (retrying until it is accepted or `stop`); false on stop.
    async fn publish(
        &mut self,
        partition: u32,
        pack: PackWriter,
        stop: &CancellationToken,
    ) -> bool {
        let frames = pack.frames() as u64;
        let payload = Bytes::from(pack.finish());
        self.seq += 1;
        let id = format!("{}-{}", self.run_id, self.seq);
        while self.inflight.len() >= self.max_inflight {
            if !self.settle_oldest(stop).await {
                return false;
            }
        }
        let Some(ack) = send(&self.bus, &self.cstats, partition, &id, &payload, stop).await else {
            return false;
        };
        self.inflight.push_back(InFlight {
            partition,
            id,
            payload,
            frames,
            ack: Some(ack),
        });
        true
    }

    /// Counts the acknowledgements already in, oldest first, without waiting.
    fn settle_ready(&mut self) {
        while let Some(f) = self.inflight.front_mut() {
            let Some(ack) = f.ack.as_mut() else { break };
            match futures_util::FutureExt::now_or_never(ack) {
                Some(Ok(())) => {
                    self.cstats.frames_published.inc_by(f.frames);
                    self.cstats.packs_published.inc();
                    self.inflight.pop_front();
                }
                Some(Err(e)) => {
                    // `settle_oldest` publishes it again.
                    tracing::warn!(error = %e, id = %f.id, "publish not acknowledged");
                    f.ack = None;
                    break;
                }
                None => break,
            }
        }
    }

    /// Waits for the oldest acknowledgement, publishing again until it comes.
    async fn settle_oldest(&mut self, stop: &CancellationToken) -> bool {
        let Some(mut f) = self.inflight.pop_front() else {
            return true;
        };
        loop {
            let r = match f.ack.as_mut() {
                Some(ack) => tokio::select! {
                    _ = stop.cancelled() => return false,
                    r = ack => r,
                },
                None => Err(super::bus::BusError {
                    what: "publishing frames".into(),
                    error: "not acknowledged".into(),
                }),
            };
            match r {
                Ok(()) => {
                    self.cstats.frames_published.inc_by(f.frames);
                    self.cstats.packs_published.inc();
                    return true;
                }
                Err(e) => {
                    self.cstats.publish_retries.inc();
                    tracing::warn!(error = %e, id = %f.id, "publish not acknowledged; publishing again");
                    match send(
                        &self.bus,
                        &self.cstats,
                        f.partition,
                        &f.id,
                        &f.payload,
                        stop,
                    )
                    .await
                    {
                        Some(ack) => f.ack = Some(ack),
                        None => return false,
                    }
                }
            }
        }
    }
}

/// Publishes one pack, retrying while the bus refuses, until `stop`.
async fn send<B: Bus>(
    bus: &B,
    cstats: &ClusterStats,
    partition: u32,
    id: &str,
    payload: &Bytes,
    stop: &CancellationToken,
) -> Option<PendingAck> {
    loop {
        match bus
            .publish(partition, id.to_string(), payload.clone())
            .await
        {
            Ok(ack) => return Some(ack),
            Err(e) => {
                cstats.publish_retries.inc();
                tracing::warn!(error = %e, "publish refused; retrying");
                tokio::select! {
                    _ = stop.cancelled() => return None,
                    _ = tokio::time::sleep(RETRY_WAIT) => {}
                }
            }
        }
    }
}

/// Runs until the source's channel closes (the end of a replay: every pack acknowledged,
/// then `replay_finished` is set) or `stop`.
pub async fn run<B: Bus>(
    bus: B,
    cfg: ClusterConfig,
    decoder: DecoderConfig,
    mut rx: mpsc::Receiver<FrameBatch>,
    stats: Arc<Stats>,
    cstats: Arc<ClusterStats>,
    stop: CancellationToken,
) {
    let mut decoder = Decoder::new(decoder);
    let mut flushed = DecodeStats::default();
    let partitions = cfg.partitions.max(1);
    let mut packs: Vec<Option<PackWriter>> = (0..partitions).map(|_| None).collect();
    let run_id = format!(
        "{}-{}",
        cfg.node_id,
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or_default()
    );
    let mut publisher = Publisher {
        bus,
        run_id,
        seq: 0,
        inflight: VecDeque::new(),
        max_inflight: cfg.max_inflight.max(1),
        cstats: cstats.clone(),
    };
    let mut now_s = f64::NEG_INFINITY;
    'batches: loop {
        let batch = tokio::select! {
            _ = stop.cancelled() => return,
            b = rx.recv() => match b {
                Some(b) => b,
                None => break,
            },
        };
        stats.routing(batch.arrived, rx.len());
        stats.frames_in.inc_by(batch.frames.len() as u64);
        let receiver = format!("{}/{}", cfg.node_id, batch.feed);
        for frame in &batch.frames {
            now_s = now_s.max(frame.time_s);
            let Ok(d) = decoder.decode(frame) else {
                cstats.frames_unroutable.inc();
                continue;
            };
            let p = partition_of(d.icao, partitions);
            let Some(slot) = packs.get_mut(p as usize) else {
                continue;
            };
            let pack = slot.get_or_insert_with(|| PackWriter::new(&receiver));
            pack.push(frame);
            if pack.len_bytes() >= MAX_PACK_BYTES {
                if let Some(full) = slot.take() {
                    if !publisher.publish(p, full, &stop).await {
                        return;
                    }
                }
            }
        }
        stats.observe_feed_time(now_s);
        stats.add_decode(decoder.stats(), &flushed);
        flushed = decoder.stats().clone();
        for (p, slot) in packs.iter_mut().enumerate() {
            if let Some(pack) = slot.take() {
                if !publisher.publish(p as u32, pack, &stop).await {
                    break 'batches;
                }
            }
        }
        publisher.settle_ready();
        if rx.is_empty() {
            stats.router_idle();
        }
    }
    while !publisher.inflight.is_empty() {
        if !publisher.settle_oldest(&stop).await {
            return;
        }
    }
    stats.router_idle();
    stats
        .replay_finished
        .store(true, std::sync::atomic::Ordering::Release);
    tracing::info!(
        frames = cstats.frames_published.get(),
        packs = cstats.packs_published.get(),
        "source ended: every frame published and acknowledged"
    );
}
