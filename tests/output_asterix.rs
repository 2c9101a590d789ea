//! ASTERIX CAT062 output (issue 13): the daemon replays a real recording with
//! `[output.asterix]` pointed at a UDP socket of the test; the datagrams are written to a pcap
//! and decoded by Wireshark's own dissector (`tshark`), and every decoded record is compared
//! with the `--tracks-out` line of the same update: position to the item's LSB, velocity,
//! track number, address, callsign, mode of movement, accuracies. CI installs tshark; without
//! it locally the decode half is skipped with a message (the framing is still checked).

mod common;

use adsb_tracker::config::Config;
use adsb_tracker::daemon::source::{Replay, ReplayData};
use adsb_tracker::daemon::Source;
use common::{fixture, get_json, TestDaemon};
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

const LSB_DEG: f64 = 180.0 / 33_554_432.0;

/// A pcap (libpcap, Ethernet) of UDP datagrams from 127.0.0.1:40000 to 127.0.0.1:`port`.
fn write_pcap(path: &Path, port: u16, payloads: &[Vec<u8>]) {
    let mut out = Vec::new();
    out.extend_from_slice(&0xa1b2_c3d4u32.to_le_bytes());
    out.extend_from_slice(&2u16.to_le_bytes());
    out.extend_from_slice(&4u16.to_le_bytes());
    out.extend_from_slice(&0i32.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&65_535u32.to_le_bytes());
    out.extend_from_slice(&1u32.to_le_bytes()); // LINKTYPE_ETHERNET
    for (i, p) in payloads.iter().enumerate() {
        let udp_len = 8 + p.len();
        let ip_len = 20 + udp_len;
        let mut ip = vec![
            0x45,
            0,
            (ip_len >> 8) as u8,
            ip_len as u8,
            0,
            0,
            0,
            0,
            64,
            17,
            0,
            0,
        ];
        ip.extend_from_slice(&[127, 0, 0, 1, 127, 0, 0, 1]);
        let sum: u32 = ip
            .chunks(2)
            .map(|c| u32::from(u16::from_be_bytes([c[0], c[1]])))
            .sum();
        let sum = (sum & 0xffff) + (sum >> 16);
        let sum = !((sum & 0xffff) + (sum >> 16)) as u16;
        ip[10..12].copy_from_slice(&sum.to_be_bytes());
        let mut frame = vec![0u8; 12];
        frame.extend_from_slice(&[0x08, 0x00]);
        frame.extend_from_slice(&ip);
        frame.extend_from_slice(&40_000u16.to_be_bytes());
        frame.extend_from_slice(&port.to_be_bytes());
        frame.extend_from_slice(&(udp_len as u16).to_be_bytes());
        frame.extend_from_slice(&[0, 0]);
        frame.extend_from_slice(p);
        out.extend_from_slice(&(1_000 + i as u32).to_le_bytes());
        out.extend_from_slice(&0u32.to_le_bytes());
        out.extend_from_slice(&(frame.len() as u32).to_le_bytes());
        out.extend_from_slice(&(frame.len() as u32).to_le_bytes());
        out.extend_from_slice(&frame);
    }
    std::fs::write(path, out).unwrap();
}

fn have_tshark() -> bool {
    Command::new("tshark")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// A decoded field as a number (tshark writes hex for some: "0x0007").
fn num(v: &Value) -> f64 {
    let s = v.as_str().unwrap_or_else(|| panic!("not a string: {v}"));
    match s.strip_prefix("0x") {
        Some(h) => i64::from_str_radix(h, 16).unwrap() as f64,
        None => s.parse().unwrap_or_else(|_| panic!("not a number: {s}")),
    }
}

fn field<'a>(msg: &'a Value, item: &str, name: &str) -> Option<&'a Value> {
    msg.get(format!("asterix.062_{item}"))?
        .get(format!("asterix.062_{item}_{name}"))
}

fn sub<'a>(msg: &'a Value, item: &str, subfield: &str, name: &str) -> Option<&'a Value> {
    msg.get(format!("asterix.062_{item}"))?
        .get(format!("asterix.062_{item}_{subfield}"))?
        .get(format!("asterix.062_{item}_{subfield}_{name}"))
}

