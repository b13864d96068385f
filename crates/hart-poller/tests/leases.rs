//! Loop tests as leases, against a simulated plant in memory: a fixed current is
//! released at its limit, when its holder goes and when the engine stops; a refused
//! request leaves the running test alone; a release the device does not confirm is
//! retried and shown until it is.

use std::time::Duration;

use hart_poller::{Engine, Faults, LeaseTerms, TrafficKind, WriteFailure, WriteOp, WriteRecord};

mod common;
use common::{local, transmitter, until, Setup};

/// The transmitter, its loop tests limited to `limit` (the engine's default without).
async fn single_device(limit: Option<Duration>) -> (Engine, usize, Faults) {
    let (engine, faults) = transmitter(Setup {
        loop_test_limit: limit,
        ..Setup::default()
    })
    .await;
    (engine, 0, faults)
}

fn who() -> WriteRecord {
    WriteRecord {
        front_end: "test",
        peer: "-".into(),
        ..Default::default()
    }
}

fn fixed(engine: &Engine, p: usize) -> Option<f32> {
    engine.image().with(p, |d| d.fixed_current).flatten()
}

/// Command 40 requests with their current, as the traffic shows them.
fn releases_seen(
    rx: &mut tokio::sync::broadcast::Receiver<std::sync::Arc<hart_poller::TrafficFrame>>,
) -> usize {
    let mut n = 0;
    while let Ok(f) = rx.try_recv() {
        if f.kind != TrafficKind::Request {
            continue;
        }
        if let Ok(frame) = hart_proto::frame::Frame::parse_pdu(&f.pdu) {
            if frame.command == 40 && frame.data == 0f32.to_be_bytes() {
                n += 1;
            }
        }
    }
    n
}

#[test]
fn a_loop_test_ends_at_its_limit() {
    local(async {
        let (engine, p, _) = single_device(None).await;
        let terms = LeaseTerms {
            limit: Some(Duration::from_millis(300)),
            by: "test".into(),
            ..Default::default()
        };
        engine
            .apply_with(p, &WriteOp::FixedCurrent(5.0), &who(), terms)
            .await
            .unwrap();
        assert_eq!(fixed(&engine, p), Some(5.0));
        let t = engine
            .image()
            .with(p, |d| d.loop_test.clone())
            .unwrap()
            .unwrap();
        assert_eq!(
            (t.current, t.failed_releases, t.by.as_str()),
            (5.0, 0, "test")
        );
        assert!(until(&engine, Duration::from_secs(3), |e| fixed(e, p).is_none()).await);
        assert_eq!(
            engine.image().with(p, |d| d.loop_test.clone()).unwrap(),
            None
        );
    });
}

#[test]
fn the_engines_limit_caps_every_front_end() {
    local(async {
        let (engine, p, _) = single_device(Some(Duration::from_secs(1))).await;
        let terms = LeaseTerms {
            limit: Some(Duration::from_secs(3600)),
            ..Default::default()
        };
        engine
            .apply_with(p, &WriteOp::FixedCurrent(6.0), &who(), terms)
            .await
            .unwrap();
        let t = engine
            .image()
            .with(p, |d| d.loop_test.clone())
            .unwrap()
            .unwrap();
        let left = t
            .release_at
            .duration_since(engine.clock().wall())
            .unwrap_or_default();
        assert!(left <= Duration::from_secs(1), "{left:?}");
        assert!(until(&engine, Duration::from_secs(4), |e| fixed(e, p).is_none()).await);
    });
}

#[test]
fn a_refused_request_leaves_the_running_test_alone() {
    local(async {
        let (engine, p, _) = single_device(None).await;
        let terms = LeaseTerms {
            limit: Some(Duration::from_millis(600)),
            ..Default::default()
        };
        engine
            .apply_with(p, &WriteOp::FixedCurrent(5.0), &who(), terms.clone())
            .await
            .unwrap();
        // 22.5 mA is past what the device can drive: refused (response code 3).
        let refused = engine
            .apply_with(p, &WriteOp::FixedCurrent(22.5), &who(), terms)
            .await;
        assert!(
            matches!(refused, Err(WriteFailure::Refused { .. })),
            "{refused:?}"
        );
        assert_eq!(fixed(&engine, p), Some(5.0));
        assert!(engine.image().with(p, |d| d.loop_test.is_some()).unwrap());
        // The first test's release still comes.
        assert!(until(&engine, Duration::from_secs(3), |e| fixed(e, p).is_none()).await);
    });
}

