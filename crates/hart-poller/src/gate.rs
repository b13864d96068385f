//! The one gate to the devices for frames a client composes itself (HART-IP
//! pass-through, command 77 through the gateway's I/O system, the web dashboard's
//! reads): [`Engine::forward`](crate::Engine::forward) judges each one by the
//! gateway's rule before it goes on a loop, and audits the writes with their outcome.
//!
//! Typed writes (Modbus registers, OPC UA methods, PROFIBUS outputs, Sparkplug DCMD,
//! the dashboard's forms) take [`Engine::apply`](crate::Engine::apply), which asks the
//! same rule. Nothing public sends a frame to a device past both.
//!
//! The rule is [`hart_access::Policy::check`] with the gateway's allow-list and declared
//! device-specific reads ([`hart_access::WritePolicy`]), and the requester's rights cut to read-only
//! when the gateway is read-only: a frame that only reads goes whoever sends it; one
//! that writes (or is not known to read) needs a requester that may write.

use std::fmt;

use hart_access::{Allowed, Policy, Refusal, Rights, WriteOutcome, WriteRecord};
use hart_proto::command::SendCommandToSubDeviceResponse;
use hart_proto::frame::{Address, Frame};
use hart_proto::wire::{Reader, Wire};

/// Who sends a frame through the gate, with what rights, and how the audit names them.
#[derive(Debug, Clone)]
pub struct Requester {
    /// What this requester may do (the gateway's `--read-only` cuts it further).
    pub rights: Rights,
    /// The audit record's who and where (`front_end`, `session`, `peer`, `identity`,
    /// `via`); the gate fills in the device, the command and the operation.
    pub record: WriteRecord,
    /// Levels of command 77 the gateway's own I/O system already took off the frame
    /// (the client sent it wrapped): the audit's `via` counts them with the frame's.
    pub unwrapped: usize,
}

impl Requester {
    /// A requester that only reads: the gateway's own reads for a front end (the
    /// HART-IP I/O system's scans, the web dashboard's device reads). `via` says what
    /// for.
    pub fn reader(front_end: &'static str, via: &str) -> Self {
        Requester {
            rights: Rights::ReadOnly,
            record: WriteRecord {
                front_end,
                peer: "-".into(),
                via: via.into(),
                ..WriteRecord::default()
            },
            unwrapped: 0,
        }
    }

    /// The same requester for the frame a command 77 it sent carries.
    pub fn inside_77(&self) -> Self {
        Requester {
            unwrapped: self.unwrapped + 1,
            ..self.clone()
        }
    }
}

/// Why the gate did not let a frame through; nothing was sent.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Denied {
    /// The gateway's rule refuses it (read-only, allow-list, command 77 too deep).
    Policy(Refusal),
    /// It is not a HART request frame, so what it would do cannot be judged.
    NotAFrame(String),
}

impl fmt::Display for Denied {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Denied::Policy(r) => r.fmt(f),
            Denied::NotAFrame(e) => write!(
                f,
                "not a HART request frame ({e}), so the gateway cannot judge what it does"
            ),
        }
    }
}

impl std::error::Error for Denied {}

/// The gateway's rule (its access `policy`, and whether it is `read_only`), with
/// `rights` cut to read-only when the gateway is.
pub(crate) fn judge(
    policy: &Policy,
    read_only: bool,
    rights: Rights,
    frame: &Frame<'_>,
    device_type: Option<u16>,
) -> Result<Allowed, Refusal> {
    let rights = if read_only { Rights::ReadOnly } else { rights };
    policy.check(rights, frame, device_type)
}

/// The audit record of a write `from` sends, to `device` with `command` at `depth`
/// levels of command 77.
pub(crate) fn record_of(
    from: &Requester,
    device: String,
    command: u16,
    depth: usize,
) -> WriteRecord {
    let via = match from.unwrapped + depth {
        0 => from.record.via.clone(),
        1 => format!("{}, command 77", from.record.via),
        n => format!("{}, command 77 ({n} levels)", from.record.via),
    };
    WriteRecord {
        device,
        command,
        via,
        operation: hart_proto::command::title(command).map(str::to_string),
        ..from.record.clone()
    }
}

/// What became of a write sent as `request` (wrapped in `depth` levels of command 77)
/// that got `reply`: judged by the innermost reply, the write's own device's answer,
/// not by the I/O system's that carried it.
pub(crate) fn outcome(command: u16, depth: usize, reply: Option<&[u8]>) -> WriteOutcome {
    let Some(mut reply) = reply.map(<[u8]>::to_vec) else {
        return crate::write::outcome_of(command, None);
    };
    for _ in 0..depth {
        let Ok(f) = Frame::parse_pdu(&reply) else {
            break;
        };
        // An I/O system that refused to carry the frame (or carried nothing) is judged
        // by its own answer.
        if f.command != 77 || f.response_code.unwrap_or(0) != 0 {
            break;
        }
        let Ok(carried) = SendCommandToSubDeviceResponse::decode(&mut Reader::new(f.data)) else {
            break;
        };
        if carried.frame.as_slice().is_empty() {
            break;
        }
        // The sub-device's reply with its check byte, judged next whether it parses or
        // not (a broken one is judged as such).
        let mut buf = [0u8; hart_proto::frame::MAX_PDU_LEN];
        let _ = carried.embedded_frame(&mut buf);
        reply = buf[..=carried.frame.as_slice().len()].to_vec();
    }
    crate::write::outcome_of(command, Some(&reply))
}

/// The expanded device type of the device a frame's address names, where it says
/// (a long address); a short address leaves it to the caller.
pub(crate) fn device_type_of(address: &Address) -> Option<u16> {
    match address {
        Address::Long(a) if !a.id.is_broadcast() => Some(a.id.expanded_device_type),
        _ => None,
    }
}
