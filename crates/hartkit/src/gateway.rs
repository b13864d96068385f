//! `hartkit serve`: the gateway. One polling engine (hart-poller) owns the loops; the
//! front ends asked for (HART-IP, Modbus TCP, Modbus RTU, OPC UA) sit on it. This module only
//! reads the options and the configuration file and wires the parts together.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use hart_modbus::map::{Entry, FloatOrder, RegisterMap};
use hart_poller::{Engine, EngineConfig, Line, LoopSettings, LoopSpec, PollSettings};
use serde::Deserialize;

/// A failure: the message and the process exit code (2 usage, 5 I/O).
pub type Failure = (String, u8);

/// The gateway configuration file (`hartkit serve --config FILE`); every section is
/// optional, and options on the command line add to it.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GatewayFile {
    /// Poll defaults (`[poll]`).
    #[serde(default)]
    pub poll: Option<PollSettings>,
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
    /// The OPC UA front end (`[opcua]`).
    #[serde(default)]
    pub opcua: Option<OpcUaSection>,
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
    /// Most TCP connections at once (default 64); a full pool closes its oldest idle
    /// connection to admit a new one.
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

/// The command line of `hartkit serve`.
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
    /// `--print-map`: print the Modbus map and exit.
    pub print_map: bool,
    /// `--json` (with `--print-map`, or the console view).
    pub json: bool,
    /// `--run-for` seconds.
    pub run_for: Option<f64>,
}

/// `ADDR[:PORT]` (`port` when none) as a socket address; `what` names the option.
pub fn socket_addr(what: &str, text: &str, port: u16) -> Result<SocketAddr, Failure> {
    use std::net::ToSocketAddrs;
    let with_port = if text
        .rsplit_once(':')
        .is_some_and(|(_, p)| p.parse::<u16>().is_ok())
    {
        text.to_string()
    } else {
        format!("{text}:{port}")
    };
    with_port
        .to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
        .ok_or_else(|| (format!("{what} {text}: not an address"), 2))
}

/// The plant behind `--sim [PROFILES...]`: the profiles at polling addresses 1, 2, ...,
/// or the demo plant when none are given.
fn sim_plant(profiles: &[String]) -> Result<hart_host::transport::Plant, Failure> {
    use hart_host::transport::Plant;
    if profiles.is_empty() {
        Ok(Plant::demo())
    } else {
        Plant::from_profiles(profiles).map_err(|e| (format!("--sim: {e}"), 2))
    }
}

/// The OPC UA settings from the file's `[opcua]` and the options; `None`: no OPC UA.
fn opcua_config(
    file: &GatewayFile,
    opts: &ServeOptions,
) -> Result<Option<hart_opcua::Config>, Failure> {
    let section = file.opcua.clone().unwrap_or_default();
    let Some(bind) = opts.opcua.clone().or(section.bind.clone()) else {
        return Ok(None);
    };
    let bind = socket_addr("--opcua", &bind, 4840)?;
    let mut users = vec![];
    for u in opts.opcua_users.iter().chain(&section.users) {
        let Some((name, pass)) = u
            .split_once(':')
            .filter(|(n, p)| !n.is_empty() && !p.is_empty())
        else {
            return Err((
                format!("--opcua-user {u:?}: give NAME:PASSWORD (both non-empty)"),
                2,
            ));
        };
        users.push((name.to_string(), pass.to_string()));
    }
    // Where the security was chosen, for the messages.
    let (security, from) = match (&opts.opcua_security, &section.security) {
        (Some(s), _) => (Some(s.as_str()), format!("--opcua-security {s}")),
        (None, Some(s)) => (
            Some(s.as_str()),
            format!("[opcua] security = {s:?} in --config"),
        ),
        (None, None) => (None, String::new()),
    };
    let security = match security {
        // Users are never ignored: they get the endpoint that takes them.
        None if !users.is_empty() => hart_opcua::Security::Basic256Sha256,
        None if bind.ip().is_loopback() => hart_opcua::Security::None,
        None => hart_opcua::Security::Basic256Sha256,
        Some("none") if !users.is_empty() => {
            return Err((
                format!(
                    "{from} with users (--opcua-user or [opcua] users): a password over \
                     SecurityPolicy None travels in clear; give --opcua-security \
                     basic256sha256 (users only, signed and encrypted) or both (anonymous \
                     read-only on None, users on Basic256Sha256)"
                ),
                2,
            ))
        }
        Some("none") => hart_opcua::Security::None,
        Some("basic256sha256") => hart_opcua::Security::Basic256Sha256,
        Some("both") => hart_opcua::Security::Both,
        Some(_) => return Err((format!("{from}: give none, basic256sha256 or both"), 2)),
    };
    let pki_dir = opts
        .opcua_pki
        .clone()
        .or(section.pki_dir.clone())
        .unwrap_or_else(default_pki_dir);
    let config = hart_opcua::Config {
        bind,
        security,
        users,
        pki_dir,
        read_only: opts.read_only,
        audit: hart_access::Audit::new(opts.audit_file.clone()),
    };
    config.check().map_err(|e| (format!("--opcua: {e}"), 2))?;
    Ok(Some(config))
}

