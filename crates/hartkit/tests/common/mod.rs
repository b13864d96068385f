//! Helpers shared by the integration tests.
#![allow(dead_code)]

use serde_json::Value;

/// `hartkit capture read FILE --json`, which must succeed: one object per frame.
pub fn capture_read(file: &std::path::Path) -> Vec<Value> {
    let (code, out, err) = hartkit(&["capture", "read", file.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0, "{err}");
    out.lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect()
}

/// A child process killed and reaped when dropped, whatever happens in the test (a
/// failed assertion included).
pub struct Kill(pub std::process::Child);

impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `hartkit sim serve --pty ARGS`: simulated devices on a pseudo-terminal, killed when
/// dropped; `pty` is the path it prints first.
pub struct SimPty {
    /// The pseudo-terminal's path, for `-p`.
    pub pty: String,
    _child: Kill,
}

/// Starts `hartkit sim serve --pty ARGS` and waits for the pseudo-terminal it names.
pub fn sim_pty(args: &[&str]) -> SimPty {
    use std::io::BufRead;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["sim", "serve", "--pty"])
        .args(args)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    std::io::BufReader::new(child.stdout.as_mut().unwrap())
        .read_line(&mut first)
        .unwrap();
    let child = Kill(child);
    let pty = first
        .trim()
        .strip_prefix("pty: ")
        .unwrap_or_else(|| panic!("the first line names the pty: {first:?}"))
        .to_string();
    SimPty { pty, _child: child }
}

/// `hartkit serve --hart-ip 127.0.0.1:0 ...` on a free port; killed when dropped. `.1`
/// is the port (UDP and TCP), read from the first line the server prints.
pub struct Server(pub std::process::Child, pub u16);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `hartkit serve --hart-ip 127.0.0.1:0` with `extra` arguments.
pub fn serve(extra: &[&str]) -> Server {
    use std::io::BufRead;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["serve", "--hart-ip", "127.0.0.1:0", "--run-for", "300"])
        .args(extra)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    let _ = std::io::BufReader::new(child.stdout.take().unwrap()).read_line(&mut line);
    // "hart-ip: udp 127.0.0.1:PORT tcp 127.0.0.1:PORT" ("-" for a transport not served).
    let port = line
        .split_whitespace()
        .find(|t| t.contains(':') && !t.ends_with(':'))
        .and_then(|a| a.rsplit(':').next())
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("server did not start: {line:?}"));
    Server(child, port)
}

