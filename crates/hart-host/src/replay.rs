//! A recorded loop as a transport (`--port replay:FILE.pcapng`): a capture written by
//! `hartkit monitor --pcap` (or any HART-IP capture) played back in virtual time.
//!
//! Everything recorded arrives at its recorded time after the start, so `monitor` shows
//! the loop as it was (without waiting: waiting costs nothing here). A request a host
//! command sends is answered by the reply that followed the same request in the
//! recording (same address, master bit aside, command and data), one turnaround later;
//! a request the recording never saw gets no reply. Once a host has sent a request the
//! recorded traffic is no longer played (the host drives the line). At the end of a
//! recording played to a listener, receiving reports the end of the input.

use std::io;

use hart_link::{Micros, TimingProfile};
use hart_proto::frame::{Address, Frame, FrameType};

use crate::transport::Transport;

/// Preambles put back before each recorded frame (captures keep none).
const PREAMBLES: usize = 5;

/// A capture played back.
pub struct ReplayTransport {
    path: String,
    /// Recorded frames: time after the first (µs) and the frame with its preambles.
    frames: Vec<(Micros, Vec<u8>)>,
    /// Request → the reply that followed it.
    answers: Vec<(Vec<u8>, Vec<u8>)>,
    next: usize,
    now: Micros,
    /// A reply on its way back: each byte with the time it arrives.
    pending: std::collections::VecDeque<(u8, Micros)>,
    /// A host has sent a request: no end of input from then on, only silence.
    driven: bool,
    profile: TimingProfile,
}

/// The request `pdu` stands for, master bit aside: address, command, data.
fn key(pdu: &[u8]) -> Option<(Address, u16, Vec<u8>)> {
    let f = Frame::parse_pdu(pdu).ok()?;
    let address = f
        .address
        .with_master(hart_proto::frame::MasterKind::Primary)
        .with_burst(false);
    Some((address, f.command, f.data.to_vec()))
}

impl ReplayTransport {
    /// Loads `path` (pcapng or pcap; HART-IP on UDP/TCP `port`).
    pub fn open(path: &str, port: u16) -> Result<Self, String> {
        let file = std::fs::File::open(path).map_err(|e| format!("replay:{path}: {e}"))?;
        let captured = hart_capture::read_capture_ports(io::BufReader::new(file), &[port])
            .map_err(|e| format!("replay:{path}: {e}"))?;
        if captured.is_empty() {
            return Err(format!(
                "replay:{path}: no HART frames in this capture (hartkit monitor --pcap makes one)"
            ));
        }
        let t0 = captured[0].time_us;
        let mut frames = vec![];
        let mut answers = vec![];
        let mut last_request: Option<Vec<u8>> = None;
        for c in &captured {
            let mut bytes = vec![0xFF; PREAMBLES];
            bytes.extend_from_slice(&c.bytes);
            frames.push((c.time_us.saturating_sub(t0), bytes));
            let Ok(f) = Frame::parse_pdu(&c.bytes) else {
                continue;
            };
            match f.frame_type() {
                FrameType::Stx => last_request = Some(c.bytes.clone()),
                FrameType::Ack => {
                    if let Some(req) = last_request.take() {
                        let same = |k: Option<(Address, u16, Vec<u8>)>| k.map(|(a, c, _)| (a, c));
                        if same(key(&req)) == same(key(&c.bytes)) {
                            answers.push((req, c.bytes.clone()));
                        }
                    }
                }
                FrameType::Back => {}
            }
        }
        Ok(ReplayTransport {
            path: path.to_string(),
            frames,
            answers,
            next: 0,
            now: 0,
            pending: Default::default(),
            driven: false,
            profile: TimingProfile::fsk(),
        })
    }

    /// Requests the recording can answer.
    pub fn answers(&self) -> usize {
        self.answers.len()
    }
}

impl Transport for ReplayTransport {
    fn profile(&self) -> TimingProfile {
        self.profile
    }

    fn now(&self) -> Micros {
        self.now
    }

    async fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let ct = self.profile.char_time;
        self.now += bytes.len() as Micros * ct;
        // A host drives the line now: the recording is no longer played, only asked.
        self.next = self.frames.len();
        self.driven = true;
        // The frame without its preambles.
        let start = bytes.iter().position(|&b| b != 0xFF).unwrap_or(bytes.len());
        let Some(k) = key(&bytes[start..]) else {
            return Ok(());
        };
        if let Some((_, reply)) = self
            .answers
            .iter()
            .find(|(req, _)| key(req).as_ref() == Some(&k))
        {
            // One turnaround (HOLD), then the reply's characters one by one.
            let first = self.now + self.profile.hold;
            self.pending = std::iter::repeat_n(0xFF, PREAMBLES)
                .chain(reply.iter().copied())
                .enumerate()
                .map(|(i, b)| (b, first + (i as Micros + 1) * ct))
                .collect();
        }
        Ok(())
    }

    async fn recv(&mut self, deadline: Micros) -> io::Result<Vec<(u8, Micros)>> {
        let ct = self.profile.char_time;
        if !self.pending.is_empty() {
            let mut out = vec![];
            while let Some(&(b, at)) = self.pending.front() {
                if at > deadline {
                    break;
                }
                out.push((b, at));
                self.pending.pop_front();
            }
            self.now = out.last().map_or(deadline, |&(_, at)| at);
            return Ok(out);
        }
        if let Some((at, bytes)) = self.frames.get(self.next) {
            if *at <= deadline {
                let at = (*at).max(self.now);
                let n = bytes.len() as Micros;
                let out = bytes
                    .iter()
                    .enumerate()
                    .map(|(i, &b)| (b, at.saturating_sub((n - 1 - i as Micros) * ct)))
                    .collect();
                self.next += 1;
                self.now = at;
                return Ok(out);
            }
        } else if !self.driven {
            return Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                format!("replay:{}: end of the recording", self.path),
            ));
        }
        self.now = self.now.max(deadline);
        Ok(vec![])
    }

    fn describe(&self) -> String {
        format!("replay of {}", self.path)
    }
}
