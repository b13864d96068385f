//! Why the gateway could not start, and the exit code that says so.

/// Why the gateway could not start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Error {
    /// What happened and what to check.
    pub message: String,
    /// A mistake in the configuration (`Config`), or the system refused something
    /// (`Io`: a port that cannot be opened, an address in use).
    pub kind: ErrorKind,
}

/// The two kinds of [`Error`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// The configuration or options are wrong (exit code 2).
    Config,
    /// An address, port or file could not be used (exit code 5).
    Io,
}

impl Error {
    /// A configuration mistake.
    pub fn config(message: impl Into<String>) -> Self {
        Error {
            message: message.into(),
            kind: ErrorKind::Config,
        }
    }

    /// A refusal of the system.
    pub fn io(message: impl Into<String>) -> Self {
        Error {
            message: message.into(),
            kind: ErrorKind::Io,
        }
    }

    /// The process exit code `hartkit` gives it: 2 for the configuration, 5 for I/O.
    pub fn exit_code(&self) -> u8 {
        match self.kind {
            ErrorKind::Config => 2,
            ErrorKind::Io => 5,
        }
    }
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Error {}
