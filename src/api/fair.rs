//! Fair turns and two lanes on the server's threads: large bodies go out a slice per turn,
//! on threads of their own, and never hold up a small request.
//!
//! hyper writes a response body for as long as the body has data and the socket takes it:
//! left alone, one poll of a connection task copies a whole 1.7 MB track list (until tokio's
//! cooperative budget of 128 socket writes runs out). With 256 clients downloading, a
//! request for `/healthz` then waits for 256 such copies before its connection is polled
//! (0.3-1 s, measured). So:
//! - **Turns.** [`Sliced`] hands hyper a shared body [`SLICE_BYTES`] at a time, and each poll
//!   of a connection has a budget of bytes ([`TURN_BYTES`]); once a poll has had its share,
//!   the body yields (the task goes to the back of the run queue): every download moves a
//!   short step per round.
//! - **Lanes.** [`serve_connection`] polls a connection on the *request lane* (the thread
//!   that accepts, reads requests and answers the small ones, at `server.request_nice`)
//!   with a budget of zero: as soon as a response with a [`Sliced`] body is under way, the
//!   connection moves to the *bulk lane* (`server.threads` threads at `server.nice`), where
//!   the copying happens; once its large bodies are sent it moves back. The copying, the
//!   CPU-heavy part, thus yields to ingest, while `/healthz` never queues behind it.
//! - **Builds.** [`spawn_build`] runs the track list's serialisation and compression on the
//!   bulk lane's blocking threads (at its niceness), wherever the request came in.

use axum::body::Bytes;
use std::cell::{Cell, RefCell};
use std::convert::Infallible;
use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};
use tokio::runtime::Handle;

/// Bytes of a large body handed to hyper at a time (zero-copy slices of the shared body).
/// 64 KiB is one segment on the loopback interface (MTU 65,536): with 1,000 tracks and 256
/// clients, 64 KiB writes served 2-2.9x the responses per CPU-second of 16 KiB ones (the
/// cost is mostly per `write` and per segment, not per byte).
pub const SLICE_BYTES: usize = 64 * 1024;

/// Bytes of large bodies one poll of a connection task may hand to hyper on the bulk lane:
/// one slice, one `write`, so the downloads under way take turns in 64 KiB steps.
pub const TURN_BYTES: usize = SLICE_BYTES;

thread_local! {
    /// Bytes the connection task being polled on this thread may still send in this poll;
    /// unlimited outside [`turns`] (a body polled by a test or a tool, not by the server).
    static TURN_LEFT: Cell<usize> = const { Cell::new(usize::MAX) };
    /// [`Sliced`] bodies made less those dropped on this thread since the connection being
    /// polled started this poll: a connection's bodies are made (by its handler) and dropped
    /// (by hyper, once sent) while it is polled, so the sum over its polls is the number it
    /// has under way.
    static SLICED_DELTA: Cell<i64> = const { Cell::new(0) };
    /// The bulk lane, on the request lane's threads: where [`spawn_build`] sends builds.
    static BULK_LANE: RefCell<Option<Handle>> = const { RefCell::new(None) };
}

/// Makes `bulk` the bulk lane of the calling thread (a request-lane thread).
pub fn set_bulk_lane(bulk: Handle) {
    BULK_LANE.with(|b| *b.borrow_mut() = Some(bulk));
}

/// Runs `f` on a blocking thread of the bulk lane (of the current runtime outside the
/// server, as in tests that call the router directly).
pub fn spawn_build<F, R>(f: F) -> tokio::task::JoinHandle<R>
where
    F: FnOnce() -> R + Send + 'static,
    R: Send + 'static,
{
    match BULK_LANE.with(|b| b.borrow().clone()) {
        Some(bulk) => bulk.spawn_blocking(f),
        None => tokio::task::spawn_blocking(f),
    }
}

/// A connection's future, movable between the lanes.
pub type Connection<T> = Pin<Box<dyn Future<Output = T> + Send>>;

/// Where a connection goes after a stretch on one lane.
enum Lane<T> {
    Done(T),
    /// To the other lane, with its [`Sliced`] bodies under way.
    Move(Connection<T>, i64),
}

/// Polls `conn` on the current thread with `bytes_per_turn` bytes a poll until it ends or,
/// after a poll, its bodies under way say it belongs on the other lane: any (`to_bulk`),
/// or none (`!to_bulk`).
async fn stretch<T>(
    conn: Connection<T>,
    bytes_per_turn: usize,
    live: i64,
    to_bulk: bool,
) -> Lane<T> {
    let mut slot = Some(conn);
    let mut live = live;
    std::future::poll_fn(move |cx| {
        // Never polled again once it has returned Ready (below), when the slot is emptied.
        let Some(conn) = slot.as_mut() else {
            return Poll::Pending;
        };
        let outer_turn = TURN_LEFT.replace(bytes_per_turn);
        let outer_delta = SLICED_DELTA.replace(0);
        let r = conn.as_mut().poll(cx);
        live += SLICED_DELTA.replace(outer_delta);
        TURN_LEFT.set(outer_turn);
        match r {
            Poll::Ready(t) => Poll::Ready(Lane::Done(t)),
            Poll::Pending if (live > 0) == to_bulk => match slot.take() {
                Some(conn) => Poll::Ready(Lane::Move(conn, live)),
                None => Poll::Pending,
            },
            Poll::Pending => Poll::Pending,
        }
    })
    .await
}

/// Aborts a task when dropped (a connection cut on the request lane is cut on the bulk one).
struct AbortOnDrop<T>(tokio::task::JoinHandle<T>);

