//! Conformance suite of the simulated field device: every command is driven through
//! the data link as a host would, and every response code the device can return is
//! provoked at least once. `docs/field-device.md` links each command to its tests.

mod common;

use common::*;
use hart_device::config::Waveform;
use hart_link::Micros;
use hart_proto::frame::{Address, Frame, FrameType, LongAddress, MasterKind, UniqueId};
use hart_proto::types::PackedString;

const SUCCESS: u8 = 0;

// ------------------------------------------------------------------ identity (0, 11, 21)

#[test]
fn cmd0_identity_in_short_and_long_frames() {
    let mut h = Host::profile("pressure");
    let a = h
        .ask_short(0, 0, &[])
        .expect("command 0 at polling address 0");
    assert_eq!(a.rc, SUCCESS);
    assert_eq!(a.data.len(), 22, "HART 7 form");
    assert_eq!(a.data[0], 254);
    assert_eq!(u16::from_be_bytes([a.data[1], a.data[2]]), 0x26F1);
    assert_eq!(a.data[4], 7, "universal revision");
    assert_eq!(&a.data[9..12], &[0x01, 0x00, 0x01], "device ID");
    assert_eq!(a.data[12], 5, "response preambles");
    assert_eq!(
        u16::from_be_bytes([a.data[17], a.data[18]]),
        0x00F0,
        "manufacturer"
    );
    assert_eq!(a.data[21], 1, "device profile");
    assert!(
        h.ask_short(5, 0, &[]).is_none(),
        "another polling address: silence"
    );
    let long = h.ask(0, &[]);
    assert_eq!(long.data, a.data);
}

#[test]
fn cmd11_and_cmd21_answer_only_their_tag() {
    let mut h = Host::profile("pressure");
    let broadcast = Address::Long(LongAddress {
        master: MasterKind::Primary,
        burst: false,
        id: UniqueId::BROADCAST,
    });
    let tag = PackedString::<6>::new("PT-100").unwrap();
    assert_eq!(
        h.ask_at(broadcast, 11, &tag.0).unwrap().data[9..12],
        [1, 0, 1]
    );
    assert!(h
        .ask_at(broadcast, 11, &PackedString::<6>::new("OTHER").unwrap().0)
        .is_none());
    assert!(
        h.ask_at(broadcast, 1, &[]).is_none(),
        "broadcast only for commands 11 and 21"
    );
    let mut long_tag = [0u8; 32];
    long_tag[..9].copy_from_slice(b"Feed pump");
    assert_eq!(h.ask(22, &long_tag).rc, SUCCESS);
    assert_eq!(h.ask_at(broadcast, 21, &long_tag).unwrap().rc, SUCCESS);
    long_tag[0] = b'X';
    assert!(h.ask_at(broadcast, 21, &long_tag).is_none());
}

// ------------------------------------------------------------------ status bits

#[test]
fn cold_start_is_reported_once_to_each_master() {
    let mut h = Host::profile("pressure");
    assert_ne!(h.ask(1, &[]).status & 0x20, 0);
    assert_eq!(h.ask(1, &[]).status & 0x20, 0);
    h.master = MasterKind::Secondary;
    assert_ne!(
        h.ask(1, &[]).status & 0x20,
        0,
        "the secondary has its own copy"
    );
    // Device reset (42) sets it again.
    assert_eq!(h.ask(42, &[]).rc, SUCCESS);
    assert_ne!(h.ask(1, &[]).status & 0x20, 0);
}

#[test]
fn configuration_changed_counter_and_cmd38() {
    let mut h = Host::profile("pressure");
    let counter0 = u16::from_be_bytes([h.ask(0, &[]).data[14], h.ask(0, &[]).data[15]]);
    assert_eq!(h.ask(19, &[0, 0, 42]).rc, SUCCESS);
    let a = h.ask(0, &[]);
    assert_ne!(a.status & 0x40, 0, "configuration changed");
    let counter = u16::from_be_bytes([a.data[14], a.data[15]]);
    assert_eq!(counter, counter0 + 1);
    assert_eq!(
        h.ask(38, &(counter + 1).to_be_bytes()).rc,
        9,
        "counter mismatch"
    );
    assert_ne!(h.ask(1, &[]).status & 0x40, 0, "flag kept on mismatch");
    let r = h.ask(38, &counter.to_be_bytes());
    assert_eq!(
        (r.rc, r.data.clone()),
        (SUCCESS, counter.to_be_bytes().to_vec())
    );
    assert_eq!(h.ask(1, &[]).status & 0x40, 0);
    h.master = MasterKind::Secondary;
    assert_ne!(
        h.ask(1, &[]).status & 0x40,
        0,
        "cleared only for the master that asked"
    );
    assert_eq!(h.ask(38, &[]).rc, SUCCESS, "legacy form without counter");
    assert_eq!(h.ask(38, &[1]).rc, 5, "one byte is too few");
}

#[test]
fn more_status_available_follows_cmd48() {
    let mut h = Host::profile("pressure");
    assert_eq!(h.ask(1, &[]).status & 0x10, 0);
    // Simulating a device variable (79) sets standardized status 0 bit 0.
    let mut req = vec![0, 1, 12];
    req.extend(float(42.0));
    req.push(0x80);
    assert_eq!(h.ask(79, &req).rc, SUCCESS);
    assert_ne!(h.ask(1, &[]).status & 0x10, 0, "more status available");
    let s = h.ask(48, &[]);
    assert_eq!(s.data.len(), 14);
    assert_eq!(s.data[8] & 0x01, 0x01);
    assert_eq!(h.ask(48, &[0; 5]).rc, 5, "1-8 bytes: too few");
    assert_eq!(h.ask(48, &[0; 9]).rc, 14, "status bytes mismatch (warning)");
    h.master = MasterKind::Secondary;
    assert_ne!(h.ask(1, &[]).status & 0x10, 0);
    assert_eq!(h.ask(48, &s.data[..9]).rc, SUCCESS);
    assert_eq!(
        h.ask(1, &[]).status & 0x10,
        0,
        "acknowledged by the secondary"
    );
    h.master = MasterKind::Primary;
    assert_eq!(
        h.ask(1, &[]).status & 0x10,
        0,
        "the primary's legacy read acknowledged it too"
    );
}

// ------------------------------------------------------------------ reads

