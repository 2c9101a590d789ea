//! The daemon's per-frame path without tokio: the same [`Decoder`] and [`Aircraft`] code the
//! router and the aircraft tasks run, driven synchronously. The evaluation bench uses it to
//! score trackers on identical frames and to time each update without scheduler noise.

use super::aircraft::{Aircraft, AircraftConfig};
use super::registry::TrackState;
use super::stats::{Counts, Stats};
use crate::decode::{Decoder, DecoderConfig, Icao};
use crate::feed::RawFrame;
use std::collections::HashMap;
use std::time::Instant;

/// What one frame changed.
#[derive(Clone, Debug)]
pub struct Update {
    /// The aircraft's new state, when the tracker took a measurement.
    pub state: Option<TrackState>,
    /// Wall time of the aircraft's handling of the message, ns.
    pub cpu_ns: u64,
    /// A new decoded position given to the tracker: (t, lat, lon, height m).
    pub fix: Option<(f64, f64, f64, f64)>,
}

/// Decoder plus one [`Aircraft`] per address, synchronously.
pub struct SyncPipeline {
    decoder: Decoder,
    aircraft: HashMap<Icao, Aircraft>,
    cfg: AircraftConfig,
    stats: Stats,
    counts: Counts,
}

impl SyncPipeline {
    pub fn new(decoder: DecoderConfig, cfg: AircraftConfig) -> Self {
        Self {
            decoder: Decoder::new(decoder),
            aircraft: HashMap::new(),
            cfg,
            stats: Stats::new(),
            counts: Counts::default(),
        }
    }

    /// Takes one frame. Returns what it changed: a new decoded position (what the tracker was
    /// given) and/or a new track state with the wall time the aircraft's handling of the
    /// message took (CPR, measurement, filter), ns.
    pub fn push(&mut self, frame: &RawFrame) -> Option<Update> {
        let (icao, updated, cpu_ns, fix_before) = self.handle(frame)?;
        let ac = self.aircraft.get_mut(&icao)?;
        let fix = ac.last_fix().filter(|f| Some(*f) != fix_before);
        let state = if updated {
            let state = ac.snapshot(&mut self.counts);
            self.counts.flush(&self.stats);
            state
        } else {
            None
        };
        (fix.is_some() || state.is_some()).then_some(Update { state, cpu_ns, fix })
    }

    /// Takes one frame without making a state: returns the wall time, ns, of the aircraft's
    /// handling of the message (CPR, measurement, filter) when it updated the tracker.
    /// What `benches/fleet.rs` times.
    pub fn push_timed(&mut self, frame: &RawFrame) -> Option<u64> {
        let (_, updated, cpu_ns, _) = self.handle(frame)?;
        updated.then_some(cpu_ns)
    }

    /// Decodes and hands the message to its aircraft: (address, tracker updated, ns taken,
    /// the aircraft's last fix before).
    #[allow(clippy::type_complexity)]
    fn handle(
        &mut self,
        frame: &RawFrame,
    ) -> Option<(Icao, bool, u64, Option<(f64, f64, f64, f64)>)> {
        let d = self.decoder.decode(frame).ok()?;
        let cfg = &self.cfg;
        let ac = self
            .aircraft
            .entry(d.icao)
            .or_insert_with(|| Aircraft::new(d.icao, cfg));
        let fix_before = ac.last_fix();
        let start = Instant::now();
        let updated = ac.handle(&d, &mut self.counts);
        let cpu_ns = start.elapsed().as_nanos() as u64;
        self.counts.flush(&self.stats);
        Some((d.icao, updated, cpu_ns, fix_before))
    }

    /// Every aircraft's snapshot now, with predictions at `horizons_s`.
    pub fn published(&mut self, horizons_s: &[f64]) -> Vec<super::registry::Published> {
        let counts = &mut self.counts;
        self.aircraft
            .values_mut()
            .filter_map(|ac| ac.published(horizons_s, counts))
            .collect()
    }

