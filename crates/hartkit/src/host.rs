//! The host commands of `hartkit`: scan, read, write, command, burst, monitor, demo.
//! Protocol work is in `hart-host`; this module turns replies into tables and JSON.

use std::io::Write as _;

use hart_host::target::AnyTransport;
use hart_host::transport::Transport;
use hart_host::{Client, DeviceInfo, DeviceRef, HostError, Reply};
use hart_proto::command::{self as cmd, Empty};
use hart_proto::deframer::{Deframer, DeframerEvent};
use hart_proto::frame::Frame;
use hart_proto::tables;
use hart_proto::types::{
    BurstModeControl, Classification, DeviceVariableCode, HartTime, TriggerMode, UnitCode,
};
use hart_proto::wire::{List, Reader, Wire};
use hart_proto::Request;
use serde_json::{json, Value};

use crate::{annotate, hex, json as fj};

/// A failure with the exit status to use.
pub type Failure = (String, u8);

fn fail(e: HostError) -> Failure {
    let code = e.exit_code();
    (e.to_string(), code)
}

fn usage(msg: impl Into<String>) -> Failure {
    (msg.into(), 2)
}

fn units(code: u8) -> Value {
    json!(tables::unit(code).map_or("", |u| u.symbol))
}

fn f(x: f32) -> Value {
    fj::float(x)
}

fn decode<T: Wire>(r: &Reply, what: &str) -> Result<T, Failure> {
    T::decode(&mut Reader::new(&r.data)).map_err(|e| usage(format!("{what}: {e}")))
}

/// Opens the client for `--port`, with a trace file and a log level.
pub async fn client(
    port: &str,
    psk: Option<&hart_ip_tls::Psk>,
    trace: Option<&std::path::Path>,
    verbose: u8,
    secondary: bool,
) -> Result<Client<AnyTransport>, Failure> {
    let kind = if secondary {
        hart_proto::MasterKind::Secondary
    } else {
        hart_proto::MasterKind::Primary
    };
    let mut c = hart_host::target::connect(port, psk, kind)
        .await
        .map_err(|e| (e.to_string(), e.exit_code()))?;
    let mut file = match trace {
        Some(p) => Some(
            std::fs::File::create(p).map_err(|e| usage(format!("--trace {}: {e}", p.display())))?,
        ),
        None => None,
    };
    if file.is_some() || verbose > 0 {
        let (mut tx_deframer, mut rx_deframer) = (Deframer::default(), Deframer::default());
        c.set_log(move |e| {
            let dir = match e.direction {
                hart_host::client::Direction::Tx => "tx",
                hart_host::client::Direction::Rx => "rx",
            };
            if let Some(f) = &mut file {
                let _ = writeln!(
                    f,
                    "{}",
                    json!({"t_us": e.time_us, "dir": dir, "hex": hex::compact(&e.bytes)})
                );
            }
            if verbose > 0 {
                tracing::debug!("{:>12} µs {dir} {}", e.time_us, hex::spaced(&e.bytes));
            }
            if verbose > 1 {
                // Received bytes come in pieces: one deframer per direction keeps state.
                let d = match e.direction {
                    hart_host::client::Direction::Tx => &mut tx_deframer,
                    hart_host::client::Direction::Rx => &mut rx_deframer,
                };
                d.feed(&e.bytes, |ev| {
                    if let DeframerEvent::Frame(f) = ev {
                        tracing::trace!("\n{}", annotate::frame(&f).trim_end());
                    }
                });
            }
        });
    }
    Ok(c)
}

/// Runs a future on a single-threaded runtime.
pub fn block_on<F: std::future::Future>(f: F) -> F::Output {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("tokio runtime")
        .block_on(f)
}

/// The target device from `--poll`, `--tag`, `--long-tag` or `--unique-id`.
pub fn device_ref(
    poll: Option<u8>,
    tag: Option<&str>,
    long_tag: Option<&str>,
    unique_id: Option<&str>,
) -> Result<DeviceRef, Failure> {
    match (poll, tag, long_tag, unique_id) {
        (Some(p), None, None, None) => Ok(DeviceRef::Poll(p)),
        (None, Some(t), None, None) => Ok(DeviceRef::Tag(t.into())),
        (None, None, Some(t), None) => Ok(DeviceRef::LongTag(t.into())),
        (None, None, None, Some(u)) => hart_proto::UniqueId::parse_hex(u)
            .map(DeviceRef::UniqueId)
            .map_err(|e| usage(format!("--unique-id {u}: {e}"))),
        (None, None, None, None) => Err(usage(
            "say which device: --poll N, --tag T, --long-tag T or --unique-id HEX",
        )),
        _ => Err(usage(
            "give only one of --poll, --tag, --long-tag, --unique-id",
        )),
    }
}

