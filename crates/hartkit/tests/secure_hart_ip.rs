//! HART-IP version 2 security end to end: `hartkit serve --psk-file` against hartkit's
//! own `tls://` and `dtls://` clients and against `openssl s_client -psk` (TLS 1.2,
//! TLS 1.3 and DTLS 1.2), a wrong key, an unknown identity and plain HART-IP on the
//! secure port refused with a log line naming the cause while the server goes on, a
//! read-only identity, and the `--plain` port beside the secure one.
//!
//! The `openssl` command comes with the system's OpenSSL; without it those checks say
//! so and are skipped.

use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

const KEY: &str = "00112233445566778899aabbccddeeff";

mod common;
use common::hartkit;

/// A secure server with a plain port beside it; its log (standard error) is read
/// when it is stopped.
struct Server {
    child: Child,
    secure: String,
    plain: String,
    psk_file: std::path::PathBuf,
}

impl Server {
    fn start() -> Server {
        let psk_file =
            std::env::temp_dir().join(format!("hartkit-keys-{}.psk", std::process::id()));
        std::fs::write(
            &psk_file,
            format!("# test keys\nplant-host:{KEY}\nviewer:ffeeddccbbaa99887766554433221100:read-only\n"),
        )
        .unwrap();
        let mut child = Command::new(env!("CARGO_BIN_EXE_hartkit"))
            .args([
                "serve",
                "--hart-ip",
                "127.0.0.1:0",
                "--sim",
                "pressure",
                "valve",
            ])
            .arg("--psk-file")
            .arg(&psk_file)
            .args(["--plain", "127.0.0.1:0", "--run-for", "300"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let addr = |line: &str| line.split_whitespace().nth(2).unwrap_or("").to_string();
        let mut first = String::new();
        let _ = out.read_line(&mut first);
        assert!(first.contains("DTLS/TLS with pre-shared keys"), "{first}");
        let mut second = String::new();
        let _ = out.read_line(&mut second);
        assert!(second.starts_with("hart-ip plain:"), "{second}");
        Server {
            child,
            secure: addr(&first),
            plain: addr(&second.replacen("hart-ip plain:", "hart-ip:", 1)),
            psk_file,
        }
    }

    /// Stops the server and returns what it logged.
    fn stop(mut self) -> String {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let mut log = String::new();
        if let Some(mut e) = self.child.stderr.take() {
            let _ = e.read_to_string(&mut log);
        }
        let _ = std::fs::remove_file(&self.psk_file);
        log
    }
}

/// Session initiate (HART-IP 2, 60 s), command 0 to polling address 0, session close.
const SESSION: &[u8] = &[
    0x02, 0x00, 0x00, 0x00, 0x00, 0x01, 0x00, 0x0D, 0x01, 0x00, 0x00, 0xEA, 0x60, // initiate
    0x02, 0x00, 0x03, 0x00, 0x00, 0x02, 0x00, 0x0D, 0x02, 0x80, 0x00, 0x00, 0x82, // cmd 0
    0x02, 0x00, 0x01, 0x00, 0x00, 0x03, 0x00, 0x08, // close
];

/// Runs `openssl s_client` with `args`, the three messages on its input; `None` when
/// there is no openssl command.
fn s_client(args: &[&str]) -> Option<(bool, Vec<u8>)> {
    let mut child = Command::new("openssl")
        .arg("s_client")
        .args(args)
        .arg("-quiet")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .ok()?;
    let mut stdin = child.stdin.take().unwrap();
    stdin.write_all(SESSION).unwrap();
    // DTLS: keep the input open until the answers are in (s_client ends at EOF).
    std::thread::sleep(Duration::from_millis(1500));
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    Some((out.status.success(), out.stdout))
}

/// The replies hold the I/O system's command 0 answer: device profile 68 after the
/// expanded device type 26FF.
fn has_io_system_identity(reply: &[u8]) -> bool {
    reply.windows(2).any(|w| w == [0x26, 0xFF]) && reply.contains(&68)
}

#[test]
fn secure_hart_ip_with_pre_shared_keys() {
    let server = Server::start();
    let tls = format!("tls://{}", server.secure);
    let dtls = format!("dtls://{}", server.secure);
    let psk = format!("plant-host:{KEY}");

    // hartkit's own clients, with --psk and with --psk-file.
    let (code, out, err) = hartkit(&[
        "read", "-p", &tls, "--psk", &psk, "--poll", "1", "pv", "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("\"units_symbol\": \"kPa\""), "{out}");
    let file = server.psk_file.display().to_string();
    let (code, out, err) = hartkit(&[
        "read",
        "-p",
        &dtls,
        "--psk-file",
        &file,
        "--poll",
        "1",
        "pv",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("kPa"), "{out}");
    // A secure target without a key says what is missing.
    let (code, _, err) = hartkit(&["read", "-p", &tls, "--poll", "1", "pv"]);
    assert_eq!(code, 2);
    assert!(err.contains("needs a pre-shared key"), "{err}");

    // A wrong key and an unknown identity are refused; the server goes on.
    let (code, _, err) = hartkit(&[
        "read",
        "-p",
        &tls,
        "--psk",
        "plant-host:ffffffffffffffffffffffffffffffff",
        "--poll",
        "1",
        "pv",
    ]);
    assert_eq!(
        code, 5,
        "a refused handshake is an I/O error, not a usage error"
    );
    assert!(err.contains("refused the TLS handshake"), "{err}");
    let (code, _, _) = hartkit(&[
        "read",
        "-p",
        &dtls,
        "--psk",
        &format!("intruder:{KEY}"),
        "--poll",
        "1",
        "pv",
    ]);
    assert_ne!(code, 0);
    // Plain HART-IP on the secure UDP port gets nothing; on the plain port it works.
    let (code, _, _) = hartkit(&[
        "read",
        "-p",
        &format!("udp://{}", server.secure),
        "--poll",
        "0",
        "info",
    ]);
    assert_ne!(code, 0);
    let (code, _, err) = hartkit(&[
        "read",
        "-p",
        &format!("udp://{}", server.plain),
        "--poll",
        "1",
        "pv",
    ]);
    assert_eq!(code, 0, "{err}");

    // A read-only identity reads but may not write.
    let viewer = "viewer:ffeeddccbbaa99887766554433221100";
    let (code, _, err) = hartkit(&["read", "-p", &tls, "--psk", viewer, "--poll", "1", "pv"]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = hartkit(&[
        "write",
        "-p",
        &tls,
        "--psk",
        viewer,
        "--poll",
        "1",
        "message",
        "NOT ALLOWED",
    ]);
    assert_eq!(code, 4, "{err}");
    assert!(err.contains("access restricted"), "{err}");

    // openssl s_client: TLS 1.2, TLS 1.3 and DTLS 1.2 carry a session.
    let connect = server.secure.clone();
    let common = [
        "-connect",
        connect.as_str(),
        "-psk",
        KEY,
        "-psk_identity",
        "plant-host",
    ];
    match s_client(&[&common[..], &["-tls1_2"]].concat()) {
        None => eprintln!("no openssl command; skipping the s_client checks"),
        Some((ok, reply)) => {
            assert!(
                ok && has_io_system_identity(&reply),
                "TLS 1.2: {reply:02X?}"
            );
            let (ok, reply) = s_client(&[&common[..], &["-tls1_3"]].concat()).unwrap();
            assert!(
                ok && has_io_system_identity(&reply),
                "TLS 1.3: {reply:02X?}"
            );
            let (_, reply) = s_client(&[&common[..], &["-dtls1_2"]].concat()).unwrap();
            assert!(has_io_system_identity(&reply), "DTLS 1.2: {reply:02X?}");
            // A wrong key fails the handshake: no HART-IP answer.
            let bad = [
                "-connect",
                connect.as_str(),
                "-psk",
                "0f0f0f0f0f0f0f0f0f0f0f0f0f0f0f0f",
                "-psk_identity",
                "plant-host",
                "-tls1_2",
            ];
            let (ok, reply) = s_client(&bad).unwrap();
            assert!(!ok && !has_io_system_identity(&reply));
        }
    }
    // Still serving everyone else.
    let (code, _, err) = hartkit(&["read", "-p", &tls, "--psk", &psk, "--poll", "2", "pv"]);
    assert_eq!(code, 0, "{err}");

    let log = server.stop();
    assert!(
        log.contains("wrong key for PSK identity \"plant-host\""),
        "{log}"
    );
    assert!(log.contains("unknown PSK identity \"intruder\""), "{log}");
    assert!(log.contains("not a DTLS handshake"), "{log}");
    assert!(log.contains("identity \"viewer\" (ReadOnly)"), "{log}");
}
