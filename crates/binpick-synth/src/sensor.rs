//! The two kinds of sensor behind one interface: the thesis's dual-laser line scanner and a
//! structured-light depth camera; scanning a scene, scanning one part alone (for BOP's
//! visible fraction) and where the sensor looks from.

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::SynthError;
use crate::depth::{DepthCameraConfig, depth_scan, depth_scan_window};
use crate::mesh::Mesh;
use crate::scanner::{Scan, ScannerConfig, SceneGeometry, scan, scan_window};

/// A sensor and its settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Sensor {
    /// The dual-laser triangulation line scanner over a belt or a bin ([`crate::scanner`]).
    LaserLine(ScannerConfig),
    /// A structured-light depth camera ([`crate::depth`]).
    DepthCamera(DepthCameraConfig),
}

/// Where a sensor looks from (scene frame, mm): what a recogniser needs to know which side of
/// a part the sensor can see.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Viewpoint {
    /// Optical centre of the camera (for the line scanner: at the middle of its sweep).
    pub position_mm: [f64; 3],
    /// Camera frame -> scene frame rotation (w, x, y, z); the camera looks along its +z.
    pub orientation_wxyz: [f64; 4],
    /// Unit viewing direction of the optical axis, scene frame.
    pub view_direction: [f64; 3],
    /// The same as a PCD `VIEWPOINT` header line: `tx ty tz qw qx qy qz`.
    pub pcd_viewpoint: String,
    /// For a line scanner, the head moves along `axis` (scene frame) from `from_mm` to
    /// `to_mm`; the camera's x position and height stay as in `position_mm`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sweep: Option<Sweep>,
}

/// The straight sweep of a line scanner's head.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sweep {
    pub axis: [f64; 3],
    pub from_mm: f64,
    pub to_mm: f64,
}

impl Sensor {
    /// `laser_line` or `depth_camera`.
    pub fn kind(&self) -> &'static str {
        match self {
            Sensor::LaserLine(_) => "laser_line",
            Sensor::DepthCamera(_) => "depth_camera",
        }
    }

    /// Scans the scene (deterministic in `seed`, whatever the thread count).
    pub fn scan(&self, geom: &SceneGeometry, seed: u64) -> Scan {
        match self {
            Sensor::LaserLine(c) => scan(geom, c, seed),
            Sensor::DepthCamera(c) => depth_scan(geom, c, seed),
        }
    }

    /// Scans `mesh` at `pose` with nothing else in the world (no floor, no walls, no other
    /// part), with the same sample positions and random streams as [`Sensor::scan`] with the
    /// same seed, restricted to the samples whose rays can reach the part. Points on the
    /// part are labelled 0.
    pub fn scan_alone(
        &self,
        mesh: &Mesh,
        pose: &Isometry3<f64>,
        seed: u64,
    ) -> Result<Scan, SynthError> {
        let placed = mesh.transformed(pose);
        let bounds = placed
            .bounds()
            .ok_or_else(|| SynthError::Geometry("empty part mesh".into()))?;
        let geom = SceneGeometry::new(None, &[], &[(&placed, Isometry3::identity())])?;
        Ok(match self {
            Sensor::LaserLine(c) => {
                let (lines, cols) = c.window_for(&bounds);
                scan_window(&geom, c, seed, lines, cols)
            }
            Sensor::DepthCamera(c) => {
                let (cols, rows) = c.window_for(&bounds);
                depth_scan_window(&geom, c, seed, cols, rows)
            }
        })
    }

    /// Nominal distance between neighbouring samples on a surface facing the sensor at the
    /// floor (z = 0), mm: the larger of line and column spacing, or a pixel's footprint.
    pub fn sample_spacing_mm(&self) -> f64 {
        match self {
            Sensor::LaserLine(c) => c.line_spacing().max(c.column_spacing()),
            Sensor::DepthCamera(c) => c.pixel_size_at(c.position[2]),
        }
    }

    /// Range-noise standard deviation at the floor, mm.
    pub fn noise_sigma_mm(&self) -> f64 {
        match self {
            Sensor::LaserLine(c) => c.noise_sigma,
            Sensor::DepthCamera(c) => c.noise_sigma_at(c.position[2]),
        }
    }

    /// Where the sensor looks from.
    pub fn viewpoint(&self) -> Viewpoint {
        let (position, sweep) = match self {
            Sensor::LaserLine(c) => (
                [0.0, 0.5 * (c.y_range[0] + c.y_range[1]), c.camera_height],
                Some(Sweep {
                    axis: [0.0, 1.0, 0.0],
                    from_mm: c.y_range[0],
                    to_mm: c.y_range[1],
                }),
            ),
            Sensor::DepthCamera(c) => (c.position, None),
        };
        // Both look straight down: camera frame = half turn about scene x.
        let q = DepthCameraConfig::ORIENTATION_WXYZ;
        Viewpoint {
            position_mm: position,
            orientation_wxyz: q,
            view_direction: [0.0, 0.0, -1.0],
            pcd_viewpoint: format!(
                "{} {} {} {} {} {} {}",
                position[0], position[1], position[2], q[0], q[1], q[2], q[3]
            ),
            sweep,
        }
    }
}
