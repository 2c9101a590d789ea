//! ASTERIX category 062 (SDPS track messages), edition 1.19, over UDP.
//!
//! Every `period_s` one data block (more when they would pass `max_datagram_bytes`) goes to
//! every destination, with one record per track updated in the period and a last record
//! (I062/080 TSE) for each track retired in it. Item layouts, LSBs and ranges are those of
//! EUROCONTROL-SPEC-0149-9, "EUROCONTROL Specification for Surveillance Data Exchange –
//! ASTERIX Part 9: Category 062 SDPS Track Messages", edition 1.19 (the edition Wireshark's
//! dissector decodes by default); each encoder below cites its item. A value outside an item's
//! range is clamped to the range's end rather than wrapped.
//!
//! User Application Profile used (FRN: item), FSPEC bit 8 of the first octet is FRN 1:
//! 1 I062/010, 3 I062/015, 4 I062/070, 5 I062/105, 6 I062/100, 7 I062/185, 8 I062/210,
//! 9 I062/060, 11 I062/380, 12 I062/040, 13 I062/080, 14 I062/290, 15 I062/200,
//! 17 I062/136, 18 I062/130, 19 I062/135, 20 I062/220, 27 I062/500.

use super::time::{time_of_day_s, utc_of_feed_time};
use super::{recv_counting, try_recv_counting, Output, OutputEvent, OutputStats};
use crate::config::AsterixConfig;
use crate::daemon::aircraft::{FPM_TO_MPS, FT_TO_M};
use crate::daemon::registry::{Published, TrackState};
use crate::decode::Icao;
use crate::track::geo::LocalFrame;
use prometheus_client::metrics::counter::Counter;
use std::collections::{HashMap, VecDeque};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::UdpSocket;
use tokio::sync::broadcast;
use tokio_util::sync::CancellationToken;

/// The category of the data blocks.
pub const CAT062: u8 = 62;

/// Transversal movement of I062/200 TRANS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trans {
    ConstantCourse = 0,
    RightTurn = 1,
    LeftTurn = 2,
}

/// Longitudinal movement of I062/200 LONG.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Long {
    ConstantSpeed = 0,
    Increasing = 1,
    Decreasing = 2,
}

/// Vertical movement of I062/200 VERT.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Vert {
    Level = 0,
    Climb = 1,
    Descent = 2,
}

/// Estimated accuracies (I062/500), 1-sigma, in the units of the items they qualify.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Accuracies {
    /// Standard deviation of the Cartesian position, X (east) and Y (north), m.
    pub x_m: f64,
    pub y_m: f64,
    /// Covariance of X and Y, m^2 (sent as sign(cov) * sqrt|cov|).
    pub xy_m2: f64,
    /// Standard deviation of latitude and longitude, degrees.
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Standard deviation of the altitude, ft.
    pub alt_ft: f64,
    /// Standard deviation of Vx, Vy, m/s.
    pub vx_mps: f64,
    pub vy_mps: f64,
    /// Standard deviation of the rate of climb, ft/min.
    pub rocd_fpm: f64,
}

/// Everything one CAT062 record says about one track.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackRecord {
    pub sac: u8,
    pub sic: u8,
    pub service_id: u8,
    /// Time of track information: seconds since the last UTC midnight.
    pub time_of_day_s: f64,
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Cartesian position relative to the system reference, m (east, north).
    pub xy_m: Option<(f64, f64)>,
    /// Velocity east and north, m/s.
    pub vx_mps: f64,
    pub vy_mps: f64,
    /// Acceleration east and north, m/s^2, when the mode has one.
    pub accel_mps2: Option<(f64, f64)>,
    /// Mode 3/A code as its 12 bits (A4 A2 A1 B4 ... D1, i.e. the octal digits).
    pub mode3a: Option<u16>,
    /// Mode 3/A changed since the track's last record.
    pub mode3a_changed: bool,
    pub track_number: u16,
    /// First record of the track (I062/080 TSB).
    pub first: bool,
    /// Last record of the track (I062/080 TSE).
    pub last: bool,
    /// No update for longer than the coasting threshold (I062/080 CST).
    pub coasting: bool,
    pub on_ground: bool,
    /// Age of the track since its first occurrence, s.
    pub track_age_s: f64,
    /// Age of the last 1090 ES report used, s.
    pub es_age_s: f64,
    pub movement: (Trans, Long, Vert),
    /// Last reported barometric altitude, flight levels (100 ft).
    pub measured_fl: Option<f64>,
    /// Calculated altitude of the track, ft.
    pub alt_ft: f64,
    /// Rate of climb (positive) or descent, ft/min.
    pub rocd_fpm: f64,
    /// 24-bit ICAO aircraft address.
    pub address: u32,
    /// Identification (callsign), up to 8 characters.
    pub callsign: Option<String>,
    pub accuracies: Accuracies,
}

/// `v / lsb` rounded, clamped to `min..=max` (NaN gives 0).
fn scaled(v: f64, lsb: f64, min: i64, max: i64) -> i64 {
    // f64 -> i64 `as` saturates and maps NaN to 0; the clamp keeps the item's range.
    ((v / lsb).round() as i64).clamp(min, max)
}

fn push_i16(out: &mut Vec<u8>, v: i64) {
    out.extend_from_slice(&(v as i16).to_be_bytes());
}

fn push_u16(out: &mut Vec<u8>, v: i64) {
    out.extend_from_slice(&(v as u16).to_be_bytes());
}

