//! Properties of the PCL bridge: each test fails if the wrapped PCL primitive, or the way the
//! bridge feeds it, is wrong.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use binpick_pcl::{
    Correspondence, Error, FpfhParams, IcpOutcome, IcpParams, IndexedCloud, Mat4, Point,
    estimate_normals, estimate_normals_at, estimate_svd, match_features, reject_sample_consensus,
    reject_sample_consensus_sweep, segment_plane, uniform_sampling, voxel_grid,
};
use nalgebra::{Isometry3, Matrix4, Point3, Translation3, UnitQuaternion, Vector3};

/// Deterministic xorshift in [0, 1).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// A deliberately asymmetric part (mm, 1 mm grid): a plate with an off-centre bump, a partial
/// wall on one edge and a cylinder stub.
fn bracket() -> Vec<Point> {
    let mut pts = Vec::new();
    for i in 0..=60 {
        for j in 0..=40 {
            let (x, y) = (i as f32, j as f32);
            let bump = 6.0 * (-((x - 15.0).powi(2) + (y - 10.0).powi(2)) / 50.0).exp();
            pts.push([x, y, bump]);
        }
    }
    for j in 0..=25 {
        for k in 1..=30 {
            pts.push([60.0 + 0.3 * k as f32, j as f32, k as f32]);
        }
    }
    for a in 0..25 {
        let t = a as f32 / 25.0 * std::f32::consts::TAU;
        for k in 1..=10 {
            pts.push([30.0 + 4.0 * t.cos(), 28.0 + 4.0 * t.sin(), k as f32]);
        }
    }
    pts
}

fn iso(axis: [f64; 3], deg: f64, t: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(axis[0], axis[1], axis[2])),
            deg.to_radians(),
        ),
    )
}

fn apply(pose: &Isometry3<f64>, pts: &[Point]) -> Vec<Point> {
    pts.iter()
        .map(|p| {
            let q = pose * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            [q.x as f32, q.y as f32, q.z as f32]
        })
        .collect()
}

fn to_mat4(pose: &Isometry3<f64>) -> Mat4 {
    let h = pose.to_homogeneous();
    std::array::from_fn(|k| h[(k / 4, k % 4)])
}

fn from_mat4(m: &Mat4) -> Matrix4<f64> {
    Matrix4::from_fn(|r, c| m[r * 4 + c])
}

/// (rotation error in degrees, translation error in mm) between two row-major transforms.
fn pose_error(a: &Mat4, b: &Isometry3<f64>) -> (f64, f64) {
    let a = from_mat4(a);
    let b = b.to_homogeneous();
    let r = a.fixed_view::<3, 3>(0, 0).transpose() * b.fixed_view::<3, 3>(0, 0);
    let cos = ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    let t = (a.fixed_view::<3, 1>(0, 3) - b.fixed_view::<3, 1>(0, 3)).norm();
    (cos.acos().to_degrees(), t)
}

#[test]
fn icp_recovers_a_known_rigid_transform() {
    let model = bracket();
    let truth = iso([0.3, -0.5, 0.8], 6.0, [4.0, -3.0, 2.5]);
    let target = IndexedCloud::new(&apply(&truth, &model)).unwrap();
    let out = target
        .icp(
            &model,
            &IcpParams {
                initial: to_mat4(&Isometry3::identity()),
                max_correspondence_distance: 20.0,
                max_iterations: 50,
                transformation_epsilon: 1e-7,
                batch_correspondences: true,
                relative_mse: 0.0,
                reciprocal: false,
            },
        )
        .unwrap();
    assert!(out.converged, "{out:?}");
    let (rot, trans) = pose_error(&out.transform, &truth);
    assert!(rot < 0.1, "rotation error {rot} deg");
    assert!(trans < 0.1, "translation error {trans} mm");
    assert!(out.fitness < 1e-3, "fitness {}", out.fitness);
}

#[test]
fn batched_icp_correspondences_match_pcl_exactly() {
    // Noisy, partial target so that ICP takes many iterations with changing correspondences.
    let model = bracket();
    let truth = iso([0.2, 0.9, -0.4], 5.0, [3.0, 2.0, -1.5]);
    let mut rng = Rng(99);
    let target: Vec<Point> = apply(&truth, &model)
        .into_iter()
        .filter(|p| p[1] > 5.0)
        .map(|p| {
            [
                p[0] + 0.2 * (rng.next() - 0.5),
                p[1] + 0.2 * (rng.next() - 0.5),
                p[2] + 0.2 * (rng.next() - 0.5),
            ]
        })
        .collect();
    let cloud = IndexedCloud::new(&target).unwrap();
    let run =
        |batch, reciprocal| icp_from_identity(&cloud, &model, 8.0, 50, 1e-7, batch, reciprocal);
    for reciprocal in [false, true] {
        let (plain, batched) = (run(false, reciprocal), run(true, reciprocal));
        assert!(plain.iterations > 5, "{plain:?}");
        assert_eq!(
            plain, batched,
            "identical transform, iterations, fitness and stop reason (reciprocal: {reciprocal})"
        );
    }
    // Mutual nearest neighbours are fewer: the runs differ.
    assert_ne!(run(true, false).transform, run(true, true).transform);
}

