//! Synthetic scenes with known poses for the pipeline tests (all mm).
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use binpick::PointCloud;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// Deterministic xorshift.
pub struct Rng(pub u64);
impl Rng {
    pub fn unit(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Approximately normal (sum of uniforms), mean 0, std `sigma`.
    pub fn gauss(&mut self, sigma: f64) -> f64 {
        (0..12).map(|_| self.unit()).sum::<f64>() * sigma - 6.0 * sigma
    }
}

/// Top view of an asymmetric bent sheet (like thesis object A): a 60 x 70 mm base with a
/// notch, bent up by 50 deg into a 55 x 70 mm leg with an off-centre hole. Model frame:
/// base on z = 0, spacing `step`.
pub fn bent_sheet(step: f64) -> Vec<[f64; 3]> {
    bent_sheet_sampled(step, None)
}

/// The sheet sampled on a grid of `step`, each sample moved by a random offset of up to half
/// a step along the surface when `jitter` is given: like a scanner, the samples do not follow
/// the part's own lattice (which would let ICP lock onto the model's identical lattice).
pub fn bent_sheet_sampled(step: f64, mut jitter: Option<&mut Rng>) -> Vec<[f64; 3]> {
    let mut jit = move || jitter.as_mut().map_or(0.0, |r| (r.unit() - 0.5) * step);
    let mut pts = Vec::new();
    let n = |len: f64| (len / step).round() as usize;
    let (c, s) = (50f64.to_radians().cos(), 50f64.to_radians().sin());
    for i in 0..=n(60.0) {
        for j in 0..=n(70.0) {
            let (x, y) = (
                (i as f64 * step + jit()).clamp(0.0, 60.0),
                (j as f64 * step + jit()).clamp(0.0, 70.0),
            );
            if x < 18.0 && y < 22.0 {
                continue; // notch
            }
            pts.push([x, y, 0.0]);
        }
    }
    for i in 1..=n(55.0) {
        for j in 0..=n(70.0) {
            let (u, y) = (
                (i as f64 * step + jit()).clamp(0.0, 55.0),
                (j as f64 * step + jit()).clamp(0.0, 70.0),
            );
            if (u - 30.0).powi(2) + (y - 50.0).powi(2) < 64.0 {
                continue; // hole
            }
            pts.push([60.0 + u * c, y, u * s]);
        }
    }
    pts
}

pub fn to_cloud(pts: &[[f64; 3]]) -> PointCloud {
    PointCloud::new(
        pts.iter()
            .map(|p| [p[0] as f32, p[1] as f32, p[2] as f32])
            .collect(),
    )
}

pub fn pose(yaw_deg: f64, x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
    )
}

pub fn place(pose: &Isometry3<f64>, pts: &[[f64; 3]]) -> Vec<[f64; 3]> {
    pts.iter()
        .map(|p| {
            let q = pose * Point3::new(p[0], p[1], p[2]);
            [q.x, q.y, q.z]
        })
        .collect()
}

pub struct SceneSpec {
    pub poses: Vec<Isometry3<f64>>,
    /// Per instance: radius (mm) of a disc-shaped object lying on the part's base, centred at
    /// model (30, 45): the part's points under it are hidden and the occluder's top surface
    /// (6 mm above the base) is added. 0 = not occluded.
    pub occluder_radius: Vec<f64>,
    pub floor: bool,
    pub noise_sigma: f64,
    pub seed: u64,
}

/// Builds the scene: a floor (z = 0, 0.7 mm grid over the parts' area) and each instance
/// sampled at 0.5 mm, lifted 2 mm (sheet thickness) above the floor, with Gaussian noise.
pub fn scene(spec: &SceneSpec) -> PointCloud {
    let mut rng = Rng(spec.seed);
    let mut pts: Vec<[f64; 3]> = Vec::new();
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for (k, pose) in spec.poses.iter().enumerate() {
        let dense = bent_sheet_sampled(0.5, Some(&mut rng));
        let placed = place(pose, &dense);
        let r = spec.occluder_radius.get(k).copied().unwrap_or(0.0);
        let covered =
            |m: &[f64; 3]| (m[0] - 30.0).powi(2) + (m[1] - 45.0).powi(2) < r * r && m[2] == 0.0;
        for (q, m) in placed.iter().zip(&dense) {
            if covered(m) {
                continue;
            }
            lo = [lo[0].min(q[0]), lo[1].min(q[1])];
            hi = [hi[0].max(q[0]), hi[1].max(q[1])];
            pts.push([q[0], q[1], q[2] + 2.0]);
        }
        if r > 0.0 {
            let mut disc = Vec::new();
            let steps = (2.0 * r / 0.5) as i64;
            for i in -steps / 2..=steps / 2 {
                for j in -steps / 2..=steps / 2 {
                    let (x, y) = (i as f64 * 0.5, j as f64 * 0.5);
                    if x * x + y * y < r * r {
                        disc.push([30.0 + x, 45.0 + y, 8.0]);
                    }
                }
            }
            pts.extend(place(pose, &disc));
        }
    }
    if spec.floor {
        let (x0, y0, x1, y1) = (lo[0] - 40.0, lo[1] - 40.0, hi[0] + 40.0, hi[1] + 40.0);
        let mut x = x0;
        while x <= x1 {
            let mut y = y0;
            while y <= y1 {
                pts.push([x, y, 0.0]);
                y += 0.7;
            }
            x += 0.7;
        }
    }
    for p in &mut pts {
        p[2] += rng.gauss(spec.noise_sigma);
    }
    to_cloud(&pts)
}

/// The model: the same sheet sampled at 0.5 mm, noise-free, model frame.
pub fn model() -> PointCloud {
    to_cloud(&bent_sheet(0.5))
}

/// Ground-truth pose of instance `pose` in the scene (the 2 mm lift included).
pub fn truth(pose: &Isometry3<f64>) -> Isometry3<f64> {
    Translation3::new(0.0, 0.0, 2.0) * pose
}

/// Mean distance, mm, between the model's points placed by `a` and by `b` (the ADD metric).
pub fn mean_point_distance(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    let pts = bent_sheet(4.0);
    pts.iter()
        .map(|p| {
            let p = Point3::new(p[0], p[1], p[2]);
            (a * p - b * p).norm()
        })
        .sum::<f64>()
        / pts.len() as f64
}

/// Centroid of the model's points, model frame.
pub fn centroid() -> Point3<f64> {
    let pts = bent_sheet(1.0);
    let n = pts.len() as f64;
    let s = pts
        .iter()
        .fold([0.0; 3], |a, p| [a[0] + p[0], a[1] + p[1], a[2] + p[2]]);
    Point3::new(s[0] / n, s[1] / n, s[2] / n)
}
