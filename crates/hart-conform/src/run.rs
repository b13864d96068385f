//! Running the catalogue against a device.

use hart_host::transport::Transport;
use hart_link::Micros;
use hart_proto::command::{
    info, BurstCommand, BurstConfiguration, BurstMessageSelect, BurstModeControlRequest,
    BurstPeriod, BurstTrigger, BurstVariables, CodeUnitValue, DeviceInformation,
    DynamicVariableAssignments, Empty, FinalAssemblyNumber, Identity, LongTag, LoopConfiguration,
    Message, ReadAdditionalStatusRequest, ReadDeviceVariablesRequest, ReadDeviceVariablesResponse,
    ReadDynamicVariablesResponse, ReadPvResponse, ReadVariablesRequest, ReadVariablesResponse,
    ResetConfigChanged, ResponsePreambles, TagDescriptorDate, TagRequest, TransducerInfo,
    VariableCode,
};
use hart_proto::frame::{Address, FrameType, MasterKind, UniqueId};
use hart_proto::tables;
use hart_proto::types::{
    hart_nan, BurstModeControl, Classification, DeviceVariableCode, HartTime, Latin1String,
    PackedString, TriggerMode, UnitCode, U24,
};
use hart_proto::wire::{List, Reader, Wire, Writer};
use hart_proto::{decode_response, Request, Response};

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

/// Command 0: identity.
const READ_0: Request = Request::ReadUniqueIdentifier(Empty {});
/// Command 1: primary variable.
const READ_1: Request = Request::ReadPrimaryVariable(Empty {});
/// Command 12: message.
const READ_12: Request = Request::ReadMessage(Empty {});
/// Command 13: tag, descriptor, date.
const READ_13: Request = Request::ReadTagDescriptorDate(Empty {});

/// `data` decoded with the layout `L`, when it decodes.
fn decode<L: Wire>(data: &[u8]) -> Option<L> {
    L::decode(&mut Reader::new(data)).ok()
}

/// The bytes `value` encodes to (empty when it does not encode).
fn encoded<L: Wire>(value: &L) -> Vec<u8> {
    let mut buf = [0u8; 255];
    let mut w = Writer::new(&mut buf);
    match value.encode(&mut w) {
        Ok(()) => w.written().to_vec(),
        Err(_) => vec![],
    }
}

