//! Track outputs in the wire formats other tools consume: ASTERIX CAT062 over UDP
//! ([`asterix`]), SBS BaseStation text on TCP ([`sbs`]) and JSON lines on TCP ([`jsonl`]).
//!
//! The aircraft tasks send every tracker update into one bounded
//! [`tokio::sync::broadcast`] channel ([`OutputEvent`]); each output is a receiver. Sending
//! never waits: an output that falls behind by more than the channel's capacity loses the
//! oldest updates (counted in `adsb_output_updates_lagged`), the pipeline never slows for it.
//! The TCP servers format each update once and fan the bytes out to their clients through a
//! second broadcast ([`tcp`]); a client that falls behind that one, or whose socket accepts
//! nothing for the write timeout, is dropped (`adsb_output_clients_dropped`), never waited for.

pub mod asterix;
pub mod jsonl;
pub mod sbs;
pub mod tcp;
pub mod time;

use crate::daemon::registry::Published;
use crate::decode::Icao;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use serde::Serialize;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use tokio::sync::broadcast;

/// Capacity of the pipeline -> outputs broadcast, in updates. A fleet of 1,000 aircraft
/// makes about 2,000 updates a second: four seconds of them, about 2.6 MB of snapshots at most.
pub const OUTPUT_CHANNEL_UPDATES: usize = 8192;

/// What the aircraft tasks tell the outputs.
#[derive(Clone, Debug)]
pub enum OutputEvent {
    /// The tracker took a report: the new estimate and the facts, as published.
    Update(Arc<Published>),
    /// The aircraft's task ended (retired after silence, the end of a replay, or shutdown):
    /// no more updates for it; its ASTERIX track number may be reused.
    Retired(Icao),
}

/// The sending side the aircraft tasks hold (`None` when no output is configured).
pub type OutputSender = broadcast::Sender<OutputEvent>;

/// A new output broadcast.
pub fn channel() -> OutputSender {
    broadcast::channel(OUTPUT_CHANNEL_UPDATES).0
}

/// The pipeline's broadcast of updates, always there for whoever listens: the outputs for
/// the daemon's life, the API's event-stream clients while connected.
///
/// Nobody listening costs the aircraft tasks one relaxed load per update: they build and
/// send an update only while [`UpdateFeed::heard`] (tokio's own receiver count takes a
/// lock).
#[derive(Debug)]
pub struct UpdateFeed {
    tx: OutputSender,
    /// Listeners now: [`Listener`]s alive plus the outputs' hold.
    listeners: AtomicUsize,
}

impl Default for UpdateFeed {
    fn default() -> Self {
        Self {
            tx: channel(),
            listeners: AtomicUsize::new(0),
        }
    }
}

impl UpdateFeed {
    /// True while anyone listens: only then are updates worth building.
    pub fn heard(&self) -> bool {
        self.listeners.load(Ordering::Relaxed) > 0
    }

    /// Sends an event to whoever listens; never waits (a slow listener misses the oldest).
    pub fn send(&self, event: OutputEvent) {
        // No receiver at all is not an error of the pipeline.
        let _ = self.tx.send(event);
    }

    /// A new listener, counted until dropped. It sees the events sent after this call.
    pub fn listen(self: &Arc<Self>) -> Listener {
        self.listeners.fetch_add(1, Ordering::Relaxed);
        Listener {
            rx: self.tx.subscribe(),
            feed: self.clone(),
        }
    }

    /// The sender, for the outputs, which subscribe for the daemon's life: call
    /// [`UpdateFeed::hold`] once for them.
    pub fn sender(&self) -> &OutputSender {
        &self.tx
    }

    /// Counts a listener that stays for the daemon's life (the configured outputs).
    pub fn hold(&self) {
        self.listeners.fetch_add(1, Ordering::Relaxed);
    }
}

/// A receiver of the [`UpdateFeed`], counted as a listener while alive.
#[derive(Debug)]
pub struct Listener {
    pub rx: broadcast::Receiver<OutputEvent>,
    feed: Arc<UpdateFeed>,
}

impl Drop for Listener {
    fn drop(&mut self) {
        self.feed.listeners.fetch_sub(1, Ordering::Relaxed);
    }
}

