//! Differential test against an independent decoder.
//!
//! `tests/oracle/hart_oracle.py` was written separately, from the public reference notes
//! and the JSON contract only, without reading this codebase. Both decoders are fed the
//! same frames (the public vectors, and thousands of generated frames, some corrupted or
//! truncated) and must agree on every field the oracle reports.

mod common;

use std::io::Write;
use std::process::{Command, Stdio};

use hart_proto::frame::{
    Address, Frame, FrameSpec, FrameType, LongAddress, MasterKind, ShortAddress, UniqueId,
};
use hartkit::{hex, json};
use serde_json::Value;

/// The project's seeded generator, so failures reproduce.
struct Rng(hart_rng::Rng);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0.next_u64()
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next() as u8).collect()
    }
}

const COMMANDS: &[u16] = &[
    0, 1, 2, 3, 6, 9, 11, 12, 13, 20, 21, 38, 48, 0, 3, 9, 200, 1024,
];

fn generated(n: usize) -> Vec<Vec<u8>> {
    let mut rng = Rng(hart_rng::Rng::new(0x9E37_79B9_7F4A_7C15));
    let mut out = vec![];
    for i in 0..n {
        let ft = [FrameType::Stx, FrameType::Ack, FrameType::Back][rng.below(3) as usize];
        let master = if rng.below(2) == 0 {
            MasterKind::Primary
        } else {
            MasterKind::Secondary
        };
        let address = if rng.below(2) == 0 {
            Address::Short(ShortAddress {
                master,
                burst: rng.below(4) == 0,
                polling_address: rng.below(64) as u8,
            })
        } else {
            let id = if rng.below(10) == 0 {
                UniqueId::BROADCAST
            } else {
                UniqueId::new(rng.next() as u16, rng.next() as u32)
            };
            Address::Long(LongAddress {
                master,
                burst: rng.below(4) == 0,
                id,
            })
        };
        let command = COMMANDS[rng.below(COMMANDS.len() as u64) as usize];
        // Lengths around each layout's sizes: 0, the HART 5/6/7 forms, and random.
        let len = [0usize, 1, 4, 5, 8, 9, 12, 17, 21, 22, 24, 25, 29, 32, 69]
            [rng.below(15) as usize]
            .min(if ft == FrameType::Stx { 255 } else { 253 });
        let mut data = rng.bytes(len);
        // Half of the floats become the HART NaN or other special patterns.
        if len >= 8 && rng.below(3) == 0 {
            data[4..8].copy_from_slice(&[0x7F, 0xA0, 0x00, 0x00]);
        }
        let rc = match rng.below(6) {
            0 => 0x80 | rng.next() as u8,
            1 => rng.below(128) as u8,
            _ => 0,
        };
        let preambles = [0usize, 2, 3, 4, 5, 20][rng.below(6) as usize];
        let spec = FrameSpec {
            preambles,
            frame_type: ft,
            address,
            expansion: if rng.below(20) == 0 { &[0x00] } else { &[] },
            physical_layer: 0,
            command,
            extended: false,
            status: Some((rc, rng.next() as u8)),
            data: &data,
        };
        let mut frame = vec![0u8; spec.encoded_len()];
        let n = spec.encode(&mut frame).unwrap();
        frame.truncate(n);
        match i % 10 {
            7 => {
                let at = rng.below(frame.len() as u64) as usize;
                frame[at] ^= 1 << rng.below(8);
            }
            8 => frame.truncate(rng.below(frame.len() as u64) as usize),
            9 => {
                let extra = 1 + rng.below(4) as usize;
                frame.extend(rng.bytes(extra));
            }
            _ => {}
        }
        if !frame.is_empty() {
            out.push(frame);
        }
    }
    out
}

fn oracle(lines: &[String]) -> Option<Vec<Value>> {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/oracle/hart_oracle.py");
    let mut child = match Command::new("python3")
        .arg(script)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
    {
        Ok(c) => c,
        Err(e) => {
            eprintln!("python3 not available ({e}); skipping the differential test");
            return None;
        }
    };
    let mut stdin = child.stdin.take().unwrap();
    let input = lines.join("\n") + "\n";
    let writer = std::thread::spawn(move || stdin.write_all(input.as_bytes()));
    let out = child.wait_with_output().unwrap();
    writer.join().unwrap().unwrap();
    assert!(out.status.success(), "oracle failed");
    Some(
        String::from_utf8(out.stdout)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect(),
    )
}

#[test]
fn agrees_with_the_independent_oracle() {
    let mut frames: Vec<Vec<u8>> = common::public_vectors()
        .iter()
        .map(|v| hex::parse(&[v["hex"].as_str().unwrap()]).unwrap())
        .collect();
    frames.extend(generated(4000));
    let lines: Vec<String> = frames.iter().map(|f| hex::spaced(f)).collect();
    let Some(answers) = oracle(&lines) else {
        return;
    };
    assert_eq!(answers.len(), frames.len());
    let mut disagreements = vec![];
    let mut compared = 0;
    for ((bytes, line), theirs) in frames.iter().zip(&lines).zip(&answers) {
        let ours = Frame::parse(bytes);
        match (ours, theirs.get("error")) {
            (Ok(f), None) => {
                compared += 1;
                let ours = json::frame(&f);
                // Every key the oracle reports must match (it decodes fewer commands, so
                // `decoded` is compared where it has one).
                if let Err(e) = common::subset(theirs, &ours, line) {
                    disagreements.push(e);
                }
            }
            (Err(_), Some(_)) => {}
            // The oracle accepts a single preamble; this decoder refuses it (a receiver
            // needs two), which is intended.
            (Err(hart_proto::FrameError::TooFewPreambles { .. }), None) => {}
            (Ok(_), Some(e)) => {
                disagreements.push(format!("{line}: oracle says {e}, we decoded it"))
            }
            (Err(e), None) => disagreements.push(format!("{line}: we say {e}, oracle decoded it")),
        }
    }
    assert!(compared > 2500, "only {compared} frames were compared");
    assert!(
        disagreements.is_empty(),
        "{} disagreements:\n{}",
        disagreements.len(),
        disagreements[..disagreements.len().min(20)].join("\n")
    );
}
