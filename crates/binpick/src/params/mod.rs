//! Every tunable number of the pipeline, in one place. `Params::default()` is the thesis's
//! chapter 4.3 configuration; [`Preset`]s reproduce its test configurations (5.5.1, 5.6.1).
//! Lengths are millimetres, like the thesis.

use serde::{Deserialize, Serialize};

use binpick_cloud::Units;

/// Which initial-alignment algorithm to run (thesis chapter 4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Algorithm {
    /// Algorithm 1 (4.1, "separated FPFH"): one RANSAC sweep per FPFH radius, best score kept.
    /// More attempts, higher recognition rate (5.3.3).
    #[default]
    #[serde(rename = "1")]
    SeparatedFpfh,
    /// Algorithm 2 (4.2, "merged FPFH"): correspondences of all radii merged (best per model
    /// keypoint), then one RANSAC sweep. About 20 % faster (5.3.3).
    #[serde(rename = "2")]
    MergedFpfh,
}

impl Algorithm {
    pub fn number(self) -> u8 {
        match self {
            Algorithm::SeparatedFpfh => 1,
            Algorithm::MergedFpfh => 2,
        }
    }
}

impl std::str::FromStr for Algorithm {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "1" => Ok(Algorithm::SeparatedFpfh),
            "2" => Ok(Algorithm::MergedFpfh),
            other => Err(format!("unknown algorithm {other:?}: expected 1 or 2")),
        }
    }
}

/// The cloud FPFH neighbourhoods are searched in (thesis 3.3.2 leaves this open).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FeatureSurface {
    /// The uniform keypoints themselves (initial leaf): ~leaf^2 fewer neighbours, so FPFH is
    /// an order of magnitude faster, with descriptors still averaged over the same radius.
    #[default]
    Keypoints,
    /// The full-resolution cluster (and model) cloud.
    Cloud,
}

/// Axis-aligned region of interest in scene coordinates, mm. Points outside are dropped
/// before anything else.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegionOfInterest {
    pub min_mm: [f64; 3],
    pub max_mm: [f64; 3],
}

/// Removal of the supporting surface (belt, bin floor, walls) by RANSAC plane fits. Not in
/// the thesis (its scans were clustered directly), but real scans contain the belt and
/// Euclidean clustering merges everything that touches it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SupportRemoval {
    /// Fit and remove planes at all. Default true.
    pub enabled: bool,
    /// Points closer than this to a plane belong to it, mm. Default 1.5 (1.5 x resolution):
    /// above the scanner noise, below the thickness of a 2 mm sheet lying flat. Range 0.1-20.
    pub distance_mm: f64,
    /// At most this many planes are removed (floor + up to four bin walls). Default 5, 0-20.
    pub max_planes: u32,
    /// A plane is support only if it has more points than this multiple of the model's point
    /// count - more than the largest cluster a part may form (cluster_max_factor), so a flat
    /// part is never taken for the belt. Default 3.0, range >= 1.
    pub min_points_factor: f64,
    /// RANSAC iterations per plane fit. Default 200, range 1-100000.
    pub ransac_iterations: u32,
}

impl Default for SupportRemoval {
    fn default() -> Self {
        Self {
            enabled: true,
            distance_mm: 1.5,
            max_planes: 5,
            min_points_factor: 3.0,
            ransac_iterations: 200,
        }
    }
}

