//! CAD mesh models: STL (ASCII and binary), OBJ and PLY with faces read through
//! `read_model` give the same mesh for the same shape; truncated, degenerate and
//! out-of-range files give errors naming the file and the problem; surface sampling covers
//! the whole surface with outward normals, deterministically, at the documented density.
//!
//! The files are written here by hand (not by the code under test).

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use binpick_cloud::io::{
    Encoding, IoError, MeshFormat, Model, ReadLimits, read_model, read_model_from_bytes,
};
use binpick_cloud::{SurfaceSampling, TriangleMesh, Units};

mod common;
use common::*;

fn mesh_of(bytes: &[u8], name: &str) -> binpick_cloud::io::LoadedMesh {
    match read_model_from_bytes(bytes, name, &ReadLimits::default()) {
        Ok(Model::Mesh(m)) => m,
        Ok(Model::Cloud(_)) => panic!("{name}: read as a cloud"),
        Err(e) => panic!("{name}: {e}"),
    }
}

fn expect_err(bytes: &[u8], name: &str, want: &str) -> IoError {
    match read_model_from_bytes(bytes, name, &ReadLimits::default()) {
        Ok(_) => panic!("{name}: expected an error containing {want:?}"),
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("{name}: ")), "{msg}");
            assert!(msg.contains(want), "{name}: expected {want:?} in: {msg}");
            assert!(!msg.contains('\n'), "{msg}");
            e
        }
    }
}

#[test]
fn every_format_gives_the_same_box() {
    let soup = box_soup();
    let files: Vec<(Vec<u8>, &str, MeshFormat, Encoding)> = vec![
        (
            ascii_stl(&soup),
            "box.stl",
            MeshFormat::Stl,
            Encoding::Ascii,
        ),
        (
            binary_stl(&soup, b"binary box"),
            "box.stl",
            MeshFormat::Stl,
            Encoding::BinaryLittleEndian,
        ),
        // Binary files whose header starts with "solid" (as some CAD programs write them).
        (
            binary_stl(&soup, b"solid box exported"),
            "solid.stl",
            MeshFormat::Stl,
            Encoding::BinaryLittleEndian,
        ),
        (box_obj(), "box.obj", MeshFormat::Obj, Encoding::Ascii),
        (box_ply(true), "box.ply", MeshFormat::Ply, Encoding::Ascii),
        (
            box_ply(false),
            "box.PLY",
            MeshFormat::Ply,
            Encoding::BinaryLittleEndian,
        ),
    ];
    let reference = mesh_of(&files[0].0, files[0].1).mesh;
    assert_eq!(reference.triangles.len(), 12);
    assert_eq!(reference.vertices.len(), 8);
    let corners = box_corners();
    for v in &reference.vertices {
        assert!(corners.contains(v), "{v:?}");
    }
    for (bytes, name, format, encoding) in &files {
        let m = mesh_of(bytes, name);
        assert_eq!(m.mesh, reference, "{name} {format:?} {encoding:?}");
        let r = &m.report;
        assert_eq!((r.format, r.encoding), (*format, *encoding), "{name}");
        assert!(r.closed && !r.winding_reversed, "{name}: {r:?}");
        assert_eq!(r.degenerate_skipped, 0, "{name}");
        assert!(
            (r.area - 2.0 * (200.0 + 600.0 + 300.0)).abs() < 1e-6,
            "{name}"
        );
        assert!((m.mesh.signed_volume() - 6000.0).abs() < 1e-6, "{name}");
        match format {
            MeshFormat::Stl => {
                assert_eq!(
                    (r.vertices_in_file, r.faces_in_file, r.polygons_split),
                    (36, 12, 0)
                );
                assert_eq!((r.duplicate_vertices_merged, r.unused_vertices), (28, 0));
            }
            _ => {
                assert_eq!(
                    (r.vertices_in_file, r.faces_in_file, r.polygons_split),
                    (8, 6, 6),
                    "{name}"
                );
                assert_eq!((r.duplicate_vertices_merged, r.unused_vertices), (0, 0));
            }
        }
    }
}

