//! Stage 3, keypoints and FPFH descriptors (thesis 3.2.3 + 3.3.2, Algorithm 1 step 1a-b),
//! computed the same way for the model (once, in `Recognizer::new`) and for every cluster.

use rayon::prelude::*;

use binpick_cloud::Point;
use binpick_pcl::{Fpfh, FpfhParams, IndexedCloud};

use crate::deadline::Deadline;
use crate::error::{Result, pcl};
use crate::params::{FeatureConfig, FeatureSurface};

/// Descriptors of one FPFH radius. Only keypoints with a defined descriptor are kept;
/// `keypoint[i]` is the keypoint index of `descriptors[i]`.
#[derive(Clone, Debug)]
pub struct RadiusFeatures {
    pub radius_mm: f64,
    pub descriptors: Vec<Fpfh>,
    pub keypoint: Vec<u32>,
}

/// The uniform keypoints of a cluster (or of a sphere, remainder or split of one) and their
/// FPFH descriptors for every radius (thesis 4.1 step 1a-b).
#[derive(Clone, Debug)]
pub(crate) struct ClusterFeatures {
    pub keypoints: Vec<Point>,
    /// One entry per radius of `fpfh_radii_mm`, keypoint indices into `keypoints`.
    pub features: Vec<RadiusFeatures>,
}

/// Keypoints at the initial leaf and FPFH per radius (radii in parallel, PCL's OpenMP at one
/// thread), normals towards the scene viewpoint. `Ok(None)` with fewer than 3 keypoints.
pub(crate) fn cluster_features(
    cluster: &[Point],
    cfg: &FeatureConfig,
    deadline: &Deadline,
) -> Result<Option<ClusterFeatures>> {
    let keypoint_idx = keypoints(cluster, cfg.initial_leaf_mm)?;
    if keypoint_idx.len() < 3 {
        return Ok(None);
    }
    let keypoints: Vec<Point> = keypoint_idx.iter().map(|&i| cluster[i as usize]).collect();
    let (surface, surface_kp) = feature_surface(cluster, &keypoint_idx, &keypoints, cfg)?;
    let features = cfg
        .fpfh_radii_mm
        .par_iter()
        .map(|&r| {
            deadline.check("cluster FPFH")?;
            fpfh_for_radius(&surface, &surface_kp, r, cfg, cfg.scene_viewpoint_mm, 1)
        })
        .collect::<Result<_>>()?;
    Ok(Some(ClusterFeatures {
        keypoints,
        features,
    }))
}

/// Uniform keypoints (indices into `points`) at `leaf`.
pub(crate) fn keypoints(points: &[Point], leaf: f64) -> Result<Vec<u32>> {
    binpick_pcl::uniform_sampling(points, leaf as f32).map_err(pcl("uniform keypoints"))
}

/// FPFH at `surface_keypoints` for one radius, normals at `normal_radius_factor` x radius,
/// oriented towards `viewpoint`.
pub(crate) fn fpfh_for_radius(
    surface: &IndexedCloud,
    surface_keypoints: &[u32],
    radius_mm: f64,
    cfg: &FeatureConfig,
    viewpoint: [f64; 3],
    threads: u32,
) -> Result<RadiusFeatures> {
    let set = surface
        .fpfh(
            surface_keypoints,
            &FpfhParams {
                feature_radius: radius_mm as f32,
                normal_radius: (radius_mm * cfg.normal_radius_factor) as f32,
                viewpoint: viewpoint.map(|c| c as f32),
                threads,
            },
        )
        .map_err(pcl("FPFH"))?;
    let mut out = RadiusFeatures {
        radius_mm,
        descriptors: Vec::with_capacity(set.descriptors.len()),
        keypoint: Vec::with_capacity(set.descriptors.len()),
    };
    for (k, (d, ok)) in set.descriptors.into_iter().zip(set.valid).enumerate() {
        if ok {
            out.descriptors.push(d);
            out.keypoint.push(k as u32);
        }
    }
    Ok(out)
}

/// The search surface for FPFH and the keypoint indices within it, per
/// [`FeatureSurface`]: either the keypoints themselves or the full cloud. The surface caches
/// its points' neighbourhoods up to the largest normal or FPFH radius, so the radii share one
/// kd-tree search per point.
pub(crate) fn feature_surface(
    points: &[Point],
    keypoint_idx: &[u32],
    keypoint_points: &[Point],
    cfg: &FeatureConfig,
) -> Result<(IndexedCloud, Vec<u32>)> {
    let widest = cfg
        .fpfh_radii_mm
        .iter()
        .map(|&r| r.max(r * cfg.normal_radius_factor))
        .fold(0.0f64, f64::max) as f32;
    let upload = |pts: &[Point]| {
        IndexedCloud::with_neighbourhoods(pts, widest, 1).map_err(pcl("FPFH surface"))
    };
    match cfg.feature_surface {
        FeatureSurface::Keypoints => Ok((
            upload(keypoint_points)?,
            (0..keypoint_points.len() as u32).collect(),
        )),
        FeatureSurface::Cloud => Ok((upload(points)?, keypoint_idx.to_vec())),
    }
}
