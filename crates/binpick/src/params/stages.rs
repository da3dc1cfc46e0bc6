//! One config per pipeline stage (thesis chapter 4), each with its defaults, ranges and
//! `validate`, declared once with [`stage_config!`](super::spec). [`Params`](super::Params)
//! is their sum, flattened into one TOML table. Lengths are millimetres.

use serde::{Deserialize, Serialize};

use super::spec::{Check, stage_config};

/// Axis-aligned region of interest in scene coordinates, mm. Points outside are dropped
/// before anything else.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegionOfInterest {
    /// Lower corner, mm.
    pub min_mm: [f64; 3],
    /// Upper corner, mm.
    pub max_mm: [f64; 3],
}

/// Finite bounds with `min < max` on every axis (or no region at all).
#[derive(Clone, Copy, Debug)]
pub struct Roi;

/// A valid optional region of interest.
pub const fn roi() -> Roi {
    Roi
}

impl Check<Option<RegionOfInterest>> for Roi {
    fn ok(&self, v: &Option<RegionOfInterest>) -> bool {
        v.is_none_or(|r| {
            (0..3).all(|i| {
                r.min_mm[i].is_finite() && r.max_mm[i].is_finite() && r.min_mm[i] < r.max_mm[i]
            })
        })
    }
    fn describe(&self) -> String {
        "finite bounds with min < max on every axis".into()
    }
    fn show(&self, v: &Option<RegionOfInterest>) -> String {
        format!("{v:?}")
    }
}

/// The cloud FPFH neighbourhoods are searched in (thesis 3.3.2 leaves this open).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum FeatureSurface {
    /// The uniform keypoints themselves (initial leaf): ~leaf^2 fewer neighbours, so FPFH is
    /// an order of magnitude faster, with descriptors still averaged over the same radius.
    #[default]
    Keypoints,
    /// The full-resolution cluster (and model) cloud.
    Cloud,
}

stage_config! {
    /// Removal of the supporting surface (belt, bin floor, walls) by RANSAC plane fits
    /// (the `[support]` table). Not in the thesis (its scans were clustered directly), but
    /// real scans contain the belt and Euclidean clustering merges everything that touches it.
    #[serde(deny_unknown_fields)]
    pub struct SupportRemoval {
        /// Fit and remove planes at all.
        enabled: bool = true, any();
        /// Points closer than this to a plane belong to it, mm: above the scanner noise, below
        /// the thickness of a 2 mm sheet lying flat. None (auto): 1.5 x the resolution.
        #[serde(skip_serializing_if = "Option::is_none")]
        distance_mm: Option<f64> = None, auto(within(0.01, 20.0, "mm"));
        /// At most this many planes are removed (floor + up to four bin walls).
        max_planes: u32 = 5, count(0, 20, "");
        /// A plane is support only if it has more points than this multiple of the model's
        /// point count - more than the largest cluster a part may form (cluster_max_factor),
        /// so a flat part is never taken for the belt.
        min_points_factor: f64 = 3.0, within(1.0, 1e6, "x model points");
        /// RANSAC iterations per plane fit.
        ransac_iterations: u32 = 200, count(1, 100_000, "");
        /// Scene voting, a curved part (one with a typical radius of curvature): a plane's
        /// point is support only within this many times the largest plane's measured noise
        /// (RMS distance of its patch) when that is nearer than `distance_mm`; the rest of
        /// the distance is the flanks of the parts lying on it (40 % of a 7 mm rod at 2 mm
        /// spacing). A flat part lies flush and keeps the whole distance.
        noise_sigmas: f64 = 3.0, within(1.0, 1000.0, "x plane RMS");
        /// ... but never nearer than this many resolutions (a thinner band leaves the noise's
        /// tail across the plane as stray points and separates nothing a voxel can).
        min_band_resolutions: f64 = 1.0, within(0.0, 100.0, "x resolution");
        /// Scene voting: the noise tail of a support plane. A point that is not support,
        /// lies past the plane distance but within this many times the largest plane's
        /// measured noise of a support plane, and has fewer than `noise_tail_min_neighbours`
        /// points that are not support within two resolutions, is the plane's noise, not a
        /// part, and is labelled support too. A depth camera's bin floor (noise 0.6 mm, plane
        /// distance 1.3 mm) leaves thousands of such points, each alone (a seventh to a quarter
        /// of what is left of its bin); a part's surface there is scanned densely. 0 = off.
        noise_tail_sigmas: f64 = 4.0, within(0.0, 1000.0, "x plane RMS (0 = off)");
        /// See `noise_tail_sigmas`: a surface scanned at the resolution has about 12 points
        /// within two resolutions.
        noise_tail_min_neighbours: usize = 3, count(1, 1000, "points");
    }
}

