//! Write -> read round trips for every encoding, with and without colours.
//!
//! Tolerance: binary encodings must give back the identical bits. ASCII encodings are held
//! to the same standard: the writers print the shortest decimal that parses back to the same
//! `f32` and the readers parse `F4`/`float` tokens directly as `f32` (no double rounding), so
//! the documented ASCII tolerance is [`ASCII_TOLERANCE_ULPS`] = 0 ulp, and `-0.0` keeps its
//! sign. (Files from other writers, e.g. PCL's 8-significant-digit ASCII, can differ from
//! the original binary values by a few ulp; that is the file's precision, not the reader's.)

// Helpers outside #[test] functions may fail loudly too: this is test code.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use binpick_cloud::PointCloud;
use binpick_cloud::io::{
    CloudFormat, Encoding, IoError, PcdEncoding, PlyEncoding, read_cloud, read_cloud_from_bytes,
    read_cloud_with_colors, read_cloud_with_colors_from_bytes, write_cloud, write_pcd,
    write_pcd_with, write_ply,
};
use common::*;

/// Largest allowed distance, in units in the last place, between a written and a re-read
/// ASCII coordinate.
const ASCII_TOLERANCE_ULPS: u32 = 0;

fn ulps(a: f32, b: f32) -> u32 {
    if a.to_bits() == b.to_bits() {
        return 0;
    }
    // Map the float bits onto a monotonic integer line.
    let key = |v: f32| {
        let i = v.to_bits() as i32;
        if i < 0 { i32::MIN - i } else { i }
    };
    key(a).abs_diff(key(b))
}

fn assert_within_ulps(a: &PointCloud, b: &PointCloud, max: u32, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: point count");
    for (i, (p, q)) in a.points.iter().zip(&b.points).enumerate() {
        for k in 0..3 {
            let d = ulps(p[k], q[k]);
            assert!(
                d <= max,
                "{what}: point {i} coordinate {k}: wrote {:e}, read {:e} ({d} ulp apart)",
                p[k],
                q[k]
            );
            assert_eq!(
                p[k].is_sign_negative(),
                q[k].is_sign_negative(),
                "{what}: sign of {i}/{k}"
            );
        }
    }
}

const PCD_ENCODINGS: [(PcdEncoding, Encoding); 3] = [
    (PcdEncoding::Ascii, Encoding::Ascii),
    (PcdEncoding::Binary, Encoding::Binary),
    (PcdEncoding::BinaryCompressed, Encoding::BinaryCompressed),
];
const PLY_ENCODINGS: [(PlyEncoding, Encoding); 3] = [
    (PlyEncoding::Ascii, Encoding::Ascii),
    (
        PlyEncoding::BinaryLittleEndian,
        Encoding::BinaryLittleEndian,
    ),
    (PlyEncoding::BinaryBigEndian, Encoding::BinaryBigEndian),
];

#[test]
fn ulps_helper_detects_differences() {
    assert_eq!(ulps(1.0, 1.0), 0);
    assert_eq!(ulps(1.0, f32::from_bits(1.0f32.to_bits() + 1)), 1);
    assert_eq!(ulps(0.0, -0.0), 0); // equal values; the sign is checked separately
    assert_eq!(ulps(-1.0, f32::from_bits((-1.0f32).to_bits() + 1)), 1);
    assert!(ulps(1.0, 1.000_001) > 0);
}

#[test]
fn pcd_round_trip_every_encoding() {
    let cloud = tricky_cloud();
    let dir = tempfile::tempdir().unwrap();
    for (enc, expect) in PCD_ENCODINGS {
        let path = dir.path().join(format!("c_{expect}.pcd"));
        write_pcd_with(&path, &cloud, enc, None).unwrap();
        let loaded = read_cloud_with_colors(&path).unwrap();
        let what = format!("PCD {expect}");
        if enc == PcdEncoding::Ascii {
            assert_within_ulps(&cloud, &loaded.cloud, ASCII_TOLERANCE_ULPS, &what);
        } else {
            assert_bits_equal(&cloud, &loaded.cloud, &what);
        }
        assert_eq!(loaded.colors, None, "{what}");
        let r = &loaded.report;
        assert_eq!(r.format, CloudFormat::Pcd);
        assert_eq!(r.encoding, expect);
        assert_eq!(r.points_in_file, cloud.len());
        assert_eq!(r.non_finite_dropped, 0);
        assert_eq!((r.width, r.height), (cloud.len(), 1));
        assert_eq!(r.fields, ["x", "y", "z"]);
    }
}

