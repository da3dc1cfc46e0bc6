//! Piles made by rigid-body physics (rapier3d): parts are dropped one by one from random
//! orientations onto the belt / floor or into a bin and simulated until everything is at rest.
//!
//! Units inside the simulation: millimetres, grams, seconds (gravity 9810 mm/s^2, z up).
//! Colliders are unions of convex hulls of the exact meshes (exact for flat runs, within
//! 0.1 mm in bends), at the real 2 mm sheet thickness; tunnelling is prevented by CCD, a
//! 480 Hz step, stiff contacts and spawning every part just above the current pile.

use std::collections::HashMap;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rapier3d::prelude::{
    ColliderBuilder, ColliderHandle, PhysicsWorld, RigidBodyBuilder, RigidBodyHandle,
};
use serde::{Deserialize, Serialize};

use crate::SynthError;
use crate::mesh::Mesh;
use crate::parts::{PartKind, PartLibrary};
use crate::rng::Rng;

type PVec = rapier3d::math::Vector;
type PPose = rapier3d::math::Pose;
type PRot = rapier3d::math::Rotation;

/// nalgebra (f64) -> rapier (glam, f32) pose.
pub fn to_rapier_pose(iso: &Isometry3<f64>) -> PPose {
    let q = iso.rotation.quaternion();
    let t = iso.translation.vector;
    PPose::from_parts(
        PVec::new(t.x as f32, t.y as f32, t.z as f32),
        PRot::from_xyzw(q.i as f32, q.j as f32, q.k as f32, q.w as f32).normalize(),
    )
}

/// rapier (glam, f32) -> nalgebra (f64) pose.
pub fn from_rapier_pose(p: &PPose) -> Isometry3<f64> {
    let r = p.rotation;
    let q = UnitQuaternion::from_quaternion(Quaternion::new(
        f64::from(r.w),
        f64::from(r.x),
        f64::from(r.y),
        f64::from(r.z),
    ));
    let t = p.translation;
    Isometry3::from_parts(
        Translation3::new(f64::from(t.x), f64::from(t.y), f64::from(t.z)),
        q,
    )
}

/// What the parts rest on; part of the scene (it is scanned too).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Environment {
    /// A conveyor belt or table: the plane z = 0, modelled as a rectangle centred on the origin.
    Flat { size: [f64; 2] },
    /// A bin: floor (z = 0, `floor_size`) and four walls around an `inner` x/y area centred on
    /// the origin.
    Bin {
        floor_size: [f64; 2],
        inner: [f64; 2],
        wall_height: f64,
        wall_thickness: f64,
    },
}

impl Environment {
    /// The walls as boxes (min, max corners).
    fn wall_boxes(&self) -> Vec<([f64; 3], [f64; 3])> {
        match *self {
            Environment::Flat { .. } => Vec::new(),
            Environment::Bin {
                inner,
                wall_height: h,
                wall_thickness: t,
                ..
            } => {
                let (ix, iy) = (0.5 * inner[0], 0.5 * inner[1]);
                vec![
                    ([-ix - t, -iy - t, 0.0], [-ix, iy + t, h]),
                    ([ix, -iy - t, 0.0], [ix + t, iy + t, h]),
                    ([-ix, -iy - t, 0.0], [ix, -iy, h]),
                    ([-ix, iy, 0.0], [ix, iy + t, h]),
                ]
            }
        }
    }

    /// Size (x, y) of the floor rectangle, centred on the origin, top face at z = 0.
    pub fn floor_size(&self) -> [f64; 2] {
        match *self {
            Environment::Flat { size } => size,
            Environment::Bin { floor_size, .. } => floor_size,
        }
    }

    /// The walls as meshes (none for a flat environment).
    pub fn wall_meshes(&self) -> Vec<Mesh> {
        self.wall_boxes()
            .into_iter()
            .map(|(a, b)| Mesh::cuboid(a, b))
            .collect()
    }

    /// Inner x/y half-extents available for parts (for a flat environment: half its size).
    pub fn inner_half_extents(&self) -> [f64; 2] {
        match *self {
            Environment::Flat { size } => [0.5 * size[0], 0.5 * size[1]],
            Environment::Bin { inner, .. } => [0.5 * inner[0], 0.5 * inner[1]],
        }
    }
}

