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
pub mod reports;

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
/// trailing spaces kept in the array and trimmed by [`Callsign::as_str`]. (Serialised as its
/// bytes, in a cluster's track values.)
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
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
    /// The 56-bit ME field of a DF17/18 frame, as repaired; 0 for other formats. With the
    /// address and the format, the whole content of an extended squitter: what a second
    /// copy of one transmission is recognised by (`Aircraft::is_copy`).
    pub me: u64,
}

/// A frame the [`Decoder`] accepted, its message not yet read: who sent it, when, and the
/// bits the message is read from ([`Heard::decoded`]). 24 bytes where a [`Decoded`] takes 104.
///
/// This is what the router hands each aircraft: the checks that need the decoder's state (the
/// CRC, the table of recently heard addresses) stay in the one router task, and the message is
/// read in the aircraft's task, on whichever core runs it. Reading it in the router and moving
/// the 104-byte result on (into the aircraft's pending messages, then its batch) cost a
/// `kalman-cv` fleet replay about a sixth of its cycles in stalls: the message, just written
/// field by field, was copied with wide loads the processor cannot forward from the narrow
/// stores still in flight (`perf annotate`: 78 % of `Decoder::decode`'s samples on one load),
/// and 1000 aircraft's pending messages outgrew the 1 MiB second-level cache.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Heard {
    /// Feed time in seconds.
    pub time_s: f64,
    /// What the message is read from: the 56-bit ME field of a DF17/18 frame (as repaired),
    /// the 13-bit field of bits 20-32 of DF0/4/16/20 (altitude) and DF5/21 (identity), the
    /// capability of DF11.
    pub payload: u64,
    pub icao: Icao,
    /// Downlink format.
    pub df: u8,
    /// Signal level byte, if the feed carries one.
    pub signal: Option<u8>,
    /// Number of bits the CRC repaired (0 for a clean frame).
    pub corrected_bits: u8,
}

impl Heard {
    /// The frame's message, read from its payload.
    #[inline(always)]
    pub fn message(&self) -> Message {
        match self.df {
            17 | 18 => adsb::decode_me(bits::Me::from_raw(self.payload)),
            0 | 4 | 16 | 20 => Message::Altitude {
                alt_ft: adsb::ac13_ft(self.payload as u32),
            },
            5 | 21 => Message::Squawk {
                squawk: adsb::id13_squawk(self.payload as u32),
            },
            _ => Message::AllCall {
                capability: self.payload as u8,
            },
        }
    }

    /// The frame decoded: [`Decoder::decode`]'s result for it.
    #[inline(always)]
    pub fn decoded(&self) -> Decoded {
        Decoded {
            time_s: self.time_s,
            icao: self.icao,
            df: self.df,
            signal: self.signal,
            corrected_bits: self.corrected_bits,
            msg: self.message(),
            me: if matches!(self.df, 17 | 18) {
                self.payload
            } else {
                0
            },
        }
    }
}

/// How the [`Decoder`] treats damaged frames and short replies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecoderConfig {
    /// Repair DF17/18 frames whose CRC syndrome matches a single flipped bit (never bits 1-5,
    /// the downlink format). Default true, as readsb and dump1090 do by default.
    pub fix_single_bit: bool,
    /// How long, in seconds of feed time, an address heard in a clean DF11/17/18 frame keeps
    /// DF0/4/5/16/20/21 replies with that address acceptable. Default 60 s.
    pub recent_address_s: f64,
}

impl Default for DecoderConfig {
    fn default() -> Self {
        Self {
            fix_single_bit: true,
            recent_address_s: 60.0,
        }
    }
}

