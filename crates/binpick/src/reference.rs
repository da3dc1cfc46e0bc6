//! The reference engine: thesis Algorithms 1 and 2 written directly in C++ against PCL
//! (`cpp/reference/pipeline.cpp`), reached through the bridge in one call per scene.
//!
//! It answers what [`Recognizer`](crate::Recognizer) answers with `thesis_strict = true`
//! (same PCL stages, settings, point orders and tie-breaks; `tests/parity.rs` checks it), but
//! is organised the way the thesis describes it rather than the way binpick is:
//!
//! | step                         | binpick (`Recognizer`)                 | reference (this module)                    |
//! |------------------------------|----------------------------------------|--------------------------------------------|
//! | model keypoints + FPFH       | once per model (`Recognizer::new`)     | again in every cluster (Alg. 1 step 1a-b)  |
//! | kd-trees                     | scene uploaded once, trees shared      | built by every PCL stage and every score   |
//! | validation scores            | kiddo kd-tree in Rust                  | `pcl::KdTreeFLANN` per call (3.1.1.3)      |
//! | ICP correspondences          | one batched FLANN query per iteration  | PCL's default (one query per point)        |
//! | parallelism                  | rayon over clusters, radii, thresholds | OpenMP `parallel for` over clusters (4.4)  |
//!
//! It always runs the thesis exactly (one detection per cluster, no duplicate suppression):
//! `thesis_strict`, `consensus_modes`, `symmetry_candidates`, `final_candidates` and
//! `duplicate_overlap` are not consulted. `time_budget_ms` is checked once the call returns
//! (the C++ loop cannot be interrupted): a late call is flagged in `Recognition::interrupted`
//! with its complete detections. The crop and stray-point removal run in Rust, shared with
//! `Recognizer`, before the C++ pipeline. `threads` sets the OpenMP team of the cluster loop (0 = OpenMP's default);
//! PCL's OpenMP estimators inside it keep their default thread count.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use binpick_cloud::{Point, PointCloud};
use binpick_pcl::{ClusterOutcome, ReferenceParams, ReferenceResult};

use crate::deadline::{Deadline, ms};
use crate::error::{InputKind, Result, input_as, pcl};
use crate::params::{Algorithm, FeatureSurface, Params};
use crate::result::{
    ClusterReport, Detection, FoundBy, IcpReport, Interruption, PreprocessReport, Recognition,
    RemovedPlane, SearchStop, StopCause, Timings,
};
use crate::stages::preprocess::{check_units, clean_scene};
use crate::stages::rank::{height_mm, rank_detections};

/// Where the reference spent its time, ms. Stages inside the cluster loop add up the work of
/// all OpenMP threads (the thesis's pie charts, 5.7).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ReferenceStages {
    /// The model's keypoints and FPFH, recomputed in every cluster.
    pub model_features_ms: f64,
    /// Each cluster's uniform keypoints.
    pub cluster_keypoints_ms: f64,
    /// Each cluster's normals and FPFH descriptors.
    pub cluster_fpfh_ms: f64,
    /// FPFH matching (and Algorithm 2's merge).
    pub correspondences_ms: f64,
    /// RANSAC correspondence rejection.
    pub rejection_ms: f64,
    /// SVD pose estimates of the consensus sets.
    pub svd_ms: f64,
    /// Euclidean validation scores of the threshold sweep (a kd-tree each).
    pub euclidean_score_ms: f64,
    /// ICP, the final alignment.
    pub icp_ms: f64,
    /// Percent-of-outliers scores (and the Euclidean tie-break) of the final alignment.
    pub outlier_score_ms: f64,
    /// OpenMP threads that ran the cluster loop.
    pub omp_threads: u32,
    /// The OpenMP runtime's max active levels: 1 means PCL's OpenMP estimators inside the
    /// cluster loop run on one thread each (nested regions are serialised).
    pub omp_max_active_levels: i32,
}

/// A reference run: the same [`Recognition`] as `Recognizer::recognize` plus the stage
/// breakdown.
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceRun {
    /// The detections and reports.
    pub recognition: Recognition,
    /// Where the time went.
    pub stages: ReferenceStages,
}

/// Recognises every instance of `model` in `scene` (both millimetres) with the reference
/// C++ pipeline; detections ranked by the thesis ranking like `Recognizer::recognize`.
/// `timings.model_preparation_ms` is the reference's up-front model check; `total_ms` is the
/// whole call, model work included (the thesis has no separate preparation).
pub fn recognize_reference(
    model: &PointCloud,
    scene: &PointCloud,
    params: &Params,
) -> Result<Recognition> {
    recognize_reference_detailed(model, scene, params).map(|r| r.recognition)
}

