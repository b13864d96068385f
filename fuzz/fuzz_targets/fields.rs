//! Requests and replies built from JSON fields (hart_proto::json::fields, what `hartkit command N
//! '{...}'` and Python's `encode_request` take from users): the first two bytes pick
//! the command and direction. The rest is read twice: as JSON text, which must build
//! or be refused with an error, never a panic, and whatever builds must decode; and as
//! command data, whose decoded view must build back into data with the same view.
#![no_main]
use hart_proto::command::COMMANDS;
use hart_proto::decode::Decoded;
use hart_proto::json::fields;
use hart_proto::json::JsonVisitor;
use libfuzzer_sys::fuzz_target;

fn view(d: &Decoded) -> serde_json::Value {
    let mut v = JsonVisitor::with_words();
    d.describe(&mut v);
    v.finish()
}

fuzz_target!(|data: &[u8]| {
    if data.len() < 2 {
        return;
    }
    let number = COMMANDS[usize::from(data[0]) % COMMANDS.len()].number;
    let reply = data[1] & 1 == 1;
    let body = &data[2..];

    if let Ok(j) = serde_json::from_slice::<serde_json::Value>(body) {
        if reply {
            if let Ok(b) = fields::response_bytes(number, &j) {
                assert!(hart_proto::decode_response(number, &b).unwrap().is_ok());
            }
        } else if let Ok(b) = fields::request_bytes(number, &j) {
            assert!(hart_proto::decode_request(number, &b).unwrap().is_ok());
        }
    }

    let decoded = if reply {
        hart_proto::decode_response(number, body)
            .unwrap()
            .ok()
            .map(Decoded::Response)
    } else {
        hart_proto::decode_request(number, body)
            .unwrap()
            .ok()
            .map(Decoded::Request)
    };
    if let Some(d) = decoded {
        let j = view(&d);
        let rebuilt = if reply {
            fields::response(number, &j).map(Decoded::Response)
        } else {
            fields::request(number, &j).map(Decoded::Request)
        };
        assert_eq!(view(&rebuilt.expect("a decoded view builds")), j);
    }
});