/// One part in a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Instance {
    pub kind: PartKind,
    /// Part (model) frame -> scene frame, mm.
    pub pose: Isometry3<f64>,
}

/// Simulation settings.
#[derive(Clone, Debug, PartialEq)]
pub struct PhysicsSettings {
    /// Time step, s.
    pub dt: f64,
    /// Simulated time between two consecutive drops, s.
    pub drop_interval: f64,
    /// Cap on the simulated time of one settling phase, s.
    pub max_settle_time: f64,
    /// Rest: over each of two consecutive `rest_window`-second windows, no point of any part
    /// moved more than `rest_displacement` mm (or every part is asleep). Measuring motion
    /// rather than velocity ignores the solver's tiny contact jitter.
    pub rest_window: f64,
    pub rest_displacement: f64,
    pub friction: f64,
    pub restitution: f64,
    /// Natural frequency (Hz) of the soft contacts between parts and with the floor / walls.
    pub contact_hz: f64,
    pub static_contact_hz: f64,
    pub solver_iterations: usize,
    /// Velocity damping (1/s) of the parts, linear and angular.
    pub linear_damping: f64,
    pub angular_damping: f64,
}

impl Default for PhysicsSettings {
    fn default() -> Self {
        Self {
            dt: 1.0 / 480.0,
            drop_interval: 0.2,
            max_settle_time: 4.0,
            rest_window: 0.1,
            rest_displacement: 0.02,
            friction: 0.5,
            restitution: 0.05,
            contact_hz: 240.0,
            static_contact_hz: 480.0,
            solver_iterations: 6,
            linear_damping: 0.5,
            angular_damping: 1.5,
        }
    }
}

/// A pile under construction: a rapier world holding the environment and the dropped parts.
pub struct Pile<'a> {
    lib: &'a PartLibrary,
    settings: PhysicsSettings,
    world: PhysicsWorld,
    parts: Vec<(PartKind, RigidBodyHandle)>,
    corral: Vec<ColliderHandle>,
    /// Physics steps taken so far.
    pub steps: usize,
}

fn cuboid_collider(min: [f64; 3], max: [f64; 3]) -> ColliderBuilder {
    let h = |i: usize| (0.5 * (max[i] - min[i])) as f32;
    let c = |i: usize| (0.5 * (max[i] + min[i])) as f32;
    ColliderBuilder::cuboid(h(0), h(1), h(2)).translation(PVec::new(c(0), c(1), c(2)))
}

impl<'a> Pile<'a> {
    /// An empty world with the environment's floor and walls, plus (optionally) a temporary
    /// corral - invisible walls around `[xmin, xmax, ymin, ymax]` that keep the falling parts
    /// together and are removed with [`Pile::remove_corral`].
    pub fn new(
        lib: &'a PartLibrary,
        env: &Environment,
        corral: Option<[f64; 4]>,
        settings: PhysicsSettings,
    ) -> Self {
        let mut world = PhysicsWorld::new();
        world.gravity = PVec::new(0.0, 0.0, -9810.0);
        world.integration_parameters.dt = settings.dt as f32;
        // Tolerances scale with this: 0.05 mm allowed penetration, 0.2 mm prediction.
        world.integration_parameters.length_unit = 10.0;
        world.integration_parameters.num_solver_iterations = settings.solver_iterations.max(1);
        // Much stiffer contacts than rapier's defaults (30 / 60 Hz, made for metre-sized
        // bodies): the soft-contact sag g / omega^2 would let the stacked 2 mm sheets sink
        // ~0.3 mm into each other. With 240 / 480 Hz and a 1/480 s step the median overlap in
        // a pile is ~0.02 mm.
        world
            .integration_parameters
            .contact_softness
            .natural_frequency = settings.contact_hz as f32;
        world
            .integration_parameters
            .static_contact_softness
            .natural_frequency = settings.static_contact_hz as f32;
        let friction = settings.friction as f32;
        world.insert_collider(
            cuboid_collider([-2000.0, -2000.0, -50.0], [2000.0, 2000.0, 0.0]).friction(friction),
            None,
        );
        for (a, b) in env.wall_boxes() {
            world.insert_collider(cuboid_collider(a, b).friction(friction), None);
        }
        let mut corral_handles = Vec::new();
        if let Some([x0, x1, y0, y1]) = corral {
            let (t, h) = (20.0, 600.0);
            for (a, b) in [
                ([x0 - t, y0 - t, 0.0], [x0, y1 + t, h]),
                ([x1, y0 - t, 0.0], [x1 + t, y1 + t, h]),
                ([x0, y0 - t, 0.0], [x1, y0, h]),
                ([x0, y1, 0.0], [x1, y1 + t, h]),
            ] {
                corral_handles
                    .push(world.insert_collider(cuboid_collider(a, b).friction(0.1), None));
            }
        }
        Self {
            lib,
            settings,
            world,
            parts: Vec::new(),
            corral: corral_handles,
            steps: 0,
        }
    }

