//! The sensor's view: the scene as a range grid seen from the sensor, and a model rendered
//! into the same grid at a hypothesis pose. A hypothesis is judged only on the model surface
//! the sensor could see in that pose (a model point facing away, or hidden behind the model's
//! own surface, says nothing), cell by cell against what the sensor saw:
//!
//! | scene along the cell's ray              | verdict      | meaning                                   |
//! |-----------------------------------------|--------------|-------------------------------------------|
//! | a surface within tolerance of the model | explained    | support for the hypothesis                |
//! | a surface in front of the model         | occluded     | hidden by something else: no evidence     |
//! | a surface behind the model              | free space   | the sensor saw through where the model    |
//! |                                         |              | puts material: a contradiction            |
//! | nothing measured                        | missing      | the model surface the sensor should have  |
//! |                                         |              | seen is not there (shadow or absent)      |
//!
//! This is the visible-surface discrepancy of Hodan et al. (2016, BOP's VSD) turned into a
//! verification score, and the free-space / occlusion reasoning of Aldoma et al. 2012
//! ("A global hypotheses verification method for 3D object recognition").

use nalgebra::{Isometry3, Point3, Vector3};

use crate::{MatchError, OrientedPoints, P3};

/// Empty cells beyond a rendered cell that make its side part of the model's outline.
const OUTLINE_GAP: i64 = 3;
/// Margin of the back-face skip in `RangeGrid::render`: far above the rounding by which a
/// normal's cosine to the sensor measured in the model's frame can differ from the one
/// measured in the scene's (under 1e-12 at any working distance), far below any incidence
/// limit.
const CULL_MARGIN: f64 = 1e-9;

/// The sensor seen from the model's frame (`RangeGrid::render`).
enum SensorInModel {
    /// Orthographic: the unit direction towards the sensor.
    Direction(Vector3<f64>),
    /// Perspective: the sensor's position.
    Position(Point3<f64>),
}

impl SensorInModel {
    /// `sensor` seen from the frame of a model placed at `pose`.
    fn new(sensor: &Sensor, pose: &Isometry3<f64>) -> Self {
        let inverse = pose.inverse();
        match sensor {
            Sensor::Orthographic { up } => SensorInModel::Direction(inverse.rotation * up),
            Sensor::Perspective { position, .. } => SensorInModel::Position(inverse * position),
        }
    }

    /// Whether the cosine between normal `n` at `p` and the direction to the sensor is below
    /// `limit` (false for a point at the sensor or non-finite input).
    fn faces_away(&self, p: &P3, n: &P3, limit: f64) -> bool {
        let n = Vector3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2]));
        match self {
            SensorInModel::Direction(d) => n.dot(d) < limit,
            SensorInModel::Position(c) => {
                let d = c - to_point(p);
                let length = d.norm();
                length > 0.0 && n.dot(&d) < limit * length
            }
        }
    }
}

/// Fit weight of a model cell explained only by a neighbouring cell's surface, off the
/// outline: a cell of lateral slack, allowed but not worth a match in place.
pub const NEIGHBOUR_FIT_WEIGHT: f64 = 0.25;

/// A free-space cell within this many cells (either way along both grid axes) of a cell a
/// part hides is a crossing ([`ViewScore::crossing`]): where a pose's surface passes from
/// in front of a part's surface to behind it, the view's tolerance leaves a band a cell or
/// two wide between the cells seen through and the hidden ones.
const CROSSING_CELLS: i64 = 2;

/// Where the sensor is. "Closeness" below is a coordinate that grows towards the sensor, mm.
#[derive(Clone, Debug, PartialEq)]
pub enum Sensor {
    /// Looking down `-up` from far away: line scanners over a belt or a bin, where rays are
    /// (close to) parallel.
    Orthographic {
        /// Unit vector towards the sensor.
        up: Vector3<f64>,
    },
    /// A camera at `position` looking along `axis` (depth and structured-light cameras).
    Perspective {
        position: Point3<f64>,
        /// Unit optical axis (from the camera into the scene).
        axis: Vector3<f64>,
    },
}

impl Sensor {
    /// An orthographic sensor above `up` (normalised; must be non-zero).
    pub fn orthographic(up: [f64; 3]) -> Result<Self, MatchError> {
        let v = Vector3::from(up);
        if !(v.norm().is_finite() && v.norm() > 1e-9) {
            return Err(MatchError::config(
                "up",
                "expected a finite, non-zero vector",
            ));
        }
        Ok(Self::Orthographic { up: v.normalize() })
    }

    /// A camera at `position` whose axis points at `target`.
    pub fn perspective(position: [f64; 3], target: [f64; 3]) -> Result<Self, MatchError> {
        let o = Point3::from(position);
        let axis = Point3::from(target) - o;
        if !(axis.norm().is_finite() && axis.norm() > 1e-9) {
            return Err(MatchError::config(
                "viewpoint",
                "the camera must not sit on the scene's centre",
            ));
        }
        Ok(Self::Perspective {
            position: o,
            axis: axis.normalize(),
        })
    }

    /// Unit vector from `p` towards the sensor.
    pub fn towards(&self, p: &Point3<f64>) -> Vector3<f64> {
        match self {
            Sensor::Orthographic { up } => *up,
            Sensor::Perspective { position, .. } => (position - p).normalize(),
        }
    }

    fn basis(&self) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let a = match self {
            Sensor::Orthographic { up } => *up,
            Sensor::Perspective { axis, .. } => *axis,
        };
        let helper = if a.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = a.cross(&helper).normalize();
        let e2 = a.cross(&e1);
        (e1, e2, a)
    }
}

/// Projects points into grid coordinates.
#[derive(Clone, Debug)]
struct Projector {
    sensor: Sensor,
    e1: Vector3<f64>,
    e2: Vector3<f64>,
    a: Vector3<f64>,
    /// Cell size: mm (orthographic) or tangent units (perspective).
    cell: f64,
}

impl Projector {
    /// `(column, row)` as continuous cell coordinates and closeness, mm; None behind a camera.
    fn project(&self, p: &Point3<f64>) -> Option<(f64, f64, f64)> {
        match &self.sensor {
            Sensor::Orthographic { .. } => {
                let v = p.coords;
                Some((
                    v.dot(&self.e1) / self.cell,
                    v.dot(&self.e2) / self.cell,
                    v.dot(&self.a),
                ))
            }
            Sensor::Perspective { position, .. } => {
                let q = p - position;
                let z = q.dot(&self.a);
                if z <= 1e-6 {
                    return None;
                }
                Some((
                    q.dot(&self.e1) / z / self.cell,
                    q.dot(&self.e2) / z / self.cell,
                    -z,
                ))
            }
        }
    }

    /// Cell edge length in mm at a given closeness.
    fn cell_mm(&self, closeness: f64) -> f64 {
        match self.sensor {
            Sensor::Orthographic { .. } => self.cell,
            Sensor::Perspective { .. } => self.cell * (-closeness).max(1e-6),
        }
    }
}

/// The scene as the sensor saw it: per grid cell the closeness of the nearest surface.
#[derive(Clone, Debug)]
pub struct RangeGrid {
    projector: Projector,
    /// Grid origin in cell coordinates.
    col0: i64,
    row0: i64,
    cols: usize,
    rows: usize,
    /// Closeness per cell, mm; NaN where nothing was measured.
    near: Vec<f32>,
    /// Whether the nearest surface in the cell is background (belt, bin floor or wall).
    background: Vec<bool>,
    /// Unit normal of the nearest surface in the cell (NaN when unknown).
    normal: Vec<[f32; 3]>,
    /// The nearest point in the cell.
    point: Vec<P3>,
    /// Whether the cell was empty and took its neighbours' surface (`fill_sampling_holes`).
    filled: Vec<bool>,
    max_normal_cos: f64,
    /// Depth tolerance, mm.
    tolerance_mm: f64,
}

