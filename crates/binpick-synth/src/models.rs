//! Model clouds (thesis Fig. 5.2 / 5.4 / 5.6) and ground truth.
//!
//! A model is the top view of the isolated part lying in its canonical stable pose, scanned by
//! a noise-free 0.5 x 0.5 mm version of the conveyor scanner, keeping only the part's points,
//! expressing them in the part's own frame and evening out the density on a 0.5 mm voxel
//! grid. Cut models are the points of the full model that lie in the part's cut range (same
//! frame). Every model also carries the exact mesh of what it shows.
//!
//! Two visible fractions:
//!
//! - [`ground_truth`] (the thesis presets): the share of the model's points that, moved by the
//!   true pose, have a scan point of that same instance (the scanner records which instance
//!   each ray hit; outliers do not count) within `tolerance` mm. For a model with symmetries
//!   the best symmetric equivalent counts, and the ground-truth pose is that equivalent
//!   (`pose * S`: the one whose model points face the scanner). A top-view model makes a part
//!   lying upside down look invisible, which is why the generalisation benchmark uses:
//! - [`ground_truth_alone`] (BOP's visib_fract): the scene's points on the instance over the
//!   points the same sensor sees of the part alone in the same pose. The thesis's datasets
//!   carry those counts too ([`ground_truth`]'s `counts`), for a model that has every side.

use std::collections::HashMap;

use nalgebra::Isometry3;

use binpick_cloud::dataset::{GroundTruth, GtInstance, ModelInfo, RevolutionAxis};
use binpick_cloud::{PointCloud, Units, pose_to_row_major, transform_point};

use crate::SynthError;
use crate::mesh::Mesh;
use crate::parts::{PartKind, PartLibrary};
use crate::physics::{Environment, Instance, canonical_pose};
use crate::scanner::{BACKGROUND, OUTLIER, Scan, ScannerConfig, SceneGeometry, scan};
use crate::sensor::Sensor;

/// Model names, in the order they are written.
pub const MODEL_NAMES: [&str; 5] = ["A", "A-cut", "B", "C", "C-cut"];

/// Visible fraction at or above which an instance is pickable.
pub const PICKABLE_FRACTION: f64 = 0.5;

/// One model: cloud in the part frame plus what the evaluator needs.
#[derive(Clone, Debug)]
pub struct Model {
    pub name: String,
    pub part: PartKind,
    pub cut: bool,
    /// Top view in the part (model) frame, mm.
    pub cloud: PointCloud,
    /// Rigid symmetries, identity first.
    pub symmetries: Vec<Isometry3<f64>>,
    /// The part's axis of revolution, if it has one.
    pub revolution_axis: Option<crate::parts::RevolutionAxis>,
    /// Largest distance between two points of `cloud` (thesis parts) or of the part's mesh
    /// (the other families), mm.
    pub diameter: f64,
    /// The exact mesh of what the model shows (the part, or its cut portion), part frame, mm.
    pub mesh: Mesh,
    /// Where the model scanner's camera was, part frame, mm (the PCD's `VIEWPOINT`): the
    /// side of the part the scan shows.
    pub viewpoint_mm: [f64; 3],
}

impl Model {
    /// `models/<name>.json`.
    pub fn info(&self) -> ModelInfo {
        let axis = self
            .revolution_axis
            .filter(|_| !self.cut)
            .map(|a| RevolutionAxis {
                point: a.point.coords.into(),
                direction: a.direction.into_inner().into(),
            });
        ModelInfo {
            diameter: self.diameter,
            symmetries: self.symmetries.iter().map(pose_to_row_major).collect(),
            revolution_axis: axis,
        }
    }
}

/// Largest distance between two points (exact: searched among the convex hull's vertices).
pub fn cloud_diameter(cloud: &PointCloud) -> f64 {
    use rapier3d::parry::math::Vector as PVec;
    let pts: Vec<PVec> = cloud
        .points
        .iter()
        .map(|p| PVec::new(p[0], p[1], p[2]))
        .collect();
    let candidates: Vec<[f64; 3]> = match rapier3d::parry::transformation::try_convex_hull(&pts) {
        Ok((verts, _)) if verts.len() >= 2 => verts
            .iter()
            .map(|v| [f64::from(v.x), f64::from(v.y), f64::from(v.z)])
            .collect(),
        _ => cloud
            .points
            .iter()
            .map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
            .collect(),
    };
    let mut best = 0.0f64;
    for (i, a) in candidates.iter().enumerate() {
        for b in &candidates[i + 1..] {
            let d = (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2);
            best = best.max(d);
        }
    }
    best.sqrt()
}

