//! Beast binary framing (`src/feed/beast.rs`).
//!
//! Input: one byte choosing how the stream is cut into reads, then the stream. Checks:
//! - the frames and counters do not depend on how the reads were cut;
//! - every byte is accounted for: what was consumed is frames (11 to 44 escaped bytes each, by
//!   length) plus Radarcape records and skipped garbage, and the unconsumed tail is one
//!   incomplete frame (a 0x1a, at most 44 bytes), counted as truncated at the end;
//! - a stream without 0x1a is all garbage;
//! - a well-formed stream built from the same bytes (frames escaped as a Beast sender does)
//!   parses back to exactly those frames, with no garbage.
#![no_main]

use adsb_tracker::feed::Format;
use adsb_tracker_fuzz::{check_detect, parse_both_ways, run_parser, split_selector};
use libfuzzer_sys::fuzz_target;

const ESC: u8 = 0x1a;

/// Escaped length bounds of a frame with `data` bytes: `0x1a type`, then counter (6), signal
/// (1) and data, each byte possibly doubled.
fn escaped_bounds(data: usize) -> (u64, u64) {
    let body = 7 + data as u64;
    (2 + body, 2 + 2 * body)
}

/// Radarcape records: 21-byte bodies.
const RADARCAPE_MAX: u64 = 2 + 2 * 21;

fn escape_into(out: &mut Vec<u8>, bytes: &[u8]) {
    for &b in bytes {
        out.push(b);
        if b == ESC {
            out.push(ESC);
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let (seed, stream) = split_selector(data);
    let run = parse_both_ways(Format::Beast, stream, seed);
    let s = &run.stats;

    // Accounting.
    assert_eq!(s.truncated_tail_bytes, run.tail.len() as u64);
    if let Some(&first) = run.tail.first() {
        assert_eq!(first, ESC, "an unconsumed tail must start a frame");
        assert!(
            run.tail.len() as u64 <= RADARCAPE_MAX,
            "tail of {}",
            run.tail.len()
        );
    }
    let consumed = run.consumed as u64;
    assert!(s.garbage_bytes <= consumed);
    let (mut lo, mut hi) = (0u64, 0u64);
    for f in &run.frames {
        let (a, b) = escaped_bounds(f.bytes().len());
        lo += a;
        hi += b;
    }
    assert!(
        s.garbage_bytes + lo <= consumed
            && consumed <= s.garbage_bytes + hi + s.bad_frames * RADARCAPE_MAX,
        "consumed {consumed}: garbage {} + frames {lo}..{hi} + {} bad frames",
        s.garbage_bytes,
        s.bad_frames
    );
    if !stream.contains(&ESC) {
        assert!(run.frames.is_empty());
        assert_eq!(s.garbage_bytes, stream.len() as u64);
    }
    assert_eq!(s.bad_lines, 0);

    check_detect(stream);

    // Round trip: frames of 2, 7 or 14 data bytes taken from the input, escaped.
    let mut wire = Vec::new();
    let mut want: Vec<(Vec<u8>, u8)> = Vec::new();
    let mut rest = stream;
    while let Some((&kind, after)) = rest.split_first() {
        let (type_byte, n) = match kind % 3 {
            0 => (b'1', 2),
            1 => (b'2', 7),
            _ => (b'3', 14),
        };
        let Some(body) = after.get(..7 + n) else {
            break;
        };
        wire.extend_from_slice(&[ESC, type_byte]);
        escape_into(&mut wire, body);
        want.push((body[7..].to_vec(), body[6]));
        rest = &after[7 + n..];
    }
    let back = run_parser(Format::Beast, &[&wire]);
    let got: Vec<(Vec<u8>, u8)> = back
        .frames
        .iter()
        .map(|f| (f.bytes().to_vec(), f.signal.unwrap_or(0)))
        .collect();
    assert!(
        got == want,
        "round trip: {} frames back of {}",
        got.len(),
        want.len()
    );
    assert!(back.frames.iter().all(|f| f.signal.is_some()));
    assert_eq!(back.stats.garbage_bytes, 0);
    assert_eq!(back.stats.bad_frames, 0);
    assert_eq!(back.consumed, wire.len());
});
