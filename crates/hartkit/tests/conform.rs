//! `hartkit conform` end to end: simulated devices of every profile pass over the
//! simulated line and over HART-IP, a faulty device fails where it should, the reports
//! are written, bad input ends in a clear verdict.

use serde_json::Value;

mod common;
use common::{hartkit, serve};

/// A plant file with `devices`: (profile, polling address, HART revision, burst, faults).
fn plant(dir: &std::path::Path, name: &str, devices: &[(&str, u8, u8, bool, &[&str])]) -> String {
    let mut text = String::new();
    for (profile, poll, revision, burst, faults) in devices {
        text.push_str(&format!(
            "[[device]]\nprofile = \"{profile}\"\npoll = {poll}\nrevision = {revision}\nfaults = {:?}\n",
            faults
        ));
        if *burst {
            text.push_str("burst = { command = 3, period = 1.0 }\n");
        }
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path.to_string_lossy().into_owned()
}

fn results(out: &str) -> Vec<Value> {
    out.lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect()
}

fn with(verdict: &str, r: &[Value]) -> Vec<String> {
    r.iter()
        .filter(|t| t["verdict"] == verdict)
        .map(|t| t["id"].as_str().unwrap().to_string())
        .collect()
}

#[test]
fn every_profile_passes_on_the_simulated_line() {
    let dir = tempfile::tempdir().unwrap();
    for profile in ["pressure", "temperature", "valve"] {
        for revision in [5u8, 6, 7] {
            for burst in [false, true] {
                let p = plant(dir.path(), "p.toml", &[(profile, 0, revision, burst, &[])]);
                let target = format!("sim:{p}?virtual");
                let (code, out, err) = hartkit(&[
                    "conform",
                    "-p",
                    &target,
                    "--poll",
                    "0",
                    "--allow-writes",
                    "--json",
                ]);
                let r = results(&out);
                assert_eq!(
                    code,
                    0,
                    "{profile} {revision} {burst}: {err} {:?}",
                    with("fail", &r)
                );
                assert!(with("fail", &r).is_empty());
                // Only the parity test cannot run on a simulated line.
                assert_eq!(
                    with("could-not-run", &r),
                    vec!["LINK-013"],
                    "{profile} {revision} {burst}"
                );
                // Every object has the documented fields.
                for t in &r {
                    for k in [
                        "id",
                        "group",
                        "rule",
                        "source",
                        "single_source",
                        "verdict",
                        "detail",
                        "evidence",
                        "duration_us",
                    ] {
                        assert!(t.get(k).is_some(), "{k} missing in {t}");
                    }
                }
            }
        }
    }
}

#[test]
fn every_profile_passes_over_hart_ip() {
    let dir = tempfile::tempdir().unwrap();
    let devices: Vec<(&str, u8, u8, bool, &[&str])> = vec![
        ("pressure", 1, 5, false, &[]),
        ("pressure", 2, 6, false, &[]),
        ("pressure", 3, 7, false, &[]),
        ("temperature", 4, 7, true, &[]),
        ("valve", 5, 6, false, &[]),
        ("valve", 6, 7, true, &[]),
        ("temperature", 7, 5, false, &[]),
    ];
    // One server per device: the built-in profiles of one kind share a tag.
    for (k, d) in devices.iter().enumerate() {
        let (profile, poll, revision, _, _) = d;
        let p = plant(dir.path(), &format!("plant{k}.toml"), &[*d]);
        let s = serve(&["-p", &format!("sim:{p}?virtual")]);
        for scheme in ["udp", "tcp"] {
            let target = format!("{scheme}://127.0.0.1:{}", s.1);
            let (code, out, err) = hartkit(&[
                "conform",
                "-p",
                &target,
                "--poll",
                &poll.to_string(),
                "--allow-writes",
                "--json",
            ]);
            let r = results(&out);
            assert_eq!(
                code,
                0,
                "{scheme} {profile} HART {revision} at {poll}: {err} {:?}",
                with("fail", &r)
            );
            // Tests of the line's characters and timing cannot run; the rest pass.
            for t in &r {
                let id = t["id"].as_str().unwrap();
                if t["verdict"] == "could-not-run" {
                    assert!(
                        t["detail"].as_str().unwrap().contains("HART-IP") || id == "LINK-013",
                        "{t}"
                    );
                }
            }
            assert!(
                with("pass", &r).len() >= 20,
                "{scheme} {profile} {revision}: {:?}",
                with("pass", &r)
            );
        }
    }
}

#[test]
fn a_faulty_device_fails_its_test_and_the_report_shows_it() {
    let dir = tempfile::tempdir().unwrap();
    let p = plant(
        dir.path(),
        "late.toml",
        &[(
            "pressure",
            0,
            7,
            false,
            &["late-reply", "master-bit-not-echoed"],
        )],
    );
    let html = dir.path().join("report.html");
    let target = format!("sim:{p}?virtual");
    let (code, out, err) = hartkit(&[
        "conform",
        "-p",
        &target,
        "--report",
        html.to_str().unwrap(),
        "--only",
        "link",
    ]);
    assert_eq!(code, 1, "{out}{err}");
    assert!(err.contains("2 conformance test(s) failed"), "{err}");
    assert!(
        out.contains("LINK-010   fail") && out.contains("LINK-007   fail"),
        "{out}"
    );
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(page.contains("<svg") && page.contains("LINK-010") && page.contains("STO"));
    // Self-contained: no stylesheet, script or image fetched from elsewhere.
    for external in ["<link", "<script", "src=", "url("] {
        assert!(!page.contains(external), "{external} in the report");
    }
}

#[test]
fn no_device_and_bad_arguments_are_clear() {
    // The demo plant has no device at polling address 9.
    let (code, out, err) = hartkit(&["conform", "-p", "sim?virtual", "--poll", "9"]);
    assert_eq!(code, 2, "{out}{err}");
    assert!(
        out.contains("no device answered command 0 at polling address 9"),
        "{out}"
    );
    let (code, _, err) = hartkit(&["conform", "-p", "sim?virtual", "--only", "link,radio"]);
    assert_eq!(code, 2);
    assert!(err.contains("unknown group \"radio\""), "{err}");
    let (code, _, err) = hartkit(&["conform", "-p", "sim?virtual", "--unique-id", "12"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--unique-id 12"), "{err}");
}

#[test]
fn phy_on_recordings() {
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("ack.wav");
    // An ACK to command 1, modulated by the modem at 500 mVpp.
    let (code, _, err) = hartkit(&[
        "modem",
        "tx",
        "--out",
        wav.to_str().unwrap(),
        "86A6F1010001010700000C42F0000069",
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = hartkit(&["conform", "phy", wav.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0, "{out}{err}");
    let r = results(&out);
    assert_eq!(with("fail", &r), Vec::<String>::new());
    assert!(with("pass", &r).contains(&"PHY-001".to_string()));
    // A truncated recording and a missing one end in a verdict or an error, not a panic.
    let bytes = std::fs::read(&wav).unwrap();
    let cut = dir.path().join("cut.wav");
    std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap();
    let (code, out, err) = hartkit(&["conform", "phy", cut.to_str().unwrap()]);
    assert!(code == 0 || code == 2, "{out}{err}");
    assert!(!err.contains("panicked"), "{err}");
    let (code, _, err) = hartkit(&["conform", "phy", "/nonexistent.wav"]);
    assert_eq!(code, 2);
    assert!(err.contains("/nonexistent.wav"), "{err}");
}

/// `hartkit sim serve --pty --profile pressure --poll 0 EXTRA`.
fn served(extra: &[&str]) -> common::SimPty {
    let mut args = vec!["--profile", "pressure", "--poll", "0"];
    args.extend_from_slice(extra);
    common::sim_pty(&args)
}

/// The whole suite against a device on a pseudo-terminal at 1200 bit/s, in real time.
#[test]
fn over_a_pseudo_terminal_at_1200_bit_s() {
    let s = served(&[]);
    let (code, out, err) = hartkit(&["conform", "-p", &s.pty, "--poll", "0", "--json"]);
    let r = results(&out);
    assert_eq!(code, 0, "{err} {:?}\n{out}", with("fail", &r));
    assert!(with("pass", &r).len() >= 30, "{:?}", with("pass", &r));
}

/// A device on the pseudo-terminal that breaks a rule (`sim serve --fault`): caught
/// through a real serial port, and nothing else fails.
#[test]
fn a_faulty_device_on_a_pseudo_terminal() {
    let s = served(&["--fault", "master-bit-not-echoed"]);
    let (code, out, err) = hartkit(&[
        "conform", "-p", &s.pty, "--poll", "0", "--only", "link", "--json",
    ]);
    let r = results(&out);
    assert_eq!(code, 1, "{err}");
    assert_eq!(with("fail", &r), vec!["LINK-007"], "{out}");
    // A pseudo-terminal has no bit rate: the timing tests say so instead of guessing.
    let cnr = with("could-not-run", &r);
    assert!(cnr.contains(&"LINK-010".to_string()) && cnr.contains(&"LINK-011".to_string()));
}

/// A write-protected device (`sim serve --write-protect`): CMD-104 checks the
/// protection; the other writing tests say they need a writable device.
#[test]
fn a_write_protected_device() {
    let s = served(&["--write-protect"]);
    let (code, out, err) = hartkit(&[
        "conform",
        "-p",
        &s.pty,
        "--poll",
        "0",
        "--only",
        "commands",
        "--allow-writes",
        "--json",
    ]);
    let r = results(&out);
    assert_eq!(code, 0, "{err} {:?}", with("fail", &r));
    assert!(with("pass", &r).contains(&"CMD-104".to_string()), "{out}");
    for id in [
        "CMD-017", "CMD-018", "CMD-019", "CMD-022", "CMD-038", "CMD-106",
    ] {
        assert!(
            with("could-not-run", &r).contains(&id.to_string()),
            "{id}: {out}"
        );
    }
}
