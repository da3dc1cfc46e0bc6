//! Whole-dataset generation: piles, scans, ground truth, manifest.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use binpick_cloud::PointCloud;
use binpick_cloud::dataset::{GroundTruth, write_json};

use crate::models::{Model, ModelLibrary, PICKABLE_FRACTION, alone_visibility, ground_truth};
use crate::parts::{PartKind, PartLibrary};
use crate::physics::{Environment, Instance, PhysicsSettings, Pile};
use crate::plan::{GroupPlan, Layout, Preset, Recipe, draw_kinds, plan};
use crate::rng::{Rng, derive_seed};
use crate::scanner::{Scan, ScannerConfig, SceneGeometry, scan};
use crate::sensor::Sensor;
use crate::{GENERATOR_VERSION, SynthError};

/// Options of [`generate`].
#[derive(Clone, Debug, PartialEq)]
pub struct SynthOptions {
    pub preset: Preset,
    /// Dataset root (created if missing).
    pub out_dir: PathBuf,
    pub seed: u64,
    /// Overrides every group's number of scans (quick runs).
    pub scenes_per_group: Option<usize>,
    /// Overrides the belt-level samples per scene (lines x columns; a scene has about 1.1-1.4
    /// times as many points, as surfaces lit by both lasers give two).
    pub points_target: Option<usize>,
}

/// What [`generate`] did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    pub out_dir: PathBuf,
    pub scenes: usize,
    pub gt_files: usize,
    pub total_points: usize,
    pub instances: usize,
    pub pickable: usize,
    /// Wall-clock time, s.
    pub elapsed_s: f64,
    /// Summed over threads: time in physics and in scanning + labelling, s.
    pub physics_s: f64,
    pub scan_s: f64,
}

/// Visible-fraction distance for a scanner: 1.5 mm, or more when the sampling and noise need
/// it: max(1.5, sqrt((line/2)^2 + (column/2)^2 + (3 sigma)^2)).
pub fn visibility_radius(cfg: &ScannerConfig) -> f64 {
    let a = 0.5 * cfg.line_spacing();
    let b = 0.5 * cfg.column_spacing();
    let c = 3.0 * cfg.noise_sigma;
    (a * a + b * b + c * c).sqrt().max(1.5)
}

/// A scanned, labelled synthetic scene.
#[derive(Clone, Debug)]
pub struct SynthScene {
    pub environment: Environment,
    pub instances: Vec<Instance>,
    pub scanner: ScannerConfig,
    pub scan: Scan,
    /// One per relevant model; `scene` paths are `scenes/<scene_id>.pcd`.
    pub gt: Vec<GroundTruth>,
    /// Distance used for the visible fractions, mm.
    pub visibility_radius: f64,
    /// Whether the physics reached rest before its time cap.
    pub settled: bool,
}

/// Scans parts at given poses and labels the result (no physics).
pub fn scan_instances(
    models: &ModelLibrary,
    environment: &Environment,
    instances: Vec<Instance>,
    scanner: &ScannerConfig,
    seed: u64,
    scene_id: &str,
) -> Result<SynthScene, SynthError> {
    let geom = SceneGeometry::from_scene(environment, &instances, &models.parts)?;
    let s = scan(&geom, scanner, seed);
    let radius = visibility_radius(scanner);
    // BOP's counts beside the thesis's fraction: the scan's sample positions and random
    // streams (`seed`), the part alone.
    let counts = alone_visibility(
        &instances,
        &s,
        &Sensor::LaserLine(scanner.clone()),
        seed,
        &models.parts,
    )?;
    let gt = ground_truth(
        &format!("scenes/{scene_id}.pcd"),
        &instances,
        &s,
        models,
        radius,
        Some(&counts),
    )?;
    Ok(SynthScene {
        environment: environment.clone(),
        instances,
        scanner: scanner.clone(),
        scan: s,
        gt,
        visibility_radius: radius,
        settled: true,
    })
}

