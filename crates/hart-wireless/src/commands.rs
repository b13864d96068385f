//! Typed layouts of the WirelessHART commands, defined as data on hart-proto's
//! [`wire_struct!`](hart_proto::wire_struct) machinery: one field list per layout
//! drives decoding, encoding, the length limits and the field-by-field description
//! ([`Visitor`]), as for the wired commands.
//!
//! In a transport PDU a request carries the layout's bytes; a response carries its
//! response code first, then the layout (only the code when the code is an error).
//! Layouts were checked against the public captures (`tests/captures`); where a field's
//! name or meaning is from one source only, its doc says so.

use alloc::vec::Vec;
use core::fmt;

use hart_proto::types::{Bytes, Date, HartTime};
use hart_proto::wire::{
    BuildError, DecodeError, EncodeError, Field, List, Meaning, Reader, Source, Value, Visitor,
    Wire, Writer,
};
use hart_proto::wire_struct;

/// A fixed number of raw bytes (a key, a unique ID), shown as hex.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Fixed<const N: usize>(pub [u8; N]);

impl<const N: usize> Default for Fixed<N> {
    fn default() -> Self {
        Fixed([0; N])
    }
}

impl<const N: usize> fmt::Debug for Fixed<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.iter().try_for_each(|b| write!(f, "{b:02x}"))
    }
}

impl<const N: usize> Wire for Fixed<N> {
    const MIN_LEN: usize = N;
    const MAX_LEN: usize = N;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(Fixed(r.array()?))
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.put(&self.0)
    }
    fn encoded_len(&self) -> usize {
        N
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        v.field(Field {
            name,
            offset,
            len: N,
            value: Value::Hex(&self.0),
            meaning: Meaning::Plain,
        });
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let mut out = [0u8; N];
        let ok = match hart_proto::wire::required(src, name)? {
            Value::Hex(b) if b.len() == N => {
                out.copy_from_slice(b);
                true
            }
            Value::Str(t) => hart_proto::wire::hex_into(t, &mut out) == Some(N),
            _ => false,
        };
        if ok {
            Ok(Fixed(out))
        } else {
            Err(BuildError::Invalid {
                field: name,
                reason: "takes exactly this field's number of bytes as hex digits",
            })
        }
    }
}

/// An absolute slot number (5 bytes, big-endian).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Asn(pub u64);

impl Wire for Asn {
    const MIN_LEN: usize = 5;
    const MAX_LEN: usize = 5;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let b: [u8; 5] = r.array()?;
        Ok(Asn(b.iter().fold(0u64, |a, &x| a << 8 | x as u64)))
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.put(&self.0.to_be_bytes()[3..])
    }
    fn encoded_len(&self) -> usize {
        5
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        // Value::Uint is 32 bits: an ASN above that is shown as its bytes.
        let b = self.0.to_be_bytes();
        let value = match u32::try_from(self.0) {
            Ok(n) => Value::Uint(n),
            Err(_) => Value::Hex(&b[3..]),
        };
        v.field(Field {
            name,
            offset,
            len: 5,
            value,
            meaning: Meaning::Plain,
        });
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let n = <u32 as hart_proto::wire::FromValue>::from_value(
            hart_proto::wire::required(src, name)?,
            name,
        )?;
        Ok(Asn(n as u64))
    }
}

/// A received signal level in dBm (signed byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Rsl(pub i8);

impl Wire for Rsl {
    const MIN_LEN: usize = 1;
    const MAX_LEN: usize = 1;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(Rsl(r.u8()? as i8))
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.u8(self.0 as u8)
    }
    fn encoded_len(&self) -> usize {
        1
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        // Value has no signed integer: the level is given as a float in dBm.
        v.field(Field {
            name,
            offset,
            len: 1,
            value: Value::Float(self.0 as f32),
            meaning: Meaning::Quantity("dBm"),
        });
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let x = <f32 as hart_proto::wire::FromValue>::from_value(
            hart_proto::wire::required(src, name)?,
            name,
        )?;
        if !(-128.0..=127.0).contains(&x) {
            return Err(BuildError::Invalid {
                field: name,
                reason: "a signal level is -128 to 127 dBm",
            });
        }
        Ok(Rsl(x as i8))
    }
}

