//! The daemon: wires feeds, the router, aircraft tasks, the registry and the outputs.
//!
//! It serves nothing itself: it exposes its state and its broadcast of updates ([`Shared`])
//! and the entry point ([`crate::app`]) hands them to the HTTP API, so `daemon` never
//! imports `api`. One [`CancellationToken`] is the shutdown: every task selects on it, and
//! [`Daemon::finished`] waits for all of them (dropped senders and `JoinSet`s, never a
//! polled flag).

pub mod aircraft;
pub mod history;
pub mod pipeline;
pub mod registry;
pub mod router;
pub mod source;
pub mod stats;

use crate::config::{Config, TrackerConfig};
use crate::decode::cpr::CprConfig;
use crate::decode::DecoderConfig;
use crate::feed::tcp::{FeedStatus, FrameBatch, TcpFeed};
use crate::output::UpdateFeed;
use crate::track::cv::{CvKalman, CvParams};
use crate::track::Tracker;
use aircraft::{AircraftConfig, TaskContext};
use registry::Registry;
use router::RouterConfig;
use source::{Replay, ReplayProgress};
use stats::Stats;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// Capacity of the feed -> router channel, in batches: a socket read of up to 256 KiB
/// (~11,000 Beast frames) or a file chunk of 1 MiB (~45,000). Four hold half a second of a
/// 100 k frames/s feed while the router is busy; more would only hold memory (a replay
/// fills whatever it is given: eight 1 MiB chunks were 8 MiB more of RSS for no speed).
const FEED_CHANNEL_BATCHES: usize = 4;

/// Where the frames come from.
#[derive(Clone, Debug)]
pub enum Source {
    /// Live TCP feeds (reconnecting forever).
    Feeds(Vec<crate::config::FeedConfig>),
    /// A recording.
    Replay(Replay),
}

/// What to run besides the pipeline.
pub struct RunOptions {
    pub source: Source,
    /// Write every track update as a JSON line here.
    pub tracks_out: Option<PathBuf>,
    /// Return once a (non-looping) replay is fully processed, instead of running until
    /// shutdown.
    pub exit_at_end: bool,
}

/// Why the daemon stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// (Each variant says its cause in its message, and has no separate `source`: an error
    /// chain printed in full says each thing once.)
    #[error("replay: {0}")]
    Replay(crate::feed::FeedError),
    #[error("{0}: {1}")]
    Io(String, std::io::Error),
    #[error("a daemon task failed: {0}")]
    Join(tokio::task::JoinError),
    /// A task that must run until shutdown ended before it.
    #[error("{0}")]
    Died(String),
    /// A setting the source cannot be made from.
    #[error("{0}")]
    Config(String),
}

impl From<crate::feed::FeedError> for DaemonError {
    fn from(e: crate::feed::FeedError) -> Self {
        Self::Replay(e)
    }
}

impl From<tokio::task::JoinError> for DaemonError {
    fn from(e: tokio::task::JoinError) -> Self {
        Self::Join(e)
    }
}

/// What a finished run saw.
#[derive(Debug)]
pub struct RunSummary {
    pub stats: stats::StatsSnapshot,
    /// Replay parse counters, when the source was a replay that finished.
    pub replay: Option<crate::feed::ParseStats>,
}

/// What a running daemon exposes to its readers (the HTTP API, wired by the entry point):
/// its snapshots, its counters, its configuration, its broadcast of updates, and the
/// shutdown every long-lived reader ends on.
#[derive(Clone)]
pub struct Shared {
    pub registry: Arc<Registry>,
    pub stats: Arc<Stats>,
    pub config: Arc<Config>,
    /// Every tracker update and retirement, while anyone listens ([`UpdateFeed::listen`]).
    pub feed: Arc<UpdateFeed>,
    /// Cancelled when the daemon shuts down.
    pub shutdown: CancellationToken,
}

