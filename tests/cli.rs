//! The binary on every real recording: `replay` and `inspect` run to the end, and count what
//! an independent decode (pyModeS 2.x, and line counts) says is there.

use std::path::PathBuf;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_adsb-tracker"))
}

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// (file, frames in it).
const RECORDINGS: &[(&str, u64)] = &[
    ("toulouse-sample.beast", 239),
    ("us-short-flights.csv", 486),
    ("pymodes-2015-03-03.txt", 4_516),
    ("afr34zg-cdg-tls.jsonl", 57_793),
    ("lax-messages.avr.txt", 215_606),
];

#[test]
fn replay_decodes_every_recording() {
    for (name, frames) in RECORDINGS {
        let out = bin()
            .args(["replay", "--speed", "max"])
            .arg(fixture(name))
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let stats: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(stats["frames"].as_u64(), Some(*frames), "{name}");
        assert!(
            stats["positions_accepted"].as_u64().unwrap() > 0,
            "{name}: {stats}"
        );
        assert_eq!(
            stats["track_errors"].as_object().map_or(0, |m| m.len()),
            0,
            "{name}: {stats}"
        );
    }
}

#[test]
fn inspect_prints_one_block_per_frame() {
    for (name, frames) in RECORDINGS {
        let out = bin().arg("inspect").arg(fixture(name)).output().unwrap();
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let text = String::from_utf8_lossy(&out.stdout);
        let headers = text.lines().filter(|l| l.starts_with("frame ")).count() as u64;
        assert_eq!(headers, *frames, "{name}");
    }
}

#[test]
fn replay_writes_track_lines() {
    let dir = std::env::temp_dir().join(format!("adsb-tracker-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out_path = dir.join("tracks.jsonl");
    let out = bin()
        .args(["replay", "--speed", "max", "--tracks-out"])
        .arg(&out_path)
        .arg(fixture("us-short-flights.csv"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stats: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let text = std::fs::read_to_string(&out_path).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // One line per tracker update.
    assert_eq!(lines.len() as u64, stats["track_updates"].as_u64().unwrap());
    for l in &lines {
        for key in [
            "t",
            "icao",
            "lat",
            "lon",
            "alt_m",
            "ve",
            "vn",
            "vu",
            "mode",
            "filter",
            "pos_sigma_m",
            "diverging",
        ] {
            assert!(l.get(key).is_some(), "line lacks {key}: {l}");
        }
    }
    // Time never goes backwards within one aircraft.
    let mut last = std::collections::HashMap::new();
    for l in &lines {
        let t = l["t"].as_f64().unwrap();
        let prev = last.insert(l["icao"].as_str().unwrap().to_string(), t);
        assert!(prev.is_none_or(|p| p <= t));
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_arguments_are_refused_clearly() {
    // Issue 11, row 6: 1e-300 waited forever and overflowed timers.
    for speed in ["fast", "1e-300", "0", "-1", "inf", "NaN", "1e300"] {
        let out = bin()
            .args(["replay", "--speed", speed])
            .arg(fixture("us-short-flights.csv"))
            .output()
            .unwrap();
        assert!(!out.status.success(), "--speed {speed}");
        assert!(String::from_utf8_lossy(&out.stderr).contains("--speed"));
    }
    let out = bin()
        .args(["replay", "--tracker", "magic"])
        .arg(fixture("us-short-flights.csv"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("tracker.algorithm"));
    let out = bin()
        .args(["replay"])
        .arg("/nonexistent/file.beast")
        .output()
        .unwrap();
    assert!(!out.status.success());
}
