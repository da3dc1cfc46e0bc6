//! Prepared models on disk (`binpick::prepared`): the same answers as preparing in place, and
//! a clear refusal of a stale or foreign file.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};

use binpick::prepared::{is_prepared, read_header};
use binpick::{Params, Recognizer, Units, load_cloud, load_part};

fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../data/tiny")
        .join(rel)
}

/// The bundled model A and its sidecar, copied where the test may change them.
fn model_copy(dir: &Path) -> PathBuf {
    for ext in ["pcd", "json"] {
        std::fs::copy(
            data(&format!("models/A.{ext}")),
            dir.join(format!("A.{ext}")),
        )
        .unwrap();
    }
    dir.join("A.pcd")
}

#[test]
fn a_prepared_model_gives_the_same_answer_without_preparing() {
    let dir = tempfile::tempdir().unwrap();
    let source = model_copy(dir.path());
    let params = Params::default();
    let (scene, _) = load_cloud(&data("scenes/tiny-conv-A-000.pcd"), Units::Millimetres).unwrap();

    let (part, _) = load_part(&source, Units::Millimetres, &params).unwrap();
    let fresh = Recognizer::with_part(part, params.clone()).unwrap();
    let scale = fresh.prepare_for(&scene).unwrap();
    let file = dir.path().join("A.prepared");
    let header = fresh
        .write_prepared(&file, &source, Units::Millimetres)
        .unwrap();
    assert!(is_prepared(&file));
    assert_eq!(read_header(&file).unwrap(), header);
    assert_eq!(header.scales.len(), 1);
    assert_eq!(header.scales[0].resolution_mm, scale.resolution_mm);
    let expected = fresh.recognize(&scene).unwrap();

    let (part, _) = load_part(&file, Units::Millimetres, &params).unwrap();
    let ready = Recognizer::with_part(part, params.clone()).unwrap();
    let before = ready.preparation();
    let got = ready.recognize(&scene).unwrap();
    // Nothing left to prepare at the first scan: the voting model came from the file.
    assert_eq!(ready.preparation(), before);
    assert!(!expected.detections.is_empty());
    assert_eq!(got.detections, expected.detections);
    assert_eq!(got.voting, expected.voting);
    assert_eq!(got.scale, expected.scale);

    // Parameters the table does not depend on may change; those it does are refused.
    let mut other = params.clone();
    other.voting.hypotheses += 1;
    let (part, _) = load_part(&file, Units::Millimetres, &other).unwrap();
    Recognizer::with_part(part, other).unwrap();
    let mut other = params.clone();
    other.voting.alpha_bins += 2;
    let e = load_part(&file, Units::Millimetres, &other).unwrap_err();
    assert!(e.to_string().contains("voting table parameters"), "{e}");
}

#[test]
fn a_stale_or_foreign_prepared_model_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let source = model_copy(dir.path());
    let params = Params::default();
    let file = dir.path().join("A.prepared");
    let (part, _) = load_part(&source, Units::Millimetres, &params).unwrap();
    Recognizer::with_part(part, params.clone())
        .unwrap()
        .write_prepared(&file, &source, Units::Millimetres)
        .unwrap();
    load_part(&file, Units::Millimetres, &params).unwrap();

    // Other units than it was prepared in.
    let e = load_part(&file, Units::Metres, &params).unwrap_err();
    assert!(e.to_string().contains("prepare it again"), "{e}");

    // A damaged payload.
    let mut bytes = std::fs::read(&file).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x5a;
    let damaged = dir.path().join("damaged.prepared");
    std::fs::write(&damaged, &bytes).unwrap();
    let e = load_part(&damaged, Units::Millimetres, &params).unwrap_err();
    assert!(e.to_string().contains("damaged"), "{e}");

    // Not a prepared model at all.
    let junk = dir.path().join("junk.prepared");
    std::fs::write(&junk, b"ply\nformat ascii 1.0\n").unwrap();
    let e = load_part(&junk, Units::Millimetres, &params).unwrap_err();
    assert!(e.to_string().contains("not a prepared model"), "{e}");

    // The model's sidecar changed after preparing: the symmetries may differ.
    let sidecar = dir.path().join("A.json");
    let mut text = std::fs::read_to_string(&sidecar).unwrap();
    text.push('\n');
    std::fs::write(&sidecar, text).unwrap();
    let e = load_part(&file, Units::Millimetres, &params).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("has changed since") && msg.contains("A.prepared"),
        "{msg}"
    );
}
