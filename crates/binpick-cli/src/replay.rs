//! `binpick replay`: recognition over recorded scans without ground truth.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use binpick::Recognizer;
use binpick_eval::median_p95;
use binpick_eval::replay_scan;
use serde::Serialize;

use crate::config::{ParamArgs, load_part, log, write_json, write_params_next_to};
use crate::progress::Progress;

#[derive(clap::Args)]
pub struct Args {
    /// Scan files (.pcd or .ply).
    #[arg(required = true)]
    pub scans: Vec<PathBuf>,
    /// Part model: scanned cloud or CAD mesh (as `recognize --model`).
    #[arg(long)]
    pub model: PathBuf,
    #[command(flatten)]
    pub params: ParamArgs,
    /// Output folder: one <scan>.json per scan plus summary.json (default: replay-out).
    #[arg(long, default_value = "replay-out")]
    pub out: PathBuf,
}

#[derive(Serialize)]
struct Summary<'a> {
    model: String,
    units: &'static str,
    scans: usize,
    failed: usize,
    detections_total: usize,
    scans_without_detection: usize,
    time_ms_median: f64,
    time_ms_p95: f64,
    results: &'a [binpick_eval::ReplayResult],
    params: &'a binpick::Params,
}

pub fn run(a: Args) -> Result<()> {
    let params = a.params.params()?;
    let part = load_part(&a.model, a.params.model_units(&params), &params)?;
    let recognizer =
        Recognizer::with_part(part, params.clone()).context("cannot prepare the model")?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let model_name = a.model.display().to_string();
    let progress = Progress::new(a.scans.len(), "replay");
    let mut results = Vec::new();
    for (k, scan) in a.scans.iter().enumerate() {
        let r = replay_scan(&recognizer, scan, &model_name, params.units);
        let stem = scan
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("scan{k}"));
        if let Some(report) = &r.report {
            write_json(&a.out.join(format!("{stem}.json")), report)?;
        }
        let msg = match &r.error {
            Some(e) => format!("{}: ERROR {e}", scan.display()),
            None => format!(
                "{}: {} found, {:.0} ms",
                scan.display(),
                r.detections,
                r.time_ms
            ),
        };
        progress.step(k + 1, &msg);
        results.push(r);
    }
    progress.finish();
    let ok: Vec<_> = results.iter().filter(|r| r.error.is_none()).collect();
    let times: Vec<f64> = ok.iter().map(|r| r.time_ms).collect();
    let (median, p95) = median_p95(&times);
    let summary = Summary {
        model: model_name,
        units: "mm",
        scans: results.len(),
        failed: results.len() - ok.len(),
        detections_total: ok.iter().map(|r| r.detections).sum(),
        scans_without_detection: ok.iter().filter(|r| r.detections == 0).count(),
        time_ms_median: median,
        time_ms_p95: p95,
        results: &results,
        params: &params,
    };
    write_json(&a.out.join("summary.json"), &summary)?;
    write_params_next_to(&a.out.join("summary.json"), &params)?;
    println!(
        "{} scan(s): {} detection(s), {} without any, {} failed; time per scan median {:.0} ms, p95 {:.0} ms",
        summary.scans,
        summary.detections_total,
        summary.scans_without_detection,
        summary.failed,
        median,
        p95
    );
    log(&format!(
        "wrote {}/summary.json and one JSON per scan",
        a.out.display()
    ));
    for r in results.iter().filter(|r| r.error.is_some()) {
        log(&format!(
            "{}: {}",
            r.scan.display(),
            r.error.as_deref().unwrap_or("")
        ));
    }
    if summary.failed > 0 {
        bail!("{} of {} scans failed", summary.failed, summary.scans);
    }
    Ok(())
}
