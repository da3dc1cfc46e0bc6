//! Recognition pipeline (being written).
