//! Loop correction: pose propagation, loop fusion, essential graph and global bundle adjustment.
