//! The truth: each aircraft's motion, integrated exactly per segment, on the WGS-84 ellipsoid.
//!
//! Kinematics are defined in the aircraft's local-level frame (east, north, up at the
//! aircraft): ground speed, true track angle, turn rate, vertical rate. That is what a pilot
//! flies and what ADS-B velocity messages report (DO-260B §2.2.3.2.6.1: east-west and
//! north-south ground velocity), so a CV segment gives constant velocity reports and "level"
//! means constant altitude however far the aircraft goes. Per segment the velocity is a closed
//! form of time; the horizontal displacement over any interval is its exact integral in that
//! frame, and it is turned into latitude and longitude with the WGS-84 meridian and
//! prime-vertical radii at the interval's mid-point (dlat = dn/(M + h),
//! dlon = de/((N + h) cos lat)). Intervals are at most [`INTEGRATION_STEP_S`] long and the
//! mid-point rule is exact to third order in them: a 100 km meridian run lands within a
//! millimetre of the meridian arc (tested).
//!
//! Over the tens of kilometres of the papers' scenarios this frame and the tangent plane at
//! the reference agree to the Earth's curvature terms (at the equator, where papers 001-003
//! sit, to a few metres horizontally at 50 km; a fixed tangent plane sees a level
//! aircraft 50 km away about 200 m lower, because the Earth curves away).

use super::scenario::MAX_ABS_LAT_DEG;
use super::scenario::{
    check_finite, check_positive, AircraftSpec, Reference, Segment, TurnDirection,
};
use super::wgs84;
use super::SimError;
use crate::decode::Icao;
use crate::track::FlightMode;
use std::io::{self, Write};

/// Longest interval integrated in one piece, seconds (see the module doc for the error).
pub const INTEGRATION_STEP_S: f64 = 0.25;

/// Header of `PREFIX.truth.csv` (DESIGN.md, "Simulator truth CSV").
pub const TRUTH_HEADER: &str = "t,icao,lat,lon,alt_m,ve,vn,vu,mode";

/// Horizontal motion over one segment, as closed forms of the time τ since its start.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Motion {
    /// Fixed track, speed s0 + a·τ (CV, CA, CH, CHCA).
    Straight {
        speed0_mps: f64,
        accel_mps2: f64,
        sin_track: f64,
        cos_track: f64,
    },
    /// Constant speed, track χ0 + ω·τ (CT; ω > 0 is a right turn).
    Turn {
        speed_mps: f64,
        track0_rad: f64,
        rate_rps: f64,
    },
    /// Constant jerk per axis (JERK): v(τ) = v0 + a0 τ + j τ²/2 on east and north.
    PerAxis {
        v0_mps: [f64; 2],
        a0_mps2: [f64; 2],
        jerk_mps3: [f64; 2],
    },
}

/// sin(x)/x, accurate near 0.
fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        1.0 - x * x / 6.0
    } else {
        x.sin() / x
    }
}

impl Motion {
    /// Ground velocity (east, north) at τ, m/s.
    fn velocity(&self, tau: f64) -> [f64; 2] {
        match *self {
            Self::Straight {
                speed0_mps,
                accel_mps2,
                sin_track,
                cos_track,
            } => {
                let s = speed0_mps + accel_mps2 * tau;
                [s * sin_track, s * cos_track]
            }
            Self::Turn {
                speed_mps,
                track0_rad,
                rate_rps,
            } => {
                let (s, c) = (track0_rad + rate_rps * tau).sin_cos();
                [speed_mps * s, speed_mps * c]
            }
            Self::PerAxis {
                v0_mps,
                a0_mps2,
                jerk_mps3,
            } => {
                let v = |k: usize| v0_mps[k] + a0_mps2[k] * tau + 0.5 * jerk_mps3[k] * tau * tau;
                [v(0), v(1)]
            }
        }
    }

    /// Acceleration (east, north) at τ for the per-axis motion, carried into a following
    /// JERK segment; zero for the others (a JERK after them starts from zero).
    fn per_axis_accel(&self, tau: f64) -> [f64; 2] {
        match *self {
            Self::PerAxis {
                a0_mps2, jerk_mps3, ..
            } => [
                a0_mps2[0] + jerk_mps3[0] * tau,
                a0_mps2[1] + jerk_mps3[1] * tau,
            ],
            _ => [0.0, 0.0],
        }
    }

