//! Fair turns on the server's thread: a large body goes out a slice per turn.
//!
//! hyper writes a response body for as long as the body has data and the socket takes it:
//! left alone, one poll of a connection task copies a whole 1.7 MB track list (until tokio's
//! cooperative budget of 128 socket writes runs out). With 256 clients downloading, a
//! request for `/healthz` then waits for 256 such copies before its connection is polled
//! (0.3-1 s, measured). [`Sliced`] hands hyper a shared body [`SLICE_BYTES`] at a time, and
//! the server runs each connection's future in [`turns`], which gives each poll a budget of
//! [`TURN_BYTES`]: once a poll has had its share, the body yields (the task goes to the back
//! of the run queue), so every connection with work gets a short turn in order and a small
//! request waits for at most one short turn of each large download.

use axum::body::Bytes;
use std::cell::Cell;
use std::convert::Infallible;
use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};

/// Bytes of a large body handed to hyper at a time (zero-copy slices of the shared body).
pub const SLICE_BYTES: usize = 16 * 1024;

/// Bytes of large bodies one poll of a connection task may hand to hyper. One slice: a
/// turn is one `write` of 16 KiB (~10 µs on this machine), so 256 downloading clients
/// make a round of a few ms.
pub const TURN_BYTES: usize = SLICE_BYTES;

thread_local! {
    /// Bytes the connection task being polled on this thread may still send in this poll;
    /// unlimited outside [`turns`] (a body polled by a test or a tool, not by the server).
    static TURN_LEFT: Cell<usize> = const { Cell::new(usize::MAX) };
}

/// Polls `fut` with a budget of `bytes_per_turn` body bytes per poll (see the module doc);
/// a turn has room for one slice at least.
pub async fn turns<F: Future>(fut: F, bytes_per_turn: usize) -> F::Output {
    let bytes_per_turn = bytes_per_turn.max(SLICE_BYTES);
    let mut fut = std::pin::pin!(fut);
    std::future::poll_fn(move |cx| {
        let outer = TURN_LEFT.replace(bytes_per_turn);
        let r = fut.as_mut().poll(cx);
        TURN_LEFT.set(outer);
        r
    })
    .await
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
        Self { rest: body }
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
        let mut body = Sliced::new(Bytes::from(vec![7u8; 100_000]));
        assert_eq!(
            one_turn(&mut body, 2 * SLICE_BYTES),
            (2 * SLICE_BYTES, false)
        );
        assert_eq!(one_turn(&mut body, SLICE_BYTES), (SLICE_BYTES, false));
        assert_eq!(
            body.size_hint().exact(),
            Some((100_000 - 3 * SLICE_BYTES) as u64)
        );
        // Outside a turn (usize::MAX) the rest comes at once.
        assert_eq!(
            one_turn(&mut body, usize::MAX),
            (100_000 - 3 * SLICE_BYTES, true)
        );
        assert!(body.is_end_stream());
    }

    #[tokio::test]
    async fn turns_restore_the_outer_budget() {
        let inner = turns(async { TURN_LEFT.get() }, 123_456).await;
        assert_eq!(inner, 123_456);
        // A turn smaller than a slice would never send anything: it is raised to one.
        let inner = turns(async { TURN_LEFT.get() }, 10).await;
        assert_eq!(inner, SLICE_BYTES);
        assert_eq!(TURN_LEFT.get(), usize::MAX);
    }
}