fn device_json(d: &DeviceInfo) -> Value {
    let id = &d.identity;
    let mut v = json!({
        "polling_address": d.polling_address,
        "unique_id": d.unique_id().to_string(),
        "expanded_device_type": id.expanded_device_type,
        "manufacturer_id": d.manufacturer_id(),
        "device_id": id.device_id.to_string(),
        "universal_revision": id.universal_revision,
        "device_revision": id.device_revision,
        "tag": d.tag,
        "long_tag": if d.revision() >= 6 { json!(d.long_tag) } else { Value::Null },
        "descriptor": d.descriptor,
    });
    if d.is_io_system() {
        v["io_system"] = json!(true);
    }
    if let Some((card, channel)) = d.io_channel {
        v["io_card"] = json!(card);
        v["channel"] = json!(channel);
    }
    v
}

/// One row of the scan table.
fn scan_row(d: &DeviceInfo) -> String {
    let poll = d
        .polling_address
        .map_or_else(|| "-".to_string(), |p| p.to_string());
    let via = match (d.io_channel, d.is_io_system()) {
        (Some((card, channel)), _) => format!("{card}/{channel}"),
        (None, true) => "I/O sys".to_string(),
        (None, false) => String::new(),
    };
    format!(
        "{:>4}  {:<7}  {:<10}  0x{:04X}    0x{:04X}    {:>3}  {:<8}  {:<16}  {}",
        poll,
        via,
        d.unique_id(),
        d.identity.expanded_device_type,
        d.manufacturer_id(),
        d.revision(),
        d.tag.as_deref().unwrap_or("").trim_end(),
        d.descriptor.as_deref().unwrap_or("").trim_end(),
        d.long_tag.as_deref().unwrap_or("")
    )
}

/// Polling addresses as short ranges: "0, 4-15, 17".
fn ranges(polls: &[u8]) -> String {
    let mut out: Vec<String> = vec![];
    let mut i = 0;
    while i < polls.len() {
        let mut j = i;
        while j + 1 < polls.len() && polls[j + 1] == polls[j] + 1 {
            j += 1;
        }
        out.push(if j == i {
            polls[i].to_string()
        } else {
            format!("{}-{}", polls[i], polls[j])
        });
        i = j + 1;
    }
    out.join(", ")
}

/// `hartkit scan`: each device is printed as soon as it is found (with `--json`, one
/// JSON object per line), sub-devices of an I/O system included; addresses where
/// nothing answered are summed up at the end; a progress bar runs on a terminal.
pub async fn scan(
    c: &mut Client<AnyTransport>,
    from: u8,
    to: u8,
    as_json: bool,
) -> Result<String, Failure> {
    if from > to || to > 63 {
        return Err(usage(format!(
            "--from {from} --to {to}: polling addresses are 0-63, from ≤ to"
        )));
    }
    let bar = if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        indicatif::ProgressBar::new(u64::from(to - from) + 1)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "scanning [{bar:30}] {pos}/{len} {msg} ({elapsed})",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("#>-"),
    );
    let port = c.transport().describe();
    let mut out = std::io::stdout();
    let mut print = |line: &str| {
        bar.suspend(|| {
            let _ = writeln!(out, "{line}");
            let _ = out.flush();
        })
    };
    if !as_json {
        print(&format!("scanning polling addresses {from}-{to} on {port}"));
        print(&format!(
            "{:>4}  {:<7}  {:<10}  {:<8}  {:<10}  {:>3}  {:<8}  {:<16}  {}",
            "poll", "via", "unique ID", "type", "manuf.", "rev", "tag", "descriptor", "long tag"
        ));
    }
    let mut absent = vec![];
    let found = c
        .scan(from..=to, |event| {
            let shown = match event {
                hart_host::ScanEvent::Address { poll, found } => {
                    bar.inc(1);
                    bar.set_message(format!("polling address {poll}"));
                    if found.is_none() {
                        absent.push(poll);
                    }
                    found
                }
                hart_host::ScanEvent::SubDevice(d) => Some(d),
            };
            if let Some(d) = shown {
                if as_json {
                    print(&device_json(d).to_string());
                } else {
                    print(&scan_row(d));
                }
            }
        })
        .await
        .map_err(fail);
    bar.finish_and_clear();
    let found = found?;
    if as_json {
        return Ok(String::new());
    }
    let mut s = format!("{} device(s) on {port}", found.len());
    if !absent.is_empty() {
        s.push_str(&format!(
            "; no device at polling address{} {}",
            if absent.len() == 1 { "" } else { "es" },
            ranges(&absent)
        ));
    }
    Ok(s)
}

