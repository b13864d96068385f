//! # hart-serial
//!
//! Serial lines and pseudo-terminals for hartkit, set up in one place: the host's
//! HART modem and RS-485 transports, the simulated devices of `hartkit sim serve`, the
//! well network's bus, and any front end on a serial line open their ports here.
//!
//! * [`Port::open`]: a serial port in raw mode at a speed and framing ([`Line`]:
//!   8O1 for HART, 8E1, 8N1), optionally for this process only (exclusive), with
//!   damaged characters marked by the line discipline (`PARMRK`) so that they can be
//!   told from good ones.
//! * [`ErrorReader`]: turns what a port gives into characters with their
//!   [`UartFlags`] (parity, framing, overrun), from the marks and, where the driver
//!   keeps them, its error counters: the same report on every port.
//! * [`pty`]: pseudo-terminal pairs, raw, for simulated devices and buses.
//! * RTS keying, the modem lines (DCD as carrier detect), hang-up detection.
//! * With the feature `tokio`, [`aio`]: the one registration of a port with tokio's
//!   reactor ([`aio::AsyncPort`]), writes that wait without blocking, and a reader task
//!   that timestamps what it reads ([`aio::Reader`]).
//!
//! Built on `nix`'s termios and ioctl wrappers; no other crate of hartkit touches
//! terminal settings.

use std::io;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, OwnedFd, RawFd};
use std::path::{Path, PathBuf};

use hart_proto::deframer::UartFlags;
use nix::fcntl::{open, OFlag};
use nix::sys::stat::Mode;
use nix::sys::termios::{
    cfmakeraw, cfsetspeed, tcdrain, tcgetattr, tcsetattr, BaudRate, ControlFlags, InputFlags,
    SetArg, SpecialCharacterIndices,
};

#[cfg(feature = "tokio")]
pub mod aio;
pub mod pty;

/// Parity of a character.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parity {
    /// None.
    None,
    /// Even (PROFIBUS, Modbus RTU's default).
    Even,
    /// Odd (HART).
    Odd,
}

/// Speed and framing of a line: 8 data bits, a parity, 1 or 2 stop bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Line {
    /// Bit rate, one of [`BAUD_RATES`].
    pub baud: u32,
    /// Parity.
    pub parity: Parity,
    /// Stop bits: 1 or 2.
    pub stop_bits: u8,
}

impl Line {
    /// HART's framing at `baud`: 8 data bits, odd parity, 1 stop bit (8O1).
    pub fn hart(baud: u32) -> Self {
        Line {
            baud,
            parity: Parity::Odd,
            stop_bits: 1,
        }
    }

    /// 8 data bits, even parity, 1 stop bit (8E1).
    pub fn even(baud: u32) -> Self {
        Line {
            baud,
            parity: Parity::Even,
            stop_bits: 1,
        }
    }

    /// 8 data bits, no parity, 1 stop bit (8N1).
    pub fn none(baud: u32) -> Self {
        Line {
            baud,
            parity: Parity::None,
            stop_bits: 1,
        }
    }

    /// `8O1`, `8E2`, ...
    pub fn framing(&self) -> String {
        let p = match self.parity {
            Parity::None => 'N',
            Parity::Even => 'E',
            Parity::Odd => 'O',
        };
        format!("8{p}{}", self.stop_bits)
    }
}

/// Bit rates a port can be set to.
pub const BAUD_RATES: [u32; 10] = [
    300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200,
];

/// Bit rates outside the termios table that a port is set to by its exact value
/// (Linux's `termios2` with `BOTHER`): PROFIBUS's 45.45 and 93.75 kbit/s. The UART
/// (or USB adapter) picks its nearest divisor; an FTDI chip makes 93 750 exactly and
/// 45 455 (0.01 % off).
#[cfg(target_os = "linux")]
pub const CUSTOM_BAUD_RATES: [u32; 2] = [45_450, 93_750];
/// Bit rates outside the termios table (none on this system).
#[cfg(not(target_os = "linux"))]
pub const CUSTOM_BAUD_RATES: [u32; 0] = [];

