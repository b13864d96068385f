//! The edge node state machine, byte-scripted: events in, topics and payloads out,
//! each payload decoded back and checked field by field against the Sparkplug 3.0
//! rules.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use hart_poller::{DeviceImage, Quality, Variable, WriteOp};
use hart_sparkplug_edge::edge::{millis, EdgeNode, Message, Output, Sample, Settings};
use hart_sparkplug_edge::metrics::{device_alias, index_of};
use hart_sparkplug_edge::proto::payload::{metric::Value as V, Metric};
use hart_sparkplug_edge::proto::Payload;
use prost::Message as _;

fn t(ms: u64) -> SystemTime {
    UNIX_EPOCH + Duration::from_millis(1_700_000_000_000 + ms)
}

fn settings() -> Settings {
    Settings {
        group: "Plant".into(),
        edge_node: "gw1".into(),
        primary_host: None,
        backlog: 1000,
        read_only: false,
        gateway: Default::default(),
    }
}

/// A device heard only in a burst message before its first poll is not born yet;
/// its first poll gives one birth with every value and unit.
#[test]
fn a_device_is_born_after_its_first_poll_not_its_first_burst() {
    let mut node = EdgeNode::new(settings());
    node.will(t(0));
    let _ = node.connected(t(1));
    let mut burst_only = device(0, 1, None, 50.0);
    burst_only.polls = 0;
    let out = node.device(&burst_only, Quality::Good, t(2), t(2));
    assert!(publishes(&out).is_empty(), "no birth before the first poll");
    let out = node.device(&device(0, 1, None, 50.5), Quality::Good, t(3), t(3));
    let msgs = publishes(&out);
    assert_eq!(msgs.len(), 1);
    assert!(msgs[0].topic.contains("/DBIRTH/"), "{}", msgs[0].topic);
}

/// An identified device at `position` (unique ID from `id`), PV `pv` kPa.
fn device(position: usize, id: u8, long_tag: Option<&str>, pv: f32) -> DeviceImage {
    use hart_proto::wire::{Reader, Wire};
    let bytes = [254, 0x26, 0x01, 5, 5, 1, 1, 0x08, 0, 0x10, 0x20, id];
    let identity = hart_proto::command::Identity::decode(&mut Reader::new(&bytes)).unwrap();
    let mut info = hart_host::DeviceInfo::identified(identity, Some(position as u8));
    info.tag = Some("PT-101".into());
    info.long_tag = long_tag.map(str::to_string);
    let mut d = DeviceImage::new(position, 0, "loop1", Duration::from_secs(10));
    d.position = position;
    d.polling_address = Some(position as u8);
    d.info = Some(info);
    d.variables[0] = Some(Variable {
        value: pv,
        units: 12,
        status: None,
    });
    d.loop_current = Some(12.0);
    // Polled once: a device is born after its first poll.
    d.polls = 1;
    d
}

fn publishes(out: &[Output]) -> Vec<&Message> {
    out.iter()
        .filter_map(|o| match o {
            Output::Publish(m) => Some(m),
            _ => None,
        })
        .collect()
}

fn decode(m: &Message) -> Payload {
    Payload::decode(m.payload.as_slice()).unwrap()
}

fn named<'a>(p: &'a Payload, name: &str) -> &'a Metric {
    p.metrics
        .iter()
        .find(|m| m.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no metric {name}"))
}

fn connected(node: &mut EdgeNode, now: SystemTime) -> Vec<Output> {
    let _will = node.will(now);
    node.connected(now)
}

