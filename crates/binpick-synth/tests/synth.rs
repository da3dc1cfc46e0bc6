//! End-to-end checks of the generator: ground truth consistency, occlusion, determinism,
//! shadows, symmetries, physics and the presets.

// Test helpers outside #[test] functions may fail loudly too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::HashMap;
use std::sync::OnceLock;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use binpick_cloud::dataset::{Dataset, GroundTruth, IDENTITY, ModelInfo};
use binpick_cloud::{PointCloud, transform_point};
use binpick_synth::mesh::{Mesh, distance_to_mesh};
use binpick_synth::models::{cloud_diameter, ground_truth};
use binpick_synth::physics::PhysicsSettings;
use binpick_synth::rng::Rng;
use binpick_synth::{
    Environment, Instance, Layout, ModelLibrary, OUTLIER, PartKind, Pile, Preset, Scan,
    ScannerConfig, SceneGeometry, SceneRequest, SynthOptions, generate, make_scene, plan, scan,
    scan_instances, scan_scene,
};

fn models() -> &'static ModelLibrary {
    static LIB: OnceLock<ModelLibrary> = OnceLock::new();
    LIB.get_or_init(|| ModelLibrary::build().expect("model library"))
}

fn belt() -> Environment {
    Layout::Conveyor.environment(false)
}

fn shifted(pose: &Isometry3<f64>, x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::identity()) * pose
}

/// Nearest-neighbour distances (capped at `cap`) from each query to `cloud`.
fn nn_distances(cloud: &PointCloud, queries: &[[f32; 3]], cap: f64) -> Vec<f64> {
    let cell = cap;
    let key = |p: &[f32; 3]| {
        (
            (f64::from(p[0]) / cell).floor() as i64,
            (f64::from(p[1]) / cell).floor() as i64,
            (f64::from(p[2]) / cell).floor() as i64,
        )
    };
    let mut grid: HashMap<(i64, i64, i64), Vec<[f32; 3]>> = HashMap::new();
    for p in &cloud.points {
        grid.entry(key(p)).or_default().push(*p);
    }
    queries
        .iter()
        .map(|q| {
            let (x, y, z) = key(q);
            let mut best = cap;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        for p in grid.get(&(x + dx, y + dy, z + dz)).into_iter().flatten() {
                            let d = (0..3)
                                .map(|k| (f64::from(p[k]) - f64::from(q[k])).powi(2))
                                .sum::<f64>()
                                .sqrt();
                            best = best.min(d);
                        }
                    }
                }
            }
            best
        })
        .collect()
}

fn conveyor(points: usize) -> ScannerConfig {
    ScannerConfig::conveyor(20.0, 0.15, points)
}

#[test]
fn model_at_true_pose_lies_on_the_scan_of_a_lone_part() {
    let lib = models();
    for kind in PartKind::THESIS {
        let pose = shifted(&lib.canonical[kind.index()], 25.0, -15.0, 0.0);
        let inst = vec![Instance { kind, pose }];
        let cfg = conveyor(200_000);
        let s = scan_scene(&belt(), &inst, &lib.parts, &cfg, 3).unwrap();
        let model = lib.model(kind.name()).unwrap();
        let moved: Vec<[f32; 3]> = model
            .cloud
            .points
            .iter()
            .map(|p| transform_point(&pose, p))
            .collect();
        let d = nn_distances(&s.cloud, &moved, 5.0);
        let within = d.iter().filter(|&&x| x <= 1.5).count() as f64 / d.len() as f64;
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        assert!(
            within >= 0.9,
            "{kind}: only {within:.3} of model points on the scan"
        );
        assert!(mean < 0.5, "{kind}: mean distance {mean:.3} mm");
        let gt = ground_truth("scenes/x.pcd", &inst, &s, lib, 1.5, None).unwrap();
        let own = gt.iter().find(|g| g.model == kind.name()).unwrap();
        assert_eq!(own.instances.len(), 1);
        let vf = own.instances[0].visible_fraction;
        assert!(vf >= 0.9 && own.instances[0].pickable, "{kind}: vf {vf}");
        // The ground-truth pose is the one given.
        let back = binpick_cloud::pose_from_row_major(&own.instances[0].pose).unwrap();
        assert!((back.to_homogeneous() - pose.to_homogeneous()).norm() < 1e-9);
    }
}

