//! WGS-84 geodetic <-> ECEF <-> local east-north-up conversions, exact both ways.
//!
//! Filters run in metres in an ENU tangent plane ([`LocalFrame`]); the API speaks degrees.
//! Geodetic -> ECEF is the textbook closed form (NIMA TR8350.2 §4); ECEF -> geodetic is
//! Vermeille's exact closed form (J. Geodesy 76 (2002) 451-454, and 78 (2004) 94-95), valid
//! everywhere except within ~43 km of the Earth's centre, far from any aircraft.

use nalgebra::{Matrix3, Vector3};

/// WGS-84 semi-major axis, metres (NIMA TR8350.2 Table 3.1).
pub const WGS84_A_M: f64 = 6_378_137.0;
/// WGS-84 flattening (NIMA TR8350.2 Table 3.1).
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// First eccentricity squared, e² = f(2 − f).
pub const WGS84_E2: f64 = WGS84_F * (2.0 - WGS84_F);

/// Geodetic latitude, longitude (degrees) and height above the ellipsoid (m) to ECEF (m):
/// X = (N + h) cos φ cos λ, Y = (N + h) cos φ sin λ, Z = (N(1 − e²) + h) sin φ,
/// N = a / sqrt(1 − e² sin² φ).
pub fn geodetic_to_ecef(lat_deg: f64, lon_deg: f64, h_m: f64) -> Vector3<f64> {
    Trig::of(lat_deg, lon_deg).ecef(h_m)
}

/// Sines and cosines of a latitude and a longitude, computed once for the position and the
/// axes at that position.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Trig {
    sin_lat: f64,
    cos_lat: f64,
    sin_lon: f64,
    cos_lon: f64,
}

impl Trig {
    fn of(lat_deg: f64, lon_deg: f64) -> Self {
        let (sin_lat, cos_lat) = lat_deg.to_radians().sin_cos();
        let (sin_lon, cos_lon) = lon_deg.to_radians().sin_cos();
        Self {
            sin_lat,
            cos_lat,
            sin_lon,
            cos_lon,
        }
    }

    /// The sines and cosines at (`lat_deg`, `lon_deg`) from those at a nearby `base`
    /// (radians `base_rad`) by the angle-addition formulas, sin(a + d) = sin a + (sin a
    /// (cos d − 1) + cos a sin d), with sin d and cos d − 1 from their Taylor series; `None`
    /// when either angle is more than [`TRIG_STEP_RAD`] from the base (or not finite).
    ///
    /// At |d| ≤ 2⁻⁷ the series' first omitted terms (d¹¹/11!, d¹⁰/10!) are below 10⁻²⁸ of
    /// the result, and the sum is formed as a correction to sin a, so the result is within
    /// about one unit in the last place of `sin_cos` (tested over random bases and steps):
    /// a few nanometres in ECEF. Two libm `sin_cos` calls cost about 220 instructions; this
    /// costs about 40.
    fn near(base: &Trig, base_rad: (f64, f64), lat_deg: f64, lon_deg: f64) -> Option<Self> {
        let d_lat = lat_deg.to_radians() - base_rad.0;
        let d_lon = lon_deg.to_radians() - base_rad.1;
        if !(d_lat.abs() <= TRIG_STEP_RAD && d_lon.abs() <= TRIG_STEP_RAD) {
            return None;
        }
        let (s_lat, cm1_lat) = sin_and_cos_minus_one(d_lat);
        let (s_lon, cm1_lon) = sin_and_cos_minus_one(d_lon);
        Some(Self {
            sin_lat: base.sin_lat + (base.sin_lat * cm1_lat + base.cos_lat * s_lat),
            cos_lat: base.cos_lat + (base.cos_lat * cm1_lat - base.sin_lat * s_lat),
            sin_lon: base.sin_lon + (base.sin_lon * cm1_lon + base.cos_lon * s_lon),
            cos_lon: base.cos_lon + (base.cos_lon * cm1_lon - base.sin_lon * s_lon),
        })
    }

