use adsb_tracker::config::Config;
use adsb_tracker::eval::consistency;
use std::path::Path;
#[test]
fn diag() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join("afr34zg-cdg-tls.jsonl");
    let frames = consistency::read_frames_at(&path, None, 1000.0).unwrap();
    let mut config = Config::default_config().unwrap();
    if let Ok(n) = std::env::var("RUNMAX") {
        config.tracker.hybrid.outlier_max_in_a_row = n.parse().unwrap();
    }
    let mut p = adsb_tracker::eval::bench::sync_pipeline(&config, "hybrid");
    let mut t0 = None;
    for f in &frames {
        if let Some(s) = p.push(f).and_then(|u| u.state) {
            let t0 = *t0.get_or_insert(s.t);
            let steady = s.t - t0 >= 60.0
                && s.mode == "CV"
                && s.lateral == "straight"
                && s.speed == "constant"
                && s.vertical == "level"
                && !s.on_ground;
            if let (Some(n), Some(d)) = (s.nis, s.nis_dof) {
                if d > 0 {
                    let (lo, hi) = consistency::chi2_band(f64::from(d));
                    eprintln!(
                        "S {:.3} steady {} nis {:.1} dof {} band {:.1} {:.1} {}",
                        s.t,
                        steady,
                        n,
                        d,
                        lo,
                        hi,
                        if n > hi {
                            "ABOVE"
                        } else if n < lo {
                            "BELOW"
                        } else {
                            "in"
                        }
                    );
                }
            }
        }
    }
}
