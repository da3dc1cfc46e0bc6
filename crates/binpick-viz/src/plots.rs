//! Charts for `binpick eval --plots DIR`: the thesis result table (section 5.5.2) per
//! configuration as grouped bars, and a histogram of per-scene times.
//!
//! Drawn with the crate's own raster primitives and the embedded DejaVu Sans font (the same
//! text rendering as the PNG render; no system fonts) and saved with the `image` crate.

use std::path::Path;

use image::RgbImage;

use crate::draw::{self, Anchor, BLACK, Fonts, Rgb, WHITE};
use crate::{VizError, check_size};

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

    /// The thesis's published percentages for a conveyor-belt configuration of section 5.5.2
    /// (`"A"`, `"B"`, `"C1"`, `"C2"`, `"C3"`), as printed there (rounded to whole percent).
    pub fn thesis_conveyor(config: &str) -> Option<Percents> {
        let v = match config {
            "A" => [86.0, 14.0, 2.0, 22.0, 0.0, 2.0],
            "B" => [73.0, 27.0, 0.0, 12.0, 0.0, 7.0],
            "C1" => [58.0, 42.0, 47.0, 15.0, 22.0, 10.0],
            "C2" => [80.0, 20.0, 70.0, 27.0, 17.0, 5.0],
            "C3" => [70.0, 30.0, 42.0, 25.0, 15.0, 2.0],
            _ => return None,
        };
        Some(Percents {
            recognition: v[0],
            false_negatives: v[1],
            false_positives: v[2],
            unpickable: v[3],
            false_best: v[4],
            starvation: v[5],
        })
    }
}

/// One configuration's counts, the rows of the thesis's absolute table (F, P, R, FN, FP, NP,
/// FB, S), with the thesis's percentages to compare with, if any.
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
    /// The thesis's percentages for this configuration, drawn as reference markers.
    pub thesis: Option<Percents>,
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
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    pub median: f64,
    /// 95th percentile. Median and p95 are nearest-rank percentiles (the value at rank
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

/// A plot rectangle in pixels with the data ranges it shows.
struct Frame {
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
    xr: (f64, f64),
    yr: (f64, f64),
}

