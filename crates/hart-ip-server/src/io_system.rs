//! The server as a HART 7 I/O system (device profile 68, HART-IP I/O system).
//!
//! Whatever sits behind it, the server answers at polling address 0 and at its own
//! unique ID as a device of its own, and reaches the field devices on its loops (its
//! sub-devices) by their unique IDs, through command 77 (send command to sub-device)
//! and, on a server with one loop, by their polling addresses 1-63. Each loop is a
//! channel of I/O card 0. The addressing rules are in `docs/hart-ip.md`.
//!
//! [`IoSystem::route`] decides where a request frame goes; [`IoSystem::local`]
//! answers the commands addressed to the I/O system itself.

use std::sync::Arc;

use hart_proto::command::{
    self as cmd, AdditionalStatus, AdditionalStatusParts, Identity, LongTag, TagDescriptorDate,
    TagRequest,
};
use hart_proto::frame::{Address, Frame, MasterKind, UniqueId, MAX_PDU_LEN};
use hart_proto::tables::rc;
use hart_proto::types::{
    hart_nan, AlarmSelection, Classification, Date, DeviceId, DeviceProfile, DeviceVariableCode,
    ExtendedStatus, Flags, HardwareRevision, Latin1String, LoopCurrentMode, MilliAmps,
    PackedString, Percent, Seconds, StandardizedStatus2, TransferFunction, UnitCode, WriteProtect,
    U24,
};
use hart_proto::wire::{List, Reader, Wire, Writer};
use hart_proto::Request;
use tokio::sync::Mutex;

pub use hart_poller::{
    Denied, LoopOutcome, LoopRequest, Requester, SubDevice, LOOP_QUEUE, MAX_QUEUE_WAIT,
};

/// The I/O system's own identity (the fixed part; tag, descriptor, message and long
/// tag can be written by hosts and start from these).
#[derive(Debug, Clone)]
pub struct GatewayIdentity {
    /// Expanded device type.
    pub expanded_device_type: u16,
    /// Device ID (24 bits).
    pub device_id: u32,
    /// Manufacturer ID (and private label distributor).
    pub manufacturer_id: u16,
    /// Tag (8 packed characters).
    pub tag: String,
    /// Descriptor (16 packed characters).
    pub descriptor: String,
    /// Long tag (32 Latin-1 characters).
    pub long_tag: String,
    /// Message (32 packed characters).
    pub message: String,
}

impl Default for GatewayIdentity {
    fn default() -> Self {
        GatewayIdentity {
            expanded_device_type: 0x26FF,
            device_id: 0x00_0001,
            manufacturer_id: 0x00F0,
            tag: "HARTGW".into(),
            descriptor: "HARTKIT GATEWAY".into(),
            long_tag: "hartkit HART-IP gateway".into(),
            message: "HARTKIT HART-IP I/O SYSTEM".into(),
        }
    }
}

/// Where a token-passing request goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Route {
    /// To the I/O system itself.
    Local,
    /// To the loop with this index, with this many retries after no reply.
    Loop {
        /// The loop (channel).
        channel: usize,
        /// Retries on the loop ([`LoopRequest::retries`]).
        retries: u8,
    },
    /// Nowhere: no sub-device with that address (answered at once, without the line).
    Nowhere,
}

/// Retries on a loop for a device the server knows (the data link's default).
pub const KNOWN_RETRIES: u8 = 3;
/// Retries on a loop for an address where the server has seen no device.
pub const UNKNOWN_RETRIES: u8 = 1;

/// Command 38: the counter in the request is not the current one.
const CONFIG_CHANGE_COUNTER_MISMATCH: u8 = 9;
/// The answer for a sub-device that did not reply (token-passing requests and command
/// 77): response code 35, "delayed response dead", as WirelessHART gateways and I/O
/// modules answer for a device that is not connected or does not respond. Hosts do
/// not repeat a request answered 35 (they do for 32, 33, 34 and 36).
pub const SUB_DEVICE_NOT_RESPONDING: u8 = rc::DR_DEAD;
/// Command 75: no device at that polling address.
const NO_SUB_DEVICE_FOUND: u8 = 9;
/// Commands 101 and 102: no such burst message.
const INVALID_BURST_MESSAGE: u8 = rc::INVALID_SELECTION;
/// Command 102: no sub-device with that index.
const INVALID_SUB_DEVICE_INDEX: u8 = 9;
/// Commands 103-109 to the I/O system: no such burst message.
const INVALID_BURST_MESSAGE_NUMBER: u8 = 9;
/// Command 103: the update periods were raised (response code 8, a warning).
const UPDATE_TIMES_ADJUSTED: u8 = 8;
/// Command 84: I/O card and channel given for index 0, the I/O system itself ("none").
const NONE: u8 = 251;

/// Burst messages the I/O system offers for commands 101 and 102.
pub const BURST_MESSAGES: usize = 3;

