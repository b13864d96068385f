//! The feed: the engine's changes and a periodic sample of every device, into the
//! writer.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::SystemTime;

use hart_poller::{DeviceImage, Engine, Quality};

use crate::{samples_of, Error, HistoryConfig, Sample, Stats, Var, Writer, WriterConfig};

/// Changes the feed holds not yet handed to the writer at most (the engine drops and
/// counts the oldest beyond it).
pub const CHANGES_CAPACITY: usize = 65_536;

/// Decides which samples of a device image to store: on a change only the values
/// that differ from the last stored of that device and variable (value, units or
/// quality), at each sample period all of them. Plain code, no I/O.
#[derive(Debug, Default)]
pub struct Recorder {
    last: HashMap<(String, Var), (u64, Option<u8>, u8)>,
}

impl Recorder {
    /// A recorder that has stored nothing yet.
    pub fn new() -> Self {
        Recorder::default()
    }

    fn remember(&mut self, s: &Sample) -> bool {
        let now = (s.value.to_bits(), s.units, s.quality);
        let key = (s.device.unique_id.clone(), s.var);
        self.last.insert(key, now) != Some(now)
    }

    /// The samples of a change: the values that changed since they were last stored.
    pub fn changed(
        &mut self,
        device: &DeviceImage,
        quality: Quality,
        at: SystemTime,
    ) -> Vec<Sample> {
        let mut v = samples_of(device, quality, at);
        v.retain(|s| self.remember(s));
        v
    }

    /// Every value of the device (the periodic sample).
    pub fn all(&mut self, device: &DeviceImage, quality: Quality, at: SystemTime) -> Vec<Sample> {
        let v = samples_of(device, quality, at);
        for s in &v {
            self.remember(s);
        }
        v
    }
}

/// The running historian: its writer's counters, and a way to stop it.
pub struct Handle {
    writer: Arc<Writer>,
    task: tokio::task::JoinHandle<()>,
}

impl Handle {
    /// The writer's counters.
    pub fn stats(&self) -> Stats {
        self.writer.stats()
    }

    /// Writes everything received so far now (blocks the calling thread until done).
    pub fn flush(&self) -> Result<(), Error> {
        self.writer.flush()
    }

    /// Stops taking samples, writes what is held, and stops the writer.
    pub async fn stop(self) -> Stats {
        self.task.abort();
        let _ = self.task.await;
        let writer = self.writer;
        tokio::task::spawn_blocking(move || match Arc::try_unwrap(writer) {
            Ok(w) => w.close(),
            Err(w) => {
                let _ = w.flush();
                w.stats()
            }
        })
        .await
        .unwrap_or_default()
    }
}

/// Starts the historian for `engine`: opens the database (failing if that fails:
/// the caller logs it and serves on without history), then stores every change of
/// the image (only the values that changed) and every device's values each
/// `sample_period`, through a writer thread committing every `batch`.
pub async fn run(engine: Engine, config: HistoryConfig) -> Result<Handle, Error> {
    config.validate()?;
    let wc = WriterConfig::from(&config);
    let db = config.db.clone();
    let writer = tokio::task::spawn_blocking(move || Writer::start(&db, wc))
        .await
        .map_err(|e| Error::Io(format!("history: the writer could not start: {e}")))??;
    tracing::info!(
        "history: storing every change and a sample every {} in {} (batches every {})",
        humantime::format_duration(config.sample_period),
        crate::store::StoreKind::of(&config.db).name_of(&config.db),
        humantime::format_duration(config.batch)
    );
    let writer = Arc::new(writer);
    let w = writer.clone();
    let mut changes = engine.image().changes(CHANGES_CAPACITY);
    let period = config.sample_period;
    let task = tokio::spawn(async move {
        let clock = *engine.clock();
        let mut rec = Recorder::new();
        let mut next = tokio::time::Instant::now() + period;
        loop {
            tokio::select! {
                c = changes.recv() => match c {
                    Some(c) => {
                        w.submit(rec.changed(&c.device, c.quality, c.at));
                    }
                    None => break,
                },
                _ = tokio::time::sleep_until(next) => {
                    next += period;
                    let now = clock.now();
                    let wall = clock.wall();
                    for d in engine.image().snapshot() {
                        w.submit(rec.all(&d, d.quality(now), wall));
                    }
                }
            }
        }
    });
    Ok(Handle { writer, task })
}
