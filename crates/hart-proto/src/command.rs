//! Typed requests and responses of the universal, common-practice and burst commands.
//!
//! Each command is one line of the `commands!` table below, naming its request and
//! response layouts; each layout is one [`wire_struct!`](crate::wire_struct) whose field
//! list drives decoding, encoding, length limits and the field-by-field description
//! (the annotated view and JSON). Adding a command is one line plus, if needed, one
//! layout.
//!
//! Decoding follows HART's compatibility rules: surplus trailing request bytes are
//! ignored; trailing fields added by later protocol revisions are `Option`s that are
//! present only when the data holds them (e.g. the 12-, 17- and 22-byte forms of
//! command 0); data that is too short is a [`DecodeError`], never a panic.

use core::fmt;

use crate::types::*;
use crate::wire::{
    BuildError, DecodeError, EncodeError, Field, List, Meaning, Reader, Source, Value, Visitor,
    Wire, Writer,
};
use crate::wire_struct;

wire_struct! {
    /// No data.
    pub struct Empty {}
}

wire_struct! {
    /// Identity: the reply of commands 0, 11, 21 (and 73). HART 5 sends bytes 0–11,
    /// HART 6 adds 12–16, HART 7 adds 17–21.
    pub struct Identity {
        /// Byte 0: always 254.
        pub expansion_code: u8,
        /// Bytes 1–2: expanded device type (HART 5/6: manufacturer ID, device type).
        pub expanded_device_type: u16,
        /// Byte 3: minimum number of preambles the device needs in requests.
        pub min_request_preambles: u8,
        /// Byte 4: HART universal (protocol major) revision.
        pub universal_revision: u8,
        /// Byte 5: device revision.
        pub device_revision: u8,
        /// Byte 6: software revision.
        pub software_revision: u8,
        /// Byte 7: hardware revision (bits 7–3) and physical signaling (2–0).
        pub hardware: HardwareRevision,
        /// Byte 8: flags (Common Table 11).
        pub flags: Flags,
        /// Bytes 9–11: device ID.
        pub device_id: DeviceId,
        /// Byte 12 (HART 6+): minimum preambles the device sends in replies.
        pub min_response_preambles: Option<u8>,
        /// Byte 13 (HART 6+): maximum number of device variables.
        pub max_device_variables: Option<u8>,
        /// Bytes 14–15 (HART 6+): configuration change counter.
        pub config_change_counter: Option<u16>,
        /// Byte 16 (HART 6+): extended field device status.
        pub extended_status: Option<ExtendedStatus>,
        /// Bytes 17–18 (HART 7): manufacturer identification code.
        pub manufacturer_id: Option<u16>,
        /// Bytes 19–20 (HART 7): private label distributor code.
        pub private_label_distributor: Option<u16>,
        /// Byte 21 (HART 7): device profile (Common Table 57).
        pub device_profile: Option<DeviceProfile>,
    }
    describe_extra = identity_legacy_fields;
    build_with = identity_build;
}

/// A HART 5 identity's description names bytes 1 and 2 `manufacturer_id` and
/// `device_type` (see [`identity_legacy_fields`]); when building one from those fields,
/// they are set aside, since `expanded_device_type` carries the same bytes and the
/// HART 7 `manufacturer_id` cannot follow a 12-byte reply.
fn identity_build(src: &mut dyn Source) -> Result<Identity, BuildError> {
    // `device_type` is no field of the layout: given, it is the legacy reading.
    let hart5 = matches!(src.value("universal_revision")?, Some(Value::Uint(r)) if r <= 5)
        && src.value("device_type")?.is_some();
    if hart5 {
        Identity::build_fields(&mut crate::wire::Hiding {
            inner: src,
            hidden: &["manufacturer_id", "device_type"],
        })
    } else {
        Identity::build_fields(src)
    }
}

/// HART 5 and older name bytes 1 and 2 manufacturer ID and device type.
/// Not when the reply carries HART 7's own `manufacturer_id`, which it would hide.
fn identity_legacy_fields(id: &Identity, offset: usize, v: &mut dyn Visitor) {
    if id.universal_revision <= 5 && id.manufacturer_id.is_none() {
        let [mfr, dt] = id.expanded_device_type.to_be_bytes();
        v.field(Field {
            name: "manufacturer_id",
            offset: offset + 1,
            len: 1,
            value: Value::Uint(mfr.into()),
            meaning: Meaning::Plain,
        });
        v.field(Field {
            name: "device_type",
            offset: offset + 2,
            len: 1,
            value: Value::Uint(dt.into()),
            meaning: Meaning::Plain,
        });
    }
}

impl Identity {
    /// The device's unique identifier for long-frame addressing.
    pub fn unique_id(&self) -> crate::frame::UniqueId {
        crate::frame::UniqueId::new(self.expanded_device_type, self.device_id.get())
    }
}

wire_struct! {
    /// Command 1 reply.
    pub struct ReadPvResponse {
        /// PV units.
        pub pv_units: UnitCode,
        /// Primary variable.
        pub pv: f32,
    }
}

wire_struct! {
    /// Command 2 reply.
    pub struct ReadLoopCurrentResponse {
        /// Loop current, mA.
        pub loop_current: MilliAmps,
        /// Percent of range (not clamped).
        pub percent_of_range: Percent,
    }
}

wire_struct! {
    /// A units code and a value.
    pub struct UnitValue {
        /// Units code.
        pub units: UnitCode,
        /// Value.
        pub value: f32,
    }
}

wire_struct! {
    /// Command 3 reply: loop current then PV, SV, TV, QV as far as the device has them.
    pub struct ReadDynamicVariablesResponse {
        /// Loop current, mA.
        pub loop_current: MilliAmps,
        /// PV, SV, TV, QV (0 to 4 of them).
        pub variables: List<UnitValue, 4>,
    }
}

wire_struct! {
    /// Command 6 request/reply (HART 5 sends only the polling address).
    pub struct PollingAddress {
        /// Polling address, 0..=63.
        pub polling_address: u8,
        /// Loop current mode (HART 6+).
        pub loop_current_mode: Option<LoopCurrentMode>,
    }
}

wire_struct! {
    /// Command 7 reply.
    pub struct LoopConfiguration {
        /// Polling address.
        pub polling_address: u8,
        /// Loop current mode.
        pub loop_current_mode: LoopCurrentMode,
    }
}

wire_struct! {
    /// Command 8 reply.
    pub struct DynamicVariableClassifications {
        /// PV classification.
        pub pv_classification: Classification,
        /// SV classification.
        pub sv_classification: Classification,
        /// TV classification.
        pub tv_classification: Classification,
        /// QV classification.
        pub qv_classification: Classification,
    }
}

wire_struct! {
    /// Command 9 request: 1 to 8 device variable codes.
    pub struct ReadDeviceVariablesRequest {
        /// Requested device variable codes, slot 0 first.
        pub slots: List<DeviceVariableCode, 8, 1>,
    }
}

wire_struct! {
    /// One slot of the command 9 reply (8 bytes).
    pub struct VariableSlot {
        /// Device variable code.
        pub code: DeviceVariableCode,
        /// Classification.
        pub classification: Classification,
        /// Units.
        pub units: UnitCode,
        /// Value.
        pub value: f32,
        /// Device variable status.
        pub status: VariableStatus,
    }
}

/// The slots of a command 9 reply and the slot-0 time stamp that follows them (HART 7).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SlotsWithTimestamp {
    /// 1 to 8 slots.
    pub slots: List<VariableSlot, 8>,
    /// Slot 0 data time stamp (absent in HART 6 replies).
    pub timestamp: Option<HartTime>,
}

impl Wire for SlotsWithTimestamp {
    const MIN_LEN: usize = 0;
    const MAX_LEN: usize = 8 * 8 + 4;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let n = r.remaining();
        let with_time = n % 8 == 4;
        let count = (if with_time { n - 4 } else { n } / 8).min(8);
        let mut slots = List::default();
        for _ in 0..count {
            slots
                .push(VariableSlot::decode(r)?)
                .map_err(|_| DecodeError::Invalid {
                    offset: r.position(),
                    reason: "too many slots",
                })?;
        }
        let timestamp = if r.remaining() >= 4 {
            Some(HartTime::decode(r)?)
        } else {
            None
        };
        Ok(SlotsWithTimestamp { slots, timestamp })
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        self.slots.encode(w)?;
        self.timestamp.encode(w)
    }
    fn encoded_len(&self) -> usize {
        self.slots.encoded_len() + self.timestamp.encoded_len()
    }
    fn describe(&self, _name: &'static str, offset: usize, v: &mut dyn Visitor) {
        self.slots.describe("slots", offset, v);
        self.timestamp
            .describe("timestamp", offset + self.slots.encoded_len(), v);
    }
    fn build(_name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        Ok(SlotsWithTimestamp {
            slots: List::build("slots", src)?,
            timestamp: Option::build("timestamp", src)?,
        })
    }
}

