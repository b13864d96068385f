//! WAV reader: arbitrary bytes must give a file or an error, never a panic, and a
//! parsed file's channel 0 must hold one sample per whole frame present.
#![no_main]
use hart_modem::wav::Wav;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(wav) = Wav::parse(data) else {
        return;
    };
    assert!(wav.channels() > 0 && wav.sample_rate() > 0);
    assert_eq!(wav.data().len(), wav.frames() * wav.frame_bytes());
    assert!(wav.data().len() <= data.len());
    let samples = wav.channel(0).expect("channel 0 always exists");
    assert_eq!(samples.len(), wav.frames());
    assert!(wav.channel(wav.channels()).is_err());
});