    /// [`geodetic_to_ecef`] of the point at height `h_m`.
    fn ecef(&self, h_m: f64) -> Vector3<f64> {
        let n = WGS84_A_M / (1.0 - WGS84_E2 * self.sin_lat * self.sin_lat).sqrt();
        Vector3::new(
            (n + h_m) * self.cos_lat * self.cos_lon,
            (n + h_m) * self.cos_lat * self.sin_lon,
            (n * (1.0 - WGS84_E2) + h_m) * self.sin_lat,
        )
    }

    /// The rotation from ECEF axes to the ENU axes at the point (rows east, north, up).
    fn enu_rotation(&self) -> Matrix3<f64> {
        let Self {
            sin_lat,
            cos_lat,
            sin_lon,
            cos_lon,
        } = *self;
        Matrix3::new(
            -sin_lon,
            cos_lon,
            0.0,
            -sin_lat * cos_lon,
            -sin_lat * sin_lon,
            cos_lat,
            cos_lat * cos_lon,
            cos_lat * sin_lon,
            sin_lat,
        )
    }
}

/// The largest step from a [`TrigCache`]'s base, radians: 2⁻⁷ (0.45°, 50 km of latitude), two
/// to four minutes of an airliner's flight before the base is taken again.
const TRIG_STEP_RAD: f64 = 1.0 / 128.0;

/// sin d and cos d − 1 for |d| ≤ [`TRIG_STEP_RAD`], Taylor series to d⁹ and d¹⁰ in Horner form
/// (cos d − 1 kept apart from the 1, so that nothing cancels).
fn sin_and_cos_minus_one(d: f64) -> (f64, f64) {
    let d2 = d * d;
    let sin = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0 * (1.0 - d2 / 72.0))));
    let cos_minus_one =
        -d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0 * (1.0 - d2 / 56.0 * (1.0 - d2 / 90.0))));
    (sin, cos_minus_one)
}

/// The sines and cosines of an aircraft's last position whose angles were taken from libm,
/// so that the next report's, a few hundred metres on, come by angle addition
/// ([`LocalFrame::to_enu_with_rotation_near`]). Always a fresh `sin_cos` at the base: the
/// additions never build on one another, so their rounding cannot accumulate.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrigCache {
    /// The base's latitude and longitude, radians, and their sines and cosines.
    base: Option<((f64, f64), Trig)>,
}

impl TrigCache {
    /// The sines and cosines at (`lat_deg`, `lon_deg`): by addition from the base when it
    /// is near, else from libm, which then becomes the base.
    fn trig(&mut self, lat_deg: f64, lon_deg: f64) -> Trig {
        if let Some((rad, base)) = &self.base {
            if let Some(t) = Trig::near(base, *rad, lat_deg, lon_deg) {
                return t;
            }
        }
        let t = Trig::of(lat_deg, lon_deg);
        self.base = Some(((lat_deg.to_radians(), lon_deg.to_radians()), t));
        t
    }
}

/// ECEF (m) to geodetic (degrees, degrees, metres above the ellipsoid), Vermeille's closed
/// form (2004, eq. numbers of the 2002 paper): no iteration, exact to f64 rounding
/// (round trips well under a micrometre at aircraft heights; see the tests).
pub fn ecef_to_geodetic(ecef: &Vector3<f64>) -> (f64, f64, f64) {
    let (x, y, z) = (ecef.x, ecef.y, ecef.z);
    let a2 = WGS84_A_M * WGS84_A_M;
    let e4 = WGS84_E2 * WGS84_E2;
    let xy = x.hypot(y);
    let p = (x * x + y * y) / a2;
    let q = (1.0 - WGS84_E2) / a2 * z * z;
    let r = (p + q - e4) / 6.0;
    let s = e4 * p * q / (4.0 * r * r * r);
    let t = (1.0 + s + (s * (2.0 + s)).sqrt()).cbrt();
    let u = r * (1.0 + t + 1.0 / t);
    let v = (u * u + e4 * q).sqrt();
    let w = WGS84_E2 * (u + v - q) / (2.0 * v);
    let k = (u + v + w * w).sqrt() - w;
    let d = k * xy / (k + WGS84_E2);
    let dz = d.hypot(z);
    let lat = 2.0 * z.atan2(d + dz);
    let lon = y.atan2(x);
    let h = (k + WGS84_E2 - 1.0) / k * dz;
    (lat.to_degrees(), lon.to_degrees(), h)
}

