//! One handle on the historian for everything that reads it while the gateway runs
//! (the web dashboard's trends, the MQTT publisher's backfill): connections opened once
//! and lent out, instead of one new connection (for PostgreSQL, a new server session
//! and its authentication) per trend drawn.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};

use crate::{Error, Store, StoreKind};

/// How many connections a [`Readers`] keeps open at most by default: the dashboard's
/// trends and the backfill rarely read at once.
pub const DEFAULT_READERS: usize = 4;

/// A shared, cloneable handle on one historian database for readers: at most `size`
/// connections, opened when first needed, lent to one caller at a time and kept for
/// the next, and dropped (opened again next time) after an error that says the
/// connection is gone ([`Error::needs_reconnect`]). Calls block: run them on a blocking
/// thread (`tokio::task::spawn_blocking`) in async code.
#[derive(Clone)]
pub struct Readers {
    inner: Arc<Inner>,
}

struct Inner {
    db: String,
    size: usize,
    state: Mutex<State>,
    returned: Condvar,
}

#[derive(Default)]
struct State {
    idle: Vec<Store>,
    /// Connections open now, idle or lent.
    open: usize,
}

impl std::fmt::Debug for Readers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Readers")
            .field("db", &StoreKind::of(&self.inner.db).name_of(&self.inner.db))
            .field("size", &self.inner.size)
            .finish_non_exhaustive()
    }
}

impl Readers {
    /// A handle on the database `db` (an SQLite path or a `postgres://` URL) with at
    /// most `size` connections (at least one). Opens nothing yet: a database that is
    /// not there shows in the first read's error, as it would have without the handle.
    pub fn new(db: impl Into<String>, size: usize) -> Readers {
        Readers {
            inner: Arc::new(Inner {
                db: db.into(),
                size: size.max(1),
                state: Mutex::new(State::default()),
                returned: Condvar::new(),
            }),
        }
    }

    /// The database's address, as given.
    pub fn db(&self) -> &str {
        &self.inner.db
    }

    /// Connections open now (idle or lent), for tests and diagnostics.
    pub fn open_connections(&self) -> usize {
        self.lock().open
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.inner.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Runs `read` with a connection of the pool: an idle one, a new one while fewer
    /// than `size` are open, or the next one returned. The connection goes back to the
    /// pool afterwards unless `read` failed with an error that needs a new connection.
    pub fn read<R>(&self, read: impl FnOnce(&mut Store) -> Result<R, Error>) -> Result<R, Error> {
        // The place taken in the pool is given back however this call ends: the
        // connection returned to the idle list, or (an error that needs a new one, a
        // failed open, a panic in `read`) the place freed for the next caller.
        let mut place = Place {
            inner: &self.inner,
            store: None,
        };
        {
            let mut state = self.lock();
            loop {
                if let Some(s) = state.idle.pop() {
                    place.store = Some(s);
                    break;
                }
                if state.open < self.inner.size {
                    state.open += 1;
                    drop(state);
                    place.store = Some(Store::open(&self.inner.db, false)?);
                    break;
                }
                state = self
                    .inner
                    .returned
                    .wait(state)
                    .unwrap_or_else(|e| e.into_inner());
            }
        }
        let store = place.store.as_mut().expect("set above");
        let result = read(store);
        if let Err(e) = &result {
            if e.needs_reconnect() {
                place.store = None;
            }
        }
        result
    }
}

/// One place in a [`Readers`] pool, held for the length of a read; dropping it hands
/// the connection back (when it has one) or frees the place.
struct Place<'a> {
    inner: &'a Inner,
    store: Option<Store>,
}

impl Drop for Place<'_> {
    fn drop(&mut self) {
        let mut state = self.inner.state.lock().unwrap_or_else(|e| e.into_inner());
        match self.store.take() {
            Some(s) if !std::thread::panicking() => state.idle.push(s),
            _ => state.open = state.open.saturating_sub(1),
        }
        drop(state);
        self.inner.returned.notify_one();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connections_are_opened_once_and_lent_again() {
        let dir = std::env::temp_dir().join(format!("hart-readers-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let db = dir.join("h.db");
        drop(Store::open(db.to_str().unwrap(), true).unwrap());
        let readers = Readers::new(db.to_str().unwrap(), 2);
        assert_eq!(
            readers.open_connections(),
            0,
            "nothing opened before a read"
        );
        for _ in 0..5 {
            let devices = readers.read(|s| s.devices()).unwrap();
            assert!(devices.is_empty());
        }
        assert_eq!(
            readers.open_connections(),
            1,
            "one connection served five reads"
        );
        // Readers at once never open more than the limit.
        let threads: Vec<_> = (0..6)
            .map(|_| {
                let r = readers.clone();
                std::thread::spawn(move || {
                    r.read(|s| {
                        std::thread::sleep(std::time::Duration::from_millis(20));
                        s.devices()
                    })
                    .unwrap()
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        assert!(readers.open_connections() <= 2);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_reader_that_panics_gives_its_place_back() {
        let readers = Readers::new("/nonexistent/folder/h.db", 1);
        // A place taken by hand, then a panic while it is held.
        let r = readers.clone();
        let _ = std::thread::spawn(move || {
            r.lock().open += 1;
            let _place = Place {
                inner: &r.inner,
                store: None,
            };
            panic!("a reader failed");
        })
        .join();
        assert_eq!(readers.open_connections(), 0, "the place was given back");
    }

    #[test]
    fn a_database_that_is_not_there_is_the_reads_error_and_takes_no_place() {
        let readers = Readers::new("/nonexistent/folder/h.db", 1);
        assert!(readers.read(|s| s.devices()).is_err());
        assert!(
            readers.read(|s| s.devices()).is_err(),
            "the place was given back"
        );
        assert_eq!(readers.open_connections(), 0);
    }
}
