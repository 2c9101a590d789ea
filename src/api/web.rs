//! The live map at `/` (issue 12) and the files it loads, all embedded in the binary: the
//! page needs no CDN, no build step and no network beyond this daemon.
//!
//! Our own files are `src/api/web/{index.html,map.js,geo.js,map.css}`; the third-party ones
//! (Leaflet, topojson-client, world-atlas's land outline, each with its licence) are copied
//! verbatim from pinned npm packages by `scripts/vendor-web.sh` into `src/api/web/vendor/`.
//! Everything is served under `/assets/` with its content type, `Cache-Control: no-cache`
//! and a strong `ETag`: a browser revalidates on each visit and gets a bodiless 304 while the
//! binary is the same, and the new file as soon as it is not.
//!
//! The page learns its settings (`[map]`'s tile server, `[receiver]`, the prediction
//! horizons) from a JSON object written into the page when the router is built. The old
//! table page stays at `/table`.

use crate::config::Config;
use axum::extract::rejection::PathRejection;
use axum::extract::Path;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use serde::Serialize;
use std::sync::{Arc, LazyLock};

use super::ApiError;

/// One embedded file.
struct Asset {
    /// Path under `/assets/`.
    path: &'static str,
    content_type: &'static str,
    bytes: &'static [u8],
}

const JS: &str = "text/javascript; charset=utf-8";
const CSS: &str = "text/css; charset=utf-8";
const JSON: &str = "application/json";
const PNG: &str = "image/png";
const TEXT: &str = "text/plain; charset=utf-8";
const HTML: &str = "text/html; charset=utf-8";

macro_rules! asset {
    ($path:literal, $type:expr) => {
        Asset {
            path: $path,
            content_type: $type,
            bytes: include_bytes!(concat!("web/", $path)),
        }
    };
}

/// Every file under `/assets/`.
const ASSETS: &[Asset] = &[
    asset!("map.js", JS),
    asset!("geo.js", JS),
    asset!("map.css", CSS),
    asset!("vendor/VERSIONS", TEXT),
    asset!("vendor/leaflet/leaflet.js", JS),
    asset!("vendor/leaflet/leaflet.css", CSS),
    asset!("vendor/leaflet/images/layers.png", PNG),
    asset!("vendor/leaflet/images/layers-2x.png", PNG),
    asset!("vendor/leaflet/LICENSE", TEXT),
    asset!("vendor/topojson-client/topojson-client.min.js", JS),
    asset!("vendor/topojson-client/LICENSE", TEXT),
    asset!("vendor/world-atlas/land-110m.json", JSON),
    asset!("vendor/world-atlas/LICENSE", TEXT),
];

/// The map page, with [`SETTINGS_PLACEHOLDER`] where its settings go.
const INDEX_HTML: &str = include_str!("web/index.html");
/// Replaced by the settings' JSON in [`INDEX_HTML`].
const SETTINGS_PLACEHOLDER: &str = "{{MAP_SETTINGS}}";
/// The table page of the first versions, kept at `/table`.
const TABLE_HTML: &str = include_str!("web/table.html");

/// FNV-1a, 64 bits: a fingerprint for `ETag`s (not a security hash: the files are ours).
fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// A strong entity tag of `bytes`.
fn etag_of(bytes: &[u8]) -> HeaderValue {
    // Hex digits and quotes only: always a valid header value.
    HeaderValue::from_str(&format!("\"{:016x}\"", fnv1a64(bytes)))
        .unwrap_or(HeaderValue::from_static("\"0\""))
}

/// [`ASSETS`]' tags, computed on first use (a hash over 250 KB, once).
static ASSET_ETAGS: LazyLock<Vec<HeaderValue>> =
    LazyLock::new(|| ASSETS.iter().map(|a| etag_of(a.bytes)).collect());

/// Whether the request's `If-None-Match` names `etag` (or is `*`).
fn not_modified(headers: &HeaderMap, etag: &HeaderValue) -> bool {
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .map(|t| t.trim().trim_start_matches("W/"))
        .any(|t| t == "*" || t.as_bytes() == etag.as_bytes())
}

/// A file's response: 304 when the client has it, else the body, with its type and tag.
fn file_response(
    headers: &HeaderMap,
    content_type: &'static str,
    etag: &HeaderValue,
    body: axum::body::Body,
) -> Response {
    let common = [
        (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
        (header::ETAG, etag.clone()),
        (
            header::X_CONTENT_TYPE_OPTIONS,
            HeaderValue::from_static("nosniff"),
        ),
    ];
    if not_modified(headers, etag) {
        return (StatusCode::NOT_MODIFIED, common).into_response();
    }
    (
        common,
        [(header::CONTENT_TYPE, HeaderValue::from_static(content_type))],
        body,
    )
        .into_response()
}

/// `GET /assets/{*path}`.
async fn asset(headers: HeaderMap, path: Result<Path<String>, PathRejection>) -> Response {
    let Ok(Path(path)) = path else {
        return ApiError::BadRequest("bad asset path".into()).into_response();
    };
    let Some((i, a)) = ASSETS.iter().enumerate().find(|(_, a)| a.path == path) else {
        return ApiError::NotFound(format!("no asset {path:?}")).into_response();
    };
    let Some(etag) = ASSET_ETAGS.get(i) else {
        return ApiError::NotFound(format!("no asset {path:?}")).into_response();
    };
    file_response(
        &headers,
        a.content_type,
        etag,
        axum::body::Body::from(a.bytes),
    )
}

/// What the page needs to know of the configuration.
#[derive(Serialize)]
struct PageSettings<'a> {
    version: &'static str,
    /// `null` when `map.tile_url` is empty: the page then shows the outline only.
    tiles: Option<Tiles<'a>>,
    /// `null` without `[receiver]`: no range rings.
    receiver: Option<Receiver>,
    range_rings_km: &'a [f64],
    prediction_horizons_s: &'a [f64],
}