/// How a hypothesis is compared with the range grid.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewConfig {
    /// Grid cell, mm (at the scene's typical distance for a camera): about the scan's point
    /// spacing. Range > 0.
    pub cell_mm: f64,
    /// A model surface within this distance along the ray of the scene's is explained, mm:
    /// noise plus residual misalignment. Range > 0.
    pub tolerance_mm: f64,
    /// Model surface steeper than this angle to the ray is not rendered (the grid cannot
    /// resolve it), degrees. Default 75, range 10-89.
    pub max_incidence_deg: f64,
    /// A scene surface explains the model only where their normals differ by less than this,
    /// degrees (where the scene has a normal). Default 45, range 1-180 (180 = off).
    pub max_normal_angle_deg: f64,
    /// Points within this distance of a support plane were labelled support, mm (range >= 0):
    /// a background point explains a model surface as support ([`ViewScore::explained_by_support`])
    /// only where that surface lies farther from it than this. Nearer, the part's own surface
    /// would have been labelled support too (the flanks of a rod lying on the floor).
    pub support_band_mm: f64,
    /// A model cell on the outline explained only by a neighbouring cell's surface counts
    /// at this fit weight (elsewhere a quarter, [`NEIGHBOUR_FIT_WEIGHT`]): the sampled outline
    /// lies up to a cell inside the part's edge, so there the scan's surface falls in the
    /// cell or beside it about as often. Range 0-1.
    pub outline_neighbour_weight: f64,
}

impl ViewConfig {
    /// Rejects values outside the documented ranges, naming the field.
    pub fn validate(&self) -> Result<(), MatchError> {
        if !(self.cell_mm.is_finite() && self.cell_mm > 0.0) {
            return Err(MatchError::config("cell_mm", "expected > 0 mm"));
        }
        if !(self.tolerance_mm.is_finite() && self.tolerance_mm > 0.0) {
            return Err(MatchError::config("tolerance_mm", "expected > 0 mm"));
        }
        if !(10.0..=89.0).contains(&self.max_incidence_deg) {
            return Err(MatchError::config(
                "max_incidence_deg",
                "expected 10-89 deg",
            ));
        }
        if !(self.support_band_mm.is_finite() && self.support_band_mm >= 0.0) {
            return Err(MatchError::config("support_band_mm", "expected >= 0 mm"));
        }
        if !(0.0..=1.0).contains(&self.outline_neighbour_weight) {
            return Err(MatchError::config(
                "outline_neighbour_weight",
                "expected 0-1",
            ));
        }
        if !(1.0..=180.0).contains(&self.max_normal_angle_deg) {
            return Err(MatchError::config(
                "max_normal_angle_deg",
                "expected 1-180 deg",
            ));
        }
        Ok(())
    }
}

/// A hypothesis judged against the view, in grid cells.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ViewScore {
    /// Cells the model covers as the sensor would see it alone in this pose, within the
    /// scan's footprint (the grid over everything the sensor measured).
    pub visible: u32,
    /// Cells it would cover beyond the footprint: a part crossing the edge of the scanned
    /// area. Counted in no other field: where the sensor measured nothing, a surface
    /// neither confirms nor contradicts the pose.
    pub outside: u32,
    /// Cells where the scene surface agrees with the model.
    pub explained: u32,
    /// Cells where the scene surface lies in front of the model (hidden by something).
    pub occluded: u32,
    /// Cells where the sensor saw a surface behind the model: contradictions.
    pub free_space: u32,
    /// Cells with no measurement at all.
    pub missing: u32,
    /// Cells where a scene surface lies at the model's depth but faces another way (counted
    /// in neither `explained` nor `free_space`).
    pub wrong_normal: u32,
    /// Sum over explained cells of the fit weight `1 - (depth error / tolerance)^2` (a cell
    /// explained only by a neighbour counts a quarter): how well, not only how much, the
    /// scene confirms the model.
    pub fit: f64,
    /// The same sum with a neighbour's explanation on the outline at
    /// [`ViewConfig::outline_neighbour_weight`]: what acceptance (`min_fit`) reads. The
    /// competition and the pick order read `fit`, which prefers the pose that meets the
    /// scan in place.
    pub acceptance_fit: f64,
    /// Edges of the model's silhouette (cell sides between a rendered cell and an empty
    /// one) where the scene does not hide the model, and those where the scene's surface
    /// carries on past the edge at the model's depth with the model's orientation (and is
    /// not belt or bin): a real part's outline coincides with the scene's depth edges, a
    /// pose laid across other surfaces does not. Hidden edges cannot show either, so they
    /// do not count: a plate laid inside a larger sheet with its bent leg tucked under it
    /// would otherwise dilute its continued outline with the leg's.
    pub outline_edges: u32,
    pub outline_continued: u32,
    /// For each continued edge, the grid cell the scene carries on in: a
    /// neighbouring part's surface continues a part's outline too, so the scene explanation
    /// counts only continuations no taken part explains.
    pub continued_cells: Vec<u32>,
    /// The explained cells (grid indices, ascending) and their fit weights, for the scene
    /// explanation.
    pub explained_cells: Vec<u32>,
    pub explained_fit: Vec<f32>,
    /// The occluded cells whose occluder is not background (a part lies on this one), off
    /// the outline: on its edge cells a neighbour that only touches the part, or a pose a
    /// cell off, puts nearer surface in front as well.
    pub covered: u32,
    /// Model points (of a fixed sample over the whole surface) that lie behind a support
    /// plane (belt, floor, bin wall) beyond the tolerance, and the points checked: a part
    /// cannot sink into what carries it. Filled by the caller, which knows the planes.
    pub below_support: u32,
    pub support_checked: u32,
    /// How deep the part's deepest point lies behind a support plane, mm (0 when none
    /// does): a resting part touches its support, so only pose error sinks it. Filled by
    /// the caller.
    pub sunk_mm: f64,
    /// Explained cells whose best-fitting scene surface is background (belt, floor, wall)
    /// lying farther from the model than the support band: a part laid on the support
    /// rather than seen.
    pub explained_by_support: u32,
    /// Free-space cells within [`CROSSING_CELLS`] of a cell a part hides (its nearer surface
    /// is not background): the pose passes through a part the sensor saw, in front of that
    /// surface on one side (seen through) and behind it on the other. A part lying under
    /// another is hidden where the other lies on it but is not seen through beside it.
    pub crossing: u32,
}

impl ViewScore {
    /// How much the scene supports this pose: the fit weights of the explained cells less
    /// `free_space_weight` per contradicted cell (the scene explanation's gain when nothing
    /// is claimed yet).
    pub fn support(&self, free_space_weight: f64) -> f64 {
        self.fit - free_space_weight * f64::from(self.free_space)
    }

    /// Cells the pose shows the sensor in and beyond the scan: how broad a side it turns to
    /// the sensor, whatever the scan's edge cuts off (a part on the edge of its sheet shows
    /// few, a part half beyond the scan's end does not).
    pub fn view_cells(&self) -> u32 {
        self.visible + self.outside
    }

    /// Share of the visible surface the scene confirms: an estimate of the part's visible
    /// fraction (BOP's visib_fract) when the pose is right.
    pub fn visibility(&self) -> f64 {
        ratio(self.explained, self.visible)
    }

    /// Share of the visible surface contradicted by free space.
    pub fn free_space_ratio(&self) -> f64 {
        ratio(self.free_space, self.visible)
    }

    /// Free-space contradictions per explained cell: what the sensor saw through against
    /// what it confirms.
    pub fn free_space_per_explained(&self) -> f64 {
        ratio(self.free_space, self.explained)
    }

