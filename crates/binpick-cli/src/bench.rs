//! `binpick bench`: median time per stage and per scene, over repeated runs in one process;
//! with `--engine both`, the Rust orchestration and the reference C++ pipeline side by side on
//! the same scenes, with the speed ratio measured in that one run.

use std::path::PathBuf;

use anyhow::{Context, Result};
use binpick::reference::recognize_reference;
use std::time::{Duration, Instant};

use binpick::{Params, PointCloud, Recognition, RecognizeOptions, Recognizer, Timings};
use binpick_eval::median_p95;
use serde::Serialize;

use crate::config::{ParamArgs, load_part, load_scene, write_json};

#[derive(clap::Args)]
pub struct Args {
    /// Part model: scanned cloud or CAD mesh (as `recognize --model`).
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
    /// `rust` (the library, with `--engine`), `reference` (the C++ pipeline) or `both`.
    /// `both` runs the library's thesis engine thesis-strict (the reference always runs the
    /// thesis exactly), checks the detections agree and prints reference time / Rust time
    /// per scene.
    #[arg(long, value_enum, default_value_t = BenchEngine::Rust)]
    pub pipelines: BenchEngine,
    /// Also time `--repeat` runs per scene under a time budget of this fraction of the
    /// scene's median unbudgeted time (e.g. 0.5), and report how long past the budget each
    /// call returned. With `--time-budget-ms`, that budget is used instead (library engines).
    #[arg(long, value_name = "F")]
    pub budget_fraction: Option<f64>,
    /// Budgets per stage for the summary that says which stages are over, ms, as
    /// `preprocess,initial,final,ranking,total` (initial = voting and final = verification
    /// for the scene-voting engine). Default: the 0.25 s whole-process target of a belt scan
    /// split by stage (see `StageBudgets`).
    #[arg(long, value_name = "MS,MS,MS,MS,MS", value_parser = parse_stage_budgets)]
    pub stage_budgets_ms: Option<StageBudgets>,
}

/// What one scan may spend per stage, ms (library time, loading excluded).
#[derive(Serialize, Clone, Copy, Debug, PartialEq)]
pub struct StageBudgets {
    pub preprocess_ms: f64,
    /// Scene voting: voting (normals, samples, votes); thesis engine: initial alignment.
    pub initial_ms: f64,
    /// Scene voting: verification; thesis engine: final alignment.
    pub final_ms: f64,
    pub ranking_ms: f64,
    pub total_ms: f64,
}

impl Default for StageBudgets {
    /// The target of 0.25 s per belt scan of about 470 k points, whole process on 2 cores,
    /// less about 40 ms to read the binary PCD: 210 ms of library time, split as preprocessing
    /// (voxel grid, support planes) 50, voting 70, verification 80, ranking 5, and 5 to spare.
    fn default() -> Self {
        Self {
            preprocess_ms: 50.0,
            initial_ms: 70.0,
            final_ms: 80.0,
            ranking_ms: 5.0,
            total_ms: 210.0,
        }
    }
}

fn parse_stage_budgets(s: &str) -> std::result::Result<StageBudgets, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("{x:?}: {e}")))
        .collect::<std::result::Result<_, _>>()?;
    match v[..] {
        [preprocess_ms, initial_ms, final_ms, ranking_ms, total_ms]
            if v.iter().all(|x| x.is_finite() && *x > 0.0) =>
        {
            Ok(StageBudgets {
                preprocess_ms,
                initial_ms,
                final_ms,
                ranking_ms,
                total_ms,
            })
        }
        _ => Err(format!(
            "expected five positive budgets in ms, preprocess,initial,final,ranking,total (got {s:?})"
        )),
    }
}

/// One stage against its budget, over the scenes the library engine timed.
#[derive(Serialize, Debug, PartialEq)]
pub struct StageBudgetRow {
    pub stage: &'static str,
    pub budget_ms: f64,
    /// Median over the scenes of each scene's median, ms.
    pub median_ms: f64,
    /// The largest scene median, ms.
    pub worst_ms: f64,
    /// Scenes whose median is over the budget.
    pub scenes_over: usize,
    pub scenes: usize,
}