#[test]
fn will_births_and_data() {
    let mut node = EdgeNode::new(settings());
    let will = node.will(t(0));
    assert_eq!(will.topic, "spBv1.0/Plant/NDEATH/gw1");
    assert_eq!((will.qos, will.retain), (1, false));
    let p = decode(&will);
    assert_eq!(p.seq, None, "NDEATH has no seq");
    assert_eq!(p.metrics.len(), 1);
    let bd = &p.metrics[0];
    assert_eq!(bd.name.as_deref(), Some("bdSeq"));
    assert_eq!(bd.datatype, Some(4), "Int64");
    assert_eq!(bd.value, Some(V::LongValue(0)));

    // A device seen before the session: born with the node.
    assert!(node
        .device(
            &device(0, 1, Some("Feed pressure"), 50.0),
            Quality::Good,
            t(5),
            t(5)
        )
        .is_empty());
    let out = node.connected(t(10));
    assert_eq!(
        out[..2],
        [
            Output::Subscribe {
                topic: "spBv1.0/Plant/NCMD/gw1".into(),
                qos: 1
            },
            Output::Subscribe {
                topic: "spBv1.0/Plant/DCMD/gw1/+".into(),
                qos: 1
            },
        ]
    );
    let msgs = publishes(&out);
    assert_eq!(msgs.len(), 2);
    assert_eq!(msgs[0].topic, "spBv1.0/Plant/NBIRTH/gw1");
    assert_eq!((msgs[0].qos, msgs[0].retain), (0, false));
    let nbirth = decode(msgs[0]);
    assert_eq!(nbirth.seq, Some(0));
    assert_eq!(nbirth.timestamp, Some(millis(t(10))));
    assert_eq!(named(&nbirth, "bdSeq").value, Some(V::LongValue(0)));
    let rebirth = named(&nbirth, "Node Control/Rebirth");
    assert_eq!(
        (rebirth.datatype, &rebirth.value),
        (Some(11), &Some(V::BooleanValue(false)))
    );

    assert_eq!(msgs[1].topic, "spBv1.0/Plant/DBIRTH/gw1/Feed pressure");
    let dbirth = decode(msgs[1]);
    assert_eq!(dbirth.seq, Some(1));
    for m in &dbirth.metrics {
        assert!(
            m.name.is_some() && m.alias.is_some() && m.datatype.is_some(),
            "{m:?}"
        );
        assert!(m.value.is_some() || m.is_null == Some(true), "{m:?}");
    }
    let pv = named(&dbirth, "PV");
    assert_eq!(pv.alias, Some(device_alias(0, 0)));
    assert_eq!(
        (pv.datatype, &pv.value),
        (Some(9), &Some(V::FloatValue(50.0)))
    );
    assert_eq!(pv.timestamp, Some(millis(t(5))));
    let props = pv.properties.as_ref().unwrap();
    assert_eq!(props.keys, ["engUnit", "hartUnitCode"]);
    assert_eq!(named(&dbirth, "SV").is_null, Some(true));
    assert_eq!(
        named(&dbirth, "Status/Quality").value,
        Some(V::StringValue("good".into()))
    );
    assert_eq!(
        named(&dbirth, "Properties/Tag").value,
        Some(V::StringValue("PT-101".into()))
    );
    assert_eq!(
        named(&dbirth, "Properties/UniqueId").value,
        Some(V::StringValue("2601102001".into()))
    );

    // A change: DDATA with the changed metric only, by alias, no name.
    let out = node.device(
        &device(0, 1, Some("Feed pressure"), 51.5),
        Quality::Good,
        t(20),
        t(21),
    );
    let msgs = publishes(&out);
    assert_eq!(msgs.len(), 1);
    assert_eq!(msgs[0].topic, "spBv1.0/Plant/DDATA/gw1/Feed pressure");
    let p = decode(msgs[0]);
    assert_eq!(p.seq, Some(2));
    assert_eq!(p.timestamp, Some(millis(t(21))));
    assert_eq!(p.metrics.len(), 1);
    let m = &p.metrics[0];
    assert_eq!(
        (m.name.as_deref(), m.alias),
        (None, Some(device_alias(0, 0)))
    );
    assert_eq!(
        (m.value.clone(), m.timestamp, m.is_historical),
        (Some(V::FloatValue(51.5)), Some(millis(t(20))), None)
    );

    // Nothing changed: nothing sent.
    assert!(node
        .device(
            &device(0, 1, Some("Feed pressure"), 51.5),
            Quality::Good,
            t(30),
            t(30)
        )
        .is_empty());
}