    /// Crossing cells ([`ViewScore::crossing`]) per explained cell.
    pub fn crossing_per_explained(&self) -> f64 {
        ratio(self.crossing, self.explained)
    }

    /// Share of the explained cells explained by background.
    pub fn support_explained_ratio(&self) -> f64 {
        ratio(self.explained_by_support, self.explained)
    }

    /// Share of the checked model points that lie behind a support plane.
    pub fn below_support_ratio(&self) -> f64 {
        ratio(self.below_support, self.support_checked)
    }

    /// Share of the visible surface covered by something other than background.
    pub fn covered_ratio(&self) -> f64 {
        ratio(self.covered, self.visible)
    }

    /// Mean fit weight of the explained cells (0 when none).
    pub fn mean_fit(&self) -> f64 {
        if self.explained == 0 {
            0.0
        } else {
            self.fit / f64::from(self.explained)
        }
    }

    /// Mean of [`Self::acceptance_fit`] over the explained cells.
    pub fn mean_acceptance_fit(&self) -> f64 {
        if self.explained == 0 {
            0.0
        } else {
            self.acceptance_fit / f64::from(self.explained)
        }
    }

    /// Share of the outline where the scene's surface carries on past it.
    pub fn continued_ratio(&self) -> f64 {
        ratio(self.outline_continued, self.outline_edges)
    }
}

fn ratio(a: u32, b: u32) -> f64 {
    if b == 0 {
        0.0
    } else {
        f64::from(a) / f64::from(b)
    }
}

/// Fills the one-cell holes a scan sparser than the grid leaves inside a surface: an empty
/// cell between two measured cells on opposite sides (left and right, above and below, or
/// diagonally) whose depths agree within `tolerance` takes their midpoint. Only the original
/// measurements are read, so the result does not depend on the order; depth edges (the two
/// sides disagree) and the scan's borders stay empty. Returns which cells were filled.
fn fill_sampling_holes(
    cols: usize,
    near: &mut [f32],
    background: &mut [bool],
    normal: &mut [P3],
    point: &mut [P3],
    tolerance: f32,
) -> Vec<bool> {
    let rows = near.len() / cols;
    let measured = near.to_vec();
    let mut filled = vec![false; near.len()];
    let opposite: [(i64, i64); 4] = [(1, 0), (0, 1), (1, 1), (1, -1)];
    for r in 0..rows as i64 {
        for c in 0..cols as i64 {
            let k = r as usize * cols + c as usize;
            if !measured[k].is_nan() {
                continue;
            }
            let at = |dc: i64, dr: i64| -> Option<usize> {
                let (cc, rr) = (c + dc, r + dr);
                (cc >= 0 && rr >= 0 && (cc as usize) < cols && (rr as usize) < rows)
                    .then(|| rr as usize * cols + cc as usize)
                    .filter(|&j| !measured[j].is_nan())
            };
            let mut best: Option<(f32, usize, usize)> = None;
            for (dc, dr) in opposite {
                let (Some(a), Some(b)) = (at(dc, dr), at(-dc, -dr)) else {
                    continue;
                };
                let gap = (measured[a] - measured[b]).abs();
                if gap <= tolerance && best.is_none_or(|(g, _, _)| gap < g) {
                    best = Some((gap, a, b));
                }
            }
            let Some((_, a, b)) = best else { continue };
            filled[k] = true;
            near[k] = 0.5 * (measured[a] + measured[b]);
            background[k] = background[a] && background[b];
            point[k] = std::array::from_fn(|i| 0.5 * (point[a][i] + point[b][i]));
            // The mean direction; the known one where the other is unknown (NaN).
            let n: P3 = std::array::from_fn(|i| normal[a][i] + normal[b][i]);
            let len = n.iter().map(|x| x * x).sum::<f32>().sqrt();
            normal[k] = if len > 1e-6 {
                n.map(|x| x / len)
            } else if normal[a][0].is_nan() {
                normal[b]
            } else {
                normal[a]
            };
        }
    }
    filled
}

impl RangeGrid {
    /// Projects the scene (`background[i]` marks belt/floor/wall points; `normals[i]`, when
    /// given, is point i's unit normal, NaN where undefined) into a grid.
    pub fn new(
        sensor: Sensor,
        config: &ViewConfig,
        points: &[P3],
        background: &[bool],
        normals: Option<&[P3]>,
    ) -> Result<Self, MatchError> {
        config.validate()?;
        let n_normals = normals.map_or(points.len(), <[P3]>::len);
        if points.len() != background.len() || points.len() != n_normals {
            return Err(MatchError::Mismatch {
                what: "range grid",
                points: points.len(),
                normals: background.len().min(n_normals),
            });
        }
        if points.is_empty() {
            return Err(MatchError::TooFewPoints {
                what: "scene",
                points: 0,
                needed: 1,
            });
        }
        let (e1, e2, a) = sensor.basis();
        // A camera's cell is an angle: the configured size at the scene's median distance.
        let cell = match &sensor {
            Sensor::Orthographic { .. } => config.cell_mm,
            Sensor::Perspective { position, .. } => {
                let mut z: Vec<f64> = points
                    .iter()
                    .step_by((points.len() / 1000).max(1))
                    .map(|p| (to_point(p) - position).dot(&a))
                    .filter(|z| *z > 0.0)
                    .collect();
                if z.is_empty() {
                    return Err(MatchError::config(
                        "viewpoint",
                        "the whole scene lies behind the camera",
                    ));
                }
                z.sort_by(f64::total_cmp);
                config.cell_mm / z[z.len() / 2]
            }
        };
        let projector = Projector {
            sensor,
            e1,
            e2,
            a,
            cell,
        };
        let projected: Vec<Option<(i64, i64, f64)>> = points
            .iter()
            .map(|p| {
                projector
                    .project(&to_point(p))
                    .map(|(u, v, c)| (u.floor() as i64, v.floor() as i64, c))
            })
            .collect();
        let mut bounds: Option<[i64; 4]> = None;
        for (c, r, _) in projected.iter().flatten() {
            let b = bounds.get_or_insert([*c, *c, *r, *r]);
            b[0] = b[0].min(*c);
            b[1] = b[1].max(*c);
            b[2] = b[2].min(*r);
            b[3] = b[3].max(*r);
        }
        let Some([c0, c1, r0, r1]) = bounds else {
            return Err(MatchError::config(
                "viewpoint",
                "the whole scene lies behind the camera",
            ));
        };
        let (cols, rows) = ((c1 - c0 + 1) as usize, (r1 - r0 + 1) as usize);
        if cols.saturating_mul(rows) > 100_000_000 {
            return Err(MatchError::config(
                "cell_mm",
                "too small for the scene's extent: more than 100 million grid cells",
            ));
        }
        let mut near = vec![f32::NAN; cols * rows];
        let mut bg = vec![false; cols * rows];
        let mut normal = vec![[f32::NAN; 3]; cols * rows];
        let mut point = vec![[f32::NAN; 3]; cols * rows];
        for (i, proj) in projected.iter().enumerate() {
            let Some((c, r, closeness)) = proj else {
                continue;
            };
            let k = (r - r0) as usize * cols + (c - c0) as usize;
            let v = *closeness as f32;
            if near[k].is_nan() || v > near[k] {
                near[k] = v;
                bg[k] = background[i];
                point[k] = points[i];
                normal[k] = normals.map_or([f32::NAN; 3], |n| n[i]);
            }
        }
        let filled = fill_sampling_holes(
            cols,
            &mut near,
            &mut bg,
            &mut normal,
            &mut point,
            config.tolerance_mm as f32,
        );
        Ok(Self {
            projector,
            col0: c0,
            row0: r0,
            cols,
            rows,
            near,
            background: bg,
            normal,
            point,
            filled,
            max_normal_cos: config.max_normal_angle_deg.to_radians().cos(),
            tolerance_mm: config.tolerance_mm,
        })
    }

