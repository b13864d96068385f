//! The one task that owns a loop: client requests and writes in turn, the scan that
//! finds the devices, and the polls that keep the image current.
//!
//! Each turn takes, in this order: a write (SCADA front ends); a client request
//! (HART-IP), unless [`FAIR_SHARE`] of them in a row have kept an overdue poll
//! waiting; a scan step when due; the poll of the device due longest. With nothing to
//! do it listens to the line for burst frames.

use std::sync::Arc;
use std::time::{Duration, Instant};

use hart_host::DeviceInfo;
use hart_proto::command::{
    Damping, Empty, FixedCurrent, Identity, LongTag, RangeValues, ReadDeviceVariablesRequest,
    TagDescriptorDate,
};
use hart_proto::frame::{Address, Frame, UniqueId};
use hart_proto::tables::field_device_status as fds;
use hart_proto::types::{DeviceVariableCode, MilliAmps, Seconds, UnitCode};
use hart_proto::wire::{List, Reader, Wire};
use hart_proto::Request;
use tokio::sync::mpsc;

use crate::clock::Clock;
use crate::config::{LoopSettings, ReadCommand};
use crate::image::{request_pdu, DeviceImage, LastPoll};
use crate::lease::{LeaseTerms, Leases, LoopTest, ReleaseReason};
use crate::line::Line;
use crate::request::{LoopOutcome, LoopRequest};
use crate::schedule::{Micros, Schedule};
use crate::{Shared, SubDevice, TrafficFrame, TrafficKind};

/// After the first pass without polling, one more address of the scan is visited
/// whenever the loop has had no request for this long, so the sub-device list stays
/// current.
pub const RESCAN_IDLE: Duration = Duration::from_secs(2);

/// During the first pass the scan waits this long after a request before it takes the
/// line again, so a client's next request (which follows its reply within
/// milliseconds) does not queue behind a scan step.
pub const SCAN_GRACE: Duration = Duration::from_millis(150);

/// Rescan visits without a reply after which a known sub-device is marked absent in
/// the registry (it keeps its place; its image stays, "no reply").
pub const MISSES_TO_FORGET: u8 = 2;

/// Client requests carried in a row while a poll is overdue before one poll goes.
pub const FAIR_SHARE: u32 = 4;

/// Retries of a poll to a device that answered its last poll; one that did not gets
/// one retry, so a dead device costs the line two slave time-outs per visit.
pub const POLL_RETRIES: u8 = 3;

/// A device that did not answer is polled again after this long at the soonest.
pub const RETRY_DEAD_AFTER: Duration = Duration::from_secs(2);

/// Commands whose success changes what command 15 or the tags report: the device's
/// configuration is read again after one of them goes through the engine.
const CONFIG_WRITES: &[u16] = &[6, 17, 18, 22, 34, 35, 36, 37, 40, 44, 45, 46, 47, 53, 79];

/// The device variables a command 9 poll reads from a HART 7 device: PV, SV, TV, QV,
/// percent of range, loop current (HART 7 allows 8 slots).
pub const POLL_SLOTS_7: [DeviceVariableCode; 6] = [
    DeviceVariableCode(246),
    DeviceVariableCode(247),
    DeviceVariableCode(248),
    DeviceVariableCode(249),
    DeviceVariableCode(244),
    DeviceVariableCode(245),
];

/// The device variables a command 9 poll reads from a HART 6 device (4 slots at most):
/// PV, SV, TV, QV.
pub const POLL_SLOTS_6: [DeviceVariableCode; 4] = [
    DeviceVariableCode(246),
    DeviceVariableCode(247),
    DeviceVariableCode(248),
    DeviceVariableCode(249),
];

/// Command 0 to polling address `poll` (identification before the unique ID is
/// known), as a frame without preambles.
fn identify_request(poll: u8) -> Vec<u8> {
    Request::ReadUniqueIdentifier(Empty {})
        .frame(Address::short(poll))
        .map(|b| b.as_slice().to_vec())
        .unwrap_or_default()
}

/// Per device, what the task keeps besides the image.
#[derive(Debug, Clone, Default)]
struct Polled {
    /// The device refused command 9: poll it with command 3.
    no_command_9: bool,
    /// Last seen state of the configuration-changed bit.
    config_bit: bool,
    /// Read command 15 (and tags) on the next poll.
    refresh: bool,
    /// Tags too.
    refresh_tags: bool,
}

/// What the engine tells a loop's task besides requests.
#[derive(Debug, Clone)]
pub(crate) enum Control {
    /// Release every loop test, then end.
    Stop,
    /// Release the loop tests held by this holder.
    HolderGone(String),
}

