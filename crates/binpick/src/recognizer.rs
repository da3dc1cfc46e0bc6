//! The library entry point: [`Recognizer::new`] prepares a model once,
//! [`Recognizer::recognize`] finds, validates and ranks every instance in a scene.
//!
//! ```text
//! recognize(scene):
//!   preprocess: crop, voxel grid (4.3 #1), remove support planes
//!   clusters = EuclideanClusters(world, 1.5 x resolution, 0.3..3 x model size)   (3.4.1.3)
//!   in parallel, for each cluster:                                              (4.4)
//!     repeat:                                  (thesis_strict: once)
//!       initial = Algorithm 1 or 2 on the cluster; stop unless score < 100     (4.1/4.2, step 1-2)
//!       final   = ICP on the whole scene at the final leaf; stop unless < 20 % (step 3-4)
//!       accept; remove the cluster points it explains; re-cluster the rest
//!   drop duplicates of one instance, rank for picking                           (1.2 step 3)
//! ```

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use binpick_cloud::{Point, PointCloud};
use binpick_pcl::IndexedCloud;

use crate::align::{
    ClusterFeatures, FinalWorld, IcpReport, InitialAlignment, final_alignment, initial_hypotheses,
};
use crate::deadline::Deadline;
use crate::error::{Error, Result, input, pcl};
use crate::model::PreparedModel;
use crate::params::Params;
use crate::rank::rank_detections;
use crate::scene::{PreprocessReport, preprocess};
use crate::validate::{NearestIndex, outlier_percent};

/// One accepted instance of the model.
#[derive(Clone, Debug, PartialEq)]
pub struct Detection {
    /// 1 = pick first.
    pub rank: usize,
    /// Model frame -> scene frame (final x initial), mm.
    pub pose: Isometry3<f64>,
    /// The initial alignment's pose.
    pub initial_pose: Isometry3<f64>,
    /// Euclidean score of the initial alignment (3.1.1), mm^2; lower is better.
    pub initial_score: f64,
    /// Percent of outliers of the final pose (3.1.2); lower is better (less occluded).
    pub final_score: f64,
    /// Percent of outliers before ICP.
    pub score_before_icp: f64,
    /// Index of the Euclidean cluster it came from (clusters ordered by first point index).
    pub cluster: usize,
    /// 0 for the first part found in a cluster, 1 for the next touching part, ...
    pub cluster_round: usize,
    /// FPFH radius that won the initial alignment (None with Algorithm 2), mm.
    pub fpfh_radius_mm: Option<f64>,
    /// RANSAC threshold that won, mm.
    pub sac_threshold_mm: f64,
    pub sac_inliers: usize,
    pub icp: IcpReport,
    /// Height of the placed model's centroid along `Params::up`, mm.
    pub height_mm: f64,
    /// Why it ranks where it does.
    pub rank_reason: String,
}

/// What happened in one cluster.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClusterReport {
    pub index: usize,
    pub points: usize,
    pub detections: usize,
    /// Spheres the cluster was searched in (1 when searched whole).
    #[serde(default)]
    pub regions: usize,
    /// Why the search in this cluster stopped.
    pub outcome: String,
}

/// Wall-clock time per stage, milliseconds. `initial_alignment_ms` and `final_alignment_ms`
/// add up the work of all worker threads, so with parallel clusters they can exceed `total_ms`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// Model preparation in `Recognizer::new` (once per model, not per scene).
    pub model_preparation_ms: f64,
    pub preprocess_ms: f64,
    pub clustering_ms: f64,
    pub initial_alignment_ms: f64,
    pub final_alignment_ms: f64,
    pub ranking_ms: f64,
    pub total_ms: f64,
}

/// The answer for one scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Recognition {
    /// Accepted detections, ranked: `detections[0]` is the one to pick.
    pub detections: Vec<Detection>,
    pub preprocess: PreprocessReport,
    pub clusters: Vec<ClusterReport>,
    /// Detections dropped because a better one explains the same instance.
    pub duplicates_suppressed: usize,
    pub timings: Timings,
}

