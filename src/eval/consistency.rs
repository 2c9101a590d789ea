//! Consistency on real recordings, where there is no truth: how often a tracker says it is
//! diverging, how its stated uncertainty compares with the scatter of the decoded positions
//! around its track, and (when the tracker publishes one) how often its windowed normalised
//! innovation squared sits inside its chi-square band. Issue 10's claims are measured with
//! this (`adsb-tracker evaluate --recording FILE`), and the tables of `docs/evaluation.md`
//! come from it.
//!
//! Every update of the daemon's pipeline ([`super::bench::sync_pipeline`]) is one sample,
//! grouped by the aircraft's declared NACp at that update ("none" before or without an
//! operational status). Definitions:
//! - airborne: the aircraft's last position was airborne;
//! - steady: airborne, the track at least [`STEADY_AFTER_S`] old, and the published labels
//!   straight, constant speed, level (for `kalman-cv`, which never labels, every airborne
//!   update past the start);
//! - scatter: the horizontal distance from each decoded position to the track's estimate
//!   published on that update (the estimate moves towards the fix by its gain, so this is a
//!   slight underestimate of the distance to the prior track);
//! - NIS in band: the published windowed NIS (`nis`, a sum over `nis_dof` measured
//!   components) inside the two-sided 95 % band of χ²(`nis_dof`);
//! - velocity reports held: the airborne ground-velocity reports (subtypes 1 and 2) whose
//!   east and north components repeat the aircraft's previous report exactly, of those
//!   within [`HELD_MAX_GAP_S`] of it (a second copy of one transmission,
//!   `decode.duplicate_window_s`, is not a report). Reported in 1-kt steps, the velocity of
//!   an aircraft in steady flight repeats: those innovations are near zero whatever the
//!   filter claims, so this share bounds how chi-square the windowed NIS can look
//!   (`docs/evaluation.md`). A property of the recording: the same for every tracker.

use super::bench::{decoder_config, sync_pipeline};
use crate::config::Config;
use crate::decode::{Decoder, Icao, Message};
use crate::feed::RawFrame;
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::fmt::Write;

/// A track younger than this is still converging: not "steady", s.
pub const STEADY_AFTER_S: f64 = 30.0;

/// Successive velocity reports further apart than this are not compared for a repeat, s:
/// four ADS-B velocity intervals, after which a held value says little.
pub const HELD_MAX_GAP_S: f64 = 2.0;

pub use super::bench::{read_frames_at, read_recording};

/// Counts and samples of one group (a NACp, or all).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Group {
    pub updates: u64,
    pub airborne: u64,
    pub airborne_diverging: u64,
    pub steady: u64,
    pub steady_diverging: u64,
    /// Steady updates that carried a windowed NIS, and those inside its band.
    pub steady_nis: u64,
    pub steady_nis_in_band: u64,
    /// Of the rest, those below the band (the filter claims more uncertainty than its
    /// innovations show); the others are above it.
    pub steady_nis_below_band: u64,
    /// Steady updates: the windowed NIS over its dof (1 for a consistent filter).
    #[serde(skip)]
    pub nis_per_dof: Vec<f64>,
    /// Steady updates with a decoded position: distance fix-estimate, m.
    #[serde(skip)]
    pub scatter_m: Vec<f64>,
    /// Steady updates: published pos_sigma_m.
    #[serde(skip)]
    pub pos_sigma_m: Vec<f64>,
    /// Steady updates with a decoded position: that distance over the published 1-σ of the
    /// same direction, squared, summed (a position NEES against the fix: 2 + the fix's
    /// own noise over the published variance).
    #[serde(skip)]
    pub fix_nees: Vec<f64>,
    /// Airborne velocity reports compared with the aircraft's previous one, and those that
    /// repeat it exactly (module doc).
    pub velocity_reports: u64,
    pub velocity_held: u64,
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_unstable_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

fn pct(n: u64, d: u64) -> Option<f64> {
    (d > 0).then(|| 100.0 * n as f64 / d as f64)
}

impl Group {
    pub fn airborne_diverging_pct(&self) -> Option<f64> {
        pct(self.airborne_diverging, self.airborne)
    }
    pub fn steady_diverging_pct(&self) -> Option<f64> {
        pct(self.steady_diverging, self.steady)
    }
    pub fn nis_in_band_pct(&self) -> Option<f64> {
        pct(self.steady_nis_in_band, self.steady_nis)
    }

