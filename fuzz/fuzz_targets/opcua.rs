//! The gateway's OPC UA front end fed untrusted bytes: one gateway (the polling engine
//! over the demo plant in memory, with OPC UA and Modbus TCP on it) runs for the whole
//! fuzzing run. Each input goes to the OPC UA port on a new connection: raw bytes, a
//! valid Hello followed by the input, or the input as the body of an OpenSecureChannel
//! or Message chunk with a correct header (the first byte chooses). After each input a
//! fresh OPC UA client must still get its Acknowledge, and a Modbus client its
//! registers: no panic, no stall of either front end.
#![no_main]

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::OnceLock;
use std::time::Duration;

use libfuzzer_sys::fuzz_target;

#[path = "support.rs"]
mod support;

/// (OPC UA address, Modbus address).
fn gateway() -> (SocketAddr, SocketAddr) {
    static ADDRS: OnceLock<(SocketAddr, SocketAddr)> = OnceLock::new();
    *ADDRS.get_or_init(|| {
        support::in_background(|tx| async move {
            let engine = support::demo_engine().await;
            let pki = std::env::temp_dir().join(format!("hartkit-fuzz-pki-{}", std::process::id()));
            let ua = hart_opcua::start(
                engine.clone(),
                hart_opcua::Config {
                    bind: "127.0.0.1:0".parse().unwrap(),
                    security: hart_opcua::Security::None,
                    users: vec![],
                    pki_dir: pki,
                    read_only: false,
                    limits: Default::default(),
                },
            )
            .unwrap();
            let gw = hart_modbus::Gateway::new(engine, Default::default());
            let (mb, serve) = hart_modbus::bind_tcp(gw, "127.0.0.1:0".parse().unwrap())
                .await
                .unwrap();
            tx.send((ua.addr, mb)).unwrap();
            serve.await.unwrap();
            drop(ua);
        })
    })
}

/// A Hello for `url`.
fn hello(url: &str) -> Vec<u8> {
    let mut body = vec![];
    for v in [0u32, 65_536, 65_536, 0, 0] {
        body.extend_from_slice(&v.to_le_bytes());
    }
    body.extend_from_slice(&(url.len() as i32).to_le_bytes());
    body.extend_from_slice(url.as_bytes());
    chunk(b"HEL", &body)
}

/// A chunk of `kind` (final) around `body`.
fn chunk(kind: &[u8; 3], body: &[u8]) -> Vec<u8> {
    let mut out = kind.to_vec();
    out.push(b'F');
    out.extend_from_slice(&((body.len() + 8) as u32).to_le_bytes());
    out.extend_from_slice(body);
    out
}

fn still_serving(ua: SocketAddr, mb: SocketAddr) {
    let mut t = TcpStream::connect(ua).expect("OPC UA stopped accepting");
    t.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    t.write_all(&hello(&format!("opc.tcp://{ua}/"))).unwrap();
    let mut buf = [0u8; 64];
    let mut got = 0;
    while got < 4 {
        let n = t.read(&mut buf[got..]).expect("OPC UA stopped answering");
        assert!(n > 0, "OPC UA closed a good Hello");
        got += n;
    }
    assert_eq!(&buf[..4], b"ACKF", "not an Acknowledge");
    let mut m = TcpStream::connect(mb).expect("Modbus stopped accepting");
    m.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    m.write_all(&[0, 1, 0, 0, 0, 6, 1, 4, 0, 0, 0, 2]).unwrap();
    let mut r = [0u8; 13];
    m.read_exact(&mut r).expect("Modbus stalled");
    assert_eq!(&r[7..9], &[4, 4]);
}

fuzz_target!(|data: &[u8]| {
    let (ua, mb) = gateway();
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    if let Ok(mut t) = TcpStream::connect(ua) {
        let _ = t.set_read_timeout(Some(Duration::from_millis(2)));
        let bytes = match mode % 4 {
            0 => rest.to_vec(),
            1 => {
                let mut b = hello(&format!("opc.tcp://{ua}/"));
                b.extend_from_slice(rest);
                b
            }
            2 => chunk(b"OPN", rest),
            _ => {
                let mut b = hello(&format!("opc.tcp://{ua}/"));
                b.extend(chunk(b"MSG", rest));
                b
            }
        };
        let _ = t.write_all(&bytes);
        let mut buf = [0u8; 512];
        let _ = t.read(&mut buf);
    }
    still_serving(ua, mb);
});
