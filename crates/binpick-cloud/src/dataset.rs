//! The labelled dataset layout that `binpick synth` writes and `binpick eval` reads.
//!
//! ```text
//! DATASET/models/<name>.pcd     model cloud, mm, in the object's frame
//! DATASET/models/<name>.json    {"diameter": mm, "symmetries": [[16 numbers, row-major 4x4], ...],
//!                                optional "revolution_axis": {"point": [x,y,z], "direction": [x,y,z]}}
//! DATASET/models/<name>.stl     optional: the part's exact mesh (binary STL, mm, same frame)
//! DATASET/scenes/<id>.pcd       scene cloud, mm
//! DATASET/gt/<id>.json          {"scene": "scenes/<id>.pcd", "model": "<name>", "units": "mm",
//!                                "instances": [{"pose": [16 numbers, row-major, model -> scene],
//!                                               "visible_fraction": f, "pickable": bool,
//!                                               optional "visible_points": n, "alone_points": n}, ...]}
//! ```
//! Only instances of the named model are listed in a ground-truth file; other parts in the
//! scene are clutter. Symmetry lists include the identity.
//!
//! `visible_fraction` is BOP's visib_fract (`visible_points / alone_points`) on the datasets
//! of `binpick synth generalisation`. On the thesis's datasets (`synth thesis-conveyor`,
//! `thesis-arm`) it is the thesis's measure: the share of the model cloud's points (a top
//! view) the scan shows, which is near 0 for a part lying upside down however plainly it
//! shows; there `visible_points` and `alone_points` give BOP's as well
//! ([`GtInstance::bop_visible_fraction`]), the measure for a model that has every side (a CAD
//! mesh).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::{PoseError, RowMajor4x4, Units, pose_from_row_major};

/// `models/<name>.json`: what the evaluator needs to know about a model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelInfo {
    /// Largest distance between two points of the part, mm. A detection is correct when its
    /// mean model-point error is below 10 % of this.
    pub diameter: f64,
    /// Poses `S` with `model = S * model` (row-major 4x4), identity included. A part with a
    /// continuous symmetry lists samples of it.
    #[serde(default = "identity_only")]
    pub symmetries: Vec<RowMajor4x4>,
    /// For a part with a continuous rotational symmetry: the axis (model frame) about which
    /// any rotation maps it onto itself; `symmetries` then lists samples of those rotations.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub revolution_axis: Option<RevolutionAxis>,
}

/// A line in the model frame, mm: a point on it and its direction (any length but zero).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RevolutionAxis {
    pub point: [f64; 3],
    pub direction: [f64; 3],
}

fn identity_only() -> Vec<RowMajor4x4> {
    vec![IDENTITY]
}

/// The row-major 4x4 identity.
pub const IDENTITY: RowMajor4x4 = [
    1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
];

/// One labelled instance of the model in a scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GtInstance {
    /// Model frame -> scene frame, row-major 4x4, mm.
    pub pose: RowMajor4x4,
    /// Share (0..1) of the instance the scan shows at the true pose (BOP's visib_fract, or
    /// on the thesis's datasets the share of the model cloud's points: module docs).
    pub visible_fraction: f64,
    /// Whether a robot could pick it (the generator sets `visible_fraction >= 0.5`).
    pub pickable: bool,
    /// Scene points on this instance's surface (when the generator counted them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub visible_points: Option<u64>,
    /// Points the same scanner sees of this part alone in the same pose: with
    /// `visible_points`, BOP's visib_fract ([`Self::bop_visible_fraction`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alone_points: Option<u64>,
}

impl GtInstance {
    /// The share `visible / alone`, capped at 1, 0 when the part alone gives no point
    /// (unrounded).
    pub fn share_seen(visible: u64, alone: u64) -> f64 {
        if alone == 0 {
            0.0
        } else {
            (visible as f64 / alone as f64).min(1.0)
        }
    }

    /// A visible fraction as the generators write it: rounded to 4 decimals.
    pub fn round_fraction(fraction: f64) -> f64 {
        (fraction * 1e4).round() / 1e4
    }

    /// BOP's visib_fract from point counts, as written ([`Self::share_seen`], rounded).
    pub fn visib_fract(visible: u64, alone: u64) -> f64 {
        Self::round_fraction(Self::share_seen(visible, alone))
    }