/// Rotation from ECEF axes to the ENU axes at (lat, lon): rows are east, north, up.
fn ecef_to_enu_rotation(lat_deg: f64, lon_deg: f64) -> Matrix3<f64> {
    Trig::of(lat_deg, lon_deg).enu_rotation()
}

/// A local east-north-up tangent plane at an origin: the frame the filters run in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalFrame {
    origin_ecef: Vector3<f64>,
    /// ECEF -> ENU at the origin.
    rotation: Matrix3<f64>,
    origin: (f64, f64, f64),
}

impl LocalFrame {
    /// The ENU frame at (lat, lon) degrees and height `h_m` above the ellipsoid.
    pub fn new(lat_deg: f64, lon_deg: f64, h_m: f64) -> Self {
        Self {
            origin_ecef: geodetic_to_ecef(lat_deg, lon_deg, h_m),
            rotation: ecef_to_enu_rotation(lat_deg, lon_deg),
            origin: (lat_deg, lon_deg, h_m),
        }
    }

    /// The origin: latitude, longitude (degrees), height (m).
    pub fn origin(&self) -> (f64, f64, f64) {
        self.origin
    }

    /// A geodetic point in this frame, metres east, north, up.
    pub fn to_enu(&self, lat_deg: f64, lon_deg: f64, h_m: f64) -> Vector3<f64> {
        self.rotation * (geodetic_to_ecef(lat_deg, lon_deg, h_m) - self.origin_ecef)
    }

    /// A point of `other`'s frame in this one: a rotation and a translation through ECEF,
    /// no geodesy (a point kept in one plane while its track moved to another).
    pub fn from_frame(&self, other: &LocalFrame, enu: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * (other.origin_ecef + other.rotation.transpose() * enu - self.origin_ecef)
    }

    /// A point of this frame back to latitude, longitude (degrees) and height (m).
    pub fn to_geodetic(&self, enu: &Vector3<f64>) -> (f64, f64, f64) {
        ecef_to_geodetic(&(self.origin_ecef + self.rotation.transpose() * enu))
    }

    /// [`LocalFrame::to_enu`] and [`LocalFrame::rotation_from_local`] of the same point, with
    /// its sines and cosines computed once (the same numbers as the two calls).
    pub fn to_enu_with_rotation(
        &self,
        lat_deg: f64,
        lon_deg: f64,
        h_m: f64,
    ) -> (Vector3<f64>, Matrix3<f64>) {
        self.enu_with_rotation_of(&Trig::of(lat_deg, lon_deg), h_m)
    }

    /// The point whose sines and cosines are `trig`, at height `h_m`, in this frame, and the
    /// rotation from its local axes to the frame's.
    fn enu_with_rotation_of(&self, trig: &Trig, h_m: f64) -> (Vector3<f64>, Matrix3<f64>) {
        let enu = self.rotation * (trig.ecef(h_m) - self.origin_ecef);
        let rotation = self.rotation * trig.enu_rotation().transpose();
        (enu, rotation)
    }

    /// [`LocalFrame::to_enu_with_rotation`] with the point's sines and cosines taken from
    /// `cache` ([`TrigCache`]): the same numbers to about one unit in the last place of
    /// each sine, for a fifth of the trigonometry when the aircraft's reports follow one
    /// another (every position report of a track).
    pub fn to_enu_with_rotation_near(
        &self,
        cache: &mut TrigCache,
        lat_deg: f64,
        lon_deg: f64,
        h_m: f64,
    ) -> (Vector3<f64>, Matrix3<f64>) {
        self.enu_with_rotation_of(&cache.trig(lat_deg, lon_deg), h_m)
    }

    /// Rotation taking a vector expressed in the local ENU axes at (lat, lon) into this
    /// frame's axes. The axes turn with the point (a velocity "east" 500 km away is not quite
    /// this frame's east), so velocities and their covariances need it.
    pub fn rotation_from_local(&self, lat_deg: f64, lon_deg: f64) -> Matrix3<f64> {
        self.rotation * ecef_to_enu_rotation(lat_deg, lon_deg).transpose()
    }

