//! # hart-host
//!
//! The host (master) side: a [`Client`] that runs the `hart-link` master over a
//! [`transport::Transport`] chosen by a target string ([`target::open`]):
//! `/dev/ttyUSB0`, `serial:PATH?baud=1200&rts=high-tx`, `rs485:PATH?baud=19200`,
//! `sim`, `sim:PLANT.toml`, `sim?virtual`. HART-IP (`udp://`, `tcp://`) plugs into the
//! same trait in its own crate.

pub mod client;
pub mod error;
pub mod hartip;
pub mod target;
pub mod transport;

pub use client::{Client, DeviceInfo, DeviceRef, Reply};
pub use error::HostError;
