//! Scene voting, step 1: pose hypotheses from the whole scene. The model's point pairs are
//! filed once per working scale ([`VotingModel`]); the scene is sampled at the same step with
//! PCL's `UniformSampling` and `NormalEstimationOMP`; every reference point votes
//! (Drost et al. 2010) and the votes are clustered into poses under the part's symmetries.

use nalgebra::{Isometry3, Point3};

use binpick_cloud::Point;
use binpick_match::{
    OrientedPoints, PointIndex, PoseCluster, PoseClustering, PpfConfig, PpfModel, cluster_poses,
    subsample_by_facing,
};
use binpick_pcl::IcpParams;

use crate::error::{Error, Result, pcl};
use crate::params::VotingConfig;
use crate::result::DerivedScale;
use crate::stages::model::near_symmetries;
use crate::stages::part::Part;

/// Errors of the matching crate, attributed to a stage.
pub(crate) fn matching(stage: &'static str) -> impl Fn(binpick_match::MatchError) -> Error {
    move |e| Error::Input {
        what: stage,
        kind: crate::error::InputKind::Degenerate,
        message: e.to_string(),
    }
}

/// Model points a near-symmetry is judged on.
const SYMMETRY_SAMPLE_POINTS: usize = 600;

/// A near-symmetric turn within this angle ...
const DECLARED_SAME_DEG: f64 = 10.0;
/// ... and this share of the diameter of a declared symmetry is that symmetry.
const DECLARED_SAME_DIAMETERS: f64 = 0.05;

/// The part prepared for one working scale.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub(crate) struct VotingModel {
    /// The part's surface at the working resolution (what is rendered and aligned).
    pub dense: OrientedPoints,
    pub table: PpfModel,
    /// Centroid of the surface, model frame.
    pub centre: Point3<f64>,
    /// Half-turns about the principal axes that map the part nearly onto itself.
    pub near_symmetries: Vec<Isometry3<f64>>,
}

impl VotingModel {
    /// Samples the part at `scale` and files its point pairs.
    pub(crate) fn new(part: &Part, scale: &DerivedScale, cfg: &VotingConfig) -> Result<Self> {
        // Both sides of a thin part must survive the sampling (each face is seen from its own
        // side): sampled per facing, not per cell.
        let dense = subsample_by_facing(&part.surface, scale.resolution_mm);
        let samples = subsample_by_facing(&dense, scale.sampling_step_mm);
        let table = PpfModel::new(
            &samples,
            PpfConfig {
                distance_step_mm: scale.sampling_step_mm,
                feature_angle_bins: cfg.feature_angle_bins,
                alpha_bins: cfg.alpha_bins,
                max_pair_distance_mm: part.size.diameter_mm,
                spread: cfg.spread,
                max_pairs_per_bin: cfg.max_pairs_per_bin,
            },
        )
        .map_err(matching("model point pairs"))?;
        let kp: Vec<Point> = binpick_cloud::strided_points(&dense.points, SYMMETRY_SAMPLE_POINTS)
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let eps = 1e-6 * scale.resolution_mm * scale.resolution_mm;
        let near_symmetries = near_symmetries(
            &dense.points,
            &kp,
            part.size.diameter_mm,
            &|turn: &Isometry3<f64>| IcpParams {
                initial: binpick_pcl::row_major(turn),
                max_correspondence_distance: 0.1 * part.size.diameter_mm,
                max_iterations: 30,
                transformation_epsilon: eps,
                batch_correspondences: true,
                relative_mse: 1e-4,
            },
        )?
        .into_iter()
        // A declared symmetry is not a trap (a ring's half turn is one).
        .filter(|turn| {
            part.symmetries.transforms().iter().all(|s| {
                let moved = s.inverse() * turn;
                moved.rotation.angle().to_degrees() > DECLARED_SAME_DEG
                    || moved.translation.vector.norm()
                        > DECLARED_SAME_DIAMETERS * part.size.diameter_mm
            })
        })
        .collect();
        Ok(Self {
            centre: part.centre(),
            dense,
            table,
            near_symmetries,
        })
    }
}

