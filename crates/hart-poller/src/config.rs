//! What the engine polls, and how often: the `[poll]` and `[[loop]]` sections of a
//! gateway configuration file, or the defaults.

use std::time::Duration;

use serde::Deserialize;

/// The read command a poll sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(try_from = "u16")]
pub enum ReadCommand {
    /// Command 3: loop current and PV, SV, TV, QV with units (every HART revision).
    #[default]
    Dynamic,
    /// Command 9: PV, SV, TV, QV with their device variable status, the loop current
    /// and percent of range in one reply (HART 6 and later; a device that refuses it
    /// is polled with command 3 instead).
    Variables,
}

impl TryFrom<u16> for ReadCommand {
    type Error = String;
    fn try_from(n: u16) -> Result<Self, String> {
        match n {
            3 => Ok(ReadCommand::Dynamic),
            9 => Ok(ReadCommand::Variables),
            n => Err(format!(
                "read = {n}: the engine polls with command 3 (dynamic variables) or 9 \
                 (device variables with status)"
            )),
        }
    }
}

impl ReadCommand {
    /// The command number.
    pub fn number(self) -> u16 {
        match self {
            ReadCommand::Dynamic => 3,
            ReadCommand::Variables => 9,
        }
    }
}

/// Poll settings, for the whole engine (`[poll]`), a loop or a device.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PollSettings {
    /// Poll each device at most this often ("1s", "500ms"). A loop too slow for every
    /// device's period polls them in turn as fast as it can.
    #[serde(default = "default_period", with = "humantime_serde")]
    pub period: Duration,
    /// The read command: 3 or 9.
    #[serde(default)]
    pub read: ReadCommand,
    /// Values older than this are "stale" (default: 3 periods, at least 10 s).
    #[serde(default, with = "humantime_serde")]
    pub stale_after: Option<Duration>,
    /// After the first scan, one more polling address is tried this often, to find
    /// devices connected later and forget removed ones ("0s": never).
    #[serde(default = "default_rescan", with = "humantime_serde")]
    pub rescan: Duration,
}

fn default_period() -> Duration {
    Duration::from_secs(1)
}

fn default_rescan() -> Duration {
    Duration::from_secs(10)
}

impl Default for PollSettings {
    fn default() -> Self {
        PollSettings {
            period: default_period(),
            read: ReadCommand::default(),
            stale_after: None,
            rescan: default_rescan(),
        }
    }
}

impl PollSettings {
    /// The stale limit: as given, or 3 periods and at least 10 s.
    pub fn stale_limit(&self) -> Duration {
        self.stale_after
            .unwrap_or_else(|| (self.period * 3).max(Duration::from_secs(10)))
    }
}

/// A device listed in the configuration (`[[loop.device]]`): it keeps its position in
/// the device list (its Modbus unit id) whether or not it answers.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceSettings {
    /// Polling address.
    pub poll: u8,
    /// A name for the front ends (OPC UA browse name); default the long tag or tag.
    #[serde(default)]
    pub name: Option<String>,
    /// Poll period of this device.
    #[serde(default, with = "humantime_serde")]
    pub period: Option<Duration>,
    /// Read command of this device.
    #[serde(default)]
    pub read: Option<ReadCommand>,
}

/// A loop (`[[loop]]`): where it is, and what to find and poll on it.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoopSettings {
    /// Name (OPC UA folder); default `loop1`, `loop2`, ... in order.
    #[serde(default)]
    pub name: Option<String>,
    /// The line: any `hartkit --port` target (serial port, `rs485:`, `udp://`,
    /// `tcp://`, `sim`, `sim:PLANT.toml`).
    #[serde(default)]
    pub port: Option<String>,
    /// Scan polling addresses 0..=N (default 63) for devices besides those listed.
    #[serde(default = "default_scan_to")]
    pub scan_to: u8,
    /// Scan at all (`false`: only the devices listed are identified and polled).
    #[serde(default = "yes")]
    pub scan: bool,
    /// Poll period for this loop's devices.
    #[serde(default, with = "humantime_serde")]
    pub period: Option<Duration>,
    /// Read command for this loop's devices.
    #[serde(default)]
    pub read: Option<ReadCommand>,
    /// Devices listed, in order.
    #[serde(default)]
    pub device: Vec<DeviceSettings>,
}

fn default_scan_to() -> u8 {
    63
}

fn yes() -> bool {
    true
}

impl Default for LoopSettings {
    fn default() -> Self {
        LoopSettings {
            name: None,
            port: None,
            scan_to: default_scan_to(),
            scan: true,
            period: None,
            read: None,
            device: vec![],
        }
    }
}

