//! The labelled PLY: scene points coloured by the detection that explains them, plus the
//! aligned models' points, in one binary PLY.

use std::collections::HashMap;
use std::path::Path;

use binpick_cloud::PointCloud;
use binpick_cloud::io::{PlyEncoding, write_ply};
use nalgebra::Point3;

use crate::color::{rank_color, shade};
use crate::{Placed, VizError, finite_pose, finite3};

/// Grey of scene points that no detection explains.
pub const UNEXPLAINED_GREY: [u8; 3] = [150, 150, 150];

/// Model points are written in their detection's colour darkened by this factor, so in a
/// viewer they can be told from the scene points they explain (which get the pure colour).
pub const MODEL_SHADE: f64 = 0.6;

/// What [`write_labelled_ply`] wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlyInfo {
    /// Finite scene points written (first in the file, in scene order).
    pub scene_points: usize,
    /// Scene points skipped for a NaN/infinite coordinate.
    pub scene_non_finite: usize,
    /// Model points written (after the scene: all of detection 0's, then 1's, ...).
    pub model_points: usize,
    /// Per entry of `placed`: how many scene points it explains (its model has the nearest
    /// point within the distance). Skipped detections explain none.
    pub explained: Vec<usize>,
    /// Scene points no detection explains (written grey).
    pub unexplained: usize,
    /// Indices into `placed` not written (non-finite pose).
    pub detections_skipped: Vec<usize>,
}

/// The coloured cloud [`write_labelled_ply`] writes, without writing it: points, one colour
/// per point, and the counts.
///
/// Each finite scene point gets the colour ([`rank_color`]) of the detection whose placed model
/// has the nearest point to it, if that point is within `explain_distance_mm`, else
/// [`UNEXPLAINED_GREY`]. Then every placed model's finite points follow, in their detection's
/// colour darkened by [`MODEL_SHADE`]. Ties go to the earlier entry of `placed`.
pub fn labelled_cloud(
    scene: &PointCloud,
    model: &PointCloud,
    placed: &[Placed],
    explain_distance_mm: f64,
) -> Result<(PointCloud, Vec<[u8; 3]>, PlyInfo), VizError> {
    if !(explain_distance_mm.is_finite() && explain_distance_mm > 0.0) {
        return Err(VizError::InvalidOption(format!(
            "explain_distance_mm must be finite and > 0, got {explain_distance_mm}"
        )));
    }
    let scene_pts: Vec<[f32; 3]> = scene.points.iter().copied().filter(finite3).collect();
    let scene_non_finite = scene.points.len() - scene_pts.len();
    if scene_pts.is_empty() {
        return Err(VizError::EmptyScene {
            non_finite: scene_non_finite,
        });
    }
    let model_pts: Vec<[f32; 3]> = model.points.iter().copied().filter(finite3).collect();
    if !placed.is_empty() && model_pts.is_empty() {
        return Err(VizError::EmptyModel {
            non_finite: model.points.len(),
        });
    }

    // Placed model points, with their detection index, hashed into cubes of the explain
    // distance so a query looks at 27 cells.
    let cell = explain_distance_mm;
    let key = |p: [f64; 3]| {
        [
            (p[0] / cell).floor() as i64,
            (p[1] / cell).floor() as i64,
            (p[2] / cell).floor() as i64,
        ]
    };
    let mut placed_pts: Vec<([f64; 3], usize)> = Vec::new();
    let mut skipped = Vec::new();
    for (i, p) in placed.iter().enumerate() {
        if !finite_pose(&p.pose) {
            skipped.push(i);
            continue;
        }
        for m in &model_pts {
            let q = p.pose * Point3::new(f64::from(m[0]), f64::from(m[1]), f64::from(m[2]));
            placed_pts.push(([q.x, q.y, q.z], i));
        }
    }
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (j, (p, _)) in placed_pts.iter().enumerate() {
        grid.entry(key(*p)).or_default().push(j as u32);
    }

    let mut explained = vec![0usize; placed.len()];
    let mut unexplained = 0;
    let mut points = Vec::with_capacity(scene_pts.len() + placed_pts.len());
    let mut colors = Vec::with_capacity(scene_pts.len() + placed_pts.len());
    let r2 = explain_distance_mm * explain_distance_mm;
    for s in &scene_pts {
        let p = [f64::from(s[0]), f64::from(s[1]), f64::from(s[2])];
        let k = key(p);
        let mut best: Option<(f64, usize)> = None;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let Some(list) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) else {
                        continue;
                    };
                    for &j in list {
                        let (q, det) = placed_pts[j as usize];
                        let d2 =
                            (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2);
                        if d2 > r2 {
                            continue;
                        }
                        let better = match best {
                            None => true,
                            Some((bd, bdet)) => d2 < bd || (d2 == bd && det < bdet),
                        };
                        if better {
                            best = Some((d2, det));
                        }
                    }
                }
            }
        }
        points.push(*s);
        match best {
            Some((_, det)) => {
                explained[det] += 1;
                colors.push(rank_color(placed[det].rank));
            }
            None => {
                unexplained += 1;
                colors.push(UNEXPLAINED_GREY);
            }
        }
    }
    for (q, det) in &placed_pts {
        points.push([q[0] as f32, q[1] as f32, q[2] as f32]);
        colors.push(shade(rank_color(placed[*det].rank), MODEL_SHADE));
    }
    let info = PlyInfo {
        scene_points: scene_pts.len(),
        scene_non_finite,
        model_points: placed_pts.len(),
        explained,
        unexplained,
        detections_skipped: skipped,
    };
    Ok((PointCloud::new(points), colors, info))
}

/// Writes one binary (little-endian) PLY with the scene coloured by which detection explains
/// each point and the aligned models' points in their colours; see [`labelled_cloud`] for the
/// colouring. Returns the counts, including the explained points per detection.
pub fn write_labelled_ply(
    scene: &PointCloud,
    model: &PointCloud,
    placed: &[Placed],
    explain_distance_mm: f64,
    out: &Path,
) -> Result<PlyInfo, VizError> {
    let (cloud, colors, info) = labelled_cloud(scene, model, placed, explain_distance_mm)?;
    write_ply(out, &cloud, PlyEncoding::BinaryLittleEndian, Some(&colors))?;
    Ok(info)
}
