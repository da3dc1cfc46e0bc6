//! The generalisation benchmark: part families (meshes, true symmetries), the depth camera,
//! BOP's visible fraction, determinism and the written layout.

// Test helpers outside #[test] functions may fail loudly too.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::OnceLock;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use binpick_cloud::dataset::{Dataset, GroundTruth, IDENTITY, ModelInfo};
use binpick_cloud::{pose_to_row_major, transform_point};
use binpick_synth::generalisation::{depth_camera, line_scanner};
use binpick_synth::mesh::{Mesh, distance_to_mesh};
use binpick_synth::models::{ScanIndex, alone_visibility, instance_visibility};
use binpick_synth::parts::half_turn_about;
use binpick_synth::physics::PhysicsSettings;
use binpick_synth::rng::Rng;
use binpick_synth::{
    BenchmarkOptions, Environment, Instance, ModelLibrary, OUTLIER, PartKind, Scan, SceneGeometry,
    Sensor, generalisation_sets, generate_generalisation, make_set_scene,
};

fn lib() -> &'static ModelLibrary {
    static LIB: OnceLock<ModelLibrary> = OnceLock::new();
    LIB.get_or_init(|| ModelLibrary::build_for(&PartKind::ALL, false).expect("model library"))
}

/// The mesh as stl_io's indexed mesh (through a binary STL written and read back, which
/// merges coincident vertices), so that its own closedness check can run.
fn stl_round_trip(mesh: &Mesh) -> stl_io::IndexedMesh {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.stl");
    binpick_synth::generate::write_stl(&path, mesh).unwrap();
    let mut file = std::fs::File::open(&path).unwrap();
    stl_io::read_stl(&mut file).unwrap()
}

fn worst_move(mesh: &Mesh, motion: &Isometry3<f64>, samples: &[[f32; 3]]) -> f64 {
    let parry = mesh.to_parry().unwrap();
    samples
        .iter()
        .map(|p| distance_to_mesh(&parry, &transform_point(motion, p)))
        .fold(0.0, f64::max)
}

#[test]
fn every_part_mesh_is_closed_outward_and_the_size_asked_for() {
    let lib = lib();
    for kind in PartKind::ALL {
        let part = lib.parts.get(kind);
        let indexed = stl_round_trip(&part.mesh);
        indexed
            .validate()
            .unwrap_or_else(|e| panic!("{kind}: mesh not closed / consistently oriented: {e}"));
        assert_eq!(indexed.faces.len(), part.mesh.triangles.len(), "{kind}");
        assert!(part.volume() > 0.0, "{kind}: inward-facing mesh");
        assert!(!part.hulls.is_empty(), "{kind}");
    }
    let size = |k: PartKind| part_size(&lib.parts.get(k).mesh);
    let vol = |k: PartKind| lib.parts.get(k).volume();
    // Z bracket: 2 mm sheet, 40 mm wide, flanges 30 / 35 mm, web 26 mm, bends r 2 mm.
    let b = size(PartKind::Bracket);
    assert!(
        b[0] > 60.0 && b[0] < 80.0 && (b[1] - 40.0).abs() < 1e-3,
        "{b:?}"
    );
    let sheet_len = 30.0 + 26.0 + 35.0 + 2.0 * std::f64::consts::FRAC_PI_2 * 3.0;
    assert!((vol(PartKind::Bracket) - 2.0 * 40.0 * sheet_len).abs() < 0.005 * 8000.0);
    // Rod: 7 mm diameter, 100-150 mm of centre line.
    let r = size(PartKind::Rod);
    assert!((r[2] - 7.0).abs() < 1e-3, "{r:?}");
    let rod_len = vol(PartKind::Rod) / (std::f64::consts::PI * 3.5 * 3.5);
    assert!(rod_len > 100.0 && rod_len < 150.0, "{rod_len}");
    // Shaft: 20 / 14 / 10 mm over 35 / 25 / 20 mm; ring 50 / 28 / 4 mm (72 facets: the
    // polygon's area is 0.9987 of the circle's).
    let s = size(PartKind::Shaft);
    assert!(
        (s[0] - 20.0).abs() < 1e-3 && (s[2] - 80.0).abs() < 1e-3,
        "{s:?}"
    );
    let shaft = std::f64::consts::PI * (100.0 * 35.0 + 49.0 * 25.0 + 25.0 * 20.0);
    assert!((vol(PartKind::Shaft) / shaft - 0.9987).abs() < 1e-3);
    let ring = std::f64::consts::PI * (625.0 - 196.0) * 4.0;
    assert!((vol(PartKind::Ring) / ring - 0.9987).abs() < 1e-3);
    // Plate: 80 x 50 x 3 mm.
    assert!((vol(PartKind::Plate) - 80.0 * 50.0 * 3.0).abs() < 0.005 * 12_000.0);
}

