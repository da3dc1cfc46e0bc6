//! A robot-cell controller loop: prepare the model once, then for every incoming scan
//! recognise within a time budget and hand the best pick to the robot. Errors (a corrupt scan,
//! a blown budget) are reported and the loop carries on with the next scan.
//!
//! ```text
//! cargo run --release -p binpick --example controller -- MODEL.pcd SCAN.pcd [SCAN.pcd ...]
//! ```
//! (Here "incoming scans" are files; a real cell would receive clouds from its scanner.)

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use binpick::{Params, Recognizer, Units, load_cloud};

fn main() -> ExitCode {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let Some((model_path, scans)) = args.split_first() else {
        eprintln!("usage: controller MODEL.pcd SCAN.pcd [SCAN.pcd ...]   (clouds in mm)");
        return ExitCode::from(2);
    };

    // Once per model: validation, keypoints and FPFH of the model for every radius.
    let mut params = Params::default();
    params.runtime.time_budget_ms = Some(5_000);
    let recognizer = match load_cloud(model_path, Units::Millimetres)
        .and_then(|(model, _)| Recognizer::new(&model, params))
    {
        Ok(r) => r,
        Err(e) => {
            eprintln!("cannot prepare the model: {e}");
            return ExitCode::FAILURE;
        }
    };

    for scan in scans {
        // One cycle per scan. Nothing in here can panic or abort the controller.
        let cycle = load_cloud(scan, Units::Millimetres).and_then(|(cloud, _)| {
            recognizer.recognize_within(&cloud, Some(Duration::from_secs(5)))
        });
        match cycle {
            Ok(result) => match result.detections.first() {
                Some(best) => {
                    let t = best.pose.translation.vector;
                    let q = best.pose.rotation.quaternion();
                    println!(
                        "{}: PICK at ({:.1}, {:.1}, {:.1}) mm, q = ({:.4}, {:.4}, {:.4}, {:.4}); {:.1} % outliers; {} candidate(s); {:.0} ms",
                        scan.display(),
                        t.x,
                        t.y,
                        t.z,
                        q.w,
                        q.i,
                        q.j,
                        q.k,
                        best.final_score,
                        result.detections.len(),
                        result.timings.total_ms
                    );
                }
                None => println!(
                    "{}: nothing pickable (starvation): ask for a new scan or shake the bin",
                    scan.display()
                ),
            },
            Err(binpick::Error::TimeBudget { elapsed_ms, .. }) => {
                println!(
                    "{}: no answer within the budget ({elapsed_ms} ms): skip this cycle",
                    scan.display()
                )
            }
            Err(e) => println!("{}: scan rejected: {e}", scan.display()),
        }
    }
    ExitCode::SUCCESS
}
