//! # hart-clock
//!
//! hartkit's time, in one place:
//!
//! * [`Clock`]: where a task reads "now", monotonic and wall-clock. A running gateway
//!   uses the system's clocks; tests use tokio's clock with time paused, where hours
//!   pass in milliseconds and every step is repeatable.
//! * [`epoch`]: the one conversion between a wall-clock time and a count since
//!   1970-01-01 UTC, in the units each format stores (Sparkplug's and the web's
//!   milliseconds, the historian's signed microseconds, HART-IP's seconds), with the
//!   same rule everywhere for times before the epoch or beyond what a count holds.
//! * [`Backoff`]: the one wait between attempts to connect or open again (doubling up
//!   to a ceiling, back to the first after a success).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

mod backoff;
mod clock;
pub mod epoch;

pub use backoff::Backoff;
pub use clock::Clock;