    /// BOP's visible fraction of this instance when the generator counted its points (None
    /// otherwise): whatever the model, the share of the part the scan shows.
    pub fn bop_visible_fraction(&self) -> Option<f64> {
        Some(Self::visib_fract(self.visible_points?, self.alone_points?))
    }
}

/// `gt/<id>.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroundTruth {
    /// Scene cloud path relative to the dataset root, e.g. `scenes/0001.pcd`.
    pub scene: String,
    /// Model name: `models/<model>.pcd` and `models/<model>.json`.
    pub model: String,
    /// Units of poses and clouds; always `mm` for datasets binpick writes.
    #[serde(default)]
    pub units: Units,
    pub instances: Vec<GtInstance>,
}

/// Error reading or writing dataset files.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: invalid JSON: {source}")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{path}: instance {index}: {source}")]
    BadPose {
        path: PathBuf,
        index: usize,
        source: PoseError,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|source| DatasetError::Io {
        path: path.to_owned(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|source| DatasetError::Json {
        path: path.to_owned(),
        source,
    })
}

/// Writes `value` as pretty JSON, creating parent folders.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), DatasetError> {
    let io = |source| DatasetError::Io {
        path: path.to_owned(),
        source,
    };
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(io)?;
    }
    let text = serde_json::to_string_pretty(value).map_err(|source| DatasetError::Json {
        path: path.to_owned(),
        source,
    })?;
    std::fs::write(path, text + "\n").map_err(io)
}

impl ModelInfo {
    /// Reads and validates `models/<name>.json`.
    pub fn load(path: &Path) -> Result<Self, DatasetError> {
        let info: ModelInfo = read_json(path)?;
        if !(info.diameter.is_finite() && info.diameter > 0.0) {
            return Err(DatasetError::Invalid {
                path: path.to_owned(),
                message: format!(
                    "diameter must be a positive number of mm, got {}",
                    info.diameter
                ),
            });
        }
        if info.symmetries.is_empty() {
            return Err(DatasetError::Invalid {
                path: path.to_owned(),
                message: "symmetries is empty: list at least the identity".into(),
            });
        }
        for (index, s) in info.symmetries.iter().enumerate() {
            pose_from_row_major(s).map_err(|source| DatasetError::BadPose {
                path: path.to_owned(),
                index,
                source,
            })?;
        }
        if let Some(axis) = &info.revolution_axis {
            let d = axis.direction;
            let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let finite = axis.point.iter().chain(&d).all(|v| v.is_finite());
            if !finite || norm < 1e-9 {
                return Err(DatasetError::Invalid {
                    path: path.to_owned(),
                    message: format!(
                        "revolution_axis needs a finite point and a non-zero direction, got {axis:?}"
                    ),
                });
            }
        }
        Ok(info)
    }
}

impl GroundTruth {
    /// Reads and validates `gt/<id>.json`.
    pub fn load(path: &Path) -> Result<Self, DatasetError> {
        let gt: GroundTruth = read_json(path)?;
        for (index, inst) in gt.instances.iter().enumerate() {
            pose_from_row_major(&inst.pose).map_err(|source| DatasetError::BadPose {
                path: path.to_owned(),
                index,
                source,
            })?;
            if !(0.0..=1.0).contains(&inst.visible_fraction) {
                return Err(DatasetError::Invalid {
                    path: path.to_owned(),
                    message: format!(
                        "instance {index}: visible_fraction {} is outside 0..1",
                        inst.visible_fraction
                    ),
                });
            }
        }
        Ok(gt)
    }
}

/// A dataset folder: the ground-truth files it holds, sorted by scene id.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub root: PathBuf,
    /// Scene ids (file stems of `gt/*.json`), sorted.
    pub scene_ids: Vec<String>,
}

impl Dataset {
    /// Opens a dataset folder and lists its labelled scenes.
    pub fn open(root: &Path) -> Result<Self, DatasetError> {
        let gt_dir = root.join("gt");
        let entries = std::fs::read_dir(&gt_dir).map_err(|source| DatasetError::Io {
            path: gt_dir.clone(),
            source,
        })?;
        let mut scene_ids = Vec::new();
        for entry in entries {
            let entry = entry.map_err(|source| DatasetError::Io {
                path: gt_dir.clone(),
                source,
            })?;
            let path = entry.path();
            if path.extension().is_some_and(|e| e == "json")
                && let Some(stem) = path.file_stem().and_then(|s| s.to_str())
            {
                scene_ids.push(stem.to_owned());
            }
        }
        if scene_ids.is_empty() {
            return Err(DatasetError::Invalid {
                path: gt_dir,
                message: "no ground-truth files (*.json) found".into(),
            });
        }
        scene_ids.sort();
        Ok(Self {
            root: root.to_owned(),
            scene_ids,
        })
    }