/// The parts, their canonical poses and the models built for some of them.
#[derive(Clone, Debug)]
pub struct ModelLibrary {
    pub parts: PartLibrary,
    /// Canonical resting pose of each part (index = [`PartKind::index`]).
    pub canonical: Vec<Isometry3<f64>>,
    pub models: Vec<Model>,
}

impl ModelLibrary {
    /// Builds the parts and the thesis's five models (deterministic; a fraction of a second).
    pub fn build() -> Result<Self, SynthError> {
        Self::build_for(&PartKind::THESIS, true)
    }

    /// Builds the parts and the models of `kinds` (in that order), with the cut models of
    /// the parts that have one when `with_cuts`.
    pub fn build_for(kinds: &[PartKind], with_cuts: bool) -> Result<Self, SynthError> {
        let parts = PartLibrary::new()?;
        let canonical = PartKind::ALL
            .iter()
            .map(|&kind| canonical_pose(&parts, kind))
            .collect::<Result<Vec<_>, _>>()?;
        let mut models = Vec::new();
        for &kind in kinds {
            let pose = canonical[kind.index()];
            let full = scan_isolated(&parts, kind, &pose)?;
            let camera = nalgebra::Point3::new(0.0, 0.0, ScannerConfig::model_scan().camera_height);
            let seen_from = pose.inverse() * camera;
            let viewpoint_mm = [seen_from.x, seen_from.y, seen_from.z];
            let part = parts.get(kind);
            // The thesis's models keep the diameter of their cloud (the thesis tables were
            // measured with it); the other families use their exact mesh, as BOP does.
            let diameter = if PartKind::THESIS.contains(&kind) {
                cloud_diameter(&full)
            } else {
                cloud_diameter(&PointCloud::new(part.mesh.vertices.clone()))
            };
            models.push(Model {
                name: kind.name().to_owned(),
                part: kind,
                cut: false,
                diameter,
                symmetries: part.symmetries(),
                revolution_axis: part.revolution_axis,
                cloud: full.clone(),
                mesh: part.mesh.clone(),
                viewpoint_mm,
            });
            if let (true, Some(cut_mesh)) = (with_cuts, part.cut_mesh()?) {
                let cut = PointCloud::new(
                    full.points
                        .iter()
                        .copied()
                        .filter(|p| part.in_cut(p))
                        .collect(),
                );
                models.push(Model {
                    name: format!("{}-cut", kind.name()),
                    part: kind,
                    cut: true,
                    diameter: cloud_diameter(&cut),
                    symmetries: part.cut_symmetries(),
                    revolution_axis: None,
                    cloud: cut,
                    mesh: cut_mesh,
                    viewpoint_mm,
                });
            }
        }
        Ok(Self {
            parts,
            canonical,
            models,
        })
    }

    pub fn model(&self, name: &str) -> Option<&Model> {
        self.models.iter().find(|m| m.name == name)
    }
}

/// Leaf size of the voxel grid that evens out the model clouds' density, mm.
pub const MODEL_LEAF: f64 = 0.5;

/// Voxel-grid downsampling: one point (the centroid) per occupied `leaf`-sized cube, in voxel
/// order (deterministic).
pub fn voxel_downsample(cloud: &PointCloud, leaf: f64) -> PointCloud {
    let mut cells: std::collections::BTreeMap<(i32, i32, i32), ([f64; 3], usize)> =
        std::collections::BTreeMap::new();
    for p in &cloud.points {
        let e = cells.entry(cell_of(p, leaf)).or_insert(([0.0; 3], 0));
        for (sum, &c) in e.0.iter_mut().zip(p) {
            *sum += f64::from(c);
        }
        e.1 += 1;
    }
    PointCloud::new(
        cells
            .values()
            .map(|(s, n)| {
                let n = *n as f64;
                [(s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32]
            })
            .collect(),
    )
}

/// Scans one part alone at `pose` with [`ScannerConfig::model_scan`] and returns its points in
/// the part frame, downsampled on a [`MODEL_LEAF`] voxel grid.
pub fn scan_isolated(
    parts: &PartLibrary,
    kind: PartKind,
    pose: &Isometry3<f64>,
) -> Result<PointCloud, SynthError> {
    let env = Environment::Flat {
        size: [600.0, 600.0],
    };
    let inst = [Instance { kind, pose: *pose }];
    let geom = SceneGeometry::from_scene(&env, &inst, parts)?;
    let s = scan(&geom, &ScannerConfig::model_scan(), 0);
    let inv = pose.inverse();
    let raw = PointCloud::new(
        s.cloud
            .points
            .iter()
            .zip(&s.labels)
            .filter(|(_, l)| **l == 0)
            .map(|(p, _)| transform_point(&inv, p))
            .collect(),
    );
    Ok(voxel_downsample(&raw, MODEL_LEAF))
}

/// A hash grid over the scan's part points, for "is there a point of instance k within r".
pub struct ScanIndex<'a> {
    scan: &'a Scan,
    cell: f64,
    grid: HashMap<(i32, i32, i32), Vec<u32>>,
}

