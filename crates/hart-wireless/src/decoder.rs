//! A stateful decoder for captured WirelessHART traffic: recovers the ASN of frames
//! that do not carry it, verifies data-link MICs, decrypts network PDUs, and learns the
//! network key (command 961) and session keys (command 963) from what it decrypts.

use std::collections::{BTreeMap, HashMap};
use std::string::{String, ToString};
use std::vec::Vec;
use std::{format, vec};

use crate::capture::{hex, Packet};
use crate::crypto::{Key, WELL_KNOWN_KEY};
use crate::dll::{DlBody, Dlpdu};
use crate::mac::Address;
use crate::nl::{Npdu, Security};
use crate::tl::Tpdu;

/// Slots per second: 10 ms slots.
pub const SLOTS_PER_SECOND: f64 = 100.0;

/// A session learned from command 963 (or given).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Session {
    /// 0 unicast, 1 broadcast, 2 join.
    pub kind: u8,
    /// The peer's nickname.
    pub peer: u16,
    /// The key.
    pub key: Key,
    /// The nonce counter given with it.
    pub counter: u32,
}

/// Where a data-link key came from, for the statistics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum DlKey {
    /// The well-known key.
    WellKnown,
    /// The network key (given or learned from command 961), by index of learning.
    Network(usize),
}

/// The network-layer part of a decoded data frame.
#[derive(Debug, Clone, PartialEq)]
pub struct NlReport {
    /// The network PDU.
    pub npdu: Npdu,
    /// The full nonce counter used when decrypted.
    pub counter: Option<u32>,
    /// The decrypted transport PDU bytes.
    pub plain: Option<Vec<u8>>,
    /// The parsed transport PDU (when the plaintext is a list of commands).
    pub tpdu: Option<Tpdu>,
    /// Why no key opened it, when not decrypted.
    pub why_not: Option<&'static str>,
}

/// One decoded frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameReport {
    /// 0-based index in the capture.
    pub index: usize,
    /// Capture time, ns since the epoch.
    pub time_ns: u64,
    /// Channel, when the capture says.
    pub channel: Option<u8>,
    /// The FCS check, when the capture holds an FCS.
    pub fcs_ok: Option<bool>,
    /// The data-link PDU, or why it could not be parsed.
    pub dl: Result<Dlpdu, String>,
    /// The ASN (carried, or recovered), when known.
    pub asn: Option<u64>,
    /// The data-link MIC check; `None` when no key was known.
    pub dl_mic_ok: Option<bool>,
    /// The key the MIC verified with.
    pub dl_key: Option<DlKey>,
    /// The network layer of a data frame.
    pub nl: Option<NlReport>,
}

/// Counts kept across a run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Stats {
    /// Frames read.
    pub frames: usize,
    /// Frames by type name (`malformed` included).
    pub by_type: BTreeMap<&'static str, usize>,
    /// Data-link MICs verified, per key name.
    pub mic_ok: BTreeMap<String, usize>,
    /// Data-link MICs that failed although a key was known.
    pub mic_failed: usize,
    /// Frames whose MIC could not be checked (no key, or no ASN yet).
    pub mic_unchecked: usize,
    /// Network PDUs seen.
    pub npdus: usize,
    /// Network PDUs decrypted.
    pub decrypted: usize,
    /// Commands seen, by number.
    pub commands: BTreeMap<u16, usize>,
    /// Commands decoded by their typed layout (vendor commands counted as typed raw).
    pub commands_typed: usize,
    /// Commands whose data did not fit their layout.
    pub commands_bad: usize,
    /// Commands no table types.
    pub commands_untyped: usize,
    /// Decrypted payloads that are not a list of commands (vendor payloads).
    pub vendor_payloads: usize,
}

/// The decoder: feed it captured frames in order.
#[derive(Debug, Clone, Default)]
pub struct Decoder {
    join_keys: Vec<Key>,
    network_keys: Vec<Key>,
    sessions: Vec<Session>,
    /// Last full nonce counter per (key, sender).
    counters: HashMap<(Key, Address), u32>,
    last_adv: Option<(u64, u64)>,
    /// The statistics so far.
    pub stats: Stats,
}

