//! `binpick show`: pictures of a saved result (the JSON of `recognize`, `eval` or `replay`).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use binpick::RecognitionReport;

use crate::config::load;

#[derive(clap::Args)]
pub struct Args {
    /// A result JSON (schema in README).
    pub result: PathBuf,
    /// PNG to write (default: the JSON's path with .png).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Also write the labelled PLY here.
    #[arg(long)]
    pub ply: Option<PathBuf>,
    /// Scene cloud, if it moved since the result was written.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Model cloud, if it moved since the result was written.
    #[arg(long)]
    pub model: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    let text = std::fs::read_to_string(&a.result)
        .with_context(|| format!("cannot read {}", a.result.display()))?;
    let report: RecognitionReport = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a binpick result", a.result.display()))?;
    if report.units != "mm" {
        bail!(
            "{}: units {:?}, expected \"mm\"",
            a.result.display(),
            report.units
        );
    }
    let scene_path = a
        .scene
        .clone()
        .unwrap_or_else(|| PathBuf::from(&report.scene));
    let model_path = a
        .model
        .clone()
        .unwrap_or_else(|| PathBuf::from(&report.model));
    let scene = load(&scene_path, report.params.units, "scene")
        .context("use --scene to point at the scene cloud")?;
    let model = load(&model_path, report.model_units, "model")
        .context("use --model to point at the model cloud")?;
    let png = a
        .png
        .clone()
        .unwrap_or_else(|| a.result.with_extension("png"));
    crate::recognize::write_pictures(&report, &scene, &model, Some(&png), a.ply.as_deref())
}
