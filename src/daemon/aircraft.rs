//! One aircraft: its CPR state, its tracker and what it last said, turned into measurements
//! and published snapshots.
//!
//! [`Aircraft`] is synchronous (so it is tested without a runtime); [`run_task`] is the tokio
//! task around it, one per aircraft, as mini-redis has one handler per connection.

use super::registry::{AircraftFacts, PredictionEnu, Published, Registry, Slot, TrackState};
use super::stats::{Counts, Stats};
use crate::decode::cpr::{CprConfig, CprDecoder, PositionFix};
use crate::decode::{AltitudeSource, Decoded, Icao, Message, Velocity};
use crate::track::geo::LocalFrame;
use crate::track::{Measurement, Observed, Tracker, UNMEASURED_VARIANCE};
use nalgebra::{Matrix3, Vector3};
use std::sync::Arc;
use std::time::Instant;
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
    /// What the aircraft said about itself, and the counts, as published.
    facts: AircraftFacts,
    /// Last height used for a position, m, and whether it was measured.
    last_alt_m: Option<f64>,
    /// Rotation from the local axes at the last accepted position to the frame's axes,
    /// computed once per position for the velocity reports that follow it.
    last_rotation: Option<Matrix3<f64>>,
    /// The last position handed to the tracker: (t, lat, lon, height m), for evaluation.
    last_fix: Option<(f64, f64, f64, f64)>,
    updates: u64,
}

