//! # hart-gateway
//!
//! hartkit's gateway, assembled from one value. A [`GatewayConfig`] says the whole
//! gateway: the loops (serial modems, RS-485 lines, HART-IP servers upstream, simulated
//! plants), the polling engine's settings, and the front ends on the engine (HART-IP,
//! Modbus TCP and RTU, OPC UA, MQTT Sparkplug B, the console view). [`Gateway::start`] starts them all
//! and [`Gateway::stop`] stops them; `hartkit serve` only turns its options into the
//! value ([`GatewayConfig::from_options`]), so a test, the Python package or another
//! program starts a whole gateway the same way.
//!
//! ```no_run
//! # async fn f() -> Result<(), hart_gateway::Error> {
//! use hart_gateway::{Gateway, GatewayConfig, ServeOptions};
//! let config = GatewayConfig::from_options(&ServeOptions {
//!     sim: Some(vec![]),
//!     modbus: Some("127.0.0.1:1502".into()),
//!     ..ServeOptions::default()
//! })?;
//! // Inside a tokio LocalSet: the loops' tasks stay on one thread.
//! let gateway = Gateway::start(config).await?;
//! println!("{}", gateway.started().join("\n"));
//! gateway.stop().await;
//! # Ok(()) }
//! ```

use std::net::SocketAddr;
use std::time::Duration;

use hart_poller::{Engine, Line, LoopSpec, StartOptions};

pub mod backfill;
pub mod config;
pub mod console;
mod error;
pub mod file;
pub mod options;

pub use config::{socket_addr, ConsoleConfig, GatewayConfig, LoopConfig, LoopSource};
pub use error::{Error, ErrorKind};
pub use file::GatewayFile;
pub use options::ServeOptions;

/// A running gateway: its engine, the front ends, and the lines that say where each
/// one listens.
pub struct Gateway {
    engine: Engine,
    started: Vec<String>,
    loop_tasks: Vec<tokio::task::JoinHandle<()>>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
    hart_ip: Vec<hart_ip_server::Server>,
    opcua: Option<hart_opcua::OpcUaServer>,
    mqtt: Option<hart_sparkplug_edge::Handle>,
    history: Option<hart_recorder::Handle>,
    web: Option<hart_web::WebServer>,
    modbus_tcp: Option<SocketAddr>,
    /// The runtime of the serial front ends with reply deadlines, when one runs.
    deadlines: Option<DeadlineRuntime>,
}

/// A thread with a runtime of its own for the front ends that must answer within a
/// deadline on a serial line (a PROFIBUS DP slave within its max TSDR of about 10 ms, a
/// Modbus RTU slave within its master's time-out): nothing of the main runtime (a TLS
/// handshake, an HTTP request, an audit line written to disk, the historian's feed)
/// runs between a request and its answer.
struct DeadlineRuntime {
    handle: tokio::runtime::Handle,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl DeadlineRuntime {
    fn start() -> Result<DeadlineRuntime, Error> {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| Error::io(format!("the serial front ends' runtime: {e}")))?;
        let handle = rt.handle().clone();
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("hart-deadlines".into())
            .spawn(move || {
                rt.block_on(async {
                    let _ = stopped.await;
                });
                // Its tasks were aborted by the gateway's stop: a serial read still
                // blocked on a thread is left to end by itself.
                rt.shutdown_timeout(std::time::Duration::from_secs(1));
            })
            .map_err(|e| Error::io(format!("the serial front ends' thread: {e}")))?;
        Ok(DeadlineRuntime {
            handle,
            stop: Some(stop),
            thread: Some(thread),
        })
    }
}

impl Drop for DeadlineRuntime {
    fn drop(&mut self) {
        // Not joined: the gateway may be dropped on an async thread, which must not
        // block; the thread ends within a second.
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        drop(self.thread.take());
    }
}