#[test]
fn pcd_coloured_round_trip_every_encoding() {
    let cloud = tricky_cloud();
    let colors = colors_for(cloud.len());
    let dir = tempfile::tempdir().unwrap();
    for (enc, expect) in PCD_ENCODINGS {
        let path = dir.path().join(format!("rgb_{expect}.pcd"));
        write_pcd_with(&path, &cloud, enc, Some(&colors)).unwrap();
        let text = std::fs::read(&path).unwrap();
        let head = String::from_utf8_lossy(&text[..pcd_data_start(&text)]).into_owned();
        assert!(head.contains("FIELDS x y z rgb\n"), "{head}");
        let rgb_type = if enc == PcdEncoding::Ascii { "U" } else { "F" };
        assert!(head.contains(&format!("TYPE F F F {rgb_type}\n")), "{head}");
        let loaded = read_cloud_with_colors(&path).unwrap();
        assert_within_ulps(&cloud, &loaded.cloud, 0, &format!("PCD rgb {expect}"));
        assert_eq!(
            loaded.colors.as_deref(),
            Some(&colors[..]),
            "PCD rgb {expect}"
        );
        assert_eq!(loaded.report.fields, ["x", "y", "z", "rgb"]);
    }
}

#[test]
fn pcd_rgb_is_packed_like_pcl() {
    // PCL: rgb is an F4 whose bits are 0x00RRGGBB. In ASCII it is declared U4 and written as
    // that integer, as PCL 1.13 writes it.
    let cloud = PointCloud::new(vec![[1.0, 2.0, 3.0]]);
    let colors = [[0x12, 0x34, 0x56]];
    let bin = written_pcd(&cloud, PcdEncoding::Binary, Some(&colors));
    let data = &bin[pcd_data_start(&bin)..];
    assert_eq!(data.len(), 16);
    assert_eq!(&data[12..16], &0x0012_3456u32.to_le_bytes());
    let ascii = String::from_utf8(written_pcd(&cloud, PcdEncoding::Ascii, Some(&colors))).unwrap();
    assert!(
        ascii.contains("FIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\n"),
        "{ascii}"
    );
    assert!(ascii.ends_with("DATA ascii\n1 2 3 1193046\n"), "{ascii}");
}

#[test]
fn ply_round_trip_every_encoding_with_and_without_colours() {
    let cloud = tricky_cloud();
    let colors = colors_for(cloud.len());
    let dir = tempfile::tempdir().unwrap();
    for (enc, expect) in PLY_ENCODINGS {
        for with_colors in [false, true] {
            let what = format!("PLY {expect} colours={with_colors}");
            let path = dir.path().join(format!("c_{expect}_{with_colors}.ply"));
            let c = with_colors.then_some(&colors[..]);
            write_ply(&path, &cloud, enc, c).unwrap();
            let loaded = read_cloud_with_colors(&path).unwrap();
            if enc == PlyEncoding::Ascii {
                assert_within_ulps(&cloud, &loaded.cloud, ASCII_TOLERANCE_ULPS, &what);
            } else {
                assert_bits_equal(&cloud, &loaded.cloud, &what);
            }
            assert_eq!(loaded.colors.as_deref(), c, "{what}");
            let r = &loaded.report;
            assert_eq!(r.format, CloudFormat::Ply, "{what}");
            assert_eq!(r.encoding, expect, "{what}");
            assert_eq!((r.points_in_file, r.non_finite_dropped), (cloud.len(), 0));
            let expected_fields: &[&str] = if with_colors {
                &["x", "y", "z", "red", "green", "blue"]
            } else {
                &["x", "y", "z"]
            };
            assert_eq!(r.fields, expected_fields, "{what}");
        }
    }
}

