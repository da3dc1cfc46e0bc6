//! The JSON written for every recognition (`binpick recognize --json`, `eval`, `replay`).
//!
//! ```json
//! {
//!   "scene": "scan.pcd", "model": "part.pcd", "units": "mm", "algorithm": 1, "engine": "rust",
//!   "params": { ...every parameter actually used... },
//!   "detections": [
//!     { "rank": 1,
//!       "pose": [16 numbers, row-major 4x4, model -> scene, mm],
//!       "translation": [x, y, z], "quaternion_wxyz": [w, x, y, z],
//!       "initial_score": 0.88,      // Euclidean score, mm^2 (thesis 3.1.1)
//!       "final_score": 0.0,         // percent of outliers (3.1.2)
//!       "score_before_icp": 0.0, "cluster": 1, "cluster_round": 0,
//!       "fpfh_radius_mm": 30.0, "sac_threshold_mm": 1.0, "sac_inliers": 412,
//!       "icp": { "converged": true, "iterations": 9, "fitness_mm2": 0.41, "adopted": true },
//!       "height_mm": 13.6, "rank_reason": "occlusion band 0.0-2.0 % ..." } ],
//!   "preprocess": { "input_points": ..., "outside_roi": ..., "voxel_merged": ..., "support_planes": [...], "remaining": ... },
//!   "clusters": [ { "index": 0, "points": 11982, "detections": 1, "outcome": "..." } ],
//!   "duplicates_suppressed": 0,
//!   "timings_ms": { "model_preparation_ms": ..., "preprocess_ms": ..., "clustering_ms": ...,
//!                   "initial_alignment_ms": ..., "final_alignment_ms": ..., "ranking_ms": ..., "total_ms": ... }
//! }
//! ```

use serde::{Deserialize, Serialize};

use crate::align::IcpReport;
use crate::params::Params;
use crate::pose::{quaternion_wxyz, to_mat4};
use crate::recognizer::{ClusterReport, Detection, Recognition, Timings};
use crate::scene::PreprocessReport;

/// One detection as written to JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DetectionRecord {
    pub rank: usize,
    /// Row-major 4x4, model -> scene, mm.
    pub pose: [f64; 16],
    pub translation: [f64; 3],
    pub quaternion_wxyz: [f64; 4],
    pub initial_score: f64,
    pub final_score: f64,
    pub score_before_icp: f64,
    pub cluster: usize,
    pub cluster_round: usize,
    pub fpfh_radius_mm: Option<f64>,
    pub sac_threshold_mm: f64,
    pub sac_inliers: usize,
    pub icp: IcpReport,
    pub height_mm: f64,
    pub rank_reason: String,
}

impl From<&Detection> for DetectionRecord {
    fn from(d: &Detection) -> Self {
        let t = d.pose.translation.vector;
        Self {
            rank: d.rank,
            pose: to_mat4(&d.pose),
            translation: [t.x, t.y, t.z],
            quaternion_wxyz: quaternion_wxyz(&d.pose),
            initial_score: d.initial_score,
            final_score: d.final_score,
            score_before_icp: d.score_before_icp,
            cluster: d.cluster,
            cluster_round: d.cluster_round,
            fpfh_radius_mm: d.fpfh_radius_mm,
            sac_threshold_mm: d.sac_threshold_mm,
            sac_inliers: d.sac_inliers,
            icp: d.icp.clone(),
            height_mm: d.height_mm,
            rank_reason: d.rank_reason.clone(),
        }
    }
}

/// The whole JSON document for one scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RecognitionReport {
    pub scene: String,
    pub model: String,
    /// Always "mm": poses, scores and timings refer to millimetre clouds.
    pub units: String,
    /// Units of the model file (the scene's are `params.units`); lets `binpick show` reload
    /// both clouds.
    #[serde(default)]
    pub model_units: binpick_cloud::Units,
    pub algorithm: u8,
    /// "rust" (this library) or "reference" (the plain C++ PCL pipeline).
    pub engine: String,
    pub params: Params,
    pub detections: Vec<DetectionRecord>,
    pub preprocess: PreprocessReport,
    pub clusters: Vec<ClusterReport>,
    pub duplicates_suppressed: usize,
    pub timings_ms: Timings,
}

impl RecognitionReport {
    pub fn new(scene: &str, model: &str, engine: &str, params: &Params, r: &Recognition) -> Self {
        Self {
            scene: scene.to_owned(),
            model: model.to_owned(),
            units: "mm".to_owned(),
            model_units: params.units,
            algorithm: params.algorithm.number(),
            engine: engine.to_owned(),
            params: params.clone(),
            detections: r.detections.iter().map(DetectionRecord::from).collect(),
            preprocess: r.preprocess.clone(),
            clusters: r.clusters.clone(),
            duplicates_suppressed: r.duplicates_suppressed,
            timings_ms: r.timings.clone(),
        }
    }
}
