//! Honest readers: header counts that disagree with the data are errors stating both numbers
//! (never a silent prefix of the data), a configurable maximum point count, and the PCD
//! `VIEWPOINT` read, reported and written.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use binpick_cloud::PointCloud;
use binpick_cloud::io::{
    IoError, PcdEncoding, PlyEncoding, ReadLimits, Viewpoint, read_cloud, read_cloud_from_bytes,
    read_cloud_with, read_cloud_with_from_bytes, write_pcd_with_viewpoint,
};
use common::*;

fn cloud(n: usize) -> PointCloud {
    PointCloud::new(
        (0..n)
            .map(|i| [i as f32, (i % 7) as f32 * 0.5 + 1.0, 3.0 + (i % 3) as f32])
            .collect(),
    )
}

fn err(bytes: &[u8], name: &str) -> String {
    let e = read_cloud_from_bytes(bytes, name).unwrap_err().to_string();
    assert!(e.starts_with(&format!("{name}: ")), "{e}");
    e
}

/// The header's WIDTH and POINTS both set to `n` (as a tool that rewrote the header would).
fn claim(bytes: &[u8], from: usize, to: usize) -> Vec<u8> {
    replace_in_header(
        &replace_in_header(bytes, &format!("WIDTH {from}"), &format!("WIDTH {to}")),
        &format!("POINTS {from}"),
        &format!("POINTS {to}"),
    )
}

#[test]
fn pcd_points_smaller_than_the_data_is_an_error_with_both_counts() {
    // The case seen in the field: a 1200-point scan whose header says 1000 points.
    let c = cloud(1200);
    let bin = claim(&written_pcd(&c, PcdEncoding::Binary, None), 1200, 1000);
    let e = err(&bin, "scan.pcd");
    assert!(
        e.contains("header says POINTS 1000 but the data holds 1200 points of 12 bytes"),
        "{e}"
    );
    let e = err(
        &claim(
            &written_pcd(&c, PcdEncoding::BinaryCompressed, None),
            1200,
            1000,
        ),
        "scan.pcd",
    );
    assert!(
        e.contains(
            "header says POINTS 1000 (12000 bytes of 12-byte points) but the compressed block \
             unpacks to 14400 bytes, i.e. 1200 points"
        ),
        "{e}"
    );
    let e = err(
        &claim(&written_pcd(&c, PcdEncoding::Ascii, None), 1200, 1000),
        "scan.pcd",
    );
    assert!(
        e.contains("header says POINTS 1000 but 1200 data rows follow it"),
        "{e}"
    );
    // An organised header whose WIDTH x HEIGHT matches POINTS but not the data.
    let org = claim(&written_pcd(&c, PcdEncoding::Binary, None), 1200, 1000);
    let org = replace_in_header(&org, "WIDTH 1000", "WIDTH 500");
    let org = replace_in_header(&org, "HEIGHT 1", "HEIGHT 2");
    let e = err(&org, "org.pcd");
    assert!(
        e.contains("header says POINTS 1000 (WIDTH 500 x HEIGHT 2) but the data holds 1200"),
        "{e}"
    );
    // Extra bytes that are not a whole point, and data after a compressed block.
    let mut odd = written_pcd(&c, PcdEncoding::Binary, None);
    odd.extend([1u8, 2, 3]);
    assert!(err(&odd, "odd.pcd").contains("but 3 more bytes of data follow them"));
    let mut after = written_pcd(&c, PcdEncoding::BinaryCompressed, None);
    after.extend([7u8; 10]);
    assert!(err(&after, "after.pcd").contains("10 bytes of data follow the compressed block"));
    // PCL's zero padding stays fine.
    let mut padded = written_pcd(&c, PcdEncoding::Binary, None);
    padded.extend([0u8; 4096]);
    assert_eq!(read_cloud_from_bytes(&padded, "pad.pcd").unwrap().0, c);
}

#[test]
fn ply_vertex_count_smaller_than_the_data_is_an_error_with_both_counts() {
    let c = cloud(40);
    for enc in [
        PlyEncoding::Ascii,
        PlyEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian,
    ] {
        let v = replace_in_header(
            &written_ply(&c, enc, None),
            "element vertex 40",
            "element vertex 30",
        );
        let e = err(&v, "v.ply");
        assert!(
            e.contains("header says 30 vertices but the data holds 40"),
            "{enc:?}: {e}"
        );
    }
}