    /// Exact displacement (east, north) from τ1 to τ2 in the local-level frame, metres.
    fn displacement(&self, tau1: f64, tau2: f64) -> [f64; 2] {
        let dt = tau2 - tau1;
        match *self {
            Self::Straight {
                speed0_mps,
                accel_mps2,
                sin_track,
                cos_track,
            } => {
                // ∫ (s0 + aτ) dτ = Δ (s0 + a (τ1 + τ2)/2), no cancellation.
                let d = dt * (speed0_mps + 0.5 * accel_mps2 * (tau1 + tau2));
                [d * sin_track, d * cos_track]
            }
            Self::Turn {
                speed_mps,
                track0_rad,
                rate_rps,
            } => {
                // ∫ v (sin χ, cos χ) dτ over a circular arc: the chord 2v sin(ωΔ/2)/ω along
                // the mid-arc track χ0 + ω (τ1 + τ2)/2.
                let chord = speed_mps * dt * sinc(0.5 * rate_rps * dt);
                let (s, c) = (track0_rad + 0.5 * rate_rps * (tau1 + tau2)).sin_cos();
                [chord * s, chord * c]
            }
            Self::PerAxis {
                v0_mps,
                a0_mps2,
                jerk_mps3,
            } => {
                let d = |k: usize| {
                    dt * (v0_mps[k]
                        + 0.5 * a0_mps2[k] * (tau1 + tau2)
                        + jerk_mps3[k] * (tau1 * tau1 + tau1 * tau2 + tau2 * tau2) / 6.0)
                };
                [d(0), d(1)]
            }
        }
    }
}

/// One segment ready to integrate: its time span, label, motion and vertical rate.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Piece {
    t0_s: f64,
    t1_s: f64,
    mode: FlightMode,
    motion: Motion,
    vu_mps: f64,
}

/// An aircraft's whole flight: where it starts and what it does, segment by segment.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    start_lat_rad: f64,
    start_lon_rad: f64,
    start_alt_m: f64,
    pieces: Vec<Piece>,
}

fn invalid(key: String, reason: String) -> SimError {
    SimError::Invalid { key, reason }
}