/// Tries of each release when the engine stops, before the task gives up on it (and
/// says so): with the line's own retries, a few seconds per device at most.
pub const STOP_RELEASE_TRIES: u32 = 2;

/// How often a loop's task looks for devices gone stale, to commit it.
pub const STALE_CHECK: Duration = Duration::from_millis(500);

pub(crate) struct LoopTask {
    pub(crate) channel: u8,
    pub(crate) settings: LoopSettings,
    pub(crate) line: Line,
    pub(crate) shared: Arc<Shared>,
    pub(crate) requests: mpsc::Receiver<LoopRequest>,
    pub(crate) writes: mpsc::Receiver<LoopRequest>,
    control: mpsc::UnboundedReceiver<Control>,
    leases: Leases,
    schedule: Schedule,
    polled: std::collections::HashMap<usize, Polled>,
    scan_order: Vec<u8>,
    next_scan: usize,
    first_pass: bool,
    misses: [u8; 64],
    quiet_since: Option<Instant>,
    /// When to look for devices gone stale next ([`STALE_CHECK`]).
    next_stale_check: Option<Instant>,
    last_scan: Option<Instant>,
    in_a_row: u32,
    scan_turn: bool,
    epoch: Instant,
    clock: Clock,
    disturbance: crate::disturbance::Disturbance,
}

impl LoopTask {
    pub(crate) fn new(
        channel: u8,
        settings: LoopSettings,
        line: Line,
        shared: Arc<Shared>,
        requests: mpsc::Receiver<LoopRequest>,
        writes: mpsc::Receiver<LoopRequest>,
        control: mpsc::UnboundedReceiver<Control>,
    ) -> Self {
        let scan_order = settings.scan_order();
        let clock = *shared.image.clock();
        LoopTask {
            control,
            leases: Leases::new(shared.config.loop_test_limit()),
            channel,
            settings,
            line,
            shared,
            requests,
            writes,
            schedule: Schedule::new(RETRY_DEAD_AFTER.as_micros() as Micros),
            clock,
            polled: Default::default(),
            scan_order,
            next_scan: 0,
            first_pass: true,
            misses: [0; 64],
            quiet_since: None,
            next_stale_check: None,
            last_scan: None,
            in_a_row: 0,
            scan_turn: true,
            epoch: clock.now(),
            disturbance: Default::default(),
        }
    }

    /// Microseconds since the task started, on the engine's clock.
    fn now(&self) -> Micros {
        self.clock.since(self.epoch).as_micros() as Micros
    }

    fn polling(&self) -> bool {
        self.shared.config.poll
    }

    /// Runs until the engine stops ([`Control::Stop`]: its loop tests released first)
    /// or every request queue is closed (the engine was dropped).
    pub(crate) async fn run(mut self) {
        self.serve().await;
        self.release_all().await;
        self.shared.loop_stopped();
    }

    async fn serve(&mut self) {
        // Configured devices are polled from the start (identified on their first turn).
        if self.polling() {
            let now = self.now();
            for d in self.shared.image.snapshot() {
                if d.channel == self.channel {
                    let (period, _) = self.device_settings(d.polling_address);
                    self.schedule.insert(d.position, micros(period), now);
                }
            }
        }
        if self.line.is_memory() {
            // Answers in memory cost no line time: the whole first pass at once.
            while self.first_pass && !self.scan_order.is_empty() {
                self.scan_step().await;
            }
        }
        if self.scan_order.is_empty() {
            self.first_pass_done();
        }
        let mut turns = 0u32;
        loop {
            // A loop in virtual time never waits: let the other tasks run between steps.
            // In memory a step costs microseconds: drain the queue in runs of 64 (a
            // yield per request would put the loop behind every session task each time).
            turns = turns.wrapping_add(1);
            if !self.line.is_memory() || turns % 64 == 0 {
                tokio::task::yield_now().await;
            }
            self.shared.set_failure(self.channel, self.line.failure());
            match self.control.try_recv() {
                Ok(Control::Stop) => return,
                Ok(Control::HolderGone(h)) => {
                    self.leases.holder_gone(&h, self.clock.now());
                }
                Err(_) => {}
            }
            if let Some((p, why)) = self.leases.due(self.clock.now()) {
                self.release(p, why).await;
                continue;
            }
            if let Ok(r) = self.writes.try_recv() {
                self.carry(r).await;
                continue;
            }
            let t = self.now();
            let poll_due = self.polling() && self.schedule.due(t).is_some();
            if !(poll_due && self.in_a_row >= FAIR_SHARE) {
                match self.requests.try_recv() {
                    Ok(r) => {
                        self.in_a_row += 1;
                        self.carry(r).await;
                        continue;
                    }
                    Err(mpsc::error::TryRecvError::Disconnected) => return,
                    Err(mpsc::error::TryRecvError::Empty) => {}
                }
            }
            self.in_a_row = 0;
            let scan_wait = self.scan_wait();
            let scan_due = scan_wait == Some(Duration::ZERO);
            // In the first pass scan steps and polls take turns, so the devices found
            // first are polled while the scan goes on.
            if scan_due && (!poll_due || self.scan_turn || !self.first_pass) {
                self.scan_turn = false;
                self.scan_step().await;
            } else if poll_due {
                self.scan_turn = true;
                if let Some(p) = self.schedule.due(t) {
                    self.poll(p).await;
                }
            } else {
                let mut wait = self.line.idle_wait().min(STALE_CHECK);
                if let Some(w) = scan_wait {
                    wait = wait.min(w);
                }
                if self.polling() {
                    if let Some(d) = self.schedule.next_due() {
                        wait = wait.min(Duration::from_micros(d.saturating_sub(t)));
                    }
                }
                if let Some(d) = self.leases.next_deadline() {
                    wait = wait.min(self.clock.until(d));
                }
                tokio::select! {
                    c = self.control.recv() => match c {
                        Some(Control::Stop) | None => return,
                        Some(Control::HolderGone(h)) => {
                            self.leases.holder_gone(&h, self.clock.now());
                        }
                    },
                    r = self.writes.recv() => if let Some(r) = r { self.carry(r).await },
                    r = self.requests.recv() => match r {
                        Some(r) => { self.in_a_row += 1; self.carry(r).await }
                        None => return,
                    },
                    _ = tokio::time::sleep(wait) => {
                        if !self.line.is_memory() && wait >= self.line.idle_wait() {
                            self.line.idle().await;
                        }
                    }
                }
            }
            self.bursts();
            self.judge_line();
            self.commit_staleness();
        }
    }

