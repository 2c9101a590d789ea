//! The API under load (issue 11, row 4): the track list as cheap as it can be made (a
//! cached gzip body, ETag and 304), small endpoints that answer while many clients download
//! the large list or stall on it, and ingest that loses and changes nothing meanwhile.
//! Bounded loopback tests; the full measurement (1,000 aircraft, 256 connections, wrk) is
//! `scripts/api-load.sh`, its figures in the README.

mod common;

use adsb_tracker::config::Config;
use adsb_tracker::decode::{Icao, VerticalRateSource};
use adsb_tracker::sim::encode::{airborne_position, airborne_velocity, VelocityReport};
use common::{beast, get_json, get_with, with_beast_feed, TestDaemon};
use std::collections::BTreeMap;
use std::io::Read;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;

fn gunzip(z: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(z)
        .read_to_end(&mut out)
        .expect("a valid gzip stream");
    out
}

fn config(server: &str) -> Config {
    Config::from_toml_str(&format!("[server]\n{server}\n")).unwrap()
}

/// The gzip body is the plain body compressed; ETag names the generation and coding, and
/// If-None-Match with it gets a 304 without a body.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gzip_etag_and_304() {
    let d = TestDaemon::replay("lax-messages.avr.txt", config("")).await;
    d.wait_replay().await;
    let gz = [("Accept-Encoding", "gzip, deflate, br")];
    let plain = get_with(d.addr, "/api/v1/tracks", &[]).await;
    assert_eq!(plain.status, 200);
    assert_eq!(plain.header("content-encoding"), None);
    assert_eq!(plain.header("vary"), Some("accept-encoding"));
    let tag = plain.header("etag").expect("an ETag").to_string();
    // The first gzip request may get the plain body while the compressed one is made; the
    // next ones get it.
    let deadline = Instant::now() + Duration::from_secs(10);
    let zipped = loop {
        let r = get_with(d.addr, "/api/v1/tracks", &gz).await;
        assert_eq!(r.status, 200);
        if r.header("content-encoding") == Some("gzip") {
            break r;
        }
        assert!(Instant::now() < deadline, "never gzip-coded");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    let ztag = zipped.header("etag").unwrap().to_string();
    assert_eq!(ztag, format!("{}-gzip\"", tag.trim_end_matches('"')));
    assert_eq!(
        zipped.header("content-length"),
        Some(zipped.body.len().to_string().as_str())
    );
    // The replay is over: the registry holds still, and both are the same list.
    let text = gunzip(&zipped.body);
    assert_eq!(text, plain.body, "gzip body decodes to another list");
    assert!(
        zipped.body.len() * 2 < plain.body.len(),
        "{} bytes gzipped of {}",
        zipped.body.len(),
        plain.body.len()
    );
    let list: serde_json::Value = serde_json::from_slice(&text).unwrap();
    // On the clock its aircraft show (`feed::pace`: 796 s, not the 216 s of the default
    // 1,000 frames/s) the aircraft heard last a minute before the end are retired: 49.
    let listed = list["tracks"].as_array().unwrap().len();
    assert!(listed > 40, "{listed} tracks");

    // Conditional requests.
    let weak = format!("W/{tag}");
    for (headers, want) in [
        (vec![("If-None-Match", tag.as_str())], 304),
        (vec![("If-None-Match", weak.as_str())], 304),
        (vec![("If-None-Match", "\"g1\", *")], 304),
        (vec![("If-None-Match", "\"g0\"")], 200),
        // The gzip body's tag names another representation than the plain one's.
        (vec![("If-None-Match", ztag.as_str())], 200),
        (
            vec![
                ("If-None-Match", ztag.as_str()),
                ("Accept-Encoding", "gzip"),
            ],
            304,
        ),
        (
            vec![("If-None-Match", tag.as_str()), ("Accept-Encoding", "gzip")],
            200,
        ),
    ] {
        let r = get_with(d.addr, "/api/v1/tracks", &headers).await;
        assert_eq!(r.status, want, "{headers:?}");
        if want == 304 {
            assert!(r.body.is_empty(), "{headers:?}: a 304 has no body");
            assert!(r.header("etag").is_some(), "{headers:?}");
        }
    }
    // A filtered list: the same validator (per URL), never gzip-coded.
    let cv = get_with(d.addr, "/api/v1/tracks?mode=CV", &gz).await;
    assert_eq!(cv.status, 200);
    assert_eq!(cv.header("content-encoding"), None);
    assert_eq!(cv.header("etag"), Some(tag.as_str()));
    let n: serde_json::Value = serde_json::from_slice(&cv.body).unwrap();
    assert!(n["tracks"].as_array().unwrap().len() < list["tracks"].as_array().unwrap().len());
    let r = get_with(
        d.addr,
        "/api/v1/tracks?mode=CV",
        &[("If-None-Match", tag.as_str())],
    )
    .await;
    assert_eq!(r.status, 304);
    d.stop().await;

    // tracks_gzip_level = 0: never compressed.
    let d = TestDaemon::replay("lax-messages.avr.txt", config("tracks_gzip_level = 0")).await;
    d.wait_replay().await;
    for _ in 0..5 {
        let r = get_with(d.addr, "/api/v1/tracks", &gz).await;
        assert_eq!(r.status, 200);
        assert_eq!(r.header("content-encoding"), None);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    d.stop().await;
}

/// Aircraft of the load test's feed.
const AIRCRAFT: u32 = 400;
/// Feed time it covers, s.
const FEED_S: f64 = 30.0;
/// Frames a second the feed is sent at (about 5x real time): ingest lasts ~4 s.
const FEED_RATE: f64 = 9_000.0;

/// `AIRCRAFT` aircraft flying east for `FEED_S` s: a position every 0.5 s (even and odd
/// alternating) and a velocity every second. Returns the frames, one Vec each.
fn fleet() -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    let steps = (FEED_S / 0.5) as u32;
    for k in 0..steps {
        let t0 = 1.0 + f64::from(k) * 0.5;
        for a in 0..AIRCRAFT {
            let icao = Icao(0x300000 + a);
            let lat = 45.0 + f64::from(a % 40) * 0.1;
            let lon = 1.0 + f64::from(a / 40) * 0.5 + (t0 - 1.0) * 230.0 / 78_000.0;
            let t = t0 + f64::from(a) * 1e-4;
            let mut f = Vec::new();
            beast(
                t,
                &airborne_position(icao, 36_000.0, lat, lon, k % 2 == 1),
                &mut f,
            );
            out.push(f);
            if k % 2 == 0 {
                let v = VelocityReport {
                    ve_kt: 447.0,
                    vn_kt: 0.0,
                    vrate_fpm: 0.0,
                    vrate_source: VerticalRateSource::Baro,
                    nac_v: 2,
                };
                let mut f = Vec::new();
                beast(t + 0.01, &airborne_velocity(icao, &v), &mut f);
                out.push(f);
            }
        }
    }
    out
}

