//! `[cluster]`: one daemon's role in an ICAO-partitioned cluster over NATS JetStream
//! (issue 14, `docs/scale-out.md`). Absent, the daemon runs as it always did: one process, no
//! bus. `nats_url`, `roles`, `node_id` and `partitions` are the contract deployments rely on;
//! the other keys have defaults.

use super::{bad, int_within, seconds_within, ConfigError};
use serde::Deserialize;

/// What a node does.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Reads the feeds (or the replay), CRC-checks and publishes each message to its
    /// partition's subject.
    Ingest,
    /// Owns partitions (leases), tracks their aircraft, publishes their tracks.
    Track,
    /// Serves the HTTP API from the merged tracks of every track node.
    Api,
}

impl Role {
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Ingest => "ingest",
            Role::Track => "track",
            Role::Api => "api",
        }
    }
}

/// Most partitions: a durable consumer and a router each on the node that owns them.
pub const MAX_PARTITIONS: u32 = 1024;

/// `[cluster]`.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ClusterConfig {
    /// The NATS server, `nats://host:port`: any server of a NATS cluster, or several,
    /// comma-separated.
    pub nats_url: String,
    /// This process's roles: any non-empty subset of `ingest`, `track`, `api`.
    pub roles: Vec<Role>,
    /// Unique per process: the lease holder's name, the receiver id of what it ingests.
    pub node_id: String,
    /// Partitions of the ICAO address space, fixed when the cluster is created (the first
    /// node records it; a node configured otherwise refuses to start).
    pub partitions: u32,
    /// A partition lease lapses this long after its holder's last renewal (renewed every
    /// third of it): how long a dead track node's partitions wait for a new owner, s.
    #[serde(default = "default_lease_ttl_s")]
    pub lease_ttl_s: f64,
    /// The same frame from another receiver within this much feed time is a duplicate
    /// (dropped, counted), s. 0: no de-duplication.
    #[serde(default = "default_dedup_window_s")]
    pub dedup_window_s: f64,
    /// How often a track node publishes its changed tracks to the key-value bucket, s.
    #[serde(default = "default_publish_period_s")]
    pub publish_period_s: f64,
    /// How long the frame stream keeps messages, s: the window a takeover can rebuild an
    /// aircraft's state from (it replays its partition from the stream's start).
    #[serde(default = "default_retention_s")]
    pub retention_s: f64,
    /// Publishes an ingest node awaits the acknowledgement of at once: its backpressure
    /// (it reads nothing more until the oldest is acknowledged).
    #[serde(default = "default_max_inflight")]
    pub max_inflight: usize,
    /// Most messages a track node pulls from one partition per batch.
    #[serde(default = "default_fetch_messages")]
    pub fetch_messages: usize,
}

fn default_lease_ttl_s() -> f64 {
    3.0
}
fn default_dedup_window_s() -> f64 {
    0.5
}
fn default_publish_period_s() -> f64 {
    0.5
}
fn default_retention_s() -> f64 {
    3600.0
}
fn default_max_inflight() -> usize {
    256
}
fn default_fetch_messages() -> usize {
    64
}

impl ClusterConfig {
    pub fn has(&self, role: Role) -> bool {
        self.roles.contains(&role)
    }

    pub(super) fn validate(&self) -> Result<(), ConfigError> {
        if self
            .nats_url
            .split(',')
            .map(str::trim)
            .any(|u| u.is_empty() || u.chars().any(char::is_whitespace))
        {
            return Err(bad(
                "cluster.nats_url",
                "expected nats://host:port, or several separated by commas",
            ));
        }
        if self.roles.is_empty() {
            return Err(bad(
                "cluster.roles",
                "must name at least one of \"ingest\", \"track\", \"api\"",
            ));
        }
        let mut seen = self.roles.clone();
        seen.sort();
        seen.dedup();
        if seen.len() != self.roles.len() {
            return Err(bad("cluster.roles", "a role is named twice"));
        }
        // The node id is a key in the lease bucket and a token of the consumer names:
        // NATS allows letters, digits, '-' and '_' there.
        if self.node_id.is_empty()
            || self.node_id.len() > 64
            || !self
                .node_id
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(bad(
                "cluster.node_id",
                "1 to 64 letters, digits, '-' or '_'",
            ));
        }
        int_within("cluster.partitions", self.partitions, 1, MAX_PARTITIONS)?;
        seconds_within("cluster.lease_ttl_s", self.lease_ttl_s, 1.0, 600.0)?;
        seconds_within("cluster.dedup_window_s", self.dedup_window_s, 0.0, 60.0)?;
        seconds_within(
            "cluster.publish_period_s",
            self.publish_period_s,
            0.05,
            60.0,
        )?;
        seconds_within(
            "cluster.retention_s",
            self.retention_s,
            60.0,
            30.0 * 86_400.0,
        )?;
        int_within("cluster.max_inflight", self.max_inflight, 1, 65_536)?;
        int_within("cluster.fetch_messages", self.fetch_messages, 1, 10_000)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::config::Config;

    fn with(section: &str) -> Result<Config, String> {
        Config::from_toml_str(section).map_err(|e| e.to_string())
    }

    #[test]
    fn absent_means_one_process() {
        assert_eq!(with("").map(|c| c.cluster), Ok(None));
    }

    #[test]
    fn the_contract_keys_load_and_the_rest_default() {
        let c = with(
            "[cluster]\nnats_url = \"nats://127.0.0.1:4222\"\nroles = [\"ingest\", \"track\", \"api\"]\nnode_id = \"track-1\"\npartitions = 16\n",
        )
        .expect("valid");
        let cl = c.cluster.expect("cluster");
        assert_eq!(cl.partitions, 16);
        assert_eq!(cl.roles.len(), 3);
        assert_eq!(cl.lease_ttl_s, 3.0);
        assert_eq!(cl.dedup_window_s, 0.5);
    }

    #[test]
    fn bad_values_are_refused_by_name() {
        let base = |extra: &str, roles: &str, id: &str, parts: u32| {
            format!("[cluster]\nnats_url = \"nats://h:4222\"\nroles = {roles}\nnode_id = \"{id}\"\npartitions = {parts}\n{extra}")
        };
        for (toml, key) in [
            (base("", "[]", "a", 4), "cluster.roles"),
            (base("", "[\"track\", \"track\"]", "a", 4), "cluster.roles"),
            (base("", "[\"track\"]", "a.b", 4), "cluster.node_id"),
            (base("", "[\"track\"]", "", 4), "cluster.node_id"),
            (base("", "[\"track\"]", "a", 0), "cluster.partitions"),
            (base("", "[\"track\"]", "a", 5000), "cluster.partitions"),
            (
                base("lease_ttl_s = 0.1", "[\"track\"]", "a", 4),
                "cluster.lease_ttl_s",
            ),
        ] {
            let e = with(&toml).expect_err(&toml);
            assert!(e.contains(key), "{toml}: {e}");
        }
        let e = with(&base("", "[\"tracker\"]", "a", 4)).expect_err("unknown role");
        assert!(e.contains("tracker"), "{e}");
    }
}
