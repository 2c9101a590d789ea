//! One aircraft: its CPR state, its tracker and what it last said, turned into measurements
//! and published snapshots.
//!
//! [`Aircraft`] is synchronous (so it is tested without a runtime); [`run_task`] is the tokio
//! task around it, one per aircraft, as mini-redis has one handler per connection.

use super::registry::{Prediction, Registry, TrackState};
use super::stats::Stats;
use crate::decode::cpr::{CprConfig, CprDecoder, PositionFix, RejectReason};
use crate::decode::{AltitudeSource, Callsign, Decoded, Icao, Message, Velocity};
use crate::track::geo::LocalFrame;
use crate::track::{
    Lateral, Measurement, Observed, SpeedTrend, TrackError, Tracker, TurnDirection, VerticalTrend,
    UNMEASURED_VARIANCE,
};
use arc_swap::ArcSwapOption;
use nalgebra::{Matrix3, Vector3};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// Feet to metres (exact, international foot).
pub const FT_TO_M: f64 = 0.3048;
/// Knots to m/s (exact: 1852 m / 3600 s).
pub const KT_TO_MPS: f64 = 1852.0 / 3600.0;
/// Feet per minute to m/s.
pub const FPM_TO_MPS: f64 = FT_TO_M / 60.0;

/// Ratio of the 95 % radius of a circular 2-D Gaussian to its per-axis sigma:
/// sqrt(-2 ln 0.05). NACp/NACv bounds are 95 % horizontal radii (DO-260B §2.2.3.2.7.2.11).
const RADIUS95_PER_SIGMA_2D: f64 = 2.447_746_830_680_816;
/// 95 % two-sided bound of a 1-D Gaussian in sigmas (vertical NACv bounds).
const BOUND95_PER_SIGMA_1D: f64 = 1.959_963_984_540_054;

/// Per-axis position variance of airborne CPR quantisation: a 17-bit CPR cell is about
/// 5.1 m of latitude (360°/60/2^17), uniform error => (5.1 m)^2 / 12.
const CPR_QUANT_VAR_M2: f64 = 5.1 * 5.1 / 12.0;
/// Vertical variance of a barometric altitude in 25 ft steps plus about 3 m of altimetry noise.
const BARO_ALT_VAR_M2: f64 = (25.0 * FT_TO_M) * (25.0 * FT_TO_M) / 12.0 + 9.0;

/// 95 % horizontal position accuracy (EPU) for NACp 0-11, metres (DO-260B Table 2-71).
/// NACp 0 (unknown) is taken as 0.5 NM, a conservative value seen on old transponders.
const NACP_EPU_M: [f64; 12] = [
    926.0, 18_520.0, 7_408.0, 3_704.0, 1_852.0, 926.0, 555.6, 185.2, 92.6, 30.0, 10.0, 3.0,
];

/// 95 % horizontal accuracy implied by a version-0 position type code (NUCp via HFOM,
/// DO-260 Table 2-14), used until an operational status gives the NACp.
fn epu_from_type_code_m(tc: u8) -> f64 {
    match tc {
        // Surface positions: TC 5-8 carry NUCp 9-6.
        5 => 3.0,
        6 => 10.0,
        7 => 92.6,
        8 => 185.2,
        9 | 20 => 3.0,
        10 | 21 => 10.0,
        11 => 92.6,
        12 => 185.2,
        13 => 463.0,
        14 => 926.0,
        15 => 1_852.0,
        16 => 9_260.0,
        17 => 18_520.0,
        _ => 926.0,
    }
}

/// 95 % velocity accuracy for NACv 0-4: (horizontal, vertical) in m/s (DO-260B Table 2-22).
/// NACv 0 (unknown or >= 10 m/s) is taken as the NACv 1 bounds.
fn nacv_bounds_mps(nac_v: u8) -> (f64, f64) {
    match nac_v {
        2 => (3.0, 4.57),
        3 => (1.0, 1.52),
        4 => (0.3, 0.46),
        _ => (10.0, 15.24),
    }
}

/// Variance of a 1-kt velocity quantisation step ((1 kt)^2 / 12), and of a 64-fpm vertical step.
const KT_QUANT_VAR: f64 = KT_TO_MPS * KT_TO_MPS / 12.0;
const VRATE_QUANT_VAR: f64 = (64.0 * FPM_TO_MPS) * (64.0 * FPM_TO_MPS) / 12.0;

/// Settings every aircraft shares.
#[derive(Clone, Debug)]
pub struct AircraftConfig {
    pub cpr: CprConfig,
    /// Builds the tracker of a new aircraft.
    pub tracker: fn(&crate::config::TrackerConfig) -> Box<dyn Tracker>,
    pub tracker_config: crate::config::TrackerConfig,
}