    /// A velocity given in the local ENU axes at (lat, lon) (e.g. an ADS-B ground velocity
    /// and vertical rate) expressed in this frame's axes.
    pub fn vel_to_enu(&self, lat_deg: f64, lon_deg: f64, local_enu: &Vector3<f64>) -> Vector3<f64> {
        self.rotation_from_local(lat_deg, lon_deg) * local_enu
    }

    /// The inverse of [`LocalFrame::vel_to_enu`]: a velocity in this frame's axes expressed in
    /// the local ENU axes at (lat, lon) (ground speed east/north and vertical rate there).
    pub fn vel_from_enu(
        &self,
        lat_deg: f64,
        lon_deg: f64,
        frame_enu: &Vector3<f64>,
    ) -> Vector3<f64> {
        self.rotation_from_local(lat_deg, lon_deg).transpose() * frame_enu
    }

    /// A covariance given in the local ENU axes at (lat, lon) expressed in this frame's axes.
    pub fn cov_to_enu(&self, lat_deg: f64, lon_deg: f64, local_cov: &Matrix3<f64>) -> Matrix3<f64> {
        rotate_cov(&self.rotation_from_local(lat_deg, lon_deg), local_cov)
    }

    /// The inverse of [`LocalFrame::cov_to_enu`].
    pub fn cov_from_enu(
        &self,
        lat_deg: f64,
        lon_deg: f64,
        frame_cov: &Matrix3<f64>,
    ) -> Matrix3<f64> {
        rotate_cov(
            &self.rotation_from_local(lat_deg, lon_deg).transpose(),
            frame_cov,
        )
    }
}

/// R C Rᵀ, symmetrised: a covariance carried through the rotation R.
pub fn rotate_cov(rotation: &Matrix3<f64>, cov: &Matrix3<f64>) -> Matrix3<f64> {
    let c = rotation * cov * rotation.transpose();
    (c + c.transpose()) * 0.5
}