fn baud_rate(baud: u32) -> io::Result<BaudRate> {
    Ok(match baud {
        300 => BaudRate::B300,
        600 => BaudRate::B600,
        1200 => BaudRate::B1200,
        2400 => BaudRate::B2400,
        4800 => BaudRate::B4800,
        9600 => BaudRate::B9600,
        19200 => BaudRate::B19200,
        38400 => BaudRate::B38400,
        57600 => BaudRate::B57600,
        115200 => BaudRate::B115200,
        _ => {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "baud rate {baud} not supported (give one of {BAUD_RATES:?} or {CUSTOM_BAUD_RATES:?})"
                ),
            ))
        }
    })
}

fn errno(what: String, e: nix::Error) -> io::Error {
    let e = io::Error::from(e);
    io::Error::new(e.kind(), format!("{what}: {e}"))
}

/// How to open a port.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct OpenOptions {
    /// This process only (`TIOCEXCL`): another program that opens the port later is
    /// refused, instead of both reading half of the characters.
    pub exclusive: bool,
    /// Mark damaged characters in the input ([`ErrorReader`] decodes them); off,
    /// they are dropped by the driver.
    pub mark_errors: bool,
}

/// An open serial port or pseudo-terminal, non-blocking, in raw mode.
#[derive(Debug)]
pub struct Port {
    fd: OwnedFd,
    path: PathBuf,
    /// The line discipline marks damaged characters (`PARMRK` took effect).
    marks: bool,
}

impl Port {
    /// Opens `path` and sets it to `line` (raw, no echo, reads return at once).
    pub fn open(path: &Path, line: &Line, opts: OpenOptions) -> io::Result<Port> {
        let fd = open(
            path,
            OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_NONBLOCK | OFlag::O_CLOEXEC,
            Mode::empty(),
        )
        .map_err(|e| {
            let io = io::Error::from(e);
            io::Error::new(
                io.kind(),
                format!(
                    "cannot open {}: {io}; check the path and your permission (dialout group)",
                    path.display()
                ),
            )
        })?;
        let mut port = Port {
            fd,
            path: path.to_path_buf(),
            marks: false,
        };
        if opts.exclusive {
            port.exclusive()?;
        }
        port.marks = port.configure(Some(line), opts.mark_errors)?;
        Ok(port)
    }

    /// Takes a descriptor already open (a pseudo-terminal's end) and puts it in raw
    /// mode, non-blocking; with `line`, at that speed and framing too.
    pub fn from_fd(
        fd: OwnedFd,
        path: &Path,
        line: Option<&Line>,
        opts: OpenOptions,
    ) -> io::Result<Port> {
        let mut port = Port {
            fd,
            path: path.to_path_buf(),
            marks: false,
        };
        port.set_nonblocking()?;
        port.marks = port.configure(line, opts.mark_errors)?;
        Ok(port)
    }

    /// A second handle on the same port (a duplicated descriptor), for a reader and a
    /// writer on two threads.
    pub fn try_clone(&self) -> io::Result<Port> {
        Ok(Port {
            fd: self.fd.try_clone()?,
            path: self.path.clone(),
            marks: self.marks,
        })
    }

    /// The descriptor, for a caller that does its own I/O on it from now on.
    pub fn into_fd(self) -> OwnedFd {
        self.fd
    }

    /// The path it was opened by.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether the input carries marks of damaged characters (decode them with an
    /// [`ErrorReader`]): serial ports and pseudo-terminals opened with
    /// [`OpenOptions::mark_errors`].
    pub fn marks_errors(&self) -> bool {
        self.marks
    }

    fn set_nonblocking(&self) -> io::Result<()> {
        use nix::fcntl::{fcntl, FcntlArg};
        let fl = fcntl(&self.fd, FcntlArg::F_GETFL).map_err(|e| errno("F_GETFL".into(), e))?;
        let fl = OFlag::from_bits_truncate(fl) | OFlag::O_NONBLOCK;
        fcntl(&self.fd, FcntlArg::F_SETFL(fl)).map_err(|e| errno("F_SETFL".into(), e))?;
        Ok(())
    }

