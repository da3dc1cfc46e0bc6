//! Stage 1, preprocessing, in this order: the region of interest, stray-point removal, the
//! units check (on what is left), the resolution voxel grid (thesis 4.3 #1) and the removal
//! of the supporting surface (5.2), each step reporting how many points it removed. Cropping
//! and dropping strays come first so that a spurious return far away (or at 1e30) can neither
//! fail the units check nor blow up the voxel grid.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use binpick_cloud::{Point, PointCloud, to_point3};

use crate::deadline::Deadline;
use crate::error::{InputKind, Result, input_as, pcl};
use crate::params::{PreprocessConfig, RegionOfInterest};
use crate::result::{PreprocessReport, RemovedPlane};

/// Refuses empty clouds, non-finite points, degenerate clouds (one point, all at one
/// position, all on one line: `PointCloud::degeneracy`, worded as such rather than as a units
/// problem) and extents that mean the cloud is not in mm (both engines word it the same).
pub(crate) fn check_units(
    what: &'static str,
    cloud: &PointCloud,
    cfg: &PreprocessConfig,
) -> Result<()> {
    if cloud.is_empty() {
        return Err(input_as(what, InputKind::EmptyCloud, "the cloud is empty"));
    }
    if let Some(i) = cloud.first_non_finite() {
        return Err(input_as(
            what,
            InputKind::NonFinite,
            format!("point {i} has a non-finite coordinate"),
        ));
    }
    if let Some(d) = cloud.degeneracy() {
        return Err(input_as(what, InputKind::Degenerate, d.to_string()));
    }
    let (lo, hi) = bounds(&cloud.points);
    let extent = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let min = cfg.min_extent_resolutions * cfg.resolution();
    if extent < min {
        return Err(input_as(
            what,
            InputKind::WrongUnits,
            format!(
                "its extent is {extent:.4} mm, smaller than {} x the {} mm resolution: \
                 the cloud looks like it is in metres (binpick works in millimetres; set units = \"m\")",
                cfg.min_extent_resolutions,
                cfg.resolution()
            ),
        ));
    }
    if extent > cfg.max_extent_mm {
        return Err(input_as(
            what,
            InputKind::WrongUnits,
            format!(
                "its extent is {extent:.0} mm (> {} m): wrong units? binpick expects millimetres",
                cfg.max_extent_mm / 1000.0
            ),
        ));
    }
    Ok(())
}

/// How big one part is, for telling support from parts: a plane patch is support when it is
/// larger than `min_points_factor` x this.
#[derive(Clone, Copy, Debug)]
pub(crate) enum SupportSize {
    /// The model's point count at the resolution (the thesis engine; the C++ reference does
    /// the same).
    Points(usize),
    /// Scene voting. Patches are measured by the area they cover, so a bin wall the sensor
    /// sees at a grazing angle (few points) still counts, and the largest plane's noise is
    /// measured.
    Area {
        /// The area one view of the part shows, mm^2.
        view_area_mm2: f64,
        /// The part curves away from its support (a rod, a shaft): the flanks it rises on
        /// lie within the plane's fit distance for a while, so only the noise's band
        /// (`SupportRemoval::band`) is support. A flat part lies flush instead, and a band
        /// edge through its lowest face would split that face: the whole distance stays.
        curved: bool,
    },
}

/// Per-axis minimum and maximum, mm.
pub(crate) use binpick_match::index::bounds;

/// The scene points left for the voxel grid: cropped to the region of interest, without
/// strays, checked for units. Shared by both engines; fills the report's counts.
pub(crate) fn clean_scene(
    scene: &PointCloud,
    cfg: &PreprocessConfig,
    deadline: &Deadline,
    report: &mut PreprocessReport,
) -> Result<Vec<Point>> {
    report.input_points = scene.len();
    if scene.is_empty() {
        return Err(input_as(
            "scene",
            InputKind::EmptyCloud,
            "the cloud is empty",
        ));
    }
    let cropped = PointCloud::new(match &cfg.region_of_interest {
        None => scene.points.clone(),
        Some(roi) => crop(&scene.points, roi),
    });
    report.outside_roi = scene.len() - cropped.len();
    if cropped.is_empty() {
        return Err(input_as(
            "scene",
            InputKind::EmptyCloud,
            "no point lies inside the region of interest",
        ));
    }
    // A non-finite point is never inside a region of interest; without one it is an error.
    if let Some(i) = scene
        .first_non_finite()
        .filter(|_| cfg.region_of_interest.is_none())
    {
        return Err(input_as(
            "scene",
            InputKind::NonFinite,
            format!("point {i} has a non-finite coordinate"),
        ));
    }
    deadline.check("preprocessing")?;
    let kept = PointCloud::new(drop_isolated(
        &cropped.points,
        cfg.isolated_radius_mm,
        cfg.isolated_min_neighbours,
        deadline,
    )?);
    report.isolated_removed = cropped.len() - kept.len();
    if kept.is_empty() {
        // A single point or a cloud in metres says so first.
        check_units("scene", &cropped, cfg)?;
        return Err(input_as(
            "scene",
            InputKind::EmptyCloud,
            format!(
                "all {} points are isolated (fewer than {} neighbours within {} mm)",
                cropped.len(),
                cfg.isolated_min_neighbours,
                cfg.isolated_radius_mm
            ),
        ));
    }
    check_units("scene", &kept, cfg)?;
    Ok(kept.points)
}

/// The points inside `roi` (bounds included), in order. Non-finite points are never inside.
fn crop(points: &[Point], roi: &RegionOfInterest) -> Vec<Point> {
    points
        .iter()
        .filter(|p| {
            (0..3).all(|k| f64::from(p[k]) >= roi.min_mm[k] && f64::from(p[k]) <= roi.max_mm[k])
        })
        .copied()
        .collect()
}

