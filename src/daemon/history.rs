//! Each aircraft's recent trail: the estimated positions of the last `history.window_minutes`,
//! at most `history.max_points` of them, kept beside its published snapshot and served by
//! `GET /api/v1/tracks/{icao}/history`.
//!
//! Memory per aircraft is the scarce resource at fleet scale, so a point is 16 bytes: time
//! as milliseconds after the trail's base time (`u32`), latitude and longitude in 1e-7
//! degrees (`i32`, about 1 cm), altitude as `f32` metres (about 1 mm at airliner heights).
//! Points come at most every `window / max_points` seconds of feed time (decimation by time),
//! and the ring's storage grows with the points up to `max_points`, never past it.

use crate::config::HistoryConfig;
use serde::Serialize;
use std::collections::VecDeque;

/// One point as served: feed time, s; position, degrees; altitude, m.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct TrailPoint {
    pub t: f64,
    pub lat: f64,
    pub lon: f64,
    pub alt_m: f64,
}

/// One point as stored (16 bytes).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Stored {
    /// Milliseconds after [`Trail::base_t_s`].
    dt_ms: u32,
    lat_e7: i32,
    lon_e7: i32,
    alt_m: f32,
}

/// Resolution of the stored times, s.
const TIME_RESOLUTION_S: f64 = 1e-3;

/// Degrees to the stored units (1e-7 degree).
const E7: f64 = 1e7;

/// Largest time offset stored before the base moves up, ms (a trail older than 46 days
/// has long lost its old points; the margin below u32::MAX keeps the arithmetic exact).
const MAX_DT_MS: f64 = 4.0e9;

/// An aircraft's trail: a ring of at most `max_points` points, oldest first.
#[derive(Debug, Default)]
pub struct Trail {
    /// Feed time the stored offsets count from, s.
    base_t_s: f64,
    points: VecDeque<Stored>,
}

impl Trail {
    /// Adds the estimate at feed time `t_s` if it is at least `min_interval_s` after the
    /// newest point (else nothing), and drops what falls out of the window or past
    /// `max_points`. A time before the newest point (a replay looped onto the same
    /// aircraft) starts the trail afresh. Non-finite values are never stored.
    pub fn push(&mut self, cfg: &HistoryConfig, t_s: f64, lat: f64, lon: f64, alt_m: f64) {
        if cfg.max_points == 0
            || !(t_s.is_finite() && lat.is_finite() && lon.is_finite() && alt_m.is_finite())
        {
            return;
        }
        if let Some(last_t) = self.last_t_s() {
            // (Stored times are rounded to the millisecond: the same estimate published
            // again, at the same time, is no step back.)
            if t_s < last_t - TIME_RESOLUTION_S {
                self.points.clear();
            } else if t_s - last_t < cfg.min_interval_s() {
                return;
            }
        }
        let cutoff = t_s - cfg.window_s();
        while self
            .points
            .front()
            .is_some_and(|p| self.time_of(p) < cutoff)
        {
            self.points.pop_front();
        }
        while self.points.len() >= cfg.max_points {
            self.points.pop_front();
        }
        if self.points.is_empty() {
            self.base_t_s = t_s;
        } else if (t_s - self.base_t_s) * 1e3 > MAX_DT_MS {
            // The points left are within the window (a day at most) of t_s.
            self.rebase();
        }
        if self.points.len() == self.points.capacity() {
            // Double as a Vec would, but never past max_points.
            let want = (self.points.capacity() * 2).clamp(4, cfg.max_points);
            self.points
                .reserve_exact(want.saturating_sub(self.points.len()));
        }
        self.points.push_back(Stored {
            dt_ms: ((t_s - self.base_t_s) * 1e3).round().clamp(0.0, MAX_DT_MS) as u32,
            lat_e7: (lat * E7).round() as i32,
            lon_e7: (lon * E7).round() as i32,
            alt_m: alt_m as f32,
        });
    }

    /// Feed time of the newest point, s.
    pub fn last_t_s(&self) -> Option<f64> {
        self.points.back().map(|p| self.time_of(p))
    }

    /// True when a point at `t_s` would be stored (so the caller need not compute it).
    pub fn wants(&self, cfg: &HistoryConfig, t_s: f64) -> bool {
        cfg.max_points > 0
            && self.last_t_s().is_none_or(|last| {
                t_s < last - TIME_RESOLUTION_S || t_s - last >= cfg.min_interval_s()
            })
    }

