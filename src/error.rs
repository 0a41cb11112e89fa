//! One error type for the library. Every variant says whether the user can fix it
//! (bad input, exit code 2) or something failed on our side or the system's (exit code 1).

use std::path::PathBuf;

/// The library's error. Messages name the file, field and value first and say what was
/// expected, so a user can act on them without reading the source.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Bad input: a model spec, a parameter, a direction, a grid spec, a flag combination.
    #[error("{0}")]
    Input(String),
    /// A file that is malformed, truncated or of an unsupported version.
    #[error("{path}: {msg}")]
    InvalidFile { path: String, msg: String },
    /// Reading or writing failed at the OS level.
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// A check ran and its bound was exceeded, or an internal step failed.
    #[error("{0}")]
    Failure(String),
}

impl Error {
    /// Shorthand for [`Error::Input`] from anything printable.
    pub fn input(msg: impl Into<String>) -> Self {
        Error::Input(msg.into())
    }

    /// A malformed file; `path` is shown as given (`-` for stdin).
    pub fn invalid_file(path: impl AsRef<std::path::Path>, msg: impl Into<String>) -> Self {
        Error::InvalidFile {
            path: display_path(path.as_ref()),
            msg: msg.into(),
        }
    }

    /// An I/O failure on `path`.
    pub fn io(path: impl AsRef<std::path::Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: display_path(path.as_ref()),
            source,
        }
    }

    /// The process exit code this error maps to: 2 for input the user can fix, 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Input(_) | Error::InvalidFile { .. } => 2,
            Error::Io { source, .. } => match source.kind() {
                // A missing or unreadable input file is the user's to fix.
                // So is a name that is too long, or a directory where a file is needed.
                std::io::ErrorKind::NotFound
                | std::io::ErrorKind::PermissionDenied
                | std::io::ErrorKind::InvalidFilename
                | std::io::ErrorKind::IsADirectory
                | std::io::ErrorKind::NotADirectory => 2,
                _ => 1,
            },
            Error::Failure(_) => 1,
        }
    }
}

fn display_path(p: &std::path::Path) -> String {
    if p.as_os_str() == "-" {
        "<stdin>".to_string()
    } else {
        PathBuf::from(p).display().to_string()
    }
}

/// The library's result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;
