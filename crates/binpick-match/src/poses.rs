//! Pose clustering (Drost et al. 2010, 3.4): votes from many reference points that agree on a
//! pose, up to the part's symmetries, are one hypothesis whose weight is their summed votes.

use std::collections::HashMap;

use nalgebra::{
    Isometry3, Point3, Quaternion, Translation3, Unit, UnitQuaternion, Vector3, Vector4,
};

use crate::MatchError;
use crate::ppf::Vote;

/// Rigid symmetries of a part: transforms `S` of the model frame with `model = S * model`,
/// the identity first. A continuous symmetry (a revolution) is carried as samples of it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Symmetries {
    transforms: Vec<Isometry3<f64>>,
}

impl Default for Symmetries {
    fn default() -> Self {
        Self::none()
    }
}

impl Symmetries {
    /// No symmetry: the identity only.
    pub fn none() -> Self {
        Self {
            transforms: vec![Isometry3::identity()],
        }
    }

    /// The given transforms; the identity is added first if missing, near-duplicates
    /// (within 1e-6) are dropped.
    pub fn new(transforms: &[Isometry3<f64>]) -> Self {
        let mut out = Self::none();
        for t in transforms {
            out.push(*t);
        }
        out
    }

    /// A revolution about the axis through `point` along `direction`, sampled every
    /// `step_deg` degrees, composed with `extra` (for example the half-turn that turns a
    /// washer upside down).
    pub fn revolution(
        point: [f64; 3],
        direction: [f64; 3],
        step_deg: f64,
        extra: &[Isometry3<f64>],
    ) -> Result<Self, MatchError> {
        let dir = Vector3::from(direction);
        if !(dir.norm().is_finite() && dir.norm() > 1e-9) {
            return Err(MatchError::config(
                "revolution_axis.direction",
                "expected a finite, non-zero vector",
            ));
        }
        if !(step_deg.is_finite() && step_deg > 0.0 && step_deg <= 180.0) {
            return Err(MatchError::config("step_deg", "expected (0, 180] degrees"));
        }
        let axis = Unit::new_normalize(dir);
        let c = Vector3::from(point);
        let steps = (360.0 / step_deg).round().max(1.0) as usize;
        let mut out = Self::none();
        let mut bases = vec![Isometry3::identity()];
        bases.extend_from_slice(extra);
        for b in &bases {
            for k in 0..steps {
                let angle = (k as f64 * 360.0 / steps as f64).to_radians();
                let r = Translation3::from(c)
                    * UnitQuaternion::from_axis_angle(&axis, angle)
                    * Translation3::from(-c);
                out.push(r * b);
            }
        }
        Ok(out)
    }

    fn push(&mut self, t: Isometry3<f64>) {
        let dup = self.transforms.iter().any(|s| {
            (s.translation.vector - t.translation.vector).norm() < 1e-6
                && s.rotation.angle_to(&t.rotation) < 1e-6
        });
        if !dup {
            self.transforms.push(t);
        }
    }

    /// The transforms, identity first.
    pub fn transforms(&self) -> &[Isometry3<f64>] {
        &self.transforms
    }

    /// Whether only the identity is listed.
    pub fn is_trivial(&self) -> bool {
        self.transforms.len() == 1
    }

    /// Smallest rotation angle between `a` and `b * S` over the symmetries, radians.
    pub fn angle(&self, a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
        self.closest(a, b).1
    }

    /// The symmetry `S` whose `b * S` is rotated least from `a` (first in symmetry order on
    /// ties within 1e-12 rad), and that smallest angle, radians.
    pub fn closest(&self, a: &Isometry3<f64>, b: &Isometry3<f64>) -> (Isometry3<f64>, f64) {
        let mut best = Isometry3::identity();
        let (mut best_angle, mut smallest) = (f64::INFINITY, f64::INFINITY);
        for s in &self.transforms {
            let angle = a.rotation.angle_to(&(b.rotation * s.rotation));
            if angle < best_angle - 1e-12 {
                best = *s;
                best_angle = angle;
            }
            smallest = smallest.min(angle);
        }
        (best, smallest)
    }

    /// The equivalent pose `pose * S` whose rotation is closest to the identity: one pose per
    /// equivalence class (first in symmetry order on ties).
    pub fn canonical(&self, pose: &Isometry3<f64>) -> Isometry3<f64> {
        pose * self.canonical_symmetry(pose)
    }

