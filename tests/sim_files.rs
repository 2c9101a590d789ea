//! End-to-end checks of `sim::simulate`: the files it writes, read back with parsers and
//! decoders written here (our own feed parsers and decoder are being written elsewhere),
//! against closed forms and the statistics the receiver model promises.

use adsb_tracker::decode::cpr::nl;
use adsb_tracker::decode::crc::syndrome;
use adsb_tracker::sim::{fleet, load_scenario, simulate, FleetSpec, Scenario, SimSummary};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::PathBuf;

const TICKS_PER_S: f64 = 12.0e6;

fn out_prefix(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("sim_files_{name}"))
}

fn run(scenario: &Scenario, seed: u64, name: &str) -> (SimSummary, Vec<u8>, String, String) {
    let prefix = out_prefix(name);
    let summary = simulate(scenario, seed, &prefix).unwrap();
    let beast = std::fs::read(&summary.beast_path).unwrap();
    let avr = std::fs::read_to_string(&summary.avr_path).unwrap();
    let truth = std::fs::read_to_string(&summary.truth_path).unwrap();
    (summary, beast, avr, truth)
}

/// A Beast frame as read back: 12 MHz counter, signal byte, 14 data bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
struct BeastFrame {
    tick: u64,
    signal: u8,
    data: [u8; 14],
}

/// Minimal Beast reader: 0x1a '3', then 21 bytes with 0x1a doubled; anything before a 0x1a
/// is counted as garbage.
fn parse_beast(buf: &[u8]) -> (Vec<BeastFrame>, usize) {
    let (mut frames, mut garbage, mut i) = (Vec::new(), 0usize, 0usize);
    while i < buf.len() {
        if buf[i] != 0x1a {
            garbage += 1;
            i += 1;
            continue;
        }
        assert_eq!(buf.get(i + 1), Some(&b'3'), "frame type at {i}");
        i += 2;
        let mut body = Vec::with_capacity(21);
        while body.len() < 21 {
            let b = buf[i];
            if b == 0x1a {
                assert_eq!(buf[i + 1], 0x1a, "bad escape at {i}");
                i += 1;
            }
            body.push(b);
            i += 1;
        }
        let tick = body[..6].iter().fold(0u64, |a, &b| (a << 8) | u64::from(b));
        frames.push(BeastFrame {
            tick,
            signal: body[6],
            data: body[7..].try_into().unwrap(),
        });
    }
    (frames, garbage)
}

/// AVR lines `@<12 hex><28 hex>;`; other lines are counted.
fn parse_avr(text: &str) -> (Vec<(u64, [u8; 14])>, usize) {
    let (mut frames, mut junk) = (Vec::new(), 0);
    for line in text.lines() {
        let ok = line.len() == 42 && line.starts_with('@') && line.ends_with(';');
        if !ok {
            assert!(line.bytes().all(|b| (b'g'..=b'z').contains(&b)), "{line:?}");
            junk += 1;
            continue;
        }
        let tick = u64::from_str_radix(&line[1..13], 16).unwrap();
        let mut data = [0u8; 14];
        for (k, d) in data.iter_mut().enumerate() {
            *d = u8::from_str_radix(&line[13 + 2 * k..15 + 2 * k], 16).unwrap();
        }
        frames.push((tick, data));
    }
    (frames, junk)
}

#[derive(Clone, Debug)]
struct TruthRow {
    t: f64,
    icao: String,
    lat: f64,
    lon: f64,
    alt_m: f64,
    ve: f64,
    vn: f64,
    vu: f64,
    mode: String,
}

fn parse_truth(text: &str) -> Vec<TruthRow> {
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("t,icao,lat,lon,alt_m,ve,vn,vu,mode"));
    lines
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            assert_eq!(c.len(), 9, "{l}");
            let f = |k: usize| c[k].parse::<f64>().unwrap();
            TruthRow {
                t: f(0),
                icao: c[1].to_owned(),
                lat: f(2),
                lon: f(3),
                alt_m: f(4),
                ve: f(5),
                vn: f(6),
                vu: f(7),
                mode: c[8].to_owned(),
            }
        })
        .collect()
}

fn me(d: &[u8; 14]) -> u64 {
    d[4..11].iter().fold(0, |a, &b| (a << 8) | u64::from(b))
}

fn bits(me: u64, first: u32, len: u32) -> u64 {
    (me >> (56 - (first - 1) - len)) & ((1 << len) - 1)
}

