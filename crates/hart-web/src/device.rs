//! Devices as the dashboard shows them: the plant's JSON, finding a device by unit
//! number, unique ID or tag, reading a command live, and the writes with their
//! read-back.

use std::collections::BTreeMap;
use std::time::{Duration, SystemTime};

use axum::http::StatusCode;
use hart_poller::{
    DeviceImage, Engine, LoopOutcome, Unaddressable, WriteError, WriteFailure, WriteOp,
};
use hart_proto::command::{BurstMessageSelect, Empty, ReadDeviceVariablesRequest};
use hart_proto::frame::Frame;
use hart_proto::json::{float, JsonVisitor};
use hart_proto::tables;
use hart_proto::types::{Date, DeviceVariableCode};
use hart_proto::wire::List;
use hart_proto::Request;
use serde_json::{json, Value};

use crate::ApiError;

/// Longest automatic release of a loop test.
pub(crate) const MAX_LOOP_TEST: Duration = Duration::from_secs(600);
/// The automatic release of a loop test when none is given.
pub(crate) const DEFAULT_LOOP_TEST: Duration = Duration::from_secs(60);

fn time(t: SystemTime) -> String {
    humantime::format_rfc3339_millis(t).to_string()
}

fn f(x: f32) -> Value {
    float(x)
}

/// One device as the plant view and `/api/devices` give it.
pub(crate) fn device_json(d: &DeviceImage, engine: &Engine) -> Value {
    let now = engine.clock().now();
    let quality = d.quality(now);
    let var = |i: usize| {
        d.variables[i].map_or(Value::Null, |v| {
            json!({
                "value": f(v.value),
                "units": v.units,
                "units_symbol": tables::unit_symbol(v.units).unwrap_or(""),
            })
        })
    };
    let info = d.info.as_ref();
    json!({
        "unit": d.position + 1,
        "loop": d.loop_name,
        "channel": d.channel,
        "name": d.display_name(),
        "tag": info.and_then(|i| i.tag.clone()),
        "long_tag": info.and_then(|i| i.long_tag.clone()),
        "descriptor": info.and_then(|i| i.descriptor.clone()),
        "unique_id": d.unique_id().map(|u| u.to_string()),
        "polling_address": d.polling_address,
        "manufacturer_id": info.map(|i| i.manufacturer_id()),
        "expanded_device_type": info.map(|i| i.identity.expanded_device_type),
        "universal_revision": info.map(|i| i.revision()),
        "pv": var(0),
        "sv": var(1),
        "tv": var(2),
        "qv": var(3),
        "loop_current": d.loop_current.map(f),
        "percent_of_range": d.percent_range.map(f),
        "range": d.range.map(|r| json!({
            "upper": f(r.upper),
            "lower": f(r.lower),
            "units": r.units,
            "units_symbol": tables::unit_symbol(r.units).unwrap_or(""),
            "damping": f(r.damping),
            "write_protect": r.write_protect,
        })),
        "fixed_current": d.fixed_current.map(f),
        "loop_test": d.loop_test.as_ref().map(|t| json!({
            "current": f(t.current),
            "release_at": time(t.release_at),
            "by": t.by,
            "failed_releases": t.failed_releases,
        })),
        "device_status": d.device_status,
        "device_status_set": hart_proto::json::device_status_set(d.device_status),
        "extended_status": d.extended_status,
        "quality": quality.name(),
        "quality_code": quality.code(),
        "age_s": d.seconds_since_good(now),
        "updated": d.updated.map(time),
        "polls": d.polls,
        "failures": d.failures,
    })
}

/// The whole plant: its loops (with a port down or a disturbance) and devices.
pub(crate) fn plant(engine: &Engine) -> Value {
    let loops: Vec<Value> = (0..engine.loop_count())
        .map(|c| {
            json!({
                "channel": c,
                "name": engine.loop_name(c),
                "port_failed": engine.loop_failure(c),
                "disturbed": engine.loop_disturbed(c),
            })
        })
        .collect();
    let devices: Vec<Value> = engine
        .image()
        .snapshot()
        .iter()
        .map(|d| device_json(d, engine))
        .collect();
    json!({
        "time": time(engine.clock().wall()),
        "loops": loops,
        "devices": devices,
    })
}

