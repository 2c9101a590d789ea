//! The registry: where aircraft tasks publish snapshots and the API reads them.
//!
//! Each aircraft owns one `ArcSwapOption` slot: publishing is a lock-free pointer swap, and the
//! map of slots is locked only when a task is spawned or retired (never per frame, never across
//! an `.await`). Readers never block a task.

use crate::decode::Icao;
use arc_swap::ArcSwapOption;
use serde::Serialize;
use std::collections::HashMap;
use std::sync::{Arc, RwLock};

/// Probability of each flight mode, as JSON `{"CV": .., "CA": .., ...}`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ModeProbabilities {
    #[serde(rename = "CV")]
    pub cv: f64,
    #[serde(rename = "CA")]
    pub ca: f64,
    #[serde(rename = "CT")]
    pub ct: f64,
    #[serde(rename = "CH")]
    pub ch: f64,
    #[serde(rename = "CHCA")]
    pub chca: f64,
}

impl From<[f64; 5]> for ModeProbabilities {
    fn from(p: [f64; 5]) -> Self {
        let [cv, ca, ct, ch, chca] = p;
        Self {
            cv,
            ca,
            ct,
            ch,
            chca,
        }
    }
}

/// One aircraft's published state: the `Track` of the HTTP API and the `--tracks-out` line.
///
/// The first fields are the update-line contract of DESIGN.md; more follow.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TrackState {
    /// Feed time of the estimate, s.
    pub t: f64,
    pub icao: Icao,
    pub lat: f64,
    pub lon: f64,
    /// Altitude of the estimate, m (barometric altitude when the reports are barometric).
    pub alt_m: f64,
    /// Velocity east, north, up, m/s (in the local axes at the aircraft).
    pub ve: f64,
    pub vn: f64,
    pub vu: f64,
    /// Flight-mode label of the estimate.
    pub mode: &'static str,
    /// "left" or "right" when `mode` is CT.
    pub turn: Option<&'static str>,
    /// I062/200-style movement axes: "straight" | "left" | "right".
    pub lateral: &'static str,
    /// "constant" | "increasing" | "decreasing".
    pub speed: &'static str,
    /// "level" | "climb" | "descent".
    pub vertical: &'static str,
    /// Which filter produced the estimate.
    pub filter: &'static str,
    /// 1-sigma horizontal position uncertainty, m.
    pub pos_sigma_m: f64,
    /// True while paper 000's divergence criterion holds.
    pub diverging: bool,
    /// 1-sigma horizontal velocity uncertainty, m/s.
    pub vel_sigma_mps: f64,
    pub divergence_events: u64,
    pub mode_probabilities: ModeProbabilities,
    pub callsign: Option<String>,
    pub squawk: Option<String>,
    /// Emitter category, e.g. "A3".
    pub category: Option<String>,
    pub ground_speed_mps: f64,
    /// Ground track, degrees clockwise from true north.
    pub track_deg: f64,
    pub vertical_rate_mps: f64,
    /// Last barometric altitude reported, ft.
    pub baro_alt_ft: Option<i32>,
    pub on_ground: bool,
    pub nac_p: Option<u8>,
    pub adsb_version: Option<u8>,
    /// Messages received from this aircraft.
    pub messages: u64,
    /// Feed time of the last message, s.
    pub last_seen: f64,
    pub positions_accepted: u64,
    pub positions_rejected: u64,
    /// Position covariance in the east-north-up axes at the aircraft, m^2 (row-major 3x3).
    pub pos_cov_enu_m2: [[f64; 3]; 3],
    /// Velocity covariance in the same axes, (m/s)^2.
    pub vel_cov_enu_m2ps2: [[f64; 3]; 3],
    /// Predicted positions at the configured horizons (published snapshots only; empty in
    /// `--tracks-out` lines).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub predictions: Vec<Prediction>,
}

/// A predicted position (paper 002 §1.3: extrapolation by the current mode's model).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Prediction {
    /// Seconds ahead of the estimate.
    pub dt_s: f64,
    /// Feed time of the prediction, s.
    pub t: f64,
    pub lat: f64,
    pub lon: f64,
    pub alt_m: f64,
    /// 1-sigma horizontal position uncertainty of the prediction, m.
    pub pos_sigma_m: f64,
}

/// What the API can read: every aircraft's latest snapshot.
#[derive(Default)]
pub struct Registry {
    slots: RwLock<HashMap<Icao, Arc<ArcSwapOption<TrackState>>>>,
}

impl Registry {
    /// A slot for a new aircraft task (empty until its first estimate).
    pub fn register(&self, icao: Icao) -> Arc<ArcSwapOption<TrackState>> {
        let slot = Arc::new(ArcSwapOption::empty());
        if let Ok(mut m) = self.slots.write() {
            m.insert(icao, slot.clone());
        }
        slot
    }

    /// Removes a retired aircraft.
    pub fn remove(&self, icao: Icao) {
        if let Ok(mut m) = self.slots.write() {
            m.remove(&icao);
        }
    }

    /// One aircraft's latest snapshot.
    pub fn get(&self, icao: Icao) -> Option<Arc<TrackState>> {
        let m = self.slots.read().ok()?;
        m.get(&icao)?.load_full()
    }

    /// Every aircraft that has an estimate, sorted by address (stable output).
    pub fn all(&self) -> Vec<Arc<TrackState>> {
        let mut v: Vec<Arc<TrackState>> = match self.slots.read() {
            Ok(m) => m.values().filter_map(|s| s.load_full()).collect(),
            Err(_) => Vec::new(),
        };
        v.sort_by_key(|t| t.icao);
        v
    }

    /// Aircraft tasks registered (with or without an estimate yet).
    pub fn len(&self) -> usize {
        self.slots.read().map(|m| m.len()).unwrap_or(0)
    }

    /// True when no aircraft is registered.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
