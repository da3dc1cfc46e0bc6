//! What a part model is, for the person declaring it: its size and sampling, and the
//! rotations that map it (almost) onto itself. A **symmetry** maps the surface onto itself
//! everywhere: declare it in the sidecar (`<model>.json`, see [`crate::load_part`]) so poses
//! are reported once per equivalence class. A **near-symmetry** maps most of the surface onto
//! itself but not all of it (a Z bracket's half turn swaps flanges of 30 and 35 mm): it is a
//! trap, not a symmetry, and the verifier must tell the two poses apart.
//!
//! Candidates are the rotations by 360/n degrees (n = 2, 3, 4, 5, 6, 8) about the surface's
//! three principal axes through its centroid, plus each half turn refined by PCL's ICP
//! (a near-symmetry's best axis is rarely exactly principal). Each is measured by the gaps
//! between the turned surface and the surface (a kd-tree in Rust).

use nalgebra::{Isometry3, Matrix3, Translation3, Unit, UnitQuaternion, Vector3};
use serde::Serialize;

use binpick_cloud::{Point, RowMajor4x4, pose_to_row_major};
use binpick_pcl::IcpParams;

use crate::error::Result;
pub use crate::stages::model::SelfMatchKind;
use crate::stages::model::{SelfMatchGauge, near_symmetries};
use crate::stages::part::{Part, PartSource};

/// Orders tried about each principal axis (rotation by 360/n degrees).
const ORDERS: [u32; 6] = [2, 3, 4, 5, 6, 8];
/// Two rotations are the same when they move every sample point less than this share of the
/// diameter apart.
const SAME_DIAMETERS: f64 = 0.05;

/// Two turns differ by a rotation about the revolution axis when the axis moves less than
/// this (unit vector) between them.
const REVOLUTION_SAME: f64 = 0.02;

/// A rotation found: the turn, its kind, its (median, p99) gaps in mm, whether about a
/// revolution axis.
type Found = (Isometry3<f64>, SelfMatchKind, (f64, f64), bool);

/// One rotation that maps the part (almost) onto itself.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SelfMatch {
    /// Symmetry or near-symmetry.
    pub kind: SelfMatchKind,
    /// The rotation, model frame, row-major 4x4 (mm): a sidecar `symmetries` entry.
    pub transform: RowMajor4x4,
    /// Its axis (unit vector), model frame.
    pub axis: [f64; 3],
    /// A point on the axis (the one nearest the surface's centroid), model frame, mm.
    pub point_mm: [f64; 3],
    /// Rotation angle, degrees (0-180).
    pub angle_deg: f64,
    /// Median distance from a turned surface point to the surface, mm.
    pub median_gap_mm: f64,
    /// 99th-percentile distance from a turned surface point to the surface, mm.
    pub p99_gap_mm: f64,
    /// Whether every order tried about this axis maps it onto itself (a body of
    /// revolution): declare `revolution_axis` instead of single turns.
    pub revolution: bool,
    /// A scanned model only: the turn shows the side the scanner never saw
    /// ([`Part::turn_hides_scanned_side`]). For a near-symmetry this means the scan cannot
    /// tell a part lying the other way up from the turn.
    pub hides_scanned_side: bool,
}

/// What `binpick model inspect` prints.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PartInspection {
    /// Scanned view or CAD mesh.
    pub source: PartSource,
    /// Surface points the part was given as (a mesh: after sampling).
    pub points: usize,
    /// Largest distance between two surface points, mm.
    pub diameter_mm: f64,
    /// Side of the square one surface point covers, mm (the model's resolution).
    pub spacing_mm: f64,
    /// Area of the surface one view shows, mm^2.
    pub view_area_mm2: f64,
    /// Typical radius of curvature, mm (None: mostly flat); caps the scene's normal radius.
    pub curvature_radius_mm: Option<f64>,
    /// Symmetries already declared in the sidecar (identity included).
    pub declared_symmetries: usize,
    /// Tolerance a symmetry's 99th-percentile gap met, mm.
    pub symmetry_tolerance_mm: f64,
    /// Symmetries first, then near-symmetries; each rotation once.
    pub self_matches: Vec<SelfMatch>,
}

