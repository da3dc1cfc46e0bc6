//! Output frames: results come in the scanner's frame (the scene cloud's); a cell usually
//! wants them in its robot's base frame. An [`OutputFrame`] names that frame and holds the
//! rigid transform from the scanner's frame into it (the hand-eye calibration, mm).
//!
//! File form ([`OutputFrame::read`], `.toml` or `.json`):
//!
//! ```toml
//! frame_id = "base_link"          # optional, default "base"
//! scanner_to_base = [1, 0, 0, 400,  0, -1, 0, 0,  0, 0, -1, 1200,  0, 0, 0, 1]
//! ```
//!
//! `scanner_to_base` is row-major, translation in mm: a point `p` of the scan is
//! `scanner_to_base * p` in the base frame. It may also be written as four rows of four.

use std::path::Path;

use nalgebra::Isometry3;
use serde::Deserialize;

use binpick_cloud::{RowMajor4x4, pose_from_row_major};

use crate::error::{InputKind, Result, input, input_as};
use crate::result::SCANNER_FRAME_ID;

/// The name given to the robot's base frame when a calibration file does not name it.
pub const BASE_FRAME_ID: &str = "base";

/// A frame results can be expressed in: its name and the transform scanner -> it (mm).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct OutputFrame {
    /// The frame's name, written as the result's `frame_id` (e.g. ROS's `base_link`).
    pub frame_id: String,
    /// Maps scanner-frame coordinates (mm) into this frame (mm).
    pub scanner_to_frame: Isometry3<f64>,
}

/// A 4x4 as 16 numbers or as four rows of four.
#[derive(Deserialize)]
#[serde(untagged)]
enum Matrix {
    Flat(Vec<f64>),
    Rows(Vec<Vec<f64>>),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FrameFile {
    #[serde(default)]
    frame_id: Option<String>,
    scanner_to_base: Matrix,
}

impl OutputFrame {
    /// The scanner's own frame (the identity): what recognition returns.
    pub fn scanner() -> Self {
        Self {
            frame_id: SCANNER_FRAME_ID.to_owned(),
            scanner_to_frame: Isometry3::identity(),
        }
    }

    /// A frame named `frame_id` (non-empty) reached from the scanner's by `scanner_to_frame`.
    pub fn new(frame_id: &str, scanner_to_frame: Isometry3<f64>) -> Result<Self> {
        if frame_id.trim().is_empty() {
            return Err(input("output frame", "frame_id is empty"));
        }
        Ok(Self {
            frame_id: frame_id.to_owned(),
            scanner_to_frame,
        })
    }

    /// From a row-major 4x4 (translation in mm); refuses anything but a rigid transform.
    pub fn from_row_major(frame_id: &str, m: &RowMajor4x4) -> Result<Self> {
        let pose = pose_from_row_major(m)
            .map_err(|e| input("output frame", format!("scanner_to_base: {e}")))?;
        Self::new(frame_id, pose)
    }

    /// From text holding 16 numbers separated by commas and/or white space (row-major,
    /// mm), named [`BASE_FRAME_ID`].
    pub fn parse_matrix(text: &str) -> Result<Self> {
        let numbers: Vec<f64> = text
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .map(|s| {
                s.parse::<f64>()
                    .map_err(|_| input("output frame", format!("{s:?} in the 4x4 is not a number")))
            })
            .collect::<Result<_>>()?;
        let m = flat16(&numbers)?;
        Self::from_row_major(BASE_FRAME_ID, &m)
    }

