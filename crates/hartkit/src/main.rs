//! `hartkit`: the HART toolkit command line.

use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use hart_proto::frame::{
    Address, Frame, FrameSpec, FrameType, LongAddress, MasterKind, ShortAddress, UniqueId,
};
use hartkit::{annotate, hex, json};

/// HART toolkit: decode, encode and (in later releases) talk HART.
#[derive(Parser)]
#[command(name = "hartkit", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Top,
}

#[derive(Subcommand)]
enum Top {
    /// Decode or build single HART frames.
    #[command(subcommand)]
    Frame(FrameCmd),
}

#[derive(Subcommand)]
enum FrameCmd {
    /// Decode a frame given as hex (spaces and colons allowed; with or without preamble).
    Decode {
        /// The frame bytes, e.g. `FF FF FF FF FF 02 80 00 00 82`.
        #[arg(required = true, num_args = 1..)]
        hex: Vec<String>,
        /// Print one JSON object instead of the annotated view.
        #[arg(long)]
        json: bool,
    },
    /// Build a frame and print it as hex.
    Encode(EncodeArgs),
}

#[derive(Args)]
struct EncodeArgs {
    /// Short frame to this polling address (0-63).
    #[arg(
        long,
        value_name = "N",
        conflicts_with = "long",
        required_unless_present = "long"
    )]
    short: Option<u8>,
    /// Long frame to this unique ID (10 hex digits, e.g. 264E0000D2; 0000000000 = broadcast).
    #[arg(long, value_name = "HEX")]
    long: Option<String>,
    /// Command number (0-65535; above 255 is sent through command 31).
    #[arg(long)]
    command: u16,
    /// Send the command through command 31 even if it is below 256.
    #[arg(long)]
    extended: bool,
    /// Data bytes as hex.
    #[arg(long, value_name = "HEX", default_value = "")]
    data: String,
    /// Secondary master (default primary).
    #[arg(long)]
    secondary: bool,
    /// Set the burst-mode bit of the address.
    #[arg(long)]
    burst: bool,
    /// Number of preamble bytes.
    #[arg(long, default_value_t = hart_proto::frame::DEFAULT_PREAMBLES)]
    preambles: usize,
    /// Build a reply (ACK).
    #[arg(long, conflicts_with = "back")]
    ack: bool,
    /// Build a burst frame (BACK).
    #[arg(long)]
    back: bool,
    /// Response code (first status byte) of an ACK/BACK.
    #[arg(long, default_value_t = 0)]
    rc: u8,
    /// Field device status (second status byte) of an ACK/BACK.
    #[arg(long, default_value_t = 0)]
    status: u8,
    /// Expansion bytes as hex (0-3 bytes; no use is defined).
    #[arg(long, value_name = "HEX", default_value = "")]
    expansion: String,
}

fn decode(args: &[String], as_json: bool) -> Result<String, String> {
    let bytes = hex::parse(args)?;
    let frame = Frame::parse(&bytes).map_err(|e| e.to_string())?;
    if as_json {
        Ok(serde_json::to_string_pretty(&json::frame(&frame)).map_err(|e| e.to_string())?)
    } else {
        Ok(annotate::frame(&frame).trim_end().to_string())
    }
}

fn optional_hex(s: &str) -> Result<Vec<u8>, String> {
    if s.trim().is_empty() {
        Ok(vec![])
    } else {
        hex::parse(&[s])
    }
}

fn encode(a: &EncodeArgs) -> Result<String, String> {
    let master = if a.secondary {
        MasterKind::Secondary
    } else {
        MasterKind::Primary
    };
    let address = match (&a.short, &a.long) {
        (Some(p), _) => {
            if *p > 63 {
                return Err(format!("--short {p}: polling address must be 0-63"));
            }
            Address::Short(ShortAddress {
                master,
                burst: a.burst,
                polling_address: *p,
            })
        }
        (None, Some(id)) => Address::Long(LongAddress {
            master,
            burst: a.burst,
            id: UniqueId::parse_hex(id).map_err(|e| format!("--long {id}: {e}"))?,
        }),
        (None, None) => return Err("give --short N or --long HEX".into()),
    };
    let data = optional_hex(&a.data).map_err(|e| format!("--data: {e}"))?;
    let expansion = optional_hex(&a.expansion).map_err(|e| format!("--expansion: {e}"))?;
    let frame_type = if a.ack {
        FrameType::Ack
    } else if a.back {
        FrameType::Back
    } else {
        FrameType::Stx
    };
    let spec = FrameSpec {
        preambles: a.preambles,
        frame_type,
        address,
        expansion: &expansion,
        physical_layer: 0,
        command: a.command,
        extended: a.extended,
        status: Some((a.rc, a.status)),
        data: &data,
    };
    let mut out = vec![0u8; spec.encoded_len()];
    let n = spec.encode(&mut out).map_err(|e| e.to_string())?;
    Ok(hex::spaced(&out[..n]))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Top::Frame(FrameCmd::Decode { hex, json }) => decode(hex, *json),
        Top::Frame(FrameCmd::Encode(a)) => encode(a),
    };
    match result {
        Ok(text) => {
            println!("{text}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("hartkit: error: {e}");
            ExitCode::from(2)
        }
    }
}
