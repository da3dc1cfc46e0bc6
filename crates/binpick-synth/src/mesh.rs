//! Exact triangle meshes of the parts (bent sheets and bent pipes, swept along a planar
//! profile) plus the convex pieces used as physics colliders, and simple boxes for the belt,
//! floor and bin walls.

use nalgebra::{Isometry3, Point3, Vector3};
use rapier3d::parry::math::Vector as PVec;
use rapier3d::parry::shape::TriMesh;

use crate::SynthError;
use crate::rng::Rng;

/// A triangle mesh in millimetres.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

fn v3(p: &[f32; 3]) -> Vector3<f64> {
    Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

fn f32x3(v: &Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

impl Mesh {
    /// The mesh moved by `pose` (vertices computed in f64).
    pub fn transformed(&self, pose: &Isometry3<f64>) -> Mesh {
        Mesh {
            vertices: self
                .vertices
                .iter()
                .map(|p| binpick_cloud::transform_point(pose, p))
                .collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// Appends `other`'s triangles (vertex indices shifted).
    pub fn append(&mut self, other: &Mesh) {
        let base = self.vertices.len() as u32;
        self.vertices.extend_from_slice(&other.vertices);
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }

    /// Axis-aligned bounds of the vertices, or `None` when empty.
    pub fn bounds(&self) -> Option<binpick_cloud::Aabb> {
        binpick_cloud::PointCloud::new(self.vertices.clone()).bounds()
    }

    fn corners(&self, t: &[u32; 3]) -> [Vector3<f64>; 3] {
        [
            v3(&self.vertices[t[0] as usize]),
            v3(&self.vertices[t[1] as usize]),
            v3(&self.vertices[t[2] as usize]),
        ]
    }

    /// Total surface area, mm^2.
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }

    /// Enclosed volume (divergence theorem; meaningful for closed, consistently oriented meshes).
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum()
    }

    /// `n` points drawn uniformly (area-weighted) on the surface.
    pub fn sample_surface(&self, n: usize, rng: &mut Rng) -> Vec<[f32; 3]> {
        let mut cumulative = Vec::with_capacity(self.triangles.len());
        let mut total = 0.0;
        for t in &self.triangles {
            let [a, b, c] = self.corners(t);
            total += 0.5 * (b - a).cross(&(c - a)).norm();
            cumulative.push(total);
        }
        if total <= 0.0 {
            return Vec::new();
        }
        (0..n)
            .map(|_| {
                let x = rng.uniform() * total;
                let i = cumulative
                    .partition_point(|&c| c < x)
                    .min(cumulative.len() - 1);
                let [a, b, c] = self.corners(&self.triangles[i]);
                let (mut u, mut v) = (rng.uniform(), rng.uniform());
                if u + v > 1.0 {
                    u = 1.0 - u;
                    v = 1.0 - v;
                }
                f32x3(&(a + (b - a) * u + (c - a) * v))
            })
            .collect()
    }

    /// An axis-aligned box (closed, outward-oriented).
    pub fn cuboid(min: [f64; 3], max: [f64; 3]) -> Mesh {
        let mut m = Mesh::default();
        for i in 0..8 {
            let x = if i & 1 == 0 { min[0] } else { max[0] };
            let y = if i & 2 == 0 { min[1] } else { max[1] };
            let z = if i & 4 == 0 { min[2] } else { max[2] };
            m.vertices.push([x as f32, y as f32, z as f32]);
        }
        // Faces as quads (outward CCW).
        let quads = [
            [0, 2, 3, 1], // z-
            [4, 5, 7, 6], // z+
            [0, 1, 5, 4], // y-
            [2, 6, 7, 3], // y+
            [0, 4, 6, 2], // x-
            [1, 3, 7, 5], // x+
        ];
        for q in quads {
            m.triangles.push([q[0], q[1], q[2]]);
            m.triangles.push([q[0], q[2], q[3]]);
        }
        m
    }

    /// The parry triangle mesh (with its BVH) for ray casting and point projection.
    pub fn to_parry(&self) -> Result<TriMesh, SynthError> {
        let vertices: Vec<PVec> = self
            .vertices
            .iter()
            .map(|p| PVec::new(p[0], p[1], p[2]))
            .collect();
        TriMesh::new(vertices, self.triangles.clone())
            .map_err(|e| SynthError::Geometry(format!("cannot build triangle mesh: {e:?}")))
    }

    /// Pushes a triangle, flipped if needed so that its normal points along `outward`;
    /// degenerate triangles are skipped.
    fn push_oriented(&mut self, tri: [u32; 3], outward: &Vector3<f64>) {
        let [a, b, c] = self.corners(&tri);
        let n = (b - a).cross(&(c - a));
        if n.norm() < 1e-9 {
            return;
        }
        if n.dot(outward) >= 0.0 {
            self.triangles.push(tri);
        } else {
            self.triangles.push([tri[0], tri[2], tri[1]]);
        }
    }
}

/// One piece of a planar profile curve, walked from its start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Segment {
    /// Straight run, mm.
    Straight(f64),
    /// Circular bend: signed angle (degrees, positive = turning left / towards the profile's
    /// normal) and radius of the curve itself, mm (for a sheet: the mid-surface radius).
    Bend { angle_deg: f64, radius: f64 },
}

impl Segment {
    pub fn length(&self) -> f64 {
        match *self {
            Segment::Straight(l) => l,
            Segment::Bend { angle_deg, radius } => angle_deg.abs().to_radians() * radius,
        }
    }
}

/// A planar curve made of straight runs and circular bends, starting at the origin heading +x.
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    pub segments: Vec<Segment>,
}