stage_config! {
    /// Input checks and scene preprocessing: crop, stray-point removal, units check,
    /// resolution voxel grid (thesis 4.3 #1), support removal.
    pub struct PreprocessConfig {
        /// Scan resolution: voxel-grid leaf applied to scene and model on load, mm (4.3 #1).
        /// None (auto): measured on every scan from its point spacing, and never finer than
        /// 1/100 of the model's diameter (see `binpick::scale`).
        #[serde(skip_serializing_if = "Option::is_none")]
        resolution_mm: Option<f64> = None, auto(within(0.01, 100.0, "mm"));
        /// Optional crop of the scene before anything else.
        #[serde(skip_serializing_if = "Option::is_none")]
        region_of_interest: Option<RegionOfInterest> = None, roi();
        /// Stray points: after the crop, a scene point with fewer than
        /// `isolated_min_neighbours` other points within about this distance is dropped (and
        /// counted) before the extent is measured, so a few spurious returns far away cannot
        /// stretch the scan's extent. Counted on a grid of cells this size (the point's cell
        /// and its 26 neighbours), so a point with that many neighbours within this radius is
        /// always kept. 50 mm drops nothing from our conveyor, bin and Kinect scans (10 mm
        /// would drop their scanner speckle, and change results), mm.
        isolated_radius_mm: f64 = 50.0, within(0.1, 10_000.0, "mm");
        /// See `isolated_radius_mm`: up to this many strays together are dropped; 0 keeps
        /// every point.
        isolated_min_neighbours: usize = 5, count(0, 1_000_000, "points (0 = off)");
        /// Supporting-surface removal (`[support]`).
        support: SupportRemoval = SupportRemoval::default(), any();
        /// A cloud whose extent is below this many resolutions is refused as "not in mm".
        min_extent_resolutions: f64 = 10.0, within(1.0, 1e6, "x resolution");
        /// A cloud whose extent is above this is refused as "not in mm", mm.
        max_extent_mm: f64 = 100_000.0, positive(1e9, "mm");
    }
}

impl PreprocessConfig {
    /// The resolution in effect, mm: the configured one, or the thesis's 1 mm before a scan
    /// has been measured (the recognizer always resolves auto values first, see
    /// `Params::resolved`).
    pub fn resolution(&self) -> f64 {
        self.resolution_mm.unwrap_or(super::THESIS_RESOLUTION_MM)
    }
}

impl SupportRemoval {
    /// The plane distance in effect, mm: the configured one, or 1.5 x `resolution_mm`.
    pub fn distance(&self, resolution_mm: f64) -> f64 {
        self.distance_mm.unwrap_or(1.5 * resolution_mm)
    }

    /// The support band once the scan's noise (`noise_mm`, RMS) is known, mm:
    /// `noise_sigmas` x the noise, at least `min_band_resolutions` x `resolution_mm` and at
    /// most the plane distance.
    pub fn band(&self, resolution_mm: f64, noise_mm: f64) -> f64 {
        (self.noise_sigmas * noise_mm)
            .max(self.min_band_resolutions * resolution_mm)
            .min(self.distance(resolution_mm))
    }
}

stage_config! {
    /// Euclidean clustering of the scene (thesis 3.4.1.3, 4.3 #2-4).
    pub struct ClusteringConfig {
        /// Cluster tolerance as a multiple of the resolution (4.3 #2, 5.3.1; > 1 per 3.4.1.3).
        /// The thesis uses 1.8 for robot-arm scans (5.6).
        cluster_tolerance_factor: f64 = 1.5, within(1.0, 10.0, "x resolution");
        /// Smallest cluster, as a fraction of the model's point count (4.3 #3).
        cluster_min_factor: f64 = 0.3, positive(1.0, "x model points");
        /// Largest cluster, as a multiple of the model's point count (4.3 #4).
        cluster_max_factor: f64 = 3.0, within(1.0, 1000.0, "x model points");
    }
}

stage_config! {
    /// Keypoints and FPFH descriptors (thesis 3.2.3, 3.3.2, Algorithm 1 step 1a-b), for the
    /// model and for every cluster.
    pub struct FeatureConfig {
        /// Leaf of the uniform keypoints for the initial alignment, mm (4.3 #5, 3.2.3).
        initial_leaf_mm: f64 = 3.0, within(0.01, 100.0, "mm");
        /// FPFH radii to try, mm (4.3 #6, 3.3.2).
        fpfh_radii_mm: Vec<f64> = vec![10.0, 15.0, 20.0, 25.0, 30.0], list(1000.0, "mm");
        /// Normal radius as a fraction of the FPFH radius (4.3 #7, 3.3.2.1).
        normal_radius_factor: f64 = 0.8, positive(1.0, "x FPFH radius");
        /// Where FPFH neighbourhoods are searched (see [`FeatureSurface`]).
        feature_surface: FeatureSurface = FeatureSurface::Keypoints, any();
        /// Sensor position in scene coordinates, mm; surface normals are flipped towards it.
        /// Straight above: scanners looking down along -z.
        scene_viewpoint_mm: [f64; 3] = [0.0, 0.0, 1e6], vec3();
        /// Sensor position in the model's frame, mm (where the model was scanned from).
        model_viewpoint_mm: [f64; 3] = [0.0, 0.0, 1e6], vec3();
        /// Smallest usable model, in points after the resolution voxel grid.
        min_model_points: usize = 20, count(3, 10_000_000, "points");
    }
}