/// One aircraft's state, owned by its task.
pub struct Aircraft {
    icao: Icao,
    cpr: CprDecoder,
    tracker: Box<dyn Tracker>,
    frame: Option<LocalFrame>,
    callsign: Option<Callsign>,
    squawk: Option<u16>,
    category: Option<(u8, u8)>,
    nac_p: Option<u8>,
    version: Option<u8>,
    baro_alt_ft: Option<i32>,
    /// Last height used for a position, m, and whether it was measured.
    last_alt_m: Option<f64>,
    last_pos_deg: Option<(f64, f64)>,
    /// The last position handed to the tracker: (t, lat, lon, height m), for evaluation.
    last_fix: Option<(f64, f64, f64, f64)>,
    on_ground: bool,
    messages: u64,
    last_seen: f64,
    positions_accepted: u64,
    positions_rejected: u64,
    updates: u64,
}

impl Aircraft {
    pub fn new(icao: Icao, cfg: &AircraftConfig) -> Self {
        Self {
            icao,
            cpr: CprDecoder::new(cfg.cpr),
            tracker: (cfg.tracker)(&cfg.tracker_config),
            frame: None,
            callsign: None,
            squawk: None,
            category: None,
            nac_p: None,
            version: None,
            baro_alt_ft: None,
            last_alt_m: None,
            last_pos_deg: None,
            last_fix: None,
            on_ground: false,
            messages: 0,
            last_seen: f64::NEG_INFINITY,
            positions_accepted: 0,
            positions_rejected: 0,
            updates: 0,
        }
    }

    /// The last decoded position given to the tracker: (t, lat, lon, height m).
    pub fn last_fix(&self) -> Option<(f64, f64, f64, f64)> {
        self.last_fix
    }

    /// Tracker updates done so far.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Takes one decoded message. Returns true when the tracker took a measurement (so a new
    /// estimate exists and an update line is due).
    pub fn handle(&mut self, d: &Decoded, stats: &Stats) -> bool {
        self.messages += 1;
        self.last_seen = self.last_seen.max(d.time_s);
        let t = d.time_s;
        let measurement = match d.msg {
            Message::Identification { category, callsign } => {
                self.callsign = Some(callsign);
                self.category = Some(category);
                None
            }
            Message::Squawk { squawk } | Message::Emergency { squawk, .. } => {
                self.squawk = Some(squawk);
                None
            }
            Message::Altitude { alt_ft } => {
                if alt_ft.is_some() {
                    self.baro_alt_ft = alt_ft;
                }
                None
            }
            Message::OperationalStatus { version, nac_p, .. } => {
                self.version = Some(version);
                if nac_p.is_some() {
                    self.nac_p = nac_p;
                }
                None
            }
            Message::AirbornePosition {
                type_code,
                alt_ft,
                alt_source,
                cpr,
            } => {
                self.on_ground = false;
                if alt_source == AltitudeSource::Baro && alt_ft.is_some() {
                    self.baro_alt_ft = alt_ft;
                }
                let fix = self.cpr.airborne(t, cpr);
                self.position_measurement(
                    t,
                    fix,
                    alt_ft.map(|a| f64::from(a) * FT_TO_M),
                    type_code,
                    stats,
                )
            }
            Message::SurfacePosition {
                type_code,
                cpr,
                speed_kt,
                track_deg,
            } => {
                self.on_ground = true;
                let fix = self.cpr.surface(t, cpr);
                let mut m = self.position_measurement(t, fix, None, type_code, stats);
                if let (Some(m), Some(speed), Some(track)) = (m.as_mut(), speed_kt, track_deg) {
                    let s = speed * KT_TO_MPS;
                    let tr = track.to_radians();
                    m.velocity = self.velocity_observation(
                        Vector3::new(s * tr.sin(), s * tr.cos(), 0.0),
                        (KT_QUANT_VAR + 1.0, KT_QUANT_VAR + 1.0, 0.01),
                    );
                }
                m
            }
            Message::Velocity(v) => self.velocity_measurement(t, &v),
            Message::AllCall { .. } | Message::Other { .. } => None,
        };
        let Some(m) = measurement else {
            return false;
        };
        match self.tracker.update(&m) {
            Ok(()) => {
                self.updates += 1;
                stats.track_updates.inc();
                true
            }
            Err(e) => {
                let reason = match e {
                    TrackError::NotPositiveDefinite => "not_positive_definite",
                    TrackError::OutOfOrder { .. } => "out_of_order",
                    TrackError::NonFinite(_) => "non_finite",
                };
                stats
                    .track_errors
                    .get_or_create(&vec![("reason", reason.to_string())])
                    .inc();
                tracing::debug!(icao = %self.icao, error = %e, "tracker refused a report");
                false
            }
        }
    }

