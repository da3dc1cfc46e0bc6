//! Scale-free parameters: what binpick measures on the model and on every scan, and the
//! lengths it derives from them when a parameter is left on auto. The thesis notes (4.3) that
//! its parameters must grow with the object; here they grow on their own.
//!
//! Measured:
//! - the **model's diameter** `d` (largest distance between two of its points), the area of
//!   the surface one view of it shows and its typical **radius of curvature** `R` (None when
//!   it is mostly flat);
//! - the **scan's point spacing** `s` (the side of the square each point covers, from the
//!   distance to its 8th-nearest neighbour, median over a sample) and its **gap** `g` (that
//!   distance itself: what must be bridged to connect a line scanner's lines).
//!
//! Derived (every length scales exactly with a uniformly scaled input):
//!
//! | value                 | rule                                                        |
//! |-----------------------|-------------------------------------------------------------|
//! | working resolution w  | `resolution_mm`, or max(s, d / 100), on a 2^(1/16) ladder    |
//! | support distance      | `support.distance_mm`, or 1.5 w; under a curved part, once the |
//! |                       | noise is measured, `SupportRemoval::band` (3 noise, >= w)   |
//! | connectivity          | 1.5 max(w, g) (support patches, clusters)                   |
//! | sampling step         | max(`sampling_step_diameters` d, `min_sampling_step_resolutions` w) |
//! | normal radius         | max(`normal_radius_steps` step, `min_normal_radius_resolutions` w), |
//! |                       | for a curved part at most `normal_radius_curvatures` R but at least |
//! |                       | `min_curved_normal_radius_resolutions` w                    |
//! | view cell             | `cell_resolutions` w                                        |
//! | view tolerance        | max(`tolerance_cells` cell, `tolerance_sigmas` noise)       |
//! | part points           | visible area of one part / w^2 (cluster and support bounds) |

use serde::{Deserialize, Serialize};

use binpick_cloud::Point;
use binpick_match::index::kth_nearest_distinct_on_grid;
use binpick_match::{OrientedPoints, PointIndex};

use crate::error::{InputKind, Result, input_as};
use crate::params::Params;
pub use crate::result::DerivedScale;

/// Points sampled to measure a cloud's spacing.
const SPACING_SAMPLES: usize = 2000;
/// The spacing is measured at this neighbour (the 8 around a point of a grid).
const SPACING_NEIGHBOUR: usize = 8;
/// Working resolution never finer than this fraction of the model's diameter.
const MIN_RESOLUTION_DIAMETERS: f64 = 0.01;
/// Steps of the resolution ladder per octave: scans whose spacings differ by less than a
/// step share one prepared model.
const LADDER_STEPS_PER_OCTAVE: f64 = 16.0;

/// A cloud's point spacing.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Spacing {
    /// Side of the square one point covers, mm.
    pub spacing_mm: f64,
    /// Median distance to the 8th-nearest neighbour, mm.
    pub gap_mm: f64,
}

/// Measures `points`' spacing on a strided sample; None for fewer than 9 distinct points.
pub fn measure_spacing(points: &[Point]) -> Result<Option<Spacing>> {
    if points.len() <= SPACING_NEIGHBOUR {
        return Ok(None);
    }
    let step = (points.len() / SPACING_SAMPLES).max(1);
    let sample: Vec<Point> = points.iter().step_by(step).copied().collect();
    let mut gaps: Vec<f64> = kth_nearest_distinct_on_grid(points, &sample, SPACING_NEIGHBOUR)
        .map_err(|e| input_as("cloud", InputKind::Degenerate, e.to_string()))?
        .into_iter()
        .flatten()
        .map(f64::from)
        .collect();
    if gaps.is_empty() {
        return Ok(None);
    }
    gaps.sort_by(f64::total_cmp);
    let gap_mm = gaps[gaps.len() / 2];
    if !(gap_mm > 0.0 && gap_mm.is_finite()) {
        return Ok(None);
    }
    // k neighbours within r on a surface sampled at density 1/s^2: k = pi r^2 / s^2.
    let spacing_mm = gap_mm * (std::f64::consts::PI / SPACING_NEIGHBOUR as f64).sqrt();
    Ok(Some(Spacing { spacing_mm, gap_mm }))
}

