//! A whole gateway started from one configuration value, as a program or a test
//! starts it: the demo plant in memory behind Modbus TCP, read with a Modbus request
//! written out byte by byte; and the configuration mistakes the value refuses.

use std::time::Duration;

use hart_gateway::{ErrorKind, Gateway, GatewayConfig, ServeOptions};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

fn local<F: std::future::Future>(f: F) -> F::Output {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    tokio::task::LocalSet::new().block_on(&rt, f)
}

fn sim_with_modbus() -> ServeOptions {
    ServeOptions {
        sim: Some(vec![]),
        instant: true,
        modbus: Some("127.0.0.1:0".into()),
        scan_to: 15,
        ..ServeOptions::default()
    }
}

/// Reads input registers 10..14 (PV units, status, extended status, quality) of unit
/// 1: Modbus TCP, function 4, transaction 7.
async fn read_unit_1(addr: std::net::SocketAddr) -> Vec<u8> {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(&[0, 7, 0, 0, 0, 6, 1, 4, 0, 10, 0, 4])
        .await
        .unwrap();
    let mut reply = vec![0; 9 + 8];
    tokio::time::timeout(Duration::from_secs(5), s.read_exact(&mut reply))
        .await
        .expect("a reply within 5 s")
        .unwrap();
    reply
}

