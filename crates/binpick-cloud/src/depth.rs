//! Depth images: a 16-bit depth image plus pinhole intrinsics becomes an organised point
//! cloud in the camera's frame, in millimetres (and back), as BOP datasets and depth cameras
//! store them.
//!
//! Conventions (BOP's and OpenCV's): the camera looks along its +z, image columns `u` run
//! along +x and rows `v` along +y, pixel centres are at integer coordinates, and
//! `cam_K = [fx, 0, cx, 0, fy, cy, 0, 0, 1]`. A pixel value `d` is a depth (the point's z,
//! not its distance along the ray) of `d * depth_scale_mm` millimetres; 0 means no reading.
//! The point of pixel `(u, v)` is `z * ((u - cx) / fx, (v - cy) / fy, 1)`.

use std::path::Path;

use crate::{Point, PointCloud};

/// Pinhole intrinsics, pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    /// From a row-major 3x3 `K` (BOP's `cam_K`): `[fx, 0, cx, 0, fy, cy, 0, 0, 1]`. Skew must be
    /// 0 and the focal lengths positive and finite.
    pub fn from_k(k: &[f64; 9]) -> Result<Self, DepthError> {
        let ok = k.iter().all(|v| v.is_finite())
            && k[0] > 0.0
            && k[4] > 0.0
            && k[1] == 0.0
            && k[3] == 0.0
            && k[6] == 0.0
            && k[7] == 0.0
            && k[8] == 1.0;
        if !ok {
            return Err(DepthError::Intrinsics(format!(
                "cam_K {k:?} is not [fx, 0, cx, 0, fy, cy, 0, 0, 1] with fx, fy > 0"
            )));
        }
        Ok(Self {
            fx: k[0],
            fy: k[4],
            cx: k[2],
            cy: k[5],
        })
    }

    /// The row-major 3x3 `K`.
    pub fn to_k(&self) -> [f64; 9] {
        [self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0]
    }

    /// The pixel (continuous coordinates) a camera-frame point projects to, if in front.
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        (p[2] > 0.0).then(|| {
            [
                self.fx * p[0] / p[2] + self.cx,
                self.fy * p[1] / p[2] + self.cy,
            ]
        })
    }
}

/// A 16-bit depth image, row-major (`data[v * width + u]`), 0 = no reading.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DepthImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u16>,
}

/// Error reading, writing or converting a depth image.
#[derive(Debug, thiserror::Error)]
pub enum DepthError {
    #[error("{path}: {message}")]
    Png { path: String, message: String },
    #[error("camera intrinsics: {0}")]
    Intrinsics(String),
    #[error("depth_scale: {0}")]
    Scale(String),
}

fn png_err(path: &Path, message: impl std::fmt::Display) -> DepthError {
    DepthError::Png {
        path: path.display().to_string(),
        message: message.to_string(),
    }
}

/// An organised cloud from a depth image: the valid pixels' points in row-major order.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthCloud {
    /// Camera frame, mm; one point per pixel with a reading, row by row.
    pub cloud: PointCloud,
    pub width: usize,
    pub height: usize,
    /// Pixel index (`v * width + u`) of each point of `cloud`.
    pub pixels: Vec<u32>,
}

impl DepthImage {
    /// Reads a 16-bit grayscale PNG (BOP's `depth/*.png`). Any other PNG is refused with a
    /// message saying what it is.
    pub fn read_png(path: &Path) -> Result<Self, DepthError> {
        let file = std::fs::File::open(path).map_err(|e| png_err(path, e))?;
        let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
        // Keep 16-bit samples as they are (no stripping, no expansion).
        decoder.set_transformations(png::Transformations::IDENTITY);
        let mut reader = decoder.read_info().map_err(|e| png_err(path, e))?;
        let info = reader.info();
        let (width, height) = (info.width as usize, info.height as usize);
        if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen
        {
            return Err(png_err(
                path,
                format!(
                    "a depth image must be 16-bit grayscale, this one is {:?} {:?}-bit",
                    info.color_type, info.bit_depth as u8
                ),
            ));
        }
        let size = reader
            .output_buffer_size()
            .ok_or_else(|| png_err(path, "image too large"))?;
        let mut buf = vec![0u8; size];
        let frame = reader.next_frame(&mut buf).map_err(|e| png_err(path, e))?;
        let bytes = &buf[..frame.buffer_size()];
        if bytes.len() != width * height * 2 {
            return Err(png_err(
                path,
                format!(
                    "decoded {} bytes for {width} x {height} 16-bit pixels",
                    bytes.len()
                ),
            ));
        }
        // PNG stores 16-bit samples big-endian.
        let data = bytes
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect();
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Writes a 16-bit grayscale PNG.
    pub fn write_png(&self, path: &Path) -> Result<(), DepthError> {
        if self.data.len() != self.width * self.height {
            return Err(png_err(
                path,
                format!(
                    "{} values for a {} x {} image",
                    self.data.len(),
                    self.width,
                    self.height
                ),
            ));
        }
        let file = std::fs::File::create(path).map_err(|e| png_err(path, e))?;
        let mut enc = png::Encoder::new(
            std::io::BufWriter::new(file),
            self.width as u32,
            self.height as u32,
        );
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let mut w = enc.write_header().map_err(|e| png_err(path, e))?;
        let bytes: Vec<u8> = self.data.iter().flat_map(|d| d.to_be_bytes()).collect();
        w.write_image_data(&bytes).map_err(|e| png_err(path, e))?;
        w.finish().map_err(|e| png_err(path, e))
    }

    /// The points of the pixels with a reading, camera frame, mm (see the module docs).
    pub fn to_cloud(&self, k: &Intrinsics, depth_scale_mm: f64) -> Result<DepthCloud, DepthError> {
        check_scale(depth_scale_mm)?;
        let mut points: Vec<Point> = Vec::new();
        let mut pixels = Vec::new();
        for v in 0..self.height {
            for u in 0..self.width {
                let i = v * self.width + u;
                let d = self.data[i];
                if d == 0 {
                    continue;
                }
                let z = f64::from(d) * depth_scale_mm;
                let x = (u as f64 - k.cx) / k.fx * z;
                let y = (v as f64 - k.cy) / k.fy * z;
                points.push([x as f32, y as f32, z as f32]);
                pixels.push(i as u32);
            }
        }
        Ok(DepthCloud {
            cloud: PointCloud::new(points),
            width: self.width,
            height: self.height,
            pixels,
        })
    }

    /// The depth image a camera with intrinsics `k` and `width` x `height` pixels records of
    /// camera-frame points (mm): each point lands on its nearest pixel, the nearest point per
    /// pixel wins, depths are rounded to `depth_scale_mm`. Points behind the camera, off the
    /// image or too deep for 16 bits are counted in the second value and left out.
    pub fn from_points(
        points: &[Point],
        k: &Intrinsics,
        width: usize,
        height: usize,
        depth_scale_mm: f64,
    ) -> Result<(Self, usize), DepthError> {
        check_scale(depth_scale_mm)?;
        let mut data = vec![0u16; width * height];
        let mut dropped = 0;
        for p in points {
            let p = [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])];
            let Some([pu, pv]) = k.project(p) else {
                dropped += 1;
                continue;
            };
            let (u, v) = (pu.round(), pv.round());
            let value = (p[2] / depth_scale_mm).round();
            if u < 0.0
                || v < 0.0
                || u >= width as f64
                || v >= height as f64
                || !(1.0..=f64::from(u16::MAX)).contains(&value)
            {
                dropped += 1;
                continue;
            }
            let i = v as usize * width + u as usize;
            let d = value as u16;
            if data[i] == 0 || d < data[i] {
                data[i] = d;
            }
        }
        Ok((
            Self {
                width,
                height,
                data,
            },
            dropped,
        ))
    }
}

