//! Staleness comes with time alone: the loop's task commits it as a change, so a
//! subscriber of the change stream sees a device go stale (and good again at its next
//! reply) without reading the image on a timer.

use std::time::{Duration, Instant};

use hart_host::transport::{Plant, PlantDevice};
use hart_poller::{
    Engine, EngineConfig, Line, LoopSettings, LoopSpec, MemoryLoop, PollSettings, Quality,
    ReadCommand,
};

#[test]
fn going_stale_is_committed_as_a_change() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    tokio::task::LocalSet::new().block_on(&rt, async {
        let plant = Plant {
            device: vec![PlantDevice {
                profile: "pressure".into(),
                poll: 0,
                burst: None,
                ..Default::default()
            }],
        };
        let m = MemoryLoop::new(plant.devices().unwrap());
        // Polled every 2 s, stale after 600 ms: stale between polls.
        let (engine, _) = Engine::start(
            EngineConfig {
                poll: true,
                loop_test_limit: None,
                defaults: PollSettings {
                    period: Duration::from_secs(2),
                    stale_after: Some(Duration::from_millis(600)),
                    read: ReadCommand::Dynamic,
                    ..Default::default()
                },
            },
            vec![LoopSpec {
                settings: LoopSettings::default(),
                line: Line::Memory(m),
            }],
        );
        let mut changes = engine.image().changes(1024);
        engine.ready().await;
        let mut seen = vec![];
        let end = Instant::now() + Duration::from_secs(6);
        while Instant::now() < end {
            match tokio::time::timeout(Duration::from_millis(100), changes.recv()).await {
                Ok(Some(c)) => {
                    if seen.last() != Some(&c.quality) {
                        seen.push(c.quality);
                    }
                }
                Ok(None) => break,
                Err(_) => {}
            }
        }
        // Good, stale (committed between polls), good again at the next reply.
        let stale = seen.iter().position(|q| *q == Quality::Stale);
        assert!(stale.is_some(), "{seen:?}");
        assert!(
            seen[stale.unwrap()..].contains(&Quality::Good),
            "good again after the next poll: {seen:?}"
        );
        assert!(seen[..stale.unwrap()].contains(&Quality::Good), "{seen:?}");
    });
}
