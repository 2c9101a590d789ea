//! The HTTP API (axum). Reads published snapshots only; never talks to the tasks.
//!
//! Errors are `{"error": "..."}` with a 4xx status: 400 for malformed input, 404 for an unknown
//! aircraft or endpoint.

mod fair;
pub mod openapi;
pub mod params;
pub mod readsb;
pub mod server;
pub mod stream;
mod tracks_cache;
mod web;

use crate::daemon::registry::TrackState;
use crate::daemon::Shared;
use crate::decode::Icao;
use axum::body::{Body, Bytes};
use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::extract::{FromRef, Path, Query, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Duration;
use tracks_cache::{accepts_gzip, not_modified, tracks_body, TracksCache};

/// The one error type of the API.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// Malformed input: 400.
    #[error("{0}")]
    BadRequest(String),
    /// Unknown aircraft or endpoint: 404.
    #[error("{0}")]
    NotFound(String),
    /// The server cannot answer now: 503.
    #[error("{0}")]
    Unavailable(String),
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = match self {
            ApiError::BadRequest(_) => StatusCode::BAD_REQUEST,
            ApiError::NotFound(_) => StatusCode::NOT_FOUND,
            ApiError::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
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

/// Every error: `{"error": "..."}`.
#[derive(Serialize, utoipa::ToSchema)]
struct ErrorBody {
    error: String,
}

/// The API's state: the daemon's shared state and the cached `/api/v1/tracks` body.
#[derive(Clone)]
struct ApiState {
    shared: Shared,
    tracks: Arc<TracksCache>,
    /// `now` of readsb's `aircraft.json`.
    readsb_now: Arc<readsb::NowClock>,
}

impl FromRef<ApiState> for Shared {
    fn from_ref(api: &ApiState) -> Shared {
        api.shared.clone()
    }
}

/// The router, with its state and its layers: what `serve` runs and what tests `oneshot`.
///
/// Every response with an error status is the API's `{"error": ...}` JSON, the framework's
/// own (405 with its `Allow`, extractor rejections, the request timeout's 503) included:
/// [`json_errors`] rewrites whatever is not JSON yet.
pub fn app(shared: Shared) -> Router {
    let server = &shared.config.server;
    let request_timeout =
        Duration::try_from_secs_f64(server.request_timeout_s).unwrap_or(Duration::from_secs(10));
    let state = ApiState {
        tracks: Arc::new(TracksCache::new(
            Duration::from_millis(server.tracks_cache_ms),
            server.tracks_gzip_level,
        )),
        readsb_now: Arc::new(readsb::NowClock::default()),
        shared,
    };
    let pages = web::routes(&state.shared.config);
    let tar1090_dir = state.shared.config.server.readsb.tar1090_dir.clone();
    let router = Router::new()
        .merge(pages)
        .route("/api/v1/openapi.json", get(openapi::openapi_json))
        .route("/api/v1/tracks", get(tracks))
        .route("/api/v1/tracks/{icao}", get(track))
        .route("/api/v1/tracks/{icao}/prediction", get(prediction))
        .route("/api/v1/tracks/{icao}/history", get(history))
        .route("/api/v1/stream", get(stream::stream))
        .route("/api/v1/stats", get(stats))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .route("/data/aircraft.json", get(readsb::aircraft))
        .route("/data/receiver.json", get(readsb::receiver));
    // tar1090's page, from the user's copy of its html/ (paths cannot leave the directory;
    // a file that is not there is a 404 {"error"} like any other); its data/ is ours.
    let router = if tar1090_dir.is_empty() {
        router
    } else {
        router
            .route("/tar1090/data/aircraft.json", get(readsb::aircraft))
            .route("/tar1090/data/receiver.json", get(readsb::receiver))
            .route(
                "/tar1090",
                get(|| async { axum::response::Redirect::permanent("/tar1090/") }),
            )
            .nest_service(
                "/tar1090/",
                tower_http::services::ServeDir::new(tar1090_dir),
            )
    };
    router
        .fallback(|| async { ApiError::NotFound("no such endpoint".into()) })
        .with_state(state)
        .layer(tower_http::timeout::TimeoutLayer::with_status_code(
            StatusCode::SERVICE_UNAVAILABLE,
            request_timeout,
        ))
        .layer(axum::middleware::map_response(json_errors))
}

/// Longest error text kept from a framework rejection's body.
const MAX_ERROR_TEXT_BYTES: usize = 1024;

/// Turns an error response that is not JSON (axum's 405 and rejections, the timeout's 503)
/// into `{"error": ...}`: its text body if it has one, else the status's reason. Headers
/// such as 405's `Allow` are kept.
async fn json_errors(response: Response) -> Response {
    let status = response.status();
    let is_json = response
        .headers()
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return response;
    }
    let (mut parts, body) = response.into_parts();
    let text = axum::body::to_bytes(body, MAX_ERROR_TEXT_BYTES)
        .await
        .unwrap_or_default();
    let text = String::from_utf8_lossy(&text);
    let error = match text.trim() {
        "" => match status {
            StatusCode::METHOD_NOT_ALLOWED => "method not allowed".to_string(),
            StatusCode::SERVICE_UNAVAILABLE => "request timed out".to_string(),
            s => s.canonical_reason().unwrap_or("error").to_lowercase(),
        },
        t => t.to_string(),
    };
    let body = serde_json::to_vec(&ErrorBody { error }).unwrap_or_default();
    parts.headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    parts.headers.remove(header::CONTENT_LENGTH);
    Response::from_parts(parts, Body::from(body))
}

/// A JSON body already serialised; `gzip` when it is gzip-coded. A large one is sent in
/// slices on the server's bulk lane ([`fair`]).
fn json_sliced(body: Bytes, gzip: bool) -> Response {
    let body = if body.len() > fair::SLICE_BYTES {
        Body::new(fair::Sliced::new(body))
    } else {
        Body::from(body)
    };
    let mut response = (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response();
    if gzip {
        response
            .headers_mut()
            .insert(header::CONTENT_ENCODING, HeaderValue::from_static("gzip"));
    }
    response
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

/// Every track, or those in `bbox` and of the `mode`s asked, with the feed time. Served
/// from [`TracksCache`]: the full list as cached, gzip-coded for a client that accepts it;
/// a filtered list is serialised from the cached tracks. `ETag` names the cache's
/// generation, and `If-None-Match` with it gets a 304.
#[utoipa::path(get, path = "/api/v1/tracks", tag = "tracks",
    params(
        ("bbox" = Option<String>, Query, description = "south,west,north,east in degrees (west > east crosses the antimeridian; south must not be north of north); empty is no filter"),
        ("mode" = Option<String>, Query, description = "comma-separated flight-mode labels: CV, CA, CT, CH, CHCA (any case); empty is no filter"),
    ),
    responses(
        (status = 200, description = "The tracks with an estimate (gzip-coded when the client accepts it; `ETag` names the list's generation)", body = openapi::Tracks),
        (status = 304, description = "Not modified: `If-None-Match` named the current generation"),
        (status = 400, description = "A malformed or unknown parameter, or a box whose latitudes are out of order", body = ErrorBody),
    ))]
async fn tracks(
    State(api): State<ApiState>,
    request_headers: axum::http::HeaderMap,
    query: Result<Query<TracksQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(q) = query.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let bbox = params::tracks_bbox(q.bbox.as_deref().unwrap_or(""))?;
    let modes = params::modes(q.mode.as_deref().unwrap_or(""))?;
    let filtered = bbox.is_some() || modes.is_some();
    let gzip_ok = !filtered && accepts_gzip(&request_headers);
    let cached = api.tracks.get(&api.shared, gzip_ok).await?;
    let (body, gzip, etag) = match (&cached.gzip, gzip_ok) {
        (Some(z), true) => (Some(z.clone()), true, cached.gzip_etag()),
        _ => (None, false, cached.etag()),
    };
    let mut response = if not_modified(&request_headers, &etag) {
        StatusCode::NOT_MODIFIED.into_response()
    } else if !filtered {
        json_sliced(body.unwrap_or_else(|| cached.body.clone()), gzip)
    } else {
        let selected = cached
            .tracks
            .iter()
            .filter(|t| bbox.is_none_or(|b| b.contains(t.lat, t.lon)))
            .filter(|t| modes.as_ref().is_none_or(|m| m.contains(&t.mode)));
        json_sliced(tracks_body(cached.time, selected), false)
    };
    let headers = response.headers_mut();
    headers.insert(header::ETAG, etag);
    // A cache may keep it, and must ask (If-None-Match) before reusing it.
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    if !filtered {
        headers.insert(header::VARY, HeaderValue::from_static("accept-encoding"));
    }
    Ok(response)
}

/// The `{icao}` of a path: a 400 `{"error"}` for anything but six hex digits, bad
/// percent-encoding and invalid UTF-8 included.
fn icao_of(path: Result<Path<String>, PathRejection>) -> Result<Icao, ApiError> {
    let Path(icao) = path.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    icao.parse().map_err(ApiError::BadRequest)
}

#[utoipa::path(get, path = "/api/v1/tracks/{icao}", tag = "tracks",
    params(("icao" = String, Path, description = "ICAO address, 6 hex digits", pattern = "^[0-9a-fA-F]{6}$")),
    responses(
        (status = 200, description = "The aircraft's track", body = crate::daemon::registry::TrackState),
        (status = 400, description = "Not 6 hex digits", body = ErrorBody),
        (status = 404, description = "No track for this aircraft", body = ErrorBody),
    ))]
