//! `binpick-pcl`: a thin, safe bridge over the real Point Cloud Library 1.13.
//!
//! Each function crosses the FFI boundary once per stage with flat slices (no per-point
//! calls) and returns plain Rust data; PCL types never leave this crate. Every fallible C++
//! call returns [`Result`]: C++ exceptions (bad input, PCL failures) become [`Error`]s.
//!
//! | Rust                              | PCL class (1.13)                                           |
//! |-----------------------------------|------------------------------------------------------------|
//! | [`uniform_sampling`]              | `pcl::UniformSampling` (thesis 3.2.3)                      |
//! | [`voxel_grid`]                    | `pcl::VoxelGrid`                                           |
//! | [`estimate_normals`]              | `pcl::NormalEstimationOMP`                                 |
//! | [`estimate_normals_at`]           | `pcl::NormalEstimationOMP` with `setIndices`               |
//! | [`IndexedCloud::fpfh`]            | `pcl::NormalEstimationOMP` + `pcl::FPFHEstimationOMP` (3.3.2) |
//! | [`IndexedCloud::euclidean_clusters`] | `pcl::EuclideanClusterExtraction` (3.4.1.3)            |
//! | [`segment_plane`]                 | `pcl::SACSegmentation`'s plane fit: `pcl::RandomSampleConsensus` over `pcl::SampleConsensusModelPlane` |
//! | [`match_features`]                | `pcl::registration::CorrespondenceEstimation` (3.4.1)      |
//! | [`reject_sample_consensus`]       | `pcl::registration::CorrespondenceRejectorSampleConsensus` (3.4.2.5) |
//! | [`estimate_svd`]                  | `pcl::registration::TransformationEstimationSVD` (3.5.1)   |
//! | [`IndexedCloud::icp`]             | `pcl::IterativeClosestPoint` (3.6.1)                       |
//!
//! Units are whatever the caller uses consistently (binpick: millimetres). Transforms are
//! row-major 4x4 `[f64; 16]`, source -> target.

mod ffi;

use std::cell::RefCell;
use std::sync::{Arc, Once};

use cxx::UniquePtr;
use ffi::bridge;

pub use bridge::Correspondence;
#[cfg(feature = "reference")]
pub use bridge::{
    ClusterOutcome, IcpFailure, ReferenceCluster, ReferenceDetection, ReferenceParams,
    ReferencePlane, ReferenceResult, ReferenceTimings,
};

/// One point `[x, y, z]`.
pub type Point = [f32; 3];
/// An FPFH descriptor: 3 x 11 bins (`pcl::FPFHSignature33`).
pub type Fpfh = [f32; 33];
/// Row-major 4x4 rigid transform, source -> target.
pub type Mat4 = [f64; 16];

/// Tolerance on `det(R) = +1` for transforms coming out of PCL (single precision inside).
const DET_TOLERANCE: f64 = 1e-3;

