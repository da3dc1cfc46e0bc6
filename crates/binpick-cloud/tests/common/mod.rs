//! Helpers shared by the I/O tests: hand-made PCD and PLY files of any layout, built
//! independently of the code under test (own little-endian encoding, literal-only LZF).

#![allow(dead_code)]

mod alloc_guard;
mod mesh_files;
mod mutate;

#[allow(unused_imports)]
pub use alloc_guard::ALLOC_LIMIT;
#[allow(unused_imports)]
pub use mesh_files::*;
#[allow(unused_imports)]
pub use mutate::mutate;

use std::path::{Path, PathBuf};

use binpick_cloud::PointCloud;
use binpick_cloud::io::{PcdEncoding, PlyEncoding, write_pcd_with, write_ply};

/// A tiny deterministic generator (xorshift64*), so tests need no extra crate.
pub struct XorShift(pub u64);

impl XorShift {
    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in `0..n` (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
    /// Uniform in `[lo, hi)`.
    pub fn f32_in(&mut self, lo: f32, hi: f32) -> f32 {
        let u = (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32;
        lo + (hi - lo) * u
    }
}

/// One PCD field: name, TYPE (`F`, `U`, `I`), SIZE, COUNT.
#[derive(Clone, Copy, Debug)]
pub struct Col {
    pub name: &'static str,
    pub ty: char,
    pub size: usize,
    pub count: usize,
}

pub const fn col(name: &'static str, ty: char, size: usize, count: usize) -> Col {
    Col {
        name,
        ty,
        size,
        count,
    }
}

pub const XYZ_F4: [Col; 3] = [
    col("x", 'F', 4, 1),
    col("y", 'F', 4, 1),
    col("z", 'F', 4, 1),
];

/// The header a PCL writer would produce for these fields.
pub fn pcd_header(cols: &[Col], width: usize, height: usize, data: &str) -> String {
    let join = |f: &dyn Fn(&Col) -> String| cols.iter().map(f).collect::<Vec<_>>().join(" ");
    format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {}\nSIZE {}\nTYPE {}\n\
         COUNT {}\nWIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {}\nDATA {data}\n",
        join(&|c| c.name.to_string()),
        join(&|c| c.size.to_string()),
        join(&|c| c.ty.to_string()),
        join(&|c| c.count.to_string()),
        width * height,
    )
}

/// Little-endian bytes of one value of a field.
fn value_bytes(c: &Col, v: f64) -> Vec<u8> {
    match (c.ty, c.size) {
        ('F', 4) => (v as f32).to_le_bytes().to_vec(),
        ('F', 8) => v.to_le_bytes().to_vec(),
        ('U', 1) => (v as u8).to_le_bytes().to_vec(),
        ('U', 2) => (v as u16).to_le_bytes().to_vec(),
        ('U', 4) => (v as u32).to_le_bytes().to_vec(),
        ('U', 8) => (v as u64).to_le_bytes().to_vec(),
        ('I', 1) => (v as i8).to_le_bytes().to_vec(),
        ('I', 2) => (v as i16).to_le_bytes().to_vec(),
        ('I', 4) => (v as i32).to_le_bytes().to_vec(),
        ('I', 8) => (v as i64).to_le_bytes().to_vec(),
        other => panic!("no such PCD type {other:?}"),
    }
}

fn value_text(c: &Col, v: f64) -> String {
    match c.ty {
        'F' if c.size == 4 => {
            let v = v as f32;
            if v.is_nan() {
                "nan".into()
            } else {
                format!("{v}")
            }
        }
        'F' => {
            if v.is_nan() {
                "nan".into()
            } else {
                format!("{v}")
            }
        }
        _ => format!("{}", v as i64),
    }
}

/// LZF stream made of literal runs only: valid LZF, no compression.
pub fn lzf_literal(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len() + data.len() / 32 + 1);
    for chunk in data.chunks(32) {
        out.push((chunk.len() - 1) as u8);
        out.extend_from_slice(chunk);
    }
    out
}

/// A whole PCD file. `rows[i]` holds every value of point `i`, field after field (COUNT
/// values per field). `data` is `ascii`, `binary` or `binary_compressed`.
pub fn pcd_file(
    cols: &[Col],
    rows: &[Vec<f64>],
    width: usize,
    height: usize,
    data: &str,
) -> Vec<u8> {
    assert_eq!(rows.len(), width * height);
    let per_point: usize = cols.iter().map(|c| c.count).sum();
    assert!(rows.iter().all(|r| r.len() == per_point));
    let mut out = pcd_header(cols, width, height, data).into_bytes();
    match data {
        "ascii" => {
            for r in rows {
                let mut k = 0;
                let mut toks = Vec::new();
                for c in cols {
                    for _ in 0..c.count {
                        toks.push(value_text(c, r[k]));
                        k += 1;
                    }
                }
                out.extend_from_slice(toks.join(" ").as_bytes());
                out.push(b'\n');
            }
        }
        "binary" => {
            for r in rows {
                let mut k = 0;
                for c in cols {
                    for _ in 0..c.count {
                        out.extend(value_bytes(c, r[k]));
                        k += 1;
                    }
                }
            }
        }
        "binary_compressed" => {
            // Column-major: all of field 0, then all of field 1, ...
            let mut raw = Vec::new();
            let mut start = 0;
            for c in cols {
                for r in rows {
                    for j in 0..c.count {
                        raw.extend(value_bytes(c, r[start + j]));
                    }
                }
                start += c.count;
            }
            let packed = lzf_literal(&raw);
            out.extend((packed.len() as u32).to_le_bytes());
            out.extend((raw.len() as u32).to_le_bytes());
            out.extend(packed);
        }
        other => panic!("no such DATA {other}"),
    }
    out
}

