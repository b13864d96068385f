//! # hart-poller
//!
//! The polling engine of hartkit's gateway. It owns the HART loops (serial modems,
//! RS-485 lines, HART-IP servers upstream, simulated plants): one task per loop finds
//! the devices (a scan of polling addresses, command 0, and the sub-devices of I/O
//! systems), polls each one's dynamic variables (command 3 or 9), its status (command
//! 48 when it has more) and its configuration (command 15, tags), and listens for burst
//! messages, into one current [`Image`] per device with a time stamp and a
//! [`Quality`]. Front ends (HART-IP, Modbus, OPC UA) read the image without touching
//! the loop, and hand the loop their requests ([`Engine::forward`]) and writes
//! ([`Engine::write`], ahead of polls).
//!
//! The choices of what goes on the line next ([`schedule::Schedule`], the turn order
//! in `task`) are plain code over time passed in; the tasks run on a
//! `tokio::task::LocalSet` (serial ports and simulated plants stay on one thread).

use std::sync::Arc;

use hart_access::Allowed;
use hart_host::DeviceInfo;
use hart_proto::frame::{Address, Frame};
use tokio::sync::{broadcast, mpsc, watch, Mutex};

pub mod config;
pub mod disturbance;
pub mod gate;
pub mod image;
pub mod lease;
pub mod line;
pub mod request;
pub mod schedule;
mod task;
pub mod write;

pub use config::{DeviceSettings, EngineConfig, LoopSettings, PollSettings, ReadCommand};
pub use disturbance::{Disturbance, LineCounters};
pub use gate::{Denied, Requester};
pub use hart_access::{NotPermitted, WritePolicy, WriteRecord};
pub use hart_access::{Refusal, Rights};
use hart_clock as clock;
/// The engine's one clock (hart-clock's).
pub use hart_clock::Clock;
pub use image::{
    request_pdu, Change, Changes, DeviceImage, DeviceRequest, Image, LastPoll, Quality, RangeInfo,
    Unaddressable, Variable,
};
pub use lease::{LeaseTerms, LoopTest};
pub use line::{Babble, Faults, Line, MemoryLoop, Reopening};
pub use request::{LoopOutcome, LoopRequest, LOOP_QUEUE, MAX_QUEUE_WAIT};
pub use task::{
    FAIR_SHARE, MISSES_TO_FORGET, POLL_RETRIES, POLL_SLOTS_6, POLL_SLOTS_7, RESCAN_IDLE,
    RETRY_DEAD_AFTER, SCAN_GRACE, STOP_RELEASE_TRIES,
};
pub use write::{Applied, DeviceRefusal, WriteFailure, WriteOp};

/// A device found on a loop, for routing requests to it. The engine's list of them
/// is a registry: an entry keeps its place (its index for commands 84 and 102) for the
/// life of the engine. A device that stops answering stays, marked absent; when it
/// answers again it is present at the same place; a new device takes a new place.
#[derive(Debug, Clone)]
pub struct SubDevice {
    /// Channel (loop index).
    pub channel: u8,
    /// What the scan found.
    pub info: DeviceInfo,
    /// Answering: found by the last scan of its address (or since). An absent device
    /// keeps its place and its identity, but no polling address routes to it.
    pub present: bool,
}

/// Frames kept for a traffic watcher that falls behind; older ones are lost to it
/// (counted by its receiver's lag).
pub const TRAFFIC_QUEUE: usize = 4096;

/// What a traffic frame is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrafficKind {
    /// A request the engine sent (a poll, a client's request, a write).
    Request,
    /// The reply to the request before it.
    Reply,
    /// The request before it had no reply after its retries (no bytes).
    NoReply,
    /// A burst message heard on the loop.
    Burst,
}

impl TrafficKind {
    /// `request`, `reply`, `no-reply` or `burst`.
    pub fn name(self) -> &'static str {
        match self {
            TrafficKind::Request => "request",
            TrafficKind::Reply => "reply",
            TrafficKind::NoReply => "no-reply",
            TrafficKind::Burst => "burst",
        }
    }
}

