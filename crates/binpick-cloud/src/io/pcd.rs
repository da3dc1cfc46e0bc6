//! PCD (PCL's Point Cloud Data format) reading and writing.
//!
//! The header is parsed and validated here: pcd-rs 0.13 trusts it and panics on some lying
//! headers (a compressed file whose POINTS exceed its data indexes out of bounds), aborts the
//! process on others (a padding field with a huge COUNT allocates COUNT bytes), overflows
//! when COUNTs add up past `usize` in ASCII, and reports bad numbers without saying which
//! line. Once the header is known to be consistent with the bytes that follow, pcd-rs's
//! `Reader` decodes binary and LZF-compressed data (it is fed a normalised copy of the header
//! followed by the validated data) into a record type of ours that allocates nothing per
//! point. ASCII data is parsed here, following PCL: blank lines are skipped; an integer `rgb`
//! token is the packed colour.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Cursor, Read};
use std::path::Path;

use pcd_rs::{
    DataKind, DynRecord, DynWriter, Field, PcdDeserialize, Reader, Schema, ValueKind, WriterInit,
};

use super::{
    CloudFormat, Collector, IoError, LoadReport, LoadedCloud, PcdEncoding, ReadLimits, Viewpoint,
    fmt_f32, format_err, numbered_lines, one_line, pack_rgb, show, truncated, unpack_rgb,
};
use crate::PointCloud;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    F,
    U,
    I,
}

#[derive(Clone, Debug)]
struct FieldSpec {
    name: String,
    kind: Kind,
    size: usize,
    count: usize,
}

impl FieldSpec {
    fn type_char(&self) -> char {
        match self.kind {
            Kind::F => 'F',
            Kind::U => 'U',
            Kind::I => 'I',
        }
    }
}

#[derive(Debug)]
struct Header {
    fields: Vec<FieldSpec>,
    width: u64,
    height: u64,
    points: u64,
    data: PcdEncoding,
    /// Bytes per point in binary data.
    point_size: usize,
    /// Values per point in ASCII data.
    values_per_point: usize,
    /// Offset of the first data byte.
    data_start: usize,
    /// Number of header lines (for line numbers in ASCII data errors).
    lines: usize,
    /// Indices into `fields` of x, y, z.
    xyz: [usize; 3],
    /// Index into `fields` of the colour field (`rgb` or `rgba`, 4 bytes, COUNT 1).
    color: Option<usize>,
    /// The `VIEWPOINT` line, when present.
    viewpoint: Option<Viewpoint>,
}

/// One header line: its number and its whitespace-separated tokens (keyword first).
struct Entry {
    line: usize,
    tokens: Vec<String>,
}

impl Entry {
    fn values(&self) -> &[String] {
        self.tokens.get(1..).unwrap_or(&[])
    }
}

const KEYWORDS: [&str; 11] = [
    "VERSION",
    "FIELDS",
    "COLUMNS",
    "SIZE",
    "TYPE",
    "COUNT",
    "WIDTH",
    "HEIGHT",
    "VIEWPOINT",
    "POINTS",
    "DATA",
];

