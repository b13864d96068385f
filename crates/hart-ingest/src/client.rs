//! The MQTT side: a persistent QoS 1 subscription (clean session off, a stable
//! client ID) through `rumqttc`, the broker cluster's nodes tried in turn, messages
//! fed to the [`Decoder`], samples to the historian's [`Writer`], and each message
//! acknowledged only once the samples it gave are committed: a message the ingest
//! has not stored is delivered again by the broker after a crash or a lost
//! connection, and the historian's key (device, variable, time) stores it once.

use std::time::{Duration, SystemTime};

use hart_history::{Writer, WriterConfig};
use hart_sparkplug::mqtt::{Session, Voice};
use hart_sparkplug::Broker;
use rumqttc::{AsyncClient, Event, MqttOptions, Outgoing, Packet, Publish, QoS, Transport};

use crate::decoder::{Counters, Decoder};
use crate::Error;

/// How the ingest's connection lines read (its command line's options).
const VOICE: Voice = Voice {
    prefix: "ingest",
    address: "--mqtt",
    credentials: "--username and --password-file",
    ca_file: "--ca-file",
    refused: "check its configuration, that it keeps persistent sessions, and the client ID",
    lost: "connecting again (the broker keeps the session's messages)",
    kept: "",
    next_broker: "the next broker",
};

/// How often the samples taken are committed and their messages acknowledged.
pub const COMMIT_EVERY: Duration = Duration::from_millis(250);
/// Messages at most waiting for their commit before one is made at once.
pub const MAX_UNCOMMITTED: usize = 1000;

/// The ingest's settings.
#[derive(Debug, Clone)]
pub struct IngestConfig {
    /// The broker: `mqtt://HOST[:PORT]`, or a cluster's nodes,
    /// `mqtt://h1:p1,h2:p2,h3:p3` (`mqtts://` for TLS with the system's roots).
    pub url: String,
    /// The Sparkplug group to take in.
    pub group: String,
    /// The historian: an SQLite file or a `postgres://` URL.
    pub db: String,
    /// The MQTT client ID: stable, so that the broker keeps the session and queues
    /// messages while the ingest is away (default `hartkit-ingest-GROUP`).
    pub client_id: Option<String>,
    /// The writer's settings (batches, backlog).
    pub writer: WriterConfig,
    /// User name for the broker.
    pub username: Option<String>,
    /// A file whose first line is the broker password.
    pub password_file: Option<std::path::PathBuf>,
    /// PEM file of the certificate authorities of the broker's certificate
    /// (`mqtts://`); without it, the system's roots.
    pub ca_file: Option<std::path::PathBuf>,
}

impl IngestConfig {
    /// The client ID used.
    pub fn client_id(&self) -> String {
        self.client_id
            .clone()
            .unwrap_or_else(|| format!("hartkit-ingest-{}", self.group))
    }
}

/// What the ingest did, when it stops.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Summary {
    /// The decoder's counters.
    pub counters: Counters,
    /// The historian's counters.
    pub history: hart_history::Stats,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.counters;
        write!(
            f,
            "ingest: {} messages, {} samples ({} written), {} births, {} data before a birth, {} unknown aliases, {} seq gaps, {} rebirths asked, {} messages refused",
            c.messages,
            c.samples,
            self.history.written,
            c.births,
            c.before_birth,
            c.unknown_alias,
            c.seq_gaps,
            c.rebirths,
            c.rejected
        )?;
        if self.history.dropped > 0 {
            write!(
                f,
                "; {} samples dropped by the historian",
                self.history.dropped
            )?;
        }
        Ok(())
    }
}

/// The password of `password_file` (its first line).
fn password(config: &IngestConfig) -> Result<Option<String>, Error> {
    match (&config.password_file, &config.username) {
        (Some(_), None) => Err(Error::Config(
            "--password-file is given without --username".into(),
        )),
        (Some(p), Some(_)) => std::fs::read_to_string(p)
            .map(|s| Some(s.lines().next().unwrap_or_default().to_string()))
            .map_err(|e| {
                Error::Config(format!(
                    "--password-file {}: {e}; check the path and that this user may read it",
                    p.display()
                ))
            }),
        (None, _) => Ok(None),
    }
}

