//! What the fuzz targets share: how an input is cut into socket reads, how a byte stream is
//! parsed the way the daemon's readers parse it, CRC repair so that mutated frames still reach
//! the decoder, and the invariants every target asserts.
//!
//! Each check panics with a message naming the broken invariant: libFuzzer records the input
//! as a crash, which is what we want.

use adsb_tracker::config::Config;
use adsb_tracker::daemon::aircraft::{Aircraft, AircraftConfig};
use adsb_tracker::daemon::registry::TrackState;
use adsb_tracker::daemon::stats::Counts;
use adsb_tracker::decode::cpr::CprConfig;
use adsb_tracker::decode::crc::crc24;
use adsb_tracker::decode::{Decoder, DecoderConfig, Icao};
use adsb_tracker::feed::detect::{detect, DETECT_HEAD_BYTES};
use adsb_tracker::feed::{parser_for, Format, ParseStats, RawFrame};
use std::collections::HashMap;

/// Pacing of untimed AVR frames in every target (frames per second).
pub const NOMINAL_RATE_HZ: f64 = 1000.0;

/// The formats a selector picks from (index = selector % 5).
pub const FORMATS: [Format; 5] = [
    Format::Beast,
    Format::Avr,
    Format::Csv,
    Format::Iso,
    Format::Jsonl,
];

/// The format named by a selector's bits 0-2 (5-7: Beast, the daemon's usual feed).
pub fn format_of(selector: u8) -> Format {
    FORMATS
        .get(usize::from(selector & 7))
        .copied()
        .unwrap_or(Format::Beast)
}

/// The frames of a decoder or pipeline target's stream: parsed in the format named by the
/// selector's bits 0-2 (0-4: Beast, AVR, CSV, ISO, JSON lines), or for 5-7 built by
/// [`synthetic_frames`].
pub fn frames_of(selector: u8, stream: &[u8]) -> Vec<RawFrame> {
    if selector & 7 >= 5 {
        synthetic_frames(stream)
    } else {
        run_parser(format_of(selector), &[stream]).frames
    }
}

/// DF17 frames, 8 input bytes each, that all reach the decoder and the trackers: byte 0
/// holds the time step (bits 0-5: 0.1 s units, 63 a gap of 100 s) and which of four addresses
/// sends (bits 6-7); bytes 1-7 are the ME field; the parity is computed. A few hundred
/// reports of one aircraft fit in an input, where a Beast stream holds a few dozen.
pub fn synthetic_frames(stream: &[u8]) -> Vec<RawFrame> {
    let mut t_s = 0.0;
    stream
        .chunks_exact(8)
        .filter_map(|record| {
            let (&head, me) = record.split_first()?;
            let step = head & 0x3f;
            t_s += if step == 0x3f {
                100.0
            } else {
                f64::from(step) * 0.1
            };
            let icao = 0x48_40D6 + u32::from(head >> 6);
            let mut bytes = [0u8; 14];
            bytes[0] = 0x8d; // DF17, CA 5
            bytes[1..4].copy_from_slice(&icao.to_be_bytes()[1..]);
            bytes[4..11].copy_from_slice(me);
            let parity = crc24(&bytes[..11]);
            bytes[11..].copy_from_slice(&parity.to_be_bytes()[1..]);
            RawFrame::new(t_s, &bytes, None)
        })
        .collect()
}

/// Splits off the first byte of a fuzz input (the target's own settings) from the stream.
pub fn split_selector(data: &[u8]) -> (u8, &[u8]) {
    match data.split_first() {
        Some((&s, rest)) => (s, rest),
        None => (0, &[]),
    }
}

