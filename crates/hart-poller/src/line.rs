//! What a loop task talks to: a real line through `hart_host::Client` (serial modem,
//! RS-485, HART-IP upstream, simulated plant), or devices answered in memory.

use std::time::{Duration, Instant};

use hart_host::target::AnyTransport;
use hart_host::Client;
use hart_link::master::RetryPolicy;
use hart_proto::command::{ReadPvResponse, Response};
use hart_proto::frame::{Address, Frame, FrameSpec, FrameType};
use hart_proto::types::UnitCode;

use crate::disturbance::LineCounters;

/// A loop's line.
pub enum Line {
    /// A line reached through a master client.
    Client(Box<Client<AnyTransport>>),
    /// A port opened from its target (`/dev/ttyUSB0`, `rs485:...`, `udp://...`),
    /// opened again after it fails ([`Reopening`]).
    Port(Box<Reopening>),
    /// Field devices answered at once, in memory, without line timing (benchmarks).
    Memory(MemoryLoop),
}

/// A port the engine opens again when it fails: an I/O error (an unplugged USB modem,
/// a HART-IP server gone) is logged, every request answered "no reply" meanwhile, and
/// the port opened again after 1 s, 2 s, 4 s ... up to 30 s
/// ([`hart_host::reconnect::Backoff`]) until it works.
pub struct Reopening {
    target: String,
    client: Option<Client<AnyTransport>>,
    backoff: hart_host::reconnect::Backoff,
    /// Why the port is down, and since when.
    failure: Option<(Instant, String)>,
}

impl Reopening {
    /// The client, opening the port again when its wait is over; `None` while it is
    /// down.
    async fn client(&mut self) -> Option<&mut Client<AnyTransport>> {
        if self.client.is_none() {
            let now = Instant::now();
            if !self.backoff.ready(now) {
                return None;
            }
            match hart_host::target::open_async(&self.target).await {
                Ok(t) => {
                    let down = self
                        .failure
                        .take()
                        .map_or(0.0, |(since, _)| since.elapsed().as_secs_f64());
                    tracing::info!(
                        "{}: the port is back after {down:.0} s ({} attempts)",
                        self.target,
                        self.backoff.failures()
                    );
                    self.backoff.reset();
                    self.client = Some(Client::new(t));
                }
                Err(e) => {
                    let wait = self.backoff.failed(now);
                    tracing::warn!(
                        "{}: still failed: {e}; trying again in {} s",
                        self.target,
                        wait.as_secs()
                    );
                    if let Some(f) = self.failure.as_mut() {
                        f.1 = e;
                    }
                    return None;
                }
            }
        }
        self.client.as_mut()
    }

    /// The port failed with `e`: closed, to be opened again.
    fn failed(&mut self, e: &std::io::Error) {
        self.client = None;
        let wait = self.backoff.failed(Instant::now());
        tracing::error!(
            "{}: the port failed: {e}; every device on it is \"no reply\" until it is back; \
             opening it again in {} s",
            self.target,
            wait.as_secs()
        );
        self.failure.get_or_insert((Instant::now(), e.to_string()));
    }
}

/// Devices answered in memory; burst messages are published when due.
pub struct MemoryLoop {
    devices: Vec<hart_device::Device>,
    start: Instant,
    faults: Faults,
    counters: LineCounters,
}

/// How a babbling device disturbs a [`MemoryLoop`] ([`Faults::set_babble`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Babble {
    /// Nobody babbles.
    #[default]
    Quiet,
    /// Garbage on the line: every reply is lost in it (three damaged frames heard per
    /// request).
    Garbage,
    /// Burst frames without pause (fifty heard per turn of the loop's task).
    Bursts,
    /// The first device answers at every polling address.
    AnswersEveryAddress,
}

#[derive(Default)]
struct FaultState {
    off: std::collections::HashSet<u8>,
    babble: Babble,
}

/// Fault hooks of a [`MemoryLoop`], for tests: devices taken off the loop (by polling
/// address) answer nothing until put back; a babbling device disturbs the loop.
#[derive(Clone, Default)]
pub struct Faults(std::sync::Arc<std::sync::Mutex<FaultState>>);

impl Faults {
    fn state(&self) -> std::sync::MutexGuard<'_, FaultState> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Takes the device at polling address `poll` off the loop (`false`) or puts it
    /// back (`true`).
    pub fn set_connected(&self, poll: u8, connected: bool) {
        let mut s = self.state();
        if connected {
            s.off.remove(&poll);
        } else {
            s.off.insert(poll);
        }
    }

