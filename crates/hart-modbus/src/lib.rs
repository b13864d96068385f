//! # hart-modbus
//!
//! Modbus front ends of hartkit's gateway: a Modbus TCP server and a Modbus RTU slave
//! on a serial port, both answering from the polling engine's image (reads never wait
//! for the HART loop) and carrying writes to the devices as HART commands, ahead of
//! the engine's polls.
//!
//! Each HART device is one Modbus unit: unit id 1 + its position in the engine's device
//! list. What each register holds is the [`map::RegisterMap`] (the default one is in
//! docs/gateway.md). Requests for a unit that is not in the list are answered
//! "gateway path unavailable" (TCP) or not at all (RTU, where another slave may own
//! that id); registers outside the map "illegal data address"; unsupported functions
//! "illegal function"; a write the device refuses with the Modbus exception that
//! matches its response code.

use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use hart_poller::{DeviceRefusal, Engine, WriteError, WriteFailure, WriteOp};
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

pub mod connections;
pub mod load;
pub mod map;
mod pdu;
pub mod rtu;

use map::{FloatOrder, RegisterMap, Table, Value};

/// Settings of the Modbus front ends.
#[derive(Debug, Clone)]
pub struct Config {
    /// The register map of every unit.
    pub map: RegisterMap,
    /// Layout of floats and 32-bit integers.
    pub float_order: FloatOrder,
    /// The TCP server's connection limits and priority hosts.
    pub limits: connections::Limits,
    /// Modbus TCP clients that may write (loopback only by default); others' writes
    /// are answered "illegal function". The RTU slave's master writes: whoever is
    /// wired to its port. Beyond this, every write follows the engine's write policy
    /// (`--read-only`, `--allow-commands`) and is recorded in its audit.
    pub write_from: hart_access::NetList,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            map: RegisterMap::default(),
            float_order: FloatOrder::default(),
            limits: connections::Limits::default(),
            write_from: hart_access::NetList::loopback(),
        }
    }
}

/// Counters of a Modbus front end.
#[derive(Debug, Default)]
pub struct Stats {
    /// Requests answered with data.
    pub answered: AtomicU64,
    /// Requests answered with an exception.
    pub exceptions: AtomicU64,
    /// Writes carried to a device.
    pub writes: AtomicU64,
    /// TCP connections refused (limit reached).
    pub refused: AtomicU64,
    /// Runs of bytes on the RTU line not taken as requests for us (bad CRC, other
    /// units' frames, frames cut short, garbage; see [`rtu::Discard`]).
    pub discarded: AtomicU64,
}

/// What the Modbus service needs: the engine, the settings, counters.
pub struct Gateway {
    engine: Engine,
    config: Config,
    /// Counters.
    pub stats: Stats,
    pool: connections::Pool,
}

/// The transport a request came by: TCP answers every unit id, RTU only its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Link {
    Tcp,
    Rtu,
}

/// Who sent a request: a TCP client's address, or the RTU port's path.
#[derive(Debug, Clone)]
enum Peer {
    Tcp(SocketAddr),
    Rtu(Arc<str>),
}

impl Peer {
    fn link(&self) -> Link {
        match self {
            Peer::Tcp(_) => Link::Tcp,
            Peer::Rtu(_) => Link::Rtu,
        }
    }
}

impl std::fmt::Display for Peer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Peer::Tcp(a) => a.fmt(f),
            Peer::Rtu(p) => write!(f, "serial {p}"),
        }
    }
}

impl Gateway {
    /// A gateway answering from `engine`'s image.
    pub fn new(engine: Engine, config: Config) -> Arc<Self> {
        Arc::new(Gateway {
            engine,
            config,
            stats: Stats::default(),
            pool: connections::Pool::default(),
        })
    }

    /// Modbus TCP connections open now.
    pub fn open_connections(&self) -> usize {
        self.pool.len()
    }

