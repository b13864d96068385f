//! The client against scripted devices that misbehave the way real ones do: a HART 5
//! device with 4 preambles and garbage after the check byte, busy twice before the real
//! reply, a delayed response, a communication-error reply, status-only replies.

use std::collections::VecDeque;

use hart_host::transport::Transport;
use hart_host::{Client, DeviceRef, HostError};
use hart_link::{Micros, TimingProfile};
use hart_proto::frame::{checksum, Frame};

/// A device that answers each request with the next scripted reply (raw bytes), HOLD
/// after the request, in virtual time. `None` means silence.
struct Scripted {
    now: Micros,
    replies: VecDeque<Option<Vec<u8>>>,
    pending: Vec<(u8, Micros)>,
    requests: Vec<Vec<u8>>,
}

impl Scripted {
    fn new(replies: Vec<Option<Vec<u8>>>) -> Self {
        Scripted {
            now: 0,
            replies: replies.into(),
            pending: vec![],
            requests: vec![],
        }
    }
}

impl Transport for Scripted {
    fn profile(&self) -> TimingProfile {
        TimingProfile::fsk()
    }
    fn now(&self) -> Micros {
        self.now
    }
    async fn send(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let ct = self.profile().char_time;
        self.now += bytes.len() as Micros * ct;
        self.requests.push(bytes.to_vec());
        if let Some(Some(reply)) = self.replies.pop_front() {
            let start = self.now + self.profile().hold;
            self.pending = reply
                .iter()
                .enumerate()
                .map(|(i, &b)| (b, start + (i as Micros + 1) * ct))
                .collect();
        }
        Ok(())
    }
    async fn recv(&mut self, deadline: Micros) -> std::io::Result<Vec<(u8, Micros)>> {
        if let Some(&(_, first)) = self.pending.first() {
            if first <= deadline {
                let out = std::mem::take(&mut self.pending);
                self.now = self.now.max(out.last().unwrap().1);
                return Ok(out);
            }
        }
        self.now = self.now.max(deadline);
        Ok(vec![])
    }
    fn describe(&self) -> String {
        "serial scripted device at 1200 bit/s".into()
    }
}

/// An ACK from the HART 5-style device 0x1A/0x1A/0xAD188C with `preambles` preambles.
fn ack(
    short: bool,
    command: u8,
    rc: u8,
    status: u8,
    data: &[u8],
    preambles: usize,
    trailing: &[u8],
) -> Vec<u8> {
    let mut pdu = if short {
        vec![0x06, 0x80]
    } else {
        vec![0x86, 0x9A, 0x1A, 0xAD, 0x18, 0x8C]
    };
    pdu.push(command);
    pdu.push((data.len() + 2) as u8);
    pdu.extend([rc, status]);
    pdu.extend_from_slice(data);
    pdu.push(checksum(&pdu));
    let mut out = vec![0xFF; preambles];
    out.extend(pdu);
    out.extend_from_slice(trailing);
    out
}

/// A HART 5 command 0 reply (12 bytes): manufacturer 0x1A, type 0x1A, ID 0xAD188C.
fn hart5_identity() -> Vec<u8> {
    vec![254, 0x1A, 0x1A, 5, 5, 1, 1, 0x08, 0, 0xAD, 0x18, 0x8C]
}

fn client(replies: Vec<Option<Vec<u8>>>) -> Client<Scripted> {
    Client::new(Scripted::new(replies))
}

#[tokio::test(flavor = "current_thread")]
async fn hart5_device_with_four_preambles_and_trailing_garbage() {
    let mut c = client(vec![Some(ack(
        true,
        0,
        0,
        0,
        &hart5_identity(),
        4,
        &[0x00, 0x13, 0x37],
    ))]);
    let d = c.resolve(&DeviceRef::Poll(0)).await.unwrap();
    assert_eq!(d.revision(), 5);
    assert_eq!(
        d.manufacturer_id(),
        0x1A,
        "HART 5: manufacturer ID is byte 1"
    );
    assert_eq!(d.unique_id().to_string(), "1A1AAD188C");
    assert!(d.identity.min_response_preambles.is_none());
}

