//! The api role: the tracks bucket, watched, becomes this node's registry, and the HTTP API
//! (tracks, trails, the map's stream, readsb's JSON, the outputs) serves it with the same
//! code as a single process. The bucket is the merged state of every track node: each puts
//! only its own partitions' aircraft.

use super::bus::{Bus, TrackChange};
use super::stats::ClusterStats;
use crate::daemon::registry::Slot;
use crate::daemon::Shared;
use crate::decode::Icao;
use crate::output::OutputEvent;
use futures_util::StreamExt;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// Wait before watching again after the watch failed.
const REWATCH_WAIT: Duration = Duration::from_secs(1);

/// An aircraft key: 6 hex digits.
fn parse_key(key: &str) -> Option<Icao> {
    (key.len() == 6 && key.bytes().all(|b| b.is_ascii_hexdigit()))
        .then(|| u32::from_str_radix(key, 16).ok())
        .flatten()
        .map(Icao)
}

/// Applies the bucket to `shared`'s registry until `stop`.
pub async fn run<B: Bus>(
    bus: B,
    shared: Shared,
    cstats: Arc<ClusterStats>,
    stop: CancellationToken,
) {
    let mut slots: HashMap<Icao, Slot> = HashMap::new();
    let history = *shared.registry.history_config();
    loop {
        let mut watch = tokio::select! {
            _ = stop.cancelled() => return,
            w = bus.watch_tracks() => match w {
                Ok(w) => w,
                Err(e) => {
                    tracing::warn!(error = %e, "cannot watch the tracks bucket; retrying");
                    tokio::select! {
                        _ = stop.cancelled() => return,
                        _ = tokio::time::sleep(REWATCH_WAIT) => continue,
                    }
                }
            },
        };
        loop {
            let change = tokio::select! {
                _ = stop.cancelled() => return,
                c = watch.next() => c,
            };
            let change = match change {
                Some(Ok(c)) => c,
                Some(Err(e)) => {
                    tracing::warn!(error = %e, "tracks watch failed; watching again");
                    break;
                }
                None => break,
            };
            cstats.api_updates.inc();
            match change {
                TrackChange::Put { key, value } => {
                    let Some(icao) = parse_key(&key) else {
                        cstats.bad_packs.inc();
                        continue;
                    };
                    let published = match super::state::decode(&value) {
                        Ok(p) if p.icao == icao => Arc::new(p),
                        Ok(_) | Err(_) => {
                            cstats.kv_errors.inc();
                            tracing::debug!(%key, "unreadable track value skipped");
                            continue;
                        }
                    };
                    let slot = slots.entry(icao).or_insert_with(|| {
                        shared.stats.tracks_created.inc();
                        shared.registry.register(icao)
                    });
                    slot.record(
                        &history,
                        published.estimate.t_s,
                        &published.frame,
                        &published.estimate.pos_m,
                    );
                    slot.store(published.clone());
                    if shared.feed.heard() {
                        shared.feed.send(OutputEvent::Update(published));
                    }
                    shared.registry.touch();
                }
                TrackChange::Deleted { key } => {
                    let Some(icao) = parse_key(&key) else {
                        continue;
                    };
                    if slots.remove(&icao).is_some() {
                        shared.registry.remove(icao);
                        shared.stats.tracks_retired.inc();
                        shared.feed.send(OutputEvent::Retired(icao));
                    }
                }
            }
            shared.stats.tracks_active.set(slots.len() as i64);
        }
        tokio::select! {
            _ = stop.cancelled() => return,
            _ = tokio::time::sleep(REWATCH_WAIT) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_six_hex_digits() {
        assert_eq!(parse_key("4840d6"), Some(Icao(0x4840d6)));
        assert_eq!(parse_key("4840D6"), Some(Icao(0x4840d6)));
        assert_eq!(parse_key("4840d"), None);
        assert_eq!(parse_key("4840dg"), None);
        assert_eq!(parse_key("+4840d"), None);
    }
}
