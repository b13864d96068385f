//! Target strings: which transport to open. [`parse`] reads one, [`open`] and
//! [`open_async`] open it: serial HART modems, RS-485, simulated plants and HART-IP
//! servers (`udp://HOST[:PORT]`, `tcp://HOST[:PORT]`).

use std::path::PathBuf;
use std::time::Duration;

use hart_link::{Micros, TimingProfile};

use crate::transport::{
    Plant, Rts, SerialOptions, SerialTransport, SimTransport, Transport, BAUD_RATES,
};

/// Any transport, chosen at run time.
pub enum AnyTransport {
    /// Serial or RS-485.
    Serial(Box<SerialTransport>),
    /// Simulated plant.
    Sim(Box<SimTransport>),
    /// HART-IP session.
    HartIp(Box<crate::hartip::HartIpTransport>),
    /// A recorded capture played back.
    Replay(Box<crate::replay::ReplayTransport>),
}

impl Transport for AnyTransport {
    fn profile(&self) -> TimingProfile {
        match self {
            AnyTransport::Serial(t) => t.profile(),
            AnyTransport::Sim(t) => t.profile(),
            AnyTransport::HartIp(t) => t.profile(),
            AnyTransport::Replay(t) => t.profile(),
        }
    }
    fn now(&self) -> Micros {
        match self {
            AnyTransport::Serial(t) => t.now(),
            AnyTransport::Sim(t) => t.now(),
            AnyTransport::HartIp(t) => t.now(),
            AnyTransport::Replay(t) => t.now(),
        }
    }
    async fn send(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        match self {
            AnyTransport::Serial(t) => t.send(bytes).await,
            AnyTransport::Sim(t) => t.send(bytes).await,
            AnyTransport::HartIp(t) => t.send(bytes).await,
            AnyTransport::Replay(t) => t.send(bytes).await,
        }
    }
    async fn recv(&mut self, deadline: Micros) -> std::io::Result<Vec<(u8, Micros)>> {
        match self {
            AnyTransport::Serial(t) => t.recv(deadline).await,
            AnyTransport::Sim(t) => t.recv(deadline).await,
            AnyTransport::HartIp(t) => t.recv(deadline).await,
            AnyTransport::Replay(t) => t.recv(deadline).await,
        }
    }
    fn describe(&self) -> String {
        match self {
            AnyTransport::Serial(t) => t.describe(),
            AnyTransport::Sim(t) => t.describe(),
            AnyTransport::HartIp(t) => t.describe(),
            AnyTransport::Replay(t) => t.describe(),
        }
    }
    fn take_no_reply(&mut self) -> Option<String> {
        match self {
            AnyTransport::Serial(t) => t.take_no_reply(),
            AnyTransport::Sim(t) => t.take_no_reply(),
            AnyTransport::HartIp(t) => t.take_no_reply(),
            AnyTransport::Replay(t) => t.take_no_reply(),
        }
    }
    async fn recv_flagged(
        &mut self,
        deadline: Micros,
    ) -> std::io::Result<Vec<crate::transport::RxChar>> {
        match self {
            AnyTransport::Serial(t) => t.recv_flagged(deadline).await,
            AnyTransport::Sim(t) => t.recv_flagged(deadline).await,
            AnyTransport::HartIp(t) => t.recv_flagged(deadline).await,
            AnyTransport::Replay(t) => t.recv_flagged(deadline).await,
        }
    }
    fn carrier(&mut self) -> Option<bool> {
        match self {
            AnyTransport::Serial(t) => t.carrier(),
            AnyTransport::Sim(t) => t.carrier(),
            AnyTransport::HartIp(t) => t.carrier(),
            AnyTransport::Replay(t) => t.carrier(),
        }
    }
}

/// What a target string asks for, before anything is opened.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    /// A HART modem on a serial port, or baseband RS-485 (`rs485` set).
    Serial(SerialOptions),
    /// A simulated plant: the demo plant or a plant file, in real or virtual time.
    Sim {
        /// Plant file (`sim:PLANT.toml`); `None` for the built-in demo plant.
        plant: Option<PathBuf>,
        /// Virtual time (`?virtual`): waiting costs nothing.
        virtual_time: bool,
        /// What carries the characters (`?medium=analog&cable_m=N`).
        medium: SimMedium,
    },
    /// A capture played back (`replay:FILE.pcapng[?port=N]`).
    Replay {
        /// The capture file.
        file: PathBuf,
        /// HART-IP port of a tcpdump capture (default 5094).
        port: u16,
    },
    /// A HART-IP server.
    HartIp {
        /// `HOST:PORT` (port 5094 when the target names none).
        address: String,
        /// TCP (`tcp://`, `tls://`) rather than UDP (`udp://`, `dtls://`).
        tcp: bool,
        /// HART-IP version 2 security: TLS (`tls://`) or DTLS (`dtls://`) with a
        /// pre-shared key.
        secure: bool,
    },
}

