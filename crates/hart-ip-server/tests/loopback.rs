//! Our HART-IP client against our server on loopback, over UDP and TCP, with a
//! simulated plant behind the server.

use std::time::Duration;

use hart_host::hartip::HartIpTransport;
use hart_host::target::{open, AnyTransport};
use hart_host::{Client, DeviceRef, HostError};
use hart_ip_server::{start, Config};

fn config() -> Config {
    Config {
        bind: "127.0.0.1:0".parse().unwrap(),
        ..Config::default()
    }
}

async fn connect(addr: std::net::SocketAddr, tcp: bool) -> Client<AnyTransport> {
    Client::new(AnyTransport::HartIp(Box::new(
        HartIpTransport::connect(&addr.to_string(), tcp, 60_000)
            .await
            .unwrap(),
    )))
}

#[test]
fn udp_and_tcp_sessions_reach_the_devices() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        let server = start(config(), vec![Client::new(open("sim?virtual").unwrap())])
            .await
            .unwrap();
        for (addr, tcp) in [
            (server.udp_addr.unwrap(), false),
            (server.tcp_addr.unwrap(), true),
        ] {
            let mut c = connect(addr, tcp).await;
            let d = c.resolve(&DeviceRef::Poll(1)).await.unwrap();
            assert_eq!(d.identity.expanded_device_type, 0x26F1);
            let r = c.command(&d, 3, &[]).await.unwrap();
            assert!(r.data.len() >= 9);
            let t = c.resolve(&DeviceRef::Tag("TT-200".into())).await.unwrap();
            assert_eq!(t.identity.expanded_device_type, 0x26F2);
            // Burst frames of the temperature transmitter arrive as publish messages.
            c.listen(5_000_000).await.unwrap();
            assert!(
                !c.take_bursts().is_empty(),
                "publish messages over {}",
                if tcp { "TCP" } else { "UDP" }
            );
        }
        let st = server.stats().await;
        assert_eq!(st.sessions_opened, 2);
        // Read audit log: both sessions, with their request counts.
        let probe = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let udp = server.udp_addr.unwrap();
        let mut buf = [0u8; 2048];
        probe
            .send_to(&[1, 0, 0, 0, 0, 1, 0, 13, 1, 0, 0, 0xEA, 0x60], udp)
            .await
            .unwrap();
        probe.recv_from(&mut buf).await.unwrap();
        probe
            .send_to(&[1, 0, 5, 0, 0, 2, 0, 10, 0, 10], udp)
            .await
            .unwrap();
        // Publish messages (the burst device) may come first.
        let m = loop {
            let (n, _) = probe.recv_from(&mut buf).await.unwrap();
            let (m, _) = hart_ip::Message::parse(&buf[..n]).unwrap();
            if m.header.message_type == hart_ip::MessageType::Response {
                break m;
            }
        };
        let b = m.body;
        assert_eq!(
            (b[0], b[1]),
            (0, 3),
            "three sessions so far (two clients and this probe)"
        );
        assert_eq!(u16::from_be_bytes([b[20], b[21]]), 58, "record size");
        let rec = &b[22..80];
        assert_eq!(&rec[0..4], &[127, 0, 0, 1], "client IPv4");
        assert!(
            u32::from_be_bytes([rec[50], rec[51], rec[52], rec[53]]) >= 3,
            "request PDUs"
        );
        assert_ne!(
            u16::from_be_bytes([rec[40], rec[41]]) & 0x0010,
            0,
            "insecure (v1) session"
        );
        assert!(st.forwarded >= 6 && st.published >= 2, "{st:?}");
    });
}

#[test]
fn read_only_sessions_and_limits() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        let server = start(
            Config {
                read_only: true,
                max_sessions: 1,
                ..config()
            },
            vec![Client::new(open("sim?virtual").unwrap())],
        )
        .await
        .unwrap();
        let addr = server.udp_addr.unwrap();
        let mut c = connect(addr, false).await;
        let d = c.resolve(&DeviceRef::Poll(2)).await.unwrap();
        match c.command(&d, 19, &[0, 0, 1]).await {
            Err(HostError::Device { code: 16, .. }) => {}
            other => panic!("read-only must refuse writes: {other:?}"),
        }
        assert!(c.command(&d, 16, &[]).await.is_ok(), "reads go through");
        // The limit: a second session is refused with a clear status.
        let err = HartIpTransport::connect(&addr.to_string(), false, 60_000)
            .await
            .err()
            .expect("second session refused");
        assert!(
            err.to_string()
                .contains("all available sessions in use (15)"),
            "{err}"
        );
    });
}

