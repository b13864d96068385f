//! What the dashboard's handlers share, and the tasks that keep it current: the
//! memory trend, the traffic log and the plant view's event stream.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use hart_poller::Engine;
use tokio::sync::broadcast;

use crate::auth::Sessions;
use crate::traffic::TrafficLog;
use crate::trend::MemoryTrend;
use crate::WebConfig;

/// How often the plant view's event stream may send (it sends at least every
/// [`EVENT_REFRESH`], so that ages move).
const EVENT_PERIOD: Duration = Duration::from_millis(500);
/// The plant view's longest quiet time.
const EVENT_REFRESH: Duration = Duration::from_secs(2);
/// Frames the traffic view keeps.
pub(crate) const TRAFFIC_KEPT: usize = 5000;
/// Live event streams served at once (each browser tab holds one).
pub(crate) const MAX_EVENT_STREAMS: usize = 256;

/// The dashboard's shared state.
pub struct AppState {
    pub(crate) engine: Engine,
    pub(crate) config: WebConfig,
    /// The administrator's password; `None`: no writes.
    pub(crate) password: Option<String>,
    /// Served over HTTPS (cookies are marked Secure).
    pub(crate) secure: bool,
    pub(crate) sessions: Mutex<Sessions>,
    pub(crate) trend: Mutex<MemoryTrend>,
    pub(crate) traffic: Mutex<TrafficLog>,
    /// The plant view's snapshots, as the JSON text each event stream sends.
    pub(crate) events: broadcast::Sender<Arc<str>>,
    /// Event streams open now.
    pub(crate) streams: std::sync::atomic::AtomicUsize,
    tasks: Mutex<Vec<tokio::task::JoinHandle<()>>>,
}

/// Locks `m`, whatever a panicking holder left (the state stays usable).
pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl AppState {
    /// The state, and its tasks started on the current runtime.
    pub(crate) fn start(
        engine: Engine,
        config: WebConfig,
        password: Option<String>,
        secure: bool,
    ) -> Arc<AppState> {
        let state = Arc::new(AppState {
            trend: Mutex::new(MemoryTrend::new(config.memory_window)),
            traffic: Mutex::new(TrafficLog::new(TRAFFIC_KEPT)),
            sessions: Mutex::new(Sessions::default()),
            events: broadcast::channel(4).0,
            streams: Default::default(),
            tasks: Mutex::new(vec![]),
            engine,
            config,
            password,
            secure,
        });
        let tasks = vec![
            tokio::spawn(record_trend(state.clone())),
            tokio::spawn(record_traffic(state.clone())),
            tokio::spawn(publish_plant(state.clone())),
        ];
        *lock(&state.tasks) = tasks;
        state
    }

    /// Stops the tasks. Loop tests are the engine's: released at their limit or when
    /// the engine stops, not here.
    pub(crate) fn stop(&self) {
        for t in lock(&self.tasks).drain(..) {
            t.abort();
        }
    }

    /// Whether anyone may write here: a password or a PSK identity to log in with, and
    /// the gateway not read only.
    pub(crate) fn writes(&self) -> bool {
        (self.password.is_some() || !self.config.psk_logins.is_empty()) && !self.read_only()
    }

    /// Whether the whole gateway is read-only (the engine's write policy).
    pub(crate) fn read_only(&self) -> bool {
        !self.engine.write_policy().writes_possible()
    }

    /// The plant as the event stream and `/api/devices` give it.
    pub(crate) fn plant_json(&self) -> serde_json::Value {
        crate::device::plant(&self.engine)
    }
}

/// Keeps every device's PV and loop current in memory for the trends.
async fn record_trend(state: Arc<AppState>) {
    let mut changes = state.engine.image().changes(4096);
    while let Some(c) = changes.recv().await {
        lock(&state.trend).record(&c);
    }
}

/// Keeps the last frames of every loop for the traffic view.
async fn record_traffic(state: Arc<AppState>) {
    let mut rx = state.engine.traffic();
    loop {
        match rx.recv().await {
            Ok(f) => lock(&state.traffic).push(f),
            Err(broadcast::error::RecvError::Lagged(n)) => lock(&state.traffic).lost(n),
            Err(broadcast::error::RecvError::Closed) => return,
        }
    }
}

/// Sends the plant to the open event streams: soon after a change, and every
/// [`EVENT_REFRESH`] anyway. One snapshot is made for all the streams.
async fn publish_plant(state: Arc<AppState>) {
    let mut changed = state.engine.image().subscribe();
    let mut tick = tokio::time::interval(EVENT_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut last = tokio::time::Instant::now();
    loop {
        tick.tick().await;
        let mut any = false;
        while let Ok(_) | Err(broadcast::error::TryRecvError::Lagged(_)) = changed.try_recv() {
            any = true;
        }
        if state.events.receiver_count() == 0 {
            continue;
        }
        if any || last.elapsed() >= EVENT_REFRESH {
            last = tokio::time::Instant::now();
            let text: Arc<str> = state.plant_json().to_string().into();
            let _ = state.events.send(text);
        }
    }
}
