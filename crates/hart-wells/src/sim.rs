//! The whole network in virtual time: sensors, concentrators with their stores,
//! telephone lines that fail, a handheld that collects during long outages and hands
//! over at the bureau, and the PC's schedule, on the same role cores and stores as
//! the real-time programs. Each exchange costs the time its frames take on the line.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};
use std::path::PathBuf;
use std::time::Instant;

use hart_rng::Rng;

use crate::archive::{Archive, Collector, PullLog, Step, Via};
use crate::calibration::Sensor;
use crate::concentrator::{Concentrator, ConcentratorConfig};
use crate::handheld::HandheldStation;
use crate::proto::{Message, Station, StationStatus, DIAGNOSTICS};
use crate::sensor::{Fault, SensorConfig, SimSensor};
use crate::store::{Durability, Store, StoreError, DAY_MINUTES};
use crate::Millis;

/// What to simulate.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// Wells (1-15).
    pub wells: u8,
    /// Days of virtual time.
    pub days: f64,
    /// Telephone outages per well per day (each starts at a random time).
    pub phone_outage_rate: f64,
    /// Mean length of an outage, days (exponentially distributed).
    pub outage_mean_days: f64,
    /// Days between the handheld's checks for wells in a long outage.
    pub handheld_every: f64,
    /// Hours between the PC's scheduled rounds.
    pub pull_every_hours: f64,
    /// Probability that a frame on a working telephone line is lost to noise.
    pub frame_loss: f64,
    /// Power losses per concentrator per day (the concentrator restarts from its
    /// store a minute or two later).
    pub restart_rate: f64,
    /// Room in each concentrator's store, days.
    pub capacity_days: u32,
    /// Seconds between a concentrator's polls.
    pub poll_interval_s: u64,
    /// Failures per sensor per day: the sensor stops answering for a while
    /// (exponentially distributed, mean half a day).
    pub sensor_failure_rate: f64,
    /// Bit rate of the telephone modems and the handheld's cable.
    pub uplink_baud: u32,
    /// Seed of everything random.
    pub seed: u64,
    /// Where the stores go (a temporary directory if `None`).
    pub dir: Option<PathBuf>,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            wells: 3,
            days: 30.0,
            phone_outage_rate: 0.1,
            outage_mean_days: 2.0,
            handheld_every: 3.0,
            pull_every_hours: 6.0,
            frame_loss: 0.002,
            restart_rate: 0.05,
            capacity_days: 14,
            poll_interval_s: 180,
            sensor_failure_rate: 0.0,
            uplink_baud: 1200,
            seed: 1,
            dir: None,
        }
    }
}

/// A well the PC could not reach on a round.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Unreachable {
    /// The well.
    pub well: u8,
    /// Day of the simulation.
    pub day: f64,
    /// Why.
    pub reason: String,
}

/// What the simulation found (`hartkit wells sim --json`).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SimReport {
    /// Wells simulated.
    pub wells: u8,
    /// Days simulated.
    pub days: f64,
    /// Minutes the concentrators stored (each well's minutes counted once).
    pub minutes_sampled: u64,
    /// Minutes in the PC's archive at the end.
    pub minutes_at_pc: u64,
    /// Minutes no concentrator stored a value for (between each well's first and
    /// last minute): the sensors keep three minutes, so a concentrator that is down
    /// over a poll for longer than that misses minutes. Not data lost: it never
    /// existed outside the sensor.
    pub minutes_missed: u64,
    /// Minutes sampled that never reached the PC.
    pub lost: u64,
    /// Minutes the PC or the handheld received twice.
    pub duplicated: u64,
    /// The fullest any concentrator's store got with minutes not yet handed over, as
    /// a fraction of its room (handed-over minutes stay as a local archive until their
    /// room is needed, and do not count).
    pub max_store_fill: f64,
    /// Minutes not yet at the PC when the simulated period ended (handed over by the
    /// final drain).
    pub pending_at_end: u64,
    /// Minutes a store dropped before they were handed over.
    pub dropped_unsent: u64,
    /// Polls completed by all concentrators.
    pub polls: u64,
    /// The PC's attempts to pull a well.
    pub pulls: u64,
    /// Of those, complete.
    pub pulls_complete: u64,
    /// Of those, cut off part way (resumed on a later attempt).
    pub pulls_cut: u64,
    /// Rounds on which a well could not be reached at all.
    pub unreachable: Vec<Unreachable>,
    /// Command-144 batches received by the PC and the handheld.
    pub batches: u64,
    /// Telephone outages.
    pub outages: u64,
    /// Well-days without a telephone line.
    pub outage_days: f64,
    /// Concentrator restarts.
    pub restarts: u64,
    /// Times a sensor stopped answering.
    pub sensor_failures: u64,
    /// Status reads at the PC that showed a sensor faulty or not answering.
    pub faults_reported: u64,
    /// Minutes at the PC with one of the quantities missing (its sensor was down).
    pub partial_minutes: u64,
    /// Handheld trips.
    pub handheld_trips: u64,
    /// Minutes that reached the PC through the handheld.
    pub minutes_via_handheld: u64,
    /// Minutes compared between a concentrator's store and the PC's archive.
    pub values_checked: u64,
    /// Of those, different.
    pub values_mismatched: u64,
    /// Wall-clock seconds the simulation took.
    pub elapsed_s: f64,
}