/// All parameters of a recognition. Defaults: thesis 4.3 (section numbers in each field's
/// doc). Every length is in millimetres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Params {
    /// Initial-alignment algorithm (4.1 / 4.2). Default 1, the thesis's choice (5.3.3).
    pub algorithm: Algorithm,
    /// Units of the input clouds; they are scaled to mm on load. Default mm.
    pub units: Units,

    /// Scan resolution: voxel-grid leaf applied to scene and model on load, mm (4.3 #1).
    /// Default 1.0, range 0.01-100.
    pub resolution_mm: f64,
    /// Optional crop of the scene before anything else.
    pub region_of_interest: Option<RegionOfInterest>,
    /// Supporting-surface removal.
    pub support: SupportRemoval,

    /// Cluster tolerance as a multiple of the resolution (4.3 #2, 5.3.1). Default 1.5
    /// (150 %); the thesis uses 1.8 for robot-arm scans (5.6). Range 1.0-10.
    pub cluster_tolerance_factor: f64,
    /// Smallest cluster, as a fraction of the model's point count (4.3 #3). Default 0.3.
    /// Range (0, 1].
    pub cluster_min_factor: f64,
    /// Largest cluster, as a multiple of the model's point count (4.3 #4). Default 3.0.
    /// Range 1-1000.
    pub cluster_max_factor: f64,

    /// Leaf of the uniform keypoints for the initial alignment, mm (4.3 #5, 3.2.3).
    /// Default 3.0, range 0.01-100.
    pub initial_leaf_mm: f64,
    /// FPFH radii to try, mm (4.3 #6, 3.3.2). Default {10, 15, 20, 25, 30}.
    pub fpfh_radii_mm: Vec<f64>,
    /// Normal radius as a fraction of the FPFH radius (4.3 #7, 3.3.2.1). Default 0.8,
    /// range (0, 1].
    pub normal_radius_factor: f64,
    /// Where FPFH neighbourhoods are searched. Default keypoints (see [`FeatureSurface`]).
    pub feature_surface: FeatureSurface,
    /// RANSAC inlier thresholds to sweep, mm (4.3 #8, 3.4.2.5). Default 1, 2, ..., 20.
    pub sac_thresholds_mm: Vec<f64>,
    /// RANSAC iterations per threshold (3.4.2.5). Default 50, range 1-100000.
    pub sac_iterations: u32,
    /// Consensus sets tried per threshold: 1 is the thesis (RANSAC's largest consensus only);
    /// 2 also runs RANSAC on the correspondences the first set left out, so the true pose of a
    /// nearly symmetric part is scored even when its flipped pose gathers more matches.
    /// Default 2, range 1-10 (thesis_strict uses 1).
    pub consensus_modes: u32,
    /// Also score each cluster's best initial hypotheses composed with the model's
    /// near-symmetries (half-turns about its principal axes, refined on the model itself), so
    /// a nearly symmetric part matched flipped is corrected by the Euclidean score. Not in the
    /// thesis; off in thesis_strict mode. Default true.
    pub symmetry_candidates: bool,
    /// A cluster with more points than this multiple of the model is searched in overlapping
    /// spheres of 1.5 model radii (thesis 3.4.1.2) instead of whole: in a pile, whole-cluster
    /// correspondences are spread over many parts. Not in the thesis's final algorithm; off in
    /// thesis_strict mode. Default 1.5, range >= 1.
    pub sphere_split_factor: f64,
    /// Distance between sphere centres, in model radii. Measured against 1.5 on our sets:
    /// 1.0 recognises more in bins (arm-A 43.8 vs 38.4 %, arm-C 52.1 vs 50.0 %), 1.5 more of
    /// B (74.2 vs 71.0 %) and halves the p95 time per scene (fewer, less overlapping
    /// spheres). Default 1.0, range 0.5-3.
    pub sphere_spacing_factor: f64,
    /// When the best initial alignment fails the final validation, the next best distinct
    /// ones (pose differing by more than 10 % of the model diameter or 15 deg) go through ICP
    /// too, up to this many in all; the first one accepted is kept. The thesis keeps only the
    /// best. Default 1 (the thesis): on our conveyor sets 3 found no more parts and added
    /// false positives (README, Results). Range 1-20; thesis_strict uses 1.
    pub final_candidates: u32,
    /// Keep an initial alignment only if its Euclidean score (mean squared distance, mm^2,
    /// 3.1.1) is below this (4.3 #9). Default 100, range > 0.
    pub initial_score_max: f64,

    /// Leaf of the uniform keypoints for the final alignment, mm (4.3 #10). Default 2.0.
    pub final_leaf_mm: f64,
    /// ICP iteration cap (4.3 #11, 3.6.1). Default 50, range 1-10000.
    pub icp_iterations: u32,
    /// ICP transformation epsilon (4.3 #11). Default 1e-7, range > 0.
    pub icp_transformation_epsilon: f64,
    /// ICP also stops when the mean squared correspondence distance changes by less than this
    /// fraction between iterations (PCL's Euclidean fitness epsilon). The thesis stops only at
    /// 50 iterations or epsilon 1e-7, which in millimetres almost never triggers, so its ICP
    /// always runs 50 iterations. 0 = off; off in thesis_strict mode. Default 1e-4, range 0-0.1.
    pub icp_relative_mse: f64,
    /// ICP max correspondence distance, mm. The thesis leaves PCL's default (unbounded);
    /// bounding it keeps occluders from dragging a part. Default 10.0, range > 0.
    pub icp_max_correspondence_mm: f64,
    /// After the thesis's ICP on final keypoints, a second ICP of the model at scan resolution
    /// onto the scene at scan resolution (correspondences within 2 x resolution) removes the
    /// keypoint-sampling ripples that can leave a part slid along its bend line. Not in the
    /// thesis; off in thesis_strict mode. Default true.
    pub icp_refine: bool,
    /// A model point farther than this from the scene is an outlier, mm (3.1.2.2). Default 4.0.
    pub outlier_distance_mm: f64,
    /// Keep a final alignment only if its percent of outliers is below this (4.3 #12).
    /// Default 20, range (0, 100].
    pub final_score_max_pct: f64,

    /// Sensor position in scene coordinates, mm; surface normals are flipped towards it.
    /// Default straight above (0, 0, 1e6): scanners looking down along -z.
    pub scene_viewpoint_mm: [f64; 3],
    /// Sensor position in the model's frame, mm (where the model was scanned from).
    /// Default (0, 0, 1e6).
    pub model_viewpoint_mm: [f64; 3],
    /// Up direction of the scene (for "highest in the pile"). Default +z.
    pub up: [f64; 3],

    /// Run the thesis exactly: one detection per cluster, no search of touching parts, no
    /// duplicate suppression. Default false.
    pub thesis_strict: bool,
    /// Duplicate suppression: two detections are the same instance when this fraction of one's
    /// model points lies within the outlier distance of the other's. Default 0.5, (0, 1].
    pub duplicate_overlap: f64,
    /// Pick ranking: final scores in the same band of this width (percentage points) count as
    /// equal and the higher part is picked first. Default 2.0, range >= 0 (0 = score only).
    pub rank_score_band_pct: f64,

    /// Worker threads: clusters run in parallel, PCL's OpenMP stages use the same count
    /// when not nested. 0 = all cores. Results do not depend on it.
    pub threads: usize,
    /// Time budget per recognition, ms; exceeding it is an error. None = unlimited.
    pub time_budget_ms: Option<u64>,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            algorithm: Algorithm::SeparatedFpfh,
            units: Units::Millimetres,
            resolution_mm: 1.0,
            region_of_interest: None,
            support: SupportRemoval::default(),
            cluster_tolerance_factor: 1.5,
            cluster_min_factor: 0.3,
            cluster_max_factor: 3.0,
            initial_leaf_mm: 3.0,
            fpfh_radii_mm: vec![10.0, 15.0, 20.0, 25.0, 30.0],
            normal_radius_factor: 0.8,
            feature_surface: FeatureSurface::Keypoints,
            sac_thresholds_mm: (1..=20).map(f64::from).collect(),
            sac_iterations: 50,
            consensus_modes: 2,
            symmetry_candidates: true,
            sphere_split_factor: 1.5,
            sphere_spacing_factor: 1.0,
            final_candidates: 1,
            initial_score_max: 100.0,
            final_leaf_mm: 2.0,
            icp_iterations: 50,
            icp_transformation_epsilon: 1e-7,
            icp_max_correspondence_mm: 10.0,
            icp_refine: true,
            icp_relative_mse: 1e-4,
            outlier_distance_mm: 4.0,
            final_score_max_pct: 20.0,
            scene_viewpoint_mm: [0.0, 0.0, 1e6],
            model_viewpoint_mm: [0.0, 0.0, 1e6],
            up: [0.0, 0.0, 1.0],
            thesis_strict: false,
            duplicate_overlap: 0.5,
            rank_score_band_pct: 2.0,
            threads: 0,
            time_budget_ms: None,
        }
    }
}

