//! Scene explanation: verified hypotheses compete for the scene surface they explain. The
//! one that newly explains the most surface, weighted by how well it fits (less a penalty
//! for its free-space contradictions), is taken first; a hypothesis whose surface is mostly explained already is
//! the same part again (or a worse pose of it) and is dropped. A greedy take on the global
//! hypotheses verification of Aldoma et al. 2012: every part is reported once, and together
//! the taken poses explain the pile.

use crate::MatchError;
use crate::view::ViewScore;

/// Two parts touching side by side share no surface; two poses laid across one larger
/// surface usually do. Share of the smaller's explained cells (ICP leaves a cell of slack
/// along the seam).
const PAIR_MAX_OVERLAP: f64 = 0.1;
/// ... and neither may be covered by more than this share of its visible surface.
const PAIR_MAX_COVERED: f64 = 0.02;
/// A score under this share of what acceptance asks is hopeless ([`ExplainConfig::hopeless`]).
/// Measured on the generalisation benchmark after 5 refining iterations, the parts taken
/// in the end scored at least 0.67 of the visibility and 1.4 times the cells asked.
pub const HOPELESS_SHARE: f64 = 0.5;
/// A pose refused for free space has its turns tried while the sensor saw through at most
/// this share of it ([`ExplainConfig::worth_turning`]; beyond, it lies over clutter and its
/// turns there are false detections: any share tried added 1.3 per scan on the plates belt
/// set of seed 1). A share of its own, not a multiple of `max_free_space`: a part voted the
/// wrong way round sees through about 6 % of itself (one of the touching pair of the
/// pipeline tests, whose right pose is its turn), whatever the limit for accepting a pose.
pub const TURN_MAX_FREE_SPACE: f64 = 0.10;
/// A refined pose refused for free space is past the last fine ICP pass
/// ([`ExplainConfig::past_refining`]) when it sees through more than this many times
/// `max_free_space` per confirmed cell (seeds 1-4 of the generalisation benchmark: of 4 214
/// such poses, the pass made 9 acceptable, all repeats; beyond 3.3 times, 23, 3 of them
/// taken) ...
pub const PAST_REFINING_FREE_SPACE: f64 = 5.0;
/// ... and through more than this many times [`TURN_MAX_FREE_SPACE`] of its view: the pass
/// can bring a pose within the share whose turns are tried, and a plate voted the wrong way
/// round (seen through at 0.12-0.14 before the pass, 0.08-0.10 after) was found only so.
pub const PAST_REFINING_FREE_SPACE_TURNS: f64 = 2.0;
/// A pose is refused for crossing a part ([`Rejection::CrossesPart`]) only with at least
/// this many crossing cells: one or two are a pose error at an edge beside a neighbour.
pub const MIN_CROSSING_CELLS: u32 = 3;

/// Acceptance of one hypothesis and the competition between them.
#[derive(Clone, Debug, PartialEq)]
pub struct ExplainConfig {
    /// Smallest share of its visible surface the scene must confirm. Range 0-1.
    pub min_visibility: f64,
    /// Most free-space cells per explained cell: what the sensor saw through against what
    /// the scene confirms (a part half hidden may see through half as much of its view).
    /// Range 0-1.
    pub max_free_space: f64,
    /// Most crossing cells ([`ViewScore::crossing`]: seen through beside a part's surface
    /// that hides the pose) per explained cell, once there are [`MIN_CROSSING_CELLS`]: a
    /// pose passing through a part the sensor saw. Range 0-1 (1 = off).
    pub max_crossing: f64,
    /// Largest share of its outline the scene's surface may carry on past where no taken
    /// part explains that surface (checked in the competition: a neighbouring part taken
    /// first accounts for the surface beside it). Range 0-1 (1 = off).
    pub max_continued: f64,
    /// Smallest mean fit weight of the confirmed surface (`ViewScore::fit` / `explained`):
    /// the scene must lie close to the model, not just within the tolerance. Range 0-1.
    pub min_fit: f64,
    /// The mean fit asked of a part seen at `min_visibility`; from `occluded_below_visibility`
    /// down to `min_visibility` the fit asked rises linearly from `min_fit` to this. Range
    /// 0-1 (at or below `min_fit` = off).
    pub occluded_min_fit: f64,
    /// See `occluded_min_fit`. Range 0-1.
    pub occluded_below_visibility: f64,
    /// A pose showing at most this many view cells, in and beyond the scan, is seen edge on
    /// (0 = none is). Range >= 0.
    pub edge_on_cells: f64,
    /// The mean fit asked of a pose seen edge on, in place of `fit_needed`'s: a sheet's edge
    /// is a strip a few cells wide, all outline, where the scan's edge falls beside the
    /// model's as often as on it. Range 0-1.
    pub edge_on_min_fit: f64,
    /// Fewest confirmed grid cells (the part must be seen, not guessed), and fewest a
    /// hypothesis must keep that no part taken before it claims (a support plane's cells
    /// are its own surface seen). Range >= 1.
    pub min_explained_cells: u32,
    /// Largest share of the model's surface that may lie behind a support plane that can
    /// carry a part (the part sunk into the belt, floor or a wall). Range 0-1.
    pub max_below_support: f64,
    /// Deepest any point of the part may lie behind a support plane, mm. Range >= 0
    /// (infinite: off).
    pub max_sunk_mm: f64,
    /// Largest share of its confirmed cells that the support (belt, floor, wall) may confirm:
    /// a part is seen by its own surface. Range 0-1.
    pub max_explained_by_support: f64,
    /// Each free-space cell costs this many explained cells in the competition. Range
    /// 0-100.
    pub free_space_weight: f64,
    /// A hypothesis must explain at least this share of its confirmed cells that no taken
    /// part explains yet (or explains less closely, `closer_cell_margin`). Range 0-1.
    pub min_new_share: f64,
    /// A cell a taken part explains is still new to a later hypothesis whose fit weight
    /// there is higher by more than this: the scan lies closer to it. A part lying flat on
    /// another's flange is a sheet's thickness above it, within the tolerance, so the pose
    /// beneath explains its cells too and, taken first, made it a repeat. Range 0-1 (1 =
    /// off: a fit weight is at most 1).
    pub closer_cell_margin: f64,
    /// Gains within this share of the best are a tie. Between different poses it is won by
    /// the one with the most votes of its own (the view cannot tell a near-symmetric part
    /// from its turn when the feature that differs is hidden, the votes over the whole part
    /// can); between hypotheses of one pose by the better gain. Range 0-1 (0 = the best
    /// gain wins).
    pub tie_share: f64,
}