#[test]
fn process_reads_1_2_3_8_9_33() {
    let mut h = Host::new(constant_transmitter(50.0));
    let pv = h.ask(1, &[]);
    assert_eq!((pv.data[0], f32_at(&pv.data, 1)), (12, 50.0));
    let lc = h.ask(2, &[]);
    assert_eq!((f32_at(&lc.data, 0), f32_at(&lc.data, 4)), (12.0, 50.0));
    let dv = h.ask(3, &[]);
    assert_eq!(
        dv.data.len(),
        4 + 2 * 5,
        "loop current, PV and SV (TV and QV unmapped)"
    );
    assert_eq!(f32_at(&dv.data, 0), 12.0);
    assert_eq!(dv.data[9], 32, "SV in °C");
    assert_eq!(h.ask(8, &[]).data, vec![65, 64, 0, 0]);
    let v = h.ask(9, &[0, 245, 7]);
    assert_eq!(
        v.data.len(),
        1 + 3 * 8 + 4,
        "three slots and the time stamp"
    );
    assert_eq!(
        (
            v.data[1],
            v.data[2],
            v.data[3],
            f32_at(&v.data, 4),
            v.data[8]
        ),
        (0, 65, 12, 50.0, 0xC0)
    );
    assert_eq!(
        (v.data[9], v.data[11], f32_at(&v.data, 12)),
        (245, 39, 12.0)
    );
    assert_eq!(
        (v.data[17], v.data[19], u32_at(&v.data, 20), v.data[24]),
        (7, 250, 0x7FA0_0000, 0x30),
        "unknown code: NaN, bad/constant"
    );
    assert_eq!(h.ask(9, &[251]).rc, 2, "invalid selection");
    assert_eq!(h.ask(9, &[]).rc, 5);
    let r = h.ask(33, &[1, 0]);
    assert_eq!((r.data[0], r.data[1], r.data[6], r.data[7]), (1, 32, 0, 12));
}

#[test]
fn information_reads_7_12_13_14_15_16_20_50_54_95() {
    let mut h = Host::profile("pressure");
    assert_eq!(h.ask(7, &[]).data, vec![0, 1]);
    assert_eq!(PackedString([0; 24]).0.len(), h.ask(12, &[]).data.len());
    let t = h.ask(13, &[]);
    assert_eq!(
        PackedString::<6>(t.data[..6].try_into().unwrap()).to_string(),
        "PT-100"
    );
    assert_eq!(&t.data[18..21], &[21, 11, 125]);
    let ti = h.ask(14, &[]);
    assert_eq!(
        (
            ti.data[3],
            f32_at(&ti.data, 4),
            f32_at(&ti.data, 8),
            f32_at(&ti.data, 12)
        ),
        (12, 2000.0, -100.0, 10.0)
    );
    let di = h.ask(15, &[]);
    assert_eq!(di.data.len(), 18);
    assert_eq!(
        (
            di.data[2],
            f32_at(&di.data, 3),
            f32_at(&di.data, 7),
            f32_at(&di.data, 11),
            di.data[15],
            di.data[16]
        ),
        (12, 250.0, 0.0, 0.5, 0, 250)
    );
    assert_eq!(h.ask(16, &[]).data, vec![0x01, 0x87, 0x68]);
    assert_eq!(h.ask(20, &[]).data, vec![0; 32]);
    assert_eq!(h.ask(50, &[]).data, vec![0, 1, 250, 250]);
    let info = h.ask(54, &[1]);
    assert_eq!(info.data.len(), 28);
    assert_eq!(
        (info.data[0], info.data[4], info.data[21], info.data[22]),
        (1, 32, 64, 4)
    );
    assert_eq!(h.ask(54, &[9]).rc, 2);
    let before = h.ask(95, &[]);
    let stx = u16::from_be_bytes([before.data[0], before.data[1]]);
    let after = h.ask(95, &[]);
    assert_eq!(u16::from_be_bytes([after.data[0], after.data[1]]), stx + 1);
}

// ------------------------------------------------------------------ writes

#[test]
fn writes_17_18_19_22_read_back() {
    let mut h = Host::profile("pressure");
    let msg = PackedString::<24>::new("CALIBRATED 2025-11-21").unwrap();
    assert_eq!(h.ask(17, &msg.0).data, msg.0.to_vec());
    assert_eq!(h.ask(12, &[]).data, msg.0.to_vec());
    let mut tdd = PackedString::<6>::new("FT-7").unwrap().0.to_vec();
    tdd.extend(PackedString::<12>::new("FLOW").unwrap().0);
    tdd.extend([29, 2, 124]);
    assert_eq!(h.ask(18, &tdd).rc, SUCCESS, "29 Feb 2024 is a date");
    assert_eq!(h.ask(13, &[]).data, tdd);
    let mut bad = tdd.clone();
    bad[18] = 30;
    assert_eq!(h.ask(18, &bad).rc, 9, "invalid date");
    assert_eq!(h.ask(18, &tdd[..20]).rc, 5);
    assert_eq!(h.ask(19, &[1, 2, 3]).data, vec![1, 2, 3]);
    assert_eq!(h.ask(16, &[]).data, vec![1, 2, 3]);
}

/// How the device answers one write command.
struct WriteRule {
    command: u16,
    /// Build the device from the valve profile instead of a pressure transmitter.
    valve: bool,
    /// Requests that bring the device where the write is accepted (as the primary).
    setup: Vec<(u16, Vec<u8>)>,
    /// A request the device accepts.
    data: Vec<u8>,
    /// Reply to the command with no data; `None` when the command takes no data.
    empty: Option<u8>,
    /// Reply with the write-protect jumper set.
    protected: u8,
    /// Reply to the secondary master when the device restricts it.
    secondary: u8,
    /// Reply while the self test (41) runs.
    self_test: u8,
}

/// The common rule: 5 without data, 7 with the jumper, 16 to a restricted secondary,
/// 32 during the self test.
fn write(command: u16, data: Vec<u8>) -> WriteRule {
    WriteRule {
        command,
        valve: false,
        setup: vec![],
        data,
        empty: Some(5),
        protected: 7,
        secondary: 16,
        self_test: 32,
    }
}

impl WriteRule {
    fn after(mut self, command: u16, data: Vec<u8>) -> Self {
        self.setup.push((command, data));
        self
    }

    fn on_the_valve(mut self) -> Self {
        self.valve = true;
        self
    }

    fn host(&self, restrict_secondary: bool) -> Host {
        let mut c = if self.valve {
            hart_device::profiles::load("valve").unwrap()
        } else {
            constant_transmitter(50.0)
        };
        c.restrict_secondary_writes = restrict_secondary;
        let mut h = Host::new(c);
        for (command, data) in &self.setup {
            let rc = h.ask(*command, data).rc;
            assert_eq!(rc, SUCCESS, "setup {command} of command {}", self.command);
        }
        h
    }
}

