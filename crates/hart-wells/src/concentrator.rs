//! The data concentrator, sans-IO: master to its sensors (what to send next on the
//! bus, what a reply or a time-out means), slave on its uplink (a request in, a reply
//! out). The caller moves the bytes and the time; the same core runs on serial ports
//! and in the virtual-time simulation.
//!
//! [`ConcentratorCore`] does no I/O at all: what it needs from its store, or wants
//! kept there, comes out as a [`StoreOp`] (a poll's records as a [`PollCommit`]),
//! which its runner carries out and hands back. [`Concentrator`] is that runner over
//! the SQLite [`Store`].

use tracing::{error, info, warn};

use crate::calibration::{Sensor, Table};
use crate::proto::{
    decode_transfer_request, Assembled, Diagnosis, Groups, Message, Parameters, Record,
    SegmentReply, SegmentRequest, SensorStatus, Station, TableAssembler, CALIBRATION, DIAGNOSTICS,
    NO_VALUE, PARAMETERS, RC_NOT_IMPLEMENTED, RC_TOO_FEW_BYTES, RC_TOO_LARGE, READ_VALUES,
    SEGMENT_TAKEN, STATE_NOT_ANSWERING, STATUS_NORMAL, TABLE_IN_FORCE, TRANSFER, VALID_LEVEL,
    VALID_LEVEL_SENSOR_TEMPERATURE, VALID_TEMPERATURE,
};
use crate::store::{PollOutcome, Store, StoreError};
use crate::Millis;

/// Response code the concentrator answers when its store fails (device-specific
/// command error).
pub const RC_STORE_FAILED: u8 = 6;

/// How a concentrator is set up.
#[derive(Debug, Clone, PartialEq)]
pub struct ConcentratorConfig {
    /// Its well (1-15).
    pub well: u8,
    /// Its sensors: bus address and what each measures (one of each kind).
    pub sensors: Vec<(u8, Sensor)>,
    /// Time between polls.
    pub poll_interval: Millis,
    /// Retries of a request that got no reply.
    pub retries: u8,
}

impl ConcentratorConfig {
    /// The reference deployment: water temperature at 1, level at 2, polled every 3
    /// minutes, two retries.
    pub fn reference(well: u8) -> Self {
        ConcentratorConfig {
            well,
            sensors: vec![(1, Sensor::Temperature), (2, Sensor::Level)],
            poll_interval: 180_000,
            retries: 2,
        }
    }
}

/// One sensor as the concentrator knows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorView {
    /// Its status (address, kind, state, last good minute).
    pub status: SensorStatus,
    /// Its latest value in engineering units.
    pub latest: Option<f64>,
}

#[derive(Debug, Clone)]
struct Cycle {
    /// The sensor being asked.
    index: usize,
    /// The command being asked.
    command: u8,
    /// Tries of that command so far.
    tries: u8,
    /// Groups received per sensor, with the minute in progress when each request
    /// reached its sensor (its groups are the three minutes before).
    groups: Vec<Option<(u32, Groups)>>,
    /// A request is out.
    outstanding: bool,
}

/// What the concentrator's store held at start-up: the runner reads it
/// ([`Restored::load`]) and the core starts from it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Restored {
    /// The tables downloaded earlier (none: the built-in ones), temperature then level.
    pub tables: [Option<Table>; 2],
    /// The sensors' states as last stored.
    pub sensors: Vec<SensorStatus>,
    /// The poll interval changed online, in seconds.
    pub poll_interval_s: Option<i64>,
    /// The retries changed online.
    pub retries: Option<i64>,
    /// The newest stored minute (0: none).
    pub newest: u32,
}

impl Restored {
    /// Reads what a restarted concentrator starts from out of `store`.
    pub fn load(store: &Store) -> Result<Self, StoreError> {
        Ok(Restored {
            tables: [
                store.calibration(Sensor::Temperature)?,
                store.calibration(Sensor::Level)?,
            ],
            sensors: store.sensors()?,
            poll_interval_s: store.parameter("poll_interval_s")?,
            retries: store.parameter("retries")?,
            newest: store.counts()?.2,
        })
    }
}