fn options(config: &IngestConfig, broker: &Broker) -> Result<MqttOptions, Error> {
    let mut o = MqttOptions::new(config.client_id(), broker.host.clone(), broker.port);
    // A persistent session: what arrives while the ingest is away is queued for it.
    o.set_clean_session(false);
    o.set_manual_acks(true);
    o.set_keep_alive(Duration::from_secs(10));
    // Room above the longest message decoded (decoder::MAX_MESSAGE_BYTES), which is
    // acknowledged and dropped; a longer one is taken once and dropped (the driver).
    o.set_max_packet_size(
        2 * crate::decoder::MAX_MESSAGE_BYTES,
        hart_sparkplug::driver::MAX_OUTGOING,
    );
    if let Some(u) = &config.username {
        o.set_credentials(u.clone(), password(config)?.unwrap_or_default());
    }
    if broker.tls {
        o.set_transport(Transport::Tls(
            hart_sparkplug::mqtt::tls_config(config.ca_file.as_deref())
                .map_err(|e| Error::Config(e.to_string()))?,
        ));
    } else if config.ca_file.is_some() {
        return Err(Error::Config(format!(
            "--ca-file is given but {} is not mqtts://",
            config.url
        )));
    }
    Ok(o)
}

fn check_group(group: &str) -> Result<(), Error> {
    if group.is_empty() || group.contains(['+', '/', '#']) || group.chars().any(char::is_control) {
        return Err(Error::Config(format!(
            "--group {group:?}: a Sparkplug group ID must be non-empty, without '+', '/', '#' or control characters"
        )));
    }
    Ok(())
}

