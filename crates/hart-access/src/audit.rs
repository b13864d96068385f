//! The write audit: one line for every write a front end lets through.

use std::io::Write as _;
use std::path::PathBuf;

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

/// Where accepted writes are recorded: the log (standard error, `info`), and with a
/// file, one JSON line each appended to it. Cheap to clone; shared by every front end.
#[derive(Debug, Clone, Default)]
pub struct Audit {
    file: Option<PathBuf>,
}

impl Audit {
    /// An audit that logs, and appends to `file` when one is given.
    pub fn new(file: Option<PathBuf>) -> Self {
        Audit { file }
    }

    /// The file, if any.
    pub fn file(&self) -> Option<&PathBuf> {
        self.file.as_ref()
    }

    /// Records a write about to be carried out. A file that cannot be written is
    /// reported on the log (the write goes on: the log has it).
    pub fn record(&self, w: &WriteRecord) {
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
        let Some(path) = &self.file else { return };
        let line = json_line(w);
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

/// The audit file's line for `w`: `time` (RFC 3339, ms), `front_end`, `session`,
/// `peer`, `identity`, `device`, `command`, `via`, `operation`.
pub fn json_line(w: &WriteRecord) -> String {
    serde_json::json!({
        "time": humantime::format_rfc3339_millis(std::time::SystemTime::now()).to_string(),
        "front_end": w.front_end,
        "session": w.session,
        "peer": w.peer,
        "identity": w.identity,
        "device": w.device,
        "command": w.command,
        "via": w.via,
        "operation": w.operation,
    })
    .to_string()
        + "\n"
}
