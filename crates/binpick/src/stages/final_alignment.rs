//! Stage 5, the final alignment against the whole scene (thesis Algorithm 1 steps 3-4): ICP
//! of the model's final keypoints onto the scene's, the percent-of-outliers score, and the
//! acceptance of a part.

use nalgebra::Isometry3;

use binpick_cloud::Point;
use binpick_pcl::{IcpParams, IndexedCloud};

use crate::error::{Result, input, pcl};
use crate::params::{IcpConfig, ValidationConfig};
use crate::result::{IcpReport, SearchStop};
use crate::stages::features::keypoints;
use crate::validate::{NearestIndex, euclidean_score, outlier_percent};

/// The scene at the final leaf, uploaded once per recognition and shared by every ICP and
/// every final score (step 3a, scene side).
pub(crate) struct FinalWorld {
    pub pcl: IndexedCloud,
    pub index: NearestIndex,
    /// The world at scan resolution, for the fine ICP pass (`icp_refine`).
    pub dense: Option<IndexedCloud>,
}

impl FinalWorld {
    pub(crate) fn new(world: &[Point], cfg: &IcpConfig) -> Result<Self> {
        let idx = keypoints(world, cfg.final_leaf_mm)?;
        let pts: Vec<Point> = idx.iter().map(|&i| world[i as usize]).collect();
        let dense = if cfg.icp_refine {
            Some(IndexedCloud::new(world).map_err(pcl("scene upload"))?)
        } else {
            None
        };
        Ok(Self {
            pcl: IndexedCloud::new(&pts).map_err(pcl("final keypoints upload"))?,
            index: NearestIndex::new("scene", &pts).map_err(|e| input("scene", e.to_string()))?,
            dense,
        })
    }
}

/// Result of the final alignment (thesis 4.1 step 3).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct FinalAlignment {
    pub pose: Isometry3<f64>,
    /// Percent of outliers (3.1.2) of the final pose.
    pub score: f64,
    /// Percent of outliers of the initial pose.
    pub score_before_icp: f64,
    pub icp: IcpReport,
}

/// The thesis's ICP settings (3.6.1, 4.3 #11) starting at `initial`, with the relative-MSE
/// stop extension when it is on.
pub(crate) fn icp_settings(cfg: &IcpConfig, initial: &Isometry3<f64>) -> IcpParams {
    IcpParams {
        initial: binpick_pcl::row_major(initial),
        max_correspondence_distance: cfg.icp_max_correspondence_mm,
        max_iterations: cfg.icp_iterations,
        transformation_epsilon: cfg.icp_transformation_epsilon,
        batch_correspondences: true,
        relative_mse: cfg.icp_relative_mse,
        reciprocal: false,
    }
}

/// Step 3: ICP of the model's final keypoints onto the scene's (the whole scene, not the
/// cluster), then the percent-of-outliers score; the ICP pose is adopted only if it scores
/// better (3d). The returned pose is final x initial (step 5). With the fine-pass extension
/// (`icp_refine`) a part that is accepted or nearly so gets a second ICP at scan resolution.
/// A failed ICP keeps the initial pose (reported in `icp.error`); only an interruption
/// (time budget, cancellation) is an error.
pub(crate) fn final_alignment(
    model_keypoints: &[Point],
    model_cloud: &[Point],
    world: &FinalWorld,
    initial: &Isometry3<f64>,
    cfg: &IcpConfig,
    validation: &ValidationConfig,
    resolution_mm: f64,
) -> Result<FinalAlignment> {
    let d = validation.outlier_distance_mm;
    let kp = model_keypoints;
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
            unhidden: false,
            polished: false,
            error: None,
        },
    };
    match world.pcl.icp(kp, &icp_settings(cfg, initial)) {
        Ok(out) => {
            result.icp.converged = out.converged;
            result.icp.iterations = out.iterations;
            result.icp.fitness_mm2 = IcpReport::usable_fitness(out.fitness);
            if let Some(pose) = out.pose() {
                result.icp.adopted = adopt_if_better(world, kp, d, &mut result, pose);
            }
        }
        Err(e @ binpick_pcl::Error::Interrupted { .. }) => return Err(pcl("ICP")(e)),
        Err(e) => result.icp.error = Some(e.to_string()),
    }
    // Fine pass, only for a part that is accepted or nearly so (within `icp_refine_below_factor`
    // x the final threshold): the model at scan resolution onto the world at scan resolution.
    // Point-to-point ICP between two keypoint samplings has ripples at the keypoint spacing
    // that can stop it short along a part's weakly constrained directions (a bent sheet's bend
    // line).
    if let Some(dense) = &world.dense
        && result.score < cfg.icp_refine_below_factor * validation.final_score_max_pct
    {
        let fine = dense.icp(
            model_cloud,
            &IcpParams {
                initial: binpick_pcl::row_major(&result.pose),
                max_correspondence_distance: cfg.icp_refine_distance_factor * resolution_mm,
                max_iterations: cfg.icp_iterations,
                transformation_epsilon: cfg.icp_transformation_epsilon,
                batch_correspondences: true,
                relative_mse: 0.0,
                reciprocal: false,
            },
        );
        match fine {
            Ok(out) => {
                result.icp.iterations += out.iterations;
                if let Some(pose) = out.pose() {
                    result.icp.adopted |= adopt_if_better(world, kp, d, &mut result, pose);
                }
            }
            Err(e @ binpick_pcl::Error::Interrupted { .. }) => return Err(pcl("fine ICP")(e)),
            // As before the fine pass: it is an extension, its failure keeps the ICP pose.
            Err(_) => {}
        }
    }
    Ok(result)
}

/// Step 4: a final alignment is accepted when its percent of outliers is under
/// `final_score_max_pct`.
pub(crate) fn accept(fin: &FinalAlignment, cfg: &ValidationConfig) -> bool {
    fin.score < cfg.final_score_max_pct
}

/// Why no candidate was accepted: the first one's final score (step 4).
pub(crate) fn rejection(first_score: Option<f64>, cfg: &ValidationConfig) -> SearchStop {
    SearchStop::FinalRejected {
        score: first_score.unwrap_or(f64::NAN),
        max: cfg.final_score_max_pct,
    }
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
