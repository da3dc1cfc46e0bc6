//! Deterministic generator of thesis-like bin-picking scans with ground truth.
//!
//! It reproduces the datasets of "Robot bin picking: 3D pose retrieval based on Point Cloud
//! Library" (5.1), whose scans are not public:
//!
//! - [`parts`]: the parts A (sheet bent 90 deg), B (sheet bent 20 deg) and C (pipe bent
//!   twice) as exact triangle meshes with convex-hull colliders, plus their "cut" variants,
//!   and five families nobody tuned for (Z bracket, bent rod, stepped shaft, flat ring, bent
//!   plate) with their true symmetry groups;
//! - [`physics`]: piles made with rapier3d - parts dropped one by one onto a belt, a floor or
//!   into a bin, simulated until at rest;
//! - [`scanner`]: the dual-laser / single-camera triangulation scanner (thesis 2.2), simulated
//!   by ray casting with parry3d: laser shadows and camera occlusion, range noise, outliers;
//! - [`depth`]: a structured-light depth camera seen in perspective; [`sensor`] puts both
//!   sensors behind one interface (scan a scene, scan one part alone, viewpoint);
//! - [`models`]: model clouds (the top view of the isolated part in its canonical pose) and
//!   ground truth (pose, visible fraction, pickable);
//! - [`plan`](mod@plan) / [`generate`](mod@generate): the presets `thesis-conveyor`,
//!   `thesis-arm` and `tiny` and the dataset writer (layout in [`binpick_cloud::dataset`]);
//! - [`generalisation`]: the generalisation benchmark (sets of the new families on belts, in
//!   bins and under a depth camera, with BOP's visible fraction); [`bop`] writes its
//!   depth-camera sets in BOP's format too.
//!
//! Everything is in millimetres; the scene frame has z up (belt/floor at z = 0), x across the
//! belt and y along the motion. Same seed -> byte-identical files, whatever the thread count.
//!
//! ```no_run
//! use binpick_synth::{Preset, SynthOptions, generate};
//! let opts = SynthOptions {
//!     preset: Preset::Tiny,
//!     out_dir: "out/tiny".into(),
//!     seed: 1,
//!     scenes_per_group: None,
//!     points_target: None,
//! };
//! let summary = generate(&opts, &|done, total| eprintln!("{done}/{total}"))?;
//! println!("{} scenes", summary.scenes);
//! # Ok::<(), binpick_synth::SynthError>(())
//! ```

pub mod bop;
pub mod depth;
pub mod generalisation;
pub mod generate;
pub mod mesh;
pub mod models;
pub mod parts;
pub mod physics;
pub mod plan;
pub mod rng;
pub mod scanner;
pub mod sensor;

pub use depth::DepthCameraConfig;
pub use generalisation::{
    BenchmarkOptions, BenchmarkSummary, SetScene, SetSpec, SetSummary, generalisation_sets,
    generate_generalisation, make_set_scene,
};
pub use generate::{
    SceneRequest, Summary, SynthOptions, SynthScene, generate, make_scene, scan_instances,
    visibility_radius,
};
pub use models::{Model, ModelLibrary};
pub use parts::{Part, PartKind, PartLibrary};
pub use physics::{Environment, Instance, Pile};
pub use plan::{GroupPlan, Layout, Preset, plan};
pub use scanner::{BACKGROUND, OUTLIER, Scan, ScannerConfig, SceneGeometry, scan, scan_scene};
pub use sensor::{Sensor, Viewpoint};

use std::path::PathBuf;

/// Version of the generator's output; bump when the same seed would give different files.
pub const GENERATOR_VERSION: &str = concat!(env!("CARGO_PKG_VERSION"), "+synth.2");

/// Error generating a dataset.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Cloud(#[from] binpick_cloud::io::IoError),
    #[error(transparent)]
    Dataset(#[from] binpick_cloud::dataset::DatasetError),
    #[error("geometry: {0}")]
    Geometry(String),
    #[error("invalid options: {0}")]
    InvalidOptions(String),
}
