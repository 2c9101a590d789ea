//! readsb/tar1090 compatibility (issue 12): `/data/aircraft.json` and `/data/receiver.json`
//! checked field by field against readsb's `README-json.md` (wiedehopf/readsb), on real
//! recordings, and tar1090's page served from a directory.

mod common;

use adsb_tracker::config::Config;
use common::{get_json, TestDaemon};
use serde_json::Value;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// The keys README-json.md documents for an aircraft of aircraft.json.
const DOCUMENTED: &[&str] = &[
    "hex",
    "type",
    "flight",
    "alt_baro",
    "alt_geom",
    "gs",
    "ias",
    "tas",
    "mach",
    "track",
    "track_rate",
    "roll",
    "mag_heading",
    "true_heading",
    "baro_rate",
    "geom_rate",
    "squawk",
    "emergency",
    "category",
    "nav_qnh",
    "nav_altitude_mcp",
    "nav_altitude_fms",
    "nav_heading",
    "nav_modes",
    "lat",
    "lon",
    "nic",
    "rc",
    "seen_pos",
    "version",
    "nic_baro",
    "nac_p",
    "nac_v",
    "sil",
    "sil_type",
    "gva",
    "sda",
    "mlat",
    "tisb",
    "messages",
    "seen",
    "rssi",
    "alert",
    "spi",
    "wd",
    "ws",
    "oat",
    "tat",
    "r",
    "t",
    "desc",
    "dbFlags",
    "lastPosition",
    "rr_lat",
    "rr_lon",
];
/// Ours, where readsb has nothing of the kind.
const OURS: &[&str] = &["mode", "pos_sigma_m"];
/// The `type` values README-json.md lists.
const TYPES: &[&str] = &[
    "adsb_icao",
    "adsb_icao_nt",
    "adsr_icao",
    "tisb_icao",
    "adsc",
    "mlat",
    "other",
    "mode_s",
    "adsb_other",
    "adsr_other",
    "tisb_other",
    "tisb_trackfile",
];

/// GET with the response head: (status, lower-cased head, body).
async fn get_full(addr: SocketAddr, path: &str) -> (u16, String, String) {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    let req = format!("GET {path} HTTP/1.1\r\nHost: test\r\nConnection: close\r\n\r\n");
    s.write_all(req.as_bytes()).await.unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).await.unwrap();
    let text = String::from_utf8(buf).unwrap();
    let (head, body) = text.split_once("\r\n\r\n").unwrap();
    let status = head.split(' ').nth(1).unwrap().parse().unwrap();
    (status, head.to_lowercase(), body.to_string())
}

fn int_in(v: &Value, lo: i64, hi: i64) -> bool {
    v.as_i64().is_some_and(|x| (lo..=hi).contains(&x))
}

/// Every aircraft's fields against the documented types; returns the aircraft by hex.
fn check_aircraft_json(body: &str) -> (f64, BTreeMap<String, Value>) {
    let v: Value = serde_json::from_str(body).unwrap();
    let now = v["now"].as_f64().expect("now: seconds since the epoch");
    assert!(v["messages"].as_u64().is_some(), "messages: {v}");
    let mut out = BTreeMap::new();
    for a in v["aircraft"].as_array().unwrap() {
        let o = a.as_object().unwrap();
        for k in o.keys() {
            assert!(
                DOCUMENTED.contains(&k.as_str()) || OURS.contains(&k.as_str()),
                "undocumented key {k}: {a}"
            );
        }
        let hex = a["hex"].as_str().unwrap();
        assert!(
            hex.len() == 6
                && hex
                    .bytes()
                    .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b)),
            "hex {hex}"
        );
        assert!(TYPES.contains(&a["type"].as_str().unwrap()), "{a}");
        if let Some(f) = a.get("flight") {
            assert_eq!(f.as_str().unwrap().len(), 8, "flight padded to 8: {a}");
        }
        if let Some(alt) = a.get("alt_baro") {
            assert!(alt == "ground" || alt.is_i64(), "alt_baro: {a}");
        }
        if let Some(alt) = a.get("alt_geom") {
            assert!(alt.is_i64(), "alt_geom: {a}");
        }
        // The estimate's keys, all or none: an aircraft heard without a position yet
        // has none (readsb leaves out what it has no value for).
        let estimated = a.get("lat").is_some();
        for k in [
            "lat",
            "lon",
            "gs",
            "track",
            "baro_rate",
            "seen_pos",
            "mode",
            "pos_sigma_m",
        ] {
            assert_eq!(a.get(k).is_some(), estimated, "{k}: {a}");
        }
        if estimated {
            check_estimate(a);
        }
        if let Some(sq) = a.get("squawk") {
            let sq = sq.as_str().unwrap();
            assert!(
                sq.len() == 4 && sq.bytes().all(|b| (b'0'..=b'7').contains(&b)),
                "{a}"
            );
        }
        if let Some(c) = a.get("category") {
            let c = c.as_str().unwrap().as_bytes();
            assert!(
                c.len() == 2 && (b'A'..=b'D').contains(&c[0]) && (b'0'..=b'7').contains(&c[1]),
                "{a}"
            );
        }
        if let Some(nic) = a.get("nic") {
            assert!(int_in(nic, 0, 11), "{a}");
        }
        if let Some(rc) = a.get("rc") {
            assert!(rc.as_u64().is_some_and(|r| r > 0), "{a}");
        }
        assert!(a["seen"].as_f64().unwrap() >= 0.0, "{a}");
        assert!(a["messages"].as_u64().unwrap() > 0, "{a}");
        if let Some(r) = a.get("rssi") {
            assert!(r.as_f64().unwrap() < 0.0, "rssi always negative: {a}");
        }
        if let Some(x) = a.get("version") {
            assert!(int_in(x, 0, 7), "{a}");
        }
        if let Some(x) = a.get("nac_p") {
            assert!(int_in(x, 0, 11), "{a}");
        }
        if let Some(x) = a.get("nac_v") {
            assert!(int_in(x, 0, 4), "{a}");
        }
        assert_eq!(a["mlat"], serde_json::json!([]));
        assert_eq!(a["tisb"], serde_json::json!([]));
        out.insert(hex.to_string(), a.clone());
    }
    (now, out)
}

