//! Loopback benchmark of the HART-IP server: token-passing transactions per second over
//! UDP with a simulated device behind the server (virtual time), concurrent sessions,
//! and memory per idle session.
//!
//! `cargo run --release -p hart-ip-server --example loopback_bench -- [SESSIONS] [SECONDS] [line]`
//! `cargo run --release -p hart-ip-server --example loopback_bench -- soak [SECONDS]`: 200
//! sessions connecting, polling and dropping at random; lost replies, memory and open
//! descriptors before and after.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use hart_host::target::open;
use hart_host::Client;
use hart_ip::{encode, Message, MessageId, MessageType};
use hart_ip_server::{start, start_in_memory, Config};
use tokio::net::UdpSocket;

fn rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

async fn session(server: SocketAddr) -> UdpSocket {
    session_with_timer(server, 600_000).await
}

async fn session_with_timer(server: SocketAddr, timer_ms: u32) -> UdpSocket {
    let s = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let mut buf = [0u8; 64];
    let n = encode(
        1,
        MessageType::Request,
        MessageId::SessionInitiate,
        0,
        1,
        &hart_ip::session_initiate_body(1, timer_ms),
        &mut buf,
    )
    .unwrap();
    s.send_to(&buf[..n], server).await.unwrap();
    let mut r = [0u8; 64];
    let (n, from) = s.recv_from(&mut r).await.unwrap();
    let (m, _) = Message::parse(&r[..n]).unwrap();
    assert!(
        m.header.status == 0 || m.header.status == 8,
        "session refused: status {}",
        m.header.status
    );
    s.connect(from).await.unwrap();
    s
}

/// Datagrams the kernel dropped because a UDP receive buffer was full (whole host).
fn udp_rcvbuf_errors() -> u64 {
    let snmp = std::fs::read_to_string("/proc/net/snmp").unwrap_or_default();
    let mut udp = snmp.lines().filter(|l| l.starts_with("Udp:"));
    let (Some(names), Some(values)) = (udp.next(), udp.next()) else {
        return 0;
    };
    names
        .split_whitespace()
        .zip(values.split_whitespace())
        .find(|(n, _)| *n == "RcvbufErrors")
        .and_then(|(_, v)| v.parse().ok())
        .unwrap_or(0)
}

fn open_fds() -> usize {
    std::fs::read_dir("/proc/self/fd").map_or(0, |d| d.count())
}