/// The device-specific commands declared reads: `--device-commands FILE` and the
/// configuration's `[[device_commands]]`.
fn device_commands(
    file: &GatewayFile,
    opts: &ServeOptions,
) -> Result<hart_access::DeviceCommands, Failure> {
    let from_config = hart_access::DeviceCommands::from_entries(&file.device_commands)
        .map_err(|e| (format!("--config: device_commands: {e}"), 2))?;
    let from_file = match &opts.device_commands {
        Some(p) => hart_access::DeviceCommands::load(p).map_err(|e| (e, 2))?,
        None => hart_access::DeviceCommands::default(),
    };
    Ok(from_config.merge(from_file))
}

/// Where the OPC UA certificate and the trust list of client certificates are kept by
/// default: `$XDG_DATA_HOME/hartkit/opcua-pki`, `~/.local/share/hartkit/opcua-pki`, or
/// `./hartkit-opcua-pki`.
pub fn default_pki_dir() -> PathBuf {
    std::env::var_os("XDG_DATA_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/share")))
        .map(|d| d.join("hartkit/opcua-pki"))
        .unwrap_or_else(|| PathBuf::from("hartkit-opcua-pki"))
}

/// The Modbus settings from the file's `[modbus]` and the options.
fn modbus_config(file: &GatewayFile, opts: &ServeOptions) -> Result<hart_modbus::Config, Failure> {
    let section = file.modbus.clone().unwrap_or_default();
    let map = if section.register.is_empty() {
        RegisterMap::default()
    } else {
        RegisterMap::new(section.register.clone()).map_err(|e| (e, 2))?
    };
    Ok(hart_modbus::Config {
        map,
        float_order: opts.float_order.or(section.float_order).unwrap_or_default(),
        read_only: opts.read_only,
        limits: {
            let d = hart_modbus::connections::Limits::default();
            let priority: Vec<String> = opts
                .modbus_priority
                .iter()
                .chain(&section.priority)
                .cloned()
                .collect();
            hart_modbus::connections::Limits {
                max_connections: section.max_connections.unwrap_or(d.max_connections).max(1),
                max_per_address: section.max_per_address.unwrap_or(d.max_per_address).max(1),
                first_request: section.first_request.unwrap_or(d.first_request),
                request: section.request.unwrap_or(d.request),
                priority: hart_access::NetList::parse(&priority)
                    .map_err(|e| (format!("--modbus-priority / [modbus] priority: {e}"), 2))?,
            }
        },
        write_from: match (opts.modbus_write_from.is_empty(), &section.write_from) {
            (false, _) => hart_access::NetList::parse(&opts.modbus_write_from)
                .map_err(|e| (format!("--modbus-write-from: {e}"), 2))?,
            (true, Some(nets)) => hart_access::NetList::parse(nets)
                .map_err(|e| (format!("--config: [modbus] write_from: {e}"), 2))?,
            (true, None) => hart_access::NetList::loopback(),
        },
        audit: hart_access::Audit::new(opts.audit_file.clone()),
    })
}

/// Sets up the log for a server when the command line has not ([`crate::logging`]).
pub(crate) fn init_log() {
    let _ = crate::logging::init(
        None,
        crate::logging::LogFormat::Text,
        crate::logging::Role::Server,
    );
}

