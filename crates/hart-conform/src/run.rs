//! Running the catalogue against a device.

use hart_host::transport::Transport;
use hart_link::Micros;
use hart_proto::command::Identity;
use hart_proto::frame::{Address, FrameType, MasterKind, UniqueId};
use hart_proto::tables;
use hart_proto::wire::{Reader, Wire};

use crate::catalog::{Needs, TestDef, TESTS};
use crate::expect::Expect;
use crate::frames::RxFrame;
use crate::model::{DeviceSummary, Group, Report, TestResult, Verdict};
use crate::probe::{Exchange, Probe};

/// Which device to test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceAddress {
    /// By polling address (command 0 in a short frame).
    Poll(u8),
    /// By unique ID (command 0 in a long frame).
    UniqueId(UniqueId),
}

/// Settings of a run.
#[derive(Debug, Clone)]
pub struct Options {
    /// The device.
    pub address: DeviceAddress,
    /// Groups to run (empty: all but `phy`, which needs a recording).
    pub groups: Vec<Group>,
    /// Allow tests that write (and restore).
    pub allow_writes: bool,
    /// What the device maker says the device is (`--expect`).
    pub expect: Option<Expect>,
    /// The longest a burst test listens, µs.
    pub burst_listen_max: Micros,
    /// Test-run label for the report (the `-p` target).
    pub target: String,
}

impl Options {
    /// Defaults for the device at `address` on `target`.
    pub fn new(target: &str, address: DeviceAddress) -> Self {
        Options {
            address,
            groups: vec![],
            allow_writes: false,
            expect: None,
            burst_listen_max: 70_000_000,
            target: target.to_string(),
        }
    }
}

/// Device status bits used here.
const CONFIG_CHANGED: u8 = 0x40;
const MORE_STATUS: u8 = 0x10;

/// Why a writing test could not run on a write-protected device.
const WRITE_PROTECTED: &str =
    "the device is write protected (response code 7 to a write); this test needs it writable (CMD-104 checks the protection)";

/// After this many exchanges in a row without the reply they expected, the device is
/// taken to have stopped answering and the remaining tests are not run.
const SILENT_LIMIT: u32 = 4;

type Outcome = (Verdict, String);

fn pass(s: impl Into<String>) -> Outcome {
    (Verdict::Pass, s.into())
}
fn fail(s: impl Into<String>) -> Outcome {
    (Verdict::Fail, s.into())
}
fn na(s: impl Into<String>) -> Outcome {
    (Verdict::NotApplicable, s.into())
}
fn cnr(s: impl Into<String>) -> Outcome {
    (Verdict::CouldNotRun, s.into())
}

/// What the run learnt about the device.
#[derive(Debug, Clone)]
struct Known {
    identity: Identity,
    uid: UniqueId,
    poll: Option<u8>,
    revision: u8,
    preambles: usize,
}

/// A run in progress.
struct Runner<'a, 'b, T: Transport> {
    p: Probe<'a, T>,
    opts: &'b Options,
    dev: Known,
    /// A reason the run stopped (device silent).
    stopped: Option<String>,
}

/// Runs the tests of `opts.groups` (except `phy`) against the device on `t`. Never
/// panics on what the device sends; every wait is bounded.
pub async fn run<T: Transport>(t: &mut T, opts: &Options) -> Report {
    let mut p = Probe::new(t);
    let transport = p.describe();
    let mut warnings = vec![];
    // Listen first: traffic of another master means the loop is in use.
    let heard = p.listen(p.char_time * 45, 600_000).await;
    let foreign = heard.iter().filter(|f| {
        f.frame().is_some_and(|fr| {
            fr.frame_type() == FrameType::Stx
                || (fr.frame_type() == FrameType::Ack
                    && fr.address.master() == MasterKind::Secondary)
        })
    });
    if foreign.count() > 0 {
        warnings.push(
            "the loop is in use: another master's requests or replies were heard before the run; \
             tests that write need --allow-writes and should wait for a maintenance window"
                .to_string(),
        );
    }
    let groups: Vec<Group> = if opts.groups.is_empty() {
        vec![Group::Link, Group::Commands, Group::Burst]
    } else {
        opts.groups.clone()
    };
    let selected: Vec<&TestDef> = TESTS
        .iter()
        .filter(|d| groups.contains(&d.group) && d.group != Group::Phy)
        .collect();
    if groups.contains(&Group::Phy) {
        warnings.push(
            "the phy group needs a recording of the device's signal: run `hartkit conform phy FILE.wav`"
                .to_string(),
        );
    }
    let start = p.now();
    let found = identify(&mut p, opts.address).await;
    let ident_evidence = std::mem::take(&mut p.evidence);
    let (dev, mut results) = match found {
        Ok(dev) => (Some(dev), vec![]),
        Err(why) => {
            let results = selected
                .iter()
                .map(|d| {
                    let (verdict, detail) = cnr(why.clone());
                    TestResult::of(d, verdict, detail, ident_evidence.clone(), 0)
                })
                .collect();
            (None, results)
        }
    };
    let mut summary = None;
    if let Some(dev) = dev {
        summary = Some(DeviceSummary {
            unique_id: hex_id(dev.uid),
            polling_address: dev.poll,
            universal_revision: dev.revision,
            expanded_device_type: dev.identity.expanded_device_type,
            device_id: dev.identity.device_id.get(),
            tag: None,
        });
        let mut r = Runner {
            p,
            opts,
            dev,
            stopped: None,
        };
        for d in &selected {
            let t_start = r.p.now();
            let outcome = r.one(d).await;
            let evidence = std::mem::take(&mut r.p.evidence);
            let took = r.p.now().saturating_sub(t_start);
            results.push(TestResult::of(d, outcome.0, outcome.1, evidence, took));
            if r.stopped.is_none() && r.p.silent_streak >= SILENT_LIMIT {
                r.stopped = Some(format!(
                    "the device stopped answering ({} requests in a row got no reply); check its power and wiring",
                    r.p.silent_streak
                ));
            }
        }
        if let Some(s) = &mut summary {
            s.tag = r.tag().await;
        }
        let end = r.p.now();
        return Report {
            target: opts.target.clone(),
            transport,
            device: summary,
            warnings,
            results,
            duration_us: end.saturating_sub(start),
            line_time_us: r.p.line_time,
        };
    }
    let end = p.now();
    Report {
        target: opts.target.clone(),
        transport,
        device: summary,
        warnings,
        results,
        duration_us: end.saturating_sub(start),
        line_time_us: p.line_time,
    }
}

fn hex_id(id: UniqueId) -> String {
    id.to_bytes().iter().map(|b| format!("{b:02X}")).collect()
}

