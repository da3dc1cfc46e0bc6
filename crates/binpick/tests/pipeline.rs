//! End-to-end recognition on synthetic scenes with known poses.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod support;

use binpick::{
    Algorithm, Engine, Error, FoundBy, Params, PointCloud, Recognition, Recognizer, pose,
};
use nalgebra::Isometry3;
use support::*;

/// For every true pose, the detection closest to it: (rotation error deg, translation error mm).
fn match_truth(truths: &[Isometry3<f64>], r: &Recognition) -> Vec<Option<(f64, f64)>> {
    truths
        .iter()
        .map(|t| {
            r.detections
                .iter()
                .min_by(|a, b| {
                    mean_point_distance(t, &a.pose).total_cmp(&mean_point_distance(t, &b.pose))
                })
                .filter(|d| mean_point_distance(t, &d.pose) < 10.0)
                .map(|d| {
                    (
                        pose::rotation_error_deg(t, &d.pose),
                        pose::translation_error_mm(t, &d.pose),
                    )
                })
        })
        .collect()
}

/// Poses and occluder radii. Instance 2 is partly occluded (about 9 % of its points hidden
/// under a disc lying on it); instances 4 and 5 touch (1 mm apart, one cluster).
fn layout() -> (Vec<Isometry3<f64>>, Vec<f64>) {
    let poses = vec![
        pose(0.0, 0.0, 0.0, 0.0),
        pose(100.0, 250.0, 30.0, 0.0),
        pose(200.0, 60.0, 250.0, 0.0), // partly occluded
        pose(-60.0, 250.0, 250.0, 0.0),
        // Two touching parts: side by side, 1 mm apart, so they form one Euclidean cluster.
        pose(90.0, 520.0, 0.0, 0.0),
        pose(0.0, 521.0, 0.0, 0.0),
    ];
    let occluders = vec![0.0, 0.0, 15.0, 0.0, 0.0, 0.0];
    (poses, occluders)
}

fn standard_scene() -> (PointCloud, Vec<Isometry3<f64>>) {
    let (poses, occluder_radius) = layout();
    let cloud = scene(&SceneSpec {
        poses: poses.clone(),
        occluder_radius,
        floor: true,
        noise_sigma: 0.1,
        seed: 11,
    });
    (cloud, poses.iter().map(truth).collect())
}

/// Isolated and occluded parts within 1 mm / 1 deg. The touching pair gets 5 mm: two flat
/// sheets 1 mm apart continue each other's surface, so ICP can slide a model along the seam
/// into its neighbour (measured: 4.1 mm with algorithm 2) without any keypoint becoming an
/// outlier; the percent-of-outliers score cannot see it (README, "Limitations").
fn assert_all_found(truths: &[Isometry3<f64>], r: &Recognition) {
    let found = match_truth(truths, r);
    for (i, m) in found.iter().enumerate() {
        let (rot, trans) = m.unwrap_or_else(|| panic!("instance {i} not found: {:#?}", r.clusters));
        let max_mm = if i >= 4 { 5.0 } else { 1.0 };
        assert!(
            rot < 1.0 && trans < max_mm,
            "instance {i}: {rot:.3} deg, {trans:.3} mm; truth {}; detections {:#?}",
            truths[i].translation.vector.transpose(),
            r.detections
                .iter()
                .map(|d| d.pose.translation.vector.transpose())
                .collect::<Vec<_>>()
        );
    }
    assert_eq!(
        r.detections.len(),
        truths.len(),
        "no extra detections: {:#?}",
        r.detections
    );
}

#[test]
fn finds_every_instance_with_both_algorithms() {
    let (cloud, truths) = standard_scene();
    for algorithm in [Algorithm::SeparatedFpfh, Algorithm::MergedFpfh] {
        let rec = Recognizer::new(
            &model(),
            Params {
                algorithm,
                engine: Engine::Thesis,
                ..Params::default()
            },
        )
        .unwrap();
        let r = rec.recognize(&cloud).unwrap();
        assert_all_found(&truths, &r);
        // The floor was removed as support and the touching pair shared one cluster.
        assert_eq!(r.preprocess.support_planes.len(), 1);
        assert!(
            r.clusters.iter().any(|c| c.detections == 2),
            "{:#?}",
            r.clusters
        );
        // The occluded instance is found but ranks last: it has the most outliers.
        let occluded = &truths[2];
        let last = r.detections.last().unwrap();
        assert!(
            pose::translation_error_mm(occluded, &last.pose) < 1.0,
            "{:#?}",
            r.detections
        );
        assert!(last.final_score > r.detections[0].final_score);
        match algorithm {
            Algorithm::SeparatedFpfh => assert!(r.detections.iter().all(|d| matches!(
                d.found_by,
                FoundBy::Cluster {
                    fpfh_radius_mm: Some(_),
                    ..
                }
            ))),
            Algorithm::MergedFpfh => assert!(r.detections.iter().all(|d| matches!(
                d.found_by,
                FoundBy::Cluster {
                    fpfh_radius_mm: None,
                    ..
                }
            ))),
        }
    }
}

#[test]
fn thesis_strict_finds_one_part_per_cluster() {
    let (cloud, truths) = standard_scene();
    let rec = Recognizer::new(
        &model(),
        Params {
            thesis_strict: true,
            ..Params::default()
        },
    )
    .unwrap();
    let r = rec.recognize(&cloud).unwrap();
    // The touching pair is one cluster, so the thesis finds only one of the two.
    assert_eq!(r.detections.len(), truths.len() - 1, "{:#?}", r.clusters);
    assert!(r.clusters.iter().all(|c| c.detections <= 1));
}

