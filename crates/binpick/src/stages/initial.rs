//! Stage 4, the initial alignment of the model to one cluster (thesis Algorithms 1 and 2,
//! steps 1b-2): correspondences, the RANSAC threshold sweep with SVD and Euclidean score, and
//! the choice of the best initial alignment.

use std::collections::HashSet;

use nalgebra::Isometry3;
use rayon::prelude::*;

use binpick_cloud::Point;
use binpick_pcl::{Consensus, Correspondence};

use crate::deadline::Deadline;
use crate::error::{Result, input, pcl};
use crate::params::{Algorithm, ConsensusConfig};
use crate::result::SearchStop;
use crate::stages::features::ClusterFeatures;
use crate::stages::model::PreparedModel;
use crate::validate::{NearestIndex, euclidean_score};

/// One initial alignment of a cluster (thesis 4.1 / 4.2 step 1b-D).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct InitialAlignment {
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

/// A hypothesis of the sweep; `order` breaks score ties (first in loop order wins).
#[derive(Clone, Debug)]
pub(crate) struct Hypothesis {
    order: usize,
    pub alignment: InitialAlignment,
}

/// The correspondences of one FPFH radius (Algorithm 1) or of all radii merged (Algorithm 2),
/// in keypoint indices: model initial keypoints -> cluster keypoints.
pub(crate) struct CorrespondenceSet {
    /// Index into `fpfh_radii_mm`; None for the merged set.
    radius: Option<usize>,
    pairs: Vec<Correspondence>,
}

/// The cluster's keypoints with a nearest-neighbour index, what the Euclidean score reads.
pub(crate) struct ClusterKeypoints<'a> {
    points: &'a [Point],
    index: NearestIndex,
}

impl<'a> ClusterKeypoints<'a> {
    pub(crate) fn new(features: &'a ClusterFeatures) -> Result<Self> {
        let points = &features.keypoints;
        let index =
            NearestIndex::new("cluster", points).map_err(|e| input("cluster", e.to_string()))?;
        Ok(Self { points, index })
    }
}

/// Step 1b i-iii: FPFH matches per radius (model keypoints -> cluster keypoints); with
/// Algorithm 2 all radii merged, keeping for each model keypoint the match with the smallest
/// descriptor distance (earlier radius on ties).
pub(crate) fn correspondences(
    model: &PreparedModel,
    cluster: &ClusterFeatures,
    algorithm: Algorithm,
) -> Result<Vec<CorrespondenceSet>> {
    let mut sets = Vec::new();
    for (r, (m, c)) in model.features.iter().zip(&cluster.features).enumerate() {
        if c.descriptors.is_empty() {
            continue;
        }
        let corrs = binpick_pcl::match_features(&m.descriptors, &c.descriptors)
            .map_err(pcl("feature matching"))?;
        let pairs = corrs
            .into_iter()
            .map(|k| Correspondence {
                query: m.keypoint[k.query as usize],
                matched: c.keypoint[k.matched as usize],
                distance: k.distance,
            })
            .collect();
        sets.push(CorrespondenceSet {
            radius: Some(r),
            pairs,
        });
    }
    if algorithm == Algorithm::MergedFpfh {
        let mut best: Vec<Option<Correspondence>> = vec![None; model.initial_keypoints.len()];
        for c in sets.into_iter().flat_map(|s| s.pairs) {
            let slot = &mut best[c.query as usize];
            if slot.is_none_or(|b| c.distance < b.distance) {
                *slot = Some(c);
            }
        }
        sets = vec![CorrespondenceSet {
            radius: None,
            pairs: best.into_iter().flatten().collect(),
        }];
    }
    Ok(sets)
}