/// Virtual start: 2026-03-01 00:00 UTC.
pub const START: Millis = 1_772_323_200_000;
const MINUTE: Millis = 60_000;
const HOUR: Millis = 3_600_000;
const DAY: Millis = 86_400_000;

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Ev {
    Bus(usize, u32),
    Pc,
    Handheld,
    OutageStart(usize),
    OutageEnd(usize),
    PowerLoss(usize),
    PowerBack(usize),
    SensorFails(usize, usize),
    SensorBack(usize, usize),
}

struct Well {
    number: u8,
    sensors: Vec<SimSensor>,
    /// Every minute its concentrator stored, to compare with the PC's at the end.
    sampled: Vec<u32>,
    /// Sensors that do not answer now.
    silent: Vec<bool>,
    conc: Option<Concentrator>,
    store_path: PathBuf,
    generation: u32,
    bus_reply: Option<Option<Message>>,
    phone_up: bool,
    outage_since: Millis,
}

enum PcState {
    Idle,
    Session {
        well: u8,
        col: Collector,
        status_read: bool,
        /// Attempts at this well this round before this one.
        attempts: u8,
        /// Requests without a reply in a row.
        lost_in_row: u8,
    },
}

enum HhState {
    Home,
    Collect {
        wells: Vec<usize>,
        index: usize,
        col: Option<Collector>,
    },
    HandOver {
        wells: Vec<u8>,
        index: usize,
        col: Option<Collector>,
    },
}

#[derive(Clone, Copy)]
enum Line {
    Phone(usize),
    Direct,
}

#[derive(Clone, Copy)]
enum Target {
    Conc(usize),
    Handheld,
}

/// The simulation.
pub struct Sim {
    cfg: SimConfig,
    rng: Rng,
    now: Millis,
    end: Millis,
    queue: BinaryHeap<Reverse<(Millis, u64, Ev)>>,
    seq: u64,
    wells: Vec<Well>,
    pc: Archive,
    pc_state: PcState,
    pc_queue: VecDeque<(u8, u8)>,
    pc_next_round: Millis,
    hh: Archive,
    hh_station: HandheldStation,
    hh_state: HhState,
    report: SimReport,
    _tmp: Option<tempfile::TempDir>,
    dir: PathBuf,
}

fn frame_ms(bytes: usize, baud: u32) -> Millis {
    (bytes as u64 * 11_000).div_ceil(baud.max(1) as u64)
}

