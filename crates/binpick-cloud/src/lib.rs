//! Point clouds for binpick: the [`PointCloud`] type (millimetres unless stated otherwise),
//! unit handling, PCD/PLY reading and writing and STL/OBJ/PLY mesh reading ([`io`]),
//! triangle meshes and their surface sampling ([`mesh`]), depth images to organised clouds
//! ([`depth`]) and the labelled dataset format ([`dataset`]).
//!
//! Everything here is pure Rust and independent of PCL, so the synthetic-data generator and
//! the I/O tests build without the C++ toolchain.

pub mod dataset;
mod degeneracy;
pub mod depth;
pub mod io;
pub mod mesh;
pub mod rng;

pub use degeneracy::{COLLINEAR_TOLERANCE, Degeneracy};
pub use mesh::{SampleError, SurfaceSamples, SurfaceSampling, TriangleMesh};

use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

/// One point, `[x, y, z]`, in the cloud's units (millimetres everywhere inside binpick).
pub type Point = [f32; 3];

/// An unorganised point cloud. Inside binpick the coordinates are millimetres; clouds in
/// other units are scaled on load (see [`Units`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointCloud {
    pub points: Vec<Point>,
}

/// Axis-aligned bounding box, in the cloud's units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl Aabb {
    /// Edge lengths along x, y, z.
    pub fn size(&self) -> [f32; 3] {
        [
            self.max[0] - self.min[0],
            self.max[1] - self.min[1],
            self.max[2] - self.min[2],
        ]
    }

    /// Length of the diagonal: the cloud's overall extent.
    pub fn diagonal(&self) -> f32 {
        let [x, y, z] = self.size();
        (x * x + y * y + z * z).sqrt()
    }

    /// Whether `p` lies inside (boundary included).
    pub fn contains(&self, p: &Point) -> bool {
        (0..3).all(|i| p[i] >= self.min[i] && p[i] <= self.max[i])
    }
}

impl PointCloud {
    pub fn new(points: Vec<Point>) -> Self {
        Self { points }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The coordinates as one flat slice `[x0, y0, z0, x1, ...]`, the layout the PCL bridge takes.
    pub fn as_flat(&self) -> &[f32] {
        self.points.as_flattened()
    }

    /// Bounding box, or `None` for an empty cloud.
    pub fn bounds(&self) -> Option<Aabb> {
        let first = *self.points.first()?;
        let mut b = Aabb {
            min: first,
            max: first,
        };
        for p in &self.points[1..] {
            for (i, &c) in p.iter().enumerate() {
                b.min[i] = b.min[i].min(c);
                b.max[i] = b.max[i].max(c);
            }
        }
        Some(b)
    }

    /// Index of the first point with a NaN or infinite coordinate, if any.
    pub fn first_non_finite(&self) -> Option<usize> {
        self.points
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
    }

    /// Multiplies every coordinate by `factor` (e.g. 1000 to turn metres into millimetres).
    pub fn scale(&mut self, factor: f32) {
        for p in &mut self.points {
            for c in p.iter_mut() {
                *c *= factor;
            }
        }
    }

    /// The points moved by `pose` (computed in f64, stored as f32).
    pub fn transformed(&self, pose: &Isometry3<f64>) -> PointCloud {
        PointCloud::new(
            self.points
                .iter()
                .map(|p| transform_point(pose, p))
                .collect(),
        )
    }

    /// The points at `indices` (indices must be in range).
    pub fn select(&self, indices: &[u32]) -> PointCloud {
        PointCloud::new(indices.iter().map(|&i| self.points[i as usize]).collect())
    }

    /// Mean of the points, or `None` for an empty cloud.
    pub fn centroid(&self) -> Option<[f64; 3]> {
        centroid(&self.points)
    }
}

/// Mean of `points`, or `None` when there are none.
pub fn centroid(points: &[Point]) -> Option<[f64; 3]> {
    if points.is_empty() {
        return None;
    }
    let mut s = [0.0f64; 3];
    for p in points {
        for (acc, &c) in s.iter_mut().zip(p) {
            *acc += f64::from(c);
        }
    }
    let n = points.len() as f64;
    Some([s[0] / n, s[1] / n, s[2] / n])
}

/// A point as an f64 nalgebra point, for pose arithmetic.
pub fn to_point3(p: &Point) -> Point3<f64> {
    Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

/// At most `max_points` of `points`, evenly strided (deterministic), as f64 points: a sample
/// for pose comparisons.
pub fn strided_points(points: &[Point], max_points: usize) -> Vec<Point3<f64>> {
    let step = points.len().div_ceil(max_points.max(1)).max(1);
    points.iter().step_by(step).map(to_point3).collect()
}

/// Applies a rigid transform to one point.
pub fn transform_point(pose: &Isometry3<f64>, p: &Point) -> Point {
    let q = pose * to_point3(p);
    [q.x as f32, q.y as f32, q.z as f32]
}

/// Length unit of a cloud file. binpick works in millimetres, like the thesis; a cloud in
/// metres is multiplied by 1000 on load.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Units {
    /// Millimetres (the default).
    #[default]
    #[serde(rename = "mm")]
    Millimetres,
    /// Metres (e.g. Kinect / PCL sample data).
    #[serde(rename = "m")]
    Metres,
}

impl Units {
    /// Factor that converts a coordinate in these units to millimetres.
    pub fn to_mm(self) -> f32 {
        match self {
            Units::Millimetres => 1.0,
            Units::Metres => 1000.0,
        }
    }

