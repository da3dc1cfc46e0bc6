//! Point-pair features (Drost et al. 2010, "Model globally, match locally"): a hash table of
//! every model point pair, and voting over the whole scene for (model point, rotation angle)
//! per scene reference point. Improvements from Vidal et al. 2018 ("A method for 6D pose
//! estimation of free-form rigid objects using point pair features on range data"): pairs no
//! longer than the model's diameter, and each model pair also filed under the neighbouring
//! quantisation bins its feature lies close to, so sensor noise that moves a feature across a
//! bin edge still finds it.
//!
//! Feature of a pair (p1, n1), (p2, n2) with d = p2 - p1:
//! `F = (|d|, angle(n1, d), angle(n2, d), angle(n1, n2))`, distances in mm, angles in [0, pi].
//! Every point gets a canonical frame: translate it to the origin and rotate its normal onto
//! +x; the partner then sits at an angle `phi` about x. A model pair and a scene pair with the
//! same feature give the pose `x -> s + Rs^T Rx(phi_s - phi_m) Rm (x - m)`.

use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use crate::index::PointIndex;
use crate::{MatchError, OrientedPoints, P3};

/// Quantisation and pairing of the point-pair features.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PpfConfig {
    /// Distance quantisation step, mm: the sampling step of model and scene. Range > 0.
    pub distance_step_mm: f64,
    /// Bins of each feature angle over [0, 180] deg (Drost: 15, 12 deg bins). Range 4-90.
    pub feature_angle_bins: u32,
    /// Bins of the rotation about the normal over a full turn (Drost: 30, 12 deg). Range
    /// 4-360.
    pub alpha_bins: u32,
    /// Longest pair, mm (the model's diameter: longer pairs cannot lie on one part). Range > 0.
    pub max_pair_distance_mm: f64,
    /// A model pair is also filed under a neighbouring bin when its feature lies within this
    /// fraction of a bin of the edge (Vidal's neighbour voting). Range 0-0.5 (0 = off).
    pub spread: f64,
    /// Most pairs kept per feature bin, evenly chosen. Bins of flat regions (two coplanar
    /// normals at right angles to the pair) hold thousands of pairs that all vote alike and
    /// say little about the pose; capping them bounds the voting time. Range >= 1.
    pub max_pairs_per_bin: u32,
}

impl PpfConfig {
    /// Rejects values outside the documented ranges, naming the field.
    pub fn validate(&self) -> Result<(), MatchError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.distance_step_mm) {
            return Err(MatchError::config("distance_step_mm", "expected > 0 mm"));
        }
        if !positive(self.max_pair_distance_mm) {
            return Err(MatchError::config(
                "max_pair_distance_mm",
                "expected > 0 mm",
            ));
        }
        if !(4..=90).contains(&self.feature_angle_bins) {
            return Err(MatchError::config("feature_angle_bins", "expected 4-90"));
        }
        if !(4..=360).contains(&self.alpha_bins) {
            return Err(MatchError::config("alpha_bins", "expected 4-360"));
        }
        if !(0.0..=0.5).contains(&self.spread) {
            return Err(MatchError::config("spread", "expected 0-0.5"));
        }
        if self.max_pairs_per_bin == 0 {
            return Err(MatchError::config("max_pairs_per_bin", "expected >= 1"));
        }
        let bins = self.distance_bins() as u64 * u64::from(self.feature_angle_bins).pow(3);
        if bins > 50_000_000 {
            return Err(MatchError::config(
                "distance_step_mm",
                "too small for the pair distance: more than 50 million feature bins",
            ));
        }
        Ok(())
    }

    fn distance_bins(&self) -> u32 {
        (self.max_pair_distance_mm / self.distance_step_mm).floor() as u32 + 1
    }
}

/// A point's canonical frame: `x -> rotation * (x - origin)` puts the point at the origin
/// with its normal along +x.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
struct Frame {
    origin: Vector3<f32>,
    rotation: Rotation3<f32>,
}

impl Frame {
    fn new(p: &P3, n: &P3) -> Option<Self> {
        let n = Vector3::from(*n);
        let len = n.norm();
        if !(len.is_finite() && len > 1e-6) {
            return None;
        }
        let n = n / len;
        let rotation = Rotation3::rotation_between(&n, &Vector3::x()).unwrap_or_else(|| {
            // n = -x: a half-turn about z.
            Rotation3::from_axis_angle(&Vector3::z_axis(), std::f32::consts::PI)
        });
        Some(Self {
            origin: Vector3::from(*p),
            rotation,
        })
    }

