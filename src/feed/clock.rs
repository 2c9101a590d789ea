//! Feed time: receiver counters and file timestamps -> monotonic feed seconds.
//!
//! The tracker downstream integrates over `dt_s` between reports, so it needs a time that never
//! runs backwards, never jumps by hours because a receiver restarted, and that no single bad
//! stamp can move. A Beast receiver stamps each frame with a free-running 48-bit counter at
//! 12 MHz (readsb/dump1090 `MODES_CLOCK_FREQ`, also carried by the AVR `@` format); it wraps
//! after 2^48 / 12e6 s = 271 days and restarts at zero when the receiver does. Text recordings
//! carry unix seconds, which are monotonic in every fixture but nothing guarantees it.
//!
//! [`FeedClock`] follows the stream's time robustly:
//!
//! - A frame within [`MAX_PLAIN_STEP_S`] after the latest time, or up to [`MAX_LATE_FRAME_S`]
//!   before it, is ordinary: it gets its own time (a late one the latest time).
//! - Any other step (a gap, a receiver restart, a replay looping, a recording spliced, or one
//!   corrupted stamp) is a *candidate* time base that the following frames must confirm: the
//!   frame is held, and so are the frames after it that fit the candidate better than the
//!   current time. Once [`GAP_CONFIRM_FRAMES`] frames (a forward gap of up to
//!   [`MAX_FORWARD_STEP_S`]) or [`REBASE_CONFIRM_FRAMES`] frames (a step back or a longer jump:
//!   a new time base) agree, the step is taken and the held frames are released with their
//!   times: a gap keeps the elapsed time, a new time base continues from the last time.
//! - A frame that fits the current time again refutes the candidate: the held frames were
//!   outliers. Their content is good (CRC-checked), only their stamp is not, so they are
//!   released in their place, halfway between the frames around them (or at the current
//!   time), counted in [`FeedClock::outliers`], and feed time never moved. (Before the stream
//!   has any time there is none to give them: they wait, counted the same, for the stream's
//!   first confirmed time and take it.) A frame far
//!   from both the candidate and the current time while the candidate waits is an outlier
//!   too. The end of the stream confirms nothing: a candidate still waiting then is refuted
//!   (or, if it is the stream's only time, taken).
//! - A unix timestamp that is not finite, negative or past [`MAX_UNIX_S`] (year 2200) is no
//!   time at all: counted in [`FeedClock::bad_timestamps`], and the frame is untimed.
//!
//! No frame is ever dropped: every frame that goes in comes out, in its order, with a time
//! (the fuzz targets `feed_beast` and `feed_lines` check it).
//!
//! Holding costs nothing on the ordinary path (one comparison), and at most
//! [`MAX_HELD_FRAMES`] frames are ever held, in a buffer allocated once.

use super::RawFrame;

/// Ticks per second of the Beast / AVR-`@` timestamp counter (12 MHz).
pub const COUNTER_HZ: f64 = 12.0e6;

/// The counter is 48 bits wide (6 bytes in a Beast frame, 12 hex digits in AVR `@`).
pub const COUNTER_MODULUS: u64 = 1 << 48;

/// A forward step larger than this is not elapsed time but a new time base (a receiver that
/// restarted, a recording spliced after a gap): one hour. Nothing a tracker holds survives an
/// hour of silence anyway, so treating a longer gap as continuous time loses nothing, while
/// believing a corrupted stamp would leave every later frame hours away.
pub const MAX_FORWARD_STEP_S: f64 = 3600.0;

/// A backward step up to this long is one late frame, not a new time base: the frame gets
/// the last time and the time base stays (rebasing on it would push every later frame
/// forward by its lateness). A receiver that decodes several sample blocks in parallel can
/// emit frames out of order by about a block (tens of ms); one second covers that with
/// margin, while a recording replayed in a loop or a receiver restarted after more than a
/// second steps back further and rebases, so time goes on. (dump1090's late frames, up to a
/// minute, are Mode A/C replies, which never reach the clock: see `BeastParser`.)
pub const MAX_LATE_FRAME_S: f64 = 1.0;

/// A forward step up to this long is taken at once: ordinary progress between two frames
/// (a busy feed steps by milliseconds, a single aircraft by a fraction of a second). A longer
/// step waits for the next frame to confirm it, so a stamp off by seconds to an hour cannot
/// move feed time; the same one second as [`MAX_LATE_FRAME_S`], so a frame wrong by less
/// than that in either direction costs at most that much.
pub const MAX_PLAIN_STEP_S: f64 = 1.0;

/// Frames that must agree before a forward gap (up to [`MAX_FORWARD_STEP_S`]) is taken: the
/// frame after the gap and one more. Two stamps agreeing by chance after a corrupted one is
/// beyond rare, and waiting longer would only delay a sparse feed's frames.
pub const GAP_CONFIRM_FRAMES: usize = 2;

/// Frames that must agree before a new time base (a step back past [`MAX_LATE_FRAME_S`], or
/// forward past [`MAX_FORWARD_STEP_S`]) is taken, and before the stream's first time is:
/// such a step moves every later frame, so it takes more than a chance pair to confirm it,
/// while a busy feed delivers four frames in milliseconds.
pub const REBASE_CONFIRM_FRAMES: usize = 4;

