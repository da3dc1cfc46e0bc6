//! Initial alignment of the model to one cluster (thesis Algorithms 1 and 2, steps 1-2) and
//! final alignment against the whole scene (steps 3-5).

use nalgebra::Isometry3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use binpick_cloud::Point;
use binpick_pcl::{Correspondence, IcpParams, IndexedCloud};

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

/// Thesis 4.1 step 1a-b for one cluster: keypoints, FPFH per radius, then Algorithm 1 or 2;
/// the hypothesis with the best Euclidean score (step D). `Ok(None)` when the cluster yields
/// no transform at all (too few keypoints or no RANSAC consensus at any threshold).
pub(crate) fn initial_alignment(
    model: &PreparedModel,
    cluster: &[Point],
    params: &Params,
    deadline: &Deadline,
) -> Result<Option<InitialAlignment>> {
    Ok(initial_hypotheses(model, cluster, params, deadline)?
        .into_iter()
        .next())
}

/// Every hypothesis of the sweep (one per correspondence set and threshold that produced a
/// transform), best Euclidean score first; ties keep the loop order (earlier radius and
/// threshold first).
pub(crate) fn initial_hypotheses(
    model: &PreparedModel,
    cluster: &[Point],
    params: &Params,
    deadline: &Deadline,
) -> Result<Vec<InitialAlignment>> {
    let kp_idx = keypoints(cluster, params.initial_leaf_mm)?;
    if kp_idx.len() < 3 {
        return Ok(Vec::new());
    }
    let kp: Vec<Point> = kp_idx.iter().map(|&i| cluster[i as usize]).collect();
    let (surface, surface_kp) = feature_surface(cluster, &kp_idx, &kp, params.feature_surface)?;
    // Radii in parallel; PCL's own OpenMP stays at one thread inside a cluster task.
    let features: Vec<RadiusFeatures> = params
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
    let world =
        NearestIndex::new(&kp).map_err(|e| crate::error::input("cluster", e.to_string()))?;

    // (radius index or None, correspondences in keypoint indices)
    let mut sets: Vec<(Option<usize>, Vec<Correspondence>)> = Vec::new();
    for (r, (m, c)) in model.features.iter().zip(&features).enumerate() {
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

    // Every (correspondence set, SAC threshold) pair is an independent hypothesis (step iii).
    let n_th = params.sac_thresholds_mm.len();
    let jobs: Vec<(usize, usize)> = (0..sets.len())
        .flat_map(|s| (0..n_th).map(move |t| (s, t)))
        .collect();
    let hypotheses: Vec<Option<Hypothesis>> = jobs
        .par_iter()
        .map(|&(s, t)| {
            deadline.check("RANSAC threshold sweep")?;
            let (radius, corrs) = &sets[s];
            let order = s * n_th + t;
            hypothesis(
                model,
                &kp,
                &world,
                &shuffled(corrs, order as u64),
                params.sac_thresholds_mm[t],
                params,
            )
            .map(|h| {
                h.map(|mut a| {
                    a.fpfh_radius_mm = radius.map(|r| params.fpfh_radii_mm[r]);
                    Hypothesis {
                        order,
                        alignment: a,
                    }
                })
            })
        })
        .collect::<Result<_>>()?;
    let mut all: Vec<Hypothesis> = hypotheses.into_iter().flatten().collect();
    all.sort_by(|a, b| {
        a.alignment
            .score
            .total_cmp(&b.alignment.score)
            .then(a.order.cmp(&b.order))
    });
    // The best few hypotheses, each composed with the model's near-symmetries (a flipped match
    // T of a nearly symmetric part becomes T * S, close to the true pose), scored the same way.
    let flips: Vec<Hypothesis> = all
        .iter()
        .take(SYMMETRY_EXPANDED)
        .flat_map(|h| {
            model.near_symmetries.iter().enumerate().map(|(k, s)| {
                let pose = h.alignment.pose * s;
                Hypothesis {
                    order: jobs.len() * (k + 1) + h.order,
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

/// [`initial_hypotheses`] without a time budget (diagnostics, tests).
pub fn initial_hypotheses_unbounded(
    model: &PreparedModel,
    cluster: &[Point],
    params: &Params,
) -> Result<Vec<InitialAlignment>> {
    initial_hypotheses(model, cluster, params, &Deadline::new(None))
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

/// Steps A-C for one threshold: RANSAC rejection, SVD on the kept pairs, Euclidean score.
/// With `consensus_modes` > 1, RANSAC runs again on the correspondences the previous
/// consensus did not keep (sequential RANSAC), so a second, smaller consensus - typically
/// the true pose of a nearly symmetric part whose flipped pose gathers more matches - is
/// scored too; the best Euclidean score wins. `Ok(None)` when nothing yields a proper
/// rotation.
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
    let modes = if params.thesis_strict {
        1
    } else {
        params.consensus_modes.max(1)
    };
    for _ in 0..modes {
        if remaining.len() < 3 {
            break;
        }
        let consensus = match binpick_pcl::reject_sample_consensus(
            &model.initial_keypoints,
            cluster_kp,
            &remaining,
            threshold_mm as f32,
            params.sac_iterations,
        ) {
            Ok(c) => c,
            Err(
                binpick_pcl::Error::NoConsensus { .. }
                | binpick_pcl::Error::ImproperRotation { .. },
            ) => break,
            Err(e) => {
                return Err(Error::Pcl {
                    stage: "RANSAC rejection",
                    source: e,
                });
            }
        };
        if consensus.kept.len() < 3 {
            break;
        }
        let kept: std::collections::HashSet<u32> = consensus.kept.iter().map(|c| c.query).collect();
        remaining.retain(|c| !kept.contains(&c.query));
        let m = match binpick_pcl::estimate_svd(
            &model.initial_keypoints,
            cluster_kp,
            &consensus.kept,
        ) {
            Ok(m) => m,
            Err(binpick_pcl::Error::ImproperRotation { .. }) => continue,
            Err(e) => {
                return Err(Error::Pcl {
                    stage: "SVD",
                    source: e,
                });
            }
        };
        let Some(pose) = from_mat4(&m) else { continue };
        let score = euclidean_score(world, &model.initial_keypoints, &pose);
        if best.as_ref().is_none_or(|b| score < b.score) {
            best = Some(InitialAlignment {
                pose,
                score,
                fpfh_radius_mm: None,
                sac_threshold_mm: threshold_mm,
                sac_inliers: consensus.kept.len(),
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
}

impl FinalWorld {
    pub(crate) fn new(world: &[Point], params: &Params) -> Result<Self> {
        let idx = keypoints(world, params.final_leaf_mm)?;
        let pts: Vec<Point> = idx.iter().map(|&i| world[i as usize]).collect();
        Ok(Self {
            pcl: IndexedCloud::new(&pts).map_err(pcl("final keypoints upload"))?,
            index: NearestIndex::new(&pts)
                .map_err(|e| crate::error::input("scene", e.to_string()))?,
        })
    }
}

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
    let before = outlier_percent(&world.index, &model.final_keypoints, initial, d);
    let icp = world.pcl.icp(
        &model.final_keypoints,
        &IcpParams {
            initial: to_mat4(initial),
            max_correspondence_distance: params.icp_max_correspondence_mm,
            max_iterations: params.icp_iterations,
            transformation_epsilon: params.icp_transformation_epsilon,
            batch_correspondences: true,
        },
    );
    let (refined, mut report) = match icp {
        Ok(out) => (
            from_mat4(&out.transform),
            IcpReport {
                converged: out.converged,
                iterations: out.iterations,
                fitness_mm2: (out.fitness.is_finite() && out.fitness < 1e300)
                    .then_some(out.fitness),
                adopted: false,
                error: None,
            },
        ),
        Err(e) => (
            None,
            IcpReport {
                converged: false,
                iterations: 0,
                fitness_mm2: None,
                adopted: false,
                error: Some(e.to_string()),
            },
        ),
    };
    let mut result = FinalAlignment {
        pose: *initial,
        score: before,
        score_before_icp: before,
        icp: report.clone(),
    };
    if let Some(pose) = refined {
        let after = outlier_percent(&world.index, &model.final_keypoints, &pose, d);
        // "If the score is better than before" (step 3d). The percent of outliers saturates at
        // 0 for any pose within the outlier distance, so equal scores are decided by the
        // Euclidean score (3.1.1) of the same keypoints, which ICP minimises.
        let better = after < before
            || (after == before
                && euclidean_score(&world.index, &model.final_keypoints, &pose)
                    < euclidean_score(&world.index, &model.final_keypoints, initial));
        if better {
            report.adopted = true;
            result.pose = pose;
            result.score = after;
        }
    }
    result.icp = report;
    result
}
