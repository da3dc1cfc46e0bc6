//! What a recognition returns, as plain data: [`Recognition`] with its [`Detection`]s and
//! reports, and [`RecognitionReport`], the JSON document written for every scene
//! (`binpick recognize --json`, `eval`, `replay`). Every stage above produces these types;
//! this module imports nothing of the pipeline (only the parameters a report embeds).
//!
//! The document's JSON Schema is `schema/result.schema.json` at the repository root;
//! [`RESULT_SCHEMA_VERSION`] is its version. Every pose is given twice: as a row-major 4x4 in
//! millimetres (`pose`) and as a ROS `geometry_msgs/Pose` (`pose_ros`: position in metres,
//! quaternion `x, y, z, w`), both in the frame named by the document's `frame_id`.
//!
//! ```json
//! {
//!   "schema_version": 3, "frame_id": "scanner",
//!   "scene": "scan.pcd", "model": "part.pcd", "units": "mm", "algorithm": 1,
//!   "engine": "scene-voting", "params": { ...every parameter actually used... },
//!   "detections": [
//!     { "rank": 1,
//!       "pose": [16 numbers, row-major 4x4, model -> frame_id, mm],
//!       "pose_ros": { "position": { "x": 0.0068, "y": 0.0151, "z": 0.0162 },
//!                     "orientation": { "x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0 } },
//!       "translation": [x, y, z], "quaternion_wxyz": [w, x, y, z],
//!       "initial_score": 0.88,      // Euclidean score, mm^2 (thesis 3.1.1)
//!       "final_score": 0.0,         // percent of outliers (3.1.2)
//!       "score_before_icp": 0.0,
//!       "votes": 412, "hypothesis": 0,            // scene-voting engine, or
//!       // "cluster": 1, "cluster_round": 0, "fpfh_radius_mm": 30.0,
//!       // "sac_threshold_mm": 1.0, "sac_inliers": 412   // thesis engine
//!       "view": { "visibility": 0.93, ... },      // scene-voting engine only
//!       "icp": { "converged": true, "iterations": 9, "fitness_mm2": 0.41, "adopted": true },
//!       "height_mm": 13.6, "rank_reason": "...",
//!       "free_to_pick": true,        // false: covered by another part or unreachable
//!       "initial_pose": [16 numbers] } ],
//!   "preprocess": { "input_points": ..., "outside_roi": ..., "isolated_removed": ..., "voxel_merged": ...,
//!                   "support_planes": [...], "remaining": ... },
//!   "clusters": [ { "index": 0, "points": 11982, "detections": 1, "outcome": "..." } ],
//!   "duplicates_suppressed": 0,
//!   "timings_ms": { "model_preparation_ms": ..., "queue_ms": ..., "preprocess_ms": ..., "clustering_ms": ...,
//!                   "initial_alignment_ms": ..., "final_alignment_ms": ..., "ranking_ms": ..., "total_ms": ... },
//!   "interrupted": { "cause": "time_budget" | "cancelled", "budget_ms": 300.0,
//!                    "stage": "cluster FPFH", "elapsed_ms": 304.1 }   // only when stopped early
//! }
//! ```

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use binpick_cloud::{RowMajor4x4, pose_from_row_major, pose_to_row_major};

use crate::frames::OutputFrame;
use crate::grasp::GraspCheck;
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
    /// What the final alignment (ICP) did.
    pub icp: IcpReport,
    /// Height of the placed model's centroid along `up`, mm.
    pub height_mm: f64,
    /// Why it ranks where it does.
    pub rank_reason: String,
    /// Whether the robot may take it: nothing else covers more than `covered_max` of its
    /// visible surface (scene-voting engine) and, with declared grasps, at least one approach
    /// corridor is free. Detections free to pick come first in the pick order;
    /// [`Recognition::first_pick`] is the first of them, or none. The thesis engines pick
    /// their first rank (4.2.2): always true there.
    pub free_to_pick: bool,
    /// The part's grasps (declared in the model's sidecar) in the result's frame, each with
    /// whether its approach corridor is free and what blocks it. Empty without declared
    /// grasps.
    pub grasps: Vec<GraspCheck>,
}