async fn track(
    State(shared): State<Shared>,
    path: Result<Path<String>, PathRejection>,
) -> Result<Json<TrackState>, ApiError> {
    let icao = icao_of(path)?;
    shared
        .registry
        .get(icao)
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("no track for {icao}")))
}

#[derive(Serialize, utoipa::ToSchema)]
#[schema(as = Predictions)]
struct PredictionBody {
    #[schema(value_type = String, pattern = "^[0-9a-f]{6}$")]
    icao: Icao,
    /// Time of the estimate the predictions start from, s.
    t: f64,
    mode: &'static str,
    predictions: Vec<crate::daemon::registry::Prediction>,
}

/// Positions predicted by the current mode's model at the configured horizons.
#[utoipa::path(get, path = "/api/v1/tracks/{icao}/prediction", tag = "tracks",
    params(("icao" = String, Path, description = "ICAO address, 6 hex digits", pattern = "^[0-9a-fA-F]{6}$")),
    responses(
        (status = 200, description = "Predicted positions", body = PredictionBody),
        (status = 400, description = "Not 6 hex digits", body = ErrorBody),
        (status = 404, description = "No track for this aircraft", body = ErrorBody),
    ))]
async fn prediction(
    State(shared): State<Shared>,
    path: Result<Path<String>, PathRejection>,
) -> Result<Json<PredictionBody>, ApiError> {
    let icao = icao_of(path)?;
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

/// `GET /api/v1/tracks/{icao}/history` body.
#[derive(Serialize, utoipa::ToSchema)]
#[schema(as = History)]
struct HistoryBody {
    #[schema(value_type = String, pattern = "^[0-9a-f]{6}$")]
    icao: Icao,
    /// Oldest first.
    points: Vec<crate::daemon::history::TrailPoint>,
}

/// The aircraft's recent trail of estimated positions (`[history]`), oldest first.
#[utoipa::path(get, path = "/api/v1/tracks/{icao}/history", tag = "tracks",
    params(("icao" = String, Path, description = "ICAO address, 6 hex digits", pattern = "^[0-9a-fA-F]{6}$")),
    responses(
        (status = 200, description = "The trail, oldest first", body = HistoryBody),
        (status = 400, description = "Not 6 hex digits", body = ErrorBody),
        (status = 404, description = "No track for this aircraft", body = ErrorBody),
    ))]
