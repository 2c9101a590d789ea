//! Issue 12: the map page and its embedded assets over HTTP (no browser): every file the
//! page loads is served with its content type and a validator, a revalidation is a bodiless
//! 304, the settings in the page come from the config, and the old table is at `/table`.

mod common;

use adsb_tracker::config::Config;
use common::{get_with, TestDaemon};

fn referenced_assets(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for part in text.split(['"', '`']) {
        if let Some(p) = part.strip_prefix("assets/") {
            out.push(p.to_string());
        } else if let Some(p) = part.strip_prefix("./") {
            if p.ends_with(".js") {
                out.push(p.to_string());
            }
        }
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_and_every_file_it_loads_are_served_from_the_binary() {
    let config = Config::from_toml_str(
        "[receiver]\nlat_deg = 33.9425\nlon_deg = -118.408\n\
         [map]\ntile_url = \"https://tile.openstreetmap.org/{z}/{x}/{y}.png\"\n\
         tile_attribution = \"(c) OpenStreetMap contributors\"\nrange_rings_km = [25.0, 75.0]\n",
    )
    .unwrap();
    let d = TestDaemon::replay("us-short-flights.csv", config).await;

    let page = get_with(d.addr, "/", &[]).await;
    assert_eq!(page.status, 200);
    assert_eq!(page.headers["content-type"], "text/html; charset=utf-8");
    assert_eq!(page.headers["cache-control"], "no-cache");
    let html = String::from_utf8(page.body).unwrap();
    assert!(html.contains(
        "{\"version\":\"0.1.0\",\"tiles\":{\"url\":\"https://tile.openstreetmap.org/{z}/{x}/{y}.png\",\
         \"attribution\":\"(c) OpenStreetMap contributors\",\"max_zoom\":19},\
         \"receiver\":{\"lat_deg\":33.9425,\"lon_deg\":-118.408},\"range_rings_km\":[25.0,75.0],\
         \"prediction_horizons_s\":[30.0,60.0,120.0]}"
    ));
    // The page revalidated: 304, no body.
    let again = get_with(d.addr, "/", &[("If-None-Match", &page.headers["etag"])]).await;
    assert_eq!(again.status, 304);
    assert!(again.body.is_empty());

    // Every file the page and its script load, and what they load in turn.
    let mut todo = referenced_assets(&html);
    let mut seen = Vec::new();
    while let Some(path) = todo.pop() {
        if seen.contains(&path) {
            continue;
        }
        let r = get_with(d.addr, &format!("/assets/{path}"), &[]).await;
        assert_eq!(r.status, 200, "/assets/{path}");
        let want = match path.rsplit_once('.').map(|(_, e)| e) {
            Some("js") => "text/javascript; charset=utf-8",
            Some("css") => "text/css; charset=utf-8",
            Some("json") => "application/json",
            Some("png") => "image/png",
            _ => "text/plain; charset=utf-8",
        };
        assert_eq!(r.headers["content-type"], want, "/assets/{path}");
        assert_eq!(r.headers["cache-control"], "no-cache", "/assets/{path}");
        assert_eq!(r.headers["x-content-type-options"], "nosniff");
        let etag = &r.headers["etag"];
        assert!(etag.len() == 18 && etag.starts_with('"'), "{etag}");
        let cached = get_with(
            d.addr,
            &format!("/assets/{path}"),
            &[("If-None-Match", etag)],
        )
        .await;
        assert_eq!(cached.status, 304, "/assets/{path}");
        if path.ends_with(".js") || path.ends_with(".css") {
            let text = String::from_utf8(r.body).unwrap();
            if path.ends_with(".css") {
                // url(images/x.png) relative to the stylesheet.
                let dir = path.rsplit_once('/').map_or("", |(d, _)| d);
                for url in text.split("url(").skip(1) {
                    let u = url.split(')').next().unwrap_or_default();
                    if u.ends_with(".png") && u != "images/marker-icon.png" {
                        todo.push(format!("{dir}/{u}"));
                    }
                }
            } else {
                todo.extend(referenced_assets(&text));
            }
        }
        seen.push(path);
    }
    seen.sort();
    assert_eq!(
        seen,
        [
            "geo.js",
            "map.css",
            "map.js",
            "vendor/leaflet/images/layers-2x.png",
            "vendor/leaflet/images/layers.png",
            "vendor/leaflet/leaflet.css",
            "vendor/leaflet/leaflet.js",
            "vendor/topojson-client/topojson-client.min.js",
            "vendor/world-atlas/land-110m.json",
        ]
    );

    // The world outline is the vendored TopoJSON, byte for byte.
    let land = get_with(d.addr, "/assets/vendor/world-atlas/land-110m.json", &[]).await;
    let vendored = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/src/api/web/vendor/world-atlas/land-110m.json"
    ))
    .unwrap();
    assert_eq!(land.body, vendored);
    let topo: serde_json::Value = serde_json::from_slice(&land.body).unwrap();
    assert_eq!(topo["type"], "Topology");
    assert_eq!(topo["objects"]["land"]["type"], "GeometryCollection");

    // Licences are served with the files.
    for lic in ["leaflet", "topojson-client", "world-atlas"] {
        let r = get_with(d.addr, &format!("/assets/vendor/{lic}/LICENSE"), &[]).await;
        assert_eq!(r.status, 200);
        assert!(String::from_utf8(r.body).unwrap().contains("Copyright"));
    }

    let missing = get_with(d.addr, "/assets/nope.js", &[]).await;
    assert_eq!(missing.status, 404);
    assert_eq!(missing.headers["content-type"], "application/json");
    let table = get_with(d.addr, "/table", &[]).await;
    assert_eq!(table.status, 200);
    assert!(String::from_utf8(table.body)
        .unwrap()
        .contains("fetch(\"/api/v1/tracks\")"));
    d.stop().await;
}