    /// Highest point of every part (z of its mesh's top), mm.
    fn top_of(&self, kind: PartKind, handle: RigidBodyHandle) -> f64 {
        let pose = from_rapier_pose(self.world.bodies[handle].position());
        self.lib
            .get(kind)
            .mesh
            .vertices
            .iter()
            .map(|p| binpick_cloud::transform_point(&pose, p)[2])
            .fold(f32::NEG_INFINITY, f32::max)
            .into()
    }

    /// Top of the pile (0 when empty), mm.
    pub fn height(&self) -> f64 {
        self.parts
            .iter()
            .map(|&(k, h)| self.top_of(k, h))
            .fold(0.0, f64::max)
    }

    /// Adds one part at `pose` (no settling).
    pub fn add_part(&mut self, kind: PartKind, pose: &Isometry3<f64>) -> Result<(), SynthError> {
        let part = self.lib.get(kind);
        let body = RigidBodyBuilder::dynamic()
            .pose(to_rapier_pose(pose))
            .ccd_enabled(true)
            .linear_damping(self.settings.linear_damping as f32)
            .angular_damping(self.settings.angular_damping as f32);
        let handle = self.world.insert_body(body);
        for hull in &part.hulls {
            let pts: Vec<PVec> = hull.iter().map(|p| PVec::new(p[0], p[1], p[2])).collect();
            let collider = ColliderBuilder::convex_hull(&pts)
                .ok_or_else(|| SynthError::Geometry(format!("part {kind}: degenerate hull")))?
                .density(part.density as f32)
                .friction(self.settings.friction as f32)
                .restitution(self.settings.restitution as f32);
            self.world.insert_collider(collider, Some(handle));
        }
        self.parts.push((kind, handle));
        Ok(())
    }

    /// Drops the parts one after another: each from a random orientation at a random x/y that
    /// keeps it inside `area` (`[xmin, xmax, ymin, ymax]`), its lowest point 5-25 mm above the
    /// current top of the pile, then lets everything settle. Returns whether it came to rest.
    pub fn drop_parts(
        &mut self,
        kinds: &[PartKind],
        area: [f64; 4],
        rng: &mut Rng,
    ) -> Result<bool, SynthError> {
        let interval = (self.settings.drop_interval / self.settings.dt).round() as usize;
        for &kind in kinds {
            let rot = rng.rotation();
            // Keep the whole rotated part inside the area (centred when it cannot fit).
            let turned = self
                .lib
                .get(kind)
                .mesh
                .transformed(&Isometry3::from_parts(Translation3::identity(), rot));
            let b = turned
                .bounds()
                .ok_or_else(|| SynthError::Geometry(format!("part {kind}: empty mesh")))?;
            let pick = |rng: &mut Rng, lo: f64, hi: f64, bmin: f32, bmax: f32| {
                let (a, c) = (lo - f64::from(bmin), hi - f64::from(bmax));
                if a < c {
                    rng.range(a, c)
                } else {
                    0.5 * (a + c)
                }
            };
            let x = pick(rng, area[0], area[1], b.min[0], b.max[0]);
            let y = pick(rng, area[2], area[3], b.min[1], b.max[1]);
            let z = self.height() - f64::from(b.min[2]) + rng.range(5.0, 25.0);
            self.add_part(
                kind,
                &Isometry3::from_parts(Translation3::new(x, y, z), rot),
            )?;
            for _ in 0..interval {
                self.step();
            }
        }
        Ok(self.settle())
    }

