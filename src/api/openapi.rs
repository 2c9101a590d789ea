//! `GET /api/v1/openapi.json`: the API described in OpenAPI 3.1, derived from the handlers'
//! `#[utoipa::path]` annotations and the response types themselves (`utoipa::ToSchema`), so
//! a field added to a type is in the document with it. `tests/api_openapi.rs` checks that
//! every route is described and that real responses carry every field the document requires.

use super::ErrorBody;
use crate::daemon::registry::TrackState;
use axum::Json;
use serde::Serialize;
use utoipa::OpenApi;

/// `GET /api/v1/tracks`' body (the handler serialises it from a cache; this is its shape).
#[derive(Serialize, utoipa::ToSchema)]
pub struct Tracks {
    /// Feed time of the newest frame, s.
    pub time: f64,
    pub tracks: Vec<TrackState>,
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "adsb-tracker",
        description = "Tracked aircraft: estimates, uncertainty and flight-mode labels. Errors are {\"error\": \"...\"}.",
    ),
    paths(
        super::tracks,
        super::track,
        super::prediction,
        super::history,
        super::stats,
        super::healthz,
        super::metrics,
        super::stream::stream,
        super::readsb::aircraft,
        super::readsb::receiver,
        openapi_json,
    ),
    components(schemas(ErrorBody, super::stream::Retire, Tracks)),
    tags(
        (name = "tracks", description = "Tracks, predictions, trails"),
        (name = "stream", description = "Server-sent events"),
        (name = "daemon", description = "Counters, health, metrics"),
        (name = "readsb", description = "readsb's JSON, for tar1090"),
    )
)]
pub struct ApiDoc;

/// This document.
#[utoipa::path(get, path = "/api/v1/openapi.json", tag = "daemon",
    responses((status = 200, description = "The OpenAPI 3.1 document", body = Object)))]
pub(super) async fn openapi_json() -> Json<utoipa::openapi::OpenApi> {
    Json(ApiDoc::openapi())
}
