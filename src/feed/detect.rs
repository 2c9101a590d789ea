//! Format sniffing: which parser makes sense of a recording's first bytes.
//!
//! Rather than a second set of rules that could drift from the parsers, each parser is run
//! on the head and the one that reads it best wins. The formats cannot be confused: Beast is
//! binary with 0x1a frame markers (never in text), AVR lines start with `*` or `@`, JSON
//! lines with `{`, ISO lines with a date and CSV lines with a unix time and a comma.

use super::{beast::BeastParser, text::TextParser, Format, FrameParser, RawFrame};

/// How many bytes of a file [`detect`] wants to see (more is fine, less may still work).
pub const DETECT_HEAD_BYTES: usize = 8 * 1024;

/// The line formats, in the order they are tried (ties cannot happen, see the module doc).
const LINE_FORMATS: [Format; 4] = [Format::Avr, Format::Csv, Format::Iso, Format::Jsonl];

/// Any pacing works: detection only counts frames.
const DETECT_RATE_HZ: f64 = 1.0;

/// The format of a recording whose first bytes are `head`, or `None` if no parser reads
/// more frames than it rejects.
///
/// Beast wins when it frames at least one reply and less than a quarter of the head is
/// garbage. A line format wins when it parses at least one line and more lines than it
/// rejects; the head's last line may be cut, which costs at most one bad line.
pub fn detect(head: &[u8]) -> Option<Format> {
    let mut out: Vec<RawFrame> = Vec::new();

    let mut beast = BeastParser::new();
    beast.parse(head, &mut out);
    let s = beast.stats();
    if s.frames > 0 && s.garbage_bytes.saturating_mul(4) < head.len() as u64 {
        return Some(Format::Beast);
    }

    let mut best: Option<(u64, Format)> = None;
    for format in LINE_FORMATS {
        out.clear();
        let mut parser = TextParser::new(format, DETECT_RATE_HZ);
        let used = parser.parse(head, &mut out).min(head.len());
        parser.finish_into(head.get(used..).unwrap_or(&[]), &mut out);
        let s = parser.stats();
        let rejected = s.bad_lines + u64::from(s.truncated_tail_bytes > 0);
        if s.frames > 0 && s.frames > rejected && best.is_none_or(|(n, _)| s.frames > n) {
            best = Some((s.frames, format));
        }
    }
    best.map(|(_, format)| format)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_heads() {
        assert_eq!(
            detect(b"*5DAD57202809F9;\n*02E18E3D81350E;\n"),
            Some(Format::Avr)
        );
        assert_eq!(detect(b"1.5,5DAD57202809F9\n"), Some(Format::Csv));
        assert_eq!(
            detect(b"2015-03-03T16:12:24.846557    5D4840D6F87407"),
            Some(Format::Iso)
        );
        assert_eq!(
            detect(br#"{"timestamp": 1.0, "frame": "5DAD57202809F9"}"#),
            Some(Format::Jsonl)
        );
        let beast = [0x1a, b'1', 0, 0, 0, 0xb7, 0x1b, 0, 0x55, 0x02, 0x40];
        assert_eq!(detect(&beast), Some(Format::Beast));
        assert_eq!(detect(b""), None);
        assert_eq!(detect(b"hello\nworld\n"), None);
        // One good line among many bad is not a format.
        assert_eq!(detect(b"*5DAD57202809F9;\nx\ny\n"), None);
    }
}