    /// Starts (or, with [`Babble::Quiet`], stops) a babbling device.
    pub fn set_babble(&self, babble: Babble) {
        self.state().babble = babble;
    }

    fn is_off(&self, poll: u8) -> bool {
        self.state().off.contains(&poll)
    }

    fn babble(&self) -> Babble {
        self.state().babble
    }
}

impl MemoryLoop {
    /// A loop of `devices`.
    pub fn new(devices: Vec<hart_device::Device>) -> Self {
        MemoryLoop {
            devices,
            start: Instant::now(),
            faults: Faults::default(),
            counters: LineCounters::default(),
        }
    }

    /// The loop's fault hooks.
    pub fn faults(&self) -> Faults {
        self.faults.clone()
    }

    fn now(&self) -> u64 {
        self.start.elapsed().as_micros() as u64
    }
}

impl Line {
    /// A line through `client`.
    pub fn client(client: Client<AnyTransport>) -> Self {
        Line::Client(Box::new(client))
    }

    /// A line on the port `target` names, opened now (a port that cannot be opened at
    /// the start is an error) and opened again whenever it fails later.
    pub async fn open(target: &str) -> Result<Self, String> {
        let t = hart_host::target::open_async(target).await?;
        Ok(Line::Port(Box::new(Reopening {
            target: target.to_string(),
            client: Some(Client::new(t)),
            backoff: hart_host::reconnect::Backoff::ports(),
            failure: None,
        })))
    }

    /// Why the line's port is down now, when it is.
    pub fn failure(&self) -> Option<String> {
        match self {
            Line::Port(p) => p.failure.as_ref().map(|(_, e)| e.clone()),
            _ => None,
        }
    }

    /// Sends `pdu` with `retries` after no reply; the reply's PDU, or `None`.
    pub async fn transact(&mut self, pdu: &[u8], retries: u8) -> Option<Vec<u8>> {
        match self {
            Line::Client(c) => {
                c.set_policy(RetryPolicy {
                    retries,
                    ..RetryPolicy::default()
                });
                c.forward(pdu).await.ok()
            }
            Line::Port(p) => {
                let c = p.client().await?;
                c.set_policy(RetryPolicy {
                    retries,
                    ..RetryPolicy::default()
                });
                match c.forward(pdu).await {
                    Ok(r) => Some(r),
                    Err(hart_host::HostError::Io(e)) => {
                        p.failed(&e);
                        None
                    }
                    Err(_) => None,
                }
            }
            Line::Memory(m) => {
                let t = m.now();
                let babble = m.faults.babble();
                if babble == Babble::Garbage {
                    m.counters.damaged += 3;
                    return None;
                }
                let reply = answer(&mut m.devices, &m.faults, babble, pdu, t);
                if reply.is_some() {
                    m.counters.completed += 1;
                }
                reply
            }
        }
    }

    /// What the line has heard since it was opened: replies, damaged frames, bursts
    /// (for [`crate::disturbance::Disturbance`]).
    pub fn counters(&self) -> LineCounters {
        let of = |s: hart_link::master::MasterStats| LineCounters {
            completed: s.completed,
            damaged: s.damaged,
            bursts: s.bursts,
        };
        match self {
            Line::Client(c) => of(c.stats()),
            Line::Port(p) => p
                .client
                .as_ref()
                .map_or_else(LineCounters::default, |c| of(c.stats())),
            Line::Memory(m) => m.counters,
        }
    }

    /// Whether requests are answered in memory (no line time to share).
    pub fn is_memory(&self) -> bool {
        matches!(self, Line::Memory(_))
    }

    /// Nothing else to do: listen to the line for a moment (burst frames).
    pub async fn idle(&mut self) {
        match self {
            Line::Client(c) => {
                let _ = c.listen(20_000).await;
            }
            Line::Port(p) => match p.client().await {
                Some(c) => {
                    if let Err(hart_host::HostError::Io(e)) = c.listen(20_000).await {
                        p.failed(&e);
                    }
                }
                // Down: wait a little instead of turning fast.
                None => tokio::time::sleep(Duration::from_millis(50)).await,
            },
            Line::Memory(_) => {}
        }
    }