wire_struct! {
    /// Command 9 reply.
    pub struct ReadDeviceVariablesResponse {
        /// Extended field device status.
        pub extended_status: ExtendedStatus,
        /// Slots and time stamp.
        pub data: SlotsWithTimestamp,
    }
}

wire_struct! {
    /// Commands 11 request: the tag to look for.
    pub struct TagRequest {
        /// Tag (8 packed characters).
        pub tag: PackedString<6>,
    }
}

wire_struct! {
    /// Commands 12 reply / 17 request and reply.
    pub struct Message {
        /// Message (32 packed characters).
        pub message: PackedString<24>,
    }
}

wire_struct! {
    /// Commands 13 reply / 18 request and reply.
    pub struct TagDescriptorDate {
        /// Tag (8 packed characters).
        pub tag: PackedString<6>,
        /// Descriptor (16 packed characters).
        pub descriptor: PackedString<12>,
        /// Date.
        pub date: Date,
    }
}

wire_struct! {
    /// Command 14 reply.
    pub struct TransducerInfo {
        /// Transducer serial number.
        pub transducer_serial_number: U24,
        /// Units of the limits and minimum span.
        pub limits_units: UnitCode,
        /// Upper transducer limit.
        pub upper_transducer_limit: f32,
        /// Lower transducer limit.
        pub lower_transducer_limit: f32,
        /// Minimum span.
        pub minimum_span: f32,
    }
}

wire_struct! {
    /// Command 15 reply.
    pub struct DeviceInformation {
        /// PV alarm selection.
        pub alarm_selection: AlarmSelection,
        /// PV transfer function.
        pub transfer_function: TransferFunction,
        /// Range values units.
        pub range_units: UnitCode,
        /// Upper range value.
        pub upper_range_value: f32,
        /// Lower range value.
        pub lower_range_value: f32,
        /// Damping, s.
        pub damping: Seconds,
        /// Write protect code.
        pub write_protect: WriteProtect,
        /// HART 6/7: reserved, 250. HART 5: private label distributor.
        pub reserved: u8,
        /// PV analog channel flags (HART 6+).
        pub analog_channel_flags: Option<AnalogChannelFlags>,
    }
}

wire_struct! {
    /// Commands 16 reply / 19 request and reply.
    pub struct FinalAssemblyNumber {
        /// Final assembly number.
        pub final_assembly_number: U24,
    }
}

wire_struct! {
    /// Commands 20 reply, 21 request, 22 request and reply.
    pub struct LongTag {
        /// Long tag (32 Latin-1 characters).
        pub long_tag: Latin1String<32>,
    }
}

wire_struct! {
    /// Command 38 request and reply (the counter is HART 7; older hosts send nothing).
    pub struct ResetConfigChanged {
        /// Configuration change counter the master expects.
        pub config_change_counter: Option<u16>,
    }
}

/// The named parts of command 48's additional status, as `(offset, length, name,
/// meaning)`: the table [`AdditionalStatus`]'s description and accessors rest on
/// (HART 7 universal command specification, command 48; the status tables are Common
/// Tables 14, 17 and 27-32).
pub static ADDITIONAL_STATUS_PARTS: [(usize, usize, &str, Meaning); 10] = [
    (0, 6, "device_specific_status", Meaning::Plain),
    (
        6,
        1,
        "extended_status",
        Meaning::Bits(&crate::tables::EXTENDED_DEVICE_STATUS),
    ),
    (
        7,
        1,
        "operating_mode",
        Meaning::Code(&crate::tables::DEVICE_OPERATING_MODE),
    ),
    (
        8,
        1,
        "standardized_status_0",
        Meaning::Bits(&crate::tables::STANDARDIZED_STATUS_0),
    ),
    (
        9,
        1,
        "standardized_status_1",
        Meaning::Bits(&crate::tables::STANDARDIZED_STATUS_1),
    ),
    (
        10,
        1,
        "analog_channel_saturated",
        Meaning::Bits(&crate::tables::ANALOG_CHANNEL_SATURATED),
    ),
    (
        11,
        1,
        "standardized_status_2",
        Meaning::Bits(&crate::tables::STANDARDIZED_STATUS_2),
    ),
    (
        12,
        1,
        "standardized_status_3",
        Meaning::Bits(&crate::tables::STANDARDIZED_STATUS_3),
    ),
    (
        13,
        1,
        "analog_channel_fixed",
        Meaning::Bits(&crate::tables::ANALOG_CHANNEL_FIXED),
    ),
    (14, 11, "device_specific_status_2", Meaning::Plain),
];

/// Command 48 reply: additional device status (HART 7 defines 9 to 25 bytes; anything a
/// device sends beyond that is kept as received), also shown field by field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AdditionalStatus(pub Bytes<253>);

impl AdditionalStatus {
    /// The raw bytes.
    pub fn as_slice(&self) -> &[u8] {
        self.0.as_slice()
    }

    /// Byte `at`, when the reply holds it.
    fn byte(&self, at: usize) -> Option<u8> {
        self.as_slice().get(at).copied()
    }

    /// Bytes 0-5: device-specific status (fewer when the reply is shorter).
    pub fn device_specific_status(&self) -> &[u8] {
        let b = self.as_slice();
        &b[..b.len().min(6)]
    }

    /// Byte 6: extended field device status (Common Table 17).
    pub fn extended_status(&self) -> Option<ExtendedStatus> {
        self.byte(6).map(ExtendedStatus)
    }

    /// Byte 7: device operating mode (Common Table 14).
    pub fn operating_mode(&self) -> Option<OperatingMode> {
        self.byte(7).map(OperatingMode)
    }

    /// Byte 8: standardized status 0 (Common Table 29).
    pub fn standardized_status_0(&self) -> Option<StandardizedStatus0> {
        self.byte(8).map(StandardizedStatus0)
    }

    /// Byte 9: standardized status 1 (Common Table 30).
    pub fn standardized_status_1(&self) -> Option<StandardizedStatus1> {
        self.byte(9).map(StandardizedStatus1)
    }

    /// Byte 10: analog channel saturated (Common Table 27).
    pub fn analog_channel_saturated(&self) -> Option<AnalogChannelSaturated> {
        self.byte(10).map(AnalogChannelSaturated)
    }

    /// Byte 11: standardized status 2 (Common Table 31).
    pub fn standardized_status_2(&self) -> Option<StandardizedStatus2> {
        self.byte(11).map(StandardizedStatus2)
    }

    /// Byte 12: standardized status 3 (Common Table 32).
    pub fn standardized_status_3(&self) -> Option<StandardizedStatus3> {
        self.byte(12).map(StandardizedStatus3)
    }

    /// Byte 13: analog channel fixed (Common Table 28).
    pub fn analog_channel_fixed(&self) -> Option<AnalogChannelFixed> {
        self.byte(13).map(AnalogChannelFixed)
    }

    /// Bytes 0-8, the part a HART 7 command 48 request copies back to acknowledge
    /// the status (fewer when the reply is shorter).
    pub fn acknowledged(&self) -> &[u8] {
        let b = self.as_slice();
        &b[..b.len().min(9)]
    }
}

/// The parts of a 14-byte command 48 additional status, for a device or an I/O system
/// building its reply: [`AdditionalStatus::from`] lays them out as
/// [`ADDITIONAL_STATUS_PARTS`] says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AdditionalStatusParts {
    /// Bytes 0-5: device-specific status.
    pub device_specific_status: [u8; 6],
    /// Byte 6: extended field device status.
    pub extended_status: ExtendedStatus,
    /// Byte 7: device operating mode.
    pub operating_mode: OperatingMode,
    /// Byte 8: standardized status 0.
    pub standardized_status_0: StandardizedStatus0,
    /// Byte 9: standardized status 1.
    pub standardized_status_1: StandardizedStatus1,
    /// Byte 10: analog channel saturated.
    pub analog_channel_saturated: AnalogChannelSaturated,
    /// Byte 11: standardized status 2.
    pub standardized_status_2: StandardizedStatus2,
    /// Byte 12: standardized status 3.
    pub standardized_status_3: StandardizedStatus3,
    /// Byte 13: analog channel fixed.
    pub analog_channel_fixed: AnalogChannelFixed,
}