    /// Percent of the steady updates' windowed NIS below their band.
    pub fn nis_below_band_pct(&self) -> Option<f64> {
        pct(self.steady_nis_below_band, self.steady_nis)
    }
    pub fn median_scatter_m(&self) -> Option<f64> {
        median(&mut self.scatter_m.clone())
    }
    pub fn median_nis_per_dof(&self) -> Option<f64> {
        median(&mut self.nis_per_dof.clone())
    }
    pub fn median_pos_sigma_m(&self) -> Option<f64> {
        median(&mut self.pos_sigma_m.clone())
    }
    pub fn velocity_held_pct(&self) -> Option<f64> {
        pct(self.velocity_held, self.velocity_reports)
    }
    fn merge(&mut self, o: &Group) {
        self.updates += o.updates;
        self.airborne += o.airborne;
        self.airborne_diverging += o.airborne_diverging;
        self.steady += o.steady;
        self.steady_diverging += o.steady_diverging;
        self.steady_nis += o.steady_nis;
        self.steady_nis_in_band += o.steady_nis_in_band;
        self.steady_nis_below_band += o.steady_nis_below_band;
        self.scatter_m.extend_from_slice(&o.scatter_m);
        self.pos_sigma_m.extend_from_slice(&o.pos_sigma_m);
        self.fix_nees.extend_from_slice(&o.fix_nees);
        self.nis_per_dof.extend_from_slice(&o.nis_per_dof);
        self.velocity_reports += o.velocity_reports;
        self.velocity_held += o.velocity_held;
    }
}

/// One tracker on one recording.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingResult {
    pub recording: String,
    pub tracker: String,
    /// By declared NACp ("none", "0".."11") and "all".
    pub groups: BTreeMap<String, Group>,
}

/// The two-sided 95 % band of χ²(dof) (Wilson–Hilferty; within 1 % for dof ≥ 3).
pub fn chi2_band(dof: f64) -> (f64, f64) {
    let z = 1.959_963_984_540_054;
    let a = 2.0 / (9.0 * dof);
    let q = |z: f64| dof * (1.0 - a + z * a.sqrt()).powi(3).max(0.0);
    (q(-z), q(z))
}

/// Horizontal offset (east, north) of (lat, lon) from (lat0, lon0), m, on a local sphere:
/// plenty for the metres between a fix and its estimate.
fn offset_en_m(lat0: f64, lon0: f64, lat: f64, lon: f64) -> (f64, f64) {
    const R: f64 = 6_371_008.8;
    let dn = (lat - lat0).to_radians() * R;
    let de = (lon - lon0).to_radians() * R * lat0.to_radians().cos();
    (de, dn)
}

/// Runs `frames` through the pipeline with `tracker` and gathers the groups.
pub fn measure(frames: &[RawFrame], config: &Config, tracker: &str) -> BTreeMap<String, Group> {
    let mut pipeline = sync_pipeline(config, tracker);
    let mut groups: BTreeMap<String, Group> = BTreeMap::new();
    let mut first_t: HashMap<Icao, f64> = HashMap::new();
    let labels = tracker != "kalman-cv";
    // The recording's own velocity reports, and the NACp group and ground flag of each
    // aircraft's last state: a report is counted in that group.
    let mut velocities = VelocityReports::new(config);
    let mut last_state: HashMap<Icao, (Option<u8>, bool)> = HashMap::new();
    for f in frames {
        if let Some(r) = velocities.push(f) {
            if let (Some((tp, en_prev)), Some(&(nac_p, false))) =
                (r.previous, last_state.get(&r.icao))
            {
                let dt = r.t_s - tp;
                if dt > 0.0 && dt <= HELD_MAX_GAP_S {
                    let g = groups.entry(group_key(nac_p)).or_default();
                    g.velocity_reports += 1;
                    g.velocity_held += u64::from(en_prev == r.en_kt);
                }
            }
        }
        let Some(u) = pipeline.push(f) else { continue };
        let Some(s) = &u.state else { continue };
        let t0 = *first_t.entry(s.icao).or_insert(s.t);
        last_state.insert(s.icao, (s.nac_p, s.on_ground));
        let g = groups.entry(group_key(s.nac_p)).or_default();
        g.updates += 1;
        if s.on_ground {
            continue;
        }
        g.airborne += 1;
        g.airborne_diverging += u64::from(s.diverging);
        let steady = s.t - t0 >= STEADY_AFTER_S
            && (!labels
                || (s.mode == "CV"
                    && s.lateral == "straight"
                    && s.speed == "constant"
                    && s.vertical == "level"));
        if !steady {
            continue;
        }
        g.steady += 1;
        g.steady_diverging += u64::from(s.diverging);
        g.pos_sigma_m.push(s.pos_sigma_m);
        if let (Some(nis), Some(dof)) = (s.nis, s.nis_dof) {
            if dof > 0 {
                g.steady_nis += 1;
                let (lo, hi) = chi2_band(f64::from(dof));
                g.steady_nis_in_band += u64::from((lo..=hi).contains(&nis));
                g.steady_nis_below_band += u64::from(nis < lo);
                g.nis_per_dof.push(nis / f64::from(dof));
            }
        }
        if let Some((_, lat, lon, _)) = u.fix {
            let (de, dn) = offset_en_m(s.lat, s.lon, lat, lon);
            g.scatter_m.push(de.hypot(dn));
            let c = &s.pos_cov_enu_m2;
            let p = nalgebra::Matrix2::new(c[0][0], c[0][1], c[1][0], c[1][1]);
            if let Some(ch) = p.cholesky() {
                let d = nalgebra::Vector2::new(de, dn);
                g.fix_nees.push(d.dot(&ch.solve(&d)));
            }
        }
    }
    let mut all = Group::default();
    for g in groups.values() {
        all.merge(g);
    }
    groups.insert("all".to_string(), all);
    groups
}

