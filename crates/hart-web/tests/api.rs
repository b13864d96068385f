//! The dashboard's HTTP API and pages against a real server on a loopback port, over
//! plain HTTP/1.1 written by hand (so what goes on the wire is what the test says):
//! every endpoint, logins and their throttle, CSRF, writes with read-back, and bad
//! input, which must give a 4xx with a JSON error and leave the server serving.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::time::Duration;

use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

const PASSWORD: &str = "correct horse battery staple";

fn local<F: std::future::Future>(f: F) -> F::Output {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    tokio::task::LocalSet::new().block_on(&rt, f)
}

struct Server {
    addr: SocketAddr,
    audit: std::path::PathBuf,
    _dir: tempdir::Dir,
}

mod tempdir {
    /// A directory removed when dropped.
    pub struct Dir(pub std::path::PathBuf);
    impl Dir {
        pub fn new(name: &str) -> Dir {
            let p = std::env::temp_dir().join(format!("hart-web-{name}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&p);
            std::fs::create_dir_all(&p).unwrap();
            Dir(p)
        }
    }
    impl Drop for Dir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// A dashboard on the demo plant (answered in memory), with the password unless
/// `read_only`.
async fn server(name: &str, password: bool, read_only: bool) -> Server {
    let policy = hart_poller::WritePolicy {
        read_only,
        ..Default::default()
    };
    server_on(hart_host::transport::Plant::demo(), name, password, policy).await
}

/// A polling engine on `plant`, answered in memory, its devices found, its writes
/// under `policy`.
async fn engine_on(
    plant: hart_host::transport::Plant,
    policy: hart_poller::WritePolicy,
) -> hart_poller::Engine {
    let (engine, _) = hart_poller::Engine::start_with(
        hart_poller::EngineConfig {
            poll: true,
            ..Default::default()
        },
        vec![hart_poller::LoopSpec {
            settings: Default::default(),
            line: hart_poller::Line::Memory(hart_poller::MemoryLoop::new(plant.devices().unwrap())),
        }],
        hart_poller::StartOptions {
            write_policy: policy,
            ..Default::default()
        },
    );
    engine.ready().await;
    engine
}

/// A dashboard on `plant`.
async fn server_on(
    plant: hart_host::transport::Plant,
    name: &str,
    password: bool,
    policy: hart_poller::WritePolicy,
) -> Server {
    server_full(plant, name, password, policy, |_| {}).await
}

/// A dashboard on the demo plant, its settings changed by `configure`.
async fn server_with(
    name: &str,
    password: bool,
    configure: impl FnOnce(&mut hart_web::WebConfig),
) -> Server {
    server_full(
        hart_host::transport::Plant::demo(),
        name,
        password,
        Default::default(),
        configure,
    )
    .await
}

/// A dashboard on `plant`, its settings changed by `configure`.
async fn server_full(
    plant: hart_host::transport::Plant,
    name: &str,
    password: bool,
    policy: hart_poller::WritePolicy,
    configure: impl FnOnce(&mut hart_web::WebConfig),
) -> Server {
    let dir = tempdir::Dir::new(name);
    let audit = dir.0.join("audit.jsonl");
    let engine = engine_on(
        plant,
        hart_poller::WritePolicy {
            audit: hart_access::Audit::new(Some(audit.clone())),
            ..policy
        },
    )
    .await;
    let mut config = hart_web::WebConfig::new("127.0.0.1:0".parse().unwrap());
    if password {
        let p = dir.0.join("password");
        std::fs::write(&p, format!("{PASSWORD}\n")).unwrap();
        config.admin_password_file = Some(p);
    }
    configure(&mut config);
    let web = hart_web::start(engine, config).await.unwrap();
    let addr = web.addr;
    std::mem::forget(web);
    Server {
        addr,
        audit,
        _dir: dir,
    }
}

#[derive(Debug)]
struct Reply {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Reply {
    fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| {
            panic!(
                "not JSON ({e}): {} {}",
                self.status,
                String::from_utf8_lossy(&self.body)
            )
        })
    }
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
    fn cookies(&self) -> HashMap<String, String> {
        self.headers
            .iter()
            .filter(|(k, _)| k.eq_ignore_ascii_case("set-cookie"))
            .filter_map(|(_, v)| v.split(';').next()?.split_once('='))
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }
}

/// One request on its own connection (`Connection: close`).
async fn request(
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Reply {
    let s = tokio::net::TcpStream::connect(addr).await.unwrap();
    request_on(s, &addr.to_string(), method, path, headers, body).await
}

/// A connection to `addr` from `source` (any of 127/8 on Linux).
async fn connect_from(source: &str, addr: SocketAddr) -> std::io::Result<tokio::net::TcpStream> {
    let s = tokio::net::TcpSocket::new_v4()?;
    s.bind(SocketAddr::new(source.parse().unwrap(), 0))?;
    s.connect(addr).await
}

/// One request on connection `s` with `Host: host` (`Connection: close`).
async fn request_on(
    mut s: tokio::net::TcpStream,
    host: &str,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Reply {
    let mut head = format!(
        "{method} {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\nContent-Length: {}\r\n",
        body.len()
    );
    for (k, v) in headers {
        head.push_str(&format!("{k}: {v}\r\n"));
    }
    head.push_str("\r\n");
    s.write_all(head.as_bytes()).await.unwrap();
    s.write_all(body).await.unwrap();
    let mut raw = vec![];
    tokio::time::timeout(Duration::from_secs(20), s.read_to_end(&mut raw))
        .await
        .expect("the server answers within 20 s")
        .unwrap();
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a whole HTTP head");
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let mut lines = head.lines();
    let status = lines
        .next()
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|s| s.parse().ok())
        .unwrap();
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect();
    let mut body = raw[split + 4..].to_vec();
    if headers
        .iter()
        .any(|(k, v)| k.eq_ignore_ascii_case("transfer-encoding") && v.contains("chunked"))
    {
        body = dechunk(&body);
    }
    Reply {
        status,
        headers,
        body,
    }
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = vec![];
    loop {
        let Some(eol) = b.windows(2).position(|w| w == b"\r\n") else {
            return out;
        };
        let n = usize::from_str_radix(std::str::from_utf8(&b[..eol]).unwrap().trim(), 16).unwrap();
        if n == 0 {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + n]);
        b = &b[eol + 4 + n..];
    }
}

async fn get(addr: SocketAddr, path: &str) -> Reply {
    request(addr, "GET", path, &[], b"").await
}

async fn post_json(addr: SocketAddr, path: &str, headers: &[(&str, &str)], body: &str) -> Reply {
    let mut h = vec![("Content-Type", "application/json")];
    h.extend_from_slice(headers);
    request(addr, "POST", path, &h, body.as_bytes()).await
}

/// Logs in through the API: (cookie header, CSRF token).
async fn login(addr: SocketAddr) -> (String, String) {
    let r = post_json(
        addr,
        "/api/login",
        &[],
        &format!(r#"{{"password": "{PASSWORD}"}}"#),
    )
    .await;
    assert_eq!(r.status, 200, "{}", r.text());
    let cookie = r.cookies()["hartkit_session"].clone();
    let set = r.header("set-cookie").unwrap();
    assert!(
        set.contains("HttpOnly") && set.contains("SameSite=Strict"),
        "{set}"
    );
    (
        format!("hartkit_session={cookie}"),
        r.json()["csrf"].as_str().unwrap().to_string(),
    )
}

fn assert_json_error(r: &Reply, status: u16) {
    assert_eq!(r.status, status, "{}", r.text());
    let v = r.json();
    assert_eq!(v["status"], status);
    assert!(!v["error"].as_str().unwrap().is_empty());
}

#[test]
fn every_read_endpoint_answers() {
    local(async {
        let s = server("reads", false, false).await;
        let a = s.addr;
        let plant = get(a, "/api/devices").await.json();
        let devices = plant["devices"].as_array().unwrap();
        assert!(devices.len() >= 3, "{plant}");
        assert_eq!(plant["loops"][0]["name"], "loop1");
        let d = get(a, "/api/devices/1").await.json();
        assert_eq!(d["unit"], 1);
        // The status words carry the one name every view uses (docs/frame-json.md).
        assert!(d["device_status_set"].is_array(), "{d}");
        let uid = d["unique_id"].as_str().unwrap().to_string();
        let tag = d["tag"].as_str().unwrap().to_string();
        // The same device by unique ID and by tag (any case).
        assert_eq!(
            get(a, &format!("/api/devices/{uid}")).await.json()["unit"],
            1
        );
        assert_eq!(
            get(a, &format!("/api/devices/{}", tag.to_lowercase()))
                .await
                .json()["unit"],
            1
        );
        let id = get(a, "/api/devices/1/identity").await.json();
        assert_eq!(id["command_0"]["command"], 0);
        assert_eq!(id["command_0"]["decoded"]["expansion_code"], 254);
        let vars = get(a, "/api/devices/1/variables").await.json();
        assert_eq!(vars["command"], 9, "{vars}");
        assert_eq!(vars["response_code"], 0, "{vars}");
        let status = get(a, "/api/devices/1/status").await.json();
        assert_eq!(status["command"], 48);
        assert!(status["device_status_set"].is_array(), "{status}");
        let burst = get(a, "/api/devices/2/burst").await.json();
        assert_eq!(burst["command"], 105, "{burst}");
        tokio::time::sleep(Duration::from_millis(1500)).await;
        let h = get(a, "/api/devices/1/history?window=5m").await.json();
        assert_eq!(h["source"], "memory");
        assert!(!h["points"].as_array().unwrap().is_empty(), "{h}");
        let svg = get(a, "/device/1/trend.svg?window=5m").await;
        assert_eq!(svg.header("content-type"), Some("image/svg+xml"));
        assert!(svg.text().starts_with("<svg") && svg.text().contains("<path"));
        let t = get(a, "/api/traffic?limit=20&command=3").await.json();
        let frames = t["frames"].as_array().unwrap();
        assert!(!frames.is_empty(), "{t}");
        assert!(frames
            .iter()
            .all(|f| f["frame"]["command"] == 3 || f["kind"] == "no-reply"));
        let t = get(a, "/api/traffic?device=1&limit=50").await.json();
        for f in t["frames"].as_array().unwrap() {
            if let Some(u) = f["frame"]["address"]["unique_id"].as_str() {
                assert_eq!(u, uid);
            }
        }
        let cap = get(a, "/api/traffic.pcapng?limit=40").await;
        assert_eq!(cap.status, 200);
        assert_eq!(cap.header("content-type"), Some("application/x-pcapng"));
        let frames = hart_capture::read_capture(&cap.body[..]).unwrap();
        assert!(!frames.is_empty() && frames.len() <= 40, "{}", frames.len());
        assert!(frames
            .iter()
            .all(|f| f.valid && f.comment.as_deref() == Some("loop loop1")));
        let session = get(a, "/api/session").await.json();
        assert_eq!(session["writes"], false);
        // Pages.
        for p in ["/", "/device/1", "/traffic", "/login"] {
            let r = get(a, p).await;
            assert_eq!(r.status, 200, "{p}");
            assert!(r.text().contains("<!DOCTYPE html>"));
            assert!(r.header("content-security-policy").is_some());
        }
        assert!(get(a, "/device/1").await.text().contains("Writes are off"));
        let css = get(a, "/assets/style.css").await;
        assert!(css.header("content-type").unwrap().starts_with("text/css"));
    });
}

#[test]
fn the_event_stream_sends_the_plant_at_once() {
    local(async {
        let s = server("events", false, false).await;
        let mut c = tokio::net::TcpStream::connect(s.addr).await.unwrap();
        c.write_all(format!("GET /api/events HTTP/1.1\r\nHost: {}\r\n\r\n", s.addr).as_bytes())
            .await
            .unwrap();
        let mut got = String::new();
        let mut buf = [0u8; 8192];
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        // Two plant events: the first at once, the next as values change.
        while got.matches("event: plant").count() < 2 && tokio::time::Instant::now() < deadline {
            if let Ok(Ok(n)) = tokio::time::timeout(Duration::from_secs(5), c.read(&mut buf)).await
            {
                got.push_str(&String::from_utf8_lossy(&buf[..n]));
            }
        }
        assert!(got.contains("text/event-stream"), "{got}");
        assert!(got.matches("event: plant").count() >= 2, "{got}");
        assert!(got.contains("\"devices\""));
    });
}

#[test]
fn writes_need_a_login_and_the_csrf_token_and_are_read_back() {
    local(async {
        let s = server("writes", true, false).await;
        let a = s.addr;
        let body = r#"{"damping": 2.5}"#;
        // No login.
        assert_json_error(&post_json(a, "/api/devices/1/write", &[], body).await, 401);
        let (cookie, csrf) = login(a).await;
        // No token, a forged one.
        assert_json_error(
            &post_json(a, "/api/devices/1/write", &[("Cookie", &cookie)], body).await,
            403,
        );
        let forged = "0".repeat(64);
        assert_json_error(
            &post_json(
                a,
                "/api/devices/1/write",
                &[("Cookie", &cookie), ("X-CSRF-Token", &forged)],
                body,
            )
            .await,
            403,
        );
        // Another site's page.
        assert_json_error(
            &post_json(
                a,
                "/api/devices/1/write",
                &[
                    ("Cookie", &cookie),
                    ("X-CSRF-Token", &csrf),
                    ("Origin", "http://evil.example"),
                ],
                body,
            )
            .await,
            403,
        );
        let ok = [("Cookie", cookie.as_str()), ("X-CSRF-Token", csrf.as_str())];
        let r = post_json(a, "/api/devices/1/write", &ok, body).await;
        assert_eq!(r.status, 200, "{}", r.text());
        let v = r.json();
        assert_eq!(v["confirmed"], true, "{v}");
        assert_eq!(v["read_back"]["decoded"]["damping"], 2.5);
        let r = post_json(a, "/api/devices/1/write", &ok, r#"{"tag": "PT-777"}"#).await;
        assert_eq!(r.json()["confirmed"], true, "{}", r.text());
        let r = post_json(
            a,
            "/api/devices/1/write",
            &ok,
            r#"{"long_tag": "Pressure north header"}"#,
        )
        .await;
        assert_eq!(r.json()["confirmed"], true, "{}", r.text());
        let r = post_json(
            a,
            "/api/devices/1/write",
            &ok,
            r#"{"upper_range": 300, "range_units": "kPa"}"#,
        )
        .await;
        assert_eq!(r.json()["confirmed"], true, "{}", r.text());
        // A device in multidrop mode has no loop current to fix: the device's refusal
        // is said in words.
        let r = post_json(a, "/api/devices/1/write", &ok, r#"{"loop_test_ma": 12}"#).await;
        assert_json_error(&r, 409);
        assert!(
            r.json()["error"].as_str().unwrap().contains("multidrop"),
            "{}",
            r.text()
        );
        // Every write let through is in the audit, as the web front end: a record
        // before it went, and one with its outcome (the refusal's: "refused").
        let audit = std::fs::read_to_string(&s.audit).unwrap();
        let web: Vec<serde_json::Value> = audit
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .filter(|v: &serde_json::Value| v["front_end"] == "web")
            .collect();
        assert_eq!(
            web.iter().filter(|v| v["outcome"].is_null()).count(),
            5,
            "{audit}"
        );
        assert_eq!(
            web.iter().filter(|v| v["outcome"] == "done").count(),
            4,
            "{audit}"
        );
        assert_eq!(
            web.iter().filter(|v| v["outcome"] == "refused").count(),
            1,
            "{audit}"
        );
        // Bad writes: 4xx with a JSON error.
        for (body, status) in [
            (r#"{"damping": "soft"}"#, 400),
            (r#"{"damping": 1, "tag": "X"}"#, 400),
            (r#"{"colour": "red"}"#, 400),
            (r#"{}"#, 400),
            (r#"[1, 2]"#, 400),
            (r#"{"tag": {"a": 1}}"#, 400),
            (r#"{"loop_test_ma": 40}"#, 400),
            ("not json", 400),
        ] {
            assert_json_error(
                &post_json(a, "/api/devices/1/write", &ok, body).await,
                status,
            );
        }
        assert_json_error(&post_json(a, "/api/devices/99/write", &ok, body).await, 404);
        let wrong_type = request(
            a,
            "POST",
            "/api/devices/1/write",
            &[ok[0], ok[1], ("Content-Type", "text/plain")],
            body.as_bytes(),
        )
        .await;
        assert_json_error(&wrong_type, 415);
        let huge = format!(r#"{{"tag": "{}"}}"#, "A".repeat(64 * 1024));
        assert_json_error(&post_json(a, "/api/devices/1/write", &ok, &huge).await, 413);
        // After logging out, the session is gone.
        let r = request(a, "POST", "/api/logout", &ok, b"").await;
        assert_eq!(r.status, 200);
        assert_json_error(&post_json(a, "/api/devices/1/write", &ok, body).await, 401);
        // The server still serves.
        assert_eq!(get(a, "/api/devices/1").await.status, 200);
    });
}

#[test]
fn the_login_form_and_the_write_forms_carry_their_tokens() {
    local(async {
        let s = server("forms", true, false).await;
        let a = s.addr;
        let page = get(a, "/login").await;
        let token = page.cookies()["hartkit_login"].clone();
        assert!(page.text().contains(&token));
        let cookie = format!("hartkit_login={token}");
        let form = |csrf: &str, pw: &str| format!("csrf={csrf}&password={}", pw.replace(' ', "+"));
        let ctype = ("Content-Type", "application/x-www-form-urlencoded");
        // A form without the page's token is refused.
        let r = request(
            a,
            "POST",
            "/login",
            &[ctype, ("Cookie", &cookie)],
            form("forged", PASSWORD).as_bytes(),
        )
        .await;
        assert_eq!(r.status, 403);
        let r = request(
            a,
            "POST",
            "/login",
            &[ctype, ("Cookie", &cookie)],
            form(&token, PASSWORD).as_bytes(),
        )
        .await;
        assert_eq!(r.status, 303, "{}", r.text());
        let session = format!("hartkit_session={}", r.cookies()["hartkit_session"]);
        let device = get_with(a, "/device/1", &session).await;
        let html = device.text();
        let csrf = html
            .split("name=\"csrf\" value=\"")
            .nth(1)
            .and_then(|s| s.split('"').next())
            .unwrap()
            .to_string();
        let r = request(
            a,
            "POST",
            "/device/1/write",
            &[ctype, ("Cookie", &session)],
            format!("csrf={csrf}&descriptor=NORTH+HEADER").as_bytes(),
        )
        .await;
        assert_eq!(r.status, 200);
        assert!(r.text().contains("banner ok"), "{}", r.text());
        let r = request(
            a,
            "POST",
            "/device/1/write",
            &[ctype, ("Cookie", &session)],
            b"csrf=wrong&descriptor=X",
        )
        .await;
        assert_eq!(r.status, 403);
        assert!(r.text().contains("banner bad"));
    });
}

async fn get_with(addr: SocketAddr, path: &str, cookie: &str) -> Reply {
    request(addr, "GET", path, &[("Cookie", cookie)], b"").await
}

#[test]
fn failed_logins_are_throttled() {
    local(async {
        let s = server("throttle", true, false).await;
        for _ in 0..5 {
            assert_json_error(
                &post_json(s.addr, "/api/login", &[], r#"{"password": "guess"}"#).await,
                401,
            );
        }
        // Now even the right password waits.
        let r = post_json(
            s.addr,
            "/api/login",
            &[],
            &format!(r#"{{"password": "{PASSWORD}"}}"#),
        )
        .await;
        assert_json_error(&r, 429);
        let wait: u64 = r.header("retry-after").unwrap().parse().unwrap();
        assert!((1..=60).contains(&wait), "{wait}");
    });
}

#[test]
fn a_read_only_gateway_refuses_writes_and_logins_say_why() {
    local(async {
        let s = server("readonly", true, true).await;
        let r = post_json(s.addr, "/api/devices/1/write", &[], r#"{"damping": 1}"#).await;
        assert_json_error(&r, 403);
        assert!(r.json()["error"].as_str().unwrap().contains("read-only"));
        let s = server("nopassword", false, false).await;
        let r = post_json(s.addr, "/api/login", &[], r#"{"password": "x"}"#).await;
        assert_json_error(&r, 403);
    });
}

/// `--allow-commands` is the engine's rule: a write whose command is off the list is
/// refused (403, naming the option), audited as refused (nothing sent), and one on it
/// goes (a record before it, one with its outcome).
#[test]
fn a_command_off_the_allow_list_is_refused_and_audited_as_such() {
    local(async {
        let policy = hart_poller::WritePolicy {
            allow: Some("0-33".parse().unwrap()),
            ..Default::default()
        };
        let s = server_on(hart_host::transport::Plant::demo(), "allow", true, policy).await;
        let (cookie, csrf) = login(s.addr).await;
        let ok = [("Cookie", cookie.as_str()), ("X-CSRF-Token", csrf.as_str())];
        let r = post_json(s.addr, "/api/devices/1/write", &ok, r#"{"damping": 2.5}"#).await;
        assert_json_error(&r, 403);
        let why = r.json()["error"].as_str().unwrap().to_string();
        assert!(
            why.contains("command 34") && why.contains("--allow-commands"),
            "{why}"
        );
        let audit = std::fs::read_to_string(&s.audit).unwrap();
        assert_eq!(audit.lines().count(), 1, "{audit}");
        assert!(audit.contains("\"outcome\":\"not-permitted\""), "{audit}");
        let r = post_json(s.addr, "/api/devices/1/write", &ok, r#"{"tag": "PT-778"}"#).await;
        assert_eq!(r.json()["confirmed"], true, "{}", r.text());
        let audit = std::fs::read_to_string(&s.audit).unwrap();
        assert_eq!(audit.lines().count(), 3, "{audit}");
        assert!(audit.contains("\"outcome\":\"done\""), "{audit}");
    });
}

#[test]
fn bad_requests_get_json_errors() {
    local(async {
        let s = server("bad", false, false).await;
        let a = s.addr;
        for (path, status) in [
            ("/api/devices/99", 404),
            ("/api/devices/NO-SUCH-TAG", 404),
            ("/api/devices/0", 404),
            ("/api/devices/1/history?window=soon", 400),
            ("/api/devices/1/history?window=1s", 400),
            ("/api/traffic?command=x", 400),
            ("/api/traffic?loop=9", 400),
            ("/api/traffic?limit=0", 400),
            ("/api/traffic?device=77", 404),
            ("/api/devices/1/burst?message=300", 400),
            ("/api/nothing", 404),
        ] {
            assert_json_error(&get(a, path).await, status);
        }
        assert_eq!(get(a, "/device/99").await.status, 404);
        assert_eq!(get(a, "/no/such/page").await.status, 404);
        // Garbage on the socket: the server closes that connection and goes on.
        let mut c = tokio::net::TcpStream::connect(a).await.unwrap();
        c.write_all(b"\x00\x01GARBAGE\r\n\r\n").await.unwrap();
        let mut sink = vec![];
        let _ = tokio::time::timeout(Duration::from_secs(5), c.read_to_end(&mut sink)).await;
        assert_eq!(get(a, "/api/devices/1").await.status, 200);
    });
}

#[test]
fn a_loop_test_is_released_by_itself() {
    local(async {
        // One device at polling address 0: its loop current is live.
        let plant = hart_host::transport::Plant {
            device: vec![hart_host::transport::PlantDevice {
                profile: "pressure".into(),
                poll: 0,
                ..Default::default()
            }],
        };
        let s = server_on(plant, "looptest", true, Default::default()).await;
        let a = s.addr;
        let (cookie, csrf) = login(a).await;
        let ok = [("Cookie", cookie.as_str()), ("X-CSRF-Token", csrf.as_str())];
        let r = post_json(
            a,
            "/api/devices/1/write",
            &ok,
            r#"{"loop_test_ma": 12, "release_after_s": 1}"#,
        )
        .await;
        let v = r.json();
        assert_eq!(v["confirmed"], true, "{v}");
        assert!(v["release_at"].is_string());
        assert_eq!(get(a, "/api/devices/1").await.json()["fixed_current"], 12.0);
        // Released after a second, by the gateway, and audited.
        let mut released = false;
        for _ in 0..50 {
            tokio::time::sleep(Duration::from_millis(100)).await;
            let d = get(a, "/api/devices/1").await.json();
            if d["fixed_current"].is_null() {
                released = true;
                break;
            }
        }
        assert!(released, "the loop test ended by itself");
        let audit = std::fs::read_to_string(&s.audit).unwrap();
        assert!(audit.contains("loop test release"), "{audit}");
        assert!(audit.contains("loop test limit reached"), "{audit}");
        // A loop test ended by hand ends its lease.
        let r = post_json(a, "/api/devices/1/write", &ok, r#"{"loop_test_ma": 8}"#).await;
        assert_eq!(r.json()["confirmed"], true);
        let r = post_json(a, "/api/devices/1/write", &ok, r#"{"loop_test_ma": 0}"#).await;
        assert_eq!(r.json()["confirmed"], true, "{}", r.text());
    });
}

#[test]
fn live_views_are_bounded() {
    local(async {
        let s = server("streams", false, false).await;
        // Each view from an address of its own group of 16 (the per-address limit).
        let open = |addr: SocketAddr, from: String| async move {
            let mut c = connect_from(&from, addr).await.unwrap();
            c.write_all(format!("GET /api/events HTTP/1.1\r\nHost: {addr}\r\n\r\n").as_bytes())
                .await
                .unwrap();
            let mut buf = vec![0u8; 512];
            let n = tokio::time::timeout(Duration::from_secs(10), c.read(&mut buf))
                .await
                .unwrap()
                .unwrap();
            (c, String::from_utf8_lossy(&buf[..n]).into_owned())
        };
        let mut held = vec![];
        for n in 0..256 {
            let (c, head) = open(s.addr, format!("127.0.2.{}", n / 16 + 1)).await;
            assert!(head.starts_with("HTTP/1.1 200"), "{head}");
            held.push(c);
        }
        let (_, head) = open(s.addr, "127.0.3.1".into()).await;
        assert!(head.starts_with("HTTP/1.1 503"), "{head}");
        // A 17th connection from an address whose 16 are all views is not admitted.
        let mut c = connect_from("127.0.2.1", s.addr).await.unwrap();
        let _ = c.write_all(b"GET /api/devices HTTP/1.1\r\n\r\n").await;
        let mut sink = vec![];
        let _ = tokio::time::timeout(Duration::from_secs(10), c.read_to_end(&mut sink))
            .await
            .expect("closed at once");
        assert!(sink.is_empty(), "{}", String::from_utf8_lossy(&sink));
        // A view closed frees its place (once the server's next event finds it gone).
        held.pop();
        drop(held.pop());
        let mut freed = false;
        for _ in 0..20 {
            tokio::time::sleep(Duration::from_millis(500)).await;
            let (c, head) = open(s.addr, "127.0.3.2".into()).await;
            if head.starts_with("HTTP/1.1 200") {
                freed = true;
                held.push(c);
                break;
            }
        }
        assert!(freed, "a closed view's place is given again");
    });
}

#[test]
fn silent_connections_do_not_lock_browsers_out() {
    local(async {
        hart_host::load::raise_open_file_limit(4096);
        let s = server("silent", false, false).await;
        // More silent connections than the server keeps, from 40 addresses, each
        // within the per-address limit: port scanners', crashed clients'.
        let mut silent = vec![];
        for n in 0..hart_web::limits::MAX_CONNECTIONS + 100 {
            let from = format!("127.0.1.{}", n / hart_web::limits::MAX_PER_ADDRESS + 1);
            silent.push(connect_from(&from, s.addr).await.unwrap());
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
        // A browser still gets in at once: the oldest silent ones make room.
        let started = std::time::Instant::now();
        let r = get(s.addr, "/api/devices/1").await;
        assert_eq!(r.status, 200);
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "{:?}",
            started.elapsed()
        );
        // The oldest silent connection was closed by the server.
        let mut buf = [0u8; 16];
        let n = tokio::time::timeout(Duration::from_secs(5), silent[0].read(&mut buf))
            .await
            .expect("closed, not waiting")
            .unwrap_or(0);
        assert_eq!(n, 0);
    });
}

/// The dashboard taken by one host (issue 39): 500 connections from 127.0.0.1, each
/// sending one byte and then nothing, reopened as soon as they are closed, while a
/// browser on 127.0.0.2 asks for pages. The flood holds its 16 places at most (the
/// per-address limit: its newest connections close its own oldest) of a pool of 256
/// here; the browser gets every answer. Run on two worker threads, as the gateway; each request may take up
/// to 30 s (a loaded machine), but none may fail.
#[test]
fn one_host_flooding_slow_connections_does_not_keep_others_out() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    tokio::task::LocalSet::new().block_on(&rt, async {
        hart_host::load::raise_open_file_limit(4096);
        // A pool smaller than the flood, so that it would be taken without the
        // per-address limit.
        let s = server_with("flood", false, |c| c.limits.max_connections = 256).await;
        let addr = s.addr;
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let closed = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
        let mut flood = vec![];
        for _ in 0..500 {
            let (stop, closed) = (stop.clone(), closed.clone());
            flood.push(tokio::spawn(async move {
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    let Ok(mut c) = connect_from("127.0.0.1", addr).await else {
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    };
                    if c.write_all(b"G").await.is_ok() {
                        // Until the server closes it (refused, evicted or timed out).
                        let mut sink = [0u8; 64];
                        while let Ok(n) = c.read(&mut sink).await {
                            if n == 0 {
                                break;
                            }
                        }
                    }
                    closed.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    // Reopened at once (a pause for the machine's other tests).
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
            }));
        }
        tokio::time::sleep(Duration::from_secs(1)).await;
        let mut answered = 0;
        for n in 0..20 {
            let c = tokio::time::timeout(Duration::from_secs(30), connect_from("127.0.0.2", addr))
                .await
                .unwrap_or_else(|_| panic!("request {n}: no connection within 30 s"))
                .unwrap();
            let path = if n % 2 == 0 { "/" } else { "/api/devices/1" };
            let r = tokio::time::timeout(
                Duration::from_secs(30),
                request_on(c, &addr.to_string(), "GET", path, &[], b""),
            )
            .await
            .unwrap_or_else(|_| panic!("request {n}: no answer within 30 s"));
            assert_eq!(r.status, 200, "request {n}: {}", r.text());
            answered += 1;
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        assert_eq!(answered, 20);
        assert!(
            closed.load(std::sync::atomic::Ordering::Relaxed) >= 500,
            "the flood's connections were closed by the server: {}",
            closed.load(std::sync::atomic::Ordering::Relaxed)
        );
        for f in flood {
            f.abort();
        }
    });
}

/// Reads one HTTP/1.1 answer with a Content-Length from `c`: its status.
async fn read_answer(c: &mut tokio::net::TcpStream) -> u16 {
    let mut raw = vec![];
    let mut buf = [0u8; 4096];
    loop {
        let n = c.read(&mut buf).await.unwrap();
        assert!(n > 0, "closed before a whole answer");
        raw.extend_from_slice(&buf[..n]);
        let Some(split) = raw.windows(4).position(|w| w == b"\r\n\r\n") else {
            continue;
        };
        let head = String::from_utf8_lossy(&raw[..split]).to_ascii_lowercase();
        let length: usize = head
            .lines()
            .find_map(|l| l.strip_prefix("content-length:"))
            .map(|v| v.trim().parse().unwrap())
            .expect("a Content-Length");
        if raw.len() >= split + 4 + length {
            return head.split_whitespace().nth(1).unwrap().parse().unwrap();
        }
    }
}

/// Waits for the server to close `c`; how long it took.
async fn closed_after(c: &mut tokio::net::TcpStream) -> Duration {
    let started = std::time::Instant::now();
    let mut sink = vec![];
    let _ = tokio::time::timeout(Duration::from_secs(30), c.read_to_end(&mut sink))
        .await
        .expect("the server closes it");
    started.elapsed()
}

/// The time limits, shortened: a head begun and not finished is closed after the
/// head's limit, on a new connection and on a kept-alive one; a kept-alive connection
/// without a request is closed after the idle limit, not the head's.
#[test]
fn partial_heads_and_idle_connections_are_closed_at_their_limits() {
    local(async {
        let header = Duration::from_millis(800);
        let idle = Duration::from_secs(5);
        let s = server_with("timeouts", false, |c| {
            c.limits.header_timeout = header;
            c.limits.idle_timeout = idle;
        })
        .await;
        let host = s.addr.to_string();
        // Part of a head.
        let mut c = tokio::net::TcpStream::connect(s.addr).await.unwrap();
        c.write_all(format!("GET / HTTP/1.1\r\nHost: {host}\r\nX-A: ").as_bytes())
            .await
            .unwrap();
        let waited = closed_after(&mut c).await;
        assert!(waited >= header - Duration::from_millis(100), "{waited:?}");
        // A request answered, then nothing: idle, closed at the idle limit.
        let mut c = tokio::net::TcpStream::connect(s.addr).await.unwrap();
        let head = format!("GET /api/devices/1 HTTP/1.1\r\nHost: {host}\r\n\r\n");
        c.write_all(head.as_bytes()).await.unwrap();
        assert_eq!(read_answer(&mut c).await, 200);
        let waited = closed_after(&mut c).await;
        assert!(waited >= idle - Duration::from_millis(100), "{waited:?}");
        // Within the idle limit, the connection serves another request.
        let mut c = tokio::net::TcpStream::connect(s.addr).await.unwrap();
        c.write_all(head.as_bytes()).await.unwrap();
        assert_eq!(read_answer(&mut c).await, 200);
        tokio::time::sleep(header + Duration::from_millis(500)).await;
        c.write_all(head.as_bytes()).await.unwrap();
        assert_eq!(read_answer(&mut c).await, 200);
        // Then part of a third head: closed at the head's limit.
        c.write_all(b"GET / HTTP/1.1\r\n").await.unwrap();
        let waited = closed_after(&mut c).await;
        assert!(
            waited >= header - Duration::from_millis(100) && waited < idle,
            "{waited:?}"
        );
    });
}

/// DNS rebinding: a request to a name that is not the dashboard's is refused (421,
/// saying how to allow it); `[web] hosts` allows it. A write from another origin is
/// refused (403), from the dashboard's own accepted.
#[test]
fn foreign_hosts_and_origins_are_refused() {
    local(async {
        let s = server("hosts", true, false).await;
        let a = s.addr;
        let port = a.port();
        let on = |host: String,
                  method: &'static str,
                  path: &'static str,
                  headers: Vec<(&'static str, String)>,
                  body: String| async move {
            let c = tokio::net::TcpStream::connect(a).await.unwrap();
            let h: Vec<(&str, &str)> = headers.iter().map(|(k, v)| (*k, v.as_str())).collect();
            request_on(c, &host, method, path, &h, body.as_bytes()).await
        };
        let r = on(
            format!("rebind.example:{port}"),
            "GET",
            "/",
            vec![],
            String::new(),
        )
        .await;
        assert_eq!(r.status, 421, "{}", r.text());
        assert!(
            r.text().contains("\"rebind.example:") && r.text().contains("[web] hosts"),
            "{}",
            r.text()
        );
        let r = on(
            format!("rebind.example:{port}"),
            "GET",
            "/api/devices",
            vec![],
            String::new(),
        )
        .await;
        assert_json_error(&r, 421);
        // Its own names.
        for host in [
            a.to_string(),
            format!("localhost:{port}"),
            "127.0.0.1".into(),
        ] {
            let r = on(host.clone(), "GET", "/api/devices/1", vec![], String::new()).await;
            assert_eq!(r.status, 200, "{host}: {}", r.text());
        }
        let login = format!(r#"{{"password": "{PASSWORD}"}}"#);
        let json = ("Content-Type", "application/json".to_string());
        // A write (a login) from another site's page, or another port of this host.
        for origin in [
            format!("http://rebind.example:{port}"),
            "http://127.0.0.1:1".to_string(),
            "null".to_string(),
        ] {
            let r = on(
                a.to_string(),
                "POST",
                "/api/login",
                vec![json.clone(), ("Origin", origin.clone())],
                login.clone(),
            )
            .await;
            assert_json_error(&r, 403);
        }
        let r = on(
            a.to_string(),
            "POST",
            "/api/login",
            vec![json.clone(), ("Origin", format!("http://{a}"))],
            login.clone(),
        )
        .await;
        assert_eq!(r.status, 200, "{}", r.text());

        // With the name configured.
        let s = server_with("hosts2", true, |c| {
            c.hosts = vec!["plant-gw.example".parse().unwrap()];
        })
        .await;
        let a = s.addr;
        let port = a.port();
        let on = |host: String,
                  method: &'static str,
                  path: &'static str,
                  headers: Vec<(&'static str, String)>,
                  body: String| async move {
            let c = tokio::net::TcpStream::connect(a).await.unwrap();
            let h: Vec<(&str, &str)> = headers.iter().map(|(k, v)| (*k, v.as_str())).collect();
            request_on(c, &host, method, path, &h, body.as_bytes()).await
        };
        let named = format!("plant-gw.example:{port}");
        assert_eq!(
            on(named.clone(), "GET", "/", vec![], String::new())
                .await
                .status,
            200
        );
        assert_eq!(
            on(
                format!("rebind.example:{port}"),
                "GET",
                "/",
                vec![],
                String::new()
            )
            .await
            .status,
            421
        );
        let r = on(
            named.clone(),
            "POST",
            "/api/login",
            vec![json.clone(), ("Origin", format!("http://{named}"))],
            login.clone(),
        )
        .await;
        assert_eq!(r.status, 200, "{}", r.text());
        let r = on(
            named.clone(),
            "POST",
            "/api/login",
            vec![
                json.clone(),
                ("Origin", format!("http://rebind.example:{port}")),
            ],
            login.clone(),
        )
        .await;
        assert_json_error(&r, 403);
    });
}

/// Password guessing from many addresses, each below its own limit: after 20
/// failures in a minute, a login from a browser that has not logged in here before
/// waits (429, Retry-After), even with the right password; the operator's browser,
/// which has, logs in.
#[test]
fn failed_logins_from_many_addresses_slow_new_browsers() {
    local(async {
        let s = server("globalthrottle", true, false).await;
        let a = s.addr;
        let host = a.to_string();
        let login = |from: &'static str, password: &'static str, cookie: Option<String>| {
            let host = host.clone();
            async move {
                let c = connect_from(from, a).await.unwrap();
                let body = format!(r#"{{"password": "{password}"}}"#);
                let mut h = vec![("Content-Type", "application/json".to_string())];
                if let Some(c) = cookie {
                    h.push(("Cookie", c));
                }
                let h: Vec<(&str, &str)> = h.iter().map(|(k, v)| (*k, v.as_str())).collect();
                request_on(c, &host, "POST", "/api/login", &h, body.as_bytes()).await
            }
        };
        // The operator logged in before: the browser's cookie says so.
        let r = login("127.0.0.2", PASSWORD, None).await;
        assert_eq!(r.status, 200, "{}", r.text());
        let browser = format!("hartkit_browser={}", r.cookies()["hartkit_browser"]);
        // 20 guesses from five addresses, four each (the per-address limit is five).
        for from in [
            "127.0.0.10",
            "127.0.0.11",
            "127.0.0.12",
            "127.0.0.13",
            "127.0.0.14",
        ] {
            for _ in 0..4 {
                assert_json_error(&login(from, "guess", None).await, 401);
            }
        }
        // A new browser, with the right password, waits.
        let r = login("127.0.0.3", PASSWORD, None).await;
        assert_json_error(&r, 429);
        let wait: u64 = r.header("retry-after").unwrap().parse().unwrap();
        assert!((1..=60).contains(&wait), "{wait}");
        assert!(r.json()["error"]
            .as_str()
            .unwrap()
            .contains("several addresses"));
        // So does a further guess from a new address.
        assert_json_error(&login("127.0.0.15", "guess", None).await, 429);
        // The operator's browser does not.
        let r = login("127.0.0.2", PASSWORD, Some(browser)).await;
        assert_eq!(r.status, 200, "{}", r.text());
    });
}

#[test]
fn a_request_head_that_never_ends_is_closed() {
    local(async {
        let s = server("slowloris", false, false).await;
        let mut c = tokio::net::TcpStream::connect(s.addr).await.unwrap();
        c.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n").await.unwrap();
        let started = std::time::Instant::now();
        let mut sink = vec![];
        let _ = tokio::time::timeout(Duration::from_secs(20), c.read_to_end(&mut sink))
            .await
            .expect("the server closes it");
        let waited = started.elapsed();
        assert!(
            waited >= hart_web::limits::HEADER_TIMEOUT - Duration::from_secs(1)
                && waited < hart_web::limits::HEADER_TIMEOUT + Duration::from_secs(5),
            "{waited:?}"
        );
    });
}

#[test]
fn a_psk_identity_with_write_rights_logs_in_with_its_key() {
    local(async {
        let dir = tempdir::Dir::new("psk");
        let audit = dir.0.join("audit.jsonl");
        let engine = engine_on(
            hart_host::transport::Plant::demo(),
            hart_poller::WritePolicy {
                audit: hart_access::Audit::new(Some(audit.clone())),
                ..Default::default()
            },
        )
        .await;
        let mut config = hart_web::WebConfig::new("127.0.0.1:0".parse().unwrap());
        config.psk_logins = vec![hart_web::PskLogin {
            identity: "tech1".into(),
            key: (0u8..16).collect(),
        }];
        let web = hart_web::start(engine, config).await.unwrap();
        let a = web.addr;
        let key = "000102030405060708090a0b0c0d0e0f";
        for bad in [
            r#"{"identity": "tech1", "password": "00"}"#,
            r#"{"identity": "tech2", "password": "000102030405060708090a0b0c0d0e0f"}"#,
            r#"{"password": "000102030405060708090a0b0c0d0e0f"}"#,
        ] {
            assert_json_error(&post_json(a, "/api/login", &[], bad).await, 401);
        }
        let r = post_json(
            a,
            "/api/login",
            &[],
            &format!(r#"{{"identity": "tech1", "password": "{key}"}}"#),
        )
        .await;
        assert_eq!(r.status, 200, "{}", r.text());
        let v = r.json();
        assert_eq!(v["who"], "tech1");
        let cookie = format!("hartkit_session={}", r.cookies()["hartkit_session"]);
        let csrf = v["csrf"].as_str().unwrap();
        let r = post_json(
            a,
            "/api/devices/1/write",
            &[("Cookie", &cookie), ("X-CSRF-Token", csrf)],
            r#"{"damping": 0.7}"#,
        )
        .await;
        assert_eq!(r.json()["confirmed"], true, "{}", r.text());
        let audit = std::fs::read_to_string(&audit).unwrap();
        assert!(audit.contains("\"identity\":\"tech1\""), "{audit}");
        assert!(get(a, "/login").await.text().contains("name=\"identity\""));
        web.stop();
    });
}

/// Over HTTPS the same connection wrapper serves (the TLS stream inside it): a page for
/// the dashboard's own name, 421 for another.
#[test]
fn https_serves_through_the_same_limits_and_names() {
    use openssl::{
        asn1::Asn1Time, ec::EcGroup, ec::EcKey, hash::MessageDigest, nid::Nid, pkey::PKey,
        ssl::SslConnector, ssl::SslMethod, ssl::SslVerifyMode, x509::X509,
    };
    let group = EcGroup::from_curve_name(Nid::X9_62_PRIME256V1).unwrap();
    let key = PKey::from_ec_key(EcKey::generate(&group).unwrap()).unwrap();
    let mut name = openssl::x509::X509NameBuilder::new().unwrap();
    name.append_entry_by_text("CN", "127.0.0.1").unwrap();
    let name = name.build();
    let mut b = X509::builder().unwrap();
    b.set_version(2).unwrap();
    b.set_subject_name(&name).unwrap();
    b.set_issuer_name(&name).unwrap();
    b.set_pubkey(&key).unwrap();
    b.set_not_before(&Asn1Time::days_from_now(0).unwrap())
        .unwrap();
    b.set_not_after(&Asn1Time::days_from_now(1).unwrap())
        .unwrap();
    b.sign(&key, MessageDigest::sha256()).unwrap();
    let dir = tempdir::Dir::new("https-limits");
    let files = hart_web::TlsFiles {
        cert: dir.0.join("cert.pem"),
        key: dir.0.join("key.pem"),
    };
    std::fs::write(&files.cert, b.build().to_pem().unwrap()).unwrap();
    std::fs::write(&files.key, key.private_key_to_pem_pkcs8().unwrap()).unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    tokio::task::LocalSet::new().block_on(&rt, async {
        let s = server_with("https", false, |c| c.tls = Some(files)).await;
        let addr = s.addr;
        let get = move |host: String| {
            let mut c = SslConnector::builder(SslMethod::tls_client()).unwrap();
            c.set_verify(SslVerifyMode::NONE);
            c.set_alpn_protos(b"\x08http/1.1").unwrap();
            let tcp = std::net::TcpStream::connect(addr).unwrap();
            tcp.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
            let mut tls = c.build().connect("127.0.0.1", tcp).unwrap();
            use std::io::{Read, Write};
            write!(
                tls,
                "GET /api/devices/1 HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"
            )
            .unwrap();
            let mut out = vec![];
            let _ = tls.read_to_end(&mut out);
            String::from_utf8_lossy(&out).into_owned()
        };
        let own = tokio::task::spawn_blocking(move || get(addr.to_string()))
            .await
            .unwrap();
        assert!(own.starts_with("HTTP/1.1 200"), "{own}");
        let other =
            tokio::task::spawn_blocking(move || get(format!("rebind.example:{}", addr.port())))
                .await
                .unwrap();
        assert!(other.starts_with("HTTP/1.1 421"), "{other}");
    });
}
