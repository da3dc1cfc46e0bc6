//! Hand-written mesh files of one box (10 x 20 x 30 at (1, 2, 3)) in every format.

/// The eight corners of a 10 x 20 x 30 box at (1, 2, 3), and its six faces as quads wound
/// counter-clockwise seen from outside.
pub fn box_corners() -> Vec<[f32; 3]> {
    (0..8)
        .map(|i| {
            [
                if i & 1 == 0 { 1.0 } else { 11.0 },
                if i & 2 == 0 { 2.0 } else { 22.0 },
                if i & 4 == 0 { 3.0 } else { 33.0 },
            ]
        })
        .collect()
}

pub const QUADS: [[usize; 4]; 6] = [
    [0, 2, 3, 1],
    [4, 5, 7, 6],
    [0, 1, 5, 4],
    [2, 6, 7, 3],
    [0, 4, 6, 2],
    [1, 3, 7, 5],
];

/// The box's triangles (each quad as the fan (a, b, c), (a, c, d)).
pub fn box_triangles() -> Vec<[usize; 3]> {
    QUADS
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect()
}

pub fn ascii_stl(tris: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut s = String::from("solid box\n");
    for t in tris {
        s.push_str("  facet normal 0 0 0\n    outer loop\n");
        for v in t {
            s.push_str(&format!("      vertex {} {} {}\n", v[0], v[1], v[2]));
        }
        s.push_str("    endloop\n  endfacet\n");
    }
    s.push_str("endsolid box\n");
    s.into_bytes()
}

pub fn binary_stl(tris: &[[[f32; 3]; 3]], header: &[u8]) -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b[..header.len()].copy_from_slice(header);
    b.extend((tris.len() as u32).to_le_bytes());
    for t in tris {
        b.extend([0u8; 12]);
        for v in t {
            for c in v {
                b.extend(c.to_le_bytes());
            }
        }
        b.extend([0u8; 2]);
    }
    b
}

pub fn box_soup() -> Vec<[[f32; 3]; 3]> {
    let c = box_corners();
    box_triangles()
        .iter()
        .map(|t| [c[t[0]], c[t[1]], c[t[2]]])
        .collect()
}

pub fn box_obj() -> Vec<u8> {
    let mut s = String::from("# a box\nmtllib box.mtl\no box\n");
    for v in box_corners() {
        s.push_str(&format!("v {} {} {}\n", v[0], v[1], v[2]));
    }
    s.push_str("vt 0 0\nvn 0 0 1\nusemtl steel\ng sides\n");
    for q in QUADS {
        // 1-based, with texture and normal indices that must be ignored.
        s.push_str(&format!(
            "f {}/1/1 {}/1/1 {}/1/1 {}/1/1\n",
            q[0] + 1,
            q[1] + 1,
            q[2] + 1,
            q[3] + 1
        ));
    }
    s.into_bytes()
}

pub fn box_ply(ascii: bool) -> Vec<u8> {
    let fmt = if ascii {
        "ascii"
    } else {
        "binary_little_endian"
    };
    let mut b = format!(
        "ply\nformat {fmt} 1.0\nelement vertex 8\nproperty float x\nproperty float y\n\
         property float z\nelement face 6\nproperty list uchar int vertex_indices\nend_header\n"
    )
    .into_bytes();
    for v in box_corners() {
        if ascii {
            b.extend(format!("{} {} {}\n", v[0], v[1], v[2]).bytes());
        } else {
            for c in v {
                b.extend(c.to_le_bytes());
            }
        }
    }
    for q in QUADS {
        if ascii {
            b.extend(format!("4 {} {} {} {}\n", q[0], q[1], q[2], q[3]).bytes());
        } else {
            b.push(4);
            for i in q {
                b.extend((i as i32).to_le_bytes());
            }
        }
    }
    b
}