impl Sim {
    /// Sets up the network: stores in `cfg.dir` (or a temporary directory).
    pub fn new(cfg: SimConfig) -> Result<Self, StoreError> {
        let (tmp, dir) = match &cfg.dir {
            Some(d) => (None, d.clone()),
            None => {
                let t = tempfile::tempdir().map_err(|e| StoreError {
                    path: std::env::temp_dir(),
                    what: e.to_string(),
                })?;
                let p = t.path().to_path_buf();
                (Some(t), p)
            }
        };
        std::fs::create_dir_all(&dir).map_err(|e| StoreError {
            path: dir.clone(),
            what: e.to_string(),
        })?;
        let mut rng = Rng::new(cfg.seed);
        let mut wells = Vec::new();
        for n in 1..=cfg.wells.clamp(1, 15) {
            let store_path = dir.join(format!("well{n}.db"));
            let _ = std::fs::remove_file(&store_path);
            let sensors = [(1, Sensor::Temperature), (2, Sensor::Level)]
                .iter()
                .map(|&(address, kind)| {
                    SimSensor::new(SensorConfig {
                        address,
                        kind,
                        fault: Fault::None,
                        seed: cfg.seed
                            ^ ((n as u64) << 8 | address as u64).wrapping_mul(0x9E37_79B9),
                    })
                })
                .collect();
            let mut w = Well {
                number: n,
                sampled: Vec::new(),
                silent: vec![false; 2],
                sensors,
                conc: None,
                store_path,
                generation: 0,
                bus_reply: None,
                phone_up: true,
                outage_since: 0,
            };
            w.conc = Some(open_conc(&cfg, &w, START)?);
            wells.push(w);
        }
        for f in ["pc.db", "handheld.db"] {
            let _ = std::fs::remove_file(dir.join(f));
        }
        let pc = Archive::open(&dir.join("pc.db"), Durability::Process)?;
        let hh = Archive::open(&dir.join("handheld.db"), Durability::Process)?;
        let end = START + (cfg.days * DAY as f64) as Millis;
        let report = SimReport {
            wells: wells.len() as u8,
            days: cfg.days,
            minutes_sampled: 0,
            minutes_at_pc: 0,
            minutes_missed: 0,
            lost: 0,
            duplicated: 0,
            max_store_fill: 0.0,
            pending_at_end: 0,
            dropped_unsent: 0,
            polls: 0,
            pulls: 0,
            pulls_complete: 0,
            pulls_cut: 0,
            unreachable: vec![],
            batches: 0,
            outages: 0,
            outage_days: 0.0,
            restarts: 0,
            sensor_failures: 0,
            faults_reported: 0,
            partial_minutes: 0,
            handheld_trips: 0,
            minutes_via_handheld: 0,
            values_checked: 0,
            values_mismatched: 0,
            elapsed_s: 0.0,
        };
        let _ = rng.next_u64();
        let mut s = Sim {
            cfg,
            rng,
            now: START,
            end,
            queue: BinaryHeap::new(),
            seq: 0,
            wells,
            pc,
            pc_state: PcState::Idle,
            pc_queue: VecDeque::new(),
            pc_next_round: START,
            hh,
            hh_station: HandheldStation::new(),
            hh_state: HhState::Home,
            report,
            _tmp: tmp,
            dir,
        };
        for i in 0..s.wells.len() {
            let at = s.wells[i]
                .conc
                .as_ref()
                .map_or(START, |c| c.next_deadline());
            s.at(at, Ev::Bus(i, 0));
            let o = s.exp_days(s.cfg.phone_outage_rate);
            s.at(o, Ev::OutageStart(i));
            let r = s.exp_days(s.cfg.restart_rate);
            s.at(r, Ev::PowerLoss(i));
            for k in 0..2 {
                let f = s.exp_days(s.cfg.sensor_failure_rate);
                s.at(f, Ev::SensorFails(i, k));
            }
        }
        s.at(START + HOUR, Ev::Pc);
        s.pc_next_round = START + HOUR;
        let h = START + (s.cfg.handheld_every * DAY as f64) as Millis;
        s.at(h, Ev::Handheld);
        Ok(s)
    }

    /// Where the stores are.
    pub fn dir(&self) -> &std::path::Path {
        &self.dir
    }

    fn at(&mut self, t: Millis, ev: Ev) {
        self.seq += 1;
        self.queue.push(Reverse((t, self.seq, ev)));
    }