/// A frame confirms a candidate when it follows it by up to this (or is at least twice as
/// near it as the current time): a feed's frames follow each other within seconds, so a frame
/// a quarter of an hour from both the candidate and the current time confirms neither.
pub const MAX_CONFIRM_STEP_S: f64 = 60.0;

/// Frames far from both a waiting candidate and the current time that are taken for
/// outliers; one more gives the candidate up (it was not the stream's time either).
pub const MAX_STRAY_FRAMES: usize = 2;

/// Most frames held while a candidate waits: the frames it needs plus untimed frames
/// (Mode A/C, zero counters) that arrive meanwhile and are held to keep the order. Past this,
/// an untimed frame goes out at once with the last time.
pub const MAX_HELD_FRAMES: usize = 32;

/// Latest unix time accepted from a recording, s: 2200-01-01T00:00:00Z. Recordings are of
/// the past or of now; a stamp past this is corrupt, and believing it would put feed time
/// (and, through f64 overflow, every later step) out of reach.
pub const MAX_UNIX_S: f64 = 7_258_118_400.0;

// A candidate is confirmed by frames after its first, and the held buffer has room for them.
const _: () = assert!(
    GAP_CONFIRM_FRAMES >= 2
        && REBASE_CONFIRM_FRAMES >= GAP_CONFIRM_FRAMES
        && REBASE_CONFIRM_FRAMES <= MAX_HELD_FRAMES
);

/// [`MAX_FORWARD_STEP_S`] in counter ticks.
const MAX_FORWARD_STEP_TICKS: u64 = (MAX_FORWARD_STEP_S * COUNTER_HZ) as u64;

/// [`MAX_PLAIN_STEP_S`] in counter ticks.
const MAX_PLAIN_STEP_TICKS: u64 = (MAX_PLAIN_STEP_S * COUNTER_HZ) as u64;

/// [`MAX_LATE_FRAME_S`] in counter ticks.
const MAX_LATE_FRAME_TICKS: u64 = (MAX_LATE_FRAME_S * COUNTER_HZ) as u64;

/// readsb/mlat-client mark frames synthesised from multilateration results (and UAT) with
/// the counter value `FF 00 "MLAT"` (+0..10): not a time (mlat-client
/// `is_synthetic_timestamp`).
const MAGIC_MLAT_TICKS: u64 = 0xFF00_4D4C_4154;

/// True for counter values that carry no time: zero (an untimed source) or the MLAT marks.
fn is_synthetic(ticks: u64) -> bool {
    ticks == 0 || (MAGIC_MLAT_TICKS..=MAGIC_MLAT_TICKS + 10).contains(&ticks)
}

/// A source's stamps, in a form where steps between them are plain differences.
trait Stamp: Copy + std::fmt::Debug {
    /// How a stamp maps to feed seconds.
    type Base: Copy + std::fmt::Debug;
    /// The mapping of the stream's first time base: the source's own seconds.
    const NATURAL: Self::Base;
    /// `to - from`, s.
    fn step_s(from: Self, to: Self) -> f64;
    /// The mapping that puts `at` at feed time `at_s`.
    fn anchor(at: Self, at_s: f64) -> Self::Base;
    /// Feed seconds of `x` under `base`.
    fn time_s(base: Self::Base, x: Self) -> f64;
}

/// Unix seconds (or nominal pacing); mapped by an offset, so an undisturbed stream's feed
/// time is exactly its stamps.
impl Stamp for f64 {
    type Base = f64;
    const NATURAL: f64 = 0.0;
    fn step_s(from: f64, to: f64) -> f64 {
        to - from
    }
    fn anchor(at: f64, at_s: f64) -> f64 {
        at_s - at
    }
    fn time_s(offset_s: f64, x: f64) -> f64 {
        x + offset_s
    }
}

/// Counter ticks unwrapped past the 48-bit wraps (see [`FeedClock::push_ticks`]); mapped by
/// a base tick and its feed time, so the elapsed time is an exact integer until the one
/// division.
impl Stamp for i64 {
    type Base = (i64, f64);
    const NATURAL: (i64, f64) = (0, 0.0);
    fn step_s(from: i64, to: i64) -> f64 {
        to.saturating_sub(from) as f64 / COUNTER_HZ
    }
    fn anchor(at: i64, at_s: f64) -> (i64, f64) {
        (at, at_s)
    }
    fn time_s((base, base_s): (i64, f64), x: i64) -> f64 {
        base_s + x.saturating_sub(base) as f64 / COUNTER_HZ
    }
}

/// What a frame says of a waiting candidate.
enum Verdict {
    /// It follows the candidate: one more frame agrees with it.
    Confirms,
    /// It follows the current time, or the candidate was given up: the candidate's frames
    /// were outliers.
    Refutes,
    /// It follows neither: an outlier itself.
    Stray,
}

/// A step waiting for the stream to confirm it.
#[derive(Clone, Copy, Debug)]
struct Candidate<S> {
    /// Its first stamp (the new time base's origin) and its latest.
    first: S,
    last: S,
    /// Timed frames that agree with it so far, and how many it needs.
    frames: usize,
    needed: usize,
    /// Frames far from both it and the current time while it waited (outliers).
    strays: usize,
}