/// Takes in the group's messages until `stop` says so: opens the historian (an
/// error if that fails), then connects (again and again, with backoff, moving to the
/// next broker of the URL) and stores every sample. Returns the counters.
pub async fn run(
    config: IngestConfig,
    mut stop: tokio::sync::watch::Receiver<bool>,
) -> Result<Summary, Error> {
    check_group(&config.group)?;
    let brokers = Broker::parse_list(&config.url).map_err(|e| Error::Config(e.to_string()))?;
    // Settings and files checked before the database is opened.
    options(&config, &brokers[0])?;
    let db = config.db.clone();
    let wc = config.writer.clone();
    let writer = tokio::task::spawn_blocking(move || Writer::start(&db, wc))
        .await
        .map_err(|e| Error::Config(format!("the historian's writer could not start: {e}")))?
        .map_err(Error::History)?;
    let writer = std::sync::Arc::new(writer);
    let mut decoder = Decoder::new(&config.group);
    // The births an earlier run kept, for the data the broker kept meanwhile; births
    // are saved through a connection of their own, before their messages are
    // acknowledged.
    let db = config.db.clone();
    let (store, kept) = tokio::task::spawn_blocking(move || {
        let mut store = hart_history::Store::open(&db, true)?;
        let kept = store.births()?;
        Ok::<_, hart_history::Error>((store, kept))
    })
    .await
    .map_err(|e| Error::Config(format!("the historian could not be opened: {e}")))?
    .map_err(Error::History)?;
    if !kept.is_empty() {
        tracing::info!(
            "ingest: {} births kept by an earlier run taken in",
            kept.len()
        );
    }
    decoder.restore(&kept, SystemTime::now());
    let store = std::sync::Arc::new(std::sync::Mutex::new(store));
    let mut births: Vec<(String, Vec<u8>)> = Vec::new();
    let (client, eventloop) = AsyncClient::new(options(&config, &brokers[0])?, 256);
    // The brokers tried in turn, the back-off, resubscription: the one MQTT client
    // logic of hart-sparkplug, shared with the publisher.
    let mut session = Session::new(brokers, VOICE);
    // Polled on a task of its own: a select! below must never cancel it mid-connect.
    let mut driver = hart_sparkplug::driver::Driver::spawn(eventloop);
    // Samples decoded and not yet handed to the writer, and the messages they came
    // from (with those handed over whose commit failed): acknowledged once committed.
    let mut taken: Vec<hart_history::Sample> = Vec::new();
    let mut uncommitted: Vec<Publish> = Vec::new();
    // The commit under way on a blocking thread (database work never runs here).
    let mut committing: Option<Committing> = None;
    // Connections made: a commit's acknowledgements belong to the connection its
    // messages came on.
    let mut connection: u64 = 0;
    let mut commit = tokio::time::interval(COMMIT_EVERY);
    commit.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut commit_failing = false;
    // A setting that failed while running (the password file gone): the run ends.
    let mut failed: Option<Error> = None;
    let mut refusals_logged = hart_access::pool::LogLimit::default();
    loop {
        // While MAX_UNCOMMITTED messages wait for a commit the historian cannot make,
        // nothing more is taken from the broker, which keeps it: memory stays bounded
        // and the writer never has to drop what the broker delivered.
        let room = uncommitted.len() < MAX_UNCOMMITTED;
        tokio::select! {
            ev = driver.recv(), if room => match ev {
                None => {
                    tracing::error!("ingest: the MQTT client's task ended");
                    break;
                }
                Some(Ok(Event::Incoming(Packet::ConnAck(ack)))) => {
                    session.connected();
                    connection += 1;
                    let b = session.broker();
                    tracing::info!(
                        "ingest: connected to {}:{} as {} ({} session); subscribing to {} at QoS 1",
                        b.host, b.port, config.client_id(),
                        if ack.session_present { "resumed" } else { "new" },
                        decoder.filter()
                    );
                    if let Err(e) = client.try_subscribe(decoder.filter(), QoS::AtLeastOnce) {
                        tracing::warn!("ingest: cannot subscribe: {e}");
                    }
                }
                Some(Ok(Event::Incoming(Packet::SubAck(s)))) => {
                    if s.return_codes.iter().any(|c| matches!(c, rumqttc::SubscribeReasonCode::Failure)) {
                        session.refused(
                            &format!("the subscription to {}", decoder.filter()),
                            "nothing arrives meanwhile",
                        );
                    } else {
                        tracing::info!("ingest: subscribed to {}", decoder.filter());
                    }
                }
                Some(Ok(Event::Incoming(Packet::Publish(p)))) => {
                    match decoder.received(&p.topic, &p.payload, SystemTime::now()) {
                        Ok(out) => {
                            taken.extend(out.samples);
                            births.extend(out.birth);
                            for m in out.publish {
                                tracing::info!("ingest: asking for a rebirth on {}", m.topic);
                                let _ = client.try_publish(m.topic, QoS::AtMostOnce, false, m.payload);
                            }
                        }
                        Err(e) => {
                            // Logged a few lines a second at most: a flood of bad
                            // messages is counted, not written out one by one.
                            let (log, left_out) = refusals_logged.allow(std::time::Instant::now());
                            if left_out > 0 {
                                tracing::warn!("ingest: {left_out} more messages ignored in the last second(s), not logged one by one");
                            }
                            if log {
                                tracing::warn!("ingest: message ignored: {e}");
                            }
                        }
                    }
                    if p.qos != QoS::AtMostOnce {
                        // Kept only to be acknowledged: its packet id, not its payload.
                        let mut p = p;
                        p.payload = Default::default();
                        uncommitted.push(p);
                    }
                    if uncommitted.len() >= MAX_UNCOMMITTED && committing.is_none() {
                        committing = Committing::start(&writer, &store, &mut taken, &mut births, &mut uncommitted, connection);
                    }
                }
                Some(Ok(_)) => {}
                Some(Err(e)) => {
                    let lost = session.lost(&e);
                    // Acknowledgements of the lost connection mean nothing in the next:
                    // the broker sends those messages again (their samples, taken
                    // already, are written all the same: the historian stores a sample
                    // once).
                    uncommitted.clear();
                    let mut next = None;
                    if lost.rotated {
                        match options(&config, session.broker()) {
                            Ok(o) => next = Some(o),
                            // Ended below, where the database connection may close.
                            Err(e) => {
                                failed = Some(e);
                                break;
                            }
                        }
                    }
                    // A persistent session: rumqttc keeps what it must send again.
                    driver.resume(hart_sparkplug::driver::Resume { options: next, clear: false, after: lost.after });
                }
            },
            done = async { (&mut committing.as_mut().expect("guarded").task).await }, if committing.is_some() => {
                let c = committing.take().expect("guarded");
                commit_failing = c.finished(done, &client, &mut uncommitted, &mut births, connection, commit_failing);
            }
            _ = commit.tick() => {
                if session.resubscribe_due() {
                    let _ = client.try_subscribe(decoder.filter(), QoS::AtLeastOnce);
                }
                if committing.is_none() && !(uncommitted.is_empty() && taken.is_empty()) {
                    committing = Committing::start(&writer, &store, &mut taken, &mut births, &mut uncommitted, connection);
                }
            }
            _ = stop.changed() => break,
        }
    }
    // Stop: the commit under way, then one of what is left; acknowledge; disconnect
    // (the session stays at the broker).
    if let Some(mut c) = committing.take() {
        let done = (&mut c.task).await;
        commit_failing = c.finished(
            done,
            &client,
            &mut uncommitted,
            &mut births,
            connection,
            commit_failing,
        );
    }
    if let Some(mut c) = Committing::start(
        &writer,
        &store,
        &mut taken,
        &mut births,
        &mut uncommitted,
        connection,
    ) {
        let done = (&mut c.task).await;
        c.finished(
            done,
            &client,
            &mut uncommitted,
            &mut births,
            connection,
            commit_failing,
        );
    }
    if session.is_connected() {
        let _ = client.try_disconnect();
        let _ = tokio::time::timeout(Duration::from_secs(3), async {
            loop {
                match driver.recv().await {
                    Some(Ok(Event::Outgoing(Outgoing::Disconnect)) | Err(_)) | None => break,
                    Some(Ok(_)) => {}
                }
            }
        })
        .await;
    }
    // A PostgreSQL connection is closed where it may block.
    let _ = tokio::task::spawn_blocking(move || drop(store)).await;
    if let Some(e) = failed {
        return Err(e);
    }
    let history = match std::sync::Arc::try_unwrap(writer) {
        Ok(w) => tokio::task::spawn_blocking(move || w.close())
            .await
            .unwrap_or_default(),
        Err(w) => w.stats(),
    };
    Ok(Summary {
        counters: decoder.counters(),
        history,
    })
}

