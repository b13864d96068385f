//! Requests and replies built from JSON fields (hartkit::fields) are the reverse of the
//! decoded view: the public frames (crates/hart-proto/tests/vectors/public.toml) go
//! decoded view → fields → bytes and come back byte for byte, and so does any data
//! of any typed command that decodes (property test).

mod common;

use hart_proto::command::COMMANDS;
use hart_proto::frame::Frame;
use hart_proto::wire::Writer;
use hart_proto::{decode_request, decode_response, Request, Response};
use hartkit::json::JsonVisitor;
use hartkit::{fields, hex, Decoded};
use proptest::prelude::*;
use serde_json::Value as Json;

fn view(d: &Decoded, words: bool) -> Json {
    let mut v = if words {
        JsonVisitor::with_words()
    } else {
        JsonVisitor::default()
    };
    d.describe(&mut v);
    v.finish()
}

fn request_data(r: &Request) -> Vec<u8> {
    let mut buf = [0u8; 255];
    let mut w = Writer::new(&mut buf);
    r.encode(&mut w).unwrap();
    w.written().to_vec()
}

fn response_data(r: &Response) -> Vec<u8> {
    let mut buf = [0u8; 255];
    let mut w = Writer::new(&mut buf);
    r.encode(&mut w).unwrap();
    w.written().to_vec()
}

#[test]
fn public_frames_go_back_byte_for_byte_from_their_fields() {
    let mut checked = 0;
    let mut failures = vec![];
    for v in common::public_vectors() {
        let name = v["name"].as_str().unwrap_or("?").to_string();
        let bytes = hex::parse(&[v["hex"].as_str().unwrap()]).unwrap();
        let Ok(frame) = Frame::parse(&bytes) else {
            continue;
        };
        let Some(Ok(decoded)) = hartkit::decode_body(&frame) else {
            continue;
        };
        for words in [false, true] {
            let j = view(&decoded, words);
            let (built, expect) = match &decoded {
                Decoded::Request(r) => (fields::request_bytes(frame.command, &j), request_data(r)),
                Decoded::Response(r) => {
                    (fields::response_bytes(frame.command, &j), response_data(r))
                }
            };
            match built {
                Ok(b) if b == expect => checked += 1,
                Ok(b) => failures.push(format!(
                    "{name}: {} from {j}, expected {}",
                    hex::compact(&b),
                    hex::compact(&expect)
                )),
                Err(e) => failures.push(format!("{name}: {e} ({j})")),
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(checked >= 20, "only {checked} views were checked");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    /// Any data that decodes as a command's reply or request, for every typed
    /// command, is rebuilt from its decoded view into data that decodes to the same
    /// view (the view shows every NaN and infinity as null, so views are compared, not
    /// bytes).
    #[test]
    fn any_decodable_data_is_rebuilt_from_its_view(
        data in proptest::collection::vec(any::<u8>(), 0..80),
    ) {
        for info in COMMANDS {
            let number = info.number;
            for reply in [false, true] {
                let decoded = if reply {
                    decode_response(number, &data).unwrap().ok().map(Decoded::Response)
                } else {
                    decode_request(number, &data).unwrap().ok().map(Decoded::Request)
                };
                let Some(d) = decoded else { continue };
                let j = view(&d, true);
                let rebuilt = if reply {
                    fields::response(number, &j).map(Decoded::Response)
                } else {
                    fields::request(number, &j).map(Decoded::Request)
                };
                match rebuilt {
                    Ok(r) => prop_assert_eq!(view(&r, true), j, "command {}", number),
                    Err(e) => prop_assert!(false, "{} for command {} from {}", e, number, j),
                }
            }
        }
    }
}
