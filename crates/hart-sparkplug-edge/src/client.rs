//! The MQTT side: a `rumqttc` client that carries out what the [`EdgeNode`] asks,
//! feeds it the engine's image changes and the broker's messages, and reconnects with
//! backoff. Writes from DCMD go through `Engine::apply` (access rules and audit of
//! every front end).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use hart_poller::Engine;
use rumqttc::{
    AsyncClient, ConnectionError, Event, LastWill, MqttOptions, Outgoing, Packet, QoS,
    TlsConfiguration, Transport,
};

use hart_sparkplug::config::{Broker, MqttConfig};
use hart_sparkplug::driver::{Driver, Resume};
use hart_sparkplug::mqtt::{tls_config, Session, Voice};
use hart_sparkplug::Error;

use crate::edge::{EdgeNode, Message, Output, Sample, Settings, WriteRequest};

/// How long to wait before subscribing again to a refused subscription.
pub use hart_sparkplug::mqtt::RESUBSCRIBE_AFTER;

/// How the publisher's connection lines read (the `[mqtt]` section's settings).
const VOICE: Voice = Voice {
    prefix: "mqtt",
    address: "--mqtt",
    credentials: "[mqtt] username and password_file",
    ca_file: "[mqtt] ca_file",
    refused: "check its configuration and the client ID",
    lost: "connecting again, samples are kept meanwhile",
    kept: "; samples are kept meanwhile",
    next_broker: "the next broker of the cluster",
};

/// Image changes the publisher holds at most before the engine drops the oldest (and
/// logs it): minutes of a busy gateway's polls.
pub const CHANGE_QUEUE: usize = 65_536;

/// Where the samples of a long outage are read back from: the gateway's historian,
/// which keeps every value whatever happens to the broker ([`EdgeNode::with_spill`]).
pub trait Backfill: Send + Sync + std::fmt::Debug + 'static {
    /// The engine's devices' samples from `from` to `to` (ms since the Unix epoch, `to`
    /// excluded), as the edge node's samples; or why they cannot be read. Blocking: it
    /// is called on a blocking thread.
    fn samples(&self, from: u64, to: u64) -> Result<Vec<Sample>, String>;
}

/// What the publisher is doing, for status pages and tests.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Status {
    /// An MQTT session is up.
    pub connected: bool,
    /// Births are out and data flow (connected, and the primary host online).
    pub live: bool,
    /// `bdSeq` of the current or last connection.
    pub bd_seq: u8,
    /// Samples waiting to be sent.
    pub backlog: usize,
    /// Counters of the edge node.
    pub counters: crate::edge::Counters,
    /// Why the last connection failed or ended.
    pub last_error: Option<String>,
}

/// A running publisher.
pub struct Handle {
    status: Arc<Mutex<Status>>,
    stop: tokio::sync::watch::Sender<bool>,
    task: tokio::task::JoinHandle<()>,
}

