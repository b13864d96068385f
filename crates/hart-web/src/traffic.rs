//! The traffic view's log: the last frames of every loop as the engine sent and heard
//! them, numbered, filtered, shown as `hartkit monitor` shows frames, and written as
//! pcapng for Wireshark.

use std::collections::VecDeque;
use std::sync::Arc;

use hart_poller::{TrafficFrame, TrafficKind};
use hart_proto::frame::{Address, Frame, UniqueId};
use serde_json::{json, Value};

/// Which frames a view wants.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(crate) struct Filter {
    /// Only this loop.
    pub channel: Option<u8>,
    /// Only frames to or from this device: its loop, unique ID and polling address.
    pub device: Option<(u8, Option<UniqueId>, Option<u8>)>,
    /// Only this command.
    pub command: Option<u16>,
    /// Only frames numbered after this.
    pub after: Option<u64>,
}

impl Filter {
    fn matches(&self, f: &TrafficFrame, parsed: Option<&Frame<'_>>) -> bool {
        if self.channel.is_some_and(|c| c != f.channel) {
            return false;
        }
        if let Some(cmd) = self.command {
            if parsed.is_none_or(|p| p.command != cmd) {
                return false;
            }
        }
        if let Some((channel, id, poll)) = self.device {
            if f.channel != channel {
                return false;
            }
            let hit = match parsed.map(|p| p.address) {
                Some(Address::Long(l)) => id.is_some_and(|id| id == l.id),
                Some(Address::Short(s)) => poll == Some(s.polling_address),
                None => false,
            };
            if !hit {
                return false;
            }
        }
        true
    }
}

/// The last frames, numbered from 1.
#[derive(Debug)]
pub(crate) struct TrafficLog {
    frames: VecDeque<(u64, Arc<TrafficFrame>)>,
    capacity: usize,
    next: u64,
    lost: u64,
}

impl TrafficLog {
    pub(crate) fn new(capacity: usize) -> Self {
        TrafficLog {
            frames: VecDeque::with_capacity(capacity.min(8192)),
            capacity: capacity.max(1),
            next: 1,
            lost: 0,
        }
    }

    pub(crate) fn push(&mut self, f: Arc<TrafficFrame>) {
        if self.frames.len() >= self.capacity {
            self.frames.pop_front();
        }
        self.frames.push_back((self.next, f));
        self.next += 1;
    }

    /// `n` frames the log could not keep up with (a loop answering in memory).
    pub(crate) fn lost(&mut self, n: u64) {
        self.lost += n;
        self.next += n;
    }

    /// Frames missed so far because the log fell behind.
    pub(crate) fn lost_count(&self) -> u64 {
        self.lost
    }

    /// The newest frame's number (0 before the first).
    pub(crate) fn last_seq(&self) -> u64 {
        self.next - 1
    }

    /// The frames `filter` wants, oldest first, at most the newest `limit`; a
    /// no-reply marker or a reply goes with its request when the request matches.
    pub(crate) fn select(&self, filter: &Filter, limit: usize) -> Vec<(u64, Arc<TrafficFrame>)> {
        let mut out = VecDeque::new();
        let mut request_matched = false;
        for (seq, f) in &self.frames {
            if filter.after.is_some_and(|a| *seq <= a) {
                continue;
            }
            let parsed = Frame::parse_pdu(&f.pdu).ok();
            let hit = match f.kind {
                TrafficKind::NoReply => request_matched && filter.command.is_none_or(|_| true),
                _ => filter.matches(f, parsed.as_ref()),
            };
            if f.kind == TrafficKind::Request {
                request_matched = hit;
            }
            if hit {
                out.push_back((*seq, f.clone()));
                if out.len() > limit {
                    out.pop_front();
                }
            }
        }
        out.into()
    }
}

/// Microseconds since the Unix epoch.
use hart_clock::epoch::micros as unix_us;

