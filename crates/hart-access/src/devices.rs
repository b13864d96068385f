//! `--device-commands FILE`: the device-specific commands a plant declares reads.
//!
//! ```toml
//! # The simulated valve: command 128 reads the setpoint, 129 writes it.
//! [[device]]
//! type = "26F1"          # expanded device type, hex, as its unique ID begins
//! name = "hartkit valve" # for people; not checked
//! reads = "128,130-131"
//! ```

use std::ops::RangeInclusive;
use std::path::Path;

use hart_proto::command::Access;
use serde::Deserialize;

/// One device type's declared reads (`[[device]]` in the file, `[[device_commands]]`
/// in the gateway's configuration).
#[derive(Debug, Clone, Deserialize, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct DeviceEntry {
    /// Expanded device type, hex (`"26F1"`, `"0x26F1"`).
    #[serde(rename = "type")]
    pub device_type: String,
    /// A name for people.
    #[serde(default)]
    pub name: Option<String>,
    /// The commands that only read: ranges as text (`"128,130-131"`).
    pub reads: String,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    device: Vec<DeviceEntry>,
}

/// Device-specific commands declared reads, per expanded device type.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DeviceCommands(Vec<(u16, Vec<RangeInclusive<u16>>)>);

impl DeviceCommands {
    /// Whether the plant declared `command` a read for devices of `device_type`.
    pub fn reads(&self, device_type: u16, command: u16) -> bool {
        self.0
            .iter()
            .any(|(t, r)| *t == device_type & 0x3FFF && r.iter().any(|r| r.contains(&command)))
    }

    /// Whether nothing is declared.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// From entries; a command the project knows (a universal or common-practice
    /// write, command 77) cannot be declared a read.
    pub fn from_entries(entries: &[DeviceEntry]) -> Result<Self, String> {
        let mut out = vec![];
        for e in entries {
            let t = e.device_type.trim();
            let hex = t
                .strip_prefix("0x")
                .or_else(|| t.strip_prefix("0X"))
                .unwrap_or(t);
            let ty = u16::from_str_radix(hex, 16)
                .ok()
                .filter(|v| *v <= 0x3FFF)
                .ok_or_else(|| {
                    format!(
                        "device type {t:?}: give the expanded device type in hex, 0000-3FFF \
                         (the first four digits of the device's unique ID)"
                    )
                })?;
            let ranges = crate::allow::parse_ranges(&e.reads)
                .map_err(|m| format!("device type {t}: reads: {m}"))?;
            for r in &ranges {
                for c in r.clone() {
                    match hart_proto::command::access(c) {
                        Access::Unknown | Access::Read => {}
                        _ => {
                            return Err(format!(
                                "device type {t}: command {c} ({}) is not device-specific and \
                                 does not only read; it cannot be declared a read",
                                hart_proto::command::title(c).unwrap_or("a known command")
                            ))
                        }
                    }
                }
            }
            out.push((ty, ranges));
        }
        Ok(DeviceCommands(out))
    }

    /// Reads a file of `[[device]]` tables.
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("--device-commands {}: {e}", path.display()))?;
        Self::parse(&text).map_err(|e| format!("--device-commands {}: {e}", path.display()))
    }

    /// Reads the text of a file of `[[device]]` tables.
    pub fn parse(text: &str) -> Result<Self, String> {
        let f: File = toml::from_str(text).map_err(|e| e.to_string())?;
        Self::from_entries(&f.device)
    }

    /// Both declarations together.
    pub fn merge(mut self, other: DeviceCommands) -> Self {
        self.0.extend(other.0);
        self
    }
}