stage_config! {
    /// Correspondences, the RANSAC threshold sweep, SVD and the Euclidean score (thesis
    /// Algorithm 1 steps 1b-D and 2), plus the extensions that add hypotheses.
    pub struct ConsensusConfig {
        /// RANSAC inlier thresholds to sweep, mm (4.3 #8, 3.4.2.5).
        sac_thresholds_mm: Vec<f64> = (1..=20).map(f64::from).collect(), list(1000.0, "mm");
        /// RANSAC iterations per threshold (3.4.2.5).
        sac_iterations: u32 = 50, count(1, 100_000, "");
        /// Keep an initial alignment only if its Euclidean score (mean squared distance,
        /// 3.1.1) is below this, mm^2 (4.3 #9).
        initial_score_max: f64 = 100.0, positive(1e12, "mm^2");
        /// Extension, independent RANSAC draws: each (radius, threshold) run draws from its own
        /// fixed permutation of the correspondences. PCL seeds every run alike, so in the
        /// thesis all thresholds of a sweep share their sample triples (then the sweep runs in
        /// one pass).
        independent_draws: bool = true, any();
        /// Extension, second consensus set: consensus sets tried per threshold. 1 is the thesis
        /// (RANSAC's largest consensus only); 2 also runs RANSAC on the correspondences the
        /// first set left out, so the true pose of a nearly symmetric part is scored even when
        /// its flipped pose gathers more matches. Needs independent draws.
        consensus_modes: u32 = 2, count(1, 10, "");
        /// Extension, near-symmetry candidates: also score each cluster's best initial
        /// hypotheses composed with the model's near-symmetries (half-turns about its principal
        /// axes, refined on the model itself).
        symmetry_candidates: bool = true, any();
        /// How many of a cluster's best hypotheses are composed with the near-symmetries.
        symmetry_expanded: usize = 8, count(1, 1000, "hypotheses");
        /// Extension, retry: when the best initial alignment fails the final validation, the
        /// next best distinct ones go through ICP too, up to this many in all; the first one
        /// accepted is kept. 1 is the thesis: on our conveyor sets 3 found no more parts and
        /// added false positives (docs/results-history.md).
        final_candidates: u32 = 1, count(1, 20, "");
        /// Retried initial alignments must differ from every better one by more than this
        /// translation, in model diameters ...
        distinct_shift_diameters: f64 = 0.1, positive(10.0, "model diameters");
        /// ... or this rotation, degrees.
        distinct_angle_deg: f64 = 15.0, positive(180.0, "deg");
    }
}

stage_config! {
    /// The final alignment: ICP of the model's final keypoints onto the scene's (thesis
    /// Algorithm 1 step 3, 3.6.1, 4.3 #10-11), plus the ICP extensions.
    pub struct IcpConfig {
        /// Leaf of the uniform keypoints for the final alignment, mm (4.3 #10).
        final_leaf_mm: f64 = 2.0, within(0.01, 100.0, "mm");
        /// ICP iteration cap (4.3 #11, 3.6.1).
        icp_iterations: u32 = 50, count(1, 10_000, "");
        /// ICP transformation epsilon (4.3 #11).
        icp_transformation_epsilon: f64 = 1e-7, positive(1.0, "");
        /// ICP max correspondence distance, mm. The thesis leaves PCL's default (unbounded);
        /// bounding it keeps occluders from dragging a part.
        icp_max_correspondence_mm: f64 = 10.0, positive(1e6, "mm");
        /// Extension, relative-MSE stop: ICP also stops when the mean squared correspondence
        /// distance changes by less than this fraction between iterations (PCL's Euclidean
        /// fitness epsilon). The thesis's epsilon 1e-7 in millimetres almost never triggers, so
        /// its ICP always runs 50 iterations. 0 = off.
        icp_relative_mse: f64 = 1e-4, within(0.0, 0.1, "");
        /// Extension, fine ICP pass: after the thesis's ICP on final keypoints, a second ICP of
        /// the model at scan resolution onto the scene at scan resolution removes the
        /// keypoint-sampling ripples that can leave a part slid along its bend line.
        icp_refine: bool = true, any();
        /// The fine pass runs for candidates whose percent of outliers is below this multiple
        /// of `final_score_max_pct` (the fine fit can bring a noisy near-miss under it).
        icp_refine_below_factor: f64 = 2.0, within(1.0, 100.0, "x final_score_max_pct");
        /// The fine pass's correspondence distance, in resolutions.
        icp_refine_distance_factor: f64 = 2.0, positive(100.0, "x resolution");
    }
}

