//! Beast framing of the real recording under every split, with garbage and a cut tail.
//!
//! The expected frames come from `feed_common::beast_reference`, a plain reader written from
//! the format description, not from the parser under test.

mod feed_common;

use adsb_tracker::feed::beast::BeastParser;
use adsb_tracker::feed::{FrameParser, ParseStats, RawFrame};
use feed_common::{
    beast_encode, beast_reference, parse_pieces, random_pieces, read_fixture, RefFrame,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn recording() -> (Vec<u8>, Vec<RefFrame>) {
    let wire = read_fixture("toulouse-sample.beast");
    let frames = beast_reference(&wire);
    assert_eq!(frames.len(), 239);
    (wire, frames)
}

fn assert_frames(got: &[RawFrame], want: &[RefFrame]) {
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert_eq!(g.bytes(), &w.data[..], "frame {i}");
        assert_eq!(g.signal, Some(w.signal), "frame {i}");
        assert_eq!(g.time_s, w.counter as f64 / 12e6, "frame {i}");
    }
}

fn clean(frames: u64) -> ParseStats {
    ParseStats {
        frames,
        ..ParseStats::default()
    }
}

#[test]
fn every_chunk_size_gives_the_same_frames() {
    let (wire, want) = recording();
    for chunk in 1..=wire.len() {
        let mut p = BeastParser::new();
        let got = parse_pieces(&mut p, wire.chunks(chunk));
        assert_frames(&got, &want);
        assert_eq!(p.stats(), &clean(239), "chunk {chunk}");
    }
}

#[test]
fn random_splits_give_the_same_frames() {
    let (wire, want) = recording();
    let mut rng = StdRng::seed_from_u64(0x5eed_0001);
    for round in 0..300 {
        let cuts = rng.gen_range(1..400);
        let mut p = BeastParser::new();
        let got = parse_pieces(&mut p, random_pieces(&wire, &mut rng, cuts));
        assert_frames(&got, &want);
        assert_eq!(p.stats(), &clean(239), "round {round}");
    }
}

#[test]
fn garbage_between_frames_is_skipped_and_counted_exactly() {
    let (wire, want) = recording();
    let mut rng = StdRng::seed_from_u64(0x5eed_0002);
    for round in 0..100 {
        let mut noisy = Vec::with_capacity(wire.len() * 2);
        let mut inserted = 0u64;
        for (i, f) in want.iter().enumerate() {
            // Garbage before about half the frames (and so also before the first).
            if rng.gen_bool(0.5) || i == 0 {
                let n = rng.gen_range(1..40);
                for _ in 0..n {
                    let b = loop {
                        let b: u8 = rng.gen();
                        if b != 0x1a {
                            break b;
                        }
                    };
                    noisy.push(b);
                }
                inserted += n as u64;
            }
            noisy.extend_from_slice(&wire[f.start..f.end]);
        }
        noisy.extend_from_slice(b"trailing garbage");
        inserted += 16;

        let mut p = BeastParser::new();
        let cuts = rng.gen_range(1..200);
        let got = parse_pieces(&mut p, random_pieces(&noisy, &mut rng, cuts));
        assert_frames(&got, &want);
        let expected = ParseStats {
            frames: 239,
            garbage_bytes: inserted,
            ..ParseStats::default()
        };
        assert_eq!(p.stats(), &expected, "round {round}");
    }
}

#[test]
fn truncated_tail_is_counted_and_every_intact_frame_kept() {
    let (wire, want) = recording();
    let last = &want[238];
    // Cut the last frame after each possible byte of it.
    for cut in last.start + 1..last.end {
        let mut p = BeastParser::new();
        let got = parse_pieces(&mut p, wire[..cut].chunks(97));
        assert_frames(&got, &want[..238]);
        let expected = ParseStats {
            frames: 238,
            truncated_tail_bytes: (cut - last.start) as u64,
            ..ParseStats::default()
        };
        assert_eq!(p.stats(), &expected, "cut at {cut}");
    }
}