impl Frame {
    fn px(&self, x: f64) -> f64 {
        self.x0 + (x - self.xr.0) / (self.xr.1 - self.xr.0) * (self.x1 - self.x0)
    }
    fn py(&self, y: f64) -> f64 {
        self.y1 - (y - self.yr.0) / (self.yr.1 - self.yr.0) * (self.y1 - self.y0)
    }
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

/// About `n` nice ticks within `lo..=hi`, and their step.
fn ticks(lo: f64, hi: f64, n: usize) -> (Vec<f64>, f64) {
    let step = nice_step((hi - lo) / n.max(1) as f64);
    let mut v = Vec::new();
    let mut t = (lo / step).ceil() * step;
    while t <= hi + step * 1e-9 && v.len() < 200 {
        v.push(if t.abs() < step * 1e-9 { 0.0 } else { t });
        t += step;
    }
    (v, step)
}

fn tick_label(v: f64, step: f64) -> String {
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    format!("{v:.decimals$}")
}

/// Shortest of `{:.0}`..`{:.3}` that shows `v` to 3 decimals.
fn short_num(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

/// Fresh white image of the checked size, the fonts and a base font size for it.
fn canvas(w: u32, h: u32, per_h: f64, per_w: f64) -> Result<(RgbImage, Fonts, f32), VizError> {
    check_size(w, h)?;
    let fonts = Fonts::load()?;
    let fs = (f64::from(h) / per_h)
        .min(f64::from(w) / per_w)
        .clamp(7.0, 40.0) as f32;
    Ok((RgbImage::from_pixel(w, h, image::Rgb(WHITE)), fonts, fs))
}

/// Horizontal grid lines, y tick labels, the y-axis description and the two axis lines.
fn draw_y_axis(img: &mut RgbImage, fonts: &Fonts, fs: f32, fr: &Frame, desc: &str, integer: bool) {
    let f = f64::from(fs);
    let (tv, step) = ticks(
        fr.yr.0,
        fr.yr.1,
        ((fr.y1 - fr.y0) / (f * 3.0)).clamp(2.0, 12.0) as usize,
    );
    let step = if integer { step.max(1.0) } else { step };
    for t in tv {
        if integer && (t - t.round()).abs() > 1e-9 {
            continue;
        }
        let y = fr.py(t).round();
        draw::fill_rect(
            img,
            fr.x0 as i64,
            y as i64,
            (fr.x1 - fr.x0) as i64,
            1,
            [228, 228, 228],
        );
        draw::fill_rect(img, fr.x0 as i64 - 4, y as i64, 4, 1, BLACK);
        draw::text(
            img,
            &fonts.regular,
            fs,
            fr.x0 - 6.0,
            y,
            Anchor::CenterRight,
            &tick_label(t, step),
            BLACK,
            None,
        );
    }
    let label_w = f64::from(draw::text_width(
        &fonts.regular,
        fs,
        &tick_label(fr.yr.1, step),
    ));
    draw::text_vertical(
        img,
        &fonts.regular,
        fs,
        fr.x0 - label_w - 8.0 - f * 0.8,
        (fr.y0 + fr.y1) / 2.0,
        desc,
        BLACK,
    );
    draw::fill_rect(
        img,
        fr.x0 as i64 - 1,
        fr.y0 as i64,
        1,
        (fr.y1 - fr.y0) as i64 + 1,
        BLACK,
    );
    draw::fill_rect(
        img,
        fr.x0 as i64 - 1,
        fr.y1 as i64,
        (fr.x1 - fr.x0) as i64 + 1,
        1,
        BLACK,
    );
}

/// Filled rectangle between two data-space corners (pixel edges rounded).
fn bar(img: &mut RgbImage, fr: &Frame, x0: f64, x1: f64, y0: f64, y1: f64, c: Rgb) {
    let (a, b) = (fr.px(x0).round(), fr.px(x1).round());
    let (top, bot) = (fr.py(y1).round(), fr.py(y0).round());
    draw::fill_rect(
        img,
        a as i64,
        top as i64,
        (b - a).max(1.0) as i64,
        (bot - top) as i64,
        c,
    );
}

/// Dashed line from (x0, y0) to (x1, y1), pixels.
#[allow(clippy::too_many_arguments)]
fn dashed(img: &mut RgbImage, x0: f64, y0: f64, x1: f64, y1: f64, w: f64, dash: f64, c: Rgb) {
    let len = (x1 - x0).hypot(y1 - y0);
    if !(len.is_finite() && dash > 0.0) {
        return;
    }
    let n = (len / dash).ceil() as usize;
    for i in (0..n).step_by(2) {
        let t0 = i as f64 * dash / len;
        let t1 = ((i as f64 + 1.0) * dash / len).min(1.0);
        draw::line(
            img,
            x0 + (x1 - x0) * t0,
            y0 + (y1 - y0) * t0,
            x0 + (x1 - x0) * t1,
            y0 + (y1 - y0) * t1,
            w,
            c,
        );
    }
}

const METRICS: [(&str, &str, Rgb); 6] = [
    ("R/P", "recognised \u{2191}", [44, 160, 44]),
    ("FN/P", "not recognised \u{2193}", [255, 127, 14]),
    (
        "FP/F",
        "files with a false positive \u{2193}",
        [214, 39, 40],
    ),
    ("NP/F", "files with an unpickable \u{2193}", [148, 103, 189]),
    ("FB/F", "bad cycle: false best \u{2193}", [140, 86, 75]),
    ("S/F", "bad cycle: starvation \u{2193}", [31, 119, 180]),
];

/// Grouped bar chart of the thesis table (section 5.5.2) per configuration: for each
/// configuration six bars, R/P, FN/P, FP/F, NP/F, FB/F and S/F in percent, labelled with
/// their values, and the thesis's values (when [`TableRow::thesis`] is set) as black
/// reference marks across the bars. Under each group: the configuration's name, F and P.
/// Percentages with a zero denominator are left out and marked "n/a".
pub fn plot_thesis_table(
    rows: &[TableRow],
    opts: &PlotOptions,
    out: &Path,
) -> Result<(), VizError> {
    if rows.is_empty() {
        return Err(VizError::NoData("no table rows".into()));
    }
    let (w, h) = (opts.width, opts.height);
    let (mut img, fonts, fs) = canvas(w, h, 45.0, 75.0)?;
    let f = f64::from(fs);
    let title = opts
        .title
        .clone()
        .unwrap_or_else(|| "binpick eval: thesis table 5.5.2 per configuration".into());
    let ours: Vec<[f64; 6]> = rows.iter().map(|r| r.percents().as_array()).collect();
    let mut y_max: f64 = 100.0;
    for (r, o) in rows.iter().zip(&ours) {
        let theirs = r.thesis.map(|t| t.as_array()).unwrap_or([f64::NAN; 6]);
        for v in o.iter().chain(theirs.iter()) {
            if v.is_finite() {
                y_max = y_max.max(*v);
            }
        }
    }
    let any_thesis = rows.iter().any(|r| r.thesis.is_some());

    // Legend column on the right.
    let sw = f * 1.1;
    let mut legend_w = draw::text_width(&fonts.bold, fs, "bars: this run");
    for (sym, desc, _) in METRICS {
        legend_w = legend_w.max(draw::text_width(
            &fonts.regular,
            fs * 0.95,
            &format!("{sym}  {desc}"),
        ));
    }
    let legend_w = (f64::from(legend_w) + sw + f * 1.5).min(f64::from(w) * 0.4);
    let margin = f;
    let title_h = f64::from(draw::line_height(&fonts.bold, fs * 1.3)) + margin;
    let y_label_w = f64::from(draw::text_width(&fonts.regular, fs, "100")) + f * 2.6;
    let fr = Frame {
        x0: margin + y_label_w,
        y0: title_h + margin,
        x1: (f64::from(w) - legend_w - margin).max(margin + y_label_w + 1.0),
        y1: (f64::from(h) - margin - f * 3.2).max(title_h + margin + 1.0),
        xr: (0.0, rows.len() as f64),
        yr: (0.0, y_max * 1.08),
    };
    draw::text(
        &mut img,
        &fonts.bold,
        fs * 1.3,
        f64::from(w) / 2.0,
        margin * 0.5,
        Anchor::TopCenter,
        &title,
        BLACK,
        None,
    );
    draw_y_axis(&mut img, &fonts, fs, &fr, "percent", false);

    let group = 0.8;
    let bw = group / 6.0;
    let bar_px = fr.px(bw) - fr.px(0.0);
    let small = (fs * 0.8).min((bar_px * 0.5) as f32).max(6.0);
    let fits = f64::from(draw::text_width(&fonts.regular, small, "100")) <= bar_px * 1.15;
    let mark_w = (f / 6.0).round().max(2.0);
    let mut labels: Vec<(f64, f64, String)> = Vec::new();
    for (i, (row, o)) in rows.iter().zip(&ours).enumerate() {
        for (k, (_, _, c)) in METRICS.iter().enumerate() {
            let x0 = i as f64 + (1.0 - group) / 2.0 + k as f64 * bw;
            let x1 = x0 + bw * 0.88;
            let xm = fr.px((x0 + x1) / 2.0);
            let v = o[k];
            if v.is_finite() {
                bar(&mut img, &fr, x0, x1, 0.0, v, *c);
                if fits {
                    labels.push((xm, fr.py(v) - 2.0, format!("{v:.0}")));
                }
            } else {
                labels.push((xm, fr.py(0.0) - 2.0, "n/a".into()));
            }
            if let Some(t) = row.thesis {
                let tv = t.as_array()[k];
                if tv.is_finite() {
                    let pad = bar_px * 0.1;
                    let y = fr.py(tv);
                    draw::line(
                        &mut img,
                        fr.px(x0) - pad,
                        y,
                        fr.px(x1) + pad,
                        y,
                        mark_w,
                        BLACK,
                    );
                }
            }
        }
        let cx = fr.px(i as f64 + 0.5);
        draw::text(
            &mut img,
            &fonts.bold,
            fs * 1.1,
            cx,
            fr.y1 + f * 0.4,
            Anchor::TopCenter,
            &row.config,
            BLACK,
            None,
        );
        draw::text(
            &mut img,
            &fonts.regular,
            fs * 0.8,
            cx,
            fr.y1 + f * 1.8,
            Anchor::TopCenter,
            &format!("F={} P={}", row.files, row.pickable),
            [90, 90, 90],
            None,
        );
    }
    // Value labels last, with a white halo, so reference marks never hide them.
    for (x, y, s) in labels {
        draw::text(
            &mut img,
            &fonts.regular,
            small,
            x,
            y,
            Anchor::BottomCenter,
            &s,
            BLACK,
            Some((WHITE, 2)),
        );
    }

    let lx = f64::from(w) - legend_w;
    let mut y = fr.y0;
    draw::text(
        &mut img,
        &fonts.bold,
        fs,
        lx,
        y,
        Anchor::TopLeft,
        "bars: this run",
        BLACK,
        None,
    );
    y += f * 1.7;
    for (sym, desc, c) in METRICS {
        draw::fill_rect(
            &mut img,
            lx as i64,
            (y + f * 0.05) as i64,
            sw as i64,
            sw as i64,
            c,
        );
        draw::text(
            &mut img,
            &fonts.regular,
            fs * 0.95,
            lx + sw + f * 0.5,
            y,
            Anchor::TopLeft,
            &format!("{sym}  {desc}"),
            BLACK,
            None,
        );
        y += f * 1.5;
    }
    if any_thesis {
        y += f * 0.5;
        draw::line(
            &mut img,
            lx - 1.0,
            y + sw / 2.0,
            lx + sw + 1.0,
            y + sw / 2.0,
            mark_w,
            BLACK,
        );
        draw::text(
            &mut img,
            &fonts.regular,
            fs * 0.95,
            lx + sw + f * 0.5,
            y,
            Anchor::TopLeft,
            "thesis value (5.5.2)",
            BLACK,
            None,
        );
        y += f * 1.5;
    }
    y += f * 0.8;
    for line in [
        "\u{2191} higher is better, \u{2193} lower is better",
        "P = pickable objects, F = files",
    ] {
        draw::text(
            &mut img,
            &fonts.regular,
            fs * 0.8,
            lx,
            y,
            Anchor::TopLeft,
            line,
            [90, 90, 90],
            None,
        );
        y += f * 1.2;
    }
    draw::save_png(&img, out)
}

/// Histogram of per-scene times (ms) with the median (solid line) and the 95th percentile
/// (dashed line) marked and named in a legend. Bins follow the Freedman-Diaconis rule
/// (1..=60 bins). Non-finite times are skipped; no finite time at all is an error. Returns
/// the statistics drawn.
pub fn plot_time_histogram(
    times_ms: &[f64],
    opts: &PlotOptions,
    out: &Path,
) -> Result<TimeStats, VizError> {
    let stats = TimeStats::from_times(times_ms)
        .ok_or_else(|| VizError::NoData("no finite times".into()))?;
    let (w, h) = (opts.width, opts.height);
    let (mut img, fonts, fs) = canvas(w, h, 40.0, 65.0)?;
    let f = f64::from(fs);
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
    let mut counts = vec![0usize; bins];
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
    let margin = f;
    let title_h = f64::from(draw::line_height(&fonts.bold, fs * 1.2)) + margin;
    let y_label_w = f64::from(draw::text_width(&fonts.regular, fs, &c_max.to_string())) + f * 2.6;
    let xpad = (hi - lo) * 0.03;
    let fr = Frame {
        x0: margin + y_label_w,
        y0: title_h + margin,
        x1: (f64::from(w) - margin * 1.5).max(margin + y_label_w + 1.0),
        y1: (f64::from(h) - margin - f * 2.8).max(title_h + margin + 1.0),
        xr: (lo - xpad, hi + xpad),
        yr: (0.0, c_max as f64 * 1.15),
    };
    draw::text(
        &mut img,
        &fonts.bold,
        fs * 1.2,
        f64::from(w) / 2.0,
        margin * 0.5,
        Anchor::TopCenter,
        &title,
        BLACK,
        None,
    );
    draw_y_axis(&mut img, &fonts, fs, &fr, "scenes", true);
    let (xt, xstep) = ticks(
        fr.xr.0,
        fr.xr.1,
        ((fr.x1 - fr.x0) / (f * 6.0)).clamp(2.0, 12.0) as usize,
    );
    for t in xt {
        let x = fr.px(t).round();
        draw::fill_rect(&mut img, x as i64, fr.y1 as i64, 1, 5, BLACK);
        draw::text(
            &mut img,
            &fonts.regular,
            fs,
            x,
            fr.y1 + 6.0,
            Anchor::TopCenter,
            &tick_label(t, xstep),
            BLACK,
            None,
        );
    }
    draw::text(
        &mut img,
        &fonts.regular,
        fs,
        (fr.x0 + fr.x1) / 2.0,
        fr.y1 + f * 1.6,
        Anchor::TopCenter,
        "time per scene (ms)",
        BLACK,
        None,
    );
    let fill = [158, 190, 218];
    let edge = [70, 110, 150];
    for (i, &c) in counts.iter().enumerate() {
        if c == 0 {
            continue;
        }
        let x0 = lo + i as f64 * width;
        bar(&mut img, &fr, x0, x0 + width, 0.0, c as f64, edge);
        let (a, b) = (fr.px(x0).round(), fr.px(x0 + width).round());
        let top = fr.py(c as f64).round();
        if b - a > 2.0 {
            draw::fill_rect(
                &mut img,
                a as i64 + 1,
                top as i64 + 1,
                (b - a - 2.0) as i64,
                (fr.y1 - top - 1.0) as i64,
                fill,
            );
        }
    }
    let median_c = [20, 40, 140];
    let p95_c = [200, 30, 30];
    let lw = (f / 7.0).round().max(2.0);
    let (mx, px95) = (fr.px(stats.median), fr.px(stats.p95));
    draw::line(&mut img, mx, fr.y0, mx, fr.y1, lw, median_c);
    dashed(&mut img, px95, fr.y0, px95, fr.y1, lw, f * 0.6, p95_c);

    // Legend box on the side with fewer scenes.
    let entries = [
        format!("scenes per {} ms bin", short_num(width)),
        format!("median {:.1} ms", stats.median),
        format!("95th percentile {:.1} ms", stats.p95),
    ];
    let text_w = entries
        .iter()
        .map(|e| draw::text_width(&fonts.regular, fs, e))
        .fold(0.0f32, f32::max);
    let sym_w = f * 2.0;
    let box_w = f64::from(text_w) + sym_w + f * 1.5;
    let box_h = f * 1.5 * entries.len() as f64 + f * 0.6;
    let left_mass: usize = counts[..bins / 2].iter().sum();
    let right_mass: usize = counts[bins / 2..].iter().sum();
    let bx = if right_mass <= left_mass {
        fr.x1 - box_w - f * 0.5
    } else {
        fr.x0 + f * 0.5
    };
    let by = fr.y0 + f * 0.5;
    draw::fill_rect(
        &mut img,
        bx as i64,
        by as i64,
        box_w as i64,
        box_h as i64,
        WHITE,
    );
    draw::stroke_rect(
        &mut img,
        bx as i64,
        by as i64,
        box_w as i64,
        box_h as i64,
        1,
        [150, 150, 150],
    );
    let mut y = by + f * 0.4;
    for (i, e) in entries.iter().enumerate() {
        let (sx, sy) = (bx + f * 0.5, y + f * 0.6);
        match i {
            0 => {
                draw::fill_rect(
                    &mut img,
                    sx as i64,
                    (sy - f * 0.45) as i64,
                    sym_w as i64,
                    (f * 0.9) as i64,
                    edge,
                );
                draw::fill_rect(
                    &mut img,
                    sx as i64 + 1,
                    (sy - f * 0.45) as i64 + 1,
                    sym_w as i64 - 2,
                    (f * 0.9) as i64 - 2,
                    fill,
                );
            }
            1 => draw::line(&mut img, sx, sy, sx + sym_w, sy, lw, median_c),
            _ => dashed(&mut img, sx, sy, sx + sym_w, sy, lw, sym_w / 3.0, p95_c),
        }
        draw::text(
            &mut img,
            &fonts.regular,
            fs,
            sx + sym_w + f * 0.5,
            y,
            Anchor::TopLeft,
            e,
            BLACK,
            None,
        );
        y += f * 1.5;
    }
    draw::save_png(&img, out)?;
    Ok(stats)
}