    pub fn gt_path(&self, id: &str) -> PathBuf {
        self.root.join("gt").join(format!("{id}.json"))
    }

    pub fn model_cloud_path(&self, model: &str) -> PathBuf {
        self.root.join("models").join(format!("{model}.pcd"))
    }

    pub fn model_info_path(&self, model: &str) -> PathBuf {
        self.root.join("models").join(format!("{model}.json"))
    }

    /// `models/<model>.stl`, the part's exact mesh where the dataset ships one.
    pub fn model_mesh_path(&self, model: &str) -> PathBuf {
        self.root.join("models").join(format!("{model}.stl"))
    }

    /// Resolves a ground-truth file's `scene` entry against the dataset root.
    pub fn scene_path(&self, gt: &GroundTruth) -> PathBuf {
        self.root.join(&gt.scene)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ground_truth_round_trip_and_validation() {
        let dir = tempfile::tempdir().unwrap();
        let gt = GroundTruth {
            scene: "scenes/0001.pcd".into(),
            model: "A".into(),
            units: Units::Millimetres,
            instances: vec![GtInstance {
                pose: IDENTITY,
                visible_fraction: 0.8,
                pickable: true,
                visible_points: None,
                alone_points: None,
            }],
        };
        let path = dir.path().join("gt/0001.json");
        write_json(&path, &gt).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("\"units\": \"mm\""), "{text}");
        assert_eq!(GroundTruth::load(&path).unwrap(), gt);
        let ds = Dataset::open(dir.path()).unwrap();
        assert_eq!(ds.scene_ids, vec!["0001".to_string()]);

        let mut bad = gt.clone();
        bad.instances[0].pose[0] = 2.0;
        write_json(&path, &bad).unwrap();
        let err = GroundTruth::load(&path).unwrap_err().to_string();
        assert!(err.contains("instance 0"), "{err}");
    }

    #[test]
    fn model_info_needs_positive_diameter() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.json");
        std::fs::write(&path, r#"{"diameter": -1, "symmetries": []}"#).unwrap();
        assert!(
            ModelInfo::load(&path)
                .unwrap_err()
                .to_string()
                .contains("diameter")
        );
        std::fs::write(&path, r#"{"diameter": 120.5}"#).unwrap();
        let old = ModelInfo::load(&path).unwrap();
        assert_eq!(old.symmetries, vec![IDENTITY]);
        assert_eq!(old.revolution_axis, None);
        // Files without the optional fields are written without them.
        write_json(&path, &old).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(!text.contains("revolution_axis"), "{text}");
    }

    #[test]
    fn revolution_axis_round_trips_and_is_validated() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("shaft.json");
        let info = ModelInfo {
            diameter: 82.0,
            symmetries: vec![IDENTITY],
            revolution_axis: Some(RevolutionAxis {
                point: [0.0, 0.0, 0.0],
                direction: [0.0, 0.0, 1.0],
            }),
        };
        write_json(&path, &info).unwrap();
        assert_eq!(ModelInfo::load(&path).unwrap(), info);
        std::fs::write(
            &path,
            r#"{"diameter": 82, "revolution_axis": {"point": [0, 0, 0], "direction": [0, 0, 0]}}"#,
        )
        .unwrap();
        let err = ModelInfo::load(&path).unwrap_err().to_string();
        assert!(err.contains("revolution_axis"), "{err}");
    }

    #[test]
    fn visible_and_alone_point_counts_are_optional() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("gt/s.json");
        let mut gt = GroundTruth {
            scene: "scenes/s.pcd".into(),
            model: "ring".into(),
            units: Units::Millimetres,
            instances: vec![GtInstance {
                pose: IDENTITY,
                visible_fraction: 0.25,
                pickable: false,
                visible_points: Some(100),
                alone_points: Some(400),
            }],
        };
        write_json(&path, &gt).unwrap();
        assert_eq!(GroundTruth::load(&path).unwrap(), gt);
        gt.instances[0].visible_points = None;
        gt.instances[0].alone_points = None;
        write_json(&path, &gt).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(!text.contains("_points"), "{text}");
        assert_eq!(GroundTruth::load(&path).unwrap(), gt);
    }
}
