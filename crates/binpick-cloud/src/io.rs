//! PCD and PLY clouds (read and write) and STL, OBJ and PLY meshes (read), in pure Rust.
//!
//! Clouds are read with [`read_cloud`] and its variants; part models, which may be a cloud or
//! a CAD mesh, with [`read_model`] (see [`Model`]).
//!
//! # Supported formats
//!
//! | format | read | write |
//! | --- | --- | --- |
//! | PCD `DATA ascii` | yes | yes ([`PcdEncoding::Ascii`]) |
//! | PCD `DATA binary` | yes | yes ([`PcdEncoding::Binary`], the default of [`write_pcd`]) |
//! | PCD `DATA binary_compressed` (LZF) | yes | yes ([`PcdEncoding::BinaryCompressed`]) |
//! | PLY `ascii 1.0` | yes | yes ([`PlyEncoding::Ascii`]) |
//! | PLY `binary_little_endian 1.0` | yes | yes ([`PlyEncoding::BinaryLittleEndian`]) |
//! | PLY `binary_big_endian 1.0` | yes | yes ([`PlyEncoding::BinaryBigEndian`]) |
//! | PLY with a `face` element | as a mesh ([`read_model`]) or its vertices as a cloud | no |
//! | STL ASCII and binary | as a mesh ([`read_model`], through `stl_io`) | no |
//! | OBJ (`v`, `f`) | as a mesh ([`read_model`], through `tobj`) | no |
//!
//! **Reading PCD** accepts any field layout that contains `x`, `y` and `z` (each with
//! `COUNT 1`, of any numeric type; `F4` and `F8` are the usual ones): extra fields such as
//! `rgb`/`rgba`, normals, `curvature`, descriptors with `COUNT > 1` (e.g. a 33-float `fpfh`),
//! PCL padding fields named `_`, and every valid `TYPE`/`SIZE` pair (`F` 4/8, `U` and `I`
//! 1/2/4/8). Organised clouds (`HEIGHT > 1`) are read row by row into an unorganised cloud;
//! [`LoadReport::width`] and [`LoadReport::height`] keep the original shape. As in PCL,
//! `WIDTH x HEIGHT` must equal `POINTS`, blank lines in ASCII data are skipped and `COUNT 0`
//! means 1. `POINTS` must also match the data: zero bytes after the data are PCL's padding
//! and ignored, but more data than `POINTS` (more ASCII rows, more binary points, a longer
//! compressed block) is an error stating both counts, never a silent prefix of the cloud.
//! The `VIEWPOINT` line is parsed into [`LoadReport::viewpoint`]. Colours
//! come from an `rgb` or `rgba` field of 4 bytes (`F4` bits or `U4`); in ASCII an integer
//! token is the packed value and a decimal one a float whose bits are the packed value.
//!
//! **Reading PLY** takes the `vertex` element's `x`, `y`, `z` properties (any numeric scalar
//! type) and, when present, `red`/`green`/`blue`; every other element (faces, edges, ...) is
//! parsed for validation and then ignored by [`read_cloud`]. The vertex count must match
//! the data (both counts are stated otherwise).
//!
//! **Reading meshes** ([`read_model`]): every format goes through one set of checks
//! (indices in range, finite coordinates, polygons split into fans, zero-area triangles
//! skipped and counted, vertices at one position merged, closed meshes wound outward); see
//! [`MeshReport`] for what is counted.
//!
//! **Limits**: [`ReadLimits`] bounds the points and faces a file may hold (50 million each
//! by default), checked from the header before the data is read.
//!
//! **Non-finite points**: a point with a NaN or infinite coordinate (or an `F8`/PLY `double`
//! coordinate outside the `f32` range) is dropped and counted in
//! [`LoadReport::non_finite_dropped`]. A file that holds no points, or only non-finite ones,
//! is an error ([`IoError::NoFinitePoints`]).
//!
//! **Units**: coordinates are stored and returned as they are in the file. binpick works in
//! millimetres; converting a file in metres is the caller's job (see [`crate::Units`]).
//!
//! **Writing** (PCD, PLY clouds) always stores `x y z` as `float32`, with an optional per-point colour: in
//! binary PCD an `rgb` field of type `F4` packed as PCL does (`0x00RRGGBB` reinterpreted as
//! a float), in ASCII PCD an `rgb` field of type `U4` holding that integer (what PCL 1.13
//! writes: it reads an ASCII `F4` token as a float value), in PLY `uchar red green blue`.
//! ASCII output prints every coordinate with the shortest decimal that parses back to the
//! same `f32`, so ASCII round trips are exact too. Written clouds are unorganised
//! (`HEIGHT 1`). Non-finite coordinates are written as they are (`nan`, `inf`); readers drop
//! them again. An empty cloud can be written, but reading that file back is an error. PCD
//! files get a `VIEWPOINT` line: PCL's default, or the one given to
//! [`write_pcd_with_viewpoint`].
//!
//! # Robustness
//!
//! Readers never panic and never size a buffer from a header's counts alone: counts are
//! checked against the bytes that follow (for `binary_compressed`, the LZF stream is walked
//! without decoding to check the length it really unpacks to) before anything is allocated,
//! so memory stays proportional to the data actually present. Every error names the file
//! (the path, or the name passed to [`read_cloud_from_bytes`]) and says what is wrong, e.g.
//! `scene.pcd: truncated: header says 5000 points of 16 bytes (80000 bytes) but only 1200 bytes follow`.
//!
//! The `pcd-rs` crate decodes binary and LZF-compressed PCD data and writes binary and
//! compressed PCD, after this module has validated the header (pcd-rs panics or aborts on
//! some lying headers); `ply-rs-bw` parses PLY headers and binary PLY payloads and writes
//! PLY. ASCII PCD and ASCII PLY payloads are parsed here (pcd-rs rejects blank lines and
//! reads an integer `rgb` token as a float value; ply-rs-bw rejects `nan`, `inf` and numbers
//! such as `.5`). `stl_io` decodes STL triangles once this module has decided ASCII or
//! binary and checked a binary file's triangle count against its size; `tobj` parses OBJ.
//! Every reader is fuzzed (`fuzz/`) and mutation-tested (`tests/io_mutations.rs`).

