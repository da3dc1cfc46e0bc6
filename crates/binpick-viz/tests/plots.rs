#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use binpick_viz::{
    BAR_COLORS, BarChart, BarGroup, BarMetric, Better, MEDIAN_COLOR, P95_COLOR, Percents,
    PlotOptions, REFERENCE_COLOR, TableRow, TimeStats, VizError, plot_bar_chart, plot_thesis_table,
    plot_time_histogram,
};
use common::read_png;
use image::RgbImage;

fn size(w: u32, h: u32) -> PlotOptions {
    PlotOptions {
        width: w,
        height: h,
        title: None,
    }
}

fn percents(v: [f64; 6]) -> Percents {
    Percents {
        recognition: v[0],
        false_negatives: v[1],
        false_positives: v[2],
        unpickable: v[3],
        false_best: v[4],
        starvation: v[5],
    }
}

/// A row with P = 100 and F = 50, so the counts give round percentages.
fn row(config: &str, counts: [usize; 6], reference: Option<[f64; 6]>) -> TableRow {
    TableRow {
        config: config.into(),
        files: 50,
        pickable: 100,
        recognised: counts[0],
        false_negatives: counts[1],
        files_with_fp: counts[2],
        files_with_unpickable: counts[3],
        false_best: counts[4],
        starvation: counts[5],
        reference: reference.map(percents),
    }
}

/// One group of the six thesis-table metrics with these values and references (percent).
fn one_group(values: [f64; 6], reference: Option<[f64; 6]>) -> BarChart {
    let mut chart = BarChart::thesis_table(&[row("X", [0; 6], None)]);
    chart.groups[0].values = values.to_vec();
    chart.groups[0].reference = reference.map(|r| r.to_vec());
    chart
}

/// Bars of colour `c`: maximal runs of columns holding at least `min_px` pixels of it, as
/// (first column, last column, lowest row, highest row).
fn bars(img: &RgbImage, c: [u8; 3], min_px: usize) -> Vec<(u32, u32, u32, u32)> {
    let mut out = Vec::new();
    let mut run: Option<(u32, u32, u32, u32)> = None;
    for x in 0..img.width() {
        let ys: Vec<u32> = (0..img.height())
            .filter(|&y| img.get_pixel(x, y).0 == c)
            .collect();
        if ys.len() >= min_px {
            let (lo, hi) = (ys[ys.len() - 1], ys[0]);
            run = Some(match run {
                Some((x0, _, l, h)) => (x0, x, l.max(lo), h.min(hi)),
                None => (x, x, lo, hi),
            });
        } else if let Some(r) = run.take() {
            out.push(r);
        }
    }
    out.extend(run);
    out
}

/// Horizontal runs of exactly `c` in row `y` at least `min_len` long, as (first, last).
fn row_runs(img: &RgbImage, y: u32, c: [u8; 3], min_len: u32) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    let mut start = None;
    for x in 0..=img.width() {
        let hit = x < img.width() && img.get_pixel(x, y).0 == c;
        match (hit, start) {
            (true, None) => start = Some(x),
            (false, Some(s)) => {
                if x - s >= min_len {
                    out.push((s, x - 1));
                }
                start = None;
            }
            _ => {}
        }
    }
    out
}

/// Rows in column range `x0..=x1` where `c` covers the whole range: the reference marks
/// (text never fills a bar's width with one exact colour).
fn full_rows(img: &RgbImage, x0: u32, x1: u32, c: [u8; 3]) -> Vec<u32> {
    (0..img.height())
        .filter(|&y| (x0..=x1).all(|x| img.get_pixel(x, y).0 == c))
        .collect()
}

/// Splits sorted rows into runs of consecutive rows, as (first, last).
fn row_groups(rows: &[u32]) -> Vec<(u32, u32)> {
    let mut out: Vec<(u32, u32)> = Vec::new();
    for &y in rows {
        match out.last_mut() {
            Some((_, last)) if *last + 1 == y => *last = y,
            _ => out.push((y, y)),
        }
    }
    out
}

