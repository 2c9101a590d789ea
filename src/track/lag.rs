//! How much older an aircraft's velocity reports are than its positions, learned while it is
//! tracked: the per-aircraft form of `eval::latency`'s estimator (its module doc has the
//! method and its check against the simulator's known offsets), fed the reports a tracker
//! gets, in its local plane.
//!
//! Per window of [`WINDOW_S`]: the position reports less the integral of the velocity
//! reports (trapezoids, the velocity interpolated between the reports either side of each
//! position) are fitted as c + d·τ + v·λ per horizontal axis. A position waits for the next
//! velocity report to be placed ([`PENDING`] at most). Only the sums the fit needs are kept
//! (the normal equations have 16 distinct entries), and a closed window that saw the
//! velocity change by [`MIN_VELOCITY_CHANGE_MPS`] and fits λ to within [`MAX_WINDOW_SIGMA_S`]
//! joins the aircraft's estimate, an inverse-variance mean. The lag is used once it is at
//! least [`MIN_LAG_S`] by [`LAG_SIGMAS`] standard errors: on the simulator, whose
//! velocities are current, the estimate sits at −0.04 ± 0.01 s and nothing changes.

use nalgebra::{Matrix5, Vector5};

/// Length of one window, s: long enough to hold a turn's change of velocity, short enough
/// that a GNSS error wandering over minutes is nearly a line within it.
pub const WINDOW_S: f64 = 60.0;
/// Smallest change of the velocity within a window for it to count, m/s: a 10° turn at
/// 120 m/s.
pub const MIN_VELOCITY_CHANGE_MPS: f64 = 20.0;
/// Largest standard error of a window's λ for it to count, s.
pub const MAX_WINDOW_SIGMA_S: f64 = 0.1;
/// How many standard errors the estimate must clear [`MIN_LAG_S`] by. Three, not two: the
/// standard error comes from the residuals as if they were white, and a GNSS error that
/// wanders makes the windows scatter three or four times as much (`eval::latency`'s test).
pub const LAG_SIGMAS: f64 = 3.0;
/// Smallest lag worth turning a report by, s: 0.1 s of a 3°/s turn at 140 m/s is 0.7 m/s.
pub const MIN_LAG_S: f64 = 0.1;
/// Largest lag used, s.
pub const MAX_LAG_S: f64 = 3.0;
/// Fewest positions in a window for it to count.
pub const MIN_POSITIONS: u32 = 30;
/// Positions held while waiting for the velocity report after them.
pub const PENDING: usize = 4;

/// A tracker's learner at work: made (boxed) at the aircraft's first report, given `m`
/// unless `m` is older than the track at `track_t_s` (the tracker refuses such a report
/// too). Returns the lag the IMM's CT modes are to use, the learnt one or until then
/// `configured_s`; `None` for a report left out. What the hybrid and the plain IMM share.
pub fn learn(
    learner: &mut Option<Box<VelocityLag>>,
    m: &super::Measurement,
    track_t_s: Option<f64>,
    configured_s: f64,
) -> Option<f64> {
    if track_t_s.is_some_and(|t| m.t_s < t) {
        return None;
    }
    let lag = learner.get_or_insert_with(Box::default);
    lag.push(
        m.t_s,
        m.position.as_ref().map(|o| (o.value.x, o.value.y)),
        m.velocity.as_ref().map(|o| (o.value.x, o.value.y)),
    );
    Some(lag.lag_s().unwrap_or(configured_s))
}

/// A tracker's learner when its track restarts ([`VelocityLag::new_plane`]): what the
/// hybrid and the plain IMM keep of it.
pub fn kept_over_restart(learner: Option<Box<VelocityLag>>) -> Option<Box<VelocityLag>> {
    learner.map(|mut l| {
        l.new_plane();
        l
    })
}

/// One window's least-squares fit (module doc), as the sums its normal equations need: what
/// the learner keeps per aircraft, and what `eval::latency` fits a recording's windows with.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WindowFit {
    /// The window's first position less the velocity integral there (east, north), m: the
    /// origin of the sums, so they hold metres, not the distance flown.
    origin: Option<(f64, f64)>,
    n: u32,
    tau: f64,
    tau2: f64,
    /// The sums of each horizontal axis (east, north).
    axes: [AxisSums; 2],
    /// Σ (r_e² + r_n²).
    r2: f64,
}

