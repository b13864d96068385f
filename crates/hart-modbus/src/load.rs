//! A Modbus TCP load generator (`hartkit modbus bench`): CLIENTS connections, each
//! reading COUNT input registers of a unit in a loop, one request at a time, for a
//! duration; reports requests per second, latency percentiles and errors. Run it as its
//! own process against a gateway (hartkit's or another), as a SCADA's polling would.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio_modbus::prelude::*;

/// What to load.
#[derive(Debug, Clone)]
pub struct LoadOptions {
    /// The server.
    pub address: SocketAddr,
    /// Connections at once.
    pub clients: usize,
    /// How long.
    pub duration: Duration,
    /// Unit id(s) to read, in turn.
    pub units: Vec<u8>,
    /// First input register.
    pub register: u16,
    /// Registers per request.
    pub count: u16,
    /// Worker threads (0: one per core).
    pub threads: usize,
}

/// What a run measured.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LoadReport {
    /// Connections.
    pub clients: usize,
    /// Seconds measured.
    pub seconds: f64,
    /// Requests answered with data.
    pub requests: u64,
    /// Requests answered with an exception, or failed.
    pub errors: u64,
    /// Answered requests per second.
    pub per_second: f64,
    /// Latency percentiles, ms: p50, p90, p99, max.
    pub latency_ms: [f64; 4],
}

/// Runs the load on a multi-threaded runtime of its own.
pub fn run_blocking(opts: &LoadOptions) -> std::io::Result<LoadReport> {
    let mut b = tokio::runtime::Builder::new_multi_thread();
    if opts.threads > 0 {
        b.worker_threads(opts.threads);
    }
    b.enable_all().build()?.block_on(run(opts.clone()))
}

/// Runs the load.
pub async fn run(opts: LoadOptions) -> std::io::Result<LoadReport> {
    let mut conns = vec![];
    for _ in 0..opts.clients.max(1) {
        let ctx = tcp::connect(opts.address).await.map_err(|e| {
            std::io::Error::new(
                e.kind(),
                format!(
                    "{}: {e}; is the gateway running there (hartkit serve --modbus ...)?",
                    opts.address
                ),
            )
        })?;
        conns.push(ctx);
    }
    let start = Instant::now();
    let end = start + opts.duration;
    let mut tasks = vec![];
    for (i, mut ctx) in conns.into_iter().enumerate() {
        let units = if opts.units.is_empty() {
            vec![1]
        } else {
            opts.units.clone()
        };
        let (register, count) = (opts.register, opts.count);
        tasks.push(tokio::spawn(async move {
            let mut lat = Vec::with_capacity(1 << 16);
            let (mut ok, mut err) = (0u64, 0u64);
            let mut k = i;
            while Instant::now() < end {
                ctx.set_slave(Slave(units[k % units.len()]));
                k += 1;
                let t = Instant::now();
                match ctx.read_input_registers(register, count).await {
                    Ok(Ok(_)) => {
                        ok += 1;
                        lat.push(t.elapsed().as_micros() as u32);
                    }
                    _ => err += 1,
                }
            }
            (ok, err, lat)
        }));
    }
    let (mut ok, mut err, mut lat) = (0, 0, vec![]);
    for t in tasks {
        let (o, e, l) = t.await.map_err(std::io::Error::other)?;
        ok += o;
        err += e;
        lat.extend(l);
    }
    let seconds = start.elapsed().as_secs_f64();
    lat.sort_unstable();
    let pct = |p: f64| {
        lat.get(((lat.len() as f64 * p) as usize).min(lat.len().saturating_sub(1)))
            .map_or(0.0, |&us| f64::from(us) / 1000.0)
    };
    Ok(LoadReport {
        clients: opts.clients,
        seconds,
        requests: ok,
        errors: err,
        per_second: ok as f64 / seconds,
        latency_ms: [pct(0.5), pct(0.9), pct(0.99), pct(1.0)],
    })
}
