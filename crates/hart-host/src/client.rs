//! The master client: the `hart-link` master state machine driven over a [`Transport`],
//! with device discovery, typed and raw commands, automatic command 48, and a log of
//! the raw traffic.

use std::collections::VecDeque;

use hart_link::master::{MasterOutput, RetryPolicy};
use hart_link::{LinkError, Master, Micros};
use hart_proto::command::{
    Empty, Identity, IoSystemCapabilities, LongTag, SubDeviceIndex, SubDeviceSummary, TagRequest,
};
use hart_proto::frame::{
    Address, Frame, FrameSpec, LongAddress, MasterKind, ShortAddress, UniqueId,
};
use hart_proto::tables::field_device_status as fds;
use hart_proto::tables::{response_class, response_code_name, ResponseClass};
use hart_proto::types::{Latin1String, PackedString};
use hart_proto::wire::{Reader, Wire};
use hart_proto::Request;

use crate::error::HostError;
use crate::transport::{RxChar, Transport};

/// A reply from a device.
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    /// Response code (success or warning; errors are [`HostError::Device`]).
    pub response_code: u8,
    /// Field device status.
    pub device_status: u8,
    /// Data after the status bytes (and after any extended command number).
    pub data: Vec<u8>,
    /// The reply frame (delimiter through check byte).
    pub pdu: Vec<u8>,
    /// Command 48 data, read automatically when the device said "more status available".
    pub additional_status: Option<Vec<u8>>,
}

/// How to reach a device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceRef {
    /// By polling address (command 0 in a short frame finds its long address).
    Poll(u8),
    /// By tag (command 11, broadcast).
    Tag(String),
    /// By long tag (command 21, broadcast).
    LongTag(String),
    /// By unique ID (10 hex digits).
    UniqueId(UniqueId),
}

impl core::fmt::Display for DeviceRef {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DeviceRef::Poll(p) => write!(f, "polling address {p}"),
            DeviceRef::Tag(t) => write!(f, "tag {t:?}"),
            DeviceRef::LongTag(t) => write!(f, "long tag {t:?}"),
            DeviceRef::UniqueId(id) => write!(f, "unique ID {id}"),
        }
    }
}

/// What the client knows about a device.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceInfo {
    /// Polling address, when found by one.
    pub polling_address: Option<u8>,
    /// Command 0 identity.
    pub identity: Identity,
    /// Tag (command 13), when read.
    pub tag: Option<String>,
    /// Descriptor (command 13), when read.
    pub descriptor: Option<String>,
    /// Long tag (command 20, HART 6+), when read.
    pub long_tag: Option<String>,
    /// Reached through an I/O system (a HART-IP gateway or multiplexer): its I/O card
    /// and channel, from command 84.
    pub io_channel: Option<(u8, u8)>,
}

impl DeviceInfo {
    /// A device known by its command 0 identity (found at `polling_address`, or by
    /// another address), tags not read yet.
    pub fn identified(identity: Identity, polling_address: Option<u8>) -> Self {
        DeviceInfo {
            polling_address,
            identity,
            tag: None,
            descriptor: None,
            long_tag: None,
            io_channel: None,
        }
    }

    /// Long-frame identifier.
    pub fn unique_id(&self) -> UniqueId {
        self.identity.unique_id()
    }

    /// HART universal revision.
    pub fn revision(&self) -> u8 {
        self.identity.universal_revision
    }

    /// Manufacturer ID: HART 7's 16-bit code, or byte 1 for HART 5/6.
    pub fn manufacturer_id(&self) -> u16 {
        self.identity
            .manufacturer_id
            .unwrap_or(self.identity.expanded_device_type >> 8)
    }

    /// Whether the device is an I/O system (gateway, multiplexer) with sub-devices:
    /// command 0 flag 0x04, "protocol bridge device", as hosts recognise one.
    pub fn is_io_system(&self) -> bool {
        self.identity.flags.0 & 0x04 != 0
    }
}

/// What [`Client::scan`] reports as it goes.
#[derive(Debug, Clone, Copy)]
pub enum ScanEvent<'a> {
    /// A polling address was tried: the device there (tags read), or none.
    Address {
        /// The polling address.
        poll: u8,
        /// The device found there.
        found: Option<&'a DeviceInfo>,
    },
    /// A sub-device listed by an I/O system the scan found (command 84), tags read.
    SubDevice(&'a DeviceInfo),
}

