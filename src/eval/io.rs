//! Reading what the evaluation compares: the simulator's truth CSV and `--tracks-out` lines.

use super::score::{EstimateSample, TruthSample, TruthTrack};
use crate::decode::Icao;
use crate::track::FlightMode;
use std::collections::BTreeMap;
use std::path::Path;

/// Why an input file was refused; the message names the file and the line.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("cannot read {path}: {error}")]
    Read { path: String, error: std::io::Error },
    #[error("{path}:{line}: {problem}")]
    Line {
        path: String,
        line: usize,
        problem: String,
    },
    #[error("{0}")]
    Other(String),
}

/// The header DESIGN.md fixes for truth files.
pub const TRUTH_HEADER: &str = "t,icao,lat,lon,alt_m,ve,vn,vu,mode";

/// Parses a truth CSV (`t,icao,lat,lon,alt_m,ve,vn,vu,mode`) into one track per aircraft.
pub fn parse_truth(text: &str, path: &str) -> Result<BTreeMap<Icao, TruthTrack>, EvalError> {
    let mut per: BTreeMap<Icao, Vec<TruthSample>> = BTreeMap::new();
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == TRUTH_HEADER => {}
        other => {
            return Err(EvalError::Line {
                path: path.into(),
                line: 1,
                problem: format!(
                    "expected header {TRUTH_HEADER:?}, got {:?}",
                    other.map(|(_, h)| h)
                ),
            })
        }
    }
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let bad = |problem: String| EvalError::Line {
            path: path.into(),
            line: i + 1,
            problem,
        };
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let [t, icao, lat, lon, alt, ve, vn, vu, mode] = f[..] else {
            return Err(bad(format!("expected 9 fields, got {}", f.len())));
        };
        let num = |s: &str, name: &str| {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(format!("{name}: {s:?} is not a number")))
        };
        let sample = TruthSample {
            t: num(t, "t")?,
            lat: num(lat, "lat")?,
            lon: num(lon, "lon")?,
            alt_m: num(alt, "alt_m")?,
            ve: num(ve, "ve")?,
            vn: num(vn, "vn")?,
            vu: num(vu, "vu")?,
            mode: mode.parse::<FlightMode>().map_err(bad)?,
        };
        let icao: Icao = icao.parse().map_err(bad)?;
        per.entry(icao).or_default().push(sample);
    }
    Ok(per
        .into_iter()
        .map(|(k, v)| (k, TruthTrack::new(v)))
        .collect())
}

/// Parses `--tracks-out` lines into each aircraft's estimates, in file order.
pub fn parse_tracks(
    text: &str,
    path: &str,
) -> Result<BTreeMap<Icao, Vec<EstimateSample>>, EvalError> {
    let mut per: BTreeMap<Icao, Vec<EstimateSample>> = BTreeMap::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let bad = |problem: String| EvalError::Line {
            path: path.into(),
            line: i + 1,
            problem,
        };
        let v: serde_json::Value = serde_json::from_str(line).map_err(|e| bad(e.to_string()))?;
        let num = |k: &str| {
            v.get(k)
                .and_then(serde_json::Value::as_f64)
                .ok_or_else(|| bad(format!("field {k:?} missing or not a number")))
        };
        let cov2 = |k: &str| -> Option<[[f64; 2]; 2]> {
            let m = v.get(k)?;
            let g = |r: usize, c: usize| m.get(r)?.get(c)?.as_f64();
            Some([[g(0, 0)?, g(0, 1)?], [g(1, 0)?, g(1, 1)?]])
        };
        let icao: Icao = v
            .get("icao")
            .and_then(serde_json::Value::as_str)
            .ok_or_else(|| bad("field \"icao\" missing".into()))?
            .parse()
            .map_err(bad)?;
        let mode: FlightMode = v
            .get("mode")
            .and_then(serde_json::Value::as_str)
            .ok_or_else(|| bad("field \"mode\" missing".into()))?
            .parse()
            .map_err(bad)?;
        per.entry(icao).or_default().push(EstimateSample {
            t: num("t")?,
            lat: num("lat")?,
            lon: num("lon")?,
            alt_m: num("alt_m")?,
            ve: num("ve")?,
            vn: num("vn")?,
            vu: num("vu")?,
            mode,
            pos_cov_en: cov2("pos_cov_enu_m2"),
            vel_cov_en: cov2("vel_cov_enu_m2ps2"),
            cpu_ns: None,
            nis: v
                .get("nis")
                .and_then(serde_json::Value::as_f64)
                .zip(v.get("nis_dof").and_then(serde_json::Value::as_u64))
                .and_then(|(n, d)| Some((n, u32::try_from(d).ok()?))),
            diverging: v
                .get("diverging")
                .and_then(serde_json::Value::as_bool)
                .unwrap_or(false),
        });
    }
    Ok(per)
}

/// Reads a whole file as text.
pub fn read(path: &Path) -> Result<String, EvalError> {
    std::fs::read_to_string(path).map_err(|source| EvalError::Read {
        path: path.display().to_string(),
        error: source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truth_parses_and_names_bad_lines() {
        let text = format!("{TRUTH_HEADER}\n0.0,abc123,1.0,2.0,3.0,4.0,5.0,6.0,CV\n1.0,abc123,1.1,2.0,3.0,4.0,5.0,6.0,CT\n");
        let t = parse_truth(&text, "x.csv").unwrap();
        let track = &t[&Icao(0xabc123)];
        assert_eq!(track.samples().len(), 2);
        assert_eq!(track.samples()[1].mode, FlightMode::Ct);
        let err = parse_truth(
            &format!("{TRUTH_HEADER}\n0.0,abc123,1.0,2.0,3.0,4.0,5.0,6.0,XX\n"),
            "x.csv",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("x.csv:2"), "{err}");
        assert!(parse_truth("t,lat\n", "x.csv").is_err());
    }

    #[test]
    fn tracks_parse_with_covariance() {
        let line = r#"{"t":1.5,"icao":"abc123","lat":1,"lon":2,"alt_m":3,"ve":4,"vn":5,"vu":6,"mode":"CT","filter":"x","pos_sigma_m":1,"diverging":false,"pos_cov_enu_m2":[[4,1,0],[1,9,0],[0,0,1]]}"#;
        let t = parse_tracks(line, "t.jsonl").unwrap();
        let e = &t[&Icao(0xabc123)][0];
        assert_eq!(e.mode, FlightMode::Ct);
        assert_eq!(e.pos_cov_en, Some([[4.0, 1.0], [1.0, 9.0]]));
        assert!(e.vel_cov_en.is_none());
        assert!(parse_tracks("{\"t\":1}", "t.jsonl")
            .unwrap_err()
            .to_string()
            .contains("t.jsonl:1"));
    }
}
