//! Simulated devices served from Python: a plant of device profiles behind a HART-IP
//! server (`hartkit serve --sim --instant`), on a thread of its own, for testing hosts.

use std::net::SocketAddr;

use pyo3::prelude::*;
use tokio::sync::oneshot;

use crate::TargetError;

/// A running HART-IP server with simulated devices behind it; stops when closed or
/// dropped.
#[pyclass(module = "hartkit._native")]
pub struct SimServer {
    stop: Option<oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
    udp: Option<SocketAddr>,
    tcp: Option<SocketAddr>,
}

#[pymethods]
impl SimServer {
    /// `udp://HOST:PORT` of the server, for `hartkit.connect` or `hartkit -p`.
    #[getter]
    fn target(&self) -> Option<String> {
        self.udp.map(|a| format!("udp://{a}"))
    }

    /// `tcp://HOST:PORT` of the server.
    #[getter]
    fn tcp_target(&self) -> Option<String> {
        self.tcp.map(|a| format!("tcp://{a}"))
    }

    /// The port (UDP and TCP).
    #[getter]
    fn port(&self) -> Option<u16> {
        self.udp.or(self.tcp).map(|a| a.port())
    }

    /// Stops the server and waits for its thread (with the GIL released).
    fn close(&mut self, py: Python<'_>) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.thread.take() {
            py.detach(|| {
                let _ = t.join();
            });
        }
    }
}

impl Drop for SimServer {
    fn drop(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
    }
}

/// Serves `profiles` (built-in names such as "pressure", or profile files) at polling
/// addresses 1, 2, ... behind a HART-IP server bound to `address` (port 0: a free
/// one), the devices answering at once. With `loops` (targets the CLI's `--port`
/// takes, e.g. "serial:/dev/pts/3" of a `PythonDevice`), those loops are behind it
/// instead, scanned at polling addresses 0..=`scan_to`; `transparent` lets a device at
/// polling address 0 of a single loop answer there. Returns once the server listens.
#[pyfunction]
#[pyo3(signature = (profiles, address = "127.0.0.1:0".to_string(), loops = None, scan_to = 63, transparent = false))]
pub fn serve_hart_ip(
    py: Python<'_>,
    profiles: Vec<String>,
    address: String,
    loops: Option<Vec<String>>,
    scan_to: u8,
    transparent: bool,
) -> PyResult<SimServer> {
    let bind: SocketAddr = address.parse().map_err(|e| {
        pyo3::exceptions::PyValueError::new_err(format!("address {address:?}: {e} (HOST:PORT)"))
    })?;
    if transparent && loops.as_ref().is_none_or(|l| l.len() != 1) {
        return Err(pyo3::exceptions::PyValueError::new_err(
            "transparent needs exactly one loop: with several, polling address 0 of each would answer at the same address",
        ));
    }
    let devices = match loops {
        Some(_) => Vec::new(),
        None => hart_host::transport::Plant::from_profiles(&profiles)
            .and_then(|p| p.devices())
            .map_err(TargetError::new_err)?,
    };
    let (ready_tx, ready_rx) =
        oneshot::channel::<Result<(Option<SocketAddr>, Option<SocketAddr>), String>>();
    let (stop_tx, stop_rx) = oneshot::channel::<()>();
    let thread = std::thread::Builder::new()
        .name("hartkit sim server".into())
        .spawn(move || {
            let rt = match crate::thread_runtime() {
                Ok(rt) => rt,
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                    return;
                }
            };
            let local = tokio::task::LocalSet::new();
            local.block_on(&rt, async move {
                let config = hart_ip_server::Config {
                    bind,
                    scan_to: Some(scan_to.min(63)),
                    transparent,
                    ..hart_ip_server::Config::default()
                };
                let started = match loops {
                    None => hart_ip_server::start_in_memory(config, devices).await,
                    Some(targets) => {
                        let mut clients = Vec::new();
                        for t in &targets {
                            let primary = hart_proto::MasterKind::Primary;
                            match hart_host::target::connect(t, None, primary).await {
                                Ok(c) => clients.push(c),
                                Err(m) => {
                                    let _ = ready_tx.send(Err(format!("loop {t}: {m}")));
                                    return;
                                }
                            }
                        }
                        // Returned once the loops are scanned, so the first request
                        // is routed to the devices found.
                        match hart_ip_server::start(config, clients).await {
                            Ok(server) => {
                                server.ready().await;
                                Ok(server)
                            }
                            Err(e) => Err(e),
                        }
                    }
                };
                match started {
                    Ok(server) => {
                        let _ = ready_tx.send(Ok((server.udp_addr, server.tcp_addr)));
                        let _ = stop_rx.await;
                        server.stop();
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(format!(
                            "cannot serve HART-IP on {bind}: {e}; is the port taken?"
                        )));
                    }
                }
            });
        })
        .map_err(|e| TargetError::new_err(format!("cannot start a thread: {e}")))?;
    match py.detach(|| ready_rx.blocking_recv()) {
        Ok(Ok((udp, tcp))) => Ok(SimServer {
            stop: Some(stop_tx),
            thread: Some(thread),
            udp,
            tcp,
        }),
        Ok(Err(m)) => {
            let _ = thread.join();
            Err(TargetError::new_err(m))
        }
        Err(_) => Err(TargetError::new_err(
            "the server's thread ended while starting",
        )),
    }
}
