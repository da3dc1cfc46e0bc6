//! The generalisation benchmark: labelled scans of part families and sensors that nobody
//! tuned binpick for (`binpick synth generalisation --out DIR`).
//!
//! `DIR/manifest.json` lists the sets (sensor, environment, viewpoint, per-scene counts),
//! the generator version and the seed; every `DIR/<set>/` is a regular binpick dataset
//! ([`binpick_cloud::dataset`]) with `models/<name>.pcd` (top view, as for the thesis sets),
//! `models/<name>.stl` (the exact mesh, binary, same frame, mm), `models/<name>.json`
//! (diameter, symmetries, revolution axis), `scenes/` and `gt/`, plus its own `manifest.json`.
//!
//! Ground truth lists every instance of every part family in a scene (one file per model), at
//! its physics pose, with BOP's visible fraction ([`crate::models::ground_truth_alone`]):
//! the scene's points on the instance over the points the same sensor sees of it alone.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;

use binpick_cloud::dataset::{GroundTruth, RevolutionAxis, write_json};

use crate::depth::DepthCameraConfig;
use crate::generate::{
    SceneFiles, build_pile_in, io_err, is_empty_or_synth_dir, prepare_out_dir,
    write_cloud_seen_from, write_ground_truth, write_model_files,
};
use crate::models::{Model, ModelLibrary, PICKABLE_FRACTION, ground_truth_alone};
use crate::parts::PartKind;
use crate::physics::{Environment, Instance, PhysicsSettings};
use crate::rng::{Rng, derive_seed};
use crate::scanner::{FPS, Scan, ScannerConfig, SceneGeometry};
use crate::sensor::{Sensor, Viewpoint};
use crate::{GENERATOR_VERSION, SynthError};

/// Surfaces closer than this count as touching, mm.
pub const TOUCH_MM: f64 = 0.5;

/// Scans per set unless overridden.
pub const DEFAULT_SCENES_PER_SET: usize = 10;

/// Where the parts of a scene are dropped.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum DropZone {
    /// Inside a temporary square corral (removed before the final settling) of half-size
    /// `clamp(base_mm + per_part_mm * parts, min_mm, max_mm)`, centred within `jitter_mm` of
    /// the origin: parts spread over a belt, some touching.
    Corral {
        base_mm: f64,
        per_part_mm: f64,
        min_mm: f64,
        max_mm: f64,
        jitter_mm: f64,
    },
    /// Over a random square patch of half-size `half_mm` inside a bin; with `heap`, inside a
    /// temporary corral around the patch (removed before the final settling), so that the
    /// parts stack into a heap that then slumps, instead of spreading over the floor.
    Patch { half_mm: f64, heap: bool },
}

/// One set of the benchmark.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SetSpec {
    /// Folder name and scene-id prefix.
    pub name: String,
    pub description: String,
    /// The part the set is about (`binpick eval DIR/<set> --model <target>`).
    pub target: PartKind,
    /// Number of target parts per scan (inclusive range).
    pub target_count: [usize; 2],
    /// Part types used as clutter (each clutter part is drawn uniformly among them).
    pub clutter: Vec<PartKind>,
    pub clutter_count: [usize; 2],
    pub sensor: Sensor,
    pub environment: Environment,
    pub drop: DropZone,
    pub scenes: usize,
}

impl SetSpec {
    /// The part types that may appear in the set: the target first, then the clutter.
    pub fn kinds(&self) -> Vec<PartKind> {
        let mut out = vec![self.target];
        for &k in &self.clutter {
            if !out.contains(&k) {
                out.push(k);
            }
        }
        out
    }

    /// The full models of [`SetSpec::kinds`] found in `lib`, in that order.
    pub fn models<'a>(&self, lib: &'a ModelLibrary) -> Vec<&'a Model> {
        self.kinds()
            .iter()
            .filter_map(|k| lib.models.iter().find(|m| m.part == *k && !m.cut))
            .collect()
    }

    /// Scene id of the `index`-th scan.
    pub fn scene_id(&self, index: usize) -> String {
        format!("{}-{index:03}", self.name)
    }
}

