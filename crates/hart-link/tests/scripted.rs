//! Scripted byte-and-time tests of the master, slave and burst state machines: every
//! timer edge is checked one microsecond before and at the moment it fires.

use hart_link::master::{MasterOutput, RetryPolicy};
use hart_link::slave::{BurstConfig, Handler, Reply, Slave, SlaveConfig};
use hart_link::{LinkError, Master, Micros, TimingProfile};
use hart_proto::deframer::UartFlags;
use hart_proto::frame::{Address, Frame, FrameSpec, FrameType, LongAddress, MasterKind, UniqueId};

const P: TimingProfile = TimingProfile::fsk();
const CT: Micros = P.char_time;
const ID: UniqueId = UniqueId {
    expanded_device_type: 0x2606,
    device_id: 0x123456,
};

fn frame(spec: FrameSpec<'_>) -> Vec<u8> {
    let mut out = vec![0u8; spec.encoded_len()];
    let n = spec.encode(&mut out).unwrap();
    out.truncate(n);
    out
}

fn ack_to(master: MasterKind, command: u16, rc: u8, data: &[u8]) -> Vec<u8> {
    let a = Address::Long(LongAddress {
        master,
        burst: false,
        id: ID,
    });
    frame(FrameSpec::reply(a, command, rc, 0, data))
}

fn back_to(master: MasterKind) -> Vec<u8> {
    let a = Address::Long(LongAddress {
        master,
        burst: true,
        id: ID,
    });
    frame(FrameSpec {
        frame_type: FrameType::Back,
        ..FrameSpec::reply(a, 1, 0, 0, &[6, 0x41, 0x48, 0, 0])
    })
}

/// Feeds `bytes` to the master one character time apart, the first ending at `t`;
/// returns the time the last one ended.
fn feed_master(m: &mut Master, bytes: &[u8], t: Micros) -> Micros {
    let mut now = t;
    for (i, &b) in bytes.iter().enumerate() {
        now = t + i as Micros * CT;
        m.receive(b, UartFlags::OK, now);
    }
    now
}

fn transmit_at(m: &mut Master, now: Micros) -> Option<Vec<u8>> {
    match m.poll(now) {
        Some(MasterOutput::Transmit(f, pre)) => {
            let mut v = vec![0xFF; pre];
            v.extend_from_slice(f.as_slice());
            Some(v)
        }
        Some(other) => panic!("unexpected {other:?}"),
        None => None,
    }
}

/// Asserts the master transmits exactly at `t` (not at `t - 1`) and returns the bytes.
fn expect_tx_exactly_at(m: &mut Master, t: Micros) -> Vec<u8> {
    assert!(transmit_at(m, t - 1).is_none(), "transmitted before {t}");
    assert_eq!(m.next_deadline(), Some(t), "deadline");
    transmit_at(m, t).unwrap_or_else(|| panic!("no transmission at {t}"))
}

fn cmd1_request() -> FrameSpec<'static> {
    FrameSpec::request(Address::long(ID), 1, &[])
}

#[test]
fn power_up_waits_rt1_then_sto_retries_then_fails() {
    let mut m = Master::new(MasterKind::Primary, P, RetryPolicy::default(), 0);
    m.request(&cmd1_request(), 0).unwrap();
    let tx = expect_tx_exactly_at(&mut m, P.rt1_primary);
    assert_eq!(Frame::parse(&tx).unwrap().command, 1);
    let mut sent = P.rt1_primary + tx.len() as Micros * CT;
    m.transmitted(sent);
    for attempt in 2..=4 {
        // No reply: the retry goes out exactly at STO after the request's end.
        expect_tx_exactly_at(&mut m, sent + P.sto);
        sent += P.sto + tx.len() as Micros * CT;
        m.transmitted(sent);
        assert_eq!(m.stats().retries, attempt - 1);
    }
    assert!(m.poll(sent + P.sto - 1).is_none());
    match m.poll(sent + P.sto) {
        Some(MasterOutput::Done(Err(LinkError::NoReply { attempts: 4 }))) => {}
        other => panic!("{other:?}"),
    }
    assert!(!m.is_busy());
}

