//! The data-link tests (`LINK-`): addressing, framing, timing, communication errors.

use hart_host::transport::Transport;
use hart_proto::command::{
    Empty, Identity, LongTag, LoopConfiguration, TagDescriptorDate, TagRequest,
};
use hart_proto::frame::{Address, FrameType, MasterKind, UniqueId};
use hart_proto::wire::{Reader, Wire};
use hart_proto::Request;

use crate::catalog::LinkTest;
use crate::frames::RxFrame;
use crate::probe::Probe;
use crate::runner::{
    cnr, decode, fail, hex_id, na, pass, Outcome, Runner, READ_0, READ_1, READ_13,
};

impl<T: Transport> Runner<'_, '_, T> {
    /// Runs the data-link test `t`.
    pub(crate) async fn link(&mut self, t: LinkTest) -> Outcome {
        match t {
            LinkTest::ShortFrame => self.link_short().await,
            LinkTest::LongFrame => self.link_long().await,
            LinkTest::OtherPollingAddress => self.link_other_poll().await,
            LinkTest::OtherUniqueId => self.link_other_id().await,
            LinkTest::BroadcastTag => self.link_tag(11).await,
            LinkTest::BroadcastLongTag => match self.needs6(t.id()) {
                Some(o) => o,
                None => self.link_tag(21).await,
            },
            LinkTest::MasterBit => self.link_master_bit().await,
            LinkTest::ReplyPreambles => self.link_reply_preambles().await,
            LinkTest::RequestPreambles => self.link_request_preambles().await,
            LinkTest::ReplyDelay => self.link_timing(false).await,
            LinkTest::ReplyGaps => self.link_timing(true).await,
            LinkTest::BadCheckByte => self.link_bad_check().await,
            LinkTest::ParityError => cnr(
                "no transport here can send a character with a parity error (a UART sends what it is given); test with a modem that can force parity",
            ),
            LinkTest::BadDelimiter => self.link_bad_delimiter().await,
            LinkTest::GapInRequest => self.link_gap_in_request().await,
            LinkTest::ReplyCheckBytes => self.link_reply_check_bytes().await,
            LinkTest::BusyWithoutData => self.link_busy_rules(),
        }
    }

    async fn link_short(&mut self) -> Outcome {
        let Some(poll) = self.known_poll().await else {
            return na("the device's polling address is unknown (tested by unique ID, HART 5: no command 7)");
        };
        let req = Probe::<T>::frame(self.dev.preambles, Address::short(poll), &READ_0);
        let ex = self
            .p
            .exchange(
                &format!("command 0, short frame, polling address {poll}"),
                &req,
                true,
            )
            .await;
        let Some(f) = ex.reply() else {
            return fail(format!("no reply to command 0 at polling address {poll}"));
        };
        match f.address {
            Address::Short(s) if s.polling_address == poll => {}
            other => {
                return fail(format!(
                    "the reply is addressed to {}, not to polling address {poll} in a short frame",
                    crate::frames::address_text(&other)
                ))
            }
        }
        if f.response_code != Some(0) {
            return fail(format!("response code {:?}, 0 expected", f.response_code));
        }
        let id = Identity::decode(&mut Reader::new(f.data))
            .ok()
            .map(|i| i.unique_id());
        if id != Some(self.dev.uid) {
            return fail("the identity in the short-frame reply is not the device's");
        }
        pass(format!("answered at polling address {poll}"))
    }

    async fn known_poll(&mut self) -> Option<u8> {
        if let Some(p) = self.dev.poll {
            return Some(p);
        }
        if self.dev.revision < 6 {
            return None;
        }
        let (rc, data, _) = self
            .read(&Request::ReadLoopConfiguration(Empty {}))
            .await
            .ok()?;
        // Learnt once (command 7), used by the tests of other addresses too.
        self.dev.poll = decode::<LoopConfiguration>(&data)
            .filter(|_| rc == 0)
            .map(|c| c.polling_address & 0x3F);
        self.dev.poll
    }

    async fn link_long(&mut self) -> Outcome {
        let ex = self.cmd(&READ_0).await;
        let Some(f) = ex.reply() else {
            return fail("no reply to command 0 at the device's unique ID");
        };
        match f.address {
            Address::Long(l) if l.id == self.dev.uid => {}
            other => {
                return fail(format!(
                    "the reply is addressed to {}, not to the device's unique ID",
                    crate::frames::address_text(&other)
                ))
            }
        }
        if f.response_code != Some(0) {
            return fail(format!("response code {:?}, 0 expected", f.response_code));
        }
        pass(format!("answered at unique ID {}", hex_id(self.dev.uid)))
    }

