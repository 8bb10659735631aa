//! The one error type of the library. Every fallible public function returns
//! `Result<T, lacuna::Error>`; the C API maps each variant to a status code.

use std::fmt;
use std::path::PathBuf;

#[derive(Debug)]
pub enum Error {
    /// An argument or input value is invalid; the message names it and its value.
    InvalidArgument(String),
    /// A file could not be read or written.
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A file was read but its content is malformed; `location` is a line or a field path.
    Parse {
        path: PathBuf,
        location: String,
        message: String,
    },
    /// A structure would exceed the memory budget the caller set.
    OverBudget {
        what: String,
        bytes: u64,
        budget: u64,
    },
    /// The operation was cancelled by the caller.
    Cancelled,
}

pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    pub fn invalid(msg: impl Into<String>) -> Self {
        Error::InvalidArgument(msg.into())
    }

    pub fn parse(
        path: impl Into<PathBuf>,
        location: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        Error::Parse {
            path: path.into(),
            location: location.into(),
            message: message.into(),
        }
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}

/// A worker pool that cannot start (the system refused a thread): the caller asked for more
/// than the machine gives.
impl From<rayon::ThreadPoolBuildError> for Error {
    fn from(e: rayon::ThreadPoolBuildError) -> Self {
        Error::invalid(format!("cannot start worker threads: {e}"))
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::InvalidArgument(m) => write!(f, "invalid argument: {m}"),
            Error::Io { path, source } => write!(f, "{}: {source}", path.display()),
            Error::Parse {
                path,
                location,
                message,
            } => {
                if location.is_empty() {
                    write!(f, "{}: {message}", path.display())
                } else {
                    write!(f, "{}:{location}: {message}", path.display())
                }
            }
            Error::OverBudget {
                what,
                bytes,
                budget,
            } => {
                write!(
                    f,
                    "{what} needs {bytes} bytes, over the memory budget of {budget} bytes"
                )
            }
            Error::Cancelled => write!(f, "cancelled"),
        }
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Error::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}