    /// The symmetry `S` of [`canonical`](Self::canonical).
    pub fn canonical_symmetry(&self, pose: &Isometry3<f64>) -> Isometry3<f64> {
        let mut best = Isometry3::identity();
        let mut best_angle = f64::INFINITY;
        for s in &self.transforms {
            let a = (pose * s).rotation.angle();
            if a < best_angle - 1e-12 {
                best = *s;
                best_angle = a;
            }
        }
        best
    }
}

/// Tolerances of the pose clustering.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseClustering {
    /// Poses whose model centres are closer than this are candidates for one cluster, mm.
    /// Drost: 1/10 of the diameter. Range > 0.
    pub translation_mm: f64,
    /// ... and whose rotations differ by less than this (up to symmetry), degrees. Default 24
    /// (two rotation bins). Range 1-180.
    pub rotation_deg: f64,
}

impl PoseClustering {
    /// Rejects values outside the documented ranges, naming the field.
    pub fn validate(&self) -> Result<(), MatchError> {
        if !(self.translation_mm.is_finite() && self.translation_mm > 0.0) {
            return Err(MatchError::config("translation_mm", "expected > 0 mm"));
        }
        if !(1.0..=180.0).contains(&self.rotation_deg) {
            return Err(MatchError::config("rotation_deg", "expected 1-180 deg"));
        }
        Ok(())
    }
}

/// Votes that agree on one pose.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseCluster {
    /// The vote-weighted mean pose of its members, model -> scene.
    pub pose: Isometry3<f64>,
    /// Summed votes of its members.
    pub votes: u32,
    /// Number of member votes (reference points and peaks that agree).
    pub members: u32,
}

/// Groups `votes` (any order) into clusters, strongest first: each vote, strongest first,
/// joins the first cluster whose pose is within the tolerances (the part's centre `centre`,
/// model frame, moved by both poses; rotation up to symmetry), or starts a new one. A
/// cluster's pose is the vote-weighted mean of its members' (each taken in the symmetric
/// form closest to the cluster's first; Drost et al. 2010, Vidal et al. 2018): one vote's
/// pose carries its reference point's normal and rotation bin errors, the mean averages
/// them out. Deterministic: ties are broken by the votes' order.
pub fn cluster_poses(
    votes: &[Vote],
    centre: &Point3<f64>,
    symmetries: &Symmetries,
    tolerances: &PoseClustering,
) -> Result<Vec<PoseCluster>, MatchError> {
    tolerances.validate()?;
    let mut order: Vec<usize> = (0..votes.len()).collect();
    order.sort_by(|&a, &b| votes[b].votes.cmp(&votes[a].votes).then(a.cmp(&b)));
    let cell = tolerances.translation_mm;
    let max_angle = tolerances.rotation_deg.to_radians();
    let mut clusters: Vec<PoseCluster> = Vec::new();
    let mut centres: Vec<Point3<f64>> = Vec::new();
    // Per cluster: vote-weighted sums of its members' translations and quaternions (the
    // weights sum to the cluster's votes).
    let mut sums: Vec<(Vector3<f64>, Vector4<f64>)> = Vec::new();
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    let key = |p: &Point3<f64>| {
        [
            (p.x / cell).floor() as i64,
            (p.y / cell).floor() as i64,
            (p.z / cell).floor() as i64,
        ]
    };
    for i in order {
        let v = &votes[i];
        let c = v.pose * centre;
        let k = key(&c);
        let mut joined = None;
        'search: for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(list) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) else {
                        continue;
                    };
                    for &ci in list {
                        if joined.is_some_and(|(j, _)| j < ci) || (centres[ci] - c).norm() >= cell {
                            continue;
                        }
                        let (s, angle) = symmetries.closest(&clusters[ci].pose, &v.pose);
                        if angle < max_angle {
                            joined = Some((ci, s));
                        }
                    }
                    if joined.is_some_and(|(j, _)| j == 0) {
                        break 'search;
                    }
                }
            }
        }
        match joined {
            Some((ci, s)) => {
                clusters[ci].votes += v.votes;
                clusters[ci].members += 1;
                // The member in its symmetric form closest to the cluster's first pose.
                add_pose(&mut sums[ci], &clusters[ci].pose, &(v.pose * s), v.votes);
            }
            None => {
                grid.entry(k).or_default().push(clusters.len());
                centres.push(c);
                let mut sum = (Vector3::zeros(), Vector4::zeros());
                add_pose(&mut sum, &v.pose, &v.pose, v.votes);
                sums.push(sum);
                clusters.push(PoseCluster {
                    pose: v.pose,
                    votes: v.votes,
                    members: 1,
                });
            }
        }
    }
    for (c, (t, q)) in clusters.iter_mut().zip(&sums) {
        if c.votes > 0 {
            let w = f64::from(c.votes);
            let q = UnitQuaternion::from_quaternion(Quaternion::from(*q / w));
            c.pose = Isometry3::from_parts(Translation3::from(*t / w), q);
        }
    }
    clusters.sort_by_key(|c| std::cmp::Reverse(c.votes));
    Ok(clusters)
}

