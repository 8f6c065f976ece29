//! General reflectance functions (§3.6): models, prototype tables,
//! actual-to-prototype maps and the on-disk prototype library.
//!
//! A diffuse surface reflects the same share of its power along every link
//! end and needs none of this. Any other reflectance function is tabulated
//! once, for the prototype orientation, over the global direction set
//! ([`prototype`]); each surface orientation gets a bijection on direction
//! ids onto the prototype ([`map`]); the distribution then moves light from
//! a patch's in-buffers through the map, the table and the map back to its
//! link ends (`distribute`, Figure 9).
//!
//! Pure math except [`library`], which caches tables on disk.

pub mod library;
pub mod map;
pub mod model;
pub mod prototype;

pub use map::{Frame, MapMethod, MapStats, OrientationMap};
pub use model::{Lobe, TableModel};
pub use prototype::{PrototypeTable, TableStats};