/// One axis's sums of [`WindowFit`]: its velocity v and residual r against τ.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct AxisSums {
    v: f64,
    v_tau: f64,
    v2: f64,
    r: f64,
    r_tau: f64,
    r_v: f64,
}

impl AxisSums {
    fn add(&mut self, tau: f64, v: f64, r: f64) {
        self.v += v;
        self.v_tau += v * tau;
        self.v2 += v * v;
        self.r += r;
        self.r_tau += r * tau;
        self.r_v += r * v;
    }
}

impl WindowFit {
    /// Positions added so far.
    pub fn positions(&self) -> u32 {
        self.n
    }

    /// A position (t, east, north) between velocity reports `a` and `b` (t, east, north m/s;
    /// a.0 ≤ t ≤ b.0, a.0 < b.0), the integral of the reports up to `a` being `integral_a`
    /// (east, north, m), `tau` its time from any fixed instant of the window, s: the velocity
    /// interpolated at t, the integral continued to t by the trapezoid under it.
    pub fn add_position(
        &mut self,
        tau: f64,
        (t, e, n): (f64, f64, f64),
        a: &Velocity,
        b: &Velocity,
        integral_a: (f64, f64),
    ) {
        let w = (t - a.0) / (b.0 - a.0);
        let (ve, vn) = (a.1 + w * (b.1 - a.1), a.2 + w * (b.2 - a.2));
        let s = t - a.0;
        let int_e = integral_a.0 + s * (a.1 + 0.5 * w * (b.1 - a.1));
        let int_n = integral_a.1 + s * (a.2 + 0.5 * w * (b.2 - a.2));
        let (e0, n0) = *self.origin.get_or_insert((e - int_e, n - int_n));
        let (re, rn) = (e - int_e - e0, n - int_n - n0);
        self.n += 1;
        self.tau += tau;
        self.tau2 += tau * tau;
        let [east, north] = &mut self.axes;
        east.add(tau, ve, re);
        north.add(tau, vn, rn);
        self.r2 += re * re + rn * rn;
    }

    /// λ and its standard error, when the fit is determined.
    pub fn fit(&self) -> Option<(f64, f64)> {
        let n = f64::from(self.n);
        // x = (c_e, d_e, c_n, d_n, λ); rows [1, τ, 0, 0, ve] and [0, 0, 1, τ, vn].
        let [e, nn] = &self.axes;
        let ata = Matrix5::new(
            n,
            self.tau,
            0.0,
            0.0,
            e.v, //
            self.tau,
            self.tau2,
            0.0,
            0.0,
            e.v_tau, //
            0.0,
            0.0,
            n,
            self.tau,
            nn.v, //
            0.0,
            0.0,
            self.tau,
            self.tau2,
            nn.v_tau, //
            e.v,
            e.v_tau,
            nn.v,
            nn.v_tau,
            e.v2 + nn.v2,
        );
        let atb = Vector5::new(e.r, e.r_tau, nn.r, nn.r_tau, e.r_v + nn.r_v);
        let chol = ata.cholesky()?;
        let x = chol.solve(&atb);
        // Residual sum of squares: bᵀb − xᵀAᵀb at the solution.
        let ss = (self.r2 - x.dot(&atb)).max(0.0);
        let dof = 2.0 * n - 5.0;
        let var = ss / dof * chol.inverse()[(4, 4)];
        let lambda = x[4];
        (dof > 0.0 && lambda.is_finite() && var.is_finite() && var > 0.0)
            .then(|| (lambda, var.sqrt()))
    }
}

/// A velocity report: time, east and north, m/s.
pub type Velocity = (f64, f64, f64);

