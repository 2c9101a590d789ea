//! A DF17 extended-squitter encoder: what a transponder would send.
//!
//! Frame layout (ICAO Annex 10 Vol IV §3.1.2.8.6; DO-260B §2.2.3.2): DF (5 bits) = 17,
//! CA (3) = 5 (level 2+ transponder, airborne), AA (24) = ICAO address, ME (56), PI (24) =
//! CRC-24 parity of the first 88 bits ([`crate::decode::crc`]). ME bit numbers below are
//! 1-based within the ME field, as the standard numbers them (frame bit = ME bit + 32).
//!
//! Every function is total: values outside a field's range saturate or become "not
//! available" as the standard says, never a panic.

use crate::decode::cpr::nl;
use crate::decode::crc::crc24;
use crate::decode::{Callsign, Cpr, Icao, VerticalRateSource};

/// DF 17, extended squitter.
pub const DF17: u8 = 17;
/// Capability 5: level 2+ transponder, airborne (Annex 10 Vol IV §3.1.2.5.2.2.1).
pub const CA_AIRBORNE: u8 = 5;
/// Type code of the airborne position messages we send: TC 11, barometric altitude, NIC 8
/// with NIC supplement B = 0 (DO-260B Table 2-14).
pub const TC_AIRBORNE_POSITION: u8 = 11;
/// Emitter category set A (TC 4) with category 3: large aircraft, 75,000-300,000 lb
/// (DO-260B §2.2.3.2.5.1, Table 2-9).
pub const TC_IDENTIFICATION: u8 = 4;
pub const CATEGORY_LARGE: u8 = 3;
/// 2^17: CPR encodes airborne positions on 17 bits (Nb = 17, DO-260B A.1.7.1).
const CPR_SCALE: f64 = 131_072.0;
/// NZ: latitude zones between the equator and a pole (DO-260B A.1.7.2).
const NZ: f64 = 15.0;
/// Feet per metre reciprocal: 1 ft = 0.3048 m exactly.
pub const M_PER_FT: f64 = 0.3048;
/// Knots to m/s: 1 kt = 1852 m / 3600 s.
pub const MPS_PER_KT: f64 = 1852.0 / 3600.0;
/// Feet per minute to m/s.
pub const MPS_PER_FPM: f64 = M_PER_FT / 60.0;

/// ME bits: writes `value` (its low `len` bits) at 1-based ME bit `first` (big-endian).
fn put(me: &mut u64, first: u32, len: u32, value: u64) {
    let mask = if len >= 64 {
        u64::MAX
    } else {
        (1u64 << len) - 1
    };
    let shift = 56u32.saturating_sub(first.saturating_sub(1) + len);
    *me |= (value & mask) << shift;
}

/// A whole DF17 frame: header, address, ME and the CRC-24 parity (PI, Annex 10 Vol IV
/// §3.1.2.3.3) over the first 11 bytes.
pub fn df17(icao: Icao, me: u64) -> [u8; 14] {
    let mut f = [0u8; 14];
    f[0] = (DF17 << 3) | CA_AIRBORNE;
    let aa = icao.0 & 0xFF_FFFF;
    f[1] = (aa >> 16) as u8;
    f[2] = (aa >> 8) as u8;
    f[3] = aa as u8;
    for (k, b) in f[4..11].iter_mut().enumerate() {
        *b = (me >> (48 - 8 * k)) as u8;
    }
    let pi = crc24(&f[..11]);
    f[11] = (pi >> 16) as u8;
    f[12] = (pi >> 8) as u8;
    f[13] = pi as u8;
    f
}

/// The 6-bit code of an identification character (DO-260B §2.2.3.2.5.2, Table 2-10; the
/// ICAO Annex 10 Vol IV Table 3-9 subset): A-Z = 1-26, space = 32, 0-9 = 48-57. Anything
/// else is sent as a space.
fn ident_char(b: u8) -> u64 {
    match b {
        b'A'..=b'Z' => u64::from(b - b'A' + 1),
        b'0'..=b'9' => u64::from(b),
        _ => 32,
    }
}