wire_struct! {
    /// No data.
    pub struct Empty {}
}

wire_struct! {
    /// 787 request: which part of the neighbour table to report.
    pub struct NeighborTableSelect {
        /// First neighbour table index.
        pub index: u8,
        /// Number of entries to read.
        pub count: u8,
    }
}

wire_struct! {
    /// One neighbour and the level it is heard at (787).
    pub struct NeighborSignal {
        /// The neighbour's nickname.
        pub nickname: u16,
        /// Received signal level, dBm.
        pub rsl: Rsl,
    }
}

wire_struct! {
    /// 787 response: neighbours' signal levels (sent unsolicited in a join request).
    pub struct NeighborSignalLevels {
        /// First neighbour table index.
        pub index: u8,
        /// Entries in this response.
        pub entries: u8,
        /// Neighbours in the table.
        pub total: u8,
        /// The entries.
        pub neighbors: List<NeighborSignal, 84>,
    }
}

wire_struct! {
    /// 777 response: wireless device capabilities (layout as whad reads it and as the
    /// captures carry it).
    pub struct WirelessCapabilities {
        /// Bit 7 counters saturate; bits 3-0 power source (0 line, 1 battery, 2 rechargeable/scavenging).
        pub power: u8,
        /// Peak packets per second.
        pub peak_packets_per_second: f32,
        /// Duration at peak packet rate, s.
        pub duration_at_peak: u32,
        /// Time to recover from power drain, s.
        pub time_to_recover: u32,
        /// Receiver sensitivity, dBm.
        pub rsl: Rsl,
        /// Required keep-alive time, ms.
        pub keep_alive_time: u32,
        /// Maximum number of neighbours.
        pub max_neighbors: u16,
        /// Maximum number of packet buffers.
        pub max_packet_buffers: u16,
    }
}

wire_struct! {
    /// 779 response: device health. The first ten bytes are as whad reads them and as
    /// the captures carry them; what follows differs between revisions of the command
    /// (the captures carry 21 more bytes, whad reads 23) and is kept raw [U].
    pub struct DeviceHealth {
        /// Packets generated by the device.
        pub generated: u16,
        /// Packets terminated by the device.
        pub terminated: u16,
        /// Data-link MIC failures.
        pub dl_mic_failures: u16,
        /// Network MIC failures.
        pub nl_mic_failures: u16,
        /// Power status (0 nominal, 1 low, 2 critically low, 3 recharging low, 4 recharging high).
        pub power_status: u8,
        /// CRC errors.
        pub crc_errors: u8,
        /// The further counters, raw.
        pub more: Bytes<64>,
    }
}

wire_struct! {
    /// 793 request and response: UTC time mapping (date and time of an ASN epoch).
    pub struct UtcTimeMapping {
        /// Date.
        pub date: Date,
        /// Time of day (1/32 ms).
        pub time: HartTime,
    }
}

wire_struct! {
    /// 795 request and response: a timer interval.
    pub struct TimerInterval {
        /// 0 discovery, 1 advertisement, 2 keep-alive, 3 path failure, 4 health report,
        /// 5 broadcast reply, 6 maximum PDU age, 7 maximum reply time.
        pub timer_type: u8,
        /// Interval, ms.
        pub interval: u32,
    }
}

wire_struct! {
    /// 799 request: a service (bandwidth) request.
    pub struct ServiceRequest {
        /// Service ID.
        pub service_id: u8,
        /// Bit 0 source, 1 sink, 2 intermittent.
        pub flags: u8,
        /// 0 publish, 1 event, 2 maintenance, 3 block transfer.
        pub domain: u8,
        /// Peer nickname.
        pub peer: u16,
        /// Period (1/32 ms).
        pub period: HartTime,
    }
}

wire_struct! {
    /// 799 response and 973 request: a service with its route.
    pub struct Service {
        /// Service ID.
        pub service_id: u8,
        /// Bit 0 source, 1 sink, 2 intermittent.
        pub flags: u8,
        /// 0 publish, 1 event, 2 maintenance, 3 block transfer.
        pub domain: u8,
        /// Peer nickname.
        pub peer: u16,
        /// Period (1/32 ms).
        pub period: HartTime,
        /// Route ID.
        pub route_id: u8,
    }
}

