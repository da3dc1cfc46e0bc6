//! `binpick check`: given poses of a part judged against a scan the way the scene-voting
//! engine judges its own hypotheses (`Recognizer::check_poses`): a taught pose, another
//! tool's answer, or the ground truth of a part that `recognize` did not report, with the
//! reason the engine would refuse it.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use binpick::{PoseCheck, Recognizer, ViewCheck};
use nalgebra::Isometry3;
use serde::Serialize;

use crate::config::{PartAndScan, write_json};
use crate::table::{POSE_HEADER, pose_cells};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub input: PartAndScan,
    /// A pose to judge: model -> scan frame, row-major 4x4 with the translation in mm
    /// ("16 numbers", commas or spaces). Repeat for several.
    #[arg(long, value_name = "4x4")]
    pub pose: Vec<String>,
    /// Poses to judge from a file: a result JSON (`recognize --json`, its detections, in the
    /// scanner's frame), a ground-truth JSON (`instances[].pose`, README "Dataset layout"),
    /// or text with one row-major 4x4 (16 numbers, mm) per line (`#` starts a comment).
    #[arg(long, value_name = "FILE")]
    pub poses: Option<PathBuf>,
    /// Refine each pose by ICP first, as the engine refines its hypotheses (else each is
    /// judged where it is given).
    #[arg(long)]
    pub refine: bool,
    /// Write the checks as JSON (one object per pose, in the order given).
    #[arg(long, value_name = "out.json")]
    pub json: Option<PathBuf>,
}

/// One pose to judge and where it came from.
struct Given {
    source: String,
    pose: Isometry3<f64>,
}

/// One judged pose as written to `--json`.
#[derive(Serialize)]
struct CheckRecord {
    /// Where the pose came from: `--pose N`, or the file and the entry.
    source: String,
    /// The pose as given, row-major 4x4, mm.
    given: [f64; 16],
    /// Whether it was refined by ICP before judging.
    refined: bool,
    /// The pose judged (refined when asked), row-major 4x4, mm.
    pose: [f64; 16],
    /// The view check (README "Formats", `view`).
    view: ViewCheck,
    /// View cells the pose explains.
    explained_cells: u32,
    /// None: the engine would accept it on its own; else why it would refuse it.
    refusal: Option<String>,
    /// The thesis's validators on its visible surface: Euclidean score (3.1.1), mm^2 ...
    euclidean_score_mm2: f64,
    /// ... and percent of outliers (3.1.2).
    outliers_pct: f64,
}

pub fn run(a: Args) -> Result<()> {
    let params = a.input.params.params()?;
    if a.input.params.reference() || params.stages().engine != binpick::Engine::SceneVoting {
        bail!(
            "check judges poses the way the scene-voting engine does; the thesis and reference \
             engines judge no given pose (leave out --preset, --engine and --thesis-strict)"
        );
    }
    let mut given = Vec::new();
    for (k, text) in a.pose.iter().enumerate() {
        let pose = parse_pose(text).with_context(|| format!("--pose {text:?}"))?;
        given.push(Given {
            source: format!("--pose {}", k + 1),
            pose,
        });
    }
    if let Some(path) = &a.poses {
        given.extend(read_poses(path)?);
    }
    if given.is_empty() {
        bail!("no pose to check: give --pose \"16 numbers\" or --poses FILE");
    }
    let (part, (scene, seen_from)) = a.input.load(&params)?;
    let recognizer =
        Recognizer::with_part(part, params.clone()).context("cannot prepare the model")?;
    let poses: Vec<Isometry3<f64>> = given.iter().map(|g| g.pose).collect();
    let checks = recognizer
        .check_poses(&scene, seen_from, &poses, a.refine)
        .context("check failed")?;
    print_checks(&mut std::io::stdout().lock(), &given, &checks)?;
    if let Some(out) = &a.json {
        let records: Vec<CheckRecord> = given
            .iter()
            .zip(&checks)
            .map(|(g, c)| CheckRecord {
                source: g.source.clone(),
                given: binpick_cloud::pose_to_row_major(&g.pose),
                refined: a.refine,
                pose: binpick_cloud::pose_to_row_major(&c.pose),
                view: c.view,
                explained_cells: c.explained_cells,
                refusal: c.refusal.clone(),
                euclidean_score_mm2: c.euclidean_score_mm2,
                outliers_pct: c.outliers_pct,
            })
            .collect();
        write_json(out, &records)?;
        tracing::info!("wrote {}", out.display());
    }
    Ok(())
}