/// The thesis's named test configurations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// Chapter 4.3 defaults.
    Thesis,
    /// Conveyor, object A (5.5.1.1).
    A,
    /// Conveyor, object B (5.5.1.2).
    B,
    /// Conveyor, object C, full model (5.5.1.3).
    C1,
    /// Conveyor, object C, finer keypoints (5.5.1.3).
    C2,
    /// Conveyor, object C, cut model (5.5.1.3).
    C3,
    /// Robot arm, object A (5.6.1.1).
    ArmA,
    /// Robot arm, object C, cut model (5.6.1.2).
    ArmC,
}

impl Preset {
    pub const ALL: [Preset; 8] = [
        Preset::Thesis,
        Preset::A,
        Preset::B,
        Preset::C1,
        Preset::C2,
        Preset::C3,
        Preset::ArmA,
        Preset::ArmC,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Preset::Thesis => "thesis",
            Preset::A => "A",
            Preset::B => "B",
            Preset::C1 => "C1",
            Preset::C2 => "C2",
            Preset::C3 => "C3",
            Preset::ArmA => "arm-A",
            Preset::ArmC => "arm-C",
        }
    }

    /// The parameters of this configuration.
    pub fn params(self) -> Params {
        let odd_thresholds: Vec<f64> = (0..10).map(|i| f64::from(2 * i + 1)).collect();
        // 5.5: fixed for all conveyor tests.
        let conveyor = Params {
            algorithm: Algorithm::SeparatedFpfh,
            resolution_mm: 1.0,
            cluster_tolerance_factor: 1.5,
            cluster_min_factor: 0.3,
            cluster_max_factor: 10.0,
            sac_thresholds_mm: odd_thresholds.clone(),
            ..Params::default()
        };
        // 5.6: fixed for all robot-arm tests.
        let arm = Params {
            cluster_tolerance_factor: 1.8,
            cluster_max_factor: 5.0,
            ..conveyor.clone()
        };
        let leaves = |p: Params, initial: f64, fin: f64| Params {
            initial_leaf_mm: initial,
            final_leaf_mm: fin,
            ..p
        };
        let scores = |p: Params, initial: f64, fin: f64| Params {
            initial_score_max: initial,
            final_score_max_pct: fin,
            ..p
        };
        let radii = |p: Params, r: [f64; 4]| Params {
            fpfh_radii_mm: r.to_vec(),
            ..p
        };
        match self {
            Preset::Thesis => Params::default(),
            Preset::A | Preset::B | Preset::C1 => radii(
                scores(leaves(conveyor, 3.0, 2.0), 200.0, 20.0),
                [5.0, 10.0, 15.0, 20.0],
            ),
            Preset::C2 => radii(
                scores(leaves(conveyor, 2.0, 1.5), 200.0, 25.0),
                [5.0, 9.0, 13.0, 17.0],
            ),
            Preset::C3 => radii(
                scores(leaves(conveyor, 2.0, 1.5), 100.0, 15.0),
                [3.0, 6.0, 9.0, 12.0],
            ),
            Preset::ArmA => radii(
                scores(leaves(arm, 3.0, 2.0), 100.0, 20.0),
                [5.0, 10.0, 15.0, 20.0],
            ),
            Preset::ArmC => radii(
                scores(leaves(arm, 2.0, 1.5), 100.0, 15.0),
                [3.0, 6.0, 9.0, 12.0],
            ),
        }
    }
}

