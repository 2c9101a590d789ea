//! The receiver model: what a ground station would record from the simulated aircraft.
//!
//! Each aircraft transmits, as a DO-260B transponder does (§2.2.3.3.1): airborne positions
//! alternating even and odd, and airborne velocities, each every `report_period_s` (0.5 s by
//! default: 2 per second); its identification every [`IDENT_PERIOD_S`] and its operational
//! status every [`STATUS_PERIOD_S`]. Every interval gets a uniform jitter of +-`jitter_s`
//! (0.1 s gives the standard's 0.4-0.6 s) and every stream starts at a random phase. The
//! receiver hears each frame with `reception_probability`; some heard frames get 1-3 bit
//! errors (`corrupt_frame_rate`, CRC left wrong) and runs of junk precede some frames
//! (`junk_rate`).
//!
//! Measurement errors: the horizontal position is the truth plus white Gaussian noise of
//! σ = EPU/2.4477 per axis, EPU being the NACp's 95 % bound (for a circular 2-D Gaussian the
//! 95 % radius is σ sqrt(-2 ln 0.05) = 2.4477 σ), then CPR-quantised (~5 m); the velocity is
//! the truth plus noise of σ = bound/2.4477 per horizontal axis and σ = bound/1.96 vertically
//! from the NACv's 95 % bounds, then quantised to 1 kt and 64 fpm; the altitude is the truth
//! quantised to 25 ft (no barometric error). Times are the emission times on the 12 MHz Beast
//! clock (no propagation delay: 0.3 ms at 100 km).
//!
//! What real traffic adds, each off by default (scenario keys, [`super::scenario::Settings`]):
//! white noise below the declared bound (`position_noise_sigma_m`,
//! `velocity_noise_sigma_mps`: a NACp is a 95 % bound, not a noise level); a correlated GNSS
//! error added to every position, per horizontal axis a first-order Gauss–Markov process of
//! stationary σ `gnss_bias_sigma_m` and time constant `gnss_bias_tau_s`, stepped exactly
//! between position reports (b ← e^(−Δ/τ) b + σ √(1 − e^(−2Δ/τ)) w, started from its
//! stationary law); a barometric altitude error, the same kind of process on the reported
//! altitude before its 25-ft rounding (`baro_alt_error_sigma_m`, `baro_alt_error_tau_s`:
//! an autopilot holds its altitude to a few feet, and at a step's edge the report
//! flickers); undeclared accuracy (`declare_accuracy = false`: no operational
//! status, NACv 0); a position valid `position_validity_offset_s` before the frame that
//! carries it, and a velocity valid `velocity_validity_offset_s` before its frame (real
//! velocity reports are about a second older than their positions: `eval::latency`); and a
//! position valid at a random time about that, τ ~ N(0, `position_validity_jitter_s`²) per
//! report, drawn on its own stream (a transponder whose latency varies, or a receiver that
//! stamps frames by the block of samples they came in: AFR34ZG's positions read as 40 ms
//! of such noise along the track, `docs/evaluation.md`, "Timing noise along the track"). With
//! every key at its default the random streams are the ones the simulator
//! always drew, so existing scenarios give byte-identical files.
//!
//! Outputs, all time-ordered and byte-identical for the same seed: `PREFIX.beast`,
//! `PREFIX.avr` and `PREFIX.truth.csv`.

use super::encode::{self, VelocityReport, CATEGORY_LARGE, MPS_PER_FPM, MPS_PER_KT, M_PER_FT};
use super::scenario::{AircraftPlan, Scenario};
use super::truth::{Flight, TruthState, TRUTH_HEADER};
use super::wgs84;
use super::{SimError, SimSummary};
use crate::decode::{Callsign, Icao, VerticalRateSource};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// Beast timestamps count a 12 MHz clock (the readsb/dump1090 "MLAT" counter).
pub const TICKS_PER_S: f64 = 12.0e6;
/// Identification every 5 s (DO-260B §2.2.3.3.1.4: 4.8-5.2 s).
pub const IDENT_PERIOD_S: f64 = 5.0;
/// Operational status every 2.5 s (DO-260B §2.2.3.3.1.6: 2.4-2.6 s while airborne and
/// nothing changes).
pub const STATUS_PERIOD_S: f64 = 2.5;
/// 95 % radius of a circular 2-D Gaussian in units of its per-axis σ: sqrt(-2 ln 0.05).
pub const R95_2D_PER_SIGMA: f64 = 2.447_746_830_680_816;
/// 95 % two-sided bound of a 1-D Gaussian in units of σ.
pub const R95_1D_PER_SIGMA: f64 = 1.959_963_984_540_054;
/// Range at which the signal byte saturates (amplitude falls as 1/range beyond it), metres.
const FULL_SIGNAL_RANGE_M: f64 = 5_000.0;
/// Beast escape byte (and frame start).
const ESC: u8 = 0x1a;
/// Longest junk run, bytes.
const MAX_JUNK: usize = 16;

/// Horizontal 95 % position bound (EPU) of a NACp, metres (DO-260B §2.2.3.2.7.2.11,
/// Table 2-71: NACp 1 < 10 NM ... 11 < 3 m). `None` for 0 (unknown) and values above 11.
pub fn nac_p_epu_m(nac_p: u8) -> Option<f64> {
    Some(match nac_p {
        1 => 18_520.0,
        2 => 7_408.0,
        3 => 3_704.0,
        4 => 1_852.0,
        5 => 926.0,
        6 => 555.6,
        7 => 185.2,
        8 => 92.6,
        9 => 30.0,
        10 => 10.0,
        11 => 3.0,
        _ => return None,
    })
}