#[test]
fn inward_winding_is_turned_outward_and_open_meshes_are_left_alone() {
    let mut soup = box_soup();
    for t in &mut soup {
        t.swap(1, 2);
    }
    let m = mesh_of(&ascii_stl(&soup), "inward.stl");
    assert!(m.report.closed && m.report.winding_reversed);
    assert!(m.mesh.signed_volume() > 0.0);
    // An open box (one side missing) keeps its winding, whatever it is.
    soup.truncate(10);
    let m = mesh_of(&ascii_stl(&soup), "open.stl");
    assert!(!m.report.closed && !m.report.winding_reversed);
    assert!(m.mesh.signed_volume() < 0.0);
}

#[test]
fn ply_without_faces_and_pcd_stay_clouds() {
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
               property float z\nelement face 0\nproperty list uchar int vertex_indices\n\
               end_header\n0 0 0\n1 0 0\n0 1 0\n";
    match read_model_from_bytes(ply.as_bytes(), "pts.ply", &ReadLimits::default()).unwrap() {
        Model::Cloud(c) => assert_eq!(c.cloud.len(), 3),
        Model::Mesh(_) => panic!("a PLY without faces is a cloud"),
    }
    let pcd = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\n\
               HEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3\n4 5 6\n";
    let model = read_model_from_bytes(pcd.as_bytes(), "m.pcd", &ReadLimits::default()).unwrap();
    assert!(!model.is_mesh());
}

#[test]
fn model_path_reader_and_units() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("part.stl");
    std::fs::write(&path, binary_stl(&box_soup(), b"")).unwrap();
    let mut model = read_model(&path).unwrap();
    let Model::Mesh(before) = model.clone() else {
        panic!("mesh expected")
    };
    model.scale_to_mm(Units::Metres);
    let Model::Mesh(after) = model else {
        panic!("mesh expected")
    };
    for (a, b) in before.mesh.vertices.iter().zip(&after.mesh.vertices) {
        for k in 0..3 {
            assert_eq!(a[k] * 1000.0, b[k]);
        }
    }
    assert!((after.report.area - before.report.area * 1e6).abs() < 1e-3);
    let e = read_model(&dir.path().join("missing.stl")).unwrap_err();
    assert!(e.to_string().contains("missing.stl"), "{e}");
    let e = read_model(&dir.path().join("part.xyz")).unwrap_err();
    assert!(
        e.to_string()
            .contains("supported are .pcd, .ply, .stl and .obj"),
        "{e}"
    );
}

#[test]
fn truncated_and_miscounted_stl() {
    let soup = box_soup();
    let bin = binary_stl(&soup, b"");
    expect_err(
        &bin[..bin.len() - 30],
        "cut.stl",
        "truncated: binary STL header says 12 triangles (684 bytes) but the file has only 654 \
         bytes (not a whole number of 50-byte triangles)",
    );
    expect_err(
        &bin[..bin.len() - 100],
        "cut.stl",
        "has only 584 bytes (10 triangles)",
    );
    let mut extra = bin.clone();
    extra.extend(&bin[84..134]);
    expect_err(
        &extra,
        "extra.stl",
        "header says 12 triangles (684 bytes) but the file has 734 bytes (13 triangles)",
    );
    expect_err(&bin[..40], "short.stl", "shorter than the 84-byte header");
    // A binary count above the face limit is refused before any triangle is read.
    let mut lie = bin.clone();
    lie[80..84].copy_from_slice(&4_000_000_000u32.to_le_bytes());
    expect_err(
        &lie,
        "lie.stl",
        "4000000000 faces, more than the limit of 50000000 faces",
    );

    let ascii = ascii_stl(&soup);
    let text = String::from_utf8(ascii.clone()).unwrap();
    let cut = text.rfind("endfacet").unwrap();
    expect_err(&ascii[..cut], "cut.stl", "truncated: ascii STL");
    let no_vertex = text.replacen("      vertex 1 2 3\n", "", 1);
    expect_err(
        no_vertex.as_bytes(),
        "bad.stl",
        "ascii STL, facet 0 (line 2)",
    );
    let after = format!("{text}garbage here\n");
    expect_err(
        after.as_bytes(),
        "after.stl",
        "text after the endsolid of line 86 that does not start a new solid",
    );
    let nan = text.replacen("vertex 1 2 3", "vertex nan 2 3", 1);
    expect_err(nan.as_bytes(), "nan.stl", "finite");
    // Two solids in one file are both read.
    let two = format!("{text}{text}");
    let m = mesh_of(two.as_bytes(), "two.stl");
    assert_eq!(m.report.faces_in_file, 24);
    assert_eq!(m.mesh.triangles.len(), 24);
    // A PLY named .stl.
    let e = expect_err(&box_ply(true), "box.stl", "is a PLY file");
    assert!(matches!(e, IoError::WrongFormat { .. }));
}

