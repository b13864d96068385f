//! Captures: `hartkit monitor --pcap` writes pcapng that Wireshark's stock HART-IP
//! dissector decodes (tshark, an outside reader, checks every packet: HART-IP with the
//! right message types and command numbers, no malformed packet), `--pcap -` streams it,
//! and `hartkit capture read` reads captures back, cut short or not, and refuses files
//! that are not captures with a clear error. Without tshark (`.ci/run` installs it) the
//! tshark checks say so and pass.

use std::process::Command;

mod common;
use common::{capture_read, hartkit};

fn tshark() -> bool {
    let ok = Command::new("tshark").arg("--version").output().is_ok();
    if !ok {
        eprintln!("tshark not installed; skipping the Wireshark check");
    }
    ok
}

/// tshark's fields of every packet of `file` (`;`-separated), and the malformed ones.
fn tshark_fields(file: &std::path::Path, fields: &[&str]) -> (Vec<String>, Vec<String>) {
    let run = |filter: &str, fields: &[&str]| -> Vec<String> {
        let mut cmd = Command::new("tshark");
        cmd.arg("-r")
            .arg(file)
            .args(["-Y", filter, "-T", "fields", "-E", "separator=;"]);
        for f in fields {
            cmd.args(["-e", f]);
        }
        let out = cmd.output().unwrap();
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(str::to_string)
            .collect()
    };
    (
        run("frame", fields),
        run(
            "_ws.malformed || _ws.expert.severity >= \"error\"",
            &["frame.number", "_ws.expert.message"],
        ),
    )
}

fn temp(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("hartkit-{}-{name}", std::process::id()))
}

/// `hartkit monitor -p sim --pcap FILE --duration 5` (the demo plant's burst frames):
/// the capture file and the monitor's listing.
fn record_demo(name: &str) -> (std::path::PathBuf, String) {
    let file = temp(name);
    let (code, listing, err) = hartkit(&[
        "monitor",
        "-p",
        "sim",
        "--pcap",
        file.to_str().unwrap(),
        "--duration",
        "5",
    ]);
    assert_eq!(code, 0, "{err}");
    (file, listing)
}

#[test]
fn monitor_writes_a_capture_that_wireshark_decodes() {
    let (file, listing) = record_demo("demo.pcapng");
    let shown = listing.lines().filter(|l| l.contains("BACK")).count();
    assert!(shown >= 2, "{listing}");
    // Read back: the same frames.
    let frames = capture_read(&file);
    assert_eq!(frames.len(), shown, "{frames:?}");
    assert!(
        frames
            .iter()
            .all(|f| f["command"] == 3 && f["direction"] == "burst"),
        "{frames:?}"
    );
    assert!(frames[0]["comment"]
        .as_str()
        .unwrap()
        .contains("source sim"));
    if tshark() {
        let (rows, bad) = tshark_fields(
            &file,
            &[
                "hart_ip.message_type",
                "hart_ip.message_id",
                "hart_ip.pt.command",
            ],
        );
        assert!(bad.is_empty(), "malformed: {bad:?}");
        assert_eq!(rows.len(), shown, "{rows:?}");
        // Publish (2), token-passing PDU (3), command 3.
        assert!(rows.iter().all(|r| r == "2;3;3"), "{rows:?}");
    }
    let _ = std::fs::remove_file(&file);
}

#[test]
fn requests_replies_and_damaged_bytes_in_wireshark() {
    use hart_proto::frame::{Address, FrameBuf, FrameSpec, FrameType};
    let file = temp("mixed.pcapng");
    let req = FrameBuf::encode(&FrameSpec::request(Address::short(2), 1, &[])).unwrap();
    let ack = FrameBuf::encode(&FrameSpec {
        frame_type: FrameType::Ack,
        status: Some((0, 0)),
        ..FrameSpec::request(Address::short(2), 1, &[12, 0x42, 0x48, 0, 0])
    })
    .unwrap();
    let mut w =
        hart_capture::CaptureWriter::new(std::fs::File::create(&file).unwrap(), "test").unwrap();
    for (i, (bytes, valid)) in [
        (req.as_slice(), true),
        (ack.as_slice(), true),
        (&[0x06u8, 0x82, 0xFF][..], false),
    ]
    .into_iter()
    .enumerate()
    {
        w.write(&hart_capture::Record {
            time_us: 1_764_000_000_000_000 + i as u64 * 400_000,
            bytes,
            valid,
            comment: None,
        })
        .unwrap();
    }
    drop(w);
    if tshark() {
        let (rows, bad) = tshark_fields(
            &file,
            &[
                "ip.src",
                "ip.dst",
                "hart_ip.message_type",
                "hart_ip.pt.command",
                "data.data",
            ],
        );
        assert!(bad.is_empty(), "malformed: {bad:?}");
        assert_eq!(
            rows,
            [
                "10.0.0.1;10.0.1.2;0;1;",
                "10.0.1.2;10.0.0.1;1;1;",
                ";;;;0682ff",
            ],
            "request from the primary master, the reply, damaged bytes as data"
        );
    }
    let _ = std::fs::remove_file(&file);
}