macro_rules! ensure {
    ($c:expr $(, $($m:tt)*)?) => {{
        let ok: bool = $c;
        if !ok {
            return Err(stringify!($c).to_string());
        }
    }};
}

macro_rules! ensure_eq {
    ($a:expr, $b:expr) => {
        if $a != $b {
            return Err(format!("{} = {:?}, expected {:?}", stringify!($a), $a, $b));
        }
    };
}

/// Checks a decoded record against the daemon's JSON line of an update.
fn check_record(m: &Value, line: &Value) -> Result<(), String> {
    let lat = num(field(m, "105", "LAT").unwrap());
    let lon = num(field(m, "105", "LON").unwrap());
    let f = |k: &str| line[k].as_f64().unwrap();
    ensure!(
        (lat - f("lat")).abs() <= LSB_DEG / 2.0 + 1e-9,
        "{lat} {line}"
    );
    ensure!(
        (lon - f("lon")).abs() <= LSB_DEG / 2.0 + 1e-9,
        "{lon} {line}"
    );
    let vx = num(field(m, "185", "VX").unwrap());
    let vy = num(field(m, "185", "VY").unwrap());
    ensure!((vx - f("ve")).abs() <= 0.125 + 1e-9, "{vx} {line}");
    ensure!((vy - f("vn")).abs() <= 0.125 + 1e-9, "{vy} {line}");
    let alt_ft = num(field(m, "130", "VALUE").unwrap());
    ensure!((alt_ft - f("alt_m") / 0.3048).abs() <= 3.125 + 1e-6);
    let rocd = num(field(m, "220", "VALUE").unwrap());
    ensure!((rocd - f("vu") / 0.00508).abs() <= 3.125 + 1e-6);
    if let Some(baro) = line["baro_alt_ft"].as_f64() {
        let fl = num(field(m, "136", "VALUE").unwrap());
        ensure!((fl - baro / 100.0).abs() <= 0.125 + 1e-9);
    }
    // Mode of movement from the labels.
    let trans = match line["lateral"].as_str().unwrap() {
        "straight" => 0.0,
        "right" => 1.0,
        _ => 2.0,
    };
    let long = match line["speed"].as_str().unwrap() {
        "constant" => 0.0,
        "increasing" => 1.0,
        _ => 2.0,
    };
    let vert = match line["vertical"].as_str().unwrap() {
        "level" => 0.0,
        "climb" => 1.0,
        _ => 2.0,
    };
    ensure_eq!(num(field(m, "200", "TRANS").unwrap()), trans);
    ensure_eq!(num(field(m, "200", "LONG").unwrap()), long);
    ensure_eq!(num(field(m, "200", "VERT").unwrap()), vert);
    // Identification.
    match line["callsign"].as_str() {
        Some(cs) => {
            let id = sub(m, "380", "ID", "VALUE")
                .and_then(Value::as_str)
                .unwrap_or("");
            ensure_eq!(id.trim_end(), cs);
        }
        None => ensure!(sub(m, "380", "ID", "VALUE").is_none()),
    }
    if let Some(sq) = line["squawk"].as_str() {
        let code = num(field(m, "060", "MODE3A").unwrap()) as u32;
        ensure_eq!(format!("{code:04o}"), sq);
    }
    // Accuracies from the covariance.
    let cov = &line["pos_cov_enu_m2"];
    let sx = cov[0][0].as_f64().unwrap().sqrt();
    let sy = cov[1][1].as_f64().unwrap().sqrt();
    let apc_x = num(sub(m, "500", "APC", "X").unwrap());
    let apc_y = num(sub(m, "500", "APC", "Y").unwrap());
    ensure!((apc_x - sx).abs() <= 0.25 + 1e-9, "{apc_x} vs {sx}");
    ensure!((apc_y - sy).abs() <= 0.25 + 1e-9, "{apc_y} vs {sy}");
    let vcov = &line["vel_cov_enu_m2ps2"];
    let atv_x = num(sub(m, "500", "ATV", "X").unwrap());
    let svx = vcov[0][0].as_f64().unwrap().sqrt();
    ensure!(
        (atv_x - svx.min(63.75)).abs() <= 0.125 + 1e-9,
        "ATV {atv_x} vs {svx}"
    );
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cat062_records_decoded_by_tshark_match_the_tracks() {
    let udp = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let port = udp.local_addr().unwrap().port();
    let config = Config::from_toml_str(&format!(
        "[output.asterix]\ndestinations = [\"127.0.0.1:{port}\"]\nsac = 25\nsic = 1\nperiod_s = 0.05\n"
    ))
    .unwrap();
    let dir = std::env::temp_dir().join(format!("adsb-out-asterix-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let tracks_path = dir.join("tracks.jsonl");

    // Collect every datagram until told to stop.
    let (stop_tx, mut stop_rx) = tokio::sync::oneshot::channel::<()>();
    let collector = tokio::spawn(async move {
        let mut got = Vec::new();
        let mut buf = vec![0u8; 65_536];
        loop {
            tokio::select! {
                _ = &mut stop_rx => return got,
                r = udp.recv_from(&mut buf) => {
                    let (n, _) = r.unwrap();
                    got.push(buf[..n].to_vec());
                }
            }
        }
    });

    let source = Source::Replay(Replay {
        data: ReplayData::File(fixture("afr34zg-cdg-tls.jsonl")),
        format: None,
        // 4,778 s of flight in about 2.4 s: some 50 periods of 50 ms.
        speed: 2000.0,
        loop_: false,
        nominal_rate_hz: config.decode.nominal_rate_hz,
        fit_untimed_clock: config.decode.fit_untimed_clock,
        loop_gap_s: 0.0,
        progress: false,
    });
    let d = TestDaemon::start(config, source, Some(tracks_path.clone())).await;
    d.wait_replay().await;
    // Two periods more: the last updates and the retirements go out.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (_, stats) = get_json(d.addr, "/api/v1/stats").await;
    d.stop().await;
    tokio::time::sleep(Duration::from_millis(50)).await;
    let _ = stop_tx.send(());
    let datagrams = collector.await.unwrap();

    let a = &stats["outputs"]["asterix"];
    assert_eq!(
        a["datagrams_sent"].as_u64(),
        Some(datagrams.len() as u64),
        "{a}"
    );
    assert!(datagrams.len() >= 5, "{} datagrams", datagrams.len());
    assert_eq!(a["errors"], 0);
    for g in &datagrams {
        assert_eq!(g[0], 62);
        assert_eq!(usize::from(u16::from_be_bytes([g[1], g[2]])), g.len());
        assert!(g.len() <= 1400);
    }

    if !have_tshark() {
        eprintln!(
            "SKIPPED the tshark half of this test: `tshark` is not installed \
             (apt-get install tshark; CI installs it)"
        );
        return;
    }
    let pcap = dir.join("cat062.pcap");
    write_pcap(&pcap, port, &datagrams);
    let decode_as = format!("udp.port=={port},asterix");
    let verbose = Command::new("tshark")
        .args(["-r", pcap.to_str().unwrap(), "-V", "-d", &decode_as])
        .output()
        .unwrap();
    assert!(verbose.status.success());
    let text = String::from_utf8_lossy(&verbose.stdout);
    assert!(text.contains("ASTERIX packet, Category 062"));
    assert!(!text.contains("Malformed"), "tshark: malformed packet");
    assert!(
        !text.contains("Expert Info (Error"),
        "tshark reported an error"
    );
    let json = Command::new("tshark")
        .args([
            "-r",
            pcap.to_str().unwrap(),
            "-T",
            "json",
            "--no-duplicate-keys",
            "-d",
            &decode_as,
        ])
        .output()
        .unwrap();
    assert!(json.status.success());
    let packets: Value = serde_json::from_slice(&json.stdout).unwrap();

    // The daemon's JSON of every update, by aircraft.
    let mut lines: HashMap<String, Vec<Value>> = HashMap::new();
    for l in std::fs::read_to_string(&tracks_path).unwrap().lines() {
        let v: Value = serde_json::from_str(l).unwrap();
        lines
            .entry(v["icao"].as_str().unwrap().to_string())
            .or_default()
            .push(v);
    }

    let mut numbers: HashMap<String, f64> = HashMap::new();
    let mut records = 0;
    let mut with_callsign = 0;
    let mut terminations = 0;
    let mut firsts: HashMap<String, u32> = HashMap::new();
    for p in packets.as_array().unwrap() {
        let ast = &p["_source"]["layers"]["asterix"];
        assert_eq!(ast["asterix.category"], "62");
        let msgs = match &ast["asterix.message"] {
            Value::Array(a) => a.clone(),
            m => vec![m.clone()],
        };
        for m in &msgs {
            records += 1;
            assert_eq!(num(field(m, "010", "SAC").unwrap()), 25.0);
            assert_eq!(num(field(m, "010", "SIC").unwrap()), 1.0);
            let icao = format!("{:06x}", num(sub(m, "380", "ADR", "VALUE").unwrap()) as u32);
            let tn = num(field(m, "040", "VALUE").unwrap());
            // One number per aircraft for its whole life.
            assert_eq!(*numbers.entry(icao.clone()).or_insert(tn), tn, "{icao}");
            if field(m, "080", "TSB").map(num) == Some(1.0) {
                *firsts.entry(icao.clone()).or_default() += 1;
            }
            if field(m, "080", "TSE").map(num) == Some(1.0) {
                terminations += 1;
            }
            if field(m, "080", "CST").map(num) == Some(1.0) {
                // Coasting: extrapolated past the last update, no update line to match.
                continue;
            }
            let tod = num(field(m, "070", "VALUE").unwrap());
            let lat = num(field(m, "105", "LAT").unwrap());
            let lon = num(field(m, "105", "LON").unwrap());
            // The update of this record: same aircraft, time within half the LSB
            // (1/256 s), position within half the LSB; of several (a position and a velocity
            // report at one time, in two periods), one must match in every item.
            let candidates: Vec<&Value> = lines[&icao]
                .iter()
                .filter(|l| {
                    let t = l["t"].as_f64().unwrap().rem_euclid(86_400.0);
                    (t - tod).abs() <= 1.0 / 256.0 + 1e-9
                        && (l["lat"].as_f64().unwrap() - lat).abs() <= LSB_DEG / 2.0 + 1e-9
                        && (l["lon"].as_f64().unwrap() - lon).abs() <= LSB_DEG / 2.0 + 1e-9
                })
                .collect();
            assert!(
                !candidates.is_empty(),
                "{icao} at {tod} {lat} {lon}: no such update line"
            );
            let results: Vec<Result<(), String>> =
                candidates.iter().map(|l| check_record(m, l)).collect();
            assert!(
                results.iter().any(Result::is_ok),
                "{icao} at {tod}: no update line matches: {results:?}"
            );
            if m.get("asterix.062_380")
                .and_then(|a| a.get("asterix.062_380_ID"))
                .is_some()
            {
                with_callsign += 1;
            }
            // Ages: the track's age, capped at 63.75 s.
            let trk = num(sub(m, "290", "TRK", "VALUE").unwrap());
            assert!((0.0..=63.75).contains(&trk));
        }
    }
    assert!(records >= datagrams.len(), "{records} records");
    assert!(with_callsign > 0, "no record carried a callsign");
    // Every aircraft announced once (TSB) and terminated (TSE) at the end of the replay.
    assert!(firsts.values().all(|&n| n == 1), "{firsts:?}");
    assert_eq!(firsts.len(), numbers.len());
    assert_eq!(terminations, numbers.len(), "one last record per track");
    let mut distinct: Vec<f64> = numbers.values().copied().collect();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup();
    assert_eq!(
        distinct.len(),
        numbers.len(),
        "two live tracks shared a number"
    );
    eprintln!(
        "{records} CAT062 records in {} datagrams, {} aircraft, decoded by tshark",
        datagrams.len(),
        numbers.len()
    );
    let _ = std::fs::remove_dir_all(&dir);
}
