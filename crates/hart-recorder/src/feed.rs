//! The feed: the engine's changes and a periodic sample of every device, into the
//! writer.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::SystemTime;

use hart_poller::{DeviceImage, Engine, Quality};

use hart_history::{Error, HistoryConfig, Sample, Stats, StoreKind, Var, Writer, WriterConfig};

use crate::samples::samples_of;

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
    image: Arc<hart_poller::Image>,
}

/// The longest [`Handle::stop`] waits for the feed to hand the writer the changes the
/// engine committed before it stopped.
pub const DRAIN_LIMIT: std::time::Duration = std::time::Duration::from_secs(30);

impl Handle {
    /// The writer's counters.
    pub fn stats(&self) -> Stats {
        self.writer.stats()
    }

    /// Writes everything received so far now (blocks the calling thread until done).
    pub fn flush(&self) -> Result<(), Error> {
        self.writer.flush()
    }

    /// Stops taking samples, writes what is held, and stops the writer. After the
    /// engine's stop ([`Engine::stop`]) every change it committed is written first
    /// (the change stream ends after its last one; [`DRAIN_LIMIT`] at most); before
    /// it, the feed stops where it is.
    pub async fn stop(mut self) -> Stats {
        if self.image.is_closed() {
            if tokio::time::timeout(DRAIN_LIMIT, &mut self.task)
                .await
                .is_err()
            {
                tracing::error!(
                    "history: the last changes were not all handed to the writer within {} s; \
                     the newest may be missing",
                    DRAIN_LIMIT.as_secs()
                );
                self.task.abort();
            }
        } else {
            self.task.abort();
            let _ = (&mut self.task).await;
        }
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
    if config.max_size.is_some() && StoreKind::of(&config.db) == StoreKind::Postgres {
        tracing::warn!(
            "history: [history] max_size applies to SQLite only; PostgreSQL keeps what retention keeps"
        );
    }
    let wc = WriterConfig::from(&config);
    let db = config.db.clone();
    let writer = tokio::task::spawn_blocking(move || Writer::start(&db, wc))
        .await
        .map_err(|e| Error::Io(format!("history: the writer could not start: {e}")))??;
    tracing::info!(
        "history: storing every change and a sample every {} in {} (batches every {})",
        humantime::format_duration(config.sample_period),
        StoreKind::of(&config.db).name_of(&config.db),
        humantime::format_duration(config.batch)
    );
    let writer = Arc::new(writer);
    let w = writer.clone();
    let mut changes = engine.image().changes(CHANGES_CAPACITY);
    let image = engine.image().clone();
    let period = config.sample_period;
    let task = tokio::spawn(async move {
        let clock = *engine.clock();
        let mut rec = Recorder::new();
        let mut next = tokio::time::Instant::now() + period;
        loop {
            tokio::select! {
                c = changes.recv() => match c {
                    Some(c) => {
                        w.submit(rec.changed(&c.device, c.quality, c.value_time()));
                    }
                    None => break,
                },
                _ = tokio::time::sleep_until(next) => {
                    next += period;
                    let now = clock.now();
                    let wall = clock.wall();
                    for d in engine.image().snapshot() {
                        let q = d.quality(now);
                        w.submit(rec.all(&d, q, d.value_time(q, wall)));
                    }
                }
            }
        }
    });
    Ok(Handle {
        writer,
        task,
        image,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use hart_poller::Variable;
    use hart_proto::command::Identity;
    use hart_proto::wire::{Reader, Wire};
    use std::time::{Duration, UNIX_EPOCH};

    fn device() -> DeviceImage {
        let id = Identity::decode(&mut Reader::new(&[
            254, 0x26, 0xF1, 5, 5, 1, 1, 0, 0, 0x00, 0x00, 0x01,
        ]))
        .unwrap();
        let mut d = DeviceImage::new(0, 0, "loop1", Duration::from_secs(10));
        let mut info = hart_host::DeviceInfo::identified(id, Some(1));
        info.tag = Some("PT-101  ".into());
        d.info = Some(info);
        d.variables[0] = Some(Variable {
            value: 50.0,
            units: 12,
            status: None,
        });
        d.loop_current = Some(12.0);
        d.updated = Some(UNIX_EPOCH);
        d
    }

    #[test]
    fn samples_of_an_identified_device() {
        let s = samples_of(&device(), Quality::Good, UNIX_EPOCH);
        let vars: Vec<_> = s.iter().map(|s| s.var).collect();
        assert_eq!(vars, [Var::Pv, Var::LoopCurrent, Var::DeviceStatus]);
        assert_eq!(s[0].device.tag, "PT-101");
        assert_eq!(s[0].device.unique_id.len(), 10);
        assert_eq!((s[0].value, s[0].units), (50.0, Some(12)));
        assert_eq!(s[1].units, Some(39));
        assert_eq!(s[2].units, None);
    }

    #[test]
    fn a_change_stores_only_what_changed_a_period_everything() {
        let mut r = Recorder::new();
        let mut d = device();
        assert_eq!(r.changed(&d, Quality::Good, UNIX_EPOCH).len(), 3);
        assert!(
            r.changed(&d, Quality::Good, UNIX_EPOCH).is_empty(),
            "nothing new"
        );
        d.variables[0].as_mut().unwrap().value = 51.0;
        let s = r.changed(&d, Quality::Good, UNIX_EPOCH);
        assert_eq!(s.iter().map(|s| s.var).collect::<Vec<_>>(), [Var::Pv]);
        // A quality change is a change of every value.
        assert_eq!(r.changed(&d, Quality::Stale, UNIX_EPOCH).len(), 3);
        assert_eq!(r.all(&d, Quality::Stale, UNIX_EPOCH).len(), 3);
        assert!(r.changed(&d, Quality::Stale, UNIX_EPOCH).is_empty());
        // NaN equals NaN here: a device reporting no value is not a change each poll.
        d.variables[0].as_mut().unwrap().value = f32::NAN;
        assert_eq!(r.changed(&d, Quality::Stale, UNIX_EPOCH).len(), 1);
        assert!(r.changed(&d, Quality::Stale, UNIX_EPOCH).is_empty());
    }
}
