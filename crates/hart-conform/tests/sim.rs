//! The catalogue against simulated devices in virtual time: every profile passes every
//! applicable test; each fault is caught by the test meant for it and by no other.

use hart_conform::{run, DeviceAddress, Options, Report, Verdict};
use hart_host::transport::{Plant, PlantBurst, PlantDevice, SimTransport};

fn plant(profile: &str, revision: Option<u8>, burst: bool, faults: &[&str]) -> Plant {
    Plant {
        device: vec![PlantDevice {
            profile: profile.into(),
            poll: 0,
            burst: burst.then_some(PlantBurst {
                command: 3,
                period: 1.0,
            }),
            revision,
            faults: faults.iter().map(|f| f.to_string()).collect(),
        }],
    }
}

fn conform(plant: &Plant, writes: bool) -> Report {
    let mut t = SimTransport::new(plant, true).unwrap();
    let mut o = Options::new("sim", DeviceAddress::Poll(0));
    o.allow_writes = writes;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .unwrap();
    rt.block_on(run(&mut t, &o))
}

fn failed(r: &Report) -> Vec<&'static str> {
    r.results
        .iter()
        .filter(|t| t.verdict == Verdict::Fail)
        .map(|t| t.id)
        .collect()
}

#[test]
fn every_profile_passes() {
    for profile in ["pressure", "temperature", "valve"] {
        for revision in [5, 6, 7] {
            for burst in [false, true] {
                let r = conform(&plant(profile, Some(revision), burst, &[]), true);
                assert!(
                    failed(&r).is_empty(),
                    "{profile} HART {revision} burst {burst}:\n{}",
                    hart_conform::report::text(&r)
                );
                let cnr: Vec<_> = r
                    .results
                    .iter()
                    .filter(|t| t.verdict == Verdict::CouldNotRun && t.id != "LINK-013")
                    .map(|t| t.id)
                    .collect();
                assert!(
                    cnr.is_empty(),
                    "{profile} {revision} {burst}: {cnr:?}\n{}",
                    hart_conform::report::text(&r)
                );
            }
        }
    }
}

/// Each fault and the tests that must catch it: exactly those fail.
const FAULTS: &[(&str, bool, &[&str])] = &[
    ("late-reply", false, &["LINK-010"]),
    ("gap-in-reply", false, &["LINK-011"]),
    ("bad-reply-check-byte", false, &["LINK-016"]),
    ("executes-bad-check-byte", false, &["LINK-012"]),
    ("master-bit-not-echoed", false, &["LINK-007"]),
    ("too-few-preambles", false, &["LINK-008"]),
    ("answers-other-address", false, &["LINK-003", "LINK-004"]),
    ("no-too-few-data-bytes", false, &["CMD-101"]),
    ("cmd38-no-reset", false, &["CMD-038"]),
    ("burst-period-off", true, &["BURST-001"]),
];

#[test]
fn each_fault_is_caught_by_its_test_only() {
    for (fault, burst, want) in FAULTS {
        let r = conform(&plant("pressure", None, *burst, &[fault]), true);
        assert_eq!(
            failed(&r),
            want.to_vec(),
            "fault {fault}:\n{}",
            hart_conform::report::text(&r)
        );
    }
}

#[test]
fn every_fault_has_a_row() {
    for (_, name, _) in hart_device::faults::ALL {
        assert!(
            FAULTS.iter().any(|(f, _, _)| f == name),
            "{name} has no row"
        );
    }
}

#[test]
fn no_device_is_could_not_run_everywhere() {
    let mut t = SimTransport::new(&plant("pressure", None, false, &[]), true).unwrap();
    let o = Options::new("sim", DeviceAddress::Poll(5));
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .unwrap();
    let r = rt.block_on(run(&mut t, &o));
    assert!(r.device.is_none());
    assert!(r.results.iter().all(|t| t.verdict == Verdict::CouldNotRun));
    assert!(
        r.results[0].detail.contains("no device answered"),
        "{}",
        r.results[0].detail
    );
}