/// Offset of the first data byte of a PCD file (just after the `DATA ...` line).
pub fn pcd_data_start(bytes: &[u8]) -> usize {
    let pos = bytes
        .windows(5)
        .position(|w| w == b"DATA ")
        .expect("no DATA line");
    pos + bytes[pos..]
        .iter()
        .position(|&b| b == b'\n')
        .expect("no newline")
        + 1
}

/// Replaces the first occurrence of `from` in the header part of a file.
pub fn replace_in_header(bytes: &[u8], from: &str, to: &str) -> Vec<u8> {
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .map(|p| p + 10)
        .unwrap_or_else(|| pcd_data_start(bytes));
    let head = String::from_utf8(bytes[..end].to_vec()).expect("header is text");
    assert!(head.contains(from), "{from:?} not in header:\n{head}");
    let mut out = head.replacen(from, to, 1).into_bytes();
    out.extend_from_slice(&bytes[end..]);
    out
}

/// PLY scalar types as written in headers, with their sizes.
pub fn ply_scalar_bytes(ty: &str, v: f64, big_endian: bool) -> Vec<u8> {
    macro_rules! enc {
        ($t:ty) => {{
            let x = v as $t;
            if big_endian {
                x.to_be_bytes().to_vec()
            } else {
                x.to_le_bytes().to_vec()
            }
        }};
    }
    match ty {
        "char" | "int8" => enc!(i8),
        "uchar" | "uint8" => enc!(u8),
        "short" | "int16" => enc!(i16),
        "ushort" | "uint16" => enc!(u16),
        "int" | "int32" => enc!(i32),
        "uint" | "uint32" => enc!(u32),
        "float" | "float32" => enc!(f32),
        "double" | "float64" => enc!(f64),
        other => panic!("no such PLY type {other}"),
    }
}

/// A small cloud with awkward values: signed zero, subnormal, extremes, many digits.
pub fn tricky_cloud() -> PointCloud {
    let mut rng = XorShift(0x9E37_79B9_7F4A_7C15);
    let mut pts = vec![
        [0.0, -0.0, 1.0],
        [f32::MIN_POSITIVE, 1e-40, -1e-45],
        [f32::MAX, -f32::MAX, 3.402_823e38],
        [1e-7, 123_456.79, std::f32::consts::PI],
        [-0.1, 0.2, 0.3],
        [1e9, 1e-5, 9.999_999e8],
        [16_777_217.0, -16_777_216.0, 0.5],
    ];
    for _ in 0..200 {
        pts.push([
            rng.f32_in(-1000.0, 1000.0),
            rng.f32_in(-1.0, 1.0),
            rng.f32_in(0.0, 2500.0),
        ]);
    }
    PointCloud::new(pts)
}

pub fn colors_for(n: usize) -> Vec<[u8; 3]> {
    let mut rng = XorShift(42);
    let mut c: Vec<[u8; 3]> = (0..n)
        .map(|_| {
            let v = rng.next_u64();
            [v as u8, (v >> 8) as u8, (v >> 16) as u8]
        })
        .collect();
    if n > 2 {
        c[0] = [0, 0, 0];
        c[1] = [255, 255, 255];
        c[2] = [255, 0, 128];
    }
    c
}

/// Bitwise equality of two clouds (distinguishes -0.0 from 0.0).
pub fn assert_bits_equal(a: &PointCloud, b: &PointCloud, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: point count");
    for (i, (p, q)) in a.points.iter().zip(&b.points).enumerate() {
        for k in 0..3 {
            assert_eq!(
                p[k].to_bits(),
                q[k].to_bits(),
                "{what}: point {i} coordinate {k}: {} vs {}",
                p[k],
                q[k]
            );
        }
    }
}

pub fn tmp_path(dir: &tempfile::TempDir, name: &str) -> PathBuf {
    dir.path().join(name)
}

/// Bytes of a file written by the code under test.
pub fn written_pcd(cloud: &PointCloud, enc: PcdEncoding, colors: Option<&[[u8; 3]]>) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("w.pcd");
    write_pcd_with(&p, cloud, enc, colors).unwrap();
    std::fs::read(&p).unwrap()
}

pub fn written_ply(cloud: &PointCloud, enc: PlyEncoding, colors: Option<&[[u8; 3]]>) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("w.ply");
    write_ply(&p, cloud, enc, colors).unwrap();
    std::fs::read(&p).unwrap()
}

/// The repository's `data/` folder.
pub fn repo_data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../data")
        .join(rel)
}
