//! The `/api/v1/tracks` body, serialised (and gzip-compressed) once for many readers.
//!
//! At fleet scale the full list is large (1,000 tracks are ~1.7 MB of JSON, ~0.5 MB gzipped)
//! and many clients poll it. One [`CachedTracks`] per registry generation serves them all:
//! - **Never waited for once built.** A reader that finds the cache stale starts one rebuild
//!   in the background (on the bulk lane's blocking threads, at its niceness) and is answered
//!   at once from the previous body; only the very first request, or every request with
//!   `server.tracks_cache_ms = 0`, waits for a build.
//! - **gzip once per generation.** While clients have asked for gzip within
//!   [`GZIP_WANTED_FOR`], each rebuild also compresses the body (`server.tracks_gzip_level`);
//!   a gzip request that finds no compressed body yet gets the plain one (always a valid
//!   answer) and the next rebuild compresses.
//! - **Validators.** Each body's `ETag` is its generation (`"g<generation>"`, plus `-gzip`
//!   for the compressed one): a client that sends it back in `If-None-Match` gets a 304
//!   without a body while nothing changed.

use super::ApiError;
use crate::daemon::registry::TrackState;
use crate::daemon::Shared;
use arc_swap::ArcSwapOption;
use axum::body::Bytes;
use axum::http::{header, HeaderMap, HeaderValue};
use serde::Serialize;
use std::io::Write;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// After a gzip request, rebuilds keep compressing for this long (a polling client asks
/// again well within it; a client that stopped costs no more CPU after it).
pub const GZIP_WANTED_FOR: Duration = Duration::from_secs(30);

/// Every track as `/api/v1/tracks` serves it, built once for many readers.
pub struct CachedTracks {
    /// [`crate::daemon::registry::Registry::generation`] when it was read.
    pub generation: u64,
    built: Instant,
    /// Feed time when it was read, s.
    pub time: f64,
    pub tracks: Vec<TrackState>,
    /// The unfiltered response body.
    pub body: Bytes,
    /// `body` gzip-compressed, when clients asked for gzip lately.
    pub gzip: Option<Bytes>,
}

impl CachedTracks {
    /// `ETag` of the plain body (and of any filtered list made from these tracks).
    pub fn etag(&self) -> HeaderValue {
        etag(self.generation, false)
    }

    /// `ETag` of the gzip-compressed body.
    pub fn gzip_etag(&self) -> HeaderValue {
        etag(self.generation, true)
    }
}

/// `"g<generation>"`, or `"g<generation>-gzip"`: a strong validator differs between codings.
fn etag(generation: u64, gzip: bool) -> HeaderValue {
    let tag = if gzip {
        format!("\"g{generation}-gzip\"")
    } else {
        format!("\"g{generation}\"")
    };
    // Digits, letters, quotes and a dash are valid header bytes.
    HeaderValue::from_str(&tag).unwrap_or(HeaderValue::from_static("\"g\""))
}

/// The last [`CachedTracks`]. It is current while the registry has not changed since; a
/// changed registry is still served from it for `max_age` (`server.tracks_cache_ms`), and
/// then while its replacement is being built.
pub struct TracksCache {
    max_age: Duration,
    /// `server.tracks_gzip_level`; 0: never compress.
    gzip_level: u32,
    current: ArcSwapOption<CachedTracks>,
    /// A background rebuild is under way (at most one at a time).
    rebuilding: AtomicBool,
    /// Builds a request waits for (no body yet, or `max_age` 0): one at a time; the others
    /// wait for it and take its result.
    building: tokio::sync::Mutex<()>,
    /// When a client last asked for gzip, ms after `created` (0: never).
    gzip_asked_ms: AtomicU64,
    created: Instant,
}

impl TracksCache {
    pub fn new(max_age: Duration, gzip_level: u32) -> Self {
        Self {
            max_age,
            gzip_level: gzip_level.min(9),
            current: ArcSwapOption::empty(),
            rebuilding: AtomicBool::new(false),
            building: tokio::sync::Mutex::new(()),
            gzip_asked_ms: AtomicU64::new(0),
            created: Instant::now(),
        }
    }

    fn gzip_wanted(&self) -> bool {
        let asked = self.gzip_asked_ms.load(Ordering::Relaxed);
        asked > 0 && self.created.elapsed().as_millis() as u64 <= asked + since_ms(GZIP_WANTED_FOR)
    }