/// One burst message of the I/O system: what it publishes, how often, and whether it
/// runs. With command 102 it publishes a sub-device's reply to `command`.
#[derive(Debug, Clone, Copy)]
struct GatewayBurst {
    /// Burst mode control code: 0 off, 1 (token-passing) or 4 (HART-IP) on.
    control: u8,
    /// The command published (1, 2, 3, 9, 33 or 48).
    command: u16,
    /// Device variable codes for commands 9 and 33 (250: unused).
    slots: [u8; 8],
    /// Update period, 1/32 ms.
    period: u32,
    /// Maximum update period, 1/32 ms.
    max_period: u32,
}

impl Default for GatewayBurst {
    fn default() -> Self {
        GatewayBurst {
            control: 0,
            command: 1,
            slots: [0, 1, 2, 3, 250, 250, 250, 250],
            period: 32_000,
            max_period: 60 * 32_000,
        }
    }
}

/// Commands a burst message of the I/O system may publish.
pub const BURSTABLE: &[u16] = &[1, 2, 3, 9, 33, 48];

/// Shortest update period, 1/32 ms: 50 ms, the fastest HART-IP burst period.
const MIN_PERIOD: u32 = 1_600;

/// What hosts can change in the I/O system, and its status bits.
struct Local {
    tag: PackedString<6>,
    descriptor: PackedString<12>,
    date: Date,
    message: PackedString<24>,
    long_tag: Latin1String<32>,
    final_assembly: u32,
    config_change_counter: u16,
    /// Configuration changed, per master (primary, secondary).
    changed: [bool; 2],
    /// Cold start not yet reported, per master.
    cold: [bool; 2],
    /// Commands 101/102: the sub-device index each burst message publishes (0: the
    /// I/O system itself).
    burst_map: [u16; BURST_MESSAGES],
    /// The I/O system's burst messages (commands 103, 105, 107, 108, 109).
    bursts: [GatewayBurst; BURST_MESSAGES],
    /// The sub-device registry (unique IDs and presence) as the last command 48
    /// reported it; a different one (a device found, gone or back) sets "sub-device
    /// list changed" (standardized status 2, bit 0) until command 48 reads it.
    reported: Vec<(UniqueId, bool)>,
}

/// The I/O system state.
pub struct IoSystem {
    /// The fixed identity.
    pub identity: GatewayIdentity,
    /// The engine that owns the loops.
    pub engine: hart_poller::Engine,
    /// Devices found on the loops (the engine's list).
    pub subs: Arc<Mutex<Vec<SubDevice>>>,
    /// A loop device at polling address 0 answers there instead of the I/O system
    /// (one loop only).
    pub transparent: bool,
    local: std::sync::Mutex<Local>,
}

fn encode(v: &impl Wire) -> Vec<u8> {
    let mut buf = vec![0u8; v.encoded_len()];
    let _ = v.encode(&mut Writer::new(&mut buf));
    buf
}

fn master_index(m: MasterKind) -> usize {
    match m {
        MasterKind::Primary => 0,
        MasterKind::Secondary => 1,
    }
}

impl IoSystem {
    /// An I/O system with `identity` in front of the engine's loops.
    pub fn new(identity: GatewayIdentity, engine: hart_poller::Engine, transparent: bool) -> Self {
        let subs = engine.sub_devices().clone();
        let local = Local {
            tag: PackedString::new(&identity.tag).unwrap_or_default(),
            descriptor: PackedString::new(&identity.descriptor).unwrap_or_default(),
            date: Date::new(2026, 1, 1).unwrap_or_default(),
            message: PackedString::new(&identity.message).unwrap_or_default(),
            long_tag: Latin1String::new(&identity.long_tag).unwrap_or_default(),
            final_assembly: 0,
            config_change_counter: 0,
            changed: [false; 2],
            cold: [true; 2],
            burst_map: [0; BURST_MESSAGES],
            bursts: [GatewayBurst::default(); BURST_MESSAGES],
            reported: vec![],
        };
        IoSystem {
            identity,
            engine,
            subs,
            transparent,
            local: std::sync::Mutex::new(local),
        }
    }

    fn state(&self) -> std::sync::MutexGuard<'_, Local> {
        self.local.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The I/O system's unique ID.
    pub fn unique_id(&self) -> UniqueId {
        UniqueId::new(self.identity.expanded_device_type, self.identity.device_id)
    }