/// Steps A-C for every (correspondence set, threshold) pair: RANSAC rejection, SVD on the kept
/// pairs, Euclidean score. Best score first; ties keep the loop order (earlier radius and
/// threshold first), so the first is the thesis's initial alignment (step D).
///
/// With shared draws (the thesis) one PCL rejector per threshold runs on the correspondences
/// as found; PCL seeds every run alike, so the runs share their draws and one pass per set
/// computes them all. With independent draws every pair draws from its own permutation and
/// may try several consensus sets (`consensus_modes`).
pub(crate) fn threshold_sweep(
    model: &PreparedModel,
    cluster: &ClusterKeypoints,
    sets: &[CorrespondenceSet],
    cfg: &ConsensusConfig,
    radii_mm: &[f64],
    deadline: &Deadline,
) -> Result<Vec<Hypothesis>> {
    let n_th = cfg.sac_thresholds_mm.len();
    let label = |radius: Option<usize>, t: usize, a: InitialAlignment| Hypothesis {
        order: radius.unwrap_or(0) * n_th + t,
        alignment: InitialAlignment {
            fpfh_radius_mm: radius.map(|r| radii_mm[r]),
            ..a
        },
    };
    let hypotheses: Vec<Option<Hypothesis>> = if cfg.independent_draws {
        let jobs: Vec<(usize, usize)> = (0..sets.len())
            .flat_map(|s| (0..n_th).map(move |t| (s, t)))
            .collect();
        jobs.par_iter()
            .map(|&(s, t)| {
                deadline.check("RANSAC threshold sweep")?;
                let set = &sets[s];
                let stream = (set.radius.unwrap_or(0) * n_th + t) as u64;
                let draws = shuffled(&set.pairs, stream);
                let threshold_mm = cfg.sac_thresholds_mm[t];
                consensus_sets(model, cluster, &draws, threshold_mm, cfg)
                    .map(|h| h.map(|a| label(set.radius, t, a)))
            })
            .collect::<Result<_>>()?
    } else {
        sets.par_iter()
            .map(|set| {
                deadline.check("RANSAC threshold sweep")?;
                Ok(shared_draw_sweep(model, cluster, &set.pairs, cfg)?
                    .into_iter()
                    .enumerate()
                    .map(|(t, a)| a.map(|a| label(set.radius, t, a)))
                    .collect::<Vec<_>>())
            })
            .collect::<Result<Vec<_>>>()?
            .into_iter()
            .flatten()
            .collect()
    };
    let mut all: Vec<Hypothesis> = hypotheses.into_iter().flatten().collect();
    sort_best_first(&mut all);
    Ok(all)
}

fn sort_best_first(hypotheses: &mut [Hypothesis]) {
    hypotheses.sort_by(|a, b| {
        a.alignment
            .score
            .total_cmp(&b.alignment.score)
            .then(a.order.cmp(&b.order))
    });
}

/// Extension, near-symmetry candidates: the best `symmetry_expanded` hypotheses, each
/// composed with the model's near-symmetries (a flipped match T of a nearly symmetric part
/// becomes T * S, close to the true pose), scored the same way and merged in.
pub(crate) fn with_symmetry_candidates(
    mut hypotheses: Vec<Hypothesis>,
    model: &PreparedModel,
    cluster: &ClusterKeypoints,
    cfg: &ConsensusConfig,
    radii: usize,
) -> Vec<Hypothesis> {
    if model.near_symmetries.is_empty() {
        return hypotheses;
    }
    let stride = radii * cfg.sac_thresholds_mm.len();
    let flips: Vec<Hypothesis> = hypotheses
        .iter()
        .take(cfg.symmetry_expanded)
        .flat_map(|h| {
            model.near_symmetries.iter().enumerate().map(|(k, s)| {
                let pose = h.alignment.pose * s;
                Hypothesis {
                    order: stride * (k + 1) + h.order,
                    alignment: InitialAlignment {
                        pose,
                        score: euclidean_score(&cluster.index, &model.initial_keypoints, &pose),
                        ..h.alignment.clone()
                    },
                }
            })
        })
        .collect();
    hypotheses.extend(flips);
    sort_best_first(&mut hypotheses);
    hypotheses
}

/// Step D and step 2: the best initial alignment, if its Euclidean score is under
/// `initial_score_max`; with the retry extension (`final_candidates` > 1) also the next
/// ones under it, best first, each differing from every earlier one by more than
/// `distinct_shift_diameters` model diameters or `distinct_angle_deg`.
pub(crate) fn best_initial<'h>(
    hypotheses: &'h [Hypothesis],
    cfg: &ConsensusConfig,
    model_diameter_mm: f64,
) -> std::result::Result<Vec<&'h InitialAlignment>, SearchStop> {
    let Some(best) = hypotheses.first() else {
        return Err(SearchStop::NoConsensus);
    };
    if best.alignment.score >= cfg.initial_score_max {
        return Err(SearchStop::InitialRejected {
            score: best.alignment.score,
            max: cfg.initial_score_max,
        });
    }
    let min_shift = cfg.distinct_shift_diameters * model_diameter_mm;
    let min_angle = cfg.distinct_angle_deg.to_radians();
    let mut out: Vec<&InitialAlignment> = Vec::new();
    for h in hypotheses.iter().map(|h| &h.alignment) {
        if out.len() >= cfg.final_candidates as usize || h.score >= cfg.initial_score_max {
            break;
        }
        let distinct = out.iter().all(|o| {
            (o.pose.translation.vector - h.pose.translation.vector).norm() > min_shift
                || o.pose.rotation.angle_to(&h.pose.rotation) > min_angle
        });
        if distinct {
            out.push(h);
        }
    }
    Ok(out)
}