#[test]
fn a_live_capture_on_standard_output() {
    let out = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["monitor", "-p", "sim", "--pcap", "-", "--duration", "3"])
        .output()
        .unwrap();
    assert!(out.status.success());
    // The capture on standard output, the listing on standard error.
    assert_eq!(
        &out.stdout[..4],
        &[0x0A, 0x0D, 0x0D, 0x0A],
        "a pcapng section header"
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("BACK"));
    let frames = hart_capture::read_capture(&out.stdout[..]).unwrap();
    assert!(!frames.is_empty());
}

#[test]
fn cut_and_foreign_files() {
    let (file, _) = record_demo("cut.pcapng");
    let whole = std::fs::read(&file).unwrap();
    let all = hart_capture::read_capture(&whole[..]).unwrap().len();
    // A capture cut inside its last block (a killed process, a full disk): the frames
    // before the cut.
    std::fs::write(&file, &whole[..whole.len() - 10]).unwrap();
    let (code, out, err) = hartkit(&["capture", "read", file.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().count(), all - 1);
    // Not a capture: a clear error naming the file.
    std::fs::write(&file, b"RIFF\0\0\0\0WAVEfmt ").unwrap();
    let (code, _, err) = hartkit(&["capture", "read", file.to_str().unwrap()]);
    assert_eq!(code, 2);
    assert!(
        err.contains(file.to_str().unwrap()) && err.contains("pcap"),
        "{err}"
    );
    let (code, _, err) = hartkit(&["capture", "read", "/nonexistent/x.pcapng"]);
    assert_eq!(code, 2);
    assert!(err.contains("/nonexistent/x.pcapng"), "{err}");
    // A directory that does not exist for --pcap.
    let (code, _, err) = hartkit(&[
        "monitor",
        "-p",
        "sim",
        "--pcap",
        "/nonexistent/x.pcapng",
        "--duration",
        "1",
    ]);
    assert_eq!(code, 2);
    assert!(err.contains("--pcap /nonexistent/x.pcapng"), "{err}");
    let _ = std::fs::remove_file(&file);
}

/// The software modem as a capture source: `modem rx FILE.wav --pcap` writes the frames
/// it decodes from a recording, which tshark decodes as HART-IP with their commands.
#[test]
fn the_modem_on_a_recording_writes_a_capture() {
    let wav = temp("modem.wav");
    let file = temp("modem.pcapng");
    let (code, _, err) = hartkit(&[
        "modem",
        "tx",
        "--out",
        wav.to_str().unwrap(),
        "0280000082",
        "82A606BC614E0100B0",
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = hartkit(&[
        "modem",
        "rx",
        wav.to_str().unwrap(),
        "--json",
        "--pcap",
        file.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let frames = hart_capture::read_capture(std::fs::File::open(&file).unwrap()).unwrap();
    let hex: Vec<String> = frames
        .iter()
        .map(|f| f.bytes.iter().map(|b| format!("{b:02X}")).collect())
        .collect();
    assert_eq!(hex, ["0280000082", "82A606BC614E0100B0"]);
    assert!(frames[0].comment.as_deref().unwrap().contains("mVpp"));
    if tshark() {
        let (rows, bad) = tshark_fields(&file, &["hart_ip.message_type", "hart_ip.pt.command"]);
        assert!(bad.is_empty(), "malformed: {bad:?}");
        assert_eq!(rows, ["0;0", "0;1"]);
    }
    let _ = std::fs::remove_file(&wav);
    let _ = std::fs::remove_file(&file);
}

/// The demo plant at the edge of the analog loop's reach (5550 m of 100 pF/m): some
/// burst frames arrive damaged, and the capture keeps them as raw data with the UART's
/// errors in words in the packet comment; `capture read` gives the errors back.
#[test]
fn link_errors_from_the_analog_loop_reach_the_capture() {
    let file = temp("edge.pcapng");
    let (code, listing, err) = hartkit(&[
        "monitor",
        "-p",
        "sim?virtual&medium=analog&cable_m=5550",
        "--pcap",
        file.to_str().unwrap(),
        "--duration",
        "30",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(listing.contains("BACK"), "{listing}");
    assert!(listing.contains("damaged frame"), "{listing}");
    let all = capture_read(&file);
    let damaged: Vec<&serde_json::Value> =
        all.iter().filter(|v| v.get("damaged").is_some()).collect();
    assert!(!damaged.is_empty(), "{all:?}");
    for d in &damaged {
        let comment = d["comment"].as_str().unwrap();
        assert!(
            comment.starts_with("source sim?virtual&medium=analog"),
            "{comment}"
        );
        assert!(comment.contains("damaged frame: "), "{comment}");
        assert!(
            comment.contains("parity")
                || comment.contains("framing")
                || comment.contains("check byte"),
            "{comment}"
        );
        assert_ne!(d["errors"], 0, "{d}");
    }
    if tshark() {
        let (rows, bad) = tshark_fields(&file, &["frame.comment", "pkt_comment"]);
        assert!(bad.is_empty(), "malformed: {bad:?}");
        assert!(
            rows.iter()
                .any(|r| r.contains("vertical parity error") || r.contains("framing error")),
            "{rows:?}"
        );
    }
    let _ = std::fs::remove_file(&file);
}

/// A full disk while capturing (`/dev/full` refuses every write): the monitor and the
/// modem stop with an error that names the file and the problem, never a panic.
#[test]
fn a_full_disk_while_capturing() {
    if !std::path::Path::new("/dev/full").exists() {
        eprintln!("no /dev/full here; skipping");
        return;
    }
    let (code, _, err) = hartkit(&[
        "monitor",
        "-p",
        "sim?virtual",
        "--pcap",
        "/dev/full",
        "--duration",
        "10",
    ]);
    assert_ne!(code, 0);
    assert!(
        err.contains("--pcap /dev/full") && err.contains("No space left"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    let wav = temp("full.wav");
    let (code, _, err) = hartkit(&["modem", "tx", "--out", wav.to_str().unwrap(), "0280000082"]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = hartkit(&["modem", "rx", wav.to_str().unwrap(), "--pcap", "/dev/full"]);
    assert_ne!(code, 0);
    assert!(
        err.contains("--pcap /dev/full") && err.contains("No space left"),
        "{err}"
    );
    let (code, _, err) = hartkit(&["modem", "tx", "--out", "/dev/full", "0280000082"]);
    assert_ne!(code, 0);
    assert!(
        err.contains("/dev/full") && err.contains("No space left"),
        "{err}"
    );
    let _ = std::fs::remove_file(&wav);
}

/// `kill -9` in the middle of a live capture: every frame written before is in the file
/// whole (each is one pcapng block, flushed as it is written), so it reads back and
/// tshark finds nothing malformed.
#[test]
fn a_capture_killed_mid_run_keeps_its_frames() {
    let file = temp("killed.pcapng");
    let mut child = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["monitor", "-p", "sim", "--pcap", file.to_str().unwrap()])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // The demo plant's temperature transmitter bursts every 2 s.
    std::thread::sleep(std::time::Duration::from_millis(5_500));
    child.kill().unwrap(); // SIGKILL
    let _ = child.wait();
    let frames = capture_read(&file).len();
    assert!(frames >= 2, "{frames}");
    if tshark() {
        let (rows, bad) = tshark_fields(&file, &["hart_ip.pt.command"]);
        assert!(bad.is_empty(), "malformed: {bad:?}");
        assert_eq!(rows.len(), frames, "{rows:?}");
    }
    let _ = std::fs::remove_file(&file);
}
