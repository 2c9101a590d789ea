//! The daemon's per-frame path without tokio: the same [`Decoder`] and [`Aircraft`] code the
//! router and the aircraft tasks run, driven synchronously. The evaluation bench uses it to
//! score trackers on identical frames and to time each update without scheduler noise.

use super::aircraft::{Aircraft, AircraftConfig};
use super::registry::TrackState;
use super::stats::Stats;
use crate::decode::{Decoder, DecoderConfig, Icao};
use crate::feed::RawFrame;
use std::collections::HashMap;
use std::time::Instant;

/// Decoder plus one [`Aircraft`] per address, synchronously.
pub struct SyncPipeline {
    decoder: Decoder,
    aircraft: HashMap<Icao, Aircraft>,
    cfg: AircraftConfig,
    stats: Stats,
}

impl SyncPipeline {
    pub fn new(decoder: DecoderConfig, cfg: AircraftConfig) -> Self {
        Self {
            decoder: Decoder::new(decoder),
            aircraft: HashMap::new(),
            cfg,
            stats: Stats::new(),
        }
    }

    /// Takes one frame; when it updates a track, calls `on_update` with the new state and the
    /// wall time the aircraft's handling of that message took (CPR, measurement, filter), ns.
    pub fn push(&mut self, frame: &RawFrame, mut on_update: impl FnMut(&TrackState, u64)) {
        let Ok(d) = self.decoder.decode(frame) else {
            return;
        };
        let cfg = &self.cfg;
        let ac = self
            .aircraft
            .entry(d.icao)
            .or_insert_with(|| Aircraft::new(d.icao, cfg));
        let start = Instant::now();
        let updated = ac.handle(&d, &self.stats);
        let ns = start.elapsed().as_nanos() as u64;
        if updated {
            if let Some(s) = ac.snapshot() {
                on_update(&s, ns);
            }
        }
    }

    /// Counters so far (positions, updates, errors).
    pub fn stats(&self) -> &Stats {
        &self.stats
    }
}