/// Position, unit tangent and left normal on a profile, in its plane.
#[derive(Clone, Copy, Debug)]
pub struct ProfilePoint {
    pub p: [f64; 2],
    pub t: [f64; 2],
}

impl ProfilePoint {
    pub fn normal(&self) -> [f64; 2] {
        [-self.t[1], self.t[0]]
    }
}

impl Profile {
    pub fn length(&self) -> f64 {
        self.segments.iter().map(Segment::length).sum()
    }

    /// Start arc length of each segment.
    pub fn segment_starts(&self) -> Vec<f64> {
        let mut s = 0.0;
        self.segments
            .iter()
            .map(|seg| {
                let here = s;
                s += seg.length();
                here
            })
            .collect()
    }

    /// The point at arc length `s` (clamped to the curve; beyond the ends the end runs are
    /// extended straight).
    pub fn at(&self, s: f64) -> ProfilePoint {
        let mut p = [0.0, 0.0];
        let mut heading: f64 = 0.0;
        let mut remaining = s;
        for (i, seg) in self.segments.iter().enumerate() {
            let len = seg.length();
            let last = i + 1 == self.segments.len();
            let take = if last { remaining } else { remaining.min(len) };
            match *seg {
                Segment::Straight(_) => {
                    p[0] += take * heading.cos();
                    p[1] += take * heading.sin();
                }
                Segment::Bend { angle_deg, radius } => {
                    let sign = angle_deg.signum();
                    let dphi = sign * take.min(len) / radius;
                    // Centre on the left (sign > 0) or right of the heading.
                    let cx = p[0] - sign * radius * heading.sin();
                    let cy = p[1] + sign * radius * heading.cos();
                    let h2 = heading + dphi;
                    p = [cx + sign * radius * h2.sin(), cy - sign * radius * h2.cos()];
                    heading = h2;
                    if last && take > len {
                        p[0] += (take - len) * heading.cos();
                        p[1] += (take - len) * heading.sin();
                    }
                }
            }
            remaining -= take;
            if remaining <= 0.0 && !last {
                break;
            }
        }
        ProfilePoint {
            p,
            t: [heading.cos(), heading.sin()],
        }
    }

    /// Arc lengths at which to cut sections: segment ends, every `max_bend_step_deg` inside
    /// bends, and `extra` values, restricted to `[lo, hi]`, sorted and de-duplicated.
    fn breakpoints(&self, max_bend_step_deg: f64, extra: &[f64], lo: f64, hi: f64) -> Vec<f64> {
        let mut out = vec![lo, hi];
        let starts = self.segment_starts();
        for (seg, &s0) in self.segments.iter().zip(&starts) {
            let len = seg.length();
            out.push(s0);
            out.push(s0 + len);
            if let Segment::Bend { angle_deg, .. } = *seg {
                let steps = (angle_deg.abs() / max_bend_step_deg).ceil().max(1.0) as usize;
                for k in 1..steps {
                    out.push(s0 + len * k as f64 / steps as f64);
                }
            }
        }
        out.extend_from_slice(extra);
        out.retain(|&s| s >= lo - 1e-9 && s <= hi + 1e-9);
        out.sort_by(f64::total_cmp);
        out.dedup_by(|a, b| (*a - *b).abs() < 1e-6);
        out
    }

