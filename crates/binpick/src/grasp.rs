//! Grasps: where a gripper takes a part (declared in the model sidecar, model frame) and
//! whether it can get there. Each grasp's **approach corridor** is the cylinder the gripper
//! sweeps on its way in: radius `clearance_radius_mm` around the approach axis, from the
//! grasp position back against `approach` for `clearance_length_mm`. Scene points in it
//! (other than the part's own surface) and the placed surfaces of other detections block it.
//!
//! The pick order puts the detections free to pick with at least one free grasp first
//! (keeping the engine's order otherwise), so the first pick is the best part the gripper
//! can reach. A detection whose every grasp is blocked is not free to pick and says what
//! blocks each one.

use nalgebra::{Isometry3, Point3, Unit, Vector3};
use serde::{Deserialize, Serialize};

use binpick_cloud::{Point, to_point3};

use crate::error::{Result, input};
use crate::result::Detection;
use crate::validate::NearestIndex;

/// Most surface samples of the part placed per detection (its own surface, and what blocks
/// others' corridors where the scan does not see it).
const PLACED_SAMPLES: usize = 4000;

/// A grasp declared in the model sidecar (`"grasps": [...]`), in the model's frame, mm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[non_exhaustive]
pub struct Grasp {
    /// Name in reports; default `grasp <k>` (1-based position in the sidecar's list).
    #[serde(default)]
    pub name: Option<String>,
    /// Where the gripper's tool centre point is when it closes, model frame, mm.
    pub position_mm: [f64; 3],
    /// Direction the gripper moves in to reach `position_mm` (towards the part), model
    /// frame; any non-zero length (normalised on use).
    pub approach: [f64; 3],
    /// Radius of the cylinder the gripper sweeps while approaching, mm (> 0).
    pub clearance_radius_mm: f64,
    /// Length of that cylinder, from `position_mm` back against `approach`, mm (> 0).
    pub clearance_length_mm: f64,
}

impl Grasp {
    /// A grasp at `position_mm`, approached along `approach`, with a corridor of
    /// `clearance_radius_mm` x `clearance_length_mm` (model frame, mm).
    pub fn new(
        position_mm: [f64; 3],
        approach: [f64; 3],
        clearance_radius_mm: f64,
        clearance_length_mm: f64,
    ) -> Self {
        Self {
            name: None,
            position_mm,
            approach,
            clearance_radius_mm,
            clearance_length_mm,
        }
    }

    /// The same grasp named `name`.
    pub fn named(mut self, name: &str) -> Self {
        self.name = Some(name.to_owned());
        self
    }

    /// Checks the declaration; `index` is its 0-based position (for the message).
    pub fn validate(&self, index: usize) -> Result<()> {
        let bad = |m: &str| input("grasp", format!("{}: {m}", self.label(index)));
        if !self.position_mm.iter().all(|v| v.is_finite()) {
            return Err(bad("position_mm must be three finite numbers"));
        }
        let a = Vector3::from(self.approach);
        if !a.iter().all(|v| v.is_finite()) || a.norm() < 1e-9 {
            return Err(bad("approach must be a finite, non-zero direction"));
        }
        for (v, field) in [
            (self.clearance_radius_mm, "clearance_radius_mm"),
            (self.clearance_length_mm, "clearance_length_mm"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(&format!("{field} must be > 0 mm, got {v}")));
            }
        }
        Ok(())
    }

    /// Its name, or `grasp <index + 1>`.
    pub fn label(&self, index: usize) -> String {
        self.name
            .clone()
            .unwrap_or_else(|| format!("grasp {}", index + 1))
    }

    /// Unit approach direction, model frame.
    fn approach_unit(&self) -> Unit<Vector3<f64>> {
        Unit::new_normalize(Vector3::from(self.approach))
    }
}

/// What keeps a grasp's corridor from being free.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum Blocker {
    /// Another detection: its scanned points and its placed surface in the corridor.
    Detection {
        /// The blocking detection's rank in this result.
        rank: usize,
        /// Its points in the corridor (scan points plus placed-surface samples).
        points: usize,
    },
    /// Scan points that belong to no detection (clutter, a bin wall, an unrecognised part).
    ScenePoints {
        /// How many lie in the corridor.
        points: usize,
    },
}