/// One aircraft's learner.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VelocityLag {
    /// Start of the current window, s (None before the first report).
    window_start_s: Option<f64>,
    fit: WindowFit,
    /// The last velocity report, and the integral of the reports up to it (east, north), m.
    last_velocity: Option<Velocity>,
    integral: (f64, f64),
    /// The velocity extremes of the window, for its change (east min, max, north min, max).
    extremes: [f64; 4],
    /// Positions (t, east, north) waiting for the next velocity report.
    pending: [(f64, f64, f64); PENDING],
    pending_len: usize,
    /// Σ 1/σ² and Σ λ/σ² over the windows that counted.
    weight: f64,
    weighted_lag: f64,
    /// The lag they give, once it clears the bound ([`VelocityLag::lag_s`]): worked out when
    /// a window closes, read on every report.
    learnt_s: Option<f64>,
}

impl VelocityLag {
    /// Takes a report at `t_s` (in time order): its horizontal position (east, north, m)
    /// and/or velocity (east, north, m/s) in the tracker's plane.
    pub fn push(&mut self, t_s: f64, position: Option<(f64, f64)>, velocity: Option<(f64, f64)>) {
        if !t_s.is_finite() {
            return;
        }
        let start = *self.window_start_s.get_or_insert(t_s);
        if t_s - start >= WINDOW_S || t_s < start {
            self.close_window();
            self.window_start_s = Some(t_s);
        }
        if let Some((e, n)) = position.filter(|(e, n)| e.is_finite() && n.is_finite()) {
            if self.pending_len == PENDING {
                self.pending.copy_within(1.., 0);
                self.pending_len -= 1;
            }
            if let Some(slot) = self.pending.get_mut(self.pending_len) {
                *slot = (t_s, e, n);
                self.pending_len += 1;
            }
        }
        if let Some((ve, vn)) = velocity.filter(|(e, n)| e.is_finite() && n.is_finite()) {
            self.take_velocity((t_s, ve, vn));
        }
    }

    /// The track moved to another plane (or restarted): the current window's sums are
    /// dropped, what the closed windows taught is kept (the lag is the avionics', not the
    /// track's).
    pub fn new_plane(&mut self) {
        *self = Self {
            weight: self.weight,
            weighted_lag: self.weighted_lag,
            learnt_s: self.learnt_s,
            ..Self::default()
        };
    }

    /// The lag to turn velocity reports by, s, once it is learnt (module doc).
    pub fn lag_s(&self) -> Option<f64> {
        self.learnt_s
    }

    /// A velocity report: the pending positions before it are placed between it and the
    /// last one, then it extends the integral.
    fn take_velocity(&mut self, v: Velocity) {
        let Some(a) = self.last_velocity else {
            self.last_velocity = Some(v);
            self.pending_len = 0;
            self.extremes = [v.1, v.1, v.2, v.2];
            return;
        };
        let dt = v.0 - a.0;
        if dt > 0.0 {
            let pending = self.pending;
            let mut kept = 0;
            for &(t, e, n) in pending.iter().take(self.pending_len) {
                if t > v.0 {
                    // After this report: waits for the next.
                    if let Some(slot) = self.pending.get_mut(kept) {
                        *slot = (t, e, n);
                        kept += 1;
                    }
                    continue;
                }
                if t < a.0 {
                    continue;
                }
                let tau = t - self.window_start_s.unwrap_or(t) - 0.5 * WINDOW_S;
                self.fit.add_position(tau, (t, e, n), &a, &v, self.integral);
            }
            self.pending_len = kept;
            self.integral.0 += 0.5 * (a.1 + v.1) * dt;
            self.integral.1 += 0.5 * (a.2 + v.2) * dt;
        }
        let x = &mut self.extremes;
        x[0] = x[0].min(v.1);
        x[1] = x[1].max(v.1);
        x[2] = x[2].min(v.2);
        x[3] = x[3].max(v.2);
        self.last_velocity = Some(v);
    }