/// 95 % bounds of a NACv, (horizontal m/s, vertical m/s) (DO-260B §2.2.3.2.6.1.5, Table
/// 2-22: NACv 1 < 10 m/s and < 50 ft/s ... 4 < 0.3 m/s and < 1.5 ft/s). `None` for 0
/// (unknown) and values above 4.
pub fn nac_v_bounds_mps(nac_v: u8) -> Option<(f64, f64)> {
    Some(match nac_v {
        1 => (10.0, 50.0 * M_PER_FT),
        2 => (3.0, 15.0 * M_PER_FT),
        3 => (1.0, 5.0 * M_PER_FT),
        4 => (0.3, 1.5 * M_PER_FT),
        _ => return None,
    })
}

/// The event streams of one aircraft, in the order they are served when they coincide.
const TRUTH: usize = 0;
const POSITION: usize = 1;
const VELOCITY: usize = 2;
const IDENT: usize = 3;
const STATUS: usize = 4;
const STREAMS: usize = 5;
/// A stream that will never fire again.
const NEVER: u64 = u64::MAX;

/// Everything the emitters share: derived from the scenario once.
struct Config {
    end_tick: u64,
    periods_s: [f64; STREAMS],
    jitter_s: f64,
    pos_sigma_m: f64,
    vel_sigma_mps: f64,
    vz_sigma_mps: f64,
    reception_probability: f64,
    corrupt_frame_rate: f64,
    nac_p: u8,
    nac_v: u8,
    velocity_reports: bool,
    declare_accuracy: bool,
    bias_sigma_m: f64,
    bias_tau_s: f64,
    baro_sigma_m: f64,
    baro_tau_s: f64,
    position_offset_s: f64,
    velocity_offset_s: f64,
    stale_interval_s: f64,
    stale_reports: u32,
    stale_age_s: f64,
    position_jitter_s: f64,
    ref_lat_rad: f64,
    ref_lon_rad: f64,
    ref_m: f64,
    ref_n_cos: f64,
}

fn to_ticks(t_s: f64) -> u64 {
    let t = (t_s * TICKS_PER_S).round();
    if t.is_finite() && t >= 0.0 {
        t as u64
    } else {
        0
    }
}

/// SplitMix64 finaliser: decorrelates the per-aircraft seeds derived from one seed.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// One aircraft's transmitter: its flight, its own random stream, and when each of its
/// streams fires next.
struct Emitter {
    icao: Icao,
    callsign: Callsign,
    flight: Flight,
    rng: StdRng,
    next: [u64; STREAMS],
    truth_k: u64,
    odd: bool,
    last_truth_tick: Option<u64>,
    /// The flight again, for positions valid at another time than the frame's
    /// (`position_validity_offset_s`): its own cursor, so both are queried forward in time.
    position_flight: Option<Flight>,
    /// The same for velocities valid before their frame (`velocity_validity_offset_s`).
    velocity_flight: Option<Flight>,
    /// The correlated GNSS error (east, north), m, and the time it was last stepped, s.
    bias: Option<(f64, f64, f64)>,
    /// Its own random stream, so the white-noise draws stay those of the other settings.
    bias_rng: StdRng,
    /// The barometric altitude error, m, and the time it was last stepped, s
    /// (`baro_alt_error_sigma_m`), on its own stream for the same reason.
    baro: Option<(f64, f64)>,
    baro_rng: StdRng,
    /// The position reports' random validity times (`position_validity_jitter_s`), on their
    /// own stream for the same reason.
    jitter_rng: StdRng,
    /// Stale-position bursts (`stale_position_interval_s`): the flight queried at the
    /// burst's positions' times (its own cursor), when the next burst starts, s, how many
    /// reports of the current one are left, and their own random stream.
    stale: Option<StaleBursts>,
}

/// The state of an aircraft's stale-position bursts.
struct StaleBursts {
    flight: Flight,
    next_t_s: f64,
    left: u32,
    rng: StdRng,
}

impl StaleBursts {
    /// An exponentially distributed interval of mean `mean_s`.
    fn interval(rng: &mut StdRng, mean_s: f64) -> f64 {
        -mean_s * (1.0 - rng.gen::<f64>()).ln()
    }

    /// The position this report carries, if it is one of a burst's.
    fn reported(&mut self, t_s: f64, cfg: &Config) -> Option<TruthState> {
        if self.left == 0 && t_s >= self.next_t_s {
            self.left = cfg.stale_reports;
            self.next_t_s = t_s + Self::interval(&mut self.rng, cfg.stale_interval_s);
        }
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        let t = (t_s - cfg.position_offset_s - cfg.stale_age_s).max(0.0);
        Some(self.flight.state_at(t))
    }
}