/// Runs `hartkit serve` until interrupted (or `--run-for`).
pub fn run(opts: ServeOptions) -> Result<String, Failure> {
    let file: GatewayFile = match &opts.config {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .map_err(|e| (format!("--config {}: {e}", p.display()), 2))?;
            toml::from_str(&text).map_err(|e| (format!("--config {}: {e}", p.display()), 2))?
        }
        None => GatewayFile::default(),
    };
    if opts.instant && opts.sim.is_none() {
        return Err((
            "--instant answers simulated devices in memory, so it needs --sim [PROFILES...]; \
             a loop given with --port keeps its line timing"
                .into(),
            2,
        ));
    }
    let hart_ip = opts
        .hart_ip
        .clone()
        .or(file.hart_ip.as_ref().map(|h| h.bind.clone()));
    let modbus = opts
        .modbus
        .clone()
        .or(file.modbus.as_ref().and_then(|m| m.bind.clone()));
    let rtu = match (&opts.modbus_rtu, &file.modbus_rtu) {
        (Some(path), section) => Some(hart_modbus::RtuPort {
            path: path.clone(),
            baud: opts
                .modbus_baud
                .or(section.as_ref().and_then(|s| s.baud))
                .unwrap_or(19_200),
            parity: opts
                .modbus_parity
                .or(section.as_ref().and_then(|s| s.parity))
                .unwrap_or('E'),
            stop_bits: section.as_ref().and_then(|s| s.stop_bits).unwrap_or(1),
        }),
        (None, Some(s)) => Some(hart_modbus::RtuPort {
            path: s.port.clone(),
            baud: opts.modbus_baud.or(s.baud).unwrap_or(19_200),
            parity: opts.modbus_parity.or(s.parity).unwrap_or('E'),
            stop_bits: s.stop_bits.unwrap_or(1),
        }),
        (None, None) => None,
    };
    let modbus_cfg = modbus_config(&file, &opts)?;
    let opcua_cfg = opcua_config(&file, &opts)?;
    // Polling serves the image's readers: Modbus, OPC UA, the console view (no front
    // end at all), a printed map; or when the configuration or --poll-period asks.
    let console = hart_ip.is_none() && modbus.is_none() && rtu.is_none() && opcua_cfg.is_none();
    let poll = modbus.is_some()
        || rtu.is_some()
        || opcua_cfg.is_some()
        || console
        || opts.print_map
        || file.poll.is_some()
        || opts.poll_period.is_some();
    let mut defaults = file.poll.clone().unwrap_or_default();
    if let Some(s) = opts.poll_period {
        if !(s > 0.0 && s <= 86_400.0) {
            return Err((
                format!("--poll-period {s}: give seconds, more than 0 and at most 86400"),
                2,
            ));
        }
        defaults.period = Duration::from_secs_f64(s);
    }
    let engine_config = EngineConfig { poll, defaults };

    // The loops: --port targets, --sim, or the file's [[loop]]s.
    enum Source {
        Target(String),
        Sim(hart_host::transport::Plant, bool),
    }
    let mut loops: Vec<(LoopSettings, Source)> = vec![];
    let cli_loop = |name: Option<String>| LoopSettings {
        name,
        scan_to: opts.scan_to,
        ..Default::default()
    };
    if let Some(profiles) = &opts.sim {
        let plant = sim_plant(profiles)?;
        let mut settings = cli_loop(Some("sim".into()));
        // The plant's devices are known: listed first (their unit ids), then the scan.
        settings.device = plant
            .device
            .iter()
            .map(|d| hart_poller::DeviceSettings {
                poll: d.poll,
                name: None,
                period: None,
                read: None,
            })
            .collect();
        loops.push((settings, Source::Sim(plant, opts.instant)));
    }
    for p in &opts.ports {
        loops.push((cli_loop(None), Source::Target(p.clone())));
    }
    for l in &file.loops {
        l.check().map_err(|e| (format!("--config: {e}"), 2))?;
        let Some(port) = l.port.clone() else {
            return Err((
                format!(
                    "--config: loop {} has no port; give port = \"/dev/ttyUSB0\" (any --port \
                     target, or \"sim\")",
                    l.name.as_deref().unwrap_or("(unnamed)")
                ),
                2,
            ));
        };
        loops.push((l.clone(), Source::Target(port)));
    }
    if loops.is_empty() {
        return Err((
            "no loop: give --port TARGET (a HART modem, rs485:..., udp://...), --sim, or \
             [[loop]] sections in --config"
                .into(),
            2,
        ));
    }
    if opts.transparent && loops.len() > 1 {
        return Err((
            "--transparent needs exactly one loop: with several, polling address 0 of each \
             loop is reached by the device's unique ID"
                .into(),
            2,
        ));
    }
    let hart_ip_addr = hart_ip
        .as_deref()
        .map(|b| socket_addr("--hart-ip", b, hart_ip::PORT))
        .transpose()?;
    let modbus_addr = modbus
        .as_deref()
        .map(|b| socket_addr("--modbus", b, 502))
        .transpose()?;
    let plain = opts
        .plain
        .as_deref()
        .map(|p| socket_addr("--plain", p, hart_ip::PORT))
        .transpose()?;
    let psk = opts
        .psk_file
        .as_ref()
        .map(|p| hart_ip_tls::PskTable::load(p).map(std::sync::Arc::new))
        .transpose()
        .map_err(|e| (format!("--psk-file: {e}"), 2))?;
    // Plain sessions are unauthenticated: beside secure ones they only read unless
    // told otherwise.
    let plain_rights = opts
        .plain_rights
        .or(file.hart_ip.as_ref().and_then(|h| h.plain_rights))
        .unwrap_or(if psk.is_some() {
            hart_access::Rights::ReadOnly
        } else {
            hart_access::Rights::ReadWrite
        });
    let device_commands = device_commands(&file, &opts)?;
    if !opts.print_map {
        init_log();
    }
    // Each session of a TCP server is a descriptor.
    hart_host::load::raise_open_file_limit(opts.max_sessions as u64 + 64);

    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| (e.to_string(), 5))?;
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async move {
        let mut specs = vec![];
        let mut queue = hart_poller::LOOP_QUEUE;
        for (settings, source) in loops {
            let line = match source {
                Source::Sim(plant, true) => {
                    queue = 1024;
                    let devices = plant.devices().map_err(|e| (format!("--sim: {e}"), 2))?;
                    Line::Memory(hart_poller::MemoryLoop::new(devices))
                }
                Source::Sim(plant, false) => {
                    let sim = hart_host::transport::SimTransport::new(&plant, false)
                        .map_err(|e| (format!("--sim: {e}"), 2))?;
                    Line::client(hart_host::Client::new(
                        hart_host::target::AnyTransport::Sim(Box::new(sim)),
                    ))
                }
                // Opened again whenever it fails.
                Source::Target(t) => Line::open(&t).await.map_err(|e| (e, 5))?,
            };
            specs.push(LoopSpec { settings, line });
        }
        let (engine, tasks) = Engine::start_with_queue(engine_config, specs, queue);
        if opts.print_map {
            engine.ready().await;
            let gw = hart_modbus::Gateway::new(engine, modbus_cfg);
            for t in tasks {
                t.abort();
            }
            return Ok(if opts.json {
                serde_json::to_string_pretty(&hart_modbus::map_json(&gw))
                    .map_err(|e| (e.to_string(), 5))?
            } else {
                hart_modbus::map_text(&gw).trim_end().to_string()
            });
        }
        let mut out = Vec::<String>::new();
        let mut servers = vec![];
        if let Some(addr) = hart_ip_addr {
            let config = hart_ip_server::Config {
                bind: addr,
                udp: opts.udp || !opts.tcp,
                tcp: opts.tcp || !opts.udp,
                max_sessions: opts.max_sessions,
                max_sessions_per_host: opts.max_sessions_per_host,
                read_only: opts.read_only,
                transparent: opts.transparent,
                scan_to: Some(opts.scan_to),
                psk,
                plain,
                plain_rights,
                device_commands,
                allow_commands: opts.allow_commands.clone(),
                audit_file: opts.audit_file.clone(),
                ..hart_ip_server::Config::default()
            };
            let server = hart_ip_server::start_with_engine(config, engine.clone(), vec![])
                .await
                .map_err(|e| (format!("--hart-ip {}: {e}", hart_ip.unwrap_or_default()), 5))?;
            let show = |a: Option<SocketAddr>| a.map_or("-".to_string(), |a| a.to_string());
            out.push(format!(
                "hart-ip: udp {} tcp {}{}{}",
                show(server.udp_addr),
                show(server.tcp_addr),
                if server.secure {
                    " (DTLS/TLS with pre-shared keys)"
                } else {
                    ""
                },
                if opts.read_only {
                    " (read only)"
                } else if !server.secure && plain_rights == hart_access::Rights::ReadOnly {
                    " (read only: --plain-rights)"
                } else {
                    ""
                }
            ));
            if server.plain_udp_addr.is_some() || server.plain_tcp_addr.is_some() {
                out.push(format!(
                    "hart-ip plain: udp {} tcp {} ({})",
                    show(server.plain_udp_addr),
                    show(server.plain_tcp_addr),
                    if opts.read_only {
                        hart_access::Rights::ReadOnly
                    } else {
                        plain_rights
                    }
                ));
            }
            servers.push(server);
        }
        let gw = hart_modbus::Gateway::new(engine.clone(), modbus_cfg);
        let mut front_tasks = vec![];
        if let Some(addr) = modbus_addr {
            let (bound, serve) = hart_modbus::bind_tcp(gw.clone(), addr)
                .await
                .map_err(|e| (format!("--modbus {addr}: {e}"), 5))?;
            out.push(format!(
                "modbus: tcp {bound} (floats {}){}",
                gw.config().float_order.name(),
                if opts.read_only { " (read only)" } else { "" }
            ));
            front_tasks.push(tokio::spawn(async move {
                if let Err(e) = serve.await {
                    tracing::error!("modbus: the TCP server stopped: {e}");
                }
            }));
        }
        if let Some(port) = rtu {
            out.push(format!(
                "modbus-rtu: {} {} {}{}{}",
                port.path, port.baud, 8, port.parity, port.stop_bits
            ));
            let gw = gw.clone();
            front_tasks.push(tokio::spawn(hart_modbus::serve_rtu_forever(gw, port)));
        }
        let mut opcua_server = None;
        if let Some(cfg) = opcua_cfg {
            let bind = cfg.bind;
            let describe = cfg.describe();
            let server = hart_opcua::start(engine.clone(), cfg)
                .map_err(|e| (format!("--opcua {bind}: {e}"), 5))?;
            out.push(format!("opcua: {} ({describe})", server.url));
            opcua_server = Some(server);
        }
        {
            use std::io::Write as _;
            let mut stdout = std::io::stdout();
            for line in &out {
                let _ = writeln!(stdout, "{line}");
            }
            let _ = stdout.flush();
        }
        if console {
            tokio::task::spawn_local(console_view(engine.clone(), opts.json));
        }
        match opts.run_for {
            Some(s) => tokio::time::sleep(Duration::from_secs_f64(s)).await,
            None => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
        for t in front_tasks {
            t.abort();
        }
        if let Some(s) = opcua_server {
            s.stop();
        }
        for s in servers {
            s.stop();
        }
        for t in tasks {
            t.abort();
        }
        Ok(String::new())
    })
}