#[test]
fn ply_header_is_standard() {
    let cloud = PointCloud::new(vec![[1.0, 2.0, 3.0]]);
    let bytes = written_ply(&cloud, PlyEncoding::BinaryLittleEndian, Some(&[[1, 2, 3]]));
    let text = String::from_utf8_lossy(&bytes);
    assert!(
        text.starts_with("ply\nformat binary_little_endian 1.0\n"),
        "{text}"
    );
    for line in [
        "element vertex 1\n",
        "property float x\n",
        "property float y\n",
        "property float z\n",
        "property uchar red\n",
        "property uchar green\n",
        "property uchar blue\n",
        "end_header\n",
    ] {
        assert!(text.contains(line), "missing {line:?} in {text}");
    }
    let body = &bytes[bytes.len() - 15..];
    assert_eq!(&body[..4], &1.0f32.to_le_bytes());
    assert_eq!(&body[12..], &[1, 2, 3]);
    let be = written_ply(&cloud, PlyEncoding::BinaryBigEndian, None);
    assert_eq!(&be[be.len() - 12..be.len() - 8], &1.0f32.to_be_bytes());
}

#[test]
fn write_pcd_default_is_binary_xyz() {
    let cloud = tricky_cloud();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("plain.pcd");
    write_pcd(&path, &cloud).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let start = pcd_data_start(&bytes);
    let head = String::from_utf8_lossy(&bytes[..start]).into_owned();
    assert!(
        head.contains("FIELDS x y z\n") && head.contains("DATA binary\n"),
        "{head}"
    );
    assert_eq!(bytes.len() - start, cloud.len() * 12);
    let (back, report) = read_cloud(&path).unwrap();
    assert_bits_equal(&cloud, &back, "write_pcd");
    assert_eq!(report.encoding, Encoding::Binary);
}

#[test]
fn write_cloud_picks_format_by_extension() {
    let cloud = tricky_cloud();
    let dir = tempfile::tempdir().unwrap();
    for (name, format, encoding) in [
        ("a.pcd", CloudFormat::Pcd, Encoding::Binary),
        ("b.PCD", CloudFormat::Pcd, Encoding::Binary),
        ("c.ply", CloudFormat::Ply, Encoding::BinaryLittleEndian),
    ] {
        let path = dir.path().join(name);
        write_cloud(&path, &cloud).unwrap();
        let (back, report) = read_cloud(&path).unwrap();
        assert_bits_equal(&cloud, &back, name);
        assert_eq!(
            (report.format, report.encoding),
            (format, encoding),
            "{name}"
        );
    }
    for name in ["d.xyz", "noext"] {
        let path = dir.path().join(name);
        let err = write_cloud(&path, &cloud).unwrap_err();
        assert!(
            matches!(err, IoError::UnsupportedExtension { .. }),
            "{err:?}"
        );
        let msg = err.to_string();
        assert!(msg.starts_with(&path.display().to_string()), "{msg}");
        assert!(msg.contains(".pcd") && msg.contains(".ply"), "{msg}");
        assert!(!path.exists());
    }
}

#[test]
fn colour_count_must_match_point_count() {
    let cloud = tricky_cloud();
    let short = colors_for(cloud.len() - 1);
    let dir = tempfile::tempdir().unwrap();
    let pcd = dir.path().join("bad.pcd");
    let err = write_pcd_with(&pcd, &cloud, PcdEncoding::Binary, Some(&short)).unwrap_err();
    assert!(matches!(err, IoError::InvalidArgument { .. }), "{err:?}");
    assert!(err.to_string().starts_with(&pcd.display().to_string()));
    assert!(err.to_string().contains(&format!(
        "{} colours given for {} points",
        short.len(),
        cloud.len()
    )));
    assert!(!pcd.exists());
    let ply = dir.path().join("bad.ply");
    let long = colors_for(cloud.len() + 1);
    let err = write_ply(&ply, &cloud, PlyEncoding::Ascii, Some(&long)).unwrap_err();
    assert!(matches!(err, IoError::InvalidArgument { .. }), "{err:?}");
    assert!(!ply.exists());
}

