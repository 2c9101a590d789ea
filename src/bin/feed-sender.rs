//! A local feed for load tests: serves a recording over TCP as readsb serves its Beast or AVR
//! output, to the first client that connects, as fast as the socket takes it (or at a given
//! frame rate), then closes.
//!
//! ```sh
//! feed-sender /tmp/fleet.beast --listen 127.0.0.1:30005 [--rate 100000] [--loops 1]
//! ```
//!
//! It prints one JSON line on stdout when done: bytes and frames sent, seconds taken.

use anyhow::{Context, Result};
use clap::Parser;
use std::io::Write;
use std::net::TcpListener;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(about = "Serve a Beast or AVR recording to one TCP client, as fast as it reads")]
struct Args {
    file: PathBuf,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:30005")]
    listen: String,
    /// Frames per second to pace at (0: as fast as the socket takes them).
    #[arg(long, default_value_t = 0.0)]
    rate: f64,
    /// Times to send the file.
    #[arg(long, default_value_t = 1)]
    loops: u32,
}

/// Byte offsets of the frame starts of a Beast (0x1a-escaped) or text (one frame a line)
/// recording, so the sender can pace by frames and cut only between them.
fn frame_starts(data: &[u8]) -> Vec<usize> {
    let beast = data.first() == Some(&0x1a);
    let mut starts = Vec::new();
    let mut i = 0;
    while i < data.len() {
        starts.push(i);
        if beast {
            // 0x1a, type, then payload with doubled 0x1a; the next lone 0x1a starts a frame.
            let mut j = i + 2;
            while j < data.len() {
                if data[j] == 0x1a {
                    if data.get(j + 1) == Some(&0x1a) {
                        j += 2;
                        continue;
                    }
                    break;
                }
                j += 1;
            }
            i = j;
        } else {
            i = data[i..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(data.len(), |p| i + p + 1);
        }
    }
    starts
}

fn main() -> Result<()> {
    let args = Args::parse();
    let data = std::fs::read(&args.file).with_context(|| format!("{}", args.file.display()))?;
    let starts = frame_starts(&data);
    let listener = TcpListener::bind(&args.listen).with_context(|| args.listen.clone())?;
    eprintln!(
        "feed-sender: {} frames ({} bytes) x {} on {}",
        starts.len(),
        data.len(),
        args.loops,
        listener.local_addr()?
    );
    let (mut sock, peer) = listener.accept()?;
    sock.set_nodelay(true)?;
    eprintln!("feed-sender: client {peer}");
    let start = Instant::now();
    let mut sent_frames = 0u64;
    // Paced: chunks of 1 ms worth of frames, each sent when due.
    let per_chunk = if args.rate > 0.0 {
        ((args.rate / 1000.0).ceil() as usize).max(1)
    } else {
        starts.len().max(1)
    };
    for _ in 0..args.loops {
        let mut k = 0;
        while k < starts.len() {
            let end = (k + per_chunk).min(starts.len());
            let from = starts[k];
            let to = starts.get(end).copied().unwrap_or(data.len());
            if args.rate > 0.0 {
                let due = Duration::from_secs_f64(sent_frames as f64 / args.rate);
                if let Some(wait) = due.checked_sub(start.elapsed()) {
                    std::thread::sleep(wait);
                }
            }
            sock.write_all(&data[from..to])?;
            sent_frames += (end - k) as u64;
            k = end;
        }
    }
    sock.flush()?;
    let secs = start.elapsed().as_secs_f64();
    println!(
        "{{\"frames\":{sent_frames},\"bytes\":{},\"seconds\":{secs:.3},\"frames_per_s\":{:.0}}}",
        data.len() as u64 * u64::from(args.loops),
        sent_frames as f64 / secs.max(1e-9)
    );
    Ok(())
}