impl<T> Drop for AbortOnDrop<T> {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Serves `conn` on the current thread (the request lane), moving it to `bulk` while it
/// sends [`Sliced`] bodies (see the module doc). Returns what the connection returned, or
/// None if its task on the bulk lane was cut (runtime shut down).
pub async fn serve_connection<T: Send + 'static>(conn: Connection<T>, bulk: &Handle) -> Option<T> {
    let (mut conn, mut live) = (conn, 0);
    loop {
        // Nothing large is sent on the request lane: a turn of zero bytes.
        match stretch(conn, 0, live, true).await {
            Lane::Done(t) => return Some(t),
            Lane::Move(c, l) => (conn, live) = (c, l),
        }
        let mut task = AbortOnDrop(bulk.spawn(stretch(conn, TURN_BYTES, live, false)));
        match (&mut task.0).await {
            Ok(Lane::Done(t)) => return Some(t),
            Ok(Lane::Move(c, l)) => (conn, live) = (c, l),
            Err(_) => return None,
        }
    }
}

/// Takes `n` bytes from this poll's budget, or none if fewer are left.
fn take_turn_bytes(n: usize) -> bool {
    TURN_LEFT.with(|left| {
        let l = left.get();
        if l == usize::MAX {
            return true;
        }
        if l >= n {
            left.set(l - n);
            true
        } else {
            false
        }
    })
}

/// A shared, already serialised body sent in [`SLICE_BYTES`] slices, one turn at a time.
pub struct Sliced {
    rest: Bytes,
}

impl Sliced {
    pub fn new(body: Bytes) -> Self {
        SLICED_DELTA.set(SLICED_DELTA.get() + 1);
        Self { rest: body }
    }
}

impl Drop for Sliced {
    fn drop(&mut self) {
        SLICED_DELTA.set(SLICED_DELTA.get() - 1);
    }
}

impl http_body::Body for Sliced {
    type Data = Bytes;
    type Error = Infallible;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Bytes>, Self::Error>>> {
        if self.rest.is_empty() {
            return Poll::Ready(None);
        }
        let n = self.rest.len().min(SLICE_BYTES);
        if !take_turn_bytes(n) {
            // This turn is used up: come back after the others had theirs.
            cx.waker().wake_by_ref();
            return Poll::Pending;
        }
        let slice = self.rest.split_to(n);
        Poll::Ready(Some(Ok(http_body::Frame::data(slice))))
    }

    fn is_end_stream(&self) -> bool {
        self.rest.is_empty()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        http_body::SizeHint::with_exact(self.rest.len() as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use http_body::Body;

    /// Polls `body` once in a turn of `budget` bytes; the bytes it gave.
    fn one_turn(body: &mut Sliced, budget: usize) -> (usize, bool) {
        let waker = std::task::Waker::noop();
        let mut cx = Context::from_waker(waker);
        let outer = TURN_LEFT.replace(budget);
        let mut got = 0;
        let mut ended = false;
        loop {
            match Pin::new(&mut *body).poll_frame(&mut cx) {
                Poll::Ready(Some(Ok(f))) => got += f.into_data().map(|d| d.len()).unwrap_or(0),
                Poll::Ready(None) => {
                    ended = true;
                    break;
                }
                Poll::Ready(Some(Err(e))) => match e {},
                Poll::Pending => break,
            }
        }
        TURN_LEFT.set(outer);
        (got, ended)
    }

    #[test]
    fn a_turn_gives_its_budget_and_no_more() {
        let mut body = Sliced::new(Bytes::from(vec![7u8; 3 * SLICE_BYTES + 1000]));
        // The request lane's turn: nothing.
        assert_eq!(one_turn(&mut body, 0), (0, false));
        assert_eq!(
            one_turn(&mut body, 2 * SLICE_BYTES),
            (2 * SLICE_BYTES, false)
        );
        assert_eq!(one_turn(&mut body, SLICE_BYTES), (SLICE_BYTES, false));
        assert_eq!(body.size_hint().exact(), Some(1000));
        // Outside a turn (usize::MAX) the rest comes at once.
        assert_eq!(one_turn(&mut body, usize::MAX), (1000, true));
        assert!(body.is_end_stream());
    }

    /// A connection that sends one large body, then a small answer: where each part ran.
    #[test]
    fn large_bodies_are_sent_on_the_bulk_lane_and_nothing_else() {
        let bulk = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("bulk-lane")
            .build()
            .unwrap();
        let requests = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let lane = || std::thread::current().name().unwrap_or("").to_string();
        let conn: Connection<Vec<(String, usize)>> = Box::pin(async move {
            let mut seen = vec![(lane(), 0)];
            let mut body = Sliced::new(Bytes::from(vec![1u8; 5 * SLICE_BYTES + 10]));
            loop {
                let frame = std::future::poll_fn(|cx| Pin::new(&mut body).poll_frame(cx)).await;
                match frame {
                    Some(Ok(f)) => seen.push((lane(), f.into_data().map(|d| d.len()).unwrap_or(0))),
                    Some(Err(e)) => match e {},
                    None => break,
                }
            }
            drop(body);
            // Let the lanes see the body is gone.
            tokio::task::yield_now().await;
            seen.push((lane(), 0));
            seen
        });
        let handle = bulk.handle().clone();
        let seen = requests.block_on(serve_connection(conn, &handle)).unwrap();
        let here = lane();
        assert_eq!(seen.first().map(|s| s.0.as_str()), Some(here.as_str()));
        let sent: Vec<_> = seen[1..seen.len() - 1].to_vec();
        assert_eq!(
            sent.iter().map(|s| s.1).sum::<usize>(),
            5 * SLICE_BYTES + 10
        );
        assert!(sent.iter().all(|s| s.0 == "bulk-lane"), "{seen:?}");
        assert_eq!(
            seen.last().map(|s| s.0.as_str()),
            Some(here.as_str()),
            "{seen:?}"
        );
    }
}
