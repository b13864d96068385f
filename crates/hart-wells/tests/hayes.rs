//! Dialling over a serial line to a modem: `hart_wells::hayes` on a serial line
//! against `tests/peer/fake_modem.py`, a Hayes-compatible modem written from the AT
//! command conventions, on socat pseudo-terminal pairs. The modem's telephone line to
//! the concentrator is a second pair, which the test reads and writes as the
//! concentrator. Skipped (with a message) without socat or python3.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use hart_host::target::AnyTransport;
use hart_host::transport::Transport;
use hart_wells::hayes::{dial, hang_up, DialError, DialOptions, LineAssembler};
use serde_json::Value;

/// A child process killed and reaped when dropped, a failed assertion included.
struct Kill(Child);

impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Whether socat and python3 are there; says why the test is skipped when not.
fn tools() -> bool {
    for tool in ["socat", "python3"] {
        let arg = if tool == "socat" { "-V" } else { "--version" };
        if Command::new(tool).arg(arg).output().is_err() {
            eprintln!("{tool} not installed; skipping this modem test");
            return false;
        }
    }
    true
}

/// Two connected pseudo-terminals (hart_testkit); `tools()` has checked socat is there.
fn pty_pair() -> hart_testkit::PtyPair {
    hart_testkit::pty_pair().expect("socat is installed (checked by tools())")
}

/// The fake modem, its JSON log in a file.
struct FakeModem {
    child: Kill,
    log: PathBuf,
    err: PathBuf,
    _dir: tempfile::TempDir,
}

impl FakeModem {
    /// Starts `fake_modem.py DTE ARGS` and waits until it has the DTE open.
    fn start(dte: &Path, args: &[&str]) -> FakeModem {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/peer/fake_modem.py");
        let dir = tempfile::tempdir().unwrap();
        let (log, err) = (dir.path().join("log.jsonl"), dir.path().join("stderr"));
        let child = Command::new("python3")
            .arg(script)
            .arg(dte)
            .args(args)
            .args(["--run-for", "120"])
            .stdout(File::create(&log).unwrap())
            .stderr(File::create(&err).unwrap())
            .spawn()
            .unwrap();
        let mut m = FakeModem {
            child: Kill(child),
            log,
            err,
            _dir: dir,
        };
        m.wait_for("ready", Duration::from_secs(10), |_| true);
        m
    }

    fn events(&self) -> Vec<Value> {
        std::fs::read_to_string(&self.log)
            .unwrap_or_default()
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect()
    }

    fn of(&self, event: &str) -> Vec<Value> {
        self.events()
            .into_iter()
            .filter(|e| e["event"] == event)
            .collect()
    }

    /// The command lines the modem heard ("ATE0V1Q0", "ATDT5551234", ...).
    fn commands(&self) -> Vec<String> {
        self.of("command")
            .iter()
            .map(|e| e["command"].as_str().unwrap().to_string())
            .collect()
    }