/// Why a frame gave no [`Decoded`]: every case is counted in [`DecodeStats`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Skip {
    /// A 2-byte Mode A/C reply: no address, nothing to decode.
    #[error("Mode A/C reply")]
    ModeAc,
    /// The length does not match the downlink format (DF 0-15: 56 bits, DF 16-31: 112 bits).
    #[error("length does not match the downlink format")]
    WrongLength,
    /// DF11/17/18 parity does not check (and could not be repaired).
    #[error("CRC does not check")]
    BadCrc,
    /// Address/Parity reply (DF0/4/5/16/20/21) whose address was not heard recently in a clean
    /// DF11/17/18: most likely noise, whose syndrome is a random "address".
    #[error("address not heard recently")]
    UnknownAddress,
    /// A downlink format this decoder does not use (DF19 military, DF24+ Comm-D, unassigned).
    #[error("downlink format not decoded")]
    UnsupportedDf,
    /// DF18 with a control field other than 0/1 (ADS-B ES/NT) or 6 (ADS-R): TIS-B formats.
    #[error("DF18 control field not decoded")]
    UnsupportedCf,
}

/// What the decoder saw, counted. Serialised as is into the stats endpoint.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct DecodeStats {
    /// Frames handed to [`Decoder::decode`].
    pub frames: u64,
    /// Frames that gave a [`Decoded`].
    pub decoded: u64,
    /// Mode S frames (not Mode A/C) by downlink format, counted before any check.
    pub by_df: [u64; 32],
    /// Decoded DF17/18 frames by ME type code.
    pub by_tc: [u64; 32],
    /// 2-byte Mode A/C replies ([`Skip::ModeAc`]).
    pub mode_ac: u64,
    /// [`Skip::WrongLength`].
    pub wrong_length: u64,
    /// DF11/17/18 frames rejected on CRC ([`Skip::BadCrc`]).
    pub crc_rejected: u64,
    /// DF17/18 frames accepted after repairing one bit (counted in `decoded` as well).
    pub crc_fixed: u64,
    /// [`Skip::UnknownAddress`].
    pub unknown_address: u64,
    /// [`Skip::UnsupportedDf`].
    pub unsupported_df: u64,
    /// [`Skip::UnsupportedCf`].
    pub unsupported_cf: u64,
    /// Clean addresses that found no free slot in the recent-address table (it holds
    /// [`RECENT_SLOTS`] addresses; each is only probed near its hash).
    pub address_table_full: u64,
}

/// Slots in the recent-address table: room for thousands of aircraft heard within
/// `recent_address_s`, allocated once.
pub const RECENT_SLOTS: usize = 1 << 14;
/// Longest probe sequence of the recent-address table: bounds the cost of every lookup.
const RECENT_MAX_PROBE: usize = 32;
/// A never-used slot (ICAO addresses are 24-bit).
const EMPTY_ADDRESS: u32 = u32::MAX;

/// Addresses heard in clean DF11/17/18 frames and when, in feed time: readsb's ICAO filter,
/// which keeps Address/Parity replies from inventing aircraft out of noise.
///
/// Open addressing with linear probing over a table allocated once: lookups and refreshes
/// never allocate. An expired entry is reused by the next insertion that probes past it, so
/// the table does not fill with departed aircraft.
struct RecentAddresses {
    slots: Box<[(u32, f64)]>,
}

impl RecentAddresses {
    fn new() -> Self {
        Self {
            slots: vec![(EMPTY_ADDRESS, f64::NEG_INFINITY); RECENT_SLOTS].into_boxed_slice(),
        }
    }

    /// Fibonacci hashing of the 24-bit address onto the table.
    fn home(address: u32) -> usize {
        (address.wrapping_mul(0x9E37_79B9) >> (32 - RECENT_SLOTS.trailing_zeros())) as usize
    }

    fn probe(address: u32) -> impl Iterator<Item = usize> {
        let home = Self::home(address);
        (0..RECENT_MAX_PROBE).map(move |i| (home + i) % RECENT_SLOTS)
    }

    /// Whether `address` was heard within `window_s` before `now_s`. A time in the future of
    /// `now_s` (a replay that restarted) counts as recent.
    fn contains(&self, address: u32, now_s: f64, window_s: f64) -> bool {
        for i in Self::probe(address) {
            match self.slots.get(i) {
                Some(&(a, t)) if a == address => return is_recent(t, now_s, window_s),
                Some(&(EMPTY_ADDRESS, _)) | None => return false,
                Some(_) => {}
            }
        }
        false
    }

