//! Each aircraft's recent trail: the estimated positions of the last `history.window_minutes`,
//! at most `history.max_points` of them, kept beside its published snapshot and served by
//! `GET /api/v1/tracks/{icao}/history`.
//!
//! Memory per aircraft is the scarce resource at fleet scale (the trail was the largest
//! thing an aircraft held: 16 bytes a point, 8 KiB at 300 points with the ring's doubling),
//! so the trail is stored as integers and predicted. Values are integers: time in
//! milliseconds, and the position in centimetres east, north and up in the trail's plane
//! (the track's plane of its first point, [`LocalFrame`]). The position is converted to
//! latitude, longitude and altitude when the trail is read, not when a point is stored: a
//! geodetic conversion costs about 670 instructions (two arc tangents, a cube root), 4 % of
//! a `kalman-cv` fleet replay's when every point took one, and a trail is read when a client
//! asks for it. The oldest point and its step to the next are kept whole, and so are the
//! newest point and its step; every other point is stored as the error of a prediction from
//! the step before it: the time step as its change from the step before (a delta of deltas,
//! as Gorilla stores timestamps: Pelkonen et al. 2015, "Gorilla: a fast, scalable, in-memory
//! time series database", VLDB 8(12), §4.1.1), and east, north and up as their difference
//! from the previous step scaled to this step's duration (the track's own velocity,
//! dead-reckoned). Each of the four errors is a zigzag LEB128 varint (the encoding of protocol
//! buffers' `sint64`). The prediction is computed from the stored integers the same way
//! when writing and when reading ([`predict`]), so decoding is exact: what is served is what
//! the integers say.
//! An estimated track is smooth, so the errors are small: an airliner's point, a step of
//! 250 m/s that took 3 bytes each for east and north, takes 1 each in straight flight
//! (about 5 bytes a point where plain differences took 8-10). Points come at most every
//! `window / max_points` seconds of feed time (decimation by time). The bytes live in
//! chunks of [`CHUNK`] bytes, appended and dropped whole: a growing ring reallocated at every
//! growth, and since a fleet's trails all grow at once, the blocks each growth freed stayed
//! in the allocator (16-17 bytes of RSS per 10-byte point on the fleet, against 11).

use crate::config::HistoryConfig;
use crate::track::geo::LocalFrame;
use nalgebra::Vector3;
use serde::Serialize;
use std::collections::VecDeque;

/// One point as served: feed time, s; position, degrees; altitude, m.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct TrailPoint {
    pub t: f64,
    pub lat: f64,
    pub lon: f64,
    pub alt_m: f64,
}

/// One point in stored units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Fixed {
    /// Milliseconds after [`Trail::base_t_s`].
    t_ms: i64,
    /// East, north and up in the trail's plane, cm.
    enu_cm: [i64; 3],
}

/// `x.round() as i64` (to the nearest integer, halves away from zero; saturating, NaN to
/// 0), without the call: on the baseline x86-64 target `f64::round` is a library function
/// (about 30 instructions), and a trail point rounds seven values (1.1 % of a `kalman-cv`
/// fleet replay's instructions). x − trunc(x) is exact (the fraction of a float is a
/// float), so comparing it with ±½ decides as `round` does; a |x| past i64's range
/// saturates either way. Without branches: which way a value rounds is a coin toss, and a
/// branch on it would be mispredicted half the time.
#[inline(always)]
fn round_to_i64(x: f64) -> i64 {
    let t = x as i64;
    let frac = x - t as f64;
    t.saturating_add(i64::from(frac >= 0.5) - i64::from(frac <= -0.5))
}

impl Fixed {
    fn of(base_t_s: f64, t_s: f64, enu_m: &Vector3<f64>) -> Self {
        // Float-to-integer casts saturate; every value here is finite and far inside i64.
        Self {
            t_ms: round_to_i64((t_s - base_t_s) * 1e3),
            enu_cm: [
                round_to_i64(enu_m.x * 100.0),
                round_to_i64(enu_m.y * 100.0),
                round_to_i64(enu_m.z * 100.0),
            ],
        }
    }

