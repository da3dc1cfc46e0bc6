//! Scene voting, step 2: verification. Each hypothesis is refined by ICP (PCL, through the
//! bridge) on the part of the model surface the sensor can see in that pose, then rendered
//! into the sensor's view of the scene and judged cell by cell: explained, occluded, free
//! space or missing (see `binpick_match::view`). The thesis's validators (3.1.1, 3.1.2) are
//! computed for every survivor on the same visible surface.

use nalgebra::{Isometry3, Point3, Vector3};

use binpick_cloud::{Point, to_point3, transform_point};
use binpick_match::{OrientedPoints, RangeGrid, Sensor, ViewConfig, ViewScore};
use binpick_pcl::{IcpParams, IndexedCloud};

use crate::error::matching;
use crate::error::{Result, input, pcl};
use crate::params::{SensorConfig, VerifyConfig};
use crate::result::{DerivedScale, ViewCheck};
use crate::stages::hypotheses::{VotingModel, is_ribbon};
use crate::validate::{NearestIndex, euclidean_score, outlier_percent};

/// A camera is assumed at the origin when the scene's centre lies this many scene extents
/// away from it (a cloud written in its camera's frame).
const CAMERA_FRAME_EXTENTS: f64 = 1.0;
/// Most model points one ICP aligns.
const ICP_POINTS: usize = 800;
/// Iterations of the coarse pass after which a hopeless pose stops refining: on the
/// generalisation benchmark the view score there tells hopeless poses apart as well as
/// after all 15 (the lowest visibility of a part taken in the end: 0.30 at 5, 0.31 at 15).
const PROBE_ITERATIONS: u32 = 5;
/// The thesis's outlier distance relative to its resolution (4 mm at 1 mm, 4.3 #12).
const OUTLIER_RESOLUTIONS: f64 = 4.0;
/// Orthographic sensors are placed this far along `up` for normal orientation, mm.
const FAR_MM: f64 = 1e7;
/// Model points checked against the support planes per pose.
const SUPPORT_SAMPLE_POINTS: usize = 400;
/// Support planes within this angle are parallel (a layer of parts on the floor).
const PARALLEL_DEG: f64 = 10.0;
/// A model point is behind a support plane when it lies this many view tolerances beyond it
/// (a resting part touches its support; noise and a slight tilt stay well inside).
const SUPPORT_TOLERANCES: f64 = 3.0;
/// A support plane bounds the parts when the scene's non-support points behind it number at
/// most this share of those in front (outliers: measured 0.5-3 % behind floors and walls of
/// the generalisation benchmark; 20-60 % for planes RANSAC laid across tops of parts).
const MAX_BEHIND_RATIO: f64 = 0.05;
/// ... or number at most this share of the plane's own points (measured: 55-65 outliers
/// behind 2 mm bin floors of 27 000-30 000 points, 0.2 %; planes laid across the tops of a
/// layer of rods or shafts have 6-12 % of their own points behind them).
const MAX_OUTLIER_RATIO: f64 = 0.005;

/// Asked mid-refinement whether the pose reached is worth refining further.
pub(crate) type Probe<'a> = dyn FnMut(&Isometry3<f64>) -> bool + 'a;

/// Where the sensor was: the configured one, or for `auto` a camera at the origin when the
/// scene lies far out along one side of it, else a scanner far above along `up`.
pub(crate) fn resolve_sensor(cfg: &SensorConfig, up: [f64; 3], points: &[Point]) -> Result<Sensor> {
    let bad = |e| input("sensor", format!("{e}"));
    match cfg {
        SensorConfig::Above => Sensor::orthographic(up).map_err(bad),
        SensorConfig::Camera { position_mm } => {
            Sensor::perspective(*position_mm, centroid(points)).map_err(bad)
        }
        SensorConfig::Auto => {
            let c = centroid(points);
            let extent = binpick_cloud::PointCloud::new(points.to_vec())
                .bounds()
                .map_or(0.0, |b| f64::from(b.diagonal()));
            let far = Vector3::from(c).norm() > CAMERA_FRAME_EXTENTS * extent.max(1e-9);
            if far {
                Sensor::perspective([0.0; 3], c).map_err(bad)
            } else {
                Sensor::orthographic(up).map_err(bad)
            }
        }
    }
}

/// A point to orient surface normals towards (the camera, or far above).
pub(crate) fn viewpoint(sensor: &Sensor, points: &[Point]) -> [f64; 3] {
    match sensor {
        Sensor::Perspective { position, .. } => [position.x, position.y, position.z],
        Sensor::Orthographic { up } => {
            let c = Point3::from(centroid(points)) + up * FAR_MM;
            [c.x, c.y, c.z]
        }
    }
}

fn centroid(points: &[Point]) -> [f64; 3] {
    binpick_cloud::centroid(points).unwrap_or([0.0; 3])
}

