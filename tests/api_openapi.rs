//! `GET /api/v1/openapi.json` (issue 12, item 4): OpenAPI 3.1 derived from the code. Every
//! API route is described, and real responses of a replay, every status the test provokes
//! included, match their documented schemas: every required field there, of its type, and no
//! field the document does not know.

mod common;

use adsb_tracker::config::Config;
use common::{get, get_json, paced, SseClient, TestDaemon};
use serde_json::Value;
use std::time::Duration;

/// Checks `v` against `schema` (the subset of JSON Schema utoipa writes: `$ref`, `type`
/// (one or several), `properties`, `required`, `items`, `additionalProperties`, `oneOf`,
/// `minimum`), and that objects have no property the schema does not list. Returns the
/// problems found, with their JSON path.
fn check(doc: &Value, schema: &Value, v: &Value, at: &str, problems: &mut Vec<String>) {
    if let Some(r) = schema.get("$ref").and_then(Value::as_str) {
        let name = r.trim_start_matches("#/components/schemas/");
        let target = &doc["components"]["schemas"][name];
        assert!(!target.is_null(), "{at}: dangling {r}");
        return check(doc, target, v, at, problems);
    }
    if let Some(alternatives) = schema.get("oneOf").and_then(Value::as_array) {
        let ok = alternatives.iter().filter(|s| {
            let mut p = Vec::new();
            check(doc, s, v, at, &mut p);
            p.is_empty()
        });
        if ok.count() != 1 {
            problems.push(format!("{at}: {v} matches not exactly one of {schema}"));
        }
        return;
    }
    let types: Vec<&str> = match schema.get("type") {
        Some(Value::String(t)) => vec![t.as_str()],
        Some(Value::Array(ts)) => ts.iter().filter_map(Value::as_str).collect(),
        _ => return, // any value (`body = Object`, `String` text bodies)
    };
    let fits = |t: &str| match t {
        "null" => v.is_null(),
        "boolean" => v.is_boolean(),
        "integer" => v.is_i64() || v.is_u64(),
        "number" => v.is_number(),
        "string" => v.is_string(),
        "array" => v.is_array(),
        "object" => v.is_object(),
        _ => false,
    };
    if !types.iter().any(|t| fits(t)) {
        problems.push(format!("{at}: {v} is not {types:?}"));
        return;
    }
    if let (Some(min), Some(x)) = (schema.get("minimum").and_then(Value::as_f64), v.as_f64()) {
        if x < min {
            problems.push(format!("{at}: {x} < {min}"));
        }
    }
    if let Some(items) = v.as_array() {
        if let Some(item_schema) = schema.get("items") {
            for (i, item) in items.iter().enumerate() {
                check(doc, item_schema, item, &format!("{at}[{i}]"), problems);
            }
        }
    }
    if let Some(o) = v.as_object() {
        let props = schema.get("properties").and_then(Value::as_object);
        for req in schema
            .get("required")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
        {
            let k = req.as_str().unwrap();
            if !o.contains_key(k) {
                problems.push(format!("{at}: required {k} missing"));
            }
        }
        for (k, x) in o {
            match props.and_then(|p| p.get(k)) {
                Some(s) => check(doc, s, x, &format!("{at}.{k}"), problems),
                None => match schema.get("additionalProperties") {
                    Some(s) if s.is_object() => check(doc, s, x, &format!("{at}.{k}"), problems),
                    _ => problems.push(format!("{at}: {k} is not in the document")),
                },
            }
        }
    }
}

/// The response schema the document gives `path` for `status` (JSON bodies).
fn response_schema<'a>(doc: &'a Value, path: &str, status: u16) -> &'a Value {
    let r = &doc["paths"][path]["get"]["responses"][status.to_string()];
    assert!(!r.is_null(), "{path}: status {status} not documented");
    let content = r["content"].as_object().unwrap();
    &content.values().next().unwrap()["schema"]
}

fn schemas_of(doc: &Value) -> &Value {
    &doc["components"]["schemas"]
}

