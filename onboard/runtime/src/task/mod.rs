//! Fixed-rate tasks (being written).