#[test]
fn death_and_rebirth_of_a_device() {
    let mut node = EdgeNode::new(settings());
    connected(&mut node, t(0));
    let out = node.device(&device(0, 1, None, 1.0), Quality::Good, t(1), t(1));
    assert_eq!(
        publishes(&out)[0].topic,
        "spBv1.0/Plant/DBIRTH/gw1/PT-101",
        "the tag when no long tag"
    );
    let out = node.device(&device(0, 1, None, 1.0), Quality::NoReply, t(2), t(2));
    let msgs = publishes(&out);
    assert_eq!(msgs.len(), 2);
    assert_eq!(msgs[0].topic, "spBv1.0/Plant/DDATA/gw1/PT-101");
    let q = decode(msgs[0]);
    assert_eq!(
        q.metrics
            .iter()
            .find(|m| m.alias == Some(device_alias(0, index_of("Status/Quality").unwrap())))
            .unwrap()
            .value,
        Some(V::StringValue("no reply".into()))
    );
    assert_eq!(msgs[1].topic, "spBv1.0/Plant/DDEATH/gw1/PT-101");
    let d = decode(msgs[1]);
    assert_eq!((d.seq, d.metrics.len()), (Some(3), 0));
    // Still silent: nothing more.
    assert!(node
        .device(&device(0, 1, None, 1.0), Quality::NoReply, t(3), t(3))
        .is_empty());
    // Back: DBIRTH again.
    let out = node.device(&device(0, 1, None, 2.0), Quality::Good, t(4), t(4));
    let msgs = publishes(&out);
    assert_eq!(msgs[0].topic, "spBv1.0/Plant/DBIRTH/gw1/PT-101");
    assert_eq!(decode(msgs[0]).seq, Some(4));
    // A units change is a new birth (units are properties of the birth).
    let mut d = device(0, 1, None, 2.0);
    d.variables[0].as_mut().unwrap().units = 7;
    let out = node.device(&d, Quality::Good, t(5), t(5));
    assert_eq!(publishes(&out)[0].topic, "spBv1.0/Plant/DBIRTH/gw1/PT-101");
}

#[test]
fn seq_wraps_after_255_and_rebirth_restarts_it() {
    let mut node = EdgeNode::new(settings());
    connected(&mut node, t(0));
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0)); // seq 1
    let mut seqs = vec![];
    for i in 1..=300u64 {
        let out = node.device(&device(0, 1, None, i as f32), Quality::Good, t(i), t(i));
        seqs.push(decode(publishes(&out)[0]).seq.unwrap());
    }
    assert_eq!(seqs[0], 2);
    assert_eq!(seqs[253], 255);
    assert_eq!(seqs[254], 0);
    assert!(seqs.windows(2).all(|w| w[1] == (w[0] + 1) % 256));

    let ncmd = Payload {
        timestamp: Some(1),
        metrics: vec![Metric {
            name: Some("Node Control/Rebirth".into()),
            datatype: Some(11),
            value: Some(V::BooleanValue(true)),
            ..Default::default()
        }],
        ..Default::default()
    }
    .encode_to_vec();
    let out = node.received("spBv1.0/Plant/NCMD/gw1", &ncmd, t(400));
    let msgs = publishes(&out);
    assert_eq!(msgs.len(), 2);
    let nbirth = decode(msgs[0]);
    assert_eq!(
        (nbirth.seq, named(&nbirth, "bdSeq").value.clone()),
        (Some(0), Some(V::LongValue(0))),
        "same bdSeq: same connection"
    );
    assert_eq!(decode(msgs[1]).seq, Some(1));

    // Malformed and foreign commands: logged, nothing published.
    for bad in [&[0xFFu8, 0x01][..], &[], b"not protobuf at all"] {
        assert!(node
            .received("spBv1.0/Plant/NCMD/gw1", bad, t(500))
            .is_empty());
    }
    assert!(node.counters().bad_commands >= 2);
}