#[test]
fn batched_icp_matches_pcl_on_a_lattice_full_of_equally_near_points() {
    // A 1 mm lattice (three layers) and a source on the half-way points between lattice
    // points: every source point starts equally near two to eight target points, and moves
    // a little each iteration, so the kept neighbourhoods are used, left and refreshed. At
    // 0.8 mm fewer target points than are kept lie within reach of a source point, at 3 mm
    // more.
    let mut target: Vec<Point> = Vec::new();
    for i in 0..40 {
        for j in 0..30 {
            for k in 0..3 {
                target.push([i as f32, j as f32, k as f32]);
            }
        }
    }
    let source: Vec<Point> = (0..300)
        .map(|n| {
            let (i, j) = (5 + n % 20, 5 + n / 20);
            [i as f32 + 0.5, j as f32 + 0.25 * (n % 3) as f32, 1.5]
        })
        .collect();
    let cloud = IndexedCloud::new(&target).unwrap();
    for max_correspondence_distance in [0.8, 3.0] {
        let run = |batch| {
            icp_from_identity(
                &cloud,
                &source,
                max_correspondence_distance,
                40,
                1e-9,
                batch,
                false,
            )
        };
        let (plain, batched) = (run(false), run(true));
        assert!(plain.iterations > 3, "{plain:?}");
        assert_eq!(
            plain, batched,
            "identical transform, iterations, fitness and stop reason at {max_correspondence_distance} mm"
        );
    }
}

#[test]
fn batched_icp_matches_pcl_when_points_with_no_target_near_come_within_reach() {
    // A 1 mm lattice plane at z = 0 and a source plane 1.2 mm above it with a strip 2.0 mm
    // above it: at a 1.5 mm correspondence distance the strip has no target point within
    // reach at first, and comes within reach once ICP has lowered the source. A batched
    // search that kept the strip's points without correspondences would align differently.
    let target: Vec<Point> = (0..40)
        .flat_map(|i| (0..30).map(move |j| [i as f32, j as f32, 0.0]))
        .collect();
    let source: Vec<Point> = (0..400)
        .map(|n| {
            let (x, y) = (5.0 + 0.75 * (n % 40) as f32, 5.0 + 1.9 * (n / 40) as f32);
            let z = if n % 40 < 8 { 2.0 } else { 1.2 };
            [x + 0.3, y + 0.2, z]
        })
        .collect();
    let cloud = IndexedCloud::new(&target).unwrap();
    let run = |batch| icp_from_identity(&cloud, &source, 1.5, 30, 1e-9, batch, false);
    let (plain, batched) = (run(false), run(true));
    assert!(plain.iterations > 2, "{plain:?}");
    // The strip came within reach: lowered by more than the 0.5 mm it needed.
    assert!(plain.transform[11] < -0.6, "{plain:?}");
    assert_eq!(
        plain, batched,
        "identical transform, iterations, fitness and stop reason"
    );
}

/// ICP of `source` onto `cloud` from the identity, without a relative-MSE stop, with PCL's
/// own correspondence search or (`batch`) the bridge's batched one.
fn icp_from_identity(
    cloud: &IndexedCloud,
    source: &[Point],
    max_correspondence_distance: f64,
    max_iterations: u32,
    transformation_epsilon: f64,
    batch: bool,
    reciprocal: bool,
) -> IcpOutcome {
    cloud
        .icp(
            source,
            &IcpParams {
                initial: to_mat4(&Isometry3::identity()),
                max_correspondence_distance,
                max_iterations,
                transformation_epsilon,
                batch_correspondences: batch,
                relative_mse: 0.0,
                reciprocal,
            },
        )
        .unwrap()
}

fn fpfh_at(points: &[Point], keypoints: &[u32], viewpoint: Point) -> Vec<[f32; 33]> {
    let set = IndexedCloud::new(points)
        .unwrap()
        .fpfh(
            keypoints,
            &FpfhParams {
                feature_radius: 8.5,
                normal_radius: 6.8,
                viewpoint,
                threads: 1,
            },
        )
        .unwrap();
    assert!(
        set.valid.iter().all(|&v| v),
        "every bracket keypoint has a descriptor"
    );
    set.descriptors
}

fn l1(a: &[f32; 33], b: &[f32; 33]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum()
}

/// Normals and FPFH searched through the neighbourhood cache must equal those searched
/// through the kd-tree, bit for bit: at radii below, at and above the cached radius, with the
/// keypoints as surface and with a denser surface around them, on one and two threads.
#[test]
fn cached_neighbourhoods_give_the_kd_tree_fpfh() {
    let mut rng = Rng(0x1234_5678_9abc_def1);
    let surface: Vec<Point> = bracket()
        .into_iter()
        .map(|p| p.map(|v| v + (rng.next() - 0.5) * 0.6))
        .collect();
    let keypoints = uniform_sampling(&surface, 3.0).unwrap();
    let kp_points: Vec<Point> = keypoints.iter().map(|&i| surface[i as usize]).collect();
    let all: Vec<u32> = (0..kp_points.len() as u32).collect();
    let bits = |set: &binpick_pcl::FpfhSet| {
        (
            set.valid.clone(),
            set.descriptors
                .iter()
                .map(|d| d.map(f32::to_bits))
                .collect::<Vec<_>>(),
        )
    };
    let mut cached_radii = 0;
    for (points, idx) in [(&surface, &keypoints), (&kp_points, &all)] {
        let plain = IndexedCloud::new(points).unwrap();
        let cached = IndexedCloud::with_neighbourhoods(points, 10.0, 2).unwrap();
        assert_eq!(plain.neighbourhood_radius(), None);
        assert_eq!(cached.neighbourhood_radius(), Some(10.0));
        for radius in [3.0f32, 5.5, 8.5, 10.0, 12.0] {
            for threads in [1, 2] {
                let fp = FpfhParams {
                    feature_radius: radius,
                    normal_radius: 0.8 * radius,
                    viewpoint: [30.0, 20.0, 500.0],
                    threads,
                };
                let want = plain.fpfh(idx, &fp).unwrap();
                assert!(want.valid.iter().filter(|&&v| v).count() > idx.len() / 2);
                assert_eq!(
                    bits(&cached.fpfh(idx, &fp).unwrap()),
                    bits(&want),
                    "radius {radius}, {threads} thread(s), {} surface points",
                    points.len()
                );
                cached_radii += usize::from(radius <= 10.0);
            }
        }
    }
    assert_eq!(cached_radii, 16);
    assert!(IndexedCloud::with_neighbourhoods(&surface, 0.0, 1).is_err());
    assert!(IndexedCloud::with_neighbourhoods(&surface, f32::NAN, 1).is_err());
}

