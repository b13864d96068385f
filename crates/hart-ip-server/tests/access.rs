//! Access control on every path of the HART-IP server (docs/hart-ip.md, "Access
//! control"): each kind of write (a universal write, a common-practice write, a
//! device-specific command, 41 self test, 42 device reset, an unknown command number)
//! by each path (token-passing, command 77, 77 in 77, Direct PDU) is refused on a
//! read-only server, by a read-only PSK identity and on a plain port with read-only
//! rights, and the devices read back unchanged; on read-write sessions (plain, and a
//! read-write identity beside the read-only one) each is let through and audited with
//! the innermost device and command. Subscriptions (533) change only the session and
//! pass for read-only sessions, but not past an allow-list.

mod common;
use common::{frame, run};
use std::time::Duration;

use hart_host::hartip::{direct_pdu_body, direct_pdu_reply, HartIpTransport};
use hart_host::transport::Plant;
use hart_ip::MessageId;
use hart_ip_server::access::{DeviceCommands, Rights};
use hart_ip_server::{start_in_memory, Config, Server};
use hart_proto::frame::{Address, Frame, UniqueId};

const KEY_RW: &str = "00112233445566778899AABBCCDDEEFF";
const KEY_RO: &str = "FFEEDDCCBBAA99887766554433221100";

/// The I/O system's own address (the default identity).
fn gateway() -> Address {
    Address::long(UniqueId::new(0x26FF, 1))
}

/// Command 77's data around the frame `pdu` (card 0, channel 0, 5 preambles, without
/// its check byte).
fn wrap(pdu: &[u8]) -> Vec<u8> {
    let mut d = vec![0, 0, 5];
    d.extend_from_slice(&pdu[..pdu.len() - 1]);
    d
}

/// A token-passing request: the reply's response code and data.
async fn ask(
    t: &mut HartIpTransport,
    address: Address,
    command: u16,
    data: &[u8],
) -> (u8, Vec<u8>) {
    let (st, body) = t
        .exchange(
            MessageId::TokenPassingPdu,
            &frame(address, command, data),
            Duration::from_secs(5),
        )
        .await
        .unwrap();
    assert_eq!(st, 0, "HART-IP status");
    let f = Frame::parse_pdu(&body).unwrap();
    (f.response_code.unwrap(), f.data.to_vec())
}

/// A Direct PDU of one entry: its response code.
async fn direct(t: &mut HartIpTransport, command: u16, data: &[u8]) -> u8 {
    let (st, body) = t
        .exchange(
            MessageId::DirectPdu,
            &direct_pdu_body(&[(command, data)]),
            Duration::from_secs(5),
        )
        .await
        .unwrap();
    assert_eq!(st, 0, "HART-IP status");
    let entries = direct_pdu_reply(&body);
    assert_eq!(entries.len(), 1, "{body:02X?}");
    entries[0].1
}

/// The two devices: the pressure transmitter (polling address 1) and the valve (2),
/// by unique ID.
async fn devices(t: &mut HartIpTransport) -> (Address, Address) {
    let mut ids = vec![];
    for poll in [1, 2] {
        let (rc, id) = ask(t, Address::short(poll), 0, &[]).await;
        assert_eq!(rc, 0);
        ids.push(Address::long(UniqueId::new(
            u16::from_be_bytes([id[1], id[2]]),
            u32::from_be_bytes([0, id[9], id[10], id[11]]),
        )));
    }
    (ids[0], ids[1])
}

/// What the writes would change: final assembly number (16), damping (15), the
/// valve's setpoint (128), the configuration change counter (0).
async fn state(t: &mut HartIpTransport, pt: Address, valve: Address) -> Vec<Vec<u8>> {
    let mut out = vec![];
    for (a, c) in [(pt, 16), (pt, 15), (valve, 128), (pt, 0), (valve, 0)] {
        let (rc, data) = ask(t, a, c, &[]).await;
        assert_eq!(rc, 0, "read {c}");
        out.push(data);
    }
    out
}

/// The writes tried, as (path, device address, command, the request frame or Direct
/// PDU entry). `Direct` entries go to the I/O system.
enum Path {
    TokenPassing,
    Direct,
}

fn attempts(pt: Address, valve: Address) -> Vec<(&'static str, Path, u16, Vec<u8>)> {
    let writes: Vec<(Address, u16, Vec<u8>)> = vec![
        (pt, 19, vec![0x12, 0x34, 0x56]),
        (pt, 34, 7.5f32.to_be_bytes().to_vec()),
        (valve, 129, vec![0x41, 0x48, 0, 0]),
        (pt, 41, vec![]),
        (pt, 42, vec![]),
        (pt, 4000, vec![]),
    ];
    let mut out = vec![];
    for (a, c, d) in writes {
        let direct = frame(a, c, &d);
        let in77 = frame(gateway(), 77, &wrap(&direct));
        let in77in77 = frame(gateway(), 77, &wrap(&in77));
        out.push(("token-passing", Path::TokenPassing, c, direct));
        out.push(("command 77", Path::TokenPassing, c, in77.clone()));
        out.push(("77 in 77", Path::TokenPassing, c, in77in77));
        out.push(("direct PDU, 77", Path::Direct, c, wrap(&frame(a, c, &d))));
    }
    out
}

