//! The ingest's decoder, byte-scripted: payloads built with the Sparkplug proto types,
//! fed with the time.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use hart_history::{Sample, Var};
use hart_ingest::{Decoder, Rejected};
use hart_sparkplug::metrics::{self, device_alias};
use hart_sparkplug::proto::datatype as dt;
use hart_sparkplug::proto::payload::{metric, property_value, Metric, PropertySet, PropertyValue};
use hart_sparkplug::proto::Payload;
use proptest::prelude::*;
use prost::Message as _;

const T0: u64 = 1_800_000_000_000;

fn at(ms: u64) -> SystemTime {
    UNIX_EPOCH + Duration::from_millis(ms)
}

fn named(name: &str, alias: u64, datatype: u32, value: Option<metric::Value>, ts: u64) -> Metric {
    Metric {
        name: Some(name.into()),
        alias: Some(alias),
        timestamp: Some(ts),
        datatype: Some(datatype),
        is_null: value.is_none().then_some(true),
        value,
        ..Default::default()
    }
}

fn units(code: u32) -> Option<PropertySet> {
    Some(PropertySet {
        keys: vec!["hartUnitCode".into()],
        values: vec![PropertyValue {
            r#type: Some(dt::UINT8),
            is_null: None,
            value: Some(property_value::Value::IntValue(code)),
        }],
    })
}

fn nbirth(seq: u64, bd_seq: u64) -> Vec<u8> {
    Payload {
        timestamp: Some(T0),
        seq: Some(seq),
        metrics: vec![
            named(
                metrics::NODE_BDSEQ,
                metrics::BDSEQ_ALIAS,
                dt::INT64,
                Some(metric::Value::LongValue(bd_seq)),
                T0,
            ),
            named(
                metrics::NODE_REBIRTH,
                metrics::REBIRTH_ALIAS,
                dt::BOOLEAN,
                Some(metric::Value::BooleanValue(false)),
                T0,
            ),
        ],
        ..Default::default()
    }
    .encode_to_vec()
}

/// A DBIRTH of the device at position 0 as hart-sparkplug publishes it (a subset of
/// the metrics): PV 1.5 bar (code 7), loop current, status, quality, identity.
fn dbirth(seq: u64, ts: u64) -> Vec<u8> {
    let a = |i| device_alias(0, i);
    let s = |v: &str| Some(metric::Value::StringValue(v.into()));
    let mut pv = named(
        "PV",
        a(0),
        dt::FLOAT,
        Some(metric::Value::FloatValue(1.5)),
        ts,
    );
    pv.properties = units(7);
    Payload {
        timestamp: Some(ts),
        seq: Some(seq),
        metrics: vec![
            pv,
            named("SV", a(1), dt::FLOAT, None, ts),
            named(
                "LoopCurrent",
                a(4),
                dt::FLOAT,
                Some(metric::Value::FloatValue(12.0)),
                ts,
            ),
            named(
                "Status/DeviceStatus",
                a(6),
                dt::UINT8,
                Some(metric::Value::IntValue(0)),
                ts,
            ),
            named(
                "Status/QualityCode",
                a(9),
                dt::UINT16,
                Some(metric::Value::IntValue(0)),
                ts,
            ),
            named(
                "Config/Damping",
                a(12),
                dt::FLOAT,
                Some(metric::Value::FloatValue(0.5)),
                ts,
            ),
            named("Properties/Tag", a(14), dt::STRING, s("PT-1"), ts),
            named(
                "Properties/LongTag",
                a(15),
                dt::STRING,
                s("Pressure one"),
                ts,
            ),
            named(
                "Properties/UniqueId",
                a(17),
                dt::STRING,
                s("26F1000001"),
                ts,
            ),
            named("Properties/Loop", a(18), dt::STRING, s("loop1"), ts),
        ],
        ..Default::default()
    }
    .encode_to_vec()
}

