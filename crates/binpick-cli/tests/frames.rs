//! `recognize --scanner-to-base`: with a known scanner -> base transform, every pose and
//! every grasp of the JSON comes out in the base frame (the transform applied to the
//! scanner-frame answer), named by `frame_id`; grasps declared in the model's sidecar appear
//! on each detection.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::{Matrix4, Point3, Vector3};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn recognize(model: &Path, extra: &[&str]) -> (serde_json::Value, String) {
    let scene = repo().join("data/sample/scenes/conveyor-A.pcd");
    let mut args: Vec<String> = [
        "recognize",
        "--model",
        model.to_str().unwrap(),
        "--scene",
        scene.to_str().unwrap(),
        "--engine",
        "thesis",
        "--preset",
        "A",
        "--json",
        "-",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    args.extend(extra.iter().map(|s| s.to_string()));
    let out = Command::new(env!("CARGO_BIN_EXE_binpick"))
        .args(&args)
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "binpick {args:?} failed:\n{stderr}");
    (serde_json::from_slice(&out.stdout).unwrap(), stderr)
}

fn matrix(v: &serde_json::Value) -> Matrix4<f64> {
    let m: Vec<f64> = serde_json::from_value(v.clone()).unwrap();
    Matrix4::from_row_slice(&m)
}

fn vec3(v: &serde_json::Value) -> Vector3<f64> {
    let a: [f64; 3] = serde_json::from_value(v.clone()).unwrap();
    Vector3::from(a)
}

#[test]
fn poses_and_grasps_come_out_in_the_base_frame() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("A.pcd");
    std::fs::copy(repo().join("data/sample/models/A.pcd"), &model).unwrap();
    std::fs::write(
        dir.path().join("A.json"),
        r#"{ "grasps": [
              { "name": "centre", "position_mm": [0, 0, 0], "approach": [0, 0, -1],
                "clearance_radius_mm": 4, "clearance_length_mm": 60 },
              { "position_mm": [10, 0, 0], "approach": [0, 0, -2],
                "clearance_radius_mm": 4, "clearance_length_mm": 60 } ] }"#,
    )
    .unwrap();
    // The scanner hangs 1.2 m above the base, looking down, turned 90 degrees about z.
    let t = Matrix4::new(
        0.0, -1.0, 0.0, 400.0, //
        -1.0, 0.0, 0.0, -50.0, //
        0.0, 0.0, -1.0, 1200.0, //
        0.0, 0.0, 0.0, 1.0,
    );
    let calibration = dir.path().join("cell.toml");
    std::fs::write(
        &calibration,
        "frame_id = \"base_link\"\nscanner_to_base = [[0, -1, 0, 400], [-1, 0, 0, -50], [0, 0, -1, 1200], [0, 0, 0, 1]]\n",
    )
    .unwrap();

    let (scanner, _) = recognize(&model, &[]);
    let (base, stderr) = recognize(
        &model,
        &["--scanner-to-base", calibration.to_str().unwrap()],
    );
    assert_eq!(scanner["frame_id"], "scanner");
    assert_eq!(base["frame_id"], "base_link");
    assert!(stderr.contains("poses in frame base_link"), "{stderr}");
    assert!((matrix(&base["scanner_to_frame"]) - t).norm() < 1e-12);

    let a = scanner["detections"].as_array().unwrap();
    let b = base["detections"].as_array().unwrap();
    assert!(!a.is_empty());
    assert_eq!(a.len(), b.len());
    for (da, db) in a.iter().zip(b) {
        let want = t * matrix(&da["pose"]);
        assert!((matrix(&db["pose"]) - want).norm() < 1e-6, "{db}");
        let ga = da["grasps"].as_array().unwrap();
        let gb = db["grasps"].as_array().unwrap();
        assert_eq!(ga.len(), 2);
        assert_eq!(gb[1]["name"], "grasp 2");
        // The grasp is where the detection's pose puts the declared position ...
        let pose = matrix(&db["pose"]);
        let declared = [
            (Point3::origin(), Vector3::z()),
            (Point3::new(10.0, 0.0, 0.0), Vector3::z()),
        ];
        for ((ga, gb), (p, down)) in ga.iter().zip(gb).zip(declared) {
            let at = pose.transform_point(&p);
            assert!((vec3(&gb["position_mm"]) - at.coords).norm() < 1e-6, "{gb}");
            let approach = -(pose.fixed_view::<3, 3>(0, 0) * down);
            assert!((vec3(&gb["approach"]) - approach).norm() < 1e-9, "{gb}");
            // ... the scanner-frame grasp moved by the calibration, and as free as before.
            let from_scanner = t.transform_point(&Point3::from(vec3(&ga["position_mm"])));
            assert!((vec3(&gb["position_mm"]) - from_scanner.coords).norm() < 1e-6);
            assert_eq!(ga["free"], gb["free"]);
        }
    }

    // The same transform typed on the command line.
    let inline = "0 -1 0 400, -1 0 0 -50, 0 0 -1 1200, 0 0 0 1";
    let (typed, _) = recognize(
        &model,
        &["--scanner-to-base", inline, "--frame-id", "robot"],
    );
    assert_eq!(typed["frame_id"], "robot");
    assert_eq!(
        typed["detections"][0]["pose"],
        base["detections"][0]["pose"]
    );
    assert_eq!(
        typed["detections"][0]["grasps"],
        base["detections"][0]["grasps"]
    );
}

#[test]
fn a_bad_calibration_is_a_clear_error() {
    let model = repo().join("data/sample/models/A.pcd");
    let scene = repo().join("data/sample/scenes/conveyor-A.pcd");
    let out = Command::new(env!("CARGO_BIN_EXE_binpick"))
        .args([
            "recognize",
            "--model",
            model.to_str().unwrap(),
            "--scene",
            scene.to_str().unwrap(),
            "--scanner-to-base",
            "2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("--scanner-to-base") && stderr.contains("not a rotation"),
        "{stderr}"
    );
}