/// Measures `part` and finds the rotations that map it (almost) onto itself. `threads` for
/// the ICP refinements (0 = all).
pub fn inspect_part(part: &Part) -> Result<PartInspection> {
    let surface = &part.surface.points;
    let diameter_mm = part.size.diameter_mm;
    let gauge = SelfMatchGauge::new(surface, diameter_mm)?;
    let (sample, spacing_mm, tolerance) = (&gauge.sample, gauge.spacing_mm, gauge.tolerance_mm);
    let centroid = sample.iter().map(|p| p.coords).sum::<Vector3<f64>>() / sample.len() as f64;
    let cov = sample.iter().fold(Matrix3::zeros(), |acc, p| {
        acc + (p.coords - centroid) * (p.coords - centroid).transpose()
    }) / sample.len() as f64;
    let axes = cov.symmetric_eigen().eigenvectors;

    let gaps = |t: &Isometry3<f64>| gauge.gaps(t);
    let classify = |g: (f64, f64)| gauge.classify(g);

    let mut found: Vec<Found> = Vec::new();
    for k in 0..3 {
        let axis = Unit::new_normalize(axes.column(k).into_owned());
        let turn = |n: u32| {
            Translation3::from(centroid)
                * UnitQuaternion::from_axis_angle(&axis, std::f64::consts::TAU / f64::from(n))
                * Translation3::from(-centroid)
        };
        let measured: Vec<(Isometry3<f64>, (f64, f64))> = ORDERS
            .iter()
            .map(|&n| {
                let t = turn(n);
                (t, gaps(&t))
            })
            .collect();
        let revolution = measured
            .iter()
            .all(|(_, g)| classify(*g) == Some(SelfMatchKind::Symmetry));
        for (t, g) in measured {
            if let Some(kind) = classify(g) {
                found.push((t, kind, g, revolution));
            }
        }
    }
    // Half turns refined by ICP (PCL), for near-symmetries off the principal axes.
    let keypoints: Vec<Point> = sample
        .iter()
        .step_by(4)
        .map(|p| [p.x as f32, p.y as f32, p.z as f32])
        .collect();
    let refined = near_symmetries(surface, &keypoints, diameter_mm, &|turn| IcpParams {
        initial: binpick_pcl::row_major(turn),
        max_correspondence_distance: 0.1 * diameter_mm,
        max_iterations: 30,
        transformation_epsilon: 1e-6 * spacing_mm * spacing_mm,
        batch_correspondences: true,
        relative_mse: 1e-4,
        reciprocal: false,
    })?;
    for t in refined {
        let g = gaps(&t);
        if let Some(kind) = classify(g) {
            found.push((t, kind, g, false));
        }
    }

    // Each rotation once (the better measured copy): revolutions first, then symmetries,
    // then by gap.
    found.sort_by(|a, b| {
        (a.1 != SelfMatchKind::Symmetry, !a.3)
            .cmp(&(b.1 != SelfMatchKind::Symmetry, !b.3))
            .then(a.2.1.total_cmp(&b.2.1))
    });
    // About a revolution axis every turn is one rotation class: keep its first (smallest
    // order) entry, and of the other turns one per class modulo the revolution.
    let revolution_axis = found.iter().find(|f| f.3).and_then(|f| f.0.rotation.axis());
    let mut kept: Vec<Found> = Vec::new();
    for f in found {
        if let Some(a) = revolution_axis {
            let modulo = |k: &(Isometry3<f64>, _, _, bool)| {
                ((k.0.rotation.inverse() * f.0.rotation) * a.into_inner() - a.into_inner()).norm()
                    < REVOLUTION_SAME
            };
            let about_axis =
                (f.0.rotation * a.into_inner() - a.into_inner()).norm() < REVOLUTION_SAME;
            if (about_axis && kept.iter().any(|k| k.3)) || (!about_axis && kept.iter().any(modulo))
            {
                continue;
            }
        }
        let same = |k: &(Isometry3<f64>, _, _, _)| {
            sample
                .iter()
                .map(|p| (k.0 * p - f.0 * p).norm())
                .fold(0.0, f64::max)
                < SAME_DIAMETERS * diameter_mm
        };
        if !kept.iter().any(same) {
            kept.push(f);
        }
    }
    let self_matches = kept
        .into_iter()
        .map(|(t, kind, (median, p99), revolution)| {
            let (axis, angle) = t
                .rotation
                .axis_angle()
                .map_or(([0.0, 0.0, 1.0], 0.0), |(a, ang)| {
                    ([a.x, a.y, a.z], ang.to_degrees())
                });
            // The point of the axis nearest the centroid: fixed by the rotation, so solve
            // (I - R) x = t in the plane normal to the axis (least squares).
            let a = Vector3::from(axis);
            let m = Matrix3::identity() - t.rotation.to_rotation_matrix().into_inner()
                + a * a.transpose();
            let rhs = t.translation.vector + a * a.dot(&centroid);
            let point = m.try_inverse().map_or(centroid, |inv| inv * rhs);
            SelfMatch {
                kind,
                transform: pose_to_row_major(&t),
                axis,
                point_mm: [point.x, point.y, point.z],
                angle_deg: angle,
                median_gap_mm: median,
                p99_gap_mm: p99,
                revolution,
                hides_scanned_side: part.turn_hides_scanned_side(&t),
            }
        })
        .collect();
    Ok(PartInspection {
        source: part.source,
        points: surface.len(),
        diameter_mm,
        spacing_mm,
        view_area_mm2: part.size.view_area_mm2,
        curvature_radius_mm: part.size.curvature_radius_mm,
        declared_symmetries: part.symmetries.transforms().len(),
        symmetry_tolerance_mm: tolerance,
        self_matches,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use binpick_match::OrientedPoints;

    /// The surface of the box `min`..`max` sampled every `step` mm, outward normals.
    fn box_surface(min: [f32; 3], max: [f32; 3], step: f32, out: &mut OrientedPoints) {
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for (side, sign) in [(min[axis], -1.0f32), (max[axis], 1.0)] {
                let n_u = ((max[u] - min[u]) / step).round() as usize;
                let n_v = ((max[v] - min[v]) / step).round() as usize;
                for i in 0..=n_u {
                    for j in 0..=n_v {
                        let mut p = [0.0f32; 3];
                        p[axis] = side;
                        p[u] = min[u] + (max[u] - min[u]) * i as f32 / n_u as f32;
                        p[v] = min[v] + (max[v] - min[v]) * j as f32 / n_v as f32;
                        let mut n = [0.0f32; 3];
                        n[axis] = sign;
                        out.points.push(p);
                        out.normals.push(n);
                    }
                }
            }
        }
    }

    fn part(boxes: &[([f32; 3], [f32; 3])]) -> Part {
        let mut s = OrientedPoints::default();
        let mut area = 0.0;
        for (min, max) in boxes {
            box_surface(*min, *max, 1.0, &mut s);
            let d: Vec<f64> = (0..3).map(|k| f64::from(max[k] - min[k])).collect();
            area += 2.0 * (d[0] * d[1] + d[1] * d[2] + d[0] * d[2]);
        }
        Part::from_surface(s, area).unwrap()
    }

    fn kinds(p: &Part) -> Vec<SelfMatchKind> {
        inspect_part(p)
            .unwrap()
            .self_matches
            .iter()
            .map(|m| m.kind)
            .collect()
    }

    #[test]
    fn a_box_has_three_half_turn_symmetries() {
        let r = inspect_part(&part(&[([-30.0, -15.0, -5.0], [30.0, 15.0, 5.0])])).unwrap();
        let sym: Vec<&SelfMatch> = r
            .self_matches
            .iter()
            .filter(|m| m.kind == SelfMatchKind::Symmetry)
            .collect();
        assert_eq!(sym.len(), 3, "{:#?}", r.self_matches);
        for m in &sym {
            assert!((m.angle_deg - 180.0).abs() < 1.0, "{m:#?}");
            assert!(!m.revolution);
            // About the box's axes, through its centre.
            assert!(m.axis.iter().any(|a| a.abs() > 0.999), "{m:#?}");
            assert!(m.point_mm.iter().all(|c| c.abs() < 0.5), "{m:#?}");
        }
    }

    #[test]
    fn a_square_bar_has_a_four_fold_axis_not_a_revolution() {
        let r = inspect_part(&part(&[([-10.0, -10.0, -40.0], [10.0, 10.0, 40.0])])).unwrap();
        let about_z: Vec<&SelfMatch> = r
            .self_matches
            .iter()
            .filter(|m| m.kind == SelfMatchKind::Symmetry && m.axis[2].abs() > 0.999)
            .collect();
        assert!(
            about_z.iter().any(|m| (m.angle_deg - 90.0).abs() < 1.0),
            "{:#?}",
            r.self_matches
        );
        assert!(r.self_matches.iter().all(|m| !m.revolution));
    }

    #[test]
    fn a_z_shape_with_unequal_flanges_is_only_nearly_symmetric() {
        // A web and two flanges bent opposite ways, 30 and 35 mm long (a Z bracket).
        let z = part(&[
            ([-13.0, -20.0, -1.0], [13.0, 20.0, 1.0]),
            ([-15.0, -20.0, 1.0], [-13.0, 20.0, 31.0]),
            ([13.0, -20.0, -36.0], [15.0, 20.0, -1.0]),
        ]);
        assert_eq!(kinds(&z), vec![SelfMatchKind::NearSymmetry]);
        // With equal flanges the same turn is a symmetry.
        let even = part(&[
            ([-13.0, -20.0, -1.0], [13.0, 20.0, 1.0]),
            ([-15.0, -20.0, 1.0], [-13.0, 20.0, 31.0]),
            ([13.0, -20.0, -31.0], [15.0, 20.0, -1.0]),
        ]);
        assert!(kinds(&even).contains(&SelfMatchKind::Symmetry));
    }

    #[test]
    fn an_irregular_part_has_no_symmetry() {
        let p = part(&[
            ([0.0, 0.0, 0.0], [50.0, 10.0, 4.0]),
            ([0.0, 10.0, 0.0], [8.0, 35.0, 4.0]),
            ([30.0, 0.0, 4.0], [38.0, 6.0, 20.0]),
        ]);
        assert!(
            !kinds(&p).contains(&SelfMatchKind::Symmetry),
            "{:#?}",
            inspect_part(&p).unwrap().self_matches
        );
    }

    #[test]
    fn a_cylinder_has_a_revolution_axis_and_a_flip() {
        let mut s = OrientedPoints::default();
        let (r, h) = (12.0f32, 50.0f32);
        for i in 0..240 {
            let a = i as f32 * std::f32::consts::TAU / 240.0;
            for j in 0..=50 {
                let z = -h / 2.0 + h * j as f32 / 50.0;
                s.points.push([r * a.cos(), r * a.sin(), z]);
                s.normals.push([a.cos(), a.sin(), 0.0]);
            }
            for k in 1..=12 {
                let rr = r * k as f32 / 12.0;
                for (z, n) in [(-h / 2.0, -1.0), (h / 2.0, 1.0)] {
                    s.points.push([rr * a.cos(), rr * a.sin(), z]);
                    s.normals.push([0.0, 0.0, n]);
                }
            }
        }
        let area = f64::from(std::f32::consts::TAU * r * h + std::f32::consts::TAU * r * r);
        let r = inspect_part(&Part::from_surface(s, area).unwrap()).unwrap();
        let revolution: Vec<&SelfMatch> = r.self_matches.iter().filter(|m| m.revolution).collect();
        assert_eq!(revolution.len(), 1, "{:#?}", r.self_matches);
        assert!(revolution[0].axis[2].abs() > 0.999);
        // Upside down: a half turn about an axis across it, one per class.
        let flips: Vec<&SelfMatch> = r.self_matches.iter().filter(|m| !m.revolution).collect();
        assert_eq!(flips.len(), 1, "{:#?}", r.self_matches);
        assert_eq!(flips[0].kind, SelfMatchKind::Symmetry);
        assert!(flips[0].axis[2].abs() < 0.01);
    }
}