    /// Where a request frame goes (the table in `docs/hart-ip.md`).
    pub async fn route(&self, f: &Frame<'_>) -> Route {
        let single = self.engine.loop_count() == 1;
        let subs = self.subs.lock().await;
        let on_loop = |channel: u8, known: bool| Route::Loop {
            channel: usize::from(channel),
            retries: if known {
                KNOWN_RETRIES
            } else {
                UNKNOWN_RETRIES
            },
        };
        match f.address {
            Address::Long(a) if a.id == self.unique_id() => Route::Local,
            Address::Long(a) if a.id.is_broadcast() => {
                // Commands 11 and 21 find a device by its tag: the I/O system's own,
                // else the sub-device that has it.
                let wanted = Wanted::of(f.command, f.data);
                let mine = {
                    let state = self.state();
                    wanted.is_some_and(|w| w.matches(&state.tag, &state.long_tag))
                };
                if mine {
                    return Route::Local;
                }
                let by_tag = subs.iter().find(|s| match wanted {
                    Some(Wanted::Tag(want)) => s
                        .info
                        .tag
                        .as_deref()
                        .is_some_and(|t| PackedString::<6>::new(t).is_ok_and(|p| p == want.tag)),
                    Some(Wanted::LongTag(want)) => s.info.long_tag.as_deref().is_some_and(|t| {
                        Latin1String::<32>::new(t).is_ok_and(|p| p == want.long_tag)
                    }),
                    None => false,
                });
                match by_tag {
                    Some(s) => on_loop(s.channel, true),
                    None if single => on_loop(0, false),
                    None => Route::Nowhere,
                }
            }
            Address::Long(a) => match subs.iter().find(|s| s.info.unique_id() == a.id) {
                Some(s) => on_loop(s.channel, s.present),
                // A device connected since the last scan may answer on the one loop.
                None if single => on_loop(0, false),
                None => Route::Nowhere,
            },
            Address::Short(a) if a.polling_address == 0 => {
                let device_at_0 = subs
                    .iter()
                    .any(|s| s.present && s.channel == 0 && s.info.polling_address == Some(0));
                if self.transparent && single && device_at_0 {
                    on_loop(0, true)
                } else {
                    Route::Local
                }
            }
            Address::Short(a) => {
                let known =
                    |s: &&SubDevice| s.present && s.info.polling_address == Some(a.polling_address);
                if single {
                    return on_loop(0, subs.iter().any(|s| known(&s)));
                }
                // Several loops: the polling address must name one device.
                let mut matching = subs.iter().filter(known);
                match (matching.next(), matching.next()) {
                    (Some(s), None) => on_loop(s.channel, true),
                    _ => Route::Nowhere,
                }
            }
        }
    }

    /// The expanded device type of the device request `f` reaches, when the server
    /// knows it: the I/O system's own, a long address's, or a sub-device's found at
    /// that polling address (for access control's declared device-specific reads).
    pub async fn device_type(&self, f: &Frame<'_>) -> Option<u16> {
        match f.address {
            Address::Long(a) if a.id.is_broadcast() => None,
            Address::Long(a) => Some(a.id.expanded_device_type),
            Address::Short(a) => {
                if self.route(f).await == Route::Local {
                    return Some(self.unique_id().expanded_device_type);
                }
                let subs = self.subs.lock().await;
                let mut found = subs
                    .iter()
                    .filter(|s| s.present && s.info.polling_address == Some(a.polling_address));
                match (found.next(), found.next()) {
                    (Some(s), None) => Some(s.info.unique_id().expanded_device_type),
                    _ => None,
                }
            }
        }
    }

    /// Forwards a PDU `from` a requester to loop `channel` with `retries`, between the
    /// engine's polls, through the engine's gate (judged by the gateway's rule, writes
    /// audited with their outcome). Never waits for room in the queue: a full queue
    /// answers [`LoopOutcome::Busy`].
    pub async fn forward(
        &self,
        channel: usize,
        pdu: Vec<u8>,
        retries: u8,
        from: &Requester,
    ) -> Result<LoopOutcome, Denied> {
        self.engine.forward(channel, pdu, retries, from).await
    }

    fn identity_reply(&self, state: &Local) -> Vec<u8> {
        encode(&Identity {
            expansion_code: 254,
            expanded_device_type: self.identity.expanded_device_type,
            min_request_preambles: 5,
            universal_revision: 7,
            device_revision: 1,
            software_revision: 1,
            hardware: HardwareRevision::new(1, 6), // physical signalling 6: special (HART-IP)
            flags: Flags(0x04),                    // protocol bridge device
            device_id: DeviceId::new(self.identity.device_id & 0xFF_FFFF).unwrap_or_default(),
            min_response_preambles: Some(5),
            max_device_variables: Some(0),
            config_change_counter: Some(state.config_change_counter),
            extended_status: Some(ExtendedStatus(0)),
            manufacturer_id: Some(self.identity.manufacturer_id),
            private_label_distributor: Some(self.identity.manufacturer_id),
            device_profile: Some(DeviceProfile(68)), // HART-IP I/O system
        })
    }

    /// The sub-device registry now: each place's unique ID and whether it answers.
    async fn sub_ids(&self) -> Vec<(UniqueId, bool)> {
        self.subs
            .lock()
            .await
            .iter()
            .map(|s| (s.info.unique_id(), s.present))
            .collect()
    }

    /// The field device status byte for a reply to `master`: cold start once per
    /// master after power-up, configuration changed until that master resets it, more
    /// status available while command 48 has news (the sub-device list changed).
    fn status(&self, state: &mut Local, master: MasterKind, list_changed: bool) -> u8 {
        let i = master_index(master);
        let mut s = 0;
        if list_changed {
            s |= 0x10;
        }
        if std::mem::take(&mut state.cold[i]) {
            s |= 0x20;
        }
        if state.changed[i] {
            s |= 0x40;
        }
        s
    }

    fn configuration_changed(state: &mut Local) {
        state.config_change_counter = state.config_change_counter.wrapping_add(1);
        state.changed = [true; 2];
    }