/// `points` thinned by PCL's `UniformSampling` at `leaf` (the point nearest each cell's
/// centre is kept, with its normal).
pub(crate) fn subsample(points: &OrientedPoints, leaf: f64) -> Result<OrientedPoints> {
    let idx = binpick_pcl::uniform_sampling(&points.points, leaf as f32)
        .map_err(pcl("uniform sampling"))?;
    Ok(OrientedPoints {
        points: idx.iter().map(|&i| points.points[i as usize]).collect(),
        normals: idx.iter().map(|&i| points.normals[i as usize]).collect(),
    })
}

/// Normals of `points`, oriented towards `viewpoint` (NaN where undefined): PCL's
/// `NormalEstimationOMP` at the derived radius, searching all of them, except at support
/// points (`support[i]`) whose nearest support plane in `planes` (`a x + b y + c z + d = 0`,
/// unit normal; with `true` where the plane bounds the parts) bounds the parts: those take
/// the plane's normal. A belt is most of its scan and its plane is known, so estimating its
/// normals would cost most of this stage for nothing; a plane that does not bound the parts
/// may have been laid across their tops, where the surface is not the plane.
pub(crate) fn scene_normals(
    points: &[Point],
    support: &[bool],
    planes: &[([f64; 4], bool)],
    scale: &DerivedScale,
    viewpoint: [f64; 3],
    threads: u32,
) -> Result<Vec<[f32; 3]>> {
    let vp = nalgebra::Vector3::from(viewpoint);
    let on_plane = |p: &Point| -> Option<[f32; 3]> {
        let q = nalgebra::Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        let distance = |c: &[f64; 4]| (c[0] * q.x + c[1] * q.y + c[2] * q.z + c[3]).abs();
        let (c, bounds) = planes
            .iter()
            .min_by(|a, b| distance(&a.0).total_cmp(&distance(&b.0)))?;
        bounds.then(|| {
            let n = nalgebra::Vector3::new(c[0], c[1], c[2]);
            // As PCL flips: towards the viewpoint.
            let n = if n.dot(&(vp - q)) < 0.0 { -n } else { n };
            [n.x as f32, n.y as f32, n.z as f32]
        })
    };
    let mut normals: Vec<Option<[f32; 3]>> = points
        .iter()
        .zip(support)
        .map(|(p, &s)| if s { on_plane(p) } else { None })
        .collect();
    let estimate: Vec<u32> = (0..points.len() as u32)
        .filter(|&i| normals[i as usize].is_none())
        .collect();
    let estimated = binpick_pcl::estimate_normals_at(
        points,
        &estimate,
        scale.normal_radius_mm as f32,
        viewpoint.map(|c| c as f32),
        threads,
    )
    .map_err(pcl("scene normals"))?;
    for (&i, n) in estimate.iter().zip(&estimated) {
        normals[i as usize] = Some(n.normal);
    }
    Ok(normals
        .into_iter()
        .map(|n| n.unwrap_or([f32::NAN; 3]))
        .collect())
}

/// A neighbourhood is a ribbon when its second spread (variance) is under this share of its
/// first: a strip a few points wide (a sheet seen edge on), where a plane fitted over the
/// neighbourhood cannot tell the strip's face from its width.
const RIBBON_SPREAD_RATIO: f64 = 0.15;

