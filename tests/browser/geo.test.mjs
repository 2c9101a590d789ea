// The map page's geometry (src/api/web/geo.js) against closed forms and published values.
// Run: node --test tests/browser/geo.test.mjs (tests/map_browser.rs runs it too).
import { test } from "node:test";
import assert from "node:assert/strict";
import {
  covarianceEllipse,
  ellipseLatLngs,
  metresPerDegree,
  offsetLatLon,
} from "../../src/api/web/geo.js";

const near = (got, want, tol, what) =>
  assert.ok(Math.abs(got - want) <= tol, `${what}: ${got} is not ${want} +- ${tol}`);

test("metres per degree match the WGS-84 tables", () => {
  // One degree of longitude on the equator is a * pi / 180.
  near(metresPerDegree(0).lon, (6378137 * Math.PI) / 180, 1e-6, "lon at 0");
  // One degree of latitude: the series 111132.954 - 559.822 cos 2phi + 1.175 cos 4phi m
  // (its coefficients are rounded: it agrees with the closed form to a few cm).
  const series = (deg) => {
    const p = (deg * Math.PI) / 180;
    return 111132.954 - 559.822 * Math.cos(2 * p) + 1.175 * Math.cos(4 * p);
  };
  for (const deg of [0, 20, 33.9425, 45, 60, 80]) {
    near(metresPerDegree(deg).lat, series(deg), 0.05, `lat at ${deg}`);
  }
  // At 45 degrees, the usual table's 111.132 km and 78.847 km (to the metre).
  near(metresPerDegree(45).lat, 111132, 1, "lat at 45");
  near(metresPerDegree(45).lon, 78847, 1, "lon at 45");
  const [lat, lon] = offsetLatLon(45, 10, metresPerDegree(45).lon, -metresPerDegree(45).lat);
  near(lat, 44, 1e-6, "south 1 degree");
  near(lon, 11, 1e-6, "east 1 degree");
});

test("an axis-aligned covariance gives its standard deviations, times k", () => {
  const e = covarianceEllipse([[100, 0, 0], [0, 25, 0], [0, 0, 9]], 2);
  near(e.major_m, 20, 1e-12, "major");
  near(e.minor_m, 10, 1e-12, "minor");
  near(e.azimuth_deg, 90, 1e-9, "major axis east");
  const n = covarianceEllipse([[25, 0], [0, 100]], 2);
  near(n.azimuth_deg, 0, 1e-9, "major axis north");
});

test("a correlated covariance gives its eigenvalues and eigenvector", () => {
  // [[50, 30], [30, 50]] has eigenvalues 80 (along (1, 1): north-east) and 20.
  const e = covarianceEllipse([[50, 30], [30, 50]], 2);
  near(e.major_m, 2 * Math.sqrt(80), 1e-12, "major");
  near(e.minor_m, 2 * Math.sqrt(20), 1e-12, "minor");
  near(e.azimuth_deg, 45, 1e-9, "azimuth");
  near(covarianceEllipse([[50, -30], [-30, 50]], 2).azimuth_deg, 135, 1e-9, "north-west");
  // A circle: any axis, equal semi-axes.
  const c = covarianceEllipse([[16, 0], [0, 16]], 1);
  near(c.major_m, 4, 1e-12, "circle");
  near(c.minor_m, 4, 1e-12, "circle");
});

test("every vertex of the polygon is at Mahalanobis distance k", () => {
  // A correlated covariance of the size the daemon publishes, m^2.
  const cov = [[41.2, -17.9, 0.3], [-17.9, 23.4, -0.1], [0.3, -0.1, 4.4]];
  const [a, b, c] = [cov[0][0], cov[0][1], cov[1][1]];
  const det = a * c - b * b;
  const lat0 = 33.9425;
  const lon0 = -118.408;
  const pts = ellipseLatLngs(lat0, lon0, cov, 2, 72);
  assert.equal(pts.length, 72);
  const m = metresPerDegree(lat0);
  for (const [lat, lon] of pts) {
    const e = (lon - lon0) * m.lon;
    const n = (lat - lat0) * m.lat;
    // [e n] inv(cov) [e n]' with inv = [[c, -b], [-b, a]] / det.
    const d2 = (c * e * e - 2 * b * e * n + a * n * n) / det;
    near(d2, 4, 1e-9, "squared Mahalanobis distance");
  }
});

test("what is not a covariance draws nothing", () => {
  assert.equal(covarianceEllipse([[NaN, 0], [0, 1]]), null);
  assert.equal(covarianceEllipse([[-1, 0], [0, 1]]), null);
  assert.equal(covarianceEllipse(null), null);
  assert.equal(covarianceEllipse([[1]]), null);
  assert.equal(ellipseLatLngs(90, 0, [[1, 0], [0, 1]]), null);
});