    /// Which convex piece the strip starting at `s` belongs to: one per straight run, bends
    /// split every `chunk_deg`.
    fn piece_key(&self, s_mid: f64, chunk_deg: f64) -> (usize, usize) {
        let starts = self.segment_starts();
        for (i, (seg, &s0)) in self.segments.iter().zip(&starts).enumerate() {
            if s_mid <= s0 + seg.length() || i + 1 == self.segments.len() {
                return match *seg {
                    Segment::Straight(_) => (i, 0),
                    Segment::Bend { radius, .. } => {
                        let chunk_len = chunk_deg.to_radians() * radius;
                        (i, ((s_mid - s0).max(0.0) / chunk_len) as usize)
                    }
                };
            }
        }
        (0, 0)
    }

    /// Arc length of the profile point nearest to `q` (dense sampling, then refinement).
    pub fn project(&self, q: [f64; 2]) -> f64 {
        let total = self.length();
        let n = (total / 0.5).ceil().max(2.0) as usize;
        let d2 = |s: f64| {
            let p = self.at(s).p;
            (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)
        };
        let mut best = (0.0, f64::INFINITY);
        for k in 0..=n {
            let s = total * k as f64 / n as f64;
            let d = d2(s);
            if d < best.1 {
                best = (s, d);
            }
        }
        // Golden-section refinement in the bracketing interval.
        let h = total / n as f64;
        let (mut a, mut b) = ((best.0 - h).max(0.0), (best.0 + h).min(total));
        let g = 0.618_033_988_75;
        for _ in 0..40 {
            let c = b - g * (b - a);
            let d = a + g * (b - a);
            if d2(c) < d2(d) {
                b = d;
            } else {
                a = c;
            }
        }
        0.5 * (a + b)
    }
}

/// A closed mesh with the convex pieces that make up its collider.
#[derive(Clone, Debug, Default)]
pub struct SweptMesh {
    pub mesh: Mesh,
    /// Vertex sets whose convex hulls together approximate the solid (exact for straight runs).
    pub hulls: Vec<Vec<[f32; 3]>>,
}

/// A sheet of constant thickness: a convex outline in flat coordinates (s along the profile,
/// w across it), bent along the profile (profile in the x-z plane, w along y).
#[derive(Clone, Debug, PartialEq)]
pub struct SheetSpec {
    pub profile: Profile,
    /// Convex polygon in (s, w), mm.
    pub outline: Vec<[f64; 2]>,
    pub thickness: f64,
}

/// The w-interval of a convex polygon at abscissa s.
fn polygon_span(outline: &[[f64; 2]], s: f64) -> Option<(f64, f64)> {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    let n = outline.len();
    for i in 0..n {
        let a = outline[i];
        let b = outline[(i + 1) % n];
        let (smin, smax) = (a[0].min(b[0]), a[0].max(b[0]));
        if s < smin - 1e-9 || s > smax + 1e-9 {
            continue;
        }
        if (b[0] - a[0]).abs() < 1e-12 {
            for w in [a[1], b[1]] {
                lo = lo.min(w);
                hi = hi.max(w);
            }
        } else {
            let f = ((s - a[0]) / (b[0] - a[0])).clamp(0.0, 1.0);
            let w = a[1] + f * (b[1] - a[1]);
            lo = lo.min(w);
            hi = hi.max(w);
        }
    }
    (lo <= hi).then_some((lo, hi))
}

impl SheetSpec {
    /// Range of s covered by the outline.
    pub fn s_range(&self) -> (f64, f64) {
        let lo = self
            .outline
            .iter()
            .map(|p| p[0])
            .fold(f64::INFINITY, f64::min);
        let hi = self
            .outline
            .iter()
            .map(|p| p[0])
            .fold(f64::NEG_INFINITY, f64::max);
        (lo, hi)
    }