    /// Commits, as a change, each device of this loop whose values have just gone
    /// stale (older than its `stale_after`): a quality that changes with time alone
    /// reaches every subscriber through the change stream, in order with the rest.
    /// Looked at every [`STALE_CHECK`] at most.
    fn commit_staleness(&mut self) {
        let now = self.clock.now();
        if self.next_stale_check.is_some_and(|t| now < t) {
            return;
        }
        self.next_stale_check = Some(now + STALE_CHECK);
        let stale: Vec<usize> = self
            .shared
            .image
            .snapshot()
            .iter()
            .filter(|d| {
                d.channel == self.channel
                    && !d.stale_committed
                    && d.quality(now) == crate::Quality::Stale
            })
            .map(|d| d.position)
            .collect();
        for p in stale {
            self.shared.image.update(p, |d| d.stale_committed = true);
        }
    }

    /// Whether the loop is disturbed (a babbling device): when that changes, it is
    /// logged and every device of the loop is marked, so each front end shows it.
    fn judge_line(&mut self) {
        let counters = self.line.counters();
        let reason = self
            .disturbance
            .observe(self.clock.now(), counters)
            .map(str::to_string);
        if !self.shared.set_disturbed(self.channel, reason.as_deref()) {
            return;
        }
        let name = &self.shared.loop_names[usize::from(self.channel)];
        match &reason {
            Some(why) => tracing::warn!("{name}: the loop is disturbed: {why}"),
            None => tracing::info!("{name}: the loop is quiet again"),
        }
        for d in self.shared.image.snapshot() {
            if d.channel == self.channel {
                self.shared
                    .image
                    .update(d.position, |d| d.loop_disturbed = reason.is_some());
            }
        }
    }

    /// How long until the next scan step; `Some(0)` when due, `None` for no scan.
    fn scan_wait(&self) -> Option<Duration> {
        if self.scan_order.is_empty() {
            return None;
        }
        let since = |t: Option<Instant>| t.map_or(Duration::MAX, |t| self.clock.since(t));
        let idle = since(self.quiet_since);
        if self.first_pass {
            return Some(SCAN_GRACE.saturating_sub(idle));
        }
        let rescan = self.shared.config.defaults.rescan;
        if self.polling() {
            if rescan.is_zero() {
                return None;
            }
            // With polls on the line, a rescan step every `rescan`, and not right
            // after a client's request either.
            let w = rescan
                .saturating_sub(since(self.last_scan))
                .max(RESCAN_IDLE.saturating_sub(idle).min(SCAN_GRACE));
            return Some(w);
        }
        Some(RESCAN_IDLE.saturating_sub(idle))
    }

    fn first_pass_done(&mut self) {
        self.first_pass = false;
        self.shared.loop_ready(self.channel);
    }

