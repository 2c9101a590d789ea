//! Issue 12: the live map at `/`, in a real browser. The daemon replays the LAX recording
//! (real traffic around Los Angeles) in real time x10; `tests/browser/map.mjs` drives
//! Debian's chromium (headless, through npm `playwright-core`) over the page with every
//! request off the daemon blocked, and checks that the aircraft drawn are the tracks
//! `/api/v1/tracks` lists (before and after some are retired, and after a network outage
//! the page recovers from by itself), that they move as events arrive, and that clicking
//! one opens its panel with its callsign. `tests/browser/geo.test.mjs` checks the page's geometry.
//!
//! Needs `node`, `chromium` (or `CHROMIUM=path`) and `npm ci` in `tests/browser/`. Without
//! them the tests say why and pass, unless `ADSB_BROWSER_TESTS=required` (as `.ci/run`
//! sets, after installing them), which makes their absence a failure.

mod common;

use adsb_tracker::config::Config;
use adsb_tracker::daemon::source::{Replay, ReplayData};
use adsb_tracker::daemon::Source;
use common::{fixture, get_json, TestDaemon};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// `ADSB_BROWSER_TESTS=required`: a missing tool fails the test instead of skipping it.
const REQUIRED_ENV: &str = "ADSB_BROWSER_TESTS";

fn browser_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/browser")
}

/// Why the browser tests cannot run here, if they cannot: `node` absent, `chromium`
/// absent, or `playwright-core` not installed (`need_browser`).
fn missing_tools(need_browser: bool) -> Option<String> {
    let runs = |cmd: &str, arg: &str| {
        Command::new(cmd)
            .arg(arg)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    if !runs("node", "--version") {
        return Some("`node` is not installed".into());
    }
    if !need_browser {
        return None;
    }
    let chromium = chromium_path();
    if !chromium.is_file() {
        return Some(format!(
            "no chromium at {} (apt-get install chromium, or set CHROMIUM)",
            chromium.display()
        ));
    }
    if !browser_dir()
        .join("node_modules/playwright-core/package.json")
        .is_file()
    {
        return Some("playwright-core is not installed (npm ci in tests/browser/)".into());
    }
    None
}

fn chromium_path() -> PathBuf {
    std::env::var_os("CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"))
}

/// True when the test can go on; else prints why it is skipped, or panics when the
/// environment says the tools must be there.
fn tools_present(need_browser: bool) -> bool {
    let Some(why) = missing_tools(need_browser) else {
        return true;
    };
    if std::env::var(REQUIRED_ENV).as_deref() == Ok("required") {
        panic!("{REQUIRED_ENV}=required but {why}");
    }
    eprintln!("SKIPPED: {why}; set {REQUIRED_ENV}=required to make this a failure");
    false
}

