//! The human-readable ranked table printed by `recognize` and `replay`.

use binpick::{FoundBy, Recognition};

/// What the ranked table's columns mean (printed by `recognize --help` and in the README).
pub const COLUMNS_HELP: &str = "\
Ranked table (stdout; stderr with --json -), one row per detection, pick order:
  rank       pick order (detections[0] of the JSON first); a part is picked only if it is
             free to pick (free_to_pick in the JSON: nothing lies on it, a grasp is free)
  vis %      estimated visible fraction: share of the surface the sensor would see of the
             part alone in this pose that the scan confirms (scene-voting engine; - otherwise)
  final %    percent of outliers of the final pose (thesis 3.1.2): model points farther than
             outlier_distance_mm from the scan; lower is better
  init mm^2  Euclidean score of the initial pose (thesis 3.1.1): mean squared distance of
             model points to the scan; lower is better
  x y z mm   position of the model frame's origin in the output frame: the scan's, or the
             robot base's with --scanner-to-base (the line under the table names it)
  roll pitch yaw
             orientation in degrees, rotations about the output frame's fixed x, y and z axes
             applied in that order: R = Rz(yaw) Ry(pitch) Rx(roll) (extrinsic XYZ, as ROS RPY)
  found by   scene-voting: votes of the pose cluster; thesis engine: cluster index, FPFH
             radius r in mm (merged = Algorithm 2) and RANSAC threshold t in mm that won
  why        why it ranks there: with grasps declared in the model's sidecar, which grasp is
             free or what blocks each one (a detection's rank or N scene points); then free /
             covered share, visibility band, height along up
Under the table: `no pick` and why when parts were found but none is free to pick; with
grasps declared, the first pick's free grasp (position mm and approach direction).";

/// Roll, pitch, yaw (XYZ fixed axes), degrees.
pub fn rpy_deg(p: &nalgebra::Isometry3<f64>) -> [f64; 3] {
    let (r, pi, y) = p.rotation.euler_angles();
    [r.to_degrees(), pi.to_degrees(), y.to_degrees()]
}

/// The pose columns' header: position (mm) and roll, pitch, yaw (deg), as [`pose_cells`].
pub const POSE_HEADER: &str = "     x mm      y mm      z mm     roll   pitch     yaw";

/// A pose's columns under [`POSE_HEADER`].
pub fn pose_cells(p: &nalgebra::Isometry3<f64>) -> String {
    let t = p.translation.vector;
    let [ro, pi, ya] = rpy_deg(p);
    format!(
        "{:>9.2} {:>9.2} {:>9.2}  {:>7.1} {:>7.1} {:>7.1}",
        t.x, t.y, t.z, ro, pi, ya
    )
}

/// Prints the ranked table to `out`; columns in [`COLUMNS_HELP`].
pub fn print_ranked(out: &mut impl std::io::Write, r: &Recognition) -> std::io::Result<()> {
    writeln!(
        out,
        "{:>4}  {:>6}  {:>8}  {:>10}  {POSE_HEADER}  {:<22}  why",
        "rank", "vis %", "final %", "init mm^2", "found by"
    )?;
    for d in &r.detections {
        let vis = d
            .view
            .map_or("-".to_string(), |v| format!("{:.1}", 100.0 * v.visibility));
        let found = match &d.found_by {
            FoundBy::Voting { votes, .. } => format!("{votes} votes"),
            FoundBy::Cluster {
                cluster,
                fpfh_radius_mm,
                sac_threshold_mm,
                ..
            } => format!(
                "cluster {cluster} r {} t {sac_threshold_mm:.1}",
                fpfh_radius_mm.map_or("merged".to_string(), |x| format!("{x:.0}"))
            ),
            _ => "-".to_string(),
        };
        writeln!(
            out,
            "{:>4}  {:>6}  {:>8.2}  {:>10.2}  {}  {:<22}  {}",
            d.rank,
            vis,
            d.final_score,
            d.initial_score,
            pose_cells(&d.pose),
            found,
            d.rank_reason
        )?;
    }
    writeln!(out, "poses in frame {}", r.frame.frame_id)?;
    if r.none_free_to_pick() {
        writeln!(
            out,
            "no pick: no part found is free to pick (each lies under another part or has \
             every grasp blocked): rescan or clear the pile"
        )?;
    }
    // The first pick has a free grasp whenever grasps are declared.
    if let Some(g) = r
        .first_pick()
        .and_then(|d| d.grasps.iter().find(|g| g.free))
    {
        writeln!(
            out,
            "first pick: {} at ({:.2}, {:.2}, {:.2}) mm, approach ({:.4}, {:.4}, {:.4})",
            g.name,
            g.position_mm[0],
            g.position_mm[1],
            g.position_mm[2],
            g.approach[0],
            g.approach[1],
            g.approach[2]
        )?;
    }
    Ok(())
}

/// What the scene-voting engine did, in one line, and why the best refused candidate was
/// refused (the parameter to look at when nothing is found).
pub fn voting_summary(v: &binpick::VotingReport) -> String {
    let refused = v.best_refused.as_ref().map_or(String::new(), |b| {
        format!(
            "; best refused: visibility {:.0} %, free space {:.1} %, {} cells: {}",
            100.0 * b.visibility,
            100.0 * b.free_space,
            b.explained_cells,
            b.reason
        )
    });
    format!(
        "{}: {} samples, {} votes, {} hypotheses ({} laid from flat faces), {} candidates verified, {} accepted; refused: {} too little surface, {} low visibility, {} free space, {} crossing a part, {} sunk into support, {} on support, {} no outline, {} poor fit, {} repeats, {} laid from a face against the scan's normals{refused}",
        v.sensor,
        v.scene_samples,
        v.votes,
        v.hypotheses,
        v.face_hypotheses,
        v.candidates,
        v.accepted,
        v.rejected_too_little_surface,
        v.rejected_low_visibility,
        v.rejected_free_space,
        v.rejected_crossing,
        v.rejected_below_support,
        v.rejected_on_support,
        v.rejected_no_outline,
        v.rejected_poor_fit,
        v.rejected_explained,
        v.rejected_face_normals
    )
}

pub fn summary(r: &Recognition) -> String {
    let planes = r.preprocess.support_planes.len();
    let removed: usize = r.preprocess.support_planes.iter().map(|p| p.points).sum();
    format!(
        "{} detection(s) in {:.0} ms; scene {} points, {} merged by the voxel grid, {} outside the ROI, {} stray, {} support plane(s) with {} points removed{}, {} left; {} cluster(s){}",
        r.detections.len(),
        r.timings.total_ms,
        r.preprocess.input_points,
        r.preprocess.voxel_merged,
        r.preprocess.outside_roi,
        r.preprocess.isolated_removed,
        planes,
        removed,
        if r.preprocess.support_noise > 0 {
            format!(" (and {} of their noise tail)", r.preprocess.support_noise)
        } else {
            String::new()
        },
        r.preprocess.remaining,
        r.clusters.len(),
        if r.duplicates_suppressed > 0 {
            format!(", {} duplicate(s) suppressed", r.duplicates_suppressed)
        } else {
            String::new()
        }
    )
}