    /// A time `Exp(rate per day)` from now (never, past the end, for rate 0).
    fn exp_days(&mut self, rate: f64) -> Millis {
        if rate <= 0.0 {
            return Millis::MAX / 2;
        }
        let u = self.rng.uniform().max(1e-12);
        self.now + (-u.ln() / rate * DAY as f64) as Millis
    }

    /// Runs the period, then the drain (lines back, the handheld hands over, the PC
    /// pulls every well until nothing is left), and reports.
    pub fn run(mut self) -> Result<SimReport, StoreError> {
        let started = Instant::now();
        while let Some(Reverse((t, _, ev))) = self.queue.pop() {
            if t >= self.end {
                break;
            }
            self.now = t;
            self.step(ev)?;
        }
        self.now = self.end;
        for i in 0..self.wells.len() {
            if !self.wells[i].phone_up {
                self.report.outage_days +=
                    (self.end - self.wells[i].outage_since) as f64 / DAY as f64;
            }
        }
        self.drain()?;
        self.report.elapsed_s = started.elapsed().as_secs_f64();
        Ok(self.report)
    }

    fn step(&mut self, ev: Ev) -> Result<(), StoreError> {
        match ev {
            Ev::Bus(i, gen) => self.bus(i, gen)?,
            Ev::Pc => self.pc_step()?,
            Ev::Handheld => self.hh_step()?,
            Ev::OutageStart(i) => {
                let w = &mut self.wells[i];
                if w.phone_up {
                    w.phone_up = false;
                    w.outage_since = self.now;
                    self.report.outages += 1;
                }
                let len = (-(self.rng.uniform().max(1e-12)).ln()
                    * self.cfg.outage_mean_days
                    * DAY as f64) as Millis;
                self.at(self.now + len.max(MINUTE), Ev::OutageEnd(i));
            }
            Ev::OutageEnd(i) => {
                let w = &mut self.wells[i];
                if !w.phone_up {
                    w.phone_up = true;
                    self.report.outage_days += (self.now - w.outage_since) as f64 / DAY as f64;
                }
                let next = self.exp_days(self.cfg.phone_outage_rate);
                self.at(next, Ev::OutageStart(i));
            }
            Ev::PowerLoss(i) => {
                let w = &mut self.wells[i];
                if w.conc.take().is_some() {
                    self.report.restarts += 1;
                    w.generation += 1;
                    w.bus_reply = None;
                }
                let back = 30_000 + self.rng.next_u64() % 120_000;
                self.at(self.now + back, Ev::PowerBack(i));
            }
            Ev::SensorFails(i, k) => {
                self.wells[i].silent[k] = true;
                self.report.sensor_failures += 1;
                let len = (-(self.rng.uniform().max(1e-12)).ln() * 0.5 * DAY as f64) as Millis;
                self.at(self.now + len.max(MINUTE), Ev::SensorBack(i, k));
            }
            Ev::SensorBack(i, k) => {
                self.wells[i].silent[k] = false;
                let f = self.exp_days(self.cfg.sensor_failure_rate);
                self.at(f, Ev::SensorFails(i, k));
            }
            Ev::PowerBack(i) => {
                let c = open_conc(&self.cfg, &self.wells[i], self.now)?;
                let at = c.next_deadline();
                let w = &mut self.wells[i];
                w.conc = Some(c);
                w.generation += 1;
                let gen = w.generation;
                self.at(at, Ev::Bus(i, gen));
                let next = self.exp_days(self.cfg.restart_rate);
                self.at(next, Ev::PowerLoss(i));
            }
        }
        Ok(())
    }