/// One frame on a loop, as the engine saw it: for traffic views (the web dashboard's)
/// and captures. A request retried by the line is shown once, with its reply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TrafficFrame {
    /// Loop (channel) index.
    pub channel: u8,
    /// Wall-clock time on the engine's clock.
    pub time: std::time::SystemTime,
    /// Request, reply, no reply or burst.
    pub kind: TrafficKind,
    /// The frame from its delimiter to its check byte (empty for `NoReply`).
    pub pdu: Vec<u8>,
}

/// What the engine's tasks and handles share.
pub(crate) struct Shared {
    pub(crate) config: EngineConfig,
    pub(crate) loop_names: Vec<String>,
    pub(crate) image: Arc<Image>,
    pub(crate) subs: Arc<Mutex<Vec<SubDevice>>>,
    pub(crate) bursts: broadcast::Sender<Vec<u8>>,
    pub(crate) traffic: broadcast::Sender<Arc<TrafficFrame>>,
    ready: watch::Sender<Vec<bool>>,
    /// Why each loop's port is down, when it is.
    failures: std::sync::Mutex<Vec<Option<String>>>,
    /// Why each loop is disturbed, when it is.
    disturbed: std::sync::Mutex<Vec<Option<String>>>,
    /// The rule for typed writes, and their audit.
    pub(crate) write_policy: WritePolicy,
    /// The same rule as the access policy frames are judged by ([`gate`]).
    pub(crate) frame_policy: hart_access::Policy,
    /// Loop tasks that have ended.
    stopped: watch::Sender<usize>,
    /// One lock per device that typed writes take: a read-modify-write sequence
    /// (command 13 then 18) is never interleaved with another write to the device.
    device_locks: std::sync::Mutex<std::collections::HashMap<usize, Arc<Mutex<()>>>>,
}

impl Shared {
    /// Loop `channel`'s port is down (`Some` with why) or up.
    pub(crate) fn set_failure(&self, channel: u8, failure: Option<String>) {
        let mut f = self.failures.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(slot) = f.get_mut(usize::from(channel)) {
            if *slot != failure {
                *slot = failure;
            }
        }
    }

    /// Loop `channel` is disturbed (`Some` with why) or not; returns whether that
    /// changed.
    pub(crate) fn set_disturbed(&self, channel: u8, reason: Option<&str>) -> bool {
        let mut d = self.disturbed.lock().unwrap_or_else(|e| e.into_inner());
        match d.get_mut(usize::from(channel)) {
            Some(slot) if slot.as_deref() != reason => {
                let was = slot.is_some();
                *slot = reason.map(str::to_string);
                was != reason.is_some()
            }
            _ => false,
        }
    }

    /// A loop's task has ended (its loop tests released).
    pub(crate) fn loop_stopped(&self) {
        self.stopped.send_modify(|n| *n += 1);
    }

    /// Loop `channel` has identified its listed devices and scanned once.
    pub(crate) fn loop_ready(&self, channel: u8) {
        self.ready.send_modify(|r| {
            if let Some(x) = r.get_mut(usize::from(channel)) {
                *x = true;
            }
        });
    }
}

/// A loop to start: its settings and its line.
pub struct LoopSpec {
    /// Settings (name, devices, scan).
    pub settings: LoopSettings,
    /// The line.
    pub line: Line,
}

/// Why a write did not reach the device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WriteError {
    /// No device at that position, or not identified yet.
    UnknownDevice,
    /// The device did not answer.
    NoReply,
    /// The loop was busy: its queue full, or the write waited too long.
    Busy,
    /// The reply was not a HART frame, or reported a communication error.
    BadReply(String),
}

impl std::fmt::Display for WriteError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            WriteError::UnknownDevice => f.write_str(
                "no such device, or not identified yet: check the device list (hartkit serve --print-map)",
            ),
            WriteError::NoReply => f.write_str("the device did not answer; check that it is powered and on the loop"),
            WriteError::Busy => f.write_str("the loop is busy; try again"),
            WriteError::BadReply(e) => write!(f, "bad reply: {e}"),
        }
    }
}