#[test]
fn fpfh_is_invariant_to_rigid_motion_and_separates_shapes() {
    let shape = bracket();
    let keypoints = uniform_sampling(&shape, 4.0).unwrap();
    let vp = [30.0f32, 20.0, 500.0];
    let a = fpfh_at(&shape, &keypoints, vp);

    let motion = iso([1.0, 2.0, -0.5], 73.0, [120.0, -40.0, 15.0]);
    let moved = apply(&motion, &shape);
    let vp_moved = apply(&motion, &[vp])[0];
    let b = fpfh_at(&moved, &keypoints, vp_moved);

    // Same point, same descriptor (each sub-histogram sums to 100, so 300 in all); a few
    // points whose neighbour sits within float noise of the radius may differ slightly.
    let mut same: Vec<f32> = a.iter().zip(&b).map(|(x, y)| l1(x, y)).collect();
    same.sort_by(f32::total_cmp);
    let p95 = same[same.len() * 95 / 100];
    assert!(p95 < 0.5, "95th percentile L1 difference {p95} over 300");

    // A different shape: a sphere cap of similar size. Its descriptors are far from the
    // bracket's, by much more than the motion noise.
    let mut sphere = Vec::new();
    for i in 0..60 {
        for j in 0..40 {
            let (u, v) = (i as f32 / 60.0 * 1.2 - 0.6, j as f32 / 40.0 * 1.2 - 0.6);
            sphere.push([40.0 * u.sin(), 40.0 * v.sin(), 40.0 * u.cos() * v.cos()]);
        }
    }
    let skp = uniform_sampling(&sphere, 4.0).unwrap();
    let c = fpfh_at(&sphere, &skp, [0.0, 0.0, 500.0]);
    let mean_same: f32 = same.iter().sum::<f32>() / same.len() as f32;
    let flat_plate: Vec<usize> = (0..keypoints.len())
        .filter(|&i| {
            shape[keypoints[i] as usize][0] > 35.0 && shape[keypoints[i] as usize][0] < 50.0
        })
        .collect();
    let mean_other: f32 = flat_plate
        .iter()
        .map(|&i| c.iter().map(|d| l1(&a[i], d)).fold(f32::MAX, f32::min))
        .sum::<f32>()
        / flat_plate.len() as f32;
    assert!(
        mean_other > 20.0 * mean_same.max(0.05),
        "different shapes: {mean_other} vs same shape moved: {mean_same}"
    );
}

fn blob(origin: [f32; 3], n_side: usize) -> Vec<Point> {
    let mut v = Vec::new();
    for i in 0..n_side {
        for j in 0..n_side {
            v.push([origin[0] + i as f32, origin[1] + j as f32, origin[2]]);
        }
    }
    v
}

#[test]
fn euclidean_clusters_counts_sizes_and_filters() {
    let mut pts = blob([0.0, 0.0, 0.0], 10); // 100
    pts.extend(blob([40.0, 0.0, 0.0], 15)); // 225
    pts.extend(blob([0.0, 50.0, 5.0], 20)); // 400
    let cloud = IndexedCloud::new(&pts).unwrap();
    let sizes = |v: Vec<Vec<u32>>| v.iter().map(Vec::len).collect::<Vec<_>>();
    let all = cloud.euclidean_clusters(1.5, 1, 10_000).unwrap();
    assert_eq!(sizes(all.clone()), vec![100, 225, 400]);
    assert_eq!(all[1][0], 100, "second blob starts at index 100");
    assert!(all.iter().all(|c| c.windows(2).all(|w| w[0] < w[1])));
    assert_eq!(
        sizes(cloud.euclidean_clusters(1.5, 150, 10_000).unwrap()),
        vec![225, 400]
    );
    assert_eq!(
        sizes(cloud.euclidean_clusters(1.5, 1, 300).unwrap()),
        vec![100, 225]
    );
    // A tolerance below the grid spacing shatters every blob into single points.
    assert!(cloud.euclidean_clusters(0.5, 2, 10_000).unwrap().is_empty());
    assert!(cloud.euclidean_clusters(1.5, 0, 10).is_err());
}