/// A prepared model plus parameters and worker threads. `Send + Sync`: one instance can serve
/// many threads (each call to `recognize` uses the recognizer's own thread pool).
pub struct Recognizer {
    params: Params,
    model: PreparedModel,
    pool: rayon::ThreadPool,
    threads: usize,
    preparation: Duration,
}

impl std::fmt::Debug for Recognizer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recognizer")
            .field("threads", &self.threads)
            .field("model_points", &self.model.cloud.len())
            .finish_non_exhaustive()
    }
}

/// A group larger than the model that yields no part is split again at this fraction of its
/// clustering tolerance, but not below `MIN_TOLERANCE_FACTOR` x resolution (thesis 3.4.1.3:
/// slightly above the resolution keeps single parts whole).
const TIGHTER_TOLERANCE: f64 = 0.75;
const MIN_TOLERANCE_FACTOR: f64 = 1.1;

/// Initial alignments closer than this (model diameters, degrees) to a better one are not
/// retried through the final alignment (`Params::final_candidates`).
const DISTINCT_SHIFT_DIAMETERS: f64 = 0.1;
const DISTINCT_ANGLE_DEG: f64 = 15.0;

/// Search spheres reach this many model radii from their centre.
const SPHERE_RADIUS_FACTOR: f64 = 1.5;

/// Extents outside these bounds mean the cloud is not in millimetres.
const MIN_EXTENT_RESOLUTIONS: f64 = 10.0;
const MAX_EXTENT_MM: f64 = 100_000.0;

/// Refuses empty clouds, non-finite points and extents that mean the cloud is not in mm
/// (shared with the reference engine so both word it the same).
pub(crate) fn check_extent(what: &'static str, cloud: &PointCloud, params: &Params) -> Result<()> {
    if cloud.is_empty() {
        return Err(input(what, "the cloud is empty"));
    }
    if let Some(i) = cloud.first_non_finite() {
        return Err(input(
            what,
            format!("point {i} has a non-finite coordinate"),
        ));
    }
    let extent = cloud
        .bounds()
        .map(|b| f64::from(b.diagonal()))
        .unwrap_or(0.0);
    let min = MIN_EXTENT_RESOLUTIONS * params.resolution_mm;
    if extent < min {
        return Err(input(
            what,
            format!(
                "its extent is {extent:.4} mm, smaller than {MIN_EXTENT_RESOLUTIONS} x the {} mm resolution: \
                 the cloud looks like it is in metres (binpick works in millimetres; use --units m or units = \"m\")",
                params.resolution_mm
            ),
        ));
    }
    if extent > MAX_EXTENT_MM {
        return Err(input(
            what,
            format!(
                "its extent is {extent:.0} mm (> {} m): wrong units? binpick expects millimetres",
                MAX_EXTENT_MM / 1000.0
            ),
        ));
    }
    Ok(())
}

pub(crate) fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

/// Threads to use for `params.threads` (0 = all cores).
pub fn effective_threads(params: &Params) -> usize {
    if params.threads > 0 {
        params.threads
    } else {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    }
}

