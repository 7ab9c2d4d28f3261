//! mapper node (being written).
