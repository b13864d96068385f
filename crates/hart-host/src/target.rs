//! Target strings: which transport to open.

use std::path::PathBuf;
use std::time::Duration;

use hart_link::{Micros, TimingProfile};

use crate::transport::{Plant, Rts, SerialOptions, SerialTransport, SimTransport, Transport};

/// Any transport, chosen at run time.
pub enum AnyTransport {
    /// Serial or RS-485.
    Serial(SerialTransport),
    /// Simulated plant.
    Sim(Box<SimTransport>),
    /// HART-IP session.
    HartIp(Box<crate::hartip::HartIpTransport>),
}

impl Transport for AnyTransport {
    fn profile(&self) -> TimingProfile {
        match self {
            AnyTransport::Serial(t) => t.profile(),
            AnyTransport::Sim(t) => t.profile(),
            AnyTransport::HartIp(t) => t.profile(),
        }
    }
    fn now(&self) -> Micros {
        match self {
            AnyTransport::Serial(t) => t.now(),
            AnyTransport::Sim(t) => t.now(),
            AnyTransport::HartIp(t) => t.now(),
        }
    }
    async fn send(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        match self {
            AnyTransport::Serial(t) => t.send(bytes).await,
            AnyTransport::Sim(t) => t.send(bytes).await,
            AnyTransport::HartIp(t) => t.send(bytes).await,
        }
    }
    async fn recv(&mut self, deadline: Micros) -> std::io::Result<Vec<(u8, Micros)>> {
        match self {
            AnyTransport::Serial(t) => t.recv(deadline).await,
            AnyTransport::Sim(t) => t.recv(deadline).await,
            AnyTransport::HartIp(t) => t.recv(deadline).await,
        }
    }
    fn describe(&self) -> String {
        match self {
            AnyTransport::Serial(t) => t.describe(),
            AnyTransport::Sim(t) => t.describe(),
            AnyTransport::HartIp(t) => t.describe(),
        }
    }
    fn take_no_reply(&mut self) -> Option<String> {
        match self {
            AnyTransport::Serial(t) => t.take_no_reply(),
            AnyTransport::Sim(t) => t.take_no_reply(),
            AnyTransport::HartIp(t) => t.take_no_reply(),
        }
    }
}

fn query(q: &str) -> Vec<(&str, &str)> {
    q.split('&')
        .filter(|s| !s.is_empty())
        .map(|kv| kv.split_once('=').unwrap_or((kv, "")))
        .collect()
}

/// Opens a transport from a target string.
///
/// * `/dev/ttyUSB0`, `serial:/dev/ttyUSB0?baud=1200&rts=high-tx&rts_pre_ms=5&rts_post_ms=2`
/// * `rs485:/dev/ttyUSB1?baud=19200`
/// * `sim` (the demo plant), `sim:plant.toml`, with `?virtual` for virtual time
/// * `udp://HOST:5094`, `tcp://HOST:5094`: HART-IP, not yet available
pub fn open(target: &str) -> Result<AnyTransport, String> {
    let (base, q) = target.split_once('?').unwrap_or((target, ""));
    let params = query(q);
    let get = |k: &str| params.iter().find(|(key, _)| *key == k).map(|(_, v)| *v);
    for (k, _) in &params {
        if !["baud", "rts", "rts_pre_ms", "rts_post_ms", "virtual"].contains(k) {
            return Err(format!("--port {target}: unknown option {k:?} (baud, rts, rts_pre_ms, rts_post_ms, virtual)"));
        }
    }
    if base == "sim" || base.starts_with("sim:") {
        let plant = match base.strip_prefix("sim:") {
            Some(path) => Plant::load(std::path::Path::new(path))?,
            None => Plant::demo(),
        };
        return Ok(AnyTransport::Sim(Box::new(SimTransport::new(
            &plant,
            get("virtual").is_some(),
        )?)));
    }
    if base.starts_with("udp://") || base.starts_with("tcp://") {
        return Err(format!(
            "--port {target}: HART-IP is not available in this version yet"
        ));
    }
    let (rs485, path) = if let Some(p) = base.strip_prefix("rs485:") {
        (true, p)
    } else if let Some(p) = base.strip_prefix("serial:") {
        (false, p)
    } else {
        (false, base)
    };
    let num = |k: &str, default: u64| -> Result<u64, String> {
        get(k).map_or(Ok(default), |v| {
            v.parse()
                .map_err(|_| format!("--port {target}: {k} must be a number"))
        })
    };
    let baud = num("baud", if rs485 { 19200 } else { 1200 })? as u32;
    let rts = match get("rts").unwrap_or("none") {
        "none" => Rts::None,
        "high-tx" => Rts::HighTx,
        "low-tx" => Rts::LowTx,
        other => {
            return Err(format!(
                "--port {target}: rts={other}: expected high-tx, low-tx or none"
            ))
        }
    };
    let opts = SerialOptions {
        path: PathBuf::from(path),
        baud,
        rts,
        rts_pre: Duration::from_millis(num("rts_pre_ms", 0)?),
        rts_post: Duration::from_millis(num("rts_post_ms", 0)?),
        rs485,
    };
    SerialTransport::open(opts)
        .map(AnyTransport::Serial)
        .map_err(|e| e.to_string())
}

/// Opens any target, including HART-IP (`udp://HOST[:PORT]`, `tcp://HOST[:PORT]`,
/// default port 5094), which needs the runtime to connect.
pub async fn open_async(target: &str) -> Result<AnyTransport, String> {
    let (base, _) = target.split_once('?').unwrap_or((target, ""));
    for (scheme, tcp) in [("udp://", false), ("tcp://", true)] {
        if let Some(rest) = base.strip_prefix(scheme) {
            let addr = if rest
                .rsplit_once(':')
                .is_some_and(|(_, p)| p.parse::<u16>().is_ok())
            {
                rest.to_string()
            } else {
                format!("{rest}:{}", hart_ip::PORT)
            };
            return crate::hartip::HartIpTransport::connect(&addr, tcp, 60_000)
                .await
                .map(|t| AnyTransport::HartIp(Box::new(t)))
                .map_err(|e| format!("--port {target}: {e}"));
        }
    }
    open(target)
}