#[test]
fn non_finite_coordinates_and_bad_indices() {
    let mut soup = box_soup();
    soup[3][1][2] = f32::INFINITY;
    expect_err(
        &binary_stl(&soup, b""),
        "inf.stl",
        "face 3 has a corner with a non-finite coordinate",
    );
    let ply = String::from_utf8(box_ply(true)).unwrap();
    expect_err(
        ply.replacen("4 1 3 7 5", "4 1 3 8 5", 1).as_bytes(),
        "idx.ply",
        "face 5 refers to vertex 8, out of range: there are 8 vertices (indices 0 to 7)",
    );
    expect_err(
        ply.replacen("4 1 3 7 5", "4 1 3 -1 5", 1).as_bytes(),
        "neg.ply",
        "face 5 refers to vertex -1, out of range",
    );
    expect_err(
        ply.replacen("11 22 33", "11 nan 33", 1).as_bytes(),
        "nan.ply",
        "non-finite coordinate",
    );
    let obj = String::from_utf8(box_obj()).unwrap();
    expect_err(
        obj.replacen("f 2/1/1 4/1/1 8/1/1 6/1/1", "f 2 4 9 6", 1)
            .as_bytes(),
        "idx.obj",
        "a face refers to a vertex that does not exist: there are 8 vertices",
    );
    expect_err(
        obj.replacen("f 2/1/1 4/1/1 8/1/1 6/1/1", "f 2 4 x 6", 1)
            .as_bytes(),
        "parse.obj",
        "not an integer",
    );
    let no_faces: String = obj
        .lines()
        .filter(|l| !l.starts_with("f "))
        .collect::<Vec<_>>()
        .join("\n");
    expect_err(
        no_faces.as_bytes(),
        "empty.obj",
        "contains no faces (8 vertices): a mesh model needs triangles",
    );
    // A binary PLY whose face list is cut off.
    let bin = box_ply(false);
    expect_err(&bin[..bin.len() - 3], "cut.ply", "truncated: ");
    // One face fewer announced than stored.
    let fewer =
        String::from_utf8(box_ply(true))
            .unwrap()
            .replacen("element face 6", "element face 5", 1);
    expect_err(
        fewer.as_bytes(),
        "fewer.ply",
        "unexpected data after the last element",
    );
}

