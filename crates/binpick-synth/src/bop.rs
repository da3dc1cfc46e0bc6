//! A depth-camera set written in BOP's format (<https://bop.felk.cvut.cz>) beside binpick's
//! own (`binpick synth generalisation --bop`): the same scans as 16-bit depth PNGs with camera
//! intrinsics, the same ground truth as `scene_gt.json` in the camera frame, the exact meshes
//! as PLY.
//!
//! ```text
//! <set>/bop/models/models_info.json       diameter, symmetries_discrete, symmetries_continuous
//! <set>/bop/models/obj_<id:06>.ply        the part's mesh, mm (the set's models in order: id 1, 2, ...)
//! <set>/bop/test/000001/scene_camera.json cam_K, depth_scale, cam_R_w2c, cam_t_w2c (scene -> camera)
//! <set>/bop/test/000001/scene_gt.json     cam_R_m2c, cam_t_m2c (mm), obj_id, per image
//! <set>/bop/test/000001/scene_gt_info.json visib_fract (= visible_fraction), px_count_visib, px_count_all
//! <set>/bop/test/000001/depth/<im_id:06>.png  image im_id = scan index of the set
//! ```

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;

use binpick_cloud::dataset::write_json;
use binpick_cloud::depth::{DepthImage, Intrinsics};
use binpick_cloud::pose_to_row_major;

use crate::SynthError;
use crate::depth::DepthCameraConfig;
use crate::generalisation::SetScene;
use crate::generate::io_err;
use crate::mesh::Mesh;
use crate::models::Model;

/// The one scene folder of a set (BOP scene ids start at 1 in most datasets).
pub const SCENE_ID: u32 = 1;

/// Depth units tried, mm per unit: the finest whose 16 bits hold the deepest point.
const DEPTH_SCALES_MM: [f64; 7] = [0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0];

/// The camera's pinhole intrinsics in BOP's convention (pixel centres at integers).
pub fn intrinsics(cam: &DepthCameraConfig) -> Intrinsics {
    Intrinsics {
        fx: cam.focal_px,
        fy: cam.focal_px,
        cx: 0.5 * cam.width as f64 - 0.5,
        cy: 0.5 * cam.height as f64 - 0.5,
    }
}

/// Camera frame -> scene frame (the camera looks down its +z, a half turn about x).
pub fn camera_pose(cam: &DepthCameraConfig) -> Isometry3<f64> {
    let [w, x, y, z] = DepthCameraConfig::ORIENTATION_WXYZ;
    Isometry3::from_parts(
        Translation3::new(cam.position[0], cam.position[1], cam.position[2]),
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z)),
    )
}

fn rotation_row_major(p: &Isometry3<f64>) -> [f64; 9] {
    let m = pose_to_row_major(p);
    [m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]]
}

fn translation(p: &Isometry3<f64>) -> [f64; 3] {
    let t = p.translation.vector;
    [t.x, t.y, t.z]
}

/// One image's `scene_camera.json` entry.
#[derive(Clone, Debug, Serialize)]
pub struct CameraEntry {
    #[serde(rename = "cam_K")]
    pub cam_k: [f64; 9],
    /// mm per depth unit.
    pub depth_scale: f64,
    #[serde(rename = "cam_R_w2c")]
    cam_r_w2c: [f64; 9],
    cam_t_w2c: [f64; 3],
}

/// One instance's `scene_gt.json` entry.
#[derive(Clone, Debug, Serialize)]
pub struct GtEntry {
    #[serde(rename = "cam_R_m2c")]
    cam_r_m2c: [f64; 9],
    cam_t_m2c: [f64; 3],
    obj_id: u32,
}

/// One instance's `scene_gt_info.json` entry.
#[derive(Clone, Debug, Serialize)]
pub struct GtInfoEntry {
    visib_fract: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    px_count_visib: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    px_count_all: Option<u64>,
}

/// One image's records, gathered into the scene's JSON files by [`write_scene_files`].
#[derive(Clone, Debug)]
pub struct ImageRecords {
    pub im_id: u32,
    pub camera: CameraEntry,
    pub gt: Vec<GtEntry>,
    pub gt_info: Vec<GtInfoEntry>,
}

/// Writes scan `im_id`'s depth image under `bop_root` and returns its records. `models` are
/// the set's models in object-id order (id = position + 1).
pub fn write_image(
    bop_root: &Path,
    cam: &DepthCameraConfig,
    scene: &SetScene,
    im_id: u32,
    models: &[&Model],
) -> Result<ImageRecords, SynthError> {
    let scene_to_cam = camera_pose(cam).inverse();
    let points: Vec<[f32; 3]> = scene
        .scan
        .cloud
        .points
        .iter()
        .map(|p| binpick_cloud::transform_point(&scene_to_cam, p))
        .collect();
    let deepest = points.iter().map(|p| f64::from(p[2])).fold(0.0, f64::max);
    let depth_scale = DEPTH_SCALES_MM
        .iter()
        .copied()
        .find(|s| deepest / s < f64::from(u16::MAX) - 1.0)
        .ok_or_else(|| {
            SynthError::Geometry(format!(
                "a point {deepest:.0} mm deep does not fit a 16-bit depth image"
            ))
        })?;
    let k = intrinsics(cam);
    let (image, dropped) = DepthImage::from_points(&points, &k, cam.width, cam.height, depth_scale)
        .map_err(|e| SynthError::Geometry(e.to_string()))?;
    if dropped > 0 {
        return Err(SynthError::Geometry(format!(
            "{dropped} scan point(s) of {} fall outside the depth image",
            scene.id
        )));
    }
    let path = bop_root
        .join("test")
        .join(format!("{SCENE_ID:06}"))
        .join("depth")
        .join(format!("{im_id:06}.png"));
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(io_err(parent))?;
    }
    image
        .write_png(&path)
        .map_err(|e| SynthError::Geometry(e.to_string()))?;
    let mut gt = Vec::new();
    let mut gt_info = Vec::new();
    for g in &scene.gt {
        let Some(obj) = models.iter().position(|m| m.name == g.model) else {
            continue;
        };
        for inst in &g.instances {
            let pose = binpick_cloud::pose_from_row_major(&inst.pose)
                .map_err(|e| SynthError::Geometry(format!("{}: {e}", scene.id)))?;
            let in_cam = scene_to_cam * pose;
            gt.push(GtEntry {
                cam_r_m2c: rotation_row_major(&in_cam),
                cam_t_m2c: translation(&in_cam),
                obj_id: obj as u32 + 1,
            });
            gt_info.push(GtInfoEntry {
                visib_fract: inst.visible_fraction,
                px_count_visib: inst.visible_points,
                px_count_all: inst.alone_points,
            });
        }
    }
    Ok(ImageRecords {
        im_id,
        camera: CameraEntry {
            cam_k: k.to_k(),
            depth_scale,
            cam_r_w2c: rotation_row_major(&scene_to_cam),
            cam_t_w2c: translation(&scene_to_cam),
        },
        gt,
        gt_info,
    })
}