impl std::error::Error for WriteError {}

/// A device's answer to a write.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WriteReply {
    /// Response code.
    pub response_code: u8,
    /// Field device status.
    pub device_status: u8,
    /// Reply data.
    pub data: Vec<u8>,
}

/// How an engine starts, besides its configuration and loops.
#[derive(Debug, Clone)]
pub struct StartOptions {
    /// Client requests queued per loop ([`LOOP_QUEUE`]; in-memory loops take more: no
    /// line time to wait for).
    pub queue: usize,
    /// Where the engine reads the time ([`Clock::system`] by default).
    pub clock: Clock,
    /// The gateway-wide rule for typed writes ([`Engine::apply`]) and their audit
    /// (by default every write may go, recorded on the log only).
    pub write_policy: WritePolicy,
}

impl Default for StartOptions {
    fn default() -> Self {
        StartOptions {
            queue: LOOP_QUEUE,
            clock: Clock::system(),
            write_policy: WritePolicy::default(),
        }
    }
}

/// Writes queued per loop at most (SCADA writes are few; more are answered "busy").
pub const WRITE_QUEUE: usize = 16;

/// A running engine: handles to its loops and image. Cheap to clone.
#[derive(Clone)]
pub struct Engine {
    shared: Arc<Shared>,
    requests: Vec<mpsc::Sender<LoopRequest>>,
    writes: Vec<mpsc::Sender<LoopRequest>>,
    controls: Vec<mpsc::UnboundedSender<task::Control>>,
    ready: watch::Receiver<Vec<bool>>,
}

impl Engine {
    /// Starts one task per loop; call it inside a `tokio::task::LocalSet`. Devices
    /// listed in the loops' settings take the first positions of the image, in order.
    pub fn start(
        config: EngineConfig,
        loops: Vec<LoopSpec>,
    ) -> (Engine, Vec<tokio::task::JoinHandle<()>>) {
        Self::start_with_queue(config, loops, LOOP_QUEUE)
    }

    /// [`Engine::start`] with client request queues of `queue` (in-memory loops take
    /// more: no line time to wait for).
    pub fn start_with_queue(
        config: EngineConfig,
        loops: Vec<LoopSpec>,
        queue: usize,
    ) -> (Engine, Vec<tokio::task::JoinHandle<()>>) {
        Self::start_with(
            config,
            loops,
            StartOptions {
                queue,
                ..StartOptions::default()
            },
        )
    }

    /// [`Engine::start`] with [`StartOptions`]: the queue length and the clock.
    pub fn start_with(
        config: EngineConfig,
        loops: Vec<LoopSpec>,
        options: StartOptions,
    ) -> (Engine, Vec<tokio::task::JoinHandle<()>>) {
        let StartOptions {
            queue,
            clock,
            write_policy,
        } = options;
        let loop_names: Vec<String> = loops
            .iter()
            .enumerate()
            .map(|(i, l)| {
                l.settings
                    .name
                    .clone()
                    .unwrap_or_else(|| format!("loop{}", i + 1))
            })
            .collect();
        let image = Arc::new(Image::with_clock(clock));
        for (channel, l) in loops.iter().enumerate() {
            for dev in &l.settings.device {
                let (period, _) = config.device_settings(&l.settings, Some(dev));
                let mut d = DeviceImage::new(
                    0,
                    channel as u8,
                    &loop_names[channel],
                    config.stale_limit(period),
                );
                d.name = dev.name.clone();
                d.polling_address = Some(dev.poll);
                image.push(d);
            }
        }
        let (ready_tx, ready) = watch::channel(vec![false; loops.len()]);
        let shared = Arc::new(Shared {
            config,
            loop_names,
            image,
            subs: Arc::new(Mutex::new(vec![])),
            bursts: broadcast::channel(64).0,
            traffic: broadcast::channel(TRAFFIC_QUEUE).0,
            ready: ready_tx,
            failures: std::sync::Mutex::new(vec![None; loops.len()]),
            disturbed: std::sync::Mutex::new(vec![None; loops.len()]),
            frame_policy: hart_access::Policy {
                allow: write_policy.allow.clone(),
                device_commands: write_policy.device_commands.clone(),
            },
            write_policy,
            stopped: watch::channel(0).0,
            device_locks: Default::default(),
        });
        let mut requests = vec![];
        let mut writes = vec![];
        let mut controls = vec![];
        let mut tasks = vec![];
        for (channel, l) in loops.into_iter().enumerate() {
            let (rtx, rrx) = mpsc::channel(queue.max(1));
            let (wtx, wrx) = mpsc::channel(WRITE_QUEUE);
            let (ctx, crx) = mpsc::unbounded_channel();
            requests.push(rtx);
            writes.push(wtx);
            controls.push(ctx);
            let t = task::LoopTask::new(
                channel as u8,
                l.settings,
                l.line,
                shared.clone(),
                rrx,
                wrx,
                crx,
            );
            tasks.push(tokio::task::spawn_local(t.run()));
        }
        (
            Engine {
                shared,
                requests,
                writes,
                controls,
                ready,
            },
            tasks,
        )
    }

