//! Serving through abuse: `hartkit serve --sim` (a real-time 1200 bit/s loop behind
//! it) is flooded for several seconds with UDP datagrams from many source ports of
//! other addresses (127.0.0.2, 127.0.0.3): random bytes, session initiates, and
//! initiates followed by requests for the slow loop that are never waited for. A
//! well-behaved client on 127.0.0.1 is answered within its time-out throughout (a
//! reply, or "busy" for the loop), new clients get sessions, the loop serves it again
//! soon after the flood, and the server's resident memory stays under the documented
//! bound (docs/hart-ip.md, "Serving through abuse").

use std::io::{BufRead, BufReader};
use std::net::UdpSocket;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

mod common;
use common::Kill;

/// The bound on the server's resident memory during the flood, KiB.
const RSS_BOUND_KIB: u64 = 64 * 1024;

fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

const INITIATE: [u8; 13] = [1, 0, 0, 0, 0, 1, 0, 13, 1, 0, 0, 0xEA, 0x60];

/// A token-passing request (sequence `seq`) for `pdu`.
fn tp(seq: u16, pdu: &[u8]) -> Vec<u8> {
    let mut m = vec![1, 0, 3, 0];
    m.extend(seq.to_be_bytes());
    m.extend(((8 + pdu.len()) as u16).to_be_bytes());
    m.extend_from_slice(pdu);
    m
}

/// Command 1 to polling address 1 (the pressure transmitter on the loop).
const PV_AT_1: [u8; 4] = [0x02, 0x81, 0x01, 0x00];

fn pdu_with_checksum(p: &[u8]) -> Vec<u8> {
    let mut v = p.to_vec();
    v.push(p.iter().fold(0, |a, b| a ^ b));
    v
}

/// A client that behaves: its own session, a request, an answer or a time-out.
struct Client {
    sock: UdpSocket,
    seq: u16,
}

impl Client {
    fn open(server: &str) -> Option<Client> {
        let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
        sock.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        sock.send_to(&INITIATE, server).unwrap();
        let mut buf = [0u8; 512];
        let (n, from) = sock.recv_from(&mut buf).ok()?;
        if n < 8 || buf[3] != 0 {
            return None;
        }
        sock.connect(from).unwrap();
        Some(Client { sock, seq: 1 })
    }

    /// Ends the session.
    fn close(mut self) {
        self.seq += 1;
        let mut m = vec![1, 0, 1, 0];
        m.extend(self.seq.to_be_bytes());
        m.extend(8u16.to_be_bytes());
        let _ = self.sock.send(&m);
    }

    /// The response code of the reply to `pdu`, or `None` without an answer in 5 s.
    fn ask(&mut self, pdu: &[u8]) -> Option<u8> {
        self.seq += 1;
        self.sock
            .send(&tp(self.seq, &pdu_with_checksum(pdu)))
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(5);
        let mut buf = [0u8; 512];
        while Instant::now() < deadline {
            let Ok(n) = self.sock.recv(&mut buf) else {
                return None;
            };
            // A response (not a publish message) with our sequence number.
            if n >= 8 + 7 && buf[1] == 1 && u16::from_be_bytes([buf[4], buf[5]]) == self.seq {
                // PDU: delimiter, address, command, byte count, response code.
                let pdu = &buf[8..n];
                let addr_len = if pdu[0] & 0x80 != 0 { 5 } else { 1 };
                return pdu.get(1 + addr_len + 2).copied();
            }
        }
        None
    }
}

/// Floods from `ip` until `stop`: many source ports, each sending a mix of random
/// bytes, session initiates and requests for the loop it never waits for.
fn flood(ip: &'static str, server: String, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<u64> {
    std::thread::spawn(move || {
        let mut socks: Vec<UdpSocket> = (0..200)
            .filter_map(|_| UdpSocket::bind(format!("{ip}:0")).ok())
            .collect();
        for s in &socks {
            let _ = s.set_nonblocking(true);
        }
        let mut sent = 0u64;
        let mut rng = hart_rng::Rng::new(0x1234_5678);
        let mut rnd = || rng.next_u64() as u32;
        let pass_through = tp(2, &pdu_with_checksum(&PV_AT_1));
        let mut buf = [0u8; 512];
        while !stop.load(Ordering::Relaxed) {
            for s in socks.iter_mut() {
                let r = rnd();
                let msg: Vec<u8> = match r % 3 {
                    0 => (0..(r % 300) as usize)
                        .map(|i| (r >> (i % 24)) as u8)
                        .collect(),
                    1 => INITIATE.to_vec(),
                    _ => [&INITIATE[..], &pass_through[..]].concat(),
                };
                if s.send_to(&msg, &server).is_ok() {
                    sent += 1;
                }
                // Answers are read and thrown away (a real flood would not read them).
                while s.recv(&mut buf).is_ok() {}
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        sent
    })
}

#[test]
fn serves_well_behaved_clients_through_a_flood() {
    let mut server = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args([
            "serve",
            "--hart-ip",
            "127.0.0.1:0",
            "--sim",
            "pressure",
            "temperature",
        ])
        .args(["--max-sessions", "3000", "--udp", "--run-for", "300"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    let _ = BufReader::new(server.stdout.take().unwrap()).read_line(&mut line);
    let addr = line.split_whitespace().nth(2).unwrap().to_string();
    let pid = server.id();
    let _server = Kill(server);
    let before = rss_kib(pid);

    let mut good = Client::open(&addr).expect("a session before the flood");
    assert_eq!(
        good.ask(&PV_AT_1),
        Some(0),
        "the loop answers before the flood"
    );

    let stop = Arc::new(AtomicBool::new(false));
    let floods = [
        flood("127.0.0.2", addr.clone(), stop.clone()),
        flood("127.0.0.3", addr.clone(), stop.clone()),
    ];
    let start = Instant::now();
    let mut peak = before;
    let (mut answered, mut busy, mut asked) = (0, 0, 0);
    while start.elapsed() < Duration::from_secs(8) {
        // The I/O system answers at once; the loop answers or says "busy" (32).
        asked += 2;
        match good.ask(&[0x02, 0x80, 0x00, 0x00]) {
            Some(0) => answered += 1,
            other => panic!("command 0 at polling address 0 during the flood: {other:?}"),
        }
        match good.ask(&PV_AT_1) {
            Some(0) => answered += 1,
            Some(32) => busy += 1,
            other => panic!("command 1 at polling address 1 during the flood: {other:?}"),
        }
        // A new client gets a session too.
        Client::open(&addr)
            .expect("a new session during the flood")
            .close();
        peak = peak.max(rss_kib(pid));
        std::thread::sleep(Duration::from_millis(200));
    }
    stop.store(true, Ordering::Relaxed);
    let sent: u64 = floods.into_iter().map(|f| f.join().unwrap()).sum();
    eprintln!(
        "flood: {sent} datagrams; well-behaved client: {asked} requests, {answered} answered, {busy} busy; resident memory {before} KiB before, {peak} KiB at most"
    );
    assert!(sent > 10_000, "the flood ran: {sent} datagrams");
    assert!(
        peak < RSS_BOUND_KIB,
        "resident memory {peak} KiB during the flood (bound {RSS_BOUND_KIB} KiB)"
    );
    // The loop serves the well-behaved client again soon after the flood.
    let again = Instant::now();
    loop {
        match good.ask(&PV_AT_1) {
            Some(0) => break,
            _ if again.elapsed() < Duration::from_secs(30) => {
                std::thread::sleep(Duration::from_millis(500))
            }
            other => panic!("the loop after the flood: {other:?}"),
        }
    }
}
