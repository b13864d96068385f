//! The HART-IP server fed untrusted messages: one server (an I/O system with a pressure
//! transmitter answered in memory) runs for the whole fuzzing run; each input goes to
//! it as a datagram from a new address, as a datagram inside a session that was
//! opened first, or as a TCP stream after a session initiate (the first byte chooses).
//! After each input a fresh client must still get its session: the server may refuse
//! or ignore what it was sent, but never panic (a panic in the server aborts the run)
//! nor stop serving.
#![no_main]

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::sync::OnceLock;
use std::time::Duration;

use libfuzzer_sys::fuzz_target;

const INITIATE: [u8; 13] = [1, 0, 0, 0, 0, 1, 0, 13, 1, 0, 0, 0xEA, 0x60];

#[path = "support.rs"]
mod support;

fn server() -> SocketAddr {
    static ADDR: OnceLock<SocketAddr> = OnceLock::new();
    *ADDR.get_or_init(|| {
        support::in_background(|tx| async move {
            let mut c = hart_device::profiles::load("pressure").unwrap();
            c.polling_address = 1;
            let config = hart_ip_server::Config {
                bind: "127.0.0.1:0".parse().unwrap(),
                max_sessions: 100_000,
                max_sessions_per_host: 100_000,
                ..hart_ip_server::Config::default()
            };
            let s = hart_ip_server::start_in_memory(config, vec![hart_device::Device::new(c)])
                .await
                .unwrap();
            tx.send(s.udp_addr.unwrap()).unwrap();
            std::future::pending::<()>().await;
        })
    })
}

/// A session initiate on a new socket; the server must answer it.
fn initiate(addr: SocketAddr) -> UdpSocket {
    let s = UdpSocket::bind("127.0.0.1:0").unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    s.send_to(&INITIATE, addr).unwrap();
    let mut buf = [0u8; 64];
    let (n, _) = s.recv_from(&mut buf).expect("the server stopped answering");
    assert!(n >= 8 && buf[1] == 1, "not a response");
    s
}

fuzz_target!(|data: &[u8]| {
    let addr = server();
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    match mode % 3 {
        0 => {
            let s = UdpSocket::bind("127.0.0.1:0").unwrap();
            let _ = s.send_to(rest, addr);
        }
        1 => {
            let s = initiate(addr);
            let _ = s.send_to(rest, addr);
            // Let the session handle it (an answer, if any, or a short wait).
            s.set_read_timeout(Some(Duration::from_millis(1))).unwrap();
            let mut buf = [0u8; 2048];
            let _ = s.recv_from(&mut buf);
        }
        _ => {
            if let Ok(mut t) = TcpStream::connect(addr) {
                let _ = t.set_read_timeout(Some(Duration::from_millis(1)));
                let _ = t.write_all(&INITIATE);
                let _ = t.write_all(rest);
                let mut buf = [0u8; 2048];
                let _ = t.read(&mut buf);
            }
        }
    }
    // Still serving.
    let _ = initiate(addr);
});
