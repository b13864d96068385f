//! Whole-network behaviour of the simulated line: the goals of the data link layer as
//! checks (throughput figures themselves are benchmarks, see docs/benchmarks.md).

use hart_link::{Micros, TimingProfile};
use hart_proto::frame::{Frame, FrameType};
use hart_sim::{required_gap, run, Faults, FrameKind, SimConfig, SimReport, TraceRecord};
use proptest::prelude::*;

const HOUR: Micros = 3_600_000_000;

fn kind(t: &TraceRecord) -> FrameKind {
    match Frame::parse(&t.bytes) {
        Ok(f) => match f.frame_type() {
            FrameType::Stx => FrameKind::Stx(f.address.master()),
            FrameType::Ack => FrameKind::Ack(f.address.master()),
            FrameType::Back => FrameKind::Back(f.address.master()),
        },
        Err(_) => FrameKind::Other,
    }
}

/// No station starts while another station's transmission has been on the line for a
/// whole character (it would have heard it): the only collisions possible are two
/// stations starting within one character of each other.
fn assert_listen_before_talk(r: &SimReport, p: &TimingProfile) {
    let mut sorted: Vec<&TraceRecord> = r.trace.iter().collect();
    sorted.sort_by_key(|t| t.t0_us);
    for (i, b) in sorted.iter().enumerate() {
        // Only transmissions that started within the longest frame time can overlap.
        for a in sorted[..i]
            .iter()
            .rev()
            .take_while(|a| a.t0_us + 400 * p.char_time > b.t0_us)
        {
            assert!(
                !(a.t0_us + p.char_time <= b.t0_us && b.t0_us < a.t1_us),
                "{} started at {} while {} had been sending since {}",
                b.src,
                b.t0_us,
                a.src,
                a.t0_us
            );
        }
    }
}

#[test]
fn same_seed_same_run() {
    let cfg = SimConfig {
        duration: 120_000_000,
        secondary: true,
        burst_period: Some(1_000_000),
        ber: 1e-4,
        seed: 7,
        trace: true,
        ..SimConfig::default()
    };
    assert_eq!(run(&cfg), run(&cfg));
    let other = run(&SimConfig { seed: 8, ..cfg });
    assert_ne!(run(&cfg).trace, other.trace);
}

#[test]
fn lone_primary_every_gap_is_a_rule_timer() {
    let p = TimingProfile::fsk();
    let cfg = SimConfig {
        duration: 300_000_000,
        trace: true,
        ..SimConfig::default()
    };
    let r = run(&cfg);
    assert_eq!(r.devices_found, 15);
    assert_eq!((r.failed, r.collisions, r.wrong_data), (0, 0, 0));
    assert!(r.efficiency >= 0.98, "efficiency {}", r.efficiency);
    // After the scan (which waits STO at the empty polling address 0), every silence is
    // exactly the timer the rules require: HOLD before a reply, RT2 before the next request.
    let polling = r
        .trace
        .iter()
        .position(|t| Frame::parse(&t.bytes).is_ok_and(|f| f.command == 3))
        .unwrap();
    for w in r.trace[polling..].windows(2) {
        let gap = w[1].t0_us - w[0].t1_us;
        let want = required_gap(&p, kind(&w[0]), kind(&w[1]));
        assert_eq!(
            gap, want,
            "gap between {} at {} and {} at {}",
            w[0].src, w[0].t1_us, w[1].src, w[1].t0_us
        );
        assert!(want == p.hold || want == p.rt2);
    }
}

#[test]
fn two_masters_and_a_burst_device_for_an_hour() {
    let cfg = SimConfig {
        duration: HOUR,
        secondary: true,
        burst_period: Some(2_000_000),
        trace: true,
        ..SimConfig::default()
    };
    let r = run(&cfg);
    assert_eq!((r.collisions, r.failed, r.wrong_data), (0, 0, 0));
    let (p, s) = (
        r.transactions_primary as f64,
        r.transactions_secondary as f64,
    );
    assert!(p >= 0.4 * s && s >= 0.4 * p, "primary {p}, secondary {s}");
    assert!(
        (r.burst_mean_period_s - 2.0).abs() < 0.02,
        "burst period {}",
        r.burst_mean_period_s
    );
    assert!(r.burst_alternates);
    assert!(r.burst_frames >= 1790);
    assert!(r.efficiency >= 0.98, "efficiency {}", r.efficiency);
    assert_listen_before_talk(&r, &cfg.profile);
}