fn part_size(mesh: &Mesh) -> [f64; 3] {
    let b = mesh.bounds().unwrap();
    [0, 1, 2].map(|k| f64::from(b.max[k] - b.min[k]))
}

#[test]
fn declared_symmetries_map_each_part_onto_itself_and_nothing_else_does() {
    let lib = lib();
    for kind in PartKind::FAMILIES {
        let part = lib.parts.get(kind);
        let samples = part.mesh.sample_surface(1500, &mut Rng::new(5));
        let syms = part.symmetries();
        assert_eq!(pose_to_row_major(&syms[0]), IDENTITY, "{kind}");
        let expected = match kind {
            PartKind::Shaft => 72,
            PartKind::Ring => 144,
            _ => 1,
        };
        assert_eq!(syms.len(), expected, "{kind}");
        for (i, s) in syms.iter().enumerate() {
            let worst = worst_move(&part.mesh, s, &samples);
            assert!(
                worst < 0.01,
                "{kind}: symmetry {i} moves the surface {worst} mm"
            );
        }
        // The half turns about the principal axes through the centre are no symmetry,
        // except those declared (the ring's flip).
        for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
            let turn = half_turn_about(&Point3::origin(), &axis);
            let declared = syms
                .iter()
                .any(|s| (s.to_homogeneous() - turn.to_homogeneous()).norm() < 1e-6);
            let worst = worst_move(&part.mesh, &turn, &samples);
            if declared {
                assert!(worst < 0.01, "{kind}");
            } else {
                assert!(
                    worst > 2.0,
                    "{kind}: undeclared half turn about {axis:?}: {worst} mm"
                );
            }
        }
    }
    // The bracket's trap: the half turn about its web's axis swaps flanges 5 mm apart.
    let bracket = lib.parts.get(PartKind::Bracket);
    let near = bracket.near_symmetries();
    assert_eq!(near.len(), 1);
    let samples = bracket.mesh.sample_surface(3000, &mut Rng::new(6));
    let worst = worst_move(&bracket.mesh, &near[0], &samples);
    assert!(worst > 4.0 && worst < 6.0, "{worst}");
    // ... while most of the part does map onto itself (it is almost point-symmetric).
    let parry = bracket.mesh.to_parry().unwrap();
    let on = samples
        .iter()
        .filter(|p| distance_to_mesh(&parry, &transform_point(&near[0], p)) < 0.01)
        .count();
    assert!(on as f64 > 0.8 * samples.len() as f64, "{on}");
    // Model info: the solids of revolution declare their axis.
    for kind in PartKind::FAMILIES {
        let info = lib.model(kind.name()).unwrap().info();
        let axis = info.revolution_axis.clone();
        match kind {
            PartKind::Shaft | PartKind::Ring => {
                let a = axis.unwrap();
                assert_eq!(a.direction, [0.0, 0.0, 1.0], "{kind}");
                assert!(
                    a.point.iter().all(|v| v.abs() < 1e-3),
                    "{kind}: {:?}",
                    a.point
                );
            }
            _ => assert!(axis.is_none(), "{kind}"),
        }
    }
}

fn belt_1mm(outliers: f64) -> Sensor {
    Sensor::LaserLine(line_scanner(
        1.0, 150.0, 150.0, 600.0, 240.0, 0.15, outliers,
    ))
}

fn depth(outliers: f64) -> Sensor {
    let mut c = depth_camera();
    c.outlier_rate = outliers;
    Sensor::DepthCamera(c)
}

/// The benchmark's camera at half the resolution (fewer rays, same geometry).
fn coarse_depth(outliers: f64) -> Sensor {
    let mut c = depth_camera();
    c.outlier_rate = outliers;
    c.width /= 2;
    c.height /= 2;
    c.focal_px /= 2.0;
    Sensor::DepthCamera(c)
}