/// The image position of the device `id` names: its unit number (1, 2, ...), its
/// unique ID (10 hex digits) or its tag, long tag or configured name (any case).
pub(crate) fn resolve(engine: &Engine, id: &str) -> Result<usize, ApiError> {
    let id = id.trim();
    let image = engine.image();
    if let Ok(n) = id.parse::<usize>() {
        if n >= 1 && n <= image.len() {
            return Ok(n - 1);
        }
    }
    let found = image.position_where(|d| {
        d.unique_id()
            .is_some_and(|u| u.to_string().eq_ignore_ascii_case(id))
            || d.info.as_ref().is_some_and(|i| {
                [&i.tag, &i.long_tag]
                    .iter()
                    .any(|t| t.as_deref().is_some_and(|t| t.eq_ignore_ascii_case(id)))
            })
            || d.name
                .as_deref()
                .is_some_and(|n| n.eq_ignore_ascii_case(id))
    });
    found.ok_or_else(|| {
        ApiError::not_found(format!(
            "no device {id:?}: give its unit number (1 to {}), its unique ID or its tag; \
             /api/devices lists them",
            image.len()
        ))
    })
}

/// A reply as JSON: command, response code (with its name), device status in words,
/// and the data decoded with the command table (codes with their meaning).
pub(crate) fn reply_json(reply: &[u8]) -> Result<Value, ApiError> {
    let frame = Frame::parse_pdu(reply)
        .map_err(|e| ApiError::new(StatusCode::BAD_GATEWAY, format!("bad reply: {e}")))?;
    let rc = frame.response_code.unwrap_or(0);
    let status = frame.device_status.unwrap_or(0);
    let mut v = json!({
        "command": frame.command,
        "title": hart_proto::command::title(frame.command),
        "response_code": rc,
        "response_code_name": tables::response_code_name(frame.command, rc),
        "device_status": status,
        "device_status_set": hart_proto::json::device_status_set(status),
    });
    if frame.is_communication_error() {
        v["communication_error"] = json!(true);
        return Ok(v);
    }
    match hart_proto::decode::decode_body(&frame) {
        Some(Ok(d)) => {
            let mut visitor = JsonVisitor::with_words();
            d.describe(&mut visitor);
            v["decoded"] = visitor.finish();
        }
        Some(Err(e)) => v["decode_error"] = json!(e.to_string()),
        None => {}
    }
    Ok(v)
}

/// The universal revision of the device at `position` (5 when it is not identified).
fn revision(engine: &Engine, position: usize) -> u8 {
    engine
        .image()
        .with(position, |d| d.info.as_ref().map_or(5, |i| i.revision()))
        .unwrap_or(5)
}

/// Command 9's request for the device at `position`: the device variable codes it
/// has (HART 7: up to 8, HART 6: up to 4), or PV to QV (codes 246-249) when it does
/// not say.
pub(crate) fn variables_request(engine: &Engine, position: usize) -> Request {
    let max = engine
        .image()
        .with(position, |d| {
            d.info
                .as_ref()
                .and_then(|i| i.identity.max_device_variables)
        })
        .flatten();
    let slots = if revision(engine, position) >= 7 {
        8
    } else {
        4
    };
    let codes: Vec<DeviceVariableCode> = match max {
        Some(m) if m > 0 => (0..m.min(slots)).map(DeviceVariableCode).collect(),
        _ => hart_poller::POLL_SLOTS_6.to_vec(),
    };
    Request::ReadDeviceVariablesWithStatus(ReadDeviceVariablesRequest {
        slots: List::from_slice(&codes).unwrap_or_default(),
    })
}

/// Command 105's request for burst message `message` of the device at `position`
/// (a device before HART 7 has one message and takes no number).
pub(crate) fn burst_request(engine: &Engine, position: usize, message: u8) -> Request {
    Request::ReadBurstConfiguration(BurstMessageSelect {
        burst_message: (revision(engine, position) >= 7).then_some(message),
    })
}

