//! One aircraft: its CPR state, its tracker and what it last said, turned into measurements
//! and published snapshots.
//!
//! [`Aircraft`] is synchronous (so it is tested without a runtime); [`run_task`] is the tokio
//! task around it, one per aircraft, as mini-redis has one handler per connection.

use super::registry::{AircraftFacts, PredictionEnu, Published, Registry, Slot, TrackState};
use super::stats::{Counts, Stats};
use crate::decode::cpr::{CprConfig, CprDecoder, PositionFix};
use crate::decode::{AltitudeSource, Decoded, Icao, Message, Velocity};
use crate::track::geo::{LocalFrame, TrigCache};
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

/// Farthest a position may be from the origin of its track's plane, m. A track's
/// east-north-up plane is laid at its first position; an aircraft's next position farther
/// than this is no continuation of it (a wrong first fix corrected, or a long flight gone on):
/// the track restarts in a new plane there. 1,000 km is twice a receiver's range, more than
/// any flight of the fixtures, and keeps the plane's tilt under 9 degrees; beyond a few
/// thousand kilometres the plane's "down" reaches the Earth's centre, where no geodetic
/// position exists.
pub const MAX_TRACK_RADIUS_M: f64 = 1_000_000.0;

/// Farthest a published point (estimate or prediction) may be from its track's origin, m:
/// past this the estimate ran away (a filter diverged on absurd reports) and the point
/// nears the Earth's centre, where the geodetic conversion has no answer.
pub const MAX_PUBLISHED_RADIUS_M: f64 = 5_000_000.0;

/// A point that can be published: finite, and not run away from its plane's origin.
fn publishable_point(p: &Vector3<f64>) -> bool {
    // `norm() <= max` is false for NaN too; the sum of squares of finite values can still
    // overflow to +inf, which the comparison also refuses.
    p.norm() <= MAX_PUBLISHED_RADIUS_M
}

/// An estimate that can be published: every number finite (the covariances' traces too,
/// whose square roots are the published sigmas) and its position publishable.
fn publishable(e: &crate::track::Estimate) -> bool {
    e.t_s.is_finite()
        && publishable_point(&e.pos_m)
        && e.vel_mps.iter().all(|x| x.is_finite())
        && e.pos_cov_m2.iter().all(|x| x.is_finite())
        && e.vel_cov_m2ps2.iter().all(|x| x.is_finite())
        && e.pos_sigma_m().is_finite()
        && e.vel_sigma_mps().is_finite()
        && e.mode_probabilities.iter().all(|x| x.is_finite())
}

/// Messages over which the received power is averaged (readsb averages its last 8).
const SIGNAL_MEAN_MESSAGES: f32 = 8.0;

/// Variance of a 1-kt velocity quantisation step ((1 kt)^2 / 12), and of a 64-fpm vertical step.
const KT_QUANT_VAR: f64 = KT_TO_MPS * KT_TO_MPS / 12.0;
const VRATE_QUANT_VAR: f64 = (64.0 * FPM_TO_MPS) * (64.0 * FPM_TO_MPS) / 12.0;

/// The step of an airborne ground velocity's east and north components, m/s: 1 kt, or 4 kt
/// in subtype 2 (supersonic; DO-260B §2.2.3.2.6.2). Each component is its speed rounded to
/// the step, which the simulator's encoder does too (`sim::encode`); a recording agrees:
/// AFR34ZG's reports over 20 s at cruise average 0.03 ± 0.03 m/s above the speed its
/// positions give, where a truncated magnitude would sit 0.26 m/s below.
pub fn ground_velocity_step_mps(subtype: u8) -> f64 {
    if subtype == 2 {
        4.0 * KT_TO_MPS
    } else {
        KT_TO_MPS
    }
}

/// Settings every aircraft shares.
#[derive(Clone, Debug)]
pub struct AircraftConfig {
    pub cpr: CprConfig,
    /// Builds the tracker of a new aircraft.
    pub tracker: fn(&crate::config::TrackerConfig) -> Box<dyn Tracker>,
    pub tracker_config: crate::config::TrackerConfig,
    /// `decode.duplicate_window_s`: a position or velocity report equal to the last one of
    /// its kind within this long is a copy ([`Aircraft::handle`]); 0 keeps every copy.
    pub duplicate_window_s: f64,
}

