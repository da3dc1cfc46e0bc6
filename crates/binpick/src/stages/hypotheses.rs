//! Scene voting, step 1: pose hypotheses from the whole scene. The model's point pairs are
//! filed once per working scale ([`VotingModel`]); the scene is sampled at the same step with
//! PCL's `UniformSampling` and `NormalEstimationOMP`; every reference point votes
//! (Drost et al. 2010) and the votes are clustered into poses under the part's symmetries.

use nalgebra::{Isometry3, Point3};

use binpick_cloud::Point;
use binpick_match::{
    OrientedPoints, PointIndex, PoseCluster, PoseClustering, PpfConfig, PpfModel, cluster_poses,
    subsample_by_facing,
};
use binpick_pcl::IcpParams;

use crate::error::{Error, Result, pcl};
use crate::params::VotingConfig;
use crate::result::DerivedScale;
use crate::stages::model::near_symmetries;
use crate::stages::part::Part;

/// Errors of the matching crate, attributed to a stage.
pub(crate) fn matching(stage: &'static str) -> impl Fn(binpick_match::MatchError) -> Error {
    move |e| Error::Input {
        what: stage,
        kind: crate::error::InputKind::Degenerate,
        message: e.to_string(),
    }
}

/// Model points a near-symmetry is judged on.
const SYMMETRY_SAMPLE_POINTS: usize = 600;

/// A near-symmetric turn within this angle ...
const DECLARED_SAME_DEG: f64 = 10.0;
/// ... and this share of the diameter of a declared symmetry is that symmetry.
const DECLARED_SAME_DIAMETERS: f64 = 0.05;

/// The part prepared for one working scale.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub(crate) struct VotingModel {
    /// The part's surface at the working resolution (what is rendered and aligned).
    pub dense: OrientedPoints,
    pub table: PpfModel,
    /// Centroid of the surface, model frame.
    pub centre: Point3<f64>,
    /// Half-turns about the principal axes that map the part nearly onto itself.
    pub near_symmetries: Vec<Isometry3<f64>>,
}

impl VotingModel {
    /// Samples the part at `scale` and files its point pairs.
    pub(crate) fn new(part: &Part, scale: &DerivedScale, cfg: &VotingConfig) -> Result<Self> {
        // Both sides of a thin part must survive the sampling (each face is seen from its own
        // side): sampled per facing, not per cell.
        let dense = subsample_by_facing(&part.surface, scale.resolution_mm);
        let samples = subsample_by_facing(&dense, scale.sampling_step_mm);
        let table = PpfModel::new(
            &samples,
            PpfConfig {
                distance_step_mm: scale.sampling_step_mm,
                feature_angle_bins: cfg.feature_angle_bins,
                alpha_bins: cfg.alpha_bins,
                max_pair_distance_mm: part.size.diameter_mm,
                spread: cfg.spread,
                max_pairs_per_bin: cfg.max_pairs_per_bin,
            },
        )
        .map_err(matching("model point pairs"))?;
        let kp: Vec<Point> = binpick_cloud::strided_points(&dense.points, SYMMETRY_SAMPLE_POINTS)
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let eps = 1e-6 * scale.resolution_mm * scale.resolution_mm;
        let near_symmetries = near_symmetries(
            &dense.points,
            &kp,
            part.size.diameter_mm,
            &|turn: &Isometry3<f64>| IcpParams {
                initial: binpick_pcl::row_major(turn),
                max_correspondence_distance: 0.1 * part.size.diameter_mm,
                max_iterations: 30,
                transformation_epsilon: eps,
                batch_correspondences: true,
                relative_mse: 1e-4,
            },
        )?
        .into_iter()
        // A declared symmetry is not a trap (a ring's half turn is one).
        .filter(|turn| {
            part.symmetries.transforms().iter().all(|s| {
                let moved = s.inverse() * turn;
                moved.rotation.angle().to_degrees() > DECLARED_SAME_DEG
                    || moved.translation.vector.norm()
                        > DECLARED_SAME_DIAMETERS * part.size.diameter_mm
            })
        })
        .collect();
        Ok(Self {
            centre: part.centre(),
            dense,
            table,
            near_symmetries,
        })
    }
}

/// `points` thinned by PCL's `UniformSampling` at `leaf` (the point nearest each cell's
/// centre is kept, with its normal).
pub(crate) fn subsample(points: &OrientedPoints, leaf: f64) -> Result<OrientedPoints> {
    let idx = binpick_pcl::uniform_sampling(&points.points, leaf as f32)
        .map_err(pcl("uniform sampling"))?;
    Ok(OrientedPoints {
        points: idx.iter().map(|&i| points.points[i as usize]).collect(),
        normals: idx.iter().map(|&i| points.normals[i as usize]).collect(),
    })
}

/// Normals of `points` (PCL `NormalEstimationOMP` at the derived radius, oriented towards
/// `viewpoint`; NaN where undefined).
pub(crate) fn scene_normals(
    points: &[Point],
    scale: &DerivedScale,
    viewpoint: [f64; 3],
    threads: u32,
) -> Result<Vec<[f32; 3]>> {
    let normals = binpick_pcl::estimate_normals(
        points,
        scale.normal_radius_mm as f32,
        viewpoint.map(|c| c as f32),
        threads,
    )
    .map_err(pcl("scene normals"))?;
    Ok(normals.iter().map(|n| n.normal).collect())
}

/// The scene's samples at the sampling step (the `world` points with their normals);
/// samples without a normal are dropped.
pub(crate) fn scene_samples(world: OrientedPoints, scale: &DerivedScale) -> Result<OrientedPoints> {
    Ok(subsample(&world, scale.sampling_step_mm)?.with_defined_normals())
}

/// Votes over the scene samples and the strongest pose clusters, best first.
pub(crate) fn vote(
    model: &VotingModel,
    part: &Part,
    samples: &OrientedPoints,
    scale: &DerivedScale,
    cfg: &VotingConfig,
) -> Result<(usize, Vec<PoseCluster>)> {
    if samples.len() < 3 {
        return Ok((0, Vec::new()));
    }
    let index = PointIndex::new("scene samples", &samples.points).map_err(matching("scene"))?;
    let votes = model
        .table
        .vote(
            samples,
            &index,
            &binpick_match::VotingConfig {
                reference_stride: cfg.reference_stride,
                peaks_per_reference: cfg.peaks_per_reference,
                secondary_peak_ratio: cfg.secondary_peak_ratio,
            },
        )
        .map_err(matching("voting"))?;
    let mut clusters = cluster_poses(
        &votes,
        &model.centre,
        &part.symmetries,
        &PoseClustering {
            translation_mm: cfg.cluster_translation_diameters * scale.model_diameter_mm,
            rotation_deg: cfg.cluster_rotation_deg,
        },
    )
    .map_err(matching("pose clustering"))?;
    clusters.truncate(cfg.hypotheses);
    Ok((votes.len(), clusters))
}
