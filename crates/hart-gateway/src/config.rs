//! One value that says the whole gateway: its loops, the engine's settings and every
//! front end's, resolved from the configuration file and the options.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use hart_modbus::map::RegisterMap;
use hart_poller::{EngineConfig, LoopSettings};

use crate::file::GatewayFile;
use crate::options::ServeOptions;
use crate::Error;

/// Where a loop's line comes from.
#[derive(Debug, Clone)]
pub enum LoopSource {
    /// A `--port` target: a HART modem's serial port, `rs485:...`, `udp://...`,
    /// `tcp://...`, `sim`; opened again whenever it fails.
    Target(String),
    /// A simulated plant: with `instant`, its devices answer in memory without the
    /// line's timing.
    Sim {
        /// The plant.
        plant: hart_host::transport::Plant,
        /// Answer in memory.
        instant: bool,
    },
}

/// One loop of the gateway.
#[derive(Debug, Clone)]
pub struct LoopConfig {
    /// Name, listed devices, scan.
    pub settings: LoopSettings,
    /// Its line.
    pub source: LoopSource,
}

/// The terminal view shown when no front end is asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConsoleConfig {
    /// One JSON line per device instead of a table.
    pub json: bool,
    /// How often the view is printed.
    pub every: Duration,
}

/// The whole gateway: what [`crate::Gateway::start`] runs.
#[derive(Clone)]
pub struct GatewayConfig {
    /// The polling engine's settings.
    pub engine: EngineConfig,
    /// The loops, in channel order.
    pub loops: Vec<LoopConfig>,
    /// The HART-IP server, if any.
    pub hart_ip: Option<hart_ip_server::Config>,
    /// The Modbus TCP server's address, if any.
    pub modbus_tcp: Option<SocketAddr>,
    /// The Modbus register map and rules (TCP and RTU).
    pub modbus: hart_modbus::Config,
    /// The Modbus RTU slave's port, if any.
    pub modbus_rtu: Option<hart_modbus::RtuPort>,
    /// The PROFIBUS DP slave's port and station, if any (an empty path: `--profibus`
    /// without a port, which only `--print-map` takes).
    pub profibus: Option<hart_profibus::serve::ProfibusPort>,
    /// The OPC UA server, if any.
    pub opcua: Option<hart_opcua::Config>,
    /// The historian, if any.
    pub history: Option<hart_history::HistoryConfig>,
    /// The MQTT Sparkplug B publisher, if any.
    pub mqtt: Option<hart_sparkplug_edge::MqttConfig>,
    /// The web dashboard, if any.
    pub web: Option<hart_web::WebConfig>,
    /// The console view, when no front end is asked for.
    pub console: Option<ConsoleConfig>,
    /// Only these HART commands may be sent by clients (`--allow-commands`).
    pub allow_commands: Option<hart_access::CommandAllowList>,
    /// Device-specific commands declared reads (`--device-commands`,
    /// `[[device_commands]]`): frames clients compose that carry them pass the
    /// engine's gate as reads.
    pub device_commands: hart_access::DeviceCommands,
    /// Where every write let through is recorded (`--audit-file`).
    pub audit_file: Option<PathBuf>,
    /// Everything is read only: HART-IP refuses changes, Modbus writes, OPC UA method
    /// calls.
    pub read_only: bool,
}

