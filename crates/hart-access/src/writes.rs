//! The gateway's rule for every write its front ends make through the polling engine
//! (Modbus registers, OPC UA methods, PROFIBUS outputs, Sparkplug DCMD, the web
//! dashboard, and frames HART-IP clients compose): one [`WritePolicy`], held by the
//! engine, asked once per write.
//!
//! What a front end adds of its own (which Modbus clients may write, which OPC UA
//! users, a web login, `[mqtt] read_only`) it checks before; what the whole gateway
//! says (`--read-only`, `--allow-commands`) is judged here, and the write recorded in
//! the one audit.

use std::fmt;

use crate::{Audit, CommandAllowList};

/// The gateway-wide rule for typed writes, and where they are recorded.
#[derive(Debug, Clone, Default)]
pub struct WritePolicy {
    /// No write at all (`--read-only`).
    pub read_only: bool,
    /// Only these HART commands (`--allow-commands`); `None`: every command.
    pub allow: Option<CommandAllowList>,
    /// Device-specific commands the plant declared reads (`--device-commands`,
    /// `[[device_commands]]`): frames a client composes itself that carry them pass
    /// as reads.
    pub device_commands: crate::DeviceCommands,
    /// Where each write let through is recorded.
    pub audit: Audit,
}

/// Why the gateway does not let a write through.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NotPermitted {
    /// The gateway is read-only.
    ReadOnly,
    /// The write's command is not on the allow-list.
    NotAllowed(u16),
}

impl fmt::Display for NotPermitted {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NotPermitted::ReadOnly => {
                f.write_str("the gateway is read-only (--read-only, read_only in its file)")
            }
            NotPermitted::NotAllowed(c) => write!(
                f,
                "command {c} is not on the gateway's allow-list (--allow-commands, \
                 allow_commands in its file)"
            ),
        }
    }
}

impl std::error::Error for NotPermitted {}

impl WritePolicy {
    /// Whether a write carried by HART command `command` may go.
    pub fn permits(&self, command: u16) -> Result<(), NotPermitted> {
        if self.read_only {
            return Err(NotPermitted::ReadOnly);
        }
        match &self.allow {
            Some(list) if !list.allows(command) => Err(NotPermitted::NotAllowed(command)),
            _ => Ok(()),
        }
    }

    /// Whether every one of `commands` may go: a request made of several writes is
    /// refused whole rather than done in part.
    pub fn permits_all(&self, commands: impl IntoIterator<Item = u16>) -> Result<(), NotPermitted> {
        commands.into_iter().try_for_each(|c| self.permits(c))
    }

    /// [`WritePolicy::permits_all`], with a refusal recorded in the audit as
    /// `not-permitted` (`record` says who asked and where; its command becomes the one
    /// refused).
    pub fn judge_all(
        &self,
        commands: impl IntoIterator<Item = u16>,
        record: &crate::WriteRecord,
    ) -> Result<(), NotPermitted> {
        for c in commands {
            if let Err(why) = self.permits(c) {
                self.audit.refused(
                    &crate::WriteRecord {
                        command: c,
                        ..record.clone()
                    },
                    &why.to_string(),
                );
                return Err(why);
            }
        }
        Ok(())
    }

    /// Whether any write may go at all (for a front end that shows writes as
    /// possible or not).
    pub fn writes_possible(&self) -> bool {
        !self.read_only
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn read_only_refuses_everything_and_the_list_its_outsiders() {
        let open = WritePolicy::default();
        assert_eq!(open.permits(34), Ok(()));
        let ro = WritePolicy {
            read_only: true,
            ..Default::default()
        };
        assert_eq!(ro.permits(34), Err(NotPermitted::ReadOnly));
        assert!(!ro.writes_possible());
        let listed = WritePolicy {
            allow: Some("0-22,34".parse().unwrap()),
            ..Default::default()
        };
        assert_eq!(listed.permits(34), Ok(()));
        assert_eq!(listed.permits(35), Err(NotPermitted::NotAllowed(35)));
        assert_eq!(
            listed.permits_all([34, 35, 40]),
            Err(NotPermitted::NotAllowed(35))
        );
        assert!(listed.to_string_for(35).contains("--allow-commands"));
    }

    impl WritePolicy {
        fn to_string_for(&self, c: u16) -> String {
            self.permits(c).unwrap_err().to_string()
        }
    }
}