/// Each stage's scene medians against its budget (`thesis` names the thesis engine's
/// stages, else the scene-voting engine's).
pub fn stage_budget_rows(
    scenes: &[&StageMedians],
    budgets: &StageBudgets,
    thesis: bool,
) -> Vec<StageBudgetRow> {
    let (initial, last) = if thesis {
        ("initial alignment", "final alignment")
    } else {
        ("voting", "verification")
    };
    type Of = fn(&StageMedians) -> f64;
    let stages: [(&'static str, f64, Of); 5] = [
        ("preprocessing", budgets.preprocess_ms, |m| m.preprocess_ms),
        (initial, budgets.initial_ms, |m| m.initial_alignment_ms),
        (last, budgets.final_ms, |m| m.final_alignment_ms),
        ("ranking", budgets.ranking_ms, |m| m.ranking_ms),
        ("total", budgets.total_ms, |m| m.total_ms),
    ];
    stages
        .into_iter()
        .map(|(stage, budget_ms, of)| {
            let v: Vec<f64> = scenes.iter().map(|m| of(m)).collect();
            StageBudgetRow {
                stage,
                budget_ms,
                median_ms: median_p95(&v).0,
                worst_ms: v.iter().copied().fold(0.0, f64::max),
                scenes_over: v.iter().filter(|&&x| x > budget_ms).count(),
                scenes: v.len(),
            }
        })
        .collect()
}

fn print_stage_budgets(rows: &[StageBudgetRow]) {
    println!(
        "\n{:<20} {:>10} {:>12} {:>12} {:>12} {:>14}",
        "stage (budget)", "budget", "median", "worst scene", "scenes over", "median/budget"
    );
    for r in rows {
        println!(
            "{:<20} {:>10.0} {:>12.1} {:>12.1} {:>9}/{:<2} {:>13.2}x{}",
            r.stage,
            r.budget_ms,
            r.median_ms,
            r.worst_ms,
            r.scenes_over,
            r.scenes,
            r.median_ms / r.budget_ms,
            if r.median_ms > r.budget_ms {
                "  over"
            } else {
                ""
            }
        );
    }
    println!(
        "(ms of library time per scan, medians over the scenes of each scene's median; budgets: --stage-budgets-ms)"
    );
}

/// Runs under a time budget on one scene: how long past it the calls returned.
#[derive(Serialize)]
pub struct BudgetRuns {
    pub scene: String,
    pub budget_ms: f64,
    /// Median unbudgeted total of the same scene, ms.
    pub unbudgeted_ms: f64,
    /// Wall-clock time from the call to its return, ms, per run.
    pub returned_ms: Vec<f64>,
    /// Detections returned, per run (all verified).
    pub detections: Vec<usize>,
    /// Where each run was stopped ("" when it finished within the budget).
    pub stopped_in: Vec<String>,
    /// Runs that returned within max(10 % of the budget, 50 ms) past it.
    pub within_tolerance: usize,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BenchEngine {
    Rust,
    Reference,
    Both,
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
    /// `rust` or `reference`.
    pub engine: &'static str,
    pub points: usize,
    pub detections: usize,
    pub runs: usize,
    pub median: StageMedians,
}

/// `--engine both`: one scene, both engines.
#[derive(Serialize)]
pub struct SceneComparison {
    pub scene: String,
    /// Median total reference / median total Rust (same process, same thread count).
    pub speedup: f64,
    /// Same as `speedup` but with the Rust model preparation charged to every scene.
    pub speedup_with_preparation: f64,
    pub same_detection_count: bool,
    /// Largest pose difference between matched detections, mm and degrees.
    pub max_translation_diff_mm: f64,
    pub max_rotation_diff_deg: f64,
}

#[derive(Serialize)]
struct BenchOutput {
    model_preparation_ms: f64,
    threads: usize,
    scenes: Vec<SceneBench>,
    comparisons: Vec<SceneComparison>,
    budgets: Vec<BudgetRuns>,
    stage_budgets: StageBudgets,
    /// The library engine's stages against `stage_budgets`.
    stages_against_budget: Vec<StageBudgetRow>,
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

/// One warm-up run then `repeat` timed runs.
fn time_runs(
    repeat: usize,
    mut f: impl FnMut() -> binpick::Result<Recognition>,
) -> Result<(Recognition, Vec<Timings>)> {
    let warm = f()?;
    let mut runs = Vec::new();
    for _ in 0..repeat.max(1) {
        runs.push(f()?.timings);
    }
    Ok((warm, runs))
}

fn print_header() {
    println!(
        "{:<40} {:<9} {:>8} {:>5} {:>10} {:>10} {:>10} {:>10} {:>8} {:>10} {:>10}",
        "scene",
        "engine",
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
}

fn print_row(b: &SceneBench) {
    let m = &b.median;
    println!(
        "{:<40} {:<9} {:>8} {:>5} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>8.2} {:>10.1} {:>10.1}",
        b.scene,
        b.engine,
        b.points,
        b.detections,
        m.preprocess_ms,
        m.clustering_ms,
        m.initial_alignment_ms,
        m.final_alignment_ms,
        m.ranking_ms,
        m.total_ms,
        m.total_p95_ms
    );
}

/// Largest translation (mm) and rotation (deg) difference between detections matched by
/// cluster index, and whether the counts agree.
fn pose_differences(a: &Recognition, b: &Recognition) -> (bool, f64, f64) {
    let mut dt: f64 = 0.0;
    let mut dr: f64 = 0.0;
    for d in &a.detections {
        if let Some(e) = b.detections.iter().find(|e| e.found_by == d.found_by) {
            dt = dt.max((d.pose.translation.vector - e.pose.translation.vector).norm());
            dr = dr.max(d.pose.rotation.angle_to(&e.pose.rotation).to_degrees());
        } else {
            dt = f64::INFINITY;
        }
    }
    (a.detections.len() == b.detections.len(), dt, dr)
}

pub fn run(a: Args) -> Result<()> {
    if let Some(f) = a.budget_fraction
        && !(f.is_finite() && f > 0.0)
    {
        anyhow::bail!("--budget-fraction {f}: expected a positive fraction, e.g. 0.5");
    }
    let mut params = a.params.params()?;
    if a.pipelines == BenchEngine::Both && !params.thesis_strict {
        params.thesis_strict = true;
        tracing::info!(
            "--pipelines both: the library runs the thesis engine thesis-strict, as the reference does",
        );
    }
    let part = load_part(&a.model, a.params.model_units(&params), &params)?;
    let model = part.cloud.clone();
    let recognizer =
        Recognizer::with_part(part, params.clone()).context("cannot prepare the model")?;
    let mut prep_ms = recognizer.preparation().as_secs_f64() * 1000.0;
    println!(
        "engine {}; model preparation (once per model): {prep_ms:.0} ms; {} thread(s); preset {}, algorithm {}",
        params.stages().engine.name(),
        recognizer.threads(),
        a.params.preset_name(),
        params.algorithm.number()
    );
    print_header();
    let mut out = BenchOutput {
        model_preparation_ms: 0.0,
        threads: recognizer.threads(),
        scenes: Vec::new(),
        comparisons: Vec::new(),
        budgets: Vec::new(),
        stage_budgets: a.stage_budgets_ms.unwrap_or_default(),
        stages_against_budget: Vec::new(),
    };
    for scene_path in &a.scene {
        let (scene, seen_from) = load_scene(scene_path, params.units)?;
        let name = scene_path.display().to_string();
        // Times one engine on this scene, prints and stores its row; (first result, median total).
        let mut measure =
            |engine: &'static str, timed: (Recognition, Vec<Timings>)| -> (Recognition, f64) {
                let (warm, runs) = timed;
                let b = SceneBench {
                    scene: name.clone(),
                    engine,
                    points: scene.len(),
                    detections: warm.detections.len(),
                    runs: runs.len(),
                    median: medians(&runs),
                };
                print_row(&b);
                let total = b.median.total_ms;
                out.scenes.push(b);
                (warm, total)
            };
        let rust = match a.pipelines {
            BenchEngine::Rust | BenchEngine::Both => Some(measure(
                "rust",
                time_runs(a.repeat, || {
                    recognizer.recognize_seen_from(&scene, seen_from)
                })?,
            )),
            BenchEngine::Reference => None,
        };
        // The scene-voting model is prepared at the first scan of a scale.
        prep_ms = recognizer.preparation().as_secs_f64() * 1000.0;
        let reference = match a.pipelines {
            BenchEngine::Reference | BenchEngine::Both => Some(measure(
                "reference",
                time_reference(a.repeat, &model, &scene, &params)?,
            )),
            BenchEngine::Rust => None,
        };
        let fixed_budget = a.params.time_budget_ms.map(|b| b as f64);
        if let (Some((_, rust_ms)), true) =
            (&rust, a.budget_fraction.is_some() || fixed_budget.is_some())
        {
            let budget_ms = fixed_budget.unwrap_or(a.budget_fraction.unwrap_or(1.0) * rust_ms);
            out.budgets.push(time_budgeted(
                &recognizer,
                &scene,
                seen_from,
                &name,
                budget_ms,
                *rust_ms,
                a.repeat,
            )?);
        }
        if let (Some((r, rust_ms)), Some((c, ref_ms))) = (rust, reference) {
            let (same, dt, dr) = pose_differences(&r, &c);
            out.comparisons.push(SceneComparison {
                scene: name.clone(),
                speedup: ref_ms / rust_ms,
                speedup_with_preparation: ref_ms / (rust_ms + prep_ms),
                same_detection_count: same,
                max_translation_diff_mm: dt,
                max_rotation_diff_deg: dr,
            });
        }
    }
    out.model_preparation_ms = prep_ms;
    println!(
        "(ms, medians of {} runs; * = thesis engine: summed over the clusters' worker threads, scene voting: wall time of voting and of verification; 'total' is wall time; model preparation {prep_ms:.0} ms)",
        a.repeat.max(1)
    );
    let library: Vec<&StageMedians> = out
        .scenes
        .iter()
        .filter(|b| b.engine == "rust")
        .map(|b| &b.median)
        .collect();
    if !library.is_empty() {
        let thesis = params.stages().engine.name() != "scene-voting";
        out.stages_against_budget = stage_budget_rows(&library, &out.stage_budgets, thesis);
        print_stage_budgets(&out.stages_against_budget);
    }
    if !out.comparisons.is_empty() {
        println!(
            "\n{:<40} {:>9} {:>18} {:>10} {:>12} {:>12}",
            "scene", "speedup", "with model prep", "same count", "max dt mm", "max dr deg"
        );
        for c in &out.comparisons {
            println!(
                "{:<40} {:>8.2}x {:>17.2}x {:>10} {:>12.3} {:>12.3}",
                c.scene,
                c.speedup,
                c.speedup_with_preparation,
                c.same_detection_count,
                c.max_translation_diff_mm,
                c.max_rotation_diff_deg
            );
        }
        let ratios: Vec<f64> = out.comparisons.iter().map(|c| c.speedup).collect();
        println!(
            "median speedup (reference total / Rust total): {:.2}x",
            median_p95(&ratios).0
        );
    }
    if !out.budgets.is_empty() {
        print_budgets(&out.budgets);
    }
    if let Some(path) = &a.json {
        write_json(path, &out)?;
        tracing::info!("wrote {}", path.display());
    }
    Ok(())
}

fn time_reference(
    repeat: usize,
    model: &PointCloud,
    scene: &PointCloud,
    params: &Params,
) -> Result<(Recognition, Vec<Timings>)> {
    time_runs(repeat, || recognize_reference(model, scene, params))
}

/// `repeat` calls under a budget of `budget_ms`, timed from the call to its return.
fn time_budgeted(
    recognizer: &Recognizer,
    scene: &PointCloud,
    seen_from: Option<[f64; 3]>,
    name: &str,
    budget_ms: f64,
    unbudgeted_ms: f64,
    repeat: usize,
) -> Result<BudgetRuns> {
    let budget = Duration::from_secs_f64(budget_ms.max(1.0) / 1000.0);
    let options = RecognizeOptions::default()
        .time_budget(budget)
        .sensor_position_mm(seen_from);
    let tolerance_ms = (0.1 * budget_ms).max(50.0);
    let mut runs = BudgetRuns {
        scene: name.to_owned(),
        budget_ms,
        unbudgeted_ms,
        returned_ms: Vec::new(),
        detections: Vec::new(),
        stopped_in: Vec::new(),
        within_tolerance: 0,
    };
    for _ in 0..repeat.max(1) {
        let start = Instant::now();
        let r = recognizer.recognize_with(scene, &options)?;
        let returned = start.elapsed().as_secs_f64() * 1000.0;
        if returned <= budget_ms + tolerance_ms {
            runs.within_tolerance += 1;
        }
        runs.returned_ms.push(returned);
        runs.detections.push(r.detections.len());
        runs.stopped_in
            .push(r.interrupted.map(|i| i.stage).unwrap_or_default());
    }
    Ok(runs)
}

fn print_budgets(budgets: &[BudgetRuns]) {
    println!(
        "\n{:<40} {:>10} {:>12} {:>14} {:>14} {:>12} {:>8}  stopped in",
        "scene (time budget)",
        "budget",
        "unbudgeted",
        "returned med",
        "returned max",
        "over max",
        "within"
    );
    for b in budgets {
        let (med, _) = median_p95(&b.returned_ms);
        let max = b.returned_ms.iter().copied().fold(0.0, f64::max);
        let stages: std::collections::BTreeSet<&str> = b
            .stopped_in
            .iter()
            .map(|s| if s.is_empty() { "-" } else { s.as_str() })
            .collect();
        let stages: Vec<&str> = stages.into_iter().collect();
        println!(
            "{:<40} {:>10.0} {:>12.0} {:>14.1} {:>14.1} {:>12.1} {:>5}/{:<2}  {} (found {:?})",
            b.scene,
            b.budget_ms,
            b.unbudgeted_ms,
            med,
            max,
            max - b.budget_ms,
            b.within_tolerance,
            b.returned_ms.len(),
            stages.join(", "),
            b.detections
        );
    }
    println!(
        "(ms; returned = call to return, wall clock; within = returned at most max(10 % of the budget, 50 ms) past it)"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stage(preprocess: f64, voting: f64, verification: f64) -> StageMedians {
        StageMedians {
            preprocess_ms: preprocess,
            clustering_ms: 0.0,
            initial_alignment_ms: voting,
            final_alignment_ms: verification,
            ranking_ms: 0.1,
            total_ms: preprocess + voting + verification,
            total_p95_ms: preprocess + voting + verification,
        }
    }

    #[test]
    fn each_stage_is_judged_against_its_own_budget() {
        let scenes = [
            stage(40.0, 100.0, 60.0),
            stage(60.0, 50.0, 70.0),
            stage(45.0, 90.0, 200.0),
        ];
        let refs: Vec<&StageMedians> = scenes.iter().collect();
        let rows = stage_budget_rows(&refs, &StageBudgets::default(), false);
        let row = |name: &str| rows.iter().find(|r| r.stage == name).unwrap();
        assert_eq!(row("preprocessing").median_ms, 45.0);
        assert_eq!(row("preprocessing").scenes_over, 1);
        assert_eq!(row("voting").median_ms, 90.0);
        assert_eq!(row("voting").scenes_over, 2);
        assert_eq!(row("verification").worst_ms, 200.0);
        assert_eq!(row("verification").scenes_over, 1);
        assert_eq!(row("total").scenes_over, 1);
        let thesis = stage_budget_rows(&refs, &StageBudgets::default(), true);
        assert_eq!(thesis[1].stage, "initial alignment");
    }

    #[test]
    fn stage_budgets_need_five_positive_numbers() {
        let b = parse_stage_budgets("50, 70,80,5,210").unwrap();
        assert_eq!(b, StageBudgets::default());
        for bad in [
            "50,70,80,5",
            "50,70,80,5,210,1",
            "50,70,-80,5,210",
            "50,x,80,5,210",
        ] {
            assert!(parse_stage_budgets(bad).is_err(), "{bad}");
        }
    }
}
