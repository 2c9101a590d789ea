//! The registry: where aircraft tasks publish snapshots and the API reads them.
//!
//! Each aircraft owns one `ArcSwapOption` slot: publishing is a lock-free pointer swap. The
//! map of slots is itself swapped whole (copy on write) when a task is spawned or retired
//! (never per frame): readers never take a lock, so a reader that is descheduled mid-read
//! (the HTTP server's bulk lane runs at the lowest priority) can never hold up the router
//! registering an aircraft, and readers never block a task.
//!
//! What a task publishes is a [`Published`]: the tracker's estimate in the aircraft's own
//! east-north-up plane and the raw facts the aircraft reported, with no geodesy and no string.
//! The [`TrackState`] that the API and `--tracks-out` speak (latitude, longitude, covariances
//! in the axes at the aircraft, callsign text) is made from it on read, by
//! [`Published::track_state`]: at fleet scale most snapshots are replaced before anyone
//! reads them, and converting every one cost a sixth of the CPU.

use super::history::{Trail, TrailPoint};
use crate::config::HistoryConfig;
use crate::decode::{Callsign, Icao};
use crate::track::geo::LocalFrame;
use crate::track::{Estimate, Lateral, SpeedTrend, TurnDirection, VerticalTrend};
use arc_swap::{ArcSwap, ArcSwapOption};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

/// Probability of each flight mode, as JSON `{"CV": .., "CA": .., ...}`.
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
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
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
#[schema(as = Track)]
pub struct TrackState {
    /// Feed time of the estimate, s.
    pub t: f64,
    /// ICAO 24-bit address, 6 lowercase hex digits.
    #[schema(value_type = String, pattern = "^[0-9a-f]{6}$")]
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
    /// True while paper 000's divergence criterion has held on each of the last
    /// `[tracker.divergence] confirm` reports (4): the filter has lost the aircraft, not a
    /// single large residual, which a consistent filter shows on a few % of reports.
    pub diverging: bool,
    /// 1-sigma horizontal velocity uncertainty, m/s.
    pub vel_sigma_mps: f64,
    pub divergence_events: u64,
    /// Position reports the tracker set aside as out of their time (a stale fix, another
    /// receiver's clock: `track::outlier`), over the aircraft's life. They count in
    /// `positions_accepted` too: the decoder accepted them.
    pub outlier_positions: u64,
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
    #[schema(value_type = Vec<Vec<f64>>)]
    pub pos_cov_enu_m2: [[f64; 3]; 3],
    /// Velocity covariance in the same axes, (m/s)^2.
    #[schema(value_type = Vec<Vec<f64>>)]
    pub vel_cov_enu_m2ps2: [[f64; 3]; 3],
    /// Windowed normalised innovation squared: the sum of the last updates' NIS over their
    /// measured horizontal components, east and north of position and velocity (null before
    /// the track's first update; every tracker keeps one). χ²(`nis_dof`) for a consistent filter (`track::nis`; the
    /// quantised barometric altitude and rate are left out; a ground velocity's 1-kt
    /// rounding is read through its bin, `track::quantised`; `hybrid` and `imm` read a
    /// position in steady flight under the aircraft's learned tail index, `track::tails`).
    pub nis: Option<f64>,
    /// Degrees of freedom of `nis`: the measured horizontal components in its window.
    pub nis_dof: Option<u32>,
    /// Predicted positions at the configured horizons (published snapshots only; empty in
    /// `--tracks-out` lines).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    #[schema(required = false)]
    pub predictions: Vec<Prediction>,
}

/// A predicted position (paper 002 §1.3: extrapolation by the current mode's model).
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
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

/// A prediction in the track's plane, as published (converted on read): the tracker's
/// [`PositionPrediction`](crate::track::PositionPrediction) as it is.
pub type PredictionEnu = crate::track::PositionPrediction;

