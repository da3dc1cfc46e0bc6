//! One criterion benchmark per stage of the default (scene-voting) engine on the bundled
//! sample (`data/sample`: part A's scanned model and a 167 k-point conveyor scan of five A),
//! so that a regression in one stage shows on its own:
//!
//! | group/bench             | stage                                                   |
//! |-------------------------|---------------------------------------------------------|
//! | `load/scene_pcd`        | reading the binary PCD                                  |
//! | `model/prepare`         | part surface -> point-pair table and near-symmetries at |
//! |                         | the scale derived from the scan                         |
//! | `model/read_prepared`   | the same, read from a `.prepared` file                  |
//! | `scene/normals`         | PCL normals of the voxelised scan at the normal radius  |
//! | `voting/vote`           | point-pair voting of the scene samples (belt removed)   |
//! | `verify/icp`            | one candidate's ICP (PCL) on the scene                  |
//! | `verify/view_grid`      | the sensor's range grid of the scene                    |
//! | `verify/view_score`     | one candidate judged against the grid                   |
//! | `recognize/sample`      | the whole call, model prepared                          |
//!
//! `cargo bench -p binpick --bench stages` (add `-- --quick` for a fast pass).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

use binpick::{DerivedScale, Params, Part, PointCloud, Recognizer, Units, load_cloud, load_part};
use binpick_match::{
    OrientedPoints, PointIndex, PpfConfig, PpfModel, RangeGrid, Sensor, ViewConfig, VotingConfig,
    subsample_by_facing,
};
use binpick_pcl::{IcpParams, IndexedCloud};

/// Model points one candidate's ICP aligns (as the engine).
const ICP_POINTS: usize = 800;

fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../data/sample")
        .join(rel)
}

struct Sample {
    part: Part,
    scene: PointCloud,
    /// The first labelled instance's pose, model -> scene.
    truth: Isometry3<f64>,
}

fn sample() -> Sample {
    let params = Params::default();
    let (part, _) = load_part(&data("models/A.pcd"), Units::Millimetres, &params)
        .unwrap_or_else(|e| panic!("bundled model: {e}"));
    let (scene, _) = load_cloud(&data("scenes/conveyor-A.pcd"), Units::Millimetres)
        .unwrap_or_else(|e| panic!("bundled scene: {e}"));
    let gt: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(data("gt/conveyor-A__A.json")).expect("bundled ground truth"),
    )
    .expect("ground truth JSON");
    let m: Vec<f64> = gt["instances"][0]["pose"]
        .as_array()
        .expect("pose")
        .iter()
        .map(|v| v.as_f64().expect("number"))
        .collect();
    let m: [f64; 16] = m.try_into().expect("16 numbers");
    let truth = binpick_cloud::pose_from_row_major(&m).expect("rigid pose");
    Sample { part, scene, truth }
}

/// The default `[voting]` table at the scan's sampling step.
fn ppf_config(part: &Part, scale: &DerivedScale) -> PpfConfig {
    let v = Params::default().voting;
    PpfConfig {
        distance_step_mm: scale.sampling_step_mm,
        feature_angle_bins: v.feature_angle_bins,
        alpha_bins: v.alpha_bins,
        max_pair_distance_mm: part.size.diameter_mm,
        spread: v.spread,
        max_pairs_per_bin: v.max_pairs_per_bin,
    }
}

/// The default `[voting]` scene search.
fn search_config() -> VotingConfig {
    let v = Params::default().voting;
    VotingConfig {
        reference_stride: v.reference_stride,
        peaks_per_reference: v.peaks_per_reference,
        secondary_peak_ratio: v.secondary_peak_ratio,
        distinct_pairs: v.distinct_pairs,
    }
}

fn oriented(points: &[[f32; 3]], radius_mm: f64) -> OrientedPoints {
    let normals = binpick_pcl::estimate_normals(points, radius_mm as f32, [0.0, 0.0, 1e7], 0)
        .expect("normals");
    OrientedPoints {
        points: points.to_vec(),
        normals: normals.iter().map(|n| n.normal).collect(),
    }
}