/// The workspace root.
pub fn workspace() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The interop venv's python (`scripts/interop/setup`), if `module` imports there.
/// Without it the caller skips its check, unless `HARTKIT_REQUIRE_INTEROP=1` (set by
/// `.ci/run` once the install worked), where this fails the test.
pub fn interop_python(module: &str) -> Option<std::path::PathBuf> {
    let venv = std::env::var_os("HARTKIT_INTEROP_VENV")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| workspace().join("target/interop-venv"));
    let py = venv.join("bin/python");
    let ok = std::process::Command::new(&py)
        .args(["-c", &format!("import {module}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        return Some(py);
    }
    assert!(
        std::env::var("HARTKIT_REQUIRE_INTEROP").as_deref() != Ok("1"),
        "{module} is not installed in {} although HARTKIT_REQUIRE_INTEROP=1; run scripts/interop/setup",
        venv.display()
    );
    eprintln!(
        "{module} not installed ({}); skipping this interop check (scripts/interop/setup installs it)",
        venv.display()
    );
    None
}

/// Runs the outside client `scripts/interop/SCRIPT ARGS` with the interop venv's
/// python `py` (a separate process, never imported): its standard output, or both of
/// its outputs when it fails.
pub fn interop_script(py: &std::path::Path, script: &str, args: &[&str]) -> Result<String, String> {
    let out = std::process::Command::new(py)
        .arg(workspace().join("scripts/interop").join(script))
        .args(args)
        .output()
        .map_err(|e| format!("{script}: {e}"))?;
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    if !out.status.success() {
        return Err(format!(
            "{script} failed:\n{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(stdout)
}

/// [`interop_script`] for a client that prints one JSON object last: that object
/// (a failure or anything else panics with the client's output).
pub fn interop_json(py: &std::path::Path, script: &str, args: &[&str]) -> Value {
    let stdout = interop_script(py, script, args).unwrap_or_else(|e| panic!("{e}"));
    let line = stdout.lines().last().unwrap_or("");
    serde_json::from_str(line).unwrap_or_else(|e| panic!("{script}: {e}: {stdout}"))
}

/// `hartkit serve ARGS --run-for 300`, killed when dropped, and the addresses its front
/// ends printed, by name (`hart-ip` its UDP address, `modbus` its TCP address,
/// `modbus-rtu` its serial port, `opcua` its endpoint URL).
pub struct Gateway(
    pub std::process::Child,
    pub std::collections::HashMap<String, String>,
);

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `hartkit serve ARGS` and reads the `front_ends` lines it prints first.
pub fn gateway(args: &[&str], front_ends: usize) -> Gateway {
    use std::io::BufRead;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .arg("serve")
        .args(args)
        .args(["--run-for", "300"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut addrs = std::collections::HashMap::new();
    for _ in 0..front_ends {
        let mut line = String::new();
        out.read_line(&mut line).unwrap();
        // "hart-ip: udp ADDR tcp ADDR", "hart-ip plain: udp ADDR tcp ADDR (read-only)",
        // "modbus: tcp ADDR (floats abcd)",
        // "modbus-rtu: PATH 19200 8N1", "opcua: opc.tcp://HOST:PORT/"
        // The name runs to the first word ending in ':' ("hart-ip plain: udp ...").
        let mut words = line.split_whitespace();
        let mut name = vec![];
        for w in words.by_ref() {
            name.push(w.trim_end_matches(':'));
            if w.ends_with(':') {
                break;
            }
        }
        let name = name.join(" ");
        let addr = words
            .find(|w| w.contains(':') || w.starts_with('/'))
            .unwrap_or_else(|| panic!("gateway did not start: {line:?}"));
        addrs.insert(name, addr.to_string());
    }
    Gateway(child, addrs)
}

/// Runs the `hartkit` binary with `args`: exit status, standard output, standard error.
pub fn hartkit(args: &[&str]) -> (i32, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Compares `expected` against `actual`: every key of an expected object must be present
/// with an equal value (extra keys in `actual` are fine); floats are compared as `f32`;
/// the string "nan" or a NaN float expects `null` (non-finite floats are JSON null).
pub fn subset(expected: &Value, actual: &Value, path: &str) -> Result<(), String> {
    match (expected, actual) {
        (Value::Object(e), Value::Object(a)) => {
            for (k, ev) in e {
                let av = a
                    .get(k)
                    .ok_or_else(|| format!("{path}.{k}: missing (got {actual})"))?;
                subset(ev, av, &format!("{path}.{k}"))?;
            }
            Ok(())
        }
        (Value::Array(e), Value::Array(a)) => {
            if e.len() != a.len() {
                return Err(format!(
                    "{path}: expected {} items, got {}",
                    e.len(),
                    a.len()
                ));
            }
            e.iter()
                .zip(a)
                .enumerate()
                .try_for_each(|(i, (e, a))| subset(e, a, &format!("{path}[{i}]")))
        }
        (Value::Number(e), Value::Number(a)) if e.is_f64() || a.is_f64() => {
            let (e, a) = (
                e.as_f64().unwrap_or(f64::NAN),
                a.as_f64().unwrap_or(f64::NAN),
            );
            if e as f32 == a as f32 || (e - a).abs() <= 1e-6 * e.abs().max(1.0) {
                Ok(())
            } else {
                Err(format!("{path}: expected {e}, got {a}"))
            }
        }
        (Value::String(s), Value::Null) if s.eq_ignore_ascii_case("nan") => Ok(()),
        (Value::String(e), Value::String(a))
            if e.eq_ignore_ascii_case(a) && path.ends_with("data") =>
        {
            Ok(())
        }
        _ if expected == actual => Ok(()),
        _ => Err(format!("{path}: expected {expected}, got {actual}")),
    }
}

/// Converts a TOML value to JSON (NaN floats become the string "nan").
pub fn toml_to_json(v: &toml::Value) -> Value {
    match v {
        toml::Value::String(s) => Value::String(s.clone()),
        toml::Value::Integer(i) => Value::from(*i),
        toml::Value::Float(f) if f.is_nan() => Value::String("nan".into()),
        toml::Value::Float(f) => {
            serde_json::Number::from_f64(*f).map_or(Value::Null, Value::Number)
        }
        toml::Value::Boolean(b) => Value::Bool(*b),
        toml::Value::Datetime(d) => Value::String(d.to_string()),
        toml::Value::Array(a) => Value::Array(a.iter().map(toml_to_json).collect()),
        toml::Value::Table(t) => Value::Object(
            t.iter()
                .map(|(k, v)| (k.clone(), toml_to_json(v)))
                .collect(),
        ),
    }
}

/// The public vectors file.
pub fn public_vectors() -> Vec<toml::Value> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../hart-proto/tests/vectors/public.toml"
    );
    let text = std::fs::read_to_string(path).expect("public.toml");
    let doc: toml::Value = toml::from_str(&text).expect("public.toml parses");
    doc.get("vector")
        .and_then(|v| v.as_array())
        .cloned()
        .unwrap_or_default()
}

// Not every test binary that includes this module opens a serial line.
#[allow(unused_imports)]
pub use hart_testkit::pty_pair;
