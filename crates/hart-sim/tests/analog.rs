//! The analog medium: the same network on the loop sample by sample.

use hart_sim::{run, LineOptions, LoopModel, Medium, SimConfig};

fn analog(model: LoopModel) -> Medium {
    Medium::Analog {
        model,
        options: LineOptions::default(),
    }
}

#[test]
fn a_short_loop_works_as_the_digital_line_does() {
    let cfg = SimConfig {
        devices: 3,
        duration: 30_000_000,
        medium: analog(LoopModel::default()),
        ..SimConfig::default()
    };
    let r = run(&cfg);
    let d = run(&SimConfig {
        medium: Medium::Digital,
        ..cfg
    });
    println!("{r:#?}");
    assert_eq!(r.devices_found, 3);
    assert_eq!(r.failed, 0);
    assert_eq!(r.wrong_data, 0);
    assert!(r.frames_sent > 50);
    assert_eq!(r.frames_heard, r.frames_sent);
    let ratio = r.transactions_primary as f64 / d.transactions_primary as f64;
    assert!(
        ratio > 0.9,
        "{} vs {}",
        r.transactions_primary,
        d.transactions_primary
    );
}

#[test]
fn the_cable_limit_comes_from_the_signal() {
    use hart_sim::cable::{measure, rule_length_m, CableSetup};
    let setup = CableSetup {
        model: LoopModel {
            cable_pf_per_m: 225.0,
            ..LoopModel::default()
        },
        options: LineOptions::default(),
        devices: 15,
        transactions: 60,
    };
    let rule = rule_length_m(&setup);
    assert!((rule - 685.0).abs() < 5.0, "{rule}");
    let at_rule = measure(&setup, rule);
    assert_eq!((at_rule.heard, at_rule.frames), (120, 120));
    // Far beyond: the devices' replies reach the control room under carrier detect,
    // while the master's requests still reach the field.
    let far = measure(&setup, 6.0 * rule);
    assert!(far.fer() > 0.3, "{far:?}");
}

#[test]
fn a_late_reply_collides_with_the_retry_on_the_wire() {
    use hart_sim::{Faults, LateDevice};
    // Device 2 answers 400 ms late (beyond STO) for a while: its reply runs into the
    // master's retry, and the collision is in the signal.
    let cfg = SimConfig {
        devices: 3,
        duration: 60_000_000,
        faults: Faults {
            late_device: Some(LateDevice {
                poll: 2,
                delay: 400_000,
                from: 20_000_000,
                until: 40_000_000,
            }),
            ..Faults::default()
        },
        medium: analog(LoopModel::default()),
        ..SimConfig::default()
    };
    let r = run(&cfg);
    assert!(r.collisions > 0, "{r:?}");
    assert!(r.failed > 0, "{r:?}");
    assert_eq!(r.wrong_data, 0);
    // Before and after, polling goes on.
    assert!(r.transactions_primary > 40, "{}", r.transactions_primary);
}

#[test]
fn two_masters_and_a_burst_device_share_the_loop() {
    let cfg = SimConfig {
        devices: 3,
        secondary: true,
        burst_period: Some(1_000_000),
        duration: 60_000_000,
        medium: analog(LoopModel {
            cable_length_m: 1500.0,
            ..LoopModel::default()
        }),
        ..SimConfig::default()
    };
    let r = run(&cfg);
    assert_eq!(r.wrong_data, 0);
    assert!(
        r.transactions_primary > 10 && r.transactions_secondary > 10,
        "{r:?}"
    );
    assert!(r.burst_frames > 20 && r.burst_alternates, "{r:?}");
    assert!(r.frame_error_rate() < 0.02, "{r:?}");
}
