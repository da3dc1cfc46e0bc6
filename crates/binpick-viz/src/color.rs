//! Colours: a categorical palette of saturated, mutually distinct colours for detections, a
//! green-to-red ramp for scores and a low-saturation ramp for scene height.

/// Saturated colours that stay distinct from each other and from the grey/sand scene ramp
/// (after Sasha Trubetskoy's "20 distinct colours", the low-saturation entries left out).
const PALETTE: [[u8; 3]; 16] = [
    [230, 25, 75],   // red
    [0, 130, 200],   // blue
    [60, 180, 75],   // green
    [245, 130, 48],  // orange
    [145, 30, 180],  // purple
    [0, 200, 200],   // cyan
    [240, 50, 230],  // magenta
    [170, 110, 40],  // brown
    [128, 128, 0],   // olive
    [0, 0, 128],     // navy
    [255, 200, 0],   // yellow
    [128, 0, 0],     // maroon
    [0, 128, 128],   // teal
    [255, 100, 170], // pink
    [150, 215, 0],   // lime
    [95, 95, 255],   // periwinkle
];

/// Colour of the detection with this rank (1 = best). Ranks past the palette's length cycle.
/// The same colours are used in the PNG render and the labelled PLY.
pub fn rank_color(rank: usize) -> [u8; 3] {
    PALETTE[rank.saturating_sub(1) % PALETTE.len()]
}

/// Colour for a final score (percent outliers, lower is better) within `[lo, hi]`:
/// green at `lo`, yellow halfway, red at `hi` and above.
pub fn score_color(score: f64, lo: f64, hi: f64) -> [u8; 3] {
    let t = if hi > lo && score.is_finite() {
        ((score - lo) / (hi - lo)).clamp(0.0, 1.0)
    } else if score.is_finite() {
        0.0
    } else {
        1.0
    };
    let stops: [(f64, [f64; 3]); 3] = [
        (0.0, [26.0, 170.0, 60.0]),
        (0.5, [240.0, 190.0, 0.0]),
        (1.0, [215.0, 30.0, 30.0]),
    ];
    ramp(&stops, t)
}

/// Scene colour for a normalised height `t` in 0..=1: dark slate (low) to light sand (high),
/// deliberately low in saturation so the detections' colours stand out.
pub(crate) fn height_color(t: f64) -> [u8; 3] {
    let stops: [(f64, [f64; 3]); 3] = [
        (0.0, [62.0, 68.0, 84.0]),
        (0.5, [138.0, 142.0, 146.0]),
        (1.0, [226.0, 216.0, 190.0]),
    ];
    ramp(&stops, t.clamp(0.0, 1.0))
}

fn ramp(stops: &[(f64, [f64; 3])], t: f64) -> [u8; 3] {
    let mut out = [0u8; 3];
    let Some(first) = stops.first() else {
        return out;
    };
    let mut lo = *first;
    let mut hi = *first;
    for w in stops.windows(2) {
        lo = w[0];
        hi = w[1];
        if t <= w[1].0 {
            break;
        }
    }
    let f = if hi.0 > lo.0 {
        ((t - lo.0) / (hi.0 - lo.0)).clamp(0.0, 1.0)
    } else {
        0.0
    };
    for (o, (a, b)) in out.iter_mut().zip(lo.1.iter().zip(hi.1.iter())) {
        *o = (a + (b - a) * f).round().clamp(0.0, 255.0) as u8;
    }
    out
}

/// `c` scaled towards black by `f` (1 = unchanged).
pub(crate) fn shade(c: [u8; 3], f: f64) -> [u8; 3] {
    let f = f.clamp(0.0, 1.0);
    [
        (f64::from(c[0]) * f).round() as u8,
        (f64::from(c[1]) * f).round() as u8,
        (f64::from(c[2]) * f).round() as u8,
    ]
}

/// `a` mixed with `b`: `t` = 0 gives `a`, 1 gives `b`.
pub(crate) fn mix(a: [u8; 3], b: [u8; 3], t: f64) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let m = |x: u8, y: u8| (f64::from(x) * (1.0 - t) + f64::from(y) * t).round() as u8;
    [m(a[0], b[0]), m(a[1], b[1]), m(a[2], b[2])]
}

/// Relative luminance-ish brightness (0..255), to pick black or white text on a colour.
pub(crate) fn brightness(c: [u8; 3]) -> f64 {
    0.299 * f64::from(c[0]) + 0.587 * f64::from(c[1]) + 0.114 * f64::from(c[2])
}
