//! The host side of Sparkplug B as a sans-IO state machine: a message's topic and
//! payload and the time in; the historian's samples, and the messages to publish
//! (rebirth requests), out.
//!
//! What it learns and checks (Sparkplug 3.0.0):
//! - NBIRTH starts an edge node's session: its `seq` (0) and `bdSeq`; the node's
//!   devices are forgotten until their DBIRTH;
//! - DBIRTH gives each metric's name, alias, data type and units, and the device's
//!   identity: `Properties/UniqueId`, `Properties/LongTag` (else `Properties/Tag`) and
//!   `Properties/Loop` as hart-sparkplug publishes them ([`hart_sparkplug::metrics`]);
//!   its values are samples too;
//! - DDATA names its metrics by alias; every metric is stored with its own time
//!   stamp (historical ones, sent after an outage, included);
//! - a DDATA (or DBIRTH) of a node whose NBIRTH was not seen, or a DDATA of a device
//!   whose DBIRTH was not seen, is counted and logged, and the node is asked for a
//!   rebirth with an NCMD `Node Control/Rebirth` (at most once per
//!   [`REBIRTH_EVERY`]), as section 7.4 says a host application should;
//! - `seq` gaps are counted and logged (with QoS 1 and a broker cluster a message may
//!   arrive twice: the historian's key stores it once);
//! - NDEATH (of the current `bdSeq`) and DDEATH end births.
//!
//! Malformed topics and payloads are typed errors ([`Rejected`]), never panics.

use std::collections::HashMap;
use std::time::{Duration, SystemTime};

use hart_history::{widen, DeviceKey, Sample, Var, UNITS_MILLIAMPERES, UNITS_PERCENT};
use hart_sparkplug::metrics;
use hart_sparkplug::proto::datatype as dt;
use hart_sparkplug::proto::payload::{metric, property_value, Metric};
use hart_sparkplug::proto::Payload;
use hart_sparkplug::{millis, NAMESPACE};
use prost::Message as _;

/// The shortest time between two rebirth requests to one edge node.
pub const REBIRTH_EVERY: Duration = Duration::from_secs(5);

/// Why a message was not used. Its text says what was wrong and what to check.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Rejected {
    /// The topic is not `spBv1.0/GROUP/TYPE/EDGE_NODE[/DEVICE]` of the group.
    Topic(String),
    /// The payload is not a Sparkplug B protobuf payload.
    Payload(String),
    /// The payload is longer than [`MAX_MESSAGE_BYTES`]: not decoded.
    TooLarge {
        /// Its topic.
        topic: String,
        /// Its length, bytes.
        bytes: usize,
    },
}

/// Longest message the ingest decodes, bytes (1 MiB). A Sparkplug B payload of a
/// gateway is a few kilobytes (a birth of 64 devices under 200 KiB); a longer one is
/// acknowledged, counted and dropped, so it can never hold the historian up.
pub const MAX_MESSAGE_BYTES: usize = 1 << 20;

impl std::fmt::Display for Rejected {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Rejected::Topic(m) | Rejected::Payload(m) => f.write_str(m),
            Rejected::TooLarge { topic, bytes } => write!(
                f,
                "a message of {bytes} bytes on {topic}, more than the {MAX_MESSAGE_BYTES} the \
                 ingest decodes: acknowledged and dropped; check what publishes it"
            ),
        }
    }
}

impl std::error::Error for Rejected {}

/// A message for the client to publish.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Publish {
    /// Topic.
    pub topic: String,
    /// Sparkplug B payload.
    pub payload: Vec<u8>,
}

/// What one message gave.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Output {
    /// Samples for the historian.
    pub samples: Vec<Sample>,
    /// Messages to publish (an NCMD rebirth request).
    pub publish: Vec<Publish>,
    /// A birth (NBIRTH or DBIRTH) to keep with the historian, as topic and payload:
    /// after a restart, [`Decoder::restore`] reads the data the broker kept against it.
    pub birth: Option<(String, Vec<u8>)>,
}