/// A store operation the core needs before it can answer on the uplink.
#[derive(Debug, Clone, PartialEq)]
pub enum StoreOp {
    /// Read the newest stored minute (command 1).
    Latest,
    /// Read the station status at `minute` with `sensors` (command 14).
    Status {
        /// The minute in progress.
        minute: u32,
        /// The sensors as the core sees them.
        sensors: Vec<SensorStatus>,
    },
    /// Hand over the next batch after acknowledging `ack` (command 144).
    Transfer {
        /// What the collector acknowledged.
        ack: u32,
        /// The minute in progress.
        minute: u32,
        /// The valid bits of a complete minute.
        full: u8,
    },
    /// Keep a parameter changed online (command 161).
    SetParameter {
        /// Its name.
        key: &'static str,
        /// Its value.
        value: i64,
    },
    /// Keep a complete calibration table, now in force (command 160).
    SetCalibration {
        /// The sensor it is for.
        sensor: Sensor,
        /// The table.
        table: Box<Table>,
    },
}

/// What the runner found carrying out a [`StoreOp`].
#[derive(Debug, Clone)]
pub enum StoreDone {
    /// [`StoreOp::Latest`]: the newest minute.
    Latest(Option<Record>),
    /// [`StoreOp::Status`]: the status.
    Status(crate::proto::StationStatus),
    /// [`StoreOp::Transfer`]: the batch handed over.
    Transfer(crate::proto::Batch),
    /// [`StoreOp::SetParameter`] or [`StoreOp::SetCalibration`]: kept.
    Written,
}

/// A poll's outcome for the store: its records and the sensors' states, to be kept in
/// one transaction ([`Store::commit_poll`]); the runner hands the result back with
/// [`ConcentratorCore::committed`].
#[derive(Debug, Clone, PartialEq)]
pub struct PollCommit {
    /// The minutes the poll brought (and those a failed commit left).
    pub records: Vec<Record>,
    /// The sensors' states.
    pub sensors: Vec<SensorStatus>,
    /// The minute in progress.
    pub minute: u32,
}

/// One step of answering on the uplink.
#[derive(Debug, Clone, PartialEq)]
pub enum Uplink {
    /// Send this reply.
    Reply(Message),
    /// Carry out this store operation, then hand its result to
    /// [`ConcentratorCore::resume`]. A reply that acknowledges a change is only made
    /// after the change is kept.
    Need(StoreOp),
}

/// The data concentrator, sans-IO (see the module's documentation).
pub struct ConcentratorCore {
    cfg: ConcentratorConfig,
    tables: [Table; 2],
    sensors: Vec<SensorView>,
    next_poll: Millis,
    cycle: Option<Cycle>,
    assembler: TableAssembler,
    /// Records a failed commit could not write: tried again with the next poll.
    unsaved: Vec<Record>,
    /// Polls completed.
    pub polls: u64,
    /// Bus requests that got no reply.
    pub bus_timeouts: u64,
    /// Uplink requests answered.
    pub uplink_answered: u64,
}

fn kind_index(s: Sensor) -> usize {
    match s {
        Sensor::Temperature => 0,
        Sensor::Level => 1,
    }
}