#[test]
fn a_master_that_gave_up_leaves_the_other_masters_rt1_slot_first() {
    // The other master counts its RT1 from the last request it heard; the master that
    // gave up starts again only after that slot and the two characters it needs to hear
    // the other's carrier, not at STO + RT2.
    for (kind, other_rt1) in [
        (MasterKind::Primary, P.rt1_secondary),
        (MasterKind::Secondary, P.rt1_primary),
    ] {
        let policy = RetryPolicy {
            retries: 0,
            ..RetryPolicy::default()
        };
        let mut m = Master::new(kind, P, policy, 0);
        m.request(&cmd1_request(), 0).unwrap();
        let t0 = P.rt1(kind);
        let tx = transmit_at(&mut m, t0).unwrap();
        let sent = t0 + tx.len() as Micros * CT;
        m.transmitted(sent);
        match m.poll(sent + P.sto) {
            Some(MasterOutput::Done(Err(LinkError::NoReply { attempts: 1 }))) => {}
            other => panic!("{kind:?}: {other:?}"),
        }
        m.request(&cmd1_request(), sent + P.sto).unwrap();
        let at = (sent + P.sto + P.rt2).max(sent + other_rt1 + P.chars(2));
        expect_tx_exactly_at(&mut m, at);
    }
}

#[test]
fn secondary_waits_its_longer_rt1() {
    let mut m = Master::new(MasterKind::Secondary, P, RetryPolicy::default(), 1000);
    m.request(&cmd1_request(), 1000).unwrap();
    expect_tx_exactly_at(&mut m, 1000 + P.rt1_secondary);
}

#[test]
fn reply_one_byte_at_a_time_then_rt2_before_the_next_request() {
    let mut m = Master::new(MasterKind::Primary, P, RetryPolicy::default(), 0);
    m.request(&cmd1_request(), 0).unwrap();
    let t0 = P.rt1_primary;
    let tx = transmit_at(&mut m, t0).unwrap();
    let sent = t0 + tx.len() as Micros * CT;
    m.transmitted(sent);
    let reply = ack_to(MasterKind::Primary, 1, 0, &[6, 0x41, 0x48, 0, 0]);
    // The reply starts HOLD after the request; each byte arrives one character later.
    let first = sent + P.hold + CT;
    let end = feed_master(&mut m, &reply, first);
    match m.poll(end) {
        Some(MasterOutput::Done(Ok(f))) => assert_eq!(f.as_slice(), &reply[5..]),
        other => panic!("{other:?}"),
    }
    // The next request waits RT2: the other master has the grant until then.
    m.request(&cmd1_request(), end).unwrap();
    expect_tx_exactly_at(&mut m, end + P.rt2);
}

#[test]
fn ack_to_the_other_master_grants_the_line_after_hold_plus_burst_slot() {
    let mut m = Master::new(MasterKind::Secondary, P, RetryPolicy::default(), 0);
    let reply = ack_to(MasterKind::Primary, 3, 0, &[]);
    let end = feed_master(&mut m, &reply, 100_000);
    m.request(&cmd1_request(), end).unwrap();
    expect_tx_exactly_at(&mut m, end + P.hold + 2 * CT);
}

#[test]
fn unused_grant_lapses_to_rt1() {
    let mut m = Master::new(MasterKind::Secondary, P, RetryPolicy::default(), 0);
    let end = feed_master(&mut m, &ack_to(MasterKind::Primary, 3, 0, &[]), 100_000);
    // The request comes after the grant window: wait RT1 from the ACK.
    m.request(&cmd1_request(), end + P.rt2 + 1).unwrap();
    expect_tx_exactly_at(&mut m, end + P.rt1_secondary);
}