/// Sends `request` to the device at `position` between the loop's polls, through the
/// engine's gate as a read, and returns its reply as [`reply_json`] gives it.
pub(crate) async fn read(
    engine: &Engine,
    position: usize,
    request: &Request,
) -> Result<Value, ApiError> {
    let command = request.command();
    let built = engine
        .image()
        .request_for(position, request)
        .map_err(|e| match e {
            Unaddressable::NoSuchDevice => ApiError::not_found("no such device"),
            Unaddressable::NotIdentified => ApiError::new(
                StatusCode::CONFLICT,
                "the device has not been identified yet (it has not answered command 0); \
                 try again when the plant view shows its unique ID",
            ),
            Unaddressable::Encode(e) => {
                ApiError::bad_request(format!("command {command}'s request does not encode: {e}"))
            }
        })?;
    let (channel, pdu) = (built.channel, built.pdu);
    // The dashboard's reads pass the engine's gate as reads: a command that is not
    // known to only read is refused, whoever is logged in (writes take the typed path).
    let reader = hart_poller::Requester::reader("web", "web dashboard read");
    match engine
        .forward(
            usize::from(channel),
            pdu,
            hart_poller::POLL_RETRIES,
            &reader,
        )
        .await
    {
        Err(why) => Err(ApiError::new(
            StatusCode::FORBIDDEN,
            format!("the gateway does not send command {command} as a read: {why}"),
        )),
        Ok(LoopOutcome::Reply(r)) => reply_json(&r),
        Ok(LoopOutcome::NoReply) => Err(ApiError::new(
            StatusCode::GATEWAY_TIMEOUT,
            format!(
                "the device did not answer command {command}; check that it is powered and \
                 on the loop"
            ),
        )),
        Ok(LoopOutcome::Busy) => Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "the loop is busy; try again in a moment",
        )),
    }
}

/// A write asked for: what to do, and for a loop test when to release it.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Planned {
    pub op: WriteOp,
    pub release_after: Option<Duration>,
}

/// The fields a write may carry (forms and JSON alike); exactly one operation per
/// request (the range's three fields count as one).
pub(crate) const WRITE_FIELDS: &[&str] = &[
    "tag",
    "long_tag",
    "descriptor",
    "message",
    "date",
    "upper_range",
    "lower_range",
    "range_units",
    "damping",
    "pv_units",
    "loop_test_ma",
    "release_after_s",
    "csrf",
];

/// A units code from its number or its symbol (`kPa`, any case).
pub(crate) fn parse_units(text: &str) -> Result<u8, String> {
    let t = text.trim();
    if let Ok(n) = t.parse::<u8>() {
        return Ok(n);
    }
    tables::UNITS
        .iter()
        .find(|u| u.symbol.eq_ignore_ascii_case(t) || u.name.eq_ignore_ascii_case(t))
        .map(|u| u.code)
        .ok_or_else(|| {
            format!("units {t:?}: not a units code or symbol of HART Common Table 2 (e.g. kPa, degC, 12)")
        })
}

fn parse_f32(name: &str, text: &str) -> Result<f32, String> {
    text.trim()
        .parse::<f32>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| format!("{name} {text:?}: give a finite number"))
}

fn parse_date(text: &str) -> Result<Date, String> {
    let bad = || format!("date {text:?}: give YYYY-MM-DD (1900 to 2155)");
    let mut parts = text.trim().splitn(3, '-');
    let mut next = || parts.next().and_then(|p| p.parse::<u16>().ok());
    let (Some(y), Some(m), Some(d)) = (next(), next(), next()) else {
        return Err(bad());
    };
    let (Ok(m), Ok(d)) = (u8::try_from(m), u8::try_from(d)) else {
        return Err(bad());
    };
    Date::new(y, m, d).map_err(|_| bad())
}

