//! The bus the roles talk through: a partitioned durable log of frame packs, a key-value
//! store of tracks, and leases. [`Bus`] is what the roles need of it, so another engine
//! (Kafka through `rdkafka`: topics for partitions, a compacted topic for tracks) can be put
//! behind it; [`NatsBus`] is the one built and tested, on NATS JetStream.
//!
//! On NATS:
//! - stream `ADSB_FRAMES`, subjects `adsb.frames.<p>`, file storage, kept
//!   `cluster.retention_s`; JetStream's duplicate window drops a pack republished after a
//!   lost acknowledgement (each carries a `Nats-Msg-Id`);
//! - one durable pull consumer per partition, `track-p<p>`, acknowledged cumulatively
//!   (`AckPolicy::All`): the partition's progress, whoever owns it;
//! - key-value bucket `adsb-tracks`: key = ICAO address (6 hex digits), value =
//!   [`super::state`]'s JSON; stream `ADSB_TRACKS`, subjects `adsb.tracks.<icao>`: every
//!   published value, for history;
//! - key-value bucket `adsb-leases` (`max_age` = `cluster.lease_ttl_s`): `member.<node>` and
//!   `partition.<p>` = holder; a key not renewed within the TTL expires;
//! - key-value bucket `adsb-cluster`: `partitions`, written by the first node.

use async_nats::jetstream::{self, consumer, kv, stream};
use bytes::Bytes;
use futures_util::StreamExt;
use std::future::Future;
use std::pin::Pin;
use std::time::Duration;

/// The frames stream.
pub const FRAMES_STREAM: &str = "ADSB_FRAMES";
/// The tracks' history stream.
pub const TRACKS_STREAM: &str = "ADSB_TRACKS";
pub const TRACKS_BUCKET: &str = "adsb-tracks";
pub const LEASES_BUCKET: &str = "adsb-leases";
pub const META_BUCKET: &str = "adsb-cluster";

/// A bus failure, with what was being done.
#[derive(Debug, thiserror::Error)]
#[error("{what}: {error}")]
pub struct BusError {
    pub what: String,
    pub error: String,
}

fn err(what: impl Into<String>) -> impl FnOnce(String) -> BusError {
    let what = what.into();
    move |error| BusError { what, error }
}

/// An acknowledgement still to come.
pub type PendingAck = Pin<Box<dyn Future<Output = Result<(), BusError>> + Send>>;

/// One message taken from a partition.
pub struct Delivery<M> {
    pub payload: Bytes,
    /// Its position in the partition's log.
    pub seq: u64,
    /// Messages of the partition after it, not yet delivered.
    pub pending: u64,
    pub handle: M,
}

/// A change of the tracks bucket.
#[derive(Debug)]
pub enum TrackChange {
    Put { key: String, value: Bytes },
    Deleted { key: String },
}

/// A partition's consumer: its next messages, in order, and their acknowledgement.
pub trait PartitionConsumer: Send + 'static {
    type Handle: Send + Sync + 'static;
    /// Up to `max` messages: waits for the first, takes the rest only if already there.
    fn next_batch(
        &mut self,
        max: usize,
    ) -> impl Future<Output = Result<Vec<Delivery<Self::Handle>>, BusError>> + Send;
    /// Acknowledges `handle`'s message and every one before it.
    fn ack_through(handle: Self::Handle) -> impl Future<Output = Result<(), BusError>> + Send;
}

