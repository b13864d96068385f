//! The in-memory server (`start_in_memory`, behind `hartkit serve --sim --instant`)
//! honours the configuration as a server in front of a loop does: read-only, the
//! sub-device list up to `scan_to` and devices learnt beyond it, transparent polling
//! address 0, commands 11/21 found by tag, burst messages with alternating master bits.

mod common;
use common::{frame, run};
use std::time::Duration;

use hart_host::hartip::HartIpSession;
use hart_host::transport::{Plant, PlantBurst, PlantDevice};
use hart_ip_server::{start_in_memory, Config};
use hart_proto::frame::{Address, Frame, FrameType, MasterKind, UniqueId};

/// The reply frame's (address, response code, data).
async fn ask(
    s: &HartIpSession,
    address: Address,
    command: u16,
    data: &[u8],
) -> (Address, u8, Vec<u8>) {
    let r = s
        .request(&frame(address, command, data), Duration::from_secs(5))
        .await
        .unwrap();
    let f = Frame::parse_pdu(&r).unwrap();
    assert_eq!(f.frame_type(), FrameType::Ack);
    (f.address, f.response_code.unwrap(), f.data.to_vec())
}

/// Sub-devices the I/O system lists (command 74, devices detected less itself).
async fn listed(s: &HartIpSession) -> u16 {
    let (_, rc, d) = ask(s, Address::short(0), 74, &[]).await;
    assert_eq!(rc, 0);
    u16::from_be_bytes([d[3], d[4]]) - 1
}

fn plant() -> Plant {
    let d = |profile: &str, poll: u8, burst: Option<PlantBurst>| PlantDevice {
        profile: profile.into(),
        poll,
        burst,
        ..Default::default()
    };
    Plant {
        device: vec![
            d("pressure", 0, None),
            d(
                "temperature",
                2,
                Some(PlantBurst {
                    command: 1,
                    period: 0.5,
                }),
            ),
            d("valve", 9, None),
        ],
    }
}

#[test]
fn in_memory_server_honours_the_configuration() {
    run(async {
        let devices = plant().devices().unwrap();
        let ids: Vec<UniqueId> = devices.iter().map(|d| d.unique_id()).collect();
        let tags: Vec<String> = devices.iter().map(|d| d.config().tag.clone()).collect();
        let server = start_in_memory(
            Config {
                bind: "127.0.0.1:0".parse().unwrap(),
                read_only: true,
                scan_to: Some(3),
                ..Config::default()
            },
            devices,
        )
        .await
        .unwrap();
        let s = HartIpSession::connect(&server.udp_addr.unwrap().to_string(), false, 60_000)
            .await
            .unwrap();

        // The I/O system at polling address 0; the devices up to scan_to are listed.
        let (_, rc, d) = ask(&s, Address::short(0), 0, &[]).await;
        assert_eq!((rc, u16::from_be_bytes([d[1], d[2]])), (0, 0x26FF));
        assert_eq!(listed(&s).await, 2);
        // The device at 9 answers its polling address and is learnt from it.
        let (_, rc, _) = ask(&s, Address::short(9), 0, &[]).await;
        assert_eq!(rc, 0);
        assert_eq!(listed(&s).await, 3);
        // Read only: a write is answered "access restricted" by the server.
        let (_, rc, _) = ask(&s, Address::long(ids[1]), 18, &[0; 21]).await;
        assert_eq!(rc, 16);
        // Command 11 by tag reaches the device with that tag, whichever it is.
        let tag = hart_proto::types::PackedString::<6>::new(&tags[2]).unwrap();
        let (_, rc, d) = ask(&s, Address::long(UniqueId::from_bytes([0; 5])), 11, &tag.0).await;
        assert_eq!(rc, 0);
        assert_eq!(
            UniqueId::new(
                u16::from_be_bytes([d[1], d[2]]),
                u32::from_be_bytes([0, d[9], d[10], d[11]])
            ),
            ids[2]
        );

        // Burst messages of the device at 2, the master bit alternating.
        let mut masters = vec![];
        while masters.len() < 2 {
            let p = tokio::time::timeout(Duration::from_secs(3), s.next_publish())
                .await
                .expect("a publish message within 3 s")
                .unwrap();
            let f = Frame::parse_pdu(&p).unwrap();
            assert_eq!(f.frame_type(), FrameType::Back);
            assert!(matches!(f.address, Address::Long(a) if a.id == ids[1] && a.burst));
            masters.push(f.address.master());
        }
        assert_ne!(masters[0], masters[1], "{masters:?}");
        s.close().await;
        server.stop();
    });
}

#[test]
fn in_memory_server_transparent_lets_the_device_at_0_answer() {
    run(async {
        let devices = plant().devices().unwrap();
        let id = devices[0].unique_id();
        let server = start_in_memory(
            Config {
                bind: "127.0.0.1:0".parse().unwrap(),
                transparent: true,
                ..Config::default()
            },
            devices,
        )
        .await
        .unwrap();
        let s = HartIpSession::connect(&server.tcp_addr.unwrap().to_string(), true, 60_000)
            .await
            .unwrap();
        let (address, rc, d) = ask(&s, Address::short(0), 0, &[]).await;
        assert_eq!(address.master(), MasterKind::Primary);
        assert_eq!(rc, 0);
        assert_eq!(
            UniqueId::new(
                u16::from_be_bytes([d[1], d[2]]),
                u32::from_be_bytes([0, d[9], d[10], d[11]])
            ),
            id
        );
        s.close().await;
        server.stop();
    });
}
