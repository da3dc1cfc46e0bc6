//! Part models: a scanned cloud (PCD, PLY without faces) or a CAD mesh (STL, OBJ, PLY with
//! faces), read through one entry point, [`read_model`].
//!
//! Every mesh reader hands its vertices and face corner lists to one builder here, so the
//! checks are the same for all formats: indices in range, finite coordinates, polygons split
//! into triangle fans, zero-area triangles skipped and counted, unused vertices dropped and
//! counted, vertices at the same position merged, and a closed mesh wound inward turned
//! outward.

use std::collections::HashMap;
use std::fmt;
use std::path::Path;

use super::{
    CloudFormat, Encoding, IoError, LoadedCloud, ReadLimits, Sniffed, extension, format_err,
    mesh_err, obj, pcd, ply, read_file_checked, sniff, stl, unsupported_extension,
};
use crate::Units;
use crate::mesh::{TriangleMesh, area_vector};

/// Container format of a mesh file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MeshFormat {
    Stl,
    Obj,
    Ply,
}

impl fmt::Display for MeshFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            MeshFormat::Stl => "STL",
            MeshFormat::Obj => "OBJ",
            MeshFormat::Ply => "PLY",
        })
    }
}

/// What was found while loading a mesh. Nothing is dropped without being counted here.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshReport {
    pub format: MeshFormat,
    /// `Ascii` (ASCII STL, OBJ, ASCII PLY), `BinaryLittleEndian` (binary STL, PLY) or
    /// `BinaryBigEndian` (PLY).
    pub encoding: Encoding,
    /// Vertices stored in the file (for STL, three corners per facet).
    pub vertices_in_file: usize,
    /// Faces stored in the file: STL facets, OBJ `f` lines, PLY `face` elements.
    pub faces_in_file: usize,
    /// Faces with more than three corners, split into triangle fans.
    pub polygons_split: usize,
    /// Triangles skipped because they have no area: zero-area (within f32 rounding) triangles
    /// and faces with fewer than three corners. See [`DEGENERATE_AREA_FRACTION`].
    pub degenerate_skipped: usize,
    /// File vertices that no kept triangle uses; they are not in the mesh.
    pub unused_vertices: usize,
    /// File vertices merged into another at the same position (STL stores every corner).
    pub duplicate_vertices_merged: usize,
    /// Entries that are not surfaces, ignored: OBJ points and lines (`p`, `l`), PLY elements
    /// other than `vertex` and `face` (edges, ...).
    pub other_elements_ignored: usize,
    /// Whether the mesh is closed and consistently wound (every edge shared by exactly two
    /// triangles in opposite directions); only then is "outward" defined.
    pub closed: bool,
    /// Whether every triangle's winding was reversed because the closed mesh was wound
    /// inward (negative enclosed volume), so that normals point out of the part.
    pub winding_reversed: bool,
    /// Surface area of the kept triangles, in the file's units squared.
    pub area: f64,
}

/// A mesh read from a file, with what was found on the way.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedMesh {
    pub mesh: TriangleMesh,
    pub report: MeshReport,
}

/// A part model: a scanned cloud or a CAD mesh.
#[derive(Clone, Debug, PartialEq)]
pub enum Model {
    /// PCD, or PLY without faces.
    Cloud(LoadedCloud),
    /// STL, OBJ, or PLY with at least one face.
    Mesh(LoadedMesh),
}

impl Model {
    /// Converts the coordinates (and a PCD viewpoint) from `units` to millimetres.
    pub fn scale_to_mm(&mut self, units: Units) {
        let f = units.to_mm();
        if f == 1.0 {
            return;
        }
        match self {
            Model::Cloud(c) => {
                c.cloud.scale(f);
                if let Some(v) = &mut c.report.viewpoint {
                    *v = v.scaled(f64::from(f));
                }
            }
            Model::Mesh(m) => {
                m.mesh.scale(f);
                m.report.area *= f64::from(f) * f64::from(f);
            }
        }
    }

    pub fn is_mesh(&self) -> bool {
        matches!(self, Model::Mesh(_))
    }
}

/// A triangle is degenerate (skipped and counted) when its area is at most this fraction of
/// the squared diagonal of the mesh's bounding box. That is zero up to f32 rounding of the
/// corners; such a triangle would receive under 1 % of one sample even at a spacing of
/// diagonal / 10^4.
pub const DEGENERATE_AREA_FRACTION: f64 = 1e-10;

/// Face corner lists as read: flat indices and one corner count per face.
#[derive(Clone, Debug, Default)]
pub(crate) struct FaceLists {
    pub indices: Vec<i64>,
    pub arities: Vec<u32>,
}