impl ConcentratorCore {
    /// A concentrator restarted from `restored`, first polling at the first poll time
    /// after `now`.
    pub fn new(cfg: ConcentratorConfig, restored: Restored, now: Millis) -> Self {
        let [temperature, level] = restored.tables;
        let tables = [
            temperature.unwrap_or_else(|| Table::builtin(Sensor::Temperature)),
            level.unwrap_or_else(|| Table::builtin(Sensor::Level)),
        ];
        let known = restored.sensors;
        let sensors = cfg
            .sensors
            .iter()
            .map(|&(address, kind)| {
                let old = known.iter().find(|s| s.address == address);
                SensorView {
                    status: SensorStatus {
                        address,
                        kind,
                        state: old.map_or(0, |s| s.state),
                        last_good: old.map_or(0, |s| s.last_good),
                    },
                    latest: None,
                }
            })
            .collect();
        let mut c = ConcentratorCore {
            cfg,
            tables,
            sensors,
            next_poll: 0,
            cycle: None,
            assembler: TableAssembler::default(),
            unsaved: Vec::new(),
            polls: 0,
            bus_timeouts: 0,
            uplink_answered: 0,
        };
        // Parameters changed online survive a restart.
        if let Some(v) = restored.poll_interval_s {
            c.cfg.poll_interval = v.clamp(1, 180) as Millis * 1000;
        }
        if let Some(v) = restored.retries {
            c.cfg.retries = v.clamp(0, 5) as u8;
        }
        c.next_poll = c.poll_time_after(now);
        // Back after a restart with a minute missing: poll at once, while the sensors
        // still hold it (they keep three).
        let newest = restored.newest;
        if newest > 0 && newest.saturating_add(1) < crate::minute_of(now) {
            c.next_poll = now;
        }
        c
    }

    /// Its configuration.
    pub fn config(&self) -> &ConcentratorConfig {
        &self.cfg
    }

    /// Its station address on the uplink.
    pub fn station(&self) -> Station {
        Station::concentrator(self.cfg.well)
    }

    /// The sensors as last seen.
    pub fn sensors(&self) -> &[SensorView] {
        &self.sensors
    }

    /// The table in force for `sensor`.
    pub fn table(&self, sensor: Sensor) -> &Table {
        &self.tables[kind_index(sensor)]
    }

    /// Polls start on multiples of the interval, 10 s after (or a quarter of an
    /// interval under 40 s), so the sensors have closed the minute.
    fn poll_time_after(&self, now: Millis) -> Millis {
        let i = self.cfg.poll_interval.max(1);
        let offset = (i / 4).min(10_000);
        let base = (now.saturating_sub(offset) / i + 1) * i + offset;
        if base <= now {
            base + i
        } else {
            base
        }
    }

    /// When the bus next needs the caller: the next poll, or now while a poll is in
    /// progress.
    pub fn next_deadline(&self) -> Millis {
        match &self.cycle {
            Some(_) => 0,
            None => self.next_poll,
        }
    }

    /// Whether a poll is in progress.
    pub fn polling(&self) -> bool {
        self.cycle.is_some()
    }

    /// What to send on the bus now, if anything: a poll that is due starts; the
    /// request in progress is sent (again). The caller sends it and reports the
    /// reply or the time-out with [`ConcentratorCore::bus_result`].
    pub fn bus_request(&mut self, now: Millis) -> Option<Message> {
        if self.cycle.is_none() && self.next_poll > now + 2 * self.cfg.poll_interval + 10_000 {
            // The clock was set back: poll on the new time base instead of waiting
            // out the step (the sensors keep only three minutes).
            warn!(
                well = self.cfg.well,
                "the clock went back {} s; polling on the new time",
                (self.next_poll - now) / 1000
            );
            self.next_poll = self.poll_time_after(now);
        }
        if self.cycle.is_none() {
            if now < self.next_poll || self.sensors.is_empty() {
                return None;
            }
            self.cycle = Some(Cycle {
                index: 0,
                command: READ_VALUES,
                tries: 0,
                groups: vec![None; self.sensors.len()],
                outstanding: false,
            });
        }
        let c = self.cycle.as_mut()?;
        if c.outstanding {
            return None;
        }
        c.outstanding = true;
        c.tries += 1;
        let addr = self.sensors[c.index].status.address;
        Some(Message::request(Station::sensor(addr), c.command, vec![]))
    }

