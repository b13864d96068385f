//! A software Bell 202 modem for HART.
//!
//! HART's physical layer is continuous-phase binary FSK superposed on the 4-20 mA loop:
//! 1200 Hz is a 1 (mark), 2200 Hz a 0 (space), 1200 bit/s, and every character is 11
//! bits: a start bit (0), eight data bits least significant first, odd parity and a
//! stop bit (1).
//!
//! * [`modulator`]: a phase-continuous modulator at any sample rate, amplitude in volts
//!   peak-to-peak, clean carrier start and stop.
//! * [`demod`]: a streaming demodulator: samples in, timestamped characters with
//!   parity and framing flags and whole frames out.
//! * [`wav`]: reading and writing WAV files (`alloc`).
//! * [`channel`]: the channel model: noise at a given Eb/N0, interfering tones, the
//!   network's RC, the 4-20 mA analog signal and its 10 Hz reading.
//! * [`cable`]: the longest cable a network allows (RC ≤ 65 µs).
//! * [`line`](mod@line): the loop sample by sample, every station with its own modulator and
//!   demodulator on one electrical model (`alloc`).
//!
//! The cores are `no_std` and allocate nothing; the `alloc` feature adds whole-buffer
//! helpers.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

#[cfg(feature = "alloc")]
extern crate alloc;

pub mod cable;
pub mod channel;
pub mod demod;
#[cfg(feature = "alloc")]
pub mod line;
pub mod modulator;
#[cfg(feature = "alloc")]
pub mod wav;

/// Mark frequency (binary 1), Hz.
pub const MARK_HZ: f64 = 1200.0;
/// Space frequency (binary 0), Hz.
pub const SPACE_HZ: f64 = 2200.0;
/// Bit rate, bit/s.
pub const BIT_RATE: f64 = 1200.0;
/// Bits per character on the wire: start, 8 data, odd parity, stop.
pub const BITS_PER_CHAR: usize = 11;

/// The 11 bits of one character in transmission order (start bit first), `true` = 1.
pub fn char_bits(byte: u8) -> [bool; BITS_PER_CHAR] {
    let mut bits = [false; BITS_PER_CHAR];
    for (i, bit) in bits[1..9].iter_mut().enumerate() {
        *bit = byte >> i & 1 == 1;
    }
    // Odd parity: the nine bits (data + parity) hold an odd number of ones.
    bits[9] = byte.count_ones() % 2 == 0;
    bits[10] = true;
    bits
}