fn push_i24(out: &mut Vec<u8>, v: i64) {
    let b = (v as i32).to_be_bytes();
    out.extend_from_slice(&b[1..4]);
}

/// ICAO 6-bit character code of identification (ICAO Annex 10 Vol IV, Table 3-9): A-Z 1-26,
/// space 32, 0-9 48-57; anything else is sent as a space.
fn ia5_6bit(c: u8) -> u8 {
    match c {
        b'A'..=b'Z' => c - b'A' + 1,
        b'0'..=b'9' => c,
        _ => 32,
    }
}

/// Eight characters, space padded, in 48 bits.
fn identification(callsign: &str) -> [u8; 6] {
    let mut bits: u64 = 0;
    let mut chars = callsign.bytes().map(|c| c.to_ascii_uppercase());
    for _ in 0..8 {
        bits = (bits << 6) | u64::from(ia5_6bit(chars.next().unwrap_or(b' ')));
    }
    let b = bits.to_be_bytes();
    [b[2], b[3], b[4], b[5], b[6], b[7]]
}

/// The FSPEC of a set of FRNs (bit `frn - 1` of `frns`): 7 FRNs an octet, bit 8 first,
/// bit 1 (FX) set when another octet follows.
fn fspec(frns: u64) -> Vec<u8> {
    let mut out = Vec::new();
    let mut rest = frns;
    loop {
        let mut octet = 0u8;
        for i in 0..7 {
            if rest & (1 << i) != 0 {
                octet |= 0x80 >> i;
            }
        }
        rest >>= 7;
        if rest != 0 {
            out.push(octet | 1);
        } else {
            out.push(octet);
            return out;
        }
    }
}

impl TrackRecord {
    /// Appends the record (FSPEC and items) to `out`.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut frns: u64 = 0;
        let mut set = |frn: u32| frns |= 1 << (frn - 1);
        let mut items: Vec<u8> = Vec::with_capacity(96);

        // FRN 1, I062/010 Data Source Identifier: SAC, SIC, one octet each.
        set(1);
        items.extend_from_slice(&[self.sac, self.sic]);

        // FRN 3, I062/015 Service Identification: one octet.
        set(3);
        items.push(self.service_id);

        // FRN 4, I062/070 Time Of Track Information: 3 octets, unsigned, LSB 1/128 s,
        // seconds since midnight UTC (0..86400 s).
        set(4);
        let tod = scaled(self.time_of_day_s, 1.0 / 128.0, 0, 86_400 * 128 - 1);
        let b = (tod as u32).to_be_bytes();
        items.extend_from_slice(&b[1..4]);

        // FRN 5, I062/105 Calculated Position In WGS-84 Co-ordinates: latitude and
        // longitude, 4 octets each, two's complement, LSB 180/2^25 deg; -90 <= lat <= 90,
        // -180 <= lon < 180.
        set(5);
        let lsb = 180.0 / f64::from(1u32 << 25);
        let lat = scaled(self.lat_deg, lsb, -(1 << 24), 1 << 24);
        let lon = scaled(self.lon_deg, lsb, -(1 << 25), (1 << 25) - 1);
        items.extend_from_slice(&(lat as i32).to_be_bytes());
        items.extend_from_slice(&(lon as i32).to_be_bytes());

        // FRN 6, I062/100 Calculated Track Position (Cartesian): X, Y, 3 octets each, two's
        // complement, LSB 0.5 m (+-4,194 km).
        if let Some((x, y)) = self.xy_m {
            set(6);
            push_i24(&mut items, scaled(x, 0.5, -(1 << 23), (1 << 23) - 1));
            push_i24(&mut items, scaled(y, 0.5, -(1 << 23), (1 << 23) - 1));
        }

        // FRN 7, I062/185 Calculated Track Velocity (Cartesian): Vx, Vy, 2 octets each, two's
        // complement, LSB 0.25 m/s, -8192 <= V <= 8191.75 m/s.
        set(7);
        push_i16(&mut items, scaled(self.vx_mps, 0.25, -32_768, 32_767));
        push_i16(&mut items, scaled(self.vy_mps, 0.25, -32_768, 32_767));

        // FRN 8, I062/210 Calculated Acceleration (Cartesian): Ax, Ay, 1 octet each, two's
        // complement, LSB 0.25 m/s^2, -31.75 <= A <= 31.75 m/s^2 (values beyond are sent as
        // the maximum).
        if let Some((ax, ay)) = self.accel_mps2 {
            set(8);
            items.push(scaled(ax, 0.25, -127, 127) as i8 as u8);
            items.push(scaled(ay, 0.25, -127, 127) as i8 as u8);
        }

        // FRN 9, I062/060 Track Mode 3/A Code: V (0 validated), G (0 not garbled), CH (1 the
        // code changed), a spare bit, then the 12-bit code A4..D1 in octal representation.
        if let Some(code) = self.mode3a {
            set(9);
            let ch = if self.mode3a_changed { 0x2000 } else { 0 };
            push_u16(&mut items, i64::from((code & 0x0fff) | ch));
        }