impl Emitter {
    fn new(plan: AircraftPlan, index: usize, seed: u64, cfg: &Config) -> Self {
        let mut rng = StdRng::seed_from_u64(mix(seed ^ mix(index as u64)));
        let mut next = [0u64; STREAMS];
        for (s, slot) in next.iter_mut().enumerate().skip(1) {
            *slot = to_ticks(rng.gen::<f64>() * cfg.periods_s[s]);
        }
        if !cfg.velocity_reports {
            next[VELOCITY] = NEVER;
        }
        if !cfg.declare_accuracy {
            next[STATUS] = NEVER;
        }
        let odd = rng.gen::<bool>();
        let position_flight =
            (cfg.position_offset_s != 0.0).then(|| Flight::new(plan.trajectory.clone()));
        let velocity_flight =
            (cfg.velocity_offset_s != 0.0).then(|| Flight::new(plan.trajectory.clone()));
        let stale = (cfg.stale_interval_s > 0.0).then(|| {
            let mut rng = StdRng::seed_from_u64(mix(seed ^ mix(index as u64) ^ 0x7374_616c));
            StaleBursts {
                next_t_s: StaleBursts::interval(&mut rng, cfg.stale_interval_s),
                flight: Flight::new(plan.trajectory.clone()),
                left: 0,
                rng,
            }
        });
        Self {
            icao: plan.icao,
            callsign: plan.callsign,
            flight: Flight::new(plan.trajectory),
            rng,
            next,
            truth_k: 0,
            odd,
            last_truth_tick: None,
            position_flight,
            velocity_flight,
            bias: None,
            bias_rng: StdRng::seed_from_u64(mix(seed ^ mix(index as u64) ^ 0x6761_7573)),
            baro: None,
            baro_rng: StdRng::seed_from_u64(mix(seed ^ mix(index as u64) ^ 0x6261_726f)),
            jitter_rng: StdRng::seed_from_u64(mix(seed ^ mix(index as u64) ^ 0x6a69_7474)),
            stale,
        }
    }

    /// The earliest pending event (stream, tick); ties go to the lower stream index.
    fn next_event(&self) -> (usize, u64) {
        let mut best = (TRUTH, self.next[TRUTH]);
        for (s, &t) in self.next.iter().enumerate().skip(1) {
            if t < best.1 {
                best = (s, t);
            }
        }
        best
    }

    /// Reschedules stream `s` after an emission at `tick`: one period plus jitter later.
    fn reschedule(&mut self, s: usize, tick: u64, cfg: &Config) {
        let jitter = if cfg.jitter_s > 0.0 {
            (2.0 * self.rng.gen::<f64>() - 1.0) * cfg.jitter_s
        } else {
            0.0
        };
        let step = to_ticks(cfg.periods_s.get(s).copied().unwrap_or(1.0) + jitter).max(1);
        self.next[s] = tick.saturating_add(step);
    }

    /// Serves this aircraft's earliest event.
    fn fire(&mut self, cfg: &Config, out: &mut Outputs) -> Result<(), SimError> {
        let (s, tick) = self.next_event();
        let t_s = tick as f64 / TICKS_PER_S;
        let state = self.flight.state_at(t_s);
        if s == TRUTH {
            out.write_truth(self.icao, &state)?;
            self.last_truth_tick = Some(tick);
            self.truth_k += 1;
            self.next[TRUTH] = to_ticks(self.truth_k as f64 * cfg.periods_s[TRUTH]);
            return Ok(());
        }
        let frame = match s {
            POSITION => {
                let stale = self.stale.as_mut().and_then(|b| b.reported(t_s, cfg));
                let reported = match (stale, self.position_flight.as_mut()) {
                    (Some(s), _) => s,
                    (None, Some(f)) => f.state_at((t_s - cfg.position_offset_s).max(0.0)),
                    (None, None) => state,
                };
                let (be, bn) = self.step_bias(t_s, cfg);
                let (je, jn) = self.validity_jitter(&reported, cfg);
                let baro_m = self.step_baro(t_s, cfg);
                let f = self.position_frame(&reported, (be + je, bn + jn, baro_m), cfg);
                self.odd = !self.odd;
                f
            }
            VELOCITY => {
                let reported = match self.velocity_flight.as_mut() {
                    Some(f) => f.state_at((t_s - cfg.velocity_offset_s).max(0.0)),
                    None => state,
                };
                self.velocity_frame(&reported, cfg)
            }
            IDENT => encode::identification(self.icao, CATEGORY_LARGE, &self.callsign),
            _ => encode::operational_status(self.icao, cfg.nac_p),
        };
        self.reschedule(s, tick, cfg);
        self.deliver(s, tick, frame, &state, cfg, out)
    }

    /// Where a position valid τ away from its time moves it, (east, north) m: −v τ, τ drawn
    /// from N(0, `position_validity_jitter_s`²) per report (module doc); (0, 0) without the
    /// key. Within τ (tens of ms) the aircraft's velocity is constant to a millimetre of
    /// position at 1 m/s², so −v τ is the truth at the other time.
    fn validity_jitter(&mut self, s: &TruthState, cfg: &Config) -> (f64, f64) {
        if cfg.position_jitter_s <= 0.0 {
            return (0.0, 0.0);
        }
        let tau = self.jitter_rng.sample::<f64, _>(StandardNormal) * cfg.position_jitter_s;
        (-s.ve_mps * tau, -s.vn_mps * tau)
    }

    /// The correlated GNSS error (east, north) at `t_s`, m: the Gauss–Markov process stepped
    /// exactly from its last value (module doc); (0, 0) when the scenario has none.
    fn step_bias(&mut self, t_s: f64, cfg: &Config) -> (f64, f64) {
        if cfg.bias_sigma_m <= 0.0 {
            return (0.0, 0.0);
        }
        let (sigma, tau) = (cfg.bias_sigma_m, cfg.bias_tau_s);
        let mut draw = || -> f64 { self.bias_rng.sample::<f64, _>(StandardNormal) };
        let last = self.bias.map(|(e, n, t0)| ((e, n), t_s - t0));
        let e = gauss_markov_step(last.map(|((e, _), dt)| (e, dt)), sigma, tau, draw());
        let n = gauss_markov_step(last.map(|((_, n), dt)| (n, dt)), sigma, tau, draw());
        self.bias = Some((e, n, t_s));
        (e, n)
    }

