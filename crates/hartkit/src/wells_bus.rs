//! `hartkit wells bus`: a four-wire RS-485 bus made of pseudo-terminals, so a
//! concentrator and several sensors can share a bus on one machine (the walk-through
//! in docs/wells.md, and tests). What the master end sends reaches every drop; what a
//! drop sends reaches the master end only, as on a four-wire bus where the slaves'
//! transmit pair goes to the master's receiver.

use std::path::{Path, PathBuf};

/// One pseudo-terminal of the bus: our end, and the far end kept open so reads do not
/// fail while no program has it open.
struct Pty {
    ours: hart_serial::Port,
    _far: std::os::fd::OwnedFd,
    link: PathBuf,
}

fn open_pty(link: &Path) -> Result<Pty, String> {
    let p = hart_serial::pty::open().map_err(|e| e.to_string())?;
    let _ = std::fs::remove_file(link);
    std::os::unix::fs::symlink(&p.path, link).map_err(|e| {
        format!(
            "cannot make the link {} to {}: {e}; check the directory exists and is writable",
            link.display(),
            p.path.display()
        )
    })?;
    Ok(Pty {
        ours: p.ours,
        _far: p.far,
        link: link.to_path_buf(),
    })
}

/// Writes what the drop's buffer takes: a drop nobody reads fills its buffer, and what
/// does not fit is lost, as on a bus.
fn write_some(port: &hart_serial::Port, bytes: &[u8]) {
    let mut rest = bytes;
    while let Ok(n @ 1..) = port.write(rest) {
        rest = &rest[n..];
        if rest.is_empty() {
            return;
        }
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
    let ports: Vec<&hart_serial::Port> = ptys.iter().map(|p| &p.ours).collect();
    let mut buf = [0u8; 4096];
    loop {
        let ready = hart_serial::wait_any(&ports, std::time::Duration::from_secs(1))
            .map_err(|e| e.to_string())?;
        for (i, r) in ready.into_iter().enumerate() {
            if r != hart_serial::Ready::Input {
                continue;
            }
            let n = match ports[i].read(&mut buf) {
                Ok(n) if n > 0 => n,
                _ => continue,
            };
            let bytes = &buf[..n];
            if i == 0 {
                for p in &ports[1..] {
                    write_some(p, bytes);
                }
            } else {
                write_some(ports[0], bytes);
            }
        }
    }
}
