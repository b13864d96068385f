//! The one MQTT client module of the Sparkplug B edge node (hart-sparkplug-edge) and
//! the ingest (hart-ingest): the broker list of a URL tried in turn, the back-off
//! between attempts, resubscription after a refused subscription, the log lines of
//! lost and failed connections ([`Session`]), and the TLS settings of `mqtts://`
//! ([`tls_config`]). rumqttc's event loop runs on its own task ([`crate::driver`]).

use std::time::Duration;

use rumqttc::{ConnectReturnCode, ConnectionError, TlsConfiguration};

use crate::config::Broker;
use crate::Error;

/// The TLS configuration of `mqtts://`: OpenSSL (through native-tls), TLS 1.2 or
/// newer, the broker's certificate checked against the CA file's certificates only, or
/// against the system's certificate authorities without one.
pub fn tls_config(ca_file: Option<&std::path::Path>) -> Result<TlsConfiguration, Error> {
    use native_tls::{Certificate, Protocol, TlsConnector};
    let mut builder = TlsConnector::builder();
    builder.min_protocol_version(Some(Protocol::Tlsv12));
    match ca_file {
        Some(path) => {
            let pem =
                std::fs::read(path).map_err(|e| Error::File(path.to_path_buf(), e.to_string()))?;
            let certs = Certificate::stack_from_pem(&pem).map_err(|e| {
                Error::File(
                    path.to_path_buf(),
                    format!("not a PEM certificate file: {e}"),
                )
            })?;
            if certs.is_empty() {
                return Err(Error::File(
                    path.to_path_buf(),
                    "no certificate in it (PEM, -----BEGIN CERTIFICATE-----)".into(),
                ));
            }
            // Only the operator's CA: the system's authorities do not vouch for a
            // plant's broker.
            builder.disable_built_in_roots(true);
            for c in certs {
                builder.add_root_certificate(c);
            }
        }
        None => {
            if !SYSTEM_CA_BUNDLES
                .iter()
                .any(|f| std::fs::metadata(f).is_ok_and(|m| m.len() > 0))
            {
                return Err(Error::Config(
                    "mqtts:// without ca_file, and no system certificate authorities were found; give [mqtt] ca_file".into(),
                ));
            }
        }
    }
    let connector = builder
        .build()
        .map_err(|e| Error::Config(format!("TLS: {e}")))?;
    Ok(TlsConfiguration::NativeConnector(connector))
}

/// Where Linux distributions keep the system's certificate authorities (Debian's
/// bundle first), which OpenSSL reads when no CA file is given.
const SYSTEM_CA_BUNDLES: [&str; 3] = [
    "/etc/ssl/certs/ca-certificates.crt",
    "/etc/pki/tls/certs/ca-bundle.crt",
    "/etc/ssl/cert.pem",
];

/// How a client names itself and its settings in its log lines, so that the one
/// connection code below speaks as the publisher (`mqtt: ...`, `[mqtt]` settings) or
/// as the ingest (`ingest: ...`, its options).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Voice {
    /// The prefix of every line (`mqtt`, `ingest`).
    pub prefix: &'static str,
    /// Where the broker's address is set (`--mqtt`).
    pub address: &'static str,
    /// Where the credentials are set (`[mqtt] username and password_file`).
    pub credentials: &'static str,
    /// Where the CA file is set (`[mqtt] ca_file`).
    pub ca_file: &'static str,
    /// What to check when the broker refuses the connection itself.
    pub refused: &'static str,
    /// The end of the line of a lost connection (what happens meanwhile).
    pub lost: &'static str,
    /// Said after the attempt count of a failed connection (what is kept meanwhile).
    pub kept: &'static str,
    /// How the next broker of a list is named (`the next broker of the cluster`).
    pub next_broker: &'static str,
}

/// How long to wait before subscribing again to a refused subscription (a cluster
/// electing leaders refuses for a while).
pub const RESUBSCRIBE_AFTER: Duration = Duration::from_secs(5);

/// The first wait after a failed connection; each next one doubles, up to
/// [`BACKOFF_MAX`] (0.5, 1, 2, 4, 8, 15 s).
pub const BACKOFF_FIRST: Duration = Duration::from_millis(500);
/// The longest wait between two connection attempts to one broker.
pub const BACKOFF_MAX: Duration = Duration::from_secs(15);
/// The wait before trying the next broker of a list (the back-off comes after a whole
/// round).
pub const NEXT_BROKER_AFTER: Duration = Duration::from_millis(100);

/// What to do after a connection failed or ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Lost {
    /// Why, and what to check (logged already; for status pages).
    pub why: String,
    /// The broker to try next is another one of the list: the caller makes new
    /// options for [`Session::broker`].
    pub rotated: bool,
    /// Wait this long before connecting again.
    pub after: Duration,
}