    /// Answers a command addressed to the I/O system itself (from `master`, sent by
    /// `from`): response code, field device status and data. What it carries to a
    /// sub-device (commands 75 and 77) passes the engine's gate as `from`'s.
    pub async fn local(
        &self,
        master: MasterKind,
        command: u16,
        data: &[u8],
        from: &Requester,
    ) -> (u8, u8, Vec<u8>) {
        let ids = self.sub_ids().await;
        let (code, out) = match command {
            74 => self.capabilities().await,
            75 => self.poll_sub_device(data, from).await,
            77 => self.send_to_sub_device(data, from).await,
            84 => self.sub_device_summary(data).await,
            101 | 102 => self.burst_map(command, data).await,
            103 | 105 | 107 | 108 | 109 => self.burst_config(command, data),
            48 => {
                // Device-specific status 0-5, extended status, operating mode,
                // standardized status 0 and 1, analog channel saturated, standardized
                // status 2 (bit 0: sub-device list changed, reported once), 3, analog
                // channel fixed.
                let mut st = self.state();
                let mut parts = AdditionalStatusParts::default();
                if st.reported != ids {
                    parts.standardized_status_2 = StandardizedStatus2(0x01);
                    st.reported = ids.clone();
                }
                (rc::SUCCESS, encode(&AdditionalStatus::from(parts)))
            }
            _ => self.universal(command, data),
        };
        let mut st = self.state();
        let list_changed = st.reported != ids;
        let status = self.status(&mut st, master, list_changed);
        (code, status, out)
    }

    /// Universal commands answered from the I/O system's own data. It has no process
    /// variable and no analog output: values are NaN with unit code 250 ("not used"),
    /// the loop current is fixed (multidrop).
    fn universal(&self, command: u16, data: &[u8]) -> (u8, Vec<u8>) {
        let mut st = self.state();
        let ok = |v: Vec<u8>| (rc::SUCCESS, v);
        let not_used = UnitCode(250);
        match command {
            0 => ok(self.identity_reply(&st)),
            11 | 21 => match Wanted::of(command, data) {
                None => (rc::TOO_FEW_DATA_BYTES, vec![]),
                Some(w) if w.matches(&st.tag, &st.long_tag) => ok(self.identity_reply(&st)),
                // Not this device's tag: the I/O system stays silent like a field device
                // (answered as "not implemented" only when a host sends it here
                // directly).
                Some(_) => (rc::NOT_IMPLEMENTED, vec![]),
            },
            1 => ok(encode(&cmd::ReadPvResponse {
                pv_units: not_used,
                pv: hart_nan(),
            })),
            2 => ok(encode(&cmd::ReadLoopCurrentResponse {
                loop_current: MilliAmps(hart_nan()),
                percent_of_range: Percent(hart_nan()),
            })),
            3 => ok(encode(&cmd::ReadDynamicVariablesResponse {
                loop_current: MilliAmps(hart_nan()),
                variables: List::default(),
            })),
            7 => ok(encode(&cmd::LoopConfiguration {
                polling_address: 0,
                loop_current_mode: LoopCurrentMode(0),
            })),
            8 => ok(encode(&cmd::DynamicVariableClassifications {
                pv_classification: Classification(0),
                sv_classification: Classification(0),
                tv_classification: Classification(0),
                qv_classification: Classification(0),
            })),
            9 => {
                let Ok(r) = cmd::ReadDeviceVariablesRequest::decode(&mut Reader::new(data)) else {
                    return (rc::TOO_FEW_DATA_BYTES, vec![]);
                };
                let mut slots = List::<cmd::VariableSlot, 8>::default();
                for code in r.slots.as_slice() {
                    if code.0 >= 251 {
                        return (rc::INVALID_SELECTION, vec![]);
                    }
                    // No device variables: each slot "not used", status bad / constant.
                    let _ = slots.push(cmd::VariableSlot {
                        code: DeviceVariableCode(code.0),
                        classification: Classification(0),
                        units: not_used,
                        value: hart_nan(),
                        status: hart_proto::types::VariableStatus(0x30),
                    });
                }
                ok(encode(&cmd::ReadDeviceVariablesResponse {
                    extended_status: ExtendedStatus(0),
                    data: cmd::SlotsWithTimestamp {
                        slots,
                        timestamp: Some(time_of_day()),
                    },
                }))
            }
            12 => ok(encode(&cmd::Message {
                message: st.message,
            })),
            13 => ok(encode(&TagDescriptorDate {
                tag: st.tag,
                descriptor: st.descriptor,
                date: st.date,
            })),
            14 => ok(encode(&cmd::TransducerInfo {
                transducer_serial_number: U24::default(),
                limits_units: not_used,
                upper_transducer_limit: hart_nan(),
                lower_transducer_limit: hart_nan(),
                minimum_span: hart_nan(),
            })),
            15 => ok(encode(&cmd::DeviceInformation {
                alarm_selection: AlarmSelection(251), // none
                transfer_function: TransferFunction(0),
                range_units: not_used,
                upper_range_value: hart_nan(),
                lower_range_value: hart_nan(),
                damping: Seconds(hart_nan()),
                write_protect: WriteProtect(0),
                reserved: 250,
                analog_channel_flags: Some(hart_proto::types::AnalogChannelFlags(0)),
            })),
            16 => ok(encode(&cmd::FinalAssemblyNumber {
                final_assembly_number: U24::new(st.final_assembly).unwrap_or_default(),
            })),
            17 => match cmd::Message::decode(&mut Reader::new(data)) {
                Ok(m) => {
                    st.message = m.message;
                    Self::configuration_changed(&mut st);
                    ok(encode(&m))
                }
                Err(_) => (rc::TOO_FEW_DATA_BYTES, vec![]),
            },
            18 => match TagDescriptorDate::decode(&mut Reader::new(data)) {
                Ok(t) => {
                    st.tag = t.tag;
                    st.descriptor = t.descriptor;
                    st.date = t.date;
                    Self::configuration_changed(&mut st);
                    ok(encode(&t))
                }
                Err(_) => (rc::TOO_FEW_DATA_BYTES, vec![]),
            },
            19 => match cmd::FinalAssemblyNumber::decode(&mut Reader::new(data)) {
                Ok(n) => {
                    st.final_assembly = n.final_assembly_number.get();
                    Self::configuration_changed(&mut st);
                    ok(encode(&n))
                }
                Err(_) => (rc::TOO_FEW_DATA_BYTES, vec![]),
            },
            20 => ok(encode(&LongTag {
                long_tag: st.long_tag,
            })),
            22 => match LongTag::decode(&mut Reader::new(data)) {
                Ok(t) => {
                    st.long_tag = t.long_tag;
                    Self::configuration_changed(&mut st);
                    ok(encode(&t))
                }
                Err(_) => (rc::TOO_FEW_DATA_BYTES, vec![]),
            },
            38 => {
                // HART 7: the request carries the counter the host read; a stale one
                // leaves the flag set (RC 9). Older hosts send none.
                let asked = cmd::ResetConfigChanged::decode(&mut Reader::new(data))
                    .ok()
                    .and_then(|r| r.config_change_counter);
                if asked.is_some_and(|c| c != st.config_change_counter) {
                    return (CONFIG_CHANGE_COUNTER_MISMATCH, vec![]);
                }
                st.changed = [false; 2];
                ok(encode(&cmd::ResetConfigChanged {
                    config_change_counter: Some(st.config_change_counter),
                }))
            }
            _ => (rc::NOT_IMPLEMENTED, vec![]),
        }
    }

