//! Renders synthetic bins of bent-sheet brackets to PNG (five parts on a bin floor with four
//! detections, one of them misaligned; a pile of 16 scanned from above with 13 detections),
//! a labelled PLY and the two eval plots.
//!
//! ```text
//! cargo run -p binpick-viz --release --example demo -- [OUT_DIR]
//! ```
//! Writes `demo.png`, `demo_score.png`, `demo_pile.png`, `demo.ply`, `demo_table.png`,
//! `demo_bars.png` and `demo_times.png` into OUT_DIR (default: the system temp directory).
//! `examples/demo_pile.png` and `examples/demo_table.png` beside this file are that run's
//! `demo_pile.png` and `demo_table.png`.

use std::error::Error;
use std::path::PathBuf;

use binpick_cloud::PointCloud;
use binpick_viz::{
    BarChart, BarGroup, BarMetric, Better, ColorBy, Percents, Placed, PlotOptions, RenderOptions,
    TableRow, plot_bar_chart, plot_time_histogram, render_png, write_labelled_ply,
};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// Deterministic noise in -0.5..0.5 from an integer.
fn noise(i: u64) -> f32 {
    let mut x = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
    x ^= x >> 31;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 29;
    (x % 10_000) as f32 / 10_000.0 - 0.5
}

/// An L-shaped bent sheet (thesis part A-like): 50 mm wide, legs 60 mm (along x, in the
/// model's x-y plane) and 70 mm (up along z), sampled every 1.5 mm on its outer surface.
fn bracket() -> PointCloud {
    let step = 1.5f32;
    let mut pts = Vec::new();
    let w = 50.0f32;
    let mut y = 0.0;
    while y <= w {
        let mut x = 0.0;
        while x <= 60.0 {
            pts.push([x, y, 0.0]);
            x += step;
        }
        let mut z = step;
        while z <= 70.0 {
            pts.push([0.0, y, z]);
            z += step;
        }
        y += step;
    }
    // Centre the model on its bounding box.
    let c = [30.0, 25.0, 35.0];
    PointCloud::new(
        pts.iter()
            .map(|p| [p[0] - c[0], p[1] - c[1], p[2] - c[2]])
            .collect(),
    )
}

fn pose(x: f64, y: f64, z: f64, roll: f64, pitch: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(roll.to_radians(), pitch.to_radians(), yaw.to_radians()),
    )
}