/// Crops, drops strays, checks units, voxelises (thesis 4.3 #1) and strips support planes,
/// filling `report` as it goes (an interrupted call reports the steps done). `model_points`
/// (voxelised model size) sets the smallest plane that counts as support; support patches are
/// connected at the clustering tolerance `tolerance_mm`; `threads` split the plane fits'
/// inlier counts (the result does not depend on them).
pub(crate) fn preprocess(
    scene: &PointCloud,
    cfg: &PreprocessConfig,
    tolerance_mm: f64,
    model_points: usize,
    threads: usize,
    deadline: &Deadline,
    report: &mut PreprocessReport,
) -> Result<Vec<Point>> {
    let cleaned = clean_scene(scene, cfg, deadline, report)?;
    let points = voxelise(&cleaned, cfg, deadline, report)?;
    let part = SupportSize::Points(model_points);
    let support = support_of(&points, cfg, tolerance_mm, part, threads, deadline, report)?;
    Ok(points
        .into_iter()
        .zip(support)
        .filter_map(|(p, s)| (!s).then_some(p))
        .collect())
}

/// The voxel grid of [`preprocess`] on points [`clean_scene`] returned.
pub(crate) fn voxelise(
    cleaned: &[Point],
    cfg: &PreprocessConfig,
    deadline: &Deadline,
    report: &mut PreprocessReport,
) -> Result<Vec<Point>> {
    deadline.check("preprocessing")?;
    let points = binpick_pcl::voxel_grid(cleaned, cfg.resolution() as f32)
        .map_err(pcl("scene voxel grid"))?;
    report.voxel_merged = cleaned.len() - points.len();
    Ok(points)
}

/// The support search of [`preprocess`] on the voxelised `points`: a flag per point that
/// says whether it is support (belt, floor, wall). The scene-voting engine keeps the support
/// to know what the sensor saw behind the parts.
pub(crate) fn support_of(
    points: &[Point],
    cfg: &PreprocessConfig,
    tolerance_mm: f64,
    part: SupportSize,
    threads: usize,
    deadline: &Deadline,
    report: &mut PreprocessReport,
) -> Result<Vec<bool>> {
    let support = if cfg.support.enabled {
        find_support(points, cfg, tolerance_mm, part, threads, deadline, report)?
    } else {
        vec![false; points.len()]
    };
    report.remaining = support.iter().filter(|s| !**s).count();
    Ok(support)
}

/// A point with fewer than `min_neighbours` other points in its cell of `radius_mm` and the 26
/// cells around it is a stray and dropped (0 = keep all). The block of 27 cells holds every
/// point within `radius_mm`, so any point with `min_neighbours` neighbours within the radius
/// is kept (this drops a subset of what PCL's `RadiusOutlierRemoval` with that radius and
/// count would). A grid rather than PCL's filter: it must run before the extent is known and
/// before any PCL call (a point at 1e30 overflows kd-tree distances and voxel indices), it is
/// linear in the points (no kd-tree over a 5 M-point scan), and it counts integers, so the
/// answer does not depend on point order or thread count.
pub(crate) fn drop_isolated(
    points: &[Point],
    radius_mm: f64,
    min_neighbours: usize,
    deadline: &Deadline,
) -> Result<Vec<Point>> {
    if min_neighbours == 0 || points.is_empty() {
        return Ok(points.to_vec());
    }
    type Cells<V> = HashMap<[i64; 3], V, BuildHasherDefault<CellHasher>>;
    // Saturating: cells beyond i64 (points near 1e30) share the extreme cell.
    let cell = |p: &Point| p.map(|c| floor_to_i64(f64::from(c) / radius_mm));
    let need = min_neighbours.saturating_add(1); // the point itself is in its block
    let keep = match DenseCells::over(points, &cell, deadline)? {
        Some(dense) => dense.keep(need),
        None => {
            let mut counts: Cells<usize> = Cells::default();
            for (i, p) in points.iter().enumerate() {
                if i % POLL_POINTS == 0 {
                    deadline.check("stray-point removal")?;
                }
                *counts.entry(cell(p)).or_insert(0) += 1;
            }
            let mut block: Cells<bool> = Cells::default();
            let mut keep = Vec::with_capacity(points.len());
            for (i, p) in points.iter().enumerate() {
                if i % POLL_POINTS == 0 {
                    deadline.check("stray-point removal")?;
                }
                let c = cell(p);
                let ok = counts.get(&c).is_some_and(|&n| n >= need)
                    || *block
                        .entry(c)
                        .or_insert_with(|| block_count(&counts, c) >= need);
                keep.push(ok);
            }
            keep
        }
    };
    Ok(points
        .iter()
        .zip(keep)
        .filter_map(|(p, k)| k.then_some(*p))
        .collect())
}

/// [`drop_isolated`]'s cell counts in an array over the cells' bounding box, when that box
/// holds at most [`DENSE_CELLS_PER_POINT`] cells per point (a scan's cells are a few
/// centimetres wide): the same counts and answers as the hash map, without hashing every
/// point twice. Each point's cell is computed in parallel (most of the time on a scan: three
/// divisions and floors per point), once for the box and once for its slot; the counts and
/// verdicts are integers, so the answer does not depend on the split.
struct DenseCells {
    lo: [i64; 3],
    dims: [usize; 3],
    counts: Vec<u32>,
    /// Each point's slot in `counts`.
    slots: Vec<u32>,
}