#[test]
fn malformed_messages_do_not_disturb_other_sessions() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        let server = start(config(), vec![Client::new(open("sim?virtual").unwrap())])
            .await
            .unwrap();
        let (udp, tcp) = (server.udp_addr.unwrap(), server.tcp_addr.unwrap());
        let mut good = connect(udp, false).await;
        let d = good.resolve(&DeviceRef::Poll(3)).await.unwrap();
        // A misbehaving UDP peer: short header, byte count lies, unknown message ID,
        // reserved bits, oversized PDU, garbage after a session close.
        let bad = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let junk: [&[u8]; 6] = [
            &[1, 0, 2],
            &[1, 0, 2, 0, 0, 1, 0, 200, 0, 0],
            &[1, 0, 0, 0, 0, 1, 0, 13, 1, 0, 0, 0xEA, 0x60],
            &[1, 0, 9, 0, 0, 2, 0, 8],
            &[1, 0x70, 2, 0, 0, 3, 0, 8],
            &[1, 0, 1, 0, 0, 4, 0, 8, 0xDE, 0xAD],
        ];
        for j in junk {
            bad.send_to(j, udp).await.unwrap();
        }
        let mut big = vec![1u8, 0, 3, 0, 0, 5, 0xFF, 0xFF];
        big.resize(65_000, 0xAB);
        bad.send_to(&big, udp).await.unwrap();
        // A misbehaving TCP peer: garbage that cannot be split into messages.
        let mut t = tokio::net::TcpStream::connect(tcp).await.unwrap();
        tokio::io::AsyncWriteExt::write_all(&mut t, &[1, 0, 0, 0, 0, 1, 0, 3, 9, 9, 9])
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        // The good session goes on.
        assert!(good.command(&d, 1, &[]).await.is_ok());
        assert!(server.stats().await.malformed >= 3);
    });
}

/// Two loops behind one address: the gateway answers as an I/O system and routes.
#[test]
fn multiplexer_routes_to_sub_devices() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        let plant2 =
            std::env::temp_dir().join(format!("hart-ip-server-plant2-{}.toml", std::process::id()));
        std::fs::write(&plant2, "[[device]]\nprofile = \"valve\"\npoll = 5\n").unwrap();
        let loops = vec![
            Client::new(open("sim?virtual").unwrap()),
            Client::new(open(&format!("sim:{}?virtual", plant2.display())).unwrap()),
        ];
        let server = start(
            Config {
                scan_to: Some(6),
                ..config()
            },
            loops,
        )
        .await
        .unwrap();
        // The scan runs between requests, one polling address at a time.
        tokio::time::sleep(Duration::from_millis(500)).await;
        let mut c = connect(server.udp_addr.unwrap(), false).await;
        // The gateway itself at polling address 0.
        let gw = c.resolve(&DeviceRef::Poll(0)).await.unwrap();
        assert_eq!(
            gw.identity.device_profile.map(|p| p.0),
            Some(68),
            "HART-IP I/O system"
        );
        // Command 74: one card, two channels, 3 + 1 + 1 devices (the gateway included).
        let caps = c.command(&gw, 74, &[]).await.unwrap().data;
        assert_eq!(
            (caps[0], caps[1], u16::from_be_bytes([caps[3], caps[4]])),
            (1, 2, 5)
        );
        // Command 84: index 0 is the I/O system itself (card and channel 251, "none"),
        // then the sub-devices with their channel.
        let me = c.command(&gw, 84, &0u16.to_be_bytes()).await.unwrap().data;
        assert_eq!((me[2], me[3]), (251, 251));
        assert_eq!(
            &me[6..11],
            &[0x26, 0xFF, 0, 0, 1],
            "the I/O system's own ID"
        );
        let mut channels = vec![];
        for i in 1..5u16 {
            let s = c.command(&gw, 84, &i.to_be_bytes()).await.unwrap().data;
            channels.push(s[3]);
        }
        channels.sort();
        assert_eq!(channels, vec![0, 0, 0, 1]);
        assert!(matches!(
            c.command(&gw, 84, &9u16.to_be_bytes()).await,
            Err(HostError::Device { code: 2, .. })
        ));
        // Command 77: command 0 to polling address 5 on channel 1 (short frame inside).
        let r = c
            .command(&gw, 77, &[0, 1, 5, 0x02, 0x85, 0x00, 0x00])
            .await
            .unwrap()
            .data;
        assert_eq!(
            (r[0], r[1], r[2]),
            (0, 1, 0x06),
            "card, channel, then the ACK frame"
        );
        assert!(
            matches!(
                c.command(&gw, 77, &[0, 7, 5, 0x02, 0x85, 0x00, 0x00]).await,
                Err(HostError::Device { code: 22, .. })
            ),
            "invalid channel"
        );
        assert!(
            matches!(
                c.command(&gw, 77, &[3, 0, 5, 0x02, 0x85, 0x00, 0x00]).await,
                Err(HostError::Device { code: 21, .. })
            ),
            "invalid I/O card"
        );
        // A sub-device on channel 1 reached directly by its long address.
        let valve_id = hart_proto::UniqueId::new(0x26F3, 0x030001 + 5);
        let v = c.resolve(&DeviceRef::UniqueId(valve_id)).await.unwrap();
        assert_eq!(c.command(&v, 1, &[]).await.unwrap().data[0], 57);
        let _ = std::fs::remove_file(&plant2);
    });
}