    /// Angle of `q` about +x in this frame, radians in (-pi, pi].
    fn phi(&self, q: &P3) -> f32 {
        let v = self.rotation * (Vector3::from(*q) - self.origin);
        v.z.atan2(v.y)
    }
}

/// The rotation bin of a scene partner at `phi_s` and a model partner at `phi_m` (radians in
/// [-pi, pi], as `Frame::phi` gives): the bin of `(phi_s - phi_m) mod 2 pi`, with
/// `per_radian` = bins / 2 pi. Wrapped in bin units with one comparison and no division, and
/// truncated by way of `i32` (one instruction; `as usize` takes two and a select, same
/// result for every input: NaN and negatives give 0): the voting loop's hottest line.
#[inline(always)]
fn alpha_bin(phi_s: f32, phi_m: f32, per_radian: f32, bins: usize) -> usize {
    let x = (phi_s - phi_m) * per_radian;
    let x = if x < 0.0 { x + bins as f32 } else { x };
    ((x as i32).max(0) as usize).min(bins - 1)
}

/// One scene pair's votes: every model pair `entries` of its feature bin votes for (model
/// point, rotation bin) in `acc`; slots voted for the first time are appended to
/// `touched[n_touched..]`. Returns the new `n_touched`. Apart from the voting loop so its
/// counters stay in registers (inlined there, `n_touched` went through the stack on every
/// vote).
#[inline(never)]
fn accumulate(
    entries: &[Entry],
    phi_s: f32,
    per_radian: f32,
    n_alpha: usize,
    acc: &mut [u32],
    touched: &mut [u32],
    mut n_touched: usize,
) -> usize {
    for e in entries {
        let a = alpha_bin(phi_s, e.phi, per_radian, n_alpha);
        let slot = e.point as usize * n_alpha + a;
        let count = &mut acc[slot];
        // Written without a branch: appended always, kept only when new.
        touched[n_touched] = slot as u32;
        n_touched += usize::from(*count == 0);
        *count += 1;
    }
    n_touched
}

/// The feature of a pair, or None for coincident points or undefined normals.
fn feature(p1: &P3, n1: &P3, p2: &P3, n2: &P3) -> Option<[f32; 4]> {
    let d = Vector3::from(*p2) - Vector3::from(*p1);
    let dist = d.norm();
    if dist.is_nan() || dist <= 1e-6 {
        return None;
    }
    let d = d / dist;
    let (a, b) = (Vector3::from(*n1), Vector3::from(*n2));
    let angle = |u: &Vector3<f32>, v: &Vector3<f32>| u.dot(v).clamp(-1.0, 1.0).acos();
    Some([dist, angle(&a, &d), angle(&b, &d), angle(&a, &b)])
}

/// One model pair filed in the table: the first point's index and the partner's angle.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
struct Entry {
    point: u32,
    phi: f32,
}

/// The model's point-pair table (serialisable, to be cached on disk).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct PpfModel {
    config: PpfConfig,
    frames: Vec<Frame>,
    /// `entries[offsets[k]..offsets[k + 1]]` are the pairs with key `k`.
    offsets: Vec<u32>,
    entries: Vec<Entry>,
    distance_bins: u32,
}

/// A pose voted for by one scene reference point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vote {
    /// Model -> scene.
    pub pose: Isometry3<f64>,
    /// Votes of the peak (model pairs that agree).
    pub votes: u32,
    /// The scene reference point (index into the scene points).
    pub reference: u32,
}

/// How the scene is searched. No defaults here: binpick's `params::VotingConfig` holds them
/// (one source), with the table's.
#[derive(Clone, Debug, PartialEq)]
pub struct VotingConfig {
    /// Every `reference_stride`-th scene point is a reference point (Drost: 5; piles need
    /// more to find every part). Range 1-100.
    pub reference_stride: usize,
    /// Peaks kept per reference point (a reference point on a part touching another can
    /// carry both). Range 1-20.
    pub peaks_per_reference: usize,
    /// A secondary peak is kept when it has at least this fraction of the reference point's
    /// best peak's votes. Range 0-1.
    pub secondary_peak_ratio: f64,
    /// Of the scene pairs of one reference point that share a feature bin and a rotation
    /// bin, only the first votes (Vidal et al. 2018): flat regions give many such pairs,
    /// which vote alike.
    pub distinct_pairs: bool,
}

