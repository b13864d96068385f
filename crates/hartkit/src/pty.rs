//! Pseudo-terminals: the serial ports of simulated devices and buses on one machine.

use std::ffi::CStr;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

/// A new pseudo-terminal: our end (the master), the far end (the slave, kept open
/// so reads on ours do not fail while no program has it open), and the far end's
/// path for the program that opens it.
pub fn open() -> Result<(OwnedFd, OwnedFd, String), String> {
    let errno = |what: &str| format!("{what}: {}", std::io::Error::last_os_error());
    let (mut master, mut slave) = (0, 0);
    // SAFETY: openpty writes two descriptors; name, termios and winsize may be null.
    if unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    } != 0
    {
        return Err(errno("openpty"));
    }
    // SAFETY: both descriptors were just created and are owned here.
    let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
    // SAFETY: ttyname returns a pointer to a static buffer or null.
    let name = unsafe { libc::ttyname(slave.as_raw_fd()) };
    if name.is_null() {
        return Err(errno("ttyname"));
    }
    let path = unsafe { CStr::from_ptr(name) }
        .to_string_lossy()
        .into_owned();
    Ok((master, slave, path))
}
