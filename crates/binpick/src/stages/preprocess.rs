//! Stage 1, preprocessing: the units check, region of interest, resolution voxel grid (thesis
//! 4.3 #1) and removal of the supporting surface (5.2), each step reporting how many points it
//! removed.

use binpick_cloud::{Point, PointCloud};

use crate::error::{Result, input, pcl};
use crate::params::{PreprocessConfig, SupportRemoval};
use crate::result::{PreprocessReport, RemovedPlane};

/// Refuses empty clouds, non-finite points and extents that mean the cloud is not in mm
/// (both engines word it the same).
pub(crate) fn check_units(
    what: &'static str,
    cloud: &PointCloud,
    cfg: &PreprocessConfig,
) -> Result<()> {
    if cloud.is_empty() {
        return Err(input(what, "the cloud is empty"));
    }
    if let Some(i) = cloud.first_non_finite() {
        return Err(input(
            what,
            format!("point {i} has a non-finite coordinate"),
        ));
    }
    let extent = cloud
        .bounds()
        .map(|b| f64::from(b.diagonal()))
        .unwrap_or(0.0);
    let min = cfg.min_extent_resolutions * cfg.resolution();
    if extent < min {
        return Err(input(
            what,
            format!(
                "its extent is {extent:.4} mm, smaller than {} x the {} mm resolution: \
                 the cloud looks like it is in metres (binpick works in millimetres; use --units m or units = \"m\")",
                cfg.min_extent_resolutions,
                cfg.resolution()
            ),
        ));
    }
    if extent > cfg.max_extent_mm {
        return Err(input(
            what,
            format!(
                "its extent is {extent:.0} mm (> {} m): wrong units? binpick expects millimetres",
                cfg.max_extent_mm / 1000.0
            ),
        ));
    }
    Ok(())
}

/// Crops, voxelises (thesis 4.3 #1) and strips support planes. `model_points` (voxelised
/// model size) sets the smallest plane that counts as support; support patches are connected
/// at the clustering tolerance `tolerance_mm`; `threads` split the plane fits' inlier counts
/// (the result does not depend on them).
pub(crate) fn preprocess(
    scene: &PointCloud,
    cfg: &PreprocessConfig,
    tolerance_mm: f64,
    model_points: usize,
    threads: usize,
) -> Result<(Vec<Point>, PreprocessReport)> {
    let (points, support, report) =
        preprocess_keeping_support(scene, cfg, tolerance_mm, model_points, threads)?;
    let world = points
        .into_iter()
        .zip(support)
        .filter_map(|(p, s)| (!s).then_some(p))
        .collect();
    Ok((world, report))
}

/// Like [`preprocess`], but keeps the support: every voxelised point, with a flag per point
/// that says whether it was removed as support (belt, floor, wall). The scene-voting engine
/// needs the support to know what the sensor saw behind the parts.
pub(crate) fn preprocess_keeping_support(
    scene: &PointCloud,
    cfg: &PreprocessConfig,
    tolerance_mm: f64,
    model_points: usize,
    threads: usize,
) -> Result<(Vec<Point>, Vec<bool>, PreprocessReport)> {
    let mut report = PreprocessReport {
        input_points: scene.len(),
        ..Default::default()
    };
    if scene.is_empty() {
        return Err(input("scene", "the cloud is empty"));
    }
    if let Some(i) = scene.first_non_finite() {
        return Err(input(
            "scene",
            format!("point {i} has a non-finite coordinate"),
        ));
    }
    let cropped: Vec<Point> = match &cfg.region_of_interest {
        None => scene.points.clone(),
        Some(roi) => scene
            .points
            .iter()
            .filter(|p| {
                (0..3).all(|k| f64::from(p[k]) >= roi.min_mm[k] && f64::from(p[k]) <= roi.max_mm[k])
            })
            .copied()
            .collect(),
    };
    report.outside_roi = scene.len() - cropped.len();
    if cropped.is_empty() {
        return Err(input(
            "scene",
            "no point lies inside the region of interest",
        ));
    }
    let points = binpick_pcl::voxel_grid(&cropped, cfg.resolution() as f32)
        .map_err(pcl("scene voxel grid"))?;
    report.voxel_merged = cropped.len() - points.len();

    let support = if cfg.support.enabled {
        find_support(
            &points,
            &cfg.support,
            cfg.resolution(),
            tolerance_mm,
            model_points,
            threads,
            &mut report,
        )?
    } else {
        vec![false; points.len()]
    };
    report.remaining = support.iter().filter(|s| !**s).count();
    Ok((points, support, report))
}