impl ExplainConfig {
    /// Rejects values outside the documented ranges, naming the field.
    pub fn validate(&self) -> Result<(), MatchError> {
        let unit = |v: f64| (0.0..=1.0).contains(&v);
        for (name, share) in [
            ("min_visibility", self.min_visibility),
            ("max_free_space", self.max_free_space),
            ("max_crossing", self.max_crossing),
            ("min_fit", self.min_fit),
            ("occluded_min_fit", self.occluded_min_fit),
            ("occluded_below_visibility", self.occluded_below_visibility),
            ("edge_on_min_fit", self.edge_on_min_fit),
            ("max_explained_by_support", self.max_explained_by_support),
            ("max_below_support", self.max_below_support),
            ("max_continued", self.max_continued),
            ("min_new_share", self.min_new_share),
            ("closer_cell_margin", self.closer_cell_margin),
            ("tie_share", self.tie_share),
        ] {
            if !unit(share) {
                return Err(MatchError::config(name, "expected 0-1"));
            }
        }
        if self.max_sunk_mm.is_nan() || self.max_sunk_mm < 0.0 {
            return Err(MatchError::config(
                "max_sunk_mm",
                "expected >= 0 (infinite: off)",
            ));
        }
        if !(self.edge_on_cells.is_finite() && self.edge_on_cells >= 0.0) {
            return Err(MatchError::config("edge_on_cells", "expected >= 0"));
        }
        if self.min_explained_cells == 0 {
            return Err(MatchError::config("min_explained_cells", "expected >= 1"));
        }
        if !(0.0..=100.0).contains(&self.free_space_weight) {
            return Err(MatchError::config("free_space_weight", "expected 0-100"));
        }
        Ok(())
    }

    /// Whether `s` is far below acceptance: under [`HOPELESS_SHARE`] of the confirmed cells
    /// or of the visibility asked for. Refinement moves a pose by a few tolerances; it does
    /// not double what the scene confirms of it.
    pub fn hopeless(&self, s: &ViewScore) -> bool {
        f64::from(s.explained) < HOPELESS_SHARE * f64::from(self.min_explained_cells)
            || s.visibility() < HOPELESS_SHARE * self.min_visibility
    }

    /// Whether `s`, the score of a pose already refined, is refused by more than a last fine
    /// ICP pass changes: the scene confirms too little of it (of the 8 687 poses so refused
    /// after the two refining passes on seeds 1-4 of the generalisation benchmark, that pass
    /// made one acceptable, a repeat), or it sees through far more than acceptance allows
    /// and than turns are tried for ([`PAST_REFINING_FREE_SPACE`],
    /// [`PAST_REFINING_FREE_SPACE_TURNS`]).
    pub fn past_refining(&self, s: &ViewScore) -> bool {
        match self.rejection(s) {
            Some(Rejection::TooLittleSurface | Rejection::LowVisibility) => true,
            Some(Rejection::FreeSpace) => {
                s.free_space_per_explained() > PAST_REFINING_FREE_SPACE * self.max_free_space
                    && s.free_space_ratio() > PAST_REFINING_FREE_SPACE_TURNS * TURN_MAX_FREE_SPACE
            }
            _ => false,
        }
    }

    /// The mean fit asked of a part that shows `visibility` of its visible surface: `min_fit`,
    /// rising towards `occluded_min_fit` as less of the part is seen. With half a part
    /// hidden, a wrong pose laid across a neighbour's surface confirms as much of itself as
    /// a right one; only a close fit tells them apart.
    pub fn fit_needed(&self, visibility: f64) -> f64 {
        let span = self.occluded_below_visibility - self.min_visibility;
        if span <= 0.0 || visibility >= self.occluded_below_visibility {
            return self.min_fit;
        }
        let hidden = ((self.occluded_below_visibility - visibility) / span).min(1.0);
        self.min_fit + (self.occluded_min_fit - self.min_fit).max(0.0) * hidden
    }

    /// The mean fit asked of `s`: `edge_on_min_fit` when it shows an edge
    /// (`edge_on_cells`, counted in and beyond the scan: [`ViewScore::view_cells`]), else
    /// [`Self::fit_needed`] at its visibility.
    pub fn fit_needed_by(&self, s: &ViewScore) -> f64 {
        if f64::from(s.view_cells()) <= self.edge_on_cells {
            self.edge_on_min_fit
        } else {
            self.fit_needed(s.visibility())
        }
    }

    /// Whether the near-symmetric turns of a pose scored `s` are worth trying: it is
    /// acceptable, or refused as a part voted the wrong way round would be, where its turns
    /// differ: the scene lies beside that flange (a poor fit) or the sensor saw through it
    /// (free space or a crossing, while it sees through at most [`TURN_MAX_FREE_SPACE`]).
    pub fn worth_turning(&self, s: &ViewScore) -> bool {
        match self.rejection(s) {
            None | Some(Rejection::PoorFit) => true,
            Some(Rejection::FreeSpace | Rejection::CrossesPart) => {
                s.free_space_ratio() <= TURN_MAX_FREE_SPACE
            }
            Some(_) => false,
        }
    }

