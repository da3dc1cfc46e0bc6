//! Development probe for the pile engine (temporary): runs PPF voting + view verification on
//! dataset scenes and scores against ground truth.
//! usage: ppf_probe DATASET MODEL [max_scenes] [key=value ...]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::PathBuf;
use std::time::Instant;

use binpick::eval::{TruthInstance, score_scene, scoring_points};
use binpick::{Params, Units, load_cloud};
use binpick_cloud::dataset::{Dataset, GroundTruth, ModelInfo};
use binpick_match::poses::cluster_poses;
use binpick_match::*;
use binpick_pcl::{IcpParams, IndexedCloud};
use nalgebra::{Isometry3, Point3};

/// (spacing, gap): sqrt(area per point) from the 8th-neighbour distance, and that distance.
fn nn_median(points: &[[f32; 3]]) -> (f64, f64) {
    let idx = PointIndex::new("scene", points).unwrap();
    let step = (points.len() / 3000).max(1);
    let mut d: Vec<f64> = Vec::new();
    let mut buf = Vec::new();
    for p in points.iter().step_by(step) {
        idx.within_into(p, 20.0, &mut buf);
        let mut dist: Vec<f32> = buf
            .iter()
            .map(|&k| {
                let q = points[k as usize];
                (0..3).map(|i| (q[i] - p[i]).powi(2)).sum::<f32>()
            })
            .filter(|&dd| dd > 1e-12)
            .collect();
        dist.sort_by(f32::total_cmp);
        if let Some(&d8) = dist.get(7) {
            d.push(f64::from(d8.sqrt()));
        }
    }
    d.sort_by(f64::total_cmp);
    let g = d[d.len() / 2];
    ((std::f64::consts::PI / 8.0).sqrt() * g, g)
}

