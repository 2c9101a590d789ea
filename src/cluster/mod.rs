//! Past one machine (`[cluster]`, issue 14): the daemon split into roles over NATS
//! JetStream, partitioned by ICAO address (`docs/scale-out.md` has the design).
//!
//! - [`ingest`]: feeds -> CRC check and address -> frame packs on `adsb.frames.<p>`;
//! - [`track`]: partition leases, today's routers and aircraft tasks per owned partition,
//!   acknowledgement once processed, tracks to the `adsb-tracks` bucket;
//! - [`api`]: the bucket -> a registry -> today's HTTP API.
//!
//! A process runs any non-empty subset of the roles; with no `[cluster]` section none of
//! this runs and the daemon is one process with no bus, as before. The wire format
//! ([`wire`]), the de-duplication ([`dedup`]) and the bucket values ([`state`]) are pure and
//! tested beside their code; `tests/cluster_nats.rs` runs the roles as separate processes
//! against a real NATS server.

pub mod api;
pub mod bus;
pub mod dedup;
pub mod ingest;
pub mod state;
mod stats;
pub mod track;
pub mod wire;

pub use stats::{ClusterSnapshot, ClusterStats};

use crate::config::{Config, Role};
use crate::daemon::registry::Registry;
use crate::daemon::stats::Stats;
use crate::daemon::{Daemon, DaemonError, RunOptions, RunSummary, Shared, Source};
use crate::decode::DecoderConfig;
use crate::output::UpdateFeed;
use bus::{Bus, NatsBus, NatsSettings};
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

/// Wait between attempts to reach the NATS server at start.
const CONNECT_RETRY: Duration = Duration::from_secs(1);

/// Runs this node's roles until `shutdown`, serving its HTTP API (the merged tracks on an
/// api node; on the others, their own state, `/healthz` and `/metrics`) on `listener`.
/// `source` is what an ingest node reads.
pub async fn run(
    config: Config,
    source: Source,
    listener: Option<TcpListener>,
    shutdown: CancellationToken,
) -> Result<RunSummary, DaemonError> {
    let Some(c) = config.cluster.clone() else {
        return Err(DaemonError::Config("no [cluster] section".into()));
    };
    let cstats = Arc::new(ClusterStats::new(&c.node_id, &c.roles));
    let stats = Arc::new(Stats::for_cluster(
        config.pipeline.max_queued_frames,
        config.pipeline.max_lag_s,
        cstats.clone(),
    ));
    let settings = || NatsSettings {
        url: &c.nats_url,
        partitions: c.partitions,
        lease_ttl: Duration::from_secs_f64(c.lease_ttl_s),
        retention: Duration::from_secs_f64(c.retention_s),
        max_inflight: c.max_inflight,
    };
    let bus = loop {
        match NatsBus::connect(settings()).await {
            Ok(b) => break b,
            // A cluster created otherwise is a configuration error: no retry can mend it.
            Err(e) if e.what == "cluster.partitions" => {
                return Err(DaemonError::Config(e.to_string()))
            }
            Err(e) => {
                tracing::warn!(error = %e, "NATS not ready; retrying");
                tokio::select! {
                    _ = shutdown.cancelled() => return Err(DaemonError::Died("stopped before NATS was reachable".into())),
                    _ = tokio::time::sleep(CONNECT_RETRY) => {}
                }
            }
        }
    };
    cstats
        .connected
        .store(true, std::sync::atomic::Ordering::Release);
    tracing::info!(node = %c.node_id, roles = ?c.roles, partitions = c.partitions, url = %c.nats_url, "cluster node up");
    let mut roles = tokio::task::JoinSet::new();
    roles.spawn(watch_connection(
        bus.clone(),
        cstats.clone(),
        shutdown.clone(),
    ));

    // Track: today's daemon with no feed of its own; its routers are the partitions'.
    let daemon = if c.has(Role::Track) {
        let d = Daemon::start_with_stats(
            config.clone(),
            RunOptions {
                source: Source::Feeds(Vec::new()),
                tracks_out: None,
                exit_at_end: false,
            },
            shutdown.clone(),
            stats.clone(),
        )
        .await?;
        let spawner = d
            .router_spawner()
            .ok_or_else(|| DaemonError::Died("the daemon stopped at start".into()))?;
        roles.spawn(track::run(
            bus.clone(),
            c.clone(),
            spawner,
            d.shared().registry.clone(),
            cstats.clone(),
            shutdown.clone(),
        ));
        Some(d)
    } else {
        None
    };

    let standalone = |registry: Arc<Registry>| Shared {
        registry,
        stats: stats.clone(),
        config: Arc::new(config.clone()),
        feed: Arc::new(UpdateFeed::default()),
        shutdown: shutdown.clone(),
    };
    let served = if c.has(Role::Api) {
        let shared = standalone(Arc::new(Registry::with_history(config.history)));
        roles.spawn(api::run(
            bus.clone(),
            shared.clone(),
            cstats.clone(),
            shutdown.clone(),
        ));
        shared
    } else if let Some(d) = &daemon {
        d.shared().clone()
    } else {
        standalone(Arc::new(Registry::with_history(config.history)))
    };

    if c.has(Role::Ingest) {
        let (tx, rx) = tokio::sync::mpsc::channel(8);
        let (mut feeds, replay) =
            crate::daemon::spawn_source(&source, &config, &stats, tx, &shutdown);
        let decoder = DecoderConfig {
            fix_single_bit: config.decode.fix_single_bit,
            recent_address_s: config.decode.recent_address_s,
        };
        roles.spawn(ingest::run(
            bus.clone(),
            c.clone(),
            decoder,
            rx,
            stats.clone(),
            cstats.clone(),
            shutdown.clone(),
        ));
        roles.spawn(async move {
            while feeds.join_next().await.is_some() {}
            if let Some(r) = replay {
                match r.await {
                    Ok(Ok(s)) => tracing::info!(frames = s.frames, "replay read to its end"),
                    Ok(Err(e)) => tracing::error!(error = %e, "replay failed"),
                    Err(e) => tracing::error!(error = %e, "replay task failed"),
                }
            }
        });
    }

    let server = match listener {
        Some(l) => Some(
            crate::api::server::spawn(l, served, shutdown.clone())
                .map_err(|e| DaemonError::Io("starting the HTTP server".into(), e))?,
        ),
        None => None,
    };
    shutdown.cancelled().await;
    while roles.join_next().await.is_some() {}
    let summary = match daemon {
        Some(d) => d.finished().await?,
        None => RunSummary {
            stats: stats.snapshot(),
            replay: None,
        },
    };
    if let Some(server) = server {
        if let Err(e) = server.stopped().await {
            tracing::warn!(error = %e, "HTTP server ended with an error");
        }
    }
    Ok(summary)
}

/// Keeps `connected` current (what `/healthz` reports) and logs its changes.
async fn watch_connection<B: Bus>(bus: B, cstats: Arc<ClusterStats>, stop: CancellationToken) {
    let mut tick = tokio::time::interval(Duration::from_millis(500));
    let mut was = true;
    loop {
        tokio::select! {
            _ = stop.cancelled() => return,
            _ = tick.tick() => {}
        }
        let now = bus.is_connected();
        cstats
            .connected
            .store(now, std::sync::atomic::Ordering::Release);
        if now != was {
            if now {
                tracing::info!("NATS connection back");
            } else {
                tracing::warn!("NATS connection lost; the client reconnects");
            }
            was = now;
        }
    }
}