/// The client reconnects when the server restarts, over UDP and TCP.
#[test]
fn client_survives_a_server_restart() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        for tcp in [false, true] {
            let server = start(config(), vec![Client::new(open("sim?virtual").unwrap())])
                .await
                .unwrap();
            let addr = if tcp {
                server.tcp_addr.unwrap()
            } else {
                server.udp_addr.unwrap()
            };
            let mut c = connect(addr, tcp).await;
            let d = c.resolve(&DeviceRef::Poll(1)).await.unwrap();
            assert!(c.command(&d, 1, &[]).await.is_ok());
            server.stop();
            tokio::time::sleep(Duration::from_millis(100)).await;
            // The port may be busy a moment longer (the old sockets close as their
            // tasks are dropped; another test may have drawn it): retry, as a
            // restarted service would.
            let mut again = None;
            for _ in 0..40 {
                match start(
                    Config {
                        bind: addr,
                        udp: !tcp,
                        tcp,
                        ..config()
                    },
                    vec![Client::new(open("sim?virtual").unwrap())],
                )
                .await
                {
                    Ok(s) => {
                        again = Some(s);
                        break;
                    }
                    Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
                }
            }
            let again = again.expect("the port is free again within 2 s");
            assert!(
                c.command(&d, 1, &[]).await.is_ok(),
                "after the restart over {}",
                if tcp { "TCP" } else { "UDP" }
            );
            again.stop();
        }
    });
}

/// A device that does not answer on the loop: the server says so with an empty
/// response, and the client reports it at once, without repeating the request (the
/// server already made the retries on the loop).
#[test]
fn absent_device_is_reported_by_the_server() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        let server = start(
            Config {
                scan_to: None,
                ..config()
            },
            vec![Client::new(open("sim?virtual").unwrap())],
        )
        .await
        .unwrap();
        for (addr, tcp) in [
            (server.udp_addr.unwrap(), false),
            (server.tcp_addr.unwrap(), true),
        ] {
            let mut c = connect(addr, tcp).await;
            let before = server.stats().await.forwarded;
            match c.resolve(&DeviceRef::Poll(9)).await {
                Err(e @ HostError::NoReplyBehindServer { .. }) => {
                    let msg = e.to_string();
                    assert!(msg.starts_with("no reply from polling address 9"), "{msg}");
                    assert!(msg.contains("did not answer on its loop"), "{msg}");
                    assert_eq!(e.exit_code(), 3);
                }
                other => panic!("{other:?}"),
            }
            assert_eq!(server.stats().await.forwarded, before + 1, "one request");
            // The session goes on.
            assert!(c.resolve(&DeviceRef::Poll(1)).await.is_ok());
        }
        server.stop();
    });
}

/// One raw HART-IP session over UDP, for tests that look at single messages.
struct RawSession {
    sock: tokio::net::UdpSocket,
    seq: u16,
}

impl RawSession {
    async fn open(server: std::net::SocketAddr) -> Self {
        let sock = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
        sock.connect(server).await.unwrap();
        let mut s = RawSession { sock, seq: 0 };
        let (h, _) = s
            .request(
                hart_ip::MessageId::SessionInitiate,
                &hart_ip::session_initiate_body(1, 60_000),
            )
            .await;
        assert_eq!(h.status, 0);
        s
    }

    async fn send(&mut self, id: hart_ip::MessageId, body: &[u8]) -> u16 {
        self.seq += 1;
        let mut buf = vec![0u8; 8 + body.len()];
        hart_ip::encode(
            1,
            hart_ip::MessageType::Request,
            id,
            0,
            self.seq,
            body,
            &mut buf,
        )
        .unwrap();
        self.sock.send(&buf).await.unwrap();
        self.seq
    }