fn write_rules() -> Vec<WriteRule> {
    let range = [vec![12], float(100.0).to_vec(), float(0.0).to_vec()].concat();
    let mut tdd = PackedString::<6>::new("FT-7").unwrap().0.to_vec();
    tdd.extend(PackedString::<12>::new("FLOW").unwrap().0);
    tdd.extend([1, 1, 125]);
    let simulate = [vec![0, 1, 12], float(1.0).to_vec(), vec![0xC0]].concat();
    let burst_period = [vec![0], period(1.0), period(2.0)].concat();
    let continuous = [vec![0, 0, 0, 250], float(0.0).to_vec()].concat();
    let no_data = |mut w: WriteRule| {
        w.empty = None;
        w
    };
    vec![
        write(6, vec![1, 1]),
        write(17, vec![0; 24]),
        write(18, tdd),
        write(19, vec![0; 3]),
        write(22, vec![0; 32]),
        write(34, float(1.0).to_vec()),
        write(35, range),
        // 36, 37 and 43 take the applied process as their value: they have no data.
        no_data(write(36, vec![])),
        no_data(write(37, vec![])),
        // Command 38 changes nothing but the asking master's own flag (and leaves the
        // configuration change counter alone), so a master can always acknowledge a
        // change: in write protection, when restricted, and during the self test. With
        // no data it is the legacy form, without the counter.
        WriteRule {
            empty: Some(SUCCESS),
            protected: SUCCESS,
            secondary: SUCCESS,
            self_test: SUCCESS,
            ..write(38, vec![])
        },
        write(40, float(12.0).to_vec()),
        no_data(write(43, vec![])),
        write(44, vec![7]),
        write(45, float(4.0).to_vec()).after(40, float(4.0).to_vec()),
        write(46, float(20.0).to_vec()).after(40, float(20.0).to_vec()),
        write(51, vec![1, 0]),
        write(53, vec![1, 33]),
        write(59, vec![6]),
        write(79, simulate),
        write(103, burst_period),
        write(104, continuous),
        write(107, vec![0, 250, 250, 250, 250, 250, 250, 250, 0]),
        write(108, vec![0, 1, 0]),
        write(109, vec![1, 0]),
        // The valve positioner's device-specific writes follow the same rules.
        write(129, float(25.0).to_vec()).on_the_valve(),
        write(131, float(12.0).to_vec()).on_the_valve(),
    ]
}

#[test]
fn every_write_command_refuses_short_protected_restricted_and_busy() {
    let rules = write_rules();
    // The table holds every write command of the command table, and only those.
    let typed: Vec<u16> = rules
        .iter()
        .map(|w| w.command)
        .filter(|&c| hart_proto::command::info(c).is_some())
        .collect();
    // (I/O-system commands such as 102 are not a field device's.)
    let writes: Vec<u16> = hart_proto::command::COMMANDS
        .iter()
        .filter(|c| c.writes && !hart_proto::command::IO_SYSTEM_COMMANDS.contains(&c.number))
        .map(|c| c.number)
        .collect();
    assert_eq!(typed, writes, "one rule per write command");
    for w in &rules {
        let c = w.command;
        if let Some(info) = hart_proto::command::info(c) {
            assert_eq!(
                w.empty.is_none() || w.empty == Some(SUCCESS),
                info.request_min == 0,
                "command {c}: only commands that need data answer 5 without it"
            );
        }
        let accepted = w.host(false).ask(c, &w.data).rc;
        assert!(
            matches!(accepted, SUCCESS | 8 | 14),
            "command {c}: the request is accepted ({accepted})"
        );
        if let Some(code) = w.empty {
            assert_eq!(
                w.host(false).ask(c, &[]).rc,
                code,
                "command {c} with no data"
            );
        }
        let mut h = w.host(false);
        h.device().set_write_protect(true);
        assert_eq!(h.ask(c, &w.data).rc, w.protected, "command {c}, jumper set");
        let mut h = w.host(true);
        h.master = MasterKind::Secondary;
        assert_eq!(h.ask(c, &w.data).rc, w.secondary, "command {c}, secondary");
        h.master = MasterKind::Primary;
        let a = h.ask(c, &w.data).rc;
        assert!(
            matches!(a, SUCCESS | 8 | 14),
            "command {c}: the primary is not restricted ({a})"
        );
        let mut h = w.host(false);
        assert_eq!(h.ask(41, &[]).rc, 33, "self test initiated");
        assert_eq!(h.ask(c, &w.data).rc, w.self_test, "command {c}, self test");
    }
}

#[test]
fn write_protect_jumper_is_reported_and_reads_go_on() {
    let mut h = Host::profile("pressure");
    h.device().set_write_protect(true);
    assert_eq!(h.ask(15, &[]).data[15], 1, "write protect code");
    assert_eq!(h.ask(13, &[]).rc, SUCCESS);
}

#[test]
fn cmd6_polling_address_and_multidrop() {
    let mut h = Host::new(constant_transmitter(50.0));
    assert_eq!(h.ask(6, &[64, 0]).rc, 2, "address above 63");
    assert_eq!(h.ask(6, &[3, 2]).rc, 12, "invalid loop current mode");
    assert_eq!(h.ask(6, &[]).rc, 5);
    assert_eq!(h.ask(6, &[3, 0]).data, vec![3, 0]);
    assert!(h.ask_short(0, 0, &[]).is_none());
    let a = h.ask_short(3, 0, &[]).expect("answers at the new address");
    assert_ne!(a.status & 0x08, 0, "multidrop: loop current fixed");
    assert_eq!(f32_at(&h.ask(2, &[]).data, 0), 4.0, "parked at 4 mA");
    assert_eq!(
        h.ask(40, &float(12.0)).rc,
        11,
        "no fixed current in multidrop"
    );
    assert_eq!(h.ask(7, &[]).data, vec![3, 0]);
    // HART 5 form: one byte; address 0 means analog.
    assert_eq!(h.ask(6, &[0]).data, vec![0]);
    assert_eq!(h.ask(7, &[]).data, vec![0, 1]);
    assert_eq!(f32_at(&h.ask(2, &[]).data, 0), 12.0);
}

#[test]
fn cmd34_damping_is_applied_and_rounded() {
    let mut c = constant_transmitter(0.0);
    c.variables[0].waveform = Waveform::Steps {
        values: vec![0.0, 100.0],
        period_s: 1000.0,
    };
    let mut h = Host::new(c);
    assert_eq!(h.ask(34, &float(-1.0)).rc, 4);
    assert_eq!(h.ask(34, &float(100.0)).rc, 3);
    let r = h.ask(34, &float(2.04));
    assert_eq!(
        (r.rc, f32_at(&r.data, 0)),
        (8, 2.0),
        "set to nearest possible value"
    );
    assert_eq!(f32_at(&h.ask(15, &[]).data, 11), 2.0);
    // Step from 0 to 100 at t = 1000 s; after one time constant PV reads ~63.2.
    h.wait(1_000_000_000 - 10_000 - h.now);
    h.wait(2_010_000);
    let pv = f32_at(&h.ask(1, &[]).data, 1);
    assert!(
        (60.0..80.0).contains(&pv),
        "first-order response (about 1 - e^-1.2 after the read), got {pv}"
    );
    h.wait(20_000_000);
    assert!((f32_at(&h.ask(1, &[]).data, 1) - 100.0).abs() < 0.1);
}

