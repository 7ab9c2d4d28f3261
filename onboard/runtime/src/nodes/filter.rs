//! filter node (being written).
