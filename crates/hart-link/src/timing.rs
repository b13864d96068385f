//! Data-link timers per physical layer.
//!
//! All times are whole microseconds. A character is 11 bits (start, 8 data, odd parity,
//! stop). See `docs/data-link.md` for what each timer means and the timing diagram.

/// Time in microseconds since an arbitrary origin chosen by the caller.
pub type Micros = u64;

/// The timers of one physical layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimingProfile {
    /// Short name, e.g. `"fsk"`.
    pub name: &'static str,
    /// Bit rate in bit/s.
    pub baud: u32,
    /// One character (11 bits).
    pub char_time: Micros,
    /// Slave time-out: how long a master waits after its request for the reply to start.
    pub sto: Micros,
    /// Link quiet time of the primary master.
    pub rt1_primary: Micros,
    /// Link quiet time of the secondary master (longer: the primary wins a tie).
    pub rt1_secondary: Micros,
    /// Link grant time: the window in which a granted master must start.
    pub rt2: Micros,
    /// Hold time: the shortest turnaround before a station answers or takes a grant.
    pub hold: Micros,
}

const fn char_time(baud: u32) -> Micros {
    // 11 bits, rounded to the nearest microsecond.
    (11_000_000 + baud as u64 / 2) / baud as u64
}

impl TimingProfile {
    /// Bell 202 FSK at 1200 bit/s: STO 28, RT1 33 / 41, RT2 8, HOLD 2 character times.
    pub const fn fsk() -> Self {
        Self::in_characters("fsk", 1200)
    }

    /// RS-485. At 1200 bit/s the FSK character counts; above it STO 32 ms,
    /// RT1 32 ms + 6 characters (secondary: RT1 + RT2), RT2 3 ms + 6 characters,
    /// HOLD 2 characters.
    pub const fn rs485(baud: u32) -> Self {
        if baud <= 1200 {
            let mut p = Self::in_characters("rs485", baud);
            p.name = "rs485";
            return p;
        }
        let c = char_time(baud);
        let rt1 = 32_000 + 6 * c;
        let rt2 = 3_000 + 6 * c;
        TimingProfile {
            name: "rs485",
            baud,
            char_time: c,
            sto: 32_000,
            rt1_primary: rt1,
            rt1_secondary: rt1 + rt2,
            rt2,
            hold: 2 * c,
        }
    }

    /// C8PSK at 9600 bit/s: STO 32 ms, RT1 42 ms (secondary: RT1 + RT2), RT2 14 ms,
    /// HOLD 3 ms.
    pub const fn psk() -> Self {
        TimingProfile {
            name: "psk",
            baud: 9600,
            char_time: char_time(9600),
            sto: 32_000,
            rt1_primary: 42_000,
            rt1_secondary: 56_000,
            rt2: 14_000,
            hold: 3_000,
        }
    }

    /// Infrared: STO 30 ms, RT1 261 ms (secondary: RT1 + RT2), RT2 7 ms. The bit rate
    /// is not in the public sources; 9600 bit/s is assumed (STO is then 26 characters,
    /// close to FSK's 28), HOLD 2 characters.
    pub const fn infrared() -> Self {
        let c = char_time(9600);
        TimingProfile {
            name: "infrared",
            baud: 9600,
            char_time: c,
            sto: 30_000,
            rt1_primary: 261_000,
            rt1_secondary: 268_000,
            rt2: 7_000,
            hold: 2 * c,
        }
    }

    /// HART-IP: frames travel whole inside UDP/TCP messages between one client and
    /// the server, with no shared line to hand over, so the line timers only bound the
    /// wait: STO 5 s (a gateway forwards to a 1200 bit/s loop, where it may queue behind
    /// other sessions and make its own retries), RT1 5 ms / 10 ms, RT2 0.1 ms between one
    /// transaction and the next (the server queues; the 2 ms pause used before capped a
    /// client at about 300 transactions a second), HOLD 0.1 ms, a "character" of 10 µs.
    pub const fn hart_ip() -> Self {
        TimingProfile {
            name: "hart-ip",
            baud: 0,
            char_time: 10,
            sto: 5_000_000,
            rt1_primary: 5_000,
            rt1_secondary: 10_000,
            rt2: 0,
            hold: 100,
        }
    }

    const fn in_characters(name: &'static str, baud: u32) -> Self {
        let c = char_time(baud);
        TimingProfile {
            name,
            baud,
            char_time: c,
            sto: 28 * c,
            rt1_primary: 33 * c,
            rt1_secondary: 41 * c,
            rt2: 8 * c,
            hold: 2 * c,
        }
    }

    /// RT1 of the given master.
    pub fn rt1(&self, master: hart_proto::MasterKind) -> Micros {
        match master {
            hart_proto::MasterKind::Primary => self.rt1_primary,
            hart_proto::MasterKind::Secondary => self.rt1_secondary,
        }
    }

    /// Time to send `n` characters back to back.
    pub fn chars(&self, n: usize) -> Micros {
        self.char_time * n as Micros
    }

    /// Idle time between two characters of one frame that aborts the frame: more than
    /// one character time of silence.
    pub fn gap_limit(&self) -> Micros {
        self.char_time
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fsk_in_character_times() {
        let p = TimingProfile::fsk();
        assert_eq!(p.char_time, 9167);
        assert_eq!(
            (p.sto, p.rt1_primary, p.rt1_secondary, p.rt2, p.hold),
            (28 * 9167, 33 * 9167, 41 * 9167, 8 * 9167, 2 * 9167)
        );
        assert_eq!(TimingProfile::rs485(1200).sto, p.sto);
    }

    #[test]
    fn rs485_fast() {
        let p = TimingProfile::rs485(19200);
        assert_eq!(p.char_time, 573);
        assert_eq!(p.sto, 32_000);
        assert_eq!(p.rt1_primary, 32_000 + 6 * 573);
        assert_eq!(p.rt2, 3_000 + 6 * 573);
        assert!(p.rt1_primary > p.sto && p.rt1_secondary > p.rt1_primary);
    }

    #[test]
    fn every_profile_orders_its_timers() {
        for p in [
            TimingProfile::fsk(),
            TimingProfile::rs485(1200),
            TimingProfile::rs485(38400),
            TimingProfile::psk(),
            TimingProfile::infrared(),
        ] {
            assert!(
                p.hold < p.rt2
                    && p.rt2 < p.sto
                    && p.sto < p.rt1_primary
                    && p.rt1_primary < p.rt1_secondary,
                "{}",
                p.name
            );
        }
    }
}
