// Geometry of the map page: metres on the WGS-84 ellipsoid to degrees, and the uncertainty
// ellipse of a track's east-north position covariance. Pure functions (no DOM, no Leaflet),
// so tests/browser/geo.test.mjs checks them with node against closed forms.

/** WGS-84 semi-major axis, m. */
const A_M = 6378137.0;
/** WGS-84 flattening. */
const F = 1 / 298.257223563;
/** First eccentricity squared. */
const E2 = F * (2 - F);

/**
 * Metres per degree of latitude and of longitude at a latitude: the meridian radius of
 * curvature M and the parallel's radius N cos(lat) of the ellipsoid, times pi/180.
 */
export function metresPerDegree(latDeg) {
  const phi = (latDeg * Math.PI) / 180;
  const s = Math.sin(phi);
  const w = Math.sqrt(1 - E2 * s * s);
  const meridian_m = (A_M * (1 - E2)) / (w * w * w);
  const normal_m = A_M / w;
  return {
    lat: (meridian_m * Math.PI) / 180,
    lon: (normal_m * Math.cos(phi) * Math.PI) / 180,
  };
}

/** The point `east_m`, `north_m` away from (latDeg, lonDeg), as [lat, lon] (small offsets). */
export function offsetLatLon(latDeg, lonDeg, east_m, north_m) {
  const k = metresPerDegree(latDeg);
  return [latDeg + north_m / k.lat, lonDeg + east_m / k.lon];
}

/**
 * The k-sigma ellipse of a horizontal position covariance: `cov` holds at least the 2x2
 * east-north block (rows of `pos_cov_enu_m2`, m^2). Eigen-decomposition of the symmetric
 * block [[a, b], [b, c]]: lambda = (a+c)/2 +- sqrt(((a-c)/2)^2 + b^2), the major axis at
 * theta = atan2(2b, a-c)/2 from east, counter-clockwise. Semi-axes are k sqrt(lambda).
 * Null when the block is not a covariance (non-finite or a negative variance).
 */
export function covarianceEllipse(cov, k = 2) {
  const a = cov?.[0]?.[0];
  const c = cov?.[1]?.[1];
  const b = (cov?.[0]?.[1] + cov?.[1]?.[0]) / 2;
  if (![a, b, c, k].every(Number.isFinite) || a < 0 || c < 0) return null;
  const mean = (a + c) / 2;
  const d = Math.hypot((a - c) / 2, b);
  const major2 = mean + d;
  const minor2 = Math.max(mean - d, 0);
  const theta = 0.5 * Math.atan2(2 * b, a - c);
  const azimuth = (((90 - (theta * 180) / Math.PI) % 180) + 180) % 180;
  return {
    major_m: k * Math.sqrt(major2),
    minor_m: k * Math.sqrt(minor2),
    theta_rad: theta,
    azimuth_deg: azimuth,
  };
}

/**
 * The k-sigma ellipse around (latDeg, lonDeg) as `n` [lat, lon] vertices (a polygon for
 * Leaflet, which draws no ellipse); null when there is none to draw (see covarianceEllipse)
 * or at a pole.
 */
export function ellipseLatLngs(latDeg, lonDeg, cov, k = 2, n = 36) {
  const e = covarianceEllipse(cov, k);
  if (!e || !Number.isFinite(latDeg) || !Number.isFinite(lonDeg)) return null;
  const m = metresPerDegree(latDeg);
  if (m.lon < 1) return null;
  const ct = Math.cos(e.theta_rad);
  const st = Math.sin(e.theta_rad);
  const out = [];
  for (let i = 0; i < n; i++) {
    const p = (2 * Math.PI * i) / n;
    const u = e.major_m * Math.cos(p);
    const v = e.minor_m * Math.sin(p);
    const east = u * ct - v * st;
    const north = u * st + v * ct;
    out.push([latDeg + north / m.lat, lonDeg + east / m.lon]);
  }
  return out;
}