#[test]
fn a_part_upside_down_is_invisible_to_the_top_view_model_and_not_to_bop() {
    let lib = models();
    let kind = PartKind::A;
    let right_way_up = shifted(&lib.canonical[kind.index()], 25.0, -15.0, 0.0);
    // Turned over about x and lifted clear of the belt (no physics here).
    let over = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 60.0),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    ) * right_way_up;
    let judged = |pose: Isometry3<f64>| {
        let inst = vec![Instance { kind, pose }];
        let scene = scan_instances(lib, &belt(), inst, &conveyor(200_000), 3, "x").unwrap();
        let gt = scene.gt.iter().find(|g| g.model == kind.name()).unwrap();
        let i = gt.instances[0].clone();
        (
            i.visible_fraction,
            i.pickable,
            i.bop_visible_fraction().unwrap(),
        )
    };
    let (top_view, pickable, bop) = judged(right_way_up);
    assert!(
        top_view >= 0.9 && pickable && bop >= 0.9,
        "{top_view} {bop}"
    );
    // The thesis's fraction (the top view's points) is the model's: a top-view model cannot
    // align this part. BOP's is the scan's: it shows as plainly as the other.
    let (top_view, pickable, bop) = judged(over);
    assert!(top_view < 0.3 && !pickable, "top view {top_view}");
    assert!(bop >= 0.9, "BOP {bop}");
}

#[test]
fn scan_points_lie_on_the_instance_they_are_labelled_with() {
    let lib = models();
    let mut rng = Rng::new(11);
    let env = belt();
    let (pile, _) = binpick_synth::generate::build_pile(
        &lib.parts,
        Layout::Conveyor,
        &env,
        &[PartKind::A, PartKind::B, PartKind::C, PartKind::A],
        &[],
        &mut rng,
    )
    .unwrap();
    let inst = pile.instances();
    let mut cfg = conveyor(150_000);
    cfg.noise_sigma = 0.0;
    cfg.outlier_rate = 0.0;
    let s = scan_scene(&env, &inst, &lib.parts, &cfg, 5).unwrap();
    let meshes: Vec<_> = inst
        .iter()
        .map(|i| {
            lib.parts
                .get(i.kind)
                .mesh
                .transformed(&i.pose)
                .to_parry()
                .unwrap()
        })
        .collect();
    let mut checked = 0;
    for (p, &l) in s.cloud.points.iter().zip(&s.labels).step_by(37) {
        if (l as usize) < meshes.len() {
            let d = distance_to_mesh(&meshes[l as usize], p);
            assert!(d < 0.01, "point {p:?} labelled {l} is {d} mm off its part");
            checked += 1;
        } else {
            assert!(p[2].abs() < 0.01, "background point {p:?} off the belt");
        }
    }
    assert!(checked > 500, "{checked}");
}

#[test]
fn partly_covered_part_is_less_visible_than_alone() {
    let lib = models();
    let a = lib.canonical[PartKind::A.index()];
    let alone = vec![Instance {
        kind: PartKind::A,
        pose: a,
    }];
    // B lying flat, held (no physics needed for the scanner) just over half of A.
    let b = shifted(&lib.canonical[PartKind::B.index()], 70.0, 0.0, 55.0);
    let covered = vec![
        Instance {
            kind: PartKind::A,
            pose: a,
        },
        Instance {
            kind: PartKind::B,
            pose: b,
        },
    ];
    let cfg = conveyor(150_000);
    let vf = |inst: &[Instance]| {
        let s = scan_scene(&belt(), inst, &lib.parts, &cfg, 9).unwrap();
        let gt = ground_truth("scenes/x.pcd", inst, &s, lib, 1.5, None).unwrap();
        gt.iter()
            .find(|g| g.model == "A")
            .unwrap()
            .instances
            .first()
            .unwrap()
            .visible_fraction
    };
    let (v_alone, v_covered) = (vf(&alone), vf(&covered));
    assert!(v_alone > 0.9, "{v_alone}");
    assert!(
        v_covered < v_alone - 0.2 && v_covered > 0.05,
        "alone {v_alone}, covered {v_covered}"
    );
    // Only the instance's own points count: a copy nested 1 mm over it hides it completely
    // although the copy's points lie within the radius of its model points.
    let nested = vec![
        Instance {
            kind: PartKind::A,
            pose: a,
        },
        Instance {
            kind: PartKind::A,
            pose: shifted(&a, 0.0, 0.0, 1.0),
        },
    ];
    let s = scan_scene(&belt(), &nested, &lib.parts, &cfg, 9).unwrap();
    let gt = ground_truth("scenes/x.pcd", &nested, &s, lib, 1.5, None).unwrap();
    let vfs: Vec<f64> = gt[0].instances.iter().map(|i| i.visible_fraction).collect();
    assert!(vfs[0] < 0.1 && vfs[1] > 0.9, "{vfs:?}");
}

