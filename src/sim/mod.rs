//! Scenario simulator that speaks ADS-B: the first half of the evaluation bench.
//!
//! A scenario ([`scenario`], TOML) says what each aircraft flies, segment by segment, in the
//! five flight modes of paper 002; [`truth`] integrates that motion exactly on the WGS-84
//! ellipsoid; [`encode`] turns states into DF17 frames (identification, airborne position
//! with CPR, airborne velocity, operational status); [`receiver`] models what a ground
//! station hears (rates, jitter, losses, NACp/NACv noise, bit errors, junk) and writes a Beast
//! file, an AVR file and the truth CSV. Everything random is seeded: the same seed gives
//! byte-identical files.
//!
//! The built-in scenarios (fixtures/scenarios/*.toml) are embedded in the binary, so
//! [`load_scenario`] finds them by name anywhere.

pub mod encode;
pub mod receiver;
pub mod scenario;
pub mod truth;
pub mod wgs84;

pub use scenario::{fleet, FleetSpec, Scenario};

use serde::Serialize;
use std::path::{Path, PathBuf};

/// What can go wrong loading or running a scenario.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The TOML text does not parse or does not have the scenario's shape (the message
    /// gives the line, the column and the key).
    #[error("scenario: {message}")]
    Parse { message: String },
    /// A value is out of range or inconsistent; `key` is its path, e.g.
    /// `aircraft[1].segments[2].turn_rate_dps`.
    #[error("{key}: {reason}")]
    Invalid { key: String, reason: String },
    /// Neither a readable file nor a built-in scenario.
    #[error(
        "no scenario file {spec:?} and no built-in scenario of that name (built-in: {available})"
    )]
    UnknownScenario { spec: String, available: String },
    /// Reading a scenario or writing an output failed.
    #[error("{}: {error}", path.display())]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
}

/// What a run produced, counted.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SimSummary {
    pub aircraft: usize,
    pub duration_s: f64,
    pub seed: u64,
    /// Frames the aircraft transmitted.
    pub frames_emitted: u64,
    /// Transmitted frames the receiver did not hear.
    pub frames_lost: u64,
    /// Heard frames written with 1-3 flipped bits (included in the per-type counts below).
    pub frames_corrupted: u64,
    /// Heard frames written, by type.
    pub position_frames: u64,
    pub velocity_frames: u64,
    pub identification_frames: u64,
    pub status_frames: u64,
    /// Junk runs inserted, and their total length in the Beast file (each run is also one
    /// junk line in the AVR file).
    pub junk_runs: u64,
    pub junk_bytes: u64,
    /// Rows of the truth CSV (header excluded).
    pub truth_rows: u64,
    pub beast_path: PathBuf,
    pub avr_path: PathBuf,
    pub truth_path: PathBuf,
}

impl SimSummary {
    /// Heard frames written to each feed.
    pub fn frames_written(&self) -> u64 {
        self.position_frames
            + self.velocity_frames
            + self.identification_frames
            + self.status_frames
    }
}

