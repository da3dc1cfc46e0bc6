//! Corrupt, truncated, lying and mislabelled inputs: every one must give an `IoError` that
//! names the file and says what is wrong, without panicking and without a huge allocation.
//! A randomised mutation loop then checks that no mangled file panics either.
//!
//! The test binaries run under an allocator that refuses any single allocation above
//! `common::ALLOC_LIMIT` (see `common/alloc_guard.rs`): a reader that sized a buffer from a
//! lying header (e.g. 4e9 points) would abort the test run instead of passing.

// Helpers outside #[test] functions may fail loudly too: this is test code.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::panic::{AssertUnwindSafe, catch_unwind};

use binpick_cloud::PointCloud;
use binpick_cloud::io::{
    IoError, PcdEncoding, PlyEncoding, ReadLimits, read_cloud, read_cloud_from_bytes,
    read_cloud_with_colors_from_bytes, read_cloud_with_from_bytes,
};
use common::*;

#[test]
fn allocation_guard_is_armed() {
    let mut v: Vec<u8> = Vec::new();
    assert!(v.try_reserve_exact(ALLOC_LIMIT + 1).is_err());
    assert!(v.try_reserve_exact(1 << 20).is_ok());
}

/// A small valid cloud with colours, and its files in every encoding.
fn sample() -> (PointCloud, Vec<[u8; 3]>) {
    let mut rng = XorShift(1234);
    let pts: Vec<[f32; 3]> = (0..40)
        .map(|i| [i as f32 * 0.5, rng.f32_in(-1.0, 1.0), 2.0 + (i % 4) as f32])
        .collect();
    let colors = colors_for(pts.len());
    (PointCloud::new(pts), colors)
}

fn valid_pcd(enc: PcdEncoding) -> Vec<u8> {
    let (c, col) = sample();
    written_pcd(&c, enc, Some(&col))
}

fn valid_ply(enc: PlyEncoding) -> Vec<u8> {
    let (c, col) = sample();
    written_ply(&c, enc, Some(&col))
}

/// Runs the reader, turning a panic into a test failure with the case's label.
fn read_no_panic(bytes: &[u8], name: &str, label: &str) -> Result<PointCloud, IoError> {
    match catch_unwind(AssertUnwindSafe(|| {
        read_cloud_with_colors_from_bytes(bytes, name)
    })) {
        Ok(r) => r.map(|l| l.cloud),
        Err(_) => panic!("reader panicked on case {label:?}"),
    }
}

/// Asserts the case fails with a message that starts with the file name and contains `want`.
fn expect_err(label: &str, name: &str, bytes: &[u8], want: &str) {
    match read_no_panic(bytes, name, label) {
        Ok(c) => panic!("case {label:?}: expected an error, got {} points", c.len()),
        Err(e) => {
            let msg = e.to_string();
            assert!(
                msg.starts_with(&format!("{name}: ")),
                "case {label:?}: message does not start with the file name: {msg}"
            );
            assert!(
                msg.contains(want),
                "case {label:?}: expected {want:?} in: {msg}"
            );
            assert!(
                !msg.contains('\n'),
                "case {label:?}: multi-line message: {msg}"
            );
            assert_eq!(e.path().to_str(), Some(name), "case {label:?}");
        }
    }
}

fn cut(bytes: &[u8], len: usize) -> Vec<u8> {
    bytes[..len].to_vec()
}

#[test]
fn empty_and_header_only_files() {
    expect_err("empty pcd", "e.pcd", b"", "file is empty");
    expect_err("empty ply", "e.ply", b"", "file is empty");
    for enc in [
        PcdEncoding::Ascii,
        PcdEncoding::Binary,
        PcdEncoding::BinaryCompressed,
    ] {
        let v = valid_pcd(enc);
        let start = pcd_data_start(&v);
        let label = format!("header only {enc:?}");
        expect_err(&label, "h.pcd", &cut(&v, start), "truncated: ");
    }
    // Header cut before its DATA line.
    let v = valid_pcd(PcdEncoding::Binary);
    let pos = v.windows(5).position(|w| w == b"DATA ").unwrap();
    expect_err(
        "no DATA line",
        "h.pcd",
        &cut(&v, pos),
        "without a DATA line",
    );
    for enc in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
        let v = valid_ply(enc);
        let end = v.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        expect_err(
            &format!("ply header only {enc:?}"),
            "h.ply",
            &cut(&v, end),
            "truncated: ",
        );
        expect_err(
            &format!("ply header cut {enc:?}"),
            "h.ply",
            &cut(&v, end - 11),
            "bad PLY header",
        );
    }
}