/// Direction of a logged transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Sent by this master.
    Tx,
    /// Received.
    Rx,
}

/// One logged transfer of raw bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogEntry {
    /// Transport time, µs.
    pub time_us: Micros,
    /// Direction.
    pub direction: Direction,
    /// The bytes.
    pub bytes: Vec<u8>,
}

/// Receives every raw transfer.
pub type LogSink = Box<dyn FnMut(&LogEntry)>;

/// The master client.
pub struct Client<T: Transport> {
    transport: T,
    master: Master,
    kind: MasterKind,
    policy: RetryPolicy,
    /// Read command 48 automatically when a reply says "more status available".
    pub auto_status: bool,
    bursts: VecDeque<Vec<u8>>,
    log: Option<LogSink>,
    known: Vec<DeviceInfo>,
    /// Since when the transport's carrier detect has been on.
    carrier_since: Option<Micros>,
    /// When the last character arrived.
    last_rx: Micros,
    /// Over HART-IP: cuts what arrives into frames, so that published burst frames go
    /// to the burst queue and never into the master's view of a line (there is none:
    /// a burst message may arrive while a request waits for its reply, which on a
    /// real loop cannot happen and would make the master start over).
    ip_frames: Option<hart_proto::deframer::Deframer>,
}

/// A sub-device as command 84 (read sub-device identity summary) describes it: index
/// (2 bytes), I/O card, channel, manufacturer ID (2), expanded device type (2), device
/// ID (3), universal revision, long tag (32), then, from HART 7 on, device revision,
/// device profile and private label distributor (2).
/// The data of `request`, or a usage error naming what does not encode.
fn request_data(request: &Request) -> Result<Vec<u8>, HostError> {
    request.to_vec().map_err(|e| {
        HostError::Usage(format!(
            "command {}'s request does not encode: {e}",
            request.command()
        ))
    })
}

fn summary_identity(d: &[u8]) -> Option<DeviceInfo> {
    let s = SubDeviceSummary::decode(&mut Reader::new(d)).ok()?;
    let identity = Identity {
        expansion_code: 254,
        expanded_device_type: s.expanded_device_type,
        min_request_preambles: 5,
        universal_revision: s.universal_revision,
        device_revision: s.device_revision.unwrap_or(0),
        software_revision: 0,
        hardware: Default::default(),
        flags: Default::default(),
        device_id: s.device_id,
        min_response_preambles: None,
        max_device_variables: None,
        config_change_counter: None,
        extended_status: None,
        manufacturer_id: Some(s.manufacturer_id),
        private_label_distributor: s.private_label_distributor,
        device_profile: s.device_profile,
    };
    Some(DeviceInfo {
        polling_address: None,
        identity,
        tag: None,
        descriptor: None,
        long_tag: Some(s.long_tag.to_string()),
        io_channel: Some((s.io_card, s.channel)),
    })
}

impl<T: Transport> Client<T> {
    /// A primary master on `transport`.
    pub fn new(transport: T) -> Self {
        Self::with_role(transport, MasterKind::Primary)
    }

    /// A primary or secondary master on `transport`.
    pub fn with_role(transport: T, kind: MasterKind) -> Self {
        let policy = RetryPolicy::default();
        let master = Master::new(kind, transport.profile(), policy, transport.now());
        let over_ip = transport.profile() == hart_link::TimingProfile::hart_ip();
        Client {
            transport,
            master,
            kind,
            policy,
            auto_status: true,
            bursts: VecDeque::new(),
            log: None,
            known: vec![],
            carrier_since: None,
            last_rx: 0,
            ip_frames: over_ip.then(hart_proto::deframer::Deframer::default),
        }
    }