#[test]
fn scene_without_the_part_yields_nothing() {
    // Floor plus clutter: boxes and a cylinder of similar size, no bent sheet.
    let mut pts = Vec::new();
    let mut rng = Rng(3);
    for i in 0..400 {
        for j in 0..300 {
            pts.push([i as f64 * 0.8, j as f64 * 0.8, rng.gauss(0.1)]);
        }
    }
    for (ox, oy, w, d, h) in [
        (40.0, 40.0, 60.0, 40.0, 30.0),
        (180.0, 60.0, 50.0, 50.0, 20.0),
    ] {
        let mut x = 0.0;
        while x <= w {
            let mut y = 0.0;
            while y <= d {
                pts.push([ox + x, oy + y, h + rng.gauss(0.1)]);
                y += 0.6;
            }
            x += 0.6;
        }
    }
    for a in 0..600 {
        let t = a as f64 / 600.0 * std::f64::consts::PI;
        for k in 0..120 {
            pts.push([
                100.0 + 20.0 * t.cos(),
                170.0 + k as f64 * 0.6,
                20.0 * t.sin() + rng.gauss(0.1),
            ]);
        }
    }
    let thesis = Params {
        engine: Engine::Thesis,
        ..Params::default()
    };
    let rec = Recognizer::new(&model(), thesis).unwrap();
    let r = rec.recognize(&to_cloud(&pts)).unwrap();
    assert!(r.detections.is_empty(), "{:#?}", r.detections);
    assert!(
        !r.clusters.is_empty(),
        "clutter was clustered and rejected, not skipped"
    );
    // The scene-voting engine verifies hypotheses on the clutter and refuses them all.
    let rec = Recognizer::new(&model(), Params::default()).unwrap();
    let r = rec.recognize(&to_cloud(&pts)).unwrap();
    assert!(r.detections.is_empty(), "{:#?}", r.detections);
    let v = r.voting.expect("scene-voting report");
    assert!(
        v.candidates > 0,
        "hypotheses were verified and refused: {v:?}"
    );
}

#[test]
fn one_and_many_threads_give_identical_output() {
    let (cloud, _) = standard_scene();
    let run = |threads| {
        let rec = Recognizer::new(&model(), {
            let mut p = Params::default();
            p.runtime.threads = threads;
            p
        })
        .unwrap();
        let r = rec.recognize(&cloud).unwrap();
        (r.detections, r.clusters, r.preprocess)
    };
    let one = run(1);
    let four = run(4);
    assert_eq!(one, four);
    assert!(!one.0.is_empty());
}

#[test]
fn bad_inputs_are_clear_errors() {
    let good = model();
    let msg = |e: Error| e.to_string();
    // Empty and non-finite clouds.
    assert!(
        msg(Recognizer::new(&PointCloud::default(), Params::default()).unwrap_err())
            .contains("empty")
    );
    let mut nan = good.clone();
    nan.points[5][1] = f32::NAN;
    assert!(msg(Recognizer::new(&nan, Params::default()).unwrap_err()).contains("non-finite"));
    // A model in metres.
    let mut metres = good.clone();
    metres.scale(0.001);
    let e = msg(Recognizer::new(&metres, Params::default()).unwrap_err());
    assert!(e.contains("metres") && e.contains("--units m"), "{e}");
    // Absurd parameters name the field.
    let e = msg(Recognizer::new(&good, {
        let mut p = Params::default();
        p.icp.final_leaf_mm = -2.0;
        p
    })
    .unwrap_err());
    assert!(e.contains("final_leaf_mm"), "{e}");
    // Bad scenes.
    let rec = Recognizer::new(&good, Params::default()).unwrap();
    assert!(
        msg(rec.recognize(&PointCloud::default()).unwrap_err())
            .contains("scene: the cloud is empty")
    );
    let mut scene_m = standard_scene().0;
    scene_m.scale(0.001);
    let e = msg(rec.recognize(&scene_m).unwrap_err());
    assert!(e.contains("scene") && e.contains("metres"), "{e}");
}

#[test]
fn time_budget_is_enforced() {
    let (cloud, _) = standard_scene();
    let rec = Recognizer::new(&model(), Params::default()).unwrap();
    let e = rec
        .recognize_within(&cloud, Some(std::time::Duration::from_millis(1)))
        .unwrap_err();
    assert!(matches!(e, Error::TimeBudget { budget_ms: 1, .. }), "{e}");
    assert!(e.to_string().contains("time budget of 1 ms exceeded"));
    // A generous budget changes nothing.
    let r = rec
        .recognize_within(&cloud, Some(std::time::Duration::from_secs(600)))
        .unwrap();
    assert_eq!(r.detections.len(), 6);
}

#[test]
fn recognizer_serves_several_threads() {
    let (cloud, truths) = standard_scene();
    let rec = Recognizer::new(&model(), {
        let mut p = Params::default();
        p.runtime.threads = 2;
        p
    })
    .unwrap();
    let reference = rec.recognize(&cloud).unwrap().detections;
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..3)
            .map(|_| s.spawn(|| rec.recognize(&cloud).unwrap().detections))
            .collect();
        for h in handles {
            assert_eq!(h.join().unwrap(), reference);
        }
    });
    assert_eq!(reference.len(), truths.len());
}