/// The temporary corral and drop area for a pile.
fn drop_zone(
    layout: Layout,
    env: &Environment,
    kinds: &[PartKind],
    rng: &mut Rng,
) -> (Option<[f64; 4]>, [f64; 4]) {
    let n = kinds.len() as f64;
    let has_b = kinds.contains(&PartKind::B);
    if let Environment::Bin { .. } = env {
        // Dropped over a 150 mm patch of the bin (the walls keep them in): a pile, not a
        // layer spread over the floor.
        let [hx, hy] = env.inner_half_extents();
        let half = 75.0f64.min(hx).min(hy);
        let cx = rng.range(-(hx - half), hx - half);
        let cy = rng.range(-(hy - half), hy - half);
        let m = 5.0;
        let area = [
            (cx - half).max(-hx + m),
            (cx + half).min(hx - m),
            (cy - half).max(-hy + m),
            (cy + half).min(hy - m),
        ];
        return (None, area);
    }
    let (half, jitter) = match layout {
        Layout::Conveyor => {
            let mut h = (45.0 + 6.0 * n).clamp(70.0, 100.0);
            if has_b {
                h = h.max(85.0);
            }
            (h, 15.0)
        }
        Layout::Arm => {
            let mut h = (50.0 + 7.0 * n).clamp(75.0, 110.0);
            if has_b {
                h = h.max(85.0);
            }
            (h, 40.0)
        }
    };
    let cx = rng.range(-jitter, jitter);
    let cy = rng.range(-jitter, jitter);
    let corral = [cx - half, cx + half, cy - half, cy + half];
    let m = 2.0;
    (
        Some(corral),
        [corral[0] + m, corral[1] - m, corral[2] + m, corral[3] - m],
    )
}

/// Builds a pile: `base` parts dropped first and settled, then `top` parts over them, then the
/// corral is removed and everything settles. Returns the pile and whether it came to rest.
pub fn build_pile<'a>(
    lib: &'a PartLibrary,
    layout: Layout,
    env: &Environment,
    base: &[PartKind],
    top: &[PartKind],
    rng: &mut Rng,
) -> Result<(Pile<'a>, bool), SynthError> {
    build_pile_with(lib, layout, env, base, top, rng, PhysicsSettings::default())
}

/// [`build_pile`] with explicit physics settings.
pub fn build_pile_with<'a>(
    lib: &'a PartLibrary,
    layout: Layout,
    env: &Environment,
    base: &[PartKind],
    top: &[PartKind],
    rng: &mut Rng,
    settings: PhysicsSettings,
) -> Result<(Pile<'a>, bool), SynthError> {
    let all: Vec<PartKind> = base.iter().chain(top).copied().collect();
    let (corral, area) = drop_zone(layout, env, &all, rng);
    build_pile_in(lib, env, corral, area, base, top, rng, settings)
}

/// Builds a pile in a given drop zone: `base` parts dropped at random x/y inside `area`
/// (`[xmin, xmax, ymin, ymax]`, mm) from random orientations and settled, then `top` parts
/// over them, then the temporary `corral` (if any) is removed and everything settles.
/// Returns the pile and whether it came to rest.
#[allow(clippy::too_many_arguments)]
pub fn build_pile_in<'a>(
    lib: &'a PartLibrary,
    env: &Environment,
    corral: Option<[f64; 4]>,
    area: [f64; 4],
    base: &[PartKind],
    top: &[PartKind],
    rng: &mut Rng,
    settings: PhysicsSettings,
) -> Result<(Pile<'a>, bool), SynthError> {
    let mut pile = Pile::new(lib, env, corral, settings);
    let mut settled = true;
    if !base.is_empty() {
        settled = pile.drop_parts(base, area, rng)?;
    }
    if !top.is_empty() {
        settled = pile.drop_parts(top, area, rng)?;
    }
    if corral.is_some() {
        pile.remove_corral();
        settled = pile.settle();
    }
    Ok((pile, settled))
}

/// One scene to make with [`make_scene`].
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRequest<'a> {
    pub layout: Layout,
    /// Drop the parts into a bin with walls.
    pub in_box: bool,
    /// Parts dropped first (all of them for a simple pile).
    pub base: &'a [PartKind],
    /// Parts dropped over the settled base.
    pub top: &'a [PartKind],
    pub points_target: usize,
    /// A fixed scanner instead of one drawn from the layout's ranges (`points_target` is then
    /// ignored).
    pub scanner: Option<ScannerConfig>,
    pub seed: u64,
    /// Used for the ground truth's `scene` path: `scenes/<scene_id>.pcd`.
    pub scene_id: &'a str,
}