/// Sends one attempt: the response code the session sees.
async fn attempt(t: &mut HartIpTransport, path: &Path, bytes: &[u8]) -> u8 {
    match path {
        Path::TokenPassing => {
            let (st, body) = t
                .exchange(MessageId::TokenPassingPdu, bytes, Duration::from_secs(5))
                .await
                .unwrap();
            assert_eq!(st, 0);
            Frame::parse_pdu(&body).unwrap().response_code.unwrap()
        }
        Path::Direct => direct(t, 77, bytes).await,
    }
}

async fn server(config: Config) -> Server {
    let devices = Plant::from_profiles(&["pressure".into(), "valve".into()])
        .unwrap()
        .devices()
        .unwrap();
    let server = start_in_memory(
        Config {
            bind: "127.0.0.1:0".parse().unwrap(),
            scan_to: Some(2),
            // The valve's command 128 only reads its setpoint.
            device_commands: DeviceCommands::parse(
                "[[device]]\ntype = \"26F3\"\nname = \"valve\"\nreads = \"128\"\n",
            )
            .unwrap(),
            ..config
        },
        devices,
    )
    .await
    .unwrap();
    server.ready().await;
    server
}

async fn connect(addr: std::net::SocketAddr, psk: Option<(&str, &str)>) -> HartIpTransport {
    let psk = psk.map(|(id, key)| hart_ip_tls::Psk::parse(&format!("{id}:{key}")).unwrap());
    HartIpTransport::connect_with(&addr.to_string(), false, psk, 60_000)
        .await
        .unwrap()
}

/// Every attempt refused with response code 16, and the devices unchanged.
async fn all_refused(t: &mut HartIpTransport, who: &str) {
    let (pt, valve) = devices(t).await;
    let before = state(t, pt, valve).await;
    for (path, how, command, bytes) in attempts(pt, valve) {
        assert_eq!(
            attempt(t, &how, &bytes).await,
            16,
            "{who}: command {command} by {path} must be refused"
        );
    }
    assert_eq!(state(t, pt, valve).await, before, "{who}: nothing changed");
    // Reads pass, at every depth, and the declared device-specific read too.
    assert_eq!(ask(t, valve, 128, &[]).await.0, 0);
    let read77 = frame(gateway(), 77, &wrap(&frame(pt, 1, &[])));
    assert_eq!(attempt(t, &Path::TokenPassing, &read77).await, 0, "{who}");
    assert_eq!(direct(t, 0, &[]).await, 0, "{who}: direct PDU command 0");
    // Subscriptions change only the session.
    assert_eq!(
        ask(
            t,
            Address::long(UniqueId::BROADCAST),
            533,
            &[0, 0, 0, 0, 0, 0, 1]
        )
        .await
        .0,
        0,
        "{who}: subscribe"
    );
}

#[test]
fn read_only_sessions_cannot_write_on_any_path() {
    run(async {
        // A read-only server.
        let s = server(Config {
            read_only: true,
            ..Config::default()
        })
        .await;
        let mut t = connect(s.udp_addr.unwrap(), None).await;
        all_refused(&mut t, "read-only server").await;
        t.close().await;
        s.stop();

        // A secure server: a read-only identity, the plain port read-only, and a
        // read-write identity beside them.
        let keys =
            hart_ip_tls::PskTable::parse(&format!("writer:{KEY_RW}\nviewer:{KEY_RO}:read-only\n"))
                .unwrap();
        let s = server(Config {
            psk: Some(std::sync::Arc::new(keys)),
            plain: Some("127.0.0.1:0".parse().unwrap()),
            plain_rights: Rights::ReadOnly,
            ..Config::default()
        })
        .await;
        let mut t = connect(s.udp_addr.unwrap(), Some(("viewer", KEY_RO))).await;
        all_refused(&mut t, "read-only identity").await;
        t.close().await;
        let mut t = connect(s.plain_udp_addr.unwrap(), None).await;
        all_refused(&mut t, "plain port, read-only").await;
        t.close().await;
        let mut t = connect(s.udp_addr.unwrap(), Some(("writer", KEY_RW))).await;
        let (pt, _) = devices(&mut t).await;
        assert_eq!(ask(&mut t, pt, 34, &2.0f32.to_be_bytes()).await.0, 0);
        t.close().await;
        s.stop();
    });
}