mod model;
mod obj;
mod pcd;
mod ply;
mod stl;

use std::fmt;
use std::io::Read as _;
use std::path::{Path, PathBuf};

use crate::{Point, PointCloud};

pub use model::{
    DEGENERATE_AREA_FRACTION, LoadedMesh, MeshFormat, MeshReport, Model, read_model,
    read_model_from_bytes, read_model_with,
};

/// Default of [`ReadLimits::max_points`]: ten times a 5-megapixel scan.
pub const DEFAULT_MAX_POINTS: usize = 50_000_000;
/// Default of [`ReadLimits::max_faces`].
pub const DEFAULT_MAX_FACES: usize = 50_000_000;

/// Bounds on what a reader accepts. They are checked against the counts a header announces
/// (PCD `POINTS`, PLY element counts, the binary STL triangle count) before the data is read,
/// so a file too large for the machine is refused with a clear error instead of exhausting
/// memory; formats without counts in a header (ASCII STL, OBJ) are checked once parsed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadLimits {
    /// Most points a cloud file may hold (PCD `POINTS`, PLY `vertex` count) and most vertices
    /// of a mesh file. Default [`DEFAULT_MAX_POINTS`] (50 million); range 1 and up.
    pub max_points: usize,
    /// Most faces a mesh file may hold (STL facets, OBJ `f` lines, PLY `face` elements).
    /// Default [`DEFAULT_MAX_FACES`] (50 million); range 1 and up.
    pub max_faces: usize,
}