impl DenseCells {
    /// None when the box is too large for an array (far strays, points near 1e30).
    fn over(
        points: &[Point],
        cell: &(impl Fn(&Point) -> [i64; 3] + Sync),
        deadline: &Deadline,
    ) -> Result<Option<Self>> {
        use rayon::prelude::*;
        let (lo, hi) = points
            .par_chunks(POLL_POINTS)
            .map(|chunk| {
                deadline.check("stray-point removal")?;
                let mut lo = [i64::MAX; 3];
                let mut hi = [i64::MIN; 3];
                for p in chunk {
                    let c = cell(p);
                    for a in 0..3 {
                        lo[a] = lo[a].min(c[a]);
                        hi[a] = hi[a].max(c[a]);
                    }
                }
                Ok::<_, crate::error::Error>((lo, hi))
            })
            .try_reduce(
                || ([i64::MAX; 3], [i64::MIN; 3]),
                |(l1, h1), (l2, h2)| {
                    Ok((
                        [0, 1, 2].map(|a| l1[a].min(l2[a])),
                        [0, 1, 2].map(|a| h1[a].max(h2[a])),
                    ))
                },
            )?;
        let spans = [0, 1, 2].map(|a| span(lo[a], hi[a]));
        // Checked: three spans of saturated cells (points near 1e30) overflow even i128.
        let Some(cells) = spans.iter().try_fold(1i128, |n, &s| n.checked_mul(s)) else {
            return Ok(None);
        };
        // Slots are u32: a box of more cells (a cloud of hundreds of millions of points)
        // counts in the map.
        if cells > DENSE_CELLS_PER_POINT * (points.len() as i128 + 1024)
            || cells > i128::from(u32::MAX)
        {
            return Ok(None);
        }
        let dims = spans.map(|s| s as usize);
        let mut dense = Self {
            lo,
            dims,
            counts: vec![0; cells as usize],
            slots: Vec::new(),
        };
        let mut slots = vec![0u32; points.len()];
        slots
            .par_chunks_mut(POLL_POINTS)
            .zip(points.par_chunks(POLL_POINTS))
            .try_for_each(|(slots, chunk)| {
                deadline.check("stray-point removal")?;
                for (slot, p) in slots.iter_mut().zip(chunk) {
                    *slot = dense.index(cell(p)) as u32;
                }
                Ok::<_, crate::error::Error>(())
            })?;
        for &k in &slots {
            dense.counts[k as usize] += 1;
        }
        dense.slots = slots;
        Ok(Some(dense))
    }

    /// The slot of cell `c`, which lies in the box.
    fn index(&self, c: [i64; 3]) -> usize {
        let o = [0, 1, 2].map(|a| (c[a] - self.lo[a]) as usize);
        (o[0] * self.dims[1] + o[1]) * self.dims[2] + o[2]
    }

    /// The cell of slot `k` (the inverse of [`index`](Self::index)).
    fn cell_of(&self, k: usize) -> [i64; 3] {
        let [_, ny, nz] = self.dims;
        let o = [k / (ny * nz), (k / nz) % ny, k % nz];
        [0, 1, 2].map(|a| self.lo[a] + o[a] as i64)
    }

    /// Points in `c` and the 26 cells around it (those in the box; the others are empty).
    fn block_count(&self, c: [i64; 3]) -> usize {
        let mut n = 0;
        for dx in -1..=1i64 {
            for dy in -1..=1i64 {
                for dz in -1..=1i64 {
                    let q = [c[0] + dx, c[1] + dy, c[2] + dz];
                    let inside = (0..3).all(|a| {
                        q[a] >= self.lo[a] && ((q[a] - self.lo[a]) as usize) < self.dims[a]
                    });
                    if inside {
                        n += self.counts[self.index(q)] as usize;
                    }
                }
            }
        }
        n
    }

    /// Whether each point keeps `need` points in its block (its own included).
    fn keep(&self, need: usize) -> Vec<bool> {
        // Per cell: 0 = not judged yet, 1 = kept, 2 = dropped.
        let mut judged = vec![0u8; self.counts.len()];
        self.slots
            .iter()
            .map(|&k| {
                let k = k as usize;
                if judged[k] == 0 {
                    let ok = self.counts[k] as usize >= need
                        || self.block_count(self.cell_of(k)) >= need;
                    judged[k] = if ok { 1 } else { 2 };
                }
                judged[k] == 1
            })
            .collect()
    }
}

/// `x.floor() as i64` (saturating; x not NaN) without a call to libm's `floor`, which the
/// baseline x86-64 target does not inline: a third of [`drop_isolated`]'s time on a scan.
pub(crate) fn floor_to_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// Points between two deadline checks in per-point loops (about a millisecond).
const POLL_POINTS: usize = 1 << 16;

/// Points in `c` and the 26 cells around it (each cell once, also at the saturated edges).
fn block_count<S: std::hash::BuildHasher>(
    counts: &HashMap<[i64; 3], usize, S>,
    c: [i64; 3],
) -> usize {
    let mut cells = Vec::with_capacity(27);
    for dx in -1..=1i64 {
        for dy in -1..=1i64 {
            for dz in -1..=1i64 {
                cells.push([
                    c[0].saturating_add(dx),
                    c[1].saturating_add(dy),
                    c[2].saturating_add(dz),
                ]);
            }
        }
    }
    cells.sort_unstable();
    cells.dedup();
    cells.iter().filter_map(|k| counts.get(k)).sum()
}

/// FxHash-style hasher for integer cell keys (the default SipHash is several times slower on
/// millions of cells and its DoS resistance is not needed here).
#[derive(Default)]
pub(crate) struct CellHasher(u64);

