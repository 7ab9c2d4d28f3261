//! Unit tests of the internal stages that need private access.
