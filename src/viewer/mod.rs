//! `hytrace view`: an interactive window on a scene — orbit, pan, zoom and fly; previews that
//! hold the frame rate while the camera moves and refine to `render`'s image when it rests;
//! debug views and switches; hot reload of the scene file; screenshots; scripts.
//!
//! Everything but the window itself ([`window`], [`present`], [`watch`]) works without a
//! display: the camera ([`orbit`]), the input handling and schedule ([`session`]) and scripts
//! ([`script`]) are what the unit tests drive; the render thread (`worker`, on the CPU or a
//! GPU) comes with the `viewer` feature.

pub mod input;
pub mod orbit;
#[cfg(feature = "viewer")]
pub mod present;
pub mod script;
pub mod session;
#[cfg(feature = "viewer")]
pub mod watch;
#[cfg(feature = "viewer")]
pub mod window;
#[cfg(feature = "viewer")]
pub mod worker;
