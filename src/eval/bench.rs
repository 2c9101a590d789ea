//! Monte Carlo runs: simulate a scenario with one seed per run, feed the very same frames to
//! each tracker through the daemon's own decode and per-aircraft code
//! ([`SyncPipeline`]), and score against the truth.

use super::io::{parse_truth, read, EvalError};
use super::report::TrackerResult;
use super::score::{EstimateSample, RawPosition, Scores};
use crate::config::Config;
use crate::daemon::aircraft::AircraftConfig;
use crate::daemon::pipeline::SyncPipeline;
use crate::daemon::registry::TrackState;
use crate::decode::cpr::CprConfig;
use crate::decode::{DecoderConfig, Icao};
use crate::feed::pace::{learn_clock, PaceSummary};
use crate::feed::replay::FileReader;
use crate::feed::{Format, RawFrame};
use crate::sim::Scenario;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One run of one tracker: what the plots need besides the scores.
#[derive(Clone, Debug, Default)]
pub struct RunTrace {
    pub estimates: BTreeMap<Icao, Vec<EstimateSample>>,
    pub raw: BTreeMap<Icao, Vec<RawPosition>>,
}

/// The estimate line fields the scoring reads, from a published state.
pub fn estimate_from_state(s: &TrackState, cpu_ns: Option<u64>) -> EstimateSample {
    let c = &s.pos_cov_enu_m2;
    let v = &s.vel_cov_enu_m2ps2;
    EstimateSample {
        t: s.t,
        lat: s.lat,
        lon: s.lon,
        alt_m: s.alt_m,
        ve: s.ve,
        vn: s.vn,
        vu: s.vu,
        mode: s.mode.parse().unwrap_or(crate::track::FlightMode::Cv),
        pos_cov_en: Some([[c[0][0], c[0][1]], [c[1][0], c[1][1]]]),
        vel_cov_en: Some([[v[0][0], v[0][1]], [v[1][0], v[1][1]]]),
        cpu_ns,
        nis: s.nis.zip(s.nis_dof),
        diverging: s.diverging,
    }
}

/// The daemon's synchronous pipeline with `config`'s decoder and CPR settings and the tracker
/// `algorithm` (what the bench, and `benches/fleet.rs`, drive).
pub fn sync_pipeline(config: &Config, algorithm: &str) -> SyncPipeline {
    let mut tracker_config = config.tracker.clone();
    tracker_config.algorithm = algorithm.to_string();
    SyncPipeline::new(
        decoder_config(config),
        AircraftConfig {
            cpr: CprConfig {
                pair_window_s: config.cpr.pair_window_s,
                max_speed_mps: config.cpr.max_speed_mps,
                max_surface_speed_mps: config.cpr.max_surface_speed_mps,
                ..CprConfig::default()
            },
            tracker: crate::daemon::build_tracker,
            tracker_config,
            duplicate_window_s: config.decode.duplicate_window_s,
        },
    )
}

/// The decoder the daemon runs with `config` (`[decode]`).
pub fn decoder_config(config: &Config) -> DecoderConfig {
    DecoderConfig {
        fix_single_bit: config.decode.fix_single_bit,
        recent_address_s: config.decode.recent_address_s,
    }
}

/// Runs `frames` through the daemon's pipeline with the tracker `algorithm`.
pub fn track_frames(frames: &[RawFrame], config: &Config, algorithm: &str) -> RunTrace {
    let mut pipeline = sync_pipeline(config, algorithm);
    let mut trace = RunTrace::default();
    for f in frames {
        let Some(u) = pipeline.push(f) else { continue };
        if let Some(s) = &u.state {
            trace
                .estimates
                .entry(s.icao)
                .or_default()
                .push(estimate_from_state(s, Some(u.cpu_ns)));
        }
        if let (Some((t, lat, lon, alt_m)), Some(s)) = (u.fix, &u.state) {
            trace
                .raw
                .entry(s.icao)
                .or_default()
                .push(RawPosition { t, lat, lon, alt_m });
        }
    }
    trace
}

/// Reads every frame of a recording (untimed frames at 1,000 frames/s).
pub fn read_frames(path: &Path, format: Option<Format>) -> Result<Vec<RawFrame>, EvalError> {
    read_frames_at(path, format, 1000.0)
}

