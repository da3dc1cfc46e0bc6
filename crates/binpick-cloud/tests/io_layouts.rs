//! Reading files of layouts binpick does not write itself: extra fields, F8 and integer
//! coordinates, COUNT > 1, padding, organised clouds with NaNs, PCL's ASCII conventions,
//! PLY with other property types and other elements, and the real PCL sample file.

// Helpers outside #[test] functions may fail loudly too: this is test code.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use binpick_cloud::PointCloud;
use binpick_cloud::io::{
    CloudFormat, Encoding, IoError, read_cloud, read_cloud_from_bytes,
    read_cloud_with_colors_from_bytes,
};
use common::*;

const DATA_KINDS: [&str; 3] = ["ascii", "binary", "binary_compressed"];

fn expected_encoding(data: &str) -> Encoding {
    match data {
        "ascii" => Encoding::Ascii,
        "binary" => Encoding::Binary,
        _ => Encoding::BinaryCompressed,
    }
}

#[test]
fn pcd_with_normals_and_curvature() {
    let cols = [
        XYZ_F4[0],
        XYZ_F4[1],
        XYZ_F4[2],
        col("normal_x", 'F', 4, 1),
        col("normal_y", 'F', 4, 1),
        col("normal_z", 'F', 4, 1),
        col("curvature", 'F', 4, 1),
    ];
    let mut rng = XorShift(7);
    let pts: Vec<[f32; 3]> = (0..50)
        .map(|_| {
            [
                rng.f32_in(-5.0, 5.0),
                rng.f32_in(-5.0, 5.0),
                rng.f32_in(0.0, 5.0),
            ]
        })
        .collect();
    let rows: Vec<Vec<f64>> = pts
        .iter()
        .map(|p| vec![p[0] as f64, p[1] as f64, p[2] as f64, 0.0, 0.6, 0.8, 0.01])
        .collect();
    for data in DATA_KINDS {
        let bytes = pcd_file(&cols, &rows, rows.len(), 1, data);
        let (c, r) = read_cloud_from_bytes(&bytes, "normals.pcd").unwrap();
        assert_eq!(c.points, pts, "{data}");
        assert_eq!(r.encoding, expected_encoding(data));
        assert_eq!(
            r.fields,
            [
                "x",
                "y",
                "z",
                "normal_x",
                "normal_y",
                "normal_z",
                "curvature"
            ]
        );
    }
}

#[test]
fn pcd_with_f8_coordinates() {
    let cols = [
        col("x", 'F', 8, 1),
        col("y", 'F', 8, 1),
        col("z", 'F', 8, 1),
        col("intensity", 'F', 4, 1),
    ];
    let vals = [
        [0.1f64, -2.000_000_000_1, 1_234.567_890_123],
        [1e-300, 3.0, -4.5],
        [123_456_789.123_457, 0.0, -0.0],
    ];
    let rows: Vec<Vec<f64>> = vals.iter().map(|v| vec![v[0], v[1], v[2], 7.0]).collect();
    for data in DATA_KINDS {
        let bytes = pcd_file(&cols, &rows, 3, 1, data);
        let (c, _) = read_cloud_from_bytes(&bytes, "f8.pcd").unwrap();
        let expect: Vec<[f32; 3]> = vals
            .iter()
            .map(|v| [v[0] as f32, v[1] as f32, v[2] as f32])
            .collect();
        assert_eq!(c.points, expect, "{data}");
    }
}

