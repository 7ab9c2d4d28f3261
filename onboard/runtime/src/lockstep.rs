//! Lockstep runner (being written).
