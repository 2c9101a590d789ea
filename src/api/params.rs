//! The query parameters' syntax, one regular expression per parameter, and their parsers.
//!
//! The OpenAPI document publishes exactly these patterns ([`PATTERNS`], written into it by
//! [`super::openapi`]) and the handlers accept exactly what they match, so a client (or
//! schemathesis, which generates requests from the document) can tell a valid request from
//! an invalid one without trying it. Only the rules a pattern cannot say are checked after
//! it: a box's south edge north of its north edge, and more than [`MAX_ICAO_FILTER`]
//! addresses. An empty value (`mode=`, what an HTML form with an empty field sends) is the
//! same as no parameter.

use super::ApiError;
use crate::decode::Icao;
use crate::track::FlightMode;
use regex::Regex;
use std::sync::LazyLock;

/// Most addresses in an `icao=` filter.
pub const MAX_ICAO_FILTER: usize = 10_000;

/// A latitude in decimal degrees, -90 to 90, no exponent.
macro_rules! lat {
    () => {
        r"[+-]?(90(\.0+)?|[1-8]?[0-9](\.[0-9]+)?)"
    };
}
/// A longitude in decimal degrees, -180 to 180, no exponent.
macro_rules! lon {
    () => {
        r"[+-]?(180(\.0+)?|(1[0-7][0-9]|[1-9]?[0-9])(\.[0-9]+)?)"
    };
}
/// A flight-mode label, any case.
macro_rules! mode {
    () => {
        r"[Cc]([Vv]|[Aa]|[Tt]|[Hh]([Cc][Aa])?)"
    };
}

/// `mode`: one label or a comma-separated list (`CV`, `CT,CA`), any case.
pub const MODES: &str = concat!("^( *", mode!(), " *(, *", mode!(), " *)*)?$");
/// The stream's `icao`: comma-separated ICAO addresses, 6 hex digits each.
pub const ICAOS: &str = "^( *[0-9a-fA-F]{6} *(, *[0-9a-fA-F]{6} *)*)?$";
/// `/api/v1/tracks`' `bbox`: `south,west,north,east` (latitude first).
pub const TRACKS_BBOX: &str = concat!(
    "^( *",
    lat!(),
    " *, *",
    lon!(),
    " *, *",
    lat!(),
    " *, *",
    lon!(),
    " *)?$"
);
/// The stream's `bbox`: `minLon,minLat,maxLon,maxLat` (GeoJSON's order).
pub const STREAM_BBOX: &str = concat!(
    "^( *",
    lon!(),
    " *, *",
    lat!(),
    " *, *",
    lon!(),
    " *, *",
    lat!(),
    " *)?$"
);

/// Every query parameter of the API and its pattern: (path, parameter, pattern).
pub const PATTERNS: [(&str, &str, &str); 5] = [
    ("/api/v1/tracks", "bbox", TRACKS_BBOX),
    ("/api/v1/tracks", "mode", MODES),
    ("/api/v1/stream", "bbox", STREAM_BBOX),
    ("/api/v1/stream", "icao", ICAOS),
    ("/api/v1/stream", "mode", MODES),
];

static MODES_RE: LazyLock<Regex> = LazyLock::new(|| compiled(MODES));
static ICAOS_RE: LazyLock<Regex> = LazyLock::new(|| compiled(ICAOS));
static TRACKS_BBOX_RE: LazyLock<Regex> = LazyLock::new(|| compiled(TRACKS_BBOX));
static STREAM_BBOX_RE: LazyLock<Regex> = LazyLock::new(|| compiled(STREAM_BBOX));

/// The patterns are constants, checked by `patterns_compile`: no request reaches a failure.
fn compiled(pattern: &str) -> Regex {
    Regex::new(pattern).unwrap_or_else(|e| panic!("pattern {pattern:?}: {e}"))
}

