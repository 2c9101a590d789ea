//! The track role: partition leases, one worker per owned partition, and the publication of
//! the node's tracks to the bucket.
//!
//! **Leases.** Every third of `cluster.lease_ttl_s` a node puts its member key
//! (`member.<node>`), renews the partition leases it holds (`partition.<p>`, a
//! revision-checked update: a lease someone else took is not renewed, it is lost), lists the
//! live members and takes each free partition whose rendezvous-hash owner among them it is
//! ([`owner_of`]), once the same list has held for two rounds. Every node computes the same
//! owners from the same member list, so two nodes started together split the partitions
//! evenly without talking; when one dies, its
//! member key and leases expire within the TTL and the survivors, whose lists no longer name
//! it, take its partitions. A node that joins later takes only free partitions: nothing is
//! moved from a live owner (moving a partition costs a rebuild, see below).
//!
//! **A partition's worker** takes the partition's durable consumer, resuming after the last
//! acknowledged message ([`Bus::take_partition`]). Its aircraft's state is *re-initialised
//! from the log*: the partition's messages up to that point are replayed from the stream's
//! start (as far as `cluster.retention_s` keeps them) through a fresh router before the live
//! ones, with the same decoder, de-duplication and filters, so a taken-over aircraft has
//! exactly the state its previous owner had — same message counts, same estimate. The cost
//! is the replay: the partition's retained traffic through the tracker once more, at the
//! tracker's speed (measured in `docs/scale-out.md`). The snapshot in the tracks bucket is
//! not used for this: it holds the published estimate, not a filter's full state (an IMM's
//! per-model covariances, the gate's history), and a filter restarted from it would differ.
//!
//! **Acknowledgement.** Each pulled batch goes to the partition's router as one
//! [`FrameBatch`] carrying a [`Completion`]; the ack task waits for the completions in order
//! and acknowledges each batch's last message (cumulative), so a message is acknowledged only
//! once every aircraft processed its share of it. A message of a node that dies before that
//! is delivered again to the next owner.

use super::bus::{Bus, Delivery, PartitionConsumer};
use super::dedup::Dedup;
use super::stats::ClusterStats;
use super::wire;
use crate::config::ClusterConfig;
use crate::daemon::registry::{Published, Registry};
use crate::daemon::RouterSpawner;
use crate::decode::Icao;
use crate::feed::tcp::{Completion, FrameBatch};
use crate::feed::RawFrame;
use bytes::Bytes;
use futures_util::StreamExt;
use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, oneshot};
use tokio_util::sync::CancellationToken;

/// Batches queued for a partition's router: like the daemon's feed channel.
const ROUTER_QUEUE_BATCHES: usize = 8;
/// Batches awaiting their acknowledgement, per partition.
const ACK_QUEUE_BATCHES: usize = 64;
/// Tracks put to the bucket at once.
const KV_CONCURRENCY: usize = 64;