fn belt() -> Environment {
    Environment::Flat {
        size: [1200.0, 1200.0],
    }
}

fn scene_scan(env: &Environment, inst: &[Instance], sensor: &Sensor, seed: u64) -> Scan {
    let geom = SceneGeometry::from_scene(env, inst, &lib().parts).unwrap();
    sensor.scan(&geom, seed)
}

/// `pose` moved so that the part's lowest point is `z` mm above the belt, at (x, y).
fn resting(kind: PartKind, rot: UnitQuaternion<f64>, x: f64, y: f64, z: f64) -> Isometry3<f64> {
    let mesh = &lib().parts.get(kind).mesh;
    let lowest = mesh
        .vertices
        .iter()
        .map(|p| (rot * binpick_synth::mesh::to_point3(p)).z)
        .fold(f64::INFINITY, f64::min);
    Isometry3::from_parts(Translation3::new(x, y, z - lowest), rot)
}

#[test]
fn a_lone_part_is_fully_visible_in_any_pose_including_upside_down() {
    let lib = lib();
    let mut rng = Rng::new(17);
    for kind in PartKind::FAMILIES {
        let canonical = lib.canonical[kind.index()].rotation;
        let upside_down =
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI) * canonical;
        for (pose_name, rot) in [
            ("canonical", canonical),
            ("upside down", upside_down),
            ("random", rng.rotation()),
        ] {
            let inst = vec![Instance {
                kind,
                pose: resting(kind, rot, 20.0, -30.0, 0.0),
            }];
            let mut sensors = vec![belt_1mm(0.0), coarse_depth(0.0)];
            if pose_name == "random" {
                sensors.extend([belt_1mm(0.002), coarse_depth(0.002)]);
            }
            for sensor in sensors {
                let scan = scene_scan(&belt(), &inst, &sensor, 4);
                let vis = alone_visibility(&inst, &scan, &sensor, 4, &lib.parts).unwrap();
                let (fraction, seen, alone) = vis[0];
                assert!(alone > 200, "{kind} {pose_name}: {alone} points alone");
                if outlier_rate(&sensor) == 0.0 {
                    // Same rays, nothing in the way: the very same points.
                    assert_eq!(seen, alone, "{kind} {pose_name} {}", sensor.kind());
                } else {
                    assert!(fraction > 0.97, "{kind} {pose_name}: {fraction}");
                }
            }
        }
    }
}

fn outlier_rate(sensor: &Sensor) -> f64 {
    match sensor {
        Sensor::LaserLine(c) => c.outlier_rate,
        Sensor::DepthCamera(c) => c.outlier_rate,
    }
}

#[test]
fn a_top_view_model_calls_an_upside_down_plate_invisible_bop_does_not() {
    let lib = lib();
    let canonical = lib.canonical[PartKind::Plate.index()].rotation;
    let flipped =
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI) * canonical;
    let inst = vec![Instance {
        kind: PartKind::Plate,
        pose: resting(PartKind::Plate, flipped, 0.0, 0.0, 0.0),
    }];
    let sensor = belt_1mm(0.0);
    let scan = scene_scan(&belt(), &inst, &sensor, 2);
    let model = lib.model("plate").unwrap();
    let index = ScanIndex::new(&scan, 1.5);
    let (top_view, _) = instance_visibility(&index, model, &inst[0].pose, 0, 1.5);
    let bop = alone_visibility(&inst, &scan, &sensor, 2, &lib.parts).unwrap()[0].0;
    assert!(top_view < 0.3, "top-view fraction {top_view}");
    assert!(bop > 0.99, "BOP fraction {bop}");
}

