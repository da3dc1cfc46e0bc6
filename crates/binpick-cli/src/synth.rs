//! `binpick synth`: generate a thesis-like dataset with ground truth.

use std::path::PathBuf;

use anyhow::{Context, Result};
use binpick_synth::{Preset, SynthOptions, generate};

use crate::config::log;
use crate::progress::Progress;

#[derive(clap::Args)]
pub struct Args {
    /// thesis-conveyor (90 scans, thesis 5.1.2.1), thesis-arm (100 scans, 5.1.2.2) or tiny.
    pub preset: Preset,
    /// Output dataset folder (created; layout in README "Dataset format").
    #[arg(long)]
    pub out: PathBuf,
    /// Random seed: the same seed gives byte-identical files.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Scans per group instead of the preset's (for quick runs).
    #[arg(long)]
    pub scenes_per_group: Option<usize>,
    /// Belt-level samples per scan instead of the preset's.
    #[arg(long)]
    pub points: Option<usize>,
}

pub fn run(a: Args) -> Result<()> {
    let opts = SynthOptions {
        preset: a.preset,
        out_dir: a.out.clone(),
        seed: a.seed,
        scenes_per_group: a.scenes_per_group,
        points_target: a.points,
    };
    let progress = std::sync::Mutex::new(None::<Progress>);
    let summary = generate(&opts, &|done, total| {
        if let Ok(mut p) = progress.lock() {
            p.get_or_insert_with(|| Progress::new(total, "synth"))
                .step(done, "");
        }
    })
    .with_context(|| format!("cannot generate {}", a.out.display()))?;
    if let Ok(Some(p)) = progress.lock().as_deref() {
        p.finish();
    }
    println!(
        "{}: {} scenes, {} ground-truth files, {} instances ({} pickable), {:.1} M points, {:.0} s",
        summary.out_dir.display(),
        summary.scenes,
        summary.gt_files,
        summary.instances,
        summary.pickable,
        summary.total_points as f64 / 1e6,
        summary.elapsed_s
    );
    log(&format!(
        "physics {:.0} s, scanning {:.0} s (summed over threads)",
        summary.physics_s, summary.scan_s
    ));
    Ok(())
}