    /// Is `c` what a reader may be given now?
    fn fresh(&self, c: &CachedTracks, shared: &Shared, gzip: bool) -> bool {
        let current = c.generation == shared.registry.generation()
            || (!self.max_age.is_zero() && c.built.elapsed() < self.max_age);
        current && !(gzip && c.gzip.is_none())
    }

    /// The cached tracks; `gzip` when the client accepts gzip (and the server compresses).
    /// Waits for a build only when there is no body yet or `max_age` is 0; otherwise a
    /// stale body starts a rebuild in the background and is served meanwhile.
    pub async fn get(
        self: &Arc<Self>,
        shared: &Shared,
        gzip: bool,
    ) -> Result<Arc<CachedTracks>, ApiError> {
        let gzip = gzip && self.gzip_level > 0;
        if gzip {
            let now_ms = (self.created.elapsed().as_millis() as u64).max(1);
            self.gzip_asked_ms.store(now_ms, Ordering::Relaxed);
        }
        if let Some(c) = self.current.load_full() {
            if self.fresh(&c, shared, gzip) {
                return Ok(c);
            }
            if !self.max_age.is_zero() {
                self.rebuild_in_background(shared);
                return Ok(c);
            }
        }
        let _one = self.building.lock().await;
        if let Some(c) = self.current.load_full() {
            if self.fresh(&c, shared, gzip) {
                return Ok(c);
            }
        }
        let (reader, level) = (shared.clone(), self.build_level(gzip));
        let built = super::fair::spawn_build(move || build(&reader, level))
            .await
            .map_err(|e| ApiError::Unavailable(format!("building the track list: {e}")))?;
        let built = Arc::new(built);
        self.current.store(Some(built.clone()));
        Ok(built)
    }

    /// The gzip level a build uses: 0 unless gzip is asked now or was lately.
    fn build_level(&self, gzip_now: bool) -> u32 {
        if gzip_now || self.gzip_wanted() {
            self.gzip_level
        } else {
            0
        }
    }

    /// Starts a rebuild on a blocking thread unless one is under way.
    fn rebuild_in_background(self: &Arc<Self>, shared: &Shared) {
        if self
            .rebuilding
            .compare_exchange(false, true, Ordering::AcqRel, Ordering::Acquire)
            .is_err()
        {
            return;
        }
        let (cache, reader, level) = (self.clone(), shared.clone(), self.build_level(false));
        super::fair::spawn_build(move || {
            // Cleared however the build ends, so a failed one does not stop later ones.
            let _done = Rebuilding(&cache.rebuilding);
            let built = build(&reader, level);
            cache.current.store(Some(Arc::new(built)));
        });
    }
}

/// Clears the "rebuild under way" flag when dropped.
struct Rebuilding<'a>(&'a AtomicBool);

impl Drop for Rebuilding<'_> {
    fn drop(&mut self) {
        self.0.store(false, Ordering::Release);
    }
}

fn since_ms(d: Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}

/// Reads every track and serialises (and with `gzip_level` > 0 compresses) the body.
fn build(shared: &Shared, gzip_level: u32) -> CachedTracks {
    let generation = shared.registry.generation();
    let time = shared.stats.feed_time_s();
    let tracks = shared.registry.all();
    let body = tracks_body(time, &tracks);
    let gzip = (gzip_level > 0).then(|| gzip_bytes(&body, gzip_level));
    CachedTracks {
        generation,
        built: Instant::now(),
        time,
        tracks,
        body,
        gzip,
    }
}

/// `data` gzip-compressed at `level` (1..=9).
pub fn gzip_bytes(data: &[u8], level: u32) -> Bytes {
    let mut enc = flate2::write::GzEncoder::new(
        Vec::with_capacity(data.len() / 3),
        flate2::Compression::new(level.clamp(1, 9)),
    );
    // Writing to a Vec cannot fail.
    let _ = enc.write_all(data);
    Bytes::from(enc.finish().unwrap_or_default())
}

/// `GET /api/v1/tracks` body.
#[derive(Serialize)]
struct TracksBody<'a> {
    /// Feed time of the newest frame, s.
    time: f64,
    tracks: Vec<&'a TrackState>,
}

