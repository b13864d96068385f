//! # hart-wireless
//!
//! WirelessHART, layer by layer, sans-IO:
//!
//! * [`mac`]: the IEEE 802.15.4 frame (frame control, sequence number, network ID,
//!   nicknames and EUI-64s, FCS);
//! * [`dll`]: the data-link PDU (specifier, advertise, ACK, keep-alive, disconnect,
//!   data) and its MIC;
//! * [`nl`]: the network PDU, its security sub-layer and its encryption;
//! * [`tl`]: the transport PDU and its commands;
//! * [`commands`]: typed layouts of the wireless commands, on hart-proto's
//!   decode/encode/describe machinery;
//! * [`build`]: frames built from their fields (an example join exchange);
//! * [`codes`]: each command's response codes;
//! * [`crypto`]: AES-CCM* with a 4-byte MIC (RustCrypto `aes` + `ccm`);
//! * [`capture`]: pcap/pcapng reading and pcap writing (802.15.4 link types 195, 230, 283);
//! * [`decoder`] (feature `std`): a stateful decoder that recovers ASNs, learns keys
//!   from commands 961 and 963 and decrypts what follows.
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

extern crate alloc;

pub mod build;
pub mod capture;
pub mod codes;
pub mod commands;
pub mod crypto;
#[cfg(feature = "std")]
pub mod decoder;
pub mod dll;
pub mod mac;
pub mod nl;
pub mod tl;

pub use crypto::{Key, WELL_KNOWN_KEY};
pub use dll::{DlBody, Dlpdu, PduType};
pub use mac::{Address, MacFrame};
pub use nl::{Npdu, Security};
pub use tl::Tpdu;
