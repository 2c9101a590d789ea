//! Beast binary framing (Mode-S Beast receivers, readsb/dump1090 port 30005).
//!
//! A frame on the wire:
//!
//! ```text
//! 0x1a  type  counter[6]  signal[1]  data[2 | 7 | 14]
//! ```
//!
//! `type` is `'1'` (Mode A/C, 2 data bytes), `'2'` (Mode S short, 56 bits) or `'3'` (Mode S
//! long, 112 bits); `counter` is the receiver's 48-bit 12 MHz clock, big-endian; `signal` is
//! the RSSI byte. Every 0x1a inside counter, signal or data is sent twice, so a lone 0x1a
//! followed by anything but 0x1a always starts a frame. Radarcape receivers also send type
//! `'4'` (status: counter, signal, 14 bytes) and `'5'` (GPS position: 21 bytes) records
//! (mlat-client `modes_reader.c`, `feed_beast`); they carry no Mode S reply and are skipped
//! whole, counted as bad frames. Any other type is skipped and counted, and parsing
//! resynchronises on the next 0x1a that starts a frame, as readsb's `readBeast` does.

use super::{FeedClock, FrameParser, ParseStats, RawFrame, MAX_FRAME_BYTES};

/// The frame marker, and the escape for a 0x1a data byte.
const ESC: u8 = 0x1a;

/// Counter (6 bytes) and signal (1 byte) precede the data.
const HEADER_BYTES: usize = 7;

/// Longest unescaped body: header plus a 14-byte long frame (and the size of both Radarcape
/// records).
const MAX_BODY_BYTES: usize = HEADER_BYTES + 14;

/// What follows `0x1a type`, by type byte.
#[derive(Clone, Copy)]
enum Kind {
    /// A Mode A/C or Mode S reply with this many data bytes.
    Frame(usize),
    /// A Radarcape status or position record: skipped whole.
    Radarcape,
}

fn kind(type_byte: u8) -> Option<Kind> {
    match type_byte {
        b'1' => Some(Kind::Frame(2)),
        b'2' => Some(Kind::Frame(7)),
        b'3' => Some(Kind::Frame(14)),
        b'4' | b'5' => Some(Kind::Radarcape),
        _ => None,
    }
}

impl Kind {
    fn body_bytes(self) -> usize {
        match self {
            Self::Frame(data) => HEADER_BYTES + data,
            Self::Radarcape => MAX_BODY_BYTES,
        }
    }
}

/// Result of unescaping one frame body.
enum Body {
    /// The body is complete; this many escaped bytes were used.
    Complete(usize),
    /// The buffer ends inside the body: wait for more bytes.
    Incomplete,
    /// A 0x1a not followed by 0x1a at this offset: the frame was cut short and a new one
    /// starts there.
    Broken(usize),
}

/// Copies `want` unescaped bytes from `src` into `dst` (bytes of `dst` past `want` may be
/// overwritten with whatever follows).
#[inline]
fn unescape(src: &[u8], want: usize, dst: &mut [u8; MAX_BODY_BYTES]) -> Body {
    // Fast path, taken by nearly every frame: copy a fixed-size window (plain moves, no
    // memcpy call) and check the `want` bytes that matter for an escape.
    if let (Some(window), Some(head)) = (src.first_chunk::<MAX_BODY_BYTES>(), src.get(..want)) {
        if !head.iter().fold(false, |seen, &b| seen | (b == ESC)) {
            *dst = *window;
            return Body::Complete(want);
        }
    }
    let mut used = 0;
    for slot in dst.iter_mut().take(want) {
        let (byte, step) = match src.get(used..) {
            None | Some([] | [ESC]) => return Body::Incomplete,
            Some([ESC, ESC, ..]) => (ESC, 2),
            Some([ESC, ..]) => return Body::Broken(used),
            Some([b, ..]) => (*b, 1),
        };
        *slot = byte;
        used += step;
    }
    Body::Complete(used)
}

/// Incremental Beast parser: see the module documentation for the format.
#[derive(Debug, Default)]
pub struct BeastParser {
    clock: FeedClock,
    stats: ParseStats,
}

impl BeastParser {
    /// A parser at the start of a stream.
    pub fn new() -> Self {
        Self::default()
    }
}

