//! `binpick eval`: replay a labelled dataset and print the thesis's result table.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use binpick_cloud::dataset::Dataset;
use binpick_eval::{EvalRun, dataset_models, evaluate_dataset};
use binpick_eval::{SceneScore, ThesisTable, median_p95, thesis_reference};
use serde::Serialize;

use crate::config::{ParamArgs, write_json, write_params};
use crate::progress::Progress;

#[derive(clap::Args)]
pub struct Args {
    /// Dataset folder: binpick's layout (models/, scenes/, gt/), a BOP dataset
    /// (models/models_info.json, <split>/<scene>/depth, scene_camera.json, scene_gt.json), or
    /// a benchmark root written by `binpick synth generalisation` (manifest.json listing sets:
    /// every set is evaluated with its target part and one table is printed); see README
    /// "Formats".
    pub dataset: PathBuf,
    /// Model to evaluate: a name in models/ (binpick layout) or an object id (BOP: 1 or
    /// obj_000001); needed when the dataset labels several.
    #[arg(long)]
    pub model: Option<String>,
    /// BOP datasets: the split folder to evaluate.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Which of the model's files recognises: scan (models/<name>.pcd, the scanned top view)
    /// or mesh (models/<name>.stl, the CAD mesh).
    #[arg(long, default_value = "scan")]
    pub model_file: binpick_eval::ModelFile,
    #[command(flatten)]
    pub params: ParamArgs,
    /// Output folder for per-scene JSON, summary.json, summary.csv and params.toml
    /// (default: eval-out/<model>-<preset>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Also write every detection in BOP's results CSV (scene_id,im_id,obj_id,score,R,t,time;
    /// BOP datasets keep their ids, binpick datasets get scene 0, image = position in the run,
    /// object 1).
    #[arg(long, value_name = "FILE.csv")]
    pub bop_csv: Option<PathBuf>,
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
    if let Some(sets) = suite_sets(&a.dataset)? {
        return run_suite(&a, &sets);
    }
    let mut params = a.params.params()?;
    let preset = a.params.preset.map_or("auto", |p| p.name());
    let bop = binpick_eval::bop::is_bop_dataset(&a.dataset);
    if bop && params.ranking.up == [0.0, 0.0, 1.0] {
        // BOP scans are in the camera's frame: "up" (out of the bin) points at the camera.
        params.ranking.up = [0.0, 0.0, -1.0];
        tracing::info!("BOP dataset: up = [0, 0, -1] (towards the camera) for the pick order");
    }
    // Scenes are written as they are evaluated, so a long run leaves partial results.
    let out_dir: PathBuf;
    let mut progress: Option<Progress> = None;
    let mut on_scene = |out: &Path, done: usize, total: usize, last: &binpick_eval::SceneResult| {
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
        write_scene(out, last);
    };
    let run = if bop {
        let dataset = binpick_eval::bop::BopDataset::open(&a.dataset, &a.split)
            .context("cannot open the BOP dataset")?;
        let labelled = dataset.labelled_objects();
        let obj_id = match (&a.model, labelled.as_slice()) {
            (Some(m), _) => parse_obj_id(m)?,
            (None, [only]) => *only,
            (None, many) => {
                bail!("the BOP split labels several objects ({many:?}); choose one with --model")
            }
        };
        let out = out_folder(&a, &format!("obj_{obj_id:06}"), preset)?;
        tracing::info!(
            "evaluating object {obj_id} on {} split {} ({} images) with preset {preset}; scans are depth images in the camera frame",
            a.dataset.display(),
            a.split,
            dataset.images.len()
        );
        out_dir = out.clone();
        binpick_eval::evaluate_bop(&dataset, obj_id, &params, |d, t, l| on_scene(&out, d, t, l))?
    } else {
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
        let out = out_folder(&a, &model, preset)?;
        tracing::info!(
            "evaluating model {model} on {} with preset {preset} (algorithm {})",
            a.dataset.display(),
            params.algorithm.number()
        );
        out_dir = out.clone();
        evaluate_dataset(&dataset, &model, a.model_file, &params, |d, t, l| {
            on_scene(&out, d, t, l)
        })?
    };
    if let Some(p) = &progress {
        p.finish();
    }
    let out = out_dir;
    print_table(&run, preset);
    write_summaries(&out, &run, preset, &params)?;
    if let Some(csv) = &a.bop_csv {
        let mut text = String::from(binpick_eval::bop::CSV_HEADER);
        for s in &run.scenes {
            if let Some(r) = &s.report {
                text.push_str(&binpick_eval::bop::csv_rows(
                    s.bop,
                    &r.detections,
                    s.time_ms / 1000.0,
                ));
            }
        }
        crate::config::write_text(csv, &text)?;
        tracing::info!("wrote {} (BOP results)", csv.display());
    }
    if let Some(dir) = &a.plots {
        crate::plots::eval_plots(dir, preset, &run)?;
    }
    tracing::info!(
        "wrote {}/summary.json, summary.csv, params.toml and scenes/*.json",
        out.display()
    );
    if run.failed > 0 {
        bail!(
            "{} of {} scenes failed (see summary.csv)",
            run.failed,
            run.scenes.len()
        );
    }
    Ok(())
}

