//! Pseudo-terminals: the serial ports of simulated devices and buses on one machine.

use std::io;
use std::os::fd::OwnedFd;
use std::path::PathBuf;

use crate::{OpenOptions, Port};

/// A pseudo-terminal pair: our end, the far end's path for the program that opens it,
/// and the far end itself, kept open so that reads on ours do not fail while no
/// program has it open (and a program can close and open it again).
#[derive(Debug)]
pub struct Pty {
    /// Our end (the master side), raw and non-blocking.
    pub ours: Port,
    /// The far end (the slave side), raw; keep it as long as ours is used.
    pub far: OwnedFd,
    /// The far end's path (`/dev/pts/N`).
    pub path: PathBuf,
}

/// A new pseudo-terminal pair, both ends raw (no echo, no line editing, every byte
/// passed as it is).
pub fn open() -> io::Result<Pty> {
    let p = nix::pty::openpty(None, None).map_err(|e| {
        let e = io::Error::from(e);
        io::Error::new(e.kind(), format!("openpty: {e}"))
    })?;
    let path = nix::unistd::ttyname(&p.slave).map_err(|e| {
        let e = io::Error::from(e);
        io::Error::new(e.kind(), format!("ttyname: {e}"))
    })?;
    // The far end in raw mode too, through a port that borrows its settings only.
    let far = Port::from_fd(p.slave, &path, None, OpenOptions::default())?;
    let far = far.into_fd();
    let ours = Port::from_fd(p.master, &path, None, OpenOptions::default())?;
    Ok(Pty { ours, far, path })
}