const DV_NAMES: [&str; 4] = ["PV", "SV", "TV", "QV"];

/// `hartkit read`.
pub async fn read(
    c: &mut Client<AnyTransport>,
    target: &DeviceRef,
    what: &str,
    codes: &[u8],
    as_json: bool,
) -> Result<String, Failure> {
    let d = c.resolve(target).await.map_err(fail)?;
    let v = match what {
        "pv" => {
            let r: cmd::ReadPvResponse = decode(
                &c.request(&d, &Request::ReadPrimaryVariable(Empty {}))
                    .await
                    .map_err(fail)?,
                "command 1",
            )?;
            json!({"pv": f(r.pv), "units": r.pv_units.0, "units_symbol": units(r.pv_units.0)})
        }
        "loop" => {
            let r: cmd::ReadLoopCurrentResponse = decode(
                &c.request(&d, &Request::ReadLoopCurrent(Empty {}))
                    .await
                    .map_err(fail)?,
                "command 2",
            )?;
            json!({"loop_current": f(r.loop_current.0), "percent_of_range": f(r.percent_of_range.0)})
        }
        "dynamic" => {
            let r: cmd::ReadDynamicVariablesResponse = decode(
                &c.request(&d, &Request::ReadDynamicVariables(Empty {}))
                    .await
                    .map_err(fail)?,
                "command 3",
            )?;
            let vars: Vec<Value> = r
                .variables
                .as_slice()
                .iter()
                .enumerate()
                .map(|(i, v)| json!({"name": DV_NAMES[i], "units": v.units.0, "units_symbol": units(v.units.0), "value": f(v.value)}))
                .collect();
            json!({"loop_current": f(r.loop_current.0), "variables": vars})
        }
        "vars" => {
            if codes.is_empty() || codes.len() > 8 {
                return Err(usage("read vars: give 1 to 8 device variable codes"));
            }
            let codes: Vec<DeviceVariableCode> =
                codes.iter().copied().map(DeviceVariableCode).collect();
            if d.revision() >= 6 {
                let request =
                    Request::ReadDeviceVariablesWithStatus(cmd::ReadDeviceVariablesRequest {
                        slots: List::from_slice(&codes)
                            .map_err(|e| usage(format!("read vars: {e}")))?,
                    });
                let r: cmd::ReadDeviceVariablesResponse =
                    decode(&c.request(&d, &request).await.map_err(fail)?, "command 9")?;
                let slots: Vec<Value> = r
                    .data
                    .slots
                    .as_slice()
                    .iter()
                    .map(|s| {
                        json!({"code": s.code.0, "classification": s.classification.0, "units": s.units.0, "units_symbol": units(s.units.0), "value": f(s.value),
                        "status": s.status.0, "process_data": tables::PROCESS_DATA_STATUS.name(s.status.process_data()), "limit": tables::LIMIT_STATUS.name(s.status.limit())})
                    })
                    .collect();
                json!({"variables": slots})
            } else {
                // Command 33 carries 4 codes at most: the first four.
                let request = Request::ReadDeviceVariables(cmd::ReadVariablesRequest {
                    slots: List::from_slice(&codes[..codes.len().min(4)])
                        .map_err(|e| usage(format!("read vars: {e}")))?,
                });
                let r: cmd::ReadVariablesResponse =
                    decode(&c.request(&d, &request).await.map_err(fail)?, "command 33")?;
                let slots: Vec<Value> = r.variables.as_slice().iter().map(|s| json!({"code": s.code.0, "units": s.units.0, "units_symbol": units(s.units.0), "value": f(s.value)})).collect();
                json!({"variables": slots})
            }
        }
        "status" => {
            let request = Request::ReadAdditionalStatus(Default::default());
            let reply = c.request(&d, &request).await.map_err(fail)?;
            let ds = reply.device_status;
            let status: cmd::ReadAdditionalStatusResponse = decode(&reply, "command 48")?;
            // The reply's parts as the frame view names them, with their words
            // (`extended_status` and `extended_status_set`, ...).
            let mut words = fj::JsonVisitor::with_words();
            cmd::Response::ReadAdditionalStatus(status).describe(&mut words);
            let mut v = words.finish();
            v["device_status"] = json!(ds);
            v["device_status_set"] = fj::device_status_set(ds);
            v
        }
        "info" => {
            let mut v = device_json(&d);
            if let Ok(r) = c
                .request(&d, &Request::ReadTagDescriptorDate(Empty {}))
                .await
            {
                if let Ok(t) = cmd::TagDescriptorDate::decode(&mut Reader::new(&r.data)) {
                    v["tag"] = json!(t.tag.to_string());
                    v["descriptor"] = json!(t.descriptor.to_string());
                    v["date"] = json!(t.date.to_string());
                }
            }
            if let Ok(r) = c.request(&d, &Request::ReadMessage(Empty {})).await {
                if let Ok(m) = cmd::Message::decode(&mut Reader::new(&r.data)) {
                    v["message"] = json!(m.message.to_string());
                }
            }
            if d.revision() >= 6 {
                if let Ok(r) = c.request(&d, &Request::ReadLongTag(Empty {})).await {
                    if let Ok(t) = cmd::LongTag::decode(&mut Reader::new(&r.data)) {
                        v["long_tag"] = json!(t.long_tag.to_string());
                    }
                }
            }
            if let Ok(r) = c
                .request(&d, &Request::ReadDeviceInformation(Empty {}))
                .await
            {
                if let Ok(i) = cmd::DeviceInformation::decode(&mut Reader::new(&r.data)) {
                    v["range"] = json!({"units": i.range_units.0, "units_symbol": units(i.range_units.0), "upper": f(i.upper_range_value), "lower": f(i.lower_range_value)});
                    v["damping"] = f(i.damping.0);
                    v["transfer_function"] =
                        json!(tables::TRANSFER_FUNCTION.name(i.transfer_function.0));
                    v["alarm_selection"] = json!(tables::ALARM_SELECTION.name(i.alarm_selection.0));
                    v["write_protect"] = json!(tables::WRITE_PROTECT.name(i.write_protect.0));
                }
            }
            if let Ok(r) = c
                .request(&d, &Request::ReadFinalAssemblyNumber(Empty {}))
                .await
            {
                if let Ok(n) = cmd::FinalAssemblyNumber::decode(&mut Reader::new(&r.data)) {
                    v["final_assembly_number"] = json!(n.final_assembly_number.get());
                }
            }
            v["min_request_preambles"] = json!(d.identity.min_request_preambles);
            v["config_change_counter"] = json!(d.identity.config_change_counter);
            v
        }
        other => {
            return Err(usage(format!(
                "read {other}: expected pv, loop, dynamic, vars CODES, status or info"
            )))
        }
    };
    if as_json {
        return Ok(serde_json::to_string_pretty(&v).unwrap_or_default());
    }
    Ok(text_of(&v, 0))
}

