use hart_wireless::*;
fn main() {
    let f = std::env::args().nth(1).unwrap();
    let pk = capture::read(&std::fs::read(f).unwrap()).unwrap();
    let mut dec = decoder::Decoder::new();
    dec.add_join_key(crypto::parse_key("41424344414243444142434441424344").unwrap());
    for (i, p) in pk.iter().enumerate() {
        let r = dec.decode(i, p);
        if let Some(nl) = &r.nl {
            let d = r.dl.as_ref().unwrap();
            print!(
                "{i} {}->{} mic {:?} nl {}->{} {} ctr {:?} ",
                d.src,
                d.dst,
                r.dl_mic_ok,
                nl.npdu.src,
                nl.npdu.dst,
                nl.npdu.security.name(),
                nl.counter
            );
            match (&nl.tpdu, &nl.plain) {
                (Some(t), _) => println!(
                    "tl {:02x} {:?}",
                    t.transport_byte(),
                    t.commands
                        .iter()
                        .map(|c| format!("{} {}", c.number, capture::hex(&c.data)))
                        .collect::<Vec<_>>()
                ),
                (None, Some(p)) => println!("RAW {}", capture::hex(p)),
                _ => println!("{:?}", nl.why_not),
            }
        } else if r.dl_mic_ok != Some(true) {
            println!(
                "{i} {:?} mic {:?}",
                r.dl.as_ref().map(|d| d.pdu_type),
                r.dl_mic_ok
            );
        }
    }
    println!("{:?}", dec.stats);
}