/// What the roles need of the bus.
pub trait Bus: Clone + Send + Sync + 'static {
    type Consumer: PartitionConsumer;
    type Replay: PartitionConsumer;
    type Watch: futures_util::Stream<Item = Result<TrackChange, BusError>> + Send + Unpin;

    /// Publishes a pack to partition `p` under a unique id (a republish with the same id is
    /// stored once); the returned future resolves with the log's acknowledgement.
    fn publish(
        &self,
        p: u32,
        id: String,
        payload: Bytes,
    ) -> impl Future<Output = Result<PendingAck, BusError>> + Send;
    /// Takes partition `p` over: its consumer resumes after the last acknowledged message.
    /// Returns it, the sequence of that message (0: none) and how many messages a previous
    /// owner was given but never acknowledged (they come again).
    fn take_partition(
        &self,
        p: u32,
    ) -> impl Future<Output = Result<(Self::Consumer, u64, u64), BusError>> + Send;
    /// The partition's messages from its start (as far as retention keeps them), in order.
    fn replay_partition(
        &self,
        p: u32,
    ) -> impl Future<Output = Result<Self::Replay, BusError>> + Send;
    fn put_track(
        &self,
        key: &str,
        value: Bytes,
    ) -> impl Future<Output = Result<(), BusError>> + Send;
    fn delete_track(&self, key: &str) -> impl Future<Output = Result<(), BusError>> + Send;
    /// Every track's current value, then every change.
    fn watch_tracks(&self) -> impl Future<Output = Result<Self::Watch, BusError>> + Send;
    /// Creates `key` = `holder` in the leases bucket if nobody holds it: its revision.
    fn lease_create(
        &self,
        key: &str,
        holder: &str,
    ) -> impl Future<Output = Result<Option<u64>, BusError>> + Send;
    /// Renews a lease held at `revision`: the new revision, `None` if it was lost.
    fn lease_renew(
        &self,
        key: &str,
        holder: &str,
        revision: u64,
    ) -> impl Future<Output = Result<Option<u64>, BusError>> + Send;
    /// Puts `key` = `holder` whatever was there (a member's heartbeat).
    fn lease_put(
        &self,
        key: &str,
        holder: &str,
    ) -> impl Future<Output = Result<(), BusError>> + Send;
    /// Deletes a lease (a clean release).
    fn lease_delete(&self, key: &str) -> impl Future<Output = Result<(), BusError>> + Send;
    /// Every unexpired key of the leases bucket starting with `prefix`, with its holder.
    fn lease_list(
        &self,
        prefix: &str,
    ) -> impl Future<Output = Result<Vec<(String, String)>, BusError>> + Send;
    fn is_connected(&self) -> bool;
}

/// [`Bus`] on NATS JetStream.
#[derive(Clone)]
pub struct NatsBus {
    client: async_nats::Client,
    js: jetstream::Context,
    frames_js: jetstream::Context,
    frames: stream::Stream,
    tracks: kv::Store,
    leases: kv::Store,
}

/// Connection and layout settings.
pub struct NatsSettings<'a> {
    pub url: &'a str,
    pub partitions: u32,
    pub lease_ttl: Duration,
    pub retention: Duration,
    pub max_inflight: usize,
}

