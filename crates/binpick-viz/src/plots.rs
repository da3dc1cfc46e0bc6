//! Charts for `binpick eval --plots DIR`, drawn with `plotters` into an RGB buffer (text from
//! the embedded DejaVu Sans through plotters' `ab_glyph` backend: no system fonts) and saved
//! as PNG with the `image` crate.
//!
//! - [`plot_bar_chart`]: grouped bars, one group per configuration and one bar per metric,
//!   with optional reference values (e.g. a publication's numbers, passed in by the caller)
//!   drawn as black marks. [`plot_thesis_table`] builds one from [`TableRow`]s.
//! - [`plot_time_histogram`]: per-scene times with the median and the 95th percentile.

use std::path::Path;
use std::sync::OnceLock;

use image::RgbImage;
use plotters::backend::{BitMapBackend, DrawingBackend, RGBPixel};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::{FontStyle, register_font};
use plotters_backend::{
    BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingErrorKind,
};

use crate::{VizError, check_size, draw};

/// The six percentages of the thesis's percent table (section 5.5.2), in percent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Percents {
    /// Recognition rate R/P.
    pub recognition: f64,
    /// False negatives FN/P.
    pub false_negatives: f64,
    /// Files with at least one false positive FP/F.
    pub false_positives: f64,
    /// Files with at least one (correctly aligned) unpickable object NP/F.
    pub unpickable: f64,
    /// Bad cycles due to a false best FB/F.
    pub false_best: f64,
    /// Bad cycles due to starvation S/F.
    pub starvation: f64,
}

impl Percents {
    /// In the order of the thesis table: R/P, FN/P, FP/F, NP/F, FB/F, S/F.
    pub fn as_array(&self) -> [f64; 6] {
        [
            self.recognition,
            self.false_negatives,
            self.false_positives,
            self.unpickable,
            self.false_best,
            self.starvation,
        ]
    }
}

/// One configuration's counts, the rows of the thesis's absolute table (F, P, R, FN, FP, NP,
/// FB, S), with reference percentages to compare with, if any.
#[derive(Clone, Debug, PartialEq)]
pub struct TableRow {
    /// Configuration name, e.g. `"A"` or `"C2"`.
    pub config: String,
    /// F: files (scenes) processed.
    pub files: usize,
    /// P: pickable objects in the clouds.
    pub pickable: usize,
    /// R: pickable objects recognised.
    pub recognised: usize,
    /// FN: pickable objects not recognised.
    pub false_negatives: usize,
    /// FP: files with at least one false positive.
    pub files_with_fp: usize,
    /// NP: files with at least one unpickable object (aligned correctly).
    pub files_with_unpickable: usize,
    /// FB: bad cycles due to a false best.
    pub false_best: usize,
    /// S: bad cycles due to starvation.
    pub starvation: usize,
    /// Reference percentages for this configuration (e.g. the thesis's), drawn as black
    /// marks; NaN entries (not published) get no mark.
    pub reference: Option<Percents>,
}

impl TableRow {
    /// Our percentages; NaN where the denominator (P or F) is zero.
    pub fn percents(&self) -> Percents {
        let pct = |n: usize, d: usize| {
            if d == 0 {
                f64::NAN
            } else {
                100.0 * n as f64 / d as f64
            }
        };
        Percents {
            recognition: pct(self.recognised, self.pickable),
            false_negatives: pct(self.false_negatives, self.pickable),
            false_positives: pct(self.files_with_fp, self.files),
            unpickable: pct(self.files_with_unpickable, self.files),
            false_best: pct(self.false_best, self.files),
            starvation: pct(self.starvation, self.files),
        }
    }

    /// This row as a bar group of [`BarChart::thesis_table`]: the six percentages, the
    /// reference if any, and "F=.. P=.." under the name.
    pub fn bar_group(&self) -> BarGroup {
        BarGroup {
            name: self.config.clone(),
            note: format!("F={} P={}", self.files, self.pickable),
            values: self.percents().as_array().to_vec(),
            reference: self.reference.map(|r| r.as_array().to_vec()),
        }
    }
}

/// Whether a metric is better high or low (shown as an arrow in the legend).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Better {
    /// Higher is better (arrow up).
    Higher,
    /// Lower is better (arrow down).
    Lower,
    /// Neither (no arrow).
    Neither,
}

/// One metric: one bar in every group, one colour, one legend entry.
#[derive(Clone, Debug, PartialEq)]
pub struct BarMetric {
    /// Short name, e.g. `"R/P"`.
    pub label: String,
    /// What it counts, for the legend, e.g. `"recognised"`.
    pub description: String,
    /// Direction of good.
    pub better: Better,
}

impl BarMetric {
    /// A metric from its short name, description and direction.
    pub fn new(label: &str, description: &str, better: Better) -> Self {
        Self {
            label: label.into(),
            description: description.into(),
            better,
        }
    }
}