/// Clustering through the neighbourhood cache (built on several threads) must give the
/// kd-tree's clusters: on jittered blobs and scattered points whose clusters hinge on
/// distances near the tolerance, at the cached tolerance and at smaller and larger ones.
#[test]
fn cached_neighbourhoods_give_the_kd_tree_clusters() {
    let mut rng = Rng(0x0dd_ba11);
    let mut pts = Vec::new();
    for (k, centre) in [[0.0f32, 0.0, 0.0], [31.0, 0.0, 0.0], [0.0, 45.0, 5.0]]
        .iter()
        .enumerate()
    {
        for i in 0..(20 + 5 * k) {
            for j in 0..20 {
                let jitter = |rng: &mut Rng| (rng.next() - 0.5) * 0.8;
                pts.push([
                    centre[0] + i as f32 + jitter(&mut rng),
                    centre[1] + j as f32 + jitter(&mut rng),
                    centre[2] + jitter(&mut rng),
                ]);
            }
        }
    }
    for _ in 0..1500 {
        pts.push([rng.next() * 80.0, rng.next() * 80.0, rng.next() * 10.0]);
    }
    let cached = IndexedCloud::with_neighbourhoods(&pts, 1.5, 2).unwrap();
    assert_eq!(cached.neighbourhood_radius(), Some(1.5));
    let mut distinct = std::collections::HashSet::new();
    for tolerance in [0.9f32, 1.2, 1.5, 2.5] {
        for (min, max) in [(1, 100_000), (30, 450)] {
            let want = IndexedCloud::new(&pts)
                .unwrap()
                .euclidean_clusters(tolerance, min, max)
                .unwrap();
            assert_eq!(
                cached.euclidean_clusters(tolerance, min, max).unwrap(),
                want,
                "tolerance {tolerance}, sizes {min}..{max}"
            );
            distinct.insert(want);
        }
    }
    assert!(distinct.len() >= 6, "the cases differ: {}", distinct.len());
}

#[test]
fn sac_rejector_keeps_planted_inliers_and_drops_outliers() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let source: Vec<Point> = (0..100)
        .map(|_| [rng.next() * 100.0, rng.next() * 100.0, rng.next() * 100.0])
        .collect();
    let truth = iso([0.2, 1.0, 0.3], 35.0, [10.0, 20.0, -5.0]);
    let target = apply(&truth, &source);
    let mut corrs = Vec::new();
    for i in 0..100u32 {
        // 70 true pairs; 30 pairs pointing at a different point (far away from the truth).
        let matched = if i % 10 < 7 { i } else { (i + 37) % 100 };
        corrs.push(Correspondence {
            query: i,
            matched,
            distance: 0.0,
        });
    }
    let planted_outlier = |c: &Correspondence| c.query != c.matched;
    let out = reject_sample_consensus(&source, &target, &corrs, 1.0, 50).unwrap();
    let kept_inliers = out.kept.iter().filter(|c| !planted_outlier(c)).count();
    let kept_outliers = out.kept.iter().filter(|c| planted_outlier(c)).count();
    assert_eq!(kept_inliers, 70);
    assert_eq!(kept_outliers, 0);
    let (rot, trans) = pose_error(&out.transform, &truth);
    assert!(rot < 0.01 && trans < 0.01, "{rot} deg, {trans} mm");
    let m = from_mat4(&out.transform);
    let det = m.fixed_view::<3, 3>(0, 0).determinant();
    assert!((det - 1.0).abs() < 1e-5, "det {det}");

    // Deterministic: the same call gives the same answer.
    assert_eq!(
        reject_sample_consensus(&source, &target, &corrs, 1.0, 50).unwrap(),
        out
    );

    // SVD on the kept pairs gives the same transform.
    let svd = estimate_svd(&source, &target, &out.kept).unwrap();
    let (rot, trans) = pose_error(&svd, &truth);
    assert!(rot < 0.01 && trans < 0.01, "SVD: {rot} deg, {trans} mm");
}

/// The one-pass threshold sweep must give, for every threshold, exactly what one PCL
/// rejector run at that threshold gives: same kept pairs in the same order, same transform,
/// same failures. Inputs vary the outlier share (so PCL's adaptive iteration bound stops the
/// thresholds at different iterations), the noise and the iteration cap.
#[test]
fn sweep_matches_one_rejector_per_threshold() {
    let thresholds = [1e-4f32, 0.3, 1.0, 2.0, 5.0, 20.0];
    let mut outcomes = std::collections::HashSet::new();
    let mut failures = 0;
    for (case, &(inlier_share, noise, iterations)) in [
        (0.9f32, 0.2f32, 50u32),
        (0.5, 0.5, 50),
        (0.2, 0.5, 300),
        (0.7, 1.5, 5),
        (0.05, 0.1, 100),
    ]
    .iter()
    .enumerate()
    {
        let mut rng = Rng(0x2545_f491_4f6c_dd1d ^ case as u64);
        let source: Vec<Point> = (0..150)
            .map(|_| [rng.next() * 80.0, rng.next() * 80.0, rng.next() * 80.0])
            .collect();
        let truth = iso([0.4, -0.2, 1.0], 60.0, [5.0, -12.0, 30.0]);
        let target: Vec<Point> = apply(&truth, &source)
            .into_iter()
            .map(|p| p.map(|v| v + (rng.next() - 0.5) * 2.0 * noise))
            .collect();
        let corrs: Vec<Correspondence> = (0..150u32)
            .map(|i| Correspondence {
                query: i,
                matched: if rng.next() < inlier_share {
                    i
                } else {
                    (rng.next() * 150.0) as u32 % 150
                },
                distance: rng.next(),
            })
            .collect();
        let sweep =
            reject_sample_consensus_sweep(&source, &target, &corrs, &thresholds, iterations)
                .unwrap();
        assert_eq!(sweep.len(), thresholds.len());
        for (t, swept) in thresholds.iter().zip(&sweep) {
            let single = reject_sample_consensus(&source, &target, &corrs, *t, iterations);
            assert_eq!(swept, &single, "case {case}, threshold {t}");
            match single {
                Ok(c) => {
                    outcomes.insert(c.kept.len());
                }
                Err(_) => failures += 1,
            }
        }
    }
    // The comparison covered failures and many different consensus sizes.
    assert!(failures > 0);
    assert!(outcomes.len() > 10, "{outcomes:?}");

    let pts = bracket();
    let c = |q, m| Correspondence {
        query: q,
        matched: m,
        distance: 0.0,
    };
    let three = [c(0, 0), c(1, 1), c(2, 2)];
    assert!(reject_sample_consensus_sweep(&pts, &pts, &three, &[], 50).is_err());
    assert!(reject_sample_consensus_sweep(&pts, &pts, &three, &[1.0, f32::NAN], 50).is_err());
    assert!(reject_sample_consensus_sweep(&pts, &pts, &three, &[1.0], 0).is_err());
    assert!(reject_sample_consensus_sweep(&pts, &pts, &three[..2], &[1.0], 50).is_err());
}

