//! The remote well-monitoring network (docs/wells.md): HART framing over RS-485 and
//! telephone lines between sensors, data concentrators, a handheld and the bureau's
//! PC.
//!
//! * [`proto`]: addresses, frames and the layouts of commands 1, 14, 144 and 160.
//! * [`calibration`]: the 10-segment piecewise quadratic tables and their CSV file.
//! * [`sensor`]: a simulated sensor (signal, clipped mean, faults, its answers).
//! * [`store`]: the concentrator's SQLite ring.
//! * [`concentrator`]: the concentrator, master on its bus and slave on its uplink.

#![warn(missing_docs)]

pub mod calibration;
pub mod concentrator;
pub mod proto;
pub mod sensor;
pub mod store;

/// Time: milliseconds since the Unix epoch (UTC), real or virtual.
pub type Millis = u64;

/// The minute (Unix time / 60) of a time.
pub fn minute_of(t: Millis) -> u32 {
    (t / 60_000) as u32
}
