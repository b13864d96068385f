//! Frame parser plus everything that presents a parsed frame (JSON, annotated view):
//! no input may panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(f) = hart_proto::Frame::parse(data) {
        let _ = hart_proto::json::frame(&f);
        let _ = hart_proto::annotate::frame(&f);
        assert_eq!(f.pdu.len() + f.preambles + f.trailing.len(), data.len());
    }
    let _ = hart_proto::Frame::parse_pdu(data);
});