impl std::fmt::Display for Blocker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Blocker::Detection { rank, points } => {
                write!(f, "detection {rank} ({points} points)")
            }
            Blocker::ScenePoints { points } => write!(f, "{points} scene points"),
        }
    }
}

/// One grasp of a detection, in the result's frame (`frame_id`), and whether its approach
/// corridor is free.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub struct GraspCheck {
    /// The declared grasp's name (`grasp <k>` when unnamed).
    pub name: String,
    /// Tool centre point, mm, in the result's frame.
    pub position_mm: [f64; 3],
    /// Unit direction the gripper moves in to reach it, in the result's frame.
    pub approach: [f64; 3],
    /// Nothing blocks the corridor.
    pub free: bool,
    /// What blocks it, most points first (empty when free).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub blocked_by: Vec<Blocker>,
}

impl GraspCheck {
    /// The same grasp seen through `t` (a change of frame).
    pub(crate) fn transformed(&self, t: &Isometry3<f64>) -> Self {
        let p = t * Point3::from(self.position_mm);
        let a = t.rotation * Vector3::from(self.approach);
        Self {
            position_mm: p.coords.into(),
            approach: a.into(),
            ..self.clone()
        }
    }
}

/// What the corridor check needs besides the detections.
pub(crate) struct GraspScene<'a> {
    /// The declared grasps (model frame).
    pub grasps: &'a [Grasp],
    /// The part's surface, model frame, mm.
    pub surface: &'a [Point],
    /// The scan's points the engine worked on, scene frame, mm.
    pub scene: &'a [Point],
    /// Scene points this close to a placed surface belong to that part, mm.
    pub surface_tolerance_mm: f64,
    /// A blocker needs at least this many points in a corridor.
    pub blocking_points: usize,
    /// The part's visible area, mm^2 (for the spacing of the surface samples).
    pub surface_area_mm2: f64,
}

/// One corridor in the scene frame.
struct Corridor {
    start: Point3<f64>,
    /// Unit, from the grasp position away from the part (against the approach).
    axis: Unit<Vector3<f64>>,
    length: f64,
    radius: f64,
}

impl Corridor {
    fn contains(&self, q: &Point3<f64>) -> bool {
        let d = q - self.start;
        let s = d.dot(&self.axis);
        if s <= 0.0 || s > self.length {
            return false;
        }
        d.norm_squared() - s * s <= self.radius * self.radius
    }
}

/// A blocker found in a corridor: the detection's index (None: unexplained scene points) and
/// its points there.
type Found = (Option<usize>, usize);