    /// The difference from `prev`, field by field (wrapping: never reached, never a panic).
    fn minus(&self, prev: &Self) -> Step {
        [
            self.t_ms.wrapping_sub(prev.t_ms),
            self.enu_cm[0].wrapping_sub(prev.enu_cm[0]),
            self.enu_cm[1].wrapping_sub(prev.enu_cm[1]),
            self.enu_cm[2].wrapping_sub(prev.enu_cm[2]),
        ]
    }

    fn plus(&self, d: &Step) -> Self {
        Self {
            t_ms: self.t_ms.wrapping_add(d[0]),
            enu_cm: [
                self.enu_cm[0].wrapping_add(d[1]),
                self.enu_cm[1].wrapping_add(d[2]),
                self.enu_cm[2].wrapping_add(d[3]),
            ],
        }
    }

    /// The position in metres.
    fn enu_m(&self) -> Vector3<f64> {
        Vector3::new(
            self.enu_cm[0] as f64 / 100.0,
            self.enu_cm[1] as f64 / 100.0,
            self.enu_cm[2] as f64 / 100.0,
        )
    }
}

/// The step from one point to the next in stored units (ms, cm, cm, cm).
type Step = [i64; 4];

/// The step after `prev` predicted for a step of `dt_ms` (module doc): the time step
/// `prev`'s own, each value's step `prev`'s scaled by `dt_ms` over `prev`'s duration
/// (rounded to the nearest unit), or `prev`'s as it is when that duration is not positive.
/// Writer and reader compute the same prediction from the same integers with the same
/// operations, so it need not be exact, only deterministic: IEEE 754 arithmetic is (Rust
/// allows no reassociation), and the cast back saturates. (128-bit integer division did the
/// same at 0.3 % of a fleet replay's instructions.)
fn predict(prev: &Step, dt_ms: i64) -> Step {
    if prev[0] <= 0 {
        return *prev;
    }
    let ratio = dt_ms as f64 / prev[0] as f64;
    let scale = |v: i64| round_to_i64(v as f64 * ratio);
    [prev[0], scale(prev[1]), scale(prev[2]), scale(prev[3])]
}

/// The errors of `step` against its prediction from `prev` (what is stored).
fn residual(prev: &Step, step: &Step) -> Step {
    let pred = predict(prev, step[0]);
    [
        step[0].wrapping_sub(pred[0]),
        step[1].wrapping_sub(pred[1]),
        step[2].wrapping_sub(pred[2]),
        step[3].wrapping_sub(pred[3]),
    ]
}

/// The step that [`residual`] turned into `r`: the time step first, then the prediction
/// from it.
fn unresidual(prev: &Step, r: &Step) -> Step {
    let dt_ms = prev[0].wrapping_add(r[0]);
    let pred = predict(prev, dt_ms);
    [
        dt_ms,
        pred[1].wrapping_add(r[1]),
        pred[2].wrapping_add(r[2]),
        pred[3].wrapping_add(r[3]),
    ]
}

/// Resolution of the stored times, s.
const TIME_RESOLUTION_S: f64 = 1e-3;

/// Bytes of one chunk of a trail's storage (an allocator size class of its own).
const CHUNK: usize = 256;

/// Bytes appended at the back and consumed at the front, in chunks of [`CHUNK`]: nothing is
/// ever reallocated, and at most one partly used chunk sits at each end.
#[derive(Debug, Default)]
struct Chunks {
    chunks: VecDeque<Box<[u8; CHUNK]>>,
    /// Bytes of the first chunk already consumed.
    head: usize,
    /// Bytes written in the last chunk.
    tail: usize,
}

impl Chunks {
    /// Inlined: a call per byte was 0.9 % of a `kalman-cv` fleet replay's instructions
    /// (about 6.6 bytes a point there: its estimates move by metres between points).
    #[inline(always)]
    fn push(&mut self, b: u8) {
        if self.chunks.is_empty() || self.tail >= CHUNK {
            self.chunks.push_back(Box::new([0; CHUNK]));
            self.tail = 0;
        }
        if let Some(slot) = self.chunks.back_mut().and_then(|c| c.get_mut(self.tail)) {
            *slot = b;
        }
        self.tail += 1;
    }