    /// The frames on every loop from now on ([`TrafficFrame`]); costs nothing while
    /// no one subscribes. A receiver that falls more than [`TRAFFIC_QUEUE`] frames
    /// behind loses the oldest.
    pub fn traffic(&self) -> broadcast::Receiver<Arc<TrafficFrame>> {
        self.shared.traffic.subscribe()
    }

    /// The current image.
    pub fn image(&self) -> &Arc<Image> {
        &self.shared.image
    }

    /// The rule its typed writes follow ([`Engine::apply`]), and their audit.
    pub fn write_policy(&self) -> &WritePolicy {
        &self.shared.write_policy
    }

    /// The engine's clock: "now" for the image's qualities and ages.
    pub fn clock(&self) -> &Clock {
        self.shared.image.clock()
    }

    /// Devices found on the loops, for routing (HART-IP).
    pub fn sub_devices(&self) -> &Arc<Mutex<Vec<SubDevice>>> {
        &self.shared.subs
    }

    /// Burst frames heard on any loop (PDUs).
    pub fn bursts(&self) -> &broadcast::Sender<Vec<u8>> {
        &self.shared.bursts
    }

    /// Loops, in channel order.
    pub fn loop_count(&self) -> usize {
        self.requests.len()
    }

    /// The name of loop `channel`.
    pub fn loop_name(&self, channel: usize) -> Option<&str> {
        self.shared.loop_names.get(channel).map(String::as_str)
    }

    /// Why loop `channel`'s port is down (it is being opened again), or `None` while
    /// it works.
    pub fn loop_failure(&self, channel: usize) -> Option<String> {
        self.shared
            .failures
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(channel)
            .cloned()
            .flatten()
    }

    /// Why loop `channel` is disturbed (a device babbles on it: every device there is
    /// [`Quality::LoopDisturbed`]), or `None` while it is not.
    pub fn loop_disturbed(&self, channel: usize) -> Option<String> {
        self.shared
            .disturbed
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(channel)
            .cloned()
            .flatten()
    }

    /// The engine's settings.
    pub fn config(&self) -> &EngineConfig {
        &self.shared.config
    }

    /// Waits until every loop has tried its listed devices (when it lists some) or
    /// scanned once (when it lists none): the device list's first positions are then
    /// known.
    pub async fn ready(&self) {
        let mut rx = self.ready.clone();
        let _ = rx.wait_for(|r| r.iter().all(|&x| x)).await;
    }

