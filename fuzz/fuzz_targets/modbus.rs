//! The gateway's Modbus TCP front end fed untrusted bytes: one gateway (the polling
//! engine over the demo plant answered in memory, with Modbus TCP and HART-IP on it)
//! runs for the whole fuzzing run. Each input goes to it on a new connection, as raw
//! bytes or as Modbus PDUs (function code and data fuzzed) in well-formed MBAP headers
//! for any unit id (the first byte chooses). After each input a fresh client must still
//! read unit 1's registers: the gateway may refuse or close, but never panic nor stall.
#![no_main]

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::OnceLock;
use std::time::Duration;

use libfuzzer_sys::fuzz_target;

#[path = "support.rs"]
mod support;

fn gateway() -> SocketAddr {
    static ADDR: OnceLock<SocketAddr> = OnceLock::new();
    *ADDR.get_or_init(|| {
        support::in_background(|tx| async move {
            let engine = support::demo_engine().await;
            let gw = hart_modbus::Gateway::new(
                engine,
                hart_modbus::Config {
                    limits: hart_modbus::connections::Limits {
                        max_connections: 100_000,
                        max_per_address: 100_000,
                        ..Default::default()
                    },
                    ..Default::default()
                },
            );
            let (addr, serve) = hart_modbus::bind_tcp(gw, "127.0.0.1:0".parse().unwrap())
                .await
                .unwrap();
            tx.send(addr).unwrap();
            serve.await.unwrap();
        })
    })
}

/// An MBAP header (transaction 1, protocol 0) for `unit` around `pdu`.
fn adu(unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = vec![0, 1, 0, 0];
    out.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
    out.push(unit);
    out.extend_from_slice(pdu);
    out
}

/// Reads unit 1's input registers 0-15 on a new connection; the gateway must answer.
fn still_serving(addr: SocketAddr) {
    let mut t = TcpStream::connect(addr).expect("the gateway stopped accepting");
    t.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    t.write_all(&adu(1, &[4, 0, 0, 0, 16])).unwrap();
    let mut buf = [0u8; 64];
    let mut got = 0;
    while got < 9 + 32 {
        let n = t
            .read(&mut buf[got..])
            .expect("the gateway stopped answering");
        assert!(n > 0, "the gateway closed a good connection");
        got += n;
    }
    assert_eq!(&buf[7..9], &[4, 32], "not a read answer");
}

fuzz_target!(|data: &[u8]| {
    let addr = gateway();
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    if let Ok(mut t) = TcpStream::connect(addr) {
        let _ = t.set_read_timeout(Some(Duration::from_millis(2)));
        let bytes = match mode % 3 {
            0 => rest.to_vec(),
            1 => match rest.split_first() {
                Some((&unit, pdu)) => adu(unit, pdu),
                None => vec![],
            },
            // Several short PDUs for units 0-7, one after another.
            _ => rest
                .chunks(6)
                .flat_map(|c| adu(c[0] % 8, &c[1..]))
                .collect(),
        };
        let _ = t.write_all(&bytes);
        let mut buf = [0u8; 512];
        let _ = t.read(&mut buf);
    }
    still_serving(addr);
});