/// What an aircraft said about itself, as decoded (no text made yet). Serialisable: a cluster
/// track node puts it in the tracks bucket as is (`cluster::state`).
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, serde::Deserialize)]
pub struct AircraftFacts {
    pub callsign: Option<Callsign>,
    /// Mode A code as its 12 bits (printed in octal).
    pub squawk: Option<u16>,
    /// (type code, category) of the identification message.
    pub category: Option<(u8, u8)>,
    pub baro_alt_ft: Option<i32>,
    pub on_ground: bool,
    pub nac_p: Option<u8>,
    pub adsb_version: Option<u8>,
    pub messages: u64,
    /// Feed time of the last message, s.
    pub last_seen: f64,
    pub positions_accepted: u64,
    pub positions_rejected: u64,
    /// NACv of the last velocity report (DO-260B §2.2.3.2.6.1.5).
    pub nac_v: Option<u8>,
    /// GNSS minus barometric altitude of the last velocity report that carried it, ft.
    pub geom_minus_baro_ft: Option<i32>,
    /// Type code of the last position report (it gives the NIC, with the supplements
    /// unknown: DO-260B Table 2-14).
    pub position_type_code: Option<u8>,
    /// Mean received power of the recent messages, as a fraction of full scale (Beast's
    /// signal byte squared over 255^2; an exponential mean over about 8 messages), when the
    /// feed carries it.
    pub signal_power: Option<f32>,
}

/// One aircraft's published snapshot: estimate in the track's plane, the plane, the facts.
#[derive(Clone, Debug, PartialEq)]
pub struct Published {
    pub icao: Icao,
    /// The track's east-north-up plane (the estimate's coordinates).
    pub frame: LocalFrame,
    pub estimate: Estimate,
    pub facts: AircraftFacts,
    /// Predictions at the configured horizons (empty in `--tracks-out` lines).
    pub predictions: Vec<PredictionEnu>,
}

