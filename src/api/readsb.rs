//! readsb's JSON, for tar1090 and the other tools of the readsb world: `GET
//! /data/aircraft.json` and `/data/receiver.json` in the format readsb's `README-json.md`
//! documents, and tar1090's own page (`server.readsb.tar1090_dir`) at `/tar1090/`, whose
//! `data/` requests the daemon answers.
//!
//! Positions and velocities are the tracker's estimates, not the last decoded report:
//! `lat`, `lon`, `gs`, `track` and `baro_rate` come from the estimate (the altitude the
//! tracker filters is the barometric one), `seen_pos` is the estimate's age. What the
//! aircraft said about itself is as decoded: `alt_baro` (or `"ground"`), `alt_geom` (the
//! barometric altitude plus the GNSS difference of its velocity reports), `flight`,
//! `squawk`, `category`, `version`, `nac_p`, `nac_v`, `nic` and `rc` (from the position's
//! type code, the NIC supplements taken as 0: the lower bound), `rssi`. A key is left out
//! when there is no value, as readsb does. Our own fields follow: `mode`, `pos_sigma_m`.
//! As in readsb, an aircraft heard without a position yet (one CPR format only so far, or
//! none: Mode S replies, an identification) is listed too, with what it said and without
//! the estimate's keys ([`crate::daemon::registry::SlotCell::heard`]).
//!
//! No `binCraft`, `zstd`, `reapi` or `globeIndexGrid` in `receiver.json`: those switch tar1090
//! to binary formats. `history` is 0: tar1090 asks for no `history_N.json`.

use super::{ApiError, ApiState};
use crate::daemon::registry::{AircraftFacts, Listed, Published};
use crate::decode::Icao;
use axum::body::Bytes;
use axum::extract::State;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};

/// Metres per foot, feet per metre.
const FT_PER_M: f64 = 1.0 / 0.3048;
/// Knots per m/s.
const KT_PER_MPS: f64 = 3600.0 / 1852.0;
/// ft/min per m/s.
const FPM_PER_MPS: f64 = FT_PER_M * 60.0;

/// `aircraft.json`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct AircraftJson {
    /// Feed time of the file, s since the epoch, strictly increasing from one response to
    /// the next (see [`NowClock`]).
    pub now: f64,
    /// Mode S messages processed since start.
    pub messages: u64,
    pub aircraft: Vec<ReadsbAircraft>,
}

