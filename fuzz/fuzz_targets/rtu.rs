//! The Modbus RTU slave's framer and request decoder fed untrusted bytes at fuzzed
//! times: every frame it takes must be for one of its units (1-4) or a broadcast, carry
//! a PDU, and decode to a request or an exception without panicking; a good request
//! after a silence must still be found.
#![no_main]
use std::time::{Duration, Instant};

use hart_modbus::rtu::{adu, decode_request, Event, Framer, Timing};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let timing = Timing::new(19_200, 11);
    let mut f = Framer::new(timing, 1..=4);
    let mut t = Instant::now();
    let check = |e: Event| {
        if let Event::Frame(fr) = e {
            assert!(fr.unit <= 4, "a frame for unit {}", fr.unit);
            assert!(!fr.pdu.is_empty());
            let _ = decode_request(&fr.pdu);
        }
    };
    // Each input byte pair is (gap, value): the gap before the byte in 100 µs steps
    // (0-25.5 ms, across t1.5 and t3.5); runs of bytes with no gap go in one read.
    let mut run = vec![];
    for pair in data.chunks(2) {
        let (gap, b) = (pair[0], *pair.get(1).unwrap_or(&0));
        if gap != 0 && !run.is_empty() {
            f.push(&run, t);
            run.clear();
            t += Duration::from_micros(100 * u64::from(gap));
            while let Some(e) = f.poll(t) {
                check(e);
            }
        }
        run.push(b);
    }
    f.push(&run, t);
    let request = adu(2, &[4, 0, 0, 0, 16]);
    t += timing.t35;
    f.push(&request, t);
    let mut found = false;
    while let Some(e) = f.poll(t + timing.t35) {
        found |= matches!(&e, Event::Frame(fr) if fr.unit == 2 && fr.pdu == [4, 0, 0, 0, 16]);
        check(e);
    }
    assert!(found, "a good request after a silence was not found");
});
