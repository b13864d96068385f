//! A HART master for Python: `hart_host::Client` on its own thread (one per
//! connection, with its own single-threaded tokio runtime), taking operations from a
//! queue. Each operation's result comes back on a oneshot channel, which Python either
//! awaits (asyncio, through pyo3-async-runtimes) or blocks on with the GIL released.
//! Results cross as JSON values and become Python dicts and lists on arrival.

use std::collections::HashMap;

use hart_host::target::AnyTransport;
use hart_host::{Client, DeviceInfo, DeviceRef, HostError};
use hart_proto::wire::Wire;
use pyo3::prelude::*;
use pyo3::types::PyTuple;
use serde_json::{json, Value};
use tokio::sync::{mpsc, oneshot};

use crate::{to_py, DeviceError, HartError, NoReplyError, TargetError};

/// What went wrong, to pick the Python exception.
#[derive(Debug)]
enum Failure {
    NoReply(String),
    Device {
        message: String,
        command: u16,
        code: u8,
    },
    Target(String),
    Other(String),
}

impl From<HostError> for Failure {
    fn from(e: HostError) -> Self {
        match e {
            HostError::NoReply { .. }
            | HostError::NoReplyBehindServer { .. }
            | HostError::Communication { .. } => Failure::NoReply(e.to_string()),
            HostError::Device { command, code, .. } => Failure::Device {
                message: e.to_string(),
                command,
                code,
            },
            HostError::Io(_) => Failure::Target(e.to_string()),
            _ => Failure::Other(e.to_string()),
        }
    }
}

impl Failure {
    fn into_py(self, py: Python<'_>) -> PyErr {
        match self {
            Failure::NoReply(m) => NoReplyError::new_err(m),
            Failure::Device {
                message,
                command,
                code,
            } => {
                let e = DeviceError::new_err(message);
                let v = e.value(py);
                let _ = v.setattr("response_code", code);
                let _ = v.setattr("command", command);
                e
            }
            Failure::Target(m) => TargetError::new_err(m),
            Failure::Other(m) => HartError::new_err(m),
        }
    }
}

type Outcome = Result<Value, Failure>;

/// An operation for the client's thread.
enum Op {
    Scan {
        first: u8,
        last: u8,
    },
    Resolve(DeviceRef),
    Command {
        unique_id: String,
        command: u16,
        data: Vec<u8>,
    },
    Write {
        unique_id: String,
        what: String,
        args: Vec<String>,
    },
    Listen {
        seconds: f64,
    },
}

/// A device as Python sees it.
fn device_json(d: &DeviceInfo) -> Value {
    let mut v = hart_proto::json::JsonVisitor::with_words();
    d.identity.describe("identity", 0, &mut v);
    json!({
        "unique_id": d.unique_id().to_string(),
        "polling_address": d.polling_address,
        "tag": d.tag,
        "descriptor": d.descriptor,
        "long_tag": d.long_tag,
        "universal_revision": d.revision(),
        "manufacturer_id": d.manufacturer_id(),
        "expanded_device_type": d.identity.expanded_device_type,
        "device_id": hart_proto::hex::compact(&d.identity.device_id.0),
        "io_card": d.io_channel.map(|(card, _)| card),
        "channel": d.io_channel.map(|(_, channel)| channel),
        "identity": v.finish(),
    })
}

/// A command's reply as Python sees it: codes, bytes as hex, the data decoded in words.
fn reply_json(command: u16, r: &hart_host::Reply) -> Value {
    let (decoded, decode_error) = match hart_proto::command::decode_response(command, &r.data) {
        Some(Ok(resp)) => {
            let mut v = hart_proto::json::JsonVisitor::with_words();
            resp.describe(&mut v);
            (v.finish(), None)
        }
        Some(Err(e)) => (Value::Null, Some(e.to_string())),
        None => (Value::Null, None),
    };
    json!({
        "command": command,
        "response_code": r.response_code,
        "response_code_name": hart_proto::tables::response_code_name(command, r.response_code),
        "device_status": r.device_status,
        "device_status_set": hart_proto::json::device_status_set(r.device_status),
        "data": hart_proto::hex::compact(&r.data),
        "pdu": hart_proto::hex::compact(&r.pdu),
        "decoded": decoded,
        "decode_error": decode_error,
        "additional_status": r.additional_status.as_deref().map(hart_proto::hex::compact),
    })
}

struct Worker {
    client: Client<AnyTransport>,
    /// Devices seen, by unique ID, so Python can name a device by it.
    devices: HashMap<String, DeviceInfo>,
}

impl Worker {
    /// Keeps what is known of a device: a device found by tag or unique ID keeps the
    /// polling address and tags an earlier scan found.
    fn remember(&mut self, d: &DeviceInfo) -> Value {
        let id = d.unique_id().to_string();
        let mut d = d.clone();
        if let Some(old) = self.devices.get(&id) {
            d.polling_address = d.polling_address.or(old.polling_address);
            d.io_channel = d.io_channel.or(old.io_channel);
            if d.tag.is_none() {
                d.tag.clone_from(&old.tag);
                d.descriptor.clone_from(&old.descriptor);
            }
            if d.long_tag.is_none() {
                d.long_tag.clone_from(&old.long_tag);
            }
        }
        let j = device_json(&d);
        self.devices.insert(id, d);
        j
    }

