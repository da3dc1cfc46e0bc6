//! The pipeline's stages, in thesis order. Each is a function over plain data that takes its
//! own stage config (`crate::params::stages`) and the previous stage's output; the engines and
//! the recognizer compose them.
//!
//! | stage               | thesis                      | input -> output                                  |
//! |---------------------|-----------------------------|--------------------------------------------------|
//! | [`preprocess`]      | 4.3 #1, 5.2                 | scene cloud -> world points + report             |
//! | [`cluster`]         | 3.4.1.3 (3.4.1.2 spheres)   | world -> clusters (point indices)                |
//! | [`features`]        | Alg. 1 step 1a-b            | cluster -> keypoints + FPFH per radius           |
//! | [`initial`]         | Alg. 1 steps 1b-2           | features -> correspondences -> hypotheses -> best |
//! | [`final_alignment`] | Alg. 1 steps 3-4            | initial pose -> ICP pose + percent of outliers   |
//! | [`rank`]            | 1.2 step 3, 5.4.3           | detections -> unique, ranked detections          |
//! | [`model`]           | 5.7 ("precomputed offline") | model cloud -> keypoints, FPFH, near-symmetries  |

pub(crate) mod cluster;
pub(crate) mod features;
pub(crate) mod final_alignment;
pub(crate) mod hypotheses;
pub(crate) mod initial;
pub(crate) mod model;
pub mod part;
pub(crate) mod preprocess;
pub(crate) mod rank;
pub mod scale;
pub(crate) mod verify;