/// The view grid's settings at this scale.
pub(crate) fn view_config(scale: &DerivedScale, cfg: &VerifyConfig) -> ViewConfig {
    ViewConfig {
        cell_mm: scale.cell_mm,
        tolerance_mm: scale.tolerance_mm,
        max_incidence_deg: cfg.max_incidence_deg,
        max_normal_angle_deg: cfg.max_normal_angle_deg,
        support_band_mm: scale.support_distance_mm,
        outline_neighbour_weight: cfg.outline_neighbour_weight,
    }
}

/// The preprocessed scene as the engine uses it.
pub(crate) struct SceneSurface {
    /// Every preprocessed point (support included) ...
    pub points: Vec<Point>,
    /// ... its normal (NaN where undefined) ...
    pub normals: Vec<[f32; 3]>,
    /// ... the normal the view judges poses by (`view_normals`: a strip faces the sensor) ...
    pub view_normals: Vec<[f32; 3]>,
    /// ... and whether it is support (belt, floor, wall).
    pub support: Vec<bool>,
    /// The points (not support) whose neighbourhood is a ribbon (`view_normals`).
    pub ribbons: Vec<Point>,
    /// The points that are not support.
    pub world: Vec<Point>,
    /// The support planes found in preprocessing that bound the parts, unit normal towards
    /// them and offset (mm): [`bounding_planes`].
    pub bounding: Vec<(Vector3<f64>, f64)>,
}

/// Fewer scene ribbon points or visible model rim points than this: no rim refinement.
const MIN_RIBBON_POINTS: usize = 10;

/// An edge-on pose whose outline the scene carries on past needs this share of its visible
/// rims on the scene's ribbons (measured: strips laid on faces 0-2 %, parts on their edge
/// 23-96 %).
const MIN_ON_RIBBONS: f64 = 0.1;

/// A pose that would show the sensor at most this share of the part's typical view shows
/// an edge (a Z bracket on its side: 4-8 %).
const EDGE_ON_VIEW_SHARE: f64 = 0.2;

/// Everything verification reads, built once per scene.
pub(crate) struct Verifier<'a> {
    pub grid: RangeGrid,
    pub view: ViewConfig,
    /// The ICP target ([`icp_target`]): the scene without its support, and the support
    /// points ICP could pair with a part.
    world: IndexedCloud,
    world_index: NearestIndex,
    /// The scene's ribbons, when the part has rims: the ICP target of rim hypotheses ...
    ribbons: Option<IndexedCloud>,
    /// The points of `world`.
    world_points: Vec<Point>,
    model: &'a VotingModel,
    scale: &'a DerivedScale,
    cfg: &'a VerifyConfig,
    /// The support planes that can carry a part (`sink_planes`), normals towards the parts:
    /// a pose's deepest point and its share behind them are checked against these. Not a
    /// bin's rim: parts heaped high stick out past it (its share refused the top part of a
    /// pile, fully in view, on two of the benchmark's scans).
    sink_planes: Vec<(Vector3<f64>, f64)>,
    /// A fixed sample of the model's surface checked against them (model frame).
    support_sample: Vec<Point3<f64>>,
    /// Per grid cell: the scene's surface there is one of those planes. The plane explains
    /// it already; a part explaining it too gains nothing (a pose laid half on the floor).
    pub support_explained: Vec<bool>,
}

/// The part's surface points the sensor sees at one pose ([`Verifier::seen_surface`]), scene
/// frame.
pub(crate) struct SeenSurface(Vec<Point>);

/// The thesis's validators of a pose, on the visible model surface.
pub(crate) struct ThesisScores {
    /// Euclidean score, mm^2 (3.1.1).
    pub euclidean: f64,
    /// Percent of outliers (3.1.2).
    pub outliers_pct: f64,
}

impl<'a> Verifier<'a> {
    pub(crate) fn new(
        sensor: Sensor,
        scene: &SceneSurface,
        model: &'a VotingModel,
        scale: &'a DerivedScale,
        cfg: &'a VerifyConfig,
    ) -> Result<Self> {
        let view = view_config(scale, cfg);
        let towards_sensor = match &sensor {
            Sensor::Orthographic { up } => *up,
            Sensor::Perspective { axis, .. } => -axis,
        };
        // The view grid and the scene's search trees are independent: built side by side.
        let (grid, (world, (ribbons, world_index))) = rayon::join(
            || {
                RangeGrid::new(
                    sensor,
                    &view,
                    &scene.points,
                    &scene.support,
                    Some(&scene.view_normals),
                )
                .map_err(matching("view grid"))
            },
            || {
                rayon::join(
                    || {
                        let target = icp_target(
                            scene,
                            coarse_icp_distance_mm(scale),
                            OFF_PLANE_NOISES
                                * scale.scan_noise_mm.unwrap_or(0.5 * scale.resolution_mm),
                        );
                        tracing::debug!(
                            points = target.len(),
                            support = target.len() - scene.world.len(),
                            "ICP target: the parts and the support beside them"
                        );
                        IndexedCloud::new(&target).map_err(pcl("scene upload"))
                    },
                    || {
                        rayon::join(
                            || {
                                if model.rims.is_some() && scene.ribbons.len() >= MIN_RIBBON_POINTS
                                {
                                    IndexedCloud::new(&scene.ribbons)
                                        .map(Some)
                                        .map_err(pcl("scene upload"))
                                } else {
                                    Ok(None)
                                }
                            },
                            || {
                                NearestIndex::new("scene", &scene.world)
                                    .map_err(|e| input("scene", e.to_string()))
                            },
                        )
                    },
                )
            },
        );
        let grid = grid?;
        let on_plane = scale.support_distance_mm;
        let support_explained = grid.background_cells(|p| {
            let q = to_point3(p).coords;
            scene
                .bounding
                .iter()
                .any(|(n, d)| (n.dot(&q) + d).abs() <= on_plane)
        });
        Ok(Self {
            support_explained,
            support_sample: binpick_cloud::strided_points(
                &model.dense.points,
                SUPPORT_SAMPLE_POINTS,
            ),
            sink_planes: sink_planes(&scene.bounding, scale.model_diameter_mm, &towards_sensor),
            grid,
            view,
            world: world?,
            ribbons: ribbons?,
            world_points: scene.world.clone(),
            world_index: world_index?,
            model,
            scale,
            cfg,
        })
    }