    /// Why `s` cannot be accepted on its own, or None when it can.
    pub fn rejection(&self, s: &ViewScore) -> Option<Rejection> {
        if s.explained < self.min_explained_cells {
            Some(Rejection::TooLittleSurface)
        } else if s.visibility() < self.min_visibility {
            Some(Rejection::LowVisibility)
        } else if s.free_space_per_explained() > self.max_free_space {
            Some(Rejection::FreeSpace)
        } else if s.crossing >= MIN_CROSSING_CELLS && s.crossing_per_explained() > self.max_crossing
        {
            Some(Rejection::CrossesPart)
        } else if s.sunk_mm > self.max_sunk_mm || s.below_support_ratio() > self.max_below_support {
            Some(Rejection::BelowSupport)
        } else if s.support_explained_ratio() > self.max_explained_by_support {
            Some(Rejection::OnSupport)
        } else if s.mean_acceptance_fit() < self.fit_needed_by(s) {
            Some(Rejection::PoorFit)
        } else {
            None
        }
    }
}

/// Why a hypothesis was not taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    /// Fewer confirmed cells than `min_explained_cells`.
    TooLittleSurface,
    /// Visibility below `min_visibility`.
    LowVisibility,
    /// More free-space contradictions per explained cell than `max_free_space`.
    FreeSpace,
    /// More crossing cells per explained cell than `max_crossing`: it passes through a
    /// part the sensor saw.
    CrossesPart,
    /// More than `max_below_support` of the part, or its deepest point by more than
    /// `max_sunk_mm`, lies behind a support plane.
    BelowSupport,
    /// More than `max_explained_by_support` of its confirmed surface is support.
    OnSupport,
    /// The scene's surface carries on past more than `max_continued` of its outline where
    /// no taken part explains it.
    NoOutline,
    /// The confirmed surface fits worse than `min_fit`.
    PoorFit,
    /// Its surface is already explained: less than `min_new_share` of it is new (a support
    /// plane's cells are not), or parts taken before it leave it fewer than
    /// `min_explained_cells` of its own.
    Explained,
}

/// What happened to each hypothesis.
#[derive(Clone, Debug, PartialEq)]
pub struct Explanation {
    /// Taken hypotheses (indices into the input), in the order they were taken.
    pub taken: Vec<usize>,
    /// Per input hypothesis: None if taken, else why not.
    pub rejected: Vec<Option<Rejection>>,
}

/// Greedy scene explanation over `scores` (one per hypothesis) on a view grid whose cells
/// `already_explained` marks as explained before any part is taken (the belt, floor or wall
/// the support planes explain: a pose laid half on the floor gains nothing from the floor).
/// `votes[i]` are the votes hypothesis i got for its own pose (0 for a pose nobody voted
/// for, such as a near-symmetric turn), and `same_pose(i, j)` says hypotheses i and j are
/// one pose (within the pose clustering's tolerances): in a near-tie (`tie_share`) the votes
/// choose between different poses, the gain between hypotheses of one pose. A hypothesis
/// whose outline the scene carries on past waits for a part that explains that surface; when
/// all wait, one of two uncovered twins explaining each other's outline is taken (see
/// `unblock`). Deterministic: remaining ties go to the lower index.
pub fn explain_scene(
    scores: &[ViewScore],
    votes: &[u32],
    same_pose: impl Fn(usize, usize) -> bool,
    already_explained: &[bool],
    config: &ExplainConfig,
) -> Result<Explanation, MatchError> {
    config.validate()?;
    if votes.len() != scores.len() {
        return Err(MatchError::Count {
            what: "hypothesis votes",
            expected: scores.len(),
            got: votes.len(),
        });
    }
    let mut rejected: Vec<Option<Rejection>> = scores.iter().map(|s| config.rejection(s)).collect();
    let mut open: Vec<usize> = (0..scores.len())
        .filter(|&i| rejected[i].is_none())
        .collect();
    let mut claimed = already_explained.to_vec();
    // Claimed by a part taken (not by a support plane alone).
    let mut claimed_by_parts = vec![false; claimed.len()];
    // Per cell, the best fit weight of the parts taken that claim it.
    let mut claimed_fit = vec![0.0f32; claimed.len()];
    let margin = config.closer_cell_margin as f32;
    let mut taken = Vec::new();
    loop {
        let mut gains: Vec<(f64, usize)> = Vec::with_capacity(open.len());
        // Kept waiting by their outline: (gain, index, unexplained continuation).
        let mut waiting: Vec<(f64, usize, usize)> = Vec::new();
        let mut still_open = Vec::with_capacity(open.len());
        for &i in &open {
            let s = &scores[i];
            // Newly explained cells, and their summed fit weights; and the cells no part
            // taken claims (a support plane's cells are still the part's own surface seen).
            let (mut new, mut new_fit, mut own) = (0usize, 0.0f64, 0usize);
            for (&c, &fit) in s.explained_cells.iter().zip(&s.explained_fit) {
                let c = c as usize;
                // A taken part's cell the scan fits much closer to this hypothesis.
                let closer = claimed_by_parts.get(c).copied().unwrap_or(false)
                    && fit > claimed_fit[c] + margin;
                if closer || !claimed.get(c).copied().unwrap_or(true) {
                    new += 1;
                    new_fit += f64::from(fit);
                }
                own += usize::from(closer || !claimed_by_parts.get(c).copied().unwrap_or(true));
            }
            let new = new as f64;
            if new < config.min_new_share * f64::from(s.explained)
                || (own as f64) < f64::from(config.min_explained_cells)
            {
                rejected[i] = Some(Rejection::Explained);
                continue;
            }
            still_open.push(i);
            // Well-fitting surface counts more than surface at the edge of the tolerance.
            let gain = new_fit - config.free_space_weight * f64::from(s.free_space);
            // Scene surface carrying on past its outline that no taken part explains: a
            // pose laid inside a larger surface. It may yet be explained by a part taken
            // later, so the hypothesis waits.
            let unexplained_continuation = s
                .continued_cells
                .iter()
                .filter(|&&c| !claimed.get(c as usize).copied().unwrap_or(false))
                .count();
            if unexplained_continuation as f64 > config.max_continued * f64::from(s.outline_edges) {
                waiting.push((gain, i, unexplained_continuation));
                continue;
            }
            gains.push((gain, i));
        }
        open = still_open;
        let i = match choose(&gains, votes, &same_pose, config.tie_share) {
            Some(i) => i,
            // Parts that touch at one height carry on each other's outline, so each waits
            // for the other; one whose outline the others waiting explain breaks the wait.
            None => match unblock(scores, &waiting, &claimed, config.max_continued) {
                Some(i) => i,
                None => break,
            },
        };
        for (&c, &fit) in scores[i]
            .explained_cells
            .iter()
            .zip(&scores[i].explained_fit)
        {
            if let Some(slot) = claimed.get_mut(c as usize) {
                *slot = true;
                claimed_by_parts[c as usize] = true;
                claimed_fit[c as usize] = claimed_fit[c as usize].max(fit);
            }
        }
        rejected[i] = None;
        taken.push(i);
        open.retain(|&j| j != i);
    }
    // Those still open were only ever kept waiting by their outline.
    for &i in &open {
        rejected[i].get_or_insert(Rejection::NoOutline);
    }
    Ok(Explanation { taken, rejected })
}

