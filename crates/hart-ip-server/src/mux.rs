//! The gateway as a HART-IP I/O system (multiplexer): it answers as a device itself
//! (commands 0, 13, 20, 48, 74, 84) and routes to the devices on its loops, by their
//! long address or through command 77 (send command to sub-device). Each loop is a
//! channel of I/O card 0.

use std::sync::Arc;

use hart_host::DeviceInfo;
use hart_proto::command::{Identity, LongTag, TagDescriptorDate};
use hart_proto::frame::{checksum, Address, Frame, UniqueId};
use hart_proto::tables::rc;
use hart_proto::types::{
    Date, DeviceId, DeviceProfile, ExtendedStatus, Flags, HardwareRevision, Latin1String,
    PackedString,
};
use hart_proto::wire::{Wire, Writer};
use tokio::sync::{mpsc, oneshot, Mutex};

/// A request for a loop: a PDU, and where to send the reply PDU.
pub struct LoopRequest {
    /// The frame (delimiter through check byte).
    pub pdu: Vec<u8>,
    /// The reply frame, or `None` when the device did not answer.
    pub reply: oneshot::Sender<Option<Vec<u8>>>,
}

/// The gateway's own identity.
#[derive(Debug, Clone)]
pub struct GatewayIdentity {
    /// Expanded device type.
    pub expanded_device_type: u16,
    /// Device ID.
    pub device_id: u32,
    /// Tag.
    pub tag: String,
    /// Descriptor.
    pub descriptor: String,
    /// Long tag.
    pub long_tag: String,
}

impl Default for GatewayIdentity {
    fn default() -> Self {
        GatewayIdentity {
            expanded_device_type: 0x26FF,
            device_id: 0x00_0001,
            tag: "HARTGW".into(),
            descriptor: "HARTKIT GATEWAY".into(),
            long_tag: "hartkit HART-IP gateway".into(),
        }
    }
}

/// A device found on a loop.
#[derive(Debug, Clone)]
pub struct SubDevice {
    /// Channel (loop index).
    pub channel: u8,
    /// What the scan found.
    pub info: DeviceInfo,
}

/// Where a token-passing request goes.
pub enum Route {
    /// To the gateway itself.
    Local,
    /// To the loop with this index.
    Loop(usize),
    /// Nowhere (unknown address on a multi-loop gateway).
    Nowhere,
}

/// The I/O system state.
pub struct Mux {
    /// The gateway's identity.
    pub identity: GatewayIdentity,
    /// One request queue per loop.
    pub loops: Vec<mpsc::Sender<LoopRequest>>,
    /// Devices found on the loops.
    pub subs: Arc<Mutex<Vec<SubDevice>>>,
}

fn encode(v: &impl Wire) -> Vec<u8> {
    let mut buf = vec![0u8; v.encoded_len()];
    let _ = v.encode(&mut Writer::new(&mut buf));
    buf
}

impl Mux {
    /// The gateway's unique ID.
    pub fn unique_id(&self) -> UniqueId {
        UniqueId::new(self.identity.expanded_device_type, self.identity.device_id)
    }

    /// Where a request frame goes.
    pub async fn route(&self, f: &Frame<'_>) -> Route {
        let single = self.loops.len() == 1;
        match f.address {
            Address::Long(a) if a.id == self.unique_id() => Route::Local,
            Address::Long(a) if a.id.is_broadcast() => {
                if single {
                    Route::Loop(0)
                } else {
                    Route::Local
                }
            }
            Address::Long(a) => {
                let subs = self.subs.lock().await;
                match subs.iter().find(|s| s.info.unique_id() == a.id) {
                    Some(s) => Route::Loop(usize::from(s.channel)),
                    None if single => Route::Loop(0),
                    None => Route::Nowhere,
                }
            }
            Address::Short(_) if single => Route::Loop(0),
            Address::Short(a) if a.polling_address == 0 => Route::Local,
            Address::Short(_) => Route::Nowhere,
        }
    }

    /// Forwards a PDU to loop `channel`.
    pub async fn forward(&self, channel: usize, pdu: Vec<u8>) -> Option<Vec<u8>> {
        let (tx, rx) = oneshot::channel();
        self.loops
            .get(channel)?
            .send(LoopRequest { pdu, reply: tx })
            .await
            .ok()?;
        rx.await.ok().flatten()
    }