    fn position_measurement(
        &mut self,
        t: f64,
        fix: PositionFix,
        alt_m: Option<f64>,
        type_code: u8,
        stats: &Stats,
    ) -> Option<Measurement> {
        let (lat, lon) = match fix {
            PositionFix::Accepted {
                lat_deg, lon_deg, ..
            } => (lat_deg, lon_deg),
            PositionFix::Pending => return None,
            PositionFix::Rejected(reason) => {
                self.positions_rejected += 1;
                stats
                    .positions_rejected
                    .get_or_create(&vec![("reason", reject_label(reason).to_string())])
                    .inc();
                return None;
            }
        };
        self.positions_accepted += 1;
        stats.positions_accepted.inc();
        self.last_pos_deg = Some((lat, lon));
        // A report without altitude keeps the last height, marked as not measured.
        let (h_m, v_var) = match alt_m {
            Some(h) => {
                self.last_alt_m = Some(h);
                (h, BARO_ALT_VAR_M2)
            }
            None => (self.last_alt_m.unwrap_or(0.0), UNMEASURED_VARIANCE),
        };
        self.last_fix = Some((t, lat, lon, h_m));
        let frame = *self
            .frame
            .get_or_insert_with(|| LocalFrame::new(lat, lon, 0.0));
        let enu = frame.to_enu(lat, lon, h_m);
        let epu_m = match self.nac_p {
            Some(n) => NACP_EPU_M.get(usize::from(n)).copied().unwrap_or(926.0),
            None => epu_from_type_code_m(type_code),
        };
        let sigma_h = epu_m / RADIUS95_PER_SIGMA_2D;
        let h_var = sigma_h * sigma_h + CPR_QUANT_VAR_M2;
        let local_cov = Matrix3::from_diagonal(&Vector3::new(h_var, h_var, v_var));
        let cov = frame.cov_to_enu(lat, lon, &local_cov);
        Some(Measurement {
            t_s: t,
            position: Some(Observed { value: enu, cov }),
            velocity: None,
        })
    }

    fn velocity_measurement(&mut self, t: f64, v: &Velocity) -> Option<Measurement> {
        let (ve_kt, vn_kt) = v.ground_kt?;
        let (h95, v95) = nacv_bounds_mps(v.nac_v);
        let sh = h95 / RADIUS95_PER_SIGMA_2D;
        let sv = v95 / BOUND95_PER_SIGMA_1D;
        let h_var = sh * sh + KT_QUANT_VAR;
        let (vu, vu_var) = match v.vrate_fpm {
            Some(r) => (f64::from(r) * FPM_TO_MPS, sv * sv + VRATE_QUANT_VAR),
            None => (0.0, UNMEASURED_VARIANCE),
        };
        let velocity = self.velocity_observation(
            Vector3::new(ve_kt * KT_TO_MPS, vn_kt * KT_TO_MPS, vu),
            (h_var, h_var, vu_var),
        )?;
        Some(Measurement {
            t_s: t,
            position: None,
            velocity: Some(velocity),
        })
    }

    /// A velocity in the local axes at the aircraft, rotated into the track's frame. `None`
    /// before the first position (the frame's axes are unknown until then).
    fn velocity_observation(&self, local: Vector3<f64>, var: (f64, f64, f64)) -> Option<Observed> {
        let frame = self.frame.as_ref()?;
        let (lat, lon) = self.last_pos_deg?;
        let local_cov = Matrix3::from_diagonal(&Vector3::new(var.0, var.1, var.2));
        Some(Observed {
            value: frame.vel_to_enu(lat, lon, &local),
            cov: frame.cov_to_enu(lat, lon, &local_cov),
        })
    }

    /// The published state with predicted positions `horizons_s` seconds ahead.
    pub fn snapshot_with_predictions(&self, horizons_s: &[f64]) -> Option<TrackState> {
        let mut s = self.snapshot()?;
        let frame = self.frame.as_ref()?;
        s.predictions = horizons_s
            .iter()
            .filter_map(|&dt_s| {
                let p = self.tracker.predict(s.t + dt_s)?;
                let (lat, lon, alt_m) = frame.to_geodetic(&p.pos_m);
                Some(Prediction {
                    dt_s,
                    t: p.t_s,
                    lat,
                    lon,
                    alt_m,
                    pos_sigma_m: p.pos_sigma_m(),
                })
            })
            .collect();
        Some(s)
    }

