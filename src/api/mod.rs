//! The HTTP API (axum). Reads published snapshots only; never talks to the tasks.
//!
//! Errors are `{"error": "..."}` with a 4xx status: 400 for malformed input, 404 for an unknown
//! aircraft or endpoint.

use crate::daemon::registry::TrackState;
use crate::daemon::Shared;
use crate::decode::Icao;
use crate::track::FlightMode;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, State};
use axum::http::{header, StatusCode};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde::{Deserialize, Serialize};

/// The one error type of the API.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// Malformed input: 400.
    #[error("{0}")]
    BadRequest(String),
    /// Unknown aircraft or endpoint: 404.
    #[error("{0}")]
    NotFound(String),
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = match self {
            ApiError::BadRequest(_) => StatusCode::BAD_REQUEST,
            ApiError::NotFound(_) => StatusCode::NOT_FOUND,
        };
        (
            status,
            Json(ErrorBody {
                error: self.to_string(),
            }),
        )
            .into_response()
    }
}

#[derive(Serialize)]
struct ErrorBody {
    error: String,
}

/// A live table of the tracks (the map page comes later).
const INDEX_HTML: &str = include_str!("index.html");

/// The router, with its state: what `serve` runs and what tests `oneshot`.
pub fn app(shared: Shared) -> Router {
    Router::new()
        .route("/", get(|| async { Html(INDEX_HTML) }))
        .route("/api/v1/tracks", get(tracks))
        .route("/api/v1/tracks/{icao}", get(track))
        .route("/api/v1/tracks/{icao}/prediction", get(prediction))
        .route("/api/v1/stats", get(stats))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .fallback(|| async { ApiError::NotFound("no such endpoint".into()) })
        .with_state(shared)
}

/// `GET /api/v1/tracks` query.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TracksQuery {
    /// `south,west,north,east` in degrees.
    bbox: Option<String>,
    /// One label or a comma-separated list: `CV`, `CT,CA`.
    mode: Option<String>,
}

#[derive(Serialize)]
struct TracksBody {
    /// Feed time of the newest frame, s.
    time: f64,
    tracks: Vec<TrackState>,
}

/// A latitude/longitude box; `west > east` crosses the antimeridian.
#[derive(Clone, Copy, Debug, PartialEq)]
struct BBox {
    south: f64,
    west: f64,
    north: f64,
    east: f64,
}

impl BBox {
    fn parse(s: &str) -> Result<Self, ApiError> {
        let bad = || {
            ApiError::BadRequest(format!(
                "bbox {s:?}: expected south,west,north,east in degrees"
            ))
        };
        let v: Vec<f64> = s
            .split(',')
            .map(|p| p.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| bad())?;
        let [south, west, north, east] = v[..] else {
            return Err(bad());
        };
        let lat_ok = |x: f64| (-90.0..=90.0).contains(&x);
        let lon_ok = |x: f64| (-180.0..=180.0).contains(&x);
        if !(lat_ok(south) && lat_ok(north) && lon_ok(west) && lon_ok(east)) || south > north {
            return Err(bad());
        }
        Ok(Self {
            south,
            west,
            north,
            east,
        })
    }

    fn contains(&self, lat: f64, lon: f64) -> bool {
        let lon_in = if self.west <= self.east {
            (self.west..=self.east).contains(&lon)
        } else {
            lon >= self.west || lon <= self.east
        };
        (self.south..=self.north).contains(&lat) && lon_in
    }
}

async fn tracks(
    State(shared): State<Shared>,
    query: Result<Query<TracksQuery>, QueryRejection>,
) -> Result<Json<TracksBody>, ApiError> {
    let Query(q) = query.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let bbox = q.bbox.as_deref().map(BBox::parse).transpose()?;
    let modes: Option<Vec<&'static str>> = q
        .mode
        .as_deref()
        .map(|m| {
            m.split(',')
                .map(|s| {
                    s.trim()
                        .parse::<FlightMode>()
                        .map(FlightMode::as_str)
                        .map_err(ApiError::BadRequest)
                })
                .collect()
        })
        .transpose()?;
    let tracks = shared
        .registry
        .all()
        .into_iter()
        .filter(|t| bbox.is_none_or(|b| b.contains(t.lat, t.lon)))
        .filter(|t| modes.as_ref().is_none_or(|m| m.contains(&t.mode)))
        .collect();
    Ok(Json(TracksBody {
        time: shared.stats.feed_time_s(),
        tracks,
    }))
}

