//! The options of `hartkit serve`, as data.

use std::path::PathBuf;

use hart_modbus::map::FloatOrder;

/// The options of `hartkit serve`: shortcuts for the configuration file's settings,
/// which they add to or override ([`GatewayConfig::from_options`](crate::GatewayConfig::from_options)).
#[derive(Debug, Clone, Default)]
pub struct ServeOptions {
    /// `--config FILE`.
    pub config: Option<PathBuf>,
    /// `--hart-ip ADDR[:PORT]`.
    pub hart_ip: Option<String>,
    /// `--udp` / `--tcp` (neither: both).
    pub udp: bool,
    /// `--tcp`.
    pub tcp: bool,
    /// `--port TARGET...`: loops.
    pub ports: Vec<String>,
    /// `--sim [PROFILES...]`.
    pub sim: Option<Vec<String>>,
    /// `--instant`.
    pub instant: bool,
    /// `--read-only`: HART-IP refuses changes, Modbus refuses writes, OPC UA refuses
    /// method calls.
    pub read_only: bool,
    /// `--max-sessions`.
    pub max_sessions: usize,
    /// `--max-sessions-per-host`.
    pub max_sessions_per_host: usize,
    /// `--max-inactivity` seconds (`max_inactivity` in `[hart_ip]`): the longest
    /// inactivity timer a HART-IP session is granted.
    pub max_inactivity: Option<f64>,
    /// `--transparent`.
    pub transparent: bool,
    /// `--scan-to`.
    pub scan_to: u8,
    /// `--psk-file`.
    pub psk_file: Option<PathBuf>,
    /// `--plain`.
    pub plain: Option<String>,
    /// `--plain-rights`.
    pub plain_rights: Option<hart_access::Rights>,
    /// `--device-commands FILE`.
    pub device_commands: Option<PathBuf>,
    /// `--modbus-write-from NET...`.
    pub modbus_write_from: Vec<String>,
    /// `--modbus-priority NET...`.
    pub modbus_priority: Vec<String>,
    /// `--allow-commands`.
    pub allow_commands: Option<hart_ip_server::access::CommandAllowList>,
    /// `--audit-file`: every write let through by HART-IP or OPC UA, one JSON line each.
    pub audit_file: Option<PathBuf>,
    /// `--modbus ADDR[:PORT]`.
    pub modbus: Option<String>,
    /// `--modbus-rtu PORT`.
    pub modbus_rtu: Option<String>,
    /// `--modbus-baud`.
    pub modbus_baud: Option<u32>,
    /// `--modbus-parity`.
    pub modbus_parity: Option<char>,
    /// `--profibus [PORT]`: be a PROFIBUS DP slave on this serial port (an empty
    /// string: the flag without a port, for `--print-map --profibus`).
    pub profibus: Option<String>,
    /// `--profibus-address N`: the first station address.
    pub profibus_address: Option<u8>,
    /// `--profibus-baud`.
    pub profibus_baud: Option<u32>,
    /// `--float-order`.
    pub float_order: Option<FloatOrder>,
    /// `--opcua ADDR[:PORT]`.
    pub opcua: Option<String>,
    /// `--opcua-security`.
    pub opcua_security: Option<String>,
    /// `--opcua-user NAME:PASSWORD`.
    pub opcua_users: Vec<String>,
    /// `--opcua-pki DIR`.
    pub opcua_pki: Option<PathBuf>,
    /// `--poll-period` seconds.
    pub poll_period: Option<f64>,
    /// `--loop-test-limit` seconds (`loop_test_limit` in the file).
    pub loop_test_limit: Option<f64>,
    /// `--history DB`: keep every value's history in this SQLite file or
    /// `postgres://` database.
    pub history: Option<String>,
    /// `--mqtt URL`: publish to this MQTT broker as a Sparkplug B edge node.
    pub mqtt: Option<String>,
    /// `--group G`: the Sparkplug group (default `hartkit`).
    pub mqtt_group: Option<String>,
    /// `--edge-node NAME`: the Sparkplug edge node (default: the host name).
    pub mqtt_edge_node: Option<String>,
    /// `--primary-host ID`: publish only while that primary host application is
    /// online.
    pub mqtt_primary_host: Option<String>,
    /// `--mqtt-qos 0|1`: the QoS of births and data (`[mqtt] data_qos`).
    pub mqtt_qos: Option<u8>,
    /// `--web ADDR[:PORT]`: serve the web dashboard here (a port alone: 127.0.0.1).
    pub web: Option<String>,
    /// `--web-admin-password-file FILE`: the administrator's password (first line);
    /// without it the dashboard only reads.
    pub web_admin_password_file: Option<PathBuf>,
    /// `--web-cert FILE`: HTTPS with this PEM certificate chain (with `--web-key`).
    pub web_cert: Option<PathBuf>,
    /// `--web-key FILE`: the PEM private key of `--web-cert`.
    pub web_key: Option<PathBuf>,
    /// `--web-host NAME...`: names the dashboard answers to besides its addresses and
    /// `localhost` (added to `[web] hosts`).
    pub web_hosts: Vec<String>,
    /// `--json`: the console view (no front end) prints JSON lines.
    pub json: bool,
}