impl Default for ReadLimits {
    fn default() -> Self {
        Self {
            max_points: DEFAULT_MAX_POINTS,
            max_faces: DEFAULT_MAX_FACES,
        }
    }
}

impl ReadLimits {
    /// Fails with [`IoError::TooLarge`] when `count` points exceed [`ReadLimits::max_points`].
    pub(crate) fn check_points(&self, path: &Path, count: u64) -> Result<(), IoError> {
        check_limit(path, count, self.max_points, "points", "max_points")
    }

    /// Fails with [`IoError::TooLarge`] when `count` faces exceed [`ReadLimits::max_faces`].
    pub(crate) fn check_faces(&self, path: &Path, count: u64) -> Result<(), IoError> {
        check_limit(path, count, self.max_faces, "faces", "max_faces")
    }
}

fn check_limit(
    path: &Path,
    count: u64,
    limit: usize,
    what: &'static str,
    setting: &'static str,
) -> Result<(), IoError> {
    if count > limit as u64 {
        return Err(IoError::TooLarge {
            path: path.to_owned(),
            what,
            count,
            limit,
            setting,
        });
    }
    Ok(())
}

/// A PCD file's `VIEWPOINT`: where the sensor was and how it was turned when the cloud was
/// taken, in the file's coordinates and units (PCL's `sensor_origin_` and
/// `sensor_orientation_`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Viewpoint {
    /// Sensor position `[tx, ty, tz]`, in the file's units.
    pub position: [f64; 3],
    /// Sensor orientation as a unit quaternion `[w, x, y, z]` (normalised on read).
    pub orientation_wxyz: [f64; 4],
}

impl Default for Viewpoint {
    /// PCL's default, `VIEWPOINT 0 0 0 1 0 0 0`: at the origin, not rotated.
    fn default() -> Self {
        Self {
            position: [0.0; 3],
            orientation_wxyz: [1.0, 0.0, 0.0, 0.0],
        }
    }
}

impl Viewpoint {
    /// Whether this is PCL's default `0 0 0 1 0 0 0`, which PCL writes when it knows nothing
    /// about the sensor (so it says nothing about where the scanner really was).
    pub fn is_pcl_default(&self) -> bool {
        *self == Viewpoint::default()
    }

    /// The viewpoint with its position multiplied by `factor` (e.g. 1000 for metres to mm).
    pub fn scaled(&self, factor: f64) -> Viewpoint {
        Viewpoint {
            position: self.position.map(|c| c * factor),
            orientation_wxyz: self.orientation_wxyz,
        }
    }
}

/// Error reading or writing a cloud file. Every variant names the file, and its `Display`
/// starts with the path.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The operating system refused (file missing, no permission, disk full, ...).
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The file name has no extension or one the reader does not support (clouds: `.pcd`,
    /// `.ply`; models: also `.stl`, `.obj`).
    #[error("{}: unsupported file type ({found}): supported are {supported}", .path.display())]
    UnsupportedExtension {
        path: PathBuf,
        found: String,
        supported: &'static str,
    },
    /// The content is of another format than the extension says (e.g. a PLY named `.pcd`).
    #[error("{}: {message}", .path.display())]
    WrongFormat { path: PathBuf, message: String },
    /// Malformed or inconsistent content.
    #[error("{}: {message}", .path.display())]
    Format { path: PathBuf, message: String },
    /// The data ends before everything the header announces.
    #[error("{}: truncated: {message}", .path.display())]
    Truncated { path: PathBuf, message: String },
    /// The file is well formed but holds no point with finite coordinates.
    #[error("{}: {}", .path.display(), no_points_message(*.points_in_file, *.non_finite_dropped))]
    NoFinitePoints {
        path: PathBuf,
        points_in_file: usize,
        non_finite_dropped: usize,
    },
    /// A write was asked with inconsistent arguments (e.g. fewer colours than points).
    #[error("{}: cannot write: {message}", .path.display())]
    InvalidArgument { path: PathBuf, message: String },
    /// The file announces (or holds) more points or faces than [`ReadLimits`] allows.
    #[error(
        "{}: {count} {what}, more than the limit of {limit} {what} (ReadLimits::{setting}); \
         raise the limit to read this file",
        .path.display()
    )]
    TooLarge {
        path: PathBuf,
        /// `"points"` or `"faces"`.
        what: &'static str,
        count: u64,
        limit: usize,
        /// The [`ReadLimits`] field that sets the limit.
        setting: &'static str,
    },
    /// A mesh file whose faces are unusable: none at all, all of zero area, an index out of
    /// range, a non-finite coordinate.
    #[error("{}: {message}", .path.display())]
    Mesh { path: PathBuf, message: String },
}