/// Errors from the bridge. Messages name the PCL stage and the problem.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum Error {
    /// The C++ side rejected an argument or PCL failed; the message says which and why.
    #[error("PCL {call}: {message}")]
    Pcl { call: &'static str, message: String },
    /// RANSAC found no model (PCL then returns the input correspondences and identity).
    #[error("PCL {call}: no consensus among {correspondences} correspondences")]
    NoConsensus {
        call: &'static str,
        correspondences: usize,
    },
    /// A rotation with det != +1 (a reflection or a degenerate matrix; cf. PCL issue #1707).
    #[error("PCL {call}: transform is not a proper rotation (det = {det:.5})")]
    ImproperRotation { call: &'static str, det: f64 },
    /// The caller's [`Interrupt`] asked the call to stop (`during` names the chunk loop that
    /// noticed); its answer was thrown away.
    #[error("PCL {call}: interrupted during {during}")]
    Interrupted { call: &'static str, during: String },
}

/// A stop request for long bridge calls: returns true once the running call should stop (a
/// time budget ran out, the caller cancelled). See [`set_interrupt`].
pub type Interrupt = Arc<dyn Fn() -> bool + Send + Sync>;

thread_local! {
    static INTERRUPT: RefCell<Option<Interrupt>> = const { RefCell::new(None) };
}

/// Installs `interrupt` for the bridge calls made on this thread from now on (`None` removes
/// it) and returns the previous one. Long calls poll it between chunks whose answers do not
/// depend on where they are cut (ICP iterations, RANSAC iterations of the threshold sweep and
/// of support plane fits, blocks of points of the neighbourhood search, voxel-grid tiles) and
/// return [`Error::Interrupted`] once it says stop; a call that finishes returns the same
/// answer as without it.
pub fn set_interrupt(interrupt: Option<Interrupt>) -> Option<Interrupt> {
    INTERRUPT.with(|i| i.replace(interrupt))
}

fn interrupt_requested() -> bool {
    INTERRUPT.with(|i| i.borrow().as_ref().is_some_and(|stop| stop()))
}

/// Result alias for bridge calls.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// The prefix of the C++ side's interruption (`kInterruptedMarker` in `cpp/include/internal.h`).
const INTERRUPTED_MARKER: &str = "binpick-interrupted: ";

fn pcl_err(call: &'static str) -> impl Fn(cxx::Exception) -> Error {
    move |e| match e.what().strip_prefix(INTERRUPTED_MARKER) {
        Some(during) => Error::Interrupted {
            call,
            during: during.to_owned(),
        },
        None => Error::Pcl {
            call,
            message: e.what().to_owned(),
        },
    }
}

static QUIET: Once = Once::new();

/// PCL prints warnings to stderr; binpick reports every condition as an error instead, so
/// PCL is silenced unless `BINPICK_PCL_VERBOSE` is set (0 = always .. 5 = verbose).
fn init() {
    QUIET.call_once(|| {
        let level = std::env::var("BINPICK_PCL_VERBOSE")
            .ok()
            .and_then(|v| v.parse::<i32>().ok())
            .unwrap_or(0);
        // Level is validated by PCL's wrapper; an out-of-range value just keeps the default.
        let _ = bridge::set_pcl_verbosity(level.clamp(0, 5));
    });
}

fn flat(points: &[Point]) -> &[f32] {
    points.as_flattened()
}

fn unflatten3(v: &[f32]) -> Vec<Point> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn rotation_det(m: &Mat4) -> f64 {
    let (a, b, c) = (m[0], m[1], m[2]);
    let (d, e, f) = (m[4], m[5], m[6]);
    let (g, h, i) = (m[8], m[9], m[10]);
    a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
}

fn check_proper(call: &'static str, m: &Mat4) -> Result<()> {
    let det = rotation_det(m);
    if (det - 1.0).abs() > DET_TOLERANCE || !det.is_finite() {
        return Err(Error::ImproperRotation { call, det });
    }
    Ok(())
}

/// Uniform keypoints (thesis 3.2.3): per `leaf`-sized cubic cell, the input point nearest the
/// cell centre. Returns indices into `points`, ascending. Errors on empty or non-finite input,
/// a non-positive leaf, or a leaf so small the grid would overflow PCL's 32-bit cell index.
pub fn uniform_sampling(points: &[Point], leaf: f32) -> Result<Vec<u32>> {
    init();
    bridge::uniform_sampling(flat(points), leaf).map_err(pcl_err("UniformSampling"))
}

/// Voxel-grid filter (`pcl::VoxelGrid`): one centroid per occupied `leaf`-sized cell (new
/// points, ordered by cell). A grid with more cells than PCL's 32-bit voxel index holds is
/// filtered in tiles cut at voxel boundaries, with the cells and order PCL would give with a
/// wider index; an error only when a coordinate is beyond 2^31 leaves from the origin.
pub fn voxel_grid(points: &[Point], leaf: f32) -> Result<Vec<Point>> {
    init();
    bridge::voxel_grid(flat(points), leaf)
        .map(|v| unflatten3(&v))
        .map_err(pcl_err("VoxelGrid"))
}

/// A surface normal and PCL's curvature estimate; NaN where PCL could not estimate one
/// (fewer than 3 neighbours within the radius).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Normal {
    pub normal: [f32; 3],
    pub curvature: f32,
}

/// Normals of every point from its neighbours within `radius`, flipped towards `viewpoint`.
/// `threads` = OpenMP threads (0 = all cores); the result does not depend on it.
pub fn estimate_normals(
    points: &[Point],
    radius: f32,
    viewpoint: Point,
    threads: u32,
) -> Result<Vec<Normal>> {
    init();
    let v = bridge::estimate_normals(flat(points), radius, &viewpoint, threads)
        .map_err(pcl_err("NormalEstimationOMP"))?;
    Ok(unflatten_normals(&v))
}

/// Normals of the points `at` (indices into `points`) from their neighbours among all of
/// `points` within `radius`, flipped towards `viewpoint`: the same values
/// [`estimate_normals`] gives at those points, without computing the others. An index out
/// of range is an error.
pub fn estimate_normals_at(
    points: &[Point],
    at: &[u32],
    radius: f32,
    viewpoint: Point,
    threads: u32,
) -> Result<Vec<Normal>> {
    init();
    let v = bridge::estimate_normals_at(flat(points), at, radius, &viewpoint, threads)
        .map_err(pcl_err("NormalEstimationOMP"))?;
    Ok(unflatten_normals(&v))
}

fn unflatten_normals(v: &[f32]) -> Vec<Normal> {
    v.chunks_exact(4)
        .map(|c| Normal {
            normal: [c[0], c[1], c[2]],
            curvature: c[3],
        })
        .collect()
}

/// A fitted plane `a x + b y + c z + d = 0` (unit normal) and the indices of its inliers.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    pub coefficients: [f32; 4],
    pub inliers: Vec<u32>,
}