#[test]
fn degenerate_triangles_are_skipped_and_counted() {
    let c = box_corners();
    let mut soup = box_soup();
    // A zero-area triangle (a repeated corner) and a needle of three collinear corners.
    soup.push([c[0], c[0], c[1]]);
    soup.push([c[0], [6.0, 2.0, 3.0], c[1]]);
    let m = mesh_of(&ascii_stl(&soup), "deg.stl");
    assert_eq!(m.report.degenerate_skipped, 2);
    assert_eq!(m.mesh.triangles.len(), 12);
    assert!(m.report.closed);
    // STL stores three corners per facet: the six corners of the skipped facets are unused.
    assert_eq!(
        (m.report.unused_vertices, m.report.duplicate_vertices_merged),
        (6, 36 - 8)
    );
    // Faces of one or two corners in OBJ and PLY count as degenerate too.
    let obj = format!(
        "{}f 1 2\nf 3\nl 1 2 3\np 4\n",
        String::from_utf8(box_obj()).unwrap()
    );
    let m = mesh_of(obj.as_bytes(), "short.obj");
    assert_eq!(m.report.degenerate_skipped, 2);
    assert_eq!(m.report.other_elements_ignored, 2);
    assert_eq!(m.mesh.triangles.len(), 12);

    let all_flat = [[c[0], c[1], [21.0, 2.0, 3.0]]; 3];
    let e = expect_err(
        &ascii_stl(&all_flat),
        "flat.stl",
        "all 3 triangles are degenerate (zero area)",
    );
    assert!(matches!(e, IoError::Mesh { .. }));
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
               property float z\nelement face 2\nproperty list uchar int vertex_indices\n\
               end_header\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n1 2\n";
    expect_err(
        ply.as_bytes(),
        "lines.ply",
        "contains no triangles: none of its 2 faces has three or more corners",
    );
}

/// Samples' nearest-neighbour distances (brute force over a hash grid).
fn nearest_distances(points: &[[f32; 3]], cell: f64) -> Vec<f64> {
    use std::collections::HashMap;
    let key = |p: &[f32; 3]| p.map(|c| (f64::from(c) / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, p) in points.iter().enumerate() {
        grid.entry(key(p)).or_default().push(i);
    }
    points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let k = key(p);
            let mut best = f64::INFINITY;
            for d in 0..27i64 {
                let cell = [k[0] + d % 3 - 1, k[1] + (d / 3) % 3 - 1, k[2] + d / 9 - 1];
                for &j in grid.get(&cell).map_or(&[][..], |v| &v[..]) {
                    if j != i {
                        let q = points[j];
                        let dd: f64 = (0..3)
                            .map(|a| (f64::from(p[a]) - f64::from(q[a])).powi(2))
                            .sum();
                        best = best.min(dd.sqrt());
                    }
                }
            }
            best
        })
        .collect()
}

fn sample(mesh: &TriangleMesh, spacing: f64, seed: u64) -> binpick_cloud::SurfaceSamples {
    mesh.sample_surface(&SurfaceSampling {
        spacing_mm: spacing,
        seed,
        ..Default::default()
    })
    .unwrap()
}

/// A closed UV sphere of radius `r` (poles' zero-area triangles removed by the reader).
fn sphere(r: f32, n: usize) -> TriangleMesh {
    let mut soup = Vec::new();
    let p = |i: usize, j: usize| {
        let th = std::f32::consts::PI * i as f32 / n as f32;
        let ph = std::f32::consts::PI * j as f32 / n as f32;
        [
            r * th.sin() * ph.cos(),
            r * th.sin() * ph.sin(),
            r * th.cos(),
        ]
    };
    for i in 0..n {
        for j in 0..2 * n {
            soup.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
            soup.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
        }
    }
    mesh_of(&binary_stl(&soup, b""), "sphere.stl").mesh
}

#[test]
fn sampling_density_scales_with_spacing_and_matches_the_documented_constants() {
    let cube = mesh_of(&ascii_stl(&box_soup()), "box.stl").mesh;
    let ball = sphere(20.0, 40);
    assert!(ball.area() > 0.99 * 4.0 * std::f64::consts::PI * 400.0);
    for (name, mesh) in [("box", &cube), ("sphere", &ball)] {
        let area = mesh.area();
        let mut counts = Vec::new();
        for spacing in [0.5, 1.0, 2.0] {
            let s = sample(mesh, spacing, 1);
            let n = s.cloud.len();
            let ratio = n as f64 / (area / (spacing * spacing));
            assert!(
                (0.64..0.78).contains(&ratio),
                "{name} {spacing}: {n} points, ratio {ratio}"
            );
            let mut nn = nearest_distances(&s.cloud.points, 3.0 * spacing);
            nn.sort_by(f64::total_cmp);
            let median = nn[nn.len() / 2] / spacing;
            assert!(
                (0.95..1.05).contains(&median),
                "{name} {spacing}: median {median}"
            );
            // Poisson-disk: nothing closer than the minimum distance (f32 rounding aside).
            let min_allowed = binpick_cloud::mesh::SAMPLE_MIN_DISTANCE_FACTOR * spacing * 0.999;
            assert!(
                nn[0] >= min_allowed,
                "{name} {spacing}: {} < {min_allowed}",
                nn[0]
            );
            // No holes: every sample has a neighbour within twice the spacing.
            assert!(
                nn[nn.len() - 1] < 2.0 * spacing,
                "{name} {spacing}: {}",
                nn[nn.len() - 1]
            );
            counts.push(n as f64);
        }
        // Halving the spacing quadruples the count.
        for w in counts.windows(2) {
            let q = w[0] / w[1];
            assert!((3.8..4.2).contains(&q), "{name}: {counts:?}");
        }
    }
}