/// The group of a declared NACp ("none" when nothing is declared).
fn group_key(nac_p: Option<u8>) -> String {
    nac_p.map_or("none".to_string(), |n| n.to_string())
}

/// One ground-velocity report of a recording ([`VelocityReports`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VelocityReport {
    pub icao: Icao,
    /// Feed time, s.
    pub t_s: f64,
    /// East and north, kt, as reported.
    pub en_kt: (f64, f64),
    /// The aircraft's previous report (time s, east and north kt), if any.
    pub previous: Option<(f64, (f64, f64))>,
}

/// A recording's ground-velocity reports (subtypes 1 and 2) frame by frame, each with the
/// aircraft's previous one; a second copy of one transmission (the same values within
/// `decode.duplicate_window_s` of the last) is not a report. Its own decoder: a property of
/// the recording, not of a tracker.
pub struct VelocityReports {
    decoder: Decoder,
    last: HashMap<Icao, (f64, (f64, f64))>,
    duplicate_window_s: f64,
}

impl VelocityReports {
    pub fn new(config: &Config) -> Self {
        Self {
            decoder: Decoder::new(decoder_config(config)),
            last: HashMap::new(),
            duplicate_window_s: config.decode.duplicate_window_s,
        }
    }

    /// The velocity report `f` carries, if any.
    pub fn push(&mut self, f: &RawFrame) -> Option<VelocityReport> {
        let d = self.decoder.decode(f).ok()?;
        let Message::Velocity(v) = d.msg else {
            return None;
        };
        let en_kt = v.ground_kt?;
        let previous = self.last.get(&d.icao).copied();
        if let Some((tp, en_prev)) = previous {
            if d.time_s - tp <= self.duplicate_window_s && en_prev == en_kt {
                return None;
            }
        }
        self.last.insert(d.icao, (d.time_s, en_kt));
        Some(VelocityReport {
            icao: d.icao,
            t_s: d.time_s,
            en_kt,
            previous,
        })
    }
}

fn f(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "-".to_string(), |x| format!("{x:.digits$}"))
}

/// The markdown table of `results` (one row per recording, tracker and NACp group).
pub fn markdown(results: &[RecordingResult]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| recording | tracker | NACp | airborne updates | diverging % airborne | steady updates | diverging % steady | NIS in 95 % band % (steady) | below band % | median NIS/dof (steady) | median pos_sigma_m | median fix-to-track m | velocity reports held % |"
    );
    let _ = writeln!(
        s,
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for r in results {
        // "all" first, then the groups in NACp order, "none" last.
        let mut keys: Vec<&String> = r.groups.keys().collect();
        keys.sort_by_key(|k| match k.as_str() {
            "all" => -2,
            "none" => 100,
            n => n.parse::<i32>().unwrap_or(99),
        });
        for k in keys {
            let Some(g) = r.groups.get(k) else { continue };
            if g.airborne == 0 {
                continue;
            }
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                r.recording,
                r.tracker,
                k,
                g.airborne,
                f(g.airborne_diverging_pct(), 1),
                g.steady,
                f(g.steady_diverging_pct(), 1),
                f(g.nis_in_band_pct(), 1),
                f(g.nis_below_band_pct(), 1),
                f(g.median_nis_per_dof(), 2),
                f(g.median_pos_sigma_m(), 2),
                f(g.median_scatter_m(), 2),
                f(g.velocity_held_pct(), 1),
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_band_matches_the_tables() {
        // Tabulated χ²(6): 2.5 % 1.237, 97.5 % 14.449; χ²(60): 40.482, 83.298.
        let (lo, hi) = chi2_band(6.0);
        assert!(
            (lo - 1.237).abs() < 0.05 && (hi - 14.449).abs() < 0.1,
            "{lo} {hi}"
        );
        let (lo, hi) = chi2_band(60.0);
        assert!(
            (lo - 40.482).abs() < 0.1 && (hi - 83.298).abs() < 0.1,
            "{lo} {hi}"
        );
    }

    #[test]
    fn afr34zg_flags_and_scatter_are_measured() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/afr34zg-cdg-tls.jsonl");
        let frames = read_frames_at(&path, None, 1000.0).unwrap();
        let cfg = Config::default_config().unwrap();
        let g = measure(&frames, &cfg, "hybrid");
        let all = g.get("all").unwrap();
        // The whole flight is one aircraft declaring no NACp.
        assert_eq!(g.get("none").unwrap().updates, all.updates);
        assert!(all.airborne > 10_000, "{}", all.airborne);
        assert!(all.steady > 1_000, "{}", all.steady);
        let scatter = all.median_scatter_m().unwrap();
        assert!(scatter > 1.0 && scatter < 30.0, "{scatter}");
    }
}
