//! Cost of one tracker update (predict + joint position/velocity update), the per-report work
//! of an aircraft task. Run: `cargo bench --bench tracker`.

use adsb_tracker::track::cv::CvKalman;
use adsb_tracker::track::{Measurement, Observed, Tracker};
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use nalgebra::{Matrix3, Vector3};

fn report(t_s: f64) -> Measurement {
    // A straight 230 m/s track with a deterministic ±20 m wobble, reported every 0.5 s.
    let wobble_m = 20.0 * (t_s * 1.7).sin();
    Measurement {
        t_s,
        position: Some(Observed {
            value: Vector3::new(230.0 * t_s + wobble_m, 40.0 * t_s - wobble_m, 10_000.0),
            cov: Matrix3::from_diagonal(&Vector3::new(900.0, 900.0, 100.0)),
            grid: None,
        }),
        velocity: Some(Observed {
            value: Vector3::new(230.0, 40.0, 0.0),
            cov: Matrix3::from_diagonal(&Vector3::new(2.25, 2.25, 1.0)),
            grid: None,
        }),
    }
}

fn cv_update(c: &mut Criterion) {
    let mut kf = CvKalman::default();
    let mut t_s = 0.0;
    // Past initiation, so that every measured call is a predict + update.
    for _ in 0..10 {
        kf.update(&report(t_s)).ok();
        t_s += 0.5;
    }
    c.bench_function("kalman-cv update (position + velocity)", |b| {
        b.iter(|| {
            t_s += 0.5;
            // A gap never exceeds 60 s here, so the track is never re-initialised.
            black_box(kf.update(black_box(&report(t_s))))
        })
    });
}

fn cv_predict(c: &mut Criterion) {
    let mut kf = CvKalman::default();
    for k in 0..10 {
        kf.update(&report(0.5 * f64::from(k))).ok();
    }
    // What serving an extrapolated estimate costs (F, Q and the Estimate copy).
    c.bench_function("kalman-cv predict 2 s ahead", |b| {
        b.iter(|| black_box(kf.predict(black_box(6.5))))
    });
}

criterion_group!(benches, cv_update, cv_predict);
criterion_main!(benches);
