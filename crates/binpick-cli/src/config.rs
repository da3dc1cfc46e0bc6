//! Building the parameters from a preset, a TOML file and command-line flags, in that order.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use binpick::{Algorithm, Params, Preset, Units};

/// The engines a command can run.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum EngineArg {
    SceneVoting,
    Thesis,
    Reference,
}

/// Parameter options shared by every command that recognises.
#[derive(clap::Args, Clone, Debug)]
pub struct ParamArgs {
    /// Base configuration. Without one, every length is derived from the model's diameter and
    /// the scan's point spacing. The thesis's absolute settings: thesis (4.3 defaults), A, B,
    /// C1, C2, C3 (conveyor, 5.5.1), arm-A, arm-C (robot arm, 5.6.1).
    #[arg(long)]
    pub preset: Option<Preset>,
    /// Which engine finds the parts: scene-voting (default: point-pair voting over the whole
    /// scene, verified against the sensor's view), thesis (Algorithms 1/2 per cluster), or
    /// reference (the thesis's Algorithms 1/2 written directly in C++ against PCL; always
    /// thesis-exact). `--algorithm` and `--thesis-strict` imply thesis.
    #[arg(long, value_enum)]
    pub engine: Option<EngineArg>,
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
    /// Time budget per scene, milliseconds. When it runs out the parts verified so far are
    /// returned (and written) and the command exits with code 3.
    #[arg(long, value_name = "MS")]
    pub time_budget_ms: Option<u64>,
    /// Run the thesis exactly: one part per cluster, no duplicate suppression.
    #[arg(long)]
    pub thesis_strict: bool,
}

impl ParamArgs {
    /// Preset, then the config file, then flags; validated.
    pub fn params(&self) -> Result<Params> {
        let mut p = self.preset.map_or_else(Params::default, Preset::params);
        if let Some(path) = &self.config {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read config {}", path.display()))?;
            p = Params::from_toml_over(&p, &text)
                .with_context(|| format!("config {}", path.display()))?;
        }
        if let Some(a) = self.algorithm {
            p.algorithm = a;
            p.engine = binpick::Engine::Thesis;
        }
        match self.engine {
            Some(EngineArg::SceneVoting) => p.engine = binpick::Engine::SceneVoting,
            Some(EngineArg::Thesis) => p.engine = binpick::Engine::Thesis,
            Some(EngineArg::Reference) => {
                p.engine = binpick::Engine::Thesis;
                p.thesis_strict = true;
            }
            None => {}
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
            p.engine = binpick::Engine::Thesis;
        }
        p.validate()?;
        Ok(p)
    }

    /// Whether the C++ reference pipeline was asked for.
    pub fn reference(&self) -> bool {
        self.engine == Some(EngineArg::Reference)
    }

    /// The preset's name, or "auto" without one.
    pub fn preset_name(&self) -> &'static str {
        self.preset.map_or("auto", |p| p.name())
    }

    pub fn model_units(&self, params: &Params) -> Units {
        self.model_units.unwrap_or(params.units)
    }
}

/// One part model and one scan, with the parameters: what `recognize` and `check` read.
#[derive(clap::Args, Clone, Debug)]
pub struct PartAndScan {
    /// Part model in its own frame: a scanned cloud (.pcd, .ply without faces) or a CAD mesh
    /// (.stl, .obj, .ply with faces); symmetries in `<model>.json` beside it (README).
    #[arg(long)]
    pub model: PathBuf,
    /// Scene cloud (.pcd or .ply).
    #[arg(long)]
    pub scene: PathBuf,
    #[command(flatten)]
    pub params: ParamArgs,
}

/// A scan loaded in mm and where its sensor was (mm), when its file says.
pub type LoadedScan = (binpick::PointCloud, Option<[f64; 3]>);

impl PartAndScan {
    /// The part (in the model's units) and the scan (in `params.units`), both in mm.
    pub fn load(&self, params: &Params) -> Result<(binpick::Part, LoadedScan)> {
        let part = load_part(&self.model, self.params.model_units(params), params)?;
        Ok((part, load_scene(&self.scene, params.units)?))
    }
}

/// Loads a scan, converts it to mm and logs what loading did; also returns where its sensor
/// was (mm), when the file says so (a PCD `VIEWPOINT` other than PCL's default).
pub fn load_scene(path: &Path, units: Units) -> Result<(binpick::PointCloud, Option<[f64; 3]>)> {
    let (cloud, report) = binpick::load_cloud(path, units).context("cannot load the scene")?;
    log_loaded(path, units, "scene", &cloud, &report);
    let seen_from = binpick::sensor_position(&report, units);
    if let Some(v) = seen_from {
        let why = if report.sensor_viewpoint().is_some() {
            "the file's VIEWPOINT"
        } else {
            "an organised cloud, in its camera's frame"
        };
        tracing::info!(
            "scene sensor at ({:.0}, {:.0}, {:.0}) mm ({why})",
            v[0],
            v[1],
            v[2]
        );
    }
    Ok((cloud, seen_from))
}

