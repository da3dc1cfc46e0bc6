//! The scene-voting engine's verification on a real generalisation scan: Z brackets on a
//! belt (binpick-synth, the same generator as `binpick synth generalisation`), the part given
//! as its CAD mesh (STL), exactly as a user would run it.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::PathBuf;

use binpick::{Params, PartSource, PointCloud, Recognizer, Units, load_part, pose};
use binpick_synth::{
    ModelLibrary, PartKind, generalisation_sets,
    generate::{write_model_cloud, write_stl},
};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

struct BeltScan {
    recognizer: Recognizer,
    scene: PointCloud,
    /// True poses (model -> scene, mm) of the parts at least half visible that show a broad
    /// side to the scanner (not standing on a sheet edge).
    pickable: Vec<Isometry3<f64>>,
    /// The pickable parts that show less than a quarter of that (a bracket standing on the
    /// edge of its sheet).
    on_edge: Vec<Isometry3<f64>>,
    /// The bracket's half turn that swaps its 30 and 35 mm flanges (model frame).
    near_symmetry: Isometry3<f64>,
    diameter_mm: f64,
    /// The part's STL, in `_dir`.
    part_file: PathBuf,
    _dir: tempfile::TempDir,
}

impl BeltScan {
    /// Whether `d` lies within a tenth of the part's diameter of `truth`.
    fn near(&self, truth: &Isometry3<f64>, d: &binpick::Detection) -> bool {
        pose::translation_error_mm(truth, &d.pose) < 0.1 * self.diameter_mm
    }

    /// Whether `r` reports a part at `truth` within 10 deg.
    fn reported_right(&self, r: &binpick::Recognition, truth: &Isometry3<f64>) -> bool {
        r.detections
            .iter()
            .any(|d| self.near(truth, d) && pose::rotation_error_deg(truth, &d.pose) < 10.0)
    }

    /// Fails naming the pickable parts `r` reports half turned.
    fn assert_none_turned(&self, r: &binpick::Recognition) {
        let turned = self.reported_turned(r);
        assert!(
            turned.is_empty(),
            "pickable brackets reported turned: {turned:?}"
        );
    }

    /// The pickable parts `r` reports half turned: near the truth, more than 150 deg off.
    fn reported_turned(&self, r: &binpick::Recognition) -> Vec<&Isometry3<f64>> {
        self.pickable
            .iter()
            .filter(|t| {
                r.detections
                    .iter()
                    .any(|d| self.near(t, d) && pose::rotation_error_deg(t, &d.pose) > 150.0)
            })
            .collect()
    }

    /// A recognizer for the same part on the default parameters as `change` leaves them.
    fn recognizer_with(&self, change: impl FnOnce(&mut Params)) -> Recognizer {
        let mut params = Params::default();
        change(&mut params);
        let (part, _) = load_part(&self.part_file, Units::Millimetres, &params).unwrap();
        Recognizer::with_part(part, params).unwrap()
    }
}

/// Scan `index` of the generalisation benchmark's `brackets-belt-1mm` set (seed 1).
fn belt_scan(index: usize) -> BeltScan {
    bracket_scan("brackets-belt-1mm", index)
}

/// Scan `index` of the generalisation benchmark's bracket set `set_name` (seed 1).
fn bracket_scan(set_name: &str, index: usize) -> BeltScan {
    set_scan(PartKind::Bracket, set_name, index, Params::default())
}

/// Scan `index` of the generalisation benchmark's set `set_name` of `kind` (seed 1), with a
/// recognizer on `params`.
fn set_scan(kind: PartKind, set_name: &str, index: usize, params: Params) -> BeltScan {
    seeded_scan(kind, set_name, 1, index, params)
}

/// Scan `index` of the generalisation benchmark's set `set_name` of `kind` made with `seed`
/// (`binpick synth generalisation --seed`), with a recognizer on `params`.
fn seeded_scan(
    kind: PartKind,
    set_name: &str,
    seed: u64,
    index: usize,
    params: Params,
) -> BeltScan {
    let s = seeded_scan_of_any(kind, set_name, seed, index, params);
    assert!(
        s.pickable.len() >= 2,
        "the scan has {} pickable parts",
        s.pickable.len()
    );
    s
}

/// As [`seeded_scan`], whatever number of pickable parts the scan has.
fn seeded_scan_of_any(
    kind: PartKind,
    set_name: &str,
    seed: u64,
    index: usize,
    params: Params,
) -> BeltScan {
    let lib = ModelLibrary::build_for(&[kind], false).unwrap();
    let model = &lib.models[0];
    let set = generalisation_sets(Some(index + 1))
        .into_iter()
        .find(|s| s.name == set_name)
        .unwrap();
    let scan =
        binpick_synth::generalisation::make_set_scene(&lib, &[model], &set, seed, index).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let stl: PathBuf = dir.path().join("part.stl");
    write_stl(&stl, &model.mesh).unwrap();
    let (part, _) = load_part(&stl, Units::Millimetres, &params).unwrap();
    let diameter_mm = part.size.diameter_mm;
    let instances = &scan.gt[0].instances;
    let most_seen = instances
        .iter()
        .filter_map(|i| i.alone_points)
        .max()
        .unwrap_or(0);
    let broad_side =
        |i: &&binpick_cloud::dataset::GtInstance| i.alone_points.unwrap_or(0) * 4 >= most_seen;
    let poses = |keep: &dyn Fn(&&binpick_cloud::dataset::GtInstance) -> bool| {
        instances
            .iter()
            .filter(|i| i.pickable && keep(i))
            .map(|i| binpick_cloud::pose_from_row_major(&i.pose).unwrap())
            .collect::<Vec<_>>()
    };
    let pickable = poses(&broad_side);
    let on_edge = poses(&|i| !broad_side(i));
    BeltScan {
        recognizer: Recognizer::with_part(part, params).unwrap(),
        scene: scan.scan.cloud,
        pickable,
        on_edge,
        near_symmetry: lib
            .parts
            .get(kind)
            .near_symmetries()
            .first()
            .copied()
            .unwrap_or_else(Isometry3::identity),
        diameter_mm,
        part_file: stl,
        _dir: dir,
    }
}