impl FrameParser for BeastParser {
    fn parse(&mut self, buf: &[u8], out: &mut Vec<RawFrame>) -> usize {
        let frames_before = out.len();
        let mut pos = 0;
        let mut body = [0u8; MAX_BODY_BYTES];
        while let Some(rest) = buf.get(pos..) {
            match rest {
                [] | [ESC] => break,
                [ESC, type_byte, escaped @ ..] => {
                    let Some(kind) = kind(*type_byte) else {
                        // 0x1a 0x1a here is an escaped data byte seen out of sync; anything
                        // else is an unknown frame type. Skip both bytes, as readsb does.
                        if *type_byte != ESC {
                            self.stats.bad_frames += 1;
                        }
                        self.stats.garbage_bytes += 2;
                        pos += 2;
                        continue;
                    };
                    let want = kind.body_bytes();
                    match unescape(escaped, want, &mut body) {
                        Body::Incomplete => break,
                        Body::Broken(at) => {
                            self.stats.bad_frames += 1;
                            self.stats.garbage_bytes += 2 + at as u64;
                            pos += 2 + at;
                        }
                        Body::Complete(used) => {
                            pos += 2 + used;
                            if let Kind::Frame(data) = kind {
                                self.emit(&body, data, out);
                            } else {
                                self.stats.bad_frames += 1;
                            }
                        }
                    }
                }
                _ => {
                    let skip = rest.iter().position(|&b| b == ESC).unwrap_or(rest.len());
                    self.stats.garbage_bytes += skip as u64;
                    pos += skip;
                }
            }
        }
        self.sync_stats(frames_before, out);
        pos
    }

    /// Counts the tail; frames the clock holds (a time step waiting for confirmation) stay
    /// held for the stream that follows (a reconnect).
    fn finish(&mut self, tail: &[u8]) {
        self.stats.truncated_tail_bytes += tail.len() as u64;
    }

    /// The stream ended: counts the tail and releases the frames the clock holds.
    fn finish_into(&mut self, tail: &[u8], out: &mut Vec<RawFrame>) {
        self.finish(tail);
        let frames_before = out.len();
        self.clock.flush(out);
        self.sync_stats(frames_before, out);
    }

    fn stats(&self) -> &ParseStats {
        &self.stats
    }
}

impl BeastParser {
    /// Counts the frames added to `out` since it held `frames_before`, and copies the
    /// clock's counters.
    fn sync_stats(&mut self, frames_before: usize, out: &[RawFrame]) {
        self.stats.frames += out.len().saturating_sub(frames_before) as u64;
        self.stats.clock_resets = self.clock.resets();
        self.stats.time_outliers = self.clock.outliers();
    }

    /// Hands on one unescaped body: counter, signal, then `data` bytes.
    #[inline]
    fn emit(&mut self, body: &[u8; MAX_BODY_BYTES], data: usize, out: &mut Vec<RawFrame>) {
        let [c0, c1, c2, c3, c4, c5, signal, ..] = *body;
        let ticks = u64::from_be_bytes([0, 0, c0, c1, c2, c3, c4, c5]);
        // Mode A/C replies carry no address and are never tracked, and dump1090 may hold
        // them for up to a minute before sending them (mlat-client keeps their stamps out of
        // its clock, `modes_reader.c`): one would count as a receiver restart. They get the
        // last time and leave the clock alone. Any other frame is timed now if it is an
        // ordinary one (the time first, then the frame is built in place), else by the clock
        // below.
        let ordinary_s = if data == 2 {
            None
        } else {
            self.clock.ordinary_ticks(ticks)
        };
        // The last 14 bytes of the body: the data, and for shorter frames whatever followed
        // (ignored by `from_padded`).
        let Some(tail) = body.last_chunk::<MAX_FRAME_BYTES>() else {
            return;
        };
        let mut buf = [0u8; MAX_FRAME_BYTES];
        match data {
            2 => buf[..2].copy_from_slice(&tail[..2]),
            7 => buf[..7].copy_from_slice(&tail[..7]),
            _ => buf = *tail,
        }
        if let Some(time_s) = ordinary_s {
            if let Some(frame) = RawFrame::from_padded(time_s, buf, data, Some(signal)) {
                out.push(frame);
            }
            return;
        }
        self.emit_judged(ticks, buf, data, signal, out);
    }

