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
    ("burst-trigger-any-mode", false, &["BURST-007"]),
    ("burst-any-command", false, &["BURST-008"]),
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
    let docs = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../docs/conform.md"
    ))
    .unwrap();
    for (_, name, _) in hart_device::faults::ALL {
        let (_, _, tests) = FAULTS
            .iter()
            .find(|(f, _, _)| f == name)
            .unwrap_or_else(|| panic!("{name} has no row"));
        // docs/conform.md lists it with the same tests.
        let line = docs
            .lines()
            .find(|l| l.starts_with(&format!("| `{name}` |")))
            .unwrap_or_else(|| panic!("docs/conform.md does not list {name}"));
        assert!(
            line.ends_with(&format!("| {} |", tests.join(", "))),
            "{line}"
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

/// A line that works for `good` requests, then carries nothing more (a device that
/// stops answering mid-run), or answers every request with `garbage`.
struct Faulty {
    inner: SimTransport,
    sends: usize,
    good: usize,
    garbage: Option<hart_rng::Rng>,
    now: u64,
}

impl hart_host::transport::Transport for Faulty {
    fn profile(&self) -> hart_link::TimingProfile {
        self.inner.profile()
    }
    fn now(&self) -> u64 {
        self.inner.now().max(self.now)
    }
    async fn send(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.sends += 1;
        self.inner.send(bytes).await
    }
    async fn recv(&mut self, deadline: u64) -> std::io::Result<Vec<(u8, u64)>> {
        let got = self.inner.recv(deadline).await?;
        if let (Some(rng), true) = (&mut self.garbage, self.sends > self.good) {
            // As many bytes as came, each replaced by noise (0xFF now and then, so
            // that some look like preambles).
            return Ok(got
                .into_iter()
                .map(|(_, at)| {
                    let x = rng.next_u64();
                    let b = if x % 5 == 0 { 0xFF } else { (x >> 8) as u8 };
                    (b, at)
                })
                .collect());
        }
        if self.sends > self.good && self.garbage.is_none() {
            self.now = self.now.max(deadline);
            return Ok(vec![]);
        }
        Ok(got)
    }
    fn describe(&self) -> String {
        "a faulty line".into()
    }
}

fn run_on(t: &mut Faulty) -> Report {
    let o = Options::new("faulty", DeviceAddress::Poll(0));
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .unwrap();
    rt.block_on(run(t, &o))
}

#[test]
fn a_device_that_stops_answering_is_reported_not_waited_for() {
    let inner = SimTransport::new(&plant("pressure", None, false, &[]), true).unwrap();
    let mut t = Faulty {
        inner,
        sends: 0,
        good: 12,
        garbage: None,
        now: 0,
    };
    let r = run_on(&mut t);
    assert!(r.device.is_some());
    let stopped = r
        .results
        .iter()
        .filter(|t| t.verdict == Verdict::CouldNotRun && t.detail.contains("stopped answering"))
        .count();
    assert!(stopped > 20, "{}", hart_conform::report::text(&r));
    // Bounded: after it stopped, no more than a few requests went out.
    assert!(t.sends < 40, "{} requests", t.sends);
}

#[test]
fn garbage_replies_end_in_a_clear_verdict() {
    for seed in 1..20u64 {
        let inner = SimTransport::new(&plant("pressure", None, false, &[]), true).unwrap();
        let mut t = Faulty {
            inner,
            sends: 0,
            good: 0,
            garbage: Some(hart_rng::Rng::new(seed)),
            now: 0,
        };
        let r = run_on(&mut t);
        assert!(r.device.is_none(), "seed {seed}");
        assert!(r.results.iter().all(|t| t.verdict == Verdict::CouldNotRun));
        assert!(
            r.results[0].detail.contains("no device answered"),
            "{}",
            r.results[0].detail
        );
    }
}

#[test]
fn garbage_after_identification_fails_or_cannot_run_but_ends() {
    for seed in 1..10u64 {
        let inner = SimTransport::new(&plant("pressure", None, false, &[]), true).unwrap();
        let mut t = Faulty {
            inner,
            sends: 0,
            good: 1,
            garbage: Some(hart_rng::Rng::new(seed * 0x51_7CC1)),
            now: 0,
        };
        let r = run_on(&mut t);
        assert!(r.device.is_some(), "seed {seed}");
        assert_eq!(
            r.count(Verdict::Pass)
                + r.count(Verdict::NotApplicable)
                + r.count(Verdict::Fail)
                + r.count(Verdict::CouldNotRun),
            r.results.len()
        );
        assert!(t.sends < 200, "seed {seed}: {} requests", t.sends);
    }
}

#[test]
fn a_loop_in_use_is_warned_about() {
    let mut t = SimTransport::new(&plant("pressure", None, false, &[]), true).unwrap();
    // A handheld on the loop reading command 1 every 200 ms.
    t.add_secondary(200_000);
    let mut o = Options::new("sim", DeviceAddress::Poll(0));
    o.groups = vec![hart_conform::Group::Link];
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .unwrap();
    let r = rt.block_on(run(&mut t, &o));
    assert!(
        r.warnings.iter().any(|w| w.contains("the loop is in use")),
        "{:?}",
        r.warnings
    );
}

#[test]
fn expect_files_are_checked() {
    let valve = hart_device::profiles::BUILTIN
        .iter()
        .find(|(n, _)| *n == "valve")
        .unwrap()
        .1;
    let run_with = |text: &str| {
        let mut t = SimTransport::new(&plant("valve", None, false, &[]), true).unwrap();
        let mut o = Options::new("sim", DeviceAddress::Poll(0));
        o.groups = vec![hart_conform::Group::Commands];
        o.expect = Some(hart_conform::expect::Expect::from_toml(text).unwrap());
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap();
        rt.block_on(run(&mut t, &o))
    };
    let verdict = |r: &Report, id: &str| r.results.iter().find(|t| t.id == id).unwrap().verdict;
    // The device's own profile: its identity and device-specific commands match.
    let r = run_with(valve);
    assert_eq!(
        verdict(&r, "CMD-200"),
        Verdict::Pass,
        "{}",
        hart_conform::report::text(&r)
    );
    assert_eq!(verdict(&r, "CMD-201"), Verdict::Pass);
    // Another device revision, and a command the device does not have.
    let other = valve.replace("device_revision = ", "device_revision = 9")
        + "\n[[commands]]\nnumber = 200\nreply_hex = \"0102\"\n";
    let r = run_with(&other);
    assert_eq!(
        verdict(&r, "CMD-200"),
        Verdict::Fail,
        "{}",
        hart_conform::report::text(&r)
    );
    assert_eq!(verdict(&r, "CMD-201"), Verdict::Fail);
}

#[test]
fn burst_tests_enable_a_message_on_a_quiet_device_and_restore_it() {
    let verdicts = |r: &Report| -> Vec<(&'static str, Verdict)> {
        r.results
            .iter()
            .filter(|t| t.id.starts_with("BURST-00") && t.id <= "BURST-003")
            .map(|t| (t.id, t.verdict))
            .collect()
    };
    let r = conform(&plant("pressure", None, false, &[]), true);
    assert!(
        verdicts(&r).iter().all(|(_, v)| *v == Verdict::Pass),
        "{}",
        hart_conform::report::text(&r)
    );
    // Without --allow-writes they do not apply to a device that is not bursting.
    let r = conform(&plant("pressure", None, false, &[]), false);
    assert!(verdicts(&r)
        .iter()
        .all(|(_, v)| *v == Verdict::NotApplicable));
    // A slow burst timer is caught on the message the test enabled.
    let r = conform(&plant("pressure", None, false, &["burst-period-off"]), true);
    assert_eq!(
        failed(&r),
        vec!["BURST-001"],
        "{}",
        hart_conform::report::text(&r)
    );
}
