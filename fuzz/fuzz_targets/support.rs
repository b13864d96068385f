//! What the server fuzz targets share: a server started once on a thread of its own,
//! and the demo plant's polling engine.
#![allow(dead_code)]

use std::future::Future;

/// Runs `start` on a thread with a current-thread runtime and a `LocalSet` (as
/// `hartkit serve` runs its servers) and returns what it sends once it is listening.
/// A panic anywhere, the server's thread included, ends the fuzzing run as a crash.
pub fn in_background<T, F, Fut>(start: F) -> T
where
    T: Send + 'static,
    F: FnOnce(std::sync::mpsc::Sender<T>) -> Fut + Send + 'static,
    Fut: Future<Output = ()> + 'static,
{
    std::panic::set_hook(Box::new(|info| {
        eprintln!("{info}");
        std::process::abort();
    }));
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        tokio::task::LocalSet::new().block_on(&rt, start(tx));
    });
    rx.recv().unwrap()
}

/// The polling engine over the demo plant answered in memory, ready. Call it on the
/// `LocalSet` of [`in_background`].
pub async fn demo_engine() -> hart_poller::Engine {
    let devices = hart_host::transport::Plant::demo().devices().unwrap();
    let (engine, _) = hart_poller::Engine::start(
        hart_poller::EngineConfig {
            poll: true,
            ..Default::default()
        },
        vec![hart_poller::LoopSpec {
            settings: Default::default(),
            line: hart_poller::Line::Memory(hart_poller::MemoryLoop::new(devices)),
        }],
    );
    engine.ready().await;
    engine
}
