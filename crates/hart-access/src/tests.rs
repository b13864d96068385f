use super::*;
use hart_proto::frame::{FrameSpec, UniqueId};

const VALVE: UniqueId = UniqueId {
    expanded_device_type: 0x26F1,
    device_id: 0x010002,
};

fn pdu(address: Address, command: u16, data: &[u8]) -> Vec<u8> {
    hart_proto::frame::FrameBuf::encode(&FrameSpec::request(address, command, data))
        .unwrap()
        .as_slice()
        .to_vec()
}

/// Command 77's data around `inner` (card 0, channel 0, 5 preambles, no check byte).
fn wrap(inner: &[u8]) -> Vec<u8> {
    let mut d = vec![0, 0, 5];
    d.extend_from_slice(&inner[..inner.len() - 1]);
    d
}

/// `command` to the valve wrapped in `levels` of command 77 (to the gateway at polling
/// address 0, whose sub-device is the next gateway).
fn nested(levels: usize, command: u16, data: &[u8]) -> Vec<u8> {
    let mut p = pdu(Address::long(VALVE), command, data);
    for _ in 0..levels {
        p = pdu(Address::short(0), 77, &wrap(&p));
    }
    p
}

fn check(policy: &Policy, rights: Rights, p: &[u8]) -> Result<Allowed, Refusal> {
    let f = Frame::parse_pdu(p).unwrap();
    policy.check(rights, &f, None)
}

fn declared() -> Policy {
    Policy {
        device_commands: DeviceCommands::parse(
            "[[device]]\ntype = \"26F1\"\nname = \"valve\"\nreads = \"128, 130-131\"\n",
        )
        .unwrap(),
        ..Policy::default()
    }
}

#[test]
fn read_only_sessions_send_only_known_reads_at_any_depth() {
    let p = declared();
    // (command, data, reads?)
    let cases: &[(u16, &[u8], bool)] = &[
        (0, &[], true),
        (3, &[], true),
        (48, &[], true),
        (17, &[0; 24], false),
        (19, &[0, 0, 1], false),
        (35, &[0; 9], false),
        (41, &[], false),
        (42, &[], false),
        (128, &[], true), // declared a read for 26F1
        (129, &[0x41, 0x48, 0, 0], false),
        (132, &[], false), // device-specific, not declared
        (39, &[0], false),
        (89, &[], false),
        (4096, &[], false),
    ];
    for levels in 0..=3 {
        for &(command, data, reads) in cases {
            let frame = nested(levels, command, data);
            let ro = check(&p, Rights::ReadOnly, &frame);
            let rw = check(&p, Rights::ReadWrite, &frame);
            if reads {
                assert_eq!(ro, Ok(Allowed::Read), "{command} at {levels}");
                assert_eq!(rw, Ok(Allowed::Read), "{command} at {levels}");
            } else {
                match ro {
                    Err(Refusal::ReadOnly {
                        command: c, depth, ..
                    }) => {
                        assert_eq!((c, depth), (command, levels))
                    }
                    other => panic!("{command} at {levels}: {other:?}"),
                }
                assert_eq!(
                    rw,
                    Ok(Allowed::Write(Target {
                        device: Address::long(VALVE).to_string(),
                        command,
                        depth: levels,
                    })),
                    "{command} at {levels}"
                );
            }
        }
    }
}

#[test]
fn declared_reads_belong_to_their_device_type() {
    let p = declared();
    let other = UniqueId::new(0x26F2, 1);
    let f = pdu(Address::long(other), 128, &[]);
    assert!(check(&p, Rights::ReadOnly, &f).is_err());
    // A short address: the type the caller knows decides.
    let f = pdu(Address::short(1), 128, &[]);
    let frame = Frame::parse_pdu(&f).unwrap();
    assert!(p.check(Rights::ReadOnly, &frame, None).is_err());
    assert_eq!(
        p.check(Rights::ReadOnly, &frame, Some(0x26F1)),
        Ok(Allowed::Read)
    );
    assert!(p.check(Rights::ReadOnly, &frame, Some(0x1234)).is_err());
    // Known writes cannot be declared reads; bad types are named.
    for bad in [
        "[[device]]\ntype = \"26F1\"\nreads = \"17\"\n",
        "[[device]]\ntype = \"26F1\"\nreads = \"77\"\n",
        "[[device]]\ntype = \"26F1\"\nreads = \"100-130\"\n",
        "[[device]]\ntype = \"X1\"\nreads = \"128\"\n",
        "[[device]]\ntype = \"FFFF\"\nreads = \"128\"\n",
        "[[device]]\ntype = \"26F1\"\nreads = \"130-128\"\n",
        "[[device]]\ntype = \"26F1\"\n",
        "[[device]]\ntype = \"26F1\"\nreads = \"128\"\ncolour = 1\n",
    ] {
        assert!(DeviceCommands::parse(bad).is_err(), "{bad}");
    }
}

