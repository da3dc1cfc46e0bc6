//! Parity of the two engines: the Rust pipeline (`Recognizer` with `thesis_strict = true`) and
//! the reference C++ pipeline (`binpick::reference`, thesis Algorithms 1 and 2 written directly
//! against PCL) must give the same answers on the same inputs, for both algorithms.
//!
//! What "the same" means here: identical preprocessing counts, clusters and per-cluster
//! outcomes; the same detections in the same ranking, each from the same cluster with the same
//! winning FPFH radius, SAC threshold and RANSAC inlier count and the same ICP outcome; poses
//! within 0.5 mm / 0.5 deg and scores within 1e-3 relative.
//!
//! The one legitimate difference is how a pose is carried between stages: the Rust pipeline
//! turns every 4x4 from PCL into an `Isometry3` (unit quaternion), places points with the
//! quaternion and hands ICP its initial guess converted back to a matrix, while the reference
//! keeps PCL's matrices throughout. The two guesses differ in the last bit of double precision,
//! so the ICP-refined rotation differs by a few ulps (seen: <= 6e-16 per matrix entry,
//! <= 1e-13 deg). Every point is rounded to float before a nearest-neighbour query and the
//! scores sum the same float distances in the same order in f64, so correspondences, ICP
//! iterations, translations and every score still come out identical here; a float rounding
//! flip would need a coordinate within ~1e-16 relative of a rounding boundary, and would move
//! a converged ICP far less than the bounds above. Each comparison prints its largest
//! differences and how many poses were bit-identical (the initial poses always are).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod support;

use std::path::PathBuf;
use std::time::Instant;

use binpick::RegionOfInterest;
use binpick::reference::{recognize_reference, recognize_reference_detailed};
use binpick::{
    Algorithm, Detection, Error, FeatureSurface, Params, PointCloud, Preset, Recognition,
    Recognizer, Units, load_cloud, pose,
};

const POSE_MM: f64 = 0.5;
const POSE_DEG: f64 = 0.5;
const SCORE_REL: f64 = 1e-3;

fn data(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../data")
        .join(rel)
}

fn load(rel: &str) -> PointCloud {
    load_cloud(&data(rel), Units::Millimetres).unwrap().0
}

fn strict(mut p: Params, algorithm: Algorithm) -> Params {
    p.thesis_strict = true;
    p.algorithm = algorithm;
    p
}

/// Largest differences between the engines over one comparison.
#[derive(Debug, Default, Clone, Copy)]
struct Diff {
    pose_mm: f64,
    pose_deg: f64,
    score_rel: f64,
    height_mm: f64,
    /// Poses (final and initial) compared, and how many were bit-identical.
    poses: usize,
    identical: usize,
}

impl Diff {
    fn max(self, o: Diff) -> Diff {
        Diff {
            pose_mm: self.pose_mm.max(o.pose_mm),
            pose_deg: self.pose_deg.max(o.pose_deg),
            score_rel: self.score_rel.max(o.score_rel),
            height_mm: self.height_mm.max(o.height_mm),
            poses: self.poses + o.poses,
            identical: self.identical + o.identical,
        }
    }
}

fn rel(a: f64, b: f64) -> f64 {
    if a == b {
        0.0
    } else {
        (a - b).abs() / a.abs().max(b.abs())
    }
}