/// A dual-laser belt scanner with `spacing_mm` between lines and between columns over
/// `2 x_half_mm` x `2 y_half_mm`, the head `head_height_mm` above the belt with the lasers
/// `laser_offset_mm` either side.
pub fn line_scanner(
    spacing_mm: f64,
    x_half_mm: f64,
    y_half_mm: f64,
    head_height_mm: f64,
    laser_offset_mm: f64,
    noise_sigma_mm: f64,
    outlier_rate: f64,
) -> ScannerConfig {
    ScannerConfig {
        camera_height: head_height_mm,
        laser_offset: laser_offset_mm,
        laser_height: head_height_mm,
        x_range: [-x_half_mm, x_half_mm],
        y_range: [-y_half_mm, y_half_mm],
        speed: spacing_mm * FPS,
        fps: FPS,
        columns: (2.0 * x_half_mm / spacing_mm).round() as usize,
        noise_sigma: noise_sigma_mm,
        outlier_rate,
        min_incidence_cos: 0.1,
        dual_laser: true,
    }
}

/// The benchmark's structured-light camera: 640 x 480 pixels, 800 mm above the floor looking
/// down (about 0.69 mm per pixel at the floor, 440 x 330 mm in view), projector 100 mm
/// beside it along x, depth noise 1 mm at 1 m (0.64 mm at the floor).
pub fn depth_camera() -> DepthCameraConfig {
    DepthCameraConfig {
        position: [0.0, 0.0, 800.0],
        width: 640,
        height: 480,
        focal_px: 1160.0,
        projector_offset: [100.0, 0.0, 0.0],
        noise_sigma_at_1m: 1.0,
        outlier_rate: 0.001,
        min_incidence_cos: 0.1,
    }
}

