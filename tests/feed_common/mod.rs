//! Helpers shared by the `feed_*` integration tests.
#![allow(dead_code)]

use adsb_tracker::feed::{FrameParser, RawFrame};
use rand::rngs::StdRng;
use rand::Rng;
use std::path::PathBuf;

pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

pub fn read_fixture(name: &str) -> Vec<u8> {
    std::fs::read(fixture(name)).unwrap()
}

pub fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// One Beast frame as found by [`beast_reference`].
#[derive(Clone, Debug)]
pub struct RefFrame {
    /// Byte range of the escaped frame in the recording.
    pub start: usize,
    pub end: usize,
    pub counter: u64,
    pub signal: u8,
    pub data: Vec<u8>,
}

/// A deliberately plain Beast reader for clean recordings, written from the format
/// description only (0x1a, type, 6 counter bytes, signal, data; 0x1a doubled inside), as an
/// oracle independent of the parser under test. Panics on anything unexpected.
pub fn beast_reference(wire: &[u8]) -> Vec<RefFrame> {
    let mut frames = Vec::new();
    let mut i = 0;
    while i < wire.len() {
        assert_eq!(wire[i], 0x1a, "frame start at {i}");
        let start = i;
        let data_len = match wire[i + 1] {
            b'1' => 2,
            b'2' => 7,
            b'3' => 14,
            t => panic!("type {t:#x} at {i}"),
        };
        i += 2;
        let mut body = Vec::new();
        while body.len() < 7 + data_len {
            let b = wire[i];
            i += 1;
            if b == 0x1a {
                assert_eq!(wire[i], 0x1a, "escape at {i}");
                i += 1;
            }
            body.push(b);
        }
        let counter = body[..6]
            .iter()
            .fold(0u64, |acc, &b| acc * 256 + u64::from(b));
        frames.push(RefFrame {
            start,
            end: i,
            counter,
            signal: body[6],
            data: body[7..].to_vec(),
        });
    }
    frames
}

/// Feeds `pieces` to `parser` the way a socket reader would (keeping the unconsumed tail),
/// then finishes. Checks on every call that the parser consumed no more than it was given.
pub fn parse_pieces<'a>(
    parser: &mut dyn FrameParser,
    pieces: impl IntoIterator<Item = &'a [u8]>,
) -> Vec<RawFrame> {
    let mut out = Vec::new();
    let mut pending = Vec::new();
    for piece in pieces {
        pending.extend_from_slice(piece);
        let used = parser.parse(&pending, &mut out);
        assert!(used <= pending.len());
        pending.drain(..used);
    }
    parser.finish_into(&pending, &mut out);
    out
}

/// Cuts `data` at sorted random points.
pub fn random_pieces<'a>(data: &'a [u8], rng: &mut StdRng, cuts: usize) -> Vec<&'a [u8]> {
    let mut at: Vec<usize> = (0..cuts).map(|_| rng.gen_range(0..=data.len())).collect();
    at.push(0);
    at.push(data.len());
    at.sort_unstable();
    at.windows(2).map(|w| &data[w[0]..w[1]]).collect()
}

/// Encodes one Beast frame (doubling every 0x1a after the type byte).
pub fn beast_encode(counter: u64, signal: u8, data: &[u8]) -> Vec<u8> {
    let type_byte = match data.len() {
        2 => b'1',
        7 => b'2',
        14 => b'3',
        n => panic!("{n}-byte frame"),
    };
    let mut out = vec![0x1a, type_byte];
    let mut body = counter.to_be_bytes()[2..].to_vec();
    body.push(signal);
    body.extend_from_slice(data);
    for b in body {
        out.push(b);
        if b == 0x1a {
            out.push(0x1a);
        }
    }
    out
}
