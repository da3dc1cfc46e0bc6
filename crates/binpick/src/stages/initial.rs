//! Initial alignment of the model to one cluster (thesis Algorithms 1 and 2, steps 1-2) and
//! final alignment against the whole scene (steps 3-5).

use nalgebra::Isometry3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use binpick_cloud::Point;
use binpick_pcl::{Consensus, Correspondence, IcpParams, IndexedCloud};

use crate::deadline::Deadline;
use crate::error::{Error, Result, pcl};
use crate::features::{RadiusFeatures, feature_surface, fpfh_for_radius, keypoints};
use crate::model::PreparedModel;
use crate::params::{Algorithm, Params};
use crate::pose::{from_mat4, to_mat4};
use crate::validate::{NearestIndex, euclidean_score, outlier_percent};

/// The best initial alignment of a cluster (thesis 4.1 / 4.2 step 1b-D).
#[derive(Clone, Debug, PartialEq)]
pub struct InitialAlignment {
    /// Model -> scene.
    pub pose: Isometry3<f64>,
    /// Euclidean score (3.1.1) of the model keypoints against the cluster keypoints, mm^2.
    pub score: f64,
    /// The FPFH radius whose correspondences won (Algorithm 1); None for Algorithm 2, whose
    /// correspondences mix all radii.
    pub fpfh_radius_mm: Option<f64>,
    /// The RANSAC inlier threshold that won, mm.
    pub sac_threshold_mm: f64,
    /// Correspondences RANSAC kept for the winning transform.
    pub sac_inliers: usize,
}

/// How many of a cluster's best hypotheses are also tried composed with the model's
/// near-symmetries.
const SYMMETRY_EXPANDED: usize = 8;

/// One hypothesis of the threshold sweep; `order` breaks score ties (first in loop order wins).
struct Hypothesis {
    order: usize,
    alignment: InitialAlignment,
}

/// The uniform keypoints of a cluster (or of a sphere, remainder or split of one) and their
/// FPFH descriptors for every radius (thesis 4.1 step 1a-b).
#[derive(Clone, Debug)]
pub struct ClusterFeatures {
    pub keypoints: Vec<Point>,
    /// One entry per radius of `Params::fpfh_radii_mm`, keypoint indices into `keypoints`.
    pub features: Vec<RadiusFeatures>,
}

impl ClusterFeatures {
    /// Keypoints at the initial leaf and FPFH per radius (radii in parallel, PCL's OpenMP at
    /// one thread). `Ok(None)` with fewer than 3 keypoints.
    pub(crate) fn new(
        cluster: &[Point],
        params: &Params,
        deadline: &Deadline,
    ) -> Result<Option<Self>> {
        let keypoint_idx = keypoints(cluster, params.initial_leaf_mm)?;
        if keypoint_idx.len() < 3 {
            return Ok(None);
        }
        let keypoints: Vec<Point> = keypoint_idx.iter().map(|&i| cluster[i as usize]).collect();
        let (surface, surface_kp) = feature_surface(cluster, &keypoint_idx, &keypoints, params)?;
        let features = params
            .fpfh_radii_mm
            .par_iter()
            .map(|&r| {
                deadline.check("cluster FPFH")?;
                fpfh_for_radius(
                    &surface,
                    &surface_kp,
                    r,
                    params,
                    params.scene_viewpoint_mm,
                    1,
                )
            })
            .collect::<Result<_>>()?;
        Ok(Some(Self {
            keypoints,
            features,
        }))
    }
}