/// Removes supporting planes. A RANSAC plane is support only where its inliers form a
/// connected patch larger than any part could (`min_points_factor` x model size): the belt is
/// one connected surface around the parts' shadows, while the flat faces of parts lying on
/// it are coplanar but disconnected patches and must stay. A plane with no such patch is
/// excluded from later fits (so a bin wall can still be found after it) but kept in the
/// scene.
fn find_support(
    points: &[Point],
    support: &SupportRemoval,
    resolution_mm: f64,
    tolerance: f64,
    model_points: usize,
    threads: usize,
    report: &mut PreprocessReport,
) -> Result<Vec<bool>> {
    let min_patch = (support.min_points_factor * model_points as f64)
        .ceil()
        .max(3.0) as usize;
    let mut removed = vec![false; points.len()];
    // Indices still eligible for a plane fit.
    let mut candidates: Vec<u32> = (0..points.len() as u32).collect();
    for _ in 0..support.max_planes {
        if candidates.len() < min_patch {
            break;
        }
        let cand_pts: Vec<Point> = candidates.iter().map(|&i| points[i as usize]).collect();
        let Some(plane) = binpick_pcl::segment_plane(
            &cand_pts,
            support.distance(resolution_mm) as f32,
            support.ransac_iterations,
            threads as u32,
        )
        .map_err(pcl("support plane fit"))?
        else {
            break;
        };
        if plane.inliers.len() < min_patch {
            break;
        }
        let inlier_pts: Vec<Point> = plane
            .inliers
            .iter()
            .map(|&i| cand_pts[i as usize])
            .collect();
        let mut taken = 0;
        for (k, big) in large_patches(&inlier_pts, plane.coefficients, tolerance, min_patch)
            .into_iter()
            .enumerate()
        {
            if big {
                removed[candidates[plane.inliers[k] as usize] as usize] = true;
                taken += 1;
            }
        }
        if taken > 0 {
            report.support_planes.push(RemovedPlane {
                coefficients: plane.coefficients,
                points: taken,
            });
        }
        let mut is_inlier = vec![false; candidates.len()];
        for &i in &plane.inliers {
            is_inlier[i as usize] = true;
        }
        let mut k = 0;
        candidates.retain(|_| {
            k += 1;
            !is_inlier[k - 1]
        });
    }
    Ok(removed)
}

/// For points on a plane, whether each belongs to a connected patch of at least `min_points`.
/// Connectivity is judged on a 2-D grid in the plane (cells of `cell_mm`, 8-neighbours), a
/// linear-time stand-in for Euclidean clustering that is fast enough for a 300k-point belt.
fn large_patches(points: &[Point], plane: [f32; 4], cell_mm: f64, min_points: usize) -> Vec<bool> {
    use std::collections::HashMap;
    let n = nalgebra::Vector3::new(
        f64::from(plane[0]),
        f64::from(plane[1]),
        f64::from(plane[2]),
    )
    .normalize();
    let helper = if n.x.abs() < 0.9 {
        nalgebra::Vector3::x()
    } else {
        nalgebra::Vector3::y()
    };
    let u = n.cross(&helper).normalize();
    let v = n.cross(&u);
    let cell_of = |p: &Point| {
        let q = nalgebra::Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        (
            (q.dot(&u) / cell_mm).floor() as i64,
            (q.dot(&v) / cell_mm).floor() as i64,
        )
    };
    let cells: Vec<(i64, i64)> = points.iter().map(cell_of).collect();
    let mut id: HashMap<(i64, i64), usize> = HashMap::new();
    let mut count: Vec<usize> = Vec::new();
    for c in &cells {
        let next = id.len();
        let k = *id.entry(*c).or_insert(next);
        if k == count.len() {
            count.push(0);
        }
        count[k] += 1;
    }
    // Union-find over occupied cells.
    let mut parent: Vec<usize> = (0..id.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for (&(a, b), &k) in &id {
        for (da, db) in [(1, -1), (1, 0), (1, 1), (0, 1)] {
            if let Some(&j) = id.get(&(a + da, b + db)) {
                let (ra, rb) = (root(&mut parent, k), root(&mut parent, j));
                if ra != rb {
                    parent[ra.max(rb)] = ra.min(rb);
                }
            }
        }
    }
    let mut size = vec![0usize; parent.len()];
    for (k, &c) in count.iter().enumerate() {
        let r = root(&mut parent, k);
        size[r] += c;
    }
    cells
        .iter()
        .map(|c| {
            let r = root(&mut parent, id[c]);
            size[r] >= min_points
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patches_split_by_gaps_and_sized() {
        // Two 10 x 10 grids at 1 mm, 5 mm apart, and one 3 x 3 grid far away, all on z = 0.
        let mut pts = Vec::new();
        for (ox, n) in [(0.0, 10), (14.0, 10), (100.0, 3)] {
            for i in 0..n {
                for j in 0..n {
                    pts.push([ox + i as f32, j as f32, 0.0]);
                }
            }
        }
        let big = large_patches(&pts, [0.0, 0.0, 1.0, 0.0], 1.5, 50);
        assert!(big[..200].iter().all(|&b| b), "two 100-point patches");
        assert!(big[200..].iter().all(|&b| !b), "9-point patch is small");
        // With a 60-point minimum... still both 100-point patches; with 150, none.
        assert!(
            large_patches(&pts, [0.0, 0.0, 1.0, 0.0], 1.5, 150)
                .iter()
                .all(|&b| !b)
        );
        // Joined by a bridge, the two become one 200+ patch.
        for x in 10..14 {
            pts.push([x as f32, 5.0, 0.0]);
        }
        let big = large_patches(&pts, [0.0, 0.0, 1.0, 0.0], 1.5, 150);
        assert!(big[..200].iter().all(|&b| b));
    }
}
