//! STL (ASCII and binary) reading, through the `stl_io` crate.
//!
//! The kind is decided here rather than by `stl_io` (which calls any file starting with
//! `"solid "` ASCII, while many CAD programs write binary files whose 80-byte header starts
//! that way): a file whose size is exactly 84 + 50 x its triangle count is binary, a text file
//! starting with `solid` is ASCII, anything else is a binary file whose count does not match
//! its size, reported with both numbers. `stl_io` then decodes the triangles. In ASCII,
//! several `solid ... endsolid` blocks are read one after the other, and text after an
//! `endsolid` that does not start a new solid is an error (stl_io would ignore it).

use std::borrow::Cow;
use std::io::Cursor;
use std::path::Path;

use super::model::RawMesh;
use super::{Encoding, IoError, ReadLimits, format_err, one_line, truncated};

const HEADER: usize = 84;
const TRIANGLE: u64 = 50;

fn binary_count(bytes: &[u8]) -> Option<u32> {
    let b: [u8; 4] = bytes.get(80..84)?.try_into().ok()?;
    Some(u32::from_le_bytes(b))
}

fn binary_size(count: u32) -> u64 {
    HEADER as u64 + TRIANGLE * u64::from(count)
}

fn starts_with_solid(bytes: &[u8]) -> bool {
    bytes.starts_with(b"solid") && bytes.get(5).is_none_or(|b| b.is_ascii_whitespace())
}

/// Whether the file is ASCII STL (see the module doc).
fn is_ascii(bytes: &[u8]) -> bool {
    if binary_count(bytes).is_some_and(|c| binary_size(c) == bytes.len() as u64) {
        return false;
    }
    let head = bytes.get(..bytes.len().min(4096)).unwrap_or(bytes);
    starts_with_solid(bytes) && !head.contains(&0)
}

/// Checks a binary STL's triangle count (from the first bytes of the file) against the limit.
pub(super) fn precheck(prefix: &[u8], path: &Path, limits: &ReadLimits) -> Result<(), IoError> {
    if starts_with_solid(prefix) {
        // ASCII, or binary with a "solid" header: decided on the whole file.
        return Ok(());
    }
    match binary_count(prefix) {
        Some(count) => limits.check_faces(path, u64::from(count)),
        None => Ok(()),
    }
}

/// Reads the facets: three new vertices per facet, in file order.
pub(super) fn read(
    bytes: &[u8],
    path: &Path,
    limits: &ReadLimits,
) -> Result<(RawMesh, Encoding), IoError> {
    if is_ascii(bytes) {
        Ok((read_ascii(bytes, path, limits)?, Encoding::Ascii))
    } else {
        Ok((
            read_binary(bytes, path, limits)?,
            Encoding::BinaryLittleEndian,
        ))
    }
}

fn push_triangle(raw: &mut RawMesh, t: &stl_io::Triangle) {
    let base = raw.vertices.len() as i64;
    for v in &t.vertices {
        raw.vertices
            .push([f64::from(v[0]), f64::from(v[1]), f64::from(v[2])]);
    }
    raw.faces.push(&[base, base + 1, base + 2]);
}

fn read_binary(bytes: &[u8], path: &Path, limits: &ReadLimits) -> Result<RawMesh, IoError> {
    let len = bytes.len() as u64;
    let Some(count) = binary_count(bytes) else {
        return Err(format_err(
            path,
            format!(
                "not an STL file: it does not start with \"solid\" (ASCII STL) and is shorter \
                 than the 84-byte header of a binary STL ({len} bytes)"
            ),
        ));
    };
    limits.check_faces(path, u64::from(count))?;
    let need = binary_size(count);
    let holds = |extra: u64| {
        if extra % TRIANGLE == 0 {
            format!("{} triangles", (len - HEADER as u64) / TRIANGLE)
        } else {
            "not a whole number of 50-byte triangles".to_owned()
        }
    };
    if len < need {
        return Err(truncated(
            path,
            format!(
                "binary STL header says {count} triangles ({need} bytes) but the file has only \
                 {len} bytes ({})",
                holds(len - HEADER as u64)
            ),
        ));
    }
    if len > need {
        return Err(format_err(
            path,
            format!(
                "binary STL header says {count} triangles ({need} bytes) but the file has {len} \
                 bytes ({}); the header's count must match the data",
                holds(len - HEADER as u64)
            ),
        ));
    }
    // stl_io decides ASCII by a leading "solid "; this file is binary whatever its header says.
    let data: Cow<'_, [u8]> = if bytes.starts_with(b"solid") {
        let mut patched = bytes.to_vec();
        if let Some(b) = patched.first_mut() {
            *b = b'_';
        }
        Cow::Owned(patched)
    } else {
        Cow::Borrowed(bytes)
    };
    let mut cursor = Cursor::new(data.as_ref());
    let reader = stl_io::create_stl_reader(&mut cursor)
        .map_err(|e| format_err(path, format!("binary STL: {}", one_line(&e.to_string()))))?;
    let mut raw = RawMesh::default();
    raw.vertices.reserve(count as usize * 3);
    for (i, t) in reader.enumerate() {
        let t = t.map_err(|e| {
            truncated(
                path,
                format!("binary STL triangle {i}: {}", one_line(&e.to_string())),
            )
        })?;
        push_triangle(&mut raw, &t);
    }
    Ok(raw)
}

