//! The command line: parses arguments, binds sockets, installs SIGINT/SIGTERM, and calls the
//! library. Everything else lives in the library so tests can run it.

use adsb_tracker::app::{self, RunOptions};
use adsb_tracker::config::{Config, MAX_SPEED, MIN_SPEED};
use adsb_tracker::daemon::source::{Replay, ReplayData};
use adsb_tracker::daemon::Source;
use adsb_tracker::feed::Format;
use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use tokio_util::sync::CancellationToken;

/// jemalloc: the router allocates each aircraft's batch on one core and the aircraft task
/// frees it on the other; glibc's arena lock serialised the two, and mimalloc held more
/// memory per aircraft (Cargo.toml).
#[global_allocator]
static GLOBAL: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

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
        /// Without feeds, the embedded recording to replay: `lax` (the default, 182
        /// aircraft around Los Angeles) or `afr34zg` (one flight, Paris CDG to Toulouse);
        /// overrides replay.embedded.
        #[arg(long)]
        embedded: Option<String>,
    },
    /// Run the same pipeline on a recording.
    Replay {
        file: PathBuf,
        /// auto, beast, avr, csv, iso or jsonl.
        #[arg(long, default_value = "auto")]
        format: String,
        /// Feed seconds per wall second, or `max`.
        #[arg(long, default_value = "max", allow_negative_numbers = true)]
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
    /// Simulate a scenario: writes PREFIX.beast, PREFIX.avr and PREFIX.truth.csv.
    Simulate {
        /// A built-in scenario name (paper000..paper003, departure, approach, approach-baro, airliner-nacp10, airliner-gnss-velocity, airliner-stale, airliner-timing, turns-undeclared, turns-correlated) or a TOML file.
        scenario: String,
        #[arg(long)]
        out: PathBuf,
        /// Seed (default: the scenario's).
        #[arg(long)]
        seed: Option<u64>,
    },
    /// Score trackers against simulated truth: Monte Carlo runs of a scenario
    /// (`--scenario`), or an existing `--tracks-out` file against a truth CSV
    /// (`--truth` and `--tracks`).
    Evaluate {
        #[arg(long, conflicts_with_all = ["truth", "tracks", "recording"])]
        scenario: Option<String>,
        /// Real recordings (comma-separated): consistency without truth, per declared NACp
        /// (diverging share, windowed NIS in its band, pos_sigma_m against the scatter of
        /// the decoded positions).
        #[arg(long, conflicts_with_all = ["truth", "tracks"])]
        recording: Option<String>,
        /// Frames per second of feed time for untimed frames of `--recording` files.
        #[arg(long, default_value_t = 1000.0)]
        nominal_rate: f64,
        /// Monte Carlo runs, 1..=100000.
        #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..=100_000))]
        runs: u64,
        /// Comma-separated tracker names (`--tracker NAME` for one).
        #[arg(long, alias = "tracker", default_value = "hybrid,kalman-cv,imm")]
        trackers: String,
        /// Seed of the first run (run k uses seed + k).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, requires = "tracks")]
        truth: Option<PathBuf>,
        #[arg(long)]
        tracks: Option<PathBuf>,
        /// The recording the tracks came from: its decoded positions give the raw-measurement
        /// errors to compare with (with --truth/--tracks).
        #[arg(long, requires = "tracks")]
        frames: Option<PathBuf>,
        /// Directory for the JSON results and the SVG plots.
        #[arg(long, default_value = "evaluation")]
        out: PathBuf,
        #[arg(long)]
        config: Option<PathBuf>,
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

/// `evaluate`: Monte Carlo on a scenario, or scoring an existing tracks file.
#[allow(clippy::too_many_arguments)]
fn evaluate(
    cfg: &Config,
    scenario: Option<String>,
    runs: u64,
    trackers: &str,
    seed: u64,
    truth: Option<PathBuf>,
    tracks: Option<PathBuf>,
    frames: Option<PathBuf>,
    out: &std::path::Path,
) -> Result<()> {
    use adsb_tracker::eval::{bench, io, plot, report};
    let (title, results) = match (scenario, truth, tracks) {
        (Some(name), None, None) => {
            let sc = adsb_tracker::sim::load_scenario(&name)?;
            let names: Vec<String> = trackers.split(',').map(|s| s.trim().to_string()).collect();
            for n in &names {
                if !adsb_tracker::config::ALGORITHMS.contains(&n.as_str()) {
                    bail!(
                        "--trackers: unknown {n:?}; expected some of {}",
                        adsb_tracker::config::ALGORITHMS.join(", ")
                    );
                }
            }
            if runs == 0 {
                bail!("--runs must be at least 1");
            }
            let title = format!("{name}, {runs} runs");
            let exp = bench::monte_carlo(&sc, &names, runs, seed, cfg, &out.join("work"))?;
            let _ = std::fs::remove_dir_all(out.join("work"));
            // A scenario given as a file is named by its stem: its plots go in `out`, not
            // beside the file (an absolute path would replace `out`) or in subdirectories of
            // `out` that nobody created.
            let stem = std::path::Path::new(&name)
                .file_stem()
                .map_or_else(|| name.clone(), |s| s.to_string_lossy().into_owned());
            let plots =
                plot::plot_run(&out.join(&stem), &stem, &exp.first_truth, &exp.first_traces)
                    .map_err(anyhow::Error::msg)?;
            for p in plots {
                eprintln!("wrote {}", p.display());
            }
            (title, exp.results)
        }
        (None, Some(truth), Some(tracks)) => {
            let t = io::parse_truth(&io::read(&truth)?, &truth.display().to_string())?;
            let e = io::parse_tracks(&io::read(&tracks)?, &tracks.display().to_string())?;
            // Raw positions: the recording's frames through the daemon's decode and CPR.
            let raw = match &frames {
                Some(f) => {
                    bench::track_frames(&bench::read_frames(f, None)?, cfg, &cfg.tracker.algorithm)
                        .raw
                }
                None => Default::default(),
            };
            let trace = bench::RunTrace { estimates: e, raw };
            let scores = bench::score_trace(&t, &trace);
            let stem = tracks
                .file_stem()
                .map_or("tracks".to_string(), |s| s.to_string_lossy().to_string());
            let plots = plot::plot_run(&out.join(&stem), &stem, &t, &[(stem.clone(), trace)])
                .map_err(anyhow::Error::msg)?;
            for p in plots {
                eprintln!("wrote {}", p.display());
            }
            (
                format!("{} against {}", tracks.display(), truth.display()),
                vec![report::TrackerResult::new(stem, 1, scores)],
            )
        }
        (None, None, Some(tracks)) => {
            // A real recording has no truth: plot each aircraft's mode timeline.
            let e = io::parse_tracks(&io::read(&tracks)?, &tracks.display().to_string())?;
            for (icao, est) in &e {
                let p = plot::plot_timeline(&out.join(icao.to_string()), &icao.to_string(), est)
                    .map_err(anyhow::Error::msg)?;
                eprintln!("wrote {}", p.display());
            }
            return Ok(());
        }
        _ => bail!(
            "evaluate needs --scenario NAME, or --truth FILE and --tracks FILE (or --tracks \
             alone for mode timelines)"
        ),
    };
    print!("{}", report::markdown(&title, &results));
    let json_path = out.join("results.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&results)?)
        .with_context(|| format!("writing {}", json_path.display()))?;
    eprintln!("wrote {}", json_path.display());
    Ok(())
}

/// `evaluate --recording`: consistency on real recordings, per tracker and declared NACp.
fn evaluate_recordings(
    cfg: &Config,
    recordings: &str,
    trackers: &str,
    nominal_rate_hz: f64,
    out: &std::path::Path,
) -> Result<()> {
    use adsb_tracker::eval::consistency;
    if !(nominal_rate_hz.is_finite() && nominal_rate_hz > 0.0) {
        bail!("--nominal-rate must be a positive number of frames per second");
    }
    let mut results = Vec::new();
    let mut lags = String::new();
    for path in recordings.split(',').map(str::trim) {
        let path = PathBuf::from(path);
        let (frames, pace) = consistency::read_recording(
            &path,
            None,
            nominal_rate_hz,
            cfg.decode.fit_untimed_clock,
        )?;
        let name = path
            .file_name()
            .map_or("recording".to_string(), |s| s.to_string_lossy().to_string());
        if let Some(p) = pace {
            eprintln!(
                "{name}: clock learned from {} straight, steady intervals ({} left out): \
                 real/nominal rate {:.3} overall, {:.3}..{:.3}, residual rms {:.2} sigma",
                p.intervals - p.rejected,
                p.rejected,
                p.mean_rate,
                p.min_rate,
                p.max_rate,
                p.rms_normalised_residual
            );
        }
        lags.push_str(&adsb_tracker::eval::latency::markdown_rows(&name, &frames));
        for tracker in trackers.split(',').map(str::trim) {
            if !adsb_tracker::config::ALGORITHMS.contains(&tracker) {
                bail!("--trackers: unknown {tracker:?}");
            }
            let groups = consistency::measure(&frames, cfg, tracker);
            results.push(consistency::RecordingResult {
                recording: name.clone(),
                tracker: tracker.to_string(),
                groups,
            });
        }
    }
    print!("{}", consistency::markdown(&results));
    println!();
    print!("{}{lags}", adsb_tracker::eval::latency::MARKDOWN_HEADER);
    let json_path = out.join("consistency.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&results)?)
        .with_context(|| format!("writing {}", json_path.display()))?;
    eprintln!("wrote {}", json_path.display());
    Ok(())
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
        embedded: None,
    });
    let shutdown = CancellationToken::new();
    match command {
        Command::Serve {
            config,
            listen,
            embedded,
        } => {
            let mut cfg = load_config(config.as_ref())?;
            if let Some(l) = listen {
                cfg.server.listen = l;
            }
            if let Some(e) = embedded {
                cfg.replay.embedded = e;
            }
            cfg.validate()?;
            let listener = tokio::net::TcpListener::bind(&cfg.server.listen)
                .await
                .with_context(|| format!("binding {}", cfg.server.listen))?;
            let source = app::serve_source(&mut cfg)?;
            tracing::info!("serving on http://{}", listener.local_addr()?);
            install_signals(shutdown.clone());
            if cfg.cluster.is_some() {
                // `[cluster]`: this process's roles over NATS (docs/scale-out.md).
                adsb_tracker::cluster::run(cfg, source, Some(listener), shutdown).await?;
                return Ok(());
            }
            app::run(
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
                    Ok(v) if (MIN_SPEED..=MAX_SPEED).contains(&v) => v,
                    _ => bail!(
                        "--speed: expected `max` or a number within {MIN_SPEED}..={MAX_SPEED}, got {s:?}"
                    ),
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
            let summary = app::run(
                cfg.clone(),
                RunOptions {
                    source: Source::Replay(Replay {
                        data: ReplayData::File(file),
                        format: parse_format(&format)?,
                        speed,
                        loop_: false,
                        nominal_rate_hz: cfg.decode.nominal_rate_hz,
                        fit_untimed_clock: cfg.decode.fit_untimed_clock,
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
        Command::Simulate {
            scenario,
            out,
            seed,
        } => {
            let sc = adsb_tracker::sim::load_scenario(&scenario)?;
            let seed = seed.unwrap_or(sc.settings.seed);
            let summary = adsb_tracker::sim::simulate(&sc, seed, &out)?;
            println!("{}", serde_json::to_string_pretty(&summary)?);
        }
        Command::Evaluate {
            recording: Some(recording),
            trackers,
            nominal_rate,
            out,
            config,
            ..
        } => {
            let cfg = load_config(config.as_ref())?;
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            evaluate_recordings(&cfg, &recording, &trackers, nominal_rate, &out)?;
        }
        Command::Evaluate {
            scenario,
            runs,
            trackers,
            seed,
            truth,
            tracks,
            frames,
            out,
            config,
            ..
        } => {
            let cfg = load_config(config.as_ref())?;
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            evaluate(
                &cfg, scenario, runs, &trackers, seed, truth, tracks, frames, &out,
            )?;
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
