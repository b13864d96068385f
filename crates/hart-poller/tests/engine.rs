//! The polling engine against simulated plants: devices found and polled, a device
//! that dies and comes back, writes ahead of polls, configured devices and their
//! positions, burst messages into the image.

use std::time::{Duration, Instant, SystemTime};

use hart_host::transport::Plant;
use hart_poller::{
    Clock, DeviceSettings, Engine, EngineConfig, Line, LoopSettings, LoopSpec, MemoryLoop,
    PollSettings, Quality, ReadCommand, StartOptions, WriteFailure, WriteOp,
};

fn local<F: std::future::Future>(f: F) -> F::Output {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    tokio::task::LocalSet::new().block_on(&rt, f)
}

fn config(period_ms: u64, read: ReadCommand) -> EngineConfig {
    EngineConfig {
        poll: true,
        loop_test_limit: None,
        defaults: PollSettings {
            period: Duration::from_millis(period_ms),
            read,
            ..Default::default()
        },
    }
}

/// Waits (at most `limit`) until `f` holds for the engine's image.
async fn until(engine: &Engine, limit: Duration, f: impl Fn(&Engine) -> bool) -> bool {
    let end = Instant::now() + limit;
    while Instant::now() < end {
        if f(engine) {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    f(engine)
}

/// An engine polling every `period_ms` over the demo plant in memory (one loop, default
/// settings), ready; and the loop's fault hooks. Call it inside `local`.
async fn demo_engine(period_ms: u64) -> (Engine, hart_poller::Faults) {
    let m = MemoryLoop::new(Plant::demo().devices().unwrap());
    let faults = m.faults();
    let engine = start(period_ms, LoopSettings::default(), m).await;
    (engine, faults)
}

/// An engine polling every `period_ms` with command 3 over loop `m`, ready.
async fn start(period_ms: u64, settings: LoopSettings, m: MemoryLoop) -> Engine {
    // Dropping the task handles leaves the tasks running until the runtime ends.
    let (engine, _) = Engine::start(
        config(period_ms, ReadCommand::Dynamic),
        vec![LoopSpec {
            settings,
            line: Line::Memory(m),
        }],
    );
    engine.ready().await;
    engine
}

#[test]
fn finds_and_polls_every_device_of_the_demo_plant() {
    local(async {
        let (engine, _) = demo_engine(50).await;
        let ok = until(&engine, Duration::from_secs(5), |e| {
            let img = e.image().snapshot();
            img.len() == 4
                && img
                    .iter()
                    .all(|d| d.quality(Instant::now()) == Quality::Good)
        })
        .await;
        let img = engine.image().snapshot();
        assert!(ok, "{img:#?}");
        // Found in polling address order: 1, 2, 3, 17.
        let polls: Vec<_> = img.iter().map(|d| d.polling_address).collect();
        assert_eq!(polls, [Some(1), Some(2), Some(3), Some(17)]);
        for d in &img {
            assert!(
                d.variables[0].is_some() && d.loop_current.is_some(),
                "{d:?}"
            );
            assert!(d.range.is_some(), "command 15 read: {d:?}");
            assert!(d.info.as_ref().unwrap().tag.is_some());
        }
    });
}

#[test]
fn a_dead_device_is_no_reply_within_one_poll_and_good_again_when_back() {
    local(async {
        let (engine, faults) = demo_engine(20).await;
        assert!(
            until(&engine, Duration::from_secs(5), |e| {
                e.image()
                    .with(1, |d| d.quality(Instant::now()) == Quality::Good)
                    .unwrap_or(false)
            })
            .await
        );
        // Polling address 2 is position 1.
        let polls_before = engine.image().with(1, |d| d.polls).unwrap();
        faults.set_connected(2, false);
        assert!(
            until(&engine, Duration::from_secs(5), |e| {
                e.image().with(1, |d| d.polls).unwrap() > polls_before
            })
            .await
        );
        // One poll after the fault (the one that may have been under way counts too).
        assert!(
            until(&engine, Duration::from_secs(5), |e| {
                e.image().with(1, |d| d.polls).unwrap() >= polls_before + 2
            })
            .await
        );
        let q = engine
            .image()
            .with(1, |d| d.quality(Instant::now()))
            .unwrap();
        assert_eq!(q, Quality::NoReply);
        // The others go on.
        assert_eq!(
            engine
                .image()
                .with(0, |d| d.quality(Instant::now()))
                .unwrap(),
            Quality::Good
        );
        faults.set_connected(2, true);
        assert!(
            until(&engine, Duration::from_secs(10), |e| {
                e.image()
                    .with(1, |d| d.quality(Instant::now()) == Quality::Good)
                    .unwrap()
            })
            .await,
            "back to good after the device returns"
        );
    });
}

#[test]
fn configured_devices_keep_their_positions_even_when_absent() {
    local(async {
        let m = MemoryLoop::new(Plant::demo().devices().unwrap());
        let settings = LoopSettings {
            name: Some("north".into()),
            scan: false,
            device: vec![
                DeviceSettings {
                    poll: 17,
                    name: Some("PT-017".into()),
                    period: None,
                    read: Some(ReadCommand::Variables),
                },
                DeviceSettings {
                    poll: 40,
                    name: None,
                    period: None,
                    read: None,
                },
                DeviceSettings {
                    poll: 1,
                    name: None,
                    period: None,
                    read: None,
                },
            ],
            ..Default::default()
        };
        let engine = start(20, settings, m).await;
        assert!(
            until(&engine, Duration::from_secs(5), |e| {
                let img = e.image().snapshot();
                img[0].quality(Instant::now()) == Quality::Good
                    && img[2].quality(Instant::now()) == Quality::Good
            })
            .await
        );
        let img = engine.image().snapshot();
        assert_eq!(img.len(), 3, "no scan: only the listed devices");
        assert_eq!(img[0].display_name(), "PT-017");
        assert_eq!(img[0].loop_name, "north");
        assert_eq!(img[1].polling_address, Some(40));
        assert!(img[1].info.is_none());
        assert_eq!(img[1].quality(Instant::now()), Quality::NoReply);
        assert_eq!(img[2].polling_address, Some(1));
        // Command 9 for the first: PV with its device variable status, percent of range.
        assert!(
            img[0].variables[0].unwrap().status.is_some(),
            "{:?}",
            img[0]
        );
        assert!(img[0].percent_range.is_some());
        assert!(img[2].variables[0].unwrap().status.is_none());
    });
}

#[test]
fn writes_go_through_and_the_configuration_is_read_again() {
    local(async {
        // The demo plant and a pressure transmitter at polling address 0, whose loop
        // current is live (the multidrop devices hold 4 mA).
        let mut plant = Plant::demo();
        plant.device.push(hart_host::transport::PlantDevice {
            profile: "pressure".into(),
            poll: 0,
            burst: None,
            ..Default::default()
        });
        let m = MemoryLoop::new(plant.devices().unwrap());
        let engine = start(10_000, LoopSettings::default(), m).await;
        assert!(
            until(&engine, Duration::from_secs(5), |e| {
                e.image().snapshot().iter().all(|d| d.range.is_some()) && e.image().len() == 5
            })
            .await
        );
        let who = hart_poller::WriteRecord {
            front_end: "test",
            ..Default::default()
        };
        let r = engine.apply(1, &WriteOp::Damping(2.5), &who).await.unwrap();
        assert_eq!(r.response_code, 0);
        // The period is 10 s: the new damping shows because the write hurried a poll.
        assert!(
            until(&engine, Duration::from_secs(3), |e| {
                e.image()
                    .with(1, |d| d.range.map(|r| r.damping) == Some(2.5))
                    .unwrap()
            })
            .await,
            "{:?}",
            engine.image().with(1, |d| d.range)
        );
        // A multidrop device refuses fixed current: response code 11, "in multidrop
        // mode": a refusal, no loop test.
        assert!(matches!(
            engine.apply(1, &WriteOp::FixedCurrent(12.0), &who).await,
            Err(WriteFailure::Refused { code: 11, .. })
        ));
        assert_eq!(engine.image().with(1, |d| d.fixed_current).unwrap(), None);
        assert_eq!(
            engine.image().with(1, |d| d.loop_test.clone()).unwrap(),
            None
        );
        // The device at polling address 0 (found first: position 0 is it) drives its
        // loop current: fixed, shown, released.
        let p0 = engine
            .image()
            .snapshot()
            .iter()
            .find(|d| d.polling_address == Some(0))
            .map(|d| d.position)
            .unwrap();
        let r = engine
            .apply(p0, &WriteOp::FixedCurrent(12.0), &who)
            .await
            .unwrap();
        assert_eq!(r.response_code, 0);
        assert_eq!(
            engine.image().with(p0, |d| d.fixed_current).unwrap(),
            Some(12.0)
        );
        let test = engine.image().with(p0, |d| d.loop_test.clone()).unwrap();
        assert_eq!(test.map(|t| t.current), Some(12.0));
        engine
            .apply(p0, &WriteOp::FixedCurrent(0.0), &who)
            .await
            .unwrap();
        assert_eq!(engine.image().with(p0, |d| d.fixed_current).unwrap(), None);
        assert_eq!(
            engine.image().with(p0, |d| d.loop_test.clone()).unwrap(),
            None
        );
        // No such device.
        assert_eq!(
            engine.apply(99, &WriteOp::Damping(1.0), &who).await,
            Err(WriteFailure::Link(hart_poller::WriteError::UnknownDevice))
        );
    });
}

#[test]
fn burst_messages_update_the_image() {
    local(async {
        // Polls every 60 s: after the first poll, only the burst messages of the
        // temperature transmitter (command 3 every 2 s) move its values.
        let (engine, _) = demo_engine(60_000).await;
        assert!(
            until(&engine, Duration::from_secs(5), |e| {
                e.image().with(1, |d| d.polls == 1).unwrap_or(false)
            })
            .await
        );
        let first = engine.image().with(1, |d| d.updated).unwrap();
        assert!(
            until(&engine, Duration::from_secs(5), |e| {
                e.image().with(1, |d| d.updated != first).unwrap()
            })
            .await,
            "a burst message updated the image"
        );
        assert_eq!(engine.image().with(1, |d| d.polls).unwrap(), 1);
    });
}

/// Before the engine has asked a device, its quality says so ("waiting for first
/// data", code 5) instead of "no reply": a SCADA restarting with the gateway raises no
/// alarm for devices nobody has asked yet. Once polled it is good; once silent, no reply.
#[test]
fn a_device_not_asked_yet_is_waiting_for_data() {
    local(async {
        let settings = LoopSettings {
            device: vec![DeviceSettings {
                poll: 1,
                name: Some("PT-101".into()),
                period: None,
                read: None,
            }],
            ..Default::default()
        };
        let m = MemoryLoop::new(Plant::demo().devices().unwrap());
        let faults = m.faults();
        let (engine, _) = Engine::start(
            config(50, ReadCommand::Dynamic),
            vec![LoopSpec {
                settings,
                line: Line::Memory(m),
            }],
        );
        let q = engine
            .image()
            .with(0, |d| d.quality(Instant::now()))
            .unwrap();
        assert_eq!(q, Quality::WaitingForData);
        assert_eq!((q.code(), q.name()), (5, "waiting for first data"));
        assert!(
            until(&engine, Duration::from_secs(5), |e| e
                .image()
                .with(0, |d| d.quality(Instant::now()) == Quality::Good)
                .unwrap())
            .await
        );
        faults.set_connected(1, false);
        assert!(
            until(&engine, Duration::from_secs(10), |e| e
                .image()
                .with(0, |d| d.quality(Instant::now()) == Quality::NoReply)
                .unwrap())
            .await
        );
    });
}

/// The engine on tokio's clock with time paused: an hour of polling in virtual time.
fn paused<F: std::future::Future>(f: F) -> F::Output {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .unwrap();
    tokio::task::LocalSet::new().block_on(&rt, f)
}

/// An engine on the demo plant in memory, polling every `period` on the engine's
/// tokio clock (virtual when the runtime's time is paused).
fn virtual_engine(period: Duration) -> Engine {
    let m = MemoryLoop::new(Plant::demo().devices().unwrap());
    let (engine, _) = Engine::start_with(
        EngineConfig {
            poll: true,
            loop_test_limit: None,
            defaults: PollSettings {
                period,
                read: ReadCommand::Dynamic,
                ..Default::default()
            },
        },
        vec![LoopSpec {
            settings: LoopSettings::default(),
            line: Line::Memory(m),
        }],
        StartOptions {
            clock: Clock::tokio(SystemTime::UNIX_EPOCH + Duration::from_secs(1_800_000_000)),
            ..StartOptions::default()
        },
    );
    engine
}

/// One poll is one commit: every change a subscriber sees is a whole device, so the
/// first poll's change with a PV already has the range (command 15) read in the same
/// poll. (Burst messages are commits of their own: the demo's burst device may show a
/// PV before its first poll.)
#[test]
fn each_poll_is_one_commit() {
    paused(async {
        let engine = virtual_engine(Duration::from_secs(1));
        let mut changes = engine.image().changes(100_000);
        tokio::time::sleep(Duration::from_secs(60)).await;
        let mut seen = 0;
        let mut last_seq = None;
        let mut polls = std::collections::HashMap::new();
        while let Some(c) = changes.try_recv() {
            if let Some(s) = last_seq {
                assert_eq!(c.seq, s + 1, "commit numbers follow one another");
            }
            last_seq = Some(c.seq);
            let before = polls.insert(c.device.position, c.device.polls).unwrap_or(0);
            if c.device.polls > before && c.device.variables[0].is_some() {
                assert!(c.device.range.is_some(), "a PV without its range: {c:?}");
                seen += 1;
            }
        }
        assert_eq!(changes.dropped(), 0);
        // Four devices polled every second for a minute: one commit per poll.
        assert!(
            (4 * 55..=4 * 61).contains(&seen),
            "{seen} changes with values"
        );
    });
}

/// An hour of polling runs in virtual time: the polls follow the period exactly, and
/// the values' time stamps are the engine clock's.
#[test]
fn an_hour_of_polling_in_virtual_time() {
    paused(async {
        let engine = virtual_engine(Duration::from_secs(10));
        let start = engine.clock().wall();
        let real = Instant::now();
        tokio::time::sleep(Duration::from_secs(3600)).await;
        assert!(
            real.elapsed() < Duration::from_secs(60),
            "virtual, not real time"
        );
        let img = engine.image().snapshot();
        assert_eq!(img.len(), 4);
        for d in &img {
            // 360 periods; the first poll at start.
            assert!((358..=362).contains(&d.polls), "{} polls", d.polls);
            let updated = d.updated.unwrap().duration_since(start).unwrap();
            assert!(updated > Duration::from_secs(3580) && updated <= Duration::from_secs(3600));
            assert_eq!(d.quality(engine.clock().now()), Quality::Good);
        }
    });
}

/// A subscriber that does not keep up loses the oldest changes, counted; the newest
/// are kept.
#[test]
fn a_slow_subscriber_is_told_what_it_lost() {
    paused(async {
        let engine = virtual_engine(Duration::from_secs(1));
        let mut changes = engine.image().changes(8);
        tokio::time::sleep(Duration::from_secs(30)).await;
        assert!(changes.dropped() > 50, "{} dropped", changes.dropped());
        assert_eq!(changes.len(), 8);
        let first = changes.try_recv().unwrap();
        let mut last = first.seq;
        while let Some(c) = changes.try_recv() {
            assert_eq!(c.seq, last + 1);
            last = c.seq;
        }
        assert_eq!(first.seq + 7, last);
    });
}

/// When the engine is dropped, a subscriber receives what was left and then `None`.
#[test]
fn changes_end_when_the_engine_does() {
    paused(async {
        let engine = virtual_engine(Duration::from_secs(1));
        let mut changes = engine.image().changes(1000);
        tokio::time::sleep(Duration::from_secs(5)).await;
        let waiting = changes.len();
        assert!(waiting > 0);
        // The tasks hold the engine's shared parts: end them with the runtime's loop.
        drop(engine);
        let mut n = 0;
        while tokio::time::timeout(Duration::from_secs(1), changes.recv())
            .await
            .ok()
            .flatten()
            .is_some()
        {
            n += 1;
            if n > waiting + 100 {
                break;
            }
        }
        assert!(n >= waiting);
    });
}

/// Two loops of the demo plant in memory on tokio's clock, polled every second; the
/// first loop's fault hooks.
fn two_loops() -> (Engine, hart_poller::Faults) {
    let a = MemoryLoop::new(Plant::demo().devices().unwrap());
    let faults = a.faults();
    let b = MemoryLoop::new(Plant::demo().devices().unwrap());
    let (engine, _) = Engine::start_with(
        config(1000, ReadCommand::Dynamic),
        vec![
            LoopSpec {
                settings: LoopSettings::default(),
                line: Line::Memory(a),
            },
            LoopSpec {
                settings: LoopSettings::default(),
                line: Line::Memory(b),
            },
        ],
        StartOptions {
            clock: Clock::tokio(SystemTime::UNIX_EPOCH),
            ..StartOptions::default()
        },
    );
    (engine, faults)
}

fn qualities(engine: &Engine, channel: u8) -> Vec<Quality> {
    let now = engine.clock().now();
    engine
        .image()
        .snapshot()
        .iter()
        .filter(|d| d.channel == channel)
        .map(|d| d.quality(now))
        .collect()
}

fn polls(engine: &Engine, channel: u8) -> u64 {
    engine
        .image()
        .snapshot()
        .iter()
        .filter(|d| d.channel == channel)
        .map(|d| d.polls)
        .sum()
}

/// A babbling device (garbage, then burst frames without pause) disturbs its own loop
/// only: its devices say "loop disturbed" and the loop says why, the other loop goes on
/// polling at its rate, and the loop recovers by itself when the device goes quiet.
#[test]
fn a_babbling_loop_is_marked_and_recovers_without_stalling_the_others() {
    paused(async {
        let (engine, faults) = two_loops();
        tokio::time::sleep(Duration::from_secs(10)).await;
        assert!(qualities(&engine, 0).iter().all(|q| *q == Quality::Good));
        for (babble, says) in [
            (hart_poller::Babble::Garbage, "garbage"),
            (hart_poller::Babble::Bursts, "burst frames without pause"),
        ] {
            faults.set_babble(babble);
            let before = polls(&engine, 1);
            tokio::time::sleep(Duration::from_secs(15)).await;
            assert!(
                qualities(&engine, 0)
                    .iter()
                    .all(|q| *q == Quality::LoopDisturbed),
                "{babble:?}: {:?}",
                qualities(&engine, 0)
            );
            let why = engine.loop_disturbed(0).expect("the loop says why");
            assert!(why.contains(says), "{why}");
            assert_eq!(engine.loop_disturbed(1), None);
            assert!(qualities(&engine, 1).iter().all(|q| *q == Quality::Good));
            // Four devices polled every second: the other loop kept its rate.
            let done = polls(&engine, 1) - before;
            assert!(done >= 4 * 13, "{done} polls on the quiet loop in 15 s");
            faults.set_babble(hart_poller::Babble::Quiet);
            tokio::time::sleep(Duration::from_secs(15)).await;
            assert_eq!(engine.loop_disturbed(0), None);
            assert!(
                qualities(&engine, 0).iter().all(|q| *q == Quality::Good),
                "{babble:?} over: {:?}",
                qualities(&engine, 0)
            );
        }
    });
}

/// A device that answers at every polling address is found out by the scan (asked
/// again at its own address, it still answers there) and disturbs the loop.
#[test]
fn a_device_answering_every_address_disturbs_its_loop() {
    paused(async {
        let (engine, faults) = two_loops();
        tokio::time::sleep(Duration::from_secs(10)).await;
        faults.set_babble(hart_poller::Babble::AnswersEveryAddress);
        // The rescan visits the addresses again (one every RESCAN_IDLE at the most).
        let mut disturbed = None;
        for _ in 0..300 {
            tokio::time::sleep(Duration::from_secs(1)).await;
            if let Some(why) = engine.loop_disturbed(0) {
                disturbed = Some(why);
                break;
            }
        }
        let why = disturbed.expect("disturbed within five minutes of rescans");
        assert!(why.contains("answers at polling addresses"), "{why}");
        assert_eq!(engine.loop_disturbed(1), None);
    });
}

/// The write policy is the engine's: a read-only engine and an allow-list refuse a
/// typed write before anything goes on the loop or into the audit, whichever front end
/// asks; a write on the list is done and recorded once.
#[test]
fn the_write_policy_refuses_before_the_loop_and_the_audit() {
    use hart_poller::{NotPermitted, WritePolicy, WriteRecord};
    local(async {
        let dir = std::env::temp_dir().join(format!("hartkit-policy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let audit = dir.join("audit.jsonl");
        let _ = std::fs::remove_file(&audit);
        let engine_with = |policy: WritePolicy| {
            let (engine, _) = Engine::start_with(
                config(50, ReadCommand::Dynamic),
                vec![LoopSpec {
                    settings: LoopSettings::default(),
                    line: Line::Memory(MemoryLoop::new(Plant::demo().devices().unwrap())),
                }],
                StartOptions {
                    write_policy: policy,
                    ..StartOptions::default()
                },
            );
            engine
        };
        let who = WriteRecord {
            front_end: "test",
            peer: "-".into(),
            via: "engine test".into(),
            ..Default::default()
        };
        let engine = engine_with(WritePolicy {
            allow: Some("0-33".parse().unwrap()),
            audit: hart_access::Audit::new(Some(audit.clone())),
            ..Default::default()
        });
        engine.ready().await;
        let mut traffic = engine.traffic();
        assert_eq!(
            engine.apply(0, &WriteOp::Damping(2.0), &who).await,
            Err(WriteFailure::NotPermitted(NotPermitted::NotAllowed(34)))
        );
        // The refusal is recorded (nothing was sent).
        let lines = std::fs::read_to_string(&audit).unwrap();
        assert_eq!(lines.lines().count(), 1, "{lines}");
        let refusal: serde_json::Value = serde_json::from_str(lines.trim()).unwrap();
        assert_eq!(refusal["outcome"], "not-permitted", "{lines}");
        assert_eq!(refusal["command"], 34, "{lines}");
        engine
            .apply(0, &WriteOp::Tag("PT-9".into()), &who)
            .await
            .unwrap();
        let mut commands = vec![];
        while let Ok(f) = traffic.try_recv() {
            if let Ok(frame) = hart_proto::frame::Frame::parse_pdu(&f.pdu) {
                commands.push(frame.command);
            }
        }
        assert!(commands.contains(&18), "{commands:?}");
        assert!(
            !commands.contains(&34),
            "the damping never went: {commands:?}"
        );
        // The tag's write: a record before it went, and its outcome (same id).
        let lines = std::fs::read_to_string(&audit).unwrap();
        let records: Vec<serde_json::Value> = lines
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(records.len(), 3, "{lines}");
        assert_eq!(records[1]["front_end"], "test", "{lines}");
        assert_eq!(records[1]["outcome"], serde_json::Value::Null, "{lines}");
        assert_eq!(records[2]["id"], records[1]["id"], "{lines}");
        assert_eq!(records[2]["outcome"], "done", "{lines}");
        assert_eq!(records[2]["response_code"], 0, "{lines}");

        let read_only = engine_with(WritePolicy {
            read_only: true,
            ..Default::default()
        });
        read_only.ready().await;
        let refused = read_only
            .apply(0, &WriteOp::FixedCurrent(12.0), &who)
            .await
            .unwrap_err();
        assert_eq!(refused, WriteFailure::NotPermitted(NotPermitted::ReadOnly));
        assert!(refused.to_string().contains("--read-only"), "{refused}");
        let _ = std::fs::remove_dir_all(&dir);
    });
}
