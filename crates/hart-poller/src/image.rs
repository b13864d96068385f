//! The current image: what the engine last learned of every device, with a time stamp
//! and a quality, read by the front ends (Modbus, OPC UA) without touching the loop.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, RwLock, Weak};
use std::time::{Duration, Instant, SystemTime};

use hart_host::DeviceInfo;
use hart_proto::command::{
    DeviceInformation, ReadAdditionalStatusResponse, ReadDeviceVariablesResponse,
    ReadDynamicVariablesResponse, ReadLoopCurrentResponse,
};
use hart_proto::frame::UniqueId;
use hart_proto::tables::field_device_status as fds;
use hart_proto::wire::{Reader, Wire};
use tokio::sync::broadcast;

use crate::clock::Clock;

/// How good a device's values are, as a SCADA reads it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Quality {
    /// The last poll was answered and the device reports no malfunction.
    Good,
    /// The values are older than the device's stale limit: the loop has not polled it
    /// in time (busy with other requests, or a slow loop for its poll period).
    Stale,
    /// The device did not answer its last poll.
    NoReply,
    /// The device answers but sets "device malfunction" in its status.
    DeviceMalfunction,
    /// The device's configuration changed since the engine last read it (range, units,
    /// tag): the values are current, the engine is reading the new configuration.
    ConfigurationChanged,
    /// The engine has not asked the device yet (the gateway just started, or the
    /// device was just found): no value, and no failure either.
    WaitingForData,
    /// The device's loop is disturbed: a device on it babbles (garbage, burst frames
    /// without pause, answers at addresses not its own), so values read on it may be
    /// wrong or another device's.
    LoopDisturbed,
}

impl Quality {
    /// Every quality, in code order.
    pub const ALL: [Quality; 7] = [
        Quality::Good,
        Quality::Stale,
        Quality::NoReply,
        Quality::DeviceMalfunction,
        Quality::ConfigurationChanged,
        Quality::WaitingForData,
        Quality::LoopDisturbed,
    ];

    /// The quality of a published code ([`Quality::code`]).
    pub fn from_code(code: u16) -> Option<Quality> {
        Quality::ALL.into_iter().find(|q| q.code() == code)
    }

    /// The number front ends publish (Modbus register 13): 0 good, 1 stale, 2 no
    /// reply, 3 device malfunction, 4 configuration changed, 5 waiting for first data,
    /// 6 loop disturbed.
    pub fn code(self) -> u16 {
        match self {
            Quality::Good => 0,
            Quality::Stale => 1,
            Quality::NoReply => 2,
            Quality::DeviceMalfunction => 3,
            Quality::ConfigurationChanged => 4,
            Quality::WaitingForData => 5,
            Quality::LoopDisturbed => 6,
        }
    }

    /// The name used in JSON and logs.
    pub fn name(self) -> &'static str {
        match self {
            Quality::Good => "good",
            Quality::Stale => "stale",
            Quality::NoReply => "no reply",
            Quality::DeviceMalfunction => "device malfunction",
            Quality::ConfigurationChanged => "configuration changed",
            Quality::WaitingForData => "waiting for first data",
            Quality::LoopDisturbed => "loop disturbed",
        }
    }

    /// Whether the values may be used (good, or good with a changed configuration).
    pub fn usable(self) -> bool {
        matches!(self, Quality::Good | Quality::ConfigurationChanged)
    }
}

impl std::fmt::Display for Quality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A process value with its units (HART Common Table 2 code).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Variable {
    /// The value (NaN when the device reports none).
    pub value: f32,
    /// Units code.
    pub units: u8,
    /// Device variable status (command 9 only).
    pub status: Option<u8>,
}

/// The PV range and damping (command 15).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangeInfo {
    /// Units code of the range values.
    pub units: u8,
    /// Upper range value (20 mA).
    pub upper: f32,
    /// Lower range value (4 mA).
    pub lower: f32,
    /// PV damping, s.
    pub damping: f32,
    /// Write protect code (0 not protected, 1 protected, 250/251 none).
    pub write_protect: u8,
    /// PV transfer function (Common Table 3: 0 linear, 1 square root, ...).
    pub transfer_function: u8,
}

/// The result of the last poll.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LastPoll {
    /// Not polled yet.
    Pending,
    /// Answered.
    Answered,
    /// No reply after the retries.
    NoReply,
}