fn no_points_message(points_in_file: usize, dropped: usize) -> String {
    if points_in_file == 0 {
        "contains no points".to_owned()
    } else {
        format!("contains no finite points ({dropped} NaN/infinite points dropped)")
    }
}

impl IoError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            IoError::Io { path, .. }
            | IoError::UnsupportedExtension { path, .. }
            | IoError::WrongFormat { path, .. }
            | IoError::Format { path, .. }
            | IoError::Truncated { path, .. }
            | IoError::NoFinitePoints { path, .. }
            | IoError::InvalidArgument { path, .. }
            | IoError::TooLarge { path, .. }
            | IoError::Mesh { path, .. } => path,
        }
    }
}

pub(crate) fn format_err(path: &Path, message: impl Into<String>) -> IoError {
    IoError::Format {
        path: path.to_owned(),
        message: message.into(),
    }
}

pub(crate) fn mesh_err(path: &Path, message: impl Into<String>) -> IoError {
    IoError::Mesh {
        path: path.to_owned(),
        message: message.into(),
    }
}

pub(crate) fn truncated(path: &Path, message: impl Into<String>) -> IoError {
    IoError::Truncated {
        path: path.to_owned(),
        message: message.into(),
    }
}

/// Container format of a cloud file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CloudFormat {
    Pcd,
    Ply,
}

impl fmt::Display for CloudFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CloudFormat::Pcd => "PCD",
            CloudFormat::Ply => "PLY",
        })
    }
}

/// How the data section of a file is encoded, as named in its header.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Encoding {
    /// PCD `ascii` or PLY `ascii`.
    Ascii,
    /// PCD `binary` (little endian).
    Binary,
    /// PCD `binary_compressed` (LZF, fields stored column by column).
    BinaryCompressed,
    /// PLY `binary_little_endian`.
    BinaryLittleEndian,
    /// PLY `binary_big_endian`.
    BinaryBigEndian,
}

impl fmt::Display for Encoding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Encoding::Ascii => "ascii",
            Encoding::Binary => "binary",
            Encoding::BinaryCompressed => "binary_compressed",
            Encoding::BinaryLittleEndian => "binary_little_endian",
            Encoding::BinaryBigEndian => "binary_big_endian",
        })
    }
}

/// Encoding of a written PCD file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum PcdEncoding {
    Ascii,
    #[default]
    Binary,
    BinaryCompressed,
}

impl From<PcdEncoding> for Encoding {
    fn from(e: PcdEncoding) -> Self {
        match e {
            PcdEncoding::Ascii => Encoding::Ascii,
            PcdEncoding::Binary => Encoding::Binary,
            PcdEncoding::BinaryCompressed => Encoding::BinaryCompressed,
        }
    }
}

/// Encoding of a written PLY file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum PlyEncoding {
    Ascii,
    #[default]
    BinaryLittleEndian,
    BinaryBigEndian,
}

impl From<PlyEncoding> for Encoding {
    fn from(e: PlyEncoding) -> Self {
        match e {
            PlyEncoding::Ascii => Encoding::Ascii,
            PlyEncoding::BinaryLittleEndian => Encoding::BinaryLittleEndian,
            PlyEncoding::BinaryBigEndian => Encoding::BinaryBigEndian,
        }
    }
}