#[test]
fn truncated_data() {
    let v = valid_pcd(PcdEncoding::Binary);
    let start = pcd_data_start(&v);
    expect_err(
        "binary cut",
        "scene.pcd",
        &cut(&v, start + 100),
        "scene.pcd: truncated: header says 40 points of 16 bytes (640 bytes) but only 100 bytes follow",
    );
    expect_err(
        "binary one byte short",
        "scene.pcd",
        &cut(&v, v.len() - 1),
        "but only 639 bytes follow",
    );

    let v = valid_pcd(PcdEncoding::BinaryCompressed);
    let start = pcd_data_start(&v);
    expect_err(
        "compressed cut in block",
        "c.pcd",
        &cut(&v, v.len() - 10),
        "truncated: compressed block of",
    );
    expect_err(
        "compressed cut in sizes",
        "c.pcd",
        &cut(&v, start + 5),
        "truncated: binary_compressed data starts with two 4-byte sizes",
    );

    let v = valid_pcd(PcdEncoding::Ascii);
    let last_row = v[..v.len() - 1].iter().rposition(|&b| b == b'\n').unwrap() + 1;
    expect_err(
        "ascii missing rows",
        "a.pcd",
        &cut(&v, last_row),
        "truncated: header says 40 points but only 39 data rows follow",
    );

    let v = valid_ply(PlyEncoding::BinaryLittleEndian);
    expect_err(
        "ply binary cut",
        "t.ply",
        &cut(&v, v.len() - 7),
        "truncated: header says 40 vertices of 15 bytes (600 bytes) but only 593 bytes follow",
    );
    let v = valid_ply(PlyEncoding::BinaryBigEndian);
    expect_err(
        "ply big endian cut",
        "t.ply",
        &cut(&v, v.len() - 1),
        "truncated: ",
    );
    let v = valid_ply(PlyEncoding::Ascii);
    let last_row = v[..v.len() - 1].iter().rposition(|&b| b == b'\n').unwrap() + 1;
    expect_err(
        "ply ascii cut",
        "t.ply",
        &cut(&v, last_row),
        "truncated: header says 40 \"vertex\" elements but the data ends after 39",
    );
}

