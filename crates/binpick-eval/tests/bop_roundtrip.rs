//! `eval` on a small BOP-format folder (16-bit depth PNGs + intrinsics + scene_gt.json, PLY
//! meshes) gives the same recall as on the same scans given as clouds in binpick's layout.
//!
//! The scans are two synthetic depth-camera scans of Z brackets in a bin (the generalisation
//! benchmark's `brackets-bin-depth` at half resolution). The BOP side is written by
//! `binpick_synth::bop` and read back through PNG, `scene_camera.json`, `scene_gt.json`,
//! `scene_gt_info.json` and `models_info.json`; the cloud side gets the same depth samples
//! straight from the scan (no PNG) as PCDs in the camera frame, and its ground truth is moved
//! into the camera frame here, independently of the BOP files.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use binpick::Params;
use binpick_cloud::dataset::{Dataset, GroundTruth, GtInstance, write_json};
use binpick_cloud::depth::{DepthImage, Intrinsics};
use binpick_cloud::{Units, pose_from_row_major, pose_to_row_major};
use binpick_eval::bop::BopDataset;
use binpick_eval::{ModelFile, evaluate_bop, evaluate_dataset};
use binpick_synth::{ModelLibrary, PartKind, Sensor, generalisation_sets, make_set_scene};

#[test]
fn bop_folder_and_clouds_give_the_same_recall() {
    let dir = tempfile::tempdir().unwrap();
    let bop_root = dir.path().join("bop");
    let clouds = dir.path().join("clouds");
    for sub in ["models", "scenes", "gt"] {
        std::fs::create_dir_all(clouds.join(sub)).unwrap();
    }

    let lib = ModelLibrary::build_for(&[PartKind::Bracket], false).unwrap();
    let mut set = generalisation_sets(Some(2))
        .into_iter()
        .find(|s| s.name == "brackets-bin-depth")
        .unwrap();
    let Sensor::DepthCamera(cam) = &mut set.sensor else {
        panic!("brackets-bin-depth is a depth-camera set")
    };
    // Half resolution: a quarter of the points, same field of view.
    cam.width = 320;
    cam.height = 240;
    cam.focal_px = 580.0;
    let cam = cam.clone();
    let models = set.models(&lib);
    assert_eq!(models.len(), 1);
    let model = models[0];
    binpick_synth::bop::write_models(&bop_root, &models).unwrap();
    binpick_synth::generate::write_stl(
        &clouds.join("models").join(format!("{}.stl", model.name)),
        &model.mesh,
    )
    .unwrap();
    write_json(
        &clouds.join("models").join(format!("{}.json", model.name)),
        &model.info(),
    )
    .unwrap();

    let scene_to_cam = binpick_synth::bop::camera_pose(&cam).inverse();
    let k = Intrinsics {
        fx: cam.focal_px,
        fy: cam.focal_px,
        cx: 0.5 * cam.width as f64 - 0.5,
        cy: 0.5 * cam.height as f64 - 0.5,
    };
    let mut images = Vec::new();
    for index in 0..2 {
        let scene = make_set_scene(&lib, &models, &set, 11, index).unwrap();
        let rec = binpick_synth::bop::write_image(&bop_root, &cam, &scene, index as u32, &models)
            .unwrap();
        // The same scan as a cloud in the camera frame, at the same depth resolution.
        let in_cam: Vec<[f32; 3]> = scene
            .scan
            .cloud
            .points
            .iter()
            .map(|p| binpick_cloud::transform_point(&scene_to_cam, p))
            .collect();
        let (img, dropped) =
            DepthImage::from_points(&in_cam, &k, cam.width, cam.height, rec.camera.depth_scale)
                .unwrap();
        assert_eq!(dropped, 0);
        let cloud = img.to_cloud(&k, rec.camera.depth_scale).unwrap().cloud;
        assert!(cloud.len() > 10_000, "{} points", cloud.len());
        let scene_file = format!("scenes/{}.pcd", scene.id);
        binpick_cloud::io::write_pcd(&clouds.join(&scene_file), &cloud).unwrap();
        let gt = scene.gt.iter().find(|g| g.model == model.name).unwrap();
        let moved = GroundTruth {
            scene: scene_file,
            model: model.name.clone(),
            units: Units::Millimetres,
            instances: gt
                .instances
                .iter()
                .map(|i| GtInstance {
                    pose: pose_to_row_major(
                        &(scene_to_cam * pose_from_row_major(&i.pose).unwrap()),
                    ),
                    ..i.clone()
                })
                .collect(),
        };
        write_json(
            &clouds.join("gt").join(format!("{}.json", scene.id)),
            &moved,
        )
        .unwrap();
        images.push(rec);
    }
    binpick_synth::bop::write_scene_files(&bop_root, &images).unwrap();
    // Both sides score on the same points: the mesh as binpick samples it.
    let params = Params::default();
    let (part, _) = binpick::load_part(
        &bop_root.join("models/obj_000001.ply"),
        Units::Millimetres,
        &params,
    )
    .unwrap();
    binpick_cloud::io::write_pcd(
        &clouds.join("models").join(format!("{}.pcd", model.name)),
        &part.cloud,
    )
    .unwrap();

    let bop = BopDataset::open(&bop_root, "test").unwrap();
    assert_eq!(bop.images.len(), 2);
    assert_eq!(bop.labelled_objects(), vec![1]);
    let from_bop = evaluate_bop(&bop, 1, &params, |_, _, _| {}).unwrap();
    let ds = Dataset::open(&clouds).unwrap();
    let from_clouds =
        evaluate_dataset(&ds, &model.name, ModelFile::Mesh, &params, |_, _, _| {}).unwrap();

    assert_eq!(from_bop.failed, 0, "{:?}", from_bop.scenes);
    assert_eq!(from_clouds.failed, 0, "{:?}", from_clouds.scenes);
    let (b, c) = (&from_bop.table, &from_clouds.table);
    eprintln!("BOP folder: {b:?}\nclouds:     {c:?}");
    assert!(
        c.pickable > 0 && c.recognised > 0,
        "the test needs something to find"
    );
    assert_eq!(
        (b.files, b.pickable, b.recognised),
        (c.files, c.pickable, c.recognised)
    );
    assert_eq!(
        (b.bop_targets, b.bop_recognised),
        (c.bop_targets, c.bop_recognised)
    );
    assert_eq!(b.percents().recognition, c.percents().recognition);
    assert_eq!(
        b.percents().bop_visible_recall,
        c.percents().bop_visible_recall
    );
    // Same scans, same model, same frame: the very same detections.
    assert_eq!(b, c);
}