    /// One step of a concentrator's bus: the reply (or time-out) of the request out,
    /// then the next request or the next poll time.
    fn bus(&mut self, i: usize, gen: u32) -> Result<(), StoreError> {
        let now = self.now;
        let w = &mut self.wells[i];
        if gen != w.generation {
            return Ok(());
        }
        let Some(conc) = w.conc.as_mut() else {
            return Ok(());
        };
        if let Some(reply) = w.bus_reply.take() {
            if let Some(r) = conc.bus_result(now, reply.as_ref()) {
                let o = r?;
                self.report.polls += 1;
                self.report.minutes_sampled += o.new_minutes as u64;
                w.sampled.extend_from_slice(&o.new_list);
                self.report.dropped_unsent += o.dropped_unsent as u64;
                let (_, unsent, _) = conc.store().counts()?;
                let fill = unsent as f64 / conc.store().capacity() as f64;
                if fill > self.report.max_store_fill {
                    self.report.max_store_fill = fill;
                }
            }
        }
        match conc.bus_request(now) {
            Some(req) => {
                let req_ms = frame_ms(req.to_bytes().len(), 1200);
                let silent = &w.silent;
                let reply = w
                    .sensors
                    .iter_mut()
                    .zip(silent)
                    .filter(|(_, &quiet)| !quiet)
                    .find_map(|(s, _)| s.handle(&req, now + req_ms));
                let done = match &reply {
                    Some(r) => now + req_ms + 20 + frame_ms(r.to_bytes().len(), 1200),
                    None => now + req_ms + 300,
                };
                w.bus_reply = Some(reply);
                self.at(done, Ev::Bus(i, gen));
            }
            None => {
                let at = conc.next_deadline().max(now + 1);
                self.at(at, Ev::Bus(i, gen));
            }
        }
        Ok(())
    }

    /// One exchange on the uplink: the request's time on the line, the station's
    /// answer, the reply's time; a lost frame costs the requester's time-out.
    fn transact(&mut self, target: Target, line: Line, req: &Message) -> (Option<Message>, Millis) {
        let baud = self.cfg.uplink_baud;
        let (latency, timeout) = match line {
            Line::Phone(_) => (150, 2_000),
            Line::Direct => (10, 500),
        };
        let t_req = self.now + frame_ms(req.to_bytes().len(), baud) + latency;
        let lost = match line {
            Line::Phone(i) => {
                !self.wells[i].phone_up
                    || self.rng.uniform() < self.cfg.frame_loss
                    || self.rng.uniform() < self.cfg.frame_loss
            }
            Line::Direct => false,
        };
        let answer = match target {
            Target::Conc(i) => self.wells[i]
                .conc
                .as_mut()
                .and_then(|c| c.uplink(req, t_req)),
            Target::Handheld => self.hh_station.answer(&mut self.hh, req, t_req),
        };
        match answer {
            Some(r) if !lost => {
                let t = t_req + frame_ms(r.to_bytes().len(), baud) + latency;
                (Some(r), t)
            }
            _ => (None, t_req + timeout),
        }
    }

    fn minute(&self) -> u32 {
        (self.now / MINUTE) as u32
    }