/// [`recognize_reference`] plus the per-stage timings.
pub fn recognize_reference_detailed(
    model: &PointCloud,
    scene: &PointCloud,
    params: &Params,
) -> Result<ReferenceRun> {
    let start = Instant::now();
    params.validate()?;
    check_units("model", model, &params.preprocess)?;
    // The crop and stray-point removal are binpick's, shared with the Rust engine (the C++
    // pipeline then gets no region of interest): both engines see the same points.
    let mut cleaning = PreprocessReport::default();
    let cleaned = clean_scene(
        scene,
        &params.preprocess,
        &Deadline::unlimited(),
        &mut cleaning,
    )?;
    let clean_ms = ms(start.elapsed());
    let mut flat = reference_params(params);
    flat.roi_enabled = false;
    let raw = binpick_pcl::reference_recognize(&model.points, &cleaned, &flat)
        .map_err(pcl("reference pipeline"))?;
    let mut run = convert(raw, params)?;
    let pre = &mut run.recognition.preprocess;
    pre.input_points = cleaning.input_points;
    pre.outside_roi = cleaning.outside_roi;
    pre.isolated_removed = cleaning.isolated_removed;
    run.recognition.timings.preprocess_ms += clean_ms;
    let t = Instant::now();
    rank_detections(
        &mut run.recognition.detections,
        params.ranking.rank_score_band_pct,
    );
    run.recognition.timings.ranking_ms = ms(t.elapsed());
    let elapsed = start.elapsed();
    run.recognition.timings.total_ms = ms(elapsed);
    // The C++ loop cannot be interrupted: the budget is checked at return, and a late call
    // is flagged (its detections are complete).
    if let Some(budget) = params.runtime.time_budget_ms
        && elapsed.as_millis() > u128::from(budget)
    {
        run.recognition.interrupted = Some(Interruption {
            cause: StopCause::TimeBudget,
            budget_ms: Some(budget as f64),
            stage: "return".into(),
            elapsed_ms: ms(elapsed),
        });
    }
    Ok(run)
}

/// `params` as the bridge's flat struct.
pub fn reference_params(p: &Params) -> ReferenceParams {
    let pre = &p.preprocess;
    let roi = pre.region_of_interest;
    let (cl, f, c, icp) = (&p.clustering, &p.features, &p.consensus, &p.icp);
    ReferenceParams {
        algorithm: p.algorithm.number(),
        resolution: pre.resolution(),
        roi_enabled: roi.is_some(),
        roi_min: roi.map_or([0.0; 3], |r| r.min_mm),
        roi_max: roi.map_or([0.0; 3], |r| r.max_mm),
        support_enabled: pre.support.enabled,
        support_distance: pre.support.distance(pre.resolution()),
        support_max_planes: pre.support.max_planes,
        support_min_points_factor: pre.support.min_points_factor,
        support_ransac_iterations: pre.support.ransac_iterations,
        cluster_tolerance_factor: cl.cluster_tolerance_factor,
        cluster_min_factor: cl.cluster_min_factor,
        cluster_max_factor: cl.cluster_max_factor,
        initial_leaf: f.initial_leaf_mm,
        fpfh_radii: f.fpfh_radii_mm.clone(),
        normal_radius_factor: f.normal_radius_factor,
        feature_surface_cloud: f.feature_surface == FeatureSurface::Cloud,
        sac_thresholds: c.sac_thresholds_mm.clone(),
        sac_iterations: c.sac_iterations,
        initial_score_max: c.initial_score_max,
        final_leaf: icp.final_leaf_mm,
        icp_iterations: icp.icp_iterations,
        icp_transformation_epsilon: icp.icp_transformation_epsilon,
        icp_max_correspondence: icp.icp_max_correspondence_mm,
        outlier_distance: p.validation.outlier_distance_mm,
        final_score_max: p.validation.final_score_max_pct,
        scene_viewpoint: f.scene_viewpoint_mm,
        model_viewpoint: f.model_viewpoint_mm,
        threads: u32::try_from(p.runtime.threads).unwrap_or(u32::MAX),
    }
}