        // FRN 11, I062/380 Aircraft Derived Data, compound: primary subfield ADR (bit 8) and
        // ID (bit 7); ADR: the 24-bit target address; ID: 8 characters of 6 bits (ICAO
        // Annex 10 Vol IV 3.1.2.9), space padded.
        set(11);
        let with_id = self.callsign.is_some();
        items.push(if with_id { 0xC0 } else { 0x80 });
        let a = (self.address & 0x00ff_ffff).to_be_bytes();
        items.extend_from_slice(&a[1..4]);
        if let Some(cs) = &self.callsign {
            items.extend_from_slice(&identification(cs));
        }

        // FRN 12, I062/040 Track Number: 2 octets, 0..65535.
        set(12);
        items.extend_from_slice(&self.track_number.to_be_bytes());

        // FRN 13, I062/080 Track Status, variable length, 6 octets here:
        // 1: MON (1 monosensor) SPI MRH (0 barometric altitude more reliable) SRC (3 bits,
        //    0 no source of geometric altitude) CNF (0 confirmed) FX
        // 2: SIM TSE (last message) TSB (first message) FPC AFF STP KOS FX
        // 3: AMA MD4 (2) ME MI MD5 (2) FX
        // 4: CST (coasting) PSR SSR MDS (1: no such update recently) ADS (0: ADS-B used)
        //    SUC AAC FX
        // 5: SDS (2 bits, 1 co-operative only) EMS (3 bits) PFT FPLT FX
        // 6: DUPT DUPF DUPM SFC (surface target) IDD IEC spare FX
        set(13);
        items.push(0x80 | 1);
        items.push(if self.last { 0x40 } else { 0 } | if self.first { 0x20 } else { 0 } | 1);
        items.push(1);
        items.push(if self.coasting { 0x80 } else { 0 } | 0x40 | 0x20 | 0x10 | 1);
        let ems: u8 = match self.mode3a {
            Some(0o7500) => 5,
            Some(0o7600) => 4,
            Some(0o7700) => 1,
            _ => 0,
        };
        items.push((1 << 6) | (ems << 3) | 1);
        items.push(if self.on_ground { 0x10 } else { 0 });

        // FRN 14, I062/290 System Track Update Ages, compound: primary subfield TRK (bit 8)
        // and ES (bit 3); TRK: actual track age since its first occurrence, ES: age of the
        // last 1090 Extended Squitter ADS-B report; 1 octet each, LSB 1/4 s, at most 63.75 s
        // (an older age is sent as 63.75 s).
        set(14);
        items.push(0x80 | 0x04);
        items.push(scaled(self.track_age_s, 0.25, 0, 255) as u8);
        items.push(scaled(self.es_age_s, 0.25, 0, 255) as u8);

        // FRN 15, I062/200 Mode of Movement: TRANS (bits 8-7: 0 constant course, 1 right
        // turn, 2 left turn), LONG (bits 6-5: 0 constant groundspeed, 1 increasing,
        // 2 decreasing), VERT (bits 4-3: 0 level, 1 climb, 2 descent), ADF (bit 2: 0 no
        // altitude discrepancy), bit 1 spare.
        set(15);
        let (t, l, v) = self.movement;
        items.push(((t as u8) << 6) | ((l as u8) << 4) | ((v as u8) << 2));

        // FRN 17, I062/136 Measured Flight Level: 2 octets, two's complement, LSB 1/4 FL,
        // -15 FL <= FL <= 1500 FL.
        if let Some(fl) = self.measured_fl {
            set(17);
            push_i16(&mut items, scaled(fl, 0.25, -60, 6000));
        }

        // FRN 18, I062/130 Calculated Track Geometric Altitude: 2 octets, two's complement,
        // LSB 6.25 ft, -1500 ft <= alt <= 150000 ft. (Our estimate of the reported altitude,
        // barometric for most aircraft: see also I062/135.)
        set(18);
        push_i16(&mut items, scaled(self.alt_ft, 6.25, -240, 24_000));

        // FRN 19, I062/135 Calculated Track Barometric Altitude: QNH bit (0: no QNH
        // correction), then 15 bits two's complement, LSB 1/4 FL, -15 FL <= alt <= 1500 FL.
        set(19);
        let ctb = scaled(self.alt_ft / 100.0, 0.25, -60, 6000);
        push_u16(&mut items, ctb & 0x7fff);

        // FRN 20, I062/220 Calculated Rate Of Climb/Descent: 2 octets, two's complement,
        // LSB 6.25 ft/min (positive: climb).
        set(20);
        push_i16(&mut items, scaled(self.rocd_fpm, 6.25, -32_768, 32_767));

        // FRN 27, I062/500 Estimated Accuracies, compound: primary subfield APC (bit 8),
        // COV (7), APW (6), AGA (5), ABA (4), ATV (3), FX; second octet ARC (bit 8).
        // APC: sigma X, sigma Y, 2 octets each, unsigned, LSB 0.5 m.
        // COV: XY covariance as sign(cov) * sqrt|cov|, 2 octets, two's complement, LSB 0.5 m.
        // APW: sigma latitude, sigma longitude, 2 octets each, unsigned, LSB 180/2^25 deg.
        // AGA: sigma geometric altitude, 1 octet, unsigned, LSB 6.25 ft.
        // ABA: sigma barometric altitude, 1 octet, unsigned, LSB 1/4 FL.
        // ATV: sigma Vx, sigma Vy, 1 octet each, unsigned, LSB 0.25 m/s.
        // ARC: sigma rate of climb/descent, 1 octet, unsigned, LSB 6.25 ft/min.
        set(27);
        let acc = &self.accuracies;
        items.push(0x80 | 0x40 | 0x20 | 0x10 | 0x08 | 0x04 | 1);
        items.push(0x80);
        push_u16(&mut items, scaled(acc.x_m, 0.5, 0, 65_535));
        push_u16(&mut items, scaled(acc.y_m, 0.5, 0, 65_535));
        let cov = acc.xy_m2.signum() * acc.xy_m2.abs().sqrt();
        push_i16(&mut items, scaled(cov, 0.5, -32_768, 32_767));
        push_u16(&mut items, scaled(acc.lat_deg, lsb, 0, 65_535));
        push_u16(&mut items, scaled(acc.lon_deg, lsb, 0, 65_535));
        items.push(scaled(acc.alt_ft, 6.25, 0, 255) as u8);
        items.push(scaled(acc.alt_ft / 100.0, 0.25, 0, 255) as u8);
        items.push(scaled(acc.vx_mps, 0.25, 0, 255) as u8);
        items.push(scaled(acc.vy_mps, 0.25, 0, 255) as u8);
        items.push(scaled(acc.rocd_fpm, 6.25, 0, 255) as u8);