#[test]
fn cmd35_range_checks_and_unit_conversion() {
    let mut h = Host::profile("pressure");
    let range =
        |u: u8, urv: f32, lrv: f32| [vec![u], float(urv).to_vec(), float(lrv).to_vec()].concat();
    assert_eq!(
        h.ask(35, &range(12, 3000.0, 0.0)).rc,
        11,
        "URV above the upper sensor limit"
    );
    assert_eq!(
        h.ask(35, &range(12, -200.0, -300.0)).rc,
        10,
        "LRV below the lower sensor limit"
    );
    assert_eq!(
        h.ask(35, &range(12, 100.0, 2500.0)).rc,
        9,
        "LRV above the upper limit"
    );
    assert_eq!(
        h.ask(35, &range(12, -150.0, 0.0)).rc,
        12,
        "URV below the lower limit"
    );
    assert_eq!(h.ask(35, &range(12, 50.0, 50.0)).rc, 29, "invalid span");
    assert_eq!(
        h.ask(35, &range(32, 50.0, 0.0)).rc,
        2,
        "°C is not a pressure unit"
    );
    assert_eq!(
        h.ask(35, &range(12, 105.0, 100.0)).rc,
        14,
        "span below the minimum span: applied with a warning"
    );
    assert_eq!(h.ask(35, &range(12, 100.0, 0.0)[..5]).rc, 5);
    // 1 bar = 100 kPa: the device keeps PV units and converts.
    let r = h.ask(35, &range(7, 2.0, 0.5));
    assert_eq!(r.rc, SUCCESS);
    let d = h.ask(15, &[]).data;
    assert_eq!(d[2], 12);
    assert!((f32_at(&d, 3) - 200.0).abs() < 1e-3 && (f32_at(&d, 7) - 50.0).abs() < 1e-3);
}

#[test]
fn loop_current_through_range_changes_saturation_and_alarm() {
    let mut h = Host::new(constant_transmitter(50.0));
    let current = |h: &mut Host| f32_at(&h.ask(2, &[]).data, 0);
    let range = |urv: f32, lrv: f32| [vec![12], float(urv).to_vec(), float(lrv).to_vec()].concat();
    assert_eq!(current(&mut h), 12.0);
    h.ask(35, &range(200.0, 0.0));
    assert_eq!(current(&mut h), 8.0);
    h.ask(35, &range(100.0, 50.0));
    assert_eq!(current(&mut h), 4.0);
    h.ask(35, &range(40.0, 0.0));
    assert_eq!(current(&mut h), 20.5, "saturated high");
    assert_ne!(h.ask(1, &[]).status & 0x04, 0);
    h.ask(35, &range(150.0, 60.0));
    assert_eq!(current(&mut h), 3.8, "saturated low");
    h.ask(35, &range(100.0, 0.0));
    assert_eq!(h.ask(1, &[]).status & 0x04, 0);
    // Reverse-acting range.
    h.ask(35, &range(0.0, 100.0));
    assert_eq!(current(&mut h), 12.0);
    // Square root transfer function (set in the profile).
    let mut c = constant_transmitter(25.0);
    c.range.transfer_function = 1;
    let mut sq = Host::new(c);
    assert_eq!(f32_at(&sq.ask(2, &[]).data, 4), 50.0);
    // Malfunction drives the alarm current.
    h.ask(35, &range(100.0, 0.0));
    h.device().set_malfunction(true);
    let a = h.ask(2, &[]);
    assert_eq!((f32_at(&a.data, 0), a.status & 0x80), (21.75, 0x80));
    // PV beyond the sensor limits sets the PV-out-of-limits bit.
    let mut h = Host::new(constant_transmitter(2500.0));
    assert_ne!(h.ask(1, &[]).status & 0x01, 0);
}

#[test]
fn cmd40_fixed_current() {
    let mut h = Host::new(constant_transmitter(50.0));
    assert_eq!(h.ask(40, &float(30.0)).rc, 3);
    assert_eq!(h.ask(40, &float(1.0)).rc, 4);
    assert_eq!(h.ask(40, &float(16.0)).data, float(16.0).to_vec());
    let a = h.ask(2, &[]);
    assert_eq!((f32_at(&a.data, 0), a.status & 0x08), (16.0, 0x08));
    h.ask(40, &float(0.0));
    assert_eq!(
        f32_at(&h.ask(2, &[]).data, 0),
        12.0,
        "0 leaves fixed current mode"
    );
}

#[test]
fn cmd45_cmd46_trims_change_the_reported_current() {
    let mut c = constant_transmitter(50.0);
    c.output_offset_error = 0.05;
    c.output_gain_error = 1.01;
    let mut h = Host::new(c);
    assert_eq!(h.ask(45, &float(4.0)).rc, 9, "not in fixed current mode");
    h.ask(40, &float(4.0));
    let before = f32_at(&h.ask(2, &[]).data, 0);
    assert!(
        (before - 4.09).abs() < 1e-3,
        "output error visible: {before}"
    );
    assert_eq!(h.ask(45, &float(5.0)).rc, 3);
    assert_eq!(h.ask(45, &float(3.0)).rc, 4);
    assert_eq!(h.ask(45, &float(before)).rc, SUCCESS);
    // One trim pass leaves only the gain error times the offset (here < 1 µA).
    assert!(
        (f32_at(&h.ask(2, &[]).data, 0) - 4.0).abs() < 2e-3,
        "zero trimmed"
    );
    h.ask(40, &float(20.0));
    let at20 = f32_at(&h.ask(2, &[]).data, 0);
    assert_eq!(h.ask(46, &float(at20)).rc, SUCCESS);
    assert!(
        (f32_at(&h.ask(2, &[]).data, 0) - 20.0).abs() < 1e-3,
        "gain trimmed"
    );
    h.ask(40, &float(0.0));
    assert!((f32_at(&h.ask(2, &[]).data, 0) - 12.0).abs() < 2e-3);
}

