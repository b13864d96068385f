//! Streaming deframer tests: byte-by-byte scripted streams with splits, garbage,
//! UART errors, cut-off frames and resynchronisation.

use hart_proto::deframer::{Deframer, DeframerConfig, DeframerEvent, UartFlags};
use hart_proto::frame::{checksum, Address, FrameSpec, FrameType};
use hart_proto::tables::comm_error;

/// What an event looked like, owned, so tests can collect them.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Ev {
    Frame {
        pdu: Vec<u8>,
        preambles: usize,
    },
    Damaged {
        errors: u8,
        address: Option<Address>,
        command: Option<u8>,
    },
    Invalid,
    Aborted {
        received: usize,
        expected: Option<usize>,
    },
    Garbage(usize),
}

fn own(e: DeframerEvent<'_>) -> Ev {
    match e {
        DeframerEvent::Frame(f) => Ev::Frame {
            pdu: f.pdu.to_vec(),
            preambles: f.preambles,
        },
        DeframerEvent::Damaged(d) => Ev::Damaged {
            errors: d.errors,
            address: d.address,
            command: d.command_byte,
        },
        DeframerEvent::Invalid { .. } => Ev::Invalid,
        DeframerEvent::Aborted { received, expected } => Ev::Aborted { received, expected },
        DeframerEvent::Garbage { bytes } => Ev::Garbage(bytes),
    }
}

fn run(d: &mut Deframer, bytes: &[u8]) -> Vec<Ev> {
    let mut ev = vec![];
    d.feed(bytes, |e| ev.push(own(e)));
    ev
}

fn frames(ev: &[Ev]) -> Vec<Vec<u8>> {
    ev.iter()
        .filter_map(|e| match e {
            Ev::Frame { pdu, .. } => Some(pdu.clone()),
            _ => None,
        })
        .collect()
}

const CMD0_REQ: &[u8] = &[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02, 0x80, 0x00, 0x00, 0x82];
const CMD1_REPLY: &[u8] = &[
    0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x86, 0xA6, 0x06, 0x12, 0x34, 0x56, 0x01, 0x07, 0x00, 0x00, 0x06,
    0x41, 0x48, 0x00, 0x00, 0x5F,
];

#[test]
fn one_frame_fed_in_every_split() {
    for split in 0..=CMD1_REPLY.len() {
        let mut d = Deframer::default();
        let mut ev = run(&mut d, &CMD1_REPLY[..split]);
        ev.extend(run(&mut d, &CMD1_REPLY[split..]));
        assert_eq!(
            ev,
            vec![Ev::Frame {
                pdu: CMD1_REPLY[5..].to_vec(),
                preambles: 5
            }],
            "split at {split}"
        );
    }
}

#[test]
fn back_to_back_frames_and_two_preambles() {
    let mut stream = CMD0_REQ.to_vec();
    stream.extend_from_slice(&CMD1_REPLY[3..]); // 2 preambles only
    stream.extend_from_slice(CMD0_REQ);
    let ev = run(&mut Deframer::default(), &stream);
    assert_eq!(
        frames(&ev),
        vec![
            CMD0_REQ[5..].to_vec(),
            CMD1_REPLY[5..].to_vec(),
            CMD0_REQ[5..].to_vec()
        ]
    );
    assert!(matches!(ev[1], Ev::Frame { preambles: 2, .. }));
}

#[test]
fn one_preamble_is_not_a_start_of_message() {
    let ev = run(&mut Deframer::default(), &CMD0_REQ[4..]);
    assert!(frames(&ev).is_empty());
}

#[test]
fn garbage_before_and_after() {
    let mut stream = vec![0x13, 0x37, 0x02, 0x80, 0xFF, 0x00];
    stream.extend_from_slice(CMD0_REQ);
    stream.extend_from_slice(&[0x00, 0xAB]); // trailing bytes after the check byte
    stream.extend_from_slice(CMD1_REPLY);
    let ev = run(&mut Deframer::default(), &stream);
    assert_eq!(
        frames(&ev),
        vec![CMD0_REQ[5..].to_vec(), CMD1_REPLY[5..].to_vec()]
    );
    assert_eq!(ev[0], Ev::Garbage(6));
    assert_eq!(ev[2], Ev::Garbage(2));
}

#[test]
fn cut_off_frame_followed_by_a_good_one() {
    // The first reply stops after its address (sender reset); the next frame starts
    // right away. The first "frame" reads 0xFF as command and byte count and swallows
    // the next frames as its data; when the line goes quiet the link layer aborts it and
    // the rescan finds both real frames.
    let mut stream = CMD1_REPLY[..11].to_vec();
    stream.extend_from_slice(CMD1_REPLY);
    stream.extend_from_slice(CMD0_REQ);
    let mut d = Deframer::default();
    let mut ev = run(&mut d, &stream);
    assert!(frames(&ev).is_empty());
    d.abort(&mut |e| ev.push(own(e)));
    assert_eq!(
        ev[0],
        Ev::Aborted {
            received: 6 + 21 + 10,
            expected: Some(1 + 5 + 2 + 255 + 1)
        }
    );
    assert_eq!(
        frames(&ev),
        vec![CMD1_REPLY[5..].to_vec(), CMD0_REQ[5..].to_vec()]
    );

    // With a byte count that ends inside the next frame, the check byte fails, the frame
    // is reported as damaged, and the rescan finds the next frame without any abort.
    let mut stream = CMD0_REQ[..7].to_vec(); // 02 80, then cut
    stream.extend_from_slice(&[0x00, 0x03]); // command 0, byte count 3
    stream.extend_from_slice(CMD1_REPLY);
    let ev = run(&mut Deframer::default(), &stream);
    assert!(matches!(ev[0], Ev::Damaged { .. }), "{ev:?}");
    assert_eq!(frames(&ev), vec![CMD1_REPLY[5..].to_vec()]);
}