/// RANSAC plane fit as `pcl::SACSegmentation` makes it (PCL's `RandomSampleConsensus` over
/// `SampleConsensusModelPlane`, optimised coefficients, fixed seed). `Ok(None)`
/// when PCL finds no plane. RANSAC's inlier counts are split over `threads` (0 = all cores)
/// on large clouds and counted by the bridge over contiguous copies of the points with PCL's
/// float arithmetic ([`plane_inlier_counts`]); the plane is [`segment_plane_pcl`]'s.
pub fn segment_plane(
    points: &[Point],
    distance_threshold: f32,
    max_iterations: u32,
    threads: u32,
) -> Result<Option<Plane>> {
    init();
    let fit = bridge::segment_plane(flat(points), distance_threshold, max_iterations, threads)
        .map_err(pcl_err("RANSAC plane fit"))?;
    Ok(plane(fit))
}

/// The same fit over PCL's own `SampleConsensusModelPlane` on one thread: the reference the
/// bridge tests hold [`segment_plane`] to (and hold to `SACSegmentation::segment`'s answer).
#[doc(hidden)]
pub fn segment_plane_pcl(
    points: &[Point],
    distance_threshold: f32,
    max_iterations: u32,
) -> Result<Option<Plane>> {
    init();
    let fit = bridge::segment_plane_pcl(flat(points), distance_threshold, max_iterations)
        .map_err(pcl_err("RANSAC plane fit"))?;
    Ok(plane(fit))
}

fn plane(fit: bridge::PlaneFit) -> Option<Plane> {
    fit.found.then_some(Plane {
        coefficients: fit.coefficients,
        inliers: fit.inliers,
    })
}

