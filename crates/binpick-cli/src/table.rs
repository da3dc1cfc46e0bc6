//! The human-readable ranked table printed by `recognize` and `replay`.

use binpick::Recognition;

/// Roll, pitch, yaw (XYZ fixed axes), degrees.
fn rpy_deg(p: &nalgebra::Isometry3<f64>) -> [f64; 3] {
    let (r, pi, y) = p.rotation.euler_angles();
    [r.to_degrees(), pi.to_degrees(), y.to_degrees()]
}

pub fn print_ranked(r: &Recognition) {
    println!(
        "{:>4}  {:>8}  {:>10}  {:>9} {:>9} {:>9}  {:>7} {:>7} {:>7}  {:>7}  {:>6}  {:>5}  why",
        "rank",
        "final %",
        "init mm^2",
        "x mm",
        "y mm",
        "z mm",
        "roll",
        "pitch",
        "yaw",
        "cluster",
        "radius",
        "thr"
    );
    for d in &r.detections {
        let t = d.pose.translation.vector;
        let [ro, pi, ya] = rpy_deg(&d.pose);
        let radius = d
            .fpfh_radius_mm
            .map_or("merged".to_string(), |x| format!("{x:.0}"));
        println!(
            "{:>4}  {:>8.2}  {:>10.2}  {:>9.2} {:>9.2} {:>9.2}  {:>7.1} {:>7.1} {:>7.1}  {:>7}  {:>6}  {:>5.1}  {}",
            d.rank,
            d.final_score,
            d.initial_score,
            t.x,
            t.y,
            t.z,
            ro,
            pi,
            ya,
            d.cluster,
            radius,
            d.sac_threshold_mm,
            d.rank_reason
        );
    }
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
