//! Line formats: AVR (`*hex;`, `@counter hex;`), CSV (`unix_ts,hex`), ISO time + hex, and
//! JSON lines.
//!
//! Every line is parsed on its own: a malformed line is counted in
//! [`ParseStats::bad_lines`] and parsing goes on with the next one. Blank lines and `#`
//! comments are skipped; CRLF endings, surrounding whitespace and either case of hex digit
//! are accepted.
//!
//! The frame length follows from the hex itself: 4 digits are a Mode A/C reply; otherwise
//! the downlink format in the first 5 bits decides (ICAO Annex 10 Vol IV §3.1.2.3.2.1.1:
//! DF 0-15 are 56-bit replies, DF 16 and above 112-bit), so a 28-digit line whose DF says
//! "short" is a 56-bit frame padded to 112 bits (rs1090 / traffic's JSON lines do this) and
//! keeps its first 7 bytes, while a line shorter than its DF needs is bad.

use super::{FeedClock, Format, FrameParser, ParseStats, RawFrame, MAX_FRAME_BYTES};
use serde::Deserialize;
use std::io::Write;

/// Longest line accepted (bytes, without the newline). JSON lines carrying decoded fields
/// run to a few hundred bytes; anything near this is not a frame, and the bound keeps the
/// caller's buffer of an unterminated line bounded too.
pub const MAX_LINE_BYTES: usize = 16 * 1024;

/// Hex digits of the AVR `@` timestamp: the 48-bit 12 MHz counter.
const AVR_COUNTER_DIGITS: usize = 12;

/// Most fractional-second digits accepted in an ISO time (attoseconds is already absurd).
const MAX_FRACTION_DIGITS: usize = 18;

/// The two fields a JSON line must have; every other field is skipped without allocating.
#[derive(Deserialize)]
struct JsonLine<'a> {
    /// Unix seconds.
    timestamp: f64,
    /// The frame in hex.
    frame: &'a str,
}

/// Incremental parser for the line formats (every [`Format`] but Beast).
#[derive(Debug)]
pub struct TextParser {
    format: Format,
    /// Pace of untimed AVR `*hex;` frames; `None` when the configured rate is unusable, and
    /// such frames then all get time 0.
    nominal_rate_hz: Option<f64>,
    /// Untimed frames handed on so far (the `n` in `n / nominal_rate_hz`).
    untimed_frames: u64,
    clock: FeedClock,
    stats: ParseStats,
    /// Inside a line longer than [`MAX_LINE_BYTES`] (already counted): drop bytes up to the
    /// next newline.
    discarding: bool,
}

impl TextParser {
    /// A parser for `format` (`Format::Beast` is not a line format: every line would be
    /// bad). `nominal_rate_hz` paces AVR `*hex;` frames, which carry no time: frame n gets
    /// feed time n / rate.
    pub fn new(format: Format, nominal_rate_hz: f64) -> Self {
        let usable = nominal_rate_hz.is_finite() && nominal_rate_hz > 0.0;
        Self {
            format,
            nominal_rate_hz: usable.then_some(nominal_rate_hz),
            untimed_frames: 0,
            clock: FeedClock::new(),
            stats: ParseStats::default(),
            discarding: false,
        }
    }

    /// One line without its newline.
    fn line(&mut self, line: &[u8], out: &mut Vec<RawFrame>) {
        // Too long to be a frame, whatever it holds (even a comment): the verdict `parse`
        // gives such a line when it arrives in pieces and is dropped before its end is seen.
        if line.len() > MAX_LINE_BYTES {
            self.stats.bad_lines += 1;
            return;
        }
        let line = line.trim_ascii();
        if line.is_empty() || line.first() == Some(&b'#') {
            return;
        }
        if self.frame(line, out).is_none() {
            self.stats.bad_lines += 1;
        }
    }

