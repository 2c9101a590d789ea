//! The command line: parses arguments, binds sockets, installs SIGINT/SIGTERM, and calls the
//! library. Everything else lives in the library so tests can run it.

use adsb_tracker::config::Config;
use adsb_tracker::daemon::source::{Replay, ReplayData, EMBEDDED_DEFAULT};
use adsb_tracker::daemon::{self, RunOptions, Source};
use adsb_tracker::feed::Format;
use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use tokio_util::sync::CancellationToken;

#[derive(Parser)]
#[command(
    version,
    about = "Track every aircraft of a Mode S / ADS-B feed and serve the estimates over HTTP"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Run the daemon (the default). With no feed configured it replays the embedded
    /// recording in a loop.
    Serve {
        /// Configuration file overriding config/default.toml.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Listen address (overrides server.listen).
        #[arg(long)]
        listen: Option<String>,
    },
    /// Run the same pipeline on a recording.
    Replay {
        file: PathBuf,
        /// auto, beast, avr, csv, iso or jsonl.
        #[arg(long, default_value = "auto")]
        format: String,
        /// Feed seconds per wall second, or `max`.
        #[arg(long, default_value = "max")]
        speed: String,
        /// Write every track update as a JSON line.
        #[arg(long)]
        tracks_out: Option<PathBuf>,
        /// Serve the HTTP API during the replay and after it until Ctrl-C.
        #[arg(long)]
        serve: Option<String>,
        #[arg(long)]
        config: Option<PathBuf>,
        /// Tracker algorithm (overrides tracker.algorithm).
        #[arg(long)]
        tracker: Option<String>,
        /// Frames per second of feed time for frames without a timestamp (`*hex;` AVR);
        /// overrides decode.nominal_rate_hz.
        #[arg(long)]
        nominal_rate: Option<f64>,
    },
    /// Print a full human-readable decode of every frame of a recording.
    Inspect {
        file: PathBuf,
        #[arg(long, default_value = "auto")]
        format: String,
        /// Stop after this many frames.
        #[arg(long)]
        limit: Option<u64>,
    },
}

fn parse_format(s: &str) -> Result<Option<Format>> {
    if s == "auto" {
        return Ok(None);
    }
    s.parse::<Format>().map(Some).map_err(anyhow::Error::msg)
}

fn load_config(path: Option<&PathBuf>) -> Result<Config> {
    Ok(match path {
        Some(p) => Config::load(p)?,
        None => Config::default_config()?,
    })
}

/// Cancels the token on SIGINT or SIGTERM.
fn install_signals(token: CancellationToken) {
    tokio::spawn(async move {
        let ctrl_c = tokio::signal::ctrl_c();
        #[cfg(unix)]
        {
            let mut term =
                match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                    Ok(s) => s,
                    Err(e) => {
                        tracing::warn!(error = %e, "no SIGTERM handler");
                        let _ = ctrl_c.await;
                        token.cancel();
                        return;
                    }
                };
            tokio::select! {
                _ = ctrl_c => {}
                _ = term.recv() => {}
            }
        }
        #[cfg(not(unix))]
        let _ = ctrl_c.await;
        tracing::info!("shutting down");
        token.cancel();
    });
}

#[tokio::main]
async fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let command = cli.command.unwrap_or(Command::Serve {
        config: None,
        listen: None,
    });
    let shutdown = CancellationToken::new();
    match command {
        Command::Serve { config, listen } => {
            let mut cfg = load_config(config.as_ref())?;
            if let Some(l) = listen {
                cfg.server.listen = l;
                cfg.validate()?;
            }
            let listener = tokio::net::TcpListener::bind(&cfg.server.listen)
                .await
                .with_context(|| format!("binding {}", cfg.server.listen))?;
            let source = if cfg.feeds.is_empty() {
                let data = if cfg.replay.file.is_empty() {
                    EMBEDDED_DEFAULT
                } else {
                    ReplayData::File(PathBuf::from(&cfg.replay.file))
                };
                tracing::info!(
                    ?data,
                    speed = cfg.replay.speed,
                    "no feed configured: replaying"
                );
                Source::Replay(Replay {
                    data,
                    format: parse_format(&cfg.replay.format)?,
                    speed: cfg.replay.speed,
                    loop_: cfg.replay.loop_,
                    nominal_rate_hz: cfg.decode.nominal_rate_hz,
                    loop_gap_s: cfg.tracker.retire_after_s + 1.0,
                    progress: false,
                })
            } else {
                Source::Feeds(cfg.feeds.clone())
            };
            tracing::info!("serving on http://{}", listener.local_addr()?);
            install_signals(shutdown.clone());
            daemon::run(
                cfg,
                RunOptions {
                    source,
                    listener: Some(listener),
                    tracks_out: None,
                    exit_at_end: false,
                },
                shutdown,
            )
            .await?;
        }
        Command::Replay {
            file,
            format,
            speed,
            tracks_out,
            serve,
            config,
            tracker,
            nominal_rate,
        } => {
            let mut cfg = load_config(config.as_ref())?;
            if let Some(t) = tracker {
                cfg.tracker.algorithm = t;
            }
            if let Some(r) = nominal_rate {
                cfg.decode.nominal_rate_hz = r;
            }
            cfg.validate()?;
            let speed = match speed.as_str() {
                "max" => 0.0,
                s => match s.parse::<f64>() {
                    Ok(v) if v.is_finite() && v > 0.0 => v,
                    _ => bail!("--speed: expected a number > 0 or `max`, got {s:?}"),
                },
            };
            let listener = match &serve {
                Some(addr) => Some(
                    tokio::net::TcpListener::bind(addr)
                        .await
                        .with_context(|| format!("binding {addr}"))?,
                ),
                None => None,
            };
            if let Some(l) = &listener {
                eprintln!("serving on http://{}", l.local_addr()?);
            }
            install_signals(shutdown.clone());
            let started = std::time::Instant::now();
            let summary = daemon::run(
                cfg.clone(),
                RunOptions {
                    source: Source::Replay(Replay {
                        data: ReplayData::File(file),
                        format: parse_format(&format)?,
                        speed,
                        loop_: false,
                        nominal_rate_hz: cfg.decode.nominal_rate_hz,
                        loop_gap_s: 0.0,
                        progress: true,
                    }),
                    listener,
                    tracks_out,
                    exit_at_end: serve.is_none(),
                },
                shutdown,
            )
            .await?;
            let secs = started.elapsed().as_secs_f64();
            let s = &summary.stats;
            eprintln!(
                "{} frames in {:.3} s ({:.0} frames/s); {} positions, {} track updates, {} aircraft",
                s.frames,
                secs,
                s.frames as f64 / secs.max(1e-9),
                s.positions_accepted,
                s.track_updates,
                s.tracks_created
            );
            println!("{}", serde_json::to_string_pretty(&s)?);
            if let Some(p) = summary.replay {
                eprintln!("parser: {}", serde_json::to_string(&p)?);
            }
        }
        Command::Inspect {
            file,
            format,
            limit,
        } => {
            let out = std::io::stdout();
            let mut out = std::io::BufWriter::new(out.lock());
            adsb_tracker::decode::inspect::inspect_file(
                &file,
                parse_format(&format)?,
                limit,
                &mut out,
            )?;
        }
    }
    Ok(())
}
