//! Target strings (`--port TARGET`): what each one opens, and the errors for the ones
//! that make no sense. Nothing is opened here: `target::parse` only reads the string.

use std::path::PathBuf;
use std::time::Duration;

use hart_host::target::{open, parse, SimMedium, Target};
use hart_host::transport::{Rts, SerialOptions};

fn serial(target: &str) -> SerialOptions {
    match parse(target) {
        Ok(Target::Serial(o)) => o,
        other => panic!("{target}: {other:?}"),
    }
}

fn error(target: &str) -> String {
    match parse(target) {
        Err(e) => e,
        Ok(t) => panic!("{target} should be refused, got {t:?}"),
    }
}

#[test]
fn a_bare_path_is_a_hart_modem_at_1200_bit_s_without_rts_keying() {
    assert_eq!(
        serial("/dev/ttyUSB0"),
        SerialOptions {
            path: PathBuf::from("/dev/ttyUSB0"),
            baud: 1200,
            rts: Rts::None,
            rts_pre: Duration::ZERO,
            rts_post: Duration::ZERO,
            rs485: false,
            carrier_detect: false,
        }
    );
    assert_eq!(serial("serial:/dev/ttyUSB0"), serial("/dev/ttyUSB0"));
}

#[test]
fn serial_options_set_rate_rts_keying_and_its_delays() {
    let o = serial("serial:/dev/ttyS1?baud=2400&rts=high-tx&rts_pre_ms=5&rts_post_ms=2");
    assert_eq!(o.path, PathBuf::from("/dev/ttyS1"));
    assert_eq!(o.baud, 2400);
    assert_eq!(o.rts, Rts::HighTx);
    assert_eq!(o.rts_pre, Duration::from_millis(5));
    assert_eq!(o.rts_post, Duration::from_millis(2));
    assert!(!o.rs485);
    assert_eq!(serial("/dev/ttyS1?rts=low-tx").rts, Rts::LowTx);
    assert_eq!(serial("/dev/ttyS1?rts=none").rts, Rts::None);
}

#[test]
fn carrier_dcd_watches_the_modems_dcd_line() {
    assert!(serial("serial:/dev/ttyUSB0?carrier=dcd").carrier_detect);
    assert!(serial("/dev/ttyUSB0?rts=high-tx&carrier=dcd").carrier_detect);
    assert!(!serial("/dev/ttyUSB0?carrier=none").carrier_detect);
    let e = error("/dev/ttyUSB0?carrier=1");
    assert!(e.contains("carrier=1") && e.contains("dcd"), "{e}");
}

#[test]
fn rs485_defaults_to_19200_bit_s_and_filters_its_own_echo() {
    let o = serial("rs485:/dev/ttyUSB1");
    assert!(o.rs485);
    assert_eq!(o.baud, 19200);
    let o = serial("rs485:/dev/ttyUSB1?baud=9600&rts=high-tx&rts_post_ms=1");
    assert_eq!((o.baud, o.rts), (9600, Rts::HighTx));
    assert_eq!(o.rts_post, Duration::from_millis(1));
}

#[test]
fn rs485_has_no_carrier_detect() {
    let e = error("rs485:/dev/ttyUSB1?carrier=dcd");
    assert!(e.contains("\"carrier\"") && e.contains("RS-485"), "{e}");
}

#[test]
fn sim_targets_are_the_demo_plant_or_a_plant_file_in_real_or_virtual_time() {
    assert_eq!(
        parse("sim").unwrap(),
        Target::Sim {
            plant: None,
            virtual_time: false,
            medium: SimMedium::Digital,
        }
    );
    assert_eq!(
        parse("sim?virtual").unwrap(),
        Target::Sim {
            plant: None,
            virtual_time: true,
            medium: SimMedium::Digital,
        }
    );
    assert_eq!(
        parse("sim:plants/loop.toml?virtual=1").unwrap(),
        Target::Sim {
            plant: Some(PathBuf::from("plants/loop.toml")),
            virtual_time: true,
            medium: SimMedium::Digital,
        }
    );
    assert_eq!(
        parse("sim:loop.toml?virtual=0").unwrap(),
        Target::Sim {
            plant: Some(PathBuf::from("loop.toml")),
            virtual_time: false,
            medium: SimMedium::Digital,
        }
    );
    assert_eq!(
        parse("sim?virtual&medium=analog&cable_m=1500").unwrap(),
        Target::Sim {
            plant: None,
            virtual_time: true,
            medium: SimMedium::Analog { cable_m: 1500.0 },
        }
    );
    for (bad, needle) in [
        ("sim?medium=copper", "expected digital or analog"),
        ("sim?medium=analog&cable_m=-1", "cable_m=-1"),
        ("sim?cable_m=100", "needs medium=analog"),
    ] {
        let e = parse(bad).unwrap_err();
        assert!(e.contains(needle), "{bad}: {e}");
    }
}