async fn history(
    State(shared): State<Shared>,
    path: Result<Path<String>, PathRejection>,
) -> Result<Json<HistoryBody>, ApiError> {
    let icao = icao_of(path)?;
    let points = shared
        .registry
        .history(icao)
        .ok_or_else(|| ApiError::NotFound(format!("no track for {icao}")))?;
    Ok(Json(HistoryBody { icao, points }))
}

#[utoipa::path(get, path = "/api/v1/stats", tag = "daemon",
    responses((status = 200, description = "The daemon's counters", body = crate::daemon::stats::StatsSnapshot)))]
async fn stats(State(shared): State<Shared>) -> Json<crate::daemon::stats::StatsSnapshot> {
    Json(shared.stats.snapshot())
}

#[derive(Serialize, utoipa::ToSchema)]
struct Health {
    /// "ok", or "degraded" while a configured live feed is down or silent (no frame for
    /// half its `silence_timeout_s`), or the ingest lag is past `pipeline.max_lag_s`.
    status: &'static str,
    feed_time: f64,
    /// Age of the frames being routed, s (0 when idle).
    ingest_lag_s: f64,
    tracks: usize,
    feeds: Vec<crate::feed::tcp::FeedStatusSnapshot>,
    /// A cluster node's roles, connection, partitions and counters (absent in one process).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(required = false)]
    cluster: Option<crate::cluster::ClusterSnapshot>,
}

/// 200 while the daemon can serve fresh data; 503 while a live feed is down or silent, or
/// ingest lags more than `pipeline.max_lag_s` behind (the API keeps serving the last state
/// meanwhile).
#[utoipa::path(get, path = "/healthz", tag = "daemon",
    responses(
        (status = 200, description = "Serving fresh data", body = Health),
        (status = 503, description = "Degraded: a feed down or silent, ingest lagging, or a pipeline task died", body = Health),
    ))]
async fn healthz(State(shared): State<Shared>) -> Response {
    let feeds = shared.stats.feeds();
    let feeds_down = feeds.iter().any(|f| f.silent);
    let lag_s = shared.stats.ingest_lag_s();
    let failed = shared
        .stats
        .pipeline_failed
        .load(std::sync::atomic::Ordering::Acquire);
    let cluster = shared.stats.cluster.as_ref().map(|c| c.snapshot());
    // A cluster node cut off from NATS serves nothing fresh.
    let bus_down = cluster.as_ref().is_some_and(|c| !c.connected);
    let degraded = failed || feeds_down || bus_down || lag_s > shared.stats.max_lag_s();
    let body = Health {
        cluster,
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

#[utoipa::path(get, path = "/metrics", tag = "daemon",
    responses((status = 200, description = "Prometheus / OpenMetrics text", body = String,
        content_type = "application/openmetrics-text; version=1.0.0; charset=utf-8")))]
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