fn cell_of(p: &[f32; 3], cell: f64) -> (i32, i32, i32) {
    (
        (f64::from(p[0]) / cell).floor() as i32,
        (f64::from(p[1]) / cell).floor() as i32,
        (f64::from(p[2]) / cell).floor() as i32,
    )
}

impl<'a> ScanIndex<'a> {
    /// Indexes the points that belong to an instance, with cells of `radius` mm.
    pub fn new(scan: &'a Scan, radius: f64) -> Self {
        let cell = radius.max(1e-3);
        let mut grid: HashMap<(i32, i32, i32), Vec<u32>> = HashMap::new();
        for (i, (p, &l)) in scan.cloud.points.iter().zip(&scan.labels).enumerate() {
            if l != BACKGROUND && l != OUTLIER {
                grid.entry(cell_of(p, cell)).or_default().push(i as u32);
            }
        }
        Self { scan, cell, grid }
    }

    /// Whether a point labelled `instance` lies within `radius` (<= the cell size) of `q`.
    pub fn has_near(&self, q: &[f32; 3], instance: u32, radius: f64) -> bool {
        let (cx, cy, cz) = cell_of(q, self.cell);
        let r2 = radius * radius;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(ids) = self.grid.get(&(cx + dx, cy + dy, cz + dz)) else {
                        continue;
                    };
                    for &i in ids {
                        if self.scan.labels[i as usize] != instance {
                            continue;
                        }
                        let p = self.scan.cloud.points[i as usize];
                        let d2 = (0..3)
                            .map(|k| (f64::from(p[k]) - f64::from(q[k])).powi(2))
                            .sum::<f64>();
                        if d2 <= r2 {
                            return true;
                        }
                    }
                }
            }
        }
        false
    }

    /// Share of `model` points that, moved by `pose`, have a point of `instance` within
    /// `radius`.
    pub fn visible_fraction(
        &self,
        model: &PointCloud,
        pose: &Isometry3<f64>,
        instance: u32,
        radius: f64,
    ) -> f64 {
        if model.is_empty() {
            return 0.0;
        }
        let seen = model
            .points
            .iter()
            .filter(|p| self.has_near(&transform_point(pose, p), instance, radius))
            .count();
        seen as f64 / model.len() as f64
    }
}

/// Visible fraction of an instance for a model, maximised over the model's symmetries;
/// returns the fraction and the pose of the best symmetric equivalent.
pub fn instance_visibility(
    index: &ScanIndex<'_>,
    model: &Model,
    pose: &Isometry3<f64>,
    instance: u32,
    radius: f64,
) -> (f64, Isometry3<f64>) {
    let mut best = (f64::NEG_INFINITY, *pose);
    for s in &model.symmetries {
        let p = pose * s;
        let f = index.visible_fraction(&model.cloud, &p, instance, radius);
        if f > best.0 + 1e-12 {
            best = (f, p);
        }
    }
    (best.0.max(0.0), best.1)
}

