//! Exact neighbour queries over a fixed point set (kiddo's immutable kd-tree).

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

impl PointIndex {
    /// Indexes `points` (non-empty, finite).
    pub fn new(what: &'static str, points: &[P3]) -> Result<Self, MatchError> {
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
    let grid = Grid::new(points);
    let want = (2 * k + 2).min(points.len());
    let mut best = Vec::with_capacity(want + 1);
    Ok(queries
        .iter()
        .map(|q| {
            grid.nearest_squared(points, q, want, &mut best);
            best.iter()
                .copied()
                .filter(|&d| d > 1e-12)
                .nth(k.checked_sub(1)?)
                .map(f32::sqrt)
        })
        .collect())
}

/// Per-axis minimum and maximum of `points` (infinite for none).
pub fn bounds(points: &[P3]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(f64::from(p[a]));
            hi[a] = hi[a].max(f64::from(p[a]));
        }
    }
    (lo, hi)
}

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
        let cells: Vec<u32> = points
            .iter()
            .map(|p| grid.index(grid.cell_of(p)) as u32)
            .collect();
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

    /// The `want` smallest squared distances from `q` to `points`, ascending, into `best`.
    /// Rings of cells around `q`'s cell are searched until every point outside them is
    /// farther than the `want`-th found.
    fn nearest_squared(&self, points: &[P3], q: &P3, want: usize, best: &mut Vec<f32>) {
        best.clear();
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
                        for &i in &self.order[s..e] {
                            let p = &points[i as usize];
                            let d = (p[0] - q[0]) * (p[0] - q[0])
                                + (p[1] - q[1]) * (p[1] - q[1])
                                + (p[2] - q[2]) * (p[2] - q[2]);
                            if best.len() < want || d < best[want - 1] {
                                let at = best.partition_point(|&b| b <= d);
                                best.insert(at, d);
                                best.truncate(want);
                            }
                        }
                    }
                }
            }
            if best.len() == want {
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
                // A margin for the float squares: a point at the bound never rounds below it.
                if f64::from(best[want - 1]) < outside * outside * (1.0 - 1e-4) {
                    return;
                }
            }
        }
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
}