#[test]
fn visible_fraction_drops_when_a_part_is_covered() {
    let lib = lib();
    let ring = lib.canonical[PartKind::Ring.index()];
    let inst = vec![Instance {
        kind: PartKind::Ring,
        pose: ring,
    }];
    let ring_mesh = &lib.parts.get(PartKind::Ring).mesh;
    // A board held 30 mm over the half x > 0 of the ring (not a part: background).
    let board = Mesh::cuboid([0.0, -100.0, 30.0], [100.0, 100.0, 33.0]);
    for sensor in [belt_1mm(0.001), depth(0.001)] {
        let v = |statics: &[Mesh]| {
            let geom =
                SceneGeometry::new(Some([1200.0, 1200.0]), statics, &[(ring_mesh, ring)]).unwrap();
            let scan = sensor.scan(&geom, 8);
            alone_visibility(&inst, &scan, &sensor, 8, &lib.parts).unwrap()[0].0
        };
        let (free, hidden) = (v(&[]), v(std::slice::from_ref(&board)));
        assert!(free > 0.98, "{}: {free}", sensor.kind());
        assert!(
            hidden > 0.2 && hidden < 0.6,
            "{}: half covered, {hidden} visible",
            sensor.kind()
        );
    }
    // A copy lying 5 mm above hides it completely: only the instance's own points count.
    let nested = vec![
        inst[0].clone(),
        Instance {
            kind: PartKind::Ring,
            pose: Isometry3::translation(0.0, 0.0, 5.0) * ring,
        },
    ];
    let sensor = belt_1mm(0.0);
    let scan = scene_scan(&belt(), &nested, &sensor, 8);
    let vis = alone_visibility(&nested, &scan, &sensor, 8, &lib.parts).unwrap();
    assert!(vis[0].0 < 0.05 && vis[1].0 > 0.99, "{vis:?}");
}

#[test]
fn scanning_a_part_alone_uses_exactly_the_rays_that_can_reach_it() {
    // A tall, tilted part near the edge of the field: the window must not cut any ray.
    let lib = lib();
    let rot = UnitQuaternion::from_euler_angles(1.2, 0.3, 0.7);
    for (x, y) in [(110.0, 100.0), (-120.0, -90.0)] {
        let inst = [Instance {
            kind: PartKind::Shaft,
            pose: resting(PartKind::Shaft, rot, x, y, 30.0),
        }];
        for sensor in [belt_1mm(0.0), depth(0.0)] {
            let mesh = &lib.parts.get(PartKind::Shaft).mesh;
            let full = {
                let placed = mesh.transformed(&inst[0].pose);
                let geom =
                    SceneGeometry::new(None, &[], &[(&placed, Isometry3::identity())]).unwrap();
                sensor.scan(&geom, 3)
            };
            let window = sensor.scan_alone(mesh, &inst[0].pose, 3).unwrap();
            let count = |s: &Scan| s.labels.iter().filter(|&&l| l == 0).count();
            assert!(count(&full) > 200);
            assert_eq!(count(&window), count(&full), "{}", sensor.kind());
        }
    }
}

#[test]
fn depth_camera_noise_grows_with_depth_squared_and_the_projector_casts_shadows() {
    let cfg = depth_camera();
    let sensor = Sensor::DepthCamera(cfg.clone());
    let floor = SceneGeometry::new(Some([2000.0, 2000.0]), &[], &[]).unwrap();
    let s = sensor.scan(&floor, 1);
    // Every pixel sees the floor.
    assert_eq!(s.cloud.len(), cfg.width * cfg.height);
    let zs: Vec<f64> = s
        .cloud
        .points
        .iter()
        .zip(&s.labels)
        .filter(|(_, l)| **l != OUTLIER)
        .map(|(p, _)| f64::from(p[2]))
        .collect();
    let n = zs.len() as f64;
    let mean = zs.iter().sum::<f64>() / n;
    let sd = (zs.iter().map(|z| (z - mean).powi(2)).sum::<f64>() / n).sqrt();
    let expected = cfg.noise_sigma_at(800.0);
    assert!((expected - 0.64).abs() < 1e-9);
    assert!(mean.abs() < 0.01, "{mean}");
    assert!((sd / expected - 1.0).abs() < 0.05, "{sd} vs {expected}");
    // A raised platform: its top is nearer, so noisier by (depth ratio)^2.
    let block = Mesh::cuboid([-100.0, -100.0, 0.0], [100.0, 100.0, 400.0]);
    let geom = SceneGeometry::new(
        Some([2000.0, 2000.0]),
        &[],
        &[(&block, Isometry3::identity())],
    )
    .unwrap();
    let s = sensor.scan(&geom, 1);
    let top: Vec<f64> = s
        .cloud
        .points
        .iter()
        .zip(&s.labels)
        .filter(|(p, l)| **l == 0 && p[0].abs() < 80.0 && p[1].abs() < 80.0)
        .map(|(p, _)| f64::from(p[2]))
        .collect();
    let m = top.iter().sum::<f64>() / top.len() as f64;
    let sd_top = (top.iter().map(|z| (z - m).powi(2)).sum::<f64>() / top.len() as f64).sqrt();
    let expected_top = cfg.noise_sigma_at(400.0);
    assert!(
        (sd_top / expected_top - 1.0).abs() < 0.1,
        "{sd_top} vs {expected_top}"
    );
    // The projector is 100 mm towards +x: beside a 100 mm tall post, the floor on the -x
    // side that the camera sees is in the projector's shadow; on the +x side it is measured.
    let post = Mesh::cuboid([-20.0, -20.0, 0.0], [20.0, 20.0, 100.0]);
    let geom = SceneGeometry::new(
        Some([2000.0, 2000.0]),
        &[],
        &[(&post, Isometry3::identity())],
    )
    .unwrap();
    let s = sensor.scan(&geom, 1);
    let floor_near = |x0: f32, x1: f32| {
        s.cloud
            .points
            .iter()
            .zip(&s.labels)
            .filter(|(p, l)| **l != 0 && p[0] > x0 && p[0] < x1 && p[1].abs() < 15.0)
            .count()
    };
    // Camera sees the floor beyond |x| = 20 * 800 / 700 = 22.9 mm; the projector's rays
    // over the post's -x edge reach the floor at x = -20 - 120 * 100 / 700 = -37.1 mm.
    assert_eq!(floor_near(-36.0, -24.0), 0);
    assert!(floor_near(24.0, 36.0) > 400, "{}", floor_near(24.0, 36.0));
    // The viewpoint names the camera's pose.
    let vp = sensor.viewpoint();
    assert_eq!(vp.position_mm, [0.0, 0.0, 800.0]);
    assert_eq!(vp.pcd_viewpoint, "0 0 800 0 1 0 0");
}