        out.extend_from_slice(&fspec(frns));
        out.extend_from_slice(&items);
    }
}

/// Data blocks of `records` (each already encoded), none longer than `max_bytes` (a record
/// longer than that alone goes in a block of its own).
/// Returns each block with the number of records in it.
pub fn data_blocks(records: &[Vec<u8>], max_bytes: usize) -> Vec<(Vec<u8>, u64)> {
    let mut blocks = Vec::new();
    let mut block: Vec<u8> = Vec::new();
    let mut n = 0;
    for r in records {
        if !block.is_empty() && block.len() + r.len() > max_bytes {
            blocks.push((finish_block(std::mem::take(&mut block)), n));
            n = 0;
        }
        if block.is_empty() {
            block.extend_from_slice(&[CAT062, 0, 0]);
        }
        block.extend_from_slice(r);
        n += 1;
    }
    if !block.is_empty() {
        blocks.push((finish_block(block), n));
    }
    blocks
}

/// Writes LEN (the whole block's length, CAT and LEN included) into a block.
fn finish_block(mut block: Vec<u8>) -> Vec<u8> {
    let len = u16::try_from(block.len()).unwrap_or(u16::MAX).to_be_bytes();
    if let Some(l) = block.get_mut(1..3) {
        l.copy_from_slice(&len);
    }
    block
}

/// Track numbers (I062/040): each aircraft keeps its number while tracked; a retired one
/// goes to the back of the free queue, reused only once every number never used is.
#[derive(Debug, Default)]
pub struct TrackNumbers {
    next: u32,
    free: VecDeque<u16>,
}

impl TrackNumbers {
    /// A number not held by any live track, `None` when all 65,536 are.
    pub fn take(&mut self) -> Option<u16> {
        if let Ok(n) = u16::try_from(self.next) {
            self.next += 1;
            return Some(n);
        }
        self.free.pop_front()
    }

    /// Gives a retired track's number back.
    pub fn release(&mut self, n: u16) {
        self.free.push_back(n);
    }
}

/// The record inputs derived from a published snapshot.
pub struct RecordContext<'a> {
    pub cfg: &'a AsterixConfig,
    pub system_ref: Option<LocalFrame>,
}

/// Builds a record from a track's state.
#[allow(clippy::too_many_arguments)]
pub fn record_of(
    ctx: &RecordContext<'_>,
    p: &Published,
    t: &TrackState,
    track_number: u16,
    first: bool,
    last: bool,
    first_t_s: f64,
    accel_mps2: Option<(f64, f64)>,
    mode3a_changed: bool,
    coasting: bool,
) -> TrackRecord {
    use crate::track::{Lateral, SpeedTrend, VerticalTrend};
    let est = &p.estimate;
    let movement = (
        match est.lateral {
            Lateral::Straight => Trans::ConstantCourse,
            Lateral::Right => Trans::RightTurn,
            Lateral::Left => Trans::LeftTurn,
        },
        match est.speed {
            SpeedTrend::Constant => Long::ConstantSpeed,
            SpeedTrend::Increasing => Long::Increasing,
            SpeedTrend::Decreasing => Long::Decreasing,
        },
        match est.vertical {
            VerticalTrend::Level => Vert::Level,
            VerticalTrend::Climb => Vert::Climb,
            VerticalTrend::Descent => Vert::Descent,
        },
    );
    let c = &t.pos_cov_enu_m2;
    let vc = &t.vel_cov_enu_m2ps2;
    let sd = |v: f64| v.max(0.0).sqrt();
    // Metres per degree of latitude and of longitude at the track (WGS-84 radii).
    let (m_per_deg_lat, m_per_deg_lon) = metres_per_degree(t.lat);
    let accuracies = Accuracies {
        x_m: sd(c[0][0]),
        y_m: sd(c[1][1]),
        xy_m2: c[0][1],
        lat_deg: sd(c[1][1]) / m_per_deg_lat,
        lon_deg: sd(c[0][0]) / m_per_deg_lon.max(1e-9),
        alt_ft: sd(c[2][2]) / FT_TO_M,
        vx_mps: sd(vc[0][0]),
        vy_mps: sd(vc[1][1]),
        rocd_fpm: sd(vc[2][2]) / FPM_TO_MPS,
    };
    let xy_m = ctx.system_ref.map(|f| {
        let v = f.to_enu(t.lat, t.lon, 0.0);
        (v.x, v.y)
    });
    TrackRecord {
        sac: ctx.cfg.sac,
        sic: ctx.cfg.sic,
        service_id: ctx.cfg.service_id,
        time_of_day_s: time_of_day_s(utc_of_feed_time(t.t)),
        lat_deg: t.lat,
        lon_deg: t.lon,
        xy_m,
        vx_mps: t.ve,
        vy_mps: t.vn,
        accel_mps2,
        mode3a: p.facts.squawk,
        mode3a_changed,
        track_number,
        first,
        last,
        coasting,
        on_ground: t.on_ground,
        track_age_s: (t.t - first_t_s).max(0.0),
        es_age_s: (t.t - t.last_seen).max(0.0),
        movement,
        measured_fl: t.baro_alt_ft.map(|a| f64::from(a) / 100.0),
        alt_ft: t.alt_m / FT_TO_M,
        rocd_fpm: t.vu / FPM_TO_MPS,
        address: t.icao.0,
        callsign: t.callsign.clone(),
        accuracies,
    }
}