    /// The model points the sensor would see at `pose`, at most `max` (evenly strided).
    fn visible(&self, pose: &Isometry3<f64>, max: usize) -> Vec<Point> {
        let idx = self
            .grid
            .visible_model_points(&self.model.dense, pose, &self.view);
        self.strided(&idx, max)
    }

    /// The model points ICP aligns at `pose`, at most `max` (evenly strided): those the
    /// sensor would see, less those the scene hides and those it measured nothing around
    /// (`RangeGrid::measured_model_points`; all it would see without
    /// `refine_confirmed_only`). Such points have no surface of their own in the
    /// scan to pair with, and the nearest other one pulls the pose off the part (from true
    /// poses moved 2.5 mm and 4 deg: 65 of 72 parts accepted after refinement, 61 aligning
    /// every visible point).
    fn alignable(&self, pose: &Isometry3<f64>, max: usize) -> Vec<Point> {
        if !self.cfg.refine_confirmed_only {
            return self.visible(pose, max);
        }
        let idx = self.grid.measured_model_points(
            &self.model.dense,
            pose,
            &self.view,
            self.scale.tolerance_mm,
        );
        self.strided(&idx, max)
    }

    /// At most `max` of the model points `idx`, evenly strided.
    fn strided(&self, idx: &[u32], max: usize) -> Vec<Point> {
        let step = idx.len().div_ceil(max.max(1)).max(1);
        idx.iter()
            .step_by(step)
            .map(|&i| self.model.dense.points[i as usize])
            .collect()
    }

    /// Two ICP passes on the alignable surface ([`Verifier::alignable`]): coarse
    /// (correspondences within two sampling steps), then fine (within two tolerances).
    /// Returns the pose and the last ICP outcome.
    ///
    /// With a `probe`, the coarse pass first stops after [`PROBE_ITERATIONS`] and asks it
    /// whether the pose there is worth refining further; when it is not, that pose is
    /// returned. Most hypotheses are far from any part and would run every iteration of
    /// both passes for nothing.
    pub(crate) fn refine(
        &self,
        pose: &Isometry3<f64>,
        mut probe: Option<&mut Probe<'_>>,
    ) -> Result<(Isometry3<f64>, Option<binpick_pcl::IcpOutcome>)> {
        let mut pose = *pose;
        let mut last = None;
        for distance in [
            coarse_icp_distance_mm(self.scale),
            2.0 * self.scale.tolerance_mm,
        ] {
            let src = self.alignable(&pose, ICP_POINTS);
            if src.len() < 10 {
                break;
            }
            let mut iterations = self.cfg.refine_iterations;
            if let Some(worth) = probe.take().filter(|_| iterations > PROBE_ITERATIONS) {
                let out = self.icp(&src, &pose, distance, PROBE_ITERATIONS, false)?;
                if let Some(p) = out.pose() {
                    pose = p;
                }
                let stopped = out.stop != binpick_pcl::IcpStop::Iterations;
                last = Some(out);
                if !worth(&pose) {
                    return Ok((pose, last));
                }
                if stopped {
                    continue;
                }
                iterations -= PROBE_ITERATIONS;
            }
            let out = self.icp(&src, &pose, distance, iterations, false)?;
            if let Some(p) = out.pose() {
                pose = p;
            }
            last = Some(out);
        }
        Ok((pose, last))
    }