/// Surface samples the curvature is measured on.
const CURVATURE_SAMPLES: usize = 2000;
/// The curvature is read between neighbours this far apart, in model diameters (the finest
/// scale a normal is ever fitted at: `min_normal_radius_resolutions` x d / 100) ...
const CURVATURE_REACH_DIAMETERS: f64 = 0.02;
/// ... and at least this share of that apart (a mesh's facets turn in steps).
const CURVATURE_MIN_REACH: f64 = 0.5;
/// A point's curvature is this quantile of what its neighbours show: the most curved
/// direction (a cylinder's neighbours along its axis show none).
const CURVATURE_QUANTILE: f64 = 0.9;

/// The part's typical radius of curvature, mm: the median over its surface of the smallest
/// radius of curvature at each point, measured between neighbours 0.01-0.02 diameters apart
/// facing the same side (`|n_p - n_q| / |p - q|` is exactly 1 / R on a circle of radius R).
/// None when most of the surface is flat. A thin rod gives its radius; sheet metal, whose
/// faces are flat, gives None.
pub fn measure_curvature_radius(surface: &OrientedPoints, diameter_mm: f64) -> Result<Option<f64>> {
    if surface.points.len() < 2 || diameter_mm.is_nan() || diameter_mm <= 0.0 {
        return Ok(None);
    }
    let index = PointIndex::new("model surface", &surface.points)
        .map_err(|e| input_as("model", InputKind::Degenerate, e.to_string()))?;
    let reach = (CURVATURE_REACH_DIAMETERS * diameter_mm) as f32;
    let near = CURVATURE_MIN_REACH as f32 * reach;
    let step = (surface.points.len() / CURVATURE_SAMPLES).max(1);
    let mut found = Vec::new();
    let mut ratios: Vec<f32> = Vec::new();
    let mut curvatures: Vec<f32> = Vec::with_capacity(CURVATURE_SAMPLES + 1);
    for i in (0..surface.points.len()).step_by(step) {
        let (p, n) = (surface.points[i], surface.normals[i]);
        index.within_into(&p, reach, &mut found);
        ratios.clear();
        for &j in &found {
            let (q, m) = (surface.points[j as usize], surface.normals[j as usize]);
            let d = dist(&p, &q);
            if d < near || dot(&n, &m) <= 0.0 {
                continue;
            }
            let dn = [n[0] - m[0], n[1] - m[1], n[2] - m[2]];
            ratios.push(norm(&dn) / d);
        }
        if ratios.len() < 4 {
            continue;
        }
        ratios.sort_by(f32::total_cmp);
        let k = ((ratios.len() - 1) as f64 * CURVATURE_QUANTILE).round() as usize;
        curvatures.push(ratios[k]);
    }
    if curvatures.is_empty() {
        return Ok(None);
    }
    curvatures.sort_by(f32::total_cmp);
    let typical = f64::from(curvatures[curvatures.len() / 2]);
    // Flatter than a radius of the part's diameter: as good as flat.
    Ok((typical * diameter_mm > 1.0).then(|| 1.0 / typical))
}

fn dot(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn norm(a: &[f32; 3]) -> f32 {
    dot(a, a).sqrt()
}
fn dist(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    norm(&[a[0] - b[0], a[1] - b[1], a[2] - b[2]])
}

/// `v` rounded onto the 2^(1/16) ladder (exact under scaling by powers of two).
fn on_ladder(v: f64) -> f64 {
    (2f64).powf((v.log2() * LADDER_STEPS_PER_OCTAVE).round() / LADDER_STEPS_PER_OCTAVE)
}

/// What the part looks like to the scale rules.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PartSize {
    /// Largest distance between two model points, mm.
    pub diameter_mm: f64,
    /// Area of the surface one view of the part shows, mm^2 (a scan model: all of it; a
    /// mesh: half its surface).
    pub view_area_mm2: f64,
    /// The part's typical radius of curvature, mm ([`measure_curvature_radius`]); None for a
    /// part that is mostly flat.
    pub curvature_radius_mm: Option<f64>,
}

