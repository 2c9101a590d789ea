//! Scoring a tracker's estimates against simulated truth.
//!
//! Each estimate is compared with the truth interpolated at its own time, in metres in the
//! east-north-up plane at the true position. Everything accumulates (sums, counts), so runs of a
//! Monte Carlo experiment add up with [`Scores::merge`].

use crate::track::geo::LocalFrame;
use crate::track::FlightMode;
use nalgebra::{Matrix2, Vector2};
use serde::Serialize;
use std::collections::BTreeMap;

/// One truth sample (a row of `PREFIX.truth.csv`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TruthSample {
    pub t: f64,
    pub lat: f64,
    pub lon: f64,
    pub alt_m: f64,
    pub ve: f64,
    pub vn: f64,
    pub vu: f64,
    pub mode: FlightMode,
}

/// One estimate (a `--tracks-out` line), with the covariances the NEES needs.
#[derive(Clone, Debug, PartialEq)]
pub struct EstimateSample {
    pub t: f64,
    pub lat: f64,
    pub lon: f64,
    pub alt_m: f64,
    pub ve: f64,
    pub vn: f64,
    pub vu: f64,
    pub mode: FlightMode,
    /// Horizontal position covariance (east, north) at the aircraft, m^2; `None` if absent.
    pub pos_cov_en: Option<[[f64; 2]; 2]>,
    /// Horizontal velocity covariance, (m/s)^2.
    pub vel_cov_en: Option<[[f64; 2]; 2]>,
    /// Wall time the update took, ns (bench runs only).
    pub cpu_ns: Option<u64>,
    /// The published windowed NIS and its degrees of freedom (`nis`, `nis_dof`), when the
    /// tracker keeps one.
    pub nis: Option<(f64, u32)>,
    /// The published `diverging` flag.
    pub diverging: bool,
}

/// A measured position (what the tracker was given), for the raw-measurement RMSE.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawPosition {
    pub t: f64,
    pub lat: f64,
    pub lon: f64,
    pub alt_m: f64,
}

/// Truth of one aircraft, sorted by time.
#[derive(Clone, Debug, Default)]
pub struct TruthTrack {
    samples: Vec<TruthSample>,
}

impl TruthTrack {
    /// Sorts the samples by time.
    pub fn new(mut samples: Vec<TruthSample>) -> Self {
        samples.sort_by(|a, b| a.t.total_cmp(&b.t));
        Self { samples }
    }

    /// The samples, sorted by time.
    pub fn samples(&self) -> &[TruthSample] {
        &self.samples
    }

    /// Truth at `t`, linearly interpolated between samples; the mode is that of the sample at
    /// or before `t` (the segment being flown). `None` outside the sampled span.
    pub fn at(&self, t: f64) -> Option<TruthSample> {
        let i = self.samples.partition_point(|s| s.t <= t);
        let before = self.samples.get(i.checked_sub(1)?)?;
        if before.t == t {
            return Some(*before);
        }
        let after = self.samples.get(i)?;
        let w = (t - before.t) / (after.t - before.t);
        let lerp = |a: f64, b: f64| a + w * (b - a);
        Some(TruthSample {
            t,
            lat: lerp(before.lat, after.lat),
            lon: lerp(before.lon, after.lon),
            alt_m: lerp(before.alt_m, after.alt_m),
            ve: lerp(before.ve, after.ve),
            vn: lerp(before.vn, after.vn),
            vu: lerp(before.vu, after.vu),
            mode: before.mode,
        })
    }

    /// Times at which the true mode changes, with the new mode.
    pub fn onsets(&self) -> Vec<(f64, FlightMode)> {
        self.samples
            .windows(2)
            .filter_map(|w| match w {
                [a, b] if a.mode != b.mode => Some((b.t, b.mode)),
                _ => None,
            })
            .collect()
    }
}