wire_struct! {
    /// 973 response: the service written and the service entries left.
    pub struct ServiceWritten {
        /// Service ID.
        pub service_id: u8,
        /// Bit 0 source, 1 sink, 2 intermittent.
        pub flags: u8,
        /// 0 publish, 1 event, 2 maintenance, 3 block transfer.
        pub domain: u8,
        /// Peer nickname.
        pub peer: u16,
        /// Period (1/32 ms).
        pub period: HartTime,
        /// Route ID.
        pub route_id: u8,
        /// Service entries left.
        pub remaining: u8,
    }
}

wire_struct! {
    /// 805 request and response: CCA mode (0 off, 1 energy, 2 carrier, 3 both).
    pub struct CcaMode {
        /// The mode.
        pub mode: u8,
    }
}

wire_struct! {
    /// 808 response: the TTL the device puts in network PDUs.
    pub struct PacketTtl {
        /// Time to live (hops).
        pub ttl: u8,
    }
}

wire_struct! {
    /// 960 request and response: disconnect.
    pub struct Disconnect {
        /// 0 user initiated, 1 communication failure [U: one source].
        pub reason: u8,
    }
}

wire_struct! {
    /// 961 request and response: the network key.
    pub struct NetworkKey {
        /// The key.
        pub key: Fixed<16>,
        /// When to start using it.
        pub execution_asn: Option<Asn>,
    }
}

wire_struct! {
    /// 962 request and response: the device's nickname.
    pub struct Nickname {
        /// The nickname.
        pub nickname: u16,
    }
}

wire_struct! {
    /// 963 request: a session and its key.
    pub struct SessionRequest {
        /// 0 unicast, 1 broadcast, 2 join.
        pub session_type: u8,
        /// The peer's nickname.
        pub peer: u16,
        /// The peer's unique ID (expanded device type, device ID).
        pub peer_unique_id: Fixed<5>,
        /// The peer's nonce counter.
        pub nonce_counter: u32,
        /// The session key.
        pub key: Fixed<16>,
        /// Reserved.
        pub reserved: u8,
        /// When to start using it.
        pub execution_asn: Option<Asn>,
    }
}

wire_struct! {
    /// 963 response: the session and the session entries left.
    pub struct SessionResponse {
        /// 0 unicast, 1 broadcast, 2 join.
        pub session_type: u8,
        /// The peer's nickname.
        pub peer: u16,
        /// The peer's unique ID.
        pub peer_unique_id: Fixed<5>,
        /// The peer's nonce counter.
        pub nonce_counter: u32,
        /// The session key.
        pub key: Fixed<16>,
        /// Session entries left.
        pub remaining: u8,
        /// When it starts being used.
        pub execution_asn: Option<Asn>,
    }
}

wire_struct! {
    /// 965 request: a superframe.
    pub struct Superframe {
        /// Superframe ID.
        pub superframe_id: u8,
        /// Number of slots.
        pub slots: u16,
        /// Bit 7 handheld, bit 0 active.
        pub mode: u8,
        /// Reserved.
        pub reserved: u8,
        /// When to start using it.
        pub execution_asn: Option<Asn>,
    }
}

wire_struct! {
    /// 965 response: the superframe and the superframe entries left.
    pub struct SuperframeWritten {
        /// Superframe ID.
        pub superframe_id: u8,
        /// Number of slots.
        pub slots: u16,
        /// Bit 7 handheld, bit 0 active.
        pub mode: u8,
        /// Superframe entries left.
        pub remaining: u8,
    }
}

wire_struct! {
    /// 967 request: a link.
    pub struct Link {
        /// Superframe ID.
        pub superframe_id: u8,
        /// Slot number.
        pub slot: u16,
        /// Channel offset.
        pub channel_offset: u8,
        /// Neighbour nickname (0xFFFF: any).
        pub neighbor: u16,
        /// Bit 0 transmit, 1 receive, 2 shared.
        pub options: u8,
        /// 0 normal, 1 discovery, 2 broadcast, 3 join.
        pub link_type: u8,
    }
}