#[test]
fn same_seed_gives_identical_scene_whatever_the_thread_count() {
    let lib = models();
    let kinds = [PartKind::C, PartKind::A, PartKind::C];
    let req = SceneRequest {
        layout: Layout::Conveyor,
        in_box: false,
        base: &kinds,
        top: &[],
        points_target: 60_000,
        scanner: None,
        seed: 42,
        scene_id: "det",
    };
    let one = make_scene(lib, &req).unwrap();
    let two = make_scene(lib, &req).unwrap();
    assert_eq!(one.scan, two.scan);
    assert_eq!(one.gt, two.gt);
    assert_eq!(one.instances, two.instances);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let single = pool.install(|| make_scene(lib, &req).unwrap());
    assert_eq!(one.scan, single.scan);
    let other = make_scene(lib, &SceneRequest { seed: 43, ..req }).unwrap();
    assert_ne!(one.scan.cloud, other.scan.cloud);
}

fn tall_box() -> Mesh {
    Mesh::cuboid([-15.0, -15.0, 0.0], [15.0, 15.0, 80.0])
}

fn belt_points(s: &Scan, x: [f32; 2], y: [f32; 2]) -> usize {
    s.cloud
        .points
        .iter()
        .filter(|p| p[2].abs() < 1.0 && p[0] > x[0] && p[0] < x[1] && p[1] > y[0] && p[1] < y[1])
        .count()
}

#[test]
fn tall_part_leaves_shadows_on_both_sides() {
    let bx = tall_box();
    let mut cfg = conveyor(200_000);
    cfg.outlier_rate = 0.0;
    let floor = Some([600.0, 600.0]);
    let empty = scan(&SceneGeometry::new(floor, &[], &[]).unwrap(), &cfg, 1);
    for side in [1.0f64, -1.0] {
        let pose = Isometry3::translation(60.0 * side, 0.0, 0.0);
        let geom = SceneGeometry::new(floor, &[], &[(&bx, pose)]).unwrap();
        let s = scan(&geom, &cfg, 1);
        // Camera and laser fans diverge from x = 0, 400 mm up: the top edge at |x| = 75,
        // z = 80 hides the belt up to |x| = 75 * 400 / 320 = 93.75.
        let region = if side > 0.0 {
            [77.0, 92.0]
        } else {
            [-92.0, -77.0]
        };
        assert_eq!(belt_points(&s, region, [-10.0, 10.0]), 0, "side {side}");
        assert!(belt_points(&empty, region, [-10.0, 10.0]) > 200);
        // The box's top is scanned.
        assert!(s.labels.iter().filter(|&&l| l == 0).count() > 1000);
    }
    // Along the motion, laser 1 (from -y) shadows the belt behind the box (+y side, up to
    // 80 * 160 / 400 = 32 mm from the face); the second laser fills it in.
    let geom = SceneGeometry::new(floor, &[], &[(&tall_box(), Isometry3::identity())]).unwrap();
    let behind = ([-10.0, 10.0], [17.0, 30.0]);
    let dual = scan(&geom, &cfg, 1);
    assert!(belt_points(&dual, behind.0, behind.1) > 200);
    let single = scan(
        &geom,
        &ScannerConfig {
            dual_laser: false,
            ..cfg.clone()
        },
        1,
    );
    assert_eq!(belt_points(&single, behind.0, behind.1), 0);
}

