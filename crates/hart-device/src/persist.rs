//! The device's non-volatile memory: a state file written atomically (write a
//! temporary file, fsync it, rename it over the old one, fsync the directory), so a
//! crash at any moment leaves either the old or the new configuration, never a mix.

use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::config::DeviceConfig;

/// The state file of the device at polling address `poll` in `dir`.
pub fn state_path(dir: &Path, poll: u8) -> PathBuf {
    dir.join(format!("device-{poll:02}.toml"))
}

/// Writes `config` to `path` atomically.
pub fn save(path: &Path, config: &DeviceConfig) -> std::io::Result<()> {
    let text = toml::to_string(config).map_err(|e| std::io::Error::other(e.to_string()))?;
    write_atomic(path, text.as_bytes())
}

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    fs::create_dir_all(dir)?;
    let tmp = path.with_extension("toml.tmp");
    {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    fs::rename(&tmp, path)?;
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Loads a state file; `Ok(None)` when there is none yet. A leftover temporary file
/// from a crash mid-write is ignored (and removed).
pub fn load(path: &Path) -> Result<Option<DeviceConfig>, String> {
    let tmp = path.with_extension("toml.tmp");
    if tmp.exists() {
        let _ = fs::remove_file(&tmp);
    }
    match fs::read_to_string(path) {
        Ok(text) => DeviceConfig::from_toml(&text)
            .map(Some)
            .map_err(|e| format!("state file {}: {e}", path.display())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(format!("state file {}: {e}", path.display())),
    }
}