    fn pc_step(&mut self) -> Result<(), StoreError> {
        let state = std::mem::replace(&mut self.pc_state, PcState::Idle);
        match state {
            PcState::Idle => {
                if self.pc_queue.is_empty() {
                    if self.now < self.pc_next_round {
                        let t = self.pc_next_round;
                        self.at(t, Ev::Pc);
                        return Ok(());
                    }
                    self.pc_next_round += (self.cfg.pull_every_hours * HOUR as f64) as Millis;
                    for w in &self.wells {
                        self.pc_queue.push_back((w.number, 0));
                    }
                }
                let Some((well, attempts)) = self.pc_queue.pop_front() else {
                    return Ok(());
                };
                // Dialling takes about 25 s; a dead line answers NO CARRIER.
                let i = well as usize - 1;
                self.report.pulls += 1;
                if !self.wells[i].phone_up {
                    self.pc_failed(well, attempts, "NO CARRIER: the telephone line is down");
                    return Ok(());
                }
                let col = Collector::new(&self.pc, Station::concentrator(well))?;
                self.pc_state = PcState::Session {
                    well,
                    col,
                    status_read: false,
                    attempts,
                    lost_in_row: 0,
                };
                self.at(self.now + 25_000, Ev::Pc);
            }
            PcState::Session {
                well,
                mut col,
                status_read,
                attempts,
                lost_in_row,
            } => {
                let i = well as usize - 1;
                let req = if status_read {
                    col.request()
                } else {
                    Message::request(Station::concentrator(well), DIAGNOSTICS, vec![])
                };
                let (reply, done) = self.transact(Target::Conc(i), Line::Phone(i), &req);
                self.now = done;
                let Some(reply) = reply else {
                    // Four time-outs in a row: the session is cut; try again later.
                    if lost_in_row + 1 >= 4 {
                        self.report.pulls_cut += 1;
                        self.pc.log_pull(&PullLog {
                            at: self.minute(),
                            well,
                            via: Via::Concentrator,
                            outcome: "cut".into(),
                            records: col.new,
                            batches: col.batches,
                            detail: "no reply to 4 requests in a row".into(),
                        })?;
                        self.pc_failed(well, attempts, "no reply: the line was cut");
                        return Ok(());
                    }
                    self.pc_state = PcState::Session {
                        well,
                        col,
                        status_read,
                        attempts,
                        lost_in_row: lost_in_row + 1,
                    };
                    self.at(done, Ev::Pc);
                    return Ok(());
                };
                if !status_read {
                    if let Ok(s) =
                        StationStatus::decode(reply.status.unwrap_or([0, 0]), &reply.data)
                    {
                        if s.sensors.iter().any(|x| x.state != 0) {
                            self.report.faults_reported += 1;
                        }
                        self.pc.log_status(well, self.minute(), &s)?;
                    }
                    self.pc_state = PcState::Session {
                        well,
                        col,
                        status_read: true,
                        attempts,
                        lost_in_row: 0,
                    };
                    self.at(done, Ev::Pc);
                    return Ok(());
                }
                match col.on_reply(&reply, &mut self.pc, (self.now / MINUTE) as u32) {
                    Ok(Step::More) => {
                        self.report.batches += 1;
                        self.pc_state = PcState::Session {
                            well,
                            col,
                            status_read,
                            attempts,
                            lost_in_row: 0,
                        };
                        self.at(done, Ev::Pc);
                    }
                    Ok(Step::Done) => {
                        self.report.pulls_complete += 1;
                        self.report.duplicated += col.duplicated as u64;
                        self.pc.log_pull(&PullLog {
                            at: self.minute(),
                            well,
                            via: Via::Concentrator,
                            outcome: "ok".into(),
                            records: col.new,
                            batches: col.batches,
                            detail: String::new(),
                        })?;
                        // Hang up (+++, ATH) and go on with the next well.
                        self.at(done + 3_000, Ev::Pc);
                    }
                    Err(e) => {
                        self.pc_failed(well, 3, &e.to_string());
                    }
                }
            }
        }
        Ok(())
    }

    fn pc_failed(&mut self, well: u8, attempts: u8, why: &str) {
        if attempts + 1 < 3 {
            // Try the well again at the end of the round, at least 10 minutes on.
            self.pc_queue.push_back((well, attempts + 1));
            self.at(self.now + 10 * MINUTE, Ev::Pc);
        } else {
            self.report.unreachable.push(Unreachable {
                well,
                day: ((self.now - START) as f64 / DAY as f64 * 100.0).round() / 100.0,
                reason: why.to_string(),
            });
            let _ = self.pc.log_pull(&PullLog {
                at: self.minute(),
                well,
                via: Via::Concentrator,
                outcome: "unreachable".into(),
                records: 0,
                batches: 0,
                detail: why.to_string(),
            });
            self.at(self.now + 10_000, Ev::Pc);
        }
    }

