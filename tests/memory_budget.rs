//! Issue 9's memory budget: under 16 KiB of RSS per aircraft at 1,000 aircraft (README,
//! "At fleet scale": 14.1-14.6 KiB with the default tracker after 9.3 minutes of feed, the
//! trails nearly full; 15.8-16.4 KiB before the trails were stored as prediction errors,
//! `docs/speed.md`). What an aircraft holds besides its trail is mostly these
//! structs; a change that grows one shows here, before a fleet benchmark would show it
//! (the README's figure had gone stale at 18 KiB while the real one grew to 30 KiB).

use adsb_tracker::daemon::aircraft::Aircraft;
use adsb_tracker::track::cv::CvKalman;
use adsb_tracker::track::gate::{Gate, GateParams};
use adsb_tracker::track::hybrid::HybridTracker;
use adsb_tracker::track::imm::Imm;
use std::mem::size_of;

#[test]
fn what_an_aircraft_holds_stays_within_its_budget() {
    // The aircraft itself (boxed into its task): decoder state, facts, frame; the rare
    // ended snapshot boxed (inline, it took 536 bytes of the 1,232). 40 bytes recognise a
    // report heard twice (`decode.duplicate_window_s`): 208 when they held the reports.
    assert!(size_of::<Aircraft>() <= 800, "{}", size_of::<Aircraft>());
    // The default tracker, its tuning shared: 6.3 KB when each held its own copy and the
    // gate's 32-report buffer inline; 48 bytes more since its IMM's model set follows the
    // gate (when the gate last named each mode), 16 since it learns its velocity reports'
    // age (the lag its IMM uses, and the boxed learner), 24 since it sets aside positions out
    // of their time (`track::outlier`: a run, a share, a count), 72 since it learns the white
    // position noise from successive reports (`track::noise`: a scale and the last report),
    // 56 since a velocity report carries its grid (`track::quantised::Grid`, in the pending
    // velocity) and the IMM its published mode's NIS, 32 since its steady-flight q_h is
    // scaled per aircraft (`track::process_noise`: a scale, a count, a span), 40 since it
    // learns the tail index of its position innovations (`track::tails`: two percentiles,
    // a count, ν), 8 since its IMM keeps its CV model's along-track innovation for the
    // plain `imm`'s learner and 48 since each of its three noise scales keeps the data's own
    // mean and whether they contradict the declaration (`track::noise`), 16 since its IMM
    // branch sets aside positions its held mode's velocity fit vouches for (`track::outlier`:
    // the last velocity report's time, mode and fit), 56 since it reads its velocity reports'
    // terms under their own tail index (`track::tails`: 40 for the index, 16 for the two
    // quantile residuals its IMM keeps of its published term), 72 since its gate holds an
    // acceleration by the line through its reports since it fired (`track::gate`: the
    // line's sums and where it starts), 64 since its learner centres the velocity innovation
    // on its running mean (`track::noise::InnovationMean`, 32) and each innovation summary its
    // IMM keeps for the plain `imm`'s learner carries the innovation's two horizontal
    // components (`track::noise::BlockStat`, 2 × 16), 8 since its gate notes the newest
    // barometric altitude (`track::gate`: the altitude-confirmed climb onset).
    assert!(
        size_of::<HybridTracker>() <= 2352,
        "{}",
        size_of::<HybridTracker>()
    );
    // 16 bytes more since it keeps the quantile residuals of its published term, 32 since
    // its CV model's two innovation summaries carry their horizontal components.
    assert!(size_of::<Imm>() <= 624, "{}", size_of::<Imm>());
    // The hybrid's velocity-lag learner, boxed on its first report: the sums of one 60 s
    // window and a few positions waiting for the next velocity report.
    assert!(
        size_of::<adsb_tracker::track::lag::VelocityLag>() <= 400,
        "{}",
        size_of::<adsb_tracker::track::lag::VelocityLag>()
    );
    // 72 bytes more since it holds an acceleration by its own line (the sums since it fired),
    // 8 since it notes the newest barometric altitude (the altitude-confirmed climb onset).
    assert!(size_of::<Gate>() <= 336, "{}", size_of::<Gate>());
    // 56 bytes more since a pending velocity report carries its grid.
    assert!(size_of::<CvKalman>() <= 816, "{}", size_of::<CvKalman>());
    // What the router queues per message between two batches (`decode::Heard`): a busy
    // second's messages of 1000 aircraft. 104 bytes each as decoded messages, which
    // outgrew the second-level cache (the type's doc).
    assert!(
        size_of::<adsb_tracker::decode::Heard>() <= 24,
        "{}",
        size_of::<adsb_tracker::decode::Heard>()
    );
    // Trackers built with one tuning share it: the same tracker twice costs no second copy
    // (a pointer each).
    let (a, b) = (HybridTracker::default(), HybridTracker::default());
    assert!(std::ptr::eq(a.params(), b.params()));
    let (g1, g2) = (
        Gate::new(GateParams::default()),
        Gate::new(GateParams::default()),
    );
    assert!(std::ptr::eq(g1.params(), g2.params()));
}
