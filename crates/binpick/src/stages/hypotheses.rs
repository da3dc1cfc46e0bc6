//! Scene voting, step 1: pose hypotheses from the whole scene. The model's point pairs are
//! filed once per working scale ([`VotingModel`]); the scene is sampled at the same step with
//! PCL's `UniformSampling` and `NormalEstimationOMP`; every reference point votes
//! (Drost et al. 2010) and the votes are clustered into poses under the part's symmetries.

use nalgebra::{Isometry3, Point3, Vector3};

use binpick_cloud::{Point, to_point3};
use binpick_match::{
    OrientedPoints, PointIndex, PoseCluster, PoseClustering, PpfConfig, PpfModel, cluster_poses,
    subsample_by_facing,
};
use binpick_pcl::IcpParams;

use crate::error::{Error, Result, matching, pcl};
use crate::params::VotingConfig;
use crate::result::DerivedScale;
use crate::stages::model::{near_symmetries, scan_cannot_tell_turns, self_matching_turns};
use crate::stages::part::{Part, PartSource};
use crate::stages::preprocess::plane_distance_mm;

/// Model points a near-symmetry is judged on.
const SYMMETRY_SAMPLE_POINTS: usize = 600;
/// Directions the model's extreme points are found along (its deepest point behind a plane:
/// 256 leave at most about 7 deg between a plane's normal and the nearest direction).
const EXTREME_DIRECTIONS: usize = 256;

/// A near-symmetric turn within this angle ...
const DECLARED_SAME_DEG: f64 = 10.0;
/// ... and this share of the diameter of a declared symmetry is that symmetry.
const DECLARED_SAME_DIAMETERS: f64 = 0.05;

/// A scanned part's rendered surface is sampled at this share of the view's cell.
const SCAN_DENSE_CELLS: f64 = 0.5;

/// The part prepared for one working scale.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub(crate) struct VotingModel {
    /// The part's surface at the working resolution (what is rendered and aligned).
    pub dense: OrientedPoints,
    pub table: PpfModel,
    /// The part's rims ([`model_rims`]), when it has some.
    pub rims: Option<Rims>,
    /// Centroid of the surface, model frame.
    pub centre: Point3<f64>,
    /// Half-turns about the principal axes, refined by ICP, that map the part nearly onto
    /// itself ([`self_matching_turns`](crate::stages::model::self_matching_turns)).
    pub near_symmetries: Vec<Isometry3<f64>>,
    /// The points of `dense` farthest out along a spread of directions: the part's deepest
    /// point behind any plane is one of them, or within a sample spacing of one.
    pub extremes: Vec<Point3<f64>>,
    /// A scanned part that cannot be told from one of its near-symmetric turns
    /// ([`scan_cannot_tell_turns`]): no first pick unless `pick_turn_ambiguous`.
    pub turn_ambiguous: bool,
}

impl VotingModel {
    /// Samples the part at `scale` and files its point pairs.
    pub(crate) fn new(part: &Part, scale: &DerivedScale, cfg: &VotingConfig) -> Result<Self> {
        // Both sides of a thin part must survive the sampling (each face is seen from its own
        // side): sampled per facing, not per cell.
        let at_cell = subsample_by_facing(&part.surface, scale.resolution_mm);
        let samples = subsample_by_facing(&at_cell, scale.sampling_step_mm);
        // A scan's points lie on its scanner's regular lattice, which beats against the
        // subsampling's voxels: at one point per cell a fifth of the view's cells stay
        // empty, and the scene carries on past the holes' edges as past an outline. Kept
        // at half the cell, a scan renders whole (a sampled mesh leaves a tenth empty).
        let dense = if part.source == PartSource::Scan {
            subsample_by_facing(&part.surface, SCAN_DENSE_CELLS * scale.resolution_mm)
        } else {
            at_cell
        };
        let pairs = PpfConfig {
            distance_step_mm: scale.sampling_step_mm,
            feature_angle_bins: cfg.feature_angle_bins,
            alpha_bins: cfg.alpha_bins,
            max_pair_distance_mm: part.size.diameter_mm,
            spread: cfg.spread,
            max_pairs_per_bin: cfg.max_pairs_per_bin,
        };
        let table =
            PpfModel::new(&samples, pairs.clone()).map_err(matching("model point pairs"))?;
        let (rim_profiles, on_rim) =
            model_rims(&dense, scale.sampling_step_mm, part.size.diameter_mm)?;
        let rim_samples = subsample_by_facing(&rim_profiles, scale.sampling_step_mm);
        let rims = if cfg.rim_hypotheses > 0 && rim_samples.len() >= MIN_RIM_SAMPLES {
            Some(Rims {
                table: PpfModel::new(&rim_samples, pairs).map_err(matching("model rim pairs"))?,
                on_rim,
            })
        } else {
            None
        };
        let kp: Vec<Point> = binpick_cloud::strided_points(&dense.points, SYMMETRY_SAMPLE_POINTS)
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let eps = 1e-6 * scale.resolution_mm * scale.resolution_mm;
        let half_turns: Vec<Isometry3<f64>> = near_symmetries(
            &dense.points,
            &kp,
            part.size.diameter_mm,
            &|turn: &Isometry3<f64>| IcpParams {
                initial: binpick_pcl::row_major(turn),
                max_correspondence_distance: 0.1 * part.size.diameter_mm,
                max_iterations: 30,
                transformation_epsilon: eps,
                batch_correspondences: true,
                relative_mse: 1e-4,
                reciprocal: false,
            },
        )?
        .into_iter()
        // A declared symmetry is not a trap (a ring's half turn is one).
        .filter(|turn| {
            part.symmetries.transforms().iter().all(|s| {
                let moved = s.inverse() * turn;
                moved.rotation.angle().to_degrees() > DECLARED_SAME_DEG
                    || moved.translation.vector.norm()
                        > DECLARED_SAME_DIAMETERS * part.size.diameter_mm
            })
        })
        .collect();
        let near_symmetries = self_matching_turns(part, half_turns)?;
        let turn_ambiguous = scan_cannot_tell_turns(part, &near_symmetries)?;
        Ok(Self {
            centre: part.centre(),
            extremes: extreme_points(&dense.points, EXTREME_DIRECTIONS),
            turn_ambiguous,
            dense,
            table,
            rims,
            near_symmetries,
        })
    }
}