stage_config! {
    /// The validation scores of thesis 3.1 and the acceptance of a final alignment (step 4).
    pub struct ValidationConfig {
        /// A model point farther than this from the scene is an outlier, mm (3.1.2.2).
        outlier_distance_mm: f64 = 4.0, positive(1000.0, "mm");
        /// Keep a final alignment only if its percent of outliers is below this (4.3 #12).
        final_score_max_pct: f64 = 20.0, positive(100.0, "%");
    }
}

stage_config! {
    /// Extensions that search parts of a cluster (the thesis searches each cluster once,
    /// whole, and finds at most one part in it).
    pub struct PileSearchConfig {
        /// Touching parts: after a part is accepted, the cluster points it explains are removed
        /// and the rest is clustered and searched again.
        touching_parts: bool = true, any();
        /// Tighter re-clustering: a group larger than one part that yields nothing is split
        /// again at `recluster_tolerance_factor` x its tolerance.
        tighter_recluster: bool = true, any();
        /// Fraction of the tolerance a failed group is re-clustered at ...
        recluster_tolerance_factor: f64 = 0.75, positive(1.0, "x tolerance");
        /// ... but not below this many resolutions (3.4.1.3: slightly above the resolution
        /// keeps single parts whole).
        recluster_min_tolerance_factor: f64 = 1.1, within(1.0, 10.0, "x resolution");
        /// Sphere search: a cluster with more points than `sphere_split_factor` x the model is
        /// searched in overlapping spheres (thesis 3.4.1.2) instead of whole: in a pile,
        /// whole-cluster correspondences are spread over many parts.
        sphere_search: bool = true, any();
        /// Clusters above this multiple of the model's points are searched in spheres.
        sphere_split_factor: f64 = 1.5, within(1.0, 1000.0, "x model points");
        /// Distance between sphere centres, in model radii. Measured against 1.5 on our sets:
        /// 1.0 recognises more in bins (arm-A 43.8 vs 38.4 %, arm-C 52.1 vs 50.0 %), 1.5 more
        /// of B (74.2 vs 71.0 %) and halves the p95 time per scene.
        sphere_spacing_factor: f64 = 1.0, within(0.5, 3.0, "model radii");
        /// Search spheres reach this many model radii from their centre.
        sphere_radius_factor: f64 = 1.5, within(0.5, 10.0, "model radii");
    }
}

stage_config! {
    /// Duplicate suppression and the pick ranking (thesis 1.2 step 3, 5.4.3).
    pub struct RankingConfig {
        /// Extension, duplicate suppression: among detections of one physical instance only
        /// the best final score is kept.
        suppress_duplicates: bool = true, any();
        /// Two detections are the same instance when this fraction of one's model points lies
        /// within the outlier distance of the other's.
        duplicate_overlap: f64 = 0.5, positive(1.0, "");
        /// Final scores in the same band of this width count as equal and the higher part is
        /// picked first, percentage points (4.2.2; 0 = score only).
        rank_score_band_pct: f64 = 2.0, within(0.0, 100.0, "percentage points");
        /// Up direction of the scene (for "highest in the pile"; the approach direction of a
        /// scanner looking down).
        up: [f64; 3] = [0.0, 0.0, 1.0], direction();
        /// Scene-voting engine: a part with more than this share of its visible surface
        /// covered by something other than the belt or bin is not free to pick: it ranks
        /// after the free ones, and with no free part there is no first pick. A neighbour's
        /// edge resting on a part covers a few percent of it (right plates and
        /// rods at 3.2-4.3 % lost the first pick to wrong free poses at 3 %). The same
        /// limit holds for the share of its view beyond the edge of the scanned area, where
        /// what lies on it is unknown.
        covered_max: f64 = 0.05, within(0.0, 1.0, "");
        /// Scene-voting engine: a part that made a repeat of another part's closer-fitting
        /// pose, claiming more than this share of that pose's confirmed surface, is not free
        /// to pick (`ViewCheck::contested`): its pose may be laid on the other part's
        /// surface (seed 16's `brackets-bin-2mm-002`: a pose lifted 3 mm onto the flange of
        /// a bracket lying on it was the first pick).
        contested_max: f64 = 0.6, within(0.0, 1.0, "");
        /// Scene-voting engine: pick confidences (the visible share confirmed by surface
        /// other than the support, less `free_space_weight` times the share seen through) in
        /// the same band of this width count as equal and the higher part is picked first
        /// (at 0.1 a wrong pose standing on a neighbour, 0.72 against 0.80, outranked the
        /// right part lying 55 mm lower).
        visibility_band: f64 = 0.05, within(0.0, 1.0, "");
        /// Grasps (declared in the model's sidecar): a detection, or the unexplained scan,
        /// blocks a grasp's approach corridor when at least this many of its points lie in it
        /// (scan points at the working resolution plus the other part's placed surface
        /// samples); fewer are taken for noise.
        grasp_blocking_points: u32 = 3, count(1, 1_000_000, "points");
        /// Grasps: scan points this close to a detection's own placed surface are that part,
        /// not obstacles in its corridors, mm. None (auto): the engine's view tolerance
        /// (scene-voting) or `outlier_distance_mm` (thesis).
        #[serde(skip_serializing_if = "Option::is_none")]
        grasp_surface_tolerance_mm: Option<f64> = None, auto(within(0.01, 50.0, "mm"));
        /// Scene-voting engine: pick parts found with a scanned model whose near-symmetric
        /// turn shows the side its scanner never saw (`binpick model inspect` says so). A
        /// part lying the other way up then fits the model as that turn, so no detection
        /// can be told from its turn: off, such detections are reported but none is free to
        /// pick (on the benchmark's belts of Z brackets with their top-view scan, 47 of 200
        /// first picks were the turn). Turn on only where every part lies the scanned side
        /// up; else give the CAD mesh.
        pick_turn_ambiguous: bool = false, any();
    }
}

