//! `binpick check`: the bundled conveyor scan's true poses judged as the scene-voting engine
//! judges its hypotheses; a pose moved off its part is refused, bad requests fail with
//! what is wrong.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn check(extra: &[&str]) -> Output {
    let model = repo().join("data/sample/models/A.pcd");
    let scene = repo().join("data/sample/scenes/conveyor-A.pcd");
    let mut args = vec![
        "-q".to_owned(),
        "check".to_owned(),
        "--model".to_owned(),
        model.display().to_string(),
        "--scene".to_owned(),
        scene.display().to_string(),
    ];
    args.extend(extra.iter().map(|s| (*s).to_owned()));
    Command::new(env!("CARGO_BIN_EXE_binpick"))
        .args(&args)
        .env_remove("RUST_LOG")
        .output()
        .unwrap()
}

fn truth() -> serde_json::Value {
    let text = std::fs::read_to_string(repo().join("data/sample/gt/conveyor-A__A.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

#[test]
fn true_poses_are_judged_and_a_pose_off_its_part_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("checks.json");
    let gt = repo().join("data/sample/gt/conveyor-A__A.json");
    let out = check(&[
        "--poses",
        gt.to_str().unwrap(),
        "--refine",
        "--json",
        json.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let records: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let truth = truth();
    let instances = truth["instances"].as_array().unwrap();
    assert_eq!(records.len(), instances.len());
    // Instance 4 lies flat and in full view: accepted; instances 0 and 1 show the scan 3 %
    // of their top view: refused.
    assert!(records[4]["refusal"].is_null(), "{}", records[4]);
    assert!(records[4]["refined"].as_bool().unwrap());
    assert!(records[4]["view"]["visibility"].as_f64().unwrap() > 0.7);
    for k in [0, 1] {
        assert!(records[k]["refusal"].is_string(), "{}", records[k]);
    }
    assert_eq!(
        records[4]["source"].as_str().unwrap(),
        "conveyor-A__A.json: instance 4"
    );
    assert!(stdout.contains("accepted"), "{stdout}");

    // Moved 25 mm along x onto the belt and its neighbour: refused, and the table says why.
    let mut moved: Vec<f64> = serde_json::from_value(instances[4]["pose"].clone()).unwrap();
    moved[3] += 25.0;
    let text: Vec<String> = moved.iter().map(f64::to_string).collect();
    let out = check(&["--pose", &text.join(" ")]);
    assert!(out.status.success());
    let row = String::from_utf8_lossy(&out.stdout);
    let row = row.lines().nth(1).unwrap();
    assert!(row.starts_with("--pose 1"), "{row}");
    assert!(!row.ends_with("accepted"), "{row}");
}

#[test]
fn a_check_without_a_pose_or_with_the_thesis_engine_fails_with_what_to_do() {
    let out = check(&[]);
    assert!(!out.status.success());
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("no pose to check"), "{e}");

    let identity = "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1";
    let out = check(&["--preset", "A", "--pose", identity]);
    assert!(!out.status.success());
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("scene-voting engine"), "{e}");

    let out = check(&["--pose", "1 0 0"]);
    assert!(!out.status.success());
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("--pose \"1 0 0\"") && e.contains("got 3"), "{e}");
}