/// The model's points farthest out along `directions` directions spread over the sphere
/// (Fibonacci lattice), without repeats, in first-found order.
fn extreme_points(points: &[Point], directions: usize) -> Vec<Point3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut picked: Vec<usize> = Vec::new();
    for k in 0..directions {
        let z = 1.0 - 2.0 * (k as f64 + 0.5) / directions as f64;
        let r = (1.0 - z * z).sqrt();
        let u = Vector3::new(
            r * (golden * k as f64).cos(),
            r * (golden * k as f64).sin(),
            z,
        );
        let far = points.iter().enumerate().max_by(|a, b| {
            let along = |p: &Point| u.dot(&to_point3(p).coords);
            along(a.1).total_cmp(&along(b.1))
        });
        if let Some((i, _)) = far
            && !picked.contains(&i)
        {
            picked.push(i);
        }
    }
    picked.into_iter().map(|i| to_point3(&points[i])).collect()
}

/// A part's rims: the point pairs of their profiles and which points of the dense surface
/// lie on them.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub(crate) struct Rims {
    pub table: PpfModel,
    /// Per point of [`VotingModel::dense`]: it lies on a rim.
    pub on_rim: Vec<bool>,
}

/// `points` thinned by PCL's `UniformSampling` at `leaf` (the point nearest each cell's
/// centre is kept, with its normal).
pub(crate) fn subsample(points: &OrientedPoints, leaf: f64) -> Result<OrientedPoints> {
    let idx = binpick_pcl::uniform_sampling(&points.points, leaf as f32)
        .map_err(pcl("uniform sampling"))?;
    Ok(OrientedPoints {
        points: idx.iter().map(|&i| points.points[i as usize]).collect(),
        normals: idx.iter().map(|&i| points.normals[i as usize]).collect(),
    })
}

/// The search indexes the scene's normals are estimated with: PCL's kd-tree (its normals)
/// and the view normals' (kiddo), over the points whose normals are estimated and every
/// point within the normal radius of them. A belt is most of its scan and takes its plane's
/// normal, so only its band around the parts is indexed: the neighbourhoods searched are the
/// same, and building the trees over all of it cost a tenth of a belt scan's time.
pub(crate) struct NormalIndexes {
    pcl: binpick_pcl::IndexedCloud,
    view: PointIndex,
    /// Index into the scene's points of each indexed point, ascending.
    members: Vec<u32>,
}

impl NormalIndexes {
    /// Both indexes over the points of `points` within `radius_mm` of any of `queried`
    /// (indices into `points`; a superset: every point of a grid cell of that side next to
    /// a queried point's), built side by side.
    pub(crate) fn around(points: &[Point], queried: &[u32], radius_mm: f64) -> Result<Self> {
        use rayon::prelude::*;
        use std::collections::HashSet;
        use std::hash::BuildHasherDefault;

        use crate::stages::preprocess::{CellHasher, floor_to_i64};
        // A little wider than the radius: a point at the radius is never two cells away
        // after rounding.
        let side = radius_mm * 1.001;
        let cell = |p: &Point| p.map(|c| floor_to_i64(f64::from(c) / side));
        let mut near: HashSet<[i64; 3], BuildHasherDefault<CellHasher>> = HashSet::default();
        for &q in queried {
            let [x, y, z] = cell(&points[q as usize]);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        near.insert([
                            x.saturating_add(dx),
                            y.saturating_add(dy),
                            z.saturating_add(dz),
                        ]);
                    }
                }
            }
        }
        let members: Vec<u32> = (0..points.len() as u32)
            .into_par_iter()
            .filter(|&i| near.contains(&cell(&points[i as usize])))
            .collect();
        let indexed: Vec<Point> = members.iter().map(|&i| points[i as usize]).collect();
        let (pcl, view) = rayon::join(
            || binpick_pcl::IndexedCloud::new(&indexed).map_err(pcl("scene kd-tree")),
            || PointIndex::new("scene", &indexed).map_err(matching("scene normals")),
        );
        Ok(Self {
            pcl: pcl?,
            view: view?,
            members,
        })
    }

    /// Where point `i` of the scene is among the indexed ones.
    fn position(&self, i: u32) -> Option<u32> {
        self.members.binary_search(&i).ok().map(|k| k as u32)
    }
}