    /// [`emit`](Self::emit) for a frame the clock has to judge (or hold): out of line, so the
    /// ordinary path stays small.
    #[inline(never)]
    fn emit_judged(
        &mut self,
        ticks: u64,
        buf: [u8; MAX_FRAME_BYTES],
        data: usize,
        signal: u8,
        out: &mut Vec<RawFrame>,
    ) {
        let Some(frame) = RawFrame::from_padded(0.0, buf, data, Some(signal)) else {
            return;
        };
        if data == 2 {
            self.clock.push_untimed(frame, out);
        } else {
            self.clock.push_ticks(ticks, frame, out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Escapes a body the way a Beast sender does: each 0x1a doubled.
    fn frame(type_byte: u8, body: &[u8]) -> Vec<u8> {
        let mut v = vec![ESC, type_byte];
        for &b in body {
            v.push(b);
            if b == ESC {
                v.push(ESC);
            }
        }
        v
    }

    /// Parses `buf` as a whole stream (the clock holds a stream's first frames until they
    /// agree on the time: the end of the stream releases them).
    fn parse_all(p: &mut BeastParser, buf: &[u8]) -> (Vec<RawFrame>, usize) {
        let mut out = Vec::new();
        let used = p.parse(buf, &mut out);
        p.finish_into(&[], &mut out);
        (out, used)
    }

    #[test]
    fn long_frame_with_escaped_counter_signal_and_data() {
        // Counter 00 00 1a 00 00 1a = 436,207,642 ticks, signal 0x1a, and a DF17 frame
        // (the ICAO Doc 9871 identification example 8D4840D6202CC371C32CE0576098) whose bytes
        // hold no 0x1a; then a short frame with two 0x1a data bytes.
        let df17 = [
            0x8d, 0x48, 0x40, 0xd6, 0x20, 0x2c, 0xc3, 0x71, 0xc3, 0x2c, 0xe0, 0x57, 0x60, 0x98,
        ];
        let mut body = vec![0x00, 0x00, 0x1a, 0x00, 0x00, 0x1a, 0x1a];
        body.extend_from_slice(&df17);
        let mut wire = frame(b'3', &body);
        // The short frame's counter (one tick later) holds a 0x1a too.
        let short = [
            0, 0, 0x1a, 0, 0, 0x1b, 0x20, 0x5d, 0x1a, 0x40, 0xd6, 0x1a, 0x00, 0x01,
        ];
        wire.extend(frame(b'2', &short));
        assert_eq!(wire.len(), 2 + 21 + 3 + 2 + 14 + 3);

        let mut p = BeastParser::new();
        let (out, used) = parse_all(&mut p, &wire);
        assert_eq!(used, wire.len());
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].bytes(), &df17);
        assert_eq!(out[0].signal, Some(0x1a));
        assert_eq!(out[0].time_s, 436_207_642.0 / 12e6);
        assert_eq!(out[1].bytes(), &[0x5d, 0x1a, 0x40, 0xd6, 0x1a, 0x00, 0x01]);
        assert_eq!(out[1].signal, Some(0x20));
        assert_eq!(out[1].time_s, 436_207_643.0 / 12e6);
        assert_eq!(p.stats().clock_resets, 0);
        assert_eq!(p.stats().frames, 2);
        assert_eq!(p.stats().garbage_bytes, 0);
    }

    #[test]
    fn mode_ac_frame_takes_the_last_time() {
        // A short Mode S frame at 12,000,000 ticks = 1 s, then a 2-byte Mode A/C reply stamped
        // 2 s, whose stamp does not move the clock.
        let mut wire = frame(b'2', &[0, 0, 0, 0xb7, 0x1b, 0x00, 9, 1, 2, 3, 4, 5, 6, 7]);
        wire.extend(frame(b'1', &[0, 0, 1, 0x6e, 0x36, 0x00, 0x55, 0x02, 0x40]));
        let mut p = BeastParser::new();
        let (out, used) = parse_all(&mut p, &wire);
        assert_eq!(used, 16 + 11);
        assert_eq!(out.len(), 2);
        assert!(out[1].is_mode_ac());
        assert_eq!(out[1].bytes(), &[0x02, 0x40]);
        assert_eq!(out[1].signal, Some(0x55));
        assert_eq!((out[0].time_s, out[1].time_s), (1.0, 1.0));
    }

    #[test]
    fn incomplete_frame_is_left_unconsumed() {
        let mut wire = frame(b'1', &[0, 0, 0, 0xb7, 0x1b, 0x00, 0x55, 0x02, 0x40]);
        wire.extend(frame(
            b'2',
            &[0, 0, 0, 0xb7, 0x1b, 0x01, 9, 1, 2, 3, 4, 5, 6, 7],
        ));
        for cut in 11..wire.len() {
            let mut p = BeastParser::new();
            let (out, used) = parse_all(&mut p, &wire[..cut]);
            assert_eq!((out.len(), used), (1, 11), "cut at {cut}");
            assert_eq!(p.stats().garbage_bytes, 0);
        }
        let mut p = BeastParser::new();
        // A body that ends on a lone 0x1a cannot be judged yet.
        let esc_tail = [ESC, b'2', 0, 0, ESC];
        assert_eq!(parse_all(&mut p, &esc_tail).1, 0);
        p.finish(&esc_tail);
        assert_eq!(p.stats().truncated_tail_bytes, 5);
    }

    #[test]
    fn status_unknown_type_and_broken_frame_are_counted() {
        let good = frame(b'1', &[0, 0, 0, 0xb7, 0x1b, 0x00, 0x55, 0x02, 0x40]);
        let mut wire = frame(b'4', &[0u8; 21]);
        wire.extend_from_slice(&[ESC, b'9', 0xaa, 0xbb]); // unknown type, 2 stray bytes
        wire.extend_from_slice(&good);
        wire.extend_from_slice(&[ESC, b'3', 1, 2, 3]); // cut short by the next frame
        wire.extend_from_slice(&good);
        let mut p = BeastParser::new();
        let (out, used) = parse_all(&mut p, &wire);
        assert_eq!(used, wire.len());
        assert_eq!(out.len(), 2);
        assert_eq!(p.stats().bad_frames, 3);
        // 2 (unknown header) + 2 (stray) + 5 (broken frame)
        assert_eq!(p.stats().garbage_bytes, 9);
    }
}