/// One scene, end to end: physics, scan, ground truth (in memory). Scanner speed and noise are
/// drawn from the layout's ranges unless `req.scanner` fixes them.
pub fn make_scene(models: &ModelLibrary, req: &SceneRequest<'_>) -> Result<SynthScene, SynthError> {
    let mut rng = Rng::new(req.seed);
    let env = req.layout.environment(req.in_box);
    let drawn = req.layout.random_scanner(&mut rng, req.points_target);
    let scanner = req.scanner.clone().unwrap_or(drawn);
    let (pile, settled) = build_pile(&models.parts, req.layout, &env, req.base, req.top, &mut rng)?;
    let mut scene = scan_instances(
        models,
        &env,
        pile.instances(),
        &scanner,
        derive_seed(req.seed, "scan", 0),
        req.scene_id,
    )?;
    scene.settled = settled;
    Ok(scene)
}

#[derive(Clone, Debug, Serialize)]
struct ScannerRecord {
    speed_mm_s: f64,
    line_spacing_mm: f64,
    columns: usize,
    column_spacing_mm: f64,
    noise_sigma_mm: f64,
    outlier_rate: f64,
}

#[derive(Clone, Debug, Serialize)]
struct SceneRecord {
    id: String,
    index: usize,
    parts: BTreeMap<String, usize>,
    points: usize,
    scanner: ScannerRecord,
    visibility_radius_mm: f64,
    settled: bool,
    gt: Vec<String>,
    /// Pickable instances per ground-truth model.
    pickable: BTreeMap<String, usize>,
}

#[derive(Clone, Debug, Serialize)]
struct GroupRecord {
    #[serde(flatten)]
    plan: GroupPlan,
    scene_records: Vec<SceneRecord>,
}

struct Timing {
    physics: f64,
    scan: f64,
}

/// A job's group index, scene records and timing.
type JobOutput = (usize, Vec<SceneRecord>, Timing);

pub(crate) fn io_err(path: &Path) -> impl Fn(std::io::Error) -> SynthError + '_ {
    move |source| SynthError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Writes a cloud as binary PCD, creating the folder.
pub fn write_cloud(path: &Path, cloud: &PointCloud) -> Result<(), SynthError> {
    write_cloud_seen_from(path, cloud, &binpick_cloud::io::Viewpoint::default())
}

/// Writes a binary PCD whose `VIEWPOINT` is `viewpoint` (mm), creating the folder.
pub fn write_cloud_seen_from(
    path: &Path,
    cloud: &PointCloud,
    viewpoint: &binpick_cloud::io::Viewpoint,
) -> Result<(), SynthError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(io_err(parent))?;
    }
    binpick_cloud::io::write_pcd_with_viewpoint(
        path,
        cloud,
        binpick_cloud::io::PcdEncoding::Binary,
        None,
        viewpoint,
    )?;
    Ok(())
}

/// Writes a model's cloud with its scanner's position in the `VIEWPOINT` line (so readers
/// know which side of the part the scan shows).
pub fn write_model_cloud(path: &Path, m: &crate::models::Model) -> Result<(), SynthError> {
    let viewpoint = binpick_cloud::io::Viewpoint {
        position: m.viewpoint_mm,
        orientation_wxyz: [1.0, 0.0, 0.0, 0.0],
    };
    write_cloud_seen_from(path, &m.cloud, &viewpoint)
}

/// Writes a mesh as binary STL (mm), creating the folder.
pub fn write_stl(path: &Path, mesh: &crate::mesh::Mesh) -> Result<(), SynthError> {
    let io = io_err(path);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(io_err(parent))?;
    }
    let corner = |i: u32| -> Result<[f32; 3], SynthError> {
        mesh.vertices.get(i as usize).copied().ok_or_else(|| {
            SynthError::Geometry(format!("{}: vertex index {i} out of range", path.display()))
        })
    };
    let mut triangles = Vec::with_capacity(mesh.triangles.len());
    for t in &mesh.triangles {
        let [a, b, c] = [corner(t[0])?, corner(t[1])?, corner(t[2])?];
        let (a64, b64, c64) = (
            crate::mesh::to_point3(&a),
            crate::mesh::to_point3(&b),
            crate::mesh::to_point3(&c),
        );
        let n = (b64 - a64).cross(&(c64 - a64));
        let n = if n.norm() > 0.0 { n.normalize() } else { n };
        triangles.push(stl_io::Triangle {
            normal: stl_io::Normal::new([n.x as f32, n.y as f32, n.z as f32]),
            vertices: [
                stl_io::Vertex::new(a),
                stl_io::Vertex::new(b),
                stl_io::Vertex::new(c),
            ],
        });
    }
    let mut file = std::fs::File::create(path).map_err(&io)?;
    stl_io::write_stl(&mut file, triangles.iter()).map_err(io)
}

