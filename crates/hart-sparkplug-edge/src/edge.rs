//! The Sparkplug B edge node as a sans-IO state machine: events in (connected,
//! disconnected, a device's image changed, a message received), with the time passed
//! in; what to publish, subscribe, write and keep out. The MQTT client
//! ([`crate::run`]) carries them out.
//!
//! Rules followed (Sparkplug 3.0.0):
//! - the will is an NDEATH with the `bdSeq` metric (Int64), QoS 1, not retained, and
//!   no `seq`; `bdSeq` starts at 0 and goes up by one for every CONNECT (mod 256);
//! - NBIRTH has `seq` 0, `bdSeq` equal to the will's, `Node Control/Rebirth` false;
//!   every later message of the session (DBIRTH, DDATA, DDEATH) the next `seq`, 0
//!   after 255; births, data and deaths are QoS 0 (1 with [`EdgeNode::with_data_qos`],
//!   a deliberate, configurable departure for clustered brokers), not retained;
//! - births carry every metric with name, alias, data type and value (or `is_null`);
//!   DDATA carries only the metrics that changed, by alias, with their time stamps;
//! - a device that stops answering gets DDEATH, and DBIRTH when it answers again;
//! - NCMD `Node Control/Rebirth` true: NBIRTH and every DBIRTH again (same `bdSeq`);
//! - with a primary host: nothing is published until its STATE says online; when it
//!   says offline, NDEATH and disconnect;
//! - samples taken while the broker cannot be reached (or the primary host is
//!   offline) are kept, bounded, and sent after the births as DDATA with
//!   `is_historical` true, in the order they were taken.

use std::collections::{BTreeMap, VecDeque};
use std::time::SystemTime;

use hart_poller::{DeviceImage, Quality, WriteOp};
use prost::Message as _;

use hart_sparkplug::command::{self, CommandMetric, CommandValue};
use hart_sparkplug::metrics::{self, Value, Writable, DEVICE_METRICS};
use hart_sparkplug::proto::datatype as dt;
use hart_sparkplug::proto::payload::{metric, Metric};
use hart_sparkplug::proto::Payload;

pub use hart_sparkplug::{millis, NAMESPACE};

/// What the edge node needs to know.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Sparkplug group ID.
    pub group: String,
    /// Sparkplug edge node ID.
    pub edge_node: String,
    /// The primary host application to wait for (its `spBv1.0/STATE/ID`).
    pub primary_host: Option<String>,
    /// Samples kept at most while the broker or the primary host is away.
    pub backlog: usize,
    /// Refuse every DCMD write (`[mqtt] read_only`: this front end's own rule).
    pub read_only: bool,
    /// The gateway's rule for writes (`--read-only`, `--allow-commands`), as its
    /// engine holds it: a DCMD is judged whole against it before any of its writes
    /// goes, so a DCMD is never carried out in part.
    pub gateway: hart_access::WritePolicy,
}

/// An MQTT message to publish.
#[derive(Debug, Clone, PartialEq)]
pub struct Message {
    /// Topic.
    pub topic: String,
    /// Payload (Sparkplug B protobuf).
    pub payload: Vec<u8>,
    /// QoS (0 or 1).
    pub qos: u8,
    /// Retain flag (always false for an edge node).
    pub retain: bool,
    /// The samples this message carries: to give back with
    /// [`EdgeNode::disconnected`] when it could not be sent, so that they are kept.
    pub keep: Vec<Sample>,
}

/// One device's changed values at one time.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Engine position of the device.
    pub position: usize,
    /// When the values were taken, ms since the Unix epoch.
    pub at: u64,
    /// (metric index in [`DEVICE_METRICS`], value).
    pub metrics: Vec<(usize, Value)>,
}

/// A write asked for by a DCMD, let through by the rules: carry it out with
/// `Engine::apply` (which audits it).
#[derive(Debug, Clone, PartialEq)]
pub struct WriteRequest {
    /// Engine position of the device.
    pub position: usize,
    /// Its Sparkplug device ID.
    pub device: String,
    /// The writes, in order.
    pub ops: Vec<WriteOp>,
    /// The metrics written, for the audit (`DCMD Config/Damping`).
    pub via: String,
}