/// Metres per degree of latitude and of longitude at `lat_deg` on the WGS-84 ellipsoid.
pub fn metres_per_degree(lat_deg: f64) -> (f64, f64) {
    const A_M: f64 = 6_378_137.0;
    const E2: f64 = 6.694_379_990_14e-3;
    let phi = lat_deg.to_radians();
    let s2 = phi.sin() * phi.sin();
    let w = (1.0 - E2 * s2).sqrt();
    let m = A_M * (1.0 - E2) / (w * w * w);
    let n = A_M / w;
    let per_rad_to_deg = std::f64::consts::PI / 180.0;
    (m * per_rad_to_deg, n * phi.cos() * per_rad_to_deg)
}

/// The UDP socket(s) and the resolved destinations.
pub struct UdpSender {
    v4: Option<UdpSocket>,
    v6: Option<UdpSocket>,
    destinations: Vec<SocketAddr>,
}

impl UdpSender {
    /// Resolves the destinations and binds a socket per address family they need.
    pub async fn bind(cfg: &AsterixConfig) -> std::io::Result<Self> {
        let mut destinations = Vec::new();
        for d in &cfg.destinations {
            let addr = tokio::net::lookup_host(d.as_str())
                .await?
                .next()
                .ok_or_else(|| {
                    std::io::Error::new(std::io::ErrorKind::NotFound, format!("{d}: no address"))
                })?;
            destinations.push(addr);
        }
        let v4 = if destinations.iter().any(SocketAddr::is_ipv4) {
            let s = UdpSocket::bind("0.0.0.0:0").await?;
            s.set_multicast_ttl_v4(cfg.multicast_ttl)?;
            Some(s)
        } else {
            None
        };
        let v6 = if destinations.iter().any(SocketAddr::is_ipv6) {
            Some(UdpSocket::bind("[::]:0").await?)
        } else {
            None
        };
        Ok(Self {
            v4,
            v6,
            destinations,
        })
    }

    /// Sends one datagram to every destination; returns how many sends succeeded.
    async fn send(&self, datagram: &[u8]) -> (u64, u64) {
        let (mut ok, mut failed) = (0, 0);
        for d in &self.destinations {
            let sock = if d.is_ipv4() { &self.v4 } else { &self.v6 };
            let Some(sock) = sock else { continue };
            match sock.send_to(datagram, d).await {
                Ok(_) => ok += 1,
                Err(e) => {
                    failed += 1;
                    tracing::debug!(error = %e, dest = %d, "CAT062 datagram not sent");
                }
            }
        }
        (ok, failed)
    }
}

/// One tracked aircraft, as the CAT062 output knows it.
struct Entry {
    number: u16,
    /// Feed time of its first update, s.
    first_t_s: f64,
    /// Its newest snapshot, and whether it is newer than the last record sent.
    latest: Arc<Published>,
    updated: bool,
    /// A record has been sent (the next is not the first).
    announced: bool,
    /// Time and velocity (east, north) of the last record sent, for I062/210.
    last_sent: Option<(f64, f64, f64)>,
    last_squawk: Option<u16>,
    retired: bool,
}

/// The CAT062 output's state: the tracks and their numbers.
pub struct Cat062 {
    cfg: AsterixConfig,
    system_ref: Option<LocalFrame>,
    numbers: TrackNumbers,
    tracks: HashMap<Icao, Entry>,
    /// The newest feed time of any update, s: the time coasting tracks are extrapolated to.
    feed_now_s: f64,
}

impl Cat062 {
    pub fn new(cfg: AsterixConfig) -> Self {
        let system_ref = cfg
            .system_ref
            .map(|r| LocalFrame::new(r.lat_deg, r.lon_deg, 0.0));
        Self {
            cfg,
            system_ref,
            numbers: TrackNumbers::default(),
            tracks: HashMap::new(),
            feed_now_s: f64::NEG_INFINITY,
        }
    }

    /// Takes one pipeline event.
    pub fn event(&mut self, e: OutputEvent) {
        match e {
            OutputEvent::Update(p) => {
                self.feed_now_s = self.feed_now_s.max(p.estimate.t_s);
                if let Some(entry) = self.tracks.get_mut(&p.icao) {
                    entry.latest = p;
                    entry.updated = true;
                    entry.retired = false;
                    return;
                }
                let Some(number) = self.numbers.take() else {
                    return;
                };
                self.tracks.insert(
                    p.icao,
                    Entry {
                        number,
                        first_t_s: p.estimate.t_s,
                        latest: p,
                        updated: true,
                        announced: false,
                        last_sent: None,
                        last_squawk: None,
                        retired: false,
                    },
                );
            }
            OutputEvent::Retired(icao) => {
                if let Some(e) = self.tracks.get_mut(&icao) {
                    e.retired = true;
                }
            }
        }
    }