/// TC 4 aircraft identification and category (DO-260B §2.2.3.2.5): ME 1-5 TC, 6-8 emitter
/// category, 9-56 eight 6-bit characters.
pub fn identification(icao: Icao, category: u8, callsign: &Callsign) -> [u8; 14] {
    let mut me = 0u64;
    put(&mut me, 1, 5, u64::from(TC_IDENTIFICATION));
    put(&mut me, 6, 3, u64::from(category));
    for (k, &b) in callsign.0.iter().enumerate() {
        put(&mut me, 9 + 6 * k as u32, 6, ident_char(b));
    }
    df17(icao, me)
}

/// The 12-bit altitude field with Q = 1 (25 ft increments, DO-260B §2.2.3.2.3.4.3):
/// N = (alt + 1000 ft)/25 rounded, the Q bit inserted as bit 8 of the field
/// (field = N[10..4] Q N[3..0]). `None` (the field is then 0, "no altitude") below -1000 ft
/// or above 50,175 ft, where 25-ft coding cannot say it, and for non-finite input.
pub fn altitude_field_25ft(alt_ft: f64) -> Option<u16> {
    let n = ((alt_ft + 1000.0) / 25.0).round();
    if !(0.0..=2047.0).contains(&n) {
        return None;
    }
    let n = n as u16;
    Some(((n & 0x7F0) << 1) | 0x010 | (n & 0x00F))
}

/// MOD(x, y) = x - y floor(x / y) (DO-260B A.1.7.1 note: always >= 0 for y > 0).
fn modulo(x: f64, y: f64) -> f64 {
    x - y * (x / y).floor()
}

/// CPR-encodes an airborne position (DO-260B A.1.7.1, Nb = 17):
/// Dlat_i = 360/(4 NZ - i); YZ_i = floor(2^17 MOD(lat, Dlat_i)/Dlat_i + 1/2);
/// Rlat_i = Dlat_i (YZ_i/2^17 + floor(lat/Dlat_i));
/// Dlon_i = 360/(NL(Rlat_i) - i) when NL(Rlat_i) - i > 0, else 360;
/// XZ_i = floor(2^17 MOD(lon, Dlon_i)/Dlon_i + 1/2); both then taken MOD 2^17.
///
/// NL is taken at Rlat_i, the latitude the receiver will decode, not at the true latitude:
/// that is what keeps the longitude zone count consistent across the NL transition
/// latitudes.
pub fn cpr_encode(lat_deg: f64, lon_deg: f64, odd: bool) -> Cpr {
    let i = if odd { 1.0 } else { 0.0 };
    let dlat = 360.0 / (4.0 * NZ - i);
    let yz = (CPR_SCALE * modulo(lat_deg, dlat) / dlat + 0.5).floor();
    let rlat = dlat * (yz / CPR_SCALE + (lat_deg / dlat).floor());
    let zones = f64::from(nl(rlat)) - i;
    let dlon = if zones > 0.0 { 360.0 / zones } else { 360.0 };
    let xz = (CPR_SCALE * modulo(lon_deg, dlon) / dlon + 0.5).floor();
    let wrap = |v: f64| -> u32 {
        if v.is_finite() {
            (modulo(v, CPR_SCALE) as u32) & 0x1_FFFF
        } else {
            0
        }
    };
    Cpr {
        lat: wrap(yz),
        lon: wrap(xz),
        odd,
    }
}

/// TC 11 airborne position with barometric altitude (DO-260B §2.2.3.2.3): ME 1-5 TC, 6-7
/// surveillance status (0), 8 NIC supplement B (0), 9-20 altitude, 21 T (0: not UTC
/// synchronised), 22 F (CPR format), 23-39 YZ, 40-56 XZ.
pub fn airborne_position(
    icao: Icao,
    alt_ft: f64,
    lat_deg: f64,
    lon_deg: f64,
    odd: bool,
) -> [u8; 14] {
    let cpr = cpr_encode(lat_deg, lon_deg, odd);
    let mut me = 0u64;
    put(&mut me, 1, 5, u64::from(TC_AIRBORNE_POSITION));
    put(
        &mut me,
        9,
        12,
        u64::from(altitude_field_25ft(alt_ft).unwrap_or(0)),
    );
    put(&mut me, 22, 1, u64::from(cpr.odd));
    put(&mut me, 23, 17, u64::from(cpr.lat));
    put(&mut me, 40, 17, u64::from(cpr.lon));
    df17(icao, me)
}

