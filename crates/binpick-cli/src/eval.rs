//! `binpick eval`: replay a labelled dataset and print the thesis's result table.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use binpick_cloud::dataset::Dataset;
use binpick_eval::{EvalRun, dataset_models, evaluate_dataset};
use binpick_eval::{ThesisTable, median_p95, thesis_reference};
use serde::Serialize;

use crate::config::{ParamArgs, log, write_json, write_params};
use crate::progress::Progress;

#[derive(clap::Args)]
pub struct Args {
    /// Dataset folder (models/, scenes/, gt/; see README "Dataset format").
    pub dataset: PathBuf,
    /// Model to evaluate (a name in models/); needed when the dataset labels several.
    #[arg(long)]
    pub model: Option<String>,
    /// Which of the model's files recognises: scan (models/<name>.pcd, the scanned top view)
    /// or mesh (models/<name>.stl, the CAD mesh).
    #[arg(long, default_value = "scan")]
    pub model_file: binpick_eval::ModelFile,
    #[command(flatten)]
    pub params: ParamArgs,
    /// Output folder for per-scene JSON, summary.json, summary.csv and params.toml
    /// (default: eval-<model>-<preset>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Also write charts (thesis table bars, time histogram) as PNG into this folder.
    #[arg(long)]
    pub plots: Option<PathBuf>,
}

#[derive(Serialize)]
struct Summary<'a> {
    dataset: &'a str,
    model: &'a str,
    preset: &'a str,
    units: &'static str,
    table: &'a ThesisTable,
    percents: binpick_eval::ThesisPercents,
    thesis: Option<binpick_eval::ThesisPercents>,
    time_ms_median: f64,
    time_ms_p95: f64,
    failed_scenes: usize,
    params: &'a binpick::Params,
    scenes: &'a [binpick_eval::SceneResult],
}

pub fn run(a: Args) -> Result<()> {
    let params = a.params.params()?;
    let dataset = Dataset::open(&a.dataset).context("cannot open the dataset")?;
    let models = dataset_models(&dataset)?;
    let model = match (&a.model, models.as_slice()) {
        (Some(m), _) => m.clone(),
        (None, [only]) => only.clone(),
        (None, many) => bail!(
            "the dataset labels several models ({}); choose one with --model",
            many.join(", ")
        ),
    };
    let preset = a.params.preset.map_or("auto", |p| p.name());
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("eval-{model}-{preset}")));
    std::fs::create_dir_all(out.join("scenes"))
        .with_context(|| format!("cannot create {}", out.display()))?;
    log(&format!(
        "evaluating model {model} on {} with preset {preset} (algorithm {})",
        a.dataset.display(),
        params.algorithm.number()
    ));

    let mut progress: Option<Progress> = None;
    let run = evaluate_dataset(
        &dataset,
        &model,
        a.model_file,
        &params,
        |done, total, last| {
            let p = progress.get_or_insert_with(|| Progress::new(total, "eval"));
            let what = match &last.error {
                Some(e) => format!("{}: ERROR {e}", last.id),
                None => format!(
                    "{}: {} found, {:.0} ms",
                    last.id,
                    last.score.detections.len(),
                    last.time_ms
                ),
            };
            p.step(done, &what);
            if let Some(report) = &last.report {
                // Written as we go, so a long run leaves partial results.
                let _ = write_json(
                    &out.join("scenes").join(format!("{}.json", last.id)),
                    report,
                );
            }
        },
    )?;
    if let Some(p) = &progress {
        p.finish();
    }
    print_table(&run, preset);
    let (median, p95) = median_p95(&run.times_ms);
    let summary = Summary {
        dataset: &run.dataset,
        model: &run.model,
        preset,
        units: "mm",
        table: &run.table,
        percents: run.table.percents(),
        thesis: thesis_reference(preset),
        time_ms_median: median,
        time_ms_p95: p95,
        failed_scenes: run.failed,
        params: &params,
        scenes: &run.scenes,
    };
    write_json(&out.join("summary.json"), &summary)?;
    write_csv(&out.join("summary.csv"), &run)?;
    write_params(&out.join("params.toml"), &params)?;
    if let Some(dir) = &a.plots {
        crate::plots::eval_plots(dir, preset, &run)?;
    }
    log(&format!(
        "wrote {}/summary.json, summary.csv, params.toml and scenes/*.json",
        out.display()
    ));
    if run.failed > 0 {
        bail!(
            "{} of {} scenes failed (see summary.csv)",
            run.failed,
            run.scenes.len()
        );
    }
    Ok(())
}

