//! `binpick model`: prepare a part model once and keep it on disk, so that a controller's
//! first scan does not pay the preparation. Every command that takes `--model` reads the
//! written `*.prepared` file in place of the model file.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use binpick::Recognizer;
use binpick::prepared::{PREPARED_EXTENSION, is_prepared, read_header};

use crate::config::{ParamArgs, load_part, load_scene};

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: ModelCommand,
}

#[derive(clap::Subcommand)]
pub enum ModelCommand {
    /// Print a model's diameter, resolution, point count and the (near-)symmetries found,
    /// with the sidecar that declares its symmetries.
    Inspect(crate::inspect::InspectArgs),
    /// Prepare a model (surface samples, point-pair tables, near-symmetries) and write it to
    /// a `.prepared` file; pass that file as `--model` to recognize, replay or bench. It is
    /// refused with a clear error when the model file, the units, the voting table parameters
    /// or the binpick version differ from when it was written.
    Prepare(PrepareArgs),
    /// Print a prepared model's header (JSON): source, hashes, scales, sizes.
    Info {
        /// A `.prepared` file.
        file: PathBuf,
    },
}

#[derive(clap::Args)]
pub struct PrepareArgs {
    /// Part model: scanned cloud or CAD mesh (as `recognize --model`).
    #[arg(long)]
    pub model: PathBuf,
    /// Example scans from the cell's sensor: the working scale is derived from their point
    /// spacing (one voting model per distinct scale). Without scans, and without
    /// `resolution_mm` in the parameters, only the part itself is stored.
    #[arg(long, num_args = 1..)]
    pub scene: Vec<PathBuf>,
    #[command(flatten)]
    pub params: ParamArgs,
    /// Output file (default: the model's path with the extension `.prepared`).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    match a.command {
        ModelCommand::Inspect(i) => crate::inspect::run(i),
        ModelCommand::Prepare(p) => prepare(p),
        ModelCommand::Info { file } => {
            let header = read_header(&file)?;
            println!("{}", serde_json::to_string_pretty(&header)?);
            Ok(())
        }
    }
}

fn prepare(a: PrepareArgs) -> Result<()> {
    if is_prepared(&a.model) {
        anyhow::bail!(
            "--model {}: already a prepared model; give the model file it came from",
            a.model.display()
        );
    }
    let params = a.params.params()?;
    let units = a.params.model_units(&params);
    let start = Instant::now();
    let part = load_part(&a.model, units, &params)?;
    let recognizer =
        Recognizer::with_part(part, params.clone()).context("cannot prepare the model")?;
    for scene in &a.scene {
        let (cloud, _) = load_scene(scene, params.units)?;
        let scale = recognizer
            .prepare_for(&cloud)
            .with_context(|| format!("cannot prepare the model for {}", scene.display()))?;
        tracing::info!("{}", format!("{}: {}", scene.display(), scale.summary()));
    }
    let out = a
        .out
        .unwrap_or_else(|| a.model.with_extension(PREPARED_EXTENSION));
    let header = recognizer
        .write_prepared(&out, &a.model, units)
        .with_context(|| format!("cannot write {}", out.display()))?;
    tracing::info!(
        "{}",
        format!(
            "wrote {}: {} voting model(s), {} bytes, prepared in {:.0} ms",
            out.display(),
            header.scales.len(),
            header.payload_bytes,
            start.elapsed().as_secs_f64() * 1000.0
        )
    );
    Ok(())
}