impl VotingConfig {
    /// Rejects values outside the documented ranges, naming the field.
    pub fn validate(&self) -> Result<(), MatchError> {
        if !(1..=100).contains(&self.reference_stride) {
            return Err(MatchError::config("reference_stride", "expected 1-100"));
        }
        if !(1..=20).contains(&self.peaks_per_reference) {
            return Err(MatchError::config("peaks_per_reference", "expected 1-20"));
        }
        if !(0.0..=1.0).contains(&self.secondary_peak_ratio) {
            return Err(MatchError::config("secondary_peak_ratio", "expected 0-1"));
        }
        Ok(())
    }
}

impl PpfModel {
    /// Files every ordered pair of model points no farther apart than the pair limit.
    pub fn new(model: &OrientedPoints, config: PpfConfig) -> Result<Self, MatchError> {
        config.validate()?;
        model.check("model")?;
        if model.len() < 3 {
            return Err(MatchError::TooFewPoints {
                what: "model",
                points: model.len(),
                needed: 3,
            });
        }
        if model.len() > 20_000 {
            return Err(MatchError::TooManyPoints {
                what: "model",
                points: model.len(),
                limit: 20_000,
            });
        }
        let frames: Vec<Frame> = model
            .points
            .iter()
            .zip(&model.normals)
            .map(|(p, n)| Frame::new(p, n))
            .collect::<Option<_>>()
            .ok_or(MatchError::BadNormal { what: "model" })?;
        let distance_bins = config.distance_bins();
        let quant = Quantiser::new(&config);
        let max_d = config.max_pair_distance_mm as f32;
        // (key, entry) per first point, in point order: deterministic on any thread count.
        let per_point: Vec<Vec<(u32, Entry)>> = (0..model.len())
            .into_par_iter()
            .map(|i| {
                let (p1, n1) = (&model.points[i], &model.normals[i]);
                let mut out = Vec::new();
                let mut keys = Vec::with_capacity(16);
                for j in 0..model.len() {
                    if i == j {
                        continue;
                    }
                    let Some(f) = feature(p1, n1, &model.points[j], &model.normals[j]) else {
                        continue;
                    };
                    if f[0] > max_d {
                        continue;
                    }
                    let phi = frames[i].phi(&model.points[j]);
                    quant.spread_keys(&f, config.spread as f32, &mut keys);
                    out.extend(keys.iter().map(|&k| {
                        (
                            k,
                            Entry {
                                point: i as u32,
                                phi,
                            },
                        )
                    }));
                }
                out
            })
            .collect();
        let n_keys = quant.key_count() as usize;
        let mut counts = vec![0u32; n_keys + 1];
        for (k, _) in per_point.iter().flatten() {
            counts[*k as usize + 1] += 1;
        }
        for k in 0..n_keys {
            counts[k + 1] += counts[k];
        }
        let offsets = counts.clone();
        let total = offsets[n_keys] as usize;
        let mut entries = vec![Entry { point: 0, phi: 0.0 }; total];
        let mut cursor = counts;
        for (k, e) in per_point.into_iter().flatten() {
            let slot = &mut cursor[k as usize];
            entries[*slot as usize] = e;
            *slot += 1;
        }
        let (offsets, entries) = cap_bins(&offsets, &entries, config.max_pairs_per_bin as usize);
        Ok(Self {
            config,
            frames,
            offsets,
            entries,
            distance_bins,
        })
    }

    /// Model points in the table.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether the model has no points (never true for a built model).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Pairs filed (with neighbour-bin copies).
    pub fn entries(&self) -> usize {
        self.entries.len()
    }