/// The bridge's result as a [`Recognition`] (detections not yet ranked), with the cluster
/// outcomes worded as the Rust engine words them.
fn convert(r: ReferenceResult, p: &Params) -> Result<ReferenceRun> {
    let final_kp: Vec<Point> = r
        .model_final_keypoints
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let not_rigid = || {
        input_as(
            "reference pipeline",
            InputKind::Internal,
            "returned a pose that is not rigid",
        )
    };
    let mut detections = Vec::with_capacity(r.detections.len());
    for d in &r.detections {
        let pose = d.pose().ok_or_else(not_rigid)?;
        let fpfh_radius_mm = usize::try_from(d.fpfh_radius_index)
            .ok()
            .and_then(|i| p.features.fpfh_radii_mm.get(i).copied());
        if p.algorithm == Algorithm::SeparatedFpfh && fpfh_radius_mm.is_none() {
            return Err(input_as(
                "reference pipeline",
                InputKind::Internal,
                format!("returned FPFH radius index {}", d.fpfh_radius_index),
            ));
        }
        let error = d.icp_error().map(|e| e.to_string());
        detections.push(Detection {
            rank: 0,
            pose,
            initial_pose: d.initial_pose().ok_or_else(not_rigid)?,
            initial_score: d.initial_score,
            final_score: d.final_score,
            score_before_icp: d.score_before_icp,
            found_by: FoundBy::Cluster {
                cluster: d.cluster as usize,
                round: 0,
                fpfh_radius_mm,
                sac_threshold_mm: d.sac_threshold,
                sac_inliers: d.sac_inliers as usize,
            },
            view: None,
            icp: IcpReport {
                converged: d.icp_converged,
                iterations: d.icp_iterations,
                fitness_mm2: error
                    .is_none()
                    .then(|| IcpReport::usable_fitness(d.icp_fitness))
                    .flatten(),
                adopted: d.icp_adopted,
                unhidden: false,
                polished: false,
                error,
            },
            height_mm: height_mm(&pose, &final_kp, p.ranking.up),
            rank_reason: String::new(),
            free_to_pick: true,
            grasps: Vec::new(),
        });
    }
    let clusters = r
        .clusters
        .iter()
        .enumerate()
        .map(|(index, c)| {
            let accepted = c.outcome == ClusterOutcome::Accepted;
            let (initial_max, final_max) = (
                p.consensus.initial_score_max,
                p.validation.final_score_max_pct,
            );
            let stop = match c.outcome {
                ClusterOutcome::InitialRejected => SearchStop::InitialRejected {
                    score: c.score,
                    max: initial_max,
                },
                ClusterOutcome::FinalRejected => SearchStop::FinalRejected {
                    score: c.score,
                    max: final_max,
                },
                ClusterOutcome::Accepted => SearchStop::Accepted,
                _ => SearchStop::NoConsensus,
            };
            ClusterReport {
                index,
                points: c.points as usize,
                detections: usize::from(accepted),
                regions: 1,
                outcome: stop.outcome(usize::from(accepted)),
            }
        })
        .collect();
    let t = &r.timings;
    let recognition = Recognition {
        detections,
        preprocess: PreprocessReport {
            input_points: r.input_points as usize,
            outside_roi: r.outside_roi as usize,
            isolated_removed: 0,
            voxel_merged: r.voxel_merged as usize,
            support_band_mm: None,
            support_noise: 0,
            support_planes: r
                .support_planes
                .iter()
                .map(|s| RemovedPlane {
                    coefficients: s.coefficients,
                    points: s.points as usize,
                    rms_mm: None,
                })
                .collect(),
            remaining: r.remaining as usize,
        },
        scale: None,
        voting: None,
        clusters,
        duplicates_suppressed: 0,
        interrupted: None,
        frame: crate::frames::OutputFrame::scanner(),
        timings: Timings {
            model_preparation_ms: t.model_preparation_ms,
            queue_ms: 0.0,
            preprocess_ms: t.preprocess_ms,
            clustering_ms: t.clustering_ms,
            initial_alignment_ms: t.initial_alignment_ms,
            final_alignment_ms: t.final_alignment_ms,
            ranking_ms: 0.0,
            total_ms: t.total_ms,
        },
    };
    Ok(ReferenceRun {
        recognition,
        stages: ReferenceStages {
            model_features_ms: t.model_features_ms,
            cluster_keypoints_ms: t.cluster_keypoints_ms,
            cluster_fpfh_ms: t.cluster_fpfh_ms,
            correspondences_ms: t.correspondences_ms,
            rejection_ms: t.rejection_ms,
            svd_ms: t.svd_ms,
            euclidean_score_ms: t.euclidean_score_ms,
            icp_ms: t.icp_ms,
            outlier_score_ms: t.outlier_score_ms,
            omp_threads: t.omp_threads,
            omp_max_active_levels: t.omp_max_active_levels,
        },
    })
}
