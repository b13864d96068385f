//! The gateway as a PROFIBUS DP slave, driven by an independent DP master
//! (profirust's, MIT/Apache) over a pseudo-terminal at 19.2 kbit/s in real time: a
//! simulated loop (a pressure transmitter at polling address 0, which drives its loop
//! current, and a temperature transmitter at 1, in multidrop mode) behind
//! `--profibus`; the master parameterises and configures the station from the map's
//! configuration identifiers, reads every device's PV in its units and changing, sees a
//! listed device that does not answer in its quality byte and in the diagnosis, and
//! makes loop-test writes: one lands on the device, one the device refuses.

use std::time::{Duration, Instant};

use hart_gateway::{Gateway, GatewayConfig, ServeOptions};
use hart_profibus::map::{station_cfg, INPUT_LEN, OUTPUT_LEN};
use profirust::phy::ProfibusPhy;
use profirust::{dp, fdl};

/// profirust's PHY on our end of a pseudo-terminal: bytes written go at once, and the
/// PHY reports itself transmitting for as long as they take on a 19.2 kbit/s line.
struct PtyPhy {
    port: hart_serial::Port,
    rx: Vec<u8>,
    tx_until: Option<profirust::time::Instant>,
    /// When the last request was written, until its reply's first bytes are read.
    sent: Option<Instant>,
    /// Request written to the reply's first bytes read: the gateway's response time on
    /// this host (a pseudo-terminal has no line time; min TSDR is included).
    response_times: Vec<Duration>,
}

impl PtyPhy {
    /// Reads what has come, noting when a reply's first bytes came.
    fn fill(&mut self) {
        let mut buf = [0u8; 512];
        while let Ok(n @ 1..) = self.port.read(&mut buf) {
            if let Some(sent) = self.sent.take() {
                self.response_times.push(sent.elapsed());
            }
            self.rx.extend_from_slice(&buf[..n]);
        }
    }
}

impl ProfibusPhy for PtyPhy {
    fn poll_transmission(&mut self, now: profirust::time::Instant) -> bool {
        // A pseudo-terminal carries the reply before the request's line time is over:
        // read it now to time it, hand it over once "transmission" has ended.
        self.fill();
        self.tx_until.is_some_and(|t| now < t)
    }

    fn transmit_data<F, R>(&mut self, now: profirust::time::Instant, f: F) -> R
    where
        F: FnOnce(&mut [u8]) -> (usize, R),
    {
        let mut buf = [0u8; 256];
        let (n, r) = f(&mut buf);
        self.port.write_all(&buf[..n]).unwrap();
        self.sent = Some(Instant::now());
        self.tx_until =
            Some(now + profirust::Baudrate::B19200.bits_to_time(11 * u32::try_from(n).unwrap()));
        r
    }

    fn receive_data<F, R>(&mut self, _now: profirust::time::Instant, f: F) -> R
    where
        F: FnOnce(&[u8]) -> (usize, R),
    {
        self.fill();
        let (drop, r) = f(&self.rx);
        self.rx.drain(..drop);
        r
    }
}

/// The two devices of the plant and a third listed in the configuration that is not
/// on the loop (polling address 5): it never answers.
const DEVICES: usize = 3;
const ANSWERING: usize = 2;

