//! Big-endian bit fields of a Mode S frame, numbered as the specifications number them.
//!
//! ICAO Annex 10 Vol IV §3.1.2.3.1.3 numbers the bits of a reply from 1 (the first bit
//! transmitted, the most significant bit of the first byte) to 56 or 112; DO-260B and ICAO
//! Doc 9871 number the ME field of an extended squitter from 1 to 56 (frame bits 33-88). Every
//! field in this crate is written with those numbers, so a reader can check each one against
//! the tables without converting offsets. Nothing here panics: a range that does not fit the
//! frame gives `None` (or 0 for [`Me`], whose callers only pass constant, valid ranges).

/// Frame bits `first..=last` (1-based, inclusive) of `bytes` as an unsigned integer.
///
/// `None` when the range is empty, wider than 32 bits, starts at bit 0, or runs past the end
/// of `bytes`.
pub fn field(bytes: &[u8], first: u32, last: u32) -> Option<u32> {
    if first == 0 || last < first || last - first >= 32 {
        return None;
    }
    let (first_byte, last_byte) = ((first - 1) / 8, (last - 1) / 8);
    let covering =
        bytes.get(usize::try_from(first_byte).ok()?..=usize::try_from(last_byte).ok()?)?;
    // At most 5 bytes cover a 32-bit field, so the accumulator never overflows.
    let acc = covering
        .iter()
        .fold(0u64, |acc, &b| (acc << 8) | u64::from(b));
    let bits_after = (last_byte + 1) * 8 - last;
    let width = last - first + 1;
    u32::try_from((acc >> bits_after) & ((1u64 << width) - 1)).ok()
}

/// Frame bit `n` (1-based), `None` past the end of `bytes`.
pub fn bit(bytes: &[u8], n: u32) -> Option<bool> {
    field(bytes, n, n).map(|b| b == 1)
}

/// The 56-bit ME field of an extended squitter (frame bits 33-88, DO-260B §2.2.3.2), loaded
/// once into a register so that every sub-field is a shift and a mask.
///
/// Bits are numbered 1-56 as DO-260B and ICAO Doc 9871 number ME bits (ME bit n is frame bit
/// n + 32).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Me(u64);

/// Width of the ME field in bits.
const ME_BITS: u32 = 56;

impl Me {
    /// The ME field of a long (112-bit) frame; `None` if `frame` is shorter than 11 bytes.
    pub fn from_frame(frame: &[u8]) -> Option<Me> {
        let me = frame.get(4..11)?;
        Some(Me(me
            .iter()
            .fold(0u64, |acc, &b| (acc << 8) | u64::from(b))))
    }

    /// An ME field from its 56 bits, right-aligned in `raw` (higher bits are dropped).
    pub fn from_raw(raw: u64) -> Me {
        Me(raw & ((1u64 << ME_BITS) - 1))
    }

    /// The 56 bits, right-aligned.
    pub fn raw(self) -> u64 {
        self.0
    }

    /// ME bits `first..=last` (1-based, inclusive).
    ///
    /// Returns 0 for a range that is empty, starts at 0, ends past bit 56 or is wider than 32
    /// bits: the decoders only pass constant ranges taken from the tables, and a unit test
    /// checks that an invalid range reads as 0 rather than panicking.
    pub fn get(self, first: u32, last: u32) -> u32 {
        if first == 0 || last < first || last > ME_BITS || last - first >= 32 {
            return 0;
        }
        let width = last - first + 1;
        let shifted = self.0 >> (ME_BITS - last);
        u32::try_from(shifted & ((1u64 << width) - 1)).unwrap_or(0)
    }

    /// ME bit `n` (1-based); false outside 1..=56.
    pub fn bit(self, n: u32) -> bool {
        self.get(n, n) == 1
    }