/// What the edge node asks of its MQTT client.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// Subscribe to a topic filter.
    Subscribe {
        /// Filter.
        topic: String,
        /// QoS.
        qos: u8,
    },
    /// Publish.
    Publish(Message),
    /// Disconnect from the broker (after the NDEATH just published) and connect again.
    Disconnect,
    /// Carry out a write.
    Write(WriteRequest),
    /// Read back from the historian what it kept while the backlog was full, from
    /// `from` to `to` (ms since the Unix epoch, `to` excluded), and hand it to
    /// [`EdgeNode::backfilled`] ([`EdgeNode::with_spill`]).
    Backfill {
        /// From (ms, included).
        from: u64,
        /// To (ms, excluded).
        to: u64,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Link {
    /// No MQTT session.
    Down,
    /// Connected, waiting for the primary host's STATE online.
    WaitingForHost,
    /// Births published: data flow.
    Live,
}

#[derive(Debug)]
struct Device {
    id: String,
    current: Vec<Value>,
    units: [Option<u8>; 5],
    at: u64,
    alive: bool,
    born: bool,
    /// The values as last published or stored: what DDATA and samples are diffs of.
    sent: Vec<Value>,
}

/// Counters, for logs and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Samples stored for later (broker or primary host away).
    pub stored: u64,
    /// Stored samples sent as historical DDATA.
    pub replayed: u64,
    /// Stored samples dropped because the backlog was full (the oldest go first).
    pub dropped: u64,
    /// Births published (NBIRTH and DBIRTH).
    pub births: u64,
    /// Commands refused or malformed (those below included).
    pub bad_commands: u64,
    /// Commands refused because the broker delivered them retained: a retained
    /// command would run again at every connection.
    pub retained_commands: u64,
    /// Commands refused because they came faster than [`COMMANDS_PER_SECOND`].
    pub throttled_commands: u64,
    /// Rebirths asked for within [`REBIRTH_INTERVAL_MS`] of the last, answered by
    /// one rebirth when it ends.
    pub coalesced_rebirths: u64,
}

/// Longest NCMD or DCMD payload taken, bytes: a command names a few metrics (a
/// rebirth request is under 100 bytes); a longer one is refused undecoded.
pub const MAX_COMMAND_BYTES: usize = 64 * 1024;

/// Commands (NCMD and DCMD together) taken per second on average; up to
/// [`COMMAND_BURST`] at once. More are refused, counted and logged (a few lines a
/// second at most): a flood of commands cannot queue writes without end or fill
/// the log.
pub const COMMANDS_PER_SECOND: u32 = 5;

/// Commands taken at once before [`COMMANDS_PER_SECOND`] applies.
pub const COMMAND_BURST: u32 = 20;

/// Shortest time between two rebirths asked by NCMD, ms: the first request is answered
/// at once, more within this time by one rebirth when it ends, so 300 requests cost
/// two rebirths, not 300.
pub const REBIRTH_INTERVAL_MS: u64 = 5_000;

/// Whether `now` (ms) is within [`REBIRTH_INTERVAL_MS`] after `t`. A clock stepped
/// back before `t` does not count as recent: a wall clock set back by hours must not
/// hold rebirths back for hours.
fn recent(t: u64, now: u64) -> bool {
    now >= t && now - t < REBIRTH_INTERVAL_MS
}

/// How the broker delivered a message (its MQTT flags).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Delivery {
    /// The broker kept it retained and sent it because of a subscription: not a
    /// command sent now.
    pub retained: bool,
}

/// A token bucket in ms of injected time.
#[derive(Debug, Clone)]
struct Budget {
    tokens: f64,
    at: Option<u64>,
}

impl Budget {
    fn new() -> Self {
        Budget {
            tokens: f64::from(COMMAND_BURST),
            at: None,
        }
    }