#[test]
fn cmd36_cmd37_cmd43_set_range_and_zero_to_the_process() {
    let mut h = Host::new(constant_transmitter(80.0));
    assert_eq!(h.ask(36, &[]).rc, SUCCESS);
    assert_eq!(f32_at(&h.ask(15, &[]).data, 3), 80.0);
    // Setting the LRV to the process keeps the span: 80..160.
    assert_eq!(h.ask(37, &[]).rc, SUCCESS);
    let d = h.ask(15, &[]).data;
    assert_eq!((f32_at(&d, 3), f32_at(&d, 7)), (160.0, 80.0));
    let mut near = Host::new(constant_transmitter(1950.0));
    assert_eq!(
        near.ask(37, &[]).rc,
        14,
        "the shifted URV stops at the sensor limit"
    );
    assert_eq!(f32_at(&near.ask(15, &[]).data, 3), 2000.0);
    let mut over = Host::new(constant_transmitter(2100.0));
    assert_eq!(over.ask(36, &[]).rc, 9, "applied process too high");
    let mut z = Host::new(constant_transmitter(300.0));
    assert_eq!(z.ask(43, &[]).rc, 9, "zero shift too large");
    let mut z = Host::new(constant_transmitter(3.0));
    assert_eq!(z.ask(43, &[]).rc, SUCCESS);
    assert_eq!(f32_at(&z.ask(1, &[]).data, 1), 0.0);
}

#[test]
fn cmd44_cmd53_units_convert_values() {
    let mut h = Host::new(constant_transmitter(100.0));
    assert_eq!(h.ask(44, &[7]).data, vec![7]);
    let pv = h.ask(1, &[]);
    assert_eq!(pv.data[0], 7);
    assert!((f32_at(&pv.data, 1) - 1.0).abs() < 1e-5, "100 kPa = 1 bar");
    assert!(
        (f32_at(&h.ask(15, &[]).data, 3) - 1.0).abs() < 1e-5,
        "URV converted"
    );
    assert_eq!(h.ask(44, &[32]).rc, 2);
    assert_eq!(h.ask(53, &[1, 33]).data, vec![1, 33]);
    assert_eq!(h.ask(33, &[1]).data[1], 33);
    assert_eq!(h.ask(53, &[1, 12]).rc, 12, "invalid units code");
    assert_eq!(h.ask(53, &[9, 32]).rc, 2, "invalid device variable");
}

#[test]
fn cmd51_cmd59_cmd79() {
    let mut h = Host::profile("pressure");
    assert_eq!(h.ask(51, &[1, 0]).data, vec![1, 0, 250, 250]);
    assert_eq!(h.ask(1, &[]).data[0], 32, "PV is now the temperature");
    assert_eq!(h.ask(51, &[9]).rc, 2);
    h.ask(51, &[0, 1]);
    assert_eq!(h.ask(59, &[4]).rc, 4);
    assert_eq!(h.ask(59, &[21]).rc, 3);
    assert_eq!(h.ask(59, &[8]).data, vec![8]);
    assert_eq!(
        h.ask(1, &[]).preambles,
        8,
        "replies use the new preamble count"
    );
    assert_eq!(h.ask(0, &[]).data[12], 8);
    let sim = |code: u8, wc: u8, units: u8| {
        [vec![code, wc, units], float(77.0).to_vec(), vec![0x80]].concat()
    };
    assert_eq!(
        h.ask(79, &sim(0, 1, 32)).rc,
        12,
        "units must be the variable's"
    );
    assert_eq!(
        h.ask(79, &sim(0, 2, 12)).rc,
        10,
        "invalid write device variable code"
    );
    assert_eq!(h.ask(79, &sim(9, 1, 12)).rc, 2);
    assert_eq!(h.ask(79, &sim(0, 1, 12)).rc, SUCCESS);
    let v = h.ask(9, &[0]);
    assert_eq!((f32_at(&v.data, 4), v.data[8]), (77.0, 0x80));
    assert_ne!(
        h.ask(0, &[]).data[16] & 0x20,
        0,
        "function check while simulating"
    );
    h.ask(79, &sim(0, 0, 12));
    assert_ne!(f32_at(&h.ask(1, &[]).data, 1), 77.0);
}

#[test]
fn unknown_and_extended_commands() {
    let mut h = Host::profile("pressure");
    let a = h.ask(200, &[]);
    assert_eq!((a.rc, a.data.len()), (64, 0));
    let e = h.ask(1024, &[]);
    assert_eq!(e.rc, 64, "extended command through command 31");
    assert_eq!(h.ask(90, &[]).rc, 64);
}

#[test]
fn cmd41_delayed_response_33_34_0_36_35() {
    let mut h = Host::profile("pressure");
    assert_eq!(h.ask(41, &[]).rc, 33, "delayed response initiated");
    assert_eq!(
        h.ask(19, &[0, 0, 1]).rc,
        32,
        "busy: no configuration changes during the self test"
    );
    assert_ne!(
        h.ask(48, &[]).data[0] & 0x01,
        0,
        "self test running; reads go on"
    );
    assert_eq!(h.ask(41, &[]).rc, 34, "running");
    assert_eq!(h.ask(41, &[1]).rc, 36, "a different request conflicts");
    h.wait(hart_device::device::SELF_TEST_DURATION);
    assert_eq!(h.ask(41, &[]).rc, SUCCESS, "done");
    assert_eq!(h.ask(41, &[]).rc, 33, "a new self test");
    h.ask(42, &[]);
    assert_eq!(h.ask(41, &[]).rc, 35, "lost by the reset: dead");
}

// ------------------------------------------------------------------ burst mode

fn period(secs: f32) -> Vec<u8> {
    ((secs * 32_000.0) as u32).to_be_bytes().to_vec()
}

#[test]
fn burst_periods_round_to_legal_values() {
    let mut h = Host::profile("pressure");
    let p = |h: &mut Host, a: f32, b: f32| {
        let r = h.ask(103, &[vec![0], period(a), period(b)].concat());
        (
            r.rc,
            u32_at(&r.data, 1) as f32 / 32_000.0,
            u32_at(&r.data, 5) as f32 / 32_000.0,
        )
    };
    assert_eq!(p(&mut h, 1.0, 60.0), (0, 1.0, 60.0));
    assert_eq!(p(&mut h, 0.7, 3.0), (8, 0.5, 4.0), "update times adjusted");
    assert_eq!(p(&mut h, 0.1, 5000.0), (8, 0.5, 3600.0));
    assert_eq!(
        p(&mut h, 120.0, 60.0),
        (8, 120.0, 120.0),
        "max raised to min"
    );
    assert_eq!(
        h.ask(103, &[vec![3], period(1.0), period(2.0)].concat()).rc,
        9,
        "invalid burst message"
    );
}