/// The sets, each with `scenes_per_set` scans (default [`DEFAULT_SCENES_PER_SET`]).
pub fn generalisation_sets(scenes_per_set: Option<usize>) -> Vec<SetSpec> {
    use PartKind::{A, B, Bracket, C, Plate, Ring, Rod, Shaft};
    let scenes = scenes_per_set.unwrap_or(DEFAULT_SCENES_PER_SET);
    // Belt at 1 mm: a 600 mm wide belt scanned over 780 mm (about 470 k points).
    let belt_1mm = Sensor::LaserLine(line_scanner(1.0, 300.0, 390.0, 600.0, 240.0, 0.15, 0.001));
    let belt_1mm_env = Environment::Flat {
        size: [1000.0, 1000.0],
    };
    // Belt at 0.5 mm: the thesis's conveyor head over 260 x 260 mm (about 270 k points).
    let belt_05mm = Sensor::LaserLine(line_scanner(0.5, 130.0, 130.0, 400.0, 160.0, 0.1, 0.001));
    let belt_05mm_env = Environment::Flat {
        size: [600.0, 600.0],
    };
    // Bin at 2 mm: the arm's head over 400 x 400 mm, noisier (about 45 k points).
    let bin_2mm = Sensor::LaserLine(line_scanner(2.0, 200.0, 200.0, 600.0, 220.0, 0.6, 0.005));
    let bin_2mm_env = Environment::Bin {
        floor_size: [800.0, 800.0],
        inner: [300.0, 300.0],
        wall_height: 100.0,
        wall_thickness: 10.0,
    };
    let depth = Sensor::DepthCamera(depth_camera());
    let depth_env = Environment::Bin {
        floor_size: [1200.0, 1200.0],
        inner: [260.0, 260.0],
        wall_height: 80.0,
        wall_thickness: 10.0,
    };
    let belt_corral = |min_mm: f64, max_mm: f64, jitter_mm: f64| DropZone::Corral {
        base_mm: 40.0,
        per_part_mm: 12.0,
        min_mm,
        max_mm,
        jitter_mm,
    };
    let pile = DropZone::Patch {
        half_mm: 60.0,
        heap: true,
    };
    let set = |name: &str,
               description: &str,
               target: PartKind,
               target_count: [usize; 2],
               clutter: &[PartKind],
               clutter_count: [usize; 2],
               sensor: &Sensor,
               environment: &Environment,
               drop: DropZone| SetSpec {
        name: name.into(),
        description: description.into(),
        target,
        target_count,
        clutter: clutter.to_vec(),
        clutter_count,
        sensor: sensor.clone(),
        environment: environment.clone(),
        drop,
        scenes,
    };
    vec![
        set(
            "brackets-belt-1mm",
            "3-8 Z brackets spread on a belt, some touching; 1 mm line and column spacing",
            Bracket,
            [3, 8],
            &[],
            [0, 0],
            &belt_1mm,
            &belt_1mm_env,
            belt_corral(80.0, 150.0, 100.0),
        ),
        set(
            "brackets-belt-0.5mm",
            "3-8 Z brackets on a belt, some touching; 0.5 mm spacing",
            Bracket,
            [3, 8],
            &[],
            [0, 0],
            &belt_05mm,
            &belt_05mm_env,
            belt_corral(80.0, 105.0, 15.0),
        ),
        set(
            "brackets-bin-2mm",
            "6-12 Z brackets piled in a walled bin; 2 mm spacing, 0.6 mm noise",
            Bracket,
            [6, 12],
            &[],
            [0, 0],
            &bin_2mm,
            &bin_2mm_env,
            pile.clone(),
        ),
        set(
            "rods-bin-2mm",
            "5-15 bent round rods piled in a walled bin; 2 mm spacing, 0.6 mm noise",
            Rod,
            [5, 15],
            &[],
            [0, 0],
            &bin_2mm,
            &bin_2mm_env,
            pile.clone(),
        ),
        set(
            "shafts-bin-2mm",
            "5-15 stepped shafts piled in a walled bin; 2 mm spacing, 0.6 mm noise",
            Shaft,
            [5, 15],
            &[],
            [0, 0],
            &bin_2mm,
            &bin_2mm_env,
            pile.clone(),
        ),
        set(
            "rings-bin-depth",
            "10 flat rings in a walled bin seen by a structured-light depth camera 800 mm above",
            Ring,
            [10, 10],
            &[],
            [0, 0],
            &depth,
            &depth_env,
            DropZone::Patch {
                half_mm: 60.0,
                heap: true,
            },
        ),
        set(
            "plates-belt-clutter-1mm",
            "2-4 bent plates among 3-6 other parts (thesis A/B/C and the other families) on a \
             belt; 1 mm spacing",
            Plate,
            [2, 4],
            &[A, B, C, Bracket, Rod, Shaft, Ring],
            [3, 6],
            &belt_1mm,
            &belt_1mm_env,
            DropZone::Corral {
                base_mm: 50.0,
                per_part_mm: 12.0,
                min_mm: 100.0,
                max_mm: 170.0,
                jitter_mm: 80.0,
            },
        ),
        set(
            "brackets-bin-depth",
            "6-10 Z brackets piled in a walled bin seen by the depth camera",
            Bracket,
            [6, 10],
            &[],
            [0, 0],
            &depth,
            &depth_env,
            DropZone::Patch {
                half_mm: 60.0,
                heap: true,
            },
        ),
        set(
            "mixed-bin-clutter-2mm",
            "2-4 bent plates among 5-8 other parts piled in a walled bin; 2 mm spacing, 0.6 mm noise",
            Plate,
            [2, 4],
            &[A, C, Bracket, Rod, Shaft, Ring],
            [5, 8],
            &bin_2mm,
            &bin_2mm_env,
            DropZone::Patch {
                half_mm: 80.0,
                heap: true,
            },
        ),
    ]
}

/// Options of [`generate_generalisation`].
#[derive(Clone, Debug, PartialEq)]
pub struct BenchmarkOptions {
    /// Benchmark root (created if missing; an earlier benchmark there is replaced).
    pub out_dir: PathBuf,
    pub seed: u64,
    /// Scans per set instead of [`DEFAULT_SCENES_PER_SET`].
    pub scenes_per_set: Option<usize>,
    /// Only these sets (by name); empty = all. A set's scans do not depend on which others
    /// are generated.
    pub sets: Vec<String>,
    /// Also write every depth-camera set in BOP's format under `<set>/bop/` ([`crate::bop`]).
    pub bop: bool,
}