#[test]
fn lying_point_counts() {
    for enc in [
        PcdEncoding::Ascii,
        PcdEncoding::Binary,
        PcdEncoding::BinaryCompressed,
    ] {
        let v = valid_pcd(enc);
        // WIDTH and POINTS agree with each other but not with the data.
        for big in ["41", "5000", "4000000000", "18446744073709551615"] {
            let lie = replace_in_header(
                &replace_in_header(&v, "WIDTH 40", &format!("WIDTH {big}")),
                "POINTS 40",
                &format!("POINTS {big}"),
            );
            let label = format!("{enc:?} POINTS {big}");
            let want = match enc {
                PcdEncoding::Ascii => "truncated: header says",
                PcdEncoding::Binary if big.len() > 19 => "overflows",
                PcdEncoding::Binary => "truncated: header says",
                PcdEncoding::BinaryCompressed if big.len() > 19 => "overflows",
                PcdEncoding::BinaryCompressed => "compressed block unpacks to",
            };
            // Counts above the default limit are refused from the header alone; with the
            // limit lifted, the data checks still catch the lie without allocating for it.
            if big.parse::<u64>().unwrap() > 50_000_000 {
                expect_err(
                    &label,
                    "lie.pcd",
                    &lie,
                    &format!("{big} points, more than the limit of 50000000 points"),
                );
            } else {
                expect_err(&label, "lie.pcd", &lie, want);
            }
            let unlimited = ReadLimits {
                max_points: usize::MAX,
                ..ReadLimits::default()
            };
            let e = read_cloud_with_from_bytes(&lie, "lie.pcd", &unlimited).unwrap_err();
            assert!(e.to_string().contains(want), "{label} unlimited: {e}");
        }
        // WIDTH or POINTS alone changed.
        expect_err(
            &format!("{enc:?} WIDTH lie"),
            "lie.pcd",
            &replace_in_header(&v, "WIDTH 40", "WIDTH 4000000000"),
            "WIDTH 4000000000 x HEIGHT 1 is not POINTS 40",
        );
        expect_err(
            &format!("{enc:?} HEIGHT lie"),
            "lie.pcd",
            &replace_in_header(&v, "HEIGHT 1", "HEIGHT 480"),
            "WIDTH 40 x HEIGHT 480 is not POINTS 40",
        );
        expect_err(
            &format!("{enc:?} POINTS lie"),
            "lie.pcd",
            &replace_in_header(&v, "POINTS 40", "POINTS 39"),
            "is not POINTS 39",
        );
    }
    // ASCII with fewer announced points than rows.
    let v = valid_pcd(PcdEncoding::Ascii);
    let lie = replace_in_header(
        &replace_in_header(&v, "WIDTH 40", "WIDTH 30"),
        "POINTS 40",
        "POINTS 30",
    );
    expect_err(
        "ascii too many rows",
        "lie.pcd",
        &lie,
        "more data rows than the 30 points",
    );
    // A padding field whose COUNT would make pcd-rs allocate terabytes.
    let text = "VERSION 0.7\nFIELDS x y z _\nSIZE 4 4 4 1\nTYPE F F F U\nCOUNT 1 1 1 4000000000000\n\
                WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA binary\n";
    let mut bytes = text.as_bytes().to_vec();
    bytes.extend([0u8; 16]);
    expect_err(
        "huge padding COUNT",
        "pad.pcd",
        &bytes,
        "truncated: header says 1 points of 4000000000012 bytes",
    );
    let text = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 18446744073709551615\n\
                WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n";
    expect_err(
        "COUNT overflow",
        "count.pcd",
        text.as_bytes(),
        "point size overflows",
    );
    let text = "VERSION 0.7\nFIELDS x y z f\nSIZE 4 4 4 8\nTYPE F F F F\nCOUNT 1 1 1 4611686018427387904\n\
                WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA binary\n";
    expect_err(
        "point size overflow",
        "count.pcd",
        text.as_bytes(),
        "point size overflows",
    );

    // PLY vertex counts.
    for enc in [
        PlyEncoding::Ascii,
        PlyEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian,
    ] {
        let v = valid_ply(enc);
        let label = format!("ply {enc:?}");
        expect_err(
            &format!("{label} more"),
            "v.ply",
            &replace_in_header(&v, "element vertex 40", "element vertex 41"),
            "truncated: ",
        );
        let huge = replace_in_header(&v, "element vertex 40", "element vertex 4000000000");
        expect_err(
            &format!("{label} huge"),
            "v.ply",
            &huge,
            "4000000000 points, more than the limit of 50000000 points",
        );
        let unlimited = ReadLimits {
            max_points: usize::MAX,
            ..ReadLimits::default()
        };
        let e = read_cloud_with_from_bytes(&huge, "v.ply", &unlimited).unwrap_err();
        assert!(
            e.to_string().contains("truncated: "),
            "{label} unlimited: {e}"
        );
        expect_err(
            &format!("{label} fewer"),
            "v.ply",
            &replace_in_header(&v, "element vertex 40", "element vertex 39"),
            "unexpected data after the last element",
        );
        expect_err(
            &format!("{label} beyond u64"),
            "v.ply",
            &replace_in_header(
                &v,
                "element vertex 40",
                "element vertex 99999999999999999999999",
            ),
            "bad PLY header",
        );
    }
    // A face list that claims more indices than there are bytes.
    let mut v = valid_ply(PlyEncoding::BinaryLittleEndian);
    v = replace_in_header(
        &v,
        "end_header",
        "element face 1\nproperty list uchar int vertex_indices\nend_header",
    );
    v.extend([200u8, 1, 0, 0, 0]);
    expect_err("face list too long", "f.ply", &v, "truncated: ");
}

