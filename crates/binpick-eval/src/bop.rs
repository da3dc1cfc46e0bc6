//! BOP interoperability (<https://bop.felk.cvut.cz>): reading a BOP-format dataset (depth
//! images + camera intrinsics + `scene_gt.json`) for `binpick eval`, and writing detections in
//! BOP's results CSV (`--bop-csv`).
//!
//! Layout read (BOP's, paths relative to the dataset root):
//!
//! ```text
//! models/models_info.json         {"<obj_id>": {"diameter": mm, "symmetries_discrete": [[16 numbers]],
//!                                  "symmetries_continuous": [{"axis": [x,y,z], "offset": [x,y,z]}], ...}}
//! models/obj_<obj_id:06>.ply      the object's mesh, mm
//! <split>/<scene_id:06>/scene_camera.json   {"<im_id>": {"cam_K": [9 numbers], "depth_scale": mm per unit, ...}}
//! <split>/<scene_id:06>/scene_gt.json       {"<im_id>": [{"obj_id": n, "cam_R_m2c": [9, row-major], "cam_t_m2c": [3, mm]}, ...]}
//! <split>/<scene_id:06>/scene_gt_info.json  optional: {"<im_id>": [{"visib_fract": f, ...}, ...]} (same order)
//! <split>/<scene_id:06>/depth/<im_id:06>.png  16-bit depth, z = value x depth_scale mm
//! ```
//!
//! A depth image becomes an organised cloud in the camera frame, mm
//! ([`binpick_cloud::depth`]); the camera is at its origin. Without `scene_gt_info.json` every
//! instance counts as fully visible.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use binpick::Detection;
use binpick::error::{Result, input};
use binpick_cloud::PointCloud;
use binpick_cloud::depth::{DepthImage, Intrinsics};

/// BOP's minimum visible fraction of a ground-truth instance to count as a target
/// (`visib_gt_min = 0.1` of the BOP 2019+ evaluation).
pub const BOP_MIN_VISIBLE_FRACTION: f64 = 0.1;

/// Header of BOP's results CSV.
pub const CSV_HEADER: &str = "scene_id,im_id,obj_id,score,R,t,time\n";

/// The ids a BOP results row carries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct BopIds {
    pub scene_id: u32,
    pub im_id: u32,
    pub obj_id: u32,
}

/// A detection's BOP confidence (higher is better): the estimated visible fraction with the
/// scene-voting engine, else 1 - the outlier share (thesis engine).
pub fn score(d: &Detection) -> f64 {
    match &d.view {
        Some(v) => v.visibility,
        None => (1.0 - d.final_score / 100.0).clamp(0.0, 1.0),
    }
}

/// The rows (no header) of one image's detections: `R` row-major, `t` in mm, both model ->
/// the scan's frame; `time_s` the recognition time of the image, seconds (BOP: the same for
/// every row of an image).
pub fn csv_rows(ids: BopIds, detections: &[Detection], time_s: f64) -> String {
    let mut out = String::new();
    for d in detections {
        let r = d.pose.rotation.to_rotation_matrix();
        let m = r.matrix();
        let t = d.pose.translation.vector;
        let rs: Vec<String> = (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| format!("{}", m[(i, j)]))
            .collect();
        out.push_str(&format!(
            "{},{},{},{},{},{} {} {},{}\n",
            ids.scene_id,
            ids.im_id,
            ids.obj_id,
            score(d),
            rs.join(" "),
            t.x,
            t.y,
            t.z,
            time_s
        ));
    }
    out
}

/// One object's entry of `models_info.json` (the keys binpick reads).
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
pub struct BopModelInfo {
    pub diameter: f64,
    #[serde(default)]
    pub symmetries_discrete: Vec<Vec<f64>>,
    #[serde(default)]
    pub symmetries_continuous: Vec<ContinuousSymmetry>,
}

/// A continuous symmetry: any rotation about `axis` through `offset` (model frame, mm).
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct ContinuousSymmetry {
    pub axis: [f64; 3],
    pub offset: [f64; 3],
}