    /// Bytes held.
    fn len(&self) -> usize {
        (self.chunks.len() * CHUNK).saturating_sub(self.head + (CHUNK - self.tail))
    }

    /// The bytes held, oldest first.
    fn iter(&self) -> impl Iterator<Item = u8> + '_ {
        let last = self.chunks.len().saturating_sub(1);
        self.chunks.iter().enumerate().flat_map(move |(i, c)| {
            let start = if i == 0 { self.head } else { 0 };
            let end = if i == last { self.tail } else { CHUNK };
            c.get(start..end).unwrap_or(&[]).iter().copied()
        })
    }

    /// Drops the oldest `n` bytes (`n` at most [`Chunks::len`]).
    fn consume(&mut self, n: usize) {
        if n >= self.len() {
            self.clear();
            return;
        }
        self.head += n;
        while self.head >= CHUNK && self.chunks.len() > 1 {
            self.chunks.pop_front();
            self.head -= CHUNK;
        }
    }

    fn clear(&mut self) {
        self.chunks.clear();
        self.head = 0;
        self.tail = 0;
    }

    /// Bytes allocated: the chunks and the list of them.
    fn heap_bytes(&self) -> usize {
        self.chunks.len() * CHUNK + self.chunks.capacity() * std::mem::size_of::<Box<[u8; CHUNK]>>()
    }
}

/// Appends `v` as a zigzag LEB128 varint: 7 bits a byte, low first, the high bit set on
/// every byte but the last; zigzag maps 0, −1, 1, −2, … to 0, 1, 2, 3, … so small
/// differences of either sign take one byte.
fn put_varint(out: &mut Chunks, v: i64) {
    let mut u = ((v << 1) ^ (v >> 63)) as u64;
    while u >= 0x80 {
        out.push((u as u8 & 0x7f) | 0x80);
        u >>= 7;
    }
    out.push(u as u8);
}

/// Reads one varint of [`put_varint`] from `bytes`; `None` when they end first (a trail
/// only ever reads what it wrote, so that is never reached).
fn take_varint(bytes: &mut impl Iterator<Item = u8>) -> Option<i64> {
    let mut u = 0u64;
    for shift in (0..64).step_by(7) {
        let b = bytes.next()?;
        u |= u64::from(b & 0x7f) << shift;
        if b & 0x80 == 0 {
            return Some((u >> 1) as i64 ^ -((u & 1) as i64));
        }
    }
    None
}

/// Reads one point's four prediction errors.
fn take_record(bytes: &mut impl Iterator<Item = u8>) -> Option<Step> {
    Some([
        take_varint(bytes)?,
        take_varint(bytes)?,
        take_varint(bytes)?,
        take_varint(bytes)?,
    ])
}

/// An aircraft's trail: at most `max_points` points, oldest first (module doc).
#[derive(Debug, Default)]
pub struct Trail {
    /// Feed time the stored times count from, s (the first point's since the trail was
    /// last empty).
    base_t_s: f64,
    /// Points held.
    len: usize,
    /// The oldest point (meaningful when `len > 0`).
    first: Fixed,
    /// The step from the oldest point to the next (meaningful when `len > 1`).
    first_step: Step,
    /// The newest point (meaningful when `len > 0`).
    last: Fixed,
    /// The step to the newest point from the one before (meaningful when `len > 1`).
    last_step: Step,
    /// The prediction errors of points 3..=len, each from the step before it.
    residuals: Chunks,
    /// The plane the positions are in: the first point's track's plane since the trail was
    /// last empty.
    frame: Option<LocalFrame>,
}

/// `enu_m`, a point of the plane `other`, in the plane `frame` (a rotation and a
/// translation, [`LocalFrame::from_frame`]). Out of line: a track's points are in its
/// trail's plane but for the few after a reset, and inlined this conversion cost the common
/// path its inlining of the byte writes.
#[inline(never)]
fn in_plane(frame: &LocalFrame, other: &LocalFrame, enu_m: &Vector3<f64>) -> Vector3<f64> {
    frame.from_frame(other, enu_m)
}