/// A JSON value as indented "key: value" lines.
fn text_of(v: &Value, indent: usize) -> String {
    let pad = " ".repeat(indent);
    match v {
        Value::Object(m) => m
            .iter()
            .map(|(k, x)| match x {
                Value::Object(_) | Value::Array(_) => {
                    format!("{pad}{k}:\n{}", text_of(x, indent + 2))
                }
                _ => format!("{pad}{k:<24} {}", scalar(x)),
            })
            .collect::<Vec<_>>()
            .join("\n"),
        Value::Array(a) if a.iter().all(|x| !x.is_object()) => format!(
            "{pad}{}",
            a.iter().map(scalar).collect::<Vec<_>>().join(", ")
        ),
        Value::Array(a) => a
            .iter()
            .enumerate()
            .map(|(i, x)| format!("{pad}[{i}]\n{}", text_of(x, indent + 2)))
            .collect::<Vec<_>>()
            .join("\n"),
        x => format!("{pad}{}", scalar(x)),
    }
}

fn scalar(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Null => "-".into(),
        x => x.to_string(),
    }
}

fn check_rc(r: &Reply) -> String {
    if r.response_code == 0 {
        String::new()
    } else {
        format!(
            " (device warning {}: {})",
            r.response_code,
            tables::response_code_name(0, r.response_code).unwrap_or("warning")
        )
    }
}

