//! Human-readable decoding of single frames, for `adsb-tracker inspect FILE`.
//!
//! The full field-by-field text is adsb_deku 0.8.0's `Display` (it knows every DF and many
//! registers we do not use), prefixed with our own CRC verdict and address, because adsb_deku
//! does not check the parity of DF17/18 and misreads a few fields (see
//! `tests/differential_deku.rs`). For extended squitters our own decode follows, so the two
//! can be compared. Not on the hot path: this allocates freely.

use std::fmt::Write;
use std::panic::{catch_unwind, AssertUnwindSafe};

use super::{adsb, bits, crc, single_bit_error};
use crate::feed::RawFrame;

/// A full human-readable decode of one frame of any downlink format. Never panics: an
/// adsb_deku error (or panic) becomes a line saying so.
pub fn describe(frame: &RawFrame) -> String {
    let bytes = frame.bytes();
    let mut out = String::new();
    let hex: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
    let signal = frame
        .signal
        .map(|s| format!("  signal {s}"))
        .unwrap_or_default();
    let _ = writeln!(out, "{hex}  t={:.6} s{signal}", frame.time_s);
    if frame.is_mode_ac() {
        let _ = writeln!(out, " Mode A/C reply (2 bytes): no Mode S content");
        return out;
    }
    let df = frame.df();
    let _ = writeln!(
        out,
        " DF{df}, {} bits: {}",
        bytes.len() * 8,
        verdict(bytes, df)
    );
    match catch_unwind(AssertUnwindSafe(|| {
        adsb_deku::Frame::from_bytes(bytes).map(|f| f.to_string())
    })) {
        Ok(Ok(text)) => out.push_str(&text),
        Ok(Err(e)) => {
            let _ = writeln!(out, " adsb_deku could not decode this frame: {e}");
        }
        Err(_) => {
            let _ = writeln!(out, " adsb_deku panicked on this frame");
        }
    }
    if (df == 17 || df == 18) && bytes.len() == 14 {
        if let Some(me) = bits::Me::from_frame(bytes) {
            let _ = writeln!(out, " our ME decode: {:?}", adsb::decode_me(me));
        }
    }
    out
}

/// Our CRC verdict and the address it gives, in words.
fn verdict(bytes: &[u8], df: u8) -> String {
    let expected_len = if df >= 16 { 14 } else { 7 };
    if bytes.len() != expected_len {
        return format!("length does not match the DF ({expected_len} bytes expected)");
    }
    let Some(syndrome) = crc::syndrome(bytes) else {
        return "too short for a CRC".to_string();
    };
    let announced = bits::field(bytes, 9, 32).unwrap_or(0);
    match df {
        17 | 18 if syndrome == 0 => format!("CRC ok, address {announced:06x} (announced)"),
        17 | 18 => match single_bit_error(syndrome) {
            Some(bit) => format!(
                "CRC BAD (syndrome {syndrome:06x}): one-bit error at bit {bit}, repairable; \
                 announced address {announced:06x} as received"
            ),
            None => format!(
                "CRC BAD (syndrome {syndrome:06x}), not repairable: the fields below are not \
                 to be trusted"
            ),
        },
        11 if syndrome & 0xFF_FF80 == 0 => format!(
            "CRC ok (interrogator code {}), address {announced:06x} (announced)",
            syndrome & 0x7F
        ),
        11 => format!("CRC BAD (syndrome {syndrome:06x})"),
        0 | 4 | 5 | 16 | 20 | 21 => format!(
            "Address/Parity: address {syndrome:06x} if the CRC is good (a decoder accepts it \
             only for an aircraft heard recently)"
        ),
        _ => format!("parity not checked for this DF (syndrome {syndrome:06x})"),
    }
}

/// `adsb-tracker inspect FILE`: a header line (`frame N`) and the full decode of
/// every frame of a recording, whatever its DF. Never stops on a bad frame.
pub fn inspect_file(
    path: &std::path::Path,
    format: Option<crate::feed::Format>,
    limit: Option<u64>,
    out: &mut dyn std::io::Write,
) -> Result<(), crate::feed::FeedError> {
    let io = |source| crate::feed::FeedError::Io {
        path: path.to_path_buf(),
        error: source,
    };
    let mut reader = crate::feed::replay::FileReader::open(path, format, 1000.0)?;
    let mut frames = Vec::new();
    let mut n = 0u64;
    while reader.next_batch(&mut frames)? {
        for f in &frames {
            if limit.is_some_and(|l| n >= l) {
                return Ok(());
            }
            n += 1;
            writeln!(out, "frame {n}").map_err(io)?;
            for line in describe(f).lines() {
                writeln!(out, "    {line}").map_err(io)?;
            }
        }
    }
    let s = reader.stats();
    writeln!(
        out,
        "# {} frames; {} bad lines, {} garbage bytes, {} bad frames, {} truncated tail bytes",
        s.frames, s.bad_lines, s.garbage_bytes, s.bad_frames, s.truncated_tail_bytes
    )
    .map_err(io)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(s: &str) -> RawFrame {
        let b: Vec<u8> = (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect();
        RawFrame::new(1.5, &b, Some(7)).unwrap()
    }

    #[test]
    fn clean_identification() {
        let text = describe(&frame("8D4840D6202CC371C32CE0576098"));
        assert!(
            text.starts_with("8d4840d6202cc371c32ce0576098  t=1.500000 s  signal 7\n"),
            "{text}"
        );
        assert!(
            text.contains("DF17, 112 bits: CRC ok, address 4840d6 (announced)"),
            "{text}"
        );
        // adsb_deku's own text follows.
        assert!(
            text.contains("Aircraft identification and category"),
            "{text}"
        );
        assert!(text.contains("Ident:         KLM1023"), "{text}");
        assert!(text.contains("our ME decode: Identification"), "{text}");
    }

    #[test]
    fn bad_crc_is_flagged_even_though_deku_decodes() {
        // Frame bit 52 flipped: one-bit error, repairable.
        let text = describe(&frame("8D4840D6202CD371C32CE0576098"));
        assert!(
            text.contains("one-bit error at bit 52, repairable"),
            "{text}"
        );
        assert!(
            text.contains("Aircraft identification and category"),
            "{text}"
        );
    }

    #[test]
    fn address_parity_and_all_call() {
        let df4 = describe(&frame("212800bf40f1ef"));
        assert!(df4.contains("Address/Parity: address 393322"), "{df4}");
        assert!(df4.contains("Altitude:      575 ft"), "{df4}");
        let df11 = describe(&frame("5D40621D4F94DE"));
        assert!(
            df11.contains("CRC ok (interrogator code 14), address 40621d"),
            "{df11}"
        );
    }

    #[test]
    fn never_panics() {
        // Mode A/C, a wrong length, and every DF with all-zero and all-one payloads.
        assert!(describe(&frame("1234")).contains("Mode A/C"));
        assert!(describe(&frame("8D4840D6202CC3")).contains("length does not match"));
        for df in 0..32u8 {
            for fill in [0x00u8, 0xFF, 0x55] {
                for len in [7usize, 14] {
                    let mut b = vec![fill; len];
                    b[0] = (df << 3) | (fill & 7);
                    let text = describe(&RawFrame::new(0.0, &b, None).unwrap());
                    assert!(text.contains(&format!("DF{df},")), "{text}");
                }
            }
        }
    }
}