    fn identity_reply(&self) -> Vec<u8> {
        encode(&Identity {
            expansion_code: 254,
            expanded_device_type: self.identity.expanded_device_type,
            min_request_preambles: 5,
            universal_revision: 7,
            device_revision: 1,
            software_revision: 1,
            hardware: HardwareRevision::new(1, 6),
            flags: Flags(0x04), // protocol bridge device
            device_id: DeviceId::new(self.identity.device_id & 0xFF_FFFF).unwrap_or_default(),
            min_response_preambles: Some(5),
            max_device_variables: Some(0),
            config_change_counter: Some(0),
            extended_status: Some(ExtendedStatus(0)),
            manufacturer_id: Some(0x00F0),
            private_label_distributor: Some(0x00F0),
            device_profile: Some(DeviceProfile(68)), // HART-IP I/O system
        })
    }

    /// Answers a command addressed to the gateway itself: response code and data.
    pub async fn local(&self, command: u16, data: &[u8]) -> (u8, Vec<u8>) {
        match command {
            0 => (rc::SUCCESS, self.identity_reply()),
            11 => match PackedString::<6>::new(&self.identity.tag) {
                Ok(t) if data.get(..6) == Some(&t.0[..]) => (rc::SUCCESS, self.identity_reply()),
                _ => (rc::NOT_IMPLEMENTED, vec![]),
            },
            13 => (
                rc::SUCCESS,
                encode(&TagDescriptorDate {
                    tag: PackedString::new(&self.identity.tag).unwrap_or_default(),
                    descriptor: PackedString::new(&self.identity.descriptor).unwrap_or_default(),
                    date: Date::new(2026, 1, 1).unwrap_or_default(),
                }),
            ),
            20 => (
                rc::SUCCESS,
                encode(&LongTag {
                    long_tag: Latin1String::new(&self.identity.long_tag).unwrap_or_default(),
                }),
            ),
            48 => (rc::SUCCESS, vec![0; 9]),
            74 => {
                let n = self.subs.lock().await.len() as u16 + 1;
                let mut d = vec![1, self.loops.len() as u8, 63];
                d.extend(n.to_be_bytes());
                d.extend([1, 1, 3]); // delayed responses, master mode primary, retries
                (rc::SUCCESS, d)
            }
            84 => {
                let Some(ix) = data.get(..2).map(|b| u16::from_be_bytes([b[0], b[1]])) else {
                    return (rc::TOO_FEW_DATA_BYTES, vec![]);
                };
                let subs = self.subs.lock().await;
                let Some(s) = subs.get(usize::from(ix)) else {
                    return (rc::INVALID_SELECTION, vec![]);
                };
                let id = &s.info.identity;
                let mut d = ix.to_be_bytes().to_vec();
                d.extend([0, s.channel]);
                d.extend(s.info.manufacturer_id().to_be_bytes());
                d.extend(id.expanded_device_type.to_be_bytes());
                d.extend(id.device_id.0);
                d.push(id.universal_revision);
                d.extend(
                    Latin1String::<32>::new(s.info.long_tag.as_deref().unwrap_or(""))
                        .unwrap_or_default()
                        .0,
                );
                d.push(id.device_revision);
                d.push(id.device_profile.map_or(1, |p| p.0));
                d.extend(id.private_label_distributor.unwrap_or(0).to_be_bytes());
                (rc::SUCCESS, d)
            }
            77 => self.send_to_sub_device(data).await,
            _ => (rc::NOT_IMPLEMENTED, vec![]),
        }
    }

    /// Command 77: I/O card, channel, transmit preamble count, then the embedded frame
    /// from the delimiter through the data (no check byte). The reply carries card,
    /// channel and the sub-device's reply frame in the same form.
    async fn send_to_sub_device(&self, data: &[u8]) -> (u8, Vec<u8>) {
        if data.len() < 4 {
            return (rc::TOO_FEW_DATA_BYTES, vec![]);
        }
        let (card, channel) = (data[0], data[1]);
        if card != 0 {
            return (rc::INVALID_IO_CARD, vec![]);
        }
        if usize::from(channel) >= self.loops.len() {
            return (rc::INVALID_CHANNEL, vec![]);
        }
        let mut pdu = data[3..].to_vec();
        pdu.push(checksum(&pdu));
        if Frame::parse_pdu(&pdu).is_err() {
            return (rc::TOO_FEW_DATA_BYTES, vec![]);
        }
        match self.forward(usize::from(channel), pdu).await {
            Some(reply) => {
                let mut d = vec![card, channel];
                d.extend_from_slice(&reply[..reply.len().saturating_sub(1)]);
                if d.len() > 253 {
                    return (rc::SUB_DEVICE_RESPONSE_TOO_LONG, vec![]);
                }
                (rc::SUCCESS, d)
            }
            None => (rc::DEVICE_SPECIFIC_ERROR, vec![]),
        }
    }
}