impl From<AdditionalStatusParts> for AdditionalStatus {
    fn from(p: AdditionalStatusParts) -> Self {
        let mut b = [0u8; 14];
        b[..6].copy_from_slice(&p.device_specific_status);
        b[6..].copy_from_slice(&[
            p.extended_status.0,
            p.operating_mode.0,
            p.standardized_status_0.0,
            p.standardized_status_1.0,
            p.analog_channel_saturated.0,
            p.standardized_status_2.0,
            p.standardized_status_3.0,
            p.analog_channel_fixed.0,
        ]);
        // 14 bytes always fit the 253 the layout holds.
        AdditionalStatus(Bytes::new(&b).unwrap_or_default())
    }
}

impl Wire for AdditionalStatus {
    const MIN_LEN: usize = 1;
    const MAX_LEN: usize = 253;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        if r.remaining() == 0 {
            return Err(DecodeError::TooShort {
                offset: r.position(),
                needed: 1,
                available: 0,
            });
        }
        Ok(AdditionalStatus(Bytes::decode(r)?))
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        self.0.encode(w)
    }
    fn encoded_len(&self) -> usize {
        self.0.encoded_len()
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        let b = self.as_slice();
        v.field(Field {
            name,
            offset,
            len: b.len(),
            value: Value::Hex(b),
            meaning: Meaning::Plain,
        });
        for &(at, len, name, meaning) in &ADDITIONAL_STATUS_PARTS {
            let Some(bytes) = b.get(at..(at + len).min(b.len())).filter(|s| !s.is_empty()) else {
                continue;
            };
            let value = if len == 1 {
                Value::Uint(bytes[0].into())
            } else {
                Value::Hex(bytes)
            };
            v.field(Field {
                name,
                offset: offset + at,
                len: bytes.len(),
                value,
                meaning,
            });
        }
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let b = Bytes::build(name, src)?;
        if b.as_slice().is_empty() {
            return Err(BuildError::Missing { field: name });
        }
        Ok(AdditionalStatus(b))
    }
}

wire_struct! {
    /// Command 48 reply.
    pub struct ReadAdditionalStatusResponse {
        /// Additional status bytes.
        pub additional_status: AdditionalStatus,
    }
}

wire_struct! {
    /// Command 48 request: none (legacy) or the bytes 0–8 of the status last read, to
    /// acknowledge them (HART 7).
    pub struct ReadAdditionalStatusRequest {
        /// Copy of the status bytes being acknowledged (empty for a legacy request).
        pub status_copy: Bytes<25>,
    }
}

wire_struct! {
    /// Command 33 request: 1 to 4 device variable codes.
    pub struct ReadVariablesRequest {
        /// Requested codes.
        pub slots: List<DeviceVariableCode, 4, 1>,
    }
}

wire_struct! {
    /// One slot of the command 33 reply.
    pub struct CodeUnitValue {
        /// Device variable code.
        pub code: DeviceVariableCode,
        /// Units.
        pub units: UnitCode,
        /// Value.
        pub value: f32,
    }
}

wire_struct! {
    /// Command 33 reply.
    pub struct ReadVariablesResponse {
        /// 1 to 4 slots.
        pub variables: List<CodeUnitValue, 4>,
    }
}

wire_struct! {
    /// Command 34 request and reply.
    pub struct Damping {
        /// PV damping, s.
        pub damping: Seconds,
    }
}

wire_struct! {
    /// Command 35 request and reply (note: upper before lower).
    pub struct RangeValues {
        /// Units of the range values.
        pub range_units: UnitCode,
        /// Upper range value.
        pub upper_range_value: f32,
        /// Lower range value.
        pub lower_range_value: f32,
    }
}

wire_struct! {
    /// Command 40 request and reply.
    pub struct FixedCurrent {
        /// Loop current to hold, mA; 0 leaves fixed current mode.
        pub loop_current: MilliAmps,
    }
}

wire_struct! {
    /// Command 44 request and reply.
    pub struct PvUnits {
        /// PV units.
        pub pv_units: UnitCode,
    }
}

wire_struct! {
    /// Commands 45/46 request and reply.
    pub struct TrimCurrent {
        /// Externally measured loop current, mA.
        pub measured_current: MilliAmps,
    }
}

wire_struct! {
    /// Command 50 reply.
    pub struct DynamicVariableAssignments {
        /// Device variable mapped to PV.
        pub pv_code: DeviceVariableCode,
        /// Device variable mapped to SV (250 = none).
        pub sv_code: Option<DeviceVariableCode>,
        /// Device variable mapped to TV.
        pub tv_code: Option<DeviceVariableCode>,
        /// Device variable mapped to QV.
        pub qv_code: Option<DeviceVariableCode>,
    }
}

wire_struct! {
    /// Command 53 request and reply.
    pub struct VariableUnits {
        /// Device variable code.
        pub code: DeviceVariableCode,
        /// Units.
        pub units: UnitCode,
    }
}

wire_struct! {
    /// Command 54 request.
    pub struct VariableCode {
        /// Device variable code.
        pub code: DeviceVariableCode,
    }
}

wire_struct! {
    /// Command 54 reply (27 bytes; HART 7 adds the properties byte).
    pub struct VariableInformation {
        /// Device variable code.
        pub code: DeviceVariableCode,
        /// Transducer serial number.
        pub transducer_serial_number: U24,
        /// Units of limits and minimum span.
        pub limits_units: UnitCode,
        /// Upper transducer limit.
        pub upper_transducer_limit: f32,
        /// Lower transducer limit.
        pub lower_transducer_limit: f32,
        /// Damping, s.
        pub damping: Seconds,
        /// Minimum span.
        pub minimum_span: f32,
        /// Classification.
        pub classification: Classification,
        /// Device variable family.
        pub family: VariableFamily,
        /// Acquisition (update) period.
        pub acquisition_period: HartTime,
        /// Device variable properties (HART 7).
        pub properties: Option<u8>,
    }
}

wire_struct! {
    /// Command 59 request and reply.
    pub struct ResponsePreambles {
        /// Preambles the device sends in replies (5..=20).
        pub response_preambles: u8,
    }
}

wire_struct! {
    /// Command 79 request and reply: simulate a device variable.
    pub struct WriteDeviceVariable {
        /// Device variable code.
        pub code: DeviceVariableCode,
        /// 0 normal, 1 fixed value.
        pub write_code: WriteVariableCode,
        /// Units.
        pub units: UnitCode,
        /// Value.
        pub value: f32,
        /// Device variable status to report.
        pub status: VariableStatus,
    }
}

wire_struct! {
    /// Command 90 reply.
    pub struct RealTimeClock {
        /// Current date.
        pub current_date: Date,
        /// Current time of day.
        pub current_time: HartTime,
        /// Date the clock was last set.
        pub last_set_date: Date,
        /// Time the clock was last set.
        pub last_set_time: HartTime,
        /// Real-time clock flags.
        pub rtc_flags: u8,
    }
}

wire_struct! {
    /// Command 95 reply.
    pub struct CommunicationStatistics {
        /// STX messages received.
        pub stx_count: u16,
        /// ACK messages sent.
        pub ack_count: u16,
        /// BACK messages sent.
        pub back_count: u16,
    }
}

wire_struct! {
    /// Command 103 request and reply.
    pub struct BurstPeriod {
        /// Burst message number.
        pub burst_message: u8,
        /// Update period.
        pub update_period: HartTime,
        /// Maximum update period.
        pub max_update_period: HartTime,
    }
}

wire_struct! {
    /// Command 104 request and reply.
    pub struct BurstTrigger {
        /// Burst message number.
        pub burst_message: u8,
        /// Trigger mode (Common Table 33).
        pub trigger_mode: TriggerMode,
        /// Classification of the trigger value.
        pub classification: Classification,
        /// Units of the trigger level.
        pub units: UnitCode,
        /// Trigger level.
        pub trigger_level: f32,
    }
}

/// Commands of I/O systems (multiplexers, HART-IP gateways) about their sub-devices;
/// field devices do not have them.
pub const IO_SYSTEM_COMMANDS: &[u16] = &[74, 75, 77, 84, 101, 102];

