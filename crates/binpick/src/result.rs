//! What a recognition returns, as plain data: [`Recognition`] with its [`Detection`]s and
//! reports, and [`RecognitionReport`], the JSON document written for every scene
//! (`binpick recognize --json`, `eval`, `replay`). Every stage above produces these types;
//! this module imports nothing of the pipeline (only the parameters a report embeds).
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
//!       "height_mm": 13.6, "rank_reason": "occlusion band 0.0-2.0 % ...",
//!       "initial_pose": [16 numbers] } ],
//!   "preprocess": { "input_points": ..., "outside_roi": ..., "voxel_merged": ..., "support_planes": [...], "remaining": ... },
//!   "clusters": [ { "index": 0, "points": 11982, "detections": 1, "outcome": "..." } ],
//!   "duplicates_suppressed": 0,
//!   "timings_ms": { "model_preparation_ms": ..., "preprocess_ms": ..., "clustering_ms": ...,
//!                   "initial_alignment_ms": ..., "final_alignment_ms": ..., "ranking_ms": ..., "total_ms": ... }
//! }
//! ```

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use binpick_cloud::{RowMajor4x4, pose_from_row_major, pose_to_row_major};

use crate::params::Params;

/// One accepted instance of the model. Serialises to the JSON detection record above.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(try_from = "DetectionJson")]
pub struct Detection {
    /// 1 = pick first.
    pub rank: usize,
    /// Model frame -> scene frame (final x initial), mm.
    pub pose: Isometry3<f64>,
    /// The initial alignment's pose.
    pub initial_pose: Isometry3<f64>,
    /// Euclidean score of the initial alignment (3.1.1), mm^2; lower is better.
    pub initial_score: f64,
    /// Percent of outliers of the final pose (3.1.2); lower is better (less occluded).
    pub final_score: f64,
    /// Percent of outliers before ICP.
    pub score_before_icp: f64,
    /// How the engine found it.
    pub found_by: FoundBy,
    /// The scene-voting engine's verification against the sensor's view (None from the
    /// thesis engine).
    pub view: Option<ViewCheck>,
    pub icp: IcpReport,
    /// Height of the placed model's centroid along `up`, mm.
    pub height_mm: f64,
    /// Why it ranks where it does.
    pub rank_reason: String,
}

/// How an engine found a detection.
#[derive(Clone, Debug, PartialEq)]
pub enum FoundBy {
    /// The thesis engine: Algorithm 1/2 in a Euclidean cluster.
    Cluster {
        /// Index of the Euclidean cluster (clusters ordered by first point index).
        cluster: usize,
        /// 0 for the first part found in a cluster, 1 for the next touching part, ...
        round: usize,
        /// FPFH radius that won the initial alignment (None with Algorithm 2), mm.
        fpfh_radius_mm: Option<f64>,
        /// RANSAC threshold that won, mm.
        sac_threshold_mm: f64,
        sac_inliers: usize,
    },
    /// The scene-voting engine: a pose cluster of point-pair votes.
    Voting {
        /// Summed votes of the pose cluster.
        votes: u32,
        /// Index of the hypothesis (strongest first).
        hypothesis: usize,
    },
}

/// A hypothesis judged against the sensor's view, as shares of the surface the sensor would
/// see of the part alone in that pose (grid cells of the view).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewCheck {
    /// Share confirmed by the scene: the estimated visible fraction.
    pub visibility: f64,
    /// Share the sensor saw through (a surface behind the model): contradictions.
    pub free_space: f64,
    /// Share hidden by something other than the belt or bin (a part lying on it).
    pub covered: f64,
    /// Share with no measurement at all (shadow or absent surface).
    pub missing: f64,
    /// Share of its outline the scene's surface carries on past (a pose laid across other
    /// surfaces rather than on a part).
    #[serde(default)]
    pub continued: f64,
    /// Mean fit weight of the confirmed surface (1 = the scene lies exactly on the model).
    #[serde(default)]
    pub fit: f64,
    /// Cells the model covers as the sensor would see it alone.
    pub visible_cells: u32,
}

impl Detection {
    /// The thesis engine's cluster, if it came from one.
    pub fn cluster(&self) -> Option<usize> {
        match self.found_by {
            FoundBy::Cluster { cluster, .. } => Some(cluster),
            FoundBy::Voting { .. } => None,
        }
    }

    /// Order among detections of one engine when everything else ties: cluster and round,
    /// or hypothesis index.
    pub(crate) fn found_order(&self) -> (usize, usize) {
        match self.found_by {
            FoundBy::Cluster { cluster, round, .. } => (cluster, round),
            FoundBy::Voting { hypothesis, .. } => (hypothesis, 0),
        }
    }
}

