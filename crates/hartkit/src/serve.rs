//! `hartkit sim serve`: simulated field devices on a serial port or a pseudo-terminal,
//! in real time. All devices share the line (multidrop): each hears the requests and
//! the other devices' replies, as on a real loop. The line is `hart_sim::bus`, run on
//! the real clock; this module only opens the port and moves bytes between the two.

use std::os::fd::OwnedFd;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use hart_device::{persist, profiles, Device, Node};
use hart_link::{Micros, TimingProfile};
use hart_sim::bus::{Attach, Bus, BusEvent};

/// One device to run.
#[derive(Debug, Clone)]
pub struct DeviceSpec {
    /// Built-in profile name or profile file.
    pub profile: String,
    /// Polling address.
    pub poll: u8,
}

/// Where the devices talk.
#[derive(Debug, Clone)]
pub enum Port {
    /// A new pseudo-terminal pair; the slave side's path is printed for the host.
    Pty,
    /// A serial port (HART modem) at this baud rate, 8 data bits, odd parity, 1 stop.
    Serial(PathBuf, u32),
}

/// Settings of `hartkit sim serve`.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// The port.
    pub port: Port,
    /// The devices.
    pub devices: Vec<DeviceSpec>,
    /// Keep each device's configuration in `DIR/device-NN.toml`.
    pub state_dir: Option<PathBuf>,
    /// Set every device's write-protect jumper.
    pub write_protect: bool,
    /// Stop after this long (for tests); run until killed otherwise.
    pub run_for: Option<Duration>,
    /// Rules every device breaks on purpose (`--fault`, for testing conformance
    /// testers; see `hart_device::faults`).
    pub faults: Vec<hart_device::faults::Fault>,
}

/// Opens the port: the port to use, and for a PTY the path for the host and the slave
/// side kept open (so the host can close and reopen it). A serial port is 8O1 at its
/// baud rate, this process's only, with damaged characters marked so that each
/// device hears them as damaged, as the host does.
fn open(port: &Port) -> Result<(hart_serial::Port, Option<(String, OwnedFd)>), String> {
    match port {
        Port::Pty => {
            let p = hart_serial::pty::open().map_err(|e| e.to_string())?;
            Ok((p.ours, Some((p.path.to_string_lossy().into_owned(), p.far))))
        }
        Port::Serial(path, baud) => {
            let port = hart_serial::Port::open(
                path,
                &hart_serial::Line::hart(*baud),
                hart_serial::OpenOptions {
                    exclusive: true,
                    mark_errors: true,
                },
            )
            .map_err(|e| e.to_string())?;
            Ok((port, None))
        }
    }
}

/// Builds the devices (from their state files when present).
pub fn build_nodes(opts: &ServeOptions, profile: TimingProfile) -> Result<Vec<(Node, u8)>, String> {
    let mut nodes = vec![];
    for spec in &opts.devices {
        let state = opts
            .state_dir
            .as_ref()
            .map(|d| persist::state_path(d, spec.poll));
        let saved = match &state {
            Some(p) => persist::load(p)?,
            None => None,
        };
        let cfg = match saved {
            Some(c) => c,
            None => {
                let mut c = profiles::load(&spec.profile)?;
                c.polling_address = spec.poll & 0x3F;
                // Each device of a multidrop line gets its own device ID.
                c.identity.device_id =
                    c.identity.device_id.wrapping_add(u32::from(spec.poll)) & 0xFF_FFFF;
                c
            }
        };
        let mut device = Device::new(cfg);
        device.set_write_protect(opts.write_protect);
        let mut node = Node::new(device, profile, 0);
        node.set_faults(&opts.faults);
        if let Some(p) = state {
            if !p.exists() {
                persist::save(&p, node.device.config())
                    .map_err(|e| format!("state file {}: {e}", p.display()))?;
            }
            node.persist_to(p);
        }
        nodes.push((node, spec.poll));
    }
    Ok(nodes)
}

/// Runs until killed (or `run_for`). `announce` receives the lines to print first
/// (`pty: PATH`, then one line per device).
pub fn serve(opts: &ServeOptions, mut announce: impl FnMut(&str)) -> Result<(), String> {
    let profile = match &opts.port {
        Port::Serial(_, baud) if *baud > 1200 => TimingProfile::rs485(*baud),
        _ => TimingProfile::fsk(),
    };
    let nodes = build_nodes(opts, profile)?;
    let (port, pty) = open(&opts.port)?;
    let mut reader = hart_serial::ErrorReader::new(&port);
    if let Some((path, _)) = &pty {
        announce(&format!("pty: {path}"));
    }
    for (n, _) in &nodes {
        let c = n.device.config();
        announce(&format!(
            "device: polling address {} profile {} unique ID {} tag {}{}",
            c.polling_address,
            c.profile,
            n.device.unique_id(),
            c.tag,
            if opts.write_protect {
                " (write protected)"
            } else {
                ""
            }
        ));
    }
    let mut bus = Bus::new(profile, 0, 0.0);
    // The timing of the line is the port's: one device sends at a time, and the others
    // hear its reply when it goes out, as the host does.
    bus.set_ideal(true);
    for (node, _) in nodes {
        bus.add(node, Attach::DEVICE);
    }
    let start = Instant::now();
    let now_us = || start.elapsed().as_micros() as Micros;
    let ct = profile.char_time;
    let mut last_rx: Micros = 0;
    let mut buf = [0u8; 512];
    loop {
        if opts.run_for.is_some_and(|d| start.elapsed() >= d) {
            return Ok(());
        }
        let now = now_us();
        // The line in real time: what a device starts to send goes out on the port at
        // once; the other devices hear it character by character.
        let mut written = Ok(());
        bus.run_until(now, |e| {
            if let BusEvent::Started { bytes, .. } = e {
                if written.is_ok() {
                    written = port.write_all(bytes);
                }
            }
        });
        written.map_err(|e| e.to_string())?;
        let wait_ms = bus
            .next_event()
            .map_or(100, |d| (d.saturating_sub(now) / 1000).clamp(1, 100));
        match port
            .wait(Duration::from_millis(wait_ms))
            .map_err(|e| e.to_string())?
        {
            hart_serial::Ready::Input => {
                let n = match port.read(&mut buf) {
                    Ok(n) => n,
                    Err(e)
                        if e.kind() == std::io::ErrorKind::WouldBlock
                            || e.kind() == std::io::ErrorKind::Interrupted =>
                    {
                        0
                    }
                    Err(e) => return Err(format!("read from {}: {e}", port.path().display())),
                };
                if n == 0 {
                    continue;
                }
                let chars = reader.decode(&port, &buf[..n]);
                let t = now_us();
                // A read returns what arrived since the last one: space the characters
                // back from now, one character time apart, as they came over the line.
                let first = t
                    .saturating_sub((chars.len() as Micros).saturating_sub(1) * ct)
                    .max(last_rx + 1);
                for (i, &(b, flags)) in chars.iter().enumerate() {
                    let at = first + i as Micros * ct;
                    bus.receive_outside(b, flags, at);
                    last_rx = at;
                }
            }
            // The host closed its side of the PTY; wait for it to reopen.
            hart_serial::Ready::HungUp => std::thread::sleep(Duration::from_millis(20)),
            hart_serial::Ready::Nothing => {}
        }
    }
}