/// summary.json, summary.csv and params.toml of one evaluated dataset.
fn write_summaries(
    out: &Path,
    run: &EvalRun,
    preset: &str,
    params: &binpick::Params,
) -> Result<()> {
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
        params,
        scenes: &run.scenes,
    };
    write_json(&out.join("summary.json"), &summary)?;
    write_csv(&out.join("summary.csv"), run)?;
    write_params(&out.join("params.toml"), params)
}

/// Writes one scene's result JSON under `out/scenes/` (a failure to write is a warning: the
/// evaluation goes on).
fn write_scene(out: &Path, last: &binpick_eval::SceneResult) {
    if let Some(report) = &last.report
        && let Err(e) = write_json(
            &out.join("scenes").join(format!("{}.json", last.id)),
            report,
        )
    {
        tracing::warn!("{e:#}");
    }
}

/// One set of a benchmark root: its folder and the part it is judged on.
#[derive(serde::Deserialize)]
struct SuiteSet {
    dir: String,
    target_model: String,
}

/// The sets of a benchmark root (a folder whose manifest.json lists `sets`), or None for any
/// other folder.
fn suite_sets(root: &Path) -> Result<Option<Vec<SuiteSet>>> {
    #[derive(serde::Deserialize)]
    struct Manifest {
        sets: Option<Vec<SuiteSet>>,
    }
    let path = root.join("manifest.json");
    if root.join("scenes").is_dir() || !path.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let m: Manifest = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a benchmark manifest", path.display()))?;
    match m.sets {
        Some(sets) if sets.is_empty() => bail!("{}: `sets` is empty", path.display()),
        other => Ok(other),
    }
}

/// One row of the benchmark table.
#[derive(Serialize)]
struct SuiteRow {
    set: String,
    model: String,
    scans: usize,
    pickable: usize,
    /// Pickable parts recognised, %.
    recall_pct: f64,
    /// Scans whose first pick is wrong while pickable parts were present, %.
    false_best_pct: f64,
    /// Scans whose first pick is not a correct pose of a pickable part, pickable parts
    /// present or not, %.
    wrong_first_pick_pct: f64,
    /// Wrong detections per scan.
    false_positives_per_scan: f64,
    /// Scans with pickable parts and no pick (nothing detected, or nothing free to pick), %.
    starvation_pct: f64,
    /// Scans with detections but none free to pick (no pick), pickable parts present or
    /// not, %.
    none_free_to_pick_pct: f64,
    time_ms_median: f64,
    time_ms_p95: f64,
    failed_scenes: usize,
}

impl SuiteRow {
    fn new(set: &SuiteSet, run: &EvalRun) -> Self {
        let p = run.table.percents();
        let (median, p95) = median_p95(&run.times_ms);
        let fp: usize = run.scenes.iter().map(|s| s.score.false_positives).sum();
        let share = |f: fn(&SceneScore) -> bool| {
            let n = run.scenes.iter().filter(|s| f(&s.score)).count();
            100.0 * n as f64 / run.table.files.max(1) as f64
        };
        Self {
            set: set.dir.clone(),
            model: run.model.clone(),
            scans: run.table.files,
            pickable: run.table.pickable,
            recall_pct: p.recognition,
            false_best_pct: p.false_best,
            wrong_first_pick_pct: share(|s| s.wrong_first_pick),
            false_positives_per_scan: fp as f64 / run.table.files.max(1) as f64,
            starvation_pct: p.starvation,
            none_free_to_pick_pct: share(|s| s.none_free_to_pick),
            time_ms_median: median,
            time_ms_p95: p95,
            failed_scenes: run.failed,
        }
    }
}