#[test]
fn samples_while_away_come_back_historical_in_order() {
    let mut node = EdgeNode::new(settings());
    connected(&mut node, t(0));
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    // A DDATA handed to the client that never went out, then the connection drops.
    let out = node.device(&device(0, 1, None, 1.0), Quality::Good, t(1), t(1));
    let unsent = publishes(&out)[0].keep.clone();
    node.disconnected(unsent);
    for i in 2..6u64 {
        assert!(node
            .device(&device(0, 1, None, i as f32), Quality::Good, t(i), t(i))
            .is_empty());
    }
    assert_eq!(node.backlog_len(), 5);
    let will = node.will(t(10));
    assert_eq!(
        decode(&will).metrics[0].value,
        Some(V::LongValue(1)),
        "bdSeq + 1 per CONNECT"
    );
    let out = node.connected(t(10));
    let msgs = publishes(&out);
    assert_eq!(msgs.len(), 2 + 5);
    assert_eq!(
        named(&decode(msgs[0]), "bdSeq").value,
        Some(V::LongValue(1))
    );
    assert_eq!(
        named(&decode(msgs[1]), "PV").value,
        Some(V::FloatValue(5.0)),
        "the birth has the current value"
    );
    let mut values = vec![];
    for (k, m) in msgs[2..].iter().enumerate() {
        assert_eq!(m.topic, "spBv1.0/Plant/DDATA/gw1/PT-101");
        let p = decode(m);
        assert_eq!(p.seq, Some(2 + k as u64));
        let pv = &p.metrics[0];
        assert_eq!(pv.is_historical, Some(true));
        assert_eq!(pv.timestamp, Some(millis(t(1 + k as u64))));
        values.push(pv.value.clone());
    }
    assert_eq!(
        values,
        (1..6)
            .map(|i| Some(V::FloatValue(i as f32)))
            .collect::<Vec<_>>()
    );
    assert_eq!(node.backlog_len(), 0);
    assert_eq!(node.counters().replayed, 5);
}

#[test]
fn backlog_bound_drops_the_oldest() {
    let mut node = EdgeNode::new(Settings {
        backlog: 3,
        ..settings()
    });
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    for i in 1..=5u64 {
        node.device(&device(0, 1, None, i as f32), Quality::Good, t(i), t(i));
    }
    assert_eq!(node.backlog_len(), 3);
    assert_eq!(node.counters().dropped, 2);
    let out = connected(&mut node, t(10));
    let first = decode(publishes(&out)[2]);
    assert_eq!(first.metrics[0].value, Some(V::FloatValue(3.0)));
}

fn state(online: bool, ts: u64) -> Vec<u8> {
    format!("{{\"online\": {online}, \"timestamp\": {ts}}}").into_bytes()
}

#[test]
fn primary_host_state() {
    let mut node = EdgeNode::new(Settings {
        primary_host: Some("scada".into()),
        ..settings()
    });
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    let out = connected(&mut node, t(1));
    assert!(out.contains(&Output::Subscribe {
        topic: "spBv1.0/STATE/scada".into(),
        qos: 1
    }));
    assert!(
        publishes(&out).is_empty(),
        "no birth before the host is online"
    );
    assert!(node
        .received("spBv1.0/STATE/scada", &state(false, 100), t(2))
        .is_empty());
    assert!(node
        .received("spBv1.0/STATE/scada", b"{online", t(2))
        .is_empty());
    assert!(node
        .received("spBv1.0/STATE/other", &state(true, 200), t(2))
        .is_empty());
    let out = node.received("spBv1.0/STATE/scada", &state(true, 200), t(3));
    assert_eq!(publishes(&out)[0].topic, "spBv1.0/Plant/NBIRTH/gw1");
    assert!(node.is_live());
    // An older STATE (a late retained one) changes nothing.
    assert!(node
        .received("spBv1.0/STATE/scada", &state(false, 150), t(4))
        .is_empty());
    let out = node.received("spBv1.0/STATE/scada", &state(false, 300), t(5));
    assert_eq!(out.len(), 2);
    let ndeath = publishes(&out)[0];
    assert_eq!(ndeath.topic, "spBv1.0/Plant/NDEATH/gw1");
    assert_eq!(decode(ndeath).metrics[0].value, Some(V::LongValue(0)));
    assert_eq!(out[1], Output::Disconnect);
    assert!(!node.is_live());
    // Samples while the host is away are kept.
    node.device(&device(0, 1, None, 7.0), Quality::Good, t(6), t(6));
    assert_eq!(node.backlog_len(), 1);
}