impl Aircraft {
    pub fn new(icao: Icao, cfg: &AircraftConfig) -> Self {
        Self {
            icao,
            cpr: CprDecoder::new(cfg.cpr),
            tracker: (cfg.tracker)(&cfg.tracker_config),
            frame: None,
            facts: AircraftFacts {
                last_seen: f64::NEG_INFINITY,
                ..AircraftFacts::default()
            },
            last_alt_m: None,
            last_rotation: None,
            last_fix: None,
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
    /// Counters go to `counts`, which the caller flushes into the shared [`Stats`] once per
    /// batch (a shared atomic per frame costs more than the frame when two cores contend).
    pub fn handle(&mut self, d: &Decoded, counts: &mut Counts) -> bool {
        self.facts.messages += 1;
        self.facts.last_seen = self.facts.last_seen.max(d.time_s);
        let t = d.time_s;
        let measurement = match d.msg {
            Message::Identification { category, callsign } => {
                self.facts.callsign = Some(callsign);
                self.facts.category = Some(category);
                None
            }
            Message::Squawk { squawk } | Message::Emergency { squawk, .. } => {
                self.facts.squawk = Some(squawk);
                None
            }
            Message::Altitude { alt_ft } => {
                if alt_ft.is_some() {
                    self.facts.baro_alt_ft = alt_ft;
                }
                None
            }
            Message::OperationalStatus { version, nac_p, .. } => {
                self.facts.adsb_version = Some(version);
                if nac_p.is_some() {
                    self.facts.nac_p = nac_p;
                }
                None
            }
            Message::AirbornePosition {
                type_code,
                alt_ft,
                alt_source,
                cpr,
            } => {
                self.facts.on_ground = false;
                if alt_source == AltitudeSource::Baro && alt_ft.is_some() {
                    self.facts.baro_alt_ft = alt_ft;
                }
                let fix = self.cpr.airborne(t, cpr);
                self.position_measurement(
                    t,
                    fix,
                    alt_ft.map(|a| f64::from(a) * FT_TO_M),
                    type_code,
                    counts,
                )
            }
            Message::SurfacePosition {
                type_code,
                cpr,
                speed_kt,
                track_deg,
            } => {
                self.facts.on_ground = true;
                let fix = self.cpr.surface(t, cpr);
                let mut m = self.position_measurement(t, fix, None, type_code, counts);
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
                counts.track_updates += 1;
                true
            }
            Err(e) => {
                counts.track_error(&e);
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
        counts: &mut Counts,
    ) -> Option<Measurement> {
        let (lat, lon) = match fix {
            PositionFix::Accepted {
                lat_deg, lon_deg, ..
            } => (lat_deg, lon_deg),
            PositionFix::Pending => return None,
            PositionFix::Rejected(reason) => {
                self.facts.positions_rejected += 1;
                counts.position_rejected(reason);
                return None;
            }
        };
        self.facts.positions_accepted += 1;
        counts.positions_accepted += 1;
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
        let (enu, rotation) = frame.to_enu_with_rotation(lat, lon, h_m);
        self.last_rotation = Some(rotation);
        let epu_m = match self.facts.nac_p {
            Some(n) => NACP_EPU_M.get(usize::from(n)).copied().unwrap_or(926.0),
            None => epu_from_type_code_m(type_code),
        };
        let sigma_h = epu_m / RADIUS95_PER_SIGMA_2D;
        let h_var = sigma_h * sigma_h + CPR_QUANT_VAR_M2;
        let local_cov = Matrix3::from_diagonal(&Vector3::new(h_var, h_var, v_var));
        let cov = crate::track::geo::rotate_cov(&rotation, &local_cov);
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
        let rotation = self.last_rotation.as_ref()?;
        let local_cov = Matrix3::from_diagonal(&Vector3::new(var.0, var.1, var.2));
        Some(Observed {
            value: rotation * local,
            cov: crate::track::geo::rotate_cov(rotation, &local_cov),
        })
    }

    /// The published snapshot: the estimate in the track's plane and predictions at
    /// `horizons_s`. `None` until the tracker has an estimate.
    pub fn published(&self, horizons_s: &[f64]) -> Option<Published> {
        let estimate = self.tracker.estimate()?;
        let predictions = horizons_s
            .iter()
            .filter_map(|&dt_s| {
                let p = self.tracker.predict(estimate.t_s + dt_s)?;
                Some(PredictionEnu {
                    dt_s,
                    t_s: p.t_s,
                    pos_m: p.pos_m,
                    pos_sigma_m: p.pos_sigma_m(),
                })
            })
            .collect();
        Some(Published {
            icao: self.icao,
            frame: self.frame?,
            estimate,
            facts: self.facts,
            predictions,
        })
    }

    /// The state with predicted positions `horizons_s` seconds ahead.
    pub fn snapshot_with_predictions(&self, horizons_s: &[f64]) -> Option<TrackState> {
        self.published(horizons_s).map(|p| p.track_state())
    }

    /// The state (no predictions), `None` until the tracker has an estimate.
    pub fn snapshot(&self) -> Option<TrackState> {
        self.snapshot_with_predictions(&[])
    }
}

/// Everything a task needs besides its aircraft.
pub struct TaskContext {
    pub registry: Arc<Registry>,
    pub stats: Arc<Stats>,
    /// Where update lines go (`--tracks-out`), one `Vec<u8>` of lines per processed batch.
    pub updates: Option<mpsc::Sender<Vec<u8>>>,
    /// The outputs' broadcast (`[output.*]`): every update's snapshot, never waited for.
    pub outputs: Option<crate::output::OutputSender>,
    pub shutdown: CancellationToken,
    /// Horizons of the published predictions, s.
    pub prediction_horizons_s: Vec<f64>,
}

/// One channel message to an aircraft task: its messages of one feed batch.
#[derive(Debug)]
pub struct AircraftBatch {
    pub msgs: Vec<Decoded>,
    /// When the feed batch they came in was read (or, for a paced replay, was due): the
    /// start of the latency the task records when it has published.
    pub arrived: Instant,
    /// Permits of the frame budget this batch holds ([`Stats::reserve_frames`]), given back
    /// once it is processed.
    pub permits: u32,
}

/// The task of one aircraft: receives batches of its messages, updates, publishes.
///
/// Ends when the router drops its sender (the router retired it after feed-time or
/// wall-clock silence, or the stream ended: the remaining batches are drained first and the
/// last snapshot stays published) or on shutdown.
///
pub async fn run_task(
    mut aircraft: Aircraft,
    mut rx: mpsc::Receiver<AircraftBatch>,
    slot: Slot,
    ctx: Arc<TaskContext>,
) {
    let icao = aircraft.icao;
    let mut lines: Vec<u8> = Vec::new();
    let mut counts = Counts::default();
    let cancelled = ctx.shutdown.cancelled();
    tokio::pin!(cancelled);
    loop {
        let batch = tokio::select! {
            biased;
            _ = &mut cancelled => break,
            b = rx.recv() => match b {
                Some(b) => b,
                None => break,
            },
        };
        for d in &batch.msgs {
            let updated = aircraft.handle(d, &mut counts);
            if updated {
                if let Some(tx) = &ctx.outputs {
                    if let Some(p) = aircraft.published(&[]) {
                        // No receiver (every output ended) is not an error of the pipeline.
                        let _ = tx.send(crate::output::OutputEvent::Update(Arc::new(p)));
                    }
                }
            }
            if updated && ctx.updates.is_some() {
                if let Some(s) = aircraft.snapshot() {
                    // Serialising a plain struct of numbers and strings cannot fail.
                    if serde_json::to_writer(&mut lines, &s).is_ok() {
                        lines.push(b'\n');
                    }
                }
            }
        }
        counts.flush(&ctx.stats);
        // Once per batch, whether or not the tracker moved: the message counts and the
        // identity fields are part of the snapshot too.
        publish(&aircraft, &slot, &ctx.prediction_horizons_s);
        ctx.registry.touch();
        ctx.stats.observe_latency(batch.arrived.elapsed());
        ctx.stats.release_frames(batch.permits);
        if let Some(tx) = &ctx.updates {
            if !lines.is_empty() && tx.send(std::mem::take(&mut lines)).await.is_err() {
                tracing::warn!(%icao, "update writer gone");
            }
        }
    }
    if let Some(tx) = &ctx.outputs {
        let _ = tx.send(crate::output::OutputEvent::Retired(icao));
    }
    ctx.stats.tracks_active.dec();
}

/// Swaps the aircraft's new snapshot into its slot. The old one is freed when its last
/// reader lets go. (Recycling it saved one allocation a batch but kept a second snapshot
/// alive per aircraft, 650 bytes each: memory per aircraft is the scarcer resource.)
fn publish(aircraft: &Aircraft, slot: &Slot, horizons_s: &[f64]) {
    if let Some(p) = aircraft.published(horizons_s) {
        slot.store(Some(Arc::new(p)));
    }
}