/// An aircraft's estimated keys, against the documented types.
fn check_estimate(a: &Value) {
    assert!(a["gs"].as_f64().unwrap() >= 0.0, "{a}");
    let track = a["track"].as_f64().unwrap();
    assert!((0.0..360.0).contains(&track), "{a}");
    assert!(a["baro_rate"].is_i64(), "{a}");
    assert!((-90.0..=90.0).contains(&a["lat"].as_f64().unwrap()), "{a}");
    assert!(
        (-180.0..=180.0).contains(&a["lon"].as_f64().unwrap()),
        "{a}"
    );
    assert!(a["seen_pos"].as_f64().unwrap() >= 0.0, "{a}");
    assert!(a["mode"].is_string(), "{a}");
    assert!(a["pos_sigma_m"].as_f64().unwrap() >= 0.0, "{a}");
}

/// The aircraft with a position.
fn positioned(aircraft: &BTreeMap<String, Value>) -> usize {
    aircraft.values().filter(|a| a.get("lat").is_some()).count()
}

fn check_receiver_json(head: &str, body: &str) -> Value {
    assert!(head.contains("cache-control: no-cache"), "{head}");
    let v: Value = serde_json::from_str(body).unwrap();
    assert!(v["version"].is_string());
    assert!(v["refresh"].as_u64().is_some());
    assert!(v["history"].as_u64().is_some());
    // Any of these would switch tar1090 to binary formats.
    for k in ["binCraft", "zstd", "reapi", "globeIndexGrid"] {
        assert!(v.get(k).is_none(), "{k}: {v}");
    }
    v
}