/// Reads every frame of a recording, timing untimed frames at `nominal_rate_hz` (their
/// nominal clock: [`read_recording`] learns the real one).
pub fn read_frames_at(
    path: &Path,
    format: Option<Format>,
    nominal_rate_hz: f64,
) -> Result<Vec<RawFrame>, EvalError> {
    Ok(read_recording(path, format, nominal_rate_hz, false)?.0)
}

/// Reads every frame of a recording, timing untimed frames at `nominal_rate_hz`; with
/// `fit_untimed_clock`, a recording with no time of its own is moved to the real clock its
/// aircraft show ([`crate::feed::pace`]), whose fit is returned.
pub fn read_recording(
    path: &Path,
    format: Option<Format>,
    nominal_rate_hz: f64,
    fit_untimed_clock: bool,
) -> Result<(Vec<RawFrame>, Option<PaceSummary>), EvalError> {
    let (mut frames, stats) = FileReader::open(path, format, nominal_rate_hz)
        .and_then(FileReader::read_all)
        .map_err(|e| EvalError::Other(e.to_string()))?;
    let pace = if fit_untimed_clock {
        learn_clock(&mut frames, &stats)
    } else {
        None
    };
    Ok((frames, pace))
}

/// Scores a trace against truth, aircraft by aircraft.
pub fn score_trace(truth: &BTreeMap<Icao, super::score::TruthTrack>, trace: &RunTrace) -> Scores {
    let mut scores = Scores::default();
    for (icao, t) in truth {
        let est = trace.estimates.get(icao).map_or(&[][..], Vec::as_slice);
        let raw = trace.raw.get(icao).map_or(&[][..], Vec::as_slice);
        scores.merge(&Scores::score_track(t, est, raw));
    }
    scores
}

/// A finished Monte Carlo experiment.
pub struct Experiment {
    pub results: Vec<TrackerResult>,
    /// Truth and each tracker's trace of the first run, for the plots.
    pub first_truth: BTreeMap<Icao, super::score::TruthTrack>,
    pub first_traces: Vec<(String, RunTrace)>,
}

/// `runs` Monte Carlo runs (seeds `seed`, `seed + 1`, ...) of `scenario`, each tracker on the
/// identical frames of each run. Simulated files go to `work_dir`.
pub fn monte_carlo(
    scenario: &Scenario,
    trackers: &[String],
    runs: u64,
    seed: u64,
    config: &Config,
    work_dir: &Path,
) -> Result<Experiment, EvalError> {
    std::fs::create_dir_all(work_dir).map_err(|source| EvalError::Read {
        path: work_dir.display().to_string(),
        error: source,
    })?;
    let mut merged: Vec<Scores> = vec![Scores::default(); trackers.len()];
    let mut first_truth = BTreeMap::new();
    let mut first_traces = Vec::new();
    for run in 0..runs {
        let prefix: PathBuf = work_dir.join(format!("run{run}"));
        let summary = crate::sim::simulate(scenario, seed.wrapping_add(run), &prefix)
            .map_err(|e| EvalError::Other(e.to_string()))?;
        let frames = read_frames(&summary.beast_path, Some(Format::Beast))?;
        let truth_text = read(&summary.truth_path)?;
        let truth = parse_truth(&truth_text, &summary.truth_path.display().to_string())?;
        for (i, name) in trackers.iter().enumerate() {
            let trace = track_frames(&frames, config, name);
            if let Some(m) = merged.get_mut(i) {
                m.merge(&score_trace(&truth, &trace));
            }
            if run == 0 {
                first_traces.push((name.clone(), trace));
            }
        }
        if run == 0 {
            first_truth = truth;
        }
        for p in [&summary.beast_path, &summary.avr_path, &summary.truth_path] {
            let _ = std::fs::remove_file(p);
        }
    }
    Ok(Experiment {
        results: trackers
            .iter()
            .zip(merged)
            .map(|(t, scores)| TrackerResult::new(t.clone(), runs, scores))
            .collect(),
        first_truth,
        first_traces,
    })
}
