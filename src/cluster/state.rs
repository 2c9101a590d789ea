//! The value a track node puts under an aircraft's key in the tracks bucket: JSON
//! `{"track": <Track>, "state": <StateRecord>}`.
//!
//! `track` is the API's `Track`, for whoever reads the bucket (a dashboard, `nats kv get`).
//! `state` is the snapshot as the track node's registry holds it ([`Published`]: the estimate
//! in the track's own plane, the plane's origin, the raw facts), so that an api node serves
//! exactly what a single process would: `/api/v1/tracks`, the map's stream, readsb's
//! `aircraft.json` and the outputs are all made from it, by the same code. JSON numbers
//! round-trip f64 exactly (serde_json writes the shortest exact form).

use crate::daemon::registry::{AircraftFacts, PredictionEnu, Published, TrackState};
use crate::decode::Icao;
use crate::track::geo::LocalFrame;
use crate::track::nis::NisStat;
use crate::track::{Estimate, FlightMode, Lateral, SpeedTrend, TurnDirection, VerticalTrend};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::sync::Mutex;

/// Version of [`StateRecord`]; an api node skips (and counts) another.
pub const STATE_VERSION: u8 = 1;

/// A [`Published`] snapshot, serialisable.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StateRecord {
    pub version: u8,
    pub icao: u32,
    /// The track plane's origin: latitude, longitude (degrees), height (m).
    pub origin: [f64; 3],
    pub t_s: f64,
    pub pos_m: [f64; 3],
    pub vel_mps: [f64; 3],
    /// Row-major, in the plane's axes.
    pub pos_cov_m2: [f64; 9],
    pub vel_cov_m2ps2: [f64; 9],
    pub mode: String,
    pub mode_probabilities: [f64; 5],
    pub filter: String,
    pub diverging: bool,
    pub divergence_events: u64,
    /// Absent from a peer of an older build: 0.
    #[serde(default)]
    pub outlier_positions: u64,
    pub turn: Option<String>,
    pub lateral: String,
    pub speed: String,
    pub vertical: String,
    pub nis: Option<(f64, u32)>,
    pub facts: AircraftFacts,
    /// (dt_s, t_s, east, north, up m, sigma m) per horizon.
    pub predictions: Vec<[f64; 6]>,
}

#[derive(Serialize)]
struct ValueOut<'a> {
    track: &'a TrackState,
    state: StateRecord,
}

#[derive(Deserialize)]
struct ValueIn {
    state: StateRecord,
}