/// One group of bars (one configuration).
#[derive(Clone, Debug, PartialEq)]
pub struct BarGroup {
    /// Name under the group, e.g. `"C2"`.
    pub name: String,
    /// Smaller grey line under the name (e.g. `"F=40 P=80"`); empty = none.
    pub note: String,
    /// One value per metric, in the chart's unit; NaN = not available (drawn as "n/a").
    /// Finite values must be >= 0.
    pub values: Vec<f64>,
    /// One reference value per metric, drawn as black marks; NaN = no mark for that metric.
    pub reference: Option<Vec<f64>>,
}

/// A grouped bar chart: what [`plot_bar_chart`] draws.
#[derive(Clone, Debug, PartialEq)]
pub struct BarChart {
    /// The metrics, one bar each per group; at most [`MAX_METRICS`].
    pub metrics: Vec<BarMetric>,
    /// The groups, left to right.
    pub groups: Vec<BarGroup>,
    /// Y-axis title with its unit, e.g. `"share of P or F (%)"`.
    pub y_desc: String,
    /// X-axis title, e.g. `"configuration"`.
    pub x_desc: String,
    /// Legend name of the reference marks, e.g. `"thesis (5.5.2)"`.
    pub reference_name: String,
    /// Decimals of the value labels (0..=3).
    pub decimals: usize,
    /// The y axis reaches at least this value (100 for percentages; 0 = fit the data).
    pub y_top_at_least: f64,
    /// Extra grey lines at the bottom of the legend.
    pub notes: Vec<String>,
}

impl BarChart {
    /// The thesis's percent table (section 5.5.2): six bars R/P, FN/P, FP/F, NP/F, FB/F, S/F
    /// per row, with each row's reference as black marks named "thesis".
    pub fn thesis_table(rows: &[TableRow]) -> Self {
        Self {
            metrics: vec![
                BarMetric::new("R/P", "recognised", Better::Higher),
                BarMetric::new("FN/P", "not recognised", Better::Lower),
                BarMetric::new("FP/F", "files with a false positive", Better::Lower),
                BarMetric::new("NP/F", "files with an unpickable", Better::Lower),
                BarMetric::new("FB/F", "bad cycle: false best", Better::Lower),
                BarMetric::new("S/F", "bad cycle: starvation", Better::Lower),
            ],
            groups: rows.iter().map(TableRow::bar_group).collect(),
            y_desc: "share of pickable objects P or of files F (%)".into(),
            x_desc: "configuration (F = files, P = pickable objects)".into(),
            reference_name: "thesis".into(),
            decimals: 0,
            y_top_at_least: 100.0,
            notes: vec!["\u{2191} higher is better, \u{2193} lower is better".into()],
        }
    }

    /// Checks the shape and values; the errors name the group and metric.
    fn check(&self) -> Result<(), VizError> {
        if self.groups.is_empty() {
            return Err(VizError::NoData("no bar groups".into()));
        }
        if self.metrics.is_empty() {
            return Err(VizError::NoData("no metrics".into()));
        }
        if self.metrics.len() > MAX_METRICS {
            return Err(VizError::InvalidOption(format!(
                "{} metrics, at most {MAX_METRICS} can be told apart by colour",
                self.metrics.len()
            )));
        }
        if !(self.y_top_at_least.is_finite() && self.y_top_at_least >= 0.0) {
            return Err(VizError::InvalidOption(format!(
                "y_top_at_least must be finite and >= 0, got {}",
                self.y_top_at_least
            )));
        }
        if self.decimals > 3 {
            return Err(VizError::InvalidOption(format!(
                "decimals must be 0..=3, got {}",
                self.decimals
            )));
        }
        let m = self.metrics.len();
        for g in &self.groups {
            for (what, vals) in [
                ("values", Some(&g.values)),
                ("reference", g.reference.as_ref()),
            ] {
                let Some(vals) = vals else { continue };
                if vals.len() != m {
                    return Err(VizError::InvalidOption(format!(
                        "group {:?}: {} {what} for {m} metrics",
                        g.name,
                        vals.len()
                    )));
                }
                for (v, metric) in vals.iter().zip(&self.metrics) {
                    let usable = v.is_nan() || (v.is_finite() && *v >= 0.0);
                    if !usable {
                        return Err(VizError::InvalidOption(format!(
                            "group {:?}, metric {}: {what} {v} is neither >= 0 nor NaN \
                             (not available)",
                            g.name, metric.label
                        )));
                    }
                }
            }
        }
        Ok(())
    }
}

