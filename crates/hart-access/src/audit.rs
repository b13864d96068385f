//! The write audit: one record for every write a front end lets through, and a second
//! record of the same write (the same `id`) with what became of it.

use std::io::Write as _;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// One write let through, as the audit keeps it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct WriteRecord {
    /// The front end: `hart-ip`, `modbus-tcp`, `modbus-rtu`, `opcua`.
    pub front_end: &'static str,
    /// The front end's session number (HART-IP: its audit-log record).
    pub session: Option<u64>,
    /// Where the request came from: a socket address, or a serial port.
    pub peer: String,
    /// Who: a PSK identity, an OPC UA user.
    pub identity: Option<String>,
    /// The device written, as its address reads, or the gateway's own position and name.
    pub device: String,
    /// The HART command that writes (the innermost one of command 77).
    pub command: u16,
    /// How the command got there: `token-passing`, `direct PDU`, `command 77 (2
    /// levels)`, a Modbus register, an OPC UA method.
    pub via: String,
    /// What the write does, in words (`damping 2.5 s`), when the front end knows.
    pub operation: Option<String>,
}

/// What became of a write, as the audit's second record of it says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WriteOutcome {
    /// The device did it: its response code (0, or a warning such as 8 "set to
    /// nearest possible value").
    Done {
        /// The device's response code.
        response_code: u8,
    },
    /// The device refused it with this response code.
    Refused {
        /// The device's response code.
        response_code: u8,
    },
    /// The gateway did not let it through (`--read-only`, `--allow-commands`, a
    /// front end's rights): nothing was sent.
    NotPermitted(String),
    /// The device did not answer.
    NoReply,
    /// It did not reach the device, or its answer was not a reply (busy loop, bad
    /// reply): why.
    Failed(String),
}

impl WriteOutcome {
    /// `done`, `refused`, `not-permitted`, `no-reply` or `failed`: the audit file's
    /// `outcome`.
    pub fn name(&self) -> &'static str {
        match self {
            WriteOutcome::Done { .. } => "done",
            WriteOutcome::Refused { .. } => "refused",
            WriteOutcome::NotPermitted(_) => "not-permitted",
            WriteOutcome::NoReply => "no-reply",
            WriteOutcome::Failed(_) => "failed",
        }
    }

    /// The device's response code, when it answered.
    pub fn response_code(&self) -> Option<u8> {
        match self {
            WriteOutcome::Done { response_code } | WriteOutcome::Refused { response_code } => {
                Some(*response_code)
            }
            _ => None,
        }
    }

    /// Why, when the write was not done by the device (`None` for a device's answer).
    pub fn reason(&self) -> Option<&str> {
        match self {
            WriteOutcome::NotPermitted(r) | WriteOutcome::Failed(r) => Some(r),
            WriteOutcome::NoReply => Some("the device did not answer"),
            _ => None,
        }
    }
}

/// Where accepted writes are recorded: the log (standard error, `info`), and with a
/// file, one JSON line each appended to it. Cheap to clone; shared by every front end.
#[derive(Debug, Clone, Default)]
pub struct Audit {
    file: Option<PathBuf>,
    /// The number of the next record (`id`), shared by the clones.
    next: Arc<AtomicU64>,
}

impl Audit {
    /// An audit that logs, and appends to `file` when one is given.
    pub fn new(file: Option<PathBuf>) -> Self {
        Audit {
            file,
            next: Arc::new(AtomicU64::new(1)),
        }
    }

    /// The file, if any.
    pub fn file(&self) -> Option<&PathBuf> {
        self.file.as_ref()
    }

    /// Records a write about to be carried out, and returns its number (`id`) for its
    /// outcome ([`Audit::outcome`]). A file that cannot be written is reported on the
    /// log (the write goes on: the log has it).
    pub fn record(&self, w: &WriteRecord) -> u64 {
        let id = self.next.fetch_add(1, Ordering::Relaxed);
        let session = w.session.map_or_else(|| "-".to_string(), |n| n.to_string());
        tracing::info!(
            "write: {} session {session} peer {} identity {} device {} command {} via {}{}",
            w.front_end,
            w.peer,
            w.identity
                .as_ref()
                .map_or("-".to_string(), |i| format!("{i:?}")),
            w.device,
            w.command,
            w.via,
            w.operation
                .as_ref()
                .map_or(String::new(), |o| format!(" ({o})"))
        );
        self.append(&json_line(id, w, None));
        id
    }

    /// Records what became of write `id` (as [`Audit::record`] numbered it): a second
    /// record with the same fields and `outcome`, `response_code` and `reason`.
    pub fn outcome(&self, id: u64, w: &WriteRecord, outcome: &WriteOutcome) {
        let code = outcome
            .response_code()
            .map_or(String::new(), |c| format!(", response code {c}"));
        let why = outcome.reason().map_or(String::new(), |r| format!(": {r}"));
        match outcome {
            WriteOutcome::Done { .. } => {
                tracing::info!("write {id}: {}{code}", outcome.name())
            }
            _ => tracing::warn!(
                "write {id}: {}{code}{why} ({} command {} to {})",
                outcome.name(),
                w.front_end,
                w.command,
                w.device
            ),
        }
        self.append(&json_line(id, w, Some(outcome)));
    }

    /// Records a write the gateway refused before sending it: one record, its outcome
    /// `not-permitted`.
    pub fn refused(&self, w: &WriteRecord, why: &str) {
        let id = self.next.fetch_add(1, Ordering::Relaxed);
        let outcome = WriteOutcome::NotPermitted(why.to_string());
        tracing::warn!(
            "write {id}: refused: {} session {} peer {} command {} to {}: {why}",
            w.front_end,
            w.session.map_or_else(|| "-".to_string(), |n| n.to_string()),
            w.peer,
            w.command,
            w.device
        );
        self.append(&json_line(id, w, Some(&outcome)));
    }

    fn append(&self, line: &str) {
        let Some(path) = &self.file else { return };
        // One write call a line, appended: a crash leaves whole lines behind.
        let written = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .and_then(|mut f| f.write_all(line.as_bytes()));
        if let Err(e) = written {
            tracing::error!(
                "audit file {}: {e}; the write above is not in it (check the directory exists \
                 and the gateway may write there)",
                path.display()
            );
        }
    }
}

/// The audit file's line for write `id` as `w` says it: `id`, `time` (RFC 3339, ms),
/// `front_end`, `session`, `peer`, `identity`, `device`, `command`, `via`,
/// `operation`; with an outcome (the second record of a write, or a refusal's only
/// one) also `outcome`, `response_code` and `reason`.
pub fn json_line(id: u64, w: &WriteRecord, outcome: Option<&WriteOutcome>) -> String {
    let mut v = serde_json::json!({
        "id": id,
        "time": humantime::format_rfc3339_millis(std::time::SystemTime::now()).to_string(),
        "front_end": w.front_end,
        "session": w.session,
        "peer": w.peer,
        "identity": w.identity,
        "device": w.device,
        "command": w.command,
        "via": w.via,
        "operation": w.operation,
    });
    if let Some(o) = outcome {
        v["outcome"] = o.name().into();
        v["response_code"] = o.response_code().into();
        v["reason"] = o.reason().into();
    }
    v.to_string() + "\n"
}