    /// Hands the frame on a trimmed, nonblank line to the clock, which times it into `out`
    /// (at once, or after a time step is confirmed; a frame with an impossible timestamp is
    /// counted there and dropped). `None` if the line is malformed: the clock only sees
    /// wholly valid lines.
    fn frame(&mut self, line: &[u8], out: &mut Vec<RawFrame>) -> Option<()> {
        if line.len() > MAX_LINE_BYTES {
            return None;
        }
        match self.format {
            Format::Avr => self.avr(line, out),
            Format::Csv => {
                let comma = line.iter().position(|&b| b == b',')?;
                let ts_s = parse_f64(line.get(..comma)?.trim_ascii())?;
                self.timed(ts_s, line.get(comma + 1..)?.trim_ascii(), out)
            }
            Format::Iso => {
                let gap = line.iter().position(u8::is_ascii_whitespace)?;
                let ts_s = parse_iso_utc(line.get(..gap)?)?;
                self.timed(ts_s, line.get(gap..)?.trim_ascii(), out)
            }
            Format::Jsonl => {
                let rec: JsonLine<'_> = serde_json::from_slice(line).ok()?;
                self.timed(rec.timestamp, rec.frame.as_bytes(), out)
            }
            Format::Beast => None,
        }
    }

    fn timed(&mut self, ts_s: f64, hex: &[u8], out: &mut Vec<RawFrame>) -> Option<()> {
        let (bytes, len) = frame_from_hex(hex)?;
        let frame = RawFrame::new(0.0, bytes.get(..len)?, None)?;
        self.clock.push_seconds(ts_s, frame, out);
        Some(())
    }

    /// `*<hex>;` or `@<12 hex counter><hex>;` (dump1090/readsb raw output, port 30002).
    fn avr(&mut self, line: &[u8], out: &mut Vec<RawFrame>) -> Option<()> {
        let (&mark, rest) = line.split_first()?;
        let hex = rest.strip_suffix(b";")?;
        match mark {
            b'*' => {
                let (bytes, len) = frame_from_hex(hex)?;
                let frame = RawFrame::new(0.0, bytes.get(..len)?, None)?;
                let pace_s = match self.nominal_rate_hz {
                    Some(rate_hz) => self.untimed_frames as f64 / rate_hz,
                    None => 0.0,
                };
                self.untimed_frames += 1;
                self.stats.paced_frames += 1;
                self.clock.push_paced(pace_s, frame, out);
            }
            b'@' => {
                let (counter, frame_hex) = hex.split_at_checked(AVR_COUNTER_DIGITS)?;
                let ticks = counter
                    .iter()
                    .try_fold(0u64, |acc, &c| Some(acc << 4 | u64::from(nibble(c)?)))?;
                let (bytes, len) = frame_from_hex(frame_hex)?;
                let frame = RawFrame::new(0.0, bytes.get(..len)?, None)?;
                // Mode A/C stamps do not move the clock (see `beast::BeastParser::emit`).
                if len == 2 {
                    self.clock.push_untimed(frame, out);
                } else {
                    self.clock.push_ticks(ticks, frame, out);
                }
            }
            _ => return None,
        }
        Some(())
    }

    fn sync_stats(&mut self, frames_before: usize, out: &[RawFrame]) {
        self.stats.frames += out.len().saturating_sub(frames_before) as u64;
        self.stats.clock_resets = self.clock.resets();
        self.stats.time_outliers = self.clock.outliers();
        self.stats.bad_timestamps = self.clock.bad_timestamps();
    }
}

impl FrameParser for TextParser {
    fn parse(&mut self, buf: &[u8], out: &mut Vec<RawFrame>) -> usize {
        let frames_before = out.len();
        let mut pos = 0;
        if self.discarding {
            match buf.iter().position(|&b| b == b'\n') {
                Some(newline) => {
                    pos = newline + 1;
                    self.discarding = false;
                }
                None => return buf.len(),
            }
        }
        while let Some(rest) = buf.get(pos..) {
            match rest.iter().position(|&b| b == b'\n') {
                Some(newline) => {
                    self.line(rest.get(..newline).unwrap_or(&[]), out);
                    pos += newline + 1;
                }
                None => {
                    if rest.len() > MAX_LINE_BYTES {
                        // Too long to ever be a frame: count it now and drop the rest of it
                        // as it arrives, so an endless line cannot grow the caller's buffer.
                        self.stats.bad_lines += 1;
                        self.discarding = true;
                        pos = buf.len();
                    }
                    break;
                }
            }
        }
        self.sync_stats(frames_before, out);
        pos
    }

