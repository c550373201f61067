//! Acceleration structures, one folder per family. A family never calls
//! another; `render` and `context` compose them.
#![forbid(unsafe_code)]

pub mod bvh;
pub mod entry;
pub mod fallback;
pub mod grid;
pub mod kd;
pub mod mailbox;
pub mod pgrid;
