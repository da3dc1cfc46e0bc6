//! The PNG render: a software point renderer with a z-buffer, two orthographic views side by
//! side (the scanner's and an oblique one), rank labels, legend and title.
//!
//! Each point is splatted as a small disc whose radius comes from the point density in that
//! view (the median number of points per occupied cell of a coarse pixel grid) unless
//! [`RenderOptions::point_radius_px`] fixes it. Scene points are coloured by height along
//! `up` on a low-saturation ramp; the detections' model points are drawn in saturated colours
//! on a second z-buffer and win over scene points at (almost) the same depth, so a model
//! aligned to the scene surface shows. Both layers are then shaded by screen-space "eye-dome"
//! obscurance of the depth buffer, which outlines parts that lie on top of others.
//! Everything is sequential and ordered, so the output is deterministic.

use std::collections::HashMap;
use std::path::Path;

use ab_glyph::FontRef;
use binpick_cloud::{PointCloud, to_point3};
use image::RgbImage;
use nalgebra::Vector3;

use crate::color::{brightness, height_color, mix, rank_color, score_color, shade};
use crate::draw::{self, Anchor, BLACK, Fonts, Rgb, WHITE};
use crate::{ColorBy, Placed, RenderOptions, VizError, check_size, finite_pose, finite3};

/// A rectangle of pixels, `x..x + width`, `y..y + height` (y grows downwards).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct PixelRect {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

impl PixelRect {
    /// Whether the pixel coordinate (continuous, pixel `i` covers `i..i+1`) lies inside.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= f64::from(self.x)
            && y >= f64::from(self.y)
            && x < f64::from(self.x) + f64::from(self.width)
            && y < f64::from(self.y) + f64::from(self.height)
    }
}

/// How one of the two views maps millimetres to pixels (orthographic).
#[derive(Clone, Debug, PartialEq)]
pub struct ViewInfo {
    /// "scanner" or "oblique".
    pub name: String,
    /// The whole panel, caption included.
    pub panel: PixelRect,
    /// The part of the panel the points are drawn in.
    pub plot: PixelRect,
    /// Scene direction that points right on screen (unit).
    pub right: [f64; 3],
    /// Scene direction that points up on screen (unit).
    pub screen_up: [f64; 3],
    /// Scene direction from the scene towards the viewer (unit); larger `p . toward_viewer`
    /// is nearer.
    pub toward_viewer: [f64; 3],
    /// The screen coordinates (mm along `right`, `screen_up`) shown at the plot's centre.
    pub center_mm: [f64; 2],
    /// Scale, pixels per millimetre.
    pub px_per_mm: f64,
    /// Splat radius of scene points, pixels (0 = single pixel).
    pub scene_radius_px: u32,
    /// Splat radius of model points, pixels.
    pub model_radius_px: u32,
    /// Per entry of `placed`: where its rank label was drawn (pixel centre), `None` if the
    /// detection was skipped or its label fell outside the plot.
    pub labels: Vec<Option<[f64; 2]>>,
}

impl ViewInfo {
    /// Pixel coordinates (x right, y down; continuous) of a scene point in millimetres.
    pub fn project(&self, p: [f64; 3]) -> [f64; 2] {
        let x = dot(p, self.right);
        let y = dot(p, self.screen_up);
        let cx = f64::from(self.plot.x) + f64::from(self.plot.width) / 2.0;
        let cy = f64::from(self.plot.y) + f64::from(self.plot.height) / 2.0;
        [
            cx + (x - self.center_mm[0]) * self.px_per_mm,
            cy - (y - self.center_mm[1]) * self.px_per_mm,
        ]
    }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// What [`render_png`] drew.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderInfo {
    pub width: u32,
    pub height: u32,
    /// Finite scene points drawn (each in both views, where inside the view).
    pub scene_points: usize,
    /// Scene points skipped for a NaN/infinite coordinate.
    pub scene_non_finite: usize,
    /// Finite model points (drawn once per detection).
    pub model_points: usize,
    /// Model points skipped for a NaN/infinite coordinate.
    pub model_non_finite: usize,
    /// Detections drawn.
    pub detections_drawn: usize,
    /// Indices into `placed` of detections not drawn (non-finite pose).
    pub detections_skipped: Vec<usize>,
    /// Per entry of `placed`: its colour in the image.
    pub colors: Vec<[u8; 3]>,
    /// Legend rows shown (fewer than the detections when they do not all fit).
    pub legend_rows: usize,
    /// The scanner view, then the oblique view.
    pub views: Vec<ViewInfo>,
}

/// Renders the scene with every detection overlaid, from the scanner's view and an oblique
/// view side by side, with labels, legend and title, and writes it as PNG to `out`.
///
/// Errors: image size outside [`crate::MIN_SIZE`]..=[`crate::MAX_SIZE`], a scene without finite
/// points, detections with a model without finite points, invalid options, or a write error.
/// NaN/infinite points are skipped (counted in the returned [`RenderInfo`]); detections with a
/// non-finite pose are listed in the legend as invalid and not drawn. With no detections the
/// scene is still rendered and the image says "no detections".
pub fn render_png(
    scene: &PointCloud,
    model: &PointCloud,
    placed: &[Placed],
    opts: &RenderOptions,
    out: &Path,
) -> Result<RenderInfo, VizError> {
    let (img, info) = render(scene, model, placed, opts)?;
    draw::save_png(&img, out)?;
    Ok(info)
}

fn unit(v: [f64; 3], what: &str) -> Result<Vector3<f64>, VizError> {
    let v = Vector3::from(v);
    let n = v.norm();
    if !n.is_finite() || n < 1e-12 {
        return Err(VizError::InvalidOption(format!(
            "{what} must be a finite non-zero vector, got {:?}",
            [v.x, v.y, v.z]
        )));
    }
    Ok(v / n)
}