    /// The barometric altitude error at `t_s`, m: a Gauss–Markov process of σ
    /// `baro_alt_error_sigma_m` and τ `baro_alt_error_tau_s`, stepped exactly from its last
    /// value as the GNSS error is ([`Emitter::step_bias`]); 0 when the scenario has none.
    fn step_baro(&mut self, t_s: f64, cfg: &Config) -> f64 {
        if cfg.baro_sigma_m <= 0.0 {
            return 0.0;
        }
        let w: f64 = self.baro_rng.sample(StandardNormal);
        let last = self.baro.map(|(err, t0)| (err, t_s - t0));
        let err = gauss_markov_step(last, cfg.baro_sigma_m, cfg.baro_tau_s, w);
        self.baro = Some((err, t_s));
        err
    }

    /// A position frame of `s` moved by `(east, north, up)` m of error on top of the white
    /// horizontal noise (the GNSS error and the validity jitter; the barometric error).
    fn position_frame(
        &mut self,
        s: &TruthState,
        (be, bn, bu): (f64, f64, f64),
        cfg: &Config,
    ) -> [u8; 14] {
        let dn: f64 = self.rng.sample::<f64, _>(StandardNormal) * cfg.pos_sigma_m + bn;
        let de: f64 = self.rng.sample::<f64, _>(StandardNormal) * cfg.pos_sigma_m + be;
        let lat = s.lat_deg.to_radians();
        let (m, n) = wgs84::radii_m(lat);
        let lat_deg = (lat + dn / (m + s.alt_m)).to_degrees();
        let lon_deg = (s.lon_deg.to_radians() + de / ((n + s.alt_m) * lat.cos())).to_degrees();
        encode::airborne_position(
            self.icao,
            (s.alt_m + bu) / M_PER_FT,
            lat_deg,
            lon_deg,
            self.odd,
        )
    }

    fn velocity_frame(&mut self, s: &TruthState, cfg: &Config) -> [u8; 14] {
        let mut noise = || -> f64 { self.rng.sample(StandardNormal) };
        let ve = s.ve_mps + noise() * cfg.vel_sigma_mps;
        let vn = s.vn_mps + noise() * cfg.vel_sigma_mps;
        let vu = s.vu_mps + noise() * cfg.vz_sigma_mps;
        encode::airborne_velocity(
            self.icao,
            &VelocityReport {
                ve_kt: ve / MPS_PER_KT,
                vn_kt: vn / MPS_PER_KT,
                vrate_fpm: vu / MPS_PER_FPM,
                vrate_source: VerticalRateSource::Baro,
                nac_v: if cfg.declare_accuracy { cfg.nac_v } else { 0 },
            },
        )
    }

    /// Reception, corruption, output, and the truth row that goes with a state report.
    fn deliver(
        &mut self,
        s: usize,
        tick: u64,
        mut frame: [u8; 14],
        state: &TruthState,
        cfg: &Config,
        out: &mut Outputs,
    ) -> Result<(), SimError> {
        out.summary.frames_emitted += 1;
        if self.rng.gen::<f64>() >= cfg.reception_probability {
            out.summary.frames_lost += 1;
            return Ok(());
        }
        if cfg.corrupt_frame_rate > 0.0 && self.rng.gen::<f64>() < cfg.corrupt_frame_rate {
            corrupt(&mut frame, &mut self.rng);
            out.summary.frames_corrupted += 1;
        }
        match s {
            POSITION => out.summary.position_frames += 1,
            VELOCITY => out.summary.velocity_frames += 1,
            IDENT => out.summary.identification_frames += 1,
            _ => out.summary.status_frames += 1,
        }
        out.write_frame(tick, signal_byte(state, cfg), &frame)?;
        if matches!(s, POSITION | VELOCITY) && self.last_truth_tick != Some(tick) {
            out.write_truth(self.icao, state)?;
            self.last_truth_tick = Some(tick);
        }
        Ok(())
    }
}

/// One exact step of a first-order Gauss–Markov process of stationary σ `sigma` and time
/// constant `tau_s` driven by the standard normal draw `w`: from its stationary law when
/// there is no `last` (value, seconds since), else x ← e^(−Δ/τ) x + σ √(1 − e^(−2Δ/τ)) w.
fn gauss_markov_step(last: Option<(f64, f64)>, sigma: f64, tau_s: f64, w: f64) -> f64 {
    match last {
        None => w * sigma,
        Some((x, dt_s)) => {
            let phi = (-dt_s.max(0.0) / tau_s).exp();
            phi * x + sigma * (1.0 - phi * phi).max(0.0).sqrt() * w
        }
    }
}

/// Flips 1 to 3 distinct bits anywhere in the 112 (parity included).
fn corrupt(frame: &mut [u8; 14], rng: &mut StdRng) {
    let n = rng.gen_range(1..=3usize);
    let mut taken = [usize::MAX; 3];
    for k in 0..n {
        // Draw among the bits not yet taken, then skip over the taken ones in order.
        let mut p = rng.gen_range(0..112 - k);
        let mut sorted = taken;
        sorted.sort_unstable();
        for &t in sorted.iter().filter(|&&t| t != usize::MAX) {
            if p >= t {
                p += 1;
            }
        }
        if let Some(slot) = taken.get_mut(k) {
            *slot = p;
        }
        if let Some(b) = frame.get_mut(p / 8) {
            *b ^= 0x80 >> (p % 8);
        }
    }
}

