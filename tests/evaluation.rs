//! The evaluation bench end to end through the binary, as a user runs it:
//! `simulate` -> `replay --tracks-out` -> `evaluate --truth --tracks`, on every built-in
//! scenario, with the figures checked against bounds.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_adsb-tracker"))
}

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{cmd:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

struct Scored {
    results: serde_json::Value,
    markdown: String,
}

/// simulate + replay (with `tracker`) + evaluate of one built-in scenario in `dir`.
fn simulate_replay_evaluate(scenario: &str, tracker: &str, dir: &Path) -> Scored {
    let prefix = dir.join(scenario);
    run_ok(
        bin()
            .args(["simulate", scenario, "--seed", "11", "--out"])
            .arg(&prefix),
    );
    let beast = PathBuf::from(format!("{}.beast", prefix.display()));
    let truth = PathBuf::from(format!("{}.truth.csv", prefix.display()));
    let tracks = dir.join(format!("{scenario}.tracks.jsonl"));
    let mut replay = bin();
    replay
        .args([
            "replay",
            "--speed",
            "max",
            "--tracker",
            tracker,
            "--tracks-out",
        ])
        .arg(&tracks)
        .arg(&beast);
    if scenario == "paper001" {
        // Paper 001's target reaches 300 m/s^2 and 9.8 km/s: no aircraft, so the CPR
        // plausibility limit (700 m/s by default) must be lifted for it.
        let cfg = dir.join("fast.toml");
        std::fs::write(&cfg, "[cpr]\nmax_speed_mps = 20000.0\n").unwrap();
        replay.arg("--config").arg(&cfg);
    }
    run_ok(&mut replay);
    let out_dir = dir.join(format!("{scenario}-eval"));
    let markdown = run_ok(
        bin()
            .arg("evaluate")
            .arg("--truth")
            .arg(&truth)
            .arg("--tracks")
            .arg(&tracks)
            .arg("--frames")
            .arg(&beast)
            .arg("--out")
            .arg(&out_dir),
    );
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("results.json")).unwrap())
            .unwrap();
    for plot in ["map", "error", "modes"] {
        let svg = std::fs::read_to_string(out_dir.join(format!("{scenario}.tracks-{plot}.svg")))
            .unwrap_or_else(|e| panic!("{scenario} {plot}: {e}"));
        assert!(
            svg.starts_with("<svg") && svg.contains("<polyline"),
            "{plot}"
        );
    }
    Scored { results, markdown }
}

fn rmse(group: &serde_json::Value) -> f64 {
    (group["pos_sq"].as_f64().unwrap() / group["n"].as_f64().unwrap()).sqrt()
}