/// Cuts `data` into reads as a socket might deliver them: `seed` 0 gives one read, any other
/// value a deterministic sequence of read sizes (from single bytes to half-kilobytes).
pub fn pieces(data: &[u8], seed: u8) -> Vec<&[u8]> {
    if seed == 0 || data.is_empty() {
        return vec![data];
    }
    // About 128 reads at most: a text parser rescans an unterminated line on every read,
    // and single-byte reads of a long input spent the fuzzer's time on that alone (the cut
    // points are random, so every position is still a cut now and then).
    let limit = [1usize, 2, 5, 13, 64, 300, 1500][usize::from(seed % 7)].max(data.len() / 64);
    let mut state = u32::from(seed).wrapping_mul(0x9E37_79B9) | 1;
    let mut out = Vec::new();
    let mut rest = data;
    while !rest.is_empty() {
        // xorshift32
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let n = (state as usize % limit + 1).min(rest.len());
        let (head, tail) = rest.split_at(n);
        out.push(head);
        rest = tail;
    }
    out
}

/// What a parser made of a stream.
#[derive(Debug)]
pub struct Run {
    pub frames: Vec<RawFrame>,
    pub stats: ParseStats,
    /// Bytes the parser consumed across all calls (the rest is the tail at the end).
    pub consumed: usize,
    /// What was left unconsumed when the stream ended (handed to `finish_into`).
    pub tail: Vec<u8>,
}

/// Parses `reads` in order the way the daemon's readers do (keep the unconsumed tail, append
/// the next read, parse again), then finishes with the tail. Asserts on every call that the
/// parser consumed no more than it was given.
pub fn run_parser(format: Format, reads: &[&[u8]]) -> Run {
    let mut parser = parser_for(format, NOMINAL_RATE_HZ);
    let mut frames = Vec::new();
    let mut pending: Vec<u8> = Vec::new();
    let mut consumed = 0;
    for read in reads {
        pending.extend_from_slice(read);
        let before = frames.len();
        let used = parser.parse(&pending, &mut frames);
        assert!(
            used <= pending.len(),
            "{format:?}: consumed {used} of {} bytes",
            pending.len()
        );
        assert_eq!(
            parser.stats().frames,
            frames.len() as u64,
            "{format:?}: frames counter after a call that added {}",
            frames.len() - before
        );
        consumed += used;
        pending.drain(..used);
    }
    parser.finish_into(&pending, &mut frames);
    Run {
        frames,
        stats: parser.stats().clone(),
        consumed,
        tail: pending,
    }
}

/// Frames as the daemon needs them: 2, 7 or 14 bytes, finite feed time that never goes back.
pub fn check_frames(format: Format, frames: &[RawFrame]) {
    let mut last = f64::NEG_INFINITY;
    for (i, f) in frames.iter().enumerate() {
        assert!(
            matches!(f.bytes().len(), 2 | 7 | 14),
            "{format:?}: frame {i} has {} bytes",
            f.bytes().len()
        );
        assert!(
            f.time_s.is_finite(),
            "{format:?}: frame {i} at time {}",
            f.time_s
        );
        assert!(
            f.time_s >= last,
            "{format:?}: time went back from {last} to {} at frame {i}",
            f.time_s
        );
        last = f.time_s;
    }
}

/// Parses `data` whole and cut into the reads `seed` chooses, checks both against each other
/// (the frames and every counter must not depend on how the bytes arrived) and the frames
/// themselves. Returns the whole run.
pub fn parse_both_ways(format: Format, data: &[u8], seed: u8) -> Run {
    let whole = run_parser(format, &[data]);
    check_frames(format, &whole.frames);
    assert_eq!(whole.stats.frames, whole.frames.len() as u64);
    assert_eq!(whole.consumed + whole.tail.len(), data.len());
    if seed != 0 {
        let split = run_parser(format, &pieces(data, seed));
        assert!(
            split.frames == whole.frames,
            "{format:?}: cutting the reads changed the frames ({} vs {} whole)",
            split.frames.len(),
            whole.frames.len()
        );
        assert_eq!(
            split.stats, whole.stats,
            "{format:?}: cutting the reads changed the counters"
        );
    }
    whole
}

/// Longest text [`expand_runs`] makes: room for a line past `MAX_LINE_BYTES` and more.
pub const MAX_EXPANDED_BYTES: usize = 20 * 1024;

