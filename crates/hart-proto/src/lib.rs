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
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(feature = "std")]
extern crate std;

pub mod command;
pub mod deframer;
pub mod frame;
pub mod tables;
pub mod types;
pub mod wire;

pub use command::{decode_request, decode_response, CommandInfo, Request, Response};
pub use deframer::{Deframer, DeframerEvent, UartFlags};
pub use frame::{
    Address, Frame, FrameError, FrameSpec, FrameType, LongAddress, MasterKind, ShortAddress,
    UniqueId,
};