/// Turns a write's fields (from a form or a JSON object) into the operation.
pub(crate) fn plan(fields: &BTreeMap<String, String>) -> Result<Planned, ApiError> {
    if let Some(k) = fields.keys().find(|k| !WRITE_FIELDS.contains(&k.as_str())) {
        return Err(ApiError::bad_request(format!(
            "unknown field {k:?}; a write takes one of: tag, long_tag, descriptor, message, \
             date, upper_range/lower_range/range_units, damping, pv_units, loop_test_ma \
             (with release_after_s)"
        )));
    }
    let given = |k: &str| fields.get(k).map(String::as_str).filter(|v| !v.is_empty());
    let mut ops: Vec<Planned> = vec![];
    let bad = ApiError::bad_request;
    let plain = |op| Planned {
        op,
        release_after: None,
    };
    for (k, make) in [
        ("tag", WriteOp::Tag as fn(String) -> WriteOp),
        ("long_tag", WriteOp::LongTag),
        ("descriptor", WriteOp::Descriptor),
        ("message", WriteOp::Message),
    ] {
        if let Some(v) = fields.get(k) {
            ops.push(plain(make(v.clone())));
        }
    }
    if let Some(v) = given("date") {
        ops.push(plain(WriteOp::Date(parse_date(v).map_err(bad)?)));
    }
    if given("upper_range").is_some()
        || given("lower_range").is_some()
        || given("range_units").is_some()
    {
        let num = |k: &str| given(k).map(|v| parse_f32(k, v)).transpose();
        ops.push(plain(WriteOp::Range {
            upper: num("upper_range").map_err(bad)?,
            lower: num("lower_range").map_err(bad)?,
            units: given("range_units")
                .map(parse_units)
                .transpose()
                .map_err(bad)?,
        }));
    }
    if let Some(v) = given("damping") {
        ops.push(plain(WriteOp::Damping(
            parse_f32("damping", v).map_err(bad)?,
        )));
    }
    if let Some(v) = given("pv_units") {
        ops.push(plain(WriteOp::PvUnits(parse_units(v).map_err(bad)?)));
    }
    if let Some(v) = given("loop_test_ma") {
        let ma = parse_f32("loop_test_ma", v).map_err(bad)?;
        if ma != 0.0 && !(3.5..=23.0).contains(&ma) {
            return Err(bad(format!(
                "loop_test_ma {ma}: give a current from 3.5 to 23 mA, or 0 to end the loop test"
            )));
        }
        let release_after = if ma == 0.0 {
            None
        } else {
            let s = given("release_after_s")
                .map(|s| s.trim().parse::<u64>())
                .transpose()
                .map_err(|_| ApiError::bad_request("release_after_s: give whole seconds"))?;
            let d = s.map_or(DEFAULT_LOOP_TEST, Duration::from_secs);
            if d.is_zero() || d > MAX_LOOP_TEST {
                return Err(bad(format!(
                    "release_after_s: give 1 to {} seconds; the loop test ends by itself then",
                    MAX_LOOP_TEST.as_secs()
                )));
            }
            Some(d)
        };
        ops.push(Planned {
            op: WriteOp::FixedCurrent(ma),
            release_after,
        });
    }
    match ops.len() {
        1 => Ok(ops.remove(0)),
        0 => Err(ApiError::bad_request(
            "nothing to write: give one of tag, long_tag, descriptor, message, date, \
             upper_range/lower_range/range_units, damping, pv_units or loop_test_ma",
        )),
        _ => Err(ApiError::bad_request(
            "one write per request: give only one of the fields",
        )),
    }
}

/// The fields of a JSON write: an object of strings, numbers (and nulls, ignored).
pub(crate) fn fields_of_json(v: &Value) -> Result<BTreeMap<String, String>, ApiError> {
    let Some(obj) = v.as_object() else {
        return Err(ApiError::bad_request(
            "the body must be a JSON object, e.g. {\"damping\": 2.5}",
        ));
    };
    let mut out = BTreeMap::new();
    for (k, v) in obj {
        let s = match v {
            Value::String(s) => s.clone(),
            Value::Number(n) => n.to_string(),
            Value::Null => continue,
            _ => {
                return Err(ApiError::bad_request(format!(
                    "field {k:?}: give a string or a number"
                )))
            }
        };
        out.insert(k.clone(), s);
    }
    Ok(out)
}

