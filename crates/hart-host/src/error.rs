//! Errors that say what happened and what to check.

use std::fmt;

/// A host-side failure.
#[derive(Debug)]
pub enum HostError {
    /// No reply on any attempt.
    NoReply {
        /// The device asked ("polling address 3").
        target: String,
        /// Transmissions made.
        attempts: u8,
        /// Slave time-out in ms.
        sto_ms: u64,
        /// The port, described.
        port: String,
    },
    /// A HART-IP server answered that the device did not reply on its loop (the
    /// server made the retries there).
    NoReplyBehindServer {
        /// The device asked.
        target: String,
        /// The server, described.
        port: String,
        /// The HART-IP status the server gave.
        status: String,
    },
    /// Replies arrived damaged on every attempt.
    Communication {
        /// The device asked.
        target: String,
        /// Transmissions made.
        attempts: u8,
        /// The last communication-error summary.
        last_error: u8,
    },
    /// The device answered with an error response code.
    Device {
        /// Command sent.
        command: u16,
        /// Response code.
        code: u8,
        /// Its meaning.
        name: String,
    },
    /// The reply could not be decoded.
    Decode(String),
    /// Bad arguments.
    Usage(String),
    /// The port failed.
    Io(std::io::Error),
}

impl HostError {
    /// Exit status for the command line: 3 no reply / communication, 4 device error,
    /// 5 I/O, 2 usage and decoding.
    pub fn exit_code(&self) -> u8 {
        match self {
            HostError::NoReply { .. }
            | HostError::NoReplyBehindServer { .. }
            | HostError::Communication { .. } => 3,
            HostError::Device { .. } => 4,
            HostError::Io(_) => 5,
            HostError::Decode(_) | HostError::Usage(_) => 2,
        }
    }
}

impl fmt::Display for HostError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HostError::NoReply { target, attempts, sto_ms, port } => {
                write!(f, "no reply from {target} after {attempts} tries (STO {sto_ms} ms) on {port}; ")?;
                f.write_str(if port.starts_with("serial") {
                    "is the modem's RTS set right (--port ...?rts=high-tx|low-tx|none), and is a device at that address?"
                } else if port.starts_with("RS-485") {
                    "are A and B the right way round, is the bit rate right (--port rs485:...?baud=N), and is a device at that address?"
                } else if port.starts_with("HART-IP") {
                    "is the server still running, and does a firewall let its replies through?"
                } else {
                    "is a device at that address?"
                })
            }
            HostError::NoReplyBehindServer { target, port, status } => write!(
                f,
                "no reply from {target}: {port} reports that the device did not answer on its loop ({status}); is a device at that address (hartkit scan through the server), and is the server's loop connected?"
            ),
            HostError::Communication { target, attempts, last_error } => write!(
                f,
                "{target}: damaged replies on all {attempts} tries (last communication status 0x{last_error:02X}); check the wiring, the loop resistor (at least 230 Ω) and for a second master"
            ),
            HostError::Device { command, code, name } => write!(f, "device replied '{name}' ({code}) to command {command}"),
            HostError::Decode(e) => write!(f, "cannot decode the reply: {e}"),
            HostError::Usage(e) => f.write_str(e),
            HostError::Io(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for HostError {}

impl From<std::io::Error> for HostError {
    fn from(e: std::io::Error) -> Self {
        HostError::Io(e)
    }
}
