//! The tester's side of the line: sends raw requests and collects what comes back,
//! every wait bounded, every exchange recorded as evidence.

use hart_host::transport::Transport;
use hart_link::Micros;
use hart_proto::frame::{Address, Frame, FrameSpec, FrameType};
use hart_proto::Request;

use crate::frames::{split, Char, RxFrame};
use crate::model::{hex, Evidence};

/// The result of one exchange.
#[derive(Debug, Clone, Default)]
pub struct Exchange {
    /// Frames received, in order.
    pub frames: Vec<RxFrame>,
    /// When the request's last character left (transport clock).
    pub sent_end: Micros,
    /// A transport error, if the exchange failed.
    pub error: Option<String>,
}

impl Exchange {
    /// The first complete reply (ACK), if any.
    pub fn ack(&self) -> Option<&RxFrame> {
        self.frames
            .iter()
            .find(|f| f.complete && f.frame_type() == Some(FrameType::Ack))
    }

    /// The parsed reply, if one came and parses.
    pub fn reply(&self) -> Option<Frame<'_>> {
        self.ack().and_then(RxFrame::frame)
    }

    /// Response code and data of the reply.
    pub fn rc_data(&self) -> Option<(u8, Vec<u8>)> {
        let f = self.reply()?;
        Some((f.response_code?, f.data.to_vec()))
    }
}

/// The prober: a transport, the run's clock origin, and the evidence of the test in
/// progress.
pub struct Probe<'a, T: Transport> {
    t: &'a mut T,
    /// Clock origin of the run (transport clock).
    pub t0: Micros,
    /// Evidence of the test in progress.
    pub evidence: Vec<Evidence>,
    /// Every frame received during the run, for tests that look across the run.
    pub all_frames: Vec<RxFrame>,
    /// Line time used by exchanges, µs.
    pub line_time: Micros,
    /// True when the transport shows character timing (not HART-IP).
    pub timing_visible: bool,
    /// One character time, µs.
    pub char_time: Micros,
    /// The slave time-out, µs.
    pub sto: Micros,
    /// Consecutive exchanges that expected a reply and got none.
    pub silent_streak: u32,
    /// Characters received after a reply ended (a burst frame that followed it),
    /// handed out by the next receive.
    carry: Vec<Char>,
}

impl<'a, T: Transport> Probe<'a, T> {
    /// A prober over `t`.
    pub fn new(t: &'a mut T) -> Self {
        let p = t.profile();
        let timing_visible = p.name != "hart-ip";
        let t0 = t.now();
        Probe {
            t0,
            evidence: vec![],
            all_frames: vec![],
            line_time: 0,
            timing_visible,
            char_time: p.char_time,
            sto: p.sto,
            silent_streak: 0,
            carry: vec![],
            t,
        }
    }

    /// The transport's description.
    pub fn describe(&self) -> String {
        self.t.describe()
    }

    /// The transport clock.
    pub fn now(&self) -> Micros {
        self.t.now()
    }

    /// Receives until `deadline`, returning characters.
    async fn recv_until(&mut self, deadline: Micros) -> Result<Vec<Char>, String> {
        if !self.carry.is_empty() {
            return Ok(std::mem::take(&mut self.carry));
        }
        let got = self
            .t
            .recv_flagged(deadline)
            .await
            .map_err(|e| e.to_string())?;
        Ok(got
            .into_iter()
            .map(|c| Char {
                byte: c.byte,
                damaged: c.flags.any(),
                at: c.at,
            })
            .collect())
    }

