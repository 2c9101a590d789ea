//! How much older an aircraft's velocity reports are than its position reports, measured on
//! a recording with no truth and no tracker: the data's own timing.
//!
//! A position report valid δ seconds before its frame puts the aircraft v·δ behind where it
//! is; a velocity report valid δ before gives the velocity of δ ago. Only the difference
//! between the two shows in the data, and only while the velocity changes: in a straight,
//! steady leg a constant offset along the track looks like a constant position error.
//!
//! Method, per window of [`WINDOW_S`] (the windows do not overlap, so their estimates are
//! independent): the position reports less the integral of the velocity reports,
//! r(t) = z(t) − ∫v, are fitted by least squares as r(t) = c + d (t − t̄) + v(t) λ, per
//! horizontal axis, c and d free per axis, λ shared. If the velocity reports are valid λ
//! seconds before the positions, z(t) = p(t) and ∫v = p(t − λ) + const, so
//! r = p(t) − p(t − λ) + const ≈ v(t) λ + const. The line c + d t takes up what drifts
//! slowly: a bias of the velocity reports, a GNSS error wandering over minutes. Windows
//! where the velocity changes by less than [`MIN_VELOCITY_CHANGE_MPS`] are skipped (λ is not
//! observable there); the rest are combined by their inverse variances. The variance of
//! each comes from its residuals as if they were white, which correlated GNSS error is not:
//! the spread of the windows' estimates is reported beside it.
//!
//! On `afr34zg-cdg-tls.jsonl` (real timestamps) the velocity reports are about 1 s older
//! than the positions (`docs/evaluation.md`); the transponder also repeats one velocity for
//! about a second (the same bytes two or three squitters running, in turns too), which is
//! half of it on average.

pub use crate::decode::reports::{reports, Reports};
use crate::feed::RawFrame;
use crate::track::geo::LocalFrame;
use crate::track::lag::WindowFit;

/// The window, the positions and the velocity change a window must hold: the same as the
/// tracker's learner.
pub use crate::track::lag::{MIN_POSITIONS, MIN_VELOCITY_CHANGE_MPS, WINDOW_S};

/// One aircraft's estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Offset {
    /// How much older the velocity reports are than the position reports, s (negative: the
    /// positions are older).
    pub velocity_lag_s: f64,
    /// Its standard error from the windows' residuals (white-noise assumption), s.
    pub sigma_s: f64,
    /// The standard deviation of the windows' estimates about it, s (NaN with one window).
    pub spread_s: f64,
    /// Windows that counted.
    pub windows: usize,
}

/// The header of [`markdown_rows`]' table.
pub const MARKDOWN_HEADER: &str = "| recording | aircraft | windows with a velocity change | velocity reports older than positions by, s | standard error s | spread of the windows s |\n|---|---|---:|---:|---:|---:|\n";

/// One markdown row per aircraft of `frames` whose velocity changed enough to tell
/// ([`estimate`]).
pub fn markdown_rows(recording: &str, frames: &[RawFrame]) -> String {
    let mut s = String::new();
    for (icao, r) in reports(frames) {
        if let Some(o) = estimate(&r) {
            let spread = if o.spread_s.is_finite() {
                format!("{:.2}", o.spread_s)
            } else {
                "-".to_string()
            };
            s.push_str(&format!(
                "| {recording} | {icao} | {} | {:.2} | {:.3} | {spread} |\n",
                o.windows, o.velocity_lag_s, o.sigma_s
            ));
        }
    }
    s
}

/// The velocity reports' lag behind the positions of one aircraft (module doc), or `None`
/// when no window saw the velocity change enough.
pub fn estimate(r: &Reports) -> Option<Offset> {
    let (first, last) = (r.positions.first()?.0, r.positions.last()?.0);
    let mut fits = Vec::new();
    let mut start = first;
    while start + WINDOW_S <= last {
        if let Some(fit) = window_fit(r, start, start + WINDOW_S) {
            fits.push(fit);
        }
        start += WINDOW_S;
    }
    let weight: f64 = fits.iter().map(|(_, s)| 1.0 / (s * s)).sum();
    if fits.is_empty() || !weight.is_finite() || weight <= 0.0 {
        return None;
    }
    let mean = fits.iter().map(|(x, s)| x / (s * s)).sum::<f64>() / weight;
    let spread = if fits.len() > 1 {
        let ss: f64 = fits.iter().map(|(x, _)| (x - mean).powi(2)).sum();
        (ss / (fits.len() - 1) as f64).sqrt()
    } else {
        f64::NAN
    };
    Some(Offset {
        velocity_lag_s: mean,
        sigma_s: weight.sqrt().recip(),
        spread_s: spread,
        windows: fits.len(),
    })
}