/// Normals of `points`, oriented towards `viewpoint` (NaN where undefined): PCL's
/// `NormalEstimationOMP` at the derived radius, searching all of them, except at support
/// points (`support[i]`) whose nearest support plane in `planes` (`a x + b y + c z + d = 0`,
/// unit normal; with `true` where the plane bounds the parts) bounds the parts: those take
/// the plane's normal. A belt is most of its scan and its plane is known, so estimating its
/// normals would cost most of this stage for nothing; a plane that does not bound the parts
/// may have been laid across their tops, where the surface is not the plane. Also returns
/// the indexes searched, for [`view_normals`].
pub(crate) fn scene_normals(
    points: &[Point],
    support: &[bool],
    planes: &[([f64; 4], bool)],
    scale: &DerivedScale,
    viewpoint: [f64; 3],
    threads: u32,
) -> Result<(Vec<[f32; 3]>, NormalIndexes)> {
    let vp = Vector3::from(viewpoint);
    let on_plane = |p: &Point| -> Option<[f32; 3]> {
        let q = to_point3(p).coords;
        let distance = |c: &[f64; 4]| plane_distance_mm(c, p).abs();
        let (c, bounds) = planes
            .iter()
            .min_by(|a, b| distance(&a.0).total_cmp(&distance(&b.0)))?;
        bounds.then(|| {
            let n = Vector3::new(c[0], c[1], c[2]);
            // As PCL flips: towards the viewpoint.
            let n = if n.dot(&(vp - q)) < 0.0 { -n } else { n };
            [n.x as f32, n.y as f32, n.z as f32]
        })
    };
    let mut normals: Vec<Option<[f32; 3]>> = points
        .iter()
        .zip(support)
        .map(|(p, &s)| if s { on_plane(p) } else { None })
        .collect();
    let estimate: Vec<u32> = (0..points.len() as u32)
        .filter(|&i| normals[i as usize].is_none())
        .collect();
    let indexes = NormalIndexes::around(points, &estimate, scale.normal_radius_mm)?;
    // Every point estimated is indexed (`around` keeps the queried points).
    let at: Vec<u32> = estimate
        .iter()
        .map(|&i| indexes.position(i))
        .collect::<Option<_>>()
        .ok_or_else(|| Error::Input {
            what: "scene normals",
            kind: crate::error::InputKind::Degenerate,
            message: "a point whose normal is estimated is missing from the kd-tree".into(),
        })?;
    let estimated = indexes
        .pcl
        .normals_at(
            &at,
            scale.normal_radius_mm as f32,
            viewpoint.map(|c| c as f32),
            threads,
        )
        .map_err(pcl("scene normals"))?;
    for (&i, n) in estimate.iter().zip(&estimated) {
        normals[i as usize] = Some(n.normal);
    }
    let normals = normals
        .into_iter()
        .map(|n| n.unwrap_or([f32::NAN; 3]))
        .collect();
    Ok((normals, indexes))
}

/// A neighbourhood is a ribbon when its second spread (variance) is under this share of its
/// first: a strip a few points wide (a sheet seen edge on), where a plane fitted over the
/// neighbourhood cannot tell the strip's face from its width.
const RIBBON_SPREAD_RATIO: f64 = 0.15;

/// The scene's normals as the view judges a pose by them: `normals`, except that a part's
/// point (not `support`) whose neighbourhood within `radius` (mm) is a ribbon
/// ([`RIBBON_SPREAD_RATIO`]) faces the sensor at `viewpoint` across the ribbon's axis: a
/// strip the sensor sees faces it. (Voting keeps the fitted normals.)
/// `indexes` are [`scene_normals`]'s.
pub(crate) fn view_normals(
    points: &[Point],
    indexes: &NormalIndexes,
    support: &[bool],
    normals: &[[f32; 3]],
    radius: f64,
    viewpoint: [f64; 3],
) -> Result<Vec<[f32; 3]>> {
    use rayon::prelude::*;
    let vp = Vector3::from(viewpoint);
    Ok(points
        .par_iter()
        .zip(support)
        .zip(normals)
        .map_init(Vec::new, |near, ((p, &s), &n)| {
            if s {
                return n;
            }
            indexes.view.within_into(p, radius as f32, near);
            // In the scene's order, whatever the tree's.
            near.sort_unstable();
            let Some(axis) = Spread::of(
                near.iter()
                    .map(|&k| &points[indexes.members[k as usize] as usize]),
            )
            .and_then(|s| s.ribbon_axis()) else {
                return n;
            };
            let to_sensor = (vp - to_point3(p).coords).normalize();
            let across = to_sensor - axis * axis.dot(&to_sensor);
            let len = across.norm();
            if len > 1e-6 {
                let a = across / len;
                [a.x as f32, a.y as f32, a.z as f32]
            } else {
                n
            }
        })
        .collect())
}

/// The principal spreads (summed squares, mm^2, largest first) and axes of a set of points.
struct Spread {
    values: [f64; 3],
    axes: [Vector3<f64>; 3],
    mean: Vector3<f64>,
}