#[test]
fn uniform_sampling_returns_input_points_at_most_one_per_cell() {
    let mut rng = Rng(42);
    let pts: Vec<Point> = (0..5000)
        .map(|_| {
            [
                rng.next() * 50.0 - 10.0,
                rng.next() * 50.0,
                rng.next() * 20.0,
            ]
        })
        .collect();
    let leaf = 5.0f32;
    let idx = uniform_sampling(&pts, leaf).unwrap();
    assert!(idx.windows(2).all(|w| w[0] < w[1]), "ascending, unique");
    assert!(idx.iter().all(|&i| (i as usize) < pts.len()));
    // PCL computes cells with float multiplications by the inverse leaf.
    let inv = 1.0f32 / leaf;
    let cell = |p: &Point| p.map(|c| (c * inv).floor() as i32);
    let kept: std::collections::HashSet<_> = idx.iter().map(|&i| cell(&pts[i as usize])).collect();
    assert_eq!(kept.len(), idx.len(), "at most one keypoint per cell");
    let occupied: std::collections::HashSet<_> = pts.iter().map(cell).collect();
    assert_eq!(kept, occupied, "every occupied cell has its keypoint");

    // The voxel grid returns one centroid per occupied cell too (new points).
    assert_eq!(voxel_grid(&pts, leaf).unwrap().len(), occupied.len());
}

#[test]
fn plane_segmentation_removes_the_floor_and_keeps_objects() {
    let mut rng = Rng(7);
    let mut pts = Vec::new();
    for i in 0..150 {
        for j in 0..100 {
            pts.push([i as f32 * 2.0, j as f32 * 2.0, (rng.next() - 0.5) * 0.4]);
        }
    }
    let floor = pts.len();
    for p in bracket() {
        pts.push([p[0] + 100.0, p[1] + 60.0, p[2] + 8.0]);
    }
    let plane = segment_plane(&pts, 1.0, 200, 1).unwrap().expect("a floor");
    assert_eq!(plane.inliers.len(), floor);
    assert!(plane.inliers.iter().all(|&i| (i as usize) < floor));
    let n = plane.coefficients;
    assert!(n[2].abs() > 0.999, "floor normal is vertical: {n:?}");
}