/// How an engine found a detection.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
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
        /// Inliers of the winning RANSAC consensus set.
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
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct ViewCheck {
    /// Share confirmed by the scene: the estimated visible fraction.
    pub visibility: f64,
    /// Share the sensor saw through (a surface behind the model): contradictions.
    pub free_space: f64,
    /// Share hidden by something other than the belt or bin (a part lying on it).
    pub covered: f64,
    /// Share with no measurement at all (shadow or absent surface).
    pub missing: f64,
    /// Share with a nearer surface in front, whatever it is (`covered` counts only parts,
    /// off the outline). Absent in older results: 0.
    #[serde(default)]
    pub occluded: f64,
    /// Share where a scene surface lies at the model's depth but faces another way. Absent
    /// in older results: 0.
    #[serde(default)]
    pub wrong_normal: f64,
    /// Share of its outline the scene's surface carries on past (a pose laid across other
    /// surfaces rather than on a part).
    #[serde(default)]
    pub continued: f64,
    /// Mean fit weight of the confirmed surface (1 = the scene lies exactly on the model).
    #[serde(default)]
    pub fit: f64,
    /// The same with a neighbouring cell's surface on the outline weighted as in place
    /// (`outline_neighbour_weight`): what `min_fit` judges. Absent in older results: 0.
    #[serde(default)]
    pub acceptance_fit: f64,
    /// Cells the model covers as the sensor would see it alone.
    pub visible_cells: u32,
    /// Share of the whole model surface lying behind a support plane (sunk into the belt,
    /// floor or a bin wall); 0 without support planes.
    #[serde(default)]
    pub below_support: f64,
    /// How deep the part's deepest point lies behind a support plane that can carry it (belt,
    /// floor, wall; not a rim nor a plane across a layer of parts), mm (0 when none does).
    /// Absent in older results: 0.
    #[serde(default)]
    pub sunk_mm: f64,
    /// Share of the confirmed surface whose scene surface is belt, floor or wall rather than
    /// a part: evidence the support gives whether or not the part is there.
    #[serde(default)]
    pub on_support: f64,
    /// Scene-voting engine, parts taken: the largest share of the confirmed surface of a
    /// pose of another part, fitting closer, that this part claimed in the scene
    /// explanation (making that pose a repeat); above `contested_max` the part is not
    /// free to pick. Absent in older results: 0.
    #[serde(default)]
    pub contested: f64,
    /// Cells seen through beside a part's surface that hides this one, per confirmed cell
    /// (what `max_crossing` limits, once there are three). Absent in older results: 0.
    #[serde(default)]
    pub crossing: f64,
    /// Share of the part's view beyond the edge of the scanned area (of the cells it would
    /// show in and beyond the scan; the other shares are of those in it): the sensor
    /// measured nothing there, so nothing there confirms or contradicts the pose, and what
    /// may lie on that share is unknown. Above `covered_max` the part is not free to pick.
    /// Absent in older results: 0.
    #[serde(default)]
    pub outside: f64,
}

impl ViewCheck {
    /// Share of the visible surface confirmed by scene surface that is not support.
    pub fn own_visibility(&self) -> f64 {
        self.visibility * (1.0 - self.on_support)
    }

    /// What the pick order compares: [`own_visibility`](Self::own_visibility) weighted by
    /// the mean [`fit`](Self::fit) of the confirmed surface, less `free_space_weight` times
    /// the share the sensor saw through (the scene explanation's weighing of evidence
    /// against contradiction), at least 0.
    pub fn pick_confidence(&self, free_space_weight: f64) -> f64 {
        (self.own_visibility() * self.fit - free_space_weight * self.free_space).max(0.0)
    }
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
    /// The same detection seen through `t` (a change of frame): poses and grasps.
    pub(crate) fn transformed(&self, t: &Isometry3<f64>) -> Self {
        Self {
            pose: t * self.pose,
            initial_pose: t * self.initial_pose,
            grasps: self.grasps.iter().map(|g| g.transformed(t)).collect(),
            ..self.clone()
        }
    }

