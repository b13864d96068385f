//! Acceptance test of `hartkit sim serve --pty` by an independent host.
//!
//! `tests/pty_client/hart_pty_client.py` is a HART master written separately from the
//! public reference notes only (it never read this code base): it opens the
//! pseudo-terminal, identifies the device with command 0 in a short frame, reads its
//! variables, changes tag, range, units, damping and polling address, configures and
//! enables a burst message and times the BACK frames, and checks write protection.

use std::process::Command;

#[test]
fn independent_host_over_a_pseudo_terminal() {
    if Command::new("python3").arg("--version").output().is_err() {
        eprintln!("python3 not available; skipping");
        return;
    }
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/pty_client/hart_pty_client.py"
    );
    let out = Command::new("python3")
        .arg(script)
        .arg("--hartkit")
        .arg(env!("CARGO_BIN_EXE_hartkit"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "acceptance client failed:\n{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("all 11 steps passed"), "{text}");
}

#[test]
fn serve_keeps_state_across_restarts() {
    let dir = std::env::temp_dir().join(format!("hartkit-serve-state-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let run = || {
        Command::new(env!("CARGO_BIN_EXE_hartkit"))
            .args([
                "sim",
                "serve",
                "--pty",
                "--profile",
                "valve",
                "--poll",
                "7",
                "--run-for",
                "0.2",
                "--state-dir",
            ])
            .arg(&dir)
            .output()
            .unwrap()
    };
    let first = run();
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let text = String::from_utf8_lossy(&first.stdout);
    assert!(
        text.lines().next().unwrap().starts_with("pty: /dev/pts/"),
        "{text}"
    );
    assert!(text.contains("polling address 7 profile valve"), "{text}");
    let state = dir.join("device-07.toml");
    let saved = std::fs::read_to_string(&state).unwrap();
    std::fs::write(
        &state,
        saved.replace("tag = \"FV-300\"", "tag = \"FV-999\""),
    )
    .unwrap();
    let second = run();
    assert!(
        String::from_utf8_lossy(&second.stdout).contains("tag FV-999"),
        "the state file wins over the profile"
    );
    let bad = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["sim", "serve", "--pty", "--profile", "nope"])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("not a built-in profile"));
    let _ = std::fs::remove_dir_all(&dir);
}