    /// Next message within `ms` (publish messages included).
    async fn next(&self, ms: u64) -> Option<(hart_ip::Header, Vec<u8>)> {
        let mut r = [0u8; 600];
        let n = tokio::time::timeout(Duration::from_millis(ms), self.sock.recv(&mut r))
            .await
            .ok()?
            .ok()?;
        let (m, _) = hart_ip::Message::parse(&r[..n]).ok()?;
        Some((m.header, m.body.to_vec()))
    }

    /// A request and its response (publish messages meanwhile are dropped).
    async fn request(&mut self, id: hart_ip::MessageId, body: &[u8]) -> (hart_ip::Header, Vec<u8>) {
        let seq = self.send(id, body).await;
        loop {
            let (h, b) = self.next(3000).await.expect("a response");
            if h.message_type == hart_ip::MessageType::Response && h.sequence == seq {
                return (h, b);
            }
        }
    }

    /// Command `cmd` (extended through command 31 when above 255) to the broadcast long
    /// address: the response code and data of the reply.
    async fn command(&mut self, cmd: u16, data: &[u8]) -> (u8, Vec<u8>) {
        use hart_proto::frame::{Address, Frame, FrameBuf, FrameSpec, UniqueId};
        let broadcast = Address::long(UniqueId::from_bytes([0; 5]));
        let pdu = FrameBuf::encode(&FrameSpec::request(broadcast, cmd, data)).unwrap();
        let (_, body) = self
            .request(hart_ip::MessageId::TokenPassingPdu, pdu.as_slice())
            .await;
        let f = Frame::parse_pdu(&body).unwrap();
        assert_eq!(f.command, cmd);
        (f.response_code.unwrap(), f.data.to_vec())
    }

    /// Unique IDs of the devices whose publish messages arrive within `ms`.
    async fn publishers(&self, ms: u64) -> std::collections::BTreeSet<[u8; 5]> {
        let end = tokio::time::Instant::now() + Duration::from_millis(ms);
        let mut ids = std::collections::BTreeSet::new();
        while let Some(left) = end.checked_duration_since(tokio::time::Instant::now()) {
            let Some((h, b)) = self.next(left.as_millis() as u64 + 1).await else {
                break;
            };
            if h.message_type == hart_ip::MessageType::Publish {
                let f = hart_proto::frame::Frame::parse_pdu(&b).unwrap();
                if let hart_proto::frame::Address::Long(a) = f.address {
                    ids.insert(a.id.to_bytes());
                }
            }
        }
        ids
    }
}

/// Publish subscriptions (commands 532 and 533): a session that never subscribes gets
/// every burst message; one that does gets what it subscribed to, and the rules for
/// mixing a subscription to every device with single ones hold.
#[test]
fn publish_subscriptions_with_commands_532_and_533() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        let mut devices = vec![];
        for (profile, poll) in [("pressure", 1), ("temperature", 2)] {
            let mut c = hart_device::profiles::load(profile).unwrap();
            c.polling_address = poll;
            c.burst[0].control = 1;
            c.burst[0].update_period = 16_000; // 0.5 s
            c.burst[0].max_update_period = 16_000;
            devices.push(hart_device::Device::new(c));
        }
        let ids: Vec<[u8; 5]> = devices.iter().map(|d| d.unique_id().to_bytes()).collect();
        let server = hart_ip_server::start_in_memory(config(), devices)
            .await
            .unwrap();
        let addr = server.udp_addr.unwrap();
        let everything: std::collections::BTreeSet<_> = ids.iter().copied().collect();

        // Never subscribed: every device's burst messages; 532 shows that default.
        let mut a = RawSession::open(addr).await;
        assert_eq!(a.publishers(1500).await, everything);
        assert_eq!(
            a.command(532, &[0; 5]).await,
            (0, vec![0, 0, 0, 0, 0, 0, 1])
        );

        // Subscribed to nothing: no publish messages, and nothing to read back.
        let mut b = RawSession::open(addr).await;
        assert_eq!(b.command(533, &[0, 0, 0, 0, 0, 0, 0]).await.0, 0);
        assert!(b.publishers(1500).await.is_empty());
        assert_eq!(b.command(532, &[0; 5]).await.0, 65, "no subscription");

        // One device only.
        let mut req = ids[1].to_vec();
        req.extend([0x00, 0x01]);
        assert_eq!(b.command(533, &req).await, (0, req.clone()));
        assert_eq!(b.publishers(1500).await, [ids[1]].into());
        assert_eq!(b.command(532, &ids[1]).await, (0, req.clone()));
        assert_eq!(b.command(532, &ids[0]).await.0, 65);
        // An unknown device, and too few data bytes.
        assert_eq!(b.command(533, &[0x26, 0x99, 1, 2, 3, 0, 1]).await.0, 65);
        assert_eq!(b.command(533, &[0, 0, 0]).await.0, 5);

        // Every device again; single subscriptions are then refused.
        assert_eq!(b.command(533, &[0, 0, 0, 0, 0, 0, 1]).await.0, 0);
        assert_eq!(b.command(533, &req).await.0, 9);
        assert_eq!(b.command(532, &ids[1]).await.0, 9);
        assert_eq!(b.publishers(1500).await, everything);
        // The other session was never affected.
        assert_eq!(a.publishers(1500).await, everything);
        server.stop();
    });
}

