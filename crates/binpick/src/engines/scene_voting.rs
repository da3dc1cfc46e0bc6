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
//!   each part against its acceptable turns, point by point where they differ
//!   each part: the thesis's validators on its visible surface, its canonical pose
//! ```

use std::time::Instant;

use nalgebra::Isometry3;
use rayon::prelude::*;

use binpick_cloud::Point;
use binpick_match::faces::{FlatRegions, Laying, flat_patches, laid_poses};
use binpick_match::{
    ExplainConfig, OrientedPoints, PoseCluster, Rejection, Sensor, ViewScore, explain_scene,
};

use crate::deadline::{Deadline, ms};
use crate::error::{Result, matching};
use crate::params::Params;
use crate::result::{
    CandidateRecord, DerivedScale, Detection, FoundBy, IcpReport, PoseCheck, RefusedCandidate,
    VotingReport,
};
use crate::stages::hypotheses::{
    Voted, VotingModel, scene_normals, scene_rims, scene_samples, view_normals, vote,
};
use crate::stages::part::{Part, PartSource};
use crate::stages::rank::height_mm;
use crate::stages::verify::{
    Probe, SceneSurface, SeenSurface, Verifier, bounding_planes, edge_on_cells, resolve_sensor,
    sunk_depth_mm, view_check, viewpoint,
};

/// The turns' gap ([`turn_gap_mm`]) is measured on this many of the part's surface points
/// ...
const TURN_GAP_POINTS: usize = 4000;
/// ... at this percentile of their distances to the surface.
const TURN_GAP_PERCENTILE: f64 = 0.99;
/// A taken part and its turn differ where their surfaces lie more than this share of the
/// turns' gap or of the view tolerance apart, whichever is more
/// ([`SceneVoting::settle_turns`]; at 0.5 mm a tolerance is 1.3 mm, and a pose ICP left a few
/// degrees tilted differs from its turn over much of the part by more than half that) ...
const TURN_APART_SHARE: f64 = 0.5;
/// ... there both must show the sensor at least this many surface points, unhidden ...
const TURN_MIN_APART_POINTS: usize = 30;
/// ... and the turn replaces the part when its residual there is under this share of the
/// part's ...
const TURN_CLOSER_SHARE: f64 = 0.5;
/// ... or when the sensor sees through at least this share of the part's surface there (and
/// at least [`TURN_MIN_FREE_CELLS`] cells) and through none of the turn's: a flange end laid
/// past the part's shorter one.
const TURN_SEEN_THROUGH_SHARE: f64 = 0.05;
/// The fewest cells seen through that count ([`TURN_SEEN_THROUGH_SHARE`]).
const TURN_MIN_FREE_CELLS: u32 = 3;
/// A pose of another part contests a part taken when its mean fit is at least this much
/// higher ([`SceneVoting::contested`]; the pose it displaced on seed 16's
/// `brackets-bin-2mm-002` fitted 0.94 against 0.87).
const CONTEST_FIT_MARGIN: f64 = 0.03;
/// A part taken that claims at least this share of the surface of such a pose is left out
/// of the scene explanation with every candidate of its pose, and the explanation made
/// again ([`SceneVoting::without_contested`]; seed 13's `brackets-bin-2mm-000`: a pose
/// laid across two brackets explained 543 view cells against the displaced right pose's
/// 328, fitting 0.77 against 0.84; the same share the ranking's `contested_max` defaults
/// to) ...
const CONTEST_LEAVE_OUT_SHARE: f64 = 0.6;
/// ... at most this many times.
const CONTEST_ROUNDS: usize = 3;
/// Flat faces: neighbouring samples within this many sampling steps grow one region ...
const FACE_CONNECT_STEPS: f64 = 1.5;
/// ... when their normals are within this angle of the region's seed's, deg ...
const FACE_MAX_ANGLE_DEG: f64 = 15.0;
/// ... and they lie within this many tolerances of its plane.
const FACE_OFFSET_TOLERANCES: f64 = 2.0;
/// Fewer samples make no flat face (model or scene).
const FACE_MIN_SAMPLES: usize = 12;
/// A scene patch is laid on a model face it covers at least this share of (in samples).
const FACE_MIN_COVER: f64 = 0.4;
/// Lengths of patch and face agree within this many sampling steps.
const FACE_SLACK_STEPS: f64 = 2.0;
/// A part laid from a face is refused when more than this share of its visible cells
/// meet scan surface facing another way.
const FACE_MAX_WRONG_NORMAL: f64 = 0.03;
/// Patches and faces filling less of their extent's rectangle are not laid.
const FACE_MIN_FILL: f64 = 0.5;

/// A scene sample is explained by a taken part within this many view tolerances of its
/// surface (later voting rounds skip it).
const UNEXPLAINED_TOLERANCES: f64 = 2.0;

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
    /// The support planes preprocessing found (`a x + b y + c z + d = 0`, mm).
    pub support_planes: &'a [[f64; 4]],
}

/// One verified pose.
#[derive(Clone)]
struct Candidate {
    /// Index of the pose cluster it came from.
    hypothesis: usize,
    votes: u32,
    /// A near-symmetric turn of the voted pose (its votes are the voted pose's).
    turned: bool,
    /// The voted pose (composed with a near-symmetry for a variant).
    initial: Isometry3<f64>,
    /// After refinement.
    pose: Isometry3<f64>,
    icp: IcpReport,
    score: ViewScore,
}