/// Checks every grasp of every detection (scene frame), then moves the detections not free
/// to pick (no free grasp, or covered per the engine) after the others (a stable partition
/// of the engine's order), renumbers the ranks, clears `free_to_pick` where every grasp is
/// blocked and appends the grasp verdict to each `rank_reason`. No grasps declared: nothing
/// changes.
pub(crate) fn check_and_order(detections: &mut Vec<Detection>, g: &GraspScene) -> Result<()> {
    if g.grasps.is_empty() || detections.is_empty() {
        return Ok(());
    }
    for (k, grasp) in g.grasps.iter().enumerate() {
        grasp.validate(k)?;
    }
    let step = g.surface.len().div_ceil(PLACED_SAMPLES).max(1);
    let samples: Vec<Point> = g.surface.iter().step_by(step).copied().collect();
    // The samples' typical spacing: a scene point between samples is still on the surface.
    let spacing = (2.0 * g.surface_area_mm2 / samples.len().max(1) as f64).sqrt();
    let tol = g.surface_tolerance_mm.max(spacing);
    let tol2 = (tol * tol) as f32;
    let placed: Vec<Vec<Point>> = detections
        .iter()
        .map(|d| {
            samples
                .iter()
                .map(|q| binpick_cloud::transform_point(&d.pose, q))
                .collect()
        })
        .collect();
    let indexes: Vec<Option<NearestIndex>> = placed
        .iter()
        .map(|p| NearestIndex::new("detection", p).ok())
        .collect();
    let near = |j: usize, q: &Point| {
        indexes[j]
            .as_ref()
            .is_some_and(|ix| ix.nearest(q).1 <= tol2)
    };
    let scene: Vec<Point3<f64>> = g.scene.iter().map(to_point3).collect();

    // Blockers by detection index (remapped to ranks below).
    let mut checks: Vec<Vec<(GraspCheck, Vec<Found>)>> = Vec::new();
    for (i, det) in detections.iter().enumerate() {
        let mut per = Vec::new();
        for (k, grasp) in g.grasps.iter().enumerate() {
            let position = det.pose * Point3::from(grasp.position_mm);
            let approach = det.pose.rotation * grasp.approach_unit();
            let corridor = Corridor {
                start: position,
                axis: -approach,
                length: grasp.clearance_length_mm,
                radius: grasp.clearance_radius_mm,
            };
            // counts[j] for detection j; the last slot for unexplained scene points.
            let mut counts = vec![0usize; detections.len() + 1];
            for (q, raw) in scene.iter().zip(g.scene) {
                if !corridor.contains(q) || near(i, raw) {
                    continue;
                }
                let owner = (0..detections.len()).find(|&j| j != i && near(j, raw));
                counts[owner.unwrap_or(detections.len())] += 1;
            }
            // Other parts' placed surfaces, seen or hidden.
            for (j, pts) in placed.iter().enumerate() {
                if j != i {
                    counts[j] += pts
                        .iter()
                        .filter(|p| corridor.contains(&to_point3(p)))
                        .count();
                }
            }
            let mut blockers: Vec<Found> = counts
                .iter()
                .enumerate()
                .filter(|&(_, &n)| n >= g.blocking_points)
                .map(|(j, &n)| ((j < detections.len()).then_some(j), n))
                .collect();
            blockers.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
            per.push((
                GraspCheck {
                    name: grasp.label(k),
                    position_mm: position.coords.into(),
                    approach: approach.into_inner().into(),
                    free: blockers.is_empty(),
                    blocked_by: Vec::new(),
                },
                blockers,
            ));
        }
        checks.push(per);
    }

    // Free first, the engine's order otherwise.
    let reachable: Vec<bool> = checks
        .iter()
        .map(|per| per.iter().any(|(c, _)| c.free))
        .collect();
    // A part the engine found covered stays unpickable, free grasp or not.
    let pickable: Vec<bool> = detections
        .iter()
        .zip(&reachable)
        .map(|(d, &r)| d.free_to_pick && r)
        .collect();
    let mut order: Vec<usize> = (0..detections.len()).collect();
    order.sort_by_key(|&i| !pickable[i]);
    let mut rank_of = vec![0usize; detections.len()];
    for (r, &i) in order.iter().enumerate() {
        rank_of[i] = r + 1;
    }
    let mut taken: Vec<Option<Detection>> =
        std::mem::take(detections).into_iter().map(Some).collect();
    for (r, &i) in order.iter().enumerate() {
        let Some(mut d) = taken[i].take() else {
            continue;
        };
        let engine_rank = d.rank;
        d.rank = r + 1;
        d.free_to_pick = pickable[i];
        d.grasps = checks[i]
            .iter()
            .map(|(c, blockers)| GraspCheck {
                blocked_by: blockers
                    .iter()
                    .map(|&(j, points)| match j {
                        Some(j) => Blocker::Detection {
                            rank: rank_of[j],
                            points,
                        },
                        None => Blocker::ScenePoints { points },
                    })
                    .collect(),
                ..c.clone()
            })
            .collect();
        let verdict = if reachable[i] {
            let free: Vec<&str> = d
                .grasps
                .iter()
                .filter(|c| c.free)
                .map(|c| c.name.as_str())
                .collect();
            format!("grasp free: {}", free.join(", "))
        } else {
            let blocked: Vec<String> = d
                .grasps
                .iter()
                .map(|c| {
                    let by: Vec<String> = c.blocked_by.iter().map(|b| b.to_string()).collect();
                    format!("{} by {}", c.name, by.join(" and "))
                })
                .collect();
            format!(
                "every grasp blocked ({}), after the parts with a free grasp (engine rank {engine_rank})",
                blocked.join("; ")
            )
        };
        d.rank_reason = format!("{verdict}; {}", d.rank_reason);
        detections.push(d);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::result::{FoundBy, IcpReport};
    use nalgebra::{Translation3, UnitQuaternion};

    /// A 40 x 20 mm plate in the model's xy plane, sampled every 1 mm, centred on the origin.
    fn plate() -> Vec<Point> {
        let mut pts = Vec::new();
        for i in -20..=20 {
            for j in -10..=10 {
                pts.push([i as f32, j as f32, 0.0]);
            }
        }
        pts
    }

    /// Grasped in the middle from above (+z of the model).
    fn top_grasp() -> Grasp {
        Grasp::new([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 6.0, 150.0).named("top")
    }

    fn det(hypothesis: usize, pose: Isometry3<f64>) -> Detection {
        Detection {
            rank: hypothesis + 1,
            pose,
            initial_pose: pose,
            initial_score: 0.5,
            final_score: 0.0,
            score_before_icp: 0.0,
            found_by: FoundBy::Voting {
                votes: 100,
                hypothesis,
            },
            view: None,
            icp: IcpReport {
                converged: true,
                iterations: 1,
                fitness_mm2: Some(0.1),
                adopted: true,
                unhidden: false,
                polished: false,
                error: None,
            },
            height_mm: pose.translation.z,
            rank_reason: "engine".into(),
            free_to_pick: true,
            grasps: Vec::new(),
        }
    }

    /// What a scanner above sees: the placed plates' points not hidden under a higher one.
    fn scan(poses: &[Isometry3<f64>]) -> Vec<Point> {
        let placed: Vec<Vec<Point>> = poses
            .iter()
            .map(|p| {
                plate()
                    .iter()
                    .map(|q| binpick_cloud::transform_point(p, q))
                    .collect()
            })
            .collect();
        let mut out = Vec::new();
        for (k, pts) in placed.iter().enumerate() {
            for q in pts {
                let hidden = placed.iter().enumerate().any(|(m, other)| {
                    m != k
                        && other.iter().any(|o| {
                            o[2] > q[2] + 1.0
                                && (o[0] - q[0]).abs() < 0.6
                                && (o[1] - q[1]).abs() < 0.6
                        })
                });
                if !hidden {
                    out.push(*q);
                }
            }
        }
        out
    }

    fn scene<'a>(grasps: &'a [Grasp], surface: &'a [Point], scene: &'a [Point]) -> GraspScene<'a> {
        GraspScene {
            grasps,
            surface,
            scene,
            surface_tolerance_mm: 1.0,
            blocking_points: 3,
            surface_area_mm2: 40.0 * 20.0,
        }
    }

    fn at(x: f64, y: f64, z: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
        )
    }

    #[test]
    fn a_part_lying_across_the_grasp_blocks_it_and_is_picked_first() {
        // Plate 0 on the floor; plate 1 lies across its middle, 5 mm higher, turned 90 deg.
        // The engine ranked the lower one first (say, it is better seen).
        let lower = at(0.0, 0.0, 0.0, 0.0);
        let upper = at(0.0, 0.0, 5.0, std::f64::consts::FRAC_PI_2);
        let points = scan(&[lower, upper]);
        let surface = plate();
        let grasps = [top_grasp()];
        let mut d = vec![det(0, lower), det(1, upper)];
        check_and_order(&mut d, &scene(&grasps, &surface, &points)).unwrap();
        assert_eq!(d[0].found_order().0, 1, "the part on top is the first pick");
        assert!(d[0].grasps[0].free, "{:?}", d[0].grasps);
        assert!(d[0].free_to_pick);
        let blocked = &d[1];
        assert_eq!(blocked.rank, 2);
        assert!(!blocked.grasps[0].free);
        assert!(
            !blocked.free_to_pick,
            "every grasp blocked: not free to pick"
        );
        assert!(
            matches!(
                blocked.grasps[0].blocked_by.as_slice(),
                [Blocker::Detection { rank: 1, points }] if *points >= 3
            ),
            "{:?}",
            blocked.grasps[0].blocked_by
        );
        assert!(
            blocked.rank_reason.contains("top by detection 1"),
            "{}",
            blocked.rank_reason
        );
    }

    #[test]
    fn a_free_grasp_is_chosen_over_a_better_part_whose_grasp_is_blocked() {
        // Part 0 (the engine's best) has clutter hanging over its middle; part 1 is free.
        let best = at(0.0, 0.0, 0.0, 0.0);
        let other = at(100.0, 0.0, 0.0, 0.3);
        let mut points = scan(&[best, other]);
        let clutter: Vec<Point> = (0..25)
            .map(|k| [(k % 5) as f32 - 2.0, (k / 5) as f32 - 2.0, 40.0])
            .collect();
        points.extend(&clutter);
        let surface = plate();
        // A second grasp at the plate's end, approached from the side (+x end, moving -x):
        // blocked by nothing but useful to show a part needs only one free grasp.
        let grasps = [top_grasp()];
        let mut d = vec![det(0, best), det(1, other)];
        check_and_order(&mut d, &scene(&grasps, &surface, &points)).unwrap();
        assert_eq!(d[0].found_order().0, 1, "the free part goes first");
        assert_eq!(
            d[1].grasps[0].blocked_by,
            vec![Blocker::ScenePoints { points: 25 }]
        );
        assert!(
            d[1].rank_reason.contains("25 scene points"),
            "{}",
            d[1].rank_reason
        );

        // Without the clutter the engine's order stands and both are free.
        let points = scan(&[best, other]);
        let mut d = vec![det(0, best), det(1, other)];
        check_and_order(&mut d, &scene(&grasps, &surface, &points)).unwrap();
        assert_eq!(d[0].found_order().0, 0);
        assert!(d.iter().all(|x| x.grasps[0].free));
        // The grasp comes out where the pose puts it.
        assert!(
            (Vector3::from(d[1].grasps[0].position_mm) - Vector3::new(100.0, 0.0, 0.0)).norm()
                < 1e-9
        );
        // A part the engine found covered stays unpickable with a free grasp, after the
        // free part.
        let mut d = vec![det(0, best), det(1, other)];
        d[0].free_to_pick = false;
        check_and_order(&mut d, &scene(&grasps, &surface, &points)).unwrap();
        assert_eq!(d[0].found_order().0, 1);
        assert!(d[0].free_to_pick && !d[1].free_to_pick && d[1].grasps[0].free);
    }

    #[test]
    fn one_free_grasp_is_enough_and_own_surface_never_blocks() {
        // A side grasp at the plate's +x end approached along -x, and the top grasp under
        // clutter: the part stays reachable through the side grasp.
        let pose = at(0.0, 0.0, 0.0, 0.0);
        let mut points = scan(&[pose]);
        points.extend((0..25).map(|k| [(k % 5) as f32 - 2.0, (k / 5) as f32 - 2.0, 40.0]));
        let surface = plate();
        let side = Grasp::new([20.0, 0.0, 0.0], [-1.0, 0.0, 0.0], 3.0, 80.0).named("side");
        let grasps = [top_grasp(), side];
        let mut d = vec![det(0, pose)];
        check_and_order(&mut d, &scene(&grasps, &surface, &points)).unwrap();
        assert!(
            !d[0].grasps[0].free && d[0].grasps[1].free,
            "{:?}",
            d[0].grasps
        );
        assert!(
            d[0].rank_reason.starts_with("grasp free: side"),
            "{}",
            d[0].rank_reason
        );
    }

    #[test]
    fn bad_declarations_are_refused() {
        let surface = plate();
        let points = scan(&[at(0.0, 0.0, 0.0, 0.0)]);
        for bad in [
            Grasp::new([0.0; 3], [0.0; 3], 5.0, 10.0),
            Grasp::new([0.0; 3], [0.0, 0.0, 1.0], 0.0, 10.0),
            Grasp::new([f64::NAN, 0.0, 0.0], [0.0, 0.0, 1.0], 5.0, 10.0),
        ] {
            let grasps = [bad];
            let mut d = vec![det(0, at(0.0, 0.0, 0.0, 0.0))];
            let e = check_and_order(&mut d, &scene(&grasps, &surface, &points)).unwrap_err();
            assert!(e.to_string().contains("grasp 1"), "{e}");
        }
    }
}