fn main() -> Result<(), Box<dyn Error>> {
    let out: PathBuf = std::env::args_os()
        .nth(1)
        .map_or_else(std::env::temp_dir, PathBuf::from);
    std::fs::create_dir_all(&out)?;
    let model = bracket();

    // Parts: lying on the long leg (leg 2 standing up), on the short leg, on the side.
    let truth = [
        pose(-90.0, -40.0, 35.0, 0.0, 0.0, 20.0),
        pose(10.0, 30.0, 25.0, 0.0, 90.0, -35.0),
        pose(100.0, -30.0, 25.0, 90.0, 0.0, 70.0),
        pose(-20.0, -55.0, 35.0, 0.0, 0.0, 160.0),
        pose(95.0, 60.0, 25.0, 0.0, -90.0, 120.0),
    ];
    let mut scene = Vec::new();
    // Floor 320 x 220 mm every 2 mm, with 0.3 mm of noise, and a 40 mm bin wall.
    let mut i = 0u64;
    let (hx, hy) = (160.0f32, 110.0f32);
    let mut x = -hx;
    while x <= hx {
        let mut y = -hy;
        while y <= hy {
            i += 1;
            scene.push([x, y, 0.3 * noise(i)]);
            y += 2.0;
        }
        x += 2.0;
    }
    let mut z = 2.0f32;
    while z <= 40.0 {
        let mut t = -hx;
        while t <= hx {
            scene.push([t, -hy, z]);
            scene.push([t, hy, z]);
            t += 2.0;
        }
        let mut t = -hy;
        while t <= hy {
            scene.push([-hx, t, z]);
            scene.push([hx, t, z]);
            t += 2.0;
        }
        z += 2.0;
    }
    for p in &truth {
        for m in model.transformed(p).points {
            i += 1;
            scene.push([
                m[0] + 0.4 * noise(i),
                m[1] + 0.4 * noise(i + 7),
                m[2] + 0.4 * noise(i + 13),
            ]);
        }
    }
    scene.push([f32::NAN, 0.0, 0.0]); // the renderer skips and counts it
    let scene = PointCloud::new(scene);

    // Detections: ranks by final score; rank 3 is off by 4 mm and 6 deg; the fifth part is
    // not found.
    let nudge = Isometry3::new(Vector3::new(4.0, -3.0, 0.0), Vector3::new(0.0, 0.0, 0.1));
    let placed = vec![
        Placed {
            rank: 1,
            pose: truth[0],
            final_score: 1.8,
            initial_score: 412.0,
            seen: None,
            free_to_pick: true,
        },
        Placed {
            rank: 2,
            pose: truth[3],
            final_score: 3.5,
            initial_score: 388.5,
            seen: None,
            free_to_pick: true,
        },
        Placed {
            rank: 3,
            pose: nudge * truth[2],
            final_score: 14.2,
            initial_score: 251.0,
            seen: None,
            free_to_pick: true,
        },
        Placed {
            rank: 4,
            pose: truth[1],
            final_score: 6.9,
            initial_score: 301.2,
            seen: None,
            free_to_pick: true,
        },
    ];
    let opts = RenderOptions {
        title: Some("demo: 5 brackets in a bin".into()),
        ..RenderOptions::default()
    };
    let info = render_png(&scene, &model, &placed, &opts, &out.join("demo.png"))?;
    println!(
        "demo.png: {}x{}, scene {} points ({} non-finite skipped), point radius {} / {} px",
        info.width,
        info.height,
        info.scene_points,
        info.scene_non_finite,
        info.views[0].scene_radius_px,
        info.views[1].scene_radius_px
    );
    let opts_score = RenderOptions {
        color_by: ColorBy::FinalScore,
        score_range: Some((0.0, 20.0)),
        width: 1200,
        height: 600,
        title: Some("demo, coloured by final score".into()),
        ..RenderOptions::default()
    };
    render_png(
        &scene,
        &model,
        &placed,
        &opts_score,
        &out.join("demo_score.png"),
    )?;
    let ply = write_labelled_ply(&scene, &model, &placed, 2.0, &out.join("demo.ply"))?;
    println!(
        "demo.ply: explained per detection {:?}, unexplained {}",
        ply.explained, ply.unexplained
    );

    // A cluttered pile: 16 brackets in pseudo-random poses, the scanner seeing only what is
    // visible from above (a 1.5 mm height-map sampling), 13 detections with close labels.
    let mut parts = Vec::new();
    for k in 0..16u64 {
        let a = |j: u64| f64::from(noise(k * 7 + j));
        parts.push(pose(
            a(1) * 220.0,
            a(2) * 150.0,
            30.0 + 40.0 * (a(3) + 0.5),
            a(4) * 120.0,
            a(5) * 120.0,
            a(6) * 360.0,
        ));
    }
    let mut pile = Vec::new();
    let cell = 1.5f32;
    let mut top = std::collections::HashMap::new();
    let mut put = |p: [f32; 3]| {
        let key = ((p[0] / cell).floor() as i32, (p[1] / cell).floor() as i32);
        let e = top.entry(key).or_insert(p);
        if p[2] > e[2] {
            *e = p;
        }
    };
    let mut x = -hx;
    while x <= hx {
        let mut y = -hy;
        while y <= hy {
            put([x, y, 0.0]);
            y += cell;
        }
        x += cell;
    }
    for p in &parts {
        for m in model.transformed(p).points {
            put(m);
        }
    }
    let mut keys: Vec<_> = top.keys().copied().collect();
    keys.sort_unstable();
    for k in keys {
        if let Some(p) = top.get(&k) {
            pile.push(*p);
        }
    }
    let pile = PointCloud::new(pile);
    let found: Vec<Placed> = parts
        .iter()
        .take(13)
        .enumerate()
        .map(|(i, p)| Placed {
            rank: i + 1,
            pose: *p,
            final_score: 1.0 + i as f64 * 1.3,
            initial_score: 420.0 - i as f64 * 17.0,
            seen: None,
            free_to_pick: true,
        })
        .collect();
    let opts_pile = RenderOptions {
        width: 1200,
        height: 600,
        title: Some("demo: a pile of 16 brackets, scanned from above".into()),
        ..RenderOptions::default()
    };
    render_png(
        &pile,
        &model,
        &found,
        &opts_pile,
        &out.join("demo_pile.png"),
    )?;

    // Fake counts and a fake reference (not the thesis's numbers: the caller owns those).
    // Zeros, a reference equal to the bar, a reference at zero and a missing one show how
    // the chart keeps each readable.
    let fake_reference = |c: &str| -> Option<Percents> {
        let v = match c {
            "A" => [85.0, 15.0, 5.0, 20.0, 0.0, 2.5],
            "B" => [75.9, 24.1, 0.0, 10.0, 0.0, f64::NAN],
            "C1" => [60.0, 40.0, 45.0, 15.0, 20.0, 10.0],
            "C2" => [80.0, 20.0, 60.0, 30.0, 15.0, 5.0],
            _ => return None,
        };
        Some(Percents {
            recognition: v[0],
            false_negatives: v[1],
            false_positives: v[2],
            unpickable: v[3],
            false_best: v[4],
            starvation: v[5],
        })
    };
    let rows: Vec<TableRow> = [
        ("A", 40, 102, 90, 12, 2, 8, 0, 1),
        ("B", 40, 79, 60, 19, 0, 6, 0, 2),
        ("C1", 40, 80, 50, 30, 15, 6, 7, 3),
        ("C2", 40, 80, 66, 14, 22, 10, 6, 0),
        ("C3", 40, 149, 110, 39, 14, 9, 5, 1),
        ("empty", 0, 0, 0, 0, 0, 0, 0, 0),
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
        reference: fake_reference(c),
    })
    .collect();
    let mut table = BarChart::thesis_table(&rows);
    table.reference_name = "reference (fake)".into();
    plot_bar_chart(
        &table,
        &PlotOptions {
            title: Some("demo: table per configuration (fake data)".into()),
            ..PlotOptions::default()
        },
        &out.join("demo_table.png"),
    )?;
    // Any metrics: a generalisation benchmark per part family, two of them with a reference.
    let bench = BarChart {
        metrics: vec![
            BarMetric::new("recall", "parts found", Better::Higher),
            BarMetric::new("false best", "first pick wrong", Better::Lower),
            BarMetric::new("FP/scan", "false positives per scan x10", Better::Lower),
            BarMetric::new("starvation", "scans with no pick", Better::Lower),
        ],
        groups: vec![
            BarGroup {
                name: "brackets".into(),
                note: "30 scans".into(),
                values: vec![92.5, 3.3, 4.0, 0.0],
                reference: Some(vec![90.0, 5.0, f64::NAN, 0.0]),
            },
            BarGroup {
                name: "flanges".into(),
                note: "30 scans".into(),
                values: vec![71.0, 10.0, 13.0, 6.7],
                reference: Some(vec![75.0, 10.0, f64::NAN, 3.3]),
            },
            BarGroup {
                name: "pipes".into(),
                note: "12 scans".into(),
                values: vec![48.2, 0.0, 25.0, 16.7],
                reference: None,
            },
        ],
        y_desc: "percent of parts or scans (%), FP per 10 scans".into(),
        x_desc: "part family".into(),
        reference_name: "baseline (fake)".into(),
        decimals: 1,
        y_top_at_least: 100.0,
        notes: vec!["fake numbers".into()],
    };
    plot_bar_chart(
        &bench,
        &PlotOptions {
            width: 1000,
            height: 560,
            title: Some("demo: any metrics per group (fake data)".into()),
        },
        &out.join("demo_bars.png"),
    )?;
    let times: Vec<f64> = (0..200u64)
        .map(|k| 350.0 + 120.0 * f64::from(noise(k)) + if k % 17 == 0 { 400.0 } else { 0.0 })
        .collect();
    let st = plot_time_histogram(&times, &PlotOptions::default(), &out.join("demo_times.png"))?;
    println!("times: median {:.1} ms, p95 {:.1} ms", st.median, st.p95);
    println!("wrote into {}", out.display());
    Ok(())
}
