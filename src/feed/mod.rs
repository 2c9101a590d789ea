//! Feeds: bytes from a receiver or a recording -> [`RawFrame`]s.
//!
//! Every parser is incremental (it is handed whatever a socket read or a file chunk gave and
//! keeps an incomplete tail for the next call), never panics on any input, and counts what it
//! skips in [`ParseStats`]. Time is always the feed's own time in seconds, never the wall clock.

pub mod beast;
pub mod clock;
pub mod detect;
pub mod pace;
pub mod replay;
pub mod tcp;
pub mod text;

use serde::Serialize;
use std::path::PathBuf;

pub use clock::FeedClock;

/// Longest Mode S frame: 112 bits.
pub const MAX_FRAME_BYTES: usize = 14;

/// One frame as a receiver heard it: Mode A/C (2 bytes), Mode S short (7) or long (14).
///
/// Fixed-size and `Copy` so the hot path moves frames without allocating.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawFrame {
    /// Feed time in seconds (Beast 12 MHz counter / 12e6, or the file's timestamp).
    pub time_s: f64,
    /// Receiver signal level byte (Beast), if the feed carries one.
    pub signal: Option<u8>,
    len: u8,
    buf: [u8; MAX_FRAME_BYTES],
}

impl RawFrame {
    /// A frame of 2, 7 or 14 bytes; any other length is not a frame and gives `None`.
    pub fn new(time_s: f64, bytes: &[u8], signal: Option<u8>) -> Option<Self> {
        if !matches!(bytes.len(), 2 | 7 | 14) {
            return None;
        }
        let mut buf = [0u8; MAX_FRAME_BYTES];
        buf.get_mut(..bytes.len())?.copy_from_slice(bytes);
        Some(Self {
            time_s,
            signal,
            len: bytes.len() as u8,
            buf,
        })
    }

    /// The hot-path constructor: a frame whose `len` bytes (2, 7 or 14) start `buf`, the rest
    /// of `buf` being ignored (zeroed here, so equal frames compare equal). Every move is of
    /// a fixed size: a variable-length copy followed by the wide reads of a `Vec` push stalls
    /// store forwarding and halved Beast framing speed.
    pub(crate) fn from_padded(
        time_s: f64,
        mut buf: [u8; MAX_FRAME_BYTES],
        len: usize,
        signal: Option<u8>,
    ) -> Option<Self> {
        match len {
            2 => buf[2..].fill(0),
            7 => buf[7..].fill(0),
            14 => {}
            _ => return None,
        }
        Some(Self {
            time_s,
            signal,
            len: len as u8,
            buf,
        })
    }

    /// The frame's bytes (2, 7 or 14 of them).
    pub fn bytes(&self) -> &[u8] {
        &self.buf[..usize::from(self.len).min(MAX_FRAME_BYTES)]
    }

    /// Mode S downlink format (first 5 bits); meaningless for a 2-byte Mode A/C frame.
    pub fn df(&self) -> u8 {
        self.buf[0] >> 3
    }

    /// True for a 2-byte Mode A/C reply (Beast frame type '1').
    pub fn is_mode_ac(&self) -> bool {
        self.len == 2
    }
}

/// The on-the-wire or on-disk formats a feed can carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// Beast binary (readsb/dump1090 port 30005): 0x1a escapes, 12 MHz counter, signal byte.
    Beast,
    /// AVR text (port 30002): `*<hex>;` or `@<12 hex counter><hex>;` lines.
    Avr,
    /// `unix_ts,hex` lines.
    Csv,
    /// `ISO-8601-time<whitespace>hex` lines (pyModeS sample data).
    Iso,
    /// JSON lines with `timestamp` (unix s) and `frame` (hex) fields.
    Jsonl,
}

impl std::str::FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "beast" => Ok(Self::Beast),
            "avr" => Ok(Self::Avr),
            "csv" => Ok(Self::Csv),
            "iso" => Ok(Self::Iso),
            "jsonl" => Ok(Self::Jsonl),
            other => Err(format!(
                "unknown format {other:?} (expected beast, avr, csv, iso or jsonl)"
            )),
        }
    }
}