    /// Cells in the grid.
    pub fn cells(&self) -> usize {
        self.near.len()
    }

    /// Per cell: its nearest scene surface is background and `keep` holds for that point.
    pub fn background_cells(&self, keep: impl Fn(&P3) -> bool) -> Vec<bool> {
        self.background
            .iter()
            .zip(&self.point)
            .map(|(&b, p)| b && keep(p))
            .collect()
    }

    /// The sensor this grid was built for.
    pub fn sensor(&self) -> &Sensor {
        &self.projector.sensor
    }

    fn cell_index(&self, c: i64, r: i64) -> Option<usize> {
        let (dc, dr) = (c - self.col0, r - self.row0);
        (dc >= 0 && dr >= 0 && (dc as usize) < self.cols && (dr as usize) < self.rows)
            .then(|| dr as usize * self.cols + dc as usize)
    }

    /// Renders `model` (dense points with outward normals, model frame) at `pose` as the
    /// sensor would see it alone: per cell the nearest model surface facing the sensor, in
    /// cell order. With `facing`, every model point facing the sensor at all (steeper ones
    /// too) is listed there, projected, from the same pass.
    fn render(
        &self,
        model: &OrientedPoints,
        pose: &Isometry3<f64>,
        max_incidence_cos: f64,
        mut facing: Option<&mut Vec<FacingPoint>>,
    ) -> Rendering {
        let mut cells: Vec<RenderedCell> = Vec::with_capacity(model.len());
        let mut outside: Vec<(i64, i64)> = Vec::new();
        // A point whose normal faces away from the sensor by a clear margin, measured in the
        // model's frame, is skipped before it is moved (moving a point and its normal is most
        // of the cost, and about half of a part's surface faces away). The exact test below
        // still decides every other point, so the same points are rendered and listed.
        let skip_below = if facing.is_some() {
            max_incidence_cos.min(0.0)
        } else {
            max_incidence_cos
        } - CULL_MARGIN;
        let sensor_in_model = SensorInModel::new(&self.projector.sensor, pose);
        for (i, (p, n)) in model.points.iter().zip(&model.normals).enumerate() {
            if sensor_in_model.faces_away(p, n, skip_below) {
                continue;
            }
            let q = pose * to_point(p);
            let normal =
                pose.rotation * Vector3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2]));
            let cos = normal.dot(&self.projector.sensor.towards(&q));
            let listed = facing.is_some() && cos >= 0.0;
            if cos < max_incidence_cos && !listed {
                continue;
            }
            let Some((u, v, closeness)) = self.projector.project(&q) else {
                continue;
            };
            let (col, row) = (u.floor() as i64, v.floor() as i64);
            // Beyond the scan's footprint the sensor measured nothing, so it says nothing
            // there: neither missing surface nor points to align.
            if self.cell_index(col, row).is_none() {
                if cos >= max_incidence_cos {
                    outside.push((col, row));
                }
                continue;
            }
            if let (true, Some(f)) = (listed, facing.as_deref_mut()) {
                f.push(FacingPoint {
                    index: i as u32,
                    col,
                    row,
                    closeness,
                });
            }
            if cos < max_incidence_cos {
                continue;
            }
            // Within one cell a slanted surface spans this much depth.
            let slope = (1.0 - cos * cos).max(0.0).sqrt() / cos;
            cells.push(RenderedCell {
                col,
                row,
                closeness,
                slack: slope * self.projector.cell_mm(closeness),
                position: q,
                normal,
            });
        }
        outside.sort_unstable();
        outside.dedup();
        Rendering {
            outside: outside.len() as u32,
            ..Rendering::nearest_per_cell(&cells)
        }
    }

    /// Whether the scene's normal in cell `k` agrees with `normal` (true where unknown).
    fn normal_agrees(&self, k: usize, normal: &Vector3<f64>) -> bool {
        let n = self.normal[k];
        if !n.iter().all(|c| c.is_finite()) {
            return true;
        }
        let n = Vector3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2]));
        n.dot(normal) >= self.max_normal_cos
    }

    /// Scores `model` (dense points with outward normals, model frame) at `pose`.
    pub fn score(
        &self,
        model: &OrientedPoints,
        pose: &Isometry3<f64>,
        config: &ViewConfig,
    ) -> ViewScore {
        let cos_limit = config.max_incidence_deg.to_radians().cos();
        let rendered = self.render(model, pose, cos_limit, None);
        let mut s = ViewScore {
            visible: rendered.cells.len() as u32,
            outside: rendered.outside,
            ..ViewScore::default()
        };
        let tol = self.tolerance_mm;
        // Cells hidden (for the outline) and seen through (for the crossings).
        let mut state = vec![CellState::Other; rendered.cells.len()];
        for (ci, cell) in rendered.cells.iter().enumerate() {
            let (c, r, m) = (cell.col, cell.row, cell.closeness);
            let t = tol + cell.slack;
            // Best fit among the neighbouring cells (one cell of lateral slack).
            let mut best_fit: Option<f64> = None;
            let mut best_on_background = false;
            let (mut wrong_normal, mut front, mut behind, mut any) = (false, false, false, false);
            let mut front_is_object = false;
            let mut on_outline: Option<bool> = None;
            let mut best_acceptance_fit = 0.0f64;
            for dr in -1..=1 {
                for dc in -1..=1 {
                    let Some(k) = self.cell_index(c + dc, r + dr) else {
                        continue;
                    };
                    let v = f64::from(self.near[k]);
                    if v.is_nan() {
                        continue;
                    }
                    any = true;
                    let dz = v - m;
                    // The scene point's distance from the model's tangent plane: zero for
                    // the same surface however slanted it is.
                    let off_plane = (to_point(&self.point[k]) - cell.position)
                        .dot(&cell.normal)
                        .abs();
                    if dz.abs() <= t + cell.slack && off_plane <= tol {
                        if self.normal_agrees(k, &cell.normal) {
                            let closeness = 1.0 - (off_plane / tol).powi(2);
                            let in_place = dr == 0 && dc == 0;
                            let weight = if in_place { 1.0 } else { NEIGHBOUR_FIT_WEIGHT };
                            let acceptance_weight = if in_place {
                                1.0
                            } else if *on_outline.get_or_insert_with(|| rendered.on_outline(c, r)) {
                                config.outline_neighbour_weight
                            } else {
                                NEIGHBOUR_FIT_WEIGHT
                            };
                            best_acceptance_fit =
                                best_acceptance_fit.max(acceptance_weight * closeness);
                            let fit = weight * closeness;
                            if best_fit.is_none_or(|b| fit > b) {
                                best_fit = Some(fit);
                                best_on_background =
                                    self.background[k] && dz.abs() > config.support_band_mm;
                            }
                        } else {
                            wrong_normal = true;
                        }
                    } else if dz > t {
                        front = true;
                        if dr == 0 && dc == 0 {
                            front_is_object = !self.background[k];
                        }
                    } else if dz < -t {
                        behind = true;
                    }
                }
            }
            if let Some(fit) = best_fit {
                s.explained += 1;
                s.explained_by_support += u32::from(best_on_background);
                s.fit += fit;
                s.acceptance_fit += best_acceptance_fit;
                if let Some(k) = self.cell_index(c, r) {
                    s.explained_cells.push(k as u32);
                    s.explained_fit.push(fit as f32);
                }
            } else if wrong_normal {
                s.wrong_normal += 1;
            } else if front {
                s.occluded += 1;
                state[ci] = if front_is_object {
                    CellState::HiddenByPart
                } else {
                    CellState::HiddenByOther
                };
                let on_outline = on_outline.unwrap_or_else(|| rendered.on_outline(c, r));
                s.covered += u32::from(front_is_object && !on_outline);
            } else if behind {
                s.free_space += 1;
                state[ci] = CellState::SeenThrough;
            } else if !any {
                s.missing += 1;
            }
        }
        self.outline(&rendered, &state, &mut s);
        if s.free_space > 0 && s.occluded > 0 {
            s.crossing = rendered.crossings(&state);
        }
        s
    }

    /// Counts the silhouette's edges of the cells the scene does not hide (`state[i]` of
    /// `rendered.cells[i]`) and those the scene's surface carries on past (two cells out, at
    /// the edge cell's depth within the tolerance, same orientation, not background).
    fn outline(&self, rendered: &Rendering, state: &[CellState], s: &mut ViewScore) {
        let tol = self.tolerance_mm;
        let shown = rendered
            .cells
            .iter()
            .zip(state)
            .filter(|(_, st)| !st.hidden());
        for (cell, _) in shown {
            for (dc, dr) in SIDES {
                if !rendered.is_edge(cell.col, cell.row, dc, dr) {
                    continue;
                }
                let t = tol + cell.slack;
                // Checked beyond the gap: the sampled outline lies up to a cell inside the
                // part's true edge, and ICP leaves a cell of slack. Only measured cells
                // count: a part standing on a surface meets it at its own depth, and filling
                // the scan's holes there would make its outline look continued.
                let beyond = [OUTLINE_GAP + 1, OUTLINE_GAP + 2]
                    .map(|k| self.cell_index(cell.col + k * dc, cell.row + k * dr));
                // Beside the scan's edge the outline cannot show.
                if beyond.iter().any(Option::is_none) {
                    continue;
                }
                s.outline_edges += 1;
                let carries = beyond.iter().all(|i| {
                    i.is_some_and(|i| {
                        !self.background[i]
                            && !self.filled[i]
                            && (f64::from(self.near[i]) - cell.closeness).abs() <= t
                            && self.normal_agrees(i, &cell.normal)
                    })
                });
                if let (true, Some(i)) = (carries, beyond[0]) {
                    s.outline_continued += 1;
                    s.continued_cells.push(i as u32);
                }
            }
        }
    }

    /// Indices of the model points the sensor would see at `pose` (facing it and not behind
    /// the model's own nearer surface by more than the tolerance): the points to align.
    pub fn visible_model_points(
        &self,
        model: &OrientedPoints,
        pose: &Isometry3<f64>,
        config: &ViewConfig,
    ) -> Vec<u32> {
        self.model_points_in_view(model, pose, config, None, false)
    }

    /// [`Self::visible_model_points`] less those the scene hides: where the scene's surface
    /// in the point's cell lies more than `margin_mm` nearer the sensor (a neighbour over
    /// it). ICP would pair such points with the neighbour or with the part's own surface
    /// beside it, and both pull the pose off the part.
    pub fn unhidden_model_points(
        &self,
        model: &OrientedPoints,
        pose: &Isometry3<f64>,
        config: &ViewConfig,
        margin_mm: f64,
    ) -> Vec<u32> {
        self.model_points_in_view(model, pose, config, Some(margin_mm), false)
    }

    /// [`Self::unhidden_model_points`] less those the sensor measured nothing around (in
    /// their cell and the eight beside it: a shadow), where the scan says nothing about the
    /// model's surface. A cell of slack keeps a part's edge laid past the scan's.
    pub fn measured_model_points(
        &self,
        model: &OrientedPoints,
        pose: &Isometry3<f64>,
        config: &ViewConfig,
        margin_mm: f64,
    ) -> Vec<u32> {
        self.model_points_in_view(model, pose, config, Some(margin_mm), true)
    }

    fn model_points_in_view(
        &self,
        model: &OrientedPoints,
        pose: &Isometry3<f64>,
        config: &ViewConfig,
        hidden_margin_mm: Option<f64>,
        measured_only: bool,
    ) -> Vec<u32> {
        let cos_limit = config.max_incidence_deg.to_radians().cos();
        let mut facing = Vec::new();
        let rendered = self.render(model, pose, cos_limit, Some(&mut facing));
        let hidden = |f: &FacingPoint| {
            hidden_margin_mm.is_some_and(|margin| {
                self.cell_index(f.col, f.row)
                    .map(|k| f64::from(self.near[k]))
                    .is_some_and(|near| near - f.closeness > margin)
            })
        };
        facing
            .into_iter()
            .filter(|f| match rendered.get(f.col, f.row) {
                Some(e) => f.closeness >= e.closeness - self.tolerance_mm - e.slack,
                // Steeper than the rendering limit but facing the sensor: keep it.
                None => true,
            })
            .filter(|f| !hidden(f))
            .filter(|f| {
                !measured_only
                    || (-1..=1).any(|dr| {
                        (-1..=1).any(|dc| {
                            self.cell_index(f.col + dc, f.row + dr)
                                .is_some_and(|k| !self.near[k].is_nan())
                        })
                    })
            })
            .map(|f| f.index)
            .collect()
    }
}