/// The JSON record: poses as 16 numbers, row-major, plus the translation and quaternion of
/// the final pose for readers that want them (ignored on load).
impl Serialize for Detection {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let t = self.pose.translation.vector;
        let q = self.pose.rotation.quaternion();
        let mut r = s.serialize_struct("Detection", 16)?;
        r.serialize_field("rank", &self.rank)?;
        r.serialize_field("pose", &pose_to_row_major(&self.pose))?;
        r.serialize_field("translation", &[t.x, t.y, t.z])?;
        r.serialize_field("quaternion_wxyz", &[q.w, q.i, q.j, q.k])?;
        r.serialize_field("initial_score", &self.initial_score)?;
        r.serialize_field("final_score", &self.final_score)?;
        r.serialize_field("score_before_icp", &self.score_before_icp)?;
        match &self.found_by {
            FoundBy::Cluster {
                cluster,
                round,
                fpfh_radius_mm,
                sac_threshold_mm,
                sac_inliers,
            } => {
                r.serialize_field("cluster", cluster)?;
                r.serialize_field("cluster_round", round)?;
                r.serialize_field("fpfh_radius_mm", fpfh_radius_mm)?;
                r.serialize_field("sac_threshold_mm", sac_threshold_mm)?;
                r.serialize_field("sac_inliers", sac_inliers)?;
            }
            FoundBy::Voting { votes, hypothesis } => {
                r.serialize_field("votes", votes)?;
                r.serialize_field("hypothesis", hypothesis)?;
            }
        }
        if let Some(v) = &self.view {
            r.serialize_field("view", v)?;
        }
        r.serialize_field("icp", &self.icp)?;
        r.serialize_field("height_mm", &self.height_mm)?;
        r.serialize_field("rank_reason", &self.rank_reason)?;
        r.serialize_field("initial_pose", &pose_to_row_major(&self.initial_pose))?;
        r.end()
    }
}

/// A detection record as read back. `initial_pose` is absent from results written before it
/// was added; those load with the final pose in its place.
#[derive(Deserialize)]
struct DetectionJson {
    rank: usize,
    pose: RowMajor4x4,
    initial_score: f64,
    final_score: f64,
    score_before_icp: f64,
    #[serde(default)]
    cluster: Option<usize>,
    #[serde(default)]
    cluster_round: Option<usize>,
    #[serde(default)]
    fpfh_radius_mm: Option<f64>,
    #[serde(default)]
    sac_threshold_mm: Option<f64>,
    #[serde(default)]
    sac_inliers: Option<usize>,
    #[serde(default)]
    votes: Option<u32>,
    #[serde(default)]
    hypothesis: Option<usize>,
    #[serde(default)]
    view: Option<ViewCheck>,
    icp: IcpReport,
    height_mm: f64,
    rank_reason: String,
    #[serde(default)]
    initial_pose: Option<RowMajor4x4>,
}

impl TryFrom<DetectionJson> for Detection {
    type Error = String;
    fn try_from(d: DetectionJson) -> Result<Self, String> {
        let pose = pose_from_row_major(&d.pose).map_err(|e| format!("detection pose: {e}"))?;
        let initial_pose = match d.initial_pose {
            Some(m) => pose_from_row_major(&m).map_err(|e| format!("initial_pose: {e}"))?,
            None => pose,
        };
        let found_by = match (d.votes, d.cluster) {
            (Some(votes), _) => FoundBy::Voting {
                votes,
                hypothesis: d.hypothesis.unwrap_or(0),
            },
            (None, Some(cluster)) => FoundBy::Cluster {
                cluster,
                round: d.cluster_round.unwrap_or(0),
                fpfh_radius_mm: d.fpfh_radius_mm,
                sac_threshold_mm: d.sac_threshold_mm.unwrap_or(f64::NAN),
                sac_inliers: d.sac_inliers.unwrap_or(0),
            },
            (None, None) => {
                return Err(
                    "detection has neither `votes` nor `cluster`: which engine found it?".into(),
                );
            }
        };
        Ok(Self {
            rank: d.rank,
            pose,
            initial_pose,
            initial_score: d.initial_score,
            final_score: d.final_score,
            score_before_icp: d.score_before_icp,
            found_by,
            view: d.view,
            icp: d.icp,
            height_mm: d.height_mm,
            rank_reason: d.rank_reason,
        })
    }
}