/// The built-in scenarios: name and TOML text (fixtures/scenarios/NAME.toml, embedded).
pub const BUILTIN: [(&str, &str); 17] = [
    (
        "paper000",
        include_str!("../../fixtures/scenarios/paper000.toml"),
    ),
    (
        "paper000-positions",
        include_str!("../../fixtures/scenarios/paper000-positions.toml"),
    ),
    (
        "paper001",
        include_str!("../../fixtures/scenarios/paper001.toml"),
    ),
    (
        "paper002",
        include_str!("../../fixtures/scenarios/paper002.toml"),
    ),
    (
        "paper002-positions",
        include_str!("../../fixtures/scenarios/paper002-positions.toml"),
    ),
    (
        "paper003",
        include_str!("../../fixtures/scenarios/paper003.toml"),
    ),
    (
        "departure",
        include_str!("../../fixtures/scenarios/departure.toml"),
    ),
    (
        "approach",
        include_str!("../../fixtures/scenarios/approach.toml"),
    ),
    (
        "approach-baro",
        include_str!("../../fixtures/scenarios/approach-baro.toml"),
    ),
    (
        "airliner-nacp10",
        include_str!("../../fixtures/scenarios/airliner-nacp10.toml"),
    ),
    (
        "airliner-gnss-velocity",
        include_str!("../../fixtures/scenarios/airliner-gnss-velocity.toml"),
    ),
    (
        "airliner-stale",
        include_str!("../../fixtures/scenarios/airliner-stale.toml"),
    ),
    (
        "airliner-timing",
        include_str!("../../fixtures/scenarios/airliner-timing.toml"),
    ),
    (
        "turns-undeclared",
        include_str!("../../fixtures/scenarios/turns-undeclared.toml"),
    ),
    (
        "turns-correlated",
        include_str!("../../fixtures/scenarios/turns-correlated.toml"),
    ),
    ("fleet", include_str!("../../fixtures/scenarios/fleet.toml")),
    (
        "fleet-uniform",
        include_str!("../../fixtures/scenarios/fleet-uniform.toml"),
    ),
];

/// Names of the built-in scenarios.
pub fn builtin_names() -> impl Iterator<Item = &'static str> {
    BUILTIN.iter().map(|(name, _)| *name)
}

/// A scenario from a file path, or else a built-in by name (`paper002` or `paper002.toml`).
/// An existing file wins over a built-in of the same name.
pub fn load_scenario(spec: &str) -> Result<Scenario, SimError> {
    let path = Path::new(spec);
    if path.is_file() {
        let text = std::fs::read_to_string(path).map_err(|source| SimError::Io {
            path: path.to_owned(),
            error: source,
        })?;
        return Scenario::from_toml_str(&text);
    }
    let name = spec.strip_suffix(".toml").unwrap_or(spec);
    match BUILTIN.iter().find(|(n, _)| *n == name) {
        Some((_, text)) => Scenario::from_toml_str(text),
        None => Err(SimError::UnknownScenario {
            spec: spec.to_owned(),
            available: builtin_names().collect::<Vec<_>>().join(", "),
        }),
    }
}

/// Runs `scenario` with `seed` and writes `PREFIX.beast`, `PREFIX.avr` and
/// `PREFIX.truth.csv` (see [`receiver`]). The same scenario and seed give byte-identical
/// files.
pub fn simulate(scenario: &Scenario, seed: u64, out_prefix: &Path) -> Result<SimSummary, SimError> {
    receiver::run(scenario, seed, out_prefix)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_loads_by_name_and_file_name() {
        for name in builtin_names() {
            let s = load_scenario(name).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(!s.aircraft.is_empty());
            assert_eq!(load_scenario(&format!("{name}.toml")).unwrap(), s);
        }
    }

    #[test]
    fn files_win_and_unknown_names_list_the_builtins() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/fixtures/scenarios/paper003.toml"
        );
        assert_eq!(
            load_scenario(path).unwrap(),
            load_scenario("paper003").unwrap()
        );
        let e = load_scenario("nope").unwrap_err().to_string();
        assert_eq!(
            e,
            "no scenario file \"nope\" and no built-in scenario of that name \
             (built-in: paper000, paper000-positions, paper001, paper002, paper002-positions, \
             paper003, departure, approach, approach-baro, airliner-nacp10, airliner-gnss-velocity, airliner-stale, airliner-timing, turns-undeclared, turns-correlated, fleet, fleet-uniform)"
        );
    }

    #[test]
    fn builtins_match_the_fixture_files() {
        // The embedded copies are the files in fixtures/scenarios (include_str! at build).
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/scenarios");
        let mut on_disk: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".toml"))
            .collect();
        on_disk.sort();
        let mut names: Vec<String> = builtin_names().map(|n| format!("{n}.toml")).collect();
        names.sort();
        assert_eq!(on_disk, names);
    }
}