    /// Counts the tail; frames the clock holds (a time step waiting for confirmation) stay
    /// held for the stream that follows (a reconnect).
    fn finish(&mut self, tail: &[u8]) {
        if !std::mem::take(&mut self.discarding) && !tail.trim_ascii().is_empty() {
            self.stats.truncated_tail_bytes += tail.len() as u64;
        }
    }

    /// A final line without a newline is a line: parsed if complete, else a truncated tail.
    /// Then the stream has ended: the frames the clock holds are released.
    fn finish_into(&mut self, tail: &[u8], out: &mut Vec<RawFrame>) {
        let frames_before = out.len();
        let line = tail.trim_ascii();
        let discarding = std::mem::take(&mut self.discarding);
        if !discarding
            && !line.is_empty()
            && line.first() != Some(&b'#')
            && self.frame(line, out).is_none()
        {
            self.stats.truncated_tail_bytes += tail.len() as u64;
        }
        self.clock.flush(out);
        self.sync_stats(frames_before, out);
    }

    fn stats(&self) -> &ParseStats {
        &self.stats
    }
}

/// Marks a byte that is not a hex digit in [`HEX_VALUE`] (high bit set: no digit has it).
const NOT_HEX: u8 = 0xff;

/// Value of each byte as a hex digit, or [`NOT_HEX`]. A table rather than a `match`: hex
/// digits mix ranges at random, and the branches of a `match` mispredict on nearly every
/// character (it took half the AVR parsing time).
static HEX_VALUE: [u8; 256] = {
    let mut table = [NOT_HEX; 256];
    let mut i = 0;
    while i < 10 {
        table[b'0' as usize + i] = i as u8;
        i += 1;
    }
    let mut i = 0;
    while i < 6 {
        table[b'a' as usize + i] = 10 + i as u8;
        table[b'A' as usize + i] = 10 + i as u8;
        i += 1;
    }
    table
};

/// The digit's value, or [`NOT_HEX`].
#[inline]
fn hex_value(c: u8) -> u8 {
    HEX_VALUE.get(usize::from(c)).copied().unwrap_or(NOT_HEX)
}

fn nibble(c: u8) -> Option<u8> {
    let v = hex_value(c);
    (v != NOT_HEX).then_some(v)
}

/// Decodes a frame's hex digits: 4 digits are Mode A/C (2 bytes); otherwise the DF in the
/// first 5 bits gives the length (DF < 16: 7 bytes, else 14) and 28 digits of a short frame
/// are padding after the first 14. Returns the bytes and the frame length.
fn frame_from_hex(hex: &[u8]) -> Option<([u8; MAX_FRAME_BYTES], usize)> {
    let digits = hex.len();
    if digits % 2 != 0 || !(4..=2 * MAX_FRAME_BYTES).contains(&digits) {
        return None;
    }
    let mut bytes = [0u8; MAX_FRAME_BYTES];
    // Decode every pair, then reject once if any digit was not hex (no branch per digit).
    let mut seen = 0u8;
    for (slot, pair) in bytes.iter_mut().zip(hex.chunks_exact(2)) {
        let [hi, lo] = *pair else { return None };
        let (hi, lo) = (hex_value(hi), hex_value(lo));
        seen |= hi | lo;
        *slot = hi << 4 | lo;
    }
    if seen > 0x0f {
        return None;
    }
    let have = digits / 2;
    if have == 2 {
        return Some((bytes, 2));
    }
    let [first, ..] = bytes;
    let need = if first >> 3 < 16 { 7 } else { 14 };
    (have == need || (need == 7 && have == MAX_FRAME_BYTES)).then_some((bytes, need))
}

