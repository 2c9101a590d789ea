//! The specialised Kalman steps against the generic dense ones they replace (the same
//! predictions bit for bit, updates equal to rounding: tested in `track::kalman`): one CV
//! update (6-state, joint position/velocity
//! report) and one 9-state IMM cycle's filtering (the six models' prediction and update),
//! plus a whole `Imm::step` (mixing, filtering, probabilities).

use adsb_tracker::track::divergence::{guarded_update, DivergenceParams, Observation, Prediction};
use adsb_tracker::track::imm::{Imm, ImmParams};
use adsb_tracker::track::kalman::{self, MotionModel};
use adsb_tracker::track::models::{Cv, Matrix6, Matrix9, State6, State9};
use adsb_tracker::track::Observed;
use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use std::hint::black_box;

/// A converged-looking covariance: position σ ~10 m, velocity ~1 m/s, acceleration ~0.5
/// m/s², correlated within each axis.
fn covariance9() -> Matrix9 {
    let mut p = Matrix9::zeros();
    for axis in 0..3 {
        let (i, j, k) = (axis, axis + 3, axis + 6);
        p[(i, i)] = 100.0;
        p[(j, j)] = 1.0;
        p[(k, k)] = 0.25;
        p[(i, j)] = 3.0;
        p[(j, i)] = 3.0;
        p[(j, k)] = 0.1;
        p[(k, j)] = 0.1;
    }
    p
}

fn report() -> (Observed, Observed) {
    (
        Observed {
            value: Vector3::new(12.0, -7.0, 9005.0),
            cov: Matrix3::from_diagonal(&Vector3::new(100.0, 100.0, 225.0)),
            grid: None,
        },
        Observed {
            value: Vector3::new(120.5, 0.3, -0.2),
            cov: Matrix3::identity() * 0.27,
            grid: None,
        },
    )
}

fn joint(pos: &Observed, vel: &Observed) -> (SVector<f64, 6>, SMatrix<f64, 6, 6>) {
    let mut z = SVector::<f64, 6>::zeros();
    z.fixed_rows_mut::<3>(0).copy_from(&pos.value);
    z.fixed_rows_mut::<3>(3).copy_from(&vel.value);
    let mut r = SMatrix::<f64, 6, 6>::zeros();
    r.fixed_view_mut::<3, 3>(0, 0).copy_from(&pos.cov);
    r.fixed_view_mut::<3, 3>(3, 3).copy_from(&vel.cov);
    (z, r)
}

fn cv_update(c: &mut Criterion) {
    let (pos, vel) = report();
    let (z, r) = joint(&pos, &vel);
    let x = State6::from_column_slice(&[0.0, 0.0, 9000.0, 120.0, 0.0, 0.0]);
    let p = covariance9().fixed_view::<6, 6>(0, 0).into_owned();
    let cv = Cv::default();
    let mut g = c.benchmark_group("cv-step");
    g.bench_function("update-dense", |b| {
        b.iter(|| {
            let (mut x, mut p) = (x, p);
            let h = Matrix6::identity();
            black_box(kalman::update_dense(&mut x, &mut p, &z, &h, &r).ok());
            (x, p)
        })
    });
    g.bench_function("update-selected", |b| {
        b.iter(|| {
            let (mut x, mut p) = (x, p);
            let sel = kalman::blocks6(0, 3);
            black_box(kalman::update_selected(&mut x, &mut p, &z, &sel, &r).ok());
            (x, p)
        })
    });
    g.bench_function("predict-dense", |b| {
        b.iter(|| {
            let dt = black_box(0.5);
            let f = MotionModel::<6>::f(&cv, dt);
            let q = MotionModel::<6>::q(&cv, dt);
            (f * x, kalman::symmetrise(&(f * p * f.transpose() + q)))
        })
    });
    // Through the trait (`fq`, then `kalman::predict`, which keeps the dense product below 9x9).
    // F P Fᵀ alone: nalgebra's dense product against the one written out on the models'
    // 6-state support (`kalman::sparse_fpf`, the same bits).
    let f6 = MotionModel::<6>::f(&cv, 0.5);
    g.bench_function("fpf-dense", |b| {
        b.iter(|| {
            let p = black_box(&p);
            f6 * p * f6.transpose()
        })
    });
    g.bench_function("fpf-support", |b| {
        b.iter(|| kalman::sparse_fpf(&f6, black_box(&p)))
    });
    g.bench_function("predict-trait", |b| {
        b.iter(|| {
            let (mut x, mut p) = (x, p);
            MotionModel::<6>::predict(&cv, &mut x, &mut p, black_box(0.5));
            (x, p)
        })
    });
    g.finish();
}

