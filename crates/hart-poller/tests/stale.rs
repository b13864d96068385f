//! Staleness comes with time alone: the loop's task commits it as a change, so a
//! subscriber of the change stream sees a device go stale (and good again at its next
//! reply) without reading the image on a timer.

use std::time::{Duration, Instant};

use hart_poller::Quality;

mod common;
use common::{local, transmitter, Setup};

#[test]
fn going_stale_is_committed_as_a_change() {
    local(async {
        // Polled every 2 s, stale after 600 ms: stale between polls.
        let (engine, _) = transmitter(Setup {
            period: Duration::from_secs(2),
            stale_after: Some(Duration::from_millis(600)),
            ..Setup::default()
        })
        .await;
        let mut changes = engine.image().changes(1024);
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
        // Stale committed between polls, good again at each reply, stale again: a
        // cycle per poll period.
        let stale = seen.iter().filter(|q| **q == Quality::Stale).count();
        assert!(stale >= 2, "{seen:?}");
        assert!(
            seen.windows(2)
                .any(|w| w == [Quality::Stale, Quality::Good])
                && seen
                    .windows(2)
                    .any(|w| w == [Quality::Good, Quality::Stale]),
            "{seen:?}"
        );
    });
}