fn check_scale(depth_scale_mm: f64) -> Result<(), DepthError> {
    if depth_scale_mm.is_finite() && depth_scale_mm > 0.0 {
        Ok(())
    } else {
        Err(DepthError::Scale(format!(
            "{depth_scale_mm} is not a positive number of mm per unit"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn k() -> Intrinsics {
        Intrinsics::from_k(&[500.0, 0.0, 31.5, 0.0, 520.0, 23.5, 0.0, 0.0, 1.0]).unwrap()
    }

    #[test]
    fn pixels_become_points_on_their_rays() {
        let mut img = DepthImage {
            width: 64,
            height: 48,
            data: vec![0; 64 * 48],
        };
        img.data[10 * 64 + 40] = 8000; // 800 mm at 0.1 mm per unit
        img.data[47 * 64] = 5000;
        let c = img.to_cloud(&k(), 0.1).unwrap();
        assert_eq!(c.cloud.len(), 2);
        assert_eq!(c.pixels, vec![10 * 64 + 40, 47 * 64]);
        let p = c.cloud.points[0];
        assert!((p[2] - 800.0).abs() < 1e-4);
        assert!((f64::from(p[0]) - (40.0 - 31.5) / 500.0 * 800.0).abs() < 1e-3);
        assert!((f64::from(p[1]) - (10.0 - 23.5) / 520.0 * 800.0).abs() < 1e-3);
        // Projecting the point gives its pixel back.
        let [u, v] = k()
            .project([f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
            .unwrap();
        assert!((u - 40.0).abs() < 1e-6 && (v - 10.0).abs() < 1e-6);
    }

    #[test]
    fn png_round_trip_and_points_back_to_the_same_image() {
        let dir = tempfile::tempdir().unwrap();
        let data: Vec<u16> = (0..64 * 48)
            .map(|i| {
                if i % 7 == 0 {
                    0
                } else {
                    6000 + (i % 500) as u16
                }
            })
            .collect();
        let img = DepthImage {
            width: 64,
            height: 48,
            data,
        };
        let path = dir.path().join("d.png");
        img.write_png(&path).unwrap();
        let back = DepthImage::read_png(&path).unwrap();
        assert_eq!(back, img);
        let cloud = back.to_cloud(&k(), 0.1).unwrap();
        let (again, dropped) =
            DepthImage::from_points(&cloud.cloud.points, &k(), 64, 48, 0.1).unwrap();
        assert_eq!(dropped, 0);
        assert_eq!(again, img);
    }

    #[test]
    fn bad_inputs_are_errors_that_say_what_is_wrong() {
        let dir = tempfile::tempdir().unwrap();
        // An 8-bit PNG is not a depth image.
        let path = dir.path().join("gray8.png");
        let file = std::fs::File::create(&path).unwrap();
        let mut enc = png::Encoder::new(file, 2, 2);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().unwrap();
        w.write_image_data(&[1, 2, 3, 4]).unwrap();
        w.finish().unwrap();
        let err = DepthImage::read_png(&path).unwrap_err().to_string();
        assert!(err.contains("gray8.png") && err.contains("16-bit"), "{err}");
        let err = DepthImage::read_png(&dir.path().join("none.png"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("none.png"), "{err}");
        assert!(Intrinsics::from_k(&[0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0]).is_err());
        let img = DepthImage {
            width: 1,
            height: 1,
            data: vec![1],
        };
        assert!(img.to_cloud(&k(), 0.0).is_err());
        assert!(img.to_cloud(&k(), f64::NAN).is_err());
    }
}
