//! What a station knows about the shared line: the frame being received, the last
//! complete frame and when it ended. Masters and slaves share this view; the token
//! passing rules are decisions on it.

use hart_proto::deframer::{Deframer, DeframerEvent, UartFlags};
use hart_proto::frame::{Address, FrameType, MasterKind};

use crate::timing::{Micros, TimingProfile};

/// The last thing that happened on the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LastFrame {
    /// Nothing yet since power-up.
    None,
    /// A request from `from` to `to`.
    Stx {
        /// Sending master.
        from: MasterKind,
        /// Addressed device.
        to: Address,
    },
    /// A reply to master `to`.
    Ack {
        /// Master the reply belongs to.
        to: MasterKind,
    },
    /// A burst frame granting the line to master `to`.
    Back {
        /// Master whose bit the frame carries.
        to: MasterKind,
    },
    /// Characters that did not form a good frame (noise, collision, damage).
    Noise,
}

/// A station's view of the line.
#[derive(Clone)]
pub struct LineMonitor {
    profile: TimingProfile,
    deframer: Deframer,
    last_char: Option<Micros>,
    last: LastFrame,
    last_end: Micros,
    carrier: bool,
}

impl LineMonitor {
    /// A monitor for `profile`, with the line considered quiet since `now`.
    pub fn new(profile: TimingProfile, now: Micros) -> Self {
        LineMonitor {
            profile,
            deframer: Deframer::default(),
            last_char: None,
            last: LastFrame::None,
            last_end: now,
            carrier: false,
        }
    }

    /// The timing profile.
    pub fn profile(&self) -> &TimingProfile {
        &self.profile
    }

    /// The last complete frame (or noise) and when it ended.
    pub fn last(&self) -> (LastFrame, Micros) {
        (self.last, self.last_end)
    }

    /// Records a frame this station sent itself (stations do not hear their own
    /// transmissions on a half-duplex line).
    pub fn sent(&mut self, frame: LastFrame, end: Micros) {
        self.last = frame;
        self.last_end = end;
        self.last_char = None;
    }

    /// Records the modem's carrier-detect line (for modems that have one, and in the
    /// simulation). While it is on the line is busy, even before the first character
    /// has been received.
    pub fn set_carrier(&mut self, on: bool) {
        self.carrier = on;
    }

    /// True while characters are arriving: a frame is being received, or the last
    /// character ended less than two character times ago (the next one may still come:
    /// one character of silence inside a frame is allowed).
    pub fn busy(&self, now: Micros) -> bool {
        self.deframer.in_frame()
            || self
                .last_char
                .is_some_and(|t| now < t + 2 * self.profile.char_time)
    }

    /// The earliest time the line counts as quiet (absent new characters); `None` while
    /// a frame is being received.
    pub fn quiet_from(&self) -> Option<Micros> {
        if self.carrier || self.deframer.in_frame() {
            None
        } else {
            Some(self.last_char.map_or(0, |t| t + 2 * self.profile.char_time))
        }
    }

    /// When an unfinished frame must be given up for an inter-character gap.
    pub fn gap_deadline(&self) -> Option<Micros> {
        if self.deframer.in_frame() {
            self.last_char
                .map(|t| t + self.profile.char_time + self.profile.gap_limit() + 1)
        } else {
            None
        }
    }

    /// Aborts an unfinished frame once the gap deadline has passed.
    pub fn poll_gap(&mut self, now: Micros, on_event: &mut impl FnMut(DeframerEvent<'_>, Micros)) {
        if self.gap_deadline().is_some_and(|d| now >= d) {
            let end = self.last_char.unwrap_or(now);
            let mut saw_frame = false;
            let mut last = self.last;
            self.deframer.abort(&mut |e| {
                if let DeframerEvent::Frame(f) = &e {
                    last = classify(f.frame_type(), f.address);
                    saw_frame = true;
                }
                on_event(e, end);
            });
            self.last = if saw_frame { last } else { LastFrame::Noise };
            self.last_end = end;
        }
    }

    /// Feeds a character that finished arriving at `now`.
    pub fn receive(
        &mut self,
        byte: u8,
        flags: UartFlags,
        now: Micros,
        on_event: &mut impl FnMut(DeframerEvent<'_>, Micros),
    ) {
        self.poll_gap(now, on_event);
        self.last_char = Some(now);
        let mut last = None;
        self.deframer.push(byte, flags, &mut |e| {
            match &e {
                DeframerEvent::Frame(f) => last = Some(classify(f.frame_type(), f.address)),
                DeframerEvent::Damaged(_) | DeframerEvent::Invalid { .. } => {
                    last = Some(LastFrame::Noise)
                }
                _ => {}
            }
            on_event(e, now);
        });
        if let Some(l) = last {
            self.last = l;
            self.last_end = now;
        } else if !self.deframer.in_frame() {
            // A character outside any frame: noise on the line.
            self.last = LastFrame::Noise;
            self.last_end = now;
        }
    }
}

fn classify(ft: FrameType, address: Address) -> LastFrame {
    match ft {
        FrameType::Stx => LastFrame::Stx {
            from: address.master(),
            to: address,
        },
        FrameType::Ack => LastFrame::Ack {
            to: address.master(),
        },
        FrameType::Back => LastFrame::Back {
            to: address.master(),
        },
    }
}