#[test]
fn non_finite_points_are_written_then_dropped_and_counted() {
    let mut pts = tricky_cloud().points;
    pts[3] = [f32::NAN, 0.0, 0.0];
    pts[10] = [1.0, f32::INFINITY, 0.0];
    pts[11] = [1.0, 2.0, f32::NEG_INFINITY];
    let cloud = PointCloud::new(pts.clone());
    let colors = colors_for(cloud.len());
    let finite: Vec<usize> = (0..pts.len())
        .filter(|&i| ![3, 10, 11].contains(&i))
        .collect();
    let expect = PointCloud::new(finite.iter().map(|&i| pts[i]).collect());
    let expect_colors: Vec<[u8; 3]> = finite.iter().map(|&i| colors[i]).collect();
    let dir = tempfile::tempdir().unwrap();
    for (enc, e) in PCD_ENCODINGS {
        let path = dir.path().join(format!("nan_{e}.pcd"));
        write_pcd_with(&path, &cloud, enc, Some(&colors)).unwrap();
        let loaded = read_cloud_with_colors(&path).unwrap();
        assert_bits_equal(&expect, &loaded.cloud, &format!("PCD {e}"));
        assert_eq!(loaded.colors.as_deref(), Some(&expect_colors[..]));
        assert_eq!(loaded.report.points_in_file, pts.len());
        assert_eq!(loaded.report.non_finite_dropped, 3);
    }
    for (enc, e) in PLY_ENCODINGS {
        let path = dir.path().join(format!("nan_{e}.ply"));
        write_ply(&path, &cloud, enc, Some(&colors)).unwrap();
        let loaded = read_cloud_with_colors(&path).unwrap();
        assert_bits_equal(&expect, &loaded.cloud, &format!("PLY {e}"));
        assert_eq!(loaded.colors.as_deref(), Some(&expect_colors[..]));
        assert_eq!(loaded.report.non_finite_dropped, 3);
    }
}

#[test]
fn empty_cloud_can_be_written_but_reading_it_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let empty = PointCloud::default();
    for (enc, e) in PCD_ENCODINGS {
        let path = dir.path().join(format!("empty_{e}.pcd"));
        write_pcd_with(&path, &empty, enc, None).unwrap();
        let err = read_cloud(&path).unwrap_err();
        assert!(
            matches!(
                err,
                IoError::NoFinitePoints {
                    points_in_file: 0,
                    ..
                }
            ),
            "{err:?}"
        );
        assert_eq!(
            err.to_string(),
            format!("{}: contains no points", path.display())
        );
    }
    for (enc, e) in PLY_ENCODINGS {
        let path = dir.path().join(format!("empty_{e}.ply"));
        write_ply(&path, &empty, enc, None).unwrap();
        let err = read_cloud(&path).unwrap_err();
        assert!(err.to_string().ends_with("contains no points"), "{err}");
    }
}

#[test]
fn bytes_and_path_readers_agree() {
    let cloud = tricky_cloud();
    let colors = colors_for(cloud.len());
    let bytes = written_pcd(&cloud, PcdEncoding::BinaryCompressed, Some(&colors));
    let from_bytes = read_cloud_with_colors_from_bytes(&bytes, "mem.pcd").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("disk.pcd");
    std::fs::write(&path, &bytes).unwrap();
    let from_path = read_cloud_with_colors(&path).unwrap();
    assert_eq!(from_bytes, from_path);
    let (c, r) = read_cloud_from_bytes(&bytes, "mem.pcd").unwrap();
    assert_eq!((c, r), (from_path.cloud, from_path.report));
}