/// Opens the loops' lines and starts the engine on them (inside a `LocalSet`).
async fn start_engine(
    config: &GatewayConfig,
) -> Result<(Engine, Vec<tokio::task::JoinHandle<()>>), Error> {
    let mut specs = vec![];
    let mut queue = hart_poller::LOOP_QUEUE;
    for l in &config.loops {
        let line = match &l.source {
            LoopSource::Sim {
                plant,
                instant: true,
            } => {
                queue = 1024;
                let devices = plant
                    .devices()
                    .map_err(|e| Error::config(format!("--sim: {e}")))?;
                Line::Memory(hart_poller::MemoryLoop::new(devices))
            }
            LoopSource::Sim {
                plant,
                instant: false,
            } => {
                let sim = hart_host::transport::SimTransport::new(plant, false)
                    .map_err(|e| Error::config(format!("--sim: {e}")))?;
                Line::client(hart_host::Client::new(
                    hart_host::target::AnyTransport::Sim(Box::new(sim)),
                ))
            }
            // Opened again whenever it fails.
            LoopSource::Target(t) => Line::open(t).await.map_err(Error::io)?,
        };
        specs.push(LoopSpec {
            settings: l.settings.clone(),
            line,
        });
    }
    Ok(Engine::start_with(
        config.engine.clone(),
        specs,
        StartOptions {
            queue,
            write_policy: hart_access::WritePolicy {
                read_only: config.read_only,
                allow: config.allow_commands.clone(),
                device_commands: config.device_commands.clone(),
                audit: hart_access::Audit::new(config.audit_file.clone()),
            },
            ..StartOptions::default()
        },
    ))
}

impl Gateway {
    /// Opens the loops, starts the engine and every front end of `config`. Call it
    /// inside a `tokio::task::LocalSet` (the loops' tasks stay on one thread).
    pub async fn start(config: GatewayConfig) -> Result<Gateway, Error> {
        if let Some(h) = &config.hart_ip {
            // Each session of a TCP server is a descriptor.
            hart_host::load::raise_open_file_limit(h.max_sessions as u64 + 64);
        }
        let (engine, loop_tasks) = start_engine(&config).await?;
        let mut gw = Gateway {
            engine: engine.clone(),
            started: vec![],
            loop_tasks,
            tasks: vec![],
            hart_ip: vec![],
            opcua: None,
            mqtt: None,
            history: None,
            web: None,
            modbus_tcp: None,
            deadlines: None,
        };
        // A front end that cannot start stops what has started.
        if let Err(e) = gw.start_front_ends(config).await {
            gw.stop().await;
            return Err(e);
        }
        Ok(gw)
    }

