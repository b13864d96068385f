//! The analog medium's bookkeeping: which frames reached the station they were for.
//!
//! The line itself runs in [`crate::bus`] ([`crate::bus::Bus::set_analog`]); here the
//! simulation follows each frame from its start to its addressee's demodulator, for
//! [`crate::SimReport::frame_error_rate`].

use hart_link::Micros;
use hart_proto::frame::{Address, Frame, FrameType, MasterKind};

use crate::{Sim, Source, Whom};

/// A frame on the analog line.
struct OnAir {
    src: usize,
    end: Micros,
    /// Delimiter through check byte, to recognise it when a demodulator reports it.
    pdu: Vec<u8>,
    /// The station it is for, if it exists.
    dest: Option<usize>,
    heard: bool,
    done: bool,
}

/// The frames sent on the analog line and not yet counted.
#[derive(Default)]
pub(crate) struct Air {
    on_air: Vec<OnAir>,
}

impl Sim<'_> {
    /// The station a frame is for: the device it addresses, or the master a reply or
    /// burst frame names.
    fn destination(&self, pdu: &[u8]) -> Option<usize> {
        let f = Frame::parse_pdu(pdu).ok()?;
        let master = f.address.master();
        self.whom.iter().position(|w| match *w {
            Whom::Device(poll, id) if f.frame_type() == FrameType::Stx => match f.address {
                Address::Short(a) => a.polling_address == poll,
                Address::Long(a) => a.id == id,
            },
            Whom::Master(role) if f.frame_type() != FrameType::Stx => {
                matches!(
                    (role, master),
                    (Source::Primary, MasterKind::Primary)
                        | (Source::Secondary, MasterKind::Secondary)
                )
            }
            _ => false,
        })
    }

    /// Station `src` started sending `bytes` at `t0`, until `end`.
    pub(crate) fn started(&mut self, src: usize, _t0: Micros, end: Micros, bytes: Vec<u8>) {
        if self.air.is_none() {
            return;
        }
        let pre = bytes.iter().take_while(|&&b| b == 0xFF).count();
        let pdu = bytes[pre..].to_vec();
        let dest = self.destination(&pdu);
        if let Some(air) = &mut self.air {
            air.on_air.push(OnAir {
                src,
                end,
                pdu,
                dest,
                heard: false,
                done: false,
            });
        }
    }

    /// Station `k`'s demodulator decoded `pdu`.
    pub(crate) fn heard(&mut self, k: usize, pdu: &[u8]) {
        if let Some(air) = &mut self.air {
            if let Some(tx) = air
                .on_air
                .iter_mut()
                .find(|o| !o.heard && o.dest == Some(k) && o.pdu == pdu)
            {
                tx.heard = true;
            }
        }
    }

    /// Station `k`'s transmission ended at `t_us`: frames long heard or lost are
    /// counted and leave the list.
    pub(crate) fn ended(&mut self, k: usize, t_us: Micros) {
        let Some(air) = &mut self.air else {
            return;
        };
        if let Some(o) = air.on_air.iter_mut().find(|o| o.src == k && !o.done) {
            o.done = true;
        }
        let horizon = t_us.saturating_sub(2_000_000);
        let mut sent = 0;
        let mut heard = 0;
        air.on_air.retain(|o| {
            let old = o.done && o.end < horizon;
            if old && o.dest.is_some() {
                sent += 1;
                heard += u64::from(o.heard);
            }
            !old
        });
        self.report.frames_sent += sent;
        self.report.frames_heard += heard;
    }

    /// Counts what is still on the list and reads the analog disturbance; the run
    /// ended at `end`.
    pub(crate) fn finish_analog(&mut self, end: Micros) {
        let Some(air) = &mut self.air else {
            return;
        };
        for o in air.on_air.drain(..) {
            // A frame cut off by the end of the run, or with too little time left to
            // be decoded, counts only if it was heard.
            if o.dest.is_some() && ((o.done && o.end + 100_000 <= end) || o.heard) {
                self.report.frames_sent += 1;
                self.report.frames_heard += u64::from(o.heard);
            }
        }
        self.report.analog_disturbance = self.bus.analog_disturbance();
    }
}
