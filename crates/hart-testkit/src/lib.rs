//! Helpers shared by the integration tests of several hartkit crates: what a test needs
//! from outside programs, written once. Used as a dev-dependency only.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

/// A pseudo-terminal pair joined by socat (an outside program, run as a process):
/// `.1` and `.2` are its two ends. socat is killed when dropped, and the directory of
/// the ends removed when [`pty_pair`] made it.
pub struct PtyPair(pub Child, pub PathBuf, pub PathBuf, bool);

impl Drop for PtyPair {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
        if self.3 {
            if let Some(dir) = self.1.parent() {
                let _ = std::fs::remove_dir_all(dir);
            }
        }
    }
}

/// Whether socat is here; without it a check is skipped (with a message), unless
/// `HARTKIT_REQUIRE_INTEROP=1` (set by `.ci/run`), where a missing socat fails it.
fn have_socat() -> bool {
    if Command::new("socat").arg("-V").output().is_err() {
        assert!(
            std::env::var("HARTKIT_REQUIRE_INTEROP").as_deref() != Ok("1"),
            "socat is not installed although HARTKIT_REQUIRE_INTEROP=1 (apt-get install socat)"
        );
        eprintln!("socat not installed; skipping a serial-line check");
        return false;
    }
    true
}

/// A new pseudo-terminal pair in a directory of its own, or `None` (the caller skips
/// its check) when socat is not installed.
pub fn pty_pair() -> Option<PtyPair> {
    static N: AtomicU32 = AtomicU32::new(0);
    if !have_socat() {
        return None;
    }
    let dir = std::env::temp_dir().join(format!(
        "hartkit-pty-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::create_dir_all(&dir).expect("a directory for the pseudo-terminal links");
    let mut pair = pty_pair_at(&dir.join("a"), &dir.join("b"))?;
    pair.3 = true;
    Some(pair)
}

/// A pseudo-terminal pair whose ends are linked at `a` and `b` (a port that is pulled
/// and comes back at the same path); the directory stays when it is dropped.
pub fn pty_pair_at(a: &std::path::Path, b: &std::path::Path) -> Option<PtyPair> {
    if !have_socat() {
        return None;
    }
    let child = Command::new("socat")
        .arg(format!("pty,raw,echo=0,link={}", a.display()))
        .arg(format!("pty,raw,echo=0,link={}", b.display()))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("socat starts");
    let pair = PtyPair(child, a.to_path_buf(), b.to_path_buf(), false);
    let end = Instant::now() + Duration::from_secs(10);
    while !(pair.1.exists() && pair.2.exists()) {
        assert!(Instant::now() < end, "socat made no pseudo-terminals");
        std::thread::sleep(Duration::from_millis(20));
    }
    Some(pair)
}
