//! # hart-proto
//!
//! The bottom layer of hartkit: everything about HART bytes and nothing about time or I/O.
//!
//! * [`frame`]: the token-passing frame (preamble, delimiter, short/long address,
//!   expansion bytes, command incl. command 31 expansion, byte count, status bytes, data,
//!   check byte): a zero-copy parser ([`frame::Frame::parse`]) and an encoder
//!   ([`frame::FrameSpec::encode`]).
//! * [`deframer`]: a streaming deframer fed byte by byte (with UART error flags) that
//!   resynchronises after garbage and never allocates.
//! * [`types`]: HART data types (packed ASCII, IEEE 754 float with the HART NaN,
//!   date, time, 24-bit integers).
//! * [`tables`]: engineering units, response codes, status bits and every other code
//!   table, as data.
//! * [`command`]: typed requests and responses for the universal, common-practice and
//!   burst commands, each defined once by a layout from which encoding, decoding and
//!   the field-by-field description ([`wire::Visitor`]) are derived.
//!
//! The crate is `no_std` and never allocates; every decoder returns a typed error
//! instead of panicking on untrusted input.
//!
//! ```
//! use hart_proto::{decode_response, Address, Frame, FrameSpec, Response};
//!
//! // A command 1 reply with 2 preambles: PV = 12.5 psi.
//! let bytes = [0xFF, 0xFF, 0x86, 0xA6, 0x06, 0x12, 0x34, 0x56, 0x01, 0x07,
//!              0x00, 0x00, 0x06, 0x41, 0x48, 0x00, 0x00, 0x5F];
//! let frame = Frame::parse(&bytes).unwrap();
//! assert!(frame.checksum_ok());
//! let Some(Ok(Response::ReadPrimaryVariable(r))) = decode_response(frame.command, frame.data) else {
//!     panic!("not a command 1 reply");
//! };
//! assert_eq!((r.pv_units.0, r.pv), (6, 12.5));
//!
//! // Build a command 0 request to polling address 0.
//! let mut out = [0u8; 16];
//! let n = FrameSpec::request(Address::short(0), 0, &[]).encode(&mut out).unwrap();
//! assert_eq!(&out[..n], &[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02, 0x80, 0x00, 0x00, 0x82]);
//! ```
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(feature = "json")]
extern crate alloc;
#[cfg(feature = "std")]
extern crate std;

#[cfg(feature = "std")]
pub mod annotate;
pub mod command;
pub mod decode;
pub mod deframer;
pub mod frame;
#[cfg(feature = "std")]
pub mod hex;
#[cfg(feature = "json")]
pub mod json;
pub mod tables;
pub mod types;
pub mod wire;

pub use command::{
    build_request, build_response, decode_request, decode_response, CommandInfo, Request, Response,
};
pub use deframer::{Deframer, DeframerEvent, UartFlags};
pub use frame::{
    Address, Frame, FrameError, FrameSpec, FrameType, LongAddress, MasterKind, ShortAddress,
    UniqueId,
};
