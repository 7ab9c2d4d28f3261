//! comms node (being written).