fn parse_header(bytes: &[u8], path: &Path) -> Result<Header, IoError> {
    let mut entries: HashMap<&'static str, Entry> = HashMap::new();
    let mut pos = 0usize;
    let mut line_no = 0usize;
    loop {
        if pos >= bytes.len() {
            return Err(format_err(
                path,
                format!(
                    "not a valid PCD file: the header ends after {line_no} lines without a \
                     DATA line"
                ),
            ));
        }
        let rest = bytes.get(pos..).unwrap_or(&[]);
        let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        let raw = rest.get(..len).unwrap_or(&[]);
        pos = pos.saturating_add(len + 1).min(bytes.len());
        line_no += 1;
        let line = std::str::from_utf8(raw).map_err(|_| {
            format_err(
                path,
                format!(
                    "not a valid PCD file: header line {line_no} is not text (invalid UTF-8) \
                     and no DATA line came before it"
                ),
            )
        })?;
        let content = line.find('#').map_or(line, |i| line.get(..i).unwrap_or(""));
        let tokens: Vec<String> = content
            .split_ascii_whitespace()
            .map(str::to_owned)
            .collect();
        let Some(first) = tokens.first() else {
            continue;
        };
        let upper = first.to_ascii_uppercase();
        // PCL ignores lines it does not know; so do we.
        let Some(&key) = KEYWORDS.iter().find(|k| **k == upper) else {
            continue;
        };
        let key = if key == "COLUMNS" { "FIELDS" } else { key };
        if let Some(prev) = entries.get(key) {
            return Err(format_err(
                path,
                format!(
                    "header line {line_no}: second {key} line (the first is line {})",
                    prev.line
                ),
            ));
        }
        entries.insert(
            key,
            Entry {
                line: line_no,
                tokens,
            },
        );
        if key == "DATA" {
            break;
        }
    }
    let data_start = pos;
    let header_lines = line_no;

    let get = |key: &str| -> Result<&Entry, IoError> {
        entries.get(key).ok_or_else(|| {
            format_err(
                path,
                format!("header has no {key} line (needed before DATA)"),
            )
        })
    };

    // DATA
    let data_entry = get("DATA")?;
    let data = match data_entry.values() {
        [v] => match v.to_ascii_lowercase().as_str() {
            "ascii" => PcdEncoding::Ascii,
            "binary" => PcdEncoding::Binary,
            "binary_compressed" => PcdEncoding::BinaryCompressed,
            _ => {
                return Err(format_err(
                    path,
                    format!(
                        "header line {}: unknown DATA encoding {} (expected ascii, binary or \
                         binary_compressed)",
                        data_entry.line,
                        show(v.as_bytes())
                    ),
                ));
            }
        },
        vals => {
            return Err(format_err(
                path,
                format!(
                    "header line {}: DATA needs one value, found {}",
                    data_entry.line,
                    vals.len()
                ),
            ));
        }
    };

    // FIELDS
    let fields_entry = get("FIELDS")?;
    let names = fields_entry.values();
    if names.is_empty() {
        return Err(format_err(
            path,
            format!("header line {}: FIELDS lists no field", fields_entry.line),
        ));
    }
    for (i, n) in names.iter().enumerate() {
        if n != "_" && names.get(..i).unwrap_or(&[]).contains(n) {
            return Err(format_err(
                path,
                format!(
                    "header line {}: field {} is listed twice",
                    fields_entry.line,
                    show(n.as_bytes())
                ),
            ));
        }
    }
    let per_field = |key: &str| -> Result<Option<&Entry>, IoError> {
        let Some(e) = entries.get(key) else {
            return Ok(None);
        };
        if e.values().len() != names.len() {
            return Err(format_err(
                path,
                format!(
                    "header line {}: {key} has {} entries but FIELDS has {}",
                    e.line,
                    e.values().len(),
                    names.len()
                ),
            ));
        }
        Ok(Some(e))
    };
    let size_entry =
        per_field("SIZE")?.ok_or_else(|| format_err(path, "header has no SIZE line"))?;
    let type_entry =
        per_field("TYPE")?.ok_or_else(|| format_err(path, "header has no TYPE line"))?;
    let count_entry = per_field("COUNT")?;

    let mut fields = Vec::with_capacity(names.len());
    let mut point_size = 0usize;
    let mut values_per_point = 0usize;
    for (i, name) in names.iter().enumerate() {
        let size_tok = size_entry.values().get(i).map_or("", String::as_str);
        let type_tok = type_entry.values().get(i).map_or("", String::as_str);
        let size: usize = size_tok.parse().map_err(|_| {
            format_err(
                path,
                format!(
                    "header line {}: SIZE {} of field {} is not a number",
                    size_entry.line,
                    show(size_tok.as_bytes()),
                    show(name.as_bytes())
                ),
            )
        })?;
        let kind = match type_tok.to_ascii_uppercase().as_str() {
            "F" => Kind::F,
            "U" => Kind::U,
            "I" => Kind::I,
            _ => {
                return Err(format_err(
                    path,
                    format!(
                        "header line {}: TYPE {} of field {} is not F, U or I",
                        type_entry.line,
                        show(type_tok.as_bytes()),
                        show(name.as_bytes())
                    ),
                ));
            }
        };
        let valid = match kind {
            Kind::F => matches!(size, 4 | 8),
            Kind::U | Kind::I => matches!(size, 1 | 2 | 4 | 8),
        };
        if !valid {
            return Err(format_err(
                path,
                format!(
                    "header line {}: field {} has TYPE {type_tok} with SIZE {size}, which is not \
                     a PCD type (F needs SIZE 4 or 8, U and I need 1, 2, 4 or 8)",
                    size_entry.line,
                    show(name.as_bytes())
                ),
            ));
        }
        let count = match count_entry {
            None => 1,
            Some(e) => {
                let tok = e.values().get(i).map_or("", String::as_str);
                let c: u64 = tok.parse().map_err(|_| {
                    format_err(
                        path,
                        format!(
                            "header line {}: COUNT {} of field {} is not a non-negative integer",
                            e.line,
                            show(tok.as_bytes()),
                            show(name.as_bytes())
                        ),
                    )
                })?;
                // PCL reads COUNT 0 as 1.
                usize::try_from(c.max(1)).map_err(|_| {
                    format_err(
                        path,
                        format!("header line {}: COUNT {c} is too large", e.line),
                    )
                })?
            }
        };
        let too_big = || {
            format_err(
                path,
                "header's fields are too large: the point size overflows".to_owned(),
            )
        };
        point_size = size
            .checked_mul(count)
            .and_then(|b| point_size.checked_add(b))
            .ok_or_else(too_big)?;
        values_per_point = values_per_point.checked_add(count).ok_or_else(too_big)?;
        fields.push(FieldSpec {
            name: name.clone(),
            kind,
            size,
            count,
        });
    }

    let mut xyz = [0usize; 3];
    for (axis, want) in ["x", "y", "z"].iter().enumerate() {
        let Some(i) = fields.iter().position(|f| f.name == *want) else {
            return Err(format_err(
                path,
                format!(
                    "no {want:?} field: a point cloud needs x, y and z (FIELDS: {})",
                    names.join(" ")
                ),
            ));
        };
        if fields.get(i).is_some_and(|f| f.count != 1) {
            return Err(format_err(
                path,
                format!("field {want:?} must have COUNT 1"),
            ));
        }
        if let Some(slot) = xyz.get_mut(axis) {
            *slot = i;
        }
    }
    let color = ["rgb", "rgba"].iter().find_map(|want| {
        fields
            .iter()
            .position(|f| f.name == *want && f.size == 4 && f.count == 1)
    });

    // WIDTH / HEIGHT / POINTS
    let number = |key: &str| -> Result<Option<u64>, IoError> {
        let Some(e) = entries.get(key) else {
            return Ok(None);
        };
        match e.values() {
            [v] => v.parse::<u64>().map(Some).map_err(|_| {
                format_err(
                    path,
                    format!(
                        "header line {}: {key} {} is not a non-negative integer",
                        e.line,
                        show(v.as_bytes())
                    ),
                )
            }),
            vals => Err(format_err(
                path,
                format!(
                    "header line {}: {key} needs one value, found {}",
                    e.line,
                    vals.len()
                ),
            )),
        }
    };
    let width = number("WIDTH")?;
    let height = number("HEIGHT")?;
    let points = number("POINTS")?;
    let (width, height, points) = match (width, height.unwrap_or(1), points) {
        (Some(w), h, Some(p)) => (w, h, p),
        (Some(w), h, None) => (
            w,
            h,
            w.checked_mul(h)
                .ok_or_else(|| format_err(path, format!("WIDTH {w} x HEIGHT {h} overflows")))?,
        ),
        (None, 1, Some(p)) => (p, 1, p),
        (None, _, _) => {
            return Err(format_err(path, "header has no WIDTH line"));
        }
    };
    if width.checked_mul(height) != Some(points) {
        return Err(format_err(
            path,
            format!(
                "header is inconsistent: WIDTH {width} x HEIGHT {height} is not POINTS {points}"
            ),
        ));
    }
    let viewpoint = entries
        .get("VIEWPOINT")
        .map(|e| parse_viewpoint(e, path))
        .transpose()?;

    Ok(Header {
        fields,
        width,
        height,
        points,
        data,
        point_size,
        values_per_point,
        data_start,
        lines: header_lines,
        xyz,
        color,
        viewpoint,
    })
}

