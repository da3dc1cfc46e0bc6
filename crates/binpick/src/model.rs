//! Everything that depends only on the model, computed once per `Recognizer` (the thesis
//! recomputed it per cluster; 5.7 notes it "can be precomputed offline").

use binpick_cloud::{Point, PointCloud};
use rayon::prelude::*;

use crate::error::{Result, input, pcl};
use crate::features::{RadiusFeatures, feature_surface, fpfh_for_radius, keypoints};
use crate::params::Params;

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
}

/// Smallest model the pipeline can work with, in voxelised points.
const MIN_MODEL_POINTS: usize = 20;

impl PreparedModel {
    /// Voxelises the model, extracts keypoints and computes FPFH for every radius (radii in
    /// parallel, each with `threads` OpenMP threads).
    pub fn new(model: &PointCloud, params: &Params, threads: u32) -> Result<Self> {
        let cloud = binpick_pcl::voxel_grid(&model.points, params.resolution_mm as f32)
            .map_err(pcl("model voxel grid"))?;
        if cloud.len() < MIN_MODEL_POINTS {
            return Err(input(
                "model",
                format!(
                    "only {} points remain after the {} mm voxel grid (need {MIN_MODEL_POINTS}); \
                     is the resolution too coarse or the cloud in the wrong units?",
                    cloud.len(),
                    params.resolution_mm
                ),
            ));
        }
        let kp_idx = keypoints(&cloud, params.initial_leaf_mm)?;
        let initial_keypoints: Vec<Point> = kp_idx.iter().map(|&i| cloud[i as usize]).collect();
        if initial_keypoints.len() < 3 {
            return Err(input(
                "model",
                format!(
                    "{} keypoints at the {} mm initial leaf; at least 3 are needed",
                    initial_keypoints.len(),
                    params.initial_leaf_mm
                ),
            ));
        }
        let (surface, surface_kp) =
            feature_surface(&cloud, &kp_idx, &initial_keypoints, params.feature_surface)?;
        let features = params
            .fpfh_radii_mm
            .par_iter()
            .map(|&r| {
                fpfh_for_radius(
                    &surface,
                    &surface_kp,
                    r,
                    params,
                    params.model_viewpoint_mm,
                    threads,
                )
            })
            .collect::<Result<Vec<_>>>()?;
        if let Some(f) = features.iter().find(|f| f.descriptors.len() < 3) {
            return Err(input(
                "model",
                format!(
                    "only {} keypoints have an FPFH descriptor at radius {} mm",
                    f.descriptors.len(),
                    f.radius_mm
                ),
            ));
        }
        let final_idx = keypoints(&cloud, params.final_leaf_mm)?;
        let final_keypoints = final_idx.iter().map(|&i| cloud[i as usize]).collect();
        let diameter_mm = diameter(&initial_keypoints);
        Ok(Self {
            cloud,
            initial_keypoints,
            features,
            final_keypoints,
            diameter_mm,
        })
    }
}

/// Largest pairwise distance (exact, O(n^2) over the keypoints; a few thousand at most).
pub fn diameter(points: &[Point]) -> f64 {
    let mut best = 0.0f64;
    for (i, a) in points.iter().enumerate() {
        for b in &points[i + 1..] {
            let d: f64 = (0..3).map(|k| f64::from(a[k] - b[k]).powi(2)).sum();
            best = best.max(d);
        }
    }
    best.sqrt()
}
