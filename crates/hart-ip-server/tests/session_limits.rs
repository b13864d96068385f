//! Sessions cannot be held against other clients: the inactivity timer a client asks
//! for is granted only up to the server's longest, so sessions left silent free
//! themselves; one host's sessions (UDP and TCP together) and its TCP connections stay
//! within its share. Clients come from several loopback addresses (Linux routes all of
//! 127.0.0.0/8 to the loopback interface).

use std::net::{IpAddr, SocketAddr};
use std::time::Duration;

use hart_ip::{MessageId, MessageType};
use hart_ip_server::{granted_timer, Config, MIN_TIMER_MS};
use proptest::prelude::*;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

proptest! {
    /// The timer granted is always within the server's bounds, equal to the one asked
    /// for when that is within them, and reported as changed exactly when it differs.
    #[test]
    fn the_timer_granted_stays_within_bounds(asked: u32, max: u32) {
        let (granted, changed) = granted_timer(asked, max);
        let top = max.max(MIN_TIMER_MS);
        prop_assert!((MIN_TIMER_MS..=top).contains(&granted));
        prop_assert_eq!(changed, granted != asked);
        if (MIN_TIMER_MS..=top).contains(&asked) {
            prop_assert_eq!(granted, asked);
        }
    }
}

fn ip(last: u8) -> IpAddr {
    IpAddr::from([127, 0, 0, last])
}

fn initiate(seq: u16, timer_ms: u32) -> Vec<u8> {
    let body = hart_ip::session_initiate_body(1, timer_ms);
    let mut buf = vec![0u8; 8 + body.len()];
    hart_ip::encode(
        1,
        MessageType::Request,
        MessageId::SessionInitiate,
        0,
        seq,
        &body,
        &mut buf,
    )
    .unwrap();
    buf
}

fn command_0(seq: u16) -> Vec<u8> {
    use hart_proto::frame::{Address, FrameBuf, FrameSpec};
    let pdu = FrameBuf::encode(&FrameSpec::request(Address::short(0), 0, &[])).unwrap();
    let mut buf = vec![0u8; 8 + pdu.as_slice().len()];
    hart_ip::encode(
        1,
        MessageType::Request,
        MessageId::TokenPassingPdu,
        0,
        seq,
        pdu.as_slice(),
        &mut buf,
    )
    .unwrap();
    buf
}

/// A UDP session initiate from `from` asking for `timer_ms`: the response's status and
/// the timer it grants.
async fn udp_initiate(
    server: SocketAddr,
    from: IpAddr,
    timer_ms: u32,
) -> (tokio::net::UdpSocket, u8, Option<u32>) {
    let sock = tokio::net::UdpSocket::bind(SocketAddr::new(from, 0))
        .await
        .unwrap();
    sock.connect(server).await.unwrap();
    sock.send(&initiate(1, timer_ms)).await.unwrap();
    let mut r = [0u8; 64];
    let n = tokio::time::timeout(Duration::from_secs(5), sock.recv(&mut r))
        .await
        .expect("an answer to the initiate")
        .unwrap();
    let (m, _) = hart_ip::Message::parse(&r[..n]).unwrap();
    let timer = (m.body.len() >= 5)
        .then(|| u32::from_be_bytes([m.body[1], m.body[2], m.body[3], m.body[4]]));
    (sock, m.header.status, timer)
}

/// A TCP session initiate from `from`: the response's status, or `None` when the
/// server closed the connection without one.
async fn tcp_initiate(
    server: SocketAddr,
    from: IpAddr,
) -> (Option<tokio::net::TcpStream>, Option<u8>) {
    let sock = tokio::net::TcpSocket::new_v4().unwrap();
    sock.bind(SocketAddr::new(from, 0)).unwrap();
    let mut s = sock.connect(server).await.unwrap();
    if s.write_all(&initiate(1, 60_000)).await.is_err() {
        return (None, None);
    }
    // The header alone: a refusal has no body.
    let mut h = [0u8; 8];
    match tokio::time::timeout(Duration::from_secs(5), s.read_exact(&mut h)).await {
        Ok(Ok(_)) => (Some(s), Some(h[3])),
        _ => (None, None),
    }
}

/// The longest inactivity timer of the server in the test, ms: long enough that the
/// sessions outlast filling the server on a loaded machine.
const LONGEST_MS: u32 = 5_000;