    /// The outcome of the request [`ConcentratorCore::bus_request`] gave: its reply, or
    /// `None` after the reply time-out, and `now`, the time the request reached the
    /// sensor (its groups are the three minutes before the one in progress then).
    /// Returns what the poll brought, for the store, when this completed it.
    pub fn bus_result(&mut self, now: Millis, reply: Option<&Message>) -> Option<PollCommit> {
        let c = self.cycle.as_mut()?;
        if !c.outstanding {
            return None;
        }
        c.outstanding = false;
        let sensor = &mut self.sensors[c.index];
        let addr = sensor.status.address;
        let reply = reply
            .filter(|m| m.reply && m.station == Station::sensor(addr) && m.command == c.command);
        let mut next = false;
        match (c.command, reply) {
            (_, None) => {
                self.bus_timeouts += 1;
                if c.tries > self.cfg.retries {
                    if sensor.status.state != STATE_NOT_ANSWERING {
                        warn!(well = self.cfg.well, "sensor {addr} does not answer");
                    }
                    sensor.status.state = STATE_NOT_ANSWERING;
                    next = true;
                }
            }
            (READ_VALUES, Some(m)) => {
                let status = m.status.unwrap_or([0xFF, 0xFF]);
                match Groups::decode(status, &m.data) {
                    Ok(g) => {
                        let normal = g.status == STATUS_NORMAL;
                        c.groups[c.index] = Some((crate::minute_of(now), g));
                        if normal {
                            sensor.status.state = 0;
                            next = true;
                        } else {
                            c.command = DIAGNOSTICS;
                            c.tries = 0;
                        }
                    }
                    Err(e) => {
                        warn!(well = self.cfg.well, "sensor {addr}: {e}");
                        if c.tries > self.cfg.retries {
                            next = true;
                        }
                    }
                }
            }
            (_, Some(m)) => {
                let code = m.status.map_or(0, |s| s[1]);
                if Diagnosis::from_code(code) != Some(Diagnosis::Healthy)
                    && sensor.status.state != code
                {
                    warn!(
                        well = self.cfg.well,
                        "sensor {addr}: {}",
                        crate::proto::state_name(code)
                    );
                }
                sensor.status.state = code;
                next = true;
            }
        }
        if !next {
            return None;
        }
        c.index += 1;
        c.command = READ_VALUES;
        c.tries = 0;
        if c.index < self.sensors.len() {
            return None;
        }
        let cycle = self.cycle.take()?;
        self.next_poll = self.poll_time_after(now);
        Some(self.commit(cycle, now))
    }

    fn commit(&mut self, cycle: Cycle, now: Millis) -> PollCommit {
        // Each sensor's groups are the three minutes before the one in progress when
        // its request reached it (a poll held up across a minute's end still files
        // each sensor's right).
        let mut by_minute: std::collections::BTreeMap<u32, Record> = Default::default();
        for (view, groups) in self.sensors.iter_mut().zip(&cycle.groups) {
            let Some((at, g)) = groups else { continue };
            let table = &self.tables[kind_index(view.status.kind)];
            for (k, v) in g.groups.iter().enumerate() {
                if v[0] == NO_VALUE || *at < 3 {
                    continue;
                }
                let minute = at - 3 + k as u32;
                let r = by_minute
                    .entry(minute)
                    .or_insert_with(|| Record::empty(minute));
                let x = table.eval(v[0]);
                if !x.is_finite() {
                    // Checked tables are finite over every count; should one not be,
                    // the minute stays invalid rather than valid with no value.
                    continue;
                }
                match view.status.kind {
                    Sensor::Temperature => {
                        r.valid |= VALID_TEMPERATURE;
                        r.t_raw = v[0];
                        r.temperature = x;
                    }
                    Sensor::Level => {
                        r.valid |= VALID_LEVEL;
                        r.l_raw = v[0];
                        r.level = x;
                        if v[1] != NO_VALUE {
                            r.valid |= VALID_LEVEL_SENSOR_TEMPERATURE;
                            r.ls_raw = v[1];
                        }
                    }
                }
                view.status.last_good = view.status.last_good.max(r.minute);
                view.latest = Some(x);
            }
        }
        let mut records = std::mem::take(&mut self.unsaved);
        records.extend(by_minute.into_values());
        PollCommit {
            records,
            sensors: self.sensors.iter().map(|s| s.status).collect(),
            minute: (now / 60_000) as u32,
        }
    }