    /// ICP of the part's visible rims onto the scene's ribbons, in two passes as
    /// [`Verifier::refine`]: a part lying on its sheet's edge shows the sensor a strip a few
    /// points wide, which ICP onto the whole scene slides onto its neighbours' surfaces.
    /// None without rims or when too few rim points are visible.
    pub(crate) fn refine_rim(&self, pose: &Isometry3<f64>) -> Result<Option<Isometry3<f64>>> {
        let Some(ribbons) = &self.ribbons else {
            return Ok(None);
        };
        let mut pose = *pose;
        let mut moved = false;
        for distance in [
            coarse_icp_distance_mm(self.scale),
            2.0 * self.scale.tolerance_mm,
        ] {
            let src = self.strided(&self.visible_rims(&pose), ICP_POINTS);
            if src.len() < MIN_RIBBON_POINTS {
                break;
            }
            let iterations = self.cfg.refine_iterations;
            let out = self.icp_onto(ribbons, &src, &pose, distance, iterations, false)?;
            if let Some(p) = out.pose() {
                pose = p;
                moved = true;
            }
        }
        Ok(moved.then_some(pose))
    }

    /// The model's rim points the sensor would see at `pose` (indices into the dense
    /// surface; none without rims).
    fn visible_rims(&self, pose: &Isometry3<f64>) -> Vec<u32> {
        let Some(rims) = &self.model.rims else {
            return Vec::new();
        };
        self.grid
            .visible_model_points(&self.model.dense, pose, &self.view)
            .into_iter()
            .filter(|&i| rims.on_rim[i as usize])
            .collect()
    }

    /// Whether `pose` (scored `score`) shows the sensor an edge laid on a wider surface: it
    /// would show little ([`EDGE_ON_VIEW_SHARE`] of its typical view) and some rims, the
    /// scene carries on past more than `max_continued` of its outline, and under
    /// [`MIN_ON_RIBBONS`] of those rims meet a ribbon in the scene (within two tolerances).
    /// A real part on its edge is a ribbon in the scan; a strip laid along a flat face is
    /// not, and such strips side by side explain each other's outlines. Always false for a
    /// part without rims.
    pub(crate) fn edge_on_a_surface(&self, pose: &Isometry3<f64>, score: &ViewScore) -> bool {
        if self.model.rims.is_none()
            || f64::from(score.view_cells()) > edge_on_cells(self.scale)
            || f64::from(score.outline_continued)
                <= self.cfg.max_continued * f64::from(score.outline_edges)
        {
            return false;
        }
        let rims: Vec<Point> = self
            .visible_rims(pose)
            .into_iter()
            .map(|i| transform_point(pose, &self.model.dense.points[i as usize]))
            .collect();
        if rims.is_empty() {
            return false;
        }
        let near = (2.0 * self.scale.tolerance_mm).powi(2) as f32;
        let mut buf = Vec::new();
        let on = rims
            .iter()
            .filter(|p| {
                let (k, d2) = self.world_index.nearest(p);
                d2 <= near
                    && is_ribbon(
                        &self.world_points,
                        &self.world_index,
                        &self.world_points[k],
                        self.scale.sampling_step_mm,
                        &mut buf,
                    )
            })
            .count();
        (on as f64) < MIN_ON_RIBBONS * rims.len() as f64
    }

    /// One fine ICP pass (correspondences within two tolerances) on the visible surface less
    /// what the scene hides by more than a tolerance: a part under its neighbours is
    /// otherwise pulled towards them. Meant for a pose already refined: from farther off,
    /// the part's own surface would look hidden. With `reciprocal`, only mutual nearest
    /// neighbours pair up (`IcpParams::reciprocal`). None when too little is left to align.
    pub(crate) fn refine_unhidden(
        &self,
        pose: &Isometry3<f64>,
        reciprocal: bool,
    ) -> Result<Option<(Isometry3<f64>, binpick_pcl::IcpOutcome)>> {
        let tolerance = self.scale.tolerance_mm;
        let idx = self
            .grid
            .unhidden_model_points(&self.model.dense, pose, &self.view, tolerance);
        let src = self.strided(&idx, ICP_POINTS);
        if src.len() < 10 {
            return Ok(None);
        }
        let out = self.icp(
            &src,
            pose,
            2.0 * tolerance,
            self.cfg.refine_iterations,
            reciprocal,
        )?;
        Ok(out.pose().map(|p| (p, out)))
    }

    /// PCL's ICP of the model points `src` onto the scene from `pose`.
    fn icp(
        &self,
        src: &[Point],
        pose: &Isometry3<f64>,
        distance: f64,
        iterations: u32,
        reciprocal: bool,
    ) -> Result<binpick_pcl::IcpOutcome> {
        self.icp_onto(&self.world, src, pose, distance, iterations, reciprocal)
    }

    /// PCL's ICP of the model points `src` onto `target` from `pose`.
    fn icp_onto(
        &self,
        target: &IndexedCloud,
        src: &[Point],
        pose: &Isometry3<f64>,
        distance: f64,
        iterations: u32,
        reciprocal: bool,
    ) -> Result<binpick_pcl::IcpOutcome> {
        let w = self.scale.resolution_mm;
        target
            .icp(
                src,
                &IcpParams {
                    initial: binpick_pcl::row_major(pose),
                    max_correspondence_distance: distance,
                    max_iterations: iterations,
                    transformation_epsilon: 1e-6 * w * w,
                    batch_correspondences: true,
                    relative_mse: self.cfg.refine_relative_mse,
                    reciprocal,
                },
            )
            .map_err(pcl("refinement ICP"))
    }