/// What carries the characters in a simulated plant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum SimMedium {
    /// Whole characters, delivered intact (`medium=digital`, the default).
    #[default]
    Digital,
    /// The 4-20 mA loop sample by sample (`medium=analog`): the host is a modem
    /// across the sense resistor, every device has its own modem at the end of the
    /// cable; noise, carrier detect and collisions come from the signal.
    Analog {
        /// Cable length, m (`cable_m=N`, default 0).
        cable_m: f64,
    },
}

/// Options each kind of target takes.
const SERIAL_OPTIONS: &[&str] = &["baud", "rts", "rts_pre_ms", "rts_post_ms", "carrier"];
const RS485_OPTIONS: &[&str] = &["baud", "rts", "rts_pre_ms", "rts_post_ms"];
const SIM_OPTIONS: &[&str] = &["virtual", "medium", "cable_m"];

/// Reads a target string without opening anything:
///
/// * `/dev/ttyUSB0`, `serial:/dev/ttyUSB0?baud=1200&rts=high-tx&rts_pre_ms=5&rts_post_ms=2&carrier=dcd`
///   (`baud` one of [`BAUD_RATES`], default 1200; `rts` `high-tx`, `low-tx` or `none`
///   (default); `rts_pre_ms`, `rts_post_ms` whole milliseconds, default 0; `carrier`
///   `dcd` to take the modem's DCD line as carrier detect, or `none` (default))
/// * `rs485:/dev/ttyUSB1?baud=19200` (default 19200; `rts` options as for serial)
/// * `sim` (the demo plant), `sim:plant.toml`, with `?virtual` for virtual time,
///   `?medium=analog&cable_m=N` for the loop sample by sample
/// * `udp://HOST[:PORT]`, `tcp://HOST[:PORT]`: HART-IP, port 5094 by default
/// * `replay:FILE.pcapng?port=5094`: a capture (`hartkit monitor --pcap`, or tcpdump's
///   of HART-IP on that port) played back
///
/// Errors name the option and what it takes.
pub fn parse(target: &str) -> Result<Target, String> {
    let (base, q) = target.split_once('?').unwrap_or((target, ""));
    let mut params: Vec<(&str, &str)> = vec![];
    for kv in q.split('&').filter(|s| !s.is_empty()) {
        let (k, v) = kv.split_once('=').unwrap_or((kv, ""));
        if params.iter().any(|(key, _)| *key == k) {
            return Err(format!("--port {target}: option {k:?} given twice"));
        }
        params.push((k, v));
    }
    let get = |k: &str| params.iter().find(|(key, _)| *key == k).map(|(_, v)| *v);
    let check = |kind: &str, allowed: &[&str]| -> Result<(), String> {
        match params.iter().find(|(k, _)| !allowed.contains(k)) {
            None => Ok(()),
            Some((k, _)) if allowed.is_empty() => Err(format!(
                "--port {target}: unknown option {k:?}: a {kind} target takes no options"
            )),
            Some((k, _)) => Err(format!(
                "--port {target}: unknown option {k:?} for a {kind} target (it takes {})",
                allowed.join(", ")
            )),
        }
    };
    if let Some(file) = base.strip_prefix("replay:") {
        check("replay", &["port"])?;
        if file.is_empty() {
            return Err(format!(
                "--port {target}: no capture file after replay: (replay:FILE.pcapng)"
            ));
        }
        let port = match get("port") {
            None => hart_capture::HART_IP_PORT,
            Some(p) => p.parse().map_err(|_| {
                format!("--port {target}: port={p}: give the HART-IP port of the capture, 1-65535")
            })?,
        };
        return Ok(Target::Replay {
            file: PathBuf::from(file),
            port,
        });
    }
    if base == "sim" || base.starts_with("sim:") {
        check("simulated plant", SIM_OPTIONS)?;
        let plant = match base.strip_prefix("sim:") {
            Some("") => {
                return Err(format!(
                    "--port {target}: no plant file after sim: (sim for the demo plant, sim:PLANT.toml for a file)"
                ))
            }
            Some(path) => Some(PathBuf::from(path)),
            None => None,
        };
        let virtual_time = match get("virtual") {
            None => false,
            Some("" | "1" | "true" | "yes") => true,
            Some("0" | "false" | "no") => false,
            Some(v) => {
                return Err(format!(
                    "--port {target}: virtual={v}: expected virtual alone, or virtual=1|0"
                ))
            }
        };
        let medium = match get("medium") {
            None | Some("digital") => {
                if get("cable_m").is_some() {
                    return Err(format!(
                        "--port {target}: cable_m needs medium=analog (a digital line has no cable)"
                    ));
                }
                SimMedium::Digital
            }
            Some("analog") => {
                let cable_m = match get("cable_m") {
                    None => 0.0,
                    Some(v) => v
                        .parse::<f64>()
                        .ok()
                        .filter(|m| m.is_finite() && (0.0..=100_000.0).contains(m))
                        .ok_or_else(|| {
                            format!("--port {target}: cable_m={v}: give the cable length in metres, 0-100000")
                        })?,
                };
                SimMedium::Analog { cable_m }
            }
            Some(v) => {
                return Err(format!(
                    "--port {target}: medium={v}: expected digital or analog"
                ))
            }
        };
        return Ok(Target::Sim {
            plant,
            virtual_time,
            medium,
        });
    }
    for (scheme, tcp, secure) in [
        ("udp://", false, false),
        ("tcp://", true, false),
        ("tls://", true, true),
        ("dtls://", false, true),
    ] {
        if let Some(rest) = base.strip_prefix(scheme) {
            check("HART-IP", &[])?;
            let port_of = |p: &str| -> Result<u16, String> {
                p.parse::<u16>()
                    .ok()
                    .filter(|&p| p != 0)
                    .ok_or_else(|| format!("--port {target}: port {p:?} must be a number 1-65535"))
            };
            let (host, port) = if let Some(v6) = rest.strip_prefix('[') {
                // [IPv6]:PORT or [IPv6]
                let (addr, after) = v6
                    .split_once(']')
                    .ok_or_else(|| format!("--port {target}: no ] after the IPv6 address"))?;
                let port = match after {
                    "" => hart_ip::PORT,
                    p => port_of(p.strip_prefix(':').unwrap_or(p))?,
                };
                (format!("[{addr}]"), port)
            } else if rest.matches(':').count() > 1 {
                // A bare IPv6 address: its colons are not a port.
                (format!("[{rest}]"), hart_ip::PORT)
            } else if let Some((host, p)) = rest.split_once(':') {
                (host.to_string(), port_of(p)?)
            } else {
                (rest.to_string(), hart_ip::PORT)
            };
            if host.is_empty() || host == "[]" {
                return Err(format!(
                    "--port {target}: no host after {scheme} (e.g. {scheme}192.168.1.20:5094)"
                ));
            }
            let address = format!("{host}:{port}");
            return Ok(Target::HartIp {
                address,
                tcp,
                secure,
            });
        }
    }
    let (rs485, path) = if let Some(p) = base.strip_prefix("rs485:") {
        (true, p)
    } else if let Some(p) = base.strip_prefix("serial:") {
        (false, p)
    } else if base.contains("://") {
        return Err(format!(
            "--port {target}: unknown scheme (udp://, tcp://, tls:// or dtls:// for HART-IP, serial:, rs485:, sim)"
        ));
    } else {
        (false, base)
    };
    if path.is_empty() {
        return Err(format!(
            "--port {target}: no device path (e.g. serial:/dev/ttyUSB0, rs485:/dev/ttyUSB1)"
        ));
    }
    if rs485 {
        check("RS-485", RS485_OPTIONS)?;
    } else {
        check("serial", SERIAL_OPTIONS)?;
    }
    let num = |k: &str, default: u64| -> Result<u64, String> {
        get(k).map_or(Ok(default), |v| {
            v.parse()
                .map_err(|_| format!("--port {target}: {k}={v}: must be a whole number"))
        })
    };
    let baud = num("baud", if rs485 { 19200 } else { 1200 })?;
    if !BAUD_RATES.iter().any(|&b| u64::from(b) == baud) {
        return Err(format!(
            "--port {target}: baud={baud}: not a supported rate (one of {})",
            BAUD_RATES.map(|b| b.to_string()).join(", ")
        ));
    }
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
    let carrier_detect = match get("carrier").unwrap_or("none") {
        "none" => false,
        "dcd" => true,
        other => {
            return Err(format!(
                "--port {target}: carrier={other}: expected dcd (the modem drives DCD while it hears a carrier) or none"
            ))
        }
    };
    Ok(Target::Serial(SerialOptions {
        path: PathBuf::from(path),
        baud: baud as u32,
        rts,
        rts_pre: Duration::from_millis(num("rts_pre_ms", 0)?),
        rts_post: Duration::from_millis(num("rts_post_ms", 0)?),
        rs485,
        carrier_detect,
    }))
}