/// `VIEWPOINT tx ty tz qw qx qy qz`; the quaternion is normalised (PCL stores it as given).
fn parse_viewpoint(e: &Entry, path: &Path) -> Result<Viewpoint, IoError> {
    let bad = |what: String| {
        format_err(
            path,
            format!(
                "header line {}: VIEWPOINT {what} (expected 7 numbers: tx ty tz qw qx qy qz)",
                e.line
            ),
        )
    };
    let vals = e.values();
    if vals.len() != 7 {
        return Err(bad(format!("has {} values", vals.len())));
    }
    let mut v = [0.0f64; 7];
    for (slot, tok) in v.iter_mut().zip(vals) {
        *slot = tok
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| {
                bad(format!(
                    "value {} is not a finite number",
                    show(tok.as_bytes())
                ))
            })?;
    }
    let [tx, ty, tz, qw, qx, qy, qz] = v;
    let norm = (qw * qw + qx * qx + qy * qy + qz * qz).sqrt();
    if !(norm > 1e-12 && norm.is_finite()) {
        return Err(bad("has a zero orientation quaternion".to_owned()));
    }
    Ok(Viewpoint {
        position: [tx, ty, tz],
        orientation_wxyz: [qw / norm, qx / norm, qy / norm, qz / norm],
    })
}

