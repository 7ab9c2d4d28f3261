//! The pictures of `sim pictures`: a rendered left image, its depth and a top-down terrain map
//! per preset (owned by the dataset helper).
