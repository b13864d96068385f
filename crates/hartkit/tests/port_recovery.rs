//! A pulled port comes back by itself: `hartkit serve` on a serial line (a socat
//! pseudo-terminal pair, an outside program) to a simulated transmitter (`hartkit sim
//! serve` on the other end). The pair is killed, as a USB modem unplugged: the gateway
//! logs the failure, shows the loop's port down in its terminal view and the device
//! "no reply"; the pair comes back at the same paths: the gateway opens the port again
//! on its own and the device is good again, without a restart.

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

mod common;

struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn device(b: &Path) -> Killed {
    Killed(
        Command::new(env!("CARGO_BIN_EXE_hartkit"))
            .args(["sim", "serve", "--serial"])
            .arg(b)
            .args(["--profile", "pressure", "--poll", "1"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

/// Waits (at most `limit`) for a line of the gateway's view that `f` accepts.
fn wait_for(lines: &mpsc::Receiver<String>, limit: Duration, f: impl Fn(&str) -> bool) -> bool {
    let end = Instant::now() + limit;
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        match lines.recv_timeout(left) {
            Ok(l) if f(&l) => return true,
            Ok(_) => {}
            Err(_) => return false,
        }
    }
    false
}

#[test]
fn a_pulled_port_comes_back_by_itself() {
    let dir: PathBuf = std::env::temp_dir().join(format!("hartkit-port-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (a, b) = (dir.join("a"), dir.join("b"));
    let Some(pair) = hart_testkit::pty_pair_at(&a, &b) else {
        return;
    };
    let dev = device(&b);
    let mut gw = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["serve", "--port"])
        .arg(format!("serial:{}", a.display()))
        .args([
            "--scan-to",
            "1",
            "--poll-period",
            "0.5",
            "--json",
            "--run-for",
            "120",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let out = std::io::BufReader::new(gw.stdout.take().unwrap());
    let gw = Killed(gw);
    let (tx, lines) = mpsc::channel();
    std::thread::spawn(move || {
        for l in out.lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    let good = |l: &str| l.contains("\"quality\":\"good\"");
    assert!(
        wait_for(&lines, Duration::from_secs(30), good),
        "the device is polled"
    );
    // Unplugged.
    drop(dev);
    drop(pair);
    assert!(
        wait_for(&lines, Duration::from_secs(30), |l| l
            .contains("port_failed")),
        "the view shows the loop's port down"
    );
    // Plugged back in at the same place.
    let Some(_pair) = hart_testkit::pty_pair_at(&a, &b) else {
        return;
    };
    let _dev = device(&b);
    assert!(
        wait_for(&lines, Duration::from_secs(60), good),
        "the gateway opened the port again by itself"
    );
    drop(gw);
    let _ = std::fs::remove_dir_all(&dir);
}
