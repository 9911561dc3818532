//! dynapix-motion (in progress).