impl DerivedScale {
    /// Derives every value from the part, the scan's spacing (None: the resolution is given
    /// or nothing could be measured) and `params`.
    pub fn derive(part: &PartSize, scan: Option<Spacing>, params: &Params) -> Result<Self> {
        let d = part.diameter_mm;
        let resolution_mm = match (params.preprocess.resolution_mm, scan) {
            (Some(r), _) => r,
            (None, Some(s)) => on_ladder(s.spacing_mm.max(MIN_RESOLUTION_DIAMETERS * d)),
            (None, None) => on_ladder(MIN_RESOLUTION_DIAMETERS * d),
        };
        if !(resolution_mm.is_finite() && resolution_mm > 0.0) {
            return Err(input_as(
                "scene",
                InputKind::Degenerate,
                format!("cannot derive a resolution (got {resolution_mm} mm)"),
            ));
        }
        let gap = scan.map_or(resolution_mm, |s| on_ladder(s.gap_mm));
        let wide = resolution_mm.max(gap);
        let v = &params.voting;
        let sampling_step_mm =
            (v.sampling_step_diameters * d).max(v.min_sampling_step_resolutions * resolution_mm);
        let normal_radius_mm = (v.normal_radius_steps * sampling_step_mm)
            .max(v.min_normal_radius_resolutions * resolution_mm);
        // A plane fitted over more than the part's curvature blurs a rod into a ridge.
        let normal_radius_mm = part.curvature_radius_mm.map_or(normal_radius_mm, |r| {
            normal_radius_mm
                .min(v.normal_radius_curvatures * r)
                .max(v.min_curved_normal_radius_resolutions * resolution_mm)
        });
        let cell_mm = params.verify.cell_resolutions * resolution_mm;
        Ok(Self {
            model_diameter_mm: d,
            part_view_area_mm2: part.view_area_mm2,
            part_curvature_radius_mm: part.curvature_radius_mm,
            scan_spacing_mm: scan.map(|s| s.spacing_mm),
            scan_gap_mm: scan.map(|s| s.gap_mm),
            resolution_mm,
            connect_mm: 1.5 * wide,
            support_distance_mm: params.preprocess.support.distance(resolution_mm),
            sampling_step_mm,
            normal_radius_mm,
            cell_mm,
            scan_noise_mm: None,
            tolerance_mm: params.verify.tolerance_cells * cell_mm,
            part_points: part.view_area_mm2 / (resolution_mm * resolution_mm),
        })
    }

    /// One line for logs.
    pub fn summary(&self) -> String {
        let measured = match (self.scan_spacing_mm, self.scan_gap_mm) {
            (Some(s), Some(g)) => format!("scan spacing {s:.3} mm (gap {g:.3} mm), "),
            _ => String::new(),
        };
        let noise = self
            .scan_noise_mm
            .map_or(String::new(), |n| format!(" (noise {n:.2} mm)"));
        let curvature = self
            .part_curvature_radius_mm
            .map_or(String::new(), |r| format!(", curvature radius {r:.1} mm"));
        format!(
            "{measured}model diameter {:.1} mm{curvature} -> resolution {:.3} mm, sampling step {:.2} mm, \
             normal radius {:.2} mm, view cell {:.2} mm, tolerance {:.2} mm{noise}, support distance {:.2} mm",
            self.model_diameter_mm,
            self.resolution_mm,
            self.sampling_step_mm,
            self.normal_radius_mm,
            self.cell_mm,
            self.tolerance_mm,
            self.support_distance_mm
        )
    }

    /// Takes the scan's noise into account: the view tolerance grows to
    /// `tolerance_sigmas` x the noise when that is wider, and the support distance becomes
    /// the band preprocessing labelled support with, when it narrowed one
    /// (`PreprocessReport::support_band_mm`: under a curved part).
    pub fn with_noise(
        mut self,
        noise_mm: Option<f64>,
        support_band_mm: Option<f64>,
        params: &Params,
    ) -> Self {
        self.scan_noise_mm = noise_mm;
        if let Some(sigma) = noise_mm {
            self.tolerance_mm = self
                .tolerance_mm
                .max(params.verify.tolerance_sigmas * sigma);
        }
        if let Some(band) = support_band_mm {
            self.support_distance_mm = band;
        }
        self
    }

