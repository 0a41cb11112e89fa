//! Planning: what to store and how, from an error budget. Budgets ([`budget`]), the
//! confidence-bounded error estimate of a candidate file against its source ([`estimate`]),
//! the rate-controlled encoder ([`rate`]), the grid ladder of `pack` ([`grids`]) and the older
//! exhaustive codec search kept for figures and `--effort max` comparisons ([`search`]).

pub mod budget;
pub mod build;
pub mod estimate;
pub mod grids;
pub mod manifest;
pub mod pack;
pub mod rate;
pub mod rgl;
pub mod scene;
pub mod search;
pub mod zoo;
