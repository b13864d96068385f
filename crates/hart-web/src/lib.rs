//! # hart-web
//!
//! hartkit's web dashboard: a front end on the polling engine, like the Modbus, OPC UA
//! and MQTT ones, for the people of the plant rather than its machines.
//!
//! * **Plant view** (`/`): every loop and device with its tag, PV and units, a
//!   percent-of-range bar, loop current, status in words, quality and age, updated
//!   live by server-sent events (`/api/events`).
//! * **Device page** (`/device/N`, N the device's unit number as `hartkit serve
//!   --print-map` gives it): identity (commands 0 and 20), every device variable
//!   (command 9), additional status in words (command 48), burst configuration
//!   (command 105), a trend of PV and loop current (from the historian when one runs,
//!   from memory otherwise, drawn as SVG by the server), and forms for the common
//!   writes, each confirmed by reading the value back.
//! * **Traffic view** (`/traffic`): the frames on each loop as the engine sends and
//!   hears them, filtered by loop, device and command, downloadable as pcapng.
//! * **A JSON API** under `/api/` behind the same pages (docs/web.md).
//!
//! Access: reading needs nothing; writing needs a login with the administrator's
//! password (`--web-admin-password-file`), a session cookie (HttpOnly,
//! SameSite=Strict) and a CSRF token on every form and API write; every write goes
//! through the engine's one write path and its audit. Failed logins are throttled per
//! address and across addresses. The dashboard answers only to its own names
//! ([`hosts`]: its addresses, `localhost`, `[web] hosts`), against DNS rebinding, and
//! bounds its connections per address and in all ([`limits`]). The assets are compiled
//! in: the dashboard needs no other file and no internet.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use hart_poller::Engine;

mod api;
mod auth;
mod device;
mod error;
pub mod hosts;
mod html;
pub mod limits;
mod pages;
mod state;
pub mod svg;
mod traffic;
pub mod trend;

pub use error::ApiError;
pub use state::AppState;

/// The port the dashboard listens on when `--web` gives none.
pub const DEFAULT_PORT: u16 = 8080;

/// How the dashboard runs (`--web` and the `[web]` section).
#[derive(Debug, Clone)]
pub struct WebConfig {
    /// Where it listens (127.0.0.1 unless told otherwise).
    pub bind: SocketAddr,
    /// A file whose first line is the administrator's password; without it the
    /// dashboard is read only.
    pub admin_password_file: Option<PathBuf>,
    /// HTTPS with this certificate chain and private key (PEM files).
    pub tls: Option<TlsFiles>,
    /// The historian, for trends over longer windows than memory keeps: a handle the
    /// gateway shares with its other readers ([`hart_history::Readers`]).
    pub history: Option<hart_history::Readers>,
    /// How much of each device's PV and loop current is kept in memory for trends.
    pub memory_window: Duration,
    /// How long a login lasts without use.
    pub session_idle: Duration,
    /// The HART-IP server's pre-shared keys with write rights: each identity may log in
    /// with its key (hex) as the password, and its writes are audited under its name.
    pub psk_logins: Vec<PskLogin>,
    /// Names the dashboard answers to besides its own addresses and `localhost`
    /// (`[web] hosts`, `--web-host`): a request whose `Host` is none of them is
    /// refused, and so is a write whose `Origin` is another site ([`hosts`]).
    pub hosts: Vec<hosts::HostName>,
    /// The connection limits ([`limits`]).
    pub limits: limits::Limits,
}

/// An identity that may log in with its pre-shared key.
#[derive(Clone, PartialEq, Eq)]
pub struct PskLogin {
    /// The identity.
    pub identity: String,
    /// The key.
    pub key: Vec<u8>,
}

impl std::fmt::Debug for PskLogin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never print the key.
        f.debug_struct("PskLogin")
            .field("identity", &self.identity)
            .finish_non_exhaustive()
    }
}

impl WebConfig {
    /// A read-only dashboard on `bind` with the defaults.
    pub fn new(bind: SocketAddr) -> Self {
        WebConfig {
            bind,
            admin_password_file: None,
            tls: None,
            history: None,
            memory_window: Duration::from_secs(3600),
            session_idle: Duration::from_secs(3600),
            psk_logins: vec![],
            hosts: vec![],
            limits: limits::Limits::default(),
        }
    }
}

