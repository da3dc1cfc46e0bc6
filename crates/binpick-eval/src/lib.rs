//! Evaluation of binpick against labelled datasets: scoring detections against ground truth
//! and the thesis's result table ([`score`]), running a recognizer over a dataset or over
//! recorded scans ([`dataset`]), the thesis's published numbers ([`thesis`]) and time
//! statistics ([`stats`]). The `binpick` CLI uses it; the recognition library does not.

pub mod dataset;
pub mod score;
pub mod stats;
pub mod thesis;

pub use dataset::{
    EvalRun, ModelFile, ReplayResult, SceneResult, dataset_models, evaluate_dataset, replay_scan,
};
pub use score::{
    DEFAULT_MATCH_FRACTION, DetectionVerdict, SceneScore, ThesisPercents, ThesisTable,
    TruthInstance, Verdict, pose_error_mm, score_scene,
};
pub use stats::median_p95;
pub use thesis::thesis_reference;
