//! Everything that depends only on the model, computed once per `Recognizer` (the thesis
//! recomputed it per cluster; 5.7 notes it "can be precomputed offline").

use binpick_cloud::{Point, PointCloud, to_point3};
use binpick_pcl::{IcpParams, IndexedCloud};
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use rayon::prelude::*;

use crate::error::{InputKind, Result, input_as, pcl};
use crate::params::Params;
use crate::stages::features::{RadiusFeatures, feature_surface, fpfh_for_radius, keypoints};
use crate::stages::final_alignment::icp_settings;

/// A model ready for matching. All coordinates in the model frame, mm.
#[derive(Clone, Debug)]
pub struct PreparedModel {
    /// The model after the resolution voxel grid (what cluster sizes are relative to).
    pub cloud: Vec<Point>,
    /// Uniform keypoints at the initial leaf (thesis Alg. 1 step 1a).
    pub initial_keypoints: Vec<Point>,
    /// FPFH of the initial keypoints, one entry per radius in `Params::fpfh_radii_mm`.
    pub features: Vec<RadiusFeatures>,
    /// Uniform keypoints at the final leaf, used by ICP and the final score (step 3a).
    pub final_keypoints: Vec<Point>,
    /// Largest distance between two model points, mm.
    pub diameter_mm: f64,
    /// Largest distance from the model's centroid to its points, mm (thesis 3.4.1.2).
    pub radius_mm: f64,
    /// Near-symmetries of the model (model frame -> model frame): half-turns about its
    /// principal axes, each refined by ICP of the model onto itself. Empty when the
    /// near-symmetry candidates extension is off.
    pub near_symmetries: Vec<Isometry3<f64>>,
}

/// Model points sampled to tell a near-symmetry from the identity.
const SYMMETRY_SAMPLE_POINTS: usize = 500;
/// A refined half-turn is a near-symmetry when it moves the sample by more than this, in
/// model diameters, from the identity and from the ones already found.
const SYMMETRY_MIN_MOVE_DIAMETERS: f64 = 0.1;

impl PreparedModel {
    /// Voxelises the model, extracts keypoints and computes FPFH for every radius (radii in
    /// parallel, each with `threads` OpenMP threads). `stages` are the resolved stage configs
    /// ([`Params::stages`]).
    pub(crate) fn new(model: &PointCloud, stages: &Params, threads: u32) -> Result<Self> {
        let resolution_mm = stages.preprocess.resolution();
        let cfg = &stages.features;
        let cloud = binpick_pcl::voxel_grid(&model.points, resolution_mm as f32)
            .map_err(pcl("model voxel grid"))?;
        if cloud.len() < cfg.min_model_points {
            return Err(input_as(
                "model",
                InputKind::Degenerate,
                format!(
                    "only {} points remain after the {} mm voxel grid (need {}); \
                     is the resolution too coarse or the cloud in the wrong units?",
                    cloud.len(),
                    resolution_mm,
                    cfg.min_model_points
                ),
            ));
        }
        let kp_idx = keypoints(&cloud, cfg.initial_leaf_mm)?;
        let initial_keypoints: Vec<Point> = kp_idx.iter().map(|&i| cloud[i as usize]).collect();
        if initial_keypoints.len() < 3 {
            return Err(input_as(
                "model",
                InputKind::Degenerate,
                format!(
                    "{} keypoints at the {} mm initial leaf; at least 3 are needed",
                    initial_keypoints.len(),
                    cfg.initial_leaf_mm
                ),
            ));
        }
        let (surface, surface_kp) = feature_surface(&cloud, &kp_idx, &initial_keypoints, cfg)?;
        let features = cfg
            .fpfh_radii_mm
            .par_iter()
            .map(|&r| {
                fpfh_for_radius(
                    &surface,
                    &surface_kp,
                    r,
                    cfg,
                    cfg.model_viewpoint_mm,
                    threads,
                )
            })
            .collect::<Result<Vec<_>>>()?;
        if let Some(f) = features.iter().find(|f| f.descriptors.len() < 3) {
            return Err(input_as(
                "model",
                InputKind::Degenerate,
                format!(
                    "only {} keypoints have an FPFH descriptor at radius {} mm",
                    f.descriptors.len(),
                    f.radius_mm
                ),
            ));
        }
        let final_idx = keypoints(&cloud, stages.icp.final_leaf_mm)?;
        let final_keypoints: Vec<Point> = final_idx.iter().map(|&i| cloud[i as usize]).collect();
        let diameter_mm = diameter(&initial_keypoints);
        let radius_mm = radius(&cloud);
        let near_symmetries = if stages.consensus.symmetry_candidates {
            near_symmetries(&cloud, &initial_keypoints, diameter_mm, &|turn| {
                icp_settings(&stages.icp, turn)
            })?
        } else {
            Vec::new()
        };
        Ok(Self {
            cloud,
            initial_keypoints,
            features,
            final_keypoints,
            diameter_mm,
            radius_mm,
            near_symmetries,
        })
    }
}

