//! Helpers shared by the integration tests of several hartkit crates: what a test needs
//! from outside programs, written once. Used as a dev-dependency only.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

/// A pseudo-terminal pair joined by socat (an outside program, run as a process):
/// `.1` and `.2` are its two ends. socat is killed and its directory removed when
/// dropped.
pub struct PtyPair(pub Child, pub PathBuf, pub PathBuf);

impl Drop for PtyPair {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
        if let Some(dir) = self.1.parent() {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// A new pseudo-terminal pair, or `None` (the caller skips its check, with a message)
/// when socat is not installed, unless `HARTKIT_REQUIRE_INTEROP=1` (set by `.ci/run`),
/// where a missing socat fails the test.
pub fn pty_pair() -> Option<PtyPair> {
    static N: AtomicU32 = AtomicU32::new(0);
    if Command::new("socat").arg("-V").output().is_err() {
        assert!(
            std::env::var("HARTKIT_REQUIRE_INTEROP").as_deref() != Ok("1"),
            "socat is not installed although HARTKIT_REQUIRE_INTEROP=1 (apt-get install socat)"
        );
        eprintln!("socat not installed; skipping a serial-line check");
        return None;
    }
    let dir = std::env::temp_dir().join(format!(
        "hartkit-pty-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::create_dir_all(&dir).expect("a directory for the pseudo-terminal links");
    let (a, b) = (dir.join("a"), dir.join("b"));
    let child = Command::new("socat")
        .arg(format!("pty,raw,echo=0,link={}", a.display()))
        .arg(format!("pty,raw,echo=0,link={}", b.display()))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("socat starts");
    let pair = PtyPair(child, a, b);
    let end = Instant::now() + Duration::from_secs(10);
    while !(pair.1.exists() && pair.2.exists()) {
        assert!(Instant::now() < end, "socat made no pseudo-terminals");
        std::thread::sleep(Duration::from_millis(20));
    }
    Some(pair)
}