#[test]
fn a_turned_near_symmetric_part_is_rejected() {
    let s = belt_scan(0);
    for truth in &s.pickable {
        let right = s
            .recognizer
            .check_pose(&s.scene, None, truth, true)
            .unwrap();
        assert_eq!(right.refusal, None, "true pose refused: {right:#?}");
        // Turned by the half turn that swaps the flanges, then refined by ICP: it lies on the
        // same sheet surfaces, but the flange that is 5 mm longer sticks out where the sensor
        // saw belt (free space) or misses surface it should show.
        let turned = s
            .recognizer
            .check_pose(&s.scene, None, &(truth * s.near_symmetry), true)
            .unwrap();
        assert!(
            pose::translation_error_mm(truth, &turned.pose) > 1.0
                || pose::rotation_error_deg(truth, &turned.pose) > 10.0,
            "ICP turned the pose back; the test says nothing"
        );
        assert!(
            turned.refusal.is_some(),
            "turned bracket accepted: {turned:#?}\nright pose: {right:#?}"
        );
        assert!(turned.view.fit < right.view.fit || turned.view.free_space > right.view.free_space);
    }
}

/// The part `kind` as the benchmark's top-view scan of it (`models/<name>.pcd`), written
/// beside `s`'s STL.
fn scanned_part(kind: PartKind, s: &BeltScan) -> binpick::Part {
    let lib = ModelLibrary::build_for(&[kind], false).unwrap();
    let pcd = s._dir.path().join("part.pcd");
    write_model_cloud(&pcd, &lib.models[0]).unwrap();
    let (part, _) = load_part(&pcd, Units::Millimetres, &Params::default()).unwrap();
    assert_eq!(part.source, PartSource::Scan);
    part
}

/// Seed `seed`'s scan `index` of `brackets-bin-2mm` and what defaults recognise in it.
fn recognized_in_bracket_bin(seed: u64, index: usize) -> (BeltScan, binpick::Recognition) {
    let s = seeded_scan(
        PartKind::Bracket,
        "brackets-bin-2mm",
        seed,
        index,
        Params::default(),
    );
    let r = s.recognizer.recognize(&s.scene).unwrap();
    (s, r)
}

#[test]
fn a_bracket_whose_turn_the_view_prefers_is_found_the_right_way_round() {
    // Seed 4's `brackets-bin-2mm-006`: a bracket in full view whose half turn the 2 mm view
    // scores 1.4 % above its right pose (the right pose's outline sees through 8 cells, the
    // turn's longer flange lies in a shadow). Where the two differ, at the flanges' ends,
    // the scan lies much closer to the right pose, and the scene explanation's pick is
    // settled there.
    let (s, r) = recognized_in_bracket_bin(4, 6);
    s.assert_none_turned(&r);
    let found = s
        .pickable
        .iter()
        .filter(|t| s.reported_right(&r, t))
        .count();
    assert!(
        found + 1 >= s.pickable.len(),
        "{found} of {} pickable brackets found",
        s.pickable.len()
    );
}

#[test]
fn a_bracket_whose_turn_the_sensor_sees_through_where_they_differ_is_turned_back() {
    // Seed 2's `brackets-bin-2mm-008`: a pickable bracket (63 % visible) whose half turn
    // explains a few more cells and was taken; the right pose was refused as its repeat. Where
    // the two differ the point residuals do not decide (the turn's 6.3 mm^2 against the right
    // pose's 4.4, both near the cap), but the sensor sees through 3 of the turn's 30 view
    // cells there (its longer flange laid past the part's shorter one) and through none of
    // the right pose's: the turn settling now turns it back.
    let (s, r) = recognized_in_bracket_bin(2, 8);
    s.assert_none_turned(&r);
}

#[test]
fn a_pose_laid_across_two_brackets_gives_way_to_the_closer_fitting_pose_it_displaced() {
    // Seed 13's `brackets-bin-2mm-000`: a pose turned 90 deg from a bracket standing on a
    // flange end (73 % visible) lies across it and a neighbour. It explains 543 view cells
    // against the bracket's own pose's 328 and was taken; the right pose, fitting the
    // surface they share more closely (0.84 against 0.77), was refused as its repeat. Left
    // out of the scene explanation, the pose laid across gives way to it.
    let (s, r) = recognized_in_bracket_bin(13, 0);
    let missed: Vec<&Isometry3<f64>> = s
        .pickable
        .iter()
        .chain(&s.on_edge)
        .filter(|t| !s.reported_right(&r, t))
        .collect();
    assert!(missed.is_empty(), "pickable brackets missed: {missed:?}");
    let contesting: Vec<f64> = r
        .detections
        .iter()
        .filter_map(|d| d.view.as_ref().map(|v| v.contested))
        .filter(|&c| c >= 0.6)
        .collect();
    assert!(
        contesting.is_empty(),
        "detections claiming most of a closer-fitting pose: {contesting:?}"
    );
}

#[test]
fn a_scanned_plate_at_its_true_pose_is_accepted() {
    // The bent plate's top-view scan is a lattice of 0.5 mm; sampled at one point per view
    // cell it rendered with a fifth of its cells empty, the scene carried on past a third of
    // that porous outline, and every plate lying scanned side up in this scan was refused
    // (`NoOutline`, continued 0.34-0.37 against 0.2 allowed).
    let s = set_scan(
        PartKind::Plate,
        "plates-belt-clutter-1mm",
        3,
        Params::default(),
    );
    let recognizer =
        Recognizer::with_part(scanned_part(PartKind::Plate, &s), Params::default()).unwrap();
    let mut checked = 0;
    for truth in &s.pickable {
        let check = recognizer.check_pose(&s.scene, None, truth, true).unwrap();
        if check.view.visibility < 0.9 {
            continue; // lying the other way up or on edge: the scan has no view of that
        }
        checked += 1;
        assert_eq!(check.refusal, None, "true pose refused: {check:#?}");
        assert!(check.view.continued < 0.2, "{check:#?}");
    }
    assert!(checked >= 1, "no plate lies scanned side up");
}