/// Thesis 4.1 / 4.2 steps 1b-D over a cluster (or, outside thesis_strict mode, a sphere,
/// remainder or split of one): every hypothesis of the sweep (one per correspondence set and
/// threshold that produced a transform), best Euclidean score first, so the first is the
/// thesis's initial alignment; ties keep the loop order (earlier radius and threshold first).
pub(crate) fn initial_hypotheses(
    model: &PreparedModel,
    cluster: &ClusterFeatures,
    params: &Params,
    deadline: &Deadline,
) -> Result<Vec<InitialAlignment>> {
    let kp = &cluster.keypoints;
    let world = NearestIndex::new(kp).map_err(|e| crate::error::input("cluster", e.to_string()))?;

    // (radius index or None, correspondences in keypoint indices)
    let mut sets: Vec<(Option<usize>, Vec<Correspondence>)> = Vec::new();
    for (r, (m, c)) in model.features.iter().zip(&cluster.features).enumerate() {
        if c.descriptors.is_empty() {
            continue;
        }
        let corrs = binpick_pcl::match_features(&m.descriptors, &c.descriptors)
            .map_err(pcl("feature matching"))?;
        let mapped = corrs
            .into_iter()
            .map(|k| Correspondence {
                query: m.keypoint[k.query as usize],
                matched: c.keypoint[k.matched as usize],
                distance: k.distance,
            })
            .collect();
        sets.push((Some(r), mapped));
    }
    if params.algorithm == Algorithm::MergedFpfh {
        sets = vec![(
            None,
            merge_best_per_model_keypoint(sets, model.initial_keypoints.len()),
        )];
    }

    let n_th = params.sac_thresholds_mm.len();
    let label = |radius: Option<usize>, t: usize, a: InitialAlignment| Hypothesis {
        order: radius.unwrap_or(0) * n_th + t,
        alignment: InitialAlignment {
            fpfh_radius_mm: radius.map(|r| params.fpfh_radii_mm[r]),
            ..a
        },
    };
    let hypotheses: Vec<Option<Hypothesis>> = if params.thesis_strict {
        // The thesis's sweep (step iii): one PCL rejector per threshold on the correspondences
        // as found. PCL seeds every run alike, so the runs share their draws and one pass per
        // correspondence set computes them all.
        sets.par_iter()
            .map(|(radius, corrs)| {
                deadline.check("RANSAC threshold sweep")?;
                Ok(threshold_sweep(model, kp, &world, corrs, params)?
                    .into_iter()
                    .enumerate()
                    .map(|(t, a)| a.map(|a| label(*radius, t, a)))
                    .collect::<Vec<_>>())
            })
            .collect::<Result<Vec<_>>>()?
            .into_iter()
            .flatten()
            .collect()
    } else {
        // Every (correspondence set, SAC threshold) pair is an independent hypothesis, its
        // RANSAC draws from a permutation stream keyed by (radius, threshold).
        let jobs: Vec<(usize, usize)> = (0..sets.len())
            .flat_map(|s| (0..n_th).map(move |t| (s, t)))
            .collect();
        jobs.par_iter()
            .map(|&(s, t)| {
                deadline.check("RANSAC threshold sweep")?;
                let (radius, corrs) = &sets[s];
                let stream = (radius.unwrap_or(0) * n_th + t) as u64;
                hypothesis(
                    model,
                    kp,
                    &world,
                    &shuffled(corrs, stream),
                    params.sac_thresholds_mm[t],
                    params,
                )
                .map(|h| h.map(|a| label(*radius, t, a)))
            })
            .collect::<Result<_>>()?
    };
    let mut all: Vec<Hypothesis> = hypotheses.into_iter().flatten().collect();
    all.sort_by(|a, b| {
        a.alignment
            .score
            .total_cmp(&b.alignment.score)
            .then(a.order.cmp(&b.order))
    });
    // The best few hypotheses, each composed with the model's near-symmetries (a flipped match
    // T of a nearly symmetric part becomes T * S, close to the true pose), scored the same way.
    let stride = params.fpfh_radii_mm.len() * n_th;
    let flips: Vec<Hypothesis> = all
        .iter()
        .take(SYMMETRY_EXPANDED)
        .flat_map(|h| {
            model.near_symmetries.iter().enumerate().map(|(k, s)| {
                let pose = h.alignment.pose * s;
                Hypothesis {
                    order: stride * (k + 1) + h.order,
                    alignment: InitialAlignment {
                        pose,
                        score: euclidean_score(&world, &model.initial_keypoints, &pose),
                        ..h.alignment.clone()
                    },
                }
            })
        })
        .collect();
    all.extend(flips);
    all.sort_by(|a, b| {
        a.alignment
            .score
            .total_cmp(&b.alignment.score)
            .then(a.order.cmp(&b.order))
    });
    Ok(all.into_iter().map(|h| h.alignment).collect())
}

/// All hypotheses for a whole cluster, without a time budget (diagnostics, tests).
pub fn initial_hypotheses_unbounded(
    model: &PreparedModel,
    cluster: &[Point],
    params: &Params,
) -> Result<Vec<InitialAlignment>> {
    let deadline = Deadline::new(None);
    match ClusterFeatures::new(cluster, params, &deadline)? {
        Some(cf) => initial_hypotheses(model, &cf, params, &deadline),
        None => Ok(Vec::new()),
    }
}

