//! # hart-access
//!
//! Access control for hartkit's gateway, the same on every path of every front end:
//!
//! * [`Rights`]: what a session may do (read only, or read and write), from the
//!   server's `--read-only`, a PSK identity, the listener it came in on, an OPC UA user
//!   or a Modbus client's address.
//! * [`Policy::check`]: the one question every front end asks of a request frame:
//!   may this session send it, and does it write? Deny by default: a command is a read
//!   only if hart-proto's table knows it reads ([`hart_proto::command::access`]) or the
//!   plant declared it a read for that device type ([`DeviceCommands`]); command 77 is
//!   unwrapped at every depth (up to [`MAX_DEPTH`]) and each wrapped frame checked;
//!   the allow-list ([`CommandAllowList`]) applies at every level.
//! * [`Audit`]: one line for every write let through, naming the front end, the
//!   session's identity and peer, and the innermost device and command.
//! * [`NetList`]: client addresses as networks (`10.0.0.0/24`), for Modbus writes.
//! * [`WritePolicy`]: the gateway-wide rule (`--read-only`, `--allow-commands`) for
//!   the typed writes front ends make through the polling engine, and their audit.
//! * [`pool`]: the connection pool of the TCP front ends: limits, priority hosts, which
//!   connection a full pool closes, and a budget of log lines.
//!
//! The crate does no I/O but the audit file's appends.

use std::fmt;

mod allow;
mod audit;
pub mod devices;
mod nets;
pub mod pool;
mod writes;

pub use allow::CommandAllowList;
pub use audit::{json_line, Audit, WriteOutcome, WriteRecord};
pub use devices::DeviceCommands;
pub use nets::NetList;
pub use writes::{NotPermitted, WritePolicy};

use hart_proto::command::{Access, SendCommandToSubDevice};
use hart_proto::frame::{Address, Frame, MAX_PDU_LEN};
use hart_proto::wire::{Reader, Wire};

/// What a session may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Rights {
    /// Read and write.
    #[default]
    ReadWrite,
    /// Commands that only read; every other one is refused ("access restricted").
    ReadOnly,
}

impl Rights {
    /// Whether writes are allowed.
    pub fn may_write(self) -> bool {
        self == Rights::ReadWrite
    }

    /// The lesser of two rights (a read-only server makes every identity read-only).
    pub fn and(self, other: Rights) -> Rights {
        if self.may_write() && other.may_write() {
            Rights::ReadWrite
        } else {
            Rights::ReadOnly
        }
    }

    /// `read-only` or `read-write`.
    pub fn name(self) -> &'static str {
        match self {
            Rights::ReadWrite => "read-write",
            Rights::ReadOnly => "read-only",
        }
    }
}

impl fmt::Display for Rights {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Rights {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "read-write" | "rw" => Ok(Rights::ReadWrite),
            "read-only" | "ro" => Ok(Rights::ReadOnly),
            other => Err(format!("rights {other:?}: give read-only or read-write")),
        }
    }
}

/// Most levels of command 77 checked in one request: 77 wrapping 77 wrapping ... A
/// deeper request is refused whatever the rights, since what it finally does cannot be
/// checked. Real plants nest two or three gateways at most.
pub const MAX_DEPTH: usize = 4;

/// The access rules of a server: the allow-list and the device-specific commands the
/// plant declared reads. Rights come with each request (they belong to the session).
#[derive(Debug, Clone, Default)]
pub struct Policy {
    /// Only these commands may be sent, at any depth of command 77 (`None`: every
    /// command).
    pub allow: Option<CommandAllowList>,
    /// Device-specific commands declared reads, per device type.
    pub device_commands: DeviceCommands,
}

/// A request the policy lets through.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Allowed {
    /// It only reads.
    Read,
    /// It writes: audit it before it is carried out.
    Write(Target),
}

/// Where a write goes: the innermost frame of the request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Target {
    /// The device, as its address reads (`unique ID 26F1010002`, `polling address 1`).
    pub device: String,
    /// The innermost command.
    pub command: u16,
    /// Levels of command 77 around it (0: sent to the device directly).
    pub depth: usize,
}