/// Line number (1-based) and text of each line.
fn lines(bytes: &[u8]) -> impl Iterator<Item = (usize, &[u8])> {
    bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .map(|(i, l)| (i + 1, l))
}

fn first_token(line: &[u8]) -> &[u8] {
    line.split(|b| b.is_ascii_whitespace())
        .find(|t| !t.is_empty())
        .unwrap_or(&[])
}

/// One `solid ... endsolid` block: its first line and the byte range of its body.
struct Solid {
    line: usize,
    body: std::ops::Range<usize>,
    /// Line numbers of its `facet` lines, in order.
    facet_lines: Vec<usize>,
}

fn read_ascii(bytes: &[u8], path: &Path, limits: &ReadLimits) -> Result<RawMesh, IoError> {
    // Split into solids; check that only blank lines follow each `endsolid`.
    let mut solids: Vec<Solid> = Vec::new();
    let mut ended_at: Option<usize> = None;
    let mut offset = 0usize;
    for (no, line) in lines(bytes) {
        let start = offset;
        offset += line.len() + 1;
        let token = first_token(line);
        if token == b"solid" {
            if let Some(prev) = solids.last_mut() {
                prev.body.end = start;
            }
            solids.push(Solid {
                line: no,
                body: (start + line.len() + 1).min(bytes.len())..bytes.len(),
                facet_lines: Vec::new(),
            });
            ended_at = None;
        } else if let Some(end_line) = ended_at {
            if !token.is_empty() {
                return Err(format_err(
                    path,
                    format!(
                        "ascii STL, line {no}: text after the endsolid of line {end_line} that \
                         does not start a new solid"
                    ),
                ));
            }
        } else if token == b"endsolid" {
            ended_at = Some(no);
        } else if token == b"facet" {
            if let Some(s) = solids.last_mut() {
                s.facet_lines.push(no);
            }
        }
    }
    let facets: usize = solids.iter().map(|s| s.facet_lines.len()).sum();
    limits.check_faces(path, facets as u64)?;

    let mut raw = RawMesh::default();
    let mut read = 0usize;
    for s in &solids {
        // stl_io wants a first line "solid <name>"; the body follows unchanged.
        let mut text = b"solid binpick\n".to_vec();
        text.extend_from_slice(bytes.get(s.body.clone()).unwrap_or(&[]));
        let mut cursor = Cursor::new(text);
        let reader = stl_io::create_stl_reader(&mut cursor).map_err(|e| {
            format_err(
                path,
                format!(
                    "ascii STL, solid of line {}: {}",
                    s.line,
                    one_line(&e.to_string())
                ),
            )
        })?;
        for (i, t) in reader.enumerate() {
            let t = t.map_err(|e| {
                let at = s.facet_lines.get(i).map_or_else(
                    || format!("solid of line {}, after facet {}", s.line, read + i),
                    |l| format!("facet {} (line {l})", read + i),
                );
                let message = format!("ascii STL, {at}: {}", one_line(&e.to_string()));
                if e.kind() == std::io::ErrorKind::UnexpectedEof {
                    truncated(path, message)
                } else {
                    format_err(path, message)
                }
            })?;
            push_triangle(&mut raw, &t);
        }
        read += s.facet_lines.len();
    }
    Ok(raw)
}