impl Trajectory {
    /// Builds aircraft `i` of a scenario, checking its start, velocity and segments (errors
    /// name the key, e.g. `aircraft[1].segments[2].turn_rate_dps`).
    pub fn build(
        ac: &AircraftSpec,
        i: usize,
        reference: &Reference,
        duration_s: f64,
    ) -> Result<Self, SimError> {
        let (lat, lon, alt) = start_position(ac, i, reference)?;
        let (mut vel, vz0) = initial_velocity(ac, i)?;
        let first_vz = ac.segments.first().map_or(0.0, Segment::vertical_rate_mps);
        if (vz0.1 - first_vz).abs() > 1e-9 {
            return Err(invalid(
                format!("aircraft[{i}].velocity.{}", vz0.0),
                format!(
                    "{} m/s differs from the first segment's vertical rate ({first_vz} m/s; \
                     CV, CA, CT and JERK are level)",
                    vz0.1
                ),
            ));
        }
        let mut track = vel[0].atan2(vel[1]);
        let mut accel = [0.0; 2];
        let mut t = 0.0;
        let mut pieces = Vec::with_capacity(ac.segments.len());
        for (j, seg) in ac.segments.iter().enumerate() {
            let key = |field: &str| format!("aircraft[{i}].segments[{j}].{field}");
            let dur = seg.duration_s();
            check_positive(&key("duration_s"), dur)?;
            let speed = vel[0].hypot(vel[1]);
            let straight = |accel_mps2: f64| Motion::Straight {
                speed0_mps: speed,
                accel_mps2,
                sin_track: track.sin(),
                cos_track: track.cos(),
            };
            let check_speed = |accel_mps2: f64| -> Result<(), SimError> {
                check_finite(&key("accel_mps2"), accel_mps2)?;
                let end = speed + accel_mps2 * dur;
                if end < 0.0 {
                    return Err(invalid(
                        key("accel_mps2"),
                        format!(
                            "ground speed would fall to {end} m/s by the end of the segment \
                             (it must stay >= 0)"
                        ),
                    ));
                }
                Ok(())
            };
            let (mode, motion, vu) = match *seg {
                Segment::Cv { .. } => (FlightMode::Cv, straight(0.0), 0.0),
                Segment::Ca { accel_mps2, .. } => {
                    check_speed(accel_mps2)?;
                    (FlightMode::Ca, straight(accel_mps2), 0.0)
                }
                Segment::Ct {
                    turn_rate_dps,
                    direction,
                    ..
                } => {
                    check_positive(&key("turn_rate_dps"), turn_rate_dps)?;
                    let sign = match direction {
                        TurnDirection::Left => -1.0,
                        TurnDirection::Right => 1.0,
                    };
                    let motion = Motion::Turn {
                        speed_mps: speed,
                        track0_rad: track,
                        rate_rps: sign * turn_rate_dps.to_radians(),
                    };
                    (FlightMode::Ct, motion, 0.0)
                }
                Segment::Ch {
                    vertical_rate_mps, ..
                } => {
                    check_finite(&key("vertical_rate_mps"), vertical_rate_mps)?;
                    (FlightMode::Ch, straight(0.0), vertical_rate_mps)
                }
                Segment::Chca {
                    vertical_rate_mps,
                    accel_mps2,
                    ..
                } => {
                    check_finite(&key("vertical_rate_mps"), vertical_rate_mps)?;
                    check_speed(accel_mps2)?;
                    (FlightMode::Chca, straight(accel_mps2), vertical_rate_mps)
                }
                Segment::Jerk {
                    jerk_east_mps3,
                    jerk_north_mps3,
                    ..
                } => {
                    check_finite(&key("jerk_east_mps3"), jerk_east_mps3)?;
                    check_finite(&key("jerk_north_mps3"), jerk_north_mps3)?;
                    let motion = Motion::PerAxis {
                        v0_mps: vel,
                        a0_mps2: accel,
                        jerk_mps3: [jerk_east_mps3, jerk_north_mps3],
                    };
                    (FlightMode::Ca, motion, 0.0)
                }
            };
            pieces.push(Piece {
                t0_s: t,
                t1_s: t + dur,
                mode,
                motion,
                vu_mps: vu,
            });
            vel = motion.velocity(dur);
            accel = motion.per_axis_accel(dur);
            // The track of a stopped aircraft is undefined: keep the last one.
            if vel[0].hypot(vel[1]) > 1e-9 {
                track = vel[0].atan2(vel[1]);
            }
            t += dur;
        }
        if t < duration_s {
            return Err(invalid(
                format!("aircraft[{i}].segments"),
                format!("durations sum to {t} s, less than settings.duration_s = {duration_s} s"),
            ));
        }
        Ok(Self {
            start_lat_rad: lat,
            start_lon_rad: lon,
            start_alt_m: alt,
            pieces,
        })
    }
}

/// Start position in radians and metres, from either form of `start`.
fn start_position(
    ac: &AircraftSpec,
    i: usize,
    reference: &Reference,
) -> Result<(f64, f64, f64), SimError> {
    let s = &ac.start;
    let key = |f: &str| format!("aircraft[{i}].start.{f}");
    let (lat, lon, alt) = match (s.lat_deg, s.lon_deg, s.alt_m, s.east_m, s.north_m, s.up_m) {
        (Some(lat), Some(lon), Some(alt), None, None, None) => {
            check_finite(&key("lat_deg"), lat)?;
            check_finite(&key("lon_deg"), lon)?;
            check_finite(&key("alt_m"), alt)?;
            if !(-180.0..=180.0).contains(&lon) {
                return Err(invalid(
                    key("lon_deg"),
                    format!("must be within [-180, 180], got {lon}"),
                ));
            }
            (lat.to_radians(), lon.to_radians(), alt)
        }
        (None, None, None, Some(e), Some(n), Some(u)) => {
            check_finite(&key("east_m"), e)?;
            check_finite(&key("north_m"), n)?;
            check_finite(&key("up_m"), u)?;
            // Horizontal position: the tangent-plane point (e, n, 0) of the reference, exactly;
            // the altitude is `up_m` itself (see the module doc).
            let (lat, lon, _) = wgs84::enu_to_geodetic(
                reference.lat_deg.to_radians(),
                reference.lon_deg.to_radians(),
                e,
                n,
                0.0,
            );
            (lat, lon, u)
        }
        _ => {
            return Err(invalid(
                format!("aircraft[{i}].start"),
                "give either lat_deg, lon_deg and alt_m, or east_m, north_m and up_m".into(),
            ))
        }
    };
    if lat.to_degrees().abs() > MAX_ABS_LAT_DEG {
        return Err(invalid(
            format!("aircraft[{i}].start"),
            format!(
                "latitude {} is beyond +-{MAX_ABS_LAT_DEG} degrees",
                lat.to_degrees()
            ),
        ));
    }
    if !(-2_000.0..=100_000.0).contains(&alt) {
        return Err(invalid(
            key(if s.alt_m.is_some() { "alt_m" } else { "up_m" }),
            format!("must be within [-2000, 100000] m, got {alt}"),
        ));
    }
    Ok((lat, lon, alt))
}

