//! # hart-host
//!
//! The host (master) side: a [`Client`] that runs the `hart-link` master over a
//! [`transport::Transport`] chosen by a target string ([`target::open`]):
//! `/dev/ttyUSB0`, `serial:PATH?baud=1200&rts=high-tx`, `rs485:PATH?baud=19200`,
//! `sim`, `sim:PLANT.toml`, `sim?virtual`, and HART-IP `udp://HOST[:PORT]`,
//! `tcp://HOST[:PORT]` ([`hartip`], which also has [`hartip::HartIpSession`] for several
//! requests in flight), and [`load`], a load generator for HART-IP servers.

pub mod client;
pub mod error;
pub mod hartip;
pub mod load;
pub mod reconnect;
pub mod replay;
pub mod target;
pub mod transport;
mod write;

pub use client::{Client, DeviceInfo, DeviceRef, Reply, ScanEvent};
pub use error::HostError;
pub use write::HostWrite;
