//! The real Kinect scan from PCL's test data (data/pcl, BSD): the milk carton must be found in
//! the cluttered table scene, on the carton's own points.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::PathBuf;

use binpick::validate::NearestIndex;
use binpick::{
    Engine, Params, PointCloud, Recognizer, Units, load_cloud, load_part, sensor_position,
};
use nalgebra::Isometry3;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../data/pcl")
        .join(name)
}

/// Share of `model` points, placed by `pose`, within 8 mm of the carton's own points.
fn share_on_carton(crop: &PointCloud, model: &[[f32; 3]], pose: &Isometry3<f64>) -> f64 {
    let crop_index = NearestIndex::new("crop", &crop.points).unwrap();
    let on = model
        .iter()
        .map(|p| binpick_cloud::transform_point(pose, p))
        .filter(|p| crop_index.nearest(p).1 < 64.0)
        .count();
    on as f64 / model.len() as f64
}

/// Issue 11: with defaults (only the units given), the scene-voting engine finds the carton,
/// on the carton's own points, and nothing else.
#[test]
fn defaults_find_the_milk_carton() {
    let params = Params {
        units: Units::Metres,
        ..Params::default()
    };
    assert_eq!(params.engine, Engine::SceneVoting);
    let (part, _) = load_part(&data("milk_model.pcd"), params.units, &params).unwrap();
    let (scene, report) =
        load_cloud(&data("milk_cartoon_all_small_clorox.pcd"), params.units).unwrap();
    let (crop, _) = load_cloud(&data("milk_scene_crop.pcd"), params.units).unwrap();
    let seen_from = sensor_position(&report, params.units);
    assert_eq!(
        seen_from,
        Some([0.0; 3]),
        "an organised cloud is in its camera's frame"
    );
    let surface = part.surface.points.clone();
    let rec = Recognizer::with_part(part, params).unwrap();
    let r = rec.recognize_seen_from(&scene, seen_from).unwrap();
    assert_eq!(r.detections.len(), 1, "{:#?}", r.detections);
    let best = &r.detections[0];
    let on = share_on_carton(&crop, &surface, &best.pose);
    assert!(on >= 0.8, "{on:.2} of the model on the carton");
    let view = best.view.expect("verified against the view");
    assert!(view.visibility > 0.5, "{view:?}");
}

#[test]
fn milk_carton_is_found_in_the_kinect_scene() {
    let params = Params::from_toml(&std::fs::read_to_string(data("kinect.toml")).unwrap()).unwrap();
    assert_eq!(params.units, Units::Metres);
    let (model, _) = load_cloud(&data("milk_model.pcd"), params.units).unwrap();
    let (scene, report) =
        load_cloud(&data("milk_cartoon_all_small_clorox.pcd"), params.units).unwrap();
    assert_eq!(report.points_in_file, 640 * 480);
    // The carton's own points, cut from the same scene by PCL's authors.
    let (crop, _) = load_cloud(&data("milk_scene_crop.pcd"), params.units).unwrap();

    let rec = Recognizer::new(&model, params).unwrap();
    let r = rec.recognize(&scene).unwrap();
    let best = r.detections.first().expect("the carton is found");
    assert!(best.final_score < 5.0, "{best:?}");

    // The placed model lies on the carton: most of its keypoints are within 8 mm of the crop.
    let crop_index = NearestIndex::new("crop", &crop.points).unwrap();
    let placed: Vec<_> = rec
        .model()
        .expect("the thesis engine")
        .final_keypoints
        .iter()
        .map(|p| binpick_cloud::transform_point(&best.pose, p))
        .collect();
    let on_carton = placed
        .iter()
        .filter(|p| crop_index.nearest(p).1 < 64.0)
        .count();
    assert!(
        on_carton * 10 >= placed.len() * 8,
        "{on_carton} of {} keypoints on the carton",
        placed.len()
    );
    // And nothing else in the scene is taken for a carton.
    assert_eq!(r.detections.len(), 1, "{:#?}", r.detections);
}