/// Checks the header at the start of a file (read before the rest) against `limits`. A header
/// that does not parse from this prefix is left for the full read to report.
pub(super) fn precheck(prefix: &[u8], path: &Path, limits: &ReadLimits) -> Result<(), IoError> {
    match parse_header(prefix, path) {
        Ok(h) => limits.check_points(path, h.points),
        Err(_) => Ok(()),
    }
}

pub(super) fn read(bytes: &[u8], path: &Path, limits: &ReadLimits) -> Result<LoadedCloud, IoError> {
    let h = parse_header(bytes, path)?;
    limits.check_points(path, h.points)?;
    let too_many = || format_err(path, format!("POINTS {} is too large", h.points));
    let points = usize::try_from(h.points).map_err(|_| too_many())?;
    let width = usize::try_from(h.width).map_err(|_| too_many())?;
    let height = usize::try_from(h.height).map_err(|_| too_many())?;
    if points == 0 {
        return Err(IoError::NoFinitePoints {
            path: path.to_owned(),
            points_in_file: 0,
            non_finite_dropped: 0,
        });
    }
    let data = bytes.get(h.data_start..).unwrap_or(&[]);
    let collector = match h.data {
        PcdEncoding::Ascii => read_ascii(&h, data, path)?,
        PcdEncoding::Binary => {
            let need = binary_size(&h, path)?;
            if need > data.len() as u64 {
                return Err(truncated(
                    path,
                    format!(
                        "header says {} points of {} bytes ({need} bytes) but only {} bytes follow",
                        h.points,
                        h.point_size,
                        data.len()
                    ),
                ));
            }
            let after = data.get(need as usize..).unwrap_or(&[]);
            check_after_binary(&h, after, path)?;
            read_records(&h, data, path)?
        }
        PcdEncoding::BinaryCompressed => {
            let block = check_compressed(&h, data, path)?;
            let after = data.get(block.len()..).unwrap_or(&[]);
            if !is_zero_padding(after) {
                return Err(format_err(
                    path,
                    format!(
                        "{} bytes of data follow the compressed block of POINTS {} points (only \
                         zero padding may follow it)",
                        after.len(),
                        h.points
                    ),
                ));
            }
            read_records(&h, block, path)?
        }
    };
    let report = LoadReport {
        points_in_file: points,
        non_finite_dropped: 0,
        format: CloudFormat::Pcd,
        encoding: h.data.into(),
        width,
        height,
        fields: h.fields.iter().map(|f| f.name.clone()).collect(),
        viewpoint: h.viewpoint,
    };
    collector.finish(path, report)
}

/// PCL pads files with zero bytes after the data; anything else there means the header's
/// counts do not describe the data.
fn is_zero_padding(bytes: &[u8]) -> bool {
    bytes.iter().all(|&b| b == 0)
}

/// Binary data longer than `POINTS` x point size: zero padding is fine, more points are an
/// error that states both counts (reading only the first `POINTS` would lose data silently).
fn check_after_binary(h: &Header, after: &[u8], path: &Path) -> Result<(), IoError> {
    if is_zero_padding(after) {
        return Ok(());
    }
    let ps = h.point_size.max(1);
    let shape = if h.height > 1 {
        format!(" (WIDTH {} x HEIGHT {})", h.width, h.height)
    } else {
        String::new()
    };
    let message = if after.len() % ps == 0 {
        format!(
            "header says POINTS {}{shape} but the data holds {} points of {} bytes; the header's \
             counts must match the data",
            h.points,
            h.points.saturating_add((after.len() / ps) as u64),
            h.point_size
        )
    } else {
        format!(
            "header says POINTS {}{shape} ({} bytes of {}-byte points) but {} more bytes of data \
             follow them (not zero padding, and not a whole number of points)",
            h.points,
            h.points.saturating_mul(h.point_size as u64),
            h.point_size,
            after.len()
        )
    };
    Err(format_err(path, message))
}

/// Bytes the binary data of all points take.
fn binary_size(h: &Header, path: &Path) -> Result<u64, IoError> {
    h.points.checked_mul(h.point_size as u64).ok_or_else(|| {
        format_err(
            path,
            format!(
                "header says {} points of {} bytes, which overflows",
                h.points, h.point_size
            ),
        )
    })
}

