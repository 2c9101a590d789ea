//! A cluster node's counters: `/metrics` `adsb_cluster_*`, `/api/v1/stats` and `/healthz`
//! `cluster`. Every node counts what its roles do; the rest stay zero.

use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

type Labels = Vec<(&'static str, String)>;

/// Every cluster counter of one node.
#[derive(Debug, Default)]
pub struct ClusterStats {
    /// `cluster.node_id`.
    pub node_id: String,
    /// `cluster.roles`.
    pub roles: Vec<&'static str>,
    /// True while the NATS connection is up.
    pub connected: AtomicBool,
    /// Ingest: frames and packs published (acknowledged by the stream).
    pub frames_published: Counter,
    pub packs_published: Counter,
    /// Ingest: publishes retried after a failure or a lost acknowledgement.
    pub publish_retries: Counter,
    /// Ingest: frames the decoder refused before publication (CRC, unknown address).
    pub frames_unroutable: Counter,
    /// Track: frames taken from the bus and handed to the aircraft.
    pub frames_consumed: Counter,
    /// Track: bus messages delivered more than once (a previous owner died before
    /// acknowledging them, or an acknowledgement was lost).
    pub redeliveries: Counter,
    /// Track: frames dropped as duplicates of another receiver's ([`super::dedup`]).
    pub duplicates_dropped: Counter,
    /// Track: packs (or pack tails) that could not be read, counted, skipped.
    pub bad_packs: Counter,
    /// Track: partitions this node holds the lease of now.
    pub leases_held: Gauge,
    /// Track: partitions taken over after another node held them.
    pub takeovers: Counter,
    /// Track: frames replayed from a partition's start to rebuild its aircraft on takeover.
    pub warmup_frames: Counter,
    /// Track: messages of the partition not yet delivered to this node, per partition.
    pub consumer_pending: Family<Labels, Gauge>,
    /// Track: tracks put to and deleted from the key-value bucket; failed operations.
    pub kv_puts: Counter,
    pub kv_deletes: Counter,
    pub kv_errors: Counter,
    /// Api: key-value changes applied to the served state.
    pub api_updates: Counter,
    /// Partitions held now (for the JSON views).
    owned: Mutex<Vec<u32>>,
}

impl ClusterStats {
    pub fn new(node_id: &str, roles: &[crate::config::Role]) -> Self {
        Self {
            node_id: node_id.to_string(),
            roles: roles.iter().map(|r| r.as_str()).collect(),
            ..Self::default()
        }
    }

    pub fn set_owned(&self, mut partitions: Vec<u32>) {
        partitions.sort_unstable();
        self.leases_held.set(partitions.len() as i64);
        if let Ok(mut o) = self.owned.lock() {
            *o = partitions;
        }
    }

    pub fn set_pending(&self, partition: u32, pending: u64) {
        self.consumer_pending
            .get_or_create(&vec![("partition", partition.to_string())])
            .set(pending.min(i64::MAX as u64) as i64);
    }

    pub fn is_connected(&self) -> bool {
        self.connected.load(Ordering::Acquire)
    }

    pub fn register(&self, registry: &mut prometheus_client::registry::Registry) {
        let counters: [(&str, &str, &Counter); 14] = [
            (
                "cluster_frames_published",
                "Frames published to the bus (acknowledged)",
                &self.frames_published,
            ),
            (
                "cluster_packs_published",
                "Bus messages (frame packs) published",
                &self.packs_published,
            ),
            (
                "cluster_publish_retries",
                "Publishes retried",
                &self.publish_retries,
            ),
            (
                "cluster_frames_unroutable",
                "Frames the ingest decoder refused (no partition)",
                &self.frames_unroutable,
            ),
            (
                "cluster_frames_consumed",
                "Frames taken from the bus and tracked",
                &self.frames_consumed,
            ),
            (
                "cluster_redeliveries",
                "Bus messages delivered more than once",
                &self.redeliveries,
            ),
            (
                "cluster_duplicates_dropped",
                "Frames dropped as another receiver's duplicate",
                &self.duplicates_dropped,
            ),
            (
                "cluster_bad_packs",
                "Frame packs (or pack tails) that could not be read",
                &self.bad_packs,
            ),
            (
                "cluster_takeovers",
                "Partitions taken over from another node",
                &self.takeovers,
            ),
            (
                "cluster_warmup_frames",
                "Frames replayed to rebuild a taken-over partition",
                &self.warmup_frames,
            ),
            (
                "cluster_kv_puts",
                "Tracks put to the key-value bucket",
                &self.kv_puts,
            ),
            (
                "cluster_kv_deletes",
                "Tracks deleted from the key-value bucket",
                &self.kv_deletes,
            ),
            (
                "cluster_kv_errors",
                "Failed key-value operations",
                &self.kv_errors,
            ),
            (
                "cluster_api_updates",
                "Key-value changes applied to the served state",
                &self.api_updates,
            ),
        ];
        for (name, help, c) in counters {
            registry.register(name, help, c.clone());
        }
        registry.register(
            "cluster_leases_held",
            "Partitions whose lease this node holds",
            self.leases_held.clone(),
        );
        registry.register(
            "cluster_consumer_pending",
            "Messages of the partition not yet delivered to this node",
            self.consumer_pending.clone(),
        );
    }

    pub fn snapshot(&self) -> ClusterSnapshot {
        let pending = self
            .owned
            .lock()
            .map(|o| o.clone())
            .unwrap_or_default()
            .into_iter()
            .map(|p| {
                let v = self
                    .consumer_pending
                    .get_or_create(&vec![("partition", p.to_string())])
                    .get();
                (p.to_string(), v.max(0) as u64)
            })
            .collect();
        ClusterSnapshot {
            node_id: self.node_id.clone(),
            roles: self.roles.clone(),
            connected: self.is_connected(),
            partitions_owned: self.owned.lock().map(|o| o.clone()).unwrap_or_default(),
            consumer_pending: pending,
            frames_published: self.frames_published.get(),
            packs_published: self.packs_published.get(),
            publish_retries: self.publish_retries.get(),
            frames_unroutable: self.frames_unroutable.get(),
            frames_consumed: self.frames_consumed.get(),
            redeliveries: self.redeliveries.get(),
            duplicates_dropped: self.duplicates_dropped.get(),
            bad_packs: self.bad_packs.get(),
            takeovers: self.takeovers.get(),
            warmup_frames: self.warmup_frames.get(),
            kv_puts: self.kv_puts.get(),
            kv_deletes: self.kv_deletes.get(),
            kv_errors: self.kv_errors.get(),
            api_updates: self.api_updates.get(),
        }
    }
}

/// The cluster counters of `/api/v1/stats` and `/healthz`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, utoipa::ToSchema)]
pub struct ClusterSnapshot {
    pub node_id: String,
    pub roles: Vec<&'static str>,
    /// The NATS connection is up.
    pub connected: bool,
    /// Partitions whose lease this node holds.
    pub partitions_owned: Vec<u32>,
    /// Messages not yet delivered to this node, per owned partition.
    pub consumer_pending: BTreeMap<String, u64>,
    pub frames_published: u64,
    pub packs_published: u64,
    pub publish_retries: u64,
    pub frames_unroutable: u64,
    pub frames_consumed: u64,
    pub redeliveries: u64,
    pub duplicates_dropped: u64,
    pub bad_packs: u64,
    pub takeovers: u64,
    pub warmup_frames: u64,
    pub kv_puts: u64,
    pub kv_deletes: u64,
    pub kv_errors: u64,
    pub api_updates: u64,
}