/// The robust time base of one kind of stamp.
#[derive(Clone, Debug)]
struct Track<S: Stamp> {
    base: S::Base,
    /// Latest stamp taken (late frames do not lower it); `None` before the first time base.
    last: Option<S>,
    cand: Option<Candidate<S>>,
    /// Frames held while `cand` waits, in arrival order, with their stamps (`None`: an
    /// untimed frame, which takes the time of the frame before it).
    held: Vec<(Option<S>, RawFrame)>,
}

impl<S: Stamp> Default for Track<S> {
    fn default() -> Self {
        Self {
            base: S::NATURAL,
            last: None,
            cand: None,
            held: Vec::new(),
        }
    }
}

/// What [`Track`] shares with the clock: the latest feed time and the counters.
#[derive(Clone, Copy, Debug, Default)]
struct Shared {
    last_s: f64,
    resets: u64,
    outliers: u64,
}

impl Shared {
    /// Records `t_s` as the latest time, never letting it fall below the last one (a late
    /// frame, or rounding in `base + elapsed` after a rebase).
    fn advance(&mut self, t_s: f64) -> f64 {
        if t_s > self.last_s {
            self.last_s = t_s;
        }
        self.last_s
    }
}

/// A step is ordinary progress when it is in this window.
fn is_plain(step_s: f64) -> bool {
    (-MAX_LATE_FRAME_S..=MAX_PLAIN_STEP_S).contains(&step_s)
}

/// A step a stream can make between two of its frames at all: late by up to a second, or
/// forward by up to an hour.
fn is_plausible(step_s: f64) -> bool {
    (-MAX_LATE_FRAME_S..=MAX_FORWARD_STEP_S).contains(&step_s)
}

impl<S: Stamp> Track<S> {
    /// Times one frame stamped `x` into `out`, or holds it (see the module documentation).
    fn push(&mut self, x: S, frame: RawFrame, out: &mut Vec<RawFrame>, sh: &mut Shared) {
        if let Some(c) = self.cand.as_mut() {
            let to_cand = S::step_s(c.last, x);
            let verdict = match self.last.map(|l| S::step_s(l, x)) {
                // An ordinary frame of the current time: the candidate was an outlier.
                Some(to_base) if is_plain(to_base) => Verdict::Refutes,
                // Before the stream has a time, any step it could make confirms.
                None if is_plausible(to_cand) => Verdict::Confirms,
                None => Verdict::Refutes,
                // A step the stream could make from the candidate, and a short one (a
                // minute), or at least twice as near the candidate as the current time (a
                // sparse feed's longer gaps).
                Some(to_base)
                    if is_plausible(to_cand)
                        && (to_cand.abs() <= MAX_CONFIRM_STEP_S
                            || to_cand.abs() <= to_base.abs() / 2.0) =>
                {
                    Verdict::Confirms
                }
                // Nearer the current time: the candidate was an outlier.
                Some(to_base) if is_plausible(to_base) && to_base.abs() <= to_cand.abs() => {
                    Verdict::Refutes
                }
                // Far from both: another corrupted stamp while the candidate waits, unless
                // that keeps happening (then the candidate is given up).
                Some(_) if c.strays < MAX_STRAY_FRAMES && self.held.len() < MAX_HELD_FRAMES => {
                    Verdict::Stray
                }
                Some(_) => Verdict::Refutes,
            };
            match verdict {
                Verdict::Confirms => {
                    self.held.push((Some(x), frame));
                    c.frames += 1;
                    if to_cand > 0.0 {
                        c.last = x;
                    }
                    if c.frames >= c.needed {
                        self.commit(out, sh);
                    }
                    return;
                }
                Verdict::Stray => {
                    // An outlier itself: kept in its place (it takes the time of the frame
                    // before it) and judged no further.
                    c.strays += 1;
                    sh.outliers += 1;
                    self.held.push((None, frame));
                    return;
                }
                // Then the frame is judged against the current time alone.
                Verdict::Refutes => {
                    // The outliers were heard between the last frame and this one: when this
                    // one is ordinary, halfway between is their best time (a tracker given
                    // two reports at one instant sees an infinite speed).
                    let next_s = self.last.and_then(|l| {
                        let step_s = S::step_s(l, x);
                        (0.0..=MAX_PLAIN_STEP_S)
                            .contains(&step_s)
                            .then(|| S::time_s(self.base, x))
                    });
                    self.refute(next_s, out, sh);
                }
            }
        }
        let Some(last) = self.last else {
            self.start(x, frame, REBASE_CONFIRM_FRAMES);
            return;
        };
        let step_s = S::step_s(last, x);
        if (0.0..=MAX_PLAIN_STEP_S).contains(&step_s) {
            self.last = Some(x);
            frame_at(frame, sh.advance(S::time_s(self.base, x)), out);
        } else if (-MAX_LATE_FRAME_S..0.0).contains(&step_s) {
            frame_at(frame, sh.last_s, out);
        } else if (0.0..=MAX_FORWARD_STEP_S).contains(&step_s) {
            self.start(x, frame, GAP_CONFIRM_FRAMES);
        } else {
            self.start(x, frame, REBASE_CONFIRM_FRAMES);
        }
    }

