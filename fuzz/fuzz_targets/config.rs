//! The config loader (`src/config/`: TOML text -> validated `Config`) and the simulator's
//! scenario loader (`src/sim/scenario.rs`), which take a user's file.
//!
//! Input: the TOML text. Checks: loading never panics and a refusal says why; a config that
//! loads validates again, every tracker parameter set it names builds, and the daemon's
//! pipeline runs a real recording (`fixtures/toulouse-sample.beast`) on it with every
//! published value finite (no arithmetic on a configured value may panic).
#![no_main]

use adsb_tracker::config::Config;
use adsb_tracker::feed::{Format, RawFrame};
use adsb_tracker::sim::scenario::Scenario;
use adsb_tracker_fuzz::{run_parser, run_pipeline};
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

fn frames() -> &'static [RawFrame] {
    static FRAMES: OnceLock<Vec<RawFrame>> = OnceLock::new();
    FRAMES.get_or_init(|| {
        let beast = include_bytes!("../../fixtures/toulouse-sample.beast");
        run_parser(Format::Beast, &[beast]).frames
    })
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Config::from_toml_str(text) {
        Err(e) => assert!(!e.to_string().is_empty()),
        Ok(config) => {
            if let Err(e) = config.validate() {
                panic!("a loaded config no longer validates: {e}");
            }
            let t = &config.tracker;
            if let Err(e) = t.cv_params() {
                panic!("validated config, but cv_params: {e}");
            }
            if let Err(e) = t.imm_tracker_params() {
                panic!("validated config, but imm_tracker_params: {e}");
            }
            for paper002 in [false, true] {
                if let Err(e) = t.hybrid_params(paper002) {
                    panic!("validated config, but hybrid_params({paper002}): {e}");
                }
            }
            run_pipeline(&config, frames(), false);
        }
    }
    if let Err(e) = Scenario::from_toml_str(text) {
        assert!(!e.to_string().is_empty());
    }
});
