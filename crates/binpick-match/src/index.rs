//! Exact neighbour queries over a fixed point set (kiddo's immutable kd-tree).

use std::ops::ControlFlow;

use kiddo::{ImmutableKdTree, SquaredEuclidean};

use crate::{MatchError, P3};

/// A kd-tree over points that never change.
pub struct PointIndex {
    tree: ImmutableKdTree<f32, 3>,
    len: usize,
}

impl std::fmt::Debug for PointIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PointIndex")
            .field("len", &self.len)
            .finish()
    }
}

/// Refuses an empty or non-finite point set (`what` names it).
fn indexable(what: &'static str, points: &[P3]) -> Result<(), MatchError> {
    if points.is_empty() {
        return Err(MatchError::TooFewPoints {
            what,
            points: 0,
            needed: 1,
        });
    }
    if points.iter().any(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(MatchError::NonFinite { what });
    }
    Ok(())
}

impl PointIndex {
    /// Indexes `points` (non-empty, finite).
    pub fn new(what: &'static str, points: &[P3]) -> Result<Self, MatchError> {
        indexable(what, points)?;
        let tree = ImmutableKdTree::new_from_slice(points).map_err(|e| MatchError::Index {
            what,
            message: format!("{e:?}"),
        })?;
        Ok(Self {
            tree,
            len: points.len(),
        })
    }

    /// Points indexed.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no point is indexed (never true for a built index).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Index of the nearest point and the squared distance to it, mm^2.
    pub fn nearest(&self, q: &P3) -> (usize, f32) {
        let n = self
            .tree
            .query(q)
            .nearest_one::<SquaredEuclidean<f32>>()
            .execute();
        (n.item as usize, n.distance)
    }

    /// Distance to the `k`-th nearest point that does not coincide with `q` (duplicates
    /// closer than 1e-6 mm skipped), mm; None when there are fewer such points.
    pub fn kth_nearest_distinct(&self, q: &P3, k: usize) -> Option<f32> {
        let want = std::num::NonZeroUsize::new((2 * k + 2).min(self.len))?;
        let found = self
            .tree
            .query(q)
            .nearest_n::<SquaredEuclidean<f32>>(want)
            .execute();
        found
            .iter()
            .map(|n| n.distance)
            .filter(|&d| d > 1e-12)
            .nth(k.checked_sub(1)?)
            .map(f32::sqrt)
    }

    /// Replaces `out` with the indices of every point within `radius` of `q`, in no
    /// particular order.
    pub fn within_into(&self, q: &P3, radius: f32, out: &mut Vec<u32>) {
        out.clear();
        self.tree
            .query(q)
            .within::<SquaredEuclidean<f32>>(radius * radius)
            .unsorted()
            .visit(|n| out.push(n.item));
    }
}

/// [`PointIndex::kth_nearest_distinct`] of each of `queries` over `points` (non-empty,
/// finite), found on a uniform grid instead of a kd-tree: measuring a scan's spacing asks a
/// few thousand queries of half a million points, where building the tree costs ten times
/// the queries. The same distances: the `2k + 2` nearest squared distances are found
/// exactly (summed as kiddo sums them, x then y then z) and read the same way.
pub fn kth_nearest_distinct_on_grid(
    points: &[P3],
    queries: &[P3],
    k: usize,
) -> Result<Vec<Option<f32>>, MatchError> {
    if points.is_empty() {
        return Err(MatchError::TooFewPoints {
            what: "cloud",
            points: 0,
            needed: 1,
        });
    }
    if points
        .iter()
        .chain(queries)
        .any(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(MatchError::NonFinite { what: "cloud" });
    }
    use rayon::prelude::*;
    let grid = Grid::new(points);
    let want = (2 * k + 2).min(points.len());
    // Each query on its own (in the calling pool's threads), answers in the queries' order.
    Ok(queries
        .par_iter()
        .with_min_len(64)
        .map_init(
            || Vec::with_capacity(want + 1),
            |best, q| {
                grid.nearest_squared(points, q, want, best);
                best.iter()
                    .copied()
                    .filter(|&d| d > 1e-12)
                    .nth(k.checked_sub(1)?)
                    .map(f32::sqrt)
            },
        )
        .collect())
}