/// Loads a cloud, converts it to mm and logs what loading did.
pub fn load(path: &Path, units: Units, what: &str) -> Result<binpick::PointCloud> {
    let (cloud, report) =
        binpick::load_cloud(path, units).with_context(|| format!("cannot load the {what}"))?;
    log_loaded(path, units, what, &cloud, &report);
    Ok(cloud)
}

fn log_loaded(
    path: &Path,
    units: Units,
    what: &str,
    cloud: &binpick::PointCloud,
    report: &binpick_cloud::io::LoadReport,
) {
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
    tracing::info!(
        "{what} {}: {} points{dropped}{scaled}",
        path.display(),
        cloud.len()
    );
}

/// Loads a part model (cloud or mesh, plus its sidecar), converts it to mm and logs it.
pub fn load_part(path: &Path, units: Units, params: &Params) -> Result<binpick::Part> {
    let (part, report) = binpick::load_part(path, units, params)
        .with_context(|| format!("cannot load the model {}", path.display()))?;
    let kind = if report.mesh {
        format!("mesh sampled at {} points", report.points)
    } else {
        format!("scan of {} points", report.points)
    };
    let seen = report.viewpoint.map_or(String::new(), |(v, from)| {
        format!(
            ", scanned from ({:.0}, {:.0}, {:.0}) mm ({from})",
            v[0], v[1], v[2]
        )
    });
    let sym = report.sidecar.as_ref().map_or(String::new(), |s| {
        format!(", {} symmetries from {}", report.symmetries, s.display())
    });
    tracing::info!(
        "model {}: {kind}, diameter {:.1} mm{seen}{sym}",
        path.display(),
        part.size.diameter_mm
    );
    Ok(part)
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

/// BOP results CSV output (`--bop-csv`) and the ids its rows carry.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct BopArgs {
    /// Also write the detections in BOP's results format (scene_id,im_id,obj_id,score,R,t,time;
    /// R row-major 3x3, t in mm, model -> scan frame; score = estimated visible fraction, or
    /// 1 - outlier share with the thesis engine; time in s).
    #[arg(long, value_name = "FILE.csv")]
    pub bop_csv: Option<PathBuf>,
    /// BOP object id written in the CSV.
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub bop_obj_id: u32,
    /// BOP scene id written in the CSV.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub bop_scene_id: u32,
}

impl BopArgs {
    /// The ids of a scan: its image id is the number its file stem spells (BOP names images
    /// `000042.png`), else `index`.
    pub fn ids_for(&self, scan: &Path, index: usize) -> binpick_eval::bop::BopIds {
        let im_id = scan
            .file_stem()
            .and_then(|s| s.to_str())
            .filter(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()))
            .and_then(|s| s.parse().ok())
            .unwrap_or(index as u32);
        binpick_eval::bop::BopIds {
            scene_id: self.bop_scene_id,
            im_id,
            obj_id: self.bop_obj_id,
        }
    }
}

/// Writes a text file, creating parent folders.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {}", parent.display()))?;
    }
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
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

/// The frame output poses are given in (`--scanner-to-base`, `--frame-id`).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct FrameArgs {
    /// Give every output pose (ranked table, JSON poses and grasps) in the robot's base
    /// frame: the scanner -> base transform as a row-major 4x4 in mm ("16 numbers", commas
    /// or spaces), or a .toml/.json file with `scanner_to_base` (16 numbers or 4 rows of 4)
    /// and optionally `frame_id` (README "Frames and grasps"). Pictures and the BOP CSV stay
    /// in the scanner's frame.
    #[arg(long, value_name = "4x4|FILE", allow_hyphen_values = true)]
    pub scanner_to_base: Option<String>,
    /// Name of that frame in the output (`frame_id`); default the file's `frame_id`, else
    /// "base".
    #[arg(long, value_name = "NAME", requires = "scanner_to_base")]
    pub frame_id: Option<String>,
}

impl FrameArgs {
    /// The output frame, None for the scanner's own.
    pub fn frame(&self) -> Result<Option<binpick::OutputFrame>> {
        let Some(value) = &self.scanner_to_base else {
            return Ok(None);
        };
        let path = Path::new(value);
        let frame = if path.is_file() {
            binpick::OutputFrame::read(path)
        } else {
            binpick::OutputFrame::parse_matrix(value)
        }
        .with_context(|| {
            format!("--scanner-to-base {value:?} (16 numbers, or a .toml/.json file that exists)")
        })?;
        Ok(Some(match &self.frame_id {
            Some(name) => frame.named(name).context("--frame-id")?,
            None => frame,
        }))
    }
}
