//! The frames a `decode_cpr` or `pipeline` fuzz input stands for, with the harness's parity
//! fixes applied, as `(time_s, "hex")` lines ready for a regression test, each with what the
//! decoder makes of it:
//!
//! `cargo run --manifest-path fuzz/Cargo.toml --example frames -- fuzz/artifacts/pipeline/crash-...`
use adsb_tracker::decode::{Decoder, DecoderConfig};
use adsb_tracker_fuzz::{frames_of, split_selector, CrcFixer};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: frames FUZZ_INPUT")?;
    let data = std::fs::read(path)?;
    let (selector, stream) = split_selector(&data);
    let mut decoder = Decoder::new(DecoderConfig::default());
    let mut fixer = CrcFixer::default();
    for frame in &frames_of(selector, stream) {
        let frame = if selector & 0x08 != 0 {
            fixer.fix(frame)
        } else {
            *frame
        };
        let hex: String = frame.bytes().iter().map(|b| format!("{b:02X}")).collect();
        let decoded = decoder.decode(&frame).map(|d| d.msg);
        println!("({:?}, \"{hex}\"), // {decoded:?}", frame.time_s);
    }
    Ok(())
}
