//! What travels on the bus: which partition an aircraft belongs to, and the frame pack, one
//! bus message carrying one receiver's frames of one partition.
//!
//! A pack is versioned binary, little-endian:
//!
//! ```text
//! version u8 (= 1) | receiver id: len u8, UTF-8 bytes |
//! record*: feed time f64 s | flags u8 (bit 0: signal present) | signal u8 | len u8 (2, 7, 14) | frame bytes
//! ```
//!
//! One bus message per frame would cost a publish, a server round trip and an
//! acknowledgement per frame (measured in `docs/scale-out.md`); a pack carries what one feed
//! read brought for one partition. The decoder never panics on any input: a record it cannot
//! read ends the pack, counted, and every record before it is kept.

use crate::decode::Icao;
use crate::feed::RawFrame;

/// The pack format's version byte.
pub const PACK_VERSION: u8 = 1;
/// Longest receiver id, bytes.
pub const MAX_RECEIVER_BYTES: usize = 255;
/// Fixed part of a record: time, flags, signal, length.
const RECORD_HEAD_BYTES: usize = 8 + 1 + 1 + 1;

/// The partition of an address: FNV-1a (32 bit) of its three bytes, most significant first,
/// modulo `partitions`. Stable across processes, machines and releases (never std's
/// randomised hasher): it is the cluster's layout.
pub fn partition_of(icao: Icao, partitions: u32) -> u32 {
    const FNV_OFFSET: u32 = 0x811c_9dc5;
    const FNV_PRIME: u32 = 0x0100_0193;
    let [_, a, b, c] = icao.0.to_be_bytes();
    let mut h = FNV_OFFSET;
    for byte in [a, b, c] {
        h ^= u32::from(byte);
        h = h.wrapping_mul(FNV_PRIME);
    }
    h % partitions.max(1)
}

/// The subject of a partition's frames.
pub fn frames_subject(partition: u32) -> String {
    format!("adsb.frames.{partition}")
}

/// Builds one pack.
pub struct PackWriter {
    buf: Vec<u8>,
    frames: usize,
}

impl PackWriter {
    /// An empty pack from `receiver` (truncated to [`MAX_RECEIVER_BYTES`] at a character
    /// boundary).
    pub fn new(receiver: &str) -> Self {
        let mut end = receiver.len().min(MAX_RECEIVER_BYTES);
        while !receiver.is_char_boundary(end) {
            end -= 1;
        }
        let id = receiver.get(..end).unwrap_or_default().as_bytes();
        let mut buf = Vec::with_capacity(2 + id.len() + 64 * 25);
        buf.push(PACK_VERSION);
        buf.push(id.len() as u8);
        buf.extend_from_slice(id);
        Self { buf, frames: 0 }
    }

    pub fn push(&mut self, f: &RawFrame) {
        self.buf.extend_from_slice(&f.time_s.to_le_bytes());
        self.buf.push(u8::from(f.signal.is_some()));
        self.buf.push(f.signal.unwrap_or(0));
        let bytes = f.bytes();
        self.buf.push(bytes.len() as u8);
        self.buf.extend_from_slice(bytes);
        self.frames += 1;
    }

    pub fn frames(&self) -> usize {
        self.frames
    }

    pub fn len_bytes(&self) -> usize {
        self.buf.len()
    }

    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

/// Why a pack (or its tail) was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    #[error("empty message")]
    Empty,
    #[error("unknown pack version {0}")]
    Version(u8),
    #[error("truncated header")]
    Header,
    #[error("record {0}: truncated")]
    Truncated(usize),
    #[error("record {0}: frame length {1} is not 2, 7 or 14")]
    Length(usize, u8),
    #[error("record {0}: time is not finite")]
    Time(usize),
}

/// A decoded pack: its receiver and frames, and what ended it early, if anything (the
/// frames before that are good).
#[derive(Debug, Clone, PartialEq)]
pub struct Pack {
    pub receiver: String,
    pub frames: Vec<RawFrame>,
    pub error: Option<WireError>,
}

/// Decodes a pack, appending its frames to `frames` (reused between packs). Returns the
/// receiver id and what ended the pack early; `Err` when not even the header is readable.
pub fn decode_into(
    bytes: &[u8],
    frames: &mut Vec<RawFrame>,
) -> Result<(String, Option<WireError>), WireError> {
    let (&version, rest) = bytes.split_first().ok_or(WireError::Empty)?;
    if version != PACK_VERSION {
        return Err(WireError::Version(version));
    }
    let (&id_len, rest) = rest.split_first().ok_or(WireError::Header)?;
    let id = rest.get(..usize::from(id_len)).ok_or(WireError::Header)?;
    let receiver = String::from_utf8_lossy(id).into_owned();
    let mut rest = rest.get(usize::from(id_len)..).unwrap_or_default();
    let mut index = 0;
    while !rest.is_empty() {
        let Some((head, tail)) = rest.split_first_chunk::<RECORD_HEAD_BYTES>() else {
            return Ok((receiver, Some(WireError::Truncated(index))));
        };
        let [t0, t1, t2, t3, t4, t5, t6, t7, flags, signal, len] = *head;
        let time_s = f64::from_le_bytes([t0, t1, t2, t3, t4, t5, t6, t7]);
        if !time_s.is_finite() {
            return Ok((receiver, Some(WireError::Time(index))));
        }
        let Some(body) = tail.get(..usize::from(len)) else {
            return Ok((receiver, Some(WireError::Truncated(index))));
        };
        let signal = (flags & 1 == 1).then_some(signal);
        let Some(frame) = RawFrame::new(time_s, body, signal) else {
            return Ok((receiver, Some(WireError::Length(index, len))));
        };
        frames.push(frame);
        rest = tail.get(usize::from(len)..).unwrap_or_default();
        index += 1;
    }
    Ok((receiver, None))
}