/// Size and title of a chart.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotOptions {
    /// Width in pixels, [`crate::MIN_SIZE`]..=[`crate::MAX_SIZE`].
    pub width: u32,
    /// Height in pixels, [`crate::MIN_SIZE`]..=[`crate::MAX_SIZE`].
    pub height: u32,
    /// Title; `None` = a default naming the chart.
    pub title: Option<String>,
}

impl Default for PlotOptions {
    fn default() -> Self {
        Self {
            width: 1200,
            height: 700,
            title: None,
        }
    }
}

/// Summary of the times [`plot_time_histogram`] drew, milliseconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeStats {
    /// Finite times used.
    pub n: usize,
    /// Times skipped for being NaN or infinite.
    pub non_finite: usize,
    /// Smallest time, ms.
    pub min: f64,
    /// Largest time, ms.
    pub max: f64,
    /// Mean time, ms.
    pub mean: f64,
    /// Median time, ms.
    pub median: f64,
    /// 95th percentile, ms. Median and p95 are nearest-rank percentiles (the value at rank
    /// `ceil(q n)`), the definition `binpick::eval::median_p95` prints, so the chart agrees
    /// with the table.
    pub p95: f64,
}

impl TimeStats {
    /// Statistics of the finite values of `times_ms`; `None` if there are none.
    pub fn from_times(times_ms: &[f64]) -> Option<TimeStats> {
        let mut v: Vec<f64> = times_ms.iter().copied().filter(|t| t.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let n = v.len();
        Some(TimeStats {
            n,
            non_finite: times_ms.len() - n,
            min: v[0],
            max: v[n - 1],
            mean: v.iter().sum::<f64>() / n as f64,
            median: nearest_rank(&v, 0.5),
            p95: nearest_rank(&v, 0.95),
        })
    }
}

/// Nearest-rank percentile of sorted `v`: the value at rank `ceil(q n)` (1-based).
fn nearest_rank(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let r = ((q.clamp(0.0, 1.0) * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[r - 1]
}

/// Linear-interpolation percentile of sorted, non-empty `v`; `q` in 0..=1 (for the IQR).
fn percentile_sorted(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let pos = (v.len() - 1) as f64 * q.clamp(0.0, 1.0);
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    let f = pos - lo as f64;
    v[lo] * (1.0 - f) + v[hi.min(v.len() - 1)] * f
}

/// A "nice" step (1, 2 or 5 times a power of ten) of at least `raw`.
fn nice_step(raw: f64) -> f64 {
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(raw.log10().floor());
    let m = raw / p;
    let n = if m <= 1.0 {
        1.0
    } else if m <= 2.0 {
        2.0
    } else if m <= 5.0 {
        5.0
    } else {
        10.0
    };
    n * p
}

/// The 1-2-5 step nearest to `raw` (in ratio).
fn nice_round(raw: f64) -> f64 {
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(raw.log10().floor());
    let m = raw / p;
    let n = if m < 1.5 {
        1.0
    } else if m < 3.2 {
        2.0
    } else if m < 7.1 {
        5.0
    } else {
        10.0
    };
    n * p
}

/// Shortest of `{:.0}`..`{:.3}` that shows `v` to 3 decimals.
fn short_num(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.to_string() }
}

/// Most metrics a bar chart can have: one distinct colour each.
pub const MAX_METRICS: usize = 10;

/// Bar colours by metric index (the "tab10" palette: distinct, none of them black, the
/// reference marks' colour). The first six are the thesis table's R/P .. S/F.
pub const BAR_COLORS: [[u8; 3]; MAX_METRICS] = [
    [44, 160, 44],
    [255, 127, 14],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [31, 119, 180],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
    [227, 119, 194],
];

/// Colour of the reference marks.
pub const REFERENCE_COLOR: [u8; 3] = [0, 0, 0];
/// Colour of the histogram's median line.
pub const MEDIAN_COLOR: [u8; 3] = [20, 40, 140];
/// Colour of the histogram's 95th-percentile line.
pub const P95_COLOR: [u8; 3] = [200, 30, 30];

const FAMILY: &str = "sans-serif";
const GREY: RGBColor = RGBColor(90, 90, 90);
const GRID: RGBColor = RGBColor(226, 226, 226);

fn rgb(c: [u8; 3]) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

fn plot_err<E: std::fmt::Display>(e: E) -> VizError {
    VizError::Plot(e.to_string())
}

/// Registers the embedded DejaVu Sans faces as plotters' "sans-serif" (once per process), so
/// any plotters code that measures text itself uses the font [`Backend`] draws.
fn register_fonts() -> Result<(), VizError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        register_font(FAMILY, FontStyle::Normal, draw::sans_regular()).is_ok()
            && register_font(FAMILY, FontStyle::Bold, draw::sans_bold()).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(VizError::Font(
            "embedded DejaVu Sans is not a valid font".into(),
        ))
    }
}