    /// The settings.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The reply frame to an RTU request `frame` (`None`: no reply, a broadcast), by
    /// the same answer path as Modbus TCP's ([`Gateway::call`]); a PDU that does not
    /// decode is answered with an exception (see [`rtu::decode_request`]).
    async fn rtu_reply(self: Arc<Self>, frame: &rtu::Frame, peer: &Peer) -> Option<Vec<u8>> {
        let function = frame.pdu.first().copied().unwrap_or(0);
        let result = match rtu::decode_request(&frame.pdu) {
            Ok(request) => self.clone().call(frame.unit, request, peer.clone()).await,
            Err(_) if frame.unit == 0 => Ok(None),
            Err(code) => {
                self.stats.exceptions.fetch_add(1, Ordering::Relaxed);
                Err(code)
            }
        };
        let pdu = match result {
            Ok(None) => return None,
            Ok(Some(response)) => encode_response(&response).unwrap_or_else(|| {
                vec![
                    function | 0x80,
                    u8::from(ExceptionCode::ServerDeviceFailure),
                ]
            }),
            Err(code) => vec![function | 0x80, u8::from(code)],
        };
        Some(rtu::adu(frame.unit, &pdu))
    }

    /// Answers one request for `unit`. `None`: no answer at all (RTU broadcasts and
    /// other slaves' unit ids).
    async fn call(
        self: Arc<Self>,
        unit: u8,
        request: Request<'static>,
        peer: Peer,
    ) -> Result<Option<Response>, ExceptionCode> {
        if unit == 0 && peer.link() == Link::Rtu {
            // An RTU broadcast is never answered: carry its writes out in the
            // background, so the next frame on the line is read at once rather than
            // after every device's write.
            let order = self.config.float_order;
            let values = match request {
                Request::WriteSingleRegister(register, word) => {
                    self.config.map.decode_write(register, &[word], order)
                }
                Request::WriteMultipleRegisters(start, words) => {
                    self.config.map.decode_write(start, &words, order)
                }
                _ => return Ok(None),
            };
            if let Ok(values) = values {
                let gw = self.clone();
                tokio::spawn(async move {
                    let _ = gw.write_all(None, true, values, &peer).await;
                });
            }
            return Ok(None);
        }
        let r = self.answer(unit, request, &peer).await;
        match &r {
            Ok(Some(_)) => self.stats.answered.fetch_add(1, Ordering::Relaxed),
            Err(_) => self.stats.exceptions.fetch_add(1, Ordering::Relaxed),
            Ok(None) => 0,
        };
        r
    }

    async fn answer(
        &self,
        unit: u8,
        request: Request<'static>,
        peer: &Peer,
    ) -> Result<Option<Response>, ExceptionCode> {
        let link = peer.link();
        let image = self.engine.image();
        let broadcast = link == Link::Rtu && unit == 0;
        let position = usize::from(unit).checked_sub(1);
        let known = position.is_some_and(|p| p < image.len());
        if !known && !broadcast {
            return match link {
                // Another slave on the bus may have this id.
                Link::Rtu => Ok(None),
                Link::Tcp => Err(ExceptionCode::GatewayPathUnavailable),
            };
        }
        let order = self.config.float_order;
        let read = |table: Table, start: u16, count: u16| {
            let p = position.ok_or(ExceptionCode::IllegalFunction)?;
            image
                .with(p, |d| {
                    self.config
                        .map
                        .read(table, start, count, d, Instant::now(), order)
                })
                .unwrap_or(Err(ExceptionCode::GatewayPathUnavailable))
        };
        if broadcast {
            // Carried out by `call`, in the background; never answered.
            return Ok(None);
        }
        let response = match request {
            Request::ReadInputRegisters(start, count) => {
                Response::ReadInputRegisters(read(Table::Input, start, count)?)
            }
            Request::ReadHoldingRegisters(start, count) => {
                Response::ReadHoldingRegisters(read(Table::Holding, start, count)?)
            }
            Request::WriteSingleRegister(register, word) => {
                let values = self.config.map.decode_write(register, &[word], order)?;
                self.write_all(position, false, values, peer).await?;
                Response::WriteSingleRegister(register, word)
            }
            Request::WriteMultipleRegisters(start, words) => {
                let values = self.config.map.decode_write(start, &words, order)?;
                self.write_all(position, false, values, peer).await?;
                Response::WriteMultipleRegisters(start, words.len() as u16)
            }
            _ => return Err(ExceptionCode::IllegalFunction),
        };
        Ok(Some(response))
    }

    /// Whether `peer` may write here: over TCP only from [`Config::write_from`]; over
    /// RTU, the port's master. (The gateway's own rule is the engine's.)
    fn may_write(&self, peer: &Peer) -> Result<(), String> {
        match peer {
            Peer::Tcp(a) if !self.config.write_from.contains(a.ip()) => Err(format!(
                "{} is not among the clients that may write ({}; --modbus-write-from, \
                 [modbus] write_from)",
                a.ip(),
                self.config.write_from.nets().join(", ")
            )),
            _ => Ok(()),
        }
    }