#[test]
fn percentages_follow_the_counts_and_zero_denominators_are_nan() {
    let r = row("A", [90, 10, 5, 0, 25, 50], None);
    assert_eq!(
        r.percents().as_array(),
        [90.0, 10.0, 10.0, 0.0, 50.0, 100.0]
    );
    let g = r.bar_group();
    assert_eq!(g.name, "A");
    assert_eq!(g.note, "F=50 P=100");
    assert_eq!(g.values, vec![90.0, 10.0, 10.0, 0.0, 50.0, 100.0]);
    assert_eq!(g.reference, None);
    let empty = TableRow {
        files: 0,
        pickable: 0,
        ..r
    };
    assert!(empty.percents().as_array().iter().all(|v| v.is_nan()));
}

#[test]
fn bar_chart_has_the_requested_size_and_bar_heights_follow_the_data() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.png");
    // Recognition 90 % vs 30 %: the first group's green R/P bar is 3x as tall.
    let rows = [
        row(
            "A",
            [90, 10, 2, 4, 1, 1],
            Some([86.0, 14.0, 2.0, 22.0, 0.0, 2.0]),
        ),
        row("B", [30, 70, 2, 4, 1, 1], None),
    ];
    plot_thesis_table(&rows, &size(1000, 600), &out).unwrap();
    let img = read_png(&out);
    assert_eq!(img.dimensions(), (1000, 600));
    // The legend swatch is green too but short; the bars are the tall runs.
    let green: Vec<_> = bars(&img, BAR_COLORS[0], 40);
    assert_eq!(green.len(), 2, "{green:?}");
    let height = |b: (u32, u32, u32, u32)| f64::from(b.2 - b.3 + 1);
    let ratio = height(green[0]) / height(green[1]);
    assert!(height(green[0]) > 200.0, "{green:?}");
    assert!((ratio - 3.0).abs() < 0.05, "bar heights {green:?}");
    assert!(green[0].1 < green[1].0, "groups left to right: {green:?}");
    // Both bars stand on the same baseline.
    assert_eq!(green[0].2, green[1].2);
    // There is text: dark pixels in the title band and the y-axis title strip.
    let dark = |x0: u32, x1: u32, y0: u32, y1: u32| {
        (y0..y1)
            .flat_map(|y| (x0..x1).map(move |x| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&c| c < 100))
            .count()
    };
    assert!(dark(200, 800, 0, 30) > 100, "no title");
    assert!(dark(0, 30, 150, 450) > 100, "no y-axis title");

    // Tiny images and zero denominators are fine; no rows and bad sizes are errors.
    let mut odd = rows.to_vec();
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
fn a_zero_bar_stays_visible_at_the_baseline_even_under_a_zero_reference() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("z.png");
    // FN/P (orange) is 0 with a reference of 0; S/F (blue) is 0 without a reference.
    let chart = one_group(
        [50.0, 0.0, 20.0, 10.0, 5.0, 0.0],
        Some([60.0, 0.0, 20.0, 10.0, 5.0, f64::NAN]),
    );
    plot_bar_chart(&chart, &size(900, 500), &out).unwrap();
    let img = read_png(&out);
    let green = bars(&img, BAR_COLORS[0], 40);
    assert_eq!(green.len(), 1, "{green:?}");
    let bottom = green[0].2; // the lowest bar row, just above the axis
    for k in [1, 5] {
        let stubs: Vec<_> = bars(&img, BAR_COLORS[k], 1)
            .into_iter()
            .filter(|b| b.2 + 20 > bottom) // not the legend swatch
            .collect();
        assert_eq!(stubs.len(), 1, "metric {k}: {stubs:?}");
        let (x0, x1, lo, hi) = stubs[0];
        assert!(x1 - x0 >= 10, "metric {k} stub too narrow: {stubs:?}");
        // Its colour reaches down to the baseline and it is a few pixels tall, no more.
        assert!(
            lo + 3 >= bottom && lo <= bottom,
            "metric {k}: {stubs:?}, base {bottom}"
        );
        assert!(
            (2..=10).contains(&(lo - hi + 1)),
            "metric {k} stub height: {stubs:?}"
        );
        // Visible pixels of the stub, in the middle column.
        let xm = (x0 + x1) / 2;
        let n = (hi..=lo)
            .filter(|&y| img.get_pixel(xm, y).0 == BAR_COLORS[k])
            .count();
        assert!(n >= 2, "metric {k}: only {n} pixels of the stub show");
    }
    // A missing value (NaN) draws no bar at all.
    let mut missing = chart.clone();
    missing.groups[0].values[1] = f64::NAN;
    plot_bar_chart(&missing, &size(900, 500), &out).unwrap();
    let img = read_png(&out);
    let orange: Vec<_> = bars(&img, BAR_COLORS[1], 1)
        .into_iter()
        .filter(|b| b.2 + 20 > bottom)
        .collect();
    assert!(orange.is_empty(), "{orange:?}");
}

