#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use binpick_viz::{
    Percents, PlotOptions, TableRow, TimeStats, VizError, plot_thesis_table, plot_time_histogram,
};
use common::read_png;

/// The thesis's absolute table 5.5.2 (F, P, R, FN, FP, NP, FB, S per configuration).
fn thesis_rows() -> Vec<TableRow> {
    [
        ("A", 40, 102, 88, 14, 1, 9, 0, 1),
        ("B", 40, 79, 58, 21, 0, 5, 0, 3),
        ("C1", 40, 80, 46, 34, 19, 6, 9, 4),
        ("C2", 40, 80, 64, 16, 28, 11, 7, 2),
        ("C3", 40, 149, 104, 45, 17, 10, 6, 1),
    ]
    .iter()
    .map(|&(c, f, p, r, fnn, fp, np, fb, s)| TableRow {
        config: c.into(),
        files: f,
        pickable: p,
        recognised: r,
        false_negatives: fnn,
        files_with_fp: fp,
        files_with_unpickable: np,
        false_best: fb,
        starvation: s,
        thesis: Percents::thesis_conveyor(c),
    })
    .collect()
}

fn size(w: u32, h: u32) -> PlotOptions {
    PlotOptions {
        width: w,
        height: h,
        title: None,
    }
}

#[test]
fn percentages_reproduce_the_thesis_table() {
    for row in thesis_rows() {
        let ours = row.percents().as_array();
        let theirs = row.thesis.unwrap().as_array();
        for (o, t) in ours.iter().zip(theirs) {
            // The thesis prints whole percent (x.5 rounded either way).
            assert!(
                (o - t).abs() <= 0.61,
                "{}: ours {ours:?} thesis {theirs:?}",
                row.config
            );
        }
    }
    assert!(Percents::thesis_conveyor("Z").is_none());
    let empty = TableRow {
        files: 0,
        pickable: 0,
        ..thesis_rows()[0].clone()
    };
    assert!(empty.percents().as_array().iter().all(|v| v.is_nan()));
}

/// Height in pixels of the tallest run of `c` in each column range.
fn tallest(img: &image::RgbImage, c: [u8; 3], x0: u32, x1: u32) -> u32 {
    let mut best = 0;
    for x in x0..x1 {
        let n = (0..img.height())
            .filter(|&y| img.get_pixel(x, y).0 == c)
            .count() as u32;
        best = best.max(n);
    }
    best
}

#[test]
fn thesis_table_chart_has_the_requested_size_and_bar_heights_follow_the_data() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.png");
    plot_thesis_table(&thesis_rows(), &size(900, 500), &out).unwrap();
    assert_eq!(read_png(&out).dimensions(), (900, 500));

    // Two configurations: recognition 90 % vs 30 %; the green R/P bar of the first is 3x as
    // tall as the second's.
    let mut rows = thesis_rows()[..2].to_vec();
    rows[0].pickable = 100;
    rows[0].recognised = 90;
    rows[1].pickable = 100;
    rows[1].recognised = 30;
    rows[1].thesis = None;
    plot_thesis_table(&rows, &size(1000, 600), &out).unwrap();
    let img = read_png(&out);
    assert_eq!(img.dimensions(), (1000, 600));
    let green = [44, 160, 44];
    let left = tallest(&img, green, 0, 400);
    let right = tallest(&img, green, 400, 760);
    assert!(left > 100, "{left}");
    let ratio = f64::from(left) / f64::from(right);
    assert!((ratio - 3.0).abs() < 0.15, "bar heights {left} and {right}");

    // Zero denominators and a tiny image are fine; no rows and bad sizes are errors.
    let mut odd = thesis_rows();
    odd[1].files = 0;
    odd[1].pickable = 0;
    plot_thesis_table(&odd, &size(64, 64), &out).unwrap();
    assert_eq!(read_png(&out).dimensions(), (64, 64));
    let r = plot_thesis_table(&[], &size(300, 200), &out);
    assert!(matches!(r, Err(VizError::NoData(_))), "{r:?}");
    let r = plot_thesis_table(&odd, &size(10_000, 200), &out);
    assert!(matches!(r, Err(VizError::BadSize { .. })), "{r:?}");
}

#[test]
fn time_histogram_marks_median_and_p95() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("h.png");
    // 1..=100 ms: nearest-rank median 50 and p95 95.
    let mut times: Vec<f64> = (1..=100).map(f64::from).collect();
    times.push(f64::NAN);
    let st = plot_time_histogram(&times, &size(800, 400), &out).unwrap();
    assert_eq!(st.n, 100);
    assert_eq!(st.non_finite, 1);
    assert_eq!((st.median, st.p95), (50.0, 95.0), "{st:?}");
    assert_eq!((st.min, st.max), (1.0, 100.0));
    let img = read_png(&out);
    assert_eq!(img.dimensions(), (800, 400));
    // The median line (dark blue) is drawn left of the p95 line (red), 45 ms apart on an
    // axis of about 100 ms.
    let cols = |c: [u8; 3]| -> Vec<u32> {
        (0..img.width())
            .filter(|&x| {
                (0..img.height())
                    .filter(|&y| img.get_pixel(x, y).0 == c)
                    .count()
                    > 100
            })
            .collect()
    };
    let median_x = cols([20, 40, 140]);
    let p95_x = cols([200, 30, 30]);
    assert!(
        !median_x.is_empty() && !p95_x.is_empty(),
        "{median_x:?} {p95_x:?}"
    );
    let mx = f64::from(median_x[0] + median_x[median_x.len() - 1]) / 2.0;
    let px = f64::from(p95_x[0] + p95_x[p95_x.len() - 1]) / 2.0;
    assert!(px - mx > 200.0, "median at {mx}, p95 at {px}");

    // Moving the data moves the median line.
    let slow: Vec<f64> = (1..=100)
        .map(|t| f64::from(t) + if t <= 60 { 0.0 } else { 500.0 })
        .collect();
    let st2 = plot_time_histogram(&slow, &size(800, 400), &out).unwrap();
    assert_eq!((st2.median, st2.p95), (50.0, 595.0));

    // Degenerate inputs.
    let same = plot_time_histogram(&[7.0; 5], &size(300, 200), &out).unwrap();
    assert_eq!((same.median, same.p95), (7.0, 7.0));
    plot_time_histogram(&[3.0], &size(64, 64), &out).unwrap();
    assert_eq!(read_png(&out).dimensions(), (64, 64));
    for bad in [&[][..], &[f64::NAN, f64::INFINITY][..]] {
        let r = plot_time_histogram(bad, &size(300, 200), &out);
        assert!(matches!(r, Err(VizError::NoData(_))), "{r:?}");
    }
    let r = plot_time_histogram(&times, &size(300, 20), &out);
    assert!(matches!(r, Err(VizError::BadSize { .. })), "{r:?}");
    assert_eq!(TimeStats::from_times(&[]), None);
}