#[test]
fn maximum_point_count_is_checked_from_the_header() {
    let c = cloud(40);
    let limits = ReadLimits {
        max_points: 39,
        ..ReadLimits::default()
    };
    let files = [
        (written_pcd(&c, PcdEncoding::Ascii, None), "a.pcd"),
        (written_pcd(&c, PcdEncoding::Binary, None), "b.pcd"),
        (
            written_pcd(&c, PcdEncoding::BinaryCompressed, None),
            "c.pcd",
        ),
        (written_ply(&c, PlyEncoding::Ascii, None), "a.ply"),
        (
            written_ply(&c, PlyEncoding::BinaryLittleEndian, None),
            "b.ply",
        ),
    ];
    let dir = tempfile::tempdir().unwrap();
    for (bytes, name) in &files {
        let e = read_cloud_with_from_bytes(bytes, name, &limits).unwrap_err();
        assert!(
            matches!(
                e,
                IoError::TooLarge {
                    count: 40,
                    limit: 39,
                    ..
                }
            ),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            format!(
                "{name}: 40 points, more than the limit of 39 points (ReadLimits::max_points); \
                 raise the limit to read this file"
            )
        );
        // The path reader checks the header before loading the rest of the file.
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let e = read_cloud_with(&path, &limits).unwrap_err();
        assert!(matches!(e, IoError::TooLarge { .. }), "{e}");
        assert_eq!(e.path(), path);
        // At the limit, the file reads.
        let ok = ReadLimits {
            max_points: 40,
            ..limits
        };
        assert_eq!(read_cloud_with(&path, &ok).unwrap().cloud, c);
    }
    assert_eq!(ReadLimits::default().max_points, 50_000_000);
}

#[test]
fn viewpoint_is_read_reported_and_written() {
    let c = cloud(5);
    let vp = Viewpoint {
        position: [100.0, -20.5, 800.25],
        orientation_wxyz: [0.5, 0.5, -0.5, 0.5],
    };
    let dir = tempfile::tempdir().unwrap();
    for enc in [
        PcdEncoding::Ascii,
        PcdEncoding::Binary,
        PcdEncoding::BinaryCompressed,
    ] {
        let path = dir.path().join(format!("vp_{enc:?}.pcd"));
        write_pcd_with_viewpoint(&path, &c, enc, None, &vp).unwrap();
        let (back, report) = read_cloud(&path).unwrap();
        assert_eq!(back, c);
        assert_eq!(report.viewpoint, Some(vp), "{enc:?}");
        assert_eq!(report.sensor_viewpoint(), Some(&vp));
    }
    // PCL's default says nothing about the sensor.
    let (_, report) =
        read_cloud_from_bytes(&written_pcd(&c, PcdEncoding::Binary, None), "d.pcd").unwrap();
    assert_eq!(report.viewpoint, Some(Viewpoint::default()));
    assert!(report.viewpoint.unwrap().is_pcl_default());
    assert_eq!(report.sensor_viewpoint(), None);
    // A quaternion that is not of unit length is normalised.
    let text = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\n\
                VIEWPOINT 1 2 3 0 0 0 2\nPOINTS 1\nDATA ascii\n1 2 3\n";
    let (_, report) = read_cloud_from_bytes(text.as_bytes(), "q.pcd").unwrap();
    let v = report.viewpoint.unwrap();
    assert_eq!(v.position, [1.0, 2.0, 3.0]);
    assert_eq!(v.orientation_wxyz, [0.0, 0.0, 0.0, 1.0]);
    assert_eq!(v.scaled(1000.0).position, [1000.0, 2000.0, 3000.0]);
    // Without a VIEWPOINT line, or in PLY, there is none.
    let no_vp = text.replace("VIEWPOINT 1 2 3 0 0 0 2\n", "");
    assert_eq!(
        read_cloud_from_bytes(no_vp.as_bytes(), "n.pcd")
            .unwrap()
            .1
            .viewpoint,
        None
    );
    // Malformed viewpoints are errors naming the line.
    for (bad, want) in [
        ("VIEWPOINT 1 2 3\n", "header line 8: VIEWPOINT has 3 values"),
        (
            "VIEWPOINT 1 2 3 1 0 0 x\n",
            "VIEWPOINT value \"x\" is not a finite number",
        ),
        ("VIEWPOINT 1 2 nan 1 0 0 0\n", "is not a finite number"),
        ("VIEWPOINT 1 2 3 0 0 0 0\n", "zero orientation quaternion"),
    ] {
        let t = text.replace("VIEWPOINT 1 2 3 0 0 0 2\n", bad);
        let e = err(t.as_bytes(), "vp.pcd");
        assert!(e.contains(want), "{bad}: {e}");
    }
}