    /// Raw mode, and with `line` its speed and framing; returns whether `PARMRK` took
    /// effect.
    fn configure(&self, line: Option<&Line>, mark_errors: bool) -> io::Result<bool> {
        let what = |call: &str| format!("{call} on {}", self.path.display());
        let mut t = tcgetattr(&self.fd).map_err(|e| errno(what("tcgetattr"), e))?;
        cfmakeraw(&mut t);
        let custom = line
            .map(|l| l.baud)
            .filter(|b| CUSTOM_BAUD_RATES.contains(b));
        if let Some(line) = line {
            // A custom rate is set after the rest (below); 38400 until then.
            let rate = match custom {
                Some(_) => BaudRate::B38400,
                None => baud_rate(line.baud)?,
            };
            cfsetspeed(&mut t, rate).map_err(|e| errno(what("cfsetspeed"), e))?;
            t.control_flags &= !(ControlFlags::CSIZE
                | ControlFlags::CSTOPB
                | ControlFlags::PARENB
                | ControlFlags::PARODD);
            t.control_flags |= ControlFlags::CS8 | ControlFlags::CLOCAL | ControlFlags::CREAD;
            if line.stop_bits == 2 {
                t.control_flags |= ControlFlags::CSTOPB;
            }
            match line.parity {
                Parity::None => {}
                Parity::Even => t.control_flags |= ControlFlags::PARENB,
                Parity::Odd => t.control_flags |= ControlFlags::PARENB | ControlFlags::PARODD,
            }
            if line.parity != Parity::None {
                t.input_flags |= InputFlags::INPCK;
            }
        }
        if mark_errors {
            // Mark damaged characters in the input (0xFF 0x00 X) instead of passing
            // them on as 0x00 or dropping them; a real 0xFF then arrives doubled. A
            // break is marked too (BRKINT and IGNBRK off, as cfmakeraw leaves them).
            t.input_flags |= InputFlags::PARMRK;
            t.input_flags &= !(InputFlags::IGNPAR | InputFlags::ISTRIP);
        }
        t.control_chars[SpecialCharacterIndices::VMIN as usize] = 0;
        t.control_chars[SpecialCharacterIndices::VTIME as usize] = 0;
        if tcsetattr(&self.fd, SetArg::TCSANOW, &t).is_err() {
            // A pseudo-terminal has no parity; some C libraries refuse the request then.
            t.control_flags &= !(ControlFlags::PARENB | ControlFlags::PARODD);
            t.input_flags &= !InputFlags::INPCK;
            tcsetattr(&self.fd, SetArg::TCSANOW, &t).map_err(|e| errno(what("tcsetattr"), e))?;
        }
        if let Some(baud) = custom {
            self.set_custom_speed(baud)?;
        }
        // tcsetattr succeeds when any of the settings took: see what the port has.
        let now = tcgetattr(&self.fd).map_err(|e| errno(what("tcgetattr"), e))?;
        Ok(now.input_flags.contains(InputFlags::PARMRK))
    }