/// The window [t0, t1)'s estimate of λ and its standard error, if it counts.
fn window_fit(r: &Reports, t0: f64, t1: f64) -> Option<(f64, f64)> {
    // Velocity reports covering the window (one either side, for the interpolation).
    let lo = r.velocities.partition_point(|v| v.0 < t0).saturating_sub(1);
    let hi = (r.velocities.partition_point(|v| v.0 < t1) + 1).min(r.velocities.len());
    let vel = r.velocities.get(lo..hi)?;
    let (&(tv0, ..), &(tv1, ..)) = (vel.first()?, vel.last()?);
    let change = vel
        .iter()
        .flat_map(|a| vel.iter().map(move |b| (a.1 - b.1).hypot(a.2 - b.2)))
        .fold(0.0, f64::max);
    if change < MIN_VELOCITY_CHANGE_MPS {
        return None;
    }
    // The integral of the velocity reports at each report (trapezoids), from the first.
    let mut integral = Vec::with_capacity(vel.len());
    let (mut ie, mut in_) = (0.0, 0.0);
    for (i, v) in vel.iter().enumerate() {
        if let Some(p) = i.checked_sub(1).and_then(|j| vel.get(j)) {
            let dt = v.0 - p.0;
            ie += 0.5 * (v.1 + p.1) * dt;
            in_ += 0.5 * (v.2 + p.2) * dt;
        }
        integral.push((ie, in_));
    }
    let positions: Vec<&(f64, f64, f64, f64)> = r
        .positions
        .iter()
        .filter(|p| p.0 >= t0.max(tv0) && p.0 < t1.min(tv1))
        .collect();
    if positions.len() < MIN_POSITIONS as usize {
        return None;
    }
    let n = positions.len() as f64;
    let t_mean = positions.iter().map(|p| p.0).sum::<f64>() / n;
    // A plane at the window's mean position and height: the ground speed is the speed at
    // the aircraft's height, where a degree is (R + h) / R longer than on the ellipsoid
    // (0.16 % at 10 km: in a turn's curve, enough to move λ).
    let mean = |f: fn(&&(f64, f64, f64, f64)) -> f64| positions.iter().map(f).sum::<f64>() / n;
    let frame = LocalFrame::new(mean(|p| p.1), mean(|p| p.2), mean(|p| p.3));
    // The fit the tracker's learner keeps per aircraft (`track::lag::WindowFit`).
    let mut fit = WindowFit::default();
    for &&(t, lat, lon, h) in &positions {
        // The velocity report interval holding t.
        let k = vel.partition_point(|v| v.0 <= t).clamp(1, vel.len() - 1);
        let (a, b) = (vel.get(k - 1)?, vel.get(k)?);
        if b.0 <= a.0 {
            continue;
        }
        let enu = frame.to_enu(lat, lon, h);
        fit.add_position(t - t_mean, (t, enu.x, enu.y), a, b, *integral.get(k - 1)?);
    }
    fit.fit()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The simulator's positions valid `position_s` and velocities valid `velocity_s` before
    /// their frames: the velocity reports are then `velocity_s - position_s` older than the
    /// positions. Each built-in scenario's own GNSS error and timing stay as they are.
    fn lag_of(scenario: &str, position_s: f64, velocity_s: f64) -> Offset {
        let mut s = crate::sim::load_scenario(scenario).unwrap_or_else(|e| panic!("{e}"));
        s.settings.position_validity_offset_s = position_s;
        s.settings.velocity_validity_offset_s = velocity_s;
        let dir = std::env::temp_dir().join(format!(
            "adsb-latency-{scenario}-{position_s}-{velocity_s}-{}",
            std::process::id()
        ));
        let summary = crate::sim::simulate(&s, 1, &dir).unwrap_or_else(|e| panic!("{e}"));
        let frames = crate::eval::consistency::read_frames_at(
            &summary.beast_path,
            Some(crate::feed::Format::Beast),
            1000.0,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        for p in [&summary.beast_path, &summary.avr_path, &summary.truth_path] {
            let _ = std::fs::remove_file(p);
        }
        let all = reports(&frames);
        assert_eq!(all.len(), 1, "{scenario}");
        all.values()
            .next()
            .and_then(estimate)
            .unwrap_or_else(|| panic!("{scenario}: no estimate"))
    }

    /// Known offsets come back within 0.1 s, through CPR quantisation, 1-kt velocity steps,
    /// the reception jitter and (turns-correlated) a GNSS error wandering over a minute.
    /// Measured (seed 1), positions 0, 0.5 and -1 s old: -0.04, -0.53, +0.96 s on
    /// turns-correlated, -0.04, -0.54, +0.97 s on the airliner; the windows' spread
    /// 0.02-0.04 s, where their white-noise standard error says 0.01 s (the wandering error
    /// is not white). Velocities 1 s old, as AFR34ZG's are: +0.96 and +0.97 s.
    #[test]
    fn a_known_validity_offset_is_found() {
        for scenario in ["turns-correlated", "airliner-nacp10"] {
            for (position_s, velocity_s) in [(0.0, 0.0), (0.5, 0.0), (-1.0, 0.0), (0.0, 1.0)] {
                let o = lag_of(scenario, position_s, velocity_s);
                let truth_s = velocity_s - position_s;
                assert!(
                    (o.velocity_lag_s - truth_s).abs() < 0.1,
                    "{scenario} {position_s} {velocity_s}: {o:?}"
                );
                assert!(o.windows >= 2 && o.sigma_s < 0.05, "{scenario}: {o:?}");
            }
        }
    }

    /// A straight, steady flight says nothing about the offset: no estimate.
    #[test]
    fn a_straight_flight_gives_no_estimate() {
        let positions = (0..600)
            .map(|i| {
                let t = 0.5 * f64::from(i);
                (t, 48.0 + 230.0 * t / 111_200.0, 2.0, 10_000.0)
            })
            .collect();
        let velocities = (0..600)
            .map(|i| (0.25 + 0.5 * f64::from(i), 0.0, 230.0))
            .collect();
        let r = Reports {
            positions,
            velocities,
        };
        assert_eq!(estimate(&r), None);
        assert_eq!(estimate(&Reports::default()), None);
    }
}