#[test]
fn writes_are_let_through_and_audited_on_read_write_sessions() {
    run(async {
        let audit =
            std::env::temp_dir().join(format!("hartkit-access-audit-{}.jsonl", std::process::id()));
        let _ = std::fs::remove_file(&audit);
        let s = server(Config {
            audit_file: Some(audit.clone()),
            ..Config::default()
        })
        .await;
        let mut t = connect(s.udp_addr.unwrap(), None).await;
        let (pt, valve) = devices(&mut t).await;
        let mut expected = vec![];
        for (path, how, command, bytes) in attempts(pt, valve) {
            let rc = attempt(&mut t, &how, &bytes).await;
            assert_ne!(rc, 16, "command {command} by {path} let through");
            let depth = match path {
                "command 77" | "direct PDU, 77" => 1,
                "77 in 77" => 2,
                _ => 0,
            };
            expected.push((command, depth, path));
        }
        // The writes landed (the direct ones; 77 in 77 reaches a device that is no
        // gateway and answers "not implemented").
        assert_eq!(ask(&mut t, pt, 16, &[]).await.1, vec![0x12, 0x34, 0x56]);
        t.close().await;
        s.stop();
        let log = std::fs::read_to_string(&audit).unwrap();
        let all: Vec<serde_json::Value> = log
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        // Each write: its record before it went, and one with its outcome (same id).
        let lines: Vec<&serde_json::Value> =
            all.iter().filter(|l| l["outcome"].is_null()).collect();
        assert_eq!(lines.len(), expected.len(), "{log}");
        assert_eq!(all.len(), 2 * expected.len(), "{log}");
        for l in &lines {
            assert!(
                all.iter()
                    .any(|o| o["id"] == l["id"] && o["outcome"].is_string()),
                "{log}"
            );
        }
        for (line, (command, depth, path)) in lines.iter().zip(expected) {
            assert_eq!(line["command"], command, "{path}: {line}");
            assert_eq!(line["front_end"], "hart-ip");
            let device = line["device"].as_str().unwrap();
            let want = if command == 129 { "26F3" } else { "26F1" };
            assert!(device.contains(want), "{path}: {line}");
            let via = line["via"].as_str().unwrap();
            match depth {
                0 => assert_eq!(via, "token-passing", "{line}"),
                1 => assert!(via.ends_with("command 77"), "{line}"),
                _ => assert!(via.contains("2 levels"), "{line}"),
            }
            assert!(line["peer"].as_str().unwrap().starts_with("127.0.0.1:"));
        }
        let _ = std::fs::remove_file(&audit);
    });
}

#[test]
fn the_allow_list_holds_at_every_depth_and_for_subscriptions() {
    run(async {
        let s = server(Config {
            allow_commands: Some("0-18,48,77".parse().unwrap()),
            ..Config::default()
        })
        .await;
        let mut t = connect(s.udp_addr.unwrap(), None).await;
        let (pt, _) = devices(&mut t).await;
        let before = ask(&mut t, pt, 16, &[]).await.1;
        let write19 = frame(pt, 19, &[0, 0, 9]);
        let in77 = frame(gateway(), 77, &wrap(&write19));
        assert_eq!(attempt(&mut t, &Path::TokenPassing, &in77).await, 16);
        assert_eq!(direct(&mut t, 77, &wrap(&write19)).await, 16);
        assert_eq!(direct(&mut t, 19, &[0, 0, 9]).await, 16);
        assert_eq!(
            ask(
                &mut t,
                Address::long(UniqueId::BROADCAST),
                533,
                &[0, 0, 0, 0, 0, 0, 1]
            )
            .await
            .0,
            16
        );
        assert_eq!(ask(&mut t, pt, 16, &[]).await.1, before);
        t.close().await;
        s.stop();
    });
}

/// A Direct PDU of `n` command 0 entries: the HART-IP status and the body.
async fn direct_zeros(t: &mut HartIpTransport, n: usize) -> (u8, Vec<u8>) {
    let entries: Vec<(u16, &[u8])> = vec![(0u16, &[][..]); n];
    t.exchange(
        MessageId::DirectPdu,
        &direct_pdu_body(&entries),
        Duration::from_secs(5),
    )
    .await
    .unwrap()
}

#[test]
fn direct_pdus_are_capped() {
    run(async {
        let s = server(Config::default()).await;
        let mut t = connect(s.udp_addr.unwrap(), None).await;
        let max = hart_ip_server::MAX_DIRECT_ENTRIES;
        let (st, body) = direct_zeros(&mut t, max).await;
        assert_eq!(st, 0);
        assert_eq!(direct_pdu_reply(&body).len(), max);
        let (st, body) = direct_zeros(&mut t, max + 1).await;
        assert_eq!(st, hart_ip::status::INVALID_SELECTION);
        assert!(body.is_empty());
        t.close().await;
        s.stop();
    });
}