    async fn device(&mut self, unique_id: &str) -> Result<DeviceInfo, Failure> {
        if let Some(d) = self.devices.get(unique_id) {
            return Ok(d.clone());
        }
        let id = hart_proto::UniqueId::parse_hex(unique_id)
            .map_err(|e| Failure::Other(format!("unique ID {unique_id:?}: {e}")))?;
        let d = self.client.resolve(&DeviceRef::UniqueId(id)).await?;
        self.remember(&d);
        Ok(d)
    }

    async fn run(&mut self, op: Op) -> Outcome {
        match op {
            Op::Scan { first, last } => {
                let found = self.client.scan(first..=last, |_| {}).await?;
                Ok(Value::Array(
                    found.iter().map(|d| self.remember(d)).collect(),
                ))
            }
            Op::Resolve(r) => {
                let mut d = self.client.resolve(&r).await?;
                if d.tag.is_none() {
                    self.client.read_tags(&mut d).await;
                }
                Ok(self.remember(&d))
            }
            Op::Command {
                unique_id,
                command,
                data,
            } => {
                let d = self.device(&unique_id).await?;
                let r = self.client.command(&d, command, &data).await?;
                Ok(reply_json(command, &r))
            }
            Op::Write {
                unique_id,
                what,
                args,
            } => {
                let d = self.device(&unique_id).await?;
                let write = self.client.write_request(&d, &what, &args).await?;
                let (command, confirm) = (write.request.command(), write.read_back.command());
                let r = self.client.request(&d, &write.request).await?;
                let back = self.client.request(&d, &write.read_back).await?;
                Ok(json!({
                    "reply": reply_json(command, &r),
                    "read_back": reply_json(confirm, &back),
                }))
            }
            Op::Listen { seconds } => {
                self.client
                    .listen((seconds.clamp(0.0, 86_400.0) * 1e6) as u64)
                    .await?;
                let bursts = self.client.take_bursts();
                Ok(Value::Array(
                    bursts
                        .iter()
                        .map(|b| json!(hart_proto::hex::compact(b)))
                        .collect(),
                ))
            }
        }
    }
}

/// A connection to a loop, run on its own thread.
#[pyclass(module = "hartkit._native")]
pub struct NativeLoop {
    tx: Option<mpsc::UnboundedSender<(Op, oneshot::Sender<Outcome>)>>,
    description: String,
}

impl NativeLoop {
    fn submit(&self, op: Op) -> PyResult<oneshot::Receiver<Outcome>> {
        let tx = self
            .tx
            .as_ref()
            .ok_or_else(|| TargetError::new_err("the connection is closed"))?;
        let (done, rx) = oneshot::channel();
        tx.send((op, done))
            .map_err(|_| TargetError::new_err("the connection's thread has ended"))?;
        Ok(rx)
    }

    fn finish(
        py: Python<'_>,
        r: Result<Outcome, oneshot::error::RecvError>,
    ) -> PyResult<Py<PyAny>> {
        match r {
            Ok(Ok(v)) => to_py(py, &v),
            Ok(Err(f)) => Err(f.into_py(py)),
            Err(_) => Err(TargetError::new_err("the connection's thread has ended")),
        }
    }

    /// The operation as an awaitable.
    fn later<'py>(&self, py: Python<'py>, op: Op) -> PyResult<Bound<'py, PyAny>> {
        let rx = self.submit(op)?;
        pyo3_async_runtimes::tokio::future_into_py(py, async move {
            let r = rx.await;
            Python::attach(|py| NativeLoop::finish(py, r))
        })
    }

    /// The operation, waited for with the GIL released.
    fn now(&self, py: Python<'_>, op: Op) -> PyResult<Py<PyAny>> {
        let rx = self.submit(op)?;
        let r = py.detach(|| rx.blocking_recv());
        NativeLoop::finish(py, r)
    }
}

/// An operation from its name and Python arguments (see [`NativeLoop::call`]).
fn parse_op(op: &str, args: &Bound<'_, PyTuple>) -> PyResult<Op> {
    let bad = || {
        pyo3::exceptions::PyValueError::new_err(format!(
            "{op}{args}: expected scan(first, last), resolve(kind, value), command(unique_id, command, data), write(unique_id, what, values) or listen(seconds)"
        ))
    };
    Ok(match (op, args.len()) {
        ("scan", 2) => Op::Scan {
            first: args.get_item(0)?.extract()?,
            last: args.get_item(1)?.extract()?,
        },
        ("resolve", 2) => {
            let kind: String = args.get_item(0)?.extract()?;
            Op::Resolve(device_ref(&kind, &args.get_item(1)?)?)
        }
        ("command", 3) => Op::Command {
            unique_id: args.get_item(0)?.extract()?,
            command: args.get_item(1)?.extract()?,
            data: args.get_item(2)?.extract()?,
        },
        ("write", 3) => Op::Write {
            unique_id: args.get_item(0)?.extract()?,
            what: args.get_item(1)?.extract()?,
            args: args.get_item(2)?.extract()?,
        },
        ("listen", 1) => Op::Listen {
            seconds: args.get_item(0)?.extract()?,
        },
        _ => return Err(bad()),
    })
}