impl NatsBus {
    /// Connects (once: the caller retries) and makes sure the streams and buckets exist;
    /// refuses a cluster created with another partition count.
    pub async fn connect(s: NatsSettings<'_>) -> Result<Self, BusError> {
        let client = async_nats::ConnectOptions::new()
            .name("adsb-tracker")
            .connection_timeout(Duration::from_secs(5))
            // One server or a comma-separated list (the client learns the rest of a NATS
            // cluster from the servers themselves).
            .connect(
                s.url
                    .split(',')
                    .map(str::trim)
                    .filter(|u| !u.is_empty())
                    .collect::<Vec<_>>(),
            )
            .await
            .map_err(|e| err(format!("connecting to {}", s.url))(e.to_string()))?;
        // Frames are published on a context of their own: the ingest keeps up to
        // `max_inflight` acknowledgements outstanding, and on a shared context those would
        // hold the permits the track puts and lease updates need (a node with both roles
        // stalled so). Its own bound is the ingest's; this one only backs it up.
        let frames_js = jetstream::ContextBuilder::new()
            .max_ack_inflight(s.max_inflight.max(1) + 1)
            .backpressure_on_inflight(true)
            .build(client.clone());
        let js = jetstream::new(client.clone());
        let frames = js
            .get_or_create_stream(stream::Config {
                name: FRAMES_STREAM.into(),
                subjects: vec!["adsb.frames.*".into()],
                max_age: s.retention,
                storage: stream::StorageType::File,
                duplicate_window: Duration::from_secs(120),
                ..Default::default()
            })
            .await
            .map_err(|e| err("creating stream ADSB_FRAMES")(e.to_string()))?;
        js.get_or_create_stream(stream::Config {
            name: TRACKS_STREAM.into(),
            subjects: vec!["adsb.tracks.*".into()],
            max_age: s.retention,
            storage: stream::StorageType::File,
            ..Default::default()
        })
        .await
        .map_err(|e| err("creating stream ADSB_TRACKS")(e.to_string()))?;
        let bucket = |name: &str, max_age: Duration| kv::Config {
            bucket: name.to_string(),
            history: 1,
            max_age,
            storage: stream::StorageType::File,
            ..Default::default()
        };
        let tracks = get_or_create_kv(&js, bucket(TRACKS_BUCKET, Duration::ZERO)).await?;
        let leases = get_or_create_kv(&js, bucket(LEASES_BUCKET, s.lease_ttl)).await?;
        let meta = get_or_create_kv(&js, bucket(META_BUCKET, Duration::ZERO)).await?;
        let want = s.partitions.to_string();
        // The first node records the count; any other must agree.
        let _ = meta.create("partitions", Bytes::from(want.clone())).await;
        let have = meta
            .get("partitions")
            .await
            .map_err(|e| err("reading adsb-cluster.partitions")(e.to_string()))?
            .map(|b| String::from_utf8_lossy(&b).into_owned());
        if have.as_deref() != Some(want.as_str()) {
            return Err(BusError {
                what: "cluster.partitions".into(),
                error: format!(
                    "this cluster was created with {} partitions, the configuration says {want}: \
                     the partitioning is fixed at creation",
                    have.unwrap_or_else(|| "?".into())
                ),
            });
        }
        Ok(Self {
            client,
            js,
            frames_js,
            frames,
            tracks,
            leases,
        })
    }
}

async fn get_or_create_kv(js: &jetstream::Context, cfg: kv::Config) -> Result<kv::Store, BusError> {
    let name = cfg.bucket.clone();
    match js.get_key_value(&name).await {
        Ok(s) => Ok(s),
        Err(_) => js
            .create_key_value(cfg)
            .await
            .map_err(|e| err(format!("creating bucket {name}"))(e.to_string())),
    }
}

fn consumer_name(p: u32) -> String {
    format!("track-p{p}")
}

/// A partition's durable pull consumer.
pub struct NatsConsumer {
    messages: consumer::pull::Stream,
}

/// A partition replayed from its start (ordered, unacknowledged).
pub struct NatsReplay {
    messages: consumer::pull::Ordered,
}

/// Takes what is ready without waiting, after the first.
async fn gather<S, M>(
    s: &mut S,
    max: usize,
    what: &str,
) -> Result<Vec<Delivery<jetstream::Message>>, BusError>
where
    S: futures_util::Stream<Item = Result<jetstream::Message, M>> + Unpin,
    M: std::fmt::Display,
{
    let mut out = Vec::with_capacity(max);
    let first = s
        .next()
        .await
        .ok_or_else(|| err(what)("the message stream ended".into()))?
        .map_err(|e| err(what)(e.to_string()))?;
    push(&mut out, first);
    while out.len() < max {
        match futures_util::FutureExt::now_or_never(s.next()) {
            Some(Some(Ok(m))) => push(&mut out, m),
            Some(Some(Err(e))) => return Err(err(what)(e.to_string())),
            _ => break,
        }
    }
    Ok(out)
}

fn push(out: &mut Vec<Delivery<jetstream::Message>>, m: jetstream::Message) {
    let (seq, pending) = m
        .info()
        .map(|i| (i.stream_sequence, i.pending))
        .unwrap_or((0, 0));
    out.push(Delivery {
        payload: m.payload.clone(),
        seq,
        pending,
        handle: m,
    });
}

