//! The daemon (TODO).