/// Runs `cmd` to its end, killed after `limit`; its output.
fn run_with_limit(mut cmd: Command, limit: Duration) -> Output {
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawning node");
    let end = Instant::now() + limit;
    while child.try_wait().expect("waiting for node").is_none() {
        if Instant::now() > end {
            let _ = child.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    child.wait_with_output().expect("reading node's output")
}

#[test]
fn map_geometry_matches_closed_forms() {
    if !tools_present(false) {
        return;
    }
    let mut cmd = Command::new("node");
    cmd.arg("--test").arg(browser_dir().join("geo.test.mjs"));
    let out = run_with_limit(cmd, Duration::from_secs(60));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("# pass 5"), "{stdout}");
    assert!(stdout.contains("# fail 0"), "{stdout}");
}

/// The LAX recording's real rate (README: measured from displacement against ground speed).
const LAX_RATE_HZ: f64 = 270.0;
/// Replay speed: aircraft move a few pixels a second at the page's first zoom.
const SPEED: f64 = 10.0;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_map_shows_the_replayed_tracks_in_chromium() {
    if !tools_present(true) {
        return;
    }
    let config = Config::from_toml_str(&format!(
        "[receiver]\nlat_deg = 33.9425\nlon_deg = -118.408\n\
         [decode]\nnominal_rate_hz = {LAX_RATE_HZ}\n"
    ))
    .unwrap();
    let source = Source::Replay(Replay {
        data: ReplayData::File(fixture("lax-messages.avr.txt")),
        format: None,
        speed: SPEED,
        loop_: true,
        nominal_rate_hz: LAX_RATE_HZ,
        fit_untimed_clock: true,
        loop_gap_s: config.tracker.retire_after_s + 1.0,
        progress: false,
    });
    let d = TestDaemon::start(config, source, None).await;
    // About 30 aircraft with a position after 15 s of the recording.
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let (_, tracks) = get_json(d.addr, "/api/v1/tracks").await;
        let n = tracks["tracks"].as_array().map_or(0, Vec::len);
        if n >= 30 {
            break;
        }
        assert!(Instant::now() < deadline, "only {n} tracks after 60 s");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }

    let screenshot = std::env::var_os("MAP_SCREENSHOT")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_TARGET_TMPDIR")).join("map.png"));
    let _ = std::fs::remove_file(&screenshot);
    let mut cmd = Command::new("node");
    cmd.arg(browser_dir().join("map.mjs"))
        .arg(format!("http://{}/", d.addr))
        .arg(&screenshot)
        .env("CHROMIUM", chromium_path());
    let out = tokio::task::spawn_blocking(move || run_with_limit(cmd, Duration::from_secs(180)))
        .await
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    d.stop().await;
    assert!(out.status.success(), "map.mjs failed:\n{stdout}\n{stderr}");
    let line = stdout.lines().last().unwrap_or_default();
    let r: serde_json::Value =
        serde_json::from_str(line).unwrap_or_else(|e| panic!("{e}: {stdout}"));
    println!("map.mjs: {r}");

    // Every track listed is a marker, and nothing else is.
    assert_eq!(r["same"], true, "{r}");
    assert_eq!(r["markers"], r["tracks"], "{r}");
    assert!(r["markers"].as_u64().unwrap() >= 30, "{r}");
    // Retired aircraft left the map: later, with some of the first ones retired, the markers
    // are again exactly the tracks listed.
    assert!(r["retired"].as_u64().unwrap() >= 3, "{r}");
    assert_eq!(r["later"]["same"], true, "{r}");
    // After a network outage the page reconnected by itself and dropped the aircraft
    // retired meanwhile, whose `retire` events it never got.
    assert_eq!(r["reconnected"], true, "{r}");
    assert_eq!(r["after_outage"]["same"], true, "{r}");
    assert!(
        r["after_outage"]["retired_meanwhile"].as_u64().unwrap() >= 1,
        "{r}"
    );
    // Trails start from the history endpoint.
    assert!(r["history"]["ok"].as_u64().unwrap() > 0, "{r}");
    assert!(r["history"]["points"].as_u64().unwrap() > 0, "{r}");
    // Markers move: at 10x, an airliner crosses a pixel of the first view every ~0.2 s.
    assert!(r["moved"].as_u64().unwrap() >= 5, "{r}");
    // Every aircraft in view is drawn, and the pixel under the icon clicked is its mode's
    // colour (map.mjs compares it).
    assert_eq!(r["undrawn"], 0, "{r}");
    assert_eq!(r["pixel"][3], 255, "{r}");
    // The panel of the aircraft clicked names its callsign and lists every field.
    assert_eq!(r["panel_fields"], r["api_fields"], "{r}");
    assert!(r["callsign"].is_string(), "{r}");
    assert_eq!(r["panel_title"], r["callsign"], "{r}");
    // No request left the daemon; none failed.
    assert_eq!(r["offsite"], 0, "{r}");
    assert_eq!(r["failed"], 0, "{r}");
    assert_eq!(r["errors"], 0, "{r}");
    let png = std::fs::read(&screenshot).unwrap();
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    assert!(png.len() > 50_000, "a {} byte screenshot", png.len());
}
