//! Serial settings on socat pseudo-terminal pairs (an outside program joining two
//! pseudo-terminals as a null-modem cable): each framing opens and carries bytes both
//! ways, marked input decodes a real 0xFF, and a line whose other side vanishes is
//! reported as hung up instead of silent.

use std::time::{Duration, Instant};

use hart_serial::{ErrorReader, Line, OpenOptions, Parity, Port};
use hart_testkit::pty_pair;

fn marked() -> OpenOptions {
    OpenOptions {
        mark_errors: true,
        ..OpenOptions::default()
    }
}

/// Reads from `port` until `n` characters came (or 5 s passed).
fn read_chars(port: &Port, n: usize) -> Vec<(u8, hart_proto::deframer::UartFlags)> {
    let mut reader = ErrorReader::new(port);
    let mut out = vec![];
    let end = Instant::now() + Duration::from_secs(5);
    while out.len() < n && Instant::now() < end {
        let mut buf = [0u8; 256];
        match port.read(&mut buf) {
            Ok(k) if k > 0 => out.extend(reader.decode(port, &buf[..k])),
            _ => std::thread::sleep(Duration::from_millis(5)),
        }
    }
    out
}

#[test]
fn each_framing_carries_bytes_both_ways() {
    for (a_line, b_line) in [
        (Line::hart(1200), Line::hart(1200)),
        (Line::even(19200), Line::even(19200)),
        (Line::none(9600), Line::none(9600)),
        (
            Line {
                stop_bits: 2,
                ..Line::none(38400)
            },
            Line::none(38400),
        ),
    ] {
        let Some(pair) = pty_pair() else { return };
        let a = Port::open(&pair.1, &a_line, marked()).unwrap();
        let b = Port::open(&pair.2, &b_line, marked()).unwrap();
        // A pseudo-terminal keeps the speed and stop bits; Linux clears its parity bit
        // (a pseudo-terminal has no parity), so marking is what it keeps of the rest.
        let got = a.line().unwrap();
        assert_eq!((got.baud, got.stop_bits), (a_line.baud, a_line.stop_bits));
        assert!(matches!(got.parity, Parity::None) || got.parity == a_line.parity);
        assert!(a.marks_errors(), "{}", a_line.framing());
        // HART's preambles: every 0xFF arrives doubled by the marking and decodes to one.
        let frame = [0xFF, 0xFF, 0xFF, 0x02, 0x80, 0x00, 0x00, 0x82];
        assert_eq!(a.write(&frame).unwrap(), frame.len());
        let got: Vec<u8> = read_chars(&b, frame.len()).iter().map(|c| c.0).collect();
        assert_eq!(got, frame, "{}", a_line.framing());
        assert_eq!(b.write(&[0x06, 0xFF, 0x00]).unwrap(), 3);
        let back = read_chars(&a, 3);
        assert_eq!(
            back.iter().map(|c| c.0).collect::<Vec<_>>(),
            vec![0x06, 0xFF, 0x00]
        );
        assert!(back.iter().all(|c| !c.1.any()), "good characters unflagged");
    }
}

#[test]
fn a_line_whose_other_side_vanishes_is_hung_up() {
    let Some(mut pair) = pty_pair() else { return };
    let a = Port::open(&pair.1, &Line::hart(1200), marked()).unwrap();
    assert!(!a.hung_up());
    let _ = pair.0.kill();
    let _ = pair.0.wait();
    let end = Instant::now() + Duration::from_secs(5);
    while !a.hung_up() {
        assert!(
            Instant::now() < end,
            "no hang-up reported after socat ended"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_missing_port_and_a_bad_speed_are_explained() {
    let e = Port::open(
        std::path::Path::new("/dev/hartkit-no-such-port"),
        &Line::hart(1200),
        OpenOptions::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("dialout"), "{e}");
    let Some(pair) = pty_pair() else { return };
    let e = Port::open(&pair.1, &Line::hart(1234), OpenOptions::default()).unwrap_err();
    assert!(e.to_string().contains("1234"), "{e}");
}

#[test]
fn pseudo_terminal_pairs_are_raw() {
    let pty = hart_serial::pty::open().unwrap();
    let far = Port::open(&pty.path, &Line::hart(1200), marked()).unwrap();
    assert_eq!(pty.ours.write(&[0x0D, 0x0A, 0x03]).unwrap(), 3);
    let got: Vec<u8> = read_chars(&far, 3).iter().map(|c| c.0).collect();
    assert_eq!(
        got,
        vec![0x0D, 0x0A, 0x03],
        "no line editing or translation"
    );
}

/// PROFIBUS's rates outside the termios table (45.45 and 93.75 kbit/s) are set by
/// value, 8E1, and read back as set; bytes pass.
#[cfg(target_os = "linux")]
#[test]
fn profibus_rates_are_set_by_value() {
    for baud in hart_serial::CUSTOM_BAUD_RATES {
        let pty = hart_serial::pty::open().unwrap();
        let far = Port::open(&pty.path, &Line::even(baud), OpenOptions::default()).unwrap();
        assert_eq!(far.line().unwrap().baud, baud);
        pty.ours
            .write_all(&[0x10, 0x05, 0x02, 0x49, 0x50, 0x16])
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        let mut buf = [0u8; 16];
        assert_eq!(far.read(&mut buf).unwrap(), 6);
    }
}
