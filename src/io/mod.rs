//! File formats: readers and writers of external and native BRDF files.

pub mod rgl;
