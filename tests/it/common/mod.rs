//! Helpers shared by the integration tests, one file per topic. Every helper is used by some
//! test module of this one binary (an unused one is a compiler warning, and is deleted).

mod bounded;
mod build_dir;
mod cli;
mod daemon;
mod data;
mod docs;
mod fixtures;
mod learn;
pub mod pty;
pub mod render2;
mod rng;
mod services;
mod web;

pub use bounded::*;
pub use build_dir::*;
pub use cli::*;
pub use daemon::*;
pub use data::*;
pub use docs::*;
pub use fixtures::*;
pub use learn::*;
pub use rng::*;
pub use services::*;
pub use web::*;