fn stages(c: &mut Criterion) {
    let s = sample();
    let params = Params::default();
    // The lengths the engine derives for this scan, and the model prepared for them.
    let recognizer = Recognizer::with_part(s.part.clone(), params.clone()).expect("recognizer");
    let scale = recognizer.prepare_for(&s.scene).expect("scale");
    let res = scale.resolution_mm;
    let voxels = binpick_pcl::voxel_grid(&s.scene.points, res as f32).expect("voxel grid");
    let scene = oriented(&voxels, scale.normal_radius_mm);
    // Only the parts (above the belt at z = 0) vote and are aligned to, as in the engine.
    let support: Vec<bool> = voxels
        .iter()
        .map(|p| f64::from(p[2]) <= scale.support_distance_mm)
        .collect();
    let keep: Vec<usize> = (0..voxels.len()).filter(|&i| !support[i]).collect();
    let world = OrientedPoints {
        points: keep.iter().map(|&i| scene.points[i]).collect(),
        normals: keep.iter().map(|&i| scene.normals[i]).collect(),
    };
    let picked = binpick_pcl::uniform_sampling(&world.points, scale.sampling_step_mm as f32)
        .expect("samples");
    let samples = OrientedPoints {
        points: picked.iter().map(|&i| world.points[i as usize]).collect(),
        normals: picked.iter().map(|&i| world.normals[i as usize]).collect(),
    }
    .with_defined_normals();
    let dense = subsample_by_facing(&s.part.surface, res);
    let near = s.truth
        * Isometry3::from_parts(
            Translation3::new(1.5, -1.0, 0.5),
            UnitQuaternion::from_euler_angles(0.03, -0.02, 0.04),
        );

    let mut g = c.benchmark_group("load");
    g.sample_size(10);
    g.bench_function("scene_pcd", |b| {
        b.iter(|| load_cloud(&data("scenes/conveyor-A.pcd"), Units::Millimetres).expect("scene"))
    });
    g.finish();

    let mut g = c.benchmark_group("model");
    g.sample_size(10);
    g.bench_function("prepare", |b| {
        b.iter(|| {
            let r = Recognizer::with_part(s.part.clone(), params.clone()).expect("recognizer");
            r.prepare_for(&s.scene).expect("prepared")
        })
    });
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("A.prepared");
    recognizer
        .write_prepared(&file, &data("models/A.pcd"), Units::Millimetres)
        .expect("prepared file");
    g.bench_function("read_prepared", |b| {
        b.iter(|| {
            let (part, _) = load_part(&file, Units::Millimetres, &params).expect("prepared read");
            Recognizer::with_part(part, params.clone()).expect("recognizer")
        })
    });
    g.finish();

    let mut g = c.benchmark_group("scene");
    g.sample_size(10);
    g.bench_function("normals", |b| {
        b.iter(|| oriented(black_box(&voxels), scale.normal_radius_mm))
    });
    // The scan's spacing (8th-nearest distinct neighbour of 2000 points): the grid the engine
    // uses against the kd-tree it replaced, same answers.
    let queries: Vec<[f32; 3]> = {
        let step = (s.scene.len() / 2000).max(1);
        s.scene.points.iter().step_by(step).copied().collect()
    };
    g.bench_function("spacing_grid", |b| {
        b.iter(|| {
            binpick_match::index::kth_nearest_distinct_on_grid(
                black_box(&s.scene.points),
                &queries,
                8,
            )
            .expect("grid")
        })
    });
    g.bench_function("spacing_kd_tree", |b| {
        b.iter(|| {
            let index = PointIndex::new("scene", black_box(&s.scene.points)).expect("index");
            queries
                .iter()
                .map(|q| index.kth_nearest_distinct(q, 8))
                .collect::<Vec<_>>()
        })
    });
    g.finish();

    let model_samples = subsample_by_facing(&dense, scale.sampling_step_mm);
    let table = PpfModel::new(&model_samples, ppf_config(&s.part, &scale)).expect("table");
    let index = PointIndex::new("samples", &samples.points).expect("index");
    let mut g = c.benchmark_group("voting");
    g.sample_size(10);
    g.bench_function("vote", |b| {
        b.iter(|| {
            table
                .vote(&samples, &index, &search_config())
                .expect("votes")
        })
    });
    g.finish();

    let target = IndexedCloud::new(&world.points).expect("target");
    let step = dense.len().div_ceil(ICP_POINTS);
    let src: Vec<[f32; 3]> = dense.points.iter().step_by(step).copied().collect();
    let view = ViewConfig {
        cell_mm: scale.cell_mm,
        tolerance_mm: scale.tolerance_mm,
        max_incidence_deg: 75.0,
        max_normal_angle_deg: 45.0,
        support_band_mm: scale.support_distance_mm,
        outline_neighbour_weight: Params::default().verify.outline_neighbour_weight,
    };
    let sensor = || Sensor::orthographic([0.0, 0.0, 1.0]).expect("sensor");
    let grid = RangeGrid::new(
        sensor(),
        &view,
        &scene.points,
        &support,
        Some(&scene.normals),
    )
    .expect("grid");
    let mut g = c.benchmark_group("verify");
    g.sample_size(20);
    g.bench_function("icp", |b| {
        b.iter(|| {
            target
                .icp(
                    &src,
                    &IcpParams {
                        initial: binpick_pcl::row_major(&near),
                        max_correspondence_distance: 2.0 * scale.sampling_step_mm,
                        max_iterations: params.verify.refine_iterations,
                        transformation_epsilon: 1e-6 * res * res,
                        batch_correspondences: true,
                        relative_mse: params.verify.refine_relative_mse,
                        reciprocal: false,
                    },
                )
                .expect("icp")
        })
    });
    g.bench_function("view_grid", |b| {
        b.iter(|| {
            RangeGrid::new(
                sensor(),
                &view,
                &scene.points,
                &support,
                Some(&scene.normals),
            )
            .expect("grid")
        })
    });
    g.bench_function("view_score", |b| {
        b.iter(|| grid.score(&dense, black_box(&near), &view))
    });
    g.finish();

    let mut g = c.benchmark_group("recognize");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(20));
    g.bench_function("sample", |b| {
        b.iter(|| recognizer.recognize(&s.scene).expect("recognition"))
    });
    g.finish();
}

criterion_group!(benches, stages);
criterion_main!(benches);