/// A row-major 4x4 (mm) from 16 numbers separated by commas and/or white space.
fn parse_pose(text: &str) -> Result<Isometry3<f64>> {
    let numbers = text
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<f64>()
                .with_context(|| format!("{s:?} is not a number"))
        })
        .collect::<Result<Vec<f64>>>()?;
    row_major(&numbers, 1.0)
}

/// A rigid pose from 16 row-major numbers, the translation multiplied by `to_mm`.
fn row_major(v: &[f64], to_mm: f64) -> Result<Isometry3<f64>> {
    let Ok(mut m) = <[f64; 16]>::try_from(v) else {
        bail!("expected 16 numbers (a row-major 4x4), got {}", v.len());
    };
    for i in [3, 7, 11] {
        m[i] *= to_mm;
    }
    Ok(binpick_cloud::pose_from_row_major(&m)?)
}

/// The poses of a result JSON, a ground-truth JSON or a text file of 4x4s.
fn read_poses(path: &Path) -> Result<Vec<Given>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let is_json = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    let poses = if is_json {
        json_poses(path, &text)
    } else {
        text_poses(path, &text)
    }
    .with_context(|| format!("--poses {}", path.display()))?;
    if poses.is_empty() {
        bail!("--poses {}: holds no pose", path.display());
    }
    Ok(poses)
}

fn text_poses(path: &Path, text: &str) -> Result<Vec<Given>> {
    let mut out = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let pose = parse_pose(line).with_context(|| format!("line {}", k + 1))?;
        out.push(Given {
            source: format!("{}:{}", file_name(path), k + 1),
            pose,
        });
    }
    Ok(out)
}

