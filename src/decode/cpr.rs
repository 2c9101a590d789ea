//! Compact Position Reporting (DO-260B Appendix A.1.7; ICAO Doc 9871 §C.2.6).
//!
//! An extended squitter carries latitude and longitude as 17-bit fractions of a zone
//! (YZ, XZ: ME bits 23-39 and 40-56; DO-260B §2.2.3.2.3 airborne, §2.2.3.2.4 surface).
//! The zones are 360°/(4·NZ − i) of latitude (i = 0 even, 1 odd) and 360°/max(NL(lat) − i, 1)
//! of longitude for airborne reports, and a quarter of that (90° spans) for surface reports,
//! which buys four times the resolution with the same 17 bits (A.1.7.2 and the encoding of A.1.7).
//!
//! Two ways back to degrees:
//! - globally unambiguous: one even and one odd report, close in time (A.1.7.7 airborne,
//!   A.1.7.8 surface). The surface solution is only defined modulo 90°, so a reference
//!   (the receiver, or the aircraft's last position) picks one of the four;
//! - locally unambiguous: one report and a reference within half a zone (180 NM airborne,
//!   45 NM surface; A.1.7.5).
//!
//! The pure functions ([`global_airborne`], [`global_surface`], [`local_airborne`],
//! [`local_surface`]) are the spec's algorithms. [`CprDecoder`] is the per-aircraft state the
//! daemon keeps: pairing, the choice between global and local decoding, and a plausibility
//! check against the last accepted position, with a way out of a bad first fix.

/// NZ: number of latitude zones between the equator and a pole (DO-260B A.1.7.2 b).
pub const NZ: f64 = 15.0;

/// 2^Nb with Nb = 17, the bits of an encoded coordinate (DO-260B A.1.7.2 a). YZ and XZ are
/// in `0..CPR_COUNT`; anything larger did not come from a 17-bit field.
pub const CPR_COUNT: u32 = 1 << 17;

/// [`CPR_COUNT`] as f64 (exact).
const CPR_COUNT_F64: f64 = 131_072.0;

/// Half of [`CPR_COUNT`]: the "+ 1/2" of the zone-index formulas in integer units.
const CPR_HALF_I64: i64 = 65_536;

/// Mean Earth radius (IUGG), metres: enough for a plausibility distance (error < 0.5 %).
const EARTH_MEAN_RADIUS_M: f64 = 6_371_008.8;

use super::Cpr;

/// NL(lat): number of longitude zones at a latitude (DO-260B A.1.7.2 d), in 1..=59.
///
/// Read from the table of transition latitudes ([`NL_TABLE`]) rather than the closed form:
/// a cosine and an arc cosine per position cost 4 % of the CPU of a fleet replay. The two
/// agree everywhere except within f64 rounding of a transition (tested), which is why
/// callers compare NL of both frames of a pair rather than trusting a boundary.
///
/// The latitude's quarter degree gives the NL at its lower edge, and one comparison with
/// that NL's transition says whether lat is past it: the transitions are at least 0.46°
/// apart, so a quarter degree holds at most one. No branch depends on the latitude (the
/// binary search over the 58 transitions it replaced mispredicted about half its six
/// branches: 2.9 % of a `kalman-cv` fleet replay's time, for 1.3 % of its instructions).
pub fn nl(lat_deg: f64) -> u32 {
    let lat = lat_deg.abs();
    if lat.is_nan() || lat >= 87.0 {
        return 1;
    }
    let table = &*NL_TABLE;
    // lat · 4 is exact (a power of two), so the quarter is exactly the one holding lat.
    let quarter = (lat * NL_QUARTERS_PER_DEG) as usize;
    let Some(&at_edge) = table.at_quarter.get(quarter) else {
        return 1;
    };
    // NL ≥ n exactly when |lat| ≤ the n-th transition (n = 2..=59).
    let transition = table
        .transitions_deg
        .get(usize::from(at_edge).wrapping_sub(2))
        .copied()
        .unwrap_or(f64::INFINITY);
    u32::from(at_edge) - u32::from(lat > transition)
}

/// Quarter degrees per degree: [`NlTable::at_quarter`]'s resolution, finer than the
/// closest two transitions (87° and 86.535°).
const NL_QUARTERS_PER_DEG: f64 = 4.0;

/// What [`nl`] reads.
struct NlTable {
    /// The latitudes where NL steps down, degrees, for NL = 2..=59 (decreasing): from the
    /// closed form of DO-260B A.1.7.2 d solved for the latitude,
    /// lat_n = acos(sqrt((1 − cos(π / 2NZ)) / (1 − cos(2π / n)))), the values of Table A-21
    /// (87.0, 86.535..., 85.755..., ..., 10.470...).
    transitions_deg: [f64; 58],
    /// NL at each quarter degree k/4, k = 0..348 (up to 87°): the NL of every latitude in
    /// [k/4, (k + 1)/4) up to the one transition the quarter may hold.
    at_quarter: [u8; 348],
}

/// Computed once, at first use.
static NL_TABLE: std::sync::LazyLock<NlTable> = std::sync::LazyLock::new(|| {
    let a = 1.0 - (std::f64::consts::PI / (2.0 * NZ)).cos();
    let mut transitions_deg = [0.0; 58];
    for (k, v) in transitions_deg.iter_mut().enumerate() {
        let n = (k + 2) as f64;
        let b = a / (1.0 - (2.0 * std::f64::consts::PI / n).cos());
        *v = b.sqrt().acos().to_degrees();
    }
    let mut at_quarter = [0u8; 348];
    for (k, nl) in at_quarter.iter_mut().enumerate() {
        let edge = k as f64 / NL_QUARTERS_PER_DEG;
        // 1 + the transitions at or above the edge: at most 59.
        *nl = 1 + transitions_deg.iter().filter(|&&t| t >= edge).count() as u8;
    }
    NlTable {
        transitions_deg,
        at_quarter,
    }
});

/// NL by a binary search over the transitions: what [`nl`] computed before its quarter-degree
/// table, which it is tested equal to at every latitude, transitions included.
#[cfg(test)]
fn nl_search(lat_deg: f64) -> u32 {
    let lat = lat_deg.abs();
    if lat.is_nan() || lat >= 87.0 {
        return 1;
    }
    let above = NL_TABLE.transitions_deg.partition_point(|&t| t >= lat) as u32;
    (1 + above).clamp(1, 59)
}