    /// Sets a rate outside the termios table by its value (`termios2`, `BOTHER`).
    #[cfg(target_os = "linux")]
    fn set_custom_speed(&self, baud: u32) -> io::Result<()> {
        let mut t = self.termios2()?;
        t.c_cflag &= !libc::CBAUD;
        t.c_cflag |= libc::BOTHER;
        t.c_ispeed = baud;
        t.c_ospeed = baud;
        nix::ioctl_write_ptr_bad!(tcsets2, libc::TCSETS2, libc::termios2);
        // SAFETY: TCSETS2 reads a termios2 from the pointer, which is valid.
        unsafe { tcsets2(self.fd.as_raw_fd(), &t) }.map_err(|e| {
            errno(
                format!(
                    "setting {baud} bit/s on {} (the driver may not take custom rates)",
                    self.path.display()
                ),
                e,
            )
        })?;
        let now = self.termios2()?.c_ospeed;
        if now != baud {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "{} runs at {now} bit/s when asked for {baud}: its driver cannot make that rate",
                    self.path.display()
                ),
            ));
        }
        Ok(())
    }

    #[cfg(not(target_os = "linux"))]
    fn set_custom_speed(&self, baud: u32) -> io::Result<()> {
        baud_rate(baud).map(|_| ())
    }

    #[cfg(target_os = "linux")]
    fn termios2(&self) -> io::Result<libc::termios2> {
        nix::ioctl_read_bad!(tcgets2, libc::TCGETS2, libc::termios2);
        // SAFETY: all-zero bytes are a valid termios2 (integers and a byte array).
        let mut t: libc::termios2 = unsafe { std::mem::zeroed() };
        // SAFETY: TCGETS2 writes a termios2 to the pointer, which is valid.
        unsafe { tcgets2(self.fd.as_raw_fd(), &mut t) }
            .map_err(|e| errno(format!("TCGETS2 on {}", self.path.display()), e))?;
        Ok(t)
    }

    /// The speed and framing the port has now (what the driver took).
    pub fn line(&self) -> io::Result<Line> {
        let t = tcgetattr(&self.fd)
            .map_err(|e| errno(format!("tcgetattr on {}", self.path.display()), e))?;
        // A rate set by value (BOTHER) is none of nix's BaudRate values: read it from
        // termios2 (nix's cfgetospeed would fail on it).
        #[cfg(target_os = "linux")]
        let custom = self
            .termios2()
            .ok()
            .filter(|t2| t2.c_cflag & libc::CBAUD == libc::BOTHER)
            .map(|t2| t2.c_ospeed);
        #[cfg(not(target_os = "linux"))]
        let custom: Option<u32> = None;
        let baud = match custom {
            Some(b) => b,
            None => {
                let speed = nix::sys::termios::cfgetospeed(&t);
                BAUD_RATES
                    .iter()
                    .copied()
                    .find(|&b| baud_rate(b).is_ok_and(|r| r == speed))
                    .unwrap_or(0)
            }
        };
        let c = t.control_flags;
        let parity = match (
            c.contains(ControlFlags::PARENB),
            c.contains(ControlFlags::PARODD),
        ) {
            (false, _) => Parity::None,
            (true, false) => Parity::Even,
            (true, true) => Parity::Odd,
        };
        Ok(Line {
            baud,
            parity,
            stop_bits: if c.contains(ControlFlags::CSTOPB) {
                2
            } else {
                1
            },
        })
    }

    fn exclusive(&self) -> io::Result<()> {
        nix::ioctl_none_bad!(tiocexcl, libc::TIOCEXCL);
        // SAFETY: TIOCEXCL takes no argument.
        unsafe { tiocexcl(self.fd.as_raw_fd()) }
            .map(|_| ())
            .map_err(|e| errno(format!("exclusive open of {}", self.path.display()), e))
    }

    /// Reads what is there now: `WouldBlock` when nothing is; 0 bytes may mean a
    /// hang-up (see [`Port::hung_up`]).
    pub fn read(&self, buf: &mut [u8]) -> io::Result<usize> {
        nix::unistd::read(&self.fd, buf).map_err(io::Error::from)
    }

    /// Writes what the driver takes now (`WouldBlock` when its buffer is full).
    pub fn write(&self, bytes: &[u8]) -> io::Result<usize> {
        nix::unistd::write(&self.fd, bytes).map_err(io::Error::from)
    }

    /// Writes all of `bytes`, waiting (1 ms at a time) while the driver's buffer is
    /// full. For threads that may block; async callers write through their reactor.
    pub fn write_all(&self, bytes: &[u8]) -> io::Result<()> {
        let mut rest = bytes;
        while !rest.is_empty() {
            match self.write(rest) {
                Ok(n) => rest = &rest[n..],
                Err(e)
                    if e.kind() == io::ErrorKind::WouldBlock
                        || e.kind() == io::ErrorKind::Interrupted =>
                {
                    std::thread::sleep(std::time::Duration::from_millis(1))
                }
                Err(e) => {
                    return Err(io::Error::new(
                        e.kind(),
                        format!("write to {}: {e}", self.path.display()),
                    ))
                }
            }
        }
        Ok(())
    }

    /// Waits up to `timeout` for input: what the port has then.
    pub fn wait(&self, timeout: std::time::Duration) -> io::Result<Ready> {
        Ok(wait_any(&[self], timeout)?[0])
    }

    /// Waits until the UART has sent everything written (a pseudo-terminal returns at
    /// once).
    pub fn drain(&self) {
        let _ = tcdrain(&self.fd);
    }

    /// Whether the port reports a hang-up or an error now: a pseudo-terminal whose
    /// other end closed, a modem that dropped the line, an adapter unplugged.
    pub fn hung_up(&self) -> bool {
        use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
        let mut fds = [PollFd::new(self.fd.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, PollTimeout::ZERO) {
            Ok(n) if n > 0 => fds[0]
                .revents()
                .is_some_and(|r| r.intersects(PollFlags::POLLHUP | PollFlags::POLLERR)),
            _ => false,
        }
    }

    /// Sets (`true`) or clears the RTS line.
    pub fn set_rts(&self, on: bool) -> io::Result<()> {
        nix::ioctl_write_ptr_bad!(tiocmbis, libc::TIOCMBIS, libc::c_int);
        nix::ioctl_write_ptr_bad!(tiocmbic, libc::TIOCMBIC, libc::c_int);
        let bits: libc::c_int = libc::TIOCM_RTS;
        // SAFETY: TIOCMBIS/TIOCMBIC read one c_int.
        let r = unsafe {
            if on {
                tiocmbis(self.fd.as_raw_fd(), &bits)
            } else {
                tiocmbic(self.fd.as_raw_fd(), &bits)
            }
        };
        r.map(|_| ())
            .map_err(|e| errno(format!("RTS of {}", self.path.display()), e))
    }

    /// The modem control lines now.
    pub fn modem_lines(&self) -> io::Result<ModemLines> {
        nix::ioctl_read_bad!(tiocmget, libc::TIOCMGET, libc::c_int);
        let mut bits: libc::c_int = 0;
        // SAFETY: TIOCMGET writes one c_int.
        unsafe { tiocmget(self.fd.as_raw_fd(), &mut bits) }.map_err(|e| {
            errno(
                format!(
                    "cannot read the modem lines of {} (pseudo-terminals and most RS-485 \
                     adapters have none)",
                    self.path.display()
                ),
                e,
            )
        })?;
        Ok(ModemLines {
            carrier: bits & libc::TIOCM_CAR != 0,
            cts: bits & libc::TIOCM_CTS != 0,
            dsr: bits & libc::TIOCM_DSR != 0,
            rts: bits & libc::TIOCM_RTS != 0,
        })
    }

    /// The driver's error counters, where it keeps them (`TIOCGICOUNT`, Linux; not
    /// USB adapters without the call, not pseudo-terminals).
    pub fn error_counts(&self) -> Option<ErrorCounts> {
        error_counts(self.fd.as_raw_fd())
    }
}