    /// The store's answer to a [`PollCommit`]: counts the poll, or keeps its records
    /// in memory to be written with the next one. Returns `result`.
    pub fn committed(
        &mut self,
        commit: PollCommit,
        result: Result<PollOutcome, StoreError>,
    ) -> Result<PollOutcome, StoreError> {
        match result {
            Ok(o) => {
                self.polls += 1;
                if o.dropped_unsent > 0 {
                    error!(
                        well = self.cfg.well,
                        "store full: {} minutes dropped before they were handed over; collect the data",
                        o.dropped_unsent
                    );
                }
                Ok(o)
            }
            Err(e) => {
                error!(
                    well = self.cfg.well,
                    "{e}; the poll is kept in memory and written with the next one"
                );
                let mut all = commit.records;
                all.retain(|r| r.valid != 0);
                // Keep at most a day in memory.
                let keep = all.len().saturating_sub(1440);
                all.drain(..keep);
                self.unsaved = all;
                Err(e)
            }
        }
    }

    /// Takes a request on the uplink (`None`: not for this concentrator, or not a
    /// request): the reply, or the store operation it needs first.
    pub fn uplink(&mut self, msg: &Message, now: Millis) -> Option<Uplink> {
        if msg.reply || msg.station != self.station() {
            return None;
        }
        self.uplink_answered += 1;
        let minute = (now / 60_000) as u32;
        let st = self.station();
        let reply =
            |rc: u8, data: Vec<u8>| Uplink::Reply(Message::reply(st, msg.command, [rc, 0], data));
        Some(match msg.command {
            READ_VALUES => Uplink::Need(StoreOp::Latest),
            DIAGNOSTICS => Uplink::Need(StoreOp::Status {
                minute,
                sensors: self.sensors.iter().map(|s| s.status).collect(),
            }),
            TRANSFER => match decode_transfer_request(&msg.data) {
                Err(_) => reply(RC_TOO_FEW_BYTES, vec![]),
                Ok(ack) => Uplink::Need(StoreOp::Transfer {
                    ack,
                    minute,
                    full: self.full_mask(),
                }),
            },
            CALIBRATION => match SegmentRequest::decode(&msg.data) {
                Err((rc, e)) => {
                    warn!(well = self.cfg.well, "{e}");
                    reply(rc, vec![])
                }
                Ok(seg) => match self.assembler.take(seg) {
                    Assembled::Taken => reply(0, SegmentReply::to(&seg, SEGMENT_TAKEN).encode()),
                    Assembled::AlreadyInForce => {
                        reply(0, SegmentReply::to(&seg, TABLE_IN_FORCE).encode())
                    }
                    Assembled::Refused(rc, why) => {
                        warn!(
                            well = self.cfg.well,
                            "calibration refused, the old table stays in force: {why}"
                        );
                        reply(rc, vec![])
                    }
                    Assembled::Table(sensor, table) => {
                        Uplink::Need(StoreOp::SetCalibration { sensor, table })
                    }
                },
            },
            PARAMETERS => match Parameters::decode(&msg.data) {
                Err(_) => reply(RC_TOO_FEW_BYTES, vec![]),
                Ok(p) => {
                    if p.poll_interval_s > 180 || (p.retries > 5 && p.retries != 0xFF) {
                        warn!(
                            well = self.cfg.well,
                            "parameters refused: poll interval {} s (1-180), retries {} (0-5)",
                            p.poll_interval_s,
                            p.retries
                        );
                        return Some(reply(RC_TOO_LARGE, vec![]));
                    }
                    self.parameters_step(msg, p, None)
                }
            },
            _ => reply(RC_NOT_IMPLEMENTED, vec![]),
        })
    }

    /// The reply to `msg` with `rc` and `data`.
    fn reply(&self, msg: &Message, rc: u8, data: Vec<u8>) -> Message {
        Message::reply(self.station(), msg.command, [rc, 0], data)
    }