#[test]
fn lit_spots_hidden_from_the_camera_give_no_points() {
    // A plate 50 mm over the belt: the lasers (from y = -/+160 mm, 400 mm up) reach the belt
    // right under its middle at a slant, but the camera straight above cannot see it.
    let plate = Mesh::cuboid([-20.0, -10.0, 50.0], [20.0, 10.0, 52.0]);
    let mut cfg = conveyor(200_000);
    cfg.outlier_rate = 0.0;
    let geom = SceneGeometry::new(
        Some([600.0, 600.0]),
        &[],
        &[(&plate, Isometry3::identity())],
    )
    .unwrap();
    let s = scan(&geom, &cfg, 1);
    assert_eq!(belt_points(&s, [-15.0, 15.0], [-2.0, 2.0]), 0);
    assert!(s.labels.iter().filter(|&&l| l == 0).count() > 1000);
}

#[test]
fn noise_and_outliers_follow_the_settings() {
    let mut cfg = ScannerConfig::arm(45.0, 0.4, 200_000);
    cfg.outlier_rate = 0.01;
    let geom = SceneGeometry::new(Some([800.0, 800.0]), &[], &[]).unwrap();
    let s = scan(&geom, &cfg, 7);
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
    // Range noise is along the camera ray, which is within 19 deg of vertical here.
    assert!(mean.abs() < 0.01, "{mean}");
    assert!(sd > 0.36 && sd < 0.41, "{sd}");
    let outliers = s.labels.iter().filter(|&&l| l == OUTLIER).count() as f64 / s.len_f64();
    assert!((outliers - 0.01).abs() < 0.002, "{outliers}");
    assert!(
        s.cloud
            .points
            .iter()
            .zip(&s.labels)
            .filter(|(_, l)| **l == OUTLIER)
            .all(|(p, _)| p[2].abs() >= 1.8 && p[2].abs() <= 25.0)
    );
}

trait LenF64 {
    fn len_f64(&self) -> f64;
}
impl LenF64 for Scan {
    fn len_f64(&self) -> f64 {
        self.cloud.len() as f64
    }
}

#[test]
fn declared_symmetries_map_cut_models_onto_themselves() {
    let lib = models();
    for name in ["A-cut", "C-cut"] {
        let model = lib.model(name).unwrap();
        let part = lib.parts.get(model.part);
        assert_eq!(model.symmetries.len(), 2, "{name}");
        assert_eq!(
            binpick_cloud::pose_to_row_major(&model.symmetries[0]),
            IDENTITY
        );
        let cut = part.cut_mesh().unwrap().unwrap();
        let cut_parry = cut.to_parry().unwrap();
        let full_parry = part.mesh.to_parry().unwrap();
        let samples = cut.sample_surface(3000, &mut Rng::new(1));
        let full_samples = part.mesh.sample_surface(3000, &mut Rng::new(2));
        for s in &model.symmetries {
            // The cut part's surface maps onto itself...
            let worst = samples
                .iter()
                .map(|p| distance_to_mesh(&cut_parry, &transform_point(s, p)))
                .fold(0.0, f64::max);
            assert!(
                worst < 0.01,
                "{name}: symmetry moves the surface by {worst} mm"
            );
        }
        // ... but the full part is not symmetric: the same half turn moves it visibly.
        let half_turn = &model.symmetries[1];
        let worst_full = full_samples
            .iter()
            .map(|p| distance_to_mesh(&full_parry, &transform_point(half_turn, p)))
            .fold(0.0, f64::max);
        assert!(
            worst_full > 5.0,
            "{name}: full part looks symmetric ({worst_full})"
        );
        // The full models declare only the identity.
        let full = lib.model(model.part.name()).unwrap();
        assert_eq!(full.symmetries.len(), 1);
    }
    // A-cut's top view maps onto itself (the half turn swaps the two legs' outer faces).
    let a_cut = lib.model("A-cut").unwrap();
    let moved: Vec<[f32; 3]> = a_cut
        .cloud
        .points
        .iter()
        .map(|p| transform_point(&a_cut.symmetries[1], p))
        .collect();
    let d = nn_distances(&a_cut.cloud, &moved, 3.0);
    let close = d.iter().filter(|&&x| x < 0.75).count() as f64 / d.len() as f64;
    assert!(close > 0.95, "{close}");
}

#[test]
fn cut_models_are_crops_of_the_full_models() {
    let lib = models();
    for (cut, full) in [("A-cut", "A"), ("C-cut", "C")] {
        let (c, f) = (lib.model(cut).unwrap(), lib.model(full).unwrap());
        assert!(c.cloud.len() > 2000 && c.cloud.len() < f.cloud.len());
        assert!(c.cloud.points.iter().all(|p| f.cloud.points.contains(p)));
        assert!(c.diameter < f.diameter);
    }
    for m in &lib.models {
        assert!((m.diameter - cloud_diameter(&m.cloud)).abs() < 1e-9);
    }
}

