//! SBS and JSON-lines outputs (issue 13): clients read both ports while the daemon tracks a
//! live Beast feed (the first 20,000 frames of the AFR34ZG recording, served by the test
//! once the clients are connected), and what they read is checked against `--tracks-out`:
//! the JSON lines are the update lines byte for byte, the SBS lines carry the same positions,
//! speeds, callsign and squawk in the 22-field layout. A third client that never reads is
//! dropped, counted, and holds nobody back.

mod common;

use adsb_tracker::config::Config;
use adsb_tracker::daemon::Source;
use common::{fixture, get_json, TestDaemon};
use serde_json::Value;
use std::net::SocketAddr;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const FRAMES: usize = 20_000;

/// The recording's frames as a Beast stream: 0x1a, '2' or '3', a 12 MHz counter from the
/// first frame, a signal byte, the frame; every 0x1a doubled.
fn beast_stream() -> (Vec<u8>, usize) {
    let text = std::fs::read_to_string(fixture("afr34zg-cdg-tls.jsonl")).unwrap();
    let mut out = Vec::new();
    let mut t0 = None;
    let mut n = 0;
    for line in text.lines().take(FRAMES) {
        let v: Value = serde_json::from_str(line).unwrap();
        let t = v["timestamp"].as_f64().unwrap();
        let t0 = *t0.get_or_insert(t);
        let hex = v["frame"].as_str().unwrap();
        let bytes: Vec<u8> = (0..hex.len() / 2)
            .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap())
            .collect();
        let kind = match bytes.len() {
            7 => b'2',
            14 => b'3',
            _ => continue,
        };
        let ticks = ((t - t0) * 12e6).round() as u64;
        let mut body = ticks.to_be_bytes()[2..8].to_vec();
        body.push(0x80);
        body.extend_from_slice(&bytes);
        out.extend_from_slice(&[0x1a, kind]);
        for b in body {
            out.push(b);
            if b == 0x1a {
                out.push(b);
            }
        }
        n += 1;
    }
    (out, n)
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

async fn connect(addr: SocketAddr) -> TcpStream {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        match TcpStream::connect(addr).await {
            Ok(s) => return s,
            Err(e) => {
                assert!(tokio::time::Instant::now() < deadline, "{addr}: {e}");
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }
    }
}

