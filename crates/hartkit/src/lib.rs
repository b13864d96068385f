//! Library side of the `hartkit` command-line tool: parsing hex input and presenting
//! decoded frames as JSON or as an annotated, field-by-field listing. The protocol
//! itself lives in `hart-proto`; this crate only presents it.

pub mod annotate;
pub mod cable;
pub mod demo;
pub mod fields;
pub mod gateway;
pub mod hex;
pub mod host;
pub mod ip_bench;
pub mod json;
pub mod logging;
pub mod modem;
pub mod modem_bench;
pub mod serve;
pub mod sim;
pub mod sound;
pub mod wells;
pub mod wells_bus;
pub mod wells_export;

use hart_proto::frame::{Frame, FrameType};
use hart_proto::tables::{response_class, ResponseClass};
use hart_proto::{decode_request, decode_response, wire};

/// The typed body of a frame, when the command is known and the data long enough.
// Short-lived value, built once per frame shown: the size difference does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Decoded {
    /// A request.
    Request(hart_proto::Request),
    /// A reply or burst message.
    Response(hart_proto::Response),
}

impl Decoded {
    /// Reports every field to `v`.
    pub fn describe(&self, v: &mut dyn wire::Visitor) {
        match self {
            Decoded::Request(r) => r.describe(v),
            Decoded::Response(r) => r.describe(v),
        }
    }
}

/// Decodes a frame's data with the command table.
///
/// Returns `None` when the command is not in the table, when the reply is a
/// communication-error summary, or when an error reply carries no data; returns
/// `Some(Err)` when the data is too short for the command's layout.
pub fn decode_body(frame: &Frame<'_>) -> Option<Result<Decoded, wire::DecodeError>> {
    match frame.frame_type() {
        FrameType::Stx => {
            decode_request(frame.command, frame.data).map(|r| r.map(Decoded::Request))
        }
        FrameType::Ack | FrameType::Back => {
            let rc = frame.response_code.unwrap_or(0);
            if frame.is_communication_error()
                || (response_class(rc) == ResponseClass::Error && frame.data.is_empty())
            {
                return None;
            }
            decode_response(frame.command, frame.data).map(|r| r.map(Decoded::Response))
        }
    }
}