#[test]
fn profirust_exchanges_data_with_the_gateway_over_a_pty() {
    let pty = hart_serial::pty::open().unwrap();
    let path = pty.path.display().to_string();
    let dir = std::env::temp_dir().join(format!("hartkit-profibus-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let plant = dir.join("plant.toml");
    std::fs::write(
        &plant,
        "[[device]]\nprofile = \"pressure\"\npoll = 0\n\n[[device]]\nprofile = \"temperature\"\npoll = 1\n",
    )
    .unwrap();
    let gateway_file = dir.join("gateway.toml");
    std::fs::write(
        &gateway_file,
        format!(
            "[[loop]]\nport = \"sim:{}\"\nscan_to = 2\n\n[[loop.device]]\npoll = 0\n\n[[loop.device]]\npoll = 1\n\n[[loop.device]]\npoll = 5\nname = \"missing\"\n",
            plant.display()
        ),
    )
    .unwrap();
    let opts = ServeOptions {
        config: Some(gateway_file),
        profibus: Some(path.clone()),
        profibus_address: Some(5),
        profibus_baud: Some(19_200),
        ..ServeOptions::default()
    };
    let config = GatewayConfig::from_options(&opts).unwrap();
    let (stop_tx, stop_rx) = std::sync::mpsc::channel::<()>();
    let (p0_tx, p0_rx) = std::sync::mpsc::channel::<usize>();
    let gateway = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        tokio::task::LocalSet::new().block_on(&rt, async move {
            let gw = Gateway::start(config).await.unwrap();
            assert!(
                gw.started().iter().any(|l| l.starts_with("profibus: ")),
                "{:?}",
                gw.started()
            );
            gw.engine().ready().await;
            // The device at polling address 0 drives its loop current (the others are
            // in multidrop mode and refuse fixed current, response code 11).
            let p0 = gw
                .engine()
                .image()
                .snapshot()
                .iter()
                .find(|d| d.polling_address == Some(0))
                .map(|d| d.position)
                .unwrap();
            p0_tx.send(p0).unwrap();
            while stop_rx.try_recv().is_err() {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            gw.stop().await;
        })
    });

    let cfg: &'static [u8] = Box::leak(station_cfg(DEVICES).into_boxed_slice());
    let mut master = dp::DpMaster::new(vec![]);
    let handle = master.add(
        dp::Peripheral::new(
            5,
            dp::PeripheralOptions {
                ident_number: 0x4854,
                user_parameters: Some(&[]),
                config: Some(cfg),
                max_tsdr: 200,
                ..Default::default()
            },
            vec![0u8; DEVICES * INPUT_LEN],
            vec![0u8; DEVICES * OUTPUT_LEN],
        )
        .with_diag_buffer(vec![0u8; 64]),
    );
    let mut fdl = fdl::FdlActiveStation::new(
        fdl::ParametersBuilder::new(2, profirust::Baudrate::B19200)
            // A pseudo-terminal and a busy test machine add milliseconds.
            .slot_bits(2_000)
            .highest_station_address(6)
            .watchdog_timeout(profirust::time::Duration::from_secs(2))
            .build_verified(&master),
    );
    let mut phy = PtyPhy {
        port: pty.ours,
        rx: vec![],
        tx_until: None,
        sent: None,
        response_times: vec![],
    };
    fdl.set_online();
    master.enter_operate();

    let run = |fdl: &mut fdl::FdlActiveStation,
               master: &mut dp::DpMaster,
               phy: &mut PtyPhy,
               secs: u64,
               done: &mut dyn FnMut(&mut dp::DpMaster) -> bool| {
        let end = Instant::now() + Duration::from_secs(secs);
        while Instant::now() < end {
            fdl.poll(profirust::time::Instant::now(), phy, master);
            master.take_last_events();
            if done(master) {
                return true;
            }
            std::thread::sleep(Duration::from_micros(500));
        }
        false
    };
    let module = |m: &mut dp::DpMaster, i: usize| -> Vec<u8> {
        m.get_mut(handle).pi_i()[i * INPUT_LEN..(i + 1) * INPUT_LEN].to_vec()
    };
    let pv = |b: &[u8]| f32::from_be_bytes([b[0], b[1], b[2], b[3]]);

    let ok = run(&mut fdl, &mut master, &mut phy, 30, &mut |m| {
        m.get_mut(handle).is_running() && (0..ANSWERING).all(|i| module(m, i)[23] == 0)
    });
    let state: Vec<Vec<u8>> = (0..DEVICES).map(|i| module(&mut master, i)).collect();
    assert!(ok, "no data exchange with good quality: {state:02X?}");
    let first: Vec<f32> = state.iter().map(|m| pv(m)).collect();
    for (i, m) in state.iter().enumerate().take(ANSWERING) {
        assert!(pv(m).is_finite(), "device {i}: PV {}", pv(m));
        assert_ne!(m[20], 250, "device {i}: PV units known");
    }
    // Values change over time.
    let changed = run(&mut fdl, &mut master, &mut phy, 20, &mut |m| {
        (0..ANSWERING).any(|i| pv(&module(m, i)) != first[i])
    });
    assert!(changed, "no PV changed in 20 s");

    // Loop test on the device at polling address 0: fixed current 12.5 mA with write
    // counter 1; the same on a multidrop device, which refuses it.
    let p0 = p0_rx.recv_timeout(Duration::from_secs(5)).unwrap();
    // The device that does not answer: quality 2 (no reply) in its module, and its bit
    // (module 3) in the station's device-related diagnosis, which the master fetched.
    // (Its quality is 5, waiting for data, until the engine's first poll of it.)
    let no_reply = run(&mut fdl, &mut master, &mut phy, 20, &mut |m| {
        module(m, 2)[23] == 2
    });
    assert!(no_reply, "{:02X?}", module(&mut master, 2));
    let diag_seen = run(&mut fdl, &mut master, &mut phy, 10, &mut |m| {
        m.get_mut(handle).last_diagnostics().is_some_and(|d| {
            d.flags.contains(dp::DiagnosticFlags::EXT_DIAG)
                && d.extended_diagnostics.raw_diag_buffer() == Some(&[0x02, 0b100][..])
        })
    });
    assert!(
        diag_seen,
        "{:?}",
        master.get_mut(handle).last_diagnostics().map(|d| (
            d.flags,
            d.extended_diagnostics.raw_diag_buffer().map(<[u8]>::to_vec)
        ))
    );
    let other = (p0 + 1) % ANSWERING;
    {
        let q = master.get_mut(handle).pi_q_mut();
        for (slot, counter) in [(p0, 1u8), (other, 7)] {
            let o = slot * OUTPUT_LEN;
            q[o] = counter;
            q[o + 2..o + 6].copy_from_slice(&12.5f32.to_be_bytes());
        }
    }
    let done = run(&mut fdl, &mut master, &mut phy, 20, &mut |m| {
        let d = module(m, p0);
        let e = module(m, other);
        d[26] == 1
            && d[27] == 2
            && (f32::from_be_bytes([d[16], d[17], d[18], d[19]]) - 12.5).abs() < 0.01
            && e[26] == 7
            && e[27] == 5
    });
    let (d, e) = (module(&mut master, p0), module(&mut master, other));
    assert!(done, "the loop test did not land: {d:02X?} {e:02X?}");
    // Release: 0 mA with the next counter leaves fixed current mode.
    {
        let q = master.get_mut(handle).pi_q_mut();
        let o = p0 * OUTPUT_LEN;
        q[o] = 2;
        q[o + 2..o + 6].copy_from_slice(&0f32.to_be_bytes());
    }
    let released = run(&mut fdl, &mut master, &mut phy, 20, &mut |m| {
        let d = module(m, p0);
        d[26] == 2 && d[27] == 2
    });
    assert!(released, "{:02X?}", module(&mut master, p0));
    let mut t = phy.response_times.clone();
    t.sort();
    println!(
        "response time over a pty (request written to reply read), {} replies: median {:?}, 95 % {:?}, max {:?}",
        t.len(),
        t[t.len() / 2],
        t[t.len() * 95 / 100],
        t[t.len() - 1]
    );
    let _ = stop_tx.send(());
    gateway.join().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}
