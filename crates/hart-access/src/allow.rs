//! `--allow-commands`: the commands sessions may send.

use std::ops::RangeInclusive;
use std::str::FromStr;

/// The commands sessions may send, as ranges: `0-22,48,74-84,532-533`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandAllowList(Vec<RangeInclusive<u16>>);

impl CommandAllowList {
    /// Whether `command` is on the list.
    pub fn allows(&self, command: u16) -> bool {
        self.0.iter().any(|r| r.contains(&command))
    }

    /// The ranges.
    pub fn ranges(&self) -> &[RangeInclusive<u16>] {
        &self.0
    }
}

/// Ranges of command numbers, `128,130-135`.
pub(crate) fn parse_ranges(text: &str) -> Result<Vec<RangeInclusive<u16>>, String> {
    let number = |t: &str| -> Result<u16, String> {
        t.trim()
            .parse()
            .map_err(|_| format!("{:?} is not a command number (0-65535)", t.trim()))
    };
    let mut ranges = vec![];
    for part in text.split(',').filter(|p| !p.trim().is_empty()) {
        let range = match part.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (number(a)?, number(b)?);
                if a > b {
                    return Err(format!("{:?}: the range runs backwards", part.trim()));
                }
                a..=b
            }
            None => {
                let n = number(part)?;
                n..=n
            }
        };
        ranges.push(range);
    }
    Ok(ranges)
}

impl FromStr for CommandAllowList {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let ranges = parse_ranges(text)?;
        if ranges.is_empty() {
            return Err("no command given (e.g. 0-22,48,74-84)".into());
        }
        Ok(CommandAllowList(ranges))
    }
}