/// Expands `0xFF n` into `(n + 1) * 128` copies of the byte before it (up to
/// [`MAX_EXPANDED_BYTES`] in all), so that a short input can hold the lines of tens of
/// kilobytes the text parsers must bound (`MAX_LINE_BYTES`). Text formats never carry 0xFF,
/// so nothing a real line says is lost.
pub fn expand_runs(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len());
    let mut i = 0;
    while let Some(&b) = data.get(i) {
        let run = data.get(i + 1).map(|&n| (usize::from(n) + 1) * 128);
        match (b, run, out.last().copied()) {
            (0xFF, Some(run), Some(prev)) if out.len() + run <= MAX_EXPANDED_BYTES => {
                out.resize(out.len() + run, prev);
                i += 2;
            }
            _ => {
                out.push(b);
                i += 1;
            }
        }
    }
    out
}

/// Writes a correct parity into Mode S frames, so that mutated frames reach the decoder
/// instead of dying on CRC: DF11/17/18 get the plain CRC (interrogator 0), the
/// Address/Parity replies (DF0/4/5/16/20/21) the CRC overlaid with the last DF11/17/18
/// address seen, as a transponder that was just heard would send. Mode A/C frames pass.
#[derive(Debug, Default)]
pub struct CrcFixer {
    last_address: u32,
}

impl CrcFixer {
    pub fn fix(&mut self, frame: &RawFrame) -> RawFrame {
        let mut bytes = [0u8; 14];
        let n = frame.bytes().len();
        bytes[..n].copy_from_slice(frame.bytes());
        if n < 7 {
            return *frame;
        }
        let df = bytes[0] >> 3;
        let crc = crc24(&bytes[..n - 3]);
        let parity = match df {
            11 | 17 | 18 => {
                self.last_address =
                    u32::from(bytes[1]) << 16 | u32::from(bytes[2]) << 8 | u32::from(bytes[3]);
                crc
            }
            0 | 4 | 5 | 16 | 20 | 21 => crc ^ self.last_address,
            _ => return *frame,
        };
        bytes[n - 3] = (parity >> 16) as u8;
        bytes[n - 2] = (parity >> 8) as u8;
        bytes[n - 1] = parity as u8;
        RawFrame::new(frame.time_s, &bytes[..n], frame.signal).unwrap_or(*frame)
    }
}

fn finite(name: &str, v: f64) {
    assert!(v.is_finite(), "published {name} = {v}");
}

/// Everything a published track says is a finite number in its range: what the API and
/// `--tracks-out` serialise (a NaN would print as `null`).
pub fn check_track_state(s: &TrackState) {
    for (name, v) in [
        ("t", s.t),
        ("lat", s.lat),
        ("lon", s.lon),
        ("alt_m", s.alt_m),
        ("ve", s.ve),
        ("vn", s.vn),
        ("vu", s.vu),
        ("pos_sigma_m", s.pos_sigma_m),
        ("vel_sigma_mps", s.vel_sigma_mps),
        ("ground_speed_mps", s.ground_speed_mps),
        ("track_deg", s.track_deg),
        ("vertical_rate_mps", s.vertical_rate_mps),
        ("last_seen", s.last_seen),
    ] {
        finite(name, v);
    }
    assert!((-90.0..=90.0).contains(&s.lat), "published lat {}", s.lat);
    assert!((-180.0..=180.0).contains(&s.lon), "published lon {}", s.lon);
    assert!(
        (0.0..=360.0).contains(&s.track_deg),
        "track_deg {}",
        s.track_deg
    );
    assert!(s.pos_sigma_m >= 0.0 && s.vel_sigma_mps >= 0.0);
    for (name, m) in [
        ("pos_cov_enu_m2", &s.pos_cov_enu_m2),
        ("vel_cov_enu_m2ps2", &s.vel_cov_enu_m2ps2),
    ] {
        for (i, row) in m.iter().enumerate() {
            for &v in row {
                finite(name, v);
            }
            assert!(row[i] >= 0.0, "{name} has a negative variance {}", row[i]);
        }
    }
    let p = &s.mode_probabilities;
    let probs = [p.cv, p.ca, p.ct, p.ch, p.chca];
    for v in probs {
        assert!(
            v.is_finite() && (-1e-9..=1.0 + 1e-9).contains(&v),
            "mode probability {v}"
        );
    }
    assert!(
        probs.iter().sum::<f64>() <= 1.0 + 1e-6,
        "mode probabilities {probs:?}"
    );
    for pr in &s.predictions {
        for (name, v) in [
            ("prediction dt_s", pr.dt_s),
            ("prediction t", pr.t),
            ("prediction lat", pr.lat),
            ("prediction lon", pr.lon),
            ("prediction alt_m", pr.alt_m),
            ("prediction pos_sigma_m", pr.pos_sigma_m),
        ] {
            finite(name, v);
        }
        assert!((-90.0..=90.0).contains(&pr.lat) && (-180.0..=180.0).contains(&pr.lon));
    }
    // The serialised line must hold no `null` where a number belongs.
    if let Ok(line) = serde_json::to_string(s) {
        let v: serde_json::Value = serde_json::from_str(&line).unwrap_or_default();
        for key in ["t", "lat", "lon", "alt_m", "ve", "vn", "vu", "pos_sigma_m"] {
            assert!(
                v.get(key).is_some_and(serde_json::Value::is_number),
                "{key} in {line}"
            );
        }
    }
}