    /// Listens for `window` µs (at most `max` µs in all while frames keep coming) and
    /// returns the frames heard: the line should be quiet before a request (a burst
    /// frame may be on its way).
    pub async fn listen(&mut self, window: Micros, max: Micros) -> Vec<RxFrame> {
        if !self.timing_visible {
            // HART-IP: publish messages wait in the transport; nothing to keep clear of.
            let now = self.now();
            let chars = self
                .recv_until(now + window.min(1_000))
                .await
                .unwrap_or_default();
            let frames = split(&chars, self.char_time);
            self.all_frames.extend(frames.iter().cloned());
            return frames;
        }
        let start = self.now();
        let mut chars = vec![];
        loop {
            let now = self.now();
            let deadline = (now + window).min(start + max);
            if now >= start + max {
                break;
            }
            match self.recv_until(deadline).await {
                Ok(c) if !c.is_empty() => chars.extend(c),
                _ => {
                    if self.now() >= deadline {
                        break;
                    }
                }
            }
        }
        let frames = split(&chars, self.char_time);
        self.all_frames.extend(frames.iter().cloned());
        frames
    }

    /// Waits until the line has been quiet for 3 character times (at most 1.5 s).
    pub async fn quiet(&mut self) {
        if self.timing_visible {
            let ct = self.char_time;
            self.listen(3 * ct, 1_500_000).await;
        }
    }

    /// A request frame: `preambles`, STX to `address`, the request `req` (its command
    /// number and data from hart-proto's layouts). Empty when `req` does not encode.
    pub fn frame(preambles: usize, address: Address, req: &Request) -> Vec<u8> {
        match req.to_vec() {
            Ok(data) => Self::request(preambles, address, req.command(), &data),
            Err(_) => vec![],
        }
    }

    /// A request frame: `preambles`, STX to `address`, `command`, raw `data` (for what
    /// no layout makes: a request too short on purpose, a device-specific command).
    pub fn request(preambles: usize, address: Address, command: u16, data: &[u8]) -> Vec<u8> {
        let spec = FrameSpec {
            preambles,
            ..FrameSpec::request(address, command, data)
        };
        let mut buf = vec![0u8; spec.encoded_len()];
        match spec.encode(&mut buf) {
            Ok(n) => {
                buf.truncate(n);
                buf
            }
            Err(_) => vec![],
        }
    }

    /// Sends `parts` (with a pause of `pause` µs between them, for a gap inside a
    /// frame) and listens for the reply: until a whole ACK has arrived, or until STO
    /// plus 20 character times pass with no reply started (a late reply is still seen,
    /// so that the timing test can name it), or a started frame stalls. Records the
    /// exchange as evidence under `what`.
    pub async fn exchange_parts(
        &mut self,
        what: &str,
        parts: &[&[u8]],
        pause: Micros,
        expect_reply: bool,
    ) -> Exchange {
        self.quiet().await;
        let start = self.now();
        let mut error = None;
        for (i, part) in parts.iter().enumerate() {
            if i > 0 && pause > 0 {
                // Let time pass on the line (virtual time advances while waiting).
                let until = self.now() + pause;
                while self.now() < until {
                    if self.recv_until(until).await.is_err() {
                        break;
                    }
                }
            }
            if let Err(e) = self.t.send(part).await {
                error = Some(format!("sending the request: {e}"));
                break;
            }
        }
        let sent_end = self.now();
        let sent: Vec<u8> = parts.concat();
        let ct = self.char_time;
        let mut chars: Vec<Char> = vec![];
        if error.is_none() {
            let first_deadline = sent_end + self.sto + 20 * ct;
            // However a device dribbles, the exchange ends: a frame of 280 characters
            // with gaps of 10 characters after its start is the most this waits for.
            let hard_end = first_deadline + 280 * ct + 2_000_000;
            let mut deadline = first_deadline;
            loop {
                match self.recv_until(deadline.min(hard_end)).await {
                    Err(e) => {
                        error = Some(format!("receiving the reply: {e}"));
                        break;
                    }
                    Ok(c) if c.is_empty() => {
                        if self.t.take_no_reply().is_some() {
                            break;
                        }
                        if self.now() >= deadline.min(hard_end) {
                            break;
                        }
                    }
                    Ok(c) => {
                        chars.extend(c);
                        let frames = split(&chars, ct);
                        if frames
                            .iter()
                            .any(|f| f.complete && f.frame_type() == Some(FrameType::Ack))
                        {
                            break;
                        }
                        if self.timing_visible {
                            if let Some(last) = chars.last() {
                                deadline = deadline.max(last.at + 10 * ct);
                            }
                        }
                    }
                }
            }
        }
        // Characters after the reply belong to what follows it (a burst frame): keep
        // them for the next receive.
        if let Some(end) = split(&chars, ct)
            .iter()
            .find(|f| f.complete && f.frame_type() == Some(FrameType::Ack))
            .map(|f| f.end)
        {
            if let Some(k) = chars.iter().position(|c| c.at > end) {
                self.carry = chars.split_off(k);
            }
        }
        let frames = split(&chars, ct);
        let ex = Exchange {
            frames,
            sent_end,
            error,
        };
        let ack = ex.ack();
        if expect_reply {
            if ack.is_some() {
                self.silent_streak = 0;
            } else {
                self.silent_streak += 1;
            }
        }
        let reply_delay_us = match ack {
            Some(a) if self.timing_visible => Some(a.start.saturating_sub(sent_end)),
            _ => None,
        };
        self.line_time += sent.len() as Micros * ct
            + ex.frames
                .iter()
                .map(|f| f.bytes.len() as Micros * ct)
                .sum::<Micros>();
        self.all_frames.extend(ex.frames.iter().cloned());
        let t0 = self.t0;
        self.evidence.push(Evidence {
            what: what.to_string(),
            sent_hex: hex(&sent),
            sent_start_us: start.saturating_sub(t0),
            sent_end_us: sent_end.saturating_sub(t0),
            received: ex.frames.iter().map(|f| f.seen(t0)).collect(),
            reply_delay_us,
            error: ex.error.clone(),
        });
        ex
    }