    /// 3D point for flat coordinates (s, w) at height h above the mid-surface.
    pub fn point(&self, s: f64, w: f64, h: f64) -> Vector3<f64> {
        let pp = self.profile.at(s);
        let n = pp.normal();
        Vector3::new(pp.p[0] + h * n[0], w, pp.p[1] + h * n[1])
    }

    /// The closed mesh of the part of the sheet with s in `[lo, hi]` (the whole sheet when
    /// `None`), with convex collider pieces (bends split every `chunk_deg`).
    pub fn build(&self, clip: Option<(f64, f64)>, chunk_deg: f64) -> Result<SweptMesh, SynthError> {
        let (s0, s1) = self.s_range();
        let (lo, hi) = clip.map_or((s0, s1), |(a, b)| (a.max(s0), b.min(s1)));
        if hi <= lo {
            return Err(SynthError::Geometry("empty sheet clip range".into()));
        }
        let extra: Vec<f64> = self.outline.iter().map(|p| p[0]).collect();
        let ss = self.profile.breakpoints(5.0, &extra, lo, hi);
        let half = 0.5 * self.thickness;
        let mut out = SweptMesh::default();
        let mesh = &mut out.mesh;
        let mut centres = Vec::new();
        for &s in &ss {
            let (wlo, whi) = polygon_span(&self.outline, s)
                .ok_or_else(|| SynthError::Geometry(format!("outline has no span at s={s}")))?;
            for (w, h) in [(wlo, half), (whi, half), (whi, -half), (wlo, -half)] {
                mesh.vertices.push(f32x3(&self.point(s, w, h)));
            }
            centres.push(self.point(s, 0.5 * (wlo + whi), 0.0));
        }
        let mut pieces: std::collections::BTreeMap<(usize, usize), Vec<[f32; 3]>> =
            std::collections::BTreeMap::new();
        for k in 0..ss.len() - 1 {
            let a = (4 * k) as u32;
            let b = a + 4;
            let mid = 0.5 * (centres[k] + centres[k + 1]);
            for j in 0..4u32 {
                let j1 = (j + 1) % 4;
                let quad = [a + j, a + j1, b + j1, b + j];
                let qc = quad
                    .iter()
                    .map(|&i| v3(&mesh.vertices[i as usize]))
                    .sum::<Vector3<f64>>()
                    / 4.0;
                let outward = qc - mid;
                mesh.push_oriented([quad[0], quad[1], quad[2]], &outward);
                mesh.push_oriented([quad[0], quad[2], quad[3]], &outward);
            }
            let key = self.profile.piece_key(0.5 * (ss[k] + ss[k + 1]), chunk_deg);
            let piece = pieces.entry(key).or_default();
            for i in a..b + 4 {
                piece.push(mesh.vertices[i as usize]);
            }
        }
        // End caps.
        let last = ss.len() - 1;
        for (k, sign) in [(0usize, -1.0), (last, 1.0)] {
            let t = self.profile.at(ss[k]).t;
            let outward = Vector3::new(sign * t[0], 0.0, sign * t[1]);
            let a = (4 * k) as u32;
            mesh.push_oriented([a, a + 1, a + 2], &outward);
            mesh.push_oriented([a, a + 2, a + 3], &outward);
        }
        out.hulls = pieces.into_values().collect();
        Ok(out)
    }
}

/// A round pipe swept along a profile lying in the x-y plane.
#[derive(Clone, Debug, PartialEq)]
pub struct PipeSpec {
    pub centerline: Profile,
    pub diameter: f64,
    /// Vertices per ring.
    pub ring_segments: usize,
}