/// `hartkit write`.
pub async fn write(
    c: &mut Client<AnyTransport>,
    target: &DeviceRef,
    what: &str,
    args: &[String],
    as_json: bool,
) -> Result<String, Failure> {
    let d = c.resolve(target).await.map_err(fail)?;
    let write = c.write_request(&d, what, args).await.map_err(fail)?;
    let (command, confirm) = (write.request.command(), write.read_back.command());
    let r = c.request(&d, &write.request).await.map_err(fail)?;
    let warn = check_rc(&r);
    // Confirm by reading back.
    let back = c.request(&d, &write.read_back).await.map_err(fail)?;
    let pdu = back.pdu.clone();
    let frame = Frame::parse_pdu(&pdu).map_err(|e| usage(e.to_string()))?;
    if as_json {
        // The write's own reply and the read-back, each as `hartkit frame --json` shows
        // a frame.
        let written = Frame::parse_pdu(&r.pdu).map_err(|e| usage(e.to_string()))?;
        return Ok(serde_json::to_string_pretty(&json!({
            "command": command,
            "response_code": r.response_code,
            "reply": fj::frame(&written),
            "read_back_command": confirm,
            "read_back": fj::frame(&frame),
        }))
        .unwrap_or_default());
    }
    let mut s = format!("command {command} accepted{warn}; read back with command {confirm}:\n");
    s.push_str(&annotate::frame(&frame));
    Ok(s.trim_end().to_string())
}

/// `hartkit command CMD [DATA]`: any command, reply decoded.
pub async fn command(
    c: &mut Client<AnyTransport>,
    target: &DeviceRef,
    number: u16,
    data: &[u8],
    as_json: bool,
) -> Result<String, Failure> {
    let d = c.resolve(target).await.map_err(fail)?;
    let r = c.command(&d, number, data).await.map_err(fail)?;
    let frame = Frame::parse_pdu(&r.pdu).map_err(|e| usage(e.to_string()))?;
    if as_json {
        return Ok(serde_json::to_string_pretty(&fj::frame(&frame)).unwrap_or_default());
    }
    Ok(annotate::frame(&frame).trim_end().to_string())
}