    async fn link_other_poll(&mut self) -> Outcome {
        let own = self.dev.poll.unwrap_or(0);
        let mut tried = vec![];
        let mut others = vec![];
        for cand in [(own + 33) % 64, (own + 17) % 64, (own + 49) % 64] {
            if cand == own {
                continue;
            }
            let req = Probe::<T>::frame(self.dev.preambles, Address::short(cand), &READ_0);
            let ex = self
                .p
                .exchange(
                    &format!("command 0 at polling address {cand} (not the device's)"),
                    &req,
                    false,
                )
                .await;
            tried.push(cand);
            if let Some(f) = ex.reply() {
                let id = Identity::decode(&mut Reader::new(f.data))
                    .ok()
                    .map(|i| i.unique_id());
                if id == Some(self.dev.uid) || id.is_none() {
                    return fail(format!(
                        "the device answered a request for polling address {cand}"
                    ));
                }
                others.push(cand);
            }
        }
        if others.len() == tried.len() {
            return cnr("other devices answer every polling address tried; test the device alone on its loop");
        }
        pass(format!("silent to polling addresses {tried:?}"))
    }

    async fn link_other_id(&mut self) -> Outcome {
        let b = self.dev.uid.to_bytes();
        let wrong =
            UniqueId::from_bytes([b[0] & 0x3F, b[1], b[2] ^ 0x5A, b[3] ^ 0xA5, b[4] ^ 0x3C]);
        let req = Probe::<T>::frame(self.dev.preambles, Address::long(wrong), &READ_0);
        let ex = self
            .p
            .exchange(
                &format!(
                    "command 0 at unique ID {} (not the device's)",
                    hex_id(wrong)
                ),
                &req,
                false,
            )
            .await;
        match ex.reply() {
            Some(_) => fail(format!("a reply came to unique ID {}", hex_id(wrong))),
            None => pass("silent to another unique ID"),
        }
    }

    async fn link_tag(&mut self, command: u16) -> Outcome {
        // The device's own tag: command 13 (packed, 6 bytes) or 20 (32 bytes), and the
        // request (11 or 21) that asks for it; the other tag differs from it in one bit
        // of its first character.
        let read = if command == 11 {
            READ_13
        } else {
            Request::ReadLongTag(Empty {})
        };
        let (rc, data) = match self.read(&read).await {
            Ok((rc, data, _)) => (rc, data),
            Err(o) => return o,
        };
        let requests = if command == 11 {
            decode::<TagDescriptorDate>(&data).map(|t| {
                let mut other_tag = t.tag;
                other_tag.0[0] ^= 0x04; // raw: one bit of the first character flipped, for a tag not the device's
                (
                    Request::ReadUniqueIdentifierByTag(TagRequest { tag: t.tag }),
                    Request::ReadUniqueIdentifierByTag(TagRequest { tag: other_tag }),
                )
            })
        } else {
            decode::<LongTag>(&data).map(|t| {
                let mut other_tag = t;
                other_tag.long_tag.0[0] ^= 0x04; // raw: one bit of the first character flipped, for a tag not the device's
                (
                    Request::ReadUniqueIdentifierByLongTag(t),
                    Request::ReadUniqueIdentifierByLongTag(other_tag),
                )
            })
        };
        let Some((own, other)) = requests.filter(|_| rc == 0) else {
            return cnr(format!(
                "command {} (to learn the tag) answered response code {rc}",
                read.command()
            ));
        };
        let broadcast = Address::long(UniqueId::BROADCAST);
        let req = Probe::<T>::frame(self.dev.preambles, broadcast, &own);
        let ex = self
            .p
            .exchange(
                &format!("command {command} at the broadcast address with the device's tag"),
                &req,
                true,
            )
            .await;
        let Some(f) = ex.reply() else {
            return fail(format!(
                "no reply to command {command} with the device's own tag"
            ));
        };
        let id = Identity::decode(&mut Reader::new(f.data))
            .ok()
            .map(|i| i.unique_id());
        match id {
            Some(id) if id == self.dev.uid => {}
            Some(id) => {
                return cnr(format!(
                    "device {} answered: another device on the loop has the same tag; give each its own",
                    hex_id(id)
                ))
            }
            None => return fail(format!("the command {command} reply carries no identity")),
        }
        let req = Probe::<T>::frame(self.dev.preambles, broadcast, &other);
        let ex = self
            .p
            .exchange(
                &format!("command {command} at the broadcast address with another tag"),
                &req,
                false,
            )
            .await;
        if ex.reply().is_some() {
            return fail(format!(
                "the device answered command {command} with a tag not its own"
            ));
        }
        pass(format!("command {command} answered for its tag only"))
    }

