//! Wavefront OBJ reading, through the `tobj` crate.
//!
//! Only geometry is read: `v` positions and `f` faces. The lines tobj would otherwise act on
//! but binpick does not need are blanked before tobj sees them (keeping line numbers):
//! texture coordinates and normals (`vt`, `vn`, `vp`: their indices in faces are then
//! ignored), materials (`mtllib`, `usemtl`: no other file is opened), and points and
//! polylines (`p`, `l`: tobj would turn a three-point polyline into a triangle). Those are
//! counted in [`super::MeshReport::other_elements_ignored`] when they are points or lines.

use std::collections::HashMap;
use std::io::Cursor;
use std::path::Path;

use super::model::RawMesh;
use super::{IoError, ReadLimits, format_err, mesh_err};

fn tokens(line: &str) -> impl Iterator<Item = &str> {
    line.split_whitespace()
}

/// The position of a `v` line as tobj computes it (`x y z`, divided by `w` when a fourth
/// value is given); NaN when it does not parse (tobj then fails on the line anyway).
fn position(line: &str) -> [f32; 3] {
    let vals: Vec<&str> = tokens(line).skip(1).collect();
    let num = |k: usize| vals.get(k).and_then(|t| t.parse::<f32>().ok());
    let (Some(x), Some(y), Some(z)) = (num(0), num(1), num(2)) else {
        return [f32::NAN; 3];
    };
    match (vals.len(), num(3)) {
        (4, Some(w)) => [x / w, y / w, z / w],
        _ => [x, y, z],
    }
}

pub(super) fn read(bytes: &[u8], path: &Path, limits: &ReadLimits) -> Result<RawMesh, IoError> {
    let mut filtered: Vec<u8> = Vec::with_capacity(bytes.len() + 1);
    let (mut f_lines, mut ignored) = (0usize, 0usize);
    let mut file_vertices: Vec<[f32; 3]> = Vec::new();
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let text = std::str::from_utf8(line)
            .map_err(|_| format_err(path, format!("line {}: not text (invalid UTF-8)", i + 1)))?;
        let keep = match tokens(text).next() {
            Some("v") => {
                file_vertices.push(position(text));
                true
            }
            Some("f") => {
                f_lines += 1;
                true
            }
            Some("p" | "l") => {
                ignored += 1;
                false
            }
            Some("vt" | "vn" | "vp" | "mtllib" | "usemtl") => false,
            _ => true,
        };
        if keep {
            filtered.extend_from_slice(line);
        }
        filtered.push(b'\n');
    }
    let v_lines = file_vertices.len();
    limits.check_points(path, v_lines as u64)?;
    limits.check_faces(path, f_lines as u64)?;

    let options = tobj::LoadOptions {
        single_index: false,
        triangulate: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, _) = tobj::load_obj_buf(&mut Cursor::new(filtered), &options, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| match e {
        tobj::LoadError::FaceVertexOutOfBounds => mesh_err(
            path,
            format!(
                "a face refers to a vertex that does not exist: there are {v_lines} vertices \
                 (OBJ indices run from 1, or back from -1 for the last vertex)"
            ),
        ),
        tobj::LoadError::PositionParseError => {
            format_err(path, "OBJ: a vertex line (v) does not hold three numbers")
        }
        tobj::LoadError::FaceParseError => format_err(
            path,
            "OBJ: a face line (f) has an index that is not an integer (v, v/vt, v//vn or v/vt/vn)",
        ),
        other => format_err(path, format!("OBJ: {other}")),
    })?;

    // tobj renumbers the vertices of each object; map them back to the file's vertices by
    // position, so that the report counts unused and duplicate vertices of the file.
    let mut by_position: HashMap<[u32; 3], i64> = HashMap::with_capacity(v_lines);
    for (i, p) in file_vertices.iter().enumerate() {
        by_position.entry(p.map(f32::to_bits)).or_insert(i as i64);
    }
    let mut raw = RawMesh {
        vertices: file_vertices.iter().map(|p| p.map(f64::from)).collect(),
        other_elements_ignored: ignored,
        ..Default::default()
    };
    for model in &models {
        let mesh = &model.mesh;
        let file_index: Vec<i64> = mesh
            .positions
            .chunks_exact(3)
            .map(|p| {
                let key = [p[0].to_bits(), p[1].to_bits(), p[2].to_bits()];
                *by_position.entry(key).or_insert_with(|| {
                    // Not a position of the file as parsed above (cannot happen with tobj's
                    // parsing); kept as an extra vertex.
                    raw.vertices
                        .push([f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]);
                    raw.vertices.len() as i64 - 1
                })
            })
            .collect();
        let mut at = 0usize;
        let mut push = |arity: usize| {
            let corners: Vec<i64> = mesh
                .indices
                .get(at..at + arity)
                .unwrap_or(&[])
                .iter()
                .map(|&i| file_index.get(i as usize).copied().unwrap_or(-1))
                .collect();
            at += arity;
            raw.faces.push(&corners);
        };
        if mesh.face_arities.is_empty() {
            for _ in 0..mesh.indices.len() / 3 {
                push(3);
            }
        } else {
            for &a in &mesh.face_arities {
                push(a as usize);
            }
        }
    }
    // tobj drops faces of one or two corners without a word: count them as degenerate.
    for _ in raw.faces.arities.len()..f_lines {
        raw.faces.push(&[]);
    }
    Ok(raw)
}