/// The correspondences in a pseudo-random order fixed by `stream`. PCL seeds every RANSAC
/// run with the same constant, so without this all thresholds of a sweep would draw the
/// same sample triples; the thesis treats each run as an independent random draw (3.4.2.5).
/// A fixed permutation per (radius, threshold) gives every run its own samples while keeping
/// results deterministic.
pub fn shuffled(corrs: &[Correspondence], stream: u64) -> Vec<Correspondence> {
    // SplitMix64 (Steele et al. 2014), seeded per stream.
    let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03);
    let mut next = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let mut out = corrs.to_vec();
    for i in (1..out.len()).rev() {
        let j = (next() % (i as u64 + 1)) as usize;
        out.swap(i, j);
    }
    out
}

/// Algorithm 2 step 1b-iii: all radii's correspondences in one set, keeping for each model
/// keypoint the match with the smallest descriptor distance (earlier radius on ties).
fn merge_best_per_model_keypoint(
    sets: Vec<(Option<usize>, Vec<Correspondence>)>,
    n_model: usize,
) -> Vec<Correspondence> {
    let mut best: Vec<Option<Correspondence>> = vec![None; n_model];
    for (_, corrs) in sets {
        for c in corrs {
            let slot = &mut best[c.query as usize];
            if slot.is_none_or(|b| c.distance < b.distance) {
                *slot = Some(c);
            }
        }
    }
    best.into_iter().flatten().collect()
}

/// Steps A-C for every threshold of the sweep on one correspondence set (thesis_strict):
/// PCL's rejector per threshold (computed in one pass), SVD on the kept pairs, Euclidean
/// score. One entry per threshold, `None` where nothing yields a proper rotation.
fn threshold_sweep(
    model: &PreparedModel,
    cluster_kp: &[Point],
    world: &NearestIndex,
    corrs: &[Correspondence],
    params: &Params,
) -> Result<Vec<Option<InitialAlignment>>> {
    let n_th = params.sac_thresholds_mm.len();
    if corrs.len() < 3 {
        return Ok(vec![None; n_th]);
    }
    let thresholds: Vec<f32> = params.sac_thresholds_mm.iter().map(|&t| t as f32).collect();
    let runs = binpick_pcl::reject_sample_consensus_sweep(
        &model.initial_keypoints,
        cluster_kp,
        corrs,
        &thresholds,
        params.sac_iterations,
    )
    .map_err(pcl("RANSAC rejection"))?
    .into_iter()
    .map(usable_consensus)
    .collect::<Result<Vec<_>>>()?;
    // Thresholds that keep the same pairs give the same SVD and score: compute those once.
    let mut seen: Vec<(&[Correspondence], Option<InitialAlignment>)> = Vec::new();
    let mut out = Vec::with_capacity(n_th);
    for (run, &threshold_mm) in runs.iter().zip(&params.sac_thresholds_mm) {
        let Some(consensus) = run else {
            out.push(None);
            continue;
        };
        let known = seen
            .iter()
            .find(|(kept, _)| *kept == consensus.kept.as_slice())
            .map(|(_, a)| a.clone());
        let alignment = match known {
            Some(a) => a,
            None => {
                let a = svd_and_score(model, cluster_kp, world, &consensus.kept)?;
                seen.push((&consensus.kept, a.clone()));
                a
            }
        };
        out.push(alignment.map(|a| InitialAlignment {
            sac_threshold_mm: threshold_mm,
            ..a
        }));
    }
    Ok(out)
}

/// A rejector run's consensus; `None` when RANSAC found none or its transform is not a
/// rotation (both mean "no hypothesis"), an error for anything else.
fn usable_consensus(run: binpick_pcl::Result<Consensus>) -> Result<Option<Consensus>> {
    match run {
        Ok(c) => Ok(Some(c)),
        Err(
            binpick_pcl::Error::NoConsensus { .. } | binpick_pcl::Error::ImproperRotation { .. },
        ) => Ok(None),
        Err(e) => Err(Error::Pcl {
            stage: "RANSAC rejection",
            source: e,
        }),
    }
}

