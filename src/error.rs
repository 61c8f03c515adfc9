//! The one error type every command returns, and the one exit-code rule:
//! 2 for bad input (nothing was written), 1 for a failure while working,
//! 130 when interrupted.

use std::fmt;

/// Why a command did not finish. The message is complete: it names the
/// file, field and value where there is one, and what to do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Error {
    /// The user's input (a file, a flag, a dataset folder) is not usable.
    Input(String),
    /// Something failed while working (a full disk, a failed write).
    Failure(String),
    /// Stopped by SIGINT or SIGTERM; what is complete is kept.
    Interrupted(String),
    /// What was asked for does not fit in memory (Python's `MemoryError`).
    Memory(String),
}

/// How the name of every folder a reader unpacks a packed dataset into
/// begins (`output::packs::Scratch`): a write failing there is the
/// reader's own ([`Error::is_own_write`]).
pub const UNPACK_FOLDER_PREFIX: &str = "causalcity-unpacked-";

impl Error {
    /// The process exit status for this error.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Input(_) => 2,
            Error::Failure(_) | Error::Memory(_) => 1,
            Error::Interrupted(_) => 130,
        }
    }

    /// Bad input, as a message.
    pub fn input(message: impl fmt::Display) -> Error {
        Error::Input(message.to_string())
    }

    /// A failure while working, as a message.
    pub fn failure(message: impl fmt::Display) -> Error {
        Error::Failure(message.to_string())
    }

    /// A reader's failure on the dataset at `dataset`: a write of its own
    /// (unpacking a packed dataset into `TMPDIR`: told "cannot write", as
    /// every write error of the output layer is, or "cannot make a folder
    /// to unpack into") is a failure; anything else, the dataset's damage
    /// ([`Error::damaged`]).
    pub fn reading(dataset: &std::path::Path, message: String) -> Error {
        if Error::is_own_write(&message) {
            Error::Failure(message)
        } else {
            Error::damaged(dataset, message)
        }
    }

    /// A reader's failure to open the dataset at hand: making the folder it
    /// unpacks a packed dataset into (a TMPDIR that cannot hold it) is a
    /// failure of its own; anything else, bad input. A TMPDIR that is a
    /// file exited 2, as if the dataset were the problem.
    pub fn opening(message: String) -> Error {
        if Error::is_own_write(&message) {
            Error::Failure(message)
        } else {
            Error::Input(message)
        }
    }

    /// Whether a reader's error `message` is a write of its own failing
    /// (see [`Error::reading`]), not the dataset's damage.
    pub fn is_own_write(message: &str) -> bool {
        // Told by where it writes, not by words a dataset's own path could
        // hold ("cannot write x" exited 1 for a folder of that name).
        message.starts_with("cannot make a folder to unpack into")
            || (message.contains("cannot write ") && message.contains(UNPACK_FOLDER_PREFIX))
    }

    /// A file of the dataset at `dataset` that is missing or cannot be read
    /// as causalcity wrote it: bad input (readers exited 1), told with how
    /// to find every problem.
    pub fn damaged(dataset: &std::path::Path, message: impl fmt::Display) -> Error {
        Error::Input(format!(
            "{message}\n{} is damaged: `causalcity validate {}` names every problem, and rerunning the command \
             that wrote it (gen, or counterfactual --sweep) repairs them",
            dataset.display(),
            dataset.display()
        ))
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Input(m) | Error::Failure(m) | Error::Interrupted(m) | Error::Memory(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for Error {}