#[derive(Serialize)]
struct Tiles<'a> {
    url: &'a str,
    attribution: &'a str,
    max_zoom: u8,
}

#[derive(Serialize)]
struct Receiver {
    lat_deg: f64,
    lon_deg: f64,
}

/// The page with its settings: JSON in a `<script type="application/json">`, with `<`, `>`
/// and `&` escaped so no configured text can close the element.
fn index_html(config: &Config) -> String {
    let map = &config.map;
    let settings = PageSettings {
        version: env!("CARGO_PKG_VERSION"),
        tiles: map.tiles_on().then_some(Tiles {
            url: &map.tile_url,
            attribution: &map.tile_attribution,
            max_zoom: map.tile_max_zoom,
        }),
        receiver: config.receiver.map(|r| Receiver {
            lat_deg: r.lat_deg,
            lon_deg: r.lon_deg,
        }),
        range_rings_km: &map.range_rings_km,
        prediction_horizons_s: &config.tracker.prediction_horizons_s,
    };
    // Numbers, strings and arrays of them: serialisation cannot fail.
    let json = serde_json::to_string(&settings)
        .unwrap_or_else(|_| "{}".into())
        .replace('<', "\\u003c")
        .replace('>', "\\u003e")
        .replace('&', "\\u0026");
    INDEX_HTML.replace(SETTINGS_PLACEHOLDER, &json)
}

/// A page built once, with its tag.
struct Page {
    html: axum::body::Bytes,
    etag: HeaderValue,
}

impl Page {
    fn new(html: String) -> Self {
        let etag = etag_of(html.as_bytes());
        Self {
            html: html.into(),
            etag,
        }
    }

    fn response(&self, headers: &HeaderMap) -> Response {
        file_response(
            headers,
            HTML,
            &self.etag,
            axum::body::Body::from(self.html.clone()),
        )
    }
}

/// `/` (the map), `/table` and `/assets/{*path}`.
pub fn routes<S: Clone + Send + Sync + 'static>(config: &Config) -> Router<S> {
    let map = Arc::new(Page::new(index_html(config)));
    let table = Arc::new(Page::new(TABLE_HTML.to_string()));
    Router::new()
        .route(
            "/",
            get(move |headers: HeaderMap| {
                let map = map.clone();
                async move { map.response(&headers) }
            }),
        )
        .route(
            "/table",
            get(move |headers: HeaderMap| {
                let table = table.clone();
                async move { table.response(&headers) }
            }),
        )
        .route("/assets/{*path}", get(asset))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_asset_is_embedded_once_with_a_type_matching_its_name() {
        let mut seen = std::collections::HashSet::new();
        for a in ASSETS {
            assert!(seen.insert(a.path), "{} twice", a.path);
            assert!(!a.bytes.is_empty(), "{} empty", a.path);
            let ext = a.path.rsplit_once('.').map_or("", |(_, e)| e);
            let want = match ext {
                "js" => JS,
                "css" => CSS,
                "json" => JSON,
                "png" => PNG,
                _ => TEXT,
            };
            assert_eq!(a.content_type, want, "{}", a.path);
        }
    }

    #[test]
    fn fnv1a64_matches_its_reference_vectors() {
        // From the FNV reference (Fowler, Noll, Vo: test vectors for FNV-1a 64).
        assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
        assert_eq!(fnv1a64(b"a"), 0xaf63dc4c8601ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x85944171f73967e8);
    }

    #[test]
    fn if_none_match_lists_and_weak_tags_are_understood() {
        let tag = HeaderValue::from_static("\"00000000000000ab\"");
        let mut h = HeaderMap::new();
        assert!(!not_modified(&h, &tag));
        h.insert(
            header::IF_NONE_MATCH,
            HeaderValue::from_static("\"x\", W/\"00000000000000ab\""),
        );
        assert!(not_modified(&h, &tag));
        h.insert(header::IF_NONE_MATCH, HeaderValue::from_static("\"x\""));
        assert!(!not_modified(&h, &tag));
        h.insert(header::IF_NONE_MATCH, HeaderValue::from_static("*"));
        assert!(not_modified(&h, &tag));
    }

    #[test]
    fn configured_text_cannot_close_the_settings_element() {
        let c = Config::from_toml_str(
            "[map]\ntile_url = \"https://t.example/{z}/{x}/{y}.png\"\n\
             tile_attribution = \"</script><script>alert(1)</script> & co\"\n\
             [receiver]\nlat_deg = 33.9425\nlon_deg = -118.408\n",
        )
        .unwrap();
        let html = index_html(&c);
        assert!(!html.contains(SETTINGS_PLACEHOLDER));
        assert!(!html.contains("alert(1)</script>"));
        let start = html.find("id=\"map-settings\"").unwrap();
        let json_start = start + html[start..].find('>').unwrap() + 1;
        let json_end = json_start + html[json_start..].find("</script>").unwrap();
        let v: serde_json::Value = serde_json::from_str(&html[json_start..json_end]).unwrap();
        assert_eq!(
            v["tiles"]["attribution"],
            "</script><script>alert(1)</script> & co"
        );
        assert_eq!(v["receiver"]["lat_deg"], 33.9425);
        assert_eq!(v["range_rings_km"][1], 100.0);
        assert_eq!(
            v["prediction_horizons_s"],
            serde_json::json!([30.0, 60.0, 120.0])
        );
        let plain = index_html(&Config::default_config().unwrap());
        assert!(
            plain.contains("\"tiles\":null,\"receiver\":null"),
            "{plain}"
        );
    }
}
