//! A loop test never outlives the gateway: `hartkit serve` over three simulated
//! devices, each alone on its own pseudo-terminal at 1200 bit/s (polling address 0,
//! its loop current live), one fixed through the Modbus `fixed_current` register, one
//! through the web dashboard's loop test and one through the OPC UA `LoopTest` method
//! (called by asyncua, when the interop venv is there); then SIGTERM, as a service
//! manager stops it. Afterwards each device, read directly on its own port (not
//! through the gateway), drives its live current again, and the audit file has each
//! release with its outcome.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

mod common;
use common::{gateway, hartkit, sim_pty};

/// `hartkit sim serve --pty --profile pressure --poll 0`.
fn device() -> common::SimPty {
    sim_pty(&["--profile", "pressure", "--poll", "0"])
}

/// Modbus TCP "write multiple registers" of `value` (a float, high word first) at
/// holding register `register` of `unit`; the function code of the answer (0x10, or
/// 0x90 for an exception).
fn modbus_write_float(addr: &str, unit: u8, register: u16, value: f32) -> u8 {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let v = value.to_be_bytes();
    let mut req = vec![0, 1, 0, 0, 0, 11, unit, 0x10];
    req.extend_from_slice(&register.to_be_bytes());
    req.extend_from_slice(&[0, 2, 4]);
    req.extend_from_slice(&v);
    s.write_all(&req).unwrap();
    let mut head = [0u8; 8];
    s.read_exact(&mut head).unwrap();
    head[7]
}

/// One HTTP/1.1 request with `Connection: close`: status and body.
fn http(
    addr: &str,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &str,
) -> (u16, String, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let mut req = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nOrigin: http://{addr}\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {}\r\n",
        body.len()
    );
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    req.push_str("\r\n");
    req.push_str(body);
    s.write_all(req.as_bytes()).unwrap();
    let mut out = String::new();
    let _ = s.read_to_string(&mut out);
    let (head, body) = out.split_once("\r\n\r\n").unwrap_or((&out, ""));
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    (status, head.to_string(), body.to_string())
}

/// `hartkit read -p PTY --poll 0 WHAT --json`: read directly on the device's port.
fn read_direct(pty: &str, what: &str) -> serde_json::Value {
    let (code, out, err) = hartkit(&["read", "-p", pty, "--poll", "0", what, "--json"]);
    assert_eq!(code, 0, "{out}{err}");
    serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}"))
}

