//! Everything that depends only on the model, computed once per `Recognizer` (the thesis
//! recomputed it per cluster; 5.7 notes it "can be precomputed offline").

use binpick_cloud::{Point, PointCloud, to_point3};
use binpick_pcl::{IcpParams, IndexedCloud};
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use rayon::prelude::*;

use crate::error::{InputKind, Result, input_as, pcl};
use crate::params::Params;
use crate::stages::features::{RadiusFeatures, feature_surface, fpfh_for_radius, keypoints};
use crate::stages::final_alignment::icp_settings;

/// A model ready for matching. All coordinates in the model frame, mm.
#[derive(Clone, Debug)]
pub struct PreparedModel {
    /// The model after the resolution voxel grid (what cluster sizes are relative to).
    pub cloud: Vec<Point>,
    /// Uniform keypoints at the initial leaf (thesis Alg. 1 step 1a).
    pub initial_keypoints: Vec<Point>,
    /// FPFH of the initial keypoints, one entry per radius in `Params::fpfh_radii_mm`.
    pub features: Vec<RadiusFeatures>,
    /// Uniform keypoints at the final leaf, used by ICP and the final score (step 3a).
    pub final_keypoints: Vec<Point>,
    /// Largest distance between two model points, mm.
    pub diameter_mm: f64,
    /// Largest distance from the model's centroid to its points, mm (thesis 3.4.1.2).
    pub radius_mm: f64,
    /// Near-symmetries of the model (model frame -> model frame): half-turns about its
    /// principal axes, each refined by ICP of the model onto itself. Empty when the
    /// near-symmetry candidates extension is off.
    pub near_symmetries: Vec<Isometry3<f64>>,
}

/// Model points sampled to tell a near-symmetry from the identity.
const SYMMETRY_SAMPLE_POINTS: usize = 500;
/// A refined half-turn is a near-symmetry when it moves the sample by more than this, in
/// model diameters, from the identity and from the ones already found.
const SYMMETRY_MIN_MOVE_DIAMETERS: f64 = 0.1;

impl PreparedModel {
    /// Voxelises the model, extracts keypoints and computes FPFH for every radius (radii in
    /// parallel, each with `threads` OpenMP threads). `stages` are the resolved stage configs
    /// ([`Params::stages`]).
    pub(crate) fn new(model: &PointCloud, stages: &Params, threads: u32) -> Result<Self> {
        let resolution_mm = stages.preprocess.resolution();
        let cfg = &stages.features;
        let cloud = binpick_pcl::voxel_grid(&model.points, resolution_mm as f32)
            .map_err(pcl("model voxel grid"))?;
        if cloud.len() < cfg.min_model_points {
            return Err(input_as(
                "model",
                InputKind::Degenerate,
                format!(
                    "only {} points remain after the {} mm voxel grid (need {}); \
                     is the resolution too coarse or the cloud in the wrong units?",
                    cloud.len(),
                    resolution_mm,
                    cfg.min_model_points
                ),
            ));
        }
        let kp_idx = keypoints(&cloud, cfg.initial_leaf_mm)?;
        let initial_keypoints: Vec<Point> = kp_idx.iter().map(|&i| cloud[i as usize]).collect();
        if initial_keypoints.len() < 3 {
            return Err(input_as(
                "model",
                InputKind::Degenerate,
                format!(
                    "{} keypoints at the {} mm initial leaf; at least 3 are needed",
                    initial_keypoints.len(),
                    cfg.initial_leaf_mm
                ),
            ));
        }
        let (surface, surface_kp) = feature_surface(&cloud, &kp_idx, &initial_keypoints, cfg)?;
        let features = cfg
            .fpfh_radii_mm
            .par_iter()
            .map(|&r| {
                fpfh_for_radius(
                    &surface,
                    &surface_kp,
                    r,
                    cfg,
                    cfg.model_viewpoint_mm,
                    threads,
                )
            })
            .collect::<Result<Vec<_>>>()?;
        if let Some(f) = features.iter().find(|f| f.descriptors.len() < 3) {
            return Err(input_as(
                "model",
                InputKind::Degenerate,
                format!(
                    "only {} keypoints have an FPFH descriptor at radius {} mm",
                    f.descriptors.len(),
                    f.radius_mm
                ),
            ));
        }
        let final_idx = keypoints(&cloud, stages.icp.final_leaf_mm)?;
        let final_keypoints: Vec<Point> = final_idx.iter().map(|&i| cloud[i as usize]).collect();
        let diameter_mm = diameter(&initial_keypoints);
        let radius_mm = radius(&cloud);
        let near_symmetries = if stages.consensus.symmetry_candidates {
            near_symmetries(&cloud, &initial_keypoints, diameter_mm, &|turn| {
                icp_settings(&stages.icp, turn)
            })?
        } else {
            Vec::new()
        };
        Ok(Self {
            cloud,
            initial_keypoints,
            features,
            final_keypoints,
            diameter_mm,
            radius_mm,
            near_symmetries,
        })
    }
}