/// Steps B-C: SVD on the correspondences RANSAC kept, then the Euclidean score of the model
/// keypoints placed by it. `Ok(None)` when fewer than 3 pairs or no proper rotation.
fn svd_and_score(
    model: &PreparedModel,
    cluster_kp: &[Point],
    world: &NearestIndex,
    kept: &[Correspondence],
) -> Result<Option<InitialAlignment>> {
    if kept.len() < 3 {
        return Ok(None);
    }
    let m = match binpick_pcl::estimate_svd(&model.initial_keypoints, cluster_kp, kept) {
        Ok(m) => m,
        Err(binpick_pcl::Error::ImproperRotation { .. }) => return Ok(None),
        Err(e) => {
            return Err(Error::Pcl {
                stage: "SVD",
                source: e,
            });
        }
    };
    let Some(pose) = from_mat4(&m) else {
        return Ok(None);
    };
    Ok(Some(InitialAlignment {
        pose,
        score: euclidean_score(world, &model.initial_keypoints, &pose),
        fpfh_radius_mm: None,
        sac_threshold_mm: 0.0,
        sac_inliers: kept.len(),
    }))
}

/// Steps A-C for one threshold outside thesis_strict mode: RANSAC rejection, SVD on the
/// kept pairs, Euclidean score. With `consensus_modes` > 1, RANSAC runs again on the
/// correspondences the previous consensus did not keep (sequential RANSAC), so a second,
/// smaller consensus - typically the true pose of a nearly symmetric part whose flipped pose
/// gathers more matches - is scored too; the best Euclidean score wins. `Ok(None)` when
/// nothing yields a proper rotation.
fn hypothesis(
    model: &PreparedModel,
    cluster_kp: &[Point],
    world: &NearestIndex,
    corrs: &[Correspondence],
    threshold_mm: f64,
    params: &Params,
) -> Result<Option<InitialAlignment>> {
    let mut remaining = corrs.to_vec();
    let mut best: Option<InitialAlignment> = None;
    for _ in 0..params.consensus_modes.max(1) {
        if remaining.len() < 3 {
            break;
        }
        let run = binpick_pcl::reject_sample_consensus(
            &model.initial_keypoints,
            cluster_kp,
            &remaining,
            threshold_mm as f32,
            params.sac_iterations,
        );
        let Some(consensus) = usable_consensus(run)? else {
            break;
        };
        if consensus.kept.len() < 3 {
            break;
        }
        let kept: std::collections::HashSet<u32> = consensus.kept.iter().map(|c| c.query).collect();
        remaining.retain(|c| !kept.contains(&c.query));
        if let Some(a) = svd_and_score(model, cluster_kp, world, &consensus.kept)?
            && best.as_ref().is_none_or(|b| a.score < b.score)
        {
            best = Some(InitialAlignment {
                sac_threshold_mm: threshold_mm,
                ..a
            });
        }
    }
    Ok(best)
}

/// The scene at the final leaf, uploaded once per recognition and shared by every ICP and
/// every final score.
pub(crate) struct FinalWorld {
    pub pcl: IndexedCloud,
    pub index: NearestIndex,
    /// The world at scan resolution, for the fine ICP pass (`Params::icp_refine`).
    pub dense: Option<IndexedCloud>,
}

impl FinalWorld {
    pub(crate) fn new(world: &[Point], params: &Params) -> Result<Self> {
        let idx = keypoints(world, params.final_leaf_mm)?;
        let pts: Vec<Point> = idx.iter().map(|&i| world[i as usize]).collect();
        let dense = if params.icp_refine && !params.thesis_strict {
            Some(IndexedCloud::new(world).map_err(pcl("scene upload"))?)
        } else {
            None
        };
        Ok(Self {
            pcl: IndexedCloud::new(&pts).map_err(pcl("final keypoints upload"))?,
            index: NearestIndex::new(&pts)
                .map_err(|e| crate::error::input("scene", e.to_string()))?,
            dense,
        })
    }
}

/// The fine ICP pass runs for candidates whose percent of outliers is below this multiple
/// of the final threshold.
const REFINE_BELOW_FACTOR: f64 = 2.0;

