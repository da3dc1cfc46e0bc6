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

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use binpick_cloud::PointCloud;

use crate::deadline::{Deadline, ms};
use crate::engines::cluster_search::ClusterSearch;
use crate::engines::scene_voting::SceneVoting;
use crate::error::{Error, Result};
use crate::params::{Engine, Params};
use crate::result::{ClusterReport, DerivedScale, Detection, Recognition, Timings};
use crate::stages::cluster::{euclidean_clusters, size_range};
use crate::stages::final_alignment::FinalWorld;
use crate::stages::hypotheses::VotingModel;
use crate::stages::model::PreparedModel;
use crate::stages::part::Part;
use crate::stages::preprocess::{check_units, preprocess, preprocess_keeping_support};
use crate::stages::rank::{rank_by_view, rank_detections, suppress_duplicates};
use crate::stages::scale::measure_spacing;

/// Identifies the scale a scene-voting model was prepared for.
type ModelKey = (u64, u64);

/// A prepared model plus parameters and worker threads. `Send + Sync`: one instance can serve
/// many threads (each call to `recognize` uses the recognizer's own thread pool).
pub struct Recognizer {
    /// As given (what reports embed).
    params: Params,
    /// What the stages run with: `params` with the extensions `thesis_strict` switches off.
    stages: Params,
    part: Part,
    /// The thesis engine's model (None with the scene-voting engine).
    thesis: Option<PreparedModel>,
    /// The scene-voting engine's model, prepared once per working scale (scans from one
    /// scanner share one).
    voting: Mutex<Vec<(ModelKey, Arc<VotingModel>)>>,
    pool: rayon::ThreadPool,
    threads: usize,
    preparation: Mutex<Duration>,
}