#[tokio::test(flavor = "current_thread")]
async fn busy_twice_then_the_real_reply() {
    let id = ack(true, 0, 0, 0, &hart5_identity(), 5, &[]);
    let pv = [6u8, 0x41, 0x48, 0, 0];
    let mut c = client(vec![
        Some(id),
        Some(ack(false, 1, 32, 0, &[], 5, &[])),
        Some(ack(false, 1, 32, 0, &[], 5, &[])),
        Some(ack(false, 1, 0, 0, &pv, 5, &[])),
    ]);
    let d = c.resolve(&DeviceRef::Poll(0)).await.unwrap();
    let r = c.command(&d, 1, &[]).await.unwrap();
    assert_eq!(r.data, pv);
    let sent = &c.transport().requests;
    assert_eq!(sent.len(), 4, "identify, then command 1 three times");
    assert_eq!(sent[1], sent[3], "the identical request is repeated");
}

#[tokio::test(flavor = "current_thread")]
async fn delayed_response_is_polled_until_done() {
    let id = ack(true, 0, 0, 0, &hart5_identity(), 5, &[]);
    let mut c = client(vec![
        Some(id),
        Some(ack(false, 41, 33, 0, &[], 5, &[])),
        Some(ack(false, 41, 34, 0, &[], 5, &[])),
        Some(ack(false, 41, 34, 0, &[], 5, &[])),
        Some(ack(false, 41, 0, 0, &[], 5, &[])),
    ]);
    let d = c.resolve(&DeviceRef::Poll(0)).await.unwrap();
    let r = c.command(&d, 41, &[]).await.unwrap();
    assert_eq!(
        (r.response_code, r.data.len()),
        (0, 0),
        "status-only success reply"
    );
    assert_eq!(c.transport().requests.len(), 5);
    assert!(
        c.transport().now() >= 3 * 500_000,
        "waits the delayed-response interval between polls"
    );
}

#[tokio::test(flavor = "current_thread")]
async fn communication_error_reply_is_retried() {
    let id = ack(true, 0, 0, 0, &hart5_identity(), 5, &[]);
    let pv = [6u8, 0x41, 0x48, 0, 0];
    // The device says our request arrived with a parity error (0xC0), then answers.
    let mut c = client(vec![
        Some(id.clone()),
        Some(ack(false, 1, 0xC0, 0, &[], 5, &[])),
        Some(ack(false, 1, 0, 0, &pv, 5, &[])),
    ]);
    let d = c.resolve(&DeviceRef::Poll(0)).await.unwrap();
    assert_eq!(c.command(&d, 1, &[]).await.unwrap().data, pv);
    // Always damaged: reported, with the device's error byte.
    let mut c = client(vec![
        Some(id),
        Some(ack(false, 1, 0x88, 0, &[], 5, &[])),
        Some(ack(false, 1, 0x88, 0, &[], 5, &[])),
        Some(ack(false, 1, 0x88, 0, &[], 5, &[])),
        Some(ack(false, 1, 0x88, 0, &[], 5, &[])),
    ]);
    let d = c.resolve(&DeviceRef::Poll(0)).await.unwrap();
    match c.command(&d, 1, &[]).await {
        Err(
            e @ HostError::Communication {
                attempts: 4,
                last_error: 0x88,
                ..
            },
        ) => assert!(e.to_string().contains("0x88"), "{e}"),
        other => panic!("{other:?}"),
    }
}

#[tokio::test(flavor = "current_thread")]
async fn status_only_error_reply_is_explained() {
    let id = ack(true, 0, 0, 0, &hart5_identity(), 5, &[]);
    let mut c = client(vec![Some(id), Some(ack(false, 18, 7, 0x40, &[], 5, &[]))]);
    let d = c.resolve(&DeviceRef::Poll(0)).await.unwrap();
    match c.command(&d, 18, &[0; 21]).await {
        Err(e @ HostError::Device { code: 7, .. }) => {
            assert_eq!(
                e.to_string(),
                "device replied 'in write-protect mode' (7) to command 18"
            );
            assert_eq!(e.exit_code(), 4);
        }
        other => panic!("{other:?}"),
    }
}

#[tokio::test(flavor = "current_thread")]
async fn silent_device_names_the_address_and_the_port() {
    let mut c = client(vec![None, None, None, None]);
    let e = c.resolve(&DeviceRef::Poll(3)).await.unwrap_err();
    assert_eq!(
        e.to_string(),
        "no reply from polling address 3 after 4 tries (STO 256 ms) on serial scripted device at 1200 bit/s; is the modem's RTS set right (--port ...?rts=high-tx|low-tx|none), and is a device at that address?"
    );
    // Each request went out with 5 preambles in a short frame to address 3.
    let f = Frame::parse(&c.transport().requests[0]).unwrap();
    assert_eq!((f.preambles, f.command), (5, 0));
}