#[test]
fn cloud_diameter_is_the_largest_pairwise_distance() {
    let mut rng = Rng::new(4);
    let cloud = PointCloud::new(
        (0..800)
            .map(|_| {
                [
                    rng.range(-30.0, 50.0) as f32,
                    rng.range(-10.0, 10.0) as f32,
                    rng.range(0.0, 5.0) as f32,
                ]
            })
            .collect(),
    );
    let mut brute = 0.0f64;
    for a in &cloud.points {
        for b in &cloud.points {
            let d = (0..3)
                .map(|k| (f64::from(a[k]) - f64::from(b[k])).powi(2))
                .sum::<f64>();
            brute = brute.max(d);
        }
    }
    assert!((cloud_diameter(&cloud) - brute.sqrt()).abs() < 1e-6);
}

#[test]
fn piles_settle_touching_without_tunnelling() {
    let lib = models();
    for (layout, in_box, kinds) in [
        (
            Layout::Conveyor,
            false,
            vec![
                PartKind::B,
                PartKind::A,
                PartKind::C,
                PartKind::B,
                PartKind::A,
                PartKind::C,
                PartKind::A,
            ],
        ),
        (Layout::Arm, true, vec![PartKind::A; 6]),
    ] {
        let env = layout.environment(in_box);
        let mut rng = Rng::new(21);
        let (pile, settled) =
            binpick_synth::generate::build_pile(&lib.parts, layout, &env, &kinds, &[], &mut rng)
                .unwrap();
        assert!(settled, "{layout:?}");
        assert_eq!(pile.len(), kinds.len());
        let pen = pile.max_penetration();
        assert!(pen < 0.2, "{layout:?}: penetration {pen} mm");
        let [hx, hy] = env.inner_half_extents();
        let mut resting_on_parts = 0;
        for i in pile.instances() {
            let b = lib
                .parts
                .get(i.kind)
                .mesh
                .transformed(&i.pose)
                .bounds()
                .unwrap();
            assert!(b.min[2] > -0.2, "{layout:?}: part below the floor {b:?}");
            assert!(b.min[0] > -hx as f32 && b.max[0] < hx as f32 && b.min[1] > -hy as f32);
            if b.min[2] > 1.0 {
                resting_on_parts += 1;
            }
        }
        // A pile: parts touch each other, and some lie entirely on others.
        let touching = pile.touching_pairs(0.5);
        assert!(
            touching.len() >= 2,
            "{layout:?}: touching pairs {touching:?}"
        );
        assert!(resting_on_parts >= 1 || touching.len() >= 4, "{layout:?}");
    }
}

#[test]
fn removing_the_topmost_part_settles_the_rest() {
    let lib = models();
    let env = belt();
    let mut pile = Pile::new(
        &lib.parts,
        &env,
        Some([-80.0, 80.0, -80.0, 80.0]),
        PhysicsSettings::default(),
    );
    let mut rng = Rng::new(3);
    pile.drop_parts(&[PartKind::A; 4], [-78.0, 78.0, -78.0, 78.0], &mut rng)
        .unwrap();
    let before = pile.instances();
    let top = |inst: &Instance| {
        let b = lib
            .parts
            .get(inst.kind)
            .mesh
            .transformed(&inst.pose)
            .bounds();
        b.unwrap().max[2]
    };
    let highest = before.iter().map(top).fold(f32::MIN, f32::max);
    assert_eq!(pile.remove_topmost(), Some(PartKind::A));
    assert!(pile.settle());
    let after = pile.instances();
    assert_eq!(after.len(), 3);
    assert!(after.iter().map(top).all(|z| z <= highest + 0.5));
}