/// The bitmap backend with its own text rasteriser. plotters 0.3.7's `ab_glyph` text drops
/// each glyph's side bearing and rounds every advance (uneven letter spacing) and sets the
/// baseline half a size below the anchor (labels stand above their ticks). This draws the
/// same embedded font through the crate's text mask (kerning, bearings, the line box from
/// ascent to descent at the anchor) and passes everything else through.
struct Backend<'a> {
    bitmap: BitMapBackend<'a, RGBPixel>,
    fonts: draw::Fonts,
}

impl DrawingBackend for Backend<'_> {
    type ErrorType = <BitMapBackend<'static, RGBPixel> as DrawingBackend>::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.bitmap.get_size()
    }
    fn ensure_prepared(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.ensure_prepared()
    }
    fn present(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.present()
    }
    fn draw_pixel(
        &mut self,
        point: BackendCoord,
        color: BackendColor,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.draw_pixel(point, color)
    }
    fn draw_line<S: BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.draw_line(from, to, style)
    }
    fn draw_rect<S: BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.draw_rect(upper_left, bottom_right, style, fill)
    }
    fn draw_text<S: BackendTextStyle>(
        &mut self,
        text: &str,
        style: &S,
        pos: BackendCoord,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        let color = style.color();
        let font = match style.style() {
            FontStyle::Bold => &self.fonts.bold,
            _ => &self.fonts.regular,
        };
        let Some(mask) = draw::text_mask(font, style.size() as f32, text, 0) else {
            return Ok(());
        };
        let (w, h) = (f64::from(mask.width), f64::from(mask.height));
        let anchor = style.anchor();
        let dx = match anchor.h_pos {
            HPos::Left => 0.0,
            HPos::Center => -w / 2.0,
            HPos::Right => -w,
        }
        .round() as i32;
        let dy = match anchor.v_pos {
            VPos::Top => 0.0,
            VPos::Center => -h / 2.0,
            VPos::Bottom => -h,
        }
        .round() as i32;
        // Offsets are laid out unturned, then turned with the text (y-axis titles).
        let turn = style.transform();
        let pad = mask.pad as i32;
        for my in 0..mask.h as i32 {
            for mx in 0..mask.w as i32 {
                let cov = mask.data[(my as i64 * mask.w + mx as i64) as usize];
                if cov > 0.0 {
                    let (tx, ty) = turn.transform(mx - pad + dx, my - pad + dy);
                    let c = BackendColor {
                        alpha: color.alpha * f64::from(cov),
                        rgb: color.rgb,
                    };
                    self.bitmap.draw_pixel((pos.0 + tx, pos.1 + ty), c)?;
                }
            }
        }
        Ok(())
    }
    fn estimate_text_size<S: BackendTextStyle>(
        &self,
        text: &str,
        style: &S,
    ) -> Result<(u32, u32), DrawingErrorKind<Self::ErrorType>> {
        let font = match style.style() {
            FontStyle::Bold => &self.fonts.bold,
            _ => &self.fonts.regular,
        };
        let px = style.size() as f32;
        // Unturned extents, as plotters' own estimate gives them.
        Ok((
            draw::text_width(font, px, text).ceil() as u32,
            draw::line_height(font, px).ceil() as u32,
        ))
    }
}

type Area<'a> = DrawingArea<Backend<'a>, Shift>;

/// Draws with `paint` on a white `w` x `h` canvas and saves it as PNG at `out`.
fn paint_png<T>(
    w: u32,
    h: u32,
    out: &Path,
    paint: impl FnOnce(&Area<'_>) -> Result<T, VizError>,
) -> Result<T, VizError> {
    check_size(w, h)?;
    register_fonts()?;
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    let result = {
        let backend = BitMapBackend::<RGBPixel>::with_buffer_and_format(&mut buf, (w, h))
            .map_err(plot_err)?;
        let root = Backend {
            bitmap: backend,
            fonts: draw::Fonts::load()?,
        }
        .into_drawing_area();
        let result = paint(&root)?;
        root.present().map_err(plot_err)?;
        result
    };
    let img = RgbImage::from_raw(w, h, buf)
        .ok_or_else(|| VizError::Plot("pixel buffer has the wrong size".into()))?;
    draw::save_png(&img, out)?;
    Ok(result)
}

fn font(size: f64, bold: bool) -> FontDesc<'static> {
    let style = if bold {
        FontStyle::Bold
    } else {
        FontStyle::Normal
    };
    FontDesc::new(FontFamily::SansSerif, size, style)
}

/// Text style of `size` px, colour and anchor.
fn text_style(size: f64, bold: bool, color: RGBColor, h: HPos, v: VPos) -> TextStyle<'static> {
    TextStyle {
        font: font(size, bold),
        color: color.to_backend_color(),
        pos: Pos::new(h, v),
    }
}