/// What ingest made of the feed: the stats' counts and each track's.
#[derive(Debug, PartialEq)]
struct Ingested {
    frames: u64,
    dropped: u64,
    tracks_created: u64,
    /// icao -> (messages, positions accepted, positions rejected, time of the estimate)
    tracks: BTreeMap<String, (u64, u64, u64, String)>,
}

/// Runs the daemon on a live Beast feed of [`fleet`] sent at [`FEED_RATE`]; with `load`,
/// clients pull and stall on the track list and time the small endpoints meanwhile.
/// Returns what was ingested and, under load, the probes' longest answer and counts.
async fn ingest(load: bool) -> (Ingested, Option<LoadSeen>) {
    let (d, mut sock) = with_beast_feed(config(""), "fleet", 120.0).await;
    let frames = fleet();
    let total = frames.len() as u64;
    let stop = Arc::new(AtomicBool::new(false));
    let load = match load {
        true => Some(Load::start(d.addr, stop.clone()).await),
        false => None,
    };
    // Paced in 10 ms chunks.
    let start = Instant::now();
    let per_chunk = (FEED_RATE / 100.0) as usize;
    for (i, chunk) in frames.chunks(per_chunk).enumerate() {
        let due = start + Duration::from_secs_f64(i as f64 / 100.0);
        tokio::time::sleep_until(due.into()).await;
        sock.write_all(&chunk.concat()).await.unwrap();
    }
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let (_, s) = get_json(d.addr, "/api/v1/stats").await;
        if s["frames"].as_u64() == Some(total)
            && s["queued_frames"] == 0
            && s["queued_batches"] == 0
        {
            break;
        }
        assert!(Instant::now() < deadline, "feed not ingested: {s}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    stop.store(true, Ordering::Relaxed);
    let seen = match load {
        Some(l) => Some(l.finish().await),
        None => None,
    };
    // Every aircraft task has its last frame: the counts hold still.
    let mut last = None;
    let deadline = Instant::now() + Duration::from_secs(30);
    let ingested = loop {
        let (_, s) = get_json(d.addr, "/api/v1/stats").await;
        let (_, list) = get_json(d.addr, "/api/v1/tracks").await;
        let tracks = list["tracks"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| {
                let n = |k: &str| t[k].as_u64().unwrap();
                (
                    t["icao"].as_str().unwrap().to_string(),
                    (
                        n("messages"),
                        n("positions_accepted"),
                        n("positions_rejected"),
                        t["t"].to_string(),
                    ),
                )
            })
            .collect();
        let now = Ingested {
            frames: s["frames"].as_u64().unwrap(),
            dropped: s["channel_dropped_messages"].as_u64().unwrap(),
            tracks_created: s["tracks_created"].as_u64().unwrap(),
            tracks,
        };
        let total_messages: u64 = now.tracks.values().map(|t| t.0).sum();
        if total_messages == total && last.as_ref() == Some(&now) {
            break now;
        }
        assert!(Instant::now() < deadline, "counts never settled: {now:?}");
        last = Some(now);
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    d.stop().await;
    drop(sock);
    (ingested, seen)
}

/// What the load's probes saw.
#[derive(Debug)]
struct LoadSeen {
    /// Longest answer of `/healthz` or `/api/v1/stats`.
    slowest_small: Duration,
    small_answers: u64,
    /// Whole track lists the pulling clients read.
    lists_read: u64,
}

/// Clients that pull the track list as fast as they can, clients that ask for it and never
/// read, and a probe that times the small endpoints, each on a connection of its own.
struct Load {
    tasks: Vec<tokio::task::JoinHandle<()>>,
    probe: tokio::task::JoinHandle<(Duration, u64)>,
    lists: Arc<AtomicU64>,
    stalled: Vec<TcpStream>,
}

/// Clients pulling the full list in a loop.
const PULLERS: usize = 64;
/// Clients that ask for it 20 times over and never read.
const STALLERS: usize = 64;

impl Load {
    async fn start(addr: SocketAddr, stop: Arc<AtomicBool>) -> Self {
        let lists = Arc::new(AtomicU64::new(0));
        let tasks = (0..PULLERS)
            .map(|i| {
                let (stop, lists) = (stop.clone(), lists.clone());
                tokio::spawn(async move {
                    // Half ask for gzip, as browsers do.
                    let gz: &[(&str, &str)] = if i % 2 == 0 {
                        &[("Accept-Encoding", "gzip")]
                    } else {
                        &[]
                    };
                    while !stop.load(Ordering::Relaxed) {
                        let r = get_with(addr, "/api/v1/tracks", gz).await;
                        assert_eq!(r.status, 200);
                        lists.fetch_add(1, Ordering::Relaxed);
                    }
                })
            })
            .collect();
        let probe = tokio::spawn(async move {
            let (mut slowest, mut n) = (Duration::ZERO, 0u64);
            while !stop.load(Ordering::Relaxed) {
                for path in ["/healthz", "/api/v1/stats"] {
                    let t = Instant::now();
                    let r = get_with(addr, path, &[]).await;
                    slowest = slowest.max(t.elapsed());
                    assert!(r.status == 200 || r.status == 503, "{path}: {}", r.status);
                    let _: serde_json::Value = serde_json::from_slice(&r.body).unwrap();
                    n += 1;
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            (slowest, n)
        });
        let req = b"GET /api/v1/tracks HTTP/1.1\r\nHost: x\r\n\r\n".repeat(20);
        let mut stalled = Vec::new();
        for _ in 0..STALLERS {
            let socket = tokio::net::TcpSocket::new_v4().unwrap();
            socket.set_recv_buffer_size(4096).unwrap();
            let mut s = socket.connect(addr).await.unwrap();
            // 800 bytes: they fit the socket's buffer at once.
            s.write_all(&req).await.unwrap();
            stalled.push(s);
        }
        Self {
            tasks,
            probe,
            lists,
            stalled,
        }
    }

    async fn finish(self) -> LoadSeen {
        for t in self.tasks {
            t.await.unwrap();
        }
        let (slowest_small, small_answers) = self.probe.await.unwrap();
        drop(self.stalled);
        LoadSeen {
            slowest_small,
            small_answers,
            lists_read: self.lists.load(Ordering::Relaxed),
        }
    }
}

/// 64 clients pulling the track list (half of them gzip) and 64 asking for it and never
/// reading, while a live feed streams in: `/healthz` and `/api/v1/stats` keep answering
/// (each within 1 s, a bound generous enough for a busy CI machine; a few ms measured), and
/// ingest ends with exactly the counts and tracks of a run without the load.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn small_endpoints_answer_and_ingest_is_unchanged_under_load() {
    let (quiet, _) = ingest(false).await;
    assert_eq!(quiet.tracks.len(), AIRCRAFT as usize);
    assert_eq!(quiet.dropped, 0);
    let (loaded, seen) = ingest(true).await;
    let seen = seen.unwrap();
    println!("under load: {seen:?}");
    assert!(
        seen.lists_read >= PULLERS as u64,
        "the load did not happen: {seen:?}"
    );
    assert!(seen.small_answers >= 20, "{seen:?}");
    assert!(
        seen.slowest_small < Duration::from_secs(1),
        "a small endpoint took {:?} under load",
        seen.slowest_small
    );
    assert_eq!(
        loaded, quiet,
        "ingest under load differs from ingest without it"
    );
}