/// What ICP did for one detection.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IcpReport {
    pub converged: bool,
    pub iterations: u32,
    /// PCL's fitness: mean squared distance of matched points, mm^2 (None if ICP failed or
    /// matched nothing).
    pub fitness_mm2: Option<f64>,
    /// Whether the ICP pose scored better than the initial one and was adopted (step 3d).
    pub adopted: bool,
    /// Set when PCL's ICP failed; the initial pose is kept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// Result of the final alignment (thesis 4.1 step 3).
#[derive(Clone, Debug, PartialEq)]
pub struct FinalAlignment {
    pub pose: Isometry3<f64>,
    /// Percent of outliers (3.1.2) of the final pose.
    pub score: f64,
    /// Percent of outliers of the initial pose.
    pub score_before_icp: f64,
    pub icp: IcpReport,
}

/// Step 3: ICP of the model's final keypoints onto the scene's (the whole scene, not the
/// cluster), then the percent-of-outliers score; the ICP pose is adopted only if it scores
/// better (3d). The returned pose is final x initial (step 5).
pub(crate) fn final_alignment(
    model: &PreparedModel,
    world: &FinalWorld,
    initial: &Isometry3<f64>,
    params: &Params,
) -> FinalAlignment {
    let d = params.outlier_distance_mm;
    let kp = &model.final_keypoints;
    let before = outlier_percent(&world.index, kp, initial, d);
    let mut result = FinalAlignment {
        pose: *initial,
        score: before,
        score_before_icp: before,
        icp: IcpReport {
            converged: false,
            iterations: 0,
            fitness_mm2: None,
            adopted: false,
            error: None,
        },
    };
    let icp = world.pcl.icp(
        kp,
        &IcpParams {
            initial: to_mat4(initial),
            max_correspondence_distance: params.icp_max_correspondence_mm,
            max_iterations: params.icp_iterations,
            transformation_epsilon: params.icp_transformation_epsilon,
            batch_correspondences: true,
            relative_mse: params.effective_icp_relative_mse(),
        },
    );
    match icp {
        Ok(out) => {
            result.icp.converged = out.converged;
            result.icp.iterations = out.iterations;
            result.icp.fitness_mm2 =
                (out.fitness.is_finite() && out.fitness < 1e300).then_some(out.fitness);
            if let Some(pose) = from_mat4(&out.transform) {
                result.icp.adopted = adopt_if_better(world, kp, d, &mut result, pose);
            }
        }
        Err(e) => result.icp.error = Some(e.to_string()),
    }
    // Fine pass, only for a part that is accepted or nearly so (within twice the final
    // threshold; the fine fit can bring a noisy near-miss under it): the model at scan resolution onto
    // the world at scan resolution, correspondences within two resolutions. Point-to-point
    // ICP between two 2 mm keypoint samplings has ripples at the keypoint spacing that can stop
    // it short along a part's weakly constrained directions (a bent sheet's bend line).
    if let Some(dense) = &world.dense
        && result.score < REFINE_BELOW_FACTOR * params.final_score_max_pct
    {
        let fine = dense.icp(
            &model.cloud,
            &IcpParams {
                initial: to_mat4(&result.pose),
                max_correspondence_distance: 2.0 * params.resolution_mm,
                max_iterations: params.icp_iterations,
                transformation_epsilon: params.icp_transformation_epsilon,
                batch_correspondences: true,
                relative_mse: 0.0,
            },
        );
        if let Ok(out) = fine {
            result.icp.iterations += out.iterations;
            if let Some(pose) = from_mat4(&out.transform) {
                result.icp.adopted |= adopt_if_better(world, kp, d, &mut result, pose);
            }
        }
    }
    result
}

/// Step 3d, "if the score is better than before, then transform": adopts `pose` when its
/// percent of outliers is lower, or equal with a lower Euclidean score (3.1.1) of the same
/// keypoints (the percent of outliers saturates at 0 for any pose within the outlier
/// distance, and ICP minimises the Euclidean score).
fn adopt_if_better(
    world: &FinalWorld,
    kp: &[Point],
    d: f64,
    result: &mut FinalAlignment,
    pose: Isometry3<f64>,
) -> bool {
    let after = outlier_percent(&world.index, kp, &pose, d);
    let better = after < result.score
        || (after == result.score
            && euclidean_score(&world.index, kp, &pose)
                < euclidean_score(&world.index, kp, &result.pose));
    if better {
        result.pose = pose;
        result.score = after;
    }
    better
}
