//! `hartkit sim serve`: simulated field devices on a serial port or a pseudo-terminal,
//! in real time. All devices share the line (multidrop): each hears the requests and
//! the other devices' replies, as on a real loop.

use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use hart_device::{persist, profiles, Device, Node};
use hart_link::{Micros, TimingProfile};
use hart_proto::deframer::UartFlags;

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
}

fn errno(what: &str) -> String {
    format!("{what}: {}", std::io::Error::last_os_error())
}

/// Puts `fd` in raw mode; for a serial port also sets the baud rate and 8O1.
fn configure(fd: i32, baud: Option<u32>) -> Result<(), String> {
    // SAFETY: termios is plain data; tcgetattr fills it for a valid descriptor.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    if unsafe { libc::tcgetattr(fd, &mut t) } != 0 {
        return Err(errno("tcgetattr"));
    }
    unsafe { libc::cfmakeraw(&mut t) };
    if let Some(b) = baud {
        let speed = match b {
            300 => libc::B300,
            600 => libc::B600,
            1200 => libc::B1200,
            2400 => libc::B2400,
            4800 => libc::B4800,
            9600 => libc::B9600,
            19200 => libc::B19200,
            38400 => libc::B38400,
            57600 => libc::B57600,
            115200 => libc::B115200,
            _ => return Err(format!("baud rate {b} is not supported (300-115200)")),
        };
        unsafe {
            libc::cfsetispeed(&mut t, speed);
            libc::cfsetospeed(&mut t, speed);
        }
        t.c_cflag &= !(libc::CSIZE | libc::CSTOPB);
        t.c_cflag |= libc::CS8 | libc::PARENB | libc::PARODD | libc::CLOCAL | libc::CREAD;
        // Characters with parity errors are delivered as 0x00 (INPCK without PARMRK).
        t.c_iflag |= libc::INPCK;
    }
    t.c_cc[libc::VMIN] = 0;
    t.c_cc[libc::VTIME] = 0;
    if unsafe { libc::tcsetattr(fd, libc::TCSANOW, &t) } != 0 {
        // A pseudo-terminal has no parity; some C libraries refuse the request then.
        t.c_cflag &= !(libc::PARENB | libc::PARODD);
        t.c_iflag &= !libc::INPCK;
        if unsafe { libc::tcsetattr(fd, libc::TCSANOW, &t) } != 0 {
            return Err(errno("tcsetattr"));
        }
    }
    Ok(())
}

/// Opens the port: the descriptor to use, and for a PTY the path for the host and the
/// slave side kept open (so the host can close and reopen it).
fn open(port: &Port) -> Result<(OwnedFd, Option<(String, OwnedFd)>), String> {
    match port {
        Port::Pty => {
            let (master, slave, path) = crate::pty::open()?;
            configure(slave.as_raw_fd(), None)?;
            configure(master.as_raw_fd(), None)?;
            Ok((master, Some((path, slave))))
        }
        Port::Serial(path, baud) => {
            let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes())
                .map_err(|_| "serial path contains a NUL byte".to_string())?;
            let fd =
                unsafe { libc::open(c.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK) };
            if fd < 0 {
                return Err(format!(
                    "{}: {}; check the path and that you may open it (dialout group)",
                    path.display(),
                    std::io::Error::last_os_error()
                ));
            }
            let fd = unsafe { OwnedFd::from_raw_fd(fd) };
            configure(fd.as_raw_fd(), Some(*baud))?;
            Ok((fd, None))
        }
    }
}

fn write_all(fd: i32, mut bytes: &[u8]) -> Result<(), String> {
    while !bytes.is_empty() {
        let n = unsafe { libc::write(fd, bytes.as_ptr().cast(), bytes.len()) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::WouldBlock
                || e.kind() == std::io::ErrorKind::Interrupted
            {
                std::thread::sleep(Duration::from_millis(1));
                continue;
            }
            return Err(format!("write: {e}"));
        }
        bytes = &bytes[n as usize..];
    }
    Ok(())
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
    let mut nodes = build_nodes(opts, profile)?;
    let (fd, pty) = open(&opts.port)?;
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
    let start = Instant::now();
    let now_us = || start.elapsed().as_micros() as Micros;
    let ct = profile.char_time;
    let mut last_rx: Micros = 0;
    let mut buf = [0u8; 512];
    // A transmission in progress: who sent it and when its last character leaves.
    let mut sending: Option<(usize, Micros)> = None;
    loop {
        if opts.run_for.is_some_and(|d| start.elapsed() >= d) {
            return Ok(());
        }
        let now = now_us();
        if let Some((k, end)) = sending {
            if now >= end {
                nodes[k].0.transmitted(end);
                sending = None;
            }
        }
        if sending.is_none() {
            for k in 0..nodes.len() {
                if let Some(bytes) = nodes[k].0.poll(now) {
                    write_all(fd.as_raw_fd(), &bytes)?;
                    // The other devices on the line hear it, one character at a time.
                    for (j, (other, _)) in nodes.iter_mut().enumerate() {
                        if j != k {
                            for (i, &b) in bytes.iter().enumerate() {
                                other.receive(b, UartFlags::OK, now + (i as Micros + 1) * ct);
                            }
                        }
                    }
                    sending = Some((k, now + bytes.len() as Micros * ct));
                    break;
                }
            }
        }
        let deadline = nodes.iter().filter_map(|(n, _)| n.next_deadline(now)).min();
        let deadline = match sending {
            Some((_, end)) => Some(deadline.map_or(end, |d| d.min(end))),
            None => deadline,
        };
        let wait_ms = deadline.map_or(100, |d| (d.saturating_sub(now) / 1000).clamp(0, 100)) as i32;
        let mut pfd = libc::pollfd {
            fd: fd.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        let r = unsafe { libc::poll(&mut pfd, 1, wait_ms.max(1)) };
        if r < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            return Err(format!("poll: {e}"));
        }
        if r > 0 && pfd.revents & libc::POLLIN != 0 {
            let n = unsafe { libc::read(fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
            if n > 0 {
                let n = n as usize;
                let t = now_us();
                // A read returns what arrived since the last one: space the characters
                // back from now, one character time apart, as they came over the line.
                let first = t.saturating_sub((n as Micros - 1) * ct).max(last_rx + 1);
                for (i, &b) in buf[..n].iter().enumerate() {
                    let at = first + i as Micros * ct;
                    for (node, _) in &mut nodes {
                        node.receive(b, UartFlags::OK, at);
                    }
                    last_rx = at;
                }
            } else if n < 0 {
                let e = std::io::Error::last_os_error();
                if e.kind() != std::io::ErrorKind::WouldBlock
                    && e.kind() != std::io::ErrorKind::Interrupted
                {
                    return Err(format!("read: {e}"));
                }
            }
        } else if r > 0 && pfd.revents & (libc::POLLHUP | libc::POLLERR) != 0 {
            // The host closed its side of the PTY; wait for it to reopen.
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}
