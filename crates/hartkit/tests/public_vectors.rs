//! Frames from public captures and manuals (crates/hart-proto/tests/vectors/public.toml):
//! every one must decode, and the decoded JSON must agree with what the source states.

mod common;

use hart_proto::frame::Frame;
use hartkit::{hex, json};

#[test]
fn public_vectors_decode_as_their_sources_say() {
    let vectors = common::public_vectors();
    assert!(
        vectors.len() >= 15,
        "expected the public vector set, found {}",
        vectors.len()
    );
    let mut failures = vec![];
    for v in &vectors {
        let name = v["name"].as_str().unwrap_or("?");
        assert!(
            v.get("source")
                .and_then(|s| s.as_str())
                .is_some_and(|s| !s.is_empty()),
            "{name}: every vector records its source"
        );
        let bytes = hex::parse(&[v["hex"].as_str().unwrap()]).unwrap();
        let frame = match Frame::parse(&bytes) {
            Ok(f) => f,
            Err(e) => {
                failures.push(format!("{name}: {e}"));
                continue;
            }
        };
        let actual = json::frame(&frame);
        if let Some(expect) = v.get("expect") {
            if let Err(e) = common::subset(&common::toml_to_json(expect), &actual, name) {
                failures.push(e);
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} vectors disagree:\n{}",
        failures.len(),
        vectors.len(),
        failures.join("\n")
    );
}

#[test]
fn public_vectors_cover_the_cases_users_hit() {
    let vectors = common::public_vectors();
    let frames: Vec<Vec<u8>> = vectors
        .iter()
        .map(|v| hex::parse(&[v["hex"].as_str().unwrap()]).unwrap())
        .collect();
    let parsed: Vec<Frame<'_>> = frames.iter().filter_map(|b| Frame::parse(b).ok()).collect();
    assert!(
        parsed.iter().any(|f| f.preambles == 4),
        "a reply with 4 preambles"
    );
    assert!(
        parsed.iter().any(|f| f.preambles == 0),
        "a bare PDU from HART-IP"
    );
    assert!(
        parsed.iter().any(|f| !f.trailing.is_empty()),
        "trailing bytes after the check byte"
    );
    assert!(
        parsed
            .iter()
            .any(|f| matches!(f.address, hart_proto::Address::Short(_))),
        "short frames"
    );
    assert!(
        parsed
            .iter()
            .any(|f| matches!(f.address, hart_proto::Address::Long(_))),
        "long frames"
    );
}