/// What ICP did for one detection.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IcpReport {
    pub converged: bool,
    pub iterations: u32,
    /// PCL's fitness: mean squared distance of matched points, mm^2 (None if ICP failed or
    /// matched nothing).
    pub fitness_mm2: Option<f64>,
    /// Whether the ICP pose scored better than the initial one and was adopted (step 3d).
    pub adopted: bool,
    /// Set when PCL's ICP failed; the initial pose is kept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl IcpReport {
    /// PCL's fitness score when it is meaningful (finite, not PCL's "matched nothing" value).
    pub(crate) fn usable_fitness(fitness: f64) -> Option<f64> {
        (fitness.is_finite() && fitness < 1e300).then_some(fitness)
    }
}

/// What happened in one cluster.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClusterReport {
    pub index: usize,
    pub points: usize,
    pub detections: usize,
    /// Spheres the cluster was searched in (1 when searched whole).
    #[serde(default)]
    pub regions: usize,
    /// Why the search in this cluster stopped (see [`SearchStop`]).
    pub outcome: String,
}

/// Why the search of a cluster (or of a region of one) stopped; both engines word their
/// cluster outcomes through [`SearchStop::outcome`].
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum SearchStop {
    /// Nothing was searched (a pile with no sphere big enough).
    NoCandidate,
    FewKeypoints,
    NoConsensus,
    /// Step 2: the best initial alignment's Euclidean score, mm^2, and the limit.
    InitialRejected {
        score: f64,
        max: f64,
    },
    /// Step 4: the final percent of outliers and the limit.
    FinalRejected {
        score: f64,
        max: f64,
    },
    Accepted,
    ExplainsTooFew,
    RoundLimit,
}

impl std::fmt::Display for SearchStop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SearchStop::NoCandidate => write!(f, "no candidate"),
            SearchStop::FewKeypoints => write!(f, "fewer than 3 keypoints"),
            SearchStop::NoConsensus => write!(f, "no RANSAC consensus"),
            SearchStop::InitialRejected { score, max } => {
                write!(f, "initial score {score:.1} >= {max}")
            }
            SearchStop::FinalRejected { score, max } => {
                write!(f, "final score {score:.1} % >= {max} %")
            }
            SearchStop::Accepted => write!(f, "accepted"),
            SearchStop::ExplainsTooFew => write!(
                f,
                "accepted part explains too few cluster points to search further"
            ),
            SearchStop::RoundLimit => write!(f, "round limit reached"),
        }
    }
}

impl SearchStop {
    /// A cluster's outcome line: the last stop, after the detections made before it.
    pub(crate) fn outcome(&self, detections: usize) -> String {
        match detections {
            0 => self.to_string(),
            n => format!("{n} detection(s); then {self}"),
        }
    }
}

/// Wall-clock time per stage, milliseconds. `initial_alignment_ms` and `final_alignment_ms`
/// add up the work of all worker threads, so with parallel clusters they can exceed `total_ms`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// Model preparation in `Recognizer::new` (once per model, not per scene).
    pub model_preparation_ms: f64,
    pub preprocess_ms: f64,
    pub clustering_ms: f64,
    pub initial_alignment_ms: f64,
    pub final_alignment_ms: f64,
    pub ranking_ms: f64,
    pub total_ms: f64,
}

/// Every value derived for one scan, recorded in each result.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DerivedScale {
    /// Measured on the model.
    pub model_diameter_mm: f64,
    pub part_view_area_mm2: f64,
    /// Measured on the scan (None when the resolution was given).
    pub scan_spacing_mm: Option<f64>,
    pub scan_gap_mm: Option<f64>,
    /// Derived.
    pub resolution_mm: f64,
    pub connect_mm: f64,
    pub support_distance_mm: f64,
    pub sampling_step_mm: f64,
    pub normal_radius_mm: f64,
    pub cell_mm: f64,
    pub tolerance_mm: f64,
    /// Points one part's visible surface holds at the working resolution.
    pub part_points: f64,
}

/// One removed supporting plane.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RemovedPlane {
    /// `a x + b y + c z + d = 0`, unit normal, mm.
    pub coefficients: [f32; 4],
    pub points: usize,
}

/// What preprocessing did, in points.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PreprocessReport {
    pub input_points: usize,
    /// Dropped by the region of interest.
    pub outside_roi: usize,
    /// Merged away by the voxel grid.
    pub voxel_merged: usize,
    /// Removed as supporting surface, plane by plane.
    pub support_planes: Vec<RemovedPlane>,
    /// Points left for clustering.
    pub remaining: usize,
}

