//! # hart-link
//!
//! The HART token-passing data link layer as sans-IO state machines: no clocks, no
//! threads, no I/O. Each station is fed the characters it receives (with UART error
//! flags), the end of its own transmissions and the current time in microseconds, and
//! answers with what to transmit and when it next needs the time.
//!
//! * [`master::Master`]: primary or secondary master with STO, RT1, RT2, HOLD, grants
//!   from ACK and BACK frames, retries, busy and delayed-response handling.
//! * [`slave::Slave`]: a field device's link layer: address match, reply delay,
//!   communication-error replies, gap detection, and burst mode (BACK frames with
//!   alternating master bits). The application behind it is a [`slave::Handler`].
//! * [`timing::TimingProfile`]: the timers of FSK, RS-485, PSK and infrared.
//!
//! The same code runs in firmware, behind a serial port and in `hart-sim`.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod line;
pub mod master;
pub mod slave;
pub mod timing;

pub use master::{LinkError, Master, MasterOutput, RetryPolicy};
pub use slave::{BurstConfig, Handler, Reply, Slave};
pub use timing::{Micros, TimingProfile};
