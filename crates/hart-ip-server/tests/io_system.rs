//! The server as a HART I/O system, byte by byte: what answers at polling address 0,
//! where each address goes (the table in docs/hart-ip.md), the answer for an absent
//! device, and the I/O-system commands (38, 48, 74, 75, 77, 84, 101, 102) and the
//! universal ones it answers itself.

mod common;
use common::{frame, run};
use std::time::Duration;

use hart_host::hartip::HartIpSession;
use hart_host::target::open;
use hart_host::Client;
use hart_ip_server::{start, Config, Server};
use hart_proto::frame::{Address, Frame, UniqueId};

/// The I/O system's unique ID (the default identity).
fn gateway() -> UniqueId {
    UniqueId::new(0x26FF, 1)
}

fn plant(name: &str, devices: &[(&str, u8)]) -> String {
    let path = std::env::temp_dir().join(format!("hartkit-io-{}-{name}.toml", std::process::id()));
    let mut text = String::new();
    for (profile, poll) in devices {
        text.push_str(&format!(
            "[[device]]\nprofile = \"{profile}\"\npoll = {poll}\n"
        ));
    }
    std::fs::write(&path, text).unwrap();
    format!("sim:{}?virtual", path.display())
}

async fn server(loops: &[String], transparent: bool) -> Server {
    let clients = loops
        .iter()
        .map(|t| Client::new(open(t).unwrap()))
        .collect();
    start(
        Config {
            bind: "127.0.0.1:0".parse().unwrap(),
            scan_to: Some(6),
            transparent,
            ..Config::default()
        },
        clients,
    )
    .await
    .unwrap()
}

/// Sends a request PDU and returns the reply: (response code, device status, data).
async fn ask(s: &HartIpSession, address: Address, command: u16, data: &[u8]) -> (u8, u8, Vec<u8>) {
    let r = s
        .request(&frame(address, command, data), Duration::from_secs(10))
        .await
        .unwrap();
    let f = Frame::parse_pdu(&r).unwrap();
    assert_eq!(
        f.address.to_string(),
        address.to_string(),
        "reply from the address asked"
    );
    (
        f.response_code.unwrap(),
        f.device_status.unwrap(),
        f.data.to_vec(),
    )
}

