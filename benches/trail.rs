//! What the trail costs (`src/daemon/history.rs`): a point recorded (a point of the track's
//! plane, stored as it is), the geodetic conversion a point no longer takes when it is
//! recorded, and a full default trail (600 points) read as the API serves it, each point
//! converted then, and written as JSON.

use std::hint::black_box;
use std::time::Duration;

use adsb_tracker::config::HistoryConfig;
use adsb_tracker::daemon::history::Trail;
use adsb_tracker::track::geo::LocalFrame;
use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Vector3;

/// The default trail: 10 minutes, 600 points.
fn config() -> HistoryConfig {
    HistoryConfig {
        window_minutes: 10.0,
        max_points: 600,
    }
}

/// An airliner at 250 m/s and 3 km, a point a second, in its track's plane.
fn point(i: u64) -> (f64, Vector3<f64>) {
    let s = i as f64;
    (1.7e9 + s, Vector3::new(160.0 * s, 190.0 * s, 3000.0))
}

fn trail(c: &mut Criterion) {
    let cfg = config();
    let frame = LocalFrame::new(51.47, -0.45, 0.0);
    let mut full = Trail::default();
    for i in 0..600 {
        let (t_s, enu) = point(i);
        full.push_enu(&cfg, t_s, &frame, &enu);
    }
    assert_eq!(full.len(), 600);
    let mut group = c.benchmark_group("trail");
    group.sample_size(20);
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(3));
    // A point recorded into a full trail (the oldest one dropped): what every aircraft
    // pays about once a second.
    let mut recording = Trail::default();
    let mut i = 0;
    group.bench_function("record_point", |b| {
        b.iter(|| {
            let (t_s, enu) = point(i);
            recording.push_enu(&cfg, t_s, &frame, black_box(&enu));
            i += 1;
        })
    });
    group.bench_function("to_geodetic", |b| {
        b.iter(|| frame.to_geodetic(black_box(&Vector3::new(12_000.0, 9_000.0, 3000.0))))
    });
    group.bench_function("read_600_points", |b| b.iter(|| black_box(&full).points()));
    // What a history response costs beyond the read: its JSON.
    let points = full.points();
    group.bench_function("json_600_points", |b| {
        b.iter(|| serde_json::to_vec(black_box(&points)).map(|v| v.len()))
    });
    group.finish();
}

criterion_group!(benches, trail);
criterion_main!(benches);