/// What was found while loading a cloud.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadReport {
    /// Points stored in the file (`POINTS`, i.e. width x height, for PCD; the vertex count
    /// for PLY), before non-finite points were dropped.
    pub points_in_file: usize,
    /// Points dropped because a coordinate was NaN or infinite.
    pub non_finite_dropped: usize,
    /// PCD or PLY.
    pub format: CloudFormat,
    /// Encoding of the data section.
    pub encoding: Encoding,
    /// Width of the cloud as stored: PCD `WIDTH`; the vertex count for PLY.
    pub width: usize,
    /// Height of the cloud as stored: PCD `HEIGHT` (> 1 for organised clouds); 1 for PLY.
    pub height: usize,
    /// Field names in file order: PCD `FIELDS` (padding `_` included), or the PLY `vertex`
    /// element's property names.
    pub fields: Vec<String>,
    /// The PCD `VIEWPOINT` line, when the header has one (PLY has none). In the file's units.
    pub viewpoint: Option<Viewpoint>,
}

impl LoadReport {
    /// Whether the file stored an organised (image-like) cloud.
    pub fn is_organized(&self) -> bool {
        self.height > 1
    }

    /// The sensor's viewpoint when the file states a real one: `None` when there is no
    /// `VIEWPOINT` line or it is PCL's default `0 0 0 1 0 0 0` (written when nothing is known).
    pub fn sensor_viewpoint(&self) -> Option<&Viewpoint> {
        self.viewpoint.as_ref().filter(|v| !v.is_pcl_default())
    }
}

/// A loaded cloud with its per-point colours, if the file had any.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedCloud {
    /// The finite points, in file order.
    pub cloud: PointCloud,
    /// One colour per point of `cloud` (same order), when the file has `rgb`/`rgba` (PCD) or
    /// `red`/`green`/`blue` (PLY).
    pub colors: Option<Vec<[u8; 3]>>,
    pub report: LoadReport,
}

/// Collects decoded points, dropping (and counting) non-finite ones.
pub(crate) struct Collector {
    points: Vec<Point>,
    colors: Option<Vec<[u8; 3]>>,
    dropped: usize,
}

impl Collector {
    /// `capacity` must already be bounded by the input size.
    pub(crate) fn new(capacity: usize, with_colors: bool) -> Self {
        Self {
            points: Vec::with_capacity(capacity),
            colors: with_colors.then(|| Vec::with_capacity(capacity)),
            dropped: 0,
        }
    }

    pub(crate) fn push(&mut self, p: [f64; 3], color: [u8; 3]) {
        let q = [p[0] as f32, p[1] as f32, p[2] as f32];
        if q.iter().all(|c| c.is_finite()) {
            self.points.push(q);
            if let Some(colors) = &mut self.colors {
                colors.push(color);
            }
        } else {
            self.dropped += 1;
        }
    }

    /// Same as [`Collector::push`] for coordinates that are already `f32` (keeps NaN payloads
    /// and signed zeros bit for bit).
    pub(crate) fn push_f32(&mut self, q: Point, color: [u8; 3]) {
        if q.iter().all(|c| c.is_finite()) {
            self.points.push(q);
            if let Some(colors) = &mut self.colors {
                colors.push(color);
            }
        } else {
            self.dropped += 1;
        }
    }

    /// Ends collection; `report.non_finite_dropped` is filled in here. Fails when no finite
    /// point was collected.
    pub(crate) fn finish(
        self,
        path: &Path,
        mut report: LoadReport,
    ) -> Result<LoadedCloud, IoError> {
        report.non_finite_dropped = self.dropped;
        if self.points.is_empty() {
            return Err(IoError::NoFinitePoints {
                path: path.to_owned(),
                points_in_file: report.points_in_file,
                non_finite_dropped: self.dropped,
            });
        }
        Ok(LoadedCloud {
            cloud: PointCloud::new(self.points),
            colors: self.colors,
            report,
        })
    }
}

