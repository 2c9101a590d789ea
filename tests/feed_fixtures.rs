//! Every real recording parses to exactly its known frames.
//!
//! Counts, first/last frames and times were established independently of this crate:
//! `wc -l`, and a few lines of Python (`json`, `datetime` with UTC, a plain Beast unescaper)
//! over the files in `fixtures/`; see also `fixtures/README.md`.

mod feed_common;

use adsb_tracker::feed::detect::{detect, DETECT_HEAD_BYTES};
use adsb_tracker::feed::replay::FileReader;
use adsb_tracker::feed::{Format, ParseStats, RawFrame};
use feed_common::{beast_reference, fixture, hex, read_fixture};

/// Pacing used for the untimed AVR fixture.
const RATE_HZ: f64 = 1000.0;

fn read_all(name: &str) -> (Format, Vec<RawFrame>, ParseStats, u64) {
    let mut reader = FileReader::open(fixture(name), None, RATE_HZ).unwrap();
    let mut frames = Vec::new();
    let mut batch = Vec::new();
    while reader.next_batch(&mut batch).unwrap() {
        frames.extend_from_slice(&batch);
    }
    assert_eq!(reader.bytes_read(), reader.total_bytes());
    (
        reader.format(),
        frames,
        reader.stats().clone(),
        reader.total_bytes(),
    )
}

fn clean(frames: u64) -> ParseStats {
    ParseStats {
        frames,
        ..ParseStats::default()
    }
}

fn short_count(frames: &[RawFrame]) -> usize {
    frames.iter().filter(|f| f.bytes().len() == 7).count()
}

fn assert_monotonic(frames: &[RawFrame]) {
    assert!(frames.windows(2).all(|w| w[0].time_s <= w[1].time_s));
}

#[test]
fn lax_avr() {
    let (format, frames, stats, _) = read_all("lax-messages.avr.txt");
    assert_eq!(format, Format::Avr);
    assert_eq!(frames.len(), 215_606);
    // Every frame untimed, so paced (and the clock learnable: `feed::pace`).
    assert_eq!(
        stats,
        ParseStats {
            paced_frames: 215_606,
            ..clean(215_606)
        }
    );
    // 140,965 lines of 14 hex digits, 74,641 of 28 (awk length histogram).
    assert_eq!(short_count(&frames), 140_965);
    let (first, last) = (frames[0], frames[frames.len() - 1]);
    assert_eq!(first.bytes(), hex("02C60B9ED4497C"));
    assert_eq!(last.bytes(), hex("5DAA80CA436CEF"));
    assert_eq!(first.signal, None);
    // Untimed: frame n at n / rate.
    assert_eq!(first.time_s, 0.0);
    assert_eq!(last.time_s, 215_605.0 / RATE_HZ);
    assert_eq!(frames[1000].time_s, 1.0);
    assert_monotonic(&frames);
}

#[test]
fn afr34zg_jsonl() {
    let (format, frames, stats, _) = read_all("afr34zg-cdg-tls.jsonl");
    assert_eq!(format, Format::Jsonl);
    assert_eq!(frames.len(), 57_793);
    assert_eq!(stats, clean(57_793));
    // Every frame is 28 digits; 21,018 have DF < 16 and are 56-bit frames padded.
    assert_eq!(short_count(&frames), 21_018);
    let (first, last) = (frames[0], frames[frames.len() - 1]);
    assert_eq!(first.bytes(), hex("8f393322384a02aea63afc43dcba"));
    assert_eq!(first.time_s, 1_720_248_189.525_094);
    assert_eq!(last.bytes(), hex("8c39332240291667c5484dc4c9db"));
    assert_eq!(last.time_s, 1_720_252_967.494_935);
    // Second line: DF4 "212800bf40f1ef7e5817e9cc428d" keeps its first 7 bytes.
    assert_eq!(frames[1].bytes(), hex("212800bf40f1ef"));
    assert_eq!(frames[1].time_s, 1_720_248_190.012_853);
    assert_monotonic(&frames);
}

