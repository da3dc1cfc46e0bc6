//! The parts as exact meshes in their own frame (millimetres), with physics collider pieces,
//! their canonical resting side, their true symmetry group and, for the thesis's parts, their
//! "cut" variants.
//!
//! The thesis's three parts (5.1.1):
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
//!
//! Part families nobody tuned for (the generalisation benchmark), all steel:
//!
//! | part | what | symmetry group |
//! | --- | --- | --- |
//! | `bracket` | Z bracket: 2 mm sheet 40 mm wide, flanges 30 and 35 mm bent opposite ways (inner radius 2 mm) off a 26 mm web; about 73 x 40 x 34 mm | none: a half turn about the web's axis swaps the flanges, which differ by 5 mm |
//! | `rod` | round rod, 7 mm diameter, legs 55 / 30 / 25 mm, bends of 90 and 45 deg (radius 15 mm) the same way, in one plane; 145 mm of rod | none (the bent centre line has no mirror line) |
//! | `shaft` | stepped shaft, diameters 20 / 14 / 10 mm over 35 / 25 / 20 mm along z | rotations about its axis (z), listed every 5 deg |
//! | `ring` | flat ring (washer), outer 50 mm, inner 28 mm, 4 mm thick, axis z | rotations about its axis every 5 deg, each also turned upside down |
//! | `plate` | 3 mm plate 80 x 50 mm bent 35 deg (mid radius 5 mm) 30 mm from one end | none |
//!
//! Colliders are compounds of convex pieces of the exact mesh (one per flat run or cylinder,
//! bends split every 10 deg, hollow rings in 15 deg sectors), so that non-convex parts do not
//! pile as their convex hull.

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::SynthError;
use crate::mesh::{
    Mesh, PipeSpec, Profile, RevolvedSpec, Segment, SheetSpec, SweptMesh, translate_swept,
};

/// Steel, g/mm^3 (physics uses grams, millimetres and seconds).
pub const STEEL_DENSITY: f64 = 7.85e-3;

/// The part types: the thesis's three and the generalisation benchmark's five families.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum PartKind {
    A,
    B,
    C,
    #[serde(rename = "bracket")]
    Bracket,
    #[serde(rename = "rod")]
    Rod,
    #[serde(rename = "shaft")]
    Shaft,
    #[serde(rename = "ring")]
    Ring,
    #[serde(rename = "plate")]
    Plate,
}

impl PartKind {
    /// Every part type, in [`PartKind::index`] order.
    pub const ALL: [PartKind; 8] = [
        PartKind::A,
        PartKind::B,
        PartKind::C,
        PartKind::Bracket,
        PartKind::Rod,
        PartKind::Shaft,
        PartKind::Ring,
        PartKind::Plate,
    ];
    /// The thesis's parts (the thesis presets use only these).
    pub const THESIS: [PartKind; 3] = [PartKind::A, PartKind::B, PartKind::C];
    /// The part families of the generalisation benchmark.
    pub const FAMILIES: [PartKind; 5] = [
        PartKind::Bracket,
        PartKind::Rod,
        PartKind::Shaft,
        PartKind::Ring,
        PartKind::Plate,
    ];

    pub fn name(self) -> &'static str {
        match self {
            PartKind::A => "A",
            PartKind::B => "B",
            PartKind::C => "C",
            PartKind::Bracket => "bracket",
            PartKind::Rod => "rod",
            PartKind::Shaft => "shaft",
            PartKind::Ring => "ring",
            PartKind::Plate => "plate",
        }
    }

    pub fn index(self) -> usize {
        match self {
            PartKind::A => 0,
            PartKind::B => 1,
            PartKind::C => 2,
            PartKind::Bracket => 3,
            PartKind::Rod => 4,
            PartKind::Shaft => 5,
            PartKind::Ring => 6,
            PartKind::Plate => 7,
        }
    }

    /// The models whose ground truth is written for scenes containing this part: the thesis
    /// matched A and B with their full models and C with both the full and the cut model;
    /// every other part has one model.
    pub fn gt_models(self) -> &'static [&'static str] {
        match self {
            PartKind::A => &["A"],
            PartKind::B => &["B"],
            PartKind::C => &["C", "C-cut"],
            PartKind::Bracket => &["bracket"],
            PartKind::Rod => &["rod"],
            PartKind::Shaft => &["shaft"],
            PartKind::Ring => &["ring"],
            PartKind::Plate => &["plate"],
        }
    }
}

