//! Synthetic scans (being written).
