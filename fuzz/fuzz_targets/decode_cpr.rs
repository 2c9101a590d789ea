//! The decoder (`src/decode/`: CRC, downlink formats, ME fields) and CPR (`src/decode/cpr.rs`).
//!
//! Input: one selector byte, then a stream in the format it names. Selector bits 0-2: format
//! (Beast, AVR, CSV, ISO, JSON lines; 5-7 synthetic DF17 records), bit 3: write a correct parity into every
//! frame (so mutations reach the decoder), bit 4: single-bit CRC repair, bit 5: a receiver
//! position for surface decoding, bits 6-7: the recent-address window.
//!
//! Checks: every frame is counted exactly once by reason, by DF and by type code; a decoded
//! frame's fields are within what their bits can say; a frame with a correct parity decodes
//! (DF11/17, DF18 unless its CF is TIS-B); the per-aircraft CPR decoders account for every
//! report and only accept positions on the globe; local decoding lands within half a zone of
//! its reference; encoding a position and decoding it back (globally and locally) returns it
//! within the CPR resolution.
#![no_main]

use adsb_tracker::decode::cpr::{
    global_airborne, haversine_m, local_airborne, local_surface, nl, CprConfig, CprDecoder,
    PositionFix,
};
use adsb_tracker::decode::{Cpr, Decoded, Decoder, DecoderConfig, Icao, Message, Skip};
use adsb_tracker::feed::RawFrame;
use adsb_tracker::sim::encode::cpr_encode;
use adsb_tracker_fuzz::{frames_of, split_selector, CrcFixer};
use libfuzzer_sys::fuzz_target;
use std::collections::HashMap;

/// A receiver near Toulouse (the Beast fixture's).
const RECEIVER: (f64, f64) = (43.6, 1.4);

fn check_message(d: &Decoded) {
    assert!(d.icao.0 <= 0xFF_FFFF);
    assert!(d.corrected_bits <= 1);
    let alt_ok = |a: Option<i32>| a.is_none_or(|a| (-1200..=126_700).contains(&a));
    match d.msg {
        Message::Altitude { alt_ft } => assert!(alt_ok(alt_ft), "{alt_ft:?}"),
        Message::Squawk { squawk } | Message::Emergency { squawk, .. } => {
            assert!(squawk <= 0o7777)
        }
        Message::Identification { category, callsign } => {
            assert!((1..=4).contains(&category.0) && category.1 <= 7);
            assert!(callsign
                .0
                .iter()
                .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || b" #".contains(c)));
            assert!(callsign.as_str().len() <= 8);
        }
        Message::AirbornePosition { alt_ft, cpr, .. } => {
            assert!(alt_ok(alt_ft), "{alt_ft:?}");
            assert!(cpr.lat < 1 << 17 && cpr.lon < 1 << 17);
        }
        Message::SurfacePosition {
            speed_kt,
            track_deg,
            cpr,
            ..
        } => {
            assert!(speed_kt.is_none_or(|s| (0.0..=175.0).contains(&s)));
            assert!(track_deg.is_none_or(|t| (0.0..360.0).contains(&t)));
            assert!(cpr.lat < 1 << 17 && cpr.lon < 1 << 17);
        }
        Message::Velocity(v) => {
            assert!((1..=4).contains(&v.subtype));
            if let Some((e, n)) = v.ground_kt {
                assert!(e.abs() <= 4088.0 && n.abs() <= 4088.0, "{e} {n}");
            }
            assert!(v.heading_deg.is_none_or(|h| (0.0..360.0).contains(&h)));
            assert!(v
                .airspeed_kt
                .is_none_or(|(s, _)| (0.0..=4088.0).contains(&s)));
            assert!(v.vrate_fpm.is_none_or(|r| r.abs() <= 510 * 64));
            assert!(v.gnss_minus_baro_ft.is_none_or(|g| g.abs() <= 126 * 25));
            assert!(v.nac_v <= 7);
        }
        Message::OperationalStatus {
            version,
            nac_p,
            sil,
            ..
        } => {
            assert!(version <= 7 && sil <= 3 && nac_p.is_none_or(|n| n <= 15));
        }
        Message::AllCall { capability } => assert!(capability <= 7),
        Message::Other { type_code } => assert!(type_code <= 31),
    }
}