    /// Carries the values of one write request to the device at `position` (every
    /// device for an RTU broadcast), as typed writes (one HART command each).
    async fn write_all(
        &self,
        position: Option<usize>,
        broadcast: bool,
        values: Vec<(Value, f32)>,
        peer: &Peer,
    ) -> Result<(), ExceptionCode> {
        if let Err(why) = self.may_write(peer) {
            tracing::warn!("modbus: refused a write from {peer}: {why}");
            return Err(ExceptionCode::IllegalFunction);
        }
        let targets: Vec<usize> = match (broadcast, position) {
            (true, _) => (0..self.engine.image().len()).collect(),
            (false, Some(p)) => vec![p],
            (false, None) => return Err(ExceptionCode::GatewayPathUnavailable),
        };
        let ops = operations(&values)?;
        let origin = hart_access::WriteRecord {
            front_end: match peer.link() {
                Link::Tcp => "modbus-tcp",
                Link::Rtu => "modbus-rtu",
            },
            peer: peer.to_string(),
            via: format!(
                "{}holding registers {}",
                if broadcast { "broadcast, " } else { "" },
                values
                    .iter()
                    .map(|(v, _)| v.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            ..Default::default()
        };
        // One request is done whole or not at all: every write it carries is judged
        // against the gateway's rule before the first goes (a refusal is audited).
        let commands = ops.iter().map(WriteOp::command);
        let asked = hart_access::WriteRecord {
            device: match (broadcast, position) {
                (false, Some(p)) => format!("unit {}", p + 1),
                _ => "every unit (broadcast)".into(),
            },
            operation: Some(
                ops.iter()
                    .map(WriteOp::describe)
                    .collect::<Vec<_>>()
                    .join("; "),
            ),
            ..origin.clone()
        };
        if let Err(why) = self.engine.write_policy().judge_all(commands, &asked) {
            tracing::warn!("modbus: refused a write from {peer}: {why}");
            return Err(ExceptionCode::IllegalFunction);
        }
        let mut result = Ok(());
        for p in targets {
            for op in &ops {
                self.stats.writes.fetch_add(1, Ordering::Relaxed);
                if let Err(e) = self.engine.apply(p, op, &origin).await {
                    tracing::warn!(
                        "modbus: write to unit {} ({}) not done: {e}",
                        p + 1,
                        op.describe()
                    );
                    result = Err(exception(&e));
                    break;
                }
            }
        }
        result
    }
}

/// The PDU of `response`, for the responses the gateway gives (register reads and
/// writes); `None` for others.
fn encode_response(response: &Response) -> Option<Vec<u8>> {
    let words = |function: u8, words: &[u16]| {
        let mut out = vec![function, u8::try_from(2 * words.len()).ok()?];
        out.extend(words.iter().flat_map(|w| w.to_be_bytes()));
        Some(out)
    };
    let two = |function: u8, a: u16, b: u16| {
        let mut out = vec![function];
        out.extend_from_slice(&a.to_be_bytes());
        out.extend_from_slice(&b.to_be_bytes());
        Some(out)
    };
    match response {
        Response::ReadHoldingRegisters(w) => words(3, w),
        Response::ReadInputRegisters(w) => words(4, w),
        Response::WriteSingleRegister(register, word) => two(6, *register, *word),
        Response::WriteMultipleRegisters(start, count) => two(16, *start, *count),
        _ => None,
    }
}

/// The typed writes that set `values` (one write request's): the range parts together
/// in one, then damping and fixed current.
fn operations(values: &[(Value, f32)]) -> Result<Vec<WriteOp>, ExceptionCode> {
    let mut out = vec![];
    let (mut upper, mut lower, mut units) = (None, None, None);
    for &(value, x) in values {
        match value {
            Value::UpperRange => upper = Some(x),
            Value::LowerRange => lower = Some(x),
            Value::RangeUnits => {
                if !(0.0..=255.0).contains(&x) || x.fract() != 0.0 {
                    return Err(ExceptionCode::IllegalDataValue);
                }
                units = Some(x as u8)
            }
            Value::Damping => out.push(WriteOp::Damping(x)),
            Value::FixedCurrent => out.push(WriteOp::FixedCurrent(x)),
            _ => return Err(ExceptionCode::IllegalDataAddress),
        }
    }
    if upper.is_some() || lower.is_some() || units.is_some() {
        // Command 35 sets both range values: the one not written keeps its value.
        out.insert(
            0,
            WriteOp::Range {
                upper,
                lower,
                units,
            },
        );
    }
    Ok(out)
}

/// The Modbus answer to a typed write that was not done.
fn exception(e: &WriteFailure) -> ExceptionCode {
    match e {
        WriteFailure::NotPermitted(_) => ExceptionCode::IllegalFunction,
        WriteFailure::Invalid(_) => ExceptionCode::IllegalDataValue,
        // The range was never read (the device has not answered command 15).
        WriteFailure::NotReadYet(_) => ExceptionCode::GatewayTargetDevice,
        WriteFailure::Link(WriteError::UnknownDevice) => ExceptionCode::GatewayPathUnavailable,
        WriteFailure::Link(WriteError::NoReply) => ExceptionCode::GatewayTargetDevice,
        WriteFailure::Link(WriteError::Busy) => ExceptionCode::ServerDeviceBusy,
        WriteFailure::Link(WriteError::BadReply(_)) => ExceptionCode::ServerDeviceFailure,
        WriteFailure::Refused { refusal, .. } => match refusal {
            DeviceRefusal::OutOfRange => ExceptionCode::IllegalDataValue,
            DeviceRefusal::Busy => ExceptionCode::ServerDeviceBusy,
            DeviceRefusal::NotImplemented => ExceptionCode::IllegalFunction,
            // Write protected, access restricted, in multidrop mode (40),
            // device-specific errors: the device will not do it now.
            DeviceRefusal::NotWritable | DeviceRefusal::Failed => {
                ExceptionCode::ServerDeviceFailure
            }
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refused(command: u16, code: u8) -> ExceptionCode {
        exception(&WriteFailure::Refused {
            command,
            code,
            refusal: DeviceRefusal::of(command, code).unwrap(),
        })
    }

    #[test]
    fn frame_guard_refuses_what_the_decoder_cannot_take() {
        let frame = |pdu: &[u8]| {
            let mut f = vec![0, 1, 0, 0];
            f.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
            f.push(1);
            f.extend_from_slice(pdu);
            f
        };
        let ok: &[&[u8]] = &[
            &[4, 0, 0, 0, 2],
            &[0x10, 0, 4, 0, 2, 4, 0x40, 0x20, 0, 0],
            &[0x0F, 0, 0, 0, 9, 2, 0xFF, 1],
            &[0x17, 0, 0, 0, 1, 0, 4, 0, 1, 2, 0, 0],
        ];
        for pdu in ok {
            assert_eq!(
                FrameGuard::default().feed(&frame(pdu)),
                Ok(()),
                "{pdu:02X?}"
            );
        }
        let bad: &[&[u8]] = &[
            &[0x10, 0xD2, 0xB8, 0xD2, 0x00, 0x00], // quantity * 2 overflows u16
            &[0x10, 0, 0, 0, 124, 248],            // more than 123 registers
            &[0x0F, 0, 0, 0, 100, 1, 0],           // 100 coils in 1 byte
            &[0x17, 0, 0, 0, 1, 0, 0, 0x80, 0, 0], // write quantity 32768
        ];
        for pdu in bad {
            assert!(
                FrameGuard::default().feed(&frame(pdu)).is_err(),
                "{pdu:02X?}"
            );
        }
        // Byte by byte, and two frames in one read.
        let mut g = FrameGuard::default();
        let mut two = frame(&[4, 0, 0, 0, 2]);
        two.extend(frame(&[3, 0, 0, 0, 9]));
        for b in two {
            assert_eq!(g.feed(&[b]), Ok(()));
        }
        assert!(FrameGuard::default()
            .feed(&[0, 1, 0, 0, 0xFF, 0xFF])
            .is_err());
    }

    proptest::proptest! {
        /// Any byte stream: the guard answers, never panics.
        #[test]
        fn frame_guard_takes_any_bytes(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..600)) {
            let _ = FrameGuard::default().feed(&bytes);
        }
    }

    #[test]
    fn hart_outcomes_become_modbus_exceptions() {
        assert_eq!(refused(34, 3), ExceptionCode::IllegalDataValue);
        assert_eq!(refused(35, 11), ExceptionCode::IllegalDataValue);
        // 11 for command 40 is "in multidrop mode": not the value's fault.
        assert_eq!(refused(40, 11), ExceptionCode::ServerDeviceFailure);
        assert_eq!(refused(34, 7), ExceptionCode::ServerDeviceFailure);
        assert_eq!(refused(34, 32), ExceptionCode::ServerDeviceBusy);
        assert_eq!(refused(40, 64), ExceptionCode::IllegalFunction);
        assert_eq!(
            exception(&WriteFailure::Link(WriteError::NoReply)),
            ExceptionCode::GatewayTargetDevice
        );
        assert_eq!(
            exception(&WriteFailure::Link(WriteError::UnknownDevice)),
            ExceptionCode::GatewayPathUnavailable
        );
    }

    #[test]
    fn range_parts_go_in_one_command() {
        let ops = operations(&[
            (Value::Damping, 2.0),
            (Value::UpperRange, 200.0),
            (Value::RangeUnits, 12.0),
        ])
        .unwrap();
        assert_eq!(
            ops,
            vec![
                WriteOp::Range {
                    upper: Some(200.0),
                    lower: None,
                    units: Some(12)
                },
                WriteOp::Damping(2.0)
            ]
        );
        assert!(operations(&[(Value::RangeUnits, 12.5)]).is_err());
    }
}

/// The tokio-modbus service of one TCP connection.
#[derive(Clone)]
pub struct Service {
    gateway: Arc<Gateway>,
    peer: Peer,
}

impl tokio_modbus::server::Service for Service {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future =
        Pin<Box<dyn Future<Output = Result<Option<Response>, ExceptionCode>> + Send + 'static>>;

    fn call(&self, req: Self::Request) -> Self::Future {
        let gw = self.gateway.clone();
        Box::pin(gw.call(req.slave, req.request, self.peer.clone()))
    }
}

/// A TCP stream in the connection pool until dropped ([`connections`]): its request
/// frames pass the [`FrameGuard`] before tokio-modbus decodes them, it is closed when
/// a request does not come or come whole in time, and when the pool evicts it.
struct Counted {
    stream: tokio::net::TcpStream,
    gateway: Arc<Gateway>,
    guard: FrameGuard,
    peer: SocketAddr,
    /// Its id in the pool.
    id: u64,
    opened: Instant,
    /// Woken when the pool closes it.
    close: Pin<Box<tokio::sync::futures::OwnedNotified>>,
    /// The deadline of the request under way (or of the first one).
    timer: Pin<Box<tokio::time::Sleep>>,
}

impl Counted {
    /// Closes the connection: an error for tokio-modbus, which then drops it.
    fn closed(&self, why: &str) -> std::task::Poll<std::io::Result<()>> {
        if self.gateway.pool.log.allow() {
            tracing::warn!("modbus: closed the connection from {}: {why}", self.peer);
        }
        std::task::Poll::Ready(Err(std::io::Error::new(
            std::io::ErrorKind::TimedOut,
            why.to_string(),
        )))
    }
}

/// Follows the Modbus TCP frames (MBAP header, then `length - 1` PDU bytes) a client
/// sends and refuses, before they reach the decoder, those the Modbus application
/// protocol does not allow and tokio-modbus 0.17 would panic on: write multiple coils
/// (15), write multiple registers (16) and read/write multiple registers (23) whose
/// quantity is outside the protocol's limits or disagrees with the byte count (the
/// decoder indexes coils by the quantity, and multiplies register quantities by 2 in
/// u16), and an MBAP length outside 2..=254. The connection is then closed.
#[derive(Debug, Default)]
struct FrameGuard {
    frame: Vec<u8>,
    /// Requests seen whole.
    whole: u64,
}

impl FrameGuard {
    /// Whether part of a request has come and the rest not yet.
    fn partial(&self) -> bool {
        !self.frame.is_empty()
    }

    /// Takes the bytes just received; an error names the first frame refused.
    fn feed(&mut self, bytes: &[u8]) -> Result<(), &'static str> {
        for &b in bytes {
            self.frame.push(b);
            if self.frame.len() < 6 {
                continue;
            }
            let len = usize::from(u16::from_be_bytes([self.frame[4], self.frame[5]]));
            if !(2..=254).contains(&len) {
                return Err("MBAP length outside 2-254");
            }
            if self.frame.len() == 6 + len {
                pdu::check_request_pdu(&self.frame[7..])?;
                self.frame.clear();
                self.whole += 1;
            }
        }
        Ok(())
    }
}

impl Drop for Counted {
    fn drop(&mut self) {
        self.gateway.pool.remove(self.id);
    }
}

impl tokio::io::AsyncRead for Counted {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        use connections::Phase;
        use std::task::Poll;
        let this = &mut *self;
        if this.close.as_mut().poll(cx).is_ready() {
            return this.closed("closed to admit a new connection: the pool was full");
        }
        let limits = &this.gateway.config.limits;
        let phase = this.gateway.pool.phase(this.id).unwrap_or(Phase::Idle);
        if let Some(due) = connections::deadline(phase, this.opened, limits) {
            let due = tokio::time::Instant::from_std(due);
            if this.timer.deadline() != due {
                this.timer.as_mut().reset(due);
            }
            if this.timer.as_mut().poll(cx).is_ready() {
                let why = match phase {
                    Phase::Fresh => format!(
                        "no complete request within {} s of connecting",
                        limits.first_request.as_secs_f64()
                    ),
                    _ => format!(
                        "a request begun was not whole within {} s",
                        limits.request.as_secs_f64()
                    ),
                };
                return this.closed(&why);
            }
        }
        let before = buf.filled().len();
        std::task::ready!(Pin::new(&mut this.stream).poll_read(cx, buf))?;
        let whole = this.guard.whole;
        if let Err(why) = this.guard.feed(&buf.filled()[before..]) {
            return this.closed(why);
        }
        let now = Instant::now();
        let next = if this.guard.partial() {
            match phase {
                Phase::Receiving(since) if this.guard.whole == whole => Phase::Receiving(since),
                _ => Phase::Receiving(now),
            }
        } else if this.guard.whole > whole {
            Phase::Answering
        } else {
            phase
        };
        if next != phase {
            this.gateway.pool.set_phase(this.id, next, now);
        }
        Poll::Ready(Ok(()))
    }
}

impl tokio::io::AsyncWrite for Counted {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        let r = std::task::ready!(Pin::new(&mut self.stream).poll_write(cx, buf));
        // An answer went out: between requests again (unless the next has begun).
        if !self.guard.partial() {
            self.gateway
                .pool
                .set_phase(self.id, connections::Phase::Idle, Instant::now());
        }
        std::task::Poll::Ready(r)
    }
    fn poll_flush(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }
    fn poll_shutdown(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }
}

