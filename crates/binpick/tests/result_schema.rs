//! The result document written for every scene validates against the JSON Schema kept in the
//! repository (`schema/result.schema.json`), and its ROS-style pose is the 4x4 pose.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use binpick::{
    Engine, Grasp, OutputFrame, Params, RecognitionReport, Recognizer, load_cloud, load_part,
};
use nalgebra::{Isometry3, Matrix4, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn schema() -> jsonschema::Validator {
    let text = std::fs::read_to_string(repo().join("schema/result.schema.json")).unwrap();
    let schema: serde_json::Value = serde_json::from_str(&text).unwrap();
    jsonschema::validator_for(&schema).unwrap()
}

/// A real result: part A recognised in the bundled sample scan by `engine` (computed once per
/// engine for all tests of this file).
fn sample_report(engine: Engine) -> serde_json::Value {
    static VOTING: OnceLock<serde_json::Value> = OnceLock::new();
    static THESIS: OnceLock<serde_json::Value> = OnceLock::new();
    let cell = match engine {
        Engine::SceneVoting => &VOTING,
        _ => &THESIS,
    };
    cell.get_or_init(|| recognise_sample(engine)).clone()
}

fn recognise_sample(engine: Engine) -> serde_json::Value {
    let sample = repo().join("data/sample");
    let params = Params {
        engine,
        ..Params::default()
    };
    let model = sample.join("models/A.pcd");
    let (part, _) = load_part(&model, params.units, &params).unwrap();
    // Two grasps, so the documents carry grasp records too.
    let part = part
        .with_grasps(vec![
            Grasp::new([0.0; 3], [0.0, 0.0, -1.0], 4.0, 80.0).named("centre"),
            Grasp::new([10.0, 0.0, 0.0], [1.0, 0.0, 0.0], 4.0, 80.0),
        ])
        .unwrap();
    let recognizer = Recognizer::with_part(part, params.clone()).unwrap();
    let scene_path = sample.join("scenes/conveyor-A.pcd");
    let (scene, loaded) = load_cloud(&scene_path, params.units).unwrap();
    let r = recognizer
        .recognize_seen_from(&scene, binpick::sensor_position(&loaded, params.units))
        .unwrap();
    assert!(
        !r.detections.is_empty(),
        "{engine:?} found nothing in the sample"
    );
    let report = RecognitionReport::new(
        "conveyor-A.pcd",
        "A.pcd",
        params.stages().engine.name(),
        &params,
        &r,
    );
    serde_json::to_value(&report).unwrap()
}

fn assert_valid(v: &serde_json::Value) {
    let validator = schema();
    let errors: Vec<String> = validator
        .iter_errors(v)
        .map(|e| format!("{}: {e}", e.instance_path()))
        .collect();
    assert!(errors.is_empty(), "schema violations: {errors:#?}");
}

/// The 4x4 of `pose` and the transform of `pose_ros` (metres -> mm) agree.
fn assert_ros_pose_is_the_matrix(d: &serde_json::Value) {
    let m: Vec<f64> = serde_json::from_value(d["pose"].clone()).unwrap();
    let m = Matrix4::from_row_slice(&m);
    let ros = &d["pose_ros"];
    let f = |v: &serde_json::Value| v.as_f64().unwrap();
    let o = &ros["orientation"];
    let q = UnitQuaternion::from_quaternion(Quaternion::new(
        f(&o["w"]),
        f(&o["x"]),
        f(&o["y"]),
        f(&o["z"]),
    ));
    let rot = q.to_rotation_matrix();
    for r in 0..3 {
        for c in 0..3 {
            assert!(
                (rot[(r, c)] - m[(r, c)]).abs() < 1e-9,
                "rotation ({r},{c}): {} vs {}",
                rot[(r, c)],
                m[(r, c)]
            );
        }
    }
    let p = &ros["position"];
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        assert!(
            (1000.0 * f(&p[axis]) - m[(k, 3)]).abs() < 1e-9,
            "position {axis}: {} m vs {} mm",
            f(&p[axis]),
            m[(k, 3)]
        );
    }
}

#[test]
fn real_results_of_both_engines_validate_and_their_ros_poses_are_the_4x4() {
    for engine in [Engine::SceneVoting, Engine::Thesis] {
        let v = sample_report(engine);
        assert_eq!(v["schema_version"], binpick::RESULT_SCHEMA_VERSION);
        assert_eq!(v["frame_id"], "scanner");
        assert_valid(&v);
        for d in v["detections"].as_array().unwrap() {
            assert_ros_pose_is_the_matrix(d);
            assert!(d["free_to_pick"].is_boolean(), "{d}");
        }
        // The document reads back, and what it reads back as writes a valid document with
        // the same detections.
        let back: RecognitionReport = serde_json::from_value(v.clone()).unwrap();
        let again = serde_json::to_value(&back).unwrap();
        assert_valid(&again);
        assert_eq!(
            back.detections.len(),
            v["detections"].as_array().unwrap().len()
        );
        assert_eq!(
            again["detections"][0]["rank_reason"],
            v["detections"][0]["rank_reason"]
        );
    }
}