/// Packs a colour the way PCL's `rgb` field does: `0x00RRGGBB`.
pub fn pack_rgb([r, g, b]: [u8; 3]) -> u32 {
    (u32::from(r) << 16) | (u32::from(g) << 8) | u32::from(b)
}

/// Unpacks a PCL `rgb`/`rgba` value (`0xAARRGGBB`; alpha ignored).
pub fn unpack_rgb(v: u32) -> [u8; 3] {
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

/// The lower-case extension of `path`, if any.
pub(crate) fn extension(path: &Path) -> Option<String> {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
}

pub(crate) fn unsupported_extension(path: &Path, supported: &'static str) -> IoError {
    IoError::UnsupportedExtension {
        path: path.to_owned(),
        found: extension(path)
            .map_or_else(|| "no extension".to_owned(), |e| format!("extension .{e}")),
        supported,
    }
}

fn format_from_extension(path: &Path) -> Result<CloudFormat, IoError> {
    match extension(path).as_deref() {
        Some("pcd") => Ok(CloudFormat::Pcd),
        Some("ply") => Ok(CloudFormat::Ply),
        _ => Err(unsupported_extension(
            path,
            ".pcd and .ply (mesh models .stl and .obj are read by read_model)",
        )),
    }
}

/// What the first bytes look like.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Sniffed {
    Ply,
    Pcd,
    Unknown,
}

pub(crate) fn sniff(bytes: &[u8]) -> Sniffed {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r") || bytes == b"ply" {
        return Sniffed::Ply;
    }
    // A PCD header starts with comments or keyword lines.
    let first_line = bytes.split(|&b| b == b'\n').next().unwrap_or(&[]);
    let first = String::from_utf8_lossy(first_line);
    let first = first.trim_start();
    let upper = first
        .get(..first.len().min(9))
        .unwrap_or("")
        .to_ascii_uppercase();
    if first.starts_with('#')
        || ["VERSION", "FIELDS", "COLUMNS"]
            .iter()
            .any(|k| upper.starts_with(k))
    {
        Sniffed::Pcd
    } else {
        Sniffed::Unknown
    }
}

/// Reads a `.pcd` or `.ply` file (chosen by extension), dropping non-finite points, with the
/// default [`ReadLimits`].
pub fn read_cloud(path: &Path) -> Result<(PointCloud, LoadReport), IoError> {
    read_cloud_with_colors(path).map(|l| (l.cloud, l.report))
}

/// Like [`read_cloud`] for a file already in memory; `name` is used in messages and its
/// extension (`.pcd` / `.ply`) picks the format.
pub fn read_cloud_from_bytes(
    bytes: &[u8],
    name: &str,
) -> Result<(PointCloud, LoadReport), IoError> {
    read_cloud_with_colors_from_bytes(bytes, name).map(|l| (l.cloud, l.report))
}

/// Like [`read_cloud`], also returning the per-point colours when the file has them.
pub fn read_cloud_with_colors(path: &Path) -> Result<LoadedCloud, IoError> {
    read_cloud_with(path, &ReadLimits::default())
}

/// Like [`read_cloud_with_colors`] with explicit [`ReadLimits`]. The header is read and
/// checked against the limits before the rest of the file is loaded.
pub fn read_cloud_with(path: &Path, limits: &ReadLimits) -> Result<LoadedCloud, IoError> {
    // Check the extension before touching the file, so a wrong name fails the same way
    // whether the file exists or not.
    let format = format_from_extension(path)?;
    let bytes = read_file_checked(path, |prefix| precheck_cloud(prefix, path, format, limits))?;
    read_bytes(&bytes, path, limits)
}

/// Like [`read_cloud_from_bytes`], also returning the per-point colours.
pub fn read_cloud_with_colors_from_bytes(bytes: &[u8], name: &str) -> Result<LoadedCloud, IoError> {
    read_cloud_with_from_bytes(bytes, name, &ReadLimits::default())
}

