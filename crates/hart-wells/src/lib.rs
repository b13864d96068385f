//! The remote well-monitoring network (docs/wells.md): HART framing over RS-485 and
//! telephone lines between sensors, data concentrators, a handheld and the bureau's
//! PC.
//!
//! * [`proto`]: addresses, frames and the layouts of commands 1, 14, 144 and 160.
//! * [`calibration`]: the 10-segment piecewise quadratic tables and their CSV file.
//! * [`sensor`]: a simulated sensor (signal, clipped mean, faults, its answers).
//! * [`store`]: the concentrator's SQLite ring.
//! * [`archive`]: what the PC and the handheld keep, and the requester side of
//!   commands 144 and 160.
//! * [`concentrator`]: the concentrator, master on its bus and slave on its uplink.
//! * [`handheld`]: the handheld as a station serving the PC.
//! * [`average`]: averages over minutes, hours, days, pentads, dekads and months.
//! * [`export`]: the PC's exports (CSV, GeoJSON) and trend plots.
//! * [`hayes`]: dialling a telephone modem with AT commands.
//! * [`sim`]: the whole network in virtual time.
//! * [`run`]: the roles in real time on serial ports and pseudo-terminals.

#![warn(missing_docs)]

pub mod archive;
pub mod average;
pub mod calibration;
pub mod concentrator;
pub mod export;
pub mod handheld;
pub mod hayes;
pub mod proto;
pub mod run;
pub mod sensor;
pub mod sim;
pub mod store;

/// Time: milliseconds since the Unix epoch (UTC), real or virtual.
pub type Millis = u64;

/// The minute (Unix time / 60) of a time.
pub fn minute_of(t: Millis) -> u32 {
    (t / 60_000) as u32
}