#[test]
fn a_whole_gateway_starts_from_one_value() {
    local(async {
        let config = GatewayConfig::from_options(&sim_with_modbus()).unwrap();
        assert!(config.in_memory());
        assert!(
            config.engine.poll,
            "Modbus reads the image: the engine polls"
        );
        let gateway = Gateway::start(config).await.unwrap();
        let addr = gateway.modbus_tcp_addr().unwrap();
        assert!(
            gateway.started()[0].starts_with(&format!("modbus: tcp {addr}")),
            "{:?}",
            gateway.started()
        );
        gateway.engine().ready().await;
        let mut quality = u16::MAX;
        for _ in 0..100 {
            let r = read_unit_1(addr).await;
            // MBAP: transaction 7, protocol 0, length 11, unit 1; function 4, 8 bytes.
            assert_eq!(r[..9], [0, 7, 0, 0, 0, 11, 1, 4, 8]);
            quality = u16::from_be_bytes([r[15], r[16]]);
            if quality == 0 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert_eq!(quality, 0, "the demo plant's first device reads good");
        gateway.stop().await;
        assert!(
            tokio::net::TcpStream::connect(addr).await.is_err()
                || tokio::time::timeout(Duration::from_millis(500), read_unit_1(addr))
                    .await
                    .is_err(),
            "stopped: nothing answers"
        );
    });
}

#[test]
fn the_value_refuses_what_cannot_run() {
    let cases: Vec<(ServeOptions, &str)> = vec![
        (ServeOptions::default(), "no loop"),
        (
            ServeOptions {
                ports: vec!["sim".into()],
                instant: true,
                ..ServeOptions::default()
            },
            "--instant",
        ),
        (
            ServeOptions {
                ports: vec!["sim".into(), "sim".into()],
                transparent: true,
                ..ServeOptions::default()
            },
            "--transparent needs exactly one loop",
        ),
        (
            ServeOptions {
                sim: Some(vec![]),
                poll_period: Some(0.0),
                ..ServeOptions::default()
            },
            "--poll-period 0",
        ),
        (
            ServeOptions {
                sim: Some(vec![]),
                modbus: Some("no such host name.invalid".into()),
                ..ServeOptions::default()
            },
            "not an address",
        ),
        (
            ServeOptions {
                sim: Some(vec![]),
                opcua: Some("127.0.0.1:0".into()),
                opcua_security: Some("none".into()),
                opcua_users: vec!["op:secret".into()],
                ..ServeOptions::default()
            },
            "travels in clear",
        ),
    ];
    for (opts, says) in cases {
        let e = GatewayConfig::from_options(&opts).err().expect(says);
        assert_eq!(e.kind, ErrorKind::Config, "{e}");
        assert_eq!(e.exit_code(), 2);
        assert!(e.message.contains(says), "{e} should say {says:?}");
    }
}

/// A front end that cannot start (its address is taken) is an I/O error, and what
/// had started is stopped.
#[test]
fn an_address_in_use_is_an_io_error() {
    local(async {
        let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let mut opts = sim_with_modbus();
        opts.modbus = Some(taken.local_addr().unwrap().to_string());
        let config = GatewayConfig::from_options(&opts).unwrap();
        let e = Gateway::start(config).await.err().expect("refused");
        assert_eq!(e.kind, ErrorKind::Io);
        assert!(e.message.starts_with("--modbus 127.0.0.1:"), "{e}");
    });
}

/// The MQTT publisher's store-and-forward reads an outage back from the historian: the
/// samples the gateway stored are found by device and time, each variable as its
/// metric (PV with its quality), in time order.
#[test]
fn an_outage_is_read_back_from_the_historian() {
    use hart_sparkplug_edge::Backfill as _;
    let dir = std::env::temp_dir().join(format!("hart-gateway-backfill-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let db = dir.join("plant.sqlite").to_string_lossy().into_owned();
    local(async {
        let config = GatewayConfig::from_options(&ServeOptions {
            sim: Some(vec![]),
            instant: true,
            history: Some(db.clone()),
            poll_period: Some(0.2),
            ..ServeOptions::default()
        })
        .unwrap();
        let start = std::time::SystemTime::now();
        let gateway = Gateway::start(config).await.unwrap();
        // A few batches (one a second).
        tokio::time::sleep(Duration::from_millis(3500)).await;
        let engine = gateway.engine().clone();
        gateway.stop().await;
        let ms = |t: std::time::SystemTime| {
            t.duration_since(std::time::UNIX_EPOCH).unwrap().as_millis() as u64
        };
        let source = hart_gateway::backfill::HistoryBackfill::new(
            hart_history::Readers::new(db.clone(), hart_history::DEFAULT_READERS),
            engine.clone(),
        );
        let samples = source
            .samples(ms(start), ms(std::time::SystemTime::now()) + 1)
            .unwrap();
        let pv = hart_sparkplug_edge::metrics::DEVICE_METRICS
            .iter()
            .position(|m| m.name == "PV")
            .unwrap();
        let positions: std::collections::BTreeSet<usize> =
            samples.iter().map(|s| s.position).collect();
        assert!(
            positions.len() >= 3,
            "the demo plant's devices: {positions:?}"
        );
        for p in positions {
            let mine: Vec<_> = samples.iter().filter(|s| s.position == p).collect();
            assert!(mine.windows(2).all(|w| w[0].at < w[1].at), "in time order");
            assert!(
                mine.iter().any(|s| s.metrics.iter().any(|(i, _)| *i == pv)),
                "device {p} has PV samples"
            );
        }
        // Nothing before the range.
        assert!(source.samples(0, ms(start)).unwrap().is_empty());
    });
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_web_dashboard_starts_from_options_and_the_file() {
    local(async {
        // A port alone listens on loopback only.
        let config = GatewayConfig::from_options(&ServeOptions {
            sim: Some(vec![]),
            instant: true,
            web: Some("0".into()),
            ..ServeOptions::default()
        })
        .unwrap();
        let web = config.web.clone().unwrap();
        assert!(web.bind.ip().is_loopback(), "{}", web.bind);
        assert!(config.engine.poll, "the dashboard reads the image");
        let gateway = Gateway::start(config).await.unwrap();
        let addr = gateway.web_addr().unwrap();
        assert!(
            gateway.started()[0].starts_with(&format!("web: http://{addr}/ (read only")),
            "{:?}",
            gateway.started()
        );
        gateway.stop().await;
        // The same from [web], with the historian's database for the trends.
        let dir = std::env::temp_dir().join(format!("hart-gw-web-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("gateway.toml");
        std::fs::write(
            &file,
            format!(
                "[web]\nbind = \"127.0.0.1:0\"\nmemory_window = \"2h\"\n[history]\ndb = \"{}\"\n",
                dir.join("h.sqlite").display()
            ),
        )
        .unwrap();
        let config = GatewayConfig::from_options(&ServeOptions {
            sim: Some(vec![]),
            instant: true,
            config: Some(file.clone()),
            ..ServeOptions::default()
        })
        .unwrap();
        let web = config.web.unwrap();
        assert_eq!(web.memory_window, Duration::from_secs(7200));
        assert!(web.history.unwrap().db().ends_with("h.sqlite"));
        assert_eq!(web.limits, hart_web::limits::Limits::default());
        assert!(web.hosts.is_empty());
        // Its names and connection limits, from [web] and --web-host.
        std::fs::write(
            &file,
            "[web]\nbind = \"0.0.0.0:8080\"\nhosts = [\"plant-gw.example\", \"proxy.example:443\"]\n\
             max_connections = 100\nmax_per_address = 4\npriority = [\"10.0.0.0/24\"]\n\
             header_timeout = \"5s\"\nidle_timeout = \"2m\"\n",
        )
        .unwrap();
        let config = GatewayConfig::from_options(&ServeOptions {
            sim: Some(vec![]),
            instant: true,
            config: Some(file.clone()),
            web_hosts: vec!["gw.plant.example".into()],
            ..ServeOptions::default()
        })
        .unwrap();
        let web = config.web.unwrap();
        let names: Vec<String> = web.hosts.iter().map(|h| h.to_string()).collect();
        assert_eq!(
            names,
            ["plant-gw.example", "proxy.example:443", "gw.plant.example"]
        );
        assert_eq!(web.limits.max_connections, 100);
        assert_eq!(web.limits.max_per_address, 4);
        assert!(web.limits.priority.contains("10.0.0.7".parse().unwrap()));
        assert_eq!(web.limits.header_timeout, Duration::from_secs(5));
        assert_eq!(web.limits.idle_timeout, Duration::from_secs(120));
        for (bad, says) in [
            ("hosts = [\"http://plant-gw.example/\"]", "[web] hosts"),
            ("idle_timeout = \"0s\"", "idle_timeout"),
            ("priority = [\"not a network\"]", "[web] priority"),
        ] {
            std::fs::write(&file, format!("[web]\nbind = \"127.0.0.1:0\"\n{bad}\n")).unwrap();
            let e = GatewayConfig::from_options(&ServeOptions {
                sim: Some(vec![]),
                config: Some(file.clone()),
                ..ServeOptions::default()
            })
            .err()
            .unwrap();
            assert_eq!(e.kind, ErrorKind::Config, "{e}");
            assert!(e.message.contains(says), "{bad}: {e}");
        }
        let _ = std::fs::remove_dir_all(&dir);
        // Mistakes.
        for opts in [
            ServeOptions {
                sim: Some(vec![]),
                web_admin_password_file: Some("pw".into()),
                ..ServeOptions::default()
            },
            ServeOptions {
                sim: Some(vec![]),
                web: Some("127.0.0.1:0".into()),
                web_cert: Some("cert.pem".into()),
                ..ServeOptions::default()
            },
            ServeOptions {
                sim: Some(vec![]),
                web: Some("not an address".into()),
                ..ServeOptions::default()
            },
            ServeOptions {
                sim: Some(vec![]),
                web_hosts: vec!["gw.example".into()],
                ..ServeOptions::default()
            },
            ServeOptions {
                sim: Some(vec![]),
                web: Some("127.0.0.1:0".into()),
                web_hosts: vec!["gw.example/".into()],
                ..ServeOptions::default()
            },
        ] {
            let e = GatewayConfig::from_options(&opts).err().unwrap();
            assert_eq!(e.kind, ErrorKind::Config, "{e}");
        }
        // A password file that is missing stops the start, as a port in use does.
        let config = GatewayConfig::from_options(&ServeOptions {
            sim: Some(vec![]),
            instant: true,
            web: Some("127.0.0.1:0".into()),
            web_admin_password_file: Some("/nonexistent/web.pass".into()),
            ..ServeOptions::default()
        })
        .unwrap();
        let e = Gateway::start(config).await.err().unwrap();
        assert_eq!(e.kind, ErrorKind::Io, "{e}");
        assert!(e.message.contains("--web-admin-password-file"), "{e}");
    });
}

/// The longest HART-IP inactivity timer: 5 minutes unless `--max-inactivity` or
/// `[hart_ip] max_inactivity` says otherwise (the option wins); a time outside
/// 1 s..=4294967 s is refused, naming both places.
#[test]
fn the_longest_hart_ip_timer_comes_from_the_option_or_the_file() {
    let dir = std::env::temp_dir().join(format!("hart-gw-timer-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("gw.toml");
    let timer = |opt: Option<f64>, section: &str| {
        std::fs::write(
            &file,
            format!("[hart_ip]\nbind = \"127.0.0.1:0\"\n{section}\n"),
        )
        .unwrap();
        GatewayConfig::from_options(&ServeOptions {
            sim: Some(vec![]),
            config: Some(file.clone()),
            max_inactivity: opt,
            ..ServeOptions::default()
        })
        .map(|c| c.hart_ip.unwrap().max_timer_ms)
    };
    assert_eq!(
        timer(None, "").unwrap(),
        hart_ip_server::DEFAULT_MAX_TIMER_MS
    );
    assert_eq!(timer(None, "max_inactivity = \"90s\"").unwrap(), 90_000);
    assert_eq!(timer(Some(2.5), "max_inactivity = \"90s\"").unwrap(), 2_500);
    for (opt, section) in [
        (Some(0.5), ""),
        (None, "max_inactivity = \"500ms\""),
        (Some(f64::NAN), ""),
    ] {
        let e = timer(opt, section).err().unwrap();
        assert_eq!(e.kind, ErrorKind::Config, "{e}");
        assert!(e.message.contains("max_inactivity"), "{e}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