/// The one MQTT connection logic of the publisher and the ingest: the broker list
/// (a cluster's nodes, tried in turn), the back-off between attempts
/// ([`hart_clock::Backoff`]), resubscription after a refusal, and the log lines of
/// lost and failed connections. Plain state: the caller owns the rumqttc client and
/// its [`crate::driver::Driver`].
#[derive(Debug)]
pub struct Session {
    voice: Voice,
    brokers: Vec<Broker>,
    current: usize,
    backoff: hart_clock::Backoff,
    connected: bool,
    resubscribe_at: Option<tokio::time::Instant>,
}

impl Session {
    /// A session over `brokers` (at least one: [`Broker::parse_list`] gives them),
    /// starting with the first.
    pub fn new(brokers: Vec<Broker>, voice: Voice) -> Self {
        Session {
            voice,
            brokers,
            current: 0,
            backoff: hart_clock::Backoff::new(BACKOFF_FIRST, BACKOFF_MAX),
            connected: false,
            resubscribe_at: None,
        }
    }

    /// The broker of the current (or next) connection.
    pub fn broker(&self) -> &Broker {
        &self.brokers[self.current]
    }

    /// Whether a connection is up (CONNACK seen, no error since).
    pub fn is_connected(&self) -> bool {
        self.connected
    }

    /// A CONNACK: the back-off starts over and no resubscription is due.
    pub fn connected(&mut self) {
        self.connected = true;
        self.backoff.reset();
        self.resubscribe_at = None;
    }

    /// The connection ended at the client's request (no failure): nothing to log.
    pub fn closed(&mut self) {
        self.connected = false;
        self.resubscribe_at = None;
    }

    /// The connection failed or ended with `e`: logs why (every failure while
    /// connected, then attempts 1, 2, 4, 8, ...), moves to the next broker of the list
    /// and says how long to wait.
    pub fn lost(&mut self, e: &ConnectionError) -> Lost {
        let v = self.voice;
        let why = explain(e, self.broker(), &v);
        let failures = self.backoff.failures();
        if self.connected {
            tracing::warn!("{}: connection lost: {why}; {}", v.prefix, v.lost);
        } else if failures == 0 || failures.is_power_of_two() {
            tracing::warn!(
                "{}: cannot connect: {why} (attempt {}{})",
                v.prefix,
                failures + 1,
                v.kept
            );
        }
        self.connected = false;
        self.resubscribe_at = None;
        let mut after = self.backoff.failed(std::time::Instant::now());
        let rotated = self.brokers.len() > 1;
        if rotated {
            // A cluster: the next node at once, the back-off only after a full round.
            self.current = (self.current + 1) % self.brokers.len();
            let b = self.broker();
            tracing::info!(
                "{}: trying {}, {}:{}",
                v.prefix,
                v.next_broker,
                b.host,
                b.port
            );
            if self.current != 0 {
                after = NEXT_BROKER_AFTER;
            }
        }
        Lost {
            why,
            rotated,
            after,
        }
    }

    /// The broker refused `what` (a SUBACK failure), which means `meanwhile`: logged,
    /// and asked again after [`RESUBSCRIBE_AFTER`] ([`Session::resubscribe_due`]).
    pub fn refused(&mut self, what: &str, meanwhile: &str) {
        tracing::warn!(
            "{}: the broker refused {what}: {meanwhile}; asking again in {} s; check the \
             broker's access rules for this user",
            self.voice.prefix,
            RESUBSCRIBE_AFTER.as_secs()
        );
        self.resubscribe_at = Some(tokio::time::Instant::now() + RESUBSCRIBE_AFTER);
    }

    /// Whether to subscribe again now (connected, and the wait after a refusal is
    /// over); true once per refusal.
    pub fn resubscribe_due(&mut self) -> bool {
        let due = self
            .resubscribe_at
            .is_some_and(|t| t <= tokio::time::Instant::now());
        if !self.connected || !due {
            return false;
        }
        self.resubscribe_at = None;
        true
    }
}

/// Why the broker connection failed, and what to check.
pub fn explain(e: &ConnectionError, broker: &Broker, voice: &Voice) -> String {
    let at = format!("{}:{}", broker.host, broker.port);
    match e {
        ConnectionError::ConnectionRefused(
            ConnectReturnCode::BadUserNamePassword | ConnectReturnCode::NotAuthorized,
        ) => format!(
            "the broker at {at} refused the credentials ({e}); check {}",
            voice.credentials
        ),
        ConnectionError::ConnectionRefused(c) => {
            format!(
                "the broker at {at} refused the connection ({c:?}); {}",
                voice.refused
            )
        }
        ConnectionError::Io(io) if io.kind() == std::io::ErrorKind::ConnectionRefused => format!(
            "nothing accepts connections at {at} ({io}); check that the broker runs and the host and port of {}",
            voice.address
        ),
        ConnectionError::Tls(t) => format!(
            "TLS with {at} failed ({t}); check {} and that the broker's certificate names the host {}",
            voice.ca_file, broker.host
        ),
        ConnectionError::NetworkTimeout => {
            format!(
                "no answer from {at} in time; check the network and the address of {}",
                voice.address
            )
        }
        other => format!("connection to {at}: {other}"),
    }
}