impl BopModelInfo {
    /// The declared symmetries (continuous ones sampled every
    /// [`binpick::REVOLUTION_STEP_DEG`]), identity first.
    pub fn symmetries(&self, obj_id: u32) -> Result<binpick::Symmetries> {
        let what = "BOP models_info.json";
        let discrete: Vec<Isometry3<f64>> = self
            .symmetries_discrete
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let m: [f64; 16] = m.as_slice().try_into().map_err(|_| {
                    input(
                        what,
                        format!(
                            "object {obj_id}: symmetries_discrete[{i}] has {} numbers, not 16",
                            m.len()
                        ),
                    )
                })?;
                binpick_cloud::pose_from_row_major(&m).map_err(|e| {
                    input(
                        what,
                        format!("object {obj_id}: symmetries_discrete[{i}]: {e}"),
                    )
                })
            })
            .collect::<Result<_>>()?;
        match self.symmetries_continuous.as_slice() {
            [] => Ok(binpick::Symmetries::new(&discrete)),
            [c] => binpick::Symmetries::revolution(
                c.offset,
                c.axis,
                binpick::REVOLUTION_STEP_DEG,
                &discrete,
            )
            .map_err(|e| input(what, format!("object {obj_id}: {e}"))),
            _ => Err(input(
                what,
                format!(
                    "object {obj_id}: more than one continuous symmetry (a sphere?) is not supported"
                ),
            )),
        }
    }
}

/// One ground-truth instance as BOP stores it.
#[derive(Clone, Debug, PartialEq, Deserialize)]
struct GtRecord {
    obj_id: u32,
    #[serde(rename = "cam_R_m2c")]
    cam_r_m2c: [f64; 9],
    #[serde(rename = "cam_t_m2c")]
    cam_t_m2c: [f64; 3],
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
struct GtInfoRecord {
    visib_fract: f64,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
struct CameraRecord {
    #[serde(rename = "cam_K")]
    cam_k: [f64; 9],
    depth_scale: f64,
}

/// One labelled instance of a BOP image.
#[derive(Clone, Debug, PartialEq)]
pub struct BopInstance {
    pub obj_id: u32,
    /// Model -> camera, mm.
    pub pose: Isometry3<f64>,
    /// BOP's visib_fract (1 when the dataset has no `scene_gt_info.json`).
    pub visible_fraction: f64,
}

/// One image of a BOP split.
#[derive(Clone, Debug, PartialEq)]
pub struct BopImage {
    pub scene_id: u32,
    pub im_id: u32,
    pub depth: PathBuf,
    pub intrinsics: Intrinsics,
    /// mm per depth unit.
    pub depth_scale_mm: f64,
    pub instances: Vec<BopInstance>,
}

impl BopImage {
    /// Reads the depth image and turns it into a cloud in the camera frame, mm.
    pub fn load_cloud(&self) -> Result<PointCloud> {
        let img =
            DepthImage::read_png(&self.depth).map_err(|e| input("BOP depth", e.to_string()))?;
        let cloud = img
            .to_cloud(&self.intrinsics, self.depth_scale_mm)
            .map_err(|e| input("BOP depth", format!("{}: {e}", self.depth.display())))?;
        Ok(cloud.cloud)
    }
}

/// A BOP dataset: its models and the images of one split.
#[derive(Clone, Debug)]
pub struct BopDataset {
    pub root: PathBuf,
    pub split: String,
    pub models: BTreeMap<u32, BopModelInfo>,
    /// Sorted by (scene_id, im_id).
    pub images: Vec<BopImage>,
}

fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| input("BOP dataset", format!("{}: {e}", path.display())))?;
    serde_json::from_str(&text)
        .map_err(|e| input("BOP dataset", format!("{}: {e}", path.display())))
}

fn parse_id(key: &str, path: &Path) -> Result<u32> {
    key.parse().map_err(|_| {
        input(
            "BOP dataset",
            format!("{}: key {key:?} is not an image id", path.display()),
        )
    })
}

/// Whether `root` looks like a BOP dataset (`models/models_info.json`).
pub fn is_bop_dataset(root: &Path) -> bool {
    root.join("models").join("models_info.json").is_file()
}

impl BopDataset {
    /// Opens `root` and reads every image's camera and ground truth of `split` (e.g. `test`).
    pub fn open(root: &Path, split: &str) -> Result<Self> {
        let info_path = root.join("models").join("models_info.json");
        let raw: BTreeMap<String, BopModelInfo> = read_json(&info_path)?;
        let mut models = BTreeMap::new();
        for (k, v) in raw {
            if !(v.diameter.is_finite() && v.diameter > 0.0) {
                return Err(input(
                    "BOP dataset",
                    format!(
                        "{}: object {k}: diameter {} is not a positive number of mm",
                        info_path.display(),
                        v.diameter
                    ),
                ));
            }
            models.insert(parse_id(&k, &info_path)?, v);
        }
        let split_dir = root.join(split);
        let entries = std::fs::read_dir(&split_dir).map_err(|e| {
            input(
                "BOP dataset",
                format!(
                    "{}: {e} (choose the split with --split)",
                    split_dir.display()
                ),
            )
        })?;
        let mut scene_dirs: Vec<(u32, PathBuf)> = Vec::new();
        for entry in entries.flatten() {
            let path = entry.path();
            let id = path
                .file_name()
                .and_then(|n| n.to_str())
                .and_then(|n| n.parse::<u32>().ok());
            if let Some(id) = id
                && path.join("scene_gt.json").is_file()
            {
                scene_dirs.push((id, path));
            }
        }
        if scene_dirs.is_empty() {
            return Err(input(
                "BOP dataset",
                format!(
                    "{}: no scene folder with a scene_gt.json",
                    split_dir.display()
                ),
            ));
        }
        scene_dirs.sort();
        let mut images = Vec::new();
        for (scene_id, dir) in scene_dirs {
            images.extend(read_scene(scene_id, &dir)?);
        }
        Ok(Self {
            root: root.to_owned(),
            split: split.to_owned(),
            models,
            images,
        })
    }

