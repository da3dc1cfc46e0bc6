//! PLY (Stanford polygon format) reading and writing.
//!
//! ply-rs-bw 4.0 parses the header and binary payloads (it caps its pre-allocations, so a
//! lying element count only costs the bytes actually present) and writes every encoding.
//! ASCII payloads are parsed here: ply-rs-bw's ASCII grammar rejects `nan`, `inf` and numbers
//! such as `.5` or `5.`, so it cannot read back the `NaN` its own writer prints.

use std::path::Path;

use ply_rs_bw::parser::{ParseError, Parser, Reader};
use ply_rs_bw::ply::{
    Addable, ElementDef, Encoding as FileEncoding, Header, PropertyAccess, PropertyAccessResult,
    PropertyDef, PropertyType, ScalarType,
};
use ply_rs_bw::writer::Writer;

use super::model::{FaceLists, RawMesh};
use super::{
    CloudFormat, Collector, Encoding, IoError, LoadReport, LoadedCloud, PlyEncoding, ReadLimits,
    format_err, numbered_lines, one_line, show, truncated,
};
use crate::PointCloud;

/// Names of the colour properties, in the order red, green, blue.
const COLOR_NAMES: [[&str; 3]; 2] = [
    ["red", "green", "blue"],
    ["diffuse_red", "diffuse_green", "diffuse_blue"],
];

/// Converts a colour value: integers are clamped to 0..=255, floats are taken as 0..=1.
fn color_component(v: f64, is_float: bool) -> u8 {
    let v = if is_float { v * 255.0 } else { v };
    if v.is_nan() {
        0
    } else {
        v.round().clamp(0.0, 255.0) as u8
    }
}

/// One decoded vertex: coordinates and colour, everything else ignored.
struct Vertex {
    p: [f64; 3],
    c: [u8; 3],
}