    /// The type code, ME bits 1-5 (DO-260B §2.2.3.2.1.1 and the per-format "TYPE" subfields).
    pub fn type_code(self) -> u8 {
        // Five bits always fit a u8.
        (self.get(1, 5) & 0x1F) as u8
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

    #[test]
    fn header_fields_of_a_published_frame() {
        // The 1090 MHz Riddle, "ADS-B basics": 8D4840D6202CC371C32CE0576098 has DF 17 (bits
        // 1-5), CA 5 (bits 6-8), ICAO 4840D6 (bits 9-32), TC 4 (bits 33-37), PI 576098.
        let f = hex("8D4840D6202CC371C32CE0576098");
        assert_eq!(field(&f, 1, 5), Some(17));
        assert_eq!(field(&f, 6, 8), Some(5));
        assert_eq!(field(&f, 9, 32), Some(0x4840D6));
        assert_eq!(field(&f, 33, 37), Some(4));
        assert_eq!(field(&f, 89, 112), Some(0x576098));
        assert_eq!(bit(&f, 1), Some(true));
        assert_eq!(bit(&f, 2), Some(false));
        assert_eq!(bit(&f, 112), Some(false));
    }

    #[test]
    fn riddle_airborne_position_fields() {
        // The 1090 MHz Riddle, "Airborne position": 8D40621D58C382D690C8AC2863A7 has
        // ALT 110000111000 (ME 9-20), F 0 (ME 22), LAT-CPR 93000 (ME 23-39),
        // LON-CPR 51372 (ME 40-56).
        let f = hex("8D40621D58C382D690C8AC2863A7");
        let me = Me::from_frame(&f).unwrap();
        assert_eq!(me.type_code(), 11);
        assert_eq!(me.get(9, 20), 0b1100_0011_1000);
        assert!(!me.bit(22));
        assert_eq!(me.get(23, 39), 93000);
        assert_eq!(me.get(40, 56), 51372);
        // The same fields through frame numbering (ME bit n = frame bit n + 32).
        assert_eq!(field(&f, 55, 71), Some(93000));
        assert_eq!(field(&f, 72, 88), Some(51372));
    }

    #[test]
    fn out_of_range_never_panics() {
        let f = hex("8D4840D6202CC3");
        assert_eq!(field(&f, 0, 3), None);
        assert_eq!(field(&f, 5, 4), None);
        assert_eq!(field(&f, 1, 33), None, "wider than 32 bits");
        assert_eq!(field(&f, 50, 57), None, "past the end of 7 bytes");
        assert_eq!(field(&f, 1, 32), Some(0x8D4840D6));
        assert_eq!(field(&[], 1, 1), None);
        assert_eq!(bit(&f, 57), None);
        assert_eq!(field(&f, u32::MAX - 1, u32::MAX), None);
        assert_eq!(Me::from_frame(&f), None, "a short frame has no ME field");
        let me = Me::from_raw(u64::MAX);
        assert_eq!(me.raw(), (1u64 << 56) - 1);
        assert_eq!(me.get(0, 4), 0);
        assert_eq!(me.get(50, 57), 0);
        assert_eq!(me.get(9, 8), 0);
        assert_eq!(me.get(1, 33), 0);
        assert_eq!(me.get(25, 56), u32::MAX);
        assert!(!me.bit(0));
        assert!(!me.bit(57));
    }

    #[test]
    fn every_single_bit_lands_where_numbered() {
        // Closed form: frame bit n (1-based) is bit 7 - (n - 1) % 8 of byte (n - 1) / 8.
        for n in 1..=112u32 {
            let mut f = [0u8; 14];
            f[((n - 1) / 8) as usize] = 0x80 >> ((n - 1) % 8);
            for m in 1..=112u32 {
                assert_eq!(bit(&f, m), Some(m == n), "frame bit {m} with bit {n} set");
            }
            let me = Me::from_frame(&f).unwrap();
            for m in 1..=56u32 {
                assert_eq!(me.bit(m), m + 32 == n, "ME bit {m} with frame bit {n} set");
            }
        }
    }
}