/// NL from the closed form, DO-260B A.1.7.2 d: floor(2π / acos(1 − (1 − cos(π/2NZ)) /
/// cos²(π lat / 180))). The reference [`nl`] is tested against.
#[cfg(test)]
fn nl_closed_form(lat_deg: f64) -> u32 {
    let lat = lat_deg.abs();
    if lat.is_nan() || lat >= 87.0 {
        return 1;
    }
    if lat == 0.0 {
        return 59;
    }
    let a = 1.0 - (std::f64::consts::PI / (2.0 * NZ)).cos();
    let b = (std::f64::consts::PI / 180.0 * lat).cos().powi(2);
    let x = 1.0 - a / b;
    if !(-1.0..=1.0).contains(&x) {
        return 1;
    }
    let n = (2.0 * std::f64::consts::PI / x.acos()).floor();
    (n as u32).clamp(1, 59)
}

/// The angular span the zones divide: 360° airborne, 90° surface (DO-260B A.1.7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Span {
    Airborne,
    Surface,
}

impl Span {
    fn deg(self) -> f64 {
        match self {
            Span::Airborne => 360.0,
            Span::Surface => 90.0,
        }
    }
}

/// MOD(x, y) = x − y·floor(x/y), always in [0, y) for y > 0 (DO-260B A.1.7.2 e).
fn modulo(x: f64, y: f64) -> f64 {
    x - y * (x / y).floor()
}

/// A longitude folded into [-180, 180).
fn wrap_lon(lon_deg: f64) -> f64 {
    modulo(lon_deg + 180.0, 360.0) - 180.0
}

/// i of the spec: 0 for an even frame, 1 for odd.
fn parity_index(odd: bool) -> u32 {
    u32::from(odd)
}

/// Dlat_i = span / (4·NZ − i) (DO-260B A.1.7 encoding; 360° airborne, 90° surface).
fn dlat(span: Span, odd: bool) -> f64 {
    span.deg() / (4.0 * NZ - f64::from(parity_index(odd)))
}

/// Dlon_i = span / max(NL(lat) − i, 1) (DO-260B A.1.7 encoding).
fn dlon(span: Span, lat_deg: f64, odd: bool) -> f64 {
    span.deg() / f64::from(nl(lat_deg).saturating_sub(parity_index(odd)).max(1))
}

/// A usable reference: finite, latitude within ±90°, longitude within ±360° (so that the zone
/// arithmetic stays exact; any longitude convention, [-180, 180) or [0, 360), works).
fn reference_is_valid(lat_deg: f64, lon_deg: f64) -> bool {
    lat_deg.is_finite() && lon_deg.is_finite() && lat_deg.abs() <= 90.0 && lon_deg.abs() <= 360.0
}

/// YZ/2^17 or XZ/2^17, `None` for a value a 17-bit field cannot hold.
fn fraction(v: u32) -> Option<f64> {
    (v < CPR_COUNT).then(|| f64::from(v) / CPR_COUNT_F64)
}

/// Why a decode produced no position.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RejectReason {
    /// An encoded coordinate ≥ 2^17, or a pair whose parity flags are not one even and one odd.
    InvalidCpr,
    /// A non-finite time, or a time before the aircraft's last accepted position.
    BadTime,
    /// The two latitudes of a pair lie in different NL zones: the aircraft crossed a zone
    /// boundary between the two reports and the longitude would be wrong (A.1.7.7).
    ZoneMismatch,
    /// The decoded latitude is outside ±90°, or the reference is unusable (non-finite,
    /// latitude outside ±90°, longitude outside ±360°).
    LatitudeOutOfRange,
    /// The position implies a speed above the configured maximum since the last accepted one.
    ImpossibleSpeed,
}

/// The latitude of each frame of a pair (A.1.7.7; for the surface, A.1.7.8, with the
/// northern-hemisphere solution in [0°, 90°)).
fn pair_latitudes(even: Cpr, odd: Cpr, span: Span) -> Result<(f64, f64), RejectReason> {
    if even.odd || !odd.odd {
        return Err(RejectReason::InvalidCpr);
    }
    let (Some(yz0), Some(yz1)) = (fraction(even.lat), fraction(odd.lat)) else {
        return Err(RejectReason::InvalidCpr);
    };
    // j = floor(59·YZ0/2^17 − 60·YZ1/2^17 + 1/2), computed exactly in integers
    // (both YZ < 2^17, so the products fit easily in i64).
    let j = (59 * i64::from(even.lat) - 60 * i64::from(odd.lat) + CPR_HALF_I64)
        .div_euclid(i64::from(CPR_COUNT));
    let rlat0 = dlat(span, false) * (j.rem_euclid(60) as f64 + yz0);
    let rlat1 = dlat(span, true) * (j.rem_euclid(59) as f64 + yz1);
    Ok((rlat0, rlat1))
}

/// The longitude of the latest frame of a pair, in [0°, span) (A.1.7.7, A.1.7.8).
/// `lat_deg` is the latest frame's latitude; both latitudes have the same NL (checked).
fn pair_longitude(
    even: Cpr,
    odd: Cpr,
    latest_is_odd: bool,
    lat_deg: f64,
    span: Span,
) -> Result<f64, RejectReason> {
    let (Some(xz0), Some(xz1)) = (fraction(even.lon), fraction(odd.lon)) else {
        return Err(RejectReason::InvalidCpr);
    };
    let nl_lat = nl(lat_deg);
    let ni = nl_lat.saturating_sub(parity_index(latest_is_odd)).max(1);
    // m = floor(XZ0·(NL − 1)/2^17 − XZ1·NL/2^17 + 1/2), exactly in integers.
    let m = (i64::from(even.lon) * (i64::from(nl_lat) - 1)
        - i64::from(odd.lon) * i64::from(nl_lat)
        + CPR_HALF_I64)
        .div_euclid(i64::from(CPR_COUNT));
    let xz = if latest_is_odd { xz1 } else { xz0 };
    Ok(span.deg() / f64::from(ni) * (m.rem_euclid(i64::from(ni)) as f64 + xz))
}