    async fn link_master_bit(&mut self) -> Outcome {
        for m in [MasterKind::Primary, MasterKind::Secondary] {
            let ex = self.cmd_as(m, &READ_0).await;
            let Some(f) = ex.reply() else {
                return fail(format!("no reply to the {} master", m.name()));
            };
            if f.address.master() != m {
                return fail(format!(
                    "a request from the {} master was answered with the {} master's bit",
                    m.name(),
                    f.address.master().name()
                ));
            }
        }
        pass("the master bit is echoed for both masters")
    }

    async fn link_reply_preambles(&mut self) -> Outcome {
        let Some(stated) = self.dev.identity.min_response_preambles else {
            return na(format!(
                "HART {} devices do not state their reply preambles in command 0",
                self.dev.revision
            ));
        };
        let ex = self.cmd(&READ_0).await;
        let Some(a) = ex.ack() else {
            return fail("no reply to command 0");
        };
        if a.preambles < usize::from(stated) {
            return fail(format!(
                "the reply carries {} preambles; command 0 states {stated}",
                a.preambles
            ));
        }
        pass(format!("{} preambles, {stated} stated", a.preambles))
    }

    async fn link_request_preambles(&mut self) -> Outcome {
        let min = usize::from(self.dev.identity.min_request_preambles);
        let mut notes = vec![];
        for n in [2usize, 5, 20] {
            let req = Probe::<T>::frame(n, self.long(MasterKind::Primary), &READ_0);
            let ex = self
                .p
                .exchange(&format!("command 0 with {n} preambles"), &req, n >= min)
                .await;
            if ex.reply().is_none() {
                if n < min {
                    notes.push(format!(
                        "{n} preambles not answered (below its stated minimum {min})"
                    ));
                } else {
                    return fail(format!("a request with {n} preambles got no reply"));
                }
            }
        }
        let mut s = "requests with 2, 5 and 20 preambles answered".to_string();
        if !notes.is_empty() {
            s = format!("answered from its stated minimum on; {}", notes.join("; "));
        }
        pass(s)
    }

    async fn link_timing(&mut self, gaps: bool) -> Outcome {
        let ct = self.p.char_time;
        // A pseudo-terminal has no bit rate: what the far end writes arrives at once,
        // and the port's timestamps (characters spaced back from the read) would be
        // fiction.
        if self.p.describe().contains("/dev/pts/") {
            return cnr(
                "a pseudo-terminal delivers characters at once, not at the line's bit rate: reply timing cannot be measured on it",
            );
        }
        // Serial ports stamp characters when the read returns: allow for that.
        let slack = if self.p.describe().starts_with("simulated") {
            0
        } else {
            5_000
        };
        let mut worst = 0;
        for i in 1..=3 {
            let ex = self.cmd(if i == 2 { &READ_13 } else { &READ_0 }).await;
            let Some(a) = ex.ack() else {
                return fail("no reply to measure");
            };
            if gaps {
                if a.max_gap > ct + slack {
                    return fail(format!(
                        "a gap of {:.1} ms inside the reply (one character is {:.1} ms)",
                        (a.max_gap + ct) as f64 / 1000.0,
                        ct as f64 / 1000.0
                    ));
                }
                worst = worst.max(a.max_gap);
            } else {
                let delay = a.start.saturating_sub(ex.sent_end);
                if delay > self.p.sto + slack {
                    return fail(format!(
                        "the reply started {:.1} ms after the request; STO is {:.1} ms",
                        delay as f64 / 1000.0,
                        self.p.sto as f64 / 1000.0
                    ));
                }
                worst = worst.max(delay);
            }
        }
        if gaps {
            pass(format!(
                "longest pause between characters {:.1} ms beyond the character time",
                worst as f64 / 1000.0
            ))
        } else {
            pass(format!(
                "replies started at most {:.1} ms after the request",
                worst as f64 / 1000.0
            ))
        }
    }