impl PartitionConsumer for NatsConsumer {
    type Handle = jetstream::Message;

    async fn next_batch(&mut self, max: usize) -> Result<Vec<Delivery<Self::Handle>>, BusError> {
        gather(&mut self.messages, max, "pulling frames").await
    }

    async fn ack_through(handle: Self::Handle) -> Result<(), BusError> {
        handle
            .ack()
            .await
            .map_err(|e| err("acknowledging")(e.to_string()))
    }
}

impl PartitionConsumer for NatsReplay {
    type Handle = ();

    async fn next_batch(&mut self, max: usize) -> Result<Vec<Delivery<()>>, BusError> {
        let batch = gather(&mut self.messages, max, "replaying a partition").await?;
        Ok(batch
            .into_iter()
            .map(|d| Delivery {
                payload: d.payload,
                seq: d.seq,
                pending: d.pending,
                handle: (),
            })
            .collect())
    }

    async fn ack_through(_: ()) -> Result<(), BusError> {
        Ok(())
    }
}

/// The tracks bucket's changes.
pub struct NatsWatch(kv::Watch);

impl futures_util::Stream for NatsWatch {
    type Item = Result<TrackChange, BusError>;

    fn poll_next(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Self::Item>> {
        self.0.poll_next_unpin(cx).map(|o| {
            o.map(|r| {
                r.map_err(|e| err("watching adsb-tracks")(e.to_string()))
                    .map(|e| match e.operation {
                        kv::Operation::Put => TrackChange::Put {
                            key: e.key,
                            value: e.value,
                        },
                        kv::Operation::Delete | kv::Operation::Purge => {
                            TrackChange::Deleted { key: e.key }
                        }
                    })
            })
        })
    }
}

impl Bus for NatsBus {
    type Consumer = NatsConsumer;
    type Replay = NatsReplay;
    type Watch = NatsWatch;

    async fn publish(&self, p: u32, id: String, payload: Bytes) -> Result<PendingAck, BusError> {
        let ack = self
            .frames_js
            .send_publish(
                super::wire::frames_subject(p),
                jetstream::message::PublishMessage::build()
                    .payload(payload)
                    .message_id(id),
            )
            .await
            .map_err(|e| err("publishing frames")(e.to_string()))?;
        Ok(Box::pin(async move {
            ack.await
                .map(|_| ())
                .map_err(|e| err("awaiting a publish acknowledgement")(e.to_string()))
        }))
    }

    async fn take_partition(&self, p: u32) -> Result<(NatsConsumer, u64, u64), BusError> {
        let name = consumer_name(p);
        let what = format!("taking partition {p}");
        let stream = self.frames.clone();
        // Where the previous owner got to. Its consumer is recreated from the first
        // unacknowledged message: the messages it was given and never acknowledged would
        // otherwise only come back after the acknowledgement wait, behind newer ones, and an
        // aircraft must see its messages in order.
        let (acked, delivered) = match stream.consumer_info(&name).await {
            Ok(info) => (
                info.ack_floor.stream_sequence,
                info.delivered.stream_sequence,
            ),
            Err(_) => (0, 0),
        };
        let _ = stream.delete_consumer(&name).await;
        let deliver_policy = if acked == 0 {
            consumer::DeliverPolicy::All
        } else {
            consumer::DeliverPolicy::ByStartSequence {
                start_sequence: acked + 1,
            }
        };
        let c: consumer::PullConsumer = stream
            .create_consumer(consumer::pull::Config {
                durable_name: Some(name),
                filter_subject: super::wire::frames_subject(p),
                ack_policy: consumer::AckPolicy::All,
                ack_wait: Duration::from_secs(120),
                max_ack_pending: 100_000,
                deliver_policy,
                ..Default::default()
            })
            .await
            .map_err(|e| err(what.clone())(e.to_string()))?;
        let messages = c
            .stream()
            .max_messages_per_batch(512)
            .messages()
            .await
            .map_err(|e| err(what)(e.to_string()))?;
        Ok((
            NatsConsumer { messages },
            acked,
            delivered.saturating_sub(acked),
        ))
    }