/// Finds the device: command 0 at its polling address or unique ID.
async fn identify<T: Transport>(p: &mut Probe<'_, T>, a: DeviceAddress) -> Result<Known, String> {
    let (address, what) = match a {
        DeviceAddress::Poll(n) => (
            Address::short(n),
            format!("command 0 at polling address {n}"),
        ),
        DeviceAddress::UniqueId(id) => (
            Address::long(id),
            format!("command 0 at unique ID {}", hex_id(id)),
        ),
    };
    let req = Probe::<T>::request(20, address, 0, &[]);
    let mut last = Exchange::default();
    for attempt in 1..=3 {
        last = p
            .exchange(&format!("{what} (attempt {attempt})"), &req, true)
            .await;
        if last.reply().is_some() {
            break;
        }
        if last.error.is_some() {
            break;
        }
    }
    if let Some(e) = &last.error {
        return Err(format!("{what}: {e}"));
    }
    let Some(f) = last.reply() else {
        let heard = match last.frames.first() {
            None => "nothing came back".to_string(),
            Some(f) if f.complete && f.frame().is_some() => {
                format!("only other traffic was heard: {}", f.summary())
            }
            Some(f) => format!("only an undecodable answer came back: {}", f.summary()),
        };
        return Err(format!(
            "no device answered {what} in 3 tries ({heard}): check the address (--poll/--unique-id), the port, the modem's power and the loop resistor"
        ));
    };
    if f.response_code.is_some_and(|rc| rc & 0x80 != 0) {
        return Err(format!(
            "{what}: the device answered with a communication error (0x{:02X}); the line is damaging requests (check the modem and the loop)",
            f.response_code.unwrap_or(0)
        ));
    }
    let identity = Identity::decode(&mut Reader::new(f.data)).map_err(|e| {
        format!("{what}: the reply's identity does not decode ({e}); this is no HART device or the line damages replies")
    })?;
    let revision = identity.universal_revision;
    let preambles = usize::from(identity.min_request_preambles).clamp(5, 20);
    Ok(Known {
        uid: identity.unique_id(),
        poll: match a {
            DeviceAddress::Poll(n) => Some(n),
            DeviceAddress::UniqueId(_) => None,
        },
        revision,
        preambles,
        identity,
    })
}

impl<T: Transport> Runner<'_, '_, T> {
    fn long(&self, m: MasterKind) -> Address {
        Address::long(self.dev.uid).with_master(m)
    }

    /// A request to the device (long frame, primary master) and its reply.
    async fn cmd(&mut self, command: u16, data: &[u8]) -> Exchange {
        self.cmd_as(MasterKind::Primary, command, data).await
    }

    async fn cmd_as(&mut self, m: MasterKind, command: u16, data: &[u8]) -> Exchange {
        let req = Probe::<T>::request(self.dev.preambles, self.long(m), command, data);
        let what = if data.is_empty() {
            format!("command {command}")
        } else {
            format!("command {command} with data {}", crate::model::hex(data))
        };
        self.p.exchange(&what, &req, true).await
    }

    /// Reads `command` and expects response code 0 (or a warning) with data.
    async fn read(&mut self, command: u16, data: &[u8]) -> Result<(u8, Vec<u8>, u8), Outcome> {
        let ex = self.cmd(command, data).await;
        if let Some(e) = ex.error {
            return Err(cnr(e));
        }
        let Some(f) = ex.reply() else {
            return Err(fail(format!("no reply to command {command}")));
        };
        let rc = f.response_code.unwrap_or(0);
        Ok((rc, f.data.to_vec(), f.device_status.unwrap_or(0)))
    }

    async fn tag(&mut self) -> Option<String> {
        let (rc, data, _) = self.read(13, &[]).await.ok()?;
        if rc != 0 || data.len() < 6 {
            return None;
        }
        let mut out = [0u8; 8];
        let n = hart_proto::types::packed_ascii::unpack(&data[..6], &mut out);
        Some(String::from_utf8_lossy(&out[..n]).trim_end().to_string())
    }

    async fn one(&mut self, d: &TestDef) -> Outcome {
        if let Some(why) = &self.stopped {
            return cnr(why.clone());
        }
        match d.needs {
            Needs::Line if !self.p.timing_visible => {
                return cnr(
                    "the transport (HART-IP) carries whole PDUs and hides the line's characters and timing",
                )
            }
            Needs::Writes if !self.opts.allow_writes => {
                return cnr("this test writes (and restores); run with --allow-writes");
            }
            Needs::Recording => return cnr("needs a recording: hartkit conform phy FILE.wav"),
            _ => {}
        }
        let rev = self.dev.revision;
        let needs6 = |id: &str| -> Option<Outcome> {
            (rev < 6).then(|| na(format!("{id} is a HART 6+ rule; the device is HART {rev}")))
        };
        match d.id {
            "LINK-001" => self.link_short().await,
            "LINK-002" => self.link_long().await,
            "LINK-003" => self.link_other_poll().await,
            "LINK-004" => self.link_other_id().await,
            "LINK-005" => self.link_tag(11).await,
            "LINK-006" => match needs6(d.id) {
                Some(o) => o,
                None => self.link_tag(21).await,
            },
            "LINK-007" => self.link_master_bit().await,
            "LINK-008" => self.link_reply_preambles().await,
            "LINK-009" => self.link_request_preambles().await,
            "LINK-010" => self.link_timing(false).await,
            "LINK-011" => self.link_timing(true).await,
            "LINK-012" => self.link_bad_check().await,
            "LINK-013" => cnr(
                "no transport here can send a character with a parity error (a UART sends what it is given); test with a modem that can force parity",
            ),
            "LINK-014" => self.link_bad_delimiter().await,
            "LINK-015" => self.link_gap_in_request().await,
            "LINK-016" => self.link_reply_check_bytes().await,
            "LINK-017" => self.link_busy_rules(),
            "CMD-000" => self.cmd_layout(0, &[]).await,
            "CMD-001" | "CMD-002" | "CMD-003" | "CMD-012" | "CMD-013" | "CMD-014" | "CMD-015"
            | "CMD-016" => {
                let n: u16 = d.id[4..].parse().unwrap_or(0);
                self.cmd_layout(n, &[]).await
            }
            "CMD-007" | "CMD-008" | "CMD-020" => match needs6(d.id) {
                Some(o) => o,
                None => {
                    let n: u16 = d.id[4..].parse().unwrap_or(0);
                    self.cmd_layout(n, &[]).await
                }
            },
            "CMD-009" => match needs6(d.id) {
                Some(o) => o,
                None => self.cmd_layout(9, &[0]).await,
            },
            "CMD-048" => self.cmd_48().await,
            "CMD-017" => self.write_readback(12, 17, 24).await,
            "CMD-018" => self.write_readback(13, 18, 21).await,
            "CMD-019" => self.write_readback(16, 19, 3).await,
            "CMD-022" => match needs6(d.id) {
                Some(o) => o,
                None => self.write_readback(20, 22, 32).await,
            },
            "CMD-038" => self.cmd_38().await,
            "CMD-101" => self.rc_too_few().await,
            "CMD-102" => self.rc_not_implemented().await,
            "CMD-103" => match needs6(d.id) {
                Some(o) => o,
                None => self.rc_invalid_selection().await,
            },
            "CMD-104" => self.rc_write_protected().await,
            "CMD-105" => self.common_practice().await,
            "CMD-106" => match needs6(d.id) {
                Some(o) => o,
                None => self.rc_too_large_small().await,
            },
            "CMD-200" => self.expect_commands().await,
            "CMD-201" => self.expect_identity(),
            "BURST-001" | "BURST-002" | "BURST-003" => self.burst(d.id).await,
            "BURST-004" => self.burst_105().await,
            "BURST-005" | "BURST-006" | "BURST-007" | "BURST-008" if rev < 7 => {
                na(format!("{} is a HART 7 rule (burst message numbers); the device is HART {rev}", d.id))
            }
            "BURST-005" => self.burst_invalid_message().await,
            "BURST-006" => self.burst_period_adjusted().await,
            "BURST-007" => self.burst_trigger_mode_refused().await,
            "BURST-008" => self.burst_command_refused().await,
            other => cnr(format!("{other} has no implementation in this version")),
        }
    }