    /// Command 74: read I/O system capabilities. The devices detected are the
    /// registry's places (absent devices keep theirs) and the I/O system itself, so a
    /// host that reads 84 for indexes 1..N reaches every place.
    async fn capabilities(&self) -> (u8, Vec<u8>) {
        let n = self.subs.lock().await.len() as u16 + 1;
        (
            rc::SUCCESS,
            encode(&cmd::IoSystemCapabilities {
                io_cards: 1,
                channels_per_card: self.engine.loop_count() as u8,
                sub_devices_per_channel: 63,
                devices_detected: n,
                delayed_responses: 1,
                master_mode: 1, // primary
                retry_count: KNOWN_RETRIES,
            }),
        )
    }

    /// Command 75: poll sub-device (card, channel, polling address): command 0 in a
    /// short frame on that channel; the reply is the sub-device's command 0 data.
    async fn poll_sub_device(&self, data: &[u8], from: &Requester) -> (u8, Vec<u8>) {
        let Ok(cmd::PollSubDevice {
            io_card: card,
            channel,
            polling_address: poll,
        }) = cmd::PollSubDevice::decode(&mut Reader::new(data))
        else {
            return (rc::TOO_FEW_DATA_BYTES, vec![]);
        };
        if card != 0 {
            return (rc::INVALID_IO_CARD, vec![]);
        }
        if usize::from(channel) >= self.engine.loop_count() {
            return (rc::INVALID_CHANNEL, vec![]);
        }
        if poll > 63 {
            return (rc::INVALID_SELECTION, vec![]);
        }
        let pdu = pdu_of(&hart_proto::frame::FrameSpec::request(
            Address::short(poll),
            0,
            &[],
        ));
        match self
            .forward(usize::from(channel), pdu, UNKNOWN_RETRIES, from)
            .await
        {
            Ok(LoopOutcome::Reply(r)) => match Frame::parse_pdu(&r) {
                Ok(f) => (rc::SUCCESS, f.data.to_vec()),
                Err(_) => (NO_SUB_DEVICE_FOUND, vec![]),
            },
            Ok(LoopOutcome::NoReply) => (NO_SUB_DEVICE_FOUND, vec![]),
            Ok(LoopOutcome::Busy) => (rc::BUSY, vec![]),
            Err(_) => (rc::ACCESS_RESTRICTED, vec![]),
        }
    }