#[test]
fn back_frames_grant_the_master_whose_bit_they_carry() {
    let mut p = Master::new(MasterKind::Primary, P, RetryPolicy::default(), 0);
    let end = feed_master(&mut p, &back_to(MasterKind::Primary), 50_000);
    assert!(matches!(p.poll(end), Some(MasterOutput::Burst(_))));
    p.request(&cmd1_request(), end).unwrap();
    expect_tx_exactly_at(&mut p, end + P.hold);
    assert!(p.burst_device_seen());

    let mut s = Master::new(MasterKind::Secondary, P, RetryPolicy::default(), 0);
    let end = feed_master(&mut s, &back_to(MasterKind::Primary), 50_000);
    let _ = s.poll(end);
    s.request(&cmd1_request(), end).unwrap();
    expect_tx_exactly_at(&mut s, end + P.rt1_secondary);
}

#[test]
fn never_transmits_while_characters_arrive() {
    let mut m = Master::new(MasterKind::Primary, P, RetryPolicy::default(), 0);
    m.request(&cmd1_request(), 0).unwrap();
    // A stranger's frame is on the line when RT1 would expire.
    let stranger = frame(FrameSpec::request(Address::short(4), 0, &[]));
    let start = P.rt1_primary - 3 * CT;
    for (i, &b) in stranger.iter().enumerate() {
        let t = start + i as Micros * CT;
        m.receive(b, UartFlags::OK, t);
        assert!(
            transmit_at(&mut m, t).is_none(),
            "transmitted during a frame at byte {i}"
        );
    }
    // After it, RT1 counts again from its end.
    let end = start + (stranger.len() as Micros - 1) * CT;
    let _ = m.poll(end);
    expect_tx_exactly_at(&mut m, end + P.rt1_primary);
}

#[test]
fn busy_and_delayed_responses_repeat_the_request() {
    let policy = RetryPolicy {
        busy_retries: 1,
        busy_delay: 100_000,
        delayed_retries: 2,
        delayed_delay: 200_000,
        ..RetryPolicy::default()
    };
    let mut m = Master::new(MasterKind::Primary, P, policy, 0);
    m.request(&cmd1_request(), 0).unwrap();
    let mut t = P.rt1_primary;
    let answer = |m: &mut Master, t: &mut Micros, rc: u8| -> Micros {
        let tx = transmit_at(m, *t).expect("request");
        let sent = *t + tx.len() as Micros * CT;
        m.transmitted(sent);
        feed_master(
            m,
            &ack_to(MasterKind::Primary, 1, rc, &[]),
            sent + P.hold + CT,
        )
    };
    // Busy: repeated after the busy delay (longer than RT2 here).
    let end = answer(&mut m, &mut t, 32);
    assert!(m.poll(end).is_none());
    t = end + 100_000;
    assert_eq!(m.next_deadline(), Some(t));
    // Delayed response initiated, then running: repeated after the delayed-response delay.
    let end = answer(&mut m, &mut t, 33);
    let _ = m.poll(end);
    t = end + 200_000;
    let end = answer(&mut m, &mut t, 34);
    let _ = m.poll(end);
    t = end + 200_000;
    // The third delayed answer exceeds the policy: reported to the caller as it is.
    let end = answer(&mut m, &mut t, 34);
    match m.poll(end) {
        Some(MasterOutput::Done(Ok(f))) => assert_eq!(
            Frame::parse_pdu(f.as_slice()).unwrap().response_code,
            Some(34)
        ),
        other => panic!("{other:?}"),
    }
    assert_eq!(m.stats().retries, 3);
}