impl Hasher for CellHasher {
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut b = [0u8; 8];
            b[..chunk.len()].copy_from_slice(chunk);
            self.write_u64(u64::from_le_bytes(b));
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

/// Removes supporting planes. A RANSAC plane is support only where its inliers form a
/// connected patch larger than any part could (`min_points_factor` x model size): the belt is
/// one connected surface around the parts' shadows, while the flat faces of parts lying on
/// it are coplanar but disconnected patches and must stay. A plane with no such patch is
/// excluded from later fits (so a bin wall can still be found after it) but kept in the
/// scene.
fn find_support(
    points: &[Point],
    cfg: &PreprocessConfig,
    tolerance: f64,
    part: SupportSize,
    threads: usize,
    deadline: &Deadline,
    report: &mut PreprocessReport,
) -> Result<Vec<bool>> {
    let (support, resolution_mm) = (&cfg.support, cfg.resolution());
    // A patch must beat this many points (Points), or points are only a lower bound on
    // the fit's size and the area decides (AreaMm2).
    let (min_patch, min_area) = match part {
        SupportSize::Points(n) => (
            (support.min_points_factor * n as f64).ceil().max(3.0) as usize,
            None,
        ),
        SupportSize::Area { view_area_mm2, .. } => {
            (3, Some(support.min_points_factor * view_area_mm2))
        }
    };
    let curved = matches!(part, SupportSize::Area { curved: true, .. });
    let mut removed = vec![false; points.len()];
    // Indices still eligible for a plane fit.
    let mut candidates: Vec<u32> = (0..points.len() as u32).collect();
    let mut band: Option<f64> = None;
    for _ in 0..support.max_planes {
        deadline.check("support plane fit")?;
        if candidates.len() < min_patch {
            break;
        }
        let cand_pts: Vec<Point> = candidates.iter().map(|&i| points[i as usize]).collect();
        let Some(plane) = binpick_pcl::segment_plane(
            &cand_pts,
            support.distance(resolution_mm) as f32,
            support.ransac_iterations,
            threads as u32,
        )
        .map_err(pcl("support plane fit"))?
        else {
            break;
        };
        if plane.inliers.len() < min_patch {
            break;
        }
        let inlier_pts: Vec<Point> = plane
            .inliers
            .iter()
            .map(|&i| cand_pts[i as usize])
            .collect();
        let patches = match min_area {
            None => large_patches(
                &inlier_pts,
                plane.coefficients,
                tolerance,
                PatchMin::Points(min_patch),
            ),
            Some(area) => {
                // Points on a plane seen at a grazing angle lie farther apart: connect them at
                // twice their own gap.
                let gap =
                    crate::stages::scale::measure_spacing(&inlier_pts)?.map_or(0.0, |s| s.gap_mm);
                let cell = tolerance.max(2.0 * gap);
                large_patches(
                    &inlier_pts,
                    plane.coefficients,
                    cell,
                    PatchMin::AreaMm2(area),
                )
            }
        };
        let c = plane.coefficients.map(f64::from);
        let distance = |k: usize| plane_distance_mm(&c, &inlier_pts[k]).abs();
        let patch: Vec<usize> = (0..patches.len()).filter(|&k| patches[k]).collect();
        let sq: f64 = patch.iter().map(|&k| distance(k).powi(2)).sum();
        let rms_mm = (!patch.is_empty()).then(|| (sq / patch.len() as f64).sqrt());
        // With the noise measured (scene voting) and a curved part, the band narrows to what
        // the largest plane's noise needs (reported: `DerivedScale::with_noise` takes it as
        // the support distance).
        if let (true, Some(rms), None) = (curved, rms_mm, band) {
            band = Some(support.band(resolution_mm, rms));
        }
        let mut taken = 0;
        for &k in &patch {
            if band.is_none_or(|b| distance(k) <= b) {
                removed[candidates[plane.inliers[k] as usize] as usize] = true;
                taken += 1;
            }
        }
        deadline.check("support plane fit")?;
        if taken > 0 {
            report.support_planes.push(RemovedPlane {
                coefficients: plane.coefficients,
                points: taken,
                rms_mm: min_area.and(rms_mm),
            });
        }
        let mut is_inlier = vec![false; candidates.len()];
        for &i in &plane.inliers {
            is_inlier[i as usize] = true;
        }
        let mut k = 0;
        candidates.retain(|_| {
            k += 1;
            !is_inlier[k - 1]
        });
    }
    report.support_band_mm = band;
    Ok(removed)
}

/// The noise tail of the support planes (`SupportRemoval::noise_tail_sigmas`): every point
/// that is not `support`, lies past the plane distance `from_mm` but within `to_mm` of one of
/// `planes` (`a x + b y + c z + d = 0`, unit normal, mm) and has fewer than `min_neighbours`
/// other points that are not support within `radius_mm` is labelled support. What the
/// support search left within the plane distance (small patches, the flanks of a curved
/// part) is not looked at. Decided for all points against the labels as given, so the
/// answer does not depend on order or threads. Returns how many were labelled.
pub(crate) fn label_support_noise(
    points: &[Point],
    support: &mut [bool],
    planes: &[[f64; 4]],
    from_mm: f64,
    to_mm: f64,
    radius_mm: f64,
    min_neighbours: usize,
) -> Result<usize> {
    use rayon::prelude::*;
    let near_plane = |p: &Point| {
        planes.iter().any(|c| {
            let d = plane_distance_mm(c, p).abs();
            d > from_mm && d <= to_mm
        })
    };
    if planes.is_empty() || to_mm <= from_mm {
        return Ok(0);
    }
    let rest: Vec<u32> = (0..points.len() as u32)
        .filter(|&i| !support[i as usize])
        .collect();
    let in_band: Vec<u32> = rest
        .iter()
        .copied()
        .filter(|&i| near_plane(&points[i as usize]))
        .collect();
    if in_band.is_empty() {
        return Ok(0);
    }
    let rest_points: Vec<Point> = rest.iter().map(|&i| points[i as usize]).collect();
    let index = binpick_match::PointIndex::new("scene", &rest_points)
        .map_err(crate::error::matching("support noise"))?;
    let alone: Vec<bool> = in_band
        .par_iter()
        .map_init(Vec::new, |near, &i| {
            index.within_into(&points[i as usize], radius_mm as f32, near);
            // The point itself is among them.
            near.len() < min_neighbours + 1
        })
        .collect();
    let mut labelled = 0;
    for (&i, alone) in in_band.iter().zip(alone) {
        if alone {
            support[i as usize] = true;
            labelled += 1;
        }
    }
    Ok(labelled)
}

/// Signed distance of `p` from the plane `a x + b y + c z + d = 0` (unit normal, mm).
pub(crate) fn plane_distance_mm(plane: &[f64; 4], p: &Point) -> f64 {
    plane[0] * f64::from(p[0]) + plane[1] * f64::from(p[1]) + plane[2] * f64::from(p[2]) + plane[3]
}

/// The smallest patch that counts as large.
#[derive(Clone, Copy, Debug)]
enum PatchMin {
    Points(usize),
    /// Occupied cells times the cell's area.
    AreaMm2(f64),
}

/// For points on a plane, whether each belongs to a connected patch at least `min` large.
/// Connectivity is judged on a 2-D grid in the plane (cells of `cell_mm`, 8-neighbours), a
/// linear-time stand-in for Euclidean clustering that is fast enough for a 300k-point belt.
fn large_patches(points: &[Point], plane: [f32; 4], cell_mm: f64, min: PatchMin) -> Vec<bool> {
    let n = nalgebra::Vector3::new(
        f64::from(plane[0]),
        f64::from(plane[1]),
        f64::from(plane[2]),
    )
    .normalize();
    let helper = if n.x.abs() < 0.9 {
        nalgebra::Vector3::x()
    } else {
        nalgebra::Vector3::y()
    };
    let u = n.cross(&helper).normalize();
    let v = n.cross(&u);
    let cell_of = |p: &Point| {
        let q = to_point3(p).coords;
        (
            (q.dot(&u) / cell_mm).floor() as i64,
            (q.dot(&v) / cell_mm).floor() as i64,
        )
    };
    let cells: Vec<(i64, i64)> = points.iter().map(cell_of).collect();
    let (id, numbers, occupied_cells) = CellIds::number(&cells);
    let mut count = vec![0usize; occupied_cells.len()];
    for &k in &numbers {
        count[k as usize] += 1;
    }
    // Union-find over occupied cells.
    let mut parent: Vec<usize> = (0..count.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for (k, &(a, b)) in occupied_cells.iter().enumerate() {
        for (da, db) in [(1, -1), (1, 0), (1, 1), (0, 1)] {
            if let Some(j) = id.get((a + da, b + db)) {
                let (ra, rb) = (root(&mut parent, k), root(&mut parent, j));
                if ra != rb {
                    parent[ra.max(rb)] = ra.min(rb);
                }
            }
        }
    }
    let mut size = vec![0usize; parent.len()];
    let mut occupied = vec![0usize; parent.len()];
    for (k, &c) in count.iter().enumerate() {
        let r = root(&mut parent, k);
        size[r] += c;
        occupied[r] += 1;
    }
    numbers
        .iter()
        .map(|&k| {
            let r = root(&mut parent, k as usize);
            match min {
                PatchMin::Points(n) => size[r] >= n,
                PatchMin::AreaMm2(a) => occupied[r] as f64 * cell_mm * cell_mm >= a,
            }
        })
        .collect()
}

/// Cells of a 2-D grid numbered in the order they first occur: a dense array over the cells'
/// bounding range when it is at most [`DENSE_CELLS_PER_POINT`] cells per point (a support
/// plane's inliers fill their range), a hash map otherwise (a few points far apart). Both
/// give the same numbers; the array spares hashing half a million points of a belt.
enum CellIds {
    Dense {
        /// `ids[(a - lo.0) * rows + (b - lo.1)]`: the number of cell (a, b), or `u32::MAX`.
        ids: Vec<u32>,
        lo: (i64, i64),
        hi: (i64, i64),
        rows: usize,
    },
    Sparse(HashMap<(i64, i64), u32, BuildHasherDefault<CellHasher>>),
}

/// Most cells per point for [`CellIds`]' dense array (counted over at least 1024 points, so
/// a handful of points close together takes the array too).
const DENSE_CELLS_PER_POINT: i128 = 8;

/// Cells from `lo` to `hi`, both included.
fn span(lo: i64, hi: i64) -> i128 {
    i128::from(hi) - i128::from(lo) + 1
}

impl CellIds {
    /// Numbers `cells` in first-seen order: the numbering, each cell's number and the
    /// distinct cells in number order.
    fn number(cells: &[(i64, i64)]) -> (Self, Vec<u32>, Vec<(i64, i64)>) {
        let Some(&first) = cells.first() else {
            return Self::sparse(cells);
        };
        let (lo, hi) = cells.iter().fold((first, first), |(lo, hi), &(a, b)| {
            ((lo.0.min(a), lo.1.min(b)), (hi.0.max(a), hi.1.max(b)))
        });
        // Checked: two spans of saturated cells overflow i128.
        let area = span(lo.0, hi.0).checked_mul(span(lo.1, hi.1));
        if area.is_some_and(|a| a <= DENSE_CELLS_PER_POINT * (cells.len() as i128 + 1024)) {
            Self::dense(cells, lo, hi)
        } else {
            Self::sparse(cells)
        }
    }

    /// [`CellIds::number`] in an array over `lo..=hi`, which bounds `cells`.
    fn dense(
        cells: &[(i64, i64)],
        lo: (i64, i64),
        hi: (i64, i64),
    ) -> (Self, Vec<u32>, Vec<(i64, i64)>) {
        let rows = span(lo.1, hi.1) as usize;
        let mut ids = vec![u32::MAX; (span(lo.0, hi.0) * span(lo.1, hi.1)) as usize];
        let (mut numbers, mut distinct) = (Vec::with_capacity(cells.len()), Vec::new());
        for &c in cells {
            let slot = &mut ids[(c.0 - lo.0) as usize * rows + (c.1 - lo.1) as usize];
            if *slot == u32::MAX {
                *slot = distinct.len() as u32;
                distinct.push(c);
            }
            numbers.push(*slot);
        }
        (Self::Dense { ids, lo, hi, rows }, numbers, distinct)
    }

    /// [`CellIds::number`] in a hash map.
    fn sparse(cells: &[(i64, i64)]) -> (Self, Vec<u32>, Vec<(i64, i64)>) {
        let mut map: HashMap<(i64, i64), u32, BuildHasherDefault<CellHasher>> = HashMap::default();
        let (mut numbers, mut distinct) = (Vec::with_capacity(cells.len()), Vec::new());
        for &c in cells {
            let k = *map.entry(c).or_insert_with(|| {
                distinct.push(c);
                (distinct.len() - 1) as u32
            });
            numbers.push(k);
        }
        (Self::Sparse(map), numbers, distinct)
    }

    /// The number of cell `c`, None when no point lies in it.
    fn get(&self, c: (i64, i64)) -> Option<usize> {
        match self {
            Self::Dense { ids, lo, hi, rows } => {
                let inside = (lo.0..=hi.0).contains(&c.0) && (lo.1..=hi.1).contains(&c.1);
                let slot = inside.then(|| (c.0 - lo.0) as usize * rows + (c.1 - lo.1) as usize);
                slot.map(|s| ids[s])
                    .filter(|&k| k != u32::MAX)
                    .map(|k| k as usize)
            }
            Self::Sparse(map) => map.get(&c).map(|&k| k as usize),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (xorshift32).
    fn xorshift32(mut state: u32) -> impl FnMut() -> u32 {
        move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        }
    }

    #[test]
    fn floor_to_i64_is_floor_as_i64() {
        let mut xs = vec![
            0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.999_999, -2.999_999, 1e300, -1e300,
        ];
        xs.extend([
            f64::INFINITY,
            f64::NEG_INFINITY,
            9.3e18,
            -9.3e18,
            -9_223_372_036_854_775_808.0,
        ]);
        xs.extend([
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            4_503_599_627_370_495.5,
            -4_503_599_627_370_495.5,
        ]);
        for x in xs {
            assert_eq!(floor_to_i64(x), x.floor() as i64, "{x}");
        }
    }

    /// Scan order (runs of points in one cell) and shuffled order give what the rule says
    /// point by point: kept when its block of 27 cells holds `min_neighbours` others.
    #[test]
    fn strays_are_dropped_by_their_block_in_any_point_order() {
        let mut bits = xorshift32(11);
        let mut next = move || f64::from(bits() % 10_000) / 10_000.0;
        let radius = 5.0;
        // A dense strip scanned line by line, strays between its lines, a pair of strays.
        let mut points: Vec<Point> = Vec::new();
        for line in 0..40 {
            for i in 0..50 {
                points.push([i as f32, line as f32 * 0.5, (0.2 * next()) as f32]);
            }
            if line % 9 == 0 {
                points.push([70.0 + 15.0 * (line / 9) as f32, 40.0, 3.0 * next() as f32]);
            }
        }
        points.extend([[-20.0, -20.0, 0.0], [-21.0, -20.0, 0.0]]);
        // Six together in one cell stay (one run in scan order); five together go.
        points.extend((0..6).map(|i| [-42.0 + 0.5 * i as f32, -42.0, 0.0]));
        points.extend((0..5).map(|i| [-62.0 + 0.5 * i as f32, -62.0, 0.0]));
        // Alone in its cell, but beside the strip's: kept.
        points.push([50.5, 10.0, 0.0]);
        let shuffled: Vec<Point> = {
            let mut keyed: Vec<(f64, Point)> = points.iter().map(|p| (next(), *p)).collect();
            keyed.sort_by(|a, b| a.0.total_cmp(&b.0));
            keyed.into_iter().map(|(_, p)| p).collect()
        };
        // Points near 1e30 make the cells' box too large for an array (its cell count too
        // large even for i128): the hash map counts.
        let far: Vec<Point> = points
            .iter()
            .copied()
            .chain([[1e30, 1e30, 1e30], [-1e30, -1e30, -1e30]])
            .collect();
        let cell_of = |p: &Point| p.map(|c| (f64::from(c) / radius).floor() as i64);
        let deadline = Deadline::unlimited();
        assert!(
            DenseCells::over(&points, &cell_of, &deadline)
                .unwrap()
                .is_some()
        );
        assert!(
            DenseCells::over(&far, &cell_of, &deadline)
                .unwrap()
                .is_none()
        );
        for (order, cloud) in [("scan", &points), ("shuffled", &shuffled), ("far", &far)] {
            let cell = |p: &Point| p.map(|c| i128::from((f64::from(c) / radius).floor() as i64));
            let expected: Vec<Point> = cloud
                .iter()
                .filter(|p| {
                    let c = cell(p);
                    let near = cloud
                        .iter()
                        .filter(|q| (0..3).all(|a| (cell(q)[a] - c[a]).abs() <= 1))
                        .count();
                    near > 5
                })
                .copied()
                .collect();
            let kept = drop_isolated(cloud, radius, 5, &deadline).unwrap();
            assert_eq!(kept, expected, "{order}");
            let far_ones = 2 * usize::from(order == "far");
            assert_eq!(
                cloud.len() - kept.len(),
                12 + far_ones,
                "{order}: 5 lone strays, the pair and the five (and the far points)"
            );
            assert!(kept.contains(&[50.5, 10.0, 0.0]), "{order}");
        }
    }

    /// A cloud of several of the array's parallel chunks gives the hash map's answer, point
    /// by point: 300 000 points, a tenth of them scattered thinly enough to be strays, with
    /// and without two points near 1e30 (which send the same cloud to the map).
    #[test]
    fn the_array_in_parallel_chunks_drops_what_the_map_drops() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let points: Vec<Point> = (0..300_000)
            .map(|i| {
                let spread = if i % 10 == 0 { 4000.0 } else { 400.0 };
                [0, 1, 2].map(|_| (next() * spread) as f32)
            })
            .collect();
        let far: Vec<Point> = points
            .iter()
            .copied()
            .chain([[1e30, 1e30, 1e30], [-1e30, -1e30, -1e30]])
            .collect();
        let deadline = Deadline::unlimited();
        let cell = |p: &Point| p.map(|c| floor_to_i64(f64::from(c) / 50.0));
        assert!(
            DenseCells::over(&points, &cell, &deadline)
                .unwrap()
                .is_some()
        );
        assert!(DenseCells::over(&far, &cell, &deadline).unwrap().is_none());
        let by_array = drop_isolated(&points, 50.0, 5, &deadline).unwrap();
        let by_map = drop_isolated(&far, 50.0, 5, &deadline).unwrap();
        assert_eq!(by_array, by_map);
        let dropped = points.len() - by_array.len();
        assert!((1_000..30_000).contains(&dropped), "{dropped} dropped");
    }

    /// Cells at both ends of i64 (points near 1e30 on a plane) span more cells than i128
    /// holds: numbered in the map.
    #[test]
    fn cells_at_the_ends_of_i64_are_numbered_in_the_map() {
        let cells = [(i64::MIN, i64::MIN), (0, 0), (i64::MAX, i64::MAX), (0, 0)];
        let (ids, numbers, distinct) = CellIds::number(&cells);
        assert!(matches!(ids, CellIds::Sparse(_)));
        assert_eq!(numbers, vec![0, 1, 2, 1]);
        assert_eq!(distinct, cells[..3].to_vec());
        assert_eq!(ids.get((i64::MAX, i64::MAX)), Some(2));
    }

    #[test]
    fn cells_are_numbered_alike_in_the_array_and_the_map() {
        let mut next = xorshift32(7);
        let cells: Vec<(i64, i64)> = (0..2000)
            .map(|_| {
                (
                    i64::from(next() % 60) - 30,
                    i64::from(next() % 40) + 1_000_000,
                )
            })
            .collect();
        let (lo, hi) = ((-30, 1_000_000), (29, 1_000_039));
        let (dense, dense_numbers, dense_cells) = CellIds::dense(&cells, lo, hi);
        let (sparse, sparse_numbers, sparse_cells) = CellIds::sparse(&cells);
        assert!(matches!(dense, CellIds::Dense { .. }));
        assert_eq!(dense_numbers, sparse_numbers);
        assert_eq!(dense_cells, sparse_cells);
        for a in -32..32 {
            for b in 999_998..1_000_042 {
                assert_eq!(dense.get((a, b)), sparse.get((a, b)), "cell ({a}, {b})");
            }
        }
        // Two points a million cells apart take the map.
        let (far, _, _) = CellIds::number(&[(0, 0), (1_000_000, 0)]);
        assert!(matches!(far, CellIds::Sparse(_)));
    }

    #[test]
    fn patches_split_by_gaps_and_sized() {
        // Two 10 x 10 grids at 1 mm, 5 mm apart, and one 3 x 3 grid far away, all on z = 0.
        let mut pts = Vec::new();
        for (ox, n) in [(0.0, 10), (14.0, 10), (100.0, 3)] {
            for i in 0..n {
                for j in 0..n {
                    pts.push([ox + i as f32, j as f32, 0.0]);
                }
            }
        }
        let big = large_patches(&pts, [0.0, 0.0, 1.0, 0.0], 1.5, PatchMin::Points(50));
        assert!(big[..200].iter().all(|&b| b), "two 100-point patches");
        assert!(big[200..].iter().all(|&b| !b), "9-point patch is small");
        // With a 60-point minimum... still both 100-point patches; with 150, none.
        assert!(
            large_patches(&pts, [0.0, 0.0, 1.0, 0.0], 1.5, PatchMin::Points(150))
                .iter()
                .all(|&b| !b)
        );
        // Joined by a bridge, the two become one 200+ patch.
        for x in 10..14 {
            pts.push([x as f32, 5.0, 0.0]);
        }
        let big = large_patches(&pts, [0.0, 0.0, 1.0, 0.0], 1.5, PatchMin::Points(150));
        assert!(big[..200].iter().all(|&b| b));
    }

    #[test]
    fn the_floors_noise_tail_becomes_support_and_a_sheet_lying_on_it_does_not() {
        // A floor at 1 mm spacing, all support but every 25th point, which lies 1.5-2.5 mm
        // above or below it (the tail past the support band); a 2 mm sheet, 20 x 20 mm at
        // 1 mm, lying on it; and one point far above the floor, alone.
        let (mut pts, mut support) = (Vec::new(), Vec::new());
        for i in 0..100 {
            for j in 0..100 {
                let tail = (i * 100 + j) % 25 == 0;
                let z = if tail {
                    (if (i + j) % 2 == 0 { 1.0 } else { -1.0 }) * (1.5 + (j % 3) as f32 * 0.5)
                } else {
                    0.0
                };
                pts.push([i as f32, j as f32, z]);
                support.push(!tail);
            }
        }
        let tail = support.iter().filter(|s| !**s).count();
        for i in 0..20 {
            for j in 0..20 {
                pts.push([40.0 + i as f32, 40.0 + j as f32 + 0.5, 2.0]);
                support.push(false);
            }
        }
        pts.push([10.0, 10.0, 30.0]);
        support.push(false);
        let mut labelled = support.clone();
        let n = label_support_noise(
            &pts,
            &mut labelled,
            &[[0.0, 0.0, 1.0, 0.0]],
            1.0,
            3.0,
            2.0,
            3,
        )
        .unwrap();
        // Tail points just under the sheet have its points as neighbours and stay: the
        // answer is a brute-force count's.
        let near_sheet = (0..10_000)
            .filter(|&k| {
                !support[k]
                    && pts[10_000..10_400]
                        .iter()
                        .any(|q| (0..3).map(|c| (q[c] - pts[k][c]).powi(2)).sum::<f32>() <= 4.0)
            })
            .count();
        assert!(near_sheet > 0 && tail > 300);
        assert_eq!(n, tail - near_sheet);
        assert!(
            labelled[10_000..10_400].iter().all(|s| !s),
            "the sheet stays"
        );
        assert!(!labelled[10_400], "a point away from the planes stays");
        // A tail within the plane distance is not looked at; nor is anything when the band
        // ends there.
        for (from, to) in [(3.0, 5.0), (1.0, 1.0)] {
            let mut same = support.clone();
            assert_eq!(
                label_support_noise(&pts, &mut same, &[[0.0, 0.0, 1.0, 0.0]], from, to, 2.0, 3)
                    .unwrap(),
                0
            );
            assert_eq!(same, support);
        }
    }

    /// A 200 x 200 mm floor at 1 mm spacing, noisy by up to +-0.3 mm (RMS about 0.17 mm),
    /// and a rod of radius 3.5 mm lying on it along x, seen down to 0.5 mm above the floor.
    /// Returns the points and how many are floor (first).
    fn rod_on_a_noisy_floor() -> (Vec<Point>, usize) {
        let mut pts = Vec::new();
        let mut state = 0x2545_f491_u32;
        for i in 0..200 {
            for j in 0..200 {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                let noise = (state as f32 / u32::MAX as f32 - 0.5) * 0.6;
                pts.push([i as f32, j as f32 - 100.0, noise]);
            }
        }
        let floor = pts.len();
        for i in 20..180 {
            for k in 0..=20 {
                let a = (-60.0 + 15.0 * k as f32).to_radians();
                pts.push([i as f32, 3.5 * a.cos(), 3.5 + 3.5 * a.sin()]);
            }
        }
        (pts, floor)
    }

    #[test]
    fn under_a_curved_part_the_support_band_narrows_to_three_sigmas_or_a_resolution() {
        let (pts, floor) = rod_on_a_noisy_floor();
        let run = |resolution_mm, size| {
            let mut cfg = PreprocessConfig {
                resolution_mm: Some(resolution_mm),
                ..PreprocessConfig::default()
            };
            cfg.support.distance_mm = Some(1.5);
            cfg.support.max_planes = 1;
            let mut report = PreprocessReport::default();
            let support = find_support(
                &pts,
                &cfg,
                1.5,
                size,
                2,
                &Deadline::unlimited(),
                &mut report,
            )
            .unwrap();
            (support, report, cfg)
        };
        let rod_kept = |support: &[bool]| support[floor..].iter().filter(|&&s| !s).count();
        let curved_rod = SupportSize::Area {
            view_area_mm2: 1000.0,
            curved: true,
        };
        // The thesis's path (the model's point count) labels the plane's whole 1.5 mm band.
        let (thesis, _, _) = run(0.25, SupportSize::Points(1000));
        for (p, &s) in pts[floor..].iter().zip(&thesis[floor..]) {
            if (p[2] - 1.5).abs() > 0.1 {
                assert_eq!(s, p[2] <= 1.5, "{p:?}");
            }
        }
        // Scene voting measures the floor's noise and labels 3 sigmas (0.5 mm) at a fine
        // resolution, one resolution at a coarse one: the rod's flanks above stay the rod's.
        for (resolution, sigmas) in [(0.25, Some(3.0)), (1.0, None)] {
            let (support, report, cfg) = run(resolution, curved_rod);
            // The rod's lowest points within 1.5 mm of the floor count in its RMS too.
            let rms = report.support_planes[0].rms_mm.unwrap();
            assert!((0.17..0.21).contains(&rms), "{rms}");
            let b = cfg.support.band(resolution, rms);
            assert_eq!(b, sigmas.map_or(resolution, |k| k * rms));
            assert_eq!(report.support_band_mm, Some(b), "the band used is reported");
            let b = b as f32;
            assert!(
                support[..floor].iter().all(|&s| s),
                "the whole floor is support"
            );
            for (p, &s) in pts[floor..].iter().zip(&support[floor..]) {
                if (p[2] - b).abs() > 0.1 {
                    assert_eq!(s, p[2] <= b, "{p:?}: band {b}");
                }
            }
            assert!(rod_kept(&support) > rod_kept(&thesis));
        }
        // A flat part keeps the whole distance, as the thesis's path does.
        let flat = SupportSize::Area {
            view_area_mm2: 1000.0,
            curved: false,
        };
        let (flat_support, flat_report, _) = run(0.25, flat);
        assert_eq!(flat_support, thesis);
        assert_eq!(flat_report.support_band_mm, None);
        // As wide as the plane's distance and no wider.
        let mut wide = PreprocessConfig::default();
        wide.support.noise_sigmas = 100.0;
        assert_eq!(wide.support.band(0.25, 0.17), 1.5 * 0.25);
    }
}