/// `s` split at commas and trimmed, once `re` has matched it; `None` when empty.
fn items<'a>(
    s: &'a str,
    re: &Regex,
    what: &str,
) -> Result<Option<impl Iterator<Item = &'a str>>, ApiError> {
    if !re.is_match(s) {
        return Err(ApiError::BadRequest(format!(
            "{what}: {s:?} does not match {}",
            re.as_str()
        )));
    }
    Ok((!s.is_empty()).then(|| s.split(',').map(str::trim)))
}

/// A `mode` filter, as the labels' static names; `None` when empty.
pub fn modes(s: &str) -> Result<Option<Vec<&'static str>>, ApiError> {
    let Some(labels) = items(
        s,
        &MODES_RE,
        "mode (CV, CA, CT, CH or CHCA, comma-separated)",
    )?
    else {
        return Ok(None);
    };
    labels
        .map(|m| {
            m.parse::<FlightMode>()
                .map(FlightMode::as_str)
                .map_err(ApiError::BadRequest)
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

/// An `icao` filter, sorted and without repeats; `None` when empty.
pub fn icaos(s: &str) -> Result<Option<Vec<Icao>>, ApiError> {
    let Some(list) = items(s, &ICAOS_RE, "icao (6 hex digits, comma-separated)")? else {
        return Ok(None);
    };
    let mut v: Vec<Icao> = list
        .map(|a| a.parse::<Icao>().map_err(ApiError::BadRequest))
        .collect::<Result<_, _>>()?;
    if v.len() > MAX_ICAO_FILTER {
        return Err(ApiError::BadRequest(format!(
            "icao: at most {MAX_ICAO_FILTER} addresses"
        )));
    }
    v.sort_unstable();
    v.dedup();
    Ok(Some(v))
}

/// The four numbers of a `bbox` that `re` matched; `None` when empty.
fn four_degrees(s: &str, re: &Regex, what: &str) -> Result<Option<[f64; 4]>, ApiError> {
    let Some(parts) = items(s, re, what)? else {
        return Ok(None);
    };
    let v: Vec<f64> = parts
        .map(|p| {
            p.parse::<f64>()
                .map_err(|e| ApiError::BadRequest(format!("bbox: {e}")))
        })
        .collect::<Result<_, _>>()?;
    let four: [f64; 4] = v
        .try_into()
        .map_err(|_| ApiError::BadRequest(format!("{what}: {s:?} is not four numbers")))?;
    Ok(Some(four))
}

/// `/api/v1/tracks`' `bbox`: `south,west,north,east` in degrees; `west > east` crosses the
/// antimeridian.
pub fn tracks_bbox(s: &str) -> Result<Option<LonLatBox>, ApiError> {
    const WHAT: &str = "bbox (south,west,north,east in degrees)";
    four_degrees(s, &TRACKS_BBOX_RE, WHAT)?
        .map(|[south, west, north, east]| LonLatBox::new(west, south, east, north, WHAT))
        .transpose()
}

/// The stream's `bbox`: `minLon,minLat,maxLon,maxLat` in degrees; `minLon > maxLon` crosses
/// the antimeridian.
pub fn stream_bbox(s: &str) -> Result<Option<LonLatBox>, ApiError> {
    const WHAT: &str = "bbox (minLon,minLat,maxLon,maxLat in degrees)";
    four_degrees(s, &STREAM_BBOX_RE, WHAT)?
        .map(|[min_lon, min_lat, max_lon, max_lat]| {
            LonLatBox::new(min_lon, min_lat, max_lon, max_lat, WHAT)
        })
        .transpose()
}

/// A longitude/latitude box, GeoJSON's order; `min_lon > max_lon` crosses the antimeridian.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LonLatBox {
    pub min_lon: f64,
    pub min_lat: f64,
    pub max_lon: f64,
    pub max_lat: f64,
}

impl LonLatBox {
    /// The box, if its latitudes are in order (the ranges are the patterns'). `what` names
    /// the parameter in the error.
    fn new(
        min_lon: f64,
        min_lat: f64,
        max_lon: f64,
        max_lat: f64,
        what: &str,
    ) -> Result<Self, ApiError> {
        if min_lat > max_lat {
            return Err(ApiError::BadRequest(format!(
                "{what}: the south edge {min_lat} is north of the north edge {max_lat}"
            )));
        }
        Ok(Self {
            min_lon,
            min_lat,
            max_lon,
            max_lat,
        })
    }

    pub fn contains(&self, lat: f64, lon: f64) -> bool {
        let lon_in = if self.min_lon <= self.max_lon {
            (self.min_lon..=self.max_lon).contains(&lon)
        } else {
            lon >= self.min_lon || lon <= self.max_lon
        };
        (self.min_lat..=self.max_lat).contains(&lat) && lon_in
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_compile() {
        for (_, _, p) in PATTERNS {
            assert!(Regex::new(p).is_ok(), "{p}");
        }
    }

    #[test]
    fn tracks_bbox_parses_and_contains() {
        let b = tracks_bbox("43.0,1.0,50.0,3.0").unwrap().unwrap();
        assert!(b.contains(49.0, 2.5));
        assert!(!b.contains(49.0, 3.5));
        assert!(!b.contains(42.9, 2.0));
        // Across the antimeridian.
        let b = tracks_bbox("-10,170,10,-170").unwrap().unwrap();
        assert!(b.contains(0.0, 175.0) && b.contains(0.0, -175.0) && !b.contains(0.0, 0.0));
        assert_eq!(tracks_bbox("").unwrap(), None);
        assert!(tracks_bbox("  ").is_err());
        let b = tracks_bbox(" -90 , -180.0, 90.000,+180 ").unwrap().unwrap();
        assert_eq!(
            [b.min_lat, b.min_lon, b.max_lat, b.max_lon],
            [-90.0, -180.0, 90.0, 180.0]
        );
        for s in [
            "1,2,3",
            "1,2,3,4,5",
            "a,b,c,d",
            "50,0,40,1",
            "0,0,95,1",
            "0,-190,1,1",
            "90.1,0,90.1,0",
            "0,180.5,1,1",
            "1e1,0,20,1",
            "inf,0,1,1",
            "NaN,0,1,1",
            ".5,0,1,1",
            "5.,0,1,1",
            "007,0,8,1",
            "1,,2,3",
        ] {
            assert!(tracks_bbox(s).is_err(), "{s:?} accepted");
        }
    }

    #[test]
    fn stream_bbox_is_lon_lat_and_crosses_the_antimeridian() {
        // Los Angeles: lon -118.4, lat 33.9.
        let b = stream_bbox("-119,33,-118,35").unwrap().unwrap();
        assert!(b.contains(33.9, -118.4));
        assert!(!b.contains(-118.4, 33.9));
        let b = stream_bbox("170,-10,-170,10").unwrap().unwrap();
        assert!(b.contains(0.0, 175.0) && b.contains(0.0, -175.0) && !b.contains(0.0, 0.0));
        for s in ["1,2,3", "a,b,c,d", "0,50,1,40", "0,95,1,96", "-190,0,1,1"] {
            assert!(stream_bbox(s).is_err(), "{s:?} accepted");
        }
    }

    #[test]
    fn modes_and_icaos() {
        assert_eq!(modes("CT, cv").unwrap(), Some(vec!["CT", "CV"]));
        assert_eq!(modes("chca").unwrap(), Some(vec!["CHCA"]));
        assert_eq!(modes("").unwrap(), None);
        for s in ["XX", "CV,", ",CV", "CV,,CA", "CHC", "C V"] {
            assert!(modes(s).is_err(), "{s:?} accepted");
        }
        assert_eq!(
            icaos("A0B1C2, 393322,a0b1c2").unwrap(),
            Some(vec![Icao(0x393322), Icao(0xa0b1c2)])
        );
        assert_eq!(icaos("").unwrap(), None);
        for s in ["zzzzzz", "3933", "3933221", "393322,", "0x3933"] {
            assert!(icaos(s).is_err(), "{s:?} accepted");
        }
        let many = vec!["393322"; MAX_ICAO_FILTER + 1].join(",");
        assert!(icaos(&many).is_err());
    }
}