/// Which engine finds the parts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum Engine {
    /// Point-pair-feature voting over the whole scene (Drost et al. 2010, Vidal et al. 2018),
    /// verification of every hypothesis against the surface the sensor can see, and a greedy
    /// explanation of the scene: every part of a pile, each once.
    #[default]
    SceneVoting,
    /// The thesis: Algorithm 1 or 2 on every Euclidean cluster (4.1, 4.2).
    Thesis,
}

impl Engine {
    /// The engine's name as the CLI and TOML spell it.
    pub fn name(self) -> &'static str {
        match self {
            Engine::SceneVoting => "scene-voting",
            Engine::Thesis => "thesis",
        }
    }
}

impl std::str::FromStr for Engine {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "scene-voting" => Ok(Engine::SceneVoting),
            "thesis" => Ok(Engine::Thesis),
            other => Err(format!(
                "unknown engine {other:?}: expected scene-voting or thesis"
            )),
        }
    }
}

/// Where the sensor was, for the scene-voting engine's view of the scene.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
#[non_exhaustive]
pub enum SensorConfig {
    /// A camera at the origin when the scene lies far out along one side of it (a cloud in
    /// its camera's frame, as depth cameras write them), else a scanner far above along `up`.
    #[default]
    Auto,
    /// A line scanner or far camera looking down `-up` (rays parallel).
    Above,
    /// A camera at `position_mm` (scene frame).
    Camera {
        /// Where the camera is, scene frame, mm.
        position_mm: [f64; 3],
    },
}

/// A valid sensor config.
#[derive(Clone, Copy, Debug)]
pub struct SensorCheck;

/// A valid sensor config (finite camera position).
pub const fn sensor() -> SensorCheck {
    SensorCheck
}

impl Check<SensorConfig> for SensorCheck {
    fn ok(&self, v: &SensorConfig) -> bool {
        match v {
            SensorConfig::Camera { position_mm } => position_mm.iter().all(|c| c.is_finite()),
            _ => true,
        }
    }
    fn describe(&self) -> String {
        "auto, above, or camera with a finite position_mm".into()
    }
    fn show(&self, v: &SensorConfig) -> String {
        format!("{v:?}")
    }
}

