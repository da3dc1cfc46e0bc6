//! `binpick show`: pictures of a saved `recognize` result, redrawn from its JSON; a result
//! whose scene has moved is refused with a message saying how to point at it.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn binpick(args: &[&Path]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_binpick"))
        .args(args)
        .env_remove("RUST_LOG")
        .output()
        .unwrap()
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
    let out = Command::new(env!("CARGO_BIN_EXE_binpick"))
        .args([
            "recognize",
            "--engine",
            "thesis",
            "--preset",
            "A",
            "-q",
            "--model",
        ])
        .arg(&model)
        .arg("--scene")
        .arg(&scene)
        .arg("--json")
        .arg(&json)
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let result: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let found = result["detections"].as_array().unwrap().len();
    assert!(found > 0, "the sample scene has parts to draw");

    let png = dir.path().join("again.png");
    let ply = dir.path().join("again.ply");
    let out = binpick(&[
        Path::new("show"),
        &json,
        Path::new("--png"),
        &png,
        Path::new("--ply"),
        &ply,
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
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
    let out = binpick(&[Path::new("show"), &json, Path::new("--png"), &png]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("conveyor-A.pcd") && stderr.contains("--scene"),
        "{stderr}"
    );
    let out = binpick(&[
        Path::new("show"),
        &json,
        Path::new("--png"),
        &png,
        Path::new("--scene"),
        &moved,
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // Not a result at all: refused, naming the file.
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, "{\"units\": \"mm\", \"detections\": [{\"rank\": 1}]}").unwrap();
    let out = binpick(&[Path::new("show"), &bad]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("bad.json") && stderr.contains("rank 1"),
        "{stderr}"
    );
}
