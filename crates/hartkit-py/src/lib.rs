//! `hartkit._native`: the Rust half of the `hartkit` Python package.
//!
//! * [`Frame`]: parse, build and decode frames with hart-proto, the decoded data as
//!   Python dicts with units and codes in words.
//! * `NativeLoop` (module `host`): a HART master on any target the CLI takes (serial modem, RS-485,
//!   HART-IP, a simulated plant), run by `hart-host` on its own thread; each operation
//!   comes back both as an awaitable (asyncio) and as a blocking call that releases the
//!   GIL. The Python modules `hartkit` and `hartkit.sync` wrap it.
//! * `sim_bench`: the network simulation, with the same figures as `hartkit sim bench
//!   --json`.
//!
//! Errors are exceptions under `hartkit.HartError` carrying the CLI's explanations.

use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyBytes;

mod host;
mod pyvisit;
mod sim;

create_exception!(
    _native,
    HartError,
    PyException,
    "Every error hartkit raises: what happened and what to check."
);
create_exception!(
    _native,
    FrameError,
    HartError,
    "Bytes that are not a HART frame, or data a command's layout cannot hold."
);
create_exception!(
    _native,
    DeviceError,
    HartError,
    "The device answered with an error response code (`response_code`, `command`)."
);
create_exception!(
    _native,
    NoReplyError,
    HartError,
    "No reply, or only damaged ones, after every retry."
);
create_exception!(
    _native,
    TargetError,
    HartError,
    "The target cannot be opened, or the connection is closed."
);

/// A single-threaded tokio runtime for a connection's or a server's own thread.
pub(crate) fn thread_runtime() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the runtime: {e}"))
}

/// JSON (as hartkit builds it) to Python objects.
pub(crate) fn to_py(py: Python<'_>, v: &serde_json::Value) -> PyResult<Py<PyAny>> {
    pythonize::pythonize(py, v)
        .map(Bound::unbind)
        .map_err(|e| HartError::new_err(e.to_string()))
}

/// A HART frame: parsed from bytes, or built.
#[pyclass(module = "hartkit._native", frozen, eq)]
#[derive(PartialEq)]
pub struct Frame {
    /// Preambles through check byte (and anything after it), checked to parse.
    bytes: Vec<u8>,
}

impl Frame {
    fn parsed(&self) -> hart_proto::Frame<'_> {
        // Checked when the object was made.
        hart_proto::Frame::parse(&self.bytes).expect("a Frame holds a frame")
    }

    fn make(bytes: Vec<u8>) -> PyResult<Self> {
        hart_proto::Frame::parse(&bytes).map_err(|e| FrameError::new_err(e.to_string()))?;
        Ok(Frame { bytes })
    }

    fn build(spec: &hart_proto::FrameSpec<'_>) -> PyResult<Self> {
        if spec.preambles > hart_proto::frame::MAX_PREAMBLES {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "preambles: {} is too many (at most {}; HART devices ask 5 to 20)",
                spec.preambles,
                hart_proto::frame::MAX_PREAMBLES
            )));
        }
        if spec.data.len() > 255 {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "data: {} bytes, at most 255 in a frame (less for extended commands and replies)",
                spec.data.len()
            )));
        }
        let mut buf = vec![0u8; spec.encoded_len()];
        let n = spec
            .encode(&mut buf)
            .map_err(|e| FrameError::new_err(e.to_string()))?;
        buf.truncate(n);
        Frame::make(buf)
    }
}

/// `address`: a polling address (0-63) for a short frame, or a unique ID (10 hex
/// digits) for a long one.
fn address(a: &Bound<'_, PyAny>, secondary: bool, burst: bool) -> PyResult<hart_proto::Address> {
    let base =
        if let Ok(poll) = a.extract::<u8>() {
            if poll > 63 {
                return Err(PyValueError::new_err(format!(
                    "polling address {poll}: give 0-63, or a unique ID as 10 hex digits"
                )));
            }
            hart_proto::Address::short(poll)
        } else if let Ok(s) = a.extract::<String>() {
            hart_proto::Address::long(hart_proto::UniqueId::parse_hex(&s).map_err(|e| {
                PyValueError::new_err(format!("unique ID {s:?}: {e} (10 hex digits)"))
            })?)
        } else {
            return Err(PyValueError::new_err(
                "address: a polling address (int 0-63) or a unique ID (str, 10 hex digits)",
            ));
        };
    let master = if secondary {
        hart_proto::MasterKind::Secondary
    } else {
        hart_proto::MasterKind::Primary
    };
    let mut a = base.with_master(master);
    if burst {
        match &mut a {
            hart_proto::Address::Short(s) => s.burst = true,
            hart_proto::Address::Long(l) => l.burst = true,
        }
    }
    Ok(a)
}