/// Writes a scene's cloud and ground-truth files; returns its manifest record.
fn write_scene(
    root: &Path,
    scene_id: &str,
    index: usize,
    scene: &SynthScene,
) -> Result<SceneRecord, SynthError> {
    write_cloud(
        &root.join("scenes").join(format!("{scene_id}.pcd")),
        &scene.scan.cloud,
    )?;
    let SceneFiles {
        gt_ids,
        pickable,
        parts,
    } = write_ground_truth(root, scene_id, &scene.gt, &scene.instances)?;
    let c = &scene.scanner;
    Ok(SceneRecord {
        id: scene_id.to_owned(),
        index,
        parts,
        points: scene.scan.cloud.len(),
        scanner: ScannerRecord {
            speed_mm_s: c.speed,
            line_spacing_mm: c.line_spacing(),
            columns: c.columns,
            column_spacing_mm: c.column_spacing(),
            noise_sigma_mm: c.noise_sigma,
            outlier_rate: c.outlier_rate,
        },
        visibility_radius_mm: scene.visibility_radius,
        settled: scene.settled,
        gt: gt_ids,
        pickable,
    })
}

/// What a scene's manifest record says about its ground truth.
pub(crate) struct SceneFiles {
    /// `<scene>__<model>`, one per ground-truth file written.
    pub gt_ids: Vec<String>,
    /// Pickable instances per model.
    pub pickable: BTreeMap<String, usize>,
    /// Instances per part kind in the scene.
    pub parts: BTreeMap<String, usize>,
}

/// Writes `gt/<scene_id>__<model>.json` for each of `gt` and counts what the manifest
/// records about them and about the scene's `instances`.
pub(crate) fn write_ground_truth(
    root: &Path,
    scene_id: &str,
    gt: &[GroundTruth],
    instances: &[Instance],
) -> Result<SceneFiles, SynthError> {
    let mut gt_ids = Vec::new();
    let mut pickable = BTreeMap::new();
    for g in gt {
        let gt_id = format!("{scene_id}__{}", g.model);
        write_json(&root.join("gt").join(format!("{gt_id}.json")), g)?;
        pickable.insert(
            g.model.clone(),
            g.instances.iter().filter(|i| i.pickable).count(),
        );
        gt_ids.push(gt_id);
    }
    let mut parts = BTreeMap::new();
    for inst in instances {
        *parts.entry(inst.kind.name().to_owned()).or_insert(0) += 1;
    }
    Ok(SceneFiles {
        gt_ids,
        pickable,
        parts,
    })
}

/// Runs one group's scenes (all of them for a "-Decr" sequence, else one scene).
fn run_job(
    models: &ModelLibrary,
    root: &Path,
    group: &GroupPlan,
    points_target: usize,
    seed: u64,
    only_index: Option<usize>,
    done: &(dyn Fn() + Sync),
) -> Result<(Vec<SceneRecord>, Timing), SynthError> {
    let mut timing = Timing {
        physics: 0.0,
        scan: 0.0,
    };
    let mut records = Vec::new();
    match (&group.recipe, only_index) {
        (Recipe::Decr { kind, start }, _) => {
            let gseed = derive_seed(seed, &group.slug, 0);
            let mut rng = Rng::new(gseed);
            let env = group.layout.environment(group.in_box);
            let scanner = group.layout.random_scanner(&mut rng, points_target);
            let n0 = rng.int_inclusive(start[0], start[1]).max(group.scenes);
            let kinds = vec![*kind; n0];
            let t0 = Instant::now();
            let (mut pile, mut settled) =
                build_pile(&models.parts, group.layout, &env, &kinds, &[], &mut rng)?;
            timing.physics += t0.elapsed().as_secs_f64();
            for index in 0..group.scenes {
                if index > 0 {
                    let t0 = Instant::now();
                    pile.remove_topmost();
                    settled = pile.settle();
                    timing.physics += t0.elapsed().as_secs_f64();
                }
                if pile.is_empty() {
                    break;
                }
                let id = group.scene_id(index);
                let t0 = Instant::now();
                let mut scene = scan_instances(
                    models,
                    &env,
                    pile.instances(),
                    &scanner,
                    derive_seed(gseed, "scan", index as u64),
                    &id,
                )?;
                scene.settled = settled;
                records.push(write_scene(root, &id, index, &scene)?);
                timing.scan += t0.elapsed().as_secs_f64();
                done();
            }
        }
        (recipe, Some(index)) => {
            let sseed = derive_seed(seed, &group.slug, index as u64);
            let mut rng = Rng::new(sseed);
            let (base, top) = match recipe {
                Recipe::Mixed { types, count } => (draw_kinds(types, *count, &mut rng), vec![]),
                Recipe::Over {
                    top,
                    top_count,
                    base,
                    base_count,
                } => (
                    draw_kinds(base, *base_count, &mut rng),
                    draw_kinds(top, *top_count, &mut rng),
                ),
                Recipe::Decr { .. } => (vec![], vec![]),
            };
            let env = group.layout.environment(group.in_box);
            let scanner = group.layout.random_scanner(&mut rng, points_target);
            let t0 = Instant::now();
            let (pile, settled) =
                build_pile(&models.parts, group.layout, &env, &base, &top, &mut rng)?;
            timing.physics += t0.elapsed().as_secs_f64();
            let id = group.scene_id(index);
            let t0 = Instant::now();
            let mut scene = scan_instances(
                models,
                &env,
                pile.instances(),
                &scanner,
                derive_seed(sseed, "scan", 0),
                &id,
            )?;
            scene.settled = settled;
            records.push(write_scene(root, &id, index, &scene)?);
            timing.scan += t0.elapsed().as_secs_f64();
            done();
        }
        (_, None) => {}
    }
    Ok((records, timing))
}