/// Opens a transport from a target string (see [`parse`]). HART-IP targets need the
/// runtime to connect: open them with [`open_async`].
pub fn open(target: &str) -> Result<AnyTransport, String> {
    match parse(target)? {
        Target::Sim {
            plant,
            virtual_time,
            medium,
        } => {
            let plant = match plant {
                Some(path) => Plant::load(&path)?,
                None => Plant::demo(),
            };
            let mut t = SimTransport::new(&plant, virtual_time)?;
            if let SimMedium::Analog { cable_m } = medium {
                t.set_analog(
                    hart_modem::channel::LoopModel {
                        cable_length_m: cable_m,
                        ..hart_modem::channel::LoopModel::default()
                    },
                    hart_modem::line::LineOptions::default(),
                );
            }
            Ok(AnyTransport::Sim(Box::new(t)))
        }
        Target::Replay { file, port } => crate::replay::ReplayTransport::open(&file.to_string_lossy(), port)
            .map(|t| AnyTransport::Replay(Box::new(t))),
        Target::HartIp { .. } => Err(format!(
            "--port {target}: HART-IP targets are opened with target::open_async (they connect first)"
        )),
        Target::Serial(opts) => SerialTransport::open(opts)
            .map(|t| AnyTransport::Serial(Box::new(t)))
            .map_err(|e| e.to_string()),
    }
}