/// The correspondences in a pseudo-random order fixed by `stream`. PCL seeds every RANSAC
/// run with the same constant, so without this all thresholds of a sweep would draw the
/// same sample triples; the thesis treats each run as an independent random draw (3.4.2.5).
/// A fixed permutation per (radius, threshold) gives every run its own samples while keeping
/// results deterministic.
fn shuffled(corrs: &[Correspondence], stream: u64) -> Vec<Correspondence> {
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

/// Steps A-C for every threshold of the sweep on one correspondence set, with PCL's shared
/// draws: PCL's rejector per threshold (computed in one pass), SVD on the kept pairs,
/// Euclidean score. One entry per threshold, `None` where nothing yields a proper rotation.
fn shared_draw_sweep(
    model: &PreparedModel,
    cluster: &ClusterKeypoints,
    corrs: &[Correspondence],
    cfg: &ConsensusConfig,
) -> Result<Vec<Option<InitialAlignment>>> {
    let n_th = cfg.sac_thresholds_mm.len();
    if corrs.len() < 3 {
        return Ok(vec![None; n_th]);
    }
    let thresholds: Vec<f32> = cfg.sac_thresholds_mm.iter().map(|&t| t as f32).collect();
    let runs = binpick_pcl::reject_sample_consensus_sweep(
        &model.initial_keypoints,
        cluster.points,
        corrs,
        &thresholds,
        cfg.sac_iterations,
    )
    .map_err(pcl("RANSAC rejection"))?
    .into_iter()
    .map(usable_consensus)
    .collect::<Result<Vec<_>>>()?;
    // Thresholds that keep the same pairs give the same SVD and score: compute those once.
    let mut seen: Vec<(&[Correspondence], Option<InitialAlignment>)> = Vec::new();
    let mut out = Vec::with_capacity(n_th);
    for (run, &threshold_mm) in runs.iter().zip(&cfg.sac_thresholds_mm) {
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
                let a = svd_and_score(model, cluster, &consensus.kept)?;
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

/// Steps A-C for one threshold with independent draws: RANSAC rejection, SVD on the kept
/// pairs, Euclidean score. With `consensus_modes` > 1 (the second consensus set extension),
/// RANSAC runs again on the correspondences the previous consensus did not keep (sequential
/// RANSAC), so a second, smaller consensus - typically the true pose of a nearly symmetric
/// part whose flipped pose gathers more matches - is scored too; the best Euclidean score
/// wins. `Ok(None)` when nothing yields a proper rotation.
fn consensus_sets(
    model: &PreparedModel,
    cluster: &ClusterKeypoints,
    corrs: &[Correspondence],
    threshold_mm: f64,
    cfg: &ConsensusConfig,
) -> Result<Option<InitialAlignment>> {
    let mut remaining = corrs.to_vec();
    let mut best: Option<InitialAlignment> = None;
    for _ in 0..cfg.consensus_modes {
        if remaining.len() < 3 {
            break;
        }
        let run = binpick_pcl::reject_sample_consensus(
            &model.initial_keypoints,
            cluster.points,
            &remaining,
            threshold_mm as f32,
            cfg.sac_iterations,
        );
        let Some(consensus) = usable_consensus(run)? else {
            break;
        };
        if consensus.kept.len() < 3 {
            break;
        }
        let kept: HashSet<u32> = consensus.kept.iter().map(|c| c.query).collect();
        remaining.retain(|c| !kept.contains(&c.query));
        if let Some(a) = svd_and_score(model, cluster, &consensus.kept)?
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

/// A rejector run's consensus; `None` when RANSAC found none or its transform is not a
/// rotation (both mean "no hypothesis"), an error for anything else.
fn usable_consensus(run: binpick_pcl::Result<Consensus>) -> Result<Option<Consensus>> {
    match run {
        Ok(c) => Ok(Some(c)),
        Err(
            binpick_pcl::Error::NoConsensus { .. } | binpick_pcl::Error::ImproperRotation { .. },
        ) => Ok(None),
        Err(e) => Err(pcl("RANSAC rejection")(e)),
    }
}

/// Steps B-C: SVD on the correspondences RANSAC kept, then the Euclidean score of the model
/// keypoints placed by it. `Ok(None)` when fewer than 3 pairs or no proper rotation.
fn svd_and_score(
    model: &PreparedModel,
    cluster: &ClusterKeypoints,
    kept: &[Correspondence],
) -> Result<Option<InitialAlignment>> {
    if kept.len() < 3 {
        return Ok(None);
    }
    let m = match binpick_pcl::estimate_svd(&model.initial_keypoints, cluster.points, kept) {
        Ok(m) => m,
        Err(binpick_pcl::Error::ImproperRotation { .. }) => return Ok(None),
        Err(e) => return Err(pcl("SVD")(e)),
    };
    let Some(pose) = binpick_pcl::rigid_pose(&m) else {
        return Ok(None);
    };
    Ok(Some(InitialAlignment {
        pose,
        score: euclidean_score(&cluster.index, &model.initial_keypoints, &pose),
        fpfh_radius_mm: None,
        sac_threshold_mm: 0.0,
        sac_inliers: kept.len(),
    }))
}
