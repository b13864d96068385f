//! Access control as a user meets it: `hartkit serve` with `--read-only`,
//! `--device-commands`, `--psk-file` beside `--plain` (read-only unless
//! `--plain-rights read-write`), and `hartkit command` as the client. The rules are in
//! docs/hart-ip.md ("Access control"); every path is tested in
//! crates/hart-ip-server/tests/access.rs.

mod common;
use common::{gateway, hartkit};

fn temp(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("hartkit-access-{}-{name}", std::process::id()))
}

/// The response code of a `hartkit command` reply, and the reply (JSON; null for an
/// error code, which the command reports with exit code 4).
fn rc(
    port: &str,
    poll: &str,
    command: &str,
    data: &str,
    extra: &[&str],
) -> (i64, serde_json::Value) {
    let mut args = vec![
        "command", "-p", port, "--poll", poll, command, data, "--json",
    ];
    args.extend_from_slice(extra);
    let (code, out, err) = hartkit(&args);
    if code == 4 {
        // An error response code: "device replied 'access restricted' (16) to command 129".
        let n = err
            .split_once("' (")
            .and_then(|(_, r)| r.split_once(')'))
            .and_then(|(n, _)| n.parse().ok())
            .unwrap_or_else(|| panic!("{err}"));
        return (n, serde_json::Value::Null);
    }
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap_or_else(|e| panic!("{e}: {out}"));
    (v["response_code"].as_i64().unwrap(), v)
}

/// The reproduction of the report: on a `--read-only` server a device-specific command
/// (the valve's 129, write setpoint) and 42 (device reset) were let through as reads.
/// Now they are refused, the setpoint stays, and 128 passes once declared a read.
#[test]
fn read_only_refuses_device_specific_writes_and_resets() {
    let declared = temp("valve.toml");
    std::fs::write(
        &declared,
        "[[device]]\ntype = \"26F3\"\nname = \"valve\"\nreads = \"128\"\n",
    )
    .unwrap();
    let gw = gateway(
        &[
            "--sim",
            "pressure",
            "valve",
            "--instant",
            "--hart-ip",
            "127.0.0.1:0",
            "--read-only",
            "--device-commands",
            declared.to_str().unwrap(),
        ],
        1,
    );
    let port = format!("udp://{}", gw.1["hart-ip"]);
    let (code, before) = rc(&port, "2", "128", "", &[]);
    assert_eq!(code, 0, "a declared read passes: {before}");
    assert_eq!(rc(&port, "2", "129", "41480000", &[]).0, 16);
    assert_eq!(rc(&port, "2", "42", "", &[]).0, 16);
    assert_eq!(rc(&port, "1", "41", "", &[]).0, 16);
    assert_eq!(rc(&port, "1", "17", r#"{"message":"X"}"#, &[]).0, 16);
    let (_, after) = rc(&port, "2", "128", "", &[]);
    assert_eq!(after["data"], before["data"], "the setpoint did not change");
    let _ = std::fs::remove_file(&declared);
}

/// Plain HART-IP beside a PSK file is read-only unless told otherwise, and says so.
#[test]
fn plain_sessions_beside_secure_ones_read_only_by_default() {
    let keys = temp("keys.psk");
    std::fs::write(&keys, "writer:00112233445566778899AABBCCDDEEFF\n").unwrap();
    for (rights, expect) in [(None, 16), (Some("read-write"), 0)] {
        let mut args = vec![
            "--sim",
            "--instant",
            "--hart-ip",
            "127.0.0.1:0",
            "--psk-file",
            keys.to_str().unwrap(),
            "--plain",
            "127.0.0.1:0",
        ];
        if let Some(r) = rights {
            args.extend(["--plain-rights", r]);
        }
        let gw = gateway(&args, 2);
        let plain = format!("udp://{}", gw.1["hart-ip plain"]);
        let (code, reply) = rc(&plain, "1", "17", r#"{"message":"PLAIN"}"#, &[]);
        assert_eq!(code, expect, "--plain-rights {rights:?}: {reply}");
        assert_eq!(rc(&plain, "1", "1", "", &[]).0, 0, "reads pass");
        // The writer identity writes whatever the plain port may do.
        let secure = format!("dtls://{}", gw.1["hart-ip"]);
        let (code, _) = rc(
            &secure,
            "1",
            "17",
            r#"{"message":"SECURE"}"#,
            &["--psk", "writer:00112233445566778899AABBCCDDEEFF"],
        );
        assert_eq!(code, 0);
    }
    let _ = std::fs::remove_file(&keys);
}

/// A declaration that would let a write through as a read is refused at start, with
/// the command named; so is a bad rights word.
#[test]
fn bad_declarations_are_refused_at_start() {
    let bad = temp("bad.toml");
    std::fs::write(&bad, "[[device]]\ntype = \"26F1\"\nreads = \"17\"\n").unwrap();
    let (code, _, err) = hartkit(&[
        "serve",
        "--sim",
        "--hart-ip",
        "127.0.0.1:0",
        "--device-commands",
        bad.to_str().unwrap(),
        "--run-for",
        "1",
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("command 17 (Write Message)"), "{err}");
    let (code, _, err) = hartkit(&["serve", "--sim", "--plain-rights", "all"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("read-only or read-write"), "{err}");
    let _ = std::fs::remove_file(&bad);
}