fn global_airborne_checked(
    even: Cpr,
    odd: Cpr,
    latest_is_odd: bool,
) -> Result<(f64, f64), RejectReason> {
    let (mut rlat0, mut rlat1) = pair_latitudes(even, odd, Span::Airborne)?;
    // Southern latitudes come out in [270°, 360°) (A.1.7.7).
    if rlat0 >= 270.0 {
        rlat0 -= 360.0;
    }
    if rlat1 >= 270.0 {
        rlat1 -= 360.0;
    }
    if rlat0.abs() > 90.0 || rlat1.abs() > 90.0 {
        return Err(RejectReason::LatitudeOutOfRange);
    }
    if nl(rlat0) != nl(rlat1) {
        return Err(RejectReason::ZoneMismatch);
    }
    let lat = if latest_is_odd { rlat1 } else { rlat0 };
    let lon = pair_longitude(even, odd, latest_is_odd, lat, Span::Airborne)?;
    Ok((lat, wrap_lon(lon)))
}

/// Globally unambiguous airborne decoding of an even/odd pair (DO-260B A.1.7.7).
///
/// Returns the position of the latest frame (`latest_is_odd`) in degrees, longitude in
/// [-180, 180). `None` when the flags are not one even and one odd, a field is ≥ 2^17, the
/// latitude is out of range, or the two latitudes have different NL (the aircraft crossed
/// a longitude-zone boundary between the frames: no valid longitude, wait for another pair).
/// The caller ensures the two frames are close in time (10 s, see [`CprConfig::pair_window_s`]).
pub fn global_airborne(even: Cpr, odd: Cpr, latest_is_odd: bool) -> Option<(f64, f64)> {
    global_airborne_checked(even, odd, latest_is_odd).ok()
}

fn global_surface_checked(
    even: Cpr,
    odd: Cpr,
    latest_is_odd: bool,
    ref_lat_deg: f64,
    ref_lon_deg: f64,
) -> Result<(f64, f64), RejectReason> {
    if !reference_is_valid(ref_lat_deg, ref_lon_deg) {
        return Err(RejectReason::LatitudeOutOfRange);
    }
    let (rlat0, rlat1) = pair_latitudes(even, odd, Span::Surface)?;
    // Each latitude is known modulo 90°: the northern solution in [0°, 90°) or the southern
    // one 90° below; the reference picks the hemisphere (A.1.7.8).
    let latest = if latest_is_odd { rlat1 } else { rlat0 };
    let shift = if (latest - 90.0 - ref_lat_deg).abs() < (latest - ref_lat_deg).abs() {
        -90.0
    } else {
        0.0
    };
    let (rlat0, rlat1, lat) = (rlat0 + shift, rlat1 + shift, latest + shift);
    if nl(rlat0) != nl(rlat1) {
        return Err(RejectReason::ZoneMismatch);
    }
    let lon_quadrant = pair_longitude(even, odd, latest_is_odd, lat, Span::Surface)?;
    // Four longitudes 90° apart; the one nearest the reference (A.1.7.8).
    let mut best_lon = wrap_lon(lon_quadrant);
    let mut best_dist = wrap_lon(best_lon - ref_lon_deg).abs();
    for k in 1..4 {
        let lon = wrap_lon(lon_quadrant + 90.0 * f64::from(k));
        let dist = wrap_lon(lon - ref_lon_deg).abs();
        if dist < best_dist {
            best_lon = lon;
            best_dist = dist;
        }
    }
    Ok((lat, best_lon))
}

/// Globally unambiguous surface decoding of an even/odd pair (DO-260B A.1.7.8).
///
/// The pair fixes the position modulo 90° of latitude and longitude; the reference
/// (receiver or last known position, anywhere within ~45° of the aircraft) picks the
/// solution. `None` on the same conditions as [`global_airborne`] or a non-finite reference.
pub fn global_surface(
    even: Cpr,
    odd: Cpr,
    latest_is_odd: bool,
    ref_lat_deg: f64,
    ref_lon_deg: f64,
) -> Option<(f64, f64)> {
    global_surface_checked(even, odd, latest_is_odd, ref_lat_deg, ref_lon_deg).ok()
}

/// Locally unambiguous decoding of one frame against a reference (A.1.7.5):
/// j = floor(ref/Dlat) + floor(1/2 + MOD(ref, Dlat)/Dlat − YZ/2^17), lat = Dlat·(j + YZ/2^17),
/// and likewise for the longitude with Dlon(lat).
fn local(cpr: Cpr, ref_lat_deg: f64, ref_lon_deg: f64, span: Span) -> Option<(f64, f64)> {
    let yz = fraction(cpr.lat)?;
    let xz = fraction(cpr.lon)?;
    if !reference_is_valid(ref_lat_deg, ref_lon_deg) {
        return None;
    }
    let dlat = dlat(span, cpr.odd);
    // floor(ref/Dlat) and MOD(ref, Dlat)/Dlat taken from the same quotient, so that they stay
    // consistent when ref sits on a zone edge (pyModeS's "numerical challenge" case).
    let q_lat = ref_lat_deg / dlat;
    let j = q_lat.floor() + (0.5 + (q_lat - q_lat.floor()) - yz).floor();
    let lat = dlat * (j + yz);
    if lat.abs() > 90.0 {
        return None;
    }
    let dlon = dlon(span, lat, cpr.odd);
    let q_lon = ref_lon_deg / dlon;
    let m = q_lon.floor() + (0.5 + (q_lon - q_lon.floor()) - xz).floor();
    Some((lat, wrap_lon(dlon * (m + xz))))
}

/// Locally unambiguous airborne decoding (DO-260B A.1.7.5): valid when the reference is within
/// 180 NM (half a zone) of the aircraft. `None` for a field ≥ 2^17 or a reference or result
/// outside ±90° latitude. Longitude in [-180, 180).
pub fn local_airborne(cpr: Cpr, ref_lat_deg: f64, ref_lon_deg: f64) -> Option<(f64, f64)> {
    local(cpr, ref_lat_deg, ref_lon_deg, Span::Airborne)
}

/// Locally unambiguous surface decoding (DO-260B A.1.7.5 with the surface Dlat/Dlon): the zones span 90°, so the
/// reference must be within 45 NM; among the solutions 1.5° (lat) and 90°/NL (lon) apart it
/// picks the one nearest the reference. `None` as for [`local_airborne`].
pub fn local_surface(cpr: Cpr, ref_lat_deg: f64, ref_lon_deg: f64) -> Option<(f64, f64)> {
    local(cpr, ref_lat_deg, ref_lon_deg, Span::Surface)
}