#[test]
fn burst_commands_configure_and_read_back() {
    let mut h = Host::profile("pressure");
    assert_eq!(h.ask(108, &[0, 77, 0]).rc, 2, "command 77 is not burstable");
    assert_eq!(h.ask(108, &[0, 9, 1]).data, vec![0, 9, 1]);
    assert_eq!(
        h.ask(107, &[1, 0, 250, 250, 250, 250, 250, 250, 1]).rc,
        SUCCESS
    );
    assert_eq!(h.ask(107, &[1, 0, 250, 250, 250]).rc, 5, "5-8 bytes");
    assert_eq!(
        h.ask(107, &[99, 250, 250, 250, 250, 250, 250, 250, 1]).rc,
        2
    );
    let trig = |m: u8, mode: u8, class: u8, units: u8, level: f32| {
        [vec![m, mode, class, units], float(level).to_vec()].concat()
    };
    assert_eq!(
        h.ask(104, &trig(1, 5, 64, 32, 1.0)).rc,
        13,
        "invalid trigger mode"
    );
    assert_eq!(
        h.ask(104, &trig(1, 1, 65, 32, 1.0)).rc,
        11,
        "slot 0 is a temperature"
    );
    assert_eq!(
        h.ask(104, &trig(1, 1, 64, 12, 1.0)).rc,
        12,
        "kPa is not a temperature unit"
    );
    assert_eq!(
        h.ask(104, &trig(1, 1, 64, 33, 0.5)).rc,
        SUCCESS,
        "°F converts"
    );
    assert_eq!(h.ask(109, &[5, 1]).rc, 2);
    assert_eq!(h.ask(109, &[1, 3]).rc, 9);
    assert_eq!(h.ask(109, &[1, 1]).data, vec![1, 1]);
    let c = h.ask(105, &[1]);
    assert_eq!(c.data.len(), 29);
    assert_eq!(
        (c.data[0], c.data[1], &c.data[2..4], c.data[10], c.data[11]),
        (1, 31, &[1u8, 0][..], 1, 3)
    );
    assert_eq!(u16::from_be_bytes([c.data[12], c.data[13]]), 9);
    assert_eq!((c.data[22], c.data[23], c.data[24]), (1, 64, 33));
    assert_eq!(h.ask(105, &[7]).rc, 9);
    // A new command whose trigger value has another classification resets the trigger.
    let r = h.ask(108, &[0, 2, 1]);
    assert_eq!(r.rc, 8, "trigger mode changed to continuous");
    assert_eq!(h.ask(105, &[1]).data[22], 0);
}

#[test]
fn burst_publishes_at_its_period_with_alternating_master_bits() {
    let mut h = Host::profile("pressure");
    h.ask(108, &[0, 1, 0]);
    h.ask(103, &[vec![0], period(1.0), period(8.0)].concat());
    assert_eq!(h.ask(109, &[1, 0]).rc, SUCCESS);
    assert_ne!(h.ask(1, &[]).status, 0xFF);
    h.backs.clear();
    h.wait(30_000_000);
    let backs = &h.backs;
    assert!(
        backs.len() >= 28 && backs.len() <= 31,
        "{} BACKs in 30 s",
        backs.len()
    );
    assert!(backs.iter().all(|b| b.1 == 1 && b.3.len() == 5));
    assert!(
        backs.windows(2).all(|w| w[0].2 != w[1].2),
        "master bits alternate"
    );
    let mean = (backs.last().unwrap().0 - backs[0].0) as f64 / (backs.len() - 1) as f64 / 1e6;
    assert!((mean - 1.0).abs() < 0.02, "mean period {mean}");
    // Replies carry the burst bit while bursting; disabling stops the BACKs.
    h.ask(109, &[0, 0]);
    h.backs.clear();
    h.wait(10_000_000);
    assert!(h.backs.is_empty());
}

#[test]
fn three_burst_messages_with_their_own_commands() {
    let mut h = Host::profile("pressure");
    for (m, command, secs) in [(0u8, 1u16, 1.0f32), (1, 3, 2.0), (2, 48, 4.0)] {
        h.ask(
            108,
            &[vec![], command.to_be_bytes().to_vec(), vec![m]].concat(),
        );
        h.ask(103, &[vec![m], period(secs), period(secs)].concat());
        h.ask(109, &[1, m]);
    }
    h.backs.clear();
    h.wait(40_000_000);
    let count = |c: u16| h.backs.iter().filter(|b| b.1 == c).count();
    assert!(
        (38..=41).contains(&count(1)),
        "command 1 every second: {}",
        count(1)
    );
    assert!(
        (19..=21).contains(&count(3)),
        "command 3 every 2 s: {}",
        count(3)
    );
    assert!(
        (9..=11).contains(&count(48)),
        "command 48 every 4 s: {}",
        count(48)
    );
}

#[test]
fn burst_triggers_window_rising_falling_on_change() {
    // PV ramps from 0 to 100 kPa over 100 s, then jumps back.
    let mut c = constant_transmitter(0.0);
    c.variables[0].waveform = Waveform::Ramp {
        from: 0.0,
        to: 100.0,
        period_s: 100.0,
    };
    let run = |mode: u8, level: f32| -> Vec<u64> {
        let mut h = Host::new(c.clone());
        h.ask(108, &[0, 1, 0]);
        h.ask(103, &[vec![0], period(0.5), period(16.0)].concat());
        h.ask(
            104,
            &[vec![0, mode, 65, 12], float(level).to_vec()].concat(),
        );
        h.ask(109, &[1, 0]);
        h.backs.clear();
        let start = h.now;
        h.wait(200_000_000 - start % 100_000_000);
        h.backs.iter().map(|b| (b.0 - start) / 1_000_000).collect()
    };
    // Continuous: every 0.5 s.
    let cont = run(0, 0.0);
    assert!(cont.len() > 300, "continuous: {}", cont.len());
    // Window of 10 kPa: the PV moves 1 kPa/s, so about every 10 s (and at least every 16 s).
    let window = run(1, 10.0);
    assert!(
        (15..=30).contains(&window.len()),
        "window: {}",
        window.len()
    );
    // Rising above 80 kPa: fast only while PV > 80 (20 s of each 100 s).
    let rising = run(2, 80.0);
    assert!(
        (60..=110).contains(&rising.len()),
        "rising: {}",
        rising.len()
    );
    // Falling below 20 kPa: likewise.
    let falling = run(3, 20.0);
    assert!(
        (60..=110).contains(&falling.len()),
        "falling: {}",
        falling.len()
    );
    // On change: the ramp changes continuously, so at the minimum period.
    let change = run(4, 0.0);
    assert!(change.len() > 300, "on change: {}", change.len());
}

