//! Matching a rigid part to a whole scan, in plain Rust over plain data.
//!
//! - [`ppf`]: point-pair-feature voting over the whole scene (Drost et al. 2010, with Vidal et
//!   al. 2018's neighbour-bin voting): many pose hypotheses, several per part, from every
//!   part of a pile at once;
//! - [`poses`]: pose clustering under the part's symmetries;
//! - [`view`]: the sensor's view of the scene as a range grid, and the model rendered into it
//!   at a hypothesis pose, so each hypothesis is judged only on the surface the sensor could
//!   see, with free-space and missing-surface contradictions;
//! - [`explain`]: hypotheses compete for scene surface; a greedy scene explanation keeps a
//!   set of parts that explains the pile, each part once.
//! - [`faces`]: pose hypotheses from flat faces (a scene patch laid on a model face of about
//!   its size), where voting cannot place a part that shows one flat face.
//!
//! Lengths are millimetres, angles radians unless a name says degrees. Nothing here calls
//! PCL: normals, down-sampling and ICP come from the caller (binpick uses PCL for them).

pub mod explain;
pub mod faces;
pub mod index;
pub mod poses;
pub mod ppf;
pub mod view;

pub use explain::{ExplainConfig, Explanation, Rejection, explain_scene};
pub use index::{GridIndex, PointIndex};
pub use poses::{PoseCluster, PoseClustering, Symmetries, cluster_poses};
pub use ppf::{PpfConfig, PpfModel, Vote, VotingConfig};
pub use view::{NEIGHBOUR_FIT_WEIGHT, RangeGrid, Sensor, ViewConfig, ViewScore};

/// One point `[x, y, z]`, mm.
pub type P3 = [f32; 3];

/// Points with one unit normal each.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct OrientedPoints {
    pub points: Vec<P3>,
    pub normals: Vec<P3>,
}

impl OrientedPoints {
    /// Points and normals of equal length.
    pub fn new(points: Vec<P3>, normals: Vec<P3>) -> Result<Self, MatchError> {
        let s = Self { points, normals };
        s.check("points")?;
        Ok(s)
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Keeps the points whose normal is defined (finite, non-zero).
    pub fn with_defined_normals(self) -> Self {
        let (points, normals) = self
            .points
            .into_iter()
            .zip(self.normals)
            .filter(|(p, n)| {
                let len2: f32 = n.iter().map(|c| c * c).sum();
                p.iter().all(|c| c.is_finite()) && len2.is_finite() && len2 > 1e-12
            })
            .unzip();
        Self { points, normals }
    }

    pub(crate) fn check(&self, what: &'static str) -> Result<(), MatchError> {
        if self.points.len() != self.normals.len() {
            return Err(MatchError::Mismatch {
                what,
                points: self.points.len(),
                normals: self.normals.len(),
            });
        }
        if self.points.iter().any(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(MatchError::NonFinite { what });
        }
        Ok(())
    }
}

/// What can go wrong while matching.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MatchError {
    #[error("{field}: {expected}")]
    Config {
        field: &'static str,
        expected: &'static str,
    },
    #[error("{what}: {points} point(s), at least {needed} needed")]
    TooFewPoints {
        what: &'static str,
        points: usize,
        needed: usize,
    },
    #[error(
        "{what}: {points} points, more than the {limit} this stage handles (sample it coarser)"
    )]
    TooManyPoints {
        what: &'static str,
        points: usize,
        limit: usize,
    },
    #[error("{what}: {points} points but {normals} normals")]
    Mismatch {
        what: &'static str,
        points: usize,
        normals: usize,
    },
    #[error("{what}: {got} given for {expected} hypotheses")]
    Count {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{what}: a coordinate is not finite")]
    NonFinite { what: &'static str },
    #[error("{what}: a normal is zero or not finite")]
    BadNormal { what: &'static str },
    #[error("{what}: kd-tree: {message}")]
    Index { what: &'static str, message: String },
}

impl MatchError {
    pub(crate) fn config(field: &'static str, expected: &'static str) -> Self {
        Self::Config { field, expected }
    }
}

/// Keeps, per cubic cell of `leaf` mm and per facing (the axis direction nearest the normal,
/// one of six), the point nearest the cell's centre, in input order. The two sides of a thin
/// sheet fall in one cell at coarse leaves but face opposite ways, so both survive (a plain
/// voxel or uniform sampling keeps one of them at random). Deterministic.
pub fn subsample_by_facing(points: &OrientedPoints, leaf: f64) -> OrientedPoints {
    use std::collections::HashMap;
    let mut best: HashMap<([i64; 3], u8), (usize, f64)> = HashMap::new();
    for (i, (p, n)) in points.points.iter().zip(&points.normals).enumerate() {
        let cell = p.map(|c| (f64::from(c) / leaf).floor() as i64);
        let facing = facing(n);
        let d2: f64 = (0..3)
            .map(|k| {
                let centre = (cell[k] as f64 + 0.5) * leaf;
                (f64::from(p[k]) - centre).powi(2)
            })
            .sum();
        best.entry((cell, facing))
            .and_modify(|e| {
                if d2 < e.1 {
                    *e = (i, d2);
                }
            })
            .or_insert((i, d2));
    }
    let mut keep: Vec<usize> = best.into_values().map(|(i, _)| i).collect();
    keep.sort_unstable();
    OrientedPoints {
        points: keep.iter().map(|&i| points.points[i]).collect(),
        normals: keep.iter().map(|&i| points.normals[i]).collect(),
    }
}

/// Which of the six axis directions a normal is nearest to.
fn facing(n: &P3) -> u8 {
    let (mut axis, mut best) = (0usize, 0.0f32);
    for (k, c) in n.iter().enumerate() {
        if c.abs() > best {
            best = c.abs();
            axis = k;
        }
    }
    (axis as u8) * 2 + u8::from(n[axis] < 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_sides_of_a_thin_sheet_survive() {
        // A 1 mm thick sheet: top face z = 1 (normal +z), bottom z = 0 (normal -z).
        let mut points = Vec::new();
        let mut normals = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (i as f32 * 0.5, j as f32 * 0.5);
                points.push([x, y, 1.0]);
                normals.push([0.0, 0.0, 1.0]);
                points.push([x, y, 0.0]);
                normals.push([0.0, 0.0, -1.0]);
            }
        }
        let s = subsample_by_facing(&OrientedPoints { points, normals }, 4.0);
        let up = s.normals.iter().filter(|n| n[2] > 0.0).count();
        let down = s.normals.iter().filter(|n| n[2] < 0.0).count();
        assert_eq!((up, down), (25, 25), "5 x 5 cells, both faces in each");
        assert_eq!(subsample_by_facing(&s, 4.0), s, "idempotent");
    }
}
