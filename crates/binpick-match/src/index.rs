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