/// What one set holds, for the summary and the manifest.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SetSummary {
    pub name: String,
    pub target_model: String,
    /// `laser_line` or `depth_camera`.
    pub sensor: String,
    /// `flat` (belt) or `bin`.
    pub environment: String,
    pub sample_spacing_mm: f64,
    pub scenes: usize,
    /// Smallest and largest number of parts (all kinds) in a scan.
    pub parts_per_scan: [usize; 2],
    /// Smallest, mean and largest number of points of a scan.
    pub points_per_scan: [usize; 3],
    pub target_instances: usize,
    /// Target instances with a visible fraction >= 0.5.
    pub target_pickable: usize,
    /// Target instances lying upside down (their canonical up side facing down).
    pub target_upside_down: usize,
    /// Scans in which some parts touch (surfaces within [`TOUCH_MM`]).
    pub scans_with_touching_parts: usize,
    /// Scans in which the physics did not come to rest before its time cap.
    pub unsettled: usize,
}

/// What [`generate_generalisation`] did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BenchmarkSummary {
    pub out_dir: PathBuf,
    pub sets: Vec<SetSummary>,
    pub scenes: usize,
    /// Wall-clock time, s.
    pub elapsed_s: f64,
    /// Summed over worker threads: physics, and scanning + ground truth, s.
    pub physics_s: f64,
    pub scan_s: f64,
}

/// One scan's record in the manifest.
#[derive(Clone, Debug, Serialize)]
struct SceneRecord {
    id: String,
    index: usize,
    parts: BTreeMap<String, usize>,
    points: usize,
    settled: bool,
    /// Pairs of parts whose surfaces are within 0.5 mm.
    touching_pairs: usize,
    gt: Vec<String>,
    /// Pickable instances per model.
    pickable: BTreeMap<String, usize>,
    /// Target instances whose canonical up side faces down.
    target_upside_down: usize,
    /// Seed of the scan's random streams (the alone scans of the ground truth use it too).
    scan_seed: u64,
}

#[derive(Clone, Serialize)]
struct SensorSummary {
    kind: &'static str,
    sample_spacing_mm: f64,
    noise_sigma_at_floor_mm: f64,
}

#[derive(Clone, Serialize)]
struct SetRecord<'a> {
    name: &'a str,
    description: &'a str,
    dir: &'a str,
    target_model: &'static str,
    models: Vec<&'static str>,
    target_count: [usize; 2],
    clutter: Vec<&'static str>,
    clutter_count: [usize; 2],
    sensor_summary: SensorSummary,
    sensor: &'a Sensor,
    viewpoint: Viewpoint,
    environment: &'a Environment,
    drop: &'a DropZone,
    summary: &'a SetSummary,
    scenes: &'a [SceneRecord],
}

#[derive(Serialize)]
struct ModelRecord {
    name: String,
    points: usize,
    diameter_mm: f64,
    symmetries: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    revolution_axis: Option<RevolutionAxis>,
    mesh_triangles: usize,
    mesh_volume_mm3: f64,
}

#[derive(Serialize)]
struct Manifest<'a> {
    generator: &'static str,
    generator_version: &'static str,
    preset: &'static str,
    seed: u64,
    units: &'static str,
    pickable_fraction: f64,
    visible_fraction: &'static str,
    physics: &'static str,
    models: Vec<ModelRecord>,
    sets: Vec<SetRecord<'a>>,
}

const VISIBLE_FRACTION_RULE: &str = "BOP visib_fract: scene points on the instance's own surface \
     (outliers excluded) / points the same sensor (same sample positions, same random streams) \
     sees of that part alone in the same pose; capped at 1";

const PHYSICS: &str = "rapier3d 0.36, mm/g/s, dt 1/480 s, CCD, 240/480 Hz contacts; colliders \
     are compounds of convex pieces of the exact meshes; parts dropped one by one from random \
     orientations inside a temporary corral (belt) or over a patch of the bin";

const README: &str = "\
Generalisation benchmark written by binpick-synth: part families and sensors nobody tuned for.

Units: millimetres everywhere. Scene frame: z up, belt / bin floor at z = 0.