#[pymethods]
impl Frame {
    /// Parses a frame (preambles optional) from `data`. Raises `FrameError` with what
    /// is wrong and where.
    #[staticmethod]
    fn parse(data: &[u8]) -> PyResult<Self> {
        Frame::make(data.to_vec())
    }

    /// A request (STX) to `address` (polling address or unique ID).
    #[staticmethod]
    #[pyo3(signature = (address, command, data = b"".as_slice(), *, preambles = 5, secondary = false))]
    fn request(
        address: &Bound<'_, PyAny>,
        command: u16,
        data: &[u8],
        preambles: usize,
        secondary: bool,
    ) -> PyResult<Self> {
        let a = self::address(address, secondary, false)?;
        let mut spec = hart_proto::FrameSpec::request(a, command, data);
        spec.preambles = preambles;
        Frame::build(&spec)
    }

    /// A reply (ACK), or with `burst` a burst frame (BACK), from `address`.
    #[staticmethod]
    #[pyo3(signature = (address, command, data = b"".as_slice(), *, response_code = 0, device_status = 0, preambles = 5, secondary = false, burst = false))]
    #[allow(clippy::too_many_arguments)]
    fn reply(
        address: &Bound<'_, PyAny>,
        command: u16,
        data: &[u8],
        response_code: u8,
        device_status: u8,
        preambles: usize,
        secondary: bool,
        burst: bool,
    ) -> PyResult<Self> {
        let a = self::address(address, secondary, burst)?;
        let mut spec = hart_proto::FrameSpec::reply(a, command, response_code, device_status, data);
        spec.preambles = preambles;
        if burst {
            spec.frame_type = hart_proto::FrameType::Back;
        }
        Frame::build(&spec)
    }

    /// The frame as sent on the wire, preambles included.
    fn to_bytes<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.bytes)
    }

    /// Delimiter through check byte.
    #[getter]
    fn pdu<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, self.parsed().pdu)
    }

    /// Preamble bytes before the delimiter.
    #[getter]
    fn preambles(&self) -> usize {
        self.parsed().preambles
    }

    /// "STX" (request), "ACK" (reply) or "BACK" (burst).
    #[getter]
    fn frame_type(&self) -> &'static str {
        self.parsed().frame_type().name()
    }

    /// Command number (the expanded one for command 31).
    #[getter]
    fn command(&self) -> u16 {
        self.parsed().command
    }

    /// Polling address of a short frame, else None.
    #[getter]
    fn polling_address(&self) -> Option<u8> {
        match self.parsed().address {
            hart_proto::Address::Short(s) => Some(s.polling_address),
            hart_proto::Address::Long(_) => None,
        }
    }

    /// Unique ID (10 hex digits) of a long frame, else None.
    #[getter]
    fn unique_id(&self) -> Option<String> {
        match self.parsed().address {
            hart_proto::Address::Long(l) => Some(l.id.to_string()),
            hart_proto::Address::Short(_) => None,
        }
    }

    /// "primary" or "secondary": the master that sent the request or is answered.
    #[getter]
    fn master(&self) -> &'static str {
        self.parsed().address.master().name()
    }

    /// Response code of a reply, else None.
    #[getter]
    fn response_code(&self) -> Option<u8> {
        self.parsed().response_code
    }

    /// Field device status of a reply, else None.
    #[getter]
    fn device_status(&self) -> Option<u8> {
        self.parsed().device_status
    }

    /// Data bytes (after the status bytes and any expanded command number).
    #[getter]
    fn data<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, self.parsed().data)
    }

    /// True when the check byte is right.
    #[getter]
    fn checksum_ok(&self) -> bool {
        self.parsed().checksum_ok()
    }

    /// The data decoded field by field (units, codes and status bits also in words),
    /// or None for a command hartkit does not type. Raises `FrameError` when the data
    /// does not fit the command's layout.
    #[getter]
    fn decoded(&self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        match hart_proto::decode::decode_body(&self.parsed()) {
            None => Ok(None),
            Some(Err(e)) => Err(FrameError::new_err(format!(
                "command {} data: {e}",
                self.command()
            ))),
            Some(Ok(d)) => {
                let mut v = pyvisit::PyVisitor::new(py);
                d.describe(&mut v);
                v.finish().map(|d| Some(d.into_any().unbind()))
            }
        }
    }

    /// The whole frame as a dict: the fields `hartkit frame decode --json` prints
    /// (docs/frame-json.md), with `decoded` in words.
    fn to_dict(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let f = self.parsed();
        let mut j = hart_proto::json::frame(&f);
        if let Some(Ok(d)) = hart_proto::decode::decode_body(&f) {
            let mut v = hart_proto::json::JsonVisitor::with_words();
            d.describe(&mut v);
            j["decoded"] = v.finish();
        }
        to_py(py, &j)
    }

    /// The annotated view of `hartkit frame decode`: every byte explained.
    fn explain(&self) -> String {
        hart_proto::annotate::frame(&self.parsed())
    }

    fn __bytes__<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        self.to_bytes(py)
    }

    fn __repr__(&self) -> String {
        let f = self.parsed();
        let addr = match f.address {
            hart_proto::Address::Short(s) => format!("poll {}", s.polling_address),
            hart_proto::Address::Long(l) => format!("unique ID {}", l.id),
        };
        format!(
            "<Frame {} command {} {} {}>",
            f.frame_type().name(),
            f.command,
            addr,
            hart_proto::hex::compact(f.pdu)
        )
    }
}