/// For each plane `[a, b, c, d]`, the points within `distance_threshold` of it as PCL's
/// `SampleConsensusModelPlane` and the split model [`segment_plane`] uses on large clouds find
/// them: `[pcl count, split count, pcl selection, split selection]` per plane, the counts from
/// `countWithinDistance`, the selections' sizes from `selectWithinDistance` (the split one
/// `u64::MAX` unless its indices and distances are PCL's exactly). For tests that the two agree.
#[doc(hidden)]
pub fn plane_inlier_counts(
    points: &[Point],
    planes: &[[f32; 4]],
    distance_threshold: f64,
) -> Result<Vec<[u64; 4]>> {
    init();
    let counts =
        bridge::plane_inlier_counts(flat(points), planes.as_flattened(), distance_threshold)
            .map_err(pcl_err("SampleConsensusModelPlane"))?;
    Ok(counts
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect())
}

/// For every source descriptor, its nearest target descriptor
/// (`pcl::registration::CorrespondenceEstimation<FPFHSignature33, FPFHSignature33>`);
/// `distance` is the squared L2 distance between histograms.
pub fn match_features(source: &[Fpfh], target: &[Fpfh]) -> Result<Vec<Correspondence>> {
    init();
    bridge::match_features(source.as_flattened(), target.as_flattened())
        .map_err(pcl_err("CorrespondenceEstimation"))
}

/// What the RANSAC rejector kept.
#[derive(Clone, Debug, PartialEq)]
pub struct Consensus {
    /// The inlier correspondences.
    pub kept: Vec<Correspondence>,
    /// RANSAC's best transform, source -> target (row-major, proper rotation).
    pub transform: Mat4,
}

/// `pcl::registration::CorrespondenceRejectorSampleConsensus` (thesis 3.4.2.5) with
/// `max_iterations` and `inlier_threshold` (point units). Deterministic (PCL seed 12345).
/// Errors: [`Error::NoConsensus`] when RANSAC finds no model, [`Error::ImproperRotation`]
/// when its transform is not a rotation.
pub fn reject_sample_consensus(
    source: &[Point],
    target: &[Point],
    correspondences: &[Correspondence],
    inlier_threshold: f32,
    max_iterations: u32,
) -> Result<Consensus> {
    init();
    let r = bridge::reject_sample_consensus(
        flat(source),
        flat(target),
        correspondences,
        inlier_threshold,
        max_iterations,
    )
    .map_err(pcl_err(SAC_CALL))?;
    consensus(r, correspondences.len())
}

/// [`reject_sample_consensus`] once per threshold of `inlier_thresholds` on the same
/// correspondences, with the same answers, in one pass: PCL seeds every rejector run alike, so
/// the runs of a threshold sweep draw the same samples and fit the same candidate transforms.
/// The C++ side replays `pcl::RandomSampleConsensus` for all thresholds at once with PCL's
/// registration model. One result per threshold, in order.
pub fn reject_sample_consensus_sweep(
    source: &[Point],
    target: &[Point],
    correspondences: &[Correspondence],
    inlier_thresholds: &[f32],
    max_iterations: u32,
) -> Result<Vec<Result<Consensus>>> {
    init();
    let runs = bridge::reject_sample_consensus_sweep(
        flat(source),
        flat(target),
        correspondences,
        inlier_thresholds,
        max_iterations,
    )
    .map_err(pcl_err(SAC_CALL))?;
    Ok(runs
        .into_iter()
        .map(|r| consensus(r, correspondences.len()))
        .collect())
}

/// PCL's name of the ICP call, in errors.
const ICP_CALL: &str = "IterativeClosestPoint";

const SAC_CALL: &str = "CorrespondenceRejectorSampleConsensus";

fn consensus(r: bridge::SacResult, correspondences: usize) -> Result<Consensus> {
    if !r.converged {
        return Err(Error::NoConsensus {
            call: SAC_CALL,
            correspondences,
        });
    }
    if (r.rotation_det - 1.0).abs() > DET_TOLERANCE {
        return Err(Error::ImproperRotation {
            call: SAC_CALL,
            det: r.rotation_det,
        });
    }
    Ok(Consensus {
        kept: r.kept,
        transform: r.transform,
    })
}