    /// The points, oldest first.
    pub fn points(&self) -> Vec<TrailPoint> {
        self.points
            .iter()
            .map(|p| TrailPoint {
                t: self.time_of(p),
                lat: f64::from(p.lat_e7) / E7,
                lon: f64::from(p.lon_e7) / E7,
                alt_m: f64::from(p.alt_m),
            })
            .collect()
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Bytes held by the ring's storage.
    pub fn heap_bytes(&self) -> usize {
        self.points.capacity() * std::mem::size_of::<Stored>()
    }

    fn time_of(&self, p: &Stored) -> f64 {
        self.base_t_s + f64::from(p.dt_ms) / 1e3
    }

    /// Moves the base time to the oldest point's.
    fn rebase(&mut self) {
        let Some(first) = self.points.front().map(|p| p.dt_ms) else {
            return;
        };
        for p in self.points.iter_mut() {
            p.dt_ms -= first;
        }
        self.base_t_s += f64::from(first) / 1e3;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(window_minutes: f64, max_points: usize) -> HistoryConfig {
        HistoryConfig {
            window_minutes,
            max_points,
        }
    }

    #[test]
    fn a_point_is_sixteen_bytes() {
        assert_eq!(std::mem::size_of::<Stored>(), 16);
    }

    #[test]
    fn decimates_bounds_and_keeps_time_order() {
        // 10 min, 600 points: at least 1 s apart. 30 minutes of estimates at 5 Hz.
        let c = cfg(10.0, 600);
        let mut trail = Trail::default();
        let t0 = 1.7e9;
        for i in 0..(30 * 60 * 5) {
            let t = t0 + f64::from(i) * 0.2;
            trail.push(&c, t, 33.9 + 1e-5 * f64::from(i), -118.4, 3000.0);
        }
        let p = trail.points();
        assert!(p.len() <= 600, "{}", p.len());
        assert!(p.len() >= 599, "{}", p.len());
        assert!(p.windows(2).all(|w| w[1].t - w[0].t >= 1.0 - 1e-9));
        let last = t0 + f64::from(30 * 60 * 5 - 1) * 0.2;
        assert!((p[p.len() - 1].t - last).abs() < 1.0, "{:?}", p.last());
        assert!(p[0].t >= last - 600.0 - 1e-6, "{:?}", p[0]);
        // Storage never grew past the bound.
        assert!(trail.heap_bytes() <= 600 * 16, "{}", trail.heap_bytes());
    }

    #[test]
    fn the_window_drops_old_points_before_the_count_does() {
        // 1 min window, 600 points: 0.1 s apart at least, 60 s kept.
        let c = cfg(1.0, 600);
        let mut trail = Trail::default();
        for i in 0..300 {
            trail.push(&c, 100.0 + f64::from(i), 10.0, 20.0, 0.0);
        }
        let p = trail.points();
        assert_eq!(p.len(), 61);
        assert_eq!(p[0].t, 339.0);
        assert_eq!(p[60].t, 399.0);
    }

    #[test]
    fn values_round_trip_to_a_centimetre() {
        let c = cfg(10.0, 600);
        let mut trail = Trail::default();
        trail.push(
            &c,
            1_720_248_199.464_496,
            49.005_832_341,
            2.573_563_363,
            10_668.3,
        );
        trail.push(&c, 1_720_248_201.5, -33.946_1, 179.999_999_9, -12.5);
        trail.push(&c, 1_720_248_203.5, 89.9, -180.0, 15_000.0);
        let p = trail.points();
        assert!((p[0].t - 1_720_248_199.464_496).abs() < 1e-3);
        assert!((p[0].lat - 49.005_832_341).abs() < 1e-7);
        assert!((p[0].lon - 2.573_563_363).abs() < 1e-7);
        assert!((p[0].alt_m - 10_668.3).abs() < 1e-2);
        assert!((p[1].lon - 179.999_999_9).abs() < 1e-7);
        assert_eq!(p[2].lon, -180.0);
        assert_eq!(p[2].alt_m, 15_000.0);
    }

    #[test]
    fn non_finite_and_disabled_are_not_stored() {
        let mut trail = Trail::default();
        trail.push(&cfg(10.0, 600), 1.0, f64::NAN, 0.0, 0.0);
        trail.push(&cfg(10.0, 0), 2.0, 1.0, 0.0, 0.0);
        assert!(trail.is_empty());
        assert!(!trail.wants(&cfg(10.0, 0), 5.0));
    }

    #[test]
    fn time_going_back_starts_afresh_and_a_long_life_rebases() {
        let c = cfg(1440.0, 10);
        let mut trail = Trail::default();
        trail.push(&c, 1000.0, 1.0, 1.0, 1.0);
        trail.push(&c, 10_000.0, 1.0, 1.0, 1.0);
        // The newest point's time again (rounded in storage) is no step back.
        trail.push(&c, 10_000.000_4, 3.0, 3.0, 3.0);
        assert_eq!(trail.points().len(), 2);
        trail.push(&c, 10.0, 2.0, 2.0, 2.0);
        assert_eq!(trail.points().len(), 1);
        // 50 days of points 144 min apart: offsets would pass u32 milliseconds.
        let mut trail = Trail::default();
        for i in 0..500 {
            trail.push(&c, f64::from(i) * 8640.0, 1.0, 1.0, 1.0);
        }
        let p = trail.points();
        assert_eq!(p.len(), 10);
        assert_eq!(p[9].t, 499.0 * 8640.0);
        assert!(p.windows(2).all(|w| w[1].t > w[0].t));
    }
}