    pub(crate) fn found_order(&self) -> (usize, usize) {
        match self.found_by {
            FoundBy::Cluster { cluster, round, .. } => (cluster, round),
            FoundBy::Voting { hypothesis, .. } => (hypothesis, 0),
        }
    }
}

/// The JSON record: poses as 16 numbers, row-major, mm; the final pose also as a ROS pose
/// (metres, quaternion x y z w) and as translation + quaternion (w x y z) for readers that
/// want them (all three ignored on load: `pose` is the record).
impl Serialize for Detection {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let t = self.pose.translation.vector;
        let q = self.pose.rotation.quaternion();
        let mut r = s.serialize_struct("Detection", 18)?;
        r.serialize_field("rank", &self.rank)?;
        r.serialize_field("pose", &pose_to_row_major(&self.pose))?;
        r.serialize_field("pose_ros", &RosPose::from_pose_mm(&self.pose))?;
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
        r.serialize_field("free_to_pick", &self.free_to_pick)?;
        r.serialize_field("initial_pose", &pose_to_row_major(&self.initial_pose))?;
        if !self.grasps.is_empty() {
            r.serialize_field("grasps", &self.grasps)?;
        }
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
    /// Absent in results written before it: every detection counted as free to pick.
    #[serde(default = "free_by_default")]
    free_to_pick: bool,
    #[serde(default)]
    initial_pose: Option<RowMajor4x4>,
    #[serde(default)]
    grasps: Vec<GraspCheck>,
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
            free_to_pick: d.free_to_pick,
            grasps: d.grasps,
        })
    }
}

fn free_by_default() -> bool {
    true
}

/// The version of the result document written by this library (`schema_version`; the
/// schema is `schema/result.schema.json`). Version 3 adds each detection's `free_to_pick`:
/// `detections[0]` is the first pick only when it is free to pick. Version 2 documents load
/// with every detection free to pick (their first rank was the pick); version 1 is the
/// unversioned format written before versions (no `schema_version`, `frame_id` or
/// `pose_ros`), and still loads.
pub const RESULT_SCHEMA_VERSION: u32 = 3;

/// The frame poses are given in unless a caller says otherwise: the scanner's (the frame of
/// the scene cloud as read).
pub const SCANNER_FRAME_ID: &str = "scanner";

/// A position in metres, as ROS `geometry_msgs/Point`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RosPoint {
    /// x, metres.
    pub x: f64,
    /// y, metres.
    pub y: f64,
    /// z, metres.
    pub z: f64,
}

/// A unit quaternion, as ROS `geometry_msgs/Quaternion` (`x, y, z, w`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RosQuaternion {
    /// x (vector part).
    pub x: f64,
    /// y (vector part).
    pub y: f64,
    /// z (vector part).
    pub z: f64,
    /// w (scalar part).
    pub w: f64,
}

/// A pose as ROS `geometry_msgs/Pose`: position in **metres**, orientation as a quaternion
/// `x, y, z, w`. The frame is the document's `frame_id`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RosPose {
    /// Position, metres.
    pub position: RosPoint,
    /// Orientation.
    pub orientation: RosQuaternion,
}

impl RosPose {
    /// From a pose in millimetres.
    pub fn from_pose_mm(pose: &Isometry3<f64>) -> Self {
        let t = pose.translation.vector / 1000.0;
        let q = pose.rotation.quaternion();
        Self {
            position: RosPoint {
                x: t.x,
                y: t.y,
                z: t.z,
            },
            orientation: RosQuaternion {
                x: q.i,
                y: q.j,
                z: q.k,
                w: q.w,
            },
        }
    }

    /// Back to a pose in millimetres (the quaternion is normalised).
    pub fn to_pose_mm(&self) -> Isometry3<f64> {
        let o = self.orientation;
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            o.w, o.x, o.y, o.z,
        ));
        let p = self.position;
        Isometry3::from_parts(
            nalgebra::Translation3::new(1000.0 * p.x, 1000.0 * p.y, 1000.0 * p.z),
            q,
        )
    }
}