wire_struct! {
    /// 967 response: the link and the link entries left.
    pub struct LinkWritten {
        /// Superframe ID.
        pub superframe_id: u8,
        /// Slot number.
        pub slot: u16,
        /// Channel offset.
        pub channel_offset: u8,
        /// Neighbour nickname.
        pub neighbor: u16,
        /// Bit 0 transmit, 1 receive, 2 shared.
        pub options: u8,
        /// 0 normal, 1 discovery, 2 broadcast, 3 join.
        pub link_type: u8,
        /// Link entries left.
        pub remaining: u16,
    }
}

wire_struct! {
    /// 971 request and response: a neighbour's property flags.
    pub struct NeighborFlags {
        /// Neighbour nickname.
        pub neighbor: u16,
        /// Bit 0 time source, bit 7 no links [U].
        pub flags: u8,
    }
}

wire_struct! {
    /// 972 request and response: suspend between two ASNs.
    pub struct Suspend {
        /// ASN to suspend at.
        pub suspend_asn: Asn,
        /// ASN to resume at.
        pub resume_asn: Asn,
    }
}

wire_struct! {
    /// 974 request: a route.
    pub struct Route {
        /// Route ID.
        pub route_id: u8,
        /// Destination nickname.
        pub destination: u16,
        /// Graph ID.
        pub graph_id: u16,
    }
}

wire_struct! {
    /// 974 response: the route and the route entries left.
    pub struct RouteWritten {
        /// Route ID.
        pub route_id: u8,
        /// Destination nickname.
        pub destination: u16,
        /// Graph ID.
        pub graph_id: u16,
        /// Route entries left.
        pub remaining: u8,
    }
}

/// Response codes every wireless command may return.
pub const COMMON_CODES: &[(u8, &str)] = &[
    (0, "Success"),
    (5, "Too Few Data Bytes Received"),
    (6, "Device-Specific Command Error"),
    (16, "Access Restricted"),
    (32, "Busy"),
    (33, "Delayed Response Initiated"),
    (34, "Delayed Response Running"),
    (35, "Delayed Response Dead"),
    (36, "Delayed Response Conflict"),
];

/// Response codes of the commands that write (the common ones and write protection).
pub const WRITE_CODES: &[(u8, &str)] = &[
    (0, "Success"),
    (5, "Too Few Data Bytes Received"),
    (6, "Device-Specific Command Error"),
    (7, "In Write Protect Mode"),
    (16, "Access Restricted"),
    (32, "Busy"),
    (33, "Delayed Response Initiated"),
    (34, "Delayed Response Running"),
    (35, "Delayed Response Dead"),
    (36, "Delayed Response Conflict"),
    (
        65,
        "Command-specific error (see the command's specification)",
    ),
];

/// What the table knows of one command.
#[derive(Debug, Clone, Copy)]
pub struct CommandInfo {
    /// Command number.
    pub number: u16,
    /// Name (the Rust variant).
    pub name: &'static str,
    /// Title.
    pub title: &'static str,
    /// Its response codes.
    pub codes: &'static [(u8, &'static str)],
}

/// Why a command's data could not be decoded by its layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandError {
    /// A response with no response code.
    NoResponseCode,
    /// The layout did not fit.
    Layout(DecodeError),
}

impl fmt::Display for CommandError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CommandError::NoResponseCode => f.write_str("a response with no response code"),
            CommandError::Layout(e) => e.fmt(f),
        }
    }
}

