//! AVR text lines (`*hex;`, `@counter hex;`: `src/feed/text.rs`).
//!
//! Input: one byte choosing how the stream is cut into reads, then the text (`0xFF n`
//! repeats the byte before it, so lines past `MAX_LINE_BYTES` are within reach). Checks:
//! frames and counters independent of the cuts; every line that is not blank or a comment
//! is one frame, one bad line or the truncated tail; the unconsumed tail stays bounded;
//! frames written back as AVR and CSV lines parse to the same bytes; detection agrees.
#![no_main]

use adsb_tracker::feed::Format;
use adsb_tracker_fuzz::{
    check_detect, check_line_accounting, check_reemitted, expand_runs, parse_both_ways,
    split_selector,
};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let (seed, stream) = split_selector(data);
    let stream = expand_runs(stream);
    let run = parse_both_ways(Format::Avr, &stream, seed);
    check_line_accounting(Format::Avr, &stream, &run);
    check_reemitted(&run.frames);
    check_detect(&stream);
});