impl SceneVoting<'_> {
    /// The sensor and the scene's surface with normals: `points` is the preprocessed scene,
    /// `support[i]` says point i is belt, floor or wall.
    pub(crate) fn surface(
        &self,
        points: &[Point],
        support: &[bool],
    ) -> Result<(Sensor, SceneSurface)> {
        let p = self.params;
        let sensor = resolve_sensor(&p.verify.sensor, p.ranking.up, points)?;
        let world: Vec<Point> = points
            .iter()
            .zip(support)
            .filter_map(|(q, s)| (!s).then_some(*q))
            .collect();
        let bounding = bounding_planes(
            self.support_planes,
            points,
            support,
            sunk_depth_mm(self.scale),
            self.scale.support_distance_mm,
        );
        let planes: Vec<([f64; 4], bool)> = self
            .support_planes
            .iter()
            .zip(&bounding)
            .map(|(c, b)| (*c, b.is_some()))
            .collect();
        let towards = viewpoint(&sensor, points);
        let (normals, indexes) = scene_normals(
            points,
            support,
            &planes,
            self.scale,
            towards,
            self.threads as u32,
        )?;
        let view_normals = view_normals(
            points,
            &indexes,
            support,
            &normals,
            self.scale.normal_radius_mm,
            towards,
        )?;
        let surface = SceneSurface {
            ribbons: Vec::new(),
            points: points.to_vec(),
            normals,
            view_normals,
            support: support.to_vec(),
            world,
            bounding: bounding.into_iter().flatten().collect(),
        };
        Ok((sensor, surface))
    }

    /// Judges given poses against the scene, each refined first when `refine`: the scene's
    /// surface and view are built once for all of them. In the order given.
    pub(crate) fn check(
        &self,
        points: &[Point],
        support: &[bool],
        poses: &[Isometry3<f64>],
        refine: bool,
    ) -> Result<Vec<PoseCheck>> {
        let (sensor, surface) = self.surface(points, support)?;
        let verifier = Verifier::new(
            sensor,
            &surface,
            self.model,
            self.scale,
            &self.params.verify,
        )?;
        let accept = self.acceptance(&verifier);
        poses
            .par_iter()
            .map(|pose| self.check_one(&verifier, &accept, pose, refine))
            .collect()
    }

    /// [`SceneVoting::check`] of one pose.
    fn check_one(
        &self,
        verifier: &Verifier,
        accept: &ExplainConfig,
        pose: &Isometry3<f64>,
        refine: bool,
    ) -> Result<PoseCheck> {
        let judge = |initial: &Isometry3<f64>| -> Result<(Isometry3<f64>, ViewScore)> {
            if refine {
                let (pose, _, score) = self.refine_if_better(verifier, accept, initial)?;
                Ok((pose, score))
            } else {
                Ok((*initial, verifier.score(initial)))
            }
        };
        let (pose, score) = judge(pose)?;
        // As in `detect`, the pose is judged by the scene explanation (its outline is checked
        // there) and competes with its near-symmetric turns: a turn that explains the scene
        // better wins (a half-turned bracket loses to the right one), and they are settled
        // where they differ.
        let candidate = |pose: Isometry3<f64>, score: ViewScore, turned: bool| Candidate {
            hypothesis: 0,
            votes: 0,
            turned,
            initial: pose,
            pose,
            icp: icp_report(None, false),
            score,
        };
        let mut family = vec![candidate(pose, score.clone(), false)];
        if accept.rejection(&score).is_none() && self.params.verify.near_symmetry_variants {
            for s in &self.model.near_symmetries {
                let (turned, turned_score) = judge(&(pose * s))?;
                family.push(candidate(turned, turned_score, true));
            }
        }
        // Nobody voted for the given pose or its turns: the best gain wins.
        let scores: Vec<ViewScore> = family.iter().map(|c| c.score.clone()).collect();
        let votes = vec![0; scores.len()];
        let mut explanation = explain_scene(
            &scores,
            &votes,
            |_, _| false,
            &verifier.support_explained,
            accept,
        )
        .map_err(matching("scene explanation"))?;
        let replaced = self.settle_turns(verifier, &family, &mut explanation)?;
        let refusal = match (explanation.rejected[0], explanation.taken.first()) {
            (None, _) => None,
            (Some(Rejection::Explained), Some(&k)) if replaced.contains(&0) => Some(format!(
                "NearSymmetry: where the two differ, its near-symmetric turn {k} fits the scan \
                 closer or the sensor sees through this pose"
            )),
            (Some(Rejection::Explained), Some(&k)) => Some(format!(
                "NearSymmetry: its near-symmetric turn {} explains more of the scene ({} \
                 cells against {})",
                k, scores[k].explained, score.explained
            )),
            (Some(why), _) => Some(format!("{why:?}")),
        };
        let scores = verifier.thesis_scores(&pose);
        Ok(PoseCheck {
            pose,
            view: view_check(&score),
            explained_cells: score.explained,
            refusal,
            euclidean_score_mm2: scores.euclidean,
            outliers_pct: scores.outliers_pct,
        })
    }

    /// `points`: the preprocessed scene; `support[i]`: point i is belt, floor or wall.
    pub(crate) fn detect(&self, points: &[Point], support: &[bool]) -> Result<VotingFound> {
        let p = self.params;
        let lap = Instant::now();
        let (sensor, mut surface) = self.surface(points, support)?;
        let mut report = VotingReport {
            sensor: describe(&sensor),
            turn_ambiguous: self.model.turn_ambiguous,
            ..VotingReport::default()
        };
        if surface.world.len() < 3 {
            return Ok(VotingFound {
                detections: Vec::new(),
                report,
                voting_ms: ms(lap.elapsed()),
                verify_ms: 0.0,
            });
        }
        let world_normals = surface
            .normals
            .iter()
            .zip(&surface.support)
            .filter_map(|(n, s)| (!s).then_some(*n))
            .collect();
        let samples = scene_samples(
            OrientedPoints {
                points: surface.world.clone(),
                normals: world_normals,
            },
            self.scale,
        )?;
        let rims = if self.model.rims.is_some() {
            let (rims, ribbons) = scene_rims(
                &surface.world,
                &samples,
                self.scale.sampling_step_mm,
                self.scale.model_diameter_mm,
                viewpoint(&sensor, points),
            )?;
            surface.ribbons = ribbons;
            rims
        } else {
            OrientedPoints::default()
        };
        self.deadline.check("scene normals")?;
        let voting = tracing::info_span!("voting").entered();
        let voted = vote(
            self.model, self.part, &samples, &rims, self.scale, &p.voting,
        )?;
        let hypotheses = &voted.clusters;
        report.scene_samples = samples.len();
        report.votes = voted.votes;
        report.hypotheses = hypotheses.len();
        self.deadline.check("voting")?;
        drop(voting);
        tracing::debug!(
            scene_samples = samples.len(),
            hypotheses = hypotheses.len(),
            "voted"
        );
        let voting_ms = ms(lap.elapsed());
        let _verification = tracing::info_span!("verification").entered();

        let lap = Instant::now();
        let verifier = Verifier::new(sensor, &surface, self.model, self.scale, &p.verify)?;
        let accept = self.acceptance(&verifier);
        let (mut candidates, mut laid_on_surfaces) =
            Self::off_surfaces(&verifier, self.candidates(&verifier, &accept, &voted, 0)?);
        let mut explanation = self.explain(&candidates, &verifier.support_explained, &accept)?;
        // Further rounds vote over what the taken parts leave unexplained.
        let mut offset = hypotheses.len();
        for _ in 1..p.voting.rounds {
            if self.deadline.check("voting").is_err() {
                break;
            }
            let rest = self.unexplained(&samples, &candidates, &explanation.taken)?;
            let rest_rims = self.unexplained(&rims, &candidates, &explanation.taken)?;
            let more = vote(
                self.model, self.part, &rest, &rest_rims, self.scale, &p.voting,
            )?;
            report.votes += more.votes;
            report.hypotheses += more.clusters.len();
            if more.clusters.is_empty() {
                break;
            }
            self.later_round(
                &verifier,
                &accept,
                &more,
                &mut offset,
                &mut candidates,
                &mut report,
                &mut laid_on_surfaces,
            )?;
            explanation = self.explain(&candidates, &verifier.support_explained, &accept)?;
        }
        // Flat faces left unexplained are laid on the model's flat faces of about their size
        // (voting cannot place a flat face).
        if p.voting.face_hypotheses > 0 && self.deadline.check("voting").is_ok() {
            let rest = self.unexplained(&samples, &candidates, &explanation.taken)?;
            let laid = self.face_hypotheses(&rest)?;
            report.hypotheses += laid.clusters.len();
            report.face_hypotheses = laid.clusters.len();
            if !laid.clusters.is_empty() {
                let first = candidates.len();
                self.later_round(
                    &verifier,
                    &accept,
                    &laid,
                    &mut offset,
                    &mut candidates,
                    &mut report,
                    &mut laid_on_surfaces,
                )?;
                // Laid by one face, a part must meet the scan's normals elsewhere too.
                let before = candidates.len();
                let mut k = 0;
                candidates.retain(|c| {
                    k += 1;
                    k <= first
                        || f64::from(c.score.wrong_normal)
                            <= FACE_MAX_WRONG_NORMAL * f64::from(c.score.visible)
                });
                report.rejected_face_normals += before - candidates.len();
                explanation = self.explain(&candidates, &verifier.support_explained, &accept)?;
            }
        }
        let mut explanation = self.without_contested(
            &candidates,
            &verifier.support_explained,
            &accept,
            explanation,
        )?;
        let turned_out = self.settle_turns(&verifier, &candidates, &mut explanation)?;
        report.candidates = candidates.len();
        let scores: Vec<ViewScore> = candidates.iter().map(|c| c.score.clone()).collect();
        self.tally(&explanation.rejected, &scores, &mut report);
        report.rejected_no_outline += laid_on_surfaces;
        report.accepted = explanation.taken.len();
        if p.verify.report_candidates {
            report.candidates_detail = candidates
                .iter()
                .zip(&explanation.rejected)
                .enumerate()
                .map(|(k, (c, why))| CandidateRecord {
                    hypothesis: c.hypothesis,
                    votes: c.votes,
                    pose: binpick_cloud::pose_to_row_major(&c.pose),
                    view: view_check(&c.score),
                    explained_cells: c.score.explained,
                    verdict: if turned_out.contains(&k) {
                        "TurnFitsCloser".to_owned()
                    } else {
                        why.map_or("taken".to_owned(), |w| format!("{w:?}"))
                    },
                })
                .collect();
        }

        let contested = self.contested(&candidates, &explanation);
        let taken = explanation
            .taken
            .par_iter()
            .map(|&i| self.polished(&verifier, &candidates[i]))
            .collect::<Result<Vec<Candidate>>>()?;
        let detections = taken
            .par_iter()
            .zip(&contested)
            .map(|(c, &contested)| {
                let mut d = self.detection(&verifier, c);
                if let Some(v) = &mut d.view {
                    v.contested = contested;
                }
                d
            })
            .collect();
        Ok(VotingFound {
            detections,
            report,
            voting_ms,
            verify_ms: ms(lap.elapsed()),
        })
    }

    /// A later round's hypotheses `more` judged and added to `candidates` (numbered from
    /// `offset`, which moves past them), less those laid on wider surfaces and those the
    /// support explains.
    #[allow(clippy::too_many_arguments)]
    fn later_round(
        &self,
        verifier: &Verifier,
        accept: &ExplainConfig,
        more: &Voted,
        offset: &mut usize,
        candidates: &mut Vec<Candidate>,
        report: &mut VotingReport,
        laid_on_surfaces: &mut usize,
    ) -> Result<()> {
        let (judged, laid) =
            Self::off_surfaces(verifier, self.candidates(verifier, accept, more, *offset)?);
        *laid_on_surfaces += laid;
        let (seen, on_support): (Vec<Candidate>, Vec<Candidate>) =
            judged.into_iter().partition(|c| {
                c.score.support_explained_ratio() <= self.params.verify.max_explained_by_support
            });
        report.rejected_on_support += on_support.len();
        candidates.extend(seen);
        *offset += more.clusters.len();
        Ok(())
    }

    /// Hypotheses that lay the model's flat faces on the flat patches of `rest` of about
    /// their size (`binpick_match::faces`), best agreeing lengths first, at most
    /// `voting.face_hypotheses`.
    fn face_hypotheses(&self, rest: &OrientedPoints) -> Result<Voted> {
        let step = self.scale.sampling_step_mm;
        let regions = FlatRegions {
            connect_mm: FACE_CONNECT_STEPS * step,
            max_angle_deg: FACE_MAX_ANGLE_DEG,
            max_offset_mm: FACE_OFFSET_TOLERANCES * self.scale.tolerance_mm,
            min_points: FACE_MIN_SAMPLES,
        };
        let patches = flat_patches(rest, &regions).map_err(matching("scene faces"))?;
        let clusters: Vec<PoseCluster> = if patches.is_empty() {
            Vec::new()
        } else {
            let sampled = binpick_match::subsample_by_facing(&self.model.dense, step);
            let faces = flat_patches(&sampled, &regions).map_err(matching("model faces"))?;
            let laying = Laying {
                slack_mm: FACE_SLACK_STEPS * step,
                spacing_mm: step,
                min_cover: FACE_MIN_COVER,
                min_fill: FACE_MIN_FILL,
                max_poses: self.params.voting.face_hypotheses,
            };
            laid_poses(&faces, &patches, &laying)
                .into_iter()
                .map(|pose| PoseCluster {
                    pose,
                    votes: 0,
                    members: 0,
                })
                .collect()
        };
        Ok(Voted {
            votes: 0,
            first_rim: clusters.len(),
            clusters,
        })
    }

    /// The hypotheses refined and judged, with the near-symmetric turns of those acceptable
    /// or refused as a turned part would be; `offset` numbers them after the earlier
    /// rounds'.
    fn candidates(
        &self,
        verifier: &Verifier,
        accept: &ExplainConfig,
        voted: &Voted,
        offset: usize,
    ) -> Result<Vec<Candidate>> {
        // Interrupted, the candidates verified so far still compete for the scene (each
        // taken part was verified against the view); the others are dropped. Hypotheses are
        // taken up best voted first, so those verified so far are the likeliest parts.
        let verified = in_order(&voted.clusters, |i, h| {
            // A rim's pose is first aligned on the scene's ribbons alone; refinement and the
            // report start from there.
            let rim = if i >= voted.first_rim {
                verifier.refine_rim(&h.pose)
            } else {
                Ok(None)
            };
            let c = rim.and_then(|rim| {
                let initial = rim.unwrap_or(h.pose);
                self.verify(verifier, accept, offset + i, h.votes, &initial)
            });
            self.deadline.partial(c)
        })?;
        let mut candidates: Vec<Candidate> = verified.into_iter().flatten().collect();
        if !self.params.verify.near_symmetry_variants || self.model.near_symmetries.is_empty() {
            return Ok(candidates);
        }
        let turns = self.model.near_symmetries.len();
        let acceptable: Vec<usize> = (0..candidates.len())
            .filter(|&k| accept.worth_turning(&candidates[k].score))
            .collect();
        let turned: Vec<(usize, Isometry3<f64>)> = acceptable
            .iter()
            .flat_map(|&k| {
                let c = &candidates[k];
                self.model
                    .near_symmetries
                    .iter()
                    .map(move |s| (k, c.pose * s))
            })
            .collect();
        let variants = in_order(&turned, |_, &(k, ref pose)| {
            let c = &candidates[k];
            self.deadline.partial(
                self.verify(verifier, accept, c.hypothesis, c.votes, pose)
                    .map(|v| Candidate { turned: true, ..v }),
            )
        })?;
        // Interrupted, a candidate and its turns compete only when all of them were
        // judged: a turn left alone would win without its rival (a half-turned twin
        // taken because the right pose was dropped). Incomplete families are dropped.
        let mut unjudged = Vec::new();
        let mut families = variants.into_iter();
        for &k in &acceptable {
            let family: Vec<Option<Candidate>> = families.by_ref().take(turns).collect();
            if family.iter().all(Option::is_some) {
                candidates.extend(family.into_iter().flatten());
            } else {
                unjudged.push(k);
            }
        }
        for k in unjudged.into_iter().rev() {
            candidates.remove(k);
        }
        Ok(candidates)
    }

    /// `candidates` less the edge-on poses laid on a wider surface
    /// ([`Verifier::edge_on_a_surface`]), and how many those were: their outline fails in
    /// their own right, whatever other strips beside them explain.
    fn off_surfaces(verifier: &Verifier, candidates: Vec<Candidate>) -> (Vec<Candidate>, usize) {
        let laid: Vec<bool> = candidates
            .par_iter()
            .map(|c| verifier.edge_on_a_surface(&c.pose, &c.score))
            .collect();
        let dropped = laid.iter().filter(|&&l| l).count();
        let kept = candidates
            .into_iter()
            .zip(laid)
            .filter_map(|(c, laid)| (!laid).then_some(c))
            .collect();
        (kept, dropped)
    }

    /// A taken part against its near-symmetric turns that were acceptable but found their
    /// surface explained by it: where the two differ (model points more than
    /// [`TURN_APART_SHARE`] of the turns' gap or of the tolerance apart), the scene is
    /// compared with each, point by point, finer than the view's cells. A turn the scene
    /// confirms much more closely there ([`TURN_CLOSER_SHARE`] of the taken part's residual)
    /// replaces it. The view cannot tell a Z bracket from its turn when the flanges'
    /// difference (5 mm) is within a cell or two of slack. A part seen edge on is judged
    /// from the scan's side ([`Verifier::scan_residuals`]): its turn replaces it when it
    /// explains the scan points either explains that closely. Returns the candidates
    /// replaced.
    fn settle_turns(
        &self,
        verifier: &Verifier,
        candidates: &[Candidate],
        explanation: &mut binpick_match::Explanation,
    ) -> Result<Vec<usize>> {
        let mut replaced = Vec::new();
        if !self.params.verify.near_symmetry_variants || self.model.near_symmetries.is_empty() {
            return Ok(replaced);
        }
        let (near_mm, near_rad) = self.same_pose_tolerances();
        let centre = self.model.centre;
        let edge_on = edge_on_cells(self.scale);
        let turn_of = |i: usize, j: usize| {
            let (a, b) = (&candidates[i].pose, &candidates[j].pose);
            (a * centre - b * centre).norm() < near_mm
                && self
                    .model
                    .near_symmetries
                    .iter()
                    .any(|s| self.part.symmetries.angle(&(a * s), b) < near_rad)
        };
        let rivals: Vec<(usize, Vec<usize>)> = explanation
            .taken
            .iter()
            .enumerate()
            // A scanned part lacks the sides its scanner never saw, the sheet's edge a part
            // seen edge on shows among them: the scan there is neither pose's, and such a
            // part is left as taken (seed 1's `brackets-belt-1mm-006`, the scanned model: a
            // right pose lost to its turn).
            .filter(|&(_, &i)| {
                self.part.source == PartSource::Mesh
                    || f64::from(candidates[i].score.view_cells()) > edge_on
            })
            .map(|(t, &i)| {
                let r = (0..candidates.len())
                    .filter(|&j| {
                        explanation.rejected[j] == Some(Rejection::Explained) && turn_of(i, j)
                    })
                    .collect();
                (t, r)
            })
            .filter(|(_, r): &(usize, Vec<usize>)| !r.is_empty())
            .collect();
        if rivals.is_empty() {
            return Ok(replaced);
        }
        let surface = &self.part.surface;
        let index = binpick_match::GridIndex::new("part surface", &surface.points)
            .map_err(matching("part surface"))?;
        let apart = TURN_APART_SHARE
            * turn_gap_mm(&self.model.near_symmetries, surface, &index)
                .max(self.scale.tolerance_mm);
        tracing::trace!(apart_mm = apart, "turns settled where they differ by more");
        // What the sensor sees of each pose involved, once.
        let mut involved: Vec<usize> = rivals
            .iter()
            .flat_map(|(t, r)| std::iter::once(explanation.taken[*t]).chain(r.iter().copied()))
            .collect();
        involved.sort_unstable();
        involved.dedup();
        let seen: Vec<SeenSurface> = involved
            .par_iter()
            .map(|&k| verifier.seen_surface(surface, &candidates[k].pose))
            .collect();
        let seen_of = |k: usize| -> &SeenSurface {
            // `involved` holds every candidate asked for.
            &seen[involved.binary_search(&k).unwrap_or_default()]
        };
        let choices: Vec<Option<(f64, usize)>> = rivals
            .par_iter()
            .map(|(t, rivals)| {
                let i = explanation.taken[*t];
                let mut best: Option<(f64, usize)> = None;
                // A part seen edge on is a strip whose ends are all outline: its seen points
                // where it and its turn differ are too few or fall beside the scan's edge
                // (`edge_on_min_fit`), so the scan's points there judge it.
                if f64::from(candidates[i].score.view_cells()) <= edge_on {
                    for &j in rivals {
                        let (si, sj, n) = verifier.scan_residuals(
                            (seen_of(i), &candidates[i].pose),
                            (seen_of(j), &candidates[j].pose),
                            &index,
                            apart,
                        );
                        tracing::trace!(taken = i, turn = j, si, sj, n, "edge on, the scan's side");
                        if n >= TURN_MIN_APART_POINTS
                            && sj < TURN_CLOSER_SHARE * si
                            && best.is_none_or(|(b, _)| sj / si < b)
                        {
                            best = Some((sj / si, j));
                        }
                    }
                    return best;
                }
                for &j in rivals {
                    let (ri, ni) = verifier.residual_apart_from(
                        seen_of(i),
                        &index,
                        &candidates[j].pose,
                        apart,
                    );
                    let (rj, nj) = verifier.residual_apart_from(
                        seen_of(j),
                        &index,
                        &candidates[i].pose,
                        apart,
                    );
                    let closer = ni.min(nj) >= TURN_MIN_APART_POINTS && rj < TURN_CLOSER_SHARE * ri;
                    let seen_through = || {
                        let si = verifier.score_apart_from(
                            &index,
                            &candidates[i].pose,
                            &candidates[j].pose,
                            apart,
                        );
                        let sj = verifier.score_apart_from(
                            &index,
                            &candidates[j].pose,
                            &candidates[i].pose,
                            apart,
                        );
                        tracing::trace!(
                            taken = i,
                            turn = j,
                            free_i = si.free_space,
                            visible_i = si.visible,
                            free_j = sj.free_space,
                            "seen through where they differ"
                        );
                        sj.free_space == 0
                            && si.free_space >= TURN_MIN_FREE_CELLS
                            && si.free_space_ratio() >= TURN_SEEN_THROUGH_SHARE
                    };
                    tracing::trace!(taken = i, turn = j, ri, ni, rj, nj, "where they differ");
                    // Rivals rank by residual share; one qualifying by free space alone may
                    // have no judged points on the taken part (ri = 0): last, not NaN.
                    let share = if ri > 0.0 { rj / ri } else { f64::INFINITY };
                    // The renders of `seen_through` only for a rival that would rank first.
                    if best.is_none_or(|(b, _)| share < b) && (closer || seen_through()) {
                        best = Some((share, j));
                    }
                }
                best
            })
            .collect();
        for ((t, _), choice) in rivals.iter().zip(choices) {
            let Some((share, j)) = choice else { continue };
            let i = explanation.taken[*t];
            tracing::debug!(
                taken = i,
                turn = j,
                residual_share = share,
                "a turn fits closer where they differ"
            );
            explanation.taken[*t] = j;
            explanation.rejected[j] = None;
            explanation.rejected[i] = Some(Rejection::Explained);
            replaced.push(i);
        }
        Ok(replaced)
    }

    /// Per part taken, the largest share of the explained cells of a pose of another part
    /// (its centre farther than the pose clustering's tolerance) that fits closer by
    /// [`CONTEST_FIT_MARGIN`] and was refused as a repeat, that the part claims
    /// ([`ViewCheck::contested`](crate::ViewCheck)). A pose laid on another part's surface
    /// can explain more cells than that part's own right pose and so be taken first; it
    /// then fits that surface less closely than the pose it displaced.
    fn contested(
        &self,
        candidates: &[Candidate],
        explanation: &binpick_match::Explanation,
    ) -> Vec<f64> {
        let (near_mm, _) = self.same_pose_tolerances();
        let centre = self.model.centre;
        explanation
            .taken
            .iter()
            .map(|&t| {
                let part = &candidates[t];
                let mut claimed = part.score.explained_cells.clone();
                claimed.sort_unstable();
                let fit = part.score.mean_fit();
                explanation
                    .rejected
                    .iter()
                    .enumerate()
                    .filter(|&(c, why)| {
                        let other = &candidates[c];
                        *why == Some(Rejection::Explained)
                            && (part.pose * centre - other.pose * centre).norm() >= near_mm
                            && other.score.mean_fit() >= fit + CONTEST_FIT_MARGIN
                    })
                    .map(|(c, _)| {
                        let cells = &candidates[c].score.explained_cells;
                        let shared = cells
                            .iter()
                            .filter(|x| claimed.binary_search(x).is_ok())
                            .count();
                        shared as f64 / cells.len().max(1) as f64
                    })
                    .fold(0.0, f64::max)
            })
            .collect()
    }

    /// The scene samples farther than two view tolerances from every taken part's surface.
    fn unexplained(
        &self,
        samples: &OrientedPoints,
        candidates: &[Candidate],
        taken: &[usize],
    ) -> Result<OrientedPoints> {
        let placed: Vec<binpick_match::P3> = taken
            .iter()
            .flat_map(|&k| {
                let pose = candidates[k].pose;
                self.model
                    .dense
                    .points
                    .iter()
                    .map(move |p| binpick_cloud::transform_point(&pose, p))
            })
            .collect();
        if placed.is_empty() {
            return Ok(samples.clone());
        }
        let index = binpick_match::PointIndex::new("taken parts", &placed)
            .map_err(matching("taken parts"))?;
        let far = (UNEXPLAINED_TOLERANCES * self.scale.tolerance_mm).powi(2) as f32; // mm^2
        let keep: Vec<bool> = samples
            .points
            .par_iter()
            .map(|q| index.nearest(q).1 > far)
            .collect();
        let pick = |v: &[binpick_match::P3]| {
            v.iter()
                .zip(&keep)
                .filter_map(|(x, k)| k.then_some(*x))
                .collect()
        };
        Ok(OrientedPoints {
            points: pick(&samples.points),
            normals: pick(&samples.normals),
        })
    }

    /// Refines one pose and judges it against the view.
    fn verify(
        &self,
        verifier: &Verifier,
        accept: &ExplainConfig,
        hypothesis: usize,
        votes: u32,
        initial: &Isometry3<f64>,
    ) -> Result<Candidate> {
        self.deadline.check("verification")?;
        let (pose, icp, score) = self.refine_if_better(verifier, accept, initial)?;
        Ok(Candidate {
            hypothesis,
            votes,
            turned: false,
            initial: *initial,
            score,
            pose,
            icp,
        })
    }

    /// ICP refinement, adopted only when the view supports the refined pose at least as
    /// well as the initial one: among touching parts ICP can slide a right pose onto a
    /// neighbour's surface (measured on a bin of rings: true poses refined from a view fit
    /// of 0.77 down to 0.37-0.54). A pose hopeless at the start (`ExplainConfig::hopeless`)
    /// is probed after a few iterations and stops there when it still is; a refined pose
    /// refused by more than the unhidden pass changes (`ExplainConfig::past_refining`)
    /// skips that pass.
    fn refine_if_better(
        &self,
        verifier: &Verifier,
        accept: &ExplainConfig,
        initial: &Isometry3<f64>,
    ) -> Result<(Isometry3<f64>, IcpReport, ViewScore)> {
        let w = self.params.verify.free_space_weight;
        let before = verifier.score(initial);
        let mut probed: Option<ViewScore> = None;
        let mut probe = |pose: &Isometry3<f64>| {
            let s = verifier.score(pose);
            let worth = !accept.hopeless(&s);
            if !worth {
                probed = Some(s);
            }
            worth
        };
        let (refined, icp) = verifier.refine(
            initial,
            accept
                .hopeless(&before)
                .then_some(&mut probe as &mut Probe<'_>),
        )?;
        // Without an ICP answer the refined pose is the initial one: no second score.
        let Some(out) = icp else {
            return Ok((*initial, icp_report(None, false), before));
        };
        let stopped_hopeless = probed.is_some();
        let after = probed.unwrap_or_else(|| verifier.score(&refined));
        let (pose, report, score) = if after.support(w) < before.support(w) {
            (*initial, icp_report(Some(&out), false), before)
        } else {
            (refined, icp_report(Some(&out), true), after)
        };
        if stopped_hopeless || !self.params.verify.unhidden_pass || accept.past_refining(&score) {
            return Ok((pose, report, score));
        }
        Ok(self
            .refine_unhidden(verifier, &pose, &score)?
            .unwrap_or((pose, report, score)))
    }

    /// The last pass of [`Verifier::refine_unhidden`] from `pose` (scored `score`), when it
    /// fits closer without explaining less.
    fn refine_unhidden(
        &self,
        verifier: &Verifier,
        pose: &Isometry3<f64>,
        score: &ViewScore,
    ) -> Result<Option<(Isometry3<f64>, IcpReport, ViewScore)>> {
        Ok(self
            .closer(verifier, pose, score, false)?
            .map(|(unhidden, out, s)| {
                let report = IcpReport {
                    unhidden: true,
                    ..icp_report(Some(&out), true)
                };
                (unhidden, report, s)
            }))
    }

    /// `c` after the polish pass (`polish_pass`): one fine pass with mutual nearest
    /// neighbours on the surface the scene does not hide, adopted when the part fits closer
    /// without explaining less. Skipped once the time budget is spent.
    fn polished(&self, verifier: &Verifier, c: &Candidate) -> Result<Candidate> {
        if !self.params.verify.polish_pass || self.deadline.check("polish").is_err() {
            return Ok(c.clone());
        }
        let Some((pose, out, score)) = self.closer(verifier, &c.pose, &c.score, true)? else {
            return Ok(c.clone());
        };
        Ok(Candidate {
            pose,
            score,
            icp: IcpReport {
                polished: true,
                unhidden: c.icp.unhidden,
                ..icp_report(Some(&out), true)
            },
            ..c.clone()
        })
    }

    /// One fine pass of [`Verifier::refine_unhidden`] from `pose` (scored `score`), with
    /// only mutual nearest neighbours when `reciprocal`: the pose it reaches, ICP's outcome
    /// and its score, when the part fits closer there without explaining less.
    fn closer(
        &self,
        verifier: &Verifier,
        pose: &Isometry3<f64>,
        score: &ViewScore,
        reciprocal: bool,
    ) -> Result<Option<(Isometry3<f64>, binpick_pcl::IcpOutcome, ViewScore)>> {
        let w = self.params.verify.free_space_weight;
        let Some((moved, out)) = verifier.refine_unhidden(pose, reciprocal)? else {
            return Ok(None);
        };
        let s = verifier.score(&moved);
        let better = s.mean_fit() > score.mean_fit() && s.support(w) >= score.support(w);
        Ok(better.then_some((moved, out, s)))
    }

    /// The pose clustering's tolerances: two poses whose part centres lie closer than the
    /// first (mm) and whose rotations differ by less than the second (radians, up to
    /// symmetry) are one pose.
    fn same_pose_tolerances(&self) -> (f64, f64) {
        let v = &self.params.voting;
        (
            v.cluster_translation_diameters * self.scale.model_diameter_mm,
            v.cluster_rotation_deg.to_radians(),
        )
    }

    /// Whether `a` and `b` are one pose ([`Self::same_pose_tolerances`]).
    fn same_pose(&self, a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        let (near_mm, near_rad) = self.same_pose_tolerances();
        let centre = self.model.centre;
        (a * centre - b * centre).norm() < near_mm && self.part.symmetries.angle(a, b) < near_rad
    }

    /// The greedy scene explanation over `candidates`: a near-tie between different poses
    /// goes to the pose with more votes of its own (a turn has none), one between
    /// hypotheses of one pose (within the pose clustering's tolerances) to the better fit.
    fn explain(
        &self,
        candidates: &[Candidate],
        already_explained: &[bool],
        accept: &ExplainConfig,
    ) -> Result<binpick_match::Explanation> {
        self.explain_without(candidates, already_explained, accept, &[])
    }

    /// [`Self::explain`] with the candidates `excluded` marks left out (refused as repeats).
    fn explain_without(
        &self,
        candidates: &[Candidate],
        already_explained: &[bool],
        accept: &ExplainConfig,
        excluded: &[bool],
    ) -> Result<binpick_match::Explanation> {
        let out = |k: usize| excluded.get(k).copied().unwrap_or(false);
        let scores: Vec<ViewScore> = candidates
            .iter()
            .enumerate()
            .map(|(k, c)| {
                if out(k) {
                    ViewScore::default()
                } else {
                    c.score.clone()
                }
            })
            .collect();
        let votes: Vec<u32> = candidates
            .iter()
            .map(|c| if c.turned { 0 } else { c.votes })
            .collect();
        let same_pose =
            |i: usize, j: usize| self.same_pose(&candidates[i].pose, &candidates[j].pose);
        let mut explanation = explain_scene(&scores, &votes, same_pose, already_explained, accept)
            .map_err(matching("scene explanation"))?;
        for (k, why) in explanation.rejected.iter_mut().enumerate() {
            if out(k) {
                *why = Some(Rejection::Explained);
            }
        }
        Ok(explanation)
    }

    /// `explanation` made again without the parts taken that contest a closer-fitting pose
    /// of another part ([`Self::contested`] at least [`CONTEST_LEAVE_OUT_SHARE`]) and
    /// without every candidate of their poses, while the parts then taken explain the view
    /// as well, less [`CONTEST_FIT_MARGIN`] per cell the left-out parts explained
    /// ([`Self::explained_worth`]); at most [`CONTEST_ROUNDS`] times. A pose laid across two
    /// parts explains more cells than either part's own pose and is taken first, and the
    /// pose it displaced fits the surface they share more closely. The left out are refused
    /// as repeats.
    fn without_contested(
        &self,
        candidates: &[Candidate],
        already_explained: &[bool],
        accept: &ExplainConfig,
        mut explanation: binpick_match::Explanation,
    ) -> Result<binpick_match::Explanation> {
        let mut excluded = vec![false; candidates.len()];
        // Worked out only when a part is contested (most scans have none).
        let mut worth: Option<f64> = None;
        for _ in 0..CONTEST_ROUNDS {
            let mut trial = excluded.clone();
            // Cells of the parts left out: the contest's fit margin over them is what the
            // explanation may lose (the pose displaced fits closer by that much at least).
            let mut left_out_cells = 0u32;
            for (&t, share) in explanation
                .taken
                .iter()
                .zip(self.contested(candidates, &explanation))
            {
                if share >= CONTEST_LEAVE_OUT_SHARE {
                    for (k, other) in candidates.iter().enumerate() {
                        trial[k] |= self.same_pose(&candidates[t].pose, &other.pose);
                    }
                    left_out_cells += candidates[t].score.explained;
                }
            }
            if left_out_cells == 0 {
                break;
            }
            let current =
                *worth.get_or_insert_with(|| self.explained_worth(candidates, &explanation.taken));
            let again = self.explain_without(candidates, already_explained, accept, &trial)?;
            let again_worth = self.explained_worth(candidates, &again.taken);
            tracing::debug!(
                worth = current,
                again_worth,
                left_out_cells,
                "parts contesting closer poses left out"
            );
            if again_worth < current - CONTEST_FIT_MARGIN * f64::from(left_out_cells) {
                break;
            }
            (explanation, excluded) = (again, trial);
            worth = Some(again_worth);
        }
        Ok(explanation)
    }

    /// How well the parts `taken` explain the view together: per view cell the best fit
    /// weight of a part that explains it, summed, less `free_space_weight` per cell a part
    /// is seen through (the scene explanation's gain, over all parts at once).
    fn explained_worth(&self, candidates: &[Candidate], taken: &[usize]) -> f64 {
        let mut best: std::collections::HashMap<u32, f32> = std::collections::HashMap::new();
        let mut free = 0u32;
        for &k in taken {
            let s = &candidates[k].score;
            free += s.free_space;
            for (&c, &fit) in s.explained_cells.iter().zip(&s.explained_fit) {
                let b = best.entry(c).or_insert(0.0);
                *b = b.max(fit);
            }
        }
        let mut fits: Vec<f32> = best.into_values().collect();
        fits.sort_by(f32::total_cmp); // summed in one order whatever the map's
        fits.iter().map(|&f| f64::from(f)).sum::<f64>()
            - self.params.verify.free_space_weight * f64::from(free)
    }

    /// Acceptance and competition settings at this scale.
    fn acceptance(&self, verifier: &Verifier) -> ExplainConfig {
        let v = &self.params.verify;
        ExplainConfig {
            min_visibility: v.min_visibility,
            max_free_space: v.max_free_space,
            max_crossing: v.max_crossing,
            max_below_support: v.max_below_support,
            max_sunk_mm: v.max_sunk_tolerances * verifier.tolerance_mm(),
            // Applied to later rounds only (`detect`).
            max_explained_by_support: 1.0,
            max_continued: v.max_continued,
            min_fit: v.min_fit,
            occluded_min_fit: v.occluded_min_fit,
            occluded_below_visibility: v.occluded_below_visibility,
            min_explained_cells: (v.min_explained_share * verifier.typical_cells())
                .ceil()
                .max(1.0) as u32,
            free_space_weight: v.free_space_weight,
            min_new_share: v.min_new_share,
            closer_cell_margin: v.closer_cell_margin,
            tie_share: v.tie_share,
            // Only a part with rims: its edge must then meet the scene's ribbons where the
            // scene carries on past its outline (`Verifier::edge_on_a_surface`).
            edge_on_cells: if self.model.rims.is_some() {
                edge_on_cells(self.scale)
            } else {
                0.0
            },
            edge_on_min_fit: v.edge_on_min_fit,
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
                Rejection::CrossesPart => r.rejected_crossing += 1,
                Rejection::BelowSupport => r.rejected_below_support += 1,
                Rejection::OnSupport => r.rejected_on_support += 1,
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
            let reason = refusal_reason(why, s);
            RefusedCandidate {
                visibility: s.visibility(),
                free_space: s.free_space_ratio(),
                explained_cells: s.explained,
                reason,
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
            // Decided by the pick order (`rank_by_view`).
            free_to_pick: true,
            grasps: Vec::new(),
        }
    }
}

/// `f` over `items` on the worker threads, which take them up in order (rayon's own split
/// would start the second half at once, verifying weak hypotheses before strong ones when a
/// time budget cuts the work short); results in the items' order, whatever the thread count.
fn in_order<T: Sync, R: Send>(
    items: &[T],
    f: impl Fn(usize, &T) -> Result<R> + Sync,
) -> Result<Vec<R>> {
    let mut done: Vec<(usize, R)> = items
        .iter()
        .enumerate()
        .par_bridge()
        .map(|(i, x)| f(i, x).map(|r| (i, r)))
        .collect::<Result<_>>()?;
    done.sort_unstable_by_key(|(i, _)| *i);
    Ok(done.into_iter().map(|(_, r)| r).collect())
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

/// What the refinement's ICP did, for the detection's report.
fn icp_report(icp: Option<&binpick_pcl::IcpOutcome>, adopted: bool) -> IcpReport {
    IcpReport {
        converged: icp.is_some_and(|o| o.converged),
        iterations: icp.map_or(0, |o| o.iterations),
        fitness_mm2: icp.and_then(|o| IcpReport::usable_fitness(o.fitness)),
        adopted,
        unhidden: false,
        polished: false,
        error: None,
    }
}

/// How far the part's near-symmetric `turns` lie off its `surface` (model frame, indexed by
/// `index`) where they differ most: the largest over the turns of the
/// [`TURN_GAP_PERCENTILE`] of the distances from the turned surface ([`TURN_GAP_POINTS`]
/// of its points) to the surface, mm;
/// `model inspect`'s gap (3.6 mm for the Z bracket, whose flanges differ by 5 mm).
fn turn_gap_mm(
    turns: &[Isometry3<f64>],
    surface: &OrientedPoints,
    index: &binpick_match::GridIndex,
) -> f64 {
    turns
        .iter()
        .map(|s| {
            let mut d: Vec<f32> = binpick_cloud::strided_points(&surface.points, TURN_GAP_POINTS)
                .iter()
                .map(|p| {
                    let q = s * p;
                    index.nearest_squared(&[q.x as f32, q.y as f32, q.z as f32])
                })
                .collect();
            if d.is_empty() {
                return 0.0;
            }
            let k = (TURN_GAP_PERCENTILE * (d.len() - 1) as f64) as usize;
            d.select_nth_unstable_by(k, f32::total_cmp);
            f64::from(d[k]).sqrt()
        })
        .fold(0.0, f64::max)
}

/// Why a candidate was refused, in words, with the parameter to look at (the one line the
/// CLI prints when nothing is found).
fn refusal_reason(why: Rejection, s: &ViewScore) -> String {
    match why {
        Rejection::TooLittleSurface => "too little confirmed surface (min_explained_share)".into(),
        Rejection::LowVisibility => {
            "too little of its visible surface confirmed (min_visibility)".into()
        }
        // The rule reads free space per confirmed cell; `RefusedCandidate::free_space` is
        // a share of the whole visible surface, as in every view check.
        Rejection::FreeSpace => format!(
            "the sensor saw through {:.1} cells per 100 it confirms (max_free_space)",
            100.0 * s.free_space_per_explained()
        ),
        Rejection::CrossesPart => format!(
            "it passes through a part the sensor saw: {} cells seen through beside that \
             part's surface, {:.1} per 1000 it confirms (max_crossing)",
            s.crossing,
            1000.0 * s.crossing_per_explained()
        ),
        Rejection::BelowSupport => {
            "it sinks into the belt, floor or a wall (max_below_support, max_sunk_tolerances)"
                .into()
        }
        Rejection::OnSupport => {
            "the belt, floor or a wall confirms most of it (max_explained_by_support)".into()
        }
        Rejection::NoOutline => {
            "the scene's surface carries on past its outline (max_continued)".into()
        }
        Rejection::PoorFit => "the scene lies too far from the model (min_fit)".into(),
        Rejection::Explained => "repeats a taken part (min_new_share, min_explained_share)".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refusal_for_free_space_gives_the_figure_the_rule_reads() {
        // Half hidden: 4 cells seen through of 200 visible is 2 % of the view, but 4 per 100
        // of the 100 the scene confirms, which is what `max_free_space` limits.
        let s = ViewScore {
            visible: 200,
            explained: 100,
            free_space: 4,
            ..ViewScore::default()
        };
        assert_eq!(s.free_space_ratio(), 0.02);
        assert_eq!(
            refusal_reason(Rejection::FreeSpace, &s),
            "the sensor saw through 4.0 cells per 100 it confirms (max_free_space)"
        );
        assert!(refusal_reason(Rejection::BelowSupport, &s).contains("max_sunk_tolerances"));
    }

    #[test]
    fn a_refusal_for_crossing_a_part_gives_its_cells_and_the_share_the_rule_reads() {
        let s = ViewScore {
            visible: 1000,
            explained: 800,
            free_space: 6,
            crossing: 4,
            ..ViewScore::default()
        };
        assert_eq!(
            refusal_reason(Rejection::CrossesPart, &s),
            "it passes through a part the sensor saw: 4 cells seen through beside that \
             part's surface, 5.0 per 1000 it confirms (max_crossing)"
        );
    }
}