/// Checks the size prefix and LZF stream of a `binary_compressed` data section against the
/// header, without allocating; returns the prefix and stream (what pcd-rs reads).
fn check_compressed<'a>(h: &Header, data: &'a [u8], path: &Path) -> Result<&'a [u8], IoError> {
    let (Some(cs), Some(us)) = (read_u32(data, 0), read_u32(data, 4)) else {
        return Err(truncated(
            path,
            format!(
                "binary_compressed data starts with two 4-byte sizes but only {} bytes follow \
                 the header",
                data.len()
            ),
        ));
    };
    let available = data.len() - 8;
    if cs as usize > available {
        return Err(truncated(
            path,
            format!("compressed block of {cs} bytes announced but only {available} bytes follow"),
        ));
    }
    let need = binary_size(h, path)?;
    if u64::from(us) != need {
        let ps = h.point_size.max(1) as u64;
        let holds = if u64::from(us) % ps == 0 {
            format!(", i.e. {} points", u64::from(us) / ps)
        } else {
            ", not a whole number of points".to_owned()
        };
        return Err(format_err(
            path,
            format!(
                "header says POINTS {} ({need} bytes of {}-byte points) but the compressed block \
                 unpacks to {us} bytes{holds}",
                h.points, h.point_size
            ),
        ));
    }
    let block = data.get(..8 + cs as usize).unwrap_or(data);
    let stream = block.get(8..).unwrap_or(&[]);
    let decoded = lzf_decoded_len(stream)
        .map_err(|e| format_err(path, format!("corrupt binary_compressed data: {e}")))?;
    if decoded != u64::from(us) {
        return Err(format_err(
            path,
            format!(
                "corrupt binary_compressed data: the LZF stream unpacks to {decoded} bytes, not \
                 the {us} bytes announced"
            ),
        ));
    }
    Ok(block)
}

fn read_u32(data: &[u8], at: usize) -> Option<u32> {
    let b: [u8; 4] = data.get(at..at + 4)?.try_into().ok()?;
    Some(u32::from_le_bytes(b))
}

/// Walks an LZF stream and returns the length it decodes to, without decoding it. Fails on
/// a stream that runs past its end or refers back before its start.
fn lzf_decoded_len(input: &[u8]) -> Result<u64, String> {
    let mut i = 0usize;
    let mut out = 0u64;
    while let Some(&ctrl) = input.get(i) {
        let at = i;
        i += 1;
        let ctrl = usize::from(ctrl);
        if ctrl < 32 {
            let len = ctrl + 1;
            if input.len() - i < len {
                return Err(format!(
                    "literal run of {len} bytes at offset {at} runs past the end of the stream"
                ));
            }
            i += len;
            out += len as u64;
        } else {
            let mut len = ctrl >> 5;
            if len == 7 {
                let &extra = input
                    .get(i)
                    .ok_or_else(|| format!("back reference at offset {at} is cut off"))?;
                len += usize::from(extra);
                i += 1;
            }
            len += 2;
            let &low = input
                .get(i)
                .ok_or_else(|| format!("back reference at offset {at} is cut off"))?;
            i += 1;
            let distance = ((ctrl & 0x1f) << 8) + usize::from(low) + 1;
            if distance as u64 > out {
                return Err(format!(
                    "back reference at offset {at} points {distance} bytes back but only {out} \
                     bytes were decoded"
                ));
            }
            out += len as u64;
        }
    }
    Ok(out)
}

/// The header pcd-rs is given: the validated fields, one row of POINTS points.
fn normalised_header(h: &Header) -> String {
    let join =
        |f: &dyn Fn(&FieldSpec) -> String| h.fields.iter().map(f).collect::<Vec<_>>().join(" ");
    format!(
        "VERSION 0.7\nFIELDS {}\nSIZE {}\nTYPE {}\nCOUNT {}\nWIDTH {p}\nHEIGHT 1\n\
         VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {p}\nDATA {}\n",
        join(&|f| f.name.clone()),
        join(&|f| f.size.to_string()),
        join(&|f| f.type_char().to_string()),
        join(&|f| f.count.to_string()),
        match h.data {
            PcdEncoding::BinaryCompressed => "binary_compressed",
            _ => "binary",
        },
        p = h.points,
    )
}

/// One decoded point: the record type pcd-rs's `Reader` produces for us. It implements
/// pcd-rs's `PcdDeserialize` by hand so that no memory is allocated per point (pcd-rs's
/// `DynRecord` allocates one `Vec` per field per point, which made a 640 x 480 scene take
/// five times longer).
struct PointRecord {
    xyz: [f64; 3],
    /// The coordinates when all three are `F4` (kept bit for bit).
    xyz_f32: Option<[f32; 3]>,
    rgb: Option<u32>,
    rgba: Option<u32>,
}

