//! The writer: a thread that batches samples into transactions and rides out the
//! database's faults with a bounded backlog in memory.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use crate::{Error, HistoryConfig, Sample, Store};

/// Messages queued to the writer at most (each a device's samples of one change).
pub const CHANNEL: usize = 65_536;
/// How often retention runs.
pub const RETENTION_EVERY: Duration = Duration::from_secs(60);
/// How long one retention step may hold the writer.
pub const RETENTION_BUDGET: Duration = Duration::from_millis(100);
/// The longest wait between two tries after a failure.
pub const MAX_BACKOFF: Duration = Duration::from_secs(30);

/// The writer's settings.
#[derive(Debug, Clone, PartialEq)]
pub struct WriterConfig {
    /// Commit a batch at least this often.
    pub batch: Duration,
    /// Commit early when the batch holds this many samples.
    pub max_batch: usize,
    /// Samples kept while the database cannot be written.
    pub backlog: usize,
    /// Delete samples older than this.
    pub retention: Option<Duration>,
    /// SQLite: delete the oldest days beyond this many bytes.
    pub max_size: Option<u64>,
    /// SQLite: what to do when the file is removed or replaced under the writer.
    pub on_file_lost: crate::FileLost,
}

impl From<&HistoryConfig> for WriterConfig {
    fn from(c: &HistoryConfig) -> Self {
        WriterConfig {
            batch: c.batch,
            max_batch: c.max_batch,
            backlog: c.backlog,
            retention: c.retention,
            max_size: c.max_size,
            on_file_lost: c.on_file_lost,
        }
    }
}

impl Default for WriterConfig {
    fn default() -> Self {
        WriterConfig::from(&HistoryConfig::with_db(""))
    }
}

/// The writer's counters.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Stats {
    /// Samples committed.
    pub written: u64,
    /// Transactions committed.
    pub batches: u64,
    /// Samples dropped: the queue to the writer was full, or the backlog was.
    pub dropped: u64,
    /// Samples waiting in memory to be written.
    pub backlog: u64,
    /// Failed tries to write.
    pub failures: u64,
    /// The last database error, cleared when a write succeeds again.
    pub last_error: Option<String>,
}

#[derive(Default)]
struct Shared {
    written: AtomicU64,
    batches: AtomicU64,
    dropped: AtomicU64,
    backlog: AtomicU64,
    failures: AtomicU64,
    last_error: Mutex<Option<String>>,
}

enum Msg {
    Samples(Vec<Sample>),
    Flush(mpsc::Sender<Result<(), Error>>),
}

/// A writer thread. Dropping it (or [`Writer::close`]) writes what it holds and stops.
pub struct Writer {
    tx: Option<SyncSender<Msg>>,
    shared: Arc<Shared>,
    thread: Option<std::thread::JoinHandle<()>>,
    full_logged: std::sync::atomic::AtomicBool,
}