/// What the engine knows of one device.
#[derive(Debug, Clone)]
pub struct DeviceImage {
    /// Position in the device list: Modbus unit id 1 + position. Configured devices
    /// come first in the order of the configuration, then devices found by the scan in
    /// the order found. Positions never change while the engine runs.
    pub position: usize,
    /// Loop (channel) index.
    pub channel: u8,
    /// The loop's name.
    pub loop_name: String,
    /// A name given in the configuration (OPC UA browse name), if any.
    pub name: Option<String>,
    /// The polling address the configuration gives, or where the scan found it.
    pub polling_address: Option<u8>,
    /// Identity and tags; `None` for a configured device not found yet.
    pub info: Option<DeviceInfo>,
    /// PV, SV, TV, QV.
    pub variables: [Option<Variable>; 4],
    /// Loop current, mA.
    pub loop_current: Option<f32>,
    /// PV percent of range.
    pub percent_range: Option<f32>,
    /// Field device status byte of the last reply.
    pub device_status: u8,
    /// Extended device status (command 9 or 48).
    pub extended_status: u8,
    /// The last command 48 reply data (empty until read).
    pub additional_status: Vec<u8>,
    /// PV range and damping (command 15), when read.
    pub range: Option<RangeInfo>,
    /// The loop current the device holds in fixed current mode, when the gateway set
    /// it (command 40) and the device reports "loop current fixed".
    pub fixed_current: Option<f32>,
    /// Wall-clock time of the values (source time stamp).
    pub updated: Option<SystemTime>,
    /// When the last good reply came.
    pub last_good: Option<Instant>,
    /// What the last poll gave.
    pub last_poll: LastPoll,
    /// The configuration-changed bit has been seen and not yet acted on.
    pub config_changed_pending: bool,
    /// Values older than this are stale.
    pub stale_after: Duration,
    /// Polls sent and polls unanswered.
    pub polls: u64,
    /// Polls without a reply.
    pub failures: u64,
    /// The device's loop is disturbed ([`Quality::LoopDisturbed`]).
    pub loop_disturbed: bool,
    /// The loop test the engine holds for it ([`crate::lease`]): its fixed current,
    /// when it is released, and whether a release already failed (an alarm).
    pub loop_test: Option<crate::lease::LoopTest>,
    /// Its going stale has been committed as a change (cleared by the next good
    /// reply): staleness comes with time alone, so the loop's task commits it, and
    /// subscribers of [`Image::changes`] see it without reading the image on a timer.
    pub stale_committed: bool,
}

impl DeviceImage {
    /// An empty image at `position`.
    pub fn new(position: usize, channel: u8, loop_name: &str, stale_after: Duration) -> Self {
        DeviceImage {
            position,
            channel,
            loop_name: loop_name.to_string(),
            name: None,
            polling_address: None,
            info: None,
            variables: [None; 4],
            loop_current: None,
            percent_range: None,
            device_status: 0,
            extended_status: 0,
            additional_status: vec![],
            range: None,
            fixed_current: None,
            updated: None,
            last_good: None,
            last_poll: LastPoll::Pending,
            config_changed_pending: false,
            stale_after,
            polls: 0,
            failures: 0,
            loop_disturbed: false,
            loop_test: None,
            stale_committed: false,
        }
    }

    /// The one time stamp of the device's values, for every front end and the
    /// historian: the reply's (`updated`) while they are the device's answer (good,
    /// configuration changed, device malfunction); `otherwise` (the time of the change
    /// or of the sample) when they are not (no reply, stale, waiting, disturbed), so a
    /// change of quality never shares a time stamp with the values it replaces.
    pub fn value_time(&self, quality: Quality, otherwise: SystemTime) -> SystemTime {
        match quality {
            Quality::Good | Quality::ConfigurationChanged | Quality::DeviceMalfunction => {
                self.updated.unwrap_or(otherwise)
            }
            _ => otherwise,
        }
    }

    /// The device's unique ID, once identified.
    pub fn unique_id(&self) -> Option<UniqueId> {
        self.info.as_ref().map(|i| i.unique_id())
    }