#[test]
fn frame_cut_short_mid_stream_resynchronises_on_the_next_frame() {
    let (wire, want) = recording();
    // Drop the second half of frame 100: the next frame's 0x1a ends it.
    let f = &want[100];
    let keep = (f.end - f.start) / 2;
    let mut damaged = wire[..f.start + keep].to_vec();
    damaged.extend_from_slice(&wire[f.end..]);
    let mut p = BeastParser::new();
    let got = parse_pieces(&mut p, damaged.chunks(13));
    let mut expect: Vec<RefFrame> = want.clone();
    expect.remove(100);
    assert_frames(&got, &expect);
    assert_eq!(p.stats().bad_frames, 1);
    assert_eq!(p.stats().garbage_bytes, keep as u64);
}

#[test]
fn parser_is_reusable_after_finish() {
    let (wire, want) = recording();
    let mut p = BeastParser::new();
    let mid = (want[120].start + want[120].end) / 2;
    let mut got = parse_pieces(&mut p, [&wire[..mid]]);
    // A reconnect: the rest of the cut frame arrives first, then whole frames.
    got.extend(parse_pieces(&mut p, [&wire[mid..]]));
    let mut expect: Vec<RefFrame> = want.clone();
    expect.remove(120);
    assert_frames(&got, &expect);
    assert_eq!(
        p.stats().truncated_tail_bytes,
        (mid - want[120].start) as u64
    );
    assert_eq!(p.stats().garbage_bytes, (want[120].end - mid) as u64);
}

#[test]
fn recording_replayed_twice_keeps_time_running_forward() {
    let (wire, want) = recording();
    let twice = [wire.clone(), wire].concat();
    let mut p = BeastParser::new();
    let got = parse_pieces(&mut p, twice.chunks(500));
    assert_eq!(got.len(), 478);
    assert_frames(&got[..239], &want);
    // The counter steps back 24 s at the seam: one rebase, and the second copy continues
    // from the last time with the recording's own spacing.
    assert_eq!(p.stats().clock_resets, 1);
    let last_s = want[238].counter as f64 / 12e6;
    for (g, w) in got[239..].iter().zip(&want) {
        let expected_s = last_s + (w.counter - want[0].counter) as f64 / 12e6;
        assert!(
            (g.time_s - expected_s).abs() < 1e-9,
            "{} vs {expected_s}",
            g.time_s
        );
        assert_eq!(g.bytes(), &w.data[..]);
    }
    assert!(got.windows(2).all(|w| w[0].time_s <= w[1].time_s));
}

#[test]
fn counter_wrap_keeps_elapsed_time() {
    let (_, want) = recording();
    // Re-stamp the recording so that the 48-bit counter wraps just before frame 100 (which
    // lands on 1000 ticks, not 0: a zero counter means "no time").
    let wrap_at = want[100].counter;
    let start = (1u64 << 48) - (wrap_at - want[0].counter) + 1000;
    let wire: Vec<u8> = want
        .iter()
        .flat_map(|f| {
            let counter = (start + (f.counter - want[0].counter)) % (1 << 48);
            beast_encode(counter, f.signal, &f.data)
        })
        .collect();
    let mut p = BeastParser::new();
    let got = parse_pieces(&mut p, wire.chunks(64));
    assert_eq!(got.len(), 239);
    assert_eq!(p.stats().clock_resets, 1);
    let t0 = got[0].time_s;
    assert_eq!(t0, start as f64 / 12e6);
    for (g, w) in got.iter().zip(&want) {
        let elapsed_s = (w.counter - want[0].counter) as f64 / 12e6;
        // Relative to a time of 2^48 / 12e6 = 2.3e7 s, f64 resolves about 4e-9 s.
        assert!(
            (g.time_s - t0 - elapsed_s).abs() < 1e-7,
            "{}",
            g.time_s - t0 - elapsed_s
        );
    }
}