wire_struct! {
    /// Command 74 reply: what an I/O system (a multiplexer, a HART-IP gateway) has.
    pub struct IoSystemCapabilities {
        /// I/O cards.
        pub io_cards: u8,
        /// Channels per card.
        pub channels_per_card: u8,
        /// Sub-devices per channel.
        pub sub_devices_per_channel: u8,
        /// Devices detected, the I/O system itself included.
        pub devices_detected: u16,
        /// Delayed responses the I/O system can hold at once.
        pub delayed_responses: u8,
        /// Master mode on its channels: 0 secondary, 1 primary.
        pub master_mode: u8,
        /// Retries on its channels.
        pub retry_count: u8,
    }
}

wire_struct! {
    /// Command 75 request (poll sub-device); the reply is the sub-device's command 0
    /// data ([`Identity`]).
    pub struct PollSubDevice {
        /// I/O card.
        pub io_card: u8,
        /// Channel.
        pub channel: u8,
        /// Polling address on that channel.
        pub polling_address: u8,
    }
}

wire_struct! {
    /// Command 77 request: send a command to a sub-device of an I/O system. The
    /// embedded frame runs from its delimiter through its data; the I/O system adds the
    /// check byte (HART 7 common practice command specification, command 77; Wireshark's
    /// `dissect_cmd77`).
    pub struct SendCommandToSubDevice {
        /// I/O card.
        pub io_card: u8,
        /// Channel.
        pub channel: u8,
        /// Preambles to send before the embedded frame.
        pub transmit_preambles: u8,
        /// The embedded request frame, delimiter through data, without its check byte.
        pub frame: Bytes<252>,
    }
}

wire_struct! {
    /// Command 77 reply: the sub-device's reply frame, delimiter through data (its
    /// status bytes included), without its check byte.
    pub struct SendCommandToSubDeviceResponse {
        /// I/O card.
        pub io_card: u8,
        /// Channel.
        pub channel: u8,
        /// The embedded reply frame, delimiter through data, without its check byte.
        pub frame: Bytes<253>,
    }
}

/// The frame `embedded` (delimiter through data) parsed, with its check byte computed
/// into `buf`.
fn embedded_frame<'b>(
    embedded: &[u8],
    buf: &'b mut [u8; crate::frame::MAX_PDU_LEN],
) -> Result<crate::frame::Frame<'b>, crate::frame::FrameError> {
    let n = embedded.len();
    // Bytes<253> at most, so the check byte always fits the 267 bytes of `buf`.
    buf[..n].copy_from_slice(embedded);
    buf[n] = crate::frame::checksum(embedded);
    crate::frame::Frame::parse_pdu(&buf[..=n])
}

impl SendCommandToSubDevice {
    /// Wraps the request `frame` (a PDU, delimiter through check byte) for the
    /// sub-device on `io_card`/`channel`: its check byte is left out, as command 77
    /// carries it. Fails when the PDU is empty or longer than the 253 bytes that fit.
    pub fn wrap(
        io_card: u8,
        channel: u8,
        transmit_preambles: u8,
        frame: &crate::frame::FrameBuf,
    ) -> Result<Self, EncodeError> {
        let pdu = frame.as_slice();
        let body = pdu
            .split_last()
            .map(|(_, body)| body)
            .ok_or(EncodeError::Invalid("command 77 needs a frame to carry"))?;
        Ok(SendCommandToSubDevice {
            io_card,
            channel,
            transmit_preambles,
            frame: Bytes::new(body).map_err(|_| {
                EncodeError::Invalid(
                    "the frame is too long for command 77 (252 bytes before its check byte)",
                )
            })?,
        })
    }

    /// The embedded request frame, its check byte computed into `buf`; an error when
    /// the bytes are not a frame.
    pub fn embedded_frame<'b>(
        &self,
        buf: &'b mut [u8; crate::frame::MAX_PDU_LEN],
    ) -> Result<crate::frame::Frame<'b>, crate::frame::FrameError> {
        embedded_frame(self.frame.as_slice(), buf)
    }
}

impl SendCommandToSubDeviceResponse {
    /// The embedded reply frame, its check byte computed into `buf`; an error when the
    /// bytes are not a frame.
    pub fn embedded_frame<'b>(
        &self,
        buf: &'b mut [u8; crate::frame::MAX_PDU_LEN],
    ) -> Result<crate::frame::Frame<'b>, crate::frame::FrameError> {
        embedded_frame(self.frame.as_slice(), buf)
    }
}

wire_struct! {
    /// Command 84 request: which sub-device (0 is the I/O system itself).
    pub struct SubDeviceIndex {
        /// Sub-device index.
        pub index: u16,
    }
}

wire_struct! {
    /// Command 84 reply: read sub-device identity summary. Bytes 44-47 were added by a
    /// later revision of the command.
    pub struct SubDeviceSummary {
        /// Sub-device index.
        pub index: u16,
        /// I/O card (251 "none" for the I/O system itself).
        pub io_card: u8,
        /// Channel (251 "none" for the I/O system itself).
        pub channel: u8,
        /// Manufacturer ID.
        pub manufacturer_id: u16,
        /// Expanded device type.
        pub expanded_device_type: u16,
        /// Device ID.
        pub device_id: DeviceId,
        /// HART universal revision.
        pub universal_revision: u8,
        /// Long tag.
        pub long_tag: Latin1String<32>,
        /// Device revision.
        pub device_revision: Option<u8>,
        /// Device profile.
        pub device_profile: Option<DeviceProfile>,
        /// Private label distributor.
        pub private_label_distributor: Option<u16>,
    }
}

wire_struct! {
    /// Command 101 request: the burst message whose sub-device to read.
    pub struct BurstMessageNumber {
        /// Burst message number.
        pub burst_message: u8,
    }
}

wire_struct! {
    /// Commands 101 (reply) and 102 (request and reply): which sub-device a burst
    /// message of an I/O system publishes.
    pub struct SubDeviceBurstMap {
        /// Burst message number.
        pub burst_message: u8,
        /// Sub-device index (0: the I/O system itself).
        pub sub_device_index: u16,
    }
}

wire_struct! {
    /// Command 105 request (HART 7: the message number; legacy: nothing).
    pub struct BurstMessageSelect {
        /// Burst message number.
        pub burst_message: Option<u8>,
    }
}

wire_struct! {
    /// Command 105 reply (HART 7: 29 bytes; older devices stop earlier).
    pub struct BurstConfiguration {
        /// Burst mode control code.
        pub control: BurstModeControl,
        /// 31 in HART 7 replies; the 8-bit burst command number in legacy replies.
        pub command_expansion: u8,
        /// Device variable codes of slots 0–7 (250 = unused).
        pub slots: List<DeviceVariableCode, 8>,
        /// Burst message number.
        pub burst_message: Option<u8>,
        /// Number of burst messages the device supports.
        pub max_burst_messages: Option<u8>,
        /// Burst command number.
        pub command_number: Option<CommandNumber>,
        /// Update period.
        pub update_period: Option<HartTime>,
        /// Maximum update period.
        pub max_update_period: Option<HartTime>,
        /// Trigger mode.
        pub trigger_mode: Option<TriggerMode>,
        /// Trigger classification.
        pub trigger_classification: Option<Classification>,
        /// Trigger units.
        pub trigger_units: Option<UnitCode>,
        /// Trigger level.
        pub trigger_level: Option<f32>,
    }
}

impl BurstConfiguration {
    /// The command the burst message publishes: the 16-bit `command_number` of a
    /// HART 7 reply, else the legacy reply's 8-bit number in `command_expansion`.
    pub fn burst_command(&self) -> u16 {
        self.command_number
            .map_or(self.command_expansion.into(), |c| c.0)
    }
}

/// Command 107 request and reply: device variables for the burst slots. HART 7 sends 8
/// codes and the message number; legacy hosts send 1 to 4 codes (message 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BurstVariables {
    /// Slot codes (250 = unused).
    pub slots: List<DeviceVariableCode, 8, 1>,
    /// Burst message number (HART 7 form only).
    pub burst_message: Option<u8>,
}

