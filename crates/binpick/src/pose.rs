//! Pose conversions (row-major 4x4 <-> nalgebra) and pose differences.

use nalgebra::Isometry3;

use binpick_cloud::{RowMajor4x4, pose_from_row_major, pose_to_row_major};

/// Row-major 4x4 -> pose; `None` if it is not a rigid transform (within 1e-4).
pub fn from_mat4(m: &RowMajor4x4) -> Option<Isometry3<f64>> {
    pose_from_row_major(m).ok()
}

/// Pose -> row-major 4x4.
pub fn to_mat4(pose: &Isometry3<f64>) -> RowMajor4x4 {
    pose_to_row_major(pose)
}

/// Rotation angle between two poses, degrees.
pub fn rotation_error_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    a.rotation.angle_to(&b.rotation).to_degrees()
}

/// Distance between two poses' translations, mm.
pub fn translation_error_mm(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    (a.translation.vector - b.translation.vector).norm()
}

/// Unit quaternion as `[w, x, y, z]`.
pub fn quaternion_wxyz(pose: &Isometry3<f64>) -> [f64; 4] {
    let q = pose.rotation.quaternion();
    [q.w, q.i, q.j, q.k]
}