    /// The records of one period: every updated track, and a last record of every retired
    /// one (whose number is then free); sorted by track number.
    pub fn period_records(&mut self) -> Vec<TrackRecord> {
        let ctx = RecordContext {
            cfg: &self.cfg,
            system_ref: self.system_ref,
        };
        let mut out = Vec::new();
        let mut gone = Vec::new();
        for (icao, e) in self.tracks.iter_mut() {
            // A live track without an update for `coast_after_s` of feed time is sent every
            // period as coasting (I062/080 CST), extrapolated along its velocity.
            let coasting = !(e.updated || e.retired)
                && self.feed_now_s - e.latest.estimate.t_s > self.cfg.coast_after_s;
            if !(e.updated || e.retired || coasting) {
                continue;
            }
            let extrapolated;
            let p: &Published = if coasting {
                let mut q = (*e.latest).clone();
                let dt_s = self.feed_now_s - q.estimate.t_s;
                q.estimate.pos_m += q.estimate.vel_mps * dt_s;
                q.estimate.t_s = self.feed_now_s;
                extrapolated = q;
                &extrapolated
            } else {
                &e.latest
            };
            let t = p.track_state();
            let has_accel = !coasting && matches!(t.mode, "CA" | "CT" | "CHCA");
            let accel = match e.last_sent {
                Some((t0, ve0, vn0)) if has_accel && t.t - t0 >= 0.5 => {
                    let dt = t.t - t0;
                    Some(((t.ve - ve0) / dt, (t.vn - vn0) / dt))
                }
                _ => None,
            };
            let changed = e.last_squawk.is_some() && e.last_squawk != e.latest.facts.squawk;
            out.push(record_of(
                &ctx,
                p,
                &t,
                e.number,
                !e.announced,
                e.retired,
                e.first_t_s,
                accel,
                changed,
                coasting,
            ));
            e.announced = true;
            e.updated = false;
            e.last_sent = Some((t.t, t.ve, t.vn));
            e.last_squawk = e.latest.facts.squawk;
            if e.retired {
                gone.push(*icao);
            }
        }
        for icao in gone {
            if let Some(e) = self.tracks.remove(&icao) {
                self.numbers.release(e.number);
            }
        }
        out.sort_by_key(|r| r.track_number);
        out
    }
}

/// Sends `[output.asterix]` until shutdown.
pub async fn run(
    sender: UdpSender,
    cfg: AsterixConfig,
    mut rx: broadcast::Receiver<OutputEvent>,
    stats: Arc<OutputStats>,
    shutdown: CancellationToken,
) {
    let lagged = stats.updates_lagged(Output::Asterix);
    let sent = stats.messages_sent(Output::Asterix);
    let datagrams = stats.datagrams_sent(Output::Asterix);
    let errors = stats.errors(Output::Asterix);
    let period = Duration::try_from_secs_f64(cfg.period_s).unwrap_or(Duration::from_secs(1));
    let max_bytes = cfg.max_datagram_bytes;
    let mut state = Cat062::new(cfg);
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut pipeline_open = true;
    let counters = (sent, datagrams, errors);
    loop {
        tokio::select! {
            biased;
            _ = shutdown.cancelled() => {
                // What the pipeline sent before it stopped (the last updates, the
                // retirements at the end of a replay) goes out in one last period.
                while let Some(e) = try_recv_counting(&mut rx, &lagged) {
                    state.event(e);
                }
                send_period(&mut state, &sender, max_bytes, &counters).await;
                break;
            }
            _ = tick.tick() => send_period(&mut state, &sender, max_bytes, &counters).await,
            e = recv_counting(&mut rx, &lagged), if pipeline_open => match e {
                Some(e) => state.event(e),
                None => pipeline_open = false,
            },
        }
    }
}