    async fn replay_partition(&self, p: u32) -> Result<NatsReplay, BusError> {
        let what = format!("replaying partition {p}");
        let c = self
            .frames
            .create_consumer(consumer::pull::OrderedConfig {
                filter_subject: super::wire::frames_subject(p),
                deliver_policy: consumer::DeliverPolicy::All,
                ..Default::default()
            })
            .await
            .map_err(|e| err(what.clone())(e.to_string()))?;
        let messages = c.messages().await.map_err(|e| err(what)(e.to_string()))?;
        Ok(NatsReplay { messages })
    }

    async fn put_track(&self, key: &str, value: Bytes) -> Result<(), BusError> {
        let history = self
            .js
            .publish(format!("adsb.tracks.{key}"), value.clone())
            .await
            .map_err(|e| err("publishing track history")(e.to_string()))?;
        self.tracks
            .put(key, value)
            .await
            .map_err(|e| err("putting a track")(e.to_string()))?;
        history
            .await
            .map(|_| ())
            .map_err(|e| err("publishing track history")(e.to_string()))
    }

    async fn delete_track(&self, key: &str) -> Result<(), BusError> {
        self.tracks
            .delete(key)
            .await
            .map_err(|e| err("deleting a track")(e.to_string()))
    }

    async fn watch_tracks(&self) -> Result<NatsWatch, BusError> {
        self.tracks
            .watch_with_history(">")
            .await
            .map(NatsWatch)
            .map_err(|e| err("watching adsb-tracks")(e.to_string()))
    }

    async fn lease_create(&self, key: &str, holder: &str) -> Result<Option<u64>, BusError> {
        match self
            .leases
            .create(key, Bytes::copy_from_slice(holder.as_bytes()))
            .await
        {
            Ok(rev) => Ok(Some(rev)),
            Err(e) if e.kind() == kv::CreateErrorKind::AlreadyExists => Ok(None),
            Err(e) => Err(err(format!("creating lease {key}"))(e.to_string())),
        }
    }

    async fn lease_renew(
        &self,
        key: &str,
        holder: &str,
        revision: u64,
    ) -> Result<Option<u64>, BusError> {
        match self
            .leases
            .update(key, Bytes::copy_from_slice(holder.as_bytes()), revision)
            .await
        {
            Ok(rev) => Ok(Some(rev)),
            Err(e) if e.kind() == kv::UpdateErrorKind::WrongLastRevision => Ok(None),
            Err(e) => Err(err(format!("renewing lease {key}"))(e.to_string())),
        }
    }

    async fn lease_put(&self, key: &str, holder: &str) -> Result<(), BusError> {
        self.leases
            .put(key, Bytes::copy_from_slice(holder.as_bytes()))
            .await
            .map(|_| ())
            .map_err(|e| err(format!("putting {key}"))(e.to_string()))
    }

    async fn lease_delete(&self, key: &str) -> Result<(), BusError> {
        self.leases
            .delete(key)
            .await
            .map_err(|e| err(format!("deleting {key}"))(e.to_string()))
    }

    async fn lease_list(&self, prefix: &str) -> Result<Vec<(String, String)>, BusError> {
        let what = "listing leases";
        let mut keys = match self.leases.keys().await {
            Ok(k) => k,
            Err(e) => return Err(err(what)(e.to_string())),
        };
        let mut out = Vec::new();
        while let Some(k) = keys.next().await {
            let k = k.map_err(|e| err(what)(e.to_string()))?;
            if !k.starts_with(prefix) {
                continue;
            }
            if let Ok(Some(v)) = self.leases.get(&k).await {
                out.push((k, String::from_utf8_lossy(&v).into_owned()));
            }
        }
        Ok(out)
    }

    fn is_connected(&self) -> bool {
        self.client.connection_state() == async_nats::connection::State::Connected
    }
}