/// What ICP did for one detection.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IcpReport {
    /// Whether PCL's ICP reported convergence.
    pub converged: bool,
    /// Iterations run.
    pub iterations: u32,
    /// PCL's fitness: mean squared distance of matched points, mm^2 (None if ICP failed or
    /// matched nothing).
    pub fitness_mm2: Option<f64>,
    /// Whether the ICP pose scored better than the initial one and was adopted (step 3d).
    pub adopted: bool,
    /// Whether a last pass on the model surface the scene does not hide fitted better and
    /// was adopted (scene voting; `converged`, `iterations` and `fitness_mm2` are then that
    /// pass's). Absent in results written before it existed: false.
    #[serde(default)]
    pub unhidden: bool,
    /// Whether the last pass with mutual nearest neighbours on a taken part (scene voting,
    /// `polish_pass`) fitted closer and was adopted (`converged`, `iterations` and
    /// `fitness_mm2` are then that pass's). Absent in older results: false.
    #[serde(default)]
    pub polished: bool,
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
    /// Cluster index (clusters ordered by first point index).
    pub index: usize,
    /// Points in the cluster.
    pub points: usize,
    /// Detections accepted in it (after duplicate suppression).
    pub detections: usize,
    /// Spheres the cluster was searched in (1 when searched whole).
    #[serde(default)]
    pub regions: usize,
    /// Why the search in this cluster stopped, in words.
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
    /// The time budget ran out or the call was cancelled during `stage`: the rest of the
    /// cluster was not searched.
    Interrupted {
        cause: StopCause,
        stage: String,
    },
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
            SearchStop::Interrupted { cause, stage } => {
                write!(f, "stopped: {cause} during {stage}")
            }
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
#[non_exhaustive]
pub struct Timings {
    /// Model preparation in `Recognizer::new` (once per model, not per scene).
    pub model_preparation_ms: f64,
    /// Time the call waited for worker threads held by other calls on the same
    /// `Recognizer`, before its work (and its time budget) started. Not part of `total_ms`.
    #[serde(default)]
    pub queue_ms: f64,
    /// Crop, strays, units check, voxel grid, support removal.
    pub preprocess_ms: f64,
    /// Euclidean clustering (thesis engine).
    pub clustering_ms: f64,
    /// Initial alignment: RANSAC sweeps (thesis engine) or voting (scene-voting engine), summed over threads.
    pub initial_alignment_ms: f64,
    /// Final alignment: ICP (thesis engine) or verification (scene-voting engine), summed over threads.
    pub final_alignment_ms: f64,
    /// Duplicate suppression, pick order and grasp corridors.
    pub ranking_ms: f64,
    /// From the start of the work to the return of the call (queue wait excluded).
    pub total_ms: f64,
}

/// Every value derived for one scan, recorded in each result.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct DerivedScale {
    /// Measured on the model.
    pub model_diameter_mm: f64,
    /// Area of the part one view shows, mm^2.
    pub part_view_area_mm2: f64,
    /// The part's typical radius of curvature, mm; None when it is mostly flat.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part_curvature_radius_mm: Option<f64>,
    /// Measured on the scan (None when the resolution was given).
    pub scan_spacing_mm: Option<f64>,
    /// Median distance of a scan point to its 8th-nearest neighbour, mm.
    pub scan_gap_mm: Option<f64>,
    /// Derived.
    pub resolution_mm: f64,
    /// Points closer than this are connected (one surface), mm.
    pub connect_mm: f64,
    /// Points this close to a support plane are support, mm: the plane fit's distance, then
    /// (scene voting with a curved part, once the noise is measured) the band narrowed to
    /// 3 x the noise, at least one resolution (`SupportRemoval::band`).
    pub support_distance_mm: f64,
    /// Step between the model's and scene's voting samples, mm.
    pub sampling_step_mm: f64,
    /// Radius of the scene's normal estimation, mm.
    pub normal_radius_mm: f64,
    /// Cell of the sensor's view grid, mm.
    pub cell_mm: f64,
    /// The scan's noise (RMS distance of the belt's or bin floor's points to their plane),
    /// when a support plane was found, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scan_noise_mm: Option<f64>,
    /// How far a scan point may lie from the placed model and still confirm it, mm.
    pub tolerance_mm: f64,
    /// Points one part's visible surface holds at the working resolution.
    pub part_points: f64,
}