/// The hypothesis to take among `gains` ((gain, index), none waiting): the best gain, or in
/// a near-tie (`tie_share`) the pose with more votes of its own (see [`explain_scene`]).
fn choose(
    gains: &[(f64, usize)],
    votes: &[u32],
    same_pose: &impl Fn(usize, usize) -> bool,
    tie_share: f64,
) -> Option<usize> {
    // Best gain first, then the lower index.
    let better = |a: &(f64, usize), b: &(f64, usize)| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1));
    let &(top, best) = gains.iter().max_by(|a, b| better(a, b))?;
    let tied: Vec<&(f64, usize)> = gains
        .iter()
        .filter(|(g, _)| *g >= top - tie_share * top.abs())
        .collect();
    let voted = tied
        .iter()
        .max_by(|a, b| votes[a.1].cmp(&votes[b.1]).then(better(a, b)))
        .map_or(best, |t| t.1);
    Some(if votes[voted] > votes[best] && !same_pose(voted, best) {
        tied.iter()
            .filter(|t| t.1 == voted || same_pose(t.1, voted))
            .max_by(|a, b| better(a, b))
            .map_or(voted, |t| t.1)
    } else {
        best
    })
}

/// When every open hypothesis waits for its outline ((gain, index, continuation no taken
/// part explains) in `waiting`): one of a pair of waiting hypotheses whose outlines the
/// other explains (all but `max_continued` of each), that share almost none of their
/// surface (`PAIR_MAX_OVERLAP`) and that nothing covers (`PAIR_MAX_COVERED`): two parts
/// touching at one height, each carrying on the other's outline. Of those, the one with the
/// least continuation no taken part explains, then the best gain. Poses laid on a larger
/// surface do not pair up: the surface carries on past the outline of both, they overlap,
/// or (a box top under other things) the cover cuts their outline.
fn unblock(
    scores: &[ViewScore],
    waiting: &[(f64, usize, usize)],
    claimed: &[bool],
    max_continued: f64,
) -> Option<usize> {
    // Whether `b` explains all but `max_continued` of the continuation of `a`.
    let explains_outline = |a: usize, b: usize| {
        let (sa, sb) = (&scores[a], &scores[b]);
        let residual = sa
            .continued_cells
            .iter()
            .filter(|&&c| {
                !claimed.get(c as usize).copied().unwrap_or(false)
                    && sb.explained_cells.binary_search(&c).is_err()
            })
            .count();
        residual as f64 <= max_continued * f64::from(sa.outline_edges)
    };
    // Nothing lies on it: a pose laid across a partly covered surface (a box top under other
    // things) has its outline cut by the cover, where twins side by side on a belt do not.
    let uncovered = |a: usize| scores[a].covered_ratio() <= PAIR_MAX_COVERED;
    // Whether `a` and `b` share at most `PAIR_MAX_OVERLAP` of the smaller's cells.
    let apart = |a: usize, b: usize| {
        let (sa, sb) = (&scores[a], &scores[b]);
        let shared = sa
            .explained_cells
            .iter()
            .filter(|c| sb.explained_cells.binary_search(c).is_ok())
            .count();
        shared as f64 <= PAIR_MAX_OVERLAP * f64::from(sa.explained.min(sb.explained))
    };
    waiting
        .iter()
        .filter(|&&(_, a, _)| {
            waiting.iter().any(|&(_, b, _)| {
                b != a
                    && uncovered(a)
                    && uncovered(b)
                    && explains_outline(a, b)
                    && explains_outline(b, a)
                    && apart(a, b)
            })
        })
        .min_by(|x, y| {
            let share =
                |w: &(f64, usize, usize)| w.2 as f64 / f64::from(scores[w.1].outline_edges.max(1));
            share(x)
                .total_cmp(&share(y))
                .then(y.0.total_cmp(&x.0))
                .then(x.1.cmp(&y.1))
        })
        .map(|w| w.1)
}

#[cfg(test)]
mod tests {
    use nalgebra::Isometry3;

    use super::*;
    use crate::view::{RangeGrid, ViewConfig};
    use crate::{OrientedPoints, P3};

    /// A flat square of `side` mm at height `z`, sampled every `step` mm, normals up.
    fn square(x0: f32, y0: f32, side: f32, z: f32, step: f32) -> Vec<P3> {
        let n = (side / step) as usize;
        (0..n)
            .flat_map(|i| (0..n).map(move |j| [x0 + i as f32 * step, y0 + j as f32 * step, z]))
            .collect()
    }

    fn square_parts() -> ExplainConfig {
        ExplainConfig {
            min_visibility: 0.5,
            max_free_space: 0.1,
            max_crossing: 1.0,
            max_continued: 0.2,
            min_fit: 0.5,
            occluded_min_fit: 0.5,
            occluded_below_visibility: 0.5,
            min_explained_cells: 10,
            max_below_support: 1.0,
            max_sunk_mm: f64::INFINITY,
            max_explained_by_support: 1.0,
            free_space_weight: 2.0,
            min_new_share: 0.5,
            closer_cell_margin: 1.0,
            tie_share: 0.0,
            edge_on_cells: 0.0,
            edge_on_min_fit: 0.5,
        }
    }