#[test]
fn pcd_with_count_gt_1_padding_and_rgb() {
    // x y z, a 33-float FPFH histogram, 3 bytes of PCL padding, a U2 COUNT 2 field, rgb.
    let cols = [
        XYZ_F4[0],
        XYZ_F4[1],
        XYZ_F4[2],
        col("fpfh", 'F', 4, 33),
        col("_", 'U', 1, 3),
        col("ring", 'U', 2, 2),
        col("rgb", 'F', 4, 1),
    ];
    let colors = colors_for(20);
    let mut rows = Vec::new();
    let mut pts = Vec::new();
    for (i, c) in colors.iter().enumerate() {
        let p = [i as f32, -(i as f32) * 0.5, 100.0 + i as f32];
        pts.push(p);
        let mut r: Vec<f64> = p.iter().map(|&v| v as f64).collect();
        r.extend((0..33).map(|k| (k * i) as f64 * 0.25));
        r.extend([0.0, 0.0, 0.0]);
        r.extend([i as f64, 65535.0]);
        // binary: the bits of the F4; the ASCII writer prints the float, whose bits are kept.
        let packed =
            f32::from_bits((u32::from(c[0]) << 16) | (u32::from(c[1]) << 8) | u32::from(c[2]));
        r.push(packed as f64);
        rows.push(r);
    }
    for data in DATA_KINDS {
        let bytes = pcd_file(&cols, &rows, 20, 1, data);
        let l = read_cloud_with_colors_from_bytes(&bytes, "fpfh.pcd").unwrap();
        assert_eq!(l.cloud.points, pts, "{data}");
        assert_eq!(l.colors.as_deref(), Some(&colors[..]), "{data}");
        assert_eq!(l.report.fields, ["x", "y", "z", "fpfh", "_", "ring", "rgb"]);
    }
}

#[test]
fn pcd_with_every_integer_type_and_integer_coordinates() {
    let cols = [
        col("a", 'U', 1, 1),
        col("x", 'I', 2, 1),
        col("b", 'I', 1, 2),
        col("y", 'I', 4, 1),
        col("c", 'U', 2, 1),
        col("z", 'U', 4, 1),
        col("d", 'U', 8, 1),
        col("e", 'I', 8, 1),
        col("f", 'F', 8, 1),
    ];
    let rows = vec![
        vec![
            255.0,
            -300.0,
            -128.0,
            127.0,
            -70000.0,
            65535.0,
            4_000_000_000.0,
            1.0,
            -1.0,
            0.5,
        ],
        vec![0.0, 32767.0, 1.0, 2.0, 123.0, 0.0, 7.0, 2.0, 3.0, 4.0],
    ];
    for data in DATA_KINDS {
        let bytes = pcd_file(&cols, &rows, 2, 1, data);
        let (c, _) = read_cloud_from_bytes(&bytes, "ints.pcd").unwrap();
        assert_eq!(
            c.points,
            vec![[-300.0, -70000.0, 4e9], [32767.0, 123.0, 7.0]],
            "{data}"
        );
    }
}

/// An organised 8 x 6 cloud like a Kinect frame: x y z rgba, NaN where there is no depth.
/// Rows to write, the finite points, their colours, the number of NaN points.
type Organised = (Vec<Vec<f64>>, Vec<[f32; 3]>, Vec<[u8; 3]>, usize);

fn organised_rows() -> Organised {
    let (w, h) = (8, 6);
    let mut rows = Vec::new();
    let mut finite = Vec::new();
    let mut colors = Vec::new();
    let mut nan = 0;
    for v in 0..h {
        for u in 0..w {
            let rgba = 0xFF00_0000u32 | ((u as u32 * 30) << 16) | ((v as u32 * 40) << 8) | 7;
            if (u + v) % 3 == 0 {
                rows.push(vec![f64::NAN, f64::NAN, f64::NAN, rgba as f64]);
                nan += 1;
            } else {
                let p = [u as f32 * 0.01, v as f32 * 0.01, 1.0 + u as f32 * 0.001];
                rows.push(vec![p[0] as f64, p[1] as f64, p[2] as f64, rgba as f64]);
                finite.push(p);
                colors.push([(u * 30) as u8, (v * 40) as u8, 7]);
            }
        }
    }
    (rows, finite, colors, nan)
}

