//! Pose hypotheses from flat faces: a flat patch of the scene laid on a flat face of the
//! model of about its size.
//!
//! Point-pair voting is weakest where it sees a flat face: every pair on a plane has the
//! same angles, so the pairs of a scene patch vote for every flat face of the model that it
//! fits in, and for every turn about the normal. A Z bracket standing on a flange's end shows
//! the sensor little but its web, a 28 x 40 mm rectangle that its 35 x 40 mm flanges outvote.
//! A patch's extent fixes what voting cannot: the turn (its principal axes) and the place
//! (its ends). Both patch and face are found the same way, by growing flat regions over
//! sampled points with normals.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::{MatchError, OrientedPoints, P3, PointIndex};

/// A flat region of sampled points: centre, unit normal, two in-plane axes (`axes[1]` =
/// normal x `axes[0]`, `axes[0]` the longer extent) and the points' extent along each axis
/// from the centre, mm.
#[derive(Clone, Debug, PartialEq)]
pub struct FlatPatch {
    /// Centroid of the points, mm.
    pub centre: Vector3<f64>,
    /// Unit normal, as the points' normals face.
    pub normal: Vector3<f64>,
    /// In-plane unit axes: the longer extent first; `axes[1]` = `normal` x `axes[0]`.
    pub axes: [Vector3<f64>; 2],
    /// Lowest and highest coordinate of the points along each axis, from `centre`, mm.
    pub extent: [[f64; 2]; 2],
    /// Points in the patch.
    pub points: usize,
}

impl FlatPatch {
    /// Length along axis `k`, mm.
    pub fn length(&self, k: usize) -> f64 {
        self.extent[k][1] - self.extent[k][0]
    }
}

/// How flat regions are grown.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlatRegions {
    /// Neighbours within this distance join a region, mm (about 1.5 sample spacings).
    pub connect_mm: f64,
    /// A point joins when its normal is within this angle of the region's seed's, degrees.
    pub max_angle_deg: f64,
    /// ... and it lies within this distance of the seed's plane, mm.
    pub max_offset_mm: f64,
    /// Regions with fewer points are dropped.
    pub min_points: usize,
}

/// The flat regions of `points` (normals needed), largest first (ties in seed order):
/// regions grow from each point not yet taken, in index order, over neighbours within
/// `connect_mm` whose normal and offset agree with the seed's plane.
pub fn flat_patches(
    points: &OrientedPoints,
    regions: &FlatRegions,
) -> Result<Vec<FlatPatch>, MatchError> {
    if points.len() < regions.min_points.max(3) {
        return Ok(Vec::new());
    }
    let index = PointIndex::new("flat regions", &points.points)?;
    let cos_max = regions.max_angle_deg.to_radians().cos();
    let vec = |p: &P3| Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
    let mut taken = vec![false; points.len()];
    let mut patches = Vec::new();
    let mut near = Vec::new();
    for seed in 0..points.len() {
        if taken[seed] {
            continue;
        }
        let n0 = vec(&points.normals[seed]);
        if n0.norm().is_nan() || n0.norm() <= 0.5 {
            continue;
        }
        let n0 = n0.normalize();
        let p0 = vec(&points.points[seed]);
        taken[seed] = true;
        let mut region = vec![seed];
        let mut next = 0;
        while next < region.len() {
            let q = region[next];
            next += 1;
            index.within_into(&points.points[q], regions.connect_mm as f32, &mut near);
            near.sort_unstable();
            for &k in &near {
                let k = k as usize;
                if taken[k] {
                    continue;
                }
                let n = vec(&points.normals[k]);
                if n.dot(&n0) < cos_max * n.norm()
                    || (vec(&points.points[k]) - p0).dot(&n0).abs() > regions.max_offset_mm
                {
                    continue;
                }
                taken[k] = true;
                region.push(k);
            }
        }
        if region.len() >= regions.min_points {
            let pts: Vec<Vector3<f64>> = region.iter().map(|&k| vec(&points.points[k])).collect();
            if let Some(p) = patch_of(&pts, &n0) {
                patches.push(p);
            }
        }
    }
    // Stable: equal sizes keep seed order.
    patches.sort_by_key(|p| std::cmp::Reverse(p.points));
    Ok(patches)
}