impl PipeSpec {
    /// The closed mesh of the pipe between arc lengths `[lo, hi]` of its centre line (the whole
    /// pipe when `None`), with convex collider pieces (bends split every `chunk_deg`).
    pub fn build(&self, clip: Option<(f64, f64)>, chunk_deg: f64) -> Result<SweptMesh, SynthError> {
        let total = self.centerline.length();
        let (lo, hi) = clip.map_or((0.0, total), |(a, b)| (a.max(0.0), b.min(total)));
        if hi <= lo || self.ring_segments < 3 {
            return Err(SynthError::Geometry("empty pipe clip range".into()));
        }
        let ss = self.centerline.breakpoints(7.5, &[], lo, hi);
        let r = 0.5 * self.diameter;
        let m = self.ring_segments as u32;
        let mut out = SweptMesh::default();
        let mesh = &mut out.mesh;
        let mut centres = Vec::new();
        for &s in &ss {
            let pp = self.centerline.at(s);
            let c = Vector3::new(pp.p[0], pp.p[1], 0.0);
            let n1 = Vector3::new(pp.normal()[0], pp.normal()[1], 0.0);
            let n2 = Vector3::z();
            for j in 0..m {
                let phi = std::f64::consts::TAU * f64::from(j) / f64::from(m);
                mesh.vertices
                    .push(f32x3(&(c + r * (phi.cos() * n1 + phi.sin() * n2))));
            }
            centres.push(c);
        }
        let mut pieces: std::collections::BTreeMap<(usize, usize), Vec<[f32; 3]>> =
            std::collections::BTreeMap::new();
        for k in 0..ss.len() - 1 {
            let a = k as u32 * m;
            let b = a + m;
            let mid = 0.5 * (centres[k] + centres[k + 1]);
            for j in 0..m {
                let j1 = (j + 1) % m;
                let quad = [a + j, a + j1, b + j1, b + j];
                let qc = quad
                    .iter()
                    .map(|&i| v3(&mesh.vertices[i as usize]))
                    .sum::<Vector3<f64>>()
                    / 4.0;
                let outward = qc - mid;
                mesh.push_oriented([quad[0], quad[1], quad[2]], &outward);
                mesh.push_oriented([quad[0], quad[2], quad[3]], &outward);
            }
            let key = self
                .centerline
                .piece_key(0.5 * (ss[k] + ss[k + 1]), chunk_deg);
            let piece = pieces.entry(key).or_default();
            for i in a..b + m {
                piece.push(mesh.vertices[i as usize]);
            }
        }
        // Caps: a fan around a centre vertex.
        let last = ss.len() - 1;
        for (k, sign) in [(0usize, -1.0), (last, 1.0)] {
            let t = self.centerline.at(ss[k]).t;
            let outward = Vector3::new(sign * t[0], sign * t[1], 0.0);
            let centre = mesh.vertices.len() as u32;
            mesh.vertices.push(f32x3(&centres[k]));
            let a = k as u32 * m;
            for j in 0..m {
                mesh.push_oriented([centre, a + j, a + (j + 1) % m], &outward);
            }
        }
        out.hulls = pieces.into_values().collect();
        Ok(out)
    }
}

/// A solid of revolution about the z axis made of bands stacked along z: band `[h0, h1,
/// r_inner, r_outer]` is the tube (a cylinder when `r_inner` = 0) between heights `h0` and `h1`,
/// mm. Each band starts where the previous one ends.
#[derive(Clone, Debug, PartialEq)]
pub struct RevolvedSpec {
    pub bands: Vec<[f64; 4]>,
    /// Facets around the axis (vertices per ring), >= 3.
    pub segments: usize,
    /// Facets per convex collider piece of a hollow band (a solid band is one piece).
    pub sector_segments: usize,
}

impl RevolvedSpec {
    /// The closed (r, h) outline of the solid, counter-clockwise with r along x: bottom,
    /// outer side upwards, top, inner side downwards; collinear points dropped.
    pub fn outline(&self) -> Result<Vec<[f64; 2]>, SynthError> {
        let bad = |m: String| Err(SynthError::Geometry(format!("revolved part: {m}")));
        if self.bands.is_empty() || self.segments < 3 || self.sector_segments == 0 {
            return bad("needs bands, >= 3 segments and >= 1 segment per sector".into());
        }
        for (i, b) in self.bands.iter().enumerate() {
            let [h0, h1, ri, ro] = *b;
            if !(h1 > h0 && ro > ri && ri >= 0.0) {
                return bad(format!("band {i} {b:?} is empty or inside out"));
            }
            if i > 0 && (self.bands[i - 1][1] - h0).abs() > 1e-9 {
                return bad(format!("band {i} does not start where band {} ends", i - 1));
            }
        }
        let mut pts = Vec::new();
        for b in &self.bands {
            pts.push([b[3], b[0]]);
            pts.push([b[3], b[1]]);
        }
        for b in self.bands.iter().rev() {
            pts.push([b[2], b[1]]);
            pts.push([b[2], b[0]]);
        }
        // Drop repeated and collinear points (cyclically) until none is left.
        loop {
            let n = pts.len();
            let redundant = (0..n).find(|&i| {
                let (a, b, c) = (pts[(i + n - 1) % n], pts[i], pts[(i + 1) % n]);
                let cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
                cross.abs() < 1e-12
            });
            match redundant {
                Some(i) if n > 3 => {
                    pts.remove(i);
                }
                _ => break,
            }
        }
        Ok(pts)
    }

