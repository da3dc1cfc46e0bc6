//! `binpick recognize`: one model, one scene, ranked picks.

use std::path::PathBuf;

use anyhow::{Context, Result};
use binpick::{RecognitionReport, Recognizer};

use crate::config::{ParamArgs, load, log, write_json, write_params_next_to};
use crate::table::{print_ranked, summary};

#[derive(clap::Args)]
pub struct Args {
    /// Model cloud (.pcd or .ply), in the object's frame.
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
    /// Which pipeline recognises: `rust` (binpick's orchestration) or `reference` (the
    /// thesis's Algorithms 1/2 written directly in C++ against PCL; always runs the thesis
    /// exactly, as `--thesis-strict`).
    #[arg(long, value_enum, default_value_t = Engine::Rust)]
    pub engine: Engine,
}

/// The two recognition pipelines.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Engine {
    Rust,
    Reference,
}

impl Engine {
    pub fn name(self) -> &'static str {
        match self {
            Engine::Rust => "rust",
            Engine::Reference => "reference",
        }
    }
}

pub fn run(a: Args) -> Result<()> {
    let params = a.params.params()?;
    let model = load(&a.model, a.params.model_units(&params), "model")?;
    let scene = load(&a.scene, params.units, "scene")?;
    let result = match a.engine {
        Engine::Rust => {
            let recognizer =
                Recognizer::new(&model, params.clone()).context("cannot prepare the model")?;
            log(&format!(
                "model prepared in {:.0} ms: {} points, {} keypoints, {} FPFH radii, diameter {:.1} mm; {} thread(s)",
                recognizer_prep_ms(&recognizer),
                recognizer.model().cloud.len(),
                recognizer.model().initial_keypoints.len(),
                recognizer.model().features.len(),
                recognizer.model().diameter_mm,
                recognizer.threads()
            ));
            recognizer.recognize(&scene).context("recognition failed")?
        }
        Engine::Reference => {
            log("reference engine: thesis Algorithms 1/2 in C++ against PCL, one part per cluster");
            binpick::reference::recognize_reference(&model, &scene, &params)
                .context("reference recognition failed")?
        }
    };
    log(&summary(&result));
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
        a.engine.name(),
        &params,
        &result,
    );
    report.model_units = a.params.model_units(&params);
    if let Some(out) = &a.json {
        write_json(out, &report)?;
        let p = write_params_next_to(out, &params)?;
        log(&format!("wrote {} and {}", out.display(), p.display()));
    }
    write_pictures(&report, &scene, &model, a.png.as_deref(), a.ply.as_deref())
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