fn ddata(seq: u64, metrics: Vec<(usize, metric::Value, u64, bool)>) -> Vec<u8> {
    Payload {
        timestamp: Some(T0 + 10_000),
        seq: Some(seq),
        metrics: metrics
            .into_iter()
            .map(|(i, v, ts, historical)| Metric {
                alias: Some(device_alias(0, i)),
                timestamp: Some(ts),
                is_historical: historical.then_some(true),
                value: Some(v),
                ..Default::default()
            })
            .collect(),
        ..Default::default()
    }
    .encode_to_vec()
}

const NB: &str = "spBv1.0/Plant/NBIRTH/gwA";
const DB: &str = "spBv1.0/Plant/DBIRTH/gwA/PT-1";
const DD: &str = "spBv1.0/Plant/DDATA/gwA/PT-1";

fn born() -> Decoder {
    let mut d = Decoder::new("Plant");
    assert!(d
        .received(NB, &nbirth(0, 3), at(T0))
        .unwrap()
        .samples
        .is_empty());
    d.received(DB, &dbirth(1, T0), at(T0)).unwrap();
    d
}

fn find(s: &[Sample], var: Var) -> &Sample {
    s.iter().find(|s| s.var == var).unwrap()
}

#[test]
fn births_give_identity_units_and_values() {
    let mut d = Decoder::new("Plant");
    assert_eq!(d.filter(), "spBv1.0/Plant/#");
    d.received(NB, &nbirth(0, 3), at(T0)).unwrap();
    let out = d.received(DB, &dbirth(1, T0), at(T0)).unwrap();
    assert!(out.publish.is_empty());
    // PV, loop current, device status; SV is null, damping is not a variable.
    assert_eq!(out.samples.len(), 3, "{:?}", out.samples);
    let pv = find(&out.samples, Var::Pv);
    assert_eq!(pv.device.unique_id, "26F1000001");
    assert_eq!(pv.device.tag, "Pressure one");
    assert_eq!(pv.device.loop_name, "loop1");
    assert_eq!(
        (pv.value, pv.units, pv.quality, pv.time),
        (1.5, Some(7), 0, at(T0))
    );
    assert_eq!(find(&out.samples, Var::LoopCurrent).units, Some(39));
    assert_eq!(find(&out.samples, Var::DeviceStatus).units, None);
    assert_eq!(d.counters().births, 2);
}

#[test]
fn data_by_alias_with_their_own_times_and_historical() {
    let mut d = born();
    // 80.545975 as a single: stored as its shortest decimal, as the gateway does.
    let out = d
        .received(
            DD,
            &ddata(
                2,
                vec![
                    (0, metric::Value::FloatValue(80.545_975), T0 + 1000, true),
                    (9, metric::Value::IntValue(1), T0 + 2000, false),
                    (4, metric::Value::FloatValue(13.0), T0 + 2000, false),
                ],
            ),
            at(T0 + 10_000),
        )
        .unwrap();
    assert_eq!(out.samples.len(), 2);
    let pv = find(&out.samples, Var::Pv);
    assert_eq!(
        (pv.value, pv.units, pv.time),
        (80.545975, Some(7), at(T0 + 1000))
    );
    // The quality code in the same message applies to its values.
    assert_eq!(pv.quality, 1);
    assert_eq!(find(&out.samples, Var::LoopCurrent).time, at(T0 + 2000));
    assert_eq!(d.counters().seq_gaps, 0);
}