/// One aircraft's state, owned by its task.
pub struct Aircraft {
    icao: Icao,
    cpr: CprDecoder,
    tracker: Box<dyn Tracker>,
    frame: Option<LocalFrame>,
    /// The sines and cosines of a recent position, from which the next ones come by angle
    /// addition ([`TrigCache`]).
    trig: TrigCache,
    /// What the aircraft said about itself, and the counts, as published.
    facts: AircraftFacts,
    /// Last height used for a position, m, and whether it was measured.
    last_alt_m: Option<f64>,
    /// Rotation from the local axes at the last accepted position to the frame's axes,
    /// computed once per position for the velocity reports that follow it.
    last_rotation: Option<Matrix3<f64>>,
    /// The last position handed to the tracker: (t, lat, lon, height m), for evaluation.
    last_fix: Option<(f64, f64, f64, f64)>,
    /// The position decoder's reference resets seen so far (`CprStats::resets`).
    cpr_resets_seen: u64,
    updates: u64,
    /// Feed time of the last tracker update, s.
    last_update_t_s: f64,
    /// Half the trackers' `max_gap_s`: a report without a position after this much silence
    /// may end the track, so the estimate is kept first ([`Aircraft::ended`]).
    ending_gap_s: f64,
    /// The last snapshot of a track that ended (a report past the trackers' gap rule, or a
    /// reset), until published: what the aircraft's slot keeps showing. Taken at the moment
    /// the track ends, it does not depend on how the messages were batched (a snapshot made
    /// only at batch ends would: a track ending mid-batch would show an older estimate, or
    /// none, depending on where the batch boundaries fell).
    /// Boxed: it is rarely there, and inline it took 0.5 KB of every aircraft.
    ended: Option<Box<Published>>,
    /// See [`AircraftConfig::duplicate_window_s`].
    duplicate_window_s: f64,
    /// The feed time and [`report_fingerprint`] of the last position report (airborne or
    /// surface) and of the last velocity report: what a copy is recognised by
    /// ([`Aircraft::is_copy`]). Its bits, not the decoded report: two whole messages took
    /// 208 bytes of every aircraft.
    last_reports: [(f64, u64); 2],
}

/// Which of [`Aircraft::is_copy`]'s slots a report belongs to (0: a position, airborne or
/// surface; 1: a velocity) and its content: the downlink format and the 56-bit ME field, the
/// whole of an extended squitter but its address (the aircraft's) and parity. `None` for the
/// reports no tracker takes. (A hash of the decoded message cost 70 instructions a frame.)
fn report_fingerprint(d: &Decoded) -> Option<(usize, u64)> {
    let slot = match d.msg {
        Message::AirbornePosition { .. } | Message::SurfacePosition { .. } => 0,
        Message::Velocity(_) => 1,
        _ => return None,
    };
    Some((slot, (u64::from(d.df) << 56) | d.me))
}

impl Aircraft {
    pub fn new(icao: Icao, cfg: &AircraftConfig) -> Self {
        Self {
            icao,
            cpr: CprDecoder::new(cfg.cpr),
            tracker: (cfg.tracker)(&cfg.tracker_config),
            frame: None,
            trig: TrigCache::default(),
            facts: AircraftFacts {
                last_seen: f64::NEG_INFINITY,
                ..AircraftFacts::default()
            },
            last_alt_m: None,
            last_rotation: None,
            last_fix: None,
            cpr_resets_seen: 0,
            updates: 0,
            last_update_t_s: f64::NEG_INFINITY,
            ending_gap_s: 0.5 * cfg.tracker_config.max_gap_s,
            ended: None,
            duplicate_window_s: cfg.duplicate_window_s,
            last_reports: [(f64::NEG_INFINITY, 0); 2],
        }
    }

