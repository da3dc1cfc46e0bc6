//! Detection engines: each turns the preprocessed scene into accepted detections, using the
//! shared stages (`crate::stages`). The recognizer runs one engine per scene; today that is
//! [`cluster_search`], the thesis's Algorithms 1/2 per Euclidean cluster. A scene-wide engine
//! (e.g. point-pair-feature voting with verification) plugs in beside it, reusing
//! preprocessing, the final alignment, the validators and the ranking.

pub(crate) mod cluster_search;
pub(crate) mod scene_voting;
