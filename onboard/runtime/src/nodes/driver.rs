//! driver node (being written).