impl std::str::FromStr for Preset {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Preset::ALL
            .into_iter()
            .find(|p| p.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| {
                let names: Vec<_> = Preset::ALL.iter().map(|p| p.name()).collect();
                format!("unknown preset {s:?}: expected one of {}", names.join(", "))
            })
    }
}

/// A parameter outside its documented range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("parameter {field} = {value}: {expected}")]
pub struct ParamError {
    pub field: &'static str,
    pub value: String,
    pub expected: &'static str,
}

fn check_range(
    field: &'static str,
    v: f64,
    lo: f64,
    hi: f64,
    expected: &'static str,
) -> Result<(), ParamError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(ParamError {
            field,
            value: v.to_string(),
            expected,
        })
    }
}

fn check_open_low(
    field: &'static str,
    v: f64,
    hi: f64,
    expected: &'static str,
) -> Result<(), ParamError> {
    if v.is_finite() && v > 0.0 && v <= hi {
        Ok(())
    } else {
        Err(ParamError {
            field,
            value: v.to_string(),
            expected,
        })
    }
}

fn check_count(
    field: &'static str,
    v: u64,
    lo: u64,
    hi: u64,
    expected: &'static str,
) -> Result<(), ParamError> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(ParamError {
            field,
            value: v.to_string(),
            expected,
        })
    }
}

