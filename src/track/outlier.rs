//! Position reports out of their time: set aside, and counted.
//!
//! Real feeds carry a few position reports from another error process than the one a
//! filter models. The AFR34ZG recording (`fixtures/afr34zg-cdg-tls.jsonl`, merged from
//! several receivers) shows it every 16-48 s: one to four positions in a row 0.5-0.8 s
//! behind the flight (a stale fix, or a frame stamped by another receiver's clock) while
//! its velocity reports stay on the line. Against a CV filter's prediction their
//! horizontal NIS is 200-600 where 2 is usual, about 3 % of its position reports. Used,
//! each pulls the track 100 m back along its course for several seconds, and the windowed
//! NIS of the next 20 updates sits above its band: 21 % of the flight's steady updates.
//!
//! This is a validation gate in the tracking sense (Bar-Shalom, Li & Kirubarajan 2001,
//! *Estimation with Applications to Tracking and Navigation*, §5.2.3: a measurement
//! outside the gate is not the target's), made safe for a single known target:
//!
//! - **The test**: the report's horizontal position NIS above [`OutlierParams::nis`]
//!   (27.63: χ²(2) exceeds it with probability e^(−27.63/2) = 10⁻⁶, so a consistent
//!   filter sets aside one report in a million). At 18.42 (10⁻⁴) the gains on the real
//!   recordings and on `airliner-stale` were the same, but paper 002's white-noise
//!   flight lost 0.2 % of straight RMSE (10.345 → 10.364 m, 100 runs) to the valid reports
//!   in the Gaussian tail it set aside (about 10 a hundred runs).
//! - **Only when the velocity reports vouch for the flight**: the tracker asks only while
//!   its gate sees no horizontal manoeuvre in measured, current velocity reports. A real
//!   manoeuvre moves the velocity reports; a stale position does not. In an IMM (the
//!   hybrid's IMM branch, the plain `imm`) the same holds for the mode it holds at 0.9:
//!   while the last velocity report fitted that mode (a turn under CT), a position far off
//!   the mode's prediction is judged by that mode's NIS. A roll-out moves the velocity
//!   reports off CT's prediction first, so a real change is not set aside; a stale
//!   position in a turn is (`airliner-stale`, 40 runs: the hybrid's turn RMSE 8.9 → 7.1 m).
//! - **Never for long**: at most [`OutlierParams::max_in_a_row`] reports in a row (4). The
//!   next one is used whatever its NIS, so a track that has really lost the aircraft gets
//!   its position back, and paper 000's criterion still counts every set-aside report as a
//!   divergence event (a run of them opens the IMM as before).
//! - **Only while rare**: where more than [`OutlierParams::max_share`] (10 %) of an
//!   aircraft's recent position reports exceed the test, the large innovations are its
//!   noise, not outliers, and every report is used (and learned from). The LAX recording
//!   without timestamps (`--nominal-rate`, a synthetic clock) exceeds it on about half its
//!   position reports: there the gate would have set aside 55 % of the positions.
//!
//! A report set aside changes nothing: the state, the covariance, the learned noise and the
//! windowed NIS are as they were, and the track's time does not advance. Its barometric
//! altitude goes with it: on AFR34ZG it is as stale as the position (in the descents the
//! set-aside reports' altitudes read 5.9 m above the track where the used ones read 0.0 m,
//! about 0.3 s old; an altitude-only update was tried and made the simulated climbs'
//! altitude worse, `docs/evaluation.md`). The count is published per track
//! (`outlier_positions`) and over the daemon (`/metrics`).

/// χ²(2) exceeds this with probability 10⁻⁶: −2 ln 10⁻⁶ = 27.631, to the digits a
/// configuration file gives it.
pub const NIS_2DOF_1E6: f64 = 27.63;

/// The gate's settings (`[tracker.hybrid] outlier_*`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutlierParams {
    /// Horizontal position NIS above which a report may be set aside; 0 turns the gate
    /// off. Default [`NIS_2DOF_1E6`].
    pub nis: f64,
    /// At most this many reports in a row are set aside. Default 4: of AFR34ZG's runs of
    /// reports above the test (velocity reports between them fitting the line), 16 of 68
    /// are three long and 9 four, none longer; at 2 the third went in at a NIS of 30-80 and
    /// pulled the track back for the windows after it (`docs/evaluation.md`, "Positions out
    /// of their time"). Four is two seconds of positions at 2 Hz.
    pub max_in_a_row: u32,
    /// Reports are set aside only while the share of recent position reports above `nis`
    /// is below this. Default 0.1: AFR34ZG's bursts are about 3 %, a consistent filter's
    /// exceedances 10⁻⁴ %.
    pub max_share: f64,
    /// The share is an exponential mean over about this many position reports. Default 100
    /// (50 s at 2 Hz: two AFR34ZG bursts).
    pub share_window: f64,
}