    /// The closed mesh (shared vertices, outward triangles) and its convex collider pieces.
    pub fn build(&self) -> Result<SweptMesh, SynthError> {
        let outline = self.outline()?;
        let n = self.segments as u32;
        let angle = |j: u32| std::f64::consts::TAU * f64::from(j % n) / f64::from(n);
        let mut out = SweptMesh::default();
        let mesh = &mut out.mesh;
        // First vertex of each outline point's ring (one vertex for a point on the axis).
        let mut first = Vec::with_capacity(outline.len());
        for &[r, h] in &outline {
            first.push(mesh.vertices.len() as u32);
            if r <= 1e-12 {
                mesh.vertices.push(f32x3(&Vector3::new(0.0, 0.0, h)));
            } else {
                for j in 0..n {
                    let (s, c) = angle(j).sin_cos();
                    mesh.vertices.push(f32x3(&Vector3::new(r * c, r * s, h)));
                }
            }
        }
        let on_axis = |i: usize| outline[i][0] <= 1e-12;
        let vertex = |i: usize, j: u32| {
            if on_axis(i) {
                first[i]
            } else {
                first[i] + j % n
            }
        };
        for a in 0..outline.len() {
            let b = (a + 1) % outline.len();
            if on_axis(a) && on_axis(b) {
                continue;
            }
            // Outward normal of a counter-clockwise outline edge: (dh, -dr).
            let (dr, dh) = (outline[b][0] - outline[a][0], outline[b][1] - outline[a][1]);
            for j in 0..n {
                let (s, c) = (angle(j) + std::f64::consts::PI / f64::from(n)).sin_cos();
                let outward = Vector3::new(dh * c, dh * s, -dr);
                let quad = [
                    vertex(a, j),
                    vertex(a, j + 1),
                    vertex(b, j + 1),
                    vertex(b, j),
                ];
                if !on_axis(a) {
                    mesh.push_oriented([quad[0], quad[1], quad[2]], &outward);
                }
                if !on_axis(b) {
                    mesh.push_oriented([quad[0], quad[2], quad[3]], &outward);
                }
            }
        }
        let ring = |r: f64, h: f64, from: u32, to: u32| -> Vec<[f32; 3]> {
            (from..=to)
                .map(|j| {
                    let (s, c) = angle(j).sin_cos();
                    f32x3(&Vector3::new(r * c, r * s, h))
                })
                .collect()
        };
        for &[h0, h1, ri, ro] in &self.bands {
            if ri <= 1e-12 {
                let mut piece = ring(ro, h0, 0, n - 1);
                piece.extend(ring(ro, h1, 0, n - 1));
                out.hulls.push(piece);
                continue;
            }
            let k = (self.sector_segments as u32).min(n);
            let mut from = 0;
            while from < n {
                let to = (from + k).min(n);
                let mut piece = Vec::new();
                for (r, h) in [(ro, h0), (ro, h1), (ri, h0), (ri, h1)] {
                    piece.extend(ring(r, h, from, to));
                }
                out.hulls.push(piece);
                from = to;
            }
        }
        Ok(out)
    }
}

/// Shifts a swept mesh (mesh and hulls) by `offset`.
pub fn translate_swept(sm: &mut SweptMesh, offset: &Vector3<f64>) {
    let shift = |p: &mut [f32; 3]| {
        let q = v3(p) + offset;
        *p = f32x3(&q);
    };
    sm.mesh.vertices.iter_mut().for_each(shift);
    for h in &mut sm.hulls {
        h.iter_mut().for_each(shift);
    }
}

