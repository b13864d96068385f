fn main() {
    let f = std::env::args().nth(1).unwrap();
    let k = hart_wireless::crypto::parse_key("41424344414243444142434441424344").unwrap();
    let (r, s) =
        hart_wireless::decoder::decode_capture(&std::fs::read(f).unwrap(), &[k], &[]).unwrap();
    for x in &r {
        if x.nl.is_some() {
            println!("{}", x.to_line());
        }
    }
    print!("{}", s.summary());
}