    /// The scene explanation of `scores` on `grid` with the square parts' settings, no votes
    /// and no two hypotheses of one pose.
    fn unvoted_squares(scores: &[ViewScore], grid: &RangeGrid) -> Explanation {
        let votes = vec![0; scores.len()];
        explain_scene(
            scores,
            &votes,
            |_, _| false,
            &vec![false; grid.cells()],
            &square_parts(),
        )
        .unwrap()
    }

    /// A scanner above a belt (background, 200 mm square at z = 0) carrying `objects`
    /// (upward normals), its view grid at 1 mm cells, and the part: a 20 mm square modelled
    /// about its corner.
    fn tiles_on_a_belt(
        objects: impl IntoIterator<Item = [f32; 3]>,
    ) -> (RangeGrid, ViewConfig, OrientedPoints) {
        let belt = square(-50.0, -50.0, 200.0, 0.0, 1.0);
        let mut background = vec![true; belt.len()];
        let mut points = belt;
        for p in objects {
            points.push(p);
            background.push(false);
        }
        let up = [0.0f32, 0.0, 1.0];
        let (grid, view) = crate::view::tests::top_view_grid(&points, &background);
        let part_points = square(0.0, 0.0, 20.0, 0.0, 1.0);
        let part = OrientedPoints {
            normals: vec![up; part_points.len()],
            points: part_points,
        };
        (grid, view, part)
    }

    #[test]
    fn a_pose_inside_a_larger_surface_waits_for_a_part_that_explains_it() {
        // Scene: a belt (background) at z = 0 carrying a 60 mm square box top at z = 10 and,
        // beside it, a 20 mm square tile at z = 10 that stands alone.
        let box_top = square(0.0, 0.0, 60.0, 10.0, 1.0);
        let tile = square(80.0, 0.0, 20.0, 10.0, 1.0);
        let (grid, view, part) = tiles_on_a_belt(box_top.into_iter().chain(tile));
        let at = |x: f64, y: f64| Isometry3::translation(x, y, 10.0);
        let on_tile = grid.score(&part, &at(80.0, 0.0), &view);
        let inside_box = grid.score(&part, &at(20.0, 20.0), &view);
        assert!(on_tile.visibility() > 0.9 && inside_box.visibility() > 0.9);
        assert!(
            on_tile.continued_ratio() < 0.05,
            "the tile's outline is a depth edge: {}",
            on_tile.continued_ratio()
        );
        assert!(
            inside_box.continued_ratio() > 0.9,
            "the box top carries on past a square laid inside it: {}",
            inside_box.continued_ratio()
        );
        let alone = unvoted_squares(&[on_tile.clone(), inside_box.clone()], &grid);
        assert_eq!(alone.taken, vec![0]);
        assert_eq!(alone.rejected[1], Some(Rejection::NoOutline));
        // A box (60 mm part) taken first explains the surface around the square: the square
        // is then a repeat of it, not a part refused for its outline.
        let box_part = square(0.0, 0.0, 60.0, 0.0, 1.0);
        let box_model = OrientedPoints {
            normals: vec![[0.0, 0.0, 1.0]; box_part.len()],
            points: box_part,
        };
        let the_box = grid.score(&box_model, &at(0.0, 0.0), &view);
        let with_box = unvoted_squares(&[on_tile, inside_box, the_box], &grid);
        assert_eq!(with_box.taken, vec![2, 0]);
        assert_eq!(with_box.rejected[1], Some(Rejection::Explained));
    }

    #[test]
    fn a_pose_inside_a_larger_surface_is_judged_on_the_outline_it_shows() {
        // A 60 mm box top at z = 10; a cover at z = 20 hides its rows y >= 25. The square
        // laid at (20, 20) shows its rows y 20-24 inside the box top and hides the rest.
        let box_top = square(0.0, 0.0, 60.0, 10.0, 1.0);
        let cover: Vec<P3> = square(0.0, 25.0, 60.0, 20.0, 1.0)
            .into_iter()
            .filter(|p| p[1] < 60.0)
            .collect();
        let (grid, view, part) = tiles_on_a_belt(box_top.into_iter().chain(cover));
        let half_hidden = grid.score(&part, &Isometry3::translation(20.0, 20.0, 10.0), &view);
        // Row y 25 is confirmed by the box top beside it (a cell of lateral slack).
        assert_eq!(half_hidden.occluded, 280, "rows y 26-39 are hidden");
        // Shown: the bottom side (20 edges) and six rows of each flank, all inside the box
        // top. The 48 edges of the hidden outline cannot show a depth edge and do not count.
        assert_eq!(half_hidden.outline_edges, 32);
        assert!(
            half_hidden.continued_ratio() > 0.9,
            "the box top carries on past all the outline shown: {}",
            half_hidden.continued_ratio()
        );
        let alone = unvoted_squares(&[half_hidden], &grid);
        assert!(alone.taken.is_empty());
    }

    /// A score explaining grid cells `cells` at fit `fit` each, of `visible` visible cells.
    fn explaining(cells: std::ops::Range<u32>, fit: f32, visible: u32) -> ViewScore {
        let explained_cells: Vec<u32> = cells.collect();
        ViewScore {
            visible,
            explained: explained_cells.len() as u32,
            fit: f64::from(fit) * explained_cells.len() as f64,
            acceptance_fit: f64::from(fit) * explained_cells.len() as f64,
            explained_fit: vec![fit; explained_cells.len()],
            explained_cells,
            ..ViewScore::default()
        }
    }

