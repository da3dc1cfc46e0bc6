//! A structured-light depth camera seen in perspective, simulated by ray casting.
//!
//! A pinhole camera at `position` looks straight down (scene -z); image columns run along
//! scene +x and rows along scene -y (camera frame: x = scene x, y = -scene y, z = -scene z, a
//! proper rotation: a half turn about x). A projector sits `projector_offset` (the baseline)
//! from the camera. A pixel gives a point where its ray first meets a surface, that spot is
//! lit by the projector (nothing on the segment between them), and neither the camera nor the
//! projector grazes the surface at more than `acos(min_incidence_cos)`: structured light
//! leaves shadows on the side of parts away from the projector.
//!
//! Depth noise is Gaussian along the pixel's ray with a standard deviation that grows with
//! the square of the depth, `noise_sigma_at_1m * (depth / 1000 mm)^2` (as for triangulation
//! with a fixed baseline); with probability `outlier_rate` the depth is instead off by
//! 2-25 mm (a wrong pattern match). The cloud is returned row by row, pixels without a
//! reading left out (an unorganised cloud).

use std::ops::Range;

use rapier3d::parry::math::Vector as PVec;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use binpick_cloud::{Aabb, PointCloud};

use crate::rng::{Rng, derive_seed};
use crate::scanner::{OUTLIER, Scan, SceneGeometry};

/// Placement, optics and noise of the depth camera. Lengths in mm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DepthCameraConfig {
    /// Optical centre of the camera, scene frame.
    pub position: [f64; 3],
    /// Image width and height, pixels.
    pub width: usize,
    pub height: usize,
    /// Focal length, pixels (square pixels, principal point at the image centre).
    pub focal_px: f64,
    /// Projector's optical centre minus the camera's, scene frame (the baseline).
    pub projector_offset: [f64; 3],
    /// Standard deviation of the depth noise at 1 m depth; it grows with depth squared.
    pub noise_sigma_at_1m: f64,
    /// Share of pixels with a wrong depth (2-25 mm off).
    pub outlier_rate: f64,
    /// Smallest cos between the surface normal and the camera or projector ray.
    pub min_incidence_cos: f64,
}

impl DepthCameraConfig {
    /// Camera frame -> scene frame rotation, as a unit quaternion (w, x, y, z): a half turn
    /// about x (looking down, image rows along scene -y).
    pub const ORIENTATION_WXYZ: [f64; 4] = [0.0, 1.0, 0.0, 0.0];

    /// Unit ray through the centre of pixel (`u`, `v`), scene frame.
    pub fn pixel_ray(&self, u: usize, v: usize) -> [f64; 3] {
        let x = (u as f64 + 0.5 - 0.5 * self.width as f64) / self.focal_px;
        let y = (v as f64 + 0.5 - 0.5 * self.height as f64) / self.focal_px;
        let n = (x * x + y * y + 1.0).sqrt();
        [x / n, -y / n, -1.0 / n]
    }

    /// Size of a pixel's footprint on a surface facing the camera at `depth`, mm.
    pub fn pixel_size_at(&self, depth: f64) -> f64 {
        depth / self.focal_px
    }

    /// Depth-noise standard deviation at `depth` (mm along the optical axis), mm.
    pub fn noise_sigma_at(&self, depth: f64) -> f64 {
        self.noise_sigma_at_1m * (depth / 1000.0).powi(2)
    }

