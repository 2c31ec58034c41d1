//! Library part of the `meshadv-render` binary: the mesh readers, shared with the fuzz targets
//! (`fuzz/`) and the crash-regression tests.

pub mod meshio;
