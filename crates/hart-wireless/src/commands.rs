//! Typed layouts of the WirelessHART commands, defined as data on hart-proto's
//! [`wire_struct!`](hart_proto::wire_struct) machinery: one field list per layout
//! drives decoding, encoding, the length limits and the field-by-field description
//! ([`Visitor`]), as for the wired commands.
//!
//! In a transport PDU a request carries the layout's bytes; a response carries its
//! response code first, then the layout (only the code when the code is an error).
//! The layouts of the commands the public captures carry (777, 779, 787, 793, 795, 799,
//! 805, 808, 961-963, 965, 967, 971, 973, 974) are checked against them
//! (`tests/captures.rs`); the others follow one public source (the field order and
//! widths of an open-source stack's codecs, taken as facts) and are not yet confirmed
//! by traffic. "(uncertain)" marks a field whose meaning is not confirmed.

use alloc::vec::Vec;
use core::fmt;

use hart_proto::types::{Bytes, Date, HartTime, Latin1String};
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
    /// 779 response, HART 7.0 form (9 bytes): one-byte MIC failure counters.
    pub struct DeviceHealth70 {
        /// Packets generated by the device.
        pub generated: u16,
        /// Packets terminated by the device.
        pub terminated: u16,
        /// Data-link MIC failures.
        pub dl_mic_failures: u8,
        /// Network MIC failures.
        pub nl_mic_failures: u8,
        /// Power status (0 nominal, 1 low, 2 critically low, 3 recharging low, 4 recharging high).
        pub power_status: u8,
        /// CRC errors.
        pub crc_errors: u8,
        /// Unicast nonce counter values not received.
        pub nonce_not_received: u8,
    }
}

