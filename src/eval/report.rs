//! Tables of the evaluation: markdown for people, JSON for tools.

use super::score::{chi2_band_95, Scores};
use serde::Serialize;
use std::fmt::Write;

/// One tracker's merged scores on one scenario.
#[derive(Clone, Debug, Serialize)]
pub struct TrackerResult {
    pub tracker: String,
    pub runs: u64,
    pub scores: Scores,
    /// Median and 99th percentile of the CPU time per update, ns.
    pub cpu_ns_median_p99: Option<(u64, u64)>,
}

impl TrackerResult {
    /// A result with its CPU percentiles taken from the scores.
    pub fn new(tracker: String, runs: u64, scores: Scores) -> Self {
        let cpu_ns_median_p99 = scores.cpu_percentiles_ns();
        Self {
            tracker,
            runs,
            scores,
            cpu_ns_median_p99,
        }
    }
}

fn f(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "-".to_string(), |x| format!("{x:.digits$}"))
}

/// The ordering of rows: "all" first, then the modes in the papers' order.
const GROUPS: [&str; 6] = ["all", "CV", "CA", "CT", "CH", "CHCA"];

/// Markdown tables: errors per true mode, then labels, NEES and CPU.
pub fn markdown(title: &str, results: &[TrackerResult]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "### {title}\n");
    let _ = writeln!(
        s,
        "| tracker | true mode | updates | pos RMSE m | pos mean m | raw pos RMSE m | vel RMSE m/s | vel mean m/s | alt RMSE m |"
    );
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for r in results {
        for g in GROUPS {
            let Some(e) = r.scores.estimates.get(g) else {
                continue;
            };
            let raw = r.scores.raw.get(g).and_then(|x| x.pos_rmse());
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                r.tracker,
                g,
                e.n,
                f(e.pos_rmse(), 1),
                f(e.pos_mean(), 1),
                f(raw, 1),
                f(e.vel_rmse(), 2),
                f(e.vel_mean(), 2),
                f(e.alt_rmse(), 1),
            );
        }
    }
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "| tracker | runs | label accuracy | mean detection delay s | missed onsets | false switches /100 on CV | ANEES pos (2 dof) | ANEES vel (2 dof) | windowed NIS in 95 % band % | diverging % | peak pos err m | CPU/update median ns | p99 ns |"
    );
    let _ = writeln!(
        s,
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for r in results {
        let all = r.scores.estimates.get("all");
        let cpu = r.scores.cpu_percentiles_ns();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.1} | {} | {} |",
            r.tracker,
            r.runs,
            f(r.scores.label_accuracy().map(|a| 100.0 * a), 1) + " %",
            f(r.scores.mean_detection_delay_s(), 2),
            r.scores.missed_onsets,
            f(r.scores.false_switches_per_100(), 2),
            f(all.and_then(|a| a.anees_pos()), 2),
            f(all.and_then(|a| a.anees_vel()), 2),
            f(r.scores.nis_in_band_pct(), 1),
            f(r.scores.diverging_pct(), 2),
            r.scores.peak_pos_err_m,
            cpu.map_or("-".into(), |c| c.0.to_string()),
            cpu.map_or("-".into(), |c| c.1.to_string()),
        );
    }
    let _ = writeln!(
        s,
        "\n| tracker | turn onset (CT) s | acceleration onset (CA) s | climb/descent onset (CH) s | CHCA onset s | manoeuvre end (to CV) s |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|");
    for r in results {
        let cell = |mode: &str| {
            let (mean, n, missed) = r.scores.mean_delay_to_s(mode);
            match (n, missed) {
                (0, 0) => "-".to_string(),
                (_, 0) => format!("{} ({n})", f(mean, 2)),
                _ => format!("{} ({n}, {missed} missed)", f(mean, 2)),
            }
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} |",
            r.tracker,
            cell("CT"),
            cell("CA"),
            cell("CH"),
            cell("CHCA"),
            cell("CV"),
        );
    }
    let _ = writeln!(
        s,
        "\nDelays: from each change of the true mode to the first estimate with its label, mean over the changes (their number); the label table's mean detection delay is over every onset of a manoeuvre, the first four columns together."
    );
    let _ = writeln!(
        s,
        "\nANEES: 2 for a consistent filter; the 95 % band of the mean over N runs at one time is chi2(2N)/N, e.g. [{:.2}, {:.2}] for N = 100. Windowed NIS: the track's published `nis` (its last 20 updates, horizontal components) inside the two-sided 95 % band of chi2(`nis_dof`), about 95 % of the updates for a consistent filter whose innovations are white.",
        chi2_band_95(2.0, 100.0).0,
        chi2_band_95(2.0, 100.0).1
    );
    s
}