fn compare_detection(label: &str, a: &Detection, b: &Detection) -> Diff {
    let mut d = Diff::default();
    for (x, y) in [(&a.pose, &b.pose), (&a.initial_pose, &b.initial_pose)] {
        d.pose_mm = d.pose_mm.max(pose::translation_error_mm(x, y));
        d.pose_deg = d.pose_deg.max(pose::rotation_error_deg(x, y));
        d.poses += 1;
        d.identical += usize::from(x.to_homogeneous() == y.to_homogeneous());
    }
    for (x, y) in [
        (a.initial_score, b.initial_score),
        (a.final_score, b.final_score),
        (a.score_before_icp, b.score_before_icp),
    ] {
        d.score_rel = d.score_rel.max(rel(x, y));
    }
    d.height_mm = (a.height_mm - b.height_mm).abs();
    assert!(
        d.pose_mm <= POSE_MM && d.pose_deg <= POSE_DEG,
        "{label}: poses differ by {:.4} mm / {:.4} deg\nrust: {a:#?}\nreference: {b:#?}",
        d.pose_mm,
        d.pose_deg
    );
    assert!(
        d.score_rel <= SCORE_REL,
        "{label}: scores differ by {:.2e} relative\nrust: {a:#?}\nreference: {b:#?}",
        d.score_rel
    );
    assert!(d.height_mm <= POSE_MM, "{label}: heights differ");
    // The discrete choices are the same: which cluster, rank, winning radius and threshold,
    // how many correspondences RANSAC kept, what ICP did.
    assert_eq!((a.rank, &a.found_by), (b.rank, &b.found_by), "{label}");
    assert_eq!(
        (
            a.icp.converged,
            a.icp.iterations,
            a.icp.adopted,
            &a.icp.error
        ),
        (
            b.icp.converged,
            b.icp.iterations,
            b.icp.adopted,
            &b.icp.error
        ),
        "{label}"
    );
    match (a.icp.fitness_mm2, b.icp.fitness_mm2) {
        (Some(x), Some(y)) => assert!(rel(x, y) <= SCORE_REL, "{label}: ICP fitness {x} vs {y}"),
        (x, y) => assert_eq!(x, y, "{label}"),
    }
    assert_eq!(a.rank_reason, b.rank_reason, "{label}");
    d
}

/// Asserts parity of two recognitions of the same scene and returns the largest differences.
fn assert_parity(label: &str, rust: &Recognition, reference: &Recognition) -> Diff {
    assert_eq!(
        rust.preprocess, reference.preprocess,
        "{label}: preprocessing"
    );
    assert_eq!(rust.clusters, reference.clusters, "{label}: clusters");
    assert_eq!(reference.duplicates_suppressed, 0);
    assert_eq!(
        rust.detections.len(),
        reference.detections.len(),
        "{label}: detections\nrust: {:#?}\nreference: {:#?}",
        rust.detections,
        reference.detections
    );
    let mut diff = Diff::default();
    for (k, (a, b)) in rust
        .detections
        .iter()
        .zip(&reference.detections)
        .enumerate()
    {
        diff = diff.max(compare_detection(&format!("{label} rank {}", k + 1), a, b));
    }
    diff
}

/// Runs both engines on one scene and asserts parity; returns (detections, differences).
fn both(label: &str, model: &PointCloud, scene: &PointCloud, params: &Params) -> (usize, Diff) {
    let t = Instant::now();
    let rust = Recognizer::new(model, params.clone())
        .unwrap()
        .recognize(scene)
        .unwrap();
    let rust_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let reference = recognize_reference(model, scene, params).unwrap();
    let reference_ms = t.elapsed().as_secs_f64() * 1e3;
    let diff = assert_parity(label, &rust, &reference);
    eprintln!(
        "{label}: {} detection(s) of {} cluster(s); rust {rust_ms:.0} ms, reference {reference_ms:.0} ms; \
         max diff {:.2e} mm, {:.2e} deg, scores {:.2e} rel; {} of {} poses bit-identical",
        rust.detections.len(),
        rust.clusters.len(),
        diff.pose_mm,
        diff.pose_deg,
        diff.score_rel,
        diff.identical,
        diff.poses
    );
    (rust.detections.len(), diff)
}

#[test]
fn sample_conveyor_scene_both_algorithms() {
    let model = load("sample/models/A.pcd");
    let scene = load("sample/scenes/conveyor-A.pcd");
    let mut found = 0;
    for algorithm in [Algorithm::SeparatedFpfh, Algorithm::MergedFpfh] {
        let params = strict(Preset::A.params(), algorithm);
        let (n, _) = both(
            &format!("conveyor-A, alg {}", algorithm.number()),
            &model,
            &scene,
            &params,
        );
        found += n;
    }
    assert!(found > 0, "the comparison must cover accepted detections");
}