/// The patch of the points `pts` whose normals face `facing`.
fn patch_of(pts: &[Vector3<f64>], facing: &Vector3<f64>) -> Option<FlatPatch> {
    let n = pts.len() as f64;
    let centre = pts.iter().sum::<Vector3<f64>>() / n;
    let mut cov = Matrix3::zeros();
    for p in pts {
        let d = p - centre;
        cov += d * d.transpose();
    }
    let eig = nalgebra::SymmetricEigen::new(cov / n);
    // Eigenvalues ascending by index order is not promised: sort them.
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let mut normal: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
    if normal.dot(facing) < 0.0 {
        normal = -normal;
    }
    // In-plane axes of the smallest rectangle around the points (a rectangle's own edges;
    // principal axes turn with any corner hidden, and are arbitrary for a square).
    let major: Vector3<f64> = eig.eigenvectors.column(order[2]).into_owned();
    let minor = normal.cross(&major);
    let flat: Vec<(f64, f64)> = pts
        .iter()
        .map(|p| ((p - centre).dot(&major), (p - centre).dot(&minor)))
        .collect();
    let span = |angle: f64| {
        let (c, s) = (angle.cos(), angle.sin());
        let mut e = [[f64::INFINITY, f64::NEG_INFINITY]; 2];
        for &(x, y) in &flat {
            let (a, b) = (c * x + s * y, -s * x + c * y);
            e[0] = [e[0][0].min(a), e[0][1].max(a)];
            e[1] = [e[1][0].min(b), e[1][1].max(b)];
        }
        e
    };
    let area = |e: &[[f64; 2]; 2]| (e[0][1] - e[0][0]) * (e[1][1] - e[1][0]);
    let smallest = |angles: &mut dyn Iterator<Item = f64>| {
        angles
            .map(|a| (a, area(&span(a))))
            .fold((0.0, f64::INFINITY), |b, x| if x.1 < b.1 { x } else { b })
            .0
    };
    let coarse = smallest(&mut (0..90).map(|k| f64::from(k).to_radians()));
    let angle = smallest(&mut (-10..=10).map(|k| coarse + (0.1 * f64::from(k)).to_radians()));
    let (c, s) = (angle.cos(), angle.sin());
    let mut axes = [c * major + s * minor, -s * major + c * minor];
    let mut extent = span(angle);
    // The longer extent first (the smallest rectangle's angle is taken within 90 deg, so
    // either side may come out first).
    if extent[1][1] - extent[1][0] > extent[0][1] - extent[0][0] {
        axes = [axes[1], normal.cross(&axes[1])];
        extent = [extent[1], [-extent[0][1], -extent[0][0]]];
    }
    if !(normal.iter().all(|c| c.is_finite()) && centre.iter().all(|c| c.is_finite())) {
        return None;
    }
    Some(FlatPatch {
        centre,
        normal,
        axes,
        extent,
        points: pts.len(),
    })
}

/// How patches are laid on faces ([`laid_poses`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Laying {
    /// Lengths of patch and face agree within this, mm.
    pub slack_mm: f64,
    /// Spacing of the sampled points, mm: a patch's area is its points times its square.
    pub spacing_mm: f64,
    /// A patch is laid only on faces it covers this share of, in points.
    pub min_cover: f64,
    /// Patches and faces that fill less than this share of their extent's rectangle
    /// (area over length x width) are not laid: a Z-shaped end face or a wall cut by the
    /// parts in front of it has no edges to align.
    pub min_fill: f64,
    /// Poses returned, at most.
    pub max_poses: usize,
}

/// Poses (model -> scene) laying the scene's `patches` on the model's `faces`
/// ([`face_poses`]), those whose lengths agree best first (summed differences of length and
/// width; ties in patch, face and pose order), at most `laying.max_poses`.
pub fn laid_poses(
    faces: &[FlatPatch],
    patches: &[FlatPatch],
    laying: &Laying,
) -> Vec<Isometry3<f64>> {
    let filled = |p: &&FlatPatch| {
        p.points as f64 * laying.spacing_mm * laying.spacing_mm
            >= laying.min_fill * p.length(0) * p.length(1)
    };
    let faces: Vec<&FlatPatch> = faces.iter().filter(filled).collect();
    let mut laid: Vec<(f64, usize, Isometry3<f64>)> = Vec::new();
    for patch in patches.iter().filter(filled) {
        for face in &faces {
            if (patch.points as f64) < laying.min_cover * face.points as f64 {
                continue;
            }
            let mismatch =
                (patch.length(0) - face.length(0)).abs() + (patch.length(1) - face.length(1)).abs();
            for pose in face_poses(face, patch, laying.slack_mm) {
                laid.push((mismatch, laid.len(), pose));
            }
        }
    }
    laid.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    laid.into_iter()
        .take(laying.max_poses)
        .map(|(_, _, p)| p)
        .collect()
}