    /// The handheld: every few days, a trip to the wells whose line has been down for
    /// more than a day; collect at each (the concentrator keeps polling); back at the
    /// bureau, hand everything over to the PC.
    fn hh_step(&mut self) -> Result<(), StoreError> {
        let state = std::mem::replace(&mut self.hh_state, HhState::Home);
        match state {
            HhState::Home => {
                let due: Vec<usize> = (0..self.wells.len())
                    .filter(|&i| {
                        !self.wells[i].phone_up && self.now - self.wells[i].outage_since > DAY
                    })
                    .collect();
                let next = self.now + (self.cfg.handheld_every * DAY as f64) as Millis;
                self.at(next.max(self.now + HOUR), Ev::Handheld);
                if !due.is_empty() {
                    self.report.handheld_trips += 1;
                    self.hh_state = HhState::Collect {
                        wells: due,
                        index: 0,
                        col: None,
                    };
                    // Two hours' drive to the first well.
                    self.at(self.now + 2 * HOUR, Ev::Handheld);
                }
            }
            HhState::Collect { wells, index, col } => {
                let Some(&i) = wells.get(index) else {
                    // Drive back (3 h) and hand over at the bureau.
                    let held = self.hh.wells()?;
                    self.hh_state = HhState::HandOver {
                        wells: held,
                        index: 0,
                        col: None,
                    };
                    self.at(self.now + 3 * HOUR, Ev::Handheld);
                    return Ok(());
                };
                let number = self.wells[i].number;
                let mut col = match col {
                    Some(c) => c,
                    None => Collector::new(&self.hh, Station::concentrator(number))?,
                };
                let (reply, done) = self.transact(Target::Conc(i), Line::Direct, &col.request());
                self.now = done;
                let step = match reply {
                    // The concentrator is restarting: wait and ask again.
                    None => Ok(Step::More),
                    Some(r) => col.on_reply(&r, &mut self.hh, (self.now / MINUTE) as u32),
                };
                match step {
                    Ok(Step::More) => {
                        self.hh_state = HhState::Collect {
                            wells,
                            index,
                            col: Some(col),
                        };
                        self.at(done + 50, Ev::Handheld);
                    }
                    Ok(Step::Done) | Err(_) => {
                        self.report.duplicated += col.duplicated as u64;
                        self.report.batches += col.batches as u64;
                        self.hh_state = HhState::Collect {
                            wells,
                            index: index + 1,
                            col: None,
                        };
                        self.at(done + 2 * HOUR, Ev::Handheld);
                    }
                }
            }
            HhState::HandOver { wells, index, col } => {
                let Some(&well) = wells.get(index) else {
                    return Ok(());
                };
                let mut col = match col {
                    Some(c) => c,
                    None => Collector::new(&self.pc, Station::handheld(well))?,
                };
                let (reply, done) = self.transact(Target::Handheld, Line::Direct, &col.request());
                self.now = done;
                let step = match reply {
                    None => Ok(Step::Done),
                    Some(r) => col.on_reply(&r, &mut self.pc, (self.now / MINUTE) as u32),
                };
                match step {
                    Ok(Step::More) => {
                        self.report.batches += 1;
                        self.hh_state = HhState::HandOver {
                            wells,
                            index,
                            col: Some(col),
                        };
                    }
                    Ok(Step::Done) | Err(_) => {
                        self.report.duplicated += col.duplicated as u64;
                        self.report.minutes_via_handheld += col.new as u64;
                        if col.batches > 0 {
                            self.pc.log_pull(&PullLog {
                                at: self.minute(),
                                well,
                                via: Via::Handheld,
                                outcome: "ok".into(),
                                records: col.new,
                                batches: col.batches,
                                detail: String::new(),
                            })?;
                        }
                        self.hh_state = HhState::HandOver {
                            wells,
                            index: index + 1,
                            col: None,
                        };
                    }
                }
                self.at(done + 50, Ev::Handheld);
            }
        }
        Ok(())
    }