    /// Command 84: read sub-device identity summary (index). Index 0 is the I/O system
    /// itself (card and channel 251, "none"); its sub-devices are 1..=N.
    async fn sub_device_summary(&self, data: &[u8]) -> (u8, Vec<u8>) {
        let Ok(cmd::SubDeviceIndex { index }) = cmd::SubDeviceIndex::decode(&mut Reader::new(data))
        else {
            return (rc::TOO_FEW_DATA_BYTES, vec![]);
        };
        let summary = if index == 0 {
            let st = self.state();
            cmd::SubDeviceSummary {
                index,
                io_card: NONE,
                channel: NONE,
                manufacturer_id: self.identity.manufacturer_id,
                expanded_device_type: self.identity.expanded_device_type,
                device_id: DeviceId::new(self.identity.device_id & 0xFF_FFFF).unwrap_or_default(),
                universal_revision: 7,
                long_tag: st.long_tag,
                device_revision: Some(1),
                device_profile: Some(DeviceProfile(68)),
                private_label_distributor: Some(self.identity.manufacturer_id),
            }
        } else {
            let subs = self.subs.lock().await;
            let Some(s) = subs.get(usize::from(index) - 1) else {
                return (rc::INVALID_SELECTION, vec![]);
            };
            let id = &s.info.identity;
            cmd::SubDeviceSummary {
                index,
                io_card: 0,
                channel: s.channel,
                manufacturer_id: s.info.manufacturer_id(),
                expanded_device_type: id.expanded_device_type,
                device_id: id.device_id,
                universal_revision: id.universal_revision,
                long_tag: Latin1String::new(s.info.long_tag.as_deref().unwrap_or(""))
                    .unwrap_or_default(),
                device_revision: Some(id.device_revision),
                device_profile: Some(id.device_profile.unwrap_or(DeviceProfile(1))),
                private_label_distributor: Some(id.private_label_distributor.unwrap_or(0)),
            }
        };
        (rc::SUCCESS, encode(&summary))
    }

    /// Commands 101 (read sub-device to burst message map: burst message number) and
    /// 102 (map sub-device to burst message: burst message number, sub-device index
    /// u16). Both answer with the burst message number and the sub-device index.
    async fn burst_map(&self, command: u16, data: &[u8]) -> (u8, Vec<u8>) {
        let msg = if command == 101 {
            match cmd::BurstMessageNumber::decode(&mut Reader::new(data)) {
                Ok(r) => r.burst_message,
                Err(_) => return (rc::TOO_FEW_DATA_BYTES, vec![]),
            }
        } else {
            match cmd::SubDeviceBurstMap::decode(&mut Reader::new(data)) {
                Ok(r) => {
                    if usize::from(r.burst_message) >= BURST_MESSAGES {
                        return (INVALID_BURST_MESSAGE, vec![]);
                    }
                    if usize::from(r.sub_device_index) > self.subs.lock().await.len() {
                        return (INVALID_SUB_DEVICE_INDEX, vec![]);
                    }
                    let mut st = self.state();
                    st.burst_map[usize::from(r.burst_message)] = r.sub_device_index;
                    Self::configuration_changed(&mut st);
                    r.burst_message
                }
                Err(_) => return (rc::TOO_FEW_DATA_BYTES, vec![]),
            }
        };
        let Some(&index) = self.state().burst_map.get(usize::from(msg)) else {
            return (INVALID_BURST_MESSAGE, vec![]);
        };
        (
            rc::SUCCESS,
            encode(&cmd::SubDeviceBurstMap {
                burst_message: msg,
                sub_device_index: index,
            }),
        )
    }

