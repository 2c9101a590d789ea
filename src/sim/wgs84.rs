//! The few WGS-84 formulas the simulator needs, kept inside `sim` so the truth does not depend
//! on the tracker's own conversions (it is what they are checked against).
//!
//! Constants and formulas: NIMA TR8350.2 (WGS-84) §3 and §4; the ECEF -> geodetic inversion is
//! the closed form of Zhu (1994) as given by Heikkinen, exact to f64 rounding at all heights
//! an aircraft flies.

/// Semi-major axis a, metres (TR8350.2 Table 3.1).
pub const A_M: f64 = 6_378_137.0;
/// Flattening f (TR8350.2 Table 3.1).
pub const F: f64 = 1.0 / 298.257_223_563;
/// First eccentricity squared e^2 = f(2 - f).
pub const E2: f64 = F * (2.0 - F);
/// Semi-minor axis b = a(1 - f), metres.
pub const B_M: f64 = A_M * (1.0 - F);

/// Meridian radius of curvature M and prime-vertical radius N at geodetic latitude `lat_rad`:
/// M = a(1 - e^2)/(1 - e^2 sin^2 lat)^(3/2), N = a/(1 - e^2 sin^2 lat)^(1/2).
///
/// Over a small step, north motion dn changes latitude by dn/(M + h) and east motion de
/// changes longitude by de/((N + h) cos lat): the local-level kinematics of `truth`.
pub fn radii_m(lat_rad: f64) -> (f64, f64) {
    let s = lat_rad.sin();
    let w2 = 1.0 - E2 * s * s;
    let w = w2.sqrt();
    (A_M * (1.0 - E2) / (w2 * w), A_M / w)
}

/// Geodetic (lat, lon in radians, h in metres above the ellipsoid) -> ECEF metres.
pub fn geodetic_to_ecef(lat_rad: f64, lon_rad: f64, h_m: f64) -> [f64; 3] {
    let (_, n) = radii_m(lat_rad);
    let (sl, cl) = lat_rad.sin_cos();
    let (so, co) = lon_rad.sin_cos();
    [
        (n + h_m) * cl * co,
        (n + h_m) * cl * so,
        (n * (1.0 - E2) + h_m) * sl,
    ]
}

/// ECEF metres -> geodetic (lat, lon in radians, h in metres), Zhu/Heikkinen closed form.
pub fn ecef_to_geodetic(ecef: [f64; 3]) -> (f64, f64, f64) {
    let [x, y, z] = ecef;
    let a = A_M;
    let b = B_M;
    let ep2 = (a * a - b * b) / (b * b);
    let p = x.hypot(y);
    if p < 1e-9 {
        // On the polar axis: latitude is +-90 degrees, longitude is arbitrary (0).
        let lat = if z >= 0.0 {
            std::f64::consts::FRAC_PI_2
        } else {
            -std::f64::consts::FRAC_PI_2
        };
        return (lat, 0.0, z.abs() - b);
    }
    let ff = 54.0 * b * b * z * z;
    let g = p * p + (1.0 - E2) * z * z - E2 * (a * a - b * b);
    let c = E2 * E2 * ff * p * p / (g * g * g);
    let s = (1.0 + c + (c * c + 2.0 * c).sqrt()).cbrt();
    let k = s + 1.0 + 1.0 / s;
    let pp = ff / (3.0 * k * k * g * g);
    let q = (1.0 + 2.0 * E2 * E2 * pp).sqrt();
    let r0 = -(pp * E2 * p) / (1.0 + q)
        + (0.5 * a * a * (1.0 + 1.0 / q)
            - pp * (1.0 - E2) * z * z / (q * (1.0 + q))
            - 0.5 * pp * p * p)
            .max(0.0)
            .sqrt();
    let u = ((p - E2 * r0).powi(2) + z * z).sqrt();
    let v = ((p - E2 * r0).powi(2) + (1.0 - E2) * z * z).sqrt();
    let z0 = b * b * z / (a * v);
    let h = u * (1.0 - b * b / (a * v));
    let lat = (z + ep2 * z0).atan2(p);
    let lon = y.atan2(x);
    (lat, lon, h)
}

