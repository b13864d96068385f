//! What the engine's tests against a single simulated transmitter share.

#![allow(dead_code)]

use std::time::{Duration, Instant};

use hart_host::transport::{Plant, PlantDevice};
use hart_poller::{
    Engine, EngineConfig, Faults, Line, LoopSettings, LoopSpec, MemoryLoop, PollSettings,
    ReadCommand, StartOptions,
};

/// Runs `f` on a current-thread runtime inside a `LocalSet` (the loops' tasks).
pub fn local<F: std::future::Future>(f: F) -> F::Output {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    tokio::task::LocalSet::new().block_on(&rt, f)
}

/// Waits (at most `limit`) until `f` holds for the engine.
pub async fn until(engine: &Engine, limit: Duration, f: impl Fn(&Engine) -> bool) -> bool {
    let end = Instant::now() + limit;
    while Instant::now() < end {
        if f(engine) {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    f(engine)
}

/// How a test engine over one pressure transmitter runs.
pub struct Setup {
    /// Poll period (command 3).
    pub period: Duration,
    /// The stale limit (the engine's default without).
    pub stale_after: Option<Duration>,
    /// `--loop-test-limit`.
    pub loop_test_limit: Option<Duration>,
    /// Write policy, clock, queue.
    pub options: StartOptions,
}

impl Default for Setup {
    fn default() -> Self {
        Setup {
            period: Duration::from_millis(200),
            stale_after: None,
            loop_test_limit: None,
            options: StartOptions::default(),
        }
    }
}

/// A pressure transmitter alone at polling address 0 (its loop current live), in
/// memory, polled as `setup` says; returns once it is identified (position 0), with
/// the loop's fault hooks.
pub async fn transmitter(setup: Setup) -> (Engine, Faults) {
    let plant = Plant {
        device: vec![PlantDevice {
            profile: "pressure".into(),
            poll: 0,
            burst: None,
            ..Default::default()
        }],
    };
    let m = MemoryLoop::new(plant.devices().unwrap());
    let faults = m.faults();
    let (engine, _) = Engine::start_with(
        EngineConfig {
            poll: true,
            loop_test_limit: setup.loop_test_limit,
            defaults: PollSettings {
                period: setup.period,
                stale_after: setup.stale_after,
                read: ReadCommand::Dynamic,
                ..Default::default()
            },
        },
        vec![LoopSpec {
            settings: LoopSettings::default(),
            line: Line::Memory(m),
        }],
        setup.options,
    );
    engine.ready().await;
    assert!(
        until(&engine, Duration::from_secs(5), |e| e
            .image()
            .with(0, |d| d.info.is_some())
            .unwrap_or(false))
        .await,
        "the transmitter was not found"
    );
    (engine, faults)
}