#[test]
fn bad_fields_and_types() {
    let v = valid_pcd(PcdEncoding::Binary);
    let cases: &[(&str, &str, &str, &str)] = &[
        (
            "missing z",
            "FIELDS x y z rgb",
            "FIELDS x y w rgb",
            "no \"z\" field",
        ),
        (
            "missing x",
            "FIELDS x y z rgb",
            "FIELDS a y z rgb",
            "no \"x\" field",
        ),
        (
            "duplicate field",
            "FIELDS x y z rgb",
            "FIELDS x y z x",
            "listed twice",
        ),
        (
            "SIZE 3",
            "SIZE 4 4 4 4",
            "SIZE 4 3 4 4",
            "SIZE 3, which is not a PCD type",
        ),
        (
            "duplicate SIZE line",
            "TYPE F F F F",
            "TYPE F F F F\nSIZE 4 4 2 4",
            "second SIZE line",
        ),
        (
            "float of size 2",
            "SIZE 4 4 4 4",
            "SIZE 4 4 2 4",
            "TYPE F with SIZE 2",
        ),
        (
            "TYPE Q",
            "TYPE F F F F",
            "TYPE F Q F F",
            "TYPE \"Q\" of field \"y\" is not F, U or I",
        ),
        (
            "SIZE not a number",
            "SIZE 4 4 4 4",
            "SIZE 4 four 4 4",
            "SIZE \"four\" of field \"y\" is not a number",
        ),
        (
            "COUNT -1",
            "COUNT 1 1 1 1",
            "COUNT 1 -1 1 1",
            "COUNT \"-1\" of field \"y\"",
        ),
        (
            "COUNT x 2",
            "COUNT 1 1 1 1",
            "COUNT 2 1 1 1",
            "field \"x\" must have COUNT 1",
        ),
        (
            "too few SIZEs",
            "SIZE 4 4 4 4",
            "SIZE 4 4 4",
            "SIZE has 3 entries but FIELDS has 4",
        ),
        (
            "too many TYPEs",
            "TYPE F F F F",
            "TYPE F F F F F",
            "TYPE has 5 entries but FIELDS has 4",
        ),
        ("no TYPE", "TYPE F F F F", "", "no TYPE line"),
        (
            "empty FIELDS",
            "FIELDS x y z rgb",
            "FIELDS",
            "FIELDS lists no field",
        ),
        (
            "POINTS abc",
            "POINTS 40",
            "POINTS abc",
            "POINTS \"abc\" is not a non-negative integer",
        ),
        (
            "POINTS -5",
            "POINTS 40",
            "POINTS -5",
            "POINTS \"-5\" is not a non-negative integer",
        ),
        (
            "WIDTH twice",
            "WIDTH 40",
            "WIDTH 40 40",
            "WIDTH needs one value, found 2",
        ),
        (
            "bad DATA",
            "DATA binary",
            "DATA zip",
            "unknown DATA encoding \"zip\"",
        ),
        (
            "zero points",
            "POINTS 40",
            "POINTS 0",
            "WIDTH 40 x HEIGHT 1 is not POINTS 0",
        ),
    ];
    for (label, from, to, want) in cases {
        expect_err(label, "f.pcd", &replace_in_header(&v, from, to), want);
    }
    let zero = replace_in_header(
        &replace_in_header(&v, "POINTS 40", "POINTS 0"),
        "WIDTH 40",
        "WIDTH 0",
    );
    expect_err(
        "zero points consistent",
        "z.pcd",
        &zero,
        "z.pcd: contains no points",
    );

    let v = valid_ply(PlyEncoding::BinaryLittleEndian);
    let ply_cases: &[(&str, &str, &str, &str)] = &[
        (
            "no x",
            "property float x",
            "property float q",
            "vertex element has no \"x\" property",
        ),
        (
            "x is a list",
            "property float x",
            "property list uchar float x",
            "vertex property \"x\" is a list",
        ),
        (
            "no vertex",
            "element vertex 40",
            "element point 40",
            "no \"vertex\" element (elements: point)",
        ),
        (
            "bad type",
            "property float y",
            "property float16 y",
            "bad PLY header",
        ),
        (
            "bad format",
            "format binary_little_endian 1.0",
            "format binary_middle_endian 1.0",
            "bad PLY header",
        ),
        (
            "duplicate property",
            "property float y",
            "property float x",
            "repeated",
        ),
        (
            "property before element",
            "element vertex 40\n",
            "",
            "bad PLY header",
        ),
    ];
    for (label, from, to, want) in ply_cases {
        expect_err(label, "p.ply", &replace_in_header(&v, from, to), want);
    }
    let mut no_props = replace_in_header(&v, "end_header", "element empty 1000000000\nend_header");
    no_props.push(b'\n');
    expect_err(
        "element without properties",
        "p.ply",
        &no_props,
        "has 1000000000 entries but no properties",
    );
}