/// Width and height in pixels of `s` in `style`.
fn text_size(area: &Area<'_>, s: &str, style: &TextStyle<'_>) -> Result<(i32, i32), VizError> {
    let (w, h) = area.estimate_text_size(s, style).map_err(plot_err)?;
    Ok((w as i32, h as i32))
}

/// Fills the pixels `x..x + w` x `y..y + h` (absolute coordinates of `area`'s backend).
fn fill(area: &Area<'_>, x: i32, y: i32, w: i32, h: i32, c: RGBColor) -> Result<(), VizError> {
    if w <= 0 || h <= 0 {
        return Ok(());
    }
    // The bitmap backend fills rectangles without their bottom-right edge.
    area.draw(&Rectangle::new([(x, y), (x + w, y + h)], c.filled()))
        .map_err(plot_err)
}

/// Base font size in pixels for a `w` x `h` chart: `1 / per_h` of the height or `1 / per_w`
/// of the width, whichever is smaller.
fn base_font(w: u32, h: u32, per_h: f64, per_w: f64) -> f64 {
    (f64::from(h) / per_h)
        .min(f64::from(w) / per_w)
        .clamp(7.0, 40.0)
}

/// Grouped bars with value labels, reference marks, legend and axis titles (see
/// [`BarChart`]). Each bar is labelled with its value; a zero still shows as a stub a few
/// pixels tall above the axis and a missing value (NaN) as "n/a". Reference values are black
/// marks as wide as their own bar (bars are separated by gaps, so marks never touch), thin
/// enough that the bar shows above and below; a value label moves above its mark if they
/// would overlap.
pub fn plot_bar_chart(chart: &BarChart, opts: &PlotOptions, out: &Path) -> Result<(), VizError> {
    chart.check()?;
    let (w, h) = (opts.width, opts.height);
    let fs = base_font(w, h, 45.0, 75.0);
    let title = opts
        .title
        .clone()
        .unwrap_or_else(|| "binpick eval per configuration".into());
    paint_png(w, h, out, |root| {
        let body = root
            .titled(&title, font(fs * 1.3, true))
            .map_err(plot_err)?;

        // Legend on the right: heading, one line per metric, the reference, notes.
        let arrow = |b: Better| match b {
            Better::Higher => " \u{2191}",
            Better::Lower => " \u{2193}",
            Better::Neither => "",
        };
        let entries: Vec<String> = chart
            .metrics
            .iter()
            .map(|m| format!("{}  {}{}", m.label, m.description, arrow(m.better)))
            .collect();
        let any_reference = chart.groups.iter().any(|g| {
            g.reference
                .as_ref()
                .is_some_and(|r| r.iter().any(|v| v.is_finite()))
        });
        let entry_style = text_style(fs * 0.95, false, BLACK, HPos::Left, VPos::Top);
        let note_style = text_style(fs * 0.8, false, GREY, HPos::Left, VPos::Top);
        let head_style = text_style(fs, true, BLACK, HPos::Left, VPos::Top);
        let swatch = (fs * 1.1).round() as i32;
        let mut legend_w = text_size(root, "bars: this run", &head_style)?.0;
        for e in entries
            .iter()
            .chain(any_reference.then_some(&chart.reference_name))
        {
            legend_w = legend_w.max(text_size(root, e, &entry_style)?.0 + swatch + fs as i32 / 2);
        }
        for n in &chart.notes {
            legend_w = legend_w.max(text_size(root, n, &note_style)?.0);
        }
        let legend_w = (f64::from(legend_w) + fs * 1.5).min(f64::from(w) * 0.4) as i32;
        let (plot_area, legend_area) = body.split_horizontally(w as i32 - legend_w);

        // Y range: the data (bars and marks), at least `y_top_at_least`, with room above the
        // tallest for its label.
        let data_max = chart
            .groups
            .iter()
            .flat_map(|g| g.values.iter().chain(g.reference.iter().flatten()))
            .copied()
            .filter(|v| v.is_finite())
            .fold(chart.y_top_at_least, f64::max);
        // About two label heights of headroom over the estimated plot height.
        let plot_h_guess = (f64::from(h) - fs * 8.0).max(1.0);
        let headroom = (fs * 2.0 / plot_h_guess).clamp(0.04, 0.25);
        let top = if data_max > 0.0 {
            data_max * (1.0 + headroom)
        } else {
            1.0
        };
        let label_style_y = text_style(fs, false, BLACK, HPos::Right, VPos::Center);
        let widest_tick = if top >= 10.0 {
            format!("{:.0}", top)
        } else {
            short_num(top)
        };
        let y_label_w = text_size(root, &widest_tick, &label_style_y)?.0;
        let n_groups = chart.groups.len();
        let mut cc = ChartBuilder::on(&plot_area)
            .margin_left((fs * 0.5) as i32)
            .margin_right((fs * 0.5) as i32)
            .margin_top((fs * 0.8) as i32)
            .margin_bottom((fs * 0.3) as i32)
            .x_label_area_size((fs * 4.3) as i32)
            .y_label_area_size((f64::from(y_label_w) + fs * 2.2) as i32)
            .build_cartesian_2d(0f64..n_groups as f64, 0f64..top)
            .map_err(plot_err)?;
        let plot_h = f64::from(cc.plotting_area().dim_in_pixel().1);
        let y_fmt = |v: &f64| short_num(*v);
        cc.configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_labels((plot_h / (fs * 3.0)).clamp(2.0, 12.0) as usize)
            .y_label_formatter(&y_fmt)
            .label_style(font(fs, false))
            .axis_desc_style(font(fs, false))
            .y_desc(chart.y_desc.as_str())
            .x_desc(chart.x_desc.as_str())
            .bold_line_style(GRID)
            .light_line_style(WHITE)
            .draw()
            .map_err(plot_err)?;

        let px = |x: f64| cc.backend_coord(&(x, 0.0)).0;
        let py = |y: f64| cc.backend_coord(&(0.0, y)).1;
        let base = py(0.0);
        let m = chart.metrics.len();
        let group_w = 0.84;
        let slot = group_w / m as f64;
        let mark_t = (fs / 5.0).round().max(2.0) as i32;
        // A zero bar's stub: taller than half a mark, so a mark at zero leaves it visible.
        let stub = mark_t + 3;
        let slot_px = (px(slot) - px(0.0)).max(1);
        let gap = ((f64::from(slot_px) * 0.16).round() as i32).clamp(2, 12);

        // Value labels: as large as fits the slot, none if even 7 px does not.
        let widest = chart
            .groups
            .iter()
            .flat_map(|g| g.values.iter())
            .map(|v| value_label(*v, chart.decimals))
            .max_by_key(String::len)
            .unwrap_or_default();
        let mut lfs = fs * 0.8;
        let lw = text_size(
            root,
            &widest,
            &text_style(lfs, false, BLACK, HPos::Center, VPos::Bottom),
        )?
        .0;
        if lw > slot_px {
            lfs *= f64::from(slot_px) / f64::from(lw.max(1));
        }
        let show_labels = lfs >= 7.0;
        let label_h = (lfs * 0.75).round() as i32; // digit height, for overlap tests

        for (i, g) in chart.groups.iter().enumerate() {
            let x_first = i as f64 + (1.0 - group_w) / 2.0;
            let cx = px(i as f64 + 0.5);
            // A group with no value at all gets one "n/a" rather than a row of them.
            let all_missing = g.values.iter().all(|v| v.is_nan());
            if all_missing {
                let st = text_style(fs * 0.9, false, GREY, HPos::Center, VPos::Bottom);
                root.draw_text("n/a", &st, (cx, base - 3))
                    .map_err(plot_err)?;
            }
            for (k, v) in g.values.iter().enumerate() {
                let (xa, xb) = (
                    px(x_first + k as f64 * slot),
                    px(x_first + (k + 1) as f64 * slot),
                );
                let x0 = xa + gap / 2;
                let bw = (xb - xa - gap).max(1);
                let color = rgb(BAR_COLORS[k]);
                let mut label_bottom = base - 3;
                if v.is_finite() {
                    let bar_h = (base - py(*v)).max(stub);
                    fill(root, x0, base - bar_h, bw, bar_h, color)?;
                    label_bottom = base - bar_h - 3;
                }
                let reference = g.reference.as_ref().map_or(f64::NAN, |r| r[k]);
                if reference.is_finite() {
                    let ym = py(reference);
                    let mark_top = ym - mark_t / 2;
                    fill(root, x0, mark_top, bw, mark_t, rgb(REFERENCE_COLOR))?;
                    // Label above the mark if they would overlap.
                    let (l_top, l_bot) = (label_bottom - label_h, label_bottom);
                    if l_bot >= mark_top - 1 && l_top <= mark_top + mark_t + 1 {
                        label_bottom = mark_top - 3;
                    }
                }
                if show_labels && !all_missing {
                    let (s, c) = if v.is_finite() {
                        (value_label(*v, chart.decimals), BLACK)
                    } else {
                        ("n/a".to_string(), GREY)
                    };
                    let st = text_style(lfs, false, c, HPos::Center, VPos::Bottom);
                    root.draw_text(&s, &st, (x0 + bw / 2, label_bottom))
                        .map_err(plot_err)?;
                }
            }
            // Group name and note under the axis.
            let name_style = text_style(fs * 1.05, true, BLACK, HPos::Center, VPos::Top);
            root.draw_text(&g.name, &name_style, (cx, base + (fs * 0.6) as i32))
                .map_err(plot_err)?;
            if !g.note.is_empty() {
                let st = text_style(fs * 0.8, false, GREY, HPos::Center, VPos::Top);
                root.draw_text(&g.note, &st, (cx, base + (fs * 1.9) as i32))
                    .map_err(plot_err)?;
            }
        }

        // Legend.
        let (lx, _) = legend_area.get_base_pixel();
        let mut y = py(top) + 2;
        root.draw_text("bars: this run", &head_style, (lx, y))
            .map_err(plot_err)?;
        y += (fs * 1.7) as i32;
        for (k, e) in entries.iter().enumerate() {
            fill(root, lx, y, swatch, swatch, rgb(BAR_COLORS[k]))?;
            root.draw_text(e, &entry_style, (lx + swatch + (fs * 0.5) as i32, y))
                .map_err(plot_err)?;
            y += (fs * 1.5) as i32;
        }
        if any_reference {
            y += (fs * 0.4) as i32;
            fill(
                root,
                lx,
                y + swatch / 2 - mark_t / 2,
                swatch,
                mark_t,
                rgb(REFERENCE_COLOR),
            )?;
            root.draw_text(
                &chart.reference_name,
                &entry_style,
                (lx + swatch + (fs * 0.5) as i32, y),
            )
            .map_err(plot_err)?;
            y += (fs * 1.5) as i32;
        }
        y += (fs * 0.6) as i32;
        for n in &chart.notes {
            root.draw_text(n, &note_style, (lx, y)).map_err(plot_err)?;
            y += (fs * 1.2) as i32;
        }
        Ok(())
    })
}