/// A model point facing the sensor, projected: its index and cell, and how close it is
/// (mm, grows towards the sensor).
struct FacingPoint {
    index: u32,
    col: i64,
    row: i64,
    closeness: f64,
}

/// A model rendered into the view: the nearest model surface per cell, in (row, col)
/// order, and where each cell is over the rendering's bounding box (the outline test and
/// the visibility of each model point look cells up by position).
struct Rendering {
    cells: Vec<RenderedCell>,
    /// Cells the model would show beyond the scan's footprint (not in `cells`).
    outside: u32,
    col0: i64,
    row0: i64,
    cols: i64,
    rows: i64,
    /// Index into `cells` per cell of the box, row-major; `u32::MAX` where none.
    at: Vec<u32>,
}

impl Rendering {
    /// The nearest of `drawn` per cell; of equally near ones the first drawn. A pass over
    /// the bounding box, where sorting the drawn points by cell was a tenth of
    /// verification's time.
    fn nearest_per_cell(drawn: &[RenderedCell]) -> Self {
        let mut bounds: Option<(i64, i64, i64, i64)> = None;
        for d in drawn {
            let b = bounds.get_or_insert((d.col, d.col, d.row, d.row));
            *b = (
                b.0.min(d.col),
                b.1.max(d.col),
                b.2.min(d.row),
                b.3.max(d.row),
            );
        }
        let Some((col0, col1, row0, row1)) = bounds else {
            return Self {
                cells: Vec::new(),
                outside: 0,
                col0: 0,
                row0: 0,
                cols: 0,
                rows: 0,
                at: Vec::new(),
            };
        };
        let (cols, rows) = (col1 - col0 + 1, row1 - row0 + 1);
        let mut at = vec![u32::MAX; (cols * rows) as usize];
        for (i, d) in drawn.iter().enumerate() {
            let k = &mut at[((d.row - row0) * cols + d.col - col0) as usize];
            if *k == u32::MAX || d.closeness.total_cmp(&drawn[*k as usize].closeness).is_gt() {
                *k = i as u32;
            }
        }
        let mut cells = Vec::with_capacity(drawn.len());
        for k in at.iter_mut().filter(|k| **k != u32::MAX) {
            cells.push(drawn[*k as usize]);
            *k = (cells.len() - 1) as u32;
        }
        Self {
            cells,
            outside: 0,
            col0,
            row0,
            cols,
            rows,
            at,
        }
    }

    fn get(&self, col: i64, row: i64) -> Option<&RenderedCell> {
        self.index(col, row).map(|i| &self.cells[i])
    }

    fn has(&self, col: i64, row: i64) -> bool {
        self.get(col, row).is_some()
    }