/// Sums for RMSE and mean error of one group of samples.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ErrorSums {
    pub n: u64,
    pub pos_sq: f64,
    pub pos_abs: f64,
    pub vel_sq: f64,
    pub vel_abs: f64,
    pub alt_sq: f64,
    pub nees_pos: f64,
    pub nees_pos_n: u64,
    pub nees_vel: f64,
    pub nees_vel_n: u64,
}

impl ErrorSums {
    fn add(&mut self, o: &ErrorSums) {
        self.n += o.n;
        self.pos_sq += o.pos_sq;
        self.pos_abs += o.pos_abs;
        self.vel_sq += o.vel_sq;
        self.vel_abs += o.vel_abs;
        self.alt_sq += o.alt_sq;
        self.nees_pos += o.nees_pos;
        self.nees_pos_n += o.nees_pos_n;
        self.nees_vel += o.nees_vel;
        self.nees_vel_n += o.nees_vel_n;
    }
    fn mean(sum: f64, n: u64) -> Option<f64> {
        (n > 0).then(|| sum / n as f64)
    }
    /// Horizontal position RMSE, m.
    pub fn pos_rmse(&self) -> Option<f64> {
        Self::mean(self.pos_sq, self.n).map(f64::sqrt)
    }
    /// Mean horizontal position error, m.
    pub fn pos_mean(&self) -> Option<f64> {
        Self::mean(self.pos_abs, self.n)
    }
    /// Horizontal velocity RMSE, m/s.
    pub fn vel_rmse(&self) -> Option<f64> {
        Self::mean(self.vel_sq, self.n).map(f64::sqrt)
    }
    pub fn vel_mean(&self) -> Option<f64> {
        Self::mean(self.vel_abs, self.n)
    }
    /// Altitude RMSE, m.
    pub fn alt_rmse(&self) -> Option<f64> {
        Self::mean(self.alt_sq, self.n).map(f64::sqrt)
    }
    /// Average NEES of the horizontal position (2 degrees of freedom).
    pub fn anees_pos(&self) -> Option<f64> {
        Self::mean(self.nees_pos, self.nees_pos_n)
    }
    /// Average NEES of the horizontal velocity (2 degrees of freedom).
    pub fn anees_vel(&self) -> Option<f64> {
        Self::mean(self.nees_vel, self.nees_vel_n)
    }
}

/// Every figure of one tracker on one scenario (one run, or merged runs).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Scores {
    /// Estimates, by true mode ("CV", ...) and "all".
    pub estimates: BTreeMap<String, ErrorSums>,
    /// Raw measured positions, by true mode and "all" (velocity fields unused).
    pub raw: BTreeMap<String, ErrorSums>,
    /// Confusion counts: truth label -> estimated label -> count.
    pub confusion: BTreeMap<String, BTreeMap<String, u64>>,
    /// Delay from each manoeuvre onset to the first estimate with the true label, s.
    pub detection_delays_s: Vec<f64>,
    /// Onsets whose label never appeared before the segment ended.
    pub missed_onsets: u64,
    /// The same delays by the mode the truth changed to, and the ends of manoeuvres (a
    /// change back to "CV") besides: a turn's onset, a climb's and an acceleration's are
    /// told apart by data of different quality (a heading against a vertical rate against a
    /// ground speed), so one mean over all of them says little about any.
    pub delays_by_mode_s: BTreeMap<String, Vec<f64>>,
    /// Changes of the true mode (to any mode, CV included) whose label never appeared
    /// before the segment ended, by that mode.
    pub missed_by_mode: BTreeMap<String, u64>,
    /// Label switches away from CV while the truth was CV.
    pub false_switches: u64,
    /// Updates while the truth was CV (denominator of the false-switch rate).
    pub cv_updates: u64,
    /// Per-update wall time, ns (not serialised: the report gives its percentiles).
    #[serde(skip)]
    pub cpu_ns: Vec<u64>,
    /// Largest horizontal position error seen, m.
    pub peak_pos_err_m: f64,
    /// Estimates that carried a windowed NIS, and those inside its two-sided 95 % χ² band:
    /// the track's own consistency claim, checked where the truth is known.
    pub nis_updates: u64,
    pub nis_in_band: u64,
    /// Estimates flagged `diverging`.
    pub diverging_updates: u64,
}