/// Adds `pose`, weighted by `votes`, to a cluster's sums of translations and quaternions,
/// the quaternion on the hemisphere of the cluster's `first` (q and -q are one rotation).
fn add_pose(
    sum: &mut (Vector3<f64>, Vector4<f64>),
    first: &Isometry3<f64>,
    pose: &Isometry3<f64>,
    votes: u32,
) {
    let w = f64::from(votes);
    let q = pose.rotation.into_inner().coords;
    let sign = if first.rotation.into_inner().coords.dot(&q) < 0.0 {
        -1.0
    } else {
        1.0
    };
    sum.0 += w * pose.translation.vector;
    sum.1 += (sign * w) * q;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vote(deg_about_z: f64, t: [f64; 3], votes: u32, reference: u32) -> Vote {
        Vote {
            pose: Isometry3::from_parts(
                Translation3::new(t[0], t[1], t[2]),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), deg_about_z.to_radians()),
            ),
            votes,
            reference,
        }
    }

    fn wide() -> PoseClustering {
        PoseClustering {
            translation_mm: 10.0,
            rotation_deg: 24.0,
        }
    }

    fn degrees_about_z(pose: &Isometry3<f64>) -> f64 {
        let (_, _, yaw) = pose.rotation.euler_angles();
        yaw.to_degrees()
    }

    #[test]
    fn a_clusters_pose_is_the_vote_weighted_mean_of_its_members() {
        let votes = [
            vote(0.0, [0.0, 0.0, 0.0], 3, 0),
            vote(8.0, [4.0, 0.0, 0.0], 1, 1),
            // Another part, 50 mm away: its own cluster, its own pose.
            vote(40.0, [50.0, 0.0, 0.0], 2, 2),
        ];
        let c = cluster_poses(&votes, &Point3::origin(), &Symmetries::none(), &wide()).unwrap();
        assert_eq!(c.len(), 2);
        assert_eq!((c[0].votes, c[0].members), (4, 2));
        assert!((c[0].pose.translation.vector - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-9);
        assert!(
            (degrees_about_z(&c[0].pose) - 2.0).abs() < 0.01,
            "{:?}",
            c[0].pose
        );
        assert_eq!(c[1].pose, votes[2].pose);
    }

    #[test]
    fn members_are_averaged_in_the_symmetric_form_closest_to_the_first() {
        // A part with a half-turn symmetry about z: 184 deg is 4 deg from the first vote.
        let half_turn = Isometry3::rotation(Vector3::z() * std::f64::consts::PI);
        let symmetric = Symmetries::new(&[half_turn]);
        let votes = [
            vote(0.0, [0.0, 0.0, 0.0], 1, 0),
            vote(184.0, [0.0, 0.0, 0.0], 1, 1),
        ];
        let c = cluster_poses(&votes, &Point3::origin(), &symmetric, &wide()).unwrap();
        assert_eq!(c.len(), 1);
        assert!(
            (degrees_about_z(&c[0].pose) - 2.0).abs() < 0.01,
            "{:?}",
            c[0].pose
        );
        // Without the symmetry the two are different poses.
        let c = cluster_poses(&votes, &Point3::origin(), &Symmetries::none(), &wide()).unwrap();
        assert_eq!(c.len(), 2);
        assert_eq!(c[0].pose, votes[0].pose);
    }
}