/// Orthographic camera: screen right, screen up and the direction towards the viewer.
#[derive(Clone, Copy)]
struct Camera {
    right: Vector3<f64>,
    up: Vector3<f64>,
    back: Vector3<f64>,
}

/// Two unit vectors spanning the plane perpendicular to `u` (`e1 x e2 = u`); `e1` comes from
/// the world axis least aligned with `u`, so with `u = +z` they are `+x` and `+y`.
fn horizontal_basis(u: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let mut axis = 0;
    for i in 1..3 {
        if u[i].abs() < u[axis].abs() - 1e-12 {
            axis = i;
        }
    }
    let mut a = Vector3::zeros();
    a[axis] = 1.0;
    let e1 = (a - u * a.dot(u)).normalize();
    let e2 = u.cross(&e1);
    (e1, e2)
}

fn camera(back: Vector3<f64>, preferred_up: Vector3<f64>, fallback_up: Vector3<f64>) -> Camera {
    let mut su = preferred_up - back * preferred_up.dot(&back);
    if su.norm() < 0.2 {
        su = fallback_up - back * fallback_up.dot(&back);
    }
    let su = su.normalize();
    let right = su.cross(&back);
    Camera {
        right,
        up: su,
        back,
    }
}

/// Median-based point spacing in pixels of projected points (see the module docs).
fn spacing_px(pts: &[[f64; 2]]) -> f64 {
    if pts.is_empty() {
        return 1.0;
    }
    let mut g = 8.0f64;
    loop {
        let mut cells: HashMap<(i64, i64), u32> = HashMap::new();
        for p in pts {
            *cells
                .entry(((p[0] / g).floor() as i64, (p[1] / g).floor() as i64))
                .or_insert(0) += 1;
        }
        let mut counts: Vec<u32> = cells.into_values().collect();
        counts.sort_unstable();
        let m = f64::from(counts.get(counts.len() / 2).copied().unwrap_or(1).max(1));
        if m >= 6.0 || g >= 256.0 {
            return g / m.sqrt();
        }
        g *= 2.0;
    }
}

/// Splat radius that closes the gaps of a square grid of this spacing (half its diagonal,
/// plus half a pixel for rounding to pixel centres).
fn radius_from_spacing(s: f64) -> u32 {
    (s * 0.71 + 0.5).round().clamp(1.0, 24.0) as u32
}

