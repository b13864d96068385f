//! Access control (hart-access) on any request: the bytes are a request PDU, checked
//! with both rights and with and without a device type; the check answers without
//! panicking, a read-only session is let through only with a command the project
//! knows reads (or the one declared), and a request the read-write session may not
//! send is refused to the read-only one too. The same bytes as a device-commands file
//! and as a list of networks are read without panicking.
#![no_main]
use hart_access::{Allowed, DeviceCommands, NetList, Policy, Rights};
use hart_proto::command::Access;
use hart_proto::frame::Frame;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let policy = Policy {
        allow: None,
        device_commands: DeviceCommands::parse("[[device]]\ntype = \"26F3\"\nreads = \"128\"\n")
            .unwrap(),
    };
    if let Ok(f) = Frame::parse_pdu(data) {
        for ty in [None, Some(0x26F3), Some(0x1234)] {
            let ro = policy.check(Rights::ReadOnly, &f, ty);
            let rw = policy.check(Rights::ReadWrite, &f, ty);
            if rw.is_err() {
                assert!(ro.is_err());
            }
            if ro == Ok(Allowed::Read) && f.command != 77 {
                let a = policy.access(f.command, &f.address, ty);
                assert_eq!(a, Access::Read);
            }
        }
    }
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = DeviceCommands::parse(text);
        let _ = NetList::parse(&text.split(',').collect::<Vec<_>>());
        let _ = text.parse::<hart_access::CommandAllowList>();
    }
});
