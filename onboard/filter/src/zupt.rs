//! Standstill detection (in progress).