    async fn start_front_ends(&mut self, config: GatewayConfig) -> Result<(), Error> {
        let engine = self.engine.clone();
        let read_only = config.read_only;
        if let Some(h) = config.hart_ip {
            let bind = h.bind;
            let plain_rights = h.plain_rights;
            let server = hart_ip_server::start_with_engine(h, engine.clone(), vec![])
                .await
                .map_err(|e| Error::io(format!("--hart-ip {bind}: {e}")))?;
            let show = |a: Option<SocketAddr>| a.map_or("-".to_string(), |a| a.to_string());
            self.started.push(format!(
                "hart-ip: udp {} tcp {}{}{}",
                show(server.udp_addr),
                show(server.tcp_addr),
                if server.secure {
                    " (DTLS/TLS with pre-shared keys)"
                } else {
                    ""
                },
                if read_only {
                    " (read only)"
                } else if !server.secure && plain_rights == hart_access::Rights::ReadOnly {
                    " (read only: --plain-rights)"
                } else {
                    ""
                }
            ));
            if server.plain_udp_addr.is_some() || server.plain_tcp_addr.is_some() {
                self.started.push(format!(
                    "hart-ip plain: udp {} tcp {} ({})",
                    show(server.plain_udp_addr),
                    show(server.plain_tcp_addr),
                    if read_only {
                        hart_access::Rights::ReadOnly
                    } else {
                        plain_rights
                    }
                ));
            }
            self.hart_ip.push(server);
        }
        let modbus = hart_modbus::Gateway::new(engine.clone(), config.modbus);
        if let Some(addr) = config.modbus_tcp {
            let (bound, serve) = hart_modbus::bind_tcp(modbus.clone(), addr)
                .await
                .map_err(|e| Error::io(format!("--modbus {addr}: {e}")))?;
            self.modbus_tcp = Some(bound);
            self.started.push(format!(
                "modbus: tcp {bound} (floats {}){}",
                modbus.config().float_order.name(),
                if read_only { " (read only)" } else { "" }
            ));
            self.tasks.push(tokio::spawn(async move {
                if let Err(e) = serve.await {
                    tracing::error!("modbus: the TCP server stopped: {e}");
                }
            }));
        }
        if let Some(port) = config.modbus_rtu {
            self.started.push(format!(
                "modbus-rtu: {} {} {}{}{}",
                port.path, port.baud, 8, port.parity, port.stop_bits
            ));
            let rt = self.deadline_runtime()?;
            self.tasks
                .push(rt.spawn(hart_modbus::serve_rtu_forever(modbus, port)));
        }
        if let Some(port) = config.profibus {
            if port.path.is_empty() {
                return Err(Error::config(
                    "--profibus needs a serial port (--profibus /dev/ttyUSB0, or a pseudo-terminal); \
                     without one it only goes with --print-map",
                ));
            }
            self.started.push(format!(
                "profibus: {} {} 8E1, DP slave station {} and on ({} devices each, ident 0x{:04X}){}",
                port.path,
                port.baud,
                port.address,
                hart_profibus::map::DEVICES_PER_STATION,
                port.ident_number,
                if read_only { " (read only)" } else { "" }
            ));
            let rt = self.deadline_runtime()?;
            self.tasks
                .push(rt.spawn(hart_profibus::serve::serve_forever(engine.clone(), port)));
        }
        if let Some(cfg) = config.opcua {
            let bind = cfg.bind;
            let describe = cfg.describe();
            let server = hart_opcua::start(engine.clone(), cfg)
                .map_err(|e| Error::io(format!("--opcua {bind}: {e}")))?;
            self.started
                .push(format!("opcua: {} ({describe})", server.url));
            self.opcua = Some(server);
        }
        // With a historian, the MQTT publisher's full backlog leaves the rest of an
        // outage to it.
        // One handle on it for every reader: the dashboard's when it runs, else its own.
        let readers = config
            .web
            .as_ref()
            .and_then(|w| w.history.clone())
            .or_else(|| {
                config.history.as_ref().map(|h| {
                    hart_history::Readers::new(h.db.clone(), hart_history::DEFAULT_READERS)
                })
            });
        if let Some(h) = config.history {
            let what = format!(
                "history: {} (every change, and every device each {})",
                h.db,
                humantime::format_duration(h.sample_period)
            );
            let db = h.db.clone();
            let handle = hart_recorder::run(engine.clone(), h).await.map_err(|e| {
                let message = format!("--history {db}: {e}");
                if e.exit_code() == 2 {
                    Error::config(message)
                } else {
                    Error::io(message)
                }
            })?;
            self.started.push(what);
            self.history = Some(handle);
        }
        if let Some(m) = config.mqtt {
            let backfill = readers.map(|readers| {
                std::sync::Arc::new(backfill::HistoryBackfill::new(readers, engine.clone()))
                    as std::sync::Arc<dyn hart_sparkplug_edge::Backfill>
            });
            let what = format!(
                "mqtt: {} as spBv1.0/{}/+/{}{}{}",
                m.url,
                m.group,
                m.edge_node,
                m.primary_host
                    .as_ref()
                    .map_or(String::new(), |h| format!(" (primary host {h})")),
                if read_only || m.read_only {
                    " (read only)"
                } else {
                    ""
                }
            );
            let handle = hart_sparkplug_edge::run(engine.clone(), m, backfill)
                .await
                .map_err(|e| match e {
                    hart_sparkplug_edge::Error::Config(m) => Error::config(format!("--mqtt: {m}")),
                    e @ hart_sparkplug_edge::Error::File(..) => Error::io(format!("--mqtt: {e}")),
                })?;
            self.started.push(what);
            self.mqtt = Some(handle);
        }
        if let Some(w) = config.web {
            let mode = if read_only {
                "read only"
            } else if w.admin_password_file.is_some() || !w.psk_logins.is_empty() {
                "writes after login"
            } else {
                "read only: no --web-admin-password-file"
            };
            let server = hart_web::start(engine.clone(), w)
                .await
                .map_err(|e| match e {
                    hart_web::Error::Config(m) => Error::config(format!("--web: {m}")),
                    hart_web::Error::Io(m) => Error::io(format!("--web: {m}")),
                })?;
            self.started.push(format!("web: {} ({mode})", server.url));
            self.web = Some(server);
        }
        if let Some(c) = config.console {
            self.tasks
                .push(tokio::task::spawn_local(console::view(engine, c)));
        }
        Ok(())
    }