    /// The view's score of the part's surface at `pose` where it lies farther than
    /// `apart_mm` from its surface at `other` (model frame indexed by `surface_index`): the
    /// view's judgement of the surface two poses of the part do not share.
    pub(crate) fn score_apart_from(
        &self,
        surface_index: &binpick_match::GridIndex,
        pose: &Isometry3<f64>,
        other: &Isometry3<f64>,
        apart_mm: f64,
    ) -> ViewScore {
        let to_other = other.inverse() * pose;
        let apart = (apart_mm * apart_mm) as f32;
        let dense = &self.model.dense;
        let (points, normals) = dense
            .points
            .iter()
            .zip(&dense.normals)
            .filter(|(p, _)| !surface_index.any_within(&transform_point(&to_other, p), apart))
            .map(|(p, n)| (*p, *n))
            .unzip();
        self.grid
            .score(&OrientedPoints { points, normals }, pose, &self.view)
    }

    /// The view verdict of `pose`.
    pub(crate) fn score(&self, pose: &Isometry3<f64>) -> ViewScore {
        let mut s = self.grid.score(&self.model.dense, pose, &self.view);
        if !self.sink_planes.is_empty() {
            let depth = sunk_depth_mm(self.scale);
            s.support_checked = self.support_sample.len() as u32;
            s.below_support = self
                .support_sample
                .iter()
                .filter(|p| {
                    let q = pose * *p;
                    self.sink_planes
                        .iter()
                        .any(|(n, d)| n.dot(&q.coords) + d < -depth)
                })
                .count() as u32;
            s.sunk_mm = self
                .model
                .extremes
                .iter()
                .map(|p| {
                    let q = pose * p;
                    self.sink_planes
                        .iter()
                        .map(|(n, d)| -(n.dot(&q.coords) + d))
                        .fold(0.0, f64::max)
                })
                .fold(0.0, f64::max);
        }
        s
    }

    /// The thesis's validators on the visible surface: the Euclidean score and the percent of
    /// outliers at an outlier distance of 4 resolutions (4 mm at the thesis's 1 mm).
    pub(crate) fn thesis_scores(&self, pose: &Isometry3<f64>) -> ThesisScores {
        // In the model frame, so the validators place them by `pose` themselves.
        let visible = self.visible(pose, usize::MAX);
        ThesisScores {
            euclidean: euclidean_score(&self.world_index, &visible, pose),
            outliers_pct: outlier_percent(
                &self.world_index,
                &visible,
                pose,
                OUTLIER_RESOLUTIONS * self.scale.resolution_mm,
            ),
        }
    }

    /// What the sensor sees of the part's `surface` (model frame) at `pose`: the points it
    /// would see unhidden by the scene, in a cell it measured or beside one (a shadow
    /// confirms nothing and contradicts nothing).
    pub(crate) fn seen_surface(
        &self,
        surface: &OrientedPoints,
        pose: &Isometry3<f64>,
    ) -> SeenSurface {
        let tolerance = self.scale.tolerance_mm;
        SeenSurface(
            self.grid
                .measured_model_points(surface, pose, &self.view, tolerance)
                .into_iter()
                .map(|i| transform_point(pose, &surface.points[i as usize]))
                .collect(),
        )
    }

    /// How closely the scan confirms the points of `seen` that lie farther than `apart_mm`
    /// from the part's surface at `other` (model frame indexed by `surface_index`): their
    /// mean squared distance to the scan truncated at the view tolerance (mm^2), and how
    /// many there are.
    pub(crate) fn residual_apart_from(
        &self,
        seen: &SeenSurface,
        surface_index: &binpick_match::GridIndex,
        other: &Isometry3<f64>,
        apart_mm: f64,
    ) -> (f64, usize) {
        let tolerance = self.scale.tolerance_mm;
        let cap = (tolerance * tolerance) as f32;
        let apart = (apart_mm * apart_mm) as f32;
        let back = other.inverse();
        let (mut sum, mut n) = (0.0f64, 0usize);
        for q in &seen.0 {
            if !surface_index.any_within(&transform_point(&back, q), apart) {
                sum += f64::from(self.world_index.nearest(q).1.min(cap));
                n += 1;
            }
        }
        (if n == 0 { 0.0 } else { sum / n as f64 }, n)
    }

