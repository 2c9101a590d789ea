//! Decoding cost per frame over the 215,606 frames of fixtures/lax-messages.avr.txt
//! (pre-parsed, so only decoding is measured): our CRC, our `Decoder::decode`, and
//! adsb_deku 0.8.0's `Frame::from_bytes` for comparison. Criterion reports the time of one
//! pass over all frames; divide by the frame count (throughput) for ns/frame.

use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use adsb_tracker::decode::{crc, Decoder, DecoderConfig};
use adsb_tracker::feed::RawFrame;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};

/// The lax recording's `*hex;` lines, 1 ms apart in feed time (the file has no timestamps).
fn lax_frames() -> Vec<RawFrame> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/lax-messages.avr.txt");
    let text = std::fs::read_to_string(&path).unwrap_or_default();
    text.lines()
        .filter_map(|l| l.trim().strip_prefix('*')?.strip_suffix(';'))
        .filter_map(|h| {
            (0..h.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(h.get(i..i + 2)?, 16).ok())
                .collect::<Option<Vec<u8>>>()
        })
        .enumerate()
        .filter_map(|(i, b)| RawFrame::new(i as f64 * 0.001, &b, None))
        .collect()
}

fn decode(c: &mut Criterion) {
    let frames = lax_frames();
    assert!(frames.len() > 200_000, "fixture not found or truncated");
    let mut group = c.benchmark_group("lax");
    group.throughput(Throughput::Elements(frames.len() as u64));
    group.sample_size(10);
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(4));

    group.bench_function("crc_syndrome", |b| {
        b.iter(|| {
            frames
                .iter()
                .map(|f| crc::syndrome(black_box(f.bytes())).unwrap_or(0))
                .fold(0u32, |acc, s| acc ^ s)
        })
    });

    group.bench_function("decoder_decode", |b| {
        // One decoder across passes, as in the daemon: the recent-address table stays warm.
        let mut dec = Decoder::new(DecoderConfig::default());
        b.iter(|| {
            frames
                .iter()
                .filter(|f| dec.decode(black_box(f)).is_ok())
                .count()
        })
    });

    group.bench_function("adsb_deku_from_bytes", |b| {
        b.iter(|| {
            frames
                .iter()
                .filter(|f| adsb_deku::Frame::from_bytes(black_box(f.bytes())).is_ok())
                .count()
        })
    });
    group.finish();
}

criterion_group!(benches, decode);
criterion_main!(benches);
