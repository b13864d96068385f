//! What can go wrong, each with what happened and what to check.

/// A historian error. Its text says what failed and what to check; the variant says
/// what kind of fault it is (the writer keeps samples and retries on every kind but
/// [`Error::Usage`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Error {
    /// A bad argument: a time, a variable name, a size, a database address.
    Usage(String),
    /// No stored device has that tag or unique ID (or the tag names several).
    NoSuchDevice(String),
    /// The file is not an SQLite database, or it is damaged.
    Corrupt(String),
    /// Another program holds the database locked.
    Locked(String),
    /// The disk (or the database's size limit) is full.
    Full(String),
    /// The file or its folder may not be written.
    ReadOnly(String),
    /// The database server cannot be reached, or the connection was lost.
    Gone(String),
    /// The database was written by a newer hartkit (a schema version this one does not
    /// know).
    Schema(String),
    /// A file could not be opened or read.
    Io(String),
    /// Any other error the database reported.
    Database(String),
}

impl Error {
    /// The exit code of the command line: 2 for usage (and unknown devices), 5 for
    /// I/O and database faults.
    pub fn exit_code(&self) -> u8 {
        match self {
            Error::Usage(_) | Error::NoSuchDevice(_) => 2,
            _ => 5,
        }
    }

    /// Whether the connection should be opened again before the next try (the server
    /// went away, or the file was replaced).
    pub fn needs_reconnect(&self) -> bool {
        matches!(self, Error::Gone(_) | Error::Corrupt(_) | Error::Io(_))
    }

    /// The message without the kind.
    pub fn message(&self) -> &str {
        match self {
            Error::Usage(m)
            | Error::NoSuchDevice(m)
            | Error::Corrupt(m)
            | Error::Locked(m)
            | Error::Full(m)
            | Error::ReadOnly(m)
            | Error::Gone(m)
            | Error::Schema(m)
            | Error::Io(m)
            | Error::Database(m) => m,
        }
    }
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.message())
    }
}

impl std::error::Error for Error {}

impl From<Error> for (String, u8) {
    fn from(e: Error) -> Self {
        let code = e.exit_code();
        (e.to_string(), code)
    }
}