fn icao_of(d: &[u8; 14]) -> String {
    format!("{:02x}{:02x}{:02x}", d[1], d[2], d[3])
}

fn tc(d: &[u8; 14]) -> u64 {
    bits(me(d), 1, 5)
}

/// WGS-84 geodetic -> ECEF, written here for the checks (TR8350.2 eq. 4-14).
fn ecef(lat_deg: f64, lon_deg: f64, h: f64) -> [f64; 3] {
    let a = 6_378_137.0;
    let f = 1.0 / 298.257_223_563;
    let e2 = f * (2.0 - f);
    let (la, lo) = (lat_deg.to_radians(), lon_deg.to_radians());
    let n = a / (1.0 - e2 * la.sin().powi(2)).sqrt();
    [
        (n + h) * la.cos() * lo.cos(),
        (n + h) * la.cos() * lo.sin(),
        (n * (1.0 - e2) + h) * la.sin(),
    ]
}

/// East-north-up of a point in the tangent plane at (lat0, lon0, 0).
fn enu(lat0: f64, lon0: f64, lat: f64, lon: f64, h: f64) -> [f64; 3] {
    let p = ecef(lat, lon, h);
    let o = ecef(lat0, lon0, 0.0);
    let d = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
    let (sl, cl) = lat0.to_radians().sin_cos();
    let (so, co) = lon0.to_radians().sin_cos();
    [
        -so * d[0] + co * d[1],
        -sl * co * d[0] - sl * so * d[1] + cl * d[2],
        cl * co * d[0] + cl * so * d[1] + sl * d[2],
    ]
}

fn modulo(x: f64, y: f64) -> f64 {
    x - y * (x / y).floor()
}

/// DO-260B A.1.7.5 locally unambiguous decoding against a reference position.
fn cpr_local(yz: u32, xz: u32, odd: bool, ref_lat: f64, ref_lon: f64) -> (f64, f64) {
    let i = if odd { 1.0 } else { 0.0 };
    let (yz, xz) = (f64::from(yz) / 131_072.0, f64::from(xz) / 131_072.0);
    let dlat = 360.0 / (60.0 - i);
    let j = (ref_lat / dlat).floor() + (0.5 + modulo(ref_lat, dlat) / dlat - yz).floor();
    let lat = dlat * (j + yz);
    let zones = f64::from(nl(lat)) - i;
    let dlon = if zones > 0.0 { 360.0 / zones } else { 360.0 };
    let m = (ref_lon / dlon).floor() + (0.5 + modulo(ref_lon, dlon) / dlon - xz).floor();
    (lat, dlon * (m + xz))
}

#[test]
fn same_seed_gives_identical_bytes_and_another_seed_does_not() {
    let s = load_scenario("departure").unwrap();
    let (a, beast_a, avr_a, truth_a) = run(&s, 4, "det_a");
    let (b, beast_b, avr_b, truth_b) = run(&s, 4, "det_b");
    assert!(beast_a == beast_b && avr_a == avr_b && truth_a == truth_b);
    assert_eq!(a.frames_emitted, b.frames_emitted);
    let (_, beast_c, avr_c, truth_c) = run(&s, 5, "det_c");
    assert!(beast_a != beast_c && avr_a != avr_c && truth_a != truth_c);
}

