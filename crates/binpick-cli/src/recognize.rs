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
    /// Print only the JSON-equivalent table, no per-cluster report.
    #[arg(long, short)]
    pub quiet: bool,
}

pub fn run(a: Args) -> Result<()> {
    let params = a.params.params()?;
    let model = load(&a.model, a.params.model_units(&params), "model")?;
    let scene = load(&a.scene, params.units, "scene")?;
    let recognizer = Recognizer::new(&model, params.clone()).context("cannot prepare the model")?;
    log(&format!(
        "model prepared in {:.0} ms: {} points, {} keypoints, {} FPFH radii, diameter {:.1} mm; {} thread(s)",
        recognizer_prep_ms(&recognizer),
        recognizer.model().cloud.len(),
        recognizer.model().initial_keypoints.len(),
        recognizer.model().features.len(),
        recognizer.model().diameter_mm,
        recognizer.threads()
    ));
    let result = recognizer.recognize(&scene).context("recognition failed")?;
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
    if let Some(out) = &a.json {
        let report = RecognitionReport::new(
            &a.scene.display().to_string(),
            &a.model.display().to_string(),
            "rust",
            &params,
            &result,
        );
        write_json(out, &report)?;
        let p = write_params_next_to(out, &params)?;
        log(&format!("wrote {} and {}", out.display(), p.display()));
    }
    Ok(())
}

fn recognizer_prep_ms(r: &Recognizer) -> f64 {
    r.preparation().as_secs_f64() * 1000.0
}