/// Decodes the data of a reply to `command` (after the status bytes) into a dict;
/// None for a command hartkit does not type.
#[pyfunction]
fn decode_reply(py: Python<'_>, command: u16, data: &[u8]) -> PyResult<Option<Py<PyAny>>> {
    decode(
        py,
        command,
        hart_proto::command::decode_response(command, data)
            .map(|r| r.map(hart_proto::decode::Decoded::Response)),
    )
}

/// Decodes the data of a request for `command` into a dict; None for a command hartkit
/// does not type.
#[pyfunction]
fn decode_request(py: Python<'_>, command: u16, data: &[u8]) -> PyResult<Option<Py<PyAny>>> {
    decode(
        py,
        command,
        hart_proto::command::decode_request(command, data)
            .map(|r| r.map(hart_proto::decode::Decoded::Request)),
    )
}

/// The request data of `command` built from its fields: a dict with the names
/// `decode_request` gives (units and codes also by name, the words beside them
/// ignored). Raises FrameError naming the field at fault, or when hartkit has no layout
/// for the command.
#[pyfunction]
fn encode_request(
    py: Python<'_>,
    command: u16,
    fields: &Bound<'_, PyAny>,
) -> PyResult<Py<PyBytes>> {
    let j = fields_json(fields)?;
    hart_proto::json::fields::request_bytes(command, &j)
        .map(|b| PyBytes::new(py, &b).unbind())
        .map_err(|e| FrameError::new_err(format!("command {command} request: {e}")))
}

/// The reply data of `command` (after the status bytes) built from its fields, the
/// names `decode_reply` gives. Raises FrameError as `encode_request` does.
#[pyfunction]
fn encode_reply(py: Python<'_>, command: u16, fields: &Bound<'_, PyAny>) -> PyResult<Py<PyBytes>> {
    let j = fields_json(fields)?;
    hart_proto::json::fields::response_bytes(command, &j)
        .map(|b| PyBytes::new(py, &b).unbind())
        .map_err(|e| FrameError::new_err(format!("command {command} reply: {e}")))
}

fn fields_json(fields: &Bound<'_, PyAny>) -> PyResult<serde_json::Value> {
    pythonize::depythonize(fields).map_err(|e| {
        FrameError::new_err(format!(
            "fields must be a dict of numbers, text, lists and dicts: {e}"
        ))
    })
}