fn parse_f64(text: &[u8]) -> Option<f64> {
    std::str::from_utf8(text).ok()?.parse().ok()
}

/// Two or four ASCII digits as a number.
fn decimal(digits: &[u8]) -> Option<i64> {
    digits.iter().try_fold(0i64, |acc, &c| {
        c.is_ascii_digit().then(|| acc * 10 + i64::from(c - b'0'))
    })
}

/// Days from 1970-01-01 to a proleptic Gregorian date (H. Hinnant, "chrono-Compatible
/// Low-Level Date Algorithms", `days_from_civil`).
fn days_from_civil(year: i64, month: i64, day: i64) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (month + 9) % 12; // March = 0
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

fn days_in_month(year: i64, month: i64) -> i64 {
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    match month {
        2 if leap => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

/// Unix seconds for `YYYY-MM-DDTHH:MM:SS[.fraction][Z]`, read as UTC (pyModeS sample data
/// is UTC and carries no zone). Years before 1970 and leap seconds are rejected. The result is
/// the correctly rounded f64 of the exact decimal, as a unix timestamp written out would be.
fn parse_iso_utc(text: &[u8]) -> Option<f64> {
    let text = text.strip_suffix(b"Z").unwrap_or(text);
    let (date_time, fraction) = match text.iter().position(|&b| b == b'.') {
        Some(dot) => (text.get(..dot)?, Some(text.get(dot + 1..)?)),
        None => (text, None),
    };
    let [y0, y1, y2, y3, b'-', m0, m1, b'-', d0, d1, b'T', h0, h1, b':', n0, n1, b':', s0, s1] =
        *date_time
    else {
        return None;
    };
    let year = decimal(&[y0, y1, y2, y3])?;
    let month = decimal(&[m0, m1])?;
    let day = decimal(&[d0, d1])?;
    let hour = decimal(&[h0, h1])?;
    let minute = decimal(&[n0, n1])?;
    let second = decimal(&[s0, s1])?;
    let valid = year >= 1970
        && (1..=12).contains(&month)
        && (1..=days_in_month(year, month)).contains(&day)
        && hour < 24
        && minute < 60
        && second < 60;
    if !valid {
        return None;
    }
    let unix_s = days_from_civil(year, month, day) * 86_400 + hour * 3600 + minute * 60 + second;
    let Some(fraction) = fraction else {
        return Some(unix_s as f64);
    };
    if fraction.is_empty()
        || fraction.len() > MAX_FRACTION_DIGITS
        || !fraction.iter().all(u8::is_ascii_digit)
    {
        return None;
    }
    // Write "<seconds>.<fraction>" on the stack and let the standard parser round it once.
    let mut text = [0u8; 48];
    let unused = {
        let mut w: &mut [u8] = &mut text;
        write!(w, "{unix_s}.").ok()?;
        w.write_all(fraction).ok()?;
        w.len()
    };
    parse_f64(text.get(..text.len() - unused)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(format: Format, input: &str) -> (Vec<RawFrame>, ParseStats, usize) {
        let mut p = TextParser::new(format, 10.0);
        let mut out = Vec::new();
        let used = p.parse(input.as_bytes(), &mut out);
        // The end of the stream releases the first frames, which the clock holds until
        // enough agree on the time.
        p.finish_into(&[], &mut out);
        (out, p.stats().clone(), used)
    }

    #[test]
    fn iso_dates_match_known_unix_times() {
        // Reference values from `date -u -d ... +%s` / Python's datetime, not from this code.
        assert_eq!(parse_iso_utc(b"1970-01-01T00:00:00"), Some(0.0));
        assert_eq!(parse_iso_utc(b"2000-03-01T00:00:00Z"), Some(951_868_800.0));
        assert_eq!(parse_iso_utc(b"2016-12-31T23:59:59"), Some(1_483_228_799.0));
        assert_eq!(
            parse_iso_utc(b"2024-02-29T12:00:00.5"),
            Some(1_709_208_000.5)
        );
        assert_eq!(
            parse_iso_utc(b"2015-03-03T16:12:24.846557"),
            Some(1_425_399_144.846557)
        );
        assert_eq!(parse_iso_utc(b"2023-02-29T00:00:00"), None);
        assert_eq!(parse_iso_utc(b"2015-03-03T24:00:00"), None);
        assert_eq!(parse_iso_utc(b"2015-03-03T16:12:24."), None);
        assert_eq!(parse_iso_utc(b"2015-03-03 16:12:24"), None);
        assert_eq!(parse_iso_utc(b"1969-12-31T23:59:59"), None);
    }

    #[test]
    fn frame_length_follows_df() {
        // DF11 all-call reply (56 bits) from the lax recording.
        let short = frame_from_hex(b"5dad57202809f9").map(|(_, n)| n);
        assert_eq!(short, Some(7));
        // Padded to 28 digits (afr34zg style): still 7 bytes.
        let padded = frame_from_hex(b"212800bf40f1ef7e5817e9cc428d").map(|(b, n)| b[..n].to_vec());
        assert_eq!(padded, Some(vec![0x21, 0x28, 0x00, 0xbf, 0x40, 0xf1, 0xef]));
        // DF17 needs 28 digits.
        assert_eq!(frame_from_hex(b"8DA64E2AEA0538").map(|(_, n)| n), None);
        assert_eq!(
            frame_from_hex(b"8DA64E2AEA0538A0015F08DC46E5").map(|(_, n)| n),
            Some(14)
        );
        assert_eq!(frame_from_hex(b"0000").map(|(_, n)| n), Some(2));
        assert_eq!(frame_from_hex(b"5dad57202809f"), None);
        assert_eq!(frame_from_hex(b"5dad57202809fg"), None);
        assert_eq!(frame_from_hex(b"5dad572028"), None);
    }

    #[test]
    fn avr_lines_crlf_comments_and_pacing() {
        let input = "# header\r\n*5DAD57202809F9;\r\n\r\n*8da64e2aea0538a0015f08dc46e5;\nbogus\n*8DA6;\n*5D;\n";
        let (out, stats, used) = run(Format::Avr, input);
        assert_eq!(used, input.len());
        assert_eq!(out.len(), 3);
        assert_eq!(out[0].bytes(), &[0x5d, 0xad, 0x57, 0x20, 0x28, 0x09, 0xf9]);
        assert_eq!(out[1].bytes()[0], 0x8d);
        assert_eq!(out[2].bytes(), &[0x8d, 0xa6]);
        // 10 Hz nominal rate: frames n = 0, 1, 2 at 0, 0.1, 0.2 s.
        assert_eq!(
            out.iter().map(|f| f.time_s).collect::<Vec<_>>(),
            [0.0, 0.1, 0.2]
        );
        assert_eq!(stats.bad_lines, 2);
        assert_eq!(stats.frames, 3);
    }

    #[test]
    fn avr_with_counter() {
        // 0x00000b71b00 ticks = 12,000,000 = 1 s; 0x000016e3600 = 24,000,000 = 2 s.
        let input = "@000000B71B005DAD57202809F9;\n@0000016E36008DA64E2AEA0538A0015F08DC46E5;\n@00000B71B00;\n";
        let (out, stats, _) = run(Format::Avr, input);
        assert_eq!(out.iter().map(|f| f.time_s).collect::<Vec<_>>(), [1.0, 2.0]);
        assert_eq!(out[1].bytes().len(), 14);
        assert_eq!(stats.bad_lines, 1);
    }

    #[test]
    fn csv_iso_and_json_lines() {
        let (out, stats, _) = run(
            Format::Csv,
            "1753827785.8086092,8DADA5265851E6616376C2EB4463\ntimestamp,frame\n",
        );
        assert_eq!(out[0].time_s, 1_753_827_785.808_609_2);
        assert_eq!(stats.bad_lines, 1);

        let (out, _, _) = run(
            Format::Iso,
            "2015-03-03T16:12:24.846557    5D4840D6F87407\n",
        );
        assert_eq!(out[0].time_s, 1_425_399_144.846_557);
        assert_eq!(out[0].bytes(), &[0x5d, 0x48, 0x40, 0xd6, 0xf8, 0x74, 0x07]);

        let json = concat!(
            r#"{"timestamp":1720248190.012853,"frame":"212800bf40f1ef7e5817e9cc428d","df":"4","altitude":575}"#,
            "\n",
            r#"{"frame":"212800bf40f1ef7e5817e9cc428d"}"#,
            "\n",
            r#"{"timestamp":1720248190.5,"frame":"2128"#,
            "\n"
        );
        let (out, stats, _) = run(Format::Jsonl, json);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].time_s, 1_720_248_190.012_853);
        assert_eq!(out[0].bytes().len(), 7);
        assert_eq!(stats.bad_lines, 2);
    }

    #[test]
    fn final_line_without_newline_is_parsed_at_finish() {
        let mut p = TextParser::new(Format::Csv, 10.0);
        let mut out = Vec::new();
        let input = b"1.5,5DAD57202809F9\n2.5,5DAD57202809F9";
        let used = p.parse(input, &mut out);
        assert_eq!(used, 19);
        p.finish_into(&input[used..], &mut out);
        assert_eq!(out.iter().map(|f| f.time_s).collect::<Vec<_>>(), [1.5, 2.5]);
        // A cut line is a truncated tail, not a frame.
        p.finish_into(b"3.5,5DAD5720", &mut out);
        assert_eq!(out.len(), 2);
        assert_eq!(p.stats().truncated_tail_bytes, 12);
        assert_eq!(p.stats().frames, 2);
    }

    /// Fuzz finding (target `feed_avr`): an overlong comment line was skipped when it came
    /// in one read but counted as a bad line when it came in pieces (`parse` drops an
    /// unterminated line past `MAX_LINE_BYTES` before seeing that it is a comment).
    #[test]
    fn overlong_comment_counts_the_same_however_it_arrives() {
        let mut input = b"#a".to_vec();
        input.resize(2 + 129 * 128, b'a');
        input.extend_from_slice(b"\n*8D4840D6202CC371C32CE0576098;\n");
        let mut counts = Vec::new();
        for chunk in [268, input.len()] {
            let mut p = TextParser::new(Format::Avr, 10.0);
            let mut out = Vec::new();
            let mut pending: Vec<u8> = Vec::new();
            for piece in input.chunks(chunk) {
                pending.extend_from_slice(piece);
                let used = p.parse(&pending, &mut out);
                pending.drain(..used);
            }
            p.finish_into(&pending, &mut out);
            counts.push(p.stats().clone());
        }
        assert_eq!(counts[0], counts[1]);
        assert_eq!((counts[0].frames, counts[0].bad_lines), (1, 1));
    }

    #[test]
    fn overlong_line_is_one_bad_line_however_it_arrives() {
        let mut long = vec![b'*'; MAX_LINE_BYTES + 10];
        long.extend_from_slice(b"\n*5DAD57202809F9;\n");
        for chunk in [7, 1000, long.len()] {
            let mut p = TextParser::new(Format::Avr, 10.0);
            let mut out = Vec::new();
            let mut pending: Vec<u8> = Vec::new();
            for piece in long.chunks(chunk) {
                pending.extend_from_slice(piece);
                let used = p.parse(&pending, &mut out);
                assert!(pending.len() - used <= MAX_LINE_BYTES);
                pending.drain(..used);
            }
            assert_eq!((out.len(), p.stats().bad_lines), (1, 1), "chunk {chunk}");
        }
    }
}
