//! The conformance tester's own receiver and recording reader: arbitrary characters
//! (with arbitrary times) split into frames without a panic, every frame's bytes come
//! from the input in order, and an arbitrary recording gives a verdict per test.
#![no_main]
use hart_conform::frames::{split, Char};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // Characters: a byte and a time step from each pair of input bytes.
    let mut t = 0u64;
    let chars: Vec<Char> = data
        .chunks(2)
        .map(|c| {
            t += u64::from(*c.get(1).unwrap_or(&0)) * 100;
            Char {
                byte: c[0],
                damaged: c.get(1).is_some_and(|b| b & 1 == 1),
                at: t,
            }
        })
        .collect();
    let frames = split(&chars, 9167);
    let total: usize = frames.iter().map(|f| f.bytes.len()).sum();
    assert!(total <= chars.len());
    for f in &frames {
        assert!(f.preambles >= 2 && f.start <= f.end);
        let _ = f.summary();
        let _ = f.frame();
    }
    // The same bytes as a recording.
    let r = hart_conform::phy::run(data, "fuzz.wav", &hart_conform::phy::Limits::default());
    assert_eq!(r.results.len(), 6);
});
