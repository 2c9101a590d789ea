//! The TCP side of the SBS and JSON-lines outputs: one task that formats each update once and
//! accepts clients, and a task per client that writes what it is given.
//!
//! The formatter hands its bytes to the clients through a bounded broadcast of chunks, so a
//! client never holds the others back: one that falls more than `client_queue` chunks behind,
//! or whose socket takes nothing for `write_timeout_s`, is dropped and counted. At most
//! `max_clients` are connected; one more is closed at once and counted. All of it ends on
//! the shutdown token.

use super::{recv_counting, try_recv_counting, Output, OutputEvent, OutputStats};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::broadcast;
use tokio_util::sync::CancellationToken;

/// Largest number of pipeline events formatted into one chunk: one write per client for
/// many updates when the pipeline is busy, without holding more than this back.
const EVENTS_PER_CHUNK: usize = 256;

/// Bytes formatted for every client, with the number of messages (lines) in them.
#[derive(Debug)]
pub struct Chunk {
    pub bytes: Vec<u8>,
    pub messages: u64,
}

/// The limits of a TCP output (its config section's keys).
#[derive(Clone, Copy, Debug)]
pub struct TcpLimits {
    pub max_clients: usize,
    pub write_timeout_s: f64,
    pub client_queue: usize,
}

/// Formats pipeline events into bytes; returns the number of messages written to `out`.
pub trait Formatter: Send + 'static {
    fn format(&mut self, event: &OutputEvent, out: &mut Vec<u8>) -> u64;
}

/// Runs a TCP output until shutdown: formats what the pipeline sends, serves it to clients.
pub async fn serve<F: Formatter>(
    listener: TcpListener,
    limits: TcpLimits,
    output: Output,
    mut formatter: F,
    mut rx: broadcast::Receiver<OutputEvent>,
    stats: Arc<OutputStats>,
    shutdown: CancellationToken,
) {
    let (chunks, _) = broadcast::channel::<Arc<Chunk>>(limits.client_queue.max(1));
    let lagged = stats.updates_lagged(output);
    let clients = stats.clients(output);
    let refused = stats.clients_refused(output);
    let accepted = stats.clients_accepted(output);
    let errors = stats.errors(output);
    let write_timeout =
        Duration::try_from_secs_f64(limits.write_timeout_s).unwrap_or(Duration::from_secs(10));
    let mut tasks = tokio::task::JoinSet::new();
    let mut pipeline_open = true;
    loop {
        tokio::select! {
            biased;
            _ = shutdown.cancelled() => break,
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
            a = listener.accept() => match a {
                Ok((sock, peer)) => {
                    if tasks.len() >= limits.max_clients {
                        refused.inc();
                        tracing::debug!(%peer, output = output.as_str(), "client refused: connection cap");
                        drop(sock);
                        continue;
                    }
                    accepted.inc();
                    clients.inc();
                    tracing::debug!(%peer, output = output.as_str(), "client connected");
                    tasks.spawn(client(
                        sock,
                        chunks.subscribe(),
                        write_timeout,
                        output,
                        stats.clone(),
                        shutdown.clone(),
                    ));
                }
                Err(e) => {
                    errors.inc();
                    tracing::warn!(error = %e, output = output.as_str(), "accept failed");
                    // Out of descriptors and the like: let some close before trying again.
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            },
            e = recv_counting(&mut rx, &lagged), if pipeline_open => {
                let Some(first) = e else {
                    pipeline_open = false;
                    continue;
                };
                let mut chunk = Chunk { bytes: Vec::new(), messages: 0 };
                chunk.messages += formatter.format(&first, &mut chunk.bytes);
                for _ in 1..EVENTS_PER_CHUNK {
                    match try_recv_counting(&mut rx, &lagged) {
                        Some(e) => chunk.messages += formatter.format(&e, &mut chunk.bytes),
                        None => break,
                    }
                }
                // With no client the chunk is dropped here (send fails: nobody listens).
                if !chunk.bytes.is_empty() {
                    let _ = chunks.send(Arc::new(chunk));
                }
            }
        }
    }
    drop(chunks);
    while tasks.join_next().await.is_some() {}
}

/// One client: writes every chunk, reads and discards what the client sends (so its
/// closing is seen at once), drops it when it lags or stalls.
async fn client(
    sock: TcpStream,
    mut chunks: broadcast::Receiver<Arc<Chunk>>,
    write_timeout: Duration,
    output: Output,
    stats: Arc<OutputStats>,
    shutdown: CancellationToken,
) {
    let _ = sock.set_nodelay(true);
    let (mut rd, mut wr) = sock.into_split();
    let sent = stats.messages_sent(output);
    let dropped = stats.clients_dropped(output);
    let mut scratch = [0u8; 512];
    loop {
        tokio::select! {
            biased;
            _ = shutdown.cancelled() => break,
            r = rd.read(&mut scratch) => match r {
                Ok(0) | Err(_) => break,
                Ok(_) => {}
            },
            c = chunks.recv() => match c {
                Ok(chunk) => {
                    let write = tokio::time::timeout(write_timeout, wr.write_all(&chunk.bytes));
                    let written = tokio::select! {
                        biased;
                        _ = shutdown.cancelled() => break,
                        w = write => w,
                    };
                    match written {
                        Ok(Ok(())) => {
                            sent.inc_by(chunk.messages);
                        }
                        Ok(Err(_)) => break,
                        Err(_) => {
                            dropped.inc();
                            tracing::info!(output = output.as_str(), "client dropped: a write stalled");
                            break;
                        }
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    dropped.inc();
                    tracing::info!(output = output.as_str(), chunks = n, "client dropped: it fell behind");
                    break;
                }
                Err(broadcast::error::RecvError::Closed) => break,
            },
        }
    }
    stats.clients(output).dec();
}
