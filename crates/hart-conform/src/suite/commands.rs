//! The tests of universal and common-practice commands (`CMD-`): reply layouts,
//! writes read back, response codes, what an `--expect` file says.

use hart_host::transport::Transport;
use hart_proto::command::{
    info, CodeUnitValue, DeviceInformation, DynamicVariableAssignments, Empty, FinalAssemblyNumber,
    Identity, LongTag, LoopConfiguration, Message, ReadAdditionalStatusRequest,
    ReadDeviceVariablesRequest, ReadDeviceVariablesResponse, ReadDynamicVariablesResponse,
    ReadPvResponse, ReadVariablesRequest, ReadVariablesResponse, ResetConfigChanged,
    ResponsePreambles, TagDescriptorDate, TransducerInfo, VariableCode,
};
use hart_proto::frame::MasterKind;
use hart_proto::tables;
use hart_proto::types::{DeviceVariableCode, Latin1String, PackedString, UnitCode, U24};
use hart_proto::wire::Wire;
use hart_proto::{decode_response, Request, Response};

use crate::catalog::CommandTest;
use crate::runner::{
    cnr, decode, encoded, fail, na, pass, slots, Outcome, Runner, READ_0, READ_1, READ_12, READ_13,
    WRITE_PROTECTED,
};

/// Device status bits used here.
const CONFIG_CHANGED: u8 = 0x40;
const MORE_STATUS: u8 = 0x10;

impl<T: Transport> Runner<'_, '_, T> {
    /// Runs the command test `t`.
    pub(crate) async fn commands(&mut self, t: CommandTest) -> Outcome {
        let id = t.id();
        match t {
            CommandTest::Layout0 => self.cmd_layout(&READ_0).await,
            CommandTest::Layout1 => self.cmd_layout(&READ_1).await,
            CommandTest::Layout2 => self.cmd_layout(&Request::ReadLoopCurrent(Empty {})).await,
            CommandTest::Layout3 => {
                self.cmd_layout(&Request::ReadDynamicVariables(Empty {}))
                    .await
            }
            CommandTest::Layout12 => self.cmd_layout(&READ_12).await,
            CommandTest::Layout13 => self.cmd_layout(&READ_13).await,
            CommandTest::Layout14 => {
                self.cmd_layout(&Request::ReadPvTransducerInformation(Empty {}))
                    .await
            }
            CommandTest::Layout15 => {
                self.cmd_layout(&Request::ReadDeviceInformation(Empty {}))
                    .await
            }
            CommandTest::Layout16 => {
                self.cmd_layout(&Request::ReadFinalAssemblyNumber(Empty {}))
                    .await
            }
            CommandTest::Layout7 => match self.needs6(id) {
                Some(o) => o,
                None => {
                    self.cmd_layout(&Request::ReadLoopConfiguration(Empty {}))
                        .await
                }
            },
            CommandTest::Layout8 => match self.needs6(id) {
                Some(o) => o,
                None => {
                    self.cmd_layout(&Request::ReadDynamicVariableClassifications(Empty {}))
                        .await
                }
            },
            CommandTest::Layout20 => match self.needs6(id) {
                Some(o) => o,
                None => self.cmd_layout(&Request::ReadLongTag(Empty {})).await,
            },
            CommandTest::Layout9 => match self.needs6(id) {
                Some(o) => o,
                None => {
                    self.cmd_layout(&Request::ReadDeviceVariablesWithStatus(
                        ReadDeviceVariablesRequest { slots: slots(&[0]) },
                    ))
                    .await
                }
            },
            CommandTest::AdditionalStatus => self.cmd_48().await,
            CommandTest::WriteMessage => self.readback_message().await,
            CommandTest::WriteTag => self.readback_tag().await,
            CommandTest::WriteFinalAssemblyNumber => self.readback_final_assembly_number().await,
            CommandTest::WriteLongTag => match self.needs6(id) {
                Some(o) => o,
                None => self.readback_long_tag().await,
            },
            CommandTest::ConfigChanged => self.cmd_38().await,
            CommandTest::TooFewDataBytes => self.rc_too_few().await,
            CommandTest::NotImplemented => self.rc_not_implemented().await,
            CommandTest::InvalidSelection => match self.needs6(id) {
                Some(o) => o,
                None => self.rc_invalid_selection().await,
            },
            CommandTest::WriteProtected => self.rc_write_protected().await,
            CommandTest::CommonPractice => self.common_practice().await,
            CommandTest::ResponsePreambles => match self.needs6(id) {
                Some(o) => o,
                None => self.rc_too_large_small().await,
            },
            CommandTest::ExpectCommands => self.expect_commands().await,
            CommandTest::ExpectIdentity => self.expect_identity(),
        }
    }

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
}
