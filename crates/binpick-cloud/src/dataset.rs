//! The labelled dataset layout that `binpick synth` writes and `binpick eval` reads.
//!
//! ```text
//! DATASET/models/<name>.pcd     model cloud, mm, in the object's frame
//! DATASET/models/<name>.json    {"diameter": mm, "symmetries": [[16 numbers, row-major 4x4], ...]}
//! DATASET/scenes/<id>.pcd       scene cloud, mm
//! DATASET/gt/<id>.json          {"scene": "scenes/<id>.pcd", "model": "<name>", "units": "mm",
//!                                "instances": [{"pose": [16 numbers, row-major, model -> scene],
//!                                               "visible_fraction": f, "pickable": bool}, ...]}
//! ```
//! Only instances of the named model are listed in a ground-truth file; other parts in the
//! scene are clutter. Symmetry lists include the identity.

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
    /// Share (0..1) of the model's points that the scan actually shows at the true pose.
    pub visible_fraction: f64,
    /// Whether a robot could pick it (the generator sets `visible_fraction >= 0.5`).
    pub pickable: bool,
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
        assert_eq!(ModelInfo::load(&path).unwrap().symmetries, vec![IDENTITY]);
    }
}