    /// How closely each of two poses explains the scan where either explains it: over the
    /// scene points within the tolerance of `a`'s or `b`'s seen surface and within
    /// `apart_mm` of either pose's part surface (`surface_index`, model frame), the mean
    /// squared distance to each pose's surface, truncated at the view tolerance (mm^2), and
    /// how many points that is. The scan's side of [`Self::residual_apart_from`]: a strip
    /// seen edge on has too few seen model points where a part and its turn differ, but
    /// the turn leaves the scan's end of the longer flange unexplained.
    pub(crate) fn scan_residuals(
        &self,
        a: (&SeenSurface, &Isometry3<f64>),
        b: (&SeenSurface, &Isometry3<f64>),
        surface_index: &binpick_match::GridIndex,
        apart_mm: f64,
    ) -> (f64, f64, usize) {
        let tolerance = self.scale.tolerance_mm;
        let cap = (tolerance * tolerance) as f32;
        let apart = (apart_mm * apart_mm) as f32;
        let mut near = Vec::new();
        let mut found = Vec::new();
        for q in a.0.0.iter().chain(&b.0.0) {
            self.world_index
                .within_into(q, tolerance as f32, &mut found);
            near.extend_from_slice(&found);
        }
        near.sort_unstable();
        near.dedup();
        let (back_a, back_b) = (a.1.inverse(), b.1.inverse());
        let (mut sum_a, mut sum_b, mut n) = (0.0f64, 0.0f64, 0usize);
        for &k in &near {
            let s = &self.world_points[k as usize];
            let da = surface_index.nearest_squared(&transform_point(&back_a, s));
            let db = surface_index.nearest_squared(&transform_point(&back_b, s));
            if da.min(db) <= apart {
                sum_a += f64::from(da.min(cap));
                sum_b += f64::from(db.min(cap));
                n += 1;
            }
        }
        if n == 0 {
            return (0.0, 0.0, 0);
        }
        (sum_a / n as f64, sum_b / n as f64, n)
    }

    /// The view tolerance, mm.
    pub(crate) fn tolerance_mm(&self) -> f64 {
        self.scale.tolerance_mm
    }

    /// Cells of the model's typical view (its view area over the cell area).
    pub(crate) fn typical_cells(&self) -> f64 {
        typical_cells(self.scale)
    }
}

/// Cells of the part's typical view at `scale` (its view area over the cell area).
pub(crate) fn typical_cells(scale: &DerivedScale) -> f64 {
    scale.part_view_area_mm2 / (scale.cell_mm * scale.cell_mm)
}

/// A pose showing fewer view cells than this at `scale` shows the sensor an edge.
pub(crate) fn edge_on_cells(scale: &DerivedScale) -> f64 {
    EDGE_ON_VIEW_SHARE * typical_cells(scale)
}

/// The farthest an ICP correspondence reaches: the coarse pass's distance, two sampling
/// steps, mm.
fn coarse_icp_distance_mm(scale: &DerivedScale) -> f64 {
    2.0 * scale.sampling_step_mm
}

/// Support points farther than this many noise sigmas off every bounding plane are a
/// part's lowest surface inside the support band.
const OFF_PLANE_NOISES: f64 = 2.0;

/// Cells of the grid that finds the support near the parts, at most.
const NEAR_SUPPORT_MAX_CELLS: f64 = 4.0e6;

/// The ICP target, in the scene's order: the scene's points that are not support, and the
/// support points within about `reach_mm` of them that lie farther than `off_plane_mm` off
/// every bounding plane. A part resting on a floor or belt has its lowest surface inside the
/// support band; without it ICP pairs the lowest model points with the part's upper surface
/// and lifts the part off (from true poses moved 2.5 mm and 4 deg, 16 of 21 rods in a bin
/// accepted after refinement, 21 with the support). The plane itself is left out: paired
/// with a sheet's edges it pulls a bracket lying on it into the floor. Support farther than
/// `reach_mm` from every part is never paired either way (most of a belt).
fn icp_target(scene: &SceneSurface, reach_mm: f64, off_plane_mm: f64) -> Vec<Point> {
    let (points, support, world) = (&scene.points, &scene.support, &scene.world);
    let (lo, hi) = binpick_match::index::bounds(world);
    if world.is_empty() || reach_mm.is_nan() || reach_mm <= 0.0 {
        return world.to_vec();
    }
    let lo = lo.map(|c| c - reach_mm);
    let extent = [0, 1, 2].map(|a| hi[a] + reach_mm - lo[a]);
    // At least `reach_mm`, so that the cells beside a point's hold every point within reach.
    let cell = reach_mm.max((extent.iter().product::<f64>() / NEAR_SUPPORT_MAX_CELLS).cbrt());
    let dims = extent.map(|e| (e / cell) as usize + 1);
    let cell_of = |p: &Point| -> Option<[usize; 3]> {
        let mut c = [0usize; 3];
        for a in 0..3 {
            let x = (f64::from(p[a]) - lo[a]) / cell;
            if x.is_nan() || x < 0.0 || x as usize >= dims[a] {
                return None;
            }
            c[a] = x as usize;
        }
        Some(c)
    };
    let index = |c: [usize; 3]| (c[0] * dims[1] + c[1]) * dims[2] + c[2];
    let mut near = vec![false; dims.iter().product()];
    for p in world {
        let Some(c) = cell_of(p) else { continue };
        for x in c[0].saturating_sub(1)..=(c[0] + 1).min(dims[0] - 1) {
            for y in c[1].saturating_sub(1)..=(c[1] + 1).min(dims[1] - 1) {
                for z in c[2].saturating_sub(1)..=(c[2] + 1).min(dims[2] - 1) {
                    near[index([x, y, z])] = true;
                }
            }
        }
    }
    points
        .iter()
        .zip(support)
        .filter(|&(p, &s)| {
            !s || (cell_of(p).is_some_and(|c| near[index(c)])
                && scene.bounding.iter().all(|(n, d)| {
                    let q = Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                    (n.dot(&q) + d).abs() > off_plane_mm
                }))
        })
        .map(|(p, _)| *p)
        .collect()
}