    fn step(&mut self) {
        self.world.step();
        self.steps += 1;
    }

    /// Steps until every part is at rest (or the time cap); returns whether rest was reached.
    pub fn settle(&mut self) -> bool {
        let max_steps = (self.settings.max_settle_time / self.settings.dt).ceil() as usize;
        let window = ((self.settings.rest_window / self.settings.dt).ceil() as usize).max(1);
        let mut before = self.instances();
        let mut calm = 0;
        let mut steps = 0;
        while steps < max_steps {
            for _ in 0..window {
                self.step();
            }
            steps += window;
            if self.all_asleep() {
                return true;
            }
            let now = self.instances();
            if self.max_motion(&before, &now) < self.settings.rest_displacement {
                calm += 1;
                if calm >= 2 {
                    return true;
                }
            } else {
                calm = 0;
            }
            before = now;
        }
        false
    }

    fn all_asleep(&self) -> bool {
        self.parts
            .iter()
            .all(|&(_, h)| self.world.bodies[h].is_sleeping())
    }

    /// Largest displacement of a point of a part between two snapshots (bound: translation +
    /// bounding radius x rotation angle), mm.
    fn max_motion(&self, a: &[Instance], b: &[Instance]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| {
                let r = self.lib.get(x.kind).bounding_radius();
                let dt = (y.pose.translation.vector - x.pose.translation.vector).norm();
                let da = x.pose.rotation.angle_to(&y.pose.rotation);
                dt + r * da
            })
            .fold(0.0, f64::max)
    }

    /// Linear (mm/s) and angular (rad/s) speed of each part, in drop order.
    pub fn speeds(&self) -> Vec<(f64, f64)> {
        self.parts
            .iter()
            .map(|&(_, h)| {
                let b = &self.world.bodies[h];
                (
                    f64::from(b.linvel().length()),
                    f64::from(b.angvel().length()),
                )
            })
            .collect()
    }

    /// Largest linear (mm/s) and angular (rad/s) speed among the awake parts.
    pub fn max_speeds(&self) -> (f64, f64) {
        self.parts
            .iter()
            .map(|&(_, h)| &self.world.bodies[h])
            .filter(|b| !b.is_sleeping())
            .fold((0.0, 0.0), |(l, a), b| {
                (
                    l.max(f64::from(b.linvel().length())),
                    a.max(f64::from(b.angvel().length())),
                )
            })
    }

    /// Smallest signed distance (mm, negative = overlap) between the colliders of every pair of
    /// bodies closer than `prediction`: keys are part indices (drop order), `None` for the
    /// floor and walls (the corral excluded).
    fn proximities(&self, prediction: f64) -> HashMap<(Option<usize>, Option<usize>), f64> {
        use rapier3d::parry::bounding_volume::BoundingVolume;
        let part_of: HashMap<ColliderHandle, usize> = self
            .parts
            .iter()
            .enumerate()
            .flat_map(|(i, &(_, h))| {
                self.world.bodies[h]
                    .colliders()
                    .iter()
                    .map(move |&c| (c, i))
            })
            .collect();
        let all: Vec<(ColliderHandle, Option<usize>)> = self
            .world
            .colliders
            .iter()
            .filter(|(h, _)| !self.corral.contains(h))
            .map(|(h, _)| (h, part_of.get(&h).copied()))
            .collect();
        let mut out: HashMap<(Option<usize>, Option<usize>), f64> = HashMap::new();
        for (i, &(h1, p1)) in all.iter().enumerate() {
            for &(h2, p2) in &all[i + 1..] {
                if p1 == p2 {
                    continue;
                }
                let (c1, c2) = (&self.world.colliders[h1], &self.world.colliders[h2]);
                let grow = prediction as f32;
                if !c1
                    .compute_aabb()
                    .loosened(grow)
                    .intersects(&c2.compute_aabb())
                {
                    continue;
                }
                if let Ok(Some(c)) = rapier3d::parry::query::contact(
                    c1.position(),
                    c1.shape(),
                    c2.position(),
                    c2.shape(),
                    grow,
                ) {
                    let key = if p1 < p2 { (p1, p2) } else { (p2, p1) };
                    let d = out.entry(key).or_insert(f64::INFINITY);
                    *d = d.min(f64::from(c.dist));
                }
            }
        }
        out
    }

    /// Deepest overlap (mm, >= 0) between two different parts, or between a part and the floor
    /// / walls: a check that nothing tunnelled.
    pub fn max_penetration(&self) -> f64 {
        self.proximities(0.0)
            .values()
            .fold(0.0, |worst, &d| worst.max(-d))
    }

    /// Pairs of parts (drop-order indices) whose surfaces are within `tolerance` mm.
    pub fn touching_pairs(&self, tolerance: f64) -> Vec<(usize, usize)> {
        let mut pairs: Vec<(usize, usize)> = self
            .proximities(tolerance)
            .into_iter()
            .filter_map(|(k, d)| match k {
                (Some(a), Some(b)) if d <= tolerance => Some((a, b)),
                _ => None,
            })
            .collect();
        pairs.sort_unstable();
        pairs
    }

    /// Removes the temporary corral walls (and wakes everything up).
    pub fn remove_corral(&mut self) {
        for h in std::mem::take(&mut self.corral) {
            self.world.remove_collider(h);
        }
        self.world.wake_up_all(true);
    }

    /// Removes the part whose highest point is the highest (what a picker would take first),
    /// returning its kind. Does not settle.
    pub fn remove_topmost(&mut self) -> Option<PartKind> {
        let (idx, _) = self
            .parts
            .iter()
            .enumerate()
            .map(|(i, &(k, h))| (i, self.top_of(k, h)))
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
        let (kind, handle) = self.parts.remove(idx);
        self.world.remove_body(handle);
        self.world.wake_up_all(true);
        Some(kind)
    }

    /// Current poses of the parts, in drop order.
    pub fn instances(&self) -> Vec<Instance> {
        self.parts
            .iter()
            .map(|&(kind, h)| Instance {
                kind,
                pose: from_rapier_pose(self.world.bodies[h].position()),
            })
            .collect()
    }

    /// Number of parts in the pile.
    pub fn len(&self) -> usize {
        self.parts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }
}

