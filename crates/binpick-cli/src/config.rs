//! Building the parameters from a preset, a TOML file and command-line flags, in that order.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use binpick::{Algorithm, Params, Preset, Units};

/// Parameter options shared by every command that recognises.
#[derive(clap::Args, Clone, Debug)]
pub struct ParamArgs {
    /// Base configuration: thesis (4.3 defaults), A, B, C1, C2, C3 (conveyor, 5.5.1),
    /// arm-A, arm-C (robot arm, 5.6.1).
    #[arg(long, default_value = "thesis")]
    pub preset: Preset,
    /// TOML file whose keys override the preset (see README "Parameters").
    #[arg(long, value_name = "params.toml")]
    pub config: Option<PathBuf>,
    /// Initial-alignment algorithm: 1 (separated FPFH, thesis 4.1) or 2 (merged, 4.2).
    #[arg(long)]
    pub algorithm: Option<Algorithm>,
    /// Units of the input clouds: mm or m (scaled to mm on load).
    #[arg(long)]
    pub units: Option<Units>,
    /// Units of the model cloud if they differ from --units.
    #[arg(long)]
    pub model_units: Option<Units>,
    /// Worker threads (0 = all cores). Results do not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Time budget per scene, milliseconds; exceeding it is an error.
    #[arg(long, value_name = "MS")]
    pub time_budget_ms: Option<u64>,
    /// Run the thesis exactly: one part per cluster, no duplicate suppression.
    #[arg(long)]
    pub thesis_strict: bool,
}

impl ParamArgs {
    /// Preset, then the config file, then flags; validated.
    pub fn params(&self) -> Result<Params> {
        let mut p = self.preset.params();
        if let Some(path) = &self.config {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read config {}", path.display()))?;
            p = Params::from_toml_over(&p, &text)
                .with_context(|| format!("config {}", path.display()))?;
        }
        if let Some(a) = self.algorithm {
            p.algorithm = a;
        }
        if let Some(u) = self.units {
            p.units = u;
        }
        if let Some(t) = self.threads {
            p.runtime.threads = t;
        }
        if self.time_budget_ms.is_some() {
            p.runtime.time_budget_ms = self.time_budget_ms;
        }
        if self.thesis_strict {
            p.thesis_strict = true;
        }
        p.validate()?;
        Ok(p)
    }

    pub fn model_units(&self, params: &Params) -> Units {
        self.model_units.unwrap_or(params.units)
    }
}

/// Loads a cloud, converts it to mm and logs what loading did.
pub fn load(path: &Path, units: Units, what: &str) -> Result<binpick::PointCloud> {
    let (cloud, report) =
        binpick::load_cloud(path, units).with_context(|| format!("cannot load the {what}"))?;
    let dropped = if report.non_finite_dropped > 0 {
        format!(", {} NaN points dropped", report.non_finite_dropped)
    } else {
        String::new()
    };
    let scaled = if units == Units::Millimetres {
        String::new()
    } else {
        format!(", scaled from {units} to mm")
    };
    log(&format!(
        "{what} {}: {} points{dropped}{scaled}",
        path.display(),
        cloud.len()
    ));
    Ok(cloud)
}

/// A log line on stderr.
pub fn log(msg: &str) {
    eprintln!("binpick: {msg}");
}

/// Writes `params` as TOML next to an output file: `out.json` -> `out.params.toml`.
pub fn write_params_next_to(output: &Path, params: &Params) -> Result<PathBuf> {
    let stem = output
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "binpick".into());
    let path = output.with_file_name(format!("{stem}.params.toml"));
    write_params(&path, params)?;
    Ok(path)
}

/// Writes `params` as a TOML config that `--config` reads back.
pub fn write_params(path: &Path, params: &Params) -> Result<()> {
    std::fs::write(
        path,
        format!(
            "# Parameters used by binpick (units: mm)\n{}",
            params.to_toml()
        ),
    )
    .with_context(|| format!("cannot write {}", path.display()))
}

/// Writes pretty JSON, creating parent folders.
pub fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {}", parent.display()))?;
    }
    let text = serde_json::to_string_pretty(value)?;
    std::fs::write(path, text + "\n").with_context(|| format!("cannot write {}", path.display()))
}