#[test]
fn organised_pcd_with_nans_drops_and_counts_them() {
    let cols = [XYZ_F4[0], XYZ_F4[1], XYZ_F4[2], col("rgba", 'U', 4, 1)];
    let (rows, finite, colors, nan) = organised_rows();
    assert!(nan > 0);
    for data in DATA_KINDS {
        let bytes = pcd_file(&cols, &rows, 8, 6, data);
        let l = read_cloud_with_colors_from_bytes(&bytes, "kinect.pcd").unwrap();
        assert_eq!(l.cloud.points, finite, "{data}");
        assert_eq!(l.colors.as_deref(), Some(&colors[..]), "{data}");
        let r = &l.report;
        assert_eq!((r.width, r.height, r.points_in_file), (8, 6, 48), "{data}");
        assert_eq!(r.non_finite_dropped, nan, "{data}");
        assert!(r.is_organized());
    }
}

#[test]
fn all_nan_cloud_is_an_error_that_counts_the_nans() {
    let cols = XYZ_F4;
    let rows = vec![vec![f64::NAN, 0.0, 0.0]; 12];
    for data in DATA_KINDS {
        let bytes = pcd_file(&cols, &rows, 4, 3, data);
        let err = read_cloud_from_bytes(&bytes, "scene.pcd").unwrap_err();
        assert!(
            matches!(
                err,
                IoError::NoFinitePoints {
                    points_in_file: 12,
                    non_finite_dropped: 12,
                    ..
                }
            ),
            "{err:?}"
        );
        assert_eq!(
            err.to_string(),
            "scene.pcd: contains no finite points (12 NaN/infinite points dropped)"
        );
    }
}

#[test]
fn pcd_ascii_follows_pcl_conventions() {
    // Comments, CRLF, blank lines between rows, "nan", COUNT 0 meaning 1, COLUMNS alias,
    // lower-case keywords, rgb written as an integer (PCL) or as a float (old PCL).
    let text = "# .PCD v.7 - Point Cloud Data file format\r\n\
                VERSION .7\r\n\
                COLUMNS x y z rgb\r\n\
                size 4 4 4 4\r\n\
                TYPE F F F F\r\n\
                COUNT 1 1 0 1\r\n\
                WIDTH 4\r\n\
                HEIGHT 1\r\n\
                VIEWPOINT 0 0 0 1 0 0 0\r\n\
                POINTS 4   \r\n\
                DATA ascii\r\n\
                1 2 3 16711680\r\n\
                \r\n\
                nan nan nan 255\r\n\
                \t\n\
                -1.5e-3 .5 5. 2.3418052e-38\n\
                4 5 6 65280";
    let l = read_cloud_with_colors_from_bytes(text.as_bytes(), "pcl_ascii.pcd").unwrap();
    assert_eq!(
        l.cloud.points,
        vec![[1.0, 2.0, 3.0], [-1.5e-3, 0.5, 5.0], [4.0, 5.0, 6.0]]
    );
    let packed_float = 2.341_805_2e-38f32.to_bits();
    assert_eq!(
        l.colors.unwrap(),
        vec![
            [255, 0, 0],
            [
                (packed_float >> 16) as u8,
                (packed_float >> 8) as u8,
                packed_float as u8
            ],
            [0, 255, 0]
        ]
    );
    assert_eq!(l.report.non_finite_dropped, 1);
    assert_eq!(l.report.points_in_file, 4);
}

#[test]
fn pcd_header_may_omit_optional_lines() {
    // No VERSION, no COUNT, no HEIGHT, no VIEWPOINT; WIDTH only.
    let text = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nDATA ascii\n1 2 3\n4 5 6\n";
    let (c, r) = read_cloud_from_bytes(text.as_bytes(), "min.pcd").unwrap();
    assert_eq!(c.len(), 2);
    assert_eq!((r.width, r.height, r.points_in_file), (2, 1, 2));
    // POINTS only.
    let text = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n1 2 3\n";
    assert_eq!(
        read_cloud_from_bytes(text.as_bytes(), "min.pcd")
            .unwrap()
            .0
            .len(),
        1
    );
}