impl Writer {
    /// Opens `db` (creating an SQLite file) on a new thread and starts writing there.
    /// Fails when the first opening fails (a bad URL, a corrupt file, a server that
    /// cannot be reached): the caller logs it and goes on without history.
    pub fn start(db: &str, config: WriterConfig) -> Result<Writer, Error> {
        let db = db.to_string();
        let (ready_tx, ready_rx) = mpsc::channel();
        let (tx, rx) = mpsc::sync_channel(CHANNEL);
        let shared = Arc::new(Shared::default());
        let sh = shared.clone();
        let thread = std::thread::Builder::new()
            .name("hart-history".into())
            .spawn(move || match Store::open(&db, true) {
                Ok(store) => {
                    let _ = ready_tx.send(Ok(()));
                    Task::new(store, config, sh).run(rx);
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(|e| Error::Io(format!("history: cannot start the writer thread: {e}")))?;
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Writer {
                tx: Some(tx),
                shared,
                thread: Some(thread),
                full_logged: false.into(),
            }),
            Ok(Err(e)) => {
                let _ = thread.join();
                Err(e)
            }
            Err(_) => Err(Error::Io(
                "history: the writer thread stopped while opening the database".into(),
            )),
        }
    }

    /// Starts writing to an open store.
    pub fn with_store(store: Store, config: WriterConfig) -> Writer {
        let (tx, rx) = mpsc::sync_channel(CHANNEL);
        let shared = Arc::new(Shared::default());
        let sh = shared.clone();
        let thread = std::thread::Builder::new()
            .name("hart-history".into())
            .spawn(move || Task::new(store, config, sh).run(rx))
            .ok();
        Writer {
            tx: Some(tx),
            shared,
            thread,
            full_logged: false.into(),
        }
    }

    /// Hands samples to the writer without waiting. When its queue is full they are
    /// dropped and counted (`false`); a warning is logged once until it has room
    /// again.
    pub fn submit(&self, samples: Vec<Sample>) -> bool {
        if samples.is_empty() {
            return true;
        }
        let n = samples.len() as u64;
        let Some(tx) = &self.tx else { return false };
        match tx.try_send(Msg::Samples(samples)) {
            Ok(()) => {
                self.full_logged.store(false, Ordering::Relaxed);
                true
            }
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.shared.dropped.fetch_add(n, Ordering::Relaxed);
                if !self.full_logged.swap(true, Ordering::Relaxed) {
                    tracing::warn!(
                        "history: the writer's queue is full ({CHANNEL} changes): dropping samples; the database is too slow for this load, check its disk"
                    );
                }
                false
            }
        }
    }

    /// Hands samples to the writer, waiting for room in its queue (benchmarks and
    /// bulk loads).
    pub fn submit_wait(&self, samples: Vec<Sample>) {
        if let Some(tx) = &self.tx {
            let n = samples.len() as u64;
            if tx.send(Msg::Samples(samples)).is_err() {
                self.shared.dropped.fetch_add(n, Ordering::Relaxed);
            }
        }
    }

    /// Writes everything submitted so far now, and says whether it could.
    pub fn flush(&self) -> Result<(), Error> {
        let (tx, rx) = mpsc::channel();
        self.tx
            .as_ref()
            .ok_or_else(|| Error::Io("history: the writer is closed".into()))?
            .send(Msg::Flush(tx))
            .map_err(|_| Error::Io("history: the writer thread stopped".into()))?;
        rx.recv()
            .map_err(|_| Error::Io("history: the writer thread stopped".into()))?
    }

    /// The counters.
    pub fn stats(&self) -> Stats {
        let s = &self.shared;
        Stats {
            written: s.written.load(Ordering::Relaxed),
            batches: s.batches.load(Ordering::Relaxed),
            dropped: s.dropped.load(Ordering::Relaxed),
            backlog: s.backlog.load(Ordering::Relaxed),
            failures: s.failures.load(Ordering::Relaxed),
            last_error: s
                .last_error
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone(),
        }
    }

    /// Writes what it holds (one try) and stops the thread.
    pub fn close(mut self) -> Stats {
        self.stop();
        self.stats()
    }

