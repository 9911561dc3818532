//! dynapix-io (in progress).
