//! Scoring detections against ground truth, and the thesis's result table (5.4, 5.5.2).
//!
//! A detection is **correct** for an instance when the mean distance between the model's
//! points under the two poses, minimised over the model's declared symmetries, is below
//! `10 %` of the model diameter. Pairs are matched greedily from the smallest distance, so
//! each instance and each detection is used at most once; a second detection of an
//! already-matched instance is a false positive (a duplicate).
//!
//! Per file (scene) the thesis counts (5.4-5.5):
//!
//! | symbol | meaning                                                                          |
//! |--------|----------------------------------------------------------------------------------|
//! | F      | files processed                                                                  |
//! | P      | pickable instances present (ground truth `pickable`)                            |
//! | R      | pickable instances recognised (matched by a correct detection)                   |
//! | FN     | P - R                                                                            |
//! | FP     | files with at least one false positive (a detection matching no instance)        |
//! | NP     | files with at least one correctly aligned but unpickable instance                |
//! | FB     | bad cycles by false best: pickable parts present, and the top-ranked detection   |
//! |        | is a false positive or an unpickable instance                                    |
//! | S      | bad cycles by starvation: pickable parts present and no pick made (nothing       |
//! |        | detected, or nothing the engine found free to pick)                              |
//!
//! The **first pick** is the result's (`Recognition::first_pick`): the top-ranked detection
//! when it is free to pick, else none. FB and S judge it, not the top rank: a scene where
//! every detection is covered by another part gives no pick, and counts as starvation
//! (`none_free_to_pick` says it was that rather than nothing detected).
//! A file without pickable parts is never a bad cycle (5.4.3.2).
//!
//! Next to the thesis's table, every run reports **BOP-visible recall**: the share of
//! instances at least 10 % visible (BOP's `visib_fract >= 0.1` rule of its 2019+ evaluation)
//! that a correct detection matched, with correctness as above (a symmetry-aware mean
//! model-point distance, ADD-S over the declared symmetries, under 10 % of the diameter; not
//! BOP's VSD/MSSD/MSPD average recall). Detections on less visible instances are neither
//! counted nor penalised there.

use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

/// Default correctness threshold: mean model-point distance below this fraction of the
/// model diameter.
pub const DEFAULT_MATCH_FRACTION: f64 = 0.10;

/// What one detection turned out to be.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Correct, on a pickable instance.
    Pickable,
    /// Correct, on an instance too occluded to pick.
    Unpickable,
    /// Matches no instance (wrong alignment, clutter, or a duplicate).
    FalsePositive,
}

/// The verdict for one detection, in rank order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DetectionVerdict {
    pub rank: usize,
    pub verdict: Verdict,
    /// Ground-truth instance index, when matched.
    pub instance: Option<usize>,
    /// Symmetry-minimised mean point distance to the closest instance, mm.
    pub error_mm: f64,
}

/// One scene's score.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SceneScore {
    pub instances: usize,
    /// Instances with a visible fraction of at least [`BOP_MIN_VISIBLE`] (BOP's targets).
    #[serde(default)]
    pub bop_targets: usize,
    /// Of those, the ones matched by a correct detection.
    #[serde(default)]
    pub bop_recognised: usize,
    pub pickable: usize,
    pub recognised_pickable: usize,
    pub recognised_unpickable: usize,
    pub false_positives: usize,
    pub detections: Vec<DetectionVerdict>,
    /// Top-ranked detection wrong or unpickable while pickable parts were present.
    pub false_best: bool,
    /// A first pick was made and it is not a correct pose of a pickable part, whether or not
    /// pickable parts were present: a right pick or none (`false_best` counts only scans
    /// with pickable parts, as the thesis's table does). Absent in older summaries: false.
    #[serde(default)]
    pub wrong_first_pick: bool,
    /// Pickable parts present and no pick: no detection at all, or none free to pick.
    pub starvation: bool,
    /// Detections made but none free to pick (every part found is covered by another, or
    /// unreachable), pickable parts present or not. Absent in older summaries: false.
    #[serde(default)]
    pub none_free_to_pick: bool,
}

/// Mean distance, mm, between `points` under `a` and under `b`.
fn mean_distance(points: &[Point3<f64>], a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    if points.is_empty() {
        return f64::INFINITY;
    }
    points.iter().map(|p| (a * p - b * p).norm()).sum::<f64>() / points.len() as f64
}

