//! Mode S CRC-24 (ICAO Annex 10 Vol IV §3.1.2.3.3), table-driven.
//!
//! The generator polynomial is 0x1FFF409. For DF11/17/18 the last 24 bits are the parity
//! itself, so the syndrome of a clean frame is zero; for DF0/4/5/16/20/21 the parity is
//! overlaid with the aircraft address, so the syndrome *is* the address (Address/Parity).

/// The generator polynomial without its x^24 term (Annex 10 Vol IV, 3.1.2.3.3.1.2).
pub const GENERATOR: u32 = 0xFFF409;

/// Byte-wise CRC table: `TABLE[b]` is the CRC-24 remainder of byte `b` followed by 24 zero bits.
static TABLE: [u32; 256] = build_table();

const fn build_table() -> [u32; 256] {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = (i as u32) << 16;
        let mut bit = 0;
        while bit < 8 {
            c = if c & 0x80_0000 != 0 {
                (c << 1) ^ GENERATOR
            } else {
                c << 1
            };
            bit += 1;
        }
        table[i] = c & 0xFF_FFFF;
        i += 1;
    }
    table
}

/// CRC-24 remainder of `data` (the message part, without the 24 parity bits).
pub fn crc24(data: &[u8]) -> u32 {
    let mut crc = 0u32;
    for &b in data {
        let idx = (((crc >> 16) as u8) ^ b) as usize;
        crc = ((crc << 8) & 0xFF_FFFF) ^ TABLE[idx];
    }
    crc
}

/// Syndrome of a whole frame: CRC of the message part XOR the transmitted parity (last 3 bytes).
/// Zero for a clean DF11 (interrogator 0) / DF17 / DF18; the address for DF0/4/5/16/20/21.
/// Frames shorter than 4 bytes have no parity and give `None`.
pub fn syndrome(frame: &[u8]) -> Option<u32> {
    let n = frame.len();
    if n < 4 {
        return None;
    }
    let (msg, parity) = frame.split_at(n - 3);
    let p = match parity {
        [a, b, c] => (u32::from(*a) << 16) | (u32::from(*b) << 8) | u32::from(*c),
        _ => return None,
    };
    Some(crc24(msg) ^ p)
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
    fn clean_df17_has_zero_syndrome() {
        // Real frames from ../shared/data/us-short-flights.csv and afr34zg-cdg-tls.jsonl.
        for f in [
            "8DADA5265851E6616376C2EB4463",
            "8DADA526EA2D086FC55C085E782E",
            "8f393322384a02aea63afc43dcba",
        ] {
            assert_eq!(syndrome(&hex(f)), Some(0), "{f}");
        }
    }

    #[test]
    fn df4_syndrome_is_the_address() {
        // afr34zg: DF4 frame of 393322 (padded to 28 hex digits in the file; DF4 is 56 bits).
        assert_eq!(syndrome(&hex("212800bf40f1ef")), Some(0x393322));
        assert_eq!(syndrome(&hex("2928080069049e")), Some(0x393322));
    }

    #[test]
    fn table_matches_bitwise_definition() {
        fn bitwise(data: &[u8]) -> u32 {
            let mut crc = 0u32;
            for &b in data {
                for i in (0..8).rev() {
                    let bit = (b >> i) & 1;
                    let top = (crc >> 23) & 1;
                    crc = (crc << 1) & 0xFF_FFFF;
                    if (top ^ u32::from(bit)) == 1 {
                        crc ^= GENERATOR;
                    }
                }
            }
            crc
        }
        let data = hex("8DADA5265851E6616376C2");
        assert_eq!(crc24(&data), bitwise(&data));
        for n in 0..=255u8 {
            assert_eq!(
                crc24(&[n, n.wrapping_mul(7), 3]),
                bitwise(&[n, n.wrapping_mul(7), 3])
            );
        }
    }
}
