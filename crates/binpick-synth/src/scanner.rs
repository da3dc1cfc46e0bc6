//! The thesis's 2.5D scanner (2.2), simulated by ray casting: one camera looking straight down
//! between two line lasers placed symmetrically along the motion, sweeping along the belt.
//!
//! Geometry (scene frame: z up, belt/floor at z = 0, x across the belt, y along the motion):
//! at frame `i` the scanner head is at `y_s = y0 + i * speed / fps`; the camera (pinhole) is at
//! `(0, y_s, camera_height)`; laser 1 at `(0, y_s - laser_offset, laser_height)` and laser 2 at
//! `(0, y_s + laser_offset, laser_height)`, both fanning a plane that meets the belt on the line
//! `y = y_s`, sampled by `columns` camera columns evenly spaced across `x_range`.
//!
//! A point exists only where a laser lights the surface (first hit of the laser ray) and the
//! camera sees that very spot (nothing between it and the camera, and neither the laser nor the
//! camera grazes the surface at more than `acos(min_incidence_cos)`). Each laser is read
//! independently (its line falls on its own side of the image), so a frame gives up to two
//! points per column; where both lasers light the same spot (the belt, within half a sample
//! spacing) one point is kept. The second laser thus fills the first one's shadows: points are
//! missing only where both fail - across the belt on both sides of tall parts (the fans and the
//! camera all diverge from x = 0), next to walls and in pockets of the pile.
//!
//! The measured point is the true hit moved along the camera ray by Gaussian range noise
//! (`noise_sigma`); with probability `outlier_rate` it is instead a speckle outlier displaced
//! by 2-25 mm (either way) along the camera ray, as a wrong laser-peak detection would give.

use std::ops::Range;

use nalgebra::Isometry3;
use rapier3d::parry::math::Vector as PVec;
use rapier3d::parry::query::{Ray, RayCast};
use rapier3d::parry::shape::TriMesh;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use binpick_cloud::PointCloud;

use crate::SynthError;
use crate::mesh::Mesh;
use crate::parts::PartLibrary;
use crate::physics::{Environment, Instance};
use crate::rng::{Rng, derive_seed};

/// Frames per second of the camera (thesis 2.2: 1600 x 1200 at 28 fps).
pub const FPS: f64 = 28.0;
/// Camera columns available across the laser line.
pub const MAX_COLUMNS: usize = 1600;
/// Label of points on the belt, floor or bin walls.
pub const BACKGROUND: u32 = u32::MAX;
/// Label of speckle outliers (wrong range readings).
pub const OUTLIER: u32 = u32::MAX - 1;

/// Scanner placement, sampling and noise. Lengths in mm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScannerConfig {
    /// Height of the camera's pinhole above the belt.
    pub camera_height: f64,
    /// Distance of each laser from the camera along y.
    pub laser_offset: f64,
    /// Height of the lasers above the belt.
    pub laser_height: f64,
    /// Belt-level extent of the laser line across the belt, `[xmin, xmax]`.
    pub x_range: [f64; 2],
    /// Scanner head positions along the motion, `[ymin, ymax]`.
    pub y_range: [f64; 2],
    /// Belt (conveyor) or arm speed, mm/s.
    pub speed: f64,
    /// Camera frame rate, 1/s.
    pub fps: f64,
    /// Samples across the line (camera columns).
    pub columns: usize,
    /// Standard deviation of the range noise along the camera ray, mm.
    pub noise_sigma: f64,
    /// Share of points replaced by speckle outliers.
    pub outlier_rate: f64,
    /// Smallest |cos| between the surface normal and the laser or camera ray.
    pub min_incidence_cos: f64,
    /// Whether the second laser fills the first one's shadows.
    pub dual_laser: bool,
}

impl ScannerConfig {
    /// Distance between two scan lines, mm (speed / fps).
    pub fn line_spacing(&self) -> f64 {
        self.speed / self.fps
    }

    /// Number of frames (scan lines).
    pub fn lines(&self) -> usize {
        ((self.y_range[1] - self.y_range[0]) / self.line_spacing()).floor() as usize + 1
    }

    /// Distance between two columns at belt level, mm.
    pub fn column_spacing(&self) -> f64 {
        (self.x_range[1] - self.x_range[0]) / self.columns as f64
    }

    /// Samples of the belt-level grid (lines x columns): about the number of points of a scene
    /// (shadows remove some, surfaces lit by both lasers add some).
    pub fn grid_points(&self) -> usize {
        self.lines() * self.columns
    }

    /// Sets `columns` so that lines x columns is about `points_target` (within the camera's
    /// 64..=1600 columns).
    pub fn with_points_target(mut self, points_target: usize) -> Self {
        self.columns = (points_target / self.lines().max(1)).clamp(64, MAX_COLUMNS);
        self
    }