#[test]
fn a_scan_that_cannot_tell_a_part_from_its_turn_withholds_the_first_pick() {
    // The bracket's top-view scan (as `models/bracket.pcd` of the benchmark): the half turn
    // that swaps its flanges turns the scanned side down, so a bracket lying the other way
    // up fits the scan as that turn. On the benchmark's belts 15 % of the scan's first
    // picks were such turns; the CAD mesh, which has both sides, judges the turn.
    let s = belt_scan(0);
    let scan = scanned_part(PartKind::Bracket, &s);
    let (mesh, _) = load_part(&s.part_file, Units::Millimetres, &Params::default()).unwrap();
    assert_eq!(scan.source, PartSource::Scan);
    assert!(scan.turn_hides_scanned_side(&s.near_symmetry));
    assert!(!mesh.turn_hides_scanned_side(&s.near_symmetry));
    // A quarter turn about the scanner's axis keeps the scanned side up.
    let about_view =
        Isometry3::rotation(scan.scanned_side().unwrap() * std::f64::consts::FRAC_PI_2);
    assert!(!scan.turn_hides_scanned_side(&about_view));

    let recognize = |pick: bool| {
        let mut params = Params::default();
        params.ranking.pick_turn_ambiguous = pick;
        Recognizer::with_part(scan.clone(), params)
            .unwrap()
            .recognize(&s.scene)
            .unwrap()
    };
    let withheld = recognize(false);
    assert!(withheld.voting.as_ref().unwrap().turn_ambiguous);
    assert!(!withheld.detections.is_empty());
    assert!(
        withheld.first_pick().is_none(),
        "a first pick from an ambiguous scan"
    );
    for d in &withheld.detections {
        assert!(
            !d.free_to_pick && d.rank_reason.starts_with("withheld"),
            "{}",
            d.rank_reason
        );
    }
    // Asked for, the picks come back; the parts and their order are the same.
    let picked = recognize(true);
    assert!(picked.first_pick().is_some());
    let poses = |r: &binpick::Recognition| r.detections.iter().map(|d| d.pose).collect::<Vec<_>>();
    assert_eq!(poses(&withheld), poses(&picked));
    // The mesh is never ambiguous.
    let cad = s.recognizer.recognize(&s.scene).unwrap();
    assert!(!cad.voting.as_ref().unwrap().turn_ambiguous);
    assert!(cad.first_pick().is_some());
}

#[test]
fn poses_checked_together_are_each_judged_as_when_checked_alone() {
    let s = belt_scan(0);
    let mut poses: Vec<Isometry3<f64>> = Vec::new();
    for truth in &s.pickable {
        poses.push(*truth);
        poses.push(truth * s.near_symmetry);
        poses.push(Translation3::new(0.2 * s.diameter_mm, 0.0, 0.0) * truth);
    }
    for refine in [false, true] {
        let together = s
            .recognizer
            .check_poses(&s.scene, None, &poses, refine)
            .unwrap();
        assert_eq!(together.len(), poses.len());
        for (pose, check) in poses.iter().zip(&together) {
            let alone = s
                .recognizer
                .check_pose(&s.scene, None, pose, refine)
                .unwrap();
            assert_eq!(&alone, check, "refine {refine}");
        }
        // The set says something: right poses accepted, others refused.
        assert!(together.iter().any(|c| c.refusal.is_none()));
        assert!(together.iter().any(|c| c.refusal.is_some()));
    }
    assert!(
        s.recognizer
            .check_poses(&s.scene, None, &[], true)
            .unwrap()
            .is_empty()
    );
    let mut bad = poses[0];
    bad.translation.vector.y = f64::NAN;
    let e = s
        .recognizer
        .check_poses(&s.scene, None, &[poses[0], bad], true)
        .unwrap_err();
    assert!(e.to_string().contains("pose 1"), "{e}");
}

#[test]
fn the_verifier_score_drops_as_a_pose_moves_off_its_part() {
    let s = belt_scan(0);
    let truth = s.pickable[0];
    let at = |shift_mm: f64| {
        let moved = Translation3::from(Vector3::new(shift_mm, 0.0, 0.0)) * truth;
        s.recognizer
            .check_pose(&s.scene, None, &moved, false)
            .unwrap()
    };
    let shifts = [0.0, 0.05, 0.15, 0.3].map(|f| f * s.diameter_mm);
    let checks: Vec<_> = shifts.iter().map(|&d| at(d)).collect();
    assert_eq!(checks[0].refusal, None);
    let cells = |k: usize| f64::from(checks[k].explained_cells);
    for (k, (shift, check)) in shifts.iter().zip(&checks).enumerate().skip(1) {
        assert!(
            cells(k) < cells(0),
            "explained cells did not drop at {shift:.1} mm: {} -> {}",
            cells(0),
            cells(k)
        );
        // Moved by a sixth of its size or more, it explains little and is refused.
        if k >= 2 {
            assert!(cells(k) < 0.5 * cells(0), "{check:#?}");
            assert!(check.refusal.is_some(), "{check:#?}");
        }
    }
}

#[test]
fn a_part_sunk_into_its_support_is_refused_and_true_poses_in_a_bin_are_not() {
    // In a walled bin (floor and four walls found as support planes), no true pose lies
    // behind any of them: the planes face the parts, whatever their direction to the sensor.
    let bin = bracket_scan("brackets-bin-2mm", 0);
    for truth in &bin.pickable {
        let check = bin
            .recognizer
            .check_pose(&bin.scene, None, truth, false)
            .unwrap();
        assert!(check.view.below_support < 0.01, "{check:#?}");
        assert!(check.view.sunk_mm < 1.0, "{check:#?}");
    }
    // Pushed a third of its size down into the belt, a part is mostly behind the belt.
    let s = belt_scan(0);
    let truth = s.pickable[0];
    let sunk = Translation3::from(Vector3::new(0.0, 0.0, -s.diameter_mm / 3.0)) * truth;
    let check = s
        .recognizer
        .check_pose(&s.scene, None, &sunk, false)
        .unwrap();
    assert!(check.view.below_support > 0.3, "{check:#?}");
    assert!(check.refusal.is_some(), "{check:#?}");
}