    /// Sends one frame and listens for the reply (see [`Probe::exchange_parts`]).
    /// A reply of busy (32) or delayed response initiated or running (33, 34) is
    /// followed by the identical request again, as the rules ask of a master (HART ref
    /// §3.3), every 100 ms for at most 10 s; every try is in the evidence.
    pub async fn exchange(&mut self, what: &str, bytes: &[u8], expect_reply: bool) -> Exchange {
        let mut ex = self.exchange_parts(what, &[bytes], 0, expect_reply).await;
        let start = self.now();
        let mut tries = 1;
        while let Some(rc @ 32..=34) = ex.reply().and_then(|f| f.response_code) {
            if self.now().saturating_sub(start) > 10_000_000 {
                break;
            }
            let until = self.now() + 100_000;
            while self.now() < until {
                if self.recv_until(until).await.is_err() {
                    break;
                }
            }
            tries += 1;
            ex = self
                .exchange_parts(
                    &format!("{what} (again after response code {rc}, try {tries})"),
                    &[bytes],
                    0,
                    expect_reply,
                )
                .await;
        }
        // A HART-IP server answers "delayed response dead" (35) for a request its
        // device never answered on the loop: that is no reply from the device.
        if !self.timing_visible && ex.reply().and_then(|f| f.response_code) == Some(35) {
            ex.frames.clear();
            if let Some(e) = self.evidence.last_mut() {
                e.what
                    .push_str(" (the server's response code 35: no reply from the device)");
            }
            if expect_reply {
                self.silent_streak += 1;
            }
        }
        ex
    }

    /// Records frames heard while only listening as evidence.
    pub fn note_listen(&mut self, what: &str, frames: &[RxFrame], from: Micros, to: Micros) {
        let t0 = self.t0;
        self.evidence.push(Evidence {
            what: what.to_string(),
            sent_hex: String::new(),
            sent_start_us: from.saturating_sub(t0),
            sent_end_us: to.saturating_sub(t0),
            received: frames.iter().map(|f| f.seen(t0)).collect(),
            reply_delay_us: None,
            error: None,
        });
    }
}
