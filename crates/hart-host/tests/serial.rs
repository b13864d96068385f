//! The serial side without hardware: how marked input (`PARMRK`) is decoded, a serial
//! port and an RS-485 line played by a real pseudo-terminal pair, and what the client
//! does with UART error flags and a carrier-detect line.

use std::io;
use std::os::fd::OwnedFd;
use std::time::Duration;

use hart_host::target::open;
use hart_host::transport::{ParmrkDecoder, RxChar, Transport};
use hart_host::{Client, DeviceRef, HostError};
use hart_link::{Micros, TimingProfile};
use hart_proto::frame::checksum;
use hart_proto::tables::comm_error;
use hart_proto::UartFlags;
use hart_serial::Port;

const PARITY: UartFlags = UartFlags {
    parity: true,
    framing: false,
    overrun: false,
};
const FRAMING: UartFlags = UartFlags {
    parity: false,
    framing: true,
    overrun: false,
};

fn decode(d: &mut ParmrkDecoder, raw: &[u8]) -> Vec<(u8, UartFlags)> {
    let mut out = vec![];
    d.decode(raw, &mut out);
    out
}

#[test]
fn unmarked_input_is_passed_through() {
    let mut d = ParmrkDecoder::new();
    assert_eq!(
        decode(&mut d, &[0x02, 0x80, 0x00]),
        vec![
            (0x02, UartFlags::OK),
            (0x80, UartFlags::OK),
            (0x00, UartFlags::OK)
        ]
    );
}

#[test]
fn a_doubled_ff_is_one_data_byte_ff() {
    let mut d = ParmrkDecoder::new();
    // Five preambles as the line discipline delivers them, then a delimiter.
    let mut raw = [0xFF; 10].to_vec();
    raw.push(0x06);
    let out = decode(&mut d, &raw);
    assert_eq!(out.len(), 6);
    assert!(out[..5].iter().all(|&c| c == (0xFF, UartFlags::OK)));
    assert_eq!(out[5], (0x06, UartFlags::OK));
}

#[test]
fn ff_00_x_is_x_received_with_an_error() {
    let mut d = ParmrkDecoder::new();
    assert_eq!(decode(&mut d, &[0xFF, 0x00, 0x41]), vec![(0x41, PARITY)]);
    // A marked 0x00 is what a break or a lost stop bit gives.
    assert_eq!(decode(&mut d, &[0xFF, 0x00, 0x00]), vec![(0x00, FRAMING)]);
    // A damaged 0xFF is not mistaken for the start of another escape.
    assert_eq!(
        decode(&mut d, &[0xFF, 0x00, 0xFF, 0x01]),
        vec![(0xFF, PARITY), (0x01, UartFlags::OK)]
    );
}

#[test]
fn an_escape_split_over_two_reads_is_finished_by_the_next() {
    let mut d = ParmrkDecoder::new();
    assert_eq!(decode(&mut d, &[0x01, 0xFF]), vec![(0x01, UartFlags::OK)]);
    assert!(d.in_escape());
    assert_eq!(decode(&mut d, &[0xFF]), vec![(0xFF, UartFlags::OK)]);
    assert!(!d.in_escape());
    assert_eq!(decode(&mut d, &[0xFF, 0x00]), vec![]);
    assert!(d.in_escape());
    assert_eq!(
        decode(&mut d, &[0x7E, 0x02]),
        vec![(0x7E, PARITY), (0x02, UartFlags::OK)]
    );
}

/// A pseudo-terminal pair: the far end (the master side, playing the modem and the
/// devices) and the path of the slave side, which the transport opens.
struct Pty {
    /// The far end: what a device or an RS-485 line would be.
    far: Port,
    path: String,
    /// Kept open so the far end never sees the line hang up between opens.
    slave: OwnedFd,
}

fn pty() -> Pty {
    let p = hart_serial::pty::open().unwrap();
    Pty {
        far: p.ours,
        path: p.path.to_string_lossy().into_owned(),
        slave: p.far,
    }
}

fn write_all(port: &Port, bytes: &[u8]) {
    let mut rest = bytes;
    while !rest.is_empty() {
        match port.write(rest) {
            Ok(n) => rest = &rest[n..],
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(1))
            }
            Err(e) => panic!("write: {e}"),
        }
    }
}

