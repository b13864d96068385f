//! `--expect DEVICE.toml`: what the device maker says the device is, in the form of
//! the simulated devices' profiles (`crates/hart-device/profiles/*.toml`), so that a
//! maker describes the device once and can both simulate and test it.

use std::path::Path;

use hart_device::config::{CustomCommand, Identity};

/// What the device should be.
#[derive(Debug, Clone, PartialEq)]
pub struct Expect {
    /// The identity (`[identity]`).
    pub identity: Identity,
    /// Device-specific commands (`[[commands]]`).
    pub commands: Vec<CustomCommand>,
}

impl Expect {
    /// Reads a profile text.
    pub fn from_toml(text: &str) -> Result<Self, String> {
        let c = hart_device::DeviceConfig::from_toml(text)?;
        Ok(Expect {
            identity: c.identity,
            commands: c.commands,
        })
    }

    /// Reads a profile file; errors name the file and what is wrong in it.
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("--expect {}: {e}", path.display()))?;
        Self::from_toml(&text).map_err(|e| format!("--expect {}: {e}", path.display()))
    }
}