fn arg(kv: &[(String, String)], k: &str, default: f64) -> f64 {
    kv.iter()
        .find(|(a, _)| a == k)
        .map(|(_, v)| v.parse().unwrap())
        .unwrap_or(default)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let ds = Dataset::open(&PathBuf::from(&args[1])).unwrap();
    let model_name = &args[2];
    let max_scenes: usize = args.get(3).map(|s| s.parse().unwrap()).unwrap_or(1000);
    let kv: Vec<(String, String)> = args[4.min(args.len())..]
        .iter()
        .map(|s| {
            let (a, b) = s.split_once('=').unwrap();
            (a.to_owned(), b.to_owned())
        })
        .collect();
    let info = ModelInfo::load(&ds.model_info_path(model_name)).unwrap();
    let (model_cloud, _) = load_cloud(&ds.model_cloud_path(model_name), Units::Millimetres).unwrap();
    let d = info.diameter;
    let symmetries: Vec<Isometry3<f64>> = info
        .symmetries
        .iter()
        .map(|m| binpick::pose::from_mat4(m).unwrap())
        .collect();
    let syms = Symmetries::new(&symmetries);
    let scoring = scoring_points(&model_cloud.points, 2000);

    let mut totals = (0usize, 0usize, 0usize, 0usize, 0usize, 0usize);
    let mut times = Vec::new();
    let mut n = 0;
    for id in &ds.scene_ids {
        let gt = GroundTruth::load(&ds.gt_path(id)).unwrap();
        if &gt.model != model_name {
            continue;
        }
        n += 1;
        if n > max_scenes {
            break;
        }
        let (scene, _) = load_cloud(&ds.scene_path(&gt), Units::Millimetres).unwrap();
        let t0 = Instant::now();
        let (r, gap) = nn_median(&scene.points);
        let res = arg(&kv, "res", r.max(d / arg(&kv, "leaf_div", 100.0)));
        let delta = arg(&kv, "delta_rel", 0.04) * d;
        let delta = delta.max(arg(&kv, "delta_res", 2.0) * res);
        let rho = arg(&kv, "rho", (3.0 * res).max(0.5 * delta));
        let cellw = gap.max(res);
        let cell = arg(&kv, "cell", 1.0) * cellw;
        let tol = arg(&kv, "tol", 2.0) * cellw;
        // Preprocess with the library (voxel + support removal).
        let mut params = Params::default();
        params.resolution_mm = res;
        params.cluster_tolerance_factor = (1.5 * gap / res).clamp(1.0, 10.0);
        params.support.distance_mm = 1.5 * res;
        let model_vox = binpick_pcl::voxel_grid(&model_cloud.points, res as f32).unwrap();
        let (world, report) =
            binpick::scene::preprocess(&scene, &params, model_vox.len(), 2).unwrap();
        let vox = binpick_pcl::voxel_grid(&scene.points, res as f32).unwrap();
        let background: Vec<bool> = vox
            .iter()
            .map(|p| {
                report.support_planes.iter().any(|pl| {
                    let c = pl.coefficients;
                    (c[0] * p[0] + c[1] * p[1] + c[2] * p[2] + c[3]).abs()
                        <= 1.5 * params.support.distance_mm as f32
                })
            })
            .collect();
        let t_pre = t0.elapsed();
        // Scene samples with normals.
        let far = [0.0f32, 0.0, 1e5];
        let normals = binpick_pcl::estimate_normals(&world, rho as f32, far, 2).unwrap();
        let sidx = binpick_pcl::uniform_sampling(&world, delta as f32).unwrap();
        let scene_s = OrientedPoints {
            points: sidx.iter().map(|&i| world[i as usize]).collect(),
            normals: sidx.iter().map(|&i| normals[i as usize].normal).collect(),
        }
        .with_defined_normals();
        // Model samples and dense model.
        let mview = model_viewpoint(model_name);
        let mnormals = binpick_pcl::estimate_normals(&model_vox, rho as f32, mview, 2).unwrap();
        let dense = OrientedPoints {
            points: model_vox.clone(),
            normals: mnormals.iter().map(|n| n.normal).collect(),
        }
        .with_defined_normals();
        let midx = binpick_pcl::uniform_sampling(&dense.points, delta as f32).unwrap();
        let model_s = OrientedPoints {
            points: midx.iter().map(|&i| dense.points[i as usize]).collect(),
            normals: midx.iter().map(|&i| dense.normals[i as usize]).collect(),
        };
        let t1 = Instant::now();
        let table = PpfModel::new(
            &model_s,
            PpfConfig {
                distance_step_mm: delta,
                feature_angle_bins: arg(&kv, "abins", 15.0) as u32,
                alpha_bins: 30,
                max_pair_distance_mm: d,
                spread: arg(&kv, "spread", 0.25),
                max_pairs_per_bin: arg(&kv, "cap", 200.0) as u32,
            },
        )
        .unwrap();
        let t_model = t1.elapsed();
        let t2 = Instant::now();
        let index = PointIndex::new("scene", &scene_s.points).unwrap();
        let votes = table
            .vote(
                &scene_s,
                &index,
                &VotingConfig {
                    reference_stride: arg(&kv, "stride", 2.0) as usize,
                    peaks_per_reference: arg(&kv, "peaks", 3.0) as usize,
                    secondary_peak_ratio: 0.6,
                },
            )
            .unwrap();
        let centre = {
            let c = model_cloud.centroid().unwrap();
            Point3::new(c[0], c[1], c[2])
        };
        let clusters = cluster_poses(
            &votes,
            &centre,
            &syms,
            &PoseClustering {
                translation_mm: 0.1 * d,
                rotation_deg: 24.0,
            },
        )
        .unwrap();
        let t_vote = t2.elapsed();
        let t3 = Instant::now();
        let k = arg(&kv, "k", 60.0) as usize;
        let grid = RangeGrid::new(
            Sensor::orthographic([0.0, 0.0, 1.0]).unwrap(),
            &ViewConfig {
                cell_mm: cell,
                tolerance_mm: tol,
                max_incidence_deg: 75.0,
            },
            &vox,
            &background,
        )
        .unwrap();
        let vcfg = ViewConfig {
            cell_mm: cell,
            tolerance_mm: tol,
            max_incidence_deg: 75.0,
        };
        let target = IndexedCloud::new(&world).unwrap();
        let refined: Vec<Isometry3<f64>> = clusters
            .iter()
            .take(k)
            .map(|c| {
                let mut pose = c.pose;
                for (dist, iters) in [(2.0 * delta, 15), (3.0 * res, 15)] {
                    let vis = grid.visible_model_points(&model_s_dense(&dense), &pose, &vcfg);
                    let src: Vec<[f32; 3]> = vis
                        .iter()
                        .step_by(2)
                        .map(|&i| dense.points[i as usize])
                        .collect();
                    if src.len() < 10 {
                        break;
                    }
                    if let Ok(o) = target.icp(
                        &src,
                        &IcpParams {
                            initial: binpick::pose::to_mat4(&pose),
                            max_correspondence_distance: dist,
                            max_iterations: iters,
                            transformation_epsilon: 1e-6,
                            batch_correspondences: true,
                            relative_mse: 1e-4,
                        },
                    ) {
                        if let Some(p) = binpick::pose::from_mat4(&o.transform) {
                            pose = p;
                        }
                    }
                }
                pose
            })
            .collect();
        let scores: Vec<ViewScore> = refined.iter().map(|p| grid.score(&dense, p, &vcfg)).collect();
        let ecfg = ExplainConfig {
            min_visibility: arg(&kv, "minvis", 0.25),
            max_free_space: arg(&kv, "maxfree", 0.08),
            min_explained_cells: (arg(&kv, "mincells", 0.1) * dense.len() as f64) as u32,
            free_space_weight: 2.0,
            min_new_share: 0.5,
        };
        let ex = explain_scene(&scores, grid.cells(), &ecfg).unwrap();
        let t_verify = t3.elapsed();
        let total = t0.elapsed();
        times.push(total.as_secs_f64() * 1000.0);
        // Rank: uncovered first, then visibility.
        let mut taken = ex.taken.clone();
        taken.sort_by(|&a, &b| {
            let (sa, sb) = (&scores[a], &scores[b]);
            (sa.covered_ratio() > 0.03)
                .cmp(&(sb.covered_ratio() > 0.03))
                .then(sb.visibility().total_cmp(&sa.visibility()))
        });
        let truth: Vec<TruthInstance> = gt
            .instances
            .iter()
            .map(|i| TruthInstance {
                pose: binpick::pose::from_mat4(&i.pose).unwrap(),
                pickable: i.pickable,
            })
            .collect();
        let dets: Vec<(usize, Isometry3<f64>)> = taken
            .iter()
            .enumerate()
            .map(|(r, &i)| (r + 1, refined[i]))
            .collect();
        let s = score_scene(&scoring, &symmetries, d, &truth, &dets, 0.1);
        // Does any candidate (before verification) hit each pickable instance?
        let cand: Vec<(usize, Isometry3<f64>)> =
            refined.iter().enumerate().map(|(r, p)| (r + 1, *p)).collect();
        let sc = score_scene(&scoring, &symmetries, d, &truth, &cand, 0.1);
        totals.0 += s.pickable;
        totals.1 += s.recognised_pickable;
        totals.2 += s.false_positives;
        totals.3 += usize::from(s.false_best);
        totals.4 += sc.recognised_pickable;
        totals.5 += usize::from(s.starvation);
        println!(
            "{id}: r={res:.2} delta={delta:.1} pts={} world={} samples={} model_s={} entries={} votes={} clusters={} | P={} R={} FP={} FB={} cand_R={} | pre {:.0} model {:.0} vote {:.0} verify {:.0} total {:.0} ms",
            scene.len(),
            world.len(),
            scene_s.len(),
            model_s.len(),
            table.entries(),
            votes.len(),
            clusters.len(),
            s.pickable,
            s.recognised_pickable,
            s.false_positives,
            s.false_best,
            sc.recognised_pickable,
            t_pre.as_secs_f64() * 1e3,
            t_model.as_secs_f64() * 1e3,
            t_vote.as_secs_f64() * 1e3,
            t_verify.as_secs_f64() * 1e3,
            total.as_secs_f64() * 1e3,
        );
        if std::env::var("PROBE_GT").is_ok() {
            println!("   spacing {r:.3} gap {gap:.3}; support planes {:?}", report.support_planes.iter().map(|p| p.points).collect::<Vec<_>>());
            for (k, t) in truth.iter().enumerate() {
                let g = grid.score(&dense, &t.pose, &vcfg);
                let near_vote = votes.iter().filter(|v| binpick::eval::pose_error_mm(&scoring, &v.pose, &t.pose, &symmetries) < 0.1 * d).count();
                let near_cluster = clusters.iter().position(|c| binpick::eval::pose_error_mm(&scoring, &c.pose, &t.pose, &symmetries) < 0.1 * d);
                println!("   gt {k} pickable {} vis_gt {:.2} | view: vis {:.2} free {:.3} cov {:.2} expl {} visible {} | votes near {near_vote} first cluster {near_cluster:?}",
                    t.pickable, gt.instances[k].visible_fraction, g.visibility(), g.free_space_ratio(), g.covered_ratio(), g.explained, g.visible);
            }
        }
        if std::env::var("PROBE_VERBOSE").is_ok() {
            for (rank, &i) in taken.iter().enumerate() {
                let v = &s.detections[rank];
                let sc = &scores[i];
                println!(
                    "   #{} cand {} {:?} err {:.1} vis {:.2} free {:.3} cov {:.2} expl {} visible {}",
                    rank + 1,
                    i,
                    v.verdict,
                    v.error_mm,
                    sc.visibility(),
                    sc.free_space_ratio(),
                    sc.covered_ratio(),
                    sc.explained,
                    sc.visible
                );
            }
            for (k, v) in sc.detections.iter().enumerate() {
                if v.verdict != binpick::eval::Verdict::FalsePositive {
                    let sc = &scores[k];
                    println!(
                        "   cand {} {:?} inst {:?} err {:.1} vis {:.2} free {:.3} rej {:?}",
                        k, v.verdict, v.instance, v.error_mm, sc.visibility(), sc.free_space_ratio(), ex.rejected[k]
                    );
                }
            }
        }
    }
    times.sort_by(f64::total_cmp);
    println!(
        "TOTAL scenes={} P={} R={} ({:.1} %) FP={} FB={} S={} cand_R={} median {:.0} ms",
        times.len(),
        totals.0,
        totals.1,
        100.0 * totals.1 as f64 / totals.0.max(1) as f64,
        totals.2,
        totals.3,
        totals.5,
        totals.4,
        times.get(times.len() / 2).copied().unwrap_or(0.0)
    );
}

/// Where the model scanner sat, in the model frame (synth datasets: above the canonical pose).
fn model_viewpoint(name: &str) -> [f32; 3] {
    use binpick_synth::parts::{PartKind, PartLibrary};
    let kind = match name.split('-').next() {
        Some("A") => PartKind::A,
        Some("B") => PartKind::B,
        _ => PartKind::C,
    };
    let lib = PartLibrary::new().unwrap();
    let pose = binpick_synth::physics::canonical_pose(&lib, kind).unwrap();
    let v = pose.inverse() * Point3::new(0.0, 0.0, 1e5);
    [v.x as f32, v.y as f32, v.z as f32]
}

fn model_s_dense(d: &OrientedPoints) -> OrientedPoints {
    d.clone()
}