/// Counters, for the summary line and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Messages decoded.
    pub messages: u64,
    /// Samples given to the historian.
    pub samples: u64,
    /// NBIRTH and DBIRTH seen.
    pub births: u64,
    /// Data messages of a node or device whose birth was not seen.
    pub before_birth: u64,
    /// Metrics by an alias the device's birth did not name.
    pub unknown_alias: u64,
    /// `seq` not the one after the previous message of the node.
    pub seq_gaps: u64,
    /// Messages refused (bad topic or payload, too large).
    pub rejected: u64,
    /// Messages refused for being longer than [`MAX_MESSAGE_BYTES`].
    pub too_large: u64,
    /// NCMD rebirth requests published.
    pub rebirths: u64,
}

/// The message types of the Sparkplug B topic namespace.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    NBirth,
    NDeath,
    DBirth,
    DDeath,
    NData,
    DData,
    Command,
}

#[derive(Debug, Default)]
struct Device {
    /// Alias to metric name, from the DBIRTH.
    names: HashMap<u64, String>,
    unique_id: Option<String>,
    long_tag: Option<String>,
    tag: Option<String>,
    loop_name: Option<String>,
    /// HART units code of each variable, from the DBIRTH's `hartUnitCode` properties.
    units: HashMap<Var, u8>,
    quality: u8,
}

#[derive(Debug, Default)]
struct Node {
    born: bool,
    bd_seq: Option<u64>,
    seq: Option<u8>,
    devices: HashMap<String, Device>,
    last_rebirth: Option<SystemTime>,
    warned_before_birth: bool,
}

/// The ingest's decoder for one Sparkplug group.
#[derive(Debug)]
pub struct Decoder {
    group: String,
    nodes: HashMap<String, Node>,
    counters: Counters,
}

/// The historian's variable a device metric is (hart-sparkplug's one table,
/// [`metrics::STORED`]).
fn var_of(name: &str) -> Option<Var> {
    Var::from_code(i64::from(metrics::stored_code(name)?))
}

/// A metric's value as a number, when it is one.
fn number(m: &Metric) -> Option<f64> {
    if m.is_null == Some(true) {
        return None;
    }
    match m.value.as_ref()? {
        metric::Value::FloatValue(x) => Some(widen(*x)),
        metric::Value::DoubleValue(x) => Some(*x),
        metric::Value::IntValue(x) => Some(match m.datatype {
            Some(dt::INT8) => f64::from(*x as u8 as i8),
            Some(dt::INT16) => f64::from(*x as u16 as i16),
            Some(dt::INT32) => f64::from(*x as i32),
            _ => f64::from(*x),
        }),
        metric::Value::LongValue(x) => Some(match m.datatype {
            Some(dt::INT64) => *x as i64 as f64,
            _ => *x as f64,
        }),
        metric::Value::BooleanValue(b) => Some(f64::from(u8::from(*b))),
        _ => None,
    }
}

fn text(m: &Metric) -> Option<String> {
    match (&m.value, m.is_null) {
        (_, Some(true)) => None,
        (Some(metric::Value::StringValue(s)), _) => {
            Some(s.trim().to_string()).filter(|s| !s.is_empty())
        }
        _ => None,
    }
}

fn unit_code(m: &Metric) -> Option<u8> {
    let p = m.properties.as_ref()?;
    let i = p.keys.iter().position(|k| k == "hartUnitCode")?;
    match p.values.get(i)?.value.as_ref()? {
        property_value::Value::IntValue(c) => u8::try_from(*c).ok(),
        property_value::Value::LongValue(c) => u8::try_from(*c).ok(),
        _ => None,
    }
}

/// The time `ms` after the epoch (a time beyond what the system can hold is taken as
/// the epoch: the sample is still stored, where it can be seen to be wrong).
use hart_clock::epoch::from_millis as time_of;

impl Decoder {
    /// A decoder for the Sparkplug group `group` that has seen nothing yet.
    pub fn new(group: &str) -> Self {
        Decoder {
            group: group.to_string(),
            nodes: HashMap::new(),
            counters: Counters::default(),
        }
    }