impl std::str::FromStr for PartKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        PartKind::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = PartKind::ALL.iter().map(|k| k.name()).collect();
                format!("unknown part {s:?}: expected one of {}", names.join(", "))
            })
    }
}

impl std::fmt::Display for PartKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// How a part is built.
#[derive(Clone, Debug, PartialEq)]
pub enum Geometry {
    /// Profile in the part's raw x-z plane, width along y.
    Sheet(SheetSpec),
    /// Centre line in the part's raw x-y plane.
    Pipe(PipeSpec),
    /// Solid of revolution about the raw z axis.
    Revolved(RevolvedSpec),
}

impl Geometry {
    /// The swept profile (sheet) or centre line (pipe); none for a solid of revolution.
    fn profile(&self) -> Option<&Profile> {
        match self {
            Geometry::Sheet(s) => Some(&s.profile),
            Geometry::Pipe(p) => Some(&p.centerline),
            Geometry::Revolved(_) => None,
        }
    }

    /// Profile-plane coordinates of a raw 3D point.
    fn to_plane(&self, p: &Vector3<f64>) -> [f64; 2] {
        match self {
            Geometry::Sheet(_) => [p.x, p.z],
            Geometry::Pipe(_) | Geometry::Revolved(_) => [p.x, p.y],
        }
    }

    /// Raw 3D vector from profile-plane coordinates.
    fn plane_to_3d(&self, q: [f64; 2]) -> Vector3<f64> {
        match self {
            Geometry::Sheet(_) => Vector3::new(q[0], 0.0, q[1]),
            Geometry::Pipe(_) | Geometry::Revolved(_) => Vector3::new(q[0], q[1], 0.0),
        }
    }

    fn build(&self, clip: Option<(f64, f64)>) -> Result<SweptMesh, SynthError> {
        match self {
            Geometry::Sheet(s) => s.build(clip, 10.0),
            Geometry::Pipe(p) => p.build(clip, 10.0),
            Geometry::Revolved(r) if clip.is_none() => r.build(),
            Geometry::Revolved(_) => Err(SynthError::Geometry(
                "a solid of revolution has no cut".into(),
            )),
        }
    }
}

/// A continuous rotational symmetry: the line about which any rotation maps the part onto
/// itself (part frame, mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RevolutionAxis {
    pub point: Point3<f64>,
    pub direction: Unit<Vector3<f64>>,
}