/// Encodes and sends one period's records; counts records, datagrams and failed sends.
async fn send_period(
    state: &mut Cat062,
    sender: &UdpSender,
    max_bytes: usize,
    (sent, datagrams, errors): &(Counter, Counter, Counter),
) {
    let records = state.period_records();
    if records.is_empty() {
        return;
    }
    let encoded: Vec<Vec<u8>> = records
        .iter()
        .map(|r| {
            let mut b = Vec::with_capacity(96);
            r.encode(&mut b);
            b
        })
        .collect();
    for (block, n) in data_blocks(&encoded, max_bytes) {
        let (ok, failed) = sender.send(&block).await;
        datagrams.inc_by(ok);
        sent.inc_by(n * ok);
        errors.inc_by(failed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record() -> TrackRecord {
        TrackRecord {
            sac: 25,
            sic: 1,
            service_id: 1,
            time_of_day_s: 24_189.5,
            lat_deg: 43.5,
            lon_deg: 1.25,
            xy_m: Some((1000.0, -2000.5)),
            vx_mps: 100.0,
            vy_mps: -50.25,
            accel_mps2: Some((1.0, -0.5)),
            mode3a: Some(0o1000),
            mode3a_changed: false,
            track_number: 7,
            first: true,
            last: false,
            coasting: false,
            on_ground: false,
            track_age_s: 100.0,
            es_age_s: 0.5,
            movement: (Trans::LeftTurn, Long::Increasing, Vert::Climb),
            measured_fl: Some(350.0),
            alt_ft: 35_000.0,
            rocd_fpm: 1500.0,
            address: 0x39_33_22,
            callsign: Some("AFR34ZG".into()),
            accuracies: Accuracies {
                x_m: 10.0,
                y_m: 12.0,
                xy_m2: -4.0,
                lat_deg: 1e-4,
                lon_deg: 2e-4,
                alt_ft: 25.0,
                vx_mps: 1.0,
                vy_mps: 1.5,
                rocd_fpm: 100.0,
            },
        }
    }

    #[test]
    fn fspec_bits() {
        assert_eq!(fspec(1), vec![0x80]);
        assert_eq!(fspec(1 << 7), vec![0x01, 0x80]);
        // FRNs 1, 3, 4 and 27.
        assert_eq!(fspec(0b1101 | (1 << 26)), vec![0xB1, 0x01, 0x01, 0x04]);
    }

    #[test]
    fn identification_is_six_bit_ia5() {
        // "A" = 1, space = 32: 000001 100000 ... in 48 bits.
        let b = identification("A");
        assert_eq!(b[0], 0b0000_0110);
        assert_eq!(identification("AFR34ZG "), identification("afr34zg"));
    }

    #[test]
    fn record_items_have_their_lsbs() {
        let mut b = Vec::new();
        record().encode(&mut b);
        // FSPEC: FRNs 1,3,4,5,6,7 | 8,9,11,12,13,14 | 15,17,18,19,20 | 27.
        assert_eq!(
            &b[..4],
            &[0b1011_1111, 0b1101_1111, 0b1011_1101, 0b0000_0100]
        );
        if let Ok(path) = std::env::var("CAT062_DUMP") {
            let block = data_blocks(&[b.clone()], 1400);
            std::fs::write(path, &block[0].0).unwrap();
        }
        let items = &b[4..];
        assert_eq!(&items[..3], &[25, 1, 1]);
        // 24189.5 s * 128 = 3096256 = 0x2F3EC0.
        assert_eq!(&items[3..6], &[0x2F, 0x3E, 0xC0]);
        // 43.5 deg / (180/2^25) = 8108987.7 -> 8108988.
        let lat = i32::from_be_bytes([items[6], items[7], items[8], items[9]]);
        assert_eq!(lat, 8_108_988);
        // X 1000 m = 2000 LSB; Y -2000.5 m = -4001 LSB.
        assert_eq!(&items[14..17], &[0x00, 0x07, 0xD0]);
        let y = i32::from_be_bytes([0xff, items[17], items[18], items[19]]);
        assert_eq!(y, -4001);
        // Vx 100 m/s = 400; Vy -50.25 = -201.
        assert_eq!(i16::from_be_bytes([items[20], items[21]]), 400);
        assert_eq!(i16::from_be_bytes([items[22], items[23]]), -201);
        // Ax 1.0 = 4, Ay -0.5 = -2.
        assert_eq!((items[24] as i8, items[25] as i8), (4, -2));
        // Mode 3/A 1000 octal.
        assert_eq!(u16::from_be_bytes([items[26], items[27]]), 0o1000);
        // I062/380: ADR and ID.
        assert_eq!(items[28], 0xC0);
        assert_eq!(&items[29..32], &[0x39, 0x33, 0x22]);
        assert_eq!(&items[32..38], &identification("AFR34ZG"));
        // Track number 7.
        assert_eq!(&items[38..40], &[0, 7]);
        // Track status: MON, TSB, ..., PSR SSR MDS no update, SDS co-operative.
        assert_eq!(&items[40..46], &[0x81, 0x21, 0x01, 0x71, 0x41, 0x00]);
        // Ages: TRK 100 s capped at 63.75 s (255), ES 0.5 s (2).
        assert_eq!(&items[46..49], &[0x84, 255, 2]);
        // Mode of movement: left turn (2), increasing (1), climb (1).
        assert_eq!(items[49], 0b1001_0100);
        // FL 350 = 1400 quarter-FL; 35000 ft / 6.25 = 5600; CTB 1400; 1500 fpm / 6.25 = 240.
        assert_eq!(i16::from_be_bytes([items[50], items[51]]), 1400);
        assert_eq!(i16::from_be_bytes([items[52], items[53]]), 5600);
        assert_eq!(u16::from_be_bytes([items[54], items[55]]), 1400);
        assert_eq!(i16::from_be_bytes([items[56], items[57]]), 240);
        // Accuracies.
        assert_eq!(&items[58..60], &[0xFD, 0x80]);
        assert_eq!(u16::from_be_bytes([items[60], items[61]]), 20);
        assert_eq!(u16::from_be_bytes([items[62], items[63]]), 24);
        assert_eq!(i16::from_be_bytes([items[64], items[65]]), -4);
        assert_eq!(items.len(), 60 + 4 + 2 + 4 + 1 + 1 + 2 + 1);
    }

    #[test]
    fn out_of_range_values_are_clamped() {
        let mut r = record();
        r.vx_mps = 1e9;
        r.lat_deg = f64::NAN;
        r.accel_mps2 = Some((-100.0, 100.0));
        let mut b = Vec::new();
        r.encode(&mut b);
        let items = &b[4..];
        assert_eq!(&items[6..10], &[0, 0, 0, 0]);
        assert_eq!(i16::from_be_bytes([items[20], items[21]]), i16::MAX);
        assert_eq!((items[24] as i8, items[25] as i8), (-127, 127));
    }

    #[test]
    fn blocks_are_split_and_sized() {
        let recs: Vec<Vec<u8>> = (0..10).map(|i| vec![i; 100]).collect();
        let blocks = data_blocks(&recs, 350);
        assert_eq!(blocks.len(), 4);
        assert_eq!(blocks.iter().map(|b| b.1).sum::<u64>(), 10);
        for (b, _) in &blocks {
            assert_eq!(b[0], 62);
            assert_eq!(usize::from(u16::from_be_bytes([b[1], b[2]])), b.len());
            assert!(b.len() <= 350);
        }
        assert_eq!((blocks[0].0.len(), blocks[0].1), (303, 3));
        assert_eq!((blocks[3].0.len(), blocks[3].1), (103, 1));
    }

    #[test]
    fn track_numbers_are_reused_only_after_all_new_ones() {
        let mut n = TrackNumbers::default();
        assert_eq!(n.take(), Some(0));
        assert_eq!(n.take(), Some(1));
        n.release(0);
        assert_eq!(n.take(), Some(2));
        n.next = 65_536;
        assert_eq!(n.take(), Some(0));
        assert_eq!(n.take(), None);
    }
    fn published(icao: u32, t_s: f64, east_m: f64, ve_mps: f64) -> Arc<Published> {
        use crate::daemon::registry::AircraftFacts;
        use crate::track::{Estimate, FlightMode};
        use nalgebra::{Matrix3, Vector3};
        Arc::new(Published {
            icao: Icao(icao),
            frame: LocalFrame::new(49.0, 2.5, 0.0),
            estimate: Estimate {
                t_s,
                pos_m: Vector3::new(east_m, 0.0, 3000.0),
                vel_mps: Vector3::new(ve_mps, 0.0, 0.0),
                pos_cov_m2: Matrix3::from_diagonal_element(100.0),
                vel_cov_m2ps2: Matrix3::from_diagonal_element(4.0),
                mode: FlightMode::Cv,
                mode_probabilities: [1.0, 0.0, 0.0, 0.0, 0.0],
                filter: "kalman-cv",
                diverging: false,
                divergence_events: 0,
                outlier_positions: 0,
                turn: None,
                lateral: Default::default(),
                speed: Default::default(),
                vertical: Default::default(),
                nis: None,
            },
            facts: AircraftFacts {
                squawk: Some(0o7700),
                ..AircraftFacts::default()
            },
            predictions: Vec::new(),
        })
    }

    fn config() -> AsterixConfig {
        crate::config::Config::from_toml_str(
            "[output.asterix]\ndestinations = [\"127.0.0.1:8600\"]\nsac = 25\nsic = 1\nperiod_s = 1.0\n",
        )
        .unwrap()
        .output
        .asterix
        .unwrap()
    }

    #[test]
    fn tracks_are_created_coasted_terminated_and_numbered() {
        // Feed times that are Unix times (2024-07-06), as the records' time of day needs.
        const T0: f64 = 1_720_248_189.5;
        let mut c = Cat062::new(config());
        c.event(OutputEvent::Update(published(0xA, T0, 0.0, 200.0)));
        c.event(OutputEvent::Update(published(0xB, T0, 0.0, 100.0)));
        let r = c.period_records();
        assert_eq!(r.len(), 2);
        assert!(r.iter().all(|r| r.first && !r.last && !r.coasting));
        assert_eq!((r[0].address, r[0].track_number), (0xA, 0));
        assert_eq!((r[1].address, r[1].track_number), (0xB, 1));
        assert_eq!(r[0].mode3a, Some(0o7700));
        // Nothing new: nothing sent.
        assert!(c.period_records().is_empty());
        // B is updated 10 s later; A, silent past coast_after_s (5 s), coasts: extrapolated
        // 10 s at 200 m/s east.
        c.event(OutputEvent::Update(published(
            0xB,
            T0 + 10.0,
            1000.0,
            100.0,
        )));
        let r = c.period_records();
        assert_eq!(r.len(), 2);
        let (a, b) = (&r[0], &r[1]);
        assert!(a.coasting && !a.first && !b.coasting && !b.first);
        assert!((a.time_of_day_s - b.time_of_day_s).abs() < 1e-9);
        let (_, m_per_deg_lon) = metres_per_degree(49.0);
        assert!(
            ((a.lon_deg - 2.5) * m_per_deg_lon - 2000.0).abs() < 1.0,
            "{}",
            a.lon_deg
        );
        assert!((b.track_age_s - 10.0).abs() < 1e-9);
        // A retires: one last record, then its number waits behind every unused one.
        c.event(OutputEvent::Retired(Icao(0xA)));
        let r = c.period_records();
        assert_eq!(r.len(), 1);
        assert!(r[0].last && r[0].address == 0xA);
        assert!(c.period_records().iter().all(|r| r.address != 0xA));
        c.event(OutputEvent::Update(published(0xC, T0 + 11.0, 0.0, 100.0)));
        let r = c.period_records();
        let cr = r.iter().find(|r| r.address == 0xC).unwrap();
        assert_eq!(cr.track_number, 2);
    }
}
