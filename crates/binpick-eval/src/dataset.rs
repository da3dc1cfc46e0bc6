//! Running recognition over a labelled dataset (`binpick eval`) or over unlabelled scans
//! (`binpick replay`).

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

use binpick_cloud::Units;
use binpick_cloud::dataset::{Dataset, GroundTruth, ModelInfo};

use binpick::error::{Result, input};
use binpick::{Params, RecognitionReport, Recognizer, load_cloud};

use crate::score::{DEFAULT_MATCH_FRACTION, SceneScore, ThesisTable, TruthInstance, score_scene};

fn rigid(
    m: &binpick_cloud::RowMajor4x4,
    what: &'static str,
    message: &str,
) -> Result<Isometry3<f64>> {
    binpick_cloud::pose_from_row_major(m).map_err(|_| input(what, message))
}

/// Points used for the pose-error metric (evenly strided from the model cloud).
const SCORING_POINTS: usize = 2000;

/// One evaluated scene.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SceneResult {
    /// Ground-truth id (file stem in `gt/`).
    pub id: String,
    pub scene: String,
    /// Recognition time (load excluded), ms.
    pub time_ms: f64,
    pub score: SceneScore,
    /// Set when this scene could not be processed; its score is then empty.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    #[serde(skip)]
    pub report: Option<RecognitionReport>,
}

/// A whole evaluation run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalRun {
    pub dataset: String,
    pub model: String,
    pub scenes: Vec<SceneResult>,
    pub table: ThesisTable,
    pub times_ms: Vec<f64>,
    pub failed: usize,
}

/// The model names that have ground truth in `dataset`, sorted.
pub fn dataset_models(dataset: &Dataset) -> Result<Vec<String>> {
    let mut names = Vec::new();
    for id in &dataset.scene_ids {
        let gt = GroundTruth::load(&dataset.gt_path(id))?;
        if !names.contains(&gt.model) {
            names.push(gt.model);
        }
    }
    names.sort();
    Ok(names)
}

/// Which of a dataset model's files recognises.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ModelFile {
    /// `models/<name>.pcd`: the scanned top view.
    #[default]
    Scan,
    /// `models/<name>.stl`: the CAD mesh.
    Mesh,
}

impl std::str::FromStr for ModelFile {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "scan" => Ok(ModelFile::Scan),
            "mesh" => Ok(ModelFile::Mesh),
            other => Err(format!(
                "unknown model file {other:?}: expected scan or mesh"
            )),
        }
    }
}

/// Evaluates `model` on every ground-truth file of `dataset` naming it, recognising with the
/// model's `file`. Poses are scored on the scanned model's points whichever file recognises.
/// `progress(done, total, last)` is called after each scene.
pub fn evaluate_dataset(
    dataset: &Dataset,
    model: &str,
    file: ModelFile,
    params: &Params,
    mut progress: impl FnMut(usize, usize, &SceneResult),
) -> Result<EvalRun> {
    let gts: Vec<(String, GroundTruth)> = dataset
        .scene_ids
        .iter()
        .map(|id| GroundTruth::load(&dataset.gt_path(id)).map(|gt| (id.clone(), gt)))
        .collect::<Result<Vec<_>, _>>()?
        .into_iter()
        .filter(|(_, gt)| gt.model == model)
        .collect();
    if gts.is_empty() {
        let names = dataset_models(dataset)?;
        return Err(input(
            "dataset",
            format!(
                "no ground truth names model {model:?}; models present: {}",
                names.join(", ")
            ),
        ));
    }
    let info = ModelInfo::load(&dataset.model_info_path(model))?;
    let (model_cloud, _) = load_cloud(&dataset.model_cloud_path(model), Units::Millimetres)?;
    let model_path = match file {
        ModelFile::Scan => dataset.model_cloud_path(model),
        ModelFile::Mesh => dataset.model_mesh_path(model),
    };
    let (part, _) = binpick::load_part(&model_path, Units::Millimetres, params)?;
    let recognizer = Recognizer::with_part(part, params.clone())?;
    let points: Vec<Point3<f64>> =
        binpick_cloud::strided_points(&model_cloud.points, SCORING_POINTS);
    let symmetries: Vec<Isometry3<f64>> = info
        .symmetries
        .iter()
        .map(|s| rigid(s, "model info", "a symmetry is not a rigid transform"))
        .collect::<Result<_>>()?;

    let mut run = EvalRun {
        dataset: dataset.root.display().to_string(),
        model: model.to_owned(),
        scenes: Vec::new(),
        table: ThesisTable::default(),
        times_ms: Vec::new(),
        failed: 0,
    };
    let total = gts.len();
    for (k, (id, gt)) in gts.into_iter().enumerate() {
        let scene_path = dataset.scene_path(&gt);
        let result = evaluate_scene(
            &recognizer,
            &scene_path,
            &gt,
            &points,
            &symmetries,
            info.diameter,
            params,
            model,
        );
        let scene_result = match result {
            Ok((report, score)) => SceneResult {
                id,
                scene: gt.scene.clone(),
                time_ms: report.timings_ms.total_ms,
                score,
                error: None,
                report: Some(report),
            },
            Err(e) => SceneResult {
                id,
                scene: gt.scene.clone(),
                time_ms: 0.0,
                score: SceneScore::default(),
                error: Some(e.to_string()),
                report: None,
            },
        };
        if scene_result.error.is_some() {
            run.failed += 1;
        } else {
            run.table.add(&scene_result.score);
            run.times_ms.push(scene_result.time_ms);
        }
        progress(k + 1, total, &scene_result);
        run.scenes.push(scene_result);
    }
    Ok(run)
}