#[test]
fn ddata_before_dbirth_asks_for_a_rebirth_at_most_every_5_s() {
    let mut d = Decoder::new("Plant");
    let data = ddata(7, vec![(0, metric::Value::FloatValue(2.0), T0, false)]);
    let out = d.received(DD, &data, at(T0)).unwrap();
    assert!(out.samples.is_empty());
    assert_eq!(out.publish.len(), 1);
    assert_eq!(out.publish[0].topic, "spBv1.0/Plant/NCMD/gwA");
    let cmd = Payload::decode(out.publish[0].payload.as_slice()).unwrap();
    assert_eq!(cmd.metrics[0].name.as_deref(), Some("Node Control/Rebirth"));
    assert_eq!(cmd.metrics[0].datatype, Some(dt::BOOLEAN));
    assert_eq!(
        cmd.metrics[0].value,
        Some(metric::Value::BooleanValue(true))
    );
    // Again within 5 s: counted, not asked again; after: asked again.
    assert!(d
        .received(DD, &data, at(T0 + 1000))
        .unwrap()
        .publish
        .is_empty());
    assert_eq!(
        d.received(DD, &data, at(T0 + 6000)).unwrap().publish.len(),
        1
    );
    assert_eq!(d.counters().before_birth, 3);
    assert_eq!(d.counters().rebirths, 2);
    // A node born, but a device's DDATA without its DBIRTH: the same.
    d.received(NB, &nbirth(0, 1), at(T0 + 7000)).unwrap();
    let out = d
        .received(
            "spBv1.0/Plant/DDATA/gwA/other",
            &ddata(1, vec![]),
            at(T0 + 20_000),
        )
        .unwrap();
    assert_eq!(out.publish.len(), 1);
}

#[test]
fn seq_gaps_are_counted_and_data_still_stored() {
    let mut d = born();
    let m = |v| vec![(0, metric::Value::FloatValue(v), T0 + 5, false)];
    assert_eq!(
        d.received(DD, &ddata(5, m(2.0)), at(T0))
            .unwrap()
            .samples
            .len(),
        1
    );
    assert_eq!(d.counters().seq_gaps, 1);
    d.received(DD, &ddata(6, m(3.0)), at(T0)).unwrap();
    assert_eq!(d.counters().seq_gaps, 1);
    // A message sent again (QoS 1): a gap too, stored (the key keeps it once).
    d.received(DD, &ddata(6, m(3.0)), at(T0)).unwrap();
    assert_eq!(d.counters().seq_gaps, 2);
}

#[test]
fn deaths_end_births_but_a_stale_will_does_not() {
    let mut d = born();
    let death = |bd: u64| {
        Payload {
            timestamp: Some(T0),
            metrics: vec![Metric {
                name: Some("bdSeq".into()),
                datatype: Some(dt::INT64),
                value: Some(metric::Value::LongValue(bd)),
                ..Default::default()
            }],
            ..Default::default()
        }
        .encode_to_vec()
    };
    let one = ddata(2, vec![(0, metric::Value::FloatValue(2.0), T0, false)]);
    d.received("spBv1.0/Plant/NDEATH/gwA", &death(2), at(T0))
        .unwrap();
    assert_eq!(d.received(DD, &one, at(T0)).unwrap().samples.len(), 1);
    d.received("spBv1.0/Plant/NDEATH/gwA", &death(3), at(T0))
        .unwrap();
    assert!(d.received(DD, &one, at(T0)).unwrap().samples.is_empty());
    let mut d = born();
    d.received(
        "spBv1.0/Plant/DDEATH/gwA/PT-1",
        &Payload::default().encode_to_vec(),
        at(T0),
    )
    .unwrap();
    assert!(d.received(DD, &one, at(T0)).unwrap().samples.is_empty());
}

#[test]
fn unknown_aliases_and_foreign_devices() {
    let mut d = born();
    let out = d
        .received(
            DD,
            &ddata(2, vec![(200, metric::Value::FloatValue(1.0), T0, false)]),
            at(T0),
        )
        .unwrap();
    assert!(out.samples.is_empty());
    assert_eq!(d.counters().unknown_alias, 1);
    // A device of another edge node software, without the identity metrics.
    let p = Payload {
        seq: Some(2),
        metrics: vec![named(
            "PV",
            1,
            dt::DOUBLE,
            Some(metric::Value::DoubleValue(4.25)),
            T0,
        )],
        ..Default::default()
    };
    let out = d
        .received("spBv1.0/Plant/DBIRTH/gwA/Other", &p.encode_to_vec(), at(T0))
        .unwrap();
    assert_eq!(out.samples[0].device.unique_id, "gwA/Other");
    assert_eq!(out.samples[0].device.tag, "Other");
    assert_eq!(out.samples[0].value, 4.25);
}