fn assert_valid(doc: &Value, schema: &Value, v: &Value, what: &str) {
    let mut problems = Vec::new();
    check(doc, schema, v, what, &mut problems);
    assert!(problems.is_empty(), "{what}:\n{}", problems.join("\n"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_document_describes_every_route_and_real_responses_match_it() {
    let config = Config::from_toml_str(
        "[decode]\nnominal_rate_hz = 270.0\n[receiver]\nlat_deg = 33.9425\nlon_deg = -118.4081\n",
    )
    .unwrap();
    let d = TestDaemon::start(
        config.clone(),
        paced("lax-messages.avr.txt", &config, 10.0),
        None,
    )
    .await;
    let (code, doc) = get_json(d.addr, "/api/v1/openapi.json").await;
    assert_eq!(code, 200);
    assert_eq!(doc["openapi"], "3.1.0");
    let mut paths: Vec<&str> = doc["paths"]
        .as_object()
        .unwrap()
        .keys()
        .map(|k| k.as_str())
        .collect();
    paths.sort_unstable();
    // Every route of api::app but the page at `/`.
    assert_eq!(
        paths,
        [
            "/api/v1/openapi.json",
            "/api/v1/stats",
            "/api/v1/stream",
            "/api/v1/tracks",
            "/api/v1/tracks/{icao}",
            "/api/v1/tracks/{icao}/history",
            "/api/v1/tracks/{icao}/prediction",
            "/data/aircraft.json",
            "/data/receiver.json",
            "/healthz",
            "/metrics",
        ]
    );
    // Some tracks first.
    let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
    let icao = loop {
        let (_, v) = get_json(d.addr, "/api/v1/tracks").await;
        if let Some(t) = v["tracks"].as_array().and_then(|t| t.get(20)) {
            break t["icao"].as_str().unwrap().to_string();
        }
        assert!(tokio::time::Instant::now() < deadline);
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let cases: Vec<(String, &str, u16)> = vec![
        ("/api/v1/tracks".into(), "/api/v1/tracks", 200),
        (
            "/api/v1/tracks?bbox=33,-119,35,-117&mode=CV,CT".into(),
            "/api/v1/tracks",
            200,
        ),
        ("/api/v1/tracks?bbox=1,2".into(), "/api/v1/tracks", 400),
        // Empty is no filter (what a form with empty fields sends).
        ("/api/v1/tracks?bbox=&mode=".into(), "/api/v1/tracks", 200),
        // Valid per its pattern, refused by the one rule a pattern cannot say.
        (
            "/api/v1/tracks?bbox=50,0,40,1".into(),
            "/api/v1/tracks",
            400,
        ),
        // Exponents are not in the pattern, so not accepted either.
        (
            "/api/v1/tracks?bbox=3.3e1,-119,35,-117".into(),
            "/api/v1/tracks",
            400,
        ),
        (
            format!("/api/v1/tracks/{icao}"),
            "/api/v1/tracks/{icao}",
            200,
        ),
        ("/api/v1/tracks/abcdef".into(), "/api/v1/tracks/{icao}", 404),
        ("/api/v1/tracks/xyz".into(), "/api/v1/tracks/{icao}", 400),
        (
            format!("/api/v1/tracks/{icao}/prediction"),
            "/api/v1/tracks/{icao}/prediction",
            200,
        ),
        (
            "/api/v1/tracks/abcdef/prediction".into(),
            "/api/v1/tracks/{icao}/prediction",
            404,
        ),
        (
            format!("/api/v1/tracks/{icao}/history"),
            "/api/v1/tracks/{icao}/history",
            200,
        ),
        (
            "/api/v1/tracks/zz/history".into(),
            "/api/v1/tracks/{icao}/history",
            400,
        ),
        ("/api/v1/stats".into(), "/api/v1/stats", 200),
        ("/healthz".into(), "/healthz", 200),
        ("/data/aircraft.json".into(), "/data/aircraft.json", 200),
        ("/data/receiver.json".into(), "/data/receiver.json", 200),
        ("/api/v1/stream?mode=XX".into(), "/api/v1/stream", 400),
    ];
    for (url, path, want) in &cases {
        let (code, v) = get_json(d.addr, url).await;
        assert_eq!(code, *want, "{url}: {v}");
        assert_valid(&doc, response_schema(&doc, path, code), &v, url);
    }
    // The check itself finds what is wrong: a field missing, one unknown, one mistyped.
    let (_, mut t) = get_json(d.addr, &format!("/api/v1/tracks/{icao}")).await;
    let o = t.as_object_mut().unwrap();
    o.remove("lat");
    o.insert("bogus".into(), Value::from(1));
    o.insert("messages".into(), Value::from("many"));
    let mut problems = Vec::new();
    check(
        &doc,
        &schemas_of(&doc)["Track"],
        &t,
        "broken",
        &mut problems,
    );
    assert_eq!(problems.len(), 3, "{problems:?}");

    let (code, text) = get(d.addr, "/metrics").await;
    assert_eq!(code, 200);
    assert!(text.contains("adsb_frames_total"));
    assert!(
        doc["paths"]["/metrics"]["get"]["responses"]["200"]["content"]
            .as_object()
            .unwrap()
            .keys()
            .any(|k| k.starts_with("application/openmetrics-text"))
    );

    // Each query parameter carries the pattern its handler checks.
    for (path, name, pattern) in adsb_tracker::api::params::PATTERNS {
        let params = doc["paths"][path]["get"]["parameters"].as_array().unwrap();
        let p = params.iter().find(|p| p["name"] == name).unwrap();
        assert_eq!(p["schema"]["pattern"], pattern, "{path} {name}");
    }

    // The stream's events: their data against Track, Retire and Stats, as the document
    // says (one event is {event, data}, data JSON of the schema its name selects).
    let schemas = &doc["components"]["schemas"];
    let event_schema = &doc["paths"]["/api/v1/stream"]["get"]["responses"]["200"]["content"]
        ["text/event-stream"]["schema"];
    let by_name: std::collections::BTreeMap<String, String> = event_schema["oneOf"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            let p = &e["properties"];
            assert_eq!(p["data"]["contentMediaType"], "application/json");
            (
                p["event"]["const"].as_str().unwrap().to_string(),
                p["data"]["contentSchema"]["$ref"]
                    .as_str()
                    .unwrap()
                    .to_string(),
            )
        })
        .collect();
    assert_eq!(
        by_name.into_iter().collect::<Vec<_>>(),
        [
            ("retire".into(), "#/components/schemas/Retire".into()),
            ("stats".into(), "#/components/schemas/Stats".into()),
            ("track".into(), "#/components/schemas/Track".into()),
        ]
    );
    let mut c = SseClient::connect(d.addr, "/api/v1/stream").await;
    let events = c.events_for(Duration::from_secs(3)).await;
    let mut seen = std::collections::BTreeSet::new();
    for e in &events {
        let schema = match e.name.as_str() {
            "track" => &schemas["Track"],
            "retire" => &schemas["Retire"],
            "stats" => &schemas["Stats"],
            other => panic!("event {other}"),
        };
        assert_valid(&doc, schema, &e.json(), &format!("event {}", e.name));
        seen.insert(e.name.clone());
    }
    assert!(seen.contains("track") && seen.contains("stats"), "{seen:?}");
    d.stop().await;
}