    /// `models/obj_<id:06>.ply`.
    pub fn model_path(&self, obj_id: u32) -> PathBuf {
        self.root
            .join("models")
            .join(format!("obj_{obj_id:06}.ply"))
    }

    /// The object ids that have ground truth, sorted.
    pub fn labelled_objects(&self) -> Vec<u32> {
        let mut ids: Vec<u32> = self
            .images
            .iter()
            .flat_map(|i| i.instances.iter().map(|g| g.obj_id))
            .collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }
}

fn read_scene(scene_id: u32, dir: &Path) -> Result<Vec<BopImage>> {
    let cam_path = dir.join("scene_camera.json");
    let gt_path = dir.join("scene_gt.json");
    let info_path = dir.join("scene_gt_info.json");
    let cameras: BTreeMap<String, CameraRecord> = read_json(&cam_path)?;
    let gts: BTreeMap<String, Vec<GtRecord>> = read_json(&gt_path)?;
    let infos: Option<BTreeMap<String, Vec<GtInfoRecord>>> = if info_path.is_file() {
        Some(read_json(&info_path)?)
    } else {
        None
    };
    let bad = |path: &Path, m: String| input("BOP dataset", format!("{}: {m}", path.display()));
    let mut images = Vec::new();
    for (key, records) in &gts {
        let im_id = parse_id(key, &gt_path)?;
        let cam = cameras
            .get(key)
            .ok_or_else(|| bad(&cam_path, format!("no camera for image {key}")))?;
        let intrinsics = Intrinsics::from_k(&cam.cam_k)
            .map_err(|e| bad(&cam_path, format!("image {key}: {e}")))?;
        if !(cam.depth_scale.is_finite() && cam.depth_scale > 0.0) {
            return Err(bad(
                &cam_path,
                format!(
                    "image {key}: depth_scale {} is not positive",
                    cam.depth_scale
                ),
            ));
        }
        let info = match &infos {
            Some(m) => {
                let v = m
                    .get(key)
                    .ok_or_else(|| bad(&info_path, format!("no entry for image {key}")))?;
                if v.len() != records.len() {
                    return Err(bad(
                        &info_path,
                        format!(
                            "image {key}: {} entries for {} ground-truth instances",
                            v.len(),
                            records.len()
                        ),
                    ));
                }
                Some(v)
            }
            None => None,
        };
        let mut instances = Vec::new();
        for (k, g) in records.iter().enumerate() {
            let pose = bop_pose(&g.cam_r_m2c, &g.cam_t_m2c)
                .map_err(|m| bad(&gt_path, format!("image {key}, instance {k}: {m}")))?;
            let visible_fraction = info.map_or(1.0, |v| v[k].visib_fract);
            if !(0.0..=1.0).contains(&visible_fraction) {
                return Err(bad(
                    &info_path,
                    format!(
                        "image {key}, instance {k}: visib_fract {visible_fraction} is outside 0..1"
                    ),
                ));
            }
            instances.push(BopInstance {
                obj_id: g.obj_id,
                pose,
                visible_fraction,
            });
        }
        let depth = dir.join("depth").join(format!("{im_id:06}.png"));
        if !depth.is_file() {
            let tif = depth.with_extension("tif");
            let why = if tif.is_file() {
                " (TIFF depth images are not supported; convert them to 16-bit PNG)"
            } else {
                ""
            };
            return Err(bad(&depth, format!("missing depth image{why}")));
        }
        images.push(BopImage {
            scene_id,
            im_id,
            depth,
            intrinsics,
            depth_scale_mm: cam.depth_scale,
            instances,
        });
    }
    images.sort_by_key(|i| i.im_id);
    Ok(images)
}

