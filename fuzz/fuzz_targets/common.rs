//! Checks shared by the reader targets: a reader returns `Ok` with a usable result or an
//! `Err` whose message names the file, on one line; it never panics (libFuzzer reports a
//! panic as a crash).

use binpick_cloud::io::{IoError, LoadedCloud, Model, ReadLimits, read_model_from_bytes};
use binpick_cloud::{SurfaceSampling, TriangleMesh};

pub fn check_err(e: &IoError, name: &str) {
    let msg = e.to_string();
    assert!(
        msg.starts_with(&format!("{name}: ")),
        "error does not name the file: {msg}"
    );
    assert!(!msg.contains('\n'), "multi-line error: {msg}");
    assert_eq!(e.path().to_str(), Some(name));
}

pub fn check_cloud(c: &LoadedCloud) {
    assert!(!c.cloud.is_empty(), "Ok with no points");
    assert!(
        c.cloud.first_non_finite().is_none(),
        "non-finite point kept"
    );
    if let Some(colors) = &c.colors {
        assert_eq!(colors.len(), c.cloud.len());
    }
    assert_eq!(
        c.report.points_in_file,
        c.cloud.len() + c.report.non_finite_dropped,
        "points lost without being counted"
    );
    let _ = c.cloud.degeneracy();
}

pub fn check_mesh(m: &TriangleMesh) {
    assert!(!m.triangles.is_empty(), "Ok with no triangles");
    for t in 0..m.triangles.len() {
        let a = m.triangle_area(t).expect("index out of range");
        assert!(a > 0.0 && a.is_finite(), "degenerate triangle kept: {a}");
    }
    for v in &m.vertices {
        assert!(v.iter().all(|c| c.is_finite()), "non-finite vertex kept");
    }
    // Sample at a spacing that gives about 100 points, to exercise the sampler too.
    let area = m.area();
    let spacing = (area / 100.0).sqrt();
    if spacing.is_finite() && spacing > 0.0 {
        if let Ok(s) = m.sample_surface(&SurfaceSampling {
            spacing_mm: spacing,
            ..Default::default()
        }) {
            assert_eq!(s.cloud.len(), s.normals.len());
            for n in &s.normals {
                let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                assert!((l - 1.0).abs() < 1e-3, "normal of length {l}");
            }
        }
    }
}

/// Reads `data` as a model named `name` and checks the outcome.
pub fn model(data: &[u8], name: &str) {
    match read_model_from_bytes(data, name, &ReadLimits::default()) {
        Ok(Model::Cloud(c)) => check_cloud(&c),
        Ok(Model::Mesh(m)) => {
            check_mesh(&m.mesh);
            let r = &m.report;
            assert_eq!(
                r.vertices_in_file,
                r.unused_vertices + r.duplicate_vertices_merged + m.mesh.vertices.len()
            );
        }
        Err(e) => check_err(&e, name),
    }
}