/// A bar's value label.
fn value_label(v: f64, decimals: usize) -> String {
    if v.is_finite() {
        format!("{v:.decimals$}")
    } else {
        "n/a".into()
    }
}

/// Grouped bar chart of the thesis table (section 5.5.2) per configuration
/// ([`BarChart::thesis_table`]): for each row six bars R/P, FN/P, FP/F, NP/F, FB/F and S/F in
/// percent and the row's [`TableRow::reference`] as black marks. Under each group: the
/// configuration's name, F and P. Percentages with a zero denominator show as "n/a".
pub fn plot_thesis_table(
    rows: &[TableRow],
    opts: &PlotOptions,
    out: &Path,
) -> Result<(), VizError> {
    plot_bar_chart(&BarChart::thesis_table(rows), opts, out)
}

/// Histogram of per-scene times (ms) with the median (solid line) and the 95th percentile
/// (dashed line), each labelled with its value in ms. Bins follow the Freedman-Diaconis rule
/// rounded to a 1-2-5 width (1..=61 bins). Non-finite times are skipped; no finite time at
/// all is an error. Returns the statistics drawn.
pub fn plot_time_histogram(
    times_ms: &[f64],
    opts: &PlotOptions,
    out: &Path,
) -> Result<TimeStats, VizError> {
    let stats = TimeStats::from_times(times_ms)
        .ok_or_else(|| VizError::NoData("no finite times".into()))?;
    let (w, h) = (opts.width, opts.height);
    check_size(w, h)?;
    let fs = base_font(w, h, 40.0, 65.0);
    let mut v: Vec<f64> = times_ms.iter().copied().filter(|t| t.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    let (mut lo, mut hi) = (stats.min, stats.max);
    if hi - lo < 1e-9 * lo.abs().max(1.0) {
        let pad = (lo.abs() * 0.05).max(0.5);
        lo -= pad;
        hi += pad;
    }
    // Bin width: the Freedman-Diaconis width (or range / sqrt(n) when the IQR is 0) rounded
    // to the nearest 1-2-5 step, at most about 60 bins, edges on multiples of the width.
    let iqr = percentile_sorted(&v, 0.75) - percentile_sorted(&v, 0.25);
    let n = v.len() as f64;
    let fd = 2.0 * iqr / n.cbrt();
    let raw = if fd > 0.0 {
        fd
    } else {
        (hi - lo) / n.sqrt().ceil()
    };
    let width = nice_round(raw).max(nice_step((hi - lo) / 60.0));
    let lo = (lo / width).floor() * width;
    let bins = (((hi - lo) / width).floor() as usize + 1).clamp(1, 61);
    let hi = lo + bins as f64 * width;
    let mut counts = vec![0u32; bins];
    for t in &v {
        let b = (((t - lo) / width).floor().max(0.0) as usize).min(bins - 1);
        counts[b] += 1;
    }
    let c_max = counts.iter().copied().max().unwrap_or(1).max(1);
    let title = opts.title.clone().unwrap_or_else(|| {
        format!(
            "binpick eval: time per scene (n = {}, mean {:.0} ms, max {:.0} ms)",
            stats.n, stats.mean, stats.max
        )
    });
    let y_desc = format!("scenes per {} ms bin (count)", short_num(width));
    paint_png(w, h, out, |root| {
        let body = root
            .titled(&title, font(fs * 1.2, true))
            .map_err(plot_err)?;
        let label_style_y = text_style(fs, false, BLACK, HPos::Right, VPos::Center);
        let plot_h_guess = f64::from(h) - fs * 8.0;
        // Headroom for two rows of line labels above the tallest bin.
        let free = (1.0 - fs * 3.4 / plot_h_guess.max(1.0)).clamp(0.4, 0.9);
        let top = ((f64::from(c_max) / free).ceil() as u32).max(c_max + 1);
        let y_label_w = text_size(root, &top.to_string(), &label_style_y)?.0;
        let xpad = (hi - lo) * 0.03;
        let mut cc = ChartBuilder::on(&body)
            .margin_left((fs * 0.5) as i32)
            .margin_right((fs * 1.5) as i32)
            .margin_top((fs * 0.5) as i32)
            .margin_bottom((fs * 0.3) as i32)
            .x_label_area_size((fs * 3.2) as i32)
            .y_label_area_size((f64::from(y_label_w) + fs * 2.2) as i32)
            .build_cartesian_2d((lo - xpad)..(hi + xpad), 0u32..top)
            .map_err(plot_err)?;
        let (plot_w, plot_h) = cc.plotting_area().dim_in_pixel();
        let x_fmt = |x: &f64| short_num(*x);
        cc.configure_mesh()
            .disable_x_mesh()
            .x_labels((f64::from(plot_w) / (fs * 6.0)).clamp(2.0, 12.0) as usize)
            .y_labels((f64::from(plot_h) / (fs * 2.5)).clamp(2.0, 12.0) as usize)
            .x_label_formatter(&x_fmt)
            .label_style(font(fs, false))
            .axis_desc_style(font(fs, false))
            .x_desc("time per scene (ms)")
            .y_desc(y_desc.as_str())
            .bold_line_style(GRID)
            .light_line_style(WHITE)
            .draw()
            .map_err(plot_err)?;
        let px = |x: f64| cc.backend_coord(&(x, 0)).0;
        let py = |c: u32| cc.backend_coord(&(lo, c)).1;
        let base = py(0);
        let edge = RGBColor(70, 110, 150);
        let inner = RGBColor(158, 190, 218);
        for (i, &c) in counts.iter().enumerate() {
            if c == 0 {
                continue;
            }
            let x0 = lo + i as f64 * width;
            let (a, b) = (px(x0), px(x0 + width));
            let t = py(c);
            fill(root, a, t, (b - a).max(1), base - t, edge)?;
            fill(root, a + 1, t + 1, b - a - 2, base - t - 1, inner)?;
        }
        let top_px = py(top);
        let lw = (fs / 7.0).round().max(2.0) as i32;
        let (mx, qx) = (px(stats.median), px(stats.p95));
        fill(
            root,
            mx - lw / 2,
            top_px,
            lw,
            base - top_px,
            rgb(MEDIAN_COLOR),
        )?;
        let dash = (fs * 0.6).round().max(3.0) as i32;
        let mut y = top_px;
        while y < base {
            fill(root, qx - lw / 2, y, lw, dash.min(base - y), rgb(P95_COLOR))?;
            y += 2 * dash;
        }

        // Labels at the top of the lines, on a white box; the second row if they would
        // overlap in the first.
        let right_edge = px(hi + xpad);
        let row_h = (fs * 1.5) as i32;
        let mut taken: Vec<(i32, i32)> = Vec::new(); // x-extents in the first row
        for (x, text, color) in [
            (
                mx,
                format!("median {:.1} ms", stats.median),
                rgb(MEDIAN_COLOR),
            ),
            (qx, format!("p95 {:.1} ms", stats.p95), rgb(P95_COLOR)),
        ] {
            let st = text_style(fs, true, color, HPos::Left, VPos::Top);
            let (tw, _) = text_size(root, &text, &st)?;
            let pad = (fs * 0.3) as i32;
            let lx = if x + lw + pad + tw + pad <= right_edge {
                x + lw / 2 + 2
            } else {
                x - lw / 2 - 2 - tw - 2 * pad
            };
            let extent = (lx, lx + tw + 2 * pad);
            let row = i32::from(taken.iter().any(|&(a, b)| extent.0 < b && a < extent.1));
            if row == 0 {
                taken.push(extent);
            }
            let ly = top_px + (fs * 0.3) as i32 + row * row_h;
            fill(root, lx, ly, tw + 2 * pad, (fs * 1.25) as i32, WHITE)?;
            root.draw_text(&text, &st, (lx + pad, ly + (fs * 0.15) as i32))
                .map_err(plot_err)?;
        }
        Ok(())
    })?;
    Ok(stats)
}