/// Toulouse, Beast with signal levels: every field readsb documents that we fill, and the
/// same estimate as the Track API.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn aircraft_json_has_readsbs_fields_and_types() {
    let config = Config::from_toml_str("[receiver]\nlat_deg = 43.6\nlon_deg = 1.4\n").unwrap();
    let d = TestDaemon::replay("toulouse-sample.beast", config).await;
    let stats = d.wait_replay().await;
    let (code, head, body) = get_full(d.addr, "/data/aircraft.json").await;
    assert_eq!(code, 200);
    assert!(head.contains("cache-control: no-cache"), "{head}");
    assert!(head.contains("content-type: application/json"), "{head}");
    let (now, aircraft) = check_aircraft_json(&body);
    let v: Value = serde_json::from_str(&body).unwrap();
    assert_eq!(v["messages"], stats["frames"]);
    let (_, tracks) = get_json(d.addr, "/api/v1/tracks").await;
    let tracks = tracks["tracks"].as_array().unwrap();
    // Every track, and every other aircraft the registry holds, without a position.
    assert_eq!(positioned(&aircraft), tracks.len());
    assert_eq!(
        aircraft.len() as u64,
        stats["tracks_active"].as_u64().unwrap()
    );
    assert!(!tracks.is_empty());
    for t in tracks {
        let a = &aircraft[t["icao"].as_str().unwrap()];
        // The tracker's estimate, in readsb's units.
        assert!((a["lat"].as_f64().unwrap() - t["lat"].as_f64().unwrap()).abs() < 1e-6);
        assert!((a["lon"].as_f64().unwrap() - t["lon"].as_f64().unwrap()).abs() < 1e-6);
        let gs_kt = t["ground_speed_mps"].as_f64().unwrap() * 3600.0 / 1852.0;
        assert!((a["gs"].as_f64().unwrap() - gs_kt).abs() <= 0.05, "{a} {t}");
        let fpm = t["vertical_rate_mps"].as_f64().unwrap() / 0.3048 * 60.0;
        assert!(
            (a["baro_rate"].as_f64().unwrap() - fpm).abs() <= 0.5,
            "{a} {t}"
        );
        assert_eq!(a["messages"], t["messages"]);
        assert_eq!(a.get("squawk"), t.get("squawk").filter(|s| !s.is_null()));
        if let Some(cs) = t["callsign"].as_str() {
            assert_eq!(a["flight"].as_str().unwrap().trim_end(), cs);
        }
        let seen = now - t["last_seen"].as_f64().unwrap();
        assert!((a["seen"].as_f64().unwrap() - seen).abs() <= 0.051, "{a}");
        assert_eq!(a["mode"], t["mode"]);
        // A Beast feed carries signal levels: rssi in dBFS.
        assert!(a["rssi"].as_f64().unwrap() > -50.0, "{a}");
    }
    // TRA89M: airborne with baro altitude, GNSS difference, version 2, NACp and NACv.
    let a = &aircraft["48520a"];
    assert_eq!(a["flight"], "TRA89M  ");
    assert_eq!(a["alt_baro"], 38000);
    assert_eq!(a["alt_geom"], 38250);
    assert_eq!(a["category"], "A3");
    assert_eq!(
        (a["version"].clone(), a["nac_p"].clone()),
        (2.into(), 9.into())
    );
    assert_eq!((a["nic"].clone(), a["rc"].clone()), (8.into(), 186.into()));

    // `now` strictly increases, even with the feed time stopped at the replay's end.
    let mut last = now;
    for _ in 0..3 {
        let (_, _, body) = get_full(d.addr, "/data/aircraft.json").await;
        let (n, _) = check_aircraft_json(&body);
        assert!(n > last, "{n} after {last}");
        last = n;
    }
    let (code, head, body) = get_full(d.addr, "/data/receiver.json").await;
    assert_eq!(code, 200);
    let r = check_receiver_json(&head, &body);
    assert_eq!(
        (r["lat"].as_f64(), r["lon"].as_f64()),
        (Some(43.6), Some(1.4))
    );
    assert_eq!(r["refresh"], 1000);
    assert_eq!(r["history"], 0);
    // Not served without a tar1090 directory.
    let (code, _, body) = get_full(d.addr, "/tar1090/data/aircraft.json").await;
    assert_eq!(code, 404, "{body}");
    d.stop().await;
}