/// Writes the models (`models/<name>.pcd`, `.stl` and `.json`).
pub fn write_models(root: &Path, models: &ModelLibrary) -> Result<(), SynthError> {
    let dir = root.join("models");
    models
        .models
        .iter()
        .try_for_each(|m| write_model_files(&dir, m))
}

/// Writes one model into `dir`: its top-view cloud (`<name>.pcd`), exact mesh (`.stl`) and
/// evaluator info (`.json`).
pub(crate) fn write_model_files(dir: &Path, m: &Model) -> Result<(), SynthError> {
    write_model_cloud(&dir.join(format!("{}.pcd", m.name)), m)?;
    write_stl(&dir.join(format!("{}.stl", m.name)), &m.mesh)?;
    write_json(&dir.join(format!("{}.json", m.name)), &m.info())?;
    Ok(())
}

const README: &str = "\
Synthetic bin-picking dataset written by binpick-synth (reproduces the datasets of the thesis
\"Robot bin picking: 3D pose retrieval based on Point Cloud Library\", 5.1.2).

Units: millimetres everywhere. Scene frame: z up, belt / floor at z = 0, x across the belt,
y along the scanning motion.

models/<name>.pcd    top view of the part in its canonical resting pose, in the part's frame
                     (noise-free 0.5 x 0.5 mm scan); A-cut / C-cut are crops of A / C
models/<name>.stl    the exact mesh of what the model shows (binary STL, same frame; A-cut /
                     C-cut: the cut portion)
models/<name>.json   {\"diameter\": max point distance, \"symmetries\": [row-major 4x4, ...]}
scenes/<id>.pcd      one simulated dual-laser scan (binary PCD, x y z float32)
gt/<id>__<model>.json  every instance of that model's part in the scene: pose (model -> scene,
                     row-major 4x4), visible_fraction, pickable (visible_fraction >= 0.5),
                     visible_points, alone_points; other parts in the scene are clutter
manifest.json        preset, seed, generator version, groups, per-scene part counts, scanner
                     settings and visibility radius

visible_fraction = share of the model's points that, moved by the true pose, have a scan point
of that same instance (outliers excluded) within the scene's visibility radius
(max(1.5 mm, sqrt((line/2)^2 + (column/2)^2 + (3 sigma)^2))). For models with symmetries
(A-cut, C-cut) the best symmetric equivalent counts and its pose is the one listed.
Instances hidden under others are listed too, with their low visible fraction. A top-view
model makes a part lying upside down look invisible however plainly it shows; for a model
with every side (the mesh), BOP's visible fraction visible_points / alone_points counts: the
scan's points on the instance over the points the same scanner sees of the part alone in the
same pose (`binpick eval --model-file mesh` judges pickability so).
";

#[derive(Serialize)]
struct ModelRecord {
    name: String,
    part: PartKind,
    points: usize,
    diameter_mm: f64,
    symmetries: usize,
}

