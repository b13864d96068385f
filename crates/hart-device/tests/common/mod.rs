//! A minimal host for driving a device through its data link, as a master would:
//! frames go in one character at a time, replies come out of the slave.
#![allow(dead_code)]

use hart_device::{Device, DeviceConfig, Node};
use hart_link::{Micros, TimingProfile};
use hart_proto::deframer::UartFlags;
use hart_proto::frame::{
    Address, Frame, FrameSpec, FrameType, LongAddress, MasterKind, ShortAddress,
};

pub const P: TimingProfile = TimingProfile::fsk();

/// A reply: response code, device status, data.
#[derive(Debug, Clone, PartialEq)]
pub struct Answer {
    pub rc: u8,
    pub status: u8,
    pub data: Vec<u8>,
    pub preambles: usize,
}

pub struct Host {
    pub node: Node,
    pub now: Micros,
    pub master: MasterKind,
    /// BACK frames heard: (time, command, master bit, data).
    pub backs: Vec<(Micros, u16, MasterKind, Vec<u8>)>,
}

impl Host {
    pub fn new(cfg: DeviceConfig) -> Self {
        Self::with_device(Device::new(cfg))
    }

    pub fn profile(name: &str) -> Self {
        Self::new(hart_device::profiles::load(name).unwrap())
    }

    pub fn with_device(device: Device) -> Self {
        Host {
            node: Node::new(device, P, 0),
            now: 1_000_000,
            master: MasterKind::Primary,
            backs: vec![],
        }
    }

    pub fn device(&mut self) -> &mut Device {
        &mut self.node.device
    }

    /// Lets `us` microseconds of virtual time pass, serving burst frames.
    pub fn wait(&mut self, us: Micros) {
        let end = self.now + us;
        loop {
            let next = self
                .node
                .next_deadline(self.now)
                .unwrap_or(end)
                .max(self.now + 1);
            if next > end {
                self.now = end;
                self.node.device.tick(end);
                return;
            }
            self.now = next;
            if let Some(bytes) = self.node.poll(self.now) {
                self.now += P.chars(bytes.len());
                self.node.transmitted(self.now);
                let f = Frame::parse(&bytes).expect("device sent a valid frame");
                if f.frame_type() == FrameType::Back {
                    self.backs
                        .push((self.now, f.command, f.address.master(), f.data.to_vec()));
                }
            }
        }
    }

    fn transact(&mut self, address: Address, command: u16, data: &[u8]) -> Option<Answer> {
        let spec = FrameSpec::request(address.with_master(self.master), command, data);
        let mut bytes = vec![0u8; spec.encoded_len()];
        let n = spec.encode(&mut bytes).unwrap();
        // The host takes the line after a quiet period, as a master after RT1.
        self.wait(P.rt1_primary);
        for &b in &bytes[..n] {
            self.now += P.char_time;
            self.node.receive(b, UartFlags::OK, self.now);
        }
        let sent = self.now;
        // The reply must start within STO.
        loop {
            let next = self.node.next_deadline(self.now);
            match next {
                Some(t) if t <= sent + P.sto => {
                    self.now = t.max(self.now);
                    if let Some(reply) = self.node.poll(self.now) {
                        assert!(
                            self.now - sent >= P.hold && self.now - sent < P.sto,
                            "reply started {} µs after the request",
                            self.now - sent
                        );
                        self.now += P.chars(reply.len());
                        self.node.transmitted(self.now);
                        let f = Frame::parse(&reply).expect("valid reply");
                        if f.frame_type() == FrameType::Back {
                            self.backs.push((
                                self.now,
                                f.command,
                                f.address.master(),
                                f.data.to_vec(),
                            ));
                            continue;
                        }
                        assert_eq!(f.frame_type(), FrameType::Ack);
                        assert_eq!(
                            f.address.master(),
                            self.master,
                            "reply carries the requesting master's bit"
                        );
                        assert_eq!(f.command, command);
                        return Some(Answer {
                            rc: f.response_code.unwrap(),
                            status: f.device_status.unwrap(),
                            data: f.data.to_vec(),
                            preambles: f.preambles,
                        });
                    }
                    self.now += 1;
                }
                _ => {
                    self.now = sent + P.sto;
                    return None;
                }
            }
        }
    }

    /// A request in a long frame to the device's unique ID.
    pub fn ask(&mut self, command: u16, data: &[u8]) -> Answer {
        let id = self.node.device.unique_id();
        self.transact(
            Address::Long(LongAddress {
                master: self.master,
                burst: false,
                id,
            }),
            command,
            data,
        )
        .unwrap_or_else(|| panic!("no reply to command {command}"))
    }

    /// A request in a short frame to `poll`; `None` when the device stays silent.
    pub fn ask_short(&mut self, poll: u8, command: u16, data: &[u8]) -> Option<Answer> {
        self.transact(
            Address::Short(ShortAddress {
                master: self.master,
                burst: false,
                polling_address: poll,
            }),
            command,
            data,
        )
    }

    /// A request to an arbitrary address.
    pub fn ask_at(&mut self, address: Address, command: u16, data: &[u8]) -> Option<Answer> {
        self.transact(address, command, data)
    }
}

pub fn f32_at(d: &[u8], at: usize) -> f32 {
    f32::from_be_bytes([d[at], d[at + 1], d[at + 2], d[at + 3]])
}

pub fn u32_at(d: &[u8], at: usize) -> u32 {
    u32::from_be_bytes([d[at], d[at + 1], d[at + 2], d[at + 3]])
}

pub fn float(x: f32) -> [u8; 4] {
    x.to_be_bytes()
}

/// A transmitter with a constant PV, for exact loop-current checks.
pub fn constant_transmitter(pv: f32) -> DeviceConfig {
    let mut c = hart_device::profiles::load("pressure").unwrap();
    c.variables[0].waveform = hart_device::config::Waveform::Constant { value: pv };
    c.range.damping = 0.0;
    c.range.upper = 100.0;
    c.range.lower = 0.0;
    c
}