    /// The topic filter to subscribe to: every message of the group.
    pub fn filter(&self) -> String {
        format!("{NAMESPACE}/{}/#", self.group)
    }

    /// The counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Takes in the births an earlier run kept ([`Output::birth`]): each node's NBIRTH,
    /// then its DBIRTHs, so that the data the broker kept for the session while the
    /// ingest was away (its metrics carry aliases only) can be read. Nothing is stored
    /// or asked, and the counters stay as they were.
    pub fn restore(&mut self, births: &[(String, Vec<u8>)], now: SystemTime) {
        let counters = self.counters;
        let is = |t: &str, kind: &str| t.split('/').nth(2) == Some(kind);
        for (topic, payload) in births.iter().filter(|(t, _)| is(t, "NBIRTH")) {
            let _ = self.decode(topic, payload, now);
        }
        for (topic, payload) in births.iter().filter(|(t, _)| is(t, "DBIRTH")) {
            let _ = self.decode(topic, payload, now);
        }
        self.counters = counters;
    }

    /// One message received on `topic`, at `now`.
    pub fn received(
        &mut self,
        topic: &str,
        payload: &[u8],
        now: SystemTime,
    ) -> Result<Output, Rejected> {
        let r = if payload.len() > MAX_MESSAGE_BYTES {
            self.counters.too_large += 1;
            Err(Rejected::TooLarge {
                topic: topic.to_string(),
                bytes: payload.len(),
            })
        } else {
            self.decode(topic, payload, now)
        };
        match &r {
            Ok(o) => {
                self.counters.messages += 1;
                self.counters.samples += o.samples.len() as u64;
            }
            Err(_) => self.counters.rejected += 1,
        }
        r
    }

