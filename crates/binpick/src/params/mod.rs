//! Every tunable number of the pipeline. One config per stage ([`stages`]), each declaring
//! its fields' defaults and ranges once; [`Params`] is their sum, the TOML-facing struct
//! (flat keys plus the `[support]` table). `Params::default()` is the thesis's chapter 4.3
//! configuration; [`Preset`]s reproduce its test configurations (5.5.1, 5.6.1). Lengths are
//! millimetres, like the thesis.

pub(crate) mod spec;
pub mod stages;

use serde::{Deserialize, Serialize};

use binpick_cloud::Units;

pub use stages::{
    ClusteringConfig, ConsensusConfig, Engine, FeatureConfig, FeatureSurface, IcpConfig,
    PileSearchConfig, PreprocessConfig, RankingConfig, RegionOfInterest, RuntimeConfig,
    SensorConfig, SupportRemoval, ValidationConfig, VerifyConfig, VotingConfig,
};

/// The thesis's scan resolution (4.3 #1), mm: what the presets use.
pub const THESIS_RESOLUTION_MM: f64 = 1.0;
/// The thesis presets' support-plane distance: 1.5 x the resolution, mm.
pub const THESIS_SUPPORT_DISTANCE_MM: f64 = 1.5;

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
    /// The thesis's number of the algorithm: 1 or 2.
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

/// All parameters of a recognition: the stage configs, flattened into one TOML table (keys
/// as in earlier versions; unknown keys are an error). Defaults: thesis 4.3.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Params {
    /// Which engine finds the parts. Default scene-voting; `thesis_strict` selects thesis.
    pub engine: Engine,
    /// Initial-alignment algorithm of the thesis engine (4.1 / 4.2). Default 1, the thesis's
    /// choice (5.3.3).
    pub algorithm: Algorithm,
    /// Units of the input clouds; they are scaled to mm on load. Default mm.
    pub units: Units,
    /// Run the thesis exactly: switches every extension off (one detection per cluster, no
    /// search of touching parts, shared RANSAC draws, no duplicate suppression, ...; see
    /// [`Params::stages`]). Default false.
    pub thesis_strict: bool,
    /// Stage 1: crop, strays, units check, voxel grid, support removal.
    #[serde(flatten)]
    pub preprocess: PreprocessConfig,
    /// Stage 2 (thesis engine): Euclidean clustering.
    #[serde(flatten)]
    pub clustering: ClusteringConfig,
    /// Stage 3 (thesis engine): keypoints, normals and FPFH descriptors.
    #[serde(flatten)]
    pub features: FeatureConfig,
    /// Stage 4 (thesis engine): RANSAC consensus of the initial alignment.
    #[serde(flatten)]
    pub consensus: ConsensusConfig,
    /// Stage 5: ICP, the final alignment.
    #[serde(flatten)]
    pub icp: IcpConfig,
    /// Acceptance thresholds of the validation scores (thesis 3.1).
    #[serde(flatten)]
    pub validation: ValidationConfig,
    /// Thesis engine: searching clusters that hold several touching parts.
    #[serde(flatten)]
    pub pile: PileSearchConfig,
    /// Stage 6: duplicate suppression, pick order and grasp corridors.
    #[serde(flatten)]
    pub ranking: RankingConfig,
    /// Scene-voting engine: point-pair-feature voting.
    #[serde(flatten)]
    pub voting: VotingConfig,
    /// Scene-voting engine: verification against the sensor's view.
    #[serde(flatten)]
    pub verify: VerifyConfig,
    /// Threads and time budget.
    #[serde(flatten)]
    pub runtime: RuntimeConfig,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            engine: Engine::SceneVoting,
            algorithm: Algorithm::SeparatedFpfh,
            units: Units::Millimetres,
            thesis_strict: false,
            preprocess: PreprocessConfig::default(),
            clustering: ClusteringConfig::default(),
            features: FeatureConfig::default(),
            consensus: ConsensusConfig::default(),
            icp: IcpConfig::default(),
            validation: ValidationConfig::default(),
            pile: PileSearchConfig::default(),
            ranking: RankingConfig::default(),
            voting: VotingConfig::default(),
            verify: VerifyConfig::default(),
            runtime: RuntimeConfig::default(),
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
    /// Every preset, in the order `binpick --help` lists them.
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

    /// The preset's name as the CLI and TOML spell it (`thesis`, `A`, `arm-C`, ...).
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
        // 4.3: the thesis's absolute scale.
        // The thesis's engine: its configurations were tuned for it, and with its top-view
        // scanned models the scene-voting engine finds more but picks worse (docs/results-history.md).
        let mut thesis = Params {
            engine: Engine::Thesis,
            ..Params::default()
        };
        thesis.preprocess.resolution_mm = Some(THESIS_RESOLUTION_MM);
        thesis.preprocess.support.distance_mm = Some(THESIS_SUPPORT_DISTANCE_MM);
        let mut conveyor = thesis.clone();
        conveyor.clustering.cluster_max_factor = 10.0;
        conveyor.consensus.sac_thresholds_mm = odd_thresholds;
        // 5.6: fixed for all robot-arm tests.
        let mut arm = conveyor.clone();
        arm.clustering.cluster_tolerance_factor = 1.8;
        arm.clustering.cluster_max_factor = 5.0;
        // (base, initial leaf, final leaf, initial score max, final score max, radii)
        let (mut p, initial_leaf, final_leaf, initial_max, final_max, radii) = match self {
            Preset::Thesis => return thesis,
            Preset::A | Preset::B | Preset::C1 => {
                (conveyor, 3.0, 2.0, 200.0, 20.0, [5.0, 10.0, 15.0, 20.0])
            }
            Preset::C2 => (conveyor, 2.0, 1.5, 200.0, 25.0, [5.0, 9.0, 13.0, 17.0]),
            Preset::C3 => (conveyor, 2.0, 1.5, 100.0, 15.0, [3.0, 6.0, 9.0, 12.0]),
            Preset::ArmA => (arm, 3.0, 2.0, 100.0, 20.0, [5.0, 10.0, 15.0, 20.0]),
            Preset::ArmC => (arm, 2.0, 1.5, 100.0, 15.0, [3.0, 6.0, 9.0, 12.0]),
        };
        p.features.initial_leaf_mm = initial_leaf;
        p.icp.final_leaf_mm = final_leaf;
        p.consensus.initial_score_max = initial_max;
        p.validation.final_score_max_pct = final_max;
        p.features.fpfh_radii_mm = radii.to_vec();
        p
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