fn dcmd(metrics: Vec<Metric>) -> Vec<u8> {
    Payload {
        timestamp: Some(1),
        metrics,
        ..Default::default()
    }
    .encode_to_vec()
}

fn float(name: &str, x: f32) -> Metric {
    Metric {
        name: Some(name.into()),
        datatype: Some(9),
        value: Some(V::FloatValue(x)),
        ..Default::default()
    }
}

#[test]
fn dcmd_writes_follow_the_rules() {
    let mut node = EdgeNode::new(settings());
    connected(&mut node, t(0));
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    let topic = "spBv1.0/Plant/DCMD/gw1/PT-101";
    let out = node.received(topic, &dcmd(vec![float("Config/Damping", 2.5)]), t(1));
    let Output::Write(w) = &out[0] else {
        panic!("{out:?}")
    };
    assert_eq!(
        (w.position, w.ops.clone()),
        (0, vec![WriteOp::Damping(2.5)])
    );
    assert_eq!(w.via, "DCMD Config/Damping");
    // The range's two values make one command 35; by alias works too.
    let mut lower = float("", 0.0);
    lower.name = None;
    lower.alias = Some(device_alias(0, index_of("Config/LowerRange").unwrap()));
    let out = node.received(
        topic,
        &dcmd(vec![float("Config/UpperRange", 200.0), lower]),
        t(1),
    );
    let Output::Write(w) = &out[0] else {
        panic!("{out:?}")
    };
    assert_eq!(
        w.ops,
        vec![WriteOp::Range {
            upper: Some(200.0),
            lower: Some(0.0),
            units: None
        }]
    );
    // Refused: not writable, wrong type, unknown device, not a payload, NaN.
    for (topic, payload) in [
        (topic, dcmd(vec![float("PV", 1.0)])),
        (topic, dcmd(vec![float("Properties/Tag", 1.0)])),
        (topic, dcmd(vec![float("Config/Damping", f32::NAN)])),
        (
            "spBv1.0/Plant/DCMD/gw1/nobody",
            dcmd(vec![float("Config/Damping", 1.0)]),
        ),
        (topic, vec![0x0A, 0xFF]),
    ] {
        assert!(
            node.received(topic, &payload, t(2)).is_empty(),
            "{payload:02X?}"
        );
    }
    // Read-only, and the allow-list without command 34.
    let mut ro = EdgeNode::new(Settings {
        read_only: true,
        ..settings()
    });
    connected(&mut ro, t(0));
    ro.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    assert!(ro
        .received(topic, &dcmd(vec![float("Config/Damping", 2.5)]), t(1))
        .is_empty());
    let mut allow = EdgeNode::new(Settings {
        gateway: hart_access::WritePolicy {
            allow: Some("0-33,35-200".parse().unwrap()),
            ..Default::default()
        },
        ..settings()
    });
    connected(&mut allow, t(0));
    allow.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    assert!(allow
        .received(topic, &dcmd(vec![float("Config/Damping", 2.5)]), t(1))
        .is_empty());
    assert_eq!(
        allow
            .received(topic, &dcmd(vec![float("Config/UpperRange", 2.5)]), t(1))
            .len(),
        1
    );
}

#[test]
fn device_ids_are_valid_unique_and_stable() {
    let mut node = EdgeNode::new(settings());
    connected(&mut node, t(0));
    node.device(
        &device(0, 1, Some("Reactor feed"), 0.0),
        Quality::Good,
        t(0),
        t(0),
    );
    node.device(
        &device(1, 2, Some("reactor FEED"), 0.0),
        Quality::Good,
        t(0),
        t(0),
    );
    node.device(&device(2, 3, Some("a/b"), 0.0), Quality::Good, t(0), t(0));
    let mut d = device(3, 4, None, 0.0);
    d.info.as_mut().unwrap().tag = Some("  ".into());
    node.device(&d, Quality::Good, t(0), t(0));
    assert_eq!(node.device_id(0), Some("Reactor feed"));
    assert_eq!(
        node.device_id(1),
        Some("reactor FEED-2601102002"),
        "same in lower case: suffixed"
    );
    assert_eq!(
        node.device_id(2),
        Some("PT-101"),
        "'/' is not allowed: the tag"
    );
    assert_eq!(
        node.device_id(3),
        Some("2601102004"),
        "no usable tag: the unique ID"
    );
    // A new long tag later does not move the device.
    node.device(
        &device(0, 1, Some("Renamed"), 0.0),
        Quality::Good,
        t(1),
        t(1),
    );
    assert_eq!(node.device_id(0), Some("Reactor feed"));
    // Not identified: not published.
    let mut anon = DeviceImage::new(4, 0, "loop1", Duration::from_secs(10));
    anon.polls = 1;
    anon.position = 4;
    assert!(node
        .device(&anon, Quality::WaitingForData, t(2), t(2))
        .is_empty());
    assert_eq!(node.device_id(4), None);
}

