//! The three parts of the thesis (5.1.1), as exact meshes in their own frame (millimetres),
//! with physics collider pieces, their canonical resting side and their "cut" variants.
//!
//! | part | what | bounding box (part frame) | mass |
//! | --- | --- | --- | --- |
//! | A | 2 mm steel sheet, 50 mm wide, legs 60 and 70 mm, bent 90 deg (inner radius 2 mm), one corner chamfered 12 mm | 64 x 50 x 74 mm | 105 g |
//! | B | 2 mm steel sheet 140 x 90 mm, bent 20 deg (radius 30 mm) 50 mm from one end, one corner chamfered 15 mm | 135 x 90 x 31 mm | 196 g |
//! | C | steel pipe, 14 mm outer diameter (3 mm wall for the mass), legs 30 / 60 / 45 mm, two 45 deg bends (radius 21 mm) in one plane | 100 x 115 x 14 mm | 135 g |
//!
//! Canonical resting poses (the pose the model is scanned in): A like a tent on the free edges
//! of its legs, B on its long leg with the hollow side up, C flat.
//!
//! A and C have "cut" models (thesis Fig. 5.2 and 5.6): A-cut keeps the bend and 20 mm of each
//! leg; C-cut drops the unequal end legs, keeping the middle run, both bends and 12 mm of each
//! leg, so that the pipe looks the same from either side (a 180 deg turn about the in-plane axis
//! across the middle run maps it onto itself). The full parts have no symmetry.

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::SynthError;
use crate::mesh::{Mesh, PipeSpec, Profile, Segment, SheetSpec, SweptMesh, translate_swept};

/// Steel, g/mm^3 (physics uses grams, millimetres and seconds).
pub const STEEL_DENSITY: f64 = 7.85e-3;

/// The three part types.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum PartKind {
    A,
    B,
    C,
}

impl PartKind {
    pub const ALL: [PartKind; 3] = [PartKind::A, PartKind::B, PartKind::C];

    pub fn name(self) -> &'static str {
        match self {
            PartKind::A => "A",
            PartKind::B => "B",
            PartKind::C => "C",
        }
    }

    pub fn index(self) -> usize {
        match self {
            PartKind::A => 0,
            PartKind::B => 1,
            PartKind::C => 2,
        }
    }

    /// The models whose ground truth is written for scenes containing this part: the thesis
    /// matched A and B with their full models and C with both the full and the cut model.
    pub fn gt_models(self) -> &'static [&'static str] {
        match self {
            PartKind::A => &["A"],
            PartKind::B => &["B"],
            PartKind::C => &["C", "C-cut"],
        }
    }
}

impl std::fmt::Display for PartKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How a part is swept.
#[derive(Clone, Debug, PartialEq)]
pub enum Geometry {
    /// Profile in the part's raw x-z plane, width along y.
    Sheet(SheetSpec),
    /// Centre line in the part's raw x-y plane.
    Pipe(PipeSpec),
}

impl Geometry {
    fn profile(&self) -> &Profile {
        match self {
            Geometry::Sheet(s) => &s.profile,
            Geometry::Pipe(p) => &p.centerline,
        }
    }

    /// Profile-plane coordinates of a raw 3D point.
    fn to_plane(&self, p: &Vector3<f64>) -> [f64; 2] {
        match self {
            Geometry::Sheet(_) => [p.x, p.z],
            Geometry::Pipe(_) => [p.x, p.y],
        }
    }

    /// Raw 3D vector from profile-plane coordinates.
    fn plane_to_3d(&self, q: [f64; 2]) -> Vector3<f64> {
        match self {
            Geometry::Sheet(_) => Vector3::new(q[0], 0.0, q[1]),
            Geometry::Pipe(_) => Vector3::new(q[0], q[1], 0.0),
        }
    }

    fn build(&self, clip: Option<(f64, f64)>) -> Result<SweptMesh, SynthError> {
        match self {
            Geometry::Sheet(s) => s.build(clip, 10.0),
            Geometry::Pipe(p) => p.build(clip, 10.0),
        }
    }
}

