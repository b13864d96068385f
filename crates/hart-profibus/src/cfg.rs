//! Configuration identifiers (what Chk_Cfg carries and Get_Cfg returns): how many
//! input and output bytes a list of them declares.
//!
//! * **Compact** (bits 5..4 not 00): bit 7 consistency over the whole length, bit 6
//!   words (1) or bytes (0), bits 5..4 `01` input, `10` output, `11` input and output
//!   of that length each, bits 3..0 length − 1 (1..=16 units).
//! * **Special** (bits 5..4 = 00): bits 7..6 `01` an input length byte follows, `10`
//!   an output length byte, `11` both (output first), `00` none (an empty slot when
//!   the whole byte is 0); bits 3..0 the number of manufacturer bytes after the length
//!   bytes. A length byte: bit 7 consistency, bit 6 words, bits 5..0 length − 1
//!   (1..=64 units).

use std::fmt;

/// Input and output bytes declared by configuration identifiers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct IoLengths {
    /// Input bytes (slave to master).
    pub inputs: usize,
    /// Output bytes (master to slave).
    pub outputs: usize,
}

/// Why bytes are no list of configuration identifiers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CfgError {
    /// Where the identifier that runs past the end starts.
    pub offset: usize,
}

impl fmt::Display for CfgError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "the special configuration identifier at byte {} announces more bytes than follow",
            self.offset
        )
    }
}

impl std::error::Error for CfgError {}

fn units(len_minus_one: u8, words: bool) -> usize {
    (usize::from(len_minus_one) + 1) * if words { 2 } else { 1 }
}

/// The input and output lengths that `cfg` declares.
pub fn io_lengths(cfg: &[u8]) -> Result<IoLengths, CfgError> {
    let mut io = IoLengths::default();
    let mut i = 0;
    while i < cfg.len() {
        let b = cfg[i];
        let start = i;
        i += 1;
        let kind = (b >> 4) & 0x03;
        if kind != 0 {
            let n = units(b & 0x0F, b & 0x40 != 0);
            if kind & 0x01 != 0 {
                io.inputs += n;
            }
            if kind & 0x02 != 0 {
                io.outputs += n;
            }
            continue;
        }
        let manufacturer = usize::from(b & 0x0F);
        let (has_out, has_in) = (b & 0x80 != 0, b & 0x40 != 0);
        for (present, is_output) in [(has_out, true), (has_in, false)] {
            if !present {
                continue;
            }
            let l = *cfg.get(i).ok_or(CfgError { offset: start })?;
            i += 1;
            let n = units(l & 0x3F, l & 0x40 != 0);
            if is_output {
                io.outputs += n;
            } else {
                io.inputs += n;
            }
        }
        if i + manufacturer > cfg.len() {
            return Err(CfgError { offset: start });
        }
        i += manufacturer;
    }
    Ok(io)
}

/// A compact identifier for `bytes` consistent input (`output == false`) or output
/// bytes, in words when `bytes` is even and more than 16, or `None` when no compact
/// identifier holds that many (more than 32 bytes, or an odd number above 16).
pub fn compact(bytes: usize, output: bool) -> Option<u8> {
    let dir = if output { 0x20 } else { 0x10 };
    if (1..=16).contains(&bytes) {
        Some(0x80 | dir | (bytes as u8 - 1))
    } else if bytes % 2 == 0 && (2..=32).contains(&bytes) {
        Some(0x80 | 0x40 | dir | ((bytes / 2) as u8 - 1))
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compact_and_special() {
        // ET 200B 8DI/8DO as profirust's example configures it: 0x20 (1 byte out),
        // 0x10 (1 byte in).
        assert_eq!(
            io_lengths(&[0x20, 0x10]).unwrap(),
            IoLengths {
                inputs: 1,
                outputs: 1
            }
        );
        // 0xDD: 14 words consistent input = 28 bytes; 0xE2: 3 words output = 6 bytes.
        assert_eq!(
            io_lengths(&[0xDD, 0xE2]).unwrap(),
            IoLengths {
                inputs: 28,
                outputs: 6
            }
        );
        // Special: input and output, 1 manufacturer byte, 4 words out, 10 bytes in.
        assert_eq!(
            io_lengths(&[0xC1, 0x43, 0x09, 0xAA]).unwrap(),
            IoLengths {
                inputs: 10,
                outputs: 8
            }
        );
        assert_eq!(io_lengths(&[0x00]).unwrap(), IoLengths::default());
        assert_eq!(io_lengths(&[0xC1, 0x43]), Err(CfgError { offset: 0 }));
        assert_eq!(compact(28, false), Some(0xDD));
        assert_eq!(compact(6, true), Some(0xA5));
        assert_eq!(compact(33, true), None);
    }
}