/// `{"time": ..., "tracks": [...]}` for these tracks.
pub fn tracks_body<'a>(time: f64, tracks: impl IntoIterator<Item = &'a TrackState>) -> Bytes {
    let body = TracksBody {
        time,
        tracks: tracks.into_iter().collect(),
    };
    // Serialising plain numbers and strings into memory cannot fail.
    Bytes::from(serde_json::to_vec(&body).unwrap_or_default())
}

/// Does this request accept a gzip-coded response (RFC 9110 §12.5.3: `gzip` or `x-gzip`,
/// or `*`, with a non-zero q)?
pub fn accepts_gzip(headers: &HeaderMap) -> bool {
    let mut gzip = None;
    let mut any = None;
    for value in headers.get_all(header::ACCEPT_ENCODING) {
        let Ok(value) = value.to_str() else { continue };
        for item in value.split(',') {
            let mut parts = item.split(';');
            let coding = parts.next().unwrap_or("").trim();
            let q = parts
                .filter_map(|p| p.trim().strip_prefix("q=").or(p.trim().strip_prefix("Q=")))
                .filter_map(|q| q.trim().parse::<f32>().ok())
                .next()
                .unwrap_or(1.0);
            if coding.eq_ignore_ascii_case("gzip") || coding.eq_ignore_ascii_case("x-gzip") {
                gzip = Some(q > 0.0);
            } else if coding == "*" {
                any = Some(q > 0.0);
            }
        }
    }
    gzip.or(any).unwrap_or(false)
}

/// Does `If-None-Match` name `etag` (weak comparison, RFC 9110 §13.1.2), or `*`?
pub fn not_modified(headers: &HeaderMap, etag: &HeaderValue) -> bool {
    let ours = etag.as_bytes();
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .flat_map(|v| v.as_bytes().split(|&b| b == b','))
        .map(|t| t.trim_ascii())
        .any(|t| t == b"*" || t.strip_prefix(b"W/").unwrap_or(t) == ours)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(pairs: &[(header::HeaderName, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.append(k.clone(), HeaderValue::from_str(v).unwrap());
        }
        h
    }

    #[test]
    fn gzip_is_accepted_as_rfc_9110_says() {
        let ae = header::ACCEPT_ENCODING;
        for (value, want) in [
            ("gzip", true),
            ("gzip, deflate, br", true),
            ("deflate, gzip;q=0.5", true),
            ("GZip", true),
            ("x-gzip", true),
            ("*", true),
            ("br;q=1, *;q=0.1", true),
            ("gzip;q=0", false),
            ("gzip; q=0.000", false),
            ("*;q=0", false),
            ("gzip;q=0, *", false),
            ("identity", false),
            ("br, zstd", false),
            ("", false),
        ] {
            assert_eq!(
                accepts_gzip(&headers(&[(ae.clone(), value)])),
                want,
                "{value:?}"
            );
        }
        assert!(!accepts_gzip(&HeaderMap::new()));
        // Several header lines are one list.
        let h = headers(&[(ae.clone(), "br"), (ae.clone(), "gzip")]);
        assert!(accepts_gzip(&h));
    }

    #[test]
    fn if_none_match_compares_weakly_and_lists() {
        let inm = header::IF_NONE_MATCH;
        let tag = etag(42, false);
        assert_eq!(tag, "\"g42\"");
        assert_eq!(etag(42, true), "\"g42-gzip\"");
        for (value, want) in [
            ("\"g42\"", true),
            ("W/\"g42\"", true),
            ("\"g41\", \"g42\"", true),
            ("*", true),
            ("\"g42-gzip\"", false),
            ("\"g4\"", false),
            ("g42", false),
            ("", false),
        ] {
            assert_eq!(
                not_modified(&headers(&[(inm.clone(), value)]), &tag),
                want,
                "{value:?}"
            );
        }
        assert!(!not_modified(&HeaderMap::new(), &tag));
    }

    #[test]
    fn gzip_round_trips() {
        use std::io::Read;
        let data = br#"{"time":1.5,"tracks":[]}"#.repeat(1000);
        let z = gzip_bytes(&data, 1);
        assert!(z.len() * 20 < data.len(), "{} of {}", z.len(), data.len());
        let mut out = Vec::new();
        flate2::read::GzDecoder::new(&z[..])
            .read_to_end(&mut out)
            .unwrap();
        assert_eq!(out, data);
    }
}