    /// Index into `cells` of cell (`col`, `row`), when the model covers it.
    fn index(&self, col: i64, row: i64) -> Option<usize> {
        let (c, r) = (col - self.col0, row - self.row0);
        if !((0..self.cols).contains(&c) && (0..self.rows).contains(&r)) {
            return None;
        }
        let i = self.at[(r * self.cols + c) as usize];
        (i != u32::MAX).then_some(i as usize)
    }

    /// Cells seen through within [`CROSSING_CELLS`] of a cell a part hides (`state[i]` of
    /// `cells[i]`).
    fn crossings(&self, state: &[CellState]) -> u32 {
        let near_hidden = |cell: &RenderedCell| {
            (-CROSSING_CELLS..=CROSSING_CELLS).any(|dr| {
                (-CROSSING_CELLS..=CROSSING_CELLS).any(|dc| {
                    self.index(cell.col + dc, cell.row + dr)
                        .is_some_and(|k| state[k] == CellState::HiddenByPart)
                })
            })
        };
        self.cells
            .iter()
            .zip(state)
            .filter(|&(cell, st)| *st == CellState::SeenThrough && near_hidden(cell))
            .count() as u32
    }

    /// Whether the side (`dc`, `dr`) of cell (`col`, `row`) is an edge of the outline. The
    /// model is sampled at about one point per cell, so its rendering has holes of a cell
    /// or two (more on slanted faces): an edge has `OUTLINE_GAP` empty cells beyond it.
    fn is_edge(&self, col: i64, row: i64, dc: i64, dr: i64) -> bool {
        !(1..=OUTLINE_GAP).any(|k| self.has(col + k * dc, row + k * dr))
    }

    /// Whether any side of cell (`col`, `row`) is an edge of the outline.
    fn on_outline(&self, col: i64, row: i64) -> bool {
        SIDES.iter().any(|&(dc, dr)| self.is_edge(col, row, dc, dr))
    }
}

/// What the scene shows in a rendered cell, as far as the outline and crossings go.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum CellState {
    /// A part's surface (not background) lies in front of the model there.
    HiddenByPart,
    /// Something else lies in front of it (belt, bin, or a surface a cell away).
    HiddenByOther,
    /// The sensor saw a surface behind the model there.
    SeenThrough,
    Other,
}

impl CellState {
    fn hidden(self) -> bool {
        matches!(self, CellState::HiddenByPart | CellState::HiddenByOther)
    }
}

/// The four sides of a cell, (column, row) steps.
const SIDES: [(i64, i64); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];

/// One cell of a rendered model: the nearest model surface in it.
#[derive(Clone, Copy, Debug)]
struct RenderedCell {
    col: i64,
    row: i64,
    /// mm, grows towards the sensor.
    closeness: f64,
    /// Depth a slanted surface spans within the cell, mm.
    slack: f64,
    /// The model point, scene frame, mm.
    position: Point3<f64>,
    /// Outward unit normal, scene frame.
    normal: Vector3<f64>,
}