    /// A frame without a time of its own: the last time, or held behind a waiting candidate
    /// so the order of frames is kept. When the buffer is full, the candidate is given up
    /// (its frames are outliers, released at the current time) so the order still holds.
    fn push_untimed(&mut self, frame: RawFrame, out: &mut Vec<RawFrame>, sh: &mut Shared) {
        if self.cand.is_some() {
            if self.held.len() < MAX_HELD_FRAMES {
                self.held.push((None, frame));
                return;
            }
            if let Some(c) = self.cand.take() {
                sh.outliers += c.frames as u64;
            }
            for (_, held) in self.held.drain(..) {
                frame_at(held, sh.last_s, out);
            }
        }
        frame_at(frame, sh.last_s, out);
    }

    fn start(&mut self, x: S, frame: RawFrame, needed: usize) {
        // Allocated once: `clear` keeps the capacity.
        if self.held.capacity() < MAX_HELD_FRAMES {
            self.held.reserve_exact(MAX_HELD_FRAMES);
        }
        self.held.push((Some(x), frame));
        self.cand = Some(Candidate {
            first: x,
            last: x,
            frames: 1,
            needed,
            strays: 0,
        });
    }

    /// The stream confirmed the candidate: take its time base and release its frames.
    fn commit(&mut self, out: &mut Vec<RawFrame>, sh: &mut Shared) {
        let Some(c) = self.cand.take() else {
            return;
        };
        match self.last {
            // The stream's first time: its own.
            None => self.base = S::NATURAL,
            // A forward gap: the elapsed time is kept, the base stays.
            Some(l) if (0.0..=MAX_FORWARD_STEP_S).contains(&S::step_s(l, c.first)) => {}
            // A new time base: it continues from the last time.
            Some(_) => {
                self.base = S::anchor(c.first, sh.last_s);
                sh.resets += 1;
            }
        }
        // Outliers held before the stream had a time (see `refute`) take its first time.
        let mut lead_s = self.last.is_none().then(|| S::time_s(self.base, c.first));
        self.last = Some(c.last);
        for (stamp, frame) in self.held.drain(..) {
            let t_s = match (stamp, lead_s) {
                (Some(x), _) => {
                    lead_s = None;
                    sh.advance(S::time_s(self.base, x))
                }
                (None, Some(first_s)) => sh.advance(first_s),
                (None, None) => sh.last_s,
            };
            frame_at(frame, t_s, out);
        }
    }

    /// The stream did not confirm the candidate: its frames were outliers. Their content is
    /// good, so they are handed on in their place: halfway to `next_s` (the time of the
    /// ordinary frame that refuted them, when there is one) or at the current time. If the
    /// stream has no time yet, there is none to give them: they stay held, untimed, in front
    /// of the next candidate, and take the stream's first time when one is confirmed (or the
    /// current time, should they fill the buffer first).
    fn refute(&mut self, next_s: Option<f64>, out: &mut Vec<RawFrame>, sh: &mut Shared) {
        let Some(c) = self.cand.take() else {
            return;
        };
        sh.outliers += c.frames as u64;
        if self.last.is_none() && self.held.len() + REBASE_CONFIRM_FRAMES < MAX_HELD_FRAMES {
            for (stamp, _) in &mut self.held {
                *stamp = None;
            }
            return;
        }
        let t_s = match next_s {
            Some(next_s) if next_s > sh.last_s => sh.last_s + 0.5 * (next_s - sh.last_s),
            _ => sh.last_s,
        };
        for (_, frame) in self.held.drain(..) {
            frame_at(frame, sh.advance(t_s), out);
        }
    }

    /// The stream ended: nothing more will confirm a waiting candidate. It is refuted, unless
    /// it is the stream's only time (a stream of fewer frames than the confirmation needs).
    fn flush(&mut self, out: &mut Vec<RawFrame>, sh: &mut Shared) {
        if self.last.is_none() {
            self.commit(out, sh);
        } else {
            self.refute(None, out, sh);
        }
    }
}

/// Hands on `frame` at feed time `t_s`.
fn frame_at(mut frame: RawFrame, t_s: f64, out: &mut Vec<RawFrame>) {
    frame.time_s = t_s;
    out.push(frame);
}

/// Maps a source's clock (12 MHz counter ticks or unix seconds) to monotonic feed seconds,
/// robustly: see the module documentation.
///
/// Frames go in with [`push_ticks`](Self::push_ticks), [`push_seconds`](Self::push_seconds),
/// [`push_paced`](Self::push_paced) or [`push_untimed`](Self::push_untimed) and come out,
/// timed, in `out`: at once on the ordinary path, a few frames later after a step the stream
/// has to confirm. [`flush`](Self::flush) at the end of a stream releases what is held.
#[derive(Clone, Debug, Default)]
pub struct FeedClock {
    sh: Shared,
    ticks: Track<i64>,
    seconds: Track<f64>,
    bad_timestamps: u64,
}

impl FeedClock {
    /// A clock that has seen nothing yet: the first stamps the stream confirms set the time.
    pub fn new() -> Self {
        Self::default()
    }