/// Splitting and counting RANSAC's inliers in the bridge must not change the fit: PCL's own
/// plane model and the bridge's fit on 1, 2, 3 threads and all cores return the same plane
/// bit for bit and the same inliers in the same order, on a cloud large enough to be split
/// and on one counted in a single shard. Two noisy planes and uniform clutter of similar
/// sizes make RANSAC use all its iterations and choose between close counts. Both are also
/// `pcl::SACSegmentation::segment`'s answer as Debian's precompiled libpcl_segmentation gives
/// it (`scripts/golden/sac_segmentation.cpp` on these clouds: coefficient bits, inlier count
/// and an FNV-1a hash of the inlier indices), which the bridge no longer compiles.
#[test]
fn plane_fit_is_the_same_on_any_number_of_threads() {
    let mut rng = Rng(0xfeed_beef);
    let mut pts = Vec::new();
    for _ in 0..30_000 {
        let (x, y) = (rng.next() * 400.0, rng.next() * 300.0);
        pts.push([x, y, (rng.next() - 0.5) * 3.0]);
    }
    for _ in 0..25_000 {
        let (x, z) = (rng.next() * 400.0, rng.next() * 200.0);
        pts.push([x, 0.3 * z + (rng.next() - 0.5) * 3.0, z]);
    }
    for _ in 0..35_000 {
        pts.push([rng.next() * 400.0, rng.next() * 300.0, rng.next() * 200.0]);
    }
    let key = |p: &binpick_pcl::Plane| (p.coefficients.map(f32::to_bits), p.inliers.clone());
    // The same mix, 90 000 points (split over threads) and every 15th of them (one shard).
    let small: Vec<Point> = pts.iter().step_by(15).copied().collect();
    for (cloud, least) in [(&pts, 20_000), (&small, 1_200)] {
        let pcl = binpick_pcl::segment_plane_pcl(cloud, 1.0, 300)
            .unwrap()
            .expect("a plane");
        assert!(pcl.inliers.len() > least, "{}", pcl.inliers.len());
        // BINPICK_GOLDEN_DIR=<dir> writes the clouds for scripts/golden/sac_segmentation.cpp.
        if let Some(dir) = std::env::var_os("BINPICK_GOLDEN_DIR") {
            let bytes: Vec<u8> = cloud
                .iter()
                .flatten()
                .flat_map(|c| c.to_le_bytes())
                .collect();
            let path = std::path::Path::new(&dir).join(format!("plane-{}.bin", cloud.len()));
            std::fs::write(&path, bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        }
        let sac_segmentation = match cloud.len() {
            90_000 => (
                [3131341071, 3145730587, 1065353075, 1064612652],
                20_123,
                0x31d2_7431_a375_0983,
            ),
            6_000 => (
                [3138624241, 3114585266, 1065353173, 1065637329],
                1_291,
                0x43d0_88d3_8325_83da,
            ),
            n => panic!("no SACSegmentation answer recorded for {n} points"),
        };
        let fnv = pcl.inliers.iter().fold(0xcbf2_9ce4_8422_2325_u64, |h, &i| {
            (h ^ u64::from(i)).wrapping_mul(0x100_0000_01b3)
        });
        assert_eq!(
            (pcl.coefficients.map(f32::to_bits), pcl.inliers.len(), fnv),
            sac_segmentation,
            "SACSegmentation's plane on {} points",
            cloud.len()
        );
        for threads in [1, 2, 3, 0] {
            let split = segment_plane(cloud, 1.0, 300, threads)
                .unwrap()
                .expect("a plane");
            assert_eq!(
                key(&split),
                key(&pcl),
                "{} points, {threads} threads",
                cloud.len()
            );
        }
    }
}

/// The split count that RANSAC's inner loop uses on large clouds is PCL's count exactly, and
/// the split selection PCL's selection (same indices, order and distances), down to the
/// rounding of each distance: points placed within a few ulps of the threshold on
/// both sides of 40 planes (summing the plane's terms in another order moves some of them
/// across it: 10 of the first plane's 500).
#[test]
fn split_plane_count_is_pcls_count_to_the_last_point() {
    let mut rng = Rng(0x5eed_f91a_4e01);
    let threshold = 1.0;
    let mut planes = Vec::new();
    let mut pts = Vec::new();
    for _ in 0..40 {
        let n = Vector3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5).normalize();
        let d = (rng.next() - 0.5) * 400.0;
        planes.push([n.x, n.y, n.z, d]);
        for k in 0..500 {
            // A point of the plane, moved off it by the threshold give or take a few ulps.
            let q = Vector3::new(rng.next() * 300.0, rng.next() * 300.0, rng.next() * 300.0);
            let on = q - n * (n.dot(&q) + d);
            let off = threshold as f32 * (1.0 + (rng.next() - 0.5) * 4e-7);
            let p = on + n * if k % 2 == 0 { off } else { -off };
            pts.push([p.x, p.y, p.z]);
        }
    }
    for _ in 0..5_000 {
        pts.push([rng.next() * 300.0, rng.next() * 300.0, rng.next() * 300.0]);
    }
    let counts = binpick_pcl::plane_inlier_counts(&pts, &planes, threshold).unwrap();
    assert_eq!(counts.len(), planes.len());
    for (k, [pcl, split, pcl_selected, split_selected]) in counts.iter().enumerate() {
        assert_eq!(pcl, split, "plane {k}: counts");
        assert_eq!(pcl_selected, pcl, "plane {k}: PCL selects what it counts");
        assert_eq!(split_selected, pcl_selected, "plane {k}: selections");
    }
    // The boundary is really tested: about half of each plane's 500 points fall inside.
    let inside: u64 = counts.iter().map(|c| c[0]).sum();
    assert!((4_000..16_000).contains(&inside), "{inside}");
}

#[test]
fn normals_follow_the_viewpoint() {
    let pts = blob([0.0, 0.0, 0.0], 20);
    let up = estimate_normals(&pts, 3.0, [10.0, 10.0, 100.0], 1).unwrap();
    let down = estimate_normals(&pts, 3.0, [10.0, 10.0, -100.0], 2).unwrap();
    assert!(up.iter().all(|n| n.normal[2] > 0.999));
    assert!(down.iter().all(|n| n.normal[2] < -0.999));
}

#[test]
fn normals_at_some_points_are_the_normals_of_all_at_those_points() {
    let shape = bracket();
    let all = estimate_normals(&shape, 3.0, [30.0, 20.0, 500.0], 2).unwrap();
    let at: Vec<u32> = (0..shape.len() as u32).rev().step_by(7).collect();
    // The same from a cloud uploaded once, searched with its own kd-tree.
    let uploaded = IndexedCloud::new(&shape).unwrap();
    for threads in [1, 2] {
        let some = estimate_normals_at(&shape, &at, 3.0, [30.0, 20.0, 500.0], threads).unwrap();
        let from_upload = uploaded
            .normals_at(&at, 3.0, [30.0, 20.0, 500.0], threads)
            .unwrap();
        let bits = |v: &[binpick_pcl::Normal]| -> Vec<[u32; 4]> {
            v.iter()
                .map(|n| {
                    let [x, y, z] = n.normal.map(f32::to_bits);
                    [x, y, z, n.curvature.to_bits()]
                })
                .collect()
        };
        assert_eq!(bits(&some), bits(&from_upload), "{threads} thread(s)");
        assert_eq!(some.len(), at.len());
        for (&i, n) in at.iter().zip(&some) {
            let want = &all[i as usize];
            assert_eq!(
                n.normal.map(f32::to_bits),
                want.normal.map(f32::to_bits),
                "point {i}"
            );
            assert_eq!(n.curvature.to_bits(), want.curvature.to_bits(), "point {i}");
        }
    }
    assert!(
        estimate_normals_at(&shape, &[], 3.0, [0.0, 0.0, 1.0], 1)
            .unwrap()
            .is_empty()
    );
    let err = estimate_normals_at(&shape, &[shape.len() as u32], 3.0, [0.0, 0.0, 1.0], 1)
        .unwrap_err()
        .to_string();
    assert!(err.contains("out of range"), "{err}");
    let err = uploaded
        .normals_at(&[shape.len() as u32], 3.0, [0.0, 0.0, 1.0], 1)
        .unwrap_err()
        .to_string();
    assert!(err.contains("out of range"), "{err}");
    assert!(uploaded.normals_at(&at, 0.0, [0.0, 0.0, 1.0], 1).is_err());
}

