//! The human-readable ranked table printed by `recognize` and `replay`.

use binpick::{FoundBy, Recognition};

/// Roll, pitch, yaw (XYZ fixed axes), degrees.
fn rpy_deg(p: &nalgebra::Isometry3<f64>) -> [f64; 3] {
    let (r, pi, y) = p.rotation.euler_angles();
    [r.to_degrees(), pi.to_degrees(), y.to_degrees()]
}

/// Columns: rank; `vis %` the estimated visible fraction (scene-voting) or `-`; `final %` the
/// percent of outliers (thesis 3.1.2); `init mm^2` the Euclidean score of the initial pose
/// (3.1.1); position; roll/pitch/yaw (rotations about the fixed x, y, z axes, applied in
/// that order, degrees); `found by` (votes of the pose cluster, or cluster / FPFH radius /
/// RANSAC threshold of the thesis engine); why it ranks there.
pub fn print_ranked(r: &Recognition) {
    println!(
        "{:>4}  {:>6}  {:>8}  {:>10}  {:>9} {:>9} {:>9}  {:>7} {:>7} {:>7}  {:<22}  why",
        "rank",
        "vis %",
        "final %",
        "init mm^2",
        "x mm",
        "y mm",
        "z mm",
        "roll",
        "pitch",
        "yaw",
        "found by"
    );
    for d in &r.detections {
        let t = d.pose.translation.vector;
        let [ro, pi, ya] = rpy_deg(&d.pose);
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
        };
        println!(
            "{:>4}  {:>6}  {:>8.2}  {:>10.2}  {:>9.2} {:>9.2} {:>9.2}  {:>7.1} {:>7.1} {:>7.1}  {:<22}  {}",
            d.rank,
            vis,
            d.final_score,
            d.initial_score,
            t.x,
            t.y,
            t.z,
            ro,
            pi,
            ya,
            found,
            d.rank_reason
        );
    }
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
        "{}: {} samples, {} votes, {} hypotheses, {} candidates verified, {} accepted; refused: {} too little surface, {} low visibility, {} free space, {} no outline, {} poor fit, {} repeats{refused}",
        v.sensor,
        v.scene_samples,
        v.votes,
        v.hypotheses,
        v.candidates,
        v.accepted,
        v.rejected_too_little_surface,
        v.rejected_low_visibility,
        v.rejected_free_space,
        v.rejected_no_outline,
        v.rejected_poor_fit,
        v.rejected_explained
    )
}

pub fn summary(r: &Recognition) -> String {
    let planes = r.preprocess.support_planes.len();
    let removed: usize = r.preprocess.support_planes.iter().map(|p| p.points).sum();
    format!(
        "{} detection(s) in {:.0} ms; scene {} points, {} merged by the voxel grid, {} outside the ROI, {} support plane(s) with {} points removed, {} left; {} cluster(s){}",
        r.detections.len(),
        r.timings.total_ms,
        r.preprocess.input_points,
        r.preprocess.voxel_merged,
        r.preprocess.outside_roi,
        planes,
        removed,
        r.preprocess.remaining,
        r.clusters.len(),
        if r.duplicates_suppressed > 0 {
            format!(", {} duplicate(s) suppressed", r.duplicates_suppressed)
        } else {
            String::new()
        }
    )
}