/// Surface points a self-match's gaps are measured on.
const GAP_SAMPLES: usize = 4000;
/// A symmetry's 99th-percentile gap is at most this many surface spacings ...
const SYMMETRY_GAP_SPACINGS: f64 = 2.0;
/// ... plus this share of the diameter (sampling of curved surfaces).
const SYMMETRY_GAP_DIAMETERS: f64 = 0.005;
/// A near-symmetry's median gap is within the symmetry tolerance (most of the surface maps
/// onto itself) and its 99th-percentile gap is at most this share of the diameter.
const NEAR_GAP_DIAMETERS: f64 = 0.15;

/// Whether a rotation maps the part onto itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SelfMatchKind {
    /// Everywhere, within the sampling: declare it.
    Symmetry,
    /// Most of the surface, not all: a pose turned by it is wrong.
    NearSymmetry,
}

/// Measures how closely a rotation maps a surface onto itself: the gaps between the turned
/// surface and the surface (a kd-tree in Rust), and what they make it.
pub(crate) struct SelfMatchGauge {
    index: binpick_match::PointIndex,
    /// The points the gaps are measured on (evenly strided).
    pub sample: Vec<Point3<f64>>,
    /// The surface's point spacing, mm.
    pub spacing_mm: f64,
    /// A symmetry's largest 99th-percentile gap (and a near-symmetry's largest median), mm.
    pub tolerance_mm: f64,
    diameter_mm: f64,
}

impl SelfMatchGauge {
    pub(crate) fn new(surface: &[Point], diameter_mm: f64) -> Result<Self> {
        let spacing_mm = crate::stages::scale::measure_spacing(surface)?
            .map(|s| s.spacing_mm)
            .ok_or_else(|| crate::error::input("model", "fewer than 9 distinct points"))?;
        let index = binpick_match::PointIndex::new("model", surface)
            .map_err(|e| crate::error::input("model", e.to_string()))?;
        Ok(Self {
            index,
            sample: binpick_cloud::strided_points(surface, GAP_SAMPLES),
            spacing_mm,
            tolerance_mm: SYMMETRY_GAP_SPACINGS * spacing_mm + SYMMETRY_GAP_DIAMETERS * diameter_mm,
            diameter_mm,
        })
    }

    /// Median and 99th-percentile distance from a sample point turned by `t` to the
    /// surface, mm.
    pub(crate) fn gaps(&self, t: &Isometry3<f64>) -> (f64, f64) {
        let mut d: Vec<f64> = self
            .sample
            .iter()
            .map(|p| {
                let q = t * p;
                let q: Point = [q.x as f32, q.y as f32, q.z as f32];
                f64::from(self.index.nearest(&q).1).sqrt()
            })
            .collect();
        d.sort_by(f64::total_cmp);
        let at = |f: f64| d[((d.len() - 1) as f64 * f).round() as usize];
        (at(0.5), at(0.99))
    }