/// `hartkit burst`.
pub async fn burst(
    c: &mut Client<AnyTransport>,
    target: &DeviceRef,
    action: &BurstAction,
    as_json: bool,
) -> Result<String, Failure> {
    let d = c.resolve(target).await.map_err(fail)?;
    let mut notes = vec![];
    let period = |s: f32| ((s as f64) * 32_000.0).round() as u32;
    match action {
        BurstAction::Config {
            message,
            command,
            vars,
            period: p,
            max_period,
            trigger,
            level,
        } => {
            let m = *message;
            let request = Request::WriteBurstCommandNumber(cmd::BurstCommand {
                command_number: *command,
                burst_message: Some(m),
            });
            let r = c.request(&d, &request).await.map_err(fail)?;
            notes.push(format!("command {command}{}", check_rc(&r)));
            if !vars.is_empty() {
                // Eight slots; those not given are 250, "not used".
                let mut slots = [DeviceVariableCode(250); 8];
                for (slot, v) in slots.iter_mut().zip(vars.iter()) {
                    *slot = DeviceVariableCode(*v);
                }
                let request = Request::WriteBurstDeviceVariables(cmd::BurstVariables {
                    slots: List::from_slice(&slots).map_err(|e| usage(e.to_string()))?,
                    burst_message: Some(m),
                });
                let r = c.request(&d, &request).await.map_err(fail)?;
                notes.push(format!("slots {vars:?}{}", check_rc(&r)));
            }
            let max = max_period.unwrap_or(p.max(60.0));
            let request = Request::WriteBurstPeriod(cmd::BurstPeriod {
                burst_message: m,
                update_period: HartTime(period(*p)),
                max_update_period: HartTime(period(max)),
            });
            let r = c.request(&d, &request).await.map_err(fail)?;
            let bp = cmd::BurstPeriod::decode(&mut Reader::new(&r.data))
                .map_err(|e| usage(e.to_string()))?;
            notes.push(format!(
                "period {} s, max {} s{}",
                bp.update_period.as_secs_f64(),
                bp.max_update_period.as_secs_f64(),
                check_rc(&r)
            ));
            let mode = match trigger.as_str() {
                "continuous" => 0u8,
                "window" => 1,
                "rising" => 2,
                "falling" => 3,
                "on-change" => 4,
                other => {
                    return Err(usage(format!(
                    "--trigger {other}: expected continuous, window, rising, falling or on-change"
                )))
                }
            };
            let (class, unit, lvl) = if matches!(mode, 0 | 4) {
                (0u8, 250u8, hart_proto::types::hart_nan())
            } else {
                let level = level
                    .ok_or_else(|| usage("--trigger window/rising/falling needs --level X"))?;
                // The trigger is in the units and classification of the value the command carries.
                let src = if matches!(command, 9 | 33) {
                    vars.first().copied().unwrap_or(0)
                } else {
                    246
                };
                let request =
                    Request::ReadDeviceVariablesWithStatus(cmd::ReadDeviceVariablesRequest {
                        slots: List::from_slice(&[DeviceVariableCode(src)])
                            .map_err(|e| usage(e.to_string()))?,
                    });
                let v = c.request(&d, &request).await.map_err(fail)?;
                let slot = cmd::ReadDeviceVariablesResponse::decode(&mut Reader::new(&v.data))
                    .map_err(|e| usage(e.to_string()))?;
                let s = slot
                    .data
                    .slots
                    .as_slice()
                    .first()
                    .copied()
                    .ok_or_else(|| usage("no trigger variable"))?;
                (s.classification.0, s.units.0, level)
            };
            let request = Request::WriteBurstTrigger(cmd::BurstTrigger {
                burst_message: m,
                trigger_mode: TriggerMode(mode),
                classification: Classification(class),
                units: UnitCode(unit),
                trigger_level: lvl,
            });
            let r = c.request(&d, &request).await.map_err(fail)?;
            notes.push(format!("trigger {trigger}{}", check_rc(&r)));
        }
        BurstAction::On { message } | BurstAction::Off { message } => {
            let code = u8::from(matches!(action, BurstAction::On { .. }));
            let request = Request::BurstModeControl(cmd::BurstModeControlRequest {
                control: BurstModeControl(code),
                burst_message: Some(*message),
            });
            let r = c.request(&d, &request).await.map_err(fail)?;
            notes.push(format!(
                "burst message {message} {}{}",
                if code == 1 { "on" } else { "off" },
                check_rc(&r)
            ));
        }
        BurstAction::Show { .. } => {}
    }
    let message = match action {
        BurstAction::Config { message, .. }
        | BurstAction::On { message }
        | BurstAction::Off { message }
        | BurstAction::Show { message } => *message,
    };
    let request = Request::ReadBurstConfiguration(cmd::BurstMessageSelect {
        burst_message: Some(message),
    });
    let r = c.request(&d, &request).await.map_err(fail)?;
    let frame = Frame::parse_pdu(&r.pdu).map_err(|e| usage(e.to_string()))?;
    if as_json {
        let mut v = fj::frame(&frame);
        v["changes"] = json!(notes);
        return Ok(serde_json::to_string_pretty(&v).unwrap_or_default());
    }
    let mut s = notes.join("\n");
    if !s.is_empty() {
        s.push('\n');
    }
    s.push_str(&annotate::frame(&frame));
    Ok(s.trim_end().to_string())
}

/// What `hartkit burst` does.
#[derive(Debug, Clone)]
pub enum BurstAction {
    /// Configure a burst message.
    Config {
        /// Message number.
        message: u8,
        /// Command published.
        command: u16,
        /// Device variable codes for the slots.
        vars: Vec<u8>,
        /// Update period, s.
        period: f32,
        /// Maximum update period, s.
        max_period: Option<f32>,
        /// Trigger mode name.
        trigger: String,
        /// Trigger level.
        level: Option<f32>,
    },
    /// Enable.
    On {
        /// Message number.
        message: u8,
    },
    /// Disable.
    Off {
        /// Message number.
        message: u8,
    },
    /// Show the configuration.
    Show {
        /// Message number.
        message: u8,
    },
}