/// One removed supporting plane.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RemovedPlane {
    /// `a x + b y + c z + d = 0`, unit normal, mm.
    pub coefficients: [f32; 4],
    /// Points removed with it.
    pub points: usize,
    /// Root mean square distance of the removed points to the plane, mm: the scanner's noise
    /// (and the surface's roughness). Measured by the scene-voting engine.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_mm: Option<f64>,
}

/// What preprocessing did, in points.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct PreprocessReport {
    /// Points of the scene as given.
    pub input_points: usize,
    /// Dropped by the region of interest (first, before anything else looks at the points).
    pub outside_roi: usize,
    /// Isolated points dropped next: strays with too few neighbours to be part of anything
    /// (`isolated_radius_mm`, `isolated_min_neighbours`).
    #[serde(default)]
    pub isolated_removed: usize,
    /// Merged away by the voxel grid.
    pub voxel_merged: usize,
    /// Removed as supporting surface, plane by plane.
    pub support_planes: Vec<RemovedPlane>,
    /// Under a curved part (scene voting), the band around each plane within which points
    /// were labelled support, narrowed to the first plane's noise (`SupportRemoval::band`),
    /// mm; absent where the whole support distance was labelled.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub support_band_mm: Option<f64>,
    /// Scene voting: points past the plane distance labelled support as the planes' noise
    /// tail (`noise_tail_sigmas`).
    #[serde(default)]
    pub support_noise: usize,
    /// Points left for clustering.
    pub remaining: usize,
}

/// Why a recognition stopped before searching everything.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum StopCause {
    /// The time budget ran out.
    TimeBudget,
    /// The caller's `CancelToken` was cancelled.
    Cancelled,
}

impl std::fmt::Display for StopCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            StopCause::TimeBudget => "time budget ran out",
            StopCause::Cancelled => "cancelled",
        })
    }
}

/// A recognition that was stopped by its time budget or its cancel token: what it returns
/// is what it had verified by then (every detection passed the final validation).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct Interruption {
    /// Why it stopped.
    pub cause: StopCause,
    /// The budget, ms (None without one).
    pub budget_ms: Option<f64>,
    /// What was running when the stop was noticed, e.g. "preprocessing", "cluster FPFH",
    /// "ICP". "return" when every stage finished but the call returned after its budget
    /// (the detections are then complete).
    pub stage: String,
    /// Time from the start of the work to the return of the call, ms.
    pub elapsed_ms: f64,
}

impl std::fmt::Display for Interruption {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (self.cause, self.budget_ms) {
            (StopCause::TimeBudget, Some(b)) => write!(
                f,
                "time budget of {b:.0} ms ran out during {}; returned after {:.0} ms",
                self.stage, self.elapsed_ms
            ),
            (cause, _) => write!(
                f,
                "{cause} during {}; returned after {:.0} ms",
                self.stage, self.elapsed_ms
            ),
        }
    }
}

