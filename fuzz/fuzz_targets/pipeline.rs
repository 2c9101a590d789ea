//! The aircraft pipeline: feed bytes to published tracks (feed parser, decoder, router
//! retirement, each aircraft's CPR, measurements and tracker, the published snapshot with
//! predictions and its API view: `src/daemon/aircraft.rs`, `src/track/`).
//!
//! Input: one selector byte, then a stream. Selector bits 0-2: format (Beast, AVR, CSV, ISO,
//! JSON lines; 5-7 synthetic DF17 records, `adsb_tracker_fuzz::synthetic_frames`), bit 3:
//! write a correct parity into every frame (so mutated positions and velocities reach the
//! trackers), bits 4-7: the tracker (every algorithm the daemon can run). Checks: every published value finite and in range (no NaN leaves the
//! daemon), an update always leaves an estimate, counters agree.
#![no_main]

use adsb_tracker::config::{Config, ALGORITHMS};
use adsb_tracker_fuzz::{frames_of, run_pipeline, split_selector};
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

/// The embedded default configuration, once per tracker.
fn config(algorithm: usize) -> Option<&'static Config> {
    static CONFIGS: OnceLock<Vec<Config>> = OnceLock::new();
    CONFIGS
        .get_or_init(|| {
            let base = Config::default_config().expect("the embedded config loads");
            ALGORITHMS
                .iter()
                .map(|name| {
                    let mut c = base.clone();
                    c.tracker.algorithm = (*name).to_string();
                    c
                })
                .collect()
        })
        .get(algorithm % ALGORITHMS.len())
}

fuzz_target!(|data: &[u8]| {
    let (selector, stream) = split_selector(data);
    let Some(config) = config(usize::from(selector >> 4)) else {
        return;
    };
    run_pipeline(config, &frames_of(selector, stream), selector & 0x08 != 0);
});