    /// The transport.
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// The transport, mutable.
    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.transport
    }

    /// Calls `f` with every raw transfer.
    pub fn set_log(&mut self, f: impl FnMut(&LogEntry) + 'static) {
        self.log = Some(Box::new(f));
    }

    /// Replaces the retry policy.
    pub fn set_policy(&mut self, policy: RetryPolicy) {
        self.policy = policy;
        self.master.set_policy(policy);
    }

    /// Counters of the data-link master (completed, failed, retries, bursts heard).
    pub fn stats(&self) -> hart_link::master::MasterStats {
        self.master.stats()
    }

    /// Burst frames (PDUs) heard so far and not yet taken.
    pub fn take_bursts(&mut self) -> Vec<Vec<u8>> {
        self.bursts.drain(..).collect()
    }

    fn log(&mut self, direction: Direction, bytes: &[u8], time_us: Micros) {
        if let Some(f) = &mut self.log {
            f(&LogEntry {
                time_us,
                direction,
                bytes: bytes.to_vec(),
            });
        }
    }

    /// Listens to the line for `duration` µs (bursts and other masters' traffic).
    pub async fn listen(&mut self, duration: Micros) -> Result<(), HostError> {
        let end = self.transport.now() + duration;
        while self.transport.now() < end {
            let bytes = self.transport.recv_flagged(end).await?;
            self.feed(&bytes);
            while let Some(out) = self.master.poll(self.transport.now()) {
                if let MasterOutput::Burst(f) = out {
                    self.bursts.push_back(f.as_slice().to_vec());
                }
            }
        }
        Ok(())
    }

    /// Passes received characters, with the UART's error flags, and the carrier-detect
    /// line to the data-link master.
    fn feed(&mut self, chars: &[RxChar]) {
        if let Some(last) = chars.last() {
            let raw: Vec<u8> = chars.iter().map(|c| c.byte).collect();
            self.log(Direction::Rx, &raw, last.at);
            if let Some(d) = self.ip_frames.as_mut() {
                let mut frames: Vec<(bool, Vec<u8>)> = vec![];
                d.feed(&raw, |e| {
                    if let hart_proto::deframer::DeframerEvent::Frame(f) = e {
                        frames.push((
                            f.frame_type() == hart_proto::frame::FrameType::Back,
                            f.pdu.to_vec(),
                        ));
                    }
                });
                for (burst, pdu) in frames {
                    if burst {
                        self.bursts.push_back(pdu);
                    } else {
                        for &b in [0xFF, 0xFF].iter().chain(&pdu) {
                            self.master
                                .receive(b, hart_proto::deframer::UartFlags::OK, last.at);
                        }
                    }
                }
            } else {
                for c in chars {
                    self.master.receive(c.byte, c.flags, c.at);
                }
            }
            self.last_rx = last.at;
        }
        self.sense_carrier();
    }

    /// Tells the master whether the transport's carrier-detect line is on, for
    /// transports that watch one. A carrier that has stayed on for longer than STO
    /// with no character arriving is taken as stuck (a modem holding DCD on all the
    /// time) and ignored until it drops: a carrier holds the master's transmissions
    /// back, and a stuck one would hold them back for ever.
    fn sense_carrier(&mut self) {
        let Some(on) = self.transport.carrier() else {
            return;
        };
        let now = self.transport.now();
        self.carrier_since = match (on, self.carrier_since) {
            (false, _) => None,
            (true, Some(since)) => Some(since),
            (true, None) => Some(now),
        };
        let sto = self.transport.profile().sto;
        let heard = self
            .carrier_since
            .is_some_and(|since| now.saturating_sub(since.max(self.last_rx)) <= sto);
        self.master.carrier(heard);
    }

    /// One transaction with retries, busy and delayed-response handling (by the
    /// data-link master); `what` names the target in errors.
    /// [`Client::transact`] with a typed request.
    async fn transact_request(
        &mut self,
        address: Address,
        request: &Request,
        preambles: usize,
        what: &str,
    ) -> Result<Reply, HostError> {
        let data = request_data(request)?;
        self.transact(address, request.command(), &data, preambles, what)
            .await
    }

    async fn transact(
        &mut self,
        address: Address,
        command: u16,
        data: &[u8],
        preambles: usize,
        what: &str,
    ) -> Result<Reply, HostError> {
        let spec = FrameSpec {
            preambles,
            ..FrameSpec::request(address.with_master(self.kind), command, data)
        };
        self.master
            .request(&spec, self.transport.now())
            .map_err(|e| HostError::Usage(e.to_string()))?;
        let reply = self.run(what).await?;
        self.finish(reply.as_slice(), command, what)
    }

    /// Drives the master's transaction in progress to its end: the reply's PDU.
    async fn run(&mut self, what: &str) -> Result<hart_proto::frame::FrameBuf, HostError> {
        loop {
            let now = self.transport.now();
            while let Some(out) = self.master.poll(now) {
                match out {
                    MasterOutput::Transmit(frame, pre) => {
                        let mut bytes = vec![0xFF; pre];
                        bytes.extend_from_slice(frame.as_slice());
                        self.log(Direction::Tx, &bytes, self.transport.now());
                        self.transport.send(&bytes).await?;
                        self.master.transmitted(self.transport.now());
                    }
                    MasterOutput::Done(Ok(fb)) => return Ok(fb),
                    MasterOutput::Done(Err(e)) => {
                        let sto_ms = self.transport.profile().sto / 1000;
                        let port = self.transport.describe();
                        return Err(match e {
                            LinkError::NoReply { attempts } => HostError::NoReply {
                                target: what.to_string(),
                                attempts,
                                sto_ms,
                                port,
                            },
                            LinkError::CommunicationError {
                                attempts,
                                last_error,
                            } => HostError::Communication {
                                target: what.to_string(),
                                attempts,
                                last_error,
                            },
                        });
                    }
                    MasterOutput::Burst(f) => self.bursts.push_back(f.as_slice().to_vec()),
                }
            }
            let now = self.transport.now();
            let deadline = self
                .master
                .next_deadline()
                .unwrap_or(now + 50_000)
                .clamp(now + 1, now + 200_000);
            let bytes = self.transport.recv_flagged(deadline).await?;
            self.feed(&bytes);
            if let Some(status) = self.transport.take_no_reply() {
                if self.master.abandon().is_some() {
                    return Err(HostError::NoReplyBehindServer {
                        target: what.to_string(),
                        port: self.transport.describe(),
                        status,
                    });
                }
            }
        }
    }

    fn finish(&mut self, pdu: &[u8], command: u16, what: &str) -> Result<Reply, HostError> {
        let f = Frame::parse_pdu(pdu).map_err(|e| HostError::Decode(e.to_string()))?;
        let rc = f.response_code.unwrap_or(0);
        // A HART-IP I/O system answers for a sub-device that did not reply on its loop
        // with response code 35 and no data.
        if rc == hart_proto::tables::rc::DR_DEAD
            && f.data.is_empty()
            && self.transport.profile() == hart_link::TimingProfile::hart_ip()
        {
            return Err(HostError::NoReplyBehindServer {
                target: what.to_string(),
                port: self.transport.describe(),
                status: "response code 35: the I/O system reports the sub-device silent or unknown"
                    .into(),
            });
        }
        if response_class(rc) == ResponseClass::Error {
            return Err(HostError::Device {
                command,
                code: rc,
                name: response_code_name(command, rc)
                    .unwrap_or("undefined response code")
                    .to_string(),
            });
        }
        Ok(Reply {
            response_code: rc,
            device_status: f.device_status.unwrap_or(0),
            data: f.data.to_vec(),
            pdu: pdu.to_vec(),
            additional_status: None,
        })
    }

    /// Sends a frame as it is (a gateway forwarding a PDU) and returns the reply's PDU,
    /// whatever its response code. The master bit is set to this client's.
    pub async fn forward(&mut self, pdu: &[u8]) -> Result<Vec<u8>, HostError> {
        let f = Frame::parse_pdu(pdu).map_err(|e| HostError::Decode(e.to_string()))?;
        let data = f.data.to_vec();
        let spec = FrameSpec {
            preambles: 5,
            expansion: f.expansion,
            extended: f.extended,
            ..FrameSpec::request(f.address, f.command, &data)
        };
        self.master
            .request(
                &FrameSpec {
                    address: spec.address.with_master(self.kind),
                    ..spec
                },
                self.transport.now(),
            )
            .map_err(|e| HostError::Usage(e.to_string()))?;
        let what = f.address.to_string();
        Ok(self.run(&what).await?.as_slice().to_vec())
    }

    /// Identifies the device at polling address `poll` (command 0 in a short frame).
    pub async fn identify(&mut self, poll: u8) -> Result<DeviceInfo, HostError> {
        let what = format!("polling address {poll}");
        let addr = Address::Short(ShortAddress {
            master: self.kind,
            burst: false,
            polling_address: poll,
        });
        let r = self.transact(addr, 0, &[], 5, &what).await?;
        let identity = Identity::decode(&mut Reader::new(&r.data))
            .map_err(|e| HostError::Decode(format!("command 0 reply from {what}: {e}")))?;
        let info = DeviceInfo::identified(identity, Some(poll));
        self.remember(&info);
        Ok(info)
    }

    fn remember(&mut self, info: &DeviceInfo) {
        self.known.retain(|k| k.unique_id() != info.unique_id());
        self.known.push(info.clone());
    }

    /// Finds a device: by polling address (command 0), tag (11), long tag (21), or a
    /// unique ID (command 0 in a long frame).
    pub async fn resolve(&mut self, r: &DeviceRef) -> Result<DeviceInfo, HostError> {
        let broadcast = Address::Long(LongAddress {
            master: self.kind,
            burst: false,
            id: UniqueId::BROADCAST,
        });
        let what = r.to_string();
        let reply = match r {
            DeviceRef::Poll(p) => return self.identify(*p).await,
            DeviceRef::Tag(t) => {
                let tag = PackedString::<6>::new(t)
                    .map_err(|e| HostError::Usage(format!("tag {t:?}: {e}")))?;
                let request = Request::ReadUniqueIdentifierByTag(TagRequest { tag });
                self.transact_request(broadcast, &request, 5, &what).await
            }
            DeviceRef::LongTag(t) => {
                let long_tag = Latin1String::<32>::new(t)
                    .map_err(|e| HostError::Usage(format!("long tag {t:?}: {e}")))?;
                let request = Request::ReadUniqueIdentifierByLongTag(LongTag { long_tag });
                self.transact_request(broadcast, &request, 5, &what).await
            }
            DeviceRef::UniqueId(id) => self.transact(Address::long(*id), 0, &[], 5, &what).await,
        }
        .map_err(|e| match e {
            HostError::NoReply {
                attempts,
                sto_ms,
                port,
                ..
            } => HostError::NoReply {
                target: what.clone(),
                attempts,
                sto_ms,
                port,
            },
            e => e,
        })?;
        let identity = Identity::decode(&mut Reader::new(&reply.data))
            .map_err(|e| HostError::Decode(format!("identity reply from {what}: {e}")))?;
        let info = DeviceInfo::identified(identity, None);
        self.remember(&info);
        Ok(info)
    }

    /// Sends a typed `request` to `device` ([`Client::command`] with its bytes): the
    /// way every command with a layout in hart-proto is sent.
    pub async fn request(
        &mut self,
        device: &DeviceInfo,
        request: &Request,
    ) -> Result<Reply, HostError> {
        let data = request_data(request)?;
        self.command(device, request.command(), &data).await
    }

    /// Sends `command` with `data` to a known device in a long frame, with the
    /// device's preamble count; reads command 48 when the reply says more status is
    /// available (and [`Client::auto_status`] is on). For bytes a caller composed
    /// itself (a pass-through, a device-specific command); [`Client::request`] for the
    /// commands hart-proto knows.
    pub async fn command(
        &mut self,
        device: &DeviceInfo,
        command: u16,
        data: &[u8],
    ) -> Result<Reply, HostError> {
        let what = match device.polling_address {
            Some(p) => format!("polling address {p} (unique ID {})", device.unique_id()),
            None => format!("unique ID {}", device.unique_id()),
        };
        let preambles = usize::from(device.identity.min_request_preambles).clamp(5, 20);
        let addr = Address::long(device.unique_id());
        let mut reply = self.transact(addr, command, data, preambles, &what).await?;
        if self.auto_status
            && reply.device_status & fds::MORE_STATUS_AVAILABLE != 0
            && command != 48
        {
            let status = Request::ReadAdditionalStatus(Default::default());
            if let Ok(s) = self.transact_request(addr, &status, preambles, &what).await {
                reply.additional_status = Some(s.data);
            }
        }
        Ok(reply)
    }

    /// Scans polling addresses (command 0 in short frames, one retry) and reads each
    /// device's tag, descriptor and (HART 6+) long tag as it is found. An address
    /// where nothing answers (directly, or behind a HART-IP server) is reported and the
    /// scan goes on. When a device is an I/O system (a HART-IP gateway or
    /// multiplexer), its sub-devices are listed with commands 74 and 84 and identified
    /// by their unique IDs. `progress` hears of every address and sub-device in turn.
    pub async fn scan(
        &mut self,
        range: std::ops::RangeInclusive<u8>,
        mut progress: impl FnMut(ScanEvent<'_>),
    ) -> Result<Vec<DeviceInfo>, HostError> {
        let mut found: Vec<DeviceInfo> = vec![];
        let mut io_systems = vec![];
        for poll in range {
            let normal = self.policy;
            self.master.set_policy(RetryPolicy {
                retries: 1,
                ..normal
            });
            let r = self.identify(poll).await;
            self.master.set_policy(normal);
            match r {
                Ok(mut info) => {
                    self.read_tags(&mut info).await;
                    progress(ScanEvent::Address {
                        poll,
                        found: Some(&info),
                    });
                    if info.is_io_system() {
                        io_systems.push(info.unique_id());
                    }
                    found.push(info);
                }
                Err(HostError::NoReply { .. })
                | Err(HostError::NoReplyBehindServer { .. })
                | Err(HostError::Communication { .. })
                | Err(HostError::Device { .. })
                | Err(HostError::Decode(_)) => progress(ScanEvent::Address { poll, found: None }),
                Err(e) => return Err(e),
            }
        }
        // Then the sub-devices of each I/O system, those not found by polling address
        // already (on other channels, or at addresses outside the range).
        for io in io_systems {
            let known: Vec<UniqueId> = found.iter().map(|d| d.unique_id()).collect();
            for sub in self.sub_devices(io, &known).await {
                progress(ScanEvent::SubDevice(&sub));
                found.push(sub);
            }
        }
        Ok(found)
    }

    /// Reads tag and descriptor (command 13) and, from HART 6 on, the long tag
    /// (command 20); what fails stays unknown.
    pub async fn read_tags(&mut self, info: &mut DeviceInfo) {
        if let Ok(r) = self
            .request(info, &Request::ReadTagDescriptorDate(Empty {}))
            .await
        {
            if let Ok(t) = hart_proto::command::TagDescriptorDate::decode(&mut Reader::new(&r.data))
            {
                info.tag = Some(t.tag.to_string());
                info.descriptor = Some(t.descriptor.to_string());
            }
        }
        if info.revision() >= 6 {
            if let Ok(r) = self.request(info, &Request::ReadLongTag(Empty {})).await {
                if let Ok(t) = hart_proto::command::LongTag::decode(&mut Reader::new(&r.data)) {
                    info.long_tag = Some(t.long_tag.to_string());
                }
            }
        }
    }

    /// The sub-devices of the I/O system `io` but those in `skip`: command 74 for their
    /// number, command 84 for each (index 1 on; index 0 is the I/O system itself), then
    /// command 0 by unique ID for the full identity (the summary's when the sub-device
    /// is silent) and its tags.
    pub async fn sub_devices(&mut self, io: UniqueId, skip: &[UniqueId]) -> Vec<DeviceInfo> {
        let gateway = Address::long(io);
        let capabilities = Request::ReadIoSystemCapabilities(Empty {});
        let count = match self
            .transact_request(gateway, &capabilities, 5, "the I/O system")
            .await
        {
            Ok(r) => IoSystemCapabilities::decode(&mut Reader::new(&r.data))
                .map_or(256, |c| c.devices_detected),
            Err(_) => 256,
        };
        let mut subs = vec![];
        for ix in 1..count {
            let summary = Request::ReadSubDeviceIdentitySummary(SubDeviceIndex { index: ix });
            let Ok(r) = self
                .transact_request(gateway, &summary, 5, "the I/O system")
                .await
            else {
                break;
            };
            let Some(mut info) = summary_identity(&r.data) else {
                break;
            };
            if info.unique_id() == io || skip.contains(&info.unique_id()) {
                continue;
            }
            let channel = info.io_channel;
            if let Ok(mut full) = self.resolve(&DeviceRef::UniqueId(info.unique_id())).await {
                full.long_tag = info.long_tag.take();
                full.io_channel = channel;
                info = full;
            }
            self.read_tags(&mut info).await;
            self.remember(&info);
            subs.push(info);
        }
        subs
    }
}