    // ---- data link ----

    async fn link_short(&mut self) -> Outcome {
        let Some(poll) = self.known_poll().await else {
            return na("the device's polling address is unknown (tested by unique ID, HART 5: no command 7)");
        };
        let req = Probe::<T>::request(self.dev.preambles, Address::short(poll), 0, &[]);
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
        let (rc, data, _) = self.read(7, &[]).await.ok()?;
        // Learnt once (command 7), used by the tests of other addresses too.
        self.dev.poll = (rc == 0 && !data.is_empty()).then(|| data[0] & 0x3F);
        self.dev.poll
    }

    async fn link_long(&mut self) -> Outcome {
        let ex = self.cmd(0, &[]).await;
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
            let req = Probe::<T>::request(self.dev.preambles, Address::short(cand), 0, &[]);
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
        let req = Probe::<T>::request(self.dev.preambles, Address::long(wrong), 0, &[]);
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
        // The device's own tag: command 13 (packed, 6 bytes) or 20 (32 bytes).
        let (read, len) = if command == 11 { (13, 6) } else { (20, 32) };
        let tag = match self.read(read, &[]).await {
            Ok((0, data, _)) if data.len() >= len => data[..len].to_vec(),
            Ok((rc, _, _)) => {
                return cnr(format!(
                    "command {read} (to learn the tag) answered response code {rc}"
                ))
            }
            Err(o) => return o,
        };
        let broadcast = Address::long(UniqueId::BROADCAST);
        let req = Probe::<T>::request(self.dev.preambles, broadcast, command, &tag);
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
        let mut other = tag.clone();
        if let Some(x) = other.first_mut() {
            *x ^= 0x04;
        }
        let req = Probe::<T>::request(self.dev.preambles, broadcast, command, &other);
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
            let ex = self.cmd_as(m, 0, &[]).await;
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
        let ex = self.cmd(0, &[]).await;
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
            let req = Probe::<T>::request(n, self.long(MasterKind::Primary), 0, &[]);
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
            let ex = self.cmd(if i == 2 { 13 } else { 0 }, &[]).await;
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
            Probe::<T>::request(self.dev.preambles, self.long(MasterKind::Primary), 1, &[]);
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
            Probe::<T>::request(self.dev.preambles, self.long(MasterKind::Primary), 0, &[]);
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
        let req = Probe::<T>::request(self.dev.preambles, self.long(MasterKind::Primary), 0, &[]);
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
        for c in [0u16, 1, 13] {
            let ex = self.cmd(c, &[]).await;
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

    // ---- commands ----

    async fn cmd_layout(&mut self, c: u16, req: &[u8]) -> Outcome {
        let rev = self.dev.revision;
        let (rc, d, _) = match self.read(c, req).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        if tables::response_class(rc) == tables::ResponseClass::Error {
            return fail(format!("command {c} answered error response code {rc}"));
        }
        let unit_ok = |u: u8| {
            tables::unit(u).is_some() || tables::is_manufacturer_specific_unit(u) || u == 250
        };
        let len = d.len();
        let bad_len = |want: &str| fail(format!("command {c}: {len} data bytes, {want} expected"));
        // Lengths of the replies whose length is all there is to check (or that need
        // it before their fields are looked at).
        let min = match c {
            1 => 5,
            2 => 8,
            7 => 2,
            8 => 4,
            9 => 13,
            12 => 24,
            13 => 21,
            14 => 16,
            16 => 3,
            20 => 32,
            _ => 0,
        };
        if len < min {
            return bad_len(&min.to_string());
        }
        match c {
            0 => {
                let want = match rev {
                    5 => 12,
                    6 => 17,
                    _ => 22,
                };
                if len < want {
                    return bad_len(&format!("{want} (HART {rev})"));
                }
                if d[0] != 254 {
                    return fail(format!("byte 0 is {}, 254 expected", d[0]));
                }
                if !(5..=7).contains(&d[4]) {
                    return fail(format!("universal revision {} (5, 6 or 7 expected)", d[4]));
                }
                if !(2..=20).contains(&d[3]) {
                    return fail(format!(
                        "minimum request preambles {} (2-20 expected)",
                        d[3]
                    ));
                }
            }
            1 if !unit_ok(d[0]) => {
                return fail(format!("units code {} is in no table", d[0]));
            }
            3 => {
                if len < 9 || (len - 4) % 5 != 0 && len < 24 {
                    return bad_len("9, 14, 19 or 24");
                }
                for k in 0..((len.min(24) - 4) / 5) {
                    if !unit_ok(d[4 + 5 * k]) {
                        return fail(format!("units code {} is in no table", d[4 + 5 * k]));
                    }
                }
            }
            7 => {
                if self.dev.poll.is_some_and(|p| p != d[0] & 0x3F) {
                    return fail(format!(
                        "polling address {} reported, {:?} used",
                        d[0], self.dev.poll
                    ));
                }
                if d[1] > 1 {
                    return fail(format!("loop current mode {} (0 or 1 expected)", d[1]));
                }
            }
            9 => {
                if d[1] != 0 {
                    return fail(format!(
                        "slot 0 carries device variable {}, 0 was asked",
                        d[1]
                    ));
                }
                if !unit_ok(d[3]) {
                    return fail(format!("units code {} is in no table", d[3]));
                }
            }
            13 => {
                let (day, month) = (d[18], d[19]);
                if !(1..=31).contains(&day) || !(1..=12).contains(&month) {
                    return fail(format!("date day {day} month {month} is no date"));
                }
            }
            14 if !unit_ok(d[3]) => {
                return fail(format!("units code {} is in no table", d[3]));
            }
            15 => {
                let want = if rev >= 6 { 18 } else { 17 };
                if len < want {
                    return bad_len(&want.to_string());
                }
                if tables::ALARM_SELECTION.name(d[0]).is_none() {
                    return fail(format!(
                        "alarm selection code {} is not in Common Table 6",
                        d[0]
                    ));
                }
                if tables::TRANSFER_FUNCTION.name(d[1]).is_none() {
                    return fail(format!(
                        "transfer function code {} is not in Common Table 3",
                        d[1]
                    ));
                }
                if !unit_ok(d[2]) {
                    return fail(format!("range units code {} is in no table", d[2]));
                }
                if tables::WRITE_PROTECT.name(d[15]).is_none() {
                    return fail(format!(
                        "write protect code {} is not in Common Table 7",
                        d[15]
                    ));
                }
                if rev >= 6 && d[16] != 250 {
                    return fail(format!("byte 16 is {}, 250 expected (HART 6+)", d[16]));
                }
            }
            _ => {}
        }
        pass(format!("response code {rc}, {len} data bytes"))
    }

    async fn cmd_48(&mut self) -> Outcome {
        let (rc0, _, status) = match self.read(0, &[]).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        let _ = rc0;
        let (rc, d, _) = match self.read(48, &[]).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        if rc == 64 {
            if status & MORE_STATUS != 0 {
                return fail(
                    "the status says more status is available but command 48 is not implemented",
                );
            }
            return na("command 48 not implemented");
        }
        if tables::response_class(rc) == tables::ResponseClass::Error {
            return fail(format!("command 48 answered error response code {rc}"));
        }
        let min = if self.dev.revision >= 7 { 9 } else { 6 };
        if d.len() < min || d.len() > 25 {
            return fail(format!("{} data bytes, {min}-25 expected", d.len()));
        }
        pass(format!("{} bytes of additional status", d.len()))
    }

    async fn write_readback(&mut self, read: u16, write: u16, len: usize) -> Outcome {
        let original = match self.read(read, &[]).await {
            Ok((0, d, _)) if d.len() >= len => d[..len].to_vec(),
            Ok((rc, d, _)) => {
                return fail(format!(
                    "command {read} answered response code {rc} with {} bytes",
                    d.len()
                ))
            }
            Err(o) => return o,
        };
        // A new value: the message, tag or long tag text changed; a valid date kept.
        let mut new = original.clone();
        match write {
            17 => {
                let _ = hart_proto::types::packed_ascii::pack(
                    "HARTKIT CONFORMANCE TEST",
                    &mut new[..24],
                );
            }
            18 => {
                let _ = hart_proto::types::packed_ascii::pack("CONFORM", &mut new[..6]);
            }
            22 => {
                new.iter_mut().for_each(|b| *b = 0);
                new[..15].copy_from_slice(b"hartkit-conform");
            }
            // The final assembly number (3 bytes): another number.
            _ => {
                if let Some(b) = new.last_mut() {
                    *b ^= 0x5A;
                }
            }
        }
        if new == original {
            new[0] ^= 0x04;
        }
        let mut verdict = None;
        let ex = self.cmd(write, &new).await;
        match ex.rc_data() {
            Some((7, _)) => return cnr(WRITE_PROTECTED),
            Some((rc, _)) if tables::response_class(rc) == tables::ResponseClass::Error => {
                verdict = Some(fail(format!("command {write} answered response code {rc}")));
            }
            None => verdict = Some(fail(format!("no reply to command {write}"))),
            Some(_) => {}
        }
        if verdict.is_none() {
            match self.read(read, &[]).await {
                Ok((0, d, _)) if d.len() >= len && d[..len] == new[..] => {}
                Ok((_, d, _)) => {
                    verdict = Some(fail(format!(
                        "command {read} read back {} instead of what was written, {}",
                        crate::model::hex(&d),
                        crate::model::hex(&new)
                    )))
                }
                Err(o) => verdict = Some(o),
            }
        }
        // Restore, and check.
        let ex = self.cmd(write, &original).await;
        let restored = matches!(ex.rc_data(), Some((rc, _)) if tables::response_class(rc) != tables::ResponseClass::Error);
        let back = matches!(self.read(read, &[]).await, Ok((0, d, _)) if d.len() >= len && d[..len] == original[..]);
        if !(restored && back) {
            return fail(format!(
                "the original value could not be restored with command {write}: set it again by hand ({})",
                crate::model::hex(&original)
            ));
        }
        verdict.unwrap_or_else(|| {
            pass(format!(
                "command {write} wrote, command {read} read back exactly; original restored"
            ))
        })
    }

    /// Status byte the master `m` sees (from a command 0 reply).
    async fn status_of(&mut self, m: MasterKind) -> Option<u8> {
        let ex = self.cmd_as(m, 0, &[]).await;
        ex.reply().and_then(|f| f.device_status)
    }

    async fn reset_38(&mut self, m: MasterKind) -> Option<u8> {
        let data = if self.dev.revision >= 7 {
            let ex = self.cmd_as(m, 0, &[]).await;
            let counter = ex
                .reply()
                .and_then(|f| Identity::decode(&mut Reader::new(f.data)).ok())
                .and_then(|i| i.config_change_counter);
            counter
                .map(|c| c.to_be_bytes().to_vec())
                .unwrap_or_default()
        } else {
            vec![]
        };
        let ex = self.cmd_as(m, 38, &data).await;
        ex.rc_data().map(|(rc, _)| rc)
    }

    async fn cmd_38(&mut self) -> Outcome {
        let (Some(p0), Some(s0)) = (
            self.status_of(MasterKind::Primary).await,
            self.status_of(MasterKind::Secondary).await,
        ) else {
            return fail("no reply to command 0");
        };
        // A write that changes nothing visible: the message written as it is.
        let msg = match self.read(12, &[]).await {
            Ok((0, d, _)) if d.len() >= 24 => d[..24].to_vec(),
            Ok((rc, _, _)) => return cnr(format!("command 12 answered response code {rc}")),
            Err(o) => return o,
        };
        let ex = self.cmd(17, &msg).await;
        if matches!(ex.rc_data(), Some((7, _))) {
            return cnr(WRITE_PROTECTED);
        }
        if !matches!(ex.rc_data(), Some((0, _))) {
            return cnr(
                "command 17 (writing the message as it is, to set the flag) was not accepted",
            );
        }
        let verdict = 'v: {
            let (Some(p1), Some(s1)) = (
                self.status_of(MasterKind::Primary).await,
                self.status_of(MasterKind::Secondary).await,
            ) else {
                break 'v fail("no reply to command 0 after the write");
            };
            if p1 & CONFIG_CHANGED == 0 || s1 & CONFIG_CHANGED == 0 {
                break 'v fail(
                    "a write (command 17) did not set \"configuration changed\" for both masters",
                );
            }
            match self.reset_38(MasterKind::Primary).await {
                Some(0) => {}
                Some(rc) => break 'v fail(format!("command 38 answered response code {rc}")),
                None => break 'v fail("no reply to command 38"),
            }
            let (Some(p2), Some(s2)) = (
                self.status_of(MasterKind::Primary).await,
                self.status_of(MasterKind::Secondary).await,
            ) else {
                break 'v fail("no reply to command 0 after command 38");
            };
            if p2 & CONFIG_CHANGED != 0 {
                break 'v fail(
                    "command 38 from the primary master left \"configuration changed\" set for it",
                );
            }
            if !self.p.timing_visible {
                // Over HART-IP the server is the only master on the loop: the
                // secondary master's flag is out of reach.
                break 'v pass(
                    "set by a write, reset by command 38 (the per-master part needs a line, not HART-IP)",
                );
            }
            if s2 & CONFIG_CHANGED == 0 {
                break 'v fail(
                    "command 38 from the primary master also reset the secondary master's flag",
                );
            }
            pass("set by a write, reset by command 38 for the asking master only")
        };
        // Restore: the flags as they were (the change counter cannot be restored).
        for (m, before) in [(MasterKind::Primary, p0), (MasterKind::Secondary, s0)] {
            if before & CONFIG_CHANGED == 0 {
                let _ = self.reset_38(m).await;
            }
        }
        verdict
    }

    async fn rc_too_few(&mut self) -> Outcome {
        let candidates: &[(u16, &str)] = if self.dev.revision >= 6 {
            &[
                (9, "command 9 with no device variable code"),
                (33, "command 33 with no code"),
            ]
        } else {
            &[
                (33, "command 33 with no code"),
                (54, "command 54 with no code"),
            ]
        };
        for &(c, _what) in candidates {
            let ex = self.cmd(c, &[]).await;
            let Some((rc, data)) = ex.rc_data() else {
                return fail(format!("no reply to command {c} without its data"));
            };
            if rc == 64 {
                continue;
            }
            if rc != 5 {
                return fail(format!(
                    "command {c} without its data answered response code {rc}, 5 expected"
                ));
            }
            if !data.is_empty() {
                return fail(format!(
                    "response code 5 came with {} data bytes",
                    data.len()
                ));
            }
            return pass(format!("command {c} without its data: response code 5"));
        }
        na("the device implements none of the commands this test sends short")
    }

    async fn rc_not_implemented(&mut self) -> Outcome {
        if let Some(e) = &self.opts.expect {
            if e.commands.iter().any(|c| c.number == 127) {
                return na("--expect lists command 127");
            }
        }
        let (rc, d, _) = match self.read(127, &[]).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        if rc != 64 {
            return fail(format!(
                "command 127 answered response code {rc} with {} bytes, 64 expected",
                d.len()
            ));
        }
        pass("command 127: response code 64")
    }

    async fn rc_invalid_selection(&mut self) -> Outcome {
        let (rc, _, _) = match self.read(9, &[255]).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        if rc != 2 {
            return fail(format!(
                "command 9 for device variable 255 answered response code {rc}, 2 expected"
            ));
        }
        pass("command 9 for device variable 255: response code 2")
    }

    async fn rc_write_protected(&mut self) -> Outcome {
        let (rc, d, _) = match self.read(15, &[]).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        if rc != 0 || d.len() < 16 {
            return cnr("command 15 (write-protect code) did not answer");
        }
        if d[15] != 1 {
            return na(format!(
                "the device is not write protected (code {})",
                d[15]
            ));
        }
        let msg = match self.read(12, &[]).await {
            Ok((0, m, _)) if m.len() >= 24 => m[..24].to_vec(),
            _ => return cnr("command 12 did not answer"),
        };
        let ex = self.cmd(17, &msg).await;
        match ex.rc_data() {
            Some((7, data)) if data.is_empty() => pass("a write answered response code 7"),
            Some((rc, _)) => fail(format!(
                "a write to the write-protected device answered response code {rc}, 7 expected"
            )),
            None => fail("no reply to command 17"),
        }
    }

    async fn common_practice(&mut self) -> Outcome {
        // (command, request, minimum reply length)
        let reads: [(u16, Vec<u8>, usize); 4] = [
            (33, vec![0], 6),
            (50, vec![], 4),
            (54, vec![0], 27),
            (95, vec![], 6),
        ];
        let mut answered = vec![];
        for (c, req, min) in reads {
            let (rc, d, _) = match self.read(c, &req).await {
                Ok(x) => x,
                Err(o) => return o,
            };
            if rc == 64 {
                continue;
            }
            if tables::response_class(rc) == tables::ResponseClass::Error {
                return fail(format!("command {c} answered error response code {rc}"));
            }
            if d.len() < min {
                return fail(format!(
                    "command {c}: {} data bytes, at least {min} expected",
                    d.len()
                ));
            }
            answered.push(c);
        }
        if answered.is_empty() {
            return na("the device implements none of commands 33, 50, 54, 95");
        }
        pass(format!("commands {answered:?} answered with their layouts"))
    }

    async fn expect_commands(&mut self) -> Outcome {
        let Some(e) = &self.opts.expect else {
            return na("no --expect file given");
        };
        let list: Vec<_> = e.commands.clone();
        if list.is_empty() {
            return na("the --expect file lists no device-specific commands");
        }
        let mut checked = 0;
        for c in list {
            // Commands that write take data we cannot invent: only reads are sent.
            if c.computed
                .as_deref()
                .is_some_and(|k| k.starts_with("write"))
            {
                continue;
            }
            let (rc, d, _) = match self.read(c.number, &[]).await {
                Ok(x) => x,
                Err(o) => return o,
            };
            if rc != 0 {
                return fail(format!("command {} answered response code {rc}", c.number));
            }
            if let Some(h) = &c.reply_hex {
                let want: Vec<u8> = (0..h.len() / 2)
                    .filter_map(|i| u8::from_str_radix(h.get(2 * i..2 * i + 2)?, 16).ok())
                    .collect();
                if d != want {
                    return fail(format!(
                        "command {} answered {}, the --expect file says {}",
                        c.number,
                        crate::model::hex(&d),
                        crate::model::hex(&want)
                    ));
                }
            }
            checked += 1;
        }
        if checked == 0 {
            return na("the --expect file lists only writing commands");
        }
        pass(format!(
            "{checked} device-specific command(s) answered as expected"
        ))
    }

    fn expect_identity(&mut self) -> Outcome {
        let Some(e) = &self.opts.expect else {
            return na("no --expect file given");
        };
        let id = &self.dev.identity;
        let want = &e.identity;
        let mut diffs = vec![];
        if id.expanded_device_type != want.expanded_device_type {
            diffs.push(format!(
                "expanded device type 0x{:04X} (0x{:04X} expected)",
                id.expanded_device_type, want.expanded_device_type
            ));
        }
        if id.device_revision != want.device_revision {
            diffs.push(format!(
                "device revision {} ({} expected)",
                id.device_revision, want.device_revision
            ));
        }
        if id.universal_revision != want.universal_revision {
            diffs.push(format!(
                "universal revision {} ({} expected)",
                id.universal_revision, want.universal_revision
            ));
        }
        if diffs.is_empty() {
            pass("identity as the --expect file says")
        } else {
            fail(diffs.join("; "))
        }
    }

    // ---- burst ----

    /// Enabled burst messages: (message, command, update period µs, max period µs).
    async fn burst_messages(&mut self) -> Result<Vec<(u8, u16, Micros, Micros)>, Outcome> {
        let mut out = vec![];
        let mut max_msgs = 1u8;
        let mut m = 0u8;
        while m < max_msgs {
            let req: Vec<u8> = if self.dev.revision >= 7 {
                vec![m]
            } else {
                vec![]
            };
            let (rc, d, _) = self.read(105, &req).await?;
            if rc == 64 {
                return Err(na(
                    "command 105 not implemented: the device has no burst mode",
                ));
            }
            if tables::response_class(rc) == tables::ResponseClass::Error || d.len() < 22 {
                return Err(fail(format!(
                    "command 105 answered response code {rc} with {} bytes",
                    d.len()
                )));
            }
            if d.len() >= 12 {
                max_msgs = d[11].clamp(1, 8);
            }
            let control = d[0];
            let command = if d.len() >= 14 {
                u16::from_be_bytes([d[12], d[13]])
            } else {
                u16::from(d[1])
            };
            let t = |b: &[u8]| u64::from(u32::from_be_bytes([b[0], b[1], b[2], b[3]])) * 1000 / 32;
            let (period, max) = if d.len() >= 22 {
                (t(&d[14..18]), t(&d[18..22]))
            } else {
                (0, 0)
            };
            if matches!(control, 1 | 3) {
                out.push((m, command, period, max.max(period)));
            }
            m += 1;
            if self.dev.revision < 7 {
                break;
            }
        }
        Ok(out)
    }

    async fn burst(&mut self, id: &str) -> Outcome {
        let msgs = match self.burst_messages().await {
            Ok(m) => m,
            Err(o) => return o,
        };
        if msgs.is_empty() {
            if !self.opts.allow_writes || self.dev.revision < 7 {
                return na(
                    "no burst message is enabled (with --allow-writes the test enables one for itself on a HART 7 device)",
                );
            }
            // Enable message 0 (command 1 every second) for this test, and put it back.
            let original = match self.burst_config(0).await {
                Ok(d) => d,
                Err(o) => return o,
            };
            if let Err(o) = self
                .burst_setup(0, 1, 32_000, &[0, 0, 250], &[0x7F, 0xA0, 0, 0], 1)
                .await
            {
                self.burst_restore(&original).await;
                return o;
            }
            let outcome = self
                .burst_check(id, vec![(0, 1, 1_000_000, 1_000_000)])
                .await;
            let restored = self.burst_restore(&original).await;
            return match (outcome, restored) {
                ((v, d), true) => (v, format!("{d} (message 0 enabled for the test, then restored)")),
                (_, false) => fail(format!(
                    "burst message 0 could not be put back as it was (command 105: {}); set it again",
                    crate::model::hex(&original)
                )),
            };
        }
        self.burst_check(id, msgs).await
    }

    /// Configures burst message `m` (command, period in 1/32 ms, trigger mode,
    /// classification and units, trigger level bytes, control) with commands 108, 103,
    /// 104 and 109.
    async fn burst_setup(
        &mut self,
        m: u8,
        command: u16,
        period: u32,
        trigger: &[u8; 3],
        level: &[u8; 4],
        control: u8,
    ) -> Result<(), Outcome> {
        let [hi, lo] = command.to_be_bytes();
        let p = period.to_be_bytes();
        let steps: [(u16, Vec<u8>); 4] = [
            (108, vec![hi, lo, m]),
            (103, [vec![m], p.to_vec(), p.to_vec()].concat()),
            (104, [vec![m], trigger.to_vec(), level.to_vec()].concat()),
            (109, vec![control, m]),
        ];
        for (c, req) in steps {
            let ex = self.cmd(c, &req).await;
            match ex.rc_data() {
                Some((7, _)) => return Err(cnr(WRITE_PROTECTED)),
                Some((rc, _)) if tables::response_class(rc) == tables::ResponseClass::Error => {
                    return Err(fail(format!(
                        "command {c} (configuring burst message {m}) answered response code {rc}"
                    )))
                }
                Some(_) => {}
                None => return Err(fail(format!("no reply to command {c}"))),
            }
        }
        Ok(())
    }

    /// Puts burst message 0 back as command 105 showed it; true when it reads back so.
    async fn burst_restore(&mut self, original: &[u8]) -> bool {
        if original.len() < 29 {
            return false;
        }
        let command = u16::from_be_bytes([original[12], original[13]]);
        let period = u32::from_be_bytes([original[14], original[15], original[16], original[17]]);
        let max = &original[18..22];
        // Off first, so that nothing bursts half-configured.
        let _ = self.cmd(109, &[0, 0]).await;
        let _ = self.cmd(108, &[original[12], original[13], 0]).await;
        let _ = self
            .cmd(
                103,
                &[vec![0], period.to_be_bytes().to_vec(), max.to_vec()].concat(),
            )
            .await;
        let _ = self
            .cmd(104, &[vec![0], original[22..29].to_vec()].concat())
            .await;
        let _ = self.cmd(109, &[original[0], 0]).await;
        let _ = command;
        matches!(self.burst_config(0).await, Ok(d) if d == original)
    }

    async fn burst_check(&mut self, id: &str, msgs: Vec<(u8, u16, Micros, Micros)>) -> Outcome {
        if id == "BURST-003" {
            let ex = self.cmd(1, &[]).await;
            return match ex.reply() {
                Some(_) => pass("a request between burst frames was answered"),
                None => fail("a request while the device bursts got no reply"),
            };
        }
        let longest = msgs.iter().map(|m| m.3).max().unwrap_or(0);
        // Our own requests shift a device's burst cadence for a period or two (a burst
        // frame waits for a slot, then the device catches up): measure after that.
        let settle = 2 * longest;
        let listen = longest * 5 + 2_000_000;
        if listen > self.opts.burst_listen_max {
            return cnr(format!(
                "the burst period ({:.0} s) needs {:.0} s of listening, more than the limit of {:.0} s",
                longest as f64 / 1e6,
                listen as f64 / 1e6,
                self.opts.burst_listen_max as f64 / 1e6
            ));
        }
        let from = self.p.now();
        let frames = self.p.listen(listen, listen).await;
        let to = self.p.now();
        self.p.note_listen(
            &format!(
                "listening for burst frames for {:.1} s",
                listen as f64 / 1e6
            ),
            &frames,
            from,
            to,
        );
        let backs: Vec<(Micros, MasterKind, u16)> = frames
            .iter()
            .filter(|f| f.frame_type() == Some(FrameType::Back))
            .filter_map(|f| {
                let fr = f.frame()?;
                match fr.address {
                    Address::Long(l) if l.id == self.dev.uid => {
                        Some((f.start, fr.address.master(), fr.command))
                    }
                    _ => None,
                }
            })
            .collect();
        if backs.len() < 3 {
            return fail(format!(
                "{} burst frame(s) in {:.1} s with {} message(s) enabled",
                backs.len(),
                listen as f64 / 1e6,
                msgs.len()
            ));
        }
        if id == "BURST-002" {
            for w in backs.windows(2) {
                if w[0].1 == w[1].1 {
                    return fail(format!(
                        "two consecutive burst frames for the {} master",
                        w[0].1.name()
                    ));
                }
            }
            return pass(format!(
                "{} burst frames, master bits alternating",
                backs.len()
            ));
        }
        // BURST-001: per message (command), intervals within ±10 % of its period.
        let mut worst = 0.0f64;
        for (_, command, period, max) in &msgs {
            let times: Vec<Micros> = backs
                .iter()
                .filter(|b| b.2 == *command && b.0 >= from + settle)
                .map(|b| b.0)
                .collect();
            if times.len() < 2 {
                return fail(format!(
                    "too few burst frames of command {command} in {:.1} s to measure its period of {:.3} s",
                    listen as f64 / 1e6,
                    *period as f64 / 1e6
                ));
            }
            for w in times.windows(2) {
                let dt = w[1] - w[0];
                let lo = *period as f64 * 0.9;
                let hi = *max as f64 * 1.1;
                if (dt as f64) < lo || (dt as f64) > hi {
                    return fail(format!(
                        "command {command}: burst frames {:.3} s apart; the period is {:.3} s (max {:.3} s), ±10 %",
                        dt as f64 / 1e6,
                        *period as f64 / 1e6,
                        *max as f64 / 1e6
                    ));
                }
                worst = worst.max((dt as f64 - *period as f64).abs() / (*period).max(1) as f64);
            }
        }
        pass(format!(
            "{} burst frames at their periods (worst {:.1} % off)",
            backs.len(),
            worst * 100.0
        ))
    }

    /// Command 105 for message 0: its reply data, or why not.
    async fn burst_config(&mut self, m: u8) -> Result<Vec<u8>, Outcome> {
        let (rc, d, _) = self.read(105, &[m]).await?;
        if rc == 64 {
            return Err(na(
                "command 105 not implemented: the device has no burst mode",
            ));
        }
        if tables::response_class(rc) == tables::ResponseClass::Error || d.len() < 22 {
            return Err(fail(format!(
                "command 105 answered response code {rc} with {} bytes",
                d.len()
            )));
        }
        Ok(d)
    }

    async fn burst_invalid_message(&mut self) -> Outcome {
        let before = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        let n = before.get(11).copied().unwrap_or(1).max(1);
        let nan = hart_proto::types::HART_NAN_BITS.to_be_bytes();
        let requests: [(u16, Vec<u8>); 5] = [
            (
                103,
                [
                    vec![n],
                    32000u32.to_be_bytes().to_vec(),
                    32000u32.to_be_bytes().to_vec(),
                ]
                .concat(),
            ),
            (104, [vec![n, 0, 0, 250], nan.to_vec()].concat()),
            (107, [vec![250; 8], vec![n]].concat()),
            (108, vec![0, 1, n]),
            (109, vec![0, n]),
        ];
        for (c, req) in requests {
            let ex = self.cmd(c, &req).await;
            match ex.rc_data() {
                Some((9, _)) => {}
                Some((7, _)) => return cnr(WRITE_PROTECTED),
                Some((rc, _)) => {
                    return fail(format!(
                        "command {c} for burst message {n} (the device has {n}) answered response code {rc}, 9 expected"
                    ))
                }
                None => return fail(format!("no reply to command {c}")),
            }
        }
        match self.burst_config(0).await {
            Ok(after) if after == before => pass(format!(
                "commands 103-109 for message {n}: response code 9, nothing changed"
            )),
            Ok(_) => fail(
                "burst message 0 changed after requests for a message the device does not have",
            ),
            Err(o) => o,
        }
    }

    async fn burst_period_adjusted(&mut self) -> Outcome {
        let before = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        let original = before[14..22].to_vec();
        // 0.3 s = 9600 in 1/32 ms: between the legal 0.5 s and nothing shorter.
        let asked = 9600u32;
        let req = [
            vec![0],
            asked.to_be_bytes().to_vec(),
            asked.to_be_bytes().to_vec(),
        ]
        .concat();
        let ex = self.cmd(103, &req).await;
        if matches!(ex.rc_data(), Some((7, _))) {
            return cnr(WRITE_PROTECTED);
        }
        let verdict = match ex.rc_data() {
            Some((8, d)) if d.len() >= 9 => {
                let got = u32::from_be_bytes([d[1], d[2], d[3], d[4]]);
                const LEGAL: [u32; 7] = [16_000, 32_000, 64_000, 128_000, 256_000, 512_000, 1_024_000];
                if LEGAL.contains(&got) || (1_920_000..=115_200_000).contains(&got) {
                    pass(format!(
                        "0.3 s answered response code 8 and {:.2} s",
                        f64::from(got) / 32_000.0
                    ))
                } else {
                    fail(format!(
                        "0.3 s adjusted to {:.3} s, which is no legal period",
                        f64::from(got) / 32_000.0
                    ))
                }
            }
            Some((rc, _)) if tables::response_class(rc) == tables::ResponseClass::Error => {
                fail(format!("command 103 with 0.3 s answered error response code {rc}; 8 (adjusted) expected"))
            }
            Some((rc, _)) => fail(format!("command 103 with 0.3 s answered response code {rc}, 8 expected")),
            None => fail("no reply to command 103"),
        };
        // Restore the periods.
        let ex = self.cmd(103, &[vec![0], original.clone()].concat()).await;
        let restored = matches!(ex.rc_data(), Some((0 | 8, _)));
        let back = matches!(self.burst_config(0).await, Ok(d) if d[14..22] == original[..]);
        if !(restored && back) {
            return fail(format!(
                "the burst period of message 0 could not be restored: set it again ({})",
                crate::model::hex(&original)
            ));
        }
        verdict
    }

    /// BURST-007: command 104 with trigger mode 5, which Common Table 33 does not define.
    async fn burst_trigger_mode_refused(&mut self) -> Outcome {
        let nan = hart_proto::types::HART_NAN_BITS.to_be_bytes();
        let request = [vec![0, 5, 0, 250], nan.to_vec()].concat();
        self.burst_write_refused(104, request, 13, "trigger mode 5 (not in Common Table 33)")
            .await
    }

    /// BURST-008: command 108 with command 6 (write polling address): a write, which no
    /// device bursts.
    async fn burst_command_refused(&mut self) -> Outcome {
        self.burst_write_refused(108, vec![0, 6, 0], 2, "command 6 (a write, not burstable)")
            .await
    }

    /// Sends `command` with `request` for burst message 0 and expects response code
    /// `want` with message 0's configuration (command 105) unchanged; a configuration
    /// the device did change is written back (command number, then trigger).
    async fn burst_write_refused(
        &mut self,
        command: u16,
        request: Vec<u8>,
        want: u8,
        what: &str,
    ) -> Outcome {
        let before = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        if before.len() < 29 {
            return cnr(format!(
                "command 105 answered {} bytes, without the trigger (29 for HART 7): nothing to compare",
                before.len()
            ));
        }
        let ex = self.cmd(command, &request).await;
        let verdict = match ex.rc_data() {
            Some((rc, _)) if rc == want => pass(format!(
                "command {command} with {what}: response code {want}"
            )),
            Some((7, _)) => return cnr(WRITE_PROTECTED),
            Some((rc, _)) => fail(format!(
                "command {command} with {what} answered response code {rc}, {want} expected"
            )),
            None => return fail(format!("no reply to command {command}")),
        };
        let after = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        if after == before {
            return verdict;
        }
        // Put message 0 back as it was: its command first (command 108 may reset the
        // trigger), then its trigger.
        let restored = matches!(
            self.cmd(108, &[before[12], before[13], 0]).await.rc_data(),
            Some((0 | 8, _))
        ) && matches!(
            self.cmd(104, &[vec![0], before[22..29].to_vec()].concat())
                .await
                .rc_data(),
            Some((0 | 8, _))
        ) && matches!(self.burst_config(0).await, Ok(d) if d == before);
        let changed = format!(
            "command {command} with {what} changed burst message 0 (command 105: {} before, {} after)",
            crate::model::hex(&before),
            crate::model::hex(&after)
        );
        if restored {
            fail(format!("{changed}; it was written back"))
        } else {
            fail(format!(
                "{changed}; it could not be written back: set its command and trigger again"
            ))
        }
    }

    async fn rc_too_large_small(&mut self) -> Outcome {
        let Some(original) = self.dev.identity.min_response_preambles else {
            return cnr("command 0 does not state the reply preambles to restore");
        };
        let mut verdict = None;
        for (value, code, what) in [(255u8, 3u8, "too large"), (0, 4, "too small")] {
            let ex = self.cmd(59, &[value]).await;
            match ex.rc_data() {
                Some((64, _)) => {
                    verdict = Some(na("command 59 not implemented"));
                    break;
                }
                Some((7, _)) => return cnr(WRITE_PROTECTED),
                Some((rc, _)) if rc == code => {}
                Some((8, d)) if d.first().is_some_and(|&v| (5..=20).contains(&v)) => {}
                Some((rc, d)) => {
                    verdict = Some(fail(format!(
                        "command 59 with {value} preambles answered response code {rc} {}; {code} ({what}) or 8 with 5-20 expected",
                        crate::model::hex(&d)
                    )));
                    break;
                }
                None => {
                    verdict = Some(fail("no reply to command 59"));
                    break;
                }
            }
        }
        // Restore (harmless when nothing changed).
        let ex = self.cmd(59, &[original]).await;
        if !matches!(ex.rc_data(), Some((0 | 64, _))) {
            return fail(format!(
                "the reply preambles could not be restored to {original} with command 59"
            ));
        }
        verdict.unwrap_or_else(|| {
            pass("255 and 0 reply preambles refused or set to the nearest value")
        })
    }

    async fn burst_105(&mut self) -> Outcome {
        let req: Vec<u8> = if self.dev.revision >= 7 {
            vec![0]
        } else {
            vec![]
        };
        let (rc, d, _) = match self.read(105, &req).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        if rc == 64 {
            return na("command 105 not implemented: the device has no burst mode");
        }
        if rc != 0 && rc != 8 {
            return fail(format!(
                "command 105 for message 0 answered response code {rc}"
            ));
        }
        if self.dev.revision >= 7 {
            if d.len() != 29 && d.len() != 27 {
                return fail(format!(
                    "command 105: {} data bytes, 29 (or 27) expected",
                    d.len()
                ));
            }
            let count = d.get(11).copied().unwrap_or(1);
            let (rc, _, _) = match self.read(105, &[count]).await {
                Ok(x) => x,
                Err(o) => return o,
            };
            if rc != 9 {
                return fail(format!(
                    "command 105 for message {count} (the device has {count}) answered response code {rc}, 9 expected"
                ));
            }
            return pass(format!(
                "29-byte configuration; message {count} answered response code 9"
            ));
        }
        pass(format!("command 105: {} data bytes", d.len()))
    }
}
