//! `binpick synth`: generate a thesis-like dataset, or the generalisation benchmark, with
//! ground truth.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use binpick_synth::{
    BenchmarkOptions, BenchmarkSummary, Preset, SynthOptions, generate, generate_generalisation,
};

use crate::progress::Progress;

/// What to generate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SynthPreset {
    Thesis(Preset),
    Generalisation,
}

impl std::str::FromStr for SynthPreset {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "generalisation" | "generalization" => Ok(SynthPreset::Generalisation),
            other => other
                .parse::<Preset>()
                .map(SynthPreset::Thesis)
                .map_err(|_| {
                    format!(
                        "unknown preset {other:?}: expected \"thesis-conveyor\", \"thesis-arm\", \
                     \"tiny\" or \"generalisation\""
                    )
                }),
        }
    }
}

#[derive(clap::Args)]
pub struct Args {
    /// thesis-conveyor (90 scans, thesis 5.1.2.1), thesis-arm (100 scans, 5.1.2.2), tiny, or
    /// generalisation (9 sets x 10 scans of part families and sensors nobody tuned for: Z
    /// brackets, bent rods, stepped shafts, rings, bent plates; belts at 0.5 / 1 mm, bins at
    /// 2 mm, a depth camera; each DIR/<set> is a dataset for `binpick eval`).
    pub preset: SynthPreset,
    /// Output folder (created; layout in README "Dataset format").
    #[arg(long)]
    pub out: PathBuf,
    /// Random seed: the same seed gives byte-identical files.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Scans per group (thesis presets) or per set (generalisation) instead of the preset's.
    #[arg(long, visible_alias = "scenes-per-set")]
    pub scenes_per_group: Option<usize>,
    /// Belt-level samples per scan instead of the preset's (thesis presets only).
    #[arg(long)]
    pub points: Option<usize>,
    /// generalisation: only these sets (comma-separated names, e.g. brackets-bin-depth).
    #[arg(long, value_delimiter = ',', value_name = "SET,...")]
    pub sets: Vec<String>,
    /// generalisation: also write each depth-camera set in BOP's format under DIR/<set>/bop
    /// (16-bit depth PNGs, cam_K, scene_gt.json, PLY meshes) for `binpick eval DIR/<set>/bop`.
    #[arg(long)]
    pub bop: bool,
}

fn progress_fn(progress: &std::sync::Mutex<Option<Progress>>) -> impl Fn(usize, usize) + Sync + '_ {
    move |done, total| {
        if let Ok(mut p) = progress.lock() {
            p.get_or_insert_with(|| Progress::new(total, "synth"))
                .step(done, "");
        }
    }
}

pub fn run(a: Args) -> Result<()> {
    let progress = std::sync::Mutex::new(None::<Progress>);
    let preset = match a.preset {
        SynthPreset::Thesis(_) if a.bop || !a.sets.is_empty() => {
            bail!("--bop and --sets apply to the generalisation benchmark only")
        }
        SynthPreset::Thesis(p) => p,
        SynthPreset::Generalisation => {
            if a.points.is_some() {
                bail!(
                    "--points applies to the thesis presets only; the generalisation sets fix \
                     each sensor's sampling"
                );
            }
            let opts = BenchmarkOptions {
                out_dir: a.out.clone(),
                seed: a.seed,
                scenes_per_set: a.scenes_per_group,
                sets: a.sets.clone(),
                bop: a.bop,
            };
            let summary = generate_generalisation(&opts, &progress_fn(&progress))
                .with_context(|| format!("cannot generate {}", a.out.display()))?;
            if let Ok(Some(p)) = progress.lock().as_deref() {
                p.finish();
            }
            print_benchmark(&summary);
            return Ok(());
        }
    };
    let opts = SynthOptions {
        preset,
        out_dir: a.out.clone(),
        seed: a.seed,
        scenes_per_group: a.scenes_per_group,
        points_target: a.points,
    };
    let summary = generate(&opts, &progress_fn(&progress))
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
    tracing::info!(
        "physics {:.0} s, scanning {:.0} s (summed over threads)",
        summary.physics_s,
        summary.scan_s
    );
    Ok(())
}

/// One line per set: what it holds and how to evaluate it.
fn print_benchmark(s: &BenchmarkSummary) {
    println!(
        "{:<26} {:>7} {:<12} {:<4} {:>8} {:>6} {:>9} {:>9} {:>13}",
        "set", "model", "sensor", "env", "spacing", "scans", "parts", "points", "pickable/inst"
    );
    for set in &s.sets {
        println!(
            "{:<26} {:>7} {:<12} {:<4} {:>5.2} mm {:>6} {:>9} {:>8}k {:>13}",
            set.name,
            set.target_model,
            set.sensor,
            set.environment,
            set.sample_spacing_mm,
            set.scenes,
            format!("{}-{}", set.parts_per_scan[0], set.parts_per_scan[1]),
            set.points_per_scan[1] / 1000,
            format!("{}/{}", set.target_pickable, set.target_instances),
        );
    }
    println!(
        "{}: {} sets, {} scans, {:.0} s; evaluate a set with `binpick eval {}/<set> --model <model>`",
        s.out_dir.display(),
        s.sets.len(),
        s.scenes,
        s.elapsed_s,
        s.out_dir.display()
    );
    tracing::info!(
        "physics {:.0} s, scanning and ground truth {:.0} s (summed over threads)",
        s.physics_s,
        s.scan_s
    );
}