/// Every set of a benchmark root with its target part: per-set outputs under
/// `--out/<set>/`, one table on stdout, `suite.csv` and `suite.json` beside them.
fn run_suite(a: &Args, sets: &[SuiteSet]) -> Result<()> {
    for (flag, given) in [
        ("--model", a.model.is_some()),
        ("--bop-csv", a.bop_csv.is_some()),
        ("--plots", a.plots.is_some()),
    ] {
        if given {
            bail!(
                "{flag} does not apply to a benchmark root ({}): each set names its own part",
                a.dataset.display()
            );
        }
    }
    let params = a.params.params()?;
    let preset = a.params.preset.map_or("auto", |p| p.name());
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| Path::new("eval-out").join(format!("suite-{preset}")));
    let mut rows = Vec::new();
    for (k, set) in sets.iter().enumerate() {
        let dir = a.dataset.join(&set.dir);
        let dataset =
            Dataset::open(&dir).with_context(|| format!("cannot open set {}", dir.display()))?;
        let set_out = out.join(&set.dir);
        std::fs::create_dir_all(set_out.join("scenes"))
            .with_context(|| format!("cannot create {}", set_out.display()))?;
        let progress = Progress::new(
            dataset.scene_ids.len(),
            &format!("{}/{}", k + 1, sets.len()),
        );
        let run = evaluate_dataset(
            &dataset,
            &set.target_model,
            a.model_file,
            &params,
            |d, _, l| {
                progress.step(d, &format!("{}: {}", set.dir, l.id));
                write_scene(&set_out, l);
            },
        )?;
        progress.finish();
        write_summaries(&set_out, &run, preset, &params)?;
        let row = SuiteRow::new(set, &run);
        tracing::info!(
            "{}: recall {:.1} %, false best {:.0} %, {:.2} false detections per scan",
            row.set,
            row.recall_pct,
            row.false_best_pct,
            row.false_positives_per_scan
        );
        rows.push(row);
    }
    print_suite(&rows, preset, a.model_file);
    let mut csv = String::from(
        "set,model,scans,pickable,recall_pct,false_best_pct,false_positives_per_scan,starvation_pct,time_ms_median,time_ms_p95,failed_scenes,wrong_first_pick_pct,none_free_to_pick_pct\n",
    );
    for r in &rows {
        csv.push_str(&format!(
            "{},{},{},{},{:.1},{:.1},{:.2},{:.1},{:.0},{:.0},{},{:.1},{:.1}\n",
            r.set,
            r.model,
            r.scans,
            r.pickable,
            r.recall_pct,
            r.false_best_pct,
            r.false_positives_per_scan,
            r.starvation_pct,
            r.time_ms_median,
            r.time_ms_p95,
            r.failed_scenes,
            r.wrong_first_pick_pct,
            r.none_free_to_pick_pct
        ));
    }
    crate::config::write_text(&out.join("suite.csv"), &csv)?;
    write_json(&out.join("suite.json"), &rows)?;
    tracing::info!(
        "wrote {}/suite.csv, suite.json and one folder per set",
        out.display()
    );
    let failed: usize = rows.iter().map(|r| r.failed_scenes).sum();
    if failed > 0 {
        bail!("{failed} scene(s) failed (see each set's summary.csv)");
    }
    Ok(())
}