/// Builds the tracker `cfg.algorithm` names (validated at config load against
/// [`crate::config::ALGORITHMS`]).
///
/// The tuning comes from `cfg` (`[tracker.gate]`, `.imm`, `.divergence`, `.hybrid` and the CV
/// noise), which [`crate::config::Config::validate`] has checked: the fall-backs to the
/// code's defaults are never taken for a loaded configuration.
pub fn build_tracker(cfg: &TrackerConfig) -> Box<dyn Tracker> {
    use crate::track::hybrid::{HybridParams, HybridTracker};
    use crate::track::imm::{ImmTracker, ImmTrackerParams};
    let hybrid = |paper002_gate: bool| -> Box<dyn Tracker> {
        Box::new(HybridTracker::new(
            cfg.hybrid_params(paper002_gate)
                .unwrap_or_else(|_| HybridParams::default()),
        ))
    };
    match cfg.algorithm.as_str() {
        "kalman-cv" => Box::new(CvKalman::new(
            cfg.cv_params().unwrap_or_else(|_| CvParams::default()),
        )),
        "imm" => Box::new(ImmTracker::new(
            cfg.imm_tracker_params()
                .unwrap_or_else(|_| ImmTrackerParams::default()),
        )),
        "hybrid-paper002" => hybrid(true),
        // The other papers' trackers; "hybrid", the default, for anything else (validation
        // refuses unknown names before we get here).
        other => crate::track::build_alternative(other).unwrap_or_else(|| hybrid(false)),
    }
}

/// A running daemon: the pipeline and its feeds, started by [`Daemon::start`]. The entry
/// point hands [`Daemon::shared`] to whatever serves it (the HTTP API), then waits in
/// [`Daemon::finished`].
pub struct Daemon {
    shared: Shared,
    opts: RunOptions,
    pipeline_stop: CancellationToken,
    outputs_stop: CancellationToken,
    writer: Option<tokio::task::JoinHandle<Result<(), DaemonError>>>,
    outputs: Option<crate::output::Outputs>,
    /// What routers and aircraft tasks share; kept for [`Daemon::spawn_router`] until
    /// [`Daemon::finished`] lets it go (the update writer ends with its last holder).
    ctx: Option<Arc<TaskContext>>,
    lag_monitor: tokio::task::JoinHandle<()>,
    router: tokio::task::JoinHandle<()>,
    feed_tasks: tokio::task::JoinSet<()>,
    replay_task:
        Option<tokio::task::JoinHandle<Result<crate::feed::ParseStats, crate::feed::FeedError>>>,
}

/// Runs the daemon until `shutdown` (or, with `exit_at_end`, the end of a replay), serving
/// nothing: [`Daemon::start`] then [`Daemon::finished`].
pub async fn run(
    config: Config,
    opts: RunOptions,
    shutdown: CancellationToken,
) -> Result<RunSummary, DaemonError> {
    Daemon::start(config, opts, shutdown)
        .await?
        .finished()
        .await
}

impl Daemon {
    /// Starts the outputs, the pipeline and the feeds (or the replay).
    pub async fn start(
        config: Config,
        opts: RunOptions,
        shutdown: CancellationToken,
    ) -> Result<Self, DaemonError> {
        let stats = Arc::new(Stats::for_pipeline(
            config.pipeline.max_queued_frames,
            config.pipeline.max_lag_s,
        ));
        Self::start_with_stats(config, opts, shutdown, stats).await
    }