#[test]
fn malformed_topics_and_payloads_are_typed_errors() {
    let mut d = born();
    for t in [
        "spBv1.0/Other/DDATA/gwA/PT-1",
        "spBv1.0/Plant/XDATA/gwA",
        "spBv1.0/Plant/DDATA/gwA",
        "spBv1.0/Plant/NBIRTH/gwA/dev",
        "spBv1.0/Plant/DDATA//x",
        "other/thing",
    ] {
        assert!(
            matches!(d.received(t, &[], at(T0)), Err(Rejected::Topic(_))),
            "{t}"
        );
    }
    let e = d.received(DD, &[0xff, 0xff, 0xff], at(T0)).unwrap_err();
    assert!(matches!(e, Rejected::Payload(_)));
    assert!(e.to_string().contains("Sparkplug B"), "{e}");
    let big_seq = Payload {
        seq: Some(256),
        ..Default::default()
    };
    assert!(d.received(DD, &big_seq.encode_to_vec(), at(T0)).is_err());
    // STATE and commands are not data.
    assert!(d.received("spBv1.0/STATE/scada", b"{}", at(T0)).is_ok());
    assert!(d
        .received("spBv1.0/Plant/NCMD/gwA", &[], at(T0))
        .unwrap()
        .samples
        .is_empty());
    assert_eq!(d.counters().rejected, 8);
}

proptest! {
    #[test]
    fn random_bytes_never_panic(topic in "spBv1\\.0/Plant/(NBIRTH|DBIRTH|DDATA|NDEATH|DDEATH|NDATA)/gwA(/d[0-9])?", payload in proptest::collection::vec(any::<u8>(), 0..200)) {
        let mut d = born();
        let _ = d.received(&topic, &payload, at(T0));
    }

    #[test]
    fn random_metrics_never_panic(seq in 0u64..300, alias in 0u64..2000, dtype in 0u32..25, ts in any::<u64>(), v in any::<u32>(), null in any::<bool>()) {
        let mut d = born();
        let p = Payload {
            seq: Some(seq),
            timestamp: Some(ts),
            metrics: vec![Metric {
                alias: Some(alias),
                datatype: Some(dtype),
                timestamp: Some(ts),
                is_null: Some(null),
                value: Some(metric::Value::IntValue(v)),
                ..Default::default()
            }],
            ..Default::default()
        };
        let _ = d.received(DD, &p.encode_to_vec(), at(T0));
        let _ = d.received(DB, &p.encode_to_vec(), at(T0));
    }
}

/// Births are handed out to be kept; a new decoder that takes them in (a restarted
/// ingest) reads the data the broker kept meanwhile, without asking for a rebirth and
/// without counting the births again.
#[test]
fn kept_births_read_the_data_after_a_restart() {
    let mut first = Decoder::new("Plant");
    let nb = first.received(NB, &nbirth(0, 3), at(T0)).unwrap();
    let db = first.received(DB, &dbirth(1, T0), at(T0)).unwrap();
    let kept: Vec<(String, Vec<u8>)> = [db.birth.unwrap(), nb.birth.unwrap()].into();
    assert_eq!(kept[1].0, NB);
    // Data without births is read only after the restore (DBIRTH listed first here:
    // the restore takes NBIRTHs first whatever the order).
    let data = ddata(
        2,
        vec![(0, metric::Value::FloatValue(2.5), T0 + 1000, false)],
    );
    let mut cold = Decoder::new("Plant");
    assert!(cold
        .received(DD, &data, at(T0 + 2000))
        .unwrap()
        .samples
        .is_empty());
    let mut restarted = Decoder::new("Plant");
    restarted.restore(&kept, at(T0 + 2000));
    assert_eq!(restarted.counters().births, 0);
    let out = restarted.received(DD, &data, at(T0 + 2000)).unwrap();
    assert!(out.publish.is_empty(), "no rebirth asked");
    assert_eq!(find(&out.samples, Var::Pv).value, 2.5);
    assert!(out.birth.is_none());
}
