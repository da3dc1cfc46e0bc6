//! Property test over every reader: mutated valid files (bit flips, byte overwrites,
//! truncations, deleted, inserted and duplicated runs, header numbers replaced by 0, huge or
//! random values, 4-byte words set to extremes) never panic, every `Err` names the file on
//! one line, and every `Ok` is usable (points finite and counted; mesh indices in range,
//! coordinates finite, no zero-area triangle). 10 000 cases per reader, fixed seed; the
//! stable-Rust companion of the cargo-fuzz targets in `fuzz/`.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::panic::{AssertUnwindSafe, catch_unwind};

use binpick_cloud::PointCloud;
use binpick_cloud::io::{
    IoError, Model, PcdEncoding, PlyEncoding, ReadLimits, read_cloud_with_colors_from_bytes,
    read_model_from_bytes,
};
use common::*;

const CASES_PER_READER: usize = 10_000;

fn check_err(e: &IoError, name: &str, case: &str) {
    let msg = e.to_string();
    assert!(msg.starts_with(&format!("{name}: ")), "{case}: {msg}");
    assert!(!msg.contains('\n'), "{case}: multi-line message: {msg}");
    assert_eq!(e.path().to_str(), Some(name), "{case}");
}

/// Reads `bytes` as a model (and, for PCD and PLY, as a cloud) and checks the outcome;
/// returns whether the model read succeeded.
fn check(bytes: &[u8], name: &str, case: &str) -> bool {
    let run = catch_unwind(AssertUnwindSafe(|| {
        if name.ends_with(".pcd") || name.ends_with(".ply") {
            match read_cloud_with_colors_from_bytes(bytes, name) {
                Ok(c) => {
                    assert!(!c.cloud.is_empty(), "{case}: Ok with no points");
                    assert!(c.cloud.first_non_finite().is_none(), "{case}: NaN kept");
                    assert_eq!(
                        c.report.points_in_file,
                        c.cloud.len() + c.report.non_finite_dropped,
                        "{case}: points lost without being counted"
                    );
                }
                Err(e) => check_err(&e, name, case),
            }
        }
        match read_model_from_bytes(bytes, name, &ReadLimits::default()) {
            Ok(Model::Cloud(c)) => {
                assert!(!c.cloud.is_empty(), "{case}");
                true
            }
            Ok(Model::Mesh(m)) => {
                let mesh = &m.mesh;
                assert!(!mesh.triangles.is_empty(), "{case}");
                for t in 0..mesh.triangles.len() {
                    let a = mesh.triangle_area(t).expect("index in range");
                    assert!(a > 0.0 && a.is_finite(), "{case}: triangle {t} area {a}");
                }
                assert!(
                    mesh.vertices
                        .iter()
                        .all(|v| v.iter().all(|c| c.is_finite())),
                    "{case}"
                );
                let r = &m.report;
                assert_eq!(
                    r.vertices_in_file,
                    r.unused_vertices + r.duplicate_vertices_merged + mesh.vertices.len(),
                    "{case}: vertices lost without being counted"
                );
                true
            }
            Err(e) => {
                check_err(&e, name, case);
                false
            }
        }
    }));
    match run {
        Ok(ok) => ok,
        Err(_) => panic!("{case}: reader panicked (or a check failed, see above)"),
    }
}

fn sample_cloud(n: usize) -> PointCloud {
    let mut rng = XorShift(77);
    PointCloud::new(
        (0..n)
            .map(|i| [i as f32 * 0.5, rng.f32_in(-1.0, 1.0), 2.0 + (i % 4) as f32])
            .collect(),
    )
}

/// Runs the mutation loop over `seeds` (all valid, all with the name `name`).
fn run(reader: &str, name: &str, seeds: &[Vec<u8>], seed: u64) {
    for (i, s) in seeds.iter().enumerate() {
        assert!(
            check(s, name, &format!("{reader} seed {i}")),
            "{reader} seed {i} is invalid"
        );
    }
    let mut rng = XorShift(seed);
    let (mut ok, mut err) = (0usize, 0usize);
    for case in 0..CASES_PER_READER {
        let src = &seeds[rng.below(seeds.len())];
        let m = mutate(&mut rng, src);
        if check(&m, name, &format!("{reader} mutation {case}")) {
            ok += 1;
        } else {
            err += 1;
        }
    }
    // Both outcomes must occur, or the mutations exercise nothing.
    assert!(ok > 100 && err > 1000, "{reader}: ok {ok}, err {err}");
}

fn pcd_seeds(enc: PcdEncoding) -> Vec<Vec<u8>> {
    let c = sample_cloud(30);
    let colors = colors_for(c.len());
    let data = match enc {
        PcdEncoding::Ascii => "ascii",
        PcdEncoding::Binary => "binary",
        PcdEncoding::BinaryCompressed => "binary_compressed",
    };
    // Layouts the writer does not produce: F8, I2, COUNT 3, padding, organised with a NaN.
    let cols = [
        col("x", 'F', 8, 1),
        col("y", 'F', 4, 1),
        col("z", 'I', 2, 1),
        col("h", 'F', 4, 3),
        col("_", 'U', 1, 2),
        col("rgba", 'U', 4, 1),
    ];
    let rows: Vec<Vec<f64>> = (0..6)
        .map(|i| {
            let x = if i == 2 { f64::NAN } else { i as f64 };
            vec![x, 1.5, -3.0, 0.1, 0.2, 0.3, 0.0, 0.0, 4_278_190_335.0]
        })
        .collect();
    vec![
        written_pcd(&c, enc, Some(&colors)),
        written_pcd(&PointCloud::new(c.points[..5].to_vec()), enc, None),
        pcd_file(&cols, &rows, 3, 2, data),
    ]
}

#[test]
fn pcd_ascii_mutations() {
    run(
        "pcd ascii",
        "m.pcd",
        &pcd_seeds(PcdEncoding::Ascii),
        0x5EED_0001,
    );
}

#[test]
fn pcd_binary_mutations() {
    run(
        "pcd binary",
        "m.pcd",
        &pcd_seeds(PcdEncoding::Binary),
        0x5EED_0002,
    );
}

#[test]
fn pcd_binary_compressed_mutations() {
    run(
        "pcd binary_compressed",
        "m.pcd",
        &pcd_seeds(PcdEncoding::BinaryCompressed),
        0x5EED_0003,
    );
}

#[test]
fn ply_mutations() {
    let c = sample_cloud(30);
    let colors = colors_for(c.len());
    let mut seeds = Vec::new();
    for enc in [
        PlyEncoding::Ascii,
        PlyEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian,
    ] {
        seeds.push(written_ply(&c, enc, Some(&colors)));
    }
    // Meshes: the box with quads, ASCII and binary.
    seeds.push(box_ply(true));
    seeds.push(box_ply(false));
    run("ply", "m.ply", &seeds, 0x5EED_0004);
}

#[test]
fn stl_mutations() {
    let soup = box_soup();
    let seeds = vec![
        ascii_stl(&soup),
        binary_stl(&soup, b"binary"),
        binary_stl(&soup[..4], b"solid but binary"),
    ];
    run("stl", "m.stl", &seeds, 0x5EED_0005);
}

#[test]
fn obj_mutations() {
    let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf -4 -2 -3\nf 2 3 4\n";
    let seeds = vec![box_obj(), tri.as_bytes().to_vec()];
    run("obj", "m.obj", &seeds, 0x5EED_0006);
}
