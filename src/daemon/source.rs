//! Replay source: a recording read on a blocking thread, paced by its own feed time.
//!
//! Pacing keeps the feed clock: batch k is sent when wall time since start reaches
//! (t_k - t_0) / speed. A looped recording continues in time: each pass is shifted so that it
//! starts `loop_gap_s` after the previous one ended (longer than the retirement delay, so every
//! aircraft is retired and started afresh rather than seen to jump back).

use crate::feed::pace::PaceMap;
use crate::feed::replay::FileReader;
use crate::feed::tcp::FrameBatch;
use crate::feed::{Format, RawFrame};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// Where a replay's bytes come from.
#[derive(Clone)]
pub enum ReplayData {
    File(PathBuf),
    /// A recording compiled into the binary (the `serve` default).
    Embedded {
        name: &'static str,
        bytes: &'static [u8],
    },
}

impl std::fmt::Debug for ReplayData {
    /// The path or the name, never the embedded bytes.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::File(p) => write!(f, "{}", p.display()),
            Self::Embedded { name, bytes } => {
                write!(f, "embedded {name} ({} bytes)", bytes.len())
            }
        }
    }
}

/// A recording compiled into the binary, selectable by `replay.embedded` when no feed and
/// no `replay.file` is configured (fixtures/README.md has their sources, all MIT).
#[derive(Clone, Copy, Debug)]
pub struct EmbeddedRecording {
    /// Its name in `replay.embedded`.
    pub name: &'static str,
    pub file: &'static str,
    pub bytes: &'static [u8],
    /// Frames per second of feed time for a recording without timestamps: its real rate.
    pub nominal_rate_hz: Option<f64>,
    /// A receiver location near it (the reference for surface positions, and the receiver
    /// of readsb's `receiver.json`), used when the configuration gives none.
    pub receiver: (f64, f64),
    pub description: &'static str,
}

impl EmbeddedRecording {
    pub fn data(&self) -> ReplayData {
        ReplayData::Embedded {
            name: self.file,
            bytes: self.bytes,
        }
    }
}

/// The busiest real recording: 182 aircraft around Los Angeles, AVR text without
/// timestamps, whose real rate is about 270 frames/s (measured from aircraft displacement
/// against reported ground speed): a terminal area with turns, climbs and descents.
pub const EMBEDDED_LAX: EmbeddedRecording = EmbeddedRecording {
    name: "lax",
    file: "lax-messages.avr.txt",
    bytes: include_bytes!("../../fixtures/lax-messages.avr.txt"),
    nominal_rate_hz: Some(270.0),
    // Los Angeles International, aerodrome reference point.
    receiver: (33.9425, -118.4081),
    description: "182 aircraft around Los Angeles (rsadsb/adsb_deku)",
};

/// AFR34ZG, Paris CDG to Toulouse, gate to gate (xoolive/traffic): one flight in real time.
pub const EMBEDDED_AFR34ZG: EmbeddedRecording = EmbeddedRecording {
    name: "afr34zg",
    file: "afr34zg-cdg-tls.jsonl",
    bytes: include_bytes!("../../fixtures/afr34zg-cdg-tls.jsonl"),
    nominal_rate_hz: None,
    // Paris-CDG, aerodrome reference point.
    receiver: (49.0097, 2.5479),
    description: "AFR34ZG, Paris CDG to Toulouse, gate to gate (xoolive/traffic)",
};

/// Every embedded recording; the first is the default.
pub const EMBEDDED: &[EmbeddedRecording] = &[EMBEDDED_LAX, EMBEDDED_AFR34ZG];

/// The embedded recording of that name.
pub fn embedded(name: &str) -> Option<&'static EmbeddedRecording> {
    EMBEDDED.iter().find(|e| e.name == name)
}

/// A replay to run.
#[derive(Clone, Debug)]
pub struct Replay {
    pub data: ReplayData,
    /// `None`: detect.
    pub format: Option<Format>,
    /// Feed seconds per wall second; 0 = as fast as possible.
    pub speed: f64,
    pub loop_: bool,
    pub nominal_rate_hz: f64,
    /// A recording whose frames all lack a time is read once first to learn its real clock
    /// (`feed::pace`), and replayed on it.
    pub fit_untimed_clock: bool,
    /// Feed-time gap inserted between loops, s.
    pub loop_gap_s: f64,
    /// Print a progress line on stderr.
    pub progress: bool,
}

/// Progress of a replay, for the stats and the progress line.
#[derive(Default, Debug)]
pub struct ReplayProgress {
    pub frames: AtomicU64,
    pub passes: AtomicU64,
}

/// Wall-clock slice of paced sending: frames within one slice go in one batch.
const PACING_SLICE: Duration = Duration::from_millis(50);

/// Room for one file chunk's frames: a Beast Mode S frame takes at least 16 bytes (9 of
/// header, a 7-byte short frame), so a chunk rarely holds more, and the batch is not
/// reallocated while it fills (with 8192 slots every 256 KB chunk of DF17 frames, 23 bytes
/// each, grew once and copied 8192 frames).
const BATCH_FRAMES: usize = crate::feed::replay::CHUNK_BYTES / 16;