/// The rendezvous-hash (highest random weight) owner of partition `p` among `members`:
/// every node computes the same one from the same list, and a member's leaving moves only
/// its own partitions.
pub fn owner_of(p: u32, members: &[String]) -> Option<&str> {
    members
        .iter()
        .max_by_key(|m| {
            // FNV-1a 64 over the member's name and the partition number, then MurmurHash3's
            // 64-bit finaliser: FNV alone barely mixes its last bytes into the high bits, and
            // names differing in one character ("track-1", "track-2") then compared the same
            // way for every partition (one node took all of them).
            let mut h: u64 = 0xcbf2_9ce4_8422_2325;
            for b in m.as_bytes().iter().chain(p.to_be_bytes().iter()) {
                h ^= u64::from(*b);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
            h ^= h >> 33;
            h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
            h ^= h >> 33;
            h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
            h ^= h >> 33;
            (h, m.as_str())
        })
        .map(String::as_str)
}

fn lease_key(p: u32) -> String {
    format!("partition.{p}")
}

/// One owned partition's worker.
struct Owned {
    revision: u64,
    stop: CancellationToken,
    task: tokio::task::JoinHandle<()>,
}

/// Runs the track role until `stop`: leases, workers, and the bucket publisher.
pub async fn run<B: Bus>(
    bus: B,
    cfg: ClusterConfig,
    spawner: RouterSpawner,
    registry: Arc<Registry>,
    cstats: Arc<ClusterStats>,
    stop: CancellationToken,
) {
    let publisher = tokio::spawn(publish_tracks(
        bus.clone(),
        registry,
        cstats.clone(),
        Duration::from_secs_f64(cfg.publish_period_s),
        stop.clone(),
    ));
    let period = Duration::from_secs_f64(cfg.lease_ttl_s / 3.0);
    let member_key = format!("member.{}", cfg.node_id);
    let mut owned: BTreeMap<u32, Owned> = BTreeMap::new();
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // The first round only announces this node: nodes started together then see each other
    // before anyone takes a partition.
    let mut announced = false;
    let mut known_members: Vec<String> = Vec::new();
    loop {
        tokio::select! {
            _ = stop.cancelled() => break,
            _ = tick.tick() => {}
        }
        // Workers that ended on their own (a bus error) give their partition up.
        let ended: Vec<u32> = owned
            .iter()
            .filter(|(_, o)| o.task.is_finished())
            .map(|(p, _)| *p)
            .collect();
        for p in ended {
            owned.remove(&p);
            let _ = bus.lease_delete(&lease_key(p)).await;
            tracing::warn!(partition = p, "partition worker ended: lease released");
        }
        cstats
            .connected
            .store(bus.is_connected(), std::sync::atomic::Ordering::Release);
        if let Err(e) = bus.lease_put(&member_key, &cfg.node_id).await {
            tracing::warn!(error = %e, "member heartbeat failed");
            continue;
        }
        // Renew, and stop what was lost.
        let mut lost = Vec::new();
        for (p, o) in owned.iter_mut() {
            match bus
                .lease_renew(&lease_key(*p), &cfg.node_id, o.revision)
                .await
            {
                Ok(Some(rev)) => o.revision = rev,
                Ok(None) => lost.push(*p),
                Err(e) => tracing::warn!(partition = p, error = %e, "lease renewal failed"),
            }
        }
        for p in lost {
            if let Some(o) = owned.remove(&p) {
                tracing::warn!(
                    partition = p,
                    "lease lost to another node: stopping its worker"
                );
                o.stop.cancel();
            }
        }
        if !announced {
            announced = true;
            cstats.set_owned(Vec::new());
            continue;
        }
        let members = match bus.lease_list("member.").await {
            Ok(m) => {
                let mut names: Vec<String> = m.into_iter().map(|(_, holder)| holder).collect();
                names.sort();
                names.dedup();
                names
            }
            Err(e) => {
                tracing::warn!(error = %e, "listing members failed");
                continue;
            }
        };
        if members != known_members {
            // A new member list is acted on only once the next round lists it again. Nodes
            // started together do not always see each other in their first listing (the
            // cluster test caught a node listing itself alone 0.7 s after both announced,
            // taking all 16 partitions, so the other got none), and a list that holds for a
            // round is one every node has seen. It costs a takeover one round (a third of
            // the TTL).
            tracing::info!(?members, "track nodes");
            known_members = members;
            cstats.set_owned(owned.keys().copied().collect());
            continue;
        }
        let held: HashMap<String, String> = match bus.lease_list("partition.").await {
            Ok(l) => l.into_iter().collect(),
            Err(e) => {
                tracing::warn!(error = %e, "listing leases failed");
                continue;
            }
        };
        for p in 0..cfg.partitions {
            if owned.contains_key(&p)
                || held.contains_key(&lease_key(p))
                || owner_of(p, &members) != Some(cfg.node_id.as_str())
            {
                continue;
            }
            match bus.lease_create(&lease_key(p), &cfg.node_id).await {
                Ok(Some(revision)) => {
                    let worker_stop = stop.child_token();
                    let task = tokio::spawn(run_partition(
                        bus.clone(),
                        p,
                        cfg.clone(),
                        spawner.clone(),
                        cstats.clone(),
                        worker_stop.clone(),
                    ));
                    tracing::info!(partition = p, "lease taken");
                    owned.insert(
                        p,
                        Owned {
                            revision,
                            stop: worker_stop,
                            task,
                        },
                    );
                }
                Ok(None) => {}
                Err(e) => tracing::warn!(partition = p, error = %e, "taking a lease failed"),
            }
        }
        cstats.set_owned(owned.keys().copied().collect());
    }
    // A clean stop hands the partitions over at once rather than after the TTL.
    for (p, o) in std::mem::take(&mut owned) {
        o.stop.cancel();
        let _ = o.task.await;
        let _ = bus.lease_delete(&lease_key(p)).await;
    }
    let _ = bus.lease_delete(&member_key).await;
    cstats.set_owned(Vec::new());
    let _ = publisher.await;
}

/// Decodes a delivery's pack into `frames`, dropping duplicates (counted).
fn frames_of<H>(
    d: &Delivery<H>,
    dedup: &mut Dedup,
    cstats: &ClusterStats,
    frames: &mut Vec<RawFrame>,
) {
    let mut pack = Vec::new();
    {
        match wire::decode_into(&d.payload, &mut pack) {
            Ok((receiver, damaged)) => {
                if let Some(e) = damaged {
                    cstats.bad_packs.inc();
                    tracing::debug!(error = %e, "damaged frame pack: its good records kept");
                }
                let rx = dedup.receiver(&receiver);
                for f in pack.drain(..) {
                    if dedup.is_duplicate(&f, rx) {
                        cstats.duplicates_dropped.inc();
                    } else {
                        frames.push(f);
                    }
                }
            }
            Err(e) => {
                cstats.bad_packs.inc();
                tracing::debug!(error = %e, "unreadable frame pack skipped");
            }
        }
    }
}

/// One partition: rebuild its aircraft from the log, then follow it, acknowledging what its
/// aircraft processed.
async fn run_partition<B: Bus>(
    bus: B,
    p: u32,
    cfg: ClusterConfig,
    spawner: RouterSpawner,
    cstats: Arc<ClusterStats>,
    stop: CancellationToken,
) {
    let (mut consumer, acked, unacked) = match bus.take_partition(p).await {
        Ok(c) => c,
        Err(e) => {
            tracing::error!(partition = p, error = %e, "cannot take the partition");
            return;
        }
    };
    cstats.redeliveries.inc_by(unacked);
    let feed: Arc<str> = Arc::from(format!("partition-{p}"));
    let (tx, rx) = mpsc::channel::<FrameBatch>(ROUTER_QUEUE_BATCHES);
    let router = spawner.spawn(rx);
    let mut dedup = Dedup::new(cfg.dedup_window_s);
    let mut frames = Vec::new();

    if acked > 0 {
        cstats.takeovers.inc();
        let started = Instant::now();
        let mut replayed = 0u64;
        match bus.replay_partition(p).await {
            Ok(mut replay) => 'replay: loop {
                let batch = tokio::select! {
                    _ = stop.cancelled() => return,
                    b = replay.next_batch(cfg.fetch_messages) => b,
                };
                let batch = match batch {
                    Ok(b) => b,
                    Err(e) => {
                        tracing::error!(partition = p, error = %e, "replay failed: the partition's aircraft start afresh");
                        break 'replay;
                    }
                };
                let upto = batch
                    .iter()
                    .position(|d| d.seq > acked)
                    .unwrap_or(batch.len());
                let done = upto < batch.len() || batch.last().is_some_and(|d| d.seq >= acked);
                for d in batch.get(..upto).unwrap_or_default() {
                    frames_of(d, &mut dedup, &cstats, &mut frames);
                    replayed += frames.len() as u64;
                    cstats.warmup_frames.inc_by(frames.len() as u64);
                    if !frames.is_empty() {
                        let b = FrameBatch {
                            feed: feed.clone(),
                            frames: std::mem::take(&mut frames),
                            arrived: Instant::now(),
                            done: None,
                        };
                        if tx.send(b).await.is_err() {
                            return;
                        }
                    }
                }
                if done {
                    break;
                }
            },
            Err(e) => {
                tracing::error!(partition = p, error = %e, "cannot replay: the partition's aircraft start afresh")
            }
        }
        tracing::info!(
            partition = p,
            through_seq = acked,
            frames = replayed,
            took_s = format_args!("{:.2}", started.elapsed().as_secs_f64()),
            "partition taken over: aircraft rebuilt from the log"
        );
    }

    // Acknowledgements, in order, once processed.
    let (ack_tx, mut ack_rx) = mpsc::channel::<(
        oneshot::Receiver<()>,
        <B::Consumer as PartitionConsumer>::Handle,
    )>(ACK_QUEUE_BATCHES);
    let stopping = spawner.stopping().clone();
    let acker = tokio::spawn(async move {
        while let Some((done, handle)) = ack_rx.recv().await {
            let _ = done.await;
            // Dropped by a pipeline that is stopping is not processed: not acknowledged.
            if stopping.is_cancelled() {
                break;
            }
            if let Err(e) = <B::Consumer as PartitionConsumer>::ack_through(handle).await {
                tracing::warn!(partition = p, error = %e, "acknowledgement failed (the messages will come again)");
            }
        }
    });

    loop {
        let batch = tokio::select! {
            _ = stop.cancelled() => break,
            b = consumer.next_batch(cfg.fetch_messages) => b,
        };
        let mut batch = match batch {
            Ok(b) => b,
            Err(e) => {
                tracing::warn!(partition = p, error = %e, "pull failed");
                tokio::select! {
                    _ = stop.cancelled() => break,
                    _ = tokio::time::sleep(Duration::from_millis(200)) => continue,
                }
            }
        };
        let total = batch.len();
        // One router batch per pack: a pack is one feed read's frames of this partition, so
        // each aircraft gets its messages in the same batches as in a single process (its
        // snapshot is published once per batch), whatever the pull gathered.
        let (completion, done) = Completion::new();
        let arrived = Instant::now();
        let mut stopped = false;
        let mut last = None;
        for (i, d) in batch.drain(..).enumerate() {
            frames_of(&d, &mut dedup, &cstats, &mut frames);
            if i + 1 == total {
                cstats.set_pending(p, d.pending);
                last = Some(d.handle);
            }
            cstats.frames_consumed.inc_by(frames.len() as u64);
            if frames.is_empty() {
                continue;
            }
            let b = FrameBatch {
                feed: feed.clone(),
                frames: std::mem::take(&mut frames),
                arrived,
                done: Some(completion.clone()),
            };
            if tx.send(b).await.is_err() {
                stopped = true;
                break;
            }
        }
        drop(completion);
        let Some(last) = last else { continue };
        if stopped || ack_tx.send((done, last)).await.is_err() {
            break;
        }
    }
    drop(tx);
    drop(ack_tx);
    let _ = router.await;
    let _ = acker.await;
}