impl Published {
    /// The API's and `--tracks-out`'s view: geodetic position, velocity and covariances in
    /// the axes at the aircraft, labels and texts.
    pub fn track_state(&self) -> TrackState {
        let est = &self.estimate;
        let frame = &self.frame;
        let facts = &self.facts;
        let (lat, lon, alt_m) = frame.to_geodetic(&est.pos_m);
        // One rotation (frame axes -> axes at the aircraft) serves the velocity and both
        // covariances.
        let to_local = frame.rotation_from_local(lat, lon).transpose();
        let v = to_local * est.vel_mps;
        let (ve, vn, vu) = (v.x, v.y, v.z);
        let to_rows = |m: Matrix3<f64>| {
            [
                [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
                [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
                [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
            ]
        };
        let pos_cov = to_rows(crate::track::geo::rotate_cov(&to_local, &est.pos_cov_m2));
        let vel_cov = to_rows(crate::track::geo::rotate_cov(&to_local, &est.vel_cov_m2ps2));
        let track_deg = ve.atan2(vn).to_degrees().rem_euclid(360.0);
        TrackState {
            t: est.t_s,
            icao: self.icao,
            lat,
            lon,
            alt_m,
            ve,
            vn,
            vu,
            mode: est.mode.as_str(),
            turn: est.turn.map(|d| match d {
                TurnDirection::Left => "left",
                TurnDirection::Right => "right",
            }),
            lateral: match est.lateral {
                Lateral::Straight => "straight",
                Lateral::Left => "left",
                Lateral::Right => "right",
            },
            speed: match est.speed {
                SpeedTrend::Constant => "constant",
                SpeedTrend::Increasing => "increasing",
                SpeedTrend::Decreasing => "decreasing",
            },
            vertical: match est.vertical {
                VerticalTrend::Level => "level",
                VerticalTrend::Climb => "climb",
                VerticalTrend::Descent => "descent",
            },
            filter: est.filter,
            pos_sigma_m: est.pos_sigma_m(),
            diverging: est.diverging,
            vel_sigma_mps: est.vel_sigma_mps(),
            divergence_events: est.divergence_events,
            outlier_positions: est.outlier_positions,
            mode_probabilities: est.mode_probabilities.into(),
            callsign: facts.callsign.map(|c| c.as_str().to_string()),
            squawk: facts.squawk_octal(),
            category: facts.category_label(),
            ground_speed_mps: ve.hypot(vn),
            track_deg,
            vertical_rate_mps: vu,
            baro_alt_ft: facts.baro_alt_ft,
            on_ground: facts.on_ground,
            nac_p: facts.nac_p,
            adsb_version: facts.adsb_version,
            messages: facts.messages,
            last_seen: facts.last_seen,
            positions_accepted: facts.positions_accepted,
            positions_rejected: facts.positions_rejected,
            pos_cov_enu_m2: pos_cov,
            vel_cov_enu_m2ps2: vel_cov,
            nis: est.nis.map(|n| n.nis),
            nis_dof: est.nis.map(|n| n.dof),
            predictions: self
                .predictions
                .iter()
                .map(|p| {
                    let (lat, lon, alt_m) = frame.to_geodetic(&p.pos_m);
                    Prediction {
                        dt_s: p.dt_s,
                        t: p.t_s,
                        lat,
                        lon,
                        alt_m,
                        pos_sigma_m: p.pos_sigma_m,
                    }
                })
                .collect(),
        }
    }
}

impl AircraftFacts {
    /// The Mode A code as four octal digits, e.g. "7700".
    pub fn squawk_octal(&self) -> Option<String> {
        self.squawk.map(|s| format!("{s:04o}"))
    }

    /// The "A3"-style emitter category: set A-D from the identification's type code
    /// (4..1), then the category number.
    pub fn category_label(&self) -> Option<String> {
        let (type_code, category) = self.category?;
        let set = match type_code {
            4 => 'A',
            3 => 'B',
            2 => 'C',
            1 => 'D',
            _ => '?',
        };
        Some(format!("{set}{category}"))
    }
}

/// An aircraft as [`Registry::all_listed`] gives it.
#[derive(Clone, Debug)]
pub enum Listed {
    /// It has a snapshot.
    Tracked(Arc<Published>),
    /// Heard, no snapshot yet: its address and what it said about itself.
    Heard(Icao, Arc<AircraftFacts>),
}

/// One aircraft's place in the registry: its newest [`Published`], which its task swaps in,
/// and its trail.
#[derive(Debug, Default)]
pub struct SlotCell {
    snapshot: ArcSwapOption<Published>,
    /// What the aircraft said about itself while it has no snapshot (no position decoded
    /// yet, or none ever: a Mode S reply, an identification). readsb lists such aircraft,
    /// without a position, and so does `aircraft.json`. Dropped once a snapshot exists.
    heard: ArcSwapOption<AircraftFacts>,
    /// The recent positions (`[history]`). A std lock, held only to add a point (once per
    /// batch at most) or to copy the points out, never across an `.await`.
    trail: Mutex<Trail>,
}

impl SlotCell {
    /// Publishes a snapshot.
    pub fn store(&self, p: Arc<Published>) {
        self.snapshot.store(Some(p));
        if self.heard.load().is_some() {
            self.heard.store(None);
        }
    }

    /// Publishes what an aircraft without a snapshot said about itself.
    pub fn store_heard(&self, facts: AircraftFacts) {
        self.heard.store(Some(Arc::new(facts)));
    }

    /// What the aircraft said about itself, while it has no snapshot.
    pub fn heard(&self) -> Option<Arc<AircraftFacts>> {
        self.heard.load_full()
    }

    /// Adds an estimated position, a point `enu_m` of the track's plane `frame`, to the
    /// trail (kept if due, and converted to latitude and longitude when the trail is read:
    /// [`Trail::push_enu`]).
    pub fn record(
        &self,
        history: &HistoryConfig,
        t_s: f64,
        frame: &LocalFrame,
        enu_m: &Vector3<f64>,
    ) {
        self.trail
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push_enu(history, t_s, frame, enu_m);
    }

    /// The latest snapshot.
    pub fn load(&self) -> Option<Arc<Published>> {
        self.snapshot.load_full()
    }

    /// The trail's points, oldest first.
    pub fn trail(&self) -> Vec<TrailPoint> {
        self.trail
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .points()
    }
}

/// One aircraft's slot, shared by its task (the writer) and the registry (the readers).
pub type Slot = Arc<SlotCell>;

/// What the API can read: every aircraft's latest snapshot.
#[derive(Default)]
pub struct Registry {
    /// The slots, replaced whole on every register and remove (copy on write, ~20 µs for
    /// 1,000 aircraft, once per aircraft spawned or retired); read without a lock.
    slots: ArcSwap<HashMap<Icao, Slot>>,
    /// Serialises the writers (router and retiring tasks) so no change is lost; readers
    /// never take it.
    writing: Mutex<()>,
    /// Bumped after every change a reader could see (a slot added, removed or published):
    /// a reader that cached what it read at generation g knows it is current while the
    /// generation is still g.
    generation: AtomicU64,
    /// The trails' bounds (`[history]`).
    history: HistoryConfig,
}

impl Registry {
    /// Replaces the map with `change` applied to a copy of it.
    fn rewrite(&self, change: impl FnOnce(&mut HashMap<Icao, Slot>)) {
        // A writer that panicked left the map whole (it is swapped in only when complete).
        let _one = self.writing.lock().unwrap_or_else(|e| e.into_inner());
        let mut m = HashMap::clone(&self.slots.load());
        change(&mut m);
        self.slots.store(Arc::new(m));
    }

    /// A registry whose trails follow `history`.
    pub fn with_history(history: HistoryConfig) -> Self {
        Self {
            history,
            ..Self::default()
        }
    }

    /// The trails' bounds.
    pub fn history_config(&self) -> &HistoryConfig {
        &self.history
    }

    /// A slot for a new aircraft task (empty until its first estimate).
    pub fn register(&self, icao: Icao) -> Slot {
        let slot = Arc::new(SlotCell::default());
        self.rewrite(|m| {
            m.insert(icao, slot.clone());
        });
        self.touch();
        slot
    }

    /// Marks a change: called after a task stores a new snapshot in its slot.
    pub fn touch(&self) {
        self.generation.fetch_add(1, Ordering::Release);
    }

    /// The change counter (see [`Registry::touch`]); read it before reading the slots.
    pub fn generation(&self) -> u64 {
        self.generation.load(Ordering::Acquire)
    }

    /// Removes a retired aircraft.
    pub fn remove(&self, icao: Icao) {
        self.rewrite(|m| {
            m.remove(&icao);
        });
        self.touch();
    }

    /// One aircraft's latest snapshot, as published.
    pub fn get_published(&self, icao: Icao) -> Option<Arc<Published>> {
        self.slots.load().get(&icao)?.load()
    }

    /// True while the aircraft is registered (with or without an estimate).
    pub fn contains(&self, icao: Icao) -> bool {
        self.slots.load().contains_key(&icao)
    }

    /// One aircraft's trail, oldest first; `None` when it has no published estimate.
    pub fn history(&self, icao: Icao) -> Option<Vec<TrailPoint>> {
        let slot = self.slots.load().get(&icao)?.clone();
        slot.load()?;
        Some(slot.trail())
    }

    /// The registered aircraft's addresses, sorted.
    pub fn addresses(&self) -> Vec<Icao> {
        let mut v: Vec<Icao> = self.slots.load().keys().copied().collect();
        v.sort_unstable();
        v
    }

    /// One aircraft's latest state.
    pub fn get(&self, icao: Icao) -> Option<TrackState> {
        self.get_published(icao).map(|p| p.track_state())
    }

    /// Every aircraft's latest snapshot as published, sorted by address.
    pub fn all_published(&self) -> Vec<Arc<Published>> {
        let mut v: Vec<Arc<Published>> = self
            .slots
            .load()
            .values()
            .filter_map(|s| s.load())
            .collect();
        v.sort_by_key(|t| t.icao);
        v
    }

    /// Every aircraft with something to show, sorted by address: its snapshot, or what it
    /// said about itself while it has none ([`SlotCell::heard`]). One pass over one
    /// version of the map, so an aircraft whose first snapshot lands meanwhile is listed
    /// once.
    pub fn all_listed(&self) -> Vec<Listed> {
        let mut v: Vec<Listed> = self
            .slots
            .load()
            .iter()
            .filter_map(|(icao, s)| match s.load() {
                Some(p) => Some(Listed::Tracked(p)),
                None => s.heard().map(|f| Listed::Heard(*icao, f)),
            })
            .collect();
        v.sort_by_key(|l| match l {
            Listed::Tracked(p) => p.icao,
            Listed::Heard(icao, _) => *icao,
        });
        v
    }

    /// Every aircraft that has an estimate, sorted by address (stable output).
    pub fn all(&self) -> Vec<TrackState> {
        self.all_published()
            .iter()
            .map(|p| p.track_state())
            .collect()
    }

    /// Aircraft tasks registered (with or without an estimate yet).
    pub fn len(&self) -> usize {
        self.slots.load().len()
    }

    /// True when no aircraft is registered.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