impl Recognizer {
    /// Validates `params`, checks the model's units and precomputes everything that depends
    /// only on the model (voxelised cloud, keypoints, FPFH per radius, final keypoints).
    /// `model` must be in millimetres (see `binpick::load_cloud`).
    pub fn new(model: &PointCloud, params: Params) -> Result<Self> {
        params.validate()?;
        check_extent("model", model, &params)?;
        let threads = effective_threads(&params);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("binpick-{i}"))
            .build()
            .map_err(|e| Error::Threads(e.to_string()))?;
        let start = Instant::now();
        // Radii run in parallel on the pool; PCL's OpenMP gets the cores they leave.
        let omp = (threads / params.fpfh_radii_mm.len().max(1)).max(1) as u32;
        let model = pool.install(|| PreparedModel::new(model, &params, omp))?;
        Ok(Self {
            params,
            model,
            pool,
            threads,
            preparation: start.elapsed(),
        })
    }

    pub fn params(&self) -> &Params {
        &self.params
    }

    pub fn model(&self) -> &PreparedModel {
        &self.model
    }

    /// Time spent preparing the model in `new`.
    pub fn preparation(&self) -> Duration {
        self.preparation
    }

    /// Worker threads in use.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Recognizes every instance in `scene` (millimetres), within `Params::time_budget_ms`.
    pub fn recognize(&self, scene: &PointCloud) -> Result<Recognition> {
        self.recognize_within(scene, self.params.time_budget_ms.map(Duration::from_millis))
    }

    /// Like [`recognize`](Self::recognize) with an explicit time budget (`None` = unlimited).
    /// When the budget runs out the call returns [`Error::TimeBudget`] at the next check
    /// (between clusters, radii and thresholds).
    pub fn recognize_within(
        &self,
        scene: &PointCloud,
        budget: Option<Duration>,
    ) -> Result<Recognition> {
        let deadline = Deadline::new(budget);
        self.pool.install(|| self.run(scene, &deadline))
    }

    fn run(&self, scene: &PointCloud, deadline: &Deadline) -> Result<Recognition> {
        let p = &self.params;
        let mut timings = Timings {
            model_preparation_ms: ms(self.preparation),
            ..Timings::default()
        };
        check_extent("scene", scene, p)?;

        let t = Instant::now();
        let (world, report) = preprocess(scene, p, self.model.cloud.len(), self.threads)?;
        timings.preprocess_ms = ms(t.elapsed());
        deadline.check("preprocessing")?;
        if world.len() < 3 {
            return Ok(Recognition {
                detections: Vec::new(),
                preprocess: report,
                clusters: Vec::new(),
                duplicates_suppressed: 0,
                timings: Timings {
                    total_ms: ms(deadline.elapsed()),
                    ..timings
                },
            });
        }

        let t = Instant::now();
        let (min_size, max_size) = self.cluster_size_range();
        // Each point's neighbourhood at the tolerance is found once, on all threads.
        let tolerance = p.cluster_tolerance_mm() as f32;
        let world_cloud = IndexedCloud::with_neighbourhoods(&world, tolerance, self.threads as u32)
            .map_err(pcl("scene upload"))?;
        let clusters = world_cloud
            .euclidean_clusters(tolerance, min_size, max_size)
            .map_err(pcl("clustering"))?;
        drop(world_cloud);
        let final_world = FinalWorld::new(&world, p)?;
        timings.clustering_ms = ms(t.elapsed());
        deadline.check("clustering")?;

        let outcomes: Vec<ClusterOutcome> = clusters
            .par_iter()
            .enumerate()
            .map(|(i, idx)| {
                deadline.check("cluster alignment")?;
                let points: Vec<Point> = idx.iter().map(|&k| world[k as usize]).collect();
                self.search_cluster(i, points, &final_world, deadline)
            })
            .collect::<Result<_>>()?;

        let t = Instant::now();
        let mut detections = Vec::new();
        let mut cluster_reports = Vec::new();
        for o in outcomes {
            timings.initial_alignment_ms += o.initial_ms;
            timings.final_alignment_ms += o.final_ms;
            cluster_reports.push(o.report);
            detections.extend(o.detections);
        }
        let before = detections.len();
        if !p.thesis_strict {
            detections = self.suppress_duplicates(detections);
        }
        let duplicates_suppressed = before - detections.len();
        for c in &mut cluster_reports {
            c.detections = detections.iter().filter(|d| d.cluster == c.index).count();
        }
        rank_detections(&mut detections, p.rank_score_band_pct);
        timings.ranking_ms = ms(t.elapsed());
        timings.total_ms = ms(deadline.elapsed());
        Ok(Recognition {
            detections,
            preprocess: report,
            clusters: cluster_reports,
            duplicates_suppressed,
            timings,
        })
    }

    /// Cluster size bounds in points (thesis 4.3 #3-4, relative to the voxelised model).
    pub fn cluster_size_range(&self) -> (u32, u32) {
        let n = self.model.cloud.len() as f64;
        let min = (self.params.cluster_min_factor * n).ceil().max(1.0);
        let max = (self.params.cluster_max_factor * n).floor().max(min);
        (min as u32, max.min(f64::from(u32::MAX)) as u32)
    }

    /// Searches one cluster: keypoints and FPFH (thesis 4.1 step 1a-b), then initial and
    /// final alignment (steps 1b-5). Outside thesis-strict mode the search also runs on parts
    /// of the cluster, each with its own features: a cluster too big for one part (a pile) is
    /// searched in overlapping spheres (thesis 3.4.1.2); after each accepted part the points
    /// it explains are removed and the rest searched again, so touching parts are all found;
    /// a group larger than one part that yields nothing is split at a tighter tolerance (parts
    /// resting on each other often touch along an edge only).
    fn search_cluster(
        &self,
        index: usize,
        points: Vec<Point>,
        world: &FinalWorld,
        deadline: &Deadline,
    ) -> Result<ClusterOutcome> {
        let p = &self.params;
        let (min_size, _) = self.cluster_size_range();
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
        let everything: Vec<u32> = (0..points.len() as u32).collect();
        let tolerance = p.cluster_tolerance_mm();
        // (point indices into the cluster, the clustering tolerance that made them, mm) still
        // to search.
        let mut queue: VecDeque<(Vec<u32>, f64)> = if !p.thesis_strict
            && points.len() as f64 > p.sphere_split_factor * self.model.cloud.len() as f64
        {
            self.spheres(&points)?
                .into_iter()
                .map(|r| (r, tolerance))
                .collect()
        } else {
            VecDeque::from([(everything, tolerance)])
        };
        out.report.regions = queue.len();
        let mut last_reason = String::from("no candidate");
        // Each accepted part removes at least half a minimum cluster, so this bounds the loop.
        let max_rounds = 1 + out.report.points / (min_size as usize / 2).max(1);
        while let Some((part, tol)) = queue.pop_front() {
            if out.detections.len() >= max_rounds {
                last_reason = "round limit reached".into();
                break;
            }
            deadline.check("cluster alignment")?;
            let region: Vec<Point> = part.iter().map(|&i| points[i as usize]).collect();
            match self.search_part(index, &region, world, deadline, &mut out)? {
                Ok(pose) => {
                    last_reason = "accepted".into();
                    if p.thesis_strict {
                        break;
                    }
                    let mut mine = vec![false; points.len()];
                    self.mark_explained(&points, &pose, &mut mine)?;
                    let rest: Vec<u32> = part
                        .iter()
                        .copied()
                        .filter(|&i| !mine[i as usize])
                        .collect();
                    if part.len() - rest.len() < (min_size as usize / 2).max(1) {
                        last_reason =
                            "accepted part explains too few cluster points to search further"
                                .into();
                        continue;
                    }
                    if rest.len() >= min_size as usize {
                        queue.extend(
                            self.recluster(&points, &rest, min_size, tol)?
                                .into_iter()
                                .map(|s| (s, tol)),
                        );
                    }
                }
                Err(reason) => {
                    last_reason = reason;
                    let tighter =
                        (tol * TIGHTER_TOLERANCE).max(MIN_TOLERANCE_FACTOR * p.resolution_mm);
                    if !p.thesis_strict && part.len() > self.model.cloud.len() && tighter < tol {
                        let subs = self.recluster(&points, &part, min_size, tighter)?;
                        if subs.len() > 1 {
                            queue.extend(subs.into_iter().map(|s| (s, tighter)));
                        }
                    }
                }
            }
        }
        out.report.detections = out.detections.len();
        out.report.outcome = match out.detections.len() {
            0 => last_reason,
            n => format!("{n} detection(s); then {last_reason}"),
        };
        Ok(out)
    }

    /// Up to `k` hypotheses under the initial score threshold, best first, each differing
    /// from every earlier one by more than 10 % of the model diameter or 15 deg.
    fn distinct_candidates<'a>(
        &self,
        hypotheses: &'a [InitialAlignment],
        k: usize,
    ) -> Vec<&'a InitialAlignment> {
        let min_shift = DISTINCT_SHIFT_DIAMETERS * self.model.diameter_mm;
        let min_angle = DISTINCT_ANGLE_DEG.to_radians();
        let mut out: Vec<&InitialAlignment> = Vec::new();
        for h in hypotheses {
            if out.len() >= k || h.score >= self.params.initial_score_max {
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
        out
    }

    /// Keypoints and FPFH of a cluster or region of one (thesis 4.1 step 1a-b), then initial
    /// and final alignment. A region gets its own features rather than a subset of the whole
    /// cluster's: FPFH near the cut then describes the region as the model would see it
    /// alone, not its neighbours' surfaces. `Ok(Ok(pose))` when a part is accepted (and
    /// pushed to `out`), `Ok(Err(reason))` when none is.
    fn search_part(
        &self,
        index: usize,
        region: &[Point],
        world: &FinalWorld,
        deadline: &Deadline,
        out: &mut ClusterOutcome,
    ) -> Result<std::result::Result<Isometry3<f64>, String>> {
        let p = &self.params;
        let t = Instant::now();
        let hypotheses = match ClusterFeatures::new(region, p, deadline)? {
            Some(features) => initial_hypotheses(&self.model, &features, p, deadline)?,
            None => {
                out.initial_ms += ms(t.elapsed());
                return Ok(Err("fewer than 3 keypoints".into()));
            }
        };
        out.initial_ms += ms(t.elapsed());
        let Some(best) = hypotheses.first() else {
            return Ok(Err("no RANSAC consensus".into()));
        };
        if best.score >= p.initial_score_max {
            return Ok(Err(format!(
                "initial score {:.1} >= {}",
                best.score, p.initial_score_max
            )));
        }
        // The best initial alignment (thesis 4.1 step 5), then, if it fails the final
        // validation, the next distinct ones under the initial threshold.
        let candidates = self.distinct_candidates(&hypotheses, p.effective_final_candidates());
        let mut first_failure = None;
        let mut accepted = None;
        for initial in candidates {
            deadline.check("final alignment")?;
            let t = Instant::now();
            let fin = final_alignment(&self.model, world, &initial.pose, p);
            out.final_ms += ms(t.elapsed());
            if fin.score < p.final_score_max_pct {
                accepted = Some((initial, fin));
                break;
            }
            first_failure.get_or_insert(fin.score);
        }
        let Some((initial, fin)) = accepted else {
            return Ok(Err(format!(
                "final score {:.1} % >= {} %",
                first_failure.unwrap_or(f64::NAN),
                p.final_score_max_pct
            )));
        };
        let up = Vector3::from(p.up).normalize();
        let c = centroid(&self.model.final_keypoints);
        let height_mm = (fin.pose * c).coords.dot(&up);
        out.detections.push(Detection {
            rank: 0,
            pose: fin.pose,
            initial_pose: initial.pose,
            initial_score: initial.score,
            final_score: fin.score,
            score_before_icp: fin.score_before_icp,
            cluster: index,
            cluster_round: out.detections.len(),
            fpfh_radius_mm: initial.fpfh_radius_mm,
            sac_threshold_mm: initial.sac_threshold_mm,
            sac_inliers: initial.sac_inliers,
            icp: fin.icp,
            height_mm,
            rank_reason: String::new(),
        });
        Ok(Ok(fin.pose))
    }

    /// Overlapping spheres covering a big cluster (thesis 3.4.1.2), as point indices: centres
    /// are uniform keypoints of the cluster `sphere_spacing_factor` model radii apart (radius =
    /// centroid to farthest point), each sphere keeps the cluster points within 1.5 model
    /// radii. Spheres with fewer points than the smallest cluster are dropped.
    fn spheres(&self, points: &[Point]) -> Result<Vec<Vec<u32>>> {
        let radius = self.model.radius_mm;
        let (min_size, _) = self.cluster_size_range();
        let centres = binpick_pcl::uniform_sampling(
            points,
            (self.params.sphere_spacing_factor * radius) as f32,
        )
        .map_err(pcl("sphere centres"))?;
        let index = NearestIndex::new(points).map_err(|e| input("cluster", e.to_string()))?;
        let mut out = Vec::new();
        for c in centres {
            let mut members: Vec<u32> = index
                .within(&points[c as usize], (SPHERE_RADIUS_FACTOR * radius) as f32)
                .into_iter()
                .map(|i| i as u32)
                .collect();
            members.sort_unstable();
            if members.len() >= min_size as usize {
                out.push(members);
            }
        }
        Ok(out)
    }

    /// Marks the cluster points within the outlier distance of the placed model.
    fn mark_explained(
        &self,
        points: &[Point],
        pose: &Isometry3<f64>,
        explained: &mut [bool],
    ) -> Result<()> {
        let placed: Vec<Point> = self
            .model
            .cloud
            .iter()
            .map(|q| binpick_cloud::transform_point(pose, q))
            .collect();
        let index = NearestIndex::new(&placed).map_err(|e| input("model", e.to_string()))?;
        let limit = (self.params.outlier_distance_mm * self.params.outlier_distance_mm) as f32;
        for (e, q) in explained.iter_mut().zip(points) {
            if !*e && index.nearest(q).1 <= limit {
                *e = true;
            }
        }
        Ok(())
    }

    /// Euclidean clusters of the part's points at `tolerance_mm`, as point indices.
    fn recluster(
        &self,
        points: &[Point],
        part: &[u32],
        min_size: u32,
        tolerance_mm: f64,
    ) -> Result<Vec<Vec<u32>>> {
        let sub: Vec<Point> = part.iter().map(|&i| points[i as usize]).collect();
        let cloud = IndexedCloud::new(&sub).map_err(pcl("re-clustering"))?;
        let groups = cloud
            .euclidean_clusters(tolerance_mm as f32, min_size, u32::MAX)
            .map_err(pcl("re-clustering"))?;
        Ok(groups
            .into_iter()
            .map(|g| g.iter().map(|&k| part[k as usize]).collect())
            .collect())
    }

    /// Keeps, among detections of one physical instance, the one with the best final score:
    /// two detections are the same instance when `duplicate_overlap` of either's placed model
    /// keypoints lie within the outlier distance of the other's.
    fn suppress_duplicates(&self, mut detections: Vec<Detection>) -> Vec<Detection> {
        detections.sort_by(|a, b| {
            a.final_score
                .total_cmp(&b.final_score)
                .then(a.cluster.cmp(&b.cluster))
                .then(a.cluster_round.cmp(&b.cluster_round))
        });
        let kp = &self.model.final_keypoints;
        let d = self.params.outlier_distance_mm;
        let mut kept: Vec<(Detection, Option<NearestIndex>)> = Vec::new();
        for det in detections {
            let placed: Vec<Point> = kp
                .iter()
                .map(|q| binpick_cloud::transform_point(&det.pose, q))
                .collect();
            let index = NearestIndex::new(&placed).ok();
            let duplicate = kept.iter().any(|(other, other_index)| {
                let a = other_index
                    .as_ref()
                    .map_or(100.0, |oi| outlier_percent(oi, kp, &det.pose, d));
                let b = index
                    .as_ref()
                    .map_or(100.0, |i| outlier_percent(i, kp, &other.pose, d));
                let overlap = (100.0 - a.min(b)) / 100.0;
                overlap >= self.params.duplicate_overlap
            });
            if !duplicate {
                kept.push((det, index));
            }
        }
        kept.into_iter().map(|(d, _)| d).collect()
    }
}

struct ClusterOutcome {
    report: ClusterReport,
    detections: Vec<Detection>,
    initial_ms: f64,
    final_ms: f64,
}

fn centroid(points: &[Point]) -> Point3<f64> {
    let mut s = Vector3::zeros();
    for p in points {
        s += Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
    }
    Point3::from(s / points.len().max(1) as f64)
}
