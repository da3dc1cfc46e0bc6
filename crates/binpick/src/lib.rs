//! binpick: finds every visible instance of a part in a 3D scan of a bin, returns each one's
//! 6-DOF pose with validation scores, and ranks them for picking.
//!
//! It implements the pipeline of S. Squizzato, "Robot bin picking: 3D pose retrieval based on
//! Point Cloud Library" (thesis chapters 3-4) over the real PCL, reached through
//! [`binpick_pcl`]. Units are millimetres throughout.
//!
//! ```no_run
//! use binpick::{Params, Recognizer, load_cloud};
//! # fn main() -> binpick::Result<()> {
//! let params = Params::default();
//! let (model, _) = load_cloud("model.pcd".as_ref(), params.units)?;
//! let recognizer = Recognizer::new(&model, params)?; // model features computed once
//! let (scene, _) = load_cloud("scan.pcd".as_ref(), binpick::Units::Millimetres)?;
//! let result = recognizer.recognize(&scene)?;
//! // The first part free to pick (none when every part found lies under another).
//! if let Some(best) = result.first_pick() {
//!     println!("pick at {}", best.pose.translation.vector);
//! }
//! // With a time budget and a cancel token: partial, flagged results instead of an error.
//! let cancel = binpick::CancelToken::new();
//! let options = binpick::RecognizeOptions::default()
//!     .time_budget(std::time::Duration::from_millis(300))
//!     .cancel(cancel.clone());
//! let result = recognizer.recognize_with(&scene, &options)?;
//! if let Some(why) = &result.interrupted {
//!     println!("{why}; {} part(s) verified before that", result.detections.len());
//! }
//! # Ok(()) }
//! ```
//!
//! Layers, top to bottom (each imports only those below it):
//! [`Recognizer`] (the pipeline) and the reference engine -> the engines (per-cluster
//! Algorithms 1/2) -> the stages (preprocess, cluster, features, initial and final alignment,
//! rank, and the model prepared once) -> the validation scores ([`validate`]) -> plain data:
//! [`Params`] (one config per stage) and the results ([`Recognition`], [`Detection`],
//! [`RecognitionReport`]).
//!
//! The library never prints: it emits `tracing` spans and events (target `binpick`) for the
//! caller's subscriber, if any (the `binpick` CLI prints them on stderr with `-v`).

#![warn(missing_docs)]

mod deadline;
mod engines;
pub mod error;
mod frames;
mod grasp;
pub mod inspect;
mod params;
mod part_file;
pub mod pose;
pub mod prepared;
mod recognizer;
#[cfg(feature = "reference")]
pub mod reference;
mod result;
mod stages;
pub mod validate;
mod workers;

pub use binpick_cloud::{Point, PointCloud, Units};
pub use binpick_match::Symmetries;
pub use deadline::CancelToken;
pub use error::{Error, ErrorKind, InputKind, Result};
pub use frames::{BASE_FRAME_ID, OutputFrame};
pub use grasp::{Blocker, Grasp, GraspCheck};
pub use inspect::{PartInspection, SelfMatch, SelfMatchKind, inspect_part};
pub use params::{
    Algorithm, ClusteringConfig, ConsensusConfig, Engine, FeatureConfig, FeatureSurface, IcpConfig,
    ParamError, Params, PileSearchConfig, PreprocessConfig, Preset, RankingConfig,
    RegionOfInterest, RuntimeConfig, SensorConfig, SupportRemoval, ValidationConfig, VerifyConfig,
    VotingConfig,
};
pub use params::{THESIS_RESOLUTION_MM, THESIS_SUPPORT_DISTANCE_MM};
pub use part_file::{
    PartLoadReport, REVOLUTION_STEP_DEG, Sidecar, load_part, read_sidecar, sidecar_path,
};
pub use recognizer::{RecognizeOptions, Recognizer};
pub use result::{
    CandidateRecord, DerivedScale, PoseCheck, RESULT_SCHEMA_VERSION, RefusedCandidate, RosPoint,
    RosPose, RosQuaternion, SCANNER_FRAME_ID, VotingReport,
};
pub use result::{
    ClusterReport, Detection, FoundBy, IcpReport, Interruption, PreprocessReport, Recognition,
    RecognitionReport, RemovedPlane, StopCause, Timings, ViewCheck,
};
pub use stages::model::PreparedModel;
pub use stages::part::{Part, PartSource};
pub use stages::scale::{PartSize, Spacing};

use std::path::Path;

/// Where the sensor that captured a cloud was, in mm, as far as its file says: the PCD
/// `VIEWPOINT` when it is not PCL's default, else the origin for an organised cloud (PCL
/// writes depth images in their camera's frame); None when the file does not say.
pub fn sensor_position(report: &binpick_cloud::io::LoadReport, units: Units) -> Option<[f64; 3]> {
    match report.sensor_viewpoint() {
        Some(v) => Some(v.scaled(f64::from(units.to_mm())).position),
        None => (report.height > 1).then_some([0.0; 3]),
    }
}

/// Reads a PCD or PLY cloud and converts it to millimetres from `units`.
pub fn load_cloud(
    path: &Path,
    units: Units,
) -> Result<(PointCloud, binpick_cloud::io::LoadReport)> {
    let (mut cloud, report) = binpick_cloud::io::read_cloud(path)?;
    tracing::debug!(
        path = %path.display(),
        points = cloud.len(),
        non_finite_dropped = report.non_finite_dropped,
        organised = report.is_organized(),
        "cloud read"
    );
    let f = units.to_mm();
    if f != 1.0 {
        cloud.scale(f);
    }
    Ok((cloud, report))
}

#[cfg(test)]
mod tests {
    #[test]
    fn recognizer_is_send_and_sync() {
        fn check<T: Send + Sync>() {}
        check::<super::Recognizer>();
    }
}
