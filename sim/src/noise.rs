//! Procedural noise for terrain relief and albedo texture (owned by the terrain helper).