impl Vertex {
    fn set(&mut self, name: &str, v: f64, is_float: bool) -> PropertyAccessResult {
        match name {
            "x" => self.p[0] = v,
            "y" => self.p[1] = v,
            "z" => self.p[2] = v,
            _ => {
                let Some(channel) = COLOR_NAMES
                    .iter()
                    .find_map(|names| names.iter().position(|n| *n == name))
                else {
                    return PropertyAccessResult::Ignored;
                };
                if let Some(slot) = self.c.get_mut(channel) {
                    *slot = color_component(v, is_float);
                }
            }
        }
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for Vertex {
    fn new() -> Self {
        Vertex {
            p: [0.0; 3],
            c: [0; 3],
        }
    }
    fn set_char(&mut self, name: &str, v: i8) -> PropertyAccessResult {
        self.set(name, f64::from(v), false)
    }
    fn set_uchar(&mut self, name: &str, v: u8) -> PropertyAccessResult {
        self.set(name, f64::from(v), false)
    }
    fn set_short(&mut self, name: &str, v: i16) -> PropertyAccessResult {
        self.set(name, f64::from(v), false)
    }
    fn set_ushort(&mut self, name: &str, v: u16) -> PropertyAccessResult {
        self.set(name, f64::from(v), false)
    }
    fn set_int(&mut self, name: &str, v: i32) -> PropertyAccessResult {
        self.set(name, f64::from(v), false)
    }
    fn set_uint(&mut self, name: &str, v: u32) -> PropertyAccessResult {
        self.set(name, f64::from(v), false)
    }
    fn set_float(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        self.set(name, f64::from(v), true)
    }
    fn set_double(&mut self, name: &str, v: f64) -> PropertyAccessResult {
        self.set(name, v, true)
    }
}

/// An element whose values are read (to move past them) and dropped.
struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

fn scalar_size(t: &ScalarType) -> u64 {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

fn is_float(t: &ScalarType) -> bool {
    matches!(t, ScalarType::Float | ScalarType::Double)
}

fn is_blank(bytes: &[u8]) -> bool {
    bytes.iter().all(u8::is_ascii_whitespace)
}

/// ply-rs-bw's messages span several lines and start with a line number that means nothing
/// in binary data.
fn ply_message(e: &ParseError) -> String {
    let s = e.to_string();
    let s = match s.strip_prefix("Line ") {
        Some(rest) => rest.split_once(": ").map_or(rest, |(_, m)| m),
        None => &s,
    };
    one_line(s)
}

/// A face element's corner indices, read when a mesh is wanted.
struct FaceRec {
    corners: Option<Vec<i64>>,
}

impl FaceRec {
    fn set<T: Copy + Into<i64>>(&mut self, name: &str, v: &[T]) -> PropertyAccessResult {
        if FACE_LISTS.contains(&name) {
            self.corners = Some(v.iter().map(|&i| i.into()).collect());
            PropertyAccessResult::Set
        } else {
            PropertyAccessResult::Ignored
        }
    }
}

impl PropertyAccess for FaceRec {
    fn new() -> Self {
        FaceRec { corners: None }
    }
    fn set_list_char(&mut self, name: &str, v: Vec<i8>) -> PropertyAccessResult {
        self.set(name, &v)
    }
    fn set_list_uchar(&mut self, name: &str, v: Vec<u8>) -> PropertyAccessResult {
        self.set(name, &v)
    }
    fn set_list_short(&mut self, name: &str, v: Vec<i16>) -> PropertyAccessResult {
        self.set(name, &v)
    }
    fn set_list_ushort(&mut self, name: &str, v: Vec<u16>) -> PropertyAccessResult {
        self.set(name, &v)
    }
    fn set_list_int(&mut self, name: &str, v: Vec<i32>) -> PropertyAccessResult {
        self.set(name, &v)
    }
    fn set_list_uint(&mut self, name: &str, v: Vec<u32>) -> PropertyAccessResult {
        self.set(name, &v)
    }
}

/// Names of a face's corner-index list (`vertex_indices` is the standard one).
const FACE_LISTS: [&str; 2] = ["vertex_indices", "vertex_index"];

/// The name of the `face` element's corner list, checked to be a list of integers.
fn face_list_name<'h>(header: &'h Header, path: &Path) -> Result<Option<&'h str>, IoError> {
    let Some(face) = header.elements.get("face") else {
        return Ok(None);
    };
    let Some((name, def)) = face
        .properties
        .iter()
        .find(|(n, _)| FACE_LISTS.contains(&n.as_str()))
    else {
        return Err(format_err(
            path,
            "the \"face\" element has no vertex_indices list, so the faces cannot be read",
        ));
    };
    match &def.data_type {
        PropertyType::List(_, t) if !is_float(t) => Ok(Some(name.as_str())),
        _ => Err(format_err(
            path,
            format!("face property {name:?} must be a list of integers (vertex indices)"),
        )),
    }
}

/// What a PLY file holds, decoded.
struct Decoded {
    vertices: Vec<Vertex>,
    /// Corner indices of the `face` element, when faces were asked for and there are any.
    faces: Option<FaceLists>,
    encoding: Encoding,
    fields: Vec<String>,
    has_colors: bool,
    /// Entries of elements other than `vertex` and `face` (edges, ...), read and ignored.
    other_elements: usize,
}

/// Parses the header; returns it with the byte offset where the data starts.
fn parse_header(bytes: &[u8], path: &Path) -> Result<(Header, usize), IoError> {
    let mut reader = Reader::new(bytes);
    let header = Parser::<Vertex>::new()
        .read_header(&mut reader)
        .map_err(|e| {
            format_err(
                path,
                format!("bad PLY header: {}", one_line(&e.to_string())),
            )
        })?;
    let body_len = reader.get_ref().len();
    Ok((header, bytes.len() - body_len))
}

fn face_count(header: &Header) -> usize {
    header.elements.get("face").map_or(0, |f| f.count)
}

/// Checks the header at the start of a file (read before the rest) against `limits`; faces
/// only when a mesh is read. A header that does not parse from this prefix is left for the
/// full read to report.
pub(super) fn precheck(
    prefix: &[u8],
    path: &Path,
    limits: &ReadLimits,
    faces: bool,
) -> Result<(), IoError> {
    let Ok((header, _)) = parse_header(prefix, path) else {
        return Ok(());
    };
    let n = header.elements.get("vertex").map_or(0, |v| v.count);
    limits.check_points(path, n as u64)?;
    if faces {
        limits.check_faces(path, face_count(&header) as u64)?;
    }
    Ok(())
}

fn decode(
    bytes: &[u8],
    path: &Path,
    limits: &ReadLimits,
    want_faces: bool,
) -> Result<Decoded, IoError> {
    let (header, data_start) = parse_header(bytes, path)?;
    let header_bytes = bytes.get(..data_start).unwrap_or(&[]);
    let body = bytes.get(data_start..).unwrap_or(&[]);
    check_header_names(header_bytes, &header, path)?;

    let element_names = || {
        header
            .elements
            .keys()
            .map(String::as_str)
            .collect::<Vec<_>>()
            .join(", ")
    };
    let Some(vertex) = header.elements.get("vertex") else {
        return Err(format_err(
            path,
            format!("no \"vertex\" element (elements: {})", element_names()),
        ));
    };
    let fields: Vec<String> = vertex.properties.keys().cloned().collect();
    for axis in ["x", "y", "z"] {
        match vertex.properties.get(axis).map(|p| &p.data_type) {
            Some(PropertyType::Scalar(_)) => {}
            Some(PropertyType::List(..)) => {
                return Err(format_err(
                    path,
                    format!("vertex property {axis:?} is a list, not a number"),
                ));
            }
            None => {
                return Err(format_err(
                    path,
                    format!(
                        "vertex element has no {axis:?} property (properties: {})",
                        fields.join(" ")
                    ),
                ));
            }
        }
    }
    for (name, def) in &header.elements {
        if def.properties.is_empty() && def.count > 0 {
            return Err(format_err(
                path,
                format!(
                    "element {name:?} has {} entries but no properties",
                    def.count
                ),
            ));
        }
    }
    limits.check_points(path, vertex.count as u64)?;
    let want_faces = want_faces && face_count(&header) > 0;
    if want_faces {
        limits.check_faces(path, face_count(&header) as u64)?;
        face_list_name(&header, path)?;
    }
    let has_colors = COLOR_NAMES.iter().any(|names| {
        names.iter().all(|n| {
            matches!(
                vertex.properties.get(*n).map(|p| &p.data_type),
                Some(PropertyType::Scalar(_))
            )
        })
    });
    let other_elements = header
        .elements
        .iter()
        .filter(|(name, _)| !matches!(name.as_str(), "vertex" | "face"))
        .map(|(_, def)| def.count)
        .sum();

    let mut out = Decoded {
        vertices: Vec::new(),
        faces: want_faces.then(FaceLists::default),
        encoding: Encoding::Ascii,
        fields,
        has_colors,
        other_elements,
    };
    match header.encoding {
        FileEncoding::Ascii => {
            let first_line = header_bytes.iter().filter(|&&b| b == b'\n').count() + 1;
            read_ascii(&header, body, first_line, path, &mut out)?;
        }
        FileEncoding::BinaryLittleEndian => {
            out.encoding = Encoding::BinaryLittleEndian;
            read_binary(&header, body, path, &mut out)?;
        }
        FileEncoding::BinaryBigEndian => {
            out.encoding = Encoding::BinaryBigEndian;
            read_binary(&header, body, path, &mut out)?;
        }
    }
    Ok(out)
}

fn cloud_from(decoded: Decoded, path: &Path) -> Result<LoadedCloud, IoError> {
    let n = decoded.vertices.len();
    if n == 0 {
        return Err(IoError::NoFinitePoints {
            path: path.to_owned(),
            points_in_file: 0,
            non_finite_dropped: 0,
        });
    }
    let mut collector = Collector::new(n, decoded.has_colors);
    for v in &decoded.vertices {
        collector.push(v.p, v.c);
    }
    let report = LoadReport {
        points_in_file: n,
        non_finite_dropped: 0,
        format: CloudFormat::Ply,
        encoding: decoded.encoding,
        width: n,
        height: 1,
        fields: decoded.fields,
        viewpoint: None,
    };
    collector.finish(path, report)
}

pub(super) fn read(bytes: &[u8], path: &Path, limits: &ReadLimits) -> Result<LoadedCloud, IoError> {
    cloud_from(decode(bytes, path, limits, false)?, path)
}

/// A PLY read as a model: a mesh when it has faces, otherwise a cloud.
pub(super) enum PlyModel {
    Cloud(LoadedCloud),
    Mesh { raw: RawMesh, encoding: Encoding },
}

pub(super) fn read_model(
    bytes: &[u8],
    path: &Path,
    limits: &ReadLimits,
) -> Result<PlyModel, IoError> {
    let mut decoded = decode(bytes, path, limits, true)?;
    match decoded.faces.take() {
        Some(faces) => Ok(PlyModel::Mesh {
            raw: RawMesh {
                vertices: decoded.vertices.iter().map(|v| v.p).collect(),
                faces,
                other_elements_ignored: decoded.other_elements,
            },
            encoding: decoded.encoding,
        }),
        None => cloud_from(decoded, path).map(PlyModel::Cloud),
    }
}

/// ply-rs-bw keeps elements and properties in maps, so a repeated name silently replaces the
/// earlier one and the data would be mis-read; compare with the header's lines.
fn check_header_names(header_bytes: &[u8], header: &Header, path: &Path) -> Result<(), IoError> {
    let text = String::from_utf8_lossy(header_bytes);
    let mut elements = 0usize;
    let mut properties = 0usize;
    for line in text.lines() {
        match line.split_ascii_whitespace().next() {
            Some("element") => elements += 1,
            Some("property") => properties += 1,
            _ => {}
        }
    }
    let parsed_properties: usize = header.elements.values().map(|e| e.properties.len()).sum();
    if elements != header.elements.len() || properties != parsed_properties {
        return Err(format_err(
            path,
            "bad PLY header: an element or property name is repeated",
        ));
    }
    Ok(())
}

/// "header says 39 vertices but the data holds 40" when only vertices are stored and the
/// extra data is a whole number of them; empty otherwise.
fn vertex_count_hint(header: &Header, extra_vertices: Option<u64>) -> String {
    let n = header.elements.get("vertex").map_or(0, |v| v.count);
    match extra_vertices {
        Some(extra) if header.elements.len() == 1 && extra > 0 => format!(
            ": header says {n} vertices but the data holds {}",
            (n as u64).saturating_add(extra)
        ),
        _ => String::new(),
    }
}

fn read_binary(
    header: &Header,
    body: &[u8],
    path: &Path,
    out: &mut Decoded,
) -> Result<(), IoError> {
    // Smallest size the data can have (lists counted as empty): a lying count fails here,
    // before anything is read.
    let available = body.len() as u64;
    let mut need = 0u64;
    let mut vertex_size = 0u64;
    for (name, def) in &header.elements {
        let per: u64 = def
            .properties
            .values()
            .map(|p| match &p.data_type {
                PropertyType::Scalar(t) => scalar_size(t),
                PropertyType::List(index, _) => scalar_size(index),
            })
            .sum();
        if name == "vertex" {
            vertex_size = per;
        }
        need = (def.count as u64)
            .checked_mul(per)
            .and_then(|b| need.checked_add(b))
            .ok_or_else(|| format_err(path, "bad PLY header: element counts overflow"))?;
    }
    if need > available {
        let vertex_only = header.elements.len() == 1;
        let n = header.elements.get("vertex").map_or(0, |v| v.count);
        return Err(truncated(
            path,
            if vertex_only {
                format!(
                    "header says {n} vertices of {vertex_size} bytes ({need} bytes) but only \
                     {available} bytes follow"
                )
            } else {
                format!(
                    "header's elements need at least {need} bytes but only {available} bytes \
                     follow"
                )
            },
        ));
    }

    let mut reader = Reader::new(body);
    let map_err = |e: ParseError| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            truncated(path, ply_message(&e))
        } else {
            format_err(path, ply_message(&e))
        }
    };
    for (name, def) in &header.elements {
        if def.count == 0 {
            continue;
        }
        if name == "vertex" {
            out.vertices = Parser::<Vertex>::new()
                .read_payload_for_element(&mut reader, def, header)
                .map_err(map_err)?;
        } else if let (Some(faces), "face") = (out.faces.as_mut(), name.as_str()) {
            let recs = Parser::<FaceRec>::new()
                .read_payload_for_element(&mut reader, def, header)
                .map_err(map_err)?;
            for rec in recs {
                faces.push(rec.corners.as_deref().unwrap_or(&[]));
            }
        } else {
            Parser::<Skip>::new()
                .read_payload_for_element(&mut reader, def, header)
                .map_err(map_err)?;
        }
    }
    let rest = reader.get_ref();
    if !is_blank(rest) {
        let whole = (vertex_size > 0 && rest.len() as u64 % vertex_size == 0)
            .then(|| rest.len() as u64 / vertex_size);
        return Err(format_err(
            path,
            format!(
                "{} bytes of unexpected data after the last element (does the header's element \
                 count match the data?){}",
                rest.len(),
                vertex_count_hint(header, whole)
            ),
        ));
    }
    Ok(())
}