#[test]
fn garbage_and_non_utf8() {
    let mut rng = XorShift(99);
    let garbage: Vec<u8> = (0..4096).map(|_| rng.next_u64() as u8).collect();
    expect_err("garbage pcd", "g.pcd", &garbage, "g.pcd: ");
    expect_err("garbage ply", "g.ply", &garbage, "not a PLY file");
    expect_err(
        "text pcd",
        "t.pcd",
        b"hello world\nthis is not a cloud\n",
        "without a DATA line",
    );

    let v = valid_pcd(PcdEncoding::Binary);
    let mut bad = v.clone();
    let pos = v.windows(6).position(|w| w == b"FIELDS").unwrap();
    bad[pos + 8] = 0xFF;
    expect_err(
        "non-UTF-8 pcd header",
        "u.pcd",
        &bad,
        "header line 3 is not text",
    );

    let v = valid_ply(PlyEncoding::BinaryLittleEndian);
    let mut bad = v.clone();
    let pos = v.windows(7).position(|w| w == b"comment").unwrap();
    bad[pos + 9] = 0xC3;
    bad[pos + 10] = 0x28;
    expect_err("non-UTF-8 ply header", "u.ply", &bad, "bad PLY header");

    let v = valid_pcd(PcdEncoding::Ascii);
    let mut bad = v.clone();
    let n = bad.len();
    bad[n - 3] = 0xFF;
    expect_err("non-UTF-8 ascii data", "u.pcd", &bad, "data is not text");
}

#[test]
fn bad_ascii_rows() {
    let v = String::from_utf8(valid_pcd(PcdEncoding::Ascii)).unwrap();
    let start = pcd_data_start(v.as_bytes());
    let (head, body) = v.split_at(start);
    let header_lines = head.lines().count();
    let mut rows: Vec<String> = body.lines().map(str::to_owned).collect();
    let original = rows.clone();

    rows[5] = "1 2 3".to_owned(); // the rgb value is missing
    let bytes = format!("{head}{}\n", rows.join("\n"));
    let want = format!(
        "line {}: point 5 has 3 values but the fields need 4",
        header_lines + 6
    );
    expect_err("too few tokens", "r.pcd", bytes.as_bytes(), &want);

    rows = original.clone();
    rows[0].push_str(" 9");
    let bytes = format!("{head}{}\n", rows.join("\n"));
    expect_err(
        "too many tokens",
        "r.pcd",
        bytes.as_bytes(),
        "point 0 has 5 values but the fields need 4",
    );

    rows = original.clone();
    rows[7] = "1 two 3 0".to_owned();
    let bytes = format!("{head}{}\n", rows.join("\n"));
    expect_err(
        "word for number",
        "r.pcd",
        bytes.as_bytes(),
        "value \"two\" of field \"y\" is not a number",
    );

    rows = original;
    rows[2] = "1 2 3 red".to_owned();
    let bytes = format!("{head}{}\n", rows.join("\n"));
    expect_err(
        "word for colour",
        "r.pcd",
        bytes.as_bytes(),
        "value \"red\" of field \"rgb\" is not a number",
    );

    let ply = String::from_utf8(valid_ply(PlyEncoding::Ascii)).unwrap();
    let end = ply.find("end_header\n").unwrap() + 11;
    let (h, b) = ply.split_at(end);
    let mut lines: Vec<&str> = b.lines().collect();
    lines[3] = "1 2";
    expect_err(
        "ply too few",
        "r.ply",
        format!("{h}{}\n", lines.join("\n")).as_bytes(),
        "has too few values for its 6 properties",
    );
    lines[3] = "1 2 3 4 5 6 7";
    expect_err(
        "ply too many",
        "r.ply",
        format!("{h}{}\n", lines.join("\n")).as_bytes(),
        "has more values than its 6 properties",
    );
    lines[3] = "1 2 x 4 5 6";
    expect_err(
        "ply word",
        "r.ply",
        format!("{h}{}\n", lines.join("\n")).as_bytes(),
        "value \"x\" of property \"z\" is not a number",
    );
}

