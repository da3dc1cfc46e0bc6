//! The part to find, as the scene-voting engine sees it: its surface as oriented points in
//! the part's own frame, its size, and its symmetries. A scanned model (one view of the part)
//! and a CAD mesh (the whole surface) both end up here.

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Vector3};

use binpick_cloud::{Point, PointCloud};
use binpick_match::{OrientedPoints, Symmetries};

use crate::error::{InputKind, Result, input_as, pcl};
use crate::prepared::PreparedVoting;
use crate::stages::model::diameter;
use crate::stages::scale::{PartSize, measure_curvature_radius, measure_spacing};

/// Most points the diameter is measured on (exact over them, O(n^2)).
const DIAMETER_POINTS: usize = 3000;
/// Normals of a scanned model are fitted over this many of its point gaps.
const SCAN_NORMAL_RADIUS_GAPS: f64 = 3.0;

/// Where a part model came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum PartSource {
    /// One view of the part, scanned: only that side exists.
    Scan,
    /// A CAD mesh: the whole surface.
    Mesh,
}

/// A part model in its own frame, mm.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Part {
    /// Dense surface points with outward normals.
    pub surface: OrientedPoints,
    /// The points as given (the thesis engine works on these).
    pub cloud: PointCloud,
    /// Its diameter and the area one view shows.
    pub size: PartSize,
    /// Rigid transforms mapping it onto itself.
    pub symmetries: Symmetries,
    /// Scan or mesh.
    pub source: PartSource,
    /// Where a gripper may take it (model frame; from the sidecar's `grasps`).
    pub grasps: Vec<crate::grasp::Grasp>,
    /// Scene-voting models read from a prepared-model file (see [`crate::prepared`]).
    #[serde(skip)]
    pub(crate) prepared: Option<Arc<PreparedVoting>>,
}

impl Part {
    /// A scanned model: `viewpoint` is where the scanner was, in the model's frame (normals
    /// face it). `threads` for PCL's normal estimation (0 = all).
    pub fn from_scan(cloud: &PointCloud, viewpoint: [f64; 3], threads: u32) -> Result<Self> {
        let spacing = measure_spacing(&cloud.points)?.ok_or_else(|| {
            input_as(
                "model",
                InputKind::Degenerate,
                format!("{} point(s): too few to measure its spacing", cloud.len()),
            )
        })?;
        let radius = (SCAN_NORMAL_RADIUS_GAPS * spacing.gap_mm) as f32;
        let normals = binpick_pcl::estimate_normals(
            &cloud.points,
            radius,
            viewpoint.map(|c| c as f32),
            threads,
        )
        .map_err(pcl("model normals"))?;
        let surface = OrientedPoints {
            points: cloud.points.clone(),
            normals: normals.iter().map(|n| n.normal).collect(),
        }
        .with_defined_normals();
        let area = cloud.len() as f64 * spacing.spacing_mm * spacing.spacing_mm;
        Self::new(surface, cloud.clone(), area, PartSource::Scan)
    }

    /// A part from its surface samples with outward normals (a sampled CAD mesh): `area_mm2`
    /// is the mesh's surface area; one view shows about half of it.
    pub fn from_surface(surface: OrientedPoints, area_mm2: f64) -> Result<Self> {
        let cloud = PointCloud::new(surface.points.clone());
        Self::new(
            surface.with_defined_normals(),
            cloud,
            0.5 * area_mm2,
            PartSource::Mesh,
        )
    }

    fn new(
        surface: OrientedPoints,
        cloud: PointCloud,
        view_area_mm2: f64,
        source: PartSource,
    ) -> Result<Self> {
        if surface.len() < 20 {
            return Err(input_as(
                "model",
                InputKind::Degenerate,
                format!(
                    "only {} points with a surface normal; at least 20 are needed",
                    surface.len()
                ),
            ));
        }
        let step = surface.len().div_ceil(DIAMETER_POINTS).max(1);
        let sample: Vec<Point> = surface.points.iter().step_by(step).copied().collect();
        let diameter_mm = diameter(&sample);
        if diameter_mm.is_nan() || diameter_mm <= 0.0 {
            return Err(input_as(
                "model",
                InputKind::Degenerate,
                "all points coincide",
            ));
        }
        let curvature_radius_mm = measure_curvature_radius(&surface, diameter_mm)?;
        Ok(Self {
            surface,
            cloud,
            size: PartSize {
                diameter_mm,
                view_area_mm2,
                curvature_radius_mm,
            },
            symmetries: Symmetries::none(),
            source,
            grasps: Vec::new(),
            prepared: None,
        })
    }

    /// The same part with its declared symmetries.
    pub fn with_symmetries(mut self, symmetries: Symmetries) -> Self {
        self.symmetries = symmetries;
        self
    }

    /// The same part with grasps (model frame), each checked.
    pub fn with_grasps(mut self, grasps: Vec<crate::grasp::Grasp>) -> Result<Self> {
        for (k, g) in grasps.iter().enumerate() {
            g.validate(k)?;
        }
        self.grasps = grasps;
        Ok(self)
    }

    /// Centroid of the surface points (model frame).
    pub fn centre(&self) -> Point3<f64> {
        binpick_cloud::centroid(&self.surface.points).map_or_else(Point3::origin, Point3::from)
    }

    /// The canonical pose of `pose` under the part's symmetries.
    pub fn canonical(&self, pose: &Isometry3<f64>) -> Isometry3<f64> {
        self.symmetries.canonical(pose)
    }

    /// The direction a scanned model was seen from (its normals' mean, model frame); None
    /// for a mesh, which has every side, or a scan whose normals cancel out.
    pub fn scanned_side(&self) -> Option<Vector3<f64>> {
        if self.source != PartSource::Scan {
            return None;
        }
        let sum = self
            .surface
            .normals
            .iter()
            .fold(Vector3::zeros(), |acc, n| {
                acc + Vector3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2]))
            });
        (sum.norm() > f64::EPSILON * self.surface.len() as f64).then(|| sum.normalize())
    }

    /// Whether `turn` (model frame) shows the side of a scanned model its scanner never
    /// saw: it turns the scanned side more than 90 deg away. A near-symmetric turn that does
    /// cannot be judged against the scan (the model has no surface there to render), and a
    /// part lying the other way up fits the model as that turn: the scan cannot tell the
    /// two poses apart. Always false for a mesh.
    pub fn turn_hides_scanned_side(&self, turn: &Isometry3<f64>) -> bool {
        self.scanned_side()
            .is_some_and(|v| (turn.rotation * v).dot(&v) < 0.0)
    }
}