/// Beast signal byte: amplitude falling as 1/range (readsb reads the byte as an amplitude:
/// RSSI = 20 log10(byte/255) dBFS), full scale within 5 km, never 0.
fn signal_from_range(range_m: f64) -> u8 {
    let range = range_m.max(FULL_SIGNAL_RANGE_M);
    (255.0 * FULL_SIGNAL_RANGE_M / range)
        .round()
        .clamp(1.0, 255.0) as u8
}

/// Signal byte of a frame sent from `s`, by its slant range from the reference.
fn signal_byte(s: &TruthState, cfg: &Config) -> u8 {
    let dn = (s.lat_deg.to_radians() - cfg.ref_lat_rad) * cfg.ref_m;
    let mut dl = s.lon_deg.to_radians() - cfg.ref_lon_rad;
    if dl > std::f64::consts::PI {
        dl -= std::f64::consts::TAU;
    } else if dl < -std::f64::consts::PI {
        dl += std::f64::consts::TAU;
    }
    let de = dl * cfg.ref_n_cos;
    signal_from_range((de * de + dn * dn + s.alt_m * s.alt_m).sqrt())
}

/// One output file and its path (for errors).
struct Sink {
    path: PathBuf,
    w: BufWriter<File>,
}

impl Sink {
    fn create(path: PathBuf) -> Result<Self, SimError> {
        match File::create(&path) {
            Ok(f) => Ok(Self {
                w: BufWriter::with_capacity(1 << 16, f),
                path,
            }),
            Err(source) => Err(SimError::Io {
                path,
                error: source,
            }),
        }
    }

    fn err(&self, source: io::Error) -> SimError {
        SimError::Io {
            path: self.path.clone(),
            error: source,
        }
    }

    fn write_all(&mut self, bytes: &[u8]) -> Result<(), SimError> {
        self.w.write_all(bytes).map_err(|e| self.err(e))
    }

    fn flush(&mut self) -> Result<(), SimError> {
        self.w.flush().map_err(|e| self.err(e))
    }
}

/// The three output files, the junk generator and the counters.
struct Outputs {
    beast: Sink,
    avr: Sink,
    truth: Sink,
    junk_rng: StdRng,
    junk_rate: f64,
    summary: SimSummary,
}

const HEX: &[u8; 16] = b"0123456789ABCDEF";

impl Outputs {
    /// Writes one truth row.
    fn write_truth(&mut self, icao: Icao, state: &TruthState) -> Result<(), SimError> {
        let r = state.write_csv_row(&mut self.truth.w, icao);
        r.map_err(|e| self.truth.err(e))?;
        self.summary.truth_rows += 1;
        Ok(())
    }

    /// Writes one frame to both feeds (with a junk run before it now and then).
    fn write_frame(&mut self, tick: u64, signal: u8, frame: &[u8; 14]) -> Result<(), SimError> {
        if self.junk_rate > 0.0 && self.junk_rng.gen::<f64>() < self.junk_rate {
            self.write_junk()?;
        }
        // Beast: 0x1a '3' (long Mode S), then the 6-byte counter, the signal byte and the 14
        // data bytes, each 0x1a among them doubled.
        let mut buf = [0u8; 2 + 2 * 21];
        buf[0] = ESC;
        buf[1] = b'3';
        let mut len = 2;
        let counter = tick.to_be_bytes();
        for &b in counter[2..]
            .iter()
            .chain(std::iter::once(&signal))
            .chain(frame.iter())
        {
            for _ in 0..if b == ESC { 2 } else { 1 } {
                if let Some(slot) = buf.get_mut(len) {
                    *slot = b;
                    len += 1;
                }
            }
        }
        self.beast.write_all(buf.get(..len).unwrap_or(&buf))?;
        // AVR with timestamp: '@', 12 hex digits of the counter, 28 of the frame, ';'.
        let mut line = [0u8; 1 + 12 + 28 + 2];
        line[0] = b'@';
        for (k, &b) in counter[2..].iter().chain(frame.iter()).enumerate() {
            line[1 + 2 * k] = HEX[usize::from(b >> 4)];
            line[2 + 2 * k] = HEX[usize::from(b & 15)];
        }
        line[41] = b';';
        line[42] = b'\n';
        self.avr.write_all(&line)
    }

    /// 1 to 16 random bytes, none of them 0x1a (so that a Beast parser resynchronises
    /// after exactly these bytes and counts them all), and a text line of 1 to 16 letters g-z
    /// (never hex, so an AVR parser rejects the whole line).
    fn write_junk(&mut self) -> Result<(), SimError> {
        let n = self.junk_rng.gen_range(1..=MAX_JUNK);
        let mut bytes = [0u8; MAX_JUNK];
        let mut text = [b'\n'; MAX_JUNK + 1];
        for k in 0..n {
            let b: u8 = self.junk_rng.gen_range(0..=254);
            bytes[k] = if b >= ESC { b + 1 } else { b };
            text[k] = b'g' + self.junk_rng.gen_range(0..20u8);
        }
        self.beast.write_all(&bytes[..n])?;
        self.avr.write_all(&text[..=n])?;
        self.summary.junk_runs += 1;
        self.summary.junk_bytes += n as u64;
        Ok(())
    }
}

/// `PREFIX` + `ext`, e.g. `out/run1` + `.beast`.
fn with_ext(prefix: &Path, ext: &str) -> PathBuf {
    let mut s = prefix.as_os_str().to_owned();
    s.push(ext);
    PathBuf::from(s)
}