/// Why a value was refused.
#[derive(Debug, thiserror::Error)]
pub enum StateError {
    #[error("not a track value: {0}")]
    Json(#[from] serde_json::Error),
    #[error("state version {0} (this build reads {STATE_VERSION})")]
    Version(u8),
    #[error("unknown {0} {1:?}")]
    Label(&'static str, String),
}

fn rows(m: &Matrix3<f64>) -> [f64; 9] {
    [
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
        m[(2, 0)],
        m[(2, 1)],
        m[(2, 2)],
    ]
}

/// The bucket value of a snapshot.
pub fn encode(p: &Published) -> Vec<u8> {
    let track = p.track_state();
    let e = &p.estimate;
    let (lat, lon, h) = p.frame.origin();
    let state = StateRecord {
        version: STATE_VERSION,
        icao: p.icao.0,
        origin: [lat, lon, h],
        t_s: e.t_s,
        pos_m: [e.pos_m.x, e.pos_m.y, e.pos_m.z],
        vel_mps: [e.vel_mps.x, e.vel_mps.y, e.vel_mps.z],
        pos_cov_m2: rows(&e.pos_cov_m2),
        vel_cov_m2ps2: rows(&e.vel_cov_m2ps2),
        mode: e.mode.as_str().to_string(),
        mode_probabilities: e.mode_probabilities,
        filter: e.filter.to_string(),
        diverging: e.diverging,
        divergence_events: e.divergence_events,
        outlier_positions: e.outlier_positions,
        turn: track.turn.map(str::to_string),
        lateral: track.lateral.to_string(),
        speed: track.speed.to_string(),
        vertical: track.vertical.to_string(),
        nis: e.nis.map(|n| (n.nis, n.dof)),
        facts: p.facts,
        predictions: p
            .predictions
            .iter()
            .map(|q| {
                [
                    q.dt_s,
                    q.t_s,
                    q.pos_m.x,
                    q.pos_m.y,
                    q.pos_m.z,
                    q.pos_sigma_m,
                ]
            })
            .collect(),
    };
    // Serialising numbers and strings into a Vec cannot fail.
    serde_json::to_vec(&ValueOut {
        track: &track,
        state,
    })
    .unwrap_or_default()
}

/// The snapshot of a bucket value.
pub fn decode(bytes: &[u8]) -> Result<Published, StateError> {
    let ValueIn { state: s } = serde_json::from_slice(bytes)?;
    if s.version != STATE_VERSION {
        return Err(StateError::Version(s.version));
    }
    let mode = FlightMode::ALL
        .into_iter()
        .find(|m| m.as_str() == s.mode)
        .ok_or_else(|| StateError::Label("mode", s.mode.clone()))?;
    let turn = match s.turn.as_deref() {
        None => None,
        Some("left") => Some(TurnDirection::Left),
        Some("right") => Some(TurnDirection::Right),
        Some(o) => return Err(StateError::Label("turn", o.to_string())),
    };
    let lateral = match s.lateral.as_str() {
        "straight" => Lateral::Straight,
        "left" => Lateral::Left,
        "right" => Lateral::Right,
        o => return Err(StateError::Label("lateral", o.to_string())),
    };
    let speed = match s.speed.as_str() {
        "constant" => SpeedTrend::Constant,
        "increasing" => SpeedTrend::Increasing,
        "decreasing" => SpeedTrend::Decreasing,
        o => return Err(StateError::Label("speed", o.to_string())),
    };
    let vertical = match s.vertical.as_str() {
        "level" => VerticalTrend::Level,
        "climb" => VerticalTrend::Climb,
        "descent" => VerticalTrend::Descent,
        o => return Err(StateError::Label("vertical", o.to_string())),
    };
    let [lat, lon, h] = s.origin;
    let v3 = |a: [f64; 3]| Vector3::new(a[0], a[1], a[2]);
    Ok(Published {
        icao: Icao(s.icao & 0xff_ffff),
        frame: LocalFrame::new(lat, lon, h),
        estimate: Estimate {
            t_s: s.t_s,
            pos_m: v3(s.pos_m),
            vel_mps: v3(s.vel_mps),
            pos_cov_m2: Matrix3::from_row_slice(&s.pos_cov_m2),
            vel_cov_m2ps2: Matrix3::from_row_slice(&s.vel_cov_m2ps2),
            mode,
            mode_probabilities: s.mode_probabilities,
            filter: filter_name(&s.filter),
            diverging: s.diverging,
            divergence_events: s.divergence_events,
            outlier_positions: s.outlier_positions,
            turn,
            lateral,
            speed,
            vertical,
            nis: s.nis.map(|(nis, dof)| NisStat { nis, dof }),
        },
        facts: s.facts,
        predictions: s
            .predictions
            .iter()
            .map(|&[dt_s, t_s, x, y, z, pos_sigma_m]| PredictionEnu {
                dt_s,
                t_s,
                pos_m: Vector3::new(x, y, z),
                pos_sigma_m,
            })
            .collect(),
    })
}

/// Most distinct filter names kept: the trackers have a dozen; a value naming more is
/// someone else's, and shows as "other".
const MAX_FILTER_NAMES: usize = 64;

/// The `&'static str` of a filter name ([`Estimate::filter`] is one): the names are few and
/// fixed, so each is leaked once and reused, at most [`MAX_FILTER_NAMES`] of them.
fn filter_name(name: &str) -> &'static str {
    static NAMES: Mutex<Option<HashSet<&'static str>>> = Mutex::new(None);
    let Ok(mut guard) = NAMES.lock() else {
        return "other";
    };
    let names = guard.get_or_insert_with(HashSet::new);
    if let Some(n) = names.get(name) {
        return n;
    }
    if names.len() >= MAX_FILTER_NAMES || name.len() > 64 {
        return "other";
    }
    let leaked: &'static str = Box::leak(name.to_string().into_boxed_str());
    names.insert(leaked);
    leaked
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;
    use crate::eval::bench::sync_pipeline;
    use crate::feed::replay::FileReader;

    /// Every published snapshot of a real recording survives the bucket unchanged: the api
    /// node serves what the track node computed, to the bit.
    #[test]
    fn real_snapshots_round_trip_exactly() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/lax-messages.avr.txt");
        let mut reader = FileReader::open(&path, None, 270.0).expect("fixture");
        let config = Config::default_config().expect("defaults");
        let mut pipeline = sync_pipeline(&config, "hybrid");
        let mut frames = Vec::new();
        let mut calls = 0;
        loop {
            let more = reader.next_batch(&mut frames).expect("reads");
            for f in frames.drain(..) {
                pipeline.push(&f);
            }
            if !more {
                break;
            }
        }
        let published = pipeline.published(&[30.0, 60.0]);
        assert!(published.len() > 90, "{} aircraft", published.len());
        for p in published {
            let back = decode(&encode(&p)).expect("decodes");
            assert_eq!(back.track_state(), p.track_state());
            assert_eq!(back.estimate, p.estimate);
            assert_eq!(back.facts, p.facts);
            calls += usize::from(p.facts.callsign.is_some());
        }
        assert!(calls > 20, "{calls} aircraft with a callsign");
    }

    #[test]
    fn bad_values_are_errors() {
        assert!(decode(b"").is_err());
        assert!(decode(b"{\"state\": 3}").is_err());
        assert!(decode(b"{\"track\": {}}").is_err());
    }
}
