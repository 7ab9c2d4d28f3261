//! vision node (being written).
