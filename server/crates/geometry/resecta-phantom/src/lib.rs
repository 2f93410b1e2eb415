//! Synthetic liver phantoms with analytic truth.