fn read_array<const N: usize, R: Read>(r: &mut R) -> std::io::Result<[u8; N]> {
    let mut b = [0u8; N];
    r.read_exact(&mut b)?;
    Ok(b)
}

/// Reads one value of `kind` as `f64`, with the `f32` itself for `F32`.
fn read_value<R: Read>(r: &mut R, kind: ValueKind) -> std::io::Result<(f64, Option<f32>)> {
    Ok(match kind {
        ValueKind::U8 => (f64::from(read_array::<1, _>(r)?[0]), None),
        ValueKind::I8 => (f64::from(i8::from_le_bytes(read_array(r)?)), None),
        ValueKind::U16 => (f64::from(u16::from_le_bytes(read_array(r)?)), None),
        ValueKind::I16 => (f64::from(i16::from_le_bytes(read_array(r)?)), None),
        ValueKind::U32 => (f64::from(u32::from_le_bytes(read_array(r)?)), None),
        ValueKind::I32 => (f64::from(i32::from_le_bytes(read_array(r)?)), None),
        ValueKind::U64 => (u64::from_le_bytes(read_array(r)?) as f64, None),
        ValueKind::I64 => (i64::from_le_bytes(read_array(r)?) as f64, None),
        ValueKind::F32 => {
            let v = f32::from_le_bytes(read_array(r)?);
            (f64::from(v), Some(v))
        }
        ValueKind::F64 => (f64::from_le_bytes(read_array(r)?), None),
    })
}

/// Skips `n` bytes without allocating.
fn skip<R: BufRead>(r: &mut R, n: u64) -> std::io::Result<()> {
    let skipped = std::io::copy(&mut r.by_ref().take(n), &mut std::io::sink())?;
    if skipped < n {
        return Err(std::io::ErrorKind::UnexpectedEof.into());
    }
    Ok(())
}

impl PcdDeserialize for PointRecord {
    fn is_dynamic() -> bool {
        // Any schema: the fields are picked by name in `read_chunk`.
        true
    }

    fn read_spec() -> Vec<(Option<String>, ValueKind, Option<usize>)> {
        Vec::new()
    }

    fn read_chunk<R: BufRead>(reader: &mut R, field_defs: &Schema) -> pcd_rs::Result<Self> {
        let mut rec = PointRecord {
            xyz: [0.0; 3],
            xyz_f32: None,
            rgb: None,
            rgba: None,
        };
        let mut f32s = [None; 3];
        for def in field_defs.iter() {
            let axis = match def.name.as_str() {
                "x" => Some(0),
                "y" => Some(1),
                "z" => Some(2),
                _ => None,
            };
            match (axis, def.name.as_str()) {
                (Some(axis), _) if def.count == 1 => {
                    let (v, f) = read_value(reader, def.kind)?;
                    if let (Some(slot), Some(slot32)) = (rec.xyz.get_mut(axis), f32s.get_mut(axis))
                    {
                        *slot = v;
                        *slot32 = f;
                    }
                }
                (None, name @ ("rgb" | "rgba")) if def.kind.byte_size() == 4 && def.count == 1 => {
                    let bits = u32::from_le_bytes(read_array(reader)?);
                    if name == "rgb" {
                        rec.rgb = Some(bits);
                    } else {
                        rec.rgba = Some(bits);
                    }
                }
                _ => {
                    // Validated by the header check: this product does not overflow.
                    let bytes = (def.kind.byte_size() as u64).saturating_mul(def.count);
                    skip(reader, bytes)?;
                }
            }
        }
        if let [Some(x), Some(y), Some(z)] = f32s {
            rec.xyz_f32 = Some([x, y, z]);
        }
        Ok(rec)
    }

    fn read_line<R: BufRead>(_reader: &mut R, _field_defs: &Schema) -> pcd_rs::Result<Self> {
        // ASCII data is parsed by `read_ascii`.
        Err(pcd_rs::Error::new_invalid_argument_error(
            "ASCII PCD is not decoded through pcd-rs",
        ))
    }
}

