#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use binpick_cloud::PointCloud;
use binpick_viz::{ColorBy, PixelRect, Placed, RenderOptions, VizError, rank_color, render_png};
use common::{at, floor, plate, read_png};

fn opts(w: u32, h: u32) -> RenderOptions {
    RenderOptions {
        width: w,
        height: h,
        ..RenderOptions::default()
    }
}

fn placed(rank: usize, pose: nalgebra::Isometry3<f64>) -> Placed {
    Placed {
        rank,
        pose,
        final_score: 2.5,
        initial_score: 300.0,
        seen: None,
        free_to_pick: true,
    }
}

/// Saturated red of rank 1 (230, 25, 75), possibly darkened by the depth shading.
fn is_red(p: &image::Rgb<u8>) -> bool {
    let [r, g, b] = p.0;
    r > 100 && f32::from(r) > 3.0 * f32::from(g) && f32::from(r) > 1.8 * f32::from(b)
}

/// Red pixels in a rectangle: count and centroid.
fn red_in(img: &image::RgbImage, rect: &PixelRect) -> (usize, [f64; 2]) {
    let (mut n, mut sx, mut sy) = (0usize, 0.0, 0.0);
    for y in rect.y..rect.y + rect.height {
        for x in rect.x..rect.x + rect.width {
            if is_red(img.get_pixel(x, y)) {
                n += 1;
                sx += f64::from(x) + 0.5;
                sy += f64::from(y) + 0.5;
            }
        }
    }
    (n, [sx / n.max(1) as f64, sy / n.max(1) as f64])
}

fn red_near(img: &image::RgbImage, p: [f64; 2], r: i64) -> usize {
    let mut n = 0;
    for dy in -r..=r {
        for dx in -r..=r {
            let (x, y) = (p[0] as i64 + dx, p[1] as i64 + dy);
            if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
                n += usize::from(is_red(img.get_pixel(x as u32, y as u32)));
            }
        }
    }
    n
}

#[test]
fn image_has_requested_size() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("a.png");
    let info = render_png(
        &floor(50.0, 2.0),
        &plate(20.0, 2.0),
        &[placed(1, at(0.0, 0.0, 1.0))],
        &opts(733, 411),
        &out,
    )
    .unwrap();
    let img = read_png(&out);
    assert_eq!((img.width(), img.height()), (733, 411));
    assert_eq!((info.width, info.height), (733, 411));
    assert_eq!(info.views.len(), 2);
    // The two views sit side by side, inside the image, without overlapping.
    let (a, b) = (info.views[0].plot, info.views[1].plot);
    assert!(a.x + a.width <= b.x, "{a:?} {b:?}");
    assert!(b.x + b.width <= 733 && a.y + a.height <= 411 && b.y + b.height <= 411);
}

#[test]
fn model_pixels_appear_where_the_pose_puts_them_and_move_with_it() {
    let dir = tempfile::tempdir().unwrap();
    let scene = floor(100.0, 2.0);
    let model = plate(30.0, 1.0);
    let o = opts(1000, 500);
    let mut centroids = Vec::new();
    for (k, (x, y)) in [(50.0, -40.0), (-45.0, 50.0)].into_iter().enumerate() {
        let out = dir.path().join(format!("m{k}.png"));
        let info = render_png(&scene, &model, &[placed(1, at(x, y, 1.0))], &o, &out).unwrap();
        let img = read_png(&out);
        assert_eq!(info.colors, vec![rank_color(1)]);
        for v in &info.views {
            // Points of the plate away from the rank label are drawn in the rank colour ...
            for (dx, dy) in [(-11.0, -11.0), (11.0, -11.0), (-11.0, 11.0), (11.0, 11.0)] {
                let p = v.project([x + dx, y + dy, 1.0]);
                assert!(v.plot.contains(p[0], p[1]));
                assert!(
                    red_near(&img, p, 1) >= 5,
                    "{} view: no model colour at {p:?} for plate at ({x}, {y})",
                    v.name
                );
            }
            // ... and floor far from the plate is not.
            for (fx, fy) in [(-x, -y), (x, -y), (-x, y)] {
                let p = v.project([fx, fy, 0.0]);
                assert_eq!(
                    red_near(&img, p, 4),
                    0,
                    "{} view: model colour at {p:?}",
                    v.name
                );
            }
        }
        // Independent of ViewInfo: in the scanner view (looking down -z, x right, y up)
        // the red pixels sit where the plate is relative to the floor's pixel extent.
        let v = &info.views[0];
        let (n, c) = red_in(&img, &v.plot);
        assert!(n > 100, "only {n} red pixels");
        let floor_px = floor_extent(&img, &v.plot);
        let ex = floor_px[0] + (x + 100.0) / 200.0 * (floor_px[2] - floor_px[0]);
        let ey = floor_px[1] + (100.0 - y) / 200.0 * (floor_px[3] - floor_px[1]);
        assert!(
            (c[0] - ex).abs() < 6.0 && (c[1] - ey).abs() < 6.0,
            "red centroid {c:?}, expected about ({ex}, {ey}); floor {floor_px:?}"
        );
        // The label is drawn at the part.
        let l = v.labels[0].unwrap();
        assert!((l[0] - ex).abs() < 4.0 && (l[1] - ey).abs() < 4.0);
        centroids.push(c);
    }
    assert!(centroids[0][0] > centroids[1][0] + 100.0);
    assert!(centroids[0][1] > centroids[1][1] + 100.0);
}