/// Two loops behind one server and several requests in flight on one TCP session: a
/// request to the fast loop is answered while a request to the slow loop (a real-time
/// 1200 bit/s line) is still on its way.
#[test]
fn requests_to_different_loops_run_side_by_side() {
    use hart_host::hartip::HartIpSession;
    use hart_proto::frame::{Address, Frame, FrameBuf, FrameSpec};
    use std::sync::Arc;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async {
        let dir = std::env::temp_dir().join(format!("hartkit-loops-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let plant = |name: &str, profile: &str, poll: u8| {
            let p = dir.join(name);
            std::fs::write(
                &p,
                format!("[[device]]\nprofile = \"{profile}\"\npoll = {poll}\n"),
            )
            .unwrap();
            p.display().to_string()
        };
        let slow = open(&format!("sim:{}", plant("slow.toml", "pressure", 1))).unwrap();
        let fast = open(&format!(
            "sim:{}?virtual",
            plant("fast.toml", "temperature", 2)
        ))
        .unwrap();
        let server = start(
            Config {
                scan_to: Some(2),
                ..config()
            },
            vec![Client::new(slow), Client::new(fast)],
        )
        .await
        .unwrap();
        let session = Arc::new(
            HartIpSession::connect(&server.tcp_addr.unwrap().to_string(), true, 60_000)
                .await
                .unwrap(),
        );
        let frame = |id: hart_proto::frame::UniqueId, cmd: u16, data: &[u8]| {
            FrameBuf::encode(&FrameSpec::request(Address::long(id), cmd, data))
                .unwrap()
                .as_slice()
                .to_vec()
        };
        // Wait until the start-up scan has found both devices (command 84 to the
        // gateway itself names sub-devices 1 and 2).
        let gateway = hart_proto::frame::UniqueId::new(0x26FF, 1);
        let mut ids = vec![];
        for _ in 0..100 {
            ids.clear();
            for ix in [1u8, 2] {
                let r = session
                    .request(&frame(gateway, 84, &[0, ix]), Duration::from_secs(5))
                    .await
                    .unwrap();
                let f = Frame::parse_pdu(&r).unwrap();
                if f.response_code == Some(0) {
                    // Data: index (2), card, channel, manufacturer (2), type (2), ID (3).
                    let d = f.data;
                    let id = hart_proto::frame::UniqueId::new(
                        u16::from_be_bytes([d[6], d[7]]),
                        u32::from_be_bytes([0, d[8], d[9], d[10]]),
                    );
                    ids.push((d[3], id));
                }
            }
            if ids.len() == 2 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        ids.sort_by_key(|x| x.0);
        assert_eq!(ids.len(), 2, "both loops scanned: {ids:?}");
        let done = Arc::new(std::sync::Mutex::new(vec![]));
        let mut tasks = vec![];
        for (channel, id) in ids {
            let (session, done) = (session.clone(), done.clone());
            let pdu = frame(id, 0, &[]);
            tasks.push(tokio::task::spawn_local(async move {
                let r = session
                    .request(&pdu, Duration::from_secs(10))
                    .await
                    .unwrap();
                assert_eq!(Frame::parse_pdu(&r).unwrap().response_code, Some(0));
                done.lock().unwrap().push(channel);
            }));
            tokio::task::yield_now().await;
        }
        for t in tasks {
            t.await.unwrap();
        }
        assert_eq!(
            *done.lock().unwrap(),
            [1, 0],
            "the fast loop's reply came first although its request went second"
        );
        server.stop();
        let _ = std::fs::remove_dir_all(&dir);
    });
}