/// Binds a Modbus TCP server at `addr`; returns the address bound and the task that
/// serves it (spawn it, or await it). Each connection is served on its own task; a
/// connection that sends a malformed frame is closed, the others go on.
pub async fn bind_tcp(
    gateway: Arc<Gateway>,
    addr: SocketAddr,
) -> std::io::Result<(SocketAddr, impl Future<Output = std::io::Result<()>>)> {
    let listener = tokio::net::TcpListener::bind(addr).await?;
    let local = listener.local_addr()?;
    let server = tokio_modbus::server::tcp::Server::new(listener);
    let serve = async move {
        let on_connected = |stream: tokio::net::TcpStream, peer: SocketAddr| {
            let gateway = gateway.clone();
            async move {
                let now = Instant::now();
                let (id, close) = match gateway.pool.admit(peer, &gateway.config.limits, now) {
                    Ok(admitted) => admitted,
                    Err(why) => {
                        gateway.stats.refused.fetch_add(1, Ordering::Relaxed);
                        if gateway.pool.log.allow() {
                            tracing::warn!("modbus: connection from {peer} refused: {why}");
                        }
                        return Ok(None);
                    }
                };
                let counted = Counted {
                    stream,
                    gateway: gateway.clone(),
                    guard: FrameGuard::default(),
                    peer,
                    id,
                    opened: now,
                    close: Box::pin(close.notified_owned()),
                    timer: Box::pin(tokio::time::sleep_until(tokio::time::Instant::from_std(
                        now + gateway.config.limits.first_request,
                    ))),
                };
                let _ = counted.stream.set_nodelay(true);
                let service = Service {
                    gateway,
                    peer: Peer::Tcp(peer),
                };
                Ok(Some((service, counted)))
            }
        };
        server
            .serve(&on_connected, |e| {
                tracing::debug!("modbus: connection closed: {e}");
            })
            .await
    };
    Ok((local, serve))
}