type Labels = Vec<(&'static str, String)>;

/// The outputs' counters, labelled by output (`asterix`, `sbs`, `jsonl`):
/// `/metrics` `adsb_output_*`, `/api/v1/stats` `outputs`.
#[derive(Debug, Default)]
pub struct OutputStats {
    /// Messages sent: SBS and JSON lines written to a client (one per client), CAT062
    /// records sent (one per destination).
    pub messages_sent: Family<Labels, Counter>,
    /// UDP datagrams (CAT062 data blocks) sent, per destination.
    pub datagrams_sent: Family<Labels, Counter>,
    /// Clients connected now.
    pub clients: Family<Labels, Gauge>,
    /// Clients accepted over the output's life.
    pub clients_accepted: Family<Labels, Counter>,
    /// Clients refused at the connection cap.
    pub clients_refused: Family<Labels, Counter>,
    /// Clients dropped because they fell behind or stalled a write.
    pub clients_dropped: Family<Labels, Counter>,
    /// Track updates the output missed because it fell behind the pipeline.
    pub updates_lagged: Family<Labels, Counter>,
    /// Socket errors (a UDP send refused, a failed accept).
    pub errors: Family<Labels, Counter>,
}

/// One output's counters, as `/api/v1/stats` shows them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, utoipa::ToSchema)]
pub struct OutputCounts {
    pub messages_sent: u64,
    pub datagrams_sent: u64,
    pub clients: i64,
    pub clients_accepted: u64,
    pub clients_refused: u64,
    pub clients_dropped: u64,
    pub updates_lagged: u64,
    pub errors: u64,
}

/// The three outputs' counters.
#[derive(Clone, Debug, Default, PartialEq, Serialize, utoipa::ToSchema)]
pub struct OutputStatsSnapshot {
    pub asterix: OutputCounts,
    pub sbs: OutputCounts,
    pub jsonl: OutputCounts,
}

/// Which output a counter is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Output {
    Asterix,
    Sbs,
    Jsonl,
}

impl Output {
    pub fn as_str(self) -> &'static str {
        match self {
            Output::Asterix => "asterix",
            Output::Sbs => "sbs",
            Output::Jsonl => "jsonl",
        }
    }

    fn labels(self) -> Labels {
        vec![("output", self.as_str().to_string())]
    }
}

impl OutputStats {
    pub fn messages_sent(&self, o: Output) -> Counter {
        self.messages_sent.get_or_create(&o.labels()).clone()
    }
    pub fn datagrams_sent(&self, o: Output) -> Counter {
        self.datagrams_sent.get_or_create(&o.labels()).clone()
    }
    pub fn clients(&self, o: Output) -> Gauge {
        self.clients.get_or_create(&o.labels()).clone()
    }
    pub fn clients_accepted(&self, o: Output) -> Counter {
        self.clients_accepted.get_or_create(&o.labels()).clone()
    }
    pub fn clients_refused(&self, o: Output) -> Counter {
        self.clients_refused.get_or_create(&o.labels()).clone()
    }
    pub fn clients_dropped(&self, o: Output) -> Counter {
        self.clients_dropped.get_or_create(&o.labels()).clone()
    }
    pub fn updates_lagged(&self, o: Output) -> Counter {
        self.updates_lagged.get_or_create(&o.labels()).clone()
    }
    pub fn errors(&self, o: Output) -> Counter {
        self.errors.get_or_create(&o.labels()).clone()
    }

    /// Registers every family under `output_*` (so `/metrics` shows `adsb_output_*`).
    pub fn register(&self, registry: &mut prometheus_client::registry::Registry) {
        registry.register(
            "output_messages_sent",
            "Output messages sent: SBS and JSON lines per client, CAT062 records per destination",
            self.messages_sent.clone(),
        );
        registry.register(
            "output_datagrams_sent",
            "CAT062 UDP datagrams sent, per destination",
            self.datagrams_sent.clone(),
        );
        registry.register(
            "output_clients",
            "Output TCP clients connected now",
            self.clients.clone(),
        );
        registry.register(
            "output_clients_accepted",
            "Output TCP clients accepted",
            self.clients_accepted.clone(),
        );
        registry.register(
            "output_clients_refused",
            "Output TCP clients refused at the connection cap",
            self.clients_refused.clone(),
        );
        registry.register(
            "output_clients_dropped",
            "Output TCP clients dropped for falling behind or stalling a write",
            self.clients_dropped.clone(),
        );
        registry.register(
            "output_updates_lagged",
            "Track updates an output missed because it fell behind the pipeline",
            self.updates_lagged.clone(),
        );
        registry.register(
            "output_errors",
            "Output socket errors (UDP sends, accepts)",
            self.errors.clone(),
        );
    }