#[test]
fn hart_ip_targets_default_to_port_5094() {
    let ip = |t: &str| match parse(t) {
        Ok(Target::HartIp { address, tcp, .. }) => (address, tcp),
        other => panic!("{t}: {other:?}"),
    };
    assert_eq!(ip("udp://127.0.0.1"), ("127.0.0.1:5094".into(), false));
    assert_eq!(ip("tcp://127.0.0.1:5094"), ("127.0.0.1:5094".into(), true));
    assert_eq!(ip("udp://gw.plant:20004"), ("gw.plant:20004".into(), false));
    assert_eq!(ip("tcp://[::1]"), ("[::1]:5094".into(), true));
    assert_eq!(ip("tcp://[::1]:6000"), ("[::1]:6000".into(), true));
    assert_eq!(ip("udp://fe80::1"), ("[fe80::1]:5094".into(), false));
}

#[test]
fn hart_ip_errors_name_the_bad_part() {
    assert!(error("udp://10.0.0.1:http").contains("port \"http\""));
    assert!(error("udp://10.0.0.1:0").contains("1-65535"));
    assert!(error("tcp://").contains("no host"));
    assert!(error("tcp://10.0.0.1?baud=1200").contains("takes no options"));
    assert!(error("http://10.0.0.1").contains("unknown scheme"));
}

#[test]
fn hart_ip_needs_the_async_opener() {
    let e = open("udp://127.0.0.1").err().unwrap();
    assert!(e.contains("open_async"), "{e}");
}

#[test]
fn bad_serial_options_say_what_is_expected() {
    let e = error("/dev/ttyUSB0?baud=fast");
    assert!(e.contains("baud=fast") && e.contains("whole number"), "{e}");
    let e = error("/dev/ttyUSB0?baud=1000");
    assert!(e.contains("baud=1000") && e.contains("1200"), "{e}");
    let e = error("/dev/ttyUSB0?rts=on");
    assert!(e.contains("high-tx, low-tx or none"), "{e}");
    let e = error("/dev/ttyUSB0?rts_pre_ms=-1");
    assert!(e.contains("rts_pre_ms=-1"), "{e}");
    let e = error("/dev/ttyUSB0?parity=even");
    assert!(
        e.contains("unknown option \"parity\"") && e.contains("baud, rts"),
        "{e}"
    );
    let e = error("/dev/ttyUSB0?baud=1200&baud=2400");
    assert!(e.contains("given twice"), "{e}");
    assert!(error("serial:").contains("no device path"));
    assert!(error("rs485:?baud=19200").contains("no device path"));
}

#[test]
fn options_belong_to_their_kind_of_target() {
    let e = error("sim?baud=1200");
    assert!(e.contains("\"baud\"") && e.contains("virtual"), "{e}");
    assert!(error("/dev/ttyUSB0?virtual").contains("\"virtual\""));
    assert!(error("sim?virtual=maybe").contains("virtual=maybe"));
    assert!(error("sim:").contains("no plant file"));
}

#[test]
fn a_port_that_cannot_be_opened_says_what_to_check() {
    let e = open("/dev/hartkit-no-such-port").err().unwrap();
    assert!(
        e.contains("/dev/hartkit-no-such-port") && e.contains("permission"),
        "{e}"
    );
}

/// `PROFILE xN` makes N devices of a profile, at the next polling addresses.
#[test]
fn plants_repeat_a_profile_with_xn() {
    use hart_host::transport::Plant;
    let p = Plant::from_profiles(&["pressure".into(), "x15".into(), "valve".into()]).unwrap();
    assert_eq!(p.device.len(), 16);
    assert!(p.device[..15].iter().all(|d| d.profile == "pressure"));
    assert_eq!(
        (p.device[15].profile.as_str(), p.device[15].poll),
        ("valve", 16)
    );
    for bad in [&["x3"][..], &["pressure", "x0"], &["pressure", "x64"]] {
        let given: Vec<String> = bad.iter().map(|s| s.to_string()).collect();
        assert!(Plant::from_profiles(&given).is_err(), "{bad:?}");
    }
    let many: Vec<String> = vec![
        "pressure".into(),
        "x40".into(),
        "valve".into(),
        "x30".into(),
    ];
    assert!(Plant::from_profiles(&many)
        .unwrap_err()
        .contains("at most 63"));
}