#[test]
fn tiny_dataset_scenes_both_algorithms() {
    // (scene, model, preset): conveyor and robot-arm scans, whole and cut models.
    let cases = [
        ("tiny-conv-A-000", "A", Preset::A),
        ("tiny-conv-BC-000", "C", Preset::C1),
        ("tiny-arm-ABC-box-000", "C-cut", Preset::ArmC),
        ("tiny-arm-C-over-B-000", "C", Preset::ArmC),
    ];
    let mut found = 0;
    for (scene, model, preset) in cases {
        let s = load(&format!("tiny/scenes/{scene}.pcd"));
        let m = load(&format!("tiny/models/{model}.pcd"));
        for algorithm in [Algorithm::SeparatedFpfh, Algorithm::MergedFpfh] {
            let params = strict(preset.params(), algorithm);
            let label = format!("{scene} / {model}, alg {}", algorithm.number());
            found += both(&label, &m, &s, &params).0;
        }
    }
    assert!(found > 0, "the comparison must cover accepted detections");
}

/// The pipeline tests' synthetic scene: six bent sheets on a floor, one partly occluded and two
/// touching (one cluster, so the thesis finds one of them).
#[test]
fn synthetic_scene_both_algorithms() {
    let (poses, occluder_radius) = (
        vec![
            support::pose(0.0, 0.0, 0.0, 0.0),
            support::pose(100.0, 250.0, 30.0, 0.0),
            support::pose(200.0, 60.0, 250.0, 0.0),
            support::pose(-60.0, 250.0, 250.0, 0.0),
            support::pose(90.0, 520.0, 0.0, 0.0),
            support::pose(0.0, 521.0, 0.0, 0.0),
        ],
        vec![0.0, 0.0, 15.0, 0.0, 0.0, 0.0],
    );
    let scene = support::scene(&support::SceneSpec {
        poses,
        occluder_radius,
        floor: true,
        noise_sigma: 0.1,
        seed: 11,
    });
    let model = support::model();
    // Thesis 4.3 defaults with the conveyor tests' sweep (5.5: odd thresholds) and three of
    // the five radii, to keep the test short.
    let sweep = {
        let mut p = Params::default();
        p.features.fpfh_radii_mm = vec![10.0, 15.0, 20.0];
        p.consensus.sac_thresholds_mm = (0..10).map(|i| f64::from(2 * i + 1)).collect();
        p
    };
    for algorithm in [Algorithm::SeparatedFpfh, Algorithm::MergedFpfh] {
        let params = strict(sweep.clone(), algorithm);
        let (n, _) = both(
            &format!("synthetic, alg {}", algorithm.number()),
            &model,
            &scene,
            &params,
        );
        assert_eq!(n, 5, "one part per cluster, the touching pair counts once");
    }
}