    /// What gaps `(median, p99)` make a rotation: a symmetry, a near-symmetry or neither.
    pub(crate) fn classify(&self, (median, p99): (f64, f64)) -> Option<SelfMatchKind> {
        if p99 <= self.tolerance_mm {
            Some(SelfMatchKind::Symmetry)
        } else if median <= self.tolerance_mm && p99 <= NEAR_GAP_DIAMETERS * self.diameter_mm {
            Some(SelfMatchKind::NearSymmetry)
        } else {
            None
        }
    }
}

/// The turns of `turns` that map the part's surface onto itself, everywhere or nearly (as
/// `model inspect` classes them): only those can be mistaken for the part, so only those
/// are worth trying on a hypothesis. The half-turns about the principal axes that map a
/// bracket onto nothing like itself were refined on every acceptable hypothesis and never
/// taken.
pub(crate) fn self_matching_turns(
    part: &crate::stages::part::Part,
    turns: Vec<Isometry3<f64>>,
) -> Result<Vec<Isometry3<f64>>> {
    if turns.is_empty() {
        return Ok(turns);
    }
    let gauge = SelfMatchGauge::new(&part.surface.points, part.size.diameter_mm)?;
    Ok(turns
        .into_iter()
        .filter(|t| gauge.classify(gauge.gaps(t)).is_some())
        .collect())
}

/// Whether a scanned part cannot be told from its turn by one of `turns`: a turn that maps
/// the scan (nearly) onto itself, as `model inspect` classes it, and shows the side the scan
/// never saw ([`Part::turn_hides_scanned_side`](crate::Part::turn_hides_scanned_side)). A
/// part lying the other way up then fits the scan as that turn. Always false for a mesh.
pub(crate) fn scan_cannot_tell_turns(
    part: &crate::stages::part::Part,
    turns: &[Isometry3<f64>],
) -> Result<bool> {
    let hiding: Vec<&Isometry3<f64>> = turns
        .iter()
        .filter(|t| part.turn_hides_scanned_side(t))
        .collect();
    if hiding.is_empty() {
        return Ok(false);
    }
    let gauge = SelfMatchGauge::new(&part.surface.points, part.size.diameter_mm)?;
    Ok(hiding
        .iter()
        .any(|t| gauge.classify(gauge.gaps(t)).is_some()))
}

/// The half-turns about the model's principal axes (through its centroid), each refined by
/// ICP of the model's final keypoints onto the model, keeping those that do not collapse to
/// the identity. Bent sheets and pipes are often nearly symmetric under one of them, and the
/// RANSAC consensus then lands on the flipped pose.
pub(crate) fn near_symmetries(
    cloud: &[Point],
    keypoints: &[Point],
    diameter_mm: f64,
    icp: &(dyn Fn(&Isometry3<f64>) -> IcpParams + Sync),
) -> Result<Vec<Isometry3<f64>>> {
    let pts: Vec<Vector3<f64>> = cloud.iter().map(|p| to_point3(p).coords).collect();
    let n = pts.len() as f64;
    let c = pts.iter().sum::<Vector3<f64>>() / n;
    let cov = pts.iter().fold(Matrix3::zeros(), |acc, p| {
        acc + (p - c) * (p - c).transpose()
    }) / n;
    let axes = cov.symmetric_eigen().eigenvectors;
    let target = IndexedCloud::new(cloud).map_err(pcl("model self-registration"))?;
    let sample = binpick_cloud::strided_points(keypoints, SYMMETRY_SAMPLE_POINTS);
    // The three half-turns refined in parallel (self-registration starts far from the
    // surface, so its nearest-neighbour searches are the slow kind); kept in axis order.
    let refined: Vec<Isometry3<f64>> = (0..3)
        .into_par_iter()
        .map(|k| {
            let axis = Unit::new_normalize(axes.column(k).into_owned());
            let turn = Translation3::from(c)
                * UnitQuaternion::from_axis_angle(&axis, std::f64::consts::PI)
                * Translation3::from(-c);
            target
                .icp(keypoints, &icp(&turn))
                .ok()
                .and_then(|o| o.pose())
                .unwrap_or(turn)
        })
        .collect();
    let mut found: Vec<Isometry3<f64>> = Vec::new();
    for r in refined {
        // Keep it unless ICP slid back to the identity or to one already found.
        let distinct = |a: &Isometry3<f64>| {
            let d = sample
                .iter()
                .map(|p: &Point3<f64>| (a * p - r * p).norm())
                .sum::<f64>()
                / sample.len().max(1) as f64;
            d > SYMMETRY_MIN_MOVE_DIAMETERS * diameter_mm
        };
        if distinct(&Isometry3::identity()) && found.iter().all(distinct) {
            found.push(r);
        }
    }
    Ok(found)
}

