//! `binpick bench`: median time per stage and per scene, over repeated runs in one process.

use std::path::PathBuf;

use anyhow::{Context, Result};
use binpick::eval::median_p95;
use binpick::{Recognizer, Timings};
use serde::Serialize;

use crate::config::{ParamArgs, load, log, write_json};

#[derive(clap::Args)]
pub struct Args {
    /// Model cloud.
    #[arg(long)]
    pub model: PathBuf,
    /// Scene clouds to time.
    #[arg(long, required = true, num_args = 1..)]
    pub scene: Vec<PathBuf>,
    #[command(flatten)]
    pub params: ParamArgs,
    /// Timed repetitions per scene (after one warm-up run).
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Write the measurements as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

#[derive(Serialize, Clone, Debug)]
pub struct StageMedians {
    pub preprocess_ms: f64,
    pub clustering_ms: f64,
    /// Summed over worker threads (CPU-time-like).
    pub initial_alignment_ms: f64,
    /// Summed over worker threads.
    pub final_alignment_ms: f64,
    pub ranking_ms: f64,
    pub total_ms: f64,
    pub total_p95_ms: f64,
}

#[derive(Serialize)]
pub struct SceneBench {
    pub scene: String,
    pub points: usize,
    pub detections: usize,
    pub runs: usize,
    pub median: StageMedians,
}

pub fn medians(runs: &[Timings]) -> StageMedians {
    let m = |f: fn(&Timings) -> f64| median_p95(&runs.iter().map(f).collect::<Vec<_>>()).0;
    StageMedians {
        preprocess_ms: m(|t| t.preprocess_ms),
        clustering_ms: m(|t| t.clustering_ms),
        initial_alignment_ms: m(|t| t.initial_alignment_ms),
        final_alignment_ms: m(|t| t.final_alignment_ms),
        ranking_ms: m(|t| t.ranking_ms),
        total_ms: m(|t| t.total_ms),
        total_p95_ms: median_p95(&runs.iter().map(|t| t.total_ms).collect::<Vec<_>>()).1,
    }
}

pub fn run(a: Args) -> Result<()> {
    let params = a.params.params()?;
    let model = load(&a.model, a.params.model_units(&params), "model")?;
    let recognizer = Recognizer::new(&model, params.clone()).context("cannot prepare the model")?;
    let prep_ms = recognizer.preparation().as_secs_f64() * 1000.0;
    println!(
        "model preparation (once per model): {prep_ms:.0} ms; {} thread(s); preset {}, algorithm {}",
        recognizer.threads(),
        a.params.preset.name(),
        params.algorithm.number()
    );
    println!(
        "{:<40} {:>8} {:>5} {:>10} {:>10} {:>10} {:>10} {:>8} {:>10} {:>10}",
        "scene",
        "points",
        "found",
        "preproc",
        "cluster",
        "initial*",
        "final*",
        "rank",
        "total",
        "total p95"
    );
    let mut out = Vec::new();
    for scene_path in &a.scene {
        let scene = load(scene_path, params.units, "scene")?;
        let warm = recognizer.recognize(&scene)?;
        let mut runs = Vec::new();
        for _ in 0..a.repeat.max(1) {
            runs.push(recognizer.recognize(&scene)?.timings);
        }
        let m = medians(&runs);
        println!(
            "{:<40} {:>8} {:>5} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>8.2} {:>10.1} {:>10.1}",
            scene_path.display().to_string(),
            scene.len(),
            warm.detections.len(),
            m.preprocess_ms,
            m.clustering_ms,
            m.initial_alignment_ms,
            m.final_alignment_ms,
            m.ranking_ms,
            m.total_ms,
            m.total_p95_ms
        );
        out.push(SceneBench {
            scene: scene_path.display().to_string(),
            points: scene.len(),
            detections: warm.detections.len(),
            runs: runs.len(),
            median: m,
        });
    }
    println!(
        "(ms, medians of {} runs; * = summed over worker threads, wall time is 'total')",
        a.repeat.max(1)
    );
    if let Some(path) = &a.json {
        write_json(path, &out)?;
        log(&format!("wrote {}", path.display()));
    }
    Ok(())
}