/// With a historian beside it, a full backlog keeps the oldest samples in memory and
/// leaves the rest of the outage to the historian: after the births and the samples
/// memory held, the edge node asks for that time range back, and what the historian
/// gives is sent historical, in time order.
#[test]
fn a_full_backlog_spills_to_the_historian_and_is_read_back() {
    let mut node = EdgeNode::new(Settings {
        backlog: 3,
        ..settings()
    })
    .with_spill(true);
    connected(&mut node, t(0));
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    node.disconnected(vec![]);
    for i in 1..=10u64 {
        node.device(&device(0, 1, None, i as f32), Quality::Good, t(i), t(i));
    }
    assert_eq!(node.backlog_len(), 3, "memory holds its bound");
    assert_eq!(
        node.counters().dropped,
        0,
        "nothing dropped: the historian has it"
    );
    node.will(t(20));
    let out = node.connected(t(20));
    let msgs = publishes(&out);
    // NBIRTH, DBIRTH, the three samples memory held (values 1, 2, 3).
    assert_eq!(msgs.len(), 2 + 3);
    let backfill = out
        .iter()
        .find_map(|o| match o {
            Output::Backfill { from, to } => Some((*from, *to)),
            _ => None,
        })
        .expect("the rest is asked back");
    assert_eq!(backfill, (millis(t(4)), millis(t(10)) + 1));
    // What the historian gives (out of order here) goes out historical, in time order.
    let pv = |i: u64| Sample {
        position: 0,
        at: millis(t(i)),
        metrics: vec![(0, hart_sparkplug_edge::metrics::Value::Float(i as f32))],
    };
    let out = node.backfilled(vec![pv(9), pv(4), pv(10), pv(5)], t(21));
    let msgs = publishes(&out);
    let got: Vec<(Option<u64>, Option<bool>)> = msgs
        .iter()
        .map(|m| {
            let p = decode(m);
            (p.metrics[0].timestamp, p.metrics[0].is_historical)
        })
        .collect();
    assert_eq!(got, [4, 5, 9, 10].map(|i| (Some(millis(t(i))), Some(true))));
    // Without a historian the oldest are dropped, counted.
    let mut plain = EdgeNode::new(Settings {
        backlog: 3,
        ..settings()
    });
    connected(&mut plain, t(0));
    plain.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    plain.disconnected(vec![]);
    for i in 1..=10u64 {
        plain.device(&device(0, 1, None, i as f32), Quality::Good, t(i), t(i));
    }
    assert_eq!(plain.counters().dropped, 7);
}