fn read_ascii(
    header: &Header,
    body: &[u8],
    first_line: usize,
    path: &Path,
    out: &mut Decoded,
) -> Result<(), IoError> {
    let n = header.elements.get("vertex").map_or(0, |v| v.count);
    // A vertex line has at least three values and two separators.
    out.vertices = Vec::with_capacity(n.min(body.len() / 6 + 1));
    let mut lines = numbered_lines(body, first_line).filter(|(_, l)| !is_blank(l));
    for (name, def) in &header.elements {
        let is_vertex = name == "vertex";
        let is_face = name == "face" && out.faces.is_some();
        let mut corners: Vec<i64> = Vec::new();
        for i in 0..def.count {
            let Some((line_no, raw)) = lines.next() else {
                return Err(truncated(
                    path,
                    format!(
                        "header says {} {name:?} elements but the data ends after {i}",
                        def.count
                    ),
                ));
            };
            let line = std::str::from_utf8(raw).map_err(|_| {
                format_err(
                    path,
                    format!("line {line_no}: data is not text (invalid UTF-8)"),
                )
            })?;
            let mut tokens = line.split_ascii_whitespace();
            let too_few = || {
                format_err(
                    path,
                    format!(
                        "line {line_no}: {name} element {i} has too few values for its {} \
                         properties",
                        def.properties.len()
                    ),
                )
            };
            let mut vertex = Vertex::new();
            corners.clear();
            for (prop, pdef) in &def.properties {
                let bad = |tok: &str| {
                    format_err(
                        path,
                        format!(
                            "line {line_no}: value {} of property {prop:?} is not a number",
                            show(tok.as_bytes())
                        ),
                    )
                };
                match &pdef.data_type {
                    PropertyType::Scalar(t) => {
                        let tok = tokens.next().ok_or_else(too_few)?;
                        // Parse float directly as f32: going through f64 could round twice.
                        let v = if matches!(t, ScalarType::Float) {
                            tok.parse::<f32>().map(f64::from)
                        } else {
                            tok.parse::<f64>()
                        }
                        .map_err(|_| bad(tok))?;
                        if is_vertex {
                            vertex.set(prop, v, is_float(t));
                        }
                    }
                    PropertyType::List(_, _) => {
                        let tok = tokens.next().ok_or_else(too_few)?;
                        let len: u64 = tok.parse().map_err(|_| {
                            format_err(
                                path,
                                format!(
                                    "line {line_no}: list length {} of property {prop:?} is not \
                                     a non-negative integer",
                                    show(tok.as_bytes())
                                ),
                            )
                        })?;
                        let is_corners = is_face && FACE_LISTS.contains(&prop.as_str());
                        for _ in 0..len {
                            let tok = tokens.next().ok_or_else(too_few)?;
                            if is_corners {
                                corners.push(tok.parse::<i64>().map_err(|_| {
                                    format_err(
                                        path,
                                        format!(
                                            "line {line_no}: vertex index {} of face {i} is not \
                                             an integer",
                                            show(tok.as_bytes())
                                        ),
                                    )
                                })?);
                            } else {
                                tok.parse::<f64>().map_err(|_| bad(tok))?;
                            }
                        }
                    }
                }
            }
            if tokens.next().is_some() {
                return Err(format_err(
                    path,
                    format!(
                        "line {line_no}: {name} element {i} has more values than its {} \
                         properties",
                        def.properties.len()
                    ),
                ));
            }
            if is_vertex {
                out.vertices.push(vertex);
            } else if let (true, Some(faces)) = (is_face, out.faces.as_mut()) {
                faces.push(&corners);
            }
        }
    }
    if let Some((line_no, _)) = lines.next() {
        let extra = 1 + lines.count() as u64;
        return Err(format_err(
            path,
            format!(
                "line {line_no}: unexpected data after the last element (does the header's \
                 element count match the data?){}",
                vertex_count_hint(header, Some(extra))
            ),
        ));
    }
    Ok(())
}

