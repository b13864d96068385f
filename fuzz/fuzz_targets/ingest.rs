//! The ingest's Sparkplug B decoder fed untrusted messages: the first byte picks the
//! topic (every message type, node and device level, known and unknown devices), the
//! rest is the payload, given to a decoder that has seen a node's and a device's
//! births. Nothing may panic, and afterwards a good DBIRTH and DDATA still give their
//! samples.
#![no_main]

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use hart_ingest::Decoder;
use hart_sparkplug::proto::payload::{metric::Value, Metric};
use hart_sparkplug::proto::Payload;
use libfuzzer_sys::fuzz_target;
use prost::Message as _;

const TOPICS: [&str; 10] = [
    "spBv1.0/G/NBIRTH/E",
    "spBv1.0/G/NDEATH/E",
    "spBv1.0/G/NDATA/E",
    "spBv1.0/G/DBIRTH/E/D",
    "spBv1.0/G/DDATA/E/D",
    "spBv1.0/G/DDEATH/E/D",
    "spBv1.0/G/DDATA/E/X",
    "spBv1.0/G/DDATA/F/D",
    "spBv1.0/STATE/H",
    "spBv1.0/G/NCMD/E",
];

fn birth() -> Vec<u8> {
    let m = |name: &str, alias: u64, value: Value| Metric {
        name: Some(name.into()),
        alias: Some(alias),
        timestamp: Some(1_700_000_000_000),
        datatype: Some(if matches!(value, Value::StringValue(_)) { 12 } else { 9 }),
        value: Some(value),
        ..Default::default()
    };
    Payload {
        timestamp: Some(1_700_000_000_000),
        seq: Some(1),
        metrics: vec![
            m("PV", 256, Value::FloatValue(1.0)),
            m("Properties/UniqueId", 273, Value::StringValue("26F1000001".into())),
        ],
        ..Default::default()
    }
    .encode_to_vec()
}

fuzz_target!(|data: &[u8]| {
    let now = UNIX_EPOCH + Duration::from_secs(1_700_000_000);
    let mut d = Decoder::new("G");
    let nbirth = Payload {
        seq: Some(0),
        ..Default::default()
    }
    .encode_to_vec();
    let _ = d.received(TOPICS[0], &nbirth, now);
    let _ = d.received(TOPICS[3], &birth(), now);
    let Some((&pick, payload)) = data.split_first() else {
        return;
    };
    let topic = TOPICS[usize::from(pick) % TOPICS.len()];
    let _ = d.received(topic, payload, now);
    let _ = d.received(topic, payload, SystemTime::now());
    // Whatever came before, a new birth and data are taken in again.
    let _ = d.received(TOPICS[0], &nbirth, now);
    let out = d.received(TOPICS[3], &birth(), now).expect("a good DBIRTH");
    assert_eq!(out.samples.len(), 1);
    let data = Payload {
        seq: Some(2),
        metrics: vec![Metric {
            alias: Some(256),
            timestamp: Some(1_700_000_000_500),
            value: Some(Value::FloatValue(2.0)),
            ..Default::default()
        }],
        ..Default::default()
    }
    .encode_to_vec();
    let out = d.received(TOPICS[4], &data, now).expect("a good DDATA");
    assert_eq!(out.samples.len(), 1);
    assert_eq!(out.samples[0].value, 2.0);
});