/// A parameter outside its declared range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("parameter {field} = {value}: {expected}")]
pub struct ParamError {
    /// The parameter's name (the TOML key).
    pub field: &'static str,
    /// Its value as given.
    pub value: String,
    /// The range it must lie in, in words.
    pub expected: String,
}

impl Params {
    /// Rejects any value outside its declared range, naming the field (each stage config
    /// checks its own fields).
    pub fn validate(&self) -> Result<(), ParamError> {
        self.preprocess.validate()?;
        self.preprocess.support.validate().map_err(|e| ParamError {
            field: support_field(e.field),
            ..e
        })?;
        self.clustering.validate()?;
        self.features.validate()?;
        self.consensus.validate()?;
        self.icp.validate()?;
        self.validation.validate()?;
        self.pile.validate()?;
        self.ranking.validate()?;
        self.voting.validate()?;
        self.verify.validate()?;
        self.runtime.validate()
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

    /// The stage configs the pipeline runs with: these parameters, with every extension
    /// switched off when `thesis_strict` is set. The one place `thesis_strict` is read.
    pub fn stages(&self) -> Params {
        let mut p = self.clone();
        if p.thesis_strict {
            p.engine = Engine::Thesis;
            p.consensus.independent_draws = false;
            p.consensus.consensus_modes = 1;
            p.consensus.symmetry_candidates = false;
            p.consensus.final_candidates = 1;
            p.icp.icp_relative_mse = 0.0;
            p.icp.icp_refine = false;
            p.pile.touching_parts = false;
            p.pile.tighter_recluster = false;
            p.pile.sphere_search = false;
            p.ranking.suppress_duplicates = false;
        }
        p
    }

    /// Cluster tolerance in mm.
    pub fn cluster_tolerance_mm(&self) -> f64 {
        self.clustering.cluster_tolerance_factor * self.preprocess.resolution()
    }
}

/// The most cells PCL's `UniformSampling` can index: it numbers them with a 32-bit int.
const PCL_MAX_CELLS: f64 = i32::MAX as f64;

/// Cells of a `leaf` grid over the box `lo..hi` (mm), counted as PCL's grids count them.
fn grid_cells(leaf: f64, lo: [f64; 3], hi: [f64; 3]) -> f64 {
    (0..3)
        .map(|k| (hi[k] / leaf).floor() - (lo[k] / leaf).floor() + 1.0)
        .product()
}

/// Rejects a keypoint leaf (`field`) too small for a cloud spanning `lo..hi` (mm): PCL's
/// `UniformSampling` would overflow its 32-bit cell index and silently merge distant cells.
/// Checked where the extent is known (the model in `Recognizer::new`, the scene after
/// preprocessing); the message gives PCL's limit and the smallest leaf that fits.
pub(crate) fn check_sampling_leaf(
    field: &'static str,
    leaf: f64,
    what: &str,
    lo: [f64; 3],
    hi: [f64; 3],
) -> Result<(), ParamError> {
    if grid_cells(leaf, lo, hi) <= PCL_MAX_CELLS {
        return Ok(());
    }
    // The smallest leaf that fits, by bisection (cells fall as the leaf grows).
    let (mut small, mut big) = (leaf, leaf);
    while grid_cells(big, lo, hi) > PCL_MAX_CELLS {
        big *= 2.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (small + big);
        if grid_cells(mid, lo, hi) > PCL_MAX_CELLS {
            small = mid;
        } else {
            big = mid;
        }
    }
    let span: Vec<String> = (0..3).map(|k| format!("{:.1}", hi[k] - lo[k])).collect();
    Err(ParamError {
        field,
        value: leaf.to_string(),
        expected: format!(
            "too small for {what} ({} mm): {:.3e} cells, but PCL's UniformSampling indexes \
             cells with a 32-bit int (at most {} cells); use at least {:.3} mm",
            span.join(" x "),
            grid_cells(leaf, lo, hi),
            i32::MAX,
            big
        ),
    })
}

/// `[support]` keys are reported with their table's name.
fn support_field(field: &'static str) -> &'static str {
    match field {
        "enabled" => "support.enabled",
        "distance_mm" => "support.distance_mm",
        "max_planes" => "support.max_planes",
        "min_points_factor" => "support.min_points_factor",
        "ransac_iterations" => "support.ransac_iterations",
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_scale_free_and_use_scene_voting() {
        let p = Params::default();
        assert_eq!(p.engine, Engine::SceneVoting);
        assert_eq!(p.preprocess.resolution_mm, None, "measured on every scan");
        assert_eq!(p.preprocess.support.distance_mm, None);
        p.validate().unwrap();
        // thesis_strict runs the thesis engine.
        let strict = Params {
            thesis_strict: true,
            ..Params::default()
        };
        assert_eq!(strict.stages().engine, Engine::Thesis);
    }

    #[test]
    fn thesis_preset_is_4_3() {
        let p = Preset::Thesis.params();
        assert_eq!(p.preprocess.resolution_mm, Some(1.0));
        assert_eq!(p.cluster_tolerance_mm(), 1.5);
        assert_eq!(
            (
                p.clustering.cluster_min_factor,
                p.clustering.cluster_max_factor
            ),
            (0.3, 3.0)
        );
        assert_eq!(p.features.initial_leaf_mm, 3.0);
        assert_eq!(p.features.fpfh_radii_mm, vec![10.0, 15.0, 20.0, 25.0, 30.0]);
        assert_eq!(p.features.normal_radius_factor, 0.8);
        assert_eq!(p.consensus.sac_thresholds_mm.len(), 20);
        assert_eq!(
            (
                p.consensus.sac_thresholds_mm[0],
                p.consensus.sac_thresholds_mm[19]
            ),
            (1.0, 20.0)
        );
        assert_eq!(p.consensus.initial_score_max, 100.0);
        assert_eq!(p.icp.final_leaf_mm, 2.0);
        assert_eq!(
            (p.icp.icp_iterations, p.icp.icp_transformation_epsilon),
            (50, 1e-7)
        );
        assert_eq!(p.validation.outlier_distance_mm, 4.0);
        assert_eq!(p.validation.final_score_max_pct, 20.0);
        assert_eq!(p.algorithm, Algorithm::SeparatedFpfh);
        p.validate().unwrap();
    }

    #[test]
    fn presets_match_the_thesis_tables() {
        for preset in Preset::ALL {
            assert_eq!(preset.params().engine, Engine::Thesis, "{}", preset.name());
        }
        let c3 = Preset::C3.params();
        assert_eq!(
            (c3.features.initial_leaf_mm, c3.icp.final_leaf_mm),
            (2.0, 1.5)
        );
        assert_eq!(
            (
                c3.consensus.initial_score_max,
                c3.validation.final_score_max_pct
            ),
            (100.0, 15.0)
        );
        assert_eq!(c3.features.fpfh_radii_mm, vec![3.0, 6.0, 9.0, 12.0]);
        assert_eq!(
            c3.consensus.sac_thresholds_mm,
            vec![1.0, 3.0, 5.0, 7.0, 9.0, 11.0, 13.0, 15.0, 17.0, 19.0]
        );
        assert_eq!(c3.clustering.cluster_max_factor, 10.0);
        let arm = Preset::ArmA.params();
        assert_eq!(
            (
                arm.clustering.cluster_tolerance_factor,
                arm.clustering.cluster_max_factor
            ),
            (1.8, 5.0)
        );
        assert_eq!(
            (
                arm.consensus.initial_score_max,
                arm.validation.final_score_max_pct
            ),
            (100.0, 20.0)
        );
        let c2 = Preset::C2.params();
        assert_eq!(c2.features.fpfh_radii_mm, vec![5.0, 9.0, 13.0, 17.0]);
        assert_eq!(c2.validation.final_score_max_pct, 25.0);
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
        assert_eq!(partial.preprocess.resolution_mm, Some(2.0));
        assert_eq!(partial.algorithm, Algorithm::MergedFpfh);
        assert_eq!(partial.features.initial_leaf_mm, 3.0);
        assert!(Params::from_toml("resolutoin_mm = 2.0").is_err());
        let over = Params::from_toml_over(
            &Preset::C3.params(),
            "final_leaf_mm = 1.0\n[support]\ndistance_mm = 2.5\n",
        )
        .unwrap();
        assert_eq!(over.icp.final_leaf_mm, 1.0);
        assert_eq!(over.preprocess.support.distance_mm, Some(2.5));
        assert_eq!(
            over.preprocess.support.max_planes, 5,
            "other [support] keys keep the base value"
        );
        assert_eq!(
            over.features.fpfh_radii_mm,
            vec![3.0, 6.0, 9.0, 12.0],
            "preset values survive"
        );
        assert!(Params::from_toml_over(&Params::default(), "[support]\nbogus = 1").is_err());
        let metres = Params::from_toml("units = \"m\"").unwrap();
        assert_eq!(metres.units, Units::Metres);
    }

    #[test]
    fn absurd_values_are_rejected_by_name() {
        let set = |f: &dyn Fn(&mut Params)| {
            let mut p = Params::default();
            f(&mut p);
            p
        };
        let cases: Vec<(Params, &str)> = vec![
            (
                set(&|p| p.preprocess.resolution_mm = Some(0.0)),
                "resolution_mm",
            ),
            (
                set(&|p| p.preprocess.resolution_mm = Some(f64::NAN)),
                "resolution_mm",
            ),
            (set(&|p| p.features.fpfh_radii_mm = vec![]), "fpfh_radii_mm"),
            (
                set(&|p| p.features.fpfh_radii_mm = vec![10.0, -1.0]),
                "fpfh_radii_mm",
            ),
            (
                set(&|p| p.consensus.sac_thresholds_mm = vec![f64::INFINITY]),
                "sac_thresholds_mm",
            ),
            (
                set(&|p| p.clustering.cluster_min_factor = 1.5),
                "cluster_min_factor",
            ),
            (
                set(&|p| p.clustering.cluster_tolerance_factor = 0.5),
                "cluster_tolerance_factor",
            ),
            (
                set(&|p| p.validation.final_score_max_pct = 150.0),
                "final_score_max_pct",
            ),
            (set(&|p| p.icp.icp_iterations = 0), "icp_iterations"),
            (set(&|p| p.ranking.up = [0.0; 3]), "up"),
            (
                set(&|p| p.runtime.time_budget_ms = Some(0)),
                "time_budget_ms",
            ),
            (
                set(&|p| {
                    p.preprocess.region_of_interest = Some(RegionOfInterest {
                        min_mm: [0.0; 3],
                        max_mm: [1.0, -1.0, 1.0],
                    })
                }),
                "region_of_interest",
            ),
        ];
        for (p, field) in cases {
            let e = p.validate().unwrap_err();
            assert_eq!(e.field, field, "{e}");
            assert!(e.to_string().contains(field));
        }
    }

    #[test]
    fn consensus_modes_is_checked_against_its_declared_range() {
        let mut p = Params::default();
        p.consensus.consensus_modes = 0;
        let e = p.validate().unwrap_err();
        assert_eq!(e.field, "consensus_modes");
        assert_eq!(e.expected, "expected 1-10");
        p.consensus.consensus_modes = 11;
        assert_eq!(p.validate().unwrap_err().field, "consensus_modes");
        p.consensus.consensus_modes = 10;
        p.validate().unwrap();
    }

    #[test]
    fn thesis_strict_switches_every_extension_off() {
        let p = Params {
            thesis_strict: true,
            ..Params::default()
        }
        .stages();
        assert!(!p.consensus.independent_draws && !p.consensus.symmetry_candidates);
        assert_eq!(
            (p.consensus.consensus_modes, p.consensus.final_candidates),
            (1, 1)
        );
        assert!(!p.icp.icp_refine && p.icp.icp_relative_mse == 0.0);
        assert!(!p.pile.touching_parts && !p.pile.tighter_recluster && !p.pile.sphere_search);
        assert!(!p.ranking.suppress_duplicates);
        assert_eq!(Params::default().stages(), Params::default());
    }
}
