//! dynapix-synth (in progress).