/// 200 sessions that connect, poll, listen to publish messages and drop at random.
async fn soak(seconds: f64) {
    let config = Config {
        bind: "127.0.0.1:0".parse().unwrap(),
        tcp: false,
        max_sessions: 100_000,
        // Every client is on 127.0.0.1.
        max_sessions_per_host: 100_000,
        scan_to: None,
        ..Config::default()
    };
    let mut c = hart_device::profiles::load("pressure").unwrap();
    c.polling_address = 1;
    c.burst[0].control = 1;
    c.burst[0].update_period = 16_000;
    c.burst[0].max_update_period = 16_000;
    let server = start_in_memory(config, vec![hart_device::Device::new(c)])
        .await
        .unwrap();
    let addr = server.udp_addr.unwrap();
    let (rss0, fds0, drops0) = (rss_kib(), open_fds(), udp_rcvbuf_errors());
    let deadline = Instant::now() + Duration::from_secs_f64(seconds);
    let mut tasks = vec![];
    for k in 0..200u64 {
        tasks.push(tokio::task::spawn_local(async move {
            let mut rng = hart_rng::Rng::new(k);
            let mut next = || rng.next_u64();
            let (mut ok, mut lost, mut sessions, mut publishes) = (0u64, 0u64, 0u64, 0u64);
            let pdu = [0x02u8, 0x81, 0x01, 0x00, 0x82];
            while Instant::now() < deadline {
                // A short inactivity timer, so the sessions this client drops end soon.
                let s = session_with_timer(addr, 2000).await;
                sessions += 1;
                let polls = next() % 50;
                let mut seq = 10u16;
                for _ in 0..polls {
                    seq = seq.wrapping_add(1);
                    let mut buf = [0u8; 64];
                    let n = encode(
                        1,
                        MessageType::Request,
                        MessageId::TokenPassingPdu,
                        0,
                        seq,
                        &pdu,
                        &mut buf,
                    )
                    .unwrap();
                    s.send(&buf[..n]).await.unwrap();
                    let mut r = [0u8; 512];
                    // Publish messages may arrive before the reply.
                    let mut answered = false;
                    while let Ok(Ok(m)) =
                        tokio::time::timeout(Duration::from_secs(1), s.recv(&mut r)).await
                    {
                        match Message::parse(&r[..m]) {
                            Ok((msg, _)) if msg.header.message_type == MessageType::Publish => {
                                publishes += 1
                            }
                            Ok((msg, _)) if msg.header.sequence == seq => {
                                answered = true;
                                break;
                            }
                            _ => {}
                        }
                    }
                    if answered {
                        ok += 1
                    } else {
                        lost += 1
                    }
                    if next() % 10 == 0 {
                        tokio::time::sleep(Duration::from_millis(next() % 50)).await;
                    }
                }
                // Half the time close politely, otherwise just drop (the server times out).
                if next() % 2 == 0 {
                    let mut buf = [0u8; 8];
                    let n = encode(
                        1,
                        MessageType::Request,
                        MessageId::SessionClose,
                        0,
                        seq.wrapping_add(1),
                        &[],
                        &mut buf,
                    )
                    .unwrap();
                    let _ = s.send(&buf[..n]).await;
                }
            }
            (ok, lost, sessions, publishes)
        }));
    }
    let (mut ok, mut lost, mut sessions, mut publishes) = (0, 0, 0, 0);
    for t in tasks {
        let (a, b, c, d) = t.await.unwrap();
        ok += a;
        lost += b;
        sessions += c;
        publishes += d;
    }
    // Let the dropped sessions time out.
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let (rss1, fds1, drops1) = (rss_kib(), open_fds(), udp_rcvbuf_errors());
    let st = server.stats().await;
    println!("soak {seconds} s: {sessions} sessions ({} opened at the server; a client port the kernel reuses continues its session), {ok} replies, {lost} lost ({} datagrams dropped by full kernel receive buffers), {publishes} publish messages; resident memory {rss0} -> {rss1} KiB, open descriptors {fds0} -> {fds1}, sessions still open {}", st.sessions_opened, drops1 - drops0, server.active_sessions().await);
    server.stop();
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("soak") {
        let seconds: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(60.0);
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let local = tokio::task::LocalSet::new();
        local.block_on(&rt, soak(seconds));
        return;
    }
    let sessions: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(16);
    let seconds: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5.0);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async move {
        let config = Config { bind: "127.0.0.1:0".parse().unwrap(), tcp: false, max_sessions: 100_000, max_sessions_per_host: 100_000, scan_to: None, ..Config::default() };
        // `line` puts the device on a simulated line (the full data link); the default
        // answers in memory.
        let server = if std::env::args().any(|a| a == "line") {
            start(config, vec![Client::new(open("sim?virtual").unwrap())]).await.unwrap()
        } else {
            let mut c = hart_device::profiles::load("pressure").unwrap();
            c.polling_address = 1;
            start_in_memory(config, vec![hart_device::Device::new(c)]).await.unwrap()
        };
        let addr = server.udp_addr.unwrap();

        // Memory per idle session.
        let before = rss_kib();
        let mut idle = vec![];
        for _ in 0..1000 {
            idle.push(session(addr).await);
        }
        let after = rss_kib();
        println!("1000 idle sessions: {} KiB more resident memory ({:.1} KiB per session, both ends in one process)", after.saturating_sub(before), after.saturating_sub(before) as f64 / 1000.0);
        drop(idle);

        // Throughput: `sessions` sessions, each one command 1 request after the other.
        // A command 1 request in a short frame to polling address 1.
        let pdu = [0x02u8, 0x81, 0x01, 0x00, 0x82];
        let mut socks = vec![];
        for _ in 0..sessions {
            socks.push(session(addr).await);
        }
        let deadline = Instant::now() + Duration::from_secs_f64(seconds);
        let mut tasks = vec![];
        for (k, s) in socks.into_iter().enumerate() {
            tasks.push(tokio::task::spawn_local(async move {
                let mut done = 0u64;
                let mut seq = 2u16.wrapping_add(k as u16);
                let mut buf = [0u8; 64];
                let mut r = [0u8; 512];
                while Instant::now() < deadline {
                    seq = seq.wrapping_add(1);
                    let n = encode(1, MessageType::Request, MessageId::TokenPassingPdu, 0, seq, &pdu, &mut buf).unwrap();
                    s.send(&buf[..n]).await.unwrap();
                    match tokio::time::timeout(Duration::from_secs(2), s.recv(&mut r)).await {
                        Ok(Ok(m)) => {
                            if let Ok((msg, _)) = Message::parse(&r[..m]) {
                                if msg.header.sequence == seq && !msg.body.is_empty() {
                                    done += 1;
                                }
                            }
                        }
                        _ => break,
                    }
                }
                done
            }));
        }
        let start = Instant::now();
        let mut total = 0;
        for t in tasks {
            total += t.await.unwrap();
        }
        let secs = start.elapsed().as_secs_f64();
        println!("{sessions} sessions over UDP: {total} transactions in {secs:.2} s = {:.0} transactions/s", total as f64 / secs);
        server.stop();
    });
}