    /// Votes over the whole scene: each reference point pairs with every scene point within
    /// the pair limit and votes for (model point, rotation); its best peaks become poses.
    /// Returned in reference order, peaks best first.
    pub fn vote(
        &self,
        scene: &OrientedPoints,
        index: &PointIndex,
        config: &VotingConfig,
    ) -> Result<Vec<Vote>, MatchError> {
        config.validate()?;
        scene.check("scene")?;
        let quant = Quantiser::new(&self.config);
        let n_alpha = self.config.alpha_bins as usize;
        let alpha_step = std::f32::consts::TAU / self.config.alpha_bins as f32;
        let per_radian = self.config.alpha_bins as f32 / std::f32::consts::TAU;
        let max_d = self.config.max_pair_distance_mm as f32;
        let n_model = self.frames.len();
        let references: Vec<usize> = (0..scene.len()).step_by(config.reference_stride).collect();
        let votes: Vec<Vec<Vote>> = references
            .par_iter()
            .map_init(
                // `touched[..n]` lists the slots voted for, in first-vote order
                // (`accumulate`).
                || {
                    let slots = n_model * n_alpha;
                    let voted = std::collections::HashSet::<u64>::new();
                    (vec![0u32; slots], vec![0u32; slots + 1], Vec::new(), voted)
                },
                |(acc, touched, neighbours, voted), &r| {
                    voted.clear();
                    let mut n_touched = 0usize;
                    let (ps, ns) = (&scene.points[r], &scene.normals[r]);
                    let Some(frame) = Frame::new(ps, ns) else {
                        return Vec::new();
                    };
                    index.within_into(ps, max_d, neighbours);
                    for &k in neighbours.iter() {
                        let k = k as usize;
                        if k == r {
                            continue;
                        }
                        let Some(f) = feature(ps, ns, &scene.points[k], &scene.normals[k]) else {
                            continue;
                        };
                        let Some(key) = quant.key(&f) else {
                            continue;
                        };
                        let (lo, hi) = (
                            self.offsets[key as usize] as usize,
                            self.offsets[key as usize + 1] as usize,
                        );
                        if lo == hi {
                            continue;
                        }
                        let phi_s = frame.phi(&scene.points[k]);
                        if config.distinct_pairs {
                            // phi_s's own rotation bin (measured from -pi).
                            let bin = alpha_bin(phi_s, -std::f32::consts::PI, per_radian, n_alpha);
                            if !voted.insert(u64::from(key) * n_alpha as u64 + bin as u64) {
                                continue;
                            }
                        }
                        n_touched = accumulate(
                            &self.entries[lo..hi],
                            phi_s,
                            per_radian,
                            n_alpha,
                            acc,
                            touched,
                            n_touched,
                        );
                    }
                    let touched = &touched[..n_touched];
                    let peaks = self.peaks(acc, touched, config, n_alpha);
                    for &s in touched {
                        acc[s as usize] = 0;
                    }
                    peaks
                        .into_iter()
                        .map(|(slot, votes)| {
                            let (point, a) = (slot / n_alpha, slot % n_alpha);
                            let alpha = (a as f32 + 0.5) * alpha_step;
                            Vote {
                                pose: self.pose(&frame, point, alpha),
                                votes,
                                reference: r as u32,
                            }
                        })
                        .collect()
                },
            )
            .collect();
        Ok(votes.into_iter().flatten().collect())
    }

    /// The best peaks of one accumulator: local maxima over the rotation bins (circular) of
    /// a model point, best first, ties by slot. Only the best `peaks_per_reference` are
    /// kept while scanning (thousands of slots are touched per reference point; sorting
    /// them all was a tenth of the voting time).
    fn peaks(
        &self,
        acc: &[u32],
        touched: &[u32],
        config: &VotingConfig,
        n_alpha: usize,
    ) -> Vec<(usize, u32)> {
        let keep = config.peaks_per_reference;
        // Best first: more votes, then the lower slot.
        let better = |a: &(usize, u32), b: &(usize, u32)| a.1 > b.1 || (a.1 == b.1 && a.0 < b.0);
        let mut best: Vec<(usize, u32)> = Vec::with_capacity(keep + 1);
        for &s in touched {
            let s = s as usize;
            let v = acc[s];
            if best.len() == keep && !better(&(s, v), &best[keep - 1]) {
                continue;
            }
            let (base, a) = (s - s % n_alpha, s % n_alpha);
            let prev = acc[base + (a + n_alpha - 1) % n_alpha];
            let next = acc[base + (a + 1) % n_alpha];
            // Plateaus keep their first bin.
            if !(v > prev && v >= next) {
                continue;
            }
            let at = best
                .iter()
                .position(|b| better(&(s, v), b))
                .unwrap_or(best.len());
            best.insert(at, (s, v));
            best.truncate(keep);
        }
        let Some(&(_, top)) = best.first() else {
            return Vec::new();
        };
        let floor = (config.secondary_peak_ratio * f64::from(top)).ceil() as u32;
        best.retain(|&(_, v)| v >= floor.max(1));
        best
    }

