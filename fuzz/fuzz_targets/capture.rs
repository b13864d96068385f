//! The capture reader (`hartkit capture read`) fed untrusted files: any bytes give a
//! list of frames or an error, never a panic; and a capture we write reads back whole
//! however its frames' bytes fall (the input is cut into records).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = hart_capture::read_capture(data);
    // Our own captures of arbitrary records: every record comes back.
    let mut w = hart_capture::CaptureWriter::new(Vec::new(), "fuzz").unwrap();
    let mut n = 0;
    for (i, chunk) in data.chunks(40).enumerate() {
        let valid = hart_proto::frame::Frame::parse_pdu(chunk).is_ok_and(|f| f.checksum_ok());
        w.write(&hart_capture::Record {
            time_us: i as u64,
            bytes: chunk,
            valid,
            comment: None,
        })
        .unwrap();
        n += 1;
    }
    let file = w.into_inner();
    let back = hart_capture::read_capture(&file[..]).unwrap();
    assert_eq!(back.len(), n);
});