/// [`rotate_cov`] of the diagonal covariance diag(`var`), the same numbers bit for bit
/// (tested) with the products by its zeros left out: every report's covariance is one (its
/// axes are the local east, north and up), and the two generic 3x3 products cost 3 % of a
/// `kalman-cv` fleet replay's instructions.
///
/// The generic product sums each entry over k ascending, (a₀b₀ + a₁b₁) + a₂b₂; here the
/// terms of a zero of diag(var) are dropped from R·diag(var), which adds nothing but a
/// signed zero to a non-zero term, and R·diag(var)·Rᵀ keeps the generic order.
pub fn rotate_diag_cov(rotation: &Matrix3<f64>, var: &Vector3<f64>) -> Matrix3<f64> {
    let rd = Matrix3::from_fn(|i, j| rotation[(i, j)] * var[j]);
    let c = Matrix3::from_fn(|i, j| {
        rd[(i, 0)] * rotation[(j, 0)]
            + rd[(i, 1)] * rotation[(j, 1)]
            + rd[(i, 2)] * rotation[(j, 2)]
    });
    (c + c.transpose()) * 0.5
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// [`rotate_diag_cov`] is [`rotate_cov`] of the diagonal matrix, bit for bit, for the
    /// rotations of frames anywhere on the globe and variances over many decades.
    #[test]
    fn diagonal_rotation_is_the_generic_one_bit_for_bit() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        for _ in 0..20_000 {
            let frame = LocalFrame::new(
                rng.gen_range(-89.0..89.0),
                rng.gen_range(-180.0..180.0),
                0.0,
            );
            let r =
                frame.rotation_from_local(rng.gen_range(-89.9..89.9), rng.gen_range(-180.0..180.0));
            let var = Vector3::from_fn(|_, _| 10f64.powf(rng.gen_range(-6.0..8.0)));
            let generic = rotate_cov(&r, &Matrix3::from_diagonal(&var));
            let diagonal = rotate_diag_cov(&r, &var);
            let bits = |m: &Matrix3<f64>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&diagonal), bits(&generic), "R {r}, var {var}");
            let rt = r.transpose();
            assert_eq!(
                bits(&rotate_diag_cov(&rt, &var)),
                bits(&rotate_cov(&rt, &Matrix3::from_diagonal(&var)))
            );
        }
    }

    /// Metres per degree of latitude, roughly: converts an angular error into metres for
    /// the round-trip bounds (the bounds are three orders of magnitude above the errors).
    const M_PER_DEG: f64 = 111_320.0;

    #[test]
    fn known_ecef_values() {
        let b = WGS84_A_M * (1.0 - WGS84_F);
        // Axis points: equator/prime meridian, equator/90E, north pole.
        assert!(
            (geodetic_to_ecef(0.0, 0.0, 0.0) - Vector3::new(WGS84_A_M, 0.0, 0.0)).norm() < 1e-9
        );
        assert!(
            (geodetic_to_ecef(0.0, 90.0, 0.0) - Vector3::new(0.0, WGS84_A_M, 0.0)).norm() < 1e-9
        );
        assert!((geodetic_to_ecef(90.0, 0.0, 0.0) - Vector3::new(0.0, 0.0, b)).norm() < 1e-9);
        // pymap3d tests: (42°, -82°, 200 m) -> (660675.2518247, -4700948.68316, 4245737.66222).
        let p = geodetic_to_ecef(42.0, -82.0, 200.0);
        assert!(
            (p - Vector3::new(660_675.251_824_7, -4_700_948.683_16, 4_245_737.662_22)).norm()
                < 1e-4
        );
        let (lat, lon, h) = ecef_to_geodetic(&p);
        assert!(
            (lat - 42.0).abs() < 1e-12 && (lon + 82.0).abs() < 1e-12 && (h - 200.0).abs() < 1e-7
        );
        // qzsl6tool llh2ecef example: (34.4401061°, 132.4147804°, 233.362 m)
        // -> (-3551876.829, 3887786.860, 3586946.387); inputs rounded to 1e-7° (~1 cm).
        let q = geodetic_to_ecef(34.440_106_1, 132.414_780_4, 233.362);
        assert!((q - Vector3::new(-3_551_876.829, 3_887_786.860, 3_586_946.387)).norm() < 0.02);
        // Poles and the antimeridian through the inverse.
        let (lat, _, h) = ecef_to_geodetic(&Vector3::new(0.0, 0.0, -b - 10.0));
        assert!((lat + 90.0).abs() < 1e-12 && (h - 10.0).abs() < 1e-7);
        let (lat, lon, h) = ecef_to_geodetic(&Vector3::new(-WGS84_A_M - 1.0, 0.0, 0.0));
        assert!(lat.abs() < 1e-12 && (lon.abs() - 180.0).abs() < 1e-12 && (h - 1.0).abs() < 1e-7);
    }

    #[test]
    fn enu_of_a_published_azimuth_elevation_range() {
        // pymap3d tests: from (42°, -82°, 200 m), azimuth 33°, elevation 70°, range 1000 m
        // lands at (42.002582°, -81.997752°, 1139.7018 m). ENU = range·(cos el sin az,
        // cos el cos az, sin el).
        let frame = LocalFrame::new(42.0, -82.0, 200.0);
        let (az, el) = (33f64.to_radians(), 70f64.to_radians());
        let enu = 1000.0 * Vector3::new(el.cos() * az.sin(), el.cos() * az.cos(), el.sin());
        let (lat, lon, h) = frame.to_geodetic(&enu);
        // The published lat/lon have 6 decimals (±0.06 m), the height 4 (±0.1 mm).
        assert!((lat - 42.002_582).abs() < 1e-6, "{lat}");
        assert!((lon + 81.997_752).abs() < 1e-6, "{lon}");
        assert!((h - 1_139.701_8).abs() < 1e-3, "{h}");
    }

    #[test]
    fn round_trips_within_a_millimetre() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut worst_m: f64 = 0.0;
        for _ in 0..2000 {
            let (lat0, lon0) = (rng.gen_range(-80.0..80.0), rng.gen_range(-180.0..180.0));
            let frame = LocalFrame::new(lat0, lon0, rng.gen_range(0.0..500.0));
            // Up to 500 km away (4.5° of arc), 0-15 km high.
            let (dlat, dlon) = (rng.gen_range(-4.5..4.5), rng.gen_range(-4.5..4.5));
            let lat: f64 = lat0 + dlat;
            let lon = lon0 + dlon / lat0.to_radians().cos().max(0.2);
            let h = rng.gen_range(0.0..15_000.0);
            let enu = frame.to_enu(lat, lon, h);
            let (lat2, lon2, h2) = frame.to_geodetic(&enu);
            let lon_err_deg = (lon2 - lon + 540.0).rem_euclid(360.0) - 180.0;
            let err_m = ((lat2 - lat) * M_PER_DEG)
                .hypot(lon_err_deg * M_PER_DEG * lat.to_radians().cos())
                .hypot(h2 - h);
            worst_m = worst_m.max(err_m);
            // And the other way: ENU -> geodetic -> ENU.
            let back = frame.to_enu(lat2, lon2, h2);
            worst_m = worst_m.max((back - enu).norm());
        }
        eprintln!("geo round trip: worst {worst_m:.3e} m over 2000 random points");
        assert!(worst_m < 1e-3, "worst round trip {worst_m} m");
    }

    #[test]
    fn up_coordinate_drops_with_earth_curvature() {
        // A point 100 km north at the origin's height lies d²/(2R) below the tangent plane,
        // R the local radius of curvature of the meridian, M = a(1−e²)/(1−e² sin²φ)^{3/2}.
        let lat0: f64 = 45.0;
        let frame = LocalFrame::new(lat0, 5.0, 1000.0);
        let s2 = lat0.to_radians().sin().powi(2);
        let m_r = WGS84_A_M * (1.0 - WGS84_E2) / (1.0 - WGS84_E2 * s2).powf(1.5);
        let dlat_deg = (100_000.0 / m_r).to_degrees();
        let enu = frame.to_enu(lat0 + dlat_deg, 5.0, 1000.0);
        let expected_up = -(enu.y * enu.y) / (2.0 * m_r);
        // d²/(2R) = 785 m; the next term of the expansion is O(d⁴/R³) ~ 0.1 m.
        assert!(
            (enu.z - expected_up).abs() < 0.5,
            "{} vs {expected_up}",
            enu.z
        );
        assert!((enu.y - 100_000.0).abs() < 50.0);
        assert!(enu.x.abs() < 1e-6);
    }

    #[test]
    fn enu_with_rotation_is_the_two_calls() {
        let f = LocalFrame::new(51.47, -0.46, 0.0);
        for (lat, lon, h) in [
            (52.3, 1.2, 11_000.0),
            (49.0, -3.9, 300.0),
            (51.47, -0.46, 0.0),
        ] {
            let (enu, r) = f.to_enu_with_rotation(lat, lon, h);
            assert_eq!(enu, f.to_enu(lat, lon, h));
            assert_eq!(r, f.rotation_from_local(lat, lon));
        }
    }

    /// The sines and cosines by angle addition are libm's to about one unit in the last
    /// place, for bases anywhere on the globe and every step up to the limit (and its
    /// edge), so an ENU point agrees to nanometres; past the limit, or for a non-finite
    /// angle, libm is asked.
    #[test]
    fn trig_by_angle_addition_is_libms() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(21);
        let ulps = |a: f64, b: f64| (a - b).abs() / f64::EPSILON;
        let mut worst = 0.0_f64;
        for case in 0..200_000 {
            let (lat0, lon0) = (rng.gen_range(-89.9..89.9), rng.gen_range(-180.0..180.0));
            let step = if case % 10 == 0 {
                TRIG_STEP_RAD.to_degrees() * 0.999_999
            } else {
                rng.gen_range(0.0..TRIG_STEP_RAD.to_degrees())
            };
            let (lat, lon) = (
                lat0 + step * rng.gen_range(-1.0..1.0),
                lon0 + step * rng.gen_range(-1.0..1.0),
            );
            let base = Trig::of(lat0, lon0);
            let rad = (f64::to_radians(lat0), f64::to_radians(lon0));
            let near = Trig::near(&base, rad, lat, lon).expect("within the step");
            let exact = Trig::of(lat, lon);
            for (a, b) in [
                (near.sin_lat, exact.sin_lat),
                (near.cos_lat, exact.cos_lat),
                (near.sin_lon, exact.sin_lon),
                (near.cos_lon, exact.cos_lon),
            ] {
                worst = worst.max(ulps(a, b));
            }
        }
        // An ulp of 1 (the sines and cosines are at most 1 in size): 2.2e-16.
        assert!(worst <= 2.0, "{worst} ulps");
        // Beyond the step, and for non-finite angles: libm.
        let base = Trig::of(10.0, 20.0);
        let rad = (10f64.to_radians(), 20f64.to_radians());
        assert_eq!(Trig::near(&base, rad, 10.5, 20.0), None);
        assert_eq!(Trig::near(&base, rad, 10.0, f64::NAN), None);

        // Through the cache, a flight's ENU points agree with the direct ones to 10 nm, and
        // the base moves on as the flight leaves it.
        let frame = LocalFrame::new(51.47, -0.46, 0.0);
        let mut cache = TrigCache::default();
        let mut bases = 0;
        for k in 0..20_000 {
            let t = f64::from(k) * 0.5;
            let (lat, lon, h) = (51.0 + t * 1.0e-4, -1.0 + t * 1.5e-4, 11_000.0);
            let before = cache.base;
            let (enu, r) = frame.to_enu_with_rotation_near(&mut cache, lat, lon, h);
            bases += usize::from(cache.base != before);
            let (enu0, r0) = frame.to_enu_with_rotation(lat, lon, h);
            assert!((enu - enu0).norm() < 1e-8, "{k}: {}", (enu - enu0).norm());
            assert!((r - r0).norm() < 1e-15, "{k}");
        }
        // 1° of latitude and 1.5° of longitude over the flight (160 km): the first base,
        // then a new one each time the longitude has moved 0.45° from the last.
        assert!((3..=6).contains(&bases), "{bases} bases");
    }

    #[test]
    fn velocity_and_covariance_rotations() {
        let frame = LocalFrame::new(45.0, 0.0, 0.0);
        // At the origin the local axes are the frame's.
        let v = Vector3::new(100.0, -50.0, 5.0);
        assert!((frame.vel_to_enu(45.0, 0.0, &v) - v).norm() < 1e-12);
        // Seen from the frame at (0°, 0°), where east = ECEF Y, north = ECEF Z, up = ECEF X:
        // local north at (45°N, 0°) is ECEF (−sin45, 0, cos45), i.e. (0, cos45, −sin45) ENU.
        let frame_eq = LocalFrame::new(0.0, 0.0, 0.0);
        let north_there = frame_eq.vel_to_enu(45.0, 0.0, &Vector3::new(0.0, 1.0, 0.0));
        let c = std::f64::consts::FRAC_1_SQRT_2;
        assert!(
            (north_there - Vector3::new(0.0, c, -c)).norm() < 1e-12,
            "{north_there}"
        );
        // Local east at (0°, 90°E) is ECEF −X: straight down in that frame.
        let east_there = frame_eq.vel_to_enu(0.0, 90.0, &Vector3::new(1.0, 0.0, 0.0));
        assert!(
            (east_there - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12,
            "{east_there}"
        );
        // Inverse and covariance consistency: R C Rᵀ keeps the trace, and round-trips.
        let w = frame.vel_from_enu(47.0, 3.0, &frame.vel_to_enu(47.0, 3.0, &v));
        assert!((w - v).norm() < 1e-12);
        let cov = Matrix3::new(4.0, 1.0, 0.5, 1.0, 9.0, -0.3, 0.5, -0.3, 25.0);
        let rotated = frame.cov_to_enu(47.0, 3.0, &cov);
        assert!((rotated.trace() - cov.trace()).abs() < 1e-12);
        assert!((frame.cov_from_enu(47.0, 3.0, &rotated) - cov).norm() < 1e-12);
        assert_eq!(rotated, rotated.transpose());
    }
}
