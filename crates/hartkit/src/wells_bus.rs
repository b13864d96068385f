//! `hartkit wells bus`: a four-wire RS-485 bus made of pseudo-terminals, so a
//! concentrator and several sensors can share a bus on one machine (the walk-through
//! in docs/wells.md, and tests). What the master end sends reaches every drop; what a
//! drop sends reaches the master end only, as on a four-wire bus where the slaves'
//! transmit pair goes to the master's receiver.

use std::os::fd::{AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};

/// One pseudo-terminal of the bus: our end, and the far end kept open so reads do not
/// fail while no program has it open.
struct Pty {
    ours: OwnedFd,
    _far: OwnedFd,
    link: PathBuf,
}

fn open_pty(link: &Path) -> Result<Pty, String> {
    let (ours, far, path) = crate::pty::open()?;
    for fd in [ours.as_raw_fd(), far.as_raw_fd()] {
        // SAFETY: termios is plain data filled by tcgetattr.
        let mut t: libc::termios = unsafe { std::mem::zeroed() };
        if unsafe { libc::tcgetattr(fd, &mut t) } == 0 {
            unsafe { libc::cfmakeraw(&mut t) };
            unsafe { libc::tcsetattr(fd, libc::TCSANOW, &t) };
        }
    }
    // SAFETY: fcntl on a descriptor we own.
    unsafe {
        let fl = libc::fcntl(ours.as_raw_fd(), libc::F_GETFL);
        libc::fcntl(ours.as_raw_fd(), libc::F_SETFL, fl | libc::O_NONBLOCK);
    }
    let _ = std::fs::remove_file(link);
    std::os::unix::fs::symlink(&path, link).map_err(|e| {
        format!(
            "cannot make the link {} to {path}: {e}; check the directory exists and is writable",
            link.display()
        )
    })?;
    Ok(Pty {
        ours,
        _far: far,
        link: link.to_path_buf(),
    })
}

fn write_some(fd: i32, bytes: &[u8]) {
    // A drop nobody reads fills its buffer; what does not fit is lost, as on a bus.
    let mut rest = bytes;
    while !rest.is_empty() {
        // SAFETY: write from a valid slice to a descriptor we own.
        let n = unsafe { libc::write(fd, rest.as_ptr().cast(), rest.len()) };
        if n <= 0 {
            return;
        }
        rest = &rest[n as usize..];
    }
}

/// Runs the bus until killed: `master` is the concentrator's end, `drops` the
/// sensors' ends (links made at those paths).
pub fn run(master: &Path, drops: &[PathBuf]) -> Result<String, String> {
    if drops.is_empty() {
        return Err("give at least one --drop for a sensor".into());
    }
    let mut ptys = vec![open_pty(master)?];
    for d in drops {
        ptys.push(open_pty(d)?);
    }
    println!(
        "bus: master {} ; drops {}",
        ptys[0].link.display(),
        ptys[1..]
            .iter()
            .map(|p| p.link.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let mut fds: Vec<libc::pollfd> = ptys
        .iter()
        .map(|p| libc::pollfd {
            fd: p.ours.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        })
        .collect();
    let mut buf = [0u8; 4096];
    loop {
        // SAFETY: poll on an array of pollfd we own.
        let n = unsafe { libc::poll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, 1000) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            return Err(format!("poll: {e}"));
        }
        for i in 0..fds.len() {
            if fds[i].revents & libc::POLLIN == 0 {
                continue;
            }
            // SAFETY: read into a buffer we own.
            let n = unsafe { libc::read(fds[i].fd, buf.as_mut_ptr().cast(), buf.len()) };
            if n <= 0 {
                continue;
            }
            let bytes = &buf[..n as usize];
            if i == 0 {
                for f in &fds[1..] {
                    write_some(f.fd, bytes);
                }
            } else {
                write_some(fds[0].fd, bytes);
            }
        }
    }
}