    /// Carries a client's request or a write.
    async fn carry(&mut self, r: LoopRequest) {
        // Given up by its requester (answered "busy"), or its session ended: the line
        // is not spent on it.
        if !r.start() {
            return;
        }
        let outcome = match self.transact(&r.pdu, r.retries).await {
            Some(reply) => {
                self.learn(&r.pdu, &reply).await;
                self.after_write(&r.pdu, &reply, r.lease);
                LoopOutcome::Reply(reply)
            }
            None => LoopOutcome::NoReply,
        };
        let _ = r.reply.send(outcome);
        self.quiet_since = Some(self.clock.now());
    }

    /// A write that went through: read the device's configuration again on its next
    /// poll (at once), and keep the loop current it was fixed at.
    fn after_write(&mut self, request: &[u8], reply: &[u8], lease: LeaseTerms) {
        use hart_proto::tables::{response_class, ResponseClass};
        let (Ok(req), Ok(rep)) = (Frame::parse_pdu(request), Frame::parse_pdu(reply)) else {
            return;
        };
        if !CONFIG_WRITES.contains(&req.command)
            || rep.is_communication_error()
            || response_class(rep.response_code.unwrap_or(0xFF)) == ResponseClass::Error
        {
            return;
        }
        let Some(position) = self.position_of(&req.address) else {
            return;
        };
        // What the reply says the device now has goes into the image at once (a SCADA
        // reading back its write sees it without waiting for the next configuration
        // poll); the poll that follows confirms the rest.
        let data = || Reader::new(rep.data);
        match req.command {
            40 => {
                let current = FixedCurrent::decode(&mut data())
                    .ok()
                    .map(|f| f.loop_current.0)
                    .filter(|c| *c != 0.0);
                let now = self.clock.now();
                let test = match current {
                    // A loop test started (or changed): the engine holds it.
                    Some(c) => {
                        self.leases.granted(position, c, lease, now);
                        self.leases.get(position).map(|l| LoopTest {
                            current: c,
                            release_at: self.clock.wall_at(l.expires),
                            by: l.terms.by.clone(),
                            failed_releases: 0,
                        })
                    }
                    // Left fixed current mode, whoever asked: nothing to release.
                    None => {
                        self.leases.released(position);
                        None
                    }
                };
                self.shared.image.update(position, |d| {
                    d.fixed_current = current;
                    d.loop_test = test;
                });
            }
            34 => {
                if let Ok(Damping {
                    damping: Seconds(damping),
                }) = Damping::decode(&mut data())
                {
                    self.shared.image.update(position, |d| {
                        if let Some(r) = d.range.as_mut() {
                            r.damping = damping;
                        }
                    });
                }
            }
            35 => {
                if let Ok(RangeValues {
                    range_units: UnitCode(units),
                    upper_range_value: upper,
                    lower_range_value: lower,
                }) = RangeValues::decode(&mut data())
                {
                    self.shared.image.update(position, |d| {
                        if let Some(r) = d.range.as_mut() {
                            (r.units, r.upper, r.lower) = (units, upper, lower);
                        }
                    });
                }
            }
            _ => {}
        }
        let p = self.polled.entry(position).or_default();
        p.refresh = true;
        p.refresh_tags |= matches!(req.command, 6 | 17 | 18 | 22);
        let now = self.now();
        self.schedule.hurry(position, now);
    }

    /// Ends the loop test of the device at `position` (command 40 with 0 mA), audited
    /// as the engine's own write; a release the device does not confirm is tried
    /// again later, and shown and logged as an alarm meanwhile. Returns whether the
    /// device confirmed it.
    async fn release(&mut self, position: usize, why: ReleaseReason) -> bool {
        let Some(lease) = self.leases.get(position).cloned() else {
            return true;
        };
        let Some((id, name)) = self
            .shared
            .image
            .with(position, |d| (d.unique_id(), d.display_name()))
        else {
            self.leases.forget(position);
            return true;
        };
        let Some(id) = id else {
            self.leases.forget(position);
            return true;
        };
        let leave = Request::EnterExitFixedCurrent(FixedCurrent {
            loop_current: MilliAmps(0.0),
        });
        let request = request_pdu(id, &leave).unwrap_or_default();
        let record = hart_access::WriteRecord {
            front_end: "engine",
            peer: "-".into(),
            identity: Some("loop test release".into()),
            device: format!("{name} (unique ID {id}, unit {})", position + 1),
            command: 40,
            via: format!("{} (asked by {})", why.describe(), lease.terms.by),
            operation: Some("leave fixed current mode".into()),
            ..Default::default()
        };
        let audit = &self.shared.write_policy.audit;
        let n = audit.record(&record);
        let reply = self.transact(&request, crate::POLL_RETRIES).await;
        let outcome = crate::write::outcome_of(40, reply.as_deref());
        self.shared.write_policy.audit.outcome(n, &record, &outcome);
        if let hart_access::WriteOutcome::Done { .. } = outcome {
            self.leases.released(position);
            tracing::info!(
                "{name}: loop test at {} mA ended ({}): the loop current follows the process again",
                lease.current,
                why.describe()
            );
            self.shared.image.update(position, |d| {
                d.fixed_current = None;
                d.loop_test = None;
            });
            let p = self.polled.entry(position).or_default();
            p.refresh = true;
            let now = self.now();
            self.schedule.hurry(position, now);
            return true;
        }
        let failed = self.leases.release_failed(position, self.clock.now());
        let next = self
            .leases
            .get(position)
            .map_or(Duration::ZERO, |l| self.clock.until(l.deadline()));
        tracing::error!(
            "ALARM {name}: the loop test at {} mA could not be ended ({}; try {failed}: {}); \
             the device still drives a fixed loop current and the control system reads a false \
             value. Trying again in {} s; check the device and its loop, or end it by hand \
             (command 40 with 0 mA)",
            lease.current,
            why.describe(),
            outcome.reason().map_or_else(
                || format!("response code {}", outcome.response_code().unwrap_or(0)),
                str::to_string
            ),
            next.as_secs()
        );
        self.shared.image.update(position, |d| {
            if let Some(t) = d.loop_test.as_mut() {
                t.failed_releases = failed;
            }
        });
        false
    }

