//! The Sparkplug B edge node fed untrusted command bytes: each input is decoded as an
//! NCMD/DCMD payload, then given to a live edge node (one identified device) as an
//! NCMD, a DCMD for its device and a STATE of its primary host. Nothing may panic,
//! and the node must still answer a good rebirth request with NBIRTH (seq 0) and the
//! device's DBIRTH afterwards.
#![no_main]

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use hart_poller::{DeviceImage, Quality, Variable};
use hart_proto::wire::{Reader, Wire};
use hart_sparkplug_edge::edge::{EdgeNode, Output, Settings};
use hart_sparkplug_edge::proto::payload::{metric::Value, Metric};
use hart_sparkplug_edge::proto::Payload;
use libfuzzer_sys::fuzz_target;
use prost::Message as _;

fn node() -> EdgeNode {
    let mut node = EdgeNode::new(Settings {
        group: "G".into(),
        edge_node: "E".into(),
        primary_host: Some("H".into()),
        backlog: 16,
        read_only: false,
        gateway: Default::default(),
    });
    let now = UNIX_EPOCH + Duration::from_secs(1_700_000_000);
    let bytes = [254, 0x26, 0x01, 5, 5, 1, 1, 0x08, 0, 0x10, 0x20, 0x30];
    let identity = hart_proto::command::Identity::decode(&mut Reader::new(&bytes)).unwrap();
    let mut d = DeviceImage::new(0, 0, "loop1", Duration::from_secs(10));
    d.info = Some(hart_host::DeviceInfo::identified(identity, Some(0)));
    d.info.as_mut().unwrap().tag = Some("PT-101".into());
    d.variables[0] = Some(Variable {
        value: 1.0,
        units: 12,
        status: None,
    });
    // Polled once: a device is born after its first poll.
    d.polls = 1;
    node.device(&d, Quality::Good, now, now);
    node.will(now);
    node.connected(now);
    node.received("spBv1.0/STATE/H", br#"{"online": true, "timestamp": 1}"#, now);
    assert!(node.is_live());
    node
}

fuzz_target!(|data: &[u8]| {
    let _ = hart_sparkplug_edge::command::decode(data);
    let mut node = node();
    let now = SystemTime::now();
    let _ = node.received("spBv1.0/G/NCMD/E", data, now);
    let _ = node.received("spBv1.0/G/DCMD/E/PT-101", data, now);
    let _ = node.received("spBv1.0/STATE/H", data, now);
    if !node.is_live() {
        // A STATE "offline" newer than the last: the node left; that is allowed.
        return;
    }
    let rebirth = Payload {
        timestamp: Some(1),
        metrics: vec![Metric {
            name: Some("Node Control/Rebirth".into()),
            datatype: Some(11),
            value: Some(Value::BooleanValue(true)),
            ..Default::default()
        }],
        ..Default::default()
    }
    .encode_to_vec();
    let out = node.received("spBv1.0/G/NCMD/E", &rebirth, now);
    let topics: Vec<&str> = out
        .iter()
        .filter_map(|o| match o {
            Output::Publish(m) => Some(m.topic.as_str()),
            _ => None,
        })
        .collect();
    assert_eq!(topics, ["spBv1.0/G/NBIRTH/E", "spBv1.0/G/DBIRTH/E/PT-101"]);
});