/// The scene's normals as the view judges a pose by them: `normals`, except that a part's
/// point (not `support`) whose neighbourhood within `radius` (mm) is a ribbon
/// ([`RIBBON_SPREAD_RATIO`]) faces the sensor at `viewpoint` across the ribbon's axis: a
/// strip the sensor sees faces it. (Voting keeps the fitted normals.)
pub(crate) fn view_normals(
    points: &[Point],
    support: &[bool],
    normals: &[[f32; 3]],
    radius: f64,
    viewpoint: [f64; 3],
) -> Result<Vec<[f32; 3]>> {
    use rayon::prelude::*;
    let vp = nalgebra::Vector3::from(viewpoint);
    let index = PointIndex::new("scene", points).map_err(matching("scene normals"))?;
    let at = |q: &Point| nalgebra::Vector3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]));
    Ok(points
        .par_iter()
        .zip(support)
        .zip(normals)
        .map_init(Vec::new, |near, ((p, &s), &n)| {
            if s {
                return n;
            }
            index.within_into(p, radius as f32, near);
            if near.len() < 3 {
                return n;
            }
            let mean = near
                .iter()
                .map(|&k| at(&points[k as usize]))
                .sum::<nalgebra::Vector3<f64>>()
                / near.len() as f64;
            let cov = near
                .iter()
                .map(|&k| {
                    let d = at(&points[k as usize]) - mean;
                    d * d.transpose()
                })
                .sum::<nalgebra::Matrix3<f64>>();
            let eig = nalgebra::SymmetricEigen::new(cov);
            let mut order = [0usize, 1, 2];
            order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
            let (first, second) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]]);
            if !(first > 0.0 && second < RIBBON_SPREAD_RATIO * first) {
                return n;
            }
            let axis = eig.eigenvectors.column(order[0]).into_owned();
            let to_sensor = (vp - at(p)).normalize();
            let across = to_sensor - axis * axis.dot(&to_sensor);
            let len = across.norm();
            if len > 1e-6 {
                let a = across / len;
                [a.x as f32, a.y as f32, a.z as f32]
            } else {
                n
            }
        })
        .collect())
}

/// The scene's samples at the sampling step (the `world` points with their normals);
/// samples without a normal are dropped.
pub(crate) fn scene_samples(world: OrientedPoints, scale: &DerivedScale) -> Result<OrientedPoints> {
    Ok(subsample(&world, scale.sampling_step_mm)?.with_defined_normals())
}