fn decode(
    py: Python<'_>,
    command: u16,
    d: Option<Result<hart_proto::decode::Decoded, hart_proto::wire::DecodeError>>,
) -> PyResult<Option<Py<PyAny>>> {
    match d {
        None => Ok(None),
        Some(Err(e)) => Err(FrameError::new_err(format!("command {command} data: {e}"))),
        Some(Ok(d)) => {
            let mut v = pyvisit::PyVisitor::new(py);
            d.describe(&mut v);
            v.finish().map(|d| Some(d.into_any().unbind()))
        }
    }
}

/// A byte stream cut into frames, as a receiver does: feed it what a serial port or a
/// capture gives, in pieces of any size; it finds the preambles, follows each frame
/// to its check byte, resynchronises after garbage, and keeps count of what was
/// damaged.
#[pyclass(module = "hartkit._native")]
pub struct Deframer {
    inner: hart_proto::deframer::Deframer,
}

#[pymethods]
impl Deframer {
    #[new]
    fn new() -> Self {
        Deframer {
            inner: hart_proto::deframer::Deframer::default(),
        }
    }

    /// The frames completed by `data` (with a good check byte and no errors).
    fn feed(&mut self, data: &[u8]) -> Vec<Frame> {
        let mut out = Vec::new();
        self.inner.feed(data, |e| {
            if let hart_proto::deframer::DeframerEvent::Frame(f) = e {
                out.push(Frame {
                    bytes: f.pdu.to_vec(),
                });
            }
        });
        out
    }

    /// Good frames so far.
    #[getter]
    fn frames(&self) -> u64 {
        self.inner.stats().frames
    }

    /// Damaged frames so far (wrong check byte, UART errors, overflow).
    #[getter]
    fn damaged(&self) -> u64 {
        self.inner.stats().damaged
    }

    /// Structurally invalid frames so far.
    #[getter]
    fn invalid(&self) -> u64 {
        self.inner.stats().invalid
    }
}

/// Every command hartkit types: (number, name, title, kind, writes).
#[pyfunction]
fn command_table() -> Vec<(u16, &'static str, &'static str, &'static str, bool)> {
    hart_proto::command::COMMANDS
        .iter()
        .map(|c| {
            let kind = match c.kind {
                hart_proto::command::CommandKind::Universal => "universal",
                hart_proto::command::CommandKind::CommonPractice => "common-practice",
                hart_proto::command::CommandKind::Burst => "burst",
            };
            (c.number, c.name, c.title, kind, c.writes)
        })
        .collect()
}

/// An engineering unit code (Common Table 2): (symbol, name), or None when unknown.
#[pyfunction]
fn unit(code: u8) -> Option<(&'static str, &'static str)> {
    hart_proto::tables::unit(code).map(|u| (u.symbol, u.name))
}

/// The meaning of a response code for `command` ("Success", "Invalid selection", ...).
#[pyfunction]
#[pyo3(signature = (code, command = 0))]
fn response_code_name(code: u8, command: u16) -> Option<&'static str> {
    hart_proto::tables::response_code_name(command, code)
}

/// Runs the network simulation (`hartkit sim bench`): returns the dict `--json` prints.
#[pyfunction]
#[pyo3(signature = (*, devices = 15, duration = 60.0, secondary = false, burst = false, burst_period = 1.0, command = 3, ber = 0.0, seed = 1, analog = false, cable_m = 0.0))]
#[allow(clippy::too_many_arguments)]
fn sim_bench(
    py: Python<'_>,
    devices: u8,
    duration: f64,
    secondary: bool,
    burst: bool,
    burst_period: f64,
    command: u16,
    ber: f64,
    seed: u64,
    analog: bool,
    cable_m: f64,
) -> PyResult<Py<PyAny>> {
    if !(1..=63).contains(&devices) {
        return Err(PyValueError::new_err("devices: 1 to 63"));
    }
    if !(duration > 0.0 && duration <= 86_400.0) {
        return Err(PyValueError::new_err(
            "duration: more than 0, at most 86400 s",
        ));
    }
    if !(0.0..=0.5).contains(&ber) {
        return Err(PyValueError::new_err("ber: 0 to 0.5"));
    }
    if !(0.0..=100_000.0).contains(&cable_m) {
        return Err(PyValueError::new_err("cable_m: 0 to 100000"));
    }
    let cfg = hart_sim::SimConfig {
        devices,
        secondary,
        burst_period: burst.then_some((burst_period.clamp(0.05, 3600.0) * 1e6) as u64),
        command,
        duration: (duration * 1e6) as u64,
        ber,
        seed,
        medium: if analog {
            hart_sim::Medium::Analog {
                model: hart_sim::LoopModel {
                    cable_length_m: cable_m,
                    ..hart_sim::LoopModel::default()
                },
                options: hart_sim::LineOptions {
                    seed,
                    ..hart_sim::LineOptions::default()
                },
            }
        } else {
            hart_sim::Medium::Digital
        },
        ..hart_sim::SimConfig::default()
    };
    let (report, wall) = py.detach(|| {
        let t = std::time::Instant::now();
        let r = hart_sim::run(&cfg);
        (r, t.elapsed().as_secs_f64())
    });
    to_py(py, &report.to_json(&cfg, wall))
}