impl AsRawFd for Port {
    fn as_raw_fd(&self) -> RawFd {
        self.fd.as_raw_fd()
    }
}

impl AsFd for Port {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.fd.as_fd()
    }
}

/// What a port has after a wait.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ready {
    /// Input to read.
    Input,
    /// The line hung up (the other end of a pseudo-terminal closed, the modem dropped
    /// the line, the adapter is gone).
    HungUp,
    /// Nothing.
    Nothing,
}

/// Waits up to `timeout` until any of `ports` has input or hangs up: what each has
/// then. An interrupted wait returns with nothing.
pub fn wait_any(ports: &[&Port], timeout: std::time::Duration) -> io::Result<Vec<Ready>> {
    use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
    let mut fds: Vec<PollFd<'_>> = ports
        .iter()
        .map(|p| PollFd::new(p.fd.as_fd(), PollFlags::POLLIN))
        .collect();
    let ms = u16::try_from(timeout.as_millis()).unwrap_or(u16::MAX);
    match poll(&mut fds, PollTimeout::from(ms)) {
        Ok(_) => {}
        Err(nix::errno::Errno::EINTR) => return Ok(vec![Ready::Nothing; ports.len()]),
        Err(e) => return Err(errno("poll".into(), e)),
    }
    Ok(fds
        .iter()
        .map(|f| match f.revents() {
            Some(r) if r.contains(PollFlags::POLLIN) => Ready::Input,
            Some(r) if r.intersects(PollFlags::POLLHUP | PollFlags::POLLERR) => Ready::HungUp,
            _ => Ready::Nothing,
        })
        .collect())
}

