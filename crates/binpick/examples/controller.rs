//! A robot-cell controller loop: prepare the model once, then for every incoming scan
//! recognise within a time budget and hand the first free grasp to the robot, in the robot's
//! base frame. Errors (a corrupt scan) are reported and the loop carries on with the next
//! scan; a blown budget returns the parts verified in time, flagged.
//!
//! ```text
//! cargo run --release -p binpick --example controller -- MODEL SCAN.pcd [SCAN.pcd ...] \
//!     [--scanner-to-base cell.toml]
//! ```
//! The model's sidecar (`MODEL.json`) declares the grasps (README "Frames and grasps");
//! without grasps the pick is the part's pose. (Here "incoming scans" are files; a real cell
//! would receive clouds from its scanner.)

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use binpick::{OutputFrame, Params, RecognizeOptions, Recognizer, Units, load_cloud, load_part};

fn main() -> ExitCode {
    let mut args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    // Optional calibration: where the scanner is in the robot's base frame.
    let frame = match args
        .iter()
        .position(|a| a.as_os_str() == "--scanner-to-base")
    {
        Some(k) if k + 1 < args.len() => {
            let path = args.remove(k + 1);
            args.remove(k);
            match OutputFrame::read(&path) {
                Ok(f) => f,
                Err(e) => {
                    eprintln!("cannot read the calibration: {e}");
                    return ExitCode::FAILURE;
                }
            }
        }
        Some(_) => {
            eprintln!("--scanner-to-base needs a file");
            return ExitCode::from(2);
        }
        None => OutputFrame::scanner(),
    };
    let Some((model_path, scans)) = args.split_first() else {
        eprintln!(
            "usage: controller MODEL SCAN.pcd [SCAN.pcd ...] [--scanner-to-base cell.toml]   (mm)"
        );
        return ExitCode::from(2);
    };

    // Once per model: the part (and the grasps of its sidecar), the engine's model.
    let params = Params::default();
    let recognizer = match load_part(model_path, Units::Millimetres, &params)
        .and_then(|(part, _)| Recognizer::with_part(part, params))
    {
        Ok(r) => r,
        Err(e) => {
            eprintln!("cannot prepare the model: {e}");
            return ExitCode::FAILURE;
        }
    };

    for scan in scans {
        // One cycle per scan. Nothing in here can panic or abort the controller.
        // A blown budget is not an error: the parts verified in time come back, flagged.
        let options = RecognizeOptions::default()
            .time_budget(Duration::from_secs(5))
            .output_frame(frame.clone());
        let cycle = load_cloud(scan, Units::Millimetres).and_then(|(cloud, loaded)| {
            let seen_from = binpick::sensor_position(&loaded, Units::Millimetres);
            recognizer.recognize_with(&cloud, &options.sensor_position_mm(seen_from))
        });
        let result = match cycle {
            Ok(r) => r,
            Err(e) => {
                println!("{}: scan rejected: {e}", scan.display());
                continue;
            }
        };
        let incomplete = match &result.interrupted {
            Some(why) => format!(" ({why}: search incomplete)"),
            None => String::new(),
        };
        let Some(best) = result.first_pick() else {
            match (&result.interrupted, result.detections.first()) {
                (_, Some(top)) => println!(
                    "{}: no part is free to pick ({} found; best: {}): shake the bin{incomplete}",
                    scan.display(),
                    result.detections.len(),
                    top.rank_reason
                ),
                (Some(_), None) => println!("{}: nothing verified in time: skip", scan.display()),
                (None, None) => println!(
                    "{}: nothing pickable (starvation): ask for a new scan or shake the bin",
                    scan.display()
                ),
            }
            continue;
        };
        let frame_id = &result.frame.frame_id;
        match best.grasps.iter().find(|g| g.free) {
            Some(g) => println!(
                "{}: PICK {} at ({:.1}, {:.1}, {:.1}) mm, approach ({:.3}, {:.3}, {:.3}) in {frame_id}; {} part(s); {:.0} ms{incomplete}",
                scan.display(),
                g.name,
                g.position_mm[0],
                g.position_mm[1],
                g.position_mm[2],
                g.approach[0],
                g.approach[1],
                g.approach[2],
                result.detections.len(),
                result.timings.total_ms,
            ),
            // The first pick has a free grasp whenever grasps are declared.
            None => {
                let t = best.pose.translation.vector;
                let q = best.pose.rotation.quaternion();
                println!(
                    "{}: PICK part at ({:.1}, {:.1}, {:.1}) mm, q = ({:.4}, {:.4}, {:.4}, {:.4}) in {frame_id} (no grasps declared); {} part(s); {:.0} ms{incomplete}",
                    scan.display(),
                    t.x,
                    t.y,
                    t.z,
                    q.w,
                    q.i,
                    q.j,
                    q.k,
                    result.detections.len(),
                    result.timings.total_ms,
                );
            }
        }
    }
    ExitCode::SUCCESS
}
