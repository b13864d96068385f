//! The field device as a server: arbitrary requests (any command, any data, either
//! master) at arbitrary times. No input may panic, and every reply must encode.
#![no_main]
use hart_device::{profiles, Device};
use hart_proto::frame::{Address, Frame, FrameSpec, LongAddress, MasterKind};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let profile = ["pressure", "temperature", "valve"][usize::from(*data.first().unwrap_or(&0)) % 3];
    let mut d = Device::new(profiles::load(profile).unwrap());
    let id = d.unique_id();
    let mut now = 0u64;
    let mut rest = data.get(1..).unwrap_or(&[]);
    while rest.len() >= 4 {
        let (cmd, len, flags) = (u16::from_be_bytes([rest[0], rest[1]]), usize::from(rest[2] % 40), rest[3]);
        rest = &rest[4..];
        let body = &rest[..len.min(rest.len())];
        rest = &rest[body.len()..];
        now += u64::from(flags) * 10_000;
        d.set_write_protect(flags & 0x80 != 0);
        let master = if flags & 1 == 0 { MasterKind::Primary } else { MasterKind::Secondary };
        let spec = FrameSpec::request(Address::Long(LongAddress { master, burst: false, id }), cmd, body);
        let mut buf = [0u8; 300];
        let n = spec.encode(&mut buf).unwrap();
        let Ok(frame) = Frame::parse(&buf[..n]) else { continue };
        if let Some((code, status, reply)) = d.handle(&frame, now) {
            let mut out = [0u8; 300];
            FrameSpec::reply(frame.address, cmd, code, status, &reply).encode(&mut out).expect("reply fits a frame");
        }
        let _ = d.burst_due(now);
    }
});