impl Wire for BurstVariables {
    const MIN_LEN: usize = 1;
    const MAX_LEN: usize = 9;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        match r.remaining() {
            n if n >= 9 => {
                let mut slots = List::default();
                for _ in 0..8 {
                    let _ = slots.push(DeviceVariableCode::decode(r)?);
                }
                Ok(BurstVariables {
                    slots,
                    burst_message: Some(r.u8()?),
                })
            }
            1..=4 => Ok(BurstVariables {
                slots: List::decode(r)?,
                burst_message: None,
            }),
            // 5 to 8 bytes: neither form; a device answers "too few data bytes".
            n => Err(DecodeError::TooShort {
                offset: r.position(),
                needed: if n == 0 { 1 } else { 9 },
                available: n,
            }),
        }
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        if self.burst_message.is_some() && self.slots.len() != 8 {
            return Err(EncodeError::Invalid(
                "the HART 7 form of command 107 has exactly 8 slots (use 250 for unused)",
            ));
        }
        if self.burst_message.is_none() && self.slots.len() > 4 {
            return Err(EncodeError::Invalid(
                "the legacy form of command 107 has 1 to 4 slots",
            ));
        }
        self.slots.encode(w)?;
        self.burst_message.encode(w)
    }
    fn encoded_len(&self) -> usize {
        self.slots.encoded_len() + self.burst_message.encoded_len()
    }
    fn describe(&self, _name: &'static str, offset: usize, v: &mut dyn Visitor) {
        self.slots.describe("slots", offset, v);
        self.burst_message
            .describe("burst_message", offset + self.slots.encoded_len(), v);
    }
    fn build(_name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        Ok(BurstVariables {
            slots: List::build("slots", src)?,
            burst_message: Option::build("burst_message", src)?,
        })
    }
}

/// Command 108 request and reply: the command a burst message publishes. HART 7 sends
/// a 16-bit command number and the message number; legacy hosts one byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BurstCommand {
    /// Command to publish.
    pub command_number: u16,
    /// Burst message number (`None` for the legacy one-byte form).
    pub burst_message: Option<u8>,
}

impl Wire for BurstCommand {
    const MIN_LEN: usize = 1;
    const MAX_LEN: usize = 3;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        if r.remaining() >= 3 {
            Ok(BurstCommand {
                command_number: u16::decode(r)?,
                burst_message: Some(r.u8()?),
            })
        } else {
            Ok(BurstCommand {
                command_number: r.u8()?.into(),
                burst_message: None,
            })
        }
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        match self.burst_message {
            Some(m) => {
                self.command_number.encode(w)?;
                w.u8(m)
            }
            None => w.u8(u8::try_from(self.command_number).map_err(|_| {
                EncodeError::Invalid(
                    "the legacy form of command 108 carries an 8-bit command number",
                )
            })?),
        }
    }
    fn encoded_len(&self) -> usize {
        if self.burst_message.is_some() {
            3
        } else {
            1
        }
    }
    fn describe(&self, _name: &'static str, offset: usize, v: &mut dyn Visitor) {
        let len = if self.burst_message.is_some() { 2 } else { 1 };
        v.field(Field {
            name: "command_number",
            offset,
            len,
            value: Value::Uint(self.command_number.into()),
            meaning: Meaning::Command,
        });
        self.burst_message
            .describe("burst_message", offset + len, v);
    }
    fn build(_name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        Ok(BurstCommand {
            command_number: u16::build("command_number", src)?,
            burst_message: Option::build("burst_message", src)?,
        })
    }
}

wire_struct! {
    /// Command 109 request and reply.
    pub struct BurstModeControlRequest {
        /// Burst mode control code (0 off, 1 on token-passing...).
        pub control: BurstModeControl,
        /// Burst message number (HART 7).
        pub burst_message: Option<u8>,
    }
}

/// The flags of a client subscription (command 533): what a HART-IP server
/// publishes to the client.
pub mod subscription {
    /// Process data (burst messages).
    pub const PROCESS_DATA: u16 = 0x0001;
    /// Event notifications.
    pub const EVENT_NOTIFICATION: u16 = 0x0002;
    /// Device status.
    pub const DEVICE_STATUS: u16 = 0x0004;
    /// Device configuration.
    pub const DEVICE_CONFIGURATION: u16 = 0x0008;
}

/// The 5 bytes of a unique ID as HART-IP's client subscription commands (532, 533)
/// carry them, kept as received (bits 7-6 of the first byte included), shown as 10 hex
/// digits; all zero stands for every device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SubscriptionTarget(pub [u8; 5]);

impl SubscriptionTarget {
    /// Every device (the all-zero unique ID).
    pub const ALL: SubscriptionTarget = SubscriptionTarget([0; 5]);

    /// The device's unique ID (the master and burst bits of the first byte ignored).
    pub fn unique_id(&self) -> crate::frame::UniqueId {
        crate::frame::UniqueId::from_bytes(self.0)
    }
}

impl From<crate::frame::UniqueId> for SubscriptionTarget {
    fn from(id: crate::frame::UniqueId) -> Self {
        SubscriptionTarget(id.to_bytes())
    }
}

impl Wire for SubscriptionTarget {
    const MIN_LEN: usize = 5;
    const MAX_LEN: usize = 5;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(SubscriptionTarget(r.array()?))
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.put(&self.0)
    }
    fn encoded_len(&self) -> usize {
        5
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        v.field(Field {
            name,
            offset,
            len: 5,
            value: Value::Hex(&self.0),
            meaning: Meaning::Plain,
        });
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let bad = BuildError::Invalid {
            field: name,
            reason: "a unique ID is five bytes: ten hex digits",
        };
        match src
            .value(name)?
            .ok_or(BuildError::Missing { field: name })?
        {
            Value::Hex(b) => Ok(SubscriptionTarget(b.try_into().map_err(|_| bad)?)),
            Value::Str(text) => {
                let mut id = [0u8; 5];
                crate::wire::hex_into(text, &mut id)
                    .filter(|&n| n == 5)
                    .ok_or(bad)?;
                Ok(SubscriptionTarget(id))
            }
            _ => Err(BuildError::WrongKind {
                field: name,
                expected: "ten hex digits",
            }),
        }
    }
}

wire_struct! {
    /// Command 532 request: whose subscription to read (HART-IP; hipserver's
    /// `hscommands.cpp` and `hssubscribe.h`, docs/hart-ip.md).
    pub struct SubscriptionSelect {
        /// The device's unique ID; all zero for the subscription to every device.
        pub unique_id: SubscriptionTarget,
    }
}

wire_struct! {
    /// Command 532 reply and command 533 request and reply: a HART-IP client's publish
    /// subscription to a device (hipserver's `hscommands.cpp` and `hssubscribe.h`).
    pub struct ClientSubscription {
        /// The device's unique ID; all zero for every device.
        pub unique_id: SubscriptionTarget,
        /// What is published to the client: 0x0001 process data, 0x0002 event
        /// notification, 0x0004 device status, 0x0008 device configuration.
        pub flags: u16,
    }
}

/// The kind of command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandKind {
    /// Universal: every device implements it.
    Universal,
    /// Common practice: optional, standardised.
    CommonPractice,
    /// Burst-mode configuration (common practice).
    Burst,
}

/// What the table knows about a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandInfo {
    /// Command number.
    pub number: u16,
    /// Type name of the command (the variant of [`Request`]/[`Response`]).
    pub name: &'static str,
    /// Title as used in the HART specifications.
    pub title: &'static str,
    /// Universal, common practice or burst.
    pub kind: CommandKind,
    /// True when the command changes the device's configuration (write protection
    /// applies). Self test and device reset change the device without being
    /// configuration writes: see [`CommandInfo::access`].
    pub writes: bool,
    /// What the command does to the device, for access control.
    pub access: Access,
    /// Fewest request data bytes.
    pub request_min: usize,
    /// Most request data bytes the layout uses.
    pub request_max: usize,
    /// Fewest reply data bytes (after the status bytes).
    pub response_min: usize,
    /// Most reply data bytes.
    pub response_max: usize,
}

/// What a command does to a device, for access control (read-only sessions, allow
/// lists, audits). Deny by default: only a command the project knows to read is
/// [`Access::Read`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Only reads: the device's configuration, outputs and state stay as they are.
    Read,
    /// Changes the device: its configuration, its outputs (fixed current, trims) or
    /// its state (self test, reset, lock, squawk).
    Write,
    /// Carries other commands (77 send command to sub-device, 78 aggregated
    /// commands): the commands inside decide.
    Wrapper,
    /// Not known to the project: device-specific commands (128-253), reserved and
    /// unlisted numbers. Access control counts them as writes unless a plant declares
    /// a device's command a read.
    Unknown,
}