/// Great-circle distance on the mean sphere (haversine), metres.
pub fn haversine_m(lat1_deg: f64, lon1_deg: f64, lat2_deg: f64, lon2_deg: f64) -> f64 {
    let (p1, p2) = (lat1_deg.to_radians(), lat2_deg.to_radians());
    let dp = p2 - p1;
    let dl = (lon2_deg - lon1_deg).to_radians();
    let h = (dp / 2.0).sin().powi(2) + p1.cos() * p2.cos() * (dl / 2.0).sin().powi(2);
    2.0 * EARTH_MEAN_RADIUS_M * h.clamp(0.0, 1.0).sqrt().asin()
}

/// Whether (lat, lon) is within `allowed_m` of (lat0, lon0) by [`haversine_m`], the same
/// answer for every input (NaN: no), usually without its trigonometry.
///
/// A path along the meridian and then along a parallel is at least as long as the great
/// circle, and a parallel's degree is at most the equator's: so R (|Δφ| + |Δλ|), in radians,
/// bounds the distance from above with one multiplication. A report half a second after the
/// last one is well inside that bound's allowance; only a fix near the limit (or across the
/// antimeridian, where |Δλ| is near 360°) takes the haversine. The bound is compared with a
/// margin of 10⁻⁹ of itself, a million times the haversine's rounding, so that a computed
/// haversine could never exceed the allowance where the bound does not.
fn within_m(lat0_deg: f64, lon0_deg: f64, lat_deg: f64, lon_deg: f64, allowed_m: f64) -> bool {
    let bound_m = EARTH_MEAN_RADIUS_M
        * ((lat_deg - lat0_deg).abs() + (lon_deg - lon0_deg).abs()).to_radians();
    if bound_m * (1.0 + 1e-9) <= allowed_m {
        return true;
    }
    let distance_m = haversine_m(lat0_deg, lon0_deg, lat_deg, lon_deg);
    !(distance_m.is_nan() || distance_m > allowed_m)
}

/// Tuning of [`CprDecoder`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CprConfig {
    /// Longest time between the even and odd airborne frames of a global pair, s. DO-260B
    /// pairs airborne frames over at most 10 s: at 600 kt the aircraft moves ~3 km, inside the tolerance of
    /// the zone index j.
    pub pair_window_s: f64,
    /// The same for surface frames, s: 25 s, the usual limit for a moving surface target
    /// (surface speeds are ten times lower, and surface zones four times smaller).
    pub surface_pair_window_s: f64,
    /// Highest plausible airborne speed, m/s: 700 m/s is about Mach 2 at altitude, so a
    /// position farther than that from the last one is a decoding error, not an aircraft.
    pub max_speed_mps: f64,
    /// Highest plausible speed between two surface fixes, m/s. The surface movement field
    /// tops out at 175 kt (90 m/s, DO-260B §2.2.3.2.4); 100 m/s leaves room for the take-off roll.
    pub max_surface_speed_mps: f64,
    /// Receiver (or airport) location, degrees: the reference for the first surface fix.
    pub receiver: Option<(f64, f64)>,
    /// Longest age of the last accepted position for it to serve as the local-decoding
    /// reference, s. Local decoding is unambiguous within half a zone (180 NM airborne, 45 NM
    /// surface); 60 s at Mach 2 is 42 km, far inside either.
    pub local_max_age_s: f64,
    /// Distance allowed on top of speed × dt, metres: CPR quantisation (5.1 m airborne,
    /// 1.3 m surface: Dlat/2^17), GNSS error on both fixes and receive-time jitter, so that
    /// two reports a few milliseconds apart are not rejected.
    pub position_slack_m: f64,
    /// After this many consecutive implausible positions the last accepted one is dropped
    /// and a fresh global decode starts over, so one bad first fix cannot lock the aircraft out.
    pub rejections_before_reset: u32,
}

impl Default for CprConfig {
    fn default() -> Self {
        Self {
            pair_window_s: 10.0,
            surface_pair_window_s: 25.0,
            max_speed_mps: 700.0,
            max_surface_speed_mps: 100.0,
            receiver: None,
            local_max_age_s: 60.0,
            position_slack_m: 100.0,
            rejections_before_reset: 4,
        }
    }
}

/// The outcome of one position report.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PositionFix {
    /// A position, degrees (longitude in [-180, 180)); `global` when it came from an
    /// even/odd pair rather than from a reference.
    Accepted {
        lat_deg: f64,
        lon_deg: f64,
        global: bool,
    },
    /// Not enough yet: waiting for the other frame of a pair, or for a reference.
    Pending,
    /// Refused, for this reason (counted in [`CprStats`]).
    Rejected(RejectReason),
}

/// What a [`CprDecoder`] did with the reports it was given.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CprStats {
    /// Positions accepted from an even/odd pair.
    pub accepted_global: u64,
    /// Positions accepted from one frame and a reference.
    pub accepted_local: u64,
    /// Reports that produced no position yet.
    pub pending: u64,
    /// Rejections: [`RejectReason::InvalidCpr`].
    pub invalid_cpr: u64,
    /// Rejections: [`RejectReason::BadTime`].
    pub bad_time: u64,
    /// Rejections: [`RejectReason::ZoneMismatch`].
    pub zone_mismatch: u64,
    /// Rejections: [`RejectReason::LatitudeOutOfRange`].
    pub latitude_out_of_range: u64,
    /// Rejections: [`RejectReason::ImpossibleSpeed`].
    pub impossible_speed: u64,
    /// Times the last accepted position was dropped after repeated rejections.
    pub resets: u64,
}