macro_rules! commands {
    ( $( $num:literal $variant:ident $codes:ident $title:literal : $req:ty => $resp:ty ; )* ) => {
        /// A typed wireless command request.
        #[derive(Debug, Clone, Copy, PartialEq)]
        #[allow(missing_docs)]
        pub enum Request { $( $variant($req), )* }

        /// A typed wireless command response body (after the response code).
        #[derive(Debug, Clone, Copy, PartialEq)]
        #[allow(missing_docs, clippy::large_enum_variant)]
        pub enum Response { $( $variant($resp), )* }

        /// Every wireless command typed here, in number order.
        pub static COMMANDS: &[CommandInfo] = &[ $(
            CommandInfo { number: $num, name: stringify!($variant), title: $title, codes: $codes },
        )* ];

        /// Decodes request data; `None` for a command this table does not type.
        pub fn decode_request(command: u16, data: &[u8]) -> Option<Result<Request, DecodeError>> {
            match command {
                $( $num => Some(<$req as Wire>::decode(&mut Reader::new(data)).map(Request::$variant)), )*
                _ => None,
            }
        }

        /// Decodes a response body (the data after the response code); `None` for a
        /// command this table does not type.
        pub fn decode_response_body(command: u16, data: &[u8]) -> Option<Result<Response, DecodeError>> {
            match command {
                $( $num => Some(<$resp as Wire>::decode(&mut Reader::new(data)).map(Response::$variant)), )*
                _ => None,
            }
        }

        /// Builds a request from named fields; `None` for a command not typed here.
        pub fn build_request(command: u16, src: &mut dyn Source) -> Option<Result<Request, BuildError>> {
            match command {
                $( $num => Some(<$req as Wire>::build("request", src).map(Request::$variant)), )*
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
            /// Reports every field to `v`.
            pub fn describe(&self, v: &mut dyn Visitor) {
                match self { $( Request::$variant(x) => x.describe("request", 0, v), )* }
            }
        }

        impl Response {
            /// The command number.
            pub fn command(&self) -> u16 {
                match self { $( Response::$variant(_) => $num, )* }
            }
            /// Encodes the body (without response code).
            pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
                match self { $( Response::$variant(x) => x.encode(w), )* }
            }
            /// Reports every field to `v`.
            pub fn describe(&self, v: &mut dyn Visitor) {
                match self { $( Response::$variant(x) => x.describe("response", 0, v), )* }
            }
        }
    };
}

commands! {
    777 ReadWirelessCapabilities COMMON_CODES "Read Wireless Device Capabilities" : Empty => WirelessCapabilities;
    779 ReportDeviceHealth COMMON_CODES "Report Device Health" : Empty => DeviceHealth;
    787 ReportNeighborSignalLevels COMMON_CODES "Report Neighbor Signal Levels" : NeighborTableSelect => NeighborSignalLevels;
    793 WriteUtcTimeMapping WRITE_CODES "Write UTC Time Mapping" : UtcTimeMapping => UtcTimeMapping;
    795 WriteTimerInterval WRITE_CODES "Write Timer Interval" : TimerInterval => TimerInterval;
    799 RequestService COMMON_CODES "Request Service" : ServiceRequest => Service;
    805 WriteRadioCcaMode WRITE_CODES "Write Radio CCA Mode" : CcaMode => CcaMode;
    808 ReadPacketTtl COMMON_CODES "Read Time-to-Live" : Empty => PacketTtl;
    960 DisconnectDevice WRITE_CODES "Disconnect Device" : Disconnect => Disconnect;
    961 WriteNetworkKey WRITE_CODES "Write Network Key" : NetworkKey => NetworkKey;
    962 WriteNickname WRITE_CODES "Write Device Nickname Address" : Nickname => Nickname;
    963 WriteSession WRITE_CODES "Write Session" : SessionRequest => SessionResponse;
    965 WriteSuperframe WRITE_CODES "Write Superframe" : Superframe => SuperframeWritten;
    967 WriteLink WRITE_CODES "Write Link" : Link => LinkWritten;
    971 WriteNeighborFlags WRITE_CODES "Write Neighbor Property Flag" : NeighborFlags => NeighborFlags;
    972 SuspendDevices WRITE_CODES "Suspend Devices" : Suspend => Suspend;
    973 WriteService WRITE_CODES "Write Service" : Service => ServiceWritten;
    974 WriteRoute WRITE_CODES "Write Route" : Route => RouteWritten;
}

/// The table entry of a wireless command.
pub fn info(command: u16) -> Option<&'static CommandInfo> {
    COMMANDS.iter().find(|c| c.number == command)
}