/// The options the presets leave at their defaults: FPFH on the full cloud instead of the
/// keypoints, a region of interest, no support removal.
#[test]
fn other_options_match_too() {
    let poses = vec![
        support::pose(30.0, 0.0, 0.0, 0.0),
        support::pose(-120.0, 160.0, 20.0, 0.0),
    ];
    let scene = support::scene(&support::SceneSpec {
        poses,
        occluder_radius: vec![0.0, 0.0],
        floor: true,
        noise_sigma: 0.1,
        seed: 5,
    });
    let model = support::model();
    let cheap = {
        let mut p = Params::default();
        p.features.fpfh_radii_mm = vec![10.0, 20.0];
        p.consensus.sac_thresholds_mm = vec![1.0, 4.0, 9.0];
        p
    };
    let variants = [
        ("full-cloud FPFH", {
            let mut p = cheap.clone();
            p.features.feature_surface = FeatureSurface::Cloud;
            p.features.fpfh_radii_mm = vec![5.0, 8.0];
            p
        }),
        ("region of interest", {
            let mut p = cheap.clone();
            p.preprocess.region_of_interest = Some(RegionOfInterest {
                min_mm: [-60.0, -40.0, -5.0],
                max_mm: [120.0, 120.0, 80.0],
            });
            p
        }),
        ("no support removal, 2 mm voxels", {
            let mut p = cheap.clone();
            p.preprocess.resolution_mm = Some(2.0);
            p.features.initial_leaf_mm = 4.0;
            p.icp.final_leaf_mm = 3.0;
            p.preprocess.support = binpick::SupportRemoval {
                enabled: false,
                ..Default::default()
            };
            p
        }),
    ];
    for (name, p) in variants {
        for algorithm in [Algorithm::SeparatedFpfh, Algorithm::MergedFpfh] {
            both(
                &format!("{name}, alg {}", algorithm.number()),
                &model,
                &scene,
                &strict(p.clone(), algorithm),
            );
        }
    }
}

/// The reference's OpenMP team size changes nothing; its timings are filled.
#[test]
fn reference_is_deterministic_across_threads_and_reports_timings() {
    let model = load("tiny/models/A.pcd");
    let scene = load("tiny/scenes/tiny-conv-A-000.pcd");
    let run = |threads| {
        let p = {
            let mut p = strict(Preset::A.params(), Algorithm::SeparatedFpfh);
            p.runtime.threads = threads;
            p
        };
        recognize_reference_detailed(&model, &scene, &p).unwrap()
    };
    let one = run(1);
    let two = run(2);
    let strip = |r: &Recognition| {
        (
            r.detections.clone(),
            r.clusters.clone(),
            r.preprocess.clone(),
        )
    };
    assert_eq!(strip(&one.recognition), strip(&two.recognition));
    assert_eq!(one.stages.omp_threads, 1);
    assert_eq!(two.stages.omp_threads, 2);
    let t = &two.recognition.timings;
    assert!(t.total_ms > 0.0 && t.preprocess_ms > 0.0 && t.clustering_ms > 0.0);
    assert!(t.model_preparation_ms > 0.0 && t.initial_alignment_ms > 0.0);
    assert!(t.total_ms >= t.model_preparation_ms + t.preprocess_ms + t.clustering_ms);
    let s = &two.stages;
    assert!(s.model_features_ms > 0.0 && s.cluster_fpfh_ms > 0.0 && s.rejection_ms > 0.0);
    assert!(
        s.model_features_ms
            + s.cluster_keypoints_ms
            + s.cluster_fpfh_ms
            + s.correspondences_ms
            + s.rejection_ms
            + s.svd_ms
            + s.euclidean_score_ms
            <= t.initial_alignment_ms * 1.01 + 1.0
    );
}

