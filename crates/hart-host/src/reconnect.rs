//! One reconnect policy for everything that holds a port open for a long time (the
//! gateway's loops, its Modbus RTU slave): [`Backoff`], hart-clock's, re-exported here
//! for the crates that reach it through the host.

pub use hart_clock::Backoff;
