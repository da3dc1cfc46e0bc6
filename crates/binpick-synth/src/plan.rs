//! Presets mirroring the thesis's datasets (5.1.2) and the per-scene recipe.

use serde::{Deserialize, Serialize};

use crate::parts::PartKind;
use crate::physics::Environment;
use crate::rng::Rng;
use crate::scanner::ScannerConfig;

/// Which dataset to generate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Preset {
    /// 5.1.2.1: 9 groups x 10 conveyor scans.
    #[serde(rename = "thesis-conveyor")]
    ThesisConveyor,
    /// 5.1.2.2: 8 groups, 100 robot-arm scans.
    #[serde(rename = "thesis-arm")]
    ThesisArm,
    /// 4 small scenes for tests.
    #[serde(rename = "tiny")]
    Tiny,
}

impl Preset {
    pub fn as_str(self) -> &'static str {
        match self {
            Preset::ThesisConveyor => "thesis-conveyor",
            Preset::ThesisArm => "thesis-arm",
            Preset::Tiny => "tiny",
        }
    }

    /// Default belt-level samples per scene (lines x columns) per layout; a scene has about
    /// 1.1-1.4 times as many points (surfaces lit by both lasers give two).
    pub fn default_points_target(self, layout: Layout) -> usize {
        match (self, layout) {
            (Preset::Tiny, _) => 50_000,
            (_, Layout::Conveyor) => 340_000,
            (_, Layout::Arm) => 300_000,
        }
    }
}

impl std::str::FromStr for Preset {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "thesis-conveyor" => Ok(Preset::ThesisConveyor),
            "thesis-arm" => Ok(Preset::ThesisArm),
            "tiny" => Ok(Preset::Tiny),
            other => Err(format!(
                "unknown preset {other:?}: expected \"thesis-conveyor\", \"thesis-arm\" or \"tiny\""
            )),
        }
    }
}

impl std::fmt::Display for Preset {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Where the scanner is mounted (thesis 2.2.1 / 2.2.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Layout {
    /// Fixed head over a moving belt: fine, low-noise, small area.
    Conveyor,
    /// Head on a robot arm over a fixed area: coarser, noisier, larger.
    Arm,
}

impl Layout {
    /// Belt / arm speed range, mm/s.
    pub fn speed_range(self) -> [f64; 2] {
        match self {
            Layout::Conveyor => [10.0, 30.0],
            Layout::Arm => [30.0, 60.0],
        }
    }

    /// Range-noise standard deviation range, mm.
    pub fn noise_range(self) -> [f64; 2] {
        match self {
            Layout::Conveyor => [0.1, 0.2],
            Layout::Arm => [0.3, 0.5],
        }
    }

    /// A scanner with speed and noise drawn from this layout's ranges. With a small points
    /// target (columns more than twice as far apart as the lines), the speed is raised within
    /// the range towards equal spacing along and across, so small scans stay usable.
    pub fn random_scanner(self, rng: &mut Rng, points_target: usize) -> ScannerConfig {
        let [s0, s1] = self.speed_range();
        let [n0, n1] = self.noise_range();
        let mut speed = (rng.range(s0, s1) * 10.0).round() / 10.0;
        let noise = (rng.range(n0, n1) * 1000.0).round() / 1000.0;
        let make = |speed: f64| match self {
            Layout::Conveyor => ScannerConfig::conveyor(speed, noise, points_target),
            Layout::Arm => ScannerConfig::arm(speed, noise, points_target),
        };
        let cfg = make(speed);
        if cfg.column_spacing() > 2.0 * cfg.line_spacing() {
            let area = (cfg.x_range[1] - cfg.x_range[0]) * (cfg.y_range[1] - cfg.y_range[0]);
            let even = cfg.fps * (area / points_target.max(1) as f64).sqrt();
            speed = ((even.clamp(speed, s1)) * 10.0).round() / 10.0;
            return make(speed);
        }
        cfg
    }

    /// The environment: belt or floor, or a bin with walls.
    pub fn environment(self, in_box: bool) -> Environment {
        match (self, in_box) {
            (Layout::Conveyor, false) => Environment::Flat {
                size: [600.0, 600.0],
            },
            (Layout::Arm, false) => Environment::Flat {
                size: [800.0, 800.0],
            },
            (_, true) => Environment::Bin {
                floor_size: [800.0, 800.0],
                inner: [300.0, 300.0],
                wall_height: 100.0,
                wall_thickness: 10.0,
            },
        }
    }
}

/// How the parts of one scene (or one "-Decr" sequence) are chosen.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Recipe {
    /// `count` parts (inclusive range) of the given types, each type at least once.
    Mixed {
        types: Vec<PartKind>,
        count: [usize; 2],
    },
    /// A random base of `base` types first, then `top` types dropped over it.
    Over {
        top: Vec<PartKind>,
        top_count: [usize; 2],
        base: Vec<PartKind>,
        base_count: [usize; 2],
    },
    /// One pile of `start` parts scanned repeatedly, removing the top-most part each time.
    Decr { kind: PartKind, start: [usize; 2] },
}

/// One group of scans (a line of the thesis's dataset lists).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroupPlan {
    /// The thesis's label, e.g. `A+B`, `C over B and A`, `A-Decr`.
    pub name: String,
    /// Prefix of the scene ids, e.g. `conv-AB`.
    pub slug: String,
    pub layout: Layout,
    /// Parts dropped into a bin with walls.
    pub in_box: bool,
    pub recipe: Recipe,
    pub scenes: usize,
}