#[test]
fn sampling_covers_every_face_with_outward_normals_and_is_deterministic() {
    let cube = mesh_of(&ascii_stl(&box_soup()), "box.stl").mesh;
    let s = sample(&cube, 1.0, 7);
    assert_eq!(s.normals.len(), s.cloud.len());
    let (lo, hi) = ([1.0f32, 2.0, 3.0], [11.0f32, 22.0, 33.0]);
    let centre = [6.0f32, 12.0, 18.0];
    let mut per_side = [0usize; 6];
    for (p, n) in s.cloud.points.iter().zip(&s.normals) {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-5);
        // Every sample lies on the surface, on a side whose outward axis is its normal.
        let side = (0..3)
            .flat_map(|a| [(a, lo[a], -1.0f32), (a, hi[a], 1.0)])
            .position(|(a, v, sign)| (p[a] - v).abs() < 1e-3 && n[a] == sign)
            .unwrap_or_else(|| panic!("{p:?} {n:?} is not on a side with its outward normal"));
        per_side[side] += 1;
        let out: f32 = (0..3).map(|a| (p[a] - centre[a]) * n[a]).sum();
        assert!(out > 0.0);
    }
    // Sides of 20 x 30 (x), 10 x 30 (y), 10 x 20 (z) mm^2: counts follow the areas.
    let areas = [600.0, 600.0, 300.0, 300.0, 200.0, 200.0];
    for (k, (&n, &a)) in per_side.iter().zip(&areas).enumerate() {
        let ratio = n as f64 / a;
        assert!(
            (0.6..0.8).contains(&ratio),
            "side {k}: {n} samples on {a} mm^2"
        );
    }
    let again = sample(&cube, 1.0, 7);
    assert_eq!(again, s);
    let other = sample(&cube, 1.0, 8);
    assert_ne!(other.cloud, s.cloud);
    // Inward-wound meshes as given are sampled with their (inward) winding: the reader is what
    // turns a closed mesh outward.
    let mut inward = cube.clone();
    inward.flip();
    let s = sample(&inward, 2.0, 7);
    let out: f32 = s
        .cloud
        .points
        .iter()
        .zip(&s.normals)
        .map(|(p, n)| (0..3).map(|a| (p[a] - centre[a]) * n[a]).sum::<f32>())
        .sum();
    assert!(out < 0.0);
}

#[test]
fn small_triangles_of_a_fine_mesh_get_their_share() {
    // A sphere made of many triangles smaller than the spacing is still covered evenly.
    let ball = sphere(10.0, 80);
    let mean_area = ball.area() / ball.triangles.len() as f64;
    assert!(mean_area < 0.2, "{mean_area}");
    let s = sample(&ball, 1.0, 3);
    let ratio = s.cloud.len() as f64 / ball.area();
    assert!((0.64..0.78).contains(&ratio), "{ratio}");
    // Both hemispheres equally.
    let north = s.cloud.points.iter().filter(|p| p[2] > 0.0).count() as f64;
    let frac = north / s.cloud.len() as f64;
    assert!((0.45..0.55).contains(&frac), "{frac}");
}
