//! De-duplication of one frame heard by several receivers, as aggregators must: an aircraft
//! in range of three feeders arrives three times, and a tracker fed all three would count
//! three reports of one measurement (its covariance shrinking on no new information).
//!
//! A frame is a duplicate when the same bytes came from a *different* receiver within
//! `window_s` of feed time. The same receiver repeating the same bytes is kept: an aircraft
//! flying straight and level sends identical velocity messages, and those are real reports.
//! Feed times must be on one time base across receivers (GNSS-stamped receivers, or one
//! recording); the window is short (0.5 s by default) because duplicates arrive within
//! milliseconds of each other.
//!
//! One [`Dedup`] per partition: every frame of an aircraft passes through its partition's,
//! and the frame's bytes include its address, so the window is per aircraft.

use crate::feed::RawFrame;
use rustc_hash::FxHashMap;

/// Frame length and bytes: the key.
type Key = [u8; 15];

/// Most receiver ids remembered per partition; past it, new ids share one slot (they can
/// still be de-duplicated against the others, never against each other).
const MAX_RECEIVERS: usize = 65_536;

/// The recent frames of one partition.
#[derive(Debug, Default)]
pub struct Dedup {
    window_s: f64,
    seen: FxHashMap<Key, (f64, u32)>,
    receivers: FxHashMap<String, u32>,
    newest_s: f64,
    next_prune_s: f64,
}

impl Dedup {
    /// De-duplicates within `window_s` of feed time; 0 keeps everything.
    pub fn new(window_s: f64) -> Self {
        Self {
            window_s,
            newest_s: f64::NEG_INFINITY,
            next_prune_s: f64::NEG_INFINITY,
            ..Self::default()
        }
    }

    /// A small number for a receiver id.
    pub fn receiver(&mut self, id: &str) -> u32 {
        if let Some(&n) = self.receivers.get(id) {
            return n;
        }
        let n = self.receivers.len().min(MAX_RECEIVERS) as u32;
        if self.receivers.len() < MAX_RECEIVERS {
            self.receivers.insert(id.to_string(), n);
        }
        n
    }

    /// Whether `f` from `receiver` duplicates a frame another receiver sent within the
    /// window. A frame that is not one is remembered.
    pub fn is_duplicate(&mut self, f: &RawFrame, receiver: u32) -> bool {
        if self.window_s <= 0.0 {
            return false;
        }
        let mut key: Key = [0; 15];
        let bytes = f.bytes();
        key[0] = bytes.len() as u8;
        if let Some(dst) = key.get_mut(1..1 + bytes.len()) {
            dst.copy_from_slice(bytes);
        }
        self.newest_s = self.newest_s.max(f.time_s);
        if self.newest_s >= self.next_prune_s {
            let cutoff = self.newest_s - self.window_s;
            self.seen.retain(|_, (t, _)| *t >= cutoff);
            self.next_prune_s = self.newest_s + self.window_s;
        }
        match self.seen.get(&key) {
            Some(&(t, r)) if r != receiver && (f.time_s - t).abs() <= self.window_s => true,
            _ => {
                self.seen.insert(key, (f.time_s, receiver));
                false
            }
        }
    }

    /// Frames remembered now.
    pub fn len(&self) -> usize {
        self.seen.len()
    }

    pub fn is_empty(&self) -> bool {
        self.seen.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(t: f64, last: u8) -> RawFrame {
        let mut b = [
            0x8d, 0x48, 0x40, 0xd6, 0x20, 0x2c, 0xc3, 0x71, 0xc3, 0x2c, 0xe0, 0x57, 0x60, 0,
        ];
        b[13] = last;
        RawFrame::new(t, &b, None).expect("frame")
    }

    #[test]
    fn another_receiver_within_the_window_is_a_duplicate() {
        let mut d = Dedup::new(0.5);
        let (a, b) = (d.receiver("a"), d.receiver("b"));
        assert_ne!(a, b);
        assert_eq!(d.receiver("a"), a);
        assert!(!d.is_duplicate(&f(10.0, 1), a));
        assert!(
            d.is_duplicate(&f(10.01, 1), b),
            "same bytes, other receiver, 10 ms"
        );
        assert!(
            !d.is_duplicate(&f(10.02, 1), a),
            "the same receiver repeating is kept"
        );
        assert!(!d.is_duplicate(&f(10.02, 2), b), "other bytes are kept");
        assert!(
            !d.is_duplicate(&f(11.0, 1), b),
            "past the window: a new report"
        );
    }

    #[test]
    fn the_memory_is_pruned_to_the_window() {
        let mut d = Dedup::new(0.5);
        let a = d.receiver("a");
        for i in 0..10_000u32 {
            let t = f64::from(i) * 0.01;
            assert!(!d.is_duplicate(&f(t, (i % 251) as u8), a));
        }
        // At most ~2 windows of frames (100 per second) are held.
        assert!(d.len() <= 101, "{}", d.len());
    }

    #[test]
    fn a_zero_window_keeps_everything() {
        let mut d = Dedup::new(0.0);
        let (a, b) = (d.receiver("a"), d.receiver("b"));
        assert!(!d.is_duplicate(&f(1.0, 1), a));
        assert!(!d.is_duplicate(&f(1.0, 1), b));
        assert!(d.is_empty());
    }
}
