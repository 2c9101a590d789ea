//! The embedded default (issue 12, item 6): `serve` with no feed and no file replays the LAX
//! recording at its real rate with LAX as the receiver; `replay.embedded = "afr34zg"` (or
//! `serve --embedded afr34zg`) selects the single flight.

use adsb_tracker::app::{run, serve_source, RunOptions};
use adsb_tracker::config::Config;
use adsb_tracker::daemon::Source;
use tokio_util::sync::CancellationToken;

/// `serve`'s source for `config`, run once to its end as fast as possible.
async fn serve_once(text: &str) -> (Config, adsb_tracker::daemon::RunSummary) {
    let mut cfg = Config::from_toml_str(text).unwrap();
    let mut source = serve_source(&mut cfg).unwrap();
    let Source::Replay(replay) = &mut source else {
        panic!("no feed configured: a replay")
    };
    // As served: paced at real time, looping; here once, at full speed.
    assert_eq!(replay.speed, 1.0);
    assert!(replay.loop_);
    replay.speed = 0.0;
    replay.loop_ = false;
    let summary = run(
        cfg.clone(),
        RunOptions {
            source,
            listener: None,
            tracks_out: None,
            exit_at_end: true,
        },
        CancellationToken::new(),
    )
    .await
    .unwrap();
    (cfg, summary)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_default_is_lax_at_its_real_rate() {
    let (cfg, s) = serve_once("").await;
    assert_eq!(cfg.replay.embedded, "lax");
    let r = cfg.receiver.unwrap();
    assert_eq!((r.lat_deg, r.lon_deg), (33.9425, -118.4081));
    let s = s.stats;
    // 215,606 frames at 270 frames/s: 798.5 s of nominal time, and the real clock the
    // aircraft show (`decode.fit_untimed_clock`, `feed::pace`) is within 1 % of it in
    // length (796.1 s) while its rate swings by ±30 %.
    assert_eq!(s.frames, 215_606);
    let nominal_s = 215_605.0 / 270.0;
    assert!(
        (s.feed_time - nominal_s).abs() < 0.01 * nominal_s && (s.feed_time - nominal_s).abs() > 0.5,
        "{}",
        s.feed_time
    );
    assert!(s.tracks_created >= 170, "{}", s.tracks_created);
    assert!(s.track_updates > 45_000, "{}", s.track_updates);
    // At the real rate the aircraft fly at their speeds: at 1,000 frames/s (3.7 times too
    // slow a clock) positions would still pass, but at too fast a clock they would be
    // refused as impossible. One in 10,000 is.
    let too_fast = s
        .positions_rejected
        .get("impossible_speed")
        .copied()
        .unwrap_or(0);
    assert!(
        too_fast * 10_000 < s.positions_accepted,
        "{too_fast} of {}",
        s.positions_accepted
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn afr34zg_stays_selectable() {
    let (cfg, s) = serve_once("[replay]\nembedded = \"afr34zg\"\n").await;
    let r = cfg.receiver.unwrap();
    assert_eq!((r.lat_deg, r.lon_deg), (49.0097, 2.5479));
    assert_eq!(s.stats.frames, 57_793);
    assert_eq!(s.stats.tracks_created, 1);
    // A configured receiver is kept.
    let (cfg, _) = serve_once(
        "[replay]\nembedded = \"afr34zg\"\n[receiver]\nlat_deg = 43.63\nlon_deg = 1.37\n",
    )
    .await;
    assert_eq!(cfg.receiver.unwrap().lat_deg, 43.63);
}
