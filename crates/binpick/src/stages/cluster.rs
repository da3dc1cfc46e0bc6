//! Stage 2, Euclidean clustering of the scene (thesis 3.4.1.3, 4.3 #2-4), and the splits of a
//! cluster that the pile-search extensions search: spheres (3.4.1.2), remainders after an
//! accepted part, and tighter re-clustering.

use nalgebra::Isometry3;

use binpick_cloud::Point;
use binpick_pcl::IndexedCloud;

use crate::error::{Result, input, pcl};
use crate::params::{ClusteringConfig, PileSearchConfig};
use crate::validate::NearestIndex;

/// Cluster size bounds in points (thesis 4.3 #3-4, relative to the voxelised model).
pub(crate) fn size_range(cfg: &ClusteringConfig, model_points: usize) -> (u32, u32) {
    let n = model_points as f64;
    let min = (cfg.cluster_min_factor * n).ceil().max(1.0);
    let max = (cfg.cluster_max_factor * n).floor().max(min);
    (min as u32, max.min(f64::from(u32::MAX)) as u32)
}

/// The scene's Euclidean clusters at `tolerance_mm`, as point indices ordered by first index.
/// Each point's neighbourhood at the tolerance is found once, on all `threads`.
pub(crate) fn euclidean_clusters(
    world: &[Point],
    tolerance_mm: f64,
    (min_size, max_size): (u32, u32),
    threads: usize,
) -> Result<Vec<Vec<u32>>> {
    let tolerance = tolerance_mm as f32;
    let cloud = IndexedCloud::with_neighbourhoods(world, tolerance, threads as u32)
        .map_err(pcl("scene upload"))?;
    cloud
        .euclidean_clusters(tolerance, min_size, max_size)
        .map_err(pcl("clustering"))
}

/// Euclidean clusters of the part's points at `tolerance_mm`, as point indices.
pub(crate) fn recluster(
    points: &[Point],
    part: &[u32],
    min_size: u32,
    tolerance_mm: f64,
) -> Result<Vec<Vec<u32>>> {
    let sub: Vec<Point> = part.iter().map(|&i| points[i as usize]).collect();
    let cloud = IndexedCloud::new(&sub).map_err(pcl("re-clustering"))?;
    let groups = cloud
        .euclidean_clusters(tolerance_mm as f32, min_size, u32::MAX)
        .map_err(pcl("re-clustering"))?;
    Ok(groups
        .into_iter()
        .map(|g| g.iter().map(|&k| part[k as usize]).collect())
        .collect())
}

/// Extension, sphere search: overlapping spheres covering a big cluster (thesis 3.4.1.2), as
/// point indices. Centres are uniform keypoints of the cluster `sphere_spacing_factor` model
/// radii apart (radius = centroid to farthest point); each sphere keeps the cluster points
/// within `sphere_radius_factor` model radii. Spheres with fewer points than the smallest
/// cluster are dropped.
pub(crate) fn spheres(
    points: &[Point],
    model_radius_mm: f64,
    cfg: &PileSearchConfig,
    min_size: u32,
) -> Result<Vec<Vec<u32>>> {
    let centres =
        binpick_pcl::uniform_sampling(points, (cfg.sphere_spacing_factor * model_radius_mm) as f32)
            .map_err(pcl("sphere centres"))?;
    let index =
        NearestIndex::new("cluster", points).map_err(|e| input("cluster", e.to_string()))?;
    let mut out = Vec::new();
    for c in centres {
        let mut members: Vec<u32> = Vec::new();
        index.within_into(
            &points[c as usize],
            (cfg.sphere_radius_factor * model_radius_mm) as f32,
            &mut members,
        );
        members.sort_unstable();
        if members.len() >= min_size as usize {
            out.push(members);
        }
    }
    Ok(out)
}

/// Extension, touching parts: marks the cluster points within `outlier_distance_mm` of the
/// model placed at `pose` (the points an accepted part explains).
pub(crate) fn mark_explained(
    points: &[Point],
    model: &[Point],
    pose: &Isometry3<f64>,
    outlier_distance_mm: f64,
    explained: &mut [bool],
) -> Result<()> {
    let placed: Vec<Point> = model
        .iter()
        .map(|q| binpick_cloud::transform_point(pose, q))
        .collect();
    let index = NearestIndex::new("model", &placed).map_err(|e| input("model", e.to_string()))?;
    let limit = (outlier_distance_mm * outlier_distance_mm) as f32;
    for (e, q) in explained.iter_mut().zip(points) {
        if !*e && index.nearest(q).1 <= limit {
            *e = true;
        }
    }
    Ok(())
}