#[test]
fn beast_and_avr_carry_the_same_frames_in_time_order() {
    let s = load_scenario("departure").unwrap();
    let (sum, beast, avr, _) = run(&s, 11, "feeds");
    let (bf, garbage) = parse_beast(&beast);
    let (af, junk_lines) = parse_avr(&avr);
    assert_eq!(bf.len() as u64, sum.frames_written());
    assert_eq!(bf.len(), af.len());
    for (b, a) in bf.iter().zip(&af) {
        assert_eq!((b.tick, b.data), *a);
    }
    assert!(bf.windows(2).all(|w| w[0].tick <= w[1].tick), "time order");
    assert!(bf.last().unwrap().tick <= (480.0 * TICKS_PER_S) as u64);
    // Junk: every byte before a frame start is one the simulator put there.
    assert_eq!(garbage as u64, sum.junk_bytes);
    assert_eq!(junk_lines as u64, sum.junk_runs);
    assert!(sum.junk_runs > 0 && sum.frames_corrupted > 0);
    // Corrupted frames are exactly those whose CRC fails: 1-3 bit errors are always caught
    // (the Mode S CRC-24 has minimum distance 6 on 112 bits).
    let bad = bf.iter().filter(|f| syndrome(&f.data) != Some(0)).count();
    assert_eq!(bad as u64, sum.frames_corrupted);
    // Losses: 10 % of emitted frames (binomial, 5 sigma).
    let n = sum.frames_emitted as f64;
    let lost = sum.frames_lost as f64;
    assert!(
        (lost - 0.1 * n).abs() < 5.0 * (0.09 * n).sqrt(),
        "{lost} of {n}"
    );
    assert_eq!(sum.frames_emitted, sum.frames_written() + sum.frames_lost);
    // Corruption: 1 % of heard frames.
    let heard = sum.frames_written() as f64;
    let c = sum.frames_corrupted as f64;
    assert!(
        (c - 0.01 * heard).abs() < 5.0 * (0.0099 * heard).sqrt(),
        "{c} of {heard}"
    );
    // Rates: 2 positions and 2 velocities per second, one identification per 5 s, one
    // status per 2.5 s, before losses.
    let emitted_expected = 480.0 * (2.0 + 2.0 + 0.2 + 0.4);
    assert!(
        (n - emitted_expected).abs() < 0.02 * emitted_expected,
        "{n}"
    );
}

#[test]
fn paper002_follows_the_papers_planar_trajectory_and_reports_regularly() {
    let s = load_scenario("paper002").unwrap();
    let (sum, beast, _, truth) = run(&s, 2, "paper002");
    let rows = parse_truth(&truth);
    assert_eq!(rows.len() as u64, sum.truth_rows);

    // The paper's trajectory in its plane, by closed forms: CV x += v t; CT (ω > 0 left,
    // counter-clockwise) x += (vx sin ωt - vy (1 - cos ωt))/ω, y += (vx (1 - cos ωt) + vy sin ωt)/ω.
    let segments: [(f64, f64); 5] = [
        (200.0, 0.0),
        (200.0, 3.0),
        (200.0, 0.0),
        (100.0, -3.0),
        (300.0, 0.0),
    ];
    let planar = |t: f64| -> [f64; 4] {
        let (mut x, mut y, mut vx, mut vy) = (1000.0, 1000.0, 50.0, 50.0);
        let mut t0 = 0.0;
        for (d, rate_dps) in segments {
            let dt = (t - t0).clamp(0.0, d);
            let w = f64::to_radians(rate_dps);
            if w == 0.0 {
                x += vx * dt;
                y += vy * dt;
            } else {
                let (s, c) = (w * dt).sin_cos();
                x += (vx * s - vy * (1.0 - c)) / w;
                y += (vx * (1.0 - c) + vy * s) / w;
                (vx, vy) = (vx * c - vy * s, vx * s + vy * c);
            }
            t0 += d;
            if t <= t0 {
                break;
            }
        }
        [x, y, vx, vy]
    };
    let mut worst_m: f64 = 0.0;
    let mut grid = 0;
    for r in &rows {
        let [x, y, vx, vy] = planar(r.t);
        let p = enu(0.0, 0.0, r.lat, r.lon, r.alt_m);
        worst_m = worst_m.max((p[0] - x).hypot(p[1] - y));
        assert!(
            (r.ve - vx).abs() < 1e-3 && (r.vn - vy).abs() < 1e-3,
            "{r:?} vs {vx} {vy}"
        );
        assert!((r.alt_m - 1500.0).abs() < 1e-6 && r.vu == 0.0);
        let want = if (200.0..400.0).contains(&r.t) || (600.0..700.0).contains(&r.t) {
            "CT"
        } else {
            "CV"
        };
        if (r.t - 200.0).abs() > 1e-6
            && (r.t - 400.0).abs() > 1e-6
            && (r.t - 600.0).abs() > 1e-6
            && (r.t - 700.0).abs() > 1e-6
        {
            assert_eq!(r.mode, want, "{r:?}");
        }
        if (r.t * 2.0 - (r.t * 2.0).round()).abs() < 1e-9 {
            grid += 1;
        }
    }
    // Horizontal truth within 2 m of the paper's plane over the 30 km the track covers
    // (curvature terms of a tangent plane at the equator; see sim::truth).
    assert!(worst_m < 2.0, "{worst_m} m");
    eprintln!("paper002: truth within {worst_m:.3} m of the paper's plane");
    // Truth every 0.5 s from 0 to 1000 s inclusive (report times that fall on the grid are
    // written once).
    assert!(grid >= 2001, "{grid}");
    let times: HashSet<u64> = rows
        .iter()
        .map(|r| (r.t * TICKS_PER_S).round() as u64)
        .collect();

    // Regular 1 s reports with no losses: positions alternate even/odd and come every 1 s;
    // every position and velocity report has a truth row at its own time.
    let (frames, garbage) = parse_beast(&beast);
    assert_eq!(garbage, 0);
    let pos: Vec<&BeastFrame> = frames.iter().filter(|f| tc(&f.data) == 11).collect();
    let vel: Vec<&BeastFrame> = frames.iter().filter(|f| tc(&f.data) == 19).collect();
    assert!((1000..=1001).contains(&pos.len()) && (1000..=1001).contains(&vel.len()));
    assert!((200..=201).contains(&frames.iter().filter(|f| tc(&f.data) == 4).count()));
    assert!((400..=401).contains(&frames.iter().filter(|f| tc(&f.data) == 31).count()));
    for w in pos.windows(2) {
        assert_eq!(w[1].tick - w[0].tick, 12_000_000);
        assert_ne!(bits(me(&w[0].data), 22, 1), bits(me(&w[1].data), 22, 1));
    }
    for f in pos.iter().chain(&vel) {
        assert!(times.contains(&f.tick), "no truth row at tick {}", f.tick);
        assert_eq!(icao_of(&f.data), "780002");
    }
    // NACp 8 announced in every operational status.
    for f in frames.iter().filter(|f| tc(&f.data) == 31) {
        assert_eq!(bits(me(&f.data), 45, 4), 8);
    }
}