/// Step between the listed samples of a continuous symmetry, degrees.
pub const REVOLUTION_SAMPLE_DEG: f64 = 5.0;

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
    /// The axis of a part that is a solid of revolution.
    pub revolution_axis: Option<RevolutionAxis>,
    /// Whether a half turn about an axis perpendicular to the revolution axis (through the
    /// origin, along x) maps the part onto itself (a flat ring is the same upside down).
    pub flips: bool,
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
    /// Builds one part.
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
            PartKind::Bracket => {
                // Mid-surface bend radius 3 mm = inner radius 2 mm at 2 mm thickness.
                let profile = Profile {
                    segments: vec![
                        straight(30.0),
                        bend(90.0, 3.0),
                        straight(26.0),
                        bend(-90.0, 3.0),
                        straight(35.0),
                    ],
                };
                let l = profile.length();
                let sheet = SheetSpec {
                    profile,
                    outline: vec![[0.0, -20.0], [l, -20.0], [l, 20.0], [0.0, 20.0]],
                    thickness: 2.0,
                };
                (Geometry::Sheet(sheet), STEEL_DENSITY, None)
            }
            PartKind::Rod => {
                let centerline = Profile {
                    segments: vec![
                        straight(55.0),
                        bend(90.0, 15.0),
                        straight(30.0),
                        bend(45.0, 15.0),
                        straight(25.0),
                    ],
                };
                let pipe = PipeSpec {
                    centerline,
                    diameter: 7.0,
                    ring_segments: 24,
                };
                (Geometry::Pipe(pipe), STEEL_DENSITY, None)
            }
            PartKind::Shaft => {
                let spec = RevolvedSpec {
                    bands: vec![
                        [0.0, 35.0, 0.0, 10.0],
                        [35.0, 60.0, 0.0, 7.0],
                        [60.0, 80.0, 0.0, 5.0],
                    ],
                    segments: REVOLUTION_SEGMENTS,
                    sector_segments: REVOLUTION_SEGMENTS,
                };
                (Geometry::Revolved(spec), STEEL_DENSITY, None)
            }
            PartKind::Ring => {
                let spec = RevolvedSpec {
                    bands: vec![[-2.0, 2.0, 14.0, 25.0]],
                    segments: REVOLUTION_SEGMENTS,
                    sector_segments: 3,
                };
                (Geometry::Revolved(spec), STEEL_DENSITY, None)
            }
            PartKind::Plate => {
                let bend_len = 35f64.to_radians() * 5.0;
                let profile = Profile {
                    segments: vec![
                        straight(30.0),
                        bend(35.0, 5.0),
                        straight(80.0 - 30.0 - bend_len),
                    ],
                };
                let sheet = SheetSpec {
                    profile,
                    outline: vec![[0.0, -25.0], [80.0, -25.0], [80.0, 25.0], [0.0, 25.0]],
                    thickness: 3.0,
                };
                (Geometry::Sheet(sheet), STEEL_DENSITY, None)
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
        let canonical_up = match (&geometry, kind) {
            // A lies like a tent on the two free edges: the inside of the bend faces down.
            (Geometry::Sheet(sheet), PartKind::A) => {
                let mid = sheet.profile.at(60.0 + 0.75 * std::f64::consts::PI);
                -geometry.plane_to_3d(mid.normal())
            }
            // The Z bracket leans on the outer corner of its first bend and the tip of its
            // second flange (a face of its convex hull), the first flange in the air.
            (Geometry::Sheet(sheet), PartKind::Bracket) => {
                let half = 0.5 * sheet.thickness;
                let corner = sheet.point(30.0 + 0.75 * std::f64::consts::PI, 0.0, -half);
                let tip = sheet.point(sheet.profile.length(), 0.0, -half);
                let d = tip - corner;
                // The hull face's outward normal is d turned clockwise in the x-z plane.
                Vector3::new(-d.z, 0.0, d.x)
            }
            // B and the bent plate lie on their long leg, hollow side up.
            (Geometry::Sheet(sheet), _) => {
                let end = sheet.profile.at(sheet.profile.length());
                geometry.plane_to_3d(end.normal())
            }
            (Geometry::Pipe(_), _) => Vector3::z(),
            // A shaft lies on its side; a ring lies flat.
            (Geometry::Revolved(_), PartKind::Shaft) => Vector3::x(),
            (Geometry::Revolved(_), _) => Vector3::z(),
        };
        // The raw axis is z through the raw origin; its point at the part's centre height.
        let revolution_axis = matches!(geometry, Geometry::Revolved(_)).then(|| RevolutionAxis {
            // (+ 0.0 turns a -0.0 into 0.0 for the written files.)
            point: Point3::new(offset.x + 0.0, offset.y + 0.0, 0.0),
            direction: Vector3::z_axis(),
        });
        Ok(Part {
            kind,
            density,
            canonical_up: canonical_up.normalize(),
            cut_range,
            revolution_axis,
            flips: kind == PartKind::Ring,
            mesh: swept.mesh,
            hulls: swept.hulls,
            geometry,
            offset,
        })
    }

    /// The part's rigid symmetries (identity first): the identity alone for a part without
    /// symmetry; for a solid of revolution the rotations about its axis every
    /// [`REVOLUTION_SAMPLE_DEG`] degrees (samples of the continuous group), each also composed
    /// with the half turn that turns it upside down when [`Part::flips`].
    pub fn symmetries(&self) -> Vec<Isometry3<f64>> {
        let mut out = vec![Isometry3::identity()];
        let Some(axis) = self.revolution_axis else {
            return out;
        };
        let steps = (360.0 / REVOLUTION_SAMPLE_DEG).round() as usize;
        let turns: Vec<Isometry3<f64>> = (0..steps)
            .map(|k| {
                let angle = (k as f64 * REVOLUTION_SAMPLE_DEG).to_radians();
                rotation_about(&axis.point, &axis.direction, angle)
            })
            .collect();
        out.extend(turns.iter().skip(1).copied());
        if self.flips {
            // Any axis perpendicular to the revolution axis through its centre will do.
            let d = axis.direction.into_inner();
            let other = if d.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let across = Unit::new_normalize(d.cross(&other));
            let flip = half_turn_about(&axis.point, &across);
            out.extend(turns.iter().map(|t| t * flip));
        }
        out
    }

    /// Rigid motions that almost map the part onto itself but are NOT symmetries (the traps a
    /// recogniser must not fall into): the Z bracket's half turn about the axis through the
    /// middle of its web, across the sheet (it swaps the 30 and 35 mm flanges).
    pub fn near_symmetries(&self) -> Vec<Isometry3<f64>> {
        match (&self.geometry, self.kind) {
            (Geometry::Sheet(sheet), PartKind::Bracket) => {
                let s_mid = 30.0 + 1.5 * std::f64::consts::PI + 13.0;
                let mid = sheet.profile.at(s_mid);
                let point = self.geometry.plane_to_3d(mid.p) + self.offset;
                vec![half_turn_about(&Point3::from(point), &Vector3::y_axis())]
            }
            _ => Vec::new(),
        }
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
    /// part-frame point (none for a solid of revolution).
    pub fn arc_length_of(&self, p: &[f32; 3]) -> Option<f64> {
        let raw = crate::mesh::to_point3(p).coords - self.offset;
        let profile = self.geometry.profile()?;
        Some(profile.project(self.geometry.to_plane(&raw)))
    }

    /// Whether a part-frame point belongs to the cut model's portion (false without a cut).
    pub fn in_cut(&self, p: &[f32; 3]) -> bool {
        self.cut_range
            .is_some_and(|(lo, hi)| self.arc_length_of(p).is_some_and(|s| s >= lo && s <= hi))
    }

    /// Rigid symmetries of the cut portion (identity first): the half turn about the in-plane
    /// axis through the middle of the cut, perpendicular to the profile there.
    pub fn cut_symmetries(&self) -> Vec<Isometry3<f64>> {
        let mut out = vec![Isometry3::identity()];
        if let (Some((lo, hi)), Some(profile)) = (self.cut_range, self.geometry.profile()) {
            let mid = profile.at(0.5 * (lo + hi));
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
    rotation_about(point, axis, std::f64::consts::PI)
}

/// Rotation by `angle` (radians) about the line through `point` along `axis`.
pub fn rotation_about(
    point: &Point3<f64>,
    axis: &Unit<Vector3<f64>>,
    angle: f64,
) -> Isometry3<f64> {
    let rot = UnitQuaternion::from_axis_angle(axis, angle);
    let t = point.coords - rot * point.coords;
    Isometry3::from_parts(Translation3::from(t), rot)
}

/// Facets around the axis of the solids of revolution: a multiple of 360 /
/// [`REVOLUTION_SAMPLE_DEG`], so that every listed symmetry maps the mesh exactly onto itself.
pub const REVOLUTION_SEGMENTS: usize = 72;

/// Every part, indexable by [`PartKind::index`].
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