    /// The quality at `now`.
    pub fn quality(&self, now: Instant) -> Quality {
        if self.loop_disturbed {
            return Quality::LoopDisturbed;
        }
        match self.last_poll {
            LastPoll::Pending => Quality::WaitingForData,
            LastPoll::NoReply => Quality::NoReply,
            LastPoll::Answered => {
                if self
                    .last_good
                    .is_none_or(|t| now.saturating_duration_since(t) > self.stale_after)
                {
                    Quality::Stale
                } else if self.device_status & fds::DEVICE_MALFUNCTION != 0 {
                    Quality::DeviceMalfunction
                } else if self.config_changed_pending {
                    Quality::ConfigurationChanged
                } else {
                    Quality::Good
                }
            }
        }
    }

    /// Whole seconds since the last good reply; `None` before the first.
    pub fn seconds_since_good(&self, now: Instant) -> Option<u32> {
        self.last_good.map(|t| {
            now.saturating_duration_since(t)
                .as_secs()
                .min(u64::from(u32::MAX - 1)) as u32
        })
    }

    /// A name for the device: the configured name, the long tag, the tag, or the
    /// polling address, whichever is known first.
    pub fn display_name(&self) -> String {
        let nonblank = |s: &Option<String>| {
            s.as_deref()
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(str::to_string)
        };
        if let Some(n) = nonblank(&self.name) {
            return n;
        }
        if let Some(info) = &self.info {
            if let Some(t) = nonblank(&info.long_tag).or_else(|| nonblank(&info.tag)) {
                return t;
            }
            return format!("device-{}", info.unique_id());
        }
        match self.polling_address {
            Some(p) => format!("poll-{p}"),
            None => format!("device-{}", self.position + 1),
        }
    }

    /// Records a reply to a read command (1, 2, 3, 9, 15, 48, from a poll or a burst
    /// message) received at `now`/`wall`. Returns whether the reply carried values
    /// this image keeps.
    pub fn apply_reply(
        &mut self,
        command: u16,
        response_code: u8,
        device_status: u8,
        data: &[u8],
        now: Instant,
        wall: SystemTime,
    ) -> bool {
        use hart_proto::tables::{response_class, ResponseClass};
        self.device_status = device_status;
        if device_status & fds::LOOP_CURRENT_FIXED == 0 {
            self.fixed_current = None;
        }
        if response_class(response_code) == ResponseClass::Error {
            return false;
        }
        let mut r = Reader::new(data);
        let kept = match command {
            1 => match hart_proto::command::ReadPvResponse::decode(&mut r) {
                Ok(v) => {
                    self.variables[0] = Some(Variable {
                        value: v.pv,
                        units: v.pv_units.0,
                        status: None,
                    });
                    true
                }
                Err(_) => false,
            },
            2 => match ReadLoopCurrentResponse::decode(&mut r) {
                Ok(v) => {
                    self.loop_current = Some(v.loop_current.0);
                    self.percent_range = Some(v.percent_of_range.0);
                    true
                }
                Err(_) => false,
            },
            3 => match ReadDynamicVariablesResponse::decode(&mut r) {
                Ok(v) => {
                    self.loop_current = Some(v.loop_current.0);
                    for (i, slot) in self.variables.iter_mut().enumerate() {
                        *slot = v.variables.as_slice().get(i).map(|u| Variable {
                            value: u.value,
                            units: u.units.0,
                            status: None,
                        });
                    }
                    true
                }
                Err(_) => false,
            },
            9 => self.apply_slots(data),
            15 => match DeviceInformation::decode(&mut r) {
                Ok(d) => {
                    self.range = Some(RangeInfo {
                        units: d.range_units.0,
                        upper: d.upper_range_value,
                        lower: d.lower_range_value,
                        damping: d.damping.0,
                        write_protect: d.write_protect.0,
                        transfer_function: d.transfer_function.0,
                    });
                    true
                }
                Err(_) => false,
            },
            48 => {
                self.additional_status = data.to_vec();
                let status = ReadAdditionalStatusResponse::decode(&mut r).ok();
                if let Some(x) = status.and_then(|s| s.additional_status.extended_status()) {
                    self.extended_status = x.0;
                }
                true
            }
            _ => false,
        };
        if kept && matches!(command, 1 | 3 | 15) {
            self.percent_range = self.percent_from_range().or(self.percent_range);
        }
        if kept && matches!(command, 1 | 2 | 3 | 9) {
            self.updated = Some(wall);
            self.last_good = Some(now);
            self.stale_committed = false;
            self.last_poll = LastPoll::Answered;
        }
        kept
    }

