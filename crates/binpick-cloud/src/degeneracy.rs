//! Clouds that cannot describe a surface: one point, one position, one line.

use std::fmt;

use crate::{Point, PointCloud};

/// Why a cloud has no surface. Lengths are in the cloud's units (millimetres inside binpick).
/// A flat (coplanar) cloud is not degenerate: a part seen from one side can be flat.
#[derive(Clone, Debug, PartialEq)]
pub enum Degeneracy {
    /// Exactly one point.
    SinglePoint { at: Point },
    /// Several points, all at one position (equal up to f32 rounding).
    AllIdentical { points: usize, at: Point },
    /// All points on one straight line: none farther from it than
    /// [`COLLINEAR_TOLERANCE`] x its length.
    Collinear {
        points: usize,
        /// Distance between the two ends of the line.
        length: f64,
        /// Largest distance of a point from the line.
        max_offset: f64,
    },
}

/// A cloud is collinear when no point is farther than this fraction of its length from the
/// line through its two extreme points (a 100 mm long cloud within 0.01 mm of a line).
pub const COLLINEAR_TOLERANCE: f64 = 1e-4;

impl fmt::Display for Degeneracy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Degeneracy::SinglePoint { at } => write!(
                f,
                "the cloud is a single point ({}, {}, {}): it has no surface to match",
                at[0], at[1], at[2]
            ),
            Degeneracy::AllIdentical { points, at } => write!(
                f,
                "all {points} points are at the same position ({}, {}, {}): the cloud has no \
                 extent",
                at[0], at[1], at[2]
            ),
            Degeneracy::Collinear {
                points,
                length,
                max_offset,
            } => write!(
                f,
                "all {points} points lie on one straight line ({length:.4} mm long, none more \
                 than {max_offset:.3e} mm off it): the cloud has no surface to match"
            ),
        }
    }
}

fn to_f64(p: &Point) -> [f64; 3] {
    [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]
}

fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum()
}

/// The point of `points` farthest from `from`.
fn farthest<'a>(points: impl Iterator<Item = &'a Point>, from: [f64; 3]) -> [f64; 3] {
    points
        .map(to_f64)
        .fold((from, 0.0), |(best, bd), p| {
            let d = dist2(p, from);
            if d > bd { (p, d) } else { (best, bd) }
        })
        .0
}

impl PointCloud {
    /// Whether the cloud is degenerate (see [`Degeneracy`]); `None` for a usable or empty
    /// cloud. Non-finite points are ignored. Three passes over the points and a fourth that
    /// stops at the first point off the line (on a scan, within the first few).
    pub fn degeneracy(&self) -> Option<Degeneracy> {
        let finite = || {
            self.points
                .iter()
                .filter(|p| p.iter().all(|c| c.is_finite()))
        };
        let first = *finite().next()?;
        if finite().nth(1).is_none() {
            return Some(Degeneracy::SinglePoint { at: first });
        }
        // f32 rounding of the coordinates themselves.
        let magnitude = finite()
            .flat_map(|p| p.iter())
            .fold(0.0f64, |m, &c| m.max(f64::from(c).abs()));
        let rounding = 4.0 * f64::from(f32::EPSILON) * magnitude.max(f64::MIN_POSITIVE);
        // Ends of the cloud's longest extent (two farthest-point sweeps).
        let a = farthest(finite(), to_f64(&first));
        let b = farthest(finite(), a);
        let length = dist2(a, b).sqrt();
        if length <= rounding {
            return Some(Degeneracy::AllIdentical {
                points: finite().count(),
                at: first,
            });
        }
        let dir = [
            (b[0] - a[0]) / length,
            (b[1] - a[1]) / length,
            (b[2] - a[2]) / length,
        ];
        let limit = COLLINEAR_TOLERANCE * length + rounding;
        let mut max_offset = 0.0f64;
        let mut points = 0;
        for p in finite() {
            let d = [
                f64::from(p[0]) - a[0],
                f64::from(p[1]) - a[1],
                f64::from(p[2]) - a[2],
            ];
            let along = d[0] * dir[0] + d[1] * dir[1] + d[2] * dir[2];
            let off2 = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) - along * along;
            max_offset = max_offset.max(off2.max(0.0).sqrt());
            if max_offset > limit {
                return None;
            }
            points += 1;
        }
        Some(Degeneracy::Collinear {
            points,
            length,
            max_offset,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn degenerate_clouds_are_recognised() {
        assert_eq!(PointCloud::default().degeneracy(), None);
        let one = PointCloud::new(vec![[1.0, 2.0, 3.0]]);
        assert!(matches!(
            one.degeneracy(),
            Some(Degeneracy::SinglePoint { .. })
        ));
        let same = PointCloud::new(vec![[5.0, 5.0, 5.0]; 100]);
        let d = same.degeneracy().unwrap();
        assert!(matches!(d, Degeneracy::AllIdentical { points: 100, .. }));
        assert!(
            d.to_string()
                .contains("all 100 points are at the same position")
        );
        let line = PointCloud::new(
            (0..50)
                .map(|i| [i as f32 * 2.0 + 10.0, -(i as f32), 3.0 * i as f32])
                .collect(),
        );
        let d = line.degeneracy().unwrap();
        assert!(matches!(d, Degeneracy::Collinear { points: 50, .. }), "{d}");
        assert!(d.to_string().contains("lie on one straight line"), "{d}");
        // One point 0.5 off a 100-long line: a (thin) surface, not a line.
        let mut near = PointCloud::new((0..=100).map(|i| [i as f32, 0.0, 0.0]).collect());
        near.points.push([50.0, 0.5, 0.0]);
        assert_eq!(near.degeneracy(), None);
        // A flat cloud is fine.
        let plane = PointCloud::new(
            (0..100)
                .map(|i| [(i % 10) as f32, (i / 10) as f32, 7.0])
                .collect(),
        );
        assert_eq!(plane.degeneracy(), None);
        // NaNs are ignored.
        let mut with_nan = same.clone();
        with_nan.points.push([f32::NAN, 0.0, 0.0]);
        assert!(matches!(
            with_nan.degeneracy(),
            Some(Degeneracy::AllIdentical { .. })
        ));
    }
}