    /// The short name used on the command line and in files: `mm` or `m`.
    pub fn as_str(self) -> &'static str {
        match self {
            Units::Millimetres => "mm",
            Units::Metres => "m",
        }
    }
}

impl std::str::FromStr for Units {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "mm" | "millimetres" | "millimeters" => Ok(Units::Millimetres),
            "m" | "metres" | "meters" => Ok(Units::Metres),
            other => Err(format!("unknown unit {other:?}: expected \"mm\" or \"m\"")),
        }
    }
}

impl std::fmt::Display for Units {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A 4x4 rigid transform, row-major, as used in every binpick JSON file.
pub type RowMajor4x4 = [f64; 16];

/// Error converting a row-major matrix into a rigid pose.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PoseError {
    #[error("pose has a non-finite entry")]
    NonFinite,
    #[error("pose's last row is {0:?}, expected [0, 0, 0, 1]")]
    BadLastRow([f64; 4]),
    #[error(
        "pose's 3x3 block is not a rotation (|R^T R - I| = {orthogonality:.2e}, det = {det:.4})"
    )]
    NotRotation { orthogonality: f64, det: f64 },
}

/// Row-major 4x4 -> rigid pose. Rejects matrices whose 3x3 block is not a proper rotation
/// (tolerance 1e-4, enough for poses printed with 6+ significant digits).
pub fn pose_from_row_major(m: &RowMajor4x4) -> Result<Isometry3<f64>, PoseError> {
    if !m.iter().all(|v| v.is_finite()) {
        return Err(PoseError::NonFinite);
    }
    let last = [m[12], m[13], m[14], m[15]];
    if (last[0].abs() + last[1].abs() + last[2].abs() + (last[3] - 1.0).abs()) > 1e-9 {
        return Err(PoseError::BadLastRow(last));
    }
    let r = nalgebra::Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
    let orthogonality = (r.transpose() * r - nalgebra::Matrix3::identity()).norm();
    let det = r.determinant();
    if orthogonality > 1e-4 || (det - 1.0).abs() > 1e-4 {
        return Err(PoseError::NotRotation { orthogonality, det });
    }
    let rot = nalgebra::Rotation3::from_matrix(&r);
    Ok(Isometry3::from_parts(
        nalgebra::Translation3::new(m[3], m[7], m[11]),
        nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
    ))
}

/// Rigid pose -> row-major 4x4.
pub fn pose_to_row_major(pose: &Isometry3<f64>) -> RowMajor4x4 {
    let h = pose.to_homogeneous();
    let mut out = [0.0; 16];
    for r in 0..4 {
        for c in 0..4 {
            out[r * 4 + c] = h[(r, c)];
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_round_trip_and_rejects_reflection() {
        let pose = Isometry3::new(
            nalgebra::Vector3::new(1.0, -2.0, 3.5),
            nalgebra::Vector3::new(0.3, -0.2, 1.1),
        );
        let m = pose_to_row_major(&pose);
        let back = pose_from_row_major(&m).unwrap();
        assert!((back.to_homogeneous() - pose.to_homogeneous()).norm() < 1e-12);
        let mut reflected = m;
        for v in &mut reflected[..3] {
            *v = -*v;
        }
        assert!(matches!(
            pose_from_row_major(&reflected),
            Err(PoseError::NotRotation { .. })
        ));
        let mut bad = m;
        bad[12] = 0.5;
        assert!(matches!(
            pose_from_row_major(&bad),
            Err(PoseError::BadLastRow(_))
        ));
    }

    #[test]
    fn bounds_and_scale() {
        let mut c = PointCloud::new(vec![[0.0, 1.0, 2.0], [-1.0, 3.0, 0.5]]);
        let b = c.bounds().unwrap();
        assert_eq!(b.min, [-1.0, 1.0, 0.5]);
        assert_eq!(b.max, [0.0, 3.0, 2.0]);
        c.scale(1000.0);
        assert_eq!(c.points[1], [-1000.0, 3000.0, 500.0]);
        assert!(PointCloud::default().bounds().is_none());
    }
}