    /// The PV's percent of range from its range values (command 15), for a linear
    /// transfer function with the range in the PV's units: what command 2 would
    /// report, without its line time. (Commands 1 and 3 do not carry it.)
    fn percent_from_range(&self) -> Option<f32> {
        let r = self.range?;
        let pv = self.variables[0]?;
        if r.transfer_function != 0 || r.units != pv.units || r.upper == r.lower {
            return None;
        }
        Some((pv.value - r.lower) / (r.upper - r.lower) * 100.0)
    }

    /// Command 9's reply: extended status, then slots. Slots 246-249 are PV..QV,
    /// 244 percent of range, 245 loop current; device variables 0-3 fill PV..QV only
    /// when asked for as such (the engine asks for 246-249).
    fn apply_slots(&mut self, data: &[u8]) -> bool {
        let Ok(reply) = ReadDeviceVariablesResponse::decode(&mut Reader::new(data)) else {
            return false;
        };
        self.extended_status = reply.extended_status.0;
        for slot in reply.data.slots.as_slice() {
            let var = Variable {
                value: slot.value,
                units: slot.units.0,
                status: Some(slot.status.0),
            };
            match slot.code.0 {
                244 => self.percent_range = Some(slot.value),
                245 => self.loop_current = Some(slot.value),
                c @ 246..=249 => self.variables[usize::from(c - 246)] = Some(var),
                _ => {}
            }
        }
        true
    }

    /// Records a poll without a reply.
    pub fn no_reply(&mut self) {
        self.last_poll = LastPoll::NoReply;
        self.failures += 1;
    }
}

/// One commit of a device's image: the whole image as it was just after the change,
/// so a subscriber sees a consistent device (a new PV never beside an old range) and
/// the value it had then, however late it reads.
#[derive(Debug, Clone)]
pub struct Change {
    /// The device's image after the change (its position is inside).
    pub device: Arc<DeviceImage>,
    /// Its quality at the time of the change.
    pub quality: Quality,
    /// Wall-clock time of the change (the engine's clock).
    pub at: SystemTime,
    /// The engine-wide commit number: increases by one per change, in the order the
    /// changes were made.
    pub seq: u64,
}

impl Change {
    /// The time stamp of the values it carries ([`DeviceImage::value_time`]): the
    /// reply's, or the change's own for a change of quality.
    pub fn value_time(&self) -> SystemTime {
        self.device.value_time(self.quality, self.at)
    }
}

/// What one change subscriber holds: a bounded queue of changes and what it lost.
struct Subscriber {
    queue: Mutex<VecDeque<Change>>,
    capacity: usize,
    dropped: AtomicU64,
    notify: tokio::sync::Notify,
    closed: AtomicBool,
    /// When the last "fell behind" line was logged.
    warned: Mutex<Option<Instant>>,
}

impl Subscriber {
    fn push(&self, change: Change, now: Instant) {
        let mut q = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        let mut lost = 0;
        while q.len() >= self.capacity {
            q.pop_front();
            lost += 1;
        }
        q.push_back(change);
        drop(q);
        if lost > 0 {
            let total = self.dropped.fetch_add(lost, Ordering::Relaxed) + lost;
            let mut warned = self.warned.lock().unwrap_or_else(|e| e.into_inner());
            if warned.is_none_or(|t| now.saturating_duration_since(t) >= Duration::from_secs(60)) {
                *warned = Some(now);
                tracing::warn!(
                    "a change subscriber (history, MQTT) is {} changes behind and lost the \
                     oldest ({total} so far): it cannot keep up with the loops; check the \
                     database or broker it writes to",
                    self.capacity
                );
            }
        }
        self.notify.notify_one();
    }
}

/// A subscription to every change of the image, in commit order ([`Image::changes`]).
/// It holds at most its capacity of changes not yet received; when the subscriber
/// falls further behind, the oldest are dropped, counted ([`Changes::dropped`]) and
/// logged, never silently.
pub struct Changes {
    sub: Arc<Subscriber>,
}

impl Changes {
    /// The next change; `None` once the engine has stopped and every change has been
    /// received.
    pub async fn recv(&mut self) -> Option<Change> {
        loop {
            if let Some(c) = self.try_recv() {
                return Some(c);
            }
            if self.sub.closed.load(Ordering::Acquire) {
                return self.try_recv();
            }
            self.sub.notify.notified().await;
        }
    }