#[allow(clippy::too_many_arguments)]
fn evaluate_scene(
    recognizer: &Recognizer,
    scene_path: &Path,
    gt: &GroundTruth,
    points: &[Point3<f64>],
    symmetries: &[Isometry3<f64>],
    diameter: f64,
    params: &Params,
    model: &str,
) -> Result<(RecognitionReport, SceneScore)> {
    let (scene, loaded) = load_cloud(scene_path, gt.units)?;
    let seen_from = binpick::sensor_position(&loaded, gt.units);
    let recognition = recognizer.recognize_seen_from(&scene, seen_from)?;
    let truth: Vec<TruthInstance> = gt
        .instances
        .iter()
        .map(|i| {
            Ok(TruthInstance {
                pose: rigid(&i.pose, "ground truth", "a pose is not a rigid transform")?,
                pickable: i.pickable,
            })
        })
        .collect::<Result<_>>()?;
    let detections: Vec<(usize, Isometry3<f64>)> = recognition
        .detections
        .iter()
        .map(|d| (d.rank, d.pose))
        .collect();
    let score = score_scene(
        points,
        symmetries,
        diameter,
        &truth,
        &detections,
        DEFAULT_MATCH_FRACTION,
    );
    let report = RecognitionReport::new(
        &scene_path.display().to_string(),
        model,
        params.stages().engine.name(),
        params,
        &recognition,
    );
    Ok((report, score))
}

/// One replayed scan (no ground truth).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ReplayResult {
    pub scan: PathBuf,
    pub detections: usize,
    pub time_ms: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    #[serde(skip)]
    pub report: Option<RecognitionReport>,
}

/// Recognises `model` in one scan file (for `replay`).
pub fn replay_scan(
    recognizer: &Recognizer,
    scan: &Path,
    model_name: &str,
    units: Units,
) -> ReplayResult {
    let run = || -> Result<RecognitionReport> {
        let (scene, loaded) = load_cloud(scan, units)?;
        let seen_from = binpick::sensor_position(&loaded, units);
        let r = recognizer.recognize_seen_from(&scene, seen_from)?;
        Ok(RecognitionReport::new(
            &scan.display().to_string(),
            model_name,
            recognizer.params().stages().engine.name(),
            recognizer.params(),
            &r,
        ))
    };
    match run() {
        Ok(report) => ReplayResult {
            scan: scan.to_owned(),
            detections: report.detections.len(),
            time_ms: report.timings_ms.total_ms,
            error: None,
            report: Some(report),
        },
        Err(e) => ReplayResult {
            scan: scan.to_owned(),
            detections: 0,
            time_ms: 0.0,
            error: Some(e.to_string()),
            report: None,
        },
    }
}