impl Handle {
    /// The current status.
    pub fn status(&self) -> Status {
        self.status
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Stops: an NDEATH and a clean DISCONNECT when connected (Sparkplug 3.0 section
    /// 5.5), then the task ends.
    pub async fn shutdown(self) {
        let _ = self.stop.send(true);
        let _ = tokio::time::timeout(Duration::from_secs(5), self.task).await;
    }
}

/// Starts publishing the engine's devices to the broker of `config`. Returns once the
/// settings are checked and the files read; the connection is made (and made again)
/// in the background, with a log line for each failure.
pub async fn run(
    engine: Engine,
    config: MqttConfig,
    backfill: Option<Arc<dyn Backfill>>,
) -> Result<Handle, Error> {
    let brokers = config.check()?;
    let password = match &config.password_file {
        Some(p) => Some(
            std::fs::read_to_string(p)
                .map_err(|e| Error::File(p.clone(), e.to_string()))?
                .lines()
                .next()
                .unwrap_or_default()
                .to_string(),
        ),
        None => None,
    };
    let tls = if brokers[0].tls {
        Some(tls_config(config.ca_file.as_deref())?)
    } else {
        if config.ca_file.is_some() {
            return Err(Error::Config(format!(
                "[mqtt] ca_file is given but {} is not mqtts://",
                config.url
            )));
        }
        None
    };
    let settings = Settings {
        group: config.group.clone(),
        edge_node: config.edge_node.clone(),
        primary_host: config.primary_host.clone(),
        backlog: config.backlog,
        read_only: config.read_only,
        gateway: engine.write_policy().clone(),
    };
    let mut core = EdgeNode::new(settings)
        .with_data_qos(config.data_qos)
        .with_spill(backfill.is_some());
    let client_id = config
        .client_id
        .clone()
        .unwrap_or_else(|| format!("hartkit-{}-{}", config.group, config.edge_node));
    let template = Template {
        client_id,
        credentials: config
            .username
            .clone()
            .map(|u| (u, password.unwrap_or_default())),
        tls,
    };
    let session = Session::new(brokers, VOICE);
    let will = last_will(core.will(SystemTime::now()));
    let mut options = template.options(session.broker());
    options.set_last_will(will.clone());
    let (client, eventloop) = AsyncClient::new(options, 1024);
    // One page read back at a time: the channel never holds more than one.
    let (backfilled_tx, backfilled_rx) = tokio::sync::mpsc::channel(1);
    let status = Arc::new(Mutex::new(Status::default()));
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let (writes, queue) = tokio::sync::mpsc::unbounded_channel();
    tokio::spawn(dcmd_writer(engine.clone(), config.url.clone(), queue));
    let publisher = Publisher {
        writes,
        engine,
        backfill,
        core,
        client,
        driver: Driver::spawn(eventloop),
        will,
        backfilled_tx,
        backfilled_rx,
        backfill_run: None,
        backfill_runs: 0,
        url: config.url.clone(),
        session,
        template,
        outbox: VecDeque::new(),
        inflight: VecDeque::new(),
        unacked: VecDeque::new(),
        subscriptions: Vec::new(),
        status: status.clone(),
        last_error: None,
    };
    let task = tokio::spawn(publisher.run(stop_rx));
    Ok(Handle { status, stop, task })
}

/// What every connection's options share; the broker differs (a cluster's nodes).
struct Template {
    client_id: String,
    credentials: Option<(String, String)>,
    tls: Option<TlsConfiguration>,
}

impl Template {
    fn options(&self, broker: &Broker) -> MqttOptions {
        let mut options =
            MqttOptions::new(self.client_id.clone(), broker.host.clone(), broker.port);
        // Sparkplug 3.0 section 2.5: an edge node's session is never persistent.
        options.set_clean_session(true);
        options.set_keep_alive(Duration::from_secs(10));
        // Commands are small (edge::MAX_COMMAND_BYTES); a longer message is taken
        // once and dropped (driver.rs).
        options.set_max_packet_size(1 << 20, hart_sparkplug::driver::MAX_OUTGOING);
        if let Some((u, p)) = &self.credentials {
            options.set_credentials(u.clone(), p.clone());
        }
        if let Some(t) = &self.tls {
            options.set_transport(Transport::Tls(t.clone()));
        }
        options
    }
}

fn last_will(m: Message) -> LastWill {
    LastWill::new(m.topic, m.payload, qos(m.qos), m.retain)
}

fn qos(q: u8) -> QoS {
    if q == 0 {
        QoS::AtMostOnce
    } else {
        QoS::AtLeastOnce
    }
}

/// Samples a read-back page aims at: the time window of the next page halves when a
/// page held more, and doubles when it held less than a quarter.
pub const BACKFILL_PAGE: usize = 2_000;

/// The next page of a read-back is read only while fewer messages than this wait to
/// be handed to the MQTT client: with one page in memory at a time, a read-back of
/// any length holds at most about this many messages and one page of samples.
pub const BACKFILL_LOW_WATER: usize = 256;

/// The first page's time window.
const FIRST_WINDOW_MS: u64 = 1_000;
/// The shortest window (a page of one window is read whatever it holds).
const MIN_WINDOW_MS: u64 = 10;
/// The longest window.
const MAX_WINDOW_MS: u64 = 3_600_000;

/// A read-back from the historian, page by page.
#[derive(Debug)]
struct BackfillRun {
    /// The start of what is left (ms).
    from: u64,
    /// The end (ms, excluded).
    to: u64,
    /// The next page's time window (ms).
    window: u64,
    /// The end of the page being read, if one is.
    reading: Option<u64>,
    /// Samples sent so far.
    sent: u64,
    /// Which run (pages of an ended one are ignored).
    id: u64,
}

/// One page read back.
struct Page {
    id: u64,
    from: u64,
    end: u64,
    samples: Result<Vec<Sample>, String>,
}

struct Publisher {
    /// DCMD writes, to the one task that carries them out in order.
    writes: tokio::sync::mpsc::UnboundedSender<QueuedWrite>,
    engine: Engine,
    /// The gateway's historian, when it has one: a full store-and-forward backlog
    /// leaves the rest of an outage to it, read back afterwards.
    backfill: Option<Arc<dyn Backfill>>,
    core: EdgeNode,
    client: AsyncClient,
    /// rumqttc's event loop, on a task of its own (never cancelled mid-connect).
    driver: Driver,
    /// The will of the next (or current) session: its NDEATH.
    will: LastWill,
    /// Pages read back from the historian ([`Publisher::backfill`]).
    backfilled_tx: tokio::sync::mpsc::Sender<Page>,
    backfilled_rx: tokio::sync::mpsc::Receiver<Page>,
    /// The read-back under way, page by page.
    backfill_run: Option<BackfillRun>,
    /// Read-backs started (each run's `id`).
    backfill_runs: u64,
    url: String,
    /// The brokers of the URL tried in turn, the back-off, resubscription
    /// (hart-sparkplug's one MQTT client logic).
    session: Session,
    template: Template,
    /// What the edge node asked that the client's queue has not taken yet.
    outbox: VecDeque<Output>,
    /// The samples of each publish handed to the client and not yet written, in order.
    inflight: VecDeque<Vec<Sample>>,
    /// QoS 1 publishes written and not yet acknowledged (packet ID, samples), oldest
    /// first: rumqttc drops them when the next session is a clean one, so they are
    /// given back to the edge node (sent again, historical) unless the broker
    /// acknowledges them first.
    unacked: VecDeque<(u16, Vec<Sample>)>,
    /// The subscriptions of this session (NCMD, DCMD, STATE), to ask again when the
    /// broker refused one.
    subscriptions: Vec<(String, u8)>,
    status: Arc<Mutex<Status>>,
    last_error: Option<String>,
}

impl Publisher {
    async fn run(mut self, mut stop: tokio::sync::watch::Receiver<bool>) {
        // The image as it is, then every commit after it, in order, each with the
        // device as it was then (a commit between the two is carried by the next).
        self.feed_all();
        let mut changes = self.engine.image().changes(CHANGE_QUEUE);
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            self.hand_over();
            self.next_page();
            self.publish_status();
            tokio::select! {
                ev = self.driver.recv() => match ev {
                    Some(Ok(ev)) => self.event(ev),
                    Some(Err(e)) => {
                        let resume = self.lost(&e);
                        self.driver.resume(resume);
                    }
                    None => {
                        tracing::error!("mqtt: the MQTT client's task ended; nothing is published any more");
                        return;
                    }
                },
                Some(page) = self.backfilled_rx.recv() => self.page_read(page),
                c = changes.recv() => match c {
                    Some(c) => {
                        let out = self.core.device(&c.device, c.quality, c.value_time(), self.engine.clock().wall());
                        self.apply(out);
                    }
                    None => {
                        tracing::info!("mqtt: the engine has stopped: disconnecting");
                        self.shutdown().await;
                        return;
                    }
                },
                _ = tick.tick() => {
                    self.resubscribe_if_due();
                    let out = self.core.tick(SystemTime::now());
                    self.apply(out);
                    // Qualities that change with time alone (stale): after the changes
                    // waiting, so that nothing older follows the current image.
                    while let Some(c) = changes.try_recv() {
                        let out = self.core.device(&c.device, c.quality, c.value_time(), self.engine.clock().wall());
                        self.apply(out);
                    }
                    self.feed_all();
                }
                _ = stop.changed() => {
                    self.shutdown().await;
                    return;
                }
            }
        }
    }

    /// Subscribes again to what the broker refused, once the wait is over.
    fn resubscribe_if_due(&mut self) {
        if !self.session.resubscribe_due() {
            return;
        }
        for (topic, q) in &self.subscriptions {
            let _ = self.client.try_subscribe(topic.clone(), qos(*q));
        }
    }

    fn publish_status(&self) {
        let mut s = self.status.lock().unwrap_or_else(|e| e.into_inner());
        *s = Status {
            connected: self.session.is_connected(),
            live: self.core.is_live(),
            bd_seq: self.core.bd_seq(),
            backlog: self.core.backlog_len(),
            counters: self.core.counters(),
            last_error: self.last_error.clone(),
        };
    }

    /// Gives the client what it will take now.
    fn hand_over(&mut self) {
        while let Some(o) = self.outbox.front() {
            let r = match o {
                Output::Publish(m) => self.client.try_publish(
                    m.topic.clone(),
                    qos(m.qos),
                    m.retain,
                    m.payload.clone(),
                ),
                Output::Subscribe { topic, qos: q } => {
                    let r = self.client.try_subscribe(topic.clone(), qos(*q));
                    if r.is_ok() && !self.subscriptions.iter().any(|(t, _)| t == topic) {
                        self.subscriptions.push((topic.clone(), *q));
                    }
                    r
                }
                Output::Disconnect => self.client.try_disconnect(),
                Output::Write(_) | Output::Backfill { .. } => Ok(()),
            };
            if r.is_err() {
                // The client's queue is full: the rest waits for the next turn.
                return;
            }
            if let Some(Output::Publish(m)) = self.outbox.pop_front() {
                self.inflight.push_back(m.keep);
            }
        }
    }

    fn apply(&mut self, outputs: Vec<Output>) {
        for o in outputs {
            match o {
                Output::Write(w) => self.write(w),
                Output::Backfill { from, to } => self.backfill(from, to),
                o => self.outbox.push_back(o),
            }
        }
    }

    fn event(&mut self, ev: Event) {
        match ev {
            Event::Incoming(Packet::ConnAck(_)) => {
                self.session.connected();
                self.subscriptions.clear();
                self.last_error = None;
                tracing::info!(
                    "mqtt: connected to {} as edge node {}/{} (bdSeq {})",
                    self.url,
                    self.core.settings().group,
                    self.core.settings().edge_node,
                    self.core.bd_seq()
                );
                if let Some(h) = &self.core.settings().primary_host {
                    tracing::info!(
                        "mqtt: waiting for primary host {h} to be online (spBv1.0/STATE/{h})"
                    );
                }
                let out = self.core.connected(SystemTime::now());
                self.apply(out);
            }
            Event::Incoming(Packet::Publish(p)) => {
                let how = crate::edge::Delivery { retained: p.retain };
                let out = self
                    .core
                    .delivered(&p.topic, &p.payload, how, SystemTime::now());
                self.apply(out);
            }
            Event::Incoming(Packet::SubAck(s))
                if s.return_codes
                    .iter()
                    .any(|c| matches!(c, rumqttc::SubscribeReasonCode::Failure)) =>
            {
                self.session.refused(
                    "a subscription (NCMD, DCMD or STATE)",
                    "commands will not arrive meanwhile",
                );
            }
            Event::Outgoing(Outgoing::Publish(pkid)) => {
                let samples = self.inflight.pop_front().unwrap_or_default();
                if pkid != 0 && !samples.is_empty() {
                    self.unacked.push_back((pkid, samples));
                }
            }
            Event::Incoming(Packet::PubAck(ack)) => {
                if let Some(i) = self.unacked.iter().position(|(p, _)| *p == ack.pkid) {
                    self.unacked.remove(i);
                }
            }
            Event::Outgoing(Outgoing::Disconnect) => {
                // Asked by the edge node (primary host offline): connect again at once
                // and wait for the host there. The loop tests the host started end.
                if let Some(h) = self.primary_holder() {
                    self.engine.release_held_by(&h);
                }
                self.forget_session(None);
                self.driver.resume(Resume {
                    options: Some(self.options()),
                    clear: true,
                    after: Duration::ZERO,
                });
            }
            _ => {}
        }
    }

    /// The connection failed or ended: log why, keep what was not sent; returns how the
    /// event loop goes on (the next CONNECT's will, the next broker of a cluster, the
    /// wait before trying).
    fn lost(&mut self, e: &ConnectionError) -> Resume {
        let lost = self.session.lost(e);
        self.forget_session(Some(lost.why));
        let after = lost.after;
        Resume {
            options: Some(self.options()),
            clear: true,
            after,
        }
    }

    /// The options of the next CONNECT: the broker tried next, with the will of the
    /// session to come.
    fn options(&self) -> rumqttc::MqttOptions {
        let mut options = self.template.options(self.session.broker());
        options.set_last_will(self.will.clone());
        options
    }

    /// The session is over: what it had not sent is kept, and the next session's will
    /// (its bdSeq) is made. Nothing of the old session may go out in the new one (the
    /// [`Resume`] that follows clears rumqttc's queue).
    fn forget_session(&mut self, why: Option<String>) {
        if why.is_some() {
            self.last_error = why;
        }
        self.session.closed();
        let mut unsent: Vec<Sample> = self.unacked.drain(..).flat_map(|(_, s)| s).collect();
        unsent.extend(self.inflight.drain(..).flatten());
        for o in self.outbox.drain(..) {
            if let Output::Publish(m) = o {
                unsent.extend(m.keep);
            }
        }
        self.core.disconnected(unsent);
        if let Some(run) = self.backfill_run.take() {
            // What was not sent (the page being read included) is asked again after
            // the next births; a page read meanwhile is ignored.
            self.core.backfill_unfinished(run.from, run.to);
        }
        self.will = last_will(self.core.will(SystemTime::now()));
    }

    fn feed(&mut self, position: usize) {
        let now = self.engine.clock().now();
        let Some((image, quality)) = self
            .engine
            .image()
            .with(position, |d| (d.clone(), d.quality(now)))
        else {
            return;
        };
        let wall = self.engine.clock().wall();
        let at = image.value_time(quality, wall);
        let out = self.core.device(&image, quality, at, wall);
        self.apply(out);
    }

    fn feed_all(&mut self) {
        for p in 0..self.engine.image().len() {
            self.feed(p);
        }
    }

    /// Starts reading back what the historian kept from `from` to `to`, page by page
    /// ([`Publisher::next_page`]).
    fn backfill(&mut self, from: u64, to: u64) {
        if self.backfill.is_none() {
            let out = self.core.backfill_done(SystemTime::now());
            self.apply(out);
            return;
        }
        let run = match self.backfill_run.take() {
            Some(r) => BackfillRun {
                from: r.from.min(from),
                to: r.to.max(to),
                ..r
            },
            None => BackfillRun {
                from,
                to,
                window: FIRST_WINDOW_MS,
                reading: None,
                sent: 0,
                id: {
                    self.backfill_runs += 1;
                    self.backfill_runs
                },
            },
        };
        self.backfill_run = Some(run);
    }

    /// Reads the next page of the read-back on a blocking thread, when none is being
    /// read and the outbox has room: memory holds at most one page and the outbox's
    /// low water mark of it, whatever the outage's length.
    fn next_page(&mut self) {
        let Some(source) = self.backfill.clone() else {
            return;
        };
        let room = self.outbox.len() + self.inflight.len() < BACKFILL_LOW_WATER;
        let Some(run) = self.backfill_run.as_mut() else {
            return;
        };
        if run.reading.is_some() || !room || !self.session.is_connected() || !self.core.is_live() {
            return;
        }
        let (from, end) = (run.from, run.to.min(run.from.saturating_add(run.window)));
        run.reading = Some(end);
        let id = run.id;
        let tx = self.backfilled_tx.clone();
        tokio::spawn(async move {
            let read = tokio::task::spawn_blocking(move || source.samples(from, end))
                .await
                .unwrap_or_else(|e| Err(format!("the reading task failed: {e}")));
            let _ = tx
                .send(Page {
                    id,
                    from,
                    end,
                    samples: read,
                })
                .await;
        });
    }

    /// A page read back: sent historical, the window fitted to [`BACKFILL_PAGE`], and
    /// at the end of the range the deaths that waited for it.
    fn page_read(&mut self, page: Page) {
        let Some(run) = self.backfill_run.as_mut() else {
            return;
        };
        if run.id != page.id || run.from != page.from || run.reading != Some(page.end) {
            return; // of a session that has ended
        }
        run.reading = None;
        let now = SystemTime::now();
        match page.samples {
            Ok(samples) => {
                let n = samples.len();
                run.sent += n as u64;
                run.window = if n > BACKFILL_PAGE {
                    (run.window / 2).max(MIN_WINDOW_MS)
                } else if n < BACKFILL_PAGE / 4 {
                    run.window.saturating_mul(2).min(MAX_WINDOW_MS)
                } else {
                    run.window
                };
                run.from = page.end;
                let done = run.from >= run.to;
                let sent = run.sent;
                let out = self.core.backfilled(samples, now);
                self.apply(out);
                if done {
                    self.backfill_run = None;
                    tracing::info!(
                        "mqtt: sent {sent} samples read back from the historian as historical data"
                    );
                    let out = self.core.backfill_done(now);
                    self.apply(out);
                }
            }
            Err(e) => {
                tracing::error!(
                    "mqtt: the samples of the outage kept in the historian could not be read \
                     back ({e}); from {} ms on they are in the historian, not sent",
                    run.from
                );
                self.backfill_run = None;
                let out = self.core.backfill_done(now);
                self.apply(out);
            }
        }
    }

    /// The holder of the loop tests DCMDs start, with a primary host: they end when
    /// it goes offline.
    fn primary_holder(&self) -> Option<String> {
        self.core
            .settings()
            .primary_host
            .as_ref()
            .map(|h| format!("sparkplug primary host {h}"))
    }

    /// Hands a DCMD's writes to the one task that carries them out, in the order the
    /// DCMDs came ([`dcmd_writer`]).
    fn write(&mut self, w: WriteRequest) {
        let holder = self.primary_holder();
        let w = QueuedWrite { request: w, holder };
        if self.writes.send(w).is_err() {
            tracing::error!("mqtt: the DCMD writer has stopped; the DCMD is not carried out");
        }
    }
}

/// A DCMD's writes waiting for the writer task, with the holder of a loop test they
/// start.
struct QueuedWrite {
    request: WriteRequest,
    holder: Option<String>,
}

/// Carries out DCMD writes one after another, in the order they came: two DCMDs to
/// one device never interleave (a range written in two DCMDs ends as the last one
/// says). A device that does not answer delays the DCMDs queued behind it by its
/// loop's retries at most.
async fn dcmd_writer(
    engine: Engine,
    peer: String,
    mut queue: tokio::sync::mpsc::UnboundedReceiver<QueuedWrite>,
) {
    while let Some(QueuedWrite { request: w, holder }) = queue.recv().await {
        let origin = hart_access::WriteRecord {
            front_end: "mqtt",
            peer: peer.clone(),
            via: w.via.clone(),
            ..Default::default()
        };
        let lease = hart_poller::LeaseTerms {
            limit: None,
            holder,
            by: format!("mqtt DCMD from {}", origin.peer),
        };
        for op in &w.ops {
            match engine
                .apply_with(w.position, op, &origin, lease.clone())
                .await
            {
                Ok(_) => tracing::info!("mqtt: DCMD for {}: {} done", w.device, op.describe()),
                Err(e) => {
                    tracing::warn!(
                        "mqtt: DCMD for {}: {} not done: {e}",
                        w.device,
                        op.describe()
                    );
                    break;
                }
            }
        }
    }
}

impl Publisher {
    async fn shutdown(&mut self) {
        if !self.session.is_connected() {
            return;
        }
        self.outbox.clear();
        // The NDEATH of this session: the bdSeq it was born with.
        let m = self.core.death(SystemTime::now());
        let _ = self
            .client
            .try_publish(m.topic, QoS::AtLeastOnce, false, m.payload);
        let _ = self.client.try_disconnect();
        let _ = tokio::time::timeout(Duration::from_secs(3), async {
            loop {
                match self.driver.recv().await {
                    Some(Ok(Event::Outgoing(Outgoing::Disconnect)) | Err(_)) | None => break,
                    Some(Ok(_)) => {}
                }
            }
        })
        .await;
        tracing::info!("mqtt: NDEATH sent, disconnected from {}", self.url);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A CA file that is missing, empty, not PEM or cut short is refused with its path and
    /// what is wrong, before any connection.
    #[test]
    fn a_bad_ca_file_is_refused_with_its_path() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("absent.pem");
        assert!(matches!(tls_config(Some(&missing)), Err(Error::File(p, _)) if p == missing));
        for (name, text) in [
            ("empty.pem", &b""[..]),
            ("garbage.pem", b"not a certificate\n"),
            (
                "cut.pem",
                b"-----BEGIN CERTIFICATE-----\nMIIBszCCAVmgAwIBAgIUQ\n",
            ),
        ] {
            let f = dir.path().join(name);
            std::fs::write(&f, text).unwrap();
            match tls_config(Some(&f)) {
                Err(Error::File(p, why)) => {
                    assert_eq!(p, f);
                    assert!(
                        why.contains("no certificate") || why.contains("not a PEM"),
                        "{name}: {why}"
                    );
                }
                Err(e) => panic!("{name}: {e}"),
                Ok(_) => panic!("{name}: taken"),
            }
        }
    }
}