fn json_poses(path: &Path, text: &str) -> Result<Vec<Given>> {
    let doc: serde_json::Value = serde_json::from_str(text)?;
    let to_mm = match doc.get("units").and_then(|u| u.as_str()) {
        None | Some("mm") => 1.0,
        Some("m") => 1000.0,
        Some(u) => bail!("units {u:?}: expected \"mm\" or \"m\""),
    };
    if let Some(frame) = doc.get("frame_id").and_then(|f| f.as_str())
        && frame != binpick::SCANNER_FRAME_ID
    {
        bail!(
            "its poses are in frame {frame:?}; check needs them in the scanner's (write the \
             result without --scanner-to-base)"
        );
    }
    let (key, label) = if doc.get("detections").is_some() {
        ("detections", "detection")
    } else if doc.get("instances").is_some() {
        ("instances", "instance")
    } else {
        bail!("expected a result JSON (\"detections\") or a ground-truth JSON (\"instances\")");
    };
    let Some(entries) = doc[key].as_array() else {
        bail!("{key:?} is not an array");
    };
    entries
        .iter()
        .enumerate()
        .map(|(k, e)| {
            let numbers: Option<Vec<f64>> = e
                .get("pose")
                .and_then(|p| p.as_array())
                .and_then(|p| p.iter().map(serde_json::Value::as_f64).collect());
            let Some(numbers) = numbers else {
                bail!("{label} {k}: no \"pose\" of numbers");
            };
            let pose = row_major(&numbers, to_mm).with_context(|| format!("{label} {k}"))?;
            // A result's detections are known by their rank (1 first).
            let name = match e.get("rank").and_then(|r| r.as_u64()) {
                Some(rank) => format!("{}: rank {rank}", file_name(path)),
                None => format!("{}: {label} {k}", file_name(path)),
            };
            Ok(Given { source: name, pose })
        })
        .collect()
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// One row per pose: where it ends up, what the view says, and the verdict.
fn print_checks(
    out: &mut impl std::io::Write,
    given: &[Given],
    checks: &[PoseCheck],
) -> std::io::Result<()> {
    let w = given
        .iter()
        .map(|g| g.source.len())
        .max()
        .unwrap_or(0)
        .max(4);
    writeln!(
        out,
        "{:<w$}  {POSE_HEADER}  {:>6}  {:>5}  {:>7}  {:>9}  {:>6}  verdict",
        "pose", "vis %", "fit", "cover %", "through %", "cells"
    )?;
    for (g, c) in given.iter().zip(checks) {
        let v = &c.view;
        let verdict = c.refusal.as_deref().unwrap_or("accepted");
        writeln!(
            out,
            "{:<w$}  {}  {:>6.1}  {:>5.2}  {:>7.1}  {:>9.1}  {:>6}  {verdict}",
            g.source,
            pose_cells(&c.pose),
            100.0 * v.visibility,
            v.fit,
            100.0 * v.covered,
            100.0 * v.free_space,
            c.explained_cells,
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn poses_are_read_from_text_result_and_ground_truth_files() {
        let dir = tempfile::tempdir().unwrap();
        let row = "1 0 0 10, 0 1 0 20, 0 0 1 30, 0 0 0 1";
        let text = dir.path().join("poses.txt");
        std::fs::write(&text, format!("# taught\n{row}\n\n{row} # again\n")).unwrap();
        let p = read_poses(&text).unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!(p[1].source, "poses.txt:4");
        assert_eq!(p[0].pose.translation.vector.z, 30.0);

        let gt = dir.path().join("gt.json");
        std::fs::write(
            &gt,
            r#"{"units": "m", "instances": [{"pose": [1,0,0,0.01, 0,1,0,0.02, 0,0,1,0.03, 0,0,0,1]}]}"#,
        )
        .unwrap();
        let p = read_poses(&gt).unwrap();
        assert_eq!(p[0].source, "gt.json: instance 0");
        assert!((p[0].pose.translation.vector.y - 20.0).abs() < 1e-9);

        let result = dir.path().join("r.json");
        std::fs::write(
            &result,
            r#"{"frame_id": "scanner", "units": "mm", "detections": [{"rank": 1, "pose": [1,0,0,1, 0,1,0,2, 0,0,1,3, 0,0,0,1]}]}"#,
        )
        .unwrap();
        assert_eq!(read_poses(&result).unwrap()[0].source, "r.json: rank 1");
    }

    #[test]
    fn bad_pose_files_are_refused_with_what_is_wrong() {
        let dir = tempfile::tempdir().unwrap();
        let err = |name: &str, body: &str| {
            let path = dir.path().join(name);
            std::fs::write(&path, body).unwrap();
            format!("{:#}", read_poses(&path).err().unwrap())
        };
        let e = err("short.txt", "1 0 0 0 1 0\n");
        assert!(
            e.contains("short.txt") && e.contains("line 1") && e.contains("got 6"),
            "{e}"
        );
        let e = err("word.txt", "1 0 0 x 0 1 0 0 0 0 1 0 0 0 0 1\n");
        assert!(e.contains("\"x\" is not a number"), "{e}");
        let e = err("skew.txt", "1 1 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n");
        assert!(e.contains("rotation"), "{e}");
        let e = err("empty.txt", "# nothing\n");
        assert!(e.contains("holds no pose"), "{e}");
        let e = err(
            "base.json",
            r#"{"frame_id": "base", "detections": [{"pose": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}]}"#,
        );
        assert!(e.contains("frame \"base\""), "{e}");
        let e = err("other.json", r#"{"poses": []}"#);
        assert!(e.contains("expected a result JSON"), "{e}");
        let e = err("feet.json", r#"{"units": "ft", "instances": []}"#);
        assert!(e.contains("\"ft\""), "{e}");
        assert!(parse_pose("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1").is_ok());
    }
}