#[test]
fn binary_pcd_tolerates_pcl_zero_padding_after_the_data() {
    // PCL pads its files with zeros after the data (the sample files end with ~4 KB of them).
    let rows = vec![vec![1.0, 2.0, 3.0]; 3];
    for data in ["binary", "binary_compressed"] {
        let mut bytes = pcd_file(&XYZ_F4, &rows, 3, 1, data);
        bytes.extend(std::iter::repeat_n(0u8, 4000));
        let (c, _) = read_cloud_from_bytes(&bytes, "padded.pcd").unwrap();
        assert_eq!(c.len(), 3, "{data}");
    }
}

#[test]
fn real_pcl_milk_model_loads() {
    let path = repo_data("pcl/milk_model.pcd");
    let bytes = std::fs::read(&path).expect("data/pcl/milk_model.pcd is in the repository");
    // The expected count comes from the file's own header.
    let start = pcd_data_start(&bytes);
    let head = String::from_utf8_lossy(&bytes[..start]).into_owned();
    let points: usize = head
        .lines()
        .find_map(|l| l.strip_prefix("POINTS "))
        .and_then(|v| v.trim().parse().ok())
        .expect("POINTS line");
    assert!(head.contains("DATA binary_compressed"));
    let l = binpick_cloud::io::read_cloud_with_colors(&path).unwrap();
    let r = &l.report;
    assert_eq!(r.points_in_file, points);
    assert_eq!(l.cloud.len() + r.non_finite_dropped, points);
    assert_eq!(l.cloud.len(), points, "the model has no NaN points");
    assert_eq!(
        (r.format, r.encoding),
        (CloudFormat::Pcd, Encoding::BinaryCompressed)
    );
    assert_eq!(r.fields, ["x", "y", "z", "rgba"]);
    assert_eq!(l.colors.as_ref().map(Vec::len), Some(points));
    // A milk carton in metres: some centimetres to a few decimetres across.
    let d = l.cloud.bounds().unwrap().diagonal();
    assert!((0.05..1.0).contains(&d), "diagonal {d}");
    assert!(l.cloud.first_non_finite().is_none());
    // The same file through the path API without colours.
    let (c, r2) = read_cloud(&path).unwrap();
    assert_eq!(c, l.cloud);
    assert_eq!(&r2, r);
}

fn ply_binary(
    header_props: &[(&str, &str)],
    rows: &[Vec<f64>],
    big: bool,
    extra: &str,
    extra_data: &[u8],
) -> Vec<u8> {
    let mut h = format!(
        "ply\nformat {} 1.0\ncomment test\nelement vertex {}\n",
        if big {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        },
        rows.len()
    );
    for (ty, name) in header_props {
        h.push_str(&format!("property {ty} {name}\n"));
    }
    h.push_str(extra);
    h.push_str("end_header\n");
    let mut out = h.into_bytes();
    for r in rows {
        for ((ty, _), v) in header_props.iter().zip(r) {
            out.extend(ply_scalar_bytes(ty, *v, big));
        }
    }
    out.extend_from_slice(extra_data);
    out
}