/// `hartkit monitor`: every frame seen on the line, decoded, with timing.
pub async fn monitor(
    t: &mut AnyTransport,
    duration: Option<f64>,
    as_json: bool,
    out: &mut dyn std::io::Write,
    mut capture: Option<&mut Capture>,
) -> Result<(), Failure> {
    if let AnyTransport::HartIp(h) = t {
        // Servers that publish only to subscribers need to be asked.
        h.subscribe_all()
            .await
            .map_err(|e| fail(HostError::Io(e)))?;
    }
    let start = t.now();
    let wall_start = unix_us();
    let end = duration.map(|d| start + (d * 1e6) as u64);
    let mut deframer = Deframer::default();
    let mut last_end: Option<u64> = None;
    loop {
        let now = t.now();
        if end.is_some_and(|e| now >= e) {
            return Ok(());
        }
        let until = end.unwrap_or(now + 1_000_000).min(now + 1_000_000);
        // With the UART's flags: a modem's parity and framing errors, the analog
        // loop's demodulators', reach the damaged frames and the capture's comments.
        let chars = match t.recv_flagged(until).await {
            Ok(b) => b,
            // A recording played back has ended.
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(fail(HostError::Io(e))),
        };
        for c in chars {
            let (b, at) = (c.byte, c.at);
            let mut lines: Vec<String> = vec![];
            let mut records: Vec<(Vec<u8>, bool, String)> = vec![];
            deframer.push(b, c.flags, &mut |e| match e {
                DeframerEvent::Frame(f) => {
                    let gap = last_end.map(|l| at.saturating_sub(l));
                    lines.push(frame_line(&f, at - start, gap, as_json));
                    records.push((
                        f.pdu.to_vec(),
                        true,
                        gap.map_or(String::new(), |g| {
                            format!("gap {:.1} ms", g as f64 / 1000.0)
                        }),
                    ));
                    last_end = Some(at);
                }
                DeframerEvent::Damaged(d) => {
                    lines.push(damaged_line(d.pdu, d.errors, at - start, as_json));
                    records.push((d.pdu.to_vec(), false, damage_note(d.errors)));
                }
                _ => {}
            });
            for l in lines {
                let _ = writeln!(out, "{l}");
            }
            if let Some(c) = capture.as_deref_mut() {
                for (bytes, valid, note) in records {
                    c.record(wall_start + (at - start), &bytes, valid, &note)?;
                }
            }
        }
    }
}

/// A damaged frame's link errors in words, for a capture's comment: "damaged frame:
/// vertical parity error, framing error (errors 0xD0)".
pub fn damage_note(errors: u8) -> String {
    let words: Vec<&str> = hart_proto::tables::COMMUNICATION_ERROR
        .set_bits(errors)
        .map(|b| b.name)
        .collect();
    if words.is_empty() {
        format!("damaged frame (errors 0x{errors:02X})")
    } else {
        format!(
            "damaged frame: {} (errors 0x{errors:02X})",
            words.join(", ")
        )
    }
}

/// Microseconds since the Unix epoch, now.
fn unix_us() -> u64 {
    hart_clock::epoch::micros(std::time::SystemTime::now())
}

/// One frame as `monitor` and `capture read` print it: `t_us` (µs since the start),
/// the gap since the frame before, then the frame (JSON, or one line of text).
pub fn frame_line(f: &Frame<'_>, t_us: u64, gap: Option<u64>, as_json: bool) -> String {
    if as_json {
        let mut v = fj::frame(f);
        v["t_us"] = json!(t_us);
        v["gap_us"] = json!(gap);
        return v.to_string();
    }
    let summary = match f.response_code {
        Some(rc) => format!("rc {rc} status 0x{:02X}", f.device_status.unwrap_or(0)),
        None => String::new(),
    };
    format!(
        "{:>10.3} s {:>8} {:<4} cmd {:<4} {} {} {}",
        t_us as f64 / 1e6,
        gap.map_or(String::from("-"), |g| format!(
            "+{:.1}ms",
            g as f64 / 1000.0
        )),
        f.frame_type().name(),
        f.command,
        f.address,
        summary,
        hex::compact(f.data)
    )
}

/// Bytes that are not a valid frame, as `monitor` and `capture read` print them.
pub fn damaged_line(bytes: &[u8], errors: u8, t_us: u64, as_json: bool) -> String {
    if as_json {
        json!({"t_us": t_us, "damaged": hex::compact(bytes), "errors": errors}).to_string()
    } else {
        format!(
            "{:>10.3} s damaged frame (errors 0x{:02X}) {}",
            t_us as f64 / 1e6,
            errors,
            hex::compact(bytes)
        )
    }
}