    /// Reads a calibration file (`.toml`, or JSON for any other extension; see the module
    /// docs).
    pub fn read(path: &Path) -> Result<Self> {
        let bad = |m: String| input("output frame", format!("{}: {m}", path.display()));
        let parse = |m: String| {
            input_as(
                "output frame",
                InputKind::Parse,
                format!("{}: {m}", path.display()),
            )
        };
        let text = std::fs::read_to_string(path).map_err(|e| parse(e.to_string()))?;
        let is_toml = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
        let file: FrameFile = if is_toml {
            toml::from_str(&text).map_err(|e| parse(e.to_string()))?
        } else {
            serde_json::from_str(&text).map_err(|e| parse(e.to_string()))?
        };
        let m = match file.scanner_to_base {
            Matrix::Flat(v) => flat16(&v),
            Matrix::Rows(rows) => {
                if rows.len() != 4 || rows.iter().any(|r| r.len() != 4) {
                    Err(input(
                        "output frame",
                        "scanner_to_base: expected 16 numbers or 4 rows of 4",
                    ))
                } else {
                    flat16(&rows.concat())
                }
            }
        }
        .map_err(|e| bad(e.to_string()))?;
        let frame_id = file.frame_id.unwrap_or_else(|| BASE_FRAME_ID.to_owned());
        Self::from_row_major(&frame_id, &m).map_err(|e| bad(e.to_string()))
    }

    /// The same transform under another name.
    pub fn named(mut self, frame_id: &str) -> Result<Self> {
        self.frame_id = Self::new(frame_id, self.scanner_to_frame)?.frame_id;
        Ok(self)
    }

    /// Whether this is the scanner's frame itself.
    pub fn is_scanner(&self) -> bool {
        self.frame_id == SCANNER_FRAME_ID
    }
}

fn flat16(v: &[f64]) -> Result<RowMajor4x4> {
    <RowMajor4x4>::try_from(v).map_err(|_| {
        input(
            "output frame",
            format!(
                "scanner_to_base: expected 16 numbers (row-major 4x4), got {}",
                v.len()
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const M: &str = "0 -1 0 400, 1 0 0 -50, 0 0 1 1200, 0 0 0 1";

    #[test]
    fn a_matrix_on_the_command_line_and_in_files_gives_the_same_frame() {
        let f = OutputFrame::parse_matrix(M).unwrap();
        assert_eq!(f.frame_id, "base");
        let p = f.scanner_to_frame * nalgebra::Point3::new(10.0, 0.0, 0.0);
        assert!((p - nalgebra::Point3::new(400.0, -40.0, 1200.0)).norm() < 1e-12);
        let dir = tempfile::tempdir().unwrap();
        let toml = dir.path().join("cell.toml");
        std::fs::write(
            &toml,
            "frame_id = \"base_link\"\nscanner_to_base = [0, -1, 0, 400, 1, 0, 0, -50, 0, 0, 1, 1200, 0, 0, 0, 1]\n",
        )
        .unwrap();
        let json = dir.path().join("cell.json");
        std::fs::write(
            &json,
            r#"{"scanner_to_base": [[0,-1,0,400],[1,0,0,-50],[0,0,1,1200],[0,0,0,1]]}"#,
        )
        .unwrap();
        let t = OutputFrame::read(&toml).unwrap();
        let j = OutputFrame::read(&json).unwrap();
        assert_eq!(t.frame_id, "base_link");
        assert_eq!(j.frame_id, "base");
        assert_eq!(t.scanner_to_frame, f.scanner_to_frame);
        assert_eq!(j.scanner_to_frame, f.scanner_to_frame);
    }

    #[test]
    fn bad_calibrations_are_refused_with_the_reason() {
        for (text, want) in [
            ("1 0 0 0 0 1 0 0 0 0 1 0", "16 numbers"),
            ("2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", "rotation"),
            ("1 0 0 x 0 1 0 0 0 0 1 0 0 0 0 1", "not a number"),
        ] {
            let e = OutputFrame::parse_matrix(text).unwrap_err().to_string();
            assert!(e.contains(want), "{text}: {e}");
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cell.json");
        std::fs::write(&p, r#"{"scanner_to_base": [[1,0,0],[0,1,0],[0,0,1]]}"#).unwrap();
        let e = OutputFrame::read(&p).unwrap_err().to_string();
        assert!(e.contains("cell.json") && e.contains("4 rows of 4"), "{e}");
    }
}
