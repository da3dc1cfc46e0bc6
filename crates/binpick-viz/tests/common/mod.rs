//! Synthetic clouds shared by the integration tests.
#![allow(dead_code)]

use binpick_cloud::PointCloud;
use nalgebra::{Isometry3, Vector3};

/// Floor z = 0 from -half to +half in x and y, every `step` mm.
pub fn floor(half: f32, step: f32) -> PointCloud {
    let mut pts = Vec::new();
    let n = (2.0 * half / step).round() as i32;
    for i in 0..=n {
        for j in 0..=n {
            pts.push([-half + i as f32 * step, -half + j as f32 * step, 0.0]);
        }
    }
    PointCloud::new(pts)
}

/// Square plate `size` mm wide centred on the model origin in the model's z = 0 plane.
pub fn plate(size: f32, step: f32) -> PointCloud {
    let mut pts = Vec::new();
    let n = (size / step).round() as i32;
    for i in 0..=n {
        for j in 0..=n {
            pts.push([
                -size / 2.0 + i as f32 * step,
                -size / 2.0 + j as f32 * step,
                0.0,
            ]);
        }
    }
    PointCloud::new(pts)
}

pub fn at(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::translation(x, y, z)
}

pub fn rotated_z(x: f64, y: f64, z: f64, yaw_deg: f64) -> Isometry3<f64> {
    Isometry3::new(
        Vector3::new(x, y, z),
        Vector3::new(0.0, 0.0, yaw_deg.to_radians()),
    )
}

pub fn read_png(path: &std::path::Path) -> image::RgbImage {
    image::open(path).unwrap().to_rgb8()
}
