//! The scene-voting engine: every part of a pile from hypotheses over the whole scene, each
//! verified against what the sensor could see, competing to explain the scene.
//!
//! ```text
//! detect(points, support):
//!   sensor     = the configured sensor, or a camera at the origin / a scanner above
//!   samples    = the scene without its support, sampled at the step, with normals  (PCL)
//!   hypotheses = point-pair votes of every reference point, clustered into poses   (Drost 2010)
//!   view       = the sensor's range grid of the whole scene, support included
//!   in parallel, for each hypothesis:
//!     refine by ICP on the model surface the sensor can see in that pose          (PCL ICP)
//!     judge against the view: explained, occluded, free space, missing
//!   acceptable ones also turned by the part's near-symmetries, refined and judged
//!   parts = greedy scene explanation: most newly explained surface first          (Aldoma 2012)
//!   each part: the thesis's validators on its visible surface, its canonical pose
//! ```

use std::time::Instant;

use nalgebra::Isometry3;
use rayon::prelude::*;

use binpick_cloud::Point;
use binpick_match::{ExplainConfig, OrientedPoints, Rejection, Sensor, ViewScore, explain_scene};

use crate::deadline::{Deadline, ms};
use crate::error::Result;
use crate::params::Params;
use crate::result::{
    CandidateRecord, DerivedScale, Detection, FoundBy, IcpReport, RefusedCandidate, VotingReport,
};
use crate::stages::hypotheses::{VotingModel, matching, scene_normals, scene_samples, vote};
use crate::stages::part::Part;
use crate::stages::rank::height_mm;
use crate::stages::verify::{SceneSurface, Verifier, resolve_sensor, view_check, viewpoint};

/// What the engine found in the scene.
pub(crate) struct VotingFound {
    pub detections: Vec<Detection>,
    pub report: VotingReport,
    /// Voting (samples, normals, votes, clustering), ms.
    pub voting_ms: f64,
    /// Verification (refinement, view, explanation, validators), ms.
    pub verify_ms: f64,
}

/// Everything the engine reads.
pub(crate) struct SceneVoting<'a> {
    pub params: &'a Params,
    pub part: &'a Part,
    pub model: &'a VotingModel,
    pub scale: &'a DerivedScale,
    pub deadline: &'a Deadline,
    pub threads: usize,
}

/// One verified pose.
struct Candidate {
    /// Index of the pose cluster it came from.
    hypothesis: usize,
    votes: u32,
    /// The voted pose (composed with a near-symmetry for a variant).
    initial: Isometry3<f64>,
    /// After refinement.
    pose: Isometry3<f64>,
    icp: IcpReport,
    score: ViewScore,
}