    /// After the period: every line works, concentrators that were down are back,
    /// the handheld hands over what it holds, and the PC pulls each well to the end.
    fn drain(&mut self) -> Result<(), StoreError> {
        for i in 0..self.wells.len() {
            self.wells[i].phone_up = true;
            if self.wells[i].conc.is_none() {
                let c = open_conc(&self.cfg, &self.wells[i], self.now)?;
                self.wells[i].conc = Some(c);
            }
            if let Some(c) = &self.wells[i].conc {
                self.report.pending_at_end += c.store().counts()?.1 as u64;
            }
        }
        for w in self.hh.wells()? {
            self.report.pending_at_end += self.hh.unsent(w)? as u64;
            let mut col = Collector::new(&self.pc, Station::handheld(w))?;
            loop {
                let (reply, _) = self.transact(Target::Handheld, Line::Direct, &col.request());
                let Some(r) = reply else { break };
                match col.on_reply(&r, &mut self.pc, (self.now / MINUTE) as u32) {
                    Ok(Step::More) => self.report.batches += 1,
                    _ => break,
                }
            }
            self.report.minutes_via_handheld += col.new as u64;
            self.report.duplicated += col.duplicated as u64;
        }
        for i in 0..self.wells.len() {
            let well = self.wells[i].number;
            let mut col = Collector::new(&self.pc, Station::concentrator(well))?;
            loop {
                let (reply, _) = self.transact(Target::Conc(i), Line::Direct, &col.request());
                let Some(r) = reply else { break };
                match col.on_reply(&r, &mut self.pc, (self.now / MINUTE) as u32) {
                    Ok(Step::More) => self.report.batches += 1,
                    _ => break,
                }
            }
            self.report.duplicated += col.duplicated as u64;
            // Every minute still in the concentrator's store is at the PC, unchanged
            // but for the wire's single precision.
            if let Some(c) = &self.wells[i].conc {
                let at_pc = self.pc.range(well, 0, u32::MAX)?;
                let mut j = 0;
                for r in c.store().range(0, u32::MAX)? {
                    self.report.values_checked += 1;
                    while j < at_pc.len() && at_pc[j].minute < r.minute {
                        j += 1;
                    }
                    if at_pc.get(j).map(|p| same(p, &r.wire_rounded())) != Some(true) {
                        self.report.values_mismatched += 1;
                    }
                }
            }
            let n = self.pc.count(well)? as u64;
            self.report.minutes_at_pc += n;
            let all = self.pc.range(well, 0, u32::MAX)?;
            self.report.partial_minutes += all.iter().filter(|r| r.valid != 7).count() as u64;
            if let (Some(a), Some(b)) = (all.first(), all.last()) {
                self.report.minutes_missed += (b.minute - a.minute + 1) as u64 - n;
            }
        }
        // Lost: minutes a concentrator stored that the PC does not have, minute by
        // minute (not a difference of counts).
        self.report.lost = 0;
        for w in &self.wells {
            let at_pc: std::collections::HashSet<u32> = self
                .pc
                .range(w.number, 0, u32::MAX)?
                .iter()
                .map(|r| r.minute)
                .collect();
            self.report.lost += w.sampled.iter().filter(|m| !at_pc.contains(m)).count() as u64;
        }
        self.report.duplicated = self.report.duplicated.max(self.pc.duplicated()? as u64);
        Ok(())
    }
}

fn same(a: &crate::proto::Record, b: &crate::proto::Record) -> bool {
    let f = |x: f64, y: f64| (x.is_nan() && y.is_nan()) || x == y;
    a.minute == b.minute
        && a.valid == b.valid
        && a.t_raw == b.t_raw
        && a.l_raw == b.l_raw
        && a.ls_raw == b.ls_raw
        && f(a.temperature, b.temperature)
        && f(a.level, b.level)
}

fn open_conc(cfg: &SimConfig, w: &Well, now: Millis) -> Result<Concentrator, StoreError> {
    let store = Store::open(
        &w.store_path,
        w.number,
        cfg.capacity_days.saturating_mul(DAY_MINUTES),
        Durability::Process,
    )?;
    let mut c = ConcentratorConfig::reference(w.number);
    c.poll_interval = cfg.poll_interval_s.clamp(1, 180) * 1000;
    Concentrator::new(c, store, now)
}

/// Runs a simulation.
pub fn run(cfg: SimConfig) -> Result<SimReport, StoreError> {
    Sim::new(cfg)?.run()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_days_lose_nothing() {
        let r = run(SimConfig {
            days: 2.0,
            phone_outage_rate: 0.5,
            outage_mean_days: 0.5,
            frame_loss: 0.01,
            restart_rate: 1.0,
            ..SimConfig::default()
        })
        .unwrap();
        assert!(r.minutes_sampled > 3 * 2 * 1430, "{r:?}");
        assert_eq!(r.lost, 0, "{r:?}");
        assert_eq!(r.duplicated, 0, "{r:?}");
        assert_eq!(r.values_mismatched, 0, "{r:?}");
        assert!(r.pulls_complete > 0);
    }
}