#[test]
fn a_flat_part_mirrored_under_the_floor_is_found_sunk_by_its_deepest_point() {
    // A ring lying flat on a depth camera's bin floor, mirrored about the floor: its top face
    // now lies level with the floor and all of it behind, yet no point deeper than the
    // sunk-point tolerance of `max_below_support` (3 view tolerances, 5 mm here, beyond the
    // ring's 4 mm). Its deepest point, 4 mm behind the floor, is past `max_sunk_tolerances`
    // (the refusal that follows: `explain` tests).
    let s = set_scan(PartKind::Ring, "rings-bin-depth", 0, Params::default());
    let on_floor = s
        .pickable
        .iter()
        .filter(|p| p.rotation.transform_vector(&Vector3::z()).z.abs() > 0.99)
        .min_by(|a, b| a.translation.z.total_cmp(&b.translation.z))
        .expect("a flat ring in scan 0");
    assert!(on_floor.translation.z < 3.0, "{on_floor:?}");
    let check = |pose: &Isometry3<f64>| {
        s.recognizer
            .check_pose(&s.scene, None, pose, false)
            .unwrap()
    };
    let resting = check(on_floor);
    assert!(resting.view.sunk_mm < 1.0, "{resting:#?}");
    let mut mirrored = *on_floor;
    mirrored.translation.z = -on_floor.translation.z;
    let sunk = check(&mirrored);
    let defaults = Params::default().verify;
    assert!(
        sunk.view.below_support <= defaults.max_below_support,
        "{sunk:#?}"
    );
    assert!(
        (3.5..4.5).contains(&sunk.view.sunk_mm),
        "the ring's 4 mm behind the floor: {sunk:#?}"
    );
}

#[test]
fn a_part_under_its_neighbours_is_refined_on_the_surface_the_scene_does_not_hide() {
    // A depth camera's bin of rings. ICP on all of a ring's visible model surface pairs the
    // part the rings over it hide with them, or with its own surface beside them, and is
    // pulled off the ring: its right pose then fails `min_fit`. Started 2 mm and up to 8 deg
    // off each covered ring (a voted pose's error), the last pass on the surface the scene
    // does not hide brings the poses in; so does aligning only the surface the scan confirms
    // in every pass (`refine_confirmed_only`, the default).
    let on = set_scan(PartKind::Ring, "rings-bin-depth", 0, Params::default());
    let every_visible = on.recognizer_with(|p| p.verify.refine_confirmed_only = false);
    let neither = on.recognizer_with(|p| {
        p.verify.refine_confirmed_only = false;
        p.verify.unhidden_pass = false;
    });
    let min_fit = Params::default().verify.min_fit;
    let starts: [(f64, f64, f64); 5] = [
        (2.0, 0.0, 0.0),
        (0.0, 2.0, 0.0),
        (-2.0, 0.0, 5.0),
        (0.0, -2.0, -5.0),
        (1.5, 1.5, 8.0),
    ];
    // Starts on covered rings that fit after refinement, and their mean distance from the
    // truth (mm), for `with` and `without`.
    let compare = |with: &Recognizer, without: &Recognizer, each_fits_closer: bool| {
        let (mut fitting, mut error) = ([0; 2], [0.0; 2]);
        let mut covered = 0;
        for truth in &on.pickable {
            for &(dx, dy, tilt_deg) in &starts {
                let tilt =
                    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), tilt_deg.to_radians());
                let start = Translation3::new(dx, dy, 0.0) * truth * tilt;
                let w = with.check_pose(&on.scene, None, &start, true).unwrap();
                if w.view.covered < 0.1 {
                    continue;
                }
                covered += 1;
                let wo = without.check_pose(&on.scene, None, &start, true).unwrap();
                if each_fits_closer {
                    assert!(w.view.fit >= wo.view.fit, "{w:#?}\n{wo:#?}");
                }
                for (k, c) in [w, wo].iter().enumerate() {
                    fitting[k] += usize::from(c.view.fit >= min_fit);
                    error[k] += pose::translation_error_mm(truth, &c.pose);
                }
            }
        }
        eprintln!(
            "fitting {fitting:?} of {covered}; mean error {:.2} / {:.2} mm",
            error[0] / f64::from(covered),
            error[1] / f64::from(covered)
        );
        assert!(covered >= 20, "{covered} starts on covered rings");
        assert!(
            fitting[0] >= fitting[1] + 5,
            "fitting poses {fitting:?} of {covered}"
        );
        assert!(
            error[0] < 0.75 * error[1],
            "mean error {:.2} against {:.2} mm",
            error[0] / f64::from(covered),
            error[1] / f64::from(covered)
        );
    };
    // Measured: 28 of 30 starts fit with the pass, 16 without; mean error 0.85 and 1.65 mm
    // (27 and 0.92 mm before the support beside the parts joined ICP's target).
    compare(&every_visible, &neither, true);
    // Measured: 30 of 30 with the defaults, mean error 0.51 mm.
    compare(&on.recognizer, &neither, false);
}

#[test]
fn taken_parts_are_polished_down_onto_the_scan() {
    // A bin of bent rods scanned 2 mm apart. Point-to-point refinement pairs the model points
    // on a rod's steep flanks, which the scan samples sparsely, with the flank's last scan
    // points higher up, and leaves the rods about half a millimetre too high. The polish pass
    // pairs mutual nearest neighbours only. It moves the parts the competition took and takes
    // no part in choosing them.
    let on = set_scan(PartKind::Rod, "rods-bin-2mm", 0, Params::default());
    let off = on.recognizer_with(|p| p.verify.polish_pass = false);
    let with = on.recognizer.recognize(&on.scene).unwrap();
    let without = off.recognize(&on.scene).unwrap();
    assert_eq!(with.detections.len(), without.detections.len());
    assert!(with.detections.iter().any(|d| d.icp.polished));
    // Height above the true pose of each detection of a pickable rod, mm.
    let lift = |detections: &[binpick::Detection]| -> Vec<f64> {
        detections
            .iter()
            .filter_map(|d| {
                let truth = on
                    .pickable
                    .iter()
                    .find(|t| pose::translation_error_mm(t, &d.pose) < 0.05 * on.diameter_mm)?;
                Some(d.pose.translation.z - truth.translation.z)
            })
            .collect()
    };
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (polished, plain) = (lift(&with.detections), lift(&without.detections));
    eprintln!(
        "mean lift {:.2} mm polished ({} rods), {:.2} mm without ({} rods)",
        mean(&polished),
        polished.len(),
        mean(&plain),
        plain.len()
    );
    assert!(polished.len() >= 3 && plain.len() >= 3);
    assert!(
        mean(&plain) > 0.25,
        "lift without the pass {:.2} mm",
        mean(&plain)
    );
    assert!(
        mean(&polished).abs() < 0.5 * mean(&plain),
        "lift {:.2} mm polished against {:.2} mm",
        mean(&polished),
        mean(&plain)
    );
}

