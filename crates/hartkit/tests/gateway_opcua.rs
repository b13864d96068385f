//! The gateway's OPC UA front end against an outside client: asyncua (LGPL, run as a
//! separate process by `scripts/interop/asyncua_client.py`) against `hartkit serve
//! --sim --modbus ... --opcua ...` on defaults (the demo plant on a simulated 1200
//! bit/s loop): it browses Objects/HART, reads every PV with its EngineeringUnits,
//! status and source time stamp, subscribes and counts changes, and calls methods (a
//! damping that lands on the device, read back over HART-IP; a loop test a multidrop
//! device refuses). Then the Basic256Sha256 endpoint, signed and encrypted, with a user
//! and password, and a wrong password refused.
//!
//! Without the interop venv the checks say so and pass, unless
//! `HARTKIT_REQUIRE_INTEROP=1`.

use std::path::PathBuf;
use std::process::Command;

mod common;
use common::{gateway, hartkit, workspace};

fn python() -> Option<PathBuf> {
    common::interop_python("asyncua")
}

fn client(py: &PathBuf, url: &str, extra: &[&str]) -> Result<serde_json::Value, String> {
    let out = Command::new(py)
        .arg(workspace().join("scripts/interop/asyncua_client.py"))
        .args(["--url", url])
        .args(extra)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(format!(
            "{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    let line = stdout.lines().last().unwrap_or("");
    serde_json::from_str(line).map_err(|e| format!("{e}: {stdout}"))
}

#[test]
fn asyncua_browses_reads_subscribes_and_calls_methods() {
    let Some(py) = python() else { return };
    let pki = std::env::temp_dir().join(format!("hartkit-ua-{}", std::process::id()));
    let gw = gateway(
        &[
            "--sim",
            "--hart-ip",
            "127.0.0.1:0",
            "--modbus",
            "127.0.0.1:0",
            "--opcua",
            "127.0.0.1:0",
            "--opcua-pki",
            pki.to_str().unwrap(),
        ],
        3,
    );
    let r = client(&py, &gw.1["opcua"], &["--damping", "2.0"]).unwrap_or_else(|e| panic!("{e}"));
    let devices = r["devices"].as_array().unwrap();
    assert_eq!(devices.len(), 4, "{r}");
    // By polling address: the demo plant's units and their UNECE codes.
    let expect = [
        (1, "kPa", "KPA"),
        (2, "°C", "CEL"),
        (3, "%", "P1"),
        (17, "kPa", "KPA"),
    ];
    for (poll, eu, unece) in expect {
        let d = devices
            .iter()
            .find(|d| d["polling_address"] == poll)
            .unwrap_or_else(|| panic!("no device at {poll}: {r}"));
        assert_eq!(d["eu"], eu, "{d}");
        let id = unece.bytes().fold(0i64, |id, c| (id << 8) | i64::from(c));
        assert_eq!(d["eu_unit_id"], id, "{d}");
        assert_eq!(
            d["eu_namespace"],
            "http://www.opcfoundation.org/UA/units/un/cefact"
        );
        assert_eq!(d["status"], "Good", "{d}");
        assert_eq!(d["type_definition"], "i=2368", "AnalogItemType: {d}");
        assert!(d["source_age_s"].as_f64().is_some_and(|a| a < 30.0), "{d}");
        assert!(d["path"].as_str().unwrap().starts_with("HART/sim/"), "{d}");
    }
    // Two pressure transmitters share the tag PT-100: names made unique.
    let mut paths: Vec<_> = devices
        .iter()
        .map(|d| d["path"].as_str().unwrap())
        .collect();
    paths.sort();
    assert_eq!(
        paths,
        [
            "HART/sim/FV-300",
            "HART/sim/PT-100",
            "HART/sim/PT-100_2",
            "HART/sim/TT-200"
        ]
    );
    assert!(
        r["changes"].as_u64().unwrap() >= 2,
        "subscription changes: {r}"
    );
    assert_eq!(r["set_damping"], "ok");
    assert_eq!(r["damping"], 2.0);
    assert_eq!(r["loop_test"], "BadDeviceFailure", "multidrop: {r}");
    assert_eq!(r["bad_argument"], "BadInvalidArgument");
    // The damping is on the device.
    let hip = format!("udp://{}", gw.1["hart-ip"]);
    let (code, out, err) = hartkit(&["read", "--port", &hip, "--poll", "1", "info", "--json"]);
    assert_eq!(code, 0, "{err}");
    let info: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(info["damping"], 2.0, "{info}");
    drop(gw);
    let _ = std::fs::remove_dir_all(&pki);
}

#[test]
fn basic256sha256_with_a_user_and_password() {
    let Some(py) = python() else { return };
    let dir = std::env::temp_dir().join(format!("hartkit-ua-sec-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The client's own certificate (asyncua needs one for a secure channel).
    let (cert, key) = (dir.join("client.der"), dir.join("client.pem"));
    let ok = Command::new("openssl")
        .args([
            "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "30",
        ])
        .args(["-subj", "/CN=hartkit test client"])
        .args(["-addext", "subjectAltName=URI:urn:hartkit:test:client"])
        .args(["-keyout", key.to_str().unwrap(), "-outform", "DER"])
        .args(["-out", cert.to_str().unwrap()])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(ok, "openssl could not make a client certificate");
    let gw = gateway(
        &[
            "--sim",
            "--instant",
            "--opcua",
            "127.0.0.1:0",
            "--opcua-security",
            "basic256sha256",
            "--opcua-user",
            "operator:s3cret",
            "--opcua-pki",
            dir.join("pki").to_str().unwrap(),
        ],
        1,
    );
    let url = &gw.1["opcua"];
    let secure = |user: &str, password: &str| {
        client(
            &py,
            url,
            &[
                "--cert",
                cert.to_str().unwrap(),
                "--key",
                key.to_str().unwrap(),
                "--user",
                user,
                "--password",
                password,
                "--wait",
                "20",
            ],
        )
    };
    let r = secure("operator", "s3cret").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r["devices"].as_array().unwrap().len(), 4, "{r}");
    assert_eq!(r["set_damping"], "ok");
    let refused = secure("operator", "wrong").expect_err("a wrong password must be refused");
    assert!(
        refused.contains("BadUserAccessDenied")
            || refused.contains("BadIdentityTokenRejected")
            || refused.contains("BadIdentityTokenInvalid"),
        "{refused}"
    );
    // No anonymous access, and no unencrypted endpoint.
    let plain =
        client(&py, url, &["--wait", "5"]).expect_err("anonymous without security must be refused");
    assert!(!plain.is_empty());
    drop(gw);
    let _ = std::fs::remove_dir_all(&dir);
}