/// Distance from `p` to the closest point of a parry triangle mesh.
pub fn distance_to_mesh(mesh: &TriMesh, p: &[f32; 3]) -> f64 {
    use rapier3d::parry::query::PointQuery;
    let q = PVec::new(p[0], p[1], p[2]);
    let proj = mesh.project_local_point(q, false);
    f64::from((proj.point - q).length())
}

/// Converts a point to nalgebra.
pub fn to_point3(p: &[f32; 3]) -> Point3<f64> {
    Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profile_walks_bends_correctly() {
        let prof = Profile {
            segments: vec![
                Segment::Straight(10.0),
                Segment::Bend {
                    angle_deg: 90.0,
                    radius: 2.0,
                },
                Segment::Straight(5.0),
            ],
        };
        let end = prof.at(prof.length());
        assert!((end.p[0] - 12.0).abs() < 1e-9, "{:?}", end.p);
        assert!((end.p[1] - 7.0).abs() < 1e-9, "{:?}", end.p);
        assert!((end.t[1] - 1.0).abs() < 1e-12);
        let s = prof.project([12.5, 4.0]);
        assert!(
            (s - (10.0 + std::f64::consts::PI + 2.0)).abs() < 1e-3,
            "{s}"
        );
    }

    #[test]
    fn box_and_sheet_are_closed_and_outward() {
        let b = Mesh::cuboid([0.0, 0.0, 0.0], [2.0, 3.0, 4.0]);
        assert!((b.volume() - 24.0).abs() < 1e-9);
        assert!((b.area() - 52.0).abs() < 1e-9);
        let sheet = SheetSpec {
            profile: Profile {
                segments: vec![Segment::Straight(30.0)],
            },
            outline: vec![[0.0, -5.0], [30.0, -5.0], [30.0, 5.0], [0.0, 5.0]],
            thickness: 2.0,
        };
        let sm = sheet.build(None, 10.0).unwrap();
        assert!(
            (sm.mesh.volume() - 600.0).abs() < 1e-3,
            "{}",
            sm.mesh.volume()
        );
        assert_eq!(sm.hulls.len(), 1);
    }

    #[test]
    fn revolved_outline_drops_axis_points_and_checks_bands() {
        let shaft = RevolvedSpec {
            bands: vec![[0.0, 10.0, 0.0, 5.0], [10.0, 30.0, 0.0, 3.0]],
            segments: 8,
            sector_segments: 8,
        };
        assert_eq!(
            shaft.outline().unwrap(),
            vec![
                [5.0, 0.0],
                [5.0, 10.0],
                [3.0, 10.0],
                [3.0, 30.0],
                [0.0, 30.0],
                [0.0, 0.0]
            ]
        );
        let sm = shaft.build().unwrap();
        // One vertex per axis point, 8 per ring; two solid bands, two pieces.
        assert_eq!(sm.mesh.vertices.len(), 4 * 8 + 2);
        assert_eq!(sm.hulls.len(), 2);
        let ring = RevolvedSpec {
            bands: vec![[-1.0, 1.0, 2.0, 4.0]],
            segments: 12,
            sector_segments: 3,
        };
        assert_eq!(ring.build().unwrap().hulls.len(), 4);
        for bad in [
            vec![[0.0, 10.0, 4.0, 3.0]],
            vec![[0.0, 10.0, 0.0, 3.0], [11.0, 12.0, 0.0, 2.0]],
            vec![],
        ] {
            let spec = RevolvedSpec {
                bands: bad.clone(),
                ..ring.clone()
            };
            assert!(spec.build().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn pipe_volume_matches_cylinder() {
        let pipe = PipeSpec {
            centerline: Profile {
                segments: vec![Segment::Straight(50.0)],
            },
            diameter: 10.0,
            ring_segments: 64,
        };
        let sm = pipe.build(None, 10.0).unwrap();
        let exact = std::f64::consts::PI * 25.0 * 50.0;
        assert!(
            (sm.mesh.volume() - exact).abs() / exact < 0.01,
            "{}",
            sm.mesh.volume()
        );
    }
}