/// A list of device variable codes (a request's slots); codes beyond its room are
/// left out.
fn slots<const N: usize, const MIN: usize>(codes: &[u8]) -> List<DeviceVariableCode, N, MIN> {
    let mut l = List::default();
    for &c in codes {
        let _ = l.push(DeviceVariableCode(c));
    }
    l
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
    let req = Probe::<T>::frame(20, address, &Request::ReadUniqueIdentifier(Empty {}));
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
    async fn cmd(&mut self, req: &Request) -> Exchange {
        self.cmd_as(MasterKind::Primary, req).await
    }

    /// A request to the device from master `m` and its reply.
    async fn cmd_as(&mut self, m: MasterKind, req: &Request) -> Exchange {
        match req.to_vec() {
            Ok(data) => self.cmd_raw_as(m, req.command(), &data).await,
            Err(e) => Exchange {
                error: Some(format!(
                    "command {}: the request does not encode ({e})",
                    req.command()
                )),
                ..Exchange::default()
            },
        }
    }

    /// Raw request data, for what no layout makes on purpose: requests too short for
    /// their command (CMD-101), a command hart-proto does not know (CMD-102) and the
    /// device-specific commands of an `--expect` file (CMD-200).
    async fn cmd_raw(&mut self, command: u16, data: &[u8]) -> Exchange {
        self.cmd_raw_as(MasterKind::Primary, command, data).await
    }

    async fn cmd_raw_as(&mut self, m: MasterKind, command: u16, data: &[u8]) -> Exchange {
        let req = Probe::<T>::request(self.dev.preambles, self.long(m), command, data);
        let what = if data.is_empty() {
            format!("command {command}")
        } else {
            format!("command {command} with data {}", crate::model::hex(data))
        };
        self.p.exchange(&what, &req, true).await
    }

    /// Reads with `req` and expects a reply: its response code, data and device status.
    async fn read(&mut self, req: &Request) -> Result<(u8, Vec<u8>, u8), Outcome> {
        let ex = self.cmd(req).await;
        Self::replied(req.command(), ex)
    }

    /// [`Runner::read`] with raw request data (see [`Runner::cmd_raw`]).
    async fn read_raw(&mut self, command: u16, data: &[u8]) -> Result<(u8, Vec<u8>, u8), Outcome> {
        let ex = self.cmd_raw(command, data).await;
        Self::replied(command, ex)
    }

    fn replied(command: u16, ex: Exchange) -> Result<(u8, Vec<u8>, u8), Outcome> {
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
        let (rc, data, _) = self.read(&READ_13).await.ok()?;
        if rc != 0 {
            return None;
        }
        let t = decode::<TagDescriptorDate>(&data)?;
        Some(t.tag.with_str(str::to_string))
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
            "CMD-000" => self.cmd_layout(&READ_0).await,
            "CMD-001" => self.cmd_layout(&READ_1).await,
            "CMD-002" => self.cmd_layout(&Request::ReadLoopCurrent(Empty {})).await,
            "CMD-003" => self.cmd_layout(&Request::ReadDynamicVariables(Empty {})).await,
            "CMD-012" => self.cmd_layout(&READ_12).await,
            "CMD-013" => self.cmd_layout(&READ_13).await,
            "CMD-014" => {
                self.cmd_layout(&Request::ReadPvTransducerInformation(Empty {}))
                    .await
            }
            "CMD-015" => self.cmd_layout(&Request::ReadDeviceInformation(Empty {})).await,
            "CMD-016" => self.cmd_layout(&Request::ReadFinalAssemblyNumber(Empty {})).await,
            "CMD-007" => match needs6(d.id) {
                Some(o) => o,
                None => self.cmd_layout(&Request::ReadLoopConfiguration(Empty {})).await,
            },
            "CMD-008" => match needs6(d.id) {
                Some(o) => o,
                None => {
                    self.cmd_layout(&Request::ReadDynamicVariableClassifications(Empty {}))
                        .await
                }
            },
            "CMD-020" => match needs6(d.id) {
                Some(o) => o,
                None => self.cmd_layout(&Request::ReadLongTag(Empty {})).await,
            },
            "CMD-009" => match needs6(d.id) {
                Some(o) => o,
                None => {
                    self.cmd_layout(&Request::ReadDeviceVariablesWithStatus(
                        ReadDeviceVariablesRequest { slots: slots(&[0]) },
                    ))
                    .await
                }
            },
            "CMD-048" => self.cmd_48().await,
            "CMD-017" => self.readback_message().await,
            "CMD-018" => self.readback_tag().await,
            "CMD-019" => self.readback_final_assembly_number().await,
            "CMD-022" => match needs6(d.id) {
                Some(o) => o,
                None => self.readback_long_tag().await,
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

    // ---- commands ----

    /// Reads with `req` and checks the reply against the command's layout: at least
    /// the layout's minimum length (or the revision's length the catalogue names), then
    /// the codes the layout's fields carry.
    async fn cmd_layout(&mut self, req: &Request) -> Outcome {
        let c = req.command();
        let rev = self.dev.revision;
        let (rc, d, _) = match self.read(req).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        if tables::response_class(rc) == tables::ResponseClass::Error {
            return fail(format!("command {c} answered error response code {rc}"));
        }
        let unit_ok = |u: UnitCode| {
            let u = u.0;
            tables::unit(u).is_some() || tables::is_manufacturer_specific_unit(u) || u == 250
        };
        let len = d.len();
        let bad_len = |want: &str| fail(format!("command {c}: {len} data bytes, {want} expected"));
        // The length the catalogue's rule names, where it says more than the layout's
        // minimum: per revision (0, 15), one slot with its time stamp (9), whole
        // variables (3).
        let want = match c {
            0 => Some(match rev {
                5 => (12, "12 (HART 5)".to_string()),
                6 => (17, "17 (HART 6)".to_string()),
                _ => (22, format!("22 (HART {rev})")),
            }),
            3 if len < 9 || (len - 4) % 5 != 0 && len < 24 => {
                return bad_len("9, 14, 19 or 24");
            }
            9 => Some((13, "13".to_string())),
            15 if rev >= 6 => Some((18, "18".to_string())),
            15 => Some((17, "17".to_string())),
            _ => info(c).map(|i| (i.response_min, i.response_min.to_string())),
        };
        if let Some((min, text)) = want {
            if len < min {
                return bad_len(&text);
            }
        }
        let decoded = match decode_response(c, &d) {
            Some(Ok(r)) => r,
            Some(Err(e)) => return fail(format!("command {c}: the reply does not decode ({e})")),
            None => return cnr(format!("command {c} has no layout in this version")),
        };
        match decoded {
            Response::ReadUniqueIdentifier(id) => {
                if id.expansion_code != 254 {
                    return fail(format!("byte 0 is {}, 254 expected", id.expansion_code));
                }
                if !(5..=7).contains(&id.universal_revision) {
                    return fail(format!(
                        "universal revision {} (5, 6 or 7 expected)",
                        id.universal_revision
                    ));
                }
                if !(2..=20).contains(&id.min_request_preambles) {
                    return fail(format!(
                        "minimum request preambles {} (2-20 expected)",
                        id.min_request_preambles
                    ));
                }
            }
            Response::ReadPrimaryVariable(ReadPvResponse { pv_units, .. })
                if !unit_ok(pv_units) =>
            {
                return fail(format!("units code {} is in no table", pv_units.0));
            }
            Response::ReadDynamicVariables(ReadDynamicVariablesResponse { variables, .. }) => {
                if let Some(v) = variables.as_slice().iter().find(|v| !unit_ok(v.units)) {
                    return fail(format!("units code {} is in no table", v.units.0));
                }
            }
            Response::ReadLoopConfiguration(LoopConfiguration {
                polling_address,
                loop_current_mode,
            }) => {
                if self.dev.poll.is_some_and(|p| p != polling_address & 0x3F) {
                    return fail(format!(
                        "polling address {polling_address} reported, {:?} used",
                        self.dev.poll
                    ));
                }
                if loop_current_mode.0 > 1 {
                    return fail(format!(
                        "loop current mode {} (0 or 1 expected)",
                        loop_current_mode.0
                    ));
                }
            }
            Response::ReadDeviceVariablesWithStatus(ReadDeviceVariablesResponse {
                data, ..
            }) => {
                let Some(slot) = data.slots.as_slice().first() else {
                    return bad_len("13");
                };
                if slot.code.0 != 0 {
                    return fail(format!(
                        "slot 0 carries device variable {}, 0 was asked",
                        slot.code.0
                    ));
                }
                if !unit_ok(slot.units) {
                    return fail(format!("units code {} is in no table", slot.units.0));
                }
            }
            Response::ReadTagDescriptorDate(TagDescriptorDate { date, .. }) => {
                let (day, month) = (date.day, date.month);
                if !(1..=31).contains(&day) || !(1..=12).contains(&month) {
                    return fail(format!("date day {day} month {month} is no date"));
                }
            }
            Response::ReadPvTransducerInformation(TransducerInfo { limits_units, .. })
                if !unit_ok(limits_units) =>
            {
                return fail(format!("units code {} is in no table", limits_units.0));
            }
            Response::ReadDeviceInformation(i) => {
                if tables::ALARM_SELECTION.name(i.alarm_selection.0).is_none() {
                    return fail(format!(
                        "alarm selection code {} is not in Common Table 6",
                        i.alarm_selection.0
                    ));
                }
                if tables::TRANSFER_FUNCTION
                    .name(i.transfer_function.0)
                    .is_none()
                {
                    return fail(format!(
                        "transfer function code {} is not in Common Table 3",
                        i.transfer_function.0
                    ));
                }
                if !unit_ok(i.range_units) {
                    return fail(format!(
                        "range units code {} is in no table",
                        i.range_units.0
                    ));
                }
                if tables::WRITE_PROTECT.name(i.write_protect.0).is_none() {
                    return fail(format!(
                        "write protect code {} is not in Common Table 7",
                        i.write_protect.0
                    ));
                }
                if rev >= 6 && i.reserved != 250 {
                    return fail(format!("byte 16 is {}, 250 expected (HART 6+)", i.reserved));
                }
            }
            _ => {}
        }
        pass(format!("response code {rc}, {len} data bytes"))
    }

    async fn cmd_48(&mut self) -> Outcome {
        let (rc0, _, status) = match self.read(&READ_0).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        let _ = rc0;
        let legacy = Request::ReadAdditionalStatus(ReadAdditionalStatusRequest::default());
        let (rc, d, _) = match self.read(&legacy).await {
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

    /// CMD-017: command 17 writes a message, command 12 reads it back.
    async fn readback_message(&mut self) -> Outcome {
        self.write_readback(READ_12, Request::WriteMessage, |_: &Message| {
            [
                "HARTKIT CONFORMANCE TEST",
                // The same bytes with one bit of the first character changed.
                "IARTKIT CONFORMANCE TEST",
            ]
            .map(|text| Message {
                message: PackedString::new(text).unwrap_or_default(),
            })
        })
        .await
    }

    /// CMD-018: command 18 writes the tag (descriptor and date kept), command 13 reads
    /// it back.
    async fn readback_tag(&mut self) -> Outcome {
        self.write_readback(READ_13, Request::WriteTagDescriptorDate, |o| {
            ["CONFORM", "BONFORM"].map(|text| TagDescriptorDate {
                tag: PackedString::new(text).unwrap_or_default(),
                ..*o
            })
        })
        .await
    }

    /// CMD-019: command 19 writes another final assembly number, command 16 reads it
    /// back.
    async fn readback_final_assembly_number(&mut self) -> Outcome {
        self.write_readback(
            Request::ReadFinalAssemblyNumber(Empty {}),
            Request::WriteFinalAssemblyNumber,
            |o: &FinalAssemblyNumber| {
                // Never the same number: the lowest byte's bits change.
                let n = o.final_assembly_number.get() ^ 0x5A;
                let changed = FinalAssemblyNumber {
                    final_assembly_number: U24::new(n).unwrap_or(o.final_assembly_number),
                };
                [changed, changed]
            },
        )
        .await
    }

    /// CMD-022: command 22 writes the long tag, command 20 reads it back.
    async fn readback_long_tag(&mut self) -> Outcome {
        self.write_readback(
            Request::ReadLongTag(Empty {}),
            Request::WriteLongTag,
            |_| {
                ["hartkit-conform", "lartkit-conform"].map(|text| LongTag {
                    long_tag: Latin1String::new(text).unwrap_or_default(),
                })
            },
        )
        .await
    }

    /// Reads a value with `read`, writes another with `write` (the first of `new`'s two
    /// candidates that differs from what the device has), reads it back, and writes the
    /// original back.
    async fn write_readback<L: Wire + PartialEq + Copy + Default>(
        &mut self,
        read: Request,
        write: fn(L) -> Request,
        new: impl Fn(&L) -> [L; 2],
    ) -> Outcome {
        let (r, w) = (read.command(), write(L::default()).command());
        let original = match self.read(&read).await {
            Ok((rc, d, _)) => match decode::<L>(&d).filter(|_| rc == 0) {
                Some(v) => v,
                None => {
                    return fail(format!(
                        "command {r} answered response code {rc} with {} bytes",
                        d.len()
                    ))
                }
            },
            Err(o) => return o,
        };
        let [first, second] = new(&original);
        let new = if first == original { second } else { first };
        let mut verdict = None;
        let ex = self.cmd(&write(new)).await;
        match ex.rc_data() {
            Some((7, _)) => return cnr(WRITE_PROTECTED),
            Some((rc, _)) if tables::response_class(rc) == tables::ResponseClass::Error => {
                verdict = Some(fail(format!("command {w} answered response code {rc}")));
            }
            None => verdict = Some(fail(format!("no reply to command {w}"))),
            Some(_) => {}
        }
        if verdict.is_none() {
            match self.read(&read).await {
                Ok((0, d, _)) if decode::<L>(&d) == Some(new) => {}
                Ok((_, d, _)) => {
                    verdict = Some(fail(format!(
                        "command {r} read back {} instead of what was written, {}",
                        crate::model::hex(&d),
                        crate::model::hex(&encoded(&new))
                    )))
                }
                Err(o) => verdict = Some(o),
            }
        }
        // Restore, and check.
        let ex = self.cmd(&write(original)).await;
        let restored = matches!(ex.rc_data(), Some((rc, _)) if tables::response_class(rc) != tables::ResponseClass::Error);
        let back =
            matches!(self.read(&read).await, Ok((0, d, _)) if decode::<L>(&d) == Some(original));
        if !(restored && back) {
            return fail(format!(
                "the original value could not be restored with command {w}: set it again by hand ({})",
                crate::model::hex(&encoded(&original))
            ));
        }
        verdict.unwrap_or_else(|| {
            pass(format!(
                "command {w} wrote, command {r} read back exactly; original restored"
            ))
        })
    }

    /// Status byte the master `m` sees (from a command 0 reply).
    async fn status_of(&mut self, m: MasterKind) -> Option<u8> {
        let ex = self.cmd_as(m, &READ_0).await;
        ex.reply().and_then(|f| f.device_status)
    }

    async fn reset_38(&mut self, m: MasterKind) -> Option<u8> {
        // HART 7 names the change counter it resets; older revisions send nothing.
        let config_change_counter = if self.dev.revision >= 7 {
            let ex = self.cmd_as(m, &READ_0).await;
            ex.reply()
                .and_then(|f| decode::<Identity>(f.data))
                .and_then(|i| i.config_change_counter)
        } else {
            None
        };
        let req = Request::ResetConfigurationChanged(ResetConfigChanged {
            config_change_counter,
        });
        let ex = self.cmd_as(m, &req).await;
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
        let msg = match self.read(&READ_12).await {
            Ok((rc, d, _)) => match decode::<Message>(&d).filter(|_| rc == 0) {
                Some(m) => m,
                None => return cnr(format!("command 12 answered response code {rc}")),
            },
            Err(o) => return o,
        };
        let ex = self.cmd(&Request::WriteMessage(msg)).await;
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
            // Deliberately without the data the command needs.
            let ex = self.cmd_raw(c, &[]).await;
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
        // 127 has no layout: sent raw, on purpose.
        let (rc, d, _) = match self.read_raw(127, &[]).await {
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
        // 255 is no device variable code, on purpose.
        let req = Request::ReadDeviceVariablesWithStatus(ReadDeviceVariablesRequest {
            slots: slots(&[255]),
        });
        let (rc, _, _) = match self.read(&req).await {
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
        let (rc, d, _) = match self.read(&Request::ReadDeviceInformation(Empty {})).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        let Some(info) = decode::<DeviceInformation>(&d).filter(|_| rc == 0) else {
            return cnr("command 15 (write-protect code) did not answer");
        };
        if info.write_protect.0 != 1 {
            return na(format!(
                "the device is not write protected (code {})",
                info.write_protect.0
            ));
        }
        let msg = match self.read(&READ_12).await {
            Ok((0, m, _)) => decode::<Message>(&m),
            _ => None,
        };
        let Some(msg) = msg else {
            return cnr("command 12 did not answer");
        };
        let ex = self.cmd(&Request::WriteMessage(msg)).await;
        match ex.rc_data() {
            Some((7, data)) if data.is_empty() => pass("a write answered response code 7"),
            Some((rc, _)) => fail(format!(
                "a write to the write-protected device answered response code {rc}, 7 expected"
            )),
            None => fail("no reply to command 17"),
        }
    }

    async fn common_practice(&mut self) -> Outcome {
        let reads = [
            Request::ReadDeviceVariables(ReadVariablesRequest { slots: slots(&[0]) }),
            Request::ReadDynamicVariableAssignments(Empty {}),
            Request::ReadDeviceVariableInformation(VariableCode {
                code: DeviceVariableCode(0),
            }),
            Request::ReadCommunicationStatistics(Empty {}),
        ];
        let mut answered = vec![];
        for req in reads {
            let c = req.command();
            let (rc, d, _) = match self.read(&req).await {
                Ok(x) => x,
                Err(o) => return o,
            };
            if rc == 64 {
                continue;
            }
            if tables::response_class(rc) == tables::ResponseClass::Error {
                return fail(format!("command {c} answered error response code {rc}"));
            }
            // The layout, and where it allows less than the rule asks: at least one
            // variable (33), all four assignments (50).
            let (whole, min) = match decode_response(c, &d) {
                Some(Ok(Response::ReadDeviceVariables(ReadVariablesResponse { variables }))) => {
                    (!variables.is_empty(), CodeUnitValue::MIN_LEN)
                }
                Some(Ok(Response::ReadDynamicVariableAssignments(a))) => {
                    (a.qv_code.is_some(), DynamicVariableAssignments::MAX_LEN)
                }
                other => (
                    matches!(other, Some(Ok(_))),
                    match c {
                        33 => CodeUnitValue::MIN_LEN,
                        50 => DynamicVariableAssignments::MAX_LEN,
                        _ => info(c).map_or(0, |i| i.response_min),
                    },
                ),
            };
            if !whole {
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
            // Device-specific: no layout, sent as the --expect file gives it.
            let (rc, d, _) = match self.read_raw(c.number, &[]).await {
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
            let req = Request::ReadBurstConfiguration(BurstMessageSelect {
                burst_message: (self.dev.revision >= 7).then_some(m),
            });
            let (rc, d, _) = self.read(&req).await?;
            if rc == 64 {
                return Err(na(
                    "command 105 not implemented: the device has no burst mode",
                ));
            }
            let cfg = match burst_periods(rc, &d) {
                Some(x) => x,
                None => {
                    return Err(fail(format!(
                        "command 105 answered response code {rc} with {} bytes",
                        d.len()
                    )))
                }
            };
            let (c, period, max) = cfg;
            max_msgs = c.max_burst_messages.unwrap_or(max_msgs).clamp(1, 8);
            let (period, max) = (period.as_micros(), max.as_micros());
            if matches!(c.control.0, 1 | 3) {
                out.push((m, c.burst_command(), period, max.max(period)));
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
            let second = HartTime::from_millis(1000);
            let steps = [
                Request::WriteBurstCommandNumber(BurstCommand {
                    command_number: 1,
                    burst_message: Some(0),
                }),
                Request::WriteBurstPeriod(BurstPeriod {
                    burst_message: 0,
                    update_period: second,
                    max_update_period: second,
                }),
                Request::WriteBurstTrigger(BurstTrigger {
                    burst_message: 0,
                    trigger_mode: TriggerMode(0),
                    classification: Classification(0),
                    units: UnitCode(250),
                    trigger_level: hart_nan(),
                }),
                Request::BurstModeControl(BurstModeControlRequest {
                    control: BurstModeControl(1),
                    burst_message: Some(0),
                }),
            ];
            if let Err(o) = self.burst_setup(0, &steps).await {
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
                    crate::model::hex(&original.1)
                )),
            };
        }
        self.burst_check(id, msgs).await
    }

    /// Configures burst message `m` with `steps` (commands 108, 103, 104 and 109).
    async fn burst_setup(&mut self, m: u8, steps: &[Request]) -> Result<(), Outcome> {
        for req in steps {
            let c = req.command();
            let ex = self.cmd(req).await;
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
    async fn burst_restore(&mut self, original: &(BurstConfiguration, Vec<u8>)) -> bool {
        let Some(steps) = restore_steps(&original.0) else {
            return false;
        };
        for req in &steps {
            let _ = self.cmd(req).await;
        }
        matches!(self.burst_config(0).await, Ok((_, d)) if d == original.1)
    }

    async fn burst_check(&mut self, id: &str, msgs: Vec<(u8, u16, Micros, Micros)>) -> Outcome {
        if id == "BURST-003" {
            let ex = self.cmd(&READ_1).await;
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

    /// Command 105 for message `m`: its configuration and reply data, or why not.
    async fn burst_config(&mut self, m: u8) -> Result<(BurstConfiguration, Vec<u8>), Outcome> {
        let req = Request::ReadBurstConfiguration(BurstMessageSelect {
            burst_message: Some(m),
        });
        let (rc, d, _) = self.read(&req).await?;
        if rc == 64 {
            return Err(na(
                "command 105 not implemented: the device has no burst mode",
            ));
        }
        match burst_periods(rc, &d) {
            Some((cfg, _, _)) => Ok((cfg, d)),
            None => Err(fail(format!(
                "command 105 answered response code {rc} with {} bytes",
                d.len()
            ))),
        }
    }

    async fn burst_invalid_message(&mut self) -> Outcome {
        let before = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        // The first message number the device does not have, on purpose.
        let n = before.0.max_burst_messages.unwrap_or(1).max(1);
        let period = HartTime::from_millis(1000);
        let requests = [
            Request::WriteBurstPeriod(BurstPeriod {
                burst_message: n,
                update_period: period,
                max_update_period: period,
            }),
            Request::WriteBurstTrigger(BurstTrigger {
                burst_message: n,
                trigger_mode: TriggerMode(0),
                classification: Classification(0),
                units: UnitCode(250),
                trigger_level: hart_nan(),
            }),
            Request::WriteBurstDeviceVariables(BurstVariables {
                slots: slots(&[250; 8]),
                burst_message: Some(n),
            }),
            Request::WriteBurstCommandNumber(BurstCommand {
                command_number: 1,
                burst_message: Some(n),
            }),
            Request::BurstModeControl(BurstModeControlRequest {
                control: BurstModeControl(0),
                burst_message: Some(n),
            }),
        ];
        for req in requests {
            let c = req.command();
            let ex = self.cmd(&req).await;
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
            Ok(after) if after.1 == before.1 => pass(format!(
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
        let Some(original) = burst_periods(0, &before.1) else {
            return cnr("command 105 carries no update periods to restore");
        };
        let original = (original.1, original.2);
        // 0.3 s = 9600 in 1/32 ms: between the legal 0.5 s and nothing shorter.
        let asked = HartTime(9600);
        let req = Request::WriteBurstPeriod(BurstPeriod {
            burst_message: 0,
            update_period: asked,
            max_update_period: asked,
        });
        let ex = self.cmd(&req).await;
        if matches!(ex.rc_data(), Some((7, _))) {
            return cnr(WRITE_PROTECTED);
        }
        let verdict = match ex.rc_data() {
            Some((8, d)) if decode::<BurstPeriod>(&d).is_some() => {
                let got = decode::<BurstPeriod>(&d).map_or(0, |p| p.update_period.0);
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
        let req = Request::WriteBurstPeriod(BurstPeriod {
            burst_message: 0,
            update_period: original.0,
            max_update_period: original.1,
        });
        let ex = self.cmd(&req).await;
        let restored = matches!(ex.rc_data(), Some((0 | 8, _)));
        let back = matches!(self.burst_config(0).await, Ok((_, d)) if burst_periods(0, &d).map(|p| (p.1, p.2)) == Some(original));
        if !(restored && back) {
            return fail(format!(
                "the burst period of message 0 could not be restored: set it again ({})",
                crate::model::hex(&[encoded(&original.0), encoded(&original.1)].concat())
            ));
        }
        verdict
    }

    /// BURST-007: command 104 with trigger mode 5, which Common Table 33 does not define.
    async fn burst_trigger_mode_refused(&mut self) -> Outcome {
        let request = Request::WriteBurstTrigger(BurstTrigger {
            burst_message: 0,
            trigger_mode: TriggerMode(5),
            classification: Classification(0),
            units: UnitCode(250),
            trigger_level: hart_nan(),
        });
        self.burst_write_refused(request, 13, "trigger mode 5 (not in Common Table 33)")
            .await
    }

    /// BURST-008: command 108 with command 6 (write polling address): a write, which no
    /// device bursts.
    async fn burst_command_refused(&mut self) -> Outcome {
        let request = Request::WriteBurstCommandNumber(BurstCommand {
            command_number: 6,
            burst_message: Some(0),
        });
        self.burst_write_refused(request, 2, "command 6 (a write, not burstable)")
            .await
    }

    /// Sends `request` for burst message 0 and expects response code `want` with
    /// message 0's configuration (command 105) unchanged; a configuration the device did
    /// change is written back (command number, then trigger).
    async fn burst_write_refused(&mut self, request: Request, want: u8, what: &str) -> Outcome {
        let command = request.command();
        let before = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        let Some([_, write_command, _, write_trigger, _]) = restore_steps(&before.0) else {
            return cnr(format!(
                "command 105 answered {} bytes, without the trigger (29 for HART 7): nothing to compare",
                before.1.len()
            ));
        };
        let ex = self.cmd(&request).await;
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
        if after.1 == before.1 {
            return verdict;
        }
        // Put message 0 back as it was: its command first (command 108 may reset the
        // trigger), then its trigger.
        let restored = matches!(self.cmd(&write_command).await.rc_data(), Some((0 | 8, _)))
            && matches!(self.cmd(&write_trigger).await.rc_data(), Some((0 | 8, _)))
            && matches!(self.burst_config(0).await, Ok((_, d)) if d == before.1);
        let changed = format!(
            "command {command} with {what} changed burst message 0 (command 105: {} before, {} after)",
            crate::model::hex(&before.1),
            crate::model::hex(&after.1)
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
            let req = Request::WriteResponsePreambles(ResponsePreambles {
                response_preambles: value,
            });
            let ex = self.cmd(&req).await;
            match ex.rc_data() {
                Some((64, _)) => {
                    verdict = Some(na("command 59 not implemented"));
                    break;
                }
                Some((7, _)) => return cnr(WRITE_PROTECTED),
                Some((rc, _)) if rc == code => {}
                Some((8, d))
                    if decode::<ResponsePreambles>(&d)
                        .is_some_and(|r| (5..=20).contains(&r.response_preambles)) => {}
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
        let req = Request::WriteResponsePreambles(ResponsePreambles {
            response_preambles: original,
        });
        let ex = self.cmd(&req).await;
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
        let req = Request::ReadBurstConfiguration(BurstMessageSelect {
            burst_message: (self.dev.revision >= 7).then_some(0),
        });
        let (rc, d, _) = match self.read(&req).await {
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
            let count = decode::<BurstConfiguration>(&d)
                .and_then(|c| c.max_burst_messages)
                .unwrap_or(1);
            let req = Request::ReadBurstConfiguration(BurstMessageSelect {
                burst_message: Some(count),
            });
            let (rc, _, _) = match self.read(&req).await {
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

/// A command 105 reply with response code `rc` that carries the update periods (22 bytes
/// and more): the configuration, its update period and its maximum update period.
fn burst_periods(rc: u8, data: &[u8]) -> Option<(BurstConfiguration, HartTime, HartTime)> {
    if tables::response_class(rc) == tables::ResponseClass::Error {
        return None;
    }
    let cfg = decode::<BurstConfiguration>(data)?;
    Some((cfg, cfg.update_period?, cfg.max_update_period?))
}

/// The requests that put burst message 0 back as `cfg` shows it: off first, so that
/// nothing bursts half-configured, then its command (108), periods (103), trigger (104)
/// and control (109). `None` when `cfg` lacks one of them (a reply shorter than the 29
/// bytes of HART 7).
fn restore_steps(cfg: &BurstConfiguration) -> Option<[Request; 5]> {
    Some([
        Request::BurstModeControl(BurstModeControlRequest {
            control: BurstModeControl(0),
            burst_message: Some(0),
        }),
        Request::WriteBurstCommandNumber(BurstCommand {
            command_number: cfg.command_number?.0,
            burst_message: Some(0),
        }),
        Request::WriteBurstPeriod(BurstPeriod {
            burst_message: 0,
            update_period: cfg.update_period?,
            max_update_period: cfg.max_update_period?,
        }),
        Request::WriteBurstTrigger(BurstTrigger {
            burst_message: 0,
            trigger_mode: cfg.trigger_mode?,
            classification: cfg.trigger_classification?,
            units: cfg.trigger_units?,
            trigger_level: cfg.trigger_level?,
        }),
        Request::BurstModeControl(BurstModeControlRequest {
            control: cfg.control,
            burst_message: Some(0),
        }),
    ])
}