#[test]
fn burst_on_change_with_a_constant_value_publishes_at_the_maximum_period() {
    let mut h = Host::new(constant_transmitter(50.0));
    h.ask(108, &[0, 1, 0]);
    h.ask(103, &[vec![0], period(0.5), period(16.0)].concat());
    let on_change = [vec![0, 4, 0, 250], float(0.0).to_vec()].concat();
    assert_eq!(h.ask(104, &on_change).rc, SUCCESS);
    h.ask(109, &[1, 0]);
    h.backs.clear();
    // Neither the PV nor the device status changes: the maximum period only.
    h.wait(170_000_000);
    let times: Vec<Micros> = h.backs.iter().map(|b| b.0).collect();
    assert!(
        (10..=12).contains(&times.len()),
        "{} BACKs in 170 s",
        times.len()
    );
    for w in times.windows(2) {
        let gap = (w[1] - w[0]) as f64 / 1e6;
        assert!((gap - 16.0).abs() < 0.1, "published {gap} s apart");
    }
    // A change (here the PV simulated by command 79) is published at once, then the
    // constant value again only at the maximum period.
    let last = *times.last().unwrap();
    h.backs.clear();
    let simulate = [vec![0, 1, 12], float(60.0).to_vec(), vec![0xC0]].concat();
    assert_eq!(h.ask(79, &simulate).rc, SUCCESS);
    let changed_at = h.now;
    h.wait(40_000_000);
    let after: Vec<Micros> = h.backs.iter().map(|b| b.0).collect();
    assert!(after.len() >= 2, "{} BACKs after the change", after.len());
    assert!(
        after[0] - changed_at < 1_000_000 && after[0] - last < 16_000_000,
        "the change is published within the minimum period"
    );
    assert_eq!(f32_at(&h.backs[0].3, 1), 60.0);
    for w in after.windows(2) {
        let gap = (w[1] - w[0]) as f64 / 1e6;
        assert!((gap - 16.0).abs() < 0.1, "then {gap} s apart");
    }
}

/// A BACK as heard on the line, with its status bytes.
#[derive(Debug, Clone)]
struct Back {
    command: u16,
    master: MasterKind,
    rc: u8,
    status: u8,
    data: Vec<u8>,
}

/// Lets `us` of virtual time pass like `Host::wait`, keeping every BACK whole.
fn listen(h: &mut Host, us: Micros) -> Vec<Back> {
    let end = h.now + us;
    let mut heard = vec![];
    loop {
        let next = h.node.next_deadline(h.now).unwrap_or(end).max(h.now + 1);
        if next > end {
            h.now = end;
            h.device().tick(end);
            return heard;
        }
        h.now = next;
        if let Some(bytes) = h.node.poll(h.now) {
            h.now += P.chars(bytes.len());
            h.node.transmitted(h.now);
            let f = Frame::parse(&bytes).expect("device sent a valid frame");
            assert_eq!(f.frame_type(), FrameType::Back, "nobody asked");
            heard.push(Back {
                command: f.command,
                master: f.address.master(),
                rc: f.response_code.expect("response code"),
                status: f.device_status.expect("device status"),
                data: f.data.to_vec(),
            });
        }
    }
}

/// Configures burst message 0 to publish `command` every 0.5 s and turns it on.
fn burst_every_half_second(h: &mut Host, command: u16) {
    let mut cmd = command.to_be_bytes().to_vec();
    cmd.push(0);
    assert_eq!(h.ask(108, &cmd).rc, SUCCESS);
    h.ask(103, &[vec![0], period(0.5), period(0.5)].concat());
    assert_eq!(h.ask(109, &[1, 0]).rc, SUCCESS);
}

fn with_master(backs: &[Back], master: MasterKind) -> Vec<Back> {
    backs
        .iter()
        .filter(|b| b.master == master)
        .cloned()
        .collect()
}

#[test]
fn burst_of_cmd38_resets_no_configuration_changed_flag() {
    let mut h = Host::new(constant_transmitter(50.0));
    assert_eq!(h.ask(19, &[0, 0, 42]).rc, SUCCESS, "configuration changed");
    burst_every_half_second(&mut h, 38);
    let id = h.ask(0, &[]).data;
    let counter = [id[14], id[15]];
    let backs = listen(&mut h, 20_000_000);
    assert!(backs.len() >= 38, "{} BACKs in 20 s", backs.len());
    for b in &backs {
        assert_eq!((b.command, b.rc), (38, SUCCESS));
        assert_eq!(
            b.data,
            counter.to_vec(),
            "the command 38 reply: the counter"
        );
        assert_ne!(b.status & 0x40, 0, "{:?} still sees the change", b.master);
    }
    assert_ne!(
        h.ask(1, &[]).status & 0x40,
        0,
        "the primary still sees the configuration changed"
    );
    h.master = MasterKind::Secondary;
    assert_ne!(h.ask(1, &[]).status & 0x40, 0, "and so does the secondary");
    h.master = MasterKind::Primary;
    assert_eq!(
        h.ask(38, &counter).rc,
        SUCCESS,
        "command 38 still resets it"
    );
    assert_eq!(h.ask(1, &[]).status & 0x40, 0);
    // From now on the BACKs to the primary show it reset, those to the secondary not.
    let backs = listen(&mut h, 5_000_000);
    let primary = with_master(&backs, MasterKind::Primary);
    let secondary = with_master(&backs, MasterKind::Secondary);
    assert!(primary.len() >= 4 && secondary.len() >= 4);
    assert!(primary.iter().all(|b| b.status & 0x40 == 0));
    assert!(secondary.iter().all(|b| b.status & 0x40 != 0));
}

#[test]
fn burst_of_cmd48_acknowledges_no_status() {
    let mut h = Host::new(constant_transmitter(50.0));
    // Simulating a device variable sets "more status available" for both masters.
    let simulate = [vec![1, 1, 32], float(25.0).to_vec(), vec![0xC0]].concat();
    assert_eq!(h.ask(79, &simulate).rc, SUCCESS);
    burst_every_half_second(&mut h, 48);
    let backs = listen(&mut h, 20_000_000);
    assert!(backs.len() >= 38, "{} BACKs in 20 s", backs.len());
    assert!(backs.windows(2).all(|w| w[0].master != w[1].master));
    for b in &backs {
        assert_eq!((b.command, b.rc, b.data.len()), (48, SUCCESS, 14));
        assert_eq!(b.data[8] & 0x01, 0x01, "simulation active");
        assert_ne!(b.status & 0x10, 0, "{:?}: more status available", b.master);
    }
    assert_ne!(
        h.ask(1, &[]).status & 0x10,
        0,
        "not acknowledged for the primary"
    );
    h.master = MasterKind::Secondary;
    assert_ne!(
        h.ask(1, &[]).status & 0x10,
        0,
        "nor for the secondary, whose bit half the BACKs carry"
    );
    // Only a master's own command 48 acknowledges, and only for that master.
    let status = h.ask(48, &[]).data;
    assert_eq!(h.ask(48, &status[..9]).rc, SUCCESS);
    assert_eq!(h.ask(1, &[]).status & 0x10, 0);
    h.master = MasterKind::Primary;
    assert_ne!(h.ask(1, &[]).status & 0x10, 0);
}