impl Decoder {
    /// A decoder knowing no keys but the well-known one.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a join key (tried on join-keyed network PDUs).
    pub fn add_join_key(&mut self, k: Key) {
        if !self.join_keys.contains(&k) {
            self.join_keys.push(k);
        }
    }

    /// Adds a network key (tried on data-link MICs with the key bit set).
    pub fn add_network_key(&mut self, k: Key) {
        if !self.network_keys.contains(&k) {
            self.network_keys.push(k);
        }
    }

    /// Adds a session key.
    pub fn add_session(&mut self, s: Session) {
        if !self.sessions.iter().any(|x| x.key == s.key) {
            self.sessions.push(s);
        }
    }

    /// The network keys known.
    pub fn network_keys(&self) -> &[Key] {
        &self.network_keys
    }

    /// The sessions known.
    pub fn sessions(&self) -> &[Session] {
        &self.sessions
    }

    /// Decodes one captured frame.
    pub fn decode(&mut self, index: usize, p: &Packet) -> FrameReport {
        let mut r = FrameReport {
            index,
            time_ns: p.time_ns,
            channel: p.channel,
            fcs_ok: p.fcs_ok,
            dl: Err(String::new()),
            asn: None,
            dl_mic_ok: None,
            dl_key: None,
            nl: None,
        };
        self.stats.frames += 1;
        let d = match Dlpdu::parse(&p.frame) {
            Ok(d) => d,
            Err(e) => {
                r.dl = Err(e.to_string());
                *self.stats.by_type.entry("malformed").or_default() += 1;
                return r;
            }
        };
        *self.stats.by_type.entry(d.pdu_type.name()).or_default() += 1;
        // The ASN: carried by advertisements, else from the last one and the time.
        let candidates: Vec<u64> = match &d.body {
            DlBody::Advertise(a) => vec![a.asn],
            _ => match self.last_adv {
                Some((asn, t)) => {
                    let dt = p.time_ns as f64 / 1e9 - t as f64 / 1e9;
                    let est = asn as f64 + dt * SLOTS_PER_SECOND;
                    let base = (est.max(0.0) as u64 & !0xFF) | d.seq as u64;
                    let mut c: Vec<u64> = [base.checked_sub(256), Some(base), Some(base + 256)]
                        .into_iter()
                        .flatten()
                        .collect();
                    c.sort_by(|a, b| (*a as f64 - est).abs().total_cmp(&(*b as f64 - est).abs()));
                    c
                }
                None => vec![],
            },
        };
        let keys: Vec<(DlKey, Key)> = if d.network_key {
            self.network_keys
                .iter()
                .enumerate()
                .map(|(i, k)| (DlKey::Network(i), *k))
                .collect()
        } else {
            vec![(DlKey::WellKnown, WELL_KNOWN_KEY)]
        };
        r.asn = candidates.first().copied();
        if !keys.is_empty() && !candidates.is_empty() {
            r.dl_mic_ok = Some(false);
            'found: for &asn in &candidates {
                for (name, k) in &keys {
                    if d.verify(k, asn) {
                        r.asn = Some(asn);
                        r.dl_mic_ok = Some(true);
                        r.dl_key = Some(*name);
                        break 'found;
                    }
                }
            }
        }
        match r.dl_mic_ok {
            Some(true) => {
                let name = match r.dl_key {
                    Some(DlKey::Network(i)) => {
                        format!("network key {}", hex(&self.network_keys[i]))
                    }
                    _ => "well-known key".to_string(),
                };
                *self.stats.mic_ok.entry(name).or_default() += 1;
            }
            Some(false) => self.stats.mic_failed += 1,
            None => self.stats.mic_unchecked += 1,
        }
        if let (DlBody::Advertise(a), Some(true)) = (&d.body, r.dl_mic_ok) {
            self.last_adv = Some((a.asn, p.time_ns));
        } else if let (DlBody::Advertise(a), None) = (&d.body, r.dl_mic_ok) {
            self.last_adv = Some((a.asn, p.time_ns));
        }
        if let DlBody::Data(n) = &d.body {
            self.stats.npdus += 1;
            r.nl = Some(self.network(n));
        }
        r.dl = Ok(d);
        r
    }

    fn network(&mut self, n: &Npdu) -> NlReport {
        let mut rep = NlReport {
            npdu: n.clone(),
            counter: None,
            plain: None,
            tpdu: None,
            why_not: None,
        };
        let sender = n.src;
        let opened = match n.security {
            Security::Join(c) => {
                if self.join_keys.is_empty() {
                    rep.why_not = Some("join-keyed and no join key given (--join-key)");
                }
                self.join_keys
                    .iter()
                    .find_map(|k| n.decrypt(k, c).map(|p| (p, c, *k)))
            }
            Security::Session(low) => {
                if self.sessions.is_empty() {
                    rep.why_not =
                        Some("session-keyed and no session key learned yet (command 963)");
                }
                let mut found = None;
                'keys: for s in &self.sessions {
                    let last = self.counters.get(&(s.key, sender)).copied().unwrap_or(0);
                    let base = (last & !0xFF) | low as u32;
                    for c in [Some(base), base.checked_add(256), base.checked_sub(256)]
                        .into_iter()
                        .flatten()
                    {
                        if let Some(p) = n.decrypt(&s.key, c) {
                            found = Some((p, c, s.key));
                            break 'keys;
                        }
                    }
                }
                found
            }
        };
        match opened {
            Some((plain, c, k)) => {
                if let Security::Session(_) = n.security {
                    self.counters.insert((k, sender), c);
                }
                self.stats.decrypted += 1;
                rep.counter = Some(c);
                rep.tpdu = Tpdu::parse(&plain).ok();
                if rep.tpdu.is_none() {
                    self.stats.vendor_payloads += 1;
                }
                if let Some(t) = &rep.tpdu {
                    for cmd in &t.commands {
                        *self.stats.commands.entry(cmd.number).or_default() += 1;
                        match crate::commands::decode(cmd.number, t.response, &cmd.data) {
                            Some(Ok(_)) => self.stats.commands_typed += 1,
                            Some(Err(_)) => self.stats.commands_bad += 1,
                            None => self.stats.commands_untyped += 1,
                        }
                        self.learn(cmd.number, t.response, &cmd.data);
                    }
                }
                rep.plain = Some(plain);
                rep.why_not = None;
            }
            None => {
                if rep.why_not.is_none() {
                    rep.why_not = Some("no known key verifies its MIC");
                }
            }
        }
        rep
    }

    /// Learns keys from a decrypted command (961 network key, 963 session).
    fn learn(&mut self, number: u16, response: bool, data: &[u8]) {
        let d = if response {
            data.get(1..).unwrap_or(&[])
        } else {
            data
        };
        match number {
            961 if d.len() >= 16 => {
                let mut k = [0u8; 16];
                k.copy_from_slice(&d[..16]);
                self.add_network_key(k);
            }
            963 if d.len() >= 28 => {
                let mut k = [0u8; 16];
                k.copy_from_slice(&d[12..28]);
                self.add_session(Session {
                    kind: d[0],
                    peer: u16::from_be_bytes([d[1], d[2]]),
                    key: k,
                    counter: u32::from_be_bytes([d[8], d[9], d[10], d[11]]),
                });
            }
            _ => {}
        }
    }
}