impl SceneVoting<'_> {
    /// `points`: the preprocessed scene; `support[i]`: point i is belt, floor or wall.
    pub(crate) fn detect(&self, points: &[Point], support: &[bool]) -> Result<VotingFound> {
        let p = self.params;
        let lap = Instant::now();
        let sensor = resolve_sensor(&p.verify.sensor, p.ranking.up, points)?;
        let normals = scene_normals(
            points,
            self.scale,
            viewpoint(&sensor, points),
            self.threads as u32,
        )?;
        let (world, world_normals): (Vec<Point>, Vec<[f32; 3]>) = points
            .iter()
            .zip(&normals)
            .zip(support)
            .filter_map(|((q, n), s)| (!s).then_some((*q, *n)))
            .unzip();
        let surface = SceneSurface {
            points: points.to_vec(),
            normals,
            support: support.to_vec(),
            world,
        };
        let world = &surface.world;
        let mut report = VotingReport {
            sensor: describe(&sensor),
            ..VotingReport::default()
        };
        if world.len() < 3 {
            return Ok(VotingFound {
                detections: Vec::new(),
                report,
                voting_ms: ms(lap.elapsed()),
                verify_ms: 0.0,
            });
        }
        let samples = scene_samples(
            OrientedPoints {
                points: world.clone(),
                normals: world_normals,
            },
            self.scale,
        )?;
        self.deadline.check("scene normals")?;
        let (votes, hypotheses) = vote(self.model, self.part, &samples, self.scale, &p.voting)?;
        report.scene_samples = samples.len();
        report.votes = votes;
        report.hypotheses = hypotheses.len();
        self.deadline.check("voting")?;
        let voting_ms = ms(lap.elapsed());

        let lap = Instant::now();
        let verifier = Verifier::new(sensor, &surface, self.model, self.scale, &p.verify)?;
        let mut candidates: Vec<Candidate> = hypotheses
            .par_iter()
            .enumerate()
            .map(|(i, h)| self.verify(&verifier, i, h.votes, &h.pose))
            .collect::<Result<_>>()?;
        let accept = self.acceptance(&verifier);
        if p.verify.near_symmetry_variants && !self.model.near_symmetries.is_empty() {
            let turned: Vec<(usize, u32, Isometry3<f64>)> = candidates
                .iter()
                .filter(|c| accept.rejection(&c.score).is_none())
                .flat_map(|c| {
                    self.model
                        .near_symmetries
                        .iter()
                        .map(move |s| (c.hypothesis, c.votes, c.pose * s))
                })
                .collect();
            let variants: Vec<Candidate> = turned
                .par_iter()
                .map(|(i, v, pose)| self.verify(&verifier, *i, *v, pose))
                .collect::<Result<_>>()?;
            candidates.extend(variants);
        }
        report.candidates = candidates.len();
        let scores: Vec<ViewScore> = candidates.iter().map(|c| c.score.clone()).collect();
        let explanation = explain_scene(&scores, verifier.grid.cells(), &accept)
            .map_err(matching("scene explanation"))?;
        self.tally(&explanation.rejected, &scores, &mut report);
        report.accepted = explanation.taken.len();
        if p.verify.report_candidates {
            report.candidates_detail = candidates
                .iter()
                .zip(&explanation.rejected)
                .map(|(c, why)| CandidateRecord {
                    hypothesis: c.hypothesis,
                    votes: c.votes,
                    pose: binpick_cloud::pose_to_row_major(&c.pose),
                    view: view_check(&c.score),
                    explained_cells: c.score.explained,
                    verdict: why.map_or("taken".to_owned(), |w| format!("{w:?}")),
                })
                .collect();
        }

        let detections = explanation
            .taken
            .iter()
            .map(|&i| self.detection(&verifier, &candidates[i]))
            .collect();
        Ok(VotingFound {
            detections,
            report,
            voting_ms,
            verify_ms: ms(lap.elapsed()),
        })
    }

    /// Refines one pose and judges it against the view.
    fn verify(
        &self,
        verifier: &Verifier,
        hypothesis: usize,
        votes: u32,
        initial: &Isometry3<f64>,
    ) -> Result<Candidate> {
        self.deadline.check("verification")?;
        let (pose, icp) = verifier.refine(initial)?;
        let icp = IcpReport {
            converged: icp.as_ref().is_some_and(|o| o.converged),
            iterations: icp.as_ref().map_or(0, |o| o.iterations),
            fitness_mm2: icp
                .as_ref()
                .and_then(|o| IcpReport::usable_fitness(o.fitness)),
            adopted: icp.is_some(),
            error: None,
        };
        Ok(Candidate {
            hypothesis,
            votes,
            initial: *initial,
            score: verifier.score(&pose),
            pose,
            icp,
        })
    }

    /// Acceptance and competition settings at this scale.
    fn acceptance(&self, verifier: &Verifier) -> ExplainConfig {
        let v = &self.params.verify;
        ExplainConfig {
            min_visibility: v.min_visibility,
            max_free_space: v.max_free_space,
            max_continued: v.max_continued,
            min_fit: v.min_fit,
            min_explained_cells: (v.min_explained_share * verifier.typical_cells())
                .ceil()
                .max(1.0) as u32,
            free_space_weight: v.free_space_weight,
            min_new_share: v.min_new_share,
        }
    }

    /// Counts why candidates were refused and keeps the best refused one that was not a
    /// repeat of a taken part.
    fn tally(&self, rejected: &[Option<Rejection>], scores: &[ViewScore], r: &mut VotingReport) {
        let mut best: Option<(f64, usize, Rejection)> = None;
        for (i, why) in rejected.iter().enumerate() {
            let Some(why) = why else { continue };
            match why {
                Rejection::TooLittleSurface => r.rejected_too_little_surface += 1,
                Rejection::LowVisibility => r.rejected_low_visibility += 1,
                Rejection::FreeSpace => r.rejected_free_space += 1,
                Rejection::NoOutline => r.rejected_no_outline += 1,
                Rejection::PoorFit => r.rejected_poor_fit += 1,
                Rejection::Explained => r.rejected_explained += 1,
            }
            if *why != Rejection::Explained {
                let e = f64::from(scores[i].explained);
                if best.is_none_or(|(b, _, _)| e > b) {
                    best = Some((e, i, *why));
                }
            }
        }
        r.best_refused = best.map(|(_, i, why)| {
            let s = &scores[i];
            RefusedCandidate {
                visibility: s.visibility(),
                free_space: s.free_space_ratio(),
                explained_cells: s.explained,
                reason: match why {
                    Rejection::TooLittleSurface => {
                        "too little confirmed surface (min_explained_share)"
                    }
                    Rejection::LowVisibility => {
                        "too little of its visible surface confirmed (min_visibility)"
                    }
                    Rejection::FreeSpace => "the sensor saw through it (max_free_space)",
                    Rejection::NoOutline => {
                        "the scene's surface carries on past its outline (max_continued)"
                    }
                    Rejection::PoorFit => "the scene lies too far from the model (min_fit)",
                    Rejection::Explained => "repeats a taken part (min_new_share)",
                }
                .to_owned(),
            }
        });
    }

    /// A taken candidate as a detection: canonical pose, validators, view check.
    fn detection(&self, verifier: &Verifier, c: &Candidate) -> Detection {
        let s = self.part.symmetries.canonical_symmetry(&c.pose);
        let pose = c.pose * s;
        let initial_pose = c.initial * s;
        let before = verifier.thesis_scores(&c.initial);
        let after = verifier.thesis_scores(&c.pose);
        Detection {
            rank: 0,
            pose,
            initial_pose,
            initial_score: before.euclidean,
            final_score: after.outliers_pct,
            score_before_icp: before.outliers_pct,
            found_by: FoundBy::Voting {
                votes: c.votes,
                hypothesis: c.hypothesis,
            },
            view: Some(view_check(&c.score)),
            icp: c.icp.clone(),
            height_mm: height_mm(&pose, &self.model.dense.points, self.params.ranking.up),
            rank_reason: String::new(),
        }
    }
}

/// The sensor, in words.
fn describe(sensor: &Sensor) -> String {
    match sensor {
        Sensor::Perspective { position, .. } => format!(
            "camera at ({:.0}, {:.0}, {:.0}) mm",
            position.x, position.y, position.z
        ),
        Sensor::Orthographic { up } => {
            format!(
                "scanner above, along ({:.2}, {:.2}, {:.2})",
                up.x, up.y, up.z
            )
        }
    }
}