fn check_list(
    field: &'static str,
    v: &[f64],
    hi: f64,
    expected: &'static str,
) -> Result<(), ParamError> {
    let bad = v.is_empty()
        || v.len() > 1000
        || v.iter().any(|x| !(x.is_finite() && *x > 0.0 && *x <= hi));
    if bad {
        Err(ParamError {
            field,
            value: format!("{v:?}"),
            expected,
        })
    } else {
        Ok(())
    }
}

fn check_vec3(field: &'static str, v: [f64; 3], nonzero: bool) -> Result<(), ParamError> {
    let finite = v.iter().all(|c| c.is_finite());
    let norm = v.iter().map(|c| c * c).sum::<f64>().sqrt();
    if finite && (!nonzero || norm > 1e-9) {
        Ok(())
    } else {
        Err(ParamError {
            field,
            value: format!("{v:?}"),
            expected: if nonzero {
                "three finite numbers, not all zero"
            } else {
                "three finite numbers"
            },
        })
    }
}

impl Params {
    /// Rejects any value outside its documented range, naming the field.
    pub fn validate(&self) -> Result<(), ParamError> {
        check_range(
            "resolution_mm",
            self.resolution_mm,
            0.01,
            100.0,
            "expected 0.01-100 mm",
        )?;
        check_range(
            "support.distance_mm",
            self.support.distance_mm,
            0.1,
            20.0,
            "expected 0.1-20 mm",
        )?;
        check_count(
            "support.max_planes",
            self.support.max_planes.into(),
            0,
            20,
            "expected 0-20",
        )?;
        check_range(
            "support.min_points_factor",
            self.support.min_points_factor,
            1.0,
            1e6,
            "expected >= 1",
        )?;
        check_count(
            "support.ransac_iterations",
            self.support.ransac_iterations.into(),
            1,
            100_000,
            "expected 1-100000",
        )?;
        check_range(
            "cluster_tolerance_factor",
            self.cluster_tolerance_factor,
            1.0,
            10.0,
            "expected 1.0-10 (a multiple of the resolution, > 1 per thesis 3.4.1.3)",
        )?;
        check_open_low(
            "cluster_min_factor",
            self.cluster_min_factor,
            1.0,
            "expected a fraction in (0, 1]",
        )?;
        check_range(
            "cluster_max_factor",
            self.cluster_max_factor,
            1.0,
            1000.0,
            "expected 1-1000",
        )?;
        check_range(
            "initial_leaf_mm",
            self.initial_leaf_mm,
            0.01,
            100.0,
            "expected 0.01-100 mm",
        )?;
        check_list(
            "fpfh_radii_mm",
            &self.fpfh_radii_mm,
            1000.0,
            "expected a non-empty list of radii in (0, 1000] mm",
        )?;
        check_open_low(
            "normal_radius_factor",
            self.normal_radius_factor,
            1.0,
            "expected a fraction in (0, 1]",
        )?;
        check_list(
            "sac_thresholds_mm",
            &self.sac_thresholds_mm,
            1000.0,
            "expected a non-empty list of thresholds in (0, 1000] mm",
        )?;
        check_count(
            "sac_iterations",
            self.sac_iterations.into(),
            1,
            100_000,
            "expected 1-100000",
        )?;
        check_open_low(
            "initial_score_max",
            self.initial_score_max,
            1e12,
            "expected a positive score (mm^2)",
        )?;
        check_range(
            "final_leaf_mm",
            self.final_leaf_mm,
            0.01,
            100.0,
            "expected 0.01-100 mm",
        )?;
        check_count(
            "icp_iterations",
            self.icp_iterations.into(),
            1,
            10_000,
            "expected 1-10000",
        )?;
        check_open_low(
            "icp_transformation_epsilon",
            self.icp_transformation_epsilon,
            1.0,
            "expected a small positive number",
        )?;
        check_range(
            "sphere_split_factor",
            self.sphere_split_factor,
            1.0,
            1000.0,
            "expected 1-1000 (x the model's points)",
        )?;
        check_range(
            "sphere_spacing_factor",
            self.sphere_spacing_factor,
            0.5,
            3.0,
            "expected 0.5-3 model radii",
        )?;
        check_count(
            "final_candidates",
            self.final_candidates.into(),
            1,
            20,
            "expected 1-20",
        )?;
        check_range(
            "icp_relative_mse",
            self.icp_relative_mse,
            0.0,
            0.1,
            "expected 0 (off) to 0.1",
        )?;
        check_open_low(
            "icp_max_correspondence_mm",
            self.icp_max_correspondence_mm,
            1e6,
            "expected a positive distance in mm",
        )?;
        check_open_low(
            "outlier_distance_mm",
            self.outlier_distance_mm,
            1000.0,
            "expected (0, 1000] mm",
        )?;
        check_open_low(
            "final_score_max_pct",
            self.final_score_max_pct,
            100.0,
            "expected a percentage in (0, 100]",
        )?;
        check_vec3("scene_viewpoint_mm", self.scene_viewpoint_mm, false)?;
        check_vec3("model_viewpoint_mm", self.model_viewpoint_mm, false)?;
        check_vec3("up", self.up, true)?;
        check_open_low(
            "duplicate_overlap",
            self.duplicate_overlap,
            1.0,
            "expected a fraction in (0, 1]",
        )?;
        check_range(
            "rank_score_band_pct",
            self.rank_score_band_pct,
            0.0,
            100.0,
            "expected 0-100 percentage points",
        )?;
        check_count(
            "threads",
            self.threads as u64,
            0,
            1024,
            "expected 0 (all cores) to 1024",
        )?;
        if let Some(ms) = self.time_budget_ms {
            check_count("time_budget_ms", ms, 1, 86_400_000, "expected 1 ms to 24 h")?;
        }
        if let Some(roi) = &self.region_of_interest {
            let ok = (0..3).all(|i| {
                roi.min_mm[i].is_finite()
                    && roi.max_mm[i].is_finite()
                    && roi.min_mm[i] < roi.max_mm[i]
            });
            if !ok {
                return Err(ParamError {
                    field: "region_of_interest",
                    value: format!("{roi:?}"),
                    expected: "finite bounds with min < max on every axis",
                });
            }
        }
        Ok(())
    }