    /// Times a frame stamped with a 48-bit 12 MHz counter value into `out` (now or later).
    ///
    /// A zero counter (readsb sends 0 for frames it did not time, e.g. from an AVR input) or
    /// an MLAT mark is no time: the frame is untimed. The counter is unwrapped against the
    /// latest confirmed stamp, so a 48-bit wrap (a step forward modulo 2^48 of up to
    /// [`MAX_FORWARD_STEP_S`]) is elapsed time like any other, counted in
    /// [`resets`](Self::resets) as the wrap it is.
    #[inline]
    pub fn push_ticks(&mut self, ticks: u64, frame: RawFrame, out: &mut Vec<RawFrame>) {
        match self.ordinary_ticks(ticks) {
            Some(t_s) => frame_at(frame, t_s, out),
            None => self.push_ticks_judged(ticks, frame, out),
        }
    }

    /// The time of a frame stamped `ticks` if it is an ordinary one, as nearly every frame
    /// is (a small step forward, no wrap, nothing held), taken as
    /// [`push_ticks`](Self::push_ticks) would take it, in fewer steps; `None` for anything
    /// else, which then goes to `push_ticks`. The per-frame path of a Beast feed: a caller
    /// that builds its frame only once it has the time writes it straight into place (a frame
    /// built, then given its time and copied, costs a store-forwarding stall per frame).
    #[inline]
    pub fn ordinary_ticks(&mut self, ticks: u64) -> Option<f64> {
        let last = self.ticks.last?;
        if self.ticks.cand.is_some() || is_synthetic(ticks) {
            return None;
        }
        let step = ticks.checked_sub(last.rem_euclid(COUNTER_MODULUS as i64) as u64)?;
        if step > MAX_PLAIN_STEP_TICKS {
            return None;
        }
        // Cannot overflow: `last` is within a few 2^48 wraps of zero and `step` under 2^24.
        let x = last.wrapping_add(step as i64);
        self.ticks.last = Some(x);
        let (base, base_s) = self.ticks.base;
        Some(
            self.sh
                .advance(base_s + x.wrapping_sub(base) as f64 / COUNTER_HZ),
        )
    }

    /// [`push_ticks`](Self::push_ticks) for any frame.
    #[inline(never)]
    fn push_ticks_judged(&mut self, ticks: u64, frame: RawFrame, out: &mut Vec<RawFrame>) {
        let ticks = ticks % COUNTER_MODULUS;
        if is_synthetic(ticks) {
            self.push_untimed(frame, out);
            return;
        }
        let epoch_before = self
            .ticks
            .last
            .map(|l| l.div_euclid(COUNTER_MODULUS as i64));
        let x = self.unwrap_ticks(ticks);
        self.ticks.push(x, frame, out, &mut self.sh);
        let epoch_after = self
            .ticks
            .last
            .map(|l| l.div_euclid(COUNTER_MODULUS as i64));
        if let (Some(before), Some(after)) = (epoch_before, epoch_after) {
            if after > before {
                self.sh.resets += 1;
            }
        }
    }

    /// Times a frame stamped in unix seconds (a recording's timestamp) into `out` (now or
    /// later). A stamp that is not finite, is negative or is past [`MAX_UNIX_S`] is no time:
    /// counted in [`bad_timestamps`](Self::bad_timestamps), and the frame (its content is
    /// good) goes on untimed.
    pub fn push_seconds(&mut self, source_s: f64, frame: RawFrame, out: &mut Vec<RawFrame>) {
        if !(0.0..=MAX_UNIX_S).contains(&source_s) {
            self.bad_timestamps += 1;
            self.push_untimed(frame, out);
            return;
        }
        self.seconds.push(source_s, frame, out, &mut self.sh);
    }

    /// Times a frame of an untimed stream paced at a nominal rate (`pace_s` = n / rate): at
    /// once, at the pace, never below the last time. The pace is ours, not a stamp that can
    /// be corrupt, so nothing waits for confirmation (while stamped frames of the same
    /// stream wait, it takes its place behind them, as an untimed frame).
    pub fn push_paced(&mut self, pace_s: f64, frame: RawFrame, out: &mut Vec<RawFrame>) {
        if self.ticks.cand.is_some() || self.seconds.cand.is_some() {
            self.push_untimed(frame, out);
        } else {
            frame_at(frame, self.sh.advance(pace_s), out);
        }
    }

    /// Times a frame that carries no time (a Mode A/C reply, a zero counter): the last feed
    /// time, after any frame held before it.
    pub fn push_untimed(&mut self, frame: RawFrame, out: &mut Vec<RawFrame>) {
        if self.ticks.cand.is_some() {
            self.ticks.push_untimed(frame, out, &mut self.sh);
        } else {
            self.seconds.push_untimed(frame, out, &mut self.sh);
        }
    }

    /// The stream ended (a file's end, a dropped connection): releases the held frames (see
    /// [`Track::flush`]). The clock goes on with the next frames.
    pub fn flush(&mut self, out: &mut Vec<RawFrame>) {
        self.ticks.flush(out, &mut self.sh);
        self.seconds.flush(out, &mut self.sh);
    }

