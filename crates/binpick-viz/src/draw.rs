//! Raster primitives on an RGB image: filled shapes, lines and anti-aliased text from the
//! embedded DejaVu Sans font (no system fonts are ever looked up).

use ab_glyph::{Font, FontRef, PxScale, ScaleFont, point};
use image::RgbImage;

use crate::VizError;

/// The two embedded faces.
pub(crate) struct Fonts {
    pub regular: FontRef<'static>,
    pub bold: FontRef<'static>,
}

/// The embedded DejaVu Sans file. Every crate-internal use goes through here: `dejavu`'s
/// functions are small enough to be inlined, and each inlined call site would carry its own
/// 0.7 MB copy of the font.
#[inline(never)]
pub(crate) fn sans_regular() -> &'static [u8] {
    dejavu::sans::regular()
}

/// The embedded DejaVu Sans Bold file (see [`sans_regular`]).
#[inline(never)]
pub(crate) fn sans_bold() -> &'static [u8] {
    dejavu::sans::bold()
}

impl Fonts {
    pub fn load() -> Result<Self, VizError> {
        let regular = FontRef::try_from_slice(sans_regular())
            .map_err(|_| VizError::Font("embedded DejaVu Sans is not a valid font".into()))?;
        let bold = FontRef::try_from_slice(sans_bold())
            .map_err(|_| VizError::Font("embedded DejaVu Sans Bold is not a valid font".into()))?;
        Ok(Self { regular, bold })
    }
}

pub(crate) type Rgb = [u8; 3];

pub(crate) const BLACK: Rgb = [0, 0, 0];
pub(crate) const WHITE: Rgb = [255, 255, 255];

/// Blends `c` over the pixel at (x, y) with opacity `a` (0..=1); ignores pixels outside.
pub(crate) fn blend(img: &mut RgbImage, x: i64, y: i64, c: Rgb, a: f32) {
    if x < 0 || y < 0 || x >= i64::from(img.width()) || y >= i64::from(img.height()) {
        return;
    }
    let a = a.clamp(0.0, 1.0);
    if a <= 0.0 {
        return;
    }
    let p = img.get_pixel_mut(x as u32, y as u32);
    for (dst, &src) in p.0.iter_mut().zip(&c) {
        let v = f32::from(*dst) * (1.0 - a) + f32::from(src) * a;
        *dst = v.round().clamp(0.0, 255.0) as u8;
    }
}

pub(crate) fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb) {
    if x < 0 || y < 0 || x >= i64::from(img.width()) || y >= i64::from(img.height()) {
        return;
    }
    img.put_pixel(x as u32, y as u32, image::Rgb(c));
}

/// Filled axis-aligned rectangle `[x0, x0 + w) x [y0, y0 + h)`, clipped to the image.
pub(crate) fn fill_rect(img: &mut RgbImage, x0: i64, y0: i64, w: i64, h: i64, c: Rgb) {
    let x1 = (x0 + w).min(i64::from(img.width()));
    let y1 = (y0 + h).min(i64::from(img.height()));
    for y in y0.max(0)..y1 {
        for x in x0.max(0)..x1 {
            img.put_pixel(x as u32, y as u32, image::Rgb(c));
        }
    }
}

/// One-pixel rectangle outline of thickness `t`.
pub(crate) fn stroke_rect(img: &mut RgbImage, x0: i64, y0: i64, w: i64, h: i64, t: i64, c: Rgb) {
    fill_rect(img, x0, y0, w, t, c);
    fill_rect(img, x0, y0 + h - t, w, t, c);
    fill_rect(img, x0, y0, t, h, c);
    fill_rect(img, x0 + w - t, y0, t, h, c);
}

/// Anti-aliased filled disc of radius `r` centred at (cx, cy).
pub(crate) fn fill_disc(img: &mut RgbImage, cx: f64, cy: f64, r: f64, c: Rgb) {
    let x0 = (cx - r - 1.0).floor() as i64;
    let x1 = (cx + r + 1.0).ceil() as i64;
    let y0 = (cy - r - 1.0).floor() as i64;
    let y1 = (cy + r + 1.0).ceil() as i64;
    for y in y0..=y1 {
        for x in x0..=x1 {
            let d = ((x as f64 + 0.5 - cx).powi(2) + (y as f64 + 0.5 - cy).powi(2)).sqrt();
            let a = (r + 0.5 - d).clamp(0.0, 1.0);
            blend(img, x, y, c, a as f32);
        }
    }
}