/// Format detection on the head of a stream, as a replay does it: whatever it picks reads
/// at least one frame from that head.
pub fn check_detect(stream: &[u8]) {
    let head = stream.get(..DETECT_HEAD_BYTES).unwrap_or(stream);
    if let Some(format) = detect(head) {
        let run = run_parser(format, &[head]);
        assert!(
            !run.frames.is_empty(),
            "detected {format:?} but it reads nothing"
        );
    }
}

/// Longest line the text parsers take (`text::MAX_LINE_BYTES`).
pub use adsb_tracker::feed::text::MAX_LINE_BYTES;

/// Lines that must come out as a frame, a bad line or the truncated tail: every line but
/// blank ones and `#` comments, and any line too long to be looked at.
pub fn countable_lines(stream: &[u8]) -> u64 {
    stream
        .split(|&b| b == b'\n')
        .filter(|line| {
            let t = line.trim_ascii();
            line.len() > MAX_LINE_BYTES || !(t.is_empty() || t.first() == Some(&b'#'))
        })
        .count() as u64
}

/// Checks that a text parser accounted for every line of `stream` (parsed whole): each
/// countable line gave one frame, one bad line or the truncated tail.
pub fn check_line_accounting(format: Format, stream: &[u8], run: &Run) {
    let s = &run.stats;
    let truncated = u64::from(s.truncated_tail_bytes > 0);
    assert_eq!(
        s.frames + s.bad_lines + truncated,
        countable_lines(stream),
        "{format:?}: {} frames + {} bad lines + {truncated} truncated tail",
        s.frames,
        s.bad_lines
    );
    assert_eq!(s.garbage_bytes, 0);
    assert_eq!(s.bad_frames, 0);
    // The caller's buffer of an unterminated line stays bounded.
    assert!(
        run.tail.len() <= MAX_LINE_BYTES,
        "tail of {} bytes",
        run.tail.len()
    );
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect()
}

/// The frames written back out as AVR `*hex;` lines and as CSV lines parse back to the same
/// bytes: the length rules (4 digits Mode A/C, else by DF) agree with what was produced.
pub fn check_reemitted(frames: &[RawFrame]) {
    let want: Vec<&[u8]> = frames.iter().map(RawFrame::bytes).collect();
    let mut avr = String::new();
    let mut csv = String::new();
    for f in frames {
        avr.push_str(&format!("*{};\n", hex(f.bytes())));
        csv.push_str(&format!("{:?},{}\n", f.time_s, hex(f.bytes())));
    }
    for (format, text) in [(Format::Avr, avr), (Format::Csv, csv)] {
        let back = run_parser(format, &[text.as_bytes()]);
        let got: Vec<&[u8]> = back.frames.iter().map(RawFrame::bytes).collect();
        assert!(got == want, "{format:?}: re-emitted frames changed");
        assert_eq!(
            back.stats.bad_lines, 0,
            "{format:?}: re-emitted line refused"
        );
    }
}