    /// `x -> s + Rs^T Rx(alpha) Rm (x - m)`.
    fn pose(&self, scene: &Frame, model_point: usize, alpha: f32) -> Isometry3<f64> {
        let m = &self.frames[model_point];
        let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), alpha);
        let r = scene.rotation.inverse() * rx * m.rotation;
        let t = scene.origin - r * m.origin;
        let r64: Rotation3<f64> = nalgebra::convert(r);
        Isometry3::from_parts(
            Translation3::new(f64::from(t.x), f64::from(t.y), f64::from(t.z)),
            UnitQuaternion::from_rotation_matrix(&r64),
        )
    }

    /// The number of distance bins (for diagnostics).
    pub fn distance_bins(&self) -> u32 {
        self.distance_bins
    }
}

/// Keeps at most `cap` entries per bin, evenly spaced through the bin's list.
fn cap_bins(offsets: &[u32], entries: &[Entry], cap: usize) -> (Vec<u32>, Vec<Entry>) {
    let mut new_offsets = Vec::with_capacity(offsets.len());
    let mut kept = Vec::with_capacity(entries.len());
    new_offsets.push(0u32);
    for w in offsets.windows(2) {
        let bin = &entries[w[0] as usize..w[1] as usize];
        if bin.len() <= cap {
            kept.extend_from_slice(bin);
        } else {
            kept.extend((0..cap).map(|k| bin[k * bin.len() / cap]));
        }
        new_offsets.push(kept.len() as u32);
    }
    (new_offsets, kept)
}

/// Feature -> table key.
struct Quantiser {
    step: f32,
    angle_step: f32,
    distance_bins: u32,
    angle_bins: u32,
}

impl Quantiser {
    fn new(c: &PpfConfig) -> Self {
        Self {
            step: c.distance_step_mm as f32,
            angle_step: std::f32::consts::PI / c.feature_angle_bins as f32,
            distance_bins: c.distance_bins(),
            angle_bins: c.feature_angle_bins,
        }
    }

    fn key_count(&self) -> u32 {
        self.distance_bins * self.angle_bins.pow(3)
    }

    /// Continuous bin coordinates of a feature.
    fn coords(&self, f: &[f32; 4]) -> [f32; 4] {
        [
            f[0] / self.step,
            f[1] / self.angle_step,
            f[2] / self.angle_step,
            f[3] / self.angle_step,
        ]
    }

    fn limits(&self) -> [u32; 4] {
        [
            self.distance_bins,
            self.angle_bins,
            self.angle_bins,
            self.angle_bins,
        ]
    }

    fn pack(&self, b: [u32; 4]) -> u32 {
        ((b[0] * self.angle_bins + b[1]) * self.angle_bins + b[2]) * self.angle_bins + b[3]
    }

    fn key(&self, f: &[f32; 4]) -> Option<u32> {
        let c = self.coords(f);
        let lim = self.limits();
        let mut b = [0u32; 4];
        for k in 0..4 {
            let v = c[k].floor();
            if v.is_nan() || v < 0.0 {
                return None;
            }
            // Angles of exactly pi fall in the last bin.
            let v = if k > 0 { v.min((lim[k] - 1) as f32) } else { v };
            if v as u32 >= lim[k] {
                return None;
            }
            b[k] = v as u32;
        }
        Some(self.pack(b))
    }