    /// The I/O system's burst messages: 103 (period), 105 (read), 107 (device
    /// variables for 9 and 33), 108 (command), 109 (on/off). Message numbers 0-2.
    fn burst_config(&self, command: u16, data: &[u8]) -> (u8, Vec<u8>) {
        use hart_proto::types::{BurstModeControl, CommandNumber, HartTime};
        let mut st = self.state();
        let pick = |m: Option<u8>| usize::from(m.unwrap_or(0));
        let bad_msg = (INVALID_BURST_MESSAGE_NUMBER, vec![]);
        let short = (rc::TOO_FEW_DATA_BYTES, vec![]);
        let mut code = rc::SUCCESS;
        let msg = match command {
            103 => {
                let Ok(r) = cmd::BurstPeriod::decode(&mut Reader::new(data)) else {
                    return short;
                };
                let m = usize::from(r.burst_message);
                let Some(b) = st.bursts.get_mut(m) else {
                    return bad_msg;
                };
                b.period = r.update_period.0.max(MIN_PERIOD);
                b.max_period = r.max_update_period.0.max(b.period);
                if (b.period, b.max_period) != (r.update_period.0, r.max_update_period.0) {
                    code = UPDATE_TIMES_ADJUSTED;
                }
                let reply = cmd::BurstPeriod {
                    burst_message: r.burst_message,
                    update_period: HartTime(b.period),
                    max_update_period: HartTime(b.max_period),
                };
                Self::configuration_changed(&mut st);
                return (code, encode(&reply));
            }
            105 => match cmd::BurstMessageSelect::decode(&mut Reader::new(data)) {
                Ok(r) => pick(r.burst_message),
                Err(_) => return short,
            },
            107 => {
                let Ok(r) = cmd::BurstVariables::decode(&mut Reader::new(data)) else {
                    return short;
                };
                let m = pick(r.burst_message);
                let Some(b) = st.bursts.get_mut(m) else {
                    return bad_msg;
                };
                b.slots = [250; 8];
                for (slot, code) in b.slots.iter_mut().zip(r.slots.as_slice()) {
                    *slot = code.0;
                }
                Self::configuration_changed(&mut st);
                return (rc::SUCCESS, encode(&r));
            }
            108 => {
                let Ok(r) = cmd::BurstCommand::decode(&mut Reader::new(data)) else {
                    return short;
                };
                let m = pick(r.burst_message);
                let Some(b) = st.bursts.get_mut(m) else {
                    return bad_msg;
                };
                if !BURSTABLE.contains(&r.command_number) {
                    return (rc::INVALID_SELECTION, vec![]);
                }
                b.command = r.command_number;
                Self::configuration_changed(&mut st);
                return (rc::SUCCESS, encode(&r));
            }
            109 => {
                let Ok(r) = cmd::BurstModeControlRequest::decode(&mut Reader::new(data)) else {
                    return short;
                };
                let m = pick(r.burst_message);
                let Some(b) = st.bursts.get_mut(m) else {
                    return bad_msg;
                };
                // 0 off, 1 on (token-passing), 4 on (HART-IP); no TDMA (2, 3).
                if !matches!(r.control.0, 0 | 1 | 4) {
                    return (rc::INVALID_SELECTION, vec![]);
                }
                b.control = r.control.0;
                Self::configuration_changed(&mut st);
                return (rc::SUCCESS, encode(&r));
            }
            _ => return (rc::NOT_IMPLEMENTED, vec![]),
        };
        let Some(b) = st.bursts.get(msg) else {
            return bad_msg;
        };
        let mut slots = List::default();
        for &c in &b.slots {
            let _ = slots.push(DeviceVariableCode(c));
        }
        (
            rc::SUCCESS,
            encode(&cmd::BurstConfiguration {
                control: BurstModeControl(b.control),
                command_expansion: 31,
                slots,
                burst_message: Some(msg as u8),
                max_burst_messages: Some(BURST_MESSAGES as u8),
                command_number: Some(CommandNumber(b.command)),
                update_period: Some(HartTime(b.period)),
                max_update_period: Some(HartTime(b.max_period)),
                trigger_mode: Some(hart_proto::types::TriggerMode(0)), // continuous
                trigger_classification: Some(Classification(0)),
                trigger_units: Some(UnitCode(250)),
                trigger_level: Some(hart_nan()),
            }),
        )
    }

    /// Runs the I/O system's burst messages until the server stops: each message that
    /// is on sends its command to the sub-device it is mapped to (command 102; index 0,
    /// the I/O system itself, answers from its own data) once a period, and publishes
    /// the reply as a burst (BACK) frame from that device's address to the sessions
    /// subscribed to it.
    pub async fn publish_bursts(&self, out: &tokio::sync::broadcast::Sender<Vec<u8>>) {
        let mut due = [std::time::Instant::now(); BURST_MESSAGES];
        loop {
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
            for (m, due) in due.iter_mut().enumerate() {
                let (b, index) = {
                    let st = self.state();
                    (st.bursts[m], st.burst_map[m])
                };
                let now = std::time::Instant::now();
                if !matches!(b.control, 1 | 4) || now < *due {
                    continue;
                }
                *due = now + std::time::Duration::from_micros(u64::from(b.period) * 1000 / 32);
                let Some(request) = b.request() else {
                    continue;
                };
                if let Some(frame) = self.burst_frame(index, &request).await {
                    let _ = out.send(frame);
                }
            }
        }
    }

    /// The burst frame of one burst message: the reply to `command` of sub-device
    /// `index` (0: the I/O system) turned into a BACK frame with the burst bit set.
    async fn burst_frame(&self, index: u16, request: &Request) -> Option<Vec<u8>> {
        let command = request.command();
        let (address, code, status, reply) = if index == 0 {
            let reader = Requester::reader("hart-ip", "burst message of the I/O system");
            let data = request.to_vec().ok()?;
            let (code, status, d) = self
                .local(MasterKind::Primary, command, &data, &reader)
                .await;
            (Address::long(self.unique_id()), code, status, d)
        } else {
            let sub = self
                .subs
                .lock()
                .await
                .get(usize::from(index) - 1)
                .cloned()?;
            let address = Address::long(sub.info.unique_id());
            let pdu = request.frame(address).ok()?.to_vec();
            let reader = Requester::reader("hart-ip", "burst message of the I/O system");
            let Ok(LoopOutcome::Reply(reply)) = self
                .forward(usize::from(sub.channel), pdu, KNOWN_RETRIES, &reader)
                .await
            else {
                return None;
            };
            let f = Frame::parse_pdu(&reply).ok()?;
            (
                address,
                f.response_code.unwrap_or(0),
                f.device_status.unwrap_or(0),
                f.data.to_vec(),
            )
        };
        let frame = pdu_of(&hart_proto::frame::FrameSpec {
            frame_type: hart_proto::frame::FrameType::Back,
            status: Some((code, status)),
            ..hart_proto::frame::FrameSpec::request(address.with_burst(true), command, &reply)
        });
        (!frame.is_empty()).then_some(frame)
    }