impl Default for OutlierParams {
    fn default() -> Self {
        Self {
            nis: NIS_2DOF_1E6,
            max_in_a_row: 4,
            max_share: 0.1,
            share_window: 100.0,
        }
    }
}

impl OutlierParams {
    /// The gate off: every report used.
    pub fn off() -> Self {
        Self {
            nis: 0.0,
            ..Self::default()
        }
    }

    /// Whether the gate ever sets a report aside.
    pub fn enabled(&self) -> bool {
        self.nis > 0.0 && self.max_in_a_row > 0 && self.max_share > 0.0
    }
}

/// One aircraft's gate: reports set aside in a row and in all, and the recent share of
/// position reports above the test.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OutlierGate {
    run: u32,
    share: f64,
    count: u64,
}

impl OutlierGate {
    /// Judges a position report by its horizontal NIS. `vouched`: the velocity reports are
    /// current and show no horizontal manoeuvre. True: set the report aside (counted).
    pub fn set_aside(
        &mut self,
        nis_horizontal: f64,
        vouched: bool,
        params: &OutlierParams,
    ) -> bool {
        if !params.enabled() {
            return false;
        }
        let exceeds = nis_horizontal > params.nis;
        let may = self.may_set_aside(vouched, params);
        let hit = if exceeds { 1.0 } else { 0.0 };
        self.share += (hit - self.share) / params.share_window.max(1.0);
        if exceeds && may {
            self.run += 1;
            self.count = self.count.saturating_add(1);
            true
        } else {
            self.run = 0;
            false
        }
    }

    /// Whether a report exceeding the test would now be set aside: what a tracker that
    /// must prepare to go back (a copy of its state) asks before the report's update.
    pub fn may_set_aside(&self, vouched: bool, params: &OutlierParams) -> bool {
        params.enabled()
            && vouched
            && self.run < params.max_in_a_row
            && self.share < params.max_share
    }

    /// Position reports set aside over the aircraft's life.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The recent share of position reports above the test.
    pub fn share(&self) -> f64 {
        self.share
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_threshold_is_the_chi2_2_tail_of_one_in_a_million() {
        // χ²(2) survival function: exp(−x/2).
        assert!(((-NIS_2DOF_1E6 / 2.0).exp() / 1e-6 - 1.0).abs() < 1e-3);
    }

    #[test]
    fn a_burst_is_set_aside_four_reports_at_most() {
        let p = OutlierParams::default();
        let mut g = OutlierGate::default();
        for _ in 0..200 {
            assert!(!g.set_aside(2.0, true, &p));
        }
        // A burst of six: the first four set aside, the fifth used, the sixth again.
        let verdicts: Vec<bool> = [300.0, 600.0, 200.0, 80.0, 60.0, 50.0]
            .iter()
            .map(|&n| g.set_aside(n, true, &p))
            .collect();
        assert_eq!(verdicts, [true, true, true, true, false, true]);
        assert_eq!(g.count(), 5);
        assert!(!g.set_aside(1.0, true, &p));
    }

    #[test]
    fn nothing_is_set_aside_in_a_manoeuvre_or_when_off() {
        let mut g = OutlierGate::default();
        assert!(!g.set_aside(500.0, false, &OutlierParams::default()));
        assert!(!g.set_aside(500.0, true, &OutlierParams::off()));
        let none = OutlierParams {
            max_in_a_row: 0,
            ..OutlierParams::default()
        };
        assert!(!g.set_aside(500.0, true, &none));
        assert_eq!(g.count(), 0);
    }

    #[test]
    fn where_large_innovations_are_the_noise_every_report_is_used() {
        // Half the reports above the test (LAX's synthetic clock): after the share has
        // passed 10 %, nothing more is set aside.
        let p = OutlierParams::default();
        let mut g = OutlierGate::default();
        let mut aside_late = 0;
        for k in 0..2000 {
            let nis = if k % 2 == 0 { 40.0 } else { 1.0 };
            if g.set_aside(nis, true, &p) && k >= 100 {
                aside_late += 1;
            }
        }
        assert_eq!(aside_late, 0);
        assert!(g.share() > 0.4, "share {}", g.share());
        // About 5 % (AFR34ZG's bursts: two reports every 40): every burst set aside.
        let mut g = OutlierGate::default();
        let (mut above, mut aside) = (0, 0);
        for k in 0..4000 {
            let nis = if k % 40 < 2 { 300.0 } else { 1.0 };
            above += usize::from(nis > p.nis);
            aside += usize::from(g.set_aside(nis, true, &p));
        }
        assert_eq!(aside, above);
        assert!((g.share() - 0.05).abs() < 0.03, "share {}", g.share());
    }
}