    #[test]
    fn a_part_lying_on_another_keeps_the_cells_it_fits_much_closer() {
        // The pose beneath (0) confirms cells 0-99: 0-59 its own at fit 1, 60-99 those of a
        // part lying on it a sheet's thickness higher, at fit 0.5. That part (1) confirms
        // 60-129 at fit 1. Gains 80 and 70: the pose beneath is taken first.
        let mut beneath = explaining(0..100, 1.0, 100);
        for f in &mut beneath.explained_fit[60..] {
            *f = 0.5;
        }
        beneath.fit = 80.0;
        let on_top = explaining(60..130, 1.0, 70);
        // A repeat of the pose beneath, fitting less closely everywhere (gain 75).
        let repeat = explaining(0..100, 0.75, 100);
        let scores = [beneath, on_top, repeat];
        let run = |margin: f64| {
            let config = ExplainConfig {
                closer_cell_margin: margin,
                ..square_parts()
            };
            explain_scene(&scores, &[0; 3], |_, _| false, &[false; 200], &config).unwrap()
        };
        // Without the per-cell competition the part on top keeps 30 of its 70 cells.
        let off = run(1.0);
        assert_eq!(off.taken, vec![0]);
        assert_eq!(off.rejected[1], Some(Rejection::Explained));
        // With it, the 40 cells it fits closer by more than the margin are its own again;
        // the repeat wins back the 40 of the pose beneath it fits closer, 40 % of its
        // surface, and stays a repeat.
        let on = run(0.2);
        assert_eq!(on.taken, vec![0, 1]);
        assert_eq!(on.rejected[2], Some(Rejection::Explained));
        assert!(
            ExplainConfig {
                closer_cell_margin: 1.5,
                ..square_parts()
            }
            .validate()
            .is_err()
        );
    }

    #[test]
    fn a_pose_seen_edge_on_is_asked_the_edge_on_fit() {
        let config = ExplainConfig {
            min_fit: 0.7,
            occluded_min_fit: 0.7,
            edge_on_cells: 60.0,
            edge_on_min_fit: 0.6,
            ..square_parts()
        };
        // All confirmed at fit 0.65: enough for an edge (60 view cells or fewer), not for a
        // pose seen broadly.
        let edge = explaining(0..50, 0.65, 50);
        let broad = explaining(0..70, 0.65, 70);
        assert_eq!(config.rejection(&edge), None);
        assert_eq!(config.rejection(&broad), Some(Rejection::PoorFit));
        let looser = explaining(0..50, 0.55, 50);
        assert_eq!(config.rejection(&looser), Some(Rejection::PoorFit));
        // A broad side cut to 50 cells by the edge of the scan is no edge.
        let cut = ViewScore {
            outside: 20,
            ..edge.clone()
        };
        assert_eq!(cut.view_cells(), 70);
        assert_eq!(config.rejection(&cut), Some(Rejection::PoorFit));
        // Off (no pose is an edge): the edge is asked `min_fit`.
        let off = ExplainConfig {
            edge_on_cells: 0.0,
            ..config.clone()
        };
        assert_eq!(off.rejection(&edge), Some(Rejection::PoorFit));
        assert!(
            ExplainConfig {
                edge_on_cells: f64::NAN,
                ..config
            }
            .validate()
            .is_err()
        );
    }

    #[test]
    fn a_part_sunk_into_its_support_is_refused_by_its_deepest_point_or_its_share() {
        let config = ExplainConfig {
            max_below_support: 0.05,
            max_sunk_mm: 3.0,
            ..square_parts()
        };
        let seen = explaining(0..100, 0.9, 100);
        assert_eq!(config.rejection(&seen), None);
        let dipping = |sunk_mm: f64| ViewScore {
            sunk_mm,
            ..seen.clone()
        };
        assert_eq!(config.rejection(&dipping(2.9)), None);
        // A corner 4 mm deep: a small share of the part, refused all the same.
        assert_eq!(
            config.rejection(&dipping(4.0)),
            Some(Rejection::BelowSupport)
        );
        let sunk = ViewScore {
            below_support: 6,
            support_checked: 100,
            ..seen
        };
        assert_eq!(config.rejection(&sunk), Some(Rejection::BelowSupport));
    }

    #[test]
    fn turns_are_tried_for_poses_refused_as_a_turned_part_would_be() {
        let config = ExplainConfig {
            max_free_space: 0.05,
            ..square_parts()
        };
        let seen_through = |n: u32| ViewScore {
            free_space: n,
            ..explaining(0..100, 0.9, 100)
        };
        assert!(config.worth_turning(&seen_through(0)), "acceptable");
        assert!(
            config.worth_turning(&explaining(0..100, 0.3, 100)),
            "poor fit"
        );
        assert!(
            config.worth_turning(&seen_through(8)),
            "a little free space"
        );
        assert_eq!(
            config.rejection(&seen_through(8)),
            Some(Rejection::FreeSpace)
        );
        assert!(!config.worth_turning(&seen_through(12)), "over clutter");
        assert!(
            !config.worth_turning(&explaining(0..30, 0.9, 100)),
            "hardly seen"
        );
        // The turn limit is a share of its own: a stricter acceptance still turns a pose
        // seeing through 6-10 % (a part voted the wrong way round does).
        let strict = ExplainConfig {
            max_free_space: 0.03,
            ..config
        };
        assert_eq!(
            strict.rejection(&seen_through(6)),
            Some(Rejection::FreeSpace)
        );
        assert!(strict.worth_turning(&seen_through(6)));
        assert!(strict.worth_turning(&seen_through(10)));
        assert!(!strict.worth_turning(&seen_through(11)));
    }

    #[test]
    fn only_poses_refused_by_far_are_past_refining() {
        let config = ExplainConfig {
            min_visibility: 0.45,
            max_free_space: 0.03,
            ..square_parts()
        };
        // 100 cells confirmed of `visible`, `free_space` of them seen through.
        let seeing_through = |free_space: u32, visible: u32| ViewScore {
            free_space,
            ..explaining(0..100, 0.9, visible)
        };
        assert!(!config.past_refining(&seeing_through(0, 100)), "acceptable");
        assert!(
            !config.past_refining(&explaining(0..100, 0.3, 100)),
            "a poor fit a last pass may close"
        );
        // Refused for free space: past it only beyond twice the share whose turns are tried
        // (a last pass may bring the turns in) ...
        assert_eq!(
            config.rejection(&seeing_through(4, 100)),
            Some(Rejection::FreeSpace)
        );
        assert!(!config.past_refining(&seeing_through(20, 100)));
        assert!(config.past_refining(&seeing_through(21, 100)));
        // 30 cells through 100 confirmed is 10 x the limit, but 15 % of 200 visible.
        assert!(!config.past_refining(&seeing_through(30, 200)));
        // ... and beyond 5 x the limit per confirmed cell.
        let lenient = ExplainConfig {
            max_free_space: 0.1,
            ..config.clone()
        };
        assert_eq!(
            lenient.rejection(&seeing_through(40, 100)),
            Some(Rejection::FreeSpace)
        );
        assert!(!lenient.past_refining(&seeing_through(50, 100)));
        assert!(lenient.past_refining(&seeing_through(51, 100)));
        // Too little of it seen.
        assert_eq!(
            config.rejection(&explaining(0..40, 0.9, 100)),
            Some(Rejection::LowVisibility)
        );
        assert!(config.past_refining(&explaining(0..40, 0.9, 100)));
    }

