//! `binpick recognize`: one model, one scene, ranked picks.

use std::path::PathBuf;

use anyhow::{Context, Result};
use binpick::{RecognitionReport, Recognizer};

use crate::config::{ParamArgs, load_part, load_scene, log, write_json, write_params_next_to};
use crate::table::{print_ranked, summary};

#[derive(clap::Args)]
pub struct Args {
    /// Part model in its own frame: a scanned cloud (.pcd, .ply without faces) or a CAD mesh
    /// (.stl, .obj, .ply with faces); symmetries in `<model>.json` beside it (README).
    #[arg(long)]
    pub model: PathBuf,
    /// Scene cloud (.pcd or .ply).
    #[arg(long)]
    pub scene: PathBuf,
    #[command(flatten)]
    pub params: ParamArgs,
    /// Write the result as JSON (schema in README); the parameters go next to it as .params.toml.
    #[arg(long, value_name = "out.json")]
    pub json: Option<PathBuf>,
    /// Render the result as PNG: scanner view and oblique view, detections in their poses,
    /// labelled with their rank.
    #[arg(long, value_name = "out.png")]
    pub png: Option<PathBuf>,
    /// Write a PLY: the scene coloured by which detection explains each point, plus the
    /// placed models (for CloudCompare or MeshLab).
    #[arg(long, value_name = "out.ply")]
    pub ply: Option<PathBuf>,
    /// Print only the JSON-equivalent table, no per-cluster report.
    #[arg(long, short)]
    pub quiet: bool,
}

pub fn run(a: Args) -> Result<()> {
    let params = a.params.params()?;
    let part = load_part(&a.model, a.params.model_units(&params), &params)?;
    let (scene, seen_from) = load_scene(&a.scene, params.units)?;
    let engine = if a.params.reference() {
        "reference"
    } else {
        params.stages().engine.name()
    };
    let result = if a.params.reference() {
        log("reference engine: thesis Algorithms 1/2 in C++ against PCL, one part per cluster");
        binpick::reference::recognize_reference(&part.cloud, &scene, &params)
            .context("reference recognition failed")?
    } else {
        let recognizer = Recognizer::with_part(part.clone(), params.clone())
            .context("cannot prepare the model")?;
        if let Some(m) = recognizer.model() {
            log(&format!(
                "model prepared in {:.0} ms: {} points, {} keypoints, {} FPFH radii, diameter {:.1} mm; {} thread(s)",
                recognizer_prep_ms(&recognizer),
                m.cloud.len(),
                m.initial_keypoints.len(),
                m.features.len(),
                m.diameter_mm,
                recognizer.threads()
            ));
        }
        let r = recognizer
            .recognize_seen_from(&scene, seen_from)
            .context("recognition failed")?;
        if let Some(s) = &r.scale {
            log(&format!("derived: {}", s.summary()));
        }
        r
    };
    log(&summary(&result));
    if let (Some(v), false) = (&result.voting, a.quiet) {
        log(&crate::table::voting_summary(v));
    }
    if !a.quiet {
        for c in &result.clusters {
            log(&format!(
                "cluster {}: {} points: {}",
                c.index, c.points, c.outcome
            ));
        }
    }
    print_ranked(&result);
    let mut report = RecognitionReport::new(
        &a.scene.display().to_string(),
        &a.model.display().to_string(),
        engine,
        &params,
        &result,
    );
    report.model_units = a.params.model_units(&params);
    if let Some(out) = &a.json {
        write_json(out, &report)?;
        let p = write_params_next_to(out, &params)?;
        log(&format!("wrote {} and {}", out.display(), p.display()));
    }
    write_pictures(
        &report,
        &scene,
        &part.cloud,
        a.png.as_deref(),
        a.ply.as_deref(),
    )
}

/// PNG and PLY outputs of one result.
pub fn write_pictures(
    report: &RecognitionReport,
    scene: &binpick::PointCloud,
    model: &binpick::PointCloud,
    png: Option<&std::path::Path>,
    ply: Option<&std::path::Path>,
) -> Result<()> {
    if let Some(png) = png {
        let title = format!(
            "{} in {} (algorithm {})",
            report.model, report.scene, report.algorithm
        );
        crate::plots::render(
            scene,
            model,
            &report.detections,
            report.params.ranking.up,
            title,
            png,
        )?;
    }
    if let Some(ply) = ply {
        crate::plots::labelled_ply(
            scene,
            model,
            &report.detections,
            report.params.validation.outlier_distance_mm,
            ply,
        )?;
    }
    Ok(())
}

fn recognizer_prep_ms(r: &Recognizer) -> f64 {
    r.preparation().as_secs_f64() * 1000.0
}