#[test]
fn the_outline_weight_lifts_the_acceptance_fit_of_a_part_standing_on_its_edge_only() {
    // A bracket standing on its 2 mm sheet edge shows a strip nearly all outline, where the
    // scan's edge falls in the model's cell or beside it about as often; a bracket lying on
    // a broad side is mostly inside its outline. Judged at its true pose and tilted 2 deg
    // (the engine's poses of such brackets fitted at 0.59-0.70 with a quarter weight).
    let s = belt_scan(0);
    assert!(!s.on_edge.is_empty(), "scan 0 has no bracket on its edge");
    let quarter = s.recognizer_with(|p| {
        p.verify.outline_neighbour_weight = binpick_match::NEIGHBOUR_FIT_WEIGHT
    });
    let gain = |truth: &Isometry3<f64>, tilt_deg: f64| {
        let centre = (truth * nalgebra::Point3::origin()).coords;
        let tilt = UnitQuaternion::from_euler_angles(tilt_deg.to_radians(), 0.0, 0.0);
        let pose = Translation3::from(centre) * tilt * Translation3::from(-centre) * truth;
        let half = s
            .recognizer
            .check_pose(&s.scene, None, &pose, false)
            .unwrap();
        let low = quarter.check_pose(&s.scene, None, &pose, false).unwrap();
        assert_eq!(half.explained_cells, low.explained_cells);
        // The competition's fit does not change; acceptance reads the outline weight.
        assert_eq!(half.view.fit, low.view.fit);
        half.view.acceptance_fit - low.view.acceptance_fit
    };
    for truth in &s.on_edge {
        for tilt in [0.0, 2.0, -2.0] {
            let g = gain(truth, tilt);
            assert!(g > 0.05, "on its edge, tilt {tilt} deg: fit gain {g:.3}");
        }
    }
    let g = gain(&s.pickable[0], 0.0);
    assert!((0.0..0.03).contains(&g), "on a broad side: fit gain {g:.3}");
}

#[test]
fn brackets_lying_on_the_edge_of_their_sheet_in_a_pile_are_found() {
    // A depth camera's bin of Z brackets; in this scan three pickable brackets lie on the
    // 2 mm edge of their sheet and show the sensor only that Z-shaped strip. Their point
    // pairs are all coplanar, and in the whole part's table they vote with its broad faces;
    // before the rims voted on their own, none of the three was found (0 of 3).
    let s = bracket_scan("brackets-bin-depth", 1);
    assert!(s.on_edge.len() >= 3, "{} on their edge", s.on_edge.len());
    let r = s.recognizer.recognize(&s.scene).unwrap();
    let found = |truth: &Isometry3<f64>| {
        r.detections.iter().any(|d| {
            pose::translation_error_mm(truth, &d.pose) < 0.05 * s.diameter_mm
                && pose::rotation_error_deg(truth, &d.pose) < 5.0
        })
    };
    let on_edge = s.on_edge.iter().filter(|t| found(t)).count();
    assert!(
        on_edge >= 2,
        "{on_edge} of {} on their edge found",
        s.on_edge.len()
    );
    // The first pick is a right pose.
    let first = &r.first_pick().expect("a part free to pick").pose;
    assert!(
        s.pickable.iter().chain(&s.on_edge).any(|t| {
            pose::translation_error_mm(t, first) < 0.05 * s.diameter_mm
                && pose::rotation_error_deg(t, first) < 5.0
        }),
        "first pick {first:?}"
    );
}

#[test]
fn the_floors_noise_tail_is_support_and_no_hypothesis_sinks_into_the_floor() {
    // A depth camera's bin: its noise (0.6 mm) leaves thousands of floor points past the
    // plane distance (1.3 mm), each alone. Left in the scene they were more than half of its
    // samples (each stray is a sample of its own), and their sparse neighbourhoods passed for
    // the thin strips the rim table votes for: rim hypotheses went to poses sunk into the
    // floor.
    let s = bracket_scan("brackets-bin-depth", 1);
    // (noise tail labelled support, not) for a recognizer on `change`.
    let run = |change: fn(&mut Params)| {
        let with = s.recognizer_with(change).recognize(&s.scene).unwrap();
        let without = s
            .recognizer_with(|p| {
                change(p);
                p.preprocess.support.noise_tail_sigmas = 0.0;
            })
            .recognize(&s.scene)
            .unwrap();
        assert_eq!(without.preprocess.support_noise, 0);
        let tail = with.preprocess.support_noise;
        assert!(tail > 3000, "{tail} noise points");
        assert_eq!(
            with.preprocess.remaining + tail,
            without.preprocess.remaining,
            "only points that were left become support"
        );
        let (v, v0) = (with.voting.unwrap(), without.voting.unwrap());
        assert!(
            2 * v.scene_samples < v0.scene_samples,
            "scene samples {} with the tail as support, {} without",
            v.scene_samples,
            v0.scene_samples
        );
        (v.rejected_below_support, v0.rejected_below_support)
    };
    // Refined on every visible model point, a part's deepest point allowed two view
    // tolerances into the floor (as when this test was written; measured since the
    // thirty-eighth pass's averaged pose clusters: 6 with, 17 without).
    let (with, without) = run(|p| {
        p.verify.refine_confirmed_only = false;
        p.verify.max_sunk_tolerances = 2.0;
    });
    assert!(
        2 * with < without,
        "poses sunk into the support: {with} with, {without} without"
    );
    // Refinement aligning only what the scan confirms (the default since the thirty-second
    // pass): a hypothesis voted into the floor has its sunk points hidden by the floor, is
    // not lifted out and is refused as sunk either way. Measured: 8 with the tail as
    // support, 21 without.
    let (with, without) = run(|p| p.verify.max_sunk_tolerances = 2.0);
    assert!(
        2 * with < without,
        "poses sunk into the support, confirmed only: {with} with, {without} without"
    );
    // The defaults (one tolerance since the thirty-third pass) refuse more poses as sunk
    // either way; the tail still more than halves them (measured: 10 with, 25 without).
    let (with, without) = run(|_| {});
    assert!(
        2 * with < without,
        "poses sunk into the support with the defaults: {with} with, {without} without"
    );
}