#[test]
fn presets_have_the_thesis_groups_and_counts() {
    let conv = plan(Preset::ThesisConveyor, None);
    let names: Vec<&str> = conv.iter().map(|g| g.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "A", "B", "C", "A+B", "B+C", "C+A", "A-Decr", "B-Decr", "C-Decr"
        ]
    );
    assert!(
        conv.iter()
            .all(|g| g.scenes == 10 && g.layout == Layout::Conveyor)
    );
    assert_eq!(conv.iter().map(|g| g.scenes).sum::<usize>(), 90);

    let arm = plan(Preset::ThesisArm, None);
    let names: Vec<&str> = arm.iter().map(|g| g.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "A",
            "A over B",
            "A over B and C",
            "C",
            "C over B",
            "C over B and A",
            "A+B+C",
            "A+B+C-Box"
        ]
    );
    assert_eq!(arm.iter().map(|g| g.scenes).sum::<usize>(), 100);
    assert_eq!(arm.iter().filter(|g| g.scenes == 20).count(), 2);
    assert!(arm.iter().all(|g| g.layout == Layout::Arm));
    assert_eq!(arm.iter().filter(|g| g.in_box).count(), 1);

    assert_eq!(
        plan(Preset::Tiny, None)
            .iter()
            .map(|g| g.scenes)
            .sum::<usize>(),
        4
    );
    assert!(
        plan(Preset::ThesisArm, Some(2))
            .iter()
            .all(|g| g.scenes == 2)
    );
    let mut slugs: Vec<String> = conv
        .iter()
        .chain(&arm)
        .chain(&plan(Preset::Tiny, None))
        .map(|g| g.slug.clone())
        .collect();
    slugs.sort();
    slugs.dedup();
    assert_eq!(slugs.len(), 9 + 8 + 4);
    assert_eq!("thesis-arm".parse::<Preset>(), Ok(Preset::ThesisArm));
    assert!("thesis".parse::<Preset>().is_err());
}

fn pcd_point_count(path: &std::path::Path) -> usize {
    let bytes = std::fs::read(path).unwrap();
    let marker = b"DATA binary\n";
    let at = bytes
        .windows(marker.len())
        .position(|w| w == marker)
        .expect("binary PCD");
    let header = std::str::from_utf8(&bytes[..at]).unwrap();
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("POINTS "))
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    assert_eq!(
        bytes.len() - at - marker.len(),
        12 * n,
        "{}",
        path.display()
    );
    n
}

#[test]
fn tiny_preset_writes_a_valid_reproducible_dataset() {
    let dirs = [tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap()];
    let mut summaries = Vec::new();
    for d in &dirs {
        let opts = SynthOptions {
            preset: Preset::Tiny,
            out_dir: d.path().to_owned(),
            seed: 9,
            scenes_per_group: None,
            points_target: Some(20_000),
        };
        let calls = std::sync::atomic::AtomicUsize::new(0);
        let s = generate(&opts, &|done, total| {
            assert!(done <= total && total == 4);
            calls.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        })
        .unwrap();
        assert_eq!(calls.into_inner(), 4);
        summaries.push(s);
    }
    let root = dirs[0].path();
    assert_eq!(summaries[0].scenes, 4);
    for name in ["A", "A-cut", "B", "C", "C-cut"] {
        let info = ModelInfo::load(&root.join(format!("models/{name}.json"))).unwrap();
        assert!(info.diameter > 50.0 && info.diameter < 200.0, "{name}");
        assert!(pcd_point_count(&root.join(format!("models/{name}.pcd"))) > 2000);
        let stl = root.join(format!("models/{name}.stl"));
        let binpick_cloud::io::Model::Mesh(m) = binpick_cloud::io::read_model(&stl).unwrap() else {
            panic!("{name}: the STL holds no mesh")
        };
        assert!(m.mesh.triangles.len() >= 12, "{name}");
    }
    let ds = Dataset::open(root).unwrap();
    assert_eq!(ds.scene_ids.len(), summaries[0].gt_files);
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("manifest.json")).unwrap())
            .unwrap();
    assert_eq!(manifest["preset"], "tiny");
    assert_eq!(manifest["seed"], 9);
    let mut scenes_with_c = 0;
    for g in manifest["groups"].as_array().unwrap() {
        for sc in g["scene_records"].as_array().unwrap() {
            let id = sc["id"].as_str().unwrap();
            let n = pcd_point_count(&root.join(format!("scenes/{id}.pcd")));
            assert_eq!(n as u64, sc["points"].as_u64().unwrap());
            for (part, count) in sc["parts"].as_object().unwrap() {
                let gt = GroundTruth::load(&ds.gt_path(&format!("{id}__{part}"))).unwrap();
                assert_eq!(gt.scene, format!("scenes/{id}.pcd"));
                assert_eq!(gt.instances.len() as u64, count.as_u64().unwrap());
                assert!(ds.scene_path(&gt).exists());
                assert!(
                    gt.instances
                        .iter()
                        .all(|i| i.pickable == (i.visible_fraction >= 0.5))
                );
                // BOP's counts beside the thesis's fraction.
                assert!(gt.instances.iter().all(|i| {
                    i.bop_visible_fraction()
                        .is_some_and(|v| (0.0..=1.0).contains(&v))
                }));
                if part == "C" {
                    scenes_with_c += 1;
                    let cut = GroundTruth::load(&ds.gt_path(&format!("{id}__C-cut"))).unwrap();
                    assert_eq!(cut.instances.len(), gt.instances.len());
                }
            }
        }
    }
    assert!(scenes_with_c >= 2);
    // Same options -> byte-identical files.
    let mut files: Vec<_> = walk(root);
    files.sort();
    let mut other: Vec<_> = walk(dirs[1].path());
    other.sort();
    assert_eq!(files.len(), other.len());
    for (a, b) in files.iter().zip(&other) {
        assert_eq!(
            a.strip_prefix(root).unwrap(),
            b.strip_prefix(dirs[1].path()).unwrap()
        );
        assert!(
            std::fs::read(a).unwrap() == std::fs::read(b).unwrap(),
            "{} differs",
            a.display()
        );
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
    out
}

