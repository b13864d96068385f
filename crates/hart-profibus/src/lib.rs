//! # hart-profibus
//!
//! A PROFIBUS DP-V0 slave, sans-IO: the bytes a serial line gives and the time they
//! were read go in ([`Slave::receive`]), the bytes to send and when come out
//! ([`Slave::poll_transmit`], [`Slave::deadline`]). The serial port is opened and
//! read elsewhere (hartkit's gateway, through `hart-serial`), so the same slave runs
//! on a real RS-485 line, a pseudo-terminal, or a simulated bus in virtual time.
//!
//! * [`fdl`]: the telegrams SD1, SD2, SD3, SD4 and the short acknowledgement, with
//!   the frame check sum and the end delimiter; damaged telegrams are typed errors.
//! * [`cfg`](mod@cfg): configuration identifiers and the input and output lengths they declare.
//! * [`slave`]: the DP services (Slave_Diag, Set_Prm, Chk_Cfg, Get_Cfg, Data_Exchange,
//!   Global_Control, RD_Inp, RD_Outp) and the states Wait_Prm, Wait_Cfg, Data_Exch,
//!   with the watchdog, the station delay (min TSDR from Set_Prm, max TSDR from the
//!   GSD), and the diagnosis a master expects.
//!
//! Timing: a reply is due `min TSDR` bit times after the request was read, and counted
//! late after `max TSDR`. After a damaged telegram the slave ignores the line until it
//! has been idle for 33 bit times (TSYN), so a damaged telegram is never answered and
//! the rest of it is never mistaken for a new one.

#![warn(missing_docs)]

pub mod cfg;
pub mod fdl;
#[cfg(feature = "gateway")]
pub mod map;
#[cfg(feature = "gateway")]
pub mod serve;
pub mod slave;

pub use cfg::IoLengths;
pub use slave::{ConfigError, DpState, Event, Slave, SlaveConfig, Stats};

/// The bit rates a serial port can carry, with the largest station delay (max TSDR,
/// in bit times) the slave declares at each in its GSD file: about 10 ms, what a
/// program on a general-purpose host answers within (a debug build over a
/// pseudo-terminal answered in 2.3 ms median, 3.9 ms at the 95th percentile; see
/// docs/benchmarks.md). The master's slot time must exceed it.
pub const BAUD_RATES: [(u32, u16); 4] =
    [(9_600, 100), (19_200, 200), (45_450, 450), (93_750, 1_000)];

/// Max TSDR for `baud`, if the slave supports that rate.
pub fn max_tsdr_bits(baud: u32) -> Option<u16> {
    BAUD_RATES.iter().find(|(b, _)| *b == baud).map(|(_, t)| *t)
}