#[test]
fn damaged_reply_is_retried_after_the_reply_slots() {
    let mut m = Master::new(MasterKind::Primary, P, RetryPolicy::default(), 0);
    m.request(&cmd1_request(), 0).unwrap();
    let tx = transmit_at(&mut m, P.rt1_primary).unwrap();
    let sent = P.rt1_primary + tx.len() as Micros * CT;
    m.transmitted(sent);
    let reply = ack_to(MasterKind::Primary, 1, 0, &[6, 0x41, 0x48, 0, 0]);
    let mut end = 0;
    for (i, &b) in reply.iter().enumerate() {
        end = sent + P.hold + CT + i as Micros * CT;
        let flags = if i == 14 {
            UartFlags {
                parity: true,
                ..UartFlags::OK
            }
        } else {
            UartFlags::OK
        };
        m.receive(b, flags, end);
    }
    assert!(m.poll(end).is_none());
    // Slots after a reply: burst device at HOLD, granted master at HOLD + 2 characters,
    // the retrying master at HOLD + 4 characters.
    let retry = expect_tx_exactly_at(&mut m, end + P.hold + 4 * CT);
    assert_eq!(retry, tx);
}

#[test]
fn late_reply_after_sto_meets_the_retry() {
    let mut m = Master::new(MasterKind::Primary, P, RetryPolicy::default(), 0);
    m.request(&cmd1_request(), 0).unwrap();
    let tx = transmit_at(&mut m, P.rt1_primary).unwrap();
    let sent = P.rt1_primary + tx.len() as Micros * CT;
    m.transmitted(sent);
    // The slave starts one microsecond too late: the master has already retried.
    expect_tx_exactly_at(&mut m, sent + P.sto);
    assert_eq!(m.stats().retries, 1);
}

// ---------------------------------------------------------------- collisions

/// A character that overlapped another station's transmission, as a receiver gets it:
/// altered, with a framing error.
fn collided(b: u8) -> (u8, UartFlags) {
    (
        b ^ 0x5A,
        UartFlags {
            framing: true,
            ..UartFlags::OK
        },
    )
}

/// Feeds `bytes` one character apart, the first ending at `t`, those whose index
/// satisfies `hit` garbled by a collision; checks the master never transmits meanwhile.
/// Returns the time the last one ended.
fn feed_master_colliding(
    m: &mut Master,
    bytes: &[u8],
    t: Micros,
    hit: impl Fn(usize) -> bool,
) -> Micros {
    let mut now = t;
    for (i, &b) in bytes.iter().enumerate() {
        now = t + i as Micros * CT;
        let (b, flags) = if hit(i) {
            collided(b)
        } else {
            (b, UartFlags::OK)
        };
        m.receive(b, flags, now);
        assert!(
            transmit_at(m, now).is_none(),
            "transmitted while character {i} arrived"
        );
    }
    now
}

#[test]
fn collision_in_the_reply_is_retried_then_reported_as_a_communication_error() {
    let mut m = Master::new(MasterKind::Primary, P, RetryPolicy::default(), 0);
    m.request(&cmd1_request(), 0).unwrap();
    let reply = ack_to(MasterKind::Primary, 1, 0, &[6, 0x41, 0x48, 0, 0]);
    let mut at = P.rt1_primary;
    for attempt in 1..=4u64 {
        let tx = expect_tx_exactly_at(&mut m, at);
        assert_eq!(Frame::parse(&tx).unwrap().command, 1);
        let sent = at + tx.len() as Micros * CT;
        m.transmitted(sent);
        // Another station starts in the middle of the reply: from the response code on,
        // every character is garbled.
        let end = feed_master_colliding(&mut m, &reply, sent + P.hold + CT, |i| i >= 13);
        assert_eq!(m.stats().retries, attempt - 1);
        if attempt < 4 {
            // Slots after a reply: burst device at HOLD, the master the reply granted
            // the line at HOLD + 2 characters, the retrying master at HOLD + 4.
            at = end + P.hold + 4 * CT;
            continue;
        }
        // The fourth damaged reply: no more retries, the error is reported, never a reply.
        let outcome = (end..end + P.rt1_secondary).find_map(|t| m.poll(t));
        match outcome {
            Some(MasterOutput::Done(Err(LinkError::CommunicationError {
                attempts: 4,
                last_error,
            }))) => assert_eq!(last_error & 0x90, 0x90, "framing error reported"),
            other => panic!("{other:?}"),
        }
    }
    assert_eq!((m.stats().completed, m.stats().failed), (0, 1));
}