#[test]
fn every_builtin_scenario_through_the_whole_bench() {
    let dir = std::env::temp_dir().join(format!("adsb-eval-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for scenario in [
        "paper000",
        "paper001",
        "paper002",
        "paper003",
        "departure",
        "approach",
    ] {
        let s = simulate_replay_evaluate(scenario, "kalman-cv", &dir);
        let scores = &s.results[0]["scores"];
        let all = &scores["estimates"]["all"];
        assert!(
            all["n"].as_u64().unwrap() > 100,
            "{scenario}: {}",
            s.markdown
        );
        let est = rmse(all);
        assert!(est.is_finite() && est > 0.0, "{scenario}: {}", s.markdown);
        assert!(s.markdown.contains("| tracker |"), "{scenario}");
        // Bounds for the CV Kalman filter per scenario: in every scenario but paper001 (whose
        // 300 m/s^2 manoeuvre no CV filter follows) the filter stays within a few hundred metres.
        if scenario != "paper001" {
            assert!(
                est < 400.0,
                "{scenario}: position RMSE {est} m\n{}",
                s.markdown
            );
        }
    }
    // Paper 002: on straight legs the CV Kalman filter beats the raw measurements clearly.
    let s = simulate_replay_evaluate("paper002", "kalman-cv", &dir);
    let scores = &s.results[0]["scores"];
    let est_cv = rmse(&scores["estimates"]["CV"]);
    let raw_cv = rmse(&scores["raw"]["CV"]);
    assert!(
        est_cv < 0.5 * raw_cv,
        "CV legs: filter {est_cv:.1} m vs raw {raw_cv:.1} m\n{}",
        s.markdown
    );
    // Its label is always CV, so it never switches falsely and is right exactly on CV legs.
    assert_eq!(scores["false_switches"], 0);
    let cv_updates = scores["cv_updates"].as_f64().unwrap();
    let n = scores["estimates"]["all"]["n"].as_f64().unwrap();
    let acc_expected = cv_updates / n;
    let confusion = &scores["confusion"];
    let right = confusion["CV"]["CV"].as_f64().unwrap();
    assert!((right / n - acc_expected).abs() < 1e-9);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn monte_carlo_runs_are_reproducible_and_score_the_same_frames() {
    let dir = std::env::temp_dir().join(format!("adsb-mc-{}", std::process::id()));
    let run = |sub: &str| {
        let out = dir.join(sub);
        let md = run_ok(
            bin()
                .args([
                    "evaluate",
                    "--scenario",
                    "paper002",
                    "--runs",
                    "5",
                    "--seed",
                    "3",
                ])
                .arg("--out")
                .arg(&out),
        );
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap())
                .unwrap();
        (md, v)
    };
    let (md_a, a) = run("a");
    let (_, b) = run("b");
    // Same seeds: identical error sums (CPU timings differ, so compare the estimates).
    assert_eq!(
        a[0]["scores"]["estimates"], b[0]["scores"]["estimates"],
        "{md_a}"
    );
    assert_eq!(a[0]["runs"], 5);
    // 5 runs of paper002 (1000 s, 2 position + 2 velocity reports a second, some lost).
    let n = a[0]["scores"]["estimates"]["all"]["n"].as_u64().unwrap();
    assert!((7_000..=20_000).contains(&n), "{n} updates");
    std::fs::remove_dir_all(&dir).ok();
}

/// A scenario given as a file (an absolute path, as a script would pass it) is plotted into
/// `--out` under its stem, and nothing is written beside the file.
#[test]
fn a_scenario_file_is_plotted_into_out() {
    let dir = std::env::temp_dir().join(format!("adsb-scnfile-{}", std::process::id()));
    let scn_dir = dir.join("scenarios");
    std::fs::create_dir_all(&scn_dir).unwrap();
    let scn = scn_dir.join("approach.toml");
    std::fs::copy(
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/fixtures/scenarios/approach.toml"
        ),
        &scn,
    )
    .unwrap();
    let out = dir.join("out");
    run_ok(
        bin()
            .args([
                "evaluate",
                "--runs",
                "1",
                "--trackers",
                "kalman-cv",
                "--scenario",
            ])
            .arg(&scn)
            .arg("--out")
            .arg(&out),
    );
    for plot in ["map", "error", "modes"] {
        let svg = std::fs::read_to_string(out.join(format!("approach-{plot}.svg"))).unwrap();
        assert!(svg.contains("<svg"), "{plot}");
    }
    let beside: Vec<_> = std::fs::read_dir(&scn_dir).unwrap().collect();
    assert_eq!(beside.len(), 1, "only the scenario itself: {beside:?}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn evaluate_refuses_bad_input_clearly() {
    let out = bin()
        .args([
            "evaluate",
            "--scenario",
            "paper002",
            "--trackers",
            "nope",
            "--runs",
            "1",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("nope"));
    let out = bin()
        .args(["evaluate", "--scenario", "no-such-scenario", "--runs", "1"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("paper002"),
        "lists the built-ins"
    );
    let dir = std::env::temp_dir().join(format!("adsb-badscn-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    let good = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/fixtures/scenarios/paper002.toml"
    ))
    .unwrap();
    std::fs::write(
        &bad,
        good.replacen("turn_rate_dps = 3.0", "turn_rate_dps = -3.0", 1),
    )
    .unwrap();
    let out = bin()
        .arg("simulate")
        .arg(&bad)
        .arg("--out")
        .arg(dir.join("x"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("turn_rate_dps"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}