fn device_ref(kind: &str, value: &Bound<'_, PyAny>) -> PyResult<DeviceRef> {
    Ok(match kind {
        "poll" => DeviceRef::Poll(value.extract()?),
        "tag" => DeviceRef::Tag(value.extract()?),
        "long_tag" => DeviceRef::LongTag(value.extract()?),
        "unique_id" => {
            let s: String = value.extract()?;
            DeviceRef::UniqueId(hart_proto::UniqueId::parse_hex(&s).map_err(|e| {
                pyo3::exceptions::PyValueError::new_err(format!("unique ID {s:?}: {e}"))
            })?)
        }
        other => {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "{other}: say poll, tag, long_tag or unique_id"
            )))
        }
    })
}

#[pymethods]
impl NativeLoop {
    /// What the connection is ("simulated plant of 4 device(s) (virtual time)").
    #[getter]
    fn description(&self) -> &str {
        &self.description
    }

    /// Runs operation `op` with `args`, as an awaitable of its result:
    ///
    /// * `"scan", (first, last)`: the devices at polling addresses `first..=last`
    ///   (a list of device dicts);
    /// * `"resolve", (kind, value)`: the device by `kind` "poll", "tag", "long_tag" or
    ///   "unique_id" (a device dict);
    /// * `"command", (unique_id, command, data)`: the reply dict;
    /// * `"write", (unique_id, what, [values])`: as `hartkit write WHAT VALUES`
    ///   (tag, long-tag, descriptor, message, date, range, units, damping, ...):
    ///   {"reply", "read_back"};
    /// * `"listen", (seconds,)`: the burst frames heard (PDUs as hex).
    fn call<'py>(
        &self,
        py: Python<'py>,
        op: &str,
        args: &Bound<'py, PyTuple>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let op = parse_op(op, args)?;
        self.later(py, op)
    }

    /// `call`, blocking (the GIL released while it waits).
    fn call_blocking(
        &self,
        py: Python<'_>,
        op: &str,
        args: &Bound<'_, PyTuple>,
    ) -> PyResult<Py<PyAny>> {
        let op = parse_op(op, args)?;
        self.now(py, op)
    }

    /// Closes the connection (the thread ends once the operation in progress is done).
    fn close(&mut self) {
        self.tx = None;
    }
}

/// Opens `target` (anything `hartkit --port` takes) as the primary master, or the
/// secondary; `psk` ("IDENTITY:HEXKEY") for tls:// and dtls:// targets. Blocks, with
/// the GIL released, until the target is open.
#[pyfunction]
#[pyo3(signature = (target, *, secondary = false, psk = None))]
pub fn open_loop(
    py: Python<'_>,
    target: String,
    secondary: bool,
    psk: Option<String>,
) -> PyResult<NativeLoop> {
    let psk = psk
        .map(|p| hart_ip_tls::Psk::parse(&p))
        .transpose()
        .map_err(TargetError::new_err)?;
    let (opened_tx, opened_rx) = oneshot::channel::<Result<String, String>>();
    let (tx, mut rx) = mpsc::unbounded_channel::<(Op, oneshot::Sender<Outcome>)>();
    std::thread::Builder::new()
        .name(format!("hartkit {target}"))
        .spawn(move || {
            let rt = match crate::thread_runtime() {
                Ok(rt) => rt,
                Err(e) => {
                    let _ = opened_tx.send(Err(e));
                    return;
                }
            };
            rt.block_on(async move {
                let role = if secondary {
                    hart_proto::MasterKind::Secondary
                } else {
                    hart_proto::MasterKind::Primary
                };
                let client = match hart_host::target::connect(&target, psk.as_ref(), role).await {
                    Ok(c) => c,
                    Err(e) => {
                        let _ = opened_tx.send(Err(e.to_string()));
                        return;
                    }
                };
                use hart_host::transport::Transport as _;
                let _ = opened_tx.send(Ok(client.transport().describe()));
                let mut w = Worker {
                    client,
                    devices: HashMap::new(),
                };
                while let Some((op, done)) = rx.recv().await {
                    let r = w.run(op).await;
                    let _ = done.send(r);
                }
            });
        })
        .map_err(|e| TargetError::new_err(format!("cannot start a thread: {e}")))?;
    match py.detach(|| opened_rx.blocking_recv()) {
        Ok(Ok(description)) => Ok(NativeLoop {
            tx: Some(tx),
            description,
        }),
        Ok(Err(m)) => Err(TargetError::new_err(m)),
        Err(_) => Err(TargetError::new_err(
            "the connection's thread ended while opening",
        )),
    }
}