/// `ADDR[:PORT]` (`port` when none) as a socket address; `what` names the option.
pub fn socket_addr(what: &str, text: &str, port: u16) -> Result<SocketAddr, Error> {
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
        .ok_or_else(|| Error::config(format!("{what} {text}: not an address")))
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

impl GatewayConfig {
    /// The gateway that `opts` ask for: the configuration file they name (if any) with
    /// the options added to and over it.
    pub fn from_options(opts: &ServeOptions) -> Result<GatewayConfig, Error> {
        let file = match &opts.config {
            Some(p) => GatewayFile::load(p)?,
            None => GatewayFile::default(),
        };
        Self::from_file(&file, opts)
    }

    /// The gateway of configuration `file` with the options `opts` over it.
    pub fn from_file(file: &GatewayFile, opts: &ServeOptions) -> Result<GatewayConfig, Error> {
        if opts.instant && opts.sim.is_none() {
            return Err(Error::config(
                "--instant answers simulated devices in memory, so it needs --sim \
                 [PROFILES...]; a loop given with --port keeps its line timing",
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
        let modbus_rtu = rtu_port(file, opts);
        let profibus = profibus_port(file, opts)?;
        let modbus_cfg = modbus_config(file, opts)?;
        let opcua = opcua_config(file, opts)?;
        let mqtt = mqtt_config(file, opts)?;
        let mut web = web_config(file, opts)?;
        let history = match (&opts.history, &file.history) {
            (Some(db), Some(section)) => Some(hart_history::HistoryConfig {
                db: db.clone(),
                ..section.clone()
            }),
            (Some(db), None) => Some(hart_history::HistoryConfig::with_db(db.clone())),
            (None, section) => section.clone(),
        };
        if let Some(h) = &history {
            h.validate()
                .map_err(|e| Error::config(format!("--history: {e}")))?;
        }
        // Polling serves the image's readers: Modbus, OPC UA, MQTT, the console view
        // (no front end at all); or when the configuration or --poll-period asks.
        let console = hart_ip.is_none()
            && modbus.is_none()
            && modbus_rtu.is_none()
            && profibus.is_none()
            && opcua.is_none()
            && mqtt.is_none()
            && web.is_none()
            && history.is_none();
        let poll = modbus.is_some()
            || modbus_rtu.is_some()
            || profibus.is_some()
            || opcua.is_some()
            || mqtt.is_some()
            || web.is_some()
            || history.is_some()
            || console
            || file.poll.is_some()
            || opts.poll_period.is_some();
        let mut defaults = file.poll.clone().unwrap_or_default();
        if let Some(s) = opts.poll_period {
            if !(s > 0.0 && s <= 86_400.0) {
                return Err(Error::config(format!(
                    "--poll-period {s}: give seconds, more than 0 and at most 86400"
                )));
            }
            defaults.period = Duration::from_secs_f64(s);
        }
        let loops = loops(file, opts)?;
        if opts.transparent && loops.len() > 1 {
            return Err(Error::config(
                "--transparent needs exactly one loop: with several, polling address 0 of \
                 each loop is reached by the device's unique ID",
            ));
        }
        // Checked whichever front ends run: a mistake in the file is said at once.
        let device_commands = device_commands(file, opts)?;
        let hart_ip = match hart_ip {
            Some(bind) => Some(hart_ip_config(file, opts, &bind, device_commands.clone())?),
            None => None,
        };
        let modbus_tcp = modbus
            .as_deref()
            .map(|b| socket_addr("--modbus", b, 502))
            .transpose()?;
        // The dashboard's trends read the historian's database, through the handle the
        // gateway's other readers share (the MQTT publisher's backfill).
        if let (Some(w), Some(h)) = (web.as_mut(), history.as_ref()) {
            w.history = Some(hart_history::Readers::new(
                h.db.clone(),
                hart_history::DEFAULT_READERS,
            ));
        }
        Ok(GatewayConfig {
            engine: EngineConfig {
                poll,
                defaults,
                loop_test_limit: loop_test_limit(file, opts)?,
            },
            loops,
            hart_ip,
            modbus_tcp,
            modbus: modbus_cfg,
            modbus_rtu,
            profibus,
            opcua,
            mqtt,
            web,
            history,
            allow_commands: opts.allow_commands.clone(),
            audit_file: opts.audit_file.clone(),
            device_commands,
            console: console.then_some(ConsoleConfig {
                json: opts.json,
                every: Duration::from_secs(5),
            }),
            read_only: opts.read_only,
        })
    }

    /// Whether the gateway answers in memory only (`--sim --instant`): its loops cost
    /// no line time.
    pub fn in_memory(&self) -> bool {
        self.loops
            .iter()
            .any(|l| matches!(l.source, LoopSource::Sim { instant: true, .. }))
    }
}

/// The loops: --sim, --port targets, then the file's [[loop]]s.
/// The loop test limit: `--loop-test-limit` seconds, or the file's `loop_test_limit`.
fn loop_test_limit(file: &GatewayFile, opts: &ServeOptions) -> Result<Option<Duration>, Error> {
    match opts.loop_test_limit {
        Some(s) => Duration::try_from_secs_f64(s)
            .ok()
            .filter(|d| *d >= Duration::from_secs(1))
            .map(Some)
            .ok_or_else(|| {
                Error::config(format!(
                    "--loop-test-limit {s}: give a number of seconds, at least 1 (600 is 10 minutes)"
                ))
            }),
        None => match file.loop_test_limit {
            Some(d) if d < Duration::from_secs(1) => Err(Error::config(
                "loop_test_limit: give at least \"1s\" (the default is \"10m\")",
            )),
            d => Ok(d),
        },
    }
}

fn loops(file: &GatewayFile, opts: &ServeOptions) -> Result<Vec<LoopConfig>, Error> {
    let mut loops = vec![];
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
        loops.push(LoopConfig {
            settings,
            source: LoopSource::Sim {
                plant,
                instant: opts.instant,
            },
        });
    }
    for p in &opts.ports {
        loops.push(LoopConfig {
            settings: cli_loop(None),
            source: LoopSource::Target(p.clone()),
        });
    }
    for l in &file.loops {
        l.check()
            .map_err(|e| Error::config(format!("--config: {e}")))?;
        let Some(port) = l.port.clone() else {
            return Err(Error::config(format!(
                "--config: loop {} has no port; give port = \"/dev/ttyUSB0\" (any --port \
                 target, or \"sim\")",
                l.name.as_deref().unwrap_or("(unnamed)")
            )));
        };
        loops.push(LoopConfig {
            settings: l.clone(),
            source: LoopSource::Target(port),
        });
    }
    if loops.is_empty() {
        return Err(Error::config(
            "no loop: give --port TARGET (a HART modem, rs485:..., udp://...), --sim, or \
             [[loop]] sections in --config",
        ));
    }
    Ok(loops)
}

/// The plant behind `--sim [PROFILES...]`: the profiles at polling addresses 1, 2, ...,
/// or the demo plant when none are given.
fn sim_plant(profiles: &[String]) -> Result<hart_host::transport::Plant, Error> {
    use hart_host::transport::Plant;
    if profiles.is_empty() {
        Ok(Plant::demo())
    } else {
        Plant::from_profiles(profiles).map_err(|e| Error::config(format!("--sim: {e}")))
    }
}

/// The HART-IP server bound to `bind`.
fn hart_ip_config(
    file: &GatewayFile,
    opts: &ServeOptions,
    bind: &str,
    device_commands: hart_access::DeviceCommands,
) -> Result<hart_ip_server::Config, Error> {
    let addr = socket_addr("--hart-ip", bind, hart_ip::PORT)?;
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
        .map_err(|e| Error::config(format!("--psk-file: {e}")))?;
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
    let max_timer_ms = match opts
        .max_inactivity
        .or(file
            .hart_ip
            .as_ref()
            .and_then(|h| h.max_inactivity.map(|d| d.as_secs_f64())))
    {
        None => hart_ip_server::DEFAULT_MAX_TIMER_MS,
        Some(s) if s.is_finite() && (1.0..=4_294_967.0).contains(&s) => (s * 1000.0).round() as u32,
        Some(s) => {
            return Err(Error::config(format!(
                "--max-inactivity / [hart_ip] max_inactivity: {s} s is not a time from 1 s to 4294967 s (the inactivity timer is a 32-bit count of milliseconds)"
            )))
        }
    };
    Ok(hart_ip_server::Config {
        bind: addr,
        max_timer_ms,
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
    })
}

/// The Modbus RTU port from `--modbus-rtu` and `[modbus_rtu]`.
fn rtu_port(file: &GatewayFile, opts: &ServeOptions) -> Option<hart_modbus::RtuPort> {
    let section = file.modbus_rtu.as_ref();
    let path = opts
        .modbus_rtu
        .clone()
        .or(section.map(|s| s.port.clone()))?;
    Some(hart_modbus::RtuPort {
        path,
        baud: opts
            .modbus_baud
            .or(section.and_then(|s| s.baud))
            .unwrap_or(19_200),
        parity: opts
            .modbus_parity
            .or(section.and_then(|s| s.parity))
            .unwrap_or('E'),
        stop_bits: section.and_then(|s| s.stop_bits).unwrap_or(1),
    })
}

/// The PROFIBUS DP port and station from `--profibus` and `[profibus]`.
fn profibus_port(
    file: &GatewayFile,
    opts: &ServeOptions,
) -> Result<Option<hart_profibus::serve::ProfibusPort>, Error> {
    let section = file.profibus.as_ref();
    let path = match (&opts.profibus, section) {
        (Some(p), Some(s)) if p.is_empty() => s.port.clone(),
        (Some(p), _) => p.clone(),
        (None, Some(s)) => s.port.clone(),
        (None, None) => {
            if opts.profibus_address.is_some() || opts.profibus_baud.is_some() {
                return Err(Error::config(
                    "--profibus-address and --profibus-baud set up --profibus PORT: give the port too",
                ));
            }
            return Ok(None);
        }
    };
    let port = hart_profibus::serve::ProfibusPort {
        path,
        address: opts
            .profibus_address
            .or(section.and_then(|s| s.address))
            .unwrap_or(5),
        baud: opts
            .profibus_baud
            .or(section.and_then(|s| s.baud))
            .unwrap_or(19_200),
        ident_number: section
            .and_then(|s| s.ident_number)
            .unwrap_or(hart_profibus::serve::DEFAULT_IDENT_NUMBER),
    };
    // The number of devices is known only once the loops are up; one station's worth
    // is checked here, all of them when the front end starts.
    port.check(1).map_err(Error::config)?;
    Ok(Some(port))
}

/// The OPC UA settings from the file's `[opcua]` and the options; `None`: no OPC UA.
fn opcua_config(
    file: &GatewayFile,
    opts: &ServeOptions,
) -> Result<Option<hart_opcua::Config>, Error> {
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
            return Err(Error::config(format!(
                "--opcua-user {u:?}: give NAME:PASSWORD (both non-empty)"
            )));
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
            return Err(Error::config(format!(
                "{from} with users (--opcua-user or [opcua] users): a password over \
                 SecurityPolicy None travels in clear; give --opcua-security \
                 basic256sha256 (users only, signed and encrypted) or both (anonymous \
                 read-only on None, users on Basic256Sha256)"
            )))
        }
        Some("none") => hart_opcua::Security::None,
        Some("basic256sha256") => hart_opcua::Security::Basic256Sha256,
        Some("both") => hart_opcua::Security::Both,
        Some(_) => {
            return Err(Error::config(format!(
                "{from}: give none, basic256sha256 or both"
            )))
        }
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
        limits: {
            let d = hart_opcua::connections::Limits::default();
            let max_message_size = section.max_message_size.unwrap_or(d.max_message_size);
            hart_opcua::connections::Limits {
                max_connections: section.max_connections.unwrap_or(d.max_connections),
                max_per_address: section.max_per_address.unwrap_or(d.max_per_address),
                priority: hart_access::NetList::parse(&section.priority)
                    .map_err(|e| Error::config(format!("[opcua] priority: {e}")))?,
                handshake: section.handshake_timeout.unwrap_or(d.handshake),
                max_sessions: section.max_sessions.unwrap_or(d.max_sessions),
                session_timeout: section.session_timeout.unwrap_or(d.session_timeout),
                max_message_size,
                max_chunk_count: hart_opcua::connections::chunks_for(max_message_size),
            }
        },
    };
    config
        .check()
        .map_err(|e| Error::config(format!("--opcua / [opcua]: {e}")))?;
    Ok(Some(config))
}

/// The MQTT settings from the file's `[mqtt]` and the options; `None`: no MQTT.
fn mqtt_config(
    file: &GatewayFile,
    opts: &ServeOptions,
) -> Result<Option<hart_sparkplug_edge::MqttConfig>, Error> {
    let mut config = match (&opts.mqtt, &file.mqtt) {
        (Some(url), Some(section)) => hart_sparkplug_edge::MqttConfig {
            url: url.clone(),
            ..section.clone()
        },
        (Some(url), None) => hart_sparkplug_edge::MqttConfig::new(
            url,
            hart_sparkplug_edge::DEFAULT_GROUP,
            &hart_sparkplug_edge::default_edge_node(),
        ),
        (None, Some(section)) => section.clone(),
        (None, None) => {
            if opts.mqtt_group.is_some()
                || opts.mqtt_edge_node.is_some()
                || opts.mqtt_primary_host.is_some()
                || opts.mqtt_qos.is_some()
            {
                return Err(Error::config(
                    "--group, --edge-node, --primary-host and --mqtt-qos are settings of the MQTT \
                     publisher: give --mqtt mqtt://HOST[:PORT] (or [mqtt] url in --config)",
                ));
            }
            return Ok(None);
        }
    };
    if let Some(g) = &opts.mqtt_group {
        config.group = g.clone();
    }
    if let Some(e) = &opts.mqtt_edge_node {
        config.edge_node = e.clone();
    }
    if let Some(h) = &opts.mqtt_primary_host {
        config.primary_host = Some(h.clone());
    }
    if let Some(q) = opts.mqtt_qos {
        config.data_qos = q;
    }
    config.read_only |= opts.read_only;
    config.check().map_err(|e| Error::config(e.to_string()))?;
    Ok(Some(config))
}

/// The device-specific commands declared reads: `--device-commands FILE` and the
/// configuration's `[[device_commands]]`.
fn device_commands(
    file: &GatewayFile,
    opts: &ServeOptions,
) -> Result<hart_access::DeviceCommands, Error> {
    let from_config = hart_access::DeviceCommands::from_entries(&file.device_commands)
        .map_err(|e| Error::config(format!("--config: device_commands: {e}")))?;
    let from_file = match &opts.device_commands {
        Some(p) => hart_access::DeviceCommands::load(p).map_err(Error::config)?,
        None => hart_access::DeviceCommands::default(),
    };
    Ok(from_config.merge(from_file))
}

/// The Modbus settings from the file's `[modbus]` and the options.
fn modbus_config(file: &GatewayFile, opts: &ServeOptions) -> Result<hart_modbus::Config, Error> {
    let section = file.modbus.clone().unwrap_or_default();
    let map = if section.register.is_empty() {
        RegisterMap::default()
    } else {
        RegisterMap::new(section.register.clone()).map_err(Error::config)?
    };
    let d = hart_modbus::connections::Limits::default();
    let priority: Vec<String> = opts
        .modbus_priority
        .iter()
        .chain(&section.priority)
        .cloned()
        .collect();
    Ok(hart_modbus::Config {
        map,
        float_order: opts.float_order.or(section.float_order).unwrap_or_default(),
        limits: hart_modbus::connections::Limits {
            max_connections: section.max_connections.unwrap_or(d.max_connections).max(1),
            max_per_address: section.max_per_address.unwrap_or(d.max_per_address).max(1),
            first_request: section.first_request.unwrap_or(d.first_request),
            request: section.request.unwrap_or(d.request),
            priority: hart_access::NetList::parse(&priority).map_err(|e| {
                Error::config(format!("--modbus-priority / [modbus] priority: {e}"))
            })?,
        },
        write_from: match (opts.modbus_write_from.is_empty(), &section.write_from) {
            (false, _) => hart_access::NetList::parse(&opts.modbus_write_from)
                .map_err(|e| Error::config(format!("--modbus-write-from: {e}")))?,
            (true, Some(nets)) => hart_access::NetList::parse(nets)
                .map_err(|e| Error::config(format!("--config: [modbus] write_from: {e}")))?,
            (true, None) => hart_access::NetList::loopback(),
        },
    })
}

/// The web dashboard from `--web*` and `[web]`; `None`: no dashboard. A port alone
/// (`--web 8080`) listens on 127.0.0.1: the dashboard is reached from elsewhere only
/// when an address says so.
fn web_config(
    file: &GatewayFile,
    opts: &ServeOptions,
) -> Result<Option<hart_web::WebConfig>, Error> {
    let section = file.web.clone().unwrap_or_default();
    let Some(bind) = opts.web.clone().or(section.bind.clone()) else {
        if opts.web_admin_password_file.is_some()
            || opts.web_cert.is_some()
            || opts.web_key.is_some()
            || !opts.web_hosts.is_empty()
        {
            return Err(Error::config(
                "--web-admin-password-file, --web-cert, --web-key and --web-host go with \
                 --web ADDR[:PORT]",
            ));
        }
        return Ok(None);
    };
    let bind = match bind.trim().parse::<u16>() {
        Ok(port) => SocketAddr::from(([127, 0, 0, 1], port)),
        Err(_) => socket_addr("--web", &bind, hart_web::DEFAULT_PORT)?,
    };
    let mut web = hart_web::WebConfig::new(bind);
    web.admin_password_file = opts
        .web_admin_password_file
        .clone()
        .or(section.admin_password_file);
    if let Some(w) = section.memory_window {
        if w < Duration::from_secs(60) || w > Duration::from_secs(7 * 86_400) {
            return Err(Error::config(
                "[web] memory_window: give 1m to 7d (each device keeps at most 3600 points)",
            ));
        }
        web.memory_window = w;
    }
    web.hosts = section
        .hosts
        .iter()
        .map(|h| (h, "[web] hosts"))
        .chain(opts.web_hosts.iter().map(|h| (h, "--web-host")))
        .map(|(h, from)| {
            h.parse::<hart_web::hosts::HostName>()
                .map_err(|e| Error::config(format!("{from}: {e}")))
        })
        .collect::<Result<_, _>>()?;
    let d = hart_web::limits::Limits::default();
    web.limits = hart_web::limits::Limits {
        max_connections: section.max_connections.unwrap_or(d.max_connections).max(1),
        max_per_address: section.max_per_address.unwrap_or(d.max_per_address).max(1),
        priority: hart_access::NetList::parse(&section.priority)
            .map_err(|e| Error::config(format!("[web] priority: {e}")))?,
        header_timeout: section.header_timeout.unwrap_or(d.header_timeout),
        idle_timeout: section.idle_timeout.unwrap_or(d.idle_timeout),
    };
    for (name, t) in [
        ("header_timeout", web.limits.header_timeout),
        ("idle_timeout", web.limits.idle_timeout),
    ] {
        if t < Duration::from_millis(100) || t > Duration::from_secs(3600) {
            return Err(Error::config(format!("[web] {name}: give 100ms to 1h")));
        }
    }
    // The HART-IP server's identities with write rights may log in with their keys.
    if let Some(p) = &opts.psk_file {
        let table = hart_ip_tls::PskTable::load(p)
            .map_err(|e| Error::config(format!("--psk-file: {e}")))?;
        web.psk_logins = table
            .keys
            .iter()
            .filter(|k| k.rights.may_write())
            .map(|k| hart_web::PskLogin {
                identity: k.identity.clone(),
                key: k.key.clone(),
            })
            .collect();
    }
    web.tls =
        match (
            opts.web_cert.clone().or(section.cert),
            opts.web_key.clone().or(section.key),
        ) {
            (Some(cert), Some(key)) => Some(hart_web::TlsFiles { cert, key }),
            (None, None) => None,
            _ => return Err(Error::config(
                "HTTPS needs both --web-cert FILE and --web-key FILE (or cert and key in [web])",
            )),
        };
    Ok(Some(web))
}