    /// Stops the engine: every loop's task releases its loop tests ([`lease`]: command
    /// 40 with 0 mA, each tried [`task::STOP_RELEASE_TRIES`] times), then ends; the
    /// image is closed after the last commit, so every change subscription
    /// ([`Image::changes`]) ends once its subscriber has received everything. Waits
    /// for every loop; call it after the front ends that write have stopped.
    pub async fn stop(&self) {
        for c in &self.controls {
            let _ = c.send(task::Control::Stop);
        }
        let loops = self.controls.len();
        let mut stopped = self.shared.stopped.subscribe();
        let _ = stopped.wait_for(|n| *n >= loops).await;
        self.shared.image.close();
    }

    /// The write lock of the device at `position`.
    pub(crate) fn device_lock(&self, position: usize) -> Arc<Mutex<()>> {
        self.shared
            .device_locks
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry(position)
            .or_default()
            .clone()
    }

    /// Releases the loop tests held by `holder` ([`LeaseTerms::holder`]): a PROFIBUS
    /// master whose watchdog expired, a Sparkplug primary host gone offline.
    pub fn release_held_by(&self, holder: &str) {
        for c in &self.controls {
            let _ = c.send(task::Control::HolderGone(holder.to_string()));
        }
    }

    /// Carries a request PDU a client composed to loop `channel` with `retries`,
    /// between polls, through the gateway's one gate ([`gate`]): the frame is judged by
    /// the gateway's rule with `from`'s rights (every level of command 77 inside it),
    /// and a frame that writes is recorded in the audit before it goes and again with
    /// the device's answer (the innermost reply of a command 77). A refused frame is
    /// not sent ([`Denied`], audited as `not-permitted` when `from` may write, so the
    /// refusal is the gateway's rule and not the requester's own rights). Never waits
    /// for room in the queue: a full queue answers [`LoopOutcome::Busy`].
    pub async fn forward(
        &self,
        channel: usize,
        pdu: Vec<u8>,
        retries: u8,
        from: &Requester,
    ) -> Result<LoopOutcome, Denied> {
        let verdict = {
            let frame = Frame::parse_pdu(&pdu).map_err(|e| Denied::NotAFrame(e.to_string()))?;
            let device_type = match gate::device_type_of(&frame.address) {
                Some(t) => Some(t),
                None => self.device_type_at(channel, &frame.address).await,
            };
            match gate::judge(
                &self.shared.frame_policy,
                self.shared.write_policy.read_only,
                from.rights,
                &frame,
                device_type,
            ) {
                Ok(a) => a,
                Err(why) => {
                    if from.rights.may_write() {
                        let record =
                            gate::record_of(from, frame.address.to_string(), frame.command, 0);
                        self.shared
                            .write_policy
                            .audit
                            .refused(&record, &why.to_string());
                    }
                    return Err(Denied::Policy(why));
                }
            }
        };
        let Some(queue) = self.requests.get(channel) else {
            return Ok(LoopOutcome::NoReply);
        };
        let Allowed::Write(target) = verdict else {
            return Ok(request::submit(queue, pdu, retries, LeaseTerms::default()).await);
        };
        let record = gate::record_of(from, target.device, target.command, target.depth);
        let audit = &self.shared.write_policy.audit;
        let id = audit.record(&record);
        let lease = LeaseTerms {
            by: format!("{} from {}", record.front_end, record.peer),
            ..LeaseTerms::default()
        };
        let outcome = request::submit(queue, pdu, retries, lease).await;
        let written = match &outcome {
            LoopOutcome::Reply(r) => gate::outcome(target.command, target.depth, Some(r)),
            LoopOutcome::NoReply => gate::outcome(target.command, target.depth, None),
            LoopOutcome::Busy => hart_access::WriteOutcome::Failed(
                "not sent: the loop was busy (the client was answered busy)".into(),
            ),
        };
        audit.outcome(id, &record, &written);
        Ok(outcome)
    }

    /// The expanded device type of the device at short `address` on loop `channel`,
    /// when one device found there has that polling address.
    async fn device_type_at(&self, channel: usize, address: &Address) -> Option<u16> {
        let Address::Short(a) = address else {
            return None;
        };
        let subs = self.shared.subs.lock().await;
        let mut found = subs.iter().filter(|s| {
            s.present
                && usize::from(s.channel) == channel
                && s.info.polling_address == Some(a.polling_address)
        });
        match (found.next(), found.next()) {
            (Some(s), None) => Some(s.info.unique_id().expanded_device_type),
            _ => None,
        }
    }