/// What the scene-voting engine did, for diagnostics.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct VotingReport {
    /// The sensor the view was built for ("camera at (x, y, z) mm" or "above along (x, y, z)").
    pub sensor: String,
    /// Scene samples with a normal (they vote).
    pub scene_samples: usize,
    /// Votes cast (peaks of all reference points).
    pub votes: usize,
    /// Pose clusters verified.
    pub hypotheses: usize,
    /// Of `hypotheses`, those laid from flat faces left unexplained after the voting rounds
    /// (a scene patch on a model face of about its size).
    #[serde(default)]
    pub face_hypotheses: usize,
    /// Candidates that competed in the scene explanation (hypotheses plus their
    /// near-symmetry variants). Later-round candidates refused before it, as confirmed
    /// mostly by the support, are counted in `rejected_on_support` only.
    pub candidates: usize,
    /// Candidates taken as parts.
    pub accepted: usize,
    /// Candidates refused: too little confirmed surface, too little of the visible surface
    /// confirmed, too much free space, or surface already explained by a taken part.
    pub rejected_too_little_surface: usize,
    /// Refused: too little of the visible surface confirmed.
    pub rejected_low_visibility: usize,
    /// Refused: the sensor saw through too much of it (free space).
    pub rejected_free_space: usize,
    /// Refused: it passes through a part the sensor saw (`max_crossing`).
    #[serde(default)]
    pub rejected_crossing: usize,
    /// Refused: it would sink into a support plane (belt, floor, bin wall).
    #[serde(default)]
    pub rejected_below_support: usize,
    /// Refused: mostly confirmed by the support rather than by a part's surface.
    #[serde(default)]
    pub rejected_on_support: usize,
    /// Refused: its outline does not continue in the scan (the scan's surface carries on
    /// past it), including poses that show only an edge laid on a wider surface (refused
    /// before the explanation, not counted in `candidates`).
    #[serde(default)]
    pub rejected_no_outline: usize,
    /// Refused: the scan fits its surface poorly.
    #[serde(default)]
    pub rejected_poor_fit: usize,
    /// Refused: its surface is already explained by a taken part.
    pub rejected_explained: usize,
    /// Refused before the explanation: laid from a flat face, it meets scan surface facing
    /// another way on more than 3 % of its visible cells (not counted in `candidates`).
    #[serde(default)]
    pub rejected_face_normals: usize,
    /// The model is a scan whose near-symmetric turn shows the side its scanner never saw
    /// ([`Part::turn_hides_scanned_side`](crate::Part::turn_hides_scanned_side)): no
    /// detection can be told from its turn, and none is free to pick unless
    /// `pick_turn_ambiguous`. Absent (false) otherwise.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub turn_ambiguous: bool,
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
    /// Index of the pose cluster it came from.
    pub hypothesis: usize,
    /// Summed votes of that cluster.
    pub votes: u32,
    /// Row-major 4x4, model -> scene, after refinement.
    pub pose: RowMajor4x4,
    /// Its view check.
    pub view: ViewCheck,
    /// View cells it explains.
    pub explained_cells: u32,
    /// "taken", or why it was refused.
    pub verdict: String,
}

/// A given pose judged against a scene (`Recognizer::check_pose`).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct PoseCheck {
    /// The pose judged (refined when asked), model -> scene, mm.
    pub pose: Isometry3<f64>,
    /// Its view check.
    pub view: ViewCheck,
    /// View cells it explains.
    pub explained_cells: u32,
    /// Why the engine would refuse it on its own (None: it would accept it).
    pub refusal: Option<String>,
    /// The thesis's validators on its visible surface: Euclidean score, mm^2 (3.1.1), and
    /// percent of outliers (3.1.2).
    pub euclidean_score_mm2: f64,
    /// Percent of outliers (3.1.2) on its visible surface.
    pub outliers_pct: f64,
}

/// A refused candidate's figures and why it was refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RefusedCandidate {
    /// Estimated visible fraction (0..1).
    pub visibility: f64,
    /// Share the sensor saw through (0..1).
    pub free_space: f64,
    /// View cells it explains.
    pub explained_cells: u32,
    /// Why it was refused.
    pub reason: String,
}

/// The answer for one scene.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct Recognition {
    /// Accepted detections in pick order: `detections[0]` is the one to pick when it is
    /// free to pick ([`first_pick`](Self::first_pick)).
    pub detections: Vec<Detection>,
    /// What preprocessing did.
    pub preprocess: PreprocessReport,
    /// Values derived for this scan (None when every length was given).
    pub scale: Option<DerivedScale>,
    /// Scene-voting engine diagnostics (None with the thesis engine).
    pub voting: Option<VotingReport>,
    /// Per-cluster outcomes (thesis engine).
    pub clusters: Vec<ClusterReport>,
    /// Detections dropped because a better one explains the same instance.
    pub duplicates_suppressed: usize,
    /// Time per stage.
    pub timings: Timings,
    /// Set when the time budget ran out or the call was cancelled: the detections are those
    /// verified before it stopped (possibly none), and clusters report what was not searched.
    pub interrupted: Option<Interruption>,
    /// The frame of every pose and grasp: the scanner's unless
    /// [`express_in`](Self::express_in) (or `RecognizeOptions::output_frame`) moved them.
    pub frame: OutputFrame,
}