    async fn link_bad_check(&mut self) -> Outcome {
        // Command 1, harmless if executed, with its check byte inverted.
        let mut req =
            Probe::<T>::frame(self.dev.preambles, self.long(MasterKind::Primary), &READ_1);
        if let Some(last) = req.last_mut() {
            *last ^= 0xFF;
        }
        let ex = self
            .p
            .exchange("command 1 with a bad check byte", &req, true)
            .await;
        let Some(f) = ex.reply() else {
            return fail("no reply: a request for the device with a bad check byte must get the communication-error summary");
        };
        let rc = f.response_code.unwrap_or(0);
        if rc & 0x80 == 0 {
            return fail(format!(
                "answered with response code {rc} and {} data bytes: the command was executed despite the bad check byte",
                f.data.len()
            ));
        }
        if rc & 0x08 == 0 {
            return fail(format!(
                "communication-error summary 0x{rc:02X} without the check-byte bit (0x08)"
            ));
        }
        if !f.data.is_empty() {
            return fail(format!(
                "the communication-error reply carries {} data bytes",
                f.data.len()
            ));
        }
        pass(format!("communication-error summary 0x{rc:02X}, no data"))
    }

    async fn link_bad_delimiter(&mut self) -> Outcome {
        let mut req =
            Probe::<T>::frame(self.dev.preambles, self.long(MasterKind::Primary), &READ_0);
        let pre = self.dev.preambles;
        let Some(&old) = req.get(pre) else {
            return cnr("the request could not be built");
        };
        // Frame type 7 is no frame type; fix the check byte so only the delimiter is wrong.
        req[pre] = (old & !0x07) | 0x07;
        if let Some(last) = req.last_mut() {
            *last ^= old ^ ((old & !0x07) | 0x07);
        }
        let ex = self
            .p
            .exchange("command 0 with an invalid delimiter", &req, false)
            .await;
        match ex
            .frames
            .iter()
            .find(|f| f.frame_type() == Some(FrameType::Ack))
        {
            Some(f) => fail(format!("a reply came: {}", f.summary())),
            None => pass("silent to an invalid delimiter"),
        }
    }

    async fn link_gap_in_request(&mut self) -> Outcome {
        let req = Probe::<T>::frame(self.dev.preambles, self.long(MasterKind::Primary), &READ_0);
        let cut = (self.dev.preambles + 3).min(req.len());
        let pause = self.p.char_time * 3;
        let ex = self
            .p
            .exchange_parts(
                "command 0 with a pause of 3 character times after its third byte",
                &[&req[..cut], &req[cut..]],
                pause,
                false,
            )
            .await;
        match ex
            .frames
            .iter()
            .find(|f| f.frame_type() == Some(FrameType::Ack))
        {
            Some(f) => fail(format!(
                "a reply came to a request with a gap inside: {}",
                f.summary()
            )),
            None => pass("silent to a request with a gap inside"),
        }
    }

    async fn link_reply_check_bytes(&mut self) -> Outcome {
        for req in [READ_0, READ_1, READ_13] {
            let c = req.command();
            let ex = self.cmd(&req).await;
            let Some(f) = ex.reply() else {
                return fail(format!("no reply to command {c}"));
            };
            if !f.checksum_ok() {
                return fail(format!(
                    "the reply to command {c} carries check byte 0x{:02X}; its bytes give 0x{:02X}",
                    f.check_byte, f.expected_check_byte
                ));
            }
        }
        // And every reply the run has seen so far.
        let bad: Vec<&RxFrame> = self
            .p
            .all_frames
            .iter()
            .filter(|f| f.frame_type() == Some(FrameType::Ack))
            .filter(|f| f.frame().is_some_and(|fr| !fr.checksum_ok()))
            .collect();
        if let Some(first) = bad.first() {
            return fail(format!(
                "{} reply(ies) earlier in the run had a wrong check byte, the first: {} ({})",
                bad.len(),
                crate::model::hex(&first.bytes),
                first.summary()
            ));
        }
        pass("every reply's check byte is right")
    }

    fn link_busy_rules(&mut self) -> Outcome {
        let mut seen = 0;
        for f in self.p.all_frames.iter().filter_map(RxFrame::frame) {
            if let Some(rc @ 32..=36) = f.response_code {
                seen += 1;
                if !f.data.is_empty() {
                    return fail(format!(
                        "response code {rc} came with {} data bytes",
                        f.data.len()
                    ));
                }
            }
        }
        if seen == 0 {
            return na("no busy or delayed response occurred during the run");
        }
        pass(format!("{seen} busy/delayed response(s), all without data"))
    }
}