impl Spread {
    /// None for fewer than 3 points.
    fn of<'p>(points: impl Iterator<Item = &'p Point> + Clone) -> Option<Self> {
        let n = points.clone().count();
        if n < 3 {
            return None;
        }
        let mean = points
            .clone()
            .map(|p| to_point3(p).coords)
            .sum::<Vector3<f64>>()
            / n as f64;
        let cov = points
            .map(|q| {
                let d = to_point3(q).coords - mean;
                d * d.transpose()
            })
            .sum::<nalgebra::Matrix3<f64>>();
        let eig = nalgebra::SymmetricEigen::new(cov);
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        Some(Self {
            values: order.map(|k| eig.eigenvalues[k]),
            axes: order.map(|k| eig.eigenvectors.column(k).into_owned()),
            mean,
        })
    }

    /// The axis of a ribbon ([`RIBBON_SPREAD_RATIO`]).
    fn ribbon_axis(&self) -> Option<Vector3<f64>> {
        let [first, second, _] = self.values;
        (first > 0.0 && second < RIBBON_SPREAD_RATIO * first).then_some(self.axes[0])
    }

    /// The normal of a flat profile: a plane that the points fill in two directions
    /// ([`PROFILE_WIDTH`], [`PROFILE_FLATNESS`]).
    fn profile_normal(&self) -> Option<Vector3<f64>> {
        let [first, second, third] = self.values;
        (first > 0.0 && second > PROFILE_WIDTH * first && third < PROFILE_FLATNESS * second)
            .then_some(self.axes[2])
    }
}

/// Rims are fitted into profiles over this many diameters.
const RIM_PROFILE_DIAMETERS: f64 = 0.25;
/// A profile's second spread is at least this share of its first (a bend, not a line) ...
const PROFILE_WIDTH: f64 = 0.05;
/// ... and its third under this share of its second (flat).
const PROFILE_FLATNESS: f64 = 0.1;
/// A rim profile faces the sensor (or its face's normal) within 45 deg.
const RIM_FACING_COS: f64 = 0.7;
/// Fewer model rim samples than this make no rim table.
const MIN_RIM_SAMPLES: usize = 8;

/// The part's rims, with the normals of their profiles: the points of `dense` whose face
/// (neighbours within `radius`, mm, facing within 60 deg of theirs) is a ribbon, where the
/// rim points within a quarter of `diameter` (mm) form a flat profile facing as the face.
/// A Z bracket's rims are the 2 mm edges of its sheet: lying on its side, the sensor sees
/// one edge flat on, a strip whose pairs of points are all coplanar, which the table of the
/// whole part files with the pairs of its wide faces (and those outvote it).
pub(crate) fn model_rims(
    dense: &OrientedPoints,
    radius: f64,
    diameter: f64,
) -> Result<(OrientedPoints, Vec<bool>)> {
    use rayon::prelude::*;
    let index = PointIndex::new("model", &dense.points).map_err(matching("model rims"))?;
    let on_rim: Vec<bool> = dense
        .points
        .par_iter()
        .zip(&dense.normals)
        .map_init(Vec::new, |near, (p, n)| {
            index.within_into(p, radius as f32, near);
            let n = to_point3(n).coords;
            let face = near
                .iter()
                .filter(|&&k| to_point3(&dense.normals[k as usize]).coords.dot(&n) > 0.5)
                .map(|&k| &dense.points[k as usize]);
            Spread::of(face).and_then(|s| s.ribbon_axis()).is_some()
        })
        .collect();
    let rim: Vec<usize> = (0..dense.len()).filter(|&i| on_rim[i]).collect();
    let rim_points: Vec<Point> = rim.iter().map(|&i| dense.points[i]).collect();
    let facing: Vec<Vector3<f64>> = rim
        .iter()
        .map(|&i| to_point3(&dense.normals[i]).coords)
        .collect();
    let profiled = profiles(&rim_points, diameter, None, |k, normal| {
        let c = normal.dot(&facing[k]);
        (c.abs() > RIM_FACING_COS).then(|| normal * c.signum())
    });
    Ok((profiled, on_rim))
}

/// Whether the neighbourhood of `p` within `radius` (mm) among `points` (indexed by `index`;
/// `near` is scratch space) is a ribbon ([`RIBBON_SPREAD_RATIO`]).
pub(crate) fn is_ribbon(
    points: &[Point],
    index: &PointIndex,
    p: &Point,
    radius: f64,
    near: &mut Vec<u32>,
) -> bool {
    index.within_into(p, radius as f32, near);
    Spread::of(near.iter().map(|&k| &points[k as usize]))
        .and_then(|s| s.ribbon_axis())
        .is_some()
}