/// Horizontal (east, north) and vertical offset of a position from the truth, metres, in
/// the truth's own east-north-up axes.
pub fn offset_m(truth: &TruthSample, lat: f64, lon: f64, alt_m: f64) -> (Vector2<f64>, f64) {
    let frame = LocalFrame::new(truth.lat, truth.lon, truth.alt_m);
    let e = frame.to_enu(lat, lon, alt_m);
    (Vector2::new(e.x, e.y), e.z)
}

fn nees(e: &Vector2<f64>, cov: &[[f64; 2]; 2]) -> Option<f64> {
    let p = Matrix2::new(cov[0][0], cov[0][1], cov[1][0], cov[1][1]);
    let chol = p.cholesky()?;
    Some(e.dot(&chol.solve(e)))
}

impl Scores {
    /// Scores one aircraft's estimates (in time order) and raw positions against its truth.
    pub fn score_track(
        truth: &TruthTrack,
        estimates: &[EstimateSample],
        raw: &[RawPosition],
    ) -> Self {
        let mut s = Scores::default();
        let mut last_label: Option<FlightMode> = None;
        for est in estimates {
            let Some(tr) = truth.at(est.t) else { continue };
            let (d, dz) = offset_m(&tr, est.lat, est.lon, est.alt_m);
            let dv = Vector2::new(est.ve - tr.ve, est.vn - tr.vn);
            let mut sums = ErrorSums {
                n: 1,
                pos_sq: d.norm_squared(),
                pos_abs: d.norm(),
                vel_sq: dv.norm_squared(),
                vel_abs: dv.norm(),
                alt_sq: dz * dz,
                ..Default::default()
            };
            if let Some(v) = est.pos_cov_en.as_ref().and_then(|c| nees(&d, c)) {
                sums.nees_pos = v;
                sums.nees_pos_n = 1;
            }
            if let Some(v) = est.vel_cov_en.as_ref().and_then(|c| nees(&dv, c)) {
                sums.nees_vel = v;
                sums.nees_vel_n = 1;
            }
            s.peak_pos_err_m = s.peak_pos_err_m.max(d.norm());
            if let Some((nis, dof)) = est.nis.filter(|&(_, dof)| dof > 0) {
                let (lo, hi) = chi2_band_95(f64::from(dof), 1.0);
                s.nis_updates += 1;
                s.nis_in_band += u64::from((lo..=hi).contains(&nis));
            }
            s.diverging_updates += u64::from(est.diverging);
            for key in [tr.mode.as_str(), "all"] {
                s.estimates.entry(key.to_string()).or_default().add(&sums);
            }
            *s.confusion
                .entry(tr.mode.as_str().to_string())
                .or_default()
                .entry(est.mode.as_str().to_string())
                .or_default() += 1;
            if tr.mode == FlightMode::Cv {
                s.cv_updates += 1;
                if last_label == Some(FlightMode::Cv) && est.mode != FlightMode::Cv {
                    s.false_switches += 1;
                }
            }
            last_label = Some(est.mode);
            if let Some(ns) = est.cpu_ns {
                s.cpu_ns.push(ns);
            }
        }
        for r in raw {
            let Some(tr) = truth.at(r.t) else { continue };
            let (d, dz) = offset_m(&tr, r.lat, r.lon, r.alt_m);
            let sums = ErrorSums {
                n: 1,
                pos_sq: d.norm_squared(),
                pos_abs: d.norm(),
                alt_sq: dz * dz,
                ..Default::default()
            };
            for key in [tr.mode.as_str(), "all"] {
                s.raw.entry(key.to_string()).or_default().add(&sums);
            }
        }
        // Detection delay: from each change of the true mode to the first estimate labelled
        // with the new mode, before the segment ends. The headline figures count the onsets
        // of manoeuvres (a change to a mode other than CV); the table by mode has the ends
        // (back to CV) too.
        let onsets = truth.onsets();
        for (i, &(t0, mode)) in onsets.iter().enumerate() {
            let end = onsets.get(i + 1).map_or(f64::INFINITY, |&(t1, _)| t1);
            let found = estimates
                .iter()
                .find(|e| e.t >= t0 && e.t < end && e.mode == mode);
            let key = mode.as_str().to_string();
            match found {
                Some(e) => s.delays_by_mode_s.entry(key).or_default().push(e.t - t0),
                None => *s.missed_by_mode.entry(key).or_default() += 1,
            }
            if mode == FlightMode::Cv {
                continue;
            }
            match found {
                Some(e) => s.detection_delays_s.push(e.t - t0),
                None => s.missed_onsets += 1,
            }
        }
        s
    }

