//! A minimal simulated field device: answers commands 0, 1, 2, 3, 9, 11 and 38 with
//! plausible, slowly changing values and everything else with "command not
//! implemented". The full HART 7 field device plugs into the same
//! [`hart_link::Handler`] seam.

use hart_link::slave::{Handler, Reply};
use hart_proto::command::{
    Identity, ReadDeviceVariablesRequest, ReadDeviceVariablesResponse,
    ReadDynamicVariablesResponse, ReadLoopCurrentResponse, ReadPvResponse, ResetConfigChanged,
    SlotsWithTimestamp, TagRequest, UnitValue, VariableSlot,
};
use hart_proto::frame::{Frame, UniqueId};
use hart_proto::tables::rc;
use hart_proto::types::{
    DeviceId, DeviceProfile, DeviceVariableCode, ExtendedStatus, Flags, HardwareRevision, HartTime,
    MilliAmps, Percent, UnitCode, VariableStatus,
};
use hart_proto::wire::{List, Reader, Wire, Writer};

/// Expanded device type used by simulated devices.
pub const SIM_DEVICE_TYPE: u16 = 0x26F0;

/// A minimal responder.
#[derive(Debug, Clone)]
pub struct SimpleDevice {
    /// Polling address.
    pub polling_address: u8,
    /// Device ID (24 bits).
    pub device_id: u32,
    /// Requests answered.
    pub served: u64,
    /// Command published in burst mode.
    pub burst_command: u16,
}

impl SimpleDevice {
    /// A device with polling address `polling_address`.
    pub fn new(polling_address: u8) -> Self {
        SimpleDevice {
            polling_address,
            device_id: 0x10_0000 + u32::from(polling_address),
            served: 0,
            burst_command: 3,
        }
    }

    /// Its unique ID.
    pub fn unique_id(&self) -> UniqueId {
        UniqueId::new(SIM_DEVICE_TYPE, self.device_id)
    }

    fn identity(&self) -> Identity {
        Identity {
            expansion_code: 254,
            expanded_device_type: SIM_DEVICE_TYPE,
            min_request_preambles: 5,
            universal_revision: 7,
            device_revision: 1,
            software_revision: 1,
            hardware: HardwareRevision::new(1, 0),
            flags: Flags(0),
            device_id: DeviceId::new(self.device_id).unwrap_or_default(),
            min_response_preambles: Some(5),
            max_device_variables: Some(4),
            config_change_counter: Some(0),
            extended_status: Some(ExtendedStatus(0)),
            manufacturer_id: Some(0x00F0),
            private_label_distributor: Some(0x00F0),
            device_profile: Some(DeviceProfile(1)),
        }
    }

    /// A process value that changes with every request served.
    fn pv(&self) -> f32 {
        let phase = (self.served % 200) as f32 / 200.0;
        50.0 + 25.0 * (phase * core::f32::consts::TAU).sin() + self.polling_address as f32
    }

    fn respond(&mut self, command: u16, data: &[u8], reply: &mut Reply) -> bool {
        let pv = self.pv();
        let current = 4.0 + 16.0 * (pv / 100.0).clamp(0.0, 1.0);
        let mut buf = [0u8; 253];
        let mut w = Writer::new(&mut buf);
        let ok = match command {
            0 => self.identity().encode(&mut w),
            11 => {
                // Answer only the tag "SIM-NN".
                let mut tag = hart_proto::types::PackedString::<6>::default();
                let mut text = [0u8; 8];
                let n = format_tag(self.polling_address, &mut text);
                if let Ok(t) = hart_proto::types::PackedString::<6>::new(
                    core::str::from_utf8(&text[..n]).unwrap_or(""),
                ) {
                    tag = t;
                }
                match TagRequest::decode(&mut Reader::new(data)) {
                    Ok(r) if r.tag == tag => {}
                    _ => return false,
                }
                self.identity().encode(&mut w)
            }
            1 => ReadPvResponse {
                pv_units: UnitCode(12),
                pv,
            }
            .encode(&mut w),
            2 => ReadLoopCurrentResponse {
                loop_current: MilliAmps(current),
                percent_of_range: Percent(pv),
            }
            .encode(&mut w),
            3 => {
                let vars = [
                    UnitValue {
                        units: UnitCode(12),
                        value: pv,
                    },
                    UnitValue {
                        units: UnitCode(32),
                        value: 21.5,
                    },
                    UnitValue {
                        units: UnitCode(250),
                        value: hart_proto::types::hart_nan(),
                    },
                    UnitValue {
                        units: UnitCode(250),
                        value: hart_proto::types::hart_nan(),
                    },
                ];
                ReadDynamicVariablesResponse {
                    loop_current: MilliAmps(current),
                    variables: List::from_slice(&vars).unwrap_or_default(),
                }
                .encode(&mut w)
            }
            9 => {
                let Ok(request) = ReadDeviceVariablesRequest::decode(&mut Reader::new(data)) else {
                    reply.response_code = rc::TOO_FEW_DATA_BYTES;
                    return true;
                };
                let mut slots = List::<VariableSlot, 8>::default();
                for &DeviceVariableCode(code) in request.slots.as_slice() {
                    let _ = slots.push(VariableSlot {
                        code: DeviceVariableCode(code),
                        classification: hart_proto::types::Classification(if code == 0 {
                            65
                        } else {
                            0
                        }),
                        units: UnitCode(if code == 0 { 12 } else { 250 }),
                        value: if code == 0 {
                            pv
                        } else {
                            hart_proto::types::hart_nan()
                        },
                        status: VariableStatus(if code == 0 { 0xC0 } else { 0x30 }),
                    });
                }
                if slots.is_empty() {
                    reply.response_code = rc::TOO_FEW_DATA_BYTES;
                    return true;
                }
                ReadDeviceVariablesResponse {
                    extended_status: ExtendedStatus(0),
                    data: SlotsWithTimestamp {
                        slots,
                        timestamp: Some(HartTime(self.served as u32 * 32)),
                    },
                }
                .encode(&mut w)
            }
            // The counter the master sent back (0 from a master that sent none).
            38 => ResetConfigChanged {
                config_change_counter: Some(
                    ResetConfigChanged::decode(&mut Reader::new(data))
                        .ok()
                        .and_then(|r| r.config_change_counter)
                        .unwrap_or(0),
                ),
            }
            .encode(&mut w),
            _ => {
                reply.response_code = rc::NOT_IMPLEMENTED;
                return true;
            }
        };
        if ok.is_ok() {
            let n = w.position();
            reply.set_data(&buf[..n]);
        }
        true
    }
}

fn format_tag(poll: u8, out: &mut [u8; 8]) -> usize {
    out[..4].copy_from_slice(b"SIM-");
    out[4] = b'0' + poll / 10 % 10;
    out[5] = b'0' + poll % 10;
    6
}

impl Handler for SimpleDevice {
    fn request(&mut self, request: &Frame<'_>, reply: &mut Reply, _now: u64) -> bool {
        self.served += 1;
        self.respond(request.command, request.data, reply)
    }

    fn burst(&mut self, reply: &mut Reply, _now: u64) -> u16 {
        self.served += 1;
        let command = self.burst_command;
        self.respond(command, &[0], reply);
        command
    }
}