    /// Conveyor layout (2.2.1): the head is fixed 400 mm above the belt, lasers 160 mm either
    /// side (22 deg triangulation), 260 mm of belt across and 260 mm along; `speed` 10-30 mm/s.
    pub fn conveyor(speed: f64, noise_sigma: f64, points_target: usize) -> Self {
        Self {
            camera_height: 400.0,
            laser_offset: 160.0,
            laser_height: 400.0,
            x_range: [-130.0, 130.0],
            y_range: [-130.0, 130.0],
            speed,
            fps: FPS,
            columns: 1000,
            noise_sigma,
            outlier_rate: 0.001,
            min_incidence_cos: 0.1,
            dual_laser: true,
        }
        .with_points_target(points_target)
    }

    /// Robot-arm layout (2.2.2): the head moves 600 mm above the floor, lasers 220 mm either
    /// side (20 deg), covering 400 x 400 mm; `speed` 30-60 mm/s.
    pub fn arm(speed: f64, noise_sigma: f64, points_target: usize) -> Self {
        Self {
            camera_height: 600.0,
            laser_offset: 220.0,
            laser_height: 600.0,
            x_range: [-200.0, 200.0],
            y_range: [-200.0, 200.0],
            speed,
            fps: FPS,
            columns: 1000,
            noise_sigma,
            outlier_rate: 0.003,
            min_incidence_cos: 0.1,
            dual_laser: true,
        }
        .with_points_target(points_target)
    }

    /// The noise-free, outlier-free, fine (0.5 x 0.5 mm) conveyor scan used to build models.
    pub fn model_scan() -> Self {
        let mut c = Self::conveyor(0.5 * FPS, 0.0, 0);
        c.outlier_rate = 0.0;
        c.x_range = [-100.0, 100.0];
        c.y_range = [-100.0, 100.0];
        c.columns = 400;
        c
    }
}

/// A scanned scene: the cloud and, for each point, the index of the instance whose surface it
/// lies on ([`BACKGROUND`] for belt/floor/walls, [`OUTLIER`] for speckle).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scan {
    pub cloud: PointCloud,
    pub labels: Vec<u32>,
}

/// Everything the rays can hit: the floor / belt as an exact plane rectangle, and the walls and
/// parts merged into one BVH-accelerated triangle mesh, with the owner of every triangle and
/// each object's bounding box (rays that miss every box skip the BVH).
pub struct SceneGeometry {
    /// Half extents of the floor rectangle (z = 0, centred on the origin), if any.
    floor: Option<[f32; 2]>,
    mesh: Option<TriMesh>,
    owner: Vec<u32>,
    boxes: Vec<([f32; 3], [f32; 3])>,
}

/// Whether the segment `origin + t * dir`, t in [0, max_t], meets the box.
fn ray_meets_box(origin: PVec, inv_dir: PVec, max_t: f32, b: &([f32; 3], [f32; 3])) -> bool {
    let mut t0 = 0.0f32;
    let mut t1 = max_t;
    for k in 0..3 {
        let (o, inv) = (origin[k], inv_dir[k]);
        let (mut a, mut c) = ((b.0[k] - o) * inv, (b.1[k] - o) * inv);
        if a > c {
            std::mem::swap(&mut a, &mut c);
        }
        // NaN (0 * inf, ray in the slab's plane) keeps the current bounds.
        if a > t0 {
            t0 = a;
        }
        if c < t1 {
            t1 = c;
        }
        if t0 > t1 {
            return false;
        }
    }
    true
}

impl SceneGeometry {
    /// A floor rectangle of `floor_size` (x, y) at z = 0 (labelled background), other static
    /// meshes (background, e.g. walls) and instances (labelled by their index).
    pub fn new(
        floor_size: Option<[f64; 2]>,
        static_meshes: &[Mesh],
        instances: &[(&Mesh, Isometry3<f64>)],
    ) -> Result<Self, SynthError> {
        let mut all = Mesh::default();
        let mut owner = Vec::new();
        let mut boxes = Vec::new();
        let mut add = |m: &Mesh, label: u32| {
            if let Some(b) = m.bounds() {
                let pad = 0.01;
                boxes.push((
                    [b.min[0] - pad, b.min[1] - pad, b.min[2] - pad],
                    [b.max[0] + pad, b.max[1] + pad, b.max[2] + pad],
                ));
            }
            all.append(m);
            owner.extend(std::iter::repeat_n(label, m.triangles.len()));
        };
        for m in static_meshes {
            add(m, BACKGROUND);
        }
        for (i, (m, pose)) in instances.iter().enumerate() {
            add(&m.transformed(pose), i as u32);
        }
        let mesh = if all.triangles.is_empty() {
            None
        } else {
            Some(all.to_parry()?)
        };
        Ok(Self {
            floor: floor_size.map(|s| [(0.5 * s[0]) as f32, (0.5 * s[1]) as f32]),
            mesh,
            owner,
            boxes,
        })
    }