/// Serial settings of the RTU slave.
#[derive(Debug, Clone)]
pub struct RtuPort {
    /// Device path (`/dev/ttyUSB0`).
    pub path: String,
    /// Baud rate.
    pub baud: u32,
    /// Parity: `'N'`, `'E'` or `'O'` (Modbus RTU's default is even).
    pub parity: char,
    /// Stop bits (1 or 2; Modbus asks 2 with no parity).
    pub stop_bits: u8,
}

/// Serves Modbus RTU on `port` for as long as the gateway runs: after the port fails (a
/// USB adapter unplugged, a pseudo-terminal gone), it is opened again after
/// [`RTU_REOPEN`], then less and less often while it keeps failing. Nothing a master or
/// another slave sends stops the port: bad frames are ignored ([`rtu::Framer`]).
pub async fn serve_rtu_forever(gateway: Arc<Gateway>, port: RtuPort) {
    // The engine's reconnect policy, from RTU_REOPEN: a port that keeps failing is
    // tried less and less often (up to 30 s), one that served a while starts over.
    let mut backoff =
        hart_host::reconnect::Backoff::new(RTU_REOPEN, std::time::Duration::from_secs(30));
    loop {
        let started = Instant::now();
        let task = tokio::spawn(serve_rtu(gateway.clone(), port.clone()));
        let outcome = task.await;
        if started.elapsed() > std::time::Duration::from_secs(60) {
            backoff.reset();
        }
        match outcome {
            Ok(Ok(())) => tracing::warn!("modbus-rtu: {} closed", port.path),
            Ok(Err(e)) => tracing::error!("modbus-rtu: {e}"),
            Err(e) if e.is_panic() => {
                tracing::error!("modbus-rtu: {}: the slave failed (a bug)", port.path)
            }
            Err(_) => return,
        }
        let wait = backoff.failed(Instant::now());
        tracing::info!(
            "modbus-rtu: opening {} again in {} s",
            port.path,
            wait.as_secs()
        );
        tokio::time::sleep(wait).await;
    }
}