#[test]
fn the_allow_list_applies_at_every_level() {
    let p = Policy {
        allow: Some("0-18,48,77".parse().unwrap()),
        ..Policy::default()
    };
    assert_eq!(
        check(&p, Rights::ReadWrite, &nested(2, 19, &[0, 0, 1])),
        Err(Refusal::NotListed {
            command: 19,
            depth: 2
        })
    );
    assert!(matches!(
        check(&p, Rights::ReadWrite, &nested(2, 17, &[0; 24])),
        Ok(Allowed::Write(_))
    ));
    let no77 = Policy {
        allow: Some("0-22".parse().unwrap()),
        ..Policy::default()
    };
    assert_eq!(
        check(&no77, Rights::ReadWrite, &nested(1, 1, &[])),
        Err(Refusal::NotListed {
            command: 77,
            depth: 0
        })
    );
}

#[test]
fn nesting_deeper_than_the_limit_is_refused_whatever_the_rights() {
    let p = Policy::default();
    assert!(check(&p, Rights::ReadOnly, &nested(MAX_DEPTH, 1, &[])).is_ok());
    for rights in [Rights::ReadOnly, Rights::ReadWrite] {
        assert_eq!(
            check(&p, rights, &nested(MAX_DEPTH + 1, 1, &[])),
            Err(Refusal::TooDeep)
        );
    }
}

#[test]
fn a_77_that_wraps_no_frame_is_not_a_read() {
    let p = Policy::default();
    let f = pdu(Address::short(0), 77, &[0, 0, 5, 0x02]);
    assert!(matches!(
        check(&p, Rights::ReadOnly, &f),
        Err(Refusal::ReadOnly { command: 77, .. })
    ));
    // Command 78 carries commands whose layout the project does not check.
    let f = pdu(Address::short(0), 78, &[1, 0, 1, 0]);
    assert!(check(&p, Rights::ReadOnly, &f).is_err());
}

#[test]
fn refusals_explain() {
    let p = Policy::default();
    let e = check(&p, Rights::ReadOnly, &nested(2, 17, &[0; 24])).unwrap_err();
    assert_eq!(
        e.to_string(),
        "command 17 (wrapped in 2 levels of command 77) changes the device, and the session is read-only"
    );
    let e = check(&p, Rights::ReadOnly, &nested(0, 200, &[])).unwrap_err();
    assert!(e.to_string().contains("--device-commands"), "{e}");
}

#[test]
fn rights_and_networks() {
    assert_eq!(Rights::ReadWrite.and(Rights::ReadOnly), Rights::ReadOnly);
    assert_eq!(Rights::ReadWrite.and(Rights::ReadWrite), Rights::ReadWrite);
    assert_eq!("ro".parse::<Rights>(), Ok(Rights::ReadOnly));
    assert!("all".parse::<Rights>().is_err());
    let n = NetList::parse(&["10.0.0.0/24", "192.168.1.7", "fd00::/8"]).unwrap();
    for ok in ["10.0.0.9", "192.168.1.7", "fd00::1", "::ffff:10.0.0.200"] {
        assert!(n.contains(ok.parse().unwrap()), "{ok}");
    }
    for no in ["10.0.1.1", "192.168.1.8", "127.0.0.1", "::1"] {
        assert!(!n.contains(no.parse().unwrap()), "{no}");
    }
    let lo = NetList::loopback();
    assert!(lo.contains("127.0.0.1".parse().unwrap()));
    assert!(lo.contains("::1".parse().unwrap()));
    assert!(!lo.contains("10.0.0.1".parse().unwrap()));
    assert!(NetList::parse(&["10.0.0.0/33"]).is_err());
    assert!(NetList::parse(&["plant"]).is_err());
}

#[test]
fn allow_lists() {
    let a: CommandAllowList = "0-22, 48,74-84".parse().unwrap();
    for c in [0, 13, 22, 48, 74, 84] {
        assert!(a.allows(c), "{c}");
    }
    for c in [23, 47, 49, 85, 533] {
        assert!(!a.allows(c), "{c}");
    }
    for bad in ["", "x", "5-2", "0-70000"] {
        assert!(bad.parse::<CommandAllowList>().is_err(), "{bad}");
    }
    assert!("1,,".parse::<CommandAllowList>().is_ok());
}

proptest::proptest! {
    /// Any bytes as a request: the check answers without panicking, and a read-only
    /// session is let through only with a command the project knows reads.
    #[test]
    fn any_request_is_checked(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..300)) {
        let p = declared();
        if let Ok(f) = Frame::parse_pdu(&bytes) {
            if let Ok(Allowed::Read) = p.check(Rights::ReadOnly, &f, None) {
                proptest::prop_assert!(f.command != 77 || f.data.len() >= 3);
            }
            let _ = p.check(Rights::ReadWrite, &f, Some(0x26F1));
        }
        let mut buf = vec![];
        let _ = wrapped(&bytes, &mut buf);
    }

    /// Wrapping never turns a refused request into a read.
    #[test]
    fn wrapping_keeps_the_verdict(command in 0u16..600, levels in 0usize..=MAX_DEPTH) {
        // Command byte 31 announces an extended number: not a command of its own.
        proptest::prop_assume!(command != 31);
        let p = declared();
        let direct = check(&p, Rights::ReadOnly, &nested(0, command, &[])).is_ok();
        let wrapped = check(&p, Rights::ReadOnly, &nested(levels, command, &[])).is_ok();
        proptest::prop_assert_eq!(direct, wrapped);
    }
}