impl LoopSettings {
    /// Checks what serde cannot: listed polling addresses are 0-63 (HART's six bits).
    pub fn check(&self) -> Result<(), String> {
        match self.device.iter().find(|d| d.poll > 63) {
            Some(d) => Err(format!(
                "loop {}: device poll = {}: polling addresses are 0-63",
                self.name.as_deref().unwrap_or("(unnamed)"),
                d.poll
            )),
            None => Ok(()),
        }
    }

    /// The polling addresses the scan visits, listed devices first (addresses over 63,
    /// which [`LoopSettings::check`] refuses, are left out).
    pub fn scan_order(&self) -> Vec<u8> {
        let mut order: Vec<u8> = vec![];
        for d in &self.device {
            if d.poll <= 63 && !order.contains(&d.poll) {
                order.push(d.poll);
            }
        }
        if self.scan {
            for p in 0..=self.scan_to.min(63) {
                if !order.contains(&p) {
                    order.push(p);
                }
            }
        }
        order
    }
}

/// The engine's settings.
#[derive(Debug, Clone, Default)]
pub struct EngineConfig {
    /// Poll the devices into the image (off: the engine only carries requests and
    /// scans, as a plain HART-IP server does).
    pub poll: bool,
    /// Defaults for every loop and device.
    pub defaults: PollSettings,
    /// The longest a loop test (a fixed current, command 40) lasts before the engine
    /// releases it, whoever asked for it (`--loop-test-limit`); `None`:
    /// [`crate::lease::DEFAULT_LIMIT`].
    pub loop_test_limit: Option<Duration>,
}

impl EngineConfig {
    /// The longest a loop test lasts.
    pub fn loop_test_limit(&self) -> Duration {
        self.loop_test_limit
            .unwrap_or(crate::lease::DEFAULT_LIMIT)
            .max(Duration::from_secs(1))
    }

    /// The poll period and read command of a device on `lp` (`dev`: as listed).
    pub fn device_settings(
        &self,
        lp: &LoopSettings,
        dev: Option<&DeviceSettings>,
    ) -> (Duration, ReadCommand) {
        let period = dev
            .and_then(|d| d.period)
            .or(lp.period)
            .unwrap_or(self.defaults.period);
        let read = dev
            .and_then(|d| d.read)
            .or(lp.read)
            .unwrap_or(self.defaults.read);
        (period.max(Duration::from_millis(10)), read)
    }

    /// The stale limit of a device polled every `period`.
    pub fn stale_limit(&self, period: Duration) -> Duration {
        self.defaults
            .stale_after
            .unwrap_or_else(|| (period * 3).max(Duration::from_secs(10)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Deserialize)]
    struct File {
        poll: PollSettings,
        #[serde(rename = "loop")]
        loops: Vec<LoopSettings>,
    }

    #[test]
    fn parses_a_full_example() {
        let f: File = toml::from_str(
            r#"
            [poll]
            period = "2s"
            read = 9
            stale_after = "30s"

            [[loop]]
            name = "north"
            port = "/dev/ttyUSB0"
            scan_to = 15
            [[loop.device]]
            poll = 3
            name = "FT-101"
            period = "500ms"
            read = 3
            "#,
        )
        .unwrap();
        assert_eq!(f.poll.period, Duration::from_secs(2));
        assert_eq!(f.poll.read, ReadCommand::Variables);
        let lp = &f.loops[0];
        assert_eq!(lp.scan_order()[..3], [3, 0, 1]);
        assert_eq!(lp.scan_order().len(), 16);
        let e = EngineConfig {
            loop_test_limit: None,
            poll: true,
            defaults: f.poll,
        };
        assert_eq!(
            e.device_settings(lp, Some(&lp.device[0])),
            (Duration::from_millis(500), ReadCommand::Dynamic)
        );
        assert_eq!(
            e.device_settings(lp, None),
            (Duration::from_secs(2), ReadCommand::Variables)
        );
    }

    #[test]
    fn refuses_polling_addresses_over_63() {
        let l: LoopSettings = toml::from_str("[[device]]\npoll = 200\n").unwrap();
        assert!(l.check().unwrap_err().contains("0-63"));
        // The engine, given one anyway, leaves it out of the scan.
        assert!(!l.scan_order().contains(&200));
    }

    #[test]
    fn refuses_other_read_commands() {
        let e = toml::from_str::<PollSettings>("read = 1").unwrap_err();
        assert!(e.to_string().contains("command 3"), "{e}");
    }
}
