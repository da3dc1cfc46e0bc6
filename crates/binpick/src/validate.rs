//! The validation functions of thesis 3.1, in plain Rust over a kiddo kd-tree.
//!
//! All three take the model points in the model frame plus a pose (model -> scene) and the
//! scene ("world") points in a [`NearestIndex`]; distances are millimetres.
//!
//! | function              | thesis  | formula                                                        | perfect | worst        |
//! |-----------------------|---------|----------------------------------------------------------------|---------|--------------|
//! | [`euclidean_score`]   | 3.1.1   | (1/m) sum_i min_j \|\|o_i - w_j\|\|^2  (mm^2)                      | 0       | f64::MAX     |
//! | [`outlier_percent`]   | 3.1.2   | (100/m) sum_i [min_j \|\|o_i - w_j\|\| > d]                        | 0       | 100          |
//! | [`normal_angle_score`]| 3.1.3   | (1/m) sum_i angle(n(o_i), n(w_nearest(i)))^2  (deg^2)          | 0       | 180^2        |

use nalgebra::{Isometry3, Vector3};

use binpick_cloud::{Point, transform_point};

/// Exact nearest-neighbour index over a fixed set of points (kiddo's immutable kd-tree; the
/// one the scene-voting engine uses too).
pub use binpick_match::PointIndex as NearestIndex;

/// Euclidean distance validation (thesis 3.1.1): the mean, over the model points placed by
/// `pose`, of the squared distance to the nearest world point, mm^2. 0 is a perfect
/// alignment; an empty model scores `f64::MAX` (the thesis's FLT_MAX "worst").
pub fn euclidean_score(world: &NearestIndex, model: &[Point], pose: &Isometry3<f64>) -> f64 {
    if model.is_empty() {
        return f64::MAX;
    }
    let sum: f64 = model
        .iter()
        .map(|p| f64::from(world.nearest(&transform_point(pose, p)).1))
        .sum();
    sum / model.len() as f64
}

/// Percent-of-outliers validation (thesis 3.1.2): the share, in percent, of model points placed
/// by `pose` whose nearest world point is farther than `distance_mm`. Every outlier counts 1
/// however far it is. 0 is perfect, 100 worst (also for an empty model).
pub fn outlier_percent(
    world: &NearestIndex,
    model: &[Point],
    pose: &Isometry3<f64>,
    distance_mm: f64,
) -> f64 {
    if model.is_empty() {
        return 100.0;
    }
    let limit = (distance_mm * distance_mm) as f32;
    let outliers = model
        .iter()
        .filter(|p| world.nearest(&transform_point(pose, p)).1 > limit)
        .count();
    100.0 * outliers as f64 / model.len() as f64
}