/// A layout's scanner as recorded in the manifest (speed and noise vary per scene).
#[derive(Serialize)]
struct LayoutScanner {
    fps: f64,
    camera_height_mm: f64,
    laser_offset_mm: f64,
    laser_height_mm: f64,
    x_range_mm: [f64; 2],
    y_range_mm: [f64; 2],
    speed_range_mm_s: [f64; 2],
    noise_sigma_range_mm: [f64; 2],
    outlier_rate: f64,
    min_incidence_cos: f64,
    dual_laser: bool,
    /// Belt-level samples (lines x columns) aimed at; columns = target / lines, 64..=1600.
    points_target: usize,
}

impl LayoutScanner {
    fn new(layout: Layout, points_target: usize) -> Self {
        let c = match layout {
            Layout::Conveyor => ScannerConfig::conveyor(20.0, 0.0, points_target),
            Layout::Arm => ScannerConfig::arm(45.0, 0.0, points_target),
        };
        Self {
            fps: c.fps,
            camera_height_mm: c.camera_height,
            laser_offset_mm: c.laser_offset,
            laser_height_mm: c.laser_height,
            x_range_mm: c.x_range,
            y_range_mm: c.y_range,
            speed_range_mm_s: layout.speed_range(),
            noise_sigma_range_mm: layout.noise_range(),
            outlier_rate: c.outlier_rate,
            min_incidence_cos: c.min_incidence_cos,
            dual_laser: c.dual_laser,
            points_target,
        }
    }
}

#[derive(Serialize)]
struct Manifest<'a> {
    generator: &'static str,
    generator_version: &'static str,
    preset: Preset,
    seed: u64,
    units: &'static str,
    scanner: BTreeMap<&'static str, LayoutScanner>,
    pickable_fraction: f64,
    physics: &'a str,
    models: Vec<ModelRecord>,
    groups: Vec<GroupRecord>,
}

/// Whether `root` is missing, empty, or holds a `manifest.json` written by binpick-synth.
pub(crate) fn is_empty_or_synth_dir(root: &Path) -> Result<bool, SynthError> {
    if !root.exists() {
        return Ok(true);
    }
    let mut entries = std::fs::read_dir(root).map_err(io_err(root))?;
    if entries.next().is_none() {
        return Ok(true);
    }
    let manifest = std::fs::read_to_string(root.join("manifest.json")).unwrap_or_default();
    Ok(manifest.contains("\"generator\": \"binpick-synth\""))
}

/// Creates `root`, or empties a dataset that binpick-synth wrote there before (its `scenes/`,
/// `gt/` and `models/` files, manifest and README), so that no stale scene survives. Refuses a
/// non-empty folder that is not such a dataset.
pub(crate) fn prepare_out_dir(root: &Path) -> Result<(), SynthError> {
    let io = io_err(root);
    if root.exists() {
        if !is_empty_or_synth_dir(root)? {
            return Err(SynthError::InvalidOptions(format!(
                "{} is not empty and holds no binpick-synth dataset; choose an empty folder",
                root.display()
            )));
        }
        let mut entries = std::fs::read_dir(root).map_err(&io)?;
        if entries.next().is_some() {
            for (dir, exts) in [
                ("scenes", &["pcd"][..]),
                ("gt", &["json"][..]),
                ("models", &["pcd", "json", "stl"][..]),
            ] {
                let d = root.join(dir);
                let Ok(list) = std::fs::read_dir(&d) else {
                    continue;
                };
                for e in list {
                    let p = e.map_err(io_err(&d))?.path();
                    if p.extension().is_some_and(|x| exts.iter().any(|e| x == *e)) {
                        std::fs::remove_file(&p).map_err(io_err(&p))?;
                    }
                }
            }
            for f in ["manifest.json", "README.txt"] {
                let p = root.join(f);
                if p.exists() {
                    std::fs::remove_file(&p).map_err(io_err(&p))?;
                }
            }
            // A BOP copy written by binpick-synth (`--bop`).
            let bop = root.join("bop");
            let ours = std::fs::read_to_string(bop.join("README.txt"))
                .is_ok_and(|t| t.contains("written by\nbinpick-synth"));
            if ours {
                std::fs::remove_dir_all(&bop).map_err(io_err(&bop))?;
            }
        }
    }
    std::fs::create_dir_all(root).map_err(io)
}

