//! Geometry shared by tracking, relocalisation and evaluation: the one
//! RANSAC driver, the one least-squares alignment (Umeyama), and PnP.

pub mod alignment;
pub mod pnp;
pub mod ransac;
