//! The library's error type: every variant says what went wrong and where.

use crate::params::ParamError;

/// Everything that can go wrong in a recognition. No variant is a panic in disguise: a cell
/// controller can match on it and carry on with the next scan.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Params(#[from] ParamError),
    /// The model or scene cloud is unusable (empty, non-finite, wrong units, too small).
    #[error("{what}: {message}")]
    Input { what: &'static str, message: String },
    /// A PCL stage failed.
    #[error("{stage}: {source}")]
    Pcl {
        stage: &'static str,
        source: binpick_pcl::Error,
    },
    /// The caller's time budget ran out.
    #[error("time budget of {budget_ms} ms exceeded during {stage} ({elapsed_ms} ms elapsed)")]
    TimeBudget {
        budget_ms: u64,
        elapsed_ms: u64,
        stage: &'static str,
    },
    #[error(transparent)]
    Io(#[from] binpick_cloud::io::IoError),
    #[error(transparent)]
    Dataset(#[from] binpick_cloud::dataset::DatasetError),
    #[error("worker threads: {0}")]
    Threads(String),
}

/// Result alias for the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

pub(crate) fn pcl(stage: &'static str) -> impl Fn(binpick_pcl::Error) -> Error {
    move |source| Error::Pcl { stage, source }
}

/// An [`Error::Input`] about `what`.
pub fn input(what: &'static str, message: impl Into<String>) -> Error {
    Error::Input {
        what,
        message: message.into(),
    }
}