/// Largest distance from the centroid to a point.
pub(crate) fn radius(points: &[Point]) -> f64 {
    let n = points.len().max(1) as f64;
    let mut c = [0.0f64; 3];
    for p in points {
        for k in 0..3 {
            c[k] += f64::from(p[k]) / n;
        }
    }
    points
        .iter()
        .map(|p| {
            (0..3)
                .map(|k| (f64::from(p[k]) - c[k]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
}

/// Largest pairwise distance (exact, O(n^2) over the keypoints; a few thousand at most).
pub(crate) fn diameter(points: &[Point]) -> f64 {
    let mut best = 0.0f64;
    for (i, a) in points.iter().enumerate() {
        for b in &points[i + 1..] {
            let d: f64 = (0..3).map(|k| f64::from(a[k] - b[k]).powi(2)).sum();
            best = best.max(d);
        }
    }
    best.sqrt()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::stages::part::Part;

    /// A flat 60 x 20 mm sheet scanned from above (0.5 mm grid), centred on the origin.
    fn scanned_sheet() -> Part {
        let points: Vec<Point> = (0..120)
            .flat_map(|i| {
                (0..40).map(move |j| [i as f32 * 0.5 - 29.75, j as f32 * 0.5 - 9.75, 0.0])
            })
            .collect();
        Part::from_scan(&PointCloud::new(points), [0.0, 0.0, 300.0], 1).unwrap()
    }

    /// The half turn about `axis` through `through`.
    fn half(axis: Vector3<f64>, through: Vector3<f64>) -> Isometry3<f64> {
        Translation3::from(through)
            * UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis), std::f64::consts::PI)
            * Translation3::from(-through)
    }

    #[test]
    fn only_turns_that_map_the_part_onto_itself_are_tried() {
        let sheet = scanned_sheet();
        let flip = half(Vector3::x(), Vector3::zeros());
        let about_view = half(Vector3::z(), Vector3::zeros());
        // About the long axis, through a line 20 mm off it: the turned sheet lies beside
        // itself, a pose nobody would mistake for the part.
        let beside = half(Vector3::x(), Vector3::new(0.0, 20.0, 0.0));
        let kept = self_matching_turns(&sheet, vec![flip, beside, about_view]).unwrap();
        assert_eq!(kept, vec![flip, about_view]);
        assert!(self_matching_turns(&sheet, Vec::new()).unwrap().is_empty());
    }

    #[test]
    fn a_scan_cannot_tell_a_turn_that_fits_it_upside_down() {
        let sheet = scanned_sheet();
        // Upside down onto itself: the scan shows nothing that tells the two apart.
        let flip = half(Vector3::x(), Vector3::zeros());
        assert!(sheet.turn_hides_scanned_side(&flip));
        assert!(scan_cannot_tell_turns(&sheet, &[flip]).unwrap());
        // About the scanner's axis the scanned side stays up: the view judges the turn.
        let about_view = half(Vector3::z(), Vector3::zeros());
        assert!(!sheet.turn_hides_scanned_side(&about_view));
        assert!(!scan_cannot_tell_turns(&sheet, &[about_view]).unwrap());
        // Upside down but 40 mm away from itself: not a self-match, nothing to confuse.
        let far = half(Vector3::x(), Vector3::new(0.0, 20.0, 0.0));
        assert!(sheet.turn_hides_scanned_side(&far));
        assert!(!scan_cannot_tell_turns(&sheet, &[far]).unwrap());
        assert!(scan_cannot_tell_turns(&sheet, &[about_view, far, flip]).unwrap());
    }
}