    /// Burst frames heard (or, in memory, due) since the last call.
    pub fn take_bursts(&mut self) -> Vec<Vec<u8>> {
        match self {
            Line::Client(c) => c.take_bursts(),
            Line::Port(p) => p.client.as_mut().map_or(vec![], |c| c.take_bursts()),
            Line::Memory(m) => {
                use hart_link::slave::Handler;
                let t = m.now();
                let mut out = vec![];
                if m.faults.babble() == Babble::Bursts {
                    // A stranger's command 1 burst frames, back to back.
                    let pv = Response::ReadPrimaryVariable(ReadPvResponse {
                        pv_units: UnitCode(12),
                        pv: 50.0,
                    });
                    let data = pv.to_vec().unwrap_or_default();
                    let flood = pdu(&FrameSpec {
                        frame_type: FrameType::Back,
                        status: Some((0, 0)),
                        ..FrameSpec::request(
                            Address::long(hart_proto::frame::UniqueId::new(0x26F3, 0x0B_AB1E))
                                .with_burst(true),
                            1,
                            &data,
                        )
                    });
                    out.extend(std::iter::repeat_n(flood, 50));
                    m.counters.bursts += 50;
                }
                for d in &mut m.devices {
                    if d.burst_mode() && d.burst_due(t).is_some_and(|due| due <= t) {
                        let mut reply = hart_link::slave::Reply::default();
                        let master = d.burst_master();
                        let command = d.burst(&mut reply, t);
                        let id = d.unique_id();
                        out.push(pdu(&FrameSpec {
                            frame_type: FrameType::Back,
                            status: Some((reply.response_code, reply.device_status)),
                            ..FrameSpec::request(
                                Address::long(id).with_burst(true).with_master(master),
                                command,
                                reply.data(),
                            )
                        }));
                        d.set_burst_master(master.other());
                    }
                }
                out
            }
        }
    }

    /// The sub-devices of the I/O system `io` on this line (commands 74 and 84), but
    /// those in `skip`; none in memory.
    pub async fn sub_devices(
        &mut self,
        io: hart_proto::frame::UniqueId,
        skip: &[hart_proto::frame::UniqueId],
    ) -> Vec<hart_host::DeviceInfo> {
        match self {
            Line::Client(c) => {
                c.set_policy(RetryPolicy::default());
                c.sub_devices(io, skip).await
            }
            Line::Port(p) => match p.client().await {
                Some(c) => {
                    c.set_policy(RetryPolicy::default());
                    c.sub_devices(io, skip).await
                }
                None => vec![],
            },
            Line::Memory(_) => vec![],
        }
    }

    /// How long to wait for requests before [`Line::idle`].
    pub fn idle_wait(&self) -> Duration {
        Duration::from_millis(20)
    }
}

/// The PDU of `spec` (no preambles); empty if it cannot be encoded.
pub fn pdu(spec: &FrameSpec<'_>) -> Vec<u8> {
    hart_proto::frame::FrameBuf::encode(spec).map_or_else(|_| vec![], |b| b.as_slice().to_vec())
}

/// The reply of the device a request frame addresses, as its data-link slave would
/// accept it (polling address; unique ID; the broadcast address for commands 11 and 21,
/// which only the device with that tag answers), or `None` when none answers.
fn answer(
    devices: &mut [hart_device::Device],
    faults: &Faults,
    babble: Babble,
    request: &[u8],
    t: u64,
) -> Option<Vec<u8>> {
    let f = Frame::parse_pdu(request).ok()?;
    let first = devices.first().map(|d| d.config().polling_address);
    devices
        .iter_mut()
        .filter(|d| !faults.is_off(d.config().polling_address))
        .filter(|d| match f.address {
            Address::Short(_)
                if babble == Babble::AnswersEveryAddress
                    && Some(d.config().polling_address) == first =>
            {
                true
            }
            Address::Short(a) => a.polling_address == d.config().polling_address,
            Address::Long(a) => {
                a.id == d.unique_id() || (a.id.is_broadcast() && matches!(f.command_byte, 11 | 21))
            }
        })
        .find_map(|d| {
            let (code, status, data) = d.handle(&f, t)?;
            Some(pdu(&FrameSpec {
                frame_type: FrameType::Ack,
                extended: f.extended,
                status: Some((code, status)),
                ..FrameSpec::request(f.address.with_burst(d.burst_mode()), f.command, &data)
            }))
        })
}
