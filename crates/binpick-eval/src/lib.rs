//! Evaluation of binpick against labelled datasets: scoring detections against ground truth
//! and the thesis's result table ([`score`]), running a recognizer over a dataset or over
//! recorded scans ([`dataset`]), BOP datasets and results CSV ([`bop`]), the thesis's published numbers ([`thesis`]) and time
//! statistics ([`stats`]). The `binpick` CLI uses it; the recognition library does not.

pub mod bop;
pub mod dataset;
pub mod score;
pub mod stats;
pub mod thesis;

pub use dataset::{
    EvalRun, ModelFile, PICKABLE_FRACTION, ReplayResult, SceneResult, dataset_models, evaluate_bop,
    evaluate_dataset, replay_scan,
};
pub use score::{
    BOP_MIN_VISIBLE, DEFAULT_MATCH_FRACTION, DetectionVerdict, SceneScore, ThesisPercents,
    ThesisTable, TruthInstance, Verdict, pose_error_mm, score_scene,
};
pub use stats::median_p95;
pub use thesis::thesis_reference;