/// Pixel bounds (x0, y0, x1, y1) of the floor (lowest scene colour) inside `rect`.
fn floor_extent(img: &image::RgbImage, rect: &PixelRect) -> [f64; 4] {
    let mut b = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
    for y in rect.y + 1..rect.y + rect.height - 1 {
        for x in rect.x + 1..rect.x + rect.width - 1 {
            // The low end of the scene's height ramp, a dark slate blue (62, 68, 84); greys
            // of anti-aliased black overlays have r = g = b and do not count.
            let [r, g, bl] = img.get_pixel(x, y).0.map(i32::from);
            if bl >= r + 12 && bl >= g + 6 && bl > 40 && bl < 150 {
                b[0] = b[0].min(f64::from(x));
                b[1] = b[1].min(f64::from(y));
                b[2] = b[2].max(f64::from(x) + 1.0);
                b[3] = b[3].max(f64::from(y) + 1.0);
            }
        }
    }
    b
}

#[test]
fn oblique_view_lifts_raised_parts() {
    let dir = tempfile::tempdir().unwrap();
    let scene = floor(100.0, 2.0);
    let model = plate(30.0, 1.0);
    let o = opts(1000, 500);
    let mut ys = Vec::new();
    for z in [1.0, 60.0] {
        let out = dir.path().join(format!("z{z}.png"));
        let info = render_png(&scene, &model, &[placed(1, at(0.0, 0.0, z))], &o, &out).unwrap();
        let img = read_png(&out);
        let (top, obl) = (&info.views[0], &info.views[1]);
        // Seen from above the plate does not move, seen obliquely it rises on screen.
        let (n_top, c_top) = red_in(&img, &top.plot);
        let (n_obl, c_obl) = red_in(&img, &obl.plot);
        assert!(n_top > 100 && n_obl > 100);
        let fe = floor_extent(&img, &top.plot);
        assert!((c_top[0] - (fe[0] + fe[2]) / 2.0).abs() < 5.0);
        assert!((c_top[1] - (fe[1] + fe[3]) / 2.0).abs() < 5.0);
        ys.push((c_obl[1] - obl.project([0.0, 0.0, 0.0])[1]) / obl.px_per_mm);
    }
    // 60 mm up at 40 degrees elevation is about 60 cos(40) = 46 mm higher on screen.
    let lift = ys[0] - ys[1];
    assert!(
        (lift - 60.0 * 40f64.to_radians().cos()).abs() < 4.0,
        "lift {lift} mm"
    );
}

#[test]
fn zero_detections_still_renders_the_scene() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("none.png");
    let scene = floor(80.0, 2.0);
    // No detections: an empty model is fine.
    let info = render_png(&scene, &PointCloud::default(), &[], &opts(800, 400), &out).unwrap();
    let img = read_png(&out);
    assert_eq!(info.detections_drawn, 0);
    assert_eq!(info.legend_rows, 0);
    assert_eq!(info.scene_points, scene.len());
    for v in &info.views {
        let fe = floor_extent(&img, &v.plot);
        assert!(
            fe[2] - fe[0] > 100.0,
            "{} view: floor not drawn: {fe:?}",
            v.name
        );
        assert!(v.labels.is_empty());
    }
    // "no detections" is written in dark red in both views and the legend.
    let msg = img
        .pixels()
        .filter(|p| p.0[0] > 120 && p.0[1] < 60 && p.0[2] < 60)
        .count();
    assert!(msg > 200, "{msg} message pixels");
}