fn imm_filtering(c: &mut Criterion) {
    let (pos, vel) = report();
    let (z, r) = joint(&pos, &vel);
    let obs = Observation::Both(pos, vel);
    let mut x = State9::zeros();
    x[2] = 9000.0;
    x[3] = 120.0;
    let p = covariance9();
    let models = ImmParams::default().models.models();
    let params = DivergenceParams::default();
    let mut g = c.benchmark_group("imm-step");
    // The six mode-matched filters of one IMM cycle, generic: dense F P Fᵀ, dense update.
    g.bench_function("six-filters-dense", |b| {
        b.iter(|| {
            let mut h = SMatrix::<f64, 6, 9>::zeros();
            for i in 0..6 {
                h[(i, i)] = 1.0;
            }
            let mut out = [0.0; 6];
            for (o, m) in out.iter_mut().zip(&models) {
                let dt = black_box(0.5);
                let f = m.f(dt);
                let (mut x1, mut p1) = (
                    f * x,
                    kalman::symmetrise(&(f * p * f.transpose() + m.q(dt))),
                );
                if let Ok(inn) = kalman::update_dense(&mut x1, &mut p1, &z, &h, &r) {
                    *o = inn.log_likelihood() + p1[(0, 0)];
                }
            }
            out
        })
    });
    // The same with the specialised steps, through paper 000's guard as the IMM runs them.
    g.bench_function("six-filters-specialised", |b| {
        b.iter(|| {
            let mut out = [0.0; 6];
            for (o, m) in out.iter_mut().zip(&models) {
                let pred = Prediction::<9>::new(m.as_dyn(), &x, &p, black_box(0.5));
                let (mut x1, mut p1) = (x, p);
                if let Ok(gd) = guarded_update(&pred, &obs, &params, 0, &mut x1, &mut p1) {
                    *o = gd.log_likelihood + p1[(0, 0)];
                }
            }
            out
        })
    });
    let ct = models[2];
    g.bench_function("ct-fpf-dense", |b| {
        b.iter(|| {
            let (f, q) = ct.fq(black_box(0.5));
            f * p * f.transpose() + q
        })
    });
    g.bench_function("ct-fpf-sparse", |b| {
        b.iter(|| {
            let (f, q) = ct.fq(black_box(0.5));
            kalman::sparse_fpf(&f, &p) + q
        })
    });
    let mut imm = Imm::new(ImmParams::default());
    imm.reset(&x, &p, None);
    // Spread the modes apart as a turn does.
    for _ in 0..20 {
        let _ = imm.step(0.5, &obs);
    }
    g.bench_function("imm-step", |b| {
        b.iter_batched_ref(
            || imm.clone(),
            |imm| black_box(imm.step(black_box(0.5), &obs)),
            criterion::BatchSize::SmallInput,
        )
    });
    // A realistic run: a 3°/s turn at 120 m/s reported as ADS-B does, a position and a
    // velocity report alternately every 0.25 s (ten seconds of them), with a few metres and
    // tenths of m/s of deterministic scatter. Per report, the cost of `Imm::step` in a
    // manoeuvre, the IMM's working regime in the hybrid tracker.
    let omega = 3f64.to_radians();
    let reports: Vec<Observation> = (0..40)
        .map(|k| {
            let t = 0.25 * k as f64;
            let (s, c) = (omega * t).sin_cos();
            let wobble = (1.7 * k as f64).sin();
            if k % 2 == 0 {
                Observation::Position(Observed {
                    value: Vector3::new(
                        120.0 * s / omega + 4.0 * wobble,
                        120.0 * (1.0 - c) / omega,
                        9000.0,
                    ),
                    cov: Matrix3::from_diagonal(&Vector3::new(100.0, 100.0, 225.0)),
                    grid: None,
                })
            } else {
                Observation::Velocity(Observed {
                    value: Vector3::new(120.0 * c + 0.3 * wobble, 120.0 * s, 0.1 * wobble),
                    cov: Matrix3::identity() * 0.27,
                    grid: None,
                })
            }
        })
        .collect();
    let mut start = Imm::new(ImmParams::default());
    let mut x0 = State9::zeros();
    x0[2] = 9000.0;
    x0[3] = 120.0;
    start.reset(&x0, &covariance9(), None);
    g.throughput(criterion::Throughput::Elements(reports.len() as u64));
    g.bench_function("turn-reports", |b| {
        b.iter_batched_ref(
            || start.clone(),
            |imm| {
                for obs in &reports {
                    let _ = black_box(imm.step(black_box(0.25), obs));
                }
            },
            criterion::BatchSize::SmallInput,
        )
    });
    g.finish();
}

criterion_group!(benches, cv_update, imm_filtering);
criterion_main!(benches);
