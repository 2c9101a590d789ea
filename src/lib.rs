//! adsb-tracker: a Mode S / ADS-B daemon that tracks every aircraft it hears.
//!
//! The data path runs one way (see `DESIGN.md`):
//! [`feed`] (bytes -> [`feed::RawFrame`]) -> [`decode`] (frames -> [`decode::Decoded`])
//! -> [`daemon`] (a task per aircraft: CPR -> [`track::Measurement`] -> [`track::Tracker`])
//! -> [`api`] (HTTP, reading published snapshots only). [`app`] wires the daemon and the API
//! together; the daemon never imports the API.
//!
//! [`track`] is pure math: no tokio, no I/O, no JSON.

pub mod api;
pub mod app;
pub mod cluster;
pub mod config;
pub mod daemon;
pub mod decode;
pub mod eval;
pub mod feed;
pub mod output;
pub mod sim;
pub mod track;