/// Initial ground velocity (east, north) and the vertical rate with the key that gave it.
fn initial_velocity(
    ac: &AircraftSpec,
    i: usize,
) -> Result<([f64; 2], (&'static str, f64)), SimError> {
    let v = &ac.velocity;
    let key = |f: &str| format!("aircraft[{i}].velocity.{f}");
    let horizontal = match (v.ground_speed_mps, v.track_deg, v.ve_mps, v.vn_mps) {
        (Some(gs), Some(trk), None, None) => {
            check_finite(&key("ground_speed_mps"), gs)?;
            check_finite(&key("track_deg"), trk)?;
            if gs < 0.0 {
                return Err(invalid(
                    key("ground_speed_mps"),
                    format!("must be >= 0, got {gs}"),
                ));
            }
            let (s, c) = trk.to_radians().sin_cos();
            [gs * s, gs * c]
        }
        (None, None, Some(ve), Some(vn)) => {
            check_finite(&key("ve_mps"), ve)?;
            check_finite(&key("vn_mps"), vn)?;
            [ve, vn]
        }
        _ => {
            return Err(invalid(
                format!("aircraft[{i}].velocity"),
                "give either ground_speed_mps and track_deg, or ve_mps and vn_mps".into(),
            ))
        }
    };
    let vertical = match (v.vertical_rate_mps, v.vu_mps) {
        (Some(_), Some(_)) => {
            return Err(invalid(
                format!("aircraft[{i}].velocity"),
                "give vertical_rate_mps or vu_mps, not both".into(),
            ))
        }
        (Some(r), None) => ("vertical_rate_mps", r),
        (None, Some(r)) => ("vu_mps", r),
        (None, None) => ("vertical_rate_mps", 0.0),
    };
    check_finite(&key(vertical.0), vertical.1)?;
    Ok((horizontal, vertical))
}

/// The true state of one aircraft at one time: a row of the truth CSV.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthState {
    pub t_s: f64,
    pub lat_deg: f64,
    /// In (-180, 180].
    pub lon_deg: f64,
    /// Altitude above the ellipsoid, metres (also the barometric altitude: ISA, no offset).
    pub alt_m: f64,
    /// Velocity in the local east-north-up frame at the aircraft, m/s.
    pub ve_mps: f64,
    pub vn_mps: f64,
    pub vu_mps: f64,
    pub mode: FlightMode,
}

impl TruthState {
    /// Writes the state as a truth CSV row (columns of [`TRUTH_HEADER`]), formatting straight
    /// into the writer (no allocation).
    pub fn write_csv_row<W: Write>(&self, w: &mut W, icao: Icao) -> io::Result<()> {
        writeln!(
            w,
            "{:.9},{},{:.9},{:.9},{:.3},{:.4},{:.4},{:.4},{}",
            self.t_s,
            icao,
            self.lat_deg,
            self.lon_deg,
            self.alt_m,
            self.ve_mps,
            self.vn_mps,
            self.vu_mps,
            self.mode.as_str()
        )
    }
}

/// A trajectory being flown: integrates forward on a fixed grid (multiples of
/// [`INTEGRATION_STEP_S`] and the segment boundaries), so the state at a time does not depend
/// on which other times were asked for before.
#[derive(Clone, Debug)]
pub struct Flight {
    trajectory: Trajectory,
    piece: usize,
    next_grid: u64,
    t_s: f64,
    lat_rad: f64,
    lon_rad: f64,
    alt_m: f64,
}