/// A commit under way on a blocking thread: the samples handed to the writer and
/// flushed there, and the messages they came from, to acknowledge once it is done.
struct Committing {
    messages: Vec<Publish>,
    /// The births saved with it (given back when it fails).
    births: Vec<(String, Vec<u8>)>,
    connection: u64,
    task: tokio::task::JoinHandle<Result<u64, hart_history::Error>>,
}

impl Committing {
    /// Hands `taken` to the writer and commits on a blocking thread; `None` when there
    /// is nothing to commit.
    fn start(
        writer: &std::sync::Arc<Writer>,
        store: &std::sync::Arc<std::sync::Mutex<hart_history::Store>>,
        taken: &mut Vec<hart_history::Sample>,
        births: &mut Vec<(String, Vec<u8>)>,
        uncommitted: &mut Vec<Publish>,
        connection: u64,
    ) -> Option<Committing> {
        if taken.is_empty() && uncommitted.is_empty() && births.is_empty() {
            return None;
        }
        let samples = std::mem::take(taken);
        let saving = std::mem::take(births);
        let kept = saving.clone();
        let w = writer.clone();
        let store = store.clone();
        let task = tokio::task::spawn_blocking(move || {
            let dropped = w.stats().dropped;
            // The samples to the writer first (a failure below leaves them there, for
            // the next commit); a message is acknowledged only once the births that
            // read its data after a restart are kept too.
            w.submit_wait(samples);
            store
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .save_births(&saving)?;
            w.flush()?;
            Ok(w.stats().dropped.saturating_sub(dropped))
        });
        Some(Committing {
            messages: std::mem::take(uncommitted),
            births: kept,
            connection,
            task,
        })
    }

    /// What became of the commit: its messages acknowledged when every sample they
    /// gave was committed on the connection they came on; given back to wait for the
    /// next commit when it failed. Returns whether commits are failing (logged once
    /// until they work again).
    fn finished(
        self,
        done: Result<Result<u64, hart_history::Error>, tokio::task::JoinError>,
        client: &AsyncClient,
        uncommitted: &mut Vec<Publish>,
        births: &mut Vec<(String, Vec<u8>)>,
        connection: u64,
        was_failing: bool,
    ) -> bool {
        let same = self.connection == connection;
        match done {
            Ok(Ok(0)) => {
                if same {
                    for p in &self.messages {
                        let _ = client.try_ack(p);
                    }
                }
                if was_failing {
                    tracing::info!("ingest: the historian takes samples again");
                }
                false
            }
            Ok(Ok(dropped)) => {
                // Not acknowledged: the broker delivers them again after the next
                // connection, and the historian stores what it missed.
                tracing::error!(
                    "ingest: the historian dropped {dropped} samples; the {} messages of this commit are not acknowledged, so the broker delivers them again after a reconnection",
                    self.messages.len()
                );
                false
            }
            Ok(Err(e)) => {
                if !was_failing {
                    tracing::warn!(
                        "ingest: the historian cannot commit ({e}); messages are not acknowledged until it can, so the broker keeps them"
                    );
                }
                if same {
                    // Their samples are with the writer: the next commit covers them.
                    let newer = std::mem::replace(uncommitted, self.messages);
                    uncommitted.extend(newer);
                }
                let newer = std::mem::replace(births, self.births);
                births.extend(newer);
                true
            }
            Err(e) => {
                tracing::error!(
                    "ingest: the commit's thread failed ({e}); its messages are not acknowledged"
                );
                true
            }
        }
    }
}