/// A device that dies during an outage whose data went to the historian: after the
/// births, its data up to its death is read back and sent historical while it is still
/// born, and only then its DDEATH; a tick's feed meanwhile does not kill it early.
#[test]
fn a_device_dead_during_the_outage_gets_its_data_before_its_death() {
    let mut node = EdgeNode::new(Settings {
        backlog: 2,
        ..settings()
    })
    .with_spill(true);
    connected(&mut node, t(0));
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    node.device(&device(1, 2, None, 0.0), Quality::Good, t(0), t(0));
    node.disconnected(vec![]);
    for i in 1..=10u64 {
        node.device(&device(0, 1, None, i as f32), Quality::Good, t(i), t(i));
        if i <= 5 {
            node.device(&device(1, 2, None, i as f32), Quality::Good, t(i), t(i));
        }
    }
    // Device 1 stops answering at 6.
    node.device(&device(1, 2, None, 5.0), Quality::NoReply, t(6), t(6));
    node.will(t(20));
    let out = node.connected(t(20));
    let topics: Vec<&str> = publishes(&out).iter().map(|m| m.topic.as_str()).collect();
    assert!(
        !topics.iter().any(|t| t.contains("DDEATH")),
        "no death before the read-back: {topics:?}"
    );
    assert!(out.iter().any(|o| matches!(o, Output::Backfill { .. })));
    assert!(node.is_backfilling());
    // The gateway's tick feeds the dead device again: still no death.
    let out = node.device(&device(1, 2, None, 5.0), Quality::NoReply, t(6), t(21));
    assert!(publishes(&out).is_empty(), "{out:?}");
    // Its samples from the historian go out historical, under its birth.
    let sample = |position: usize, i: u64| Sample {
        position,
        at: millis(t(i)),
        metrics: vec![(0, hart_sparkplug_edge::metrics::Value::Float(i as f32))],
    };
    let out = node.backfilled(vec![sample(1, 3), sample(1, 4), sample(1, 5)], t(22));
    let msgs = publishes(&out);
    assert_eq!(msgs.len(), 3);
    assert!(msgs.iter().all(|m| m.topic.contains("/DDATA/")));
    assert!(msgs
        .iter()
        .all(|m| decode(m).metrics[0].is_historical == Some(true)));
    // The end of the read-back: now its death.
    let out = node.backfill_done(t(23));
    let msgs = publishes(&out);
    assert_eq!(msgs.len(), 1, "{msgs:?}");
    assert!(msgs[0].topic.contains("/DDEATH/"), "{}", msgs[0].topic);
    assert!(!node.is_backfilling());
    assert_eq!(node.counters().dropped, 0);
}

/// With a historian, samples given back on a disconnect (sent, never acknowledged)
/// over a full backlog join the range left to the historian instead of being dropped;
/// a read-back the session did not finish is asked again after the next births.
#[test]
fn nothing_the_historian_holds_is_dropped_and_an_unfinished_read_back_is_asked_again() {
    let mut node = EdgeNode::new(Settings {
        backlog: 3,
        ..settings()
    })
    .with_spill(true);
    connected(&mut node, t(0));
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    let unsent: Vec<Sample> = (1..=6u64)
        .map(|i| Sample {
            position: 0,
            at: millis(t(i)),
            metrics: vec![(0, hart_sparkplug_edge::metrics::Value::Float(i as f32))],
        })
        .collect();
    node.disconnected(unsent);
    assert_eq!(node.counters().dropped, 0);
    assert_eq!(node.backlog_len(), 3);
    node.will(t(10));
    let out = node.connected(t(10));
    let range = out
        .iter()
        .find_map(|o| match o {
            Output::Backfill { from, to } => Some((*from, *to)),
            _ => None,
        })
        .expect("the rest is asked back");
    assert_eq!(range, (millis(t(4)), millis(t(6)) + 1));
    // The session ends with the read-back half done: the rest is asked again.
    node.backfill_unfinished(millis(t(5)), range.1);
    node.disconnected(vec![]);
    node.will(t(30));
    let out = node.connected(t(30));
    let again = out.iter().find_map(|o| match o {
        Output::Backfill { from, to } => Some((*from, *to)),
        _ => None,
    });
    assert_eq!(again, Some((millis(t(5)), millis(t(6)) + 1)));
}

fn writes(out: &[Output]) -> usize {
    out.iter().filter(|o| matches!(o, Output::Write(_))).count()
}

