//! Rays, triangles, the triangle mesh as the renderer stores it, and the BVH over it.

mod bvh;
mod instances;
mod mesh;
mod ray;
mod triangle;

pub use bvh::{Bvh, RayQuery, BUNDLE};
pub use instances::{
    flatten_into, usable_placements, Instance, InstanceError, InstanceHit, Instances, Placement,
    Prototype, Unplaced,
};
pub use mesh::{renderable, Mesh, MeshError};
pub use ray::Ray;
pub(crate) use triangle::box_reciprocal;
pub use triangle::{intersect_watertight, RayPrecomp, TriangleHit};
