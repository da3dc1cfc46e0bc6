//! FPFH descriptors at uniform keypoints (thesis 3.2.3 + 3.3.2), computed the same way for
//! the model (once, in `Recognizer::new`) and for every cluster.

use binpick_cloud::Point;
use binpick_pcl::{Fpfh, FpfhParams, IndexedCloud};

use crate::error::{Result, pcl};
use crate::params::{FeatureSurface, Params};

/// Descriptors of one FPFH radius. Only keypoints with a defined descriptor are kept;
/// `keypoint[i]` is the keypoint index of `descriptors[i]`.
#[derive(Clone, Debug)]
pub struct RadiusFeatures {
    pub radius_mm: f64,
    pub descriptors: Vec<Fpfh>,
    pub keypoint: Vec<u32>,
}

/// Uniform keypoints (indices into `points`) at `leaf`.
pub fn keypoints(points: &[Point], leaf: f64) -> Result<Vec<u32>> {
    binpick_pcl::uniform_sampling(points, leaf as f32).map_err(pcl("uniform keypoints"))
}

/// FPFH at `keypoint_idx` (indices into `points`) for one radius, normals at
/// `normal_radius_factor` x radius, oriented towards `viewpoint`.
pub fn fpfh_for_radius(
    surface: &IndexedCloud,
    surface_keypoints: &[u32],
    radius_mm: f64,
    params: &Params,
    viewpoint: [f64; 3],
    threads: u32,
) -> Result<RadiusFeatures> {
    let set = surface
        .fpfh(
            surface_keypoints,
            &FpfhParams {
                feature_radius: radius_mm as f32,
                normal_radius: (radius_mm * params.normal_radius_factor) as f32,
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
/// its points' neighbourhoods up to the largest normal or FPFH radius of `params`, so the
/// radii share one kd-tree search per point.
pub fn feature_surface(
    points: &[Point],
    keypoint_idx: &[u32],
    keypoint_points: &[Point],
    params: &Params,
) -> Result<(IndexedCloud, Vec<u32>)> {
    let widest = params
        .fpfh_radii_mm
        .iter()
        .map(|&r| r.max(r * params.normal_radius_factor))
        .fold(0.0f64, f64::max) as f32;
    let upload = |pts: &[Point]| {
        IndexedCloud::with_neighbourhoods(pts, widest, 1).map_err(pcl("FPFH surface"))
    };
    match params.feature_surface {
        FeatureSurface::Keypoints => Ok((
            upload(keypoint_points)?,
            (0..keypoint_points.len() as u32).collect(),
        )),
        FeatureSurface::Cloud => Ok((upload(points)?, keypoint_idx.to_vec())),
    }
}