/// What the scene-voting engine did, for diagnostics.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VotingReport {
    /// The sensor the view was built for ("camera at (x, y, z) mm" or "above along (x, y, z)").
    pub sensor: String,
    /// Scene samples with a normal (they vote).
    pub scene_samples: usize,
    /// Votes cast (peaks of all reference points).
    pub votes: usize,
    /// Pose clusters verified.
    pub hypotheses: usize,
    /// Candidates verified (hypotheses plus their near-symmetry variants).
    pub candidates: usize,
    /// Candidates taken as parts.
    pub accepted: usize,
    /// Candidates refused: too little confirmed surface, too little of the visible surface
    /// confirmed, too much free space, or surface already explained by a taken part.
    pub rejected_too_little_surface: usize,
    pub rejected_low_visibility: usize,
    pub rejected_free_space: usize,
    #[serde(default)]
    pub rejected_no_outline: usize,
    #[serde(default)]
    pub rejected_poor_fit: usize,
    pub rejected_explained: usize,
    /// The best refused candidate that was not a repeat of a taken part, when there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub best_refused: Option<RefusedCandidate>,
    /// Every verified candidate (with `report_candidates`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub candidates_detail: Vec<CandidateRecord>,
}

/// One verified candidate (`report_candidates`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CandidateRecord {
    pub hypothesis: usize,
    pub votes: u32,
    /// Row-major 4x4, model -> scene, after refinement.
    pub pose: RowMajor4x4,
    pub view: ViewCheck,
    pub explained_cells: u32,
    /// "taken", or why it was refused.
    pub verdict: String,
}

/// A refused candidate's figures and why it was refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RefusedCandidate {
    pub visibility: f64,
    pub free_space: f64,
    pub explained_cells: u32,
    pub reason: String,
}

/// The answer for one scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Recognition {
    /// Accepted detections, ranked: `detections[0]` is the one to pick.
    pub detections: Vec<Detection>,
    pub preprocess: PreprocessReport,
    /// Values derived for this scan (None when every length was given).
    pub scale: Option<DerivedScale>,
    /// Scene-voting engine diagnostics (None with the thesis engine).
    pub voting: Option<VotingReport>,
    pub clusters: Vec<ClusterReport>,
    /// Detections dropped because a better one explains the same instance.
    pub duplicates_suppressed: usize,
    pub timings: Timings,
}

impl Recognition {
    /// Nothing found: the scene had too few points left after preprocessing.
    pub(crate) fn empty(preprocess: PreprocessReport, timings: Timings) -> Self {
        Self {
            detections: Vec::new(),
            preprocess,
            scale: None,
            voting: None,
            clusters: Vec::new(),
            duplicates_suppressed: 0,
            timings,
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
    pub detections: Vec<Detection>,
    pub preprocess: PreprocessReport,
    /// Values derived from the model and this scan.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<DerivedScale>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub voting: Option<VotingReport>,
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
            detections: r.detections.clone(),
            preprocess: r.preprocess.clone(),
            scale: r.scale,
            voting: r.voting.clone(),
            clusters: r.clusters.clone(),
            duplicates_suppressed: r.duplicates_suppressed,
            timings_ms: r.timings.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn detection() -> Detection {
        let pose = Isometry3::from_parts(
            Translation3::new(1.0, -2.0, 3.5),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3),
        );
        Detection {
            rank: 1,
            pose,
            initial_pose: Isometry3::identity(),
            initial_score: 2.5,
            final_score: 1.0,
            score_before_icp: 3.0,
            found_by: FoundBy::Cluster {
                cluster: 4,
                round: 0,
                fpfh_radius_mm: Some(10.0),
                sac_threshold_mm: 3.0,
                sac_inliers: 40,
            },
            view: None,
            icp: IcpReport {
                converged: true,
                iterations: 7,
                fitness_mm2: Some(0.2),
                adopted: true,
                error: None,
            },
            height_mm: 12.0,
            rank_reason: "best".into(),
        }
    }

    #[test]
    fn detection_json_keeps_the_record_fields_and_round_trips() {
        let d = detection();
        let v = serde_json::to_value(&d).unwrap();
        for key in [
            "rank",
            "pose",
            "translation",
            "quaternion_wxyz",
            "final_score",
            "icp",
        ] {
            assert!(v.get(key).is_some(), "{key} missing");
        }
        assert_eq!(v["pose"].as_array().unwrap().len(), 16);
        assert_eq!(v["translation"][2], 3.5);
        let back: Detection = serde_json::from_value(v.clone()).unwrap();
        assert!((back.pose.translation.vector - d.pose.translation.vector).norm() < 1e-12);
        assert_eq!(back.icp, d.icp);
        // A record written before `initial_pose` existed still loads.
        let mut old = v;
        old.as_object_mut().unwrap().remove("initial_pose");
        let back: Detection = serde_json::from_value(old).unwrap();
        assert_eq!(back.initial_pose, back.pose);
    }
}
