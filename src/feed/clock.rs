//! Feed time: receiver counters and file timestamps -> monotonic feed seconds.
//!
//! The tracker downstream integrates over `dt_s` between reports, so it needs a time that never
//! runs backwards and never jumps by hours because a receiver restarted. A Beast receiver
//! stamps each frame with a free-running 48-bit counter at 12 MHz (readsb/dump1090 `MODES_
//! CLOCK_FREQ`, also carried by the AVR `@` format); it wraps after 2^48 / 12e6 s = 271 days
//! and restarts at zero when the receiver does. Text recordings carry unix seconds, which are
//! monotonic in every fixture but nothing guarantees it. [`FeedClock`] turns either into feed
//! seconds that continue from the last time whenever the source misbehaves, and counts each
//! rebase in [`ParseStats::clock_resets`](super::ParseStats::clock_resets).

/// Ticks per second of the Beast / AVR-`@` timestamp counter (12 MHz).
pub const COUNTER_HZ: f64 = 12.0e6;

/// The counter is 48 bits wide (6 bytes in a Beast frame, 12 hex digits in AVR `@`).
pub const COUNTER_MODULUS: u64 = 1 << 48;

/// A forward step larger than this is not elapsed time but a new time base (a receiver that
/// restarted, a recording spliced after a gap, a corrupted stamp): one hour. Nothing a tracker
/// holds survives an hour of silence anyway, so treating a longer gap as continuous time loses
/// nothing, while believing a corrupted stamp would leave every later frame hours away.
pub const MAX_FORWARD_STEP_S: f64 = 3600.0;

/// A backward step up to this long is one late frame, not a new time base: the frame gets
/// the last time and the time base stays (rebasing on it would push every later frame
/// forward by its lateness). A receiver that decodes several sample blocks in parallel can
/// emit frames out of order by about a block (tens of ms); one second covers that with
/// margin, while a recording replayed in a loop or a receiver restarted after more than a
/// second steps back further and rebases, so time goes on. (dump1090's late frames, up to a
/// minute, are Mode A/C replies, which never reach the clock: see `BeastParser`.)
pub const MAX_LATE_FRAME_S: f64 = 1.0;

/// [`MAX_FORWARD_STEP_S`] in counter ticks.
const MAX_FORWARD_STEP_TICKS: u64 = (MAX_FORWARD_STEP_S * COUNTER_HZ) as u64;

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

/// Maps a source's clock (12 MHz counter ticks or seconds) to monotonic feed seconds.
///
/// As long as the source behaves, feed time is exactly the source's time (`ticks / 12e6`, or
/// the timestamp itself). A frame up to [`MAX_LATE_FRAME_S`] older than the latest gets the
/// last feed time. A larger step back, a jump forward beyond [`MAX_FORWARD_STEP_S`], or a
/// 48-bit wrap rebases the clock: that frame gets the last feed time (for a wrap, the last
/// time plus the modular elapsed time) and later frames advance from there.
#[derive(Clone, Debug, Default)]
pub struct FeedClock {
    /// Feed time of the latest frame, in seconds; 0 before the first.
    last_s: f64,
    /// Counter value at the current time base and the feed time it maps to.
    base_ticks: u64,
    base_s: f64,
    /// Latest counter value seen (late frames do not lower it), if any.
    last_ticks: Option<u64>,
    /// Offset added to source seconds, and the latest source seconds seen.
    offset_s: f64,
    last_source_s: Option<f64>,
    resets: u64,
}

impl FeedClock {
    /// A clock that has seen nothing yet: the first stamp sets the time base.
    pub fn new() -> Self {
        Self::default()
    }

    /// Feed seconds for a 48-bit 12 MHz counter value.
    ///
    /// A zero counter (readsb sends 0 for frames it did not time, e.g. from an AVR input) or
    /// an MLAT mark is no time: the frame gets the last feed time.
    pub fn at_ticks(&mut self, ticks: u64) -> f64 {
        let ticks = ticks % COUNTER_MODULUS;
        if is_synthetic(ticks) {
            return self.last_s;
        }
        if let Some(last) = self.last_ticks {
            if ticks < last {
                let wrapped = ticks + (COUNTER_MODULUS - last);
                if wrapped <= MAX_FORWARD_STEP_TICKS {
                    // A genuine 48-bit wrap: keep the elapsed time exact.
                    self.rebase_ticks(ticks, self.last_s + wrapped as f64 / COUNTER_HZ);
                } else if last - ticks <= MAX_LATE_FRAME_TICKS {
                    return self.last_s;
                } else {
                    self.rebase_ticks(ticks, self.last_s);
                }
            } else if ticks - last > MAX_FORWARD_STEP_TICKS {
                self.rebase_ticks(ticks, self.last_s);
            }
        }
        self.last_ticks = Some(ticks);
        // `ticks >= base_ticks` holds: the base is only ever set to the current counter.
        let since_base_s = ticks.saturating_sub(self.base_ticks) as f64 / COUNTER_HZ;
        self.advance(self.base_s + since_base_s)
    }

    /// Feed seconds for a source timestamp in seconds (unix time from a recording, or the
    /// nominal pacing of an untimed AVR stream), by the rules of
    /// [`at_ticks`](Self::at_ticks) without the wrap. Non-finite input is the caller's to
    /// reject; given one anyway, it yields the last time.
    pub fn at_seconds(&mut self, source_s: f64) -> f64 {
        if !source_s.is_finite() {
            return self.last_s;
        }
        if let Some(last) = self.last_source_s {
            let step_s = source_s - last;
            if (-MAX_LATE_FRAME_S..0.0).contains(&step_s) {
                return self.last_s;
            }
            if !(0.0..=MAX_FORWARD_STEP_S).contains(&step_s) {
                self.offset_s = self.last_s - source_s;
                self.resets += 1;
            }
        }
        self.last_source_s = Some(source_s);
        self.advance(source_s + self.offset_s)
    }