fn wrap_lon(lon: f64) -> f64 {
    (lon + 180.0).rem_euclid(360.0) - 180.0
}

/// Local decoding lands within half a zone of its reference (DO-260B A.1.7.5: that is what
/// the choice of j and m guarantees), on the globe.
fn check_local(cpr: Cpr, ref_lat: f64, ref_lon: f64, surface: bool) {
    let span = if surface { 90.0 } else { 360.0 };
    let i = if cpr.odd { 1.0 } else { 0.0 };
    let got = if surface {
        local_surface(cpr, ref_lat, ref_lon)
    } else {
        local_airborne(cpr, ref_lat, ref_lon)
    };
    // The decoder takes any finite longitude within ±360° (it wraps).
    let ref_ok = (-90.0..=90.0).contains(&ref_lat) && (-360.0..=360.0).contains(&ref_lon);
    let Some((lat, lon)) = got else { return };
    assert!(
        ref_ok,
        "local decode against an invalid reference {ref_lat} {ref_lon}"
    );
    assert!(
        (-90.0..=90.0).contains(&lat) && (-180.0..180.0).contains(&lon),
        "{lat} {lon}"
    );
    let dlat = span / (60.0 - i);
    assert!(
        (lat - ref_lat).abs() <= dlat / 2.0 + 1e-9,
        "local lat {lat} is more than half a zone from {ref_lat}"
    );
    let zones = (f64::from(nl(lat)) - i).max(1.0);
    let dlon = span / zones;
    assert!(
        wrap_lon(lon - ref_lon).abs() <= dlon / 2.0 + 1e-9,
        "local lon {lon} is more than half a zone ({dlon}) from {ref_lon} at lat {lat}"
    );
}

/// A point from 8 bytes: latitude within ±89.9°, longitude in [-180, 180).
fn point(b: &[u8]) -> Option<(f64, f64)> {
    let lat_bits = u32::from_le_bytes(b.get(..4)?.try_into().ok()?);
    let lon_bits = u32::from_le_bytes(b.get(4..8)?.try_into().ok()?);
    let lat = (f64::from(lat_bits) / f64::from(u32::MAX)) * 179.8 - 89.9;
    let lon = (f64::from(lon_bits) / f64::from(u32::MAX)) * 360.0 - 180.0;
    Some((lat, lon.min(179.999_999)))
}

