//! Every HART-IP packet our client and server exchange, captured with tshark on the
//! loopback interface and decoded by Wireshark's HART-IP dissector: no malformed
//! packets, no expert errors, and the decoded fields are what we sent.
//!
//! `.ci/run` installs tshark; without it (or without permission to capture) the test
//! says so and passes.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

mod common;
use common::{capture_read, hartkit};

#[test]
fn wireshark_decodes_our_hart_ip_traffic() {
    if Command::new("tshark").arg("--version").output().is_err() {
        eprintln!("tshark not installed; skipping the Wireshark check");
        return;
    }
    let port = "5094";
    let file = std::env::temp_dir().join(format!("hartkit-hartip-{}.pcapng", std::process::id()));
    let mut capture = Command::new("tshark")
        .args(["-i", "lo", "-f", &format!("port {port}"), "-w"])
        .arg(&file)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(2500));
    if let Ok(Some(status)) = capture.try_wait() {
        eprintln!("tshark cannot capture here ({status}); skipping the Wireshark check");
        return;
    }
    let mut server = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args([
            "serve",
            "--hart-ip",
            &format!("127.0.0.1:{port}"),
            "--sim",
            "pressure",
            "temperature",
            // Ended by the test; the limit only stops a server the test left behind.
            "--run-for",
            "600",
        ])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    // The server says where it listens once its sockets are bound.
    // (The pipe stays open until the end, so later output cannot fail.)
    let mut server_out = BufReader::new(server.stdout.take().unwrap());
    let mut ready = String::new();
    let _ = server_out.read_line(&mut ready);
    assert!(ready.contains("hart-ip"), "server did not start: {ready}");
    let udp = format!("udp://127.0.0.1:{port}");
    let tcp = format!("tcp://127.0.0.1:{port}");
    let (c1, live, e1) = hartkit(&["read", "-p", &udp, "--poll", "1", "dynamic", "--json"]);
    let (c2, _, e2) = hartkit(&["read", "-p", &tcp, "--poll", "2", "info"]);
    let (c3, _, e3) = hartkit(&["command", "-p", &udp, "--poll", "1", "1024"]);
    let (c4, _, e4) = hartkit(&[
        "burst",
        "-p",
        &tcp,
        "--poll",
        "1",
        "config",
        "--command",
        "1",
        "--period",
        "1",
    ]);
    let (c5, _, e5) = hartkit(&["burst", "-p", &tcp, "--poll", "1", "on"]);
    // The server as an I/O system (command 84 at polling address 0), and its answer
    // for an absent device (an ACK with response code 35).
    let (c7, _, e7) = hartkit(&["command", "-p", &udp, "--poll", "0", "84", "0001"]);
    let (c8, _, _) = hartkit(&["read", "-p", &tcp, "--poll", "9", "pv"]);
    // An outside client's session, when hartip-py is installed (scripts/interop/setup).
    let venv = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../target/interop-venv/bin/python");
    if venv.exists() {
        let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../scripts/interop/hartip_py_client.py");
        let _ = Command::new(&venv)
            .arg(script)
            .args(["--host", "127.0.0.1", "--port", port, "--transport", "udp"])
            .output();
    }
    // The device bursts every second; a few seconds of listening hear several.
    let (c6, mon, e6) = hartkit(&["monitor", "-p", &udp, "--duration", "5"]);
    std::thread::sleep(Duration::from_millis(500));
    let _ = Command::new("kill")
        .args(["-INT", &capture.id().to_string()])
        .status();
    let _ = capture.wait();
    let _ = server.kill();
    let _ = server.wait();
    drop(server_out);
    assert_eq!(c1, 0, "{e1}");
    assert_eq!(c2, 0, "{e2}");
    assert_eq!(c3, 4, "command 1024 is not implemented: {e3}");
    assert_eq!((c4, c5, c6), (0, 0, 0), "{e4}{e5}{e6}");
    assert_eq!(c7, 0, "{e7}");
    assert_eq!(c8, 3, "absent device");
    assert!(
        mon.contains("BACK"),
        "publish messages reach the monitor: {mon}"
    );

    let decode = |filter: &str, fields: &[&str]| -> Vec<String> {
        let mut args = vec![
            "-r".to_string(),
            file.display().to_string(),
            "-d".into(),
            format!("udp.port=={port},hart_ip"),
            "-d".into(),
            format!("tcp.port=={port},hart_ip"),
            "-Y".into(),
            filter.into(),
            "-T".into(),
            "fields".into(),
        ];
        for f in fields {
            args.push("-e".into());
            args.push((*f).into());
        }
        args.extend([
            "-E".into(),
            "separator=;".into(),
            "-E".into(),
            "occurrence=a".into(),
            "-E".into(),
            "aggregator=|".into(),
        ]);
        let out = Command::new("tshark").args(&args).output().unwrap();
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(str::to_string)
            .collect()
    };
    let bad = decode(
        "_ws.malformed || _ws.expert.severity >= \"error\"",
        &["frame.number", "_ws.expert.message"],
    );
    assert!(
        bad.is_empty(),
        "Wireshark reports malformed packets or expert errors:\n{}",
        bad.join("\n")
    );
    let msgs = decode(
        "hart_ip",
        &[
            "hart_ip.message_type",
            "hart_ip.message_id",
            "hart_ip.transaction_id",
            "hart_ip.pt.command",
            "hart_ip.pt.response_code",
        ],
    );
    assert!(msgs.len() >= 30, "HART-IP packets decoded: {}", msgs.len());
    let has = |pred: &dyn Fn(&[&str]) -> bool| {
        msgs.iter().any(|l| pred(&l.split(';').collect::<Vec<_>>()))
    };
    // Session initiate request and response, token-passing requests with the commands we
    // sent, replies, publish messages and session close.
    assert!(
        has(&|f| f[0] == "0" && f[1] == "0"),
        "session initiate request"
    );
    assert!(
        has(&|f| f[0] == "1" && f[1] == "0"),
        "session initiate response"
    );
    for cmd in ["0", "3", "13", "15", "31", "108", "103", "109", "105"] {
        assert!(
            has(&|f| f[0] == "0" && f[1] == "3" && f[3].split('|').any(|c| c == cmd)),
            "token-passing request with command {cmd}"
        );
    }
    assert!(
        has(&|f| f[0] == "1" && f[1] == "3" && f[3] == "3" && f[4] == "0"),
        "command 3 reply with response code 0"
    );
    assert!(has(&|f| f[0] == "2" && f[1] == "3"), "publish messages");
    assert!(
        has(&|f| f[0] == "1" && f[1] == "3" && f[3] == "84" && f[4] == "0"),
        "command 84 reply of the I/O system"
    );
    assert!(
        has(&|f| f[0] == "1" && f[1] == "3" && f[4] == "35"),
        "response code 35 for the absent device"
    );
    assert!(has(&|f| f[0] == "0" && f[1] == "1"), "session close");
    // Sequence numbers: every response carries the sequence number of a request.
    let seqs = |ty: &str| -> std::collections::HashSet<String> {
        msgs.iter()
            .filter(|l| l.starts_with(&format!("{ty};3;")))
            .map(|l| l.split(';').nth(2).unwrap_or("").to_string())
            .collect()
    };
    let (req, resp) = (seqs("0"), seqs("1"));
    assert!(
        resp.is_subset(&req),
        "responses answer requests: {resp:?} vs {req:?}"
    );
    // `hartkit capture read` reads the capture tshark wrote (Ethernet frames on the
    // loopback interface, UDP and TCP): the token-passing frames with their directions.
    let frames = capture_read(&file);
    let seen = |dir: &str, cmd: u64| {
        frames
            .iter()
            .any(|f| f["direction"] == dir && f["command"] == cmd)
    };
    assert!(seen("primary->device", 3), "command 3 request: {frames:?}");
    assert!(seen("device->primary", 3), "command 3 reply: {frames:?}");
    assert!(seen("device->primary", 84), "command 84 reply: {frames:?}");
    assert!(
        seen("burst", 3) || seen("burst", 1),
        "a publish message: {frames:?}"
    );
    // The capture as a replay source: the same read answered from the recording.
    let replay = format!("replay:{}", file.display());
    let (code, replayed, err) =
        hartkit(&["read", "-p", &replay, "--poll", "1", "dynamic", "--json"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(replayed, live, "the recorded answer");
    let (code, _, err) = hartkit(&["read", "-p", &replay, "--poll", "40", "pv"]);
    assert_eq!(code, 3, "never recorded: no reply: {err}");
    let _ = std::fs::remove_file(&file);
}