    /// The next change if one is waiting.
    pub fn try_recv(&mut self) -> Option<Change> {
        self.sub
            .queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop_front()
    }

    /// Changes waiting.
    pub fn len(&self) -> usize {
        self.sub
            .queue
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .len()
    }

    /// Whether no change is waiting.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Changes lost because this subscriber fell more than its capacity behind.
    pub fn dropped(&self) -> u64 {
        self.sub.dropped.load(Ordering::Relaxed)
    }
}

/// Why no request can be built for an image position ([`Image::request_for`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unaddressable {
    /// No device at that position.
    NoSuchDevice,
    /// Not identified yet (no command 0 reply): its unique ID is not known.
    NotIdentified,
    /// The request does not encode (a typed value breaking its layout's own rule).
    Encode(hart_proto::wire::EncodeError),
}

impl std::fmt::Display for Unaddressable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unaddressable::NoSuchDevice => f.write_str("no such device"),
            Unaddressable::NotIdentified => f.write_str(
                "the device has not been identified yet (it has not answered command 0)",
            ),
            Unaddressable::Encode(e) => write!(f, "the request does not encode: {e}"),
        }
    }
}

impl std::error::Error for Unaddressable {}

/// A request for one device of the image ([`Image::request_for`]): the loop it goes
/// on, the device, and its frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceRequest {
    /// The loop (channel) the device is on.
    pub channel: u8,
    /// The device's unique ID, the frame's address.
    pub unique_id: UniqueId,
    /// The frame, delimiter through check byte, no preambles.
    pub pdu: Vec<u8>,
}

/// The frame [`Image::request_for`] builds, for a device known by its unique ID only
/// (identification and tags before it has a position; an I/O system's sub-device):
/// a long frame from the primary master.
pub fn request_pdu(
    id: UniqueId,
    request: &hart_proto::Request,
) -> Result<Vec<u8>, hart_proto::wire::EncodeError> {
    request
        .frame(hart_proto::frame::Address::long(id))
        .map(|b| b.as_slice().to_vec())
}

/// Every device's image, shared by the engine (which writes) and the front ends (which
/// read). Each change is one commit under the image's lock: announced by position on
/// a broadcast channel ([`Image::subscribe`], for readers that look at the current
/// image) and, whole, to every [`Changes`] subscriber.
pub struct Image {
    devices: RwLock<Vec<DeviceImage>>,
    changes: broadcast::Sender<usize>,
    subscribers: Mutex<Vec<Weak<Subscriber>>>,
    /// Whether any subscriber is alive (saves the copy of a change when none is).
    subscribed: AtomicBool,
    seq: AtomicU64,
    clock: Clock,
    /// The engine stopped: no more commits, every subscription ends.
    closed: AtomicBool,
}

impl Default for Image {
    fn default() -> Self {
        Image::with_clock(Clock::system())
    }
}

impl Drop for Image {
    fn drop(&mut self) {
        self.close();
    }
}

impl Image {
    /// An empty image whose changes are stamped by `clock`.
    pub fn with_clock(clock: Clock) -> Self {
        Image {
            devices: RwLock::new(vec![]),
            changes: broadcast::channel(1024).0,
            subscribers: Mutex::new(vec![]),
            subscribed: AtomicBool::new(false),
            seq: AtomicU64::new(0),
            clock,
            closed: AtomicBool::new(false),
        }
    }

    /// Ends every change subscription: each [`Changes::recv`] gives what was
    /// committed before, then `None` (the engine stopped: no commit comes after).
    /// Subscriptions made later end at once.
    pub fn close(&self) {
        self.closed.store(true, Ordering::Release);
        for s in self
            .subscribers
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .filter_map(Weak::upgrade)
        {
            s.closed.store(true, Ordering::Release);
            s.notify.notify_one();
        }
    }

    /// Whether [`Image::close`] was called (the engine stopped).
    pub fn is_closed(&self) -> bool {
        self.closed.load(Ordering::Acquire)
    }

    /// The clock that stamps the image's values and changes.
    pub fn clock(&self) -> &Clock {
        &self.clock
    }