    /// An environment with parts at their poses (instance index = index in `instances`).
    pub fn from_scene(
        env: &Environment,
        instances: &[Instance],
        lib: &PartLibrary,
    ) -> Result<Self, SynthError> {
        let placed: Vec<(&Mesh, Isometry3<f64>)> = instances
            .iter()
            .map(|i| (&lib.get(i.kind).mesh, i.pose))
            .collect();
        Self::new(Some(env.floor_size()), &env.wall_meshes(), &placed)
    }

    fn may_hit(&self, origin: PVec, dir: PVec, max_t: f32) -> bool {
        let inv = PVec::new(1.0 / dir.x, 1.0 / dir.y, 1.0 / dir.z);
        self.boxes
            .iter()
            .any(|b| ray_meets_box(origin, inv, max_t, b))
    }

    /// First hit along `origin + t * dir` (`dir` unit), t in (0, max_t]: (t, unit normal facing
    /// the ray, owner).
    pub(crate) fn first_hit(
        &self,
        origin: PVec,
        dir: PVec,
        max_t: f32,
    ) -> Option<(f32, PVec, u32)> {
        let t_floor = match self.floor {
            Some(_) if dir.z < 0.0 && origin.z > 0.0 => -origin.z / dir.z,
            _ => f32::INFINITY,
        };
        let limit = max_t.min(t_floor);
        if let Some(mesh) = &self.mesh
            && self.may_hit(origin, dir, limit)
            && let Some(hit) =
                mesh.cast_local_ray_and_get_normal(&Ray::new(origin, dir), limit, true)
        {
            let owner = *self.owner.get(hit.subshape as usize)?;
            return Some((hit.time_of_impact, hit.normal, owner));
        }
        let [hx, hy] = self.floor?;
        if t_floor > max_t {
            return None;
        }
        let p = origin + dir * t_floor;
        (p.x.abs() <= hx && p.y.abs() <= hy).then_some((t_floor, PVec::Z, BACKGROUND))
    }

    /// Whether anything lies on the open segment from `from` to `to` (ends excluded by
    /// `margin` mm). The floor never blocks (rays end above or on it).
    pub(crate) fn blocked(&self, from: PVec, to: PVec, margin: f32) -> bool {
        let d = to - from;
        let len = d.length();
        if len <= margin {
            return false;
        }
        let dir = d / len;
        let Some(mesh) = &self.mesh else {
            return false;
        };
        self.may_hit(from, dir, len - margin)
            && mesh
                .cast_local_ray(&Ray::new(from, dir), len - margin, true)
                .is_some()
    }
}

/// One measured sample: true surface point, owner, unit camera ray direction.
struct Measurement {
    point: PVec,
    owner: u32,
    view: PVec,
}

fn measure(
    geom: &SceneGeometry,
    cfg: &ScannerConfig,
    laser: PVec,
    target: PVec,
    camera: PVec,
) -> Option<Measurement> {
    let dir = target - laser;
    let dir_len = dir.length();
    let dir = dir / dir_len;
    // The belt is at t = dir_len; allow a little beyond (the floor may be slightly lower).
    let (t, n, owner) = geom.first_hit(laser, dir, dir_len * 1.5)?;
    let point = laser + dir * t;
    let to_cam = camera - point;
    let cam_dist = to_cam.length();
    let to_cam_u = to_cam / cam_dist;
    let cos_min = cfg.min_incidence_cos as f32;
    // n faces the laser; the camera must be on the same side and neither may graze.
    let cos_cam = n.dot(to_cam_u);
    if n.dot(-dir) < cos_min || cos_cam < cos_min {
        return None;
    }
    if geom.blocked(camera, point, 0.02) {
        return None;
    }
    Some(Measurement {
        point,
        owner,
        view: -to_cam_u,
    })
}

/// Scans the geometry. Deterministic in `seed`; lines are processed in parallel with one
/// random stream per line, so the output does not depend on the number of threads.
pub fn scan(geom: &SceneGeometry, cfg: &ScannerConfig, seed: u64) -> Scan {
    scan_window(geom, cfg, seed, 0..cfg.lines(), 0..cfg.columns.max(1))
}