/// A capture being written by `monitor --pcap`: the pcapng writer and where the frames
/// come from (for each packet's comment).
pub struct Capture {
    writer: hart_capture::CaptureWriter<Box<dyn std::io::Write>>,
    source: String,
    path: String,
}

impl Capture {
    /// Starts a capture of frames from `source` into `path` (`-`: standard output).
    pub fn create(path: &str, source: &str) -> Result<Self, Failure> {
        let out: Box<dyn std::io::Write> = if path == "-" {
            Box::new(std::io::stdout())
        } else {
            Box::new(std::io::BufWriter::new(
                std::fs::File::create(path).map_err(|e| {
                    (
                        format!(
                            "--pcap {path}: {e}; check the directory and that you may write there"
                        ),
                        2,
                    )
                })?,
            ))
        };
        let writer = hart_capture::CaptureWriter::new(out, "hartkit monitor")
            .map_err(|e| (format!("--pcap {path}: {e}"), 5))?;
        Ok(Capture {
            writer,
            source: source.to_string(),
            path: path.to_string(),
        })
    }

    /// Writes one frame (`valid`) or run of damaged bytes seen at `time_us` (µs since
    /// the Unix epoch), with `note` after the source in the packet's comment.
    pub fn record(
        &mut self,
        time_us: u64,
        bytes: &[u8],
        valid: bool,
        note: &str,
    ) -> Result<(), Failure> {
        let comment = if note.is_empty() {
            format!("source {}", self.source)
        } else {
            format!("source {}; {note}", self.source)
        };
        self.writer
            .write(&hart_capture::Record {
                time_us,
                bytes,
                valid,
                comment: Some(comment),
            })
            .map_err(|e| {
                (
                    format!(
                        "--pcap {}: {e}; the frames written before are kept (each block is whole)",
                        self.path
                    ),
                    5,
                )
            })
    }
}

/// `hartkit capture read FILE`: every HART frame of a pcapng or pcap capture (HART-IP
/// on `ports`), as `monitor` prints them (times from the first frame).
pub fn capture_read(
    path: &str,
    ports: &[u16],
    as_json: bool,
    out: &mut dyn std::io::Write,
) -> Result<(), Failure> {
    let file = std::fs::File::open(path).map_err(|e| (format!("{path}: {e}"), 2))?;
    let frames = hart_capture::read_capture_ports(std::io::BufReader::new(file), ports)
        .map_err(|e| (format!("{path}: {e}"), 2))?;
    let start = frames.first().map_or(0, |f| f.time_us);
    let mut last: Option<u64> = None;
    for c in &frames {
        let t = c.time_us.saturating_sub(start);
        let line = match Frame::parse_pdu(&c.bytes) {
            Ok(f) if c.valid => {
                let gap = last.map(|l| c.time_us.saturating_sub(l));
                last = Some(c.time_us);
                let mut l = frame_line(&f, t, gap, as_json);
                if as_json {
                    if let Ok(mut v) = serde_json::from_str::<Value>(&l) {
                        v["direction"] = json!(c.direction.name());
                        v["comment"] = json!(c.comment);
                        l = v.to_string();
                    }
                }
                l
            }
            _ => {
                // hartkit's own captures keep the link errors in the comment.
                let errors = c
                    .comment
                    .as_deref()
                    .and_then(|m| m.split("(errors 0x").nth(1))
                    .and_then(|r| u8::from_str_radix(r.get(..2)?, 16).ok())
                    .unwrap_or(0);
                let mut l = damaged_line(&c.bytes, errors, t, as_json);
                if as_json {
                    if let Ok(mut v) = serde_json::from_str::<Value>(&l) {
                        v["comment"] = json!(c.comment);
                        l = v.to_string();
                    }
                }
                l
            }
        };
        let _ = writeln!(out, "{line}");
    }
    if frames.is_empty() && !as_json {
        let _ = writeln!(
            out,
            "no HART frames in {path} (HART-IP on port {}, or hartkit's own captures; --port N for another)",
            ports.iter().map(u16::to_string).collect::<Vec<_>>().join(", ")
        );
    }
    Ok(())
}