#[test]
fn sigterm_releases_every_loop_test_before_the_gateway_ends() {
    let (a, b, c) = (device(), device(), device());
    let asyncua = common::interop_python("asyncua");
    let dir = tempfile::tempdir().unwrap();
    let pki = dir.path().join("pki");
    let password = dir.path().join("password");
    std::fs::write(&password, "loop-test-secret\n").unwrap();
    let audit = dir.path().join("audit.jsonl");
    let mut gw = gateway(
        &[
            "--port",
            &a.pty,
            "--port",
            &b.pty,
            "--port",
            &c.pty,
            "--scan-to",
            "0",
            "--modbus",
            "127.0.0.1:0",
            "--modbus-write-from",
            "127.0.0.0/8",
            "--web",
            "127.0.0.1:0",
            "--web-admin-password-file",
            password.to_str().unwrap(),
            "--audit-file",
            audit.to_str().unwrap(),
            "--opcua",
            "127.0.0.1:0",
            "--opcua-pki",
            pki.to_str().unwrap(),
        ],
        3,
    );
    let modbus = gw.1["modbus"].clone();
    let web = gw.1["web"]
        .trim_start_matches("http://")
        .trim_end_matches('/')
        .to_string();
    // Both devices found and polled.
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        let (_, _, body) = http(&web, "GET", "/api/devices", &[], "");
        let v: serde_json::Value = serde_json::from_str(&body).unwrap_or_default();
        let ok = v["devices"]
            .as_array()
            .is_some_and(|d| d.len() == 3 && d.iter().all(|d| d["quality"] == "good"));
        if ok {
            break;
        }
        assert!(Instant::now() < end, "the devices were not polled: {body}");
        std::thread::sleep(Duration::from_millis(300));
    }
    // Devices are numbered (Modbus unit, web id) in the order the scan found them,
    // which need not be the order of the ports: each is found by its loop.
    let (_, _, body) = http(&web, "GET", "/api/devices", &[], "");
    let devices: serde_json::Value = serde_json::from_str(&body).unwrap();
    let unit_of = |loop_name: &str| -> u64 {
        devices["devices"]
            .as_array()
            .unwrap()
            .iter()
            .find(|d| d["loop"] == loop_name)
            .and_then(|d| d["unit"].as_u64())
            .unwrap_or_else(|| panic!("no device on {loop_name}: {devices}"))
    };
    let (unit1, unit2) = (unit_of("loop1"), unit_of("loop2"));
    // Modbus: 5 mA on the first loop's device.
    assert_eq!(modbus_write_float(&modbus, unit1 as u8, 6, 5.0), 0x10);
    // Web: log in, then a 10-minute loop test at 6 mA on the second loop's device.
    let (status, head, body) = http(
        &web,
        "POST",
        "/api/login",
        &[],
        r#"{"password": "loop-test-secret"}"#,
    );
    assert_eq!(status, 200, "{head}{body}");
    let cookie = head
        .lines()
        .find_map(|l| {
            l.strip_prefix("set-cookie: ")
                .or_else(|| l.strip_prefix("Set-Cookie: "))
        })
        .and_then(|c| c.split(';').next())
        .unwrap()
        .to_string();
    let csrf = serde_json::from_str::<serde_json::Value>(&body).unwrap()["csrf"]
        .as_str()
        .unwrap()
        .to_string();
    let (status, _, body) = http(
        &web,
        "POST",
        &format!("/api/devices/{unit2}/write"),
        &[("Cookie", &cookie), ("X-CSRF-Token", &csrf)],
        r#"{"loop_test_ma": 6, "release_after_s": 600}"#,
    );
    assert_eq!(status, 200, "{body}");
    // OPC UA: 7 mA on the third loop's device.
    let mut fixed = vec![(&a.pty, 5.0), (&b.pty, 6.0)];
    if let Some(py) = &asyncua {
        let r = common::interop_json(
            py,
            "asyncua_loop_test.py",
            &["--url", &gw.1["opcua"], "--loop", "loop3", "--ma", "7"],
        );
        assert_eq!(r["loop_test"], "ok", "{r}");
        fixed.push((&c.pty, 7.0));
    }
    // Fixed, as the gateway shows them.
    let (_, _, body) = http(&web, "GET", "/api/devices", &[], "");
    let v: serde_json::Value = serde_json::from_str(&body).unwrap();
    let on = |loop_name: &str| {
        v["devices"]
            .as_array()
            .unwrap()
            .iter()
            .find(|d| d["loop"] == loop_name)
            .cloned()
            .unwrap()
    };
    assert_eq!(on("loop1")["fixed_current"], 5.0, "{body}");
    assert_eq!(on("loop2")["fixed_current"], 6.0, "{body}");
    assert!(on("loop2")["loop_test"]["release_at"].is_string(), "{body}");

    // SIGTERM, as systemd's stop.
    let pid = gw.0.id().to_string();
    assert!(std::process::Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .unwrap()
        .success());
    let end = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(s) = gw.0.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < end, "the gateway did not stop");
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(status.success(), "{status}");

    // Each device, read on its own port: its loop current follows the process again
    // (not 5 or 6 mA) and its status says nothing of a fixed current (bit 3).
    for &(pty, fixed) in &fixed {
        let r = read_direct(pty, "status");
        let status = r["device_status"].as_u64().unwrap();
        assert_eq!(status & 0x08, 0, "loop current still fixed: {r}");
        let r = read_direct(pty, "dynamic");
        let current = r["loop_current"].as_f64().unwrap();
        assert!((current - fixed).abs() > 0.01, "{r}");
    }
    // The audit: each release with its outcome, the engine's own write.
    let audit = std::fs::read_to_string(&audit).unwrap();
    let releases: Vec<serde_json::Value> = audit
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["identity"] == "loop test release" && v["outcome"] == "done")
        .collect();
    assert_eq!(releases.len(), fixed.len(), "{audit}");
    assert!(releases
        .iter()
        .all(|r| r["via"].as_str().unwrap().starts_with("gateway stopping")));
}

