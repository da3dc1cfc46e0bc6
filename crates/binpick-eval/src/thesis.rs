//! The thesis's published results, in one place: the percent tables of sections 5.5.2
//! (conveyor belt) and 5.6.2 (robot arm), for side-by-side comparison with `binpick eval`.

use crate::score::ThesisPercents;

/// The thesis's published percentages (5.5.2 conveyor, 5.6.2 arm), for side-by-side tables.
/// NP is not published for the arm tests.
pub fn thesis_reference(config: &str) -> Option<ThesisPercents> {
    let row = |r, fnr, fp, np, fb, s| ThesisPercents {
        recognition: r,
        false_negatives: fnr,
        files_with_false_positive: fp,
        files_with_unpickable: np,
        false_best: fb,
        starvation: s,
        precision: f64::NAN,
        bop_visible_recall: f64::NAN,
    };
    match config {
        "A" => Some(row(86.0, 14.0, 2.0, 22.0, 0.0, 2.0)),
        "B" => Some(row(73.0, 27.0, 0.0, 12.0, 0.0, 7.0)),
        "C1" => Some(row(58.0, 42.0, 47.0, 15.0, 22.0, 10.0)),
        "C2" => Some(row(80.0, 20.0, 70.0, 27.0, 17.0, 5.0)),
        "C3" => Some(row(70.0, 30.0, 42.0, 25.0, 15.0, 2.0)),
        "arm-A" => Some(row(85.0, 15.0, 20.0, f64::NAN, 3.0, 0.0)),
        "arm-C" => Some(row(57.0, 43.0, 57.0, f64::NAN, 10.0, 7.0)),
        _ => None,
    }
}