stage_config! {
    /// Scene voting, hypotheses: point-pair features of model and scene sampled at one step
    /// tied to the model's diameter (Vidal et al. 2018), every scene reference point voting
    /// for a model point and a rotation (Drost et al. 2010), votes clustered into poses.
    pub struct VotingConfig {
        /// Sampling step of model and scene, in model diameters (Drost: 0.05).
        sampling_step_diameters: f64 = 0.04, within(0.005, 0.5, "x diameter");
        /// ... but at least this many working resolutions (no finer than the scan).
        min_sampling_step_resolutions: f64 = 2.0, within(1.0, 100.0, "x resolution");
        /// Surface normals are fitted over this radius, in sampling steps ...
        normal_radius_steps: f64 = 0.75, within(0.1, 10.0, "x sampling step");
        /// ... but at least this many working resolutions (noise).
        min_normal_radius_resolutions: f64 = 3.0, within(1.0, 100.0, "x resolution");
        /// A curved part's normals are fitted over at most this many of its typical radii of
        /// curvature (wider, a rod's normals are those of a ridge) ...
        normal_radius_curvatures: f64 = 1.0, within(0.1, 100.0, "x radius of curvature");
        /// ... but over at least this many working resolutions.
        min_curved_normal_radius_resolutions: f64 = 2.0, within(1.0, 100.0, "x resolution");
        /// Bins of each feature angle over 0-180 deg (Drost: 12 deg bins).
        feature_angle_bins: u32 = 15, count(4, 90, "");
        /// Bins of the rotation about the normal over a full turn.
        alpha_bins: u32 = 30, count(4, 360, "");
        /// A model pair is also filed under a neighbouring bin when its feature lies within
        /// this fraction of a bin of the edge (Vidal's neighbour voting; 0 = off).
        spread: f64 = 0.25, within(0.0, 0.5, "x bin");
        /// Most model pairs kept per feature bin (flat regions fill a few bins with thousands
        /// of pairs that vote alike).
        max_pairs_per_bin: u32 = 200, count(1, 1_000_000, "");
        /// Every n-th scene sample is a reference point.
        reference_stride: usize = 2, count(1, 100, "");
        /// Peaks kept per reference point.
        peaks_per_reference: usize = 3, count(1, 20, "");
        /// A secondary peak needs this share of the reference point's best peak.
        secondary_peak_ratio: f64 = 0.6, within(0.0, 1.0, "");
        /// Of one reference point's scene pairs that share a feature bin and a rotation bin,
        /// only the first votes (Vidal et al. 2018; flat regions give many that vote alike).
        /// A quarter off the voting; off by default (docs/results-history.md, "Twenty-sixth pass").
        distinct_pairs: bool = false, any();
        /// Votes whose poses move the model's centre less than this, in diameters ...
        cluster_translation_diameters: f64 = 0.1, positive(1.0, "x diameter");
        /// ... and rotate it less than this (up to symmetry) are one hypothesis, deg.
        cluster_rotation_deg: f64 = 24.0, within(1.0, 180.0, "deg");
        /// Strongest pose clusters verified, at most (per round).
        hypotheses: usize = 40, count(1, 10_000, "");
        /// Strongest pose clusters of the rims' own votes verified besides, at most (per
        /// round; 0 = no rim table). A rim is a thin face seen flat on: a sheet part lying
        /// on its side shows its sensor only the edge of its sheet.
        rim_hypotheses: usize = 10, count(0, 10_000, "");
        /// Poses laid from flat faces verified after the voting rounds, at most (0 = none):
        /// each flat patch of the scene left unexplained laid on the model's flat faces of
        /// about its size. Pairs on one plane vote alike, so voting cannot place a part that
        /// shows the sensor little but one face. Off by default: with 40 it found more parts
        /// but laid plates on clutter faces, once as a first pick (docs/results-history.md,
        /// "Forty-first pass").
        face_hypotheses: usize = 0, count(0, 10_000, "");
        /// Voting rounds: each next round votes again over the scene samples that no part
        /// taken so far explains, so parts outvoted by their neighbours get hypotheses too.
        rounds: u32 = 2, count(1, 5, "");
    }
}