/// What an airborne velocity message carries (DO-260B §2.2.3.2.6.1, subtypes 1 and 2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VelocityReport {
    /// Ground velocity east (negative: west), knots.
    pub ve_kt: f64,
    /// Ground velocity north (negative: south), knots.
    pub vn_kt: f64,
    /// Vertical rate, feet per minute, positive up.
    pub vrate_fpm: f64,
    pub vrate_source: VerticalRateSource,
    /// NACv, 0..=7 (3 bits).
    pub nac_v: u8,
}

/// Magnitude code of a velocity component: |v|/unit rounded, plus 1 (0 means "not
/// available"), saturating at 1023 ("> 1021.5 units", DO-260B §2.2.3.2.6.1.7).
fn speed_code(v: f64, unit: f64) -> u64 {
    let c = (v.abs() / unit).round();
    if c.is_finite() {
        (c as u64 + 1).min(1023)
    } else {
        1023
    }
}

/// TC 19 airborne velocity over ground (DO-260B §2.2.3.2.6.1): ME 1-5 TC = 19, 6-8 subtype,
/// 9 intent change (0), 10 IFR capability (0), 11-13 NACv, 14 east-west direction (1 = west),
/// 15-24 east-west speed code, 25 north-south direction (1 = south), 26-35 north-south speed
/// code, 36 vertical rate source (1 = barometric), 37 vertical rate sign (1 = down), 38-46
/// vertical rate code (|rate|/64 fpm + 1, saturating at 511), 47-48 reserved, 49-56
/// GNSS-minus-baro difference (0: not available).
///
/// Subtype 1 (1 kt units) when both components fit (|v| <= 1021 kt), else subtype 2
/// (supersonic, 4 kt units, saturating at 4086 kt).
pub fn airborne_velocity(icao: Icao, v: &VelocityReport) -> [u8; 14] {
    let subsonic = v.ve_kt.abs().max(v.vn_kt.abs()) < 1021.5;
    let (subtype, unit) = if subsonic { (1, 1.0) } else { (2, 4.0) };
    let mut me = 0u64;
    put(&mut me, 1, 5, 19);
    put(&mut me, 6, 3, subtype);
    put(&mut me, 11, 3, u64::from(v.nac_v));
    put(&mut me, 14, 1, u64::from(v.ve_kt < 0.0));
    put(&mut me, 15, 10, speed_code(v.ve_kt, unit));
    put(&mut me, 25, 1, u64::from(v.vn_kt < 0.0));
    put(&mut me, 26, 10, speed_code(v.vn_kt, unit));
    put(
        &mut me,
        36,
        1,
        u64::from(v.vrate_source == VerticalRateSource::Baro),
    );
    put(&mut me, 37, 1, u64::from(v.vrate_fpm < 0.0));
    let vr = (v.vrate_fpm.abs() / 64.0).round();
    let vr = if vr.is_finite() {
        (vr as u64 + 1).min(511)
    } else {
        511
    };
    put(&mut me, 38, 9, vr);
    df17(icao, me)
}

/// SIL we announce: 3, probability of exceeding the containment radius <= 1e-7 per hour.
pub const SIL: u8 = 3;
/// GVA we announce: 2, geometric altitude 95 % accuracy <= 45 m.
pub const GVA: u8 = 2;

