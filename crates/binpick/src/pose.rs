//! Pose differences, for comparing detections (poses are nalgebra isometries, model ->
//! scene, mm; the bridge converts PCL's matrices in one place, `binpick_pcl::rigid_pose`).

use nalgebra::Isometry3;

/// Rotation angle between two poses, degrees.
pub fn rotation_error_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    a.rotation.angle_to(&b.rotation).to_degrees()
}

/// Distance between two poses' translations, mm.
pub fn translation_error_mm(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    (a.translation.vector - b.translation.vector).norm()
}