/// Puts every changed track of the node's registry to the bucket each `period`, and deletes
/// the retired ones.
async fn publish_tracks<B: Bus>(
    bus: B,
    registry: Arc<Registry>,
    cstats: Arc<ClusterStats>,
    period: Duration,
    stop: CancellationToken,
) {
    let mut last: HashMap<Icao, Arc<Published>> = HashMap::new();
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = stop.cancelled() => break,
            _ = tick.tick() => {}
        }
        let now = registry.all_published();
        let changed: Vec<Arc<Published>> = now
            .iter()
            .filter(|p| last.get(&p.icao).is_none_or(|l| !Arc::ptr_eq(l, p)))
            .cloned()
            .collect();
        let current: std::collections::HashSet<Icao> = now.iter().map(|p| p.icao).collect();
        let gone: Vec<Icao> = last
            .keys()
            .filter(|i| !current.contains(i))
            .copied()
            .collect();
        let results = futures_util::stream::iter(changed)
            .map(|p| {
                let bus = bus.clone();
                async move {
                    let value = Bytes::from(super::state::encode(&p));
                    let r = bus.put_track(&p.icao.to_string(), value).await;
                    (p, r)
                }
            })
            .buffer_unordered(KV_CONCURRENCY)
            .collect::<Vec<_>>()
            .await;
        for (p, r) in results {
            match r {
                Ok(()) => {
                    cstats.kv_puts.inc();
                    last.insert(p.icao, p);
                }
                Err(e) => {
                    cstats.kv_errors.inc();
                    tracing::debug!(error = %e, "track put failed (retried next period)");
                }
            }
        }
        for icao in gone {
            match bus.delete_track(&icao.to_string()).await {
                Ok(()) => {
                    cstats.kv_deletes.inc();
                    last.remove(&icao);
                }
                Err(_) => {
                    cstats.kv_errors.inc();
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rendezvous_owners_split_evenly_and_move_only_the_leavers_share() {
        let three: Vec<String> = ["track-1", "track-2", "track-3"].map(String::from).to_vec();
        let two: Vec<String> = ["track-1", "track-2"].map(String::from).to_vec();
        let mut counts: HashMap<&str, u32> = HashMap::new();
        let mut moved = 0;
        for p in 0..300 {
            let a = owner_of(p, &three).expect("an owner");
            *counts.entry(a).or_default() += 1;
            let b = owner_of(p, &two).expect("an owner");
            if a != "track-3" {
                assert_eq!(a, b, "partition {p} moved though its owner stayed");
            } else {
                moved += 1;
            }
        }
        assert!(
            counts.values().all(|&c| (70..130).contains(&c)),
            "{counts:?}"
        );
        assert_eq!(moved, counts["track-3"]);
        assert_eq!(owner_of(3, &[]), None);
    }
}