/// The bounding planes (normals towards the parts) that can carry a part: not one facing
/// away from the sensor (`towards_sensor`), a bin's rim, which parts heaped high stick out
/// past; nor one in front of a parallel plane by less than `diameter_mm`, RANSAC laid across
/// the tops of a layer of flat parts on the floor (rings 4 mm thick), which bounds the rest
/// by their points while a part on the floor lies behind it by its thickness.
fn sink_planes(
    planes: &[(Vector3<f64>, f64)],
    diameter_mm: f64,
    towards_sensor: &Vector3<f64>,
) -> Vec<(Vector3<f64>, f64)> {
    let parallel = PARALLEL_DEG.to_radians().cos();
    planes
        .iter()
        .enumerate()
        .filter(|&(i, &(n, d))| {
            let on_plane = -d * n;
            if n.dot(towards_sensor) < -parallel {
                return false;
            }
            !planes.iter().enumerate().any(|(j, &(m, e))| {
                let ahead = m.dot(&on_plane) + e;
                j != i && n.dot(&m) > parallel && ahead > 0.0 && ahead < diameter_mm
            })
        })
        .map(|(_, &p)| p)
        .collect()
}

/// How far behind a support plane a model point counts as sunk, mm.
pub(crate) fn sunk_depth_mm(scale: &DerivedScale) -> f64 {
    SUPPORT_TOLERANCES * scale.tolerance_mm
}

/// For each support plane (`a x + b y + c z + d = 0`), whether it bounds the parts, with its
/// normal turned towards them: it does when (almost) all the scene's non-support points (of
/// `points`, where `support` is false) lie on one side of it, beyond `depth` mm
/// (`MAX_BEHIND_RATIO`), or when those behind it are as few as a sensor's outliers behind the
/// plane's own points (the support points within `on_plane_mm`; `MAX_OUTLIER_RATIO`: a few
/// thin rods on a large floor). A plane with parts on both sides
/// (RANSAC laid across the tops of a layer of parts, say) bounds nothing.
pub(crate) fn bounding_planes(
    planes: &[[f64; 4]],
    points: &[Point],
    support: &[bool],
    depth: f64,
    on_plane_mm: f64,
) -> Vec<Option<(Vector3<f64>, f64)>> {
    let side_of = |on_support: bool| {
        points
            .iter()
            .zip(support)
            .filter_map(move |(p, &s)| (s == on_support).then_some(p))
    };
    planes
        .iter()
        .map(|&[a, b, c, d]| {
            let n = Vector3::new(a, b, c);
            let (mut front, mut behind) = (0usize, 0usize);
            for p in side_of(false) {
                let side = n.dot(&to_point3(p).coords) + d;
                front += usize::from(side > depth);
                behind += usize::from(side < -depth);
            }
            let (major, minor, sign) = if front >= behind {
                (front, behind, 1.0)
            } else {
                (behind, front, -1.0)
            };
            // The plane's own points are counted only when the share alone does not do.
            let few = minor as f64 <= MAX_BEHIND_RATIO * major as f64 || {
                let on_plane = side_of(true)
                    .filter(|p| (n.dot(&to_point3(p).coords) + d).abs() <= on_plane_mm)
                    .count();
                minor as f64 <= MAX_OUTLIER_RATIO * on_plane as f64
            };
            (major > 0 && few).then_some((n * sign, d * sign))
        })
        .collect()
}

