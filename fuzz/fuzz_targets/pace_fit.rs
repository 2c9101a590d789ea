//! The learned clock of an untimed recording (`src/feed/pace.rs`) on arbitrary intervals.
//!
//! Input: 16 bytes of start and end (two little-endian f64; the span is cut to 2,000 s so
//! that each run stays fast: the knot cap has its own unit test), then 32 bytes per interval
//! (a, b, real seconds, sigma). Checks: no panic; a map, when there is one, gives finite
//! times that never run backwards and starts at the start.
#![no_main]

use adsb_tracker::feed::pace::{Interval, PaceMap};
use libfuzzer_sys::fuzz_target;

fn f64_at(data: &[u8], i: usize) -> Option<f64> {
    let bytes: [u8; 8] = data.get(i * 8..i * 8 + 8)?.try_into().ok()?;
    Some(f64::from_le_bytes(bytes))
}

fuzz_target!(|data: &[u8]| {
    let (Some(start), Some(end)) = (f64_at(data, 0), f64_at(data, 1)) else {
        return;
    };
    if !(start.is_finite() && end.is_finite()) || start.abs() > 1e9 {
        return;
    }
    let end = end.clamp(start, start + 2000.0);
    let obs: Vec<Interval> = data
        .get(16..)
        .unwrap_or(&[])
        .chunks_exact(32)
        .filter_map(|c| {
            Some(Interval {
                a_s: f64_at(c, 0)?,
                b_s: f64_at(c, 1)?,
                real_s: f64_at(c, 2)?,
                sigma_s: f64_at(c, 3)?,
            })
        })
        .collect();
    let Some(map) = PaceMap::fit(&obs, start, end) else {
        return;
    };
    assert!((map.real_s(start) - start).abs() <= 1e-6 * (1.0 + start.abs()));
    let mut last = f64::NEG_INFINITY;
    for k in 0..=200 {
        let s = start + (end - start) * f64::from(k) / 200.0;
        let t = map.real_s(s);
        assert!(t.is_finite(), "{s} -> {t}");
        assert!(t >= last, "{s} -> {t} after {last}");
        last = t;
    }
});