/// The HTTP status and message of a failed write.
pub(crate) fn write_error(e: &WriteFailure) -> ApiError {
    let status = match e {
        WriteFailure::NotPermitted(_) => StatusCode::FORBIDDEN,
        WriteFailure::Invalid(_) => StatusCode::BAD_REQUEST,
        WriteFailure::NotReadYet(_) | WriteFailure::Refused { .. } => StatusCode::CONFLICT,
        WriteFailure::Link(WriteError::UnknownDevice) => StatusCode::NOT_FOUND,
        WriteFailure::Link(WriteError::NoReply) => StatusCode::GATEWAY_TIMEOUT,
        WriteFailure::Link(WriteError::Busy) => StatusCode::SERVICE_UNAVAILABLE,
        WriteFailure::Link(WriteError::BadReply(_)) => StatusCode::BAD_GATEWAY,
    };
    ApiError::new(status, e.to_string())
}

/// The command that reads back what `op` wrote.
/// The read that shows whether `op` was done.
fn read_back_request(op: &WriteOp) -> Request {
    match op {
        WriteOp::Tag(_) | WriteOp::Descriptor(_) | WriteOp::Date(_) => {
            Request::ReadTagDescriptorDate(Empty {})
        }
        WriteOp::Message(_) => Request::ReadMessage(Empty {}),
        WriteOp::LongTag(_) => Request::ReadLongTag(Empty {}),
        WriteOp::Range { .. } | WriteOp::Damping(_) => Request::ReadDeviceInformation(Empty {}),
        WriteOp::PvUnits(_) => Request::ReadPrimaryVariable(Empty {}),
        WriteOp::FixedCurrent(_) => Request::ReadLoopCurrent(Empty {}),
    }
}

fn same_float(got: Option<f64>, want: f32) -> bool {
    got.is_some_and(|g| (g as f32 - want).abs() <= want.abs() * 1e-6 + 1e-6)
}

fn same_text(got: Option<&str>, want: &str, packed: bool) -> bool {
    let norm = |s: &str| {
        let s = s.trim_end_matches(['\0', ' ']).to_string();
        if packed {
            s.to_ascii_uppercase()
        } else {
            s
        }
    };
    got.is_some_and(|g| norm(g) == norm(want))
}

/// Whether `decoded` (the read-back reply's fields) shows `op` done; `status` is
/// the read-back's device status (fixed current mode ends when its bit clears).
pub(crate) fn confirms(op: &WriteOp, decoded: &Value, status: u8) -> bool {
    let num = |k: &str| decoded.get(k).and_then(Value::as_f64);
    let text = |k: &str| decoded.get(k).and_then(Value::as_str);
    match op {
        WriteOp::Tag(t) => same_text(text("tag"), t, true),
        WriteOp::Descriptor(t) => same_text(text("descriptor"), t, true),
        WriteOp::Message(t) => same_text(text("message"), t, true),
        WriteOp::LongTag(t) => same_text(text("long_tag"), t, false),
        WriteOp::Date(d) => text("date") == Some(d.to_string().as_str()),
        WriteOp::Range {
            upper,
            lower,
            units,
        } => {
            upper.is_none_or(|u| same_float(num("upper_range_value"), u))
                && lower.is_none_or(|l| same_float(num("lower_range_value"), l))
                && units.is_none_or(|u| num("range_units") == Some(f64::from(u)))
        }
        WriteOp::Damping(s) => same_float(num("damping"), *s),
        WriteOp::PvUnits(u) => num("pv_units") == Some(f64::from(*u)),
        WriteOp::FixedCurrent(ma) if *ma == 0.0 => {
            status & hart_proto::tables::field_device_status::LOOP_CURRENT_FIXED == 0
        }
        WriteOp::FixedCurrent(ma) => {
            num("loop_current").is_some_and(|c| (c - f64::from(*ma)).abs() < 0.01)
        }
    }
}