/// With no front end, `hartkit serve` shows the image: every few seconds a table
/// (or, with `--json`, one JSON line per device, with its poll and failure counts).
async fn console_view(engine: Engine, json: bool) {
    use std::io::Write as _;
    let mut tick = tokio::time::interval(Duration::from_secs(5));
    loop {
        tick.tick().await;
        let now = std::time::Instant::now();
        let mut out = std::io::stdout();
        let image = engine.image().snapshot();
        // A loop whose port is down says so first.
        for channel in 0..engine.loop_count() {
            if let Some(why) = engine.loop_failure(channel) {
                let name = engine.loop_name(channel).unwrap_or("?");
                let _ = if json {
                    writeln!(
                        out,
                        "{}",
                        serde_json::json!({"loop": name, "port_failed": why})
                    )
                } else {
                    writeln!(
                        out,
                        "loop {name}: the port is down ({why}); opening it again"
                    )
                };
            }
        }
        if !json {
            let _ = writeln!(
                out,
                "{:>4}  {:<24} {:>12} {:<8} {:>9}  quality",
                "unit", "device", "PV", "units", "current"
            );
        }
        for d in &image {
            let pv = d.variables[0];
            let units = pv
                .and_then(|v| hart_proto::tables::unit_symbol(v.units))
                .unwrap_or("");
            if json {
                let line = serde_json::json!({
                    "unit": d.position + 1,
                    "loop": d.loop_name,
                    "name": d.display_name(),
                    "pv": pv.map(|v| v.value),
                    "pv_units": units,
                    "loop_current": d.loop_current,
                    "device_status": d.device_status,
                    "quality": d.quality(now).name(),
                    "polls": d.polls,
                    "failures": d.failures,
                });
                let _ = writeln!(out, "{line}");
            } else {
                let _ = writeln!(
                    out,
                    "{:>4}  {:<24} {:>12} {:<8} {:>9}  {}",
                    d.position + 1,
                    d.display_name(),
                    pv.map_or("-".to_string(), |v| format!("{:.3}", v.value)),
                    units,
                    d.loop_current
                        .map_or("-".to_string(), |c| format!("{c:.3} mA")),
                    d.quality(now)
                );
            }
        }
        let _ = out.flush();
    }
}

