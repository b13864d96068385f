//! Malformed Modbus TCP requests against the gateway's server: each closes (or is
//! answered on) its own connection, and the server goes on answering others.
//! Byte-scripted: MBAP header (transaction, protocol 0, length, unit), then the PDU.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};

async fn server() -> std::net::SocketAddr {
    let devices = hart_host::transport::Plant::demo().devices().unwrap();
    let (engine, _) = hart_poller::Engine::start(
        hart_poller::EngineConfig {
            poll: true,
            ..Default::default()
        },
        vec![hart_poller::LoopSpec {
            settings: Default::default(),
            line: hart_poller::Line::Memory(hart_poller::MemoryLoop::new(devices)),
        }],
    );
    engine.ready().await;
    let gw = hart_modbus::Gateway::new(engine, Default::default());
    let (addr, serve) = hart_modbus::bind_tcp(gw, "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    tokio::spawn(serve);
    addr
}

/// Sends `bytes` on a new connection; what came back before the server closed it or
/// went quiet for 300 ms.
async fn exchange(addr: std::net::SocketAddr, bytes: &[u8]) -> Vec<u8> {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(bytes).await.unwrap();
    let mut out = vec![];
    let mut buf = [0u8; 512];
    while let Ok(Ok(n)) = tokio::time::timeout(Duration::from_millis(300), s.read(&mut buf)).await {
        if n == 0 {
            break;
        }
        out.extend_from_slice(&buf[..n]);
    }
    out
}

/// Read input registers 0-1 of unit 1: the answer must be two registers.
async fn still_serving(addr: std::net::SocketAddr) {
    let r = exchange(addr, &[0, 7, 0, 0, 0, 6, 1, 4, 0, 0, 0, 2]).await;
    assert_eq!(&r[..9], &[0, 7, 0, 0, 0, 7, 1, 4, 4], "{r:02X?}");
}

/// Set by any panic, the server's connection tasks included (tokio would catch those
/// and close only that connection: still a panic on untrusted input).
static PANICKED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

#[tokio::test(flavor = "current_thread")]
async fn malformed_requests_close_only_their_connection() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        PANICKED.store(true, std::sync::atomic::Ordering::SeqCst);
        default(info);
    }));
    let local = tokio::task::LocalSet::new();
    local
        .run_until(async {
            let addr = server().await;
            still_serving(addr).await;
            let cases: &[(&str, &[u8])] = &[
                // The fuzzer's find: write multiple registers (0x10) with quantity
                // 0xD200, byte count 0, for unit 0xD2.
                (
                    "quantity * 2 overflows u16",
                    &[
                        0, 1, 0, 0, 0, 9, 0xD2, 0x10, 0xD2, 0xB8, 0xD2, 0x00, 0x00, 0x10, 0x10,
                    ],
                ),
                (
                    "100 coils in one byte (the decoder would index past it)",
                    &[0, 1, 0, 0, 0, 8, 1, 0x0F, 0, 0, 0, 100, 1, 0],
                ),
                (
                    "read/write multiple registers, write quantity 32768",
                    &[0, 1, 0, 0, 0, 11, 1, 0x17, 0, 0, 0, 1, 0, 0, 0x80, 0, 0],
                ),
                ("length 0", &[0, 1, 0, 0, 0, 0]),
                ("length past the PDU limit", &[0, 1, 0, 0, 0xFF, 0xFF, 1, 4]),
                ("protocol id not 0", &[0, 1, 0, 1, 0, 6, 1, 4, 0, 0, 0, 2]),
                ("truncated read", &[0, 1, 0, 0, 0, 6, 1, 4, 0]),
                (
                    "byte count not twice the quantity",
                    &[0, 1, 0, 0, 0, 9, 1, 0x10, 0, 4, 0, 2, 3, 0, 0],
                ),
                ("unknown function", &[0, 1, 0, 0, 0, 2, 1, 0x63]),
            ];
            for (what, bytes) in cases {
                let r = exchange(addr, bytes).await;
                // Closed, or an exception answer (function | 0x80).
                assert!(
                    r.is_empty() || r.get(7).is_some_and(|f| f & 0x80 != 0),
                    "{what}: {r:02X?}"
                );
                still_serving(addr).await;
                assert!(
                    !PANICKED.load(std::sync::atomic::Ordering::SeqCst),
                    "{what}: the server panicked"
                );
            }
        })
        .await;
}
