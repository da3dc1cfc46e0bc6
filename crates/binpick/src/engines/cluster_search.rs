//! The thesis's engine: Algorithm 1 (or 2) run on every Euclidean cluster (thesis 4.1, 4.2,
//! 4.4), plus the pile-search extensions that search parts of a cluster.
//!
//! ```text
//! detect(world):
//!   clusters = EuclideanClusters(world)                                   (3.4.1.3)
//!   in parallel, for each cluster:                                        (4.4)
//!     regions = [cluster]        (sphere search: overlapping spheres, 3.4.1.2)
//!     for each region:
//!       search_region: Algorithm 1/2 steps 1-4 -> accepted part or why not
//!       touching parts: remove the points the part explains, re-cluster the rest
//!       tighter re-clustering: a failed group bigger than a part is split again
//! ```

use std::collections::VecDeque;
use std::time::Instant;

use nalgebra::Isometry3;
use rayon::prelude::*;

use binpick_cloud::Point;

use crate::deadline::{Deadline, ms};
use crate::error::Result;
use crate::params::Params;
use crate::result::{ClusterReport, Detection, FoundBy, SearchStop};
use crate::stages::cluster::{self, mark_explained, recluster, spheres};
use crate::stages::features::cluster_features;
use crate::stages::final_alignment::{FinalWorld, accept, final_alignment, rejection};
use crate::stages::initial::{
    ClusterKeypoints, best_initial, correspondences, threshold_sweep, with_symmetry_candidates,
};
use crate::stages::model::PreparedModel;
use crate::stages::rank::height_mm;

/// What the engine found in one cluster.
struct ClusterOutcome {
    pub report: ClusterReport,
    pub detections: Vec<Detection>,
    /// Time spent in the initial / final alignment, ms (summed over regions).
    pub initial_ms: f64,
    pub final_ms: f64,
}

/// What the engine found in the whole scene: detections in cluster order, one report per
/// cluster, and the alignment times summed over clusters, ms.
#[derive(Default)]
pub(crate) struct Found {
    pub detections: Vec<Detection>,
    pub clusters: Vec<ClusterReport>,
    pub initial_ms: f64,
    pub final_ms: f64,
}

/// Everything the per-cluster search reads, shared by all clusters.
pub(crate) struct ClusterSearch<'a> {
    /// Resolved stage configs ([`Params::stages`]).
    pub stages: &'a Params,
    pub model: &'a PreparedModel,
    pub world: &'a FinalWorld,
    pub deadline: &'a Deadline,
}

