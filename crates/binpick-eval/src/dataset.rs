//! Running recognition over a labelled dataset (`binpick eval`) or over unlabelled scans
//! (`binpick replay`).

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

use binpick_cloud::Units;
use binpick_cloud::dataset::{Dataset, GroundTruth, GtInstance, ModelInfo};

use binpick::error::{Result, input};
use binpick::{Params, PointCloud, RecognitionReport, Recognizer, load_cloud};

use crate::bop::{BopDataset, BopIds};
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
    /// The scene's BOP ids (BOP datasets: their own; binpick datasets: scene 0, image =
    /// position in the run, object 1), for `--bop-csv`.
    #[serde(default)]
    pub bop: BopIds,
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

/// How detections are scored for one model: its points (a sample), symmetries and diameter.
struct Scoring {
    points: Vec<Point3<f64>>,
    symmetries: Vec<Isometry3<f64>>,
    diameter_mm: f64,
}

/// One labelled scene to evaluate: where it is, its BOP ids, and how to load it.
struct LabelledScene<'a> {
    id: String,
    scene: String,
    bop: BopIds,
    load: Box<dyn FnOnce() -> Result<LoadedScene> + 'a>,
}

/// The scan (mm), where its sensor was, and the ground truth of the evaluated model.
type LoadedScene = (PointCloud, Option<[f64; 3]>, Vec<TruthInstance>);

/// Evaluates `model` on every ground-truth file of `dataset` naming it, recognising with the
/// model's `file`. Poses are scored on the scanned model's points whichever file recognises.
/// With the mesh, an instance is pickable by BOP's visible fraction where the ground truth
/// counts it ([`GtInstance::bop_visible_fraction`]; the same as its
/// `visible_fraction` on the generalisation benchmark, not on the thesis's datasets, whose
/// fraction is the top-view model's).
/// `progress(done, total, last)` is called after each scene.
pub fn evaluate_dataset(
    dataset: &Dataset,
    model: &str,
    file: ModelFile,
    params: &Params,
    progress: impl FnMut(usize, usize, &SceneResult),
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
    let scoring = Scoring {
        points: binpick_cloud::strided_points(&model_cloud.points, SCORING_POINTS),
        symmetries: info
            .symmetries
            .iter()
            .map(|s| rigid(s, "model info", "a symmetry is not a rigid transform"))
            .collect::<Result<_>>()?,
        diameter_mm: info.diameter,
    };
    let scenes: Vec<LabelledScene<'_>> = gts
        .into_iter()
        .enumerate()
        .map(|(k, (id, gt))| {
            let scene_path = dataset.scene_path(&gt);
            LabelledScene {
                id,
                scene: gt.scene.clone(),
                bop: BopIds {
                    scene_id: 0,
                    im_id: k as u32,
                    obj_id: 1,
                },
                load: Box::new(move || {
                    let (scene, loaded) = load_cloud(&scene_path, gt.units)?;
                    let seen_from = binpick::sensor_position(&loaded, gt.units);
                    let truth = gt
                        .instances
                        .iter()
                        .map(|i| {
                            let (pickable, visible_fraction) = judged_visibility(i, file);
                            Ok(TruthInstance {
                                pose: rigid(
                                    &i.pose,
                                    "ground truth",
                                    "a pose is not a rigid transform",
                                )?,
                                pickable,
                                visible_fraction,
                            })
                        })
                        .collect::<Result<_>>()?;
                    Ok((scene, seen_from, truth))
                }),
            }
        })
        .collect();
    Ok(evaluate_scenes(
        &recognizer,
        &scoring,
        &dataset.root.display().to_string(),
        model,
        scenes,
        progress,
    ))
}

