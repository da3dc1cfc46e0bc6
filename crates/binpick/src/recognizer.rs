//! The library entry point: [`Recognizer::new`] prepares a model once,
//! [`Recognizer::recognize`] finds, validates and ranks every instance in a scene
//! ([`Recognizer::recognize_with`]: with a time budget, a cancel token, a region of interest).
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

use std::borrow::Cow;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use binpick_cloud::{PointCloud, Units};

use crate::deadline::{CancelToken, Deadline, ms};
use crate::engines::cluster_search::{ClusterSearch, Found};
use crate::engines::scene_voting::SceneVoting;
use crate::error::{Error, Result};
use crate::frames::OutputFrame;
use crate::grasp::{GraspScene, check_and_order};
use crate::params::{Engine, Params, RegionOfInterest, check_sampling_leaf};
use crate::prepared::{ModelKey, PreparedHeader, voting_params_hash};
use crate::result::{
    ClusterReport, DerivedScale, Detection, Interruption, PreprocessReport, Recognition, StopCause,
    Timings,
};
use crate::stages::cluster::{euclidean_clusters, size_range};
use crate::stages::final_alignment::FinalWorld;
use crate::stages::hypotheses::VotingModel;
use crate::stages::model::PreparedModel;
use crate::stages::part::Part;
use crate::stages::preprocess::{
    SupportSize, bounds, check_units, clean_scene, label_support_noise, preprocess, support_of,
    voxelise,
};
use crate::stages::rank::{rank_by_view, rank_detections, suppress_duplicates, withhold_picks};
use crate::stages::scale::measure_spacing;
use crate::workers::Workers;

/// Why a turn-ambiguous model's picks are withheld (`VotingReport::turn_ambiguous`).
const TURN_AMBIGUOUS: &str = "the model is a scan whose near-symmetric turn shows the side its \
     scanner never saw, so a part lying the other way up fits it as that turn and no pose can \
     be told from its turn (give the CAD mesh, or set pick_turn_ambiguous where every part \
     lies the scanned side up)";

/// One scan made ready for the scene-voting engine.
struct PreparedScene {
    scale: DerivedScale,
    model: Arc<VotingModel>,
    /// The preprocessed points, support included ...
    points: Vec<binpick_cloud::Point>,
    /// ... and which of them are support ...
    support: Vec<bool>,
    /// ... and the support planes, `a x + b y + c z + d = 0` (mm).
    planes: Vec<[f64; 4]>,
}

/// What one call runs with: its stage configs (the recognizer's, with the call's options),
/// its deadline and the threads it leased.
#[derive(Clone, Copy)]
struct Call<'a> {
    p: &'a Params,
    deadline: &'a Deadline,
    threads: usize,
}

/// A prepared model plus parameters and worker threads. `Send + Sync`: one instance can serve
/// many threads. Concurrent calls share its `threads` cores without oversubscribing them: a
/// call alone uses all of them, queued calls split them (see [`Timings::queue_ms`]).
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
    workers: Workers,
    preparation: Mutex<Duration>,
}

/// Options of one call to [`Recognizer::recognize_with`]; `Default` is what
/// [`Recognizer::recognize`] uses. Build it with the setters:
///
/// ```
/// # use std::time::Duration;
/// let cancel = binpick::CancelToken::new();
/// let options = binpick::RecognizeOptions::default()
///     .time_budget(Duration::from_millis(500))
///     .cancel(cancel.clone());
/// ```
#[derive(Clone, Debug, Default)]
#[non_exhaustive]
pub struct RecognizeOptions {
    /// Time budget of this call, counted from the start of its work (not the wait for
    /// worker threads). `None`: the recognizer's `time_budget_ms` (itself unlimited unless
    /// set). When it runs out the call returns what it verified so far, flagged.
    pub time_budget: Option<Duration>,
    /// Stops the call when cancelled (before or during it); it then returns what it verified
    /// so far, flagged.
    pub cancel: Option<CancelToken>,
    /// Crop box for this call, replacing the parameters' `region_of_interest`.
    pub region_of_interest: Option<RegionOfInterest>,
    /// Where the sensor was (scene frame, mm; a PCD's `VIEWPOINT`): with `sensor = auto`, the
    /// scene-voting engine then sees the scene from a camera there.
    pub sensor_position_mm: Option<[f64; 3]>,
    /// The frame poses and grasps come back in (e.g. the robot's base): None for the
    /// scanner's own. Ranking and grasp checks run in the scanner's frame either way.
    pub output_frame: Option<OutputFrame>,
}

