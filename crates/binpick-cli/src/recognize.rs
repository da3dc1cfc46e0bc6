//! `binpick recognize`: one model, one scene, ranked picks.

use std::path::PathBuf;

use anyhow::{Context, Result};
use binpick::{RecognitionReport, Recognizer};

use std::io::Write;

use crate::Done;
use crate::config::{
    BopArgs, FrameArgs, PartAndScan, write_json, write_params_next_to, write_text,
};
use crate::table::{print_ranked, summary};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub input: PartAndScan,
    /// Write the result as JSON (schema/result.schema.json); the parameters go next to it as
    /// out.params.toml. `--json -` writes the JSON to stdout instead, and the ranked table
    /// then goes to stderr (the parameters are inside the JSON).
    #[arg(long, value_name = "out.json")]
    pub json: Option<PathBuf>,
    #[command(flatten)]
    pub bop: BopArgs,
    #[command(flatten)]
    pub frame: FrameArgs,
    /// Render the result as PNG: scanner view and oblique view, detections in their poses,
    /// labelled with their rank.
    #[arg(long, value_name = "out.png")]
    pub png: Option<PathBuf>,
    /// Write a PLY: the scene coloured by which detection explains each point, plus the
    /// placed models (for CloudCompare or MeshLab).
    #[arg(long, value_name = "out.ply")]
    pub ply: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<Done> {
    let params = a.input.params.params()?;
    let frame = a.frame.frame()?;
    let (part, (scene, seen_from)) = a.input.load(&params)?;
    let engine = if a.input.params.reference() {
        "reference"
    } else {
        params.stages().engine.name()
    };
    let spinner = crate::logging::Spinner::start(&format!(
        "recognising {}",
        a.input.scene.file_name().map_or_else(
            || a.input.scene.display().to_string(),
            |n| n.to_string_lossy().into_owned()
        )
    ));
    let result = if a.input.params.reference() {
        tracing::info!(
            "reference engine: thesis Algorithms 1/2 in C++ against PCL, one part per cluster"
        );
        binpick::reference::recognize_reference(&part.cloud, &scene, &params)
            .context("reference recognition failed")?
    } else {
        let recognizer = Recognizer::with_part(part.clone(), params.clone())
            .context("cannot prepare the model")?;
        if let Some(m) = recognizer.model() {
            tracing::info!(
                "model prepared in {:.0} ms: {} points, {} keypoints, {} FPFH radii, diameter {:.1} mm; {} thread(s)",
                recognizer_prep_ms(&recognizer),
                m.cloud.len(),
                m.initial_keypoints.len(),
                m.features.len(),
                m.diameter_mm,
                recognizer.threads()
            );
        }
        let r = recognizer
            .recognize_seen_from(&scene, seen_from)
            .context("recognition failed")?;
        if let Some(s) = &r.scale {
            tracing::info!("derived: {}", s.summary());
        }
        r
    };
    drop(spinner);
    tracing::info!("{}", summary(&result));
    if let Some(why) = &result.interrupted {
        tracing::warn!(
            "{why}: the {} part(s) below were verified before that; the search is incomplete",
            result.detections.len()
        );
    }
    if let Some(v) = &result.voting {
        tracing::info!("{}", crate::table::voting_summary(v));
    }
    for c in &result.clusters {
        tracing::info!("cluster {}: {} points: {}", c.index, c.points, c.outcome);
    }
    // Pictures and the BOP CSV are drawn in the scanner's frame (the scan's); the table
    // and the JSON in the output frame.
    let mut scanner_report = RecognitionReport::new(
        &a.input.scene.display().to_string(),
        &a.input.model.display().to_string(),
        engine,
        &params,
        &result,
    );
    scanner_report.model_units = a.input.params.model_units(&params);
    let mut report = scanner_report.clone();
    let mut shown = result;
    if let Some(f) = &frame {
        shown.express_in(f);
        report.express_in(f);
        tracing::info!("poses in frame {:?} (--scanner-to-base)", f.frame_id);
    }
    let json_to_stdout = a.json.as_deref() == Some(std::path::Path::new("-"));
    if json_to_stdout {
        print_ranked(&mut std::io::stderr().lock(), &shown)?;
    } else {
        print_ranked(&mut std::io::stdout().lock(), &shown)?;
    }
    match &a.json {
        Some(_) if json_to_stdout => {
            let text = serde_json::to_string_pretty(&report)?;
            let mut out = std::io::stdout().lock();
            writeln!(out, "{text}").context("cannot write the JSON to stdout")?;
        }
        Some(out) => {
            write_json(out, &report)?;
            let p = write_params_next_to(out, &params)?;
            tracing::info!("wrote {} and {}", out.display(), p.display());
        }
        None => {}
    }
    if let Some(csv) = &a.bop.bop_csv {
        let ids = a.bop.ids_for(&a.input.scene, 0);
        let mut text = String::from(binpick_eval::bop::CSV_HEADER);
        text.push_str(&binpick_eval::bop::csv_rows(
            ids,
            &scanner_report.detections,
            scanner_report.timings_ms.total_ms / 1000.0,
        ));
        write_text(csv, &text)?;
        tracing::info!("wrote {} (BOP results)", csv.display());
    }
    write_pictures(
        &scanner_report,
        &scene,
        &part.cloud,
        a.png.as_deref(),
        a.ply.as_deref(),
    )?;
    Ok(match shown.interrupted {
        Some(_) => Done::BudgetExhausted,
        None => Done::Complete,
    })
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
        // The algorithm number means something to the thesis engines only.
        let how = if report.engine == binpick::Engine::SceneVoting.name() {
            report.engine.clone()
        } else {
            format!("{}, algorithm {}", report.engine, report.algorithm)
        };
        let title = format!("{} in {} ({how})", report.model, report.scene);
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
