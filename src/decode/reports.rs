//! Each aircraft's decoded position and ground-velocity reports, gathered from a whole
//! recording: what the tools that look at a recording's own timing need (the velocity lag of
//! `eval::latency`, the learned clock of `feed::pace`), without a tracker.

use crate::daemon::aircraft::{FT_TO_M, KT_TO_MPS};
use crate::decode::cpr::{CprConfig, CprDecoder, PositionFix};
use crate::decode::{Decoder, DecoderConfig, Icao, Message};
use crate::feed::RawFrame;
use std::collections::BTreeMap;

/// The reports of one aircraft: positions (t, lat°, lon°, barometric altitude m) and ground
/// velocities (t, east m/s, north m/s), in feed time order.
#[derive(Clone, Debug, Default)]
pub struct Reports {
    pub positions: Vec<(f64, f64, f64, f64)>,
    pub velocities: Vec<(f64, f64, f64)>,
}

/// Gathers every airborne aircraft's reports from `frames`: positions decoded by the daemon's
/// own CPR decoder (its plausibility checks included), ground velocities as sent.
pub fn reports(frames: &[RawFrame]) -> BTreeMap<Icao, Reports> {
    let mut c = Collector::new();
    c.add(frames);
    c.finish()
}

/// [`reports`] batch by batch, for a file too large to hold its frames (only the reports
/// are kept: two or three numbers per position or velocity).
pub struct Collector {
    decoder: Decoder,
    cpr: BTreeMap<Icao, CprDecoder>,
    out: BTreeMap<Icao, Reports>,
}

impl Default for Collector {
    fn default() -> Self {
        Self::new()
    }
}

impl Collector {
    pub fn new() -> Self {
        Self {
            decoder: Decoder::new(DecoderConfig::default()),
            cpr: BTreeMap::new(),
            out: BTreeMap::new(),
        }
    }

    /// The reports of the next frames of the recording.
    pub fn add(&mut self, frames: &[RawFrame]) {
        for f in frames {
            let Ok(d) = self.decoder.decode(f) else {
                continue;
            };
            match d.msg {
                Message::AirbornePosition {
                    cpr: c,
                    alt_ft: Some(alt_ft),
                    ..
                } => {
                    let fix = self
                        .cpr
                        .entry(d.icao)
                        .or_insert_with(|| CprDecoder::new(CprConfig::default()))
                        .airborne(d.time_s, c);
                    if let PositionFix::Accepted {
                        lat_deg, lon_deg, ..
                    } = fix
                    {
                        let r = self.out.entry(d.icao).or_default();
                        r.positions
                            .push((d.time_s, lat_deg, lon_deg, f64::from(alt_ft) * FT_TO_M));
                    }
                }
                Message::Velocity(v) => {
                    if let Some((e_kt, n_kt)) = v.ground_kt {
                        let r = self.out.entry(d.icao).or_default();
                        r.velocities
                            .push((d.time_s, e_kt * KT_TO_MPS, n_kt * KT_TO_MPS));
                    }
                }
                _ => {}
            }
        }
    }

    /// Every aircraft's reports, each kind in time order.
    pub fn finish(mut self) -> BTreeMap<Icao, Reports> {
        for r in self.out.values_mut() {
            r.positions.sort_by(|a, b| a.0.total_cmp(&b.0));
            r.velocities.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
        self.out
    }
}