async fn track(
    State(shared): State<Shared>,
    Path(icao): Path<String>,
) -> Result<Json<TrackState>, ApiError> {
    let icao: Icao = icao.parse().map_err(ApiError::BadRequest)?;
    shared
        .registry
        .get(icao)
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("no track for {icao}")))
}

#[derive(Serialize)]
struct PredictionBody {
    icao: Icao,
    /// Time of the estimate the predictions start from, s.
    t: f64,
    mode: &'static str,
    predictions: Vec<crate::daemon::registry::Prediction>,
}

/// Positions predicted by the current mode's model at the configured horizons.
async fn prediction(
    State(shared): State<Shared>,
    Path(icao): Path<String>,
) -> Result<Json<PredictionBody>, ApiError> {
    let icao: Icao = icao.parse().map_err(ApiError::BadRequest)?;
    let t = shared
        .registry
        .get(icao)
        .ok_or_else(|| ApiError::NotFound(format!("no track for {icao}")))?;
    Ok(Json(PredictionBody {
        icao,
        t: t.t,
        mode: t.mode,
        predictions: t.predictions,
    }))
}

async fn stats(State(shared): State<Shared>) -> Json<crate::daemon::stats::StatsSnapshot> {
    Json(shared.stats.snapshot())
}

#[derive(Serialize)]
struct Health {
    /// "ok", or "degraded" when live feeds are configured and none is connected, or when
    /// the ingest lag is past `pipeline.max_lag_s`.
    status: &'static str,
    feed_time: f64,
    /// Age of the frames being routed, s (0 when idle).
    ingest_lag_s: f64,
    tracks: usize,
    feeds: Vec<crate::feed::tcp::FeedStatusSnapshot>,
}

/// 200 while the daemon can serve fresh data; 503 when every live feed is down or ingest
/// lags more than `pipeline.max_lag_s` behind (the API keeps serving the last state
/// meanwhile).
async fn healthz(State(shared): State<Shared>) -> Response {
    let feeds = shared.stats.feeds();
    let feeds_down = !feeds.is_empty() && !feeds.iter().any(|f| f.connected);
    let lag_s = shared.stats.ingest_lag_s();
    let degraded = feeds_down || lag_s > shared.stats.max_lag_s();
    let body = Health {
        status: if degraded { "degraded" } else { "ok" },
        feed_time: shared.stats.feed_time_s(),
        ingest_lag_s: lag_s,
        tracks: shared.registry.len(),
        feeds,
    };
    let code = if degraded {
        StatusCode::SERVICE_UNAVAILABLE
    } else {
        StatusCode::OK
    };
    (code, Json(body)).into_response()
}

async fn metrics(State(shared): State<Shared>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )],
        shared.stats.encode_prometheus(),
    )
        .into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bbox_parses_and_contains() {
        let b = BBox::parse("43.0,1.0,50.0,3.0").unwrap();
        assert!(b.contains(49.0, 2.5));
        assert!(!b.contains(49.0, 3.5));
        assert!(!b.contains(42.9, 2.0));
        // Across the antimeridian.
        let b = BBox::parse("-10,170,10,-170").unwrap();
        assert!(b.contains(0.0, 175.0) && b.contains(0.0, -175.0) && !b.contains(0.0, 0.0));
    }

    #[test]
    fn bad_bboxes_are_refused() {
        for s in [
            "",
            "1,2,3",
            "1,2,3,4,5",
            "a,b,c,d",
            "50,0,40,1",
            "0,0,95,1",
            "0,-190,1,1",
        ] {
            assert!(BBox::parse(s).is_err(), "{s:?} accepted");
        }
    }
}
