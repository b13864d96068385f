//! The handheld as a station: slave to the PC at `0xC0 + well` for each well it
//! holds minutes of, handing them over with command 144 (its own handed-over mark per
//! well), and taking calibration tables with command 160 to download to a well's
//! concentrator on its next visit. Its master side is [`crate::archive::Collector`]
//! and [`crate::archive::CalibrationSender`].

use std::collections::HashMap;

use tracing::{info, warn};

use crate::archive::Archive;
use crate::proto::{
    decode_transfer_request, Assembled, Message, Role, SegmentReply, SegmentRequest,
    TableAssembler, CALIBRATION, RC_NOT_IMPLEMENTED, RC_TOO_FEW_BYTES, SEGMENT_TAKEN,
    TABLE_IN_FORCE, TRANSFER,
};
use crate::Millis;

/// Response code when the handheld's archive fails.
pub const RC_STORE_FAILED: u8 = 6;

/// The handheld's station side.
#[derive(Default)]
pub struct HandheldStation {
    assemblers: HashMap<u8, TableAssembler>,
}

impl HandheldStation {
    /// A station.
    pub fn new() -> Self {
        Self::default()
    }

    /// Answers a request from the PC (`None`: not a request for the handheld; a well
    /// it holds nothing of gets an empty batch).
    pub fn answer(&mut self, archive: &mut Archive, msg: &Message, now: Millis) -> Option<Message> {
        if msg.reply || msg.station.role() != Role::Handheld {
            return None;
        }
        let well = msg.station.number();
        let minute = (now / 60_000) as u32;
        let reply = |rc: u8, data: Vec<u8>| Message::reply(msg.station, msg.command, [rc, 0], data);
        match msg.command {
            TRANSFER => {
                // A well it holds nothing of: an empty batch (nothing to hand over),
                // rather than silence that would look like a broken cable.
                Some(match decode_transfer_request(&msg.data) {
                    Err(_) => reply(RC_TOO_FEW_BYTES, vec![]),
                    Ok(ack) => match archive.transfer(well, ack, minute) {
                        Ok(b) => reply(0, b.encode()),
                        Err(e) => {
                            warn!("{e}");
                            reply(RC_STORE_FAILED, vec![])
                        }
                    },
                })
            }
            CALIBRATION => Some(match SegmentRequest::decode(&msg.data) {
                Err((rc, e)) => {
                    warn!("{e}");
                    reply(rc, vec![])
                }
                Ok(seg) => match self.assemblers.entry(well).or_default().take(seg) {
                    Assembled::Taken => reply(0, SegmentReply::to(&seg, SEGMENT_TAKEN).encode()),
                    Assembled::AlreadyInForce => {
                        reply(0, SegmentReply::to(&seg, TABLE_IN_FORCE).encode())
                    }
                    Assembled::Refused(rc, why) => {
                        warn!("calibration for well {well} refused: {why}");
                        reply(rc, vec![])
                    }
                    Assembled::Table(sensor, t) => {
                        match archive.set_pending_calibration(well, sensor, &t) {
                            Ok(()) => {
                                self.assemblers
                                    .entry(well)
                                    .or_default()
                                    .confirm(sensor, seg.segment);
                                info!(
                                    "{} calibration table for well {well} kept for the next visit",
                                    sensor.name()
                                );
                                reply(0, SegmentReply::to(&seg, TABLE_IN_FORCE).encode())
                            }
                            Err(e) => {
                                warn!("{e}");
                                reply(RC_STORE_FAILED, vec![])
                            }
                        }
                    }
                },
            }),
            _ => Some(reply(RC_NOT_IMPLEMENTED, vec![])),
        }
    }
}
