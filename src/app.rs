//! The entry point's wiring: the daemon, and the HTTP API over what it exposes.
//!
//! `main.rs` parses the command line, binds the listener and installs the signal handlers;
//! [`run`] does everything else and is what the tests call. The daemon knows nothing of HTTP
//! ([`crate::daemon::Shared`] is all it shows); the API knows nothing of the daemon's tasks.

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