    /// Releases every loop test of the loop (the engine stops), each tried
    /// [`STOP_RELEASE_TRIES`] times; what the devices do not confirm is logged as an
    /// alarm.
    async fn release_all(&mut self) {
        if self.leases.is_empty() {
            return;
        }
        self.leases.release_all(self.clock.now());
        let positions: Vec<usize> = self.leases.iter().map(|(p, _)| p).collect();
        for p in positions {
            for _ in 0..STOP_RELEASE_TRIES {
                if self.release(p, ReleaseReason::Stopping).await {
                    break;
                }
            }
        }
        for (p, l) in self.leases.iter() {
            tracing::error!(
                "ALARM unit {}: stopping with its loop current still fixed at {} mA: end the \
                 loop test by hand (command 40 with 0 mA)",
                p + 1,
                l.current
            );
        }
    }

    /// The image position of the device a request addresses on this loop.
    fn position_of(&self, address: &Address) -> Option<usize> {
        match address {
            Address::Long(a) => self.shared.image.find(self.channel, a.id),
            Address::Short(a) => self.shared.image.position_where(|d| {
                d.channel == self.channel
                    && d.polling_address == Some(a.polling_address)
                    && d.info.is_some()
            }),
        }
    }

    /// One address of the scan: identify it, list what answers, forget what stopped
    /// answering.
    async fn scan_step(&mut self) {
        let Some(&poll) = self.scan_order.get(self.next_scan) else {
            return;
        };
        match self.identify(poll).await {
            Some(info) => {
                if let Some(m) = self.misses.get_mut(usize::from(poll)) {
                    *m = 0;
                }
                self.check_duplicate(poll, &info).await;
                let io = info.is_io_system().then(|| info.unique_id());
                self.register(info).await;
                if let Some(io) = io {
                    self.io_system(io).await;
                }
            }
            None => {
                let misses = self.misses.get_mut(usize::from(poll)).map_or(0, |m| {
                    *m = m.saturating_add(1);
                    *m
                });
                if misses >= MISSES_TO_FORGET {
                    crate::forget(&self.shared.subs, self.channel, poll).await;
                }
            }
        }
        self.next_scan += 1;
        // Listed devices come first in the scan order: once they have been tried, the
        // device list's first positions are known.
        let listed = self.settings.device.len();
        if self.first_pass && listed > 0 && self.next_scan == listed {
            self.shared.loop_ready(self.channel);
        }
        if self.next_scan >= self.scan_order.len() {
            self.next_scan = 0;
            self.first_pass_done();
        }
        self.last_scan = Some(self.clock.now());
        if !self.first_pass && !self.polling() {
            self.quiet_since = Some(self.clock.now());
        }
    }

    /// A device found at `poll` that is listed at another polling address: asked there
    /// again, and when it still answers there too, it answers addresses not its own
    /// (a device whose address was changed answers only at the new one).
    async fn check_duplicate(&mut self, poll: u8, info: &DeviceInfo) {
        let id = info.unique_id();
        let other = self
            .shared
            .subs
            .lock()
            .await
            .iter()
            .find(|s| {
                s.channel == self.channel
                    && s.present
                    && s.info.unique_id() == id
                    && s.info.polling_address.is_some_and(|p| p != poll)
            })
            .and_then(|s| s.info.polling_address);
        let Some(other) = other else {
            return;
        };
        let request = identify_request(other);
        let again = self.transact(&request, 1).await;
        let same = again
            .as_deref()
            .and_then(|r| Frame::parse_pdu(r).ok())
            .and_then(|f| Identity::decode(&mut Reader::new(f.data)).ok())
            .is_some_and(|i| DeviceInfo::identified(i, None).unique_id() == id);
        if same {
            self.disturbance
                .duplicate(self.clock.now(), &id.to_string(), other, poll);
        }
    }