manifest.json        seed, generator version, and per set: target model, sensor settings,
                     viewpoint (camera position and orientation, also as a PCD VIEWPOINT
                     line; a line scanner's sweep), environment, drop zone, per-scan counts
<set>/               a regular binpick dataset: `binpick eval <set> --model <target>`
  models/<name>.pcd  top view of the part in its canonical resting pose, part frame
  models/<name>.stl  the part's exact mesh (binary STL), same frame
  models/<name>.json diameter, symmetries (identity first; continuous symmetries sampled
                     every 5 deg) and, for solids of revolution, revolution_axis
  scenes/<id>.pcd    one scan (binary PCD x y z float32; pixels / samples without a reading
                     are left out)
  gt/<id>__<model>.json  every instance of that model's part in the scan: pose (model ->
                     scene), visible_fraction, pickable (>= 0.5), visible_points, alone_points;
                     other parts in the scan are clutter
  manifest.json      this set's record

visible_fraction = BOP's visib_fract: the scan's points on the instance's own surface divided by
the points the same sensor sees of that part alone in the same pose (so a part lying upside down
is as visible as the scan shows it).
";

/// One scan of a set, in memory.
#[derive(Clone, Debug)]
pub struct SetScene {
    /// `<set>-<index>`; the ground truth's scene paths are `scenes/<id>.pcd`.
    pub id: String,
    pub instances: Vec<Instance>,
    pub scan: Scan,
    /// One per model of the set whose part is in the scan.
    pub gt: Vec<GroundTruth>,
    /// Whether the physics came to rest before its time cap.
    pub settled: bool,
    /// Pairs of parts whose surfaces are within [`TOUCH_MM`] of each other.
    pub touching_pairs: usize,
    /// Seed of the scan's random streams (the alone scans of the ground truth use it too).
    pub scan_seed: u64,
    /// Time in physics and in scanning + ground truth, s.
    pub physics_s: f64,
    pub scan_s: f64,
}

/// Scan `index` of `set`, end to end: parts drawn and dropped, scanned, labelled with BOP's
/// visible fraction for every model of `models` whose part is present. Deterministic in
/// (`seed`, set name, `index`), whatever the thread count.
pub fn make_set_scene(
    lib: &ModelLibrary,
    models: &[&Model],
    set: &SetSpec,
    seed: u64,
    index: usize,
) -> Result<SetScene, SynthError> {
    let sseed = derive_seed(seed, &set.name, index as u64);
    let mut rng = Rng::new(sseed);
    let n_target = rng.int_inclusive(set.target_count[0], set.target_count[1]);
    let n_clutter = if set.clutter.is_empty() {
        0
    } else {
        rng.int_inclusive(set.clutter_count[0], set.clutter_count[1])
    };
    let mut kinds = vec![set.target; n_target];
    for _ in 0..n_clutter {
        kinds.push(set.clutter[rng.int_inclusive(0, set.clutter.len() - 1)]);
    }
    for i in (1..kinds.len()).rev() {
        let j = rng.int_inclusive(0, i);
        kinds.swap(i, j);
    }
    let (corral, area) = drop_area(&set.drop, &set.environment, kinds.len(), &mut rng);
    let t0 = Instant::now();
    let (pile, settled) = build_pile_in(
        &lib.parts,
        &set.environment,
        corral,
        area,
        &kinds,
        &[],
        &mut rng,
        PhysicsSettings::default(),
    )?;
    let instances = pile.instances();
    let touching_pairs = pile.touching_pairs(TOUCH_MM).len();
    let physics_s = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let id = set.scene_id(index);
    let geom = SceneGeometry::from_scene(&set.environment, &instances, &lib.parts)?;
    let scan_seed = derive_seed(sseed, "scan", 0);
    let scan = set.sensor.scan(&geom, scan_seed);
    let gt = ground_truth_alone(
        &format!("scenes/{id}.pcd"),
        &instances,
        &scan,
        &set.sensor,
        scan_seed,
        &lib.parts,
        models,
    )?;
    Ok(SetScene {
        id,
        instances,
        scan,
        gt,
        settled,
        touching_pairs,
        scan_seed,
        physics_s,
        scan_s: t0.elapsed().as_secs_f64(),
    })
}