    fn decode(&mut self, topic: &str, payload: &[u8], now: SystemTime) -> Result<Output, Rejected> {
        let mut out = Output::default();
        let parts: Vec<&str> = topic.split('/').collect();
        if parts.first() != Some(&NAMESPACE) {
            return Err(Rejected::Topic(format!(
                "topic {topic:?} is not in the {NAMESPACE} namespace; check what else publishes under the subscription"
            )));
        }
        if parts.get(1) == Some(&"STATE") {
            return Ok(out);
        }
        if parts.get(1) != Some(&self.group.as_str()) {
            return Err(Rejected::Topic(format!(
                "topic {topic:?} is not of group {}",
                self.group
            )));
        }
        let kind = match parts.get(2).copied() {
            Some("NBIRTH") => Kind::NBirth,
            Some("NDEATH") => Kind::NDeath,
            Some("DBIRTH") => Kind::DBirth,
            Some("DDEATH") => Kind::DDeath,
            Some("NDATA") => Kind::NData,
            Some("DDATA") => Kind::DData,
            Some("NCMD" | "DCMD") => Kind::Command,
            other => {
                return Err(Rejected::Topic(format!(
                    "topic {topic:?}: unknown Sparkplug message type {:?}",
                    other.unwrap_or("")
                )))
            }
        };
        if kind == Kind::Command {
            // Commands are for edge nodes (ours included).
            return Ok(out);
        }
        let device_level = matches!(kind, Kind::DBirth | Kind::DDeath | Kind::DData);
        let (edge, device) = match (parts.len(), device_level) {
            (4, false) => (parts[3], None),
            (5, true) => (parts[3], Some(parts[4])),
            _ => {
                return Err(Rejected::Topic(format!(
                    "topic {topic:?}: expected {NAMESPACE}/GROUP/TYPE/EDGE_NODE{}",
                    if device_level { "/DEVICE" } else { "" }
                )))
            }
        };
        if edge.is_empty() || device.is_some_and(str::is_empty) {
            return Err(Rejected::Topic(format!("topic {topic:?}: an empty ID")));
        }
        let p = Payload::decode(payload).map_err(|e| {
            Rejected::Payload(format!(
                "{topic}: the payload is not a Sparkplug B payload ({e}); check that the publisher speaks Sparkplug B (spBv1.0)"
            ))
        })?;
        let sent = p.timestamp.map_or(now, time_of);
        let node = self.nodes.entry(edge.to_string()).or_default();
        // Sequence numbers: NDEATH has none; NBIRTH starts at its own.
        if kind != Kind::NDeath {
            match p.seq {
                Some(s) if s > 255 => {
                    return Err(Rejected::Payload(format!(
                        "{topic}: seq {s} is out of 0-255"
                    )))
                }
                Some(s) => {
                    let s = s as u8;
                    if kind != Kind::NBirth {
                        if let Some(last) = node.seq {
                            if s != last.wrapping_add(1) {
                                self.counters.seq_gaps += 1;
                                tracing::info!(
                                    "ingest: {topic}: seq {s} after {last} (a gap, or a message sent again at QoS 1)"
                                );
                            }
                        }
                    }
                    node.seq = Some(s);
                }
                None => {}
            }
        }
        if matches!(kind, Kind::NBirth | Kind::DBirth) {
            out.birth = Some((topic.to_string(), payload.to_vec()));
        }
        match kind {
            Kind::NBirth => {
                let bd_seq = p
                    .metrics
                    .iter()
                    .find(|m| m.name.as_deref() == Some(metrics::NODE_BDSEQ))
                    .and_then(|m| match m.value {
                        Some(metric::Value::LongValue(v)) => Some(v),
                        Some(metric::Value::IntValue(v)) => Some(u64::from(v)),
                        _ => None,
                    });
                *node = Node {
                    born: true,
                    bd_seq,
                    seq: node.seq,
                    devices: HashMap::new(),
                    last_rebirth: node.last_rebirth,
                    warned_before_birth: false,
                };
                self.counters.births += 1;
            }
            Kind::NDeath => {
                let bd_seq = p.metrics.iter().find_map(|m| match m.value {
                    Some(metric::Value::LongValue(v))
                        if m.name.as_deref() == Some(metrics::NODE_BDSEQ) =>
                    {
                        Some(v)
                    }
                    _ => None,
                });
                // A will of an earlier session (late, or sent again) ends nothing.
                if bd_seq.is_none() || node.bd_seq.is_none() || bd_seq == node.bd_seq {
                    node.born = false;
                    node.devices.clear();
                }
            }
            Kind::NData => {
                if !node.born {
                    Self::before_birth(
                        &mut self.counters,
                        node,
                        topic,
                        edge,
                        &self.group,
                        now,
                        &mut out,
                    );
                }
            }
            Kind::DBirth => {
                let id = device.unwrap_or_default();
                if !node.born {
                    // The values and names are all here: stored, but the node's
                    // session is unknown, so ask for a full rebirth.
                    Self::before_birth(
                        &mut self.counters,
                        node,
                        topic,
                        edge,
                        &self.group,
                        now,
                        &mut out,
                    );
                }
                self.counters.births += 1;
                let mut d = Device::default();
                for m in &p.metrics {
                    let Some(name) = m.name.clone() else { continue };
                    if let Some(a) = m.alias {
                        d.names.insert(a, name.clone());
                    }
                    if let (Some(v), Some(c)) = (var_of(&name), unit_code(m)) {
                        d.units.insert(v, c);
                    }
                }
                let named: Vec<(String, &Metric)> = p
                    .metrics
                    .iter()
                    .filter_map(|m| m.name.clone().map(|n| (n, m)))
                    .collect();
                Self::samples(&mut d, edge, id, &named, sent, &mut out.samples);
                node.devices.insert(id.to_string(), d);
            }
            Kind::DDeath => {
                node.devices.remove(device.unwrap_or_default());
            }
            Kind::DData => {
                let id = device.unwrap_or_default();
                let Some(d) = node.devices.get_mut(id) else {
                    Self::before_birth(
                        &mut self.counters,
                        node,
                        topic,
                        edge,
                        &self.group,
                        now,
                        &mut out,
                    );
                    return Ok(out);
                };
                let mut named = Vec::with_capacity(p.metrics.len());
                for m in &p.metrics {
                    let name = match (&m.name, m.alias) {
                        (Some(n), _) => n.clone(),
                        (None, Some(a)) => match d.names.get(&a) {
                            Some(n) => n.clone(),
                            None => {
                                self.counters.unknown_alias += 1;
                                tracing::debug!("ingest: {topic}: alias {a} is not in the DBIRTH");
                                continue;
                            }
                        },
                        (None, None) => continue,
                    };
                    named.push((name, m));
                }
                Self::samples(d, edge, id, &named, sent, &mut out.samples);
            }
            Kind::Command => {}
        }
        Ok(out)
    }