/// A part: mesh, colliders and metadata, all in the part's own frame (the model frame).
#[derive(Clone, Debug)]
pub struct Part {
    pub kind: PartKind,
    pub geometry: Geometry,
    /// Closed triangle mesh, part frame, mm.
    pub mesh: Mesh,
    /// Convex vertex sets whose hulls form the physics collider.
    pub hulls: Vec<Vec<[f32; 3]>>,
    /// Density applied to the collider volume, g/mm^3.
    pub density: f64,
    /// Direction (part frame) that points up when the part lies in its canonical pose, the
    /// pose its model is scanned in.
    pub canonical_up: Vector3<f64>,
    /// Arc-length range of the profile kept by the cut model, if the part has one.
    pub cut_range: Option<(f64, f64)>,
    /// Raw sweep coordinates -> part frame (a translation centring the bounding box).
    offset: Vector3<f64>,
}

fn straight(l: f64) -> Segment {
    Segment::Straight(l)
}

fn bend(angle_deg: f64, radius: f64) -> Segment {
    Segment::Bend { angle_deg, radius }
}

impl Part {
    /// Builds one of the thesis's parts.
    pub fn new(kind: PartKind) -> Result<Part, SynthError> {
        let (geometry, density, cut_range) = match kind {
            PartKind::A => {
                let profile = Profile {
                    segments: vec![straight(60.0), bend(90.0, 3.0), straight(70.0)],
                };
                let l = profile.length();
                let bend_end = 60.0 + 1.5 * std::f64::consts::PI;
                let sheet = SheetSpec {
                    profile,
                    outline: vec![
                        [0.0, -25.0],
                        [l, -25.0],
                        [l, 13.0],
                        [l - 12.0, 25.0],
                        [0.0, 25.0],
                    ],
                    thickness: 2.0,
                };
                (
                    Geometry::Sheet(sheet),
                    STEEL_DENSITY,
                    Some((40.0, bend_end + 20.0)),
                )
            }
            PartKind::B => {
                let bend_len = 20f64.to_radians() * 30.0;
                let profile = Profile {
                    segments: vec![
                        straight(50.0),
                        bend(20.0, 30.0),
                        straight(140.0 - 50.0 - bend_len),
                    ],
                };
                let sheet = SheetSpec {
                    profile,
                    outline: vec![
                        [0.0, -45.0],
                        [140.0, -45.0],
                        [140.0, 30.0],
                        [125.0, 45.0],
                        [0.0, 45.0],
                    ],
                    thickness: 2.0,
                };
                (Geometry::Sheet(sheet), STEEL_DENSITY, None)
            }
            PartKind::C => {
                let r = 21.0;
                let bend_len = 45f64.to_radians() * r;
                let centerline = Profile {
                    segments: vec![
                        straight(30.0),
                        bend(45.0, r),
                        straight(60.0),
                        bend(45.0, r),
                        straight(45.0),
                    ],
                };
                let pipe = PipeSpec {
                    centerline,
                    diameter: 14.0,
                    ring_segments: 24,
                };
                // A 3 mm wall tube: its steel area over the full disc area of the collider.
                let (ro, ri): (f64, f64) = (7.0, 4.0);
                let fill = (ro * ro - ri * ri) / (ro * ro);
                (
                    Geometry::Pipe(pipe),
                    STEEL_DENSITY * fill,
                    Some((18.0, 30.0 + 2.0 * bend_len + 60.0 + 12.0)),
                )
            }
        };
        let mut swept = geometry.build(None)?;
        let b = swept
            .mesh
            .bounds()
            .ok_or_else(|| SynthError::Geometry("empty part mesh".into()))?;
        let offset = -Vector3::new(
            0.5 * f64::from(b.min[0] + b.max[0]),
            0.5 * f64::from(b.min[1] + b.max[1]),
            0.5 * f64::from(b.min[2] + b.max[2]),
        );
        translate_swept(&mut swept, &offset);
        let profile = geometry.profile();
        let canonical_up = match (&geometry, kind) {
            // A lies like a tent on the two free edges: the inside of the bend faces down.
            (Geometry::Sheet(_), PartKind::A) => {
                let mid = profile.at(60.0 + 0.75 * std::f64::consts::PI);
                let n = mid.normal();
                -geometry.plane_to_3d(n)
            }
            // B lies on its long leg, hollow side up.
            (Geometry::Sheet(_), _) => {
                let end = profile.at(profile.length());
                geometry.plane_to_3d(end.normal())
            }
            (Geometry::Pipe(_), _) => Vector3::z(),
        };
        Ok(Part {
            kind,
            density,
            canonical_up: canonical_up.normalize(),
            cut_range,
            mesh: swept.mesh,
            hulls: swept.hulls,
            geometry,
            offset,
        })
    }