/// Reads back what `op` wrote: the reply (as [`reply_json`]) and whether it shows the
/// value written.
pub(crate) async fn read_back(engine: &Engine, position: usize, op: &WriteOp) -> (Value, bool) {
    match read(engine, position, &read_back_request(op)).await {
        Ok(v) => {
            let status = v["device_status"].as_u64().unwrap_or(0) as u8;
            let ok = v.get("decoded").is_some_and(|d| confirms(op, d, status));
            (v, ok)
        }
        Err(e) => (e.json(), false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fields(pairs: &[(&str, &str)]) -> BTreeMap<String, String> {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn plans_each_write_and_refuses_bad_ones() {
        let p = |pairs: &[(&str, &str)]| plan(&fields(pairs));
        assert_eq!(
            p(&[("tag", "PT-101"), ("csrf", "x")]).unwrap().op,
            WriteOp::Tag("PT-101".into())
        );
        assert_eq!(p(&[("damping", "2.5")]).unwrap().op, WriteOp::Damping(2.5));
        assert_eq!(
            p(&[
                ("upper_range", "200"),
                ("range_units", "kPa"),
                ("lower_range", "")
            ])
            .unwrap()
            .op,
            WriteOp::Range {
                upper: Some(200.0),
                lower: None,
                units: Some(12)
            }
        );
        let lt = p(&[("loop_test_ma", "12"), ("release_after_s", "30")]).unwrap();
        assert_eq!(lt.op, WriteOp::FixedCurrent(12.0));
        assert_eq!(lt.release_after, Some(Duration::from_secs(30)));
        assert_eq!(p(&[("loop_test_ma", "0")]).unwrap().release_after, None);
        assert_eq!(
            p(&[("loop_test_ma", "12")]).unwrap().release_after,
            Some(DEFAULT_LOOP_TEST)
        );
        assert_eq!(
            p(&[("date", "2026-11-27")]).unwrap().op,
            WriteOp::Date(Date::new(2026, 11, 27).unwrap())
        );
        for bad in [
            &[][..],
            &[("damping", "NaN")],
            &[("damping", "inf")],
            &[("tag", "A"), ("damping", "1")],
            &[("loop_test_ma", "30")],
            &[("loop_test_ma", "12"), ("release_after_s", "100000")],
            &[("pv_units", "furlongs")],
            &[("date", "2026-13-01")],
            &[("date", "yesterday")],
            &[("colour", "red")],
        ] {
            let e = p(bad).unwrap_err();
            assert_eq!(e.status, StatusCode::BAD_REQUEST, "{bad:?}: {e}");
        }
    }

    #[test]
    fn json_fields() {
        let f = fields_of_json(&json!({"damping": 2.5, "csrf": "t", "x": null})).unwrap();
        assert_eq!(f.get("damping").map(String::as_str), Some("2.5"));
        assert!(fields_of_json(&json!([1])).is_err());
        assert!(fields_of_json(&json!({"tag": {"a": 1}})).is_err());
    }

    #[test]
    fn read_backs_confirm() {
        assert!(confirms(
            &WriteOp::Tag("pt-101".into()),
            &json!({"tag": "PT-101  "}),
            0
        ));
        assert!(!confirms(
            &WriteOp::Tag("PT-102".into()),
            &json!({"tag": "PT-101"}),
            0
        ));
        assert!(confirms(
            &WriteOp::Damping(0.3),
            &json!({"damping": 0.3}),
            0
        ));
        assert!(confirms(
            &WriteOp::FixedCurrent(12.0),
            &json!({"loop_current": 12.0}),
            0x08
        ));
        assert!(!confirms(&WriteOp::FixedCurrent(0.0), &json!({}), 0x08));
        assert!(confirms(&WriteOp::FixedCurrent(0.0), &json!({}), 0));
    }

    proptest::proptest! {
        /// Whatever a form or a JSON body holds, planning a write answers (a plan or
        /// a 400), never panics.
        #[test]
        fn any_fields_plan_or_refuse(
            pairs in proptest::collection::vec(
                (proptest::sample::select(WRITE_FIELDS.to_vec()), ".{0,40}"), 0..6),
            junk in ".{0,12}",
        ) {
            let mut f: BTreeMap<String, String> =
                pairs.into_iter().map(|(k, v)| (k.to_string(), v)).collect();
            let _ = plan(&f);
            f.insert(junk, "1".into());
            let _ = plan(&f);
        }

        #[test]
        fn any_json_gives_fields_or_an_error(text in ".{0,200}") {
            if let Ok(v) = serde_json::from_str::<Value>(&text) {
                let _ = fields_of_json(&v);
            }
        }
    }
}