    /// The feature's own key and, per dimension within `spread` of a bin edge, the
    /// neighbouring bin's (Cartesian product over dimensions).
    fn spread_keys(&self, f: &[f32; 4], spread: f32, out: &mut Vec<u32>) {
        out.clear();
        let c = self.coords(f);
        let lim = self.limits();
        let mut options: [[Option<u32>; 2]; 4] = [[None; 2]; 4];
        for k in 0..4 {
            let floor = c[k].floor();
            let v = if k > 0 {
                floor.min((lim[k] - 1) as f32)
            } else {
                floor
            };
            if v.is_nan() || v < 0.0 || v as u32 >= lim[k] {
                return;
            }
            let b = v as u32;
            let frac = c[k] - floor;
            options[k][0] = Some(b);
            options[k][1] = if frac < spread && b > 0 {
                Some(b - 1)
            } else if frac > 1.0 - spread && b + 1 < lim[k] {
                Some(b + 1)
            } else {
                None
            };
        }
        for a in options[0].iter().flatten() {
            for b in options[1].iter().flatten() {
                for c in options[2].iter().flatten() {
                    for d in options[3].iter().flatten() {
                        out.push(self.pack([*a, *b, *c, *d]));
                    }
                }
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::poses::{PoseClustering, Symmetries, cluster_poses};
    use nalgebra::Point3;

    #[test]
    fn alpha_bins_truncated_by_i32_are_those_truncated_by_usize() {
        let bins = 30;
        let per_radian = bins as f32 / std::f32::consts::TAU;
        let by_usize = |s: f32, m: f32| {
            let x = (s - m) * per_radian;
            let x = if x < 0.0 { x + bins as f32 } else { x };
            (x as usize).min(bins - 1)
        };
        let mut phis = vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -0.0,
            0.0,
            -7.0,
            -std::f32::consts::TAU,
            std::f32::consts::TAU,
            -1e-30,
            1e9,
            -1e9,
        ];
        let mut v = 0.376_f32;
        for _ in 0..2_000 {
            v = (v * 7.31 + 0.41).fract();
            phis.push((v - 0.5) * 14.0);
        }
        for &s in &phis {
            for &m in phis.iter().step_by(7) {
                assert_eq!(alpha_bin(s, m, per_radian, bins), by_usize(s, m), "{s} {m}");
            }
        }
    }

    #[test]
    fn alpha_bins_are_those_of_the_wrapped_difference() {
        use std::f32::consts::{PI, TAU};
        let bins = 30;
        let per_radian = bins as f32 / TAU;
        let reference = |s: f32, m: f32| -> f64 {
            let a = (f64::from(s) - f64::from(m)).rem_euclid(std::f64::consts::TAU);
            a * bins as f64 / std::f64::consts::TAU
        };
        let mut pairs = vec![
            (PI, -PI),
            (-PI, PI),
            (0.0, 0.0),
            (-0.0, 0.0),
            (PI, PI),
            (1e-7, 0.0),
        ];
        let mut v = 0.123_456_7_f32;
        for _ in 0..100_000 {
            v = (v * 7.31 + 0.41).fract();
            let s = (v - 0.5) * TAU;
            v = (v * 7.31 + 0.41).fract();
            pairs.push((s, (v - 0.5) * TAU));
        }
        for (s, m) in pairs {
            let got = alpha_bin(s, m, per_radian, bins);
            assert!(got < bins, "{s} {m}");
            let exact = reference(s, m);
            // Only a difference within float rounding of a bin edge may fall either side.
            let want = (exact.floor() as usize).min(bins - 1);
            let near_edge = (exact - exact.round()).abs() < 1e-4;
            assert!(got == want || near_edge, "{s} {m}: {got} vs {exact}");
        }
    }

    /// An L of two rectangles plus a small tab (no rigid symmetry), sampled every `step` mm
    /// with outward normals.
    pub(crate) fn l_part(step: f32) -> OrientedPoints {
        let mut points = Vec::new();
        let mut normals = Vec::new();
        let grid = |a: f32, b: f32| {
            let (na, nb) = ((a / step) as usize, (b / step) as usize);
            (0..=na).flat_map(move |i| (0..=nb).map(move |j| (i as f32 * step, j as f32 * step)))
        };
        for (x, y) in grid(60.0, 30.0) {
            points.push([x, y, 0.0]);
            normals.push([0.0, 0.0, 1.0]);
        }
        for (y, z) in grid(30.0, 20.0) {
            points.push([0.0, y, z + step]);
            normals.push([-1.0, 0.0, 0.0]);
        }
        for (x, z) in grid(15.0, 10.0) {
            points.push([40.0 + x, 0.0, z + step]);
            normals.push([0.0, -1.0, 0.0]);
        }
        OrientedPoints { points, normals }
    }

    pub(crate) fn moved(m: &OrientedPoints, pose: &Isometry3<f64>) -> OrientedPoints {
        let p = |q: &P3| {
            let r = pose * Point3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]));
            [r.x as f32, r.y as f32, r.z as f32]
        };
        let n = |q: &P3| {
            let r = pose.rotation * Vector3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]));
            [r.x as f32, r.y as f32, r.z as f32]
        };
        OrientedPoints {
            points: m.points.iter().map(p).collect(),
            normals: m.normals.iter().map(n).collect(),
        }
    }

    pub(crate) fn pose(t: [f64; 3], axis: [f64; 3], deg: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_axis_angle(
                &nalgebra::Unit::new_normalize(Vector3::from(axis)),
                deg.to_radians(),
            ),
        )
    }

    /// The L part's table settings: 3 mm steps, pairs up to 75 mm.
    fn l_part_config() -> PpfConfig {
        PpfConfig {
            distance_step_mm: 3.0,
            feature_angle_bins: 15,
            alpha_bins: 30,
            max_pair_distance_mm: 75.0,
            spread: 0.25,
            max_pairs_per_bin: 1000,
        }
    }

    /// The scene search of these tests: every other point a reference, three peaks each.
    fn search() -> VotingConfig {
        VotingConfig {
            reference_stride: 2,
            peaks_per_reference: 3,
            secondary_peak_ratio: 0.6,
            distinct_pairs: false,
        }
    }

    /// A small deterministic generator (xorshift32): `next(m)` is in `0..m`.
    pub(crate) fn xorshift(seed: u32) -> impl FnMut(u32) -> u32 {
        let mut state = seed;
        move |m| {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state % m
        }
    }

    /// The peaks as first written: every local maximum collected and sorted.
    fn peaks_by_sorting(
        acc: &[u32],
        touched: &[u32],
        config: &VotingConfig,
        n_alpha: usize,
    ) -> Vec<(usize, u32)> {
        let mut cands: Vec<(usize, u32)> = touched
            .iter()
            .map(|&s| s as usize)
            .filter(|&s| {
                let (base, a) = (s - s % n_alpha, s % n_alpha);
                let prev = acc[base + (a + n_alpha - 1) % n_alpha];
                let next = acc[base + (a + 1) % n_alpha];
                acc[s] > prev && acc[s] >= next
            })
            .map(|s| (s, acc[s]))
            .collect();
        cands.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let Some(&(_, best)) = cands.first() else {
            return Vec::new();
        };
        let floor = (config.secondary_peak_ratio * f64::from(best)).ceil() as u32;
        cands
            .into_iter()
            .take(config.peaks_per_reference)
            .filter(|&(_, v)| v >= floor.max(1))
            .collect()
    }

    #[test]
    fn peaks_kept_while_scanning_are_those_of_a_full_sort() {
        let table = PpfModel::new(&l_part(3.0), l_part_config()).unwrap();
        let n_alpha = 12;
        let mut next = xorshift(0x2545_f491);
        let mut nonempty = 0;
        for trial in 0..2000 {
            // Few distinct counts, so ties and plateaus are common.
            let slots = 24 * n_alpha;
            let acc: Vec<u32> = (0..slots).map(|_| next(6)).collect();
            let touched: Vec<u32> = (0..slots as u32).filter(|&s| acc[s as usize] > 0).collect();
            let config = VotingConfig {
                reference_stride: 1,
                peaks_per_reference: 1 + trial % 5,
                secondary_peak_ratio: [0.0, 0.6, 1.0][trial % 3],
                distinct_pairs: false,
            };
            let kept = table.peaks(&acc, &touched, &config, n_alpha);
            assert_eq!(
                kept,
                peaks_by_sorting(&acc, &touched, &config, n_alpha),
                "trial {trial}"
            );
            nonempty += usize::from(!kept.is_empty());
        }
        assert!(nonempty > 1000);
    }

    #[test]
    fn votes_recover_two_instances() {
        let model = l_part(3.0);
        let table = PpfModel::new(&model, l_part_config()).unwrap();
        assert!(table.entries() > model.len() * (model.len() - 1));
        let t1 = pose([100.0, 20.0, 5.0], [0.2, 1.0, 0.3], 70.0);
        let t2 = pose([-90.0, 40.0, 0.0], [1.0, -0.5, 0.2], 150.0);
        let (a, b) = (moved(&model, &t1), moved(&model, &t2));
        let scene = OrientedPoints {
            points: [a.points, b.points].concat(),
            normals: [a.normals, b.normals].concat(),
        };
        let index = PointIndex::new("scene", &scene.points).unwrap();
        for distinct_pairs in [false, true] {
            let config = VotingConfig {
                distinct_pairs,
                ..search()
            };
            two_instances_voted(&table, &scene, &index, &config, [t1, t2]);
        }
    }

    fn two_instances_voted(
        table: &PpfModel,
        scene: &OrientedPoints,
        index: &PointIndex,
        config: &VotingConfig,
        truths: [Isometry3<f64>; 2],
    ) {
        let votes = table.vote(scene, index, config).unwrap();
        let centre = Point3::new(30.0, 15.0, 5.0);
        let clusters = cluster_poses(
            &votes,
            &centre,
            &Symmetries::none(),
            &PoseClustering {
                translation_mm: 7.5,
                rotation_deg: 24.0,
            },
        )
        .unwrap();
        for truth in truths {
            let found = clusters.iter().take(2).any(|c| {
                (c.pose * centre - truth * centre).norm() < 3.0
                    && c.pose.rotation.angle_to(&truth.rotation).to_degrees() < 10.0
            });
            assert!(found, "{truth:?} not among {:?}", &clusters[..2]);
        }
        // Same answer again (determinism across runs and threads).
        let again = table.vote(scene, index, config).unwrap();
        assert_eq!(votes, again, "{config:?}");
    }

    /// The best peak's votes per reference point, in reference order.
    fn best_votes(votes: &[Vote]) -> Vec<(u32, u32)> {
        let mut best: Vec<(u32, u32)> = Vec::new();
        for v in votes {
            match best.last_mut() {
                Some(b) if b.0 == v.reference => b.1 = b.1.max(v.votes),
                _ => best.push((v.reference, v.votes)),
            }
        }
        best
    }

    #[test]
    fn a_scene_pair_repeated_votes_once_with_distinct_pairs() {
        let model = l_part(3.0);
        let table = PpfModel::new(&model, l_part_config()).unwrap();
        let once = moved(&model, &pose([10.0, -5.0, 3.0], [0.3, 1.0, -0.2], 40.0));
        // Every point twice: each scene pair then comes twice with the same feature and angle.
        let twice = OrientedPoints {
            points: [once.points.clone(), once.points.clone()].concat(),
            normals: [once.normals.clone(), once.normals.clone()].concat(),
        };
        let vote = |scene: &OrientedPoints, distinct_pairs: bool| {
            let index = PointIndex::new("scene", &scene.points).unwrap();
            let config = VotingConfig {
                reference_stride: 1,
                distinct_pairs,
                ..search()
            };
            best_votes(&table.vote(scene, &index, &config).unwrap())
        };
        let n = once.len() as u32;
        let first_copy = |v: Vec<(u32, u32)>| -> Vec<(u32, u32)> {
            v.into_iter().filter(|&(r, _)| r < n).collect()
        };
        // Every pair voting: the copy doubles every count.
        let all_once = vote(&once, false);
        let all_twice = first_copy(vote(&twice, false));
        assert_eq!(all_once.len(), all_twice.len());
        for (a, b) in all_once.iter().zip(&all_twice) {
            assert_eq!((a.0, 2 * a.1), *b);
        }
        // Distinct pairs only: the scene twice over votes no more than every pair of the
        // scene once, and less for most references (flat regions' repeats are dropped).
        let distinct_twice = first_copy(vote(&twice, true));
        let mut fewer = 0;
        for (a, b) in all_once.iter().zip(&distinct_twice) {
            assert_eq!(a.0, b.0);
            assert!(
                b.1 <= a.1,
                "reference {}: {} votes against {}",
                a.0,
                b.1,
                a.1
            );
            fewer += usize::from(b.1 < a.1);
        }
        assert!(fewer > all_once.len() / 2, "{fewer} of {}", all_once.len());
    }

    #[test]
    fn bad_configs_are_named() {
        let model = l_part(5.0);
        let mut c = PpfConfig {
            distance_step_mm: 0.0,
            feature_angle_bins: 15,
            alpha_bins: 30,
            max_pair_distance_mm: 75.0,
            spread: 0.25,
            max_pairs_per_bin: 1000,
        };
        let e = PpfModel::new(&model, c.clone()).unwrap_err();
        assert!(e.to_string().contains("distance_step_mm"), "{e}");
        c.distance_step_mm = 3.0;
        c.spread = 0.7;
        assert!(
            PpfModel::new(&model, c)
                .unwrap_err()
                .to_string()
                .contains("spread")
        );
    }
}
