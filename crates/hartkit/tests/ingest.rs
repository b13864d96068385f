//! Many gateways, one historian: `hartkit serve --sim --instant --mqtt ... --history
//! OWN.sqlite` gateways publish to a broker (Debian's mosquitto) or to a 3-node
//! nats-server cluster (its MQTT listener on JetStream, one node killed with SIGKILL
//! mid-run), and `hartkit history ingest` stores what they publish in one SQLite
//! historian. Each gateway's own `--history` file records every change it made, an
//! independent reference: every value change a gateway recorded while it published
//! must be in the shared historian, at the same millisecond, with the same value, and
//! every sample there must be the value the gateway had at its time, stored once.
//!
//! Skipped with a printed reason when mosquitto (or the nats-server binary that
//! `.ci/run` builds into target/nats-server/) is missing, unless
//! HARTKIT_REQUIRE_INTEROP=1; the cluster check also when HARTKIT_SKIP_NATS=1 (set
//! by `.ci/run` when there is no Go toolchain to build nats-server with).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use hart_history::{Agg, Query, Store, Var};

mod common;
use common::{workspace, Kill};

fn required() -> bool {
    std::env::var("HARTKIT_REQUIRE_INTEROP").is_ok_and(|v| v == "1")
}

fn skip(why: &str) {
    if required() {
        panic!("HARTKIT_REQUIRE_INTEROP=1 but {why}");
    }
    eprintln!("skipped: {why}");
}

fn mosquitto() -> Option<PathBuf> {
    let found = ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
        .iter()
        .map(PathBuf::from)
        .find(|p| p.exists());
    if found.is_none() {
        skip("mosquitto is not installed (apt-get install mosquitto)");
    }
    found
}

fn nats_server() -> Option<PathBuf> {
    let p = std::env::var_os("HARTKIT_NATS_SERVER")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace().join("target/nats-server/nats-server"));
    if p.exists() {
        Some(p)
    } else if std::env::var("HARTKIT_SKIP_NATS").is_ok_and(|v| v == "1") {
        // .ci/run found no Go toolchain to build it with.
        eprintln!("skipped: no nats-server, and no go to build it (HARTKIT_SKIP_NATS=1)");
        None
    } else {
        skip(&format!(
            "no nats-server at {} (.ci/run builds it: GOBIN=target/nats-server go install github.com/nats-io/nats-server/v2@v2.15.2)",
            p.display()
        ));
        None
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn wait_port(port: u16, what: &str) {
    let deadline = Instant::now() + Duration::from_secs(15);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < deadline, "{what} did not listen on {port}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn log_file(dir: &Path, name: &str) -> std::fs::File {
    std::fs::File::create(dir.join(format!("{name}.log"))).unwrap()
}

fn read_log(dir: &Path, name: &str) -> String {
    std::fs::read_to_string(dir.join(format!("{name}.log"))).unwrap_or_default()
}

/// `hartkit serve --sim PROFILES --instant` publishing as edge node `edge` of group
/// Plant, with its own history in DIR/EDGE.sqlite, for `secs` seconds.
fn gateway(dir: &Path, url: &str, edge: &str, sim: &[&str], qos: &str, secs: u32) -> Kill {
    let child = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["serve", "--instant", "--poll-period", "0.2", "--sim"])
        .args(sim)
        .args(["--mqtt", url, "--group", "Plant", "--edge-node", edge])
        .args(["--mqtt-qos", qos, "--run-for", &secs.to_string()])
        .arg("--history")
        .arg(dir.join(format!("{edge}.sqlite")))
        .args(["--log-level", "info"])
        .stdout(Stdio::null())
        .stderr(log_file(dir, edge))
        .spawn()
        .unwrap();
    Kill(child)
}

/// `hartkit history ingest` into DIR/shared.sqlite, as client `hartkit-test-ingest`.
fn ingest(dir: &Path, url: &str) -> Kill {
    ingest_into(
        dir,
        url,
        "ingest",
        &dir.join("shared.sqlite").display().to_string(),
    )
}

