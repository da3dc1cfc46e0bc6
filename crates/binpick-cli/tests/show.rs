//! `binpick show`: pictures of a saved `recognize` result, redrawn from its JSON; a result
//! whose scene has moved is refused with a message saying how to point at it.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Runs binpick with `args`: whether it succeeded, and its stderr.
fn binpick<S: AsRef<OsStr>>(args: &[S]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_binpick"))
        .args(args)
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs binpick with `args`, which must succeed.
fn binpick_ok<S: AsRef<OsStr>>(args: &[S]) {
    let (ok, stderr) = binpick(args);
    assert!(ok, "binpick failed:\n{stderr}");
}

/// The vertex count in a PLY header.
fn ply_vertices(path: &Path) -> usize {
    let bytes = std::fs::read(path).unwrap();
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(2000)]).into_owned();
    assert!(head.starts_with("ply"), "{}: not a PLY", path.display());
    head.lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .unwrap_or_else(|| panic!("{}: no vertex element", path.display()))
        .trim()
        .parse()
        .unwrap()
}

#[test]
fn a_saved_result_is_drawn_again_and_a_moved_scene_is_named() {
    let dir = tempfile::tempdir().unwrap();
    // The scene is copied so that it can be moved away afterwards.
    let scene = dir.path().join("conveyor-A.pcd");
    std::fs::copy(repo().join("data/sample/scenes/conveyor-A.pcd"), &scene).unwrap();
    let model = repo().join("data/sample/models/A.pcd");
    let json = dir.path().join("result.json");
    let (png, ply) = (dir.path().join("again.png"), dir.path().join("again.ply"));
    let path = |p: &Path| p.as_os_str().to_owned();
    binpick_ok(&[
        "recognize".into(),
        "--engine".into(),
        "thesis".into(),
        "--preset".into(),
        "A".into(),
        "-q".into(),
        "--model".into(),
        path(&model),
        "--scene".into(),
        path(&scene),
        "--json".into(),
        path(&json),
    ]);
    let result: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let found = result["detections"].as_array().unwrap().len();
    assert!(found > 0, "the sample scene has parts to draw");

    let show = |extra: &[&Path]| -> Vec<std::ffi::OsString> {
        let mut args = vec!["show".into(), path(&json), "--png".into(), path(&png)];
        args.extend(extra.iter().map(|p| path(p)));
        args
    };
    binpick_ok(&show(&[Path::new("--ply"), &ply]));
    let image = std::fs::read(&png).unwrap();
    assert!(image.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    // The scene's points plus every placed model's.
    let scene_points = binpick::load_cloud(&scene, binpick::Units::Millimetres)
        .unwrap()
        .0
        .len();
    assert!(
        ply_vertices(&ply) > scene_points,
        "the PLY holds the scene ({scene_points} points) and {found} placed models"
    );

    // Moved: the result still names the old path; the error says so and how to fix it.
    let moved = dir.path().join("elsewhere.pcd");
    std::fs::rename(&scene, &moved).unwrap();
    let (ok, stderr) = binpick(&show(&[]));
    assert!(
        !ok && stderr.contains("conveyor-A.pcd") && stderr.contains("--scene"),
        "{stderr}"
    );
    binpick_ok(&show(&[Path::new("--scene"), &moved]));

    // Not a result at all: refused, naming the file.
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, "{\"units\": \"mm\", \"detections\": [{\"rank\": 1}]}").unwrap();
    let (ok, stderr) = binpick(&["show".into(), path(&bad)]);
    assert!(
        !ok && stderr.contains("bad.json") && stderr.contains("rank 1"),
        "{stderr}"
    );
}