    /// Adds another run's (or aircraft's) scores.
    pub fn merge(&mut self, o: &Scores) {
        for (k, v) in &o.estimates {
            self.estimates.entry(k.clone()).or_default().add(v);
        }
        for (k, v) in &o.raw {
            self.raw.entry(k.clone()).or_default().add(v);
        }
        for (t, row) in &o.confusion {
            let mine = self.confusion.entry(t.clone()).or_default();
            for (e, n) in row {
                *mine.entry(e.clone()).or_default() += n;
            }
        }
        self.detection_delays_s
            .extend_from_slice(&o.detection_delays_s);
        self.missed_onsets += o.missed_onsets;
        for (k, v) in &o.delays_by_mode_s {
            self.delays_by_mode_s
                .entry(k.clone())
                .or_default()
                .extend_from_slice(v);
        }
        for (k, n) in &o.missed_by_mode {
            *self.missed_by_mode.entry(k.clone()).or_default() += n;
        }
        self.false_switches += o.false_switches;
        self.cv_updates += o.cv_updates;
        self.cpu_ns.extend_from_slice(&o.cpu_ns);
        self.peak_pos_err_m = self.peak_pos_err_m.max(o.peak_pos_err_m);
        self.nis_updates += o.nis_updates;
        self.nis_in_band += o.nis_in_band;
        self.diverging_updates += o.diverging_updates;
    }

    /// Share of the estimates carrying a windowed NIS whose NIS is inside its band, %.
    pub fn nis_in_band_pct(&self) -> Option<f64> {
        (self.nis_updates > 0).then(|| 100.0 * self.nis_in_band as f64 / self.nis_updates as f64)
    }

    /// Share of the estimates flagged `diverging`, %.
    pub fn diverging_pct(&self) -> Option<f64> {
        let n = self.estimates.get("all").map_or(0, |e| e.n);
        (n > 0).then(|| 100.0 * self.diverging_updates as f64 / n as f64)
    }

    /// Fraction of estimates whose label equals the true mode.
    pub fn label_accuracy(&self) -> Option<f64> {
        let (mut right, mut all) = (0u64, 0u64);
        for (t, row) in &self.confusion {
            for (e, n) in row {
                all += n;
                if t == e {
                    right += n;
                }
            }
        }
        (all > 0).then(|| right as f64 / all as f64)
    }

    /// Label switches away from CV on straight legs, per 100 updates there.
    pub fn false_switches_per_100(&self) -> Option<f64> {
        (self.cv_updates > 0).then(|| 100.0 * self.false_switches as f64 / self.cv_updates as f64)
    }

    /// Mean detection delay, s.
    pub fn mean_detection_delay_s(&self) -> Option<f64> {
        let n = self.detection_delays_s.len();
        (n > 0).then(|| self.detection_delays_s.iter().sum::<f64>() / n as f64)
    }