/// Runs the scenario with `seed` and writes `PREFIX.beast`, `PREFIX.avr`, `PREFIX.truth.csv`.
pub fn run(scenario: &Scenario, seed: u64, out_prefix: &Path) -> Result<SimSummary, SimError> {
    let plans = scenario.plan()?;
    let st = &scenario.settings;
    let pos_epu = nac_p_epu_m(st.nac_p).unwrap_or(f64::NAN);
    let (vel_bound, vz_bound) = nac_v_bounds_mps(st.nac_v).unwrap_or((f64::NAN, f64::NAN));
    let ref_lat = scenario.reference.lat_deg.to_radians();
    let (ref_m, ref_n) = wgs84::radii_m(ref_lat);
    let mut periods_s = [0.0; STREAMS];
    periods_s[TRUTH] = st.truth_period_s;
    periods_s[POSITION] = st.report_period_s;
    periods_s[VELOCITY] = st.report_period_s;
    periods_s[IDENT] = IDENT_PERIOD_S;
    periods_s[STATUS] = STATUS_PERIOD_S;
    let cfg = Config {
        end_tick: to_ticks(st.duration_s),
        periods_s,
        jitter_s: st.jitter_s,
        pos_sigma_m: st
            .position_noise_sigma_m
            .unwrap_or(pos_epu / R95_2D_PER_SIGMA),
        vel_sigma_mps: st
            .velocity_noise_sigma_mps
            .unwrap_or(vel_bound / R95_2D_PER_SIGMA),
        vz_sigma_mps: vz_bound / R95_1D_PER_SIGMA,
        reception_probability: st.reception_probability,
        corrupt_frame_rate: st.corrupt_frame_rate,
        nac_p: st.nac_p,
        nac_v: st.nac_v,
        velocity_reports: st.velocity_reports,
        declare_accuracy: st.declare_accuracy,
        bias_sigma_m: st.gnss_bias_sigma_m,
        bias_tau_s: st.gnss_bias_tau_s,
        baro_sigma_m: st.baro_alt_error_sigma_m,
        baro_tau_s: st.baro_alt_error_tau_s,
        position_offset_s: st.position_validity_offset_s,
        velocity_offset_s: st.velocity_validity_offset_s,
        stale_interval_s: st.stale_position_interval_s,
        stale_reports: st.stale_position_reports,
        stale_age_s: st.stale_position_age_s,
        position_jitter_s: st.position_validity_jitter_s,
        ref_lat_rad: ref_lat,
        ref_lon_rad: scenario.reference.lon_deg.to_radians(),
        ref_m,
        ref_n_cos: ref_n * ref_lat.cos(),
    };
    let mut out = Outputs {
        beast: Sink::create(with_ext(out_prefix, ".beast"))?,
        avr: Sink::create(with_ext(out_prefix, ".avr"))?,
        truth: Sink::create(with_ext(out_prefix, ".truth.csv"))?,
        junk_rng: StdRng::seed_from_u64(mix(seed ^ 0x6A75_6E6B)),
        junk_rate: st.junk_rate,
        summary: SimSummary {
            aircraft: plans.len(),
            duration_s: st.duration_s,
            seed,
            beast_path: with_ext(out_prefix, ".beast"),
            avr_path: with_ext(out_prefix, ".avr"),
            truth_path: with_ext(out_prefix, ".truth.csv"),
            ..SimSummary::default()
        },
    };
    out.truth.write_all(TRUTH_HEADER.as_bytes())?;
    out.truth.write_all(b"\n")?;
    let mut emitters: Vec<Emitter> = plans
        .into_iter()
        .enumerate()
        .map(|(i, p)| Emitter::new(p, i, seed, &cfg))
        .collect();
    let mut heap: BinaryHeap<Reverse<(u64, usize)>> = emitters
        .iter()
        .enumerate()
        .map(|(i, e)| Reverse((e.next_event().1, i)))
        .collect();
    while let Some(Reverse((tick, i))) = heap.pop() {
        if tick > cfg.end_tick {
            break;
        }
        let Some(e) = emitters.get_mut(i) else {
            continue;
        };
        e.fire(&cfg, &mut out)?;
        let (_, next) = e.next_event();
        if next <= cfg.end_tick {
            heap.push(Reverse((next, i)));
        }
    }
    out.beast.flush()?;
    out.avr.flush()?;
    out.truth.flush()?;
    Ok(out.summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sigma_from_95_percent_bounds() {
        // P(r <= k σ) = 1 - exp(-k²/2) for a circular Gaussian: 0.95 at k = R95_2D_PER_SIGMA.
        let k = R95_2D_PER_SIGMA;
        assert!((1.0 - (-k * k / 2.0).exp() - 0.95).abs() < 1e-12);
        assert_eq!(nac_p_epu_m(8), Some(92.6));
        assert_eq!(nac_p_epu_m(0), None);
        assert_eq!(nac_p_epu_m(12), None);
        assert_eq!(nac_v_bounds_mps(2), Some((3.0, 4.572)));
        assert_eq!(nac_v_bounds_mps(5), None);
    }

    #[test]
    fn signal_falls_as_one_over_range() {
        assert_eq!(signal_from_range(0.0), 255);
        assert_eq!(signal_from_range(5_000.0), 255);
        assert_eq!(signal_from_range(10_000.0), 128); // 127.5 rounds up
        assert_eq!(signal_from_range(50_000.0), 26); // 25.5 rounds up
        assert_eq!(signal_from_range(1e9), 1);
        assert_eq!(signal_from_range(f64::NAN), 255);
    }

    #[test]
    fn corruption_flips_one_to_three_distinct_bits() {
        let mut rng = StdRng::seed_from_u64(3);
        let mut counts = [0usize; 4];
        for _ in 0..3000 {
            let mut f = [0u8; 14];
            corrupt(&mut f, &mut rng);
            let ones: u32 = f.iter().map(|b| b.count_ones()).sum();
            counts[ones as usize] += 1;
        }
        assert_eq!(counts[0], 0);
        // Uniform over 1..=3: each about 1000 (binomial σ ≈ 26).
        for c in &counts[1..] {
            assert!((850..1150).contains(c), "{counts:?}");
        }
    }

    /// A position valid at a random time (`position_validity_jitter_s`): the report moves by
    /// −v τ, along the velocity only, with σ_τ |v| (9.2 m for 40 ms at 230 m/s), white; none
    /// without the key (and no draw from the stream).
    #[test]
    fn validity_jitter_moves_a_position_along_its_velocity() {
        let text = include_str!("../../fixtures/scenarios/airliner-timing.toml");
        let scenario = crate::sim::scenario::Scenario::from_toml_str(text).unwrap();
        let plan = scenario.plan().unwrap().remove(0);
        let mut cfg = test_config();
        let mut e = Emitter::new(plan.clone(), 0, 7, &cfg);
        let mut state = e.flight.state_at(10.0);
        (state.ve_mps, state.vn_mps) = (230.0 * 0.6, 230.0 * 0.8);
        assert_eq!(e.validity_jitter(&state, &cfg), (0.0, 0.0));
        cfg.position_jitter_s = 0.04;
        let mut e = Emitter::new(plan, 0, 7, &cfg);
        let n = 20_000;
        let (mut along2, mut across2, mut lag1, mut prev) = (0.0, 0.0, 0.0, 0.0);
        for _ in 0..n {
            let (de, dn) = e.validity_jitter(&state, &cfg);
            let along = 0.6 * de + 0.8 * dn;
            along2 += along * along;
            across2 += (-0.8 * de + 0.6 * dn).powi(2);
            lag1 += along * prev;
            prev = along;
        }
        let nf = f64::from(n);
        let sigma = (along2 / nf).sqrt();
        assert!((sigma - 9.2).abs() < 0.2, "σ along {sigma}");
        assert!(across2 / nf < 1e-18);
        assert!(
            (lag1 / along2).abs() < 0.03,
            "lag-1 correlation {}",
            lag1 / along2
        );
    }

    /// The correlated GNSS error: its stationary σ and its lag-Δ autocorrelation e^(−Δ/τ),
    /// over 200 simulated aircraft-hours at irregular report times.
    #[test]
    fn gnss_bias_is_gauss_markov_with_its_sigma_and_time_constant() {
        let text = include_str!("../../fixtures/scenarios/airliner-nacp10.toml");
        let scenario = crate::sim::scenario::Scenario::from_toml_str(text).unwrap();
        let plan = scenario.plan().unwrap().remove(0);
        let cfg_sigma = 4.0;
        let tau = 60.0;
        let mut cfg = test_config();
        cfg.bias_sigma_m = cfg_sigma;
        cfg.bias_tau_s = tau;
        let (mut sum2, mut lag, mut n, mut n_lag) = (0.0, 0.0, 0usize, 0usize);
        for a in 0..200 {
            let mut e = Emitter::new(plan.clone(), a, 7, &cfg);
            let mut rng = StdRng::seed_from_u64(a as u64);
            let (mut t, mut grid) = (0.0, 0.0);
            let mut prev: Option<(f64, f64)> = None;
            loop {
                let (be, bn) = e.step_bias(t, &cfg);
                sum2 += be * be + bn * bn;
                n += 2;
                // Every 30 s exactly, the product with the value 30 s before (the process
                // stepped at irregular 0.4-0.6 s in between).
                if t == grid {
                    if let Some((pe, pn)) = prev {
                        lag += pe * be + pn * bn;
                        n_lag += 2;
                    }
                    prev = Some((be, bn));
                    grid += 30.0;
                }
                if t >= 3600.0 {
                    break;
                }
                t = (t + rng.gen_range(0.4..0.6)).min(grid);
            }
        }
        let sigma = (sum2 / n as f64).sqrt();
        let rho = lag / n_lag as f64 / (sigma * sigma);
        assert!((sigma - cfg_sigma).abs() < 0.15, "sigma {sigma}");
        assert!((rho - (-30.0f64 / tau).exp()).abs() < 0.05, "rho {rho}");
    }

    /// The barometric altitude error: its stationary σ and its lag-Δ autocorrelation
    /// e^(−Δ/τ), stepped every 0.5 s over 100 aircraft-hours; none without the key.
    #[test]
    fn baro_error_is_gauss_markov_with_its_sigma_and_time_constant() {
        let text = include_str!("../../fixtures/scenarios/approach.toml");
        let scenario = crate::sim::scenario::Scenario::from_toml_str(text).unwrap();
        let plan = scenario.plan().unwrap().remove(0);
        let mut cfg = test_config();
        let mut quiet = Emitter::new(plan.clone(), 0, 7, &cfg);
        assert_eq!(quiet.step_baro(0.0, &cfg), 0.0);
        assert_eq!(quiet.step_baro(0.5, &cfg), 0.0);
        let (sigma_m, tau_s) = (3.0, 10.0);
        cfg.baro_sigma_m = sigma_m;
        cfg.baro_tau_s = tau_s;
        let (mut sum2, mut lag, mut n) = (0.0, 0.0, 0usize);
        for a in 0..100 {
            let mut e = Emitter::new(plan.clone(), a, 7, &cfg);
            let mut history = Vec::new();
            for k in 0..7200 {
                history.push(e.step_baro(0.5 * k as f64, &cfg));
            }
            sum2 += history.iter().map(|x| x * x).sum::<f64>();
            n += history.len();
            // Lag 10 s: 20 steps.
            lag += history.windows(21).map(|w| w[0] * w[20]).sum::<f64>()
                / (history.len() - 20) as f64;
        }
        let sigma = (sum2 / n as f64).sqrt();
        let rho = lag / 100.0 / (sigma * sigma);
        assert!((sigma - sigma_m).abs() < 0.1, "sigma {sigma}");
        assert!((rho - (-1.0f64).exp()).abs() < 0.05, "rho {rho}");
    }

    #[test]
    fn stale_positions_come_in_bursts_of_their_age() {
        let text = include_str!("../../fixtures/scenarios/airliner-stale.toml");
        let scenario = crate::sim::scenario::Scenario::from_toml_str(text).unwrap();
        let plan = scenario.plan().unwrap().remove(0);
        let mut cfg = test_config();
        assert!(Emitter::new(plan.clone(), 0, 7, &cfg).stale.is_none());
        cfg.stale_interval_s = 48.0;
        cfg.stale_reports = 2;
        cfg.stale_age_s = 0.6;
        cfg.position_offset_s = 0.02;
        let mut e = Emitter::new(plan, 0, 7, &cfg);
        let Some(bursts) = e.stale.as_mut() else {
            panic!("no bursts");
        };
        // Reports every 0.5 s over 20 h of feed (the plan's flight ends after 20 minutes: the
        // truth holds its last state, and the times are what is checked).
        let (mut bursts_seen, mut run, mut runs_ok) = (0_u32, 0_u32, true);
        let hours = 20.0;
        for k in 0..(hours * 7200.0) as u32 {
            let t = f64::from(k) * 0.5;
            match bursts.reported(t, &cfg) {
                Some(state) => {
                    assert!(
                        (state.t_s - (t - 0.62)).abs() < 1e-9,
                        "{} at {t}",
                        state.t_s
                    );
                    run += 1;
                }
                None => {
                    // A burst may start on the report after the last one ended: runs of
                    // two reports, or of twice two.
                    runs_ok &= run % 2 == 0;
                    bursts_seen += run / 2;
                    run = 0;
                }
            }
        }
        assert!(runs_ok, "every burst is two reports");
        let mean = hours * 3600.0 / f64::from(bursts_seen);
        // Exponential intervals of mean 48 s, begun at the next report: about 1,500 bursts,
        // a standard error of 2.6 %.
        assert!(
            (mean - 48.3).abs() < 0.08 * 48.3,
            "mean interval {mean} s over {bursts_seen} bursts"
        );
    }

    fn test_config() -> Config {
        Config {
            end_tick: 0,
            periods_s: [1.0; STREAMS],
            jitter_s: 0.0,
            pos_sigma_m: 0.0,
            vel_sigma_mps: 0.0,
            vz_sigma_mps: 0.0,
            reception_probability: 1.0,
            corrupt_frame_rate: 0.0,
            nac_p: 10,
            nac_v: 2,
            velocity_reports: true,
            declare_accuracy: true,
            bias_sigma_m: 0.0,
            bias_tau_s: 60.0,
            baro_sigma_m: 0.0,
            baro_tau_s: 10.0,
            position_offset_s: 0.0,
            velocity_offset_s: 0.0,
            stale_interval_s: 0.0,
            stale_reports: 2,
            stale_age_s: 0.6,
            position_jitter_s: 0.0,
            ref_lat_rad: 0.0,
            ref_lon_rad: 0.0,
            ref_m: 6.4e6,
            ref_n_cos: 6.4e6,
        }
    }

    /// Undeclared accuracy: no operational status, NACv 0 in every velocity message.
    #[test]
    fn undeclared_accuracy_sends_no_status_and_nacv_0() {
        let dir = std::env::temp_dir().join(format!("adsb-undeclared-{}", std::process::id()));
        let scenario = crate::sim::load_scenario("turns-undeclared").unwrap();
        let summary = run(&scenario, 3, &dir).unwrap();
        assert_eq!(summary.status_frames, 0);
        assert!(
            summary.velocity_frames > 1000,
            "{}",
            summary.velocity_frames
        );
        let beast = std::fs::read(&summary.beast_path).unwrap();
        let frames = crate::eval::consistency::read_frames_at(
            &summary.beast_path,
            Some(crate::feed::Format::Beast),
            1000.0,
        )
        .unwrap();
        assert!(!beast.is_empty());
        let mut velocities = 0;
        for f in &frames {
            let b = f.bytes();
            // DF17, TC 19: NACv is ME bits 11-13, i.e. bits 43-45 of the frame.
            if b.len() == 14 && b[0] >> 3 == 17 && b[4] >> 3 == 19 {
                velocities += 1;
                assert_eq!((b[5] >> 3) & 0b111, 0);
            }
        }
        assert!(velocities > 1000);
        for p in [&summary.beast_path, &summary.avr_path, &summary.truth_path] {
            let _ = std::fs::remove_file(p);
        }
    }
}