/// Ground-truth files for one scanned scene: one per model relevant to the part kinds present
/// (see [`PartKind::gt_models`]), in [`MODEL_NAMES`] order, listing every instance of that
/// part (buried ones too, with their low visible fraction). `counts`, when given, are BOP's
/// point counts per instance ([`alone_visibility`]), written beside the thesis's fraction.
pub fn ground_truth(
    scene_path: &str,
    instances: &[Instance],
    scan: &Scan,
    models: &ModelLibrary,
    radius: f64,
    counts: Option<&[(f64, u64, u64)]>,
) -> Result<Vec<GroundTruth>, SynthError> {
    let index = ScanIndex::new(scan, radius);
    let mut out = Vec::new();
    for name in MODEL_NAMES {
        let Some(model) = models.model(name) else {
            continue;
        };
        if !model.part.gt_models().contains(&name)
            || !instances.iter().any(|i| i.kind == model.part)
        {
            continue;
        }
        let mut gt_instances = Vec::new();
        for (k, inst) in instances.iter().enumerate() {
            if inst.kind != model.part {
                continue;
            }
            let (vf, pose) = instance_visibility(&index, model, &inst.pose, k as u32, radius);
            let vf = GtInstance::round_fraction(vf);
            let count = counts.and_then(|c| c.get(k));
            gt_instances.push(GtInstance {
                pose: pose_to_row_major(&pose),
                visible_fraction: vf,
                pickable: vf >= PICKABLE_FRACTION,
                visible_points: count.map(|c| c.1),
                alone_points: count.map(|c| c.2),
            });
        }
        out.push(GroundTruth {
            scene: scene_path.to_owned(),
            model: name.to_owned(),
            units: Units::Millimetres,
            instances: gt_instances,
        });
    }
    if out.is_empty() && !instances.is_empty() {
        return Err(SynthError::Geometry(
            "no model for the scene's parts".into(),
        ));
    }
    Ok(out)
}

/// Scene points on each instance's own surface (speckle outliers excluded), by instance.
pub fn visible_points(scan: &Scan, instances: usize) -> Vec<u64> {
    let mut counts = vec![0u64; instances];
    for &l in &scan.labels {
        if let Some(c) = counts.get_mut(l as usize) {
            *c += 1;
        }
    }
    counts
}

/// BOP's visible fraction (visib_fract) of every instance: the scene's points on its own
/// surface over the points the same sensor sees of the part alone in the same pose (same
/// sample positions and random streams, seed `seed`), capped at 1; 0 when the part alone
/// gives no point. Returns (fraction, visible points, alone points) per instance.
pub fn alone_visibility(
    instances: &[Instance],
    scan: &Scan,
    sensor: &Sensor,
    seed: u64,
    parts: &PartLibrary,
) -> Result<Vec<(f64, u64, u64)>, SynthError> {
    let visible = visible_points(scan, instances.len());
    instances
        .iter()
        .zip(visible)
        .map(|(inst, seen)| {
            let alone = sensor.scan_alone(&parts.get(inst.kind).mesh, &inst.pose, seed)?;
            let alone = alone.labels.iter().filter(|&&l| l == 0).count() as u64;
            Ok((GtInstance::share_seen(seen, alone), seen, alone))
        })
        .collect()
}

/// Ground truth with BOP's visible fraction ([`alone_visibility`]): independent of any model
/// cloud, so a part lying upside down is exactly as visible as the scan shows it. One file
/// per model in `models` (full models) whose part is in the scene, listing every instance of
/// that part (buried ones too) at its physics pose.
pub fn ground_truth_alone(
    scene_path: &str,
    instances: &[Instance],
    scan: &Scan,
    sensor: &Sensor,
    seed: u64,
    parts: &PartLibrary,
    models: &[&Model],
) -> Result<Vec<GroundTruth>, SynthError> {
    let vis = alone_visibility(instances, scan, sensor, seed, parts)?;
    let mut out = Vec::new();
    for model in models {
        if !instances.iter().any(|i| i.kind == model.part) {
            continue;
        }
        let gt_instances = instances
            .iter()
            .zip(&vis)
            .filter(|(inst, _)| inst.kind == model.part)
            .map(|(inst, &(_, seen, alone))| {
                let vf = GtInstance::visib_fract(seen, alone);
                GtInstance {
                    pose: pose_to_row_major(&inst.pose),
                    visible_fraction: vf,
                    pickable: vf >= PICKABLE_FRACTION,
                    visible_points: Some(seen),
                    alone_points: Some(alone),
                }
            })
            .collect();
        out.push(GroundTruth {
            scene: scene_path.to_owned(),
            model: model.name.clone(),
            units: Units::Millimetres,
            instances: gt_instances,
        });
    }
    Ok(out)
}
