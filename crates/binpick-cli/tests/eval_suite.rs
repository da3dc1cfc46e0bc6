//! `binpick eval` over a benchmark root (a manifest.json listing sets, as `binpick synth
//! generalisation` writes): every set with its own part, one table, suite.csv and suite.json,
//! and the same figures as evaluating each set alone. The thesis engine with preset A keeps
//! the runs short.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn binpick(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_binpick"))
        .args(args)
        .env_remove("RUST_LOG")
        .output()
        .unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// A benchmark root whose two sets are the bundled tiny dataset judged on parts A and B.
fn root(dir: &Path) -> PathBuf {
    let root = dir.join("bench");
    std::fs::create_dir_all(&root).unwrap();
    let tiny = repo().join("data/tiny").canonicalize().unwrap();
    for set in ["tiny-A", "tiny-B"] {
        std::os::unix::fs::symlink(&tiny, root.join(set)).unwrap();
    }
    let manifest = serde_json::json!({
        "generator": "test",
        "sets": [
            {"dir": "tiny-A", "target_model": "A"},
            {"dir": "tiny-B", "target_model": "B"},
        ]
    });
    std::fs::write(root.join("manifest.json"), manifest.to_string()).unwrap();
    root
}

#[test]
fn a_benchmark_root_gives_one_table_with_each_sets_own_figures() {
    let dir = tempfile::tempdir().unwrap();
    let root = root(dir.path());
    let out = dir.path().join("out");
    let run = binpick(&["eval", s(&root), "--preset", "A", "--out", s(&out), "-q"]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(stdout.contains("benchmark, preset A"), "{stdout}");
    let rows = json(&out.join("suite.json"));
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 2);
    let csv = std::fs::read_to_string(out.join("suite.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "{csv}");
    for (row, (set, model)) in rows.iter().zip([("tiny-A", "A"), ("tiny-B", "B")]) {
        assert_eq!(row["set"], set);
        assert_eq!(row["model"], model);
        assert!(stdout.lines().any(|l| l.starts_with(set)), "{stdout}");
        // The same figures as the set evaluated alone.
        let alone = dir.path().join(format!("alone-{model}"));
        let single = binpick(&[
            "eval",
            s(&repo().join("data/tiny")),
            "--model",
            model,
            "--preset",
            "A",
            "--out",
            s(&alone),
            "-q",
        ]);
        assert!(single.status.success());
        let summary = json(&alone.join("summary.json"));
        assert_eq!(row["scans"], summary["table"]["files"]);
        assert_eq!(row["pickable"], summary["table"]["pickable"]);
        assert_eq!(row["recall_pct"], summary["percents"]["recognition"]);
        assert_eq!(row["false_best_pct"], summary["percents"]["false_best"]);
        // Wrong first picks: the scans whose top detection is not a right pickable part,
        // which includes every false best.
        let scenes = summary["scenes"].as_array().unwrap();
        let wrong = scenes
            .iter()
            .filter(|sc| sc["score"]["wrong_first_pick"] == true)
            .count();
        let wrong_pct = row["wrong_first_pick_pct"].as_f64().unwrap();
        assert!((wrong_pct - 100.0 * wrong as f64 / scenes.len() as f64).abs() < 1e-9);
        assert!(wrong_pct >= row["false_best_pct"].as_f64().unwrap());
        // Scans with detections but none free to pick: no pick, each counted as such.
        let none_free = scenes
            .iter()
            .filter(|sc| sc["score"]["none_free_to_pick"] == true)
            .count();
        let none_free_pct = row["none_free_to_pick_pct"].as_f64().unwrap();
        assert!((none_free_pct - 100.0 * none_free as f64 / scenes.len() as f64).abs() < 1e-9);
        assert!(out.join(set).join("summary.json").is_file());
    }
    // Each set names its part: --model makes no sense here and is refused, by name.
    let refused = binpick(&["eval", s(&root), "--model", "A", "--out", s(&out)]);
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        err.contains("--model") && err.contains("benchmark root"),
        "{err}"
    );
}

#[test]
fn one_dataset_prints_the_thesis_table_with_its_own_figures() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let tiny = repo().join("data/tiny");
    let run = binpick(&[
        "eval",
        s(&tiny),
        "--model",
        "A",
        "--preset",
        "A",
        "--out",
        s(&out),
        "-q",
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{stdout}");
    let summary = json(&out.join("summary.json"));
    let row = |symbol: &str| {
        stdout
            .lines()
            .find(|l| l.split_whitespace().any(|w| w == symbol))
            .unwrap_or_else(|| panic!("no {symbol} row: {stdout}"))
            .trim_end()
            .to_string()
    };
    let counts = [
        ("F", "files"),
        ("P", "pickable"),
        ("R", "recognised"),
        ("FN", "false_negatives"),
        ("FP", "files_with_false_positive"),
        ("NP", "files_with_unpickable"),
        ("FB", "false_best"),
        ("S", "starvation"),
    ];
    for (symbol, key) in counts {
        let n = summary["table"][key].as_u64().unwrap();
        assert!(
            row(symbol).ends_with(&format!(" {n}")),
            "{symbol}: {stdout}"
        );
    }
    // Ours to one decimal, then the thesis's own figure for configuration A (table 5.5.2).
    let percents = [
        ("R/P", "recognition", 86),
        ("FN/P", "false_negatives", 14),
        ("FP/F", "files_with_false_positive", 2),
        ("NP/F", "files_with_unpickable", 22),
        ("FB/F", "false_best", 0),
        ("S/F", "starvation", 2),
    ];
    for (symbol, key, thesis) in percents {
        let ours = summary["percents"][key].as_f64().unwrap();
        let line = row(symbol);
        assert!(
            line.contains(&format!("{ours:.1} %")) && line.ends_with(&format!(" {thesis} %")),
            "{symbol}: {line}"
        );
    }
}