/// The scene's rims: the samples of `samples` whose neighbourhood in `world` within
/// `radius` (mm) is a ribbon, where those within a quarter of `diameter` (mm) form a flat
/// profile facing the sensor at `viewpoint`, with the profile's normal (what votes over the
/// rim table); and every point of `world` within `radius` of a ribbon sample whose own
/// neighbourhood is a ribbon (what rim poses are aligned on).
pub(crate) fn scene_rims(
    world: &[Point],
    samples: &OrientedPoints,
    radius: f64,
    diameter: f64,
    viewpoint: [f64; 3],
) -> Result<(OrientedPoints, Vec<Point>)> {
    use rayon::prelude::*;
    if world.is_empty() || samples.is_empty() {
        return Ok((OrientedPoints::default(), Vec::new()));
    }
    let vp = Vector3::from(viewpoint);
    let index = PointIndex::new("scene", world).map_err(matching("scene rims"))?;
    let ribbon = |p: &Point, near: &mut Vec<u32>| is_ribbon(world, &index, p, radius, near);
    let on_rim: Vec<bool> = samples
        .points
        .par_iter()
        .map_init(Vec::new, |near, p| ribbon(p, near))
        .collect();
    let rim_points: Vec<Point> = (0..samples.len())
        .filter(|&i| on_rim[i])
        .map(|i| samples.points[i])
        .collect();
    let ribbons = match PointIndex::new("rims", &rim_points) {
        Ok(rims) => {
            let near_rim = (radius * radius) as f32;
            world
                .par_iter()
                .map_init(Vec::new, |near, p| {
                    (rims.nearest(p).1 <= near_rim && ribbon(p, near)).then_some(*p)
                })
                .flatten()
                .collect()
        }
        Err(_) => Vec::new(),
    };
    let level = RimLevel {
        viewpoint: vp,
        band_mm: radius,
    };
    let profiled = profiles(&rim_points, diameter, Some(&level), |k, normal| {
        let to_sensor = (vp - to_point3(&rim_points[k]).coords).normalize();
        let c = normal.dot(&to_sensor);
        (c.abs() > RIM_FACING_COS).then(|| normal * c.signum())
    });
    Ok((profiled, ribbons))
}

/// The points of `rim` that lie in a flat profile of their neighbours within a quarter of
/// `diameter`, with the normal `orient` gives the profile's (None drops the point). With a
/// `level`, a point whose neighbours are not flat tries the profile at its own depth.
fn profiles(
    rim: &[Point],
    diameter: f64,
    level: Option<&RimLevel>,
    orient: impl Fn(usize, Vector3<f64>) -> Option<Vector3<f64>> + Sync,
) -> OrientedPoints {
    use rayon::prelude::*;
    let Ok(index) = PointIndex::new("rims", rim) else {
        return OrientedPoints::default();
    };
    let radius = (RIM_PROFILE_DIAMETERS * diameter) as f32;
    let normals: Vec<Option<Vector3<f64>>> = rim
        .par_iter()
        .enumerate()
        .map_init(Vec::new, |near, (k, p)| {
            index.within_into(p, radius, near);
            Spread::of(near.iter().map(|&j| &rim[j as usize]))
                .and_then(|s| s.profile_normal())
                .and_then(|n| orient(k, n))
                .or_else(|| {
                    level
                        .and_then(|l| l.profile_normal(rim, near, p))
                        .and_then(|n| orient(k, n))
                })
        })
        .collect();
    let (points, normals) = rim
        .iter()
        .zip(normals)
        .filter_map(|(p, n)| n.map(|n| (*p, [n.x as f32, n.y as f32, n.z as f32])))
        .unzip();
    OrientedPoints { points, normals }
}

/// A scene rim's profile at one level. A part standing on the edge of its sheet shows the
/// sensor that edge, and at a grazing angle strips of its faces below it, which pass the
/// ribbon test too: over a quarter of the diameter they tilt the profile out of flat
/// (traced on a Z bracket standing on its profile: 1 of 51 ribbon samples kept). The
/// profile is then fitted to the rim samples within `band_mm` of the point's depth towards
/// the sensor, and taken again over those within `band_mm` of that plane.
struct RimLevel {
    viewpoint: Vector3<f64>,
    band_mm: f64,
}

impl RimLevel {
    /// The profile's normal at `p` from its neighbours `near` (indices into `rim`).
    fn profile_normal(&self, rim: &[Point], near: &[u32], p: &Point) -> Option<Vector3<f64>> {
        let q = to_point3(p).coords;
        let to_sensor = (self.viewpoint - q).try_normalize(1e-12)?;
        let points = || near.iter().map(|&j| &rim[j as usize]);
        let level = Spread::of(
            points().filter(|r| (to_point3(r).coords - q).dot(&to_sensor).abs() <= self.band_mm),
        )?;
        // A line at that depth gives no plane: the profile must bend there.
        let [first, second, _] = level.values;
        if !(first > 0.0 && second > PROFILE_WIDTH * first) {
            return None;
        }
        let (normal, mean) = (level.axes[2], level.mean);
        Spread::of(
            points().filter(|r| (to_point3(r).coords - mean).dot(&normal).abs() <= self.band_mm),
        )?
        .profile_normal()
    }
}

/// The scene's samples at the sampling step (the `world` points with their normals);
/// samples without a normal are dropped.
pub(crate) fn scene_samples(world: OrientedPoints, scale: &DerivedScale) -> Result<OrientedPoints> {
    Ok(subsample(&world, scale.sampling_step_mm)?.with_defined_normals())
}