    /// The sub-devices of an I/O system found on this loop (a HART-IP gateway or
    /// multiplexer upstream): listed and polled by their unique IDs through it.
    async fn io_system(&mut self, io: UniqueId) {
        let known: Vec<UniqueId> = self
            .shared
            .image
            .snapshot()
            .iter()
            .filter(|d| d.channel == self.channel)
            .filter_map(|d| d.unique_id())
            .collect();
        for info in self.line.sub_devices(io, &known).await {
            self.register(info).await;
        }
    }

    /// Identifies the device at `poll` (one retry only: an empty address must not hold
    /// the line, and the requests queued behind it, for four slave time-outs), then
    /// reads its tag and descriptor (command 13) and, from HART 6 on, its long tag
    /// (command 20).
    async fn identify(&mut self, poll: u8) -> Option<DeviceInfo> {
        let request = identify_request(poll);
        let reply = self.transact(&request, 1).await?;
        let f = Frame::parse_pdu(&reply).ok()?;
        if f.is_communication_error() || f.response_code != Some(0) {
            return None;
        }
        let identity = Identity::decode(&mut Reader::new(f.data)).ok()?;
        let mut info = DeviceInfo::identified(identity, Some(poll));
        self.read_tags(&mut info).await;
        Some(info)
    }

    async fn read_tags(&mut self, info: &mut DeviceInfo) {
        if let Some((0, _, data)) = self
            .command(
                info,
                &Request::ReadTagDescriptorDate(Empty {}),
                POLL_RETRIES,
            )
            .await
        {
            if let Ok(t) = TagDescriptorDate::decode(&mut Reader::new(&data)) {
                info.tag = Some(t.tag.to_string().trim_end().to_string());
                info.descriptor = Some(t.descriptor.to_string().trim_end().to_string());
            }
        }
        if info.revision() >= 6 {
            if let Some((0, _, data)) = self
                .command(info, &Request::ReadLongTag(Empty {}), POLL_RETRIES)
                .await
            {
                if let Ok(t) = LongTag::decode(&mut Reader::new(&data)) {
                    info.long_tag = Some(t.long_tag.to_string().trim_end().to_string());
                }
            }
        }
    }

    /// Sends `request` to a known device by its unique ID: (response code, device
    /// status, data), or `None` for no reply or a communication error.
    async fn command(
        &mut self,
        info: &DeviceInfo,
        request: &Request,
        retries: u8,
    ) -> Option<(u8, u8, Vec<u8>)> {
        let request = request_pdu(info.unique_id(), request).ok()?;
        let reply = self.transact(&request, retries).await?;
        let f = Frame::parse_pdu(&reply).ok()?;
        if f.is_communication_error() {
            return None;
        }
        Some((f.response_code?, f.device_status?, f.data.to_vec()))
    }

    /// The poll period and read command of a device at `poll` on this loop.
    fn device_settings(&self, poll: Option<u8>) -> (Duration, ReadCommand) {
        let dev = poll.and_then(|p| self.settings.device.iter().find(|d| d.poll == p));
        self.shared.config.device_settings(&self.settings, dev)
    }

    /// Lists a device found on this loop: in the routing list, and in the image (a
    /// configured slot with its polling address, the entry with its unique ID, or a
    /// new entry at the end), scheduled for polling.
    async fn register(&mut self, info: DeviceInfo) {
        crate::remember(
            &self.shared.subs,
            SubDevice {
                channel: self.channel,
                info: info.clone(),
                present: true,
            },
        )
        .await;
        let id = info.unique_id();
        let image = &self.shared.image;
        let position = image.find(self.channel, id).or_else(|| {
            // A configured device not yet found, at this polling address.
            image.position_where(|d| {
                d.channel == self.channel
                    && d.info.is_none()
                    && d.polling_address.is_some()
                    && d.polling_address == info.polling_address
            })
        });
        let (period, _) = self.device_settings(info.polling_address);
        let position = match position {
            Some(p) => {
                image.update(p, |d| {
                    let mut info = info;
                    if let Some(old) = &d.info {
                        info.polling_address = info.polling_address.or(old.polling_address);
                        info.tag = info.tag.or(old.tag.clone());
                        info.descriptor = info.descriptor.or(old.descriptor.clone());
                        info.long_tag = info.long_tag.or(old.long_tag.clone());
                    }
                    d.polling_address = info.polling_address;
                    d.info = Some(info);
                });
                p
            }
            None => {
                let mut d = DeviceImage::new(
                    0,
                    self.channel,
                    &self.shared.loop_names[usize::from(self.channel)],
                    self.shared.config.stale_limit(period),
                );
                d.polling_address = info.polling_address;
                d.info = Some(info);
                let p = image.push(d);
                tracing::info!(
                    "{}: device {} found ({})",
                    self.shared.loop_names[usize::from(self.channel)],
                    p + 1,
                    image.with(p, |d| d.display_name()).unwrap_or_default()
                );
                p
            }
        };
        if self.polling() && !self.schedule.contains(position) {
            let now = self.now();
            self.schedule.insert(position, micros(period), now);
        }
    }