/// What [`run_pipeline`] did.
#[derive(Debug, Default)]
pub struct PipelineRun {
    /// Frames the decoder accepted.
    pub decoded: u64,
    /// Tracker updates (measurements taken).
    pub updates: u64,
    /// Published snapshots checked.
    pub published: u64,
}

/// Frames to published tracks the way the daemon runs them: the router's [`Decoder`] and
/// retirement after `tracker.retire_after_s` of feed-time silence, each aircraft's
/// [`Aircraft`] (CPR, measurements, tracker), and after every message the snapshot it would
/// publish, with predictions, turned into the API's [`TrackState`]. Every published state is
/// checked ([`check_track_state`]), as are the counters.
pub fn run_pipeline(config: &Config, frames: &[RawFrame], fix_crc: bool) -> PipelineRun {
    let mut decoder = Decoder::new(DecoderConfig {
        fix_single_bit: config.decode.fix_single_bit,
        recent_address_s: config.decode.recent_address_s,
    });
    let cfg = AircraftConfig {
        cpr: CprConfig {
            pair_window_s: config.cpr.pair_window_s,
            max_speed_mps: config.cpr.max_speed_mps,
            max_surface_speed_mps: config.cpr.max_surface_speed_mps,
            receiver: config.receiver.map(|r| (r.lat_deg, r.lon_deg)),
            ..CprConfig::default()
        },
        tracker: adsb_tracker::daemon::build_tracker,
        tracker_config: config.tracker.clone(),
        duplicate_window_s: config.decode.duplicate_window_s,
    };
    let horizons = &config.tracker.prediction_horizons_s;
    let mut fixer = CrcFixer::default();
    let mut aircraft: HashMap<Icao, (Aircraft, f64)> = HashMap::new();
    let mut counts = Counts::default();
    let mut run = PipelineRun::default();
    for frame in frames {
        let frame = if fix_crc { fixer.fix(frame) } else { *frame };
        let Ok(d) = decoder.decode(&frame) else {
            continue;
        };
        run.decoded += 1;
        let entry = aircraft
            .entry(d.icao)
            .or_insert_with(|| (Aircraft::new(d.icao, &cfg), d.time_s));
        if d.time_s - entry.1 > config.tracker.retire_after_s {
            *entry = (Aircraft::new(d.icao, &cfg), d.time_s);
        }
        entry.1 = d.time_s;
        let ac = &mut entry.0;
        let updated = ac.handle(&d, &mut counts);
        if updated {
            run.updates += 1;
            // An update leaves an estimate, unless publishing it found it non-finite or run
            // away and reset the track (counted).
            let resets = counts.track_resets_nonfinite;
            assert!(
                ac.snapshot(&mut counts).is_some() || counts.track_resets_nonfinite > resets,
                "an update left no estimate"
            );
        }
        if let Some(p) = ac.published(horizons, &mut counts) {
            let s = p.track_state();
            check_track_state(&s);
            assert_eq!(s.predictions.len(), horizons.len().min(s.predictions.len()));
            assert!(
                s.t <= s.last_seen,
                "estimate at {} after the last message {}",
                s.t,
                s.last_seen
            );
            run.published += 1;
        }
    }
    assert_eq!(counts.track_updates, run.updates);
    assert_eq!(decoder.stats().decoded, run.decoded);
    run
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pieces_cover_the_input() {
        let data: Vec<u8> = (0..=255).collect();
        for seed in 0..=255u8 {
            let p = pieces(&data, seed);
            assert_eq!(p.concat(), data);
            assert!(p.iter().all(|x| !x.is_empty()));
        }
    }

    #[test]
    fn runs_expand() {
        assert_eq!(expand_runs(b"a\xff\x00b").len(), 1 + 128 + 1);
        assert_eq!(expand_runs(b"\xff\x01"), b"\xff\x01");
    }
}
