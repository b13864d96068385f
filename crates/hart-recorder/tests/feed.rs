//! The recorder on the engine: the demo plant polled in memory, its changes and
//! periodic samples stored by the historian.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use hart_history::{Agg, Query, Store, Var};

fn sqlite_path(dir: &tempfile::TempDir) -> String {
    dir.path().join("h.sqlite").display().to_string()
}

/// The feed on the demo plant (in memory, real time): every device's values are
/// stored, a steady value only once per sample period.
#[test]
fn feed_stores_the_engine_changes_and_periodic_samples() {
    use hart_host::transport::Plant;
    use hart_poller::{
        Engine, EngineConfig, Line, LoopSettings, LoopSpec, MemoryLoop, PollSettings, ReadCommand,
    };
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let stats = tokio::task::LocalSet::new().block_on(&rt, async {
        let (engine, _) = Engine::start(
            EngineConfig {
                poll: true,
                loop_test_limit: None,
                defaults: PollSettings {
                    period: Duration::from_millis(20),
                    read: ReadCommand::Dynamic,
                    ..Default::default()
                },
            },
            vec![LoopSpec {
                settings: LoopSettings::default(),
                line: Line::Memory(MemoryLoop::new(Plant::demo().devices().unwrap())),
            }],
        );
        let mut config = hart_history::HistoryConfig::with_db(db.clone());
        config.batch = Duration::from_millis(50);
        config.sample_period = Duration::from_millis(300);
        let h = hart_recorder::run(engine.clone(), config).await.unwrap();
        engine.ready().await;
        tokio::time::sleep(Duration::from_millis(1500)).await;
        h.stop().await
    });
    assert_eq!(stats.dropped, 0, "{stats:?}");
    assert!(stats.written > 0 && stats.batches > 0, "{stats:?}");
    let mut s = Store::open(&db, false).unwrap();
    let devices = s.devices().unwrap();
    assert_eq!(devices.len(), 4, "{devices:?}");
    for d in &devices {
        let rows = s
            .query(&Query {
                device: d.unique_id.clone(),
                var: Var::LoopCurrent,
                from: UNIX_EPOCH,
                to: SystemTime::now() + Duration::from_secs(60),
                every: None,
                agg: Agg::Last,
            })
            .unwrap();
        assert!(!rows.is_empty(), "{d:?}");
        assert!(rows.iter().all(|r| r.units == Some(39)), "mA");
    }
    // The device status of a healthy device does not change: stored at the first
    // change and at each of the (about 5) sample periods, not at every 20 ms poll.
    let status = s
        .query(&Query {
            device: devices[0].unique_id.clone(),
            var: Var::DeviceStatus,
            from: UNIX_EPOCH,
            to: SystemTime::now() + Duration::from_secs(60),
            every: None,
            agg: Agg::Last,
        })
        .unwrap();
    assert!(
        (2..=12).contains(&status.len()),
        "{} device status rows",
        status.len()
    );
}

/// The engine stops in the middle of a burst of changes (every device polled every
/// millisecond, in memory): the historian stores every sample of every change the
/// engine committed before its stop, none lost in the queues between them. The count
/// to expect is made by a second subscriber that follows the same changes with its
/// own recorder.
#[test]
fn every_change_committed_before_the_engines_stop_is_stored() {
    use hart_host::transport::Plant;
    use hart_poller::{
        Engine, EngineConfig, Line, LoopSettings, LoopSpec, MemoryLoop, PollSettings, ReadCommand,
    };
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let (stats, expected, changes) = tokio::task::LocalSet::new().block_on(&rt, async {
        let (engine, _) = Engine::start(
            EngineConfig {
                poll: true,
                loop_test_limit: None,
                defaults: PollSettings {
                    period: Duration::from_millis(1),
                    read: ReadCommand::Dynamic,
                    ..Default::default()
                },
            },
            vec![LoopSpec {
                settings: LoopSettings::default(),
                line: Line::Memory(MemoryLoop::new(Plant::demo().devices().unwrap())),
            }],
        );
        let mut config = hart_history::HistoryConfig::with_db(db.clone());
        config.batch = Duration::from_millis(20);
        // No periodic sample inside the test: only changes are stored.
        config.sample_period = Duration::from_secs(3600);
        let h = hart_recorder::run(engine.clone(), config).await.unwrap();
        // Subscribed with no await since the historian's own subscription (the loop's
        // task cannot run between them): both see the same changes.
        let mut witness = engine.image().changes(1 << 22);
        engine.ready().await;
        tokio::time::sleep(Duration::from_millis(800)).await;
        engine.stop().await;
        let stats = h.stop().await;
        let mut rec = hart_recorder::Recorder::new();
        let (mut expected, mut changes) = (0u64, 0u64);
        while let Some(c) = witness.recv().await {
            changes += 1;
            expected += rec.changed(&c.device, c.quality, c.value_time()).len() as u64;
        }
        assert_eq!(witness.dropped(), 0);
        (stats, expected, changes)
    });
    assert!(changes > 100, "a burst: {changes} changes");
    assert_eq!(stats.dropped, 0, "{stats:?}");
    assert_eq!(stats.written, expected, "{stats:?}, {changes} changes");
}