/// Makes scan `index` of `set` and writes it and its ground truth under `root` (the set's
/// folder); returns its manifest record and timings.
fn run_scene(
    lib: &ModelLibrary,
    set_models: &[&Model],
    set: &SetSpec,
    root: &Path,
    seed: u64,
    index: usize,
    bop: bool,
) -> Result<(SceneRecord, f64, f64, Option<crate::bop::ImageRecords>), SynthError> {
    let scene = make_set_scene(lib, set_models, set, seed, index)?;
    let t0 = Instant::now();
    let id = &scene.id;
    let bop_records = match (&set.sensor, bop) {
        (crate::sensor::Sensor::DepthCamera(cam), true) => Some(crate::bop::write_image(
            &root.join("bop"),
            cam,
            &scene,
            index as u32,
            set_models,
        )?),
        _ => None,
    };
    // A depth camera's scan records where the camera was; a line scanner's keeps PCL's
    // default (its rays are parallel along the sweep: "above" is the better description).
    let viewpoint = match &set.sensor {
        crate::sensor::Sensor::DepthCamera(_) => {
            let v = set.sensor.viewpoint();
            binpick_cloud::io::Viewpoint {
                position: v.position_mm,
                orientation_wxyz: v.orientation_wxyz,
            }
        }
        crate::sensor::Sensor::LaserLine(_) => binpick_cloud::io::Viewpoint::default(),
    };
    write_cloud_seen_from(
        &root.join("scenes").join(format!("{id}.pcd")),
        &scene.scan.cloud,
        &viewpoint,
    )?;
    let SceneFiles {
        gt_ids,
        pickable,
        parts,
    } = write_ground_truth(root, id, &scene.gt, &scene.instances)?;
    let up = lib.parts.get(set.target).canonical_up;
    let target_upside_down = scene
        .instances
        .iter()
        .filter(|i| i.kind == set.target && (i.pose.rotation * up).dot(&Vector3::z()) < 0.0)
        .count();
    let record = SceneRecord {
        id: scene.id.clone(),
        index,
        parts,
        points: scene.scan.cloud.len(),
        settled: scene.settled,
        touching_pairs: scene.touching_pairs,
        gt: gt_ids,
        pickable,
        target_upside_down,
        scan_seed: scene.scan_seed,
    };
    let write_s = t0.elapsed().as_secs_f64();
    Ok((record, scene.physics_s, scene.scan_s + write_s, bop_records))
}

/// The corral (if any) and the drop area (`[xmin, xmax, ymin, ymax]`) for `parts` parts.
fn drop_area(
    drop: &DropZone,
    env: &Environment,
    parts: usize,
    rng: &mut Rng,
) -> (Option<[f64; 4]>, [f64; 4]) {
    match *drop {
        DropZone::Corral {
            base_mm,
            per_part_mm,
            min_mm,
            max_mm,
            jitter_mm,
        } => {
            let half = (base_mm + per_part_mm * parts as f64).clamp(min_mm, max_mm);
            let cx = rng.range(-jitter_mm, jitter_mm);
            let cy = rng.range(-jitter_mm, jitter_mm);
            let corral = [cx - half, cx + half, cy - half, cy + half];
            let m = 2.0;
            (
                Some(corral),
                [corral[0] + m, corral[1] - m, corral[2] + m, corral[3] - m],
            )
        }
        DropZone::Patch { half_mm, heap } => {
            let [hx, hy] = env.inner_half_extents();
            let half = half_mm.min(hx).min(hy);
            let cx = rng.range(-(hx - half), hx - half);
            let cy = rng.range(-(hy - half), hy - half);
            let m = 5.0;
            let area = [
                (cx - half).max(-hx + m),
                (cx + half).min(hx - m),
                (cy - half).max(-hy + m),
                (cy + half).min(hy - m),
            ];
            let corral = heap.then_some([area[0] - m, area[1] + m, area[2] - m, area[3] + m]);
            (corral, area)
        }
    }
}

/// Writes a set's models: top-view cloud, exact mesh and evaluator info.
fn write_set_models(root: &Path, models: &[&Model]) -> Result<(), SynthError> {
    let dir = root.join("models");
    models.iter().try_for_each(|m| write_model_files(&dir, m))
}