impl FaceLists {
    pub fn push(&mut self, corners: &[i64]) {
        self.indices.extend_from_slice(corners);
        self.arities.push(corners.len() as u32);
    }
}

/// A mesh as a reader found it, before the checks.
#[derive(Clone, Debug, Default)]
pub(crate) struct RawMesh {
    pub vertices: Vec<[f64; 3]>,
    pub faces: FaceLists,
    pub other_elements_ignored: usize,
}

fn fmt_point(p: &[f64; 3]) -> String {
    format!("({}, {}, {})", p[0], p[1], p[2])
}

/// Checks a raw mesh and turns it into a [`LoadedMesh`] (see the module doc).
pub(crate) fn build(
    raw: RawMesh,
    path: &Path,
    format: MeshFormat,
    encoding: Encoding,
    limits: &ReadLimits,
) -> Result<LoadedMesh, IoError> {
    let n = raw.vertices.len();
    limits.check_points(path, n as u64)?;
    if n > u32::MAX as usize {
        return Err(mesh_err(
            path,
            format!("{n} vertices: at most 2^32 are supported"),
        ));
    }
    let faces_in_file = raw.faces.arities.len();
    limits.check_faces(path, faces_in_file as u64)?;
    if faces_in_file == 0 {
        return Err(mesh_err(
            path,
            format!("contains no faces ({n} vertices): a mesh model needs triangles"),
        ));
    }

    // Corners as f32 positions; every index checked, every used coordinate finite.
    let mut positions: Vec<Option<[f32; 3]>> = vec![None; n];
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let mut polygons_split = 0usize;
    let mut degenerate = 0usize;
    let mut at = 0usize;
    for (f, &arity) in raw.faces.arities.iter().enumerate() {
        let corners = raw
            .faces
            .indices
            .get(at..at + arity as usize)
            .ok_or_else(|| format_err(path, format!("face {f}: its corner list is cut off")))?;
        at += arity as usize;
        for &i in corners {
            let Some(p) = usize::try_from(i).ok().and_then(|u| raw.vertices.get(u)) else {
                return Err(mesh_err(
                    path,
                    format!(
                        "face {f} refers to vertex {i}, out of range: there are {n} vertices \
                         (indices 0 to {})",
                        n.saturating_sub(1)
                    ),
                ));
            };
            let q = p.map(|c| c as f32);
            if !q.iter().all(|c| c.is_finite()) {
                return Err(mesh_err(
                    path,
                    format!(
                        "face {f} has a corner with a non-finite coordinate {} (or one outside \
                         the f32 range)",
                        fmt_point(p)
                    ),
                ));
            }
            if let Some(slot) = positions.get_mut(i as usize) {
                *slot = Some(q);
            }
        }
        if arity < 3 {
            degenerate += 1;
            continue;
        }
        if arity > 3 {
            polygons_split += 1;
        }
        // Fan triangulation; indices are < n <= u32::MAX (checked below).
        let c = |k: usize| corners.get(k).map_or(0, |&i| i as u32);
        for k in 1..arity as usize - 1 {
            triangles.push([c(0), c(k), c(k + 1)]);
        }
    }
    if triangles.is_empty() {
        return Err(mesh_err(
            path,
            format!(
                "contains no triangles: none of its {faces_in_file} faces has three or more \
                 corners"
            ),
        ));
    }

    // Degenerate triangles, relative to the size of the used part of the mesh.
    let pos = |i: u32| {
        positions
            .get(i as usize)
            .copied()
            .flatten()
            .unwrap_or([0.0; 3])
    };
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in positions.iter().flatten() {
        for k in 0..3 {
            lo[k] = lo[k].min(f64::from(p[k]));
            hi[k] = hi[k].max(f64::from(p[k]));
        }
    }
    let diag2: f64 = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum();
    let min_twice_area = 2.0 * DEGENERATE_AREA_FRACTION * diag2;
    let corners_of = |t: &[u32; 3]| t.map(|i| pos(i).map(f64::from));
    let total = triangles.len();
    triangles.retain(|t| {
        let v = area_vector(&corners_of(t));
        let twice_area = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        twice_area > min_twice_area
    });
    degenerate += total - triangles.len();
    if triangles.is_empty() {
        return Err(mesh_err(
            path,
            format!("all {total} triangles are degenerate (zero area): the mesh has no surface"),
        ));
    }

    // Vertices in order of first use, merged by position (-0 and +0 are one position).
    let mut new_index: HashMap<[u32; 3], u32> = HashMap::new();
    let mut file_used = vec![false; n];
    let mut vertices: Vec<[f32; 3]> = Vec::new();
    for t in &mut triangles {
        for i in t.iter_mut() {
            if let Some(u) = file_used.get_mut(*i as usize) {
                *u = true;
            }
            let p = pos(*i).map(|c| c + 0.0);
            let key = p.map(f32::to_bits);
            *i = *new_index.entry(key).or_insert_with(|| {
                vertices.push(p);
                (vertices.len() - 1) as u32
            });
        }
    }
    let used = file_used.iter().filter(|&&u| u).count();
    let mut mesh = TriangleMesh::new(vertices, triangles);
    let closed = mesh.is_closed();
    let winding_reversed = closed && mesh.signed_volume() < 0.0;
    if winding_reversed {
        mesh.flip();
    }
    let report = MeshReport {
        format,
        encoding,
        vertices_in_file: n,
        faces_in_file,
        polygons_split,
        degenerate_skipped: degenerate,
        unused_vertices: n - used,
        duplicate_vertices_merged: used - mesh.vertices.len(),
        other_elements_ignored: raw.other_elements_ignored,
        closed,
        winding_reversed,
        area: mesh.area(),
    };
    Ok(LoadedMesh { mesh, report })
}