/// What `hartkit opcua trust` does.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TrustAction {
    /// `FILE`: a certificate file, or a rejected one by file name or thumbprint.
    File(String),
    /// `--all`: every rejected certificate.
    All,
    /// `--list`: show the rejected and trusted certificates.
    List,
}

/// `hartkit opcua trust [--opcua-pki DIR] [FILE | --all | --list]`: moves client
/// certificates into the gateway's trust list, or lists it; `pki` defaults to
/// [`default_pki_dir`].
pub fn opcua_trust(pki: Option<PathBuf>, action: TrustAction) -> Result<String, Failure> {
    let pki = pki.unwrap_or_else(default_pki_dir);
    let show = |c: &hart_opcua::trust::CertInfo| {
        format!(
            "{}  {}{}",
            c.thumbprint,
            c.subject,
            c.not_after
                .as_ref()
                .map_or(String::new(), |t| format!("  (valid until {t})"))
        )
    };
    let what = match action {
        TrustAction::List => {
            let l = hart_opcua::trust::list(&pki).map_err(|e| (e, 5))?;
            let mut out = vec![];
            for (name, dir, certs) in [
                ("rejected", &l.rejected_dir, &l.rejected),
                ("trusted", &l.trusted_dir, &l.trusted),
            ] {
                out.push(format!("{name} ({}):", dir.display()));
                if certs.is_empty() {
                    out.push("  none".into());
                }
                for c in certs {
                    out.push(format!("  {}", show(c)));
                    out.push(format!(
                        "      {}",
                        c.path.file_name().unwrap_or_default().to_string_lossy()
                    ));
                }
            }
            for (f, e) in &l.unreadable {
                out.push(format!("not a certificate: {} ({e})", f.display()));
            }
            return Ok(out.join("\n"));
        }
        TrustAction::All => hart_opcua::trust::Trust::AllRejected,
        TrustAction::File(f) => hart_opcua::trust::Trust::File(f),
    };
    let done = hart_opcua::trust::trust(&pki, &what).map_err(|e| (e, 2))?;
    Ok(done
        .iter()
        .map(|c| format!("trusted {} -> {}", show(c), c.path.display()))
        .collect::<Vec<_>>()
        .join("\n"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The complete example of docs/gateway.md is a configuration the gateway reads.
    #[test]
    fn the_documented_example_reads() {
        let doc = include_str!("../../../docs/gateway.md");
        let start = doc
            .find("```toml\n# Poll defaults")
            .expect("the example in docs/gateway.md");
        let body = &doc[start + "```toml\n".len()..];
        let example = &body[..body.find("```").unwrap()];
        let file: GatewayFile = toml::from_str(example).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.loops.len(), 2);
        assert_eq!(
            file.hart_ip.unwrap().plain_rights,
            Some(hart_access::Rights::ReadOnly)
        );
        let commands = hart_access::DeviceCommands::from_entries(&file.device_commands).unwrap();
        assert!(commands.reads(0x26F3, 128) && !commands.reads(0x26F3, 129));
        let nets = file.modbus.unwrap().write_from.unwrap();
        assert!(hart_access::NetList::parse(&nets)
            .unwrap()
            .contains("10.0.0.9".parse().unwrap()));
    }
}