    /// Feed seconds for one counter value with no frame to hold: the time the clock has
    /// after it (the current time while a step waits for confirmation). For tests and
    /// one-off stamps; parsers use [`push_ticks`](Self::push_ticks).
    pub fn at_ticks(&mut self, ticks: u64) -> f64 {
        let mut sink = Vec::new();
        if let Some(probe) = RawFrame::new(0.0, &[0, 0], None) {
            self.push_ticks(ticks, probe, &mut sink);
        }
        self.sh.last_s
    }

    /// [`at_ticks`](Self::at_ticks) for unix seconds.
    pub fn at_seconds(&mut self, source_s: f64) -> f64 {
        let mut sink = Vec::new();
        if let Some(probe) = RawFrame::new(0.0, &[0, 0], None) {
            self.push_seconds(source_s, probe, &mut sink);
        }
        self.sh.last_s
    }

    /// Feed time of the latest frame handed on (0 before the first).
    pub fn last_s(&self) -> f64 {
        self.sh.last_s
    }

    /// How many times the time base was reset (a confirmed step back or jump past an hour,
    /// or a 48-bit wrap).
    pub fn resets(&self) -> u64 {
        self.sh.resets
    }

    /// Frames whose stamp the stream did not confirm: handed on with the current time (or,
    /// before the stream had one, with its first time).
    pub fn outliers(&self) -> u64 {
        self.sh.outliers
    }

    /// Frames whose unix stamp was not finite, negative or past [`MAX_UNIX_S`]: handed on
    /// untimed.
    pub fn bad_timestamps(&self) -> u64 {
        self.bad_timestamps
    }