/// A rod resting on the bin floor has its lowest flanks inside the support band. Without
/// them in ICP's target, ICP pairs the rod's lowest model points with its upper surface and
/// lifts it off, to a pose that fits too loosely to be accepted (seed 7
/// `rods-bin-2mm-006`: 2 of its 5 pickable rods refined from their true poses moved 2.5 mm
/// and 4 deg were accepted; all 5 with the support near the parts in the target).
#[test]
fn rods_on_the_floor_refined_from_poses_nearby_are_accepted() {
    let s = seeded_scan(PartKind::Rod, "rods-bin-2mm", 7, 6, Params::default());
    let truths: Vec<Isometry3<f64>> = s.pickable.iter().chain(&s.on_edge).copied().collect();
    let moved: Vec<Isometry3<f64>> = truths
        .iter()
        .enumerate()
        .map(|(k, truth)| {
            // A different direction and axis for each rod, fixed.
            let a = k as f64 * 2.4;
            let along = Vector3::new(a.cos(), a.sin(), 0.5 * (1.7 * a).sin()).normalize();
            let axis = Vector3::new((0.7 * a).sin(), (0.7 * a).cos(), 0.8).normalize();
            Isometry3::from_parts(
                Translation3::from(truth.translation.vector + 2.5 * along),
                UnitQuaternion::from_axis_angle(
                    &nalgebra::Unit::new_normalize(axis),
                    4f64.to_radians(),
                ) * truth.rotation,
            )
        })
        .collect();
    let checks = s
        .recognizer
        .check_poses(&s.scene, None, &moved, true)
        .unwrap();
    let refused: Vec<_> = checks
        .iter()
        .zip(&truths)
        .filter(|(c, _)| c.refusal.is_some())
        .map(|(c, t)| {
            (
                c.refusal.clone(),
                pose::translation_error_mm(t, &c.pose),
                c.view.acceptance_fit,
            )
        })
        .collect();
    assert!(truths.len() >= 4, "{} rods to refine", truths.len());
    assert!(refused.is_empty(), "refused after refinement: {refused:?}");
}

#[test]
fn the_top_part_of_a_pile_sticking_out_past_the_bins_rim_is_found() {
    // Seed 5 `brackets-bin-2mm-008`: the top bracket of the pile lies in full view with its
    // upper flange above the bin's rim. The rim is a support plane with every other part
    // behind it, so it bounds the parts; counted as a plane a part may not lie behind
    // (`max_below_support`), it refused every right pose of that bracket (7 % of the part
    // more than three tolerances behind it). Only planes that can carry a part are checked
    // now, as for the deepest point (`max_sunk_tolerances`).
    let s = seeded_scan(
        PartKind::Bracket,
        "brackets-bin-2mm",
        5,
        8,
        Params::default(),
    );
    let top = s
        .pickable
        .iter()
        .max_by(|a, b| a.translation.z.total_cmp(&b.translation.z))
        .expect("pickable brackets");
    let found = s.recognizer.recognize(&s.scene).unwrap();
    assert!(
        found.detections.iter().any(|d| {
            pose::translation_error_mm(top, &d.pose) < 0.05 * s.diameter_mm
                && pose::rotation_error_deg(top, &d.pose) < 5.0
        }),
        "the top bracket at {:?} was not found: {:#?}",
        top.translation.vector,
        found.detections
    );
}

/// The one bracket of `s` standing on the edge of its profile (the sheet's width, the
/// model's y axis, vertical).
fn standing_on_its_profile(s: &BeltScan) -> Isometry3<f64> {
    let standing: Vec<_> = s
        .on_edge
        .iter()
        .filter(|p| (p.rotation * nalgebra::Vector3::y()).z.abs() > 0.95)
        .collect();
    assert_eq!(standing.len(), 1, "one bracket standing on its profile");
    *standing[0]
}

#[test]
fn a_bracket_standing_on_its_profile_edge_is_found_past_the_strips_of_its_sides() {
    // Seed 11 `brackets-bin-depth-005`: a Z bracket stands in full view on the edge of its
    // profile. The sensor sees that edge, and at a grazing angle strips of its sides below
    // it; over a quarter of the diameter they tilted the rim's profile out of flat, so 1 of
    // its 51 ribbon samples was a rim and the rim table had nothing to vote with. The
    // profile is now also tried at the rim's own level (`RimLevel`).
    let s = seeded_scan(
        PartKind::Bracket,
        "brackets-bin-depth",
        11,
        5,
        Params::default(),
    );
    let standing = standing_on_its_profile(&s);
    let found = s.recognizer.recognize(&s.scene).unwrap();
    assert!(
        found.detections.iter().any(|d| {
            pose::translation_error_mm(&standing, &d.pose) < 0.05 * s.diameter_mm
                && pose::rotation_error_deg(&standing, &d.pose) < 5.0
        }),
        "the standing bracket at {:?} was not found: {:#?}",
        standing.translation.vector,
        found.detections
    );
}

#[test]
fn a_bracket_standing_on_its_profile_is_told_from_its_turn_by_the_scan_at_its_ends() {
    // Seed 4 `brackets-bin-2mm-002`: a Z bracket stands alone on the edge of its profile
    // (108 points at 2 mm). Its half turn fits the strip as well in the view, and the
    // settling of turns left parts seen edge on as taken: the turn was reported. The scan
    // points either pose explains judge them now (`Verifier::scan_residuals`): the turn
    // leaves the end of the scan's longer flange unexplained.
    let s = seeded_scan(
        PartKind::Bracket,
        "brackets-bin-2mm",
        4,
        2,
        Params::default(),
    );
    let standing = standing_on_its_profile(&s);
    let found = s.recognizer.recognize(&s.scene).unwrap();
    let near: Vec<_> = found
        .detections
        .iter()
        .filter(|d| pose::translation_error_mm(&standing, &d.pose) < 0.1 * s.diameter_mm)
        .collect();
    assert_eq!(near.len(), 1, "reported once: {near:#?}");
    assert!(
        pose::rotation_error_deg(&standing, &near[0].pose) < 5.0,
        "the standing bracket at {:?} was reported as {:?}",
        standing.translation.vector,
        near[0].pose
    );
}