/// What a terminal does with damaged input now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InputChecks {
    /// Parity is checked (`INPCK`).
    pub parity_checked: bool,
    /// Damaged characters are marked (`PARMRK`).
    pub marked: bool,
    /// Damaged characters are dropped (`IGNPAR`).
    pub ignored: bool,
}

/// What the terminal open at `fd` does with damaged input (for checks and
/// diagnostics; a [`Port`] reports [`Port::marks_errors`]).
pub fn input_checks(fd: impl AsFd) -> io::Result<InputChecks> {
    let t = tcgetattr(fd).map_err(|e| errno("tcgetattr".into(), e))?;
    Ok(InputChecks {
        parity_checked: t.input_flags.contains(InputFlags::INPCK),
        marked: t.input_flags.contains(InputFlags::PARMRK),
        ignored: t.input_flags.contains(InputFlags::IGNPAR),
    })
}

/// The modem control lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModemLines {
    /// DCD: the modem hears a carrier.
    pub carrier: bool,
    /// CTS.
    pub cts: bool,
    /// DSR.
    pub dsr: bool,
    /// RTS as set.
    pub rts: bool,
}

/// Error counts of a UART: parity, framing (breaks included), overruns (in the
/// hardware and in the kernel's buffer).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ErrorCounts {
    /// Parity errors.
    pub parity: u32,
    /// Framing errors and breaks.
    pub framing: u32,
    /// Overruns.
    pub overrun: u32,
}

/// The driver's error counters (`struct serial_icounter_struct`, Linux).
#[cfg(target_os = "linux")]
#[repr(C)]
#[derive(Default, Clone, Copy)]
struct IcounterRaw {
    cts: libc::c_int,
    dsr: libc::c_int,
    rng: libc::c_int,
    dcd: libc::c_int,
    rx: libc::c_int,
    tx: libc::c_int,
    frame: libc::c_int,
    overrun: libc::c_int,
    parity: libc::c_int,
    brk: libc::c_int,
    buf_overrun: libc::c_int,
    reserved: [libc::c_int; 9],
}

fn error_counts(fd: RawFd) -> Option<ErrorCounts> {
    #[cfg(target_os = "linux")]
    {
        nix::ioctl_read_bad!(tiocgicount, libc::TIOCGICOUNT, IcounterRaw);
        let mut c = IcounterRaw::default();
        // SAFETY: TIOCGICOUNT fills a struct serial_icounter_struct, which IcounterRaw
        // mirrors.
        unsafe { tiocgicount(fd, &mut c) }.ok()?;
        Some(ErrorCounts {
            parity: c.parity as u32,
            framing: c.frame.wrapping_add(c.brk) as u32,
            overrun: c.overrun.wrapping_add(c.buf_overrun) as u32,
        })
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = fd;
        None
    }
}

/// Decodes the input of a port configured with `PARMRK` and `INPCK`, without `IGNPAR`
/// (how [`Port::open`] sets a port with [`OpenOptions::mark_errors`]): the line
/// discipline marks a character received with a parity or framing error as
/// `0xFF 0x00 X`, and doubles a real `0xFF` (every HART preamble) to `0xFF 0xFF`; any
/// other byte is itself.
///
/// The mark does not say which error it was: a marked `0x00` (what a break or a lost
/// stop bit gives) counts as a framing error, any other marked character as a parity
/// error. [`ErrorReader`] corrects this from the driver's error counters where the
/// driver keeps them. An escape split over two reads is carried over to the next call.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ParmrkDecoder {
    /// Bytes of an unfinished escape: 0 none, 1 after `0xFF`, 2 after `0xFF 0x00`.
    held: u8,
}

impl ParmrkDecoder {
    /// A decoder between characters.
    pub fn new() -> Self {
        Self::default()
    }