/// Vendor-specific commands (64512-65535) stay raw.
pub fn is_vendor(command: u16) -> bool {
    command >= 64512
}

/// A short name for listings: the table's name, hart-proto's for wired commands,
/// `vendor` for 64512 and up, `unknown` otherwise.
pub fn name(command: u16) -> &'static str {
    if let Some(i) = info(command) {
        return i.name;
    }
    if let Some(i) = hart_proto::command::info(command) {
        return i.name;
    }
    if is_vendor(command) {
        "vendor"
    } else {
        "unknown"
    }
}

/// The name of a response code of `command`.
pub fn code_name(command: u16, code: u8) -> Option<&'static str> {
    let codes = info(command).map_or(COMMON_CODES, |i| i.codes);
    codes.iter().find(|(c, _)| *c == code).map(|(_, n)| *n)
}

/// A command decoded by its layout.
#[derive(Debug, Clone, PartialEq)]
pub enum Typed {
    /// A wireless request.
    Request(Request),
    /// A wireless response: its code and, unless only the code was sent, the body.
    Response(u8, Option<Response>),
    /// A wired request (hart-proto's table).
    WiredRequest(hart_proto::Request),
    /// A wired response: code and body.
    #[allow(clippy::large_enum_variant)]
    WiredResponse(u8, Option<hart_proto::Response>),
    /// A vendor-specific command (64512 and up), kept raw.
    Vendor,
}

/// Decodes a command of a transport PDU by its typed layout; `None` for a command no
/// table types (and that is not vendor-specific).
pub fn decode(command: u16, response: bool, data: &[u8]) -> Option<Result<Typed, CommandError>> {
    if is_vendor(command) {
        return Some(Ok(Typed::Vendor));
    }
    if !response {
        if let Some(r) = decode_request(command, data) {
            return Some(r.map(Typed::Request).map_err(CommandError::Layout));
        }
        return hart_proto::decode_request(command, data)
            .map(|r| r.map(Typed::WiredRequest).map_err(CommandError::Layout));
    }
    let Some((&code, body)) = data.split_first() else {
        return (info(command).is_some() || hart_proto::command::info(command).is_some())
            .then_some(Err(CommandError::NoResponseCode));
    };
    let only_code = body.is_empty() && code != 0;
    if info(command).is_some() {
        if only_code {
            return Some(Ok(Typed::Response(code, None)));
        }
        return decode_response_body(command, body).map(|r| {
            r.map(|b| Typed::Response(code, Some(b)))
                .map_err(CommandError::Layout)
        });
    }
    if hart_proto::command::info(command).is_some() {
        if only_code {
            return Some(Ok(Typed::WiredResponse(code, None)));
        }
        return hart_proto::decode_response(command, body).map(|r| {
            r.map(|b| Typed::WiredResponse(code, Some(b)))
                .map_err(CommandError::Layout)
        });
    }
    None
}

/// Encodes a typed command back to its data bytes (`None` for [`Typed::Vendor`],
/// whose bytes are kept by the caller).
pub fn encode(t: &Typed) -> Option<Vec<u8>> {
    let mut buf = [0u8; 256];
    let mut w = Writer::new(&mut buf);
    let ok = match t {
        Typed::Request(r) => r.encode(&mut w),
        Typed::WiredRequest(r) => r.encode(&mut w),
        Typed::Response(code, body) => w.u8(*code).and_then(|_| match body {
            Some(b) => b.encode(&mut w),
            None => Ok(()),
        }),
        Typed::WiredResponse(code, body) => w.u8(*code).and_then(|_| match body {
            Some(b) => b.encode(&mut w),
            None => Ok(()),
        }),
        Typed::Vendor => return None,
    };
    ok.ok().map(|_| w.written().to_vec())
}

/// Reports the fields of a typed command to `v`.
pub fn describe(t: &Typed, v: &mut dyn Visitor) {
    match t {
        Typed::Request(r) => r.describe(v),
        Typed::WiredRequest(r) => r.describe(v),
        Typed::Response(_, Some(b)) => b.describe(v),
        Typed::WiredResponse(_, Some(b)) => b.describe(v),
        _ => {}
    }
}
