//! Ports under tokio (feature `tokio`): the one place a serial port's descriptor is
//! registered with the reactor, for every async user (the host's modem and RS-485
//! transports, Modbus RTU, PROFIBUS DP).
//!
//! * [`AsyncPort`]: a [`Port`] whose reads wait for input; a hang-up is an error, not
//!   silence forever.
//! * [`Port::write_all_async`]: writes everything, waiting while the driver's buffer is
//!   full (at most [`WRITE_PATIENCE`]).
//! * [`Reader`]: a task that reads a port as bytes come and timestamps each read, so
//!   that the times stay right while its owner is busy; it ends when dropped.

use std::io::{self, ErrorKind};
use std::time::{Duration, Instant};

use tokio::io::unix::AsyncFd;
use tokio::sync::mpsc;

use crate::Port;

/// Longest a write waits while the driver's buffer stays full before it fails.
pub const WRITE_PATIENCE: Duration = Duration::from_secs(1);

/// A port registered with tokio's reactor.
#[derive(Debug)]
pub struct AsyncPort {
    fd: AsyncFd<Port>,
}

impl AsyncPort {
    /// Registers `port` with the reactor of the runtime this is called in (which must
    /// have I/O enabled).
    pub fn new(port: Port) -> io::Result<AsyncPort> {
        let path = port.path().display().to_string();
        // SAFETY: the port owns its descriptor; it stays open and refers to the same
        // port until the AsyncFd (which owns the port) is dropped.
        let fd = unsafe { AsyncFd::register(port) }.map_err(|e| {
            let e = io::Error::from(e);
            io::Error::new(
                e.kind(),
                format!("cannot wait for input on {path}: {e} (a tokio runtime with I/O enabled is needed)"),
            )
        })?;
        Ok(AsyncPort { fd })
    }

    /// The port, for what does not wait (RTS, modem lines, error counters, drain).
    pub fn get_ref(&self) -> &Port {
        self.fd.get_ref()
    }

    /// Waits for input and reads it into `buf`: at least one byte. A hang-up (the
    /// other end of a pseudo-terminal closed, the modem dropped the line, the adapter
    /// is gone) is an error of kind `BrokenPipe`; any other failure names the port.
    /// Cancel-safe: nothing is read unless it returns.
    pub async fn read(&self, buf: &mut [u8]) -> io::Result<usize> {
        let port = self.fd.get_ref();
        loop {
            let mut guard = self.fd.readable().await?;
            match port.read(buf) {
                Ok(0) if port.hung_up() => {
                    return Err(io::Error::new(
                        ErrorKind::BrokenPipe,
                        format!(
                            "{} hung up (the other end closed it, the line dropped or the \
                             adapter is gone)",
                            port.path().display()
                        ),
                    ))
                }
                // Nothing to read (a raw port with VMIN 0 answers 0).
                Ok(0) => guard.clear_ready(),
                Ok(n) => return Ok(n),
                Err(e) if e.kind() == ErrorKind::WouldBlock => guard.clear_ready(),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(io::Error::new(
                        e.kind(),
                        format!("read from {}: {e}", port.path().display()),
                    ))
                }
            }
        }
    }

    /// [`Port::write_all_async`] on this port.
    pub async fn write_all(&self, bytes: &[u8]) -> io::Result<()> {
        self.fd.get_ref().write_all_async(bytes).await
    }
}

impl Port {
    /// Writes all of `bytes`, waiting (1 ms at a time, without blocking the thread)
    /// while the driver's buffer is full, at most [`WRITE_PATIENCE`]; a failure names
    /// the port. Works on a second handle of a port ([`Port::try_clone`]) whose first
    /// is read by an [`AsyncPort`] or a [`Reader`].
    pub async fn write_all_async(&self, bytes: &[u8]) -> io::Result<()> {
        let give_up = Instant::now() + WRITE_PATIENCE;
        let mut rest = bytes;
        while !rest.is_empty() {
            match self.write(rest) {
                Ok(n) => rest = &rest[n..],
                Err(e)
                    if (e.kind() == ErrorKind::WouldBlock
                        || e.kind() == ErrorKind::Interrupted)
                        && Instant::now() < give_up =>
                {
                    tokio::time::sleep(Duration::from_millis(1)).await
                }
                Err(e) => {
                    return Err(io::Error::new(
                        e.kind(),
                        format!("write to {}: {e}", self.path().display()),
                    ))
                }
            }
        }
        Ok(())
    }
}

/// What a [`Reader`] hands over: bytes and when they were read, or the port's failure.
pub type Read = io::Result<(Vec<u8>, Instant)>;

/// A port read by a task of its own as bytes come, each read with the time it
/// returned, until the port fails or hangs up (handed over as an error). The task
/// ends when the reader is dropped.
#[derive(Debug)]
pub struct Reader {
    rx: mpsc::UnboundedReceiver<Read>,
    task: tokio::task::AbortHandle,
}

impl Reader {
    /// Starts reading `port` on a task of the current tokio runtime.
    pub fn spawn(port: Port) -> Reader {
        let (tx, rx) = mpsc::unbounded_channel();
        let task = tokio::spawn(read_into(port, tx)).abort_handle();
        Reader { rx, task }
    }

    /// The next read, waiting for it; an error once the port has failed (or the task
    /// has stopped). Cancel-safe.
    pub async fn recv(&mut self) -> Read {
        match self.rx.recv().await {
            Some(r) => r,
            None => Err(io::Error::other("the port's reader stopped")),
        }
    }

    /// The next read if one is waiting.
    pub fn try_recv(&mut self) -> Option<Read> {
        self.rx.try_recv().ok()
    }
}

impl Drop for Reader {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Reads `port` onto `tx` until it fails or the receiver is gone.
async fn read_into(port: Port, tx: mpsc::UnboundedSender<Read>) {
    let port = match AsyncPort::new(port) {
        Ok(p) => p,
        Err(e) => {
            let _ = tx.send(Err(e));
            return;
        }
    };
    let mut buf = [0u8; 1024];
    loop {
        match port.read(&mut buf).await {
            Ok(n) => {
                if tx.send(Ok((buf[..n].to_vec(), Instant::now()))).is_err() {
                    return;
                }
            }
            Err(e) => {
                let _ = tx.send(Err(e));
                return;
            }
        }
    }
}