/// Decodes a whole pack.
pub fn decode(bytes: &[u8]) -> Result<Pack, WireError> {
    let mut frames = Vec::new();
    let (receiver, error) = decode_into(bytes, &mut frames)?;
    Ok(Pack {
        receiver,
        frames,
        error,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn frame(t: f64, hex: &str, signal: Option<u8>) -> RawFrame {
        let bytes: Vec<u8> = (0..hex.len())
            .step_by(2)
            .filter_map(|i| u8::from_str_radix(hex.get(i..i + 2)?, 16).ok())
            .collect();
        RawFrame::new(t, &bytes, signal).expect("a frame")
    }

    #[test]
    fn partitions_are_fnv1a_of_the_address() {
        // FNV-1a of 0x4840d6's bytes 48 40 d6, computed by hand from the definition:
        // h = 0x811c9dc5; h = (h ^ b) * 0x01000193 mod 2^32 for each byte.
        let mut h: u32 = 0x811c_9dc5;
        for b in [0x48u8, 0x40, 0xd6] {
            h = (h ^ u32::from(b)).wrapping_mul(0x0100_0193);
        }
        assert_eq!(partition_of(Icao(0x4840d6), 16), h % 16);
        assert_eq!(partition_of(Icao(0x4840d6), 1), 0);
        // Every partition is used, roughly evenly, by consecutive addresses.
        let mut counts = [0u32; 16];
        for a in 0..16_000u32 {
            counts[partition_of(Icao(0x400000 + a), 16) as usize] += 1;
        }
        assert!(
            counts.iter().all(|&c| (800..1200).contains(&c)),
            "{counts:?}"
        );
    }

    #[test]
    fn a_pack_round_trips() {
        let frames = [
            frame(1.5, "8D4840D6202CC371C32CE0576098", Some(200)),
            frame(2.25, "5D4840D6A6C7D1", None),
            frame(3.0, "0000", Some(0)),
        ];
        let mut w = PackWriter::new("rx-1");
        for f in &frames {
            w.push(f);
        }
        assert_eq!(w.frames(), 3);
        let p = decode(&w.finish()).expect("decodes");
        assert_eq!(p.receiver, "rx-1");
        assert_eq!(p.frames, frames);
        assert_eq!(p.error, None);
    }

    #[test]
    fn a_damaged_tail_keeps_the_good_records() {
        let mut w = PackWriter::new("rx");
        w.push(&frame(1.0, "8D4840D6202CC371C32CE0576098", None));
        w.push(&frame(2.0, "8D4840D6202CC371C32CE0576098", None));
        let bytes = w.finish();
        let cut = decode(bytes.get(..bytes.len() - 3).expect("cut")).expect("header");
        assert_eq!(cut.frames.len(), 1);
        assert_eq!(cut.error, Some(WireError::Truncated(1)));
        let mut bad_len = bytes.clone();
        // Second record's length byte: header 2 + 2 id bytes, record 11 + 14 bytes.
        bad_len[4 + 25 + 10] = 9;
        let p = decode(&bad_len).expect("header");
        assert_eq!(p.frames.len(), 1);
        assert_eq!(p.error, Some(WireError::Length(1, 9)));
        assert_eq!(decode(&[]), Err(WireError::Empty));
        assert_eq!(decode(&[2, 0]), Err(WireError::Version(2)));
        assert_eq!(decode(&[1, 5, b'a']), Err(WireError::Header));
    }

    #[test]
    fn a_long_receiver_id_is_cut_at_a_character() {
        let id = "é".repeat(200);
        let w = PackWriter::new(&id);
        let p = decode(&w.finish()).expect("decodes");
        assert_eq!(p.receiver.len(), 254);
        assert!(p.receiver.chars().all(|c| c == 'é'));
    }

    proptest! {
        /// Any bytes: no panic, and never more frames than the bytes could hold.
        #[test]
        fn any_bytes_decode_without_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            if let Ok(p) = decode(&bytes) {
                prop_assert!(p.frames.len() * (RECORD_HEAD_BYTES + 2) <= bytes.len());
            }
        }
    }
}
