//! Writes the project's committed sample data:
//!
//! - `DATA/sample/`: models A, A-cut, B, C, C-cut and one conveyor scene of five A parts
//!   (`scenes/conveyor-A.pcd`, `gt/conveyor-A__A.json`), the first seed (from 1) whose pile has
//!   touching parts and a partly covered one;
//! - `DATA/tiny/`: the `tiny` preset, seed 1.
//!
//! `cargo run --release -p binpick-synth --example make_sample -- DATA_DIR`
//!
//! Every written cloud is read back and compared with what was meant to be written.

use std::path::{Path, PathBuf};

use binpick_cloud::PointCloud;
use binpick_cloud::dataset::write_json;
use binpick_synth::generate::{write_cloud, write_models};
use binpick_synth::mesh::distance_to_mesh;
use binpick_synth::rng::Rng;
use binpick_synth::{
    Layout, ModelLibrary, PartKind, Preset, ScannerConfig, SceneRequest, SynthOptions, SynthScene,
    generate, make_scene,
};

/// The sample scene's scanner: the conveyor layout at its fastest belt speed (30 mm/s, 1.07 mm
/// between lines) with 600 camera columns (0.43 mm apart) instead of the presets' ~1100-1600,
/// to keep the file near 2 MB; noise and outliers as in the presets.
fn sample_scanner() -> ScannerConfig {
    let mut c = ScannerConfig::conveyor(30.0, 0.15, 0);
    c.columns = 600;
    c
}

type Res<T> = Result<T, Box<dyn std::error::Error>>;

/// Parses a binary x y z float32 PCD (what `write_pcd` writes).
fn read_binary_pcd(path: &Path) -> Res<PointCloud> {
    let bytes = std::fs::read(path)?;
    let marker = b"DATA binary\n";
    let at = bytes
        .windows(marker.len())
        .position(|w| w == marker)
        .ok_or("no DATA binary line")?;
    let header = std::str::from_utf8(&bytes[..at])?;
    let field = |key: &str| -> Res<String> {
        Ok(header
            .lines()
            .find_map(|l| l.strip_prefix(key))
            .ok_or(format!("no {key}"))?
            .trim()
            .to_owned())
    };
    if field("FIELDS ")? != "x y z" || field("SIZE ")? != "4 4 4" || field("TYPE ")? != "F F F" {
        return Err("unexpected fields".into());
    }
    let n: usize = field("POINTS ")?.parse()?;
    let data = &bytes[at + marker.len()..];
    if data.len() != 12 * n {
        return Err(format!("{} data bytes for {n} points", data.len()).into());
    }
    Ok(PointCloud::new(
        data.chunks_exact(12)
            .map(|c| {
                let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
                [f(0), f(4), f(8)]
            })
            .collect(),
    ))
}

/// Reads a written cloud back (own parser, and binpick-cloud's reader when it has one) and
/// checks it is exactly what was written.
fn check_cloud(path: &Path, expected: Option<&PointCloud>) -> Res<usize> {
    let back = read_binary_pcd(path)?;
    if let Some(i) = back.first_non_finite() {
        return Err(format!("{}: point {i} not finite", path.display()).into());
    }
    if let Some(e) = expected
        && &back != e
    {
        return Err(format!("{}: read back differs", path.display()).into());
    }
    match binpick_cloud::io::read_cloud(path) {
        Ok((c, _)) if c == back => {}
        Ok(_) => {
            return Err(format!("{}: binpick-cloud reads it differently", path.display()).into());
        }
        Err(e) => eprintln!("  (binpick_cloud::io::read_cloud unavailable here: {e})"),
    }
    Ok(back.len())
}

/// Whether two placed parts touch (surface samples of one within 0.5 mm of the other).
fn touching(lib: &ModelLibrary, scene: &SynthScene, i: usize, j: usize) -> Res<bool> {
    let (a, b) = (&scene.instances[i], &scene.instances[j]);
    let mb = lib.parts.get(b.kind).mesh.transformed(&b.pose).to_parry()?;
    let samples = lib
        .parts
        .get(a.kind)
        .mesh
        .transformed(&a.pose)
        .sample_surface(3000, &mut Rng::new(1));
    Ok(samples.iter().any(|p| distance_to_mesh(&mb, p) < 0.5))
}