/// First wait before the RTU port is opened again (then doubling up to 30 s while it
/// keeps failing).
pub const RTU_REOPEN: std::time::Duration = std::time::Duration::from_secs(2);

impl RtuPort {
    /// The line's speed and framing.
    pub fn line(&self) -> std::io::Result<hart_serial::Line> {
        let parity = match self.parity.to_ascii_uppercase() {
            'N' => hart_serial::Parity::None,
            'E' => hart_serial::Parity::Even,
            'O' => hart_serial::Parity::Odd,
            p => {
                return Err(std::io::Error::other(format!(
                    "parity {p:?}: give N, E or O"
                )))
            }
        };
        Ok(hart_serial::Line {
            baud: self.baud,
            parity,
            stop_bits: if self.stop_bits == 2 { 2 } else { 1 },
        })
    }
}

/// Opens `port` and serves Modbus RTU on it until the port fails (an error that says
/// how). Frames are found by [`rtu::Framer`] (silence, length and CRC); requests for
/// the gateway's units are answered by the same code as Modbus TCP's, t3.5 after the
/// request at the earliest; broadcasts are carried out and not answered; everything
/// else is ignored (logged at debug level, counted in [`Stats::discarded`]).
pub async fn serve_rtu(gateway: Arc<Gateway>, port: RtuPort) -> std::io::Result<()> {
    let line = port.line()?;
    let path = std::path::Path::new(&port.path);
    let serial = hart_serial::Port::open(
        path,
        &line,
        hart_serial::OpenOptions {
            exclusive: true,
            mark_errors: false,
        },
    )?;
    let writer = serial.try_clone()?;
    // Reads are timestamped by their own task, so that the times stay right while a
    // write request is carried to a device.
    let mut reader = hart_serial::aio::Reader::spawn(serial);
    let timing = rtu::Timing::for_line(&line);
    let units = |gw: &Gateway| {
        1..=u8::try_from(gw.engine.image().len())
            .unwrap_or(247)
            .min(247)
    };
    let mut framer = rtu::Framer::new(timing, units(&gateway));
    let peer = Peer::Rtu(port.path.as_str().into());
    // Requests whose last byte came before this were received while the previous reply
    // was being made: their master has moved on (or retried), they are not answered
    // late.
    let mut busy_until = Instant::now();
    loop {
        let deadline = framer.deadline().map(tokio::time::Instant::from_std);
        let first = tokio::select! {
            biased;
            r = reader.recv() => Some(r),
            _ = tokio::time::sleep_until(deadline.unwrap_or_else(tokio::time::Instant::now)),
                if deadline.is_some() => None,
        };
        let mut reads: Vec<hart_serial::aio::Read> = first.into_iter().collect();
        while let Some(r) = reader.try_recv() {
            reads.push(r);
        }
        if !reads.is_empty() {
            framer.set_units(units(&gateway));
        }
        for r in reads {
            let (bytes, at) = r?;
            framer.push(&bytes, at);
        }
        while let Some(event) = framer.poll(Instant::now()) {
            let frame = match event {
                rtu::Event::Frame(f) => f,
                rtu::Event::Discarded(why) => {
                    gateway.stats.discarded.fetch_add(1, Ordering::Relaxed);
                    tracing::debug!("modbus-rtu: {}: ignored {why}", port.path);
                    continue;
                }
            };
            if frame.end < busy_until {
                gateway.stats.discarded.fetch_add(1, Ordering::Relaxed);
                tracing::debug!(
                    "modbus-rtu: {}: ignored a request for unit {} that came while the \
                     previous one was being answered",
                    port.path,
                    frame.unit
                );
                continue;
            }
            let reply = gateway.clone().rtu_reply(&frame, &peer).await;
            if let Some(reply) = reply {
                // Not before the line has been quiet for t3.5 after the request.
                tokio::time::sleep_until(tokio::time::Instant::from_std(frame.end + timing.t35))
                    .await;
                // Taken before the write: a busy host may stall between the write and
                // the next statement, while the master's next request comes.
                // (A broadcast has no reply: its master goes on at once, and its next
                // request may come in the same read.)
                busy_until = Instant::now();
                writer.write_all_async(&reply).await?;
            }
        }
    }
}