/// The certificate chain and private key of HTTPS (PEM).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    /// Certificate chain, PEM.
    pub cert: PathBuf,
    /// Private key, PEM.
    pub key: PathBuf,
}

/// Why the dashboard could not start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Error {
    /// A mistake in the configuration (a password file that is empty).
    Config(String),
    /// A file or an address that could not be used.
    Io(String),
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Error::Config(m) | Error::Io(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for Error {}

/// A running dashboard.
pub struct WebServer {
    /// Where it listens.
    pub addr: SocketAddr,
    /// Its address as a URL (`http://127.0.0.1:8080/`).
    pub url: String,
    handle: axum_server::Handle,
    state: Arc<AppState>,
}

impl WebServer {
    /// Stops serving (open event streams end) and the dashboard's tasks.
    pub fn stop(self) {
        self.handle.shutdown();
        self.state.stop();
    }
}

/// Starts the dashboard on `engine`: binds its address at once (an address in use is
/// an error here, not later), then serves on the current runtime. Its writes follow
/// the engine's write policy (`--read-only`, `--allow-commands`, the audit), after a
/// login of its own.
pub async fn start(engine: Engine, config: WebConfig) -> Result<WebServer, Error> {
    let password = match &config.admin_password_file {
        Some(p) => Some(auth::read_password_file(p)?),
        None => None,
    };
    let tls = match &config.tls {
        Some(t) => Some(tls_config(t)?),
        None => None,
    };
    let listener = std::net::TcpListener::bind(config.bind).map_err(|e| {
        Error::Io(format!(
            "cannot listen on {}: {e}; check that no other program uses the port, or give \
             another with --web ADDR:PORT",
            config.bind
        ))
    })?;
    listener
        .set_nonblocking(true)
        .map_err(|e| Error::Io(e.to_string()))?;
    let addr = listener
        .local_addr()
        .map_err(|e| Error::Io(e.to_string()))?;
    let scheme = if tls.is_some() { "https" } else { "http" };
    let state = AppState::start(engine, config, password, tls.is_some());
    let app = api::router(state.clone()).into_make_service_with_connect_info::<SocketAddr>();
    let handle = axum_server::Handle::new();
    let h = handle.clone();
    // Sockets: the event streams and the connection limit, with room for the rest.
    let conn_limits = state.config.limits.clone();
    hart_host::load::raise_open_file_limit(conn_limits.max_connections as u64 + 256);
    match tls {
        Some(tls) => {
            let mut server = axum_server::from_tcp(listener)
                .acceptor(axum_server::tls_openssl::OpenSSLAcceptor::new(tls))
                .map(|a| limits::Limit::new(a, conn_limits))
                .handle(h);
            own_time_limits(server.http_builder());
            tokio::spawn(async move {
                if let Err(e) = server.serve(app).await {
                    tracing::error!("web: the HTTPS server stopped: {e}");
                }
            });
        }
        None => {
            let mut server = axum_server::from_tcp(listener)
                .map(|a| limits::Limit::new(a, conn_limits))
                .handle(h);
            own_time_limits(server.http_builder());
            tokio::spawn(async move {
                if let Err(e) = server.serve(app).await {
                    tracing::error!("web: the HTTP server stopped: {e}");
                }
            });
        }
    }
    Ok(WebServer {
        addr,
        url: format!("{scheme}://{addr}/"),
        handle,
        state,
    })
}

/// Leaves the time limits of a request's head and of idle connections to
/// [`limits`]: hyper's `header_read_timeout` runs from the moment it waits for a head,
/// so it would close kept-alive connections at the head's limit rather than the idle
/// one.
fn own_time_limits(b: &mut hyper_util::server::conn::auto::Builder<hyper_util::rt::TokioExecutor>) {
    b.http1()
        .timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(None);
}

/// The HTTPS configuration of `files` (OpenSSL, TLS 1.2 and 1.3 with Mozilla's
/// intermediate ciphers, HTTP/2 or HTTP/1.1 by ALPN), with errors that say which file is
/// wrong.
fn tls_config(files: &TlsFiles) -> Result<axum_server::tls_openssl::OpenSSLConfig, Error> {
    use openssl::ssl::{AlpnError, SslAcceptor, SslFiletype, SslMethod};
    for (what, p) in [("certificate", &files.cert), ("key", &files.key)] {
        if let Err(e) = std::fs::metadata(p) {
            return Err(Error::Io(format!(
                "--web-{}: cannot read {}: {e}",
                if what == "key" { "key" } else { "cert" },
                p.display()
            )));
        }
    }
    let refused = |e: openssl::error::ErrorStack| {
        Error::Config(format!(
            "--web-cert {} / --web-key {}: {e}; give a PEM certificate chain and its \
             PEM private key (PKCS#8, PKCS#1 or SEC1) that belong together",
            files.cert.display(),
            files.key.display()
        ))
    };
    let mut b = SslAcceptor::mozilla_intermediate_v5(SslMethod::tls_server()).map_err(refused)?;
    b.set_certificate_chain_file(&files.cert).map_err(refused)?;
    b.set_private_key_file(&files.key, SslFiletype::PEM)
        .map_err(refused)?;
    b.check_private_key().map_err(refused)?;
    b.set_alpn_select_callback(|_, client| {
        openssl::ssl::select_next_proto(b"\x02h2\x08http/1.1", client).ok_or(AlpnError::NOACK)
    });
    Ok(axum_server::tls_openssl::OpenSSLConfig::from_acceptor(
        std::sync::Arc::new(b.build()),
    ))
}

#[cfg(test)]
mod tls_tests {
    use super::*;
    use openssl::{
        asn1::Asn1Time, ec::EcGroup, ec::EcKey, hash::MessageDigest, nid::Nid, pkey::PKey,
        x509::X509,
    };

    /// A fresh P-256 key and a self-signed certificate for it, both PEM.
    fn key_and_cert() -> (Vec<u8>, Vec<u8>) {
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
        (
            key.private_key_to_pem_pkcs8().unwrap(),
            b.build().to_pem().unwrap(),
        )
    }

    fn files(dir: &std::path::Path, key: &[u8], cert: &[u8]) -> TlsFiles {
        let files = TlsFiles {
            cert: dir.join("cert.pem"),
            key: dir.join("key.pem"),
        };
        std::fs::write(&files.cert, cert).unwrap();
        std::fs::write(&files.key, key).unwrap();
        files
    }

    #[test]
    fn a_matching_key_and_certificate_are_taken() {
        let dir = tempfile::tempdir().unwrap();
        let (key, cert) = key_and_cert();
        assert!(tls_config(&files(dir.path(), &key, &cert)).is_ok());
    }

    #[test]
    fn wrong_or_missing_files_say_which_and_what_to_give() {
        let dir = tempfile::tempdir().unwrap();
        let (key, cert) = key_and_cert();
        let (other_key, _) = key_and_cert();
        // A key that does not belong to the certificate.
        let e = tls_config(&files(dir.path(), &other_key, &cert)).unwrap_err();
        assert!(
            matches!(&e, Error::Config(m) if m.contains("belong together")),
            "{e}"
        );
        // Garbage for a certificate, a truncated key.
        let e = tls_config(&files(dir.path(), &key, b"not a certificate")).unwrap_err();
        assert!(
            matches!(&e, Error::Config(m) if m.contains("--web-cert")),
            "{e}"
        );
        let e = tls_config(&files(dir.path(), &key[..key.len() / 2], &cert)).unwrap_err();
        assert!(
            matches!(&e, Error::Config(m) if m.contains("--web-key")),
            "{e}"
        );
        // A file that is not there.
        let mut missing = files(dir.path(), &key, &cert);
        missing.key = dir.path().join("absent.pem");
        let e = tls_config(&missing).unwrap_err();
        assert!(
            matches!(&e, Error::Io(m) if m.starts_with("--web-key: cannot read")),
            "{e}"
        );
    }
}