/// One frame as the traffic view and `/api/traffic` give it: its number, time, loop,
/// kind, and the frame as `hartkit monitor --json` gives it (under `frame`), with a
/// one-line text like monitor's.
pub(crate) fn frame_json(seq: u64, f: &TrafficFrame, loop_name: &str) -> Value {
    let time = humantime::format_rfc3339_millis(f.time).to_string();
    let mut v = json!({
        "seq": seq,
        "time": time,
        "time_us": unix_us(f.time),
        "loop": loop_name,
        "channel": f.channel,
        "kind": f.kind.name(),
    });
    match Frame::parse_pdu(&f.pdu) {
        Ok(frame) => {
            v["text"] = json!(line(&frame));
            v["frame"] = hart_proto::json::frame(&frame);
            if let Some(t) = hart_proto::command::title(frame.command) {
                v["title"] = json!(t);
            }
        }
        Err(e) if f.kind != TrafficKind::NoReply => {
            v["text"] = json!(format!(
                "not a frame ({e}): {}",
                f.pdu.iter().map(|b| format!("{b:02X}")).collect::<String>()
            ));
        }
        Err(_) => v["text"] = json!("no reply after the retries"),
    }
    v
}

/// The frame on one line, as `hartkit monitor` prints it after its times.
fn line(f: &Frame<'_>) -> String {
    let rc = match f.response_code {
        Some(rc) => format!(" rc {rc} status 0x{:02X}", f.device_status.unwrap_or(0)),
        None => String::new(),
    };
    format!(
        "{:<4} cmd {:<4} {}{} {}",
        f.frame_type().name(),
        f.command,
        f.address,
        rc,
        f.data
            .iter()
            .map(|b| format!("{b:02X}"))
            .collect::<String>()
    )
}

/// The frames as a pcapng capture (hart-capture's form: HART-IP over UDP, as
/// Wireshark dissects it), each packet's comment naming its loop.
pub(crate) fn pcapng(
    frames: &[(u64, Arc<TrafficFrame>)],
    loop_name: impl Fn(u8) -> String,
) -> Result<Vec<u8>, String> {
    let mut w =
        hart_capture::CaptureWriter::new(Vec::new(), "hartkit web").map_err(|e| e.to_string())?;
    for (_, f) in frames
        .iter()
        .filter(|(_, f)| f.kind != TrafficKind::NoReply)
    {
        w.write(&hart_capture::Record {
            time_us: unix_us(f.time),
            bytes: &f.pdu,
            valid: Frame::parse_pdu(&f.pdu).is_ok(),
            comment: Some(format!("loop {}", loop_name(f.channel))),
        })
        .map_err(|e| e.to_string())?;
    }
    Ok(w.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use hart_proto::frame::FrameSpec;
    use std::time::SystemTime;

    fn frame(kind: TrafficKind, poll: u8, command: u8) -> Arc<TrafficFrame> {
        let command = u16::from(command);
        let spec = match kind {
            TrafficKind::Request => FrameSpec::request(Address::short(poll), command, &[]),
            _ => FrameSpec::reply(Address::short(poll), command, 0, 0, &[]),
        };
        let pdu = hart_poller::line::pdu(&spec);
        Arc::new(TrafficFrame {
            channel: 0,
            time: SystemTime::now(),
            kind,
            pdu,
        })
    }

    #[test]
    fn filters_by_device_and_command_and_keeps_the_newest() {
        let mut log = TrafficLog::new(100);
        for i in 0..60u8 {
            log.push(frame(TrafficKind::Request, i % 3, 3));
            log.push(frame(TrafficKind::Reply, i % 3, 3));
        }
        assert_eq!(log.last_seq(), 120);
        let f = Filter {
            device: Some((0, None, Some(1))),
            ..Filter::default()
        };
        let got = log.select(&f, 1000);
        assert!(!got.is_empty() && got.len() <= 34);
        let none = log.select(
            &Filter {
                command: Some(48),
                ..Filter::default()
            },
            10,
        );
        assert!(none.is_empty());
        let newest = log.select(&Filter::default(), 5);
        assert_eq!(newest.last().unwrap().0, 120);
        assert_eq!(newest.len(), 5);
        let after = log.select(
            &Filter {
                after: Some(118),
                ..Filter::default()
            },
            10,
        );
        assert_eq!(after.len(), 2);
        let text = frame_json(1, &newest[0].1, "sim");
        assert!(text["text"].as_str().unwrap().contains("cmd 3"));
        let cap = pcapng(&newest, |_| "sim".into()).unwrap();
        assert_eq!(
            hart_capture::read_capture(&cap[..]).unwrap().len(),
            5,
            "the capture reads back"
        );
    }
}
