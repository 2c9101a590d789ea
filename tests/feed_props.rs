//! Properties of every parser on arbitrary input: no panic, never consumes more than it is
//! given, time never decreases, counters add up, and the result does not depend on how the
//! bytes were split into reads.

use adsb_tracker::feed::{parser_for, FeedClock, Format, ParseStats, RawFrame};
use proptest::prelude::*;
use proptest::sample::Index;

const FORMATS: [Format; 5] = [
    Format::Beast,
    Format::Avr,
    Format::Csv,
    Format::Iso,
    Format::Jsonl,
];

/// Parses `pieces` in order the way a reader does, then finishes; checks `consumed <= len`
/// on every call.
fn run(format: Format, pieces: &[&[u8]]) -> Result<(Vec<RawFrame>, ParseStats), TestCaseError> {
    let mut parser = parser_for(format, 25.0);
    let mut out = Vec::new();
    let mut pending: Vec<u8> = Vec::new();
    for piece in pieces {
        pending.extend_from_slice(piece);
        let used = parser.parse(&pending, &mut out);
        prop_assert!(
            used <= pending.len(),
            "{format:?} consumed {used} of {}",
            pending.len()
        );
        pending.drain(..used);
    }
    parser.finish_into(&pending, &mut out);
    Ok((out, parser.stats().clone()))
}

fn check(data: &[u8], cuts: &[Index]) -> Result<(), TestCaseError> {
    let mut at: Vec<usize> = cuts.iter().map(|i| i.index(data.len() + 1)).collect();
    at.extend([0, data.len()]);
    at.sort_unstable();
    let pieces: Vec<&[u8]> = at.windows(2).map(|w| &data[w[0]..w[1]]).collect();
    for format in FORMATS {
        let (whole, whole_stats) = run(format, &[data])?;
        let (split, split_stats) = run(format, &pieces)?;
        prop_assert_eq!(whole_stats.frames, whole.len() as u64);
        prop_assert!(
            whole.windows(2).all(|w| w[0].time_s <= w[1].time_s),
            "{:?}: time went backwards",
            format
        );
        prop_assert!(whole
            .iter()
            .all(|f| f.time_s.is_finite() && matches!(f.bytes().len(), 2 | 7 | 14)));
        prop_assert!(whole == split, "{:?}: split changed the frames", format);
        prop_assert_eq!(whole_stats, split_stats);
    }
    Ok(())
}

/// Bytes dense in Beast structure: markers, type bytes, zero counters. (Mapped from plain
/// bytes: a `prop_oneof!` per byte is slow to generate.)
fn beastish(len: std::ops::Range<usize>) -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<(u8, u8)>(), len).prop_map(|v| {
        v.into_iter()
            .map(|(pick, byte)| match pick % 13 {
                0..=3 => byte,
                4..=6 => 0x1a,
                7 => b'1',
                8 => b'2',
                9 => b'3',
                10 => b'4',
                _ => 0,
            })
            .collect()
    })
}

fn hex_digits(max: usize) -> impl Strategy<Value = String> {
    proptest::string::string_regex(&format!("[0-9a-fA-F]{{0,{max}}}")).unwrap()
}

/// Lines close to every text format, with arbitrary timestamps and hex of any length.
fn textish_line() -> impl Strategy<Value = String> {
    let ts = prop_oneof![
        any::<f64>().prop_map(|t| t.to_string()),
        (0.0..2e9f64).prop_map(|t| t.to_string())
    ];
    prop_oneof![
        hex_digits(30).prop_map(|h| format!("*{h};")),
        (hex_digits(12), hex_digits(30)).prop_map(|(c, h)| format!("@{c:0>12}{h};")),
        (ts.clone(), hex_digits(30)).prop_map(|(t, h)| format!("{t},{h}")),
        (
            1970u32..2100,
            1u32..13,
            1u32..32,
            0u32..24,
            0u32..60,
            0u32..60,
            0u32..1_000_000,
            hex_digits(30)
        )
            .prop_map(|(y, mo, d, h, mi, s, us, x)| format!(
                "{y}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}.{us:06}  {x}"
            )),
        (ts, hex_digits(30))
            .prop_map(|(t, h)| format!(r#"{{"timestamp":{t},"frame":"{h}","x":[1]}}"#)),
        "[ -~]{0,40}",
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn arbitrary_bytes(data in prop::collection::vec(any::<u8>(), 0..3000),
                       cuts in prop::collection::vec(any::<Index>(), 0..20)) {
        check(&data, &cuts)?;
    }

    #[test]
    fn beast_like_bytes(data in beastish(0..3000),
                        cuts in prop::collection::vec(any::<Index>(), 0..20)) {
        check(&data, &cuts)?;
    }

    #[test]
    fn text_like_lines(lines in prop::collection::vec(textish_line(), 0..80),
                       crlf in any::<bool>(),
                       cuts in prop::collection::vec(any::<Index>(), 0..20)) {
        let data = lines.join(if crlf { "\r\n" } else { "\n" });
        check(data.as_bytes(), &cuts)?;
    }

    #[test]
    fn clock_never_goes_back(ticks in prop::collection::vec(
                                 prop_oneof![any::<u64>(), 0u64..10_000_000_000, Just(0u64)], 1..300),
                             secs in prop::collection::vec(
                                 prop_oneof![any::<f64>(), -1e4..1e4f64], 1..300)) {
        let mut clock = FeedClock::new();
        let mut last = clock.last_s();
        for t in ticks {
            let now = clock.at_ticks(t);
            prop_assert!(now >= last && now.is_finite());
            last = now;
        }
        for s in secs {
            let now = clock.at_seconds(s);
            prop_assert!(now >= last && now.is_finite());
            last = now;
        }
    }
}
