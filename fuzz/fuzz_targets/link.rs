//! Master and slave state machines fed arbitrary characters, UART flags, carrier
//! changes and time steps: no input may panic, and time never runs backwards inside.
#![no_main]
use hart_link::master::RetryPolicy;
use hart_link::slave::{BurstConfig, Handler, Reply, Slave, SlaveConfig};
use hart_link::{Master, TimingProfile};
use hart_proto::deframer::UartFlags;
use hart_proto::frame::{Address, Frame, FrameSpec, MasterKind, UniqueId};
use libfuzzer_sys::fuzz_target;

struct Any;
impl Handler for Any {
    fn request(&mut self, request: &Frame<'_>, reply: &mut Reply, _now: u64) -> bool {
        reply.set_data(request.data);
        request.command != 11
    }
    fn burst(&mut self, reply: &mut Reply, _now: u64) -> u16 {
        reply.set_data(&[1, 2, 3]);
        3
    }
}

fuzz_target!(|data: &[u8]| {
    let p = TimingProfile::fsk();
    let id = UniqueId::new(0x2606, 0x123456);
    let mut m = Master::new(MasterKind::Primary, p, RetryPolicy::default(), 0);
    let mut s = Slave::new(SlaveConfig { polling_address: 1, unique_id: id, reply_delay: None, response_preambles: 5 }, p, 0);
    s.set_burst(Some(BurstConfig { period: 500_000 }), 0);
    let mut h = Any;
    let mut now = 0u64;
    for chunk in data.chunks(3) {
        let (op, b, dt) = (chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&1));
        now += u64::from(dt) * 500;
        match op % 8 {
            0 => {
                let _ = m.request(&FrameSpec::request(Address::long(id), u16::from(b), &[b]), now);
            }
            1 => m.carrier(b & 1 == 1),
            2 => s.carrier(b & 1 == 1),
            3 => m.transmitted(now),
            4 => s.transmitted(now),
            _ => {
                let flags = UartFlags { parity: op & 0x10 != 0, framing: op & 0x20 != 0, overrun: op & 0x40 != 0 };
                m.receive(b, flags, now);
                s.receive(b, flags, now, &mut h);
            }
        }
        while m.poll(now).is_some() {}
        let _ = s.poll(now, &mut h);
        let _ = (m.next_deadline(), s.next_deadline());
    }
});
