//! A frame's data decoded with the command table, whichever way it goes (request,
//! reply or burst message).

use crate::frame::{Frame, FrameType};
use crate::tables::{response_class, ResponseClass};
use crate::{decode_request, decode_response, wire};

/// The typed body of a frame, when the command is known and the data long enough.
// Short-lived value, built once per frame shown: the size difference does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Decoded {
    /// A request.
    Request(crate::Request),
    /// A reply or burst message.
    Response(crate::Response),
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