#[test]
fn schema_rejects_what_it_should() {
    let good = sample_report(Engine::SceneVoting);
    let validator = schema();
    assert!(validator.is_valid(&good));
    let mut no_version = good.clone();
    no_version.as_object_mut().unwrap().remove("schema_version");
    assert!(!validator.is_valid(&no_version));
    let mut short_pose = good.clone();
    short_pose["detections"][0]["pose"] = serde_json::json!([1.0, 0.0, 0.0]);
    assert!(!validator.is_valid(&short_pose));
    let mut wxyz = good.clone();
    wxyz["detections"][0]["pose_ros"]["orientation"]
        .as_object_mut()
        .unwrap()
        .remove("w");
    assert!(!validator.is_valid(&wxyz));
    let mut flag = good.clone();
    flag["detections"][0]["free_to_pick"] = serde_json::json!("yes");
    assert!(!validator.is_valid(&flag));
}

#[test]
fn unversioned_results_still_load() {
    let mut old = sample_report(Engine::SceneVoting);
    let obj = old.as_object_mut().unwrap();
    obj.remove("schema_version");
    obj.remove("frame_id");
    for d in old["detections"].as_array_mut().unwrap() {
        d.as_object_mut().unwrap().remove("pose_ros");
    }
    let back: RecognitionReport = serde_json::from_value(old).unwrap();
    assert_eq!(back.schema_version, 1);
    assert_eq!(back.frame_id, binpick::SCANNER_FRAME_ID);
}

/// The scanner 1.2 m above the robot's base, looking down, turned about z.
fn scanner_to_base() -> OutputFrame {
    let t = Isometry3::from_parts(
        Translation3::new(400.0, -50.0, 1200.0),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.7),
    );
    OutputFrame::new("base_link", t).unwrap()
}

fn vec3(v: &serde_json::Value) -> Vector3<f64> {
    let a: [f64; 3] = serde_json::from_value(v.clone()).unwrap();
    Vector3::from(a)
}

#[test]
fn results_in_the_base_frame_validate_and_go_back_to_the_scanner_frame() {
    for engine in [Engine::SceneVoting, Engine::Thesis] {
        let v = sample_report(engine);
        let scanner: RecognitionReport = serde_json::from_value(v.clone()).unwrap();
        assert!(scanner.detections.iter().all(|d| d.grasps.len() == 2));
        let frame = scanner_to_base();
        let t = frame.scanner_to_frame;
        let mut base = scanner.clone();
        base.express_in(&frame);
        let doc = serde_json::to_value(&base).unwrap();
        assert_valid(&doc);
        assert_eq!(doc["frame_id"], "base_link");
        for (a, b) in scanner.detections.iter().zip(&base.detections) {
            let want = (t * a.pose).to_homogeneous();
            assert!((b.pose.to_homogeneous() - want).norm() < 1e-9);
            for (ga, gb) in a.grasps.iter().zip(&b.grasps) {
                let p = t * Point3::from(ga.position_mm);
                assert!((Vector3::from(gb.position_mm) - p.coords).norm() < 1e-9);
                let dir = t.rotation * Vector3::from(ga.approach);
                assert!((Vector3::from(gb.approach) - dir).norm() < 1e-12);
                assert_eq!((ga.free, &ga.blocked_by), (gb.free, &gb.blocked_by));
            }
        }
        for d in doc["detections"].as_array().unwrap() {
            assert_ros_pose_is_the_matrix(d);
            // Each grasp is the declared one placed by the detection's (base-frame) pose.
            let m: Vec<f64> = serde_json::from_value(d["pose"].clone()).unwrap();
            let m = Matrix4::from_row_slice(&m);
            let centre = m.transform_point(&Point3::origin());
            assert!((vec3(&d["grasps"][0]["position_mm"]) - centre.coords).norm() < 1e-9);
            assert_eq!(d["grasps"][1]["name"], "grasp 2");
        }
        // Read back and moved to the scanner's frame again: the original poses.
        let mut back: RecognitionReport = serde_json::from_value(doc).unwrap();
        assert!(back.scanner_to_frame.is_some());
        back.express_in(&OutputFrame::scanner());
        assert_eq!(back.frame_id, "scanner");
        assert!(back.scanner_to_frame.is_none());
        for (a, b) in scanner.detections.iter().zip(&back.detections) {
            assert!((a.pose.to_homogeneous() - b.pose.to_homogeneous()).norm() < 1e-9);
            for (ga, gb) in a.grasps.iter().zip(&b.grasps) {
                let d = Vector3::from(ga.position_mm) - Vector3::from(gb.position_mm);
                assert!(d.norm() < 1e-9);
            }
        }
    }
}

#[test]
fn schema_checks_grasp_records() {
    let good = sample_report(Engine::Thesis);
    let validator = schema();
    assert!(validator.is_valid(&good));
    let mut no_free = good.clone();
    no_free["detections"][0]["grasps"][0]
        .as_object_mut()
        .unwrap()
        .remove("free");
    assert!(!validator.is_valid(&no_free));
    let mut bad_blocker = good.clone();
    bad_blocker["detections"][0]["grasps"][0]["blocked_by"] =
        serde_json::json!([{ "detection": { "rank": 0, "points": 5 } }]);
    assert!(!validator.is_valid(&bad_blocker));
    let mut blocked = good.clone();
    blocked["detections"][0]["grasps"][0]["free"] = serde_json::json!(false);
    blocked["detections"][0]["grasps"][0]["blocked_by"] = serde_json::json!([{ "scene_points": { "points": 12 } }, { "detection": { "rank": 2, "points": 40 } }]);
    assert!(validator.is_valid(&blocked));
}
