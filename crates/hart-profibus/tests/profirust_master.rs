//! Our slave against an independent DP master: profirust's (MIT/Apache), on
//! profirust's simulated bus in virtual time. The simulated bus checks the line's
//! timing itself: it panics when a station sends while another is sending or before
//! the station delay has passed.

use std::time::Duration;

use hart_profibus::{DpState, Event, Slave, SlaveConfig};
use profirust::dp;
use profirust::fdl;
use profirust::phy::{ProfibusPhy, SimulatorPhy};

const SLAVE: u8 = 5;
const MASTER: u8 = 2;
const IDENT: u16 = 0x4854;
/// Two modules of 28 input bytes (14 words) and 6 output bytes.
const CFG: [u8; 4] = [0xDD, 0xA5, 0xDD, 0xA5];
const STEP_US: i64 = 100;

fn slave(baud: u32) -> Slave {
    Slave::new(SlaveConfig {
        address: SLAVE,
        ident_number: IDENT,
        cfg: CFG.to_vec(),
        baud,
        max_tsdr_bits: 60,
        user_prm_len: 0,
    })
    .unwrap()
}

fn micros(t: profirust::time::Instant) -> Duration {
    Duration::from_micros(t.total_micros() as u64)
}

/// The slave's side of the simulated bus.
struct SlaveOnBus {
    phy: SimulatorPhy,
    slave: Slave,
    events: Vec<Event>,
    replies: u32,
    log: Vec<(i64, &'static str, Vec<u8>)>,
}

impl SlaveOnBus {
    fn poll(&mut self, now: profirust::time::Instant) {
        if self.phy.poll_transmission(now) {
            return;
        }
        let slave = &mut self.slave;
        let log = &mut self.log;
        self.phy.receive_data(now, |buf| {
            slave.receive(micros(now), buf);
            if !buf.is_empty() {
                match log.last_mut() {
                    Some((t, "rx", b)) => {
                        b.extend_from_slice(buf);
                        *t = now.total_micros();
                    }
                    _ => log.push((now.total_micros(), "rx", buf.to_vec())),
                }
            }
            (buf.len(), ())
        });
        if let Some(bytes) = self.slave.poll_transmit(micros(now)) {
            self.replies += 1;
            self.log.push((now.total_micros(), "tx", bytes.clone()));
            self.phy.transmit_data(now, |buf| {
                buf[..bytes.len()].copy_from_slice(&bytes);
                (bytes.len(), ())
            });
        }
        self.events.extend(self.slave.take_events());
    }
}

struct Rig {
    baud: profirust::Baudrate,
    cfg: &'static [u8],
    ident: u16,
    master_phy: SimulatorPhy,
    fdl: fdl::FdlActiveStation,
    dp: dp::DpMaster<'static>,
    handle: dp::PeripheralHandle,
    slave: SlaveOnBus,
    now: profirust::time::Instant,
    dp_events: Vec<dp::PeripheralEvent>,
}

/// A DP master for our slave, with its own process image.
fn master(
    baud: profirust::Baudrate,
    options: dp::PeripheralOptions<'static>,
) -> (
    fdl::FdlActiveStation,
    dp::DpMaster<'static>,
    dp::PeripheralHandle,
) {
    let io = hart_profibus::cfg::io_lengths(options.config.unwrap()).unwrap();
    let mut dp = dp::DpMaster::new(vec![]);
    let handle = dp.add(
        dp::Peripheral::new(SLAVE, options, vec![0u8; io.inputs], vec![0u8; io.outputs])
            .with_diag_buffer(vec![0u8; 64]),
    );
    let mut fdl = fdl::FdlActiveStation::new(
        fdl::ParametersBuilder::new(MASTER, baud)
            .highest_station_address(8)
            .watchdog_timeout(profirust::time::Duration::from_millis(200))
            .build_verified(&dp),
    );
    fdl.set_online();
    dp.enter_operate();
    (fdl, dp, handle)
}

impl Rig {
    fn new(baud: profirust::Baudrate, rate: u32, (cfg, ident): (&'static [u8], u16)) -> Self {
        let master_phy = SimulatorPhy::new(baud, "master");
        let slave_phy = master_phy.duplicate("hartkit");
        let (fdl, dp, handle) = master(baud, options(cfg, ident));
        Rig {
            baud,
            cfg,
            ident,
            master_phy,
            fdl,
            dp,
            handle,
            slave: SlaveOnBus {
                phy: slave_phy,
                slave: slave(rate),
                events: Vec::new(),
                replies: 0,
                log: Vec::new(),
            },
            now: profirust::time::Instant::ZERO,
            dp_events: Vec::new(),
        }
    }

    /// Runs the bus for `ms` milliseconds of virtual time; the master is polled only
    /// when `master_on`.
    fn run(&mut self, ms: i64, master_on: bool) {
        let end = self.now + profirust::time::Duration::from_millis(ms as u64);
        while self.now < end {
            self.now += profirust::time::Duration::from_micros(STEP_US as u64);
            self.master_phy.set_bus_time(self.now);
            if master_on {
                self.fdl.poll(self.now, &mut self.master_phy, &mut self.dp);
                let ev = self.dp.take_last_events();
                if let Some((_, e)) = ev.peripheral {
                    self.dp_events.push(e);
                }
            } else {
                // A master that stopped still has to drain what the slave sends.
                self.master_phy.receive_data(self.now, |b| (b.len(), ()));
            }
            self.slave.poll(self.now);
        }
    }

    /// The master restarts: a new master process, on a fresh connection to the bus.
    fn restart_master(&mut self) {
        let (fdl, dp, handle) = master(self.baud, options(self.cfg, self.ident));
        self.fdl = fdl;
        self.dp = dp;
        self.handle = handle;
        self.master_phy = self.master_phy.duplicate("master");
        self.master_phy.receive_data(self.now, |b| (b.len(), ()));
    }

    /// What the slave saw and did, for a failure's message.
    fn report(&self) -> String {
        let mut r = format!(
            "master events {:?}\nslave events {:?}\nstats {:?}\nstate {:?}\n",
            self.dp_events,
            self.slave.events,
            self.slave.slave.stats(),
            self.slave.slave.state()
        );
        for l in &self.slave.log[self.slave.log.len().saturating_sub(30)..] {
            r += &format!("{l:?}\n");
        }
        r
    }

    fn run_until(&mut self, max_ms: i64, mut done: impl FnMut(&mut Self) -> bool) -> bool {
        for _ in 0..max_ms {
            self.run(1, true);
            if done(self) {
                return true;
            }
        }
        false
    }
}

fn options(cfg: &'static [u8], ident: u16) -> dp::PeripheralOptions<'static> {
    dp::PeripheralOptions {
        ident_number: ident,
        user_parameters: Some(&[]),
        config: Some(cfg),
        max_tsdr: 60,
        ..Default::default()
    }
}

#[test]
fn profirust_reaches_data_exchange_and_exchanges_the_image() {
    for (baud, rate) in [
        (profirust::Baudrate::B19200, 19_200),
        (profirust::Baudrate::B93750, 93_750),
        (profirust::Baudrate::B9600, 9_600),
        (profirust::Baudrate::B45450, 45_450),
    ] {
        let mut rig = Rig::new(baud, rate, (&CFG, IDENT));
        let inputs: Vec<u8> = (0..56u8).collect();
        rig.slave.slave.set_inputs(&inputs);
        let handle = rig.handle;
        let ok = rig.run_until(5_000, |r| r.dp.get_mut(handle).is_running());
        assert!(ok, "{baud:?}: no data exchange; {}", rig.report());
        assert_eq!(rig.slave.slave.state(), DpState::DataExch);
        assert_eq!(rig.slave.slave.master(), Some(MASTER));
        assert_eq!(rig.slave.slave.watchdog(), Some(Duration::from_millis(200)));
        rig.run(300, true);
        assert_eq!(rig.dp.get_mut(handle).pi_i(), &inputs[..], "{baud:?}");

        // Outputs reach the slave; new inputs reach the master.
        rig.dp
            .get_mut(handle)
            .pi_q_mut()
            .copy_from_slice(&[9u8; 12]);
        let next: Vec<u8> = (100..156u8).collect();
        rig.slave.slave.set_inputs(&next);
        rig.run(500, true);
        assert_eq!(rig.slave.slave.outputs(), &[9u8; 12], "{baud:?}");
        assert_eq!(rig.dp.get_mut(handle).pi_i(), &next[..], "{baud:?}");
        assert!(rig.slave.events.contains(&Event::Outputs));
        let stats = rig.slave.slave.stats();
        assert_eq!(stats.damaged, 0);
        assert_eq!(stats.late, 0, "{baud:?}: {stats:?}");
    }
}

#[test]
fn device_diagnosis_reaches_the_master() {
    let mut rig = Rig::new(profirust::Baudrate::B19200, 19_200, (&CFG, IDENT));
    let handle = rig.handle;
    assert!(rig.run_until(5_000, |r| r.dp.get_mut(handle).is_running()));
    rig.dp_events.clear();
    // Device 1 (the second module) stops answering: the data exchange reply turns
    // "data high", the master fetches the diagnosis.
    rig.slave.slave.set_unit_diag(&[0b10]);
    rig.run(200, true);
    assert!(rig.dp_events.contains(&dp::PeripheralEvent::Diagnostics));
    let p = rig.dp.get_mut(handle);
    let d = p.last_diagnostics().unwrap();
    assert!(d.flags.contains(dp::DiagnosticFlags::EXT_DIAG));
    assert_eq!(d.ident_number, IDENT);
    assert_eq!(d.master_address, Some(MASTER));
    assert_eq!(
        d.extended_diagnostics.raw_diag_buffer(),
        Some(&[2u8, 0b10][..])
    );
    assert!(p.is_running());
}

#[test]
fn watchdog_clears_outputs_and_the_master_recovers() {
    let mut rig = Rig::new(profirust::Baudrate::B19200, 19_200, (&CFG, IDENT));
    let handle = rig.handle;
    assert!(rig.run_until(5_000, |r| r.dp.get_mut(handle).is_running()));
    rig.dp.get_mut(handle).pi_q_mut().fill(7);
    rig.run(100, true);
    assert_eq!(rig.slave.slave.outputs(), &[7u8; 12]);

    // The master stops for longer than the 200 ms watchdog.
    rig.run(150, false);
    assert_eq!(rig.slave.slave.state(), DpState::DataExch);
    rig.run(100, false);
    assert_eq!(rig.slave.slave.state(), DpState::WaitPrm);
    assert_eq!(rig.slave.slave.outputs(), &[0u8; 12]);
    assert!(rig
        .slave
        .events
        .iter()
        .any(|e| matches!(e, Event::WatchdogExpired { master: MASTER, .. })));
    assert_eq!(
        rig.slave.slave.diagnosis(Some(MASTER))[1] & 0x01,
        0x01,
        "Prm_Req"
    );

    // The master comes back: it is refused data exchange, reads the diagnosis,
    // parameterises and configures again.
    rig.slave.events.clear();
    rig.restart_master();
    rig.dp.get_mut(rig.handle).pi_q_mut().fill(7);
    let handle = rig.handle;
    let ok = rig.run_until(5_000, |r| {
        r.slave.slave.state() == DpState::DataExch && r.dp.get_mut(handle).is_running()
    });
    assert!(ok, "{}", rig.report());
    rig.run(100, true);
    assert_eq!(rig.slave.slave.outputs(), &[7u8; 12]);
}

#[test]
fn a_wrong_configuration_is_a_configuration_fault() {
    static WRONG: [u8; 2] = [0xDD, 0xA5];
    let mut rig = Rig::new(profirust::Baudrate::B19200, 19_200, (&WRONG, IDENT));
    rig.run(3_000, true);
    assert!(
        rig.dp_events.contains(&dp::PeripheralEvent::ConfigError),
        "{:?}",
        rig.dp_events
    );
    assert!(!rig.dp_events.contains(&dp::PeripheralEvent::DataExchanged));
    assert_ne!(rig.slave.slave.state(), DpState::DataExch);
    assert!(rig
        .slave
        .events
        .iter()
        .any(|e| matches!(e, Event::ConfigurationFault { .. })));
    assert_eq!(rig.slave.slave.outputs(), &[0u8; 12]);
}

#[test]
fn a_wrong_ident_number_is_a_parameter_fault() {
    let mut rig = Rig::new(profirust::Baudrate::B19200, 19_200, (&CFG, 0x1234));
    rig.run(3_000, true);
    assert!(
        rig.dp_events.contains(&dp::PeripheralEvent::ParameterError),
        "{:?}",
        rig.dp_events
    );
    assert_eq!(rig.slave.slave.state(), DpState::WaitPrm);
    let d = rig.slave.slave.diagnosis(Some(MASTER));
    assert_eq!(d[0] & 0x40, 0x40, "Prm_Fault");
    assert!(rig
        .slave
        .events
        .iter()
        .any(|e| matches!(e, Event::ParameterFault { reason, .. } if reason.contains("0x1234"))));
}

/// The DP cycle on the simulated bus with the demo plant's station (4 modules: 112
/// input bytes, 24 output bytes) against the line's minimum for the same telegrams,
/// and our station delay as profirust's master sees it. Printed for
/// docs/benchmarks.md (`cargo test -p hart-profibus --test profirust_master cycle --
/// --nocapture`).
#[test]
fn cycle_time_against_the_line_minimum() {
    static DEMO: [u8; 8] = [0xDD, 0xA5, 0xDD, 0xA5, 0xDD, 0xA5, 0xDD, 0xA5];
    for (baud, rate) in [
        (profirust::Baudrate::B19200, 19_200u32),
        (profirust::Baudrate::B93750, 93_750),
    ] {
        let mut rig = Rig::new(baud, rate, (&DEMO, IDENT));
        rig.slave.slave = Slave::new(SlaveConfig {
            address: SLAVE,
            ident_number: IDENT,
            cfg: DEMO.to_vec(),
            baud: rate,
            max_tsdr_bits: 60,
            user_prm_len: 0,
        })
        .unwrap();
        let handle = rig.handle;
        assert!(rig.run_until(10_000, |r| r.dp.get_mut(handle).is_running()));
        rig.run(2_000, true);
        let before = rig.slave.slave.stats().data_exchanges;
        let (t0, log0) = (rig.now, rig.slave.log.len());
        rig.run(10_000, true);
        let cycles = rig.slave.slave.stats().data_exchanges - before;
        let cycle_ms = (rig.now - t0).total_micros() as f64 / 1000.0 / cycles as f64;
        // Minimum: request SD2 with 24 output bytes (33 characters), reply SD2 with 112
        // input bytes (121 characters), 11 bits each; min TSDR 11 bits; the master's
        // idle TSYN of 33 bits before its request.
        let bits = (33 + 121) * 11 + 11 + 33;
        let min_ms = f64::from(bits) * 1000.0 / f64::from(rate);
        // Station delay: from the end of a request to the first byte of our reply
        // (time steps of 100 µs), as logged on the slave's side.
        let mut tsdr = vec![];
        for w in rig.slave.log[log0..].windows(2) {
            if let [(t_rx, "rx", req), (t_tx, "tx", _)] = w {
                // t_rx: the step in which the request was whole.
                if req.len() > 6 {
                    tsdr.push((t_tx - t_rx) as f64);
                }
            }
        }
        tsdr.sort_by(f64::total_cmp);
        let bit_us = 1e6 / f64::from(rate);
        println!(
            "{rate} bit/s: {cycles} cycles, {cycle_ms:.2} ms per DP cycle (line minimum {min_ms:.2} ms, {:.0} %); \
             TSDR median {:.0} µs = {:.1} bit times (min TSDR 11 = {:.0} µs)",
            100.0 * cycle_ms / min_ms,
            tsdr[tsdr.len() / 2],
            tsdr[tsdr.len() / 2] / bit_us,
            11.0 * bit_us
        );
        assert!(cycle_ms < 2.0 * min_ms, "{cycle_ms} ms against {min_ms} ms");
    }
}