#[test]
fn a_pose_laid_on_the_flange_of_a_part_lying_on_it_is_not_the_first_pick() {
    // Seed 16 `brackets-bin-2mm-002`: a bracket in full view lies with a flange flat on a
    // flange of another, 43 % visible. A pose of the lower one lifted 3 mm lays its flange
    // in the upper one's and explains more cells than the upper one's right pose (which
    // fits closer), so it was taken first, nothing lay on it, and it was the first pick:
    // a part not pickable. It claimed 69 % of that closer-fitting pose
    // (`ViewCheck::contested`) and is not free to pick now.
    let s = seeded_scan(
        PartKind::Bracket,
        "brackets-bin-2mm",
        16,
        2,
        Params::default(),
    );
    let found = s.recognizer.recognize(&s.scene).unwrap();
    let first = found.first_pick().expect("a first pick");
    assert!(
        s.pickable.iter().chain(&s.on_edge).any(|p| {
            pose::translation_error_mm(p, &first.pose) < 0.05 * s.diameter_mm
                && pose::rotation_error_deg(p, &first.pose) < 5.0
        }),
        "the first pick is not a pickable part's pose: {first:#?}"
    );
    assert!(
        found
            .detections
            .iter()
            .any(|d| d.view.is_some_and(|v| v.contested > 0.6) && !d.free_to_pick),
        "no contested part: {:#?}",
        found.detections
    );
}

#[test]
fn a_bracket_nested_between_two_others_wins_back_the_cells_it_fits_closer() {
    // Seed 14 `brackets-bin-2mm-006`: three brackets lie nested, flange on flange, the
    // middle one 61 % visible. The poses of the one above and the one beneath, a sheet's
    // thickness away, explain its cells within the tolerance; taken first, they left its
    // right pose a repeat. Its own pose fits those cells much closer
    // (`closer_cell_margin`): it is found, and with the per-cell competition off it is not.
    let s = seeded_scan(
        PartKind::Bracket,
        "brackets-bin-2mm",
        14,
        6,
        Params::default(),
    );
    let found_by = |recognizer: &Recognizer| -> Vec<usize> {
        let found = recognizer.recognize(&s.scene).unwrap();
        s.pickable
            .iter()
            .chain(&s.on_edge)
            .enumerate()
            .filter(|(_, t)| {
                found.detections.iter().any(|d| {
                    pose::translation_error_mm(t, &d.pose) < 0.05 * s.diameter_mm
                        && pose::rotation_error_deg(t, &d.pose) < 5.0
                })
            })
            .map(|(k, _)| k)
            .collect()
    };
    let with = found_by(&s.recognizer);
    let without = found_by(&s.recognizer_with(|p| p.verify.closer_cell_margin = 1.0));
    assert!(
        without.iter().all(|k| with.contains(k)) && with.len() > without.len(),
        "pickable parts found {with:?}, with every claimed cell taken {without:?}"
    );
}

#[test]
fn a_pose_sunk_into_the_floor_does_not_take_the_place_of_the_part_it_lies_across() {
    // Seed 4 `mixed-bin-clutter-2mm-009`: a bent plate lies in full view among clutter. A
    // pose of the plate turned half-way, laid across it and a clutter part with a corner
    // 4.5 mm (1.6 view tolerances) in the floor, claimed its surface when two tolerances
    // were allowed: the plate went unreported and the first pick was a wrong pose. At one
    // tolerance (`max_sunk_tolerances`, the thirty-third pass) the turn is refused.
    let s = seeded_scan_of_any(
        PartKind::Plate,
        "mixed-bin-clutter-2mm",
        4,
        9,
        Params::default(),
    );
    assert_eq!(s.pickable.len(), 1, "one plate in full view");
    let right = |d: &binpick::Detection| {
        s.pickable.iter().any(|t| {
            pose::translation_error_mm(t, &d.pose) < 0.05 * s.diameter_mm
                && pose::rotation_error_deg(t, &d.pose) < 5.0
        })
    };
    let found = s.recognizer.recognize(&s.scene).unwrap();
    let first = found.first_pick().expect("a first pick");
    assert!(right(first), "first pick {first:#?}");
    let lenient = s
        .recognizer_with(|p| p.verify.max_sunk_tolerances = 2.0)
        .recognize(&s.scene)
        .unwrap();
    assert!(
        !lenient.detections.iter().any(right),
        "with two tolerances the plate was not found: {:#?}",
        lenient.detections
    );
}

#[test]
fn a_bracket_standing_on_a_flange_end_is_laid_from_its_web() {
    // Seed 11's `brackets-bin-depth-004`: a bracket in full view standing on a flange's end
    // (3 037 points) shows the camera its web, a flat 40 x 26 mm rectangle, and the edge of
    // its upper flange. Every pair on the web votes alike for the flanges' wider faces: no
    // voted hypothesis came within 6 mm of it. Its web's patch laid on the model's web
    // places it (within 1 mm and 2 deg before refinement). Off by default (docs/results-history.md,
    // "Forty-first pass"), so turned on here.
    let mut params = Params::default();
    params.voting.face_hypotheses = 40;
    let s = seeded_scan(PartKind::Bracket, "brackets-bin-depth", 11, 4, params);
    let web_up: Vec<&Isometry3<f64>> = s
        .pickable
        .iter()
        .filter(|t| (t.rotation * Vector3::x()).z > 15f64.to_radians().cos())
        .collect();
    assert!(
        web_up.len() >= 2,
        "{} brackets with their web up",
        web_up.len()
    );
    // Seen from the depth camera, as from its PCD's `VIEWPOINT`.
    let camera = generalisation_sets(None)
        .into_iter()
        .find(|set| set.name == "brackets-bin-depth")
        .unwrap()
        .sensor
        .viewpoint()
        .position_mm;
    let r = s
        .recognizer
        .recognize_seen_from(&s.scene, Some(camera))
        .unwrap();
    let missed: Vec<&&Isometry3<f64>> =
        web_up.iter().filter(|t| !s.reported_right(&r, t)).collect();
    assert!(
        missed.is_empty(),
        "brackets with their web up missed: {missed:?}"
    );
    let v = r.voting.as_ref().unwrap();
    assert!(v.face_hypotheses > 0 && v.face_hypotheses <= 40);
}