/// The benchmark table: one line per set, then the sums.
fn print_suite(rows: &[SuiteRow], preset: &str, file: binpick_eval::ModelFile) {
    let file = match file {
        binpick_eval::ModelFile::Scan => "scan",
        binpick_eval::ModelFile::Mesh => "mesh",
    };
    println!("benchmark, preset {preset}, model file {file}");
    println!(
        "{:<26} {:>5} {:>8} {:>8} {:>8} {:>8} {:>9} {:>8} {:>8} {:>10} {:>10}",
        "set",
        "scans",
        "pickable",
        "R/P %",
        "FB/F %",
        "WP/F %",
        "FP/scan",
        "S/F %",
        "NF/F %",
        "median ms",
        "p95 ms"
    );
    for r in rows {
        println!(
            "{:<26} {:>5} {:>8} {:>8.1} {:>8.0} {:>8.0} {:>9.2} {:>8.0} {:>8.0} {:>10.0} {:>10.0}",
            r.set,
            r.scans,
            r.pickable,
            r.recall_pct,
            r.false_best_pct,
            r.wrong_first_pick_pct,
            r.false_positives_per_scan,
            r.starvation_pct,
            r.none_free_to_pick_pct,
            r.time_ms_median,
            r.time_ms_p95
        );
    }
    let n = rows.len().max(1) as f64;
    let mean = |f: fn(&SuiteRow) -> f64| rows.iter().map(f).sum::<f64>() / n;
    println!(
        "{:<26} {:>5} {:>8} {:>8.1} {:>8.0} {:>8.0} {:>9.2} {:>8.0} {:>8.0}   (means over sets)",
        "all sets",
        rows.iter().map(|r| r.scans).sum::<usize>(),
        rows.iter().map(|r| r.pickable).sum::<usize>(),
        mean(|r| r.recall_pct),
        mean(|r| r.false_best_pct),
        mean(|r| r.wrong_first_pick_pct),
        mean(|r| r.false_positives_per_scan),
        mean(|r| r.starvation_pct),
        mean(|r| r.none_free_to_pick_pct)
    );
}

/// `--out`, or `eval-out/<model>-<preset>`; created with its `scenes/`.
fn out_folder(a: &Args, model: &str, preset: &str) -> Result<PathBuf> {
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| Path::new("eval-out").join(format!("{model}-{preset}")));
    std::fs::create_dir_all(out.join("scenes"))
        .with_context(|| format!("cannot create {}", out.display()))?;
    Ok(out)
}

/// A BOP object id: `7` or `obj_000007`.
fn parse_obj_id(s: &str) -> Result<u32> {
    s.trim_start_matches("obj_")
        .parse()
        .with_context(|| format!("--model {s:?}: a BOP object id is a number (7 or obj_000007)"))
}

fn write_csv(path: &Path, run: &EvalRun) -> Result<()> {
    let mut s = String::from(
        "id,scene,instances,pickable,recognised_pickable,recognised_unpickable,false_positives,false_best,starvation,none_free_to_pick,time_ms,error\n",
    );
    for r in &run.scenes {
        let e = r.error.as_deref().unwrap_or("").replace(['"', '\n'], " ");
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{:.1},\"{e}\"\n",
            r.id,
            r.scene,
            r.score.instances,
            r.score.pickable,
            r.score.recognised_pickable,
            r.score.recognised_unpickable,
            r.score.false_positives,
            u8::from(r.score.false_best),
            u8::from(r.score.starvation),
            u8::from(r.score.none_free_to_pick),
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
    type Percent = fn(&binpick_eval::ThesisPercents) -> f64;
    let thv = |f: Percent| match th {
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
    let counts = [
        ("files processed", "F", t.files),
        ("pickable objects in the clouds", "P", t.pickable),
        ("pickable objects recognised", "R", t.recognised),
        ("false negatives", "FN", t.false_negatives),
        (
            "files with a false positive",
            "FP",
            t.files_with_false_positive,
        ),
        (
            "files with an aligned unpickable object",
            "NP",
            t.files_with_unpickable,
        ),
        ("bad cycles by false best", "FB", t.false_best),
        ("bad cycles by starvation", "S", t.starvation),
    ];
    for (property, symbol, n) in counts {
        println!("{property:<44} {symbol:>6} {n:>9}");
    }
    let percents: [(&str, &str, Percent); 6] = [
        ("recognition rate", "R/P", |x| x.recognition),
        ("false negatives", "FN/P", |x| x.false_negatives),
        ("clouds with false positives", "FP/F", |x| {
            x.files_with_false_positive
        }),
        ("clouds with unpickable objects", "NP/F", |x| {
            x.files_with_unpickable
        }),
        ("bad cycles by false best", "FB/F", |x| x.false_best),
        ("bad cycles by starvation", "S/F", |x| x.starvation),
    ];
    for (property, symbol, f) in percents {
        println!("{property:<44} {symbol:>6} {:>7.1} % {}", f(&p), thv(f));
    }
    println!(
        "{:<44} {:>6} {:>7.1} %",
        "precision (correct / all detections)", "", p.precision
    );
    println!(
        "{:<44} {:>6} {:>7.1} % ({} of {} instances >= 10 % visible)",
        "BOP-visible recall (visib_fract >= 0.1)",
        "",
        p.bop_visible_recall,
        t.bop_recognised,
        t.bop_targets
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