/// `pcl::registration::TransformationEstimationSVD` (thesis 3.5.1): the rigid transform
/// source -> target minimising the squared distances of the corresponding points.
pub fn estimate_svd(
    source: &[Point],
    target: &[Point],
    correspondences: &[Correspondence],
) -> Result<Mat4> {
    const CALL: &str = "TransformationEstimationSVD";
    init();
    let t =
        bridge::estimate_svd(flat(source), flat(target), correspondences).map_err(pcl_err(CALL))?;
    check_proper(CALL, &t.m)?;
    Ok(t.m)
}

/// FPFH settings: radii in point units, sensor viewpoint for normal orientation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FpfhParams {
    pub feature_radius: f32,
    pub normal_radius: f32,
    pub viewpoint: Point,
    /// OpenMP threads for normals and FPFH (0 = all cores). Results do not depend on it.
    pub threads: u32,
}

/// FPFH descriptors at a set of keypoints; `valid[i]` is false where PCL could not compute
/// one (no neighbours or no normal), and that descriptor must not be matched.
#[derive(Clone, Debug, PartialEq)]
pub struct FpfhSet {
    pub descriptors: Vec<Fpfh>,
    pub valid: Vec<bool>,
}

/// ICP settings (thesis 3.6.1: 50 iterations, epsilon 1e-7).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpParams {
    /// Initial guess, source -> target.
    pub initial: Mat4,
    pub max_correspondence_distance: f64,
    pub max_iterations: u32,
    pub transformation_epsilon: f64,
    /// Find each iteration's correspondences with one batched FLANN query over the same index
    /// PCL builds, instead of PCL's one query per point: identical correspondences, several
    /// times faster. `false` runs PCL's default `CorrespondenceEstimation`.
    pub batch_correspondences: bool,
    /// Also stop when the mean squared correspondence distance changes by less than this
    /// fraction between two iterations (`setEuclideanFitnessEpsilon`); 0 = off (PCL default).
    pub relative_mse: f64,
    /// Keep only correspondences whose target point has the source point as its own nearest
    /// source point (`setUseReciprocalCorrespondences`): where the scan samples a steep face
    /// sparsely, many model points would otherwise pair with its last scan point and pull
    /// the pose towards it.
    pub reciprocal: bool,
}

/// Why ICP stopped (`pcl::registration::DefaultConvergenceCriteria::ConvergenceState`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IcpStop {
    NotConverged,
    Iterations,
    Transform,
    AbsoluteMse,
    RelativeMse,
    NoCorrespondences,
    FailureAfterMaxIterations,
    Unknown(i32),
}

impl IcpStop {
    fn from_pcl(state: i32) -> Self {
        match state {
            0 => Self::NotConverged,
            1 => Self::Iterations,
            2 => Self::Transform,
            3 => Self::AbsoluteMse,
            4 => Self::RelativeMse,
            5 => Self::NoCorrespondences,
            6 => Self::FailureAfterMaxIterations,
            s => Self::Unknown(s),
        }
    }
}

/// ICP outcome. `transform` is the full source -> target transform (initial guess included).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpOutcome {
    pub transform: Mat4,
    pub converged: bool,
    /// PCL's fitness score: mean squared distance of source points to their nearest target
    /// point, over those within the max correspondence distance.
    pub fitness: f64,
    pub iterations: u32,
    pub stop: IcpStop,
}

/// A cloud uploaded to PCL once, with its kd-tree (FLANN), reused by many calls: clustering,
/// feature surfaces, ICP targets, nearest-neighbour queries. `Send + Sync`: it is immutable
/// after construction and every call only reads it.
pub struct IndexedCloud {
    inner: UniquePtr<bridge::Cloud>,
    len: usize,
}

impl std::fmt::Debug for IndexedCloud {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("IndexedCloud")
            .field("len", &self.len)
            .finish()
    }
}

