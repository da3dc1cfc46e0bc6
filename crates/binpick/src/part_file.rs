//! Loading a part model from disk: a scanned cloud (PCD, PLY without faces) or a CAD mesh
//! (STL, OBJ, PLY with faces), plus its sidecar.
//!
//! **Sidecar** `<model>.json` next to the model file (the dataset's `models/<name>.json` is
//! one), every key optional:
//!
//! ```json
//! { "symmetries": [[16 numbers, row-major 4x4, model frame], ...],
//!   "revolution_axis": { "point": [x, y, z], "direction": [x, y, z] },
//!   "diameter": 71.3,
//!   "grasps": [ { "name": "top", "position_mm": [0, 0, 4], "approach": [0, 0, -1],
//!                 "clearance_radius_mm": 12, "clearance_length_mm": 150 } ] }
//! ```
//!
//! `symmetries` are rigid transforms `S` with `model = S * model` (the identity may be left
//! out); `revolution_axis` declares a continuous symmetry about a line (sampled every
//! [`REVOLUTION_STEP_DEG`] and composed with the listed transforms, e.g. a washer's
//! upside-down half-turn). `diameter` is only read by the evaluator. `grasps` are
//! [`Grasp`]s: where the gripper closes and the direction it moves in to get there (model
//! frame, mm), and the cylinder it needs free on the way (see [`crate::grasp`]).

use std::path::{Path, PathBuf};

use nalgebra::Isometry3;
use serde::Deserialize;

use binpick_cloud::dataset::RevolutionAxis;
use binpick_cloud::io::{Model, read_model};
use binpick_cloud::{RowMajor4x4, SurfaceSampling, Units, pose_from_row_major};
use binpick_match::{OrientedPoints, Symmetries};

use crate::error::{InputKind, Result, input, input_as};
use crate::grasp::Grasp;
use crate::params::Params;
use crate::stages::part::Part;

/// A declared revolution symmetry is sampled every this many degrees.
pub const REVOLUTION_STEP_DEG: f64 = 5.0;
/// A scanned model whose centre lies this many extents from the origin was captured by a
/// camera at the origin (a cloud in its camera's frame).
const CAMERA_FRAME_EXTENTS: f64 = 2.0;
/// A mesh is sampled this finely, in model extents (bounding-box diagonals): finer than any
/// working resolution (never below 1/100 of the diameter).
const MESH_SAMPLING_EXTENTS: f64 = 1.0 / 250.0;

/// The sidecar's keys (see the module docs).
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[non_exhaustive]
pub struct Sidecar {
    /// Rigid transforms mapping the part onto itself (row-major 4x4, model frame).
    #[serde(default)]
    pub symmetries: Vec<RowMajor4x4>,
    /// A continuous symmetry about a line.
    #[serde(default)]
    pub revolution_axis: Option<RevolutionAxis>,
    /// The part's diameter, mm (read by the evaluator only).
    #[serde(default)]
    pub diameter: Option<f64>,
    /// Where a gripper may take the part (model frame).
    #[serde(default)]
    pub grasps: Vec<Grasp>,
}

impl Sidecar {
    /// The declared symmetries.
    pub fn symmetries(&self, path: &Path) -> Result<Symmetries> {
        let bad = |m: String| input("model sidecar", format!("{}: {m}", path.display()));
        let listed: Vec<Isometry3<f64>> = self
            .symmetries
            .iter()
            .enumerate()
            .map(|(i, m)| pose_from_row_major(m).map_err(|e| bad(format!("symmetry {i}: {e}"))))
            .collect::<Result<_>>()?;
        match &self.revolution_axis {
            None => Ok(Symmetries::new(&listed)),
            Some(axis) => {
                Symmetries::revolution(axis.point, axis.direction, REVOLUTION_STEP_DEG, &listed)
                    .map_err(|e| bad(e.to_string()))
            }
        }
    }
}

/// Where a model's sidecar is: the same path with the extension `.json`.
pub fn sidecar_path(model: &Path) -> PathBuf {
    model.with_extension("json")
}

/// Reads the sidecar of `model`, if there is one.
pub fn read_sidecar(model: &Path) -> Result<Option<Sidecar>> {
    let path = sidecar_path(model);
    if !path.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).map_err(|e| {
        input_as(
            "model sidecar",
            InputKind::Parse,
            format!("{}: {e}", path.display()),
        )
    })?;
    serde_json::from_str(&text).map(Some).map_err(|e| {
        input_as(
            "model sidecar",
            InputKind::Parse,
            format!("{}: {e}", path.display()),
        )
    })
}