    /// Command 77: I/O card, channel, transmit preamble count, then the embedded frame
    /// from the delimiter through the data (no check byte). The reply carries card,
    /// channel and the sub-device's reply frame in the same form.
    async fn send_to_sub_device(&self, data: &[u8], from: &Requester) -> (u8, Vec<u8>) {
        let request = match cmd::SendCommandToSubDevice::decode(&mut Reader::new(data)) {
            Ok(r) if !r.frame.as_slice().is_empty() => r,
            _ => return (rc::TOO_FEW_DATA_BYTES, vec![]),
        };
        let (card, channel) = (request.io_card, request.channel);
        if card != 0 {
            return (rc::INVALID_IO_CARD, vec![]);
        }
        if usize::from(channel) >= self.engine.loop_count() {
            return (rc::INVALID_CHANNEL, vec![]);
        }
        let mut buf = [0u8; MAX_PDU_LEN];
        let Ok(address) = request.embedded_frame(&mut buf).map(|f| f.address) else {
            return (rc::TOO_FEW_DATA_BYTES, vec![]);
        };
        // The embedded frame with its check byte, as the loop sends it.
        let pdu = buf[..=request.frame.as_slice().len()].to_vec();
        let known = {
            let subs = self.subs.lock().await;
            subs.iter().any(|s| {
                s.present
                    && s.channel == channel
                    && match address {
                        Address::Long(a) => s.info.unique_id() == a.id,
                        Address::Short(a) => s.info.polling_address == Some(a.polling_address),
                    }
            })
        };
        let retries = if known {
            KNOWN_RETRIES
        } else {
            UNKNOWN_RETRIES
        };
        let from = from.inside_77();
        match self
            .forward(usize::from(channel), pdu, retries, &from)
            .await
        {
            Err(_) => (rc::ACCESS_RESTRICTED, vec![]),
            Ok(LoopOutcome::Busy) => (rc::BUSY, vec![]),
            Ok(LoopOutcome::Reply(reply)) => {
                // The reply frame without its check byte; card, channel and frame
                // must fit the 253 bytes of a reply's data.
                let body = reply.split_last().map_or(&[][..], |(_, body)| body);
                match hart_proto::types::Bytes::<253>::new(body) {
                    Ok(frame) if body.len() + 2 <= 253 => (
                        rc::SUCCESS,
                        encode(&cmd::SendCommandToSubDeviceResponse {
                            io_card: card,
                            channel,
                            frame,
                        }),
                    ),
                    _ => (rc::SUB_DEVICE_RESPONSE_TOO_LONG, vec![]),
                }
            }
            Ok(LoopOutcome::NoReply) => (SUB_DEVICE_NOT_RESPONDING, vec![]),
        }
    }
}

/// The tag a command 11 or 21 request looks for; `None` for another command or a
/// request too short to carry one.
#[derive(Debug, Clone, Copy)]
enum Wanted {
    /// Command 11: the packed tag.
    Tag(TagRequest),
    /// Command 21: the long tag.
    LongTag(LongTag),
}

impl Wanted {
    fn of(command: u16, data: &[u8]) -> Option<Self> {
        match command {
            11 => TagRequest::decode(&mut Reader::new(data))
                .ok()
                .map(Wanted::Tag),
            21 => LongTag::decode(&mut Reader::new(data))
                .ok()
                .map(Wanted::LongTag),
            _ => None,
        }
    }

    /// Whether it names a device with `tag` and `long_tag`.
    fn matches(&self, tag: &PackedString<6>, long_tag: &Latin1String<32>) -> bool {
        match self {
            Wanted::Tag(t) => t.tag == *tag,
            Wanted::LongTag(t) => t.long_tag == *long_tag,
        }
    }
}

impl GatewayBurst {
    /// The request a burst message sends: its command, with the device variable codes
    /// it selects for commands 9 and 33 (250 ends them). `None` for a command without
    /// a typed request.
    fn request(&self) -> Option<Request> {
        let codes = self
            .slots
            .iter()
            .take_while(|&&c| c != 250)
            .map(|&c| DeviceVariableCode(c));
        match self.command {
            9 => {
                let mut slots = List::default();
                codes.for_each(|c| {
                    let _ = slots.push(c);
                });
                Some(Request::ReadDeviceVariablesWithStatus(
                    cmd::ReadDeviceVariablesRequest { slots },
                ))
            }
            33 => {
                let mut slots = List::default();
                codes.take(4).for_each(|c| {
                    let _ = slots.push(c);
                });
                Some(Request::ReadDeviceVariables(cmd::ReadVariablesRequest {
                    slots,
                }))
            }
            c => hart_proto::decode_request(c, &[]).and_then(Result::ok),
        }
    }
}

/// The PDU of `spec` (no preambles); empty if it cannot be encoded.
fn pdu_of(spec: &hart_proto::frame::FrameSpec<'_>) -> Vec<u8> {
    hart_proto::frame::FrameBuf::encode(spec).map_or_else(|_| vec![], |b| b.as_slice().to_vec())
}

/// Time of day for command 9's time stamp.
fn time_of_day() -> hart_proto::types::HartTime {
    let us = hart_clock::epoch::micros(std::time::SystemTime::now());
    hart_proto::types::HartTime::time_of_day(us)
}