#[test]
fn a_holder_that_goes_ends_its_loop_tests_only() {
    local(async {
        let (engine, p, _) = single_device(None).await;
        let terms = LeaseTerms {
            holder: Some("profibus:3".into()),
            ..Default::default()
        };
        engine
            .apply_with(p, &WriteOp::FixedCurrent(7.0), &who(), terms)
            .await
            .unwrap();
        engine.release_held_by("profibus:4");
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert_eq!(fixed(&engine, p), Some(7.0));
        engine.release_held_by("profibus:3");
        assert!(until(&engine, Duration::from_secs(3), |e| fixed(e, p).is_none()).await);
    });
}

#[test]
fn stopping_the_engine_releases_every_loop_test_and_ends_the_change_streams() {
    local(async {
        let (engine, p, _) = single_device(None).await;
        let mut changes = engine.image().changes(1 << 16);
        let mut traffic = engine.traffic();
        engine
            .apply(p, &WriteOp::FixedCurrent(8.0), &who())
            .await
            .unwrap();
        engine.stop().await;
        assert_eq!(releases_seen(&mut traffic), 1);
        assert_eq!(fixed(&engine, p), None);
        // The stream gives every change, the release's last, then ends.
        let mut last = None;
        while let Some(c) = changes.recv().await {
            last = Some(c);
        }
        let last = last.unwrap();
        assert_eq!(last.device.fixed_current, None);
        assert_eq!(last.device.loop_test, None);
    });
}

#[test]
fn a_release_the_device_does_not_confirm_is_retried_and_shown() {
    local(async {
        let (engine, p, faults) = single_device(None).await;
        let terms = LeaseTerms {
            limit: Some(Duration::from_millis(100)),
            ..Default::default()
        };
        engine
            .apply_with(p, &WriteOp::FixedCurrent(9.0), &who(), terms)
            .await
            .unwrap();
        let mut traffic = engine.traffic();
        // The device stops answering before its test ends.
        faults.set_connected(0, false);
        let failing = |e: &Engine| {
            e.image()
                .with(p, |d| d.loop_test.as_ref().map_or(0, |t| t.failed_releases))
                .unwrap_or(0)
        };
        assert!(until(&engine, Duration::from_secs(5), |e| failing(e) >= 2).await);
        assert!(fixed(&engine, p).is_some(), "still shown fixed");
        assert!(releases_seen(&mut traffic) >= 2);
        // Back: the next try ends it.
        faults.set_connected(0, true);
        assert!(until(&engine, Duration::from_secs(10), |e| fixed(e, p).is_none()).await);
        assert_eq!(
            engine.image().with(p, |d| d.loop_test.clone()).unwrap(),
            None
        );
    });
}

#[test]
fn a_fixed_current_passed_through_raw_is_held_too() {
    local(async {
        let (engine, p, _) = single_device(Some(Duration::from_secs(1))).await;
        let id = engine.image().with(p, |d| d.unique_id()).unwrap().unwrap();
        let pdu = hart_poller::line::pdu(&hart_proto::frame::FrameSpec::request(
            hart_proto::frame::Address::long(id)
                .with_master(hart_proto::frame::MasterKind::Primary),
            40,
            &4.5f32.to_be_bytes(),
        ));
        let client = hart_poller::Requester {
            rights: hart_poller::Rights::ReadWrite,
            record: who(),
            unwrapped: 0,
        };
        let out = engine.forward(0, pdu, 3, &client).await;
        assert!(
            matches!(out, Ok(hart_poller::LoopOutcome::Reply(_))),
            "{out:?}"
        );
        assert_eq!(fixed(&engine, p), Some(4.5));
        assert!(until(&engine, Duration::from_secs(4), |e| fixed(e, p).is_none()).await);
    });
}
