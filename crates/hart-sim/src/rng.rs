//! A small seeded generator (SplitMix64), so a run is reproducible bit for bit on
//! every platform.

/// SplitMix64.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// Seeds the generator.
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Number of error-free bits before the next bit error, for bit error rate `ber`
    /// (geometric distribution); `u64::MAX` when `ber` is 0.
    pub fn bits_to_next_error(&mut self, ber: f64) -> u64 {
        if ber <= 0.0 {
            return u64::MAX;
        }
        if ber >= 1.0 {
            return 0;
        }
        let u = 1.0 - self.next_f64(); // (0, 1]
        (u.ln() / (1.0 - ber).ln())
            .floor()
            .min(u64::MAX as f64 / 2.0) as u64
    }
}