/// One aircraft of `aircraft.json`; `None` keys are left out. An aircraft heard without a
/// position yet has no `lat`, `lon`, `gs`, `track`, `baro_rate`, `seen_pos`, `mode` or
/// `pos_sigma_m` (readsb leaves out the keys it has no value for).
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct ReadsbAircraft {
    pub hex: String,
    #[serde(rename = "type")]
    pub kind: &'static str,
    /// Callsign, space-padded to 8 characters.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flight: Option<String>,
    /// Barometric altitude, ft, or the string "ground".
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alt_baro: Option<AltBaro>,
    /// GNSS altitude, ft.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alt_geom: Option<i32>,
    /// Ground speed, kt (estimate).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gs: Option<f64>,
    /// Track over ground, degrees (estimate).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub track: Option<f64>,
    /// Vertical rate, ft/min (estimate).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub baro_rate: Option<i32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub squawk: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub category: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lat: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lon: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nic: Option<u8>,
    /// Radius of containment, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rc: Option<u32>,
    /// Age of the position, s.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seen_pos: Option<f64>,
    /// Age of the last message, s.
    pub seen: f64,
    pub messages: u64,
    /// Recent mean signal power, dBFS (negative).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rssi: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub version: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nac_p: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nac_v: Option<u8>,
    /// Fields derived from MLAT / TIS-B: none.
    #[schema(value_type = Vec<String>, max_items = 0)]
    pub mlat: [&'static str; 0],
    #[schema(value_type = Vec<String>, max_items = 0)]
    pub tisb: [&'static str; 0],
    /// Ours: the flight-mode label of the estimate.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mode: Option<&'static str>,
    /// Ours: 1-sigma horizontal position uncertainty, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pos_sigma_m: Option<f64>,
}

/// `alt_baro`: feet, or `"ground"`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
#[serde(untagged)]
pub enum AltBaro {
    Feet(i32),
    Ground(&'static str),
}

/// `receiver.json`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct ReceiverJson {
    pub version: String,
    /// How often tar1090 fetches `aircraft.json`, ms.
    pub refresh: u64,
    /// Valid `history_N.json` files: none.
    pub history: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lat: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lon: Option<f64>,
}

/// `now` of `aircraft.json`: the feed time, but strictly increasing from one response to the
/// next, as tar1090 expects (it drops a file whose `now` is not newer): when the feed time has
/// not moved (a replay's end, a silent feed), each response adds a millisecond.
#[derive(Debug, Default)]
pub struct NowClock {
    last_bits: AtomicU64,
}

/// The step added to a `now` that did not advance, s.
const NOW_STEP_S: f64 = 1e-3;

impl NowClock {
    pub fn next(&self, feed_time_s: f64) -> f64 {
        let mut last = self.last_bits.load(Ordering::Acquire);
        loop {
            let prev = f64::from_bits(last);
            let now = if feed_time_s > prev {
                feed_time_s
            } else {
                prev + NOW_STEP_S
            };
            match self.last_bits.compare_exchange_weak(
                last,
                now.to_bits(),
                Ordering::AcqRel,
                Ordering::Acquire,
            ) {
                Ok(_) => return now,
                Err(actual) => last = actual,
            }
        }
    }
}

/// NIC and radius of containment (m) of a position type code with the NIC supplements
/// unknown (taken as 0, the lower NIC): DO-260B Table 2-14 (airborne) and 2-19 (surface).
pub fn nic_rc(type_code: u8) -> Option<(u8, u32)> {
    Some(match type_code {
        9 | 20 | 5 => (11, 8),
        10 | 21 | 6 => (10, 25),
        11 | 7 => (8, 186),
        12 => (7, 371),
        13 => (6, 926),
        14 => (5, 1852),
        15 => (4, 3704),
        16 => (2, 14_816),
        17 => (1, 37_040),
        18 | 22 | 8 => (0, 0),
        _ => return None,
    })
}

impl ReadsbAircraft {
    /// The aircraft as readsb would list it, `now_s` being the file's time.
    pub fn from_published(p: &Published, now_s: f64) -> Self {
        let s = p.track_state();
        Self {
            gs: Some(round(s.ground_speed_mps * KT_PER_MPS, 1)),
            track: Some(round(s.track_deg, 2)),
            baro_rate: Some((s.vertical_rate_mps * FPM_PER_MPS).round() as i32),
            lat: Some(round(s.lat, 6)),
            lon: Some(round(s.lon, 6)),
            seen_pos: Some(round((now_s - s.t).max(0.0), 1)),
            mode: Some(s.mode),
            pos_sigma_m: Some(round(s.pos_sigma_m, 1)),
            ..Self::from_facts(p.icao, &p.facts, now_s)
        }
    }

    /// An aircraft from what it said about itself alone: no estimate, so no position,
    /// velocity or label (an aircraft heard without a position yet).
    pub fn from_facts(icao: Icao, f: &AircraftFacts, now_s: f64) -> Self {
        let alt_baro = if f.on_ground {
            Some(AltBaro::Ground("ground"))
        } else {
            f.baro_alt_ft.map(AltBaro::Feet)
        };
        let alt_geom = match (f.on_ground, f.baro_alt_ft, f.geom_minus_baro_ft) {
            (false, Some(baro), Some(d)) => Some(baro.saturating_add(d)),
            _ => None,
        };
        let (nic, rc) = match f.position_type_code.and_then(nic_rc) {
            Some((nic, rc)) => (Some(nic), (rc > 0).then_some(rc)),
            None => (None, None),
        };
        // Full scale is 0 dBFS; readsb's floor is about -49.5 dBFS.
        let rssi = f
            .signal_power
            .map(|power| round(10.0 * f64::from(power).max(1e-5).log10(), 1));
        Self {
            hex: icao.to_string(),
            kind: "adsb_icao",
            flight: f.callsign.as_ref().map(|c| format!("{:<8}", c.as_str())),
            alt_baro,
            alt_geom,
            gs: None,
            track: None,
            baro_rate: None,
            squawk: f.squawk_octal(),
            category: f.category_label(),
            lat: None,
            lon: None,
            nic,
            rc,
            seen_pos: None,
            seen: round((now_s - f.last_seen).max(0.0), 1),
            messages: f.messages,
            rssi,
            version: f.adsb_version,
            nac_p: f.nac_p,
            nac_v: f.nac_v,
            mlat: [],
            tisb: [],
            mode: None,
            pos_sigma_m: None,
        }
    }
}

/// `x` rounded to `places` decimals.
fn round(x: f64, places: i32) -> f64 {
    let k = 10f64.powi(places);
    (x * k).round() / k
}

/// readsb's answers are never cached: tar1090 polls them.
fn no_cache<T: Serialize>(body: T) -> Response {
    (
        [(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"))],
        Json(body),
    )
        .into_response()
}

/// `GET /data/aircraft.json` (and `/tar1090/data/aircraft.json`).
#[utoipa::path(get, path = "/data/aircraft.json", tag = "readsb",
    responses((status = 200, description = "readsb's aircraft.json (README-json.md), the tracker's estimates", body = AircraftJson)))]
pub(super) async fn aircraft(State(api): State<ApiState>) -> Result<Response, ApiError> {
    let shared = api.shared.clone();
    let clock = api.readsb_now.clone();
    // Converting and serialising every snapshot is ~1 ms per 1,000 aircraft: off the
    // server's threads.
    let body = tokio::task::spawn_blocking(move || {
        let now = clock.next(shared.stats.feed_time_s());
        serde_json::to_vec(&AircraftJson {
            now,
            messages: shared.stats.frames_in.get(),
            aircraft: shared
                .registry
                .all_listed()
                .iter()
                .map(|l| match l {
                    Listed::Tracked(p) => ReadsbAircraft::from_published(p, now),
                    Listed::Heard(icao, f) => ReadsbAircraft::from_facts(*icao, f, now),
                })
                .collect(),
        })
    })
    .await
    .map_err(|e| ApiError::Unavailable(format!("building aircraft.json: {e}")))?
    .map_err(|e| ApiError::Unavailable(format!("serialising aircraft.json: {e}")))?;
    // About 320 bytes an aircraft (0.3 MB for 1,000): sent in slices on the bulk lane, like
    // the tracks.
    let mut response = super::json_sliced(Bytes::from(body), false);
    response
        .headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    Ok(response)
}

/// `GET /data/receiver.json` (and `/tar1090/data/receiver.json`).
#[utoipa::path(get, path = "/data/receiver.json", tag = "readsb",
    responses((status = 200, description = "readsb's receiver.json", body = ReceiverJson)))]
pub(super) async fn receiver(State(api): State<ApiState>) -> Response {
    let config = &api.shared.config;
    let receiver = config.receiver;
    no_cache(ReceiverJson {
        version: format!("adsb-tracker {}", env!("CARGO_PKG_VERSION")),
        refresh: config.server.readsb.refresh_ms,
        history: 0,
        lat: receiver.map(|r| r.lat_deg),
        lon: receiver.map(|r| r.lon_deg),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn now_strictly_increases() {
        let c = NowClock::default();
        assert_eq!(c.next(100.0), 100.0);
        // A feed time that stopped, or went back: a millisecond more each time.
        let a = c.next(100.0);
        let b = c.next(99.0);
        assert!(
            (a - 100.001).abs() < 1e-9 && (b - 100.002).abs() < 1e-9,
            "{a} {b}"
        );
        assert_eq!(c.next(200.0), 200.0);
    }

    #[test]
    fn nic_follows_the_type_code() {
        assert_eq!(nic_rc(11), Some((8, 186)));
        assert_eq!(nic_rc(9), Some((11, 8)));
        assert_eq!(nic_rc(18), Some((0, 0)));
        assert_eq!(nic_rc(19), None);
    }
}