impl IndexedCloud {
    /// Copies `points` into a `pcl::PointCloud<PointXYZ>` and builds its kd-tree. Errors on an
    /// empty cloud or a non-finite coordinate.
    pub fn new(points: &[Point]) -> Result<Self> {
        init();
        Self::uploaded(bridge::upload_cloud(flat(points)))
    }

    /// [`IndexedCloud::new`], and every point's neighbours within `radius` found once (on
    /// `threads` threads, 0 = all cores), so normals and FPFH ([`IndexedCloud::fpfh`]) and
    /// Euclidean clustering at any radius up to it reuse them instead of searching the kd-tree
    /// again per radius and per pass. Same answers as without; a cloud so dense that the lists
    /// would exceed 16 Mi neighbours is searched without them.
    pub fn with_neighbourhoods(points: &[Point], radius: f32, threads: u32) -> Result<Self> {
        init();
        Self::uploaded(bridge::upload_cloud_with_neighbourhoods(
            flat(points),
            radius,
            threads,
        ))
    }

    fn uploaded(upload: Result<UniquePtr<bridge::Cloud>, cxx::Exception>) -> Result<Self> {
        let inner = upload.map_err(pcl_err("upload"))?;
        let len = bridge::cloud_len(&inner);
        Ok(Self { inner, len })
    }

    fn cloud(&self) -> &bridge::Cloud {
        // `new` is the only constructor and `upload_cloud` never returns null on success.
        self.inner
            .as_ref()
            .unwrap_or_else(|| unreachable!("IndexedCloud holds a null pointer"))
    }

    pub fn len(&self) -> usize {
        self.len
    }