/// AFR34ZG at the end of its flight, on the ground at Toulouse (`alt_baro` "ground"); LAX,
/// many aircraft from AVR text without signal levels (no `rssi`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ground_and_a_busy_sky() {
    let d = TestDaemon::replay("afr34zg-cdg-tls.jsonl", Config::default_config().unwrap()).await;
    d.wait_replay().await;
    let (_, _, body) = get_full(d.addr, "/data/aircraft.json").await;
    let (_, aircraft) = check_aircraft_json(&body);
    let a = &aircraft["393322"];
    assert_eq!(a["alt_baro"], "ground", "{a}");
    assert!(a.get("alt_geom").is_none(), "{a}");
    assert_eq!(a["flight"], "AFR34ZG ");
    assert!(a.get("rssi").is_none(), "{a}");
    d.stop().await;

    let config = Config::from_toml_str("[decode]\nnominal_rate_hz = 270.0\n").unwrap();
    let d = TestDaemon::replay("lax-messages.avr.txt", config).await;
    let stats = d.wait_replay().await;
    let (_, _, body) = get_full(d.addr, "/data/aircraft.json").await;
    let (_, aircraft) = check_aircraft_json(&body);
    let (_, tracks) = get_json(d.addr, "/api/v1/tracks").await;
    assert_eq!(
        positioned(&aircraft),
        tracks["tracks"].as_array().unwrap().len()
    );
    assert_eq!(
        aircraft.len() as u64,
        stats["tracks_active"].as_u64().unwrap()
    );
    // (At the end of the recording: those not yet retired after a minute of silence.)
    assert!(positioned(&aircraft) >= 40, "{}", aircraft.len());
    // And aircraft heard without a position, listed as readsb lists them: what they said
    // about themselves, their message count and age.
    let unplaced: Vec<&Value> = aircraft
        .values()
        .filter(|a| a.get("lat").is_none())
        .collect();
    // 24 of the 73 at the end (18 of them with an altitude): positions of one CPR format
    // only, or none at all.
    assert!(unplaced.len() >= 20, "{}", unplaced.len());
    let with_altitude = unplaced
        .iter()
        .filter(|a| a.get("alt_baro").is_some())
        .count();
    assert!(with_altitude >= 15, "{with_altitude}");
    let tracked: Vec<&str> = tracks["tracks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["icao"].as_str().unwrap())
        .collect();
    assert!(unplaced
        .iter()
        .all(|a| !tracked.contains(&a["hex"].as_str().unwrap())));
    assert!(aircraft.values().all(|a| a.get("rssi").is_none()));
    let named = aircraft
        .values()
        .filter(|a| a.get("flight").is_some())
        .count();
    assert!(named * 2 >= aircraft.len(), "{named}");
    let (_, head, body) = get_full(d.addr, "/data/receiver.json").await;
    let r = check_receiver_json(&head, &body);
    assert!(r.get("lat").is_none(), "no receiver configured: {r}");
    d.stop().await;
}

/// tar1090's html/ served at /tar1090/, its data/ answered by the daemon, nothing outside
/// the directory reachable, every 404 JSON.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tar1090_directory_is_served_with_our_data() {
    let dir = std::env::temp_dir().join(format!("tar1090-html-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("js")).unwrap();
    std::fs::write(
        dir.join("index.html"),
        "<html><title>tar1090</title></html>",
    )
    .unwrap();
    std::fs::write(dir.join("js/script.js"), "var x = 1;").unwrap();
    std::fs::write(dir.parent().unwrap().join("secret.txt"), "secret").unwrap();
    let config = Config::from_toml_str(&format!(
        "[server.readsb]\ntar1090_dir = {:?}\nrefresh_ms = 2000\n",
        dir.display().to_string()
    ))
    .unwrap();
    let d = TestDaemon::replay("toulouse-sample.beast", config).await;
    d.wait_replay().await;
    let (code, head, body) = get_full(d.addr, "/tar1090/").await;
    assert_eq!(code, 200);
    assert!(head.contains("content-type: text/html"), "{head}");
    assert!(body.contains("tar1090"));
    let (code, head, _) = get_full(d.addr, "/tar1090").await;
    assert_eq!(code, 308, "{head}");
    assert!(head.contains("location: /tar1090/"), "{head}");
    let (code, head, body) = get_full(d.addr, "/tar1090/js/script.js").await;
    assert_eq!((code, body.as_str()), (200, "var x = 1;"), "{head}");
    let (code, _, body) = get_full(d.addr, "/tar1090/data/aircraft.json").await;
    assert_eq!(code, 200);
    let (_, aircraft) = check_aircraft_json(&body);
    let (_, tracks) = get_json(d.addr, "/api/v1/tracks").await;
    assert_eq!(
        positioned(&aircraft),
        tracks["tracks"].as_array().unwrap().len()
    );
    assert!(aircraft.contains_key("48520a"));
    let (code, head, body) = get_full(d.addr, "/tar1090/data/receiver.json").await;
    assert_eq!(code, 200);
    assert_eq!(check_receiver_json(&head, &body)["refresh"], 2000);
    for path in [
        "/tar1090/missing.js",
        "/tar1090/../secret.txt",
        "/tar1090/%2e%2e/secret.txt",
        "/tar1090/js/../../secret.txt",
        "/tar1090/%2e%2e%2fsecret.txt",
    ] {
        let (code, _, body) = get_full(d.addr, path).await;
        assert_eq!(code, 404, "{path}: {body}");
        assert!(!body.contains("secret"), "{path}: {body}");
        let v: Value =
            serde_json::from_str(&body).unwrap_or_else(|e| panic!("{path}: {e}: {body}"));
        assert!(v["error"].is_string(), "{path}: {body}");
    }
    d.stop().await;
    let _ = std::fs::remove_dir_all(&dir);
}