/// Reads a client's stream to its end (the daemon's shutdown).
fn read_all(mut s: TcpStream) -> tokio::task::JoinHandle<String> {
    tokio::spawn(async move {
        let mut buf = Vec::new();
        let _ = s.read_to_end(&mut buf).await;
        String::from_utf8(buf).unwrap()
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sbs_and_json_lines_clients_get_every_update() {
    let (stream, frames) = beast_stream();
    let feed = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let feed_addr = feed.local_addr().unwrap();
    let (go_tx, go_rx) = tokio::sync::oneshot::channel::<()>();
    let feeder = tokio::spawn(async move {
        let (mut s, _) = feed.accept().await.unwrap();
        let _ = go_rx.await;
        s.write_all(&stream).await.unwrap();
        // A live feed that has gone quiet: keep the connection open.
        tokio::time::sleep(Duration::from_secs(120)).await;
    });

    let sbs_addr: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    let jsonl_addr: SocketAddr = format!("127.0.0.1:{}", free_port()).parse().unwrap();
    let config = Config::from_toml_str(&format!(
        "[receiver]\nlat_deg = 49.0097\nlon_deg = 2.5479\n\
         [[feeds]]\nname = \"afr\"\naddr = \"{feed_addr}\"\nformat = \"beast\"\n\
         [output.sbs]\nlisten = \"{sbs_addr}\"\n\
         [output.jsonl]\nlisten = \"{jsonl_addr}\"\nwrite_timeout_s = 0.5\n"
    ))
    .unwrap();
    let dir = std::env::temp_dir().join(format!("adsb-out-tcp-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let tracks_path = dir.join("tracks.jsonl");
    let source = Source::Feeds(config.feeds.clone());
    let d = TestDaemon::start(config, source, Some(tracks_path.clone())).await;

    let sbs = read_all(connect(sbs_addr).await);
    let jsonl = read_all(connect(jsonl_addr).await);
    // Connected and never reading: its socket fills, a write stalls, it is dropped.
    let _stalled = connect(jsonl_addr).await;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        let (_, s) = get_json(d.addr, "/api/v1/stats").await;
        if s["outputs"]["sbs"]["clients"] == 1 && s["outputs"]["jsonl"]["clients"] == 2 {
            break;
        }
        assert!(tokio::time::Instant::now() < deadline, "clients: {s}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    go_tx.send(()).unwrap();

    // Wait for every frame and every update to be sent.
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    let mut last = Value::Null;
    let stats = loop {
        tokio::time::sleep(Duration::from_millis(300)).await;
        let (_, s) = get_json(d.addr, "/api/v1/stats").await;
        let done = s["frames"].as_u64() == Some(frames as u64)
            && s["queued_frames"] == 0
            && s["outputs"]["jsonl"]["messages_sent"] == last["outputs"]["jsonl"]["messages_sent"]
            && s["outputs"]["sbs"]["messages_sent"] == last["outputs"]["sbs"]["messages_sent"]
            && s["outputs"]["jsonl"]["clients_dropped"] == 1;
        if done {
            break s;
        }
        assert!(tokio::time::Instant::now() < deadline, "stuck: {s}");
        last = s;
    };
    d.stop().await;
    feeder.abort();
    let sbs = sbs.await.unwrap();
    let jsonl = jsonl.await.unwrap();
    let tracks = std::fs::read_to_string(&tracks_path).unwrap();
    let updates = tracks.lines().count();
    assert!(updates > 1000, "{updates} updates");
    assert_eq!(stats["track_updates"].as_u64(), Some(updates as u64));

    // JSON lines: the --tracks-out lines, byte for byte, in order.
    assert_eq!(jsonl.lines().count(), updates);
    assert!(jsonl == tracks, "the JSON lines differ from --tracks-out");
    let o = &stats["outputs"];
    assert_eq!(o["jsonl"]["updates_lagged"], 0, "{o}");
    assert_eq!(o["sbs"]["updates_lagged"], 0, "{o}");
    assert_eq!(o["jsonl"]["clients_dropped"], 1, "{o}");
    assert_eq!(o["sbs"]["clients_dropped"], 0, "{o}");
    assert_eq!(o["jsonl"]["clients_accepted"], 2, "{o}");
    // The stalled client got some lines before it was dropped; the reader got them all.
    let jsonl_sent = o["jsonl"]["messages_sent"].as_u64().unwrap();
    assert!(jsonl_sent >= updates as u64, "{o}");

    // SBS: 22 fields a line; per update MSG,3 and MSG,4 (airborne) or MSG,2 (surface).
    let sbs_lines: Vec<Vec<&str>> = sbs
        .split("\r\n")
        .filter(|l| !l.is_empty())
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(
        o["sbs"]["messages_sent"].as_u64(),
        Some(sbs_lines.len() as u64)
    );
    for f in &sbs_lines {
        assert_eq!(f.len(), 22, "{f:?}");
        assert_eq!(f[0], "MSG");
        assert_eq!(f[4], "393322");
        assert_eq!(f[6].len(), 10, "date {f:?}");
        assert_eq!(f[7].len(), 12, "time {f:?}");
    }
    let of_type = |t: &'static str| sbs_lines.iter().filter(move |f| f[1] == t);
    let positions: Vec<&Vec<&str>> = sbs_lines
        .iter()
        .filter(|f| f[1] == "3" || f[1] == "2")
        .collect();
    assert_eq!(positions.len(), updates);
    let track_lines: Vec<Value> = tracks
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let mut velocities = of_type("4");
    let mut surface = 0;
    for (f, t) in positions.iter().zip(&track_lines) {
        let lat: f64 = f[14].parse().unwrap();
        let lon: f64 = f[15].parse().unwrap();
        assert!(
            (lat - t["lat"].as_f64().unwrap()).abs() <= 0.5e-6,
            "{f:?} {t}"
        );
        assert!(
            (lon - t["lon"].as_f64().unwrap()).abs() <= 0.5e-6,
            "{f:?} {t}"
        );
        let gs_kt = t["ground_speed_mps"].as_f64().unwrap() * 3600.0 / 1852.0;
        let ground = t["on_ground"].as_bool().unwrap();
        assert_eq!(f[21], if ground { "-1" } else { "0" });
        if f[1] == "3" {
            assert!(!ground);
            let alt: f64 = f[11].parse().unwrap();
            assert!((alt - t["alt_m"].as_f64().unwrap() / 0.3048).abs() <= 0.5);
            let v = velocities.next().unwrap();
            let speed: f64 = v[12].parse().unwrap();
            assert!((speed - gs_kt).abs() <= 0.05 + 1e-9, "{v:?} {t}");
            let track: f64 = v[13].parse().unwrap();
            assert!((track - t["track_deg"].as_f64().unwrap()).abs() <= 0.05 + 1e-9);
            let vr: f64 = v[16].parse().unwrap();
            assert!((vr - t["vu"].as_f64().unwrap() / 0.00508).abs() <= 0.5);
        } else {
            surface += 1;
            assert!(ground);
            let speed: f64 = f[12].parse().unwrap();
            assert!((speed - gs_kt).abs() <= 0.05 + 1e-9);
        }
    }
    assert!(velocities.next().is_none());
    assert!(surface > 0, "the recording starts at the gate");
    // Identity: the callsign (MSG,1), the squawk (MSG,6), the reported altitude (MSG,5),
    // each when it changes and at least every 10 s of feed time while updated.
    let callsigns: Vec<&str> = of_type("1").map(|f| f[10]).collect();
    assert!(!callsigns.is_empty());
    assert!(callsigns.iter().all(|c| *c == "AFR34ZG"), "{callsigns:?}");
    let squawks: Vec<&str> = of_type("6").map(|f| f[17]).collect();
    let last = &track_lines[updates - 1];
    assert_eq!(squawks.last().copied(), last["squawk"].as_str());
    let alts: Vec<i64> = of_type("5").map(|f| f[11].parse().unwrap()).collect();
    assert!(alts.len() > 1);
    let _ = std::fs::remove_dir_all(&dir);
}