/// Moves `detections` from the frame `from` (given as scanner -> it) into `to`.
fn reframe(detections: &mut [Detection], from: &Isometry3<f64>, to: &Isometry3<f64>) {
    let change = to * from.inverse();
    for d in detections {
        *d = d.transformed(&change);
    }
}

impl Recognition {
    /// The detection to pick: the first in pick order when it is
    /// [free to pick](Detection::free_to_pick); none when nothing was found or every part
    /// found is covered by another (or, with grasps, unreachable): rescan or clear the pile.
    pub fn first_pick(&self) -> Option<&Detection> {
        first_pick(&self.detections)
    }

    /// Parts were found but none is free to pick: no pick (not "nothing found").
    pub fn none_free_to_pick(&self) -> bool {
        none_free_to_pick(&self.detections)
    }

    /// Gives every pose and grasp in `frame` instead of the current one (ranking values such
    /// as `height_mm` stay measured in the scanner's frame, along `up`).
    pub fn express_in(&mut self, frame: &OutputFrame) {
        reframe(
            &mut self.detections,
            &self.frame.scanner_to_frame,
            &frame.scanner_to_frame,
        );
        self.frame = frame.clone();
    }

    /// Nothing found yet: an empty result to fill stage by stage.
    pub(crate) fn empty(preprocess: PreprocessReport, timings: Timings) -> Self {
        Self {
            detections: Vec::new(),
            preprocess,
            scale: None,
            voting: None,
            clusters: Vec::new(),
            duplicates_suppressed: 0,
            timings,
            interrupted: None,
            frame: OutputFrame::scanner(),
        }
    }

    /// Whether the time budget ran out (the detections may be incomplete).
    pub fn budget_exhausted(&self) -> bool {
        self.interrupted
            .as_ref()
            .is_some_and(|i| i.cause == StopCause::TimeBudget)
    }

    /// Whether the call was cancelled (the detections may be incomplete).
    pub fn cancelled(&self) -> bool {
        self.interrupted
            .as_ref()
            .is_some_and(|i| i.cause == StopCause::Cancelled)
    }
}

/// The whole JSON document for one scene (schema: `schema/result.schema.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct RecognitionReport {
    /// [`RESULT_SCHEMA_VERSION`] when written; 1 for documents written before versions.
    #[serde(default = "unversioned")]
    pub schema_version: u32,
    /// The frame every pose of the document is in (`pose`, `pose_ros`, `initial_pose`):
    /// [`SCANNER_FRAME_ID`] unless the caller names another.
    #[serde(default = "scanner_frame")]
    pub frame_id: String,
    /// The transform from the scanner's frame into `frame_id` (row-major, mm); absent when
    /// `frame_id` is the scanner's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scanner_to_frame: Option<RowMajor4x4>,
    /// The scene as named by the caller (usually its file).
    pub scene: String,
    /// The model as named by the caller (usually its file).
    pub model: String,
    /// Always "mm": poses, scores and timings refer to millimetre clouds.
    pub units: String,
    /// Units of the model file (the scene's are `params.units`); lets `binpick show` reload
    /// both clouds.
    #[serde(default)]
    pub model_units: binpick_cloud::Units,
    /// Thesis algorithm number (1 or 2), used by the thesis engines only.
    pub algorithm: u8,
    /// The engine that ran: "scene-voting" (the default), "thesis", or "reference" (the
    /// thesis's algorithms in plain C++ against PCL).
    pub engine: String,
    /// Every parameter used.
    pub params: Params,
    /// Detections in pick order, poses in `frame_id`.
    pub detections: Vec<Detection>,
    /// What preprocessing did.
    pub preprocess: PreprocessReport,
    /// Values derived from the model and this scan.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<DerivedScale>,
    /// Scene-voting engine diagnostics.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub voting: Option<VotingReport>,
    /// Per-cluster outcomes (thesis engine).
    pub clusters: Vec<ClusterReport>,
    /// Detections dropped as repeats of a better one.
    pub duplicates_suppressed: usize,
    /// Time per stage, ms.
    pub timings_ms: Timings,
    /// Present when the time budget ran out or the call was cancelled (see [`Interruption`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub interrupted: Option<Interruption>,
}