/// TC 31 subtype 0 aircraft operational status, version 2 (DO-260B §2.2.3.2.7.2): ME 1-5
/// TC = 31, 6-8 subtype 0 (airborne), 9-24 capability class (0), 25-40 operational mode (0),
/// 41-43 version = 2, 44 NIC supplement A (0), 45-48 NACp, 49-50 GVA, 51-52 SIL, 53 NICbaro
/// (1: altitude cross-checked), 54 HRD (0: true north), 55 SIL supplement (0: per hour),
/// 56 reserved.
pub fn operational_status(icao: Icao, nac_p: u8) -> [u8; 14] {
    let mut me = 0u64;
    put(&mut me, 1, 5, 31);
    put(&mut me, 41, 3, 2);
    put(&mut me, 45, 4, u64::from(nac_p));
    put(&mut me, 49, 2, u64::from(GVA));
    put(&mut me, 51, 2, u64::from(SIL));
    put(&mut me, 53, 1, 1);
    df17(icao, me)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decode::crc::syndrome;

    fn hex(f: &[u8]) -> String {
        f.iter().map(|b| format!("{b:02X}")).collect()
    }

    #[test]
    fn identification_matches_a_published_frame() {
        // "The 1090MHz Riddle" (Sun), §Identification: 8D4840D6202CC371C32CE0576098 is
        // KLM1023, category set A (TC 4) category 0.
        let f = identification(Icao(0x4840D6), 0, &Callsign(*b"KLM1023 "));
        assert_eq!(hex(&f), "8D4840D6202CC371C32CE0576098");
    }

    #[test]
    fn even_position_matches_a_published_frame() {
        // The 1090MHz Riddle, §Airborne position: 8D40621D58C382D690C8AC2863A7 is the even
        // frame, 38,000 ft, YZ = 93000, XZ = 51372; its decoded position (from the newer even
        // frame) is lat 52.25720214843750, lon 3.91937255859375, which lies exactly on the
        // even grid, so encoding it gives those YZ/XZ back.
        let f = airborne_position(
            Icao(0x40621D),
            38_000.0,
            52.2572021484375,
            3.91937255859375,
            false,
        );
        assert_eq!(hex(&f), "8D40621D58C382D690C8AC2863A7");
        let c = cpr_encode(52.2572021484375, 3.91937255859375, false);
        assert_eq!((c.lat, c.lon, c.odd), (93000, 51372, false));
        // The odd frame 8D40621D58C386435CC412692AD6: YZ = 74158, XZ = 50194. The riddle's
        // global decode of the pair gives the zone index j = 8 and m = 0, so the odd frame's
        // own position is lat = 360/59 (8 + 74158/2^17) = 52.26578 and, with NL = 36,
        // lon = 360/35 (0 + 50194/2^17): encoding that position as odd gives the frame back.
        let lat_odd = 360.0 / 59.0 * (8.0 + 74158.0 / 131_072.0);
        let lon_odd = 360.0 / 35.0 * (50194.0 / 131_072.0);
        let c = cpr_encode(lat_odd, lon_odd, true);
        assert_eq!((c.lat, c.lon, c.odd), (74158, 50194, true));
        let f = airborne_position(Icao(0x40621D), 38_000.0, lat_odd, lon_odd, true);
        assert_eq!(hex(&f), "8D40621D58C386435CC412692AD6");
    }

    #[test]
    fn velocity_matches_a_published_frame_in_every_field_we_send() {
        // The 1090MHz Riddle, §Airborne velocity: 8D485020994409940838175B284F is subtype 1,
        // NACv 0, 8 kt west, 159 kt south, 832 fpm down from GNSS, IFR bit 1 and a
        // GNSS-baro difference of 550 ft (the last two we never send: ME bits 10 and 49-56
        // are masked, and the parity recomputed).
        let f = airborne_velocity(
            Icao(0x485020),
            &VelocityReport {
                ve_kt: -8.0,
                vn_kt: -159.0,
                vrate_fpm: -832.0,
                vrate_source: VerticalRateSource::Gnss,
                nac_v: 0,
            },
        );
        let mut want = [
            0x8D, 0x48, 0x50, 0x20, 0x99, 0x44, 0x09, 0x94, 0x08, 0x38, 0x17, 0, 0, 0,
        ];
        want[5] &= !0x40; // ME bit 10 (IFR) = frame byte 5, bit 6 from the top
        want[10] = 0; // ME bits 49-56 (GNSS-baro difference)
        let pi = crc24(&want[..11]);
        want[11..].copy_from_slice(&[(pi >> 16) as u8, (pi >> 8) as u8, pi as u8]);
        assert_eq!(f, want);
        assert_eq!(syndrome(&f), Some(0));
    }

    #[test]
    fn altitude_field_q_bit_coding() {
        // 38,000 ft: N = 1560 = 0b110_0001_1000 -> 1100001 1 1000 = 0xC38 (the riddle's frame).
        assert_eq!(altitude_field_25ft(38_000.0), Some(0xC38));
        // -1000 ft is N = 0: only the Q bit. 50,175 ft is N = 2047, the top of 25-ft coding.
        assert_eq!(altitude_field_25ft(-1000.0), Some(0x010));
        assert_eq!(altitude_field_25ft(50_175.0), Some(0xFFF));
        assert_eq!(altitude_field_25ft(50_200.0), None);
        assert_eq!(altitude_field_25ft(-1013.0), None);
        assert_eq!(altitude_field_25ft(f64::NAN), None);
        // Rounds to the nearest 25 ft.
        assert_eq!(altitude_field_25ft(12.4), altitude_field_25ft(0.0));
        assert_eq!(altitude_field_25ft(12.6), altitude_field_25ft(25.0));
    }

    #[test]
    fn velocity_saturates_and_goes_supersonic() {
        let me_of = |f: [u8; 14]| f[4..11].iter().fold(0u64, |a, &b| (a << 8) | u64::from(b));
        let field =
            |me: u64, first: u32, len: u32| (me >> (56 - (first - 1) - len)) & ((1 << len) - 1);
        let v = |ve_kt, vn_kt, vrate_fpm| VelocityReport {
            ve_kt,
            vn_kt,
            vrate_fpm,
            vrate_source: VerticalRateSource::Baro,
            nac_v: 2,
        };
        let me = me_of(airborne_velocity(Icao(1), &v(1021.0, -3.4, 100_000.0)));
        assert_eq!(field(me, 6, 3), 1);
        assert_eq!(field(me, 15, 10), 1022);
        assert_eq!((field(me, 25, 1), field(me, 26, 10)), (1, 4));
        assert_eq!(
            (field(me, 36, 1), field(me, 37, 1), field(me, 38, 9)),
            (1, 0, 511)
        );
        assert_eq!(field(me, 11, 3), 2);
        let me = me_of(airborne_velocity(Icao(1), &v(-2000.0, 10.0, -64.0)));
        assert_eq!(field(me, 6, 3), 2);
        assert_eq!((field(me, 14, 1), field(me, 15, 10)), (1, 501));
        assert_eq!(field(me, 26, 10), 4); // 10 kt / 4 = 2.5 -> 3 (round half away) + 1
        assert_eq!((field(me, 37, 1), field(me, 38, 9)), (1, 2));
        let me = me_of(airborne_velocity(Icao(1), &v(1e6, f64::NAN, f64::INFINITY)));
        assert_eq!(
            (field(me, 15, 10), field(me, 26, 10), field(me, 38, 9)),
            (1023, 1023, 511)
        );
    }

    #[test]
    fn operational_status_fields() {
        let f = operational_status(Icao(0xABCDEF), 9);
        assert_eq!(syndrome(&f), Some(0));
        // ME = 11111 000 | 16 x 0 | 16 x 0 | 010 0 1001 10 11 1 0 0 0
        //    = F8 00 00 00 00 | 0100 1001 | 1011 1000 = F8 00 00 00 00 49 B8.
        assert_eq!(&f[4..11], &[0xF8, 0, 0, 0, 0, 0x49, 0xB8]);
        assert_eq!(&f[..4], &[0x8D, 0xAB, 0xCD, 0xEF]);
    }

    #[test]
    fn cpr_is_total_on_odd_inputs() {
        for (lat, lon) in [
            (90.0, 180.0),
            (-90.0, -180.0),
            (f64::NAN, 0.0),
            (0.0, f64::INFINITY),
            (89.99, 359.0),
        ] {
            let c = cpr_encode(lat, lon, true);
            assert!(c.lat < 1 << 17 && c.lon < 1 << 17);
        }
    }
}