    /// Counters so far (positions, updates, errors).
    pub fn stats(&self) -> &Stats {
        &self.stats
    }
}

#[cfg(test)]
mod tests {
    use crate::config::{Config, ALGORITHMS};
    use crate::eval::bench::sync_pipeline;
    use crate::feed::RawFrame;

    fn frame(t: f64, hex: &str) -> RawFrame {
        let bytes: Vec<u8> = (0..hex.len())
            .step_by(2)
            .filter_map(|i| u8::from_str_radix(hex.get(i..i + 2)?, 16).ok())
            .collect();
        RawFrame::new(t, &bytes, None).unwrap()
    }

    /// Fuzz finding (target `pipeline`): a velocity report 82 s after the track's last
    /// report ends the track (every tracker's `max_gap_s` rule) instead of updating it. It was
    /// counted as a tracker update that left no estimate (`Aircraft::handle` returned true).
    /// The frames are the fuzzer's (parity written by the harness).
    #[test]
    fn a_report_that_ends_the_track_is_not_an_update() {
        let frames = [
            frame(35.125626, "8D48520A58C381180018385E43D0"),
            frame(35.125626, "8D48520A48520C2C31040B916943"),
            frame(68.45978166666666, "8D48520A4A5867C53C0821C37B98"),
            frame(117.68010858333334, "5F000009CC99D1"),
            frame(117.68010858333334, "8D48520A990C2C766C5F000CB492"),
        ];
        let config = Config::default_config().unwrap();
        for algorithm in ALGORITHMS {
            let mut p = sync_pipeline(&config, algorithm);
            let mut states = 0;
            for f in &frames {
                if p.push(f).is_some_and(|u| u.state.is_some()) {
                    states += 1;
                }
            }
            assert_eq!(
                p.stats().track_updates.get(),
                states,
                "{algorithm}: every counted update published a state"
            );
        }
    }

    /// Fuzz finding (target `pipeline`, synthetic records; issue 11 row 9): random airborne
    /// positions, then a supersonic velocity. After four rejections the CPR decoder forgets
    /// its last fix and accepts one 6,500 km from it 1 s later (its reset rule); the tracker
    /// takes it as an ordinary report, its estimate ends up thousands of km below the
    /// ellipsoid (finite in ENU), and the geodetic conversion on publication
    /// (`ecef_to_geodetic`) gave `lat = NaN` for 8 of the 12 trackers. The jump and
    /// non-finite resets (`track_resets_jump`, `track_resets_nonfinite`) now catch it.
    #[test]
    fn random_reports_never_publish_a_nan() {
        let frames = [
            frame(0.2, "8D4840D69395D748F285D3DA2E55"),
            frame(0.4, "8D4840D6F8A6AD010A99B4E14D97"),
            frame(0.6000000000000001, "8D4840D672EAEAF7902ECA0FD1D6"),
            frame(0.8, "8D4840D6ADD365DCDEE618BAB995"),
            frame(1.0, "8D4840D66C6174897590529105F2"),
            frame(1.2, "8D4840D6669B4F3BC6D8A4118E7B"),
            frame(1.4, "8D4840D6932A3494B0AAF046D88C"),
            frame(1.5999999999999999, "8D4840D68A565F20DCDEE6A1918D"),
            frame(4.0, "8D4840D69A6F20DCDEE618CF8678"),
        ];
        let config = Config::default_config().unwrap();
        let mut bad = Vec::new();
        for algorithm in ALGORITHMS {
            let mut p = sync_pipeline(&config, algorithm);
            for f in &frames {
                let Some(s) = p.push(f).and_then(|u| u.state) else {
                    continue;
                };
                let values = [s.lat, s.lon, s.alt_m, s.ve, s.vn, s.vu, s.pos_sigma_m];
                if !values.iter().all(|v| v.is_finite()) {
                    bad.push(format!("{algorithm} at t = {}: {values:?}", f.time_s));
                }
            }
        }
        assert!(bad.is_empty(), "non-finite states published: {bad:#?}");
    }
}