#[test]
fn feature_matching_pairs_each_source_descriptor_with_its_twin() {
    let shape = bracket();
    let kp = uniform_sampling(&shape, 4.0).unwrap();
    let f = fpfh_at(&shape, &kp, [30.0, 20.0, 500.0]);
    let rev: Vec<_> = f.iter().rev().copied().collect();
    let corrs = match_features(&f, &rev).unwrap();
    assert_eq!(corrs.len(), f.len());
    // Flat regions repeat the same descriptor, so the twin is not always the only answer;
    // what must hold is that each match is an identical descriptor at distance 0.
    for c in &corrs {
        assert_eq!(rev[c.matched as usize], f[c.query as usize], "{c:?}");
        assert!(c.distance < 1e-6, "{c:?}");
    }
    let exact = corrs
        .iter()
        .filter(|c| c.matched as usize == f.len() - 1 - c.query as usize)
        .count();
    assert!(
        exact * 2 > f.len(),
        "most descriptors are unique: {exact} of {}",
        f.len()
    );
    assert!(corrs.iter().all(|c| c.distance >= 0.0));
}

#[test]
fn bad_input_is_an_error_not_a_crash() {
    let msg = |e: Error| e.to_string();
    assert!(msg(uniform_sampling(&[], 1.0).unwrap_err()).contains("empty"));
    assert!(
        msg(uniform_sampling(&[[0.0, f32::NAN, 0.0]], 1.0).unwrap_err()).contains("non-finite")
    );
    assert!(
        msg(uniform_sampling(&[[0.0; 3], [1000.0; 3]], 1e-6).unwrap_err()).contains("too small")
    );
    // A grid too wide for PCL's index is tiled (see below); one beyond its coordinates is not.
    assert_eq!(voxel_grid(&[[0.0; 3], [1e6; 3]], 1e-3).unwrap().len(), 2);
    assert!(msg(voxel_grid(&[[0.0; 3], [1e7; 3]], 1e-3).unwrap_err()).contains("32-bit"));
    assert!(uniform_sampling(&[[0.0; 3]], -1.0).is_err());
    assert!(IndexedCloud::new(&[]).is_err());
    assert!(IndexedCloud::new(&[[f32::INFINITY, 0.0, 0.0]]).is_err());
    let pts = bracket();
    let cloud = IndexedCloud::new(&pts).unwrap();
    assert!(
        cloud
            .fpfh(
                &[u32::MAX],
                &FpfhParams {
                    feature_radius: 5.0,
                    normal_radius: 4.0,
                    viewpoint: [0.0; 3],
                    threads: 1
                }
            )
            .is_err()
    );
    assert!(
        cloud
            .fpfh(
                &[0],
                &FpfhParams {
                    feature_radius: f32::NAN,
                    normal_radius: 4.0,
                    viewpoint: [0.0; 3],
                    threads: 1
                }
            )
            .is_err()
    );
    let c = |q, m| Correspondence {
        query: q,
        matched: m,
        distance: 0.0,
    };
    assert!(reject_sample_consensus(&pts, &pts, &[c(0, 0), c(1, 1)], 1.0, 50).is_err());
    assert!(
        reject_sample_consensus(&pts, &pts, &[c(0, 0), c(1, 1), c(2, 99_999)], 1.0, 50).is_err()
    );
    assert!(estimate_svd(&pts, &pts, &[c(0, 0)]).is_err());
    let icp = |iters, dist| {
        cloud.icp(
            &pts,
            &IcpParams {
                initial: to_mat4(&Isometry3::identity()),
                max_correspondence_distance: dist,
                max_iterations: iters,
                transformation_epsilon: 1e-7,
                batch_correspondences: true,
                relative_mse: 0.0,
                reciprocal: false,
            },
        )
    };
    assert!(icp(0, 5.0).is_err());
    assert!(icp(10, -1.0).is_err());
    let mut bad_guess = to_mat4(&Isometry3::identity());
    bad_guess[3] = f64::NAN;
    assert!(
        cloud
            .icp(
                &pts,
                &IcpParams {
                    initial: bad_guess,
                    max_correspondence_distance: 5.0,
                    max_iterations: 5,
                    transformation_epsilon: 1e-7,
                    batch_correspondences: true,
                    relative_mse: 0.0,
                    reciprocal: false,
                }
            )
            .is_err()
    );
    assert!(match_features(&[[f32::NAN; 33]], &[[0.0; 33]]).is_err());
    assert!(segment_plane(&pts[..2], 1.0, 10, 1).is_err());
    // All points collinear: PCL finds no plane; reported as None, not garbage.
    let line: Vec<Point> = (0..50).map(|i| [i as f32, 0.0, 0.0]).collect();
    assert!(segment_plane(&line, 0.1, 50, 2).unwrap().is_none());
}