/// The half-turns about the model's principal axes (through its centroid), each refined by
/// ICP of the model's final keypoints onto the model, keeping those that do not collapse to
/// the identity. Bent sheets and pipes are often nearly symmetric under one of them, and the
/// RANSAC consensus then lands on the flipped pose.
pub(crate) fn near_symmetries(
    cloud: &[Point],
    keypoints: &[Point],
    diameter_mm: f64,
    icp: &(dyn Fn(&Isometry3<f64>) -> IcpParams + Sync),
) -> Result<Vec<Isometry3<f64>>> {
    let pts: Vec<Vector3<f64>> = cloud.iter().map(|p| to_point3(p).coords).collect();
    let n = pts.len() as f64;
    let c = pts.iter().sum::<Vector3<f64>>() / n;
    let cov = pts.iter().fold(Matrix3::zeros(), |acc, p| {
        acc + (p - c) * (p - c).transpose()
    }) / n;
    let axes = cov.symmetric_eigen().eigenvectors;
    let target = IndexedCloud::new(cloud).map_err(pcl("model self-registration"))?;
    let sample = binpick_cloud::strided_points(keypoints, SYMMETRY_SAMPLE_POINTS);
    // The three half-turns refined in parallel (self-registration starts far from the
    // surface, so its nearest-neighbour searches are the slow kind); kept in axis order.
    let refined: Vec<Isometry3<f64>> = (0..3)
        .into_par_iter()
        .map(|k| {
            let axis = Unit::new_normalize(axes.column(k).into_owned());
            let turn = Translation3::from(c)
                * UnitQuaternion::from_axis_angle(&axis, std::f64::consts::PI)
                * Translation3::from(-c);
            target
                .icp(keypoints, &icp(&turn))
                .ok()
                .and_then(|o| o.pose())
                .unwrap_or(turn)
        })
        .collect();
    let mut found: Vec<Isometry3<f64>> = Vec::new();
    for r in refined {
        // Keep it unless ICP slid back to the identity or to one already found.
        let distinct = |a: &Isometry3<f64>| {
            let d = sample
                .iter()
                .map(|p: &Point3<f64>| (a * p - r * p).norm())
                .sum::<f64>()
                / sample.len().max(1) as f64;
            d > SYMMETRY_MIN_MOVE_DIAMETERS * diameter_mm
        };
        if distinct(&Isometry3::identity()) && found.iter().all(distinct) {
            found.push(r);
        }
    }
    Ok(found)
}

/// Largest distance from the centroid to a point.
pub(crate) fn radius(points: &[Point]) -> f64 {
    let n = points.len().max(1) as f64;
    let mut c = [0.0f64; 3];
    for p in points {
        for k in 0..3 {
            c[k] += f64::from(p[k]) / n;
        }
    }
    points
        .iter()
        .map(|p| {
            (0..3)
                .map(|k| (f64::from(p[k]) - c[k]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
}

/// Largest pairwise distance (exact, O(n^2) over the keypoints; a few thousand at most).
pub(crate) fn diameter(points: &[Point]) -> f64 {
    let mut best = 0.0f64;
    for (i, a) in points.iter().enumerate() {
        for b in &points[i + 1..] {
            let d: f64 = (0..3).map(|k| f64::from(a[k] - b[k]).powi(2)).sum();
            best = best.max(d);
        }
    }
    best.sqrt()
}