    /// `ticks` (48 bits) unwrapped next to the latest confirmed stamp: the nearest value
    /// congruent modulo 2^48 by the rules of a step (forward up to an hour, which covers a
    /// wrap; any step back without a wrap, a receiver restart; back across a wrap only as a
    /// late frame; otherwise a jump forward).
    fn unwrap_ticks(&self, ticks: u64) -> i64 {
        let Some(last) = self.ticks.last else {
            return ticks as i64;
        };
        let modulus = COUNTER_MODULUS as i64;
        let last_mod = last.rem_euclid(modulus) as u64;
        let forward = ticks.wrapping_sub(last_mod) % COUNTER_MODULUS;
        let back = (COUNTER_MODULUS - forward) % COUNTER_MODULUS;
        if forward <= MAX_FORWARD_STEP_TICKS {
            last.saturating_add(forward as i64)
        } else if ticks < last_mod || back <= MAX_LATE_FRAME_TICKS {
            last.saturating_sub(back as i64)
        } else {
            last.saturating_add(forward as i64)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A clock and what came out of it, one frame per stamp; the frames' first byte numbers
    /// them so the tests can see which frame got which time.
    struct Run {
        clock: FeedClock,
        out: Vec<RawFrame>,
        n: u8,
    }

    impl Run {
        fn new() -> Self {
            Self {
                clock: FeedClock::new(),
                out: Vec::new(),
                n: 0,
            }
        }
        fn frame(&mut self) -> RawFrame {
            self.n += 1;
            RawFrame::new(0.0, &[self.n, 0], None).unwrap()
        }
        fn ticks(&mut self, t: u64) -> &mut Self {
            let f = self.frame();
            self.clock.push_ticks(t, f, &mut self.out);
            self
        }
        fn secs(&mut self, t: f64) -> &mut Self {
            let f = self.frame();
            self.clock.push_seconds(t, f, &mut self.out);
            self
        }
        fn untimed(&mut self) -> &mut Self {
            let f = self.frame();
            self.clock.push_untimed(f, &mut self.out);
            self
        }
        fn flush(&mut self) -> &mut Self {
            self.clock.flush(&mut self.out);
            self
        }
        /// (frame number, time) of everything out so far.
        fn got(&self) -> Vec<(u8, f64)> {
            self.out.iter().map(|f| (f.bytes()[0], f.time_s)).collect()
        }
        fn times(&self) -> Vec<f64> {
            self.out.iter().map(|f| f.time_s).collect()
        }
    }

    const S: u64 = 12_000_000; // ticks per second

    #[test]
    fn counter_maps_to_seconds_at_12_mhz() {
        let mut r = Run::new();
        // 12,000,000 ticks is one second by definition of the 12 MHz counter. The first time
        // waits for four frames to agree.
        r.ticks(S).ticks(S * 3 / 2).ticks(2 * S);
        assert!(r.out.is_empty());
        r.ticks(5 * S / 2).ticks(3 * S);
        assert_eq!(r.times(), [1.0, 1.5, 2.0, 2.5, 3.0]);
        assert_eq!((r.clock.resets(), r.clock.outliers()), (0, 0));
    }

    #[test]
    fn short_stream_is_released_at_its_end() {
        let mut r = Run::new();
        r.ticks(S).ticks(S * 3 / 2).flush();
        assert_eq!(r.times(), [1.0, 1.5]);
    }

    #[test]
    fn zero_counter_and_mlat_marks_get_last_time_in_order() {
        let mut r = Run::new();
        // Held behind the first (unconfirmed) frames, untimed frames keep their place.
        r.ticks(2 * S).untimed().ticks(0).ticks(0xFF00_4D4C_4154);
        r.ticks(0xFF00_4D4C_4155)
            .ticks(3 * S)
            .ticks(4 * S)
            .ticks(5 * S);
        let got = r.got();
        assert_eq!(
            got,
            [
                (1, 2.0),
                (2, 2.0),
                (3, 2.0),
                (4, 2.0),
                (5, 2.0),
                (6, 3.0),
                (7, 4.0),
                (8, 5.0)
            ]
        );
        r.ticks(0).ticks(6 * S);
        assert_eq!(&r.times()[8..], [5.0, 6.0]);
        assert_eq!(r.clock.resets(), 0);
    }

    /// Four frames a second apart from `start_s` (confirmed, released).
    fn started(start_s: u64) -> Run {
        let mut r = Run::new();
        for i in 0..4 {
            r.ticks((start_s + i) * S);
        }
        r
    }

    #[test]
    fn receiver_restart_continues_from_last_time() {
        let mut r = started(97);
        assert_eq!(r.clock.last_s(), 100.0);
        // The receiver restarts: its counter falls back to 1 s. Held until four frames
        // agree, then the first gets the last time and the others follow by the counter.
        r.ticks(S).ticks(S * 3 / 2).ticks(2 * S);
        assert_eq!(r.out.len(), 4);
        r.ticks(S * 5 / 2).ticks(3 * S);
        assert_eq!(&r.times()[4..], [100.0, 100.5, 101.0, 101.5, 102.0]);
        assert_eq!((r.clock.resets(), r.clock.outliers()), (1, 0));
    }

    #[test]
    fn late_frame_keeps_the_time_base() {
        let mut r = started(97);
        // A frame stamped 0.5 s earlier: last time, no rebase.
        r.ticks(99 * S + S / 2);
        // The next frame is timed from the unchanged base.
        r.ticks(101 * S);
        assert_eq!(&r.times()[4..], [100.0, 101.0]);
        assert_eq!(r.clock.resets(), 0);
    }

    #[test]
    fn one_stamp_off_by_half_an_hour_moves_nothing() {
        for off_s in [1_800i64, -1_800, 3, -3, 7_200, -90_000] {
            let mut r = started(100_000);
            let bad = (100_003 + off_s) as u64 * S + S / 4;
            r.ticks(bad).ticks(100_003 * S + S / 2).ticks(100_004 * S);
            // The outlier keeps its place, halfway between its neighbours; the stream goes
            // on.
            assert_eq!(
                &r.got()[4..],
                [(5, 100_003.25), (6, 100_003.5), (7, 100_004.0)],
                "offset {off_s}"
            );
            assert_eq!((r.clock.resets(), r.clock.outliers()), (0, 1));
        }
    }

    #[test]
    fn outlier_while_a_gap_waits_is_an_outlier() {
        // A sparse stretch of a real flight (afr34zg): a genuine 1.75 s gap waits for its
        // confirmation when a frame stamped half an hour late arrives; the gap is still
        // confirmed by the next frame, and the late stamp is an outlier in its place.
        let mut r = Run::new();
        r.secs(230.0).secs(231.0).secs(232.0).secs(234.744);
        r.secs(236.492).secs(2_080.918).secs(236.984).secs(239.769);
        assert_eq!(&r.got()[4..], [(5, 236.492), (6, 236.492), (7, 236.984)],);
        assert_eq!((r.clock.resets(), r.clock.outliers()), (0, 1));
        // A gap waits; two strays are outliers, a third gives the gap up (an outlier too,
        // like the strays at the current time), and is judged on its own: refuted by the next
        // ordinary frame, halfway to which it goes.
        r.secs(241.0).secs(260.0);
        r.secs(3_000.0).secs(3_100.0).secs(3_200.0).secs(242.0);
        assert_eq!(r.clock.outliers(), 5);
        assert_eq!(r.out.len(), 14);
        assert_eq!(&r.times()[9..], [241.0, 241.0, 241.0, 241.5, 242.0]);
    }

    #[test]
    fn outlier_at_the_start_takes_the_first_time() {
        let mut r = Run::new();
        r.ticks(5_000 * S);
        for i in 0..4 {
            r.ticks((10 + i) * S);
        }
        assert_eq!(
            r.got(),
            [(1, 10.0), (2, 10.0), (3, 11.0), (4, 12.0), (5, 13.0)]
        );
        assert_eq!((r.clock.resets(), r.clock.outliers()), (0, 1));
    }

    /// Fuzz finding (targets `feed_beast`, `feed_lines`): a stream whose stamps never agree
    /// lost the frames held before it had a time (uncounted when untimed frames were among
    /// them). Every frame now comes out, in order, however the stamps go.
    #[test]
    fn random_stamps_lose_no_frame() {
        let mut r = Run::new();
        // A xorshift sequence of stamps all over the 48-bit range, with untimed frames mixed
        // in: nothing confirms anything for long.
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for i in 0..200u32 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            if i % 5 == 3 {
                r.untimed();
            } else {
                r.ticks(x % COUNTER_MODULUS);
            }
        }
        r.flush();
        let numbers: Vec<u8> = r.got().iter().map(|&(n, _)| n).collect();
        let want: Vec<u8> = (1..=200u32).map(|n| n as u8).collect();
        assert_eq!(numbers, want, "every frame, in order");
        assert!(r.times().windows(2).all(|w| w[0] <= w[1]));
        assert!(r.clock.outliers() > 0);

        // Untimed frames past the buffer's room while the first time waits: the wait is
        // given up rather than the order.
        let mut r = Run::new();
        r.ticks(5 * S);
        for _ in 0..MAX_HELD_FRAMES + 3 {
            r.untimed();
        }
        r.ticks(6 * S).flush();
        let numbers: Vec<u8> = r.got().iter().map(|&(n, _)| n).collect();
        let want: Vec<u8> = (1..=(MAX_HELD_FRAMES as u8 + 5)).collect();
        assert_eq!(numbers, want);
    }

    #[test]
    fn outlier_at_the_end_is_not_taken() {
        let mut r = started(10);
        r.ticks(3_000 * S).flush();
        assert_eq!(&r.got()[4..], [(5, 13.0)]);
        assert_eq!(r.clock.outliers(), 1);
    }

    #[test]
    fn wrap_keeps_elapsed_time() {
        let mut r = Run::new();
        let near_top = COUNTER_MODULUS - 6_000_000; // 0.5 s before the wrap
        for i in 0..4 {
            r.ticks(near_top - (3 - i) * S / 10);
        }
        let t0 = r.clock.last_s();
        assert_eq!(t0, near_top as f64 / 12e6);
        // 0.25 s after the wrap: 0.75 s after the previous frame.
        let t1 = r.ticks(3_000_000).clock.last_s();
        assert!((t1 - t0 - 0.75).abs() < 1e-6, "{}", t1 - t0);
        // A late frame from before the wrap is late, not a jump.
        r.ticks(COUNTER_MODULUS - 1_000);
        assert_eq!(r.clock.last_s(), t1);
        let t2 = r.ticks(15_000_000).clock.last_s();
        assert!((t2 - t0 - 1.75).abs() < 1e-6, "{}", t2 - t0);
        assert_eq!(r.out.len(), 7);
        assert_eq!((r.clock.resets(), r.clock.outliers()), (1, 0));
    }

    #[test]
    fn gap_is_taken_once_confirmed_and_keeps_elapsed_time() {
        let mut r = started(1);
        // Fifty minutes of silence is plausible: confirmed by the next frame, kept.
        r.ticks(3_004 * S);
        assert_eq!(r.out.len(), 4);
        r.ticks(3_005 * S);
        assert_eq!(&r.times()[4..], [3_004.0, 3_005.0]);
        assert_eq!(r.clock.resets(), 0);
        // A sparse feed (a frame every 2 s) waits one frame each time, and keeps its times.
        for i in 1..=5 {
            r.ticks((3_005 + 2 * i) * S);
        }
        assert_eq!(&r.times()[6..], [3_007.0, 3_009.0, 3_011.0, 3_013.0]);
        assert_eq!(r.clock.outliers(), 0);
    }

    #[test]
    fn absurd_forward_jump_rebases_once_confirmed() {
        let mut r = started(1);
        // Two hours of counter in one step, confirmed by three more frames.
        for i in 0..4 {
            r.ticks((7_204 + i) * S);
        }
        assert_eq!(&r.times()[4..], [4.0, 5.0, 6.0, 7.0]);
        assert_eq!(r.clock.resets(), 1);
    }

    #[test]
    fn seconds_source_is_monotonic() {
        let mut r = Run::new();
        r.secs(1_000.0).secs(1_000.5).secs(1_000.75).secs(1_001.0);
        // A late line: last time, same base.
        r.secs(1_000.25).secs(1_001.5);
        assert_eq!(
            r.times(),
            [1_000.0, 1_000.5, 1_000.75, 1_001.0, 1_001.0, 1_001.5]
        );
        // Far back, confirmed: rebase.
        r.secs(500.0).secs(500.5).secs(500.75).secs(501.0);
        assert_eq!(&r.times()[6..], [1_001.5, 1_002.0, 1_002.25, 1_002.5]);
        for bad in [
            f64::NAN,
            f64::INFINITY,
            -1.0,
            1e308,
            -1e308,
            MAX_UNIX_S * 1.01,
        ] {
            r.secs(bad);
        }
        // Not times at all: counted, and the frames go on untimed (the last time).
        assert_eq!(&r.times()[10..], [1_002.5; 6]);
        assert_eq!(r.clock.bad_timestamps(), 6);
        // Far forward, confirmed: rebase.
        r.secs(1e9).secs(1e9 + 1.0).secs(1e9 + 1.5).secs(1e9 + 2.0);
        assert_eq!(&r.times()[16..], [1_002.5, 1_003.5, 1_004.0, 1_004.5]);
        assert_eq!((r.clock.resets(), r.clock.outliers()), (2, 0));
    }

    #[test]
    fn at_seconds_gives_the_clock_time() {
        let mut c = FeedClock::new();
        for t in [10.0, 10.5, 11.0] {
            assert_eq!(c.at_seconds(t), 0.0);
        }
        assert_eq!(c.at_seconds(11.5), 11.5);
        assert_eq!(c.at_seconds(f64::NAN), 11.5);
        assert_eq!(c.at_seconds(12.0), 12.0);
    }
}
