//! SBS "BaseStation" text on TCP (port 30003 by convention): the 22 comma-separated fields
//! that Virtual Radar Server, PlanePlotter and loggers read, with our *estimates* where a
//! decoder would repeat the last report.
//!
//! Per tracker update: `MSG,3` (airborne position: estimated latitude, longitude and
//! altitude) or `MSG,2` (surface position, with ground speed and track), then `MSG,4`
//! (airborne velocity: ground speed, track, vertical rate) when airborne. When the aircraft's
//! identity facts change: `MSG,1` (callsign), `MSG,5` (reported barometric altitude),
//! `MSG,6` (squawk). Fields, 1-based: 1 `MSG`, 2 transmission type, 3 session id, 4 aircraft
//! id, 5 hex ident, 6 flight id, 7-8 date and time generated (the update's feed time when it
//! is a Unix time, else the wall clock), 9-10 date and time logged (the wall clock), all UTC;
//! 11 callsign, 12 altitude (ft), 13 ground speed (kt), 14 track (deg), 15 latitude,
//! 16 longitude, 17 vertical rate (ft/min), 18 squawk, 19 alert (squawk changed), 20 emergency,
//! 21 SPI, 22 on ground; flags are `-1` (true) or `0`, empty when unknown.

use super::tcp::{self, Formatter, TcpLimits};
use super::time::{now_unix_s, sbs_date_time, utc_of_feed_time};
use super::{Output, OutputEvent, OutputStats};
use crate::config::SbsConfig;
use crate::daemon::aircraft::{FPM_TO_MPS, FT_TO_M, KT_TO_MPS};
use crate::daemon::registry::TrackState;
use crate::decode::Icao;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::sync::Arc;
use tokio::net::TcpListener;
use tokio::sync::broadcast;
use tokio_util::sync::CancellationToken;

/// Identity messages (`MSG,1`, `5`, `6`) are repeated at least this often while the aircraft
/// is updated, feed time, s: a client that connects later learns the callsign and squawk
/// within this (a decoder's SBS output repeats them as the aircraft does, every ~5 s).
pub const IDENTITY_REPEAT_S: f64 = 10.0;

/// What was last sent about an aircraft's identity, and when (feed time, s).
#[derive(Default)]
struct Sent {
    callsign: Option<(String, f64)>,
    baro_alt_ft: Option<(i32, f64)>,
    squawk: Option<(String, f64)>,
}

/// True when `value` differs from what was `sent`, or was sent `IDENTITY_REPEAT_S` ago.
fn due<T: PartialEq>(value: &T, sent: &Option<(T, f64)>, t_s: f64) -> bool {
    match sent {
        None => true,
        Some((v, at)) => v != value || !(t_s - at < IDENTITY_REPEAT_S && t_s >= *at),
    }
}

/// Formats updates as SBS lines, remembering per aircraft which identity facts were sent.
#[derive(Default)]
pub struct SbsFormatter {
    sent: HashMap<Icao, Sent>,
}

/// Emergency squawks: hijack, radio failure, general emergency.
fn is_emergency(squawk: &str) -> bool {
    matches!(squawk, "7500" | "7600" | "7700")
}

fn flag(b: bool) -> &'static str {
    if b {
        "-1"
    } else {
        "0"
    }
}

impl SbsFormatter {
    /// Appends the lines of one update of `t`; returns how many.
    pub fn lines(&mut self, t: &TrackState, logged_unix_s: f64, out: &mut String) -> u64 {
        let (gen_d, gen_t) = sbs_date_time(utc_of_feed_time(t.t));
        let (log_d, log_t) = sbs_date_time(logged_unix_s);
        let hex = t.icao.to_string().to_ascii_uppercase();
        let head = |out: &mut String, ty: u8| {
            let _ = write!(out, "MSG,{ty},1,1,{hex},1,{gen_d},{gen_t},{log_d},{log_t},");
        };
        let squawk = t.squawk.as_deref();
        let emergency = squawk.map(|s| flag(is_emergency(s))).unwrap_or("");
        let ground = flag(t.on_ground);
        let alt_ft = (t.alt_m / FT_TO_M).round() as i64;
        let gs_kt = t.ground_speed_mps / KT_TO_MPS;
        let vr_fpm = (t.vertical_rate_mps / FPM_TO_MPS).round() as i64;
        let sent = self.sent.entry(t.icao).or_default();
        let mut n = 0;
        if let Some(cs) = &t.callsign {
            if due(cs, &sent.callsign, t.t) {
                head(out, 1);
                let _ = writeln!(out, "{cs},,,,,,,,,,,{ground}\r");
                sent.callsign = Some((cs.clone(), t.t));
                n += 1;
            }
        }
        if t.on_ground {
            head(out, 2);
            let _ = writeln!(
                out,
                ",,{gs_kt:.1},{:.1},{:.6},{:.6},,,,,,{ground}\r",
                t.track_deg, t.lat, t.lon
            );
            n += 1;
        } else {
            head(out, 3);
            let _ = writeln!(
                out,
                ",{alt_ft},,,{:.6},{:.6},,,0,{emergency},0,{ground}\r",
                t.lat, t.lon
            );
            head(out, 4);
            let _ = writeln!(
                out,
                ",,{gs_kt:.1},{:.1},,,{vr_fpm},,0,{emergency},0,{ground}\r",
                t.track_deg
            );
            n += 2;
        }
        if let Some(a) = t.baro_alt_ft {
            if due(&a, &sent.baro_alt_ft, t.t) {
                head(out, 5);
                let _ = writeln!(out, ",{a},,,,,,,0,{emergency},0,{ground}\r");
                sent.baro_alt_ft = Some((a, t.t));
                n += 1;
            }
        }
        if let Some(sq) = squawk {
            if due(&sq.to_string(), &sent.squawk, t.t) {
                head(out, 6);
                // Alert: the squawk changed from the one sent before.
                let alert = flag(sent.squawk.as_ref().is_some_and(|(s, _)| s != sq));
                let _ = writeln!(out, ",,,,,,,{sq},{alert},{emergency},0,{ground}\r");
                sent.squawk = Some((sq.to_string(), t.t));
                n += 1;
            }
        }
        n
    }
}

impl Formatter for SbsFormatter {
    fn format(&mut self, event: &OutputEvent, out: &mut Vec<u8>) -> u64 {
        match event {
            OutputEvent::Update(p) => {
                let mut s = String::new();
                let n = self.lines(&p.track_state(), now_unix_s(), &mut s);
                out.extend_from_slice(s.as_bytes());
                n
            }
            OutputEvent::Retired(icao) => {
                self.sent.remove(icao);
                0
            }
        }
    }
}

/// Serves `[output.sbs]` until shutdown.
pub async fn run(
    listener: TcpListener,
    cfg: SbsConfig,
    rx: broadcast::Receiver<OutputEvent>,
    stats: Arc<OutputStats>,
    shutdown: CancellationToken,
) {
    let limits = TcpLimits {
        max_clients: cfg.max_clients,
        write_timeout_s: cfg.write_timeout_s,
        client_queue: cfg.client_queue,
    };
    tcp::serve(
        listener,
        limits,
        Output::Sbs,
        SbsFormatter::default(),
        rx,
        stats,
        shutdown,
    )
    .await;
}
