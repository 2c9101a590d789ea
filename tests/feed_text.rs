//! Text recordings with garbage lines, CRLF endings, comments, random splits and a cut
//! final line: every intact line's frame comes out exactly, every garbage line is counted.
//!
//! Reference: the same file parsed clean in one piece, whose frames `feed_fixtures` checks
//! against independently established counts, first and last frames and times.

mod feed_common;

use adsb_tracker::feed::text::TextParser;
use adsb_tracker::feed::{Format, FrameParser, ParseStats, RawFrame};
use feed_common::{parse_pieces, random_pieces, read_fixture};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

const RATE_HZ: f64 = 50.0;

/// The fixtures, limited to their first `max_lines` lines so the test stays quick.
const CASES: [(&str, Format, usize); 5] = [
    ("lax-messages.avr.txt", Format::Avr, 20_000),
    ("afr34zg-cdg-tls.jsonl", Format::Jsonl, 10_000),
    ("us-short-flights.csv", Format::Csv, usize::MAX),
    ("pymodes-2015-03-03.txt", Format::Iso, usize::MAX),
    ("pymodes-2015-03-03.txt", Format::Iso, 100),
];

fn lines(name: &str, max_lines: usize) -> Vec<String> {
    let text = String::from_utf8(read_fixture(name)).unwrap();
    text.lines().take(max_lines).map(str::to_owned).collect()
}

fn parse(format: Format, data: &[u8]) -> (Vec<RawFrame>, ParseStats) {
    let mut p = TextParser::new(format, RATE_HZ);
    let frames = parse_pieces(&mut p, [data]);
    (frames, p.stats().clone())
}

/// A line that no format accepts: it holds an `x`, which is neither hex, nor part of a
/// number, date or JSON literal, and it is neither blank nor a `#` comment.
fn garbage_line(rng: &mut StdRng) -> String {
    const CHARS: &[u8] = b"xyz!?-:; *@{},.0123456789abcdefABCDEF\"T";
    let n = rng.gen_range(1..60);
    let mut line: Vec<u8> = (0..n)
        .map(|_| CHARS[rng.gen_range(0..CHARS.len())])
        .collect();
    let at = rng.gen_range(0..=line.len());
    line.insert(at, b'x');
    String::from_utf8(line).unwrap()
}

#[test]
fn garbage_lines_are_counted_and_every_frame_kept() {
    let mut rng = StdRng::seed_from_u64(0x7e47_0001);
    for (name, format, max_lines) in CASES {
        let lines = lines(name, max_lines);
        let clean = lines.join("\n") + "\n";
        let (want, want_stats) = parse(format, clean.as_bytes());
        assert_eq!(want.len(), lines.len(), "{name}");
        assert_eq!(want_stats.bad_lines, 0);

        for round in 0..3 {
            let mut noisy = String::new();
            let mut inserted = 0u64;
            for line in &lines {
                match rng.gen_range(0..10) {
                    0 | 1 => {
                        noisy += &garbage_line(&mut rng);
                        noisy += "\n";
                        inserted += 1;
                    }
                    2 => noisy += "# a comment\r\n",
                    3 => noisy += "   \r\n",
                    _ => {}
                }
                noisy += line;
                noisy += if rng.gen_bool(0.3) { "\r\n" } else { "\n" };
            }
            let mut p = TextParser::new(format, RATE_HZ);
            let cuts = rng.gen_range(1..2000);
            let got = parse_pieces(&mut p, random_pieces(noisy.as_bytes(), &mut rng, cuts));
            assert!(got == want, "{name} round {round}: frames differ");
            let expected = ParseStats {
                frames: want.len() as u64,
                bad_lines: inserted,
                // Plain AVR carries no time: each of its frames is paced.
                paced_frames: if format == Format::Avr {
                    want.len() as u64
                } else {
                    0
                },
                ..ParseStats::default()
            };
            assert_eq!(p.stats(), &expected, "{name} round {round}");
        }
    }
}

#[test]
fn upper_and_lower_case_hex_are_the_same_frames() {
    for (name, format, max_lines) in CASES {
        let text = lines(name, max_lines).join("\n");
        let upper = with_hex_case(&text, true);
        let lower = with_hex_case(&text, false);
        assert_ne!(upper, lower);
        assert!(
            parse(format, upper.as_bytes()) == parse(format, lower.as_bytes()),
            "{name}"
        );
        assert!(
            parse(format, upper.as_bytes()) == parse(format, text.as_bytes()),
            "{name}"
        );
    }
}

/// `text` with the frame field of every line in upper or lower case (only that field: JSON
/// keys and the ISO `T` are case-sensitive).
fn with_hex_case(text: &str, upper: bool) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.split('\n') {
        let (head, hex, tail) = split_hex(line);
        out += head;
        out += &if upper {
            hex.to_ascii_uppercase()
        } else {
            hex.to_ascii_lowercase()
        };
        out += tail;
        out.push('\n');
    }
    out
}

/// A line as (before the frame field, the frame's hex, after it).
fn split_hex(line: &str) -> (&str, &str, &str) {
    if let Some(i) = line.find("\"frame\":\"") {
        let start = i + 9;
        let end = start + line[start..].find('"').unwrap();
        return (&line[..start], &line[start..end], &line[end..]);
    }
    if let Some(rest) = line.strip_prefix('*') {
        let end = rest.find(';').unwrap();
        return (&line[..1], &rest[..end], &rest[end..]);
    }
    let start = line.rfind([',', ' ']).map_or(0, |i| i + 1);
    (&line[..start], &line[start..], "")
}

#[test]
fn cut_final_line_is_a_truncated_tail() {
    for (name, format, max_lines) in CASES {
        let all = lines(name, max_lines);
        // The last 50 lines are plenty, and keep the quadratic re-parsing quick.
        let lines = &all[all.len().saturating_sub(50)..];
        let (want, _) = parse(format, (lines.join("\n") + "\n").as_bytes());
        let last = lines.last().unwrap();
        let body = lines[..lines.len() - 1].join("\n") + "\n";
        for cut in 1..last.len() {
            let cut_line = &last[..cut];
            // Four hex digits are a whole Mode A/C frame: a cut that leaves exactly four
            // digits in a CSV or ISO line's frame field is a valid (if unlucky) line.
            let field = cut_line.rsplit([',', ' ']).next().unwrap_or("");
            let mode_ac = matches!(format, Format::Csv | Format::Iso)
                && cut_line.contains([',', ' '])
                && field.len() == 4;
            let data = format!("{body}{cut_line}");
            let (got, stats) = parse(format, data.as_bytes());
            let kept = if mode_ac { want.len() } else { want.len() - 1 };
            assert_eq!(got.len(), kept, "{name} cut {cut}");
            assert!(
                got[..want.len() - 1] == want[..want.len() - 1],
                "{name} cut {cut}"
            );
            if mode_ac {
                assert_eq!(got[kept - 1].bytes(), &feed_common::hex(field)[..]);
            } else {
                assert_eq!(stats.truncated_tail_bytes, cut as u64, "{name} cut {cut}");
            }
            assert_eq!(stats.bad_lines, 0);
        }
        // Whole, without its newline: parsed at the end.
        let (got, stats) = parse(format, format!("{body}{last}").as_bytes());
        assert!(got == want, "{name}");
        assert_eq!(stats.truncated_tail_bytes, 0);
    }
}