/// What loading a part did, for logs.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct PartLoadReport {
    /// Whether the model was a mesh (else a scanned cloud).
    pub mesh: bool,
    /// Points of the part's surface (mesh: samples).
    pub points: usize,
    /// Where the scanner was for a scanned model, mm (model frame), and where that came from.
    pub viewpoint: Option<([f64; 3], &'static str)>,
    /// The sidecar that was read, if any.
    pub sidecar: Option<PathBuf>,
    /// Symmetries attached (the identity included).
    pub symmetries: usize,
    /// Grasps declared in the sidecar.
    pub grasps: usize,
}

/// Loads a part model: a mesh is sampled over its whole surface with outward normals; a
/// scanned cloud gets normals facing its scanner (the PCD `VIEWPOINT` when the file has
/// one, else `features.model_viewpoint_mm`). The sidecar's symmetries are attached.
///
/// A prepared model (`*.prepared`, written by `binpick model prepare`, see
/// [`crate::prepared`]) is read as it was prepared, with its voting models.
pub fn load_part(path: &Path, units: Units, params: &Params) -> Result<(Part, PartLoadReport)> {
    let _span = tracing::debug_span!("load_part", path = %path.display()).entered();
    if crate::prepared::is_prepared(path) {
        let (part, header) = crate::prepared::read(path, units, params)?;
        let sidecar = sidecar_path(&header.source);
        let report = PartLoadReport {
            mesh: part.source == crate::PartSource::Mesh,
            points: part.surface.len(),
            viewpoint: None,
            sidecar: sidecar.exists().then_some(sidecar),
            symmetries: part.symmetries.transforms().len(),
            grasps: part.grasps.len(),
        };
        return Ok((part, report));
    }
    let mut model = read_model(path)?;
    model.scale_to_mm(units);
    let threads = params.runtime.threads as u32;
    let (part, mesh, viewpoint) = match model {
        Model::Mesh(m) => {
            let bounds = m.mesh.bounds().ok_or_else(|| {
                input_as(
                    "model",
                    InputKind::Degenerate,
                    format!("{}: the mesh has no vertices", path.display()),
                )
            })?;
            let spacing = f64::from(bounds.diagonal()) * MESH_SAMPLING_EXTENTS;
            let samples = m
                .mesh
                .sample_surface(&SurfaceSampling {
                    spacing_mm: spacing,
                    ..SurfaceSampling::default()
                })
                .map_err(|e| input("model", format!("{}: {e}", path.display())))?;
            let surface = OrientedPoints {
                points: samples.cloud.points,
                normals: samples.normals,
            };
            (Part::from_surface(surface, m.mesh.area())?, true, None)
        }
        Model::Cloud(c) => {
            let far_from_origin = c.cloud.bounds().is_some_and(|b| {
                let centre = binpick_cloud::centroid(&c.cloud.points).unwrap_or([0.0; 3]);
                let dist = centre.iter().map(|x| x * x).sum::<f64>().sqrt();
                dist > CAMERA_FRAME_EXTENTS * f64::from(b.diagonal())
            });
            let (viewpoint, from) = match (c.report.sensor_viewpoint(), c.report.height > 1) {
                (Some(v), _) => (v.position, "the file's VIEWPOINT"),
                (None, true) => ([0.0; 3], "an organised cloud, in its camera's frame"),
                (None, false) if far_from_origin => (
                    [0.0; 3],
                    "far from the origin: a cloud in its camera's frame",
                ),
                (None, false) => (params.features.model_viewpoint_mm, "model_viewpoint_mm"),
            };
            let part = Part::from_scan(&c.cloud, viewpoint, threads)?;
            (part, false, Some((viewpoint, from)))
        }
    };
    let sidecar = read_sidecar(path)?;
    let symmetries = match &sidecar {
        Some(s) => s.symmetries(&sidecar_path(path))?,
        None => Symmetries::none(),
    };
    let report = PartLoadReport {
        mesh,
        points: part.surface.len(),
        viewpoint,
        sidecar: sidecar.as_ref().map(|_| sidecar_path(path)),
        symmetries: symmetries.transforms().len(),
        grasps: sidecar.as_ref().map_or(0, |s| s.grasps.len()),
    };
    tracing::debug!(
        mesh = report.mesh,
        points = report.points,
        symmetries = report.symmetries,
        grasps = report.grasps,
        "part loaded"
    );
    let grasps = sidecar.map(|s| s.grasps).unwrap_or_default();
    let part = part.with_grasps(grasps).map_err(|e| {
        input(
            "model sidecar",
            format!("{}: {e}", sidecar_path(path).display()),
        )
    })?;
    Ok((part.with_symmetries(symmetries), report))
}
