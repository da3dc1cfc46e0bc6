//! The library's error type: every variant says what went wrong and where.

use crate::params::ParamError;

/// Everything that can go wrong in a recognition. No variant is a panic in disguise: a cell
/// controller can match on it and carry on with the next scan.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A parameter is out of its range (the field, its value and the expected range).
    #[error(transparent)]
    Params(#[from] ParamError),
    /// The model or scene cloud, or a declaration, is unusable; `kind` says how (wrong
    /// units, empty, degenerate, ...) so a caller can react without reading `message`.
    #[error("{what}: {message}")]
    Input {
        /// What was unusable: "scene", "model", "model sidecar", "output frame", ...
        what: &'static str,
        /// The kind of problem.
        kind: InputKind,
        /// The problem in words (library field names, never command-line flags).
        message: String,
    },
    /// A PCL stage failed.
    #[error("{stage}: {source}")]
    Pcl {
        /// The stage that called PCL.
        stage: &'static str,
        /// The bridge's error.
        source: binpick_pcl::Error,
    },
    /// The time budget ran out or the call was cancelled while `stage` ran. Stages and
    /// engines unwind with it; `Recognizer::recognize*` never return it: they return what was
    /// verified so far with `Recognition::interrupted` set.
    #[error("interrupted during {stage} (time budget or cancellation)")]
    Interrupted {
        /// The stage that noticed the stop.
        stage: &'static str,
    },
    /// A cloud or mesh file could not be read (missing, corrupt, truncated).
    #[error(transparent)]
    Io(#[from] binpick_cloud::io::IoError),
    /// A labelled dataset is malformed.
    #[error(transparent)]
    Dataset(#[from] binpick_cloud::dataset::DatasetError),
    /// The worker threads could not be started, or one panicked.
    #[error("worker threads: {0}")]
    Threads(String),
}

/// How an input was unusable ([`Error::Input`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum InputKind {
    /// The cloud's size is implausible for millimetres: it looks like metres (or another
    /// unit). Set `Params::units` (`units = "m"`) or scale the cloud.
    WrongUnits,
    /// No points: an empty cloud, none inside the region of interest, or all of them strays.
    EmptyCloud,
    /// A point with a NaN or infinite coordinate where none is allowed.
    NonFinite,
    /// Degenerate geometry: all points coincide or lie on a line or plane, or too few points
    /// (or keypoints, normals, descriptors) remain to work with.
    Degenerate,
    /// A file that could not be parsed (model sidecar, calibration).
    Parse,
    /// A declared or computed value is unusable (a grasp, a frame, the sensor, a pose).
    Invalid,
    /// Something the library produced itself is inconsistent (a bug: please report it).
    Internal,
}

/// The kind of any [`Error`], for a controller's `match`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// Bad input ([`Error::Input`]), with how it was bad.
    Input(InputKind),
    /// A parameter out of range ([`Error::Params`]).
    Parameter,
    /// A PCL call failed ([`Error::Pcl`]).
    Pcl,
    /// The time budget ran out or the call was cancelled ([`Error::Interrupted`]; never
    /// returned by `Recognizer::recognize*`, which return partial results instead).
    Budget,
    /// A file could not be read or parsed ([`Error::Io`], [`Error::Dataset`]).
    File,
    /// The worker threads failed ([`Error::Threads`]).
    Threads,
}

impl Error {
    /// This error's kind.
    pub fn kind(&self) -> ErrorKind {
        match self {
            Error::Params(_) => ErrorKind::Parameter,
            Error::Input { kind, .. } => ErrorKind::Input(*kind),
            Error::Pcl { .. } => ErrorKind::Pcl,
            Error::Interrupted { .. } => ErrorKind::Budget,
            Error::Io(_) | Error::Dataset(_) => ErrorKind::File,
            Error::Threads(_) => ErrorKind::Threads,
        }
    }
}

/// Result alias for the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Maps a bridge error to this stage; an interruption noticed inside PCL stays one.
pub(crate) fn pcl(stage: &'static str) -> impl Fn(binpick_pcl::Error) -> Error {
    move |source| match source {
        binpick_pcl::Error::Interrupted { .. } => Error::Interrupted { stage },
        source => Error::Pcl { stage, source },
    }
}

/// Maps an error of the matching crate to this stage: degenerate input (too few points,
/// no surface to match).
pub(crate) fn matching(stage: &'static str) -> impl Fn(binpick_match::MatchError) -> Error {
    move |e| Error::Input {
        what: stage,
        kind: InputKind::Degenerate,
        message: e.to_string(),
    }
}

/// An [`Error::Input`] about `what` of kind [`InputKind::Invalid`].
pub fn input(what: &'static str, message: impl Into<String>) -> Error {
    input_as(what, InputKind::Invalid, message)
}

/// An [`Error::Input`] about `what` of `kind`.
pub fn input_as(what: &'static str, kind: InputKind, message: impl Into<String>) -> Error {
    Error::Input {
        what,
        kind,
        message: message.into(),
    }
}