    /// Command 161, after the parameter `done` (if any) was kept: the next one to keep,
    /// or the reply with the values in force.
    fn parameters_step(&self, msg: &Message, p: Parameters, done: Option<&str>) -> Uplink {
        if p.poll_interval_s != 0 && done.is_none() {
            return Uplink::Need(StoreOp::SetParameter {
                key: "poll_interval_s",
                value: p.poll_interval_s as i64,
            });
        }
        if p.retries != 0xFF && done != Some("retries") {
            return Uplink::Need(StoreOp::SetParameter {
                key: "retries",
                value: p.retries as i64,
            });
        }
        Uplink::Reply(self.reply(msg, 0, self.parameters().encode()))
    }

    /// Takes the result of the store operation [`ConcentratorCore::uplink`] (or an
    /// earlier `resume`) asked for while answering `msg`: the reply, or the next
    /// operation.
    pub fn resume(
        &mut self,
        msg: &Message,
        op: StoreOp,
        result: Result<StoreDone, StoreError>,
        now: Millis,
    ) -> Uplink {
        let failed = |c: &Self, e: &dyn std::fmt::Display| {
            error!("{e}");
            Uplink::Reply(c.reply(msg, RC_STORE_FAILED, vec![]))
        };
        let done = match result {
            Ok(d) => d,
            Err(e) => {
                if matches!(op, StoreOp::SetCalibration { .. }) {
                    error!("{e}; the old table stays in force");
                    return Uplink::Reply(self.reply(msg, RC_STORE_FAILED, vec![]));
                }
                return failed(self, &e);
            }
        };
        match (op, done) {
            (StoreOp::Latest, StoreDone::Latest(r)) => {
                let mut d = Vec::new();
                if let Some(r) = r {
                    r.encode(&mut d);
                }
                Uplink::Reply(self.reply(msg, 0, d))
            }
            (StoreOp::Status { .. }, StoreDone::Status(s)) => {
                let (status, d) = s.encode();
                Uplink::Reply(Message::reply(self.station(), DIAGNOSTICS, status, d))
            }
            (StoreOp::Transfer { .. }, StoreDone::Transfer(b)) => {
                Uplink::Reply(self.reply(msg, 0, b.encode()))
            }
            (StoreOp::SetCalibration { sensor, table }, StoreDone::Written) => {
                let Ok(seg) = SegmentRequest::decode(&msg.data) else {
                    return failed(self, &"calibration kept for a request that is not one");
                };
                self.assembler.confirm(sensor, seg.segment);
                info!(
                    well = self.cfg.well,
                    "new {} calibration table in force",
                    sensor.name()
                );
                self.tables[kind_index(sensor)] = *table;
                Uplink::Reply(self.reply(msg, 0, SegmentReply::to(&seg, TABLE_IN_FORCE).encode()))
            }
            (StoreOp::SetParameter { key, value }, StoreDone::Written) => {
                let Ok(p) = Parameters::decode(&msg.data) else {
                    return failed(self, &"parameter kept for a request that is not one");
                };
                if key == "poll_interval_s" {
                    self.cfg.poll_interval = value as Millis * 1000;
                    if self.cycle.is_none() {
                        self.next_poll = self.poll_time_after(now);
                    }
                    info!(well = self.cfg.well, "poll interval now {value} s");
                } else {
                    self.cfg.retries = value as u8;
                }
                self.parameters_step(msg, p, Some(key))
            }
            (op, done) => failed(self, &format!("the store answered {op:?} with {done:?}")),
        }
    }

    /// The valid bits of a minute with every quantity this concentrator's working
    /// sensors give (a sensor not answering or faulty gives nothing to wait for).
    pub fn full_mask(&self) -> u8 {
        self.sensors
            .iter()
            .filter(|s| s.status.state == 0)
            .fold(0, |m, s| {
                m | match s.status.kind {
                    Sensor::Temperature => VALID_TEMPERATURE,
                    Sensor::Level => VALID_LEVEL,
                }
            })
    }

    /// The parameters in force.
    pub fn parameters(&self) -> Parameters {
        Parameters {
            poll_interval_s: (self.cfg.poll_interval / 1000).clamp(1, 180) as u16,
            retries: self.cfg.retries,
        }
    }
}

