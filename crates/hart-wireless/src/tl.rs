//! The WirelessHART transport PDU: the transport byte (acknowledged, response and
//! broadcast flags, 5-bit sequence number), device status, extended device status, then
//! the commands, each {command number (2 bytes), length, data}; a response's data
//! starts with its response code.

use alloc::vec::Vec;
use core::fmt;

/// One command of a transport PDU.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Command {
    /// Command number.
    pub number: u16,
    /// Its data (for a response, the response code first).
    pub data: Vec<u8>,
}

/// A transport PDU (the decrypted payload of a network PDU).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Tpdu {
    /// Bit 7: acknowledged service.
    pub acknowledged: bool,
    /// Bit 6: a response.
    pub response: bool,
    /// Bit 5: broadcast.
    pub broadcast: bool,
    /// Bits 4-0: transport sequence number.
    pub seq: u8,
    /// Device status (as in wired HART).
    pub device_status: u8,
    /// Extended device status.
    pub extended_status: u8,
    /// The commands.
    pub commands: Vec<Command>,
}

/// Why a transport PDU could not be parsed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TlError {
    /// Fewer than the 3 header bytes.
    TooShort {
        /// Bytes present.
        available: usize,
    },
    /// A command's header or data runs past the end.
    CommandCut {
        /// Offset of the command header within the transport PDU.
        offset: usize,
    },
}

impl fmt::Display for TlError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TlError::TooShort { available } => write!(
                f,
                "transport PDU has {available} byte(s); 3 are needed (transport byte, device status, extended status)"
            ),
            TlError::CommandCut { offset } => write!(
                f,
                "the command at transport byte {offset} runs past the end of the PDU (a vendor payload, or a wrong key?)"
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for TlError {}

impl Tpdu {
    /// Parses a transport PDU.
    pub fn parse(b: &[u8]) -> Result<Self, TlError> {
        if b.len() < 3 {
            return Err(TlError::TooShort { available: b.len() });
        }
        let mut commands = Vec::new();
        let mut p = 3;
        while p < b.len() {
            if b.len() - p < 3 {
                return Err(TlError::CommandCut { offset: p });
            }
            let number = u16::from_be_bytes([b[p], b[p + 1]]);
            let len = b[p + 2] as usize;
            if b.len() - p - 3 < len {
                return Err(TlError::CommandCut { offset: p });
            }
            commands.push(Command {
                number,
                data: b[p + 3..p + 3 + len].to_vec(),
            });
            p += 3 + len;
        }
        Ok(Tpdu {
            acknowledged: b[0] & 0x80 != 0,
            response: b[0] & 0x40 != 0,
            broadcast: b[0] & 0x20 != 0,
            seq: b[0] & 0x1F,
            device_status: b[1],
            extended_status: b[2],
            commands,
        })
    }

    /// The transport byte.
    pub fn transport_byte(&self) -> u8 {
        (self.acknowledged as u8) << 7
            | (self.response as u8) << 6
            | (self.broadcast as u8) << 5
            | (self.seq & 0x1F)
    }

    /// Encodes the PDU; commands with more than 255 data bytes are cut to 255.
    pub fn encode(&self) -> Vec<u8> {
        let mut v = alloc::vec![
            self.transport_byte(),
            self.device_status,
            self.extended_status
        ];
        for c in &self.commands {
            let d = &c.data[..c.data.len().min(255)];
            v.extend_from_slice(&c.number.to_be_bytes());
            v.push(d.len() as u8);
            v.extend_from_slice(d);
        }
        v
    }
}
