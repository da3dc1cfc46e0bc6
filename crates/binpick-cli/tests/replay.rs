//! `binpick replay` on the bundled data: the per-scan CSV and table, output names that never
//! collide, `--shard` and `--compare`; `recognize --json -`. The thesis engine with preset A
//! keeps these runs short (a second per scan).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn binpick(args: &[&str]) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_binpick"))
        .args(args)
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "binpick {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Rows of a CSV as maps column -> value (no quoted commas in these files).
fn csv(path: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            assert_eq!(cells.len(), header.len(), "{l}");
            header
                .iter()
                .zip(cells)
                .map(|(h, c)| (h.to_string(), c.to_string()))
                .collect()
        })
        .collect()
}

const FAST: [&str; 4] = ["--engine", "thesis", "--preset", "A"];

fn model() -> String {
    repo().join("data/tiny/models/A.pcd").display().to_string()
}

fn scene(name: &str) -> String {
    repo()
        .join("data/tiny/scenes")
        .join(name)
        .display()
        .to_string()
}

#[test]
fn csv_table_pictures_and_names_that_never_collide() {
    let dir = tempfile::tempdir().unwrap();
    // Two scans with the same file name in different folders.
    for day in ["day1", "day2"] {
        std::fs::create_dir_all(dir.path().join(day)).unwrap();
        std::fs::copy(
            scene("tiny-conv-A-000.pcd"),
            dir.path().join(day).join("scan.pcd"),
        )
        .unwrap();
    }
    let out = dir.path().join("out");
    let png = dir.path().join("png");
    let a = dir.path().join("day1/scan.pcd");
    let b = dir.path().join("day2/scan.pcd");
    let mut args = vec!["replay", s(&a), s(&b), "--model"];
    let m = model();
    args.push(&m);
    args.extend(FAST);
    args.extend(["--out", s(&out), "--png", s(&png)]);
    let run = binpick(&args);
    let rows = csv(&out.join("replay.csv"));
    assert_eq!(rows.len(), 2);
    assert_ne!(rows[0]["name"], rows[1]["name"]);
    for r in &rows {
        assert!(r["name"].starts_with("scan-"), "{}", r["name"]);
        assert_eq!(r["config"], "base");
        assert_eq!(r["detections"], "1", "the tiny belt scan shows one part A");
        assert!(r["total_ms"].parse::<f64>().unwrap() > 0.0);
        assert!(r["preprocess_ms"].parse::<f64>().unwrap() > 0.0);
        assert!(!r["pick_x_mm"].is_empty() && r["error"].is_empty());
        assert!(
            out.join("scans")
                .join(format!("{}.json", r["name"]))
                .is_file()
        );
        assert!(png.join(format!("{}.png", r["name"])).is_file());
    }
    // Same scan, same answer.
    assert_eq!(rows[0]["pick_x_mm"], rows[1]["pick_x_mm"]);
    let table = String::from_utf8(run.stdout).unwrap();
    assert!(table.lines().next().unwrap().starts_with("scan"));
    for r in &rows {
        assert!(table.contains(&r["name"]), "{table}");
    }
    assert!(table.contains("2 scan(s): 2 detection(s)"), "{table}");
    // Each part found is free to pick: no scan without a pick.
    assert!(table.contains("0 with none free to pick"), "{table}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["scans_none_free_to_pick"], 0);
}

#[test]
fn shards_cover_the_archive_once_and_match_the_whole_run() {
    let dir = tempfile::tempdir().unwrap();
    let scans = [
        scene("tiny-conv-A-000.pcd"),
        scene("tiny-arm-ABC-box-000.pcd"),
        scene("tiny-arm-C-over-B-000.pcd"),
    ];
    let m = model();
    let run = |extra: &[&str], out: &Path| {
        let mut args: Vec<&str> = vec!["replay", "--model", &m, "--out", s(out), "-q"];
        args.extend(scans.iter().map(String::as_str));
        args.extend(FAST);
        args.extend(extra);
        binpick(&args);
    };
    let whole = dir.path().join("whole");
    run(&[], &whole);
    let shared = dir.path().join("shards");
    run(&["--shard", "1/2"], &shared);
    run(&["--shard", "2/2"], &shared);
    let all = csv(&whole.join("replay.csv"));
    let one = csv(&shared.join("replay-1of2.csv"));
    let two = csv(&shared.join("replay-2of2.csv"));
    assert_eq!(all.len(), 3);
    assert_eq!(
        (one.len(), two.len()),
        (2, 1),
        "round robin over the sorted list"
    );
    let mut names: Vec<&String> = one.iter().chain(&two).map(|r| &r["name"]).collect();
    names.sort();
    let mut expected: Vec<&String> = all.iter().map(|r| &r["name"]).collect();
    expected.sort();
    assert_eq!(names, expected, "every scan in exactly one shard");
    for r in one.iter().chain(&two) {
        let w = all.iter().find(|w| w["name"] == r["name"]).unwrap();
        assert_eq!(
            (&w["detections"], &w["pick_x_mm"]),
            (&r["detections"], &r["pick_x_mm"])
        );
    }
    assert!(
        shared.join("summary-1of2.json").is_file() && shared.join("summary-2of2.json").is_file()
    );
}

#[test]
fn compare_prints_per_scan_and_total_differences() {
    let dir = tempfile::tempdir().unwrap();
    let other = dir.path().join("strict.toml");
    // No initial alignment is that good: the compared configuration finds nothing.
    std::fs::write(&other, "initial_score_max = 0.5\n").unwrap();
    let out = dir.path().join("out");
    let m = model();
    let sample = repo().join("data/sample/scenes/conveyor-A.pcd");
    let conv = scene("tiny-conv-A-000.pcd");
    let mut args = vec!["replay", "--model", &m, "--out", s(&out), s(&sample), &conv];
    args.extend(FAST);
    args.extend(["--compare", s(&other)]);
    let run = binpick(&args);
    let stdout = String::from_utf8(run.stdout).unwrap();
    assert!(
        stdout.contains("total over 2 scan(s): detections 2 -> 0 (-2)"),
        "{stdout}"
    );
    let diffs = csv(&out.join("compare.csv"));
    assert_eq!(diffs.len(), 2);
    for d in &diffs {
        assert_eq!(
            (
                &*d["detections"],
                &*d["detections_compare"],
                &*d["detections_diff"]
            ),
            ("1", "0", "-1")
        );
        assert_eq!(d["first_pick_changed"], "1");
        assert!(stdout.contains(&d["name"]));
    }
    let rows = csv(&out.join("replay.csv"));
    assert_eq!(rows.iter().filter(|r| r["config"] == "compare").count(), 2);
    assert!(out.join("compare").read_dir().unwrap().count() == 2);
}

#[test]
fn recognize_json_to_stdout_puts_the_table_on_stderr() {
    let m = repo().join("data/sample/models/A.pcd");
    let sc = repo().join("data/sample/scenes/conveyor-A.pcd");
    let mut args = vec![
        "recognize",
        "--model",
        s(&m),
        "--scene",
        s(&sc),
        "--json",
        "-",
    ];
    args.extend(FAST);
    let run = binpick(&args);
    let v: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(v["schema_version"], 3);
    assert_eq!(v["detections"].as_array().unwrap().len(), 1);
    let stderr = String::from_utf8(run.stderr).unwrap();
    assert!(
        stderr.contains("rank") && stderr.contains("final %"),
        "{stderr}"
    );
    assert!(!Path::new("-").exists() && !Path::new("-.params.toml").exists());
    // -q leaves only the table on stderr: no info lines.
    args.push("-q");
    let quiet = binpick(&args);
    let stderr = String::from_utf8(quiet.stderr).unwrap();
    assert!(!stderr.contains("binpick:"), "{stderr}");
}