#[test]
fn bad_lzf_blocks() {
    let v = valid_pcd(PcdEncoding::BinaryCompressed);
    let s = pcd_data_start(&v);
    let cs = u32::from_le_bytes(v[s..s + 4].try_into().unwrap());
    let us = u32::from_le_bytes(v[s + 4..s + 8].try_into().unwrap());
    let with_sizes = |c: u32, u: u32| {
        let mut b = v.clone();
        b[s..s + 4].copy_from_slice(&c.to_le_bytes());
        b[s + 4..s + 8].copy_from_slice(&u.to_le_bytes());
        b
    };
    expect_err(
        "compressed size too big",
        "z.pcd",
        &with_sizes(cs + 1, us),
        "truncated: compressed block of",
    );
    expect_err(
        "compressed size huge",
        "z.pcd",
        &with_sizes(u32::MAX, us),
        "truncated: compressed block of 4294967295 bytes",
    );
    expect_err(
        "uncompressed size small",
        "z.pcd",
        &with_sizes(cs, us / 2),
        "compressed block unpacks to",
    );
    expect_err(
        "uncompressed size huge",
        "z.pcd",
        &with_sizes(cs, u32::MAX),
        "compressed block unpacks to 4294967295 bytes",
    );
    expect_err(
        "both zero",
        "z.pcd",
        &with_sizes(0, 0),
        "compressed block unpacks to 0 bytes",
    );
    expect_err(
        "compressed size short",
        "z.pcd",
        &with_sizes(cs - 3, us),
        "corrupt binary_compressed data",
    );
    // A back reference before the start of the output.
    let mut b = v.clone();
    b[s + 8] = 0xE0;
    expect_err(
        "bad back reference",
        "z.pcd",
        &b,
        "corrupt binary_compressed data",
    );
    // A literal run that runs past the end of the stream.
    let mut b = with_sizes(1, us);
    b[s + 8] = 31;
    expect_err("literal past end", "z.pcd", &b, "literal run of 32 bytes");

    // A hand-made stream whose header lies about 10 million points: refused before
    // anything of that size is allocated.
    let text = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 10000000\n\
                HEIGHT 1\nPOINTS 10000000\nDATA binary_compressed\n";
    let mut b = text.as_bytes().to_vec();
    b.extend(3u32.to_le_bytes());
    b.extend(120_000_000u32.to_le_bytes());
    b.extend([0u8, 0, 0xE0]); // one literal byte, then a cut-off long back reference
    expect_err(
        "10M point bomb",
        "bomb.pcd",
        &b,
        "corrupt binary_compressed data",
    );
}

#[test]
fn mislabelled_and_unsupported_files() {
    let ply = valid_ply(PlyEncoding::BinaryLittleEndian);
    expect_err(
        "ply named pcd",
        "model.pcd",
        &ply,
        "has a .pcd extension but is a PLY file",
    );
    let pcd = valid_pcd(PcdEncoding::Binary);
    expect_err(
        "pcd named ply",
        "model.ply",
        &pcd,
        "has a .ply extension but looks like a PCD file",
    );
    expect_err(
        "xyz",
        "model.xyz",
        &pcd,
        "unsupported file type (extension .xyz): supported are .pcd and .ply",
    );
    expect_err(
        "no extension",
        "model",
        &pcd,
        "unsupported file type (no extension)",
    );
    let e = read_cloud_from_bytes(&ply, "model.pcd").unwrap_err();
    assert!(matches!(e, IoError::WrongFormat { .. }), "{e:?}");
}