/// Per-axis minimum and maximum of `points` (infinite for none). Large clouds are split over
/// the threads of the calling pool: minima and maxima do not depend on the split.
pub fn bounds(points: &[P3]) -> ([f64; 3], [f64; 3]) {
    use rayon::prelude::*;
    let of = |chunk: &[P3]| {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in chunk {
            for a in 0..3 {
                lo[a] = lo[a].min(f64::from(p[a]));
                hi[a] = hi[a].max(f64::from(p[a]));
            }
        }
        (lo, hi)
    };
    if points.len() < PARALLEL_POINTS {
        return of(points);
    }
    points.par_chunks(PARALLEL_POINTS).map(of).reduce(
        || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(l1, h1), (l2, h2)| {
            (
                [0, 1, 2].map(|a| l1[a].min(l2[a])),
                [0, 1, 2].map(|a| h1[a].max(h2[a])),
            )
        },
    )
}

/// Clouds of at least this many points have their per-point passes (bounds, grid cells)
/// split over threads; below it the split costs more than it saves.
const PARALLEL_POINTS: usize = 1 << 15;

/// Points sorted into the cells of a uniform grid over their bounding box (a counting sort:
/// `order[start[c]..start[c + 1]]` are the points of cell `c`).
struct Grid {
    lo: [f64; 3],
    cell: f64,
    dims: [usize; 3],
    start: Vec<u32>,
    order: Vec<u32>,
}

impl Grid {
    /// About one cell per point over the box's volume (a scan is a surface, so its occupied
    /// cells hold tens of points); thin boxes are widened to a thousandth of their extent.
    fn new(points: &[P3]) -> Self {
        let (lo, hi) = bounds(points);
        let extent = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let largest = extent.iter().copied().fold(0.0, f64::max);
        let floor = (largest * 1e-3).max(1e-6);
        let volume: f64 = extent.iter().map(|e| e.max(floor)).product();
        let cell = (volume / points.len() as f64).cbrt().max(floor);
        // (e / cell) multiplies out to about the point count: no axis can be too long.
        let dims = extent.map(|e| (e / cell) as usize + 1);
        let grid = Self {
            lo,
            cell,
            dims,
            start: Vec::new(),
            order: Vec::new(),
        };
        let cell = |p: &P3| grid.index(grid.cell_of(p)) as u32;
        let cells: Vec<u32> = if points.len() < PARALLEL_POINTS {
            points.iter().map(cell).collect()
        } else {
            use rayon::prelude::*;
            points
                .par_iter()
                .with_min_len(PARALLEL_POINTS)
                .map(cell)
                .collect()
        };
        let n_cells = dims.iter().product::<usize>();
        let mut start = vec![0u32; n_cells + 1];
        for &c in &cells {
            start[c as usize + 1] += 1;
        }
        for c in 0..n_cells {
            start[c + 1] += start[c];
        }
        let mut cursor = start.clone();
        let mut order = vec![0u32; points.len()];
        for (i, &c) in cells.iter().enumerate() {
            order[cursor[c as usize] as usize] = i as u32;
            cursor[c as usize] += 1;
        }
        Self {
            start,
            order,
            ..grid
        }
    }

    /// The cell holding `p`, clamped into the grid (`as` truncates, which is the floor at
    /// and above the box's low corner and saturates to 0 below it, without libm's `floor`).
    fn cell_of(&self, p: &P3) -> [usize; 3] {
        [0, 1, 2].map(|a| {
            let x = (f64::from(p[a]) - self.lo[a]) / self.cell;
            (x as usize).min(self.dims[a] - 1)
        })
    }

    fn index(&self, c: [usize; 3]) -> usize {
        (c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]
    }

    /// Visits the cells around `q`'s cell ring by ring (ring `r` is the shell of cells `r`
    /// away in the largest axis), calling `visit` with each cell's point indices, until
    /// `visit` says stop or `enough(outside)` holds, where every point outside the rings
    /// searched lies at least `outside` mm from `q`.
    fn search_rings<S>(
        &self,
        q: &P3,
        state: &mut S,
        visit: impl Fn(&mut S, &[u32]) -> ControlFlow<()>,
        enough: impl Fn(&S, f64) -> bool,
    ) {
        let c = self.cell_of(q);
        let reach = (0..3)
            .map(|a| c[a].max(self.dims[a] - 1 - c[a]))
            .max()
            .unwrap_or(0);
        for r in 0..=reach {
            let range = |a: usize| c[a].saturating_sub(r)..=(c[a] + r).min(self.dims[a] - 1);
            for x in range(0) {
                for y in range(1) {
                    // Inside the ring's shell in x and y, only its two z faces are new.
                    let shell = x.abs_diff(c[0]).max(y.abs_diff(c[1])) == r;
                    for z in range(2) {
                        if !shell && z.abs_diff(c[2]) != r {
                            continue;
                        }
                        let cell = self.index([x, y, z]);
                        let (s, e) = (self.start[cell] as usize, self.start[cell + 1] as usize);
                        if visit(state, &self.order[s..e]).is_break() {
                            return;
                        }
                    }
                }
            }
            // Every point outside the searched block lies at least this far from q.
            let outside = (0..3)
                .map(|a| {
                    let below = if c[a] > r {
                        f64::from(q[a]) - (self.lo[a] + (c[a] - r) as f64 * self.cell)
                    } else {
                        f64::INFINITY
                    };
                    let above = if c[a] + r + 1 < self.dims[a] {
                        self.lo[a] + (c[a] + r + 1) as f64 * self.cell - f64::from(q[a])
                    } else {
                        f64::INFINITY
                    };
                    below.min(above)
                })
                .fold(f64::INFINITY, f64::min);
            if enough(state, outside) {
                return;
            }
        }
    }