wire_struct! {
    /// 779 response, later form: two-byte MIC failure counters (as whad reads it and
    /// as the captures carry it, 31 bytes); the counters after the CRC errors differ
    /// between revisions and are kept raw (uncertain).
    pub struct DeviceHealthLong {
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

/// 779 response: the form is chosen by the length (the command's length byte): 9
/// bytes is HART 7.0's, anything else the later form with wider counters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DeviceHealth {
    /// HART 7.0.
    V70(DeviceHealth70),
    /// Later revisions.
    Long(DeviceHealthLong),
}

impl Default for DeviceHealth {
    fn default() -> Self {
        DeviceHealth::V70(DeviceHealth70::default())
    }
}

impl Wire for DeviceHealth {
    const MIN_LEN: usize = 9;
    const MAX_LEN: usize = DeviceHealthLong::MAX_LEN;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        if r.remaining() == 9 {
            DeviceHealth70::decode(r).map(DeviceHealth::V70)
        } else {
            DeviceHealthLong::decode(r).map(DeviceHealth::Long)
        }
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        match self {
            DeviceHealth::V70(x) => x.encode(w),
            DeviceHealth::Long(x) => x.encode(w),
        }
    }
    fn encoded_len(&self) -> usize {
        match self {
            DeviceHealth::V70(x) => x.encoded_len(),
            DeviceHealth::Long(x) => x.encoded_len(),
        }
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        match self {
            DeviceHealth::V70(x) => x.describe(name, offset, v),
            DeviceHealth::Long(x) => x.describe(name, offset, v),
        }
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        // The later form when its raw tail is given, else HART 7.0's.
        if src.value("more")?.is_some() {
            DeviceHealthLong::build(name, src).map(DeviceHealth::Long)
        } else {
            DeviceHealth70::build(name, src).map(DeviceHealth::V70)
        }
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
        /// 0 user initiated, 1 communication failure (uncertain: one source).
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
        /// Bit 0 time source, bit 7 no links (uncertain).
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

wire_struct! {
    /// 768 request and response: the join key.
    pub struct JoinKey {
        /// The key.
        pub key: Fixed<16>,
    }
}

wire_struct! {
    /// 769 response: join status.
    pub struct JoinStatus {
        /// Wireless operation mode.
        pub wireless_mode: u8,
        /// Join status bits.
        pub join_status: u16,
        /// Neighbours heard.
        pub available_neighbors: u8,
        /// Advertisements received.
        pub advertisements_received: u8,
        /// Join attempts.
        pub join_attempts: u8,
        /// Join retry timer (1/32 ms).
        pub join_retry_timer: HartTime,
        /// Network search timer (1/32 ms).
        pub network_search_timer: HartTime,
    }
}

wire_struct! {
    /// 773 request and response, 774 response: the network ID.
    pub struct NetworkId {
        /// Network ID (the 802.15.4 PAN ID).
        pub network_id: u16,
    }
}

wire_struct! {
    /// 778 response: battery life.
    pub struct BatteryLife {
        /// Days of battery life left.
        pub days_remaining: u16,
    }
}

wire_struct! {
    /// One neighbour's health (780).
    pub struct NeighborHealth {
        /// The neighbour's nickname.
        pub nickname: u16,
        /// Bit 0 time source, bit 7 no links.
        pub flags: u8,
        /// Mean received signal level since the last report, dBm.
        pub mean_rsl: Rsl,
        /// Packets sent to it.
        pub transmitted: u16,
        /// Failed transmissions to it.
        pub failed: u16,
        /// Packets received from it.
        pub received: u16,
    }
}

wire_struct! {
    /// 780 response: the neighbour health list.
    pub struct NeighborHealthList {
        /// First neighbour table index.
        pub index: u8,
        /// Entries in this response.
        pub entries: u8,
        /// Neighbours in the table.
        pub total: u8,
        /// The entries.
        pub neighbors: List<NeighborHealth, 25>,
    }
}

wire_struct! {
    /// 788 (path down), 791 (transport layer failed) alarms: a nickname.
    pub struct AlarmNickname {
        /// The neighbour or peer that cannot be reached.
        pub nickname: u16,
    }
}

wire_struct! {
    /// 789 alarm: a source route failed.
    pub struct SourceRouteFailed {
        /// The neighbour that could not be reached.
        pub nickname: u16,
        /// The network MIC of the packet that failed.
        pub npdu_mic: u32,
    }
}

wire_struct! {
    /// 790 alarm: a graph route failed.
    pub struct GraphRouteFailed {
        /// The graph ID.
        pub graph_id: u16,
    }
}

wire_struct! {
    /// 794 response: UTC time.
    pub struct UtcTime {
        /// Date.
        pub date: Date,
        /// Time of day (1/32 ms).
        pub time: HartTime,
    }
}

wire_struct! {
    /// 800 request: which services to list (also 780 and 787 requests' shape).
    pub struct ListSelect {
        /// First index.
        pub index: u8,
        /// Entries to read.
        pub count: u8,
    }
}

wire_struct! {
    /// 800 response: the service list.
    pub struct ServiceList {
        /// First index.
        pub index: u8,
        /// Entries in this response.
        pub entries: u8,
        /// Active services.
        pub active: u8,
        /// The services.
        pub services: List<Service, 25>,
    }
}

wire_struct! {
    /// 801 request: delete a service.
    pub struct DeleteService {
        /// Service ID.
        pub service_id: u8,
        /// Reason code.
        pub reason: u8,
    }
}

wire_struct! {
    /// 801 response: the service deleted and the entries left.
    pub struct ServiceDeleted {
        /// Service ID.
        pub service_id: u8,
        /// Reason code.
        pub reason: u8,
        /// Service entries left.
        pub remaining: u8,
    }
}

wire_struct! {
    /// 814 request: part of a device list.
    pub struct DeviceListSelect {
        /// Which list (0 active, 1 whitelist, 2 blacklist ...).
        pub list: u8,
        /// Entries to read.
        pub count: u8,
        /// First index.
        pub start: u16,
    }
}

wire_struct! {
    /// 814 response: device list entries (unique IDs).
    pub struct DeviceList {
        /// Which list.
        pub list: u8,
        /// Entries in this response.
        pub entries: u8,
        /// First index.
        pub start: u16,
        /// Entries in the list.
        pub total: u16,
        /// The unique IDs.
        pub unique_ids: List<Fixed<5>, 48>,
    }
}

wire_struct! {
    /// 817 response: the channel blacklist.
    pub struct ChannelBlacklist {
        /// Bits in the channel map.
        pub bits: u8,
        /// Channels in use (bit set: channel used).
        pub current: u16,
        /// Channels to use from the next change.
        pub pending: u16,
    }
}

wire_struct! {
    /// 818 request and response: a new channel map.
    pub struct WriteChannelMap {
        /// Bits in the channel map.
        pub bits: u8,
        /// The new map.
        pub pending: u16,
    }
}

wire_struct! {
    /// Gateway commands' device selector (836, 838, 839, 840, 843 requests).
    pub struct UniqueIdSelect {
        /// The device's unique ID.
        pub unique_id: Fixed<5>,
    }
}

wire_struct! {
    /// 832 response: a device's identity.
    pub struct NetworkDeviceIdentity {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// Nickname.
        pub nickname: u16,
        /// Long tag.
        pub long_tag: Latin1String<32>,
    }
}

wire_struct! {
    /// 833 request: a device's neighbours.
    pub struct NeighborHealthSelect {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// First index.
        pub index: u8,
        /// Entries to read.
        pub count: u8,
    }
}

wire_struct! {
    /// One neighbour of 833.
    pub struct GatewayNeighbor {
        /// Nickname.
        pub nickname: u16,
        /// Received signal level, dBm.
        pub rsl: Rsl,
        /// Packets sent to it.
        pub transmitted: u32,
        /// Packets sent without ACK.
        pub not_acknowledged: u32,
        /// Packets received from it.
        pub received: u32,
    }
}

wire_struct! {
    /// 833 response: a device's neighbours' health.
    pub struct NetworkDeviceNeighbors {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// First index.
        pub index: u8,
        /// Entries in this response.
        pub entries: u8,
        /// The neighbours.
        pub neighbors: List<GatewayNeighbor, 16>,
    }
}

wire_struct! {
    /// 834 request: a device's graph.
    pub struct TopologySelect {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// Graph index.
        pub graph_index: u16,
    }
}

wire_struct! {
    /// 834 response: one graph of a device and its neighbours on it.
    pub struct Topology {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// Graph index.
        pub graph_index: u16,
        /// Graphs of the device.
        pub total_graphs: u16,
        /// Graph ID.
        pub graph_id: u16,
        /// Neighbours on it.
        pub neighbor_count: u16,
        /// Their nicknames.
        pub neighbors: List<u16, 120>,
    }
}

wire_struct! {
    /// One burst command of 835.
    pub struct BurstCount {
        /// Command burst.
        pub command: u16,
        /// Burst packets received.
        pub received: u32,
    }
}

wire_struct! {
    /// 835 response: a device's burst messages.
    pub struct BurstMessageList {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// Burst commands.
        pub count: u8,
        /// The commands.
        pub commands: List<BurstCount, 40>,
    }
}

wire_struct! {
    /// 837 request and response, 838 response: notification mask.
    pub struct NotificationMask {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// Change notification flags.
        pub flags: u16,
    }
}

wire_struct! {
    /// 839 response: change notifications.
    pub struct ChangeNotifications {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// Notifications.
        pub count: u8,
        /// Changed command numbers.
        pub commands: List<u16, 10>,
    }
}

wire_struct! {
    /// 840 response: device statistics.
    pub struct DeviceStatistics {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// Active graphs.
        pub graphs: u16,
        /// Active superframes.
        pub frames: u16,
        /// Active links.
        pub links: u16,
        /// Neighbours.
        pub neighbors: u8,
        /// Average latency (1/32 ms).
        pub average_latency: HartTime,
        /// Joins.
        pub join_count: u16,
        /// Date of the last join.
        pub last_join_date: Date,
        /// Time of the last join (1/32 ms).
        pub last_join_time: HartTime,
        /// Packets generated.
        pub generated: u32,
        /// Packets terminated.
        pub terminated: u32,
        /// Data-link MIC failures.
        pub dl_mic_failures: u32,
        /// Network MIC failures.
        pub nl_mic_failures: u32,
        /// CRC errors.
        pub crc_errors: u32,
        /// Nonce counter values not received by the device.
        pub nonce_not_received_by: u32,
        /// Nonce counter values not received from the device.
        pub nonce_not_received_from: u32,
        /// Standard deviation of latency (1/32 ms).
        pub latency_deviation: HartTime,
    }
}

wire_struct! {
    /// 841 response: a device's identity by nickname.
    pub struct IdentityByNickname {
        /// Nickname.
        pub nickname: u16,
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// Long tag.
        pub long_tag: Latin1String<32>,
    }
}

wire_struct! {
    /// 842 request and response, 843 response: scheduling flags.
    pub struct SchedulingFlags {
        /// Unique ID.
        pub unique_id: Fixed<5>,
        /// Flags.
        pub flags: u8,
    }
}

wire_struct! {
    /// 844 response, 845 request and response: network constraints.
    pub struct NetworkConstraints {
        /// Network flags.
        pub flags: u8,
        /// Request/response pairs per ten seconds.
        pub pairs_per_ten_seconds: u8,
    }
}

wire_struct! {
    /// 964 request: delete a session.
    pub struct DeleteSession {
        /// 0 unicast, 1 broadcast, 2 join.
        pub session_type: u8,
        /// Peer nickname.
        pub peer: u16,
    }
}

wire_struct! {
    /// 964 response.
    pub struct SessionDeleted {
        /// 0 unicast, 1 broadcast, 2 join.
        pub session_type: u8,
        /// Peer nickname.
        pub peer: u16,
        /// Session entries left.
        pub remaining: u8,
    }
}

wire_struct! {
    /// 966 request: delete a superframe.
    pub struct SuperframeId {
        /// Superframe ID.
        pub superframe_id: u8,
    }
}

wire_struct! {
    /// 966 response.
    pub struct SuperframeDeleted {
        /// Superframe ID.
        pub superframe_id: u8,
        /// Superframe entries left.
        pub remaining: u8,
    }
}

wire_struct! {
    /// 968 request: delete a link.
    pub struct DeleteLink {
        /// Superframe ID.
        pub superframe_id: u8,
        /// Slot.
        pub slot: u16,
        /// Neighbour nickname.
        pub neighbor: u16,
    }
}

wire_struct! {
    /// 968 response.
    pub struct LinkDeleted {
        /// Superframe ID.
        pub superframe_id: u8,
        /// Slot.
        pub slot: u16,
        /// Neighbour nickname.
        pub neighbor: u16,
        /// Link entries left.
        pub remaining: u16,
    }
}

wire_struct! {
    /// 969, 970 requests: a graph edge.
    pub struct GraphEdge {
        /// Graph ID.
        pub graph_id: u16,
        /// Neighbour nickname.
        pub neighbor: u16,
    }
}

wire_struct! {
    /// 969, 970 responses.
    pub struct GraphEdgeWritten {
        /// Graph ID.
        pub graph_id: u16,
        /// Neighbour nickname.
        pub neighbor: u16,
        /// Connection entries left.
        pub remaining: u8,
    }
}

wire_struct! {
    /// 975, 977 requests, 977 response: a route ID.
    pub struct RouteId {
        /// Route ID.
        pub route_id: u8,
    }
}

wire_struct! {
    /// 975 response.
    pub struct RouteDeleted {
        /// Route ID.
        pub route_id: u8,
        /// Route entries left.
        pub remaining: u8,
    }
}

wire_struct! {
    /// 976 request: a source route.
    pub struct SourceRoute {
        /// Route ID.
        pub route_id: u8,
        /// Hops.
        pub hop_count: u8,
        /// The hops' nicknames (1 to 8).
        pub hops: List<u16, 8>,
    }
}

wire_struct! {
    /// 976 response.
    pub struct SourceRouteWritten {
        /// Route ID.
        pub route_id: u8,
        /// Hops.
        pub hop_count: u8,
        /// The hops' nicknames (1 to 8).
        pub hops: List<u16, 8>,
        /// Source route entries left.
        pub remaining: u8,
    }
}

wire_struct! {
    /// 796 request: which timer.
    pub struct TimerSelect {
        /// Timer type (as in 795).
        pub timer_type: u8,
    }
}

wire_struct! {
    /// 797 request and response, 798 response: radio output power.
    pub struct RadioPower {
        /// Output power, dBm.
        pub power: Rsl,
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

/// What the table knows of one command.
#[derive(Debug, Clone, Copy)]
pub struct CommandInfo {
    /// Command number.
    pub number: u16,
    /// Name (the Rust variant).
    pub name: &'static str,
    /// Title.
    pub title: &'static str,
}

impl CommandInfo {
    /// Its response codes.
    pub fn codes(&self) -> &'static [(u8, &'static str)] {
        response_codes(self.number)
    }
}

/// The response codes of `command`: its own list where known, else the common ones.
pub fn response_codes(command: u16) -> &'static [(u8, &'static str)] {
    crate::codes::RESPONSE_CODES
        .iter()
        .find(|(n, _)| *n == command)
        .map_or(COMMON_CODES, |(_, c)| *c)
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
    ( $( $num:literal $variant:ident $title:literal : $req:ty => $resp:ty ; )* ) => {
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
            CommandInfo { number: $num, name: stringify!($variant), title: $title },
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
    768 WriteJoinKey "Write Join Key" : JoinKey => JoinKey;
    769 ReadJoinStatus "Read Join Status" : Empty => JoinStatus;
    773 WriteNetworkId "Write Network ID" : NetworkId => NetworkId;
    774 ReadNetworkId "Read Network ID" : Empty => NetworkId;
    777 ReadWirelessCapabilities "Read Wireless Device Capabilities" : Empty => WirelessCapabilities;
    778 ReadBatteryLife "Read Battery Life" : Empty => BatteryLife;
    779 ReportDeviceHealth "Report Device Health" : Empty => DeviceHealth;
    780 ReportNeighborHealthList "Report Neighbor Health List" : ListSelect => NeighborHealthList;
    787 ReportNeighborSignalLevels "Report Neighbor Signal Levels" : NeighborTableSelect => NeighborSignalLevels;
    788 AlarmPathDown "Alarm: Path Down" : Empty => AlarmNickname;
    789 AlarmSourceRouteFailed "Alarm: Source Route Failed" : Empty => SourceRouteFailed;
    790 AlarmGraphRouteFailed "Alarm: Graph Route Failed" : Empty => GraphRouteFailed;
    791 AlarmTransportLayerFailed "Alarm: Transport Layer Failed" : Empty => AlarmNickname;
    793 WriteUtcTimeMapping "Write UTC Time Mapping" : UtcTimeMapping => UtcTimeMapping;
    794 ReadUtcTime "Read UTC Time" : Empty => UtcTime;
    795 WriteTimerInterval "Write Timer Interval" : TimerInterval => TimerInterval;
    796 ReadTimerInterval "Read Timer Interval" : TimerSelect => TimerInterval;
    797 WriteRadioPower "Write Radio Power Output" : RadioPower => RadioPower;
    798 ReadRadioPower "Read Radio Power Output" : Empty => RadioPower;
    799 RequestService "Request Service" : ServiceRequest => Service;
    800 ReadServiceList "Read Service List" : ListSelect => ServiceList;
    801 DeleteService "Delete Service" : DeleteService => ServiceDeleted;
    805 WriteRadioCcaMode "Write Radio CCA Mode" : CcaMode => CcaMode;
    808 ReadPacketTtl "Read Time-to-Live" : Empty => PacketTtl;
    814 ReadDeviceListEntries "Read Device List Entries" : DeviceListSelect => DeviceList;
    817 ReadChannelBlacklist "Read Channel Blacklist" : Empty => ChannelBlacklist;
    818 WriteChannelBlacklist "Write Channel Blacklist" : WriteChannelMap => WriteChannelMap;
    832 ReadNetworkDeviceIdentity "Read Network Device Identity" : UniqueIdSelect => NetworkDeviceIdentity;
    833 ReadNetworkDeviceNeighborHealth "Read Network Device's Neighbor Health" : NeighborHealthSelect => NetworkDeviceNeighbors;
    834 ReadNetworkTopology "Read Network Topology Information" : TopologySelect => Topology;
    835 ReadBurstMessageList "Read Burst Message List" : UniqueIdSelect => BurstMessageList;
    836 FlushCachedResponses "Flush Cached Responses for a Device" : UniqueIdSelect => UniqueIdSelect;
    837 WriteUpdateNotificationMask "Write Update Notification Bit Mask" : NotificationMask => NotificationMask;
    838 ReadUpdateNotificationMask "Read Update Notification Bit Mask" : UniqueIdSelect => NotificationMask;
    839 ChangeNotification "Change Notification" : UniqueIdSelect => ChangeNotifications;
    840 ReadDeviceStatistics "Read Device's Statistics" : UniqueIdSelect => DeviceStatistics;
    841 ReadIdentityByNickname "Read Network Device Identity by Nickname" : Nickname => IdentityByNickname;
    842 WriteSchedulingFlags "Write Device's Scheduling Flags" : SchedulingFlags => SchedulingFlags;
    843 ReadSchedulingFlags "Read Device's Scheduling Flags" : UniqueIdSelect => SchedulingFlags;
    844 ReadNetworkConstraints "Read Network Constraints" : Empty => NetworkConstraints;
    845 WriteNetworkConstraints "Write Network Constraints" : NetworkConstraints => NetworkConstraints;
    960 DisconnectDevice "Disconnect Device" : Disconnect => Disconnect;
    961 WriteNetworkKey "Write Network Key" : NetworkKey => NetworkKey;
    962 WriteNickname "Write Device Nickname Address" : Nickname => Nickname;
    963 WriteSession "Write Session" : SessionRequest => SessionResponse;
    964 DeleteSession "Delete Session" : DeleteSession => SessionDeleted;
    965 WriteSuperframe "Write Superframe" : Superframe => SuperframeWritten;
    966 DeleteSuperframe "Delete Superframe" : SuperframeId => SuperframeDeleted;
    967 WriteLink "Write Link" : Link => LinkWritten;
    968 DeleteLink "Delete Link" : DeleteLink => LinkDeleted;
    969 WriteGraphNeighbor "Write Graph Neighbor Pair" : GraphEdge => GraphEdgeWritten;
    970 DeleteGraphConnection "Delete Graph Connection" : GraphEdge => GraphEdgeWritten;
    971 WriteNeighborFlags "Write Neighbor Property Flag" : NeighborFlags => NeighborFlags;
    972 SuspendDevices "Suspend Devices" : Suspend => Suspend;
    973 WriteService "Write Service" : Service => ServiceWritten;
    974 WriteRoute "Write Route" : Route => RouteWritten;
    975 DeleteRoute "Delete Route" : RouteId => RouteDeleted;
    976 WriteSourceRoute "Write Source Route" : SourceRoute => SourceRouteWritten;
    977 DeleteSourceRoute "Delete Source Route" : RouteId => RouteId;
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
    response_codes(command)
        .iter()
        .find(|(c, _)| *c == code)
        .map(|(_, n)| *n)
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