fn normalise_lon_deg(lon_rad: f64) -> f64 {
    let d = lon_rad.to_degrees().rem_euclid(360.0);
    if d > 180.0 {
        d - 360.0
    } else {
        d
    }
}

impl Flight {
    pub fn new(trajectory: Trajectory) -> Self {
        Self {
            piece: 0,
            next_grid: 1,
            t_s: 0.0,
            lat_rad: trajectory.start_lat_rad,
            lon_rad: trajectory.start_lon_rad,
            alt_m: trajectory.start_alt_m,
            trajectory,
        }
    }

    /// Integrates piece `p` from the cursor's time to `t_s` and returns (lat, lon, alt).
    fn integrate(&self, p: &Piece, t_s: f64) -> (f64, f64, f64) {
        let (tau1, tau2) = (self.t_s - p.t0_s, t_s - p.t0_s);
        let [de, dn] = p.motion.displacement(tau1, tau2);
        let du = p.vu_mps * (tau2 - tau1);
        let h_mid = self.alt_m + 0.5 * du;
        let (m0, _) = wgs84::radii_m(self.lat_rad);
        let lat_mid = self.lat_rad + 0.5 * dn / (m0 + h_mid);
        let (m, n) = wgs84::radii_m(lat_mid);
        (
            self.lat_rad + dn / (m + h_mid),
            self.lon_rad + de / ((n + h_mid) * lat_mid.cos()),
            self.alt_m + du,
        )
    }