/// Waits until the background scan has listed `n` sub-devices (command 74).
async fn scanned(s: &HartIpSession, n: u16) {
    for _ in 0..200 {
        let (_, _, d) = ask(s, Address::long(gateway()), 74, &[]).await;
        if u16::from_be_bytes([d[3], d[4]]) == n + 1 {
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("the scan did not find {n} sub-devices");
}

/// One loop with a device at polling address 0: the I/O system answers there, the
/// device by its unique ID and through command 77; polling addresses 1-63 go to the
/// loop; an absent device gets response code 35 at once from the I/O system's view.
#[test]
fn one_loop_the_io_system_answers_at_polling_address_0() {
    run(async {
        let server = server(&[plant("one", &[("pressure", 0), ("valve", 3)])], false).await;
        let s = HartIpSession::connect(&server.udp_addr.unwrap().to_string(), false, 60_000)
            .await
            .unwrap();
        // Command 0 at polling address 0: the I/O system (flags 0x04 protocol bridge,
        // device profile 68), cold start reported once.
        let (rc, status, id) = ask(&s, Address::short(0), 0, &[]).await;
        assert_eq!(rc, 0);
        assert_eq!(status & 0x20, 0x20, "cold start");
        assert_eq!((id[1], id[2]), (0x26, 0xFF), "expanded device type");
        assert_eq!(id[8] & 0x04, 0x04, "protocol bridge flag");
        assert_eq!(id[21], 68, "HART-IP I/O system profile");
        let (_, status, _) = ask(&s, Address::short(0), 0, &[]).await;
        assert_eq!(status & 0x20, 0, "cold start reported once");
        scanned(&s, 2).await;
        // Command 84: index 0 is the I/O system, 1 and 2 the devices, 3 beyond.
        let (rc, _, me) = ask(&s, Address::long(gateway()), 84, &[0, 0]).await;
        assert_eq!((rc, me[2], me[3]), (0, 251, 251));
        let (rc, _, first) = ask(&s, Address::long(gateway()), 84, &[0, 1]).await;
        assert_eq!((rc, first[2], first[3]), (0, 0, 0), "card 0, channel 0");
        let device_at_0 = UniqueId::new(
            u16::from_be_bytes([first[6], first[7]]),
            u32::from_be_bytes([0, first[8], first[9], first[10]]),
        );
        assert_eq!(ask(&s, Address::long(gateway()), 84, &[0, 3]).await.0, 2);
        // The device at polling address 0 by its unique ID.
        let (rc, _, pv) = ask(&s, Address::long(device_at_0), 1, &[]).await;
        assert_eq!((rc, pv[0]), (0, 12), "kPa");
        // Polling addresses 1-63 go to the one loop.
        assert_eq!(ask(&s, Address::short(3), 0, &[]).await.0, 0);
        // An absent device: response code 35 from its own address, no data.
        let before = server.stats().await.forwarded;
        let (rc, _, data) = ask(&s, Address::short(9), 1, &[]).await;
        assert_eq!((rc, data.len()), (35, 0));
        assert_eq!(server.stats().await.forwarded, before + 1);
        let stranger = UniqueId::new(0x1234, 0x56);
        assert_eq!(ask(&s, Address::long(stranger), 0, &[]).await.0, 35);
        // Command 75: poll sub-device, the command 0 data of the device there.
        let (rc, _, d) = ask(&s, Address::long(gateway()), 75, &[0, 0, 3]).await;
        assert_eq!((rc, d[1], d[2]), (0, 0x26, 0xF3), "the valve at 3");
        assert_eq!(ask(&s, Address::long(gateway()), 75, &[0, 0, 9]).await.0, 9);
        assert_eq!(
            ask(&s, Address::long(gateway()), 75, &[0, 4, 3]).await.0,
            22
        );
        // Command 77 to a silent address: 35, not a wait.
        let (rc, _, _) = ask(
            &s,
            Address::long(gateway()),
            77,
            &[0, 0, 5, 0x02, 0x89, 0, 0],
        )
        .await;
        assert_eq!(rc, 35);
        s.close().await;
        server.stop();
    });
}

/// `transparent`: a loop device at polling address 0 answers there; the I/O system
/// stays reachable by its unique ID.
#[test]
fn transparent_lets_the_device_at_0_answer() {
    run(async {
        let server = server(&[plant("tr", &[("temperature", 0)])], true).await;
        let s = HartIpSession::connect(&server.tcp_addr.unwrap().to_string(), true, 60_000)
            .await
            .unwrap();
        scanned(&s, 1).await;
        let (rc, _, id) = ask(&s, Address::short(0), 0, &[]).await;
        assert_eq!(
            (rc, id[1], id[2]),
            (0, 0x26, 0xF2),
            "the temperature transmitter"
        );
        let (rc, _, id) = ask(&s, Address::long(gateway()), 0, &[]).await;
        assert_eq!((rc, id[21]), (0, 68));
        s.close().await;
        server.stop();
    });
}

/// Several loops: short addresses 1-63 go to the one loop with a device there, else
/// the answer is 35 at once; tags find devices on any loop.
#[test]
fn several_loops_route_by_polling_address_tag_and_unique_id() {
    run(async {
        let server = server(
            &[
                plant("a", &[("pressure", 1)]),
                plant("b", &[("valve", 1), ("temperature", 4)]),
            ],
            false,
        )
        .await;
        let s = HartIpSession::connect(&server.udp_addr.unwrap().to_string(), false, 60_000)
            .await
            .unwrap();
        scanned(&s, 3).await;
        // Polling address 4 names one device (loop b); 1 names two; 2 none.
        let (rc, _, id) = ask(&s, Address::short(4), 0, &[]).await;
        assert_eq!((rc, id[2]), (0, 0xF2));
        assert_eq!(ask(&s, Address::short(1), 0, &[]).await.0, 35);
        assert_eq!(ask(&s, Address::short(2), 0, &[]).await.0, 35);
        // Command 11 (by tag) with the broadcast address finds the valve on loop b.
        let tag = hart_proto::types::PackedString::<6>::new("FV-300").unwrap();
        let (rc, _, id) = ask(&s, Address::long(UniqueId::BROADCAST), 11, &tag.0).await;
        assert_eq!((rc, id[2]), (0, 0xF3));
        // ... and the I/O system by its own tag.
        let tag = hart_proto::types::PackedString::<6>::new("HARTGW").unwrap();
        let (rc, _, id) = ask(&s, Address::long(UniqueId::BROADCAST), 11, &tag.0).await;
        assert_eq!((rc, id[2]), (0, 0xFF));
        s.close().await;
        server.stop();
    });
}

/// The I/O system's own data: writes (17, 18, 22) set "configuration changed" until
/// command 38 resets it with the right counter; command 48 reports a changed
/// sub-device list once; commands 101/102 map burst messages to sub-devices.
#[test]
fn io_system_commands_and_status() {
    run(async {
        let server = server(&[plant("st", &[("pressure", 1)])], false).await;
        let s = HartIpSession::connect(&server.udp_addr.unwrap().to_string(), false, 60_000)
            .await
            .unwrap();
        let gw = Address::long(gateway());
        scanned(&s, 1).await;
        // Sub-device list changed: "more status available" until command 48 reads it.
        let (_, status, _) = ask(&s, gw, 13, &[]).await;
        assert_eq!(status & 0x10, 0x10);
        let (rc, _, st) = ask(&s, gw, 48, &[]).await;
        assert_eq!((rc, st.len(), st[11] & 0x01), (0, 14, 0x01));
        let (_, status, st) = ask(&s, gw, 48, &[]).await;
        assert_eq!((status & 0x10, st[11]), (0, 0), "reported once");
        // Write the message; read it back; the counter goes up.
        let (_, _, id) = ask(&s, gw, 0, &[]).await;
        let counter = u16::from_be_bytes([id[14], id[15]]);
        let msg = hart_proto::types::PackedString::<24>::new("LINE 3 MUX").unwrap();
        assert_eq!(ask(&s, gw, 17, &msg.0).await.0, 0);
        let (_, status, back) = ask(&s, gw, 12, &[]).await;
        assert_eq!(back, msg.0);
        assert_eq!(status & 0x40, 0x40, "configuration changed");
        let (_, _, id) = ask(&s, gw, 0, &[]).await;
        let now = u16::from_be_bytes([id[14], id[15]]);
        assert_eq!(now, counter + 1);
        assert_eq!(
            ask(&s, gw, 38, &counter.to_be_bytes()).await.0,
            9,
            "stale counter"
        );
        assert_eq!(ask(&s, gw, 38, &now.to_be_bytes()).await.0, 0);
        assert_eq!(ask(&s, gw, 13, &[]).await.1 & 0x40, 0, "flag reset");
        // No process variable: unit 250 ("not used") and NaN.
        let (rc, _, pv) = ask(&s, gw, 1, &[]).await;
        assert_eq!((rc, pv[0], &pv[1..5]), (0, 250, &[0x7F, 0xA0, 0, 0][..]));
        // Commands 101/102: burst message 1 publishes sub-device 1.
        assert_eq!(ask(&s, gw, 101, &[1]).await, (0, 0, vec![1, 0, 0]));
        assert_eq!(ask(&s, gw, 102, &[1, 0, 1]).await.2, vec![1, 0, 1]);
        assert_eq!(ask(&s, gw, 101, &[1]).await.2, vec![1, 0, 1]);
        assert_eq!(ask(&s, gw, 102, &[1, 0, 7]).await.0, 9, "no sub-device 7");
        assert_eq!(ask(&s, gw, 101, &[9]).await.0, 2, "no burst message 9");
        assert_eq!(ask(&s, gw, 101, &[]).await.0, 5);
        // Commands the I/O system does not have.
        assert_eq!(ask(&s, gw, 35, &[0; 9]).await.0, 64);
        s.close().await;
        server.stop();
    });
}

#[test]
fn io_system_publishes_a_mapped_sub_device() {
    run(async {
        let server = server(&[plant("pub", &[("pressure", 1)])], false).await;
        let s = HartIpSession::connect(&server.udp_addr.unwrap().to_string(), false, 60_000)
            .await
            .unwrap();
        let gw = Address::long(gateway());
        scanned(&s, 1).await;
        // Message 1: sub-device 1, command 1, every 0.1 s (raised from 0.01 s: RC 8).
        assert_eq!(ask(&s, gw, 102, &[1, 0, 1]).await.0, 0);
        assert_eq!(ask(&s, gw, 108, &[0, 1, 1]).await.0, 0);
        let (rc, _, period) = ask(&s, gw, 103, &[1, 0, 0, 1, 64, 0, 0, 1, 64]).await;
        assert_eq!(
            (rc, &period[1..5]),
            (8, &[0, 0, 0x06, 0x40][..]),
            "50 ms at least"
        );
        assert_eq!(
            ask(&s, gw, 103, &[1, 0, 0, 0x0C, 0x80, 0, 0, 0x0C, 0x80])
                .await
                .0,
            0
        );
        assert_eq!(ask(&s, gw, 109, &[2, 1]).await.0, 2, "no TDMA");
        assert_eq!(ask(&s, gw, 109, &[1, 1]).await.0, 0);
        assert_eq!(ask(&s, gw, 109, &[1, 7]).await.0, 9, "no burst message 7");
        let (rc, _, conf) = ask(&s, gw, 105, &[1]).await;
        assert_eq!((rc, conf[0], conf[10], conf[12], conf[13]), (0, 1, 1, 0, 1));
        // Burst frames of the pressure transmitter arrive as publish messages.
        let mut seen = 0;
        for _ in 0..50 {
            let Ok(Some(p)) =
                tokio::time::timeout(Duration::from_millis(200), s.next_publish()).await
            else {
                continue;
            };
            let f = Frame::parse_pdu(&p).unwrap();
            if f.command == 1 && f.address.burst() {
                assert_eq!(f.frame_type(), hart_proto::frame::FrameType::Back);
                assert_eq!(f.data[0], 12, "kPa");
                seen += 1;
                if seen == 3 {
                    break;
                }
            }
        }
        assert_eq!(seen, 3, "publish messages of the mapped sub-device");
        s.close().await;
        server.stop();
    });
}

/// Sub-device indexes hold: a device that stops answering keeps its index (command 84
/// still names it), one that comes back is at the same index, and a new device takes
/// a new index; command 48 reports each change of the list once.
#[test]
fn sub_device_indexes_are_stable() {
    run(async {
        use hart_poller::{Engine, EngineConfig, Line, LoopSettings, LoopSpec, MemoryLoop};
        let devices = hart_host::transport::Plant::from_profiles(&[
            "pressure".into(),
            "temperature".into(),
            "valve".into(),
        ])
        .unwrap()
        .devices()
        .unwrap();
        let m = MemoryLoop::new(devices);
        let faults = m.faults();
        // Polling, with a rescan step every 5 ms: a device is found gone (two rescan
        // visits without a reply) within a fraction of a second.
        let mut config = EngineConfig {
            poll: true,
            ..EngineConfig::default()
        };
        config.defaults.rescan = Duration::from_millis(5);
        config.defaults.period = Duration::from_millis(50);
        let (engine, tasks) = Engine::start(
            config,
            vec![LoopSpec {
                settings: LoopSettings {
                    scan_to: 4,
                    ..Default::default()
                },
                line: Line::Memory(m),
            }],
        );
        let server = hart_ip_server::start_with_engine(
            Config {
                bind: "127.0.0.1:0".parse().unwrap(),
                ..Config::default()
            },
            engine,
            tasks,
        )
        .await
        .unwrap();
        server.ready().await;
        let s = HartIpSession::connect(&server.udp_addr.unwrap().to_string(), false, 60_000)
            .await
            .unwrap();
        let gw = Address::long(gateway());
        scanned(&s, 3).await;
        // Index -> device ID (bytes 7-9 of command 84's reply).
        let index = |i: u8| {
            let s = &s;
            async move {
                let (rc, _, d) = ask(s, gw, 84, &[0, i]).await;
                (rc == 0).then(|| d[7..10].to_vec())
            }
        };
        let before = [index(1).await, index(2).await, index(3).await];
        assert!(before.iter().all(Option::is_some), "{before:?}");
        let _ = ask(&s, gw, 48, &[]).await; // the list as it is now
                                            // The temperature transmitter (polling address 2) goes away.
        faults.set_connected(2, false);
        let mut changed = false;
        for _ in 0..400 {
            tokio::time::sleep(Duration::from_millis(10)).await;
            let (_, _, d) = ask(&s, gw, 48, &[]).await;
            if d[11] & 1 != 0 {
                changed = true;
                break;
            }
        }
        assert!(changed, "command 48 reports the device gone");
        assert_eq!(
            [index(1).await, index(2).await, index(3).await],
            before,
            "indexes hold while it is away"
        );
        assert_eq!(
            ask(&s, gw, 74, &[]).await.2[3..5],
            [0, 4],
            "places, with the I/O system"
        );
        // Back: at its own index again.
        faults.set_connected(2, true);
        let mut back = false;
        for _ in 0..400 {
            tokio::time::sleep(Duration::from_millis(10)).await;
            let (_, _, d) = ask(&s, gw, 48, &[]).await;
            if d[11] & 1 != 0 {
                back = true;
                break;
            }
        }
        assert!(back, "command 48 reports it back");
        assert_eq!([index(1).await, index(2).await, index(3).await], before);
        assert_eq!(
            index(4).await,
            None,
            "no new place for a device that came back"
        );
        s.close().await;
        server.stop();
    });
}