#[test]
fn ply_with_double_coordinates_other_properties_and_faces() {
    let props = [
        ("double", "x"),
        ("double", "y"),
        ("double", "z"),
        ("float", "nx"),
        ("uchar", "red"),
        ("uchar", "green"),
        ("uchar", "blue"),
        ("int", "label"),
    ];
    let rows = vec![
        vec![0.1, 0.2, 0.3, 1.0, 10.0, 20.0, 30.0, -5.0],
        vec![1e-3, -2.5, 1e6, 0.0, 255.0, 0.0, 128.0, 7.0],
        vec![4.0, 5.0, 6.0, 0.0, 1.0, 2.0, 3.0, 8.0],
    ];
    for big in [false, true] {
        // Two faces: a triangle and a quad, with uchar counts and int indices.
        let mut faces = Vec::new();
        for f in [vec![0, 1, 2], vec![0, 1, 2, 0]] {
            faces.push(f.len() as u8);
            for i in f {
                faces.extend(ply_scalar_bytes("int", i as f64, big));
            }
        }
        let bytes = ply_binary(
            &props,
            &rows,
            big,
            "element face 2\nproperty list uchar int vertex_indices\n",
            &faces,
        );
        let l = read_cloud_with_colors_from_bytes(&bytes, "mesh.ply").unwrap();
        let expect: Vec<[f32; 3]> = rows
            .iter()
            .map(|r| [r[0] as f32, r[1] as f32, r[2] as f32])
            .collect();
        assert_eq!(l.cloud.points, expect, "big={big}");
        assert_eq!(
            l.colors.unwrap(),
            vec![[10, 20, 30], [255, 0, 128], [1, 2, 3]]
        );
        assert_eq!(
            l.report.fields,
            ["x", "y", "z", "nx", "red", "green", "blue", "label"]
        );
        assert_eq!(
            l.report.encoding,
            if big {
                Encoding::BinaryBigEndian
            } else {
                Encoding::BinaryLittleEndian
            }
        );
    }
    // The same mesh in ASCII, with the face element before the vertices.
    let text = "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n\
                element vertex 3\nproperty double x\nproperty double y\nproperty double z\n\
                property float nx\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
                property int label\nend_header\n3 0 1 2\n0.1 0.2 0.3 1 10 20 30 -5\n\
                0.001 -2.5 1000000 0 255 0 128 7\n4 5 6 0 1 2 3 8\n";
    let l = read_cloud_with_colors_from_bytes(text.as_bytes(), "mesh.ply").unwrap();
    assert_eq!(l.cloud.len(), 3);
    assert_eq!(l.cloud.points[1], [1e-3, -2.5, 1e6]);
    assert_eq!(l.colors.unwrap()[1], [255, 0, 128]);
}

#[test]
fn ply_integer_coordinates_and_float_colours() {
    let props = [
        ("short", "x"),
        ("int", "y"),
        ("uint", "z"),
        ("float", "red"),
        ("float", "green"),
        ("float", "blue"),
    ];
    let rows = vec![vec![-3.0, 70000.0, 5.0, 1.0, 0.5, 0.0]];
    let bytes = ply_binary(&props, &rows, false, "", &[]);
    let l = read_cloud_with_colors_from_bytes(&bytes, "ints.ply").unwrap();
    assert_eq!(l.cloud.points, vec![[-3.0, 70000.0, 5.0]]);
    assert_eq!(l.colors.unwrap(), vec![[255, 128, 0]]);
}

#[test]
fn ply_ascii_accepts_nan_inf_and_short_numbers() {
    let text = "ply\r\nformat ascii 1.0\r\nelement vertex 5\r\nproperty float x\r\n\
                property float y\r\nproperty float z\r\nend_header\r\n\
                1 2 3\r\nnan 0 0\r\n.5 5. -1e-3\r\n\r\n0 inf 0\r\n  -0 +7 NaN  \r\n";
    let (c, r) = read_cloud_from_bytes(text.as_bytes(), "odd.ply").unwrap();
    assert_eq!(c.points, vec![[1.0, 2.0, 3.0], [0.5, 5.0, -1e-3]]);
    assert_eq!((r.points_in_file, r.non_finite_dropped), (5, 3));
}

#[test]
fn extension_is_case_insensitive() {
    let cloud = PointCloud::new(vec![[1.0, 2.0, 3.0]]);
    let bytes = written_ply(&cloud, binpick_cloud::io::PlyEncoding::Ascii, None);
    assert_eq!(read_cloud_from_bytes(&bytes, "UPPER.PLY").unwrap().0, cloud);
}