/// Normal-angle validation (thesis 3.1.3): the mean squared angle, in degrees^2, between each
/// model point's normal (rotated by `pose`) and the normal of its nearest world point. Points
/// whose own or matched normal is undefined (NaN) are skipped; 0 is perfect, 180^2 worst (also
/// when no point has a defined pair). The thesis found it slower and less discriminative than
/// the other two; it is kept for comparison, not used by the pipeline.
pub fn normal_angle_score(
    world: &NearestIndex,
    world_normals: &[[f32; 3]],
    model: &[Point],
    model_normals: &[[f32; 3]],
    pose: &Isometry3<f64>,
) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for (p, mn) in model.iter().zip(model_normals) {
        let (j, _) = world.nearest(&transform_point(pose, p));
        let Some(wn) = world_normals.get(j) else {
            continue;
        };
        let a = pose.rotation * Vector3::new(f64::from(mn[0]), f64::from(mn[1]), f64::from(mn[2]));
        let b = Vector3::new(f64::from(wn[0]), f64::from(wn[1]), f64::from(wn[2]));
        let (na, nb) = (a.norm(), b.norm());
        if !(na.is_finite() && nb.is_finite() && na > 0.0 && nb > 0.0) {
            continue;
        }
        let angle = (a.dot(&b) / (na * nb)).clamp(-1.0, 1.0).acos().to_degrees();
        sum += angle * angle;
        n += 1;
    }
    if n == 0 {
        180.0 * 180.0
    } else {
        sum / n as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn shift(x: f64, y: f64, z: f64) -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::identity())
    }

    // World: 4 points on the x axis at 0, 10, 20, 30 mm.
    fn world() -> NearestIndex {
        NearestIndex::new(
            "world",
            &[
                [0.0, 0.0, 0.0],
                [10.0, 0.0, 0.0],
                [20.0, 0.0, 0.0],
                [30.0, 0.0, 0.0],
            ],
        )
        .unwrap()
    }

    #[test]
    fn euclidean_score_by_hand() {
        let w = world();
        // Model points at x = 1, 12, 26 (after a +1 mm shift in z): nearest world points
        // at squared distances 1+1, 4+1, 16+1 -> mean (2 + 5 + 17) / 3 = 8.
        let model = [[1.0, 0.0, 0.0], [12.0, 0.0, 0.0], [26.0, 0.0, 0.0]];
        let s = euclidean_score(&w, &model, &shift(0.0, 0.0, 1.0));
        assert!((s - 8.0).abs() < 1e-5, "{s}");
        assert_eq!(euclidean_score(&w, &[], &Isometry3::identity()), f64::MAX);
        assert_eq!(
            euclidean_score(&w, &[[20.0, 0.0, 0.0]], &Isometry3::identity()),
            0.0
        );
    }

    #[test]
    fn outlier_percent_by_hand() {
        let w = world();
        // Distances 1, 2, 4.5, 9 with threshold 4: two outliers of four = 50 %.
        let model = [
            [1.0, 0.0, 0.0],
            [12.0, 0.0, 0.0],
            [20.0, 4.5, 0.0],
            [30.0, 0.0, 9.0],
        ];
        assert_eq!(
            outlier_percent(&w, &model, &Isometry3::identity(), 4.0),
            50.0
        );
        // A point exactly at the threshold is not an outlier ("> distanceThreshold").
        assert_eq!(
            outlier_percent(&w, &[[0.0, 4.0, 0.0]], &Isometry3::identity(), 4.0),
            0.0
        );
        // Far is no worse than just-outside: each outlier counts 1.
        assert_eq!(
            outlier_percent(&w, &[[0.0, 1e4, 0.0]], &Isometry3::identity(), 4.0),
            100.0
        );
        assert_eq!(outlier_percent(&w, &[], &Isometry3::identity(), 4.0), 100.0);
        // Moving the model moves its points: +40 mm along x puts everything beyond the world.
        assert_eq!(
            outlier_percent(&w, &model[..2], &shift(40.0, 0.0, 0.0), 4.0),
            100.0
        );
    }

    #[test]
    fn normal_angle_score_by_hand() {
        let w = world();
        let up = [0.0f32, 0.0, 1.0];
        let world_normals = [up, up, [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]];
        // Nearest pairs: point 0 (0 deg), point 2 (90 deg), point 3 (180 deg).
        let model = [[0.0, 0.0, 0.0], [20.0, 0.0, 0.0], [30.0, 0.0, 0.0]];
        let s = normal_angle_score(
            &w,
            &world_normals,
            &model,
            &[up, up, up],
            &Isometry3::identity(),
        );
        let expect = (0.0 + 90.0f64.powi(2) + 180.0f64.powi(2)) / 3.0;
        assert!((s - expect).abs() < 1e-6, "{s} vs {expect}");
        // Rotating the model by 90 deg about y turns its +z normals into +x: point 2 now agrees.
        let rot = Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::FRAC_PI_2),
        );
        let s2 = normal_angle_score(
            &w,
            &world_normals,
            &[[20.0, 0.0, 0.0]],
            &[up],
            &(shift(20.0, 0.0, 0.0) * rot * shift(-20.0, 0.0, 0.0)),
        );
        assert!(s2 < 1e-6, "{s2}");
        let nan = [f32::NAN; 3];
        assert_eq!(
            normal_angle_score(
                &w,
                &world_normals,
                &model[..1],
                &[nan],
                &Isometry3::identity()
            ),
            180.0 * 180.0
        );
    }

    #[test]
    fn index_rejects_bad_points() {
        assert!(NearestIndex::new("world", &[]).is_err());
        assert!(NearestIndex::new("world", &[[0.0; 3], [f32::NAN, 0.0, 0.0]]).is_err());
        let w = world();
        let mut found = Vec::new();
        w.within_into(&[10.5, 0.0, 0.0], 10.0, &mut found);
        found.sort();
        assert_eq!(found, vec![1, 2]);
    }
}