    fn counts(&self, o: Output) -> OutputCounts {
        OutputCounts {
            messages_sent: self.messages_sent(o).get(),
            datagrams_sent: self.datagrams_sent(o).get(),
            clients: self.clients(o).get(),
            clients_accepted: self.clients_accepted(o).get(),
            clients_refused: self.clients_refused(o).get(),
            clients_dropped: self.clients_dropped(o).get(),
            updates_lagged: self.updates_lagged(o).get(),
            errors: self.errors(o).get(),
        }
    }

    pub fn snapshot(&self) -> OutputStatsSnapshot {
        OutputStatsSnapshot {
            asterix: self.counts(Output::Asterix),
            sbs: self.counts(Output::Sbs),
            jsonl: self.counts(Output::Jsonl),
        }
    }
}

/// Receives the next event, counting the updates missed when the receiver fell behind.
/// `None` when the pipeline is gone (every sender dropped).
pub async fn recv_counting(
    rx: &mut broadcast::Receiver<OutputEvent>,
    lagged: &Counter,
) -> Option<OutputEvent> {
    loop {
        match rx.recv().await {
            Ok(e) => return Some(e),
            Err(broadcast::error::RecvError::Lagged(n)) => {
                lagged.inc_by(n);
            }
            Err(broadcast::error::RecvError::Closed) => return None,
        }
    }
}

/// Takes what is already queued without waiting, counting lags; `None` when nothing is.
pub fn try_recv_counting(
    rx: &mut broadcast::Receiver<OutputEvent>,
    lagged: &Counter,
) -> Option<OutputEvent> {
    loop {
        match rx.try_recv() {
            Ok(e) => return Some(e),
            Err(broadcast::error::TryRecvError::Lagged(n)) => {
                lagged.inc_by(n);
            }
            Err(_) => return None,
        }
    }
}

/// The running outputs: their tasks end on the shutdown token or when the pipeline's
/// senders are all dropped.
pub struct Outputs {
    tasks: tokio::task::JoinSet<()>,
}

impl Outputs {
    /// Binds the configured outputs (a bind failure is an error at start, naming the key)
    /// and spawns their tasks. Returns `None` when no output is configured.
    pub async fn start(
        cfg: &crate::config::OutputConfig,
        tx: &OutputSender,
        stats: Arc<OutputStats>,
        shutdown: tokio_util::sync::CancellationToken,
    ) -> Result<Self, (String, std::io::Error)> {
        let mut tasks = tokio::task::JoinSet::new();
        if let Some(c) = &cfg.jsonl {
            let listener = tokio::net::TcpListener::bind(&c.listen)
                .await
                .map_err(|e| (format!("output.jsonl.listen {}", c.listen), e))?;
            tasks.spawn(jsonl::run(
                listener,
                c.clone(),
                tx.subscribe(),
                stats.clone(),
                shutdown.clone(),
            ));
        }
        if let Some(c) = &cfg.sbs {
            let listener = tokio::net::TcpListener::bind(&c.listen)
                .await
                .map_err(|e| (format!("output.sbs.listen {}", c.listen), e))?;
            tasks.spawn(sbs::run(
                listener,
                c.clone(),
                tx.subscribe(),
                stats.clone(),
                shutdown.clone(),
            ));
        }
        if let Some(c) = &cfg.asterix {
            let sender = asterix::UdpSender::bind(c)
                .await
                .map_err(|e| ("output.asterix.destinations".to_string(), e))?;
            tasks.spawn(asterix::run(
                sender,
                c.clone(),
                tx.subscribe(),
                stats.clone(),
                shutdown.clone(),
            ));
        }
        Ok(Self { tasks })
    }

    /// Waits for every output task to end.
    pub async fn stopped(mut self) {
        while self.tasks.join_next().await.is_some() {}
    }
}
