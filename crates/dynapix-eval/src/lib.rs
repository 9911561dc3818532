//! dynapix-eval (in progress).