fn write_csv(path: &Path, run: &EvalRun) -> Result<()> {
    let mut s = String::from(
        "id,scene,instances,pickable,recognised_pickable,recognised_unpickable,false_positives,false_best,starvation,time_ms,error\n",
    );
    for r in &run.scenes {
        let e = r.error.as_deref().unwrap_or("").replace(['"', '\n'], " ");
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{:.1},\"{e}\"\n",
            r.id,
            r.scene,
            r.score.instances,
            r.score.pickable,
            r.score.recognised_pickable,
            r.score.recognised_unpickable,
            r.score.false_positives,
            u8::from(r.score.false_best),
            u8::from(r.score.starvation),
            r.time_ms
        ));
    }
    std::fs::write(path, s).with_context(|| format!("cannot write {}", path.display()))
}

/// Prints the thesis's table (5.5.2) in absolute and percent form, with the thesis's own
/// percentages beside ours when the preset is one of its configurations.
pub fn print_table(run: &EvalRun, preset: &str) {
    let t = &run.table;
    let p = t.percents();
    let th = thesis_reference(preset);
    let thv = |f: fn(&binpick_eval::ThesisPercents) -> f64| match th {
        Some(x) if !f(&x).is_nan() => format!("{:>6.0} %", f(&x)),
        _ => "       -".into(),
    };
    println!(
        "model {} on {} ({} files), preset {preset}",
        run.model, run.dataset, t.files
    );
    println!(
        "{:<44} {:>6} {:>9} {:>9}",
        "property", "symbol", "ours", "thesis"
    );
    println!("{:<44} {:>6} {:>9}", "files processed", "F", t.files);
    println!(
        "{:<44} {:>6} {:>9}",
        "pickable objects in the clouds", "P", t.pickable
    );
    println!(
        "{:<44} {:>6} {:>9}",
        "pickable objects recognised", "R", t.recognised
    );
    println!(
        "{:<44} {:>6} {:>9}",
        "false negatives", "FN", t.false_negatives
    );
    println!(
        "{:<44} {:>6} {:>9}",
        "files with a false positive", "FP", t.files_with_false_positive
    );
    println!(
        "{:<44} {:>6} {:>9}",
        "files with an aligned unpickable object", "NP", t.files_with_unpickable
    );
    println!(
        "{:<44} {:>6} {:>9}",
        "bad cycles by false best", "FB", t.false_best
    );
    println!(
        "{:<44} {:>6} {:>9}",
        "bad cycles by starvation", "S", t.starvation
    );
    println!(
        "{:<44} {:>6} {:>7.1} % {}",
        "recognition rate",
        "R/P",
        p.recognition,
        thv(|x| x.recognition)
    );
    println!(
        "{:<44} {:>6} {:>7.1} % {}",
        "false negatives",
        "FN/P",
        p.false_negatives,
        thv(|x| x.false_negatives)
    );
    println!(
        "{:<44} {:>6} {:>7.1} % {}",
        "clouds with false positives",
        "FP/F",
        p.files_with_false_positive,
        thv(|x| x.files_with_false_positive)
    );
    println!(
        "{:<44} {:>6} {:>7.1} % {}",
        "clouds with unpickable objects",
        "NP/F",
        p.files_with_unpickable,
        thv(|x| x.files_with_unpickable)
    );
    println!(
        "{:<44} {:>6} {:>7.1} % {}",
        "bad cycles by false best",
        "FB/F",
        p.false_best,
        thv(|x| x.false_best)
    );
    println!(
        "{:<44} {:>6} {:>7.1} % {}",
        "bad cycles by starvation",
        "S/F",
        p.starvation,
        thv(|x| x.starvation)
    );
    println!(
        "{:<44} {:>6} {:>7.1} %",
        "precision (correct / all detections)", "", p.precision
    );
    let (median, p95) = median_p95(&run.times_ms);
    println!(
        "{:<44} {:>6} {:>7.0} ms (p95 {:.0} ms)",
        "time per scene, median", "", median, p95
    );
    if run.failed > 0 {
        println!("{} scene(s) failed and are not counted", run.failed);
    }
}