/// Evaluates object `obj_id` on every image of a BOP split that labels it. The model is the
/// object's mesh (`models/obj_<id>.ply`) with the symmetries of `models_info.json`; scans are
/// the depth images as clouds in the camera frame (camera at the origin). An instance is
/// pickable when its visib_fract is at least 0.5 (as for binpick's own datasets). `params`'s
/// `up` is used as given: in a camera frame looking down at a bin, "up" is `[0, 0, -1]`.
pub fn evaluate_bop(
    dataset: &BopDataset,
    obj_id: u32,
    params: &Params,
    progress: impl FnMut(usize, usize, &SceneResult),
) -> Result<EvalRun> {
    let info = dataset.models.get(&obj_id).ok_or_else(|| {
        input(
            "BOP dataset",
            format!("object {obj_id} is not in models/models_info.json"),
        )
    })?;
    let symmetries = info.symmetries(obj_id)?;
    let model_path = dataset.model_path(obj_id);
    let (part, _) = binpick::load_part(&model_path, Units::Millimetres, params)?;
    let scoring = Scoring {
        points: binpick_cloud::strided_points(&part.cloud.points, SCORING_POINTS),
        symmetries: symmetries.transforms().to_vec(),
        diameter_mm: info.diameter,
    };
    let recognizer = Recognizer::with_part(part.with_symmetries(symmetries), params.clone())?;
    let scenes: Vec<LabelledScene<'_>> = dataset
        .images
        .iter()
        .filter(|im| im.instances.iter().any(|i| i.obj_id == obj_id))
        .map(|im| LabelledScene {
            id: format!("{:06}-{:06}", im.scene_id, im.im_id),
            scene: im
                .depth
                .strip_prefix(&dataset.root)
                .unwrap_or(&im.depth)
                .display()
                .to_string(),
            bop: BopIds {
                scene_id: im.scene_id,
                im_id: im.im_id,
                obj_id,
            },
            load: Box::new(move || {
                let cloud = im.load_cloud()?;
                let truth = im
                    .instances
                    .iter()
                    .filter(|i| i.obj_id == obj_id)
                    .map(|i| TruthInstance {
                        pose: i.pose,
                        pickable: i.visible_fraction >= PICKABLE_FRACTION,
                        visible_fraction: i.visible_fraction,
                    })
                    .collect();
                Ok((cloud, Some([0.0; 3]), truth))
            }),
        })
        .collect();
    if scenes.is_empty() {
        return Err(input(
            "BOP dataset",
            format!(
                "no image of split {} labels object {obj_id}; labelled objects: {:?}",
                dataset.split,
                dataset.labelled_objects()
            ),
        ));
    }
    Ok(evaluate_scenes(
        &recognizer,
        &scoring,
        &dataset.root.display().to_string(),
        &format!("obj_{obj_id:06}"),
        scenes,
        progress,
    ))
}

/// A visible fraction of at least this makes an instance pickable (binpick's datasets).
pub const PICKABLE_FRACTION: f64 = 0.5;

/// Whether an instance counts as pickable when recognising with `file`, and its visible
/// fraction. A mesh has every side, so it is judged by BOP's fraction where the ground truth
/// counted it (module docs of `binpick_cloud::dataset`); a scanned top view by the ground
/// truth's own (the thesis's, on its datasets: a part lying upside down is not pickable
/// with a top-view model).
fn judged_visibility(instance: &GtInstance, file: ModelFile) -> (bool, f64) {
    match instance
        .bop_visible_fraction()
        .filter(|_| file == ModelFile::Mesh)
    {
        Some(v) => (v >= PICKABLE_FRACTION, v),
        None => (instance.pickable, instance.visible_fraction),
    }
}

