//! The library entry point: [`Recognizer::new`] prepares a model once,
//! [`Recognizer::recognize`] finds, validates and ranks every instance in a scene.
//!
//! [`Recognizer::run`] is the pipeline, one call per step of the thesis (Algorithm 1, 4.1;
//! each stage takes its own config and the previous stage's output):
//!
//! ```text
//!   scene --preprocess--> world --cluster--> clusters
//!         --engine (per cluster: keypoints+FPFH, correspondences, RANSAC sweep+SVD+score,
//!                   best initial, ICP + percent of outliers, accept)--> detections
//!         --suppress duplicates--> --rank--> Recognition
//! ```

use std::time::{Duration, Instant};

use binpick_cloud::PointCloud;

use crate::deadline::{Deadline, ms};
use crate::engines::cluster_search::ClusterSearch;
use crate::error::{Error, Result};
use crate::params::Params;
use crate::result::{ClusterReport, Detection, Recognition, Timings};
use crate::stages::cluster::{euclidean_clusters, size_range};
use crate::stages::final_alignment::FinalWorld;
use crate::stages::model::PreparedModel;
use crate::stages::preprocess::{check_units, preprocess};
use crate::stages::rank::{rank_detections, suppress_duplicates};

/// A prepared model plus parameters and worker threads. `Send + Sync`: one instance can serve
/// many threads (each call to `recognize` uses the recognizer's own thread pool).
pub struct Recognizer {
    /// As given (what reports embed).
    params: Params,
    /// What the stages run with: `params` with the extensions `thesis_strict` switches off.
    stages: Params,
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

/// Threads to use for `threads` (0 = all cores).
fn effective_threads(threads: usize) -> usize {
    if threads > 0 {
        threads
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
        let stages = params.stages();
        check_units("model", model, &stages.preprocess)?;
        let threads = effective_threads(params.runtime.threads);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("binpick-{i}"))
            .build()
            .map_err(|e| Error::Threads(e.to_string()))?;
        let start = Instant::now();
        // Radii run in parallel on the pool; PCL's OpenMP gets the cores they leave.
        let omp = (threads / stages.features.fpfh_radii_mm.len().max(1)).max(1) as u32;
        let model = pool.install(|| PreparedModel::new(model, &stages, omp))?;
        Ok(Self {
            params,
            stages,
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

    /// Recognizes every instance in `scene` (millimetres), within `time_budget_ms`.
    pub fn recognize(&self, scene: &PointCloud) -> Result<Recognition> {
        let budget = self.params.runtime.time_budget_ms;
        self.recognize_within(scene, budget.map(Duration::from_millis))
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

    /// The pipeline: thesis Algorithm 1 (or 2) over every cluster of the scene, then ranking.
    fn run(&self, scene: &PointCloud, deadline: &Deadline) -> Result<Recognition> {
        let p = &self.stages;
        let model = &self.model;
        let mut timings = Timings {
            model_preparation_ms: ms(self.preparation),
            ..Timings::default()
        };
        let mut lap = Instant::now();
        let mut step = |t: &mut f64, stage: &'static str| {
            *t = ms(lap.elapsed());
            lap = Instant::now();
            deadline.check(stage)
        };

        // Preprocessing: units check, crop, voxel grid (4.3 #1), support removal (5.2).
        check_units("scene", scene, &p.preprocess)?;
        let tolerance = p.cluster_tolerance_mm();
        let n = model.cloud.len();
        let (world, preprocessed) = preprocess(scene, &p.preprocess, tolerance, n, self.threads)?;
        step(&mut timings.preprocess_ms, "preprocessing")?;
        if world.len() < 3 {
            timings.total_ms = ms(deadline.elapsed());
            return Ok(Recognition::empty(preprocessed, timings));
        }
        // Euclidean clusters (3.4.1.3) and the scene's final keypoints for ICP (step 3a).
        let sizes = size_range(&p.clustering, n);
        let clusters = euclidean_clusters(&world, tolerance, sizes, self.threads)?;
        let final_world = FinalWorld::new(&world, &p.icp)?;
        step(&mut timings.clustering_ms, "clustering")?;

        // Per cluster, Algorithm 1/2: keypoints + FPFH, correspondences, RANSAC threshold
        // sweep + SVD + Euclidean score, best initial alignment, ICP final alignment +
        // percent of outliers, accept (steps 1-5).
        let engine = ClusterSearch {
            stages: p,
            model,
            world: &final_world,
            deadline,
        };
        let found = engine.run(&world, &clusters)?;
        timings.initial_alignment_ms = found.initial_ms;
        timings.final_alignment_ms = found.final_ms;

        // Drop duplicates of one instance (extension), rank for picking (1.2 step 3).
        lap = Instant::now();
        let mut cluster_reports = found.clusters;
        let (detections, duplicates) = self.rank(found.detections, &mut cluster_reports);
        timings.ranking_ms = ms(lap.elapsed());
        timings.total_ms = ms(deadline.elapsed());
        Ok(Recognition {
            duplicates_suppressed: duplicates,
            detections,
            preprocess: preprocessed,
            clusters: cluster_reports,
            timings,
        })
    }

    /// Duplicate suppression (when on), the per-cluster counts that survive it, and the pick
    /// ranking; also returns how many duplicates were dropped.
    fn rank(
        &self,
        mut detections: Vec<Detection>,
        clusters: &mut [ClusterReport],
    ) -> (Vec<Detection>, usize) {
        let p = &self.stages;
        let found = detections.len();
        if p.ranking.suppress_duplicates {
            let d = p.validation.outlier_distance_mm;
            let overlap = p.ranking.duplicate_overlap;
            let keypoints = &self.model.final_keypoints;
            detections = suppress_duplicates(detections, keypoints, d, overlap);
        }
        for c in clusters.iter_mut() {
            c.detections = detections.iter().filter(|d| d.cluster == c.index).count();
        }
        rank_detections(&mut detections, p.ranking.rank_score_band_pct);
        let duplicates = found - detections.len();
        (detections, duplicates)
    }
}