impl GroupPlan {
    /// Scene id of the `index`-th scan.
    pub fn scene_id(&self, index: usize) -> String {
        format!("{}-{index:03}", self.slug)
    }
}

fn mixed(types: &[PartKind], lo: usize, hi: usize) -> Recipe {
    Recipe::Mixed {
        types: types.to_vec(),
        count: [lo, hi],
    }
}

fn over(top: &[PartKind], base: &[PartKind]) -> Recipe {
    Recipe::Over {
        top: top.to_vec(),
        top_count: [3, 5],
        base: base.to_vec(),
        base_count: [2, 4],
    }
}

fn group(
    name: &str,
    slug: &str,
    layout: Layout,
    in_box: bool,
    recipe: Recipe,
    scenes: usize,
) -> GroupPlan {
    GroupPlan {
        name: name.into(),
        slug: slug.into(),
        layout,
        in_box,
        recipe,
        scenes,
    }
}

/// The groups of a preset; `scenes_per_group` overrides every group's scene count.
pub fn plan(preset: Preset, scenes_per_group: Option<usize>) -> Vec<GroupPlan> {
    use Layout::{Arm, Conveyor};
    use PartKind::{A, B, C};
    let n = |default: usize| scenes_per_group.unwrap_or(default);
    let decr = |k: PartKind| Recipe::Decr {
        kind: k,
        start: [8, 10],
    };
    match preset {
        Preset::ThesisConveyor => vec![
            group("A", "conv-A", Conveyor, false, mixed(&[A], 3, 8), n(10)),
            group("B", "conv-B", Conveyor, false, mixed(&[B], 3, 8), n(10)),
            group("C", "conv-C", Conveyor, false, mixed(&[C], 3, 8), n(10)),
            group(
                "A+B",
                "conv-AB",
                Conveyor,
                false,
                mixed(&[A, B], 3, 8),
                n(10),
            ),
            group(
                "B+C",
                "conv-BC",
                Conveyor,
                false,
                mixed(&[B, C], 3, 8),
                n(10),
            ),
            group(
                "C+A",
                "conv-CA",
                Conveyor,
                false,
                mixed(&[C, A], 3, 8),
                n(10),
            ),
            group("A-Decr", "conv-A-decr", Conveyor, false, decr(A), n(10)),
            group("B-Decr", "conv-B-decr", Conveyor, false, decr(B), n(10)),
            group("C-Decr", "conv-C-decr", Conveyor, false, decr(C), n(10)),
        ],
        Preset::ThesisArm => vec![
            group("A", "arm-A", Arm, false, mixed(&[A], 3, 8), n(10)),
            group(
                "A over B",
                "arm-A-over-B",
                Arm,
                false,
                over(&[A], &[B]),
                n(10),
            ),
            group(
                "A over B and C",
                "arm-A-over-BC",
                Arm,
                false,
                over(&[A], &[B, C]),
                n(10),
            ),
            group("C", "arm-C", Arm, false, mixed(&[C], 3, 8), n(10)),
            group(
                "C over B",
                "arm-C-over-B",
                Arm,
                false,
                over(&[C], &[B]),
                n(10),
            ),
            group(
                "C over B and A",
                "arm-C-over-BA",
                Arm,
                false,
                over(&[C], &[B, A]),
                n(10),
            ),
            group(
                "A+B+C",
                "arm-ABC",
                Arm,
                false,
                mixed(&[A, B, C], 4, 8),
                n(20),
            ),
            group(
                "A+B+C-Box",
                "arm-ABC-box",
                Arm,
                true,
                mixed(&[A, B, C], 4, 8),
                n(20),
            ),
        ],
        Preset::Tiny => vec![
            group("A", "tiny-conv-A", Conveyor, false, mixed(&[A], 3, 4), n(1)),
            group(
                "B+C",
                "tiny-conv-BC",
                Conveyor,
                false,
                mixed(&[B, C], 3, 4),
                n(1),
            ),
            group(
                "C over B",
                "tiny-arm-C-over-B",
                Arm,
                false,
                Recipe::Over {
                    top: vec![C],
                    top_count: [2, 3],
                    base: vec![B],
                    base_count: [1, 2],
                },
                n(1),
            ),
            group(
                "A+B+C-Box",
                "tiny-arm-ABC-box",
                Arm,
                true,
                mixed(&[A, B, C], 3, 4),
                n(1),
            ),
        ],
    }
}

/// Draws `count` parts from `types`, each type at least once (when count allows), in random
/// order.
pub fn draw_kinds(types: &[PartKind], count: [usize; 2], rng: &mut Rng) -> Vec<PartKind> {
    if types.is_empty() {
        return Vec::new();
    }
    let n = rng.int_inclusive(count[0], count[1]).max(1);
    let mut out: Vec<PartKind> = types.iter().copied().take(n).collect();
    while out.len() < n {
        out.push(types[rng.int_inclusive(0, types.len() - 1)]);
    }
    // Fisher-Yates shuffle.
    for i in (1..out.len()).rev() {
        let j = rng.int_inclusive(0, i);
        out.swap(i, j);
    }
    out
}