/// What a file name says the model is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Pcd,
    Ply,
    Stl,
    Obj,
}

const MODEL_EXTENSIONS: &str = ".pcd, .ply, .stl and .obj";

fn kind_from_extension(path: &Path) -> Result<Kind, IoError> {
    match extension(path).as_deref() {
        Some("pcd") => Ok(Kind::Pcd),
        Some("ply") => Ok(Kind::Ply),
        Some("stl") => Ok(Kind::Stl),
        Some("obj") => Ok(Kind::Obj),
        _ => Err(unsupported_extension(path, MODEL_EXTENSIONS)),
    }
}

/// Reads a part model with the default [`ReadLimits`]: a cloud from `.pcd` (and `.ply`
/// without faces), a mesh from `.stl` (ASCII or binary), `.obj` and `.ply` with faces.
/// Coordinates are as in the file; see [`Model::scale_to_mm`].
pub fn read_model(path: &Path) -> Result<Model, IoError> {
    read_model_with(path, &ReadLimits::default())
}

/// Like [`read_model`] with explicit limits; headers are checked against them before the
/// rest of the file is loaded.
pub fn read_model_with(path: &Path, limits: &ReadLimits) -> Result<Model, IoError> {
    let kind = kind_from_extension(path)?;
    let bytes = read_file_checked(path, |prefix| match kind {
        Kind::Pcd => pcd::precheck(prefix, path, limits),
        Kind::Ply => ply::precheck(prefix, path, limits, true),
        Kind::Stl => stl::precheck(prefix, path, limits),
        Kind::Obj => Ok(()),
    })?;
    read_model_bytes(&bytes, path, limits)
}

/// Like [`read_model_with`] for a file already in memory; `name` is used in messages and its
/// extension picks the format.
pub fn read_model_from_bytes(
    bytes: &[u8],
    name: &str,
    limits: &ReadLimits,
) -> Result<Model, IoError> {
    read_model_bytes(bytes, Path::new(name), limits)
}

fn read_model_bytes(bytes: &[u8], path: &Path, limits: &ReadLimits) -> Result<Model, IoError> {
    let kind = kind_from_extension(path)?;
    if bytes.is_empty() {
        return Err(format_err(path, "file is empty"));
    }
    let wrong = |ext: &str, actual: &str| IoError::WrongFormat {
        path: path.to_owned(),
        message: format!("has a .{ext} extension but is a {actual} file; rename it"),
    };
    match kind {
        Kind::Pcd | Kind::Ply => {
            let format = if kind == Kind::Pcd {
                CloudFormat::Pcd
            } else {
                CloudFormat::Ply
            };
            // The cloud reader's own checks of extension against content apply first.
            if format == CloudFormat::Ply && sniff(bytes) == Sniffed::Ply {
                return match ply::read_model(bytes, path, limits)? {
                    ply::PlyModel::Cloud(c) => Ok(Model::Cloud(c)),
                    ply::PlyModel::Mesh { raw, encoding } => {
                        build(raw, path, MeshFormat::Ply, encoding, limits).map(Model::Mesh)
                    }
                };
            }
            super::read_bytes(bytes, path, limits).map(Model::Cloud)
        }
        Kind::Stl | Kind::Obj if sniff(bytes) == Sniffed::Ply => {
            Err(wrong(if kind == Kind::Stl { "stl" } else { "obj" }, "PLY"))
        }
        Kind::Stl => {
            let (raw, encoding) = stl::read(bytes, path, limits)?;
            build(raw, path, MeshFormat::Stl, encoding, limits).map(Model::Mesh)
        }
        Kind::Obj => {
            let raw = obj::read(bytes, path, limits)?;
            build(raw, path, MeshFormat::Obj, Encoding::Ascii, limits).map(Model::Mesh)
        }
    }
}