    #[test]
    fn free_space_is_judged_against_the_surface_the_scene_confirms() {
        let config = ExplainConfig {
            min_visibility: 0.45,
            max_free_space: 0.03,
            ..square_parts()
        };
        let seeing_through = |explained: u32, free_space: u32, visible: u32| ViewScore {
            free_space,
            ..explaining(0..explained, 0.9, visible)
        };
        // Seen in full, 2 cells through 98 confirmed pass and 4 through 96 do not.
        assert_eq!(config.rejection(&seeing_through(98, 2, 100)), None);
        assert_eq!(
            config.rejection(&seeing_through(96, 4, 100)),
            Some(Rejection::FreeSpace)
        );
        // Half hidden under a neighbour: 4 cells through 100 confirmed is 2 % of the
        // visible surface but 4 % of what the scene confirms: refused (a pose laid across a
        // neighbour's surface and over clutter; the share of the visible surface passed it).
        let half = seeing_through(100, 4, 200);
        assert!(half.free_space_ratio() < config.max_free_space);
        assert_eq!(config.rejection(&half), Some(Rejection::FreeSpace));
        assert_eq!(config.rejection(&seeing_through(100, 3, 200)), None);
    }

    #[test]
    fn a_pose_crossing_a_part_is_refused_from_three_cells() {
        let config = ExplainConfig {
            min_visibility: 0.45,
            max_free_space: 0.03,
            max_crossing: 0.004,
            ..square_parts()
        };
        let crossing = |explained: u32, crossing: u32| ViewScore {
            free_space: crossing,
            crossing,
            ..explaining(0..explained, 0.9, explained)
        };
        // 1 000 cells confirmed: 4 crossing cells are within the share, 5 are not.
        assert_eq!(config.rejection(&crossing(1000, 4)), None);
        assert_eq!(
            config.rejection(&crossing(1000, 5)),
            Some(Rejection::CrossesPart)
        );
        // A small part: 2 crossing cells of 300 are over the share but too few to judge.
        assert_eq!(config.rejection(&crossing(300, 2)), None);
        assert_eq!(
            config.rejection(&crossing(300, 3)),
            Some(Rejection::CrossesPart)
        );
        // Seen through as much away from any part hidden: free space only, within its limit.
        let apart = ViewScore {
            crossing: 0,
            ..crossing(300, 3)
        };
        assert_eq!(config.rejection(&apart), None);
        // Its near-symmetric turns are tried, as for a pose seen through.
        assert!(config.worth_turning(&crossing(300, 3)));
    }

    #[test]
    fn a_part_seen_less_must_fit_closer() {
        let config = ExplainConfig {
            min_visibility: 0.45,
            min_fit: 0.7,
            occluded_min_fit: 0.85,
            occluded_below_visibility: 0.6,
            ..square_parts()
        };
        let close = |v: f64, want: f64| (config.fit_needed(v) - want).abs() < 1e-12;
        assert!(close(0.9, 0.7) && close(0.6, 0.7), "seen well: min_fit");
        assert!(close(0.525, 0.775), "half-way down: half the rise");
        assert!(
            close(0.45, 0.85) && close(0.3, 0.85),
            "at min_visibility and below"
        );
        // 100 of 200 cells seen (0.5): a loose fit is refused, a close one taken; seen
        // in full, the loose fit passes.
        let half_loose = explaining(0..100, 0.75, 200);
        let half_close = explaining(0..100, 0.85, 200);
        let full_loose = explaining(0..100, 0.75, 100);
        assert_eq!(config.rejection(&half_loose), Some(Rejection::PoorFit));
        assert_eq!(config.rejection(&half_close), None);
        assert_eq!(config.rejection(&full_loose), None);
        // At or below min_fit the rule is off.
        let off = ExplainConfig {
            occluded_min_fit: 0.5,
            ..config.clone()
        };
        assert_eq!(off.fit_needed(0.45), 0.7);
        assert_eq!(off.rejection(&half_loose), None);
    }

    #[test]
    fn background_cells_are_those_whose_nearest_surface_is_background() {
        // A 20 mm tile at z = 10 on the belt: its cells are not background, the belt's are.
        let (grid, _, _) = tiles_on_a_belt(square(0.0, 0.0, 20.0, 10.0, 1.0));
        let all = grid.background_cells(|_| true);
        assert_eq!(all.len(), grid.cells());
        let belt = all.iter().filter(|&&b| b).count();
        assert_eq!(belt, 200 * 200 - 20 * 20);
        // `keep` sees the cell's point: only the belt's left half.
        let left = grid.background_cells(|p| p[0] < 50.0);
        assert_eq!(left.iter().filter(|&&b| b).count(), 100 * 200 - 20 * 20);
    }

    #[test]
    fn surface_the_support_already_explains_is_no_gain() {
        // A right pose explains 1000 cells of a part. A wrong pose (a bracket turned and
        // shifted so one flange lies on the floor) explains 600 of the same cells and 800
        // cells of floor: counted, it gains the most and the right pose repeats it.
        let right = explaining(0..1000, 0.9, 1100);
        let on_floor = explaining(400..1800, 0.9, 1500);
        let scores = [right, on_floor];
        let votes = [0, 0];
        let none = vec![false; 3000];
        let e = explain_scene(&scores, &votes, |_, _| false, &none, &square_parts()).unwrap();
        assert_eq!(e.taken, vec![1], "floor counted as the part's own surface");
        assert_eq!(e.rejected[0], Some(Rejection::Explained));
        // The floor is the support's: the right pose wins and the other repeats it.
        let mut floor = none.clone();
        floor[1000..1800].fill(true);
        let e = explain_scene(&scores, &votes, |_, _| false, &floor, &square_parts()).unwrap();
        assert_eq!(e.taken, vec![0]);
        assert_eq!(e.rejected[1], Some(Rejection::Explained));
    }

