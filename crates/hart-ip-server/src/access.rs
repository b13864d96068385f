//! Access control: which commands sessions may send (`--allow-commands`), who may
//! write (`--read-only`, read-only PSK identities), and an audit line for every write
//! the server lets through.

use std::io::Write as _;
use std::net::SocketAddr;
use std::ops::RangeInclusive;
use std::path::PathBuf;
use std::str::FromStr;

use hart_proto::frame::Frame;

/// The commands sessions may send, as ranges: `0-22,48,74-84,532-533`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandAllowList(Vec<RangeInclusive<u16>>);

impl CommandAllowList {
    /// Whether `command` is on the list.
    pub fn allows(&self, command: u16) -> bool {
        self.0.iter().any(|r| r.contains(&command))
    }
}

impl FromStr for CommandAllowList {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let number = |t: &str| -> Result<u16, String> {
            t.trim()
                .parse()
                .map_err(|_| format!("{t:?} is not a command number (0-65535)"))
        };
        let mut ranges = vec![];
        for part in text.split(',').filter(|p| !p.trim().is_empty()) {
            let range = match part.split_once('-') {
                Some((a, b)) => {
                    let (a, b) = (number(a)?, number(b)?);
                    if a > b {
                        return Err(format!("{part:?}: the range runs backwards"));
                    }
                    a..=b
                }
                None => {
                    let n = number(part)?;
                    n..=n
                }
            };
            ranges.push(range);
        }
        if ranges.is_empty() {
            return Err("no command given (e.g. 0-22,48,74-84)".into());
        }
        Ok(CommandAllowList(ranges))
    }
}

/// The command a frame carries, and for command 77 (send command to sub-device) the
/// command wrapped in it.
pub(crate) fn commands(f: &Frame<'_>) -> (u16, Option<u16>) {
    let inner = (f.command == 77)
        .then(|| embedded(f).map(|g| g.1))
        .flatten();
    (f.command, inner)
}

/// The frame wrapped in a command 77 request (card, channel, preambles, then the
/// frame without its check byte): its address, described, and its command.
pub(crate) fn embedded(f: &Frame<'_>) -> Option<(String, u16)> {
    let mut inner = f.data.get(3..)?.to_vec();
    inner.push(hart_proto::frame::checksum(&inner));
    Frame::parse_pdu(&inner)
        .ok()
        .map(|g| (g.address.to_string(), g.command))
}

/// One accepted write, for the audit.
pub(crate) struct Write<'a> {
    pub(crate) session: Option<u64>,
    pub(crate) peer: SocketAddr,
    pub(crate) identity: Option<&'a str>,
    pub(crate) device: String,
    pub(crate) command: u16,
}

/// Logs an accepted write (standard error, and the audit file when one is set).
pub(crate) fn audit_write(file: Option<&PathBuf>, w: &Write<'_>) {
    let session = w.session.map_or_else(|| "-".to_string(), |n| n.to_string());
    let identity = w.identity.unwrap_or("-");
    tracing::info!(
        "write: session {session} peer {} identity {identity:?} device {} command {}",
        w.peer,
        w.device,
        w.command
    );
    let Some(path) = file else { return };
    let line = serde_json::json!({
        "time": humantime::format_rfc3339_millis(std::time::SystemTime::now()).to_string(),
        "session": w.session,
        "peer": w.peer.to_string(),
        "identity": w.identity,
        "device": w.device,
        "command": w.command,
    })
    .to_string()
        + "\n";
    // One write call a line, appended: a crash leaves whole lines behind.
    let written = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .and_then(|mut f| f.write_all(line.as_bytes()));
    if let Err(e) = written {
        tracing::error!(
            "audit file {}: {e}; the write above is not in it",
            path.display()
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn allow_lists() {
        let a: CommandAllowList = "0-22, 48,74-84".parse().unwrap();
        for c in [0, 13, 22, 48, 74, 84] {
            assert!(a.allows(c), "{c}");
        }
        for c in [23, 47, 49, 85, 533] {
            assert!(!a.allows(c), "{c}");
        }
        for bad in ["", "x", "5-2", "0-70000", "1,,"] {
            if bad == "1,," {
                assert!(bad.parse::<CommandAllowList>().is_ok());
                continue;
            }
            assert!(bad.parse::<CommandAllowList>().is_err(), "{bad}");
        }
    }
}