    /// Waits for an `event` for which `pred` holds.
    fn wait_for(&mut self, event: &str, within: Duration, pred: impl Fn(&Value) -> bool) {
        let end = Instant::now() + within;
        loop {
            if self.of(event).iter().any(&pred) {
                return;
            }
            if let Ok(Some(status)) = self.child.0.try_wait() {
                panic!(
                    "fake modem exited ({status}) before {event}: {}",
                    std::fs::read_to_string(&self.err).unwrap_or_default()
                );
            }
            assert!(
                Instant::now() < end,
                "no {event} from the fake modem in {within:?}: {:?}",
                self.events()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// The serial line at `path` as the command line opens it (a HART modem at 1200 bit/s,
/// no RTS keying).
fn open(path: &Path) -> AnyTransport {
    hart_host::target::open(&format!("serial:{}", path.display())).unwrap()
}

/// Reads until `n` bytes came or `within` passed.
async fn read_n<T: Transport>(t: &mut T, n: usize, within: Duration) -> Vec<u8> {
    let end = t.now() + within.as_micros() as u64;
    let mut got = vec![];
    while got.len() < n {
        let chunk = t.recv(end).await.unwrap();
        if chunk.is_empty() {
            break;
        }
        got.extend(chunk.into_iter().map(|c| c.0));
    }
    got
}

fn opts(number: &str) -> DialOptions {
    DialOptions {
        number: number.into(),
        ..Default::default()
    }
}

/// Dial with the default options (the modem starts echoing, E1), data both ways
/// through the call, and the hang-up with the default guard times.
#[tokio::test]
async fn dial_carries_data_both_ways_and_hangs_up() {
    if !tools() {
        return;
    }
    let (dte, line) = (pty_pair(), pty_pair());
    let connect = format!("5551234={}", line.1.display());
    let mut modem = FakeModem::start(&dte.2, &["--connect", &connect]);
    let mut pc = open(&dte.1);

    let started = Instant::now();
    let r = dial(&mut pc, &opts("T 555-1234")).await;
    assert_eq!(r.unwrap(), "CONNECT 1200");
    assert!(started.elapsed() >= Duration::from_millis(450));
    assert_eq!(modem.commands(), ["ATE0V1Q0", "ATDT5551234"]);
    let dial_ev = &modem.of("dial")[0];
    assert_eq!(dial_ev["number"], "5551234");
    assert_eq!(dial_ev["outcome"], "CONNECT 1200");

    // The concentrator's end of the line.
    let mut conc = open(&line.2);
    let request = b"\xFF\xFF\x02\x83\x90\x04\x01\xBC\x61\x4E\x4D";
    pc.send(request).await.unwrap();
    let got = read_n(&mut conc, request.len(), Duration::from_secs(3)).await;
    assert_eq!(got, request);
    let reply = b"\xFF\xFF\x06\x83\x90\x02\x00\x00\x17\r\n+++ATH\r\n";
    conc.send(reply).await.unwrap();
    let got = read_n(&mut pc, reply.len(), Duration::from_secs(3)).await;
    assert_eq!(got, reply, "data from the line passes untouched");

    let started = Instant::now();
    hang_up(&mut pc, &DialOptions::default()).await.unwrap();
    // Guard, escape, guard (the modem's own 1 s), ATH.
    assert!(
        started.elapsed() >= Duration::from_millis(2200),
        "{:?}",
        started.elapsed()
    );
    modem.wait_for("hangup", Duration::from_secs(2), |e| e["how"] == "ATH");
    assert_eq!(modem.of("escape").len(), 1);
    assert_eq!(modem.commands(), ["ATE0V1Q0", "ATDT5551234", "ATH"]);
    let results: Vec<Value> = modem
        .of("result")
        .iter()
        .map(|e| e["text"].clone())
        .collect();
    assert_eq!(results, ["OK", "CONNECT 1200", "OK", "OK"]);

    // The modem is back in command mode, ready for the next call.
    let r = dial(&mut pc, &opts("5551234")).await;
    assert_eq!(r.unwrap(), "CONNECT 1200");
    let o = DialOptions {
        guard: Duration::from_millis(1100),
        ..Default::default()
    };
    hang_up(&mut pc, &o).await.unwrap();
}

/// Every way a dial can fail, on one modem (and one without a dial tone).
#[tokio::test]
async fn failed_dials_say_why() {
    if !tools() {
        return;
    }
    let dte = pty_pair();
    let modem = FakeModem::start(
        &dte.2,
        &[
            "--busy",
            "111",
            "--no-carrier",
            "222",
            "--no-answer",
            "333",
            "--no-answer-seconds",
            "1",
            "--ring-seconds",
            "0.2",
        ],
    );
    let mut pc = open(&dte.1);
    let e = dial(&mut pc, &opts("111")).await.unwrap_err();
    assert!(matches!(e, DialError::Busy), "{e:?}");
    assert!(e.to_string().contains("busy"));
    let e = dial(&mut pc, &opts("222")).await.unwrap_err();
    assert!(matches!(e, DialError::NoCarrier), "{e:?}");
    let started = Instant::now();
    let e = dial(&mut pc, &opts("333")).await.unwrap_err();
    assert!(matches!(e, DialError::NoAnswer), "{e:?}");
    assert!(started.elapsed() >= Duration::from_millis(900));
    // A number nobody answers with a carrier.
    let e = dial(&mut pc, &opts("444")).await.unwrap_err();
    assert!(matches!(e, DialError::NoCarrier), "{e:?}");
    // Numeric results (V0).
    let v0 = DialOptions {
        init: "ATE0V0".into(),
        ..opts("111")
    };
    let e = dial(&mut pc, &v0).await.unwrap_err();
    assert!(matches!(e, DialError::Busy), "{e:?}");
    assert!(modem.of("result").iter().any(|r| r["sent"] == "7\r"));
    // A command the modem does not know.
    let bad = DialOptions {
        init: "ATE0V1Q0J".into(),
        ..opts("111")
    };
    let e = dial(&mut pc, &bad).await.unwrap_err();
    assert!(
        matches!(&e, DialError::Error { command } if command == "ATE0V1Q0J"),
        "{e:?}"
    );
    drop(modem);

    let dte = pty_pair();
    let _modem = FakeModem::start(&dte.2, &["--no-dialtone"]);
    let mut pc = open(&dte.1);
    let e = dial(&mut pc, &opts("111")).await.unwrap_err();
    assert!(matches!(e, DialError::NoDialtone), "{e:?}");
    assert!(e.to_string().contains("dial tone"));
}

/// A modem that answers nothing: the initialisation times out.
#[tokio::test]
async fn a_silent_modem_times_out() {
    if !tools() {
        return;
    }
    let dte = pty_pair();
    let mut modem = FakeModem::start(&dte.2, &["--silent"]);
    let mut pc = open(&dte.1);
    let o = DialOptions {
        command_timeout: Duration::from_millis(700),
        ..opts("111")
    };
    let started = Instant::now();
    let e = dial(&mut pc, &o).await.unwrap_err();
    assert!(
        matches!(&e, DialError::Timeout { waiting_for, after }
            if waiting_for == "ATE0V1Q0" && *after == Duration::from_millis(700)),
        "{e:?}"
    );
    assert!(started.elapsed() >= Duration::from_millis(700));
    assert!(e
        .to_string()
        .starts_with("no answer from the modem to ATE0V1Q0 after 700ms"));
    // It heard the command all the same.
    modem.wait_for("command", Duration::from_secs(2), |e| {
        e["command"] == "ATE0V1Q0"
    });
}

/// A bad number is refused before anything reaches the modem.
#[tokio::test]
async fn a_bad_number_sends_nothing() {
    if !tools() {
        return;
    }
    let dte = pty_pair();
    let mut modem = FakeModem::start(&dte.2, &["--busy", "111"]);
    let mut pc = open(&dte.1);
    for number in ["555-CALL", "111\r\nATH", ""] {
        let e = dial(&mut pc, &opts(number)).await.unwrap_err();
        assert!(matches!(e, DialError::BadNumber(_)), "{number:?}: {e:?}");
    }
    std::thread::sleep(Duration::from_millis(300));
    let e = dial(&mut pc, &opts("111")).await.unwrap_err();
    assert!(matches!(e, DialError::Busy), "{e:?}");
    modem.wait_for("result", Duration::from_secs(2), |e| e["text"] == "BUSY");
    // The first line the modem heard is the one of the good dial.
    assert_eq!(modem.commands(), ["ATE0V1Q0", "ATD111"]);
    assert!(modem.of("ignored_line").is_empty());
}

/// The far end drops the call: the modem says NO CARRIER in the data phase, and
/// hang_up still leaves it on hook in command mode.
#[tokio::test]
async fn a_dropped_call_hangs_up_all_the_same() {
    if !tools() {
        return;
    }
    let (dte, line) = (pty_pair(), pty_pair());
    let connect = format!("777={}", line.1.display());
    let mut modem = FakeModem::start(
        &dte.2,
        &[
            "--connect",
            &connect,
            "--drop-after",
            "0.5",
            "--guard",
            "0.3",
        ],
    );
    let mut pc = open(&dte.1);
    assert_eq!(dial(&mut pc, &opts("777")).await.unwrap(), "CONNECT 1200");
    let got = read_n(&mut pc, 14, Duration::from_secs(3)).await;
    assert_eq!(
        LineAssembler::new().feed(&got),
        ["NO CARRIER"],
        "{:?}",
        String::from_utf8_lossy(&got)
    );
    modem.wait_for("carrier_lost", Duration::from_secs(1), |_| true);
    let o = DialOptions {
        guard: Duration::from_millis(400),
        command_timeout: Duration::from_secs(1),
        ..Default::default()
    };
    hang_up(&mut pc, &o).await.unwrap();
    // "+++" went into the command line ahead of ATH; the modem hunted for AT.
    let ath = modem
        .of("command")
        .into_iter()
        .last()
        .expect("a command after the drop");
    assert_eq!(ath["command"], "ATH");
    assert_eq!(ath["raw"], "+++ATH");
    assert!(modem.of("escape").is_empty());
}