    fn stop(&mut self) {
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Writer {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The writer thread's state.
struct Task {
    store: Store,
    config: WriterConfig,
    shared: Arc<Shared>,
    pending: VecDeque<Sample>,
    /// When the next commit is due.
    due: Instant,
    /// After a failure: the wait before the next try (the one back-off,
    /// hart-clock's: 0.5 s doubling to [`MAX_BACKOFF`]); no failure since the last
    /// success while its count is 0.
    backoff: hart_clock::Backoff,
    /// A failure that wants a new connection first.
    reconnect: bool,
    /// The last try failed (cleared, with a log line, by the next success).
    failing: bool,
    dropping: bool,
    next_retention: Instant,
    retention_pending: bool,
    /// The file was lost and [`crate::FileLost::Stop`] asked for history to stop:
    /// why.
    stopped: Option<String>,
    /// A lost file was logged and is being opened anew (logged once per loss).
    reopening: bool,
}

impl Task {
    fn new(store: Store, config: WriterConfig, shared: Arc<Shared>) -> Task {
        let now = Instant::now();
        Task {
            store,
            due: now + config.batch,
            config,
            shared,
            pending: VecDeque::new(),
            backoff: hart_clock::Backoff::new(Duration::from_millis(500), MAX_BACKOFF),
            reconnect: false,
            failing: false,
            dropping: false,
            next_retention: now + Duration::from_secs(5),
            retention_pending: false,
            stopped: None,
            reopening: false,
        }
    }

    fn run(mut self, rx: mpsc::Receiver<Msg>) {
        loop {
            let wait = self.due.saturating_duration_since(Instant::now());
            match rx.recv_timeout(wait) {
                Ok(Msg::Samples(v)) => {
                    self.add(v);
                    // Take whatever else is queued before deciding.
                    while self.pending.len() < self.config.max_batch {
                        match rx.try_recv() {
                            Ok(Msg::Samples(v)) => self.add(v),
                            Ok(Msg::Flush(reply)) => {
                                let _ = reply.send(self.flush());
                            }
                            Err(_) => break,
                        }
                    }
                    if self.pending.len() >= self.config.max_batch && self.backoff.failures() == 0 {
                        self.due = Instant::now();
                    }
                }
                Ok(Msg::Flush(reply)) => {
                    let _ = reply.send(self.flush());
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => {
                    let _ = self.flush();
                    if !self.pending.is_empty() {
                        tracing::error!(
                            "history: stopping with {} samples not written to {} (last error: {}); they are lost",
                            self.pending.len(),
                            self.store.describe(),
                            self.shared.last_error.lock().unwrap_or_else(|e| e.into_inner()).clone().unwrap_or_default()
                        );
                    }
                    return;
                }
            }
            if Instant::now() >= self.due {
                self.commit();
                self.maybe_retention();
            }
        }
    }

    fn add(&mut self, v: Vec<Sample>) {
        if self.stopped.is_some() {
            self.shared
                .dropped
                .fetch_add(v.len() as u64, Ordering::Relaxed);
            return;
        }
        self.pending.extend(v);
        let over = self.pending.len().saturating_sub(self.config.backlog);
        if over > 0 {
            self.pending.drain(..over);
            self.shared
                .dropped
                .fetch_add(over as u64, Ordering::Relaxed);
            if !self.dropping {
                self.dropping = true;
                tracing::error!(
                    "history: the backlog is full ({} samples kept in memory while {} cannot be written): dropping the oldest; check the database (last error: {})",
                    self.config.backlog,
                    self.store.describe(),
                    self.shared.last_error.lock().unwrap_or_else(|e| e.into_inner()).clone().unwrap_or_default()
                );
            }
        }
        self.shared
            .backlog
            .store(self.pending.len() as u64, Ordering::Relaxed);
    }

    /// Writes everything pending now, whatever the backoff.
    fn flush(&mut self) -> Result<(), Error> {
        if let Some(why) = &self.stopped {
            return Err(Error::Io(why.clone()));
        }
        self.backoff.reset();
        while !self.pending.is_empty() {
            self.write_chunk()?;
        }
        Ok(())
    }

    /// Writes one chunk when due; schedules the next commit.
    fn commit(&mut self) {
        if Instant::now() < self.due {
            return;
        }
        if self.pending.is_empty() {
            self.due = Instant::now() + self.config.batch;
            return;
        }
        match self.write_chunk() {
            Ok(()) if self.pending.len() >= self.config.max_batch => {
                // More waiting (a backlog): go on at once.
                self.due = Instant::now();
            }
            Ok(()) => self.due = Instant::now() + self.config.batch,
            Err(_) => {}
        }
    }

    /// Whether the file is still the one the writer opened: when it was removed or
    /// replaced, a new one is opened at the path, or history stops, as configured.
    /// Checked before every transaction, so at most one batch goes to a lost file.
    fn check_file(&mut self) -> Result<(), Error> {
        if let Some(why) = &self.stopped {
            return Err(Error::Io(why.clone()));
        }
        if self.reopening {
            // Logged already; the reconnection below (or its retries) opens it.
            return Ok(());
        }
        let Some(lost) = self.store.file_lost() else {
            return Ok(());
        };
        let path = self.store.describe();
        // The old log's pages go into the old file, never into one now at the path.
        self.store.release();
        match self.config.on_file_lost {
            crate::FileLost::Reopen => {
                tracing::error!(
                    "history: {path} {lost} while the gateway wrote to it: a new file is \
                     opened there (what the old one held is gone with it unless someone moved \
                     it; [history] on_file_lost = \"stop\" stops history instead)"
                );
                self.reopening = true;
                self.reconnect = true;
                Ok(())
            }
            crate::FileLost::Stop => {
                let why = format!(
                    "history: {path} {lost} while the gateway wrote to it: history stopped \
                     ([history] on_file_lost = \"stop\"); restart the gateway to write again"
                );
                tracing::error!("{why}");
                let n = self.pending.len() as u64;
                self.pending.clear();
                let s = &self.shared;
                s.dropped.fetch_add(n, Ordering::Relaxed);
                s.backlog.store(0, Ordering::Relaxed);
                *s.last_error.lock().unwrap_or_else(|e| e.into_inner()) = Some(why.clone());
                self.stopped = Some(why.clone());
                Err(Error::Io(why))
            }
        }
    }

    /// One transaction of up to `max_batch` samples.
    fn write_chunk(&mut self) -> Result<(), Error> {
        self.check_file()?;
        let n = self.pending.len().min(self.config.max_batch);
        if n == 0 {
            return Ok(());
        }
        if self.reconnect {
            if let Err(e) = self.store.reconnect() {
                self.failed(e.clone(), n);
                return Err(e);
            }
            self.reconnect = false;
            if std::mem::take(&mut self.reopening) {
                tracing::info!("history: {} opened anew", self.store.describe());
            }
        }
        let chunk = &self.pending.make_contiguous()[..n];
        match self.store.insert(chunk) {
            Ok(()) => {
                self.pending.drain(..n);
                let s = &self.shared;
                s.written.fetch_add(n as u64, Ordering::Relaxed);
                s.batches.fetch_add(1, Ordering::Relaxed);
                s.backlog
                    .store(self.pending.len() as u64, Ordering::Relaxed);
                self.backoff.reset();
                if std::mem::take(&mut self.failing) || self.dropping {
                    tracing::info!(
                        "history: writing to {} again ({} samples still waiting)",
                        self.store.describe(),
                        self.pending.len()
                    );
                    *s.last_error.lock().unwrap_or_else(|e| e.into_inner()) = None;
                }
                self.dropping = false;
                Ok(())
            }
            Err(e) => {
                self.failed(e.clone(), n);
                Err(e)
            }
        }
    }

    fn failed(&mut self, e: Error, n: usize) {
        self.shared.failures.fetch_add(1, Ordering::Relaxed);
        self.failing = true;
        self.reconnect = e.needs_reconnect();
        let backoff = self.backoff.failed(Instant::now());
        let mut last = self
            .shared
            .last_error
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let msg = e.to_string();
        if last.as_deref() != Some(msg.as_str()) {
            tracing::error!(
                "history: writing {n} samples failed: {msg}; keeping {} samples in memory (at most {}) and trying again",
                self.pending.len(),
                self.config.backlog
            );
        }
        *last = Some(msg);
        self.due = Instant::now() + backoff;
    }

    fn maybe_retention(&mut self) {
        if self.config.retention.is_none() && self.config.max_size.is_none() {
            return;
        }
        // Never through a lost file (or a stopped history).
        if self.check_file().is_err() || self.reconnect {
            return;
        }
        if self.backoff.failures() > 0 {
            return;
        }
        let now = Instant::now();
        if !self.retention_pending && now < self.next_retention {
            return;
        }
        match self.store.retention(
            SystemTime::now(),
            self.config.retention,
            self.config.max_size,
            RETENTION_BUDGET,
        ) {
            Ok(o) => {
                if o.deleted > 0 {
                    tracing::info!(
                        "history: retention deleted {} old samples from {}",
                        o.deleted,
                        self.store.describe()
                    );
                }
                self.retention_pending = !o.done;
            }
            Err(e) => {
                tracing::warn!("history: retention failed: {e}; trying again later");
                self.retention_pending = false;
            }
        }
        self.next_retention = now + RETENTION_EVERY;
    }
}