/// Votes over the scene samples and the strongest pose clusters, best first; then, when
/// the part has rims, the strongest of the rim samples' own votes over the rim table.
pub(crate) fn vote(
    model: &VotingModel,
    part: &Part,
    samples: &OrientedPoints,
    rim_samples: &OrientedPoints,
    scale: &DerivedScale,
    cfg: &VotingConfig,
) -> Result<Voted> {
    let (votes, mut clusters) = vote_table(&model.table, model, part, samples, scale, cfg)?;
    clusters.truncate(cfg.hypotheses);
    let first_rim = clusters.len();
    let Some(rims) = &model.rims else {
        return Ok(Voted {
            votes,
            clusters,
            first_rim,
        });
    };
    let (rim_votes, mut rim_clusters) =
        vote_table(&rims.table, model, part, rim_samples, scale, cfg)?;
    rim_clusters.truncate(cfg.rim_hypotheses);
    clusters.extend(rim_clusters);
    Ok(Voted {
        votes: votes + rim_votes,
        clusters,
        first_rim,
    })
}

/// The hypotheses of one voting round.
pub(crate) struct Voted {
    /// Votes cast.
    pub votes: usize,
    /// Pose clusters, the whole part's best first, then the rims'.
    pub clusters: Vec<PoseCluster>,
    /// `clusters[first_rim..]` came from the rims.
    pub first_rim: usize,
}