fn summarise(set: &SetSpec, records: &[SceneRecord]) -> SetSummary {
    let target = set.target.name();
    let parts: Vec<usize> = records.iter().map(|r| r.parts.values().sum()).collect();
    let points: Vec<usize> = records.iter().map(|r| r.points).collect();
    let mean = if points.is_empty() {
        0
    } else {
        points.iter().sum::<usize>() / points.len()
    };
    SetSummary {
        name: set.name.clone(),
        target_model: target.to_owned(),
        sensor: set.sensor.kind().to_owned(),
        environment: match set.environment {
            Environment::Flat { .. } => "flat".into(),
            Environment::Bin { .. } => "bin".into(),
        },
        sample_spacing_mm: set.sensor.sample_spacing_mm(),
        scenes: records.len(),
        parts_per_scan: [
            parts.iter().copied().min().unwrap_or(0),
            parts.iter().copied().max().unwrap_or(0),
        ],
        points_per_scan: [
            points.iter().copied().min().unwrap_or(0),
            mean,
            points.iter().copied().max().unwrap_or(0),
        ],
        target_instances: records
            .iter()
            .map(|r| r.parts.get(target).copied().unwrap_or(0))
            .sum(),
        target_pickable: records
            .iter()
            .map(|r| r.pickable.get(target).copied().unwrap_or(0))
            .sum(),
        target_upside_down: records.iter().map(|r| r.target_upside_down).sum(),
        scans_with_touching_parts: records.iter().filter(|r| r.touching_pairs > 0).count(),
        unsettled: records.iter().filter(|r| !r.settled).count(),
    }
}