#[test]
fn a_first_detection_not_free_to_pick_is_said_to_give_no_pick() {
    let dir = tempfile::tempdir().unwrap();
    let scene = floor(80.0, 2.0);
    let model = plate(30.0, 1.0);
    // Dark red message pixels, anti-aliased on white: red well above green, green and blue
    // alike (rank 1's red has more blue than green).
    let message = |free_to_pick: bool| {
        let out = dir.path().join(format!("{free_to_pick}.png"));
        let p = [Placed {
            free_to_pick,
            ..placed(1, at(0.0, 0.0, 5.0))
        }];
        let info = render_png(&scene, &model, &p, &opts(800, 400), &out).unwrap();
        assert_eq!(info.legend_rows, 1);
        let img = read_png(&out);
        img.pixels()
            .filter(|p| {
                let [r, g, b] = p.0.map(i32::from);
                r - g > 60 && (g - b).abs() < 12
            })
            .count()
    };
    let (picked, none) = (message(true), message(false));
    assert!(none > picked + 100, "{picked} -> {none} message pixels");
}

#[test]
fn score_colouring_uses_green_for_good_and_red_for_bad() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.png");
    let o = RenderOptions {
        color_by: ColorBy::FinalScore,
        score_range: Some((0.0, 20.0)),
        ..opts(800, 400)
    };
    let mut good = placed(1, at(-40.0, 0.0, 1.0));
    good.final_score = 0.0;
    let mut bad = placed(2, at(40.0, 0.0, 1.0));
    bad.final_score = 35.0;
    let info = render_png(&floor(80.0, 2.0), &plate(30.0, 1.0), &[good, bad], &o, &out).unwrap();
    let [g, r] = [info.colors[0], info.colors[1]];
    assert!(g[1] > g[0] && g[1] > g[2], "{g:?}");
    assert!(r[0] > r[1] && r[0] > r[2], "{r:?}");
    let img = read_png(&out);
    let v = &info.views[0];
    let p = v.project([-40.0 + 11.0, 11.0, 1.0]);
    let c = img.get_pixel(p[0] as u32, p[1] as u32).0;
    assert!(
        c[1] > c[0] + 40 && c[1] > c[2] + 40,
        "good part pixel {c:?}"
    );
    let p = v.project([40.0 + 11.0, 11.0, 1.0]);
    let c = img.get_pixel(p[0] as u32, p[1] as u32).0;
    assert!(c[0] > c[1] + 40 && c[0] > c[2] + 40, "bad part pixel {c:?}");
}

#[test]
fn occluded_detection_shows_through_faintly() {
    let dir = tempfile::tempdir().unwrap();
    // A plate 20 mm under a raised scene slab: hidden from above, drawn "x-ray".
    let mut scene = floor(80.0, 2.0);
    scene
        .points
        .extend(plate(60.0, 1.5).transformed(&at(0.0, 0.0, 20.0)).points);
    let model = plate(30.0, 1.0);
    let p = [placed(1, at(0.0, 30.0, 1.0))];
    for (show, expect_tint) in [(true, true), (false, false)] {
        let out = dir.path().join(format!("x{show}.png"));
        let o = RenderOptions {
            show_occluded: show,
            ..opts(800, 400)
        };
        let info = render_png(&scene, &model, &p, &o, &out).unwrap();
        let img = read_png(&out);
        let v = &info.views[0];
        // Under the slab (y = 20, covered) vs beside it (y = 40, visible).
        let hidden = img.get_pixel_checked(
            v.project([-10.0, 22.0, 20.0])[0] as u32,
            v.project([-10.0, 22.0, 20.0])[1] as u32,
        );
        let c = hidden.unwrap().0;
        let tinted = i32::from(c[0]) > i32::from(c[1]) + 25;
        assert_eq!(tinted, expect_tint, "show_occluded={show}: pixel {c:?}");
        assert!(red_near(&img, v.project([-10.0, 40.0, 1.0]), 1) >= 5);
    }
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("e.png");
    let scene = floor(20.0, 2.0);
    let model = plate(10.0, 2.0);
    let one = [placed(1, at(0.0, 0.0, 0.0))];
    let r = render_png(&PointCloud::default(), &model, &one, &opts(200, 200), &out);
    assert!(
        matches!(r, Err(VizError::EmptyScene { non_finite: 0 })),
        "{r:?}"
    );
    let nan_scene = PointCloud::new(vec![[f32::NAN, 0.0, 0.0]; 3]);
    let r = render_png(&nan_scene, &model, &one, &opts(200, 200), &out);
    assert!(
        matches!(r, Err(VizError::EmptyScene { non_finite: 3 })),
        "{r:?}"
    );
    let r = render_png(&scene, &PointCloud::default(), &one, &opts(200, 200), &out);
    assert!(matches!(r, Err(VizError::EmptyModel { .. })), "{r:?}");
    for (w, h) in [(0, 100), (63, 100), (100, 8193), (u32::MAX, u32::MAX)] {
        let r = render_png(&scene, &model, &one, &opts(w, h), &out);
        assert!(matches!(r, Err(VizError::BadSize { .. })), "{w}x{h}: {r:?}");
    }
    let bad = [
        RenderOptions {
            up: [0.0, 0.0, 0.0],
            ..opts(200, 200)
        },
        RenderOptions {
            up: [f64::NAN, 0.0, 1.0],
            ..opts(200, 200)
        },
        RenderOptions {
            view_dir: Some([0.0, 0.0, 0.0]),
            ..opts(200, 200)
        },
        RenderOptions {
            oblique_elevation_deg: f64::NAN,
            ..opts(200, 200)
        },
        RenderOptions {
            score_range: Some((5.0, 5.0)),
            ..opts(200, 200)
        },
    ];
    for o in &bad {
        let r = render_png(&scene, &model, &one, o, &out);
        assert!(matches!(r, Err(VizError::InvalidOption(_))), "{o:?}: {r:?}");
    }
    assert!(!out.exists(), "no file is written on error");
    // Writing into a missing directory is an I/O error.
    let r = render_png(
        &scene,
        &model,
        &one,
        &opts(200, 200),
        &dir.path().join("no/such.png"),
    );
    assert!(matches!(r, Err(VizError::Io { .. })), "{r:?}");
}

