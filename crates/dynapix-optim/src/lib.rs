//! dynapix-optim (in progress).