/// Recognises and scores every scene in order; a scene that fails is recorded, not fatal.
fn evaluate_scenes(
    recognizer: &Recognizer,
    scoring: &Scoring,
    dataset: &str,
    model: &str,
    scenes: Vec<LabelledScene<'_>>,
    mut progress: impl FnMut(usize, usize, &SceneResult),
) -> EvalRun {
    let mut run = EvalRun {
        dataset: dataset.to_owned(),
        model: model.to_owned(),
        scenes: Vec::new(),
        table: ThesisTable::default(),
        times_ms: Vec::new(),
        failed: 0,
    };
    let total = scenes.len();
    for (k, s) in scenes.into_iter().enumerate() {
        let span = tracing::info_span!("scene", id = %s.id);
        let _entered = span.enter();
        let result = (s.load)().and_then(|(cloud, seen_from, truth)| {
            evaluate_scene(
                recognizer, scoring, &cloud, seen_from, &truth, &s.scene, model,
            )
        });
        let scene_result = match result {
            Ok((report, score)) => SceneResult {
                id: s.id,
                scene: s.scene,
                bop: s.bop,
                time_ms: report.timings_ms.total_ms,
                score,
                error: None,
                report: Some(report),
            },
            Err(e) => {
                tracing::warn!("{e}");
                SceneResult {
                    id: s.id,
                    scene: s.scene,
                    bop: s.bop,
                    time_ms: 0.0,
                    score: SceneScore::default(),
                    error: Some(e.to_string()),
                    report: None,
                }
            }
        };
        if scene_result.error.is_some() {
            run.failed += 1;
        } else {
            tracing::debug!(
                detections = scene_result.score.detections.len(),
                recognised_pickable = scene_result.score.recognised_pickable,
                time_ms = scene_result.time_ms,
                "scored"
            );
            run.table.add(&scene_result.score);
            run.times_ms.push(scene_result.time_ms);
        }
        progress(k + 1, total, &scene_result);
        run.scenes.push(scene_result);
    }
    run
}

fn evaluate_scene(
    recognizer: &Recognizer,
    scoring: &Scoring,
    scene: &PointCloud,
    seen_from: Option<[f64; 3]>,
    truth: &[TruthInstance],
    scene_name: &str,
    model: &str,
) -> Result<(RecognitionReport, SceneScore)> {
    let recognition = recognizer.recognize_seen_from(scene, seen_from)?;
    let detections: Vec<(usize, Isometry3<f64>)> = recognition
        .detections
        .iter()
        .map(|d| (d.rank, d.pose))
        .collect();
    let score = score_scene(
        &scoring.points,
        &scoring.symmetries,
        scoring.diameter_mm,
        truth,
        &detections,
        recognition.first_pick().map(|d| d.rank),
        DEFAULT_MATCH_FRACTION,
    );
    let params = recognizer.params();
    let report = RecognitionReport::new(
        scene_name,
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

#[cfg(test)]
mod tests {
    use super::*;

    fn instance(visible_fraction: f64, counts: Option<(u64, u64)>) -> GtInstance {
        GtInstance {
            pose: binpick_cloud::dataset::IDENTITY,
            visible_fraction,
            pickable: visible_fraction >= PICKABLE_FRACTION,
            visible_points: counts.map(|c| c.0),
            alone_points: counts.map(|c| c.1),
        }
    }

    #[test]
    fn a_mesh_judges_pickability_by_the_bop_counts_and_a_scan_by_the_ground_truth() {
        // A part lying upside down on a thesis dataset: the top view sees 3 % of it, the
        // scan shows 90 % of what the scanner would see of it alone.
        let upside_down = instance(0.03, Some((90, 100)));
        assert_eq!(
            judged_visibility(&upside_down, ModelFile::Scan),
            (false, 0.03)
        );
        assert_eq!(
            judged_visibility(&upside_down, ModelFile::Mesh),
            (true, 0.9)
        );
        // Hidden under others either way.
        let buried = instance(0.6, Some((20, 100)));
        assert_eq!(judged_visibility(&buried, ModelFile::Scan), (true, 0.6));
        assert_eq!(judged_visibility(&buried, ModelFile::Mesh), (false, 0.2));
        // Without counts the ground truth's own judgement stands.
        let uncounted = instance(0.03, None);
        assert_eq!(
            judged_visibility(&uncounted, ModelFile::Mesh),
            (false, 0.03)
        );
        // Counts as the generators round them; nothing seen alone is nothing visible.
        assert_eq!(GtInstance::visib_fract(2, 3), 0.6667);
        assert_eq!(GtInstance::visib_fract(120, 100), 1.0);
        assert_eq!(GtInstance::visib_fract(0, 0), 0.0);
    }
}