impl FrameReport {
    /// The frame type as the JSON view names it (`"malformed"` when unparsable).
    pub fn type_name(&self) -> &'static str {
        match &self.dl {
            Ok(d) => d.pdu_type.name(),
            Err(_) => "malformed",
        }
    }

    /// The JSON object of this frame (one line of `hartkit wireless decode --json`).
    pub fn to_json(&self) -> serde_json::Value {
        use serde_json::{json, Map, Value};
        let mut o = Map::new();
        o.insert("index".into(), json!(self.index));
        o.insert("time".into(), json!(self.time_ns as f64 / 1e9));
        o.insert("channel".into(), json!(self.channel));
        o.insert("type".into(), json!(self.type_name()));
        let d = match &self.dl {
            Ok(d) => d,
            Err(reason) => {
                o.insert("reason".into(), json!(reason));
                o.insert("fcs_ok".into(), json!(self.fcs_ok));
                return Value::Object(o);
            }
        };
        o.insert("seq".into(), json!(d.seq));
        o.insert("network_id".into(), json!(format!("{:04x}", d.network_id)));
        o.insert("src".into(), json!(d.src.to_string()));
        o.insert("dst".into(), json!(d.dst.to_string()));
        o.insert("asn".into(), json!(self.asn));
        o.insert("fcs_ok".into(), json!(self.fcs_ok));
        o.insert(
            "dl_key".into(),
            json!(if d.network_key {
                "network"
            } else {
                "well-known"
            }),
        );
        o.insert("dl_mic_ok".into(), json!(self.dl_mic_ok));
        match &d.body {
            DlBody::Advertise(a) => {
                o.insert(
                    "advertise".into(),
                    json!({
                        "join_control": a.join_control,
                        "channel_map": format!("{:04x}", a.channel_map),
                        "graph_id": a.graph_id,
                        "superframes": a.superframes.iter().map(|s| json!({
                            "id": s.id, "slots": s.slots,
                            "links": s.links.iter().map(|l| json!({"slot": l.slot, "channel_offset": l.channel_offset(), "transmit": l.transmit()})).collect::<Vec<_>>(),
                        })).collect::<Vec<_>>(),
                    }),
                );
            }
            DlBody::Ack(a) => {
                o.insert(
                    "ack".into(),
                    json!({"response_code": a.response_code, "time_adjustment_us": a.time_adjustment}),
                );
            }
            _ => {}
        }
        if let Some(nl) = &self.nl {
            let n = &nl.npdu;
            let mut m = Map::new();
            m.insert("src".into(), json!(n.src.to_string()));
            m.insert("dst".into(), json!(n.dst.to_string()));
            m.insert("ttl".into(), json!(n.ttl));
            m.insert("graph_id".into(), json!(n.graph_id));
            m.insert("security".into(), json!(n.security.name()));
            m.insert(
                "counter".into(),
                json!(nl.counter.unwrap_or(n.security.counter())),
            );
            m.insert("decrypted".into(), json!(nl.plain.is_some()));
            if let Some(why) = nl.why_not {
                m.insert("reason".into(), json!(why));
            }
            match (&nl.tpdu, &nl.plain) {
                (Some(t), _) => {
                    m.insert("response".into(), json!(t.response));
                    m.insert(
                        "commands".into(),
                        Value::Array(
                            t.commands
                                .iter()
                                .map(|c| command_json(c.number, t.response, &c.data))
                                .collect(),
                        ),
                    );
                }
                (None, Some(p)) => {
                    m.insert("commands".into(), json!([]));
                    m.insert("vendor_payload".into(), json!(hex(p)));
                }
                _ => {}
            }
            o.insert("nl".into(), Value::Object(m));
        }
        Value::Object(o)
    }

    /// One human-readable line: time, channel, type, source → destination, commands.
    pub fn to_line(&self) -> String {
        use std::fmt::Write;
        let mut s = format!("{:>5} {:>14.6}", self.index, self.time_ns as f64 / 1e9);
        match self.channel {
            Some(c) => {
                let _ = write!(s, " ch{c:<2}");
            }
            None => s.push_str(" ch? "),
        }
        let d = match &self.dl {
            Ok(d) => d,
            Err(e) => {
                let _ = write!(s, " malformed: {e}");
                return s;
            }
        };
        let _ = write!(s, " {:<10} {} -> {}", d.pdu_type.name(), d.src, d.dst);
        match self.dl_mic_ok {
            Some(true) => {}
            Some(false) => s.push_str(" [MIC FAILED]"),
            None => s.push_str(" [MIC unchecked]"),
        }
        if let Some(nl) = &self.nl {
            let _ = write!(
                s,
                " | {} -> {} {}",
                nl.npdu.src,
                nl.npdu.dst,
                nl.npdu.security.name()
            );
            match (&nl.tpdu, &nl.plain) {
                (Some(t), _) => {
                    s.push_str(if t.response { " rsp" } else { " req" });
                    for c in &t.commands {
                        let _ = write!(s, " {}:{}", c.number, crate::commands::name(c.number));
                    }
                }
                (None, Some(p)) => {
                    let _ = write!(s, " vendor payload ({} bytes)", p.len());
                }
                _ => s.push_str(" (sealed)"),
            }
        }
        s
    }
}