/// Decodes binary or compressed records with pcd-rs. `data` has been validated against the
/// header: it holds every point (binary) or exactly the size prefix and a well-formed LZF
/// stream of the right length (compressed).
fn read_records(h: &Header, data: &[u8], path: &Path) -> Result<Collector, IoError> {
    let what = match h.data {
        PcdEncoding::BinaryCompressed => "binary_compressed",
        _ => "binary",
    };
    let source = Cursor::new(normalised_header(h).into_bytes()).chain(data);
    let reader: Reader<PointRecord, _> =
        Reader::from_reader(BufReader::new(source)).map_err(|e| {
            format_err(
                path,
                format!(
                    "cannot decode the {what} data: {}",
                    one_line(&e.to_string())
                ),
            )
        })?;
    let color_is_rgba = h
        .color
        .and_then(|i| h.fields.get(i))
        .is_some_and(|f| f.name == "rgba");
    let mut collector = Collector::new(h.points as usize, h.color.is_some());
    let mut read = 0u64;
    for record in reader {
        let rec = record.map_err(|e| {
            format_err(
                path,
                format!(
                    "point {read}: cannot decode the {what} data: {}",
                    one_line(&e.to_string())
                ),
            )
        })?;
        let bits = if color_is_rgba { rec.rgba } else { rec.rgb };
        let color = bits.map_or([0; 3], unpack_rgb);
        match rec.xyz_f32 {
            Some(p) => collector.push_f32(p, color),
            None => collector.push(rec.xyz, color),
        }
        read += 1;
    }
    if read != h.points {
        return Err(truncated(
            path,
            format!(
                "header says {} points but only {read} could be decoded",
                h.points
            ),
        ));
    }
    Ok(collector)
}

fn is_blank(line: &[u8]) -> bool {
    line.iter().all(u8::is_ascii_whitespace)
}

fn read_ascii(h: &Header, data: &[u8], path: &Path) -> Result<Collector, IoError> {
    let per_point = h.values_per_point;
    // Each value takes at least two bytes ("0 "); never reserve more than the text can hold.
    let capacity = (h.points as usize).min(data.len() / per_point.max(1).saturating_mul(2) + 1);
    let mut collector = Collector::new(capacity, h.color.is_some());
    let mut read = 0u64;
    let mut lines = numbered_lines(data, h.lines + 1);
    while let Some((line_no, raw)) = lines.next() {
        if is_blank(raw) {
            continue;
        }
        if read == h.points {
            let rows = read + 1 + lines.filter(|(_, l)| !is_blank(l)).count() as u64;
            return Err(format_err(
                path,
                format!(
                    "line {line_no}: more data rows than the {} points the header announces: \
                     header says POINTS {} but {rows} data rows follow it",
                    h.points, h.points
                ),
            ));
        }
        let line = std::str::from_utf8(raw).map_err(|_| {
            format_err(
                path,
                format!("line {line_no}: data is not text (invalid UTF-8)"),
            )
        })?;
        let wrong_count = || {
            format_err(
                path,
                format!(
                    "line {line_no}: point {read} has {} values but the fields need {per_point}",
                    line.split_ascii_whitespace().count()
                ),
            )
        };
        let mut tokens = line.split_ascii_whitespace();
        let mut p = [0.0f64; 3];
        let mut color = [0u8; 3];
        for (fi, f) in h.fields.iter().enumerate() {
            let axis = h.xyz.iter().position(|&i| i == fi);
            for _ in 0..f.count {
                let tok = tokens.next().ok_or_else(wrong_count)?;
                let not_number = || {
                    format_err(
                        path,
                        format!(
                            "line {line_no}: value {} of field {} is not a number",
                            show(tok.as_bytes()),
                            show(f.name.as_bytes())
                        ),
                    )
                };
                if let Some(axis) = axis {
                    // Parse F4 directly as f32: going through f64 could round twice.
                    let v = if f.kind == Kind::F && f.size == 4 {
                        tok.parse::<f32>().map(f64::from)
                    } else {
                        tok.parse::<f64>()
                    };
                    if let Some(slot) = p.get_mut(axis) {
                        *slot = v.map_err(|_| not_number())?;
                    }
                } else if Some(fi) == h.color {
                    // PCL writes an F4 rgb as the integer of its bits; older files as a float.
                    let bits = match tok.parse::<u32>() {
                        Ok(v) => v,
                        Err(_) => tok.parse::<f32>().map_err(|_| not_number())?.to_bits(),
                    };
                    color = unpack_rgb(bits);
                } else if tok.parse::<f64>().is_err() {
                    return Err(not_number());
                }
            }
        }
        if tokens.next().is_some() {
            return Err(wrong_count());
        }
        collector.push(p, color);
        read += 1;
    }
    if read < h.points {
        return Err(truncated(
            path,
            format!(
                "header says {} points but only {read} data rows follow",
                h.points
            ),
        ));
    }
    Ok(collector)
}