#[test]
fn large_structured_cloud_round_trips_through_lzf() {
    // A depth-image-like grid compresses well, so the LZF stream has many back references.
    let mut pts = Vec::new();
    for v in 0..240 {
        for u in 0..320 {
            pts.push([
                u as f32 * 0.5 - 80.0,
                v as f32 * 0.5 - 60.0,
                700.0 + ((u / 7 + v / 5) % 3) as f32,
            ]);
        }
    }
    let cloud = PointCloud::new(pts);
    let colors: Vec<[u8; 3]> = (0..cloud.len())
        .map(|i| [(i % 7) as u8, 100, 200])
        .collect();
    let bytes = written_pcd(&cloud, PcdEncoding::BinaryCompressed, Some(&colors));
    assert!(
        bytes.len() < cloud.len() * 16 / 2,
        "LZF should compress a grid ({} bytes)",
        bytes.len()
    );
    let loaded = read_cloud_with_colors_from_bytes(&bytes, "grid.pcd").unwrap();
    assert_bits_equal(&cloud, &loaded.cloud, "grid");
    assert_eq!(loaded.colors.unwrap(), colors);
}

#[test]
fn written_pcd_files_are_readable_by_pcd_rs() {
    // Interoperability: another reader (pcd-rs on its own, header and all) agrees.
    let cloud = tricky_cloud();
    for enc in [
        PcdEncoding::Ascii,
        PcdEncoding::Binary,
        PcdEncoding::BinaryCompressed,
    ] {
        let bytes = written_pcd(&cloud, enc, None);
        let reader = pcd_rs::DynReader::from_bytes(&bytes).unwrap();
        assert_eq!(reader.meta().num_points as usize, cloud.len());
        let records: Vec<pcd_rs::DynRecord> = reader.collect::<Result<_, _>>().unwrap();
        for (p, r) in cloud.points.iter().zip(&records) {
            let xyz: [f32; 3] = r.to_xyz().unwrap();
            for k in 0..3 {
                assert_eq!(p[k].to_bits(), xyz[k].to_bits(), "{enc:?}");
            }
        }
    }
}

#[test]
fn pcd_rs_written_files_are_readable() {
    // Files written by pcd-rs's own writer, with an F8 field and a COUNT 4 field.
    use pcd_rs::{DataKind, DynRecord, Field, Schema, ValueKind, WriterInit};
    for kind in [
        DataKind::Ascii,
        DataKind::Binary,
        DataKind::BinaryCompressed,
    ] {
        let schema: Schema = vec![
            ("x", ValueKind::F32, 1u64),
            ("y", ValueKind::F32, 1),
            ("z", ValueKind::F32, 1),
            ("t", ValueKind::F64, 1),
            ("h", ValueKind::U16, 4),
        ]
        .into_iter()
        .collect();
        let mut buf = Vec::new();
        let mut w = WriterInit {
            width: 3,
            height: 1,
            viewpoint: Default::default(),
            data_kind: kind,
            schema: Some(schema),
            version: None,
        }
        .build_from_writer(std::io::Cursor::new(&mut buf))
        .unwrap();
        for i in 0..3 {
            let f = i as f32;
            w.push(&DynRecord(vec![
                Field::F32(vec![f]),
                Field::F32(vec![f + 0.25]),
                Field::F32(vec![-f]),
                Field::F64(vec![1e300]),
                Field::U16(vec![1, 2, 3, 4]),
            ]))
            .unwrap();
        }
        w.finish().unwrap();
        let (c, r) = read_cloud_from_bytes(&buf, "pcdrs.pcd").unwrap();
        assert_eq!(
            c.points,
            vec![[0.0, 0.25, -0.0], [1.0, 1.25, -1.0], [2.0, 2.25, -2.0]],
            "{kind:?}"
        );
        assert_eq!(r.fields, ["x", "y", "z", "t", "h"]);
    }
}