    /// Sends `request` to the device at image `position`, ahead of every poll and
    /// client request of its loop, and returns the device's answer (whatever its
    /// response code: the caller judges it). After a write that changes the
    /// configuration, the engine reads the device's configuration again. Not public:
    /// every write goes through [`Engine::apply`], which asks the policy and audits.
    pub(crate) async fn write(
        &self,
        position: usize,
        request: &hart_proto::Request,
        lease: LeaseTerms,
    ) -> Result<WriteReply, WriteFailure> {
        let built = self
            .shared
            .image
            .request_for(position, request)
            .map_err(|e| match e {
                image::Unaddressable::Encode(e) => WriteFailure::Invalid(e.to_string()),
                _ => WriteFailure::Link(WriteError::UnknownDevice),
            })?;
        let queue = self
            .writes
            .get(usize::from(built.channel))
            .ok_or(WriteFailure::Link(WriteError::UnknownDevice))?;
        write_reply(request::submit(queue, built.pdu, POLL_RETRIES, lease).await)
            .map_err(WriteFailure::Link)
    }
}

/// What a write's [`LoopOutcome`] means: the device's answer, or why there is none.
fn write_reply(outcome: LoopOutcome) -> Result<WriteReply, WriteError> {
    match outcome {
        LoopOutcome::Busy => Err(WriteError::Busy),
        LoopOutcome::NoReply => Err(WriteError::NoReply),
        LoopOutcome::Reply(r) => {
            let f = Frame::parse_pdu(&r).map_err(|e| WriteError::BadReply(e.to_string()))?;
            if f.is_communication_error() {
                return Err(WriteError::BadReply(format!(
                    "the device reports a communication error ({:#04x}); check the loop's wiring and noise",
                    f.response_code.unwrap_or(0)
                )));
            }
            Ok(WriteReply {
                response_code: f.response_code.unwrap_or(0),
                device_status: f.device_status.unwrap_or(0),
                data: f.data.to_vec(),
            })
        }
    }
}

/// Adds a sub-device to the registry, or updates the one with the same unique ID
/// (present again, at its place). A different device now answering at a polling
/// address takes a new place; the one seen there before stays, absent, without that
/// polling address.
pub(crate) async fn remember(subs: &Mutex<Vec<SubDevice>>, sub: SubDevice) {
    let mut subs = subs.lock().await;
    if let Some(p) = sub.info.polling_address {
        for s in subs.iter_mut().filter(|s| {
            s.channel == sub.channel
                && s.info.polling_address == Some(p)
                && s.info.unique_id() != sub.info.unique_id()
        }) {
            s.present = false;
            s.info.polling_address = None;
        }
    }
    match subs
        .iter_mut()
        .find(|s| s.info.unique_id() == sub.info.unique_id())
    {
        Some(s) => {
            let old = std::mem::replace(s, sub);
            // Keep what the new sighting did not learn.
            s.info.polling_address = s.info.polling_address.or(old.info.polling_address);
            s.info.tag = s.info.tag.take().or(old.info.tag);
            s.info.descriptor = s.info.descriptor.take().or(old.info.descriptor);
            s.info.long_tag = s.info.long_tag.take().or(old.info.long_tag);
            s.info.io_channel = s.info.io_channel.or(old.info.io_channel);
        }
        None => subs.push(sub),
    }
}

/// Marks the devices of `channel` at polling address `poll` absent (they stopped
/// answering): they keep their places.
pub(crate) async fn forget(subs: &Mutex<Vec<SubDevice>>, channel: u8, poll: u8) {
    for s in subs
        .lock()
        .await
        .iter_mut()
        .filter(|s| s.channel == channel && s.info.polling_address == Some(poll))
    {
        s.present = false;
    }
}