    /// [`Daemon::start`] counting into `stats` (a cluster node's one set of counters, which
    /// its other roles share).
    pub async fn start_with_stats(
        config: Config,
        opts: RunOptions,
        shutdown: CancellationToken,
        stats: Arc<Stats>,
    ) -> Result<Self, DaemonError> {
        let shared = Shared {
            registry: Arc::new(Registry::with_history(config.history)),
            stats,
            config: Arc::new(config.clone()),
            feed: Arc::new(UpdateFeed::default()),
            shutdown: shutdown.clone(),
        };
        // The pipeline has its own token, a child of the caller's: the end of a replay stops
        // the pipeline without stopping the caller's other work, and shutdown stops both.
        let pipeline_stop = shutdown.child_token();

        // Track update lines (--tracks-out): a writer task, lossless (tasks wait for it).
        let (updates_tx, writer) = match &opts.tracks_out {
            Some(path) => {
                let file = tokio::fs::File::create(path)
                    .await
                    .map_err(|e| DaemonError::Io(path.display().to_string(), e))?;
                let (tx, mut rx) = mpsc::channel::<Vec<u8>>(1024);
                let path = path.clone();
                let writer = tokio::spawn(async move {
                    let mut out = tokio::io::BufWriter::with_capacity(1 << 20, file);
                    while let Some(lines) = rx.recv().await {
                        out.write_all(&lines)
                            .await
                            .map_err(|e| DaemonError::Io(path.display().to_string(), e))?;
                    }
                    out.flush()
                        .await
                        .map_err(|e| DaemonError::Io(path.display().to_string(), e))
                });
                (Some(tx), Some(writer))
            }
            None => (None, None),
        };

        // The outputs (`[output.*]`): bound before the pipeline starts, so a bad address
        // fails the start and no update is missed. They listen for the daemon's life.
        let outputs_stop = shutdown.child_token();
        let outputs = if config.output.any() {
            shared.feed.hold();
            Some(
                crate::output::Outputs::start(
                    &config.output,
                    shared.feed.sender(),
                    shared.stats.outputs.clone(),
                    outputs_stop.clone(),
                )
                .await
                .map_err(|(what, e)| DaemonError::Io(what, e))?,
            )
        } else {
            None
        };

        let ctx = Arc::new(TaskContext {
            registry: shared.registry.clone(),
            stats: shared.stats.clone(),
            updates: updates_tx,
            feed: shared.feed.clone(),
            shutdown: pipeline_stop.clone(),
            prediction_horizons_s: config.tracker.prediction_horizons_s.clone(),
        });
        let lag_monitor = tokio::spawn(monitor_lag(shared.stats.clone(), pipeline_stop.clone()));

        let (batch_tx, batch_rx) = mpsc::channel::<FrameBatch>(FEED_CHANNEL_BATCHES);
        // A replay always waits: an evaluation must see every frame.
        let overload = if matches!(opts.source, Source::Replay(_)) {
            router::Overload::Backpressure
        } else {
            config.pipeline.overload
        };
        let router = spawn_router(batch_rx, router_config(&config, overload), ctx.clone());

        // The feeds.
        let (feed_tasks, replay_task) = spawn_source(
            &opts.source,
            &config,
            &shared.stats,
            batch_tx,
            &pipeline_stop,
        );
        Ok(Self {
            shared,
            opts,
            pipeline_stop,
            outputs_stop,
            writer,
            outputs,
            ctx: Some(ctx),
            lag_monitor,
            router,
            feed_tasks,
            replay_task,
        })
    }

    /// What the daemon exposes to its readers.
    pub fn shared(&self) -> &Shared {
        &self.shared
    }

    /// What starts more routers into this daemon's registry: a cluster track node runs one
    /// per partition it owns ([`RouterSpawner`]). `None` once the daemon is finishing.
    pub fn router_spawner(&self) -> Option<RouterSpawner> {
        Some(RouterSpawner {
            config: self.shared.config.clone(),
            ctx: self.ctx.clone()?,
        })
    }
}

/// Starts routers, each with its own decoder, aircraft and feed clock, publishing into one
/// daemon's registry. A cluster track node runs one per partition, so that each partition
/// keeps its own feed clock (a partition replayed from its start after a takeover must not
/// look 'silent' against the others and have its aircraft retired). Always lossless
/// (backpressure): a bus message is acknowledged only once processed.
#[derive(Clone)]
pub struct RouterSpawner {
    config: Arc<Config>,
    ctx: Arc<TaskContext>,
}

impl RouterSpawner {
    /// A router on `rx`: it ends when `rx` closes (its aircraft drain first) or when the
    /// daemon stops.
    pub fn spawn(&self, rx: mpsc::Receiver<FrameBatch>) -> tokio::task::JoinHandle<()> {
        spawn_router(
            rx,
            router_config(&self.config, router::Overload::Backpressure),
            self.ctx.clone(),
        )
    }

    /// Cancelled when the pipeline stops: its aircraft tasks then drop what they had not
    /// processed yet, so nothing released after it may be acknowledged.
    pub fn stopping(&self) -> &CancellationToken {
        &self.ctx.shutdown
    }
}

