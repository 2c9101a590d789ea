//! Round trip of the simulator's DF17 encoder: random states -> frames -> decoded values.
//!
//! Two independent decoders read the frames back: adsb_deku 0.8.0 (the project's oracle
//! until our own decoder is merged; it reads 7 callsign characters only and no altitude at
//! or below 0 ft, so those are checked by the second decoder alone), and a decoder written
//! here from the DO-260B field tables, including a CPR global decode of an even/odd pair
//! (DO-260B A.1.7.7). Bounds: the quantisation of each field (CPR: half a step of
//! Dlat/2^17 and Dlon/2^17; altitude 12.5 ft; velocity 0.5 kt; vertical rate 32 fpm).
//!
//! adsb_deku costs about a millisecond a frame in a debug build, so it reads every
//! `SIM_ROUNDTRIP_DEKU_EVERY`-th random state (default 500: 200 states, 1000 frames) plus a
//! set of edge cases; our own decoder reads all of them. `SIM_ROUNDTRIP_STATES` overrides the
//! number of random states (default 100,000); `SIM_ROUNDTRIP_DEKU_EVERY=1` gives adsb_deku
//! every state (minutes in debug, seconds with `--release`).

use adsb_deku::adsb::{AirborneVelocitySubType, ME};
use adsb_deku::{CPRFormat, Frame, DF};
use adsb_tracker::decode::cpr::nl;
use adsb_tracker::decode::crc::syndrome;
use adsb_tracker::decode::{Callsign, Icao, VerticalRateSource};
use adsb_tracker::sim::encode::{
    airborne_position, airborne_velocity, identification, operational_status, VelocityReport,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

const CHARSET: &[u8; 64] = b"#ABCDEFGHIJKLMNOPQRSTUVWXYZ##### ###############0123456789######";
const CPR_SCALE: f64 = 131_072.0;
/// Metres per degree of a great circle on a sphere of the Earth's mean radius (for the
/// reported error figures only; the pass/fail bounds are in degrees).
const M_PER_DEG: f64 = 6_371_008.8 * std::f64::consts::PI / 180.0;

/// ME field of a DF17 frame as a 56-bit integer.
fn me(f: &[u8; 14]) -> u64 {
    f[4..11].iter().fold(0, |a, &b| (a << 8) | u64::from(b))
}

/// ME bits `first..first+len` (1-based, as DO-260B numbers them).
fn bits(me: u64, first: u32, len: u32) -> u64 {
    (me >> (56 - (first - 1) - len)) & ((1 << len) - 1)
}

fn modulo(x: f64, y: f64) -> f64 {
    x - y * (x / y).floor()
}

/// DO-260B A.1.7.7 globally unambiguous airborne decoding of an even/odd pair; returns the
/// position of the `latest` frame (true: odd) and the zone count used for its longitude, or
/// None when the two latitudes fall in different NL zones (the pair must then be dropped).
fn cpr_global(even: (u32, u32), odd: (u32, u32), latest_odd: bool) -> Option<(f64, f64, f64)> {
    let (yz0, xz0) = (f64::from(even.0) / CPR_SCALE, f64::from(even.1) / CPR_SCALE);
    let (yz1, xz1) = (f64::from(odd.0) / CPR_SCALE, f64::from(odd.1) / CPR_SCALE);
    let j = (59.0 * yz0 - 60.0 * yz1 + 0.5).floor();
    let mut rlat0 = 6.0 * (modulo(j, 60.0) + yz0);
    let mut rlat1 = 360.0 / 59.0 * (modulo(j, 59.0) + yz1);
    if rlat0 >= 270.0 {
        rlat0 -= 360.0;
    }
    if rlat1 >= 270.0 {
        rlat1 -= 360.0;
    }
    if nl(rlat0) != nl(rlat1) {
        return None;
    }
    let (lat, i, xz) = if latest_odd {
        (rlat1, 1, xz1)
    } else {
        (rlat0, 0, xz0)
    };
    let nl_lat = f64::from(nl(lat));
    let ni = (nl_lat - f64::from(i)).max(1.0);
    let m = (xz0 * (nl_lat - 1.0) - xz1 * nl_lat + 0.5).floor();
    let mut lon = 360.0 / ni * (modulo(m, ni) + xz);
    if lon >= 180.0 {
        lon -= 360.0;
    }
    Some((lat, lon, 360.0 / ni))
}

fn wrap_deg(d: f64) -> f64 {
    let d = modulo(d + 180.0, 360.0);
    d - 180.0
}

#[derive(Default)]
struct Tally {
    cpr_lat_over_bound: f64,
    cpr_lon_over_bound: f64,
    cpr_m_mid: f64,
    cpr_m_all: f64,
    alt_ft: f64,
    vel_kt: f64,
    vrate_fpm: f64,
    nl_mismatch: usize,
    deku_states: usize,
    deku_positions: usize,
    deku_alts: usize,
}

#[derive(Clone, Copy, Debug)]
struct State {
    icao: Icao,
    lat: f64,
    lon: f64,
    alt_ft: f64,
    report: VelocityReport,
    callsign: [u8; 8],
    nac_p: u8,
}

fn random_state(rng: &mut StdRng) -> State {
    let mut callsign = [b' '; 8];
    for c in callsign.iter_mut() {
        *c = b"ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789 "[rng.gen_range(0..37)];
    }
    State {
        icao: Icao(rng.gen_range(1..0xFF_FFFF)),
        lat: rng.gen_range(-89.9..89.9),
        lon: rng.gen_range(-180.0..180.0),
        alt_ft: rng.gen_range(-1000.0..50_175.0),
        report: VelocityReport {
            ve_kt: rng.gen_range(-1021.0..1021.0),
            vn_kt: rng.gen_range(-1021.0..1021.0),
            vrate_fpm: rng.gen_range(-32_000.0..32_000.0),
            vrate_source: if rng.gen() {
                VerticalRateSource::Baro
            } else {
                VerticalRateSource::Gnss
            },
            nac_v: rng.gen_range(0..=4),
        },
        callsign,
        nac_p: rng.gen_range(0..=11),
    }
}

/// Encodes one state into its five frames, decodes them back and checks every field.
fn check(s: &State, t: &mut Tally, with_deku: bool) {
    let State {
        icao,
        lat,
        lon,
        alt_ft,
        report,
        callsign: cs,
        nac_p,
    } = *s;
    let even = airborne_position(icao, alt_ft, lat, lon, false);
    let odd = airborne_position(icao, alt_ft, lat, lon, true);
    let vel = airborne_velocity(icao, &report);
    let id = identification(icao, 3, &Callsign(cs));
    let st = operational_status(icao, nac_p);
    for f in [&even, &odd, &vel, &id, &st] {
        assert_eq!(syndrome(f), Some(0));
        assert_eq!(f[0], 0x8D);
        assert_eq!(u32::from_be_bytes([0, f[1], f[2], f[3]]), icao.0);
    }

    // Our own reading of the fields.
    let (me0, me1) = (me(&even), me(&odd));
    assert_eq!(
        (bits(me0, 1, 5), bits(me0, 22, 1), bits(me1, 22, 1)),
        (11, 0, 1)
    );
    let field = bits(me0, 9, 12);
    assert_eq!(field & 0x10, 0x10, "Q bit");
    let n25 = ((field & 0xFE0) >> 1) | (field & 0xF);
    let alt_dec = 25.0 * n25 as f64 - 1000.0;
    assert!((alt_dec - alt_ft).abs() <= 12.5, "{alt_ft} -> {alt_dec}");
    t.alt_ft = t.alt_ft.max((alt_dec - alt_ft).abs());
    let e = (bits(me0, 23, 17) as u32, bits(me0, 40, 17) as u32);
    let o = (bits(me1, 23, 17) as u32, bits(me1, 40, 17) as u32);
    for latest_odd in [false, true] {
        let Some((la, lo, dlon)) = cpr_global(e, o, latest_odd) else {
            t.nl_mismatch += 1;
            continue;
        };
        let dlat = if latest_odd { 360.0 / 59.0 } else { 6.0 };
        let (err_lat, err_lon) = ((la - lat).abs(), wrap_deg(lo - lon).abs());
        t.cpr_lat_over_bound = t
            .cpr_lat_over_bound
            .max(err_lat / (dlat / (2.0 * CPR_SCALE)));
        t.cpr_lon_over_bound = t
            .cpr_lon_over_bound
            .max(err_lon / (dlon / (2.0 * CPR_SCALE)));
        assert!(
            err_lat <= dlat / (2.0 * CPR_SCALE) + 1e-9,
            "{lat} {lon}: lat {la}"
        );
        assert!(
            err_lon <= dlon / (2.0 * CPR_SCALE) + 1e-9,
            "{lat} {lon}: lon {lo}"
        );
        let m = (err_lat * M_PER_DEG).hypot(err_lon * M_PER_DEG * lat.to_radians().cos());
        t.cpr_m_all = t.cpr_m_all.max(m);
        if lat.abs() <= 80.0 {
            t.cpr_m_mid = t.cpr_m_mid.max(m);
            assert!(m <= 5.0, "{lat} {lon}: {m} m");
        }
    }

    let mv = me(&vel);
    assert_eq!((bits(mv, 1, 5), bits(mv, 6, 3)), (19, 1));
    assert_eq!(bits(mv, 11, 3), u64::from(report.nac_v));
    let comp = |dir_bit, first| {
        let v = bits(mv, first, 10) as f64 - 1.0;
        if bits(mv, dir_bit, 1) == 1 {
            -v
        } else {
            v
        }
    };
    let (ve, vn) = (comp(14, 15), comp(25, 26));
    let vr_mag = (bits(mv, 38, 9) as f64 - 1.0) * 64.0;
    let vr = if bits(mv, 37, 1) == 1 {
        -vr_mag
    } else {
        vr_mag
    };
    assert_eq!(
        bits(mv, 36, 1) == 1,
        report.vrate_source == VerticalRateSource::Baro
    );
    let ev = (ve - report.ve_kt).abs().max((vn - report.vn_kt).abs());
    assert!(ev <= 0.5, "{report:?} -> {ve} {vn}");
    assert!((vr - report.vrate_fpm).abs() <= 32.0, "{report:?} -> {vr}");
    t.vel_kt = t.vel_kt.max(ev);
    t.vrate_fpm = t.vrate_fpm.max((vr - report.vrate_fpm).abs());

    let mi = me(&id);
    assert_eq!((bits(mi, 1, 5), bits(mi, 6, 3)), (4, 3));
    let decoded: Vec<u8> = (0..8)
        .map(|c| CHARSET[bits(mi, 9 + 6 * c, 6) as usize])
        .collect();
    assert_eq!(decoded, cs, "callsign");

    let ms = me(&st);
    assert_eq!(
        (bits(ms, 1, 5), bits(ms, 6, 3), bits(ms, 41, 3)),
        (31, 0, 2)
    );
    assert_eq!(bits(ms, 45, 4), u64::from(nac_p));

    if !with_deku {
        return;
    }
    t.deku_states += 1;
    let deku = |f: &[u8; 14]| match Frame::from_bytes(f) {
        Ok(Frame {
            df: DF::ADSB(adsb),
            crc: 0,
        }) => {
            assert_eq!(adsb.icao.0, [f[1], f[2], f[3]]);
            adsb.me
        }
        other => panic!("adsb_deku on {f:02x?}: {other:?}"),
    };
    let (
        ME::AirbornePositionBaroAltitude { altitude: a0, .. },
        ME::AirbornePositionBaroAltitude { altitude: a1, .. },
    ) = (deku(&even), deku(&odd))
    else {
        panic!("position frames not decoded as TC 9-18 by adsb_deku");
    };
    assert_eq!(
        (a0.odd_flag, a1.odd_flag),
        (CPRFormat::Even, CPRFormat::Odd)
    );
    assert_eq!(
        (a0.lat_cpr, a0.lon_cpr, a1.lat_cpr, a1.lon_cpr),
        (e.0, e.1, o.0, o.1)
    );
    if alt_dec > 0.0 {
        assert_eq!(a0.alt.map(f64::from), Some(alt_dec));
        assert_eq!(a1.alt.map(f64::from), Some(alt_dec));
        t.deku_alts += 1;
    }
    // adsb_deku skips the NL consistency check: compare only where it holds.
    if let (Some(p), Some((_, _, dlon))) = (
        adsb_deku::cpr::get_position((&a0, &a1)),
        cpr_global(e, o, true),
    ) {
        assert!(
            (p.latitude - lat).abs() <= 360.0 / 59.0 / (2.0 * CPR_SCALE) + 1e-9,
            "{s:?} {p:?}"
        );
        assert!(
            wrap_deg(p.longitude - lon).abs() <= dlon / (2.0 * CPR_SCALE) + 1e-9,
            "{s:?} {p:?}"
        );
        t.deku_positions += 1;
    }
    match deku(&vel) {
        ME::AirborneVelocity(v) => {
            assert_eq!(v.st, 1);
            assert_eq!(v.nac_v, report.nac_v);
            let AirborneVelocitySubType::GroundSpeedDecoding(g) = v.sub_type else {
                panic!("velocity subtype");
            };
            assert_eq!(
                f64::from(g.ew_vel as i16 - 1) * f64::from(g.ew_sign.value()),
                ve
            );
            assert_eq!(
                f64::from(g.ns_vel as i16 - 1) * f64::from(g.ns_sign.value()),
                vn
            );
            let (_, _, vrate) = v.calculate().unwrap();
            assert_eq!(f64::from(vrate), vr);
        }
        other => panic!("velocity: {other:?}"),
    }
    match deku(&id) {
        ME::AircraftIdentification { identification, .. } => {
            let first7: String = cs[..7]
                .iter()
                .filter(|&&c| c != b' ')
                .map(|&c| c as char)
                .collect();
            assert_eq!(identification.cn, first7);
            assert_eq!(identification.ca, 3);
        }
        other => panic!("identification: {other:?}"),
    }
    match deku(&st) {
        ME::AircraftOperationStatus(adsb_deku::adsb::OperationStatus::Airborne(s)) => {
            assert_eq!(s.navigational_accuracy_category, nac_p);
            assert_eq!(
                s.version_number,
                adsb_deku::adsb::ADSBVersion::DOC9871AppendixC
            );
            assert_eq!(
                (s.source_integrity_level, s.geometric_vertical_accuracy),
                (3, 2)
            );
        }
        other => panic!("operational status: {other:?}"),
    }
}

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

#[test]
fn hundred_thousand_random_states_round_trip() {
    let n = env_usize("SIM_ROUNDTRIP_STATES", 100_000);
    let deku_every = env_usize("SIM_ROUNDTRIP_DEKU_EVERY", 500).max(1);
    let mut rng = StdRng::seed_from_u64(0x5EED);
    let mut t = Tally::default();
    for k in 0..n {
        check(&random_state(&mut rng), &mut t, k % deku_every == 0);
    }
    // Pairs straddling an NL transition are dropped by a correct decoder; they are rare.
    assert!(
        t.nl_mismatch * 1000 < n,
        "{} NL mismatches in {n}",
        t.nl_mismatch
    );
    assert!(t.deku_positions * 10 >= t.deku_states * 9 && t.deku_alts * 10 >= t.deku_states * 9);
    eprintln!(
        "{n} states ({} through adsb_deku): CPR error max {:.4} x half-step (lat), {:.4} x \
         half-step (lon); max {:.2} m within 80 deg of the equator, {:.2} m everywhere; \
         altitude max {:.2} ft; velocity max {:.3} kt; vertical rate max {:.1} fpm; {} \
         NL-straddling pairs",
        t.deku_states,
        t.cpr_lat_over_bound,
        t.cpr_lon_over_bound,
        t.cpr_m_mid,
        t.cpr_m_all,
        t.alt_ft,
        t.vel_kt,
        t.vrate_fpm,
        t.nl_mismatch
    );
}

#[test]
fn edge_cases_round_trip_through_both_decoders() {
    // DO-260B Table A-21 transition latitudes (NL changes there), poles, the antimeridian,
    // the ends of every field's range.
    let transitions = [
        10.470_471_30,
        14.828_174_37,
        18.186_263_57,
        21.029_394_93,
        23.545_044_87,
        29.911_356_86,
        38.413_418_56,
        45.546_267_23,
        52.403_052_97,
        59.954_592_77,
        66.255_674_83,
        72.260_710_08,
        80.247_539_49,
        84.891_661_91,
        86.535_373_86,
        87.0,
    ];
    let mut lats = vec![0.0, 89.9, -89.9, 85.0, -85.0];
    for &l in &transitions {
        for d in [-1e-9, 0.0, 1e-9] {
            lats.push(l + d);
            lats.push(-(l + d));
        }
    }
    let mut t = Tally::default();
    let mut k = 0u32;
    for &lat in &lats {
        for lon in [-180.0, 179.999_999, -1e-9] {
            k += 1;
            let (alt_ft, ve_kt, vn_kt, vrate_fpm) = match k % 4 {
                0 => (25.0, 0.0, 0.0, 0.0),
                1 => (50_175.0, 1021.0, -1021.0, 32_640.0),
                2 => (37_012.4, -0.49, 0.5, -32_640.0),
                _ => (-1000.0, 0.4, -0.4, 31.9),
            };
            let s = State {
                icao: Icao(0xABC000 + k),
                lat,
                lon,
                alt_ft,
                report: VelocityReport {
                    ve_kt,
                    vn_kt,
                    vrate_fpm,
                    vrate_source: VerticalRateSource::Baro,
                    nac_v: (k % 5) as u8,
                },
                callsign: *b"Z9 0A  Q",
                nac_p: (k % 12) as u8,
            };
            check(&s, &mut t, true);
        }
    }
    assert_eq!(t.deku_states, lats.len() * 3);
}