#[test]
fn noise_matches_the_nacp_and_nacv_it_announces() {
    // A long straight flight heard perfectly: errors are noise plus quantisation only.
    let text = r#"
[reference]
lat_deg = 47.0
lon_deg = 8.0
[settings]
duration_s = 1500.0
nac_p = 8
nac_v = 2
reception_probability = 1.0
jitter_s = 0.1
[[aircraft]]
icao = "4b1234"
callsign = "SWR123"
start = { east_m = 0.0, north_m = -100000.0, up_m = 11000.0 }
velocity = { ground_speed_mps = 230.0, track_deg = 20.0 }
segments = [ { mode = "CV", duration_s = 1500.0 } ]
"#;
    let s = Scenario::from_toml_str(text).unwrap();
    let (_, beast, _, truth) = run(&s, 99, "noise");
    let truth_at: HashMap<u64, TruthRow> = parse_truth(&truth)
        .into_iter()
        .map(|r| ((r.t * TICKS_PER_S).round() as u64, r))
        .collect();
    let (frames, _) = parse_beast(&beast);
    let (mut de, mut dn, mut within) = (Vec::new(), Vec::new(), 0usize);
    let (mut dve, mut dvn, mut dvu) = (Vec::new(), Vec::new(), Vec::new());
    for f in &frames {
        let m = me(&f.data);
        let Some(t) = truth_at.get(&f.tick) else {
            continue;
        };
        match bits(m, 1, 5) {
            11 => {
                let (lat, lon) = cpr_local(
                    bits(m, 23, 17) as u32,
                    bits(m, 40, 17) as u32,
                    bits(m, 22, 1) == 1,
                    t.lat,
                    t.lon,
                );
                let p = enu(t.lat, t.lon, lat, lon, t.alt_m);
                de.push(p[0]);
                dn.push(p[1]);
                if p[0].hypot(p[1]) < 92.6 {
                    within += 1;
                }
                let field = bits(m, 9, 12);
                let alt_ft = 25.0 * (((field & 0xFE0) >> 1) | (field & 0xF)) as f64 - 1000.0;
                assert!((alt_ft * 0.3048 - t.alt_m).abs() <= 12.5 * 0.3048 + 1e-9);
            }
            19 => {
                let comp = |dir: u32, first: u32| {
                    let v = (bits(m, first, 10) as f64 - 1.0) * 1852.0 / 3600.0;
                    if bits(m, dir, 1) == 1 {
                        -v
                    } else {
                        v
                    }
                };
                dve.push(comp(14, 15) - t.ve);
                dvn.push(comp(25, 26) - t.vn);
                let vr = (bits(m, 38, 9) as f64 - 1.0) * 64.0 * 0.3048 / 60.0;
                dvu.push(if bits(m, 37, 1) == 1 { -vr } else { vr } - t.vu);
                assert_eq!(bits(m, 11, 3), 2);
            }
            _ => {}
        }
    }
    let stats = |v: &[f64]| {
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        (n, mean, sd)
    };
    // Position: σ = 92.6 / 2.4477 = 37.83 m per axis, plus CPR quantisation (a uniform step
    // of about 5.1 m north, 5.1·... m east: variance step²/12, ~2 m²) -> 37.86 m.
    let sigma_p =
        (92.6f64 / 2.447_746_830_680_816).hypot((6.0f64 / 131_072.0 * 111_200.0) / 12f64.sqrt());
    for v in [&de, &dn] {
        let (n, mean, sd) = stats(v);
        assert!(n > 2900.0, "{n}");
        assert!(mean.abs() < 4.0 * sigma_p / n.sqrt(), "mean {mean}");
        assert!((sd / sigma_p - 1.0).abs() < 0.05, "sd {sd} vs {sigma_p}");
        eprintln!("position noise: n {n}, mean {mean:.2} m, sd {sd:.2} m (expected {sigma_p:.2})");
    }
    // 95 % of horizontal errors within the NACp bound (minus a little for quantisation).
    let frac = within as f64 / de.len() as f64;
    assert!((0.935..0.965).contains(&frac), "{frac}");
    eprintln!("within the NACp 8 bound: {frac:.4}");
    // Velocity: σ = 3 / 2.4477 = 1.2256 m/s per axis plus 1-kt quantisation (0.5144²/12);
    // vertical σ = 15 ft/s / 1.96 = 2.3327 m/s plus 64-fpm quantisation (0.32512²/12).
    let sigma_v = (3.0f64 / 2.447_746_830_680_816).hypot(0.514_444 / 12f64.sqrt());
    let sigma_vz = (4.572f64 / 1.959_963_984_540_054).hypot(0.325_12 / 12f64.sqrt());
    for (v, sigma) in [(&dve, sigma_v), (&dvn, sigma_v), (&dvu, sigma_vz)] {
        let (n, mean, sd) = stats(v);
        assert!(n > 2900.0, "{n}");
        assert!(mean.abs() < 4.0 * sigma / n.sqrt(), "mean {mean}");
        assert!((sd / sigma - 1.0).abs() < 0.05, "sd {sd} vs {sigma}");
        eprintln!(
            "velocity noise: n {n}, mean {mean:.3} m/s, sd {sd:.3} m/s (expected {sigma:.3})"
        );
    }
}

