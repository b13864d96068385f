//! The PROFIBUS DP slave fed untrusted bytes at fuzzed times: the telegram decoder and
//! the state machine must not panic, everything the slave sends must be one whole
//! telegram for the master that asked, and a good diagnosis request after an idle line
//! must still be answered.
#![no_main]
use std::time::Duration;

use hart_profibus::fdl;
use hart_profibus::{Slave, SlaveConfig};
use libfuzzer_sys::fuzz_target;

fn check(reply: &[u8]) {
    let (t, n) = fdl::decode(reply)
        .expect("the slave sent a damaged telegram")
        .expect("the slave sent part of a telegram");
    assert_eq!(n, reply.len(), "more than one telegram at once");
    if let fdl::Telegram::Data(d) = t {
        assert_eq!(d.sa, 5, "a reply from another address");
    }
}

fuzz_target!(|data: &[u8]| {
    let Ok(mut slave) = Slave::new(SlaveConfig {
        address: 5,
        ident_number: 0x4854,
        cfg: vec![0xDD, 0xA5],
        baud: 19_200,
        max_tsdr_bits: 60,
        user_prm_len: 0,
    }) else {
        return;
    };
    let mut now = Duration::from_secs(1);
    // Pairs (gap, byte): the gap before the byte in 100 µs steps; bytes without a gap
    // go in one read.
    let mut run = vec![];
    for pair in data.chunks(2) {
        let (gap, b) = (pair[0], *pair.get(1).unwrap_or(&0));
        if gap != 0 && !run.is_empty() {
            slave.receive(now, &run);
            run.clear();
            now += Duration::from_micros(100 * u64::from(gap));
            while let Some(reply) = slave.poll_transmit(now) {
                check(&reply);
            }
        }
        run.push(b);
    }
    slave.receive(now, &run);
    now += Duration::from_millis(10);
    if let Some(reply) = slave.poll_transmit(now) {
        check(&reply);
    }
    // Diagnosis request from master 2 after an idle line: answered.
    now += Duration::from_millis(10);
    slave.receive(
        now,
        &[0x68, 0x05, 0x05, 0x68, 0x85, 0x82, 0x6D, 0x3C, 0x3E, 0xEE, 0x16],
    );
    now += Duration::from_millis(1);
    let reply = slave.poll_transmit(now).expect("a diagnosis request after silence");
    check(&reply);
});