impl Trail {
    /// Adds the estimate at feed time `t_s`, the point `enu_m` of the track's plane `frame`,
    /// if it is at least `min_interval_s` after the newest point (else nothing), and drops
    /// what falls out of the window or past `max_points`. A time before the newest point (a
    /// replay looped onto the same aircraft) starts the trail afresh. Non-finite values are
    /// never stored. The point is stored as it is while the trail is in that plane (a
    /// track's points are, until the track is reset in a new one), else moved into the
    /// trail's plane ([`LocalFrame::from_frame`]).
    pub fn push_enu(
        &mut self,
        cfg: &HistoryConfig,
        t_s: f64,
        frame: &LocalFrame,
        enu_m: &Vector3<f64>,
    ) {
        if !enu_m.iter().all(|v| v.is_finite()) {
            return;
        }
        if cfg.max_points == 0 || !t_s.is_finite() {
            return;
        }
        if let Some(last_t) = self.last_t_s() {
            // (Stored times are rounded to the millisecond: the same estimate published
            // again, at the same time, is no step back.)
            if t_s < last_t - TIME_RESOLUTION_S {
                self.clear();
            } else if t_s - last_t < cfg.min_interval_s() {
                return;
            }
        }
        let cutoff = t_s - cfg.window_s();
        while self.len > 0 && self.time_of(&self.first) < cutoff {
            self.pop_front();
        }
        while self.len >= cfg.max_points {
            self.pop_front();
        }
        if self.len == 0 {
            self.frame = Some(*frame);
        }
        let Some(own) = self.frame.as_ref() else {
            return;
        };
        // A plane is its origin's (`LocalFrame::new` is its only constructor).
        let enu_m = if frame.origin() == own.origin() {
            *enu_m
        } else {
            in_plane(own, frame, enu_m)
        };
        if !enu_m.iter().all(|v| v.is_finite()) {
            return;
        }
        if self.len == 0 {
            self.base_t_s = t_s;
            self.first = Fixed::of(t_s, t_s, &enu_m);
            self.last = self.first;
            self.len = 1;
            return;
        }
        let point = Fixed::of(self.base_t_s, t_s, &enu_m);
        let step = point.minus(&self.last);
        if self.len == 1 {
            self.first_step = step;
        } else {
            for r in residual(&self.last_step, &step) {
                put_varint(&mut self.residuals, r);
            }
        }
        self.last = point;
        self.last_step = step;
        self.len += 1;
    }

    /// Feed time of the newest point, s.
    pub fn last_t_s(&self) -> Option<f64> {
        (self.len > 0).then(|| self.time_of(&self.last))
    }

    /// True when a point at `t_s` would be stored (so the caller need not compute it).
    pub fn wants(&self, cfg: &HistoryConfig, t_s: f64) -> bool {
        cfg.max_points > 0
            && self.last_t_s().is_none_or(|last| {
                t_s < last - TIME_RESOLUTION_S || t_s - last >= cfg.min_interval_s()
            })
    }