    /// The true state at `t_s` (any time; cheapest when times do not decrease).
    pub fn state_at(&mut self, t_s: f64) -> TruthState {
        if t_s < self.t_s {
            *self = Self::new(self.trajectory.clone());
        }
        let n_pieces = self.trajectory.pieces.len();
        while let Some(p) = self.trajectory.pieces.get(self.piece).copied() {
            let grid_t = self.next_grid as f64 * INTEGRATION_STEP_S;
            let boundary = if self.piece + 1 < n_pieces {
                p.t1_s
            } else {
                f64::INFINITY
            };
            let node = grid_t.min(boundary);
            if node > t_s {
                break;
            }
            (self.lat_rad, self.lon_rad, self.alt_m) = self.integrate(&p, node);
            self.t_s = node;
            if node >= grid_t {
                self.next_grid += 1;
            }
            if node >= boundary {
                self.piece += 1;
            }
        }
        let Some(p) = self.trajectory.pieces.get(self.piece).copied() else {
            // No segments at all (refused by validation): the aircraft stays where it is.
            return TruthState {
                t_s,
                lat_deg: self.lat_rad.to_degrees(),
                lon_deg: normalise_lon_deg(self.lon_rad),
                alt_m: self.alt_m,
                ve_mps: 0.0,
                vn_mps: 0.0,
                vu_mps: 0.0,
                mode: FlightMode::Cv,
            };
        };
        let (lat, lon, alt) = self.integrate(&p, t_s);
        let [ve, vn] = p.motion.velocity(t_s - p.t0_s);
        TruthState {
            t_s,
            lat_deg: lat.to_degrees(),
            lon_deg: normalise_lon_deg(lon),
            alt_m: alt,
            ve_mps: ve,
            vn_mps: vn,
            vu_mps: p.vu_mps,
            mode: p.mode,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::scenario::{InitialVelocity, Start};

    fn aircraft(start: Start, velocity: InitialVelocity, segments: Vec<Segment>) -> AircraftSpec {
        AircraftSpec {
            icao: "abcdef".into(),
            callsign: "T".into(),
            start,
            velocity,
            segments,
        }
    }

    fn at(lat_deg: f64, lon_deg: f64, alt_m: f64) -> Start {
        Start {
            lat_deg: Some(lat_deg),
            lon_deg: Some(lon_deg),
            alt_m: Some(alt_m),
            ..Start::default()
        }
    }

    fn vel(ve: f64, vn: f64) -> InitialVelocity {
        InitialVelocity {
            ve_mps: Some(ve),
            vn_mps: Some(vn),
            ..InitialVelocity::default()
        }
    }

    const REF: Reference = Reference {
        lat_deg: 0.0,
        lon_deg: 0.0,
    };

    fn flight(ac: &AircraftSpec) -> Flight {
        let span: f64 = ac.segments.iter().map(Segment::duration_s).sum();
        Flight::new(Trajectory::build(ac, 0, &REF, span).unwrap())
    }

    /// Meridian arc length from the equator to `lat` on WGS-84 (Helmert's series as in
    /// Snyder, Map Projections: A Working Manual, eq. 3-21), an independent closed form.
    fn meridian_arc_m(lat: f64) -> f64 {
        let e2 = wgs84::E2;
        let (e4, e6) = (e2 * e2, e2 * e2 * e2);
        wgs84::A_M
            * ((1.0 - e2 / 4.0 - 3.0 * e4 / 64.0 - 5.0 * e6 / 256.0) * lat
                - (3.0 * e2 / 8.0 + 3.0 * e4 / 32.0 + 45.0 * e6 / 1024.0) * (2.0 * lat).sin()
                + (15.0 * e4 / 256.0 + 45.0 * e6 / 1024.0) * (4.0 * lat).sin()
                - (35.0 * e6 / 3072.0) * (6.0 * lat).sin())
    }

    #[test]
    fn due_north_follows_the_meridian_arc() {
        // 1000 s north at 100 m/s at sea level from 40 N: the meridian arc grows by 100 km.
        let ac = aircraft(
            at(40.0, 5.0, 0.0),
            vel(0.0, 100.0),
            vec![Segment::Cv { duration_s: 1000.0 }],
        );
        let mut f = flight(&ac);
        let s = f.state_at(1000.0);
        let arc = meridian_arc_m(s.lat_deg.to_radians()) - meridian_arc_m(40f64.to_radians());
        assert!((arc - 100_000.0).abs() < 1e-3, "{arc}");
        assert!((s.lon_deg - 5.0).abs() < 1e-12);
        assert_eq!(
            (s.ve_mps, s.vn_mps, s.vu_mps, s.mode),
            (0.0, 100.0, 0.0, FlightMode::Cv)
        );
    }

    #[test]
    fn along_the_equator_longitude_is_distance_over_radius() {
        // CA then JERK east on the equator at 10 km: Δlon = x / (a + h), with x the closed-form
        // distance s0 t + a t²/2, then v t + a t²/2 + j t³/6 (acceleration restarting at 0).
        let ac = aircraft(
            at(0.0, 10.0, 10_000.0),
            vel(200.0, 0.0),
            vec![
                Segment::Ca {
                    duration_s: 100.0,
                    accel_mps2: 2.0,
                },
                Segment::Jerk {
                    duration_s: 50.0,
                    jerk_east_mps3: 0.3,
                    jerk_north_mps3: 0.0,
                },
            ],
        );
        let mut f = flight(&ac);
        let r = wgs84::A_M + 10_000.0;
        let s = f.state_at(100.0);
        let x1 = 200.0 * 100.0 + 0.5 * 2.0 * 100.0 * 100.0;
        assert!(
            ((s.lon_deg - 10.0).to_radians() * r - x1).abs() < 1e-4,
            "{}",
            (s.lon_deg - 10.0).to_radians() * r - x1
        );
        assert!((s.ve_mps - 400.0).abs() < 1e-9 && s.mode == FlightMode::Ca);
        let s = f.state_at(150.0);
        let x2 = x1 + 400.0 * 50.0 + 0.3 * 50f64.powi(3) / 6.0;
        assert!(((s.lon_deg - 10.0).to_radians() * r - x2).abs() < 1e-4);
        assert!((s.ve_mps - (400.0 + 0.15 * 2500.0)).abs() < 1e-9);
        assert!(s.lat_deg.abs() < 1e-12 && (s.alt_m - 10_000.0).abs() < 1e-9);
    }

    #[test]
    fn full_circle_closes_and_has_the_right_radius() {
        // 3 deg/s for 120 s: one full circle of radius v/ω centred on the equator. It closes,
        // and half way it is one diameter (2 v/ω) from the start.
        let v = 150.0;
        let w = 3f64.to_radians();
        let r = v / w;
        // Start at the southernmost point of the circle heading east, turning left.
        let lat0 = -(r / 6_335_439.327_293).to_degrees();
        let ac = aircraft(
            at(lat0, 0.0, 0.0),
            vel(v, 0.0),
            vec![Segment::Ct {
                duration_s: 120.0,
                turn_rate_dps: 3.0,
                direction: TurnDirection::Left,
            }],
        );
        let mut f = flight(&ac);
        let half = f.state_at(60.0);
        let (m, _) = wgs84::radii_m(0.0);
        let dn = (half.lat_deg - lat0).to_radians() * m;
        assert!((dn - 2.0 * r).abs() < 0.05, "{dn} vs {}", 2.0 * r);
        assert!((half.ve_mps + v).abs() < 1e-9 && half.vn_mps.abs() < 1e-9);
        let end = f.state_at(120.0);
        let err_n = (end.lat_deg - lat0).to_radians() * m;
        let err_e = end.lon_deg.to_radians() * wgs84::A_M;
        assert!(err_n.abs() < 1e-3 && err_e.abs() < 1e-3, "{err_n} {err_e}");
        assert_eq!(end.mode, FlightMode::Ct);
    }

    #[test]
    fn climbs_and_accelerations_are_closed_forms() {
        let ac = aircraft(
            at(45.0, 7.0, 152.4),
            InitialVelocity {
                ground_speed_mps: Some(80.0),
                track_deg: Some(270.0),
                vertical_rate_mps: Some(10.0),
                ..InitialVelocity::default()
            },
            vec![
                Segment::Chca {
                    duration_s: 60.0,
                    vertical_rate_mps: 10.0,
                    accel_mps2: 0.5,
                },
                Segment::Ch {
                    duration_s: 100.0,
                    vertical_rate_mps: 12.0,
                },
            ],
        );
        let mut f = flight(&ac);
        let s = f.state_at(30.0);
        assert!((s.alt_m - 452.4).abs() < 1e-9 && s.mode == FlightMode::Chca);
        assert!((s.ve_mps + 95.0).abs() < 1e-9 && s.vn_mps.abs() < 1e-9 && s.vu_mps == 10.0);
        let s = f.state_at(160.0);
        assert!((s.alt_m - (152.4 + 600.0 + 1200.0)).abs() < 1e-9 && s.mode == FlightMode::Ch);
        assert!((s.ve_mps + 110.0).abs() < 1e-9);
    }

    #[test]
    fn state_does_not_depend_on_earlier_queries() {
        let ac = aircraft(
            at(30.0, 120.0, 9000.0),
            vel(50.0, 50.0),
            vec![
                Segment::Cv { duration_s: 200.0 },
                Segment::Ct {
                    duration_s: 200.0,
                    turn_rate_dps: 3.0,
                    direction: TurnDirection::Left,
                },
            ],
        );
        let mut a = flight(&ac);
        let mut b = flight(&ac);
        let mut last = a.state_at(0.0);
        for k in 0..3000 {
            last = a.state_at(f64::from(k) * 0.13 + 0.011);
        }
        let direct = b.state_at(last.t_s);
        assert_eq!(last, direct);
        // Going back in time restarts the integration and gives the same answer.
        let again = a.state_at(last.t_s);
        assert_eq!(a.state_at(12.3), b.state_at(12.3));
        assert_eq!(again, direct);
    }

    #[test]
    fn start_in_the_tangent_plane() {
        let ac = AircraftSpec {
            start: Start {
                east_m: Some(1000.0),
                north_m: Some(1000.0),
                up_m: Some(9000.0),
                ..Start::default()
            },
            ..aircraft(
                Start::default(),
                vel(50.0, 50.0),
                vec![Segment::Cv { duration_s: 10.0 }],
            )
        };
        let mut f = Flight::new(Trajectory::build(&ac, 0, &REF, 10.0).unwrap());
        let s = f.state_at(0.0);
        // At the equator, 1 km north/east: lat = atan-ish n / M, lon = e / a (to 1e-10 rad).
        assert!((s.lat_deg.to_radians() * 6_335_439.327_293 - 1000.0).abs() < 0.01);
        assert!((s.lon_deg.to_radians() * wgs84::A_M - 1000.0).abs() < 0.01);
        assert_eq!(s.alt_m, 9000.0);
    }
}