/// The router's settings from the configuration.
fn router_config(config: &Config, overload: router::Overload) -> RouterConfig {
    RouterConfig {
        decoder: DecoderConfig {
            fix_single_bit: config.decode.fix_single_bit,
            recent_address_s: config.decode.recent_address_s,
        },
        aircraft: AircraftConfig {
            cpr: CprConfig {
                pair_window_s: config.cpr.pair_window_s,
                max_speed_mps: config.cpr.max_speed_mps,
                max_surface_speed_mps: config.cpr.max_surface_speed_mps,
                receiver: config.receiver.map(|r| (r.lat_deg, r.lon_deg)),
                ..CprConfig::default()
            },
            tracker: build_tracker,
            tracker_config: config.tracker.clone(),
            duplicate_window_s: config.decode.duplicate_window_s,
        },
        retire_after_s: config.tracker.retire_after_s,
        idle: Duration::try_from_secs_f64(config.tracker.retire_after_s).unwrap_or(Duration::MAX),
        channel_capacity: config.tracker.channel_capacity,
        overload,
    }
}

/// Spawns a router.
fn spawn_router(
    rx: mpsc::Receiver<FrameBatch>,
    cfg: RouterConfig,
    ctx: Arc<TaskContext>,
) -> tokio::task::JoinHandle<()> {
    // Unconstrained: the router sends one message per aircraft per batch, a thousand at
    // fleet scale, and tokio's cooperative budget (128 operations) made it yield to the
    // back of the run queue several times a batch: 35 % more CPU for the same work. It
    // still yields whenever it waits (an empty feed channel, a full aircraft channel).
    tokio::spawn(tokio::task::unconstrained(router::run_router(rx, cfg, ctx)))
}

/// The tasks reading a source.
type SourceTasks = (
    tokio::task::JoinSet<()>,
    Option<tokio::task::JoinHandle<Result<crate::feed::ParseStats, crate::feed::FeedError>>>,
);

/// Starts the source's readers, sending into `batch_tx`: a TCP client per feed (its status
/// registered in `stats`), or the replay on a blocking thread. A cluster ingest node reads
/// its source with the same code.
pub fn spawn_source(
    source: &Source,
    config: &Config,
    stats: &Arc<Stats>,
    batch_tx: mpsc::Sender<FrameBatch>,
    pipeline_stop: &CancellationToken,
) -> SourceTasks {
    let mut feed_tasks = tokio::task::JoinSet::new();
    let mut replay_task = None;
    match source {
        Source::Feeds(feeds) => {
            for f in feeds {
                let feed = TcpFeed {
                    name: f.name.clone(),
                    addr: f.addr.clone(),
                    format: f.format,
                    nominal_rate_hz: config.decode.nominal_rate_hz,
                    silence_timeout_s: f.silence_timeout_s,
                };
                let status = Arc::new(FeedStatus::with_silence_timeout(
                    f.name.as_str(),
                    feed.silence_timeout(),
                ));
                stats.add_feed(status.clone());
                feed_tasks.spawn(crate::feed::tcp::run_client(
                    feed,
                    batch_tx.clone(),
                    status,
                    pipeline_stop.clone(),
                ));
            }
        }
        Source::Replay(replay) => {
            let replay = replay.clone();
            let tx = batch_tx.clone();
            let stop = pipeline_stop.clone();
            let progress = Arc::new(ReplayProgress::default());
            replay_task = Some(tokio::task::spawn_blocking(move || {
                source::run_replay(&replay, &tx, &progress, &stop)
            }));
        }
    }
    drop(batch_tx);
    (feed_tasks, replay_task)
}
impl Daemon {
    /// Waits until shutdown (or, with `exit_at_end`, the end of a replay), then for every
    /// task. A pipeline task that dies first cancels the shutdown token (everything else
    /// stops too) and is the error returned.
    pub async fn finished(self) -> Result<RunSummary, DaemonError> {
        let Self {
            shared,
            opts,
            pipeline_stop,
            outputs_stop,
            writer,
            outputs,
            ctx,
            lag_monitor,
            router,
            mut feed_tasks,
            replay_task,
        } = self;
        // Routers and aircraft tasks hold their own; the update writer ends with the last.
        drop(ctx);
        let shutdown = shared.shutdown.clone();
        let mut replay_stats = None;
        if let Some(task) = replay_task {
            tokio::select! {
                r = task => replay_stats = Some(r??),
                _ = shutdown.cancelled() => {}
            }
            router_done(router, &pipeline_stop, false).await?;
            shared
                .stats
                .replay_finished
                .store(replay_stats.is_some(), std::sync::atomic::Ordering::Release);
            if !opts.exit_at_end {
                // Keep serving the last state until shutdown.
                shutdown.cancelled().await;
            }
        } else {
            // Live: the router and the feed clients run until shutdown. One that ends before
            // has died (a panic): serving a dead pipeline with a healthy /healthz would hide
            // it, so the daemon stops with an error (a non-zero exit for its supervisor).
            let mut router = router;
            let died = tokio::select! {
                biased;
                _ = shutdown.cancelled() => None,
                r = &mut router => Some(match r {
                    Err(e) => format!("the router task failed: {e}"),
                    Ok(()) => "the router task ended".to_string(),
                }),
                Some(r) = feed_tasks.join_next(), if !feed_tasks.is_empty() => Some(match r {
                    Err(e) => format!("a feed task failed: {e}"),
                    Ok(()) => "a feed task ended".to_string(),
                }),
            };
            // A task that ended because shutdown began (its token is a child of ours) did
            // not die.
            let died = died.filter(|_| !shutdown.is_cancelled());
            pipeline_stop.cancel();
            while feed_tasks.join_next().await.is_some() {}
            if let Some(why) = died {
                tracing::error!("{why}: stopping the daemon");
                shared
                    .stats
                    .pipeline_failed
                    .store(true, std::sync::atomic::Ordering::Release);
                shutdown.cancel();
                return Err(DaemonError::Died(why));
            }
            router_done(router, &pipeline_stop, true).await?;
        }
        pipeline_stop.cancel();
        let _ = lag_monitor.await;
        if let Some(w) = writer {
            w.await??;
        }
        if let Some(outputs) = outputs {
            outputs_stop.cancel();
            outputs.stopped().await;
        }
        Ok(RunSummary {
            stats: shared.stats.snapshot(),
            replay: replay_stats,
        })
    }
}