#[test]
fn late_reply_running_into_the_retry_is_never_taken_for_an_answer() {
    let mut m = Master::new(MasterKind::Primary, P, RetryPolicy::default(), 0);
    m.request(&cmd1_request(), 0).unwrap();
    let tx = transmit_at(&mut m, P.rt1_primary).unwrap();
    let len = tx.len() as Micros;
    let sent = P.rt1_primary + len * CT;
    m.transmitted(sent);
    // No reply within STO: the retry goes out at STO...
    let retry_at = sent + P.sto;
    assert_eq!(expect_tx_exactly_at(&mut m, retry_at), tx);
    let retry_end = retry_at + len * CT;
    // ...and the device's reply starts half a character later: the characters that
    // overlap the retry arrive garbled, the rest intact but without their start.
    let reply = ack_to(MasterKind::Primary, 1, 0, &[6, 0x41, 0x48, 0, 0]);
    let first = retry_at + CT / 2 + CT;
    let mut transmitted = false;
    let mut end = 0;
    for (i, &b) in reply.iter().enumerate() {
        end = first + i as Micros * CT;
        if !transmitted && end > retry_end {
            m.transmitted(retry_end);
            transmitted = true;
        }
        let (b, flags) = if end - CT < retry_end {
            collided(b)
        } else {
            (b, UartFlags::OK)
        };
        m.receive(b, flags, end);
        assert!(transmit_at(&mut m, end).is_none());
    }
    // Not an answer: the master retries in its slot after what it heard.
    let again = expect_tx_exactly_at(&mut m, end + P.hold + 4 * CT);
    assert_eq!(again, tx);
    assert_eq!((m.stats().completed, m.stats().retries), (0, 2));
}

#[test]
fn a_master_hearing_a_collision_waits_its_rt1_after_it() {
    let mut s = Master::new(MasterKind::Secondary, P, RetryPolicy::default(), 0);
    s.request(&cmd1_request(), 0).unwrap();
    // Two stations' frames on top of each other: garbage from the first character on,
    // still arriving when the secondary's RT1 would expire.
    let request = frame(FrameSpec::request(Address::short(4), 0, &[]));
    let reply = ack_to(MasterKind::Primary, 0, 0, &[0; 8]);
    let start = P.rt1_secondary - 10 * CT;
    let overlap_end = feed_master_colliding(&mut s, &request, start, |_| true);
    // The longer frame goes on alone, intact but without its start.
    let end = feed_master_colliding(&mut s, &reply[request.len()..], overlap_end + CT, |_| false);
    // Nothing it heard granted it the line: RT1 of silence from the last character.
    let tx = expect_tx_exactly_at(&mut s, end + P.rt1_secondary);
    assert_eq!(
        Frame::parse(&tx).unwrap().address.master(),
        MasterKind::Secondary
    );
}

// ---------------------------------------------------------------- slave

struct Echo {
    requests: Vec<u16>,
}

impl Handler for Echo {
    fn request(&mut self, request: &Frame<'_>, reply: &mut Reply, _now: u64) -> bool {
        self.requests.push(request.command);
        if request.command == 11 {
            return request.data == [0x41, 0x4B, 0x71, 0xC3, 0x18, 0x20];
        }
        reply.set_data(&[request.command as u8]);
        true
    }
    fn burst(&mut self, reply: &mut Reply, _now: u64) -> u16 {
        reply.set_data(&[6, 0x41, 0x48, 0, 0]);
        1
    }
}