/// The concentrator on its SQLite [`Store`]: the runner of a [`ConcentratorCore`],
/// which carries out the store operations the core asks for. A change the core
/// acknowledges on the uplink (a parameter, a calibration table) is written before
/// the reply is made, so the reply's sender only ever acknowledges what is kept. The
/// core's own methods are reached through `Deref`.
pub struct Concentrator {
    core: ConcentratorCore,
    store: Store,
}

impl std::ops::Deref for Concentrator {
    type Target = ConcentratorCore;
    fn deref(&self) -> &ConcentratorCore {
        &self.core
    }
}

impl std::ops::DerefMut for Concentrator {
    fn deref_mut(&mut self) -> &mut ConcentratorCore {
        &mut self.core
    }
}

impl Concentrator {
    /// A concentrator on `store`, first polling at the first poll time after `now`.
    pub fn new(cfg: ConcentratorConfig, store: Store, now: Millis) -> Result<Self, StoreError> {
        let restored = Restored::load(&store)?;
        Ok(Concentrator {
            core: ConcentratorCore::new(cfg, restored, now),
            store,
        })
    }

    /// Its store.
    pub fn store(&self) -> &Store {
        &self.store
    }

    /// The outcome of the request [`ConcentratorCore::bus_request`] gave (see
    /// [`ConcentratorCore::bus_result`]); returns what the poll stored when this
    /// completed it.
    pub fn bus_result(
        &mut self,
        now: Millis,
        reply: Option<&Message>,
    ) -> Option<Result<PollOutcome, StoreError>> {
        let commit = self.core.bus_result(now, reply)?;
        let result = self
            .store
            .commit_poll(&commit.records, &commit.sensors, commit.minute);
        Some(self.core.committed(commit, result))
    }

    /// The latest values in engineering units: water temperature (°C), level (m),
    /// the level sensor's temperature (°C), from the newest stored minute.
    pub fn latest(&self) -> Result<Option<Record>, StoreError> {
        let (_, _, newest) = self.store.counts()?;
        self.store.get(newest)
    }

    /// Answers a request on the uplink (`None`: not for this concentrator, or not a
    /// request), carrying out what the core needs from the store first.
    pub fn uplink(&mut self, msg: &Message, now: Millis) -> Option<Message> {
        let mut step = self.core.uplink(msg, now)?;
        loop {
            match step {
                Uplink::Reply(m) => return Some(m),
                Uplink::Need(op) => {
                    let result = self.carry_out(&op);
                    step = self.core.resume(msg, op, result, now);
                }
            }
        }
    }