/// Quantile of an unsorted slice (sorted copy; nearest rank).
fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s: Vec<f64> = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return 0.0;
    }
    let i = ((s.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    s[i.min(s.len() - 1)]
}

pub(crate) fn fmt_num(v: f64) -> String {
    if !v.is_finite() {
        "n/a".into()
    } else if v.abs() >= 1000.0 {
        format!("{v:.0}")
    } else if v.abs() >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

fn nice_length(target: f64) -> f64 {
    if !(target.is_finite() && target > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(target.log10().floor());
    let m = target / p;
    let n = if m < 1.5 {
        1.0
    } else if m < 3.5 {
        2.0
    } else if m < 7.5 {
        5.0
    } else {
        10.0
    };
    n * p
}

/// One detection, ready to draw.
struct Det {
    index: usize,
    pts: Vec<Vector3<f64>>,
    centroid: Vector3<f64>,
    color: Rgb,
}

struct Layout {
    fs: f32,
    margin: i64,
    legend: PixelRect,
    panels: [PixelRect; 2],
    caption_h: i64,
}

fn layout(w: u32, h: u32, fonts: &Fonts, placed: &[Placed], color_by: ColorBy) -> Layout {
    let fs = (f64::from(h) / 50.0)
        .min(f64::from(w) / 90.0)
        .clamp(8.0, 40.0) as f32;
    let margin = (f64::from(fs) * 0.5).round().max(2.0) as i64;
    let title_h = draw::line_height(&fonts.bold, fs * 1.25).ceil() as i64 + 2 * margin;
    // Legend width: the widest row at the legend's font size.
    let mut widest = draw::text_width(&fonts.bold, fs, "Detections (colour = score)");
    let columns = Columns::of(placed, color_by);
    for line in columns.notes() {
        widest = widest.max(draw::text_width(&fonts.regular, fs * 0.85, line));
    }
    let row_w = |p: &Placed| {
        let [a, b] = columns.values(p);
        fs * 2.2
            + draw::text_width(&fonts.bold, fs, &format!("#{}", p.rank)).max(fs * 2.2)
            + draw::text_width(&fonts.regular, fs, &a).max(fs * 3.5)
            + draw::text_width(&fonts.regular, fs, &b).max(fs * 3.5)
            + fs * 2.0
    };
    for p in placed.iter().take(200) {
        widest = widest.max(row_w(p));
    }
    let legend_w = (f64::from(widest) + 2.0 * margin as f64)
        .min(f64::from(w) * 0.3)
        .max(1.0) as i64;
    let lx = i64::from(w) - legend_w - margin;
    let top = title_h;
    let bottom = i64::from(h) - margin;
    let panels_w = (lx - 2 * margin).max(2);
    let pw = ((panels_w - margin) / 2).max(1);
    let ph = (bottom - top).max(1);
    let caption_h = draw::line_height(&fonts.regular, fs).ceil() as i64 + margin / 2 + 2;
    let rect = |x: i64, y: i64, w: i64, h: i64| PixelRect {
        x: x.max(0) as u32,
        y: y.max(0) as u32,
        width: w.max(1) as u32,
        height: h.max(1) as u32,
    };
    Layout {
        fs,
        margin,
        legend: rect(lx, top, legend_w, ph),
        panels: [
            rect(margin, top, pw, ph),
            rect(margin + pw + margin, top, pw, ph),
        ],
        caption_h,
    }
}

const LEGEND_NOTES: [&str; 3] = [
    "final = % model points that are",
    "outliers after ICP (lower = better)",
    "initial = coarse alignment score",
];

/// Dark red of the notices ("no detections", "no pick").
const NOTICE_RED: [u8; 3] = [170, 20, 20];

/// The legend's notes when it shows the view check ([`crate::Seen`]).
const SEEN_NOTES: [&str; 3] = [
    "vis = % of its visible surface",
    "the scan confirms (higher = better)",
    "fit = 1 when the scan lies on it",
];

/// The legend's two figures per detection: the view check when every detection has one
/// (scene voting) and colours follow the rank, else the thesis's final and initial scores
/// (colours by final score keep the score they show). Headers, notes, values.
struct Columns {
    seen: bool,
}

impl Columns {
    fn of(placed: &[Placed], color_by: ColorBy) -> Self {
        Self {
            seen: color_by == ColorBy::Rank
                && !placed.is_empty()
                && placed.iter().all(|p| p.seen.is_some()),
        }
    }

    fn headers(&self) -> [&'static str; 2] {
        if self.seen {
            ["vis %", "fit"]
        } else {
            ["final %", "initial"]
        }
    }

    fn notes(&self) -> [&'static str; 3] {
        if self.seen { SEEN_NOTES } else { LEGEND_NOTES }
    }

    fn values(&self, p: &Placed) -> [String; 2] {
        match p.seen.filter(|_| self.seen) {
            Some(v) => [fmt_num(100.0 * v.visibility), format!("{:.2}", v.fit)],
            None => [fmt_num(p.final_score), fmt_num(p.initial_score)],
        }
    }
}

fn render(
    scene: &PointCloud,
    model: &PointCloud,
    placed: &[Placed],
    opts: &RenderOptions,
) -> Result<(RgbImage, RenderInfo), VizError> {
    check_size(opts.width, opts.height)?;
    let up = unit(opts.up, "up")?;
    let view_dir = match opts.view_dir {
        Some(v) => unit(v, "view_dir")?,
        None => -up,
    };
    let el = opts.oblique_elevation_deg;
    let az = opts.oblique_azimuth_deg;
    if !(el.is_finite() && (-90.0..=90.0).contains(&el)) {
        return Err(VizError::InvalidOption(format!(
            "oblique_elevation_deg must be within -90..=90, got {el}"
        )));
    }
    if !az.is_finite() {
        return Err(VizError::InvalidOption(format!(
            "oblique_azimuth_deg must be finite, got {az}"
        )));
    }
    if let Some((lo, hi)) = opts.score_range {
        if !(lo.is_finite() && hi.is_finite() && hi > lo) {
            return Err(VizError::InvalidOption(format!(
                "score_range must be finite with lo < hi, got ({lo}, {hi})"
            )));
        }
    }
    let fonts = Fonts::load()?;

    // --- points -----------------------------------------------------------------------
    // A cloud's finite points, and how many were not.
    let finite = |cloud: &PointCloud| -> (Vec<Vector3<f64>>, usize) {
        let pts: Vec<Vector3<f64>> = cloud
            .points
            .iter()
            .filter(|p| finite3(p))
            .map(|p| to_point3(p).coords)
            .collect();
        let skipped = cloud.points.len() - pts.len();
        (pts, skipped)
    };
    let (scene_pts, scene_non_finite) = finite(scene);
    if scene_pts.is_empty() {
        return Err(VizError::EmptyScene {
            non_finite: scene_non_finite,
        });
    }
    let (model_pts, model_non_finite) = finite(model);
    if !placed.is_empty() && model_pts.is_empty() {
        return Err(VizError::EmptyModel {
            non_finite: model_non_finite,
        });
    }
    let (score_lo, score_hi) = opts.score_range.unwrap_or_else(|| {
        let max = placed
            .iter()
            .map(|p| p.final_score)
            .filter(|s| s.is_finite())
            .fold(1.0f64, f64::max);
        (0.0, max)
    });
    let colors: Vec<Rgb> = placed
        .iter()
        .map(|p| match opts.color_by {
            ColorBy::Rank => rank_color(p.rank),
            ColorBy::FinalScore => score_color(p.final_score, score_lo, score_hi),
        })
        .collect();
    let mut dets = Vec::new();
    let mut skipped = Vec::new();
    for (i, p) in placed.iter().enumerate() {
        if !finite_pose(&p.pose) {
            skipped.push(i);
            continue;
        }
        let pts: Vec<Vector3<f64>> = model_pts
            .iter()
            .map(|m| (p.pose * nalgebra::Point3::from(*m)).coords)
            .collect();
        let centroid = pts.iter().sum::<Vector3<f64>>() / pts.len().max(1) as f64;
        dets.push(Det {
            index: i,
            pts,
            centroid,
            color: colors[i],
        });
    }
    let heights: Vec<f64> = scene_pts.iter().map(|p| p.dot(&up)).collect();
    let h_lo = quantile(&heights, 0.01);
    let mut h_hi = quantile(&heights, 0.99);
    if h_hi - h_lo < 1e-6 {
        h_hi = h_lo + 1.0;
    }

    // --- cameras ----------------------------------------------------------------------
    let (e1, e2) = horizontal_basis(&up);
    let back0 = -view_dir;
    let scanner = if back0.dot(&up).abs() > 0.7 {
        camera(back0, e2, up)
    } else {
        camera(back0, up, e2)
    };
    let (elr, azr) = (el.to_radians(), az.to_radians());
    let horiz = -e2 * azr.cos() + e1 * azr.sin();
    let oblique = camera(horiz * elr.cos() + up * elr.sin(), up, e2);

    // --- image ------------------------------------------------------------------------
    let lay = layout(opts.width, opts.height, &fonts, placed, opts.color_by);
    let mut img = RgbImage::from_pixel(opts.width, opts.height, image::Rgb(WHITE));
    let captions = [
        if opts.view_dir.is_some() {
            "Scanner view (orthographic, along view direction)".to_string()
        } else {
            "Scanner view (orthographic, looking along \u{2212}up)".to_string()
        },
        format!("Oblique view ({el:.0}\u{b0} elevation, orthographic)"),
    ];
    let mut views = Vec::new();
    for (k, cam) in [scanner, oblique].iter().enumerate() {
        let v = draw_view(
            &mut img,
            &fonts,
            &lay,
            lay.panels[k],
            &captions[k],
            if k == 0 { "scanner" } else { "oblique" },
            cam,
            &scene_pts,
            (&heights, h_lo, h_hi),
            &dets,
            placed,
            opts,
            k == 0,
        );
        views.push(v);
    }
    let legend_rows = draw_legend(
        &mut img,
        &fonts,
        &lay,
        placed,
        &colors,
        &skipped,
        opts,
        (score_lo, score_hi),
        (h_lo, h_hi),
    );
    // Title.
    let title = opts
        .title
        .clone()
        .unwrap_or_else(|| "binpick result".into());
    let n = dets.len();
    let what = if n == 0 {
        "no detections".to_string()
    } else if n == 1 {
        "1 detection".to_string()
    } else {
        format!("{n} detections")
    };
    let mut line = format!(
        "{title} \u{2014} {what} \u{b7} scene {} points",
        scene_pts.len()
    );
    if scene_non_finite > 0 {
        line.push_str(&format!(" ({scene_non_finite} non-finite skipped)"));
    }
    if !skipped.is_empty() {
        line.push_str(&format!(
            " \u{b7} {} invalid pose(s) not drawn",
            skipped.len()
        ));
    }
    draw::text(
        &mut img,
        &fonts.bold,
        lay.fs * 1.25,
        lay.margin as f64,
        lay.margin as f64,
        Anchor::TopLeft,
        &line,
        BLACK,
        None,
    );
    let info = RenderInfo {
        width: opts.width,
        height: opts.height,
        scene_points: scene_pts.len(),
        scene_non_finite,
        model_points: model_pts.len(),
        model_non_finite,
        detections_drawn: dets.len(),
        detections_skipped: skipped,
        colors,
        legend_rows,
        views,
    };
    Ok((img, info))
}

#[allow(clippy::too_many_arguments)]
fn draw_view(
    img: &mut RgbImage,
    fonts: &Fonts,
    lay: &Layout,
    panel: PixelRect,
    caption: &str,
    name: &str,
    cam: &Camera,
    scene: &[Vector3<f64>],
    (heights, h_lo, h_hi): (&[f64], f64, f64),
    dets: &[Det],
    placed: &[Placed],
    opts: &RenderOptions,
    scale_bar: bool,
) -> ViewInfo {
    let fs = lay.fs;
    // The full caption, or its first two words when the panel is too narrow for it.
    let short: String = caption.split(' ').take(2).collect::<Vec<_>>().join(" ");
    for c in [caption, short.as_str()] {
        if f64::from(draw::text_width(&fonts.regular, fs, c)) + 2.0 <= f64::from(panel.width) {
            draw::text(
                img,
                &fonts.regular,
                fs,
                f64::from(panel.x) + 2.0,
                f64::from(panel.y),
                Anchor::TopLeft,
                c,
                [40, 40, 40],
                None,
            );
            break;
        }
    }
    let plot = PixelRect {
        x: panel.x,
        y: panel.y + lay.caption_h.max(0) as u32,
        width: panel.width,
        height: (i64::from(panel.height) - lay.caption_h).max(1) as u32,
    };
    let proj = |p: &Vector3<f64>| [p.dot(&cam.right), p.dot(&cam.up), p.dot(&cam.back)];
    let sp: Vec<[f64; 3]> = scene.iter().map(proj).collect();
    let mp: Vec<Vec<[f64; 3]>> = dets
        .iter()
        .map(|d| d.pts.iter().map(proj).collect())
        .collect();

    // Fit: robust scene extent (0.1 %..99.9 %, so stray scanner points do not shrink the
    // picture) united with every drawn model point.
    let (qlo, qhi) = if sp.len() >= 1000 {
        (0.001, 0.999)
    } else {
        (0.0, 1.0)
    };
    let xs: Vec<f64> = sp.iter().map(|p| p[0]).collect();
    let ys: Vec<f64> = sp.iter().map(|p| p[1]).collect();
    let (mut x0, mut x1) = (quantile(&xs, qlo), quantile(&xs, qhi));
    let (mut y0, mut y1) = (quantile(&ys, qlo), quantile(&ys, qhi));
    for p in mp.iter().flatten() {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    let span_x = (x1 - x0).max(1e-3) * 1.04;
    let span_y = (y1 - y0).max(1e-3) * 1.04;
    let avail_w = (f64::from(plot.width) - 2.0).max(1.0);
    let avail_h = (f64::from(plot.height) - 2.0).max(1.0);
    let s = (avail_w / span_x).min(avail_h / span_y);
    let mut view = ViewInfo {
        name: name.into(),
        panel,
        plot,
        right: cam.right.into(),
        screen_up: cam.up.into(),
        toward_viewer: cam.back.into(),
        center_mm: [(x0 + x1) / 2.0, (y0 + y1) / 2.0],
        px_per_mm: s,
        scene_radius_px: 0,
        model_radius_px: 0,
        labels: vec![None; placed.len()],
    };
    let (pw, ph) = (plot.width as usize, plot.height as usize);
    let to_px = |p: &[f64; 3]| {
        let cx = f64::from(plot.width) / 2.0;
        let cy = f64::from(plot.height) / 2.0;
        [
            cx + (p[0] - view.center_mm[0]) * s,
            cy - (p[1] - view.center_mm[1]) * s,
        ]
    };
    let scene_px: Vec<[f64; 2]> = sp.iter().map(to_px).collect();
    let model_px: Vec<Vec<[f64; 2]>> = mp.iter().map(|v| v.iter().map(to_px).collect()).collect();
    let r_scene = opts
        .point_radius_px
        .map_or_else(|| radius_from_spacing(spacing_px(&scene_px)), |r| r.min(64));
    let all_model: Vec<[f64; 2]> = model_px.iter().flatten().copied().collect();
    let r_model = if all_model.is_empty() {
        r_scene
    } else {
        radius_from_spacing(spacing_px(&all_model)).max(r_scene)
    };
    view.scene_radius_px = r_scene;
    view.model_radius_px = r_model;

    // --- z-buffers --------------------------------------------------------------------
    let n = pw * ph;
    let mut sdepth = vec![f32::NEG_INFINITY; n];
    let mut scol = vec![[0u8; 3]; n];
    let mut mdepth = vec![f32::NEG_INFINITY; n];
    let mut mid = vec![u32::MAX; n];
    let disc = |r: u32| -> Vec<(i64, i64)> {
        let r = i64::from(r);
        let mut v = Vec::new();
        for dy in -r..=r {
            for dx in -r..=r {
                if dx * dx + dy * dy <= r * r + r {
                    v.push((dx, dy));
                }
            }
        }
        v
    };
    let scene_disc = disc(r_scene);
    let model_disc = disc(r_model);
    for (i, p) in scene_px.iter().enumerate() {
        let t = (heights[i] - h_lo) / (h_hi - h_lo);
        let c = height_color(t);
        let d = sp[i][2] as f32;
        let (bx, by) = (p[0].floor() as i64, p[1].floor() as i64);
        for &(dx, dy) in &scene_disc {
            let (x, y) = (bx + dx, by + dy);
            if x < 0 || y < 0 || x >= pw as i64 || y >= ph as i64 {
                continue;
            }
            let k = y as usize * pw + x as usize;
            if d > sdepth[k] {
                sdepth[k] = d;
                scol[k] = c;
            }
        }
    }
    // Detections in rank order; where two overlap at (nearly) the same depth the better rank
    // keeps the pixel instead of both flickering in depth noise.
    let mut by_rank: Vec<usize> = (0..dets.len()).collect();
    by_rank.sort_by_key(|&j| (placed[dets[j].index].rank, dets[j].index));
    let tie = (0.5 / s.max(1e-12)) as f32;
    for j in by_rank {
        for (i, p) in model_px[j].iter().enumerate() {
            let d = mp[j][i][2] as f32;
            let (bx, by) = (p[0].floor() as i64, p[1].floor() as i64);
            for &(dx, dy) in &model_disc {
                let (x, y) = (bx + dx, by + dy);
                if x < 0 || y < 0 || x >= pw as i64 || y >= ph as i64 {
                    continue;
                }
                let k = y as usize * pw + x as usize;
                let other = mid[k] != u32::MAX && mid[k] != j as u32;
                if d > mdepth[k] + if other { tie } else { 0.0 } {
                    mdepth[k] = d;
                    mid[k] = j as u32;
                }
            }
        }
    }

    // --- compose with eye-dome shading -------------------------------------------------
    let mm_per_px = 1.0 / s.max(1e-12);
    // A model point wins over scene points up to this much nearer than it: the model lies
    // on the surface it was aligned to, within noise and alignment error.
    let bias = (3.0 * mm_per_px * f64::from(r_scene.max(1))).max(3.0) as f32;
    let mut shown = vec![f32::NEG_INFINITY; n];
    let mut is_model = vec![false; n];
    for k in 0..n {
        if mid[k] != u32::MAX && mdepth[k] + bias >= sdepth[k] {
            shown[k] = mdepth[k].max(sdepth[k]);
            is_model[k] = true;
        } else {
            shown[k] = sdepth[k];
        }
    }
    let step = i64::from(r_scene.max(1));
    let offsets: [(i64, i64); 8] = [
        (step, 0),
        (-step, 0),
        (0, step),
        (0, -step),
        (step, step),
        (-step, step),
        (step, -step),
        (-step, -step),
    ];
    for y in 0..ph as i64 {
        for x in 0..pw as i64 {
            let k = y as usize * pw + x as usize;
            let d = shown[k];
            if !d.is_finite() {
                continue;
            }
            let mut obsc = 0.0f64;
            for &(dx, dy) in &offsets {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= pw as i64 || ny >= ph as i64 {
                    continue;
                }
                let dn = shown[ny as usize * pw + nx as usize];
                if !dn.is_finite() {
                    continue;
                }
                let dist = (((dx * dx + dy * dy) as f64).sqrt()) * mm_per_px;
                obsc += (f64::from(dn - d) / dist).max(0.0);
            }
            let sh = (-0.9 * obsc / 8.0).exp();
            let c = if is_model[k] {
                let base = dets[mid[k] as usize].color;
                shade(base, 0.55 + 0.45 * sh)
            } else {
                let sc = shade(scol[k], 0.3 + 0.7 * sh);
                if opts.show_occluded && mid[k] != u32::MAX {
                    mix(sc, dets[mid[k] as usize].color, 0.4)
                } else {
                    sc
                }
            };
            draw::put(img, i64::from(plot.x) + x, i64::from(plot.y) + y, c);
        }
    }
    draw::stroke_rect(
        img,
        i64::from(plot.x),
        i64::from(plot.y),
        i64::from(plot.width),
        i64::from(plot.height),
        1,
        [190, 190, 190],
    );

    // --- overlays -----------------------------------------------------------------------
    if dets.is_empty() {
        draw::text(
            img,
            &fonts.bold,
            fs * 1.6,
            f64::from(plot.x) + f64::from(plot.width) / 2.0,
            f64::from(plot.y) + f64::from(fs) * 2.0,
            Anchor::Center,
            "no detections",
            NOTICE_RED,
            Some((WHITE, (fs / 6.0).ceil() as u32)),
        );
    }
    if scale_bar {
        let len_mm = nice_length(f64::from(plot.width) * 0.18 / s);
        let len_px = len_mm * s;
        let x0 = f64::from(plot.x) + f64::from(fs);
        let y0 = f64::from(plot.y) + f64::from(plot.height) - f64::from(fs) * 1.2;
        if len_px > 4.0 && len_px < f64::from(plot.width) {
            let th = (f64::from(fs) / 5.0).max(2.0);
            draw::line(img, x0, y0, x0 + len_px, y0, th + 4.0, WHITE);
            draw::line(img, x0, y0, x0 + len_px, y0, th, BLACK);
            for xe in [x0, x0 + len_px] {
                draw::line(img, xe, y0 - th * 1.5, xe, y0 + th * 1.5, th * 0.6, BLACK);
            }
            let label = if len_mm >= 1.0 {
                format!("{len_mm:.0} mm")
            } else {
                format!("{len_mm} mm")
            };
            draw::text(
                img,
                &fonts.regular,
                fs * 0.9,
                x0 + len_px / 2.0,
                y0 - f64::from(fs) * 0.9,
                Anchor::Center,
                &label,
                BLACK,
                Some((WHITE, 2)),
            );
        }
    }
    draw_axes(img, fonts, fs, &plot, cam);

    // Rank labels: a disc in the detection's colour with a black ring, the rank in white
    // with a black outline, at the projected centroid; nudged apart when they would
    // overlap, with a leader line back to the part.
    let mut taken: Vec<[f64; 2]> = Vec::new();
    let mut order: Vec<usize> = (0..dets.len()).collect();
    order.sort_by_key(|&j| (placed[dets[j].index].rank, dets[j].index));
    let cxp = f64::from(plot.x) + f64::from(plot.width) / 2.0;
    let cyp = f64::from(plot.y) + f64::from(plot.height) / 2.0;
    for j in order {
        let det = &dets[j];
        let c = det.centroid;
        let x = c.dot(&cam.right);
        let y = c.dot(&cam.up);
        let ax = cxp + (x - view.center_mm[0]) * s;
        let ay = cyp - (y - view.center_mm[1]) * s;
        let label = format!("{}", placed[det.index].rank);
        let tw = f64::from(draw::text_width(&fonts.bold, fs * 1.1, &label));
        let r = (f64::from(fs) * 0.85).max(tw / 2.0 + 3.0);
        let mut pos = [ax, ay];
        let candidates = [
            (0.0, 0.0),
            (0.0, -1.0),
            (1.0, 0.0),
            (0.0, 1.0),
            (-1.0, 0.0),
            (1.0, -1.0),
            (-1.0, -1.0),
            (1.0, 1.0),
            (-1.0, 1.0),
            (0.0, -2.0),
            (2.0, 0.0),
            (0.0, 2.0),
            (-2.0, 0.0),
        ];
        for (ox, oy) in candidates {
            let cand = [ax + ox * 2.2 * r, ay + oy * 2.2 * r];
            if taken
                .iter()
                .all(|t| (t[0] - cand[0]).hypot(t[1] - cand[1]) >= 2.0 * r + 2.0)
            {
                pos = cand;
                break;
            }
        }
        let lo_x = f64::from(plot.x) + r + 1.0;
        let hi_x = f64::from(plot.x) + f64::from(plot.width) - r - 1.0;
        let lo_y = f64::from(plot.y) + r + 1.0;
        let hi_y = f64::from(plot.y) + f64::from(plot.height) - r - 1.0;
        if lo_x <= hi_x && lo_y <= hi_y {
            pos = [pos[0].clamp(lo_x, hi_x), pos[1].clamp(lo_y, hi_y)];
        }
        if !plot.contains(pos[0], pos[1]) {
            continue;
        }
        if (pos[0] - ax).hypot(pos[1] - ay) > r {
            draw::line(img, pos[0], pos[1], ax, ay, 3.0, WHITE);
            draw::line(img, pos[0], pos[1], ax, ay, 1.5, BLACK);
            draw::fill_disc(img, ax, ay, 3.0, BLACK);
        }
        draw::fill_disc(img, pos[0], pos[1], r + 1.0, WHITE);
        draw::fill_disc(img, pos[0], pos[1], r, BLACK);
        draw::fill_disc(img, pos[0], pos[1], r - 2.0, det.color);
        let (tc, oc) = if brightness(det.color) > 200.0 {
            (BLACK, WHITE)
        } else {
            (WHITE, BLACK)
        };
        draw::text(
            img,
            &fonts.bold,
            fs * 1.1,
            pos[0],
            pos[1],
            Anchor::Center,
            &label,
            tc,
            Some((oc, (fs / 8.0).ceil().max(1.0) as u32)),
        );
        taken.push(pos);
        view.labels[det.index] = Some(pos);
    }
    view
}

/// Small orientation triad (scene x, y, z projected) in the plot's lower-right corner.
fn draw_axes(img: &mut RgbImage, fonts: &Fonts, fs: f32, plot: &PixelRect, cam: &Camera) {
    let fs = fs.max(12.0);
    let len = f64::from(fs) * 1.8;
    let ox = f64::from(plot.x) + f64::from(plot.width) - len - f64::from(fs) * 1.5;
    let oy = f64::from(plot.y) + f64::from(plot.height) - len - f64::from(fs) * 0.8;
    if ox < f64::from(plot.x) + 6.0 * len || oy < f64::from(plot.y) + 4.0 * len {
        return; // no room: a small plot is better off without it
    }
    let grey = [50, 50, 50];
    for (i, name) in ["x", "y", "z"].iter().enumerate() {
        let mut e = Vector3::zeros();
        e[i] = 1.0;
        let (dx, dy) = (e.dot(&cam.right), -e.dot(&cam.up));
        let l = dx.hypot(dy);
        if l < 0.15 {
            // Pointing at or away from the viewer.
            let toward = e.dot(&cam.back) > 0.0;
            draw::fill_disc(img, ox, oy, 5.5, WHITE);
            draw::fill_disc(img, ox, oy, 4.0, grey);
            if !toward {
                draw::fill_disc(img, ox, oy, 2.0, WHITE);
            }
            draw::text(
                img,
                &fonts.bold,
                fs * 1.0,
                ox - f64::from(fs) * 0.6,
                oy + f64::from(fs) * 0.6,
                Anchor::Center,
                name,
                grey,
                Some((WHITE, 1)),
            );
            continue;
        }
        let (ex, ey) = (ox + dx * len, oy + dy * len);
        draw::line(img, ox, oy, ex, ey, 4.5, WHITE);
        draw::line(img, ox, oy, ex, ey, 2.0, grey);
        draw::text(
            img,
            &fonts.bold,
            fs * 1.0,
            ox + dx / l * (l * len + f64::from(fs) * 0.6),
            oy + dy / l * (l * len + f64::from(fs) * 0.6),
            Anchor::Center,
            name,
            grey,
            Some((WHITE, 1)),
        );
    }
}

#[allow(clippy::too_many_arguments)]
fn draw_legend(
    img: &mut RgbImage,
    fonts: &Fonts,
    lay: &Layout,
    placed: &[Placed],
    colors: &[Rgb],
    skipped: &[usize],
    opts: &RenderOptions,
    (score_lo, score_hi): (f64, f64),
    (h_lo, h_hi): (f64, f64),
) -> usize {
    let fs = lay.fs;
    let f = f64::from(fs);
    let r = lay.legend;
    let x0 = f64::from(r.x);
    let mut y = f64::from(r.y);
    let bottom = f64::from(r.y) + f64::from(r.height);
    let bold: &FontRef<'static> = &fonts.bold;
    let reg: &FontRef<'static> = &fonts.regular;
    let heading = match opts.color_by {
        ColorBy::Rank => "Detections (colour = rank)",
        ColorBy::FinalScore => "Detections (colour = score)",
    };
    let lw = f64::from(r.width);
    let fits =
        |font: &FontRef<'static>, px: f32, t: &str| f64::from(draw::text_width(font, px, t)) <= lw;
    let heading = if fits(bold, fs, heading) {
        heading
    } else {
        "Detections"
    };
    draw::text(img, bold, fs, x0, y, Anchor::TopLeft, heading, BLACK, None);
    y += f * 1.6;
    // Columns: swatch, rank, two figures (`Columns`; numbers right-aligned).
    let columns = Columns::of(placed, opts.color_by);
    let right = x0 + f64::from(r.width);
    let c_rank = x0 + f * 1.8;
    let c_init = right - f * 0.3;
    let c_final = c_init - f * 4.2;
    let grey = [90, 90, 90];
    draw::text(
        img,
        reg,
        fs * 0.85,
        c_rank,
        y,
        Anchor::TopLeft,
        "rank",
        grey,
        None,
    );
    draw::text(
        img,
        reg,
        fs * 0.85,
        c_final,
        y,
        Anchor::TopRight,
        columns.headers()[0],
        grey,
        None,
    );
    draw::text(
        img,
        reg,
        fs * 0.85,
        c_init,
        y,
        Anchor::TopRight,
        columns.headers()[1],
        grey,
        None,
    );
    y += f * 1.3;
    draw::fill_rect(img, x0 as i64, y as i64, r.width as i64, 1, [180, 180, 180]);
    y += f * 0.3;
    let row_h = f * 1.45;
    let footer_h = f * (columns.notes().len() as f64 * 1.1 + 5.5)
        + if opts.color_by == ColorBy::FinalScore {
            f * 3.0
        } else {
            0.0
        };
    let no_pick = placed
        .iter()
        .min_by_key(|p| p.rank)
        .is_some_and(|p| !p.free_to_pick);
    let room = (((bottom - footer_h - y) / row_h).floor() as usize)
        .saturating_sub(usize::from(no_pick))
        .max(1);
    let mut shown = 0;
    if !placed.is_empty() {
        let fits = placed.len() <= room;
        let n_rows = if fits {
            placed.len()
        } else {
            room.saturating_sub(1)
        };
        for (i, p) in placed.iter().enumerate().take(n_rows) {
            let invalid = skipped.contains(&i);
            let sw = f * 1.2;
            draw::fill_rect(
                img,
                x0 as i64,
                (y + f * 0.1) as i64,
                sw as i64,
                sw as i64,
                BLACK,
            );
            draw::fill_rect(
                img,
                x0 as i64 + 2,
                (y + f * 0.1) as i64 + 2,
                sw as i64 - 4,
                sw as i64 - 4,
                colors[i],
            );
            let tc = if invalid { [150, 150, 150] } else { BLACK };
            draw::text(
                img,
                bold,
                fs,
                c_rank,
                y,
                Anchor::TopLeft,
                &format!("#{}", p.rank),
                tc,
                None,
            );
            if invalid {
                draw::text(
                    img,
                    reg,
                    fs,
                    c_init,
                    y,
                    Anchor::TopRight,
                    "invalid pose",
                    tc,
                    None,
                );
            } else {
                let [a, b] = columns.values(p);
                draw::text(img, reg, fs, c_final, y, Anchor::TopRight, &a, tc, None);
                draw::text(img, reg, fs, c_init, y, Anchor::TopRight, &b, tc, None);
            }
            y += row_h;
            shown += 1;
        }
        if !fits {
            let more = placed.len() - n_rows;
            draw::text(
                img,
                reg,
                fs,
                c_rank,
                y,
                Anchor::TopLeft,
                &format!("\u{2026} and {more} more"),
                grey,
                None,
            );
            y += row_h;
        }
    }
    let notice = if placed.is_empty() {
        Some("no detections")
    } else {
        no_pick.then_some("no pick: none free")
    };
    if let Some(notice) = notice {
        draw::text(
            img,
            bold,
            fs,
            x0,
            y,
            Anchor::TopLeft,
            notice,
            NOTICE_RED,
            None,
        );
        y += row_h;
    }
    y += f * 0.5;
    for line in columns
        .notes()
        .into_iter()
        .filter(|l| fits(reg, fs * 0.85, l))
    {
        draw::text(
            img,
            reg,
            fs * 0.85,
            x0,
            y,
            Anchor::TopLeft,
            line,
            grey,
            None,
        );
        y += f * 1.1;
    }
    y += f * 0.6;
    let bar_w = (f64::from(r.width) - f * 0.5).max(4.0);
    let gradient = |img: &mut RgbImage, y: f64, c: &dyn Fn(f64) -> Rgb| {
        let n = bar_w.max(1.0) as i64;
        for i in 0..n {
            let col = c(i as f64 / (n - 1).max(1) as f64);
            draw::fill_rect(img, x0 as i64 + i, y as i64, 1, (f * 0.9) as i64, col);
        }
        draw::stroke_rect(
            img,
            x0 as i64,
            y as i64,
            n,
            (f * 0.9) as i64,
            1,
            [120, 120, 120],
        );
    };
    // A captioned colour bar with its two ends labelled; the y below its labels.
    let scale_bar = |img: &mut RgbImage,
                     mut y: f64,
                     caption: &str,
                     colour: &dyn Fn(f64) -> Rgb,
                     (lo, hi): (String, String)| {
        draw::text(
            img,
            reg,
            fs * 0.85,
            x0,
            y,
            Anchor::TopLeft,
            caption,
            grey,
            None,
        );
        y += f * 1.15;
        gradient(img, y, colour);
        y += f * 1.0;
        draw::text(img, reg, fs * 0.8, x0, y, Anchor::TopLeft, &lo, grey, None);
        let right = x0 + bar_w;
        draw::text(
            img,
            reg,
            fs * 0.8,
            right,
            y,
            Anchor::TopRight,
            &hi,
            grey,
            None,
        );
        y
    };
    if opts.color_by == ColorBy::FinalScore {
        y = scale_bar(
            img,
            y,
            "final score colour",
            &|t| score_color(score_lo + t * (score_hi - score_lo), score_lo, score_hi),
            (
                format!("{} %", fmt_num(score_lo)),
                format!("{} %", fmt_num(score_hi)),
            ),
        );
        y += f * 1.3;
    }
    scale_bar(
        img,
        y,
        "scene height along up",
        &height_color,
        (
            format!("{} mm", fmt_num(h_lo)),
            format!("{} mm", fmt_num(h_hi)),
        ),
    );
    shown
}

#[cfg(test)]
mod tests {
    use super::*;

    fn placed(rank: usize, seen: Option<crate::Seen>) -> Placed {
        Placed {
            rank,
            pose: nalgebra::Isometry3::identity(),
            final_score: 2.5,
            initial_score: 300.0,
            seen,
            free_to_pick: true,
        }
    }

    #[test]
    fn the_legend_shows_the_view_check_only_when_every_detection_has_one() {
        let seen = Some(crate::Seen {
            visibility: 0.955,
            fit: 0.876,
        });
        let all = [placed(1, seen), placed(2, seen)];
        let c = Columns::of(&all, ColorBy::Rank);
        assert_eq!(c.headers(), ["vis %", "fit"]);
        assert_eq!(c.notes(), SEEN_NOTES);
        assert_eq!(c.values(&all[0]), ["95.5".to_owned(), "0.88".to_owned()]);

        // One detection without it (a thesis engine's): the thesis's scores for all.
        let mixed = [placed(1, seen), placed(2, None)];
        let c = Columns::of(&mixed, ColorBy::Rank);
        assert_eq!(c.headers(), ["final %", "initial"]);
        assert_eq!(c.notes(), LEGEND_NOTES);
        assert_eq!(c.values(&mixed[0]), ["2.50".to_owned(), "300.0".to_owned()]);
        assert_eq!(
            Columns::of(&[], ColorBy::Rank).headers(),
            ["final %", "initial"]
        );
        // Coloured by final score: the legend shows the score the colours follow.
        assert_eq!(
            Columns::of(&all, ColorBy::FinalScore).headers(),
            ["final %", "initial"]
        );
    }
}