/// Runs the replay to its end (or forever when looping) on the calling (blocking) thread.
pub fn run_replay(
    replay: &Replay,
    tx: &mpsc::Sender<FrameBatch>,
    progress: &ReplayProgress,
    shutdown: &CancellationToken,
) -> Result<crate::feed::ParseStats, crate::feed::FeedError> {
    let mut offset_s = 0.0;
    let start_wall = Instant::now();
    let mut start_feed: Option<f64> = None;
    let mut last_stats;
    let mut frames: Vec<RawFrame> = Vec::with_capacity(BATCH_FRAMES);
    let mut last_print = Instant::now();
    let feed_name: Arc<str> = Arc::from(match &replay.data {
        ReplayData::File(p) => p.display().to_string(),
        ReplayData::Embedded { name, .. } => name.to_string(),
    });
    let open = || match &replay.data {
        ReplayData::File(p) => FileReader::open(p, replay.format, replay.nominal_rate_hz),
        ReplayData::Embedded { bytes, name } => {
            FileReader::from_bytes(bytes, name, replay.format, replay.nominal_rate_hz)
        }
    };
    let pace = if replay.fit_untimed_clock {
        let map = PaceMap::fit_reader(open()?)?;
        if let Some(p) = map.as_ref().map(PaceMap::summary) {
            tracing::info!(
                feed = %feed_name,
                intervals = p.intervals - p.rejected,
                left_out = p.rejected,
                mean_rate = p.mean_rate,
                min_rate = p.min_rate,
                max_rate = p.max_rate,
                "untimed recording: real clock learned from its aircraft"
            );
        }
        map
    } else {
        None
    };
    loop {
        let mut reader = open()?;
        let mut first_in_pass: Option<f64> = None;
        let mut last_in_pass = 0.0;
        loop {
            if shutdown.is_cancelled() {
                return Ok(reader.stats().clone());
            }
            frames.clear();
            let more = reader.next_batch(&mut frames)?;
            if let Some(map) = &pace {
                map.apply(&mut frames);
            }
            for f in frames.iter_mut() {
                first_in_pass.get_or_insert(f.time_s);
                last_in_pass = f.time_s;
                f.time_s += offset_s;
            }
            progress
                .frames
                .fetch_add(frames.len() as u64, Ordering::Relaxed);
            if replay.speed > 0.0 {
                send_paced(
                    &frames,
                    replay.speed,
                    start_wall,
                    &mut start_feed,
                    tx,
                    &feed_name,
                    shutdown,
                );
            } else if !frames.is_empty() {
                let batch = FrameBatch {
                    feed: feed_name.clone(),
                    frames: std::mem::replace(&mut frames, Vec::with_capacity(BATCH_FRAMES)),
                    arrived: Instant::now(),
                    done: None,
                };
                if tx.blocking_send(batch).is_err() {
                    return Ok(reader.stats().clone());
                }
            }
            if replay.progress && last_print.elapsed() > Duration::from_millis(500) {
                last_print = Instant::now();
                let pct = 100.0 * reader.bytes_read() as f64 / reader.total_bytes().max(1) as f64;
                let n = progress.frames.load(Ordering::Relaxed);
                let rate = n as f64 / start_wall.elapsed().as_secs_f64().max(1e-9);
                eprint!("\rreplay: {pct:5.1} %  {n} frames  {rate:.0} frames/s   ");
            }
            if !more {
                break;
            }
        }
        last_stats = reader.stats().clone();
        progress.passes.fetch_add(1, Ordering::Relaxed);
        if replay.progress {
            eprintln!();
        }
        if !replay.loop_ {
            return Ok(last_stats);
        }
        let Some(first) = first_in_pass else {
            return Ok(last_stats); // an empty file would loop forever doing nothing
        };
        offset_s += (last_in_pass - first) + replay.loop_gap_s;
    }
}

/// Sends `frames` in slices, sleeping until each slice's feed time is due.
fn send_paced(
    frames: &[RawFrame],
    speed: f64,
    start_wall: Instant,
    start_feed: &mut Option<f64>,
    tx: &mpsc::Sender<FrameBatch>,
    feed: &Arc<str>,
    shutdown: &CancellationToken,
) {
    let mut rest = frames;
    while let Some(first) = rest.first() {
        let t0 = *start_feed.get_or_insert(first.time_s);
        // Saturating: a timestamp absurdly far ahead must not panic the replay.
        let due = |t: f64| {
            Duration::try_from_secs_f64(((t - t0) / speed).max(0.0)).unwrap_or(Duration::MAX)
        };
        let slice_end = due(first.time_s).saturating_add(PACING_SLICE);
        let n = rest
            .iter()
            .position(|f| due(f.time_s) >= slice_end)
            .unwrap_or(rest.len());
        let (now, later) = rest.split_at(n);
        let wait = due(first.time_s).saturating_sub(start_wall.elapsed());
        // Sleep in short steps so shutdown is noticed within 100 ms.
        // An absurd wait (a timestamp far ahead) sleeps until shutdown rather than panicking.
        let wake = Instant::now()
            .checked_add(wait)
            .unwrap_or_else(|| Instant::now() + Duration::from_secs(86_400 * 365));
        while Instant::now() < wake {
            if shutdown.is_cancelled() {
                return;
            }
            std::thread::sleep((wake - Instant::now()).min(Duration::from_millis(100)));
        }
        let batch = FrameBatch {
            feed: feed.clone(),
            frames: now.to_vec(),
            // Due then: a replay that falls behind its schedule shows it as ingest lag.
            arrived: start_wall
                .checked_add(due(first.time_s))
                .unwrap_or_else(Instant::now),
            done: None,
        };
        if tx.blocking_send(batch).is_err() {
            return;
        }
        rest = later;
    }
}
