fn main() {
    let f = std::env::args().nth(1).unwrap();
    let idx: usize = std::env::args().nth(2).unwrap().parse().unwrap();
    let bytes = std::fs::read(f).unwrap();
    let pk = hart_wireless::capture::read(&bytes).unwrap();
    let k = hart_wireless::crypto::parse_key("41424344414243444142434441424344").unwrap();
    let (r, _) = hart_wireless::decoder::decode_capture(&bytes, &[k], &[]).unwrap();
    println!("{}", hart_wireless::capture::hex(&pk[idx].frame));
    println!("{:#?}", r[idx]);
}