/// Writes the scene's `scene_camera.json`, `scene_gt.json` and `scene_gt_info.json`.
pub fn write_scene_files(bop_root: &Path, images: &[ImageRecords]) -> Result<(), SynthError> {
    let dir = bop_root.join("test").join(format!("{SCENE_ID:06}"));
    // Integer keys: written as strings, in numeric order.
    let camera: BTreeMap<u32, &CameraEntry> = images.iter().map(|i| (i.im_id, &i.camera)).collect();
    let gt: BTreeMap<u32, &Vec<GtEntry>> = images.iter().map(|i| (i.im_id, &i.gt)).collect();
    let info: BTreeMap<u32, &Vec<GtInfoEntry>> =
        images.iter().map(|i| (i.im_id, &i.gt_info)).collect();
    write_json(&dir.join("scene_camera.json"), &camera)?;
    write_json(&dir.join("scene_gt.json"), &gt)?;
    write_json(&dir.join("scene_gt_info.json"), &info)?;
    Ok(())
}

#[derive(Serialize)]
struct ModelsInfoEntry {
    diameter: f64,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    symmetries_discrete: Vec<[f64; 16]>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    symmetries_continuous: Vec<ContinuousEntry>,
}

#[derive(Serialize)]
struct ContinuousEntry {
    axis: [f64; 3],
    offset: [f64; 3],
}

/// Writes `models/obj_<id>.ply` and `models/models_info.json` for `models` (id = position + 1).
pub fn write_models(bop_root: &Path, models: &[&Model]) -> Result<(), SynthError> {
    let dir = bop_root.join("models");
    std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
    let mut info = BTreeMap::new();
    for (k, m) in models.iter().enumerate() {
        let id = k + 1;
        write_ply_mesh(&dir.join(format!("obj_{id:06}.ply")), &m.mesh)?;
        let axis = m.revolution_axis.filter(|_| !m.cut);
        // With an axis, the listed rotations about it are its samples: BOP declares it as a
        // continuous symmetry and lists only the other transforms (e.g. a flip).
        let about_axis = |s: &Isometry3<f64>| {
            axis.is_some_and(|a| {
                let d: Vector3<f64> = a.direction.into_inner();
                (s.rotation * d).dot(&d) > 1.0 - 1e-6 && (s * a.point - a.point).norm() < 1e-6
            })
        };
        let discrete: Vec<[f64; 16]> = m
            .symmetries
            .iter()
            .filter(|s| !(s.rotation.angle() < 1e-9 && s.translation.vector.norm() < 1e-9))
            .filter(|s| !about_axis(s))
            .map(pose_to_row_major)
            .collect();
        let continuous = axis
            .map(|a| ContinuousEntry {
                axis: a.direction.into_inner().into(),
                offset: a.point.coords.into(),
            })
            .into_iter()
            .collect();
        info.insert(
            id.to_string(),
            ModelsInfoEntry {
                diameter: m.diameter,
                symmetries_discrete: discrete,
                symmetries_continuous: continuous,
            },
        );
    }
    write_json(&dir.join("models_info.json"), &info)?;
    Ok(())
}

/// An ASCII PLY mesh (vertices in mm, triangles as `vertex_indices`).
fn write_ply_mesh(path: &Path, mesh: &Mesh) -> Result<(), SynthError> {
    use std::fmt::Write;
    let mut s = format!(
        "ply\nformat ascii 1.0\ncomment binpick-synth part mesh, mm\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.triangles.len()
    );
    for v in &mesh.vertices {
        let _ = writeln!(s, "{} {} {}", v[0], v[1], v[2]);
    }
    for t in &mesh.triangles {
        let _ = writeln!(s, "3 {} {} {}", t[0], t[1], t[2]);
    }
    std::fs::write(path, s).map_err(io_err(path))
}

/// What `bop/README.txt` says.
pub const README: &str = "\
The depth-camera scans of this set in BOP's format (https://bop.felk.cvut.cz), written by
binpick-synth beside binpick's own layout in the folder above: the same scans as 16-bit depth
PNGs (z = value x depth_scale mm) with pinhole intrinsics cam_K, the same ground truth in the
camera frame (cam_R_m2c row-major, cam_t_m2c in mm; visib_fract = visible_fraction), the exact
part meshes as PLY (obj_000001 = the set's target part, then its clutter parts).
Evaluate with `binpick eval <this folder> --model 1`.
";
