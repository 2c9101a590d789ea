//! SVG plots of an evaluation: truth and estimates on a map, error over time, and the mode
//! timeline against truth.

use super::bench::RunTrace;
use super::score::TruthTrack;
use crate::decode::Icao;
use crate::track::geo::LocalFrame;
use crate::track::FlightMode;
use plotters::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Colours of the trackers, in order.
const PALETTE: [RGBColor; 6] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
];

fn err<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

fn mode_row(m: FlightMode) -> f64 {
    match m {
        FlightMode::Cv => 0.0,
        FlightMode::Ca => 1.0,
        FlightMode::Ct => 2.0,
        FlightMode::Ch => 3.0,
        FlightMode::Chca => 4.0,
    }
}

/// Writes `PREFIX-map.svg`, `PREFIX-error.svg` and `PREFIX-modes.svg` for the first aircraft
/// of the truth; returns the paths written.
pub fn plot_run(
    prefix: &Path,
    title: &str,
    truth: &BTreeMap<Icao, TruthTrack>,
    traces: &[(String, RunTrace)],
) -> Result<Vec<PathBuf>, String> {
    let Some((icao, tr)) = truth.iter().next() else {
        return Ok(Vec::new());
    };
    let Some(first) = tr.samples().first() else {
        return Ok(Vec::new());
    };
    let frame = LocalFrame::new(first.lat, first.lon, 0.0);
    let en = |lat: f64, lon: f64| {
        let v = frame.to_enu(lat, lon, 0.0);
        (v.x / 1000.0, v.y / 1000.0)
    };
    let path_of = |suffix: &str| {
        let mut p = prefix.as_os_str().to_owned();
        p.push(suffix);
        PathBuf::from(p)
    };
    let mut written = Vec::new();

    // Map: truth, raw positions and each tracker's estimates, km east/north.
    let truth_xy: Vec<(f64, f64)> = tr.samples().iter().map(|s| en(s.lat, s.lon)).collect();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in &truth_xy {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    let pad = 0.05 * (x1 - x0).max(y1 - y0).max(1.0);
    let map_path = path_of("-map.svg");
    {
        let root = SVGBackend::new(&map_path, (900, 800)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut c = ChartBuilder::on(&root)
            .caption(format!("{title}: {icao} on the map"), ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d((x0 - pad)..(x1 + pad), (y0 - pad)..(y1 + pad))
            .map_err(err)?;
        c.configure_mesh()
            .x_desc("east, km")
            .y_desc("north, km")
            .draw()
            .map_err(err)?;
        if let Some((_, t0)) = traces.first() {
            if let Some(raw) = t0.raw.get(icao) {
                c.draw_series(
                    raw.iter().map(|r| {
                        Circle::new(en(r.lat, r.lon), 1, RGBColor(170, 170, 170).filled())
                    }),
                )
                .map_err(err)?
                .label("measured positions")
                .legend(|(x, y)| Circle::new((x + 10, y), 3, RGBColor(170, 170, 170).filled()));
            }
        }
        c.draw_series(LineSeries::new(
            truth_xy.iter().copied(),
            BLACK.stroke_width(2),
        ))
        .map_err(err)?
        .label("truth")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
        for (i, (name, t)) in traces.iter().enumerate() {
            let col = PALETTE[i % PALETTE.len()];
            if let Some(est) = t.estimates.get(icao) {
                c.draw_series(LineSeries::new(est.iter().map(|e| en(e.lat, e.lon)), col))
                    .map_err(err)?
                    .label(name.as_str())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], col));
            }
        }
        c.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    written.push(map_path);

    // Position error over time.
    let t_start = first.t;
    let t_end = tr.samples().last().map_or(t_start + 1.0, |s| s.t);
    let mut series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    let mut y_max: f64 = 1.0;
    for (name, t) in traces {
        let pts: Vec<(f64, f64)> = t
            .estimates
            .get(icao)
            .map(|est| {
                est.iter()
                    .filter_map(|e| {
                        let truth = tr.at(e.t)?;
                        let f = LocalFrame::new(truth.lat, truth.lon, truth.alt_m);
                        let d = f.to_enu(e.lat, e.lon, e.alt_m);
                        Some((e.t - t_start, d.x.hypot(d.y)))
                    })
                    .collect()
            })
            .unwrap_or_default();
        // Clip the axis at the 99th percentile so one spike does not flatten the rest.
        let mut ys: Vec<f64> = pts.iter().map(|p| p.1).collect();
        ys.sort_by(f64::total_cmp);
        if let Some(&p99) = ys.get(ys.len().saturating_sub(1) * 99 / 100) {
            y_max = y_max.max(p99 * 1.2);
        }
        series.push((name.clone(), pts));
    }
    let err_path = path_of("-error.svg");
    {
        let root = SVGBackend::new(&err_path, (1000, 420)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut c = ChartBuilder::on(&root)
            .caption(
                format!("{title}: horizontal position error"),
                ("sans-serif", 20),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(0.0..(t_end - t_start), 0.0..y_max)
            .map_err(err)?;
        c.configure_mesh()
            .x_desc("time, s")
            .y_desc("error, m")
            .draw()
            .map_err(err)?;
        for (i, (name, pts)) in series.iter().enumerate() {
            let col = PALETTE[i % PALETTE.len()];
            c.draw_series(LineSeries::new(
                pts.iter().map(|&(x, y)| (x, y.min(y_max))),
                col,
            ))
            .map_err(err)?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], col));
        }
        c.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    written.push(err_path);

    // Mode timeline: truth as a thick line, each tracker's label as dots slightly offset.
    let modes_path = path_of("-modes.svg");
    {
        let root = SVGBackend::new(&modes_path, (1000, 360)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut c = ChartBuilder::on(&root)
            .caption(
                format!("{title}: flight-mode label against truth"),
                ("sans-serif", 20),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..(t_end - t_start), -0.5..4.5)
            .map_err(err)?;
        c.configure_mesh()
            .x_desc("time, s")
            .y_labels(5)
            .y_label_formatter(&|y: &f64| {
                let labels = ["CV", "CA", "CT", "CH", "CHCA"];
                labels
                    .get(y.round().clamp(0.0, 4.0) as usize)
                    .map_or(String::new(), |s| s.to_string())
            })
            .draw()
            .map_err(err)?;
        c.draw_series(LineSeries::new(
            tr.samples()
                .iter()
                .map(|s| (s.t - t_start, mode_row(s.mode))),
            BLACK.stroke_width(3),
        ))
        .map_err(err)?
        .label("truth")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(3)));
        for (i, (name, t)) in traces.iter().enumerate() {
            let col = PALETTE[i % PALETTE.len()];
            let off = 0.12 * (i as f64 + 1.0);
            if let Some(est) = t.estimates.get(icao) {
                c.draw_series(est.iter().map(|e| {
                    Circle::new((e.t - t_start, mode_row(e.mode) + off), 1, col.filled())
                }))
                .map_err(err)?
                .label(name.as_str())
                .legend(move |(x, y)| Circle::new((x + 10, y), 3, col.filled()));
            }
        }
        c.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    written.push(modes_path);
    Ok(written)
}

/// The flight-mode timeline of one aircraft of a real recording (no truth): its altitude
/// profile, and its label at each update. Writes `PREFIX-timeline.svg`.
pub fn plot_timeline(
    prefix: &Path,
    title: &str,
    estimates: &[super::score::EstimateSample],
) -> Result<PathBuf, String> {
    let mut p = prefix.as_os_str().to_owned();
    p.push("-timeline.svg");
    let path = PathBuf::from(p);
    let (Some(first), Some(last)) = (estimates.first(), estimates.last()) else {
        return Err("no estimates to plot".into());
    };
    let t0 = first.t;
    let span_min = ((last.t - t0) / 60.0).max(1.0);
    let alt_max = estimates.iter().map(|e| e.alt_m).fold(1000.0_f64, f64::max) * 1.05;
    let svg_path = path.clone();
    let root = SVGBackend::new(&svg_path, (1100, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let (upper, lower) = root.split_vertically(300);
    let mut c = ChartBuilder::on(&upper)
        .caption(format!("{title}: altitude"), ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(25)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..span_min, 0.0..alt_max)
        .map_err(err)?;
    c.configure_mesh()
        .y_desc("altitude, m")
        .draw()
        .map_err(err)?;
    c.draw_series(LineSeries::new(
        estimates.iter().map(|e| ((e.t - t0) / 60.0, e.alt_m)),
        PALETTE[0].stroke_width(2),
    ))
    .map_err(err)?;
    let mut m = ChartBuilder::on(&lower)
        .caption("flight-mode label", ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..span_min, -0.5..4.5)
        .map_err(err)?;
    m.configure_mesh()
        .x_desc("time, min")
        .y_labels(5)
        .y_label_formatter(&|y: &f64| {
            ["CV", "CA", "CT", "CH", "CHCA"]
                .get(y.round().clamp(0.0, 4.0) as usize)
                .map_or(String::new(), |s| s.to_string())
        })
        .draw()
        .map_err(err)?;
    m.draw_series(estimates.iter().map(|e| {
        Circle::new(
            ((e.t - t0) / 60.0, mode_row(e.mode)),
            1,
            PALETTE[1].filled(),
        )
    }))
    .map_err(err)?;
    root.present().map_err(err)?;
    Ok(path)
}