/// Reads one byte from the far end, waiting at most `within`.
fn read_byte(port: &Port, within: Duration) -> Option<u8> {
    let end = std::time::Instant::now() + within;
    let mut b = [0u8];
    loop {
        if let Ok(1) = port.read(&mut b) {
            return Some(b[0]);
        }
        if std::time::Instant::now() >= end {
            return None;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Reads one request (preambles through check byte) arriving at the far end.
fn read_request(fd: &Port, within: Duration) -> Option<Vec<u8>> {
    let mut req = vec![];
    let mut b = read_byte(fd, within)?;
    while b == 0xFF {
        req.push(b);
        b = read_byte(fd, within)?;
    }
    req.push(b);
    let address = if b & 0x80 != 0 { 5 } else { 1 };
    let expansion = usize::from((b >> 5) & 3);
    for _ in 0..address + expansion + 1 {
        req.push(read_byte(fd, within)?);
    }
    let count = read_byte(fd, within)?;
    req.push(count);
    for _ in 0..=count {
        req.push(read_byte(fd, within)?);
    }
    Some(req)
}

/// A HART 5 command 0 reply from polling address 1 with device ID 0xFF00FF (0xFF
/// bytes in the middle of the frame, besides the preambles).
fn identity_reply() -> Vec<u8> {
    let data = [254, 0x1A, 0x1A, 5, 5, 1, 1, 0x08, 0, 0xFF, 0x00, 0xFF];
    let mut pdu = vec![0x06, 0x81, 0x00, data.len() as u8 + 2, 0, 0];
    pdu.extend(data);
    pdu.push(checksum(&pdu));
    let mut out = vec![0xFF; 5];
    out.extend(pdu);
    out
}

/// Plays a two-wire RS-485 line at the far end: every request is read back to its
/// sender (the echo), followed 50 ms later (a device's turnaround, long enough for
/// the line to fall quiet in between) by `reply` when there is one. Returns the
/// requests seen once the line has been quiet for a second.
fn rs485_line(far: &Port, reply: Option<Vec<u8>>) -> std::thread::JoinHandle<Vec<Vec<u8>>> {
    let port = far.try_clone().unwrap();
    std::thread::spawn(move || {
        let mut seen = vec![];
        while let Some(req) = read_request(&port, Duration::from_secs(1)) {
            write_all(&port, &req);
            if let Some(reply) = &reply {
                std::thread::sleep(Duration::from_millis(50));
                write_all(&port, reply);
            }
            seen.push(req);
        }
        seen
    })
}

#[tokio::test(flavor = "current_thread")]
async fn rs485_drops_its_own_echo_and_takes_the_reply() {
    let p = pty();
    let line = rs485_line(&p.far, Some(identity_reply()));
    let mut c = Client::new(open(&format!("rs485:{}?baud=1200", p.path)).unwrap());
    let d = c.resolve(&DeviceRef::Poll(1)).await.unwrap();
    assert_eq!(
        d.identity.device_id.get(),
        0xFF00FF,
        "0xFF data bytes arrive once each"
    );
    assert_eq!(d.unique_id().to_string(), "1A1AFF00FF");
    assert_eq!(
        c.stats().retries,
        0,
        "the echo was not taken for a reply that went wrong"
    );
    drop(c);
    assert_eq!(
        line.join().unwrap().len(),
        1,
        "one request, answered at once"
    );
}

#[tokio::test(flavor = "current_thread")]
async fn rs485_echo_alone_is_no_reply_not_a_stranger_on_the_line() {
    let p = pty();
    let line = rs485_line(&p.far, None);
    let mut c = Client::new(open(&format!("rs485:{}?baud=19200", p.path)).unwrap());
    match c.resolve(&DeviceRef::Poll(1)).await {
        Err(HostError::NoReply { attempts: 4, .. }) => {}
        other => panic!("{other:?}"),
    }
    drop(c);
    assert_eq!(line.join().unwrap().len(), 4);
}

#[tokio::test(flavor = "current_thread")]
async fn a_serial_port_reads_ff_bytes_and_look_alike_marks_as_sent() {
    let p = pty();
    let mut t = open(&format!("serial:{}", p.path)).unwrap();
    // The port is set to mark damaged characters, and a pseudo-terminal honours it.
    let checks = hart_serial::input_checks(&p.slave).unwrap();
    assert!(checks.marked, "PARMRK set");
    assert!(checks.parity_checked, "INPCK set");
    assert!(!checks.ignored, "IGNPAR clear");
    // Data that looks like a mark is data: the line discipline doubles each 0xFF.
    let sent = [0xFF, 0x00, 0x41, 0xFF, 0xFF, 0x7E, 0xFF];
    write_all(&p.far, &sent);
    let mut got: Vec<RxChar> = vec![];
    let deadline = t.now() + 2_000_000;
    while got.len() < sent.len() && t.now() < deadline {
        got.extend(t.recv_flagged(deadline).await.unwrap());
    }
    assert_eq!(got.iter().map(|c| c.byte).collect::<Vec<_>>(), sent);
    assert!(got.iter().all(|c| c.flags == UartFlags::OK));
    assert_eq!(t.carrier(), None, "no carrier detect unless asked for");
}

#[test]
fn carrier_dcd_on_a_port_without_modem_lines_says_to_leave_it_out() {
    let p = pty();
    let e = open(&format!("serial:{}?carrier=dcd", p.path))
        .err()
        .unwrap();
    assert!(
        e.contains("carrier=dcd") && e.contains(&p.path) && e.contains("leave out"),
        "{e}"
    );
}

/// A device that answers each request with the next scripted reply, HOLD after the
/// request, in virtual time; with UART flags on chosen reply characters and a
/// carrier-detect line that follows a schedule.
struct Line {
    now: Micros,
    replies: Vec<Vec<u8>>,
    /// Per reply, the index of a character received with a parity error.
    damaged: Vec<Option<usize>>,
    pending: Vec<RxChar>,
    /// (time, bytes) of every request.
    sent: Vec<(Micros, Vec<u8>)>,
    /// When each reply finished arriving.
    reply_ends: Vec<Micros>,
    carrier: fn(&Line) -> Option<bool>,
}

impl Line {
    fn new(replies: Vec<Vec<u8>>, damaged: Vec<Option<usize>>) -> Self {
        Line {
            now: 0,
            replies,
            damaged,
            pending: vec![],
            sent: vec![],
            reply_ends: vec![],
            carrier: |_| None,
        }
    }
}

impl Transport for Line {
    fn profile(&self) -> TimingProfile {
        TimingProfile::fsk()
    }
    fn now(&self) -> Micros {
        self.now
    }
    async fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        assert!(self.now < 60_000_000, "the master stopped making progress");
        let ct = self.profile().char_time;
        self.sent.push((self.now, bytes.to_vec()));
        self.now += bytes.len() as Micros * ct;
        let k = self.sent.len() - 1;
        if let Some(reply) = self.replies.get(k) {
            let start = self.now + self.profile().hold;
            let bad = self.damaged.get(k).copied().flatten();
            self.pending = reply
                .iter()
                .enumerate()
                .map(|(i, &byte)| RxChar {
                    byte,
                    flags: if bad == Some(i) {
                        PARITY
                    } else {
                        UartFlags::OK
                    },
                    at: start + (i as Micros + 1) * ct,
                })
                .collect();
            self.reply_ends.push(self.pending.last().unwrap().at);
        }
        Ok(())
    }
    async fn recv(&mut self, deadline: Micros) -> io::Result<Vec<(u8, Micros)>> {
        let chars = self.recv_flagged(deadline).await?;
        Ok(chars.into_iter().map(|c| (c.byte, c.at)).collect())
    }
    async fn recv_flagged(&mut self, deadline: Micros) -> io::Result<Vec<RxChar>> {
        assert!(self.now < 60_000_000, "the master stopped making progress");
        if self.pending.first().is_some_and(|c| c.at <= deadline) {
            let out = std::mem::take(&mut self.pending);
            self.now = self.now.max(out.last().unwrap().at);
            return Ok(out);
        }
        self.now = self.now.max(deadline);
        Ok(vec![])
    }
    fn carrier(&mut self) -> Option<bool> {
        (self.carrier)(self)
    }
    fn describe(&self) -> String {
        "serial scripted line at 1200 bit/s".into()
    }
}

/// A HART 5 ACK with 5 preambles: command 0 in a short frame from polling address
/// 0, any other command in a long frame from unique ID 1A1AAD188C.
fn ack(command: u8, data: &[u8]) -> Vec<u8> {
    let mut pdu = if command == 0 {
        vec![0x06, 0x80]
    } else {
        vec![0x86, 0x9A, 0x1A, 0xAD, 0x18, 0x8C]
    };
    pdu.extend([command, data.len() as u8 + 2, 0, 0]);
    pdu.extend_from_slice(data);
    pdu.push(checksum(&pdu));
    let mut out = vec![0xFF; 5];
    out.extend(pdu);
    out
}

fn hart5_identity() -> Vec<u8> {
    vec![254, 0x1A, 0x1A, 5, 5, 1, 1, 0x08, 0, 0xAD, 0x18, 0x8C]
}

#[tokio::test(flavor = "current_thread")]
async fn a_reply_with_a_parity_error_is_damaged_even_when_its_bytes_add_up() {
    let reply = ack(0, &hart5_identity());
    // The response code byte (index 9) arrives with a parity error on every try.
    let mut c = Client::new(Line::new(vec![reply; 4], vec![Some(9); 4]));
    match c.identify(0).await {
        Err(HostError::Communication {
            attempts: 4,
            last_error,
            ..
        }) => assert_ne!(last_error & comm_error::PARITY, 0, "{last_error:#04x}"),
        other => panic!("{other:?}"),
    }
}

#[tokio::test(flavor = "current_thread")]
async fn a_damaged_reply_is_retried() {
    let reply = ack(0, &hart5_identity());
    let mut c = Client::new(Line::new(vec![reply.clone(), reply], vec![Some(12), None]));
    let d = c.identify(0).await.unwrap();
    assert_eq!(d.unique_id().to_string(), "1A1AAD188C");
    assert_eq!(
        c.transport().sent.len(),
        2,
        "asked again after the damaged reply"
    );
}

/// Carrier on for 200 ms after the first reply ends: another station talking.
fn busy_after_first_reply(l: &Line) -> Option<bool> {
    let end = *l.reply_ends.first()?;
    Some(l.now >= end && l.now < end + 200_000)
}

#[tokio::test(flavor = "current_thread")]
async fn the_master_holds_its_request_while_the_carrier_is_on() {
    let replies = vec![ack(0, &hart5_identity()), ack(1, &[6, 0x41, 0x48, 0, 0])];
    let mut line = Line::new(replies.clone(), vec![]);
    line.carrier = busy_after_first_reply;
    let mut c = Client::new(line);
    let d = c.identify(0).await.unwrap();
    c.command(&d, 1, &[]).await.unwrap();
    let l = c.transport();
    assert!(
        l.sent[1].0 >= l.reply_ends[0] + 200_000,
        "second request at {} µs, carrier dropped at {} µs",
        l.sent[1].0,
        l.reply_ends[0] + 200_000
    );
    // Without carrier detect the same request goes out RT2 after the reply.
    let mut c = Client::new(Line::new(replies, vec![]));
    let d = c.identify(0).await.unwrap();
    c.command(&d, 1, &[]).await.unwrap();
    let l = c.transport();
    assert!(l.sent[1].0 < l.reply_ends[0] + 100_000);
}

#[tokio::test(flavor = "current_thread")]
async fn a_carrier_stuck_on_is_ignored_after_sto_of_silence() {
    let replies = vec![ack(0, &hart5_identity()), ack(1, &[6, 0x41, 0x48, 0, 0])];
    let mut line = Line::new(replies, vec![]);
    line.carrier = |_| Some(true);
    let mut c = Client::new(line);
    let d = c.identify(0).await.unwrap();
    assert_eq!(c.command(&d, 1, &[]).await.unwrap().data[0], 6);
    let l = c.transport();
    let sto = TimingProfile::fsk().sto;
    assert!(
        l.sent[1].0 >= l.reply_ends[0] + sto,
        "believed while characters were recent"
    );
    assert!(
        l.sent[1].0 < l.reply_ends[0] + sto + 200_000,
        "then ignored"
    );
    assert_eq!(l.sent.len(), 2);
}