#[test]
fn reference_marks_sit_at_their_values_and_never_overlap() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.png");
    let values = [80.0, 40.0, 60.0, 10.0, 30.0, 20.0];
    let reference = [50.0, 10.0, 60.0, 45.0, 25.0, 90.0];
    plot_bar_chart(&one_group(values, Some(reference)), &size(900, 500), &out).unwrap();
    let img = read_png(&out);
    // Pixels per percent from the tallest bar (80 %).
    let green = bars(&img, BAR_COLORS[0], 40);
    let bottom = f64::from(green[0].2);
    // Not the legend swatch: the bar standing on the baseline.
    let bar_px = |k: usize| {
        bars(&img, BAR_COLORS[k], 2)
            .into_iter()
            .find(|b| f64::from(b.2) + 2.0 >= bottom)
            .unwrap()
    };
    // The bar's top row may be under its mark, so measure the taller, mark-free one.
    let scale = (bottom + 1.0 - f64::from(bar_px(0).3)) / 80.0;
    assert!(scale > 3.0, "{scale}");
    let mut spans = Vec::new();
    for k in 0..6 {
        let (x0, x1, _, _) = bar_px(k);
        let marks = row_groups(&full_rows(&img, x0, x1, REFERENCE_COLOR));
        // One mark per bar (none of these references is 0, so none is at the axis line).
        let marks: Vec<_> = marks
            .into_iter()
            .filter(|m| f64::from(m.1) < bottom)
            .collect();
        assert_eq!(marks.len(), 1, "metric {k}: {marks:?}");
        let centre = f64::from(marks[0].0 + marks[0].1) / 2.0;
        let expect = bottom + 0.5 - reference[k] * scale;
        assert!(
            (centre - expect).abs() <= 1.5,
            "metric {k}: mark at row {centre}, expected {expect}"
        );
        // The mark is no wider than its bar: the columns just outside are not black.
        let y = marks[0].0;
        for x in [x0 - 1, x1 + 1] {
            assert_ne!(
                img.get_pixel(x, y).0,
                REFERENCE_COLOR,
                "metric {k} at x {x}"
            );
        }
        spans.push((x0, x1));
        // A mark inside its bar leaves bar colour above and below it.
        if reference[k] < values[k] {
            let xm = (x0 + x1) / 2;
            let (above, below) = (marks[0].0 - 1, marks[0].1 + 1);
            assert_eq!(img.get_pixel(xm, above).0, BAR_COLORS[k], "metric {k}");
            assert_eq!(img.get_pixel(xm, below).0, BAR_COLORS[k], "metric {k}");
        }
    }
    for w in spans.windows(2) {
        assert!(w[0].1 + 2 <= w[1].0, "bars (and marks) touch: {spans:?}");
    }

    // Seven groups of six equal references on a wide chart (the CLI's): every mark is its
    // own run in the row, separated from its neighbours.
    let rows: Vec<TableRow> = (0..7)
        .map(|i| row(&format!("G{i}"), [20, 10, 5, 5, 5, 5], Some([40.0; 6])))
        .collect();
    plot_thesis_table(&rows, &size(1400, 700), &out).unwrap();
    let img = read_png(&out);
    let first = bars(&img, BAR_COLORS[0], 40)[0];
    let (x0, x1, _, _) = first;
    let mark_rows = full_rows(&img, x0, x1, REFERENCE_COLOR);
    let mark = row_groups(&mark_rows)
        .into_iter()
        .find(|m| m.1 < first.3)
        .unwrap();
    // Right of the y axis (its tick at 40 is black too).
    let runs: Vec<_> = row_runs(&img, (mark.0 + mark.1) / 2, REFERENCE_COLOR, 5)
        .into_iter()
        .filter(|r| r.0 >= x0)
        .collect();
    assert_eq!(runs.len(), 42, "{runs:?}");
    for w in runs.windows(2) {
        assert!(w[0].1 + 2 <= w[1].0, "marks touch: {runs:?}");
    }
}