#[test]
fn a_fleet_runs_in_order_with_every_aircraft_heard() {
    let spec = FleetSpec {
        reference: adsb_tracker::sim::scenario::Reference {
            lat_deg: 51.47,
            lon_deg: -0.46,
        },
        aircraft: 100,
        radius_km: 200.0,
        duration_s: 300.0,
        seed: 42,
        mode_weights: Default::default(),
    };
    let s = fleet(&spec).unwrap();
    let started = std::time::Instant::now();
    let (sum, beast, _, truth) = run(&s, 42, "fleet");
    let elapsed = started.elapsed();
    let (frames, _) = parse_beast(&beast);
    assert!(frames.windows(2).all(|w| w[0].tick <= w[1].tick));
    let mut per_icao: BTreeMap<String, usize> = BTreeMap::new();
    for f in &frames {
        *per_icao.entry(icao_of(&f.data)).or_default() += 1;
    }
    assert_eq!(per_icao.len(), 100);
    // 4.6 frames/s emitted, 90 % heard: ~1242 per aircraft in 300 s.
    for (icao, n) in &per_icao {
        assert!((1100..1400).contains(n), "{icao}: {n}");
    }
    let rows = parse_truth(&truth);
    let distinct: HashSet<&str> = rows.iter().map(|r| r.icao.as_str()).collect();
    assert_eq!(distinct.len(), 100);
    assert!(rows.windows(2).all(|w| w[0].t <= w[1].t));
    eprintln!(
        "fleet of 100 for 300 s: {} frames, {} truth rows in {elapsed:?}",
        sum.frames_written(),
        sum.truth_rows
    );
}

#[test]
fn an_unwritable_prefix_names_the_file() {
    let s = load_scenario("paper003").unwrap();
    let prefix = out_prefix("no_such_dir").join("run");
    let e = simulate(&s, 1, &prefix).unwrap_err().to_string();
    let want = format!("{}.beast: ", prefix.display());
    assert!(e.starts_with(&want), "{e}");
}
