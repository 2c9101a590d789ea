//! The timestamped line formats: CSV `unix_ts,hex`, ISO-8601 time + hex, JSON lines
//! (`src/feed/text.rs`), and format detection (`src/feed/detect.rs`).
//!
//! Input: one byte (format = byte % 3: CSV, ISO, JSON lines; cuts = byte / 3), then the text
//! (`0xFF n` repeats the byte before it). Checks as for AVR: frames and counters independent
//! of the cuts, time finite and never back, every line accounted for, the tail bounded,
//! frames written back parse to the same bytes, and detection agrees with the parsers.
#![no_main]

use adsb_tracker::feed::Format;
use adsb_tracker_fuzz::{
    check_detect, check_line_accounting, check_reemitted, expand_runs, parse_both_ways,
    split_selector,
};
use libfuzzer_sys::fuzz_target;

const LINE_FORMATS: [Format; 3] = [Format::Csv, Format::Iso, Format::Jsonl];

fuzz_target!(|data: &[u8]| {
    let (selector, stream) = split_selector(data);
    let format = LINE_FORMATS[usize::from(selector % 3)];
    let stream = expand_runs(stream);
    let run = parse_both_ways(format, &stream, selector / 3);
    check_line_accounting(format, &stream, &run);
    check_reemitted(&run.frames);
    check_detect(&stream);
});
