#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use binpick_cloud::PointCloud;
use binpick_cloud::io::read_cloud_with_colors;
use binpick_viz::{Placed, VizError, labelled_cloud, rank_color, write_labelled_ply};
use common::{at, floor, plate, rotated_z};

fn placed(rank: usize, pose: nalgebra::Isometry3<f64>) -> Placed {
    Placed {
        rank,
        pose,
        final_score: 1.0,
        initial_score: 100.0,
        seen: None,
        free_to_pick: true,
    }
}

/// Brute force: for each scene point, the index of the placed model with the nearest point
/// within `d`, or None.
fn expected_labels(
    scene: &PointCloud,
    model: &PointCloud,
    list: &[Placed],
    d: f64,
) -> Vec<Option<usize>> {
    let placed: Vec<(usize, PointCloud)> = list
        .iter()
        .enumerate()
        .map(|(i, p)| (i, model.transformed(&p.pose)))
        .collect();
    scene
        .points
        .iter()
        .map(|s| {
            let mut best: Option<(f64, usize)> = None;
            for (i, pts) in &placed {
                for q in &pts.points {
                    let d2: f64 = (0..3)
                        .map(|k| (f64::from(s[k]) - f64::from(q[k])).powi(2))
                        .sum();
                    if d2 <= d * d && best.is_none_or(|(bd, _)| d2 < bd) {
                        best = Some((d2, *i));
                    }
                }
            }
            best.map(|(_, i)| i)
        })
        .collect()
}

#[test]
fn scene_points_under_a_model_get_its_colour_and_counts_match() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("l.ply");
    let scene = floor(60.0, 2.0);
    let model = plate(20.0, 1.0);
    let list = [
        placed(1, at(-30.0, -30.0, 0.5)),
        placed(2, rotated_z(25.0, 20.0, 0.0, 30.0)),
    ];
    let info = write_labelled_ply(&scene, &model, &list, 1.5, &out).unwrap();
    let back = read_cloud_with_colors(&out).unwrap();
    let colors = back.colors.unwrap();
    // Points: the scene, then every placed model.
    assert_eq!(info.scene_points, scene.len());
    assert_eq!(info.model_points, 2 * model.len());
    assert_eq!(back.cloud.len(), scene.len() + 2 * model.len());
    assert_eq!(colors.len(), back.cloud.len());
    assert_eq!(&back.cloud.points[..scene.len()], &scene.points[..]);
    // Explained points per detection, against brute force.
    let want = expected_labels(&scene, &model, &list, 1.5);
    for (i, w) in want.iter().enumerate() {
        let c = colors[i];
        match w {
            Some(k) => assert_eq!(c, rank_color(list[*k].rank), "scene point {i}"),
            None => assert_eq!(c, binpick_viz::UNEXPLAINED_GREY, "scene point {i}"),
        }
    }
    let count = |k| want.iter().filter(|w| **w == Some(k)).count();
    assert_eq!(info.explained, vec![count(0), count(1)]);
    // A 20 mm plate on a 2 mm grid covers about 11 x 11 floor points.
    assert!(
        (100..=200).contains(&info.explained[0]),
        "{:?}",
        info.explained
    );
    assert_eq!(info.unexplained, scene.len() - count(0) - count(1));
    // Points right under the first plate's centre are its colour, far ones grey.
    let idx = |x: f32, y: f32| {
        scene
            .points
            .iter()
            .position(|p| p[0] == x && p[1] == y)
            .unwrap()
    };
    assert_eq!(colors[idx(-30.0, -30.0)], rank_color(1));
    assert_eq!(colors[idx(24.0, 20.0)], rank_color(2));
    assert_eq!(colors[idx(40.0, -40.0)], binpick_viz::UNEXPLAINED_GREY);
    // Model points carry their detection's (darkened) colour.
    let m0 = colors[scene.len()];
    let m1 = colors[scene.len() + model.len()];
    assert_ne!(m0, m1);
    assert!(m0[0] > m0[1], "rank 1 is red: {m0:?}");
    // Moving a detection moves its explained points.
    let moved = [placed(1, at(30.0, -30.0, 0.5))];
    let (_, c2, i2) = labelled_cloud(&scene, &model, &moved, 1.5).unwrap();
    assert_eq!(c2[idx(-30.0, -30.0)], binpick_viz::UNEXPLAINED_GREY);
    assert_eq!(c2[idx(30.0, -30.0)], rank_color(1));
    assert_eq!(i2.explained[0], info.explained[0]);
}

#[test]
fn distance_is_respected_and_bad_input_is_an_error() {
    let scene = floor(20.0, 2.0);
    let model = plate(10.0, 1.0);
    // 3 mm above the floor: nothing within 2 mm, everything under it within 4 mm.
    let list = [placed(1, at(0.0, 0.0, 3.0))];
    let (_, _, near) = labelled_cloud(&scene, &model, &list, 2.0).unwrap();
    assert_eq!(near.explained, vec![0]);
    let (_, _, far) = labelled_cloud(&scene, &model, &list, 4.0).unwrap();
    assert!(far.explained[0] >= 36, "{:?}", far.explained);

    for d in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let r = labelled_cloud(&scene, &model, &list, d);
        assert!(matches!(r, Err(VizError::InvalidOption(_))), "{d}: {r:?}");
    }
    let r = labelled_cloud(&PointCloud::default(), &model, &list, 1.0);
    assert!(matches!(r, Err(VizError::EmptyScene { .. })), "{r:?}");
    let r = labelled_cloud(&scene, &PointCloud::default(), &list, 1.0);
    assert!(matches!(r, Err(VizError::EmptyModel { .. })), "{r:?}");
    // No detections: every point grey; NaN points and NaN poses are skipped and counted.
    let mut s2 = scene.clone();
    s2.points.push([f32::NAN, 0.0, 0.0]);
    let mut bad = at(0.0, 0.0, 0.0);
    bad.translation.vector.z = f64::NAN;
    let (cloud, colors, info) = labelled_cloud(&s2, &model, &[placed(1, bad)], 1.0).unwrap();
    assert_eq!(info.scene_non_finite, 1);
    assert_eq!(info.detections_skipped, vec![0]);
    assert_eq!(info.explained, vec![0]);
    assert_eq!(cloud.len(), scene.len());
    assert!(colors.iter().all(|c| *c == binpick_viz::UNEXPLAINED_GREY));
    let (_, _, none) = labelled_cloud(&scene, &PointCloud::default(), &[], 1.0).unwrap();
    assert_eq!(none.unexplained, scene.len());
}