    /// Records `address` as heard at `now_s`; false when no slot was free.
    fn refresh(&mut self, address: u32, now_s: f64, window_s: f64) -> bool {
        let mut free = None;
        for i in Self::probe(address) {
            match self.slots.get(i) {
                Some(&(a, _)) if a == address => {
                    free = Some(i);
                    break;
                }
                Some(&(EMPTY_ADDRESS, _)) => {
                    free = free.or(Some(i));
                    break;
                }
                Some(&(_, t)) if free.is_none() && !is_recent(t, now_s, window_s) => free = Some(i),
                _ => {}
            }
        }
        match free.and_then(|i| self.slots.get_mut(i)) {
            Some(slot) => {
                *slot = (address, now_s);
                true
            }
            None => false,
        }
    }
}

/// Whether an address last heard at `heard_s` is still recent at `now_s`. NaN times are never
/// recent; a time after `now_s` (a replay that restarted) is.
fn is_recent(heard_s: f64, now_s: f64, window_s: f64) -> bool {
    now_s - heard_s <= window_s
}

/// Single-bit error syndromes of a 112-bit frame, sorted: `(syndrome, bit)` for bits 6-112.
///
/// The CRC is linear, so a frame with one flipped bit has the syndrome of that bit alone:
/// x^(112 - bit) mod G(x) (Annex 10 Vol IV §3.1.2.3.3), for parity bits and data bits alike.
/// Bits 1-5 (the downlink format) are left out: "repairing" them would turn a damaged frame
/// of one format into another. The 107 syndromes are distinct (unit test), so a match is
/// unambiguous. Built at compile time.
static SINGLE_BIT_SYNDROMES: [(u32, u8); 107] = single_bit_syndromes();

const fn single_bit_syndromes() -> [(u32, u8); 107] {
    let mut table = [(0u32, 0u8); 107];
    let mut syndrome: u32 = 1; // x^0: bit 112, the last parity bit
    let mut bit: u32 = 112;
    let mut i = 0;
    while bit >= 6 {
        table[i] = (syndrome, bit as u8);
        i += 1;
        bit -= 1;
        syndrome <<= 1;
        if syndrome & 0x100_0000 != 0 {
            syndrome ^= 0x100_0000 | crc::GENERATOR;
        }
    }
    // Insertion sort by syndrome, for binary search.
    let mut j = 1;
    while j < table.len() {
        let mut k = j;
        while k > 0 && table[k - 1].0 > table[k].0 {
            let tmp = table[k - 1];
            table[k - 1] = table[k];
            table[k] = tmp;
            k -= 1;
        }
        j += 1;
    }
    table
}

/// The bit (1-based, 6..=112) whose flip explains `syndrome` in a 112-bit frame, if any.
pub fn single_bit_error(syndrome: u32) -> Option<u8> {
    SINGLE_BIT_SYNDROMES
        .binary_search_by_key(&syndrome, |&(s, _)| s)
        .ok()
        .and_then(|i| SINGLE_BIT_SYNDROMES.get(i))
        .map(|&(_, bit)| bit)
}

/// Mode S frames -> [`Decoded`] with readsb's acceptance rules, counting everything it skips.
///
/// Holds the recent-address table (allocated once in [`Decoder::new`]); `decode` itself
/// never allocates.
pub struct Decoder {
    cfg: DecoderConfig,
    stats: DecodeStats,
    recent: RecentAddresses,
}

