//! Our CPR decoder against rs1090's independent decode of a real gate-to-gate flight
//! (AFR34ZG, Paris CDG to Toulouse; fixtures/README.md).
//!
//! Every position line of the fixture carries the raw CPR fields (`lat_cpr`, `lon_cpr`,
//! `parity`) and rs1090's `latitude`/`longitude`. rs1090 decodes surface reports against a
//! reference position (the airport) and airborne ones from pairs, then locally; we feed the
//! same fields in order through one `CprDecoder` with the receiver at CDG.

use adsb_tracker::decode::cpr::{haversine_m, CprConfig, CprDecoder, CprStats, PositionFix};
use adsb_tracker::decode::Cpr;
use serde_json::Value;

/// Charles de Gaulle, where the flight starts at the gate (the receiver of the recording).
const CDG: (f64, f64) = (49.0, 2.57);

/// Toulouse-Blagnac, where it lands.
const TLS: (f64, f64) = (43.63, 1.37);

/// A position counts as matched when within this distance of rs1090's, metres.
const MATCH_M: f64 = 5.0;

struct Report {
    t_s: f64,
    surface: bool,
    cpr: Cpr,
    reference: (f64, f64),
}

fn reports() -> Vec<Report> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/fixtures/afr34zg-cdg-tls.jsonl"
    );
    let text = std::fs::read_to_string(path).expect("fixture present");
    let mut out = Vec::new();
    for line in text.lines() {
        let v: Value = serde_json::from_str(line).expect("valid JSON line");
        let Some(lat_cpr) = v.get("lat_cpr").and_then(Value::as_u64) else {
            continue;
        };
        let field = |k: &str| v.get(k).and_then(Value::as_f64).expect(k);
        let bds = v.get("bds").and_then(Value::as_str).expect("bds");
        let parity = v.get("parity").and_then(Value::as_str).expect("parity");
        out.push(Report {
            t_s: field("timestamp"),
            surface: match bds {
                "05" => false,
                "06" => true,
                other => panic!("unexpected bds {other}"),
            },
            cpr: Cpr {
                lat: u32::try_from(lat_cpr).expect("17-bit"),
                lon: u32::try_from(v.get("lon_cpr").and_then(Value::as_u64).expect("lon_cpr"))
                    .expect("17-bit"),
                odd: match parity {
                    "odd" => true,
                    "even" => false,
                    other => panic!("unexpected parity {other}"),
                },
            },
            reference: (field("latitude"), field("longitude")),
        });
    }
    out
}

/// What one pass over the flight gave.
#[derive(Debug)]
struct Outcome {
    matched: usize,
    mismatched: usize,
    not_decoded: usize,
    worst_matched_m: f64,
    stats: CprStats,
}

fn run(reports: &[Report], receiver: Option<(f64, f64)>) -> Outcome {
    let mut dec = CprDecoder::new(CprConfig {
        receiver,
        ..CprConfig::default()
    });
    let mut out = Outcome {
        matched: 0,
        mismatched: 0,
        not_decoded: 0,
        worst_matched_m: 0.0,
        stats: CprStats::default(),
    };
    for r in reports {
        let fix = if r.surface {
            dec.surface(r.t_s, r.cpr)
        } else {
            dec.airborne(r.t_s, r.cpr)
        };
        match fix {
            PositionFix::Accepted {
                lat_deg, lon_deg, ..
            } => {
                let d = haversine_m(lat_deg, lon_deg, r.reference.0, r.reference.1);
                if d <= MATCH_M {
                    out.matched += 1;
                    out.worst_matched_m = out.worst_matched_m.max(d);
                } else {
                    out.mismatched += 1;
                }
            }
            PositionFix::Pending | PositionFix::Rejected(_) => out.not_decoded += 1,
        }
    }
    out.stats = *dec.stats();
    // rs1090 gives a position on every line, so "decoded by us, not by the reference" is 0 by
    // construction; what we lack is `not_decoded`.
    eprintln!(
        "receiver {receiver:?}: {}/{} matched within {MATCH_M} m ({:.3} %), worst matched \
         {:.4} m; {} decoded differently; {} not decoded by us; 0 decoded only by us; {:?}",
        out.matched,
        reports.len(),
        100.0 * out.matched as f64 / reports.len() as f64,
        out.worst_matched_m,
        out.mismatched,
        out.not_decoded,
        out.stats
    );
    out
}

#[test]
fn fixture_has_both_kinds_of_position() {
    let reports = reports();
    let airborne = reports.iter().filter(|r| !r.surface).count();
    // The fixture as rs1090 decoded it: 6457 BDS 0,5 and 1867 BDS 0,6 lines.
    assert_eq!((reports.len(), airborne), (8324, 6457));
}

#[test]
fn matches_rs1090_with_the_receiver_at_cdg() {
    let reports = reports();
    let out = run(&reports, Some(CDG));
    let pct = 100.0 * out.matched as f64 / reports.len() as f64;
    assert!(pct >= 99.5, "only {pct:.3} % matched");
    assert_eq!(out.mismatched, 0, "positions that disagree with rs1090");
    assert_eq!(out.stats.resets, 0);
    assert_eq!(
        out.stats.accepted_global + out.stats.accepted_local,
        (out.matched + out.mismatched) as u64
    );
}

#[test]
fn without_a_receiver_only_the_first_taxi_is_lost() {
    // No reference for the surface reports at CDG: they wait (Pending) until the first
    // airborne pair; everything after it, including the Toulouse surface reports (decoded
    // against the aircraft's own last position), must match.
    let reports = reports();
    let first_airborne = reports.iter().position(|r| !r.surface).expect("airborne");
    // The first airborne frame that has an other-parity airborne frame within 10 s before it.
    let first_pair = (first_airborne..reports.len())
        .find(|&i| {
            let r = &reports[i];
            !r.surface
                && reports[first_airborne..i]
                    .iter()
                    .any(|p| !p.surface && p.cpr.odd != r.cpr.odd && r.t_s - p.t_s <= 10.0)
        })
        .expect("a pair");
    let out = run(&reports, None);
    assert_eq!(out.not_decoded, first_pair);
    assert_eq!(out.mismatched, 0);
    assert_eq!(out.matched, reports.len() - first_pair);
}

#[test]
fn a_wrong_receiver_costs_a_few_fixes_then_recovers() {
    // Receiver at Toulouse while the aircraft taxis at CDG, 5.4 degrees away: far beyond the
    // 45 NM of local surface decoding, so the first fix is wrong. The global surface decode
    // (which only needs the reference within 45 degrees) disagrees with it, the rejections
    // pile up, the decoder resets and the rest of the flight matches.
    let reports = reports();
    // The recording opens with two even surface frames 5 s apart, so the first two fixes
    // are local: against the receiver, then against that wrong fix (2 mismatches). Each
    // later frame has a partner: its global decode is the true position, 5.4 degrees from the
    // wrong fix, and is rejected until the 4th rejection (`rejections_before_reset`) resets.
    let out = run(&reports, Some(TLS));
    assert_eq!(out.mismatched, 2, "{out:?}");
    assert_eq!(out.not_decoded, 4, "{out:?}");
    assert_eq!(out.stats.impossible_speed, 4, "{out:?}");
    assert_eq!(out.stats.resets, 1, "{out:?}");
    let pct = 100.0 * out.matched as f64 / reports.len() as f64;
    assert!(pct >= 99.5, "only {pct:.3} % matched");
}
