//! The evaluation bench: trackers scored against simulated truth, side by side.
//!
//! Real recordings have no truth; simulated flights do, and they go through the very decode and
//! tracking code of the daemon ([`crate::daemon::pipeline`]).

pub mod bench;
pub mod consistency;
pub mod io;
pub mod latency;
pub mod plot;
pub mod report;
pub mod score;