impl ClusterSearch<'_> {
    /// Searches every cluster of `world` (point indices per cluster), in parallel. When the
    /// deadline stops the search, each cluster keeps the parts it had accepted and says where
    /// it stopped; only other errors fail the call.
    pub(crate) fn run(&self, world: &[Point], clusters: &[Vec<u32>]) -> Result<Found> {
        let outcomes: Vec<ClusterOutcome> = clusters
            .par_iter()
            .enumerate()
            .map(|(i, idx)| {
                let points: Vec<Point> = idx.iter().map(|&k| world[k as usize]).collect();
                self.search_cluster(i, points)
            })
            .collect::<Result<_>>()?;
        let mut found = Found {
            detections: Vec::new(),
            clusters: Vec::new(),
            initial_ms: 0.0,
            final_ms: 0.0,
        };
        for o in outcomes {
            found.initial_ms += o.initial_ms;
            found.final_ms += o.final_ms;
            found.clusters.push(o.report);
            found.detections.extend(o.detections);
        }
        Ok(found)
    }

    /// One cluster: searched whole (the thesis) or, with the pile-search extensions, in
    /// spheres, remainders after each accepted part, and tighter splits of failed groups.
    /// An interrupted search keeps the parts accepted before the stop.
    fn search_cluster(&self, index: usize, points: Vec<Point>) -> Result<ClusterOutcome> {
        let mut out = ClusterOutcome {
            report: ClusterReport {
                index,
                points: points.len(),
                detections: 0,
                regions: 1,
                outcome: String::new(),
            },
            detections: Vec::new(),
            initial_ms: 0.0,
            final_ms: 0.0,
        };
        let search = self.search_regions(index, &points, &mut out);
        let last = match self.deadline.partial(search)? {
            Some(last) => last,
            None => match self.deadline.report_now() {
                Some(i) => SearchStop::Interrupted {
                    cause: i.cause,
                    stage: i.stage,
                },
                None => SearchStop::NoCandidate,
            },
        };
        out.report.detections = out.detections.len();
        out.report.outcome = last.outcome(out.detections.len());
        Ok(out)
    }

    /// The search loop of [`search_cluster`](Self::search_cluster): accepted parts go to
    /// `out` as they are found; returns why the search stopped.
    fn search_regions(
        &self,
        index: usize,
        points: &[Point],
        out: &mut ClusterOutcome,
    ) -> Result<SearchStop> {
        let p = self.stages;
        let pile = &p.pile;
        let model_points = self.model.cloud.len();
        let (min_size, _) = cluster::size_range(&p.clustering, model_points);
        let min_explained = (min_size as usize / 2).max(1);
        self.deadline.check("cluster alignment")?;
        let tolerance = p.cluster_tolerance_mm();
        // (point indices into the cluster, the clustering tolerance that made them, mm) still
        // to search.
        let mut queue: VecDeque<(Vec<u32>, f64)> = if pile.sphere_search
            && points.len() as f64 > pile.sphere_split_factor * model_points as f64
        {
            spheres(points, self.model.radius_mm, pile, min_size)?
                .into_iter()
                .map(|r| (r, tolerance))
                .collect()
        } else {
            VecDeque::from([((0..points.len() as u32).collect(), tolerance)])
        };
        out.report.regions = queue.len();
        let mut last = SearchStop::NoCandidate;
        // Each accepted part removes at least half a minimum cluster, so this bounds the loop.
        let max_rounds = 1 + out.report.points / min_explained;
        while let Some((part, tol)) = queue.pop_front() {
            if out.detections.len() >= max_rounds {
                last = SearchStop::RoundLimit;
                break;
            }
            self.deadline.check("cluster alignment")?;
            let region: Vec<Point> = part.iter().map(|&i| points[i as usize]).collect();
            match self.search_region(index, &region, out)? {
                Ok(pose) => {
                    last = SearchStop::Accepted;
                    if !pile.touching_parts {
                        break;
                    }
                    let mut mine = vec![false; points.len()];
                    let d = p.validation.outlier_distance_mm;
                    mark_explained(points, &self.model.cloud, &pose, d, &mut mine)?;
                    let rest: Vec<u32> = part
                        .iter()
                        .copied()
                        .filter(|&i| !mine[i as usize])
                        .collect();
                    if part.len() - rest.len() < min_explained {
                        last = SearchStop::ExplainsTooFew;
                        continue;
                    }
                    if rest.len() >= min_size as usize {
                        let groups = recluster(points, &rest, min_size, tol)?;
                        queue.extend(groups.into_iter().map(|s| (s, tol)));
                    }
                }
                Err(stop) => {
                    last = stop;
                    let tighter = (tol * pile.recluster_tolerance_factor)
                        .max(pile.recluster_min_tolerance_factor * p.preprocess.resolution());
                    if pile.tighter_recluster && part.len() > model_points && tighter < tol {
                        let subs = recluster(points, &part, min_size, tighter)?;
                        if subs.len() > 1 {
                            queue.extend(subs.into_iter().map(|s| (s, tighter)));
                        }
                    }
                }
            }
        }
        Ok(last)
    }

    /// Algorithm 1 (or 2) on one region of a cluster, step by step (thesis 4.1). A region
    /// gets its own features rather than a subset of the whole cluster's: FPFH near the cut
    /// then describes the region as the model would see it alone. `Ok(Ok(pose))` when a part
    /// is accepted (and pushed to `out`), `Ok(Err(stop))` when none is.
    fn search_region(
        &self,
        cluster: usize,
        region: &[Point],
        out: &mut ClusterOutcome,
    ) -> Result<std::result::Result<Isometry3<f64>, SearchStop>> {
        let p = self.stages;
        let t = Instant::now();
        // Step 1a-b: uniform keypoints and FPFH per radius.
        let Some(features) = cluster_features(region, &p.features, self.deadline)? else {
            out.initial_ms += ms(t.elapsed());
            return Ok(Err(SearchStop::FewKeypoints));
        };
        let keypoints = ClusterKeypoints::new(&features)?;
        // Step 1b i-iii: correspondences per radius (Algorithm 2: merged over radii).
        let sets = correspondences(self.model, &features, p.algorithm)?;
        // Steps A-C: RANSAC threshold sweep, SVD, Euclidean score of every hypothesis.
        let radii = &p.features.fpfh_radii_mm;
        let hypotheses = threshold_sweep(
            self.model,
            &keypoints,
            &sets,
            &p.consensus,
            radii,
            self.deadline,
        )?;
        let hypotheses = with_symmetry_candidates(
            hypotheses,
            self.model,
            &keypoints,
            &p.consensus,
            radii.len(),
        );
        out.initial_ms += ms(t.elapsed());
        // Step D and 2: the best initial alignment, if under the Euclidean threshold.
        let candidates = match best_initial(&hypotheses, &p.consensus, self.model.diameter_mm) {
            Ok(c) => c,
            Err(stop) => return Ok(Err(stop)),
        };
        // Steps 3-4: ICP on the whole scene, percent of outliers, accept under the threshold.
        let mut first_score = None;
        for initial in candidates {
            self.deadline.check("final alignment")?;
            let t = Instant::now();
            let resolution = p.preprocess.resolution();
            let fin = final_alignment(
                &self.model.final_keypoints,
                &self.model.cloud,
                self.world,
                &initial.pose,
                &p.icp,
                &p.validation,
                resolution,
            )?;
            out.final_ms += ms(t.elapsed());
            if accept(&fin, &p.validation) {
                // Step 5: the detection, final x initial pose.
                out.detections.push(Detection {
                    rank: 0,
                    pose: fin.pose,
                    initial_pose: initial.pose,
                    initial_score: initial.score,
                    final_score: fin.score,
                    score_before_icp: fin.score_before_icp,
                    found_by: FoundBy::Cluster {
                        cluster,
                        round: out.detections.len(),
                        fpfh_radius_mm: initial.fpfh_radius_mm,
                        sac_threshold_mm: initial.sac_threshold_mm,
                        sac_inliers: initial.sac_inliers,
                    },
                    view: None,
                    icp: fin.icp,
                    height_mm: height_mm(&fin.pose, &self.model.final_keypoints, p.ranking.up),
                    rank_reason: String::new(),
                    free_to_pick: true,
                    grasps: Vec::new(),
                });
                return Ok(Ok(fin.pose));
            }
            first_score.get_or_insert(fin.score);
        }
        Ok(Err(rejection(first_score, &p.validation)))
    }
}