impl Stats {
    /// The summary printed after a run.
    pub fn summary(&self) -> String {
        use std::fmt::Write;
        let mut s = format!("{} frames:", self.frames);
        for (t, n) in &self.by_type {
            let _ = write!(s, " {t} {n},");
        }
        s.pop();
        s.push('\n');
        for (k, n) in &self.mic_ok {
            let _ = writeln!(s, "data-link MICs verified with the {k}: {n}");
        }
        let _ = writeln!(
            s,
            "data-link MICs failed: {}, not checked (key or ASN not known yet): {}",
            self.mic_failed, self.mic_unchecked
        );
        let _ = writeln!(
            s,
            "network PDUs: {}, decrypted: {} ({} vendor payloads)",
            self.npdus, self.decrypted, self.vendor_payloads
        );
        let _ = writeln!(
            s,
            "commands: {} decoded by their layout, {} did not fit, {} untyped",
            self.commands_typed, self.commands_bad, self.commands_untyped
        );
        let list: Vec<String> = self
            .commands
            .iter()
            .map(|(c, n)| format!("{c} {} ×{n}", crate::commands::name(*c)))
            .collect();
        let _ = writeln!(s, "commands seen: {}", list.join(", "));
        s
    }

    /// The statistics as JSON.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "frames": self.frames,
            "by_type": self.by_type,
            "mic_ok": self.mic_ok,
            "mic_failed": self.mic_failed,
            "mic_unchecked": self.mic_unchecked,
            "npdus": self.npdus,
            "decrypted": self.decrypted,
            "vendor_payloads": self.vendor_payloads,
            "commands_typed": self.commands_typed,
            "commands_bad": self.commands_bad,
            "commands_untyped": self.commands_untyped,
            "commands": self.commands.iter().map(|(c, n)| (c.to_string(), *n)).collect::<BTreeMap<_, _>>(),
        })
    }
}