    /// A message of a node or device whose birth was not seen: counted, logged (once
    /// until the next birth), and a rebirth asked for (at most every
    /// [`REBIRTH_EVERY`]).
    fn before_birth(
        counters: &mut Counters,
        node: &mut Node,
        topic: &str,
        edge: &str,
        group: &str,
        now: SystemTime,
        out: &mut Output,
    ) {
        counters.before_birth += 1;
        if !node.warned_before_birth {
            node.warned_before_birth = true;
            tracing::warn!(
                "ingest: {topic} before its birth was seen (the ingest started after the edge node, or the birth was lost): its data cannot be named; asking {edge} for a rebirth"
            );
        }
        let due = node
            .last_rebirth
            .is_none_or(|t| now.duration_since(t).map_or(true, |d| d >= REBIRTH_EVERY));
        if due {
            node.last_rebirth = Some(now);
            counters.rebirths += 1;
            out.publish.push(rebirth(group, edge, now));
        }
    }

    /// The samples of a birth's or data message's metrics, after the identity, units
    /// and quality they carry are taken in.
    fn samples(
        d: &mut Device,
        edge: &str,
        id: &str,
        metrics: &[(String, &Metric)],
        sent: SystemTime,
        out: &mut Vec<Sample>,
    ) {
        for (name, m) in metrics {
            match name.as_str() {
                "Properties/UniqueId" => d.unique_id = text(m),
                "Properties/LongTag" => d.long_tag = text(m),
                "Properties/Tag" => d.tag = text(m),
                "Properties/Loop" => d.loop_name = text(m),
                "Status/QualityCode" => {
                    if let Some(q) = number(m) {
                        d.quality = q.clamp(0.0, 255.0) as u8;
                    }
                }
                _ => {}
            }
        }
        let key = DeviceKey {
            unique_id: d
                .unique_id
                .clone()
                .unwrap_or_else(|| format!("{edge}/{id}")),
            tag: d
                .long_tag
                .clone()
                .or_else(|| d.tag.clone())
                .unwrap_or_else(|| {
                    if d.unique_id.is_none() {
                        id.to_string()
                    } else {
                        String::new()
                    }
                }),
            loop_name: d.loop_name.clone().unwrap_or_default(),
        };
        for (name, m) in metrics {
            let Some(var) = var_of(name) else { continue };
            let Some(value) = number(m) else { continue };
            let units = match var {
                Var::LoopCurrent => Some(UNITS_MILLIAMPERES),
                Var::PercentRange => Some(UNITS_PERCENT),
                Var::DeviceStatus => None,
                v => d.units.get(&v).copied(),
            };
            out.push(Sample {
                device: key.clone(),
                var,
                value,
                units,
                quality: d.quality,
                time: m.timestamp.map_or(sent, time_of),
            });
        }
    }
}

/// The NCMD asking edge node `edge` of `group` for a rebirth (Sparkplug 3.0 section
/// 6.4.17: `Node Control/Rebirth`, Boolean true).
pub fn rebirth(group: &str, edge: &str, now: SystemTime) -> Publish {
    let payload = Payload {
        timestamp: Some(millis(now)),
        metrics: vec![Metric {
            name: Some(metrics::NODE_REBIRTH.into()),
            timestamp: Some(millis(now)),
            datatype: Some(dt::BOOLEAN),
            value: Some(metric::Value::BooleanValue(true)),
            ..Default::default()
        }],
        ..Default::default()
    };
    Publish {
        topic: format!("{NAMESPACE}/{group}/NCMD/{edge}"),
        payload: payload.encode_to_vec(),
    }
}
