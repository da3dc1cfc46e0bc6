//! PCD and PLY reading and writing.
//!
//! PLACEHOLDER: this minimal version exists only so dependent crates compile; the full
//! implementation (all encodings, corrupt-file handling) replaces it. Signatures are final.

use std::path::{Path, PathBuf};

use crate::PointCloud;

/// Error reading or writing a cloud file. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
}

/// What was found while loading a cloud.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LoadReport {
    /// Points stored in the file (width x height for organised PCD).
    pub points_in_file: usize,
    /// Points dropped because a coordinate was NaN or infinite.
    pub non_finite_dropped: usize,
}

/// Reads a `.pcd` or `.ply` file (chosen by extension), dropping non-finite points.
pub fn read_cloud(path: &Path) -> Result<(PointCloud, LoadReport), IoError> {
    Err(IoError::Format {
        path: path.to_owned(),
        message: "reader not available yet".into(),
    })
}

/// Writes a binary PCD with fields `x y z` (float32).
pub fn write_pcd(path: &Path, cloud: &PointCloud) -> Result<(), IoError> {
    let n = cloud.len();
    let mut out = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n\
         TYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    .into_bytes();
    for p in &cloud.points {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    std::fs::write(path, out).map_err(|source| IoError::Io {
        path: path.to_owned(),
        source,
    })
}