impl Decoder {
    pub fn new(cfg: DecoderConfig) -> Self {
        Self {
            cfg,
            stats: DecodeStats::default(),
            recent: RecentAddresses::new(),
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> &DecodeStats {
        &self.stats
    }

    /// Decodes one frame. Checks, in order: Mode A/C, length against the DF, then per DF:
    ///
    /// - DF17/18: CRC syndrome must be 0, or (with `fix_single_bit`) explained by one flipped
    ///   bit outside the DF; a repair inside the address (bits 9-32) is kept only if the
    ///   repaired address was heard recently. DF18 only with CF 0, 1 or 6. The ME field then
    ///   goes to [`adsb::decode_me`].
    /// - DF11: syndrome 0, or only an interrogator code in its low 7 bits (Annex 10 Vol IV
    ///   §3.1.2.3.3.2: PI = parity XOR the interrogator's II/SI code); with a non-zero
    ///   interrogator code the address must have been heard recently, as a lone interrogated
    ///   reply is not enough to start an aircraft.
    /// - DF0/4/16/20 (altitude) and DF5/21 (identity): the syndrome is the address
    ///   (Address/Parity), accepted only if heard within `recent_address_s`.
    ///
    /// Clean DF11 (interrogator 0), DF17 and DF18 with CF 0 or 6 (the CFs whose AA is an ICAO
    /// address, as readsb takes them) refresh the recent-address table; repaired frames do
    /// not.
    pub fn decode(&mut self, frame: &RawFrame) -> Result<Decoded, Skip> {
        self.accept(frame).map(|h| h.decoded())
    }

    /// [`Decoder::decode`]'s checks and counts, without reading the message: what the router
    /// does, leaving the reading to the aircraft's task ([`Heard`]).
    #[inline(always)]
    pub fn accept(&mut self, frame: &RawFrame) -> Result<Heard, Skip> {
        self.stats.frames += 1;
        let result = self.accept_frame(frame);
        let stats = &mut self.stats;
        match result {
            Ok(ref d) => {
                stats.decoded += 1;
                if d.corrected_bits > 0 {
                    stats.crc_fixed += 1;
                }
            }
            Err(Skip::ModeAc) => stats.mode_ac += 1,
            Err(Skip::WrongLength) => stats.wrong_length += 1,
            Err(Skip::BadCrc) => stats.crc_rejected += 1,
            Err(Skip::UnknownAddress) => stats.unknown_address += 1,
            Err(Skip::UnsupportedDf) => stats.unsupported_df += 1,
            Err(Skip::UnsupportedCf) => stats.unsupported_cf += 1,
        }
        result
    }

    #[inline(always)]
    fn accept_frame(&mut self, frame: &RawFrame) -> Result<Heard, Skip> {
        if frame.is_mode_ac() {
            return Err(Skip::ModeAc);
        }
        let bytes = frame.bytes();
        let df = bytes.first().map(|b| b >> 3).ok_or(Skip::WrongLength)?;
        if let Some(n) = self.stats.by_df.get_mut(usize::from(df)) {
            *n += 1;
        }
        // Annex 10 Vol IV §3.1.2.3.2.1.2: formats 0-15 are 56 bits, 16-31 are 112 bits.
        let expected_len = if df >= 16 { 14 } else { 7 };
        if bytes.len() != expected_len {
            return Err(Skip::WrongLength);
        }
        let now_s = frame.time_s;
        let heard = |icao: u32, corrected_bits: u8, payload: u64| Heard {
            time_s: now_s,
            payload,
            icao: Icao(icao),
            df,
            signal: frame.signal,
            corrected_bits,
        };
        match df {
            0 | 4 | 16 | 20 | 5 | 21 => {
                let icao = self.address_parity(bytes, now_s)?;
                // Altitude (AC13) or identity (ID13): the same 13 bits.
                let field = bits::field(bytes, 20, 32).ok_or(Skip::WrongLength)?;
                Ok(heard(icao, 0, u64::from(field)))
            }
            11 => {
                let (icao, capability) = self.all_call(bytes, now_s)?;
                Ok(heard(icao, 0, u64::from(capability)))
            }
            17 | 18 => {
                let (icao, corrected, me) = self.extended_squitter(bytes, df, now_s)?;
                Ok(heard(icao, corrected, me))
            }
            _ => Err(Skip::UnsupportedDf),
        }
    }

    /// The address of an Address/Parity reply, if recently heard.
    fn address_parity(&self, bytes: &[u8], now_s: f64) -> Result<u32, Skip> {
        let address = crc::syndrome(bytes).ok_or(Skip::WrongLength)?;
        if self
            .recent
            .contains(address, now_s, self.cfg.recent_address_s)
        {
            Ok(address)
        } else {
            Err(Skip::UnknownAddress)
        }
    }

    /// DF11: (AA, CA) if the parity checks up to an interrogator code.
    fn all_call(&mut self, bytes: &[u8], now_s: f64) -> Result<(u32, u8), Skip> {
        let syndrome = crc::syndrome(bytes).ok_or(Skip::WrongLength)?;
        if syndrome & 0xFF_FF80 != 0 {
            return Err(Skip::BadCrc);
        }
        let address = bits::field(bytes, 9, 32).ok_or(Skip::WrongLength)?;
        let capability = bits::field(bytes, 6, 8).ok_or(Skip::WrongLength)? as u8;
        let window_s = self.cfg.recent_address_s;
        if syndrome == 0 {
            self.remember(address, now_s);
        } else if !self.recent.contains(address, now_s, window_s) {
            return Err(Skip::UnknownAddress);
        }
        Ok((address, capability))
    }

    /// DF17/18: (AA, bits repaired, the ME field's 56 bits).
    #[inline(always)]
    fn extended_squitter(
        &mut self,
        bytes: &[u8],
        df: u8,
        now_s: f64,
    ) -> Result<(u32, u8, u64), Skip> {
        let mut frame: [u8; 14] = bytes.try_into().map_err(|_| Skip::WrongLength)?;
        let syndrome = crc::syndrome(&frame).ok_or(Skip::WrongLength)?;
        let mut repaired_bit = None;
        if syndrome != 0 {
            if !self.cfg.fix_single_bit {
                return Err(Skip::BadCrc);
            }
            let bit = single_bit_error(syndrome).ok_or(Skip::BadCrc)?;
            let byte = frame
                .get_mut(usize::from((bit - 1) / 8))
                .ok_or(Skip::BadCrc)?;
            *byte ^= 0x80 >> ((bit - 1) % 8);
            repaired_bit = Some(bit);
        }
        let address = bits::field(&frame, 9, 32).ok_or(Skip::WrongLength)?;
        if let Some(bit) = repaired_bit {
            // readsb's caution: a repair that changes the address is trusted only for an
            // aircraft already known, otherwise one noisy frame could invent one.
            if (9..=32).contains(&bit)
                && !self
                    .recent
                    .contains(address, now_s, self.cfg.recent_address_s)
            {
                return Err(Skip::BadCrc);
            }
        }
        // DF18 control field (DO-260B §2.2.3.1.2, Table 2-10): 0 ES/NT with ICAO address,
        // 1 ES/NT with another address, 6 ADS-R; 2-5 are TIS-B formats, 7 reserved.
        let cf = frame.first().map_or(0, |b| b & 7);
        if df == 18 && !matches!(cf, 0 | 1 | 6) {
            return Err(Skip::UnsupportedCf);
        }
        let me = bits::Me::from_frame(&frame).ok_or(Skip::WrongLength)?;
        if let Some(n) = self.stats.by_tc.get_mut(usize::from(me.type_code())) {
            *n += 1;
        }
        if repaired_bit.is_none() && (df == 17 || cf == 0 || cf == 6) {
            self.remember(address, now_s);
        }
        let corrected = u8::from(repaired_bit.is_some());
        Ok((address, corrected, me.raw()))
    }

    fn remember(&mut self, address: u32, now_s: f64) {
        if !self
            .recent
            .refresh(address, now_s, self.cfg.recent_address_s)
        {
            self.stats.address_table_full += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    fn frame(t: f64, s: &str) -> RawFrame {
        RawFrame::new(t, &hex(s), Some(42)).unwrap()
    }

    /// Recomputes the parity of a long frame whose message part was edited.
    fn with_parity(mut f: Vec<u8>) -> Vec<u8> {
        let p = crc::crc24(&f[..11]);
        f[11..].copy_from_slice(&p.to_be_bytes()[1..]);
        f
    }

    const KLM1023: &str = "8D4840D6202CC371C32CE0576098";

    #[test]
    fn single_bit_syndromes_are_distinct_and_exclude_the_df() {
        for w in SINGLE_BIT_SYNDROMES.windows(2) {
            assert!(
                w[0].0 < w[1].0,
                "duplicate or unsorted syndrome {:06x}",
                w[1].0
            );
        }
        let mut bits: Vec<u8> = SINGLE_BIT_SYNDROMES.iter().map(|&(_, b)| b).collect();
        bits.sort_unstable();
        assert_eq!(bits, (6..=112).collect::<Vec<u8>>());
        assert_eq!(single_bit_error(0), None);
    }

    #[test]
    fn every_single_bit_error_outside_the_df_is_repaired() {
        // Flip each bit of a clean frame: the syndrome (from the table-driven CRC, an
        // independent computation) must point back to exactly that bit.
        let clean = hex(KLM1023);
        for bit in 1..=112u32 {
            let mut f = clean.clone();
            f[((bit - 1) / 8) as usize] ^= 0x80 >> ((bit - 1) % 8);
            let syn = crc::syndrome(&f).unwrap();
            assert_ne!(syn, 0);
            let expected = (bit >= 6).then_some(bit as u8);
            assert_eq!(single_bit_error(syn), expected, "bit {bit}");
        }
    }

    #[test]
    fn df17_repair_and_rejection_are_counted() {
        let mut dec = Decoder::new(DecoderConfig::default());
        // Flip ME bit 20 (frame bit 52) of KLM1023: a character bit, outside the address.
        let mut f = hex(KLM1023);
        f[6] ^= 0x80 >> 3;
        let d = dec.decode(&RawFrame::new(1.0, &f, None).unwrap()).unwrap();
        assert_eq!(d.corrected_bits, 1);
        assert_eq!(d.icao, Icao(0x4840D6));
        match d.msg {
            Message::Identification { callsign, .. } => assert_eq!(callsign.as_str(), "KLM1023"),
            other => panic!("{other:?}"),
        }
        // Two flipped bits: not a single-bit syndrome (checked), rejected.
        f[7] ^= 0x01;
        assert!(single_bit_error(crc::syndrome(&f).unwrap()).is_none());
        assert_eq!(
            dec.decode(&RawFrame::new(2.0, &f, None).unwrap()),
            Err(Skip::BadCrc)
        );
        // Repair disabled: even one bit is rejected.
        let mut strict = Decoder::new(DecoderConfig {
            fix_single_bit: false,
            ..Default::default()
        });
        let mut one = hex(KLM1023);
        one[6] ^= 0x10;
        assert_eq!(
            strict.decode(&RawFrame::new(1.0, &one, None).unwrap()),
            Err(Skip::BadCrc)
        );
        assert_eq!(dec.stats().crc_fixed, 1);
        assert_eq!(dec.stats().crc_rejected, 1);
        assert_eq!(dec.stats().decoded, 1);
        assert_eq!(dec.stats().by_df[17], 2);
        assert_eq!(dec.stats().by_tc[4], 1);
        assert_eq!(strict.stats().crc_rejected, 1);
    }

    #[test]
    fn address_repair_needs_a_known_aircraft() {
        // A one-bit error inside AA repairs to 4840D6 only once 4840D6 has been heard clean.
        let mut f = hex(KLM1023);
        f[2] ^= 0x04; // frame bit 22, inside AA
        let mut dec = Decoder::new(DecoderConfig::default());
        assert_eq!(
            dec.decode(&RawFrame::new(0.0, &f, None).unwrap()),
            Err(Skip::BadCrc)
        );
        dec.decode(&frame(1.0, KLM1023)).unwrap();
        let d = dec.decode(&RawFrame::new(2.0, &f, None).unwrap()).unwrap();
        assert_eq!((d.icao, d.corrected_bits), (Icao(0x4840D6), 1));
        // The DF bits are never repaired: flipping bit 3 turns DF17 into DF21 (an
        // Address/Parity reply), whose syndrome is then just an unknown address.
        let mut g = hex(KLM1023);
        g[0] ^= 0x20;
        assert_eq!(g[0] >> 3, 21);
        assert_eq!(
            dec.decode(&RawFrame::new(3.0, &g, None).unwrap()),
            Err(Skip::UnknownAddress)
        );
    }

    #[test]
    fn address_parity_replies_need_a_recent_clean_address() {
        // fixtures/afr34zg-cdg-tls.jsonl: DF4 of 393322 at 575 ft (rs1090: altitude 575),
        // DF5 squawk 1000, and a clean DF17 of 393322.
        let df4 = "212800bf40f1ef";
        let df5 = "2928080069049e";
        let df17 = "8f393322384a02aea63afc43dcba";
        let mut dec = Decoder::new(DecoderConfig::default());
        assert_eq!(dec.decode(&frame(0.0, df4)), Err(Skip::UnknownAddress));
        dec.decode(&frame(10.0, df17)).unwrap();
        let d = dec.decode(&frame(20.0, df4)).unwrap();
        assert_eq!(d.icao, Icao(0x393322));
        assert_eq!(d.df, 4);
        assert_eq!(d.signal, Some(42));
        assert_eq!(d.time_s, 20.0);
        assert_eq!(d.msg, Message::Altitude { alt_ft: Some(575) });
        let d = dec.decode(&frame(70.0, df5)).unwrap();
        assert_eq!(d.msg, Message::Squawk { squawk: 0o1000 });
        // 60 s after the last clean frame the address has expired.
        assert_eq!(dec.decode(&frame(70.001, df4)), Err(Skip::UnknownAddress));
        assert_eq!(dec.stats().unknown_address, 2);
        assert_eq!(dec.stats().decoded, 3);
    }

    #[test]
    fn all_call_rules() {
        // fixtures/pymodes-2015-03-03.txt: DF11 of 40621D (the aircraft of the 1090 MHz
        // Riddle's position example), CA 5, once with interrogator code 0 and once with 14.
        let clean = hex("5D40621D4F94D0");
        let ic14 = hex("5D40621D4F94DE");
        assert_eq!(crc::syndrome(&clean), Some(0));
        assert_eq!(crc::syndrome(&ic14), Some(14));
        let mut dec = Decoder::new(DecoderConfig::default());
        // Unknown address with a non-zero interrogator code: not enough to start an aircraft.
        assert_eq!(
            dec.decode(&RawFrame::new(0.0, &ic14, None).unwrap()),
            Err(Skip::UnknownAddress)
        );
        let d = dec
            .decode(&RawFrame::new(1.0, &clean, None).unwrap())
            .unwrap();
        assert_eq!(
            (d.icao, d.msg),
            (Icao(0x40621D), Message::AllCall { capability: 5 })
        );
        let d = dec
            .decode(&RawFrame::new(2.0, &ic14, None).unwrap())
            .unwrap();
        assert_eq!(d.icao, Icao(0x40621D));
        // The clean DF11 makes the address known to Address/Parity replies (pyModeS's DF4
        // header 20001718 is 36000 ft).
        let mut df4 = hex("20001718000000");
        let ap = crc::crc24(&df4[..4]) ^ 0x40621D;
        df4[4..].copy_from_slice(&ap.to_be_bytes()[1..]);
        let d = dec
            .decode(&RawFrame::new(3.0, &df4, None).unwrap())
            .unwrap();
        assert_eq!(
            (d.icao, d.msg),
            (
                Icao(0x40621D),
                Message::Altitude {
                    alt_ft: Some(36000)
                }
            )
        );
        // A syndrome above the low 7 bits is a bad CRC.
        let mut bad = clean.clone();
        bad[5] ^= 0x01;
        assert_eq!(
            dec.decode(&RawFrame::new(4.0, &bad, None).unwrap()),
            Err(Skip::BadCrc)
        );
        assert_eq!(dec.stats().crc_rejected, 1);
    }

    #[test]
    fn df18_control_fields() {
        // Re-label the KLM1023 frame as DF18 with each CF and recompute the parity.
        for cf in 0..8u8 {
            let mut f = hex(KLM1023);
            f[0] = (18 << 3) | cf;
            let f = with_parity(f);
            let mut dec = Decoder::new(DecoderConfig::default());
            let r = dec.decode(&RawFrame::new(0.0, &f, None).unwrap());
            if matches!(cf, 0 | 1 | 6) {
                assert_eq!(r.unwrap().icao, Icao(0x4840D6), "CF {cf}");
            } else {
                assert_eq!(r, Err(Skip::UnsupportedCf), "CF {cf}");
            }
            // Only ICAO-address CFs (0, 6) make the address known.
            let mut df4 = hex("20001718000000");
            let ap = crc::crc24(&df4[..4]) ^ 0x4840D6;
            df4[4..].copy_from_slice(&ap.to_be_bytes()[1..]);
            let known = dec.decode(&RawFrame::new(1.0, &df4, None).unwrap()).is_ok();
            assert_eq!(known, cf == 0 || cf == 6, "CF {cf}");
        }
    }

    #[test]
    fn other_skips_are_counted() {
        let mut dec = Decoder::new(DecoderConfig::default());
        assert_eq!(
            dec.decode(&RawFrame::new(0.0, &[0x12, 0x34], None).unwrap()),
            Err(Skip::ModeAc)
        );
        // DF17 in 7 bytes, DF4 in 14 bytes.
        assert_eq!(
            dec.decode(&frame(0.0, &KLM1023[..14])),
            Err(Skip::WrongLength)
        );
        assert_eq!(
            dec.decode(&frame(0.0, "212800bf40f1ef7e5817e9cc428d")),
            Err(Skip::WrongLength)
        );
        // DF19 (military) and DF24 (Comm-D).
        assert_eq!(
            dec.decode(&frame(0.0, "9800000000000000000000000000")),
            Err(Skip::UnsupportedDf)
        );
        assert_eq!(
            dec.decode(&frame(0.0, "C000000000000000000000000000")),
            Err(Skip::UnsupportedDf)
        );
        let s = dec.stats();
        assert_eq!(
            (
                s.frames,
                s.decoded,
                s.mode_ac,
                s.wrong_length,
                s.unsupported_df
            ),
            (5, 0, 1, 2, 2)
        );
        assert_eq!(
            (s.by_df[17], s.by_df[4], s.by_df[19], s.by_df[24]),
            (1, 1, 1, 1)
        );
        let json = serde_json::to_value(s).unwrap();
        assert_eq!(json["by_df"].as_array().unwrap().len(), 32);
        assert_eq!(json["wrong_length"], 2);
    }

    #[test]
    fn recent_table_reuses_expired_slots_and_reports_when_full() {
        let mut t = RecentAddresses::new();
        // Addresses that share a home slot: a probe sequence of RECENT_MAX_PROBE fills up.
        let home = RecentAddresses::home(0x000001);
        let same_home: Vec<u32> = (1..0xFF_FFFF)
            .filter(|&a| RecentAddresses::home(a) == home)
            .take(RECENT_MAX_PROBE + 1)
            .collect();
        for &a in &same_home[..RECENT_MAX_PROBE] {
            assert!(t.refresh(a, 0.0, 60.0));
        }
        let last = same_home[RECENT_MAX_PROBE];
        assert!(
            !t.refresh(last, 1.0, 60.0),
            "all probed slots hold live addresses"
        );
        assert!(!t.contains(last, 1.0, 60.0));
        // Once they expire, the slot of the first expired one is reused.
        assert!(t.refresh(last, 61.5, 60.0));
        assert!(t.contains(last, 61.5, 60.0));
        assert!(!t.contains(same_home[0], 61.5, 60.0));
        assert!(t.contains(same_home[1], 30.0, 60.0));
        // A refresh of a present address updates it in place (no duplicate).
        assert!(t.refresh(same_home[1], 100.0, 60.0));
        assert!(t.contains(same_home[1], 150.0, 60.0));
        assert!(!t.contains(0x123456, 0.0, 60.0));
    }
}
