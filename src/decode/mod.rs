//! Decoding: [`RawFrame`] -> [`Decoded`] (CRC, downlink format, extended-squitter fields).
//!
//! The hot path reads the fields the daemon uses with our own zero-allocation bit reading
//! ([`adsb`]); adsb_deku serves [`inspect`] and the differential tests only (it costs
//! microseconds and dozens of allocations a frame, and misreads several fields: see the
//! pipeline issue and `tests/differential_deku.rs`).

pub mod adsb;
pub mod bits;
pub mod cpr;
pub mod crc;
pub mod inspect;

#[allow(unused_imports)]
use crate::feed::RawFrame;
use serde::Serialize;
use std::fmt;

/// A 24-bit ICAO aircraft address.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Icao(pub u32);

impl fmt::Display for Icao {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:06x}", self.0 & 0xFF_FFFF)
    }
}

impl std::str::FromStr for Icao {
    type Err = String;
    /// Exactly six hex digits, either case.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.len() != 6 || !s.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(format!("{s:?} is not an ICAO address (6 hex digits)"));
        }
        u32::from_str_radix(s, 16)
            .map(Icao)
            .map_err(|e| e.to_string())
    }
}

impl Serialize for Icao {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// An 8-character callsign as transmitted (ICAO 6-bit charset, DO-260B §2.2.3.2.5),
/// trailing spaces kept in the array and trimmed by [`Callsign::as_str`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Callsign(pub [u8; 8]);

impl Callsign {
    /// The callsign without trailing spaces.
    pub fn as_str(&self) -> &str {
        std::str::from_utf8(&self.0).unwrap_or("").trim_end()
    }
}

/// One CPR-encoded position report (17-bit latitude and longitude, DO-260B §A.1.7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cpr {
    /// YZ: encoded latitude, 0..2^17.
    pub lat: u32,
    /// XZ: encoded longitude, 0..2^17.
    pub lon: u32,
    /// F: false for an even frame, true for odd.
    pub odd: bool,
}

/// Which altitude an airborne position carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum AltitudeSource {
    /// Barometric pressure altitude (TC 9-18), feet above the 1013.25 hPa level.
    Baro,
    /// GNSS height above the WGS-84 ellipsoid (TC 20-22).
    Gnss,
}

/// Source of a velocity message's vertical rate (ME bit 36; 0 = GNSS, as dump1090 and
/// pyModeS read DO-260B §2.2.3.2.6.1.13).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum VerticalRateSource {
    Gnss,
    Baro,
}

/// Airborne velocity (DF17/18 TC 19), subtypes 1-4.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Velocity {
    /// Subtype 1-4 (1/2: ground speed, 3/4: airspeed and heading; 2/4 supersonic, x4 units).
    pub subtype: u8,
    /// Ground velocity east and north in knots (subtypes 1, 2), if available.
    pub ground_kt: Option<(f64, f64)>,
    /// Magnetic heading in degrees (subtypes 3, 4), if available.
    pub heading_deg: Option<f64>,
    /// Airspeed in knots (subtypes 3, 4), and whether it is true (else indicated).
    pub airspeed_kt: Option<(f64, bool)>,
    /// Vertical rate in feet per minute, positive up, if available.
    pub vrate_fpm: Option<i32>,
    /// Source of the vertical rate.
    pub vrate_source: VerticalRateSource,
    /// GNSS height minus barometric altitude in feet, if available.
    pub gnss_minus_baro_ft: Option<i32>,
    /// Navigation accuracy category for velocity (NUCr/NACv, 3 bits).
    pub nac_v: u8,
}

/// The messages the daemon uses; everything else is counted by DF/TC and dropped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message {
    /// DF11 all-call reply (capability).
    AllCall { capability: u8 },
    /// DF4/20 surveillance altitude, feet (None when not available or metric).
    Altitude { alt_ft: Option<i32> },
    /// DF5/21 identity (squawk as its four octal digits, e.g. 7700 -> 0o7700).
    Squawk { squawk: u16 },
    /// TC 1-4 identification and category.
    Identification {
        /// Emitter category set (TC) and category (CA), e.g. (4, 3) = A3.
        category: (u8, u8),
        callsign: Callsign,
    },
    /// TC 9-18 (barometric) and 20-22 (GNSS) airborne position.
    AirbornePosition {
        type_code: u8,
        alt_ft: Option<i32>,
        alt_source: AltitudeSource,
        cpr: Cpr,
    },
    /// TC 5-8 surface position.
    SurfacePosition {
        type_code: u8,
        /// Ground speed in knots from the movement field (None: not available).
        speed_kt: Option<f64>,
        /// Ground track in degrees (None: not valid).
        track_deg: Option<f64>,
        cpr: Cpr,
    },
    /// TC 19 airborne velocity.
    Velocity(Velocity),
    /// TC 31 operational status.
    OperationalStatus {
        /// ADS-B version number (0, 1, 2).
        version: u8,
        /// Navigation accuracy category for position (versions 1, 2).
        nac_p: Option<u8>,
        /// NIC supplement-A.
        nic_supp_a: bool,
        /// Source integrity level.
        sil: u8,
    },
    /// TC 28 subtype 1: emergency state and squawk.
    Emergency { state: u8, squawk: u16 },
    /// A DF17/18 type code the daemon does not use (counted by type code).
    Other { type_code: u8 },
}

/// A frame that decoded: who sent it and what it said.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Decoded {
    /// Feed time in seconds.
    pub time_s: f64,
    pub icao: Icao,
    /// Downlink format.
    pub df: u8,
    /// Signal level byte, if the feed carries one.
    pub signal: Option<u8>,
    /// Number of bits the CRC repaired (0 for a clean frame).
    pub corrected_bits: u8,
    pub msg: Message,
}