#[test]
fn new_families_pile_without_tunnelling() {
    let lib = lib();
    let env = Environment::Bin {
        floor_size: [800.0, 800.0],
        inner: [300.0, 300.0],
        wall_height: 100.0,
        wall_thickness: 10.0,
    };
    let kinds = [
        PartKind::Rod,
        PartKind::Ring,
        PartKind::Bracket,
        PartKind::Shaft,
        PartKind::Plate,
        PartKind::Ring,
        PartKind::Rod,
        PartKind::Bracket,
    ];
    let area = [-55.0, 55.0, -55.0, 55.0];
    let corral = Some([-60.0, 60.0, -60.0, 60.0]);
    let (pile, _) = binpick_synth::generate::build_pile_in(
        &lib.parts,
        &env,
        corral,
        area,
        &kinds,
        &[],
        &mut Rng::new(3),
        PhysicsSettings::default(),
    )
    .unwrap();
    assert_eq!(pile.len(), kinds.len());
    let depth = pile.max_penetration();
    assert!(depth < 0.5, "parts overlap by {depth} mm");
    // A heap: some part rests on others.
    let highest = pile
        .instances()
        .iter()
        .map(|i| i.pose.translation.vector.z)
        .fold(0.0, f64::max);
    assert!(highest > 15.0, "{highest}");
}

#[test]
fn set_scenes_do_not_depend_on_the_thread_count() {
    let lib = lib();
    let sets = generalisation_sets(Some(1));
    for name in ["rings-bin-depth", "plates-belt-clutter-1mm"] {
        let set = sets.iter().find(|s| s.name == name).unwrap();
        let models = set.models(lib);
        let a = make_set_scene(lib, &models, set, 11, 0).unwrap();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let b = pool.install(|| make_set_scene(lib, &models, set, 11, 0).unwrap());
        assert_eq!(a.scan, b.scan, "{name}");
        assert_eq!(a.gt, b.gt, "{name}");
        assert_eq!(a.instances, b.instances, "{name}");
        let c = make_set_scene(lib, &models, set, 12, 0).unwrap();
        assert_ne!(a.scan.cloud, c.scan.cloud, "{name}");
    }
}

fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out.sort();
    out
}

