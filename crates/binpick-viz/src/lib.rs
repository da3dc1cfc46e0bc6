//! Pictures of binpick results as files, for headless robot cells and CI (no display, no
//! system fonts: the DejaVu Sans font is embedded).
//!
//! - [`render_png`]: the scene with every detected model overlaid in its pose, seen from the
//!   scanner (orthographic, looking along `-up`) and from an oblique viewpoint, side by side,
//!   with rank labels at the parts, a legend (rank, final score, initial score) and a title.
//! - [`write_labelled_ply`]: one binary PLY with the scene coloured by the detection that
//!   explains each point and the aligned models' points, for CloudCompare or MeshLab.
//! - [`plot_bar_chart`] (and [`plot_thesis_table`] on top of it) and [`plot_time_histogram`]:
//!   charts for `binpick eval --plots`, drawn with `plotters`.
//!
//! Units are millimetres everywhere. Nothing here panics on bad input: empty clouds, absurd
//! image sizes and invalid options are errors; NaN/infinite points are skipped and counted.

mod color;
mod draw;
mod plots;
mod ply;
mod render;

use std::path::PathBuf;

pub use color::{rank_color, score_color};
pub use plots::{
    BAR_COLORS, BarChart, BarGroup, BarMetric, Better, MAX_METRICS, MEDIAN_COLOR, P95_COLOR,
    Percents, PlotOptions, REFERENCE_COLOR, TableRow, TimeStats, plot_bar_chart, plot_thesis_table,
    plot_time_histogram,
};
pub use ply::{MODEL_SHADE, PlyInfo, UNEXPLAINED_GREY, labelled_cloud, write_labelled_ply};
pub use render::{PixelRect, RenderInfo, ViewInfo, render_png};

/// Smallest accepted image edge, in pixels.
pub const MIN_SIZE: u32 = 64;
/// Largest accepted image edge, in pixels.
pub const MAX_SIZE: u32 = 8192;

/// One detection to draw: the model placed in the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Placed {
    /// Pick rank, 1 = best. Labels show it and the rank colours follow it.
    pub rank: usize,
    /// Model frame -> scene frame.
    pub pose: nalgebra::Isometry3<f64>,
    /// Final score: percent of model points that are outliers after ICP (lower = better).
    pub final_score: f64,
    /// Initial (coarse alignment) score.
    pub initial_score: f64,
    /// What the scene-voting engine's view check says of it; `None` for the thesis's
    /// engines. When every detection has it and colours follow the rank, the legend shows
    /// it in place of the scores.
    pub seen: Option<Seen>,
    /// Whether the robot may take it (the result's `free_to_pick`): when the first in rank
    /// is not, nothing is picked and the legend says so.
    pub free_to_pick: bool,
}

/// A detection's view check (scene-voting engine), as the legend shows it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Seen {
    /// Share of the surface the sensor would see of the part alone that the scan confirms,
    /// 0-1 (higher = better).
    pub visibility: f64,
    /// Mean fit weight of the confirmed surface, 0-1 (1 = the scan lies on the model).
    pub fit: f64,
}

/// What the detections' colours encode.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ColorBy {
    /// One distinct saturated colour per rank ([`rank_color`]).
    #[default]
    Rank,
    /// Green (low final score, good) to red (high, bad) over [`RenderOptions::score_range`]
    /// ([`score_color`]).
    FinalScore,
}

/// Options of [`render_png`].
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// Image width in pixels, [`MIN_SIZE`]..=[`MAX_SIZE`].
    pub width: u32,
    /// Image height in pixels, [`MIN_SIZE`]..=[`MAX_SIZE`].
    pub height: u32,
    /// The scene's up direction (need not be normalised). Default `+z`.
    pub up: [f64; 3],
    /// Direction the scanner looks along; `None` = `-up`.
    pub view_dir: Option<[f64; 3]>,
    /// Elevation of the oblique view above the horizontal, degrees (default 40).
    pub oblique_elevation_deg: f64,
    /// Azimuth of the oblique viewpoint, degrees, turning it from the `-y`-ish side towards
    /// `+x`-ish (default -35: seen from front-left).
    pub oblique_azimuth_deg: f64,
    /// What the detections' colours mean.
    pub color_by: ColorBy,
    /// Final-score range mapped green..red with [`ColorBy::FinalScore`]; `None` = from 0 to
    /// the largest final score drawn (at least 1).
    pub score_range: Option<(f64, f64)>,
    /// Title line; `None` = "binpick result".
    pub title: Option<String>,
    /// Splat radius of the scene points in pixels; `None` = derived per view from the point
    /// density and the image scale.
    pub point_radius_px: Option<u32>,
    /// Draw the hidden parts of detections (behind scene points) faintly, "x-ray" style, so a
    /// detection under other parts is still visible. Default true.
    pub show_occluded: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            width: 1600,
            height: 800,
            up: [0.0, 0.0, 1.0],
            view_dir: None,
            oblique_elevation_deg: 40.0,
            oblique_azimuth_deg: -35.0,
            color_by: ColorBy::Rank,
            score_range: None,
            title: None,
            point_radius_px: None,
            show_occluded: true,
        }
    }
}

/// Everything that can go wrong; nothing in this crate panics instead.
#[derive(Debug, thiserror::Error)]
pub enum VizError {
    /// The scene has no points, or none with finite coordinates.
    #[error("scene has no finite points ({non_finite} non-finite skipped)")]
    EmptyScene { non_finite: usize },
    /// Detections were given but the model has no finite points.
    #[error("model has no finite points ({non_finite} non-finite skipped)")]
    EmptyModel { non_finite: usize },
    /// Image size out of range.
    #[error("image size {width}x{height} out of range: each side must be {min}..={max} pixels")]
    BadSize {
        width: u32,
        height: u32,
        min: u32,
        max: u32,
    },
    /// An option or argument is invalid (e.g. a zero `up` vector).
    #[error("invalid option: {0}")]
    InvalidOption(String),
    /// Nothing to plot (e.g. no finite times).
    #[error("nothing to plot: {0}")]
    NoData(String),
    /// The embedded font could not be used.
    #[error("font: {0}")]
    Font(String),
    /// Creating or writing the output file failed.
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// PNG encoding failed.
    #[error("{}: cannot write PNG: {message}", .path.display())]
    Image { path: PathBuf, message: String },
    /// Writing the PLY failed.
    #[error(transparent)]
    Ply(#[from] binpick_cloud::io::IoError),
    /// The chart library reported an error.
    #[error("plot: {0}")]
    Plot(String),
}

/// Checks an image size against [`MIN_SIZE`]..=[`MAX_SIZE`].
pub(crate) fn check_size(width: u32, height: u32) -> Result<(), VizError> {
    let ok = |v: u32| (MIN_SIZE..=MAX_SIZE).contains(&v);
    if ok(width) && ok(height) {
        Ok(())
    } else {
        Err(VizError::BadSize {
            width,
            height,
            min: MIN_SIZE,
            max: MAX_SIZE,
        })
    }
}

/// Whether every coordinate is finite.
pub(crate) fn finite3(p: &[f32; 3]) -> bool {
    p.iter().all(|c| c.is_finite())
}

/// Whether a pose has only finite entries.
pub(crate) fn finite_pose(p: &nalgebra::Isometry3<f64>) -> bool {
    p.translation.vector.iter().all(|c| c.is_finite())
        && p.rotation.coords.iter().all(|c| c.is_finite())
}
