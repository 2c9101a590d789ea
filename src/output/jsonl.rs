//! JSON lines on TCP: every track update as the `--tracks-out` line (the API's Track object,
//! without predictions), one per line, with `[output.jsonl]`'s `bbox` and `modes` filters
//! (those of `GET /api/v1/tracks`).

use super::tcp::{self, Formatter, TcpLimits};
use super::{Output, OutputEvent, OutputStats};
use crate::config::{BBox, JsonlConfig};
use std::sync::Arc;
use tokio::net::TcpListener;
use tokio::sync::broadcast;
use tokio_util::sync::CancellationToken;

/// Formats updates as JSON lines, keeping those the filters let through.
pub struct JsonlFormatter {
    bbox: Option<BBox>,
    modes: Option<Vec<String>>,
}

impl JsonlFormatter {
    pub fn new(cfg: &JsonlConfig) -> Self {
        Self {
            bbox: cfg.bbox.as_deref().and_then(BBox::parse),
            modes: cfg.modes.clone(),
        }
    }
}

impl Formatter for JsonlFormatter {
    fn format(&mut self, event: &OutputEvent, out: &mut Vec<u8>) -> u64 {
        let OutputEvent::Update(p) = event else {
            return 0;
        };
        let t = p.track_state();
        if self.bbox.is_some_and(|b| !b.contains(t.lat, t.lon)) {
            return 0;
        }
        if self
            .modes
            .as_ref()
            .is_some_and(|m| !m.iter().any(|m| m == t.mode))
        {
            return 0;
        }
        // Serialising a plain struct of numbers and strings cannot fail.
        if serde_json::to_writer(&mut *out, &t).is_ok() {
            out.push(b'\n');
            1
        } else {
            0
        }
    }
}

/// Serves `[output.jsonl]` until shutdown.
pub async fn run(
    listener: TcpListener,
    cfg: JsonlConfig,
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
        Output::Jsonl,
        JsonlFormatter::new(&cfg),
        rx,
        stats,
        shutdown,
    )
    .await;
}