#[test]
fn the_bridge_survives_calls_from_several_threads() {
    use rayon::prelude::*;
    let model = bracket();
    let truth = iso([0.0, 0.0, 1.0], 4.0, [2.0, 1.0, 0.0]);
    let scene = IndexedCloud::new(&apply(&truth, &model)).unwrap();
    let params = IcpParams {
        initial: to_mat4(&Isometry3::identity()),
        max_correspondence_distance: 10.0,
        max_iterations: 50,
        transformation_epsilon: 1e-7,
        batch_correspondences: true,
        relative_mse: 0.0,
        reciprocal: false,
    };
    let kp = uniform_sampling(&model, 3.0).unwrap();
    let fp = FpfhParams {
        feature_radius: 7.0,
        normal_radius: 5.6,
        viewpoint: [0.0, 0.0, 300.0],
        threads: 2,
    };
    let reference_icp = scene.icp(&model, &params).unwrap();
    let model_cloud = IndexedCloud::new(&model).unwrap();
    let reference_fpfh = model_cloud.fpfh(&kp, &fp).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(8)
        .build()
        .unwrap();
    pool.install(|| {
        (0..32).into_par_iter().for_each(|i| {
            if i % 2 == 0 {
                assert_eq!(scene.icp(&model, &params).unwrap(), reference_icp);
            } else {
                assert_eq!(model_cloud.fpfh(&kp, &fp).unwrap(), reference_fpfh);
                assert_eq!(uniform_sampling(&model, 3.0).unwrap(), kp);
            }
        });
    });
}

/// A voxel grid wider than PCL's 32-bit voxel index is filtered in tiles: two blobs 3 m
/// apart at a 1 mm leaf (2.7e10 cells) give exactly each blob's own voxel grid, in PCL's
/// order (lower z first); a coordinate beyond 2^31 leaves is a clear error, not garbage.
#[test]
fn a_voxel_grid_too_wide_for_pcl_is_done_in_tiles() {
    let mut rng = Rng(99);
    let cloud = |o: f32, rng: &mut Rng| -> Vec<Point> {
        (0..5000)
            .map(|_| {
                [
                    o + rng.next() * 40.0,
                    o + rng.next() * 30.0,
                    o + rng.next() * 20.0,
                ]
            })
            .collect()
    };
    let near = cloud(0.0, &mut rng);
    let far = cloud(3000.0, &mut rng);
    let both: Vec<Point> = far.iter().chain(&near).copied().collect();
    let bits = |v: Vec<Point>| -> Vec<[u32; 3]> { v.iter().map(|p| p.map(f32::to_bits)).collect() };
    let mut expected = voxel_grid(&near, 1.0).unwrap();
    expected.extend(voxel_grid(&far, 1.0).unwrap());
    assert_eq!(bits(voxel_grid(&both, 1.0).unwrap()), bits(expected));
    let e = voxel_grid(&[[0.0, 0.0, 0.0], [1e30, 0.0, 0.0]], 1.0).unwrap_err();
    assert!(e.to_string().contains("32-bit"), "{e}");
}

/// An installed interrupt stops the long calls between their chunks (an error that says so);
/// one that never fires leaves every answer as it was.
#[test]
fn interrupts_stop_long_calls_and_change_no_answer() {
    use std::sync::Arc;
    let mut rng = Rng(5);
    let pts: Vec<Point> = (0..60_000)
        .map(|_| [rng.next() * 400.0, rng.next() * 300.0, rng.next() * 2.0])
        .collect();
    let target = IndexedCloud::new(&pts).unwrap();
    let source: Vec<Point> = pts.iter().step_by(50).copied().collect();
    let icp = IcpParams {
        initial: to_mat4(&iso([0.0, 0.0, 1.0], 2.0, [1.0, 0.0, 0.0])),
        max_correspondence_distance: 10.0,
        max_iterations: 20,
        transformation_epsilon: 1e-9,
        batch_correspondences: true,
        relative_mse: 0.0,
        reciprocal: false,
    };
    let far: Vec<Point> = [[0.0, 0.0, 0.0], [5000.0, 5000.0, 5000.0]]
        .iter()
        .chain(&pts[..10])
        .copied()
        .collect();
    let run = || {
        (
            target.icp(&source, &icp).map(|o| o.transform),
            segment_plane(&pts, 1.0, 100, 2).map(|p| p.map(|p| p.inliers.len())),
            IndexedCloud::with_neighbourhoods(&pts, 3.0, 2).map(|c| c.len()),
            voxel_grid(&far, 0.5).map(|v| v.len()),
        )
    };
    let plain = run();
    assert!(plain.0.is_ok() && plain.1.is_ok() && plain.2.is_ok() && plain.3.is_ok());
    binpick_pcl::set_interrupt(Some(Arc::new(|| false)));
    assert_eq!(run(), plain);
    binpick_pcl::set_interrupt(Some(Arc::new(|| true)));
    let stopped = run();
    binpick_pcl::set_interrupt(None);
    fn interrupted<T>(r: &Result<T, Error>) -> bool {
        matches!(r, Err(Error::Interrupted { .. }))
    }
    assert!(interrupted(&stopped.0), "ICP: {:?}", stopped.0);
    assert!(interrupted(&stopped.1), "plane fit: {:?}", stopped.1);
    assert!(interrupted(&stopped.2), "neighbourhoods: {:?}", stopped.2);
    assert!(interrupted(&stopped.3), "voxel tiles: {:?}", stopped.3);
    // Other threads are not affected, and removing it restores the answers.
    std::thread::scope(|s| {
        binpick_pcl::set_interrupt(Some(Arc::new(|| true)));
        assert_eq!(s.spawn(run).join().unwrap(), plain);
        binpick_pcl::set_interrupt(None);
    });
    assert_eq!(run(), plain);
}