/// Commands the broker delivers retained are refused (they are not sent now, and
/// would run again at every connection), as are commands longer than a command can
/// be and commands beyond the rate; values out of range never become a write.
#[test]
fn retained_oversized_flooded_and_out_of_range_commands_are_refused() {
    use hart_sparkplug_edge::edge::{
        Delivery, COMMANDS_PER_SECOND, COMMAND_BURST, MAX_COMMAND_BYTES,
    };
    let mut node = EdgeNode::new(settings());
    connected(&mut node, t(0));
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    let topic = "spBv1.0/Plant/DCMD/gw1/PT-101";
    let damping = dcmd(vec![float("Config/Damping", 3.25)]);
    let retained = Delivery { retained: true };
    assert!(node.delivered(topic, &damping, retained, t(1)).is_empty());
    assert_eq!(node.counters().retained_commands, 1);
    let rebirth = dcmd(vec![Metric {
        name: Some("Node Control/Rebirth".into()),
        datatype: Some(11),
        value: Some(V::BooleanValue(true)),
        ..Default::default()
    }]);
    assert!(node
        .delivered("spBv1.0/Plant/NCMD/gw1", &rebirth, retained, t(1))
        .is_empty());
    assert_eq!(node.counters().retained_commands, 2);
    // Too long: refused undecoded.
    let mut long = damping.clone();
    long.resize(MAX_COMMAND_BYTES + 1, 0);
    assert!(node.received(topic, &long, t(2)).is_empty());
    // Out of range: a fixed current of -1 mA (2^64-1 read as a signed integer), a
    // negative damping.
    for bad in [
        Metric {
            name: Some("Config/FixedCurrent".into()),
            datatype: Some(4),
            value: Some(V::LongValue(u64::MAX)),
            ..Default::default()
        },
        float("Config/Damping", -1.0),
    ] {
        assert_eq!(writes(&node.received(topic, &dcmd(vec![bad]), t(3))), 0);
    }
    // The rate: a burst, then COMMANDS_PER_SECOND a second.
    let mut node = EdgeNode::new(settings());
    connected(&mut node, t(0));
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    let taken = (0..100)
        .map(|_| writes(&node.received(topic, &damping, t(10))))
        .sum::<usize>();
    assert_eq!(taken, COMMAND_BURST as usize);
    assert_eq!(
        node.counters().throttled_commands,
        100 - u64::from(COMMAND_BURST)
    );
    let taken = (0..100)
        .map(|_| writes(&node.received(topic, &damping, t(1010))))
        .sum::<usize>();
    assert_eq!(taken, COMMANDS_PER_SECOND as usize, "one second later");
}

/// Rebirth requests: the first is answered at once; more within the interval are
/// answered by one rebirth when it ends ([`EdgeNode::tick`]).
#[test]
fn a_flood_of_rebirth_requests_costs_two_rebirths() {
    use hart_sparkplug_edge::edge::REBIRTH_INTERVAL_MS;
    let mut node = EdgeNode::new(settings());
    connected(&mut node, t(0));
    node.device(&device(0, 1, None, 0.0), Quality::Good, t(0), t(0));
    let rebirth = dcmd(vec![Metric {
        name: Some("Node Control/Rebirth".into()),
        datatype: Some(11),
        value: Some(V::BooleanValue(true)),
        ..Default::default()
    }]);
    let nbirths = |out: &[Output]| {
        publishes(out)
            .iter()
            .filter(|m| m.topic.contains("/NBIRTH/"))
            .count()
    };
    let mut births = 0;
    for i in 0..300u64 {
        // Spread over 3 s: within the rate, all within the interval.
        births += nbirths(&node.received("spBv1.0/Plant/NCMD/gw1", &rebirth, t(100 + i * 10)));
        births += nbirths(&node.tick(t(100 + i * 10)));
    }
    assert_eq!(births, 1, "one at once");
    assert!(node.counters().coalesced_rebirths > 0);
    assert_eq!(nbirths(&node.tick(t(100 + REBIRTH_INTERVAL_MS - 1))), 0);
    assert_eq!(
        nbirths(&node.tick(t(100 + REBIRTH_INTERVAL_MS))),
        1,
        "one when the interval ends"
    );
    assert_eq!(
        nbirths(&node.tick(t(100 + 3 * REBIRTH_INTERVAL_MS))),
        0,
        "and no more"
    );
    // The wall clock stepped back an hour: a request is answered at once, not an hour
    // later.
    let back = t(100 + 3 * REBIRTH_INTERVAL_MS) - Duration::from_secs(3600);
    assert_eq!(
        nbirths(&node.received("spBv1.0/Plant/NCMD/gw1", &rebirth, back)),
        1
    );
}