    /// Ends the window: its λ joins the estimate if it counts; the next window starts from
    /// the last velocity report.
    fn close_window(&mut self) {
        let x = self.extremes;
        let change = (x[1] - x[0]).hypot(x[3] - x[2]);
        if self.fit.positions() >= MIN_POSITIONS && change >= MIN_VELOCITY_CHANGE_MPS {
            if let Some((lambda, sigma)) = self.fit.fit() {
                if sigma <= MAX_WINDOW_SIGMA_S {
                    let w = 1.0 / (sigma * sigma);
                    self.weight += w;
                    self.weighted_lag += w * lambda;
                    let lag = self.weighted_lag / self.weight;
                    let sigma = self.weight.sqrt().recip();
                    self.learnt_s = (lag - LAG_SIGMAS * sigma >= MIN_LAG_S && lag.is_finite())
                        .then(|| lag.min(MAX_LAG_S));
                }
            }
        }
        self.fit = WindowFit::default();
        if let Some(v) = self.last_velocity {
            self.extremes = [v.1, v.1, v.2, v.2];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    /// A flight at 140 m/s: straight 60 s, a left turn at 3°/s for 30 s, straight again, in
    /// a loop, for `duration_s`. Positions every 0.5 s with 3 m of noise, velocities every
    /// 0.5 s (0.25 s after) with 0.3 m/s, each `lag_s` old.
    fn learner_after(duration_s: f64, lag_s: f64, seed: u64) -> VelocityLag {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut noise = |sigma: f64| sigma * (rng.gen::<f64>() + rng.gen::<f64>() - 1.0) * 2.45;
        let omega = 3.0_f64.to_radians();
        // Heading and position by small steps of the truth.
        let dt = 0.01;
        let mut truth = Vec::new();
        let (mut e, mut n, mut heading) = (0.0, 0.0, 0.0_f64);
        let mut t = 0.0;
        while t < duration_s + 1.0 {
            let turning = (t % 120.0) >= 60.0 && (t % 120.0) < 90.0;
            truth.push((t, e, n, heading));
            if turning {
                heading += omega * dt;
            }
            e += 140.0 * heading.sin() * dt;
            n += 140.0 * heading.cos() * dt;
            t += dt;
        }
        let at = |t: f64| truth.get((t / dt).round().max(0.0) as usize).copied();
        let mut lag = VelocityLag::default();
        let mut k = 0;
        while 0.5 * f64::from(k) < duration_s {
            let t = 0.5 * f64::from(k);
            if let Some((_, e, n, _)) = at(t) {
                lag.push(t, Some((e + noise(3.0), n + noise(3.0))), None);
            }
            let tv = t + 0.25;
            if let Some((_, _, _, h)) = at(tv - lag_s) {
                let v = (140.0 * h.sin() + noise(0.3), 140.0 * h.cos() + noise(0.3));
                lag.push(tv, None, Some(v));
            }
            k += 1;
        }
        lag
    }

    #[test]
    fn a_second_late_velocity_is_learnt_from_the_turns() {
        for seed in 0..5 {
            let l = learner_after(600.0, 1.0, seed);
            let lag = l.lag_s().unwrap_or_else(|| panic!("{seed}: {l:?}"));
            assert!((lag - 1.0).abs() < 0.05, "{seed}: {lag}");
            // 0.5 s too.
            let lag = learner_after(600.0, 0.5, seed).lag_s().unwrap_or(0.0);
            assert!((lag - 0.5).abs() < 0.05, "{seed}: {lag}");
        }
    }

    /// Current velocities, or a flight too short for a window with a turn: nothing is used.
    #[test]
    fn current_velocities_change_nothing() {
        for seed in 0..20 {
            assert_eq!(learner_after(600.0, 0.0, seed).lag_s(), None, "{seed}");
            assert_eq!(learner_after(600.0, 0.05, seed).lag_s(), None, "{seed}");
        }
        assert_eq!(learner_after(59.0, 1.0, 1).lag_s(), None);
    }

    /// A new plane drops the window being summed and keeps what was learnt.
    #[test]
    fn a_new_plane_keeps_the_lag() {
        let mut l = learner_after(600.0, 1.0, 3);
        let lag = l.lag_s();
        assert!(lag.is_some());
        l.new_plane();
        assert_eq!(l.lag_s(), lag);
        assert_eq!(l.fit, WindowFit::default());
        assert_eq!((l.pending_len, l.last_velocity), (0, None));
        // Non-finite reports are ignored.
        l.push(f64::NAN, Some((1.0, 2.0)), None);
        l.push(700.0, Some((f64::INFINITY, 0.0)), Some((f64::NAN, 1.0)));
        assert_eq!(l.lag_s(), lag);
    }
}