/// The map as text: one line per entry, for `hartkit serve --print-map`.
pub fn map_text(gateway: &Gateway) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let image = gateway.engine.image().snapshot();
    let _ = writeln!(
        out,
        "units (Modbus unit id = 1 + position in the device list):"
    );
    for d in &image {
        let _ = writeln!(
            out,
            "  unit {:>3}  {:<10} poll {:>2}  {:<32} {}",
            d.position + 1,
            d.loop_name,
            d.polling_address.map_or("-".to_string(), |p| p.to_string()),
            d.display_name(),
            d.unique_id()
                .map_or("(not found yet)".to_string(), |u| format!("unique ID {u}"))
        );
    }
    if image.is_empty() {
        let _ = writeln!(out, "  (no device found)");
    }
    let _ = writeln!(
        out,
        "registers of every unit (floats and 32-bit integers in {} order):",
        gateway.config.float_order.name()
    );
    for e in gateway.config.map.entries() {
        let table = match e.table {
            Table::Input => "input",
            Table::Holding => "holding",
        };
        let regs = if e.format().words() == 2 {
            format!("{}-{}", e.register, e.register + 1)
        } else {
            e.register.to_string()
        };
        let _ = writeln!(
            out,
            "  {table:<7} {regs:>11}  {:<6} {:<16} {}{}",
            format!("{:?}", e.format()).to_lowercase(),
            e.value.name(),
            e.value.description(),
            if e.table == Table::Holding && e.value.writable() {
                " [read/write]"
            } else {
                ""
            }
        );
    }
    out
}

/// The map as JSON: `units` (unit id, loop, polling address, name, unique ID) and
/// `registers` (table, register, words, format, value, writable, description).
pub fn map_json(gateway: &Gateway) -> serde_json::Value {
    let units: Vec<_> = gateway
        .engine
        .image()
        .snapshot()
        .iter()
        .map(|d| {
            serde_json::json!({
                "unit": d.position + 1,
                "loop": d.loop_name,
                "polling_address": d.polling_address,
                "name": d.display_name(),
                "unique_id": d.unique_id().map(|u| u.to_string()),
                "tag": d.info.as_ref().and_then(|i| i.tag.clone()),
                "long_tag": d.info.as_ref().and_then(|i| i.long_tag.clone()),
            })
        })
        .collect();
    let registers: Vec<_> = gateway
        .config
        .map
        .entries()
        .iter()
        .map(|e| {
            serde_json::json!({
                "table": e.table,
                "register": e.register,
                "words": e.format().words(),
                "format": e.format(),
                "value": e.value,
                "writable": e.table == Table::Holding && e.value.writable(),
                "description": e.value.description(),
            })
        })
        .collect();
    serde_json::json!({
        "float_order": gateway.config.float_order.name(),
        "units": units,
        "registers": registers,
    })
}
