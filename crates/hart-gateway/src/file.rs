//! The gateway's configuration file (`hartkit serve --config FILE`), as TOML.

use std::path::PathBuf;
use std::time::Duration;

use hart_modbus::map::{Entry, FloatOrder};
use hart_poller::{LoopSettings, PollSettings};
use serde::Deserialize;

/// The gateway configuration file (`hartkit serve --config FILE`); every section is
/// optional, and options on the command line add to it.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GatewayFile {
    /// Poll defaults (`[poll]`).
    #[serde(default)]
    pub poll: Option<PollSettings>,
    /// The longest a loop test (fixed loop current) lasts before the gateway releases
    /// it ("10m", the default; `--loop-test-limit`).
    #[serde(default, with = "humantime_serde")]
    pub loop_test_limit: Option<Duration>,
    /// The loops (`[[loop]]`).
    #[serde(default, rename = "loop")]
    pub loops: Vec<LoopSettings>,
    /// The HART-IP front end (`[hart_ip]`).
    #[serde(default)]
    pub hart_ip: Option<HartIpSection>,
    /// The Modbus TCP front end (`[modbus]`).
    #[serde(default)]
    pub modbus: Option<ModbusSection>,
    /// The Modbus RTU front end (`[modbus_rtu]`).
    #[serde(default)]
    pub modbus_rtu: Option<RtuSection>,
    /// The PROFIBUS DP front end (`[profibus]`).
    #[serde(default)]
    pub profibus: Option<ProfibusSection>,
    /// The OPC UA front end (`[opcua]`).
    #[serde(default)]
    pub opcua: Option<OpcUaSection>,
    /// The historian (`[history]`).
    #[serde(default)]
    pub history: Option<hart_history::HistoryConfig>,
    /// The MQTT Sparkplug B publisher (`[mqtt]`).
    #[serde(default)]
    pub mqtt: Option<hart_sparkplug_edge::MqttConfig>,
    /// The web dashboard (`[web]`).
    #[serde(default)]
    pub web: Option<WebSection>,
    /// Device-specific commands declared reads (`[[device_commands]]`, as the
    /// `[[device]]` tables of `--device-commands FILE`).
    #[serde(default)]
    pub device_commands: Vec<hart_access::devices::DeviceEntry>,
}

/// `[opcua]`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpcUaSection {
    /// `ADDR[:PORT]` (port 4840 by default).
    #[serde(default)]
    pub bind: Option<String>,
    /// `none`, `basic256sha256` or `both`; default `basic256sha256` when users are
    /// configured, else `none` on a loopback address and `basic256sha256` on any other.
    #[serde(default)]
    pub security: Option<String>,
    /// Users of the secure endpoint, `NAME:PASSWORD` (with any, anonymous sessions only
    /// read; not with security `none`).
    #[serde(default)]
    pub users: Vec<String>,
    /// Where the certificate and key are kept.
    #[serde(default)]
    pub pki_dir: Option<PathBuf>,
    /// Most TCP connections at once (default 64); a full pool closes one still in its
    /// handshake, else the one idle longest, to admit a new one.
    #[serde(default)]
    pub max_connections: Option<usize>,
    /// Most TCP connections from one address (default 16; priority hosts aside).
    #[serde(default)]
    pub max_per_address: Option<usize>,
    /// Hosts (addresses or networks) whose connections are never closed to admit
    /// others nor limited per address: the SCADA hosts.
    #[serde(default)]
    pub priority: Vec<String>,
    /// A new connection must open its secure channel (HEL/ACK, OPN) within this
    /// (default 10 s).
    #[serde(default, with = "humantime_serde")]
    pub handshake_timeout: Option<Duration>,
    /// Most sessions at once (default 100).
    #[serde(default)]
    pub max_sessions: Option<usize>,
    /// The longest session time-out granted (default 30 s): a session without requests
    /// for that long, one never activated among them, is closed.
    #[serde(default, with = "humantime_serde")]
    pub session_timeout: Option<Duration>,
    /// The largest message in bytes either way (default 2 MiB).
    #[serde(default)]
    pub max_message_size: Option<usize>,
}

/// `[hart_ip]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HartIpSection {
    /// `ADDR[:PORT]` (port 5094 by default).
    pub bind: String,
    /// What plain sessions may do: `read-only` (the default with a PSK file) or
    /// `read-write` (the default without).
    #[serde(default)]
    pub plain_rights: Option<hart_access::Rights>,
    /// Longest inactivity timer a session is granted (default 5 minutes): a client
    /// asking for more gets this.
    #[serde(default, with = "humantime_serde")]
    pub max_inactivity: Option<Duration>,
}

