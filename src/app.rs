//! The entry point's wiring: the daemon, and the HTTP API over what it exposes.
//!
//! `main.rs` parses the command line, binds the listener and installs the signal handlers;
//! [`run`] does everything else and is what the tests call. The daemon knows nothing of HTTP
//! ([`crate::daemon::Shared`] is all it shows); the API knows nothing of the daemon's tasks.

use crate::config::{Config, ReceiverConfig};
use crate::daemon::source::{embedded, Replay, ReplayData};
use crate::daemon::{Daemon, DaemonError, RunSummary, Source};
use std::path::PathBuf;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

/// What to run: the daemon's options and the API's listener.
pub struct RunOptions {
    pub source: Source,
    /// Serve the HTTP API on this listener.
    pub listener: Option<TcpListener>,
    /// Write every track update as a JSON line here.
    pub tracks_out: Option<PathBuf>,
    /// Return once a (non-looping) replay is fully processed, instead of serving until
    /// shutdown.
    pub exit_at_end: bool,
}

/// Runs the daemon, and the HTTP API on `opts.listener`, until `shutdown` (or, with
/// `exit_at_end`, the end of a replay). The server has a runtime of its own: no client can
/// slow the pipeline's.
pub async fn run(
    config: crate::config::Config,
    opts: RunOptions,
    shutdown: CancellationToken,
) -> Result<RunSummary, DaemonError> {
    let daemon = Daemon::start(
        config,
        crate::daemon::RunOptions {
            source: opts.source,
            tracks_out: opts.tracks_out,
            exit_at_end: opts.exit_at_end,
        },
        shutdown.clone(),
    )
    .await?;
    let server = match opts.listener {
        Some(listener) => Some(
            crate::api::server::spawn(listener, daemon.shared().clone(), shutdown.clone())
                .map_err(|e| DaemonError::Io("starting the HTTP server".into(), e))?,
        ),
        None => None,
    };
    let result = daemon.finished().await;
    if let Some(server) = server {
        if result.is_err() {
            // The pipeline died: the daemon cancelled the shutdown; the server follows.
            shutdown.cancel();
        }
        if let Err(e) = server.stopped().await {
            tracing::warn!(error = %e, "HTTP server ended with an error");
        }
    }
    result
}

/// What `serve` runs: the configured feeds; without any, `replay.file`; without one, the
/// embedded recording `replay.embedded` (the LAX recording by default), replayed at its real
/// rate, whose receiver location stands in for `[receiver]` when that is not configured
/// (surface positions need a reference, readsb's `receiver.json` shows it).
pub fn serve_source(cfg: &mut Config) -> Result<Source, DaemonError> {
    if !cfg.feeds.is_empty() {
        return Ok(Source::Feeds(cfg.feeds.clone()));
    }
    let format = match cfg.replay.format.as_str() {
        "auto" => None,
        f => Some(
            f.parse()
                .map_err(|e: String| DaemonError::Config(format!("replay.format: {e}")))?,
        ),
    };
    let (data, nominal_rate_hz) = if cfg.replay.file.is_empty() {
        // Validation refuses an unknown name.
        let e = embedded(&cfg.replay.embedded).ok_or_else(|| {
            DaemonError::Config(format!(
                "replay.embedded: no recording {:?}",
                cfg.replay.embedded
            ))
        })?;
        if cfg.receiver.is_none() {
            cfg.receiver = Some(ReceiverConfig {
                lat_deg: e.receiver.0,
                lon_deg: e.receiver.1,
            });
        }
        (
            e.data(),
            e.nominal_rate_hz.unwrap_or(cfg.decode.nominal_rate_hz),
        )
    } else {
        (
            ReplayData::File(PathBuf::from(&cfg.replay.file)),
            cfg.decode.nominal_rate_hz,
        )
    };
    tracing::info!(
        ?data,
        speed = cfg.replay.speed,
        nominal_rate_hz,
        "no feed configured: replaying"
    );
    Ok(Source::Replay(Replay {
        data,
        format,
        speed: cfg.replay.speed,
        loop_: cfg.replay.loop_,
        nominal_rate_hz,
        fit_untimed_clock: cfg.decode.fit_untimed_clock,
        loop_gap_s: cfg.tracker.retire_after_s + 1.0,
        progress: false,
    }))
}