/// Anti-aliased line of width `w` from (x0, y0) to (x1, y1).
pub(crate) fn line(img: &mut RgbImage, x0: f64, y0: f64, x1: f64, y1: f64, w: f64, c: Rgb) {
    let (dx, dy) = (x1 - x0, y1 - y0);
    let len2 = dx * dx + dy * dy;
    let half = w / 2.0;
    let minx = (x0.min(x1) - half - 1.0).floor() as i64;
    let maxx = (x0.max(x1) + half + 1.0).ceil() as i64;
    let miny = (y0.min(y1) - half - 1.0).floor() as i64;
    let maxy = (y0.max(y1) + half + 1.0).ceil() as i64;
    for y in miny..=maxy {
        for x in minx..=maxx {
            let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
            let t = if len2 > 0.0 {
                (((px - x0) * dx + (py - y0) * dy) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let (qx, qy) = (x0 + t * dx, y0 + t * dy);
            let d = ((px - qx).powi(2) + (py - qy).powi(2)).sqrt();
            let a = (half + 0.5 - d).clamp(0.0, 1.0);
            blend(img, x, y, c, a as f32);
        }
    }
}

/// Horizontal text metrics at `px` pixels per em-height.
pub(crate) fn text_width(font: &FontRef<'static>, px: f32, s: &str) -> f32 {
    let f = font.as_scaled(PxScale::from(px));
    let mut w = 0.0;
    let mut prev = None;
    for ch in s.chars() {
        let id = f.glyph_id(ch);
        if let Some(p) = prev {
            w += f.kern(p, id);
        }
        w += f.h_advance(id);
        prev = Some(id);
    }
    w
}

/// Height of one line of text (ascent - descent) at `px`.
pub(crate) fn line_height(font: &FontRef<'static>, px: f32) -> f32 {
    let f = font.as_scaled(PxScale::from(px));
    f.ascent() - f.descent()
}

/// How text is placed relative to the given point.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Anchor {
    /// (x, y) is the top-left corner of the line box.
    TopLeft,
    /// (x, y) is the centre of the line box.
    Center,
    /// (x, y) is the top-right corner.
    TopRight,
}

/// Coverage mask of one line of text: `w x h` values in 0..=1, row-major, with `pad` pixels
/// of empty border on every side; the line box (ascent to descent) starts at (pad, pad).
pub(crate) struct Mask {
    pub w: i64,
    pub h: i64,
    pub pad: i64,
    pub data: Vec<f32>,
    /// Advance width of the text, pixels.
    pub width: f32,
    /// Line height (ascent - descent), pixels.
    pub height: f32,
}

impl Mask {
    fn at(&self, x: i64, y: i64) -> f32 {
        if x < 0 || y < 0 || x >= self.w || y >= self.h {
            0.0
        } else {
            self.data[(y * self.w + x) as usize]
        }
    }

    /// The mask grown by a disc of radius `r` (max filter): the halo behind outlined text.
    fn dilated(&self, r: i64) -> Vec<f32> {
        let mut out = vec![0.0f32; self.data.len()];
        for y in 0..self.h {
            for x in 0..self.w {
                let mut m = 0.0f32;
                for dy in -r..=r {
                    for dx in -r..=r {
                        if dx * dx + dy * dy <= r * r + r {
                            m = m.max(self.at(x + dx, y + dy));
                        }
                    }
                }
                out[(y * self.w + x) as usize] = m;
            }
        }
        out
    }
}

/// Rasterises `s` at `px` pixels (line height about 1.16 `px` for DejaVu Sans), with room for
/// an outline of `pad_extra` pixels; `None` for empty text or absurd sizes.
pub(crate) fn text_mask(font: &FontRef<'static>, px: f32, s: &str, pad_extra: i64) -> Option<Mask> {
    if s.is_empty() || !px.is_finite() || !(1.0..=2000.0).contains(&px) {
        return None;
    }
    let f = font.as_scaled(PxScale::from(px));
    let width = text_width(font, px, s);
    let height = f.ascent() - f.descent();
    let pad = pad_extra.max(0) + 2;
    let w = width.ceil() as i64 + 2 * pad + 2;
    let h = height.ceil() as i64 + 2 * pad + 2;
    if w <= 0 || h <= 0 || w > 100_000 || h > 10_000 {
        return None;
    }
    let mut data = vec![0.0f32; (w * h) as usize];
    let mut caret = 0.0f32;
    let mut prev = None;
    for ch in s.chars() {
        let id = f.glyph_id(ch);
        if let Some(p) = prev {
            caret += f.kern(p, id);
        }
        let glyph = id.with_scale_and_position(
            PxScale::from(px),
            point(caret + pad as f32, f.ascent() + pad as f32),
        );
        if let Some(og) = font.outline_glyph(glyph) {
            let b = og.px_bounds();
            og.draw(|gx, gy, cov| {
                let mx = b.min.x as i64 + i64::from(gx);
                let my = b.min.y as i64 + i64::from(gy);
                if mx >= 0 && my >= 0 && mx < w && my < h {
                    let i = (my * w + mx) as usize;
                    data[i] = (data[i] + cov).min(1.0);
                }
            });
        }
        caret += f.h_advance(id);
        prev = Some(id);
    }
    Some(Mask {
        w,
        h,
        pad,
        data,
        width,
        height,
    })
}

/// Draws one line of text; with `outline`, a halo of that colour and width (pixels) is drawn
/// first so the text stays readable on any background. Returns the drawn width.
#[allow(clippy::too_many_arguments)]
pub(crate) fn text(
    img: &mut RgbImage,
    font: &FontRef<'static>,
    px: f32,
    x: f64,
    y: f64,
    anchor: Anchor,
    s: &str,
    color: Rgb,
    outline: Option<(Rgb, u32)>,
) -> f32 {
    let ow = outline.map_or(0, |(_, w)| i64::from(w));
    let Some(mask) = text_mask(font, px, s, ow) else {
        return 0.0;
    };
    if !x.is_finite() || !y.is_finite() {
        return 0.0;
    }
    let (width, height) = (f64::from(mask.width), f64::from(mask.height));
    let (left, top) = match anchor {
        Anchor::TopLeft => (x, y),
        Anchor::Center => (x - width / 2.0, y - height / 2.0),
        Anchor::TopRight => (x - width, y),
    };
    let ox = left.round() as i64 - mask.pad;
    let oy = top.round() as i64 - mask.pad;
    let halo = outline.map(|(c, w)| (c, mask.dilated(i64::from(w))));
    for (layer, col) in halo
        .iter()
        .map(|(c, d)| (d.as_slice(), *c))
        .chain(std::iter::once((mask.data.as_slice(), color)))
    {
        for my in 0..mask.h {
            for mx in 0..mask.w {
                let a = layer[(my * mask.w + mx) as usize];
                if a > 0.0 {
                    blend(img, ox + mx, oy + my, col, a);
                }
            }
        }
    }
    mask.width
}

/// Saves `img` as PNG, creating nothing but the file itself.
pub(crate) fn save_png(img: &RgbImage, out: &std::path::Path) -> Result<(), VizError> {
    let file = std::fs::File::create(out).map_err(|source| VizError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let mut w = std::io::BufWriter::new(file);
    let encoder = image::codecs::png::PngEncoder::new_with_quality(
        &mut w,
        image::codecs::png::CompressionType::Best,
        image::codecs::png::FilterType::Adaptive,
    );
    img.write_with_encoder(encoder)
        .map_err(|e| VizError::Image {
            path: out.to_path_buf(),
            message: e.to_string(),
        })?;
    use std::io::Write;
    w.flush().map_err(|source| VizError::Io {
        path: out.to_path_buf(),
        source,
    })
}