    /// The engine (its image, its loops).
    pub fn engine(&self) -> &Engine {
        &self.engine
    }

    /// One line per front end started, saying where it listens (what `hartkit serve`
    /// prints first).
    pub fn started(&self) -> &[String] {
        &self.started
    }

    /// The historian's counters (samples written, batches, dropped, the last error), if
    /// it runs.
    pub fn history_stats(&self) -> Option<hart_history::Stats> {
        self.history.as_ref().map(|h| h.stats())
    }

    /// The MQTT publisher's state (connected, births out, backlog), if it runs.
    pub fn mqtt_status(&self) -> Option<hart_sparkplug_edge::Status> {
        self.mqtt.as_ref().map(|m| m.status())
    }

    /// The runtime of the serial front ends with deadlines, started on first use.
    fn deadline_runtime(&mut self) -> Result<tokio::runtime::Handle, Error> {
        if self.deadlines.is_none() {
            self.deadlines = Some(DeadlineRuntime::start()?);
        }
        Ok(self
            .deadlines
            .as_ref()
            .map(|d| d.handle.clone())
            .expect("started above"))
    }

    /// Where the web dashboard listens, if it runs.
    pub fn web_addr(&self) -> Option<SocketAddr> {
        self.web.as_ref().map(|w| w.addr)
    }

    /// Where the Modbus TCP server listens, if it runs.
    pub fn modbus_tcp_addr(&self) -> Option<SocketAddr> {
        self.modbus_tcp
    }

    /// Stops the gateway without leaving anything behind: the front ends that take
    /// writes stop first; then the engine releases every loop test (command 40 with
    /// 0 mA) and commits its last changes; the MQTT publisher says its NDEATH; the
    /// historian writes every change the engine committed; then the loops end.
    pub async fn stop(self) {
        if let Some(w) = self.web {
            w.stop();
        }
        for t in self.tasks {
            t.abort();
        }
        if let Some(s) = self.opcua {
            s.stop();
        }
        for s in self.hart_ip {
            s.stop();
        }
        if tokio::time::timeout(ENGINE_STOP_LIMIT, self.engine.stop())
            .await
            .is_err()
        {
            tracing::error!(
                "the loops did not stop within {} s; a loop test may still be running: check \
                 the devices' loop currents",
                ENGINE_STOP_LIMIT.as_secs()
            );
        }
        if let Some(m) = self.mqtt {
            m.shutdown().await;
        }
        if let Some(h) = self.history {
            h.stop().await;
        }
        for t in self.loop_tasks {
            t.abort();
        }
    }
}