/// How often the lag monitor looks at the ingest lag.
const LAG_CHECK_PERIOD: Duration = Duration::from_millis(250);

/// Watches the ingest lag and logs its episodes past `pipeline.max_lag_s`: one warning when
/// one starts, one note with the worst lag when it ends. (`/healthz` and the stats read the
/// lag themselves.)
async fn monitor_lag(stats: Arc<Stats>, stop: CancellationToken) {
    let mut tick = tokio::time::interval(LAG_CHECK_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // The worst lag of the episode under way, if one is.
    let mut episode_worst_s: Option<f64> = None;
    loop {
        tokio::select! {
            _ = stop.cancelled() => return,
            _ = tick.tick() => {}
        }
        let lag_s = stats.ingest_lag_s();
        let max_s = stats.max_lag_s();
        match (episode_worst_s, lag_s > max_s) {
            (None, true) => {
                episode_worst_s = Some(lag_s);
                tracing::warn!(
                    lag_s = format_args!("{lag_s:.1}"),
                    queued_frames = stats.aircraft_queued(),
                    queued_batches = stats.router_queued(),
                    "ingest is falling behind real time (pipeline.max_lag_s = {max_s} s)"
                );
            }
            (Some(worst_s), true) => episode_worst_s = Some(worst_s.max(lag_s)),
            (Some(worst_s), false) => {
                episode_worst_s = None;
                tracing::info!(
                    worst_lag_s = format_args!("{worst_s:.1}"),
                    "ingest caught up"
                );
            }
            (None, false) => {}
        }
    }
}

/// Waits for the router (and so every aircraft task) to finish. After a replay the channel is
/// closed and the router drains; on shutdown it is cancelled.
async fn router_done(
    router: tokio::task::JoinHandle<()>,
    stop: &CancellationToken,
    cancel: bool,
) -> Result<(), DaemonError> {
    if cancel {
        stop.cancel();
    }
    router.await?;
    Ok(())
}