fn slave() -> (Slave, Echo) {
    (
        Slave::new(
            SlaveConfig {
                polling_address: 3,
                unique_id: ID,
                reply_delay: None,
                response_preambles: 5,
            },
            P,
            0,
        ),
        Echo { requests: vec![] },
    )
}

/// Feeds bytes to the slave one character apart starting at `t`; returns the end time.
fn feed_slave(s: &mut Slave, h: &mut Echo, bytes: &[u8], t: Micros) -> Micros {
    let mut now = t;
    for (i, &b) in bytes.iter().enumerate() {
        now = t + i as Micros * CT;
        s.receive(b, UartFlags::OK, now, h);
    }
    now
}

fn slave_tx(s: &mut Slave, h: &mut Echo, now: Micros) -> Option<Vec<u8>> {
    s.poll(now, h).map(|t| t.bytes.to_vec())
}

#[test]
fn slave_answers_hold_after_the_request() {
    let (mut s, mut h) = slave();
    let req = frame(FrameSpec::request(Address::short(3), 0, &[]));
    let end = feed_slave(&mut s, &mut h, &req, 10_000);
    assert!(slave_tx(&mut s, &mut h, end + P.hold - 1).is_none());
    assert_eq!(s.next_deadline(), Some(end + P.hold));
    let reply = slave_tx(&mut s, &mut h, end + P.hold).unwrap();
    let f = Frame::parse(&reply).unwrap();
    assert_eq!(
        (f.frame_type(), f.command, f.address.master(), f.data),
        (FrameType::Ack, 0, MasterKind::Primary, &[0u8][..])
    );
    s.transmitted(end + P.hold + reply.len() as Micros * CT);
    assert_eq!(s.stats().replies, 1);
}

#[test]
fn slave_addressing_rules() {
    let (mut s, mut h) = slave();
    let mut t = 0;
    let mut ask = |s: &mut Slave, h: &mut Echo, spec: FrameSpec<'_>| -> bool {
        let end = feed_slave(s, h, &frame(spec), t);
        t = end + 1_000_000;
        let r = slave_tx(s, h, end + P.hold).is_some();
        if r {
            s.transmitted(end + P.hold + 40 * CT);
        }
        r
    };
    assert!(
        !ask(
            &mut s,
            &mut h,
            FrameSpec::request(Address::short(4), 0, &[])
        ),
        "other polling address"
    );
    assert!(
        ask(
            &mut s,
            &mut h,
            FrameSpec::request(Address::long(ID), 1, &[])
        ),
        "own long address"
    );
    assert!(
        !ask(
            &mut s,
            &mut h,
            FrameSpec::request(Address::long(UniqueId::new(0x2606, 0x123457)), 1, &[])
        ),
        "other device ID"
    );
    assert!(
        !ask(
            &mut s,
            &mut h,
            FrameSpec::request(Address::long(UniqueId::BROADCAST), 1, &[])
        ),
        "broadcast only for 11 and 21"
    );
    let tag = [0x41, 0x4B, 0x71, 0xC3, 0x18, 0x20];
    assert!(
        ask(
            &mut s,
            &mut h,
            FrameSpec::request(Address::long(UniqueId::BROADCAST), 11, &tag)
        ),
        "broadcast command 11, matching tag"
    );
    assert!(
        !ask(
            &mut s,
            &mut h,
            FrameSpec::request(Address::long(UniqueId::BROADCAST), 11, &[0; 6])
        ),
        "command 11, other tag: silence"
    );
    // Polling addresses up to 63 work.
    s.set_polling_address(63);
    assert!(ask(
        &mut s,
        &mut h,
        FrameSpec::request(Address::short(63), 0, &[])
    ));
}