    /// Learns devices from the identity replies (commands 0, 11 and 21) that clients'
    /// requests bring back, so devices connected after the scan are routed too.
    async fn learn(&mut self, request: &[u8], reply: &[u8]) {
        let (Ok(req), Ok(rep)) = (Frame::parse_pdu(request), Frame::parse_pdu(reply)) else {
            return;
        };
        if !matches!(rep.command, 0 | 11 | 21) || rep.response_code.unwrap_or(0xFF) != 0 {
            return;
        }
        let Ok(identity) = Identity::decode(&mut Reader::new(rep.data)) else {
            return;
        };
        let polling_address = match req.address {
            Address::Short(a) => Some(a.polling_address),
            Address::Long(_) => None,
        };
        self.register(DeviceInfo::identified(identity, polling_address))
            .await;
    }

    /// Polls the device at `position`: its read command (3 or 9), then command 48 when
    /// it has more status, and its configuration (command 15, tags) when it is new,
    /// changed, or was just written.
    async fn poll(&mut self, position: usize) {
        let Some(img) = self.shared.image.with(position, |d| d.clone()) else {
            return;
        };
        let now = self.now();
        let Some(info) = img.info.clone() else {
            // A configured device not found yet: identify it at its polling address.
            let found = match img.polling_address {
                Some(p) => self.identify(p).await,
                None => None,
            };
            match found {
                Some(info) => {
                    self.register(info).await;
                    self.schedule.hurry(position, now);
                }
                None => {
                    self.shared.image.update(position, |d| d.no_reply());
                    self.schedule.polled(position, self.now(), false);
                }
            }
            return;
        };
        let (_, read) = self.device_settings(img.polling_address);
        let mut st = self.polled.get(&position).cloned().unwrap_or_default();
        let use_9 = read == ReadCommand::Variables && info.revision() >= 6 && !st.no_command_9;
        let request = if use_9 {
            // PV..QV, percent of range, loop current: 6 slots (HART 7 allows 8, HART 6
            // only 4: there PV..QV).
            let slots: &[DeviceVariableCode] = if info.revision() >= 7 {
                &POLL_SLOTS_7
            } else {
                &POLL_SLOTS_6
            };
            Request::ReadDeviceVariablesWithStatus(ReadDeviceVariablesRequest {
                slots: List::from_slice(slots).unwrap_or_default(),
            })
        } else {
            Request::ReadDynamicVariables(Empty {})
        };
        let command = request.command();
        let retries = if img.last_poll == LastPoll::NoReply {
            1
        } else {
            POLL_RETRIES
        };
        let reply = self.command(&info, &request, retries).await;
        let Some((rc, status, data)) = reply else {
            if img.last_poll != LastPoll::NoReply {
                tracing::warn!(
                    "{}: device {} ({}) stopped answering",
                    img.loop_name,
                    position + 1,
                    img.display_name()
                );
            }
            self.shared.image.update(position, |d| {
                d.polls += 1;
                d.no_reply()
            });
            self.schedule.polled(position, self.now(), false);
            return;
        };
        if command == 9
            && hart_proto::tables::response_class(rc) == hart_proto::tables::ResponseClass::Error
        {
            // Not implemented, or slots it does not know: command 3 from now on.
            self.polled.entry(position).or_default().no_command_9 = true;
            self.schedule.hurry(position, self.now());
            return;
        }
        if img.last_poll == LastPoll::NoReply {
            tracing::info!(
                "{}: device {} ({}) answers again",
                img.loop_name,
                position + 1,
                img.display_name()
            );
        }
        // The replies of this poll are gathered and go into the image in one commit at
        // the end: a reader never sees the new values beside the old status or range.
        let mut replies = vec![Reply::new(&self.clock, command, rc, status, data)];
        // Configuration changed: shown for one period, then read again.
        let bit = status & fds::CONFIGURATION_CHANGED != 0;
        let first = img.range.is_none();
        let newly_changed = bit && !st.config_bit && !first;
        let reread = st.refresh || first || (img.config_changed_pending && !newly_changed);
        st.config_bit = bit;
        let tags = st.refresh_tags || img.config_changed_pending;
        if status & fds::MORE_STATUS_AVAILABLE != 0 {
            self.carry_writes().await;
            if let Some((rc, status, data)) = self
                .command(
                    &info,
                    &Request::ReadAdditionalStatus(Default::default()),
                    POLL_RETRIES,
                )
                .await
            {
                replies.push(Reply::new(&self.clock, 48, rc, status, data));
            }
        }
        let mut fresh_tags = None;
        if reread {
            self.carry_writes().await;
            if let Some((rc, status, data)) = self
                .command(
                    &info,
                    &Request::ReadDeviceInformation(Empty {}),
                    POLL_RETRIES,
                )
                .await
            {
                replies.push(Reply::new(&self.clock, 15, rc, status, data));
            }
            if tags {
                self.carry_writes().await;
                let mut fresh = info.clone();
                self.read_tags(&mut fresh).await;
                fresh_tags = Some(fresh);
            }
            st.refresh = false;
            st.refresh_tags = false;
        }
        self.shared.image.update(position, |d| {
            d.polls += 1;
            for r in &replies {
                d.apply_reply(r.command, r.rc, r.status, &r.data, r.instant, r.wall);
            }
            if newly_changed {
                d.config_changed_pending = true;
            } else if reread {
                d.config_changed_pending = false;
            }
            if let (Some(fresh), Some(i)) = (fresh_tags, &mut d.info) {
                i.tag = fresh.tag.or(i.tag.take());
                i.descriptor = fresh.descriptor.or(i.descriptor.take());
                i.long_tag = fresh.long_tag.or(i.long_tag.take());
            }
        });
        self.polled.insert(position, st);
        self.schedule.polled(position, self.now(), true);
    }