fn vote_table(
    table: &PpfModel,
    model: &VotingModel,
    part: &Part,
    samples: &OrientedPoints,
    scale: &DerivedScale,
    cfg: &VotingConfig,
) -> Result<(usize, Vec<PoseCluster>)> {
    if samples.len() < 3 {
        return Ok((0, Vec::new()));
    }
    let index = PointIndex::new("scene samples", &samples.points).map_err(matching("scene"))?;
    let votes = table
        .vote(
            samples,
            &index,
            &binpick_match::VotingConfig {
                reference_stride: cfg.reference_stride,
                peaks_per_reference: cfg.peaks_per_reference,
                secondary_peak_ratio: cfg.secondary_peak_ratio,
                distinct_pairs: cfg.distinct_pairs,
            },
        )
        .map_err(matching("voting"))?;
    let clusters = cluster_poses(
        &votes,
        &model.centre,
        &part.symmetries,
        &PoseClustering {
            translation_mm: cfg.cluster_translation_diameters * scale.model_diameter_mm,
            rotation_deg: cfg.cluster_rotation_deg,
        },
    )
    .map_err(matching("pose clustering"))?;
    Ok((votes.len(), clusters))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Params;
    use crate::stages::scale::PartSize;

    #[test]
    fn the_extreme_points_hold_the_deepest_point_along_any_axis() {
        // A 40 x 20 x 4 mm box sampled on a 1 mm grid over its volume.
        let mut points: Vec<Point> = Vec::new();
        for i in 0..=40 {
            for j in 0..=20 {
                for k in 0..=4 {
                    points.push([i as f32 - 20.0, j as f32 - 10.0, k as f32 - 2.0]);
                }
            }
        }
        let extremes = extreme_points(&points, EXTREME_DIRECTIONS);
        assert!(extremes.len() < 100, "{}", extremes.len());
        for axis in [Vector3::x(), Vector3::y(), Vector3::z(), -Vector3::z()] {
            let lowest = |ps: &mut dyn Iterator<Item = f64>| ps.fold(f64::MAX, f64::min);
            let all = lowest(&mut points.iter().map(|p| axis.dot(&to_point3(p).coords)));
            let ext = lowest(&mut extremes.iter().map(|p| axis.dot(&p.coords)));
            assert_eq!(all, ext, "along {axis:?}");
        }
    }

    /// A tilted belt (z = 0.1 x) with a box standing on it, scanned from above.
    fn belt_with_box() -> (Vec<Point>, Vec<bool>, [f64; 4]) {
        let tilt = 0.1f64;
        let mut points = Vec::new();
        let mut support = Vec::new();
        for i in 0..60 {
            for j in 0..60 {
                let (x, y) = (i as f32, j as f32);
                points.push([x, y, tilt as f32 * x]);
                support.push(true);
                // The box's top, 10 mm above the belt.
                if (20..40).contains(&i) && (20..40).contains(&j) {
                    points.push([x + 0.5, y + 0.5, tilt as f32 * (x + 0.5) + 10.0]);
                    support.push(false);
                }
            }
        }
        let norm = (1.0 + tilt * tilt).sqrt();
        (points, support, [-tilt / norm, 0.0, 1.0 / norm, 0.0])
    }

    #[test]
    fn support_of_a_bounding_plane_takes_its_normal_and_other_points_are_estimated() {
        let (points, support, plane) = belt_with_box();
        let part = PartSize {
            diameter_mm: 40.0,
            view_area_mm2: 400.0,
            curvature_radius_mm: None,
        };
        let scale = DerivedScale::derive(&part, None, &Params::default()).unwrap();
        let radius = scale.normal_radius_mm as f32;
        let above = [30.0, 30.0, 1e6];
        let normals = |planes: &[([f64; 4], bool)], threads| {
            scene_normals(&points, &support, planes, &scale, above, threads).unwrap()
        };
        let (both, indexes) = normals(&[(plane, true)], 2);
        let flipped = plane.map(|c| -c);
        let (other, _) = normals(&[(flipped, true)], 1);
        let estimated =
            binpick_pcl::estimate_normals(&points, radius, above.map(|c| c as f32), 1).unwrap();
        // PCL over the points indexed: the box and the belt within the radius of it.
        let indexed: Vec<Point> = indexes
            .members
            .iter()
            .map(|&i| points[i as usize])
            .collect();
        assert!(indexed.len() < points.len());
        let estimated_there =
            binpick_pcl::estimate_normals(&indexed, radius, above.map(|c| c as f32), 1).unwrap();
        let up = plane.map(|c| c as f32);
        for (i, s) in support.iter().enumerate() {
            if *s {
                // The plane's normal, turned towards the sensor whichever way it was given.
                for n in [both[i], other[i]] {
                    for k in 0..3 {
                        assert!((n[k] - up[k]).abs() < 1e-6, "point {i}: {n:?}");
                    }
                }
                continue;
            }
            // Every point within the radius is indexed ...
            let d2 = |q: &Point| (0..3).map(|k| (q[k] - points[i][k]).powi(2)).sum::<f32>();
            for (j, q) in points.iter().enumerate() {
                if d2(q) <= radius * radius {
                    assert!(indexes.position(j as u32).is_some(), "{j} near {i}");
                }
            }
            // ... so the normal is PCL's estimate there, bit for bit, and PCL's over the
            // whole scan up to the order the neighbours are summed in.
            let k = indexes.position(i as u32).unwrap() as usize;
            assert_eq!(
                both[i].map(f32::to_bits),
                estimated_there[k].normal.map(f32::to_bits)
            );
            for (a, b) in both[i].iter().zip(&estimated[i].normal) {
                assert!((a - b).abs() < 1e-5, "{i}");
            }
        }
        // A plane that does not bound the parts leaves its points to PCL: all indexed.
        let (kept, _) = normals(&[(plane, false)], 2);
        for (k, e) in kept.iter().zip(&estimated) {
            assert_eq!(k.map(f32::to_bits), e.normal.map(f32::to_bits));
        }
    }

    #[test]
    fn a_strip_seen_edge_on_faces_the_sensor_in_the_view_and_nothing_else_moves() {
        // Deterministic noise of about 0.6 mm.
        let noise = |k: usize| 0.6 * ((k as f32 * 12.9898).sin() * 43_758.547).fract();
        let mut points = Vec::new();
        let mut support = Vec::new();
        let mut normals = Vec::new();
        // A sheet's edge 40 mm up, two rows of a 2 mm scan wide, with sideways normals (what
        // a plane fitted across the strip and its noise can give).
        for i in 0..30 {
            for row in [0.0, 1.5] {
                let k = points.len();
                points.push([2.0 * i as f32, row, 40.0 + noise(k)]);
                support.push(false);
                normals.push([0.0, 1.0, 0.0]);
            }
        }
        let strip = points.len();
        // A tilted face of a part (z = 0.3 x + 10) with its fitted normals, and a floor strip.
        let tilted = {
            let n = Vector3::new(-0.3f32, 0.0, 1.0).normalize();
            [n.x, n.y, n.z]
        };
        for i in 0..20 {
            for j in 0..20 {
                let (x, y) = (2.0 * i as f32, 20.0 + 2.0 * j as f32);
                points.push([x, y, 0.3 * x + 10.0]);
                support.push(false);
                normals.push(tilted);
            }
        }
        for i in 0..30 {
            points.push([2.0 * i as f32, -30.0, 0.0]);
            support.push(true);
            normals.push([0.0, 1.0, 0.0]);
        }
        let above = [30.0, 0.0, 1e7];
        let everything: Vec<u32> = (0..points.len() as u32).collect();
        let indexes = NormalIndexes::around(&points, &everything, 5.75).unwrap();
        let view = view_normals(&points, &indexes, &support, &normals, 5.75, above).unwrap();
        // Away from its ends (within a radius of an end the neighbourhood is a short, wide
        // patch: the fitted normal stands).
        for (i, n) in view[..strip].iter().enumerate() {
            let x = points[i][0];
            if (6.0..=52.0).contains(&x) {
                assert!(n[2] > 0.99, "strip point {i}: {n:?}");
            }
        }
        for k in strip..points.len() {
            assert_eq!(
                view[k].map(f32::to_bits),
                normals[k].map(f32::to_bits),
                "{k}"
            );
        }
    }

    /// An L-shaped sheet 2 mm thick: a 30 mm leg along x and a 25 mm leg up z, 40 mm wide
    /// along y; every face sampled at 1 mm with its outward normal. Its two 2 mm edges along
    /// the L (the faces at y = 0 and y = 40) are its rims.
    fn angle_sheet() -> OrientedPoints {
        let mut points = Vec::new();
        let mut normals = Vec::new();
        // The profile: (x, z) along the L and the in-plane normal there.
        let mut profile = Vec::new();
        for i in 0..=30 {
            profile.push(([i as f32, 0.0], [0.0f32, 1.0]));
        }
        for k in 1..=25 {
            profile.push(([30.0, k as f32], [-1.0, 0.0]));
        }
        for &([x, z], [nx, nz]) in &profile {
            for t in [-1.0f32, 0.0, 1.0] {
                for (y, ny) in [(0.0f32, -1.0f32), (40.0, 1.0)] {
                    points.push([x + t * nx, y, z + t * nz]);
                    normals.push([0.0, ny, 0.0]);
                }
            }
            for j in 1..40 {
                for side in [-1.0f32, 1.0] {
                    points.push([x + side * nx, j as f32, z + side * nz]);
                    normals.push([side * nx, 0.0, side * nz]);
                }
            }
        }
        OrientedPoints { points, normals }
    }

    #[test]
    fn a_sheet_edge_is_a_rim_with_its_face_normal_and_a_wide_face_is_not() {
        let sheet = angle_sheet();
        let (rims, on_rim) = model_rims(&sheet, 5.0, 60.0).unwrap();
        assert_eq!(on_rim.len(), sheet.len());
        assert!(rims.len() > 60, "{} rim points", rims.len());
        for (p, n) in rims.points.iter().zip(&rims.normals) {
            // On an edge, facing as that edge does.
            let outward = if p[1] < 20.0 { -1.0 } else { 1.0 };
            assert!(p[1] == 0.0 || p[1] == 40.0, "{p:?}");
            assert!(n[1] * outward > 0.99, "{p:?}: {n:?}");
        }
        // The wide faces away from the edges are not rims.
        for (k, p) in sheet.points.iter().enumerate() {
            if (5.0..=35.0).contains(&p[1]) {
                assert!(!on_rim[k], "{p:?}");
            }
        }
    }

    #[test]
    fn the_scene_sees_a_rim_where_an_edge_faces_it_and_not_on_a_wide_face() {
        // The sheet lying on its side, its y = 40 edge up, seen from above: the edge (an L
        // strip 3 points wide) and, beside it, a wide face seen flat on.
        let sheet = angle_sheet();
        let mut world: Vec<Point> = sheet
            .points
            .iter()
            .zip(&sheet.normals)
            .filter(|(p, n)| p[1] == 40.0 && n[1] > 0.5)
            .map(|(p, _)| [p[0], p[2], p[1]])
            .collect();
        let strip = world.len();
        for i in 0..30 {
            for j in 0..30 {
                world.push([60.0 + i as f32, j as f32, 20.0]);
            }
        }
        let samples = OrientedPoints {
            points: world.iter().step_by(3).copied().collect(),
            normals: vec![[0.0, 0.0, 1.0]; world.len().div_ceil(3)],
        };
        let (rims, ribbons) = scene_rims(&world, &samples, 5.0, 60.0, [0.0, 0.0, 1e6]).unwrap();
        assert!(rims.len() > 10, "{} rim samples", rims.len());
        for (p, n) in rims.points.iter().zip(&rims.normals) {
            assert!(p[0] < 40.0, "{p:?}");
            assert!(n[2] > 0.99, "{p:?}: {n:?}");
        }
        assert!(ribbons.len() > strip / 2, "{} of {strip}", ribbons.len());
        assert!(ribbons.iter().all(|p| p[0] < 40.0));
    }

    #[test]
    fn a_rim_profile_is_taken_at_its_own_level_past_the_strips_of_faces_below_it() {
        // A Z profile 40 mm up, seen from above (rim samples every 3.5 mm), and the strips
        // a grazing face leaves 9 to 15 mm below its middle leg.
        let mut rim: Vec<Point> = Vec::new();
        let step = 3.5f32;
        for k in 0..9 {
            let t = k as f32 * step;
            rim.push([-t, -15.0, 40.0]);
            rim.push([0.0, -15.0 + t, 40.0]);
            rim.push([t, 15.0, 40.0]);
        }
        let top = rim.len();
        for k in 0..9 {
            for z in [25.0f32, 28.0, 31.0] {
                rim.push([1.5, -14.0 + k as f32 * step, z]);
            }
        }
        let up = [0.0, 0.0, 1e6];
        let facing = |k: usize, n: Vector3<f64>| {
            let to_sensor = (Vector3::from(up) - to_point3(&rim[k]).coords).normalize();
            let c = n.dot(&to_sensor);
            (c.abs() > RIM_FACING_COS).then(|| n * c.signum())
        };
        let diameter = 87.5;
        let plain = profiles(&rim, diameter, None, facing);
        let level = RimLevel {
            viewpoint: Vector3::from(up),
            band_mm: f64::from(step),
        };
        let levelled = profiles(&rim, diameter, Some(&level), facing);
        // Over a quarter of the diameter the strips below tilt most of the profile ...
        assert!(plain.len() < top / 2, "{} of {top}", plain.len());
        // ... at its own level the edge is a profile facing up (all but the far ends of the
        // outer legs, which see no bend within a quarter of the diameter), the strips not.
        let on_top = |p: &Point| p[2] == 40.0;
        let kept = levelled.points.iter().filter(|p| on_top(p)).count();
        assert!(kept >= 2 * top / 3, "{kept} of {top}");
        let near_a_bend = |p: &Point| {
            [-15.0f32, 15.0].iter().any(|&y| {
                (p[0].powi(2) + (p[1] - y).powi(2)).sqrt() < 0.25 * diameter as f32 - step
            })
        };
        for p in rim[..top].iter().filter(|p| near_a_bend(p)) {
            assert!(levelled.points.contains(p), "{p:?}");
        }
        assert!(levelled.points.iter().all(on_top));
        assert!(
            levelled.normals.iter().all(|n| n[2] > 0.99),
            "{:?}",
            levelled.normals
        );
        // Where the neighbours are flat the level changes nothing.
        for (p, n) in plain.points.iter().zip(&plain.normals) {
            let k = levelled.points.iter().position(|q| q == p).unwrap();
            assert_eq!(levelled.normals[k], *n);
        }
    }
}