/// Why a request is refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Refusal {
    /// The allow-list leaves out `command` (at `depth` levels of command 77).
    NotListed {
        /// The command.
        command: u16,
        /// Levels of command 77 around it.
        depth: usize,
    },
    /// The session may only read, and `command` writes, or is not known to read.
    ReadOnly {
        /// The innermost command.
        command: u16,
        /// What the project knows of it.
        access: Access,
        /// Levels of command 77 around it.
        depth: usize,
    },
    /// Command 77 nested deeper than [`MAX_DEPTH`].
    TooDeep,
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let inside = |depth: usize| match depth {
            0 => String::new(),
            1 => " (wrapped in command 77)".to_string(),
            n => format!(" (wrapped in {n} levels of command 77)"),
        };
        match self {
            Refusal::NotListed { command, depth } => write!(
                f,
                "command {command}{} is not on the allow-list (--allow-commands)",
                inside(*depth)
            ),
            Refusal::ReadOnly {
                command,
                access,
                depth,
            } => {
                let why = match access {
                    Access::Read => "reads, but the session may not send it", // not reached
                    Access::Write => "changes the device",
                    Access::Wrapper => "carries commands that cannot be checked",
                    Access::Unknown => {
                        "is not known to only read (a device-specific command can be \
                         declared a read with --device-commands)"
                    }
                };
                write!(
                    f,
                    "command {command}{} {why}, and the session is read-only",
                    inside(*depth)
                )
            }
            Refusal::TooDeep => write!(
                f,
                "command 77 nested deeper than {MAX_DEPTH} levels cannot be checked"
            ),
        }
    }
}

impl std::error::Error for Refusal {}

/// The frame a command 77 request wraps (I/O card, channel, transmit preambles, then
/// the frame from its delimiter through its data, without the check byte), or `None`
/// when the data is not such a frame.
pub fn wrapped<'a>(data: &[u8], buf: &'a mut Vec<u8>) -> Option<Frame<'a>> {
    let request = SendCommandToSubDevice::decode(&mut Reader::new(data)).ok()?;
    buf.clear();
    buf.resize(MAX_PDU_LEN, 0);
    request
        .embedded_frame(buf.as_mut_slice().try_into().ok()?)
        .ok()
}

/// HART-IP's publish subscription commands (532 read client subscription summary, 533
/// write client subscription flags): a HART-IP server answers them for the session
/// itself whatever the address. They change no device, so read-only sessions may send
/// them; the allow-list still applies ([`Policy::check_session_command`]).
pub const SESSION_COMMANDS: &[u16] = &[532, 533];

impl Policy {
    /// The check for a command the server answers for the session itself
    /// ([`SESSION_COMMANDS`]): the allow-list only.
    pub fn check_session_command(&self, command: u16) -> Result<Allowed, Refusal> {
        match &self.allow {
            Some(a) if !a.allows(command) => Err(Refusal::NotListed { command, depth: 0 }),
            _ => Ok(Allowed::Read),
        }
    }

    /// Whether a session with `rights` may send `frame` (a request PDU), and whether it
    /// writes. `device_type` names the expanded device type of a short-addressed
    /// frame's device when the caller knows it (long addresses carry their own); it
    /// decides which declared device-specific reads apply.
    pub fn check(
        &self,
        rights: Rights,
        frame: &Frame<'_>,
        device_type: Option<u16>,
    ) -> Result<Allowed, Refusal> {
        self.check_command(
            rights,
            frame.address,
            frame.command,
            frame.data,
            device_type,
        )
    }

    /// [`Policy::check`] for a command given apart from a frame (a Direct PDU entry,
    /// addressed to the server itself, `address`).
    pub fn check_command(
        &self,
        rights: Rights,
        address: Address,
        command: u16,
        data: &[u8],
        device_type: Option<u16>,
    ) -> Result<Allowed, Refusal> {
        let mut address = address;
        let mut command = command;
        let mut data = data.to_vec();
        let mut device_type = device_type;
        let mut depth = 0;
        loop {
            if let Some(allow) = &self.allow {
                if !allow.allows(command) {
                    return Err(Refusal::NotListed { command, depth });
                }
            }
            let access = self.access(command, &address, device_type);
            if access == Access::Wrapper && command == 77 {
                let mut buf = vec![];
                if let Some(inner) = wrapped(&data, &mut buf) {
                    if depth == MAX_DEPTH {
                        return Err(Refusal::TooDeep);
                    }
                    depth += 1;
                    address = inner.address;
                    command = inner.command;
                    device_type = None;
                    data = inner.data.to_vec();
                    continue;
                }
                // Not a frame: the I/O system answers "too few data bytes"; nothing
                // inside can write, but nothing is known to read either.
            }
            return match access {
                Access::Read => Ok(Allowed::Read),
                _ if !rights.may_write() => Err(Refusal::ReadOnly {
                    command,
                    access,
                    depth,
                }),
                _ => Ok(Allowed::Write(Target {
                    device: address.to_string(),
                    command,
                    depth,
                })),
            };
        }
    }

    /// What `command` to the device at `address` does: the table's answer, or, for a
    /// command the table does not know, the plant's declaration for the device type.
    pub fn access(&self, command: u16, address: &Address, device_type: Option<u16>) -> Access {
        match hart_proto::command::access(command) {
            Access::Unknown => {
                let ty = match address {
                    Address::Long(a) if !a.id.is_broadcast() => Some(a.id.expanded_device_type),
                    _ => device_type,
                };
                match ty {
                    Some(t) if self.device_commands.reads(t, command) => Access::Read,
                    _ => Access::Unknown,
                }
            }
            a => a,
        }
    }
}

#[cfg(test)]
mod tests;