    /// Carries out one store operation.
    fn carry_out(&mut self, op: &StoreOp) -> Result<StoreDone, StoreError> {
        match op {
            StoreOp::Latest => self.latest().map(StoreDone::Latest),
            StoreOp::Status { minute, sensors } => self
                .store
                .status(*minute, sensors.clone())
                .map(StoreDone::Status),
            StoreOp::Transfer { ack, minute, full } => self
                .store
                .transfer(*ack, *minute, *full)
                .map(StoreDone::Transfer),
            StoreOp::SetParameter { key, value } => self
                .store
                .set_parameter(key, *value)
                .map(|()| StoreDone::Written),
            StoreOp::SetCalibration { sensor, table } => self
                .store
                .set_calibration(*sensor, table)
                .map(|()| StoreDone::Written),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::Durability;

    fn conc(d: &tempfile::TempDir, now: Millis) -> Concentrator {
        let store = Store::open(&d.path().join("c.db"), 1, 0, Durability::Process).unwrap();
        Concentrator::new(ConcentratorConfig::reference(1), store, now).unwrap()
    }

    /// The core polls, answers and takes a calibration with no store at all: what is
    /// to be kept or read comes out as an effect, and a change is acknowledged only
    /// once the runner says it is kept.
    #[test]
    fn the_core_runs_without_a_store_and_asks_for_what_it_needs() {
        let t0 = 29_500_000 * 60_000;
        let mut c =
            ConcentratorCore::new(ConcentratorConfig::reference(1), Restored::default(), t0);
        let start = c.next_deadline();
        let g = Groups {
            status: 0,
            width: 1,
            groups: [[100, 5], [101, 5], [102, 5]],
        };
        let (s, data) = g.encode();
        let r1 = c.bus_request(start).unwrap();
        assert!(c
            .bus_result(
                start + 100,
                Some(&Message::reply(r1.station, 1, s, data.clone()))
            )
            .is_none());
        let r2 = c.bus_request(start + 200).unwrap();
        let commit = c
            .bus_result(start + 300, Some(&Message::reply(r2.station, 1, s, data)))
            .expect("the poll is complete");
        assert_eq!(commit.records.len(), 3);
        assert_eq!(commit.sensors.len(), 2);
        // A failed commit keeps the records for the next poll.
        let err = StoreError {
            path: "nowhere".into(),
            what: "no store".into(),
        };
        assert!(c.committed(commit.clone(), Err(err)).is_err());
        assert_eq!(c.polls, 0);

        let station = c.station();
        let read = Message::request(station, READ_VALUES, vec![]);
        assert_eq!(c.uplink(&read, start), Some(Uplink::Need(StoreOp::Latest)));

        let p = Parameters {
            poll_interval_s: 60,
            retries: 0xFF,
        };
        let set = Message::request(station, PARAMETERS, p.encode());
        let Some(Uplink::Need(op)) = c.uplink(&set, start) else {
            panic!("a parameter change is kept before it is acknowledged");
        };
        assert_eq!(
            op,
            StoreOp::SetParameter {
                key: "poll_interval_s",
                value: 60
            }
        );
        assert_eq!(c.config().poll_interval, 180_000, "not yet in force");
        let Uplink::Reply(m) = c.resume(&set, op, Ok(StoreDone::Written), start) else {
            panic!("one parameter to keep");
        };
        assert_eq!(m.status, Some([0, 0]));
        assert_eq!(c.config().poll_interval, 60_000);
    }

    #[test]
    fn a_clock_set_back_polls_on_the_new_time() {
        let d = tempfile::tempdir().unwrap();
        let t0 = 29_500_000 * 60_000;
        let mut c = conc(&d, t0);
        assert!(c.bus_request(t0).is_none());
        // Ten minutes back: the next poll is within a poll interval of the new time.
        let back = t0 - 600_000;
        assert!(c.bus_request(back).is_none());
        assert!(
            c.next_deadline() <= back + 180_000 + 10_000,
            "{}",
            c.next_deadline() - back
        );
    }

    #[test]
    fn each_reply_is_filed_by_the_minute_it_arrived_in() {
        let d = tempfile::tempdir().unwrap();
        let t0 = 29_500_000 * 60_000;
        let mut c = conc(&d, t0);
        let start = c.next_deadline();
        let groups = |w: usize| {
            let g = Groups {
                status: 0,
                width: w,
                groups: [[100, 5], [101, 5], [102, 5]],
            };
            let (s, data) = g.encode();
            (s, data)
        };
        // Temperature answers in one minute, the level sensor (after retries) in the
        // next.
        let r1 = c.bus_request(start).unwrap();
        let (s, data) = groups(1);
        c.bus_result(start + 100, Some(&Message::reply(r1.station, 1, s, data)));
        let r2 = c.bus_request(start + 200).unwrap();
        let late = (start / 60_000 + 1) * 60_000 + 500;
        let (s, data) = groups(2);
        let o = c
            .bus_result(late, Some(&Message::reply(r2.station, 1, s, data)))
            .unwrap()
            .unwrap();
        // Minutes m-3..m-1 from the first, m-2..m from the second: four minutes.
        assert_eq!(o.new_minutes, 4);
        let m = (start / 60_000) as u32;
        let first = c.store().get(m - 3).unwrap().unwrap();
        assert_eq!((first.valid, first.t_raw), (VALID_TEMPERATURE, 100));
        let last = c.store().get(m).unwrap().unwrap();
        assert_eq!(last.valid & VALID_LEVEL, VALID_LEVEL);
        assert_eq!(last.l_raw, 102);
    }
}
