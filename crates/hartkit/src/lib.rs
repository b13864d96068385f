//! Library side of the `hartkit` command-line tool: parsing hex input and presenting
//! decoded frames as JSON or as an annotated, field-by-field listing. The protocol
//! itself lives in `hart-proto`; this crate only presents it.

/// The annotated, field-by-field view of a frame (hart-proto's).
pub use hart_proto::annotate;
pub mod cable;
pub mod demo;
pub mod fields;
pub mod gateway;
pub mod hex;
pub mod host;
pub mod ip_bench;
/// The `--json` view of a frame (hart-proto's, feature `json`).
pub use hart_proto::json;
pub mod logging;
pub mod modem;
pub mod modem_bench;
pub mod serve;
pub mod sim;
pub mod sound;
pub mod wells;
pub mod wells_bus;
pub mod wells_export;
pub mod wireless;

pub use hart_proto::decode::{decode_body, Decoded};