fn sample_scene(lib: &ModelLibrary) -> Res<(u64, SynthScene)> {
    let kinds = [PartKind::A; 5];
    for seed in 1..200u64 {
        let scene = make_scene(
            lib,
            &SceneRequest {
                layout: Layout::Conveyor,
                in_box: false,
                base: &kinds,
                top: &[],
                points_target: 0,
                scanner: Some(sample_scanner()),
                seed,
                scene_id: "conveyor-A",
            },
        )?;
        let gt = scene.gt.iter().find(|g| g.model == "A").ok_or("no A gt")?;
        let vfs: Vec<f64> = gt.instances.iter().map(|i| i.visible_fraction).collect();
        let bounds: Vec<_> = scene
            .instances
            .iter()
            .map(|i| lib.parts.get(i.kind).mesh.transformed(&i.pose).bounds())
            .collect::<Option<_>>()
            .ok_or("empty mesh")?;
        let in_view = bounds.iter().all(|b| {
            b.min[0] > -128.0 && b.max[0] < 128.0 && b.min[1] > -128.0 && b.max[1] < 128.0
        });
        // Partly covered: a part 20-80 % visible with another part over it.
        let covered = (0..5).any(|i| {
            (0.2..0.8).contains(&vfs[i])
                && (0..5).any(|j| {
                    j != i
                        && bounds[j].max[2] > bounds[i].max[2]
                        && bounds[j].min[0] < bounds[i].max[0]
                        && bounds[j].max[0] > bounds[i].min[0]
                        && bounds[j].min[1] < bounds[i].max[1]
                        && bounds[j].max[1] > bounds[i].min[1]
                })
        });
        let pickable = gt.instances.iter().filter(|i| i.pickable).count();
        if !(scene.settled && in_view && covered && pickable >= 3) {
            continue;
        }
        let mut pairs = 0;
        for i in 0..5 {
            for j in i + 1..5 {
                if touching(lib, &scene, i, j)? {
                    pairs += 1;
                }
            }
        }
        if pairs >= 2 {
            eprintln!("sample scene: seed {seed}, {pairs} touching pairs, visible {vfs:?}");
            return Ok((seed, scene));
        }
    }
    Err("no seed gave a suitable sample scene".into())
}

fn main() -> Res<()> {
    let data: PathBuf = std::env::args()
        .nth(1)
        .ok_or("usage: make_sample DATA_DIR")?
        .into();
    let lib = ModelLibrary::build()?;

    // data/sample
    let sample = data.join("sample");
    write_models(&sample, &lib)?;
    for m in &lib.models {
        let n = check_cloud(
            &sample.join(format!("models/{}.pcd", m.name)),
            Some(&m.cloud),
        )?;
        eprintln!(
            "models/{}.pcd: {n} points, diameter {:.1} mm",
            m.name, m.diameter
        );
    }
    let (seed, scene) = sample_scene(&lib)?;
    let scene_path = sample.join("scenes/conveyor-A.pcd");
    write_cloud(&scene_path, &scene.scan.cloud)?;
    let n = check_cloud(&scene_path, Some(&scene.scan.cloud))?;
    let gt = scene
        .gt
        .iter()
        .find(|g| g.model == "A")
        .ok_or("no A ground truth")?;
    write_json(&sample.join("gt/conveyor-A__A.json"), gt)?;
    let s = &scene.scanner;
    let readme = format!(
        "Sample data written by `cargo run --release -p binpick-synth --example make_sample -- data`\n\
         (binpick-synth {ver}).\n\n\
         models/      A, A-cut, B, C, C-cut: top views of the parts in their canonical pose, part\n\
         \x20            frame, mm (0.5 mm voxel grid); <name>.json: diameter and symmetries.\n\
         scenes/conveyor-A.pcd  a simulated conveyor scan of 5 parts A (make_scene seed {seed}):\n\
         \x20            {n} points, belt {speed} mm/s at 28 fps ({line:.2} mm between lines),\n\
         \x20            {cols} columns ({col:.2} mm apart - fewer than the ~1100 of the full\n\
         \x20            presets, to keep the file small), range noise sigma {sigma} mm, 0.1 % outliers.\n\
         gt/conveyor-A__A.json  true poses (model -> scene), visible fractions (radius {radius:.2} mm)\n\
         \x20            and pickable flags of the 5 instances.\n\n\
         Frame: z up, belt at z = 0, x across the belt, y along the motion.\n\
         ../tiny/ is the `tiny` preset (seed 1): 4 small labelled scenes in the dataset layout.\n",
        ver = binpick_synth::GENERATOR_VERSION,
        speed = s.speed,
        line = s.line_spacing(),
        cols = s.columns,
        col = s.column_spacing(),
        sigma = s.noise_sigma,
        radius = scene.visibility_radius,
    );
    std::fs::write(sample.join("README.txt"), readme)?;
    eprintln!("scenes/conveyor-A.pcd: {n} points");

    // data/tiny
    let tiny = data.join("tiny");
    let summary = generate(
        &SynthOptions {
            preset: Preset::Tiny,
            out_dir: tiny.clone(),
            seed: 1,
            scenes_per_group: None,
            points_target: None,
        },
        &|_, _| {},
    )?;
    for e in std::fs::read_dir(tiny.join("scenes"))? {
        let p = e?.path();
        let n = check_cloud(&p, None)?;
        eprintln!("tiny/{}: {n} points", p.display());
    }
    eprintln!(
        "tiny: {} scenes, {} gt files, {} points",
        summary.scenes, summary.gt_files, summary.total_points
    );
    Ok(())
}
