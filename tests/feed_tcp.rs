//! The TCP client against a real local server: a connection cut mid-frame, a reconnect that
//! serves the rest, refused connections, and shutdown.

mod feed_common;

use adsb_tracker::feed::tcp::{run_client_with, ClientTiming, FeedStatus, FrameBatch, TcpFeed};
use adsb_tracker::feed::{Format, RawFrame};
use feed_common::{beast_reference, hex, read_fixture};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::TcpListener;
use tokio::sync::{mpsc, oneshot};
use tokio_util::sync::CancellationToken;

/// Short waits so the test runs in well under a second.
const TIMING: ClientTiming = ClientTiming {
    backoff_initial: Duration::from_millis(20),
    backoff_max: Duration::from_millis(100),
    connect_timeout: Duration::from_secs(2),
    idle_timeout: Duration::from_secs(5),
};

/// Upper bound on any wait in these tests.
const DEADLINE: Duration = Duration::from_secs(10);

fn feed(addr: std::net::SocketAddr, format: Format) -> TcpFeed {
    TcpFeed {
        name: "test".to_string(),
        addr: addr.to_string(),
        format,
        nominal_rate_hz: 100.0,
        silence_timeout_s: 5.0,
    }
}

/// Receives batches until `n` frames have arrived (or the deadline passes).
async fn receive(rx: &mut mpsc::Receiver<FrameBatch>, n: usize) -> (Vec<RawFrame>, usize) {
    let mut frames = Vec::new();
    let mut batches = 0;
    tokio::time::timeout(DEADLINE, async {
        while frames.len() < n {
            let batch = rx.recv().await.expect("client dropped the channel");
            assert_eq!(&*batch.feed, "test");
            assert!(!batch.frames.is_empty());
            frames.extend(batch.frames);
            batches += 1;
        }
    })
    .await
    .expect("frames did not arrive in time");
    (frames, batches)
}

#[tokio::test]
async fn beast_reconnect_after_a_cut_mid_frame() {
    let wire = read_fixture("toulouse-sample.beast");
    let reference = beast_reference(&wire);
    // Frame 120 holds no escaped byte, so its second half (sent first on the new
    // connection) contains no 0x1a and is skipped as plain garbage.
    let cut_frame = &reference[120];
    assert!(!wire[cut_frame.start + 1..cut_frame.end].contains(&0x1a));
    let cut = (cut_frame.start + cut_frame.end) / 2;

    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (first, rest) = (wire[..cut].to_vec(), wire[cut..].to_vec());
    let (release, released) = oneshot::channel::<()>();
    let server = tokio::spawn(async move {
        let (mut conn, _) = listener.accept().await.unwrap();
        conn.write_all(&first).await.unwrap();
        drop(conn); // the cut: mid-frame
        let (mut conn, _) = listener.accept().await.unwrap();
        conn.write_all(&rest).await.unwrap();
        let _ = released.await; // hold the second connection open
    });

    let (tx, mut rx) = mpsc::channel(16);
    let status = Arc::new(FeedStatus::new("test"));
    let shutdown = CancellationToken::new();
    let client = tokio::spawn(run_client_with(
        feed(addr, Format::Beast),
        TIMING,
        tx,
        Arc::clone(&status),
        shutdown.clone(),
    ));

    let (frames, batches) = receive(&mut rx, 238).await;
    assert!(
        batches >= 2,
        "one batch per read, and at least one per connection"
    );
    let expected: Vec<_> = reference
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != 120)
        .map(|(_, f)| f)
        .collect();
    assert_eq!(frames.len(), expected.len());
    for (i, (got, want)) in frames.iter().zip(&expected).enumerate() {
        assert_eq!(got.bytes(), &want.data[..], "frame {i}");
        assert_eq!(got.signal, Some(want.signal), "frame {i}");
        assert_eq!(got.time_s, want.counter as f64 / 12e6, "frame {i}");
    }

    let s = status.snapshot();
    assert!(s.connected);
    assert_eq!((s.connects, s.disconnects), (2, 1));
    assert_eq!(s.bytes, wire.len() as u64);
    assert_eq!(s.frames, 238);
    assert_eq!(s.last_error.as_deref(), Some("closed by peer"));
    assert_eq!(s.parse.frames, 238);
    assert_eq!(s.parse.truncated_tail_bytes, (cut - cut_frame.start) as u64);
    assert_eq!(s.parse.garbage_bytes, (cut_frame.end - cut) as u64);
    assert_eq!(s.parse.bad_frames, 0);
    // The snapshot serialises for /healthz.
    let json = serde_json::to_value(&s).unwrap();
    assert_eq!(
        json["parse"]["truncated_tail_bytes"],
        (cut - cut_frame.start) as u64
    );

    shutdown.cancel();
    tokio::time::timeout(DEADLINE, client)
        .await
        .unwrap()
        .unwrap();
    let s = status.snapshot();
    assert!(!s.connected);
    assert_eq!(s.disconnects, 2);
    let _ = release.send(());
    tokio::time::timeout(DEADLINE, server)
        .await
        .unwrap()
        .unwrap();
}