/// `hartkit history ingest` into `db`, as client `hartkit-test-NAME`, logging to
/// DIR/NAME.log; returns once it has subscribed.
fn ingest_into(dir: &Path, url: &str, name: &str, db: &str) -> Kill {
    let child = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["history", "ingest", "--mqtt", url, "--group", "Plant"])
        .args(["--history", db])
        .args(["--client-id", &format!("hartkit-test-{name}")])
        .args(["--log-level", "info"])
        .stdout(log_file(dir, &format!("{name}-out")))
        .stderr(log_file(dir, name))
        .spawn()
        .unwrap();
    // Subscribed, and still so 2 s later: a new cluster's JetStream may close the
    // first connections while it sets up the MQTT streams, and a session's first
    // subscription only takes what is published after it is in place.
    let deadline = Instant::now() + Duration::from_secs(40);
    let mut settled_since: Option<(Instant, usize)> = None;
    loop {
        let log = read_log(dir, name);
        let sub = log.rfind("subscribed to spBv1.0/Plant/#");
        let lost = log
            .rfind("connection lost")
            .max(log.rfind("cannot connect"));
        if sub.is_some() && sub > lost {
            match settled_since {
                Some((t, len)) if len == log.len() => {
                    if t.elapsed() >= Duration::from_secs(2) {
                        break;
                    }
                }
                _ => settled_since = Some((Instant::now(), log.len())),
            }
        } else {
            settled_since = None;
        }
        assert!(
            Instant::now() < deadline,
            "the ingest did not subscribe:\n{log}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    Kill(child)
}

/// mosquitto on a free loopback port with `extra` lines of configuration, up; and its
/// URL.
fn start_mosquitto(mosquitto: &Path, dir: &Path, extra: &str) -> (Kill, String) {
    let port = free_port();
    std::fs::write(
        dir.join("mosquitto.conf"),
        format!("listener {port} 127.0.0.1\nallow_anonymous true\n{extra}"),
    )
    .unwrap();
    let broker = Kill(
        Command::new(mosquitto)
            .arg("-c")
            .arg(dir.join("mosquitto.conf"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    wait_port(port, "mosquitto");
    (broker, format!("mqtt://127.0.0.1:{port}"))
}

/// Waits for a gateway's --run-for to end.
fn finish(mut g: Kill, dir: &Path, edge: &str) {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        if let Some(status) = g.0.try_wait().unwrap() {
            assert!(
                status.success(),
                "{edge}: {status}\n{}",
                read_log(dir, edge)
            );
            return;
        }
        assert!(Instant::now() < deadline, "{edge} did not stop");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// SIGINT (Ctrl-C): the ingest commits, disconnects and prints its summary.
fn stop_ingest(i: Kill, dir: &Path) -> String {
    stop_ingest_named(i, dir, "ingest")
}

fn stop_ingest_named(mut i: Kill, dir: &Path, name: &str) -> String {
    let pid = i.0.id().to_string();
    assert!(Command::new("kill")
        .args(["-INT", &pid])
        .status()
        .unwrap()
        .success());
    let status = i.0.wait().unwrap();
    let out = read_log(dir, &format!("{name}-out"));
    assert!(
        status.success(),
        "{name}: {status}\n{out}\n{}",
        read_log(dir, name)
    );
    out
}

/// (time in ms, value) of every stored sample of each (device, variable).
type Series = BTreeMap<(String, Var), Vec<(i64, Option<u64>)>>;

fn series(db: &Path) -> Series {
    series_of(db.to_str().unwrap())
}

fn series_of(db: &str) -> Series {
    let mut store = Store::open(db, false).unwrap();
    let mut out = Series::new();
    for d in store.devices().unwrap() {
        for var in Var::ALL {
            let points = store
                .query(&Query {
                    device: d.unique_id.clone(),
                    var,
                    from: UNIX_EPOCH + Duration::from_secs(1),
                    to: SystemTime::now() + Duration::from_secs(3600),
                    every: None,
                    agg: Agg::Mean,
                })
                .unwrap();
            if points.is_empty() {
                continue;
            }
            let v = points
                .iter()
                .map(|p| {
                    let us = hart_history::micros(p.time);
                    (us.div_euclid(1000), p.value.map(f64::to_bits))
                })
                .collect();
            out.insert((d.unique_id.clone(), var), v);
        }
    }
    out
}

/// Checks the shared historian against one gateway's own history: every sample of
/// the gateway's devices in the shared one is the value the gateway recorded for that
/// millisecond (a change then, or the value in effect) and, between the first and the last the shared one
/// holds, every value change the gateway recorded is there. Returns how many changes
/// were checked.
fn compare(edge: &str, own: &Series, shared: &Series) -> usize {
    let mut checked = 0;
    assert!(!own.is_empty(), "{edge} recorded nothing");
    for (key, rows) in own {
        let got = shared
            .get(key)
            .unwrap_or_else(|| panic!("{edge}: {key:?} is not in the shared historian"));
        let recorded: BTreeMap<i64, Option<u64>> = rows.iter().copied().collect();
        let times: BTreeSet<i64> = got.iter().map(|r| r.0).collect();
        assert_eq!(times.len(), got.len(), "{edge} {key:?}: a time twice");
        for r in got {
            // The value the gateway had at that time: a change recorded then, or the
            // last one before (a birth states every current value again).
            let Some(then) = recorded.range(..=r.0).next_back().map(|(_, v)| *v) else {
                // Before the gateway's own history has its first row of it (its
                // historian starts after the publisher's first look at the image).
                continue;
            };
            assert_eq!(
                then,
                r.1,
                "{edge} {key:?}: {:?} at {} ms in the shared historian is not what the gateway recorded ({:?} ...)",
                r.1.map(f64::from_bits),
                r.0,
                recorded
                    .range(r.0 - 2000..r.0 + 2000)
                    .map(|(t, v)| (t - r.0, v.map(f64::from_bits)))
                    .collect::<Vec<_>>()
            );
        }
        let (first, last) = (got[0].0, got[got.len() - 1].0);
        let stored: BTreeSet<&(i64, Option<u64>)> = got.iter().collect();
        // The gateway's first row is not a change: its historian may start after
        // the publisher's first look at the device, whose birth states the value
        // earlier.
        let mut previous = None;
        for r in rows {
            let change = previous.is_some() && previous != Some(r.1);
            previous = Some(r.1);
            if change && r.0 >= first && r.0 <= last {
                checked += 1;
                assert!(
                    stored.contains(r),
                    "{edge} {key:?}: the change to {:?} at {} ms is missing from the shared historian",
                    r.1.map(f64::from_bits),
                    r.0
                );
            }
        }
    }
    checked
}

#[test]
fn two_gateways_one_broker_one_historian() {
    let Some(mosquitto) = mosquitto() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let _keep = KeepOnFailure(dir.to_path_buf());
    let (_broker, url) = start_mosquitto(&mosquitto, dir, "");
    // gwA starts before the ingest: the ingest sees its data before any birth and
    // asks it for a rebirth (NCMD), which a real edge node answers.
    let a = gateway(dir, &url, "gwA", &["pressure", "pressure"], "0", 8);
    std::thread::sleep(Duration::from_secs(2));
    let i = ingest(dir, &url);
    let b = gateway(dir, &url, "gwB", &["temperature", "valve"], "1", 6);
    finish(a, dir, "gwA");
    finish(b, dir, "gwB");
    std::thread::sleep(Duration::from_millis(1500));
    let summary = stop_ingest(i, dir);
    eprintln!("{summary}");
    assert!(
        read_log(dir, "gwA").contains("rebirth asked by NCMD"),
        "{summary}\n{}",
        read_log(dir, "ingest")
    );
    let out = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["history", "devices", "--json", "--db"])
        .arg(dir.join("shared.sqlite"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let devices: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ids: BTreeSet<String> = devices
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["unique_id"].as_str().unwrap().to_string())
        .collect();
    let shared = series(&dir.join("shared.sqlite"));
    let mut all = BTreeSet::new();
    for edge in ["gwA", "gwB"] {
        let own = series(&dir.join(format!("{edge}.sqlite")));
        all.extend(own.keys().map(|k| k.0.clone()));
        let n = compare(edge, &own, &shared);
        eprintln!("{edge}: {n} changes checked");
        assert!(n > 20, "{edge}: only {n} changes");
    }
    assert_eq!(
        ids, all,
        "hartkit history devices lists every device of both"
    );
    assert_eq!(ids.len(), 4);
}

/// The ingest killed with SIGKILL five times while a gateway publishes at QoS 1, each
/// time at another point (between commits, in one, while the broker delivers what was
/// queued for it), and started again: the shared historian holds, exactly once, every
/// change the gateway recorded, since a message is acknowledged only once its
/// samples are committed and the broker keeps the rest for the session.
#[test]
fn the_ingest_killed_five_times_loses_nothing() {
    let Some(mosquitto) = mosquitto() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let _keep = KeepOnFailure(dir.to_path_buf());
    let (_broker, url) = start_mosquitto(&mosquitto, dir, "max_queued_messages 100000\n");
    let mut i = ingest(dir, &url);
    let g = gateway(
        dir,
        &url,
        "gwK",
        &["pressure", "temperature", "valve"],
        "1",
        30,
    );
    // Points spread over the commit period (250 ms) and the run: not round numbers.
    for (n, wait_ms) in [1730u64, 2910, 1370, 3130, 2290].into_iter().enumerate() {
        std::thread::sleep(Duration::from_millis(wait_ms));
        drop(i); // SIGKILL, and waited for
                 // Away for a while: the broker queues for the session meanwhile.
        std::thread::sleep(Duration::from_millis(300 + 200 * n as u64));
        i = ingest(dir, &url);
    }
    finish(g, dir, "gwK");
    std::thread::sleep(Duration::from_millis(2000));
    let summary = stop_ingest(i, dir);
    eprintln!("{summary}");
    let shared = series(&dir.join("shared.sqlite"));
    let own = series(&dir.join("gwK.sqlite"));
    let n = compare("gwK", &own, &shared);
    eprintln!("gwK: {n} changes checked");
    assert!(n > 50, "gwK: only {n} changes");
}

/// On a failed assertion, the processes' logs and databases are copied to
/// target/ingest-test-failure/ (the temporary directory goes).
struct KeepOnFailure(PathBuf);

impl Drop for KeepOnFailure {
    fn drop(&mut self) {
        if std::thread::panicking() {
            let to = workspace().join("target/ingest-test-failure");
            let _ = std::fs::create_dir_all(&to);
            for e in std::fs::read_dir(&self.0).into_iter().flatten().flatten() {
                if e.path().is_file() {
                    let _ = std::fs::copy(e.path(), to.join(e.file_name()));
                }
            }
            eprintln!("logs and databases kept in {}", to.display());
        }
    }
}

/// A node of the nats cluster.
struct Node {
    child: Option<Child>,
    mqtt: u16,
}

impl Drop for Node {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn nats_cluster(bin: &Path, dir: &Path) -> Vec<Node> {
    let routes: Vec<u16> = (0..3).map(|_| free_port()).collect();
    let route_list = routes
        .iter()
        .map(|p| format!("nats-route://127.0.0.1:{p}"))
        .collect::<Vec<_>>()
        .join(", ");
    let mut nodes = vec![];
    for (i, route) in routes.iter().enumerate() {
        let (client, mqtt) = (free_port(), free_port());
        let store = dir.join(format!("js{i}"));
        let conf = dir.join(format!("n{i}.conf"));
        std::fs::write(
            &conf,
            format!(
                "server_name: n{i}\nlisten: 127.0.0.1:{client}\n\
                 jetstream {{ store_dir: \"{}\" }}\n\
                 cluster {{ name: hk, listen: 127.0.0.1:{route}, routes: [{route_list}] }}\n\
                 mqtt {{ listen: 127.0.0.1:{mqtt} }}\n",
                store.display()
            ),
        )
        .unwrap();
        let child = Command::new(bin)
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(log_file(dir, &format!("n{i}")))
            .spawn()
            .unwrap();
        nodes.push(Node {
            child: Some(child),
            mqtt,
        });
    }
    for (i, n) in nodes.iter().enumerate() {
        wait_port(n.mqtt, &format!("nats-server n{i}"));
    }
    nodes
}

#[test]
fn a_broker_node_killed_loses_nothing_at_qos_1() {
    let Some(bin) = nats_server() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let _keep = KeepOnFailure(dir.to_path_buf());
    let mut nodes = nats_cluster(&bin, dir);
    let m: Vec<u16> = nodes.iter().map(|n| n.mqtt).collect();
    let url = |order: [usize; 3]| {
        format!(
            "mqtt://127.0.0.1:{},127.0.0.1:{},127.0.0.1:{}",
            m[order[0]], m[order[1]], m[order[2]]
        )
    };
    // The ingest on node 3 into SQLite, and a second one (its own session) into
    // PostgreSQL when the server is installed; the gateways on nodes 1 and 2.
    let pg = hart_history::pgtest::for_test(false);
    let i = ingest(dir, &url([2, 0, 1]));
    let ipg = pg
        .as_ref()
        .map(|pg| ingest_into(dir, &url([2, 0, 1]), "ingest-pg", &pg.url()));
    let a = gateway(
        dir,
        &url([0, 1, 2]),
        "gwA",
        &["pressure", "pressure"],
        "1",
        30,
    );
    let b = gateway(
        dir,
        &url([1, 2, 0]),
        "gwB",
        &["temperature", "valve"],
        "1",
        30,
    );
    std::thread::sleep(Duration::from_secs(6));
    // kill -9 the node gwA is connected to (and the ingest, after the first
    // connections a new cluster closes, may be too). nats-server takes 10 s or so
    // here to elect new JetStream leaders and let the clean session of gwA in on
    // another node ("other session ... in the process of connecting" meanwhile),
    // hence the gateways' 30 s.
    if let Some(mut c) = nodes[0].child.take() {
        c.kill().unwrap();
        c.wait().unwrap();
    }
    finish(a, dir, "gwA");
    finish(b, dir, "gwB");
    std::thread::sleep(Duration::from_secs(2));
    let summary = stop_ingest(i, dir);
    eprintln!("{summary}");
    let pg_summary = ipg.map(|i| stop_ingest_named(i, dir, "ingest-pg"));
    let gwa = read_log(dir, "gwA");
    assert!(
        gwa.contains("connected to") && gwa.matches("connected to").count() >= 2,
        "gwA did not move to another node:\n{gwa}"
    );
    let shared = series(&dir.join("shared.sqlite"));
    for edge in ["gwA", "gwB"] {
        let own = series(&dir.join(format!("{edge}.sqlite")));
        let n = compare(edge, &own, &shared);
        eprintln!("{edge}: {n} changes checked");
        assert!(n > 20, "{edge}: only {n} changes");
    }
    if let (Some(pg), Some(summary)) = (&pg, pg_summary) {
        eprintln!("PostgreSQL {summary}");
        let shared = series_of(&pg.url());
        for edge in ["gwA", "gwB"] {
            let own = series(&dir.join(format!("{edge}.sqlite")));
            let n = compare(edge, &own, &shared);
            eprintln!("{edge}: {n} changes checked in PostgreSQL");
            assert!(n > 20, "{edge}: only {n} changes in PostgreSQL");
        }
    }
}

/// Bad settings are refused with exit code 2 and a message saying what to check,
/// before the database is made.
#[test]
fn ingest_refuses_bad_settings_before_opening_the_database() {
    let tmp = tempfile::tempdir().unwrap();
    let db = tmp.path().join("h.sqlite");
    let db = db.to_str().unwrap();
    for (args, says) in [
        (vec!["--mqtt", "tcp://x"], "unknown scheme"),
        (vec!["--mqtt", "mqtt://a,,b"], "an empty broker"),
        (
            vec!["--mqtt", "mqtt://a", "--group", "a/b"],
            "Sparkplug group ID",
        ),
        (
            vec![
                "--mqtt",
                "mqtt://a",
                "--username",
                "u",
                "--password-file",
                "/nonexistent",
            ],
            "check the path",
        ),
        (
            vec!["--mqtt", "mqtt://a", "--ca-file", "/etc/hosts"],
            "not mqtts://",
        ),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_hartkit"))
            .args(["history", "ingest", "--history", db])
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
    assert!(!Path::new(db).exists());
}

/// The interop venv's Python with paho-mqtt (scripts/interop/setup), if there.
fn paho_python() -> Option<PathBuf> {
    let python = workspace().join("target/interop-venv/bin/python");
    let ok = python.exists()
        && Command::new(&python)
            .args(["-c", "import paho.mqtt.client"])
            .status()
            .is_ok_and(|s| s.success());
    if !ok {
        skip("the interop venv with paho-mqtt is missing (scripts/interop/setup)");
        return None;
    }
    Some(python)
}

/// Publishes `sizes` zero-filled messages at QoS 1 on `topic` with paho-mqtt.
fn publish_zeros(python: &Path, url: &str, topic: &str, sizes: &[usize]) {
    let port = url.rsplit(':').next().unwrap();
    let script = "import sys, paho.mqtt.client as m\n\
        c = m.Client(m.CallbackAPIVersion.VERSION2, client_id='hartkit-test-poison')\n\
        c.connect('127.0.0.1', int(sys.argv[1])); c.loop_start()\n\
        for n in sys.argv[3:]:\n    c.publish(sys.argv[2], bytes(int(n)), qos=1).wait_for_publish(10)\n\
        c.disconnect(); c.loop_stop()\n";
    let status = Command::new(python)
        .args(["-c", script, port, topic])
        .args(sizes.iter().map(usize::to_string))
        .status()
        .unwrap();
    assert!(status.success());
}

/// The reproduction of a review: one QoS 1 message of 1.2 MB on the group sent the
/// ingest into a reconnect loop (the persistent session handed the message back each
/// time) and nothing was stored afterwards. Now a message over what the ingest decodes
/// (1.2 MB) is acknowledged and dropped, and one over what its client takes (3 MB)
/// costs one reconnection: the gateway's data published after both are all stored.
#[test]
fn oversized_messages_do_not_stop_the_historian() {
    let Some(mosquitto) = mosquitto() else { return };
    let Some(python) = paho_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let _keep = KeepOnFailure(dir.to_path_buf());
    let (_broker, url) = start_mosquitto(&mosquitto, dir, "");
    let i = ingest(dir, &url);
    publish_zeros(
        &python,
        &url,
        "spBv1.0/Plant/DDATA/gwX/dev1",
        &[1_200_000, 3_000_000],
    );
    let a = gateway(dir, &url, "gwA", &["pressure", "temperature"], "1", 8);
    finish(a, dir, "gwA");
    std::thread::sleep(Duration::from_millis(1500));
    let summary = stop_ingest(i, dir);
    let log = read_log(dir, "ingest");
    let n = compare(
        "gwA",
        &series(&dir.join("gwA.sqlite")),
        &series(&dir.join("shared.sqlite")),
    );
    assert!(n > 20, "only {n} changes stored\n{summary}\n{log}");
    assert!(
        log.contains("more than the 1048576 the ingest decodes"),
        "{log}"
    );
    let lost = log.matches("connection lost").count();
    assert!(lost <= 1, "{lost} connections lost to two messages\n{log}");
}