#[test]
fn burst_status_byte_is_that_of_the_master_whose_bit_the_back_carries() {
    let mut h = Host::new(constant_transmitter(50.0));
    burst_every_half_second(&mut h, 1);
    let primary_view = h.ask(1, &[]).status;
    assert_eq!(primary_view & 0x20, 0, "cold start reported to the primary");
    let backs = listen(&mut h, 5_000_000);
    assert!(backs.windows(2).all(|w| w[0].master != w[1].master));
    let to_primary = with_master(&backs, MasterKind::Primary);
    let to_secondary = with_master(&backs, MasterKind::Secondary);
    assert!(to_primary.len() >= 4 && to_secondary.len() >= 4);
    assert!(backs.iter().all(|b| b.rc == SUCCESS && b.data.len() == 5));
    assert!(
        to_primary.iter().all(|b| b.status == primary_view),
        "the primary's status: {:02X?}",
        to_primary.iter().map(|b| b.status).collect::<Vec<_>>()
    );
    // The secondary has not talked to the device since power-up: cold start is still
    // set for it, in its BACKs as in its first reply.
    h.master = MasterKind::Secondary;
    let secondary_view = h.ask(1, &[]).status;
    assert_ne!(
        secondary_view & 0x20,
        0,
        "cold start, as the secondary sees it"
    );
    assert!(
        to_secondary.iter().all(|b| b.status == secondary_view),
        "the secondary's status: {:02X?}",
        to_secondary.iter().map(|b| b.status).collect::<Vec<_>>()
    );
    // That reply reported cold start to the secondary; its BACKs now show it cleared.
    let backs = listen(&mut h, 5_000_000);
    let to_secondary = with_master(&backs, MasterKind::Secondary);
    assert!(!to_secondary.is_empty());
    assert!(to_secondary
        .iter()
        .all(|b| b.status == secondary_view & !0x20));
}

// ------------------------------------------------------------------ persistence

#[test]
fn configuration_survives_restart_and_crash_mid_write() {
    let dir = std::env::temp_dir().join(format!("hart-device-persist-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let path = hart_device::persist::state_path(&dir, 0);
    let mut h = Host::profile("pressure");
    h.node.persist_to(path.clone());
    let tag = PackedString::<6>::new("SAVED").unwrap();
    let mut tdd = tag.0.to_vec();
    tdd.extend([
        0x82, 0x08, 0x20, 0x82, 0x08, 0x20, 0x82, 0x08, 0x20, 0x82, 0x08, 0x20, 1, 2, 125,
    ]);
    assert_eq!(h.ask(18, &tdd).rc, SUCCESS);
    h.ask(6, &[4, 1]);
    // A crash in the middle of the next write leaves a partial temporary file.
    std::fs::write(path.with_extension("toml.tmp"), b"profile = \"pres").unwrap();
    let cfg = hart_device::persist::load(&path)
        .unwrap()
        .expect("state file");
    assert!(!path.with_extension("toml.tmp").exists());
    let mut again = Host::new(cfg);
    let a = again
        .ask_short(4, 13, &[])
        .expect("restarted at the saved polling address");
    assert_eq!(&a.data[..6], &tag.0);
    assert_ne!(a.status & 0x20, 0, "restart sets cold start");
    let _ = std::fs::remove_dir_all(&dir);
}

// ------------------------------------------------------------------ valve positioner

#[test]
fn valve_travel_follows_the_setpoint() {
    let mut h = Host::profile("valve");
    assert_eq!(h.ask(15, &[]).data[17] & 1, 1, "analog channel is an input");
    let set_current = |h: &mut Host, ma: f32| h.ask(131, &float(ma));
    set_current(&mut h, 20.0);
    let travel = |h: &mut Host| f32_at(&h.ask(1, &[]).data, 1);
    let t0 = travel(&mut h);
    h.wait(1_000_000);
    let t1 = travel(&mut h);
    assert!(t1 - t0 <= 20.0 * 1.5 + 0.5, "rate limited: {t0} -> {t1}");
    h.wait(20_000_000);
    assert!((travel(&mut h) - 100.0).abs() < 0.5);
    // Digital setpoint.
    assert_eq!(h.ask(129, &float(25.0)).rc, SUCCESS);
    assert_eq!(f32_at(&h.ask(128, &[]).data, 1), 25.0);
    h.wait(30_000_000);
    assert!((travel(&mut h) - 25.0).abs() < 0.5);
    assert_eq!(h.ask(129, &float(150.0)).rc, 3);
    assert_eq!(
        f32_at(&h.ask(2, &[]).data, 0),
        20.0,
        "the loop current is the controller's"
    );
}

#[test]
fn user_profile_with_a_fixed_device_specific_command() {
    let text = r#"
        profile = "mine"
        tag = "MY-1"
        [identity]
        device_id = 0x0ABCDE
        [[variables]]
        code = 0
        classification = 66
        units = 19
        waveform = { kind = "constant", value = 12.5 }
        [[commands]]
        number = 140
        reply_hex = "CAFE01"
    "#;
    let cfg = hart_device::DeviceConfig::from_toml(text).unwrap();
    let mut h = Host::new(cfg);
    assert_eq!(h.ask(140, &[]).data, vec![0xCA, 0xFE, 0x01]);
    assert_eq!(f32_at(&h.ask(1, &[]).data, 1), 12.5);
    assert!(
        hart_device::DeviceConfig::from_toml("no_such_key = 1").is_err(),
        "typos in profiles are errors"
    );
}

#[test]
fn access_restricted_for_the_secondary_master() {
    let mut c = hart_device::profiles::load("pressure").unwrap();
    c.restrict_secondary_writes = true;
    let mut h = Host::new(c);
    h.master = MasterKind::Secondary;
    assert_eq!(h.ask(19, &[0, 0, 1]).rc, 16, "access restricted");
    assert_eq!(h.ask(16, &[]).rc, SUCCESS);
    h.master = MasterKind::Primary;
    assert_eq!(h.ask(19, &[0, 0, 1]).rc, SUCCESS);
}