impl RecognizeOptions {
    /// Poses and grasps in `frame` (see [`OutputFrame`]).
    pub fn output_frame(mut self, frame: OutputFrame) -> Self {
        self.output_frame = Some(frame);
        self
    }

    /// Sets the call's time budget.
    pub fn time_budget(mut self, budget: Duration) -> Self {
        self.time_budget = Some(budget);
        self
    }

    /// Sets the token that cancels the call.
    pub fn cancel(mut self, token: CancelToken) -> Self {
        self.cancel = Some(token);
        self
    }

    /// Sets the call's crop box (scene frame, mm).
    pub fn region_of_interest(mut self, roi: RegionOfInterest) -> Self {
        self.region_of_interest = Some(roi);
        self
    }

    /// Sets where the sensor was (scene frame, mm), if known.
    pub fn sensor_position_mm(mut self, position: Option<[f64; 3]>) -> Self {
        self.sensor_position_mm = position;
        self
    }
}

impl std::fmt::Debug for Recognizer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recognizer")
            .field("threads", &self.workers.threads())
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
        let workers = Workers::new(threads)?;
        let start = Instant::now();
        let thesis = match stages.engine {
            Engine::Thesis => {
                check_units("model", &part.cloud, &stages.preprocess)?;
                let (lo, hi) = bounds(&part.cloud.points);
                let (f, icp) = (&stages.features, &stages.icp);
                check_sampling_leaf("initial_leaf_mm", f.initial_leaf_mm, "the model", lo, hi)?;
                check_sampling_leaf("final_leaf_mm", icp.final_leaf_mm, "the model", lo, hi)?;
                // Radii run in parallel on the pool; PCL's OpenMP gets the cores they leave.
                let omp = (threads / stages.features.fpfh_radii_mm.len().max(1)).max(1) as u32;
                Some(workers.install_full(|| PreparedModel::new(&part.cloud, &stages, omp))?)
            }
            Engine::SceneVoting => None,
        };
        // Voting models read from a prepared-model file, when they fit these parameters.
        let voting = match &part.prepared {
            Some(ready) if ready.params_hash != voting_params_hash(&params) => {
                return Err(crate::error::input(
                    "prepared model",
                    "it was prepared with other voting table parameters (feature_angle_bins, \
                     alpha_bins, spread, max_pairs_per_bin) than these; prepare it again with \
                     them (binpick model prepare)",
                ));
            }
            Some(ready) => ready.models.clone(),
            None => Vec::new(),
        };
        let recognizer = Self {
            params,
            stages,
            part,
            thesis,
            voting: Mutex::new(voting),
            workers,
            preparation: Mutex::new(start.elapsed()),
        };
        if recognizer.stages.engine == Engine::SceneVoting
            && recognizer.stages.preprocess.resolution_mm.is_some()
        {
            let scale = DerivedScale::derive(&recognizer.part.size, None, &recognizer.stages)?;
            recognizer
                .workers
                .install_full(|| recognizer.voting_model(&scale))?;
        }
        Ok(recognizer)
    }

    /// The parameters as given.
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

    /// Prepares the scene-voting model for the working scale of `scene` (the scale its
    /// recognition would derive), so that [`write_prepared`](Self::write_prepared) stores it.
    /// Returns that scale.
    pub fn prepare_for(&self, scene: &PointCloud) -> Result<DerivedScale> {
        let deadline = Deadline::unlimited();
        let mut report = PreprocessReport::default();
        let cleaned = clean_scene(scene, &self.stages.preprocess, &deadline, &mut report)?;
        let scale = self.scale_of(&cleaned, &self.stages)?;
        self.workers.install_full(|| self.voting_model(&scale))?;
        Ok(scale)
    }

    /// Writes the part and every scene-voting model prepared so far to `path` (see
    /// [`crate::prepared`]); `source` is the model file the part was loaded from, in `units`.
    pub fn write_prepared(
        &self,
        path: &std::path::Path,
        source: &std::path::Path,
        units: Units,
    ) -> Result<PreparedHeader> {
        let models = self
            .voting
            .lock()
            .map_err(|_| Error::Threads("a thread preparing the model panicked".into()))?
            .clone();
        crate::prepared::write(path, source, units, &self.params, &self.part, &models)
    }

    /// The derived lengths for a cleaned scan: its spacing measured, the rest from the part.
    fn scale_of(&self, cleaned: &[binpick_cloud::Point], p: &Params) -> Result<DerivedScale> {
        let spacing = measure_spacing(cleaned)?;
        DerivedScale::derive(&self.part.size, spacing, p)
    }

    /// Worker threads (the most one call uses).
    pub fn threads(&self) -> usize {
        self.workers.threads()
    }

    /// The scene-voting model for `scale`, prepared on first use (on the calling pool: a
    /// recognition's own lease, or every thread in `new`).
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
        let model = Arc::new(VotingModel::new(&self.part, scale, &self.stages.voting)?);
        if model.turn_ambiguous {
            tracing::warn!("{TURN_AMBIGUOUS}: first picks are withheld");
        }
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

    /// Recognizes every instance in `scene` (millimetres), within the parameters'
    /// `time_budget_ms`.
    pub fn recognize(&self, scene: &PointCloud) -> Result<Recognition> {
        self.recognize_with(scene, &RecognizeOptions::default())
    }

    /// Like [`recognize`](Self::recognize) for a scan that says where its sensor was
    /// (scene frame, mm; a PCD's `VIEWPOINT`): with `sensor = auto`, the scene-voting engine
    /// then sees the scene from a camera there.
    pub fn recognize_seen_from(
        &self,
        scene: &PointCloud,
        sensor_position_mm: Option<[f64; 3]>,
    ) -> Result<Recognition> {
        let options = RecognizeOptions::default().sensor_position_mm(sensor_position_mm);
        self.recognize_with(scene, &options)
    }

    /// [`recognize`](Self::recognize) with per-call options: a time budget, a cancel token, a
    /// region of interest, the sensor position.
    ///
    /// When the budget runs out or the token is cancelled, the call returns `Ok` promptly
    /// with the detections verified so far (each passed the final validation; possibly none)
    /// and `Recognition::interrupted` set; clusters not searched say so in their outcome.
    /// The budget and checks cover every long stage (preprocessing, clustering, each cluster,
    /// region, FPFH radius and RANSAC job, ICP iterations, support plane fits; voting and each
    /// candidate's verification). `Err` is for bad input, bad options and PCL failures only.
    pub fn recognize_with(
        &self,
        scene: &PointCloud,
        options: &RecognizeOptions,
    ) -> Result<Recognition> {
        let queued = Instant::now();
        let budget = options.time_budget.or(self
            .params
            .runtime
            .time_budget_ms
            .map(Duration::from_millis));
        let stages = match options.region_of_interest {
            None => Cow::Borrowed(&self.stages),
            Some(roi) => {
                let mut p = self.stages.clone();
                p.preprocess.region_of_interest = Some(roi);
                p.preprocess.validate()?;
                Cow::Owned(p)
            }
        };
        let Some(lease) = self.workers.lease(options.cancel.as_ref())? else {
            return Ok(self.cancelled_in_queue(ms(queued.elapsed())));
        };
        let queue_ms = ms(queued.elapsed());
        let deadline = Deadline::new(budget, options.cancel.clone());
        let threads = lease.threads();
        let mut result = lease.run(deadline.interrupt(), || {
            let call = Call {
                p: &stages,
                deadline: &deadline,
                threads,
            };
            self.run(scene, &call, options.sensor_position_mm)
        })?;
        result.timings.queue_ms = queue_ms;
        if let Some(frame) = &options.output_frame {
            result.express_in(frame);
        }
        Ok(result)
    }

    /// The answer of a call cancelled before it started.
    fn cancelled_in_queue(&self, queue_ms: f64) -> Recognition {
        let mut r = Recognition::empty(
            PreprocessReport::default(),
            Timings {
                model_preparation_ms: ms(self.preparation()),
                queue_ms,
                ..Timings::default()
            },
        );
        r.interrupted = Some(Interruption {
            cause: StopCause::Cancelled,
            budget_ms: None,
            stage: "start".into(),
            elapsed_ms: 0.0,
        });
        r
    }

    /// One engine's pipeline, then the report at return: when the deadline stopped it, what
    /// was verified is ranked and returned, flagged.
    fn run(
        &self,
        scene: &PointCloud,
        call: &Call,
        sensor_position_mm: Option<[f64; 3]>,
    ) -> Result<Recognition> {
        let mut r = match &self.thesis {
            Some(model) => self.run_thesis(model, scene, call)?,
            None => self.run_scene_voting(scene, call, sensor_position_mm)?,
        };
        // One instant for both: the flag holds exactly when the return is past the budget.
        let at_return = call.deadline.elapsed();
        r.interrupted = call.deadline.report(at_return);
        r.timings.total_ms = ms(at_return);
        Ok(r)
    }

    /// The scene-voting pipeline: clean and measure the scan, preprocess keeping the
    /// support, find every part (hypotheses from the whole scene, verified against the
    /// sensor's view, competing to explain it), rank. Interrupted, it keeps the candidates
    /// verified so far in the scene explanation.
    fn run_scene_voting(
        &self,
        scene: &PointCloud,
        call: &Call,
        sensor_position_mm: Option<[f64; 3]>,
    ) -> Result<Recognition> {
        let p = &self.stages_seen_from(call.p, sensor_position_mm);
        let call = &Call { p, ..*call };
        let mut timings = Timings::default();
        let mut preprocessed = PreprocessReport::default();
        let mut scale = None;
        let mut points = Vec::new();
        let detect = self.vote(
            scene,
            call,
            &mut timings,
            &mut preprocessed,
            &mut scale,
            &mut points,
        );
        let found = call.deadline.partial(detect)?;

        // Pick order: free parts first, then by visibility (4.2.2 extended).
        let lap = Instant::now();
        let (mut detections, voting) = match found {
            Some(f) => {
                timings.initial_alignment_ms = f.voting_ms;
                timings.final_alignment_ms = f.verify_ms;
                (f.detections, Some(f.report))
            }
            None => (Vec::new(), None),
        };
        let ranking = tracing::info_span!("ranking").entered();
        let edge_on = scale
            .as_ref()
            .map_or(0.0, crate::stages::verify::edge_on_cells);
        rank_by_view(
            &mut detections,
            &p.ranking,
            p.verify.free_space_weight,
            edge_on,
        );
        if voting.as_ref().is_some_and(|v| v.turn_ambiguous) && !p.ranking.pick_turn_ambiguous {
            withhold_picks(&mut detections, TURN_AMBIGUOUS);
        }
        let tolerance = scale.map_or(p.validation.outlier_distance_mm, |s| s.tolerance_mm);
        self.check_grasps(&mut detections, &points, p, tolerance)?;
        drop(ranking);
        timings.ranking_ms = ms(lap.elapsed());
        Ok(Recognition {
            detections,
            preprocess: preprocessed,
            scale,
            voting,
            clusters: Vec::new(),
            duplicates_suppressed: 0,
            timings,
            interrupted: None,
            frame: crate::frames::OutputFrame::scanner(),
        })
    }

    /// The scene-voting engine up to its detections (see [`run_scene_voting`](Self::run_scene_voting)).
    fn vote(
        &self,
        scene: &PointCloud,
        call: &Call,
        timings: &mut Timings,
        preprocessed: &mut PreprocessReport,
        scale_out: &mut Option<DerivedScale>,
        points_out: &mut Vec<binpick_cloud::Point>,
    ) -> Result<crate::engines::scene_voting::VotingFound> {
        let lap = Instant::now();
        let PreparedScene {
            scale,
            model,
            points,
            support,
            planes,
        } = {
            let _span = tracing::info_span!("preprocessing").entered();
            self.prepare_scene(scene, call, preprocessed, scale_out)?
        };
        tracing::debug!(
            points = points.len(),
            support = support.iter().filter(|s| **s).count(),
            resolution_mm = scale.resolution_mm,
            "scene prepared"
        );
        points_out.clone_from(&points);
        timings.model_preparation_ms = ms(self.preparation());
        timings.preprocess_ms = ms(lap.elapsed());

        // Hypotheses over the whole scene, verification, scene explanation.
        let engine = SceneVoting {
            params: call.p,
            part: &self.part,
            model: &model,
            scale: &scale,
            deadline: call.deadline,
            threads: call.threads,
            support_planes: &planes,
        };
        engine.detect(&points, &support)
    }

    /// Crop, strays, units; the scan's spacing and every length derived from it and the
    /// part; the voxel grid at the working resolution with the support found and kept (it is
    /// what the sensor saw behind the parts). The noise of the largest support plane widens
    /// the view's tolerance.
    fn prepare_scene(
        &self,
        scene: &PointCloud,
        call: &Call,
        preprocessed: &mut PreprocessReport,
        scale_out: &mut Option<DerivedScale>,
    ) -> Result<PreparedScene> {
        let p = call.p;
        let cleaned = clean_scene(scene, &p.preprocess, call.deadline, preprocessed)?;
        let scale = self.scale_of(&cleaned, p)?;
        *scale_out = Some(scale);
        let model = self.voting_model(&scale)?;
        let mut pre = p.preprocess.clone();
        pre.resolution_mm = Some(scale.resolution_mm);
        pre.support.distance_mm = Some(scale.support_distance_mm);
        let points = voxelise(&cleaned, &pre, call.deadline, preprocessed)?;
        drop(cleaned);
        let mut support = support_of(
            &points,
            &pre,
            scale.connect_mm,
            SupportSize::Area {
                view_area_mm2: scale.part_view_area_mm2,
                curved: scale.part_curvature_radius_mm.is_some(),
            },
            call.threads,
            call.deadline,
            preprocessed,
        )?;
        let noise = preprocessed.support_planes.first().and_then(|p| p.rms_mm);
        let planes: Vec<[f64; 4]> = preprocessed
            .support_planes
            .iter()
            .map(|p| p.coefficients.map(f64::from))
            .collect();
        let s = &p.preprocess.support;
        if let Some(sigma) = noise.filter(|_| s.noise_tail_sigmas > 0.0) {
            preprocessed.support_noise = label_support_noise(
                &points,
                &mut support,
                &planes,
                scale.support_distance_mm,
                s.noise_tail_sigmas * sigma,
                2.0 * scale.resolution_mm,
                s.noise_tail_min_neighbours,
            )?;
            preprocessed.remaining -= preprocessed.support_noise;
        }
        let scale = scale.with_noise(noise, preprocessed.support_band_mm, p);
        *scale_out = Some(scale);
        Ok(PreparedScene {
            scale,
            model,
            points,
            support,
            planes,
        })
    }

    /// The stage configs `p`, with the sensor at `position` when they leave it on auto.
    fn stages_seen_from(&self, p: &Params, position: Option<[f64; 3]>) -> Params {
        let mut p = p.clone();
        if let (crate::params::SensorConfig::Auto, Some(position_mm)) = (&p.verify.sensor, position)
        {
            p.verify.sensor = crate::params::SensorConfig::Camera { position_mm };
        }
        p
    }

    /// Judges a given `pose` (model -> scene, mm) against `scene` the way the scene-voting
    /// engine judges its hypotheses: on the surface the sensor can see, refined by ICP first
    /// when `refine`. For checking a taught or external pose. Runs without a time budget.
    pub fn check_pose(
        &self,
        scene: &PointCloud,
        sensor_position_mm: Option<[f64; 3]>,
        pose: &nalgebra::Isometry3<f64>,
        refine: bool,
    ) -> Result<crate::result::PoseCheck> {
        let mut checks = self.check_poses(
            scene,
            sensor_position_mm,
            std::slice::from_ref(pose),
            refine,
        )?;
        Ok(checks.remove(0))
    }

    /// [`Recognizer::check_pose`] for several poses of one scene, in the order given: the
    /// scene is preprocessed and its surface and view built once (most of a single check's
    /// time), the poses judged in parallel. Each answer is the one `check_pose` gives alone.
    pub fn check_poses(
        &self,
        scene: &PointCloud,
        sensor_position_mm: Option<[f64; 3]>,
        poses: &[nalgebra::Isometry3<f64>],
        refine: bool,
    ) -> Result<Vec<crate::result::PoseCheck>> {
        if let Some(i) = poses.iter().position(|p| {
            !(p.translation.vector.iter().all(|c| c.is_finite())
                && p.rotation.coords.iter().all(|c| c.is_finite()))
        }) {
            return Err(crate::error::input(
                "check_poses",
                format!("pose {i} has a non-finite entry"),
            ));
        }
        if poses.is_empty() {
            return Ok(Vec::new());
        }
        let p = self.stages_seen_from(&self.stages, sensor_position_mm);
        // Without a cancel token the lease always comes (after any queued calls).
        let Some(lease) = self.workers.lease(None)? else {
            return Err(crate::error::input("check_poses", "cancelled while queued"));
        };
        let deadline = Deadline::new(None, None);
        let threads = lease.threads();
        lease.run(deadline.interrupt(), || {
            let call = Call {
                p: &p,
                deadline: &deadline,
                threads,
            };
            let mut report = PreprocessReport::default();
            let prepared = self.prepare_scene(scene, &call, &mut report, &mut None)?;
            let engine = SceneVoting {
                params: &p,
                part: &self.part,
                model: &prepared.model,
                scale: &prepared.scale,
                deadline: &deadline,
                threads,
                support_planes: &prepared.planes,
            };
            engine.check(&prepared.points, &prepared.support, poses, refine)
        })
    }

    /// The thesis's pipeline: Algorithm 1 (or 2) over every cluster of the scene, then
    /// ranking. Interrupted clusters keep the parts they had accepted.
    fn run_thesis(
        &self,
        model: &PreparedModel,
        scene: &PointCloud,
        call: &Call,
    ) -> Result<Recognition> {
        let mut timings = Timings {
            model_preparation_ms: ms(self.preparation()),
            ..Timings::default()
        };
        let mut preprocessed = PreprocessReport::default();
        let mut world = Vec::new();
        let detect = self.search_clusters(
            model,
            scene,
            call,
            &mut timings,
            &mut preprocessed,
            &mut world,
        );
        let found = call.deadline.partial(detect)?.unwrap_or_default();
        timings.initial_alignment_ms = found.initial_ms;
        timings.final_alignment_ms = found.final_ms;

        // Drop duplicates of one instance (extension), rank for picking (1.2 step 3); cheap,
        // so done for an interrupted call too.
        let lap = Instant::now();
        let ranking = tracing::info_span!("ranking").entered();
        let mut clusters = found.clusters;
        let (mut detections, duplicates) =
            self.rank(call.p, model, found.detections, &mut clusters);
        let tolerance = call.p.validation.outlier_distance_mm;
        self.check_grasps(&mut detections, &world, call.p, tolerance)?;
        drop(ranking);
        timings.ranking_ms = ms(lap.elapsed());
        Ok(Recognition {
            duplicates_suppressed: duplicates,
            detections,
            preprocess: preprocessed,
            scale: None,
            voting: None,
            clusters,
            timings,
            interrupted: None,
            frame: crate::frames::OutputFrame::scanner(),
        })
    }

    /// Preprocessing, clustering and the thesis engine: the accepted detections in cluster
    /// order.
    fn search_clusters(
        &self,
        model: &PreparedModel,
        scene: &PointCloud,
        call: &Call,
        timings: &mut Timings,
        preprocessed: &mut PreprocessReport,
        world_out: &mut Vec<binpick_cloud::Point>,
    ) -> Result<Found> {
        let (p, deadline, threads) = (call.p, call.deadline, call.threads);
        let mut lap = Instant::now();
        let mut step = |t: &mut f64| {
            *t = ms(lap.elapsed());
            lap = Instant::now();
        };

        // Preprocessing: crop, strays, units check, voxel grid (4.3 #1), support removal (5.2).
        let tolerance = p.cluster_tolerance_mm();
        let n = model.cloud.len();
        let world = {
            let _span = tracing::info_span!("preprocessing").entered();
            preprocess(
                scene,
                &p.preprocess,
                tolerance,
                n,
                threads,
                deadline,
                preprocessed,
            )?
        };
        tracing::debug!(points = world.len(), "scene preprocessed");
        world_out.clone_from(&world);
        step(&mut timings.preprocess_ms);
        if world.len() < 3 {
            return Ok(Found::default());
        }
        let (lo, hi) = bounds(&world);
        let what = "the scene after preprocessing";
        check_sampling_leaf("final_leaf_mm", p.icp.final_leaf_mm, what, lo, hi)?;
        // Euclidean clusters (3.4.1.3) and the scene's final keypoints for ICP (step 3a).
        let clustering = tracing::info_span!("clustering").entered();
        deadline.check("clustering")?;
        let sizes = size_range(&p.clustering, n);
        let clusters = euclidean_clusters(&world, tolerance, sizes, threads)?;
        deadline.check("clustering")?;
        let final_world = FinalWorld::new(&world, &p.icp)?;
        drop(clustering);
        tracing::debug!(clusters = clusters.len(), "scene clustered");
        step(&mut timings.clustering_ms);

        // Per cluster, Algorithm 1/2: keypoints + FPFH, correspondences, RANSAC threshold
        // sweep + SVD + Euclidean score, best initial alignment, ICP final alignment +
        // percent of outliers, accept (steps 1-5).
        let engine = ClusterSearch {
            stages: p,
            model,
            world: &final_world,
            deadline,
        };
        let _span = tracing::info_span!("alignment").entered();
        engine.run(&world, &clusters)
    }

    /// The grasp corridors of every detection against `scene` (the points the engine worked
    /// on, scanner frame), then the detections with a free grasp first. `tolerance_mm`: the
    /// engine's, unless `grasp_surface_tolerance_mm` is set.
    fn check_grasps(
        &self,
        detections: &mut Vec<Detection>,
        scene: &[binpick_cloud::Point],
        p: &Params,
        tolerance_mm: f64,
    ) -> Result<()> {
        if self.part.grasps.is_empty() {
            return Ok(());
        }
        let _span = tracing::info_span!("grasp_check").entered();
        let g = GraspScene {
            grasps: &self.part.grasps,
            surface: &self.part.surface.points,
            scene,
            surface_tolerance_mm: p.ranking.grasp_surface_tolerance_mm.unwrap_or(tolerance_mm),
            blocking_points: p.ranking.grasp_blocking_points as usize,
            surface_area_mm2: self.part.size.view_area_mm2,
        };
        check_and_order(detections, &g)
    }

    /// Duplicate suppression (when on), the per-cluster counts that survive it, and the pick
    /// ranking; also returns how many duplicates were dropped.
    fn rank(
        &self,
        p: &Params,
        model: &PreparedModel,
        mut detections: Vec<Detection>,
        clusters: &mut [ClusterReport],
    ) -> (Vec<Detection>, usize) {
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