    /// Largest distance of a mesh vertex from the part-frame origin, mm.
    pub fn bounding_radius(&self) -> f64 {
        self.mesh
            .vertices
            .iter()
            .map(|p| crate::mesh::to_point3(p).coords.norm())
            .fold(0.0, f64::max)
    }

    /// Volume of the solid, mm^3.
    pub fn volume(&self) -> f64 {
        self.mesh.volume()
    }

    /// Mesh of the cut model's portion of the part (same frame), if the part has one.
    pub fn cut_mesh(&self) -> Result<Option<Mesh>, SynthError> {
        let Some(range) = self.cut_range else {
            return Ok(None);
        };
        let mut swept = self.geometry.build(Some(range))?;
        translate_swept(&mut swept, &self.offset);
        Ok(Some(swept.mesh))
    }

    /// Arc length along the profile (sheet) or centre line (pipe) of the point nearest to a
    /// part-frame point.
    pub fn arc_length_of(&self, p: &[f32; 3]) -> f64 {
        let raw = crate::mesh::to_point3(p).coords - self.offset;
        self.geometry
            .profile()
            .project(self.geometry.to_plane(&raw))
    }

    /// Whether a part-frame point belongs to the cut model's portion (false without a cut).
    pub fn in_cut(&self, p: &[f32; 3]) -> bool {
        self.cut_range.is_some_and(|(lo, hi)| {
            let s = self.arc_length_of(p);
            s >= lo && s <= hi
        })
    }

    /// Rigid symmetries of the cut portion (identity first): the half turn about the in-plane
    /// axis through the middle of the cut, perpendicular to the profile there.
    pub fn cut_symmetries(&self) -> Vec<Isometry3<f64>> {
        let mut out = vec![Isometry3::identity()];
        if let Some((lo, hi)) = self.cut_range {
            let mid = self.geometry.profile().at(0.5 * (lo + hi));
            let point = self.geometry.plane_to_3d(mid.p) + self.offset;
            let axis = Unit::new_normalize(self.geometry.plane_to_3d(mid.normal()));
            out.push(half_turn_about(&Point3::from(point), &axis));
        }
        out
    }

    /// The orientation of the canonical resting pose (before physics settles it).
    pub fn canonical_rotation(&self) -> UnitQuaternion<f64> {
        UnitQuaternion::rotation_between(&self.canonical_up, &Vector3::z()).unwrap_or_else(|| {
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
        })
    }
}

/// Rotation by 180 degrees about the line through `point` along `axis`.
pub fn half_turn_about(point: &Point3<f64>, axis: &Unit<Vector3<f64>>) -> Isometry3<f64> {
    let rot = UnitQuaternion::from_axis_angle(axis, std::f64::consts::PI);
    let t = point.coords - rot * point.coords;
    Isometry3::from_parts(Translation3::from(t), rot)
}

/// The three parts, indexable by [`PartKind::index`].
#[derive(Clone, Debug)]
pub struct PartLibrary {
    pub parts: Vec<Part>,
}

impl PartLibrary {
    pub fn new() -> Result<Self, SynthError> {
        Ok(Self {
            parts: PartKind::ALL
                .iter()
                .map(|&k| Part::new(k))
                .collect::<Result<_, _>>()?,
        })
    }

    pub fn get(&self, kind: PartKind) -> &Part {
        &self.parts[kind.index()]
    }
}
