//! Golden tests on the public over-the-air captures (whad project, MIT; see
//! `tests/captures/README.md`): every frame parses, every data-link MIC verifies once
//! its key is known, every network PDU decrypts once its key is known, every command
//! decodes by its typed layout, and everything re-encodes byte for byte.

use hart_wireless::capture;
use hart_wireless::commands;
use hart_wireless::decoder::decode_capture;
use hart_wireless::dll::DlBody;
use hart_wireless::{crypto, Dlpdu, Tpdu};

const JOIN_KEY: &str = "41424344414243444142434441424344";

struct Expect {
    file: &'static str,
    frames: usize,
    advertise: usize,
    ack: usize,
    keep_alive: usize,
    data: usize,
    mic_well_known: usize,
    mic_network: usize,
    mic_unchecked: usize,
    decrypted: usize,
    commands: usize,
    vendor_payloads: usize,
}

fn check(e: &Expect) {
    let path = format!("{}/tests/captures/{}", env!("CARGO_MANIFEST_DIR"), e.file);
    let bytes = std::fs::read(&path).unwrap();
    let packets = capture::read(&bytes).unwrap();
    assert_eq!(packets.len(), e.frames, "{}", e.file);
    let jk = crypto::parse_key(JOIN_KEY).unwrap();
    let (reports, stats) = decode_capture(&bytes, &[jk], &[]).unwrap();
    let by = |t: &str| stats.by_type.get(t).copied().unwrap_or(0);
    assert_eq!(by("malformed"), 0, "{}", e.file);
    assert_eq!(
        (by("advertise"), by("ack"), by("keep-alive"), by("data")),
        (e.advertise, e.ack, e.keep_alive, e.data),
        "{}",
        e.file
    );
    let mic_by = |prefix: &str| -> usize {
        stats
            .mic_ok
            .iter()
            .filter(|(k, _)| k.starts_with(prefix))
            .map(|(_, n)| n)
            .sum()
    };
    assert_eq!(mic_by("well-known"), e.mic_well_known, "{}", e.file);
    assert_eq!(mic_by("network"), e.mic_network, "{}", e.file);
    assert_eq!(stats.mic_failed, 0, "{}: a MIC failed", e.file);
    assert_eq!(stats.mic_unchecked, e.mic_unchecked, "{}", e.file);
    assert_eq!(stats.decrypted, e.decrypted, "{}", e.file);
    assert_eq!(stats.vendor_payloads, e.vendor_payloads, "{}", e.file);
    assert_eq!(stats.commands_typed, e.commands, "{}", e.file);
    assert_eq!(
        (stats.commands_bad, stats.commands_untyped),
        (0, 0),
        "{}",
        e.file
    );

    let mut network_known = false;
    for (p, r) in packets.iter().zip(&reports) {
        assert_eq!(p.fcs_ok, Some(true), "{} frame {}", e.file, r.index);
        assert!(p.channel.is_some());
        let d = r.dl.as_ref().unwrap();
        // Byte for byte from the decoded fields.
        assert_eq!(d.encode(), p.frame, "{} frame {}", e.file, r.index);
        assert_eq!(Dlpdu::parse(&d.encode()).unwrap(), *d);
        // Every MIC verifies once its key is known: the well-known key always, the
        // network key after the first 961 of the capture.
        if !d.network_key || network_known {
            assert_eq!(r.dl_mic_ok, Some(true), "{} frame {}", e.file, r.index);
        }
        if let Some(nl) = &r.nl {
            if let Some(plain) = &nl.plain {
                if let Some(t) = &nl.tpdu {
                    assert_eq!(&t.encode(), plain, "{} frame {}", e.file, r.index);
                    for c in &t.commands {
                        if c.number == 961 {
                            network_known = true;
                        }
                        let typed = commands::decode(c.number, t.response, &c.data)
                            .unwrap_or_else(|| panic!("command {} untyped", c.number))
                            .unwrap();
                        if let Some(again) = commands::encode(&typed) {
                            assert_eq!(
                                again, c.data,
                                "{} frame {} command {}",
                                e.file, r.index, c.number
                            );
                        } else {
                            assert!(commands::is_vendor(c.number));
                        }
                    }
                    assert_eq!(Tpdu::parse(plain).unwrap(), *t);
                }
            }
            if let DlBody::Data(n) = &d.body {
                assert_eq!(*n, nl.npdu);
            }
        }
    }
}

#[test]
fn channel_13_whole() {
    check(&Expect {
        file: "channel_13.pcap",
        frames: 993,
        advertise: 946,
        ack: 23,
        keep_alive: 0,
        data: 24,
        mic_well_known: 958,
        mic_network: 34,
        // Frame 434 (a broadcast before the join) is under the network key, not yet known.
        mic_unchecked: 1,
        // All but that broadcast, whose key (a broadcast session) is never sent.
        decrypted: 23,
        commands: 93,
        vendor_payloads: 0,
    });
}

#[test]
fn channel_11_two_nodes_whole() {
    check(&Expect {
        file: "channel_11_2nodes.pcap",
        frames: 2774,
        advertise: 2602,
        ack: 84,
        keep_alive: 9,
        data: 79,
        mic_well_known: 2628,
        mic_network: 146,
        mic_unchecked: 0,
        decrypted: 79,
        commands: 208,
        vendor_payloads: 14,
    });
}

#[test]
fn channel_11_pcapng_whole() {
    // No join in this capture: its network and session keys are never sent, so the
    // frames under the network key stay unchecked and the network PDUs sealed.
    check(&Expect {
        file: "channel_11.pcapng",
        frames: 446,
        advertise: 434,
        ack: 6,
        keep_alive: 2,
        data: 4,
        mic_well_known: 438,
        mic_network: 0,
        mic_unchecked: 8,
        decrypted: 0,
        commands: 0,
        vendor_payloads: 0,
    });
}

#[test]
fn the_join_response_carries_the_keys() {
    // channel_13 frame 509: the manager's join response (963, 961, 962) under the join key.
    let bytes = std::fs::read(format!(
        "{}/tests/captures/channel_13.pcap",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    let jk = crypto::parse_key(JOIN_KEY).unwrap();
    let (reports, _) = decode_capture(&bytes, &[jk], &[]).unwrap();
    let r = &reports[509];
    let nl = r.nl.as_ref().unwrap();
    assert_eq!(nl.npdu.security.name(), "join");
    let t = nl.tpdu.as_ref().unwrap();
    let nums: Vec<u16> = t.commands.iter().map(|c| c.number).collect();
    assert_eq!(nums, [963, 961, 962]);
    let Some(Ok(commands::Typed::Request(commands::Request::WriteNetworkKey(k)))) =
        commands::decode(961, false, &t.commands[1].data)
    else {
        panic!("961 not typed")
    };
    assert_eq!(capture::hex(&k.key.0), "5ac873bfa618d4ce181d6f5faeabfb3b");
    let Some(Ok(commands::Typed::Request(commands::Request::WriteNickname(n)))) =
        commands::decode(962, false, &t.commands[2].data)
    else {
        panic!("962 not typed")
    };
    assert_eq!(n.nickname, 2);
    let j = r.to_json();
    assert_eq!(j["type"], "data");
    assert_eq!(j["src"], "0001");
    assert_eq!(j["dst"], "00170d000032d368");
    assert_eq!(j["nl"]["security"], "join");
    assert_eq!(j["nl"]["decrypted"], true);
    assert_eq!(j["nl"]["commands"][1]["command"], 961);
}