impl CprStats {
    fn count(&mut self, reason: RejectReason) {
        let counter = match reason {
            RejectReason::InvalidCpr => &mut self.invalid_cpr,
            RejectReason::BadTime => &mut self.bad_time,
            RejectReason::ZoneMismatch => &mut self.zone_mismatch,
            RejectReason::LatitudeOutOfRange => &mut self.latitude_out_of_range,
            RejectReason::ImpossibleSpeed => &mut self.impossible_speed,
        };
        *counter = counter.saturating_add(1);
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Frame {
    t_s: f64,
    cpr: Cpr,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Fix {
    t_s: f64,
    lat_deg: f64,
    lon_deg: f64,
    surface: bool,
}

/// The latest even and odd frame of one kind (airborne or surface; they never pair).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct PairSlots {
    even: Option<Frame>,
    odd: Option<Frame>,
}

impl PairSlots {
    /// Stores `frame` and returns its partner when the partner is at most `window_s` older.
    fn store(&mut self, frame: Frame, window_s: f64) -> Option<Frame> {
        let (mine, other) = if frame.cpr.odd {
            (&mut self.odd, self.even)
        } else {
            (&mut self.even, self.odd)
        };
        *mine = Some(frame);
        other.filter(|p| {
            let age_s = frame.t_s - p.t_s;
            (0.0..=window_s).contains(&age_s)
        })
    }
}

/// Per-aircraft CPR state (DESIGN.md: the aircraft task owns one).
///
/// Policy, in order:
/// 1. a frame whose other-parity partner arrived within the pair window is decoded globally
///    (A.1.7.7 / A.1.7.8), even when a reference exists: a global decode depends on nothing
///    remembered, so it is what exposes a wrong reference;
/// 2. otherwise (or when the pair straddles an NL boundary) it is decoded locally against the
///    last accepted position while that is recent, and surface frames also against the
///    receiver (A.1.7.5);
/// 3. every candidate is checked against the last accepted position: farther than
///    speed × dt + slack is rejected; after `rejections_before_reset` consecutive rejections
///    the last position is forgotten and the next global decode starts afresh.
#[derive(Clone, Debug, PartialEq)]
pub struct CprDecoder {
    config: CprConfig,
    airborne_frames: PairSlots,
    surface_frames: PairSlots,
    last: Option<Fix>,
    consecutive_rejections: u32,
    stats: CprStats,
}

impl CprDecoder {
    /// A decoder that knows nothing of the aircraft yet.
    pub fn new(config: CprConfig) -> Self {
        Self {
            config,
            airborne_frames: PairSlots::default(),
            surface_frames: PairSlots::default(),
            last: None,
            consecutive_rejections: 0,
            stats: CprStats::default(),
        }
    }

    /// Counters since creation.
    pub fn stats(&self) -> &CprStats {
        &self.stats
    }

    /// An airborne position report (TC 9-18, 20-22) received at feed time `t_s`.
    pub fn airborne(&mut self, t_s: f64, cpr: Cpr) -> PositionFix {
        self.decode(t_s, cpr, Span::Airborne)
    }

    /// A surface position report (TC 5-8) received at feed time `t_s`.
    pub fn surface(&mut self, t_s: f64, cpr: Cpr) -> PositionFix {
        self.decode(t_s, cpr, Span::Surface)
    }

    fn decode(&mut self, t_s: f64, cpr: Cpr, span: Span) -> PositionFix {
        if !t_s.is_finite() || self.last.is_some_and(|l| t_s < l.t_s) {
            return self.reject(RejectReason::BadTime);
        }
        if fraction(cpr.lat).is_none() || fraction(cpr.lon).is_none() {
            return self.reject(RejectReason::InvalidCpr);
        }
        let frame = Frame { t_s, cpr };
        let recent = self
            .last
            .filter(|l| t_s - l.t_s <= self.config.local_max_age_s)
            .map(|l| (l.lat_deg, l.lon_deg));
        let candidate = match span {
            Span::Airborne => {
                let partner = self.airborne_frames.store(frame, self.config.pair_window_s);
                Self::candidate(cpr, partner, None, recent, span)
            }
            Span::Surface => {
                let partner = self
                    .surface_frames
                    .store(frame, self.config.surface_pair_window_s);
                // Any last position, however old, is within 45° of the aircraft and so picks
                // the right global solution; only a recent one is safe for local decoding.
                let any_ref = self
                    .last
                    .map(|l| (l.lat_deg, l.lon_deg))
                    .or(self.config.receiver);
                let local_ref = recent.or(self.config.receiver);
                Self::candidate(cpr, partner, any_ref, local_ref, span)
            }
        };
        match candidate {
            None => {
                self.stats.pending = self.stats.pending.saturating_add(1);
                PositionFix::Pending
            }
            Some(Err(reason)) => self.reject(reason),
            Some(Ok((lat_deg, lon_deg, global))) => {
                self.check_and_accept(t_s, lat_deg, lon_deg, global, span == Span::Surface)
            }
        }
    }

    /// The decoded position before the plausibility check: `None` when nothing can be decoded
    /// yet, `Some(Err)` when decoding failed. `global_ref` is only used by surface pairs.
    fn candidate(
        cpr: Cpr,
        partner: Option<Frame>,
        global_ref: Option<(f64, f64)>,
        local_ref: Option<(f64, f64)>,
        span: Span,
    ) -> Option<Result<(f64, f64, bool), RejectReason>> {
        let global = partner.and_then(|p| {
            let (even, odd) = if cpr.odd { (p.cpr, cpr) } else { (cpr, p.cpr) };
            match span {
                Span::Airborne => Some(global_airborne_checked(even, odd, cpr.odd)),
                Span::Surface => global_ref
                    .map(|(lat, lon)| global_surface_checked(even, odd, cpr.odd, lat, lon)),
            }
        });
        if let Some(Ok((lat, lon))) = global {
            return Some(Ok((lat, lon, true)));
        }
        // Decoded locally only when the pair gave nothing (computed for every report and
        // then dropped, it was 3 % of a `kalman-cv` fleet replay's instructions).
        let local = local_ref.map(|(lat, lon)| {
            local(cpr, lat, lon, span)
                .map(|(la, lo)| (la, lo, false))
                .ok_or(RejectReason::LatitudeOutOfRange)
        });
        match (global, local) {
            // A pair that straddles a zone boundary: the local decode still works.
            (_, Some(local)) => Some(local),
            (Some(Err(e)), None) => Some(Err(e)),
            (_, None) => None,
        }
    }

    fn check_and_accept(
        &mut self,
        t_s: f64,
        lat_deg: f64,
        lon_deg: f64,
        global: bool,
        surface: bool,
    ) -> PositionFix {
        if let Some(last) = self.last {
            let max_speed_mps = if surface && last.surface {
                self.config.max_surface_speed_mps
            } else {
                self.config.max_speed_mps
            };
            let allowed_m = max_speed_mps * (t_s - last.t_s) + self.config.position_slack_m;
            if !within_m(last.lat_deg, last.lon_deg, lat_deg, lon_deg, allowed_m) {
                self.consecutive_rejections = self.consecutive_rejections.saturating_add(1);
                if self.consecutive_rejections >= self.config.rejections_before_reset {
                    self.last = None;
                    self.consecutive_rejections = 0;
                    self.stats.resets = self.stats.resets.saturating_add(1);
                }
                return self.reject(RejectReason::ImpossibleSpeed);
            }
        }
        self.consecutive_rejections = 0;
        self.last = Some(Fix {
            t_s,
            lat_deg,
            lon_deg,
            surface,
        });
        let counter = if global {
            &mut self.stats.accepted_global
        } else {
            &mut self.stats.accepted_local
        };
        *counter = counter.saturating_add(1);
        PositionFix::Accepted {
            lat_deg,
            lon_deg,
            global,
        }
    }

    fn reject(&mut self, reason: RejectReason) -> PositionFix {
        self.stats.count(reason);
        PositionFix::Rejected(reason)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The CPR fields of a DF17 frame given as 28 hex digits: ME is bytes 4..11; F is ME bit
    /// 22, YZ ME bits 23-39, XZ ME bits 40-56 (DO-260B §2.2.3.2.3), read here by hand.
    fn cpr_of(hex: &str) -> Cpr {
        let me = u64::from_str_radix(&hex[8..22], 16).unwrap();
        Cpr {
            lat: ((me >> 17) & 0x1_FFFF) as u32,
            lon: (me & 0x1_FFFF) as u32,
            odd: (me >> 34) & 1 == 1,
        }
    }

    fn close(a: (f64, f64), b: (f64, f64), tol_deg: f64) -> bool {
        (a.0 - b.0).abs() <= tol_deg && (a.1 - b.1).abs() <= tol_deg
    }

    #[test]
    fn nl_table_equals_the_closed_form() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(17);
        let near_transition = |lat: f64| {
            NL_TABLE
                .transitions_deg
                .iter()
                .any(|t| (lat.abs() - t).abs() < 1e-9)
        };
        let mut checked = 0;
        for i in 0..2_000_000 {
            let lat: f64 = if i % 2 == 0 {
                rng.gen_range(-90.0..90.0)
            } else {
                // Close to a transition: within a micro-degree of one.
                let t = NL_TABLE.transitions_deg[rng.gen_range(0..58)];
                t + rng.gen_range(-1e-6..1e-6)
            };
            if near_transition(lat) {
                continue;
            }
            assert_eq!(nl(lat), nl_closed_form(lat), "{lat}");
            checked += 1;
        }
        assert!(checked > 1_990_000);
        for lat in [0.0, -0.0, 87.0, 90.0, -90.0, f64::NAN, 10.470_471_30] {
            assert_eq!(nl(lat), nl_closed_form(lat), "{lat}");
        }
        // Table A-21's first and last transitions.
        assert!((NL_TABLE.transitions_deg[0] - 87.0).abs() < 1e-9);
        assert!((NL_TABLE.transitions_deg[57] - 10.470_471_30).abs() < 1e-8);
    }

    /// The quarter-degree table gives the binary search's NL everywhere, to the last bit of
    /// the latitude: at each transition and the ulps around it, at each quarter's edge and
    /// the ulps around it, and at random latitudes.
    #[test]
    fn nl_table_equals_the_search() {
        use rand::{Rng, SeedableRng};
        let t = &NL_TABLE.transitions_deg;
        // At most one transition per quarter degree.
        assert!(t
            .windows(2)
            .all(|w| w[0] - w[1] > 1.0 / NL_QUARTERS_PER_DEG));
        let around = |x: f64| {
            let mut v = vec![x];
            let (mut up, mut down) = (x, x);
            for _ in 0..4 {
                up = up.next_up();
                down = down.next_down();
                v.extend([up, down]);
            }
            v
        };
        let edges = (0..=348).map(|k| f64::from(k) / NL_QUARTERS_PER_DEG);
        for lat in t.iter().copied().chain(edges).flat_map(around) {
            assert_eq!(nl(lat), nl_search(lat), "{lat}");
            assert_eq!(nl(-lat), nl_search(-lat), "{lat}");
        }
        let mut rng = rand::rngs::StdRng::seed_from_u64(29);
        for _ in 0..1_000_000 {
            let lat: f64 = rng.gen_range(-90.0..90.0);
            assert_eq!(nl(lat), nl_search(lat), "{lat}");
        }
        for lat in [
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            87.0,
            1e300,
            -0.0,
        ] {
            assert_eq!(nl(lat), nl_search(lat), "{lat}");
        }
    }

    #[test]
    fn nl_matches_transition_table() {
        // DO-260B Table A-21: NL changes at these latitudes.
        assert_eq!(nl(0.0), 59);
        assert_eq!(nl(10.47), 59);
        assert_eq!(nl(10.48), 58);
        assert_eq!(nl(52.0), 36);
        assert_eq!(nl(86.9), 2);
        assert_eq!(nl(87.0), 1);
        assert_eq!(nl(-52.0), 36);
    }

    #[test]
    fn field_extraction_matches_published_values() {
        // "The 1090 MHz Riddle" (Sun), airborne position chapter: YZ/XZ of the textbook pair.
        let even = cpr_of("8D40621D58C382D690C8AC2863A7");
        let odd = cpr_of("8D40621D58C386435CC412692AD6");
        assert_eq!(
            even,
            Cpr {
                lat: 93000,
                lon: 51372,
                odd: false
            }
        );
        assert_eq!(
            odd,
            Cpr {
                lat: 74158,
                lon: 50194,
                odd: true
            }
        );
    }

    #[test]
    fn textbook_pair_decodes_globally() {
        // The 1090 MHz Riddle / pyModeS: even then odd, the even one latest -> 52.2572, 3.9194.
        let even = cpr_of("8D40621D58C382D690C8AC2863A7");
        let odd = cpr_of("8D40621D58C386435CC412692AD6");
        let pos = global_airborne(even, odd, false).unwrap();
        assert!(close(pos, (52.25720, 3.91937), 5e-5), "{pos:?}");
        // Swapped parity flags are refused, not decoded.
        assert_eq!(global_airborne(odd, even, false), None);
    }

    #[test]
    fn pymodes_pair_and_local_reference() {
        // pyModeS tests/test_adsb.py: pair -> (49.81755, 6.08442) with the odd frame latest;
        // each frame against the reference (49.0, 6.0) -> (49.82410, 6.06785) / (49.81755, 6.08442).
        let even = cpr_of("8D40058B58C901375147EFD09357");
        let odd = cpr_of("8D40058B58C904A87F402D3B8C59");
        let pos = global_airborne(even, odd, true).unwrap();
        assert!(close(pos, (49.81755, 6.08442), 1e-5), "{pos:?}");
        let e = local_airborne(even, 49.0, 6.0).unwrap();
        assert!(close(e, (49.82410, 6.06785), 1e-5), "{e:?}");
        let o = local_airborne(odd, 49.0, 6.0).unwrap();
        assert!(close(o, (49.81755, 6.08442), 1e-5), "{o:?}");
    }

    #[test]
    fn local_airborne_reference_on_zone_edge() {
        // pyModeS "numerical challenge": the reference latitude is 5·360/59 up to rounding.
        let cpr = cpr_of("8D06A15358BF17FF7D4A84B47B95");
        let pos = local_airborne(cpr, 30.508474576271183, 7.2 * 5.0 + 3e-15).unwrap();
        assert!(close(pos, (30.50540, 33.44787), 1e-5), "{pos:?}");
    }

    #[test]
    fn surface_examples_from_pymodes() {
        // pyModeS tests/test_adsb.py: odd frame with reference (-43.5, 172.5) and the even/odd
        // pair with receiver (-43.496, 172.558), both -> (-43.48564, 172.53942).
        let even = cpr_of("8CC8200A3AC8F009BCDEF2000000");
        let odd = cpr_of("8FC8200A3AB8F5F893096B000000");
        assert!(!even.odd && odd.odd);
        let local = local_surface(odd, -43.5, 172.5).unwrap();
        assert!(close(local, (-43.48564, 172.53942), 1e-5), "{local:?}");
        let global = global_surface(even, odd, true, -43.496, 172.558).unwrap();
        assert!(close(global, (-43.48564, 172.53942), 1e-5), "{global:?}");
        // The other three longitude solutions are 90° away: a reference in another quadrant
        // picks another one, which is why surface decoding needs a reference at all.
        let far = global_surface(even, odd, true, -43.5, 172.5 - 90.0).unwrap();
        assert!(close(far, (-43.48564, 82.53942), 1e-5), "{far:?}");
    }

    #[test]
    fn no_panic_on_out_of_range_fields() {
        let bad = Cpr {
            lat: u32::MAX,
            lon: CPR_COUNT,
            odd: false,
        };
        let good = Cpr {
            lat: 0,
            lon: 0,
            odd: true,
        };
        assert_eq!(global_airborne(bad, good, true), None);
        assert_eq!(local_airborne(bad, 52.0, 4.0), None);
        assert_eq!(local_surface(bad, 52.0, 4.0), None);
        assert_eq!(local_airborne(good, f64::NAN, 4.0), None);
        assert_eq!(local_airborne(good, 52.0, 1e300), None);
        let even0 = Cpr { odd: false, ..good };
        assert!(global_surface(even0, good, true, 52.0, 4.0).is_some());
        assert_eq!(global_surface(even0, good, true, 52.0, -361.0), None);
        assert_eq!(global_surface(bad, good, true, 52.0, 4.0), None);
        let mut dec = CprDecoder::new(CprConfig::default());
        assert_eq!(
            dec.airborne(0.0, bad),
            PositionFix::Rejected(RejectReason::InvalidCpr)
        );
        assert_eq!(
            dec.surface(f64::NAN, good),
            PositionFix::Rejected(RejectReason::BadTime)
        );
        assert_eq!(dec.stats().invalid_cpr, 1);
        assert_eq!(dec.stats().bad_time, 1);
        // Every corner value through every path: no panic, and anything decoded is in range.
        let values = [0, 1, CPR_COUNT / 2, CPR_COUNT - 1, CPR_COUNT, u32::MAX];
        for &lat in &values {
            for &lon in &values {
                for odd in [false, true] {
                    let cpr = Cpr { lat, lon, odd };
                    for (la, lo) in [
                        local_airborne(cpr, 89.9, 179.9),
                        local_surface(cpr, -89.9, -180.0),
                    ]
                    .into_iter()
                    .flatten()
                    {
                        assert!(la.abs() <= 90.0 && (-180.0..180.0).contains(&lo));
                    }
                    if let Some((la, lo)) = global_airborne(cpr, Cpr { odd: true, ..good }, odd) {
                        assert!(la.abs() <= 90.0 && (-180.0..180.0).contains(&lo));
                    }
                    let _ = dec.airborne(1.0, cpr);
                    let _ = dec.surface(1.0, cpr);
                }
            }
        }
    }

    #[test]
    fn zone_mismatch_is_refused() {
        // Even frame encoded at 51.89° (NL 37 side), odd at 51.90° (NL 36 side): the boundary
        // NL 37/36 lies at 51.8934° (Table A-21), so the pair straddles it.
        let enc = |lat_deg: f64, odd: bool| {
            let d = 360.0 / (60.0 - f64::from(u32::from(odd)));
            let yz = (CPR_COUNT_F64 * modulo(lat_deg, d) / d + 0.5).floor() as u32 % CPR_COUNT;
            Cpr {
                lat: yz,
                lon: 0,
                odd,
            }
        };
        assert_eq!(nl(51.89), 37);
        assert_eq!(nl(51.90), 36);
        assert_eq!(
            global_airborne_checked(enc(51.89, false), enc(51.90, true), true),
            Err(RejectReason::ZoneMismatch)
        );
        assert!(global_airborne(enc(51.80, false), enc(51.81, true), true).is_some());
    }

    #[test]
    fn decoder_pairs_then_goes_local() {
        let even = cpr_of("8D40621D58C382D690C8AC2863A7");
        let odd = cpr_of("8D40621D58C386435CC412692AD6");
        let mut dec = CprDecoder::new(CprConfig::default());
        assert_eq!(dec.airborne(0.0, odd), PositionFix::Pending);
        // Partner too old (11 s > 10 s): still pending.
        assert_eq!(dec.airborne(11.0, even), PositionFix::Pending);
        let PositionFix::Accepted {
            lat_deg,
            lon_deg,
            global,
        } = dec.airborne(12.0, odd)
        else {
            panic!("pair within 1 s must decode");
        };
        assert!(global);
        // The odd frame is the latest here: its own zone gives the odd-frame latitude,
        // 52.26578 (The 1090 MHz Riddle: lat_odd).
        assert!((lat_deg - 52.26578).abs() < 5e-5, "{lat_deg}");
        assert!((lon_deg - 3.938).abs() < 0.01, "{lon_deg}");
        // 30 s later, no partner within 10 s: local decode against the last position.
        let PositionFix::Accepted { global, .. } = dec.airborne(42.0, even) else {
            panic!("local decode expected");
        };
        assert!(!global);
        assert_eq!(dec.stats().accepted_global, 1);
        assert_eq!(dec.stats().accepted_local, 1);
        assert_eq!(dec.stats().pending, 2);
        // Older than the last accepted position: refused.
        assert_eq!(
            dec.airborne(41.0, even),
            PositionFix::Rejected(RejectReason::BadTime)
        );
    }

    #[test]
    fn bad_first_fix_is_abandoned_after_repeated_rejections() {
        // Encode true positions near 52.26 N 3.92 E, but start from a wrong first fix: feed
        // a pair encoded 8° farther north first, then the true track.
        let enc = |lat_deg: f64, lon_deg: f64, odd: bool| {
            let i = f64::from(u32::from(odd));
            let dlat = 360.0 / (60.0 - i);
            let yz = (CPR_COUNT_F64 * modulo(lat_deg, dlat) / dlat + 0.5).floor();
            let rlat = dlat * ((lat_deg / dlat).floor() + yz / CPR_COUNT_F64);
            let dlon = 360.0 / f64::from(nl(rlat).saturating_sub(u32::from(odd)).max(1));
            let xz = (CPR_COUNT_F64 * modulo(lon_deg, dlon) / dlon + 0.5).floor();
            Cpr {
                lat: (yz as u32) % CPR_COUNT,
                lon: (xz as u32) % CPR_COUNT,
                odd,
            }
        };
        let config = CprConfig::default();
        let mut dec = CprDecoder::new(config);
        assert_eq!(
            dec.airborne(0.0, enc(60.26, 3.92, false)),
            PositionFix::Pending
        );
        assert!(matches!(
            dec.airborne(0.5, enc(60.26, 3.92, true)),
            PositionFix::Accepted { .. }
        ));
        let mut t = 1.0;
        let mut rejected = 0;
        let mut last = PositionFix::Pending;
        for k in 0..20 {
            last = dec.airborne(t, enc(52.26, 3.92, k % 2 == 1));
            if last == PositionFix::Rejected(RejectReason::ImpossibleSpeed) {
                rejected += 1;
            }
            t += 0.5;
        }
        assert_eq!(rejected, config.rejections_before_reset);
        assert_eq!(dec.stats().resets, 1);
        let PositionFix::Accepted {
            lat_deg,
            lon_deg,
            global,
        } = last
        else {
            panic!("track must recover, got {last:?}");
        };
        assert!(global);
        assert!(haversine_m(lat_deg, lon_deg, 52.26, 3.92) < 10.0);
    }

    #[test]
    fn surface_needs_a_reference() {
        let even = cpr_of("8CC8200A3AC8F009BCDEF2000000");
        let odd = cpr_of("8FC8200A3AB8F5F893096B000000");
        let mut blind = CprDecoder::new(CprConfig::default());
        assert_eq!(blind.surface(0.0, even), PositionFix::Pending);
        assert_eq!(blind.surface(2.0, odd), PositionFix::Pending);
        let mut dec = CprDecoder::new(CprConfig {
            receiver: Some((-43.496, 172.558)),
            ..CprConfig::default()
        });
        // The first frame decodes locally against the receiver, the second globally.
        let PositionFix::Accepted { global, .. } = dec.surface(0.0, even) else {
            panic!("local surface decode against the receiver expected");
        };
        assert!(!global);
        let PositionFix::Accepted {
            lat_deg,
            lon_deg,
            global,
        } = dec.surface(2.0, odd)
        else {
            panic!("global surface decode expected");
        };
        assert!(global);
        assert!(close((lat_deg, lon_deg), (-43.48564, 172.53942), 1e-5));
    }

    /// The shortcut answers as the haversine does: random pairs over the globe, from a few
    /// metres to across the antimeridian, against allowances on both sides of the distance
    /// and at it.
    #[test]
    fn within_is_the_haversine_decision() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let mut shortcut = 0;
        for _ in 0..200_000 {
            let lat0: f64 = rng.gen_range(-89.9..89.9);
            let lon0: f64 = rng.gen_range(-180.0..180.0);
            let step = 10f64.powi(rng.gen_range(-5..2));
            let lat = (lat0 + rng.gen_range(-1.0..1.0) * step).clamp(-90.0, 90.0);
            let lon = match rng.gen_range(0..8) {
                0 => -lon0.signum() * 179.99,
                _ => lon0 + rng.gen_range(-1.0..1.0) * step,
            };
            let d = haversine_m(lat0, lon0, lat, lon);
            for allowed in [
                d * rng.gen_range(0.5..3.0),
                d,
                d * (1.0 + 1e-15),
                d * (1.0 - 1e-15),
                d.next_up(),
                d.next_down(),
                0.0,
                -1.0,
            ] {
                let expected = !(d.is_nan() || d > allowed);
                assert_eq!(
                    within_m(lat0, lon0, lat, lon, allowed),
                    expected,
                    "{lat0} {lon0} {lat} {lon} {allowed}"
                );
            }
            let bound =
                EARTH_MEAN_RADIUS_M * ((lat - lat0).abs() + (lon - lon0).abs()).to_radians();
            shortcut += usize::from(bound * (1.0 + 1e-9) <= 3.0 * d);
        }
        // The shortcut is taken for a good share of these (all of a real feed's, nearly).
        assert!(shortcut > 50_000, "{shortcut}");
        assert!(!within_m(f64::NAN, 0.0, 0.0, 0.0, 1e9));
        assert!(!within_m(0.0, 0.0, 0.0, f64::NAN, 1e9));
    }

    #[test]
    fn haversine_of_one_degree_of_latitude() {
        // On the mean sphere one degree of arc is R·π/180 = 111 195.08 m.
        let d = haversine_m(10.0, 20.0, 11.0, 20.0);
        assert!((d - 111_195.08).abs() < 0.01, "{d}");
    }
}