#[test]
fn damaged_request_gets_a_communication_error_reply() {
    let (mut s, mut h) = slave();
    let req = frame(FrameSpec::request(Address::long(ID), 1, &[]));
    let mut end = 0;
    for (i, &b) in req.iter().enumerate() {
        end = 1000 + i as Micros * CT;
        // Parity error in the byte count: after the address, so the device may answer.
        let flags = if i == 12 {
            UartFlags {
                parity: true,
                ..UartFlags::OK
            }
        } else {
            UartFlags::OK
        };
        s.receive(b, flags, end, &mut h);
    }
    let reply = slave_tx(&mut s, &mut h, end + P.hold).expect("comm error reply");
    let f = Frame::parse(&reply).unwrap();
    assert_eq!(
        f.response_code,
        Some(0x80 | 0x40),
        "parity error summarised"
    );
    assert!(f.data.is_empty());
    assert!(
        h.requests.is_empty(),
        "the application never sees a damaged request"
    );

    // Damage in the address: silence.
    let (mut s, mut h) = slave();
    for (i, &b) in req.iter().enumerate() {
        end = 1000 + i as Micros * CT;
        let flags = if i == 7 {
            UartFlags {
                framing: true,
                ..UartFlags::OK
            }
        } else {
            UartFlags::OK
        };
        s.receive(b, flags, end, &mut h);
    }
    assert!(slave_tx(&mut s, &mut h, end + P.hold).is_none());
    assert_eq!(s.next_deadline(), None);
}

#[test]
fn gap_inside_a_frame_aborts_it() {
    let (mut s, mut h) = slave();
    let req = frame(FrameSpec::request(Address::short(3), 0, &[]));
    let mut t = 0;
    for (i, &b) in req.iter().enumerate() {
        // Two character times of silence before the delimiter's successor.
        t += if i == 7 { 3 * CT } else { CT };
        s.receive(b, UartFlags::OK, t, &mut h);
    }
    assert!(slave_tx(&mut s, &mut h, t + P.hold).is_none());
    // One character of silence is still tolerated.
    let (mut s, mut h) = slave();
    let mut t = 0;
    for (i, &b) in req.iter().enumerate() {
        t += if i == 7 { 2 * CT } else { CT };
        s.receive(b, UartFlags::OK, t, &mut h);
    }
    assert!(slave_tx(&mut s, &mut h, t + P.hold).is_some());
}

#[test]
fn two_frames_in_one_read() {
    // A serial read returns two frames at once: every byte has the same time stamp.
    let (mut s, mut h) = slave();
    let mut bytes = frame(FrameSpec::request(Address::short(4), 0, &[]));
    bytes.extend(frame(FrameSpec::request(Address::short(3), 2, &[])));
    for &b in &bytes {
        s.receive(b, UartFlags::OK, 5_000, &mut h);
    }
    assert_eq!(h.requests, vec![2]);
    assert!(slave_tx(&mut s, &mut h, 5_000 + P.hold).is_some());
}