    /// The points, oldest first.
    pub fn points(&self) -> Vec<TrailPoint> {
        let mut out = Vec::with_capacity(self.len);
        let (Some(frame), true) = (&self.frame, self.len > 0) else {
            return out;
        };
        let mut p = self.first;
        out.push(self.served(frame, &p));
        if self.len == 1 {
            return out;
        }
        let mut step = self.first_step;
        p = p.plus(&step);
        out.push(self.served(frame, &p));
        let mut bytes = self.residuals.iter();
        while let Some(r) = take_record(&mut bytes) {
            step = unresidual(&step, &r);
            p = p.plus(&step);
            out.push(self.served(frame, &p));
        }
        out
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes held by the trail's storage beyond its own struct.
    pub fn heap_bytes(&self) -> usize {
        self.residuals.heap_bytes()
    }

    fn time_of(&self, p: &Fixed) -> f64 {
        self.base_t_s + p.t_ms as f64 / 1e3
    }

    /// A point as served: its position converted to latitude, longitude and altitude here,
    /// when read (module doc).
    fn served(&self, frame: &LocalFrame, p: &Fixed) -> TrailPoint {
        let (lat, lon, alt_m) = frame.to_geodetic(&p.enu_m());
        TrailPoint {
            t: self.time_of(p),
            lat,
            lon,
            alt_m,
        }
    }

    /// Drops the oldest point: the next one is the oldest plus the first step, and the step
    /// after it the first record's.
    fn pop_front(&mut self) {
        if self.len <= 1 {
            self.clear();
            return;
        }
        if self.len == 2 {
            self.first = self.last;
            self.len = 1;
            return;
        }
        let mut read = 0usize;
        let record = {
            let mut bytes = self.residuals.iter().inspect(|_| read += 1);
            take_record(&mut bytes)
        };
        match record {
            Some(r) => {
                self.first = self.first.plus(&self.first_step);
                self.first_step = unresidual(&self.first_step, &r);
                self.residuals.consume(read);
                self.len -= 1;
            }
            None => self.clear(),
        }
    }

    /// Forgets every point (and frees their chunks).
    fn clear(&mut self) {
        self.len = 0;
        self.residuals.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    /// A geodetic point pushed as a track in its own plane at that point would give it:
    /// the trail's plane is then the first point's, and every later point is moved in.
    impl Trail {
        fn push(&mut self, cfg: &HistoryConfig, t_s: f64, lat: f64, lon: f64, alt_m: f64) {
            let (frame, enu_m) = own_plane(lat, lon, alt_m);
            self.push_enu(cfg, t_s, &frame, &enu_m);
        }
    }

    /// The plane at a point's latitude and longitude, and the point in it.
    fn own_plane(lat: f64, lon: f64, alt_m: f64) -> (LocalFrame, Vector3<f64>) {
        let frame = LocalFrame::new(lat, lon, 0.0);
        (frame, frame.to_enu(lat, lon, alt_m))
    }

    fn cfg(window_minutes: f64, max_points: usize) -> HistoryConfig {
        HistoryConfig {
            window_minutes,
            max_points,
        }
    }

    #[test]
    fn a_steady_airliner_point_takes_four_bytes() {
        // 250 m/s on a diagonal, climbing 10 m/s, a point a second for 10 minutes: every
        // step is predicted exactly, one byte per value (plain differences took 10: 2 for
        // the 1000 ms, 3 + 3, 2 for the 1000 cm).
        let c = cfg(10.0, 600);
        let mut trail = Trail::default();
        for i in 0..600 {
            let s = f64::from(i);
            trail.push(
                &c,
                1.7e9 + s,
                51.0 + s * 1.6e-3,
                -0.5 + s * 2.5e-3,
                300.0 + 10.0 * s,
            );
        }
        assert_eq!(trail.len(), 600);
        assert_eq!(trail.residuals.len(), 598 * 4);
        let per_point = trail.heap_bytes() as f64 / 599.0;
        assert!(per_point <= 4.5, "{per_point}");
    }

    /// An airliner's published estimates as a trail samples them: updates every 0.2-0.3 s
    /// (its position and velocity reports), a point at the first update at least 1 s after
    /// the last; 250 m/s, level for 2 minutes, then a 1.5°/s turn while climbing at 12 m/s
    /// and accelerating at 0.5 m/s², then level again.
    fn manoeuvring_airliner(trail: &mut Trail, c: &HistoryConfig) {
        let mut rng = StdRng::seed_from_u64(5);
        let (mut t, mut lat, mut lon, mut alt) = (1.7e9, 51.47, -0.45, 3000.0);
        let (mut heading, mut speed) = (0.3f64, 250.0);
        while t < 1.7e9 + 600.0 {
            let dt = rng.gen_range(0.2..0.3);
            let manoeuvring = (120.0..300.0).contains(&(t - 1.7e9));
            if manoeuvring {
                heading += 1.5f64.to_radians() * dt;
                speed += 0.5 * dt;
                alt += 12.0 * dt;
            }
            lat += speed * heading.cos() * dt / 111_195.0;
            lon += speed * heading.sin() * dt / (111_195.0 * lat.to_radians().cos());
            t += dt;
            trail.push(c, t, lat, lon, alt);
        }
    }

    #[test]
    fn a_manoeuvring_airliner_point_takes_under_six_bytes() {
        // Irregular steps (1.0-1.3 s) and a turn, climb and acceleration: the time step's
        // change and the turn's curvature cost a second byte now and then. Measured: 5.2
        // bytes a point, where the plain differences of the same points take 9.2.
        let c = cfg(10.0, 600);
        let mut trail = Trail::default();
        manoeuvring_airliner(&mut trail, &c);
        assert!(trail.len() > 450, "{}", trail.len());
        let per_point = trail.residuals.len() as f64 / (trail.len() - 2) as f64;
        let points = trail.points();
        let mut plain = Chunks::default();
        for w in points.windows(2) {
            let frame = trail.frame.unwrap();
            let fixed = |p: &TrailPoint| {
                Fixed::of(trail.base_t_s, p.t, &frame.to_enu(p.lat, p.lon, p.alt_m))
            };
            for d in fixed(&w[1]).minus(&fixed(&w[0])) {
                put_varint(&mut plain, d);
            }
        }
        let plain_per_point = plain.len() as f64 / (points.len() - 1) as f64;
        assert!(per_point <= 5.5, "{per_point}");
        assert!(plain_per_point >= 9.0, "{plain_per_point}");
    }

    /// The same rules over whole points in stored units: what the encoding must give back.
    #[derive(Default)]
    struct Reference {
        base_t_s: f64,
        points: VecDeque<Fixed>,
        frame: Option<LocalFrame>,
    }

    impl Reference {
        fn push(&mut self, cfg: &HistoryConfig, t_s: f64, lat: f64, lon: f64, alt_m: f64) {
            let time_of = |base: f64, p: &Fixed| base + p.t_ms as f64 / 1e3;
            if let Some(last) = self.points.back().map(|p| time_of(self.base_t_s, p)) {
                if t_s < last - TIME_RESOLUTION_S {
                    self.points.clear();
                } else if t_s - last < cfg.min_interval_s() {
                    return;
                }
            }
            let cutoff = t_s - cfg.window_s();
            while self
                .points
                .front()
                .is_some_and(|p| time_of(self.base_t_s, p) < cutoff)
            {
                self.points.pop_front();
            }
            while self.points.len() >= cfg.max_points {
                self.points.pop_front();
            }
            let (point_frame, point_enu) = own_plane(lat, lon, alt_m);
            if self.points.is_empty() {
                self.base_t_s = t_s;
                self.frame = Some(point_frame);
            }
            let frame = self.frame.unwrap();
            let enu_m = if frame == point_frame {
                point_enu
            } else {
                frame.from_frame(&point_frame, &point_enu)
            };
            self.points.push_back(Fixed::of(self.base_t_s, t_s, &enu_m));
        }
    }

    /// The rounding every stored value goes through is `f64::round`'s, cast.
    #[test]
    fn round_to_i64_is_round_then_cast() {
        let edges = [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            -2.5,
            0.49999999999999994,
            -0.49999999999999994,
            4503599627370495.5,
            -4503599627370495.5,
            9007199254740993.0,
            9.3e18,
            -9.3e18,
            9.223372036854775e18,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
            1e-300,
        ];
        for x in edges {
            assert_eq!(round_to_i64(x), x.round() as i64, "{x:e}");
            let (up, down) = (
                f64::from_bits(x.to_bits() + 1),
                f64::from_bits(x.to_bits().wrapping_sub(1)),
            );
            for y in [up, down] {
                assert_eq!(round_to_i64(y), y.round() as i64, "{y:e}");
            }
        }
    }

    proptest::proptest! {
        #[test]
        fn round_to_i64_is_round_then_cast_anywhere(bits in proptest::num::u64::ANY, scale in -3i32..60) {
            // Any float, and floats near halves at every magnitude a trail stores.
            let x = f64::from_bits(bits);
            proptest::prop_assert_eq!(round_to_i64(x), x.round() as i64);
            let near = (bits % 4096) as f64 / 8.0 * 2f64.powi(scale);
            for y in [near, -near, near + 0.5, near - 0.5] {
                proptest::prop_assert_eq!(round_to_i64(y), y.round() as i64);
            }
        }
    }

    proptest::proptest! {
        /// Whatever the steps (gaps, jumps across the globe, time going back, the window
        /// and the count both dropping points), the trail serves exactly the points a
        /// plain list of whole points would hold.
        #[test]
        fn the_encoding_loses_nothing(
            steps in proptest::collection::vec(
                (-5.0..400.0f64, -90.0..90.0f64, -180.0..180.0f64, -500.0..20_000.0f64, 0..8u8),
                1..400,
            ),
            window_minutes in 0.05..20.0f64,
            max_points in 1..80usize,
        ) {
            let c = cfg(window_minutes, max_points);
            let (mut trail, mut reference) = (Trail::default(), Reference::default());
            let (mut t, mut lat, mut lon, mut alt) = (1.7e9, 10.0, 20.0, 1000.0);
            for (dt, la, lo, al, kind) in steps {
                // Mostly small moves, sometimes a jump anywhere.
                if kind == 0 {
                    (lat, lon, alt) = (la, lo, al);
                } else {
                    lat = (lat + la * 1e-4).clamp(-90.0, 90.0);
                    lon = (lon + lo * 1e-4).clamp(-180.0, 180.0);
                    alt += al * 1e-3;
                }
                t += dt;
                trail.push(&c, t, lat, lon, alt);
                reference.push(&c, t, lat, lon, alt);
                let frame = reference.frame.unwrap();
                let want: Vec<TrailPoint> =
                    reference.points.iter().map(|p| trail.served(&frame, p)).collect();
                proptest::prop_assert_eq!(Some(frame), trail.frame);
                proptest::prop_assert_eq!(reference.base_t_s, trail.base_t_s);
                proptest::prop_assert_eq!(trail.points(), want);
                proptest::prop_assert_eq!(trail.len(), reference.points.len());
            }
        }
    }

    #[test]
    fn decimates_bounds_and_keeps_time_order() {
        // 10 min, 600 points: at least 1 s apart. 30 minutes of estimates at 5 Hz.
        let c = cfg(10.0, 600);
        let mut trail = Trail::default();
        let t0 = 1.7e9;
        for i in 0..(30 * 60 * 5) {
            let t = t0 + f64::from(i) * 0.2;
            trail.push(&c, t, 33.9 + 1e-5 * f64::from(i), -118.4, 3000.0);
        }
        let p = trail.points();
        assert!(p.len() <= 600, "{}", p.len());
        assert!(p.len() >= 599, "{}", p.len());
        assert!(p.windows(2).all(|w| w[1].t - w[0].t >= 1.0 - 1e-9));
        let last = t0 + f64::from(30 * 60 * 5 - 1) * 0.2;
        assert!((p[p.len() - 1].t - last).abs() < 1.0, "{:?}", p.last());
        assert!(p[0].t >= last - 600.0 - 1e-6, "{:?}", p[0]);
        // Storage never grew past the bound.
        assert!(trail.heap_bytes() <= 600 * 16, "{}", trail.heap_bytes());
    }

    #[test]
    fn the_window_drops_old_points_before_the_count_does() {
        // 1 min window, 600 points: 0.1 s apart at least, 60 s kept.
        let c = cfg(1.0, 600);
        let mut trail = Trail::default();
        for i in 0..300 {
            trail.push(&c, 100.0 + f64::from(i), 10.0, 20.0, 0.0);
        }
        let p = trail.points();
        assert_eq!(p.len(), 61);
        assert_eq!(p[0].t, 339.0);
        assert_eq!(p[60].t, 399.0);
    }

    #[test]
    fn values_round_trip_to_a_centimetre() {
        let c = cfg(10.0, 600);
        let mut trail = Trail::default();
        trail.push(
            &c,
            1_720_248_199.464_496,
            49.005_832_341,
            2.573_563_363,
            10_668.3,
        );
        trail.push(&c, 1_720_248_201.5, -33.946_1, 179.999_999_9, -12.5);
        trail.push(&c, 1_720_248_203.5, 89.9, -180.0, 15_000.0);
        let p = trail.points();
        // Half a centimetre per axis is under 5e-8° of latitude and, at these latitudes,
        // of longitude; the second and third points are half a world from the trail's plane.
        let lon_near = |a: f64, b: f64| ((a - b + 540.0).rem_euclid(360.0) - 180.0).abs();
        assert!((p[0].t - 1_720_248_199.464_496).abs() < 1e-3);
        assert!((p[0].lat - 49.005_832_341).abs() < 1e-7);
        assert!(lon_near(p[0].lon, 2.573_563_363) < 1e-7);
        assert!((p[0].alt_m - 10_668.3).abs() < 1e-2);
        assert!((p[1].lat - -33.946_1).abs() < 1e-7);
        assert!(lon_near(p[1].lon, 179.999_999_9) < 1e-7);
        assert!((p[1].alt_m - -12.5).abs() < 1e-2);
        assert!((p[2].lat - 89.9).abs() < 1e-7);
        assert!(lon_near(p[2].lon, -180.0) < 1e-4, "{}", p[2].lon);
        assert!((p[2].alt_m - 15_000.0).abs() < 1e-2);
    }

    /// A track's points are stored in its plane as they are, and converted when read; a
    /// point of another plane (the track was reset in a new one) is moved into the trail's
    /// without a step in what is served.
    #[test]
    fn points_of_a_plane_are_served_where_they_are() {
        let c = cfg(10.0, 600);
        let a = LocalFrame::new(51.47, -0.45, 0.0);
        let b = LocalFrame::new(52.0, 0.3, 0.0);
        let mut trail = Trail::default();
        let mut expected = Vec::new();
        for i in 0..120 {
            let s = f64::from(i);
            let enu_a = Vector3::new(200.0 * s, 150.0 * s, 3000.0 + 5.0 * s);
            let t_s = 1.7e9 + s;
            if i < 60 {
                trail.push_enu(&c, t_s, &a, &enu_a);
            } else {
                // The same point, given in the other plane.
                let enu_b = b.from_frame(&a, &enu_a);
                assert!((enu_b - enu_a).norm() > 10_000.0);
                trail.push_enu(&c, t_s, &b, &enu_b);
            }
            expected.push(a.to_geodetic(&enu_a));
        }
        assert_eq!(trail.frame, Some(a));
        let p = trail.points();
        assert_eq!(p.len(), 120);
        for (got, (lat, lon, alt_m)) in p.iter().zip(expected) {
            assert!(
                (got.lat - lat).abs() < 1e-7 && (got.lon - lon).abs() < 1e-7,
                "{got:?}"
            );
            assert!((got.alt_m - alt_m).abs() < 1e-2, "{got:?}");
        }
        // Straight and level in the plane: a byte a value.
        assert!(
            trail.residuals.len() <= 118 * 4 + 8,
            "{}",
            trail.residuals.len()
        );
        // A non-finite point is not stored.
        trail.push_enu(&c, 1.7e9 + 200.0, &a, &Vector3::new(f64::NAN, 0.0, 0.0));
        assert_eq!(trail.len(), 120);
    }

    #[test]
    fn non_finite_and_disabled_are_not_stored() {
        let mut trail = Trail::default();
        trail.push(&cfg(10.0, 600), 1.0, f64::NAN, 0.0, 0.0);
        trail.push(&cfg(10.0, 0), 2.0, 1.0, 0.0, 0.0);
        assert!(trail.is_empty());
        assert!(!trail.wants(&cfg(10.0, 0), 5.0));
    }

    #[test]
    fn time_going_back_starts_afresh_and_a_long_life_keeps_its_times() {
        let c = cfg(1440.0, 10);
        let mut trail = Trail::default();
        trail.push(&c, 1000.0, 1.0, 1.0, 1.0);
        trail.push(&c, 10_000.0, 1.0, 1.0, 1.0);
        // The newest point's time again (rounded in storage) is no step back.
        trail.push(&c, 10_000.000_4, 3.0, 3.0, 3.0);
        assert_eq!(trail.points().len(), 2);
        trail.push(&c, 10.0, 2.0, 2.0, 2.0);
        assert_eq!(trail.points().len(), 1);
        // 50 days of points 144 min apart: offsets past u32 milliseconds.
        let mut trail = Trail::default();
        for i in 0..500 {
            trail.push(&c, f64::from(i) * 8640.0, 1.0, 1.0, 1.0);
        }
        let p = trail.points();
        assert_eq!(p.len(), 10);
        assert_eq!(p[9].t, 499.0 * 8640.0);
        assert!(p.windows(2).all(|w| w[1].t > w[0].t));
    }
}