/// Generates the benchmark into `opts.out_dir`. `progress(done, total)` is called after each
/// scan is written (from worker threads). Same options -> byte-identical files, whatever the
/// thread count.
pub fn generate_generalisation(
    opts: &BenchmarkOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<BenchmarkSummary, SynthError> {
    let start = Instant::now();
    let root = opts.out_dir.as_path();
    let mut sets = generalisation_sets(opts.scenes_per_set);
    if !opts.sets.is_empty() {
        if let Some(unknown) = opts
            .sets
            .iter()
            .find(|n| !sets.iter().any(|s| &s.name == *n))
        {
            return Err(SynthError::InvalidOptions(format!(
                "no set named {unknown:?}; the sets are {}",
                sets.iter()
                    .map(|s| s.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        }
        sets.retain(|s| opts.sets.contains(&s.name));
    }
    // Refuse a foreign folder before deleting anything.
    let foreign = std::iter::once(root.to_owned())
        .chain(sets.iter().map(|s| root.join(&s.name)))
        .find(|d| !matches!(is_empty_or_synth_dir(d), Ok(true)));
    if let Some(dir) = foreign {
        return Err(SynthError::InvalidOptions(format!(
            "{} is not empty and holds no binpick-synth dataset; choose an empty folder",
            dir.display()
        )));
    }
    prepare_out_dir(root)?;
    for s in &sets {
        prepare_out_dir(&root.join(&s.name))?;
    }

    let mut kinds: Vec<PartKind> = Vec::new();
    for k in sets.iter().flat_map(SetSpec::kinds) {
        if !kinds.contains(&k) {
            kinds.push(k);
        }
    }
    kinds.sort();
    let lib = ModelLibrary::build_for(&kinds, false)?;
    let set_models: Vec<Vec<&Model>> = sets.iter().map(|s| s.models(&lib)).collect();
    for (s, models) in sets.iter().zip(&set_models) {
        write_set_models(&root.join(&s.name), models)?;
        if opts.bop && matches!(s.sensor, Sensor::DepthCamera(_)) {
            let bop_root = root.join(&s.name).join("bop");
            crate::bop::write_models(&bop_root, models)?;
            std::fs::write(bop_root.join("README.txt"), crate::bop::README)
                .map_err(io_err(&bop_root))?;
        }
    }

    let jobs: Vec<(usize, usize)> = sets
        .iter()
        .enumerate()
        .flat_map(|(si, s)| (0..s.scenes).map(move |i| (si, i)))
        .collect();
    let total = jobs.len();
    let done = AtomicUsize::new(0);
    type JobResult = (
        usize,
        SceneRecord,
        f64,
        f64,
        Option<crate::bop::ImageRecords>,
    );
    let results: Vec<Result<JobResult, SynthError>> = jobs
        .par_iter()
        .map(|&(si, index)| {
            let set = &sets[si];
            let (rec, physics_s, scan_s, bop) = run_scene(
                &lib,
                &set_models[si],
                set,
                &root.join(&set.name),
                opts.seed,
                index,
                opts.bop,
            )?;
            let d = done.fetch_add(1, Ordering::SeqCst) + 1;
            progress(d, total);
            Ok((si, rec, physics_s, scan_s, bop))
        })
        .collect();
    let mut per_set: Vec<Vec<SceneRecord>> = sets.iter().map(|_| Vec::new()).collect();
    let mut bop_images: Vec<Vec<crate::bop::ImageRecords>> =
        sets.iter().map(|_| Vec::new()).collect();
    let (mut physics_s, mut scan_s) = (0.0, 0.0);
    for r in results {
        let (si, rec, p, s, bop) = r?;
        physics_s += p;
        scan_s += s;
        per_set[si].push(rec);
        bop_images[si].extend(bop);
    }
    for (s, images) in sets.iter().zip(&mut bop_images) {
        if !images.is_empty() {
            images.sort_by_key(|i| i.im_id);
            crate::bop::write_scene_files(&root.join(&s.name).join("bop"), images)?;
        }
    }
    for recs in &mut per_set {
        recs.sort_by_key(|r| r.index);
    }
    let summaries: Vec<SetSummary> = sets
        .iter()
        .zip(&per_set)
        .map(|(s, recs)| summarise(s, recs))
        .collect();
    let set_records: Vec<SetRecord<'_>> = sets
        .iter()
        .zip(&per_set)
        .zip(&summaries)
        .map(|((s, recs), summary)| SetRecord {
            name: &s.name,
            description: &s.description,
            dir: &s.name,
            target_model: s.target.name(),
            models: s.kinds().iter().map(|k| k.name()).collect(),
            target_count: s.target_count,
            clutter: s.clutter.iter().map(|k| k.name()).collect(),
            clutter_count: s.clutter_count,
            sensor_summary: SensorSummary {
                kind: s.sensor.kind(),
                sample_spacing_mm: s.sensor.sample_spacing_mm(),
                noise_sigma_at_floor_mm: s.sensor.noise_sigma_mm(),
            },
            sensor: &s.sensor,
            viewpoint: s.sensor.viewpoint(),
            environment: &s.environment,
            drop: &s.drop,
            summary,
            scenes: recs,
        })
        .collect();
    let model_records = |models: &mut dyn Iterator<Item = &Model>| -> Vec<ModelRecord> {
        models
            .map(|m| {
                let info = m.info();
                ModelRecord {
                    name: m.name.clone(),
                    points: m.cloud.len(),
                    diameter_mm: m.diameter,
                    symmetries: m.symmetries.len(),
                    revolution_axis: info.revolution_axis,
                    mesh_triangles: m.mesh.triangles.len(),
                    mesh_volume_mm3: (m.mesh.volume() * 10.0).round() / 10.0,
                }
            })
            .collect()
    };
    for ((s, rec), models) in sets.iter().zip(&set_records).zip(&set_models) {
        let manifest = Manifest {
            generator: "binpick-synth",
            generator_version: GENERATOR_VERSION,
            preset: "generalisation",
            seed: opts.seed,
            units: "mm",
            pickable_fraction: PICKABLE_FRACTION,
            visible_fraction: VISIBLE_FRACTION_RULE,
            physics: PHYSICS,
            models: model_records(&mut models.iter().copied()),
            sets: vec![rec.clone()],
        };
        write_json(&root.join(&s.name).join("manifest.json"), &manifest)?;
    }
    let manifest = Manifest {
        generator: "binpick-synth",
        generator_version: GENERATOR_VERSION,
        preset: "generalisation",
        seed: opts.seed,
        units: "mm",
        pickable_fraction: PICKABLE_FRACTION,
        visible_fraction: VISIBLE_FRACTION_RULE,
        physics: PHYSICS,
        models: model_records(&mut lib.models.iter()),
        sets: set_records,
    };
    write_json(&root.join("manifest.json"), &manifest)?;
    std::fs::write(root.join("README.txt"), README).map_err(io_err(root))?;
    Ok(BenchmarkSummary {
        out_dir: opts.out_dir.clone(),
        scenes: summaries.iter().map(|s| s.scenes).sum(),
        sets: summaries,
        elapsed_s: start.elapsed().as_secs_f64(),
        physics_s,
        scan_s,
    })
}