    /// Decodes `raw` (as read from the port) onto `out`.
    pub fn decode(&mut self, raw: &[u8], out: &mut Vec<(u8, UartFlags)>) {
        for &b in raw {
            match (self.held, b) {
                (0, 0xFF) => self.held = 1,
                (0, b) => out.push((b, UartFlags::OK)),
                (1, 0xFF) => {
                    self.held = 0;
                    out.push((0xFF, UartFlags::OK));
                }
                (1, 0x00) => self.held = 2,
                (1, b) => {
                    // Not an escape the line discipline makes: pass both through.
                    self.held = 0;
                    out.push((0xFF, UartFlags::OK));
                    out.push((b, UartFlags::OK));
                }
                (_, b) => {
                    self.held = 0;
                    let flags = UartFlags {
                        parity: b != 0,
                        framing: b == 0,
                        overrun: false,
                    };
                    out.push((b, flags));
                }
            }
        }
    }

    /// True while part of an escape has been read and the rest has not.
    pub fn in_escape(&self) -> bool {
        self.held != 0
    }
}

/// Turns what a [`Port`] gives into characters with their [`UartFlags`]: escapes
/// decoded when the port marks errors, error kinds and overruns taken from the
/// driver's counters where it keeps them. One per port, fed every read in order.
#[derive(Debug, Clone)]
pub struct ErrorReader {
    marks: bool,
    decoder: ParmrkDecoder,
    /// The driver's error counters as far as they have been accounted for.
    counts: Option<ErrorCounts>,
    /// An overrun was counted before any character came to carry it.
    overrun_pending: bool,
}

impl ErrorReader {
    /// A reader for `port`, from its error counts now.
    pub fn new(port: &Port) -> Self {
        ErrorReader {
            marks: port.marks_errors(),
            decoder: ParmrkDecoder::new(),
            counts: port.error_counts(),
            overrun_pending: false,
        }
    }

    /// The characters in `raw`, just read from `port`.
    pub fn decode(&mut self, port: &Port, raw: &[u8]) -> Vec<(u8, UartFlags)> {
        let mut out = Vec::with_capacity(raw.len());
        if !self.marks {
            out.extend(raw.iter().map(|&b| (b, UartFlags::OK)));
            return out;
        }
        self.decoder.decode(raw, &mut out);
        let Some(mut seen) = self.counts else {
            return out;
        };
        let Some(now) = port.error_counts() else {
            return out;
        };
        for (_, f) in out.iter_mut().filter(|(_, f)| f.parity || f.framing) {
            // The counters include every error received so far; each marked character
            // takes one count of the kind that has counts left.
            if now.parity.wrapping_sub(seen.parity) as i32 > 0 {
                seen.parity = seen.parity.wrapping_add(1);
                (f.parity, f.framing) = (true, false);
            } else if now.framing.wrapping_sub(seen.framing) as i32 > 0 {
                seen.framing = seen.framing.wrapping_add(1);
                (f.parity, f.framing) = (false, true);
            }
        }
        if now.overrun != seen.overrun {
            seen.overrun = now.overrun;
            self.overrun_pending = true;
        }
        if self.overrun_pending {
            if let Some((_, f)) = out.first_mut() {
                // Characters were lost somewhere before the end of this read.
                f.overrun = true;
                self.overrun_pending = false;
            }
        }
        self.counts = Some(seen);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_decode_and_split_across_reads() {
        let mut d = ParmrkDecoder::new();
        let mut out = vec![];
        d.decode(&[0xFF, 0xFF, 0x82, 0xFF], &mut out);
        assert!(d.in_escape());
        d.decode(&[0x00, 0x41, 0xFF, 0x00, 0x00, 0xFF, 0x7E], &mut out);
        let bytes: Vec<u8> = out.iter().map(|c| c.0).collect();
        assert_eq!(bytes, vec![0xFF, 0x82, 0x41, 0x00, 0xFF, 0x7E]);
        assert!(out[2].1.parity && !out[2].1.framing);
        assert!(out[3].1.framing && !out[3].1.parity);
        assert!(!out[4].1.any() && !out[5].1.any());
    }

    #[test]
    fn framings_name_themselves() {
        assert_eq!(Line::hart(1200).framing(), "8O1");
        assert_eq!(Line::even(19200).framing(), "8E1");
        assert_eq!(
            Line {
                stop_bits: 2,
                ..Line::none(9600)
            }
            .framing(),
            "8N2"
        );
        assert!(baud_rate(45_450).is_err());
    }
}
