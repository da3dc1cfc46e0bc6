//! `binpick show`: pictures of a saved result (the JSON of `recognize`, `eval` or `replay`).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use binpick::{Detection, RecognitionReport};
use serde::Deserialize;

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
    /// Model (cloud or mesh), if it moved since the result was written.
    #[arg(long)]
    pub model: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    let file = a.result.display();
    let text = std::fs::read_to_string(&a.result).with_context(|| format!("cannot read {file}"))?;
    let mut report = parse(&text).with_context(|| format!("{file} is not a binpick result"))?;
    if report.units != "mm" {
        bail!("{file}: units {:?}, expected \"mm\"", report.units);
    }
    let scene_path = a
        .scene
        .clone()
        .unwrap_or_else(|| PathBuf::from(&report.scene));
    let model_path = a
        .model
        .clone()
        .unwrap_or_else(|| PathBuf::from(&report.model));
    let scene = load(&scene_path, report.params.units, "scene").with_context(|| {
        format!(
            "{file} names the scene {}: use --scene to point at the scene cloud",
            scene_path.display()
        )
    })?;
    // A mesh model (STL, OBJ) is sampled as `recognize` samples it.
    let model = binpick::load_part(&model_path, report.model_units, &report.params)
        .map(|(part, _)| part.cloud)
        .with_context(|| {
            format!(
                "{file} names the model {}: use --model to point at the model (cloud or mesh)",
                model_path.display()
            )
        })?;
    // The pictures are drawn over the scan, in the scanner's frame.
    report.express_in(&binpick::OutputFrame::scanner());
    let png = a
        .png
        .clone()
        .unwrap_or_else(|| a.result.with_extension("png"));
    crate::recognize::write_pictures(&report, &scene, &model, Some(&png), a.ply.as_deref())
        .with_context(|| format!("cannot draw the result {file}"))
}

/// A result document; a bad detection record is named by its index and rank.
fn parse(text: &str) -> Result<RecognitionReport> {
    let value: serde_json::Value = serde_json::from_str(text).context("not valid JSON")?;
    if let Some(detections) = value.get("detections").and_then(|d| d.as_array()) {
        for (i, d) in detections.iter().enumerate() {
            let rank = d
                .get("rank")
                .map_or_else(|| "no rank".to_owned(), |r| format!("rank {r}"));
            let parsed =
                Detection::deserialize(d).with_context(|| format!("detection {i} ({rank})"))?;
            let t = parsed.pose.translation.vector;
            if !(t.iter().all(|c| c.is_finite()) && parsed.final_score.is_finite()) {
                bail!("detection {i} ({rank}): non-finite pose or score");
            }
        }
    }
    Ok(RecognitionReport::deserialize(&value)?)
}

#[cfg(test)]
mod tests {
    use super::parse;

    #[test]
    fn a_bad_detection_is_named_by_index_and_rank() {
        let pose = "[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]";
        let record = |rank: u32, pose: &str| {
            format!(
                r#"{{"rank": {rank}, "pose": {pose}, "initial_score": 1.0, "final_score": 0.0,
                "score_before_icp": 0.0, "cluster": 0, "cluster_round": 0, "fpfh_radius_mm": 10.0,
                "sac_threshold_mm": 1.0, "sac_inliers": 5,
                "icp": {{"converged": true, "iterations": 1, "fitness_mm2": 0.1, "adopted": true}},
                "height_mm": 1.0, "rank_reason": ""}}"#
            )
        };
        let doc = |dets: String| format!(r#"{{"units": "mm", "detections": [{dets}]}}"#);
        let bad = "[2,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]"; // not a rotation
        let e = parse(&doc(format!("{}, {}", record(1, pose), record(2, bad)))).unwrap_err();
        let msg = format!("{e:#}");
        assert!(msg.contains("detection 1 (rank 2)"), "{msg}");
        assert!(parse("{").unwrap_err().to_string().contains("JSON"));
    }
}