/// Commands the project knows by number and title but does not type (their layouts
/// are not implemented), with what they do. Common-practice titles as HART 7's
/// common practice command specification names them (docs/protocol-decisions.md);
/// only commands that certainly only read are [`Access::Read`]: a read counted as a
/// write is refused to read-only sessions, a write counted as a read would reach the
/// device, so doubtful ones are writes.
pub static UNTYPED_COMMANDS: &[(u16, &str, Access)] = &[
    (39, "EEPROM Control", Access::Write),
    (
        47,
        "Write Primary Variable Transfer Function",
        Access::Write,
    ),
    (
        49,
        "Write Primary Variable Transducer Serial Number",
        Access::Write,
    ),
    (52, "Set Device Variable Zero", Access::Write),
    (55, "Write Device Variable Damping Value", Access::Write),
    (
        56,
        "Write Device Variable Transducer Serial Number",
        Access::Write,
    ),
    (57, "Read Unit Tag, Descriptor, Date", Access::Read),
    (58, "Write Unit Tag, Descriptor, Date", Access::Write),
    (60, "Read Analog Channel and Percent of Range", Access::Read),
    (
        61,
        "Read Dynamic Variables and Primary Variable Analog Channel",
        Access::Read,
    ),
    (62, "Read Analog Channels", Access::Read),
    (63, "Read Analog Channel Information", Access::Read),
    (
        64,
        "Write Analog Channel Additional Damping Value",
        Access::Write,
    ),
    (65, "Write Analog Channel Range Values", Access::Write),
    (66, "Enter/Exit Fixed Analog Channel Mode", Access::Write),
    (67, "Trim Analog Channel Zero", Access::Write),
    (68, "Trim Analog Channel Gain", Access::Write),
    (69, "Write Analog Channel Transfer Function", Access::Write),
    (70, "Read Analog Channel Endpoint Values", Access::Read),
    (71, "Lock Device", Access::Write),
    (72, "Squawk", Access::Write),
    // Answered only while armed (a button pressed), which it may end: a write.
    (73, "Find Device", Access::Write),
    (76, "Read Lock Device State", Access::Read),
    (78, "Read Aggregated Commands", Access::Wrapper),
    (80, "Read Device Variable Trim Points", Access::Read),
    (81, "Read Device Variable Trim Guidelines", Access::Read),
    (82, "Write Device Variable Trim Point", Access::Write),
    (83, "Reset Device Variable Trim", Access::Write),
    (85, "Read I/O Channel Statistics", Access::Read),
    (86, "Read Sub-Device Statistics", Access::Read),
    (87, "Write I/O System Master Mode", Access::Write),
    (88, "Write I/O System Retry Count", Access::Write),
    (89, "Set Real-Time Clock", Access::Write),
    (91, "Read Trend Configuration", Access::Read),
    (92, "Write Trend Configuration", Access::Write),
    (93, "Read Trend", Access::Read),
    (
        94,
        "Read I/O System Client-Side Communication Statistics",
        Access::Read,
    ),
    (96, "Read Synchronous Action", Access::Read),
    (97, "Configure Synchronous Action", Access::Write),
    (98, "Read Command Action", Access::Read),
    (99, "Configure Command Action", Access::Write),
    (100, "Write Primary Variable Alarm Code", Access::Write),
    (106, "Flush Delayed Responses", Access::Write),
    (512, "Read Country Code", Access::Read),
    (513, "Write Country Code", Access::Write),
];

/// What `command` does to a device: from the typed table ([`COMMANDS`]), then the
/// untyped one ([`UNTYPED_COMMANDS`]); [`Access::Unknown`] for any other number.
pub fn access(command: u16) -> Access {
    if let Some(i) = info(command) {
        return i.access;
    }
    UNTYPED_COMMANDS
        .iter()
        .find(|c| c.0 == command)
        .map_or(Access::Unknown, |c| c.2)
}

/// The title of `command`, typed or not.
pub fn title(command: u16) -> Option<&'static str> {
    info(command).map(|i| i.title).or_else(|| {
        UNTYPED_COMMANDS
            .iter()
            .find(|c| c.0 == command)
            .map(|c| c.1)
    })
}

/// Looks up a command in the table.
pub fn info(command: u16) -> Option<&'static CommandInfo> {
    COMMANDS.iter().find(|c| c.number == command)
}

/// A built value that does not encode (a layout's own rule, e.g. command 107's two
/// forms) is refused with the encoder's reason.
fn checked<T: Wire>(v: T) -> Result<T, BuildError> {
    let mut buf = [0u8; 255];
    match v.encode(&mut Writer::new(&mut buf)) {
        Ok(()) => Ok(v),
        Err(EncodeError::Invalid(reason)) => Err(BuildError::Invalid {
            field: "data",
            reason,
        }),
        Err(EncodeError::BufferTooSmall { .. }) => Err(BuildError::Invalid {
            field: "data",
            reason: "more than the 255 bytes a frame's data can hold",
        }),
    }
}

macro_rules! commands {
    ( $( $num:literal $variant:ident $kind:ident $rw:ident $title:literal : $req:ty => $resp:ty ; )* ) => {
        /// A typed request (the data of an STX frame).
        #[derive(Debug, Clone, Copy, PartialEq)]
        #[allow(missing_docs)]
        // Command 77 carries a whole frame inline: without an allocator it cannot be
        // boxed, and a request is at most one frame's data anyway.
        #[allow(clippy::large_enum_variant)]
        pub enum Request { $( $variant($req), )* }

        /// A typed reply (the data of an ACK/BACK frame after the status bytes).
        #[derive(Debug, Clone, Copy, PartialEq)]
        #[allow(missing_docs)]
        pub enum Response { $( $variant($resp), )* }

        /// Every command the crate types, in number order.
        pub static COMMANDS: &[CommandInfo] = &[ $(
            CommandInfo {
                number: $num,
                name: stringify!($variant),
                title: $title,
                kind: CommandKind::$kind,
                writes: commands!(@rw $rw),
                access: commands!(@access $rw),
                request_min: <$req as Wire>::MIN_LEN,
                request_max: <$req as Wire>::MAX_LEN,
                response_min: <$resp as Wire>::MIN_LEN,
                response_max: <$resp as Wire>::MAX_LEN,
            },
        )* ];

        /// Decodes request data of `command`; `None` for a command the table does not type.
        pub fn decode_request(command: u16, data: &[u8]) -> Option<Result<Request, DecodeError>> {
            match command {
                $( $num => Some(<$req as Wire>::decode(&mut Reader::new(data)).map(Request::$variant)), )*
                _ => None,
            }
        }

        /// Decodes reply data (after the status bytes) of `command`; `None` for a command
        /// the table does not type.
        pub fn decode_response(command: u16, data: &[u8]) -> Option<Result<Response, DecodeError>> {
            match command {
                $( $num => Some(<$resp as Wire>::decode(&mut Reader::new(data)).map(Response::$variant)), )*
                _ => None,
            }
        }

        /// Builds the request of `command` from named fields (the names its JSON and
        /// annotated views use); `None` for a command the table does not type. The
        /// request is checked to encode, so a value that is `Ok` can be sent.
        pub fn build_request(command: u16, src: &mut dyn Source) -> Option<Result<Request, BuildError>> {
            match command {
                $( $num => Some(<$req as Wire>::build("request", src).and_then(checked).map(Request::$variant)), )*
                _ => None,
            }
        }

        /// Builds the reply data of `command` (after the status bytes) from named
        /// fields; `None` for a command the table does not type.
        pub fn build_response(command: u16, src: &mut dyn Source) -> Option<Result<Response, BuildError>> {
            match command {
                $( $num => Some(<$resp as Wire>::build("response", src).and_then(checked).map(Response::$variant)), )*
                _ => None,
            }
        }

        impl Request {
            /// The command number.
            pub fn command(&self) -> u16 {
                match self { $( Request::$variant(_) => $num, )* }
            }
            /// Encodes the request data.
            pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
                match self { $( Request::$variant(x) => x.encode(w), )* }
            }
            /// Bytes [`Request::encode`] writes.
            pub fn encoded_len(&self) -> usize {
                match self { $( Request::$variant(x) => x.encoded_len(), )* }
            }
            /// Reports every field to `v`.
            pub fn describe(&self, v: &mut dyn Visitor) {
                match self { $( Request::$variant(x) => x.describe("request", 0, v), )* }
            }
            /// The request frame to `address` (no preambles): the command number, and
            /// the command-31 form for numbers above 255, come from the table. Needs no
            /// allocator.
            pub fn frame(&self, address: crate::frame::Address) -> Result<crate::frame::FrameBuf, EncodeError> {
                let mut data = [0u8; 255];
                let mut w = Writer::new(&mut data);
                self.encode(&mut w)?;
                let n = w.position();
                crate::frame::FrameBuf::encode(&crate::frame::FrameSpec::request(address, self.command(), &data[..n]))
            }
            /// The request data as bytes.
            #[cfg(feature = "std")]
            pub fn to_vec(&self) -> Result<std::vec::Vec<u8>, EncodeError> {
                let mut data = [0u8; 255];
                let mut w = Writer::new(&mut data);
                self.encode(&mut w)?;
                let n = w.position();
                Ok(data[..n].to_vec())
            }
        }

        impl Response {
            /// The command number.
            pub fn command(&self) -> u16 {
                match self { $( Response::$variant(_) => $num, )* }
            }
            /// Encodes the reply data.
            pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
                match self { $( Response::$variant(x) => x.encode(w), )* }
            }
            /// Bytes [`Response::encode`] writes.
            pub fn encoded_len(&self) -> usize {
                match self { $( Response::$variant(x) => x.encoded_len(), )* }
            }
            /// Reports every field to `v`.
            pub fn describe(&self, v: &mut dyn Visitor) {
                match self { $( Response::$variant(x) => x.describe("response", 0, v), )* }
            }
            /// The reply data (after the status bytes) as bytes.
            #[cfg(feature = "std")]
            pub fn to_vec(&self) -> Result<std::vec::Vec<u8>, EncodeError> {
                let mut data = [0u8; 255];
                let mut w = Writer::new(&mut data);
                self.encode(&mut w)?;
                let n = w.position();
                Ok(data[..n].to_vec())
            }
        }
    };
    (@rw read) => { false };
    (@rw write) => { true };
    (@rw action) => { false };
    (@rw wrapper) => { false };
    (@access read) => { Access::Read };
    (@access write) => { Access::Write };
    (@access action) => { Access::Write };
    (@access wrapper) => { Access::Wrapper };
}