/// BOP's `cam_R_m2c` (row-major) and `cam_t_m2c` (mm) as a pose; the rotation must be proper.
pub fn bop_pose(r: &[f64; 9], t: &[f64; 3]) -> std::result::Result<Isometry3<f64>, String> {
    let m = Matrix3::from_row_slice(r);
    if !m.iter().chain(t.iter()).all(|v| v.is_finite()) {
        return Err("non-finite pose".into());
    }
    let orthogonality = (m.transpose() * m - Matrix3::identity()).abs().max();
    if orthogonality > 1e-3 || (m.determinant() - 1.0).abs() > 1e-3 {
        return Err(format!(
            "cam_R_m2c is not a rotation (|R^T R - I| = {orthogonality:.2e}, det {:.4})",
            m.determinant()
        ));
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&m));
    Ok(Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        rot,
    ))
}

/// BOP's `cam_R_m2c` (row-major) and `cam_t_m2c` (mm) of a pose.
pub fn to_bop_pose(pose: &Isometry3<f64>) -> ([f64; 9], [f64; 3]) {
    let m = pose.rotation.to_rotation_matrix();
    let m = m.matrix();
    let mut r = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            r[3 * i + j] = m[(i, j)];
        }
    }
    let t = pose.translation.vector;
    (r, [t.x, t.y, t.z])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scene_gt record as BOP publishes them (T-LESS style), read independently of any
    /// writer here: R row-major, t in mm.
    #[test]
    fn reads_a_bop_record_row_major() {
        // A quarter turn about z: x -> y.
        let r = [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let p = bop_pose(&r, &[10.0, -20.0, 700.0]).unwrap();
        let moved = p * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((moved - nalgebra::Point3::new(10.0, -19.0, 700.0)).norm() < 1e-9);
        let (r2, t2) = to_bop_pose(&p);
        for (a, b) in r.iter().zip(&r2) {
            assert!((a - b).abs() < 1e-12);
        }
        assert_eq!(t2, [10.0, -20.0, 700.0]);
        assert!(bop_pose(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0], &[0.0; 3]).is_err());
    }

    #[test]
    fn csv_rows_follow_bop_format() {
        let pose = Isometry3::from_parts(
            Translation3::new(1.5, -2.0, 640.0),
            UnitQuaternion::from_axis_angle(
                &nalgebra::Vector3::z_axis(),
                std::f64::consts::FRAC_PI_2,
            ),
        );
        let d = Detection {
            rank: 1,
            pose,
            initial_pose: pose,
            initial_score: 1.0,
            final_score: 5.0,
            score_before_icp: 5.0,
            found_by: binpick::FoundBy::Voting {
                votes: 10,
                hypothesis: 0,
            },
            view: None,
            icp: binpick::IcpReport {
                converged: true,
                iterations: 1,
                fitness_mm2: None,
                adopted: true,
                unhidden: false,
                polished: false,
                error: None,
            },
            height_mm: 0.0,
            rank_reason: String::new(),
            free_to_pick: true,
            grasps: Vec::new(),
        };
        let ids = BopIds {
            scene_id: 3,
            im_id: 42,
            obj_id: 7,
        };
        let rows = csv_rows(ids, &[d], 0.25);
        let fields: Vec<&str> = rows.trim_end().split(',').collect();
        assert_eq!(fields.len(), 7, "{rows}");
        assert_eq!(&fields[..3], &["3", "42", "7"]);
        assert_eq!(fields[3], "0.95");
        let r: Vec<f64> = fields[4].split(' ').map(|v| v.parse().unwrap()).collect();
        assert_eq!(r.len(), 9);
        // Row-major: R[0][1] = -1 for a quarter turn about z.
        assert!((r[1] + 1.0).abs() < 1e-12 && (r[3] - 1.0).abs() < 1e-12);
        let t: Vec<f64> = fields[5].split(' ').map(|v| v.parse().unwrap()).collect();
        assert_eq!(t, vec![1.5, -2.0, 640.0]);
        assert_eq!(fields[6], "0.25");
    }

    #[test]
    fn model_info_symmetries() {
        let info: BopModelInfo = serde_json::from_str(
            r#"{"diameter": 50.0, "symmetries_discrete": [[-1,0,0,0, 0,-1,0,0, 0,0,1,0, 0,0,0,1]]}"#,
        )
        .unwrap();
        assert_eq!(info.symmetries(1).unwrap().transforms().len(), 2);
        let cont: BopModelInfo = serde_json::from_str(
            r#"{"diameter": 50.0, "symmetries_continuous": [{"axis": [0,0,1], "offset": [0,0,0]}]}"#,
        )
        .unwrap();
        assert!(cont.symmetries(1).unwrap().transforms().len() > 36);
        let bad: BopModelInfo =
            serde_json::from_str(r#"{"diameter": 50.0, "symmetries_discrete": [[1,0,0]]}"#)
                .unwrap();
        assert!(bad.symmetries(1).unwrap_err().to_string().contains("16"));
    }
}