/// Generates a whole preset into `opts.out_dir`. `progress(done, total)` is called after each
/// scene is written (from worker threads). Same options -> byte-identical files.
pub fn generate(
    opts: &SynthOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Summary, SynthError> {
    let start = Instant::now();
    if opts.points_target == Some(0) {
        return Err(SynthError::InvalidOptions(
            "points_target must be > 0".into(),
        ));
    }
    let root = opts.out_dir.as_path();
    prepare_out_dir(root)?;
    let groups = plan(opts.preset, opts.scenes_per_group);
    let total: usize = groups.iter().map(|g| g.scenes).sum();
    let models = ModelLibrary::build()?;
    write_models(root, &models)?;
    let target = |layout: Layout| {
        opts.points_target
            .unwrap_or_else(|| opts.preset.default_points_target(layout))
    };

    // Jobs: each "-Decr" sequence is one job (sequential by nature), every other scene its own.
    let mut jobs: Vec<(usize, Option<usize>)> = Vec::new();
    for (gi, g) in groups.iter().enumerate() {
        if matches!(g.recipe, Recipe::Decr { .. }) {
            if g.scenes > 0 {
                jobs.push((gi, None));
            }
        } else {
            jobs.extend((0..g.scenes).map(|i| (gi, Some(i))));
        }
    }
    // Longest first: the sequences.
    jobs.sort_by_key(|&(gi, idx)| (idx.is_some(), gi, idx));
    let done = AtomicUsize::new(0);
    let tick = || {
        let d = done.fetch_add(1, Ordering::SeqCst) + 1;
        progress(d, total);
    };
    let results: Vec<Result<JobOutput, SynthError>> = jobs
        .par_iter()
        .map(|&(gi, idx)| {
            let g = &groups[gi];
            let (recs, t) = run_job(&models, root, g, target(g.layout), opts.seed, idx, &tick)?;
            Ok((gi, recs, t))
        })
        .collect();

    let mut per_group: Vec<Vec<SceneRecord>> = groups.iter().map(|_| Vec::new()).collect();
    let mut summary = Summary {
        out_dir: opts.out_dir.clone(),
        scenes: 0,
        gt_files: 0,
        total_points: 0,
        instances: 0,
        pickable: 0,
        elapsed_s: 0.0,
        physics_s: 0.0,
        scan_s: 0.0,
    };
    for r in results {
        let (gi, recs, t) = r?;
        summary.physics_s += t.physics;
        summary.scan_s += t.scan;
        for rec in &recs {
            summary.scenes += 1;
            summary.gt_files += rec.gt.len();
            summary.total_points += rec.points;
            summary.instances += rec.parts.values().sum::<usize>();
            summary.pickable += rec
                .pickable
                .iter()
                .filter(|(m, _)| !m.ends_with("-cut"))
                .map(|(_, n)| n)
                .sum::<usize>();
        }
        per_group[gi].extend(recs);
    }
    let mut group_records = Vec::new();
    for (g, mut recs) in groups.into_iter().zip(per_group) {
        recs.sort_by_key(|r| r.index);
        group_records.push(GroupRecord {
            plan: g,
            scene_records: recs,
        });
    }
    let manifest = Manifest {
        generator: "binpick-synth",
        generator_version: GENERATOR_VERSION,
        preset: opts.preset,
        seed: opts.seed,
        units: "mm",
        scanner: [
            (
                "conveyor",
                LayoutScanner::new(Layout::Conveyor, target(Layout::Conveyor)),
            ),
            ("arm", LayoutScanner::new(Layout::Arm, target(Layout::Arm))),
        ]
        .into_iter()
        .collect(),
        pickable_fraction: PICKABLE_FRACTION,
        physics: "rapier3d 0.36, mm/g/s, dt 1/480 s, CCD, 240/480 Hz contacts, parts dropped one by one inside a \
                  temporary corral (removed before the final settling) or into the bin",
        models: models
            .models
            .iter()
            .map(|m| ModelRecord {
                name: m.name.clone(),
                part: m.part,
                points: m.cloud.len(),
                diameter_mm: m.diameter,
                symmetries: m.symmetries.len(),
            })
            .collect(),
        groups: group_records,
    };
    write_json(&root.join("manifest.json"), &manifest)?;
    std::fs::write(root.join("README.txt"), README).map_err(io_err(root))?;
    summary.elapsed_s = start.elapsed().as_secs_f64();
    Ok(summary)
}