/// What a parser saw, counted: nothing is skipped silently.
#[derive(Clone, Debug, Default, PartialEq, Serialize, utoipa::ToSchema)]
pub struct ParseStats {
    /// Frames handed on.
    pub frames: u64,
    /// Bytes skipped while resynchronising (Beast garbage between frames).
    pub garbage_bytes: u64,
    /// Text lines that were not a frame (bad hex, wrong length, unparsable timestamp).
    pub bad_lines: u64,
    /// Beast frames with an unknown type byte or a bad escape.
    pub bad_frames: u64,
    /// Times the feed clock stepped backwards or jumped and the time base was reset (once
    /// the stream confirmed the step; also counts 48-bit counter wraps).
    pub clock_resets: u64,
    /// Frames whose stamp stepped away from the stream's time and that the following frames
    /// did not confirm (a corrupted stamp): handed on in their place with a time between
    /// their neighbours' instead, so one bad stamp cannot move feed time ([`clock`] has the
    /// rules).
    pub time_outliers: u64,
    /// Frames dropped because their unix timestamp was not finite, negative, or past the year
    /// 2200 ([`clock::MAX_UNIX_S`]).
    pub bad_timestamps: u64,
    /// Bytes of an incomplete frame left at the end of a stream.
    pub truncated_tail_bytes: u64,
    /// Frames that carried no time and were paced at `decode.nominal_rate_hz` (plain AVR
    /// `*hex;`): when they are all of a recording's frames, [`pace`] can learn its real
    /// clock.
    pub paced_frames: u64,
}

impl ParseStats {
    /// Every frame so far was paced (and there was one): a recording with no time of its
    /// own, whose clock [`pace`] may learn.
    pub fn all_paced(&self) -> bool {
        self.frames > 0 && self.paced_frames == self.frames
    }
}

/// An incremental frame parser: what every feed format implements.
pub trait FrameParser: Send {
    /// Parses as many whole frames as `buf` holds into `out` and returns how many bytes of
    /// `buf` were consumed (frames and skipped garbage). Unconsumed bytes are an incomplete
    /// frame: the caller keeps them and passes them again, followed by the next bytes read.
    fn parse(&mut self, buf: &[u8], out: &mut Vec<RawFrame>) -> usize;

    /// The stream ended (or the connection dropped) with `tail` still unconsumed: count it
    /// and forget it. A parser must be usable again after this (a reconnect).
    fn finish(&mut self, tail: &[u8]);

    /// Like [`finish`](Self::finish), for formats whose last record needs no terminator: a
    /// text file's final line without a newline is still a line, and is parsed into `out` if
    /// it is complete (counted as a truncated tail if not). Beast frames carry their own
    /// length, so an unconsumed Beast tail is always incomplete and this is `finish`.
    fn finish_into(&mut self, tail: &[u8], out: &mut Vec<RawFrame>) {
        let _ = out;
        self.finish(tail);
    }

    /// Counters so far.
    fn stats(&self) -> &ParseStats;
}

/// A fresh parser for `format`. `nominal_rate_hz` paces frames of text formats that carry no
/// timestamp (plain `*hex;` AVR): frame n gets feed time n / rate.
pub fn parser_for(format: Format, nominal_rate_hz: f64) -> Box<dyn FrameParser> {
    match format {
        Format::Beast => Box::new(beast::BeastParser::new()),
        other => Box::new(text::TextParser::new(other, nominal_rate_hz)),
    }
}

/// What can go wrong opening or reading a recording (the TCP client never fails: it counts
/// its errors in [`tcp::FeedStatus`] and reconnects).
#[derive(Debug, thiserror::Error)]
pub enum FeedError {
    /// The file could not be opened or read.
    /// (The I/O error is part of the message, not a separate cause: said once.)
    #[error("cannot read {}: {error}", path.display())]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    /// No format was given and [`detect::detect`] recognised none in the file's first bytes.
    #[error(
        "cannot tell the format of {}: not Beast, AVR, CSV, ISO-time or JSON lines (name it)",
        path.display()
    )]
    UnknownFormat { path: PathBuf },
}