#[test]
fn scene_instances_are_inside_the_scanned_area() {
    let lib = models();
    for (layout, in_box) in [
        (Layout::Conveyor, false),
        (Layout::Arm, false),
        (Layout::Arm, true),
    ] {
        let kinds = [
            PartKind::B,
            PartKind::C,
            PartKind::A,
            PartKind::B,
            PartKind::C,
        ];
        let sc = make_scene(
            lib,
            &SceneRequest {
                layout,
                in_box,
                base: &kinds,
                top: &[],
                points_target: 30_000,
                scanner: None,
                seed: 77,
                scene_id: "area",
            },
        )
        .unwrap();
        let cfg = &sc.scanner;
        for i in &sc.instances {
            let b = lib
                .parts
                .get(i.kind)
                .mesh
                .transformed(&i.pose)
                .bounds()
                .unwrap();
            let c = Vector3::new(
                0.5 * f64::from(b.min[0] + b.max[0]),
                0.5 * f64::from(b.min[1] + b.max[1]),
                0.0,
            );
            assert!(
                c.x > cfg.x_range[0] && c.x < cfg.x_range[1],
                "{layout:?} {in_box}: {c:?}"
            );
            assert!(
                c.y > cfg.y_range[0] && c.y < cfg.y_range[1],
                "{layout:?}: {c:?}"
            );
        }
        assert!(sc.settled);
        // Every part type present has its ground truth.
        assert!(sc.gt.iter().any(|g| g.model == "C-cut"));
    }
}

#[test]
fn output_folder_must_be_empty_or_an_earlier_dataset() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("notes.txt"), "mine").unwrap();
    let opts = SynthOptions {
        preset: Preset::Tiny,
        out_dir: dir.path().to_owned(),
        seed: 1,
        scenes_per_group: Some(1),
        points_target: Some(5_000),
    };
    let err = generate(&opts, &|_, _| {}).unwrap_err().to_string();
    assert!(err.contains("not empty"), "{err}");
    assert!(dir.path().join("notes.txt").exists());

    let ds = dir.path().join("ds");
    let first = SynthOptions {
        out_dir: ds.clone(),
        ..opts.clone()
    };
    assert_eq!(generate(&first, &|_, _| {}).unwrap().scenes, 4);
    // Regenerating with fewer scenes leaves no stale scene or ground truth behind.
    let fewer = SynthOptions {
        scenes_per_group: Some(0),
        ..first
    };
    assert_eq!(generate(&fewer, &|_, _| {}).unwrap().scenes, 0);
    assert_eq!(std::fs::read_dir(ds.join("scenes")).unwrap().count(), 0);
    assert_eq!(std::fs::read_dir(ds.join("gt")).unwrap().count(), 0);
    assert_eq!(std::fs::read_dir(ds.join("models")).unwrap().count(), 15);
}