    /// The pixel columns and rows whose rays can meet anything inside `bounds` (below the
    /// camera): the projection of the box's corners, one pixel wider on each side.
    pub fn window_for(&self, bounds: &Aabb) -> (Range<usize>, Range<usize>) {
        let mut u = (f64::INFINITY, f64::NEG_INFINITY);
        let mut v = (f64::INFINITY, f64::NEG_INFINITY);
        for k in 0..8 {
            let c = [
                if k & 1 == 0 {
                    bounds.min[0]
                } else {
                    bounds.max[0]
                },
                if k & 2 == 0 {
                    bounds.min[1]
                } else {
                    bounds.max[1]
                },
                if k & 4 == 0 {
                    bounds.min[2]
                } else {
                    bounds.max[2]
                },
            ];
            let rel = [
                f64::from(c[0]) - self.position[0],
                f64::from(c[1]) - self.position[1],
                f64::from(c[2]) - self.position[2],
            ];
            // Camera frame: (x, -y, -z); a corner at or above the camera sees everything.
            let depth = -rel[2];
            if depth <= 1e-6 {
                return (0..self.width, 0..self.height);
            }
            let pu = self.focal_px * rel[0] / depth + 0.5 * self.width as f64 - 0.5;
            let pv = self.focal_px * -rel[1] / depth + 0.5 * self.height as f64 - 0.5;
            u = (u.0.min(pu), u.1.max(pu));
            v = (v.0.min(pv), v.1.max(pv));
        }
        let range = |(lo, hi): (f64, f64), n: usize| {
            let a = (lo.floor() - 1.0).clamp(0.0, n as f64) as usize;
            let b = (hi.ceil() + 2.0).clamp(0.0, n as f64) as usize;
            a..b.max(a)
        };
        (range(u, self.width), range(v, self.height))
    }
}

/// Takes one depth image of the geometry. Rows run in parallel, each with its own random
/// stream, so the output does not depend on the number of threads.
pub fn depth_scan(geom: &SceneGeometry, cfg: &DepthCameraConfig, seed: u64) -> Scan {
    depth_scan_window(geom, cfg, seed, 0..cfg.width, 0..cfg.height)
}

/// [`depth_scan`] restricted to pixel columns `cols` and rows `rows` (same rays).
pub fn depth_scan_window(
    geom: &SceneGeometry,
    cfg: &DepthCameraConfig,
    seed: u64,
    cols: Range<usize>,
    rows: Range<usize>,
) -> Scan {
    let camera = PVec::new(
        cfg.position[0] as f32,
        cfg.position[1] as f32,
        cfg.position[2] as f32,
    );
    let projector = camera
        + PVec::new(
            cfg.projector_offset[0] as f32,
            cfg.projector_offset[1] as f32,
            cfg.projector_offset[2] as f32,
        );
    let cos_min = cfg.min_incidence_cos as f32;
    // Rays end at the floor (z = 0) at the latest; allow for tilted rays.
    let max_t = (2.0 * cfg.position[2].abs() + 1.0) as f32;
    let per_row: Vec<(Vec<[f32; 3]>, Vec<u32>)> = rows
        .into_par_iter()
        .map(|v| {
            let mut rng = Rng::new(derive_seed(seed, "depth-row", v as u64));
            let mut pts = Vec::new();
            let mut labels = Vec::new();
            for u in cols.clone() {
                let r = cfg.pixel_ray(u, v);
                let dir = PVec::new(r[0] as f32, r[1] as f32, r[2] as f32);
                let Some((t, n, owner)) = geom.first_hit(camera, dir, max_t) else {
                    continue;
                };
                let point = camera + dir * t;
                let to_projector = projector - point;
                let lit_len = to_projector.length();
                if lit_len <= 0.0 {
                    continue;
                }
                if n.dot(-dir) < cos_min || n.dot(to_projector / lit_len) < cos_min {
                    continue;
                }
                if geom.blocked(projector, point, 0.02) {
                    continue;
                }
                // Depth along the optical axis (scene -z); noise moves the point along its ray.
                let cos_axis = f64::from(-dir.z).max(1e-6);
                let depth = f64::from(t) * cos_axis;
                let (offset, label) = if cfg.outlier_rate > 0.0 && rng.chance(cfg.outlier_rate) {
                    let mag = rng.range(2.0, 25.0);
                    let sign = if rng.chance(0.5) { 1.0 } else { -1.0 };
                    (sign * mag, OUTLIER)
                } else if cfg.noise_sigma_at_1m > 0.0 {
                    (cfg.noise_sigma_at(depth) * rng.gaussian(), owner)
                } else {
                    (0.0, owner)
                };
                let p = point + dir * (offset / cos_axis) as f32;
                pts.push([p.x, p.y, p.z]);
                labels.push(label);
            }
            (pts, labels)
        })
        .collect();
    let total: usize = per_row.iter().map(|(p, _)| p.len()).sum();
    let mut out = Scan {
        cloud: PointCloud::new(Vec::with_capacity(total)),
        labels: Vec::with_capacity(total),
    };
    for (p, l) in per_row {
        out.cloud.points.extend(p);
        out.labels.extend(l);
    }
    out
}