#[test]
fn odd_but_valid_inputs_render() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("odd.png");
    // NaN points are skipped and counted; a NaN pose is listed but not drawn.
    let mut scene = floor(20.0, 2.0);
    scene.points.push([f32::NAN, 1.0, 2.0]);
    scene.points.push([f32::INFINITY, 1.0, 2.0]);
    let mut model = plate(10.0, 2.0);
    model.points.push([0.0, f32::NAN, 0.0]);
    let mut nan_pose = at(0.0, 0.0, 0.0);
    nan_pose.translation.vector.x = f64::NAN;
    let list = [placed(1, at(0.0, 0.0, 0.5)), placed(2, nan_pose)];
    let info = render_png(&scene, &model, &list, &opts(64, 64), &out).unwrap();
    assert_eq!(info.scene_non_finite, 2);
    assert_eq!(info.model_non_finite, 1);
    assert_eq!(info.detections_drawn, 1);
    assert_eq!(info.detections_skipped, vec![1]);
    assert_eq!(read_png(&out).dimensions(), (64, 64));
    // A single point, a sideways up vector, a tilted scanner, many detections, a huge image.
    let single = PointCloud::new(vec![[5.0, 5.0, 5.0]]);
    let many: Vec<Placed> = (1..=40)
        .map(|k| placed(k, at(f64::from(k as u32) * 3.0, 0.0, 0.0)))
        .collect();
    for (s, o, p) in [
        (&single, opts(300, 200), &list[..1]),
        (
            &scene,
            RenderOptions {
                up: [0.0, 1.0, 0.0],
                ..opts(300, 200)
            },
            &list[..],
        ),
        (
            &scene,
            RenderOptions {
                view_dir: Some([0.3, 0.1, -1.0]),
                oblique_elevation_deg: 90.0,
                ..opts(300, 200)
            },
            &list[..],
        ),
        (&scene, opts(400, 200), &many[..]),
        (&scene, opts(8192, 64), &list[..]),
    ] {
        let info = render_png(s, &model, p, &o, &out).unwrap();
        assert_eq!(read_png(&out).dimensions(), (o.width, o.height));
        assert!(info.legend_rows <= p.len());
    }
}

#[test]
fn output_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let scene = floor(60.0, 1.5);
    let model = plate(20.0, 1.0);
    let list = [
        placed(1, common::rotated_z(10.0, 5.0, 1.0, 30.0)),
        placed(2, common::rotated_z(-20.0, -15.0, 1.0, -60.0)),
    ];
    let a = dir.path().join("a.png");
    let b = dir.path().join("b.png");
    render_png(&scene, &model, &list, &opts(600, 300), &a).unwrap();
    render_png(&scene, &model, &list, &opts(600, 300), &b).unwrap();
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
}