#[test]
fn any_metrics_can_be_charted_and_bad_charts_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("g.png");
    let chart = BarChart {
        metrics: vec![
            BarMetric::new("recall", "parts found", Better::Higher),
            BarMetric::new("false best", "first pick wrong", Better::Lower),
            BarMetric::new("FP/scan", "false positives per scan", Better::Lower),
            BarMetric::new("starvation", "scans without a pick", Better::Lower),
        ],
        groups: vec![
            BarGroup {
                name: "brackets".into(),
                note: "30 scans".into(),
                values: vec![2.0, 0.5, 1.5, 0.0],
                reference: Some(vec![2.5, f64::NAN, 1.0, 0.0]),
            },
            BarGroup {
                name: "flanges".into(),
                note: String::new(),
                values: vec![1.0, 0.25, 0.0, 0.75],
                reference: None,
            },
        ],
        y_desc: "count per scan".into(),
        x_desc: "part family".into(),
        reference_name: "baseline".into(),
        decimals: 2,
        y_top_at_least: 0.0,
        notes: vec![],
    };
    plot_bar_chart(&chart, &size(800, 450), &out).unwrap();
    let img = read_png(&out);
    // The axis fits the data (2.5 at most), so the tallest bar (2.0) fills most of it.
    let green = bars(&img, BAR_COLORS[0], 40);
    assert_eq!(green.len(), 2, "{green:?}");
    let h0 = green[0].2 - green[0].3;
    assert!(h0 > 180, "{green:?}");
    let ratio = f64::from(h0 + 1) / f64::from(green[1].2 - green[1].3 + 1);
    assert!((ratio - 2.0).abs() < 0.05, "{green:?}");

    let bad = |f: &dyn Fn(&mut BarChart)| {
        let mut c = chart.clone();
        f(&mut c);
        plot_bar_chart(&c, &size(400, 300), &out)
    };
    for (what, r) in [
        (
            "length",
            bad(&|c| {
                c.groups[1].values.pop();
            }),
        ),
        ("negative", bad(&|c| c.groups[0].values[2] = -1.0)),
        ("infinite", bad(&|c| c.groups[0].values[2] = f64::INFINITY)),
        (
            "reference length",
            bad(&|c| c.groups[0].reference = Some(vec![1.0])),
        ),
        (
            "too many metrics",
            bad(&|c| c.metrics = vec![c.metrics[0].clone(); 11]),
        ),
        ("decimals", bad(&|c| c.decimals = 9)),
    ] {
        assert!(
            matches!(r, Err(VizError::InvalidOption(_))),
            "{what}: {r:?}"
        );
    }
    let r = bad(&|c| c.groups.clear());
    assert!(matches!(r, Err(VizError::NoData(_))), "{r:?}");
    let r = bad(&|c| c.metrics.clear());
    assert!(matches!(r, Err(VizError::NoData(_))), "{r:?}");
    // The error names the group.
    let r = bad(&|c| c.groups[1].values[0] = -2.0);
    assert!(format!("{}", r.unwrap_err()).contains("flanges"));
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
    let median_x = cols(MEDIAN_COLOR);
    let p95_x = cols(P95_COLOR);
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