/// Encode, decode back: globally from a pair, locally from a reference a little off.
fn check_round_trip(lat: f64, lon: f64, offset: u8) {
    let even = cpr_encode(lat, lon, false);
    let odd = cpr_encode(lat, lon, true);
    // The CPR grid is 2^17 cells per zone: about 5.1 m of latitude; plus the longitude cell.
    let tolerance_m = 30.0;
    for latest_is_odd in [false, true] {
        if let Some((la, lo)) = global_airborne(even, odd, latest_is_odd) {
            let d = haversine_m(lat, lon, la, lo);
            assert!(
                d <= tolerance_m,
                "global decode of {lat} {lon}: {la} {lo}, {d} m off"
            );
        }
    }
    // A reference up to ~1.2° away, well inside half a zone (3°).
    let shift = (f64::from(offset) - 127.5) / 106.0;
    let (rlat, rlon) = (lat + shift, wrap_lon(lon - shift));
    if rlat.abs() <= 90.0 {
        for cpr in [even, odd] {
            if let Some((la, lo)) = local_airborne(cpr, rlat, rlon) {
                let d = haversine_m(lat, lon, la, lo);
                // Near the poles a degree of longitude is short but zones are few: the
                // reference may be more than half a longitude zone away; only check where
                // it cannot be.
                let zones = f64::from(nl(lat).saturating_sub(u32::from(cpr.odd)).max(1));
                let lon_half_zone = 180.0 / zones;
                if shift.abs() < lon_half_zone - 0.1 {
                    assert!(
                        d <= tolerance_m,
                        "local decode of {lat} {lon}: {la} {lo}, {d} m off"
                    );
                }
            }
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let (selector, stream) = split_selector(data);
    let fix_crc = selector & 0x08 != 0;
    let cfg = DecoderConfig {
        fix_single_bit: selector & 0x10 != 0,
        recent_address_s: [60.0, 1.0, 1e-3, 1e9][usize::from(selector >> 6)],
    };
    let receiver = (selector & 0x20 != 0).then_some(RECEIVER);

    let frames = frames_of(selector, stream);
    let mut decoder = Decoder::new(cfg);
    let mut fixer = CrcFixer::default();
    let mut cpr: HashMap<Icao, (CprDecoder, u64)> = HashMap::new();
    let mut es_decoded = 0u64;
    for frame in &frames {
        let frame: RawFrame = if fix_crc { fixer.fix(frame) } else { *frame };
        let result = decoder.decode(&frame);
        let bytes = frame.bytes();
        let df = frame.df();
        if fix_crc && bytes.len() == 14 && df == 17 {
            assert!(
                result.is_ok(),
                "DF17 with a correct parity refused: {result:?}"
            );
        }
        if fix_crc && bytes.len() == 14 && df == 18 {
            let cf = bytes[0] & 7;
            let want = if matches!(cf, 0 | 1 | 6) {
                Ok(())
            } else {
                Err(Skip::UnsupportedCf)
            };
            assert_eq!(
                result.map(|_| ()),
                want,
                "DF18 CF {cf} with a correct parity"
            );
        }
        if fix_crc && bytes.len() == 7 && df == 11 {
            assert!(
                result.is_ok(),
                "DF11 with a correct parity refused: {result:?}"
            );
        }
        let Ok(d) = result else { continue };
        assert_eq!(d.df, df);
        assert_eq!(d.time_s.to_bits(), frame.time_s.to_bits());
        assert_eq!(d.signal, frame.signal);
        check_message(&d);
        if matches!(d.df, 17 | 18) {
            es_decoded += 1;
        }
        let (cpr_msg, surface) = match d.msg {
            Message::AirbornePosition { cpr, .. } => (cpr, false),
            Message::SurfacePosition { cpr, .. } => (cpr, true),
            _ => continue,
        };
        let (dec, calls) = cpr.entry(d.icao).or_insert_with(|| {
            (
                CprDecoder::new(CprConfig {
                    receiver,
                    ..CprConfig::default()
                }),
                0,
            )
        });
        *calls += 1;
        let fix = if surface {
            dec.surface(d.time_s, cpr_msg)
        } else {
            dec.airborne(d.time_s, cpr_msg)
        };
        if let PositionFix::Accepted {
            lat_deg, lon_deg, ..
        } = fix
        {
            assert!((-90.0..=90.0).contains(&lat_deg), "{lat_deg}");
            assert!((-180.0..=180.0).contains(&lon_deg), "{lon_deg}");
            // The same frame decoded locally against what was just accepted stays put.
            check_local(cpr_msg, lat_deg, lon_deg, surface);
        }
        if let Some((rlat, rlon)) = receiver {
            check_local(cpr_msg, rlat, rlon, surface);
        }
        // A reference anywhere, including off the globe: refused or within half a zone.
        let rlat = f64::from(cpr_msg.lon) / 655.36 - 100.0;
        let rlon = f64::from(cpr_msg.lat) / 327.68 - 200.0;
        check_local(cpr_msg, rlat, rlon, surface);
    }

    // Every frame counted once, by reason and by DF.
    let s = decoder.stats();
    assert_eq!(s.frames, frames.len() as u64);
    let skipped = s.mode_ac
        + s.wrong_length
        + s.crc_rejected
        + s.unknown_address
        + s.unsupported_df
        + s.unsupported_cf;
    assert_eq!(s.decoded + skipped, s.frames, "{s:?}");
    assert_eq!(s.by_df.iter().sum::<u64>(), s.frames - s.mode_ac);
    assert_eq!(s.by_tc.iter().sum::<u64>(), es_decoded);
    assert!(s.crc_fixed <= s.decoded);
    for (dec, calls) in cpr.values() {
        let c = dec.stats();
        let outcomes = c.accepted_global
            + c.accepted_local
            + c.pending
            + c.invalid_cpr
            + c.bad_time
            + c.zone_mismatch
            + c.latitude_out_of_range
            + c.impossible_speed;
        assert_eq!(outcomes, *calls, "CPR outcomes {c:?}");
    }

    // Encoding round trips at points taken from the input.
    for chunk in stream.chunks_exact(9).take(16) {
        if let Some((lat, lon)) = point(chunk) {
            check_round_trip(lat, lon, chunk[8]);
        }
    }
});