    /// Carries the writes waiting now, between the transactions of a step that takes
    /// several (a poll that also reads status and configuration takes up to five, 3 s
    /// on a loop with a burst device): a write waits at most for one transaction, never
    /// for a whole step, so it is not given up as "busy" after MAX_QUEUE_WAIT.
    /// One transaction on the line, shown to the traffic views
    /// ([`crate::Engine::traffic`]) when someone watches.
    async fn transact(&mut self, pdu: &[u8], retries: u8) -> Option<Vec<u8>> {
        let watched = self.shared.traffic.receiver_count() > 0;
        if watched {
            self.traffic(TrafficKind::Request, pdu.to_vec());
        }
        let reply = self.line.transact(pdu, retries).await;
        if watched {
            match &reply {
                Some(r) => self.traffic(TrafficKind::Reply, r.clone()),
                None => self.traffic(TrafficKind::NoReply, vec![]),
            }
        }
        reply
    }

    fn traffic(&self, kind: TrafficKind, pdu: Vec<u8>) {
        let _ = self.shared.traffic.send(Arc::new(TrafficFrame {
            channel: self.channel,
            time: self.clock.wall(),
            kind,
            pdu,
        }));
    }

    async fn carry_writes(&mut self) {
        while let Ok(r) = self.writes.try_recv() {
            self.carry(r).await;
        }
    }

    /// Burst frames heard: to the subscribers (HART-IP), and into the image.
    fn bursts(&mut self) {
        for b in self.line.take_bursts() {
            if let Ok(f) = Frame::parse_pdu(&b) {
                if let (Some(p), Some(rc), Some(status)) = (
                    self.position_of(&f.address),
                    f.response_code,
                    f.device_status,
                ) {
                    let (command, data) = (f.command, f.data.to_vec());
                    let (now, wall) = (self.clock.now(), self.clock.wall());
                    self.shared
                        .image
                        .update(p, |d| d.apply_reply(command, rc, status, &data, now, wall));
                }
            }
            if self.shared.traffic.receiver_count() > 0 {
                self.traffic(TrafficKind::Burst, b.clone());
            }
            let _ = self.shared.bursts.send(b);
        }
    }
}

/// One reply of a poll, kept until the poll's commit.
struct Reply {
    command: u16,
    rc: u8,
    status: u8,
    data: Vec<u8>,
    instant: Instant,
    wall: std::time::SystemTime,
}

impl Reply {
    fn new(clock: &Clock, command: u16, rc: u8, status: u8, data: Vec<u8>) -> Self {
        Reply {
            command,
            rc,
            status,
            data,
            instant: clock.now(),
            wall: clock.wall(),
        }
    }
}

fn micros(d: Duration) -> Micros {
    d.as_micros().min(u128::from(u64::MAX)) as Micros
}