fn server_config(max_timer_ms: u32) -> Config {
    Config {
        bind: "127.0.0.1:0".parse().unwrap(),
        max_timer_ms,
        scan_to: Some(2),
        ..Config::default()
    }
}

fn devices() -> Vec<hart_device::Device> {
    let mut c = hart_device::profiles::load("pressure").unwrap();
    c.polling_address = 0;
    vec![hart_device::Device::new(c)]
}

/// The reproduction of a review: sixteen UDP sessions from each of four addresses ask
/// for an inactivity timer of 0xFFFFFFFF ms (49.7 days), send one command 0 and then
/// nothing. They are granted the server's longest (status 8, the body saying how long),
/// fill the server while they last, and free it when that time has passed: a client
/// from a fifth address, refused meanwhile, then gets its session.
#[test]
fn sessions_asking_for_a_timer_of_49_days_free_the_server_within_its_longest() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        let server = hart_ip_server::start_in_memory(server_config(LONGEST_MS), devices())
            .await
            .unwrap();
        let udp = server.udp_addr.unwrap();
        let tcp = server.tcp_addr.unwrap();
        let mut held = vec![];
        for host in 2..=5 {
            for _ in 0..16 {
                let (sock, status, timer) = udp_initiate(udp, ip(host), u32::MAX).await;
                assert_eq!(
                    status, 8,
                    "a timer beyond the longest is set to the nearest (status 8)"
                );
                assert_eq!(
                    timer,
                    Some(LONGEST_MS),
                    "the initiate's body carries the timer granted"
                );
                sock.send(&command_0(2)).await.unwrap();
                held.push(sock);
            }
        }
        // Every session is taken: a fifth host is refused, over UDP and TCP.
        let (_, status, _) = udp_initiate(udp, ip(6), 60_000).await;
        assert_eq!(status, 15, "all available sessions in use");
        let (_, status) = tcp_initiate(tcp, ip(6)).await;
        assert_eq!(status, Some(15));
        // A host holding its share over UDP has none left over TCP either.
        let (_, status) = tcp_initiate(tcp, ip(2)).await;
        assert_eq!(
            status,
            Some(15),
            "the per-host limit counts UDP and TCP together"
        );

        // The attackers go silent (their sockets even stay open). Within the longest
        // timer (and the server's check after it), the sessions are closed: a fifth
        // host, asking again now and then, gets its session.
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        let (_sock, timer) = loop {
            let (sock, status, timer) = udp_initiate(udp, ip(6), 60_000).await;
            if status != 15 {
                assert_eq!(status, 8, "a session, with the longest timer");
                break (sock, timer);
            }
            assert!(
                std::time::Instant::now() < deadline,
                "the silent sessions were never closed"
            );
            tokio::time::sleep(Duration::from_millis(250)).await;
        };
        assert_eq!(timer, Some(LONGEST_MS));
        let (conn, status) = tcp_initiate(tcp, ip(7)).await;
        assert_eq!(status, Some(8));
        drop((conn, held));
        server.stop();
    });
}

/// A host that opens TCP connections and sends nothing in them holds no more than its
/// share of the server's connections: another host's session is opened meanwhile.
#[test]
fn silent_connections_from_one_host_leave_room_for_others() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        let server = hart_ip_server::start_in_memory(server_config(60_000), devices())
            .await
            .unwrap();
        let tcp = server.tcp_addr.unwrap();
        let mut silent = vec![];
        for _ in 0..120 {
            let sock = tokio::net::TcpSocket::new_v4().unwrap();
            sock.bind(SocketAddr::new(ip(9), 0)).unwrap();
            if let Ok(s) = sock.connect(tcp).await {
                silent.push(s);
            }
        }
        // Let the server accept (and close what is over the host's share).
        tokio::time::sleep(Duration::from_millis(300)).await;
        let (conn, status) = tcp_initiate(tcp, ip(10)).await;
        assert_eq!(status, Some(0), "another host's session is opened");
        // Most of the silent host's connections were closed at once.
        let mut open = 0;
        for s in &silent {
            let mut b = [0u8; 1];
            // Still open: nothing to read yet. Closed: end of stream or a reset.
            if tokio::time::timeout(Duration::from_millis(5), s.peek(&mut b))
                .await
                .is_err()
            {
                open += 1;
            }
        }
        assert!(
            open <= 18,
            "{open} silent connections of one host kept open (its share is 16 + 2)"
        );
        drop((conn, silent));
        server.stop();
    });
}
