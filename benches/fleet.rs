//! CPU per track update at fleet scale, one core, no runtime: every frame of a fleet
//! recording through the daemon's own decoder and per-aircraft code (`SyncPipeline`),
//! timing each aircraft's handling of each message that updated its tracker.
//!
//! `FLEET_FILE=target/fleet/fleet.beast cargo bench --bench fleet` (scripts/fleet-bench.sh
//! makes that file: the built-in `fleet` scenario, 1000 aircraft, 10 min). Without
//! `FLEET_FILE` it simulates a smaller fleet (200 aircraft, 2 min) into the target directory.

use adsb_tracker::config::Config;
use adsb_tracker::eval::bench::{read_frames, sync_pipeline};
use adsb_tracker::sim::scenario::Reference;
use adsb_tracker::sim::{fleet, simulate, FleetSpec};
use std::path::PathBuf;
use std::time::Instant;

fn fleet_file() -> PathBuf {
    if let Some(p) = std::env::var_os("FLEET_FILE") {
        return PathBuf::from(p);
    }
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/fleet-bench");
    let path = dir.join("small.beast");
    if !path.exists() {
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        let spec = FleetSpec {
            reference: Reference {
                lat_deg: 51.47,
                lon_deg: -0.46,
            },
            aircraft: 200,
            radius_km: 300.0,
            duration_s: 120.0,
            seed: 9,
            mode_weights: Default::default(),
        };
        let scenario = fleet(&spec).unwrap_or_else(|e| panic!("{e}"));
        simulate(&scenario, 9, &dir.join("small")).unwrap_or_else(|e| panic!("{e}"));
    }
    path
}

fn main() {
    let path = fleet_file();
    let frames = read_frames(&path, None).unwrap_or_else(|e| panic!("{e}"));
    let config = Config::default_config().unwrap_or_else(|e| panic!("{e}"));
    for algorithm in ["hybrid", "kalman-cv"] {
        let mut pipeline = sync_pipeline(&config, algorithm);
        let mut per_update_ns: Vec<u64> = Vec::with_capacity(frames.len());
        let start = Instant::now();
        for f in &frames {
            if let Some(u) = pipeline.push_timed(f) {
                per_update_ns.push(u);
            }
        }
        let secs = start.elapsed().as_secs_f64();
        per_update_ns.sort_unstable();
        let pick = |q: f64| {
            let i = ((per_update_ns.len() as f64 - 1.0) * q).round() as usize;
            per_update_ns.get(i).copied().unwrap_or(0)
        };
        let mean = per_update_ns.iter().sum::<u64>() as f64 / per_update_ns.len().max(1) as f64;
        println!(
            "{algorithm}: {} frames, {} updates; per update median {} ns, p99 {} ns, mean {:.0} ns; \
             whole pipeline {:.2} M frames/s on one core ({})",
            frames.len(),
            per_update_ns.len(),
            pick(0.5),
            pick(0.99),
            mean,
            frames.len() as f64 / secs / 1e6,
            path.display()
        );
    }
}