#[test]
fn reference_rejects_bad_input() {
    let model = support::model();
    let scene = load("tiny/scenes/tiny-conv-A-000.pcd");
    let p = strict(Params::default(), Algorithm::SeparatedFpfh);
    let msg = |e: Error| e.to_string();

    // Empty and non-finite clouds, model and scene.
    let e = msg(recognize_reference(&PointCloud::default(), &scene, &p).unwrap_err());
    assert!(e.contains("model: the cloud is empty"), "{e}");
    let e = msg(recognize_reference(&model, &PointCloud::default(), &p).unwrap_err());
    assert!(e.contains("scene: the cloud is empty"), "{e}");
    let mut nan = scene.clone();
    nan.points[7][2] = f32::NAN;
    let e = msg(recognize_reference(&model, &nan, &p).unwrap_err());
    assert!(
        e.contains("scene: point 7 has a non-finite coordinate"),
        "{e}"
    );
    let mut inf = model.clone();
    inf.points[3][0] = f32::INFINITY;
    let e = msg(recognize_reference(&inf, &scene, &p).unwrap_err());
    assert!(e.contains("non-finite"), "{e}");

    // Wrong units.
    let mut metres = scene.clone();
    metres.scale(0.001);
    let e = msg(recognize_reference(&model, &metres, &p).unwrap_err());
    assert!(e.contains("scene") && e.contains("metres"), "{e}");
    let mut huge = model.clone();
    huge.scale(10_000.0);
    let e = msg(recognize_reference(&huge, &scene, &p).unwrap_err());
    assert!(e.contains("wrong units"), "{e}");

    // Absurd parameters name the field, as with the Rust engine.
    for (bad, field) in [
        (
            {
                let mut p = p.clone();
                p.icp.final_leaf_mm = -2.0;
                p
            },
            "final_leaf_mm",
        ),
        (
            {
                let mut p = p.clone();
                p.features.fpfh_radii_mm = vec![];
                p
            },
            "fpfh_radii_mm",
        ),
        (
            {
                let mut p = p.clone();
                p.preprocess.resolution_mm = Some(f64::NAN);
                p
            },
            "resolution_mm",
        ),
        (
            {
                let mut p = p.clone();
                p.consensus.sac_thresholds_mm = vec![3.0, f64::INFINITY];
                p
            },
            "sac_thresholds_mm",
        ),
    ] {
        let e = msg(recognize_reference(&model, &scene, &bad).unwrap_err());
        assert!(e.contains(field), "{e}");
    }

    // A model that the voxel grid reduces below 20 points is refused by the C++ side.
    // (A zig-zag: a straight line is refused before, as degenerate.)
    let sparse = PointCloud::new(
        (0..15)
            .map(|i| [i as f32 * 5.0, (i % 2) as f32 * 5.0, 0.0])
            .collect(),
    );
    let e = msg(recognize_reference(&sparse, &scene, &p).unwrap_err());
    assert!(
        e.contains("reference pipeline") && e.contains("voxel grid"),
        "{e}"
    );

    // A region of interest with nothing inside.
    let e = msg(recognize_reference(&model, &scene, &{
        let mut p = p.clone();
        p.preprocess.region_of_interest = Some(RegionOfInterest {
            min_mm: [5000.0; 3],
            max_mm: [6000.0; 3],
        });
        p
    })
    .unwrap_err());
    assert!(e.contains("region of interest"), "{e}");

    // The C++ entry point itself, reached without the Rust checks, refuses bad input with an
    // error instead of crashing.
    let good = binpick::reference::reference_params(&p);
    let call = |m: &[[f32; 3]], s: &[[f32; 3]], rp: &binpick_pcl::ReferenceParams| {
        binpick_pcl::reference_recognize(m, s, rp)
            .unwrap_err()
            .to_string()
    };
    let e = call(&[], &scene.points, &good);
    assert!(e.contains("model: the cloud is empty"), "{e}");
    let e = call(&model.points, &nan.points, &good);
    assert!(
        e.contains("scene: point 7 has a non-finite coordinate"),
        "{e}"
    );
    for (mutate, what) in [
        (
            Box::new(|r: &mut binpick_pcl::ReferenceParams| r.resolution = f64::NAN)
                as Box<dyn Fn(&mut binpick_pcl::ReferenceParams)>,
            "resolution",
        ),
        (Box::new(|r| r.fpfh_radii.clear()), "FPFH radii"),
        (
            Box::new(|r| r.sac_thresholds = vec![0.0]),
            "SAC inlier threshold",
        ),
        (Box::new(|r| r.algorithm = 3), "algorithm"),
        (Box::new(|r| r.icp_iterations = 0), "ICP"),
        (Box::new(|r| r.initial_leaf = 1e-6), "too small"),
        (
            Box::new(|r| r.scene_viewpoint[1] = f64::INFINITY),
            "viewpoint",
        ),
    ] {
        let mut rp = good.clone();
        mutate(&mut rp);
        let e = call(&model.points, &scene.points, &rp);
        assert!(e.contains(what), "{what}: {e}");
    }
}