/// Poses (model -> scene) that lay the model's `face` on the scene's `patch`: the face's
/// normal onto the patch's, its axes onto the patch's either way round, and, along each axis,
/// the middles together when the lengths agree within `slack_mm`, or either end together
/// when the patch is shorter (the rest of the face hidden). None when the patch is longer
/// than the face either way round.
pub fn face_poses(face: &FlatPatch, patch: &FlatPatch, slack_mm: f64) -> Vec<Isometry3<f64>> {
    let mut poses = Vec::new();
    let model_frame = Matrix3::from_columns(&[face.axes[0], face.axes[1], face.normal]);
    for (axis, sign) in [(0usize, 1.0f64), (0, -1.0), (1, 1.0), (1, -1.0)] {
        let d0 = sign * patch.axes[axis];
        let d1 = patch.normal.cross(&d0);
        let scene_frame = Matrix3::from_columns(&[d0, d1, patch.normal]);
        let r = Rotation3::from_matrix_unchecked(scene_frame * model_frame.transpose());
        // The patch's extent along d0 and d1.
        let along = |k: usize, s: f64| {
            let [lo, hi] = patch.extent[k];
            if s > 0.0 { [lo, hi] } else { [-hi, -lo] }
        };
        let other = 1 - axis;
        // d1 = n x (sign * a_axis): +a_other for axis 0, -a_other for axis 1 (a1 = n x a0).
        let sign1 = if axis == 0 { sign } else { -sign };
        let spans = [along(axis, sign), along(other, sign1)];
        let mut shifts: Vec<Vec<f64>> = Vec::with_capacity(2);
        for ([plo, phi], [flo, fhi]) in spans.into_iter().zip(face.extent) {
            let (pl, fl) = (phi - plo, fhi - flo);
            if pl > fl + slack_mm {
                shifts.clear();
                break;
            }
            shifts.push(if pl >= fl - slack_mm {
                vec![0.5 * (plo + phi) - 0.5 * (flo + fhi)]
            } else {
                vec![plo - flo, phi - fhi]
            });
        }
        if shifts.len() < 2 {
            continue;
        }
        for &u0 in &shifts[0] {
            for &u1 in &shifts[1] {
                let t = patch.centre - r * face.centre + u0 * d0 + u1 * d1;
                poses.push(Isometry3::from_parts(
                    Translation3::from(t),
                    UnitQuaternion::from_rotation_matrix(&r),
                ));
            }
        }
    }
    poses
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(w: usize, h: usize, step: f32, at: impl Fn(f32, f32) -> (P3, P3)) -> OrientedPoints {
        let mut o = OrientedPoints::default();
        for i in 0..w {
            for j in 0..h {
                let (p, n) = at(i as f32 * step, j as f32 * step);
                o.points.push(p);
                o.normals.push(n);
            }
        }
        o
    }

    /// The patch of a `w` x `h` grid at 1 mm in the plane z = 0, facing +z.
    fn flat_rectangle(w: usize, h: usize) -> FlatPatch {
        let r = grid(w, h, 1.0, |x, y| ([x, y, 0.0], [0.0, 0.0, 1.0]));
        flat_patches(&r, &REGIONS).unwrap().remove(0)
    }

    const REGIONS: FlatRegions = FlatRegions {
        connect_mm: 1.5,
        max_angle_deg: 10.0,
        max_offset_mm: 0.5,
        min_points: 10,
    };

    #[test]
    fn a_rectangle_is_one_patch_with_its_length_and_width() {
        let r = grid(41, 21, 1.0, |x, y| ([x, y, 5.0], [0.0, 0.0, 1.0]));
        let p = flat_patches(&r, &REGIONS).unwrap();
        assert_eq!(p.len(), 1);
        assert!((p[0].length(0) - 40.0).abs() < 1e-6 && (p[0].length(1) - 20.0).abs() < 1e-6);
        assert!((p[0].normal.z - 1.0).abs() < 1e-9);
    }

    #[test]
    fn a_rectangle_with_a_corner_hidden_keeps_its_edges_as_axes() {
        let turn = 30f32.to_radians();
        let mut r = grid(41, 27, 1.0, |x, y| {
            let (c, s) = (turn.cos(), turn.sin());
            ([c * x - s * y, s * x + c * y, 2.0], [0.0, 0.0, 1.0])
        });
        // Hide a 12 x 12 mm corner: the principal axes turn away from the edges.
        let keep: Vec<bool> = (0..41)
            .flat_map(|i| (0..27).map(move |j| !(i >= 29 && j >= 15)))
            .collect();
        let mut k = keep.iter();
        r.points.retain(|_| *k.next().unwrap());
        let mut k = keep.iter();
        r.normals.retain(|_| *k.next().unwrap());
        let p = flat_patches(&r, &REGIONS).unwrap().remove(0);
        let along = Vector3::new(f64::from(turn.cos()), f64::from(turn.sin()), 0.0);
        assert!(p.axes[0].dot(&along).abs() > 0.9999, "{:?}", p.axes);
        assert!((p.length(0) - 40.0).abs() < 0.05 && (p.length(1) - 26.0).abs() < 0.05);
    }

    #[test]
    fn two_faces_at_right_angles_are_two_patches() {
        let mut r = grid(20, 20, 1.0, |x, y| ([x, y, 0.0], [0.0, 0.0, 1.0]));
        let wall = grid(20, 10, 1.0, |y, z| ([-1.0, y, z + 1.0], [-1.0, 0.0, 0.0]));
        r.points.extend(wall.points);
        r.normals.extend(wall.normals);
        let p = flat_patches(&r, &REGIONS).unwrap();
        assert_eq!(
            p.iter().map(|p| p.points).collect::<Vec<_>>(),
            vec![400, 200]
        );
    }

    #[test]
    fn a_face_laid_on_its_moved_copy_gives_the_move_back() {
        let face = flat_rectangle(31, 16);
        let moved = Isometry3::new(Vector3::new(10.0, -4.0, 30.0), Vector3::new(0.3, -0.5, 1.1));
        let seen = grid(31, 16, 1.0, |x, y| {
            let p = moved * nalgebra::Point3::new(x as f64, y as f64, 0.0);
            let n = moved.rotation * Vector3::z();
            (
                [p.x as f32, p.y as f32, p.z as f32],
                [n.x as f32, n.y as f32, n.z as f32],
            )
        });
        let patch = flat_patches(&seen, &REGIONS).unwrap().remove(0);
        let poses = face_poses(&face, &patch, 1.0);
        // A rectangle fits its copy four ways (the in-plane half turn, and flipped axes
        // only when square); one of them is the move.
        assert!(!poses.is_empty());
        let best = poses
            .iter()
            .map(|p| {
                let d = p.inverse() * moved;
                d.translation.vector.norm() + d.rotation.angle()
            })
            .fold(f64::INFINITY, f64::min);
        assert!(best < 1e-3, "{best}");
    }

    #[test]
    fn a_patch_longer_than_the_face_gives_no_pose() {
        let (face, patch) = (flat_rectangle(11, 11), flat_rectangle(31, 11));
        assert!(face_poses(&face, &patch, 1.0).is_empty());
    }

    #[test]
    fn faces_whose_lengths_agree_come_first_and_thin_shapes_are_not_laid() {
        let mut ell = grid(41, 6, 1.0, |x, y| ([x, y, 0.0], [0.0, 0.0, 1.0]));
        let arm = grid(6, 35, 1.0, |x, y| ([x, y + 6.0, 0.0], [0.0, 0.0, 1.0]));
        ell.points.extend(arm.points);
        ell.normals.extend(arm.normals);
        let ell = flat_patches(&ell, &REGIONS).unwrap().remove(0);
        let faces = [flat_rectangle(41, 41), ell, flat_rectangle(41, 27)];
        let patch = flat_rectangle(41, 27);
        let laying = Laying {
            slack_mm: 1.0,
            spacing_mm: 1.0,
            min_cover: 0.4,
            min_fill: 0.5,
            max_poses: 100,
        };
        let poses = laid_poses(&faces, std::slice::from_ref(&patch), &laying);
        // The 41 x 27 face first (its two in-plane half turns), then the square's hidden
        // ends; none from the L (it fills a quarter of its rectangle).
        let from_rectangle = face_poses(&faces[2], &patch, 1.0);
        assert_eq!(from_rectangle.len(), 2);
        assert_eq!(poses[..2], from_rectangle[..]);
        assert_eq!(poses.len(), 2 + face_poses(&faces[0], &patch, 1.0).len());
        let capped = laid_poses(
            &faces,
            std::slice::from_ref(&patch),
            &Laying {
                max_poses: 1,
                ..laying
            },
        );
        assert_eq!(capped, poses[..1]);
    }
}