    /// Parses a TOML config. Keys not given keep their defaults (or the base preset's, see
    /// [`Params::from_toml_over`]); unknown keys are an error.
    pub fn from_toml(text: &str) -> Result<Self, toml::de::Error> {
        toml::from_str(text)
    }

    /// Applies the keys of a TOML config on top of `base` (e.g. a preset): keys not in the file
    /// keep `base`'s values, nested tables (`[support]`) merge key by key, unknown keys are an
    /// error.
    pub fn from_toml_over(base: &Params, text: &str) -> Result<Self, toml::de::Error> {
        fn merge(into: &mut toml::Table, from: toml::Table) {
            for (k, v) in from {
                match (into.get_mut(&k), v) {
                    (Some(toml::Value::Table(a)), toml::Value::Table(b)) => merge(a, b),
                    (_, v) => {
                        into.insert(k, v);
                    }
                }
            }
        }
        let overrides: toml::Table = toml::from_str(text)?;
        let mut table: toml::Table = toml::from_str(&base.to_toml())?;
        merge(&mut table, overrides);
        table.try_into()
    }

    /// The config as TOML (the file written next to every output).
    pub fn to_toml(&self) -> String {
        // Serialising plain data with finite floats cannot fail; fall back to Debug if it does.
        toml::to_string_pretty(self)
            .unwrap_or_else(|e| format!("# could not serialise params: {e}\n# {self:?}\n"))
    }