/// Like [`read_cloud_with_colors_from_bytes`] with explicit [`ReadLimits`].
pub fn read_cloud_with_from_bytes(
    bytes: &[u8],
    name: &str,
    limits: &ReadLimits,
) -> Result<LoadedCloud, IoError> {
    read_bytes(bytes, Path::new(name), limits)
}

/// How much of a file is read first to check its header against the limits.
const HEADER_PREFIX_BYTES: u64 = 64 << 10;

/// Reads a whole file, after running `precheck` on its first bytes (its header), so that a
/// header announcing more than the limits is refused before the file is loaded.
pub(crate) fn read_file_checked(
    path: &Path,
    precheck: impl FnOnce(&[u8]) -> Result<(), IoError>,
) -> Result<Vec<u8>, IoError> {
    let io = |source| IoError::Io {
        path: path.to_owned(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut bytes = Vec::new();
    file.by_ref()
        .take(HEADER_PREFIX_BYTES)
        .read_to_end(&mut bytes)
        .map_err(io)?;
    precheck(&bytes)?;
    file.read_to_end(&mut bytes).map_err(io)?;
    Ok(bytes)
}

/// Checks a cloud file's header (possibly followed by only part of the data) against the
/// limits. A header that cannot be parsed from the prefix is left to the full read.
fn precheck_cloud(
    prefix: &[u8],
    path: &Path,
    format: CloudFormat,
    limits: &ReadLimits,
) -> Result<(), IoError> {
    match format {
        CloudFormat::Pcd => pcd::precheck(prefix, path, limits),
        CloudFormat::Ply => ply::precheck(prefix, path, limits, false),
    }
}

fn read_bytes(bytes: &[u8], path: &Path, limits: &ReadLimits) -> Result<LoadedCloud, IoError> {
    let format = format_from_extension(path)?;
    if bytes.is_empty() {
        return Err(format_err(path, "file is empty"));
    }
    let wrong = |message: &str| IoError::WrongFormat {
        path: path.to_owned(),
        message: message.to_owned(),
    };
    match (format, sniff(bytes)) {
        (CloudFormat::Pcd, Sniffed::Ply) => Err(wrong(
            "has a .pcd extension but is a PLY file (it starts with \"ply\"); rename it to .ply",
        )),
        (CloudFormat::Ply, Sniffed::Pcd) => Err(wrong(
            "has a .ply extension but looks like a PCD file (it starts with a PCD header); \
             rename it to .pcd",
        )),
        (CloudFormat::Ply, Sniffed::Unknown) => Err(format_err(
            path,
            "not a PLY file: it does not start with the line \"ply\"",
        )),
        (CloudFormat::Pcd, _) => pcd::read(bytes, path, limits),
        (CloudFormat::Ply, _) => ply::read(bytes, path, limits),
    }
}

fn check_colors(
    path: &Path,
    cloud: &PointCloud,
    colors: Option<&[[u8; 3]]>,
) -> Result<(), IoError> {
    match colors {
        Some(c) if c.len() != cloud.len() => Err(IoError::InvalidArgument {
            path: path.to_owned(),
            message: format!("{} colours given for {} points", c.len(), cloud.len()),
        }),
        _ => Ok(()),
    }
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    std::fs::write(path, bytes).map_err(|source| IoError::Io {
        path: path.to_owned(),
        source,
    })
}

/// Writes a binary PCD with fields `x y z` (float32).
pub fn write_pcd(path: &Path, cloud: &PointCloud) -> Result<(), IoError> {
    write_pcd_with(path, cloud, PcdEncoding::Binary, None)
}

/// Writes a PCD with fields `x y z` (float32) and, with `colors`, an `rgb` field (`F4`,
/// packed as PCL does). `colors` must have one entry per point.
pub fn write_pcd_with(
    path: &Path,
    cloud: &PointCloud,
    encoding: PcdEncoding,
    colors: Option<&[[u8; 3]]>,
) -> Result<(), IoError> {
    write_pcd_with_viewpoint(path, cloud, encoding, colors, &Viewpoint::default())
}

/// Like [`write_pcd_with`], with the sensor's `viewpoint` (in the cloud's units) in the
/// header's `VIEWPOINT` line.
pub fn write_pcd_with_viewpoint(
    path: &Path,
    cloud: &PointCloud,
    encoding: PcdEncoding,
    colors: Option<&[[u8; 3]]>,
    viewpoint: &Viewpoint,
) -> Result<(), IoError> {
    check_colors(path, cloud, colors)?;
    let bytes = pcd::encode(cloud, encoding, colors, viewpoint)
        .map_err(|message| format_err(path, message))?;
    write_file(path, &bytes)
}

/// Writes a PLY with a `vertex` element of `float x y z` and, with `colors`,
/// `uchar red green blue`. `colors` must have one entry per point.
pub fn write_ply(
    path: &Path,
    cloud: &PointCloud,
    encoding: PlyEncoding,
    colors: Option<&[[u8; 3]]>,
) -> Result<(), IoError> {
    check_colors(path, cloud, colors)?;
    let bytes =
        ply::encode(cloud, encoding, colors).map_err(|message| format_err(path, message))?;
    write_file(path, &bytes)
}

/// Writes `cloud` in the format its extension names: `.pcd` as binary PCD, `.ply` as binary
/// little-endian PLY.
pub fn write_cloud(path: &Path, cloud: &PointCloud) -> Result<(), IoError> {
    match format_from_extension(path)? {
        CloudFormat::Pcd => write_pcd(path, cloud),
        CloudFormat::Ply => write_ply(path, cloud, PlyEncoding::BinaryLittleEndian, None),
    }
}

/// Formats an `f32` for ASCII output: the shortest decimal that parses back to the same
/// value, in plain notation for ordinary magnitudes and scientific notation otherwise;
/// `nan`, `inf`, `-inf` for non-finite values.
pub(crate) fn fmt_f32(v: f32) -> String {
    if v.is_nan() {
        "nan".to_owned()
    } else if v.is_infinite() {
        if v > 0.0 { "inf" } else { "-inf" }.to_owned()
    } else if v == 0.0 || (1e-5..1e9).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Splits `text` into lines (without the `\n`), numbering them from `first_line_no`.
pub(crate) fn numbered_lines(
    text: &[u8],
    first_line_no: usize,
) -> impl Iterator<Item = (usize, &[u8])> {
    // A trailing newline does not start another line.
    let body = text.strip_suffix(b"\n").unwrap_or(text);
    let empty = body.is_empty() && text.is_empty();
    body.split(|&b| b == b'\n')
        .enumerate()
        .filter(move |_| !empty)
        .map(move |(i, l)| (first_line_no + i, l))
}

/// Shortens a message for an error line: no newlines or tabs, at most ~200 characters.
pub(crate) fn one_line(s: &str) -> String {
    let mut out = String::with_capacity(s.len().min(220));
    let mut last_space = false;
    for ch in s.chars() {
        let ch = if ch.is_whitespace() { ' ' } else { ch };
        if ch == ' ' && last_space {
            continue;
        }
        last_space = ch == ' ';
        out.push(ch);
        if out.len() >= 200 {
            out.push_str("...");
            break;
        }
    }
    out.trim().to_owned()
}

/// Shows the start of a token or line in a message, escaped and shortened.
pub(crate) fn show(bytes: &[u8]) -> String {
    let s = String::from_utf8_lossy(&bytes[..bytes.len().min(40)]);
    let mut out = format!("{:?}", s.trim_end_matches('\r'));
    if bytes.len() > 40 {
        out.push_str("...");
    }
    out
}