    /// The key of the model preparation these values need.
    pub(crate) fn model_key(&self) -> (u64, u64) {
        (
            self.resolution_mm.to_bits(),
            self.sampling_step_mm.to_bits(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_spacing_is_measured() {
        // A 1 x 1 mm grid: 8th neighbour at sqrt(2), spacing ~ 0.89 (pi/8 correction).
        let pts: Vec<Point> = (0..100)
            .flat_map(|i| (0..100).map(move |j| [i as f32, j as f32, 0.0]))
            .collect();
        let s = measure_spacing(&pts).unwrap().unwrap();
        assert!((s.gap_mm - 2f64.sqrt()).abs() < 1e-5, "{s:?}");
        // Scaling the cloud by 2 scales both exactly.
        let big: Vec<Point> = pts.iter().map(|p| [2.0 * p[0], 2.0 * p[1], 0.0]).collect();
        let b = measure_spacing(&big).unwrap().unwrap();
        assert_eq!(b.gap_mm, 2.0 * s.gap_mm);
        assert_eq!(b.spacing_mm, 2.0 * s.spacing_mm);
        assert!(measure_spacing(&pts[..5]).unwrap().is_none());
    }

    #[test]
    fn derived_values_scale_exactly() {
        let params = Params::default();
        let part = PartSize {
            diameter_mm: 71.3,
            view_area_mm2: 2500.0,
            curvature_radius_mm: None,
        };
        let scan = Spacing {
            spacing_mm: 0.61,
            gap_mm: 0.97,
        };
        let a = DerivedScale::derive(&part, Some(scan), &params).unwrap();
        for k in [2.0, 0.5] {
            let p2 = PartSize {
                diameter_mm: part.diameter_mm * k,
                view_area_mm2: part.view_area_mm2 * k * k,
                curvature_radius_mm: None,
            };
            let s2 = Spacing {
                spacing_mm: scan.spacing_mm * k,
                gap_mm: scan.gap_mm * k,
            };
            let b = DerivedScale::derive(&p2, Some(s2), &params).unwrap();
            assert_eq!(b.resolution_mm, k * a.resolution_mm);
            assert_eq!(b.sampling_step_mm, k * a.sampling_step_mm);
            assert_eq!(b.normal_radius_mm, k * a.normal_radius_mm);
            assert_eq!(b.cell_mm, k * a.cell_mm);
            assert_eq!(b.tolerance_mm, k * a.tolerance_mm);
            assert_eq!(b.connect_mm, k * a.connect_mm);
            assert_eq!(b.part_points, a.part_points);
        }
        // A given resolution wins over the measured one.
        let mut fixed = Params::default();
        fixed.preprocess.resolution_mm = Some(3.0);
        let f = DerivedScale::derive(&part, Some(scan), &fixed).unwrap();
        assert_eq!(f.resolution_mm, 3.0);
        // Small parts are not processed finer than 1/100 of their diameter.
        let coarse = DerivedScale::derive(
            &part,
            Some(Spacing {
                spacing_mm: 0.05,
                gap_mm: 0.08,
            }),
            &params,
        )
        .unwrap();
        assert!(coarse.resolution_mm >= 0.7 * 0.713 && coarse.resolution_mm <= 0.75);
    }

    /// A cylinder of `radius` and `length` along x, sampled about every `step` mm around and
    /// along, with outward normals.
    fn cylinder(radius: f32, length: f32, step: f32) -> OrientedPoints {
        let around = (std::f32::consts::TAU * radius / step).ceil() as usize;
        let along = (length / step).ceil() as usize;
        let mut c = OrientedPoints::default();
        for i in 0..along {
            for j in 0..around {
                let a = j as f32 * std::f32::consts::TAU / around as f32;
                let (sin, cos) = a.sin_cos();
                c.points.push([i as f32 * step, radius * cos, radius * sin]);
                c.normals.push([0.0, cos, sin]);
            }
        }
        c
    }

    #[test]
    fn a_rod_measures_its_radius_and_a_plate_is_flat() {
        for radius in [3.5f32, 10.0] {
            let rod = cylinder(radius, 100.0, 0.25);
            let r = measure_curvature_radius(&rod, 100.0).unwrap().unwrap();
            assert!((r / f64::from(radius) - 1.0).abs() < 0.05, "{radius}: {r}");
            // Exactly proportional under scaling.
            let big = OrientedPoints {
                points: rod.points.iter().map(|p| p.map(|c| 2.0 * c)).collect(),
                normals: rod.normals.clone(),
            };
            let rb = measure_curvature_radius(&big, 200.0).unwrap().unwrap();
            assert!((rb / (2.0 * r) - 1.0).abs() < 1e-5, "{rb} vs 2 x {r}");
        }
        // A plate 2 mm thick: both faces flat, each seen from its own side.
        let mut plate = OrientedPoints::default();
        for i in 0..200 {
            for j in 0..100 {
                for (z, n) in [(0.0, -1.0), (2.0, 1.0)] {
                    plate.points.push([i as f32 * 0.5, j as f32 * 0.5, z]);
                    plate.normals.push([0.0, 0.0, n]);
                }
            }
        }
        assert_eq!(measure_curvature_radius(&plate, 112.0).unwrap(), None);
        assert_eq!(
            measure_curvature_radius(&OrientedPoints::default(), 1.0).unwrap(),
            None
        );
    }

    #[test]
    fn a_curved_part_caps_the_normal_radius_at_its_curvature_but_not_below_two_resolutions() {
        let params = Params::default();
        let scan = Some(Spacing {
            spacing_mm: 1.9,
            gap_mm: 3.0,
        });
        let part = |curvature_radius_mm| PartSize {
            diameter_mm: 94.0,
            view_area_mm2: 1600.0,
            curvature_radius_mm,
        };
        let flat = DerivedScale::derive(&part(None), scan, &params).unwrap();
        let w = flat.resolution_mm;
        assert_eq!(flat.normal_radius_mm, 3.0 * w);
        // Curved more gently than the radius: unchanged.
        let gentle = DerivedScale::derive(&part(Some(8.0)), scan, &params).unwrap();
        assert_eq!(gentle.normal_radius_mm, flat.normal_radius_mm);
        assert_eq!(gentle.part_curvature_radius_mm, Some(8.0));
        // A rod of 5 mm radius: 5 mm.
        let rod = DerivedScale::derive(&part(Some(5.0)), scan, &params).unwrap();
        assert_eq!(rod.normal_radius_mm, 5.0);
        // A thinner one: two resolutions (noise).
        let thin = DerivedScale::derive(&part(Some(1.0)), scan, &params).unwrap();
        assert_eq!(thin.normal_radius_mm, 2.0 * w);
        // Nothing else moves.
        for d in [&gentle, &rod, &thin] {
            assert_eq!(d.sampling_step_mm, flat.sampling_step_mm);
            assert_eq!(d.tolerance_mm, flat.tolerance_mm);
            assert_eq!(d.support_distance_mm, flat.support_distance_mm);
        }
        // Once the floor's noise (0.6 mm) is known, the support distance becomes the band
        // preprocessing narrowed to under a curved part (3 x 0.6 mm, at least one resolution)
        // and stays the whole 1.5 w where it labelled the whole distance (a flat part).
        assert_eq!(flat.support_distance_mm, 1.5 * w);
        assert_eq!(
            flat.with_noise(Some(0.6), None, &params)
                .support_distance_mm,
            1.5 * w
        );
        let band = params.preprocess.support.band(w, 0.6);
        assert_eq!(band, (3.0 * 0.6f64).max(w));
        let banded = rod.with_noise(Some(0.6), Some(band), &params);
        assert_eq!(banded.support_distance_mm, band);
        assert_eq!(
            banded.tolerance_mm,
            flat.with_noise(Some(0.6), None, &params).tolerance_mm
        );
    }
}