commands! {
    0   ReadUniqueIdentifier Universal read "Read Unique Identifier" : Empty => Identity;
    1   ReadPrimaryVariable Universal read "Read Primary Variable" : Empty => ReadPvResponse;
    2   ReadLoopCurrent Universal read "Read Loop Current and Percent of Range" : Empty => ReadLoopCurrentResponse;
    3   ReadDynamicVariables Universal read "Read Dynamic Variables and Loop Current" : Empty => ReadDynamicVariablesResponse;
    6   WritePollingAddress Universal write "Write Polling Address" : PollingAddress => PollingAddress;
    7   ReadLoopConfiguration Universal read "Read Loop Configuration" : Empty => LoopConfiguration;
    8   ReadDynamicVariableClassifications Universal read "Read Dynamic Variable Classifications" : Empty => DynamicVariableClassifications;
    9   ReadDeviceVariablesWithStatus Universal read "Read Device Variables with Status" : ReadDeviceVariablesRequest => ReadDeviceVariablesResponse;
    11  ReadUniqueIdentifierByTag Universal read "Read Unique Identifier Associated With Tag" : TagRequest => Identity;
    12  ReadMessage Universal read "Read Message" : Empty => Message;
    13  ReadTagDescriptorDate Universal read "Read Tag, Descriptor, Date" : Empty => TagDescriptorDate;
    14  ReadPvTransducerInformation Universal read "Read Primary Variable Transducer Information" : Empty => TransducerInfo;
    15  ReadDeviceInformation Universal read "Read Device Information" : Empty => DeviceInformation;
    16  ReadFinalAssemblyNumber Universal read "Read Final Assembly Number" : Empty => FinalAssemblyNumber;
    17  WriteMessage Universal write "Write Message" : Message => Message;
    18  WriteTagDescriptorDate Universal write "Write Tag, Descriptor, Date" : TagDescriptorDate => TagDescriptorDate;
    19  WriteFinalAssemblyNumber Universal write "Write Final Assembly Number" : FinalAssemblyNumber => FinalAssemblyNumber;
    20  ReadLongTag Universal read "Read Long Tag" : Empty => LongTag;
    21  ReadUniqueIdentifierByLongTag Universal read "Read Unique Identifier Associated With Long Tag" : LongTag => Identity;
    22  WriteLongTag Universal write "Write Long Tag" : LongTag => LongTag;
    33  ReadDeviceVariables CommonPractice read "Read Device Variables" : ReadVariablesRequest => ReadVariablesResponse;
    34  WritePvDamping CommonPractice write "Write Primary Variable Damping Value" : Damping => Damping;
    35  WritePvRange CommonPractice write "Write Primary Variable Range Values" : RangeValues => RangeValues;
    36  SetPvUpperRange CommonPractice write "Set Primary Variable Upper Range Value" : Empty => Empty;
    37  SetPvLowerRange CommonPractice write "Set Primary Variable Lower Range Value" : Empty => Empty;
    38  ResetConfigurationChanged Universal write "Reset Configuration Changed Flag" : ResetConfigChanged => ResetConfigChanged;
    40  EnterExitFixedCurrent CommonPractice write "Enter/Exit Fixed Current Mode" : FixedCurrent => FixedCurrent;
    41  PerformSelfTest CommonPractice action "Perform Self Test" : Empty => Empty;
    42  PerformDeviceReset CommonPractice action "Perform Device Reset" : Empty => Empty;
    43  SetPvZero CommonPractice write "Set Primary Variable Zero" : Empty => Empty;
    44  WritePvUnits CommonPractice write "Write Primary Variable Units" : PvUnits => PvUnits;
    45  TrimLoopCurrentZero CommonPractice write "Trim Loop Current Zero" : TrimCurrent => TrimCurrent;
    46  TrimLoopCurrentGain CommonPractice write "Trim Loop Current Gain" : TrimCurrent => TrimCurrent;
    48  ReadAdditionalStatus Universal read "Read Additional Device Status" : ReadAdditionalStatusRequest => ReadAdditionalStatusResponse;
    50  ReadDynamicVariableAssignments CommonPractice read "Read Dynamic Variable Assignments" : Empty => DynamicVariableAssignments;
    51  WriteDynamicVariableAssignments CommonPractice write "Write Dynamic Variable Assignments" : DynamicVariableAssignments => DynamicVariableAssignments;
    53  WriteDeviceVariableUnits CommonPractice write "Write Device Variable Units" : VariableUnits => VariableUnits;
    54  ReadDeviceVariableInformation CommonPractice read "Read Device Variable Information" : VariableCode => VariableInformation;
    59  WriteResponsePreambles CommonPractice write "Write Number of Response Preambles" : ResponsePreambles => ResponsePreambles;
    74  ReadIoSystemCapabilities CommonPractice read "Read I/O System Capabilities" : Empty => IoSystemCapabilities;
    75  PollSubDevice CommonPractice read "Poll Sub-Device" : PollSubDevice => Identity;
    77  SendCommandToSubDevice CommonPractice wrapper "Send Command to Sub-Device" : SendCommandToSubDevice => SendCommandToSubDeviceResponse;
    79  WriteDeviceVariable CommonPractice write "Write Device Variable" : WriteDeviceVariable => WriteDeviceVariable;
    84  ReadSubDeviceIdentitySummary CommonPractice read "Read Sub-Device Identity Summary" : SubDeviceIndex => SubDeviceSummary;
    90  ReadRealTimeClock CommonPractice read "Read Real-Time Clock" : Empty => RealTimeClock;
    95  ReadCommunicationStatistics CommonPractice read "Read Device Communications Statistics" : Empty => CommunicationStatistics;
    101 ReadSubDeviceBurstMap CommonPractice read "Read Sub-Device to Burst Message Map" : BurstMessageNumber => SubDeviceBurstMap;
    102 MapSubDeviceToBurstMessage CommonPractice write "Map Sub-Device to Burst Message" : SubDeviceBurstMap => SubDeviceBurstMap;
    103 WriteBurstPeriod Burst write "Write Burst Period" : BurstPeriod => BurstPeriod;
    104 WriteBurstTrigger Burst write "Write Burst Trigger" : BurstTrigger => BurstTrigger;
    105 ReadBurstConfiguration Burst read "Read Burst Mode Configuration" : BurstMessageSelect => BurstConfiguration;
    107 WriteBurstDeviceVariables Burst write "Write Burst Device Variables" : BurstVariables => BurstVariables;
    108 WriteBurstCommandNumber Burst write "Write Burst Mode Command Number" : BurstCommand => BurstCommand;
    109 BurstModeControl Burst write "Burst Mode Control" : BurstModeControlRequest => BurstModeControlRequest;
    // HART-IP's client subscriptions, answered by a HART-IP server for the session.
    // 533 changes the session, not a device's configuration: write protection does
    // not apply (`action`), access control counts it a write.
    532 ReadClientSubscriptionSummary CommonPractice read "Read Client Subscription Summary" : SubscriptionSelect => ClientSubscription;
    533 WriteClientSubscriptionFlags CommonPractice action "Write Client Subscription Flags" : ClientSubscription => ClientSubscription;
}

