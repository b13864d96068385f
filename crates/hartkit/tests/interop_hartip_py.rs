//! An outside HART-IP client against `hartkit serve --sim` with its defaults: the
//! third-party package hartip-py (run as a separate process by
//! `scripts/interop/hartip_py_client.py`; GPL, never linked or imported by hartkit)
//! opens a session over UDP and over TCP, reads command 0 at polling address 0 (the
//! server as a HART I/O system), lists the sub-devices with command 84 and reads
//! commands 1, 3 and 20 from a field device found through it.
//!
//! `scripts/interop/setup` (run by `.ci/run`) installs hartip-py into
//! `target/interop-venv`. Without it the test says so and passes, unless
//! `HARTKIT_REQUIRE_INTEROP=1` (set by `.ci/run` once the install worked).

use std::path::PathBuf;
use std::process::Command;

mod common;
use common::{serve, workspace};

/// The venv's python, if hartip-py is installed there.
fn python() -> Option<PathBuf> {
    common::interop_python("hartip")
}

fn run_client(py: &std::path::Path, port: u16, transport: &str) -> Vec<serde_json::Value> {
    let port = port.to_string();
    let args = [
        "--host",
        "127.0.0.1",
        "--port",
        &port,
        "--transport",
        transport,
    ];
    common::interop_script(py, "hartip_py_client.py", &args)
        .unwrap_or_else(|e| panic!("hartip-py over {transport}: {e}"))
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect()
}

#[test]
fn hartip_py_finds_and_reads_devices_over_udp_and_tcp() {
    let Some(py) = python() else { return };
    let server = serve(&["--sim"]);
    for transport in ["udp", "tcp"] {
        let steps = run_client(&py, server.1, transport);
        let step = |name: &str| {
            steps
                .iter()
                .find(|s| s["step"] == name)
                .unwrap_or_else(|| panic!("no {name} step over {transport}: {steps:?}"))
        };
        // Polling address 0 answers at once, as a HART-IP I/O system.
        let id = step("cmd0");
        assert_eq!(id["poll"], 0);
        assert_eq!(id["response_code"], 0);
        assert_eq!(id["device_profile"], 68, "{id}");
        assert_eq!(id["io_system"], true);
        // Commands 1, 3 and 20 from a field device found through it.
        for c in ["cmd1", "cmd3", "cmd20"] {
            assert_eq!(step(c)["response_code"], 0, "{c} over {transport}");
        }
        assert_eq!(step("cmd1")["pv_unit"], "kPa");
        assert_eq!(step("result")["ok"], true);
    }
}

/// hartip-py's HART-IP version 2 client with a pre-shared key (TLS 1.2 over TCP)
/// against `hartkit serve --psk-file`, in the STARTTLS order of HCF_SPEC-085 (session
/// initiate in the clear, then the handshake: hartip-py's default, as hipserver does
/// it) and TLS first. Needs Python 3.13 in the venv (its ssl module's PSK callbacks).
#[test]
fn hartip_py_over_tls_with_a_pre_shared_key() {
    let Some(py) = python() else { return };
    let psk = std::env::temp_dir().join(format!("hartkit-interop-{}.psk", std::process::id()));
    std::fs::write(&psk, "interop:00112233445566778899aabbccddeeff\n").unwrap();
    let server = serve(&[
        "--sim",
        "pressure",
        "--tcp",
        "--psk-file",
        psk.to_str().unwrap(),
    ]);
    let out = Command::new(&py)
        .arg(workspace().join("scripts/interop/hartip_py_tls.py"))
        .args(["--port", &server.1.to_string(), "--identity", "interop"])
        .args(["--key", "00112233445566778899aabbccddeeff"])
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&psk);
    let stdout = String::from_utf8_lossy(&out.stdout);
    if out.status.code() == Some(3) {
        // A machine without Python 3.13: hartip-py cannot do TLS-PSK there.
        eprintln!("the interop venv's Python is older than 3.13; skipping hartip-py over TLS-PSK");
        return;
    }
    assert!(
        out.status.success(),
        "hartip-py over TLS-PSK failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(stdout.lines().count(), 2, "{stdout}");
}