/// A point given in the east-north-up tangent plane of a reference on the ellipsoid
/// (`ref_lat_rad`, `ref_lon_rad`, height 0) -> geodetic (lat, lon in radians, h in metres).
pub fn enu_to_geodetic(
    ref_lat_rad: f64,
    ref_lon_rad: f64,
    east_m: f64,
    north_m: f64,
    up_m: f64,
) -> (f64, f64, f64) {
    let [x0, y0, z0] = geodetic_to_ecef(ref_lat_rad, ref_lon_rad, 0.0);
    let (sl, cl) = ref_lat_rad.sin_cos();
    let (so, co) = ref_lon_rad.sin_cos();
    // Columns of the ENU -> ECEF rotation: east, north, up unit vectors in ECEF.
    let x = x0 - so * east_m - sl * co * north_m + cl * co * up_m;
    let y = y0 + co * east_m - sl * so * north_m + cl * so * up_m;
    let z = z0 + cl * north_m + sl * up_m;
    ecef_to_geodetic([x, y, z])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ecef_of_known_points() {
        // The equator at the prime meridian is (a, 0, 0); the north pole is (0, 0, b).
        let p = geodetic_to_ecef(0.0, 0.0, 0.0);
        assert!((p[0] - 6_378_137.0).abs() < 1e-9 && p[1].abs() < 1e-9 && p[2].abs() < 1e-9);
        let p = geodetic_to_ecef(std::f64::consts::FRAC_PI_2, 0.0, 0.0);
        assert!(
            p[0].abs() < 1e-6 && (p[2] - 6_356_752.314_245).abs() < 1e-5,
            "{p:?}"
        );
        // Radii at the equator: M = a(1 - e^2) = 6 335 439.327 293 m, N = a.
        let (m, n) = radii_m(0.0);
        assert!((m - 6_335_439.327_293).abs() < 1e-5 && (n - A_M).abs() < 1e-9);
    }

    #[test]
    fn geodetic_round_trip_is_sub_millimetre() {
        for &lat in &[-89.5, -60.0, -12.3, 0.0, 0.001, 37.5, 52.25, 84.9] {
            for &lon in &[-179.9, -45.0, 0.0, 1.37, 120.0, 180.0] {
                for &h in &[-100.0, 0.0, 152.4, 11_000.0, 40_000.0] {
                    let (la, lo) = (f64::to_radians(lat), f64::to_radians(lon));
                    let (la2, lo2, h2) = ecef_to_geodetic(geodetic_to_ecef(la, lo, h));
                    let dn = (la2 - la) * 6.4e6;
                    let mut dl = lo2 - lo;
                    if dl > std::f64::consts::PI {
                        dl -= 2.0 * std::f64::consts::PI;
                    } else if dl < -std::f64::consts::PI {
                        dl += 2.0 * std::f64::consts::PI;
                    }
                    let de = dl * 6.4e6 * la.cos();
                    assert!(
                        dn.abs() < 1e-4 && de.abs() < 1e-4 && (h2 - h).abs() < 1e-4,
                        "{lat} {lon} {h}: {dn} {de} {}",
                        h2 - h
                    );
                }
            }
        }
    }

    #[test]
    fn enu_offsets_match_geometry() {
        // 1000 m up from a reference: same lat/lon, h = 1000.
        let (la, lo) = (43.6_f64.to_radians(), 1.37_f64.to_radians());
        let (la2, lo2, h) = enu_to_geodetic(la, lo, 0.0, 0.0, 1000.0);
        assert!((la2 - la).abs() < 1e-12 && (lo2 - lo).abs() < 1e-12 && (h - 1000.0).abs() < 1e-6);
        // 10 km east on the tangent plane at the equator: the point sits sqrt(a^2 + d^2) - a
        // above the ellipsoid and atan(d/a) east (the equator is a circle of radius a).
        let (la3, lo3, h3) = enu_to_geodetic(0.0, 0.0, 10_000.0, 0.0, 0.0);
        assert!(la3.abs() < 1e-12);
        assert!((lo3 - (10_000.0_f64 / A_M).atan()).abs() < 1e-13);
        assert!((h3 - ((A_M * A_M + 1e8).sqrt() - A_M)).abs() < 1e-6, "{h3}");
    }
}