    fn take(&mut self, now_ms: u64) -> bool {
        match self.at {
            // The clock stepped back: what was gained cannot be told; start afresh
            // rather than refuse every command until it catches up.
            Some(at) if now_ms < at => self.tokens = f64::from(COMMAND_BURST),
            Some(at) => {
                let gained = (now_ms - at) as f64 / 1000.0 * f64::from(COMMANDS_PER_SECOND);
                self.tokens = (self.tokens + gained).min(f64::from(COMMAND_BURST));
            }
            None => {}
        }
        self.at = Some(now_ms);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// The edge node.
#[derive(Debug)]
pub struct EdgeNode {
    settings: Settings,
    link: Link,
    next_bd_seq: u8,
    bd_seq: u8,
    seq: u8,
    devices: BTreeMap<usize, Device>,
    backlog: VecDeque<Sample>,
    backlog_full_logged: bool,
    host_online: bool,
    last_state: Option<u64>,
    counters: Counters,
    data_qos: u8,
    /// A historian keeps what the full backlog cannot ([`EdgeNode::with_spill`]).
    spill: bool,
    /// The times (ms, first and last) of the samples left to the historian.
    spilled: Option<(u64, u64)>,
    /// A read-back from the historian is under way ([`Output::Backfill`]): the
    /// deaths of devices that do not answer wait for its end
    /// ([`EdgeNode::backfill_done`]), so their data up to their death is sent first.
    backfilling: bool,
    /// Commands taken ([`COMMANDS_PER_SECOND`]).
    commands: Budget,
    /// Lines about refused commands ([`hart_access::pool::LogLimit`]).
    refusals_logged: hart_access::pool::LogLimit,
    /// When a rebirth asked by NCMD was last published, ms ([`REBIRTH_INTERVAL_MS`]).
    last_births: Option<u64>,
    /// A rebirth asked within [`REBIRTH_INTERVAL_MS`], published by [`EdgeNode::tick`].
    rebirth_pending: bool,
}

impl EdgeNode {
    /// A new edge node, not connected.
    pub fn new(settings: Settings) -> Self {
        EdgeNode {
            settings,
            link: Link::Down,
            next_bd_seq: 0,
            bd_seq: 0,
            seq: 0,
            devices: BTreeMap::new(),
            backlog: VecDeque::new(),
            backlog_full_logged: false,
            host_online: false,
            last_state: None,
            counters: Counters::default(),
            data_qos: 0,
            spill: false,
            spilled: None,
            backfilling: false,
            commands: Budget::new(),
            refusals_logged: Default::default(),
            last_births: None,
            rebirth_pending: false,
        }
    }

    /// Births, data and device deaths at QoS `qos` (0, Sparkplug's rule, by default;
    /// 1 for a clustered broker feeding a historian). Values above 1 count as 1.
    pub fn with_data_qos(mut self, qos: u8) -> Self {
        self.data_qos = qos.min(1);
        self
    }

    /// The settings.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The topic of message type `kind` for the node (`device` `None`) or a device.
    pub fn topic(&self, kind: &str, device: Option<&str>) -> String {
        match device {
            Some(d) => format!(
                "{NAMESPACE}/{}/{kind}/{}/{d}",
                self.settings.group, self.settings.edge_node
            ),
            None => format!(
                "{NAMESPACE}/{}/{kind}/{}",
                self.settings.group, self.settings.edge_node
            ),
        }
    }

    /// The primary host's STATE topic.
    pub fn state_topic(&self) -> Option<String> {
        self.settings
            .primary_host
            .as_ref()
            .map(|h| format!("{NAMESPACE}/STATE/{h}"))
    }

    /// Whether births are out and data flow.
    pub fn is_live(&self) -> bool {
        self.link == Link::Live
    }

    /// The `bdSeq` of the current (or last) connection.
    pub fn bd_seq(&self) -> u8 {
        self.bd_seq
    }

    /// Samples waiting to be sent.
    pub fn backlog_len(&self) -> usize {
        self.backlog.len()
    }

    /// The counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// The Sparkplug device ID of the device at engine `position`, once identified.
    pub fn device_id(&self, position: usize) -> Option<&str> {
        self.devices.get(&position).map(|d| d.id.as_str())
    }

    /// The will (NDEATH) for the next CONNECT: takes the next `bdSeq`.
    pub fn will(&mut self, now: SystemTime) -> Message {
        self.bd_seq = self.next_bd_seq;
        self.next_bd_seq = self.next_bd_seq.wrapping_add(1);
        self.death(now)
    }

    /// The NDEATH of the current connection's `bdSeq`: the will, and what to publish
    /// before an intentional DISCONNECT.
    pub fn death(&self, now: SystemTime) -> Message {
        let payload = Payload {
            timestamp: Some(millis(now)),
            metrics: vec![Metric {
                name: Some(metrics::NODE_BDSEQ.into()),
                datatype: Some(dt::INT64),
                value: Some(metric::Value::LongValue(u64::from(self.bd_seq))),
                ..Default::default()
            }],
            ..Default::default()
        };
        Message {
            topic: self.topic("NDEATH", None),
            payload: payload.encode_to_vec(),
            qos: 1,
            retain: false,
            keep: vec![],
        }
    }

    fn next_seq(&mut self) -> u64 {
        let s = self.seq;
        self.seq = self.seq.wrapping_add(1);
        u64::from(s)
    }

    /// The MQTT session is up (CONNACK accepted): subscriptions, then the births, or
    /// waiting for the primary host.
    pub fn connected(&mut self, now: SystemTime) -> Vec<Output> {
        let mut out = vec![
            Output::Subscribe {
                topic: self.topic("NCMD", None),
                qos: 1,
            },
            Output::Subscribe {
                topic: self.topic("DCMD", Some("+")),
                qos: 1,
            },
        ];
        if let Some(t) = self.state_topic() {
            // A STATE of an earlier session does not count: wait for this one's.
            self.host_online = false;
            self.link = Link::WaitingForHost;
            out.push(Output::Subscribe { topic: t, qos: 1 });
        } else {
            self.births(now, &mut out);
        }
        out
    }

    /// The MQTT session is gone. `unsent`: the samples of messages handed to the
    /// client that did not go out, oldest first; they are kept ahead of anything
    /// stored later.
    pub fn disconnected(&mut self, unsent: Vec<Sample>) {
        self.link = Link::Down;
        for d in self.devices.values_mut() {
            d.born = false;
        }
        for s in unsent.into_iter().rev() {
            self.counters.stored += 1;
            self.backlog.push_front(s);
        }
        self.trim_backlog();
    }

    /// The device's image changed (or its quality did): DBIRTH, DDATA or DDEATH when
    /// live, a stored sample otherwise.
    pub fn device(
        &mut self,
        image: &DeviceImage,
        quality: Quality,
        at: SystemTime,
        now: SystemTime,
    ) -> Vec<Output> {
        let Some(info) = image.info.as_ref() else {
            // Not identified yet: no device ID to publish under.
            return vec![];
        };
        if image.polls == 0 {
            // Not polled yet: a burst message heard before the first poll carries only
            // some of the device's values and units, and a birth then would be
            // followed at once by another with the rest.
            return vec![];
        }
        let position = image.position;
        let values = crate::image::values(image, quality);
        let units = crate::image::units(image);
        let alive = !matches!(quality, Quality::NoReply | Quality::WaitingForData);
        let at = millis(at);
        if !self.devices.contains_key(&position) {
            let id = self.new_device_id(image, &info.unique_id().to_string());
            self.devices.insert(
                position,
                Device {
                    id,
                    current: values.clone(),
                    units,
                    at,
                    alive,
                    born: false,
                    sent: values.clone(),
                },
            );
            if self.link != Link::Live {
                // First seen while away: its birth will carry these values.
                return vec![];
            }
        }
        let mut out = vec![];
        let live = self.link == Link::Live;
        let backfilling = self.backfilling;
        let Some(d) = self.devices.get_mut(&position) else {
            return out;
        };
        let units_changed = d.units != units;
        d.current = values.clone();
        d.units = units;
        d.at = at;
        d.alive = alive;
        if !live {
            let diff = diff(&d.sent, &values);
            d.sent = values;
            if !diff.is_empty() {
                self.store(Sample {
                    position,
                    at,
                    metrics: diff,
                });
            }
            return out;
        }
        if alive && (!d.born || units_changed) {
            self.dbirth(position, now, &mut out);
        } else if d.born && !alive && backfilling {
            // Dead during the outage: its data up to its death is being read back from
            // the historian; its death follows that ([`EdgeNode::backfill_done`]).
        } else if d.born && !alive {
            // Its last values (quality "no reply") first, then the death.
            self.ddata(position, now, &mut out);
            self.ddeath(position, now, &mut out);
        } else if d.born {
            self.ddata(position, now, &mut out);
        } else {
            d.sent = values;
        }
        out
    }

    /// With `on`, a full backlog does not drop samples: the gateway's historian keeps
    /// every value anyway, so the edge node remembers the time range it left to it and,
    /// after the births and the samples memory held, asks for it back
    /// ([`Output::Backfill`]).
    pub fn with_spill(mut self, on: bool) -> Self {
        self.spill = on;
        self
    }

    /// The samples read back from the historian for an [`Output::Backfill`]: sent as
    /// historical DDATA in time order (kept again if the session has ended meanwhile).
    pub fn backfilled(&mut self, mut samples: Vec<Sample>, now: SystemTime) -> Vec<Output> {
        samples.sort_by_key(|s| s.at);
        let mut out = vec![];
        if self.link != Link::Live {
            for s in samples {
                self.store(s);
            }
            return out;
        }
        if !samples.is_empty() {
            tracing::debug!(
                "mqtt: sending {} samples read back from the historian as historical data",
                samples.len()
            );
        }
        for s in samples {
            self.historical(s, now, &mut out);
        }
        out
    }

    /// A message arrived on a subscribed topic, sent now (not retained).
    pub fn received(&mut self, topic: &str, payload: &[u8], now: SystemTime) -> Vec<Output> {
        self.delivered(topic, payload, Delivery::default(), now)
    }

    /// A message arrived on a subscribed topic, delivered as `how` says. Commands
    /// (NCMD, DCMD) delivered retained, longer than [`MAX_COMMAND_BYTES`] or beyond
    /// [`COMMANDS_PER_SECOND`] are refused: counted, and logged a few lines a second
    /// at most.
    pub fn delivered(
        &mut self,
        topic: &str,
        payload: &[u8],
        how: Delivery,
        now: SystemTime,
    ) -> Vec<Output> {
        let mut out = vec![];
        let ncmd = topic == self.topic("NCMD", None);
        let dcmd_prefix = self.topic("DCMD", Some(""));
        let dcmd = topic.strip_prefix(&dcmd_prefix);
        if payload.len() > MAX_COMMAND_BYTES && !(ncmd || dcmd.is_some()) {
            self.refuse(now, || {
                format!(
                    "mqtt: a message of {} bytes on {topic} ignored: more than the {MAX_COMMAND_BYTES} \
                     the edge node reads",
                    payload.len()
                )
            });
            return out;
        }
        if ncmd || dcmd.is_some() {
            let kind = if ncmd { "NCMD" } else { "DCMD" };
            if how.retained {
                self.counters.retained_commands += 1;
                self.refuse(now, || {
                    format!(
                        "mqtt: {kind} on {topic} refused: the broker delivered it retained, so it \
                         is not a command sent now and would run again at every connection; \
                         commands must be published without the retain flag (clear it with an \
                         empty retained message on {topic})"
                    )
                });
                return out;
            }
            if payload.len() > MAX_COMMAND_BYTES {
                self.refuse(now, || {
                    format!(
                        "mqtt: {kind} on {topic} refused: {} bytes, more than the {MAX_COMMAND_BYTES} \
                         a command may have",
                        payload.len()
                    )
                });
                return out;
            }
            if !self.commands.take(millis(now)) {
                self.counters.throttled_commands += 1;
                self.refuse(now, || {
                    format!(
                        "mqtt: {kind} on {topic} refused: more than {COMMANDS_PER_SECOND} commands \
                         a second (after a burst of {COMMAND_BURST})"
                    )
                });
                return out;
            }
        }
        if ncmd {
            self.ncmd(payload, now, &mut out);
        } else if let Some(device) = dcmd {
            self.dcmd(device, payload, now, &mut out);
        } else if Some(topic) == self.state_topic().as_deref() {
            self.state(payload, now, &mut out);
        } else {
            tracing::debug!("mqtt: message on {topic} ignored (not for this edge node)");
        }
        out
    }

    fn new_device_id(&self, image: &DeviceImage, unique_id: &str) -> String {
        let valid = |s: &str| {
            !s.is_empty()
                && s.len() <= 64
                && !s.contains(['+', '/', '#'])
                && !s.chars().any(char::is_control)
        };
        let nonblank = |s: &Option<String>| {
            s.as_deref()
                .map(str::trim)
                .filter(|s| valid(s))
                .map(str::to_string)
        };
        let info = image.info.as_ref();
        let candidate = nonblank(&image.name)
            .or_else(|| info.and_then(|i| nonblank(&i.long_tag)))
            .or_else(|| info.and_then(|i| nonblank(&i.tag)))
            .unwrap_or_else(|| unique_id.to_string());
        let taken = |c: &str| {
            self.devices
                .values()
                .any(|d| d.id.to_lowercase() == c.to_lowercase())
        };
        if !taken(&candidate) {
            return candidate;
        }
        let with_id = format!("{candidate}-{unique_id}");
        if !taken(&with_id) {
            return with_id;
        }
        format!("{with_id}-{}", image.position + 1)
    }

    fn store(&mut self, sample: Sample) {
        let limit = self.settings.backlog.max(1);
        if self.spill && self.backlog.len() >= limit {
            // The historian has it: the time range is enough to read it back.
            self.spill_range(sample.at);
            self.counters.stored += 1;
            if !self.backlog_full_logged {
                self.backlog_full_logged = true;
                tracing::warn!(
                    "mqtt: the store-and-forward backlog is full ({limit} samples in memory): \
                     the rest of the outage is read back from the historian and sent, \
                     historical, when the broker is back"
                );
            }
            return;
        }
        self.counters.stored += 1;
        self.backlog.push_back(sample);
        self.trim_backlog();
    }

    /// Adds time `at` to the range left to the historian. Memory then keeps only
    /// samples older than the whole range (the newer ones join it): what the historian
    /// gives back and what memory sends never overlap, so nothing arrives twice.
    fn spill_range(&mut self, at: u64) {
        let (from, to) = self
            .spilled
            .map_or((at, at), |(from, to)| (from.min(at), to.max(at)));
        let mut from = from;
        while let Some(s) = self.backlog.back() {
            if s.at < from {
                break;
            }
            from = from.min(s.at);
            self.backlog.pop_back();
        }
        self.spilled = Some((from, to));
    }

    fn trim_backlog(&mut self) {
        let limit = self.settings.backlog.max(1);
        if self.spill {
            // The historian has every sample: the newest in memory join the range left
            // to it (all later than those kept, so the range stays one), none dropped.
            while self.backlog.len() > limit {
                if let Some(s) = self.backlog.pop_back() {
                    self.spill_range(s.at);
                }
            }
            return;
        }
        while self.backlog.len() > limit {
            self.backlog.pop_front();
            self.counters.dropped += 1;
            if !self.backlog_full_logged {
                self.backlog_full_logged = true;
                tracing::warn!(
                    "mqtt: the store-and-forward backlog is full ({limit} samples): the oldest \
                     samples are dropped from now on until the broker{} is back; raise [mqtt] \
                     backlog, or check the broker",
                    if self.settings.primary_host.is_some() {
                        " and the primary host"
                    } else {
                        ""
                    }
                );
            }
        }
    }

    /// NBIRTH, every DBIRTH, the stored samples as historical DDATA, then DDEATH for
    /// the devices that do not answer now.
    fn births(&mut self, now: SystemTime, out: &mut Vec<Output>) {
        self.rebirth_pending = false;
        self.link = Link::Live;
        self.seq = 0;
        let seq = self.next_seq();
        let named = |name: &str, alias: u64, datatype: u32, value: metric::Value| Metric {
            name: Some(name.into()),
            alias: Some(alias),
            timestamp: Some(millis(now)),
            datatype: Some(datatype),
            value: Some(value),
            ..Default::default()
        };
        let payload = Payload {
            timestamp: Some(millis(now)),
            seq: Some(seq),
            metrics: vec![
                named(
                    metrics::NODE_BDSEQ,
                    metrics::BDSEQ_ALIAS,
                    dt::INT64,
                    metric::Value::LongValue(u64::from(self.bd_seq)),
                ),
                named(
                    metrics::NODE_REBIRTH,
                    metrics::REBIRTH_ALIAS,
                    dt::BOOLEAN,
                    metric::Value::BooleanValue(false),
                ),
                named(
                    metrics::NODE_SOFTWARE,
                    metrics::SOFTWARE_ALIAS,
                    dt::STRING,
                    metric::Value::StringValue(format!("hartkit {}", env!("CARGO_PKG_VERSION"))),
                ),
            ],
            ..Default::default()
        };
        self.counters.births += 1;
        out.push(Output::Publish(Message {
            topic: self.topic("NBIRTH", None),
            payload: payload.encode_to_vec(),
            qos: self.data_qos,
            retain: false,
            keep: vec![],
        }));
        let positions: Vec<usize> = self.devices.keys().copied().collect();
        for &p in &positions {
            self.dbirth(p, now, out);
        }
        let stored = self.backlog.len();
        while let Some(sample) = self.backlog.pop_front() {
            self.historical(sample, now, out);
        }
        if let Some((from, to)) = self.spilled.take() {
            // After what memory held: the rest of the outage, from the historian.
            self.backfilling = true;
            out.push(Output::Backfill {
                from,
                to: to.saturating_add(1),
            });
        }
        if stored > 0 {
            tracing::info!(
                "mqtt: sent {stored} stored samples as historical data{}",
                if self.counters.dropped > 0 {
                    format!(
                        " ({} dropped since the start: the backlog was full)",
                        self.counters.dropped
                    )
                } else {
                    String::new()
                }
            );
        }
        self.backlog_full_logged = false;
        if !self.backfilling {
            self.deaths(now, out);
        }
    }

    /// DDEATH for every born device that does not answer.
    fn deaths(&mut self, now: SystemTime, out: &mut Vec<Output>) {
        let dead: Vec<usize> = self
            .devices
            .iter()
            .filter(|(_, d)| d.born && !d.alive)
            .map(|(p, _)| *p)
            .collect();
        for p in dead {
            self.ddeath(p, now, out);
        }
    }

    /// The read-back asked by [`Output::Backfill`] has been sent whole (or could not be
    /// read): the devices that died during the outage, whose data up to their death has
    /// now gone out historical, get their DDEATH.
    pub fn backfill_done(&mut self, now: SystemTime) -> Vec<Output> {
        let mut out = vec![];
        if !std::mem::take(&mut self.backfilling) {
            return out;
        }
        if self.link == Link::Live {
            self.deaths(now, &mut out);
        }
        out
    }

    /// The session ended before the read-back from `from` to `to` (ms, `to`
    /// excluded) was sent: it is asked again after the next births.
    pub fn backfill_unfinished(&mut self, from: u64, to: u64) {
        self.backfilling = false;
        if from >= to {
            return;
        }
        self.spill_range(from);
        self.spill_range(to - 1);
    }

    /// Whether a read-back from the historian is under way.
    pub fn is_backfilling(&self) -> bool {
        self.backfilling
    }

    fn dbirth(&mut self, position: usize, now: SystemTime, out: &mut Vec<Output>) {
        let seq = self.next_seq();
        let Some(d) = self.devices.get_mut(&position) else {
            return;
        };
        let metrics = DEVICE_METRICS
            .iter()
            .zip(&d.current)
            .enumerate()
            .map(|(i, (def, v))| Metric {
                name: Some(def.name.into()),
                alias: Some(metrics::device_alias(position, i)),
                timestamp: Some(d.at),
                properties: metrics::properties(i, &d.units),
                ..metrics::metric(def.datatype, v)
            })
            .collect();
        let payload = Payload {
            timestamp: Some(millis(now)),
            seq: Some(seq),
            metrics,
            ..Default::default()
        };
        d.born = true;
        d.sent = d.current.clone();
        let keep = vec![Sample {
            position,
            at: d.at,
            metrics: d.current.iter().cloned().enumerate().collect(),
        }];
        let id = d.id.clone();
        let topic = self.topic("DBIRTH", Some(&id));
        self.counters.births += 1;
        out.push(Output::Publish(Message {
            topic,
            payload: payload.encode_to_vec(),
            qos: self.data_qos,
            retain: false,
            keep,
        }));
    }

    fn ddata(&mut self, position: usize, now: SystemTime, out: &mut Vec<Output>) {
        let Some(d) = self.devices.get_mut(&position) else {
            return;
        };
        let changed = diff(&d.sent, &d.current);
        d.sent = d.current.clone();
        if changed.is_empty() {
            return;
        }
        let sample = Sample {
            position,
            at: d.at,
            metrics: changed,
        };
        let m = self.data_message(sample, false, now);
        out.push(Output::Publish(m));
    }

    fn historical(&mut self, sample: Sample, now: SystemTime, out: &mut Vec<Output>) {
        if !self.devices.get(&sample.position).is_some_and(|d| d.born) {
            return;
        }
        self.counters.replayed += 1;
        let m = self.data_message(sample, true, now);
        out.push(Output::Publish(m));
    }

    fn data_message(&mut self, sample: Sample, historical: bool, now: SystemTime) -> Message {
        let seq = self.next_seq();
        let id = self
            .devices
            .get(&sample.position)
            .map_or(String::new(), |d| d.id.clone());
        let metrics = sample
            .metrics
            .iter()
            .map(|(i, v)| Metric {
                alias: Some(metrics::device_alias(sample.position, *i)),
                timestamp: Some(sample.at),
                is_historical: historical.then_some(true),
                ..metrics::metric(DEVICE_METRICS[*i].datatype, v)
            })
            .collect();
        let payload = Payload {
            timestamp: Some(millis(now)),
            seq: Some(seq),
            metrics,
            ..Default::default()
        };
        Message {
            topic: self.topic("DDATA", Some(&id)),
            payload: payload.encode_to_vec(),
            qos: self.data_qos,
            retain: false,
            keep: vec![sample],
        }
    }

    fn ddeath(&mut self, position: usize, now: SystemTime, out: &mut Vec<Output>) {
        let seq = self.next_seq();
        let Some(d) = self.devices.get_mut(&position) else {
            return;
        };
        d.born = false;
        let id = d.id.clone();
        let payload = Payload {
            timestamp: Some(millis(now)),
            seq: Some(seq),
            ..Default::default()
        };
        out.push(Output::Publish(Message {
            topic: self.topic("DDEATH", Some(&id)),
            payload: payload.encode_to_vec(),
            qos: self.data_qos,
            retain: false,
            keep: vec![],
        }));
    }

    fn ncmd(&mut self, payload: &[u8], now: SystemTime, out: &mut Vec<Output>) {
        let metrics = match command::decode(payload) {
            Ok(m) => m,
            Err(e) => {
                self.refuse(now, || format!("mqtt: NCMD ignored: {e}"));
                return;
            }
        };
        for m in metrics {
            let rebirth = m.name.as_deref() == Some(metrics::NODE_REBIRTH)
                || m.name.is_none() && m.alias == Some(metrics::REBIRTH_ALIAS);
            match (rebirth, &m.value) {
                (true, CommandValue::Bool(true)) => {
                    let recent = self.last_births.is_some_and(|t| recent(t, millis(now)));
                    if self.link == Link::Live && recent {
                        // One rebirth answers every request within the interval.
                        self.counters.coalesced_rebirths += 1;
                        if !self.rebirth_pending {
                            self.rebirth_pending = true;
                            tracing::info!(
                                "mqtt: rebirth asked by NCMD within {} s of the last one: \
                                 one rebirth follows when that time is up",
                                REBIRTH_INTERVAL_MS / 1000
                            );
                        }
                    } else if self.link == Link::Live {
                        tracing::info!("mqtt: rebirth asked by NCMD: NBIRTH and DBIRTH again");
                        self.last_births = Some(millis(now));
                        self.births(now, out);
                    } else {
                        tracing::info!(
                            "mqtt: rebirth asked by NCMD while waiting for the primary host: \
                             the births follow when it is online"
                        );
                    }
                }
                (true, CommandValue::Bool(false)) => {}
                (true, v) => {
                    self.refuse(now, || {
                        format!(
                            "mqtt: NCMD {} ignored: it takes the Boolean true, not {v:?}",
                            metrics::NODE_REBIRTH
                        )
                    });
                }
                (false, _) => {
                    self.refuse(now, || {
                        format!(
                            "mqtt: NCMD for {} ignored: the node's only command is {}",
                            m.label(),
                            metrics::NODE_REBIRTH
                        )
                    });
                }
            }
        }
    }

    fn dcmd(&mut self, device: &str, payload: &[u8], now: SystemTime, out: &mut Vec<Output>) {
        let Some((&position, _)) = self.devices.iter().find(|(_, d)| d.id == device) else {
            self.refuse(now, || {
                format!(
                    "mqtt: DCMD for device {device:?} ignored: no such device on this edge node; \
                 check the device IDs in the DBIRTH topics"
                )
            });
            return;
        };
        let metrics = match command::decode(payload) {
            Ok(m) => m,
            Err(e) => {
                self.refuse(now, || format!("mqtt: DCMD for {device} ignored: {e}"));
                return;
            }
        };
        match self.write_ops(position, &metrics) {
            Ok(ops) => {
                if self.settings.read_only {
                    self.refuse(now, || format!(
                        "mqtt: DCMD for {device} refused: the MQTT front end is read-only ([mqtt] read_only)"
                    ));
                    return;
                }
                let via = format!(
                    "DCMD {}",
                    metrics
                        .iter()
                        .map(CommandMetric::label)
                        .collect::<Vec<_>>()
                        .join(", ")
                );
                let commands = ops.iter().map(WriteOp::command);
                let asked = hart_access::WriteRecord {
                    front_end: "mqtt",
                    peer: "broker".into(),
                    device: device.to_string(),
                    via: via.clone(),
                    operation: Some(
                        ops.iter()
                            .map(WriteOp::describe)
                            .collect::<Vec<_>>()
                            .join("; "),
                    ),
                    ..Default::default()
                };
                if let Err(why) = self.settings.gateway.judge_all(commands, &asked) {
                    self.refuse(now, || format!("mqtt: DCMD for {device} refused: {why}"));
                    return;
                }
                out.push(Output::Write(WriteRequest {
                    position,
                    device: device.to_string(),
                    ops,
                    via,
                }));
            }
            Err(why) => {
                self.refuse(now, || format!("mqtt: DCMD for {device} ignored: {why}"));
            }
        }
    }

    /// A command refused: counted, and logged unless the second's lines are spent
    /// (how many were left out is logged when the next second begins).
    fn refuse(&mut self, now: SystemTime, line: impl FnOnce() -> String) {
        self.counters.bad_commands += 1;
        let (log, left_out) = self.refusals_logged.allow_ms(millis(now));
        if left_out > 0 {
            tracing::warn!(
                "mqtt: {left_out} more commands refused in the last second(s), not logged one by one"
            );
        }
        if log {
            tracing::warn!("{}", line());
        }
    }

    /// Time passing (call about once a second): the rebirth asked for within
    /// [`REBIRTH_INTERVAL_MS`] of the last births, once that time is up.
    pub fn tick(&mut self, now: SystemTime) -> Vec<Output> {
        let mut out = vec![];
        let due = self.last_births.is_none_or(|t| !recent(t, millis(now)));
        if self.rebirth_pending && due && self.link == Link::Live {
            tracing::info!("mqtt: rebirth asked by NCMD: NBIRTH and DBIRTH again");
            self.last_births = Some(millis(now));
            self.births(now, &mut out);
        }
        out
    }

    /// The typed writes `metrics` ask of the device at `position`.
    fn write_ops(
        &self,
        position: usize,
        metrics: &[CommandMetric],
    ) -> Result<Vec<WriteOp>, String> {
        let (mut upper, mut lower) = (None, None);
        let mut ops = vec![];
        for m in metrics {
            let index = match (&m.name, m.alias) {
                (Some(n), _) => metrics::index_of(n),
                (None, Some(a)) => match metrics::from_alias(a) {
                    Some((p, i)) if p == position => Some(i),
                    _ => None,
                },
                (None, None) => None,
            };
            let Some(index) = index else {
                return Err(format!("{} is not a metric of this device", m.label()));
            };
            let def = DEVICE_METRICS[index];
            let Some(kind) = def.write else {
                return Err(format!(
                    "{} cannot be written; writable: {}",
                    def.name,
                    DEVICE_METRICS
                        .iter()
                        .filter(|d| d.write.is_some())
                        .map(|d| d.name)
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            };
            let number = || match &m.value {
                CommandValue::Number(x) if x.is_finite() => Ok(*x as f32),
                v => Err(format!("{} takes a finite number, not {v:?}", def.name)),
            };
            let text = || match &m.value {
                CommandValue::Text(s) => Ok(s.clone()),
                v => Err(format!("{} takes a string, not {v:?}", def.name)),
            };
            match kind {
                Writable::UpperRange => upper = Some(number()?),
                Writable::LowerRange => lower = Some(number()?),
                Writable::Damping => ops.push(WriteOp::Damping(number()?)),
                Writable::FixedCurrent => ops.push(WriteOp::FixedCurrent(number()?)),
                Writable::Tag => ops.push(WriteOp::Tag(text()?)),
                Writable::LongTag => ops.push(WriteOp::LongTag(text()?)),
            }
        }
        if upper.is_some() || lower.is_some() {
            // Command 35 writes both: the one not given keeps the device's value.
            ops.insert(
                0,
                WriteOp::Range {
                    upper,
                    lower,
                    units: None,
                },
            );
        }
        for op in &ops {
            op.validate().map_err(|e| e.to_string())?;
        }
        Ok(ops)
    }

    fn state(&mut self, payload: &[u8], now: SystemTime, out: &mut Vec<Output>) {
        #[derive(serde::Deserialize)]
        struct State {
            online: bool,
            timestamp: u64,
        }
        let host = self.settings.primary_host.clone().unwrap_or_default();
        let s: State = match serde_json::from_slice(payload) {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!(
                    "mqtt: STATE of primary host {host} ignored: not the Sparkplug 3.0 JSON \
                     {{\"online\": true|false, \"timestamp\": ms}} ({e})"
                );
                return;
            }
        };
        if self.last_state.is_some_and(|t| s.timestamp < t) {
            tracing::debug!("mqtt: STATE of {host} older than the last one: ignored");
            return;
        }
        self.last_state = Some(s.timestamp);
        self.host_online = s.online;
        match (s.online, self.link) {
            (true, Link::WaitingForHost) => {
                tracing::info!("mqtt: primary host {host} is online: publishing the births");
                self.births(now, out);
            }
            (false, Link::Live) => {
                tracing::warn!(
                    "mqtt: primary host {host} is offline: NDEATH, disconnecting, keeping \
                     samples until it is back"
                );
                out.push(Output::Publish(self.death(now)));
                out.push(Output::Disconnect);
                self.disconnected(vec![]);
            }
            _ => {}
        }
    }
}

/// The metrics of `new` that differ from `old`.
fn diff(old: &[Value], new: &[Value]) -> Vec<(usize, Value)> {
    new.iter()
        .enumerate()
        .filter(|(i, v)| old.get(*i).is_none_or(|o| !o.same(v)))
        .map(|(i, v)| (i, v.clone()))
        .collect()
}