/// Opens any target, including HART-IP (`udp://HOST[:PORT]`, `tcp://HOST[:PORT]`,
/// default port 5094), which needs the runtime to connect.
pub async fn open_async(target: &str) -> Result<AnyTransport, String> {
    open_async_with(target, None).await
}

/// What to give for a secure HART-IP target opened without a pre-shared key.
fn needs_psk(target: &str) -> String {
    format!(
        "--port {target}: a secure HART-IP target needs a pre-shared key: --psk IDENTITY:HEXKEY or --psk-file FILE"
    )
}

/// Opens a master client on `target` (the `--port` syntax of [`parse`]) in `role`.
///
/// A target that does not read, or a secure HART-IP target without a pre-shared key,
/// is [`HostError::Usage`] (exit status 2); one that reads but cannot be opened or
/// connected (a port missing, a server refusing the handshake) is [`HostError::Io`]
/// (exit status 5). The command line, the Python package and every other tool that
/// takes a target open it here.
pub async fn connect(
    target: &str,
    psk: Option<&hart_ip_tls::Psk>,
    role: hart_proto::MasterKind,
) -> Result<crate::Client<AnyTransport>, crate::HostError> {
    let parsed = parse(target).map_err(crate::HostError::Usage)?;
    if matches!(parsed, Target::HartIp { secure: true, .. }) && psk.is_none() {
        return Err(crate::HostError::Usage(needs_psk(target)));
    }
    let t = open_async_with(target, psk)
        .await
        .map_err(|e| crate::HostError::Io(std::io::Error::other(e)))?;
    Ok(crate::Client::with_role(t, role))
}

/// Opens any target; `psk` is the key for HART-IP version 2 targets
/// (`tls://HOST[:PORT]`, `dtls://HOST[:PORT]`), which need one.
pub async fn open_async_with(
    target: &str,
    psk: Option<&hart_ip_tls::Psk>,
) -> Result<AnyTransport, String> {
    if let Target::HartIp {
        address,
        tcp,
        secure,
    } = parse(target)?
    {
        let psk = match (secure, psk) {
            (true, None) => return Err(needs_psk(target)),
            (true, Some(k)) => Some(k.clone()),
            (false, _) => None,
        };
        return crate::hartip::HartIpTransport::connect_with(&address, tcp, psk, 60_000)
            .await
            .map(|t| AnyTransport::HartIp(Box::new(t)))
            .map_err(|e| format!("--port {target}: {e}"));
    }
    open(target)
}
