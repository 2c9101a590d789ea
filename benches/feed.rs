//! Feed parsing throughput on the real recordings, reported as frames per second.
//!
//! `cargo bench --bench feed`. Beast framing is measured on the Toulouse recording repeated
//! to about 1 MB (the counter steps back at each repetition, so the clock-reset path is
//! exercised too); AVR on the whole LAX recording. The output vector is reused, as the
//! readers do, so nothing is allocated per frame.
//!
//! Times are the benchmarking thread's CPU time (Linux `/proc/thread-self/schedstat`; wall
//! time elsewhere): the machine is shared, and wall time would mostly measure the
//! neighbours. Throughput is then frames per CPU-second, the unit DESIGN.md compares readsb
//! in. Samples are long (hundreds of ms) so the scheduler tick granularity of that counter
//! stays below a percent.

use adsb_tracker::feed::beast::BeastParser;
use adsb_tracker::feed::text::TextParser;
use adsb_tracker::feed::{Format, FrameParser, RawFrame};
use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use std::path::PathBuf;
use std::time::{Duration, Instant};

fn fixture(name: &str) -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Parses `data` in 64 KiB reads, as the file reader does; returns the frame count.
fn parse_chunked(parser: &mut dyn FrameParser, data: &[u8], out: &mut Vec<RawFrame>) -> usize {
    const CHUNK: usize = 64 * 1024;
    let mut frames = 0;
    let mut start = 0;
    while start < data.len() {
        let end = (start + CHUNK).min(data.len());
        out.clear();
        start += parser.parse(&data[start..end], out);
        frames += out.len();
        if end == data.len() {
            break;
        }
    }
    frames
}

/// CPU time consumed by this thread so far, if the kernel tells.
fn thread_cpu_time() -> Option<Duration> {
    let stat = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = stat.split_whitespace().next()?.parse().ok()?;
    Some(Duration::from_nanos(ns))
}

/// Runs `f` `iters` times and returns the CPU time it took (wall time if unavailable).
fn cpu_timed(iters: u64, mut f: impl FnMut()) -> Duration {
    let (cpu0, wall0) = (thread_cpu_time(), Instant::now());
    for _ in 0..iters {
        f();
    }
    match (cpu0, thread_cpu_time()) {
        (Some(a), Some(b)) => b.saturating_sub(a),
        _ => wall0.elapsed(),
    }
}

fn frame_count(parser: &mut dyn FrameParser, data: &[u8]) -> usize {
    parse_chunked(parser, data, &mut Vec::new())
}

fn beast(c: &mut Criterion) {
    let one = fixture("toulouse-sample.beast");
    let data: Vec<u8> = one.repeat(250);
    let frames = frame_count(&mut BeastParser::new(), &data);
    assert_eq!(frames, 239 * 250);
    let mut group = c.benchmark_group("feed");
    group.throughput(Throughput::Elements(frames as u64));
    let mut out = Vec::with_capacity(8192);
    group.sample_size(20);
    group.measurement_time(Duration::from_secs(6));
    group.bench_function("beast_framing", |b| {
        b.iter_custom(|iters| {
            cpu_timed(iters, || {
                let mut p = BeastParser::new();
                black_box(parse_chunked(&mut p, black_box(&data), &mut out));
            })
        })
    });
    group.finish();
}

fn avr(c: &mut Criterion) {
    let data = fixture("lax-messages.avr.txt");
    let frames = frame_count(&mut TextParser::new(Format::Avr, 1000.0), &data);
    assert_eq!(frames, 215_606);
    let mut group = c.benchmark_group("feed");
    group.throughput(Throughput::Elements(frames as u64));
    group.sample_size(20);
    group.measurement_time(Duration::from_secs(10));
    let mut out = Vec::with_capacity(8192);
    group.bench_function("avr_text", |b| {
        b.iter_custom(|iters| {
            cpu_timed(iters, || {
                let mut p = TextParser::new(Format::Avr, 1000.0);
                black_box(parse_chunked(&mut p, black_box(&data), &mut out));
            })
        })
    });
    group.finish();
}

criterion_group!(benches, beast, avr);
criterion_main!(benches);