    fn read(&self) -> std::sync::RwLockReadGuard<'_, Vec<DeviceImage>> {
        self.devices.read().unwrap_or_else(|e| e.into_inner())
    }

    fn write(&self) -> std::sync::RwLockWriteGuard<'_, Vec<DeviceImage>> {
        self.devices.write().unwrap_or_else(|e| e.into_inner())
    }

    /// Devices in the list.
    pub fn len(&self) -> usize {
        self.read().len()
    }

    /// Whether no device is listed yet.
    pub fn is_empty(&self) -> bool {
        self.read().is_empty()
    }

    /// A copy of every device's image, in position order.
    pub fn snapshot(&self) -> Vec<DeviceImage> {
        self.read().clone()
    }

    /// Calls `f` with the image at `position` without copying it.
    pub fn with<R>(&self, position: usize, f: impl FnOnce(&DeviceImage) -> R) -> Option<R> {
        self.read().get(position).map(f)
    }

    /// The one place a request for the device at image `position` is built: `request`
    /// in a long frame to the device's unique ID, from the primary master (the
    /// engine's role on every loop), with the loop it goes on. The command number,
    /// and the command-31 form for numbers above 255, come from hart-proto.
    pub fn request_for(
        &self,
        position: usize,
        request: &hart_proto::Request,
    ) -> Result<DeviceRequest, Unaddressable> {
        let (channel, id) = self
            .with(position, |d| (d.channel, d.unique_id()))
            .ok_or(Unaddressable::NoSuchDevice)?;
        let unique_id = id.ok_or(Unaddressable::NotIdentified)?;
        let pdu = request_pdu(unique_id, request).map_err(Unaddressable::Encode)?;
        Ok(DeviceRequest {
            channel,
            unique_id,
            pdu,
        })
    }

    /// Receives the position of every device whose image changed. A receiver more
    /// than 1024 changes behind is told it lagged (and must look at the whole image);
    /// a subscriber that needs every change takes [`Image::changes`].
    pub fn subscribe(&self) -> broadcast::Receiver<usize> {
        self.changes.subscribe()
    }

    /// Subscribes to every change from now on, each with the device's whole image as
    /// committed, holding up to `capacity` (at least 1) not yet received.
    pub fn changes(&self, capacity: usize) -> Changes {
        let sub = Arc::new(Subscriber {
            queue: Mutex::new(VecDeque::new()),
            capacity: capacity.max(1),
            dropped: AtomicU64::new(0),
            notify: tokio::sync::Notify::new(),
            closed: AtomicBool::new(self.is_closed()),
            warned: Mutex::new(None),
        });
        let mut subs = self.subscribers.lock().unwrap_or_else(|e| e.into_inner());
        subs.retain(|s| s.strong_count() > 0);
        subs.push(Arc::downgrade(&sub));
        self.subscribed.store(true, Ordering::Release);
        Changes { sub }
    }

    /// Announces the change of `device` (called with the image's write lock held, so
    /// commits reach subscribers in the order they were made).
    fn announce(&self, device: &DeviceImage) {
        let _ = self.changes.send(device.position);
        if !self.subscribed.load(Ordering::Acquire) {
            return;
        }
        let mut subs = self.subscribers.lock().unwrap_or_else(|e| e.into_inner());
        subs.retain(|s| s.strong_count() > 0);
        if subs.is_empty() {
            self.subscribed.store(false, Ordering::Release);
            return;
        }
        let now = self.clock.now();
        let change = Change {
            device: Arc::new(device.clone()),
            quality: device.quality(now),
            at: self.clock.wall(),
            seq: self.seq.fetch_add(1, Ordering::Relaxed),
        };
        for s in subs.iter().filter_map(Weak::upgrade) {
            s.push(change.clone(), now);
        }
    }

    /// Changes the image at `position` and announces it: one commit, however many
    /// fields `f` changes.
    pub fn update<R>(&self, position: usize, f: impl FnOnce(&mut DeviceImage) -> R) -> Option<R> {
        let mut devices = self.write();
        let d = devices.get_mut(position)?;
        let r = f(d);
        self.announce(d);
        Some(r)
    }

    /// Adds a device at the end of the list; returns its position.
    pub fn push(&self, mut device: DeviceImage) -> usize {
        let mut d = self.write();
        device.position = d.len();
        let p = device.position;
        d.push(device);
        self.announce(&d[p]);
        p
    }

    /// The position of the device with `id` on `channel`.
    pub fn find(&self, channel: u8, id: UniqueId) -> Option<usize> {
        self.position_where(|d| d.channel == channel && d.unique_id() == Some(id))
    }

    /// The position of the first device for which `f` holds, without copying the list.
    pub fn position_where(&self, f: impl Fn(&DeviceImage) -> bool) -> Option<usize> {
        self.read().iter().find(|d| f(d)).map(|d| d.position)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image() -> DeviceImage {
        DeviceImage::new(0, 0, "loop1", Duration::from_secs(10))
    }

    /// A command 3 reply, field by field: 12.0 mA, PV 50.0 kPa (units 12), SV
    /// 25.0 degC (units 32).
    #[test]
    fn command_3_fills_pv_sv_and_current() {
        let data = [
            0x41, 0x40, 0x00, 0x00, // loop current 12.0 mA
            12, 0x42, 0x48, 0x00, 0x00, // PV kPa 50.0
            32, 0x41, 0xC8, 0x00, 0x00, // SV degC 25.0
        ];
        let mut d = image();
        let now = Instant::now();
        assert!(d.apply_reply(3, 0, 0, &data, now, SystemTime::now()));
        assert_eq!(d.loop_current, Some(12.0));
        assert_eq!(d.variables[0].unwrap().value, 50.0);
        assert_eq!(d.variables[0].unwrap().units, 12);
        assert_eq!(d.variables[1].unwrap().units, 32);
        assert!(d.variables[2].is_none());
        assert_eq!(d.quality(now), Quality::Good);
        assert_eq!(d.quality(now + Duration::from_secs(11)), Quality::Stale);
    }

    #[test]
    fn malfunction_and_no_reply() {
        let mut d = image();
        let now = Instant::now();
        assert_eq!(d.quality(now), Quality::WaitingForData, "not asked yet");
        let data = [0x41, 0x40, 0, 0, 12, 0x42, 0x48, 0, 0];
        d.apply_reply(3, 0, fds::DEVICE_MALFUNCTION, &data, now, SystemTime::now());
        assert_eq!(d.quality(now), Quality::DeviceMalfunction);
        d.no_reply();
        assert_eq!(d.quality(now), Quality::NoReply);
        // An error reply (command not implemented) keeps the values it had.
        assert!(!d.apply_reply(3, 64, 0, &[], now, SystemTime::now()));
        assert_eq!(d.variables[0].unwrap().value, 50.0);
    }

    /// Command 9 with slots 246, 244, 245: the engine's request for PV, percent of
    /// range and loop current.
    #[test]
    fn command_9_slots() {
        let data = [
            0x00, // extended status
            246, 64, 12, 0x42, 0x48, 0x00, 0x00, 0xC0, // PV 50.0 kPa, good
            244, 0, 57, 0x42, 0x48, 0x00, 0x00, 0xC0, // 50 %
            245, 0, 39, 0x41, 0x40, 0x00, 0x00, 0xC0, // 12 mA
            0, 0, 0, 0, // time stamp
        ];
        let mut d = image();
        assert!(d.apply_reply(9, 0, 0, &data, Instant::now(), SystemTime::now()));
        assert_eq!(d.variables[0].unwrap().status, Some(0xC0));
        assert_eq!(d.percent_range, Some(50.0));
        assert_eq!(d.loop_current, Some(12.0));
    }

    #[test]
    fn codes_round_trip() {
        for (i, q) in Quality::ALL.into_iter().enumerate() {
            assert_eq!(usize::from(q.code()), i);
            assert_eq!(Quality::from_code(q.code()), Some(q));
        }
        assert_eq!(Quality::from_code(7), None);
    }

    #[test]
    fn display_names() {
        let mut d = image();
        d.polling_address = Some(3);
        assert_eq!(d.display_name(), "poll-3");
        d.name = Some("  ".into());
        assert_eq!(d.display_name(), "poll-3");
        d.name = Some("FT-101".into());
        assert_eq!(d.display_name(), "FT-101");
    }

    proptest::proptest! {
        /// Any reply data, for any command, never panics the image.
        #[test]
        fn any_reply_is_safe(command in 0u16..300, rc: u8, status: u8,
                             data in proptest::collection::vec(proptest::num::u8::ANY, 0..64)) {
            let mut d = image();
            d.apply_reply(command, rc, status, &data, Instant::now(), SystemTime::now());
            let _ = d.quality(Instant::now());
        }
    }
}