#[test]
fn burst_device_follows_acks_and_alternates_master_bits() {
    let (mut s, mut h) = slave();
    s.set_burst(Some(BurstConfig { period: 500_000 }), 0);
    // An ACK of another device to the primary: the BACK follows HOLD later.
    let other = Address::Long(LongAddress {
        master: MasterKind::Primary,
        burst: false,
        id: UniqueId::new(0x2606, 1),
    });
    let end = feed_slave(
        &mut s,
        &mut h,
        &frame(FrameSpec::reply(other, 3, 0, 0, &[1, 2, 3, 4])),
        1_000_000,
    );
    assert!(slave_tx(&mut s, &mut h, end + P.hold - 1).is_none());
    let back = slave_tx(&mut s, &mut h, end + P.hold).expect("BACK after the ACK");
    let f = Frame::parse(&back).unwrap();
    assert_eq!(
        (f.frame_type(), f.address.master(), f.address.burst()),
        (FrameType::Back, MasterKind::Primary, true)
    );
    let sent = end + P.hold + back.len() as Micros * CT;
    s.transmitted(sent);
    // Not due again before the period: the next ACK passes without a BACK.
    let end2 = feed_slave(
        &mut s,
        &mut h,
        &frame(FrameSpec::reply(other, 3, 0, 0, &[])),
        sent + 100_000,
    );
    assert!(slave_tx(&mut s, &mut h, end2 + P.hold).is_none());
    // A request to another device that is never answered: BACK after RT1 of its master.
    let req = frame(FrameSpec {
        address: Address::Long(LongAddress {
            master: MasterKind::Secondary,
            burst: false,
            id: UniqueId::new(0x2606, 1),
        }),
        ..FrameSpec::request(Address::short(0), 1, &[])
    });
    let end3 = feed_slave(&mut s, &mut h, &req, 1_000_000 + 500_000);
    assert!(slave_tx(&mut s, &mut h, end3 + P.rt1_secondary - 1).is_none());
    let back2 = slave_tx(&mut s, &mut h, end3 + P.rt1_secondary).expect("BACK restores the line");
    assert_eq!(
        Frame::parse(&back2).unwrap().address.master(),
        MasterKind::Secondary,
        "alternates"
    );
}

#[test]
fn burst_device_answers_its_own_requests_first() {
    let (mut s, mut h) = slave();
    s.set_burst(Some(BurstConfig { period: 500_000 }), 0);
    let end = feed_slave(
        &mut s,
        &mut h,
        &frame(FrameSpec::request(Address::long(ID), 1, &[])),
        1_000_000,
    );
    let reply = slave_tx(&mut s, &mut h, end + P.hold).expect("ACK");
    let f = Frame::parse(&reply).unwrap();
    assert_eq!(f.frame_type(), FrameType::Ack);
    assert!(
        f.address.burst(),
        "the burst bit is set in replies while bursting"
    );
    let sent = end + P.hold + reply.len() as Micros * CT;
    s.transmitted(sent);
    // Its own ACK counts as an ACK on the line: the due BACK follows HOLD later.
    let back = slave_tx(&mut s, &mut h, sent + P.hold).expect("BACK");
    assert_eq!(Frame::parse(&back).unwrap().frame_type(), FrameType::Back);
}

#[test]
fn request_hit_by_a_collision_silence_unless_address_and_length_survive() {
    // Preambles 0-4, delimiter 5, address 6-10, command 11, byte count 12, data 13-16,
    // check byte 17.
    let req = frame(FrameSpec::request(Address::long(ID), 1, &[1, 2, 3, 4]));
    let feed = |from: usize| {
        let (mut s, mut h) = slave();
        let mut end = 0;
        for (i, &b) in req.iter().enumerate() {
            end = 1000 + i as Micros * CT;
            let (b, flags) = if i >= from {
                collided(b)
            } else {
                (b, UartFlags::OK)
            };
            s.receive(b, flags, end, &mut h);
        }
        // Whatever it sends, it sends by STO (at its deadlines: reply delay, or the gap
        // that ends a frame whose garbled byte count promised more).
        let mut reply = None;
        while let Some(t) = s.next_deadline().filter(|&t| t <= end + P.sto) {
            if let Some(r) = slave_tx(&mut s, &mut h, t) {
                reply = Some(r);
                break;
            }
        }
        assert!(
            h.requests.is_empty(),
            "the application never sees a collided request"
        );
        reply
    };
    // The collision starts inside the address: the device cannot know the request was
    // its own and stays silent.
    assert_eq!(feed(8), None);
    // It starts at the byte count: the frame never ends, the gap after it aborts it.
    assert_eq!(feed(12), None);
    // It starts in the data: the address is trusted, the reply reports framing.
    let reply = feed(14).expect("communication-error reply");
    let f = Frame::parse(&reply).unwrap();
    assert_eq!(f.response_code.map(|rc| rc & 0xD0), Some(0x90));
    assert!(f.data.is_empty());
}