#[test]
fn path_errors_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.pcd");
    let e = read_cloud(&missing).unwrap_err();
    assert!(matches!(e, IoError::Io { .. }), "{e:?}");
    assert!(
        e.to_string()
            .starts_with(&format!("{}: ", missing.display())),
        "{e}"
    );

    let v = valid_pcd(PcdEncoding::Binary);
    let path = dir.path().join("scene.pcd");
    std::fs::write(&path, &v[..v.len() - 20]).unwrap();
    let e = read_cloud(&path).unwrap_err();
    assert_eq!(
        e.to_string(),
        format!(
            "{}: truncated: header says 40 points of 16 bytes (640 bytes) but only 620 bytes follow",
            path.display()
        )
    );
    assert_eq!(e.path(), path);
}

#[test]
fn randomised_mutations_never_panic() {
    let (cloud, colors) = sample();
    let few = PointCloud::new(cloud.points[..6].to_vec());
    let mut seeds: Vec<(Vec<u8>, &str)> = Vec::new();
    for enc in [
        PcdEncoding::Ascii,
        PcdEncoding::Binary,
        PcdEncoding::BinaryCompressed,
    ] {
        seeds.push((written_pcd(&cloud, enc, Some(&colors)), "m.pcd"));
        seeds.push((written_pcd(&few, enc, None), "m.pcd"));
    }
    for enc in [
        PlyEncoding::Ascii,
        PlyEncoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian,
    ] {
        seeds.push((written_ply(&cloud, enc, Some(&colors)), "m.ply"));
        seeds.push((written_ply(&few, enc, None), "m.ply"));
    }
    // Layouts the writers do not produce: F8, COUNT > 1, padding, organised with NaNs.
    let cols = [
        col("x", 'F', 8, 1),
        col("y", 'F', 4, 1),
        col("z", 'I', 2, 1),
        col("h", 'F', 4, 3),
        col("_", 'U', 1, 2),
        col("rgba", 'U', 4, 1),
    ];
    let rows: Vec<Vec<f64>> = (0..6)
        .map(|i| {
            let x = if i == 2 { f64::NAN } else { i as f64 };
            vec![x, 1.5, -3.0, 0.1, 0.2, 0.3, 0.0, 0.0, 4_278_190_335.0]
        })
        .collect();
    for data in ["ascii", "binary", "binary_compressed"] {
        seeds.push((pcd_file(&cols, &rows, 3, 2, data), "m.pcd"));
    }
    let mesh = "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty double x\n\
                property double y\nproperty double z\nelement face 1\n\
                property list uchar int vertex_indices\nend_header\n";
    let mut mesh = mesh.as_bytes().to_vec();
    for v in [1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0] {
        mesh.extend(v.to_le_bytes());
    }
    mesh.push(2);
    mesh.extend(0i32.to_le_bytes());
    mesh.extend(1i32.to_le_bytes());
    seeds.push((mesh, "m.ply"));
    // Every seed is valid to begin with.
    for (i, (s, name)) in seeds.iter().enumerate() {
        read_cloud_from_bytes(s, name).unwrap_or_else(|e| panic!("seed {i} invalid: {e}"));
    }

    let mut rng = XorShift(0x5EED_1234_ABCD_0001);
    let (mut ok, mut err) = (0usize, 0usize);
    const ITERATIONS: usize = 6000;
    for iter in 0..ITERATIONS {
        let (src, name) = &seeds[rng.below(seeds.len())];
        let m = mutate(&mut rng, src);
        match read_no_panic(&m, name, &format!("mutation {iter}")) {
            Ok(c) => {
                assert!(!c.is_empty(), "mutation {iter}: Ok with no points");
                assert!(
                    c.first_non_finite().is_none(),
                    "mutation {iter}: non-finite point kept"
                );
                ok += 1;
            }
            Err(e) => {
                let msg = e.to_string();
                assert!(
                    msg.starts_with(&format!("{name}: ")),
                    "mutation {iter}: {msg}"
                );
                assert!(
                    !msg.contains('\n'),
                    "mutation {iter}: multi-line message: {msg}"
                );
                err += 1;
            }
        }
    }
    // Both outcomes must occur, or the mutations are not exercising anything.
    assert!(ok > 100 && err > 1000, "ok {ok}, err {err}");
}