    /// The ICP relative-MSE stop in effect (0 in thesis_strict mode).
    pub fn effective_icp_relative_mse(&self) -> f64 {
        if self.thesis_strict {
            0.0
        } else {
            self.icp_relative_mse
        }
    }

    /// Initial alignments tried through the final alignment (1 in thesis_strict mode).
    pub fn effective_final_candidates(&self) -> usize {
        if self.thesis_strict {
            1
        } else {
            self.final_candidates as usize
        }
    }

    /// Cluster tolerance in mm.
    pub fn cluster_tolerance_mm(&self) -> f64 {
        self.cluster_tolerance_factor * self.resolution_mm
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_thesis_4_3() {
        let p = Params::default();
        assert_eq!(p.resolution_mm, 1.0);
        assert_eq!(p.cluster_tolerance_mm(), 1.5);
        assert_eq!((p.cluster_min_factor, p.cluster_max_factor), (0.3, 3.0));
        assert_eq!(p.initial_leaf_mm, 3.0);
        assert_eq!(p.fpfh_radii_mm, vec![10.0, 15.0, 20.0, 25.0, 30.0]);
        assert_eq!(p.normal_radius_factor, 0.8);
        assert_eq!(p.sac_thresholds_mm.len(), 20);
        assert_eq!(
            (p.sac_thresholds_mm[0], p.sac_thresholds_mm[19]),
            (1.0, 20.0)
        );
        assert_eq!(p.initial_score_max, 100.0);
        assert_eq!(p.final_leaf_mm, 2.0);
        assert_eq!((p.icp_iterations, p.icp_transformation_epsilon), (50, 1e-7));
        assert_eq!(p.outlier_distance_mm, 4.0);
        assert_eq!(p.final_score_max_pct, 20.0);
        assert_eq!(p.algorithm, Algorithm::SeparatedFpfh);
        p.validate().unwrap();
    }

    #[test]
    fn presets_match_the_thesis_tables() {
        let c3 = Preset::C3.params();
        assert_eq!((c3.initial_leaf_mm, c3.final_leaf_mm), (2.0, 1.5));
        assert_eq!(
            (c3.initial_score_max, c3.final_score_max_pct),
            (100.0, 15.0)
        );
        assert_eq!(c3.fpfh_radii_mm, vec![3.0, 6.0, 9.0, 12.0]);
        assert_eq!(
            c3.sac_thresholds_mm,
            vec![1.0, 3.0, 5.0, 7.0, 9.0, 11.0, 13.0, 15.0, 17.0, 19.0]
        );
        assert_eq!(c3.cluster_max_factor, 10.0);
        let arm = Preset::ArmA.params();
        assert_eq!(
            (arm.cluster_tolerance_factor, arm.cluster_max_factor),
            (1.8, 5.0)
        );
        assert_eq!(
            (arm.initial_score_max, arm.final_score_max_pct),
            (100.0, 20.0)
        );
        let c2 = Preset::C2.params();
        assert_eq!(c2.fpfh_radii_mm, vec![5.0, 9.0, 13.0, 17.0]);
        assert_eq!(c2.final_score_max_pct, 25.0);
        for p in Preset::ALL {
            p.params().validate().unwrap();
            assert_eq!(p.name().parse::<Preset>().unwrap(), p);
        }
        assert!("Z9".parse::<Preset>().unwrap_err().contains("arm-C"));
    }

    #[test]
    fn toml_round_trip_and_unknown_keys() {
        let p = Preset::C2.params();
        let back = Params::from_toml(&p.to_toml()).unwrap();
        assert_eq!(back, p);
        let partial = Params::from_toml("resolution_mm = 2.0\nalgorithm = \"2\"\n").unwrap();
        assert_eq!(partial.resolution_mm, 2.0);
        assert_eq!(partial.algorithm, Algorithm::MergedFpfh);
        assert_eq!(partial.initial_leaf_mm, 3.0);
        assert!(Params::from_toml("resolutoin_mm = 2.0").is_err());
        let over = Params::from_toml_over(
            &Preset::C3.params(),
            "final_leaf_mm = 1.0\n[support]\ndistance_mm = 2.5\n",
        )
        .unwrap();
        assert_eq!(over.final_leaf_mm, 1.0);
        assert_eq!(over.support.distance_mm, 2.5);
        assert_eq!(
            over.support.max_planes, 5,
            "other [support] keys keep the base value"
        );
        assert_eq!(
            over.fpfh_radii_mm,
            vec![3.0, 6.0, 9.0, 12.0],
            "preset values survive"
        );
        assert!(Params::from_toml_over(&Params::default(), "[support]\nbogus = 1").is_err());
        let metres = Params::from_toml("units = \"m\"").unwrap();
        assert_eq!(metres.units, Units::Metres);
    }

    #[test]
    fn absurd_values_are_rejected_by_name() {
        let cases: Vec<(Params, &str)> = vec![
            (
                Params {
                    resolution_mm: 0.0,
                    ..Params::default()
                },
                "resolution_mm",
            ),
            (
                Params {
                    resolution_mm: f64::NAN,
                    ..Params::default()
                },
                "resolution_mm",
            ),
            (
                Params {
                    fpfh_radii_mm: vec![],
                    ..Params::default()
                },
                "fpfh_radii_mm",
            ),
            (
                Params {
                    fpfh_radii_mm: vec![10.0, -1.0],
                    ..Params::default()
                },
                "fpfh_radii_mm",
            ),
            (
                Params {
                    sac_thresholds_mm: vec![f64::INFINITY],
                    ..Params::default()
                },
                "sac_thresholds_mm",
            ),
            (
                Params {
                    cluster_min_factor: 1.5,
                    ..Params::default()
                },
                "cluster_min_factor",
            ),
            (
                Params {
                    cluster_tolerance_factor: 0.5,
                    ..Params::default()
                },
                "cluster_tolerance_factor",
            ),
            (
                Params {
                    final_score_max_pct: 150.0,
                    ..Params::default()
                },
                "final_score_max_pct",
            ),
            (
                Params {
                    icp_iterations: 0,
                    ..Params::default()
                },
                "icp_iterations",
            ),
            (
                Params {
                    up: [0.0; 3],
                    ..Params::default()
                },
                "up",
            ),
            (
                Params {
                    time_budget_ms: Some(0),
                    ..Params::default()
                },
                "time_budget_ms",
            ),
            (
                Params {
                    region_of_interest: Some(RegionOfInterest {
                        min_mm: [0.0; 3],
                        max_mm: [1.0, -1.0, 1.0],
                    }),
                    ..Params::default()
                },
                "region_of_interest",
            ),
        ];
        for (p, field) in cases {
            let e = p.validate().unwrap_err();
            assert_eq!(e.field, field, "{e}");
            assert!(e.to_string().contains(field));
        }
    }
}