/// Header of an ASCII PCD: `x y z` float32, plus `rgb` as `U 4` when coloured.
fn pcd_ascii_header(n: usize, with_colors: bool, viewpoint: &Viewpoint) -> String {
    // In ASCII the colour is declared U4 and written as its integer, as PCL 1.13 itself
    // writes it: PCL 1.13 reads an F4 rgb token as a float value, so an F4 declaration
    // would make it mis-read the integer.
    let (fields, size, ty, count) = if with_colors {
        ("x y z rgb", "4 4 4 4", "F F F U", "1 1 1 1")
    } else {
        ("x y z", "4 4 4", "F F F", "1 1 1")
    };
    let [px, py, pz] = viewpoint.position;
    let [qw, qx, qy, qz] = viewpoint.orientation_wxyz;
    format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {fields}\n\
         SIZE {size}\nTYPE {ty}\nCOUNT {count}\nWIDTH {n}\nHEIGHT 1\n\
         VIEWPOINT {px} {py} {pz} {qw} {qx} {qy} {qz}\nPOINTS {n}\nDATA ascii\n"
    )
}

/// Encodes a cloud as PCD; `colors` has been checked to match the cloud.
pub(super) fn encode(
    cloud: &PointCloud,
    encoding: PcdEncoding,
    colors: Option<&[[u8; 3]]>,
    viewpoint: &Viewpoint,
) -> Result<Vec<u8>, String> {
    match encoding {
        PcdEncoding::Ascii => Ok(encode_ascii(cloud, colors, viewpoint)),
        PcdEncoding::Binary => encode_with_pcd_rs(cloud, DataKind::Binary, colors, viewpoint),
        PcdEncoding::BinaryCompressed => {
            encode_with_pcd_rs(cloud, DataKind::BinaryCompressed, colors, viewpoint)
        }
    }
}

fn encode_ascii(cloud: &PointCloud, colors: Option<&[[u8; 3]]>, viewpoint: &Viewpoint) -> Vec<u8> {
    let mut out = pcd_ascii_header(cloud.len(), colors.is_some(), viewpoint);
    for (i, p) in cloud.points.iter().enumerate() {
        let _ = write!(out, "{} {} {}", fmt_f32(p[0]), fmt_f32(p[1]), fmt_f32(p[2]));
        if let Some(c) = colors.and_then(|c| c.get(i)) {
            let _ = write!(out, " {}", pack_rgb(*c));
        }
        out.push('\n');
    }
    out.into_bytes()
}

fn encode_with_pcd_rs(
    cloud: &PointCloud,
    kind: DataKind,
    colors: Option<&[[u8; 3]]>,
    viewpoint: &Viewpoint,
) -> Result<Vec<u8>, String> {
    let [tx, ty, tz] = viewpoint.position;
    let [qw, qx, qy, qz] = viewpoint.orientation_wxyz;
    let mut fields = vec![
        ("x", ValueKind::F32, 1u64),
        ("y", ValueKind::F32, 1),
        ("z", ValueKind::F32, 1),
    ];
    if colors.is_some() {
        fields.push(("rgb", ValueKind::F32, 1));
    }
    let schema: Schema = fields.into_iter().collect();
    let mut buf = Vec::new();
    let mut writer: DynWriter<_> = WriterInit {
        width: cloud.len() as u64,
        height: 1,
        viewpoint: pcd_rs::ViewPoint {
            tx,
            ty,
            tz,
            qw,
            qx,
            qy,
            qz,
        },
        data_kind: kind,
        schema: Some(schema),
        version: None,
    }
    .build_from_writer(Cursor::new(&mut buf))
    .map_err(|e| format!("pcd-rs: {e}"))?;
    let pushed = (|| -> pcd_rs::Result<()> {
        for (i, p) in cloud.points.iter().enumerate() {
            let mut values = vec![
                Field::F32(vec![p[0]]),
                Field::F32(vec![p[1]]),
                Field::F32(vec![p[2]]),
            ];
            if let Some(c) = colors.and_then(|c| c.get(i)) {
                values.push(Field::F32(vec![f32::from_bits(pack_rgb(*c))]));
            }
            writer.push(&DynRecord(values))?;
        }
        Ok(())
    })();
    // pcd-rs's writer panics when dropped unfinished, so finish it even after an error.
    let finished = writer.finish();
    pushed.map_err(|e| format!("pcd-rs: {e}"))?;
    finished.map_err(|e| format!("pcd-rs: {e}"))?;
    Ok(buf)
}