#[test]
fn bit_errors_are_retried_never_accepted() {
    for (secondary, burst) in [(false, None), (true, Some(1_000_000))] {
        let cfg = SimConfig {
            duration: HOUR / 2,
            secondary,
            burst_period: burst,
            ber: 1e-4,
            seed: 3,
            ..SimConfig::default()
        };
        let r = run(&cfg);
        assert_eq!(r.wrong_data, 0, "a damaged reply was accepted");
        assert!(
            r.retries > 50,
            "bit errors should cause retries, got {}",
            r.retries
        );
        assert_eq!(r.failed, 0, "every damaged transaction recovers at 1e-4");
        assert_eq!(r.collisions, 0);
    }
    // Far worse lines: failures are reported, wrong data still never accepted.
    let r = run(&SimConfig {
        duration: 600_000_000,
        ber: 2e-3,
        seed: 5,
        ..SimConfig::default()
    });
    assert_eq!(r.wrong_data, 0);
    assert!(r.failed > 0);
}

#[test]
fn a_device_that_falls_silent_fails_alone() {
    let cfg = SimConfig {
        duration: 120_000_000,
        faults: Faults {
            silent_device: Some((4, 30_000_000)),
            ..Faults::default()
        },
        ..SimConfig::default()
    };
    let r = run(&cfg);
    let healthy = run(&SimConfig {
        faults: Faults::default(),
        ..cfg
    });
    assert!(
        r.failed >= 5,
        "polls of the silent device fail: {}",
        r.failed
    );
    assert!(r.transactions_primary > healthy.transactions_primary / 2);
    assert_eq!(r.collisions, 0);
}

#[test]
fn slow_devices_inside_sto_are_fine_beyond_it_they_fail() {
    let p = TimingProfile::fsk();
    let slow = SimConfig {
        duration: 120_000_000,
        faults: Faults {
            slow_device: Some((2, p.sto - 5_000)),
            ..Faults::default()
        },
        ..SimConfig::default()
    };
    let r = run(&slow);
    assert_eq!((r.failed, r.collisions), (0, 0));
    let too_slow = SimConfig {
        faults: Faults {
            slow_device: Some((2, p.sto + 5_000)),
            ..Faults::default()
        },
        ..slow
    };
    let r = run(&too_slow);
    assert!(
        r.devices_found == 14,
        "a device answering after STO is never found"
    );
}

#[test]
fn every_physical_layer_runs_clean() {
    for profile in [
        TimingProfile::fsk(),
        TimingProfile::rs485(1200),
        TimingProfile::rs485(19200),
        TimingProfile::psk(),
        TimingProfile::infrared(),
    ] {
        let r = run(&SimConfig {
            profile,
            duration: 120_000_000,
            secondary: true,
            burst_period: Some(1_000_000),
            ..SimConfig::default()
        });
        assert_eq!(
            (r.collisions, r.failed, r.wrong_data),
            (0, 0, 0),
            "{}",
            profile.name
        );
        assert!(r.efficiency > 0.95, "{}: {}", profile.name, r.efficiency);
    }
}

#[test]
fn full_field_devices_drop_into_the_network() {
    for profile in ["pressure", "temperature", "valve"] {
        let cfg = SimConfig {
            duration: 600_000_000,
            secondary: true,
            burst_period: Some(1_000_000),
            device_profile: Some(profile),
            trace: true,
            ..SimConfig::default()
        };
        let r = run(&cfg);
        assert_eq!(r.devices_found, 15, "{profile}");
        assert_eq!(
            (r.collisions, r.failed, r.wrong_data),
            (0, 0, 0),
            "{profile}"
        );
        assert!(
            r.burst_frames > 500 && r.burst_alternates,
            "{profile}: {} BACKs",
            r.burst_frames
        );
        assert_listen_before_talk(&r, &cfg.profile);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Random networks and schedules: nobody ever talks over a transmission it could
    /// hear, nothing collides, nothing wrong is accepted.
    #[test]
    fn random_networks_never_talk_over_each_other(
        devices in 1u8..8,
        secondary in any::<bool>(),
        burst in proptest::option::of(300_000u64..4_000_000),
        command in prop_oneof![Just(1u16), Just(2), Just(3), Just(9), Just(48)],
        phy in 0usize..4,
        slow in proptest::option::of((1u8..8, 0u64..200_000)),
        seed in any::<u64>(),
    ) {
        let profile = [TimingProfile::fsk(), TimingProfile::rs485(9600), TimingProfile::psk(), TimingProfile::infrared()][phy];
        let slow = slow.map(|(a, d)| (a, d.min(profile.sto.saturating_sub(profile.char_time))));
        let cfg = SimConfig { profile, devices, secondary, burst_period: burst, command, duration: 40_000_000, seed, trace: true, faults: Faults { slow_device: slow, ..Faults::default() }, ..SimConfig::default() };
        let r = run(&cfg);
        assert_listen_before_talk(&r, &profile);
        prop_assert_eq!(r.collisions, 0);
        prop_assert_eq!(r.wrong_data, 0);
        prop_assert_eq!(r.failed, 0);
        prop_assert_eq!(r.devices_found, u64::from(devices));
    }
}