/// The longest [`Gateway::stop`] waits for the loops to release their loop tests: two
/// tries per device on a slow loop (four retries of 300 ms each) and some.
pub const ENGINE_STOP_LIMIT: Duration = Duration::from_secs(20);

/// The Modbus register map of the gateway `config` describes, once its loops have
/// listed their devices: as text, or as JSON with `json` (`hartkit serve
/// --print-map`). Call it inside a `LocalSet`.
pub async fn print_map(config: GatewayConfig, json: bool) -> Result<String, Error> {
    let (engine, tasks) = start_engine(&config).await?;
    engine.ready().await;
    if let Some(port) = &config.profibus {
        // `--print-map --profibus`: the PROFIBUS modules instead of the Modbus units.
        for t in tasks {
            t.abort();
        }
        return Ok(
            hart_profibus::serve::map_text(port.address, &engine.image().snapshot())
                .trim_end()
                .to_string(),
        );
    }
    let gw = hart_modbus::Gateway::new(engine, config.modbus);
    for t in tasks {
        t.abort();
    }
    Ok(if json {
        serde_json::to_string_pretty(&hart_modbus::map_json(&gw))
            .map_err(|e| Error::io(e.to_string()))?
    } else {
        hart_modbus::map_text(&gw).trim_end().to_string()
    })
}

/// The GSD file of the gateway's PROFIBUS station (`hartkit serve --print-gsd`), with
/// the ident number of the configuration file's `[profibus]` (or the default). Needs
/// no loop: the module is the same for every device.
pub fn print_gsd(opts: &ServeOptions) -> Result<String, Error> {
    let file = match &opts.config {
        Some(p) => GatewayFile::load(p)?,
        None => GatewayFile::default(),
    };
    Ok(hart_profibus::map::gsd(&hart_profibus::map::GsdInfo {
        ident_number: file
            .profibus
            .as_ref()
            .and_then(|p| p.ident_number)
            .unwrap_or(hart_profibus::serve::DEFAULT_IDENT_NUMBER),
        version: env!("CARGO_PKG_VERSION").to_string(),
    }))
}

/// Runs the gateway of `config` on a runtime of its own until `until` ends (Ctrl-C,
/// a time limit): prints the lines of [`Gateway::started`] to standard output first.
pub fn run_until<F>(config: GatewayConfig, until: F) -> Result<(), Error>
where
    F: std::future::Future<Output = ()>,
{
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Error::io(e.to_string()))?;
    let local = tokio::task::LocalSet::new();
    local.block_on(&rt, async move {
        let gateway = Gateway::start(config).await?;
        {
            use std::io::Write as _;
            let mut stdout = std::io::stdout();
            for line in gateway.started() {
                let _ = writeln!(stdout, "{line}");
            }
            let _ = stdout.flush();
        }
        until.await;
        gateway.stop().await;
        Ok(())
    })
}

/// Until Ctrl-C (SIGINT) or SIGTERM (a service manager's stop), or for `seconds`
/// when given: the `until` of `hartkit serve`. Either signal also ends a timed run
/// early, so the gateway always stops through [`Gateway::stop`].
pub async fn interrupted_or(seconds: Option<f64>) {
    let time = async {
        match seconds {
            Some(s) => {
                tokio::time::sleep(Duration::try_from_secs_f64(s).unwrap_or(Duration::MAX)).await
            }
            None => std::future::pending().await,
        }
    };
    let term = async {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{signal, SignalKind};
            match signal(SignalKind::terminate()) {
                Ok(mut s) => {
                    s.recv().await;
                }
                Err(_) => std::future::pending().await,
            }
        }
        #[cfg(not(unix))]
        std::future::pending::<()>().await
    };
    let signal = tokio::signal::ctrl_c();
    tokio::select! {
        _ = time => {}
        _ = term => tracing::info!("SIGTERM: stopping (loop tests released, history written)"),
        _ = signal => tracing::info!("interrupted: stopping (loop tests released, history written)"),
    }
}