stage_config! {
    /// Scene voting, verification: every hypothesis is refined by ICP on the model surface
    /// the sensor can see, then judged against the sensor's view of the scene (explained,
    /// occluded, free-space and missing surface); hypotheses compete for scene surface
    /// (greedy scene explanation, after Aldoma et al. 2012).
    pub struct VerifyConfig {
        /// View grid cell, in working resolutions.
        cell_resolutions: f64 = 1.0, within(0.25, 20.0, "x resolution");
        /// A model surface within this many cells (along the ray) of the scene's is explained
        /// ...
        tolerance_cells: f64 = 1.5, within(0.1, 20.0, "x cell");
        /// ... or within this many times the scan's noise, when that is wider.
        tolerance_sigmas: f64 = 3.0, within(0.0, 20.0, "x noise");
        /// ... and only where the surfaces' normals differ by less than this, deg.
        max_normal_angle_deg: f64 = 45.0, within(1.0, 180.0, "deg");
        /// Model surface steeper than this to the sensor's ray is not judged, deg.
        max_incidence_deg: f64 = 75.0, within(10.0, 89.0, "deg");
        /// A part must show at least this share of the surface the sensor would see of it
        /// alone in that pose. Below about half, the part cannot be picked and the scene
        /// confirms too little of it to tell a right pose from a plausible wrong one.
        min_visibility: f64 = 0.45, within(0.0, 1.0, "");
        /// The sensor may have seen through at most this many cells of that surface per cell
        /// the scene confirms (0.08 before the eighth pass, 0.05 before the eighteenth: README
        /// Results; a share of the whole visible surface before the thirty-third, which let a
        /// pose half hidden under a neighbour see through twice as much of what is left).
        /// Right poses see through at most 0.4 % in 95 % of the benchmark's parts, false ones
        /// 1 % in half.
        max_free_space: f64 = 0.03, within(0.0, 1.0, "");
        /// A pose may see through at most this many cells beside a part that hides it, per
        /// cell the scene confirms, once there are three (1 = off): a pose passing through a
        /// part the sensor saw is in front of that part's surface on one side and behind it
        /// on the other. A part lying under another is hidden but not seen through beside
        /// it (docs/results-history.md, "Forty-eighth pass").
        max_crossing: f64 = 0.004, within(0.0, 1.0, "");
        /// At most this share of the part may lie behind a support plane that can carry a
        /// part (sunk into the belt, floor or a bin wall by more than three view
        /// tolerances; not a bin's rim, which the top of a pile sticks out past: before the
        /// thirty-fourth pass the rim counted too, docs/results-history.md).
        max_below_support: f64 = 0.05, within(0.0, 1.0, "");
        /// No point of the part may lie deeper than this many view tolerances behind such a
        /// plane: a resting part touches it, and pose error dips a corner less than a
        /// tolerance (a bent plate's flange 15 mm in the floor is a small share of the
        /// part). 2 before the thirty-third pass: of 3 641 right pickable detections on the
        /// benchmark one sank deeper than a tolerance, of 100 false ones 13 (docs/results-history.md).
        max_sunk_tolerances: f64 = 1.0, within(0.0, 100.0, "x tolerance");
        /// Candidates of later voting rounds (voted from what the taken parts leave
        /// unexplained, bin rims included): at most this share of their confirmed surface
        /// may be belt, floor or wall (a part laid on the support, not seen). Not applied in
        /// the first round: parts' surfaces taken for support (a plane across the tops of a
        /// layer of shafts) would refuse true parts.
        max_explained_by_support: f64 = 0.5, within(0.0, 1.0, "");
        /// The scene's surface may carry on past at most this share of the part's outline
        /// where no part taken before it explains that surface (a real part's outline is a
        /// depth edge of the scene or a neighbour's surface; a pose laid inside a larger
        /// surface, a plate on a box top, is not). 1 = off.
        max_continued: f64 = 0.2, within(0.0, 1.0, "");
        /// The confirmed surface's mean fit weight, 1 - (depth error / tolerance)^2 with a
        /// quarter for a neighbouring cell, must reach this (the scene must lie on the model,
        /// not just near it).
        min_fit: f64 = 0.7, within(0.0, 1.0, "");
        /// A part seen at `min_visibility` must fit this closely; from
        /// `occluded_below_visibility` down, the fit asked rises linearly from `min_fit` to
        /// this. With half a part hidden, a wrong pose laid across a neighbour's surface
        /// confirms as much of itself as a right one, but fits it loosely. At or below
        /// `min_fit` = off.
        occluded_min_fit: f64 = 0.85, within(0.0, 1.0, "");
        /// See `occluded_min_fit`.
        occluded_below_visibility: f64 = 0.6, within(0.0, 1.0, "");
        /// ... judged with a model cell on the part's outline that only a neighbouring
        /// cell's surface explains weighing this much (a quarter elsewhere): the sampled
        /// outline lies up to a cell inside the part's edge. A part standing on a 2 mm sheet
        /// edge is nearly all outline; at a quarter its right pose fitted at 0.59-0.70. The
        /// competition and the pick order keep the quarter (they prefer the pose that meets
        /// the scan in place).
        outline_neighbour_weight: f64 = 0.5, within(0.0, 1.0, "");
        /// A part with rims seen edge on (showing at most a fifth of its typical view) must
        /// fit this closely (in place of `min_fit` and `occluded_min_fit`): a Z bracket on the
        /// 2 mm edge of its sheet is a strip one to three cells wide, all outline, and its
        /// right poses fitted at 0.55-0.70 in the depth bin (Results, "Thirteenth pass").
        /// Such a pose must also meet the scene's ribbons with its rims where the scene
        /// carries on past its outline.
        edge_on_min_fit: f64 = 0.6, within(0.0, 1.0, "");
        /// A part must explain at least this share of the cells the model covers in its
        /// median view (it must be seen, not guessed), and keep this share that no part
        /// taken before it claims in the scene explanation (cells a support plane explains
        /// are still its own surface seen: before the thirty-fourth pass they counted as
        /// claimed, and a bracket on its edge lost its lowest cells to the floor). A part on
        /// its thinnest side shows little: a Z bracket on the 2 mm edge of its sheet shows
        /// 4-5 % of its median view; at 0.04 (before the eleventh pass) the few cells a
        /// neighbour claimed sent it under. The thesis's part A, a 2 mm sheet bent to an L of
        /// 60 and 70 mm legs, standing on its edge shows about 1 % (0.03 before the
        /// fifty-second pass: 19 of the 22 parts A missed on the thesis conveyor with its
        /// mesh; docs/results-history.md).
        min_explained_share: f64 = 0.01, within(0.0, 1.0, "");
        /// In the competition, each free-space cell costs this many explained cells.
        free_space_weight: f64 = 2.0, within(0.0, 100.0, "");
        /// A hypothesis must newly explain this share of its cells (else it repeats a part).
        min_new_share: f64 = 0.5, within(0.0, 1.0, "");
        /// A cell a taken part explains is new to a later hypothesis whose fit weight there
        /// is higher by more than this (the scan lies closer to it; Aldoma et al.'s per-point
        /// competition, by cell): a bracket lying flat on another's flange is a sheet's
        /// thickness above it, within the tolerance, so a pose of the one beneath explained
        /// its cells too and, taken first, left it a repeat (before the thirty-seventh pass,
        /// when every claimed cell was taken). 1 = off (a fit weight is at most 1).
        closer_cell_margin: f64 = 0.3, within(0.0, 1.0, "");
        /// In the competition, gains within this share of the best are a tie. Between
        /// different poses the one with the most votes for its own pose wins (a
        /// near-symmetric turn has none): with the flange that tells a part from its turn
        /// hidden, the view scores both alike, the votes over the whole part do not. Between
        /// hypotheses of one pose the better fit wins. 0 = the best gain wins.
        tie_share: f64 = 0.01, within(0.0, 1.0, "");
        /// ICP iterations per refinement pass (two passes: coarse, then fine).
        refine_iterations: u32 = 15, count(1, 1000, "");
        /// ... or fewer: a pass stops once an iteration changes the mean squared distance of
        /// its correspondences by less than this share (0 = off). Half the fine passes run
        /// all 15 iterations, creeping along the part's faces; 1e-3 saves 11 % of the
        /// correspondence searches but gave 0.03 more false detections per scan over seeds
        /// 1-4 (docs/speed-history.md, "Seventh pass").
        refine_relative_mse: f64 = 1e-4, within(0.0, 0.1, "");
        /// The two passes align only the model points the scan can confirm: not hidden by the
        /// scene, with a measurement in their cell or beside it (a neighbour over a part, or
        /// the scanner's shadow, leaves its points nothing of their own to pair with, and the
        /// nearest other surface pulls the pose off the part). False aligns every point the
        /// sensor would see (before the thirty-second pass; docs/results-history.md).
        refine_confirmed_only: bool = true, any();
        /// After the two passes, one more fine pass on the model surface the scene does not
        /// hide (where the scene lies over the model by more than a tolerance, a neighbour
        /// does); adopted when the part fits closer without explaining less. Under its
        /// neighbours a part is otherwise pulled towards them, and its right pose fails
        /// `min_fit` (measured on bins of rings and rods: fits 0.5-0.65 and 1-2 mm off).
        /// Skipped for a pose refused by more than it changes: too little of the part seen,
        /// or far more free space than allowed (`ExplainConfig::past_refining`).
        unhidden_pass: bool = true, any();
        /// Each part taken gets a last fine pass on the surface the scene does not hide that
        /// pairs only mutual nearest neighbours (PCL's reciprocal correspondences), adopted
        /// when the part fits closer without explaining less. A scan samples steep faces
        /// sparsely, and point-to-point ICP pairs many model points with a face's last scan
        /// point: on the 2 mm bins it left parts 0.4-0.5 mm too high. Mutual pairs do not,
        /// but they change which of two near-twins fits best (in the refinement itself they
        /// cost brackets-bin-2mm 9-14 points of recall on seed 1), so this pass only polishes
        /// the poses the competition chose (Results, "Fourteenth pass").
        polish_pass: bool = true, any();
        /// Also try each hypothesis turned by the model's near-symmetries (a near-symmetric
        /// part turned half-way matches the scene almost as well; the view decides).
        near_symmetry_variants: bool = true, any();
        /// Where the sensor was (see [`SensorConfig`]).
        sensor: SensorConfig = SensorConfig::Auto, sensor();
        /// Record every verified candidate (pose, view shares, verdict) in the result, for
        /// diagnosing what was refused and why.
        report_candidates: bool = false, any();
    }
}

stage_config! {
    /// How a recognition runs (not what it finds: results do not depend on these).
    pub struct RuntimeConfig {
        /// Worker threads: clusters run in parallel, PCL's OpenMP stages use the same count
        /// when not nested. Concurrent calls on one recognizer share them (a call alone uses
        /// all, queued calls split them). 0 = all cores.
        threads: usize = 0, count(0, 1024, "(0 = all cores)");
        /// Time budget per recognition, ms, counted from the start of the work (a wait for
        /// worker threads held by other calls is not counted). When it runs out the call
        /// returns what it verified so far, flagged (`Recognition::interrupted`). None =
        /// unlimited.
        #[serde(skip_serializing_if = "Option::is_none")]
        time_budget_ms: Option<u64> = None, count(1, 86_400_000, "ms");
    }
}