#[tokio::test]
async fn avr_final_line_without_newline_is_delivered_at_disconnect() {
    let text = String::from_utf8(read_fixture("lax-messages.avr.txt")).unwrap();
    let lines: Vec<&str> = text.lines().take(100).collect();
    let payload = lines.join("\n"); // no newline after the last line
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let server = tokio::spawn(async move {
        let (mut conn, _) = listener.accept().await.unwrap();
        conn.write_all(payload.as_bytes()).await.unwrap();
        // Close, then refuse further connections by dropping the listener.
    });

    let (tx, mut rx) = mpsc::channel(16);
    let status = Arc::new(FeedStatus::new("test"));
    let shutdown = CancellationToken::new();
    let client = tokio::spawn(run_client_with(
        feed(addr, Format::Avr),
        TIMING,
        tx,
        Arc::clone(&status),
        shutdown.clone(),
    ));
    let (frames, _) = receive(&mut rx, 100).await;
    assert_eq!(frames.len(), 100);
    assert_eq!(frames[0].bytes(), hex("02C60B9ED4497C"));
    assert_eq!(frames[99].bytes(), hex(&lines[99][1..lines[99].len() - 1]));
    // 100 Hz nominal pacing: frame 99 at 0.99 s.
    assert_eq!(frames[99].time_s, 99.0 / 100.0);
    tokio::time::timeout(DEADLINE, server)
        .await
        .unwrap()
        .unwrap();
    let s = status.snapshot();
    assert_eq!(s.parse.truncated_tail_bytes, 0);
    assert_eq!(s.parse.bad_lines, 0);

    shutdown.cancel();
    tokio::time::timeout(DEADLINE, client)
        .await
        .unwrap()
        .unwrap();
}

#[tokio::test]
async fn refused_connections_back_off_and_shutdown_stops_the_client() {
    // A port nobody listens on: bind, note it, close.
    let addr = {
        let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
        l.local_addr().unwrap()
    };
    let (tx, _rx) = mpsc::channel(16);
    let status = Arc::new(FeedStatus::new("test"));
    let shutdown = CancellationToken::new();
    let client = tokio::spawn(run_client_with(
        feed(addr, Format::Beast),
        TIMING,
        tx,
        Arc::clone(&status),
        shutdown.clone(),
    ));
    tokio::time::sleep(Duration::from_millis(300)).await;
    let s = status.snapshot();
    assert_eq!((s.connects, s.connected), (0, false));
    let err = s.last_error.unwrap_or_default();
    assert!(err.starts_with(&format!("connect to {addr}")), "{err}");

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(1), client)
        .await
        .expect("client did not stop on shutdown")
        .unwrap();
}