impl ScannerConfig {
    /// The scan lines and columns whose rays can meet anything inside `bounds` (scene frame,
    /// mm, above the belt): a sub-grid of the full scan, for scanning one part alone quickly.
    pub fn window_for(&self, bounds: &binpick_cloud::Aabb) -> (Range<usize>, Range<usize>) {
        let (lo, hi) = (bounds.min.map(f64::from), bounds.max.map(f64::from));
        let top = hi[2].max(0.0);
        // A laser at y_s -/+ laser_offset reaches height z at y_s -/+ offset * z / height;
        // its fan spreads from x = 0, so a target column x_t reaches height z at
        // x_t * (1 - z / height).
        let along = self.laser_offset * top / self.laser_height + self.line_spacing();
        let (y_lo, y_hi) = (lo[1] - along, hi[1] + along);
        let spread = 1.0 / (1.0 - top / self.laser_height).max(1e-3);
        let x_lo = lo[0].min(lo[0] * spread) - self.column_spacing();
        let x_hi = hi[0].max(hi[0] * spread) + self.column_spacing();
        let dy = self.line_spacing();
        let dx = self.column_spacing();
        let index = |v: f64, origin: f64, step: f64, n: usize| -> usize {
            ((v - origin) / step).floor().clamp(0.0, n as f64) as usize
        };
        let lines = self.lines();
        let cols = self.columns.max(1);
        let l0 = index(y_lo, self.y_range[0], dy, lines);
        let l1 = (index(y_hi, self.y_range[0], dy, lines) + 2).min(lines);
        let c0 = index(x_lo, self.x_range[0], dx, cols);
        let c1 = (index(x_hi, self.x_range[0], dx, cols) + 2).min(cols);
        (l0..l1.max(l0), c0..c1.max(c0))
    }
}

/// [`scan`] restricted to scan lines `lines` and camera columns `columns` of the full grid
/// (same sample positions; each line keeps its own random stream, drawn from the window's
/// first column on).
pub fn scan_window(
    geom: &SceneGeometry,
    cfg: &ScannerConfig,
    seed: u64,
    lines: Range<usize>,
    columns: Range<usize>,
) -> Scan {
    let dy = cfg.line_spacing();
    let cols = columns.len();
    let dx = cfg.column_spacing();
    let dedup = (0.5 * dy.min(dx)) as f32;
    let per_line: Vec<(Vec<[f32; 3]>, Vec<u32>)> = lines
        .into_par_iter()
        .map(|i| {
            let mut rng = Rng::new(derive_seed(seed, "scan-line", i as u64));
            let ys = cfg.y_range[0] + i as f64 * dy;
            let camera = PVec::new(0.0, ys as f32, cfg.camera_height as f32);
            let laser1 = PVec::new(0.0, (ys - cfg.laser_offset) as f32, cfg.laser_height as f32);
            let laser2 = PVec::new(0.0, (ys + cfg.laser_offset) as f32, cfg.laser_height as f32);
            let mut pts = Vec::with_capacity(cols);
            let mut labels = Vec::with_capacity(cols);
            for j in columns.clone() {
                let x = cfg.x_range[0] + (j as f64 + 0.5) * dx;
                let target = PVec::new(x as f32, ys as f32, 0.0);
                let m1 = measure(geom, cfg, laser1, target, camera);
                let m2 = if cfg.dual_laser {
                    measure(geom, cfg, laser2, target, camera)
                } else {
                    None
                };
                // Both lasers lit the same spot (the belt, or low surfaces): one reading.
                let m2 = m2.filter(|b| {
                    m1.as_ref()
                        .is_none_or(|a| (a.point - b.point).length() > dedup)
                });
                for m in [m1, m2].into_iter().flatten() {
                    let (offset, label) = if cfg.outlier_rate > 0.0 && rng.chance(cfg.outlier_rate)
                    {
                        let mag = rng.range(2.0, 25.0);
                        let sign = if rng.chance(0.5) { 1.0 } else { -1.0 };
                        (sign * mag, OUTLIER)
                    } else if cfg.noise_sigma > 0.0 {
                        (cfg.noise_sigma * rng.gaussian(), m.owner)
                    } else {
                        (0.0, m.owner)
                    };
                    let p = m.point + m.view * offset as f32;
                    pts.push([p.x, p.y, p.z]);
                    labels.push(label);
                }
            }
            (pts, labels)
        })
        .collect();
    let total: usize = per_line.iter().map(|(p, _)| p.len()).sum();
    let mut out = Scan {
        cloud: PointCloud::new(Vec::with_capacity(total)),
        labels: Vec::with_capacity(total),
    };
    for (p, l) in per_line {
        out.cloud.points.extend(p);
        out.labels.extend(l);
    }
    out
}

/// Convenience: scan an environment with parts at their poses.
pub fn scan_scene(
    env: &Environment,
    instances: &[Instance],
    lib: &PartLibrary,
    cfg: &ScannerConfig,
    seed: u64,
) -> Result<Scan, SynthError> {
    let geom = SceneGeometry::from_scene(env, instances, lib)?;
    Ok(scan(&geom, cfg, seed))
}