    #[test]
    fn a_part_is_left_too_little_surface_only_by_the_parts_taken() {
        // A bracket seen edge on explains 15 cells (10 are needed), the lowest 6 in the
        // floor's band: the floor explains those already, but no part claims them, so it
        // still shows 15 cells of its own and is taken. A neighbour taken over the same 6
        // leaves it 9: too little surface of its own, it repeats the neighbour.
        let strip = explaining(0..15, 0.9, 16);
        let mut floor = vec![false; 3000];
        floor[0..6].fill(true);
        let alone = [strip.clone()];
        let e = explain_scene(&alone, &[0], |_, _| false, &floor, &square_parts()).unwrap();
        assert_eq!(
            e.taken,
            vec![0],
            "refused for the floor's cells: {:?}",
            e.rejected
        );
        let mut neighbour = explaining(100..400, 0.9, 300);
        neighbour.explained_cells.extend(0..6);
        neighbour.explained_fit.extend([0.9; 6]);
        neighbour.explained += 6;
        let both = [strip, neighbour];
        let none = vec![false; 3000];
        let e = explain_scene(&both, &[0, 0], |_, _| false, &none, &square_parts()).unwrap();
        assert_eq!(e.taken, vec![1]);
        assert_eq!(e.rejected[0], Some(Rejection::Explained));
    }

    #[test]
    fn a_near_tie_goes_to_the_pose_with_more_votes_of_its_own() {
        // A part and its near-symmetric turn explain almost the same cells (the flange that
        // differs is hidden): the turn explains 1 % more of them. A third hypothesis stands
        // apart and explains less.
        let right = explaining(0..1000, 0.9, 1100);
        let turn = explaining(5..1015, 0.9, 1100);
        let apart = explaining(2000..2500, 0.9, 550);
        let scores = [right, turn, apart];
        let votes = [60_000, 0, 100_000];
        let config = ExplainConfig {
            tie_share: 0.02,
            ..square_parts()
        };
        let different = |_: usize, _: usize| false;
        let e = explain_scene(&scores, &votes, different, &[false; 3000], &config).unwrap();
        assert_eq!(e.taken, vec![0, 2], "the voted pose wins the near-tie");
        assert_eq!(e.rejected[1], Some(Rejection::Explained));
        // Without the tie band the larger gain wins, whatever the votes.
        let strict = ExplainConfig {
            tie_share: 0.0,
            ..config.clone()
        };
        let e = explain_scene(&scores, &votes, different, &[false; 3000], &strict).unwrap();
        assert_eq!(e.taken, vec![1, 2]);
        // Two hypotheses of one pose: the better fit wins, not the more voted.
        let e = explain_scene(&scores, &votes, |_, _| true, &[false; 3000], &config).unwrap();
        assert_eq!(e.taken, vec![1, 2]);
        // A clear win is not a tie: the part explaining 10 % more is taken first.
        let larger = explaining(5..1105, 0.9, 1200);
        let e = explain_scene(
            &[scores[0].clone(), larger],
            &[60_000, 0],
            different,
            &[false; 3000],
            &config,
        )
        .unwrap();
        assert_eq!(e.taken, vec![1]);
        // The votes must match the hypotheses.
        assert!(matches!(
            explain_scene(&scores, &votes[..2], different, &[false; 3000], &config),
            Err(MatchError::Count { .. })
        ));
    }

    #[test]
    fn two_touching_parts_at_one_height_are_both_taken() {
        // Two 20 mm tiles side by side on a belt, touching, at the same height: each carries
        // on the other's outline along the shared side, and only the two together end in
        // depth edges all round.
        let tiles = square(0.0, 0.0, 20.0, 10.0, 1.0)
            .into_iter()
            .chain(square(20.0, 0.0, 20.0, 10.0, 1.0));
        let (grid, view, part) = tiles_on_a_belt(tiles);
        let at = |x: f64| Isometry3::translation(x, 0.0, 10.0);
        let left = grid.score(&part, &at(0.0), &view);
        let right = grid.score(&part, &at(20.0), &view);
        for s in [&left, &right] {
            assert!(
                s.continued_ratio() > square_parts().max_continued,
                "the shared side carries on each outline: {}",
                s.continued_ratio()
            );
        }
        // Straddling the seam: half on each tile, its outline carried on past both ends.
        let straddling = grid.score(&part, &at(10.0), &view);
        let e = unvoted_squares(&[straddling, left, right], &grid);
        assert_eq!(e.taken, vec![1, 2], "{e:?}");
        assert_eq!(e.rejected[0], Some(Rejection::Explained));
    }

    #[test]
    fn a_pose_mostly_off_its_part_is_hopeless_and_one_half_on_it_is_not() {
        // One 20 mm tile 10 mm above the belt; the model laid over it, shifted along x.
        let (grid, view, part) = tiles_on_a_belt(square(0.0, 0.0, 20.0, 10.0, 1.0));
        let config = square_parts();
        let hopeless = |x: f64| {
            let s = grid.score(&part, &Isometry3::translation(x, 0.0, 10.0), &view);
            (config.hopeless(&s), s.visibility())
        };
        // On it, and half on it (visibility 0.5, at the threshold): worth refining.
        assert!(!hopeless(0.0).0, "{:?}", hopeless(0.0));
        assert!(!hopeless(10.0).0, "{:?}", hopeless(10.0));
        // A fifth on it: under half the visibility asked (0.5 x 0.5).
        let (off, visibility) = hopeless(17.0);
        assert!(off && visibility < 0.25, "{visibility}");
        // Off it altogether.
        assert!(hopeless(40.0).0);
    }
}