#[test]
fn one_scan_per_set_writes_the_benchmark_layout() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("bench");
    let opts = BenchmarkOptions {
        sets: Vec::new(),
        bop: false,
        out_dir: root.clone(),
        seed: 5,
        scenes_per_set: Some(1),
    };
    let summary = generate_generalisation(&opts, &|_, _| {}).unwrap();
    assert!(summary.sets.len() >= 8);
    assert_eq!(summary.scenes, summary.sets.len());
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("manifest.json")).unwrap())
            .unwrap();
    assert_eq!(manifest["seed"], 5);
    assert_eq!(manifest["preset"], "generalisation");
    let sets = manifest["sets"].as_array().unwrap();
    assert_eq!(sets.len(), summary.sets.len());
    let mut sensors = std::collections::BTreeSet::new();
    for set in sets {
        let name = set["name"].as_str().unwrap();
        let target = set["target_model"].as_str().unwrap();
        let set_dir = root.join(name);
        sensors.insert(set["sensor"]["kind"].as_str().unwrap().to_owned());
        assert_eq!(set["viewpoint"]["view_direction"][2], -1.0, "{name}");
        assert!(set["viewpoint"]["position_mm"][2].as_f64().unwrap() > 300.0);
        // Each set is a regular dataset whose models come with their meshes.
        let ds = Dataset::open(&set_dir).unwrap();
        for model in set["models"].as_array().unwrap() {
            let model = model.as_str().unwrap();
            let info = ModelInfo::load(&ds.model_info_path(model)).unwrap();
            assert!(info.diameter > 40.0 && info.diameter < 200.0, "{model}");
            let (cloud, _) = binpick_cloud::io::read_cloud(&ds.model_cloud_path(model)).unwrap();
            assert!(cloud.len() > 1000, "{model}");
            let mut f = std::fs::File::open(ds.model_mesh_path(model)).unwrap();
            let mesh = stl_io::read_stl(&mut f).unwrap();
            mesh.validate().unwrap();
        }
        let scene = &set["scenes"][0];
        let id = scene["id"].as_str().unwrap();
        let (cloud, _) =
            binpick_cloud::io::read_cloud(&set_dir.join(format!("scenes/{id}.pcd"))).unwrap();
        assert_eq!(cloud.len() as u64, scene["points"].as_u64().unwrap());
        for (part, count) in scene["parts"].as_object().unwrap() {
            let gt = GroundTruth::load(&ds.gt_path(&format!("{id}__{part}"))).unwrap();
            assert_eq!(
                gt.instances.len() as u64,
                count.as_u64().unwrap(),
                "{id} {part}"
            );
            for i in &gt.instances {
                let (seen, alone) = (i.visible_points.unwrap(), i.alone_points.unwrap());
                assert!(seen <= alone + alone / 50 + 2, "{id}: {seen} of {alone}");
                assert_eq!(i.pickable, i.visible_fraction >= 0.5);
            }
        }
        assert!(scene["parts"][target].as_u64().unwrap() >= 1, "{name}");
        let own: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(set_dir.join("manifest.json")).unwrap())
                .unwrap();
        assert_eq!(own["sets"][0]["name"], name);
    }
    assert!(sensors.contains("depth_camera") && sensors.contains("laser_line"));
    // The depth camera's viewpoint, as a PCD VIEWPOINT line.
    let rings = sets
        .iter()
        .find(|s| s["name"] == "rings-bin-depth")
        .unwrap();
    assert_eq!(rings["viewpoint"]["pcd_viewpoint"], "0 0 800 0 1 0 0");

    // Writing again over it: allowed, and no file is left over from the first run.
    let before = walk(&root);
    let again = generate_generalisation(
        &BenchmarkOptions {
            sets: Vec::new(),
            bop: false,
            scenes_per_set: Some(0),
            ..opts.clone()
        },
        &|_, _| {},
    )
    .unwrap();
    assert_eq!(again.scenes, 0);
    let after = walk(&root);
    assert!(after.len() < before.len());
    assert!(
        after
            .iter()
            .all(|p| !p.to_string_lossy().contains("/scenes/"))
    );
    // A folder holding something else is refused.
    let foreign = dir.path().join("mine");
    std::fs::create_dir_all(&foreign).unwrap();
    std::fs::write(foreign.join("notes.txt"), "keep").unwrap();
    let err = generate_generalisation(
        &BenchmarkOptions {
            sets: Vec::new(),
            bop: false,
            out_dir: foreign.clone(),
            ..opts
        },
        &|_, _| {},
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("not empty"), "{err}");
    assert!(foreign.join("notes.txt").exists());
}