fn to_point(p: &P3) -> Point3<f64> {
    Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A 1 mm view grid of `points` (upward normals, `background[i]` marks support) seen by
    /// a scanner looking down, with a 1.5 mm tolerance.
    pub(crate) fn top_view_grid(points: &[P3], background: &[bool]) -> (RangeGrid, ViewConfig) {
        let view = ViewConfig {
            cell_mm: 1.0,
            tolerance_mm: 1.5,
            max_incidence_deg: 75.0,
            max_normal_angle_deg: 45.0,
            support_band_mm: 0.0,
            outline_neighbour_weight: NEIGHBOUR_FIT_WEIGHT,
        };
        let grid = RangeGrid::new(
            Sensor::orthographic([0.0, 0.0, 1.0]).unwrap(),
            &view,
            points,
            background,
            Some(&vec![[0.0, 0.0, 1.0]; points.len()]),
        )
        .unwrap();
        (grid, view)
    }

    #[test]
    fn a_point_skipped_as_facing_away_fails_the_exact_incidence_test_too() {
        // Normals at cosines to the sensor on both sides of the limit and within 1e-8 of it
        // (f32 rounding spreads them), many poses, both kinds of sensor: whatever the
        // model-frame test skips, render's own test in the scene's frame refuses as well, and
        // it skips everything clearly facing away.
        let limit = 75f64.to_radians().cos();
        let sensors = [
            Sensor::orthographic([0.1, -0.2, 1.0]).unwrap(),
            Sensor::perspective([30.0, -20.0, 900.0], [0.0, 0.0, 0.0]).unwrap(),
        ];
        let mut draw = crate::ppf::tests::xorshift(0x2545_f491);
        let mut next = move || f64::from(draw(1 << 24)) / f64::from(1u32 << 24);
        let (mut skipped, mut near) = (0, 0);
        for sensor in &sensors {
            for _ in 0..200 {
                let pose = Isometry3::new(
                    Vector3::new(
                        next() * 200.0 - 100.0,
                        next() * 200.0 - 100.0,
                        next() * 50.0,
                    ),
                    Vector3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 6.0,
                );
                let seen_from_model = SensorInModel::new(sensor, &pose);
                for j in 0..200 {
                    let p: P3 = [0, 1, 2].map(|_| (next() * 80.0 - 40.0) as f32);
                    let q = pose * to_point(&p);
                    let towards = sensor.towards(&q);
                    let across = towards
                        .cross(&Vector3::new(next(), next(), next()))
                        .normalize();
                    let cos = if j % 2 == 0 {
                        limit + (next() - 0.5) * 1e-7
                    } else {
                        next() * 2.0 - 1.0
                    };
                    let in_scene = towards * cos + across * (1.0 - cos * cos).sqrt();
                    let n_model = pose.rotation.inverse() * in_scene;
                    let n: P3 = [n_model.x as f32, n_model.y as f32, n_model.z as f32];
                    let exact = (pose.rotation
                        * Vector3::new(f64::from(n[0]), f64::from(n[1]), f64::from(n[2])))
                    .dot(&towards);
                    near += usize::from((exact - limit).abs() < 1e-8);
                    if seen_from_model.faces_away(&p, &n, limit - CULL_MARGIN) {
                        skipped += 1;
                        assert!(exact < limit, "skipped at cosine {exact} (limit {limit})");
                    } else {
                        // And it skips every point clearly past the limit.
                        assert!(exact >= limit - 1e-6, "kept at cosine {exact}");
                    }
                }
            }
        }
        assert!(
            skipped > 10_000 && near > 5_000,
            "{skipped} skipped, {near} near"
        );
    }

    /// The nearest per cell as first written: sorted by cell, then nearest first (stable),
    /// the first of each cell kept.
    fn nearest_by_sorting(drawn: &[RenderedCell]) -> Vec<RenderedCell> {
        let mut cells = drawn.to_vec();
        cells.sort_by(|a, b| {
            (a.row, a.col)
                .cmp(&(b.row, b.col))
                .then(b.closeness.total_cmp(&a.closeness))
        });
        cells.dedup_by(|next, kept| next.col == kept.col && next.row == kept.row);
        cells
    }

    /// A 20 x 20 mm tile at z = `z` (x 0-19, y 10-29, 1 mm apart), facing up.
    fn tile_20mm(z: f32) -> OrientedPoints {
        OrientedPoints {
            points: rows(z, 10..30)
                .into_iter()
                .filter(|p| p[0] < 20.0)
                .collect(),
            normals: vec![[0.0, 0.0, 1.0]; 20 * 20],
        }
    }

    /// Points of the plane z = `z` over x in [0, 40) every 1 mm and y in `ys`.
    fn rows(z: f32, ys: impl Iterator<Item = u32>) -> Vec<P3> {
        ys.flat_map(|y| (0..40).map(move |x| [x as f32 + 0.5, y as f32 + 0.5, z]))
            .collect()
    }

    #[test]
    fn holes_between_scan_lines_are_filled_and_depth_edges_are_not() {
        // Scan lines every 2 mm on a 1 mm grid: a flat tile (z = 0, y < 20) and a box top
        // (z = 10, y >= 20); the empty row at y = 19 lies on the depth edge between them.
        let points: Vec<P3> = rows(0.0, (0..20).step_by(2))
            .into_iter()
            .chain(rows(10.0, (20..40).step_by(2)))
            .collect();
        let up = [0.0f32, 0.0, 1.0];
        let (grid, view) = top_view_grid(&points, &vec![false; points.len()]);
        let depth = |x: i64, y: i64| {
            let (c, r, _) = grid
                .projector
                .project(&Point3::new(x as f64 + 0.5, y as f64 + 0.5, 0.0))
                .unwrap();
            let k = grid.cell_index(c.floor() as i64, r.floor() as i64).unwrap();
            grid.near[k]
        };
        // Inside each surface the missing lines take the surface's depth ...
        for (y, z) in [(1, 0.0), (17, 0.0), (21, 10.0), (37, 10.0)] {
            for x in [0, 13, 39] {
                assert_eq!(depth(x, y), depth(x, y - 1), "x {x} y {y}");
                assert_eq!(depth(x, y) - depth(x, 0), z, "x {x} y {y}");
            }
        }
        // ... the line on the depth edge stays empty.
        assert!(depth(5, 19).is_nan());
        // A tile modelled on the flat part is explained in every cell by its own.
        let tile = OrientedPoints {
            points: rows(0.0, 0..18),
            normals: vec![up; 40 * 18],
        };
        let s = grid.score(&tile, &Isometry3::identity(), &view);
        assert_eq!(s.explained, s.visible);
        assert!(
            (s.mean_fit() - 1.0).abs() < 1e-9,
            "mean fit {}",
            s.mean_fit()
        );
    }

    #[test]
    fn support_explains_a_model_surface_as_support_only_outside_its_band() {
        // A belt (background) at z = 0 and a 20 mm square modelled 1 mm above it: the belt
        // explains the square within the 1.5 mm tolerance.
        let belt = rows(0.0, 0..40);
        let square = tile_20mm(1.0);
        let (grid, view) = top_view_grid(&belt, &vec![true; belt.len()]);
        let s = grid.score(&square, &Isometry3::identity(), &view);
        assert_eq!(s.explained, 400);
        assert_eq!(
            s.explained_by_support, 400,
            "no band: all of it is the belt's"
        );
        // Points within 2 mm of the belt's plane were labelled belt: a surface 1 mm above it
        // would have been too, so the belt does not count against it.
        let banded = ViewConfig {
            support_band_mm: 2.0,
            ..view.clone()
        };
        let s = grid.score(&square, &Isometry3::identity(), &banded);
        assert_eq!(s.explained, 400);
        assert_eq!(s.explained_by_support, 0);
        // A negative band is refused, naming the field.
        let bad = ViewConfig {
            support_band_mm: -1.0,
            ..view
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("support_band_mm")
        );
    }

    #[test]
    fn model_points_under_a_nearer_surface_are_hidden_beyond_the_margin_only() {
        // A 40 x 40 mm tile at z = 0; over its rows y < 10 lies a plate 5 mm higher, over
        // rows 10-19 a skin 1 mm higher (noise, or the tile itself a little off); rows
        // 20-39 are the tile's own surface.
        let scene: Vec<P3> = rows(5.0, 0..10)
            .into_iter()
            .chain(rows(1.0, 10..20))
            .chain(rows(0.0, 20..40))
            .collect();
        let (grid, view) = top_view_grid(&scene, &vec![false; scene.len()]);
        let tile = OrientedPoints {
            points: rows(0.0, 0..40),
            normals: vec![[0.0, 0.0, 1.0]; 40 * 40],
        };
        let pose = Isometry3::identity();
        let row_of = |i: &u32| i / 40;
        let visible = grid.visible_model_points(&tile, &pose, &view);
        assert_eq!(
            visible.len(),
            1600,
            "the model alone hides nothing of itself"
        );
        let unhidden = grid.unhidden_model_points(&tile, &pose, &view, 1.5);
        assert!(
            unhidden.iter().all(|i| row_of(i) >= 10),
            "under the plate: hidden"
        );
        assert_eq!(unhidden.len(), 1200, "within the margin: kept");
        // A margin wider than the plate's height hides nothing.
        assert_eq!(
            grid.unhidden_model_points(&tile, &pose, &view, 6.0).len(),
            1600
        );
    }

    #[test]
    fn model_points_where_the_sensor_measured_nothing_around_are_left_out() {
        // The scan of a 40 x 40 mm tile stops at row 30 (the rest in a shadow); a point of
        // the floor far beyond keeps the tile inside the scanned area.
        let mut scene = rows(0.0, 0..30);
        scene.push([0.5, 60.5, -20.0]);
        let (grid, view) = top_view_grid(&scene, &vec![false; scene.len()]);
        let tile = OrientedPoints {
            points: rows(0.0, 0..40),
            normals: vec![[0.0, 0.0, 1.0]; 40 * 40],
        };
        let pose = Isometry3::identity();
        assert_eq!(
            grid.unhidden_model_points(&tile, &pose, &view, 1.5).len(),
            1600,
            "nothing hides the tile"
        );
        let measured = grid.measured_model_points(&tile, &pose, &view, 1.5);
        assert!(
            measured.iter().all(|i| i / 40 <= 30),
            "rows more than a cell past the scan's last left out"
        );
        assert_eq!(
            measured.len(),
            31 * 40,
            "the row beside the scan's edge kept"
        );
    }

    #[test]
    fn a_part_crossing_the_edge_of_the_scan_is_judged_on_the_scanned_area_only() {
        // A 40 x 40 mm tile, scanned up to row 20, where the scan ends.
        let tile = OrientedPoints {
            points: rows(0.0, 0..40),
            normals: vec![[0.0, 0.0, 1.0]; 40 * 40],
        };
        let pose = Isometry3::identity();
        // A floor 20 mm below on either side (x -10..0 and 40..50).
        let mut scene = rows(0.0, 0..20);
        let mut floor = vec![false; scene.len()];
        for y in 0..20 {
            for x in (-10..0).chain(40..50) {
                scene.push([x as f32 + 0.5, y as f32 + 0.5, -20.0]);
                floor.push(true);
            }
        }
        let (grid, view) = top_view_grid(&scene, &floor);
        let s = grid.score(&tile, &pose, &view);
        assert_eq!((s.visible, s.outside), (800, 800), "half beyond the scan");
        assert_eq!((s.explained, s.missing), (800, 0));
        assert_eq!(s.visibility(), 1.0);
        // Its outline is the two sides over the floor; none where the scan ends.
        assert_eq!((s.outline_edges, s.outline_continued), (2 * 20, 0));
        assert_eq!(
            grid.visible_model_points(&tile, &pose, &view).len(),
            800,
            "only the scanned half is aligned"
        );
        // The same tile with the scan's edge far off: its other half is in a shadow.
        scene.push([0.5, 60.5, -20.0]);
        floor.push(true);
        let (grid, view) = top_view_grid(&scene, &floor);
        let s = grid.score(&tile, &pose, &view);
        assert_eq!(s.outside, 0);
        assert_eq!(s.visible, 1600);
        assert!(s.missing >= 760, "{} missing", s.missing);
        assert!(s.visibility() < 0.55);
    }

    #[test]
    fn a_neighbours_surface_weighs_more_on_the_outline_than_inside_for_acceptance() {
        // A model strip two cells wide (y 10-11) over a scan of it one cell over (y 11-12),
        // on a belt 20 mm lower: row 10, on the outline, is explained by row 11 beside it.
        let strip = OrientedPoints {
            points: rows(0.0, 10..12),
            normals: vec![[0.0, 0.0, 1.0]; 80],
        };
        let scene: Vec<P3> = rows(-20.0, 0..40)
            .into_iter()
            .filter(|p| !(11.0..13.0).contains(&p[1]))
            .chain(rows(0.0, 11..13))
            .collect();
        let (grid, view) = top_view_grid(&scene, &vec![false; scene.len()]);
        let fit = |w: f64| {
            let config = ViewConfig {
                outline_neighbour_weight: w,
                ..view.clone()
            };
            let s = grid.score(&strip, &Isometry3::identity(), &config);
            assert_eq!(s.explained, 80);
            // The competition's fit keeps the quarter weight.
            assert!((s.mean_fit() - 0.625).abs() < 1e-9, "{}", s.mean_fit());
            s.mean_acceptance_fit()
        };
        // Every cell of the strip is on its outline: half its cells count at the weight.
        assert!((fit(0.25) - 0.625).abs() < 1e-9, "{}", fit(0.25));
        assert!((fit(0.5) - 0.75).abs() < 1e-9, "{}", fit(0.5));
        // A 20-cell-wide tile scanned one cell over: only its edge rows and columns are on
        // the outline, so the weight moves its fit little.
        let tile = OrientedPoints {
            points: rows(0.0, 10..30),
            normals: vec![[0.0, 0.0, 1.0]; 800],
        };
        let scene = rows(0.0, 11..31);
        let (grid, view) = top_view_grid(&scene, &vec![false; scene.len()]);
        let tile_fit = |w: f64| {
            let config = ViewConfig {
                outline_neighbour_weight: w,
                ..view.clone()
            };
            grid.score(&tile, &Isometry3::identity(), &config)
                .mean_acceptance_fit()
        };
        assert!(tile_fit(0.5) - tile_fit(0.25) < 0.02);
        // Out of range, the field is named.
        let bad = ViewConfig {
            outline_neighbour_weight: 1.5,
            ..view
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("outline_neighbour_weight")
        );
    }

    #[test]
    fn only_surface_over_the_inside_of_a_part_covers_it() {
        // A 20 x 20 mm tile (x 0-19, y 10-29) lying in a 40 x 40 mm scene at z = 0.
        let tile = tile_20mm(0.0);
        let covered_with = |over: &dyn Fn(&P3) -> bool| {
            let scene: Vec<P3> = rows(0.0, 0..40)
                .into_iter()
                .map(|p| if over(&p) { [p[0], p[1], 5.0] } else { p })
                .collect();
            let (grid, view) = top_view_grid(&scene, &vec![false; scene.len()]);
            let s = grid.score(&tile, &Isometry3::identity(), &view);
            (s.covered, s.occluded)
        };
        // A neighbour 5 mm higher reaching two rows over the tile's edge (y 10 and 11): the
        // row inside is explained by the tile's surface a cell away, the edge row is occluded
        // but on the outline, so nothing covers the tile.
        assert_eq!(covered_with(&|p| p[1] < 12.0), (0, 20));
        // The same neighbour over the tile's middle covers it.
        let (covered, _) = covered_with(&|p| (15.0..25.0).contains(&p[1]) && p[0] < 15.0);
        assert!(covered >= 100, "covered {covered}");
    }

    #[test]
    fn a_pose_through_a_part_crosses_it_and_one_under_a_part_does_not() {
        // The 20 x 20 mm tile (x 0-19, y 10-29) at z = 0.
        let tile = tile_20mm(0.0);
        let score = |scene: &[P3], background: &[bool]| {
            let (grid, view) = top_view_grid(scene, background);
            grid.score(&tile, &Isometry3::identity(), &view)
        };
        // A part's sheet rising across the tile, 4 mm per cell, level with it at x = 10:
        // seen through up to x = 8, hidden from x = 10 (x = 9 sees the sheet in front a cell
        // away). Only the column at x = 8 lies within two cells of the hidden ones.
        let steep: Vec<P3> = rows(0.0, 0..40)
            .into_iter()
            .map(|p| [p[0], p[1], 4.0 * (p[0] - 10.0)])
            .collect();
        let s = score(&steep, &vec![false; steep.len()]);
        assert_eq!((s.free_space, s.crossing), (9 * 20, 20));
        // The tile under a neighbour (z = 5 from x = 10, y 15-24), its pose 2 mm past the
        // part's edge over the floor (z = -10 for x < 2): seen through and covered, but
        // far apart.
        let under: Vec<P3> = rows(0.0, 0..40)
            .into_iter()
            .map(|p| {
                if p[0] < 2.0 {
                    [p[0], p[1], -10.0]
                } else if p[0] >= 10.0 && (15.0..25.0).contains(&p[1]) {
                    [p[0], p[1], 5.0]
                } else {
                    p
                }
            })
            .collect();
        let floor: Vec<bool> = under.iter().map(|p| p[2] < -5.0).collect();
        let s = score(&under, &floor);
        assert!(s.free_space > 0 && s.covered > 0, "{s:?}");
        assert_eq!(s.crossing, 0);
    }

    #[test]
    fn a_filled_hole_takes_the_known_normal_of_its_sides() {
        // One row: measured, empty, measured; the left side's normal is unknown.
        let up = [0.0f32, 0.0, 1.0];
        let mut near = vec![5.0, f32::NAN, 5.5];
        let mut background = vec![true, false, true];
        let mut normal = vec![[f32::NAN; 3], [f32::NAN; 3], up];
        let mut point = vec![[0.0, 0.0, 5.0], [f32::NAN; 3], [2.0, 0.0, 5.5]];
        let filled =
            fill_sampling_holes(3, &mut near, &mut background, &mut normal, &mut point, 1.0);
        assert_eq!(filled, vec![false, true, false]);
        assert_eq!(near[1], 5.25);
        assert!(background[1]);
        assert_eq!(normal[1], up);
        assert_eq!(point[1], [1.0, 0.0, 5.25]);
        // Beyond the tolerance the sides are a depth edge: nothing is filled.
        let mut near = vec![5.0, f32::NAN, 7.0];
        let filled =
            fill_sampling_holes(3, &mut near, &mut background, &mut normal, &mut point, 1.0);
        assert_eq!(filled, vec![false; 3]);
        assert!(near[1].is_nan());
    }

    #[test]
    fn nearest_per_cell_is_that_of_a_stable_sort() {
        let mut next = crate::ppf::tests::xorshift(0x9e37_79b9);
        for trial in 0..300 {
            // Few cells and few depths: many points share a cell and a depth.
            let drawn: Vec<RenderedCell> = (0..trial % 60)
                .map(|i| RenderedCell {
                    col: i64::from(next(5)) - 2,
                    row: i64::from(next(4)) + 7,
                    closeness: f64::from(next(3)),
                    slack: 0.0,
                    // Tells equally near points apart.
                    position: Point3::new(f64::from(i), 0.0, 0.0),
                    normal: Vector3::z(),
                })
                .collect();
            let grid = Rendering::nearest_per_cell(&drawn);
            let sorted = nearest_by_sorting(&drawn);
            let key = |c: &RenderedCell| (c.col, c.row, c.closeness.to_bits(), c.position.x);
            assert_eq!(
                grid.cells.iter().map(key).collect::<Vec<_>>(),
                sorted.iter().map(key).collect::<Vec<_>>(),
                "trial {trial}"
            );
            for c in &sorted {
                assert_eq!(grid.get(c.col, c.row).map(key), Some(key(c)));
            }
            assert!(!grid.has(-3, 7) && !grid.has(0, 6) && !grid.has(3, 11));
        }
    }
}