/// Symmetry-aware pose error: min over `symmetries` S of the mean distance between the model
/// points under `estimate` and under `truth * S`, mm.
pub fn pose_error_mm(
    points: &[Point3<f64>],
    estimate: &Isometry3<f64>,
    truth: &Isometry3<f64>,
    symmetries: &[Isometry3<f64>],
) -> f64 {
    let identity = [Isometry3::identity()];
    let syms = if symmetries.is_empty() {
        &identity[..]
    } else {
        symmetries
    };
    syms.iter()
        .map(|s| mean_distance(points, estimate, &(truth * s)))
        .fold(f64::INFINITY, f64::min)
}

/// BOP's minimum visible fraction of a target instance (`visib_gt_min`).
pub const BOP_MIN_VISIBLE: f64 = 0.1;

/// A ground-truth instance in scoring form.
#[derive(Clone, Debug)]
pub struct TruthInstance {
    pub pose: Isometry3<f64>,
    pub pickable: bool,
    /// Share (0..1) of the instance the scan shows (BOP's visib_fract where the dataset has it).
    pub visible_fraction: f64,
}

/// Scores one scene. `detections` are (rank, pose) in rank order; `first_pick` is the rank
/// of the detection picked first (the result's first pick), None when no pick was made.
pub fn score_scene(
    points: &[Point3<f64>],
    symmetries: &[Isometry3<f64>],
    diameter_mm: f64,
    truth: &[TruthInstance],
    detections: &[(usize, Isometry3<f64>)],
    first_pick: Option<usize>,
    match_fraction: f64,
) -> SceneScore {
    let limit = match_fraction * diameter_mm;
    // All (detection, instance) errors, then greedy assignment from the smallest.
    let errors: Vec<Vec<f64>> = detections
        .iter()
        .map(|(_, est)| {
            truth
                .iter()
                .map(|t| pose_error_mm(points, est, &t.pose, symmetries))
                .collect()
        })
        .collect();
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (d, row) in errors.iter().enumerate() {
        for (i, &e) in row.iter().enumerate() {
            if e < limit {
                pairs.push((e, d, i));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut det_match: Vec<Option<usize>> = vec![None; detections.len()];
    let mut inst_used = vec![false; truth.len()];
    for (_, d, i) in pairs {
        if det_match[d].is_none() && !inst_used[i] {
            det_match[d] = Some(i);
            inst_used[i] = true;
        }
    }
    let bop_target = |t: &TruthInstance| t.visible_fraction >= BOP_MIN_VISIBLE;
    let mut score = SceneScore {
        instances: truth.len(),
        pickable: truth.iter().filter(|t| t.pickable).count(),
        bop_targets: truth.iter().filter(|t| bop_target(t)).count(),
        bop_recognised: det_match
            .iter()
            .flatten()
            .filter(|&&i| bop_target(&truth[i]))
            .count(),
        ..SceneScore::default()
    };
    for (d, (rank, _)) in detections.iter().enumerate() {
        let closest = errors[d].iter().copied().fold(f64::INFINITY, f64::min);
        let (verdict, instance) = match det_match[d] {
            Some(i) if truth[i].pickable => (Verdict::Pickable, Some(i)),
            Some(i) => (Verdict::Unpickable, Some(i)),
            None => (Verdict::FalsePositive, None),
        };
        match verdict {
            Verdict::Pickable => score.recognised_pickable += 1,
            Verdict::Unpickable => score.recognised_unpickable += 1,
            Verdict::FalsePositive => score.false_positives += 1,
        }
        score.detections.push(DetectionVerdict {
            rank: *rank,
            verdict,
            instance,
            error_mm: instance.map_or(closest, |i| errors[d][i]),
        });
    }
    let pick = first_pick.and_then(|r| score.detections.iter().find(|v| v.rank == r));
    score.none_free_to_pick = !detections.is_empty() && pick.is_none();
    score.wrong_first_pick = pick.is_some_and(|v| v.verdict != Verdict::Pickable);
    if score.pickable > 0 {
        match pick {
            None => score.starvation = true,
            Some(v) => score.false_best = v.verdict != Verdict::Pickable,
        }
    }
    score
}

/// The thesis's table (5.5.2) for one configuration, in absolute numbers.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ThesisTable {
    /// F: files processed.
    pub files: usize,
    /// P: pickable instances present.
    pub pickable: usize,
    /// R: pickable instances recognised.
    pub recognised: usize,
    /// FN = P - R.
    pub false_negatives: usize,
    /// FP: files with at least one false positive.
    pub files_with_false_positive: usize,
    /// NP: files with at least one correctly aligned unpickable instance.
    pub files_with_unpickable: usize,
    /// FB: bad cycles by false best.
    pub false_best: usize,
    /// S: bad cycles by starvation.
    pub starvation: usize,
    /// All detections, and how many were correct (pickable or not): for precision.
    pub detections: usize,
    pub correct_detections: usize,
    /// Instances at least 10 % visible (BOP's targets), and how many were recognised.
    #[serde(default)]
    pub bop_targets: usize,
    #[serde(default)]
    pub bop_recognised: usize,
}

impl ThesisTable {
    pub fn add(&mut self, s: &SceneScore) {
        self.files += 1;
        self.pickable += s.pickable;
        self.recognised += s.recognised_pickable;
        self.false_negatives += s.pickable - s.recognised_pickable;
        self.files_with_false_positive += usize::from(s.false_positives > 0);
        self.files_with_unpickable += usize::from(s.recognised_unpickable > 0);
        self.false_best += usize::from(s.false_best);
        self.starvation += usize::from(s.starvation);
        self.detections += s.detections.len();
        self.correct_detections += s.recognised_pickable + s.recognised_unpickable;
        self.bop_targets += s.bop_targets;
        self.bop_recognised += s.bop_recognised;
    }

    fn pct(num: usize, den: usize) -> f64 {
        if den == 0 {
            0.0
        } else {
            100.0 * num as f64 / den as f64
        }
    }

    /// The percent form (5.5.2): R/P, FN/P, FP/F, NP/F, FB/F, S/F, and precision.
    pub fn percents(&self) -> ThesisPercents {
        ThesisPercents {
            recognition: Self::pct(self.recognised, self.pickable),
            false_negatives: Self::pct(self.false_negatives, self.pickable),
            files_with_false_positive: Self::pct(self.files_with_false_positive, self.files),
            files_with_unpickable: Self::pct(self.files_with_unpickable, self.files),
            false_best: Self::pct(self.false_best, self.files),
            starvation: Self::pct(self.starvation, self.files),
            precision: Self::pct(self.correct_detections, self.detections),
            bop_visible_recall: Self::pct(self.bop_recognised, self.bop_targets),
        }
    }
}

/// The table's percent form.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ThesisPercents {
    pub recognition: f64,
    pub false_negatives: f64,
    pub files_with_false_positive: f64,
    pub files_with_unpickable: f64,
    pub false_best: f64,
    pub starvation: f64,
    /// Share of detections that are correct (not in the thesis's table).
    pub precision: f64,
    /// BOP-visible recall: instances at least 10 % visible that were recognised (module docs).
    #[serde(default)]
    pub bop_visible_recall: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn model() -> Vec<Point3<f64>> {
        // An L of points, 100 mm long: diameter ~ 100.
        let mut v: Vec<Point3<f64>> = (0..=100).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        v.extend((1..=40).map(|i| Point3::new(0.0, i as f64, 0.0)));
        v
    }

    fn at(x: f64, y: f64, yaw_deg: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
        )
    }

    /// The hand-built case from the issue: one correct, one flipped, one duplicate, one missed.
    #[test]
    fn counts_a_hand_built_case() {
        let pts = model();
        let truth = vec![
            TruthInstance {
                pose: at(0.0, 0.0, 0.0),
                pickable: true,
                visible_fraction: 1.0,
            },
            TruthInstance {
                pose: at(300.0, 0.0, 30.0),
                pickable: true,
                visible_fraction: 1.0,
            },
            TruthInstance {
                pose: at(0.0, 300.0, 90.0),
                pickable: true,
                visible_fraction: 1.0,
            }, // missed
        ];
        let detections = vec![
            (1, at(1.0, 0.5, 0.5)),     // correct on instance 0 (mean error ~1 mm)
            (2, at(300.0, 0.0, 210.0)), // instance 1 flipped by 180 deg: wrong
            (3, at(2.0, 0.0, 0.0)),     // duplicate of instance 0
        ];
        let s = score_scene(
            &pts,
            &[],
            100.0,
            &truth,
            &detections,
            Some(1),
            DEFAULT_MATCH_FRACTION,
        );
        assert_eq!(s.pickable, 3);
        assert_eq!(s.recognised_pickable, 1);
        assert_eq!(s.false_positives, 2, "flipped and duplicate");
        let v: Vec<Verdict> = s.detections.iter().map(|d| d.verdict).collect();
        assert_eq!(
            v,
            vec![
                Verdict::Pickable,
                Verdict::FalsePositive,
                Verdict::FalsePositive
            ]
        );
        assert_eq!(s.detections[0].instance, Some(0));
        assert!(!s.false_best && !s.starvation);
        let mut t = ThesisTable::default();
        t.add(&s);
        assert_eq!(
            (t.files, t.pickable, t.recognised, t.false_negatives),
            (1, 3, 1, 2)
        );
        assert_eq!(
            (
                t.files_with_false_positive,
                t.files_with_unpickable,
                t.false_best,
                t.starvation
            ),
            (1, 0, 0, 0)
        );
        let p = t.percents();
        assert!((p.recognition - 100.0 / 3.0).abs() < 1e-9);
        assert!((p.precision - 100.0 / 3.0).abs() < 1e-9);
    }

    #[test]
    fn symmetry_makes_a_flip_correct() {
        let pts: Vec<Point3<f64>> = (-50..=50)
            .map(|i| Point3::new(i as f64, 0.0, 0.0))
            .collect();
        let truth = vec![TruthInstance {
            pose: at(0.0, 0.0, 0.0),
            pickable: true,
            visible_fraction: 1.0,
        }];
        let flipped = vec![(1, at(0.0, 0.0, 180.0))];
        let no_sym = score_scene(
            &pts,
            &[],
            100.0,
            &truth,
            &flipped,
            Some(1),
            DEFAULT_MATCH_FRACTION,
        );
        assert_eq!(no_sym.false_positives, 1);
        let syms = [Isometry3::identity(), at(0.0, 0.0, 180.0)];
        let sym = score_scene(
            &pts,
            &syms,
            100.0,
            &truth,
            &flipped,
            Some(1),
            DEFAULT_MATCH_FRACTION,
        );
        assert_eq!(sym.recognised_pickable, 1);
        assert!(sym.detections[0].error_mm < 1e-9);
    }

    #[test]
    fn false_best_and_starvation() {
        let pts = model();
        let truth = vec![
            TruthInstance {
                pose: at(0.0, 0.0, 0.0),
                pickable: false,
                visible_fraction: 0.05,
            },
            TruthInstance {
                pose: at(300.0, 0.0, 0.0),
                pickable: true,
                visible_fraction: 1.0,
            },
        ];
        // Top detection on the unpickable instance, the other on the pickable one.
        let both = |first_pick| {
            let found = [(1, at(0.0, 0.0, 0.0)), (2, at(300.0, 0.0, 0.0))];
            score_scene(&pts, &[], 100.0, &truth, &found, first_pick, 0.1)
        };
        // The top one picked: false best, and NP.
        let s = both(Some(1));
        assert!(s.false_best);
        assert_eq!((s.recognised_unpickable, s.recognised_pickable), (1, 1));
        // BOP's rule: the 5 %-visible instance is no target, its match is not counted.
        assert_eq!((s.bop_targets, s.bop_recognised), (1, 1));
        let mut t = ThesisTable::default();
        t.add(&s);
        t.add(&score_scene(&pts, &[], 100.0, &truth, &[], None, 0.1));
        assert_eq!((t.bop_targets, t.bop_recognised), (2, 1));
        assert!((t.percents().bop_visible_recall - 50.0).abs() < 1e-9);
        // Nothing detected: starvation.
        let s = score_scene(&pts, &[], 100.0, &truth, &[], None, 0.1);
        assert!(s.starvation && !s.false_best && !s.none_free_to_pick);
        // Detections but none free to pick: no pick, which starves the cell but is not a
        // false best, however wrong the top rank is.
        let s = both(None);
        assert!(s.starvation && s.none_free_to_pick && !s.false_best && !s.wrong_first_pick);
        assert_eq!(s.recognised_pickable, 1, "recall counts every detection");
        // No pickable parts: never a bad cycle.
        let s = score_scene(
            &pts,
            &[],
            100.0,
            &truth[..1],
            &[(1, at(500.0, 0.0, 0.0))],
            Some(1),
            0.1,
        );
        assert!(!s.starvation && !s.false_best);
        assert_eq!(s.false_positives, 1);
        // ... but a pick was made where none should be: a wrong first pick.
        assert!(s.wrong_first_pick);
        let none = score_scene(&pts, &[], 100.0, &truth[..1], &[], None, 0.1);
        assert!(!none.wrong_first_pick, "no pick is not a wrong pick");
        let right = score_scene(
            &pts,
            &[],
            100.0,
            &truth,
            &[(1, at(300.0, 0.0, 0.0))],
            Some(1),
            0.1,
        );
        assert!(!right.wrong_first_pick && !right.false_best);
    }
}