    /// The radius up to which neighbourhoods are cached ([`IndexedCloud::with_neighbourhoods`]),
    /// `None` when they are not.
    pub fn neighbourhood_radius(&self) -> Option<f64> {
        let r = bridge::cloud_neighbourhood_radius(self.cloud());
        (r > 0.0).then_some(r)
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Squared distance from each query point to its nearest cloud point.
    pub fn nearest_sq_distances(&self, query: &[Point]) -> Result<Vec<f32>> {
        bridge::nearest_sq_distances(self.cloud(), flat(query)).map_err(pcl_err("KdTree"))
    }

    /// [`estimate_normals_at`] of this cloud's points `at`, searched with the kd-tree built on
    /// upload (the one `estimate_normals_at` would build): the same normals, and the tree can
    /// be built ahead, while something else runs.
    pub fn normals_at(
        &self,
        at: &[u32],
        radius: f32,
        viewpoint: Point,
        threads: u32,
    ) -> Result<Vec<Normal>> {
        let v = bridge::cloud_normals_at(self.cloud(), at, radius, &viewpoint, threads)
            .map_err(pcl_err("NormalEstimationOMP"))?;
        Ok(unflatten_normals(&v))
    }

    /// FPFH at `keypoints` (indices into this cloud), with the whole cloud as search surface:
    /// normals at `normal_radius`, descriptors at `feature_radius` (thesis 3.3.2).
    pub fn fpfh(&self, keypoints: &[u32], params: &FpfhParams) -> Result<FpfhSet> {
        let f = bridge::cloud_fpfh(
            self.cloud(),
            keypoints,
            params.feature_radius,
            params.normal_radius,
            &params.viewpoint,
            params.threads,
        )
        .map_err(pcl_err("FPFHEstimationOMP"))?;
        let descriptors = f
            .values
            .chunks_exact(33)
            .map(|c| {
                let mut d = [0.0f32; 33];
                d.copy_from_slice(c);
                d
            })
            .collect();
        Ok(FpfhSet {
            descriptors,
            valid: f.valid,
        })
    }

    /// Euclidean clusters (thesis 3.4.1.3): indices per cluster, ascending; clusters with a
    /// size outside `[min_size, max_size]` are dropped; clusters ordered by first index.
    pub fn euclidean_clusters(
        &self,
        tolerance: f32,
        min_size: u32,
        max_size: u32,
    ) -> Result<Vec<Vec<u32>>> {
        let c = bridge::euclidean_clusters(self.cloud(), tolerance, min_size, max_size)
            .map_err(pcl_err("EuclideanClusterExtraction"))?;
        Ok(c.offsets
            .windows(2)
            .map(|w| c.indices[w[0] as usize..w[1] as usize].to_vec())
            .collect())
    }

    /// ICP of `source` onto this cloud, reusing its kd-tree. Errors if PCL's transform is not
    /// a proper rotation.
    pub fn icp(&self, source: &[Point], params: &IcpParams) -> Result<IcpOutcome> {
        let p = bridge::IcpParams {
            initial: params.initial,
            max_correspondence_distance: params.max_correspondence_distance,
            max_iterations: params.max_iterations,
            transformation_epsilon: params.transformation_epsilon,
            batch_correspondences: params.batch_correspondences,
            relative_mse: params.relative_mse,
            reciprocal: params.reciprocal,
        };
        let r = bridge::icp_align(self.cloud(), flat(source), &p).map_err(pcl_err(ICP_CALL))?;
        check_proper(ICP_CALL, &r.transform)?;
        Ok(IcpOutcome {
            transform: r.transform,
            converged: r.converged,
            fitness: r.fitness,
            iterations: r.iterations,
            stop: IcpStop::from_pcl(r.state),
        })
    }
}

#[cfg(feature = "reference")]
/// The reference pipeline (`cpp/reference/`): thesis Algorithms 1 and 2 written directly in C++
/// against PCL, the way the thesis describes them (model features recomputed per cluster, a
/// kd-tree built by every stage and every score, an OpenMP loop over clusters), in one call:
/// model and scene points plus parameters -> detections in cluster order, per-cluster
/// outcomes, preprocessing counts and stage timings. Bad input is an [`Error::Pcl`].
pub fn reference_recognize(
    model: &[Point],
    scene: &[Point],
    params: &ReferenceParams,
) -> Result<ReferenceResult> {
    init();
    bridge::reference_recognize(flat(model), flat(scene), params)
        .map_err(pcl_err("reference pipeline"))
}

/// Row-major 4x4 -> rigid pose; `None` unless it is a rigid transform within 1e-4. The one
/// place where the bridge's matrices become poses.
pub fn rigid_pose(m: &Mat4) -> Option<nalgebra::Isometry3<f64>> {
    binpick_cloud::pose_from_row_major(m).ok()
}

/// Rigid pose -> row-major 4x4 (for [`IcpParams::initial`]).
pub fn row_major(pose: &nalgebra::Isometry3<f64>) -> Mat4 {
    binpick_cloud::pose_to_row_major(pose)
}

impl IcpOutcome {
    /// The final transform as a pose; `None` if it is not rigid within 1e-4.
    pub fn pose(&self) -> Option<nalgebra::Isometry3<f64>> {
        rigid_pose(&self.transform)
    }
}

#[cfg(feature = "reference")]
impl ReferenceDetection {
    /// The final pose (model -> scene); `None` if the matrix is not rigid.
    pub fn pose(&self) -> Option<nalgebra::Isometry3<f64>> {
        rigid_pose(&self.pose)
    }

    /// The initial alignment's pose; `None` if the matrix is not rigid.
    pub fn initial_pose(&self) -> Option<nalgebra::Isometry3<f64>> {
        rigid_pose(&self.initial_pose)
    }

    /// Why ICP failed, worded as the bridge's own ICP call words it; `None` when it ran.
    pub fn icp_error(&self) -> Option<Error> {
        match self.icp_failure {
            IcpFailure::Pcl => Some(Error::Pcl {
                call: ICP_CALL,
                message: self.icp_error.clone(),
            }),
            IcpFailure::ImproperRotation => Some(Error::ImproperRotation {
                call: ICP_CALL,
                det: self.icp_det,
            }),
            _ => None,
        }
    }
}