/// `[modbus]`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusSection {
    /// `ADDR[:PORT]` of the TCP server (port 502 by default); none: no TCP server
    /// (the section then only sets the map for `[modbus_rtu]`).
    #[serde(default)]
    pub bind: Option<String>,
    /// `abcd` (default), `cdab`, `badc` or `dcba`.
    #[serde(default)]
    pub float_order: Option<FloatOrder>,
    /// A custom register map (`[[modbus.register]]`), replacing the default one.
    #[serde(default)]
    pub register: Vec<Entry>,
    /// Most TCP connections at once (default 64); a full pool closes one not in use
    /// (from the host holding the most) to admit a new one.
    #[serde(default)]
    pub max_connections: Option<usize>,
    /// Most TCP connections from one address (default 16; priority hosts aside).
    #[serde(default)]
    pub max_per_address: Option<usize>,
    /// Hosts (addresses or networks) whose connections are never closed to admit
    /// others nor limited per address: the SCADA hosts.
    #[serde(default)]
    pub priority: Vec<String>,
    /// A new connection must complete a request within this (default 10 s).
    #[serde(default, with = "humantime_serde")]
    pub first_request: Option<Duration>,
    /// A request begun must be whole within this (default 5 s).
    #[serde(default, with = "humantime_serde")]
    pub request: Option<Duration>,
    /// Clients that may write, as networks (`["10.0.0.0/24"]`); loopback only by
    /// default. Others' writes are answered "illegal function".
    #[serde(default)]
    pub write_from: Option<Vec<String>>,
}

/// `[modbus_rtu]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RtuSection {
    /// Serial port.
    pub port: String,
    /// Baud rate (default 19200).
    #[serde(default)]
    pub baud: Option<u32>,
    /// Parity `N`, `E` (default) or `O`.
    #[serde(default)]
    pub parity: Option<char>,
    /// Stop bits (default 1; 2 with no parity).
    #[serde(default)]
    pub stop_bits: Option<u8>,
}

/// `[profibus]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfibusSection {
    /// Serial port (an RS-485 adapter, or a pseudo-terminal).
    pub port: String,
    /// Station address of the first 8 devices (default 5); further devices take the
    /// next addresses.
    #[serde(default)]
    pub address: Option<u8>,
    /// Bit rate: 9600, 19200 (default), 45450 or 93750.
    #[serde(default)]
    pub baud: Option<u32>,
    /// Ident number (default 0x4854, as in the GSD file `--print-gsd` writes).
    #[serde(default)]
    pub ident_number: Option<u16>,
}

impl GatewayFile {
    /// Reads and checks the file at `path`.
    pub fn load(path: &std::path::Path) -> Result<GatewayFile, crate::Error> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| crate::Error::config(format!("--config {}: {e}", path.display())))?;
        toml::from_str(&text)
            .map_err(|e| crate::Error::config(format!("--config {}: {e}", path.display())))
    }
}

/// `[web]`: the web dashboard (docs/web.md).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WebSection {
    /// `ADDR[:PORT]` (a port alone: 127.0.0.1), as `--web`.
    pub bind: Option<String>,
    /// The administrator's password file, as `--web-admin-password-file`.
    pub admin_password_file: Option<PathBuf>,
    /// HTTPS certificate chain (PEM), as `--web-cert`.
    pub cert: Option<PathBuf>,
    /// HTTPS private key (PEM), as `--web-key`.
    pub key: Option<PathBuf>,
    /// How much of each device's PV and loop current the dashboard keeps in memory
    /// for trends without a historian (default 1h).
    #[serde(default, with = "humantime_serde")]
    pub memory_window: Option<std::time::Duration>,
    /// Names the dashboard answers to besides its own addresses and `localhost`
    /// (`plant-gw.example`, `plant-gw.example:8443`), as `--web-host`: a request to any
    /// other `Host` is refused (DNS rebinding), and so is a write from another origin.
    #[serde(default)]
    pub hosts: Vec<String>,
    /// Most connections at once (default 512); a full pool closes one that has not
    /// completed a request, else one idle, to admit a new one.
    #[serde(default)]
    pub max_connections: Option<usize>,
    /// Most connections from one address (default 16; priority hosts aside).
    #[serde(default)]
    pub max_per_address: Option<usize>,
    /// Hosts (addresses or networks) whose connections are never closed to admit
    /// others nor limited per address: a reverse proxy, the control room.
    #[serde(default)]
    pub priority: Vec<String>,
    /// A request's head must come whole within this, and its body within this after
    /// it (default 10s).
    #[serde(default, with = "humantime_serde")]
    pub header_timeout: Option<std::time::Duration>,
    /// A kept-alive connection without a request this long is closed (default 60s).
    #[serde(default, with = "humantime_serde")]
    pub idle_timeout: Option<std::time::Duration>,
}