/// A view verdict as reported in a detection.
pub(crate) fn view_check(s: &ViewScore) -> ViewCheck {
    let share = |n: u32| {
        if s.visible == 0 {
            0.0
        } else {
            f64::from(n) / f64::from(s.visible)
        }
    };
    ViewCheck {
        visibility: share(s.explained),
        free_space: share(s.free_space),
        covered: share(s.covered),
        missing: share(s.missing),
        occluded: share(s.occluded),
        wrong_normal: share(s.wrong_normal),
        continued: s.continued_ratio(),
        fit: s.mean_fit(),
        acceptance_fit: s.mean_acceptance_fit(),
        visible_cells: s.visible,
        below_support: s.below_support_ratio(),
        sunk_mm: s.sunk_mm,
        on_support: s.support_explained_ratio(),
        contested: 0.0,
        crossing: s.crossing_per_explained(),
        outside: f64::from(s.outside) / f64::from(s.view_cells().max(1)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn icp_aligns_onto_the_parts_and_their_lowest_surface_in_the_support_band() {
        // A floor z = 0 (support) 200 mm wide; a rod across it from x = 40 to 80, its
        // points above the band (not support) and its lowest flanks at z = 1.5-2.5 inside it
        // (support); a noise point 2 mm above the floor far from the rod.
        let mut points: Vec<Point> = Vec::new();
        let mut support = Vec::new();
        for i in 0..200 {
            for j in 0..200 {
                points.push([i as f32, j as f32, 0.1 * ((i + j) % 3) as f32 - 0.1]);
                support.push(true);
            }
        }
        let rod: Vec<Point> = (40..80)
            .flat_map(|x| [[x as f32, 100.0, 8.0], [x as f32, 97.0, 5.0]])
            .collect();
        let flanks: Vec<Point> = (40..80)
            .map(|x| [x as f32, 96.0, 1.5 + (x % 2) as f32])
            .collect();
        points.extend(&rod);
        support.extend(rod.iter().map(|_| false));
        points.extend(&flanks);
        support.extend(flanks.iter().map(|_| true));
        points.push([170.0, 20.0, 2.0]);
        support.push(true);
        let scene = SceneSurface {
            world: rod.clone(),
            bounding: vec![(Vector3::z(), 0.0)],
            ribbons: Vec::new(),
            normals: vec![[f32::NAN; 3]; points.len()],
            view_normals: vec![[f32::NAN; 3]; points.len()],
            points,
            support,
        };
        let target = icp_target(&scene, 7.7, 1.2);
        let mut expected = rod.clone();
        expected.extend(&flanks);
        assert_eq!(target.len(), expected.len(), "{target:?}");
        assert!(expected.iter().all(|p| target.contains(p)));
        // Without a support plane to measure from, every support point near the parts joins
        // (none here is farther than 1.2 mm off a plane that is not there), and none far off.
        let unbounded = SceneSurface {
            bounding: Vec::new(),
            ..scene
        };
        let all_near = icp_target(&unbounded, 7.7, 1.2);
        assert!(all_near.len() > expected.len());
        assert!(!all_near.contains(&[170.0, 20.0, 2.0]));
        assert!(
            all_near
                .iter()
                .all(|p| (p[1] - 98.0).abs() < 2.0 * 7.7 * 3f32.sqrt() + 2.0)
        );
    }

    #[test]
    fn a_layer_of_parts_on_the_floor_and_a_bins_rim_carry_no_part_and_the_walls_do() {
        let floor = (Vector3::z(), 0.2);
        let layer = (Vector3::new(0.005, -0.019, 1.0).normalize(), -3.35);
        let rim = (-Vector3::z(), 80.0);
        let wall = (Vector3::x(), 130.0);
        let up = Vector3::z();
        let kept = sink_planes(&[floor, layer, rim, wall], 50.0, &up);
        assert_eq!(kept, vec![floor, wall]);
        // A shelf a part's size above the floor is a support of its own.
        let shelf = (Vector3::z(), -60.0);
        assert_eq!(sink_planes(&[floor, shelf], 50.0, &up).len(), 2);
    }

    #[test]
    fn a_large_floor_bounds_a_few_thin_parts_despite_its_outliers_and_a_layer_does_not() {
        let grid = |n: usize, z: f32| -> Vec<Point> {
            (0..n)
                .map(|i| [(i % 200) as f32, (i / 200) as f32, z])
                .collect()
        };
        // 1000 points of rods 5 mm above a 30 000-point floor, 60 outliers 10-25 mm below.
        let floor = grid(30_000, 0.0);
        let mut world = grid(1000, 5.0);
        world.extend((0..60).map(|i| [i as f32, 0.0, -10.0 - (i % 16) as f32]));
        let planes = [[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 1.0, -8.0]];
        // The scene: `world` (not support) and then `on_support`.
        let bounding = |planes: &[[f64; 4]], world: &[Point], on_support: &[Point]| {
            let mask: Vec<bool> = (0..world.len() + on_support.len())
                .map(|i| i >= world.len())
                .collect();
            bounding_planes(planes, &[world, on_support].concat(), &mask, 3.0, 1.0)
        };
        assert_eq!(
            bounding(&planes[..1], &world, &floor),
            vec![Some((Vector3::z(), 0.0))]
        );
        // Without the floor's own points, 6 % behind it is too many.
        assert_eq!(bounding(&planes[..1], &world, &[]), vec![None]);
        // A plane across the tops of a layer (800 of its own points, 8 mm up) with rods
        // stacked 4 mm above it and 100 rod points 4 mm below bounds nothing.
        world.extend(grid(300, 12.0));
        world.extend(grid(100, 4.0));
        let on = [floor, grid(800, 8.0)].concat();
        assert_eq!(bounding(&planes[1..], &world, &on), vec![None]);
    }
}