    /// The published state, `None` until the tracker has an estimate.
    pub fn snapshot(&self) -> Option<TrackState> {
        let est = self.tracker.estimate()?;
        let frame = self.frame.as_ref()?;
        let (lat, lon, alt_m) = frame.to_geodetic(&est.pos_m);
        let v = frame.vel_from_enu(lat, lon, &est.vel_mps);
        let (ve, vn, vu) = (v.x, v.y, v.z);
        let to_rows = |m: Matrix3<f64>| {
            [
                [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
                [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
                [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
            ]
        };
        let pos_cov = to_rows(frame.cov_from_enu(lat, lon, &est.pos_cov_m2));
        let vel_cov = to_rows(frame.cov_from_enu(lat, lon, &est.vel_cov_m2ps2));
        let track_deg = ve.atan2(vn).to_degrees().rem_euclid(360.0);
        Some(TrackState {
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
            mode_probabilities: est.mode_probabilities.into(),
            callsign: self.callsign.map(|c| c.as_str().to_string()),
            squawk: self.squawk.map(|s| format!("{s:04o}")),
            category: self.category.map(|(set, cat)| category_label(set, cat)),
            ground_speed_mps: ve.hypot(vn),
            track_deg,
            vertical_rate_mps: vu,
            baro_alt_ft: self.baro_alt_ft,
            on_ground: self.on_ground,
            nac_p: self.nac_p,
            adsb_version: self.version,
            messages: self.messages,
            last_seen: self.last_seen,
            positions_accepted: self.positions_accepted,
            positions_rejected: self.positions_rejected,
            pos_cov_enu_m2: pos_cov,
            vel_cov_enu_m2ps2: vel_cov,
            predictions: Vec::new(),
        })
    }
}

/// The stats label of a refused position.
fn reject_label(r: RejectReason) -> &'static str {
    match r {
        RejectReason::InvalidCpr => "invalid_cpr",
        RejectReason::BadTime => "bad_time",
        RejectReason::ZoneMismatch => "zone_mismatch",
        RejectReason::LatitudeOutOfRange => "latitude_out_of_range",
        RejectReason::ImpossibleSpeed => "impossible_speed",
    }
}

/// "A3"-style emitter category: set A-D from the type code (4..1), category number.
fn category_label(type_code: u8, category: u8) -> String {
    let set = match type_code {
        4 => 'A',
        3 => 'B',
        2 => 'C',
        1 => 'D',
        _ => '?',
    };
    format!("{set}{category}")
}

/// Everything a task needs besides its aircraft.
pub struct TaskContext {
    pub registry: Arc<Registry>,
    pub stats: Arc<Stats>,
    /// Where update lines go (`--tracks-out`), one `Vec<u8>` of lines per processed batch.
    pub updates: Option<mpsc::Sender<Vec<u8>>>,
    /// Wall-clock silence after which a task retires even if the feed's clock stopped
    /// (a dead feed): the feed-time retirement is done by the router.
    pub idle: Duration,
    pub shutdown: CancellationToken,
    /// Horizons of the published predictions, s.
    pub prediction_horizons_s: Vec<f64>,
}

/// The task of one aircraft: receives batches of its messages, updates, publishes.
///
/// Ends when the router drops its sender (the router retired it, or the stream ended: the
/// remaining batches are drained first and the last snapshot stays published), on shutdown,
/// or after `idle` of wall-clock silence (a dead feed), when it unpublishes itself.
pub async fn run_task(
    mut aircraft: Aircraft,
    mut rx: mpsc::Receiver<Vec<Decoded>>,
    slot: Arc<ArcSwapOption<TrackState>>,
    ctx: Arc<TaskContext>,
) {
    let icao = aircraft.icao;
    let mut lines: Vec<u8> = Vec::new();
    loop {
        let batch = tokio::select! {
            biased;
            _ = ctx.shutdown.cancelled() => break,
            b = rx.recv() => match b {
                Some(b) => b,
                None => break,
            },
            _ = tokio::time::sleep(ctx.idle) => {
                tracing::debug!(%icao, "idle, retiring");
                ctx.registry.remove(icao);
                ctx.stats.tracks_retired.inc();
                break;
            }
        };
        let mut changed = false;
        for d in &batch {
            if aircraft.handle(d, &ctx.stats) {
                changed = true;
                if ctx.updates.is_some() {
                    if let Some(s) = aircraft.snapshot() {
                        // Serialising a plain struct of numbers and strings cannot fail.
                        if serde_json::to_writer(&mut lines, &s).is_ok() {
                            lines.push(b'\n');
                        }
                    }
                }
            }
        }
        if changed {
            slot.store(
                aircraft
                    .snapshot_with_predictions(&ctx.prediction_horizons_s)
                    .map(Arc::new),
            );
        }
        if let Some(tx) = &ctx.updates {
            if !lines.is_empty() && tx.send(std::mem::take(&mut lines)).await.is_err() {
                tracing::warn!(%icao, "update writer gone");
            }
        }
    }
    ctx.stats.tracks_active.dec();
}