/// Votes over the scene samples and the strongest pose clusters, best first.
pub(crate) fn vote(
    model: &VotingModel,
    part: &Part,
    samples: &OrientedPoints,
    scale: &DerivedScale,
    cfg: &VotingConfig,
) -> Result<(usize, Vec<PoseCluster>)> {
    if samples.len() < 3 {
        return Ok((0, Vec::new()));
    }
    let index = PointIndex::new("scene samples", &samples.points).map_err(matching("scene"))?;
    let votes = model
        .table
        .vote(
            samples,
            &index,
            &binpick_match::VotingConfig {
                reference_stride: cfg.reference_stride,
                peaks_per_reference: cfg.peaks_per_reference,
                secondary_peak_ratio: cfg.secondary_peak_ratio,
            },
        )
        .map_err(matching("voting"))?;
    let mut clusters = cluster_poses(
        &votes,
        &model.centre,
        &part.symmetries,
        &PoseClustering {
            translation_mm: cfg.cluster_translation_diameters * scale.model_diameter_mm,
            rotation_deg: cfg.cluster_rotation_deg,
        },
    )
    .map_err(matching("pose clustering"))?;
    clusters.truncate(cfg.hypotheses);
    Ok((votes.len(), clusters))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Params;
    use crate::stages::scale::PartSize;

    /// A tilted belt (z = 0.1 x) with a box standing on it, scanned from above.
    fn belt_with_box() -> (Vec<Point>, Vec<bool>, [f64; 4]) {
        let tilt = 0.1f64;
        let mut points = Vec::new();
        let mut support = Vec::new();
        for i in 0..60 {
            for j in 0..60 {
                let (x, y) = (i as f32, j as f32);
                points.push([x, y, tilt as f32 * x]);
                support.push(true);
                // The box's top, 10 mm above the belt.
                if (20..40).contains(&i) && (20..40).contains(&j) {
                    points.push([x + 0.5, y + 0.5, tilt as f32 * (x + 0.5) + 10.0]);
                    support.push(false);
                }
            }
        }
        let norm = (1.0 + tilt * tilt).sqrt();
        (points, support, [-tilt / norm, 0.0, 1.0 / norm, 0.0])
    }

    #[test]
    fn support_of_a_bounding_plane_takes_its_normal_and_other_points_are_estimated() {
        let (points, support, plane) = belt_with_box();
        let part = PartSize {
            diameter_mm: 40.0,
            view_area_mm2: 400.0,
            curvature_radius_mm: None,
        };
        let scale = DerivedScale::derive(&part, None, &Params::default()).unwrap();
        let above = [30.0, 30.0, 1e6];
        let both = scene_normals(&points, &support, &[(plane, true)], &scale, above, 2).unwrap();
        let flipped = plane.map(|c| -c);
        let other = scene_normals(&points, &support, &[(flipped, true)], &scale, above, 1).unwrap();
        let estimated = binpick_pcl::estimate_normals(
            &points,
            scale.normal_radius_mm as f32,
            [30.0, 30.0, 1e6],
            1,
        )
        .unwrap();
        let up = plane.map(|c| c as f32);
        for (i, s) in support.iter().enumerate() {
            if *s {
                // The plane's normal, turned towards the sensor whichever way it was given.
                for n in [both[i], other[i]] {
                    for k in 0..3 {
                        assert!((n[k] - up[k]).abs() < 1e-6, "point {i}: {n:?}");
                    }
                }
            } else {
                // PCL's own estimate, bit for bit, searching the belt too.
                assert_eq!(
                    both[i].map(f32::to_bits),
                    estimated[i].normal.map(f32::to_bits)
                );
            }
        }
        // A plane that does not bound the parts leaves its points to PCL.
        let kept = scene_normals(&points, &support, &[(plane, false)], &scale, above, 2).unwrap();
        for (k, e) in kept.iter().zip(&estimated) {
            assert_eq!(k.map(f32::to_bits), e.normal.map(f32::to_bits));
        }
    }

    #[test]
    fn a_strip_seen_edge_on_faces_the_sensor_in_the_view_and_nothing_else_moves() {
        // Deterministic noise of about 0.6 mm.
        let noise = |k: usize| 0.6 * ((k as f32 * 12.9898).sin() * 43_758.547).fract();
        let mut points = Vec::new();
        let mut support = Vec::new();
        let mut normals = Vec::new();
        // A sheet's edge 40 mm up, two rows of a 2 mm scan wide, with sideways normals (what
        // a plane fitted across the strip and its noise can give).
        for i in 0..30 {
            for row in [0.0, 1.5] {
                let k = points.len();
                points.push([2.0 * i as f32, row, 40.0 + noise(k)]);
                support.push(false);
                normals.push([0.0, 1.0, 0.0]);
            }
        }
        let strip = points.len();
        // A tilted face of a part (z = 0.3 x + 10) with its fitted normals, and a floor strip.
        let tilted = {
            let n = nalgebra::Vector3::new(-0.3f32, 0.0, 1.0).normalize();
            [n.x, n.y, n.z]
        };
        for i in 0..20 {
            for j in 0..20 {
                let (x, y) = (2.0 * i as f32, 20.0 + 2.0 * j as f32);
                points.push([x, y, 0.3 * x + 10.0]);
                support.push(false);
                normals.push(tilted);
            }
        }
        for i in 0..30 {
            points.push([2.0 * i as f32, -30.0, 0.0]);
            support.push(true);
            normals.push([0.0, 1.0, 0.0]);
        }
        let above = [30.0, 0.0, 1e7];
        let view = view_normals(&points, &support, &normals, 5.75, above).unwrap();
        // Away from its ends (within a radius of an end the neighbourhood is a short, wide
        // patch: the fitted normal stands).
        for (i, n) in view[..strip].iter().enumerate() {
            let x = points[i][0];
            if (6.0..=52.0).contains(&x) {
                assert!(n[2] > 0.99, "strip point {i}: {n:?}");
            }
        }
        for k in strip..points.len() {
            assert_eq!(
                view[k].map(f32::to_bits),
                normals[k].map(f32::to_bits),
                "{k}"
            );
        }
    }
}
