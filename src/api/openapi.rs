//! `GET /api/v1/openapi.json`: the API described in OpenAPI 3.1, derived from the handlers'
//! `#[utoipa::path]` annotations and the response types themselves (`utoipa::ToSchema`), so
//! a field added to a type is in the document with it. `tests/api_openapi.rs` checks that
//! every route is described and that real responses carry every field the document requires.
//!
//! Two things the annotations cannot say are written into the document after utoipa
//! ([`document`]): each query parameter's pattern, from [`super::params`] (the handlers check
//! the same expressions), and the stream's events. OpenAPI 3.1 describes a
//! `text/event-stream` by the schema of one event, `{event, data, id, retry}` (what
//! schemathesis checks each event against); `data` is JSON text whose schema
//! (`contentSchema`) depends on the event's name.

use super::ErrorBody;
use crate::daemon::registry::TrackState;
use axum::body::Bytes;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use serde_json::{json, Value};
use std::sync::LazyLock;
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
pub(super) async fn openapi_json() -> Response {
    // Built and serialised once: the document does not change while the daemon runs.
    static DOCUMENT: LazyLock<Bytes> =
        LazyLock::new(|| Bytes::from(serde_json::to_vec(&document()).unwrap_or_default()));
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        DOCUMENT.clone(),
    )
        .into_response()
}

/// The OpenAPI document: utoipa's, with the parameters' patterns and the events' schema.
pub fn document() -> Value {
    let mut doc = serde_json::to_value(ApiDoc::openapi()).unwrap_or_default();
    for (path, name, pattern) in super::params::PATTERNS {
        if let Some(params) = doc["paths"][path]["get"]["parameters"].as_array_mut() {
            for p in params.iter_mut().filter(|p| p["name"] == name) {
                p["schema"]["pattern"] = Value::from(pattern);
            }
        }
    }
    let events = &mut doc["paths"]["/api/v1/stream"]["get"]["responses"]["200"]["content"]
        ["text/event-stream"]["schema"];
    *events = sse_event_schema();
    doc
}

/// One server-sent event of `/api/v1/stream`: a `track`, `retire` or `stats` event with JSON
/// data of that type.
fn sse_event_schema() -> Value {
    let event = |name: &str, schema: &str| {
        json!({
            "type": "object",
            "required": ["event", "data"],
            "properties": {
                "event": {"const": name},
                "data": {
                    "type": "string",
                    "contentMediaType": "application/json",
                    "contentSchema": {"$ref": format!("#/components/schemas/{schema}")},
                },
                "id": {"type": "string"},
                "retry": {"type": "integer", "minimum": 0},
            },
            "additionalProperties": false,
        })
    };
    json!({
        "oneOf": [event("track", "Track"), event("retire", "Retire"), event("stats", "Stats")],
    })
}