/// Lays one part in its canonical resting pose: dropped from just above the belt in its
/// canonical orientation, settled, then moved so that its bounding box is centred on x = y = 0.
pub fn canonical_pose(lib: &PartLibrary, kind: PartKind) -> Result<Isometry3<f64>, SynthError> {
    let part = lib.get(kind);
    let env = Environment::Flat {
        size: [1000.0, 1000.0],
    };
    let mut pile = Pile::new(lib, &env, None, PhysicsSettings::default());
    let rot = part.canonical_rotation();
    let lowest = part
        .mesh
        .vertices
        .iter()
        .map(|p| (rot * crate::mesh::to_point3(p)).z)
        .fold(f64::INFINITY, f64::min);
    let start = Isometry3::from_parts(Translation3::new(0.0, 0.0, -lowest + 1.0), rot);
    pile.add_part(kind, &start)?;
    pile.settle();
    let pose = pile
        .instances()
        .pop()
        .map(|i| i.pose)
        .ok_or_else(|| SynthError::Geometry("canonical drop lost the part".into()))?;
    let placed = part.mesh.transformed(&pose);
    let b = placed
        .bounds()
        .ok_or_else(|| SynthError::Geometry("empty part mesh".into()))?;
    let shift = Vector3::new(
        -0.5 * f64::from(b.min[0] + b.max[0]),
        -0.5 * f64::from(b.min[1] + b.max[1]),
        0.0,
    );
    Ok(Isometry3::from_parts(Translation3::from(shift), UnitQuaternion::identity()) * pose)
}
