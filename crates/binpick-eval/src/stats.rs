//! Summary statistics of per-scene times.

/// Median and 95th percentile (nearest-rank) of `values`; (0, 0) when empty.
pub fn median_p95(values: &[f64]) -> (f64, f64) {
    if values.is_empty() {
        return (0.0, 0.0);
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = |q: f64| v[((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
    (rank(0.5), rank(0.95))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_p95() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(median_p95(&v), (50.0, 95.0));
        assert_eq!(median_p95(&[7.0]), (7.0, 7.0));
        assert_eq!(median_p95(&[]), (0.0, 0.0));
    }
}