/// A vertex to write.
struct OutVertex {
    p: [f32; 3],
    c: [u8; 3],
}

impl PropertyAccess for OutVertex {
    fn new() -> Self {
        OutVertex {
            p: [0.0; 3],
            c: [0; 3],
        }
    }
    fn get_float(&self, name: &str) -> Option<f32> {
        match name {
            "x" => Some(self.p[0]),
            "y" => Some(self.p[1]),
            "z" => Some(self.p[2]),
            _ => None,
        }
    }
    fn get_uchar(&self, name: &str) -> Option<u8> {
        match name {
            "red" => Some(self.c[0]),
            "green" => Some(self.c[1]),
            "blue" => Some(self.c[2]),
            _ => None,
        }
    }
}

/// Encodes a cloud as PLY; `colors` has been checked to match the cloud.
pub(super) fn encode(
    cloud: &PointCloud,
    encoding: PlyEncoding,
    colors: Option<&[[u8; 3]]>,
) -> Result<Vec<u8>, String> {
    let mut header = Header::new();
    header.encoding = match encoding {
        PlyEncoding::Ascii => FileEncoding::Ascii,
        PlyEncoding::BinaryLittleEndian => FileEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian => FileEncoding::BinaryBigEndian,
    };
    header.comments.push("written by binpick".to_owned());
    let mut vertex = ElementDef::new("vertex".to_owned());
    vertex.count = cloud.len();
    for name in ["x", "y", "z"] {
        vertex.properties.add(PropertyDef::new(
            name.to_owned(),
            PropertyType::Scalar(ScalarType::Float),
        ));
    }
    if colors.is_some() {
        for name in ["red", "green", "blue"] {
            vertex.properties.add(PropertyDef::new(
                name.to_owned(),
                PropertyType::Scalar(ScalarType::UChar),
            ));
        }
    }
    header.elements.add(vertex.clone());

    let writer = Writer::<OutVertex>::new();
    let mut out = Vec::with_capacity(256 + cloud.len() * 15);
    let err = |e: std::io::Error| format!("ply-rs-bw: {e}");
    writer.write_header(&mut out, &header).map_err(err)?;
    for (i, p) in cloud.points.iter().enumerate() {
        let v = OutVertex {
            p: *p,
            c: colors.and_then(|c| c.get(i)).copied().unwrap_or([0; 3]),
        };
        match encoding {
            PlyEncoding::Ascii => writer.write_ascii_element(&mut out, &v, &vertex),
            PlyEncoding::BinaryLittleEndian => {
                writer.write_little_endian_element(&mut out, &v, &vertex)
            }
            PlyEncoding::BinaryBigEndian => writer.write_big_endian_element(&mut out, &v, &vertex),
        }
        .map_err(err)?;
    }
    Ok(out)
}