impl fmt::Display for CommandInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} {}", self.number, self.title)
    }
}

#[cfg(test)]
mod access_tests {
    use super::*;

    #[test]
    fn access_denies_by_default() {
        // The reviewed reads.
        for c in [0, 1, 2, 3, 9, 11, 12, 13, 15, 20, 48, 57, 76, 84, 105, 512] {
            assert_eq!(access(c), Access::Read, "{c}");
        }
        // Writes, actions (self test, reset), wrappers, and what is not known.
        for c in [6, 17, 18, 38, 40, 41, 42, 71, 72, 73, 89, 102, 109, 513] {
            assert_eq!(access(c), Access::Write, "{c}");
        }
        assert_eq!(access(77), Access::Wrapper);
        assert!(info(77).is_some_and(|i| !i.writes));
        assert_eq!(access(78), Access::Wrapper);
        // HART-IP's client subscriptions: reading one only reads; writing one changes
        // the session, which write protection does not cover.
        assert_eq!(access(532), Access::Read);
        assert_eq!(access(533), Access::Write);
        assert!(!info(533).unwrap().writes);
        for c in [
            4, 5, 10, 23, 31, 128, 129, 200, 253, 254, 255, 514, 4096, 65535,
        ] {
            assert_eq!(access(c), Access::Unknown, "{c}");
        }
        // Self test and reset change the device but write protection does not stop
        // them.
        assert!(!info(41).unwrap().writes && !info(42).unwrap().writes);
    }

    #[test]
    fn untyped_commands_are_not_typed_and_listed_once() {
        let mut seen = std::collections::BTreeSet::new();
        for &(n, title, _) in UNTYPED_COMMANDS {
            assert!(info(n).is_none(), "{n} is typed");
            assert!(seen.insert(n), "{n} listed twice");
            assert_eq!(super::title(n), Some(title));
        }
        assert_eq!(title(17), Some("Write Message"));
    }
}

#[cfg(test)]
mod helper_tests {
    use super::*;
    use crate::frame::{Address, Frame, UniqueId};

    #[test]
    fn additional_status_parts_lay_out_as_the_table_says() {
        let parts = AdditionalStatusParts {
            device_specific_status: [1, 2, 3, 4, 5, 6],
            extended_status: ExtendedStatus(7),
            operating_mode: OperatingMode(8),
            standardized_status_0: StandardizedStatus0(9),
            standardized_status_1: StandardizedStatus1(10),
            analog_channel_saturated: AnalogChannelSaturated(11),
            standardized_status_2: StandardizedStatus2(12),
            standardized_status_3: StandardizedStatus3(13),
            analog_channel_fixed: AnalogChannelFixed(14),
        };
        let s = AdditionalStatus::from(parts);
        assert_eq!(s.as_slice(), &(1..=14).collect::<std::vec::Vec<u8>>()[..]);
        for &(at, len, name, _) in &ADDITIONAL_STATUS_PARTS[1..9] {
            assert_eq!(len, 1, "{name}");
            let got = match name {
                "extended_status" => s.extended_status().map(|x| x.0),
                "operating_mode" => s.operating_mode().map(|x| x.0),
                "standardized_status_0" => s.standardized_status_0().map(|x| x.0),
                "standardized_status_1" => s.standardized_status_1().map(|x| x.0),
                "analog_channel_saturated" => s.analog_channel_saturated().map(|x| x.0),
                "standardized_status_2" => s.standardized_status_2().map(|x| x.0),
                "standardized_status_3" => s.standardized_status_3().map(|x| x.0),
                "analog_channel_fixed" => s.analog_channel_fixed().map(|x| x.0),
                other => panic!("{other}"),
            };
            assert_eq!(got, Some(at as u8 + 1), "{name}");
        }
        assert_eq!(s.device_specific_status(), &[1, 2, 3, 4, 5, 6]);
        assert_eq!(s.acknowledged(), &[1, 2, 3, 4, 5, 6, 7, 8, 9]);
    }

    #[test]
    fn a_short_additional_status_has_no_later_parts() {
        let s = AdditionalStatus(Bytes::new(&[1, 2, 3]).unwrap());
        assert_eq!(s.device_specific_status(), &[1, 2, 3]);
        assert_eq!(s.acknowledged(), &[1, 2, 3]);
        assert_eq!(s.extended_status(), None);
        assert_eq!(s.analog_channel_fixed(), None);
    }

    #[test]
    fn a_request_frames_itself_and_extends_numbers_above_255() {
        let id = UniqueId::new(0x1234, 0x56789A);
        let r = Request::WritePvDamping(Damping {
            damping: Seconds(2.0),
        });
        let fb = r.frame(Address::long(id)).unwrap();
        let f = fb.frame().unwrap();
        assert_eq!(f.command, 34);
        assert_eq!(f.data, &r.to_vec().unwrap()[..]);
        assert_eq!(fb.to_vec(), fb.as_slice());
        let mut spec_buf = [0u8; 64];
        let n = crate::frame::FrameSpec {
            preambles: 0,
            ..crate::frame::FrameSpec::request(Address::long(id), 34, f.data)
        }
        .encode(&mut spec_buf)
        .unwrap();
        assert_eq!(fb.as_slice(), &spec_buf[..n]);
        assert!(Frame::parse_pdu(fb.as_slice()).unwrap().checksum_ok());
    }

    #[test]
    fn response_to_vec_is_its_encoding() {
        let r = Response::WritePvUnits(PvUnits {
            pv_units: UnitCode(12),
        });
        assert_eq!(r.to_vec().unwrap(), std::vec![12]);
    }

    #[test]
    fn the_burst_command_comes_from_either_form() {
        let mut c = BurstConfiguration {
            command_expansion: 3,
            ..Default::default()
        };
        assert_eq!(c.burst_command(), 3);
        c.command_expansion = 31;
        c.command_number = Some(CommandNumber(9));
        assert_eq!(c.burst_command(), 9);
    }

    #[test]
    fn command_77_wraps_a_frame_and_gives_it_back() {
        let id = UniqueId::new(0x1234, 0x56789A);
        let inner = Request::ReadPrimaryVariable(Empty {})
            .frame(Address::long(id))
            .unwrap();
        let r = SendCommandToSubDevice::wrap(1, 2, 5, &inner).unwrap();
        assert_eq!(
            r.frame.as_slice(),
            &inner.as_slice()[..inner.as_slice().len() - 1]
        );
        let mut buf = [0u8; crate::frame::MAX_PDU_LEN];
        let f = r.embedded_frame(&mut buf).unwrap();
        assert_eq!((f.command, f.checksum_ok()), (1, true));
        let data = Request::SendCommandToSubDevice(r).to_vec().unwrap();
        assert_eq!(&data[..3], &[1, 2, 5]);
        assert_eq!(
            decode_request(77, &data),
            Some(Ok(Request::SendCommandToSubDevice(r)))
        );
        // Bytes that are no frame are an error, not a panic.
        let junk = SendCommandToSubDeviceResponse {
            io_card: 0,
            channel: 0,
            frame: Bytes::new(&[0x86]).unwrap(),
        };
        assert!(junk.embedded_frame(&mut buf).is_err());
    }

    #[test]
    fn a_client_subscription_round_trips() {
        let data = [0xC0, 0, 0, 0, 0, 0x00, 0x01];
        let Some(Ok(Request::WriteClientSubscriptionFlags(s))) = decode_request(533, &data) else {
            panic!("533 does not decode");
        };
        assert_eq!(s.flags, 1);
        assert_eq!(s.unique_id.unique_id(), UniqueId::BROADCAST);
        assert_eq!(
            Request::WriteClientSubscriptionFlags(s).to_vec().unwrap(),
            data
        );
        assert!(matches!(decode_request(532, &[0; 4]), Some(Err(_))));
    }
}