/// Reads a capture and decodes it whole with the given keys.
pub fn decode_capture(
    data: &[u8],
    join_keys: &[Key],
    network_keys: &[Key],
) -> Result<(Vec<FrameReport>, Stats), crate::capture::CaptureError> {
    let packets = crate::capture::read(data)?;
    let mut d = Decoder::new();
    join_keys.iter().for_each(|k| d.add_join_key(*k));
    network_keys.iter().for_each(|k| d.add_network_key(*k));
    let reports = packets
        .iter()
        .enumerate()
        .map(|(i, p)| d.decode(i, p))
        .collect();
    Ok((reports, d.stats))
}

/// One command as JSON: `command`, `name`, `data` (hex), and when its layout decoded
/// it, `response_code` (responses) and `fields`, or `error` when the data did not fit.
pub fn command_json(number: u16, response: bool, data: &[u8]) -> serde_json::Value {
    use crate::commands::{self, Typed};
    let mut o = serde_json::Map::new();
    o.insert("command".into(), number.into());
    o.insert("name".into(), commands::name(number).into());
    o.insert("data".into(), hex(data).into());
    match commands::decode(number, response, data) {
        Some(Ok(t)) => {
            if let Typed::Response(code, _) | Typed::WiredResponse(code, _) = &t {
                o.insert("response_code".into(), (*code).into());
                if let Some(n) = commands::code_name(number, *code) {
                    o.insert("response_code_name".into(), n.into());
                }
            }
            if !matches!(t, Typed::Vendor) {
                let mut v = hart_proto::json::JsonVisitor::default();
                commands::describe(&t, &mut v);
                o.insert("fields".into(), v.finish());
            }
        }
        Some(Err(e)) => {
            o.insert("error".into(), e.to_string().into());
        }
        None => {}
    }
    serde_json::Value::Object(o)
}