/// A key given from Python: 16 bytes, or 32 hex digits.
fn wireless_key(k: &Bound<'_, PyAny>, what: &str) -> PyResult<hart_wireless::Key> {
    if let Ok(b) = k.extract::<Vec<u8>>() {
        if let Ok(key) = <[u8; 16]>::try_from(b.as_slice()) {
            return Ok(key);
        }
    }
    if let Ok(text) = k.extract::<String>() {
        if let Some(key) = hart_wireless::crypto::parse_key(&text) {
            return Ok(key);
        }
    }
    Err(pyo3::exceptions::PyValueError::new_err(format!(
        "{what}: give 16 bytes or 32 hex digits, e.g. '41424344414243444142434441424344'"
    )))
}

/// Decodes a WirelessHART capture (the bytes of a pcap or pcapng file) whole: a dict
/// with `frames` (one dict per frame, as `hartkit wireless decode --json` prints them)
/// and `summary`. Keys learned from the traffic (commands 961, 963) are used for what
/// follows. Raises FrameError when the bytes are not a capture of 802.15.4 frames.
#[pyfunction]
#[pyo3(signature = (data, keys=Vec::new(), network_keys=Vec::new()))]
fn wireless_decode(
    py: Python<'_>,
    data: &[u8],
    keys: Vec<Bound<'_, PyAny>>,
    network_keys: Vec<Bound<'_, PyAny>>,
) -> PyResult<Py<PyAny>> {
    let join: Vec<hart_wireless::Key> = keys
        .iter()
        .map(|k| wireless_key(k, "a join key"))
        .collect::<PyResult<_>>()?;
    let network: Vec<hart_wireless::Key> = network_keys
        .iter()
        .map(|k| wireless_key(k, "a network key"))
        .collect::<PyResult<_>>()?;
    let (frames, stats) = py
        .detach(|| hart_wireless::decoder::decode_capture(data, &join, &network))
        .map_err(|e| FrameError::new_err(e.to_string()))?;
    let j = serde_json::json!({
        "frames": frames.iter().map(|f| f.to_json()).collect::<Vec<_>>(),
        "summary": stats.to_json(),
    });
    to_py(py, &j)
}

/// The `hartkit._native` module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<Frame>()?;
    m.add_class::<Deframer>()?;
    m.add_class::<host::NativeLoop>()?;
    m.add_class::<sim::SimServer>()?;
    m.add_function(wrap_pyfunction!(sim::serve_hart_ip, m)?)?;
    m.add_function(wrap_pyfunction!(decode_reply, m)?)?;
    m.add_function(wrap_pyfunction!(decode_request, m)?)?;
    m.add_function(wrap_pyfunction!(encode_request, m)?)?;
    m.add_function(wrap_pyfunction!(encode_reply, m)?)?;
    m.add_function(wrap_pyfunction!(command_table, m)?)?;
    m.add_function(wrap_pyfunction!(unit, m)?)?;
    m.add_function(wrap_pyfunction!(response_code_name, m)?)?;
    m.add_function(wrap_pyfunction!(sim_bench, m)?)?;
    m.add_function(wrap_pyfunction!(wireless_decode, m)?)?;
    m.add_function(wrap_pyfunction!(host::open_loop, m)?)?;
    m.add("HartError", py.get_type::<HartError>())?;
    m.add("FrameError", py.get_type::<FrameError>())?;
    m.add("DeviceError", py.get_type::<DeviceError>())?;
    m.add("NoReplyError", py.get_type::<NoReplyError>())?;
    m.add("TargetError", py.get_type::<TargetError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
