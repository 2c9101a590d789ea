//! What a cluster node reads off the bus (`src/cluster/`): frame packs (`wire::decode`) and
//! track-bucket values (`state::decode`), which any client of the NATS server can write.
//!
//! Input: the message bytes. Checks: neither decoder panics; a pack's frames re-encode to a
//! pack that decodes to the same frames, from the same receiver (when its id, invalid UTF-8
//! replaced, still fits the id's 255 bytes).
#![no_main]

use adsb_tracker::cluster::{state, wire};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(p) = wire::decode(data) {
        let mut w = wire::PackWriter::new(&p.receiver);
        for f in &p.frames {
            w.push(f);
        }
        let again = wire::decode(&w.finish()).expect("a written pack decodes");
        assert_eq!(again.frames, p.frames);
        if p.receiver.len() <= wire::MAX_RECEIVER_BYTES {
            assert_eq!(again.receiver, p.receiver);
        }
        assert_eq!(again.error, None);
    }
    if let Ok(p) = state::decode(data) {
        // A value that decodes makes a Track without panicking.
        let _ = p.track_state();
    }
});