#[test]
fn false_start_inside_garbage() {
    // Garbage that looks like a start of message with a large byte count.
    let mut stream = vec![0xFF, 0xFF, 0x02, 0x80, 0x01, 0x40];
    stream.extend_from_slice(CMD0_REQ);
    let mut d = Deframer::default();
    let mut ev = run(&mut d, &stream);
    // The false frame is still waiting for its 64 data bytes: the line goes quiet,
    // the link layer reports the gap, and the rescan finds the real frame.
    assert!(frames(&ev).is_empty());
    d.abort(&mut |e| ev.push(own(e)));
    assert_eq!(frames(&ev), vec![CMD0_REQ[5..].to_vec()]);
    assert!(matches!(
        ev[0],
        Ev::Aborted {
            received: 14,
            expected: Some(69)
        }
    ));
}

#[test]
fn bad_check_byte_is_reported_with_the_address() {
    let mut f = CMD1_REPLY.to_vec();
    *f.last_mut().unwrap() ^= 0x01;
    let ev = run(&mut Deframer::default(), &f);
    let Ev::Damaged {
        errors,
        address,
        command,
    } = &ev[0]
    else {
        panic!("{ev:?}")
    };
    assert_eq!(*errors, comm_error::FLAG | comm_error::CHECK_BYTE);
    assert_eq!(
        address.unwrap().to_string(),
        "unique ID 2606123456 (primary master)"
    );
    assert_eq!(*command, Some(1));
}

#[test]
fn uart_errors_are_summarised() {
    let mut d = Deframer::default();
    let mut ev = vec![];
    for (i, &b) in CMD1_REPLY.iter().enumerate() {
        let flags = match i {
            15 => UartFlags {
                parity: true,
                ..UartFlags::OK
            },
            17 => UartFlags {
                overrun: true,
                framing: true,
                ..UartFlags::OK
            },
            _ => UartFlags::OK,
        };
        d.push(b, flags, &mut |e| ev.push(own(e)));
    }
    let Ev::Damaged {
        errors,
        address,
        command,
    } = &ev[0]
    else {
        panic!("{ev:?}")
    };
    assert_eq!(
        *errors,
        comm_error::FLAG | comm_error::PARITY | comm_error::OVERRUN | comm_error::FRAMING
    );
    assert!(
        address.is_some() && command.is_some(),
        "errors after the header leave the address usable"
    );

    // An error in the address: the frame is reported, but nobody may trust the address.
    let mut d = Deframer::default();
    let mut ev = vec![];
    for (i, &b) in CMD1_REPLY.iter().enumerate() {
        let flags = if i == 7 {
            UartFlags {
                parity: true,
                ..UartFlags::OK
            }
        } else {
            UartFlags::OK
        };
        d.push(b, flags, &mut |e| ev.push(own(e)));
    }
    assert!(
        matches!(
            ev[0],
            Ev::Damaged {
                address: None,
                command: None,
                ..
            }
        ),
        "{ev:?}"
    );
}

#[test]
fn uart_error_in_preamble_delays_the_start() {
    let mut d = Deframer::default();
    let mut ev = vec![];
    for (i, &b) in CMD0_REQ.iter().enumerate() {
        let flags = if i == 3 {
            UartFlags {
                framing: true,
                ..UartFlags::OK
            }
        } else {
            UartFlags::OK
        };
        d.push(b, flags, &mut |e| ev.push(own(e)));
    }
    // Only one good preamble follows the damaged one: no start of message.
    assert!(frames(&ev).is_empty());
}

#[test]
fn overflow_for_a_small_receive_buffer() {
    let mut d = Deframer::new(DeframerConfig {
        max_byte_count: 4,
        ..DeframerConfig::default()
    });
    let ev = run(&mut d, CMD1_REPLY);
    assert!(
        matches!(ev[0], Ev::Damaged { errors, .. } if errors & comm_error::BUFFER_OVERFLOW != 0),
        "{ev:?}"
    );
}

#[test]
fn invalid_frames_are_reported_then_skipped() {
    // ACK with byte count 1 (cannot hold the status bytes), then a good frame.
    let bad = [0xFF, 0xFF, 0x06, 0x80, 0x00, 0x01, 0x00];
    let mut stream = bad.to_vec();
    stream.push(checksum(&bad[2..]));
    stream.extend_from_slice(CMD0_REQ);
    let ev = run(&mut Deframer::default(), &stream);
    assert_eq!(ev[0], Ev::Invalid);
    assert_eq!(frames(&ev), vec![CMD0_REQ[5..].to_vec()]);
}

#[test]
fn abort_mid_frame_then_continue() {
    let mut d = Deframer::default();
    let mut ev = run(&mut d, &CMD1_REPLY[..9]);
    d.abort(&mut |e| ev.push(own(e)));
    ev.extend(run(&mut d, CMD0_REQ));
    assert_eq!(
        ev[0],
        Ev::Aborted {
            received: 4,
            expected: None
        }
    );
    assert_eq!(frames(&ev), vec![CMD0_REQ[5..].to_vec()]);
    let s = d.stats();
    assert_eq!((s.frames, s.aborted), (1, 1));
}

#[test]
fn largest_frame() {
    let data = [0x5Au8; 253];
    let mut out = [0u8; 300];
    let spec = FrameSpec {
        frame_type: FrameType::Ack,
        status: Some((0, 0)),
        ..FrameSpec::request(Address::short(3), 9, &data)
    };
    let n = spec.encode(&mut out).unwrap();
    let ev = run(&mut Deframer::default(), &out[..n]);
    assert_eq!(frames(&ev).len(), 1);
}
