//! Pictures for the CLI: `recognize --png/--ply`, `show`, `eval --plots` (rendering in
//! binpick-viz).

use std::path::Path;

use anyhow::{Context, Result};
use binpick::{Detection, PointCloud};
use binpick_eval::{EvalRun, ThesisTable, thesis_reference};
use binpick_viz::{BarChart, Percents, Placed, PlotOptions, RenderOptions, Seen, TableRow};
use serde::{Deserialize, Serialize};

/// Detections as the renderer wants them.
pub fn placed(detections: &[Detection]) -> Result<Vec<Placed>> {
    detections
        .iter()
        .map(|d| {
            Ok(Placed {
                rank: d.rank,
                pose: d.pose,
                final_score: d.final_score,
                initial_score: d.initial_score,
                seen: d.view.as_ref().map(|v| Seen {
                    visibility: v.visibility,
                    fit: v.fit,
                }),
                free_to_pick: d.free_to_pick,
            })
        })
        .collect()
}

/// Renders the scanner view and an oblique view with every detection overlaid.
pub fn render(
    scene: &PointCloud,
    model: &PointCloud,
    detections: &[Detection],
    up: [f64; 3],
    title: String,
    out: &Path,
) -> Result<()> {
    let opts = RenderOptions {
        up,
        title: Some(title),
        ..RenderOptions::default()
    };
    let info = binpick_viz::render_png(scene, model, &placed(detections)?, &opts, out)
        .with_context(|| format!("cannot render {}", out.display()))?;
    tracing::info!(
        "wrote {} ({}x{} px)",
        out.display(),
        opts.width,
        opts.height
    );
    let _ = info;
    Ok(())
}

/// Writes the scene coloured by which detection explains each point, plus the placed models.
pub fn labelled_ply(
    scene: &PointCloud,
    model: &PointCloud,
    detections: &[Detection],
    explain_mm: f64,
    out: &Path,
) -> Result<()> {
    let info = binpick_viz::write_labelled_ply(scene, model, &placed(detections)?, explain_mm, out)
        .with_context(|| format!("cannot write {}", out.display()))?;
    tracing::info!(
        "wrote {}: {} scene points explained by detections ({:?} per rank), {} unexplained",
        out.display(),
        info.explained.iter().sum::<usize>(),
        info.explained,
        info.unexplained
    );
    Ok(())
}

/// One configuration's table, kept in `DIR/tables.json` so that evaluating several
/// configurations into the same plots folder draws them side by side.
#[derive(Serialize, Deserialize)]
struct StoredTable {
    config: String,
    table: ThesisTable,
}

fn to_percents(p: binpick_eval::ThesisPercents) -> Percents {
    Percents {
        recognition: p.recognition,
        false_negatives: p.false_negatives,
        false_positives: p.files_with_false_positive,
        unpickable: p.files_with_unpickable,
        false_best: p.false_best,
        starvation: p.starvation,
    }
}

/// `eval --plots DIR`: the thesis table chart (all configurations evaluated into DIR) and this
/// run's time histogram.
pub fn eval_plots(dir: &Path, preset: &str, run: &EvalRun) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let store = dir.join("tables.json");
    let mut tables: Vec<StoredTable> = match std::fs::read_to_string(&store) {
        Ok(text) => serde_json::from_str(&text)
            .with_context(|| format!("{} is not a binpick plot table", store.display()))?,
        Err(_) => Vec::new(),
    };
    tables.retain(|t| t.config != preset);
    tables.push(StoredTable {
        config: preset.to_owned(),
        table: run.table.clone(),
    });
    let order = |c: &str| {
        ["A", "B", "C1", "C2", "C3", "arm-A", "arm-C", "thesis"]
            .iter()
            .position(|x| *x == c)
            .unwrap_or(99)
    };
    tables.sort_by_key(|t| (order(&t.config), t.config.clone()));
    crate::config::write_json(&store, &tables)?;
    let rows: Vec<TableRow> = tables
        .iter()
        .map(|t| TableRow {
            config: t.config.clone(),
            files: t.table.files,
            pickable: t.table.pickable,
            recognised: t.table.recognised,
            false_negatives: t.table.false_negatives,
            files_with_fp: t.table.files_with_false_positive,
            files_with_unpickable: t.table.files_with_unpickable,
            false_best: t.table.false_best,
            starvation: t.table.starvation,
            // The thesis's numbers from their one place in the library (moved to
            // binpick-eval later).
            reference: thesis_reference(&t.config).map(to_percents),
        })
        .collect();
    let table_png = dir.join("thesis-table.png");
    let mut chart = BarChart::thesis_table(&rows);
    chart.reference_name = "thesis (5.5.2, 5.6.2)".into();
    binpick_viz::plot_bar_chart(
        &chart,
        &PlotOptions {
            width: 1400,
            height: 700,
            title: Some(
                "binpick vs thesis (5.5.2, 5.6.2): bars = ours, black marks = thesis".into(),
            ),
        },
        &table_png,
    )
    .with_context(|| format!("cannot draw {}", table_png.display()))?;
    let hist = dir.join(format!("times-{preset}.png"));
    binpick_viz::plot_time_histogram(
        &run.times_ms,
        &PlotOptions {
            width: 1000,
            height: 500,
            title: Some(format!(
                "time per scene, preset {preset}, model {} (ms)",
                run.model
            )),
        },
        &hist,
    )
    .with_context(|| format!("cannot draw {}", hist.display()))?;
    tracing::info!("wrote {} and {}", table_png.display(), hist.display());
    Ok(())
}