impl std::fmt::Debug for Recognizer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recognizer")
            .field("threads", &self.threads)
            .field("engine", &self.stages.engine)
            .field("model_points", &self.part.surface.len())
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
    /// A recognizer for a scanned model cloud (millimetres, see `binpick::load_cloud`) seen
    /// from `features.model_viewpoint_mm`.
    pub fn new(model: &PointCloud, params: Params) -> Result<Self> {
        params.validate()?;
        check_units("model", model, &params.stages().preprocess)?;
        let threads = effective_threads(params.runtime.threads);
        let part = Part::from_scan(model, params.features.model_viewpoint_mm, threads as u32)?;
        Self::with_part(part, params)
    }

    /// Validates `params` and precomputes everything that depends only on the part: for the
    /// thesis engine its keypoints and FPFH per radius; for the scene-voting engine its point
    /// pairs (now when the resolution is given, else at the first scan of each scale).
    pub fn with_part(part: Part, params: Params) -> Result<Self> {
        params.validate()?;
        let stages = params.stages();
        let threads = effective_threads(params.runtime.threads);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("binpick-{i}"))
            .build()
            .map_err(|e| Error::Threads(e.to_string()))?;
        let start = Instant::now();
        let thesis = match stages.engine {
            Engine::Thesis => {
                check_units("model", &part.cloud, &stages.preprocess)?;
                // Radii run in parallel on the pool; PCL's OpenMP gets the cores they leave.
                let omp = (threads / stages.features.fpfh_radii_mm.len().max(1)).max(1) as u32;
                Some(pool.install(|| PreparedModel::new(&part.cloud, &stages, omp))?)
            }
            Engine::SceneVoting => None,
        };
        let recognizer = Self {
            params,
            stages,
            part,
            thesis,
            voting: Mutex::new(Vec::new()),
            pool,
            threads,
            preparation: Mutex::new(start.elapsed()),
        };
        if recognizer.stages.engine == Engine::SceneVoting
            && recognizer.stages.preprocess.resolution_mm.is_some()
        {
            let scale = DerivedScale::derive(&recognizer.part.size, None, &recognizer.stages)?;
            recognizer.voting_model(&scale)?;
        }
        Ok(recognizer)
    }

    pub fn params(&self) -> &Params {
        &self.params
    }

    /// The part being searched for.
    pub fn part(&self) -> &Part {
        &self.part
    }

    /// The thesis engine's prepared model (None with the scene-voting engine).
    pub fn model(&self) -> Option<&PreparedModel> {
        self.thesis.as_ref()
    }

    /// Time spent preparing the model so far (in `new`, and for the scene-voting engine at
    /// the first scan of each new scale).
    pub fn preparation(&self) -> Duration {
        self.preparation.lock().map(|d| *d).unwrap_or_default()
    }

    /// Worker threads in use.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// The scene-voting model for `scale`, prepared on first use.
    fn voting_model(&self, scale: &DerivedScale) -> Result<Arc<VotingModel>> {
        let key = scale.model_key();
        let poisoned = || Error::Threads("a thread preparing the model panicked".into());
        if let Some((_, m)) = self
            .voting
            .lock()
            .map_err(|_| poisoned())?
            .iter()
            .find(|(k, _)| *k == key)
        {
            return Ok(Arc::clone(m));
        }
        let start = Instant::now();
        let model = Arc::new(
            self.pool
                .install(|| VotingModel::new(&self.part, scale, &self.stages.voting))?,
        );
        let mut cache = self.voting.lock().map_err(|_| poisoned())?;
        if let Some((_, m)) = cache.iter().find(|(k, _)| *k == key) {
            return Ok(Arc::clone(m));
        }
        cache.push((key, Arc::clone(&model)));
        if let Ok(mut d) = self.preparation.lock() {
            *d += start.elapsed();
        }
        Ok(model)
    }

    /// Recognizes every instance in `scene` (millimetres), within `time_budget_ms`.
    pub fn recognize(&self, scene: &PointCloud) -> Result<Recognition> {
        let budget = self.params.runtime.time_budget_ms;
        self.recognize_within(scene, budget.map(Duration::from_millis))
    }

    /// Like [`recognize`](Self::recognize) for a scan that says where its sensor was
    /// (scene frame, mm; a PCD's `VIEWPOINT`): with `sensor = auto`, the scene-voting engine
    /// then sees the scene from a camera there.
    pub fn recognize_seen_from(
        &self,
        scene: &PointCloud,
        sensor_position_mm: Option<[f64; 3]>,
    ) -> Result<Recognition> {
        let budget = self.params.runtime.time_budget_ms;
        let deadline = Deadline::new(budget.map(Duration::from_millis));
        self.pool
            .install(|| self.run(scene, &deadline, sensor_position_mm))
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
        self.pool.install(|| self.run(scene, &deadline, None))
    }

    fn run(
        &self,
        scene: &PointCloud,
        deadline: &Deadline,
        sensor_position_mm: Option<[f64; 3]>,
    ) -> Result<Recognition> {
        match &self.thesis {
            Some(model) => self.run_thesis(model, scene, deadline),
            None => self.run_scene_voting(scene, deadline, sensor_position_mm),
        }
    }

    /// The scene-voting pipeline: measure the scan, preprocess keeping the support, find
    /// every part (hypotheses from the whole scene, verified against the sensor's view,
    /// competing to explain it), rank.
    fn run_scene_voting(
        &self,
        scene: &PointCloud,
        deadline: &Deadline,
        sensor_position_mm: Option<[f64; 3]>,
    ) -> Result<Recognition> {
        let p = &self.stages;
        let seen_from;
        let p = match (&p.verify.sensor, sensor_position_mm) {
            (crate::params::SensorConfig::Auto, Some(position_mm)) => {
                let mut q = p.clone();
                q.verify.sensor = crate::params::SensorConfig::Camera { position_mm };
                seen_from = q;
                &seen_from
            }
            _ => p,
        };
        let mut timings = Timings::default();
        let mut lap = Instant::now();
        let mut step = |t: &mut f64, stage: &'static str| {
            *t = ms(lap.elapsed());
            lap = Instant::now();
            deadline.check(stage)
        };

        // Scale: the scan's spacing, and every length derived from it and the part.
        check_units("scene", scene, &p.preprocess)?;
        let spacing = measure_spacing(&scene.points)?;
        let scale = DerivedScale::derive(&self.part.size, spacing, p)?;
        let model = self.voting_model(&scale)?;
        timings.model_preparation_ms = ms(self.preparation());

        // Preprocessing: crop, voxel grid at the working resolution, support found (kept).
        let mut pre = p.preprocess.clone();
        pre.resolution_mm = Some(scale.resolution_mm);
        pre.support.distance_mm = Some(scale.support_distance_mm);
        let part_points = scale.part_points.ceil() as usize;
        let (points, support, preprocessed) =
            preprocess_keeping_support(scene, &pre, scale.connect_mm, part_points, self.threads)?;
        step(&mut timings.preprocess_ms, "preprocessing")?;

        // Hypotheses over the whole scene, verification, scene explanation.
        let engine = SceneVoting {
            params: p,
            part: &self.part,
            model: &model,
            scale: &scale,
            deadline,
            threads: self.threads,
        };
        let found = engine.detect(&points, &support)?;
        timings.initial_alignment_ms = found.voting_ms;
        timings.final_alignment_ms = found.verify_ms;

        // Pick order: free parts first, then by visibility (4.2.2 extended).
        lap = Instant::now();
        let mut detections = found.detections;
        rank_by_view(&mut detections, &p.ranking);
        timings.ranking_ms = ms(lap.elapsed());
        timings.total_ms = ms(deadline.elapsed());
        Ok(Recognition {
            detections,
            preprocess: preprocessed,
            scale: Some(scale),
            voting: Some(found.report),
            clusters: Vec::new(),
            duplicates_suppressed: 0,
            timings,
        })
    }

    /// The thesis's pipeline: Algorithm 1 (or 2) over every cluster of the scene, then
    /// ranking.
    fn run_thesis(
        &self,
        model: &PreparedModel,
        scene: &PointCloud,
        deadline: &Deadline,
    ) -> Result<Recognition> {
        let p = &self.stages;
        let mut timings = Timings {
            model_preparation_ms: ms(self.preparation()),
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
        let (detections, duplicates) = self.rank(model, found.detections, &mut cluster_reports);
        timings.ranking_ms = ms(lap.elapsed());
        timings.total_ms = ms(deadline.elapsed());
        Ok(Recognition {
            duplicates_suppressed: duplicates,
            detections,
            preprocess: preprocessed,
            scale: None,
            voting: None,
            clusters: cluster_reports,
            timings,
        })
    }

    /// Duplicate suppression (when on), the per-cluster counts that survive it, and the pick
    /// ranking; also returns how many duplicates were dropped.
    fn rank(
        &self,
        model: &PreparedModel,
        mut detections: Vec<Detection>,
        clusters: &mut [ClusterReport],
    ) -> (Vec<Detection>, usize) {
        let p = &self.stages;
        let found = detections.len();
        if p.ranking.suppress_duplicates {
            let d = p.validation.outlier_distance_mm;
            let overlap = p.ranking.duplicate_overlap;
            let keypoints = &model.final_keypoints;
            detections = suppress_duplicates(detections, keypoints, d, overlap);
        }
        for c in clusters.iter_mut() {
            c.detections = detections
                .iter()
                .filter(|d| d.cluster() == Some(c.index))
                .count();
        }
        rank_detections(&mut detections, p.ranking.rank_score_band_pct);
        let duplicates = found - detections.len();
        (detections, duplicates)
    }
}