pub(crate) fn first_pick(detections: &[Detection]) -> Option<&Detection> {
    detections.first().filter(|d| d.free_to_pick)
}

fn none_free_to_pick(detections: &[Detection]) -> bool {
    !detections.is_empty() && first_pick(detections).is_none()
}

fn unversioned() -> u32 {
    1
}

fn scanner_frame() -> String {
    SCANNER_FRAME_ID.to_owned()
}

impl RecognitionReport {
    /// The detection to pick, as [`Recognition::first_pick`].
    pub fn first_pick(&self) -> Option<&Detection> {
        first_pick(&self.detections)
    }

    /// As [`Recognition::none_free_to_pick`].
    pub fn none_free_to_pick(&self) -> bool {
        none_free_to_pick(&self.detections)
    }

    /// The document for `r`, poses in its frame (the scanner's unless it was moved).
    pub fn new(scene: &str, model: &str, engine: &str, params: &Params, r: &Recognition) -> Self {
        Self {
            schema_version: RESULT_SCHEMA_VERSION,
            frame_id: r.frame.frame_id.clone(),
            scanner_to_frame: (!r.frame.is_scanner())
                .then(|| pose_to_row_major(&r.frame.scanner_to_frame)),
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
            interrupted: r.interrupted.clone(),
        }
    }
    /// Gives every pose and grasp in `frame` instead of the document's current frame. A
    /// document whose `scanner_to_frame` is unreadable counts as in the scanner's frame.
    pub fn express_in(&mut self, frame: &OutputFrame) {
        let from = self
            .scanner_to_frame
            .and_then(|m| pose_from_row_major(&m).ok())
            .unwrap_or_else(Isometry3::identity);
        reframe(&mut self.detections, &from, &frame.scanner_to_frame);
        self.frame_id = frame.frame_id.clone();
        self.scanner_to_frame =
            (!frame.is_scanner()).then(|| pose_to_row_major(&frame.scanner_to_frame));
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
                unhidden: false,
                polished: false,
                error: None,
            },
            height_mm: 12.0,
            rank_reason: "best".into(),
            free_to_pick: true,
            grasps: Vec::new(),
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
        let back: Detection = serde_json::from_value(old.clone()).unwrap();
        assert_eq!(back.initial_pose, back.pose);
        // `free_to_pick` is written, read back, and true in records written before it.
        let covered = Detection {
            free_to_pick: false,
            ..d
        };
        let v = serde_json::to_value(&covered).unwrap();
        assert_eq!(v["free_to_pick"], false);
        let back: Detection = serde_json::from_value(v).unwrap();
        assert!(!back.free_to_pick);
        assert_eq!(first_pick(std::slice::from_ref(&back)), None);
        assert!(none_free_to_pick(std::slice::from_ref(&back)));
        assert!(!none_free_to_pick(&[]), "nothing found is not 'none free'");
        old.as_object_mut().unwrap().remove("free_to_pick");
        let back: Detection = serde_json::from_value(old).unwrap();
        assert!(back.free_to_pick);
        assert_eq!(first_pick(std::slice::from_ref(&back)), Some(&back));
    }

    #[test]
    fn ros_pose_is_the_pose_in_metres_with_xyzw() {
        let d = detection();
        let v = serde_json::to_value(&d).unwrap();
        let ros: RosPose = serde_json::from_value(v["pose_ros"].clone()).unwrap();
        assert_eq!(v["pose_ros"]["position"]["z"], 0.0035);
        let q = d.pose.rotation.quaternion();
        assert_eq!(ros.orientation.w, q.w);
        assert_eq!(ros.orientation.z, q.k);
        assert!(
            ros.orientation.z > 0.1,
            "a turn about z is in the z component"
        );
        let back = ros.to_pose_mm();
        assert!((back.translation.vector - d.pose.translation.vector).norm() < 1e-12);
        assert!(back.rotation.angle_to(&d.pose.rotation) < 1e-12);
    }
}
