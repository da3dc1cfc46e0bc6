//! Wavefront OBJ reading, through the `tobj` crate.
//!
//! Only geometry is read: `v` positions and `f` faces. The lines tobj would otherwise act on
//! but binpick does not need are blanked before tobj sees them (keeping line numbers):
//! texture coordinates and normals (`vt`, `vn`, `vp`: their indices in faces are then
//! ignored), materials (`mtllib`, `usemtl`: no other file is opened), and points and
//! polylines (`p`, `l`: tobj would turn a three-point polyline into a triangle). Those are
//! counted in [`super::MeshReport::other_elements_ignored`] when they are points or lines.

use std::io::Cursor;
use std::path::Path;

use super::model::RawMesh;
use super::{IoError, ReadLimits, format_err, mesh_err};

fn tokens(line: &str) -> impl Iterator<Item = &str> {
    line.split_whitespace()
}

pub(super) fn read(bytes: &[u8], path: &Path, limits: &ReadLimits) -> Result<RawMesh, IoError> {
    let mut filtered: Vec<u8> = Vec::with_capacity(bytes.len() + 1);
    let (mut v_lines, mut f_lines, mut ignored) = (0usize, 0usize, 0usize);
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let text = std::str::from_utf8(line)
            .map_err(|_| format_err(path, format!("line {}: not text (invalid UTF-8)", i + 1)))?;
        let keep = match tokens(text).next() {
            Some("v") => {
                v_lines += 1;
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
    limits.check_points(path, v_lines as u64)?;
    limits.check_faces(path, f_lines as u64)?;

    let options = tobj::LoadOptions {
        single_index: false,
        triangulate: false,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
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

    let mut raw = RawMesh {
        other_elements_ignored: ignored,
        vertices_in_file: Some(v_lines),
        ..Default::default()
    };
    for model in &models {
        let mesh = &model.mesh;
        let base = raw.vertices.len() as i64;
        raw.vertices.extend(
            mesh.positions
                .chunks_exact(3)
                .map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]),
        );
        let mut at = 0usize;
        let mut push = |arity: usize| {
            let corners: Vec<i64> = mesh
                .indices
                .get(at..at + arity)
                .unwrap_or(&[])
                .iter()
                .map(|&i| base + i64::from(i))
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
