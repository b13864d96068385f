//! Built-in device profiles (shipped as TOML files in `crates/hart-device/profiles/`,
//! embedded at build time) and loading user profiles.

use std::path::Path;

use crate::config::DeviceConfig;

/// Names and texts of the built-in profiles.
pub const BUILTIN: &[(&str, &str)] = &[
    ("pressure", include_str!("../profiles/pressure.toml")),
    ("temperature", include_str!("../profiles/temperature.toml")),
    ("valve", include_str!("../profiles/valve.toml")),
];

/// Loads a built-in profile by name, or a profile file by path.
pub fn load(name_or_path: &str) -> Result<DeviceConfig, String> {
    if let Some((_, text)) = BUILTIN.iter().find(|(n, _)| *n == name_or_path) {
        return DeviceConfig::from_toml(text)
            .map_err(|e| format!("built-in profile {name_or_path}: {e}"));
    }
    let path = Path::new(name_or_path);
    if !path.exists() {
        let names: Vec<&str> = BUILTIN.iter().map(|(n, _)| *n).collect();
        return Err(format!(
            "profile {name_or_path}: not a built-in profile ({}) and no such file",
            names.join(", ")
        ));
    }
    let text =
        std::fs::read_to_string(path).map_err(|e| format!("profile {}: {e}", path.display()))?;
    DeviceConfig::from_toml(&text).map_err(|e| format!("profile {}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_builtin_profile_parses() {
        for (name, _) in super::BUILTIN {
            let c = super::load(name).unwrap();
            assert_eq!(c.profile, *name);
            assert!(c.burst.len() >= 3);
        }
    }
}