#[test]
fn a_part_crossing_the_end_of_the_scan_is_found_and_not_free_to_pick() {
    // The belt scan cut where a bracket's centre lies, as a scan ending there would: half
    // the bracket is beyond the scanned area. Counted as surface the sensor failed to see,
    // that half made the right pose "missing" half its view.
    let s = belt_scan(0);
    let cut_at = |truth: &Isometry3<f64>| {
        let y = truth.translation.y as f32;
        PointCloud {
            points: s
                .scene
                .points
                .iter()
                .copied()
                .filter(|p| p[1] <= y)
                .collect(),
        }
    };
    let mut found_any = false;
    for truth in &s.pickable {
        let r = s.recognizer.recognize(&cut_at(truth)).unwrap();
        let Some(d) = r
            .detections
            .iter()
            .find(|d| s.near(truth, d) && pose::rotation_error_deg(truth, &d.pose) < 10.0)
        else {
            continue;
        };
        found_any = true;
        let v = d.view.expect("a view check");
        // Judged on its scanned part: that is all there (it was 56 % with the rest counted
        // as missing).
        assert!(v.outside > 0.2 && v.visibility > 0.8, "{v:?}");
        assert!(!d.free_to_pick, "{}", d.rank_reason);
        assert!(
            d.rank_reason.contains("beyond the edge of the scan"),
            "{}",
            d.rank_reason
        );
    }
    assert!(found_any, "no bracket cut by the scan's end was found");
}

/// The thesis's parts A (a 2 mm sheet bent to an L, 50 mm wide, legs 60 and 70 mm) as
/// physics left ten of them on seed 1's `conv-A-decr-000`, scanned by the thesis's conveyor
/// scanner. Three stand on the edge of their sheet, the legs' plane upright: the scanner sees
/// an L-shaped 2 mm strip, about 1 % of the part's median view where a neighbour hides part
/// of it. With `min_explained_share` at 0.03 (before the fifty-second pass) their true poses
/// are refused for too little surface and none of the three is found.
#[test]
fn sheet_parts_standing_on_their_edge_are_found() {
    #[rustfmt::skip]
    const POSES: [[f64; 12]; 10] = [
        [-0.04009, 0.99811, -0.04649, -57.61729, 0.65129, 0.06139, 0.75634, 13.86018, 0.75777, 0.00004, -0.65253, 1.40731],
        [-0.00000, 0.58944, 0.80781, 24.30141, 0.00000, 0.80781, -0.58944, -47.87273, -1.00000, 0.00000, -0.00000, 31.99941],
        [0.03615, -0.95850, 0.28280, -75.35910, -0.58644, -0.24948, -0.77062, 24.16031, 0.80919, -0.13798, -0.57112, 25.16162],
        [-0.97253, 0.00003, -0.23278, 25.05178, -0.23278, 0.00002, 0.97253, 40.90794, 0.00003, 1.00000, -0.00001, 24.99858],
        [0.99187, 0.00001, -0.12725, 45.04083, 0.12725, -0.00001, 0.99187, 71.55197, 0.00001, -1.00000, -0.00001, 24.99943],
        [-0.87655, 0.00001, -0.48130, 19.87180, -0.48130, 0.00001, 0.87655, 84.90372, 0.00001, 1.00000, -0.00000, 24.99954],
        [-0.07738, -0.52516, -0.84748, -67.23600, 0.69295, -0.63948, 0.33300, -47.81730, -0.71682, -0.56149, 0.41339, 51.05943],
        [0.07337, -0.91016, 0.40772, 45.08108, -0.21425, -0.41366, -0.88486, 26.78759, 0.97402, -0.02243, -0.22535, 23.84109],
        [0.85823, 0.50740, 0.07741, -65.14967, -0.31961, 0.64630, -0.69292, -54.19239, -0.40162, 0.56995, 0.71684, 54.43058],
        [0.43275, 0.18637, -0.88204, -46.33885, -0.82668, 0.47232, -0.30579, 16.48777, 0.35961, 0.86150, 0.35847, 46.30783],
    ];
    /// The three standing on their edge.
    const ON_EDGE: [usize; 3] = [3, 4, 5];
    let pose = |m: &[f64; 12]| {
        Isometry3::from_parts(
            Translation3::new(m[3], m[7], m[11]),
            UnitQuaternion::from_matrix(&nalgebra::Matrix3::new(
                m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10],
            )),
        )
    };
    let lib = ModelLibrary::build_for(&[PartKind::A], false).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let stl = dir.path().join("A.stl");
    write_stl(&stl, &lib.models[0].mesh).unwrap();
    let instances = POSES
        .iter()
        .map(|m| binpick_synth::Instance {
            kind: PartKind::A,
            pose: pose(m),
        })
        .collect();
    let scan = binpick_synth::scan_instances(
        &lib,
        &binpick_synth::Layout::Conveyor.environment(false),
        instances,
        &binpick_synth::ScannerConfig::conveyor(20.0, 0.15, 340_000),
        7,
        "a-on-edge",
    )
    .unwrap();
    let found_on_edge = |change: &dyn Fn(&mut Params)| {
        let mut params = Params::default();
        change(&mut params);
        let (part, _) = load_part(&stl, Units::Millimetres, &params).unwrap();
        let r = Recognizer::with_part(part, params)
            .unwrap()
            .recognize(&scan.scan.cloud)
            .unwrap();
        ON_EDGE
            .iter()
            .filter(|&&k| {
                let truth = pose(&POSES[k]);
                r.detections.iter().any(|d| {
                    pose::translation_error_mm(&truth, &d.pose) < 5.0
                        && pose::rotation_error_deg(&truth, &d.pose) < 10.0
                })
            })
            .count()
    };
    let found = found_on_edge(&|_| {});
    assert_eq!(found, 3, "parts on their edge found");
    let before = found_on_edge(&|p| p.verify.min_explained_share = 0.03);
    assert_eq!(
        before, 0,
        "found at 0.03 too: the scene no longer shows what this test is about"
    );
}