    /// The `want` smallest squared distances from `q` to `points`, ascending, into `best`.
    fn nearest_squared(&self, points: &[P3], q: &P3, want: usize, best: &mut Vec<f32>) {
        best.clear();
        self.search_rings(
            q,
            best,
            |best, cell| {
                for &i in cell {
                    let d = squared_distance(&points[i as usize], q);
                    if best.len() < want || d < best[want - 1] {
                        let at = best.partition_point(|&b| b <= d);
                        best.insert(at, d);
                        best.truncate(want);
                    }
                }
                ControlFlow::Continue(())
            },
            // A margin for the float squares: a point at the bound never rounds below it.
            |best, outside| {
                best.len() == want && f64::from(best[want - 1]) < outside * outside * (1.0 - 1e-4)
            },
        );
    }
}

/// Squared distance summed as kiddo sums it (x, then y, then z), so that answers found on a
/// grid are the kd-tree's bit for bit.
fn squared_distance(p: &P3, q: &P3) -> f32 {
    (p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) + (p[2] - q[2]) * (p[2] - q[2])
}

/// Exact nearest-point queries on a uniform grid: for a dense surface asked about points
/// on or near it (a part's surface at another pose), where the answer is a cell or two
/// away and "is any point within r" stops at the first one found. Distances are
/// [`PointIndex`]'s bit for bit.
pub struct GridIndex {
    grid: Grid,
    points: Vec<P3>,
    lo: [f64; 3],
    hi: [f64; 3],
}

impl std::fmt::Debug for GridIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GridIndex")
            .field("len", &self.points.len())
            .finish()
    }
}

impl GridIndex {
    /// Indexes `points` (non-empty, finite).
    pub fn new(what: &'static str, points: &[P3]) -> Result<Self, MatchError> {
        indexable(what, points)?;
        let (lo, hi) = bounds(points);
        Ok(Self {
            grid: Grid::new(points),
            points: points.to_vec(),
            lo,
            hi,
        })
    }

    /// Squared distance to the nearest point, mm^2 ([`PointIndex::nearest`]'s).
    pub fn nearest_squared(&self, q: &P3) -> f32 {
        let mut best = Vec::with_capacity(2);
        self.grid.nearest_squared(&self.points, q, 1, &mut best);
        best[0]
    }