#[test]
fn toulouse_beast() {
    let (format, frames, stats, total) = read_all("toulouse-sample.beast");
    assert_eq!(format, Format::Beast);
    assert_eq!(total, 4218);
    assert_eq!(frames.len(), 239);
    assert_eq!(stats, clean(239));
    // 185 type '2' and 54 type '3' frames; 16 escaped 0x1a pairs in the file.
    assert_eq!(short_count(&frames), 185);
    let (first, last) = (frames[0], frames[238]);
    assert_eq!(first.bytes(), hex("20000ca8f70aa7"));
    assert_eq!(first.signal, Some(13));
    assert!((first.time_s - 30.280_522_5).abs() < 1e-9); // counter 363,366,270
    assert_eq!(last.bytes(), hex("a80018a7ca380030a800001d4e3e"));
    assert_eq!(last.signal, Some(7));
    assert!((last.time_s - 54.197_677_5).abs() < 1e-9); // counter 650,372,130
    assert_monotonic(&frames);

    // Every frame against the independent reference reader.
    let reference = beast_reference(&read_fixture("toulouse-sample.beast"));
    assert_eq!(reference.len(), 239);
    for (got, want) in frames.iter().zip(&reference) {
        assert_eq!(got.bytes(), &want.data[..]);
        assert_eq!(got.signal, Some(want.signal));
        assert_eq!(got.time_s, want.counter as f64 / 12e6);
    }
}

#[test]
fn us_short_flights_csv() {
    let (format, frames, stats, _) = read_all("us-short-flights.csv");
    assert_eq!(format, Format::Csv);
    assert_eq!(frames.len(), 486);
    assert_eq!(stats, clean(486));
    assert_eq!(short_count(&frames), 0); // all DF17
    let (first, last) = (frames[0], frames[485]);
    assert_eq!(first.bytes(), hex("8DADA5265851E6616376C2EB4463"));
    assert_eq!(first.time_s, 1_753_827_785.808_609_2);
    assert_eq!(last.bytes(), hex("8DACF4E899141D24D0A8183B9ADB"));
    assert_eq!(last.time_s, 1_753_827_846.403_851_5);
    assert_monotonic(&frames);
}

#[test]
fn pymodes_iso() {
    let (format, frames, stats, _) = read_all("pymodes-2015-03-03.txt");
    assert_eq!(format, Format::Iso);
    // 4,515 newlines: the last line has none and is parsed at the end of the file.
    assert_eq!(frames.len(), 4_516);
    assert_eq!(stats, clean(4_516));
    assert_eq!(short_count(&frames), 3_149);
    let (first, last) = (frames[0], frames[4_515]);
    assert_eq!(first.bytes(), hex("5D4840D6F87407"));
    // datetime(2015,3,3,16,12,24,846557,tzinfo=utc).timestamp()
    assert_eq!(first.time_s, 1_425_399_144.846_557);
    assert_eq!(last.bytes(), hex("5D45AC33A55D52"));
    assert_eq!(last.time_s, 1_425_399_324.101_592);
    assert_monotonic(&frames);
}

#[test]
fn detect_recognises_every_fixture() {
    for (name, format) in [
        ("lax-messages.avr.txt", Format::Avr),
        ("afr34zg-cdg-tls.jsonl", Format::Jsonl),
        ("toulouse-sample.beast", Format::Beast),
        ("us-short-flights.csv", Format::Csv),
        ("pymodes-2015-03-03.txt", Format::Iso),
    ] {
        let data = read_fixture(name);
        let head = &data[..data.len().min(DETECT_HEAD_BYTES)];
        assert_eq!(detect(head), Some(format), "{name}");
        // A short head, cut mid-line or mid-frame, still works.
        assert_eq!(detect(&data[..1000]), Some(format), "{name} (1000 bytes)");
    }
    assert_eq!(detect(&read_fixture("README.md")), None);
}