    /// Whether `d` repeats the last report of its kind (a position, airborne or surface, or
    /// a velocity) within `duplicate_window_s` of feed time, either side: one transmission
    /// heard by two receivers whose frames one feed merges (OpenSky's recordings, a feeder
    /// with two antennas). A tracker given both copies would count one measurement twice,
    /// its covariance shrinking on no new information (`afr34zg-cdg-tls.jsonl`: 6 % of its
    /// positions and 5 % of its velocities arrive twice, microseconds apart). A transponder
    /// repeats an unchanged report 0.4 s later at the soonest, which the window stays under
    /// (`config::MAX_DUPLICATE_WINDOW_S`). A report that is not a copy becomes the last of
    /// its kind; a copy does not, so the window runs from the first copy.
    fn is_copy(&mut self, d: &Decoded) -> bool {
        if self.duplicate_window_s <= 0.0 {
            return false;
        }
        let Some((slot, fingerprint)) = report_fingerprint(d) else {
            return false;
        };
        let Some(last) = self.last_reports.get_mut(slot) else {
            return false;
        };
        if (d.time_s - last.0).abs() <= self.duplicate_window_s && last.1 == fingerprint {
            return true;
        }
        *last = (d.time_s, fingerprint);
        false
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
        counts.messages += 1;
        self.facts.last_seen = self.facts.last_seen.max(d.time_s);
        if let Some(signal) = d.signal {
            let power = (f32::from(signal) / 255.0).powi(2);
            self.facts.signal_power = Some(match self.facts.signal_power {
                Some(mean) => mean + (power - mean) / SIGNAL_MEAN_MESSAGES,
                None => power,
            });
        }
        if self.is_copy(d) {
            counts.duplicate_reports += 1;
            return false;
        }
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
                self.facts.position_type_code = Some(type_code);
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
                self.facts.position_type_code = Some(type_code);
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
            Message::Velocity(v) => {
                self.facts.nac_v = Some(v.nac_v);
                if v.gnss_minus_baro_ft.is_some() {
                    self.facts.geom_minus_baro_ft = v.gnss_minus_baro_ft;
                }
                self.velocity_measurement(t, &v)
            }
            Message::AllCall { .. } | Message::Other { .. } => None,
        };
        // Borrowed, not moved out of the `Option` (a copy of the whole report).
        let Some(m) = &measurement else {
            return false;
        };
        // Rare (a report without a position after a long silence): keep the estimate this
        // report may end.
        let before = if m.position.is_none() && m.t_s - self.last_update_t_s > self.ending_gap_s {
            self.published(&[], counts)
        } else {
            None
        };
        self.tracker.set_accuracy_declared(
            self.facts.nac_p.is_some(),
            self.facts.nac_v.is_some_and(|v| v > 0),
        );
        // Positions the tracker sets aside (`track::outlier`), counted over the daemon: only
        // a report with a position can be one, so the others do not ask.
        let outliers_before = m
            .position
            .is_some()
            .then(|| self.tracker.outlier_positions());
        match self.tracker.update(m) {
            // A report without a position long after the track's last one ends the track
            // (every tracker's `max_gap_s` rule) rather than updating it: no estimate left.
            Ok(()) if m.position.is_none() && !self.tracker.has_track() => {
                if let Some(p) = before {
                    self.ended = Some(Box::new(p));
                }
                false
            }
            Ok(()) => {
                self.last_update_t_s = m.t_s;
                self.updates += 1;
                counts.track_updates += 1;
                if let Some(before) = outliers_before {
                    counts.outlier_positions +=
                        self.tracker.outlier_positions().saturating_sub(before);
                }
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
        // After repeated rejections the position decoder gives up its reference, and the
        // position that follows is checked against nothing: the track built on the old
        // reference cannot be continued with it (a jump of hundreds of kilometres in a
        // second would be "measured" as a velocity of tens of km/s).
        let cpr_resets = self.cpr.stats().resets;
        if cpr_resets != self.cpr_resets_seen {
            self.cpr_resets_seen = cpr_resets;
            if self.frame.is_some() {
                self.reset_track(counts);
                counts.track_resets_jump += 1;
            }
        }
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
        let (mut enu, mut rotation) =
            frame.to_enu_with_rotation_near(&mut self.trig, lat, lon, h_m);
        if enu.norm() > MAX_TRACK_RADIUS_M {
            // Too far from the track's plane to continue it: a new track, in a new plane.
            self.reset_track(counts);
            counts.track_resets_jump += 1;
            let frame = *self.frame.insert(LocalFrame::new(lat, lon, 0.0));
            (enu, rotation) = frame.to_enu_with_rotation_near(&mut self.trig, lat, lon, h_m);
        }
        self.last_rotation = Some(rotation);
        let epu_m = match self.facts.nac_p {
            Some(n) => NACP_EPU_M.get(usize::from(n)).copied().unwrap_or(926.0),
            None => epu_from_type_code_m(type_code),
        };
        let sigma_h = epu_m / RADIUS95_PER_SIGMA_2D;
        let h_var = sigma_h * sigma_h + CPR_QUANT_VAR_M2;
        let cov = crate::track::geo::rotate_diag_cov(&rotation, &Vector3::new(h_var, h_var, v_var));
        Some(Measurement {
            t_s: t,
            position: Some(Observed {
                value: enu,
                cov,
                grid: None,
            }),
            velocity: None,
        })
    }

    fn velocity_measurement(&mut self, t: f64, v: &Velocity) -> Option<Measurement> {
        let (ve_kt, vn_kt) = v.ground_kt?;
        let (h95, v95) = nacv_bounds_mps(v.nac_v);
        let sh = h95 / RADIUS95_PER_SIGMA_2D;
        let sv = v95 / BOUND95_PER_SIGMA_1D;
        // Subtype 2 (supersonic) sends 4-kt steps; its rounding variance is 16 times.
        let step_mps = ground_velocity_step_mps(v.subtype);
        let h_var = sh * sh + step_mps * step_mps / 12.0;
        let (vu, vu_var) = match v.vrate_fpm {
            Some(r) => (f64::from(r) * FPM_TO_MPS, sv * sv + VRATE_QUANT_VAR),
            None => (0.0, UNMEASURED_VARIANCE),
        };
        let mut velocity = self.velocity_observation(
            Vector3::new(ve_kt * KT_TO_MPS, vn_kt * KT_TO_MPS, vu),
            (h_var, h_var, vu_var),
        )?;
        velocity.grid = Some(crate::track::quantised::Grid::new(
            step_mps,
            self.last_rotation.as_ref()?,
        ));
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
        Some(Observed {
            value: rotation * local,
            cov: crate::track::geo::rotate_diag_cov(rotation, &Vector3::new(var.0, var.1, var.2)),
            grid: None,
        })
    }

    /// The published snapshot: the estimate in the track's plane and predictions at
    /// `horizons_s`. `None` until the tracker has an estimate.
    ///
    /// No non-finite number ever leaves the daemon: an estimate or prediction that is not
    /// [`publishable`] (non-finite, or run away past [`MAX_PUBLISHED_RADIUS_M`], where the
    /// geodetic conversion fails) is not published; the track is reset instead and counted in
    /// `counts.track_resets_nonfinite`. Checked here, once per publication, rather than after
    /// every tracker step: the estimate is made here anyway, and a step's result that is never
    /// published harms nothing before the next check.
    pub fn published(&mut self, horizons_s: &[f64], counts: &mut Counts) -> Option<Published> {
        let estimate = self.tracker.estimate()?;
        let frame = self.frame?;
        let mut predictions = Vec::with_capacity(horizons_s.len());
        let mut ok = publishable(&estimate);
        if ok {
            self.tracker
                .predict_positions(estimate.t_s, horizons_s, &mut predictions);
            ok = predictions.iter().all(|p: &PredictionEnu| {
                p.t_s.is_finite() && publishable_point(&p.pos_m) && p.pos_sigma_m.is_finite()
            });
        }
        if !ok {
            tracing::debug!(icao = %self.icao, "non-finite or runaway estimate: track reset");
            self.clear_track();
            counts.track_resets_nonfinite += 1;
            return None;
        }
        Some(Published {
            icao: self.icao,
            frame,
            estimate,
            facts: self.facts,
            predictions,
        })
    }

    /// The estimate's time, the track's plane and the position in it, for the trail (which
    /// converts it to latitude and longitude when read); `None` without an estimate or when
    /// it could not be published.
    pub fn position(&self) -> Option<(f64, &LocalFrame, Vector3<f64>)> {
        let (t_s, pos_m) = self.tracker.estimated_position()?;
        let frame = self.frame.as_ref()?;
        if !(t_s.is_finite() && publishable_point(&pos_m)) {
            return None;
        }
        Some((t_s, frame, pos_m))
    }

    /// The state with predicted positions `horizons_s` seconds ahead (checked as
    /// [`published`](Self::published) is).
    pub fn snapshot_with_predictions(
        &mut self,
        horizons_s: &[f64],
        counts: &mut Counts,
    ) -> Option<TrackState> {
        self.published(horizons_s, counts).map(|p| p.track_state())
    }

    /// The state (no predictions), `None` until the tracker has an estimate.
    pub fn snapshot(&mut self, counts: &mut Counts) -> Option<TrackState> {
        self.snapshot_with_predictions(&[], counts)
    }

    /// Drops the track (not what the aircraft said about itself, nor its CPR state): the
    /// next position starts a new one, in a new plane.
    /// Ends the track, keeping its last snapshot ([`Aircraft::ended`]).
    fn reset_track(&mut self, counts: &mut Counts) {
        if let Some(p) = self.published(&[], counts) {
            self.ended = Some(Box::new(p));
        }
        self.clear_track();
    }

    /// Ends the track without a snapshot (its estimate is not publishable).
    fn clear_track(&mut self) {
        self.tracker.reset();
        self.frame = None;
        self.last_rotation = None;
    }
}

/// Everything a task needs besides its aircraft.
pub struct TaskContext {
    pub registry: Arc<Registry>,
    pub stats: Arc<Stats>,
    /// Where update lines go (`--tracks-out`), one `Vec<u8>` of lines per processed batch.
    pub updates: Option<mpsc::Sender<Vec<u8>>>,
    /// The broadcast of updates (the outputs, the API's event stream): every update's
    /// snapshot while anyone listens, never waited for.
    pub feed: Arc<crate::output::UpdateFeed>,
    pub shutdown: CancellationToken,
    /// Horizons of the published predictions, s.
    pub prediction_horizons_s: Vec<f64>,
}

/// One channel message to an aircraft task: its messages of one feed batch.
#[derive(Debug)]
pub struct AircraftBatch {
    pub msgs: Vec<crate::decode::Heard>,
    /// When the feed batch they came in was read (or, for a paced replay, was due): the
    /// start of the latency the task records when it has published.
    pub arrived: Instant,
    /// Permits of the frame budget this batch holds ([`Stats::reserve_frames`]), given back
    /// once it is processed.
    pub permits: u32,
    /// The feed batch's completion ([`FrameBatch::done`](crate::feed::tcp::FrameBatch)),
    /// released when this share of it is processed and dropped.
    pub done: Option<Arc<crate::feed::tcp::Completion>>,
}

/// The task of one aircraft: receives batches of its messages, updates, publishes.
///
/// Ends when the router drops its sender (the router retired it after feed-time or
/// wall-clock silence, or the stream ended: the remaining batches are drained first and the
/// last snapshot stays published) or on shutdown.
///
/// The aircraft comes boxed: an `async fn` keeps its arguments and the locals they move
/// into side by side in its future, which held a 1.2 KB `Aircraft` twice (3.0 KB futures).
pub async fn run_task(
    mut aircraft: Box<Aircraft>,
    mut rx: mpsc::Receiver<Box<AircraftBatch>>,
    slot: Slot,
    ctx: Arc<TaskContext>,
) {
    let icao = aircraft.icao;
    let mut lines: Vec<u8> = Vec::new();
    let mut counts = Counts::default();
    let cancelled = ctx.shutdown.cancelled();
    tokio::pin!(cancelled);
    // The trail takes a point at most every `min_interval_s` of feed time: checked here on
    // the message's time, so the estimate is read and converted once per point, whatever
    // the update rate and however the messages are batched.
    let history = *ctx.registry.history_config();
    let trail_interval_s = history.min_interval_s();
    let mut next_trail_t_s = f64::NEG_INFINITY;
    loop {
        // A batch waiting is taken without polling the cancellation future (registered
        // again under the token's lock at every poll: 0.8 % of a `kalman-cv` fleet replay's
        // instructions, twice a batch); shutdown is still seen before every batch.
        let batch = tokio::select! {
            biased;
            b = rx.recv() => match b {
                Some(b) if !ctx.shutdown.is_cancelled() => b,
                _ => break,
            },
            _ = &mut cancelled => break,
        };
        for h in &batch.msgs {
            // The message is read here, not in the router (`decode::Heard`).
            let d = &h.decoded();
            let updated = aircraft.handle(d, &mut counts);
            if updated
                && (d.time_s >= next_trail_t_s
                    || d.time_s < next_trail_t_s - 2.0 * trail_interval_s)
            {
                if let Some((t_s, frame, pos_m)) = aircraft.position() {
                    slot.record(&history, t_s, frame, &pos_m);
                    next_trail_t_s = t_s + trail_interval_s;
                }
            }
            if updated && ctx.feed.heard() {
                if let Some(p) = aircraft.published(&[], &mut counts) {
                    ctx.feed
                        .send(crate::output::OutputEvent::Update(Arc::new(p)));
                }
            }
            if updated && ctx.updates.is_some() {
                if let Some(s) = aircraft.snapshot(&mut counts) {
                    // Serialising a plain struct of numbers and strings cannot fail.
                    if serde_json::to_writer(&mut lines, &s).is_ok() {
                        lines.push(b'\n');
                    }
                }
            }
        }
        // Once per batch, whether or not the tracker moved: the message counts and the
        // identity fields are part of the snapshot too.
        publish(&mut aircraft, &slot, &ctx, &mut counts);
        ctx.registry.touch();
        counts.flush(&ctx.stats);
        ctx.stats.observe_latency(batch.arrived.elapsed());
        ctx.stats.release_frames(batch.permits);
        if let Some(tx) = &ctx.updates {
            if !lines.is_empty() && tx.send(std::mem::take(&mut lines)).await.is_err() {
                tracing::warn!(%icao, "update writer gone");
            }
        }
    }
    // `tracks_active` is the router's count: it follows the registry, which keeps serving
    // this aircraft's last snapshot after a replay's end.
    ctx.feed.send(crate::output::OutputEvent::Retired(icao));
}

/// Swaps the aircraft's new snapshot into its slot. The old one is freed when its last
/// reader lets go. (Recycling it saved one allocation a batch but kept a second snapshot
/// alive per aircraft, 650 bytes each: memory per aircraft is the scarcer resource.)
fn publish(aircraft: &mut Aircraft, slot: &Slot, ctx: &TaskContext, counts: &mut Counts) {
    match aircraft.published(&ctx.prediction_horizons_s, counts) {
        Some(p) => {
            aircraft.ended = None;
            slot.store(Arc::new(p));
        }
        None => {
            if let Some(mut p) = aircraft.ended.take() {
                p.facts = aircraft.facts;
                slot.store(Arc::new(*p));
            } else if let Some(last) = slot.load() {
                // No estimate (the track ended and no new one started yet): the last
                // snapshot stays, with what the aircraft said since (its message count,
                // callsign, ...). One copy per such batch, only while facts change.
                if last.facts != aircraft.facts {
                    let mut p = Published::clone(&last);
                    p.facts = aircraft.facts;
                    slot.store(Arc::new(p));
                }
            } else if slot.heard().is_none_or(|f| *f != aircraft.facts) {
                // Never a position: listed by what it says about itself.
                slot.store_heard(aircraft.facts);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decode::{Decoder, DecoderConfig};
    use crate::feed::RawFrame;
    use crate::sim::encode::airborne_position;
    use crate::track::cv::{CvKalman, CvParams};
    use crate::track::{Estimate, TrackError};

    const ICAO: Icao = Icao(0x39_3322);

    /// A CV Kalman filter whose estimate turns NaN from its third update on: what a filter
    /// gone wrong would publish.
    struct Poisoned {
        inner: CvKalman,
        updates: u32,
    }

    impl Tracker for Poisoned {
        fn name(&self) -> &'static str {
            "poisoned"
        }
        fn update(&mut self, m: &Measurement) -> Result<(), TrackError> {
            self.updates += 1;
            self.inner.update(m)
        }
        fn estimate(&self) -> Option<Estimate> {
            let mut e = self.inner.estimate()?;
            if self.updates >= 3 {
                e.pos_m.x = f64::NAN;
            }
            Some(e)
        }
        fn predict(&self, t_s: f64) -> Option<Estimate> {
            self.inner.predict(t_s)
        }
        fn reset(&mut self) {
            *self = poisoned();
        }
    }

    fn poisoned() -> Poisoned {
        Poisoned {
            inner: CvKalman::new(CvParams::default()),
            updates: 0,
        }
    }

    /// `has_track` answers as `estimate().is_some()` would, for every tracker: before the
    /// first position, through a track, after a gap that ends it, and after a reset.
    #[test]
    fn every_tracker_has_a_track_exactly_when_it_has_an_estimate() {
        let base = crate::config::Config::default_config()
            .map(|c| c.tracker)
            .unwrap_or_else(|e| panic!("{e}"));
        let position = |t_s: f64, east_m: f64| Measurement {
            t_s,
            position: Some(Observed {
                value: Vector3::new(east_m, 0.0, 10_000.0),
                cov: Matrix3::identity() * 25.0,
                grid: None,
            }),
            velocity: None,
        };
        let velocity = |t_s: f64| Measurement {
            t_s,
            position: None,
            velocity: Some(Observed {
                value: Vector3::new(200.0, 0.0, 0.0),
                cov: Matrix3::identity(),
                grid: None,
            }),
        };
        for name in crate::config::ALGORITHMS {
            let mut cfg = base.clone();
            cfg.algorithm = (*name).to_string();
            let mut t = crate::daemon::build_tracker(&cfg);
            let mut answers = Vec::new();
            let mut ask = |t: &dyn Tracker| {
                assert_eq!(t.has_track(), t.estimate().is_some(), "{name}");
                answers.push(t.has_track());
            };
            ask(&*t);
            t.update(&velocity(0.0)).ok();
            ask(&*t);
            for k in 1..=20 {
                let t_s = f64::from(k) * 0.5;
                t.update(&position(t_s, 200.0 * t_s)).ok();
                ask(&*t);
                t.update(&velocity(t_s + 0.25)).ok();
                ask(&*t);
            }
            // Ten minutes without a report: a velocity alone does not carry the track on.
            t.update(&velocity(610.0)).ok();
            ask(&*t);
            t.update(&position(610.5, 0.0)).ok();
            ask(&*t);
            t.reset();
            ask(&*t);
            let expected: Vec<bool> = std::iter::repeat_n(false, 2)
                .chain(std::iter::repeat_n(true, 40))
                .chain([false, true, false])
                .collect();
            assert_eq!(answers, expected, "{name}");
        }
    }

    fn config(tracker: fn(&crate::config::TrackerConfig) -> Box<dyn Tracker>) -> AircraftConfig {
        AircraftConfig {
            cpr: CprConfig::default(),
            tracker,
            tracker_config: crate::config::Config::default_config()
                .map(|c| c.tracker)
                .unwrap_or_else(|e| panic!("{e}")),
            duplicate_window_s: 0.2,
        }
    }

    /// Airborne positions every half second along a meridian from (lat, lon), at 230 m/s,
    /// even and odd in turn, from `t0_s`: decoded as the router would.
    fn positions(dec: &mut Decoder, t0_s: f64, lat: f64, lon: f64, n: usize) -> Vec<Decoded> {
        (0..n)
            .filter_map(|i| {
                let t = t0_s + 0.5 * i as f64;
                let lat = lat + 230.0 * 0.5 * i as f64 / 111_200.0;
                let bytes = airborne_position(ICAO, 35_000.0, lat, lon, i % 2 == 1);
                dec.decode(&RawFrame::new(t, &bytes, None)?).ok()
            })
            .collect()
    }

    fn decoder() -> Decoder {
        Decoder::new(DecoderConfig {
            fix_single_bit: false,
            recent_address_s: 60.0,
        })
    }

    /// What `publish` needs of a task's context: nothing listening.
    fn context() -> TaskContext {
        TaskContext {
            registry: Arc::new(Registry::default()),
            stats: Arc::new(Stats::new()),
            updates: None,
            feed: Arc::new(crate::output::UpdateFeed::default()),
            shutdown: tokio_util::sync::CancellationToken::new(),
            prediction_horizons_s: Vec::new(),
        }
    }

    /// An aircraft with the default tracker, and what handling and publishing it needs.
    fn default_aircraft() -> (Aircraft, Counts, Decoder, TaskContext, Slot) {
        let cfg = config(crate::daemon::build_tracker);
        (
            Aircraft::new(ICAO, &cfg),
            Counts::default(),
            decoder(),
            context(),
            Slot::default(),
        )
    }

    /// A velocity frame: 447 kt north, level, NACv 2 (the positions' 230 m/s).
    fn northbound_velocity() -> [u8; 14] {
        use crate::sim::encode::{airborne_velocity, VelocityReport};
        airborne_velocity(
            ICAO,
            &VelocityReport {
                ve_kt: 0.0,
                vn_kt: 447.0,
                vrate_fpm: 0.0,
                vrate_source: crate::decode::VerticalRateSource::Baro,
                nac_v: 2,
            },
        )
    }

    /// One frame's bytes at `t_s`, decoded.
    fn frame(dec: &mut Decoder, t_s: f64, bytes: &[u8]) -> Decoded {
        RawFrame::new(t_s, bytes, None)
            .and_then(|f| dec.decode(&f).ok())
            .unwrap_or_else(|| panic!("a frame"))
    }

    #[test]
    fn non_finite_estimate_resets_the_track_instead_of_being_published() {
        let cfg = config(|_| Box::new(poisoned()));
        let mut ac = Aircraft::new(ICAO, &cfg);
        let mut counts = Counts::default();
        let mut dec = decoder();
        let mut published = Vec::new();
        for d in positions(&mut dec, 100.0, 48.0, 2.0, 12) {
            if ac.handle(&d, &mut counts) {
                published.push(ac.published(&[30.0], &mut counts).is_some());
            }
        }
        // The first pair gives the first position: 11 updates. Each third update of a fresh
        // tracker turns it NaN: reset, not published, and the next update starts afresh.
        assert_eq!(counts.track_updates, 11);
        assert_eq!(
            published,
            [true, true, false, true, true, false, true, true, false, true, true]
        );
        assert_eq!(counts.track_resets_nonfinite, 3);
        let p = ac
            .published(&[30.0], &mut counts)
            .unwrap_or_else(|| panic!("a fresh track"));
        let s = p.track_state();
        assert!(
            (s.lat - 48.0).abs() < 0.02 && (s.lon - 2.0).abs() < 1e-3,
            "{s:?}"
        );
    }

    /// A track that ended keeps its last estimate on show, and what the aircraft says after
    /// (its message count, its callsign) still reaches the snapshot.
    #[test]
    fn an_ended_tracks_snapshot_keeps_counting_messages() {
        use crate::sim::encode::identification;
        let (mut ac, mut counts, mut dec, ctx, slot) = default_aircraft();
        let mut one = |ac: &mut Aircraft, d: &[Decoded]| {
            for d in d {
                ac.handle(d, &mut counts);
            }
            publish(ac, &slot, &ctx, &mut counts);
            slot.load().unwrap_or_else(|| panic!("a snapshot"))
        };
        let first = one(&mut ac, &positions(&mut dec, 100.0, 48.0, 2.0, 10));
        assert_eq!(first.facts.messages, 10);
        // A velocity report 200 s later ends the track (past the gap rule): no estimate.
        let velocity = northbound_velocity();
        let ended = one(&mut ac, &[frame(&mut dec, 300.0, &velocity)]);
        assert!(ac.tracker.estimate().is_none());
        assert_eq!(ended.estimate, first.estimate);
        assert_eq!(ended.facts.messages, 11);
        // Then only its identification: the same estimate, the new facts.
        let callsign = crate::decode::Callsign(*b"AFR34ZG ");
        let id = identification(ICAO, 3, &callsign);
        let named = one(&mut ac, &[frame(&mut dec, 301.0, &id)]);
        assert_eq!(named.estimate, first.estimate);
        assert_eq!(named.facts.messages, 12);
        assert_eq!(named.facts.callsign, Some(callsign));
    }

    /// An aircraft heard before any position is listed by what it says (`SlotCell::heard`);
    /// its first snapshot replaces that.
    #[test]
    fn an_aircraft_without_a_position_is_heard_until_its_first_snapshot() {
        use crate::sim::encode::identification;
        let (mut ac, mut counts, mut dec, ctx, slot) = default_aircraft();
        let callsign = crate::decode::Callsign(*b"KLM1023 ");
        ac.handle(
            &frame(&mut dec, 99.0, &identification(ICAO, 3, &callsign)),
            &mut counts,
        );
        publish(&mut ac, &slot, &ctx, &mut counts);
        assert!(slot.load().is_none());
        let heard = slot.heard().unwrap_or_else(|| panic!("heard"));
        assert_eq!((heard.callsign, heard.messages), (Some(callsign), 1));
        for d in positions(&mut dec, 100.0, 48.0, 2.0, 4) {
            ac.handle(&d, &mut counts);
        }
        publish(&mut ac, &slot, &ctx, &mut counts);
        let p = slot.load().unwrap_or_else(|| panic!("a snapshot"));
        assert_eq!((p.facts.callsign, p.facts.messages), (Some(callsign), 5));
        assert!(slot.heard().is_none());
    }

    /// One transmission heard twice (two receivers merged into one feed, microseconds apart,
    /// either order) is used once: the track is the one the single copies give, bit for bit,
    /// and each copy is counted. An unchanged velocity repeated half a second later (a
    /// transponder's next squitter) is a new report, and with the window at 0 every copy is
    /// used.
    #[test]
    fn a_report_heard_twice_is_used_once() {
        let velocity = northbound_velocity();
        // Positions every 0.5 s, each followed by a velocity report 0.25 s later.
        let reports = |dec: &mut Decoder| -> Vec<Decoded> {
            positions(dec, 100.0, 48.0, 2.0, 20)
                .into_iter()
                .flat_map(|p| {
                    let v = frame(dec, p.time_s + 0.25, &velocity);
                    [p, v]
                })
                .collect()
        };
        let run = |window_s: f64, copies: bool| {
            let mut cfg = config(crate::daemon::build_tracker);
            cfg.duplicate_window_s = window_s;
            let mut ac = Aircraft::new(ICAO, &cfg);
            let mut counts = Counts::default();
            let mut dec = decoder();
            for (i, d) in reports(&mut dec).into_iter().enumerate() {
                if copies {
                    // The copy 20 us after or before, with another receiver's signal level.
                    let dt_s = if i % 2 == 0 { 2e-5 } else { -2e-5 };
                    let copy = Decoded {
                        time_s: d.time_s + dt_s,
                        signal: Some(99),
                        ..d
                    };
                    ac.handle(&d, &mut counts);
                    ac.handle(&copy, &mut counts);
                } else {
                    ac.handle(&d, &mut counts);
                }
            }
            (ac.tracker.estimate(), counts)
        };
        let (single, single_counts) = run(0.2, false);
        let (deduplicated, counts) = run(0.2, true);
        assert!(single.is_some());
        assert_eq!(deduplicated, single);
        assert_eq!(counts.duplicate_reports, 40);
        assert_eq!(counts.messages, 80);
        assert_eq!(counts.track_updates, single_counts.track_updates);
        // 20 positions and 20 velocities; the first position only starts the CPR pair.
        assert_eq!(single_counts.track_updates, 38);
        assert_eq!(single_counts.duplicate_reports, 0);
        // The same velocity every 0.5 s is a new report each time.
        assert_eq!(single_counts.messages, 40);
        // Window 0: every copy reaches the tracker (the copies earlier than their original
        // come out of order and are refused).
        let (_, kept) = run(0.0, true);
        assert_eq!(kept.duplicate_reports, 0);
        assert!(kept.track_updates > 38, "{kept:?}");
    }

    #[test]
    fn a_position_far_from_the_track_restarts_it() {
        let cfg = config(crate::daemon::build_tracker);
        let mut ac = Aircraft::new(ICAO, &cfg);
        let mut counts = Counts::default();
        let mut dec = decoder();
        for d in positions(&mut dec, 100.0, 48.0, 2.0, 10) {
            ac.handle(&d, &mut counts);
        }
        assert_eq!(counts.track_updates, 9);
        // An hour later, 1,450 km south-west (Lisbon): a plausible flight for the position
        // decoder, too far for the track's plane.
        for d in positions(&mut dec, 3_700.0, 38.7, -9.1, 10) {
            ac.handle(&d, &mut counts);
        }
        assert_eq!(counts.track_resets_jump, 1);
        let s = ac
            .snapshot(&mut counts)
            .unwrap_or_else(|| panic!("a track at Lisbon"));
        assert!(
            (s.lat - 38.72).abs() < 0.02 && (s.lon + 9.1).abs() < 1e-3,
            "{s:?}"
        );
        assert!(s.ground_speed_mps < 400.0, "{s:?}");
        assert_eq!(counts.track_resets_nonfinite, 0);
    }
}