    /// Whether some point lies within `radius_squared` (mm^2) of `q`: exactly whether
    /// [`GridIndex::nearest_squared`] is at most it.
    pub fn any_within(&self, q: &P3, radius_squared: f32) -> bool {
        let r2 = f64::from(radius_squared);
        // Far outside the box: nothing near (with the float squares' margin).
        let gap2: f64 = (0..3)
            .map(|a| {
                let x = f64::from(q[a]);
                let d = (self.lo[a] - x).max(x - self.hi[a]).max(0.0);
                d * d
            })
            .sum();
        if gap2 * (1.0 - 1e-4) > r2 {
            return false;
        }
        let mut found = false;
        self.grid.search_rings(
            q,
            &mut found,
            |found, cell| {
                *found = cell
                    .iter()
                    .any(|&i| squared_distance(&self.points[i as usize], q) <= radius_squared);
                if *found {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            },
            |_, outside| r2 < outside * outside * (1.0 - 1e-4),
        );
        found
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic xorshift in [0, 1).
    fn unit(state: &mut u64) -> f32 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        (*state >> 40) as f32 / (1u64 << 24) as f32
    }

    fn kd_tree_answers(points: &[P3], queries: &[P3], k: usize) -> Vec<Option<f32>> {
        let index = PointIndex::new("cloud", points).unwrap();
        queries
            .iter()
            .map(|q| index.kth_nearest_distinct(q, k))
            .collect()
    }

    #[test]
    fn the_grid_gives_the_kd_trees_kth_nearest_distinct_bit_for_bit() {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut clouds: Vec<Vec<P3>> = Vec::new();
        // A noisy belt with parts on it, a few far strays, and every 7th point doubled.
        let mut belt: Vec<P3> = (0..20_000)
            .map(|_| {
                let (x, y) = (600.0 * unit(&mut s), 400.0 * unit(&mut s));
                let z = if (x - 300.0).abs() < 50.0 {
                    30.0 * unit(&mut s)
                } else {
                    0.1 * unit(&mut s)
                };
                [x, y, z]
            })
            .collect();
        belt.extend((0..5).map(|i| [-5000.0 + 100.0 * i as f32, 9000.0, 3000.0]));
        let doubled: Vec<P3> = belt.iter().step_by(7).copied().collect();
        belt.extend(doubled);
        clouds.push(belt);
        // A lattice (many equal distances), a line, one point repeated, and a tiny cloud.
        clouds.push(
            (0..30)
                .flat_map(|i| (0..30).map(move |j| [i as f32 * 0.5, j as f32 * 0.5, 2.0]))
                .collect(),
        );
        clouds.push((0..500).map(|i| [i as f32 * 0.3, 1.0, -1.0]).collect());
        clouds.push(vec![[1.0, 2.0, 3.0]; 40]);
        clouds.push(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        for (n, points) in clouds.iter().enumerate() {
            let mut queries: Vec<P3> = points.iter().step_by(13).copied().collect();
            queries.push([1e4, -1e4, 50.0]); // outside the grid
            for k in [1, 2, 8] {
                let grid = kth_nearest_distinct_on_grid(points, &queries, k).unwrap();
                let tree = kd_tree_answers(points, &queries, k);
                let differ = grid
                    .iter()
                    .zip(&tree)
                    .filter(|(a, b)| a.map(f32::to_bits) != b.map(f32::to_bits))
                    .count();
                assert_eq!(differ, 0, "cloud {n}, k {k}");
                // Not all None (the query outside the grid answers on the repeated point).
                let answerable = points.len() > k;
                assert_eq!(
                    tree.iter().any(Option::is_some),
                    answerable,
                    "cloud {n}, k {k}"
                );
            }
        }
        assert!(kth_nearest_distinct_on_grid(&[], &[], 8).is_err());
        assert!(kth_nearest_distinct_on_grid(&[[f32::NAN, 0.0, 0.0]], &[], 8).is_err());
    }

    #[test]
    fn the_grid_index_answers_as_the_kd_tree_near_and_far_from_a_surface() {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        // A bent sheet, 3 mm thick, sampled densely: a part's surface.
        let mut sheet: Vec<P3> = (0..30_000)
            .map(|_| {
                let (u, v, w) = (80.0 * unit(&mut s), 40.0 * unit(&mut s), 3.0 * unit(&mut s));
                if u < 50.0 {
                    [u, v, w]
                } else {
                    [50.0 + w, v, u - 50.0]
                }
            })
            .collect();
        sheet.extend([[0.0, 0.0, 0.0]; 3]); // repeated points
        let tree = PointIndex::new("sheet", &sheet).unwrap();
        let grid = GridIndex::new("sheet", &sheet).unwrap();
        // Queries on it, jittered off it by up to 8 mm, and far outside its box.
        let mut queries: Vec<P3> = sheet
            .iter()
            .step_by(11)
            .map(|p| {
                let j = 8.0 * unit(&mut s);
                [
                    p[0] + j * (unit(&mut s) - 0.5),
                    p[1],
                    p[2] + j * (unit(&mut s) - 0.5),
                ]
            })
            .collect();
        queries.extend([[-3.0, -2.0, -1.0], [500.0, 20.0, 0.0], [-1e4, 1e4, 3.0]]);
        let (mut near, mut far) = (0, 0);
        for q in &queries {
            let d = tree.nearest(q).1;
            assert_eq!(grid.nearest_squared(q).to_bits(), d.to_bits(), "{q:?}");
            for r2 in [
                0.25f32,
                2.25,
                6.0,
                d,
                f32::from_bits(d.to_bits().saturating_sub(1)),
            ] {
                assert_eq!(grid.any_within(q, r2), d <= r2, "{q:?} within {r2}");
            }
            if grid.any_within(q, 2.25) {
                near += 1;
            } else {
                far += 1;
            }
        }
        // Both answers asked for many times (not all one way).
        assert!(near > 200 && far > 200, "near {near}, far {far}");
        assert!(GridIndex::new("sheet", &[]).is_err());
        assert!(GridIndex::new("sheet", &[[0.0, f32::INFINITY, 0.0]]).is_err());
    }
}