/// A read-only gateway refuses a write on every public way to its device: a Modbus
/// register (exception 1), the web dashboard's API (403), a frame through HART-IP
/// (response code 16 "access restricted", also inside command 77's path to the loop)
/// and the OPC UA LoopTest method (BadUserAccessDenied, when the interop venv is
/// there); afterwards the device, read on its own port, has no fixed current and its
/// damping unchanged. (Read-write, each of these is audited with its outcome: the test
/// above, crates/hart-ip-server/tests/access.rs and crates/hart-poller/tests/gate.rs.)
#[test]
fn a_read_only_gateway_refuses_every_path_to_the_device() {
    let a = device();
    let asyncua = common::interop_python("asyncua");
    let dir = tempfile::tempdir().unwrap();
    let pki = dir.path().join("pki");
    let password = dir.path().join("password");
    std::fs::write(&password, "read-only-secret\n").unwrap();
    let before = read_direct(&a.pty, "info");
    let gw = gateway(
        &[
            "--port",
            &a.pty,
            "--scan-to",
            "0",
            "--read-only",
            "--transparent",
            "--hart-ip",
            "127.0.0.1:0",
            "--modbus",
            "127.0.0.1:0",
            "--modbus-write-from",
            "127.0.0.0/8",
            "--web",
            "127.0.0.1:0",
            "--web-admin-password-file",
            password.to_str().unwrap(),
            "--opcua",
            "127.0.0.1:0",
            "--opcua-pki",
            pki.to_str().unwrap(),
        ],
        4,
    );
    let web = gw.1["web"]
        .trim_start_matches("http://")
        .trim_end_matches('/')
        .to_string();
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        let (_, _, body) = http(&web, "GET", "/api/devices", &[], "");
        let v: serde_json::Value = serde_json::from_str(&body).unwrap_or_default();
        if v["devices"][0]["quality"] == "good" {
            break;
        }
        assert!(Instant::now() < end, "the device was not polled: {body}");
        std::thread::sleep(Duration::from_millis(300));
    }
    // Modbus: the fixed_current register, refused with exception 1.
    assert_eq!(modbus_write_float(&gw.1["modbus"], 1, 6, 5.0), 0x90);
    // The web API: refused whoever asks.
    let (status, _, body) = http(
        &web,
        "POST",
        "/api/devices/1/write",
        &[],
        r#"{"loop_test_ma": 6, "release_after_s": 60}"#,
    );
    assert_eq!(status, 403, "{body}");
    assert!(body.contains("read-only"), "{body}");
    // HART-IP, the device answering at polling address 0 (--transparent): a fixed
    // current and a damping refused by the gateway, the device never asked.
    let target = format!("udp://{}", gw.1["hart-ip"]);
    for (what, value) in [("fixed-current", "5"), ("damping", "3.5")] {
        let (code, out, err) = hartkit(&["write", "-p", &target, "--poll", "0", what, value]);
        assert_ne!(code, 0, "{what} let through: {out}{err}");
        assert!(
            format!("{out}{err}")
                .to_lowercase()
                .contains("access restricted"),
            "{what}: {out}{err}"
        );
    }
    // OPC UA: the LoopTest method.
    if let Some(py) = &asyncua {
        let r = common::interop_json(
            py,
            "asyncua_loop_test.py",
            &["--url", &gw.1["opcua"], "--loop", "loop1", "--ma", "7"],
        );
        assert_eq!(r["loop_test"], "BadUserAccessDenied", "{r}");
    }
    drop(gw);
    // The device, on its own port: nothing changed.
    let r = read_direct(&a.pty, "status");
    assert_eq!(r["device_status"].as_u64().unwrap() & 0x08, 0, "{r}");
    let after = read_direct(&a.pty, "info");
    assert!(before["damping"].is_number(), "{before}");
    assert_eq!(before["damping"], after["damping"], "{after}");
}