    /// Mean delay to the label of changes into `mode` ("CV": the ends of manoeuvres), s,
    /// with the number of such changes labelled and missed.
    pub fn mean_delay_to_s(&self, mode: &str) -> (Option<f64>, usize, u64) {
        let d = self
            .delays_by_mode_s
            .get(mode)
            .map_or(&[][..], Vec::as_slice);
        let missed = self.missed_by_mode.get(mode).copied().unwrap_or(0);
        let mean = (!d.is_empty()).then(|| d.iter().sum::<f64>() / d.len() as f64);
        (mean, d.len(), missed)
    }

    /// Median and 99th percentile of the per-update CPU time, ns.
    pub fn cpu_percentiles_ns(&self) -> Option<(u64, u64)> {
        let mut v = self.cpu_ns.clone();
        if v.is_empty() {
            return None;
        }
        v.sort_unstable();
        let pick = |q: f64| {
            let i = ((v.len() - 1) as f64 * q).round() as usize;
            v.get(i).copied().unwrap_or(0)
        };
        Some((pick(0.5), pick(0.99)))
    }
}

/// Two-sided 95 % band of the average of `n` independent chi-square(dof) variables divided by
/// n, via the Wilson-Hilferty approximation (accurate to ~1 % for dof·n >= 10).
pub fn chi2_band_95(dof: f64, n: f64) -> (f64, f64) {
    let k = dof * n;
    let z = 1.959_963_984_540_054;
    let q = |z: f64| {
        let a = 2.0 / (9.0 * k);
        k * (1.0 - a + z * a.sqrt()).powi(3)
    };
    (q(-z) / n, q(z) / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t: f64, east_m: f64, mode: FlightMode) -> TruthSample {
        // 1 degree of longitude at the equator is 111,319.49 m on WGS-84.
        TruthSample {
            t,
            lat: 0.0,
            lon: east_m / 111_319.490_793,
            alt_m: 0.0,
            ve: 100.0,
            vn: 0.0,
            vu: 0.0,
            mode,
        }
    }

    #[test]
    fn interpolation_and_errors() {
        let truth = TruthTrack::new(vec![
            sample(0.0, 0.0, FlightMode::Cv),
            sample(10.0, 1000.0, FlightMode::Ct),
        ]);
        let at = truth.at(5.0).unwrap();
        assert!((at.lon * 111_319.490_793 - 500.0).abs() < 1e-6);
        assert_eq!(at.mode, FlightMode::Cv);
        assert!(truth.at(-1.0).is_none() && truth.at(11.0).is_none());

        // An estimate 30 m north of the truth at t = 5, 3 m/s too fast.
        let est = EstimateSample {
            t: 5.0,
            lat: 30.0 / 110_574.0,
            lon: at.lon,
            alt_m: 0.0,
            ve: 103.0,
            vn: 0.0,
            vu: 0.0,
            mode: FlightMode::Cv,
            pos_cov_en: Some([[100.0, 0.0], [0.0, 900.0]]),
            vel_cov_en: None,
            cpu_ns: Some(100),
            nis: Some((2.0, 2)),
            diverging: true,
        };
        let s = Scores::score_track(&truth, &[est], &[]);
        let all = &s.estimates["all"];
        // 1 degree of latitude at the equator is 110,574 m (WGS-84 meridian arc).
        assert!(
            (all.pos_rmse().unwrap() - 30.0).abs() < 0.01,
            "{:?}",
            all.pos_rmse()
        );
        assert!((all.vel_rmse().unwrap() - 3.0).abs() < 1e-9);
        // NEES = 30^2 / 900 = 1.
        assert!((all.anees_pos().unwrap() - 1.0).abs() < 1e-3);
        assert_eq!(s.label_accuracy(), Some(1.0));
        // χ²(2)'s 95 % band is [0.05, 7.38]: 2 is inside; the one estimate is flagged.
        assert_eq!(s.nis_in_band_pct(), Some(100.0));
        assert_eq!(s.diverging_pct(), Some(100.0));
    }

    /// An estimate at time `t` on [`sample`]'s truth (100 m/s east along the equator), with
    /// the label `mode`.
    fn on_the_truth(t: f64, mode: FlightMode) -> EstimateSample {
        EstimateSample {
            t,
            lat: 0.0,
            lon: 100.0 * t / 111_319.490_793,
            alt_m: 0.0,
            ve: 100.0,
            vn: 0.0,
            vu: 0.0,
            mode,
            pos_cov_en: None,
            vel_cov_en: None,
            cpu_ns: None,
            nis: None,
            diverging: false,
        }
    }

    #[test]
    fn detection_delay_and_false_switches() {
        let truth = TruthTrack::new(
            (0..=20)
                .map(|i| {
                    sample(
                        f64::from(i),
                        100.0 * f64::from(i),
                        if i >= 10 {
                            FlightMode::Ct
                        } else {
                            FlightMode::Cv
                        },
                    )
                })
                .collect(),
        );
        use FlightMode::*;
        let e: Vec<_> = [
            (1.0, Cv),
            (2.0, Ct),
            (3.0, Cv),
            (4.0, Cv),
            (10.5, Cv),
            (12.5, Ct),
            (13.0, Ct),
        ]
        .into_iter()
        .map(|(t, m)| on_the_truth(t, m))
        .collect();
        let s = Scores::score_track(&truth, &e, &[]);
        assert_eq!(s.detection_delays_s, vec![2.5]);
        assert_eq!(s.false_switches, 1);
        assert_eq!(s.cv_updates, 4);
        assert_eq!(s.false_switches_per_100(), Some(25.0));
    }

    /// Each change of the true mode is timed to its first label, turns apart from climbs
    /// and ends (back to CV) apart from onsets; a change never labelled is counted missed.
    #[test]
    fn delays_by_the_mode_changed_to() {
        use FlightMode::*;
        // CV 0-9 s, CT 10-19 s, CV 20-29 s, CH 30-39 s, CV from 40 s.
        let mode_at = |t: i32| match t {
            10..=19 => Ct,
            30..=39 => Ch,
            _ => Cv,
        };
        let truth = TruthTrack::new(
            (0..=50)
                .map(|i| sample(f64::from(i), 100.0 * f64::from(i), mode_at(i)))
                .collect(),
        );
        let e: Vec<_> = [
            (5.0, Cv),
            (11.0, Ct), // turn onset: 1 s
            (21.0, Ct),
            (23.5, Cv), // turn end: 3.5 s
            (31.0, Cv),
            (35.0, Ct), // the climb is never labelled CH: missed
            (42.0, Cv), // its end: 2 s
        ]
        .into_iter()
        .map(|(t, m)| on_the_truth(t, m))
        .collect();
        let s = Scores::score_track(&truth, &e, &[]);
        assert_eq!(s.mean_delay_to_s("CT"), (Some(1.0), 1, 0));
        assert_eq!(s.mean_delay_to_s("CH"), (None, 0, 1));
        assert_eq!(s.mean_delay_to_s("CV"), (Some(2.75), 2, 0));
        assert_eq!(s.mean_delay_to_s("CA"), (None, 0, 0));
        // The headline figures keep to the onsets of manoeuvres.
        assert_eq!(s.detection_delays_s, vec![1.0]);
        assert_eq!(s.missed_onsets, 1);
        let mut merged = s.clone();
        merged.merge(&s);
        assert_eq!(merged.mean_delay_to_s("CV"), (Some(2.75), 4, 0));
        assert_eq!(merged.mean_delay_to_s("CH"), (None, 0, 2));
    }

    #[test]
    fn chi2_band_matches_tables() {
        // chi2(0.025, 200) = 162.73, chi2(0.975, 200) = 241.06 (tables), n = 100, dof = 2.
        let (lo, hi) = chi2_band_95(2.0, 100.0);
        assert!((lo - 1.6273).abs() < 0.01, "{lo}");
        assert!((hi - 2.4106).abs() < 0.01, "{hi}");
    }
}