    /// Feed time of the latest frame (0 before the first).
    pub fn last_s(&self) -> f64 {
        self.last_s
    }

    /// How many times the time base was reset.
    pub fn resets(&self) -> u64 {
        self.resets
    }

    fn rebase_ticks(&mut self, ticks: u64, at_s: f64) {
        self.base_ticks = ticks;
        self.base_s = at_s;
        self.resets += 1;
    }

    /// Records `t_s` as the latest time, never letting it fall below the last one (rounding
    /// in `base + elapsed` after a rebase could otherwise shave off an ulp).
    fn advance(&mut self, t_s: f64) -> f64 {
        let t_s = if t_s >= self.last_s { t_s } else { self.last_s };
        self.last_s = t_s;
        t_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counter_maps_to_seconds_at_12_mhz() {
        let mut c = FeedClock::new();
        // 12,000,000 ticks is one second by definition of the 12 MHz counter.
        assert_eq!(c.at_ticks(12_000_000), 1.0);
        assert_eq!(c.at_ticks(18_000_000), 1.5);
        assert_eq!(c.resets(), 0);
    }

    #[test]
    fn zero_counter_gets_last_time() {
        let mut c = FeedClock::new();
        assert_eq!(c.at_ticks(0), 0.0);
        assert_eq!(c.at_ticks(24_000_000), 2.0);
        assert_eq!(c.at_ticks(0), 2.0);
        assert_eq!(c.at_ticks(36_000_000), 3.0);
        assert_eq!(c.resets(), 0);
    }

    #[test]
    fn receiver_restart_continues_from_last_time() {
        let mut c = FeedClock::new();
        assert_eq!(c.at_ticks(1_200_000_000), 100.0);
        // The receiver restarts: its counter falls back to 1 s.
        assert_eq!(c.at_ticks(12_000_000), 100.0);
        // Half a second of counter later is half a second of feed time later.
        assert_eq!(c.at_ticks(18_000_000), 100.5);
        assert_eq!(c.resets(), 1);
    }

    #[test]
    fn late_frame_keeps_the_time_base() {
        let mut c = FeedClock::new();
        assert_eq!(c.at_ticks(1_200_000_000), 100.0);
        // A frame stamped 0.5 s earlier: last time, no rebase.
        assert_eq!(c.at_ticks(1_194_000_000), 100.0);
        // The next frame is timed from the unchanged base.
        assert_eq!(c.at_ticks(1_212_000_000), 101.0);
        assert_eq!(c.resets(), 0);
    }

    #[test]
    fn mlat_marks_are_not_times() {
        let mut c = FeedClock::new();
        assert_eq!(c.at_ticks(24_000_000), 2.0);
        assert_eq!(c.at_ticks(0xFF00_4D4C_4154), 2.0);
        assert_eq!(c.at_ticks(0xFF00_4D4C_4155), 2.0);
        assert_eq!(c.at_ticks(36_000_000), 3.0);
        assert_eq!(c.resets(), 0);
    }

    #[test]
    fn wrap_keeps_elapsed_time() {
        let mut c = FeedClock::new();
        let near_top = COUNTER_MODULUS - 6_000_000; // 0.5 s before the wrap
        let t0 = c.at_ticks(near_top);
        assert_eq!(t0, near_top as f64 / 12e6);
        // 0.25 s after the wrap: 0.75 s after the previous frame.
        let t1 = c.at_ticks(3_000_000);
        assert!((t1 - t0 - 0.75).abs() < 1e-6, "{}", t1 - t0);
        let t2 = c.at_ticks(15_000_000);
        assert!((t2 - t0 - 1.75).abs() < 1e-6, "{}", t2 - t0);
        assert_eq!(c.resets(), 1);
    }

    #[test]
    fn absurd_forward_jump_rebases() {
        let mut c = FeedClock::new();
        assert_eq!(c.at_ticks(12_000_000), 1.0);
        // Two hours of counter in one step.
        assert_eq!(c.at_ticks(12_000_000 + 7200 * 12_000_000), 1.0);
        assert_eq!(c.at_ticks(12_000_000 + 7201 * 12_000_000), 2.0);
        assert_eq!(c.resets(), 1);
        // Fifty minutes is plausible and is kept.
        assert_eq!(c.at_ticks(12_000_000 + 10_201 * 12_000_000), 3002.0);
        assert_eq!(c.resets(), 1);
    }

    #[test]
    fn seconds_source_is_monotonic() {
        let mut c = FeedClock::new();
        assert_eq!(c.at_seconds(1_000.0), 1_000.0);
        assert_eq!(c.at_seconds(1_001.0), 1_001.0);
        // A late line: last time, same base.
        assert_eq!(c.at_seconds(1_000.25), 1_001.0);
        assert_eq!(c.at_seconds(1_001.5), 1_001.5);
        // Far back: rebase.
        assert_eq!(c.at_seconds(500.0), 1_001.5);
        assert_eq!(c.at_seconds(500.5), 1_002.0);
        assert_eq!(c.at_seconds(f64::NAN), 1_002.0);
        // Far forward: rebase.
        assert_eq!(c.at_seconds(1e12), 1_002.0);
        assert_eq!(c.at_seconds(1e12 + 2.0), 1_004.0);
        assert_eq!(c.resets(), 2);
    }
}
